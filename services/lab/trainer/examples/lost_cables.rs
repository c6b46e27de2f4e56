//! Where a policy loses the cable. For every seed of a step-two benchmark's JSON, one of its pairs
//! of policies (`sim_gains`, the simulation policies, or `after_gains`, step two's) acting on the
//! twin with images, on the seed's evaluation set and its 4 held-out sets (5 trials each): the
//! cables lost and each DOF's mean return. With a seed after the pair, that seed alone, and the
//! last 8 s of each trial that lost the cable: what perception saw against what the camera truly
//! saw, and the commands (a missed frame shows 0, a dropped one NaN).
//!
//! The scenario comes from CONFIG (`[missed_frames]` says how a behaviour answers a frame in
//! which perception missed the cable), so two configuration directories compare the rule.
//!
//! `cargo run --release -p trainer --example lost_cables -- BENCH.json TWIN.toml CONFIG
//! sim_gains|after_gains [SEED]` (from the repository).
use config::Eyes;
use std::path::Path;
use trainer::evaluation::policy_checkpoint;
use trainer::step_two_bench::BenchFile;
use trainer::twin_world::{Mode, TwinWorld};

/// Trace points shown before a lost trial's end: 8 s at the 0.2 s sample time.
const SHOWN: usize = 40;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 5 {
        eprintln!("usage: lost_cables BENCH.json TWIN.toml CONFIG sim_gains|after_gains [SEED]");
        std::process::exit(2);
    }
    let bench: BenchFile =
        serde_json::from_str(&std::fs::read_to_string(&args[1]).expect("the benchmark's JSON"))
            .expect("a step-two benchmark's JSON");
    let twin: config::TwinParams = config::load(Path::new(&args[2])).expect("the twin");
    let setup = trainer::Setup::load(Path::new(&args[3]), config::Preset::Default)
        .expect("the configuration directory");
    let after = match args[4].as_str() {
        "sim_gains" => false,
        "after_gains" => true,
        other => panic!("the pair is sim_gains or after_gains, not {other}"),
    };
    let only: Option<u64> = args.get(5).map(|s| s.parse().expect("a seed"));
    let sc = &setup.scenario;
    let seeds: Vec<_> = bench
        .seeds
        .iter()
        .filter(|s| only.is_none_or(|o| s.seed == o))
        .collect();
    let rows = trainer::experiment::parallel_map(
        seeds.len(),
        &trainer::progress::Progress::hidden(),
        |k| {
            let s = seeds[k];
            let seed = s.seed;
            let gains = if after { s.after_gains } else { s.sim_gains };
            let c = policy_checkpoint(sc, &setup.learning, gains);
            let (mut lost, mut returns, mut traces) = (0, [0.0; 2], String::new());
            for set in 0..5 {
                let set_seed = match set {
                    0 => seed,
                    h => config::derive_seed(seed, &format!("held-out/{}", h - 1)),
                };
                let mut w =
                    TwinWorld::from_checkpoint(sc, &twin, &c, Eyes::Images, set_seed, Mode::Act)
                        .expect("the policies load");
                w.record(only.is_some());
                for _ in 0..5 {
                    let r = w.run_trial();
                    let trace = w.take_trace();
                    lost += r.lost as u32;
                    returns[0] += r.returns.sway / 25.0;
                    returns[1] += r.returns.yaw / 25.0;
                    if !r.lost || only.is_none() {
                        continue;
                    }
                    traces += &format!(
                        "set {set} trial {}: lost after {} steps, {} frames missed, {} dropped\n",
                        r.trial, r.steps, r.missed, r.dropped
                    );
                    traces +=
                        "   t s | seen x_g, Theta deg | true x_g, Theta deg | sway, yaw, surge\n";
                    for p in &trace[trace.len().saturating_sub(SHOWN)..] {
                        traces += &format!(
                            "{:6.1} | {:7.3} {:7.2} | {:7.3} {:7.2} | {:6.3} {:6.3} {:5.2}\n",
                            p.time_s,
                            p.x_g,
                            p.theta.to_degrees(),
                            p.true_x_g,
                            p.true_theta.to_degrees(),
                            p.sway,
                            p.yaw,
                            p.surge
                        );
                    }
                }
            }
            (seed, lost, returns, traces)
        },
    );
    println!("seed | lost of 25 | J sway, yaw (mean over the 25 trials)");
    let mut total = 0;
    for (seed, lost, j, traces) in &rows {
        total += lost;
        println!("{seed:>4} | {lost:>2} | {:8.3} {:8.3}", j[0], j[1]);
        print!("{traces}");
    }
    println!("lost {total} of {}", 25 * rows.len());
}
