//! One learned DOF as its behaviour sees it: observe, act, learn, report episodes.
//!
//! The sway and yaw behaviour services and the in-process trainer call [`Agent::step`] once per
//! control step with the DOF's observed state `(position, rate)` and what the simulator says of it
//! ([`StepStatus`]). The agent closes the transition it left pending on the previous step, lets its
//! learner update, and, unless the episode ended, samples the next action.
//!
//! The task's rules (DESIGN.md, "The scenario"):
//! - the reward `-(x'Qx + u'Ru)` uses the action as applied (clipped to [-1, 1]); the learner's
//!   gradient uses the action as sampled;
//! - losing the cable is an absorbing failure: the transition's reward is the worst per-step reward
//!   over the observation box divided by `1 - gamma`, and the critic does not bootstrap past it;
//! - a time limit is not a failure: the critic bootstraps on the last observation;
//! - eligibility traces are reset at every episode end.

use crate::checkpoint::{
    AgentState, AgentStateError, GpomdpState, LearnerState, NacState, PolicyState,
};
use crate::gpomdp::{Gpomdp, GpomdpConfig};
use crate::learner::{Algorithm, Learner, PolicyLearner, Transition};
use crate::nac::{GradientHistory, Nac, NacConfig, NacStatistics};
use crate::policy::LinearGaussian;
use crate::safety::{Review, SafetyState, UpdateGuard};
use config::StepStatus;
use config::{Dof, LearningParams, QuadraticCost};
use nalgebra::{SMatrix, SVector, Vector2};
use rand::SeedableRng;
use rand::rngs::StdRng;

/// NAC on the cable task's 2-D state: 4 basis functions and 2 gains.
pub type CableNac = Nac<2, 6>;
/// Either learner on the cable task's 2-D state.
pub type CableLearner = Learner<2, 6>;

/// Why an episode ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EpisodeEnd {
    /// The cable was lost: a failure.
    Lost,
    /// The step limit was reached.
    TimeLimit,
    /// Cut short by the caller ([`Agent::abort_episode`]) or by an unusable observation: the last
    /// pending transition was dropped without learning from it.
    Aborted,
}

/// One finished episode (serialisable for learning-curve logs; the return is named `return` there).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct EpisodeSummary {
    /// The episode's number: 1 for the agent's first, counting on across checkpoints.
    pub episode: u64,
    /// Sum of the rewards of the episode's transitions, the failure reward included.
    #[serde(rename = "return")]
    pub return_: f64,
    /// Transitions (actions taken) in the episode.
    pub steps: u32,
    /// The cable was lost (`end == EpisodeEnd::Lost`).
    pub failed: bool,
    /// Why the episode ended.
    pub end: EpisodeEnd,
    /// The learner's actor updates so far (all episodes).
    pub actor_updates: u64,
    /// The policy gain at the end of the episode.
    pub gain: [f64; 2],
}

/// What one control step returns.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Step {
    /// The action to apply, in [-1, 1]; 0 when the episode just ended.
    pub action: f64,
    /// The learner changed the policy on this step.
    pub actor_updated: bool,
    /// Present when this step ended an episode.
    pub episode: Option<EpisodeSummary>,
}

/// The transition waiting for its next observation.
#[derive(Clone, Copy, Debug)]
struct Pending {
    x: Vector2<f64>,
    u_sampled: f64,
    u_applied: f64,
}

/// The reward of the transition that loses the cable: the worst per-step reward over the observation
/// box and the action range, `-(q0 m0^2 + q1 m1^2 + r)`, divided by `1 - gamma`, i.e. that worst
/// reward forever after.
pub fn failure_reward(cost: &QuadraticCost, state_max: [f64; 2], gamma: f64) -> f64 {
    cost.reward(state_max, 1.0) / (1.0 - gamma)
}

/// The behaviour core of one learned DOF: policy, learner, episode accounting.
#[derive(Clone, Debug)]
pub struct Agent {
    dof: Dof,
    params: LearningParams,
    cost: QuadraticCost,
    state_max: [f64; 2],
    failure_reward: f64,
    policy: LinearGaussian<2>,
    learner: CableLearner,
    rng: StdRng,
    pending: Option<Pending>,
    learning: bool,
    steps: u64,
    episodes: u64,
    episode_return: f64,
    episode_steps: u32,
    /// What may change the policy (step two's safety layer; inactive by default).
    guard: UpdateGuard,
    safety: SafetyState,
    /// Actor updates refused in this episode (logged once at its start and summed at its end).
    episode_refused: u64,
}

