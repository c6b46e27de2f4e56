//! Which of a seed's two policy changes costs a DOF, and is the cost real or only seen? For every
//! seed of a step-two benchmark's JSON, the four pairs of its simulation and final gains (sway's and
//! yaw's each either), acting on the seed's 4 held-out sets of 5 trials with images: each DOF's
//! return, and its state cost (the reward's `x'Qx`, rate by difference) from what perception saw and
//! from the twin's true state.
//!
//! `cargo run --release -p trainer --example pairs -- BENCH.json TWIN.toml` (from the repository).
use config::{Dof, Eyes, PerDof};
use std::path::Path;
use trainer::evaluation::policy_checkpoint;
use trainer::twin_world::{Mode, TwinWorld};

fn gains(v: &serde_json::Value) -> PerDof<[f64; 2]> {
    let g = |k: &str| [v[k][0].as_f64().unwrap(), v[k][1].as_f64().unwrap()];
    PerDof {
        sway: g("sway"),
        yaw: g("yaw"),
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let bench: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&args[1]).unwrap()).unwrap();
    let twin: config::TwinParams = config::load(Path::new(&args[2])).unwrap();
    let setup = trainer::Setup::load(Path::new("config"), config::Preset::Default).unwrap();
    let sc = &setup.scenario;
    let dt = sc.timing.sample_time_s;
    let seeds: Vec<&serde_json::Value> = bench["seeds"].as_array().unwrap().iter().collect();
    let rows = trainer::experiment::parallel_map(
        seeds.len() * 4,
        &trainer::progress::Progress::hidden(),
        |k| {
            let s = seeds[k / 4];
            let seed = s["seed"].as_u64().unwrap();
            let (sim, after) = (gains(&s["sim_gains"]), gains(&s["after_gains"]));
            let pair = match k % 4 {
                0 => sim,
                1 => PerDof {
                    sway: after.sway,
                    yaw: sim.yaw,
                },
                2 => PerDof {
                    sway: sim.sway,
                    yaw: after.yaw,
                },
                _ => after,
            };
            let c = policy_checkpoint(sc, &setup.learning, pair);
            let (mut ret, mut seen, mut truth, mut n, mut lost) =
                ([0.0; 2], [0.0; 2], [0.0; 2], 0u32, 0);
            for h in 0..4 {
                let set = config::derive_seed(seed, &format!("held-out/{h}"));
                let mut w = TwinWorld::from_checkpoint(sc, &twin, &c, Eyes::Images, set, Mode::Act)
                    .unwrap();
                w.record(true);
                for _ in 0..5 {
                    let r = w.run_trial();
                    lost += r.lost as u32;
                    ret[0] += r.returns.sway;
                    ret[1] += r.returns.yaw;
                    n += 1;
                    let tr = w.take_trace();
                    for (i, dof) in [Dof::Sway, Dof::Yaw].into_iter().enumerate() {
                        let q = sc.reward.of(dof).q;
                        let pos = |p: &trainer::twin_world::TracePoint, t: bool| match (dof, t) {
                            (Dof::Sway, false) => p.x_g,
                            (Dof::Sway, true) => p.true_x_g,
                            (Dof::Yaw, false) => p.theta,
                            (Dof::Yaw, true) => p.true_theta,
                        };
                        for win in tr.windows(2) {
                            let (a, b) = (&win[0], &win[1]);
                            if pos(a, false).is_nan() || pos(b, false).is_nan() {
                                continue;
                            }
                            for (t, acc) in [(false, &mut seen[i]), (true, &mut truth[i])] {
                                let x = pos(b, t);
                                let v = (pos(b, t) - pos(a, t)) / dt;
                                *acc -= q[0] * x * x + q[1] * v * v;
                            }
                        }
                    }
                }
            }
            let m = |a: [f64; 2]| [a[0] / n as f64, a[1] / n as f64];
            (seed, k % 4, m(ret), m(seen), m(truth), lost)
        },
    );
    println!("seed pair(sway,yaw)  J_sway J_yaw | seen cost sway yaw | true cost sway yaw | lost");
    let names = ["sim,sim", "aft,sim", "sim,aft", "aft,aft"];
    for (seed, p, r, s, t, lost) in rows {
        println!(
            "{seed:>3} {:8} {:8.3} {:8.3} | {:9.3} {:9.3} | {:9.3} {:9.3} | {lost}",
            names[p], r[0], r[1], s[0], s[1], t[0], t[1]
        );
    }
}
