//! The payloads: `#[repr(C)]`, `ZeroCopySend`, with a stable, versioned type name (a process built
//! from older code refuses to connect instead of misreading the bytes).

use iceoryx2::prelude::*;

pub use config::StepStatus;

/// The step a message belongs to. Copied unchanged from the vehicle state through every stage.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend)]
#[repr(C)]
#[type_name("cabletrack::Stamp/1")]
pub struct Stamp {
    /// Sequence number of the control step, increasing across episodes (never reused in a run).
    pub seq: u64,
    /// Time of the step (ns): simulated time on the sim endpoint, the monotonic clock on the vehicle.
    pub time_ns: u64,
    pub episode: u32,
    /// Step within the episode, 0 at the reset.
    pub step: u32,
    /// A [`StepStatus`] as u8.
    pub status: u8,
    pub _reserved: [u8; 7],
}

impl Stamp {
    pub fn new(seq: u64, time_ns: u64, episode: u32, step: u32, status: StepStatus) -> Self {
        Stamp {
            seq,
            time_ns,
            episode,
            step,
            status: status as u8,
            _reserved: [0; 7],
        }
    }

    /// The step's status; an unknown value (a corrupt or newer message) reads as `Lost`: the safe end.
    pub fn status(&self) -> StepStatus {
        StepStatus::from_u8(self.status).unwrap_or(StepStatus::Lost)
    }
}

/// The vehicle's state (pool frame pose, body velocities) and the pose's rate (current included).
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[repr(C)]
#[type_name("cabletrack::VehicleState/1")]
pub struct VehicleStateMsg {
    pub stamp: Stamp,
    pub x: f64,
    pub y: f64,
    pub psi: f64,
    pub u: f64,
    pub v: f64,
    pub r: f64,
    pub x_rate: f64,
    pub y_rate: f64,
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
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[repr(C)]
#[type_name("cabletrack::CableObservationData/1")]
pub struct CableObservationData {
    /// 1 when the cable was found (in view), 0 otherwise.
    pub found: u8,
    pub _reserved: [u8; 7],
    pub rho: f64,
    pub theta: f64,
    pub x_g: f64,
    pub y_g: f64,
    pub x_g_rate: f64,
    pub theta_rate: f64,
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
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[repr(C)]
#[type_name("cabletrack::CameraFrameHeader/1")]
pub struct CameraFrameHeader {
    pub stamp: Stamp,
    pub width: u32,
    pub height: u32,
    /// The geometric camera's line for this frame, where it is known (simulation); `found = 0`
    /// otherwise. Ideal perception passes it on; image perception is checked against it.
    pub truth: CableObservationData,
}

/// What perception found in a frame.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[repr(C)]
#[type_name("cabletrack::CableObservation/1")]
pub struct CableObservationMsg {
    pub stamp: Stamp,
    pub observation: CableObservationData,
}

impl CableObservationMsg {
    pub fn observation(&self) -> model::CableObservation {
        (&self.observation).into()
    }
}

/// One DOF's command: the normalised generalised force in [-1, 1].
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[repr(C)]
#[type_name("cabletrack::DofCommand/1")]
pub struct DofCommand {
    pub stamp: Stamp,
    pub value: f64,
}

/// Thruster setpoints in [-1, 1], in the order of the configured layout.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[repr(C)]
#[type_name("cabletrack::ThrusterSetpoints/1")]
pub struct ThrusterSetpoints {
    pub stamp: Stamp,
    pub count: u32,
    /// Bit k set: DOF k's command (0 surge, 1 sway, 2 yaw) missed its deadline and counted as 0.
    pub missing: u32,
    pub values: [f64; config::MAX_THRUSTERS],
    /// The factor applied to keep every setpoint within [-1, 1] (1 when nothing saturated).
    pub scale: f64,
}

impl ThrusterSetpoints {
    pub fn as_slice(&self) -> &[f64] {
        &self.values[..(self.count as usize).min(config::MAX_THRUSTERS)]
    }
}

/// A behaviour's report at the end of each episode.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[repr(C)]
#[type_name("cabletrack::LearningStats/2")]
pub struct LearningStats {
    /// The stamp of the step that ended the episode.
    pub stamp: Stamp,
    /// The episode's return (sum of the behaviour's rewards, the failure reward included).
    pub episode_return: f64,
    /// K after the episode (after a rollback it closed), for (position, rate).
    pub gain: [f64; 2],
    /// Actor updates since the learner started.
    pub actor_updates: u64,
    /// Transitions in the episode.
    pub steps: u32,
    /// 1 when the episode ended with the cable lost.
    pub failed: u8,
    /// 1 while learning, 0 when only acting.
    pub learning: u8,
    /// 1 for an evaluation trial of step two (the policy acted without learning).
    pub evaluation: u8,
    /// 1 when this trial closed an evaluation that restored the best policy.
    pub rolled_back: u8,
    /// Step two's safety layer so far: actor updates shortened by the trust region, refused by the
    /// stability guard, and policies replaced by the best one.
    pub bounded: u64,
    pub refused: u64,
    pub rollbacks: u64,
    /// The mean return of the evaluation this trial closed (NaN when it closed none), and the best
    /// evaluated so far (NaN before the first).
    pub evaluated: f64,
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

/// One of the supervisor's events. It belongs to no control step, so it carries no [`Stamp`]: its
/// time is the wall clock.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend)]
#[repr(C)]
#[type_name("cabletrack::SupervisorEvent/1")]
pub struct SupervisorEvent {
    /// Events count from 1 in one supervisor's run.
    pub seq: u64,
    /// When it happened: nanoseconds since the Unix epoch.
    pub wall_time_ns: u64,
    /// A [`ServiceEvent`] as u8.
    pub kind: u8,
    pub _reserved: [u8; 3],
    /// The service's process (for `Restarting`: the one that died).
    pub pid: u32,
    /// `Exited`, `Stopped`: the exit code, or minus the signal that ended it; 0 otherwise.
    pub status: i32,
    /// Times the service has been restarted so far.
    pub restarts: u32,
    /// `Restarting`: the delay before the restart (ms). `Stopped`: 1 if it had to be killed.
    pub detail: u32,
    pub _pad: u32,
    /// The service's name in the mesh file, UTF-8, NUL-padded.
    pub service: [u8; SERVICE_NAME_LEN],
}

impl SupervisorEvent {
    pub fn new(seq: u64, wall_time_ns: u64, kind: ServiceEvent, service: &str) -> Self {
        let mut name = [0u8; SERVICE_NAME_LEN];
        let mut end = service.len().min(SERVICE_NAME_LEN);
        while !service.is_char_boundary(end) {
            end -= 1;
        }
        name[..end].copy_from_slice(&service.as_bytes()[..end]);
        SupervisorEvent {
            seq,
            wall_time_ns,
            kind: kind as u8,
            service: name,
            ..Default::default()
        }
    }

    /// The event's kind; `None` for an unknown value (a newer supervisor).
    pub fn kind(&self) -> Option<ServiceEvent> {
        ServiceEvent::from_u8(self.kind)
    }

    /// The service's name (invalid UTF-8 is replaced).
    pub fn service(&self) -> String {
        let end = self
            .service
            .iter()
            .position(|&b| b == 0)
            .unwrap_or(SERVICE_NAME_LEN);
        String::from_utf8_lossy(&self.service[..end]).into_owned()
    }
}

/// The flight recorder's report after each flush of its file.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend)]
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
    pub _reserved: u32,
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
