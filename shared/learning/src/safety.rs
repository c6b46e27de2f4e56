//! Safe policy improvement on the vehicle (step two): what may change the policy, and when a change
//! is taken back. Three independent parts, each switched in `learning.toml` (`[safety]`):
//!
//! - [`TrustRegion`]: each actor update may change the mean action by at most `max_action_change`
//!   anywhere in the observation box; a longer natural-gradient step is shortened along its
//!   direction (a step bound in the spirit of TRPO's KL constraint, here on the largest KL over the
//!   box, which for a fixed sigma is `max_action_change^2 / (2 sigma^2)`).
//! - [`StableSet`]: a gain is admissible when the identified linear model of the DOF, discretised at
//!   the sample time, closed with that gain times a gain margin and with extra periods of delay, has
//!   a spectral radius of at most `max_radius` (a stability-constrained update: the learner may not
//!   step where the model, with a robustness margin, says the loop oscillates or diverges). A gain
//!   already outside (a simulation policy can be) may only move towards the set.
//! - [`KeepBest`]: after every evaluation the policy's evaluated return is compared with the best
//!   so far; worse by more than a tolerance, the best policy is restored (a conservative rollback to
//!   the best known baseline, as safe policy improvement with a baseline does). A policy under which
//!   the cable was lost has failed whatever its return: the best is restored at once (a trial that
//!   loses the cable ends early, which can cost a DOF less than tracking badly for the whole trial,
//!   so the return alone would rank such a policy above a safe one), and the best is always a policy
//!   whose evaluation kept the cable in every trial.
//!
//! [`UpdateGuard`] applies the first two to each actor update; [`SafetyState`] is what a checkpoint
//! keeps of all three (counts and the best policy), so a restarted behaviour goes on where it was.

use crate::lqr::DiscreteSystem;
use config::{StabilityParams, TrustRegionParams};
use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

/// The trust region on each actor update (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrustRegion {
    max_action_change: f64,
    state_max: [f64; 2],
}

impl TrustRegion {
    /// A trust region of `params` over the observation box `|x_i| <= state_max[i]`.
    pub fn new(params: &TrustRegionParams, state_max: [f64; 2]) -> Self {
        TrustRegion {
            max_action_change: params.max_action_change,
            state_max,
        }
    }

    /// The largest change of the mean action over the box that a gain step `dk` makes.
    pub fn action_change(&self, dk: [f64; 2]) -> f64 {
        dk[0].abs() * self.state_max[0] + dk[1].abs() * self.state_max[1]
    }

    /// `dk` shortened along its direction to the region's edge when it reaches beyond; `true` when
    /// it was shortened.
    pub fn bound(&self, dk: [f64; 2]) -> ([f64; 2], bool) {
        let change = self.action_change(dk);
        if change <= self.max_action_change || !change.is_finite() {
            return (dk, false);
        }
        let s = self.max_action_change / change;
        ([dk[0] * s, dk[1] * s], true)
    }
}

/// The set of gains the identified model says are stable with a margin (see the module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct StableSet {
    system: DiscreteSystem<2, 1>,
    gain_margin: f64,
    delay: usize,
    max_radius: f64,
}

impl StableSet {
    /// The stable set of `params` for the DOF's discretised linear model `system` (state (position,
    /// rate), input the normalised force).
    pub fn new(system: DiscreteSystem<2, 1>, params: &StabilityParams) -> Self {
        StableSet {
            system,
            gain_margin: params.gain_margin,
            delay: params.delay_frames as usize,
            max_radius: params.max_radius,
        }
    }

    /// The spectral radius of the closed loop `x' = A x + B (margin K) x_{t - delay}`: the largest
    /// magnitude of its eigenvalues (infinite for a non-finite gain).
    pub fn radius(&self, k: [f64; 2]) -> f64 {
        if !(k[0].is_finite() && k[1].is_finite()) {
            return f64::INFINITY;
        }
        let d = self.delay;
        let n = 2 * (d + 1);
        // The state [x_t; x_{t-1}; ...; x_{t-d}]: the newest two rows are the model, the others
        // shift the history down.
        let mut m = DMatrix::<f64>::zeros(n, n);
        let (a, b) = (&self.system.a, &self.system.b);
        for i in 0..2 {
            for j in 0..2 {
                m[(i, j)] += a[(i, j)];
                m[(i, 2 * d + j)] += b[(i, 0)] * self.gain_margin * k[j];
            }
        }
        for i in 2..n {
            m[(i, i - 2)] = 1.0;
        }
        m.complex_eigenvalues()
            .iter()
            .map(|z| z.norm())
            .fold(0.0, f64::max)
    }

