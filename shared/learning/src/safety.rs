//! Safe policy improvement on the vehicle (step two): what may change the policy, and when a change
//! is taken back. Three independent parts, each switched in `learning.toml` (`[safety]`):
//!
//! - [`TrustRegion`]: each actor update may change the mean action by at most the bound in force
//!   anywhere in the observation box; a longer natural-gradient step is shortened along its
//!   direction (a step bound in the spirit of TRPO's KL constraint, here on the largest KL over the
//!   box, which for a fixed sigma is `bound^2 / (2 sigma^2)`). The bound is a trust-region radius
//!   adapted to how the steps fare ([`TrustRegion::adapted`]): it starts at `min_action_change`,
//!   doubles after each learning trial that kept the cable within the envelope, and halves when
//!   the cable is lost or the envelope left, within `[min_action_change, max_action_change]`
//!   (the behaviours apply it: `behaviour::core`). The first steps on the vehicle
//!   are the ones least known to be safe: the simulation policy can lose the cable on the vehicle,
//!   and then nothing has been evaluated to fall back to, so one long step there can lose the cable
//!   for many trials; once steps keep it, longer ones let yaw follow what sway learns within the
//!   session.
//! - [`StableSet`]: a gain is admissible when the identified linear model of the DOF, discretised at
//!   the sample time, closed with that gain times a gain margin and with extra periods of delay, has
//!   a spectral radius of at most `max_radius` (a stability-constrained update: the learner may not
//!   step where the model, with a robustness margin, says the loop oscillates or diverges). A gain
//!   already outside (a simulation policy can be) may only move towards the set.
//! - [`KeepBest`]: after every evaluation the pair of policies (sway and yaw) is compared with the
//!   best pair so far on the pair's cost ([`pair_score`]); worse by more than a tolerance, the best
//!   is restored (a conservative rollback to the best known baseline, as safe policy improvement with
//!   a baseline does). A pair that costs either DOF more than the session's first evaluation (the
//!   simulation policies) did, beyond the tolerance, is no candidate whatever the other DOF gained,
//!   and the best is restored ([`worse_than_start`]): step two may leave no DOF worse than it found
//!   it. Within the tolerance such a pair stays in force, so learning goes on from it, but it is
//!   never the best: the best, which is restored and kept, costs neither DOF more than the start on
//!   the evaluation's starts (five starts are few, and a pair a little worse there in one DOF was
//!   worse on other starts). A policy under which the cable was lost has failed whatever its
//!   return: the best is restored at once (a trial that loses the cable ends early, which can cost
//!   a DOF less than tracking badly for the whole trial, so the return alone would rank such a
//!   policy above a safe one), and the best is always a pair whose evaluation kept the cable in
//!   every trial.
//!   Before there is one (the simulation policies lost the cable in their own evaluation), an
//!   evaluated pair that lost the cable in more trials than the simulation policies did gives way
//!   to them: they are the only policies known to do better, and a learned pair that loses the
//!   cable in every trial would otherwise stay in force for evaluation after evaluation.
//!
//! **Why the pair, and why its cost as both behaviours see it.** A DOF's return depends on the
//! other DOF's policy (sway moves the image under yaw's Theta), so each behaviour keeping the best
//! of its own returns can end with a pair never evaluated together, worse than either evaluation
//! said. Each behaviour therefore judges the pair, and both must reach the same verdict on every
//! evaluation, so that they restore the policies of one and the same evaluation. The pair's cost is
//! each DOF's return's cost, summed over the evaluation: its state cost `x'Qx` of the scenario's
//! reward at each observed step ([`state_costs`]; every behaviour gets every cable observation, x_g
//! and Theta alike) and its action term `r u^2` of each command it gave ([`action_costs`]; a
//! behaviour reads its partner's commands, stamped by step). The behaviours compute it apart, with
//! the same operations on the same numbers in the same order, and get the same bits. The action
//! term is not small with images, where the commands follow a noisy x_g: about 40% of sway's return
//! and 12% of yaw's (the main job's seed 2); a rule on state costs alone let a pair within the
//! tolerance cost a DOF's return more.
//!
//! Each DOF's cost counts relative to its cost in the first evaluation of the session (the
//! simulation policies on the vehicle): [`pair_score`] is minus the sum of the two ratios (-2 for the
//! first evaluation). The weights are fixed for the session, so the score orders all evaluations
//! (one best, whatever the order of judging), and a DOF counts by its relative change, not by the
//! size of its cost (sway's cost with images is many times yaw's). A change that costs one DOF is
//! not bought with the other's gain, however large: with images, a sway policy learned on the twin
//! can raise yaw's cost under yaw's simulation policy by more than half (the DOFs couple: the
//! true state's cost rises as much as the observed one, so it is not perception), and a sum of
//! the two ratios takes such a pair as better. [`worse_than_start`] refuses it: each DOF must stay
//! within the tolerance of its cost under the simulation policies.
//!
//! [`UpdateGuard`] applies the first two to each actor update; [`SafetyState`] is what a checkpoint
//! keeps of all three (counts and the best policy), so a restarted behaviour goes on where it was.

