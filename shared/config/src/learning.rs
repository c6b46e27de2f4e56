//! `learning.toml`: how the sway and yaw behaviours learn.

use crate::{Dof, Invalid, Validate, in_range, join, positive};
use serde::{Deserialize, Serialize};

/// A value for each learned DOF.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PerDof<T> {
    pub sway: T,
    pub yaw: T,
}

impl<T> PerDof<T> {
    pub fn both(value: T) -> Self
    where
        T: Clone,
    {
        PerDof {
            sway: value.clone(),
            yaw: value,
        }
    }

    pub fn get(&self, dof: Dof) -> &T {
        match dof {
            Dof::Sway => &self.sway,
            Dof::Yaw => &self.yaw,
        }
    }

    pub fn get_mut(&mut self, dof: Dof) -> &mut T {
        match dof {
            Dof::Sway => &mut self.sway,
            Dof::Yaw => &mut self.yaw,
        }
    }

    /// A value for each DOF, made by `f` (sway first).
    pub fn from_fn(mut f: impl FnMut(Dof) -> T) -> Self {
        PerDof {
            sway: f(Dof::Sway),
            yaw: f(Dof::Yaw),
        }
    }

    /// Each DOF's value through `f`.
    pub fn map<U>(&self, mut f: impl FnMut(Dof, &T) -> U) -> PerDof<U> {
        PerDof {
            sway: f(Dof::Sway, &self.sway),
            yaw: f(Dof::Yaw, &self.yaw),
        }
    }
}

/// A named set of learning parameters.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Preset {
    /// The values of `config/learning.toml` (learning rates chosen by `trainer sweep`, see docs/results.md).
    Default,
    /// The paper's values: NAC alpha = 0.01 for both DOFs.
    Paper,
}

impl std::str::FromStr for Preset {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "default" => Ok(Preset::Default),
            "paper" => Ok(Preset::Paper),
            other => Err(format!(
                "unknown preset `{other}` (expected `default` or `paper`)"
            )),
        }
    }
}

/// Policy and learner parameters for both behaviours.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LearningParams {
    pub policy: PolicyParams,
    pub nac: NacParams,
    pub gpomdp: GpomdpParams,
    /// Step two: how the behaviours evaluate their policy on the vehicle.
    pub evaluation: EvaluationParams,
    /// Step two: what keeps online learning on the vehicle safe.
    pub safety: SafetyParams,
    /// Step two: how the learner itself differs on the vehicle.
    pub step_two: StepTwoParams,
}

impl LearningParams {
    /// These parameters with a preset applied.
    pub fn with_preset(mut self, preset: Preset) -> Self {
        if preset == Preset::Paper {
            self.nac.alpha = PerDof::both(0.01);
        }
        self
    }
}

impl Validate for LearningParams {
    fn validate(&self, key: &str) -> Result<(), Invalid> {
        self.policy.validate(&join(key, "policy"))?;
        self.nac.validate(&join(key, "nac"))?;
        self.gpomdp.validate(&join(key, "gpomdp"))?;
        self.evaluation.validate(&join(key, "evaluation"))?;
        self.safety.validate(&join(key, "safety"))?;
        self.step_two.validate(&join(key, "step_two"))?;
        if self.safety.rollback.enabled && self.evaluation.trials == 0 {
            return Err(Invalid::new(
                join(key, "safety.rollback.enabled"),
                true,
                "keeping the best policy needs evaluations: set evaluation.trials > 0 or turn it off",
            ));
        }
        Ok(())
    }
}

/// The linear Gaussian policy `u ~ N(Kx, sigma^2)`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PolicyParams {
    pub sigma: f64,
    /// K at the start of step one, for (position, rate).
    pub initial_gain: PerDof<[f64; 2]>,
}

impl Default for PolicyParams {
    fn default() -> Self {
        PolicyParams {
            sigma: 0.1,
            initial_gain: PerDof::both([0.0, 0.0]),
        }
    }
}

impl Validate for PolicyParams {
    fn validate(&self, key: &str) -> Result<(), Invalid> {
        in_range(key, "sigma", self.sigma, 1e-4, 10.0)?;
        for dof in Dof::ALL {
            for (i, k) in self.initial_gain.get(dof).iter().enumerate() {
                in_range(key, &format!("initial_gain.{dof}[{i}]"), *k, -1e3, 1e3)?;
            }
        }
        Ok(())
    }
}

/// The longest history of natural gradients the angle test can look back on (`tau + 1 <= this`).
pub const MAX_ANGLE_LAG: usize = 64;

