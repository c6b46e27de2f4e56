//! Step two's evaluation protocol, in one process: a policy acts, without learning, over a fixed
//! set of starts with fixed noise streams, exactly as the vehicle mesh's behaviours do with
//! `--step-two --act-only` (and as they do in the evaluation trials of a learning session).
//!
//! **The evaluation set** of a seed is the twin seeded with it (`supervisor --seed`): its first
//! `trials` start marks (`trials.cycle` of the twin, one round of them), the twin's frame noise of
//! each mark (image noise, dropped frames: drawn per mark), and the behaviours' exploration noise of
//! each evaluation slot (stream `evaluation/j` of the DOF's stream). Evaluating two policies on one
//! set gives returns that differ by the policies only (common random numbers), so the simulation
//! policy, the policy after every few trials of step two and the twin's limit compare.
//!
//! **The evaluation's noise** is how much its mean return moves with the set: measured by
//! evaluating one policy on independent sets (other seeds) and taking the spread of the means
//! ([`spread`]); the spread of a *difference* between two policies, each set evaluating both, is the
//! noise against which "better" and "worse" are judged.

use crate::twin_world::{FromCheckpointError, Mode, TrialResult, TwinWorld};
use config::{Dof, Eyes, LearningParams, PerDof, Scenario, TwinParams};
use learning::{Algorithm, Checkpoint, CheckpointError};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// What an evaluation gave: each trial's returns, and whether the cable was lost.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Evaluation {
    /// The evaluation set's seed.
    pub seed: u64,
    pub trials: u32,
    /// Each trial's return, per DOF.
    pub returns: PerDof<Vec<f64>>,
    /// Trials in which the cable was lost.
    pub lost: u32,
}

impl Evaluation {
    /// The evaluated return: the mean over the trials, per DOF.
    pub fn mean(&self) -> PerDof<f64> {
        PerDof {
            sway: stats::mean(self.returns.sway.iter().copied()),
            yaw: stats::mean(self.returns.yaw.iter().copied()),
        }
    }

    /// The evaluation of a run's trials.
    pub fn of(seed: u64, trials: &[TrialResult]) -> Self {
        Evaluation {
            seed,
            trials: trials.len() as u32,
            returns: PerDof {
                sway: trials.iter().map(|t| t.returns.sway).collect(),
                yaw: trials.iter().map(|t| t.returns.yaw).collect(),
            },
            lost: trials.iter().filter(|t| t.lost).count() as u32,
        }
    }
}

/// A checkpoint of fresh agents (nothing learned) with the policy gains `gains` and the learning
/// parameters `learning`: a fixed policy to evaluate, or to load with `--initial`.
pub fn policy_checkpoint(
    scenario: &Scenario,
    learning: &LearningParams,
    gains: PerDof<[f64; 2]>,
) -> Checkpoint {
    let mut params = learning.clone();
    params.policy.initial_gain = gains;
    let agent = |dof: Dof| behaviour::new_agent(dof, Algorithm::Nac, scenario, &params, 0);
    let mut c = Checkpoint::single(agent(Dof::Sway).checkpoint());
    c.insert(agent(Dof::Yaw).checkpoint());
    c
}

/// The policies of `checkpoint`, evaluated on the evaluation set of `seed`: `trials` trials on the
/// twin `twin`, the behaviours acting with `--step-two --act-only`.
pub fn evaluate(
    scenario: &Scenario,
    twin: &TwinParams,
    eyes: Eyes,
    checkpoint: &Checkpoint,
    seed: u64,
    trials: u32,
) -> Result<Evaluation, FromCheckpointError> {
    let mut world = TwinWorld::from_checkpoint(scenario, twin, checkpoint, eyes, seed, Mode::Act)?;
    let run: Vec<TrialResult> = (0..trials).map(|_| world.run_trial()).collect();
    Ok(Evaluation::of(seed, &run))
}

/// A policy directory as the behaviours load it (`DIR/sway.ckpt`, `DIR/yaw.ckpt`, each with its
/// DOF's state), as one checkpoint.
pub fn load_policies(dir: &Path) -> Result<Checkpoint, CheckpointError> {
    let mut c = Checkpoint::single(Checkpoint::load_dof(&dir.join("sway.ckpt"), Dof::Sway)?);
    c.insert(Checkpoint::load_dof(&dir.join("yaw.ckpt"), Dof::Yaw)?);
    Ok(c)
}

/// Writes `checkpoint`'s policies as a directory the behaviours load with `--initial DIR/sway.ckpt`
/// and `--initial DIR/yaw.ckpt` (created if needed).
pub fn save_policies(dir: &Path, checkpoint: &Checkpoint) -> Result<(), CheckpointError> {
    std::fs::create_dir_all(dir).map_err(|source| CheckpointError::Io {
        path: dir.to_owned(),
        action: "create the directory of",
        source,
    })?;
    for dof in Dof::ALL {
        if let Some(state) = checkpoint.get(dof) {
            Checkpoint::single(state.clone()).save(&dir.join(format!("{dof}.ckpt")))?;
        }
    }
    Ok(())
}

/// The share of the gap between the simulation policy and the twin's limit that step two closed:
/// `(J_after - J_sim) / (J_limit - J_sim)`; 1 reaches the limit, 0 is the simulation policy,
/// negative is worse than it.
pub fn gap_closed(sim: f64, after: f64, limit: f64) -> f64 {
    (after - sim) / (limit - sim)
}

/// The spread (standard deviation, over the sets) of `f` evaluated on several evaluation sets.
pub fn spread(values: &[f64]) -> f64 {
    let m = stats::mean(values.iter().copied());
    let n = values.len();
    if n < 2 {
        return f64::NAN;
    }
    (values.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_gap_closed_is_the_share_of_the_way_to_the_limit() {
        assert_eq!(gap_closed(-10.0, -10.0, -6.0), 0.0);
        assert_eq!(gap_closed(-10.0, -6.0, -6.0), 1.0);
        assert_eq!(gap_closed(-10.0, -8.0, -6.0), 0.5);
        assert!(gap_closed(-10.0, -11.0, -6.0) < 0.0);
        assert!((spread(&[1.0, 2.0, 3.0]) - 1.0).abs() < 1e-12);
        assert!(spread(&[1.0]).is_nan());
    }

    /// One policy on one set: the same returns every time; on another set, other returns.
    #[test]
    fn an_evaluation_is_repeatable_and_a_set_is_its_seed() {
        let s = Scenario::default();
        let mut twin = TwinParams::default();
        twin.trials.duration_s = 20.0;
        let learning = LearningParams::default();
        let c = policy_checkpoint(
            &s,
            &learning,
            PerDof {
                sway: [4.0, 6.0],
                yaw: [9.0, 3.0],
            },
        );
        let e = |seed| evaluate(&s, &twin, Eyes::Ideal, &c, seed, 5).unwrap();
        let (a, b, other) = (e(3), e(3), e(4));
        assert_eq!(a, b);
        assert_ne!(a.returns, other.returns);
        assert_eq!((a.trials, a.returns.yaw.len()), (5, 5));
        assert!(a.mean().yaw < 0.0 && a.mean().sway < 0.0);
    }
}
