//! The payloads: `#[repr(C)]`, `ZeroCopySend`, with a stable, versioned type name (a process built
//! from older code refuses to connect instead of misreading the bytes). Each also derives its JSON
//! form and JSON Schema ([`crate::json`]): the doc comments of a payload's fields are its schema's
//! descriptions, so they say what a reader of a record needs (units, frames, meanings of codes).

use crate::json::{
    EventKind, Flag, NumberOrNull, NumbersOrNull, StepStatusCode, StopCauseCode, Text,
};
use iceoryx2::prelude::*;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

pub use config::StepStatus;

/// The step a message belongs to. Copied unchanged from the step's first message (the simulator's
/// vehicle state, the vehicle camera's frame) through every stage, so every consumer judges it alike
/// (`runtime::screen::Screen`).
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend, Serialize, Deserialize, JsonSchema,
)]
#[repr(C)]
#[type_name("cabletrack::Stamp/3")]
pub struct Stamp {
    /// Sequence number of the control step, increasing within the producer's epoch.
    pub seq: u64,
    /// Time of the step (ns): simulated time on the sim endpoint; on the vehicle the frame source's
    /// clock (the twin matches the setpoints answering a frame by it).
    pub time_ns: u64,
    /// The vehicle clock (ns) when the step was taken (the camera read its frame): the monotonic
    /// clock plus the producer's offset, signed, since a clock behind by more than the machine's
    /// uptime reads below zero and must still show its pace. 0 on the sim endpoint, whose lockstep
    /// runs on simulated time: an untimed stamp is never judged by its age.
    #[serde(default)]
    pub clock_ns: i64,
    /// The session of the process that numbered `seq`, new at each start: a restarted producer's
    /// steps start a new epoch, which consumers accept instead of taking its `seq` for an old one.
    /// 0: no epoch.
    #[serde(default)]
    pub epoch: u32,
    /// The episode (a trial on the vehicle), from 0.
    pub episode: u32,
    /// Step within the episode, 0 at the reset.
    pub step: u32,
    /// The episode's status at this step (`StepStatus` as u8): 0 running, 1 cable lost, 2 time
    /// limit.
    #[schemars(with = "StepStatusCode")]
    pub status: u8,
    #[serde(skip)]
    pub _reserved: [u8; 3],
}

impl Stamp {
    /// An untimed stamp of no epoch (the sim endpoint's; tests).
    pub fn new(seq: u64, time_ns: u64, episode: u32, step: u32, status: StepStatus) -> Self {
        Stamp {
            seq,
            time_ns,
            clock_ns: 0,
            epoch: 0,
            episode,
            step,
            status: status as u8,
            _reserved: [0; 3],
        }
    }

    /// The same step, taken at `clock_ns` on the vehicle clock in the producer's `epoch`.
    pub fn timed(self, epoch: u32, clock_ns: i64) -> Self {
        Stamp {
            epoch,
            clock_ns,
            ..self
        }
    }

    /// Whether the stamp carries the vehicle clock (the vehicle endpoint's stamps do).
    pub fn is_timed(&self) -> bool {
        self.clock_ns != 0
    }

    /// The step's status; an unknown value (a corrupt or newer message) reads as `Lost`: the safe end.
    pub fn status(&self) -> StepStatus {
        StepStatus::from_u8(self.status).unwrap_or(StepStatus::Lost)
    }
}

/// The vehicle's state and the pose's rate (current included). The pool frame: x along the pool, y
/// to the right seen from above, psi from x towards y.
#[derive(
    Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize, Deserialize, JsonSchema,
)]
#[repr(C)]
#[type_name("cabletrack::VehicleState/3")]
pub struct VehicleStateMsg {
    pub stamp: Stamp,
    /// Position along the pool, m.
    #[serde(with = "NumberOrNull")]
    pub x: f64,
    /// Position across the pool, m.
    #[serde(with = "NumberOrNull")]
    pub y: f64,
    /// Heading, rad.
    #[serde(with = "NumberOrNull")]
    pub psi: f64,
    /// Surge velocity, m/s.
    #[serde(with = "NumberOrNull")]
    pub u: f64,
    /// Sway velocity, m/s.
    #[serde(with = "NumberOrNull")]
    pub v: f64,
    /// Yaw rate, rad/s.
    #[serde(with = "NumberOrNull")]
    pub r: f64,
    /// dx/dt, m/s (current included).
    #[serde(with = "NumberOrNull")]
    pub x_rate: f64,
    /// dy/dt, m/s (current included).
    #[serde(with = "NumberOrNull")]
    pub y_rate: f64,
    /// dpsi/dt, rad/s.
    #[serde(with = "NumberOrNull")]
    pub psi_rate: f64,
}