/// The Natural Actor-Critic with LSTD-Q(lambda) (paper, Algorithm 1).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NacParams {
    /// Actor learning rate, per DOF (the rewards of sway and yaw differ in scale).
    pub alpha: PerDof<f64>,
    /// Forgetting factor applied to the critic's statistics after each actor update.
    pub beta: f64,
    /// Discount factor.
    pub gamma: f64,
    /// Eligibility rate.
    pub lambda: f64,
    /// The actor updates only when the natural gradient is within this angle of the one `tau` steps
    /// earlier (paper: the angle between w_{t+1} and w_{t-tau}).
    pub epsilon_deg: f64,
    /// The lag of the angle test, in steps beyond the previous one: 0 compares consecutive estimates.
    /// Consecutive estimates share almost all their statistics and agree even when both are noise; a
    /// lag compares estimates from different data, so the actor waits until the gradient is consistent.
    pub tau: u32,
    /// Tikhonov regularisation of the critic's solve, relative to the scale of A: A is singular at first.
    pub ridge: f64,
    /// Levenberg-Marquardt damping of the natural gradient, per transition in the statistics: adds
    /// `damping * (transitions, forgotten like A)` to the diagonal of A's natural-gradient block, so a
    /// gain the data say little about (a barely excited state) is not moved on noise. 0 is off.
    pub damping: f64,
}

impl Default for NacParams {
    fn default() -> Self {
        NacParams {
            // Chosen by `trainer sweep --algorithm nac --runs 100 --episodes 100` (docs/results.md).
            alpha: PerDof::both(2.15),
            beta: 0.9,
            gamma: 0.95,
            lambda: 0.8,
            epsilon_deg: 1.0,
            tau: 0,
            ridge: 1e-6,
            damping: 0.1,
        }
    }
}

impl Validate for NacParams {
    fn validate(&self, key: &str) -> Result<(), Invalid> {
        positive(key, "alpha.sway", self.alpha.sway)?;
        positive(key, "alpha.yaw", self.alpha.yaw)?;
        in_range(key, "beta", self.beta, 0.0, 1.0)?;
        in_range(key, "gamma", self.gamma, 0.0, 0.9999)?;
        in_range(key, "lambda", self.lambda, 0.0, 1.0)?;
        in_range(key, "epsilon_deg", self.epsilon_deg, 0.0, 180.0)?;
        in_range(key, "tau", self.tau as f64, 0.0, (MAX_ANGLE_LAG - 1) as f64)?;
        in_range(key, "ridge", self.ridge, 0.0, 1.0)?;
        in_range(key, "damping", self.damping, 0.0, 1.0e6)
    }
}

/// Baxter and Bartlett's policy gradient (OLPOMDP, the online form of GPOMDP): the Fig. 5 baseline.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GpomdpParams {
    /// Step size, per DOF.
    pub alpha: PerDof<f64>,
    /// Discount of the eligibility trace (the bias-variance knob of GPOMDP).
    pub beta: f64,
}

impl Default for GpomdpParams {
    fn default() -> Self {
        GpomdpParams {
            // Chosen by `trainer sweep --algorithm gpomdp --runs 100 --episodes 100` (docs/results.md).
            alpha: PerDof {
                sway: 0.01,
                yaw: 0.0046,
            },
            beta: 0.95,
        }
    }
}

impl Validate for GpomdpParams {
    fn validate(&self, key: &str) -> Result<(), Invalid> {
        positive(key, "alpha.sway", self.alpha.sway)?;
        positive(key, "alpha.yaw", self.alpha.yaw)?;
        in_range(key, "beta", self.beta, 0.0, 1.0)
    }
}

/// Step two's evaluations: the behaviours alternate `trials` evaluation trials, in which the policy
/// acts without learning, and `learning_trials` learning trials, starting with an evaluation (the
/// policy they were given). In evaluation trial `j` of every evaluation the exploration noise is the
/// same stream, so the returns of two evaluations differ by the policies only (common random numbers);
/// an evaluation is one round of the vehicle's start marks (the twin's `trials.cycle`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EvaluationParams {
    /// Evaluation trials per evaluation; 0: no evaluations, every trial learns.
    pub trials: u32,
    /// Learning trials between two evaluations.
    pub learning_trials: u32,
}

impl Default for EvaluationParams {
    fn default() -> Self {
        EvaluationParams {
            trials: 5,
            learning_trials: 5,
        }
    }
}

impl Validate for EvaluationParams {
    fn validate(&self, key: &str) -> Result<(), Invalid> {
        in_range(key, "trials", self.trials as f64, 0.0, 1.0e4)?;
        in_range(
            key,
            "learning_trials",
            self.learning_trials as f64,
            1.0,
            1.0e6,
        )
    }
}