impl Agent {
    /// A fresh agent for `dof`: the gain is `params.policy.initial_gain` of that DOF and the learner has
    /// seen nothing. `state_max` is the observation box (e.g. `[0.5, 0.5]` for sway, `[pi/2, 1]` for
    /// yaw); `seed` seeds the exploration noise, so a run is reproducible.
    ///
    /// The parameters are taken as valid (the config loader checks them).
    pub fn new(
        dof: Dof,
        algorithm: Algorithm,
        params: &LearningParams,
        cost: QuadraticCost,
        state_max: [f64; 2],
        seed: u64,
    ) -> Self {
        let learner = match algorithm {
            Algorithm::Nac => Learner::Nac(Nac::new(NacConfig::for_dof(&params.nac, dof))),
            Algorithm::Gpomdp => {
                Learner::Gpomdp(Gpomdp::new(GpomdpConfig::for_dof(&params.gpomdp, dof)))
            }
        };
        let policy = LinearGaussian::new(
            Vector2::from(*params.policy.initial_gain.get(dof)),
            params.policy.sigma,
        );
        Self::assemble(
            dof,
            params.clone(),
            cost,
            state_max,
            policy,
            learner,
            seed,
            (0, 0),
            SafetyState::default(),
        )
    }

    /// An agent resuming from a checkpointed state, with a fresh exploration noise seeded by `seed`.
    /// No transition is pending: the first step starts from the observation it is given.
    pub fn from_state(state: AgentState, seed: u64) -> Result<Self, AgentStateError> {
        state.validate()?;
        let dof = state.dof;
        let learner = match &state.learner {
            LearnerState::Nac(s) => {
                let mut theta = SVector::<f64, 6>::zeros();
                theta.as_mut_slice()[..4].copy_from_slice(&s.v);
                theta.as_mut_slice()[4..].copy_from_slice(&s.w);
                let stats = NacStatistics {
                    a: SMatrix::<f64, 6, 6>::from_fn(|i, j| s.a[i][j]),
                    b: SVector::from(s.b),
                    z: SVector::from(s.z),
                    theta,
                    w_history: GradientHistory::from_oldest_first(
                        s.w_history.iter().map(|w| Vector2::from(*w)),
                    ),
                    mass: s.mass,
                    steps: s.steps,
                    actor_updates: s.actor_updates,
                };
                Learner::Nac(Nac::with_statistics(
                    NacConfig::for_dof(&state.params.nac, dof),
                    stats,
                ))
            }
            LearnerState::Gpomdp(s) => Learner::Gpomdp(Gpomdp::with_trace(
                GpomdpConfig::for_dof(&state.params.gpomdp, dof),
                Vector2::from(s.z),
                s.steps,
                s.actor_updates,
            )),
        };
        let policy = LinearGaussian::new(Vector2::from(state.policy.gain), state.policy.sigma);
        Ok(Self::assemble(
            dof,
            state.params,
            state.cost,
            state.state_max,
            policy,
            learner,
            seed,
            (state.steps, state.episodes),
            state.safety,
        ))
    }

    #[allow(clippy::too_many_arguments)]
    fn assemble(
        dof: Dof,
        params: LearningParams,
        cost: QuadraticCost,
        state_max: [f64; 2],
        policy: LinearGaussian<2>,
        learner: CableLearner,
        seed: u64,
        (steps, episodes): (u64, u64),
        safety: SafetyState,
    ) -> Self {
        // gamma is the task's discount (NAC's), whichever algorithm learns: the failure is part of the
        // reward, and both algorithms must be scored on the same task.
        let failure_reward = failure_reward(&cost, state_max, params.nac.gamma);
        Agent {
            dof,
            params,
            cost,
            state_max,
            failure_reward,
            policy,
            learner,
            rng: StdRng::seed_from_u64(seed),
            pending: None,
            learning: true,
            steps,
            episodes,
            episode_return: 0.0,
            episode_steps: 0,
            guard: UpdateGuard::default(),
            safety,
            episode_refused: 0,
        }
    }

