//! The IPC contract: read this first to know what the processes say to each other.
//!
//! Every topic is an iceoryx2 publish-subscribe service of fixed-layout (`#[repr(C)]`) payloads plus
//! an event service of the same name: a publish is followed by a notification, which wakes the
//! subscribers blocked in their WaitSet. Topic names carry the endpoint:
//! `cabletrack/<sim|vehicle>/<topic>`, so the simulated mesh and the vehicle never see each other.
//!
//! ```text
//!  simulator ──VehicleState──▶ camera ──CameraFrame──▶ perception ──CableObservation──┬─▶ sway ─┐
//!      ▲                                                                               ├─▶ yaw ──┤ DofCommand
//!      │                                                                               └─▶ surge ┘
//!      └──────────────────ThrusterSetpoints◀──────── thruster-allocator ◀─────────────────────────┘
//! ```
//!
//! Every payload of the control loop starts with a [`Stamp`]: the step's sequence number (increasing
//! across episodes within the producer's epoch), its epoch, its episode and step, its time, the
//! vehicle clock when it was taken (on the vehicle endpoint), and the episode status. A consumer
//! matches inputs by epoch and `seq`, never mixes steps, and refuses stale or absurd stamps
//! (`runtime::screen::Screen`).
//!
//! Setpoints are either a step's answer or a failsafe stop ([`ThrusterSetpoints::stop`],
//! [`StopCause`]): the thruster driver's, which drives the thrusters to 0. Beside the loop, the
//! supervisor reports what happens to the services ([`SupervisorEvent`]) and the flight recorder its
//! progress ([`RecorderStatus`]); these belong to no step and carry the wall clock instead. On a
//! vehicle piloted through an ArduSub autopilot, the thruster driver publishes the autopilot's
//! telemetry ([`AutopilotState`], [`AutopilotAttitude`], [`AutopilotDepth`], [`ServoOutputs`],
//! [`StatusText`], topics `autopilot/...`): no step's either, timed by the vehicle clock.
//!
//! Below the endpoints lies the hardware level ([`topics::hardware`]): the vehicle twin's camera and
//! thrusters, `cabletrack/twin/<topic>`, reached only through the vehicle endpoint's adapters.
//!
//! QoS is fixed here, for every process: iceoryx2 takes a service's QoS from whichever process creates
//! it first, so the services are only ever opened through [`ports`].

pub mod json;
pub mod payload;
pub mod ports;
pub mod topics;

pub use payload::{
    AutopilotAttitude, AutopilotDepth, AutopilotState, CableObservationData, CableObservationMsg,
    CameraFrameHeader, DofCommand, LearningStats, Mission, MissionCommand, RecorderStatus,
    SERVO_CHANNELS, STATUS_TEXT_LEN, ServiceEvent, ServoOutputs, SetpointsForm, Stamp, Stamped,
    StatusText, StepStatus, StopCause, SupervisorEvent, ThrusterSetpoints, VehicleStateMsg,
    VideoUnit, ardusub_mode_name,
};
pub use ports::{
    FrameInbox, FrameOutbox, FrameTap, Heartbeat, Inbox, Outbox, PortError, Tap, VideoInbox,
    VideoOutbox, VideoTap,
};
pub use topics::{Endpoint, Qos, Topic};
