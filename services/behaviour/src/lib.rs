//! A learned behaviour, sway or yaw, written once for either DOF: the binaries `sway-behaviour` and
//! `yaw-behaviour` are each a call to [`main`] with their [`Dof`](config::Dof).
//!
//! - [`core`]: the behaviour itself, plain structs and no IPC: a [`learning::Agent`] fed one
//!   [`CableObservationMsg`](messages::CableObservationMsg) per step, answering with the DOF's
//!   command and, at an episode's end, its learning statistics. It applies the very rule the
//!   in-process trainer applies ([`core::behave`]), so the mesh and the trainer give the same
//!   returns for a seed.
//! - [`step_two`]: step two's protocol on the vehicle: evaluation and learning trials, the safety
//!   guard on every actor update, keeping the best policy.
//! - [`store`]: the behaviour's own checkpoint file: resume from it, fall back to the previous one
//!   (`FILE.prev`) when it is refused, keep the previous one at every save.
//! - [`shell`]: the process: command line, ports, the wait loop, periodic and final saves.

pub mod core;
pub mod shell;
pub mod step_two;
pub mod store;

pub use crate::core::{Behaviour, Output, behave, new_agent, resume_seed};
pub use shell::{Args, main};
pub use step_two::{StepTwo, TrialKind, identified_model, session_trials, trial_kind};
pub use store::{CheckpointFile, Loaded, StoreError};
