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