impl VehicleStateMsg {
    pub fn new(stamp: Stamp, state: &model::VehicleState, rate: &model::PoseRate) -> Self {
        VehicleStateMsg {
            stamp,
            x: state.pose.x,
            y: state.pose.y,
            psi: state.pose.psi,
            u: state.velocity.u,
            v: state.velocity.v,
            r: state.velocity.r,
            x_rate: rate.x,
            y_rate: rate.y,
            psi_rate: rate.psi,
        }
    }

    pub fn state(&self) -> model::VehicleState {
        model::VehicleState {
            pose: self.pose(),
            velocity: model::Velocity {
                u: self.u,
                v: self.v,
                r: self.r,
            },
        }
    }

    pub fn pose(&self) -> model::Pose {
        model::Pose {
            x: self.x,
            y: self.y,
            psi: self.psi,
        }
    }

    pub fn pose_rate(&self) -> model::PoseRate {
        model::PoseRate {
            x: self.x_rate,
            y: self.y_rate,
            psi: self.psi_rate,
        }
    }
}

/// A cable observation's numbers as carried in messages (`model::CableObservation` in `#[repr(C)]`):
/// perception's estimate in [`CableObservationMsg`], the geometric camera's truth in
/// [`CameraFrameHeader`].
#[derive(
    Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize, Deserialize, JsonSchema,
)]
#[repr(C)]
#[type_name("cabletrack::CableObservationData/2")]
pub struct CableObservationData {
    /// 1 when the cable was found (in view), 0 otherwise.
    #[serde(with = "Flag")]
    pub found: u8,
    #[serde(skip)]
    pub _reserved: [u8; 7],
    /// The line's distance from the image centre along its normal, pixels.
    #[serde(with = "NumberOrNull")]
    pub rho: f64,
    /// Theta: the cable's angle from the image's vertical axis, rad, positive when its top leans
    /// right.
    #[serde(with = "NumberOrNull")]
    pub theta: f64,
    /// The mid point of the line's border crossings, fraction of the width, positive right.
    #[serde(with = "NumberOrNull")]
    pub x_g: f64,
    /// The same, fraction of the height, positive down.
    #[serde(with = "NumberOrNull")]
    pub y_g: f64,
    /// dx_g/dt, 1/s.
    #[serde(with = "NumberOrNull")]
    pub x_g_rate: f64,
    /// dTheta/dt, rad/s.
    #[serde(with = "NumberOrNull")]
    pub theta_rate: f64,
    /// The detector's confidence in [0, 1] (1 for the geometric camera).
    #[serde(with = "NumberOrNull")]
    pub confidence: f64,
}

impl From<&model::CableObservation> for CableObservationData {
    fn from(o: &model::CableObservation) -> Self {
        CableObservationData {
            found: o.found as u8,
            _reserved: [0; 7],
            rho: o.rho,
            theta: o.theta,
            x_g: o.x_g,
            y_g: o.y_g,
            x_g_rate: o.x_g_rate,
            theta_rate: o.theta_rate,
            confidence: o.confidence,
        }
    }
}

impl CableObservationData {
    /// The observation under the rule for bad values (`model::bounds`), each quantity within its
    /// range: x_g and y_g within half the image, Theta within [-pi/2, pi/2], the rates within the
    /// scenario's clipping `limits`, the confidence within [0, 1], rho finite. A perception that
    /// never errs changes nothing here; a corrupt or forged message cannot hand a learner NaN.
    pub fn bounded(&self, limits: &config::ObservationLimits) -> (Self, model::bounds::Fixes) {
        use model::bounds::{bounded, symmetric};
        let mut fixes = model::bounds::Fixes::default();
        let mut f = |v| fixes.note(v);
        let out = CableObservationData {
            found: (self.found != 0) as u8,
            _reserved: [0; 7],
            rho: f(symmetric(self.rho, f64::MAX)),
            theta: f(symmetric(self.theta, std::f64::consts::FRAC_PI_2)),
            x_g: f(symmetric(self.x_g, 0.5)),
            y_g: f(symmetric(self.y_g, 0.5)),
            x_g_rate: f(symmetric(self.x_g_rate, limits.x_g_rate_max)),
            theta_rate: f(symmetric(self.theta_rate, limits.theta_rate_max)),
            confidence: f(bounded(self.confidence, 0.0, 1.0)),
        };
        (out, fixes)
    }
}