/// The learner on the vehicle (step two), where it differs from simulation.
///
/// `lambda` replaces NAC's eligibility rate (`nac.lambda`) for step two. In simulation the observation
/// is the state of the model the learner was tuned on; on the vehicle it is not: the thrusters lag, a
/// frame arrives a period late, and perception's filter smooths what it reports. LSTD-Q's estimate of
/// the natural gradient then leans on the critic's values of states that do not tell the whole
/// story, and the shorter the eligibility, the more: with images on the twin, at `lambda` 0.8 the
/// yaw gain of some seeds moves away from the twin's limit; at 1 (returns, not bootstrapped values)
/// it moves towards it. The default is 1 (DESIGN.md, "The learner on the vehicle"); a checkpoint
/// saved before step two had a rate of its own loads with it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StepTwoParams {
    /// NAC's eligibility rate in step two, in [0, 1].
    pub lambda: f64,
}

impl Default for StepTwoParams {
    fn default() -> Self {
        StepTwoParams { lambda: 1.0 }
    }
}

impl Validate for StepTwoParams {
    fn validate(&self, key: &str) -> Result<(), Invalid> {
        in_range(key, "lambda", self.lambda, 0.0, 1.0)
    }
}

/// Step two's safety layer, each part switchable: a bound on every actor update, a guard keeping the
/// gains in a set the identified model says is stable with a margin, and keeping the best policy.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SafetyParams {
    pub trust_region: TrustRegionParams,
    pub stability: StabilityParams,
    pub rollback: RollbackParams,
}

impl Validate for SafetyParams {
    fn validate(&self, key: &str) -> Result<(), Invalid> {
        let k = join(key, "trust_region");
        let tr = &self.trust_region;
        positive(&k, "max_action_change", tr.max_action_change)?;
        in_range(&k, "max_action_change", tr.max_action_change, 0.0, 100.0)?;
        positive(&k, "min_action_change", tr.min_action_change)?;
        if tr.min_action_change > tr.max_action_change {
            return Err(Invalid::new(
                join(&k, "min_action_change"),
                tr.min_action_change,
                format!(
                    "must be at most max_action_change ({}); for a fixed bound set the two equal",
                    tr.max_action_change
                ),
            ));
        }
        let k = join(key, "stability");
        in_range(&k, "gain_margin", self.stability.gain_margin, 1.0, 100.0)?;
        in_range(
            &k,
            "delay_frames",
            self.stability.delay_frames as f64,
            0.0,
            MAX_GUARD_DELAY as f64,
        )?;
        in_range(&k, "max_radius", self.stability.max_radius, 0.0, 1.0)?;
        positive(&k, "max_radius", self.stability.max_radius)?;
        in_range(
            &join(key, "rollback"),
            "tolerance",
            self.rollback.tolerance,
            0.0,
            10.0,
        )
    }
}

/// The longest extra delay the stability guard can assume, in control periods.
pub const MAX_GUARD_DELAY: u32 = 10;

/// A trust region on each actor update: the mean action may change by at most the bound in force
/// anywhere in the observation box, `|dK_0| m_0 + |dK_1| m_1 <= bound` (a longer step is shortened
/// along its direction). With the policy's fixed sigma, that bounds the largest KL divergence
/// between successive policies over the box by `bound^2 / (2 sigma^2)`.
///
/// The bound adapts as a trust-region radius does: it starts at `min_action_change`, doubles after
/// each learning trial that kept the cable within the safety envelope, and halves after each
/// failure (the cable lost, the envelope left), never outside `[min_action_change,
/// max_action_change]`. Equal, the bound is fixed.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrustRegionParams {
    pub enabled: bool,
    pub max_action_change: f64,
    pub min_action_change: f64,
}

/// The stability guard: an actor update is refused when its gain leaves the set in which the
/// identified linear model of the DOF (discretised at the sample time), with the loop gain times
/// `gain_margin` and `delay_frames` periods of extra delay, has a closed-loop spectral radius of at
/// most `max_radius`; a gain already outside may only move towards it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StabilityParams {
    pub enabled: bool,
    pub gain_margin: f64,
    pub delay_frames: u32,
    pub max_radius: f64,
}

/// Keep the best: after every evaluation, a policy whose evaluated return is worse than the best so
/// far by more than `tolerance` times the best's magnitude is replaced by the best, and learning goes
/// on from there (its statistics, gathered under the replaced policy, are dropped).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RollbackParams {
    pub enabled: bool,
    pub tolerance: f64,
}

impl Default for TrustRegionParams {
    fn default() -> Self {
        TrustRegionParams {
            enabled: true,
            max_action_change: 0.5,
            min_action_change: 0.5,
        }
    }
}

impl Default for StabilityParams {
    fn default() -> Self {
        StabilityParams {
            enabled: true,
            gain_margin: 2.0,
            delay_frames: 1,
            max_radius: 1.0,
        }
    }
}

impl Default for RollbackParams {
    fn default() -> Self {
        RollbackParams {
            enabled: true,
            tolerance: 0.02,
        }
    }
}