    /// Whether `k` is in the set.
    pub fn contains(&self, k: [f64; 2]) -> bool {
        self.radius(k) <= self.max_radius
    }
}

/// What the guard made of a proposed actor update.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Review {
    /// The update goes through.
    Accepted {
        /// The gain to take: the proposal, or the proposal shortened by the trust region.
        gain: [f64; 2],
        /// The trust region shortened the step.
        bounded: bool,
    },
    /// The gain would leave the stable set (or move further out): the old gain stays.
    Refused {
        /// The proposal (after the trust region).
        proposed: [f64; 2],
        /// Its spectral radius under the margin.
        radius: f64,
    },
}

/// The trust region and the stable set, applied to each actor update.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct UpdateGuard {
    /// The bound on each update's step, if any.
    pub trust_region: Option<TrustRegion>,
    /// The set the gain must stay in, if any.
    pub stable_set: Option<StableSet>,
}

impl UpdateGuard {
    /// Whether the guard checks anything.
    pub fn is_active(&self) -> bool {
        self.trust_region.is_some() || self.stable_set.is_some()
    }

    /// Reviews the actor update from `before` to `proposed`.
    pub fn review(&self, before: [f64; 2], proposed: [f64; 2]) -> Review {
        let (gain, bounded) = match &self.trust_region {
            Some(tr) => {
                let (dk, bounded) = tr.bound([proposed[0] - before[0], proposed[1] - before[1]]);
                ([before[0] + dk[0], before[1] + dk[1]], bounded)
            }
            None => (proposed, false),
        };
        if let Some(set) = &self.stable_set {
            let radius = set.radius(gain);
            let admissible = radius <= set.max_radius || radius < set.radius(before);
            if !admissible {
                return Review::Refused {
                    proposed: gain,
                    radius,
                };
            }
        }
        Review::Accepted { gain, bounded }
    }
}

/// The best policy an evaluation has seen, and its evaluated return.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct BestPolicy {
    /// K for (position, rate).
    pub gain: [f64; 2],
    /// Its evaluated return (the mean over the evaluation's trials).
    pub evaluated: f64,
}

/// What an evaluation decided.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Verdict {
    /// The policy is the best so far (or the first evaluated): it is kept as the best.
    Best,
    /// Not better than the best, but within the tolerance: learning goes on from it.
    Kept {
        /// The best so far.
        best: BestPolicy,
    },
    /// Worse than the best by more than the tolerance: the best is restored.
    RollBack {
        /// The policy to restore.
        best: BestPolicy,
    },
    /// The cable was lost in some trial of the evaluation: the policy is not a candidate for the
    /// best whatever its return, and the best (if one was evaluated, and rollback is on) is
    /// restored.
    Failed {
        /// The policy to restore, if any.
        best: Option<BestPolicy>,
    },
}

/// Keep the best: judges each evaluated policy against the best so far (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KeepBest {
    /// Roll back when worse than the best by more than this fraction of the best's magnitude;
    /// `None`: judge and remember, never roll back.
    tolerance: Option<f64>,
}

impl KeepBest {
    /// A judge that rolls back beyond `tolerance` (a fraction of the best return's magnitude), or
    /// that only keeps account (`None`).
    pub fn new(tolerance: Option<f64>) -> Self {
        KeepBest { tolerance }
    }

    /// Judges `gain`, evaluated at `evaluated`, against the best in `state` (updated: the best, the
    /// counts).
    /// An evaluation in which the cable was lost ([`SafetyState::evaluation_lost`]) is
    /// [`Verdict::Failed`].
    pub fn judge(&self, state: &mut SafetyState, gain: [f64; 2], evaluated: f64) -> Verdict {
        state.evaluations += 1;
        if state.evaluation_lost > 0 {
            // Restored, and counted, when the cable was lost (see `fall_back`).
            return Verdict::Failed {
                best: self.restorable(state),
            };
        }
        let Some(best) = state.best.filter(|b| b.evaluated.is_finite()) else {
            state.best = Some(BestPolicy { gain, evaluated });
            return Verdict::Best;
        };
        if evaluated > best.evaluated {
            state.best = Some(BestPolicy { gain, evaluated });
            return Verdict::Best;
        }
        match self.tolerance {
            Some(tol) if evaluated < best.evaluated - tol * best.evaluated.abs() => {
                state.rollbacks += 1;
                Verdict::RollBack { best }
            }
            _ => Verdict::Kept { best },
        }
    }