impl From<&CableObservationData> for model::CableObservation {
    fn from(t: &CableObservationData) -> Self {
        model::CableObservation {
            found: t.found != 0,
            rho: t.rho,
            theta: t.theta,
            x_g: t.x_g,
            y_g: t.y_g,
            x_g_rate: t.x_g_rate,
            theta_rate: t.theta_rate,
            confidence: t.confidence,
        }
    }
}

/// The user header of a camera frame; the payload is the `width x height` 8-bit image, row by row
/// (empty when the camera runs without images and only the ground truth is passed on).
#[derive(
    Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize, Deserialize, JsonSchema,
)]
#[repr(C)]
#[type_name("cabletrack::CameraFrameHeader/4")]
pub struct CameraFrameHeader {
    pub stamp: Stamp,
    /// Pixels.
    pub width: u32,
    /// Pixels.
    pub height: u32,
    /// What is known of the image, bits: 1 damaged (a compressed frame decoded with data missing:
    /// perception does not track on it).
    pub flags: u32,
    #[serde(skip)]
    pub _reserved: [u8; 4],
    /// The geometric camera's line for this frame, where it is known (simulation); `found = 0`
    /// otherwise. Ideal perception passes it on; image perception is checked against it.
    pub truth: CableObservationData,
}

impl CameraFrameHeader {
    /// The image is not whole (a compressed video frame decoded with data missing): perception
    /// does not track on it.
    pub const DAMAGED: u32 = 1;

    pub fn is_damaged(&self) -> bool {
        self.flags & Self::DAMAGED != 0
    }
}

/// One access unit of the camera's H.264 stream, as it arrived (the header of a
/// [`crate::topics::CAMERA_VIDEO`] sample; the unit's bytes, Annex B, are the sample's slice).
/// Published by the camera for every unit it gives its decoder, in that order, so that the units
/// recorded decode to the frames the mesh saw.
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend, Serialize, Deserialize, JsonSchema,
)]
#[repr(C)]
#[type_name("cabletrack::VideoUnit/1")]
pub struct VideoUnit {
    /// The camera's count of units given to its decoder, from 1 within its `epoch`.
    pub number: u64,
    /// The time of the frame it decodes to (ns): the `Stamp::time_ns` of that frame on the camera
    /// topic (the twin's time from the frame's metadata, or the camera's RTP clock).
    pub time_ns: u64,
    /// The vehicle clock (ns) when the camera published it (the clock of `Stamp::clock_ns`).
    pub clock_ns: i64,
    /// The camera's epoch (`Stamp::epoch`): new at each start of the camera, whose decoder starts
    /// afresh.
    pub epoch: u32,
    /// Bits: 1 keyframe (an IDR picture, with its SPS and PPS), 2 damaged (a packet of it or of
    /// what it references since the last keyframe is missing), 4 the decoder was started afresh
    /// before it (after an error: what it held is gone).
    pub flags: u32,
    /// The stream session (the sender's SSRC) it belongs to, from 1.
    pub session: u64,
}

impl VideoUnit {
    pub const KEYFRAME: u32 = 1;
    pub const DAMAGED: u32 = 2;
    pub const DECODER_RESTARTED: u32 = 4;

    pub fn is_keyframe(&self) -> bool {
        self.flags & Self::KEYFRAME != 0
    }
}

/// What perception found in a frame: an estimate of the cable's line and its rates.
#[derive(
    Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize, Deserialize, JsonSchema,
)]
#[repr(C)]
#[type_name("cabletrack::CableObservation/3")]
pub struct CableObservationMsg {
    pub stamp: Stamp,
    pub observation: CableObservationData,
}

impl CableObservationMsg {
    pub fn observation(&self) -> model::CableObservation {
        (&self.observation).into()
    }
}

/// One DOF's command: the normalised generalised force.
#[derive(
    Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize, Deserialize, JsonSchema,
)]
#[repr(C)]
#[type_name("cabletrack::DofCommand/3")]
pub struct DofCommand {
    pub stamp: Stamp,
    /// In [-1, 1].
    #[serde(with = "NumberOrNull")]
    pub value: f64,
}

