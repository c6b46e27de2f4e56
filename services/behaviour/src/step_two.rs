//! Step two in the behaviour: learning on the vehicle under the safety layer of `learning.toml`.
//!
//! - **Trials alternate** ([`trial_kind`]): an evaluation (`evaluation.trials` trials in which the
//!   policy acts without learning), then `evaluation.learning_trials` learning trials, and so on,
//!   beginning with an evaluation of the policy the behaviour was given. The vehicle numbers the
//!   trials (the stamp's episode), so both behaviours, and a behaviour restarted mid-session, agree on
//!   which trial is which. A behaviour that only acts evaluates in every trial.
//! - **Evaluations compare**: evaluation trial `j` (its slot) draws the exploration noise of stream
//!   `j` in every evaluation, and starts from the vehicle's `j`-th start mark when an evaluation is
//!   one round of the marks (the twin's `trials.cycle` equals `evaluation.trials`, and the period
//!   `trials + learning_trials` is a multiple of it). Two evaluations then differ by the policies
//!   only. A learning trial draws the noise of its own stream (its number), so no two learning
//!   trials share theirs.
//! - **Every actor update** passes the trust region and the stability guard ([`guard`]).
//! - **Keep the best pair**: at the end of each evaluation the pair of policies (sway's and yaw's)
//!   is judged against the best pair so far ([`learning::KeepBest`]); a pair worse by more than the
//!   tolerance is replaced by the best. A DOF's return depends on the other DOF's policy, so the two
//!   behaviours judge the pair, not each its own return: each sums the pair's cost (both DOFs' state
//!   costs, [`learning::state_costs`]) over the evaluation's observations, which both get alike, and
//!   both apply the same rule to the same numbers, so they keep, and restore, the policies of one
//!   and the same evaluation. Nothing passes between them and nothing waits: a partner that only
//!   acts, is absent or is restarting changes nothing in the judging (its DOF is observed whatever
//!   steers it). The best pair, the weights of its score and the evaluation in progress are in the
//!   checkpoint, which the shell saves after every judged evaluation: a behaviour restarted between
//!   evaluations judges on as if it had not stopped. One restarted within an evaluation misses some
//!   of its trials and does not judge it (its partner does): the two bests may then differ until an
//!   evaluation both judge beats both, which the behaviours' logs show (`best_trial`).
//! - **A lost cable is a failed policy**: a trial that loses the cable restores the best policy at
//!   once, and an evaluation in which it was lost never makes its policy the best. In a learning
//!   trial, the DOF's observed position leaving the [`SAFETY_ENVELOPE`] (the learned policy heading
//!   for the image's edge) restores the best at once, and the trial goes on with it without learning:
//!   the recovery happens before the cable is lost, not after.

use config::{Dof, EvaluationParams, LearningParams, Scenario, derive_seed};
use learning::lqr::{DiscreteSystem, LqrError, discretize_zoh};
use learning::{KeepBest, StableSet, TrustRegion, UpdateGuard};

/// The safety envelope of a learning trial, as a fraction of the DOF's observation box: sway's x_g
/// beyond 0.4 of the image's width from the centre (the cable leaves the image near 0.5), yaw's Theta
/// beyond 72 degrees. The twin's starts lie within 0.35 and 45 degrees, so a trial begins inside it;
/// in step two's benchmark (12 seeds on the default and the harsh twin, each with the current along
/// and across the cable) only the one learning trial that would have lost the cable left it.
pub const SAFETY_ENVELOPE: f64 = 0.8;

/// What a trial is for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TrialKind {
    /// The policy learns.
    Learning,
    /// Evaluation trial `slot` (from 0) of an evaluation: the policy acts without learning.
    Evaluation { slot: u32 },
}

impl TrialKind {
    pub fn is_evaluation(self) -> bool {
        matches!(self, TrialKind::Evaluation { .. })
    }
}

/// The kind of trial `trial` (numbered by the vehicle from 0) for a behaviour that learns
/// (`learning`) or only acts.
pub fn trial_kind(evaluation: &EvaluationParams, learning: bool, trial: u32) -> TrialKind {
    let e = evaluation.trials;
    if e == 0 {
        return TrialKind::Learning;
    }
    if !learning {
        return TrialKind::Evaluation { slot: trial % e };
    }
    let r = trial % (e + evaluation.learning_trials);
    if r < e {
        TrialKind::Evaluation { slot: r }
    } else {
        TrialKind::Learning
    }
}

/// The trials that close an evaluation, among the first `trials` trials of a learning session: the
/// policy evaluated there is the one learned in the learning trials before.
pub fn evaluation_ends(evaluation: &EvaluationParams, trials: u32) -> Vec<u32> {
    (0..trials)
        .filter(|&t| {
            trial_kind(evaluation, true, t)
                == TrialKind::Evaluation {
                    slot: evaluation.trials.saturating_sub(1),
                }
        })
        .collect()
}

/// The number of trials a learning session needs for `learning_trials` learning trials with an
/// evaluation before the first and after every `evaluation.learning_trials` (and after the last).
pub fn session_trials(evaluation: &EvaluationParams, learning_trials: u32) -> u32 {
    let k = evaluation.learning_trials.max(1);
    let evaluations = learning_trials.div_ceil(k) + 1;
    learning_trials + evaluation.trials * evaluations
}

