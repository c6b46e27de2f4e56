//! The step-two benchmark: over many seeds, step one in simulation, then step two on a twin in one
//! process (`TwinWorld`, the vehicle mesh's algorithm), measured by the evaluation protocol against
//! the simulation policy and the twin's limit.
//!
//! Per seed: step one is the trainer's `sim_episodes` episodes with ideal perception (the simulation
//! policy); step two is a learning session of `trials` learning trials on the twin with the seed
//! (its evaluations are the protocol's, on the seed's evaluation set: the simulation policy before
//! the first learning trial, then after every `evaluation.learning_trials`). Besides, the policy
//! after every learning trial is evaluated on the same set (a measurement only: the session does not
//! see it), which gives the trials needed to close half the gap; the twin's limit is evaluated on
//! the same set; and the simulation policy and the final one are evaluated on `held_out` other sets,
//! whose spread is the evaluation's noise.

use crate::Perceiver;
use crate::evaluation::{Evaluation, evaluate, gap_closed, policy_checkpoint, spread};
use crate::experiment::parallel_map;
use crate::progress::Progress;
use crate::twin_world::{FromCheckpointError, Mode, TrialResult, TwinWorld};
use crate::world::World;
use config::{Dof, Eyes, LearningParams, PerDof, Scenario, TwinParams, derive_seed};
use learning::{Algorithm, Checkpoint};
use serde::{Deserialize, Serialize};

/// What the benchmark runs.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BenchParams {
    pub seeds: Vec<u64>,
    /// Learning trials of step two.
    pub trials: u32,
    /// Episodes of step one.
    pub sim_episodes: usize,
    pub eyes: Eyes,
    /// Independent evaluation sets for the noise (0: none).
    pub held_out: u32,
    /// Evaluate the policy after every learning trial (for the trials to half the gap).
    pub every_trial: bool,
}

/// One point of an evaluation curve: the policy after `learning_trials` learning trials.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CurvePoint {
    pub learning_trials: u32,
    /// Its evaluated return.
    pub evaluated: PerDof<f64>,
    /// The evaluated return of the policy in force after the evaluation (the best one where it was
    /// restored), and where it was.
    pub in_force: PerDof<f64>,
    pub rolled_back: PerDof<bool>,
}

/// One seed's step two.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SeedResult {
    pub seed: u64,
    pub sim_gains: PerDof<[f64; 2]>,
    pub after_gains: PerDof<[f64; 2]>,
    /// The session's own evaluations (the protocol), before learning and after every few trials.
    pub curve: Vec<CurvePoint>,
    /// The policy after every learning trial, evaluated on the same set (a measurement).
    pub every_trial: Vec<CurvePoint>,
    pub sim: PerDof<f64>,
    pub after: PerDof<f64>,
    pub limit: PerDof<f64>,
    pub gap_closed: PerDof<f64>,
    /// The first learning trial after which the policy closed half the gap.
    pub trials_to_half: PerDof<Option<u32>>,
    /// Trials (learning and evaluation) of the session, and those that lost the cable.
    pub session_trials: u32,
    pub lost: u32,
    pub rollbacks: PerDof<u64>,
    pub refused: PerDof<u64>,
    pub bounded: PerDof<u64>,
    /// On the held-out sets: the simulation policy's and the final policy's evaluated returns.
    pub held_out_sim: PerDof<Vec<f64>>,
    pub held_out_after: PerDof<Vec<f64>>,
}

impl SeedResult {
    /// The spread of `after - sim` over the held-out sets: the evaluation's noise on the
    /// improvement.
    pub fn difference_noise(&self, dof: Dof) -> f64 {
        let d: Vec<f64> = self
            .held_out_after
            .get(dof)
            .iter()
            .zip(self.held_out_sim.get(dof))
            .map(|(a, s)| a - s)
            .collect();
        spread(&d)
    }
}

