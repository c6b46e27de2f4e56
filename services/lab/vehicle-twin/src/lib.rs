//! The vehicle twin: the plant behind the vehicle endpoint's hardware adapters (DESIGN.md,
//! "Endpoints" and "The reality gap"). This machine has no vehicle; the twin stands in for it with
//! a higher-fidelity plant and camera than the simulator's, each difference switchable in
//! `config/twin.toml` ([`config::TwinParams`]).
//!
//! - [`plant`]: [`TwinPlant`], the reality gap's dynamics: quadratic damping, thrusters with a dead
//!   band, forward/reverse asymmetry and a first-order lag, a water current.
//! - [`twin`]: [`Twin`], the hardware as the vehicle sees it: a camera mounted off the centre of
//!   rotation taking a frame every control period (harsher images, dropped frames), thrusters that
//!   hold their last setpoints until a watchdog stops them, and trials as on the real vehicle (90 s
//!   or until the cable is lost, then a reposition).
//! - [`driver`]: the pacing of the `vehicle-twin` process: real time (5 Hz; `--speed K` times
//!   faster) or lockstep with the mesh (`--lockstep`, deterministic, with a deadline).
//! - [`latency`]: the camera-to-thruster latency as the hardware sees it (`--latency FILE`).
//!
//! The `vehicle-twin` binary publishes the twin's frames on `cabletrack/twin/frame` and takes the
//! setpoints from `cabletrack/twin/thrusters` (`adapters::twin`); the vehicle endpoint's camera and
//! thruster driver reach them through their frame source and thruster sink.

pub mod ardusub;
pub mod driver;
pub mod latency;
pub mod plant;
pub mod twin;

pub use plant::{ThrusterModel, TwinPlant};
pub use twin::{Autopilot, Shot, TrialEnd, Twin, TwinError, TwinEye};