    /// One control step. `x` is the DOF's observed `(position, rate)`; it is clipped to the box here as
    /// well, so the features and the failure reward agree with the box. With [`StepStatus::Lost`], `x` is
    /// not used (perception has nothing to report). Otherwise a non-finite `x` aborts the episode
    /// (nothing is learned from it) and returns action 0.
    pub fn step(&mut self, x: [f64; 2], kind: StepStatus) -> Step {
        if kind != StepStatus::Lost && !(x[0].is_finite() && x[1].is_finite()) {
            tracing::warn!(dof = %self.dof, ?x, ?kind, "non-finite observation: episode aborted");
            return Step {
                action: 0.0,
                actor_updated: false,
                episode: self.abort_episode(),
            };
        }
        // clamp keeps NaN; a lost observation's x is never read, so that is harmless.
        let x = Vector2::new(
            x[0].clamp(-self.state_max[0], self.state_max[0]),
            x[1].clamp(-self.state_max[1], self.state_max[1]),
        );

        let mut actor_updated = false;
        if let Some(p) = self.pending.take() {
            let (reward, next) = match kind {
                StepStatus::Lost => (self.failure_reward, None),
                StepStatus::Running | StepStatus::TimeLimit => {
                    (self.cost.reward([p.x[0], p.x[1]], p.u_applied), Some(x))
                }
            };
            self.episode_return += reward;
            self.episode_steps += 1;
            self.steps += 1;
            if self.learning {
                let t = Transition {
                    x: p.x,
                    u: p.u_sampled,
                    reward,
                    next,
                };
                let before = self.gain();
                actor_updated = self.learner.update(&mut self.policy, &t);
                if actor_updated && self.guard.is_active() {
                    actor_updated = self.review(before);
                }
            }
        }

        match kind {
            StepStatus::Running => {
                let u = self.policy.sample(&x, &mut self.rng);
                let applied = if u.is_finite() {
                    u.clamp(-1.0, 1.0)
                } else {
                    // Only a diverged gain gets here; never send NaN to a thruster.
                    tracing::warn!(dof = %self.dof, gain = ?self.gain(), "non-finite action: applying 0");
                    0.0
                };
                self.pending = Some(Pending {
                    x,
                    u_sampled: u,
                    u_applied: applied,
                });
                Step {
                    action: applied,
                    actor_updated,
                    episode: None,
                }
            }
            StepStatus::Lost | StepStatus::TimeLimit => {
                let end = if kind == StepStatus::Lost {
                    EpisodeEnd::Lost
                } else {
                    EpisodeEnd::TimeLimit
                };
                Step {
                    action: 0.0,
                    actor_updated,
                    episode: self.finish_episode(end),
                }
            }
        }
    }

    /// Puts the learner's update from `before` to the policy's gain now before the guard; returns
    /// whether the policy changed.
    fn review(&mut self, before: [f64; 2]) -> bool {
        let bound = self.safety.action_change_bound;
        match self.guard.review(before, self.gain(), bound) {
            Review::Accepted { gain, bounded } => {
                self.policy.gain = gain.into();
                self.safety.bounded += bounded as u64;
                true
            }
            Review::Refused { proposed, radius } => {
                self.policy.gain = before.into();
                self.safety.refused += 1;
                self.episode_refused += 1;
                if self.episode_refused == 1 {
                    tracing::warn!(
                        dof = %self.dof,
                        gain = ?before,
                        ?proposed,
                        radius,
                        "actor update refused: the gain would leave the stable set of the identified model"
                    );
                }
                false
            }
        }
    }

    /// A control step without an observation (perception missed the cable in a frame although it is
    /// in view): returns the action to apply, 0 (hold still). The pending transition has no next
    /// state, so the learner does not see it; its reward (known from its start and its action) still
    /// counts in the episode's return. The eligibility trace is cleared, since the trajectory it
    /// follows is broken; the episode goes on, and the next observation starts a new transition.
    pub fn skip(&mut self) -> f64 {
        if let Some(p) = self.pending.take() {
            self.episode_return += self.cost.reward([p.x[0], p.x[1]], p.u_applied);
            self.episode_steps += 1;
            self.steps += 1;
            self.learner.end_episode();
        }
        0.0
    }

    /// Ends the current episode without learning from the pending transition (e.g. the simulator
    /// reset the vehicle without a terminal observation, or the service is stopping).
    /// Returns the episode's summary, or `None` if no action was taken in it.
    pub fn abort_episode(&mut self) -> Option<EpisodeSummary> {
        self.finish_episode(EpisodeEnd::Aborted)
    }

