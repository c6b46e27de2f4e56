//! What every learning rule sees: one transition at a time, and the end of each episode.
//!
//! [`PolicyLearner`] is the interface the agent and the tests drive; [`Learner`] is the closed set the
//! agent can hold (and a checkpoint can name), so a step is a `match`, not a virtual call.

use crate::gpomdp::Gpomdp;
use crate::nac::Nac;
use crate::policy::LinearGaussian;
use nalgebra::SVector;

/// One transition `(x, u, r, x')` as the learner sees it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Transition<const S: usize> {
    /// The state the action was chosen in.
    pub x: SVector<f64, S>,
    /// The action as *sampled* from the policy (before clipping): the score is taken here.
    pub u: f64,
    /// The reward of the transition (computed by the caller, e.g. from the applied action).
    pub reward: f64,
    /// The next state, or `None` when the transition ends in an absorbing state (no bootstrap).
    pub next: Option<SVector<f64, S>>,
}

/// A rule that improves a [`LinearGaussian`] policy from transitions.
pub trait PolicyLearner<const S: usize> {
    /// Learns from one transition, possibly changing `policy`. Returns `true` when the actor was updated.
    ///
    /// The transition's action must have been sampled from `policy` as it is now.
    fn update(&mut self, policy: &mut LinearGaussian<S>, transition: &Transition<S>) -> bool;

    /// The episode is over: eligibility traces are cleared (other statistics persist).
    fn end_episode(&mut self);

    /// Transitions learned from so far.
    fn steps(&self) -> u64;

    /// Actor (policy) updates so far.
    fn actor_updates(&self) -> u64;
}

/// The learning algorithms an agent can run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Algorithm {
    /// Natural Actor-Critic with LSTD-Q(lambda) (paper, Algorithm 1).
    Nac,
    /// Baxter and Bartlett's OLPOMDP (online GPOMDP): the paper's Fig. 5 baseline.
    Gpomdp,
}

impl Algorithm {
    /// Both algorithms.
    pub const ALL: [Algorithm; 2] = [Algorithm::Nac, Algorithm::Gpomdp];

    /// The lowercase name used in files and on command lines.
    pub fn name(self) -> &'static str {
        match self {
            Algorithm::Nac => "nac",
            Algorithm::Gpomdp => "gpomdp",
        }
    }
}

impl std::fmt::Display for Algorithm {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Algorithm {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "nac" => Ok(Algorithm::Nac),
            "gpomdp" | "olpomdp" => Ok(Algorithm::Gpomdp),
            other => Err(format!(
                "unknown algorithm `{other}` (expected `nac` or `gpomdp`)"
            )),
        }
    }
}

/// Either learner, for an `S`-dimensional state (`N` is NAC's size, see [`Nac`]).
#[derive(Clone, Debug, PartialEq)]
pub enum Learner<const S: usize, const N: usize> {
    /// Natural Actor-Critic.
    Nac(Nac<S, N>),
    /// OLPOMDP.
    Gpomdp(Gpomdp<S>),
}

impl<const S: usize, const N: usize> Learner<S, N> {
    /// Which algorithm this is.
    pub fn algorithm(&self) -> Algorithm {
        match self {
            Learner::Nac(_) => Algorithm::Nac,
            Learner::Gpomdp(_) => Algorithm::Gpomdp,
        }
    }

    /// Transitions learned from so far.
    pub fn steps(&self) -> u64 {
        PolicyLearner::steps(self)
    }

    /// Actor (policy) updates so far.
    pub fn actor_updates(&self) -> u64 {
        PolicyLearner::actor_updates(self)
    }

    /// Sets NAC's eligibility rate from now on; OLPOMDP has none (its trace discount is its own).
    pub fn set_eligibility_rate(&mut self, lambda: f64) {
        if let Learner::Nac(l) = self {
            l.set_lambda(lambda);
        }
    }

    /// Drops what was learned about the current policy (NAC's statistics, OLPOMDP's trace), as if
    /// nothing had been seen; the counters of transitions and actor updates stay.
    pub fn forget(&mut self) {
        match self {
            Learner::Nac(l) => l.forget(),
            Learner::Gpomdp(l) => l.end_episode(),
        }
    }
}

impl<const S: usize, const N: usize> PolicyLearner<S> for Learner<S, N> {
    #[inline]
    fn update(&mut self, policy: &mut LinearGaussian<S>, transition: &Transition<S>) -> bool {
        match self {
            Learner::Nac(l) => l.update(policy, transition),
            Learner::Gpomdp(l) => l.update(policy, transition),
        }
    }

    fn end_episode(&mut self) {
        match self {
            Learner::Nac(l) => l.end_episode(),
            Learner::Gpomdp(l) => l.end_episode(),
        }
    }

    fn steps(&self) -> u64 {
        match self {
            Learner::Nac(l) => l.steps(),
            Learner::Gpomdp(l) => l.steps(),
        }
    }

    fn actor_updates(&self) -> u64 {
        match self {
            Learner::Nac(l) => l.actor_updates(),
            Learner::Gpomdp(l) => l.actor_updates(),
        }
    }
}
