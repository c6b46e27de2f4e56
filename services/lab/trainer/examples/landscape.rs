//! What one DOF's gains are worth around a pair of policies, the other DOF's fixed: the pair with
//! that DOF's gains scaled (position and rate gain apart, then together), acting on the twin with
//! images, on the evaluation set of SEED and its 4 held-out sets (5 trials each): each DOF's mean
//! return and the cables lost. It shows where a better policy lies from a learner's start, and how
//! much one DOF's change costs the other.
//!
//! `cargo run --release -p trainer --example landscape -- TWIN.toml SEED SWAY_K YAW_K sway|yaw`
//! (from the repository; a K is `position,rate`, e.g. `4.85,6.2`).
use config::{Dof, Eyes, PerDof};
use std::path::Path;
use trainer::evaluation::{Evaluation, evaluate, policy_checkpoint};

const SCALES: [[f64; 2]; 9] = [
    [0.5, 1.0],
    [1.0, 0.5],
    [1.0, 1.0],
    [1.0, 1.5],
    [1.5, 1.0],
    [1.5, 1.5],
    [2.0, 2.0],
    [3.0, 3.0],
    [4.0, 4.0],
];

fn gain(text: &str) -> [f64; 2] {
    let v: Vec<f64> = text
        .split(',')
        .map(|x| x.trim().parse().expect("a gain is `position,rate`"))
        .collect();
    [v[0], v[1]]
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [twin, seed, sway, yaw, dof] = args.as_slice() else {
        eprintln!("usage: landscape TWIN.toml SEED SWAY_K YAW_K sway|yaw");
        std::process::exit(2);
    };
    let twin: config::TwinParams =
        config::load(Path::new(twin)).unwrap_or_else(|e| panic!("{twin}: {e}"));
    let seed: u64 = seed.parse().expect("SEED: a number");
    let Some(dof) = Dof::ALL.into_iter().find(|d| d.name() == dof) else {
        eprintln!("the DOF is sway or yaw, not {dof}");
        std::process::exit(2);
    };
    let start = PerDof {
        sway: gain(sway),
        yaw: gain(yaw),
    };
    let setup = trainer::Setup::load(Path::new("config"), config::Preset::Default)
        .expect("config/ (run from the repository)");
    let sets: Vec<u64> = std::iter::once(seed)
        .chain((0..4).map(|h| config::derive_seed(seed, &format!("held-out/{h}"))))
        .collect();
    let rows = trainer::experiment::parallel_map(
        SCALES.len(),
        &trainer::progress::Progress::hidden(),
        |k| {
            let mut pair = start;
            let g = pair.get_mut(dof);
            *g = [g[0] * SCALES[k][0], g[1] * SCALES[k][1]];
            let c = policy_checkpoint(&setup.scenario, &setup.learning, pair);
            let evaluations: Vec<Evaluation> = sets
                .iter()
                .map(|&s| evaluate(&setup.scenario, &twin, Eyes::Images, &c, s, 5).unwrap())
                .collect();
            (pair, evaluations)
        },
    );
    println!(
        "{dof}'s gains scaled | gains sway, yaw | evaluation set: J yaw, J sway | held-out mean: J yaw, J sway | cables lost"
    );
    for (k, (pair, e)) in rows.into_iter().enumerate() {
        let held = |f: fn(&PerDof<f64>) -> f64| {
            e[1..].iter().map(|e| f(&e.mean())).sum::<f64>() / (e.len() - 1) as f64
        };
        let round = |g: [f64; 2]| g.map(|v| (v * 100.0).round() / 100.0);
        println!(
            "x{:?} | {:?}, {:?} | {:8.3} {:8.3} | {:8.3} {:8.3} | {}",
            SCALES[k],
            round(pair.sway),
            round(pair.yaw),
            e[0].mean().yaw,
            e[0].mean().sway,
            held(|m| m.yaw),
            held(|m| m.sway),
            e.iter().map(|e| e.lost).sum::<u32>()
        );
    }
}