/// Step one: the trainer's episodes with ideal perception, as the checkpoint step two loads.
pub fn step_one(
    scenario: &Scenario,
    learning: &LearningParams,
    episodes: usize,
    seed: u64,
) -> Checkpoint {
    let eyes = Perceiver::Ideal(scenario.observation.clone());
    let mut world = World::new(scenario, learning, Algorithm::Nac, eyes, seed);
    for _ in 0..episodes {
        world.run_episode();
    }
    let agents = world.into_agents();
    let mut c = Checkpoint::single(agents.sway.checkpoint());
    c.insert(agents.yaw.checkpoint());
    c
}

fn gains(c: &Checkpoint) -> PerDof<[f64; 2]> {
    let g = |dof| c.get(dof).map_or([f64::NAN; 2], |s| s.policy.gain);
    PerDof {
        sway: g(Dof::Sway),
        yaw: g(Dof::Yaw),
    }
}

/// A session's learning and evaluation trials: the curve of its evaluations.
pub fn curve(trials: &[TrialResult]) -> Vec<CurvePoint> {
    let mut learned = 0;
    let mut points = Vec::new();
    for t in trials {
        if !t.evaluation {
            learned += 1;
        }
        if t.evaluated.sway.is_finite() || t.evaluated.yaw.is_finite() {
            points.push(CurvePoint {
                learning_trials: learned,
                evaluated: t.evaluated,
                in_force: t.in_force(),
                rolled_back: t.rolled_back,
            });
        }
    }
    points
}

/// Runs one seed (see the module docs); `limit` is the twin's limit policy.
#[allow(clippy::too_many_arguments)]
pub fn run_seed(
    scenario: &Scenario,
    learning: &LearningParams,
    twin: &TwinParams,
    limit: &Checkpoint,
    params: &BenchParams,
    seed: u64,
) -> Result<SeedResult, FromCheckpointError> {
    let sim = step_one(scenario, learning, params.sim_episodes, seed);
    let e = learning.evaluation.trials;
    let session = behaviour::session_trials(&learning.evaluation, params.trials);
    let mut world =
        TwinWorld::from_checkpoint(scenario, twin, &sim, params.eyes, seed, Mode::Learn)?;
    let mut run = Vec::new();
    let mut every_trial = Vec::new();
    let mut learned = 0;
    for _ in 0..session {
        let r = world.run_trial();
        if !r.evaluation {
            learned += 1;
            if params.every_trial {
                let c = policy_checkpoint(scenario, learning, r.gains);
                let ev = evaluate(scenario, twin, params.eyes, &c, seed, e)?;
                every_trial.push(CurvePoint {
                    learning_trials: learned,
                    evaluated: ev.mean(),
                    in_force: ev.mean(),
                    rolled_back: PerDof::default(),
                });
            }
        }
        run.push(r);
    }
    let curve = curve(&run);
    let first = curve.first().map(|p| p.in_force);
    let last = curve.last().map(|p| p.in_force);
    let (Some(j_sim), Some(j_after)) = (first, last) else {
        panic!("a session of {session} trials evaluates at least twice (evaluation.trials = {e})");
    };
    let final_gains = run.last().expect("one trial at least").gains;
    let j_limit = evaluate(scenario, twin, params.eyes, limit, seed, e)?.mean();
    let closed = |dof: Dof| gap_closed(*j_sim.get(dof), *j_after.get(dof), *j_limit.get(dof));
    let to_half = |dof: Dof| {
        let half = |p: &CurvePoint| {
            gap_closed(*j_sim.get(dof), *p.in_force.get(dof), *j_limit.get(dof)) >= 0.5
        };
        let points = if every_trial.is_empty() {
            &curve
        } else {
            &every_trial
        };
        points.iter().find(|p| half(p)).map(|p| p.learning_trials)
    };
    let after_checkpoint = policy_checkpoint(scenario, learning, final_gains);
    let mut held_sim: PerDof<Vec<f64>> = PerDof::default();
    let mut held_after: PerDof<Vec<f64>> = PerDof::default();
    for h in 0..params.held_out {
        let set = derive_seed(seed, &format!("held-out/{h}"));
        let s = evaluate(scenario, twin, params.eyes, &sim, set, e)?.mean();
        let a = evaluate(scenario, twin, params.eyes, &after_checkpoint, set, e)?.mean();
        for dof in Dof::ALL {
            held_sim.get_mut(dof).push(*s.get(dof));
            held_after.get_mut(dof).push(*a.get(dof));
        }
    }
    let last_trial = run.last().expect("one trial at least");
    let trials_to_half = PerDof {
        sway: to_half(Dof::Sway),
        yaw: to_half(Dof::Yaw),
    };
    Ok(SeedResult {
        seed,
        sim_gains: gains(&sim),
        after_gains: final_gains,
        curve,
        every_trial,
        sim: j_sim,
        after: j_after,
        limit: j_limit,
        gap_closed: PerDof {
            sway: closed(Dof::Sway),
            yaw: closed(Dof::Yaw),
        },
        trials_to_half,
        session_trials: session,
        lost: run.iter().filter(|t| t.lost).count() as u32,
        rollbacks: last_trial.rollbacks,
        refused: last_trial.refused,
        bounded: last_trial.bounded,
        held_out_sim: held_sim,
        held_out_after: held_after,
    })
}

