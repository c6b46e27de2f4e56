//! One step-two session in one process, as the vehicle mesh runs it: the behaviours resumed from a
//! policy directory (the main job's `step-one/`), learning under step two's protocol on a twin, with
//! the supervisor's seed (the job's `--seed`). Each evaluation: the pair's mean returns against the
//! first's, the gains it evaluated and those in force after it, each evaluation trial's return
//! against the first evaluation's on the same start and noise (the paired differences tell a real
//! change from the evaluation's noise), and what the safety layer did. A job's step two is replayed
//! bit for bit in a few seconds, so a learner's setting can be tried on the very session that went
//! wrong.
//!
//! `cargo run --release -p trainer --example session -- POLICY_DIR TWIN.toml SEED [--trials N]
//! [--eyes images|ideal] [--lambda L]` (from the repository; `--lambda`: step two's eligibility rate
//! instead of the checkpoint's).
use config::{Eyes, PerDof};
use std::path::Path;
use trainer::twin_world::{Mode, TwinWorld};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let usage =
        "usage: session POLICY_DIR TWIN.toml SEED [--trials N] [--eyes images|ideal] [--lambda L]";
    let [dir, twin, seed, options @ ..] = args.as_slice() else {
        eprintln!("{usage}");
        std::process::exit(2);
    };
    let (mut trials, mut eyes, mut lambda) = (45u32, Eyes::Images, None);
    for pair in options.chunks(2) {
        match pair {
            [k, v] if k == "--trials" => trials = v.parse().expect("--trials: a number"),
            [k, v] if k == "--eyes" => eyes = v.parse().expect("--eyes: images or ideal"),
            [k, v] if k == "--lambda" => {
                lambda = Some(v.parse::<f64>().expect("--lambda: a number"))
            }
            _ => {
                eprintln!("{usage}");
                std::process::exit(2);
            }
        }
    }
    let mut policies =
        trainer::evaluation::load_policies(Path::new(dir)).unwrap_or_else(|e| panic!("{dir}: {e}"));
    if let Some(l) = lambda {
        for a in [&mut policies.sway, &mut policies.yaw]
            .into_iter()
            .flatten()
        {
            a.params.step_two.lambda = l;
        }
    }
    let twin: config::TwinParams =
        config::load(Path::new(twin)).unwrap_or_else(|e| panic!("{twin}: {e}"));
    let seed: u64 = seed.parse().expect("SEED: a number");
    let setup = trainer::Setup::load(Path::new("config"), config::Preset::Default)
        .expect("config/ (run from the repository)");
    let mut world =
        TwinWorld::from_checkpoint(&setup.scenario, &twin, &policies, eyes, seed, Mode::Learn)
            .expect("the policies resume");
    let round = |g: [f64; 2]| g.map(|v| (v * 100.0).round() / 100.0);
    let (mut first, mut first_trials) = (None::<PerDof<f64>>, None::<Vec<PerDof<f64>>>);
    // The gains an evaluation evaluates: the policies given, then those of the last learning trial.
    let mut evaluated = PerDof {
        sway: world.agent(config::Dof::Sway).gain(),
        yaw: world.agent(config::Dof::Yaw).gain(),
    };
    let mut this = Vec::new();
    for _ in 0..trials {
        let r = world.run_trial();
        if !r.evaluation {
            evaluated = r.gains;
            continue;
        }
        this.push(r.returns);
        if r.evaluated.sway.is_nan() {
            continue;
        }
        let f = *first.get_or_insert(r.evaluated);
        let base = first_trials.get_or_insert_with(|| this.clone());
        let paired = |get: fn(&PerDof<f64>) -> f64| {
            this.iter()
                .zip(base.iter())
                .map(|(a, b)| ((get(a) - get(b)) * 100.0).round() / 100.0)
                .collect::<Vec<_>>()
        };
        let change = |now: f64, then: f64| 100.0 * (now / then - 1.0);
        println!(
            "trial {:>3}: yaw {:8.3} ({:+6.1}%), sway {:8.3} ({:+6.1}%); evaluated gains yaw {:?} sway {:?}; in force after: yaw {:?} sway {:?}; rolled back {}",
            r.trial,
            r.evaluated.yaw,
            change(r.evaluated.yaw, f.yaw),
            r.evaluated.sway,
            change(r.evaluated.sway, f.sway),
            round(evaluated.yaw),
            round(evaluated.sway),
            round(r.gains.yaw),
            round(r.gains.sway),
            r.rolled_back.yaw || r.rolled_back.sway,
        );
        println!(
            "           each trial against the first evaluation's: yaw {:?}, sway {:?}; updates shortened yaw {}, sway {}; refused yaw {}, sway {}",
            paired(|d| d.yaw),
            paired(|d| d.sway),
            r.bounded.yaw,
            r.bounded.sway,
            r.refused.yaw,
            r.refused.sway,
        );
        this.clear();
    }
}
