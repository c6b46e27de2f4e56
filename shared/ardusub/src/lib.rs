//! The thruster sink of a vehicle under ArduSub (a BlueROV2): the stack pilots the autopilot over
//! MAVLink the way a companion computer does, in the thruster driver's place of the twin's thrusters
//! (`thruster-driver --sink ardusub:URL`). README.md has the wire, the parameters ArduSub must have
//! and what the pilot gain does.
//!
//! The allocator's setpoints are turned back into the generalised forces they make with the
//! scenario's layout (`model::ThrusterLayout::forces`): what the behaviours and the surge rule
//! decided per DOF. ArduSub's own mixer then drives its thrusters from MANUAL_CONTROL's axes: x
//! surge, y sway, r yaw, each the DOF's force divided by what a full axis gives
//! ([`pilot`]). The failsafe is the driver's ([`adapters::failsafe::Failsafe`]): a stop is neutral
//! sticks, held; and ArduSub's pilot-input failsafe stops the vehicle when the driver stops sending.
//!
//! - [`companion`]: the whole conversation as a state machine (no sockets, no clock), with
//!   [`autopilot`] (its heartbeat), [`params`] (what is read and checked), [`command`] (a command
//!   carried to its end), [`pilot`] (the stick) and [`telemetry`] (what comes back, for the mesh).
//! - [`wire`]: MAVLink frames, counting what is refused; [`link`]: the UDP or TCP socket.
//! - [`ArduSubSink`]: the shell over both, a [`adapters::ThrusterSink`].

pub mod autopilot;
pub mod command;
pub mod companion;
pub mod link;
pub mod params;
pub mod pilot;
pub mod sink;
pub mod spec;
pub mod telemetry;
pub mod wire;

pub use companion::{Companion, Event, STEP_TAG, STOP_TAG};
pub use sink::{ArduSubSink, Publishers};
pub use spec::{Arming, Mode, Options, Spec, Timing, Url};

use adapters::AdapterError;

/// Why the sink could not be opened or could not do its job.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(transparent)]
    Adapter(#[from] AdapterError),
    #[error("ArduSub link {url}: cannot {what}")]
    Link {
        url: String,
        what: String,
        #[source]
        source: std::io::Error,
    },
    #[error("the ArduSub autopilot at {url}")]
    Autopilot {
        url: String,
        #[source]
        source: companion::Error,
    },
    #[error(transparent)]
    Port(#[from] messages::PortError),
}

impl From<Error> for AdapterError {
    fn from(e: Error) -> Self {
        match e {
            Error::Adapter(e) => e,
            Error::Port(e) => AdapterError::Port(e),
            e => AdapterError::Device {
                adapter: "ArduSub".into(),
                source: Box::new(e),
            },
        }
    }
}