use crate::lqr::DiscreteSystem;
use config::{Dof, PerDof, QuadraticCost, StabilityParams, TrustRegionParams};
use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

/// The trust region on each actor update (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrustRegion {
    min_action_change: f64,
    max_action_change: f64,
    state_max: [f64; 2],
}

impl TrustRegion {
    /// A trust region of `params` over the observation box `|x_i| <= state_max[i]`.
    pub fn new(params: &TrustRegionParams, state_max: [f64; 2]) -> Self {
        TrustRegion {
            min_action_change: params.min_action_change,
            max_action_change: params.max_action_change,
            state_max,
        }
    }

    /// The bound in force for the adapted bound `bound` a safety state keeps
    /// ([`SafetyState::action_change_bound`]): the smallest before any (0), and within the
    /// region's limits always.
    pub fn in_force(&self, bound: f64) -> f64 {
        if bound > 0.0 {
            bound.clamp(self.min_action_change, self.max_action_change)
        } else {
            self.min_action_change
        }
    }

    /// The bound after a learning trial that kept the cable within the envelope (`kept`: doubled)
    /// or after a failure (halved), from the adapted bound `bound`; within the region's limits.
    pub fn adapted(&self, bound: f64, kept: bool) -> f64 {
        let factor = if kept { 2.0 } else { 0.5 };
        (self.in_force(bound) * factor).clamp(self.min_action_change, self.max_action_change)
    }

    /// The largest change of the mean action over the box that a gain step `dk` makes.
    pub fn action_change(&self, dk: [f64; 2]) -> f64 {
        dk[0].abs() * self.state_max[0] + dk[1].abs() * self.state_max[1]
    }

