//! The cost of one `Agent::step` (NAC and OLPOMDP) in a closed loop with a trivial linear plant, the
//! trainer's inner loop without the simulator. `cargo bench -p learning` prints ns per step;
//! `AGENT_BENCH_STEPS` sets the number of steps (default 4 million, the trainer's step-one budget).

use config::{Dof, LearningParams, Rewards};
use learning::{Agent, Algorithm, StepStatus};
use std::hint::black_box;
use std::time::Instant;

/// The plant and the episode rules, with a policy given as a closure: position and rate of the cable
/// in the image, lost outside [-0.5, 0.5], 200-step episodes, resets from a cheap pseudo-random cycle.
fn closed_loop(steps: usize, mut act: impl FnMut([f64; 2], StepStatus) -> f64) -> (f64, u64) {
    let mut x = [0.3_f64, 0.0];
    let mut t = 0;
    let mut seed = 0x2545_f491_4f6c_dd1d_u64;
    let mut episodes = 0;
    let start = Instant::now();
    for _ in 0..steps {
        let kind = if x[0].abs() >= 0.5 {
            StepStatus::Lost
        } else if t == 200 {
            StepStatus::TimeLimit
        } else {
            StepStatus::Running
        };
        let u = act(x, kind);
        if kind == StepStatus::Running {
            x = [x[0] + 0.2 * x[1], (0.95 * x[1] + 0.03 * u).clamp(-0.5, 0.5)];
            t += 1;
        } else {
            episodes += 1;
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            x = [((seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 0.7, 0.0];
            t = 0;
        }
    }
    (start.elapsed().as_secs_f64(), episodes)
}

fn main() -> std::process::ExitCode {
    // Output stops quietly when its reader goes away (`cargo bench ... | head -1`).
    match run() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => cli::fail("agent_step", &e),
    }
}

fn run() -> std::io::Result<()> {
    let steps: usize = std::env::var("AGENT_BENCH_STEPS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(4_000_000);
    let (plant, _) = closed_loop(steps, |x, _| black_box(-x[0] - 0.5 * x[1]));
    cli::outln!(
        "plant and loop alone: {:.1} ns/step",
        plant * 1e9 / steps as f64
    )?;
    let params = LearningParams::default();
    for algorithm in Algorithm::ALL {
        let mut agent = Agent::new(
            Dof::Sway,
            algorithm,
            &params,
            Rewards::default().sway,
            [0.5, 0.5],
            1,
        );
        let (secs, episodes) = closed_loop(steps, |x, kind| agent.step(x, kind).action);
        cli::outln!(
            "{algorithm:>6}: {:.1} ns/step with the plant, {:.1} ns/step for the agent ({steps} steps, {episodes} episodes, \
             {} actor updates, gain {:?})",
            secs * 1e9 / steps as f64,
            (secs - plant) * 1e9 / steps as f64,
            agent.learner().actor_updates(),
            agent.gain(),
        )?;
    }
    Ok(())
}