/// Thruster setpoints in [-1, 1], in the order of the configured layout: a step's answer, or a
/// failsafe stop (`stop != 0`: every setpoint 0, stamped with the last step written, or an empty
/// stamp before any; never an answer to a step). Its JSON form is [`SetpointsForm`].
#[derive(
    Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize, Deserialize, JsonSchema,
)]
#[serde(into = "SetpointsForm", from = "SetpointsForm")]
#[repr(C)]
#[type_name("cabletrack::ThrusterSetpoints/3")]
pub struct ThrusterSetpoints {
    pub stamp: Stamp,
    pub count: u32,
    /// Bit k set: DOF k's command (0 surge, 1 sway, 2 yaw) missed its deadline and counted as 0.
    pub missing: u32,
    /// 0, or why the thrusters were stopped: a [`StopCause`] as u32.
    pub stop: u32,
    pub _reserved: u32,
    pub values: [f64; config::MAX_THRUSTERS],
    /// The factor applied to keep every setpoint within [-1, 1] (1 when nothing saturated).
    pub scale: f64,
}

/// The thruster allocator's setpoints, one per thruster of the layout (port, starboard, lateral):
/// the JSON form of [`ThrusterSetpoints`], whose values are the used part of its fixed array.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct SetpointsForm {
    pub stamp: Stamp,
    /// In [-1, 1], one per thruster (`null`: not a number).
    #[schemars(length(max = config::MAX_THRUSTERS))]
    pub values: Vec<Option<f64>>,
    /// Bit k set: DOF k's command (0 surge, 1 sway, 2 yaw) missed its deadline and counted as 0.
    pub missing: u32,
    /// The factor applied to keep every setpoint within [-1, 1].
    #[serde(with = "NumberOrNull")]
    pub scale: f64,
    /// 0: the answer to a step; else a failsafe stop of the thrusters and its cause: 1 the driver
    /// started, 2 deadline, 3 shutdown, 4 the allocator died, 255 unknown.
    #[serde(default)]
    #[schemars(with = "StopCauseCode")]
    pub stop: u32,
}

impl From<ThrusterSetpoints> for SetpointsForm {
    fn from(s: ThrusterSetpoints) -> Self {
        SetpointsForm {
            stamp: s.stamp,
            values: s
                .as_slice()
                .iter()
                .map(|v| v.is_finite().then_some(*v))
                .collect(),
            missing: s.missing,
            scale: s.scale,
            stop: s.stop,
        }
    }
}

impl From<SetpointsForm> for ThrusterSetpoints {
    /// Values past the array's length are dropped.
    fn from(f: SetpointsForm) -> Self {
        let mut values = [0.0; config::MAX_THRUSTERS];
        for (v, x) in values.iter_mut().zip(&f.values) {
            *v = x.unwrap_or(f64::NAN);
        }
        ThrusterSetpoints {
            stamp: f.stamp,
            count: f.values.len().min(config::MAX_THRUSTERS) as u32,
            missing: f.missing,
            stop: f.stop,
            _reserved: 0,
            values,
            scale: f.scale,
        }
    }
}

impl ThrusterSetpoints {
    pub fn as_slice(&self) -> &[f64] {
        &self.values[..(self.count as usize).min(config::MAX_THRUSTERS)]
    }

    /// Why these setpoints stop the thrusters, if they are a failsafe stop.
    pub fn stop_cause(&self) -> Option<StopCause> {
        (self.stop != 0).then(|| StopCause::from_u32(self.stop))
    }
}

/// Why the thrusters were stopped (driven to 0) without a step's answer.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u32)]
pub enum StopCause {
    /// The thruster driver started: the thrusters begin at rest.
    Start = 1,
    /// No fresh setpoints within the deadline.
    Deadline = 2,
    /// The thruster driver was asked to stop (SIGINT, SIGTERM) or is closing its thrusters.
    Shutdown = 3,
    /// The allocator's process died.
    AllocatorDead = 4,
    /// An unknown cause (a corrupt or newer message): still a stop.
    Unknown = 255,
}

impl StopCause {
    pub const ALL: [StopCause; 5] = [
        StopCause::Start,
        StopCause::Deadline,
        StopCause::Shutdown,
        StopCause::AllocatorDead,
        StopCause::Unknown,
    ];

    pub fn from_u32(v: u32) -> Self {
        match v {
            1 => StopCause::Start,
            2 => StopCause::Deadline,
            3 => StopCause::Shutdown,
            4 => StopCause::AllocatorDead,
            _ => StopCause::Unknown,
        }
    }

    /// The cause as written in logs and files.
    pub fn name(self) -> &'static str {
        match self {
            StopCause::Start => "start",
            StopCause::Deadline => "deadline",
            StopCause::Shutdown => "shutdown",
            StopCause::AllocatorDead => "allocator_dead",
            StopCause::Unknown => "unknown",
        }
    }

    /// The cause of a name written by [`StopCause::name`].
    pub fn parse(name: &str) -> Option<Self> {
        StopCause::ALL.into_iter().find(|c| c.name() == name)
    }
}

