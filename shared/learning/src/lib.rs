//! How the sway and yaw behaviours learn (paper, section II and III-C).
//!
//! - [`policy`]: the actor, a linear Gaussian policy `u ~ N(Kx, sigma^2)`.
//! - [`nac`]: the Natural Actor-Critic with LSTD-Q(lambda) (Algorithm 1).
//! - [`gpomdp`]: Baxter and Bartlett's OLPOMDP, the Fig. 5 baseline.
//! - [`learner`]: the transition interface both learners share.
//! - [`agent`]: one learned DOF as a behaviour sees it: observe, act, learn, report episodes.
//! - [`checkpoint`]: what step one hands to step two, in a checked, atomically written file.
//! - [`lqr`]: exact discretisation and discounted LQR, the optimum a linear policy should approach.
//! - [`safety`]: step two's safety layer: a trust region on each actor update, a stability guard,
//!   keeping the best policy.
//!
//! No IPC and no files except checkpoints: the behaviour services and the in-process trainer call this.

#![warn(missing_docs)]

pub mod agent;
pub mod checkpoint;
pub mod gpomdp;
pub mod learner;
pub mod lqr;
pub mod nac;
pub mod policy;
pub mod safety;

#[cfg(test)]
mod testkit;

pub use agent::{Agent, CableLearner, CableNac, EpisodeEnd, EpisodeSummary, Step, failure_reward};
pub use checkpoint::{
    AgentState, AgentStateError, Checkpoint, CheckpointError, Corruption, LearnerState,
};
pub use config::StepStatus;
pub use gpomdp::{Gpomdp, GpomdpConfig};
pub use learner::{Algorithm, Learner, PolicyLearner, Transition};
pub use nac::{GradientHistory, Nac, NacConfig, NacStatistics};
pub use policy::LinearGaussian;
pub use safety::{
    BestPolicy, Evaluated, KeepBest, Review, SafetyState, StableSet, TrustRegion, UpdateGuard,
    Verdict, action_costs, pair_scale, pair_score, state_costs,
};
