//! Step two in one process, the numbers behind the twin's calibration: a step-one policy (the
//! trainer, 100 episodes in simulation) acting on the simulator and on the twin from the same trial
//! starts, then learning online on the twin (and, for a paired comparison, acting on the twin
//! without learning over the very same trials).
//!
//! cargo run --release -p trainer --example step_two -- [--seeds 1,2,3] [--trials 20]
//!     [--eyes images|ideal] [--twin config/twin.toml] [--alpha A] [--sim-episodes 100] [--quiet]
//!
//! "Simulation" here is the twin with every effect off (`TwinParams::ideal`, with the simulator's
//! images): the identified model and the centred camera, in trials of the same length from the same
//! starts.

use config::Eyes;
use config::{Dof, LearningParams, Scenario, TwinParams};
use learning::{Algorithm, Checkpoint};
use stats::mean;
use std::path::PathBuf;
use trainer::Perceiver;
use trainer::twin_world::{TrialResult, TwinWorld};
use trainer::world::World;

fn arg<T: std::str::FromStr>(args: &[String], name: &str, default: T) -> T {
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn returns(run: &[TrialResult], dof: Dof) -> f64 {
    mean(run.iter().map(|r| *r.returns.get(dof)))
}

fn per_step(run: &[TrialResult], dof: Dof) -> f64 {
    mean(run.iter().map(|r| r.per_step(dof)))
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let seeds: String = arg(&args, "--seeds", "1".to_string());
    let trials: usize = arg(&args, "--trials", 20);
    let sim_episodes: usize = arg(&args, "--sim-episodes", 100);
    let eyes = match arg(&args, "--eyes", "images".to_string()).as_str() {
        "ideal" => Eyes::Ideal,
        _ => Eyes::Images,
    };
    let twin_path: PathBuf = arg(&args, "--twin", PathBuf::from("config/twin.toml"));
    let alpha: Option<f64> = args
        .iter()
        .position(|a| a == "--alpha")
        .and_then(|i| args[i + 1].parse().ok());
    let quiet = args.iter().any(|a| a == "--quiet");
    let scenario: Scenario = config::load(&PathBuf::from("config/scenario.toml")).unwrap();
    let learning: LearningParams = config::load(&PathBuf::from("config/learning.toml")).unwrap();
    let twin: TwinParams = config::load(&twin_path).unwrap();
    let mut sim_twin = TwinParams::ideal();
    sim_twin.trials = twin.trials.clone();
    sim_twin.render = scenario.render.clone();

    let mut counts = [0usize; 7];
    let seeds: Vec<u64> = seeds.split(',').map(|s| s.parse().unwrap()).collect();
    for &seed in &seeds {
        let t = std::time::Instant::now();
        let mut world = World::new(
            &scenario,
            &learning,
            Algorithm::Nac,
            Perceiver::Ideal(scenario.observation.clone()),
            seed,
        );
        for _ in 0..sim_episodes {
            world.run_episode();
        }
        let agents = world.into_agents();
        let mut ckpt = Checkpoint::single(agents.sway.checkpoint());
        ckpt.insert(agents.yaw.checkpoint());
        if let Some(a) = alpha {
            for dof in Dof::ALL {
                let mut s = ckpt.take(dof).unwrap();
                *s.params.nac.alpha.get_mut(dof) = a;
                ckpt.insert(s);
            }
        }
        let run = |params: &TwinParams, learn: bool| -> Vec<TrialResult> {
            let mut w = TwinWorld::from_checkpoint(&scenario, params, &ckpt, eyes, seed).unwrap();
            w.set_learning(learn);
            (0..trials).map(|_| w.run_trial()).collect()
        };
        let sim = run(&sim_twin, false);
        let frozen = run(&twin, false);
        let learned = run(&twin, true);
        let (head, tail) = (&learned[..5], &learned[trials - 5..]);
        let worse = |dof| per_step(&frozen, dof) < per_step(&sim, dof);
        let better = |dof| returns(tail, dof) > returns(head, dof);
        let total = |r: &[TrialResult]| returns(r, Dof::Yaw) + returns(r, Dof::Sway);
        let lost = |r: &[TrialResult]| r.iter().filter(|t| t.lost).count();
        for (k, ok) in [
            worse(Dof::Yaw),
            worse(Dof::Sway),
            lost(&frozen) <= 2,
            better(Dof::Yaw),
            better(Dof::Sway),
            better(Dof::Yaw) && better(Dof::Sway),
            total(tail) > total(head),
        ]
        .into_iter()
        .enumerate()
        {
            counts[k] += ok as usize;
        }
        let k0 = (agents.sway.gain(), agents.yaw.gain());
        let k1 = learned.last().unwrap().gains;
        println!(
            "seed {seed:2}: K sim sway {:5.2?} yaw {:6.2?} -> twin sway {:5.2?} yaw {:6.2?} | per step sim y {:.4} s {:.5} twin y {:.4} s {:.5} | lost sim {} twin {} learning {} | learning first5 y {:6.2} s {:.3} last5 y {:6.2} s {:.3} | paired last5 y {:+.2} s {:+.3} | {:.1}s",
            k0.0,
            k0.1,
            k1.sway,
            k1.yaw,
            per_step(&sim, Dof::Yaw),
            per_step(&sim, Dof::Sway),
            per_step(&frozen, Dof::Yaw),
            per_step(&frozen, Dof::Sway),
            lost(&sim),
            lost(&frozen),
            lost(&learned),
            returns(head, Dof::Yaw),
            returns(head, Dof::Sway),
            returns(tail, Dof::Yaw),
            returns(tail, Dof::Sway),
            returns(tail, Dof::Yaw) - returns(&frozen[trials - 5..], Dof::Yaw),
            returns(tail, Dof::Sway) - returns(&frozen[trials - 5..], Dof::Sway),
            t.elapsed().as_secs_f64()
        );
        if !quiet {
            for ((r, f), s) in learned.iter().zip(&frozen).zip(&sim) {
                println!(
                    "   trial {:2}: sim y {:7.3} s {:6.3} | twin frozen y {:7.3} s {:6.3} | learning y {:7.3} s {:6.3} steps {:3} lost {} dropped {:2} missed {:3} K sway {:5.2?} yaw {:6.2?}",
                    r.trial,
                    s.returns.yaw,
                    s.returns.sway,
                    f.returns.yaw,
                    f.returns.sway,
                    r.returns.yaw,
                    r.returns.sway,
                    r.steps,
                    r.lost as u8,
                    r.dropped,
                    r.missed,
                    r.gains.sway,
                    r.gains.yaw
                );
            }
        }
    }
    println!(
        "{} seeds: twin worse yaw {} sway {} | twin lost <= 2 of {trials}: {} | last 5 > first 5: yaw {} sway {} both {} total {}",
        seeds.len(),
        counts[0],
        counts[1],
        counts[2],
        counts[3],
        counts[4],
        counts[5],
        counts[6]
    );
}