impl std::fmt::Display for StopCause {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// A behaviour's report at the end of each episode. Fields of step two are read as their
/// defaults from records written before them.
#[derive(
    Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize, Deserialize, JsonSchema,
)]
#[repr(C)]
#[type_name("cabletrack::LearningStats/3")]
pub struct LearningStats {
    /// The stamp of the step that ended the episode.
    pub stamp: Stamp,
    /// The episode's return (sum of the behaviour's rewards, the failure reward included).
    #[serde(with = "NumberOrNull")]
    pub episode_return: f64,
    /// K after the episode (after a rollback it closed), for (position, rate).
    #[serde(with = "NumbersOrNull::<2>")]
    pub gain: [f64; 2],
    /// Actor updates since the learner started.
    pub actor_updates: u64,
    /// Transitions in the episode.
    pub steps: u32,
    /// 1 when the episode ended with the cable lost.
    #[serde(with = "Flag")]
    pub failed: u8,
    /// 1 while learning, 0 when only acting.
    #[serde(with = "Flag")]
    pub learning: u8,
    /// 1 for an evaluation trial of step two (the policy acted without learning).
    #[serde(default, with = "Flag")]
    pub evaluation: u8,
    /// 1 when this trial closed an evaluation that restored the best policy.
    #[serde(default, with = "Flag")]
    pub rolled_back: u8,
    /// Step two's safety layer so far: actor updates shortened by the trust region.
    #[serde(default)]
    pub bounded: u64,
    /// Actor updates refused by the stability guard so far.
    #[serde(default)]
    pub refused: u64,
    /// Policies replaced by the best one so far.
    #[serde(default)]
    pub rollbacks: u64,
    /// The mean return of the evaluation this trial closed (NaN when it closed none).
    #[serde(default = "NumberOrNull::missing", with = "NumberOrNull")]
    pub evaluated: f64,
    /// The evaluated mean return of the policy a rollback restores: the best so far, or before a
    /// pair kept the cable in a whole evaluation, the simulation policies' (NaN before the first).
    #[serde(default = "NumberOrNull::missing", with = "NumberOrNull")]
    pub best_evaluated: f64,
}

/// What happened to a service of the mesh ([`SupervisorEvent::kind`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum ServiceEvent {
    /// The supervisor started it (at the mesh's start, or again after it died).
    Started = 1,
    /// It exited on its own: with success (its job done) or not (it died).
    Exited = 2,
    /// It died and will be started again after [`SupervisorEvent::delay_ms`].
    Restarting = 3,
    /// The supervisor stopped it with the mesh (SIGTERM, then SIGKILL after the grace period).
    Stopped = 4,
}

impl ServiceEvent {
    pub const ALL: [ServiceEvent; 4] = [
        ServiceEvent::Started,
        ServiceEvent::Exited,
        ServiceEvent::Restarting,
        ServiceEvent::Stopped,
    ];

    pub fn from_u8(v: u8) -> Option<ServiceEvent> {
        match v {
            1 => Some(ServiceEvent::Started),
            2 => Some(ServiceEvent::Exited),
            3 => Some(ServiceEvent::Restarting),
            4 => Some(ServiceEvent::Stopped),
            _ => None,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            ServiceEvent::Started => "started",
            ServiceEvent::Exited => "exited",
            ServiceEvent::Restarting => "restarting",
            ServiceEvent::Stopped => "stopped",
        }
    }
}

/// The longest service name an event carries (longer names are cut at a character boundary).
pub const SERVICE_NAME_LEN: usize = 32;

/// One of the supervisor's events: what happened to a service of the mesh. It belongs to no control
/// step, so it carries no [`Stamp`]: its time is the wall clock.
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend, Serialize, Deserialize, JsonSchema,
)]
#[repr(C)]
#[type_name("cabletrack::SupervisorEvent/1")]
pub struct SupervisorEvent {
    /// Events count from 1 in one supervisor's run.
    pub seq: u64,
    /// When it happened: nanoseconds since the Unix epoch.
    pub wall_time_ns: u64,
    /// A [`ServiceEvent`] as u8; in JSON its name: started, exited, restarting or stopped.
    #[serde(with = "EventKind")]
    pub kind: u8,
    #[serde(skip)]
    pub _reserved: [u8; 3],
    /// The service's process (for `Restarting`: the one that died).
    pub pid: u32,
    /// `Exited`, `Stopped`: the exit code, or minus the signal that ended it; 0 otherwise.
    pub status: i32,
    /// Times the service has been restarted so far.
    pub restarts: u32,
    /// `Restarting`: the delay before the restart (ms). `Stopped`: 1 if it had to be killed.
    pub detail: u32,
    #[serde(skip)]
    pub _pad: u32,
    /// The service's name in the mesh file, UTF-8, NUL-padded.
    #[serde(with = "Text::<SERVICE_NAME_LEN>")]
    pub service: [u8; SERVICE_NAME_LEN],
}