/// Runs every seed, spread over the cores.
pub fn run(
    scenario: &Scenario,
    learning: &LearningParams,
    twin: &TwinParams,
    limit: &Checkpoint,
    params: &BenchParams,
    progress: &Progress,
) -> Result<Vec<SeedResult>, FromCheckpointError> {
    parallel_map(params.seeds.len(), progress, |i| {
        run_seed(scenario, learning, twin, limit, params, params.seeds[i])
    })
    .into_iter()
    .collect()
}

/// An evaluation, for the JSON of a command.
pub fn evaluation_json(e: &Evaluation) -> serde_json::Value {
    serde_json::json!({
        "seed": e.seed,
        "trials": e.trials,
        "returns": e.returns,
        "mean": e.mean(),
        "lost": e.lost,
    })
}

/// The benchmark's verdict over the seeds, per DOF.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DofSummary {
    /// The gap (J_limit - J_sim) relative to |J_sim|: median over seeds.
    pub median_gap: f64,
    pub median_gap_closed: f64,
    pub min_gap_closed: f64,
    /// The median over seeds of the trials to close half the gap (a seed that never did counts as
    /// more than the session's trials; `None` when half the seeds never did).
    pub median_trials_to_half: Option<f64>,
    /// Seeds whose final policy is worse than the simulation policy (on their evaluation set), and
    /// those worse by more than twice the evaluation's noise on the difference.
    pub seeds_worse: usize,
    pub seeds_worse_beyond_noise: usize,
    /// The evaluation's noise on a difference (the median over seeds of the spread of
    /// `after - sim` over the held-out sets).
    pub difference_noise: f64,
    /// The mean improvement `after - sim` on the held-out sets, median over seeds.
    pub median_held_out_improvement: f64,
}

/// The benchmark's verdict.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    pub seeds: usize,
    pub yaw: DofSummary,
    pub sway: DofSummary,
    /// Trials (learning and evaluation) that lost the cable, over all seeds.
    pub lost: u32,
    pub trials: u32,
}