    /// `dk` shortened along its direction to the edge of the region of the adapted bound `bound`
    /// when it reaches beyond; `true` when it was shortened.
    pub fn bound(&self, dk: [f64; 2], bound: f64) -> ([f64; 2], bool) {
        let change = self.action_change(dk);
        let bound = self.in_force(bound);
        if change <= bound || !change.is_finite() {
            return (dk, false);
        }
        let s = bound / change;
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

    /// Reviews the actor update from `before` to `proposed`, under the trust region's adapted
    /// bound `bound` ([`SafetyState::action_change_bound`]).
    pub fn review(&self, before: [f64; 2], proposed: [f64; 2], bound: f64) -> Review {
        let (gain, bounded) = match &self.trust_region {
            Some(tr) => {
                let dk = [proposed[0] - before[0], proposed[1] - before[1]];
                let (dk, bounded) = tr.bound(dk, bound);
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

/// The best pair an evaluation has seen: this behaviour's policy of it, and what the evaluation
/// measured.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct BestPolicy {
    /// K for (position, rate).
    pub gain: [f64; 2],
    /// Its evaluated return (the mean over the evaluation's trials).
    pub evaluated: f64,
    /// The pair's cost in that evaluation (infinite when unknown: a best from a checkpoint of
    /// format 3 or older, which the next evaluation judged replaces).
    pub cost: PerDof<f64>,
    /// The trial that closed that evaluation (the vehicle's number): both behaviours' bests name
    /// the same one.
    pub trial: u32,
}

/// One observed step's state share of the pair's cost (see the module docs): each DOF's state
/// cost `x'Qx` of `rewards` (the scenario's) at its observed (position, rate) `states`. An
/// evaluation's pair cost is, per DOF, the mean over its trials of the sum over their steps of
/// this and [`action_costs`].
pub fn state_costs(rewards: &PerDof<QuadraticCost>, states: PerDof<[f64; 2]>) -> PerDof<f64> {
    let c = |dof: Dof| {
        let (q, x) = (rewards.get(dof).q, states.get(dof));
        q[0] * x[0] * x[0] + q[1] * x[1] * x[1]
    };
    PerDof {
        sway: c(Dof::Sway),
        yaw: c(Dof::Yaw),
    }
}

/// One step's action share of the pair's cost: each DOF's `r u^2` of `rewards` for the command
/// `actions` it gave at that step (the action applied, as the return counts it).
pub fn action_costs(rewards: &PerDof<QuadraticCost>, actions: PerDof<f64>) -> PerDof<f64> {
    let c = |dof: Dof| rewards.get(dof).r * actions.get(dof) * actions.get(dof);
    PerDof {
        sway: c(Dof::Sway),
        yaw: c(Dof::Yaw),
    }
}

/// The pair's score (higher is better): minus the sum over the DOFs of the cost relative to the
/// session's first evaluation (`scale`, each DOF's cost there). The rule both behaviours apply (see
/// the module docs); NaN when a DOF's cost or scale is unknown.
pub fn pair_score(cost: PerDof<f64>, scale: PerDof<f64>) -> f64 {
    -(cost.sway / scale.sway + cost.yaw / scale.yaw)
}

/// The scale of the pair's score from the costs of the session's first evaluation: each DOF's
/// cost, floored so that a DOF tracked perfectly there does not weigh infinitely.
pub fn pair_scale(first: PerDof<f64>) -> PerDof<f64> {
    const FLOOR: f64 = 1e-9;
    PerDof {
        sway: first.sway.abs().max(FLOOR),
        yaw: first.yaw.abs().max(FLOOR),
    }
}

/// The DOF (the first, in `Dof::ALL`'s order) whose `cost` exceeds its cost in the session's first
/// evaluation (`scale`) by more than `tolerance` of it, if any: a pair the judge does not take
/// however much the other DOF gained (see the module docs).
pub fn worse_than_start(cost: PerDof<f64>, scale: PerDof<f64>, tolerance: f64) -> Option<Dof> {
    Dof::ALL
        .into_iter()
        .find(|&dof| cost.get(dof) / scale.get(dof) > 1.0 + tolerance)
}

/// One closed evaluation, as a behaviour judges it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Evaluated {
    /// The trial that closed it.
    pub trial: u32,
    /// The policy evaluated (this behaviour's).
    pub gain: [f64; 2],
    /// Its mean return over the evaluation's trials.
    pub evaluated: f64,
    /// The pair's cost in it.
    pub cost: PerDof<f64>,
}

impl From<&Evaluated> for BestPolicy {
    /// The evaluated policy, as the best or the session's start keeps it.
    fn from(e: &Evaluated) -> Self {
        BestPolicy {
            gain: e.gain,
            evaluated: e.evaluated,
            cost: e.cost,
            trial: e.trial,
        }
    }
}

/// What an evaluation decided.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Verdict {
    /// The policy is the best so far (or the first evaluated): it is kept as the best.
    Best,
    /// Not better than the best, or better but costing a DOF more than the session's first
    /// evaluation did (within the tolerance): learning goes on from it.
    Kept {
        /// The best so far.
        best: BestPolicy,
        /// The DOF the pair costs more than the start did, which keeps it from being the best.
        costlier: Option<Dof>,
    },
    /// Worse than the best by more than the tolerance: the best is restored.
    RollBack {
        /// The policy to restore.
        best: BestPolicy,
    },
    /// The pair costs this DOF more than the session's first evaluation did (the simulation
    /// policies), beyond the tolerance: whatever it gained in the other DOF it is not a candidate
    /// for the best, and the best is restored (if rollback is on).
    WorseThanStart {
        /// The DOF it costs more.
        dof: Dof,
        /// The policy to restore, if any.
        restore: Option<BestPolicy>,
    },
    /// The cable was lost in some trial of the evaluation: the policy is not a candidate for the
    /// best whatever its return, and the best (if one was evaluated, and rollback is on) is
    /// restored; with none, the session's start (the simulation policies) is, when the pair lost
    /// the cable in more of the evaluation's trials than the start did in its own.
    Failed {
        /// The policy to restore, if any.
        restore: Option<BestPolicy>,
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

    /// Judges the pair evaluated in `e` against the best pair in `state` (updated: the best, the
    /// scale of the pair's score, the counts), on [`pair_score`]: better than the best, it is the
    /// best; worse by more than the tolerance times the best's score, the best is restored. Both
    /// behaviours call it with the same `e.cost` and `e.trial` and the same state of the account, so
    /// they reach the same verdict. An evaluation in which the cable was lost
    /// ([`SafetyState::evaluation_lost`]) is [`Verdict::Failed`].
    pub fn judge(&self, state: &mut SafetyState, e: &Evaluated) -> Verdict {
        state.evaluations += 1;
        let candidate = BestPolicy::from(e);
        if state.evaluations == 1 {
            // The session's first evaluation: the simulation policies, what step two started from.
            (state.start, state.start_lost) = (Some(candidate), state.evaluation_lost);
        }
        if state.evaluation_lost > 0 {
            // With a best, it was restored, and counted, when the cable was lost (see
            // `fall_back`); without one, the start is, when the pair lost more than it did.
            let restore = self.restorable(state).or_else(|| {
                let start = state.start.filter(|_| self.tolerance.is_some())?;
                let restore = state.start_lost < state.evaluation_lost;
                state.rollbacks += restore as u64;
                restore.then_some(start)
            });
            return Verdict::Failed { restore };
        }
        if !(state.scale.sway > 0.0 && state.scale.yaw > 0.0) {
            // The session's first evaluation judged: its costs weigh the DOFs from now on.
            state.scale = pair_scale(e.cost);
        }
        let score = pair_score(e.cost, state.scale);
        if let Some(dof) = worse_than_start(e.cost, state.scale, self.tolerance.unwrap_or(0.0)) {
            let restore = self.restorable(state);
            if restore.is_some() {
                state.rollbacks += 1;
            }
            return Verdict::WorseThanStart { dof, restore };
        }
        let best = state
            .best
            .map(|b| (b, pair_score(b.cost, state.scale)))
            .filter(|(_, s)| s.is_finite());
        let Some((best, best_score)) = best else {
            state.best = Some(candidate);
            return Verdict::Best;
        };
        // The tolerance lets a pair that costs a DOF a little more than the start stay in force,
        // so learning goes on from it; the pair kept and restored costs neither DOF more.
        let costlier = worse_than_start(e.cost, state.scale, 0.0);
        if score > best_score && costlier.is_none() {
            state.best = Some(candidate);
            return Verdict::Best;
        }
        match self.tolerance {
            Some(tol) if score < best_score - tol * best_score.abs() => {
                state.rollbacks += 1;
                Verdict::RollBack { best }
            }
            _ => Verdict::Kept { best, costlier },
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
    /// ... and those of them that lost the cable, ...
    pub evaluation_lost: u32,
    /// ... and the pair's cost so far (each DOF's state and action costs summed over its steps).
    pub evaluation_cost: PerDof<f64>,
    /// Each DOF's cost in the session's first evaluation judged: the weights of the pair's score
    /// (0 before it).
    pub scale: PerDof<f64>,
    /// The trust region's adapted bound on the mean action's change ([`TrustRegion::adapted`]; 0
    /// before any: the smallest).
    pub action_change_bound: f64,
    /// The session's first evaluation judged (the simulation policies on the vehicle): the policy a
    /// failed evaluation restores when no best has been evaluated and it lost fewer trials...
    pub start: Option<BestPolicy>,
    /// ... and the trials of it that lost the cable.
    pub start_lost: u32,
}

impl SafetyState {
    /// The policy a restore falls back to: the best so far, or before one, the session's start
    /// (`None` before the first evaluation).
    pub fn reference(&self) -> Option<BestPolicy> {
        self.best.or(self.start)
    }

    /// Checks that every number is usable (finite where it must be).
    pub fn is_valid(&self) -> bool {
        self.evaluation_sum.is_finite()
            && self.evaluation_cost.sway.is_finite()
            && self.evaluation_cost.yaw.is_finite()
            && [self.scale.sway, self.scale.yaw, self.action_change_bound]
                .iter()
                .all(|s| s.is_finite() && *s >= 0.0)
            && [self.best, self.start]
                .iter()
                .flatten()
                .all(|b| b.gain.iter().all(|g| g.is_finite()) && !b.evaluated.is_nan())
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

    fn region(min_action_change: f64, max_action_change: f64) -> TrustRegion {
        let params = TrustRegionParams {
            enabled: true,
            max_action_change,
            min_action_change,
        };
        TrustRegion::new(&params, [0.5, 0.5])
    }

    #[test]
    fn the_trust_region_shortens_long_steps_along_their_direction() {
        let tr = region(0.1, 0.1);
        assert_eq!(tr.bound([0.1, -0.05], 0.1), ([0.1, -0.05], false));
        let (dk, bounded) = tr.bound([1.0, -3.0], 0.1);
        assert!(bounded);
        assert!((tr.action_change(dk) - 0.1).abs() < 1e-12);
        assert!((dk[1] / dk[0] + 3.0).abs() < 1e-12, "same direction");
    }

    /// The bound starts at the smallest, doubles on each trial that kept the cable and halves on
    /// each failure, never leaving the region's limits; a step is shortened to the bound in force.
    #[test]
    fn the_trust_regions_bound_grows_on_success_and_shrinks_on_failure() {
        let tr = region(0.05, 0.5);
        assert_eq!(tr.in_force(0.0), 0.05, "no bound adapted yet: the smallest");
        let mut bound = 0.0;
        let mut seen = Vec::new();
        for kept in [
            true, true, true, true, true, false, false, false, false, false,
        ] {
            bound = tr.adapted(bound, kept);
            seen.push(bound);
        }
        assert_eq!(
            seen,
            [0.1, 0.2, 0.4, 0.5, 0.5, 0.25, 0.125, 0.0625, 0.05, 0.05]
        );
        // A step of action change 0.2 passes under the largest bound, is halved under 0.1.
        let dk = [0.2, 0.2];
        assert_eq!(tr.bound(dk, 0.5), (dk, false));
        let (short, bounded) = tr.bound(dk, 0.1);
        assert!(bounded && (tr.action_change(short) - 0.1).abs() < 1e-12);
        // A bound kept from other limits is taken within these.
        assert_eq!((tr.in_force(3.0), tr.in_force(0.01)), (0.5, 0.05));
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
            guard.review(inside, [10.5, 3.0], 0.0),
            Review::Accepted { bounded: false, .. }
        ));
        let out = [400.0, 3.0];
        assert!(matches!(
            guard.review(inside, out, 0.0),
            Review::Refused { .. }
        ));
        // Outside, a step towards the set is allowed, a step further out is not.
        let set = guard.stable_set.as_ref().unwrap();
        assert!(!set.contains(out) && set.radius([300.0, 3.0]) < set.radius(out));
        assert!(matches!(
            guard.review(out, [300.0, 3.0], 0.0),
            Review::Accepted { .. }
        ));
        assert!(matches!(
            guard.review(out, [500.0, 3.0], 0.0),
            Review::Refused { .. }
        ));
    }

    /// An evaluation closing at `trial` of the policy `gain`, the pair's costs (sway, yaw); the
    /// behaviour's own return is minus its DOF's cost here.
    fn ev(trial: u32, gain: f64, cost: (f64, f64)) -> Evaluated {
        Evaluated {
            trial,
            gain: [gain, 0.0],
            evaluated: -cost.0,
            cost: PerDof {
                sway: cost.0,
                yaw: cost.1,
            },
        }
    }

    #[test]
    fn keep_best_rolls_back_only_beyond_the_tolerance() {
        let judge = KeepBest::new(Some(0.1));
        let mut s = SafetyState::default();
        // The first evaluation weighs the DOFs: its score is -2.
        assert_eq!(judge.judge(&mut s, &ev(4, 1.0, (10.0, 4.0))), Verdict::Best);
        assert_eq!(
            s.scale,
            PerDof {
                sway: 10.0,
                yaw: 4.0
            }
        );
        // -(0.8 + 1.0) = -1.8: better.
        assert_eq!(judge.judge(&mut s, &ev(14, 2.0, (8.0, 4.0))), Verdict::Best);
        let best = s.best.unwrap();
        assert_eq!(
            (best.gain, best.trial, best.evaluated),
            ([2.0, 0.0], 14, -8.0)
        );
        // -(0.8 + 1.075) = -1.875: worse by 4% of 1.8, within 10%: kept.
        assert_eq!(
            judge.judge(&mut s, &ev(24, 3.0, (8.0, 4.3))),
            Verdict::Kept {
                best,
                costlier: Some(Dof::Yaw)
            }
        );
        // -(1.0 + 1.075) = -2.075: worse by 15%: the best pair is restored.
        assert_eq!(
            judge.judge(&mut s, &ev(34, 4.0, (10.0, 4.3))),
            Verdict::RollBack { best }
        );
        assert_eq!((s.evaluations, s.rollbacks, s.best), (4, 1, Some(best)));
        // Keeping account only: never a rollback, even of a pair worse than the start.
        let mut t = s;
        assert_eq!(
            KeepBest::new(None).judge(&mut t, &ev(44, 4.0, (80.0, 40.0))),
            Verdict::WorseThanStart {
                dof: Dof::Sway,
                restore: None
            }
        );
        assert_eq!(t.rollbacks, 1);
        // A best from an older checkpoint (its pair's cost unknown) gives way to the next pair.
        let mut old = SafetyState {
            best: Some(BestPolicy {
                cost: PerDof::both(f64::INFINITY),
                ..best
            }),
            ..Default::default()
        };
        assert_eq!(
            judge.judge(&mut old, &ev(54, 5.0, (9.0, 9.0))),
            Verdict::Best
        );
        assert_eq!(old.best.unwrap().trial, 54);
    }

    /// Both behaviours judge the same evaluations: what each keeps in force after every evaluation
    /// (the policy evaluated, or the best restored) and its best, by evaluation.
    fn session(judge: KeepBest, evaluations: &[Evaluated]) -> Vec<(u32, Option<u32>)> {
        let mut s = SafetyState::default();
        evaluations
            .iter()
            .map(|e| {
                let in_force = match judge.judge(&mut s, e) {
                    Verdict::Best | Verdict::Kept { .. } => e.trial,
                    Verdict::RollBack { best } => best.trial,
                    Verdict::Failed { restore: best }
                    | Verdict::WorseThanStart {
                        restore: best,
                        dof: _,
                    } => best.map_or(e.trial, |b| b.trial),
                };
                (in_force, s.best.map(|b| b.trial))
            })
            .collect()
    }

    /// One DOF's cost alone (the other's 0, weighing nothing): the judge of that DOF alone, the
    /// rule before pairs.
    fn alone(evaluations: &[Evaluated], dof: Dof) -> Vec<Evaluated> {
        evaluations
            .iter()
            .map(|e| Evaluated {
                cost: PerDof {
                    sway: if dof == Dof::Sway { e.cost.sway } else { 0.0 },
                    yaw: if dof == Dof::Yaw { e.cost.yaw } else { 0.0 },
                },
                ..*e
            })
            .collect()
    }

    /// The main job's seed 2 (returns as measured there, but for the made-up middle ones): yaw's
    /// best return came after 10 learning trials, sway's after 20. Judging each DOF alone keeps yaw's
    /// policy of the one evaluation and sway's of the other, a pair never evaluated together; the
    /// pair's rule keeps one evaluation's pair in both.
    #[test]
    fn seed_2_both_keep_the_pair_of_one_evaluation() {
        let judge = KeepBest::new(Some(0.02));
        let evaluations = [
            ev(4, 0.0, (6.897, 5.912)),
            ev(14, 5.0, (6.80, 5.85)),
            ev(24, 10.0, (6.60, 5.560)),
            ev(34, 15.0, (6.30, 5.75)),
            ev(44, 20.0, (6.024, 5.80)),
        ];
        let (sway, yaw) = (
            session(judge, &alone(&evaluations, Dof::Sway)),
            session(judge, &alone(&evaluations, Dof::Yaw)),
        );
        assert_eq!(sway.last().unwrap().1, Some(44));
        assert_eq!(yaw.last().unwrap().1, Some(24), "alone, yaw keeps another");
        // The pair: one account, whichever behaviour keeps it; -(0.873 + 0.981) = -1.854 after 20
        // learning trials beats -(0.957 + 0.940) = -1.897 after 10.
        let pair = session(judge, &evaluations);
        assert_eq!(pair.last().unwrap(), &(44, Some(44)));
        let mut s = SafetyState::default();
        for e in &evaluations {
            judge.judge(&mut s, e);
        }
        let best = s.best.unwrap();
        assert_eq!(
            (best.gain, best.cost),
            (evaluations[4].gain, evaluations[4].cost)
        );
    }

    /// The main job's seed 3: sway's cost fell from 9.75 to 1.14 while yaw's rose from 7.00 to
    /// 10.09 with its simulation policy unchanged. The pair's score (-1.56 against -2) would take
    /// it; the vehicle would fly yaw worse than it came. It is refused and the simulation policies
    /// restored; a later pair that improves sway and costs yaw a little more, within the tolerance,
    /// stays in force but is not the best; one that costs yaw nothing more is.
    #[test]
    fn seed_3_a_sway_gain_that_costs_yaw_is_refused() {
        let judge = KeepBest::new(Some(0.02));
        let evaluations = [
            ev(4, 0.0, (9.75, 7.00)),
            ev(14, 5.0, (1.14, 10.09)),
            ev(24, 10.0, (1.20, 7.10)),
            ev(34, 15.0, (1.15, 7.20)),
        ];
        let mut s = SafetyState::default();
        judge.judge(&mut s, &evaluations[0]);
        let start = s.best.unwrap();
        assert_eq!(
            judge.judge(&mut s, &evaluations[1]),
            Verdict::WorseThanStart {
                dof: Dof::Yaw,
                restore: Some(start)
            }
        );
        assert_eq!((s.best, s.rollbacks), (Some(start), 1));
        // Yaw 1.4% above its start, within 2%: in force, not the best, though its score (-1.14)
        // beats the start's; then 2.9% above: refused, the start restored; then as it came: the
        // best.
        assert_eq!(
            judge.judge(&mut s, &evaluations[2]),
            Verdict::Kept {
                best: start,
                costlier: Some(Dof::Yaw)
            }
        );
        let mut evaluations = evaluations.to_vec();
        evaluations.push(ev(44, 20.0, (1.18, 7.00)));
        assert_eq!(
            session(judge, &evaluations),
            vec![
                (4, Some(4)),
                (4, Some(4)),
                (24, Some(4)),
                (4, Some(4)),
                (44, Some(44))
            ]
        );
        assert_eq!(
            worse_than_start(evaluations[3].cost, pair_scale(evaluations[0].cost), 0.02),
            Some(Dof::Yaw)
        );
    }

    /// The verdict depends on the pair's costs and the account alone: the same for both behaviours,
    /// whatever their own returns and gains, so they restore the same evaluation's policies.
    #[test]
    fn both_behaviours_reach_the_same_verdicts() {
        let judge = KeepBest::new(Some(0.02));
        let costs = [(5.0, 3.0), (4.0, 3.3), (4.5, 3.6), (3.0, 2.0), (3.2, 2.9)];
        let (mut sway, mut yaw) = (SafetyState::default(), SafetyState::default());
        for (i, &c) in costs.iter().enumerate() {
            let trial = 4 + 10 * i as u32;
            let s = judge.judge(&mut sway, &ev(trial, i as f64, c));
            let mut for_yaw = ev(trial, -(i as f64), c);
            for_yaw.evaluated = -c.1;
            let y = judge.judge(&mut yaw, &for_yaw);
            let trial_of = |v: Verdict| match v {
                Verdict::Best => None,
                Verdict::Kept { best, .. } | Verdict::RollBack { best } => Some(best.trial),
                Verdict::Failed { restore: best }
                | Verdict::WorseThanStart {
                    restore: best,
                    dof: _,
                } => best.map(|b| b.trial),
            };
            assert_eq!(std::mem::discriminant(&s), std::mem::discriminant(&y));
            assert_eq!(trial_of(s), trial_of(y));
            assert_eq!(sway.best.map(|b| b.trial), yaw.best.map(|b| b.trial));
        }
        // Yaw's cost up 10% and 20% on the start's (restored), then sway's and yaw's down (the
        // best), then worse than that best by 27% (restored).
        assert_eq!(sway.rollbacks, 3);
    }

    #[test]
    fn the_pair_cost_of_a_step_is_each_dofs_state_and_action_cost() {
        let rewards = PerDof {
            sway: QuadraticCost {
                q: [1.1, 0.2],
                r: 0.01,
            },
            yaw: QuadraticCost {
                q: [2.0, 0.25],
                r: 0.01,
            },
        };
        let c = state_costs(
            &rewards,
            PerDof {
                sway: [0.1, -0.2],
                yaw: [0.3, 0.4],
            },
        );
        assert!((c.sway - (1.1 * 0.01 + 0.2 * 0.04)).abs() < 1e-15);
        assert!((c.yaw - (2.0 * 0.09 + 0.25 * 0.16)).abs() < 1e-15);
        let a = action_costs(
            &rewards,
            PerDof {
                sway: -0.5,
                yaw: 0.2,
            },
        );
        assert!((a.sway - 0.01 * 0.25).abs() < 1e-15);
        assert!((a.yaw - 0.01 * 0.04).abs() < 1e-15);
        assert_eq!(
            pair_scale(PerDof {
                sway: 0.0,
                yaw: -2.0
            })
            .yaw,
            2.0
        );
        assert!(
            pair_scale(PerDof {
                sway: 0.0,
                yaw: 2.0
            })
            .sway
                > 0.0
        );
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
            judge.judge(&mut s, &ev(4, 1.0, (10.0, 1.0))),
            Verdict::Failed { restore: None }
        );
        assert_eq!((s.best, s.rollbacks), (None, 0));
        s.evaluation_lost = 0;
        assert_eq!(
            judge.judge(&mut s, &ev(14, 2.0, (10.0, 1.0))),
            Verdict::Best
        );
        let best = s.best.unwrap();
        // The cable lost under another policy: the best, to restore at once, counted.
        assert_eq!(judge.fall_back(&mut s), Some(best));
        assert_eq!(s.rollbacks, 1);
        // A better return (its trials ended early), but the cable was lost: the best again (its
        // restoring was counted when the cable was lost).
        s.evaluation_lost = 2;
        assert_eq!(
            judge.judge(&mut s, &ev(24, 3.0, (5.0, 1.0))),
            Verdict::Failed {
                restore: Some(best)
            }
        );
        assert_eq!((s.best, s.rollbacks), (Some(best), 1));
        // Rollback off: judged, never restored.
        assert_eq!(
            KeepBest::new(None).judge(&mut s, &ev(24, 3.0, (5.0, 1.0))),
            Verdict::Failed { restore: None }
        );
        assert_eq!(KeepBest::new(None).fall_back(&mut s), None);
        assert_eq!((s.best, s.rollbacks), (Some(best), 1));
    }

    /// Before any pair kept the cable there is no best: a learned pair that loses the cable in more
    /// of its evaluation's trials than the simulation policies did in theirs gives way to them, one
    /// that loses as many or fewer does not (nothing known is better), and the first pair that keeps
    /// the cable becomes the best.
    #[test]
    fn a_pair_losing_more_than_the_start_gives_way_to_it() {
        let judge = KeepBest::new(Some(0.1));
        let mut s = SafetyState {
            evaluation_lost: 1,
            ..SafetyState::default()
        };
        let first = ev(4, -30.0, (40.0, 30.0));
        assert_eq!(
            judge.judge(&mut s, &first),
            Verdict::Failed { restore: None }
        );
        let start = BestPolicy::from(&first);
        assert_eq!((s.start, s.start_lost), (Some(start), 1));
        // As many lost: learning goes on from the pair.
        assert_eq!(
            judge.judge(&mut s, &ev(14, -20.0, (30.0, 20.0))),
            Verdict::Failed { restore: None }
        );
        assert_eq!(s.rollbacks, 0);
        // More lost: the start, counted.
        s.evaluation_lost = 5;
        assert_eq!(
            judge.judge(&mut s, &ev(24, -10.0, (12.0, 9.0))),
            Verdict::Failed {
                restore: Some(start)
            }
        );
        assert_eq!((s.best, s.rollbacks), (None, 1));
        // Rollback off: judged, never restored.
        let mut off = s;
        assert_eq!(
            KeepBest::new(None).judge(&mut off, &ev(34, -10.0, (12.0, 9.0))),
            Verdict::Failed { restore: None }
        );
        // The first pair that keeps the cable is the best; the start stays what it was.
        s.evaluation_lost = 0;
        assert_eq!(
            judge.judge(&mut s, &ev(34, -8.0, (9.0, 8.0))),
            Verdict::Best
        );
        assert_eq!((s.start, s.start_lost), (Some(start), 1));
        // From then on a failed evaluation restores the best, never the start.
        s.evaluation_lost = 5;
        let best = s.best.unwrap();
        assert_eq!(
            judge.judge(&mut s, &ev(44, -9.0, (10.0, 9.0))),
            Verdict::Failed {
                restore: Some(best)
            }
        );
    }
}