    fn finish_episode(&mut self, end: EpisodeEnd) -> Option<EpisodeSummary> {
        self.learner.end_episode();
        self.pending = None;
        let refused = std::mem::take(&mut self.episode_refused);
        if refused > 1 {
            tracing::warn!(
                dof = %self.dof,
                refused,
                gain = ?self.gain(),
                "actor updates refused in this episode by the stability guard"
            );
        }
        let steps = std::mem::take(&mut self.episode_steps);
        let return_ = std::mem::take(&mut self.episode_return);
        if steps == 0 {
            // E.g. the first observation after a reset already had the cable lost: nothing was done.
            return None;
        }
        self.episodes += 1;
        let summary = EpisodeSummary {
            episode: self.episodes,
            return_,
            steps,
            failed: end == EpisodeEnd::Lost,
            end,
            actor_updates: self.learner.actor_updates(),
            gain: self.gain(),
        };
        tracing::debug!(
            dof = %self.dof,
            episode = summary.episode,
            return_,
            steps,
            ?end,
            gain = ?summary.gain,
            "episode ended"
        );
        Some(summary)
    }

    /// Learns from now on as step two does on the vehicle ([`config::StepTwoParams`] of its
    /// parameters): NAC's eligibility rate becomes `step_two.lambda`.
    pub fn learn_as_on_the_vehicle(&mut self) {
        self.learner
            .set_eligibility_rate(self.params.step_two.lambda);
    }

    /// Turns learning on or off. Off, the agent acts (and accounts rewards and episodes) but its
    /// learner sees nothing.
    pub fn set_learning(&mut self, on: bool) {
        self.learning = on;
    }

    /// Whether the agent learns.
    pub fn is_learning(&self) -> bool {
        self.learning
    }

    /// Puts every actor update from now on before `guard` (the trust region and the stable set of
    /// step two); `UpdateGuard::default()` lets every update through.
    pub fn set_guard(&mut self, guard: UpdateGuard) {
        self.guard = guard;
    }

    /// Step two: adapts the trust region's bound (if there is a trust region) to how the last step
    /// fared: a learning trial that kept the cable within the envelope (`kept`), or a failure.
    pub fn adapt_trust_region(&mut self, kept: bool) {
        if let Some(tr) = &self.guard.trust_region {
            let bound = &mut self.safety.action_change_bound;
            *bound = tr.adapted(*bound, kept);
        }
    }

    /// The guard every actor update passes.
    pub fn guard(&self) -> &UpdateGuard {
        &self.guard
    }

    /// The safety layer's counts and the best policy evaluated so far.
    pub fn safety(&self) -> &SafetyState {
        &self.safety
    }

    /// The safety layer's state, for the behaviour's evaluations.
    pub fn safety_mut(&mut self) -> &mut SafetyState {
        &mut self.safety
    }

    /// Restarts the exploration noise from `seed` (an evaluation trial draws the same noise as the
    /// same trial of every other evaluation).
    pub fn reseed(&mut self, seed: u64) {
        self.rng = StdRng::seed_from_u64(seed);
    }

    /// Replaces the policy's gain by `gain` (a rollback to the best policy) and drops the learner's
    /// statistics, which were gathered under the replaced policy; its counters stay.
    pub fn restore(&mut self, gain: [f64; 2]) {
        self.policy.gain = Vector2::from(gain);
        self.learner.forget();
        self.pending = None;
    }

    /// The observation box `|x_i| <= state_max[i]`.
    pub fn state_max(&self) -> [f64; 2] {
        self.state_max
    }

    /// The policy gain `K` for (position, rate).
    pub fn gain(&self) -> [f64; 2] {
        self.policy.gain.into()
    }

    /// The mean (noise-free, clipped) action for `x`: the policy map of the paper's Figs. 6 and 7.
    pub fn mean_action(&self, x: [f64; 2]) -> f64 {
        self.policy.mean(&Vector2::from(x)).clamp(-1.0, 1.0)
    }

    /// The policy.
    pub fn policy(&self) -> &LinearGaussian<2> {
        &self.policy
    }

    /// The learner (for statistics: NAC's `v`, `w`, `A`...).
    pub fn learner(&self) -> &CableLearner {
        &self.learner
    }

    /// Which algorithm learns.
    pub fn algorithm(&self) -> Algorithm {
        self.learner.algorithm()
    }

    /// The DOF.
    pub fn dof(&self) -> Dof {
        self.dof
    }

    /// The learning parameters in force.
    pub fn params(&self) -> &LearningParams {
        &self.params
    }

    /// The reward of a lost cable (see [`failure_reward`]).
    pub fn failure_reward(&self) -> f64 {
        self.failure_reward
    }

    /// Transitions completed (learning or not).
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// Episodes completed.
    pub fn episodes(&self) -> u64 {
        self.episodes
    }