impl SupervisorEvent {
    pub fn new(seq: u64, wall_time_ns: u64, kind: ServiceEvent, service: &str) -> Self {
        SupervisorEvent {
            seq,
            wall_time_ns,
            kind: kind as u8,
            service: Text::to_bytes(service),
            ..Default::default()
        }
    }

    /// The event's kind; `None` for an unknown value (a newer supervisor).
    pub fn kind(&self) -> Option<ServiceEvent> {
        ServiceEvent::from_u8(self.kind)
    }

    /// The service's name (invalid UTF-8 is replaced).
    pub fn service(&self) -> String {
        Text::of(&self.service).into_owned()
    }
}

/// The flight recorder's report after each flush of its file.
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend, Serialize, Deserialize, JsonSchema,
)]
#[repr(C)]
#[type_name("cabletrack::RecorderStatus/1")]
pub struct RecorderStatus {
    /// Reports count from 1.
    pub seq: u64,
    /// Nanoseconds since the Unix epoch.
    pub wall_time_ns: u64,
    /// Messages written so far, over every part of the record.
    pub messages: u64,
    /// Messages on disk in complete chunks: what a SIGKILL now would leave readable.
    pub flushed_messages: u64,
    /// Bytes written so far, over every part.
    pub bytes: u64,
    /// Steps a topic missed while other topics of the loop had them (the recorder's buffer
    /// overflowed, or the step was never published on that topic).
    pub holes: u64,
    /// Messages of a step seen again (re-sends), not written again.
    pub repeats: u64,
    /// The part being written (0: the file named on the command line).
    pub part: u32,
    #[serde(skip)]
    pub _reserved: u32,
}

/// What the vehicle's autopilot says of itself, from its HEARTBEAT and SYS_STATUS, published by the
/// thruster driver that pilots it over MAVLink (the ArduSub thruster sink, `shared/ardusub`): once
/// per autopilot heartbeat, and when the heartbeat is lost. Autopilot telemetry belongs to no
/// control step, so it carries no [`Stamp`]: its time is the vehicle clock (`runtime::clock`,
/// CLOCK_MONOTONIC, the clock of [`Stamp::clock_ns`]) when the message arrived, so it lines up
/// with the steps; the autopilot's own clock where the message has one.
#[derive(
    Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize, Deserialize, JsonSchema,
)]
#[repr(C)]
#[type_name("cabletrack::AutopilotState/2")]
pub struct AutopilotState {
    /// Reports count from 1 in one driver's run.
    pub seq: u64,
    /// The vehicle clock (ns) when the autopilot's message arrived (or, for a lost heartbeat, when
    /// the loss was found).
    pub clock_ns: i64,
    /// MAVLink frames refused so far on the link (broken checksums, garbage, truncated frames).
    pub frames_refused: u64,
    /// The battery as the autopilot reports it (SYS_STATUS): volts and amperes, NaN when unknown.
    #[serde(with = "NumberOrNull")]
    pub battery_v: f64,
    #[serde(with = "NumberOrNull")]
    pub battery_a: f64,
    /// The pilot gain the driver scales its commands by (ArduSub's `PilotGain`).
    #[serde(with = "NumberOrNull")]
    pub pilot_gain: f64,
    /// The autopilot's flight mode (HEARTBEAT `custom_mode`; ArduSub: 19 MANUAL, 2 ALT_HOLD,
    /// 0 STABILIZE), valid while `heartbeat` is 1.
    pub mode: u32,
    /// 1 while the autopilot's heartbeat comes; 0 before the first and once it is lost, when
    /// `armed` and `mode` are unknown.
    pub heartbeat: u8,
    /// 1 when the autopilot's heartbeat says armed (motors enabled).
    pub armed: u8,
    /// The autopilot's MAV_STATE (3 standby, 4 active, 5 critical, 6 emergency).
    pub system_status: u8,
    /// The battery's remaining charge in percent, -1 when unknown.
    pub battery_remaining: i8,
}