/// The identified linear model of `dof` (paper Table I, the decoupled (position, rate) dynamics of
/// its observation, under the commands the stack gives: `Scenario::commanded_model`), discretised
/// exactly at the sample time: what the stability guard and the LQR yardstick know of the vehicle.
pub fn identified_model(scenario: &Scenario, dof: Dof) -> Result<DiscreteSystem<2, 1>, LqrError> {
    let commanded = scenario.commanded_model();
    let lin = match dof {
        Dof::Sway => model::linear::sway(&commanded, &model::Camera::new(&scenario.camera)),
        Dof::Yaw => model::linear::yaw(&commanded),
    };
    discretize_zoh(&lin.a, &lin.b, scenario.timing.sample_time_s)
}

/// The guard every actor update of `dof` passes under `params.safety` (inactive parts left out).
pub fn guard(
    scenario: &Scenario,
    params: &LearningParams,
    dof: Dof,
) -> Result<UpdateGuard, LqrError> {
    let safety = &params.safety;
    Ok(UpdateGuard {
        trust_region: safety
            .trust_region
            .enabled
            .then(|| TrustRegion::new(&safety.trust_region, scenario.state_max(dof))),
        stable_set: if safety.stability.enabled {
            Some(StableSet::new(
                identified_model(scenario, dof)?,
                &safety.stability,
            ))
        } else {
            None
        },
    })
}

/// How a behaviour runs step two.
#[derive(Clone, Debug, PartialEq)]
pub struct StepTwo {
    pub evaluation: EvaluationParams,
    pub keep_best: KeepBest,
    /// Whether the behaviour learns at all (`false`: it only acts, and every trial evaluates).
    pub learning: bool,
    /// The exploration noise of evaluation slot `j` is stream `evaluation/j` of this seed.
    pub evaluation_seed: u64,
    /// The exploration noise of learning trial `t` is stream `trial/t` of this seed.
    pub learning_seed: u64,
}

impl StepTwo {
    /// Step two with the evaluations and the rollback of `params`.
    pub fn new(
        params: &LearningParams,
        learning: bool,
        evaluation_seed: u64,
        learning_seed: u64,
    ) -> Self {
        let rollback = &params.safety.rollback;
        StepTwo {
            evaluation: params.evaluation.clone(),
            keep_best: KeepBest::new(rollback.enabled.then_some(rollback.tolerance)),
            learning,
            evaluation_seed,
            learning_seed,
        }
    }

    pub fn kind(&self, trial: u32) -> TrialKind {
        trial_kind(&self.evaluation, self.learning, trial)
    }

    /// The exploration seed of a trial of kind `kind`.
    pub fn noise_seed(&self, trial: u32, kind: TrialKind) -> u64 {
        match kind {
            TrialKind::Evaluation { slot } => {
                derive_seed(self.evaluation_seed, &format!("evaluation/{slot}"))
            }
            TrialKind::Learning => derive_seed(self.learning_seed, &format!("trial/{trial}")),
        }
    }

    /// Whether evaluation slot `slot` closes an evaluation that is judged (a learning behaviour
    /// judges; one that only acts has nothing to keep or restore).
    pub fn closes(&self, slot: u32) -> bool {
        self.learning && slot + 1 == self.evaluation.trials
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn every(trials: u32, learning_trials: u32) -> EvaluationParams {
        EvaluationParams {
            trials,
            learning_trials,
        }
    }

    #[test]
    fn an_evaluation_comes_first_then_every_k_learning_trials() {
        let e = every(2, 3);
        let kinds: Vec<_> = (0..11).map(|t| trial_kind(&e, true, t)).collect();
        use TrialKind::*;
        assert_eq!(
            kinds,
            vec![
                Evaluation { slot: 0 },
                Evaluation { slot: 1 },
                Learning,
                Learning,
                Learning,
                Evaluation { slot: 0 },
                Evaluation { slot: 1 },
                Learning,
                Learning,
                Learning,
                Evaluation { slot: 0 },
            ]
        );
        assert_eq!(evaluation_ends(&e, 11), vec![1, 6]);
        // 6 learning trials: evaluations before, after 3 and after 6.
        assert_eq!(session_trials(&e, 6), 6 + 2 * 3);
        assert_eq!(session_trials(&every(5, 5), 20), 45);
        // Acting only, every trial evaluates; without evaluations, every trial learns.
        assert_eq!(trial_kind(&e, false, 7), Evaluation { slot: 1 });
        assert_eq!(trial_kind(&every(0, 3), true, 0), Learning);
    }

    #[test]
    fn each_slot_has_its_noise_and_each_learning_trial_its_own() {
        let s = StepTwo::new(&LearningParams::default(), true, 11, 12);
        let e = s.evaluation.trials;
        let p = e + s.evaluation.learning_trials;
        let seed = |t| s.noise_seed(t, s.kind(t));
        assert_eq!(seed(0), seed(p));
        assert_eq!(seed(1), seed(p + 1));
        assert_ne!(seed(0), seed(1));
        assert_ne!(seed(e), seed(e + 1), "learning trials");
        assert_ne!(seed(e), seed(p + e));
        assert!(s.closes(e - 1) && !s.closes(0));
        assert!(!StepTwo::new(&LearningParams::default(), false, 1, 1).closes(e - 1));
    }
}