    /// Everything needed to resume this agent (the exploration noise's state and a pending transition
    /// are not kept: a resumed agent starts a new episode with a new seed).
    pub fn checkpoint(&self) -> AgentState {
        let learner = match &self.learner {
            Learner::Nac(n) => {
                let s = n.statistics();
                let theta = s.theta.as_slice();
                LearnerState::Nac(Box::new(NacState {
                    a: std::array::from_fn(|i| std::array::from_fn(|j| s.a[(i, j)])),
                    b: s.b.into(),
                    z: s.z.into(),
                    v: theta[..4].try_into().expect("4 basis functions"),
                    w: theta[4..].try_into().expect("2 gains"),
                    w_history: s.w_history.oldest_first().map(Into::into).collect(),
                    mass: s.mass,
                    steps: s.steps,
                    actor_updates: s.actor_updates,
                }))
            }
            Learner::Gpomdp(g) => LearnerState::Gpomdp(GpomdpState {
                z: (*g.z()).into(),
                steps: g.steps(),
                actor_updates: g.actor_updates(),
            }),
        };
        AgentState {
            dof: self.dof,
            params: self.params.clone(),
            cost: self.cost,
            state_max: self.state_max,
            policy: PolicyState {
                gain: self.gain(),
                sigma: self.policy.sigma,
            },
            learner,
            steps: self.steps,
            episodes: self.episodes,
            safety: self.safety,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nac::critic_features;
    use config::Rewards;
    use rand::Rng;
    use rand_distr::StandardNormal;

    const BOX: [f64; 2] = [0.5, 0.5];
    const SIGMA: f64 = 0.1;
    const GAMMA: f64 = 0.95;

    fn cost() -> QuadraticCost {
        Rewards::default().sway
    }

    fn agent(algorithm: Algorithm, gain: [f64; 2], seed: u64) -> Agent {
        let mut params = LearningParams::default();
        params.policy.initial_gain.sway = gain;
        Agent::new(Dof::Sway, algorithm, &params, cost(), BOX, seed)
    }

    fn nac(a: &Agent) -> &CableNac {
        match a.learner() {
            Learner::Nac(n) => n,
            Learner::Gpomdp(_) => panic!("not NAC"),
        }
    }

    /// The agent's `i`-th exploration draw for `seed` (one per Running step).
    fn noise(seed: u64, i: usize) -> f64 {
        let mut rng = StdRng::seed_from_u64(seed);
        (0..i).for_each(|_| {
            rng.sample::<f64, _>(StandardNormal);
        });
        rng.sample(StandardNormal)
    }

    /// `[phi(x); grad log pi(u|x)]` for a gain `k`.
    fn phi_hat(k: [f64; 2], x: [f64; 2], u: f64) -> SVector<f64, 6> {
        let mut f: SVector<f64, 6> = critic_features::<2, 6>(&Vector2::from(x));
        let g = LinearGaussian::new(Vector2::from(k), SIGMA).grad_log(&Vector2::from(x), u);
        f[4] = g[0];
        f[5] = g[1];
        f
    }

    fn phi(x: [f64; 2]) -> SVector<f64, 6> {
        critic_features::<2, 6>(&Vector2::from(x))
    }

    fn mean(k: [f64; 2], x: [f64; 2]) -> f64 {
        k[0] * x[0] + k[1] * x[1]
    }

    #[test]
    fn the_reward_uses_the_clipped_action_and_the_gradient_the_sampled_one() {
        // The mean action 10 * 0.3 = 3 is far outside [-1, 1]: applied 1, sampled about 3.
        let (seed, k) = (11, [10.0, 0.0]);
        let mut a = agent(Algorithm::Nac, k, seed);
        let (x0, x1) = ([0.3, 0.1], [0.25, 0.0]);
        assert_eq!(a.step(x0, StepStatus::Running).action, 1.0);
        let u_sampled = mean(k, x0) + SIGMA * noise(seed, 0);
        a.step(x1, StepStatus::Running);

        // The first transition alone: z = phi_hat, b = z r, A = z (phi_hat - gamma phi(x1))'.
        let n = nac(&a);
        let ph = phi_hat(k, x0, u_sampled);
        let r = cost().reward(x0, 1.0);
        assert!(r != cost().reward(x0, u_sampled));
        assert!(
            (n.z() - ph).norm() < 1e-12,
            "the score must be taken at the sampled action"
        );
        assert!(
            (n.b() - ph * r).norm() < 1e-12,
            "the reward must use the applied action"
        );
        assert!((n.a() - ph * (ph - GAMMA * phi(x1)).transpose()).norm() < 1e-10);
        // With the applied action in the score instead, z would differ.
        assert!((n.z() - phi_hat(k, x0, 1.0)).norm() > 1.0);
    }

    #[test]
    fn losing_the_cable_is_an_absorbing_failure() {
        let (seed, k) = (5, [-1.0, -0.5]);
        let mut a = agent(Algorithm::Nac, k, seed);
        let x0 = [0.2, -0.1];
        let applied = a.step(x0, StepStatus::Running).action;
        let u_sampled = mean(k, x0) + SIGMA * noise(seed, 0);
        assert_eq!(applied, u_sampled, "not clipped here");
        // Perception has nothing to say when the cable is lost: x is not used, even if NaN.
        let s = a.step([f64::NAN, f64::NAN], StepStatus::Lost);

        let r_fail = -(1.1 * 0.5 * 0.5 + 0.2 * 0.5 * 0.5 + 0.01) / (1.0 - GAMMA);
        assert!((a.failure_reward() - r_fail).abs() < 1e-12);
        assert_eq!(s.action, 0.0);
        let e = s.episode.expect("the episode ended");
        assert_eq!(
            (e.steps, e.failed, e.end, e.episode),
            (1, true, EpisodeEnd::Lost, 1)
        );
        assert_eq!(e.return_, a.failure_reward());

        let n = nac(&a);
        let ph = phi_hat(k, x0, u_sampled);
        assert!((n.b() - ph * r_fail).norm() < 1e-10);
        assert!(
            (n.a() - ph * ph.transpose()).norm() < 1e-10,
            "no bootstrap: no -gamma phi(x') term"
        );
        assert_eq!(
            *n.z(),
            SVector::<f64, 6>::zeros(),
            "the trace is reset at the episode's end"
        );

        // Nothing is pending any more: a second terminal observation is not an episode and teaches nothing.
        let (a_mat, b_vec) = (*n.a(), *n.b());
        assert!(a.step(x0, StepStatus::Lost).episode.is_none());
        assert!(a.step(x0, StepStatus::TimeLimit).episode.is_none());
        assert_eq!((*nac(&a).a(), *nac(&a).b()), (a_mat, b_vec));
        assert_eq!((a.steps(), a.episodes()), (1, 1));
    }

    #[test]
    fn a_time_limit_bootstraps_on_the_last_observation() {
        let (seed, k) = (8, [-1.0, -0.5]);
        let mut a = agent(Algorithm::Nac, k, seed);
        let (x0, x1) = ([0.2, -0.1], [0.1, -0.2]);
        let applied = a.step(x0, StepStatus::Running).action;
        let u_sampled = mean(k, x0) + SIGMA * noise(seed, 0);
        let s = a.step(x1, StepStatus::TimeLimit);
        let r = cost().reward(x0, applied);
        let e = s.episode.unwrap();
        assert_eq!(
            (s.action, e.steps, e.failed, e.end),
            (0.0, 1, false, EpisodeEnd::TimeLimit)
        );
        assert_eq!(e.return_, r);
        let ph = phi_hat(k, x0, u_sampled);
        assert!((nac(&a).a() - ph * (ph - GAMMA * phi(x1)).transpose()).norm() < 1e-10);
        assert!((nac(&a).b() - ph * r).norm() < 1e-12);
    }

    #[test]
    fn the_trace_restarts_with_each_episode() {
        let (seed, k) = (21, [-1.0, -0.5]);
        let mut a = agent(Algorithm::Nac, k, seed);
        for x in [[0.3, 0.0], [0.2, -0.1], [0.1, -0.1]] {
            a.step(x, StepStatus::Running);
        }
        assert!(nac(&a).z().norm() > 0.0);
        a.step([0.05, 0.0], StepStatus::TimeLimit);
        assert_eq!(*nac(&a).z(), SVector::<f64, 6>::zeros());

        // The next episode's first transition starts a fresh trace: z = phi_hat (times beta if the
        // actor was updated on that step), nothing of the previous episode.
        let y0 = [-0.2, 0.1];
        a.step(y0, StepStatus::Running);
        let k_now = a.gain();
        let u_sampled = mean(k_now, y0) + SIGMA * noise(seed, 3);
        let s = a.step([-0.15, 0.1], StepStatus::Running);
        let expect = phi_hat(k_now, y0, u_sampled) * if s.actor_updated { 0.9 } else { 1.0 };
        assert!((nac(&a).z() - expect).norm() < 1e-10);
    }

    /// A damped plant for closed-loop tests: position and rate respond to the action.
    fn plant(x: [f64; 2], u: f64) -> [f64; 2] {
        [
            (x[0] + 0.2 * x[1]).clamp(-0.5, 0.5),
            (0.95 * x[1] + 0.05 * u).clamp(-0.5, 0.5),
        ]
    }

    /// Runs `steps` control steps with episodes of 50 steps, resets from a fixed cycle of poses.
    fn run(a: &mut Agent, steps: usize) -> (Vec<f64>, Vec<EpisodeSummary>) {
        let starts: [[f64; 2]; 3] = [[0.3, 0.0], [-0.25, 0.1], [0.1, -0.2]];
        let (mut actions, mut episodes) = (Vec::new(), Vec::new());
        let mut x = starts[0];
        let mut t = 0;
        for i in 0..steps {
            let kind = if x[0].abs() >= 0.5 {
                StepStatus::Lost
            } else if t == 50 {
                StepStatus::TimeLimit
            } else {
                StepStatus::Running
            };
            let s = a.step(x, kind);
            actions.push(s.action);
            t += 1;
            x = plant(x, s.action);
            if let Some(e) = s.episode {
                episodes.push(e);
                x = starts[i % 3];
                t = 0;
            }
        }
        (actions, episodes)
    }

    #[test]
    fn a_seed_makes_a_run_reproducible() {
        for algorithm in Algorithm::ALL {
            let mut a = agent(algorithm, [-1.0, -0.5], 42);
            let mut b = agent(algorithm, [-1.0, -0.5], 42);
            let mut c = agent(algorithm, [-1.0, -0.5], 43);
            let (ra, rb, rc) = (run(&mut a, 2000), run(&mut b, 2000), run(&mut c, 2000));
            assert_eq!(ra, rb);
            assert_eq!(a.checkpoint(), b.checkpoint());
            assert_ne!(ra.0, rc.0);
        }
    }

    #[test]
    fn learning_off_acts_and_accounts_but_leaves_the_policy_and_learner_alone() {
        for algorithm in Algorithm::ALL {
            let k = [-1.0, -0.5];
            let mut a = agent(algorithm, k, 1);
            a.set_learning(false);
            let before = a.learner().clone();
            let (_, mut episodes) = run(&mut a, 2000);
            episodes.extend(a.abort_episode());
            assert_eq!(a.gain(), k);
            assert_eq!(*a.learner(), before);
            assert!(
                episodes.len() >= 30
                    && episodes
                        .iter()
                        .all(|e| e.return_ < 0.0 && e.actor_updates == 0)
            );
            assert_eq!(
                a.steps(),
                episodes.iter().map(|e| e.steps as u64).sum::<u64>()
            );
            assert_eq!(a.episodes(), episodes.len() as u64);
            a.set_learning(true);
            run(&mut a, 2000);
            assert_ne!(
                a.gain(),
                k,
                "{algorithm}: learning back on must move the gain"
            );
        }
    }

    #[test]
    fn the_episode_return_sums_the_rewards_of_the_applied_actions_and_the_failure() {
        for algorithm in Algorithm::ALL {
            for end in [StepStatus::Lost, StepStatus::TimeLimit] {
                let mut a = agent(algorithm, [4.0, 0.0], 3); // a large gain: most actions are clipped
                let xs = [[0.3, 0.1], [0.35, 0.2], [0.4, 0.3], [0.45, 0.4]];
                let mut want = 0.0_f64;
                let mut last = None;
                for x in xs {
                    if let Some((px, pu)) = last {
                        want += cost().reward(px, pu);
                    }
                    let u = a.step(x, StepStatus::Running).action;
                    assert!((-1.0..=1.0).contains(&u));
                    last = Some((x, u));
                }
                let (px, pu) = last.unwrap();
                want += if end == StepStatus::Lost {
                    a.failure_reward()
                } else {
                    cost().reward(px, pu)
                };
                let e = a.step([0.45, 0.45], end).episode.unwrap();
                assert!(
                    (e.return_ - want).abs() < 1e-12,
                    "{algorithm} {end:?}: {} vs {want}",
                    e.return_
                );
                assert_eq!((e.steps, e.episode, a.episodes()), (4, 1, 1));
                assert_eq!(e.actor_updates, a.learner().actor_updates());
                assert_eq!(e.gain, a.gain());
            }
        }
    }

    #[test]
    fn gpomdp_learns_from_the_failure_reward() {
        let (seed, k) = (9, [-1.0, -0.5]);
        let mut a = agent(Algorithm::Gpomdp, k, seed);
        let x0 = [0.2, -0.1];
        a.step(x0, StepStatus::Running);
        let u_sampled = mean(k, x0) + SIGMA * noise(seed, 0);
        a.step(x0, StepStatus::Lost);
        let g =
            LinearGaussian::new(Vector2::from(k), SIGMA).grad_log(&Vector2::from(x0), u_sampled);
        let alpha = *LearningParams::default().gpomdp.alpha.get(a.dof());
        let want = Vector2::from(k) + alpha * a.failure_reward() * g;
        assert!((Vector2::from(a.gain()) - want).norm() < 1e-12);
        let Learner::Gpomdp(l) = a.learner() else {
            panic!()
        };
        assert_eq!(
            *l.z(),
            Vector2::zeros(),
            "the trace is reset at the episode's end"
        );
    }

    #[test]
    fn observations_are_clipped_to_the_box_and_unusable_ones_abort_the_episode() {
        let (seed, k) = (4, [-1.0, -0.5]);
        let mut a = agent(Algorithm::Nac, k, seed);
        a.step([2.0, -3.0], StepStatus::Running);
        let u_sampled = mean(k, [0.5, -0.5]) + SIGMA * noise(seed, 0);
        a.step([0.4, -0.4], StepStatus::Running);
        assert!((nac(&a).z() - phi_hat(k, [0.5, -0.5], u_sampled)).norm() < 1e-10);

        let (a_mat, steps) = (*nac(&a).a(), a.steps());
        let s = a.step([f64::NAN, 0.0], StepStatus::Running);
        assert_eq!(s.action, 0.0);
        let e = s.episode.unwrap();
        assert_eq!((e.end, e.failed, e.steps), (EpisodeEnd::Aborted, false, 1));
        assert_eq!(
            (*nac(&a).a(), a.steps()),
            (a_mat, steps),
            "nothing learned from the dropped transition"
        );
        assert_eq!(*nac(&a).z(), SVector::<f64, 6>::zeros());
    }

    #[test]
    fn a_skipped_observation_teaches_nothing_but_counts_its_reward() {
        let (seed, k) = (6, [-1.0, -0.5]);
        let mut a = agent(Algorithm::Nac, k, seed);
        let (x0, x1, x2) = ([0.3, 0.0], [0.25, -0.1], [0.2, -0.1]);
        let u0 = a.step(x0, StepStatus::Running).action;
        a.step(x1, StepStatus::Running);
        let (a_mat, b_vec) = (*nac(&a).a(), *nac(&a).b());
        let u1 = a.pending.unwrap().u_applied;
        assert_eq!(a.skip(), 0.0);
        assert_eq!(
            (*nac(&a).a(), *nac(&a).b()),
            (a_mat, b_vec),
            "no next state: nothing learned"
        );
        assert_eq!(
            *nac(&a).z(),
            SVector::<f64, 6>::zeros(),
            "the trajectory is broken"
        );
        assert_eq!(a.skip(), 0.0, "a second miss has nothing pending");
        // The episode goes on from the next observation.
        let u2 = a.step(x2, StepStatus::Running).action;
        let e = a.step([0.15, -0.1], StepStatus::TimeLimit).episode.unwrap();
        let want = cost().reward(x0, u0) + cost().reward(x1, u1) + cost().reward(x2, u2);
        assert!((e.return_ - want).abs() < 1e-12);
        assert_eq!((e.steps, a.steps()), (3, 3));
    }

    #[test]
    fn a_resumed_agent_is_the_agent_that_was_saved() {
        for algorithm in Algorithm::ALL {
            let mut a = agent(algorithm, [-1.0, -0.5], 77);
            run(&mut a, 3000);
            a.abort_episode();
            let state = a.checkpoint();
            let mut b = Agent::from_state(state.clone(), 5).unwrap();
            assert_eq!(b.checkpoint(), state);
            assert_eq!(b.learner(), a.learner());
            assert_eq!(
                (b.gain(), b.steps(), b.episodes()),
                (a.gain(), a.steps(), a.episodes())
            );
            // Two resumptions with the same seed continue identically.
            let mut c = Agent::from_state(state.clone(), 5).unwrap();
            assert_eq!(run(&mut b, 500), run(&mut c, 500));

            let mut bad = state.clone();
            bad.state_max = [0.0, 1.0];
            assert!(Agent::from_state(bad, 1).is_err());
        }
    }
}