fn dof_summary(results: &[SeedResult], dof: Dof, learning_trials: u32) -> DofSummary {
    let closed: Vec<f64> = results.iter().map(|r| *r.gap_closed.get(dof)).collect();
    let noise = stats::median(results.iter().map(|r| r.difference_noise(dof)));
    let worse = |r: &SeedResult, margin: f64| {
        *r.after.get(dof) < *r.sim.get(dof) - if margin.is_finite() { margin } else { 0.0 }
    };
    let halves: Vec<f64> = results
        .iter()
        .map(|r| {
            r.trials_to_half
                .get(dof)
                .map_or(f64::INFINITY, |t| t as f64)
        })
        .collect();
    let median_half = stats::median(halves.iter().copied());
    DofSummary {
        median_gap: stats::median(
            results
                .iter()
                .map(|r| (*r.limit.get(dof) - *r.sim.get(dof)) / r.sim.get(dof).abs()),
        ),
        median_gap_closed: stats::median(closed.iter().copied()),
        min_gap_closed: closed.iter().copied().fold(f64::INFINITY, f64::min),
        median_trials_to_half: (median_half <= learning_trials as f64).then_some(median_half),
        seeds_worse: results.iter().filter(|r| worse(r, 0.0)).count(),
        seeds_worse_beyond_noise: results
            .iter()
            .filter(|r| worse(r, 2.0 * r.difference_noise(dof)))
            .count(),
        difference_noise: noise,
        median_held_out_improvement: stats::median(results.iter().map(|r| {
            stats::mean(
                r.held_out_after
                    .get(dof)
                    .iter()
                    .zip(r.held_out_sim.get(dof))
                    .map(|(a, s)| a - s),
            )
        })),
    }
}

/// The verdict over `results`.
pub fn summary(results: &[SeedResult]) -> Summary {
    let learning_trials = results
        .first()
        .and_then(|r| r.curve.last())
        .map_or(0, |p| p.learning_trials);
    Summary {
        seeds: results.len(),
        yaw: dof_summary(results, Dof::Yaw, learning_trials),
        sway: dof_summary(results, Dof::Sway, learning_trials),
        lost: results.iter().map(|r| r.lost).sum(),
        trials: results.iter().map(|r| r.session_trials).sum(),
    }
}

/// The benchmark's table (Markdown) and its verdict.
pub fn table(results: &[SeedResult], params: &BenchParams) -> String {
    use std::fmt::Write as _;
    let mut t = String::new();
    let pct = |v: f64| format!("{:.0}%", 100.0 * v);
    let half = |v: Option<u32>| v.map_or("–".to_owned(), |v| v.to_string());
    let _ = writeln!(
        t,
        "| seed | yaw: sim | after | limit | closed | sway: sim | after | limit | closed | half (yaw, sway) | rollbacks | refused | lost |"
    );
    let _ = writeln!(
        t,
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
    );
    for r in results {
        let _ = writeln!(
            t,
            "| {} | {:.3} | {:.3} | {:.3} | {} | {:.4} | {:.4} | {:.4} | {} | {}, {} | {}, {} | {}, {} | {} |",
            r.seed,
            r.sim.yaw,
            r.after.yaw,
            r.limit.yaw,
            pct(r.gap_closed.yaw),
            r.sim.sway,
            r.after.sway,
            r.limit.sway,
            pct(r.gap_closed.sway),
            half(r.trials_to_half.yaw),
            half(r.trials_to_half.sway),
            r.rollbacks.yaw,
            r.rollbacks.sway,
            r.refused.yaw,
            r.refused.sway,
            r.lost
        );
    }
    let s = summary(results);
    let _ = writeln!(
        t,
        "\n{} seeds, {} learning trials each ({} trials a session with the evaluations), {} perception:",
        s.seeds,
        params.trials,
        results.first().map_or(0, |r| r.session_trials),
        params.eyes
    );
    for (dof, d) in [(Dof::Yaw, &s.yaw), (Dof::Sway, &s.sway)] {
        let _ = writeln!(
            t,
            "{dof:>4}: gap (J_limit - J_sim)/|J_sim| median {}; gap closed median {}, worst {}; trials to half the gap median {}; \
             worse than the simulation policy: {} seeds, beyond twice the evaluation's noise ({:.4}): {}; held-out improvement median {:+.4}",
            pct(d.median_gap),
            pct(d.median_gap_closed),
            pct(d.min_gap_closed),
            d.median_trials_to_half
                .map_or("> the session".to_owned(), |v| format!("{v}")),
            d.seeds_worse,
            d.difference_noise,
            d.seeds_worse_beyond_noise,
            d.median_held_out_improvement
        );
    }
    let _ = writeln!(t, "cable lost in {} of {} trials", s.lost, s.trials);
    t
}