/// ArduSub's name of a flight mode number (HEARTBEAT `custom_mode`, [`AutopilotState::mode`]),
/// for logs and `status`; a number ArduSub does not define is shown as such.
pub fn ardusub_mode_name(custom_mode: u32) -> String {
    let name = match custom_mode {
        0 => "STABILIZE",
        1 => "ACRO",
        2 => "ALT_HOLD",
        3 => "AUTO",
        4 => "GUIDED",
        7 => "CIRCLE",
        9 => "SURFACE",
        16 => "POSHOLD",
        19 => "MANUAL",
        20 => "MOTOR_DETECT",
        21 => "SURFTRAK",
        m => return format!("mode {m}"),
    };
    name.into()
}

/// The autopilot's attitude (MAVLink ATTITUDE): Euler angles in the NED frame, the project's
/// conventions (yaw from north towards east, as psi from x towards y). Time as in
/// [`AutopilotState`].
#[derive(
    Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize, Deserialize, JsonSchema,
)]
#[repr(C)]
#[type_name("cabletrack::AutopilotAttitude/2")]
pub struct AutopilotAttitude {
    pub seq: u64,
    pub clock_ns: i64,
    /// Radians, and radians per second.
    #[serde(with = "NumberOrNull")]
    pub roll: f64,
    #[serde(with = "NumberOrNull")]
    pub pitch: f64,
    #[serde(with = "NumberOrNull")]
    pub yaw: f64,
    #[serde(with = "NumberOrNull")]
    pub roll_rate: f64,
    #[serde(with = "NumberOrNull")]
    pub pitch_rate: f64,
    #[serde(with = "NumberOrNull")]
    pub yaw_rate: f64,
    /// The autopilot's clock: milliseconds since it booted.
    pub boot_ms: u32,
    #[serde(skip)]
    pub _reserved: u32,
}

/// The vehicle's depth and heading as the autopilot reports them (MAVLink VFR_HUD: ArduSub puts
/// its altitude relative to the surface in `alt`, negative below it). Time as in
/// [`AutopilotState`].
#[derive(
    Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize, Deserialize, JsonSchema,
)]
#[repr(C)]
#[type_name("cabletrack::AutopilotDepth/2")]
pub struct AutopilotDepth {
    pub seq: u64,
    pub clock_ns: i64,
    /// Metres below the surface (VFR_HUD `alt` negated).
    #[serde(with = "NumberOrNull")]
    pub depth_m: f64,
    /// Degrees from north, 0 to 360.
    #[serde(with = "NumberOrNull")]
    pub heading_deg: f64,
    /// Metres per second, positive up (VFR_HUD `climb`).
    #[serde(with = "NumberOrNull")]
    pub climb_m_s: f64,
    /// The vertical thrust the autopilot gives, in percent.
    #[serde(with = "NumberOrNull")]
    pub throttle_pct: f64,
}

/// The most output channels a [`ServoOutputs`] carries.
pub const SERVO_CHANNELS: usize = 16;

/// The autopilot's outputs to the thrusters' ESCs (MAVLink SERVO_OUTPUT_RAW): pulse widths in
/// microseconds, 1500 at rest on a BlueROV2. Time as in [`AutopilotState`].
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend, Serialize, Deserialize, JsonSchema,
)]
#[repr(C)]
#[type_name("cabletrack::ServoOutputs/2")]
pub struct ServoOutputs {
    pub seq: u64,
    pub clock_ns: i64,
    /// The autopilot's clock (microseconds since boot, wrapping).
    pub time_us: u32,
    /// The output port: channels 1 to 16 are port 0, 17 to 32 port 1.
    pub port: u8,
    /// Channels carried (8, or 16 with MAVLink 2's extension).
    pub count: u8,
    #[serde(skip)]
    pub _reserved: [u8; 2],
    /// Channel k+1's pulse width (us); 0 where the autopilot sends none.
    pub pwm_us: [u16; SERVO_CHANNELS],
}

/// The longest text a [`StatusText`] carries (MAVLink STATUSTEXT's).
pub const STATUS_TEXT_LEN: usize = 50;

/// A text the autopilot sends its ground stations (MAVLink STATUSTEXT: "PreArm: ...", "Lost manual
/// control", ...), as it comes. Time as in [`AutopilotState`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend, Serialize, Deserialize, JsonSchema)]
#[repr(C)]
#[type_name("cabletrack::StatusText/2")]
pub struct StatusText {
    pub seq: u64,
    pub clock_ns: i64,
    /// MAV_SEVERITY: 0 emergency ... 4 warning, 5 notice, 6 info, 7 debug.
    pub severity: u8,
    #[serde(skip)]
    pub _reserved: [u8; 7],
    /// UTF-8, NUL-padded.
    #[serde(with = "Text::<STATUS_TEXT_LEN>")]
    pub text: [u8; STATUS_TEXT_LEN],
    #[serde(skip)]
    pub _pad: [u8; 6],
}