    /// The cable was lost under the policy in force: the best policy to restore at once (counted
    /// as a rollback), or `None` when none was evaluated yet or rollback is off.
    pub fn fall_back(&self, state: &mut SafetyState) -> Option<BestPolicy> {
        let best = self.restorable(state)?;
        state.rollbacks += 1;
        Some(best)
    }

    /// The best policy, when there is one and rollback is on.
    fn restorable(&self, state: &SafetyState) -> Option<BestPolicy> {
        state
            .best
            .filter(|b| b.evaluated.is_finite() && self.tolerance.is_some())
    }
}

/// What a checkpoint keeps of the safety layer: counts, the best policy, and the evaluation in
/// progress.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SafetyState {
    /// Actor updates shortened by the trust region.
    pub bounded: u64,
    /// Actor updates refused by the stability guard.
    pub refused: u64,
    /// Policies replaced by the best one.
    pub rollbacks: u64,
    /// Evaluations judged.
    pub evaluations: u64,
    /// The best policy evaluated so far.
    pub best: Option<BestPolicy>,
    /// The evaluation in progress: the sum of its trials' returns...
    pub evaluation_sum: f64,
    /// ... and their number, ...
    pub evaluation_trials: u32,
    /// ... and those of them that lost the cable.
    pub evaluation_lost: u32,
}

