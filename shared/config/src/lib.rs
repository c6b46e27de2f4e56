//! The numbers every part of cabletrack agrees on.
//!
//! Two files describe an experiment: `config/scenario.toml` (the vehicle model, camera, cable, episode,
//! rewards, thrusters, and how the stack pilots an autopilot: [`Scenario`]) and `config/learning.toml` (policy and learner parameters:
//! [`LearningParams`]); the vehicle twin's reality gap is `config/twin.toml` ([`TwinParams`]). Every
//! library takes its parameters from the types here, so a number is defined once. The defaults are
//! the numbers of `DESIGN.md` and the paper; the files in `config/` repeat them so that an operator
//! can read and change them.
//!
//! Loading is strict: an unknown key, a wrong type or an out-of-range value is an error that names the
//! file and the key (see [`ConfigError`]). Missing keys take their defaults.

mod autopilot;
mod error;
mod learning;
mod pilot;
mod scenario;
mod twin;
mod vision;

pub use autopilot::{
    ARDUSUB_PARAMS, ArduSubGeneration, AutopilotParams, ParamKind, ParamSpec, Since, param_value_ok,
};
pub use error::{ConfigError, Invalid};
pub use learning::{
    EvaluationParams, GpomdpParams, LearningParams, MAX_ANGLE_LAG, MAX_GUARD_DELAY, NacParams,
    PerDof, PolicyParams, Preset, RollbackParams, SafetyParams, StabilityParams, StepTwoParams,
    TrustRegionParams,
};
pub use pilot::{ACRO_YAW_P_DEFAULT, FULL_STICK_CDEG, PilotFractions, PilotMode, PilotParams};
pub use scenario::{
    CableParams, CameraParams, DofModel, MAX_THRUSTERS, MissedFrames, ModelParams,
    ObservationLimits, PoolParams, QuadraticCost, ResetParams, Rewards, Scenario, SurgeParams,
    ThrusterParams, Thrusters, Timing,
};
pub use twin::{
    AsymmetryParams, CurrentParams, DampingParams, DeadBandParams, DofDamping, DropParams,
    FrameParams, GainParams, LagParams, LatencyParams, MAX_LATENCY_FRAMES, MountParams,
    ThrusterGap, TrialParams, TwinParams,
};
pub use vision::{
    BlurParams, CablePolarity, ClutterParams, LightingParams, NoiseParams, PerceptionParams,
    RenderParams, TextureParams, TrackingParams,
};

use serde::de::DeserializeOwned;
use std::path::Path;

/// The two degrees of freedom that are learned.
#[derive(
    Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum Dof {
    Sway,
    Yaw,
}

impl Dof {
    pub const ALL: [Dof; 2] = [Dof::Sway, Dof::Yaw];

    /// The other learned DOF.
    pub fn partner(self) -> Dof {
        match self {
            Dof::Sway => Dof::Yaw,
            Dof::Yaw => Dof::Sway,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Dof::Sway => "sway",
            Dof::Yaw => "yaw",
        }
    }
}

impl std::fmt::Display for Dof {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Where an episode stands at a step: the one status the simulator, the vehicle twin, the messages
/// (as a `u8`) and the learners share.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
#[repr(u8)]
pub enum StepStatus {
    /// The cable is in view and the episode goes on.
    Running = 0,
    /// The cable has left the image: an absorbing failure, the episode is over.
    Lost = 1,
    /// The episode reached its last step with the cable in view: over, but not a failure.
    TimeLimit = 2,
}

impl StepStatus {
    pub fn from_u8(v: u8) -> Option<StepStatus> {
        match v {
            0 => Some(StepStatus::Running),
            1 => Some(StepStatus::Lost),
            2 => Some(StepStatus::TimeLimit),
            _ => None,
        }
    }

    pub fn is_terminal(self) -> bool {
        self != StepStatus::Running
    }

    /// How an episode ending with this status is told in logs.
    pub fn describe(self) -> &'static str {
        match self {
            StepStatus::Running => "running",
            StepStatus::Lost => "cable lost",
            StepStatus::TimeLimit => "time limit",
        }
    }
}

/// How the behaviours see the cable: one choice for the camera, perception, the trainer and the
/// twin.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Eyes {
    /// The geometric camera's exact line and rates (ideal perception; frames carry no image).
    Ideal,
    /// Rendered camera images and the vision system's perception, as on the vehicle.
    Images,
}

impl Eyes {
    pub fn name(self) -> &'static str {
        match self {
            Eyes::Ideal => "ideal",
            Eyes::Images => "images",
        }
    }
}

impl std::fmt::Display for Eyes {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Eyes {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "ideal" => Ok(Eyes::Ideal),
            "images" => Ok(Eyes::Images),
            other => Err(format!(
                "`{other}` is not a kind of eyes (expected `ideal` or `images`)"
            )),
        }
    }
}

/// A configuration section that can check its own values.
pub trait Validate {
    /// Checks every value; `key` is the dotted path of this section in its file (e.g. `model.yaw`).
    fn validate(&self, key: &str) -> Result<(), Invalid>;
}

/// Reads and checks one configuration file.
pub fn load<T: DeserializeOwned + Validate>(path: &Path) -> Result<T, ConfigError> {
    let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
        file: path.to_owned(),
        source,
    })?;
    parse(&text, path)
}

/// Parses and checks configuration text; `path` only names the source in errors.
pub fn parse<T: DeserializeOwned + Validate>(text: &str, path: &Path) -> Result<T, ConfigError> {
    let value: T = toml::from_str(text).map_err(|source| ConfigError::Parse {
        file: path.to_owned(),
        source: Box::new(source),
    })?;
    value.validate("").map_err(|invalid| ConfigError::Invalid {
        file: path.to_owned(),
        invalid,
    })?;
    Ok(value)
}

/// Joins a section's key and a field name into a dotted key.
pub(crate) fn join(section: &str, field: &str) -> String {
    if section.is_empty() {
        field.to_owned()
    } else {
        format!("{section}.{field}")
    }
}

/// Checks that `value` is finite and within `[min, max]`.
pub(crate) fn in_range(
    section: &str,
    field: &str,
    value: f64,
    min: f64,
    max: f64,
) -> Result<(), Invalid> {
    if value.is_finite() && value >= min && value <= max {
        Ok(())
    } else {
        Err(Invalid::new(
            join(section, field),
            value,
            format!("must be within [{min}, {max}]"),
        ))
    }
}

/// Checks that `value` is finite and strictly positive.
pub(crate) fn positive(section: &str, field: &str, value: f64) -> Result<(), Invalid> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(Invalid::new(
            join(section, field),
            value,
            "must be a finite number > 0",
        ))
    }
}

/// Checks that `value` is a finite number.
pub(crate) fn finite(section: &str, field: &str, value: f64) -> Result<(), Invalid> {
    if value.is_finite() {
        Ok(())
    } else {
        Err(Invalid::new(
            join(section, field),
            value,
            "must be a finite number",
        ))
    }
}

/// The seed of one random stream of an experiment: each component (the simulator's resets, each
/// behaviour's exploration, the renderer's noise) draws from its own stream, so the in-process trainer
/// and the process mesh draw the same numbers for the same experiment seed.
pub fn derive_seed(seed: u64, stream: &str) -> u64 {
    // FNV-1a of the stream name, mixed with the seed by splitmix64.
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in stream.bytes() {
        h = (h ^ b as u64).wrapping_mul(0x0100_0000_01b3);
    }
    let mut z = seed.wrapping_add(h).wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}