impl Default for StatusText {
    fn default() -> Self {
        StatusText {
            seq: 0,
            clock_ns: 0,
            severity: 0,
            _reserved: [0; 7],
            text: [0; STATUS_TEXT_LEN],
            _pad: [0; 6],
        }
    }
}

impl StatusText {
    /// A text of `severity`; a longer one is cut at a character boundary.
    pub fn new(severity: u8, text: &str) -> Self {
        let mut out = StatusText {
            severity,
            ..Default::default()
        };
        let mut end = text.len().min(STATUS_TEXT_LEN);
        while !text.is_char_boundary(end) {
            end -= 1;
        }
        out.text[..end].copy_from_slice(&text.as_bytes()[..end]);
        out
    }

    /// The text (invalid UTF-8 is replaced).
    pub fn text(&self) -> String {
        let end = self
            .text
            .iter()
            .position(|&b| b == 0)
            .unwrap_or(STATUS_TEXT_LEN);
        String::from_utf8_lossy(&self.text[..end]).into_owned()
    }
}

/// What the shore asks of the vehicle's mesh (see [`crate::topics::shore::MISSION`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend)]
#[repr(C)]
#[type_name("cabletrack::MissionCommand/1")]
pub struct MissionCommand {
    /// Increases with every command the shore sends (a repeated one is not obeyed twice).
    pub seq: u64,
    /// The sender's monotonic clock (ns), for the link's latency.
    pub time_ns: u64,
    /// A [`Mission`] as u8.
    pub command: u8,
    pub _reserved: [u8; 7],
}

/// The commands the shore may send.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Mission {
    /// Stop the run: the supervisor stops every service, as on SIGTERM.
    Stop = 1,
}

impl MissionCommand {
    pub fn new(seq: u64, time_ns: u64, command: Mission) -> Self {
        MissionCommand {
            seq,
            time_ns,
            command: command as u8,
            _reserved: [0; 7],
        }
    }

    /// The command; an unknown value (a newer shore) is `None` and not obeyed.
    pub fn mission(&self) -> Option<Mission> {
        (self.command == Mission::Stop as u8).then_some(Mission::Stop)
    }
}

/// A message that belongs to one control step.
pub trait Stamped {
    fn stamp(&self) -> &Stamp;
}

macro_rules! stamped {
    ($($t:ty),*) => {$(
        impl Stamped for $t {
            fn stamp(&self) -> &Stamp {
                &self.stamp
            }
        }
    )*};
}

stamped!(
    VehicleStateMsg,
    CameraFrameHeader,
    CableObservationMsg,
    DofCommand,
    ThrusterSetpoints,
    LearningStats
);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn autopilot_payloads_have_no_hidden_padding_and_texts_are_cut_at_a_boundary() {
        use std::mem::size_of;
        assert_eq!(size_of::<AutopilotState>(), 56);
        assert_eq!(size_of::<AutopilotAttitude>(), 72);
        assert_eq!(size_of::<AutopilotDepth>(), 48);
        assert_eq!(size_of::<ServoOutputs>(), 56);
        assert_eq!(size_of::<StatusText>(), 80);
        assert_eq!(
            StatusText::new(4, "Lost manual control").text(),
            "Lost manual control"
        );
        let long = format!("{}é", "a".repeat(49));
        assert_eq!(StatusText::new(6, &long).text(), "a".repeat(49));
        assert_eq!(StatusText::new(6, &long).severity, 6);
    }

    #[test]
    fn an_event_carries_the_service_name_cut_at_a_character_boundary() {
        let e = SupervisorEvent::new(3, 7, ServiceEvent::Restarting, "sway-behaviour");
        assert_eq!(e.service(), "sway-behaviour");
        assert_eq!(e.kind(), Some(ServiceEvent::Restarting));
        assert_eq!(
            std::mem::size_of::<SupervisorEvent>(),
            72,
            "no hidden padding"
        );
        // 31 ASCII bytes and a two-byte character: the character does not fit and is left out.
        let long = format!("{}é", "a".repeat(31));
        assert_eq!(
            SupervisorEvent::new(1, 0, ServiceEvent::Started, &long).service(),
            "a".repeat(31)
        );
        let unknown = SupervisorEvent {
            kind: 9,
            ..Default::default()
        };
        assert_eq!(unknown.kind(), None);
    }
}