impl SafetyState {
    /// Checks that every number is usable (finite where it must be).
    pub fn is_valid(&self) -> bool {
        self.evaluation_sum.is_finite()
            && self
                .best
                .is_none_or(|b| b.gain.iter().all(|g| g.is_finite()) && !b.evaluated.is_nan())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lqr::discretize_zoh;
    use nalgebra::{Matrix2, Vector2};

    /// The identified yaw model of the paper's Table I: (Theta, dTheta/dt), d2Theta = -gamma
    /// dTheta - alpha tau.
    fn yaw() -> DiscreteSystem<2, 1> {
        let (alpha, gamma) = (0.2878, 3.4628);
        discretize_zoh(
            &Matrix2::new(0.0, 1.0, 0.0, -gamma),
            &Vector2::new(0.0, -alpha),
            0.2,
        )
        .unwrap()
    }

    fn stability(gain_margin: f64, delay_frames: u32) -> StabilityParams {
        StabilityParams {
            enabled: true,
            gain_margin,
            delay_frames,
            max_radius: 1.0,
        }
    }

    #[test]
    fn the_trust_region_shortens_long_steps_along_their_direction() {
        let tr = TrustRegion::new(
            &TrustRegionParams {
                enabled: true,
                max_action_change: 0.1,
            },
            [0.5, 0.5],
        );
        assert_eq!(tr.bound([0.1, -0.05]), ([0.1, -0.05], false));
        let (dk, bounded) = tr.bound([1.0, -3.0]);
        assert!(bounded);
        assert!((tr.action_change(dk) - 0.1).abs() < 1e-12);
        assert!((dk[1] / dk[0] + 3.0).abs() < 1e-12, "same direction");
    }

    /// Without delay and margin the radius is that of A + BK; the plant alone (K = 0) has the
    /// model's own poles (1 and e^{-gamma dt}).
    #[test]
    fn the_radius_is_the_closed_loops_and_the_margin_refuses_high_gains() {
        let sys = yaw();
        let plain = StableSet::new(sys, &stability(1.0, 0));
        assert!((plain.radius([0.0, 0.0]) - 1.0).abs() < 1e-9);
        let k = [10.78, 3.26]; // the LQR gain of the identified model
        let want = (sys.a + sys.b * nalgebra::RowVector2::new(k[0], k[1]))
            .complex_eigenvalues()
            .iter()
            .map(|z| z.norm())
            .fold(0.0, f64::max);
        assert!((plain.radius(k) - want).abs() < 1e-12);
        let robust = StableSet::new(sys, &stability(2.0, 1));
        assert!(plain.contains(k) && robust.contains(k));
        // A gain far beyond the LQR one is stable on the model as identified, but not with twice
        // the thrust and a period of delay; the wrong sign diverges either way.
        let high = [60.0, 3.0];
        assert!(plain.contains(high) && !robust.contains(high));
        assert!(!plain.contains([-2.0, 0.0]) && !robust.contains([-2.0, 0.0]));
        // A negative rate gain undoes the model's damping.
        assert!(!robust.contains([3.0, -14.0]));
        assert_eq!(plain.radius([f64::NAN, 0.0]), f64::INFINITY);
    }

    #[test]
    fn the_guard_refuses_leaving_the_set_but_lets_an_outsider_come_closer() {
        let guard = UpdateGuard {
            trust_region: None,
            stable_set: Some(StableSet::new(yaw(), &stability(2.0, 1))),
        };
        let inside = [10.0, 3.0];
        assert!(matches!(
            guard.review(inside, [10.5, 3.0]),
            Review::Accepted { bounded: false, .. }
        ));
        let out = [400.0, 3.0];
        assert!(matches!(guard.review(inside, out), Review::Refused { .. }));
        // Outside, a step towards the set is allowed, a step further out is not.
        let set = guard.stable_set.as_ref().unwrap();
        assert!(!set.contains(out) && set.radius([300.0, 3.0]) < set.radius(out));
        assert!(matches!(
            guard.review(out, [300.0, 3.0]),
            Review::Accepted { .. }
        ));
        assert!(matches!(
            guard.review(out, [500.0, 3.0]),
            Review::Refused { .. }
        ));
    }

    #[test]
    fn keep_best_rolls_back_only_beyond_the_tolerance() {
        let judge = KeepBest::new(Some(0.1));
        let mut s = SafetyState::default();
        assert_eq!(judge.judge(&mut s, [1.0, 0.0], -10.0), Verdict::Best);
        assert_eq!(judge.judge(&mut s, [2.0, 0.0], -8.0), Verdict::Best);
        let best = BestPolicy {
            gain: [2.0, 0.0],
            evaluated: -8.0,
        };
        // Within 10% of the best: kept.
        assert_eq!(
            judge.judge(&mut s, [3.0, 0.0], -8.7),
            Verdict::Kept { best }
        );
        assert_eq!(
            judge.judge(&mut s, [4.0, 0.0], -9.0),
            Verdict::RollBack { best }
        );
        assert_eq!((s.evaluations, s.rollbacks, s.best), (4, 1, Some(best)));
        // Keeping account only: never a rollback.
        let mut t = s;
        assert_eq!(
            KeepBest::new(None).judge(&mut t, [4.0, 0.0], -90.0),
            Verdict::Kept { best }
        );
        assert_eq!(t.rollbacks, 1);
    }

    /// A lost cable fails the policy whatever its return: it never becomes the best, and the best is
    /// restored (when rollback is on and a best exists).
    #[test]
    fn a_lost_cable_fails_the_policy_whatever_its_return() {
        let judge = KeepBest::new(Some(0.1));
        let mut s = SafetyState::default();
        // Nothing evaluated yet: nothing to fall back to.
        assert_eq!(judge.fall_back(&mut s), None);
        s.evaluation_lost = 1;
        assert_eq!(
            judge.judge(&mut s, [1.0, 0.0], -10.0),
            Verdict::Failed { best: None }
        );
        assert_eq!((s.best, s.rollbacks), (None, 0));
        s.evaluation_lost = 0;
        assert_eq!(judge.judge(&mut s, [2.0, 0.0], -10.0), Verdict::Best);
        let best = s.best.unwrap();
        // The cable lost under another policy: the best, to restore at once, counted.
        assert_eq!(judge.fall_back(&mut s), Some(best));
        assert_eq!(s.rollbacks, 1);
        // A better return (its trials ended early), but the cable was lost: the best again (its
        // restoring was counted when the cable was lost).
        s.evaluation_lost = 2;
        assert_eq!(
            judge.judge(&mut s, [3.0, 0.0], -5.0),
            Verdict::Failed { best: Some(best) }
        );
        assert_eq!((s.best, s.rollbacks), (Some(best), 1));
        // Rollback off: judged, never restored.
        assert_eq!(
            KeepBest::new(None).judge(&mut s, [3.0, 0.0], -5.0),
            Verdict::Failed { best: None }
        );
        assert_eq!(KeepBest::new(None).fall_back(&mut s), None);
        assert_eq!((s.best, s.rollbacks), (Some(best), 1));
    }
}
