//! `scenario.toml`: the vehicle, its world and the task.

use crate::{Invalid, PerceptionParams, RenderParams, Validate, finite, in_range, join, positive};
use serde::{Deserialize, Serialize};

/// Everything about the task except how the behaviours learn.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Scenario {
    pub timing: Timing,
    pub model: ModelParams,
    pub camera: CameraParams,
    pub cable: CableParams,
    pub pool: PoolParams,
    pub reset: ResetParams,
    pub observation: ObservationLimits,
    pub missed_frames: MissedFrames,
    pub reward: Rewards,
    pub surge: SurgeParams,
    pub thrusters: Thrusters,
    pub render: RenderParams,
    pub perception: PerceptionParams,
    /// How the stack flies the vehicle through its autopilot, if it does (`[pilot]`): then `model`
    /// is the vehicle itself and the stack commands [`Scenario::commanded_model`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pilot: Option<crate::PilotParams>,
}

impl Scenario {
    /// The model of what the stack's commands do: `model` itself, or with a `[pilot]` the
    /// autopilot's response to the pilot's sticks on that vehicle ([`crate::PilotParams::commanded`]).
    /// Step one's simulator, the LQR yardstick, the stability guard and the surge rule use it; the
    /// vehicle twin's plant is `model`.
    pub fn commanded_model(&self) -> ModelParams {
        match &self.pilot {
            Some(p) => p.commanded(&self.model),
            None => self.model.clone(),
        }
    }

    /// The observation box of a learned DOF, `|x_i| <= state_max[i]`: |x_g| <= 0.5 and
    /// |Theta| <= pi/2 (the image's limits), the rates as clipped by [`ObservationLimits`]. Every agent
    /// of a DOF (the trainer's and the behaviour service's) takes its box, and so its failure reward,
    /// from here.
    pub fn state_max(&self, dof: crate::Dof) -> [f64; 2] {
        match dof {
            crate::Dof::Sway => [0.5, self.observation.x_g_rate_max],
            crate::Dof::Yaw => [std::f64::consts::FRAC_PI_2, self.observation.theta_rate_max],
        }
    }
}

impl Validate for Scenario {
    fn validate(&self, key: &str) -> Result<(), Invalid> {
        self.timing.validate(&join(key, "timing"))?;
        self.model.validate(&join(key, "model"))?;
        self.camera.validate(&join(key, "camera"))?;
        self.cable.validate(&join(key, "cable"))?;
        self.pool.validate(&join(key, "pool"))?;
        self.reset.validate(&join(key, "reset"))?;
        self.observation.validate(&join(key, "observation"))?;
        self.missed_frames.validate(&join(key, "missed_frames"))?;
        self.reward.validate(&join(key, "reward"))?;
        self.surge.validate(&join(key, "surge"))?;
        self.thrusters.validate(&join(key, "thrusters"))?;
        self.render.validate(&join(key, "render"))?;
        self.perception.validate(&join(key, "perception"))?;
        if let Some(p) = &self.pilot {
            p.validate(&join(key, "pilot"))?;
            self.commanded_model()
                .validate(&join(key, "pilot"))
                .map_err(|i| {
                    Invalid::new(i.key, i.value, format!("the commanded model: {}", i.reason))
                })?;
        }
        Ok(())
    }
}

/// The control period and the episode length.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Timing {
    /// Seconds between two control steps (the camera's frame period on the vehicle).
    pub sample_time_s: f64,
    /// An episode ends after this many steps, or earlier when the cable leaves the image.
    pub max_steps: u32,
}

impl Default for Timing {
    fn default() -> Self {
        Timing {
            sample_time_s: 0.2,
            max_steps: 200,
        }
    }
}

impl Validate for Timing {
    fn validate(&self, key: &str) -> Result<(), Invalid> {
        in_range(key, "sample_time_s", self.sample_time_s, 0.001, 10.0)?;
        in_range(key, "max_steps", self.max_steps as f64, 1.0, 1.0e7)
    }
}

/// One degree of freedom of the identified model (paper, Table I):
/// `dv/dt = alpha*tau - beta*v*|v| - gamma*v + delta`, with `tau` the normalised thrust in [-1, 1].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DofModel {
    pub alpha: f64,
    pub beta: f64,
    pub gamma: f64,
    pub delta: f64,
}

impl DofModel {
    /// The steady velocity reached under constant thrust `tau`.
    pub fn steady_velocity(&self, tau: f64) -> f64 {
        let force = self.alpha * tau + self.delta;
        if self.beta == 0.0 {
            return force / self.gamma;
        }
        // beta*v|v| + gamma*v = force: solve the quadratic on the side of the force's sign.
        let s = force.signum();
        let a = self.beta;
        let v =
            (-self.gamma + (self.gamma * self.gamma + 4.0 * a * force.abs()).sqrt()) / (2.0 * a);
        s * v
    }
}

impl Validate for DofModel {
    fn validate(&self, key: &str) -> Result<(), Invalid> {
        positive(key, "alpha", self.alpha)?;
        in_range(key, "beta", self.beta, 0.0, 1.0e3)?;
        in_range(key, "gamma", self.gamma, 0.0, 1.0e3)?;
        finite(key, "delta", self.delta)?;
        if self.beta == 0.0 && self.gamma == 0.0 {
            return Err(Invalid::new(
                join(key, "gamma"),
                self.gamma,
                "beta and gamma cannot both be 0 (the velocity would grow without bound)",
            ));
        }
        Ok(())
    }
}

/// The 3-DOF model of DESIGN.md: surge u, sway v, yaw rate r. With a `[pilot]` it is the vehicle's
/// own (what the twin's plant integrates); see [`Scenario::commanded_model`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ModelParams {
    pub surge: DofModel,
    pub sway: DofModel,
    pub yaw: DofModel,
    /// Longest integration sub-step; one 0.2 s Euler step is wrong for yaw (time constant 0.29 s).
    pub max_substep_s: f64,
}

impl Default for ModelParams {
    fn default() -> Self {
        ModelParams {
            surge: DofModel {
                alpha: 0.1347,
                beta: 0.0,
                gamma: 0.4458,
                delta: 0.0040,
            },
            sway: DofModel {
                alpha: 0.1508,
                beta: 0.0,
                gamma: 0.2586,
                delta: -0.0004,
            },
            yaw: DofModel {
                alpha: 0.2878,
                beta: 0.0,
                gamma: 3.4628,
                delta: -0.0026,
            },
            max_substep_s: 0.01,
        }
    }
}

impl Validate for ModelParams {
    fn validate(&self, key: &str) -> Result<(), Invalid> {
        self.surge.validate(&join(key, "surge"))?;
        self.sway.validate(&join(key, "sway"))?;
        self.yaw.validate(&join(key, "yaw"))?;
        in_range(key, "max_substep_s", self.max_substep_s, 1.0e-5, 0.01)
    }
}

/// The downward-looking camera.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CameraParams {
    pub width: u32,
    pub height: u32,
    pub hfov_deg: f64,
    /// Height of the camera above the pool floor (constant: heave is not modelled).
    pub altitude_m: f64,
    /// Camera position in the body frame (forward, starboard) relative to the centre of rotation.
    pub mount_x_m: f64,
    pub mount_y_m: f64,
    /// The cable counts as in view when at least this much of its centre line is inside the image.
    pub min_visible_px: f64,
}

impl Default for CameraParams {
    fn default() -> Self {
        CameraParams {
            width: 320,
            height: 240,
            hfov_deg: 60.0,
            altitude_m: 1.0,
            mount_x_m: 0.0,
            mount_y_m: 0.0,
            min_visible_px: 20.0,
        }
    }
}

impl Validate for CameraParams {
    fn validate(&self, key: &str) -> Result<(), Invalid> {
        in_range(key, "width", self.width as f64, 16.0, 4096.0)?;
        in_range(key, "height", self.height as f64, 16.0, 4096.0)?;
        in_range(key, "hfov_deg", self.hfov_deg, 1.0, 170.0)?;
        in_range(key, "altitude_m", self.altitude_m, 0.05, 100.0)?;
        in_range(key, "mount_x_m", self.mount_x_m, -10.0, 10.0)?;
        in_range(key, "mount_y_m", self.mount_y_m, -10.0, 10.0)?;
        let diagonal = ((self.width as f64).powi(2) + (self.height as f64).powi(2)).sqrt();
        in_range(key, "min_visible_px", self.min_visible_px, 0.0, diagonal)
    }
}

/// The straight cable on the pool floor.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CableParams {
    /// A point of the cable in the pool frame.
    pub x_m: f64,
    pub y_m: f64,
    /// The cable's direction in the pool frame, from x towards y.
    pub heading_deg: f64,
    pub width_m: f64,
}

impl Default for CableParams {
    fn default() -> Self {
        CableParams {
            x_m: 0.0,
            y_m: 0.0,
            heading_deg: 0.0,
            width_m: 0.05,
        }
    }
}

impl Validate for CableParams {
    fn validate(&self, key: &str) -> Result<(), Invalid> {
        finite(key, "x_m", self.x_m)?;
        finite(key, "y_m", self.y_m)?;
        in_range(key, "heading_deg", self.heading_deg, -360.0, 360.0)?;
        in_range(key, "width_m", self.width_m, 0.001, 1.0)
    }
}

/// The pool floor (what the camera sees around the cable).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PoolParams {
    pub length_m: f64,
    pub width_m: f64,
}

impl Default for PoolParams {
    fn default() -> Self {
        PoolParams {
            length_m: 18.0,
            width_m: 8.0,
        }
    }
}

impl Validate for PoolParams {
    fn validate(&self, key: &str) -> Result<(), Invalid> {
        in_range(key, "length_m", self.length_m, 1.0, 1.0e4)?;
        in_range(key, "width_m", self.width_m, 1.0, 1.0e4)
    }
}

/// Where an episode starts: a random pose around the cable with the cable in view.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ResetParams {
    /// x_g ~ U[-x_g_max, x_g_max].
    pub x_g_max: f64,
    /// Theta ~ U[-theta_max_deg, theta_max_deg].
    pub theta_max_deg: f64,
    /// The start point along the cable ~ U[-along_cable_m, along_cable_m] from the cable's point.
    pub along_cable_m: f64,
}

impl Default for ResetParams {
    fn default() -> Self {
        ResetParams {
            x_g_max: 0.35,
            theta_max_deg: 45.0,
            along_cable_m: 3.0,
        }
    }
}

impl Validate for ResetParams {
    fn validate(&self, key: &str) -> Result<(), Invalid> {
        in_range(key, "x_g_max", self.x_g_max, 0.0, 0.45)?;
        in_range(key, "theta_max_deg", self.theta_max_deg, 0.0, 80.0)?;
        in_range(key, "along_cable_m", self.along_cable_m, 0.0, 1.0e4)
    }
}

/// The observation box: rates are clipped to it (DESIGN.md, paper section III-C).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ObservationLimits {
    /// |dx_g/dt| is clipped to this (1/s).
    pub x_g_rate_max: f64,
    /// |dTheta/dt| is clipped to this (rad/s).
    pub theta_rate_max: f64,
}

impl Default for ObservationLimits {
    fn default() -> Self {
        ObservationLimits {
            x_g_rate_max: 0.5,
            theta_rate_max: 1.0,
        }
    }
}

impl Validate for ObservationLimits {
    fn validate(&self, key: &str) -> Result<(), Invalid> {
        positive(key, "x_g_rate_max", self.x_g_rate_max)?;
        positive(key, "theta_rate_max", self.theta_rate_max)
    }
}

/// What a step-two behaviour does in a frame in which perception missed the cable although it is
/// in view. Holding still lets the vehicle coast: with images, a policy that swings the cable fast
/// across the image can miss it for a second or two as it crosses the centre, and drift on to the
/// other edge, where the cable is lost.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MissedFrames {
    /// Missed frames in a row in which the behaviour acts on its DOF's state as the identified model
    /// predicts it from the last observed state and the commands given since (learning nothing
    /// from them); after them, and with 0, it holds still.
    pub predict: u32,
}

impl Validate for MissedFrames {
    fn validate(&self, key: &str) -> Result<(), Invalid> {
        in_range(key, "predict", f64::from(self.predict), 0.0, 50.0)
    }
}

/// A quadratic cost `x'Qx + u'Ru` with diagonal Q; the reward is its negative.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct QuadraticCost {
    /// The diagonal of Q, for (position, rate).
    pub q: [f64; 2],
    pub r: f64,
}

impl QuadraticCost {
    /// The per-step reward `-(x'Qx + u'Ru)`.
    pub fn reward(&self, x: [f64; 2], u: f64) -> f64 {
        -(self.q[0] * x[0] * x[0] + self.q[1] * x[1] * x[1] + self.r * u * u)
    }
}

impl Validate for QuadraticCost {
    fn validate(&self, key: &str) -> Result<(), Invalid> {
        in_range(key, "q[0]", self.q[0], 0.0, 1.0e6)?;
        in_range(key, "q[1]", self.q[1], 0.0, 1.0e6)?;
        in_range(key, "r", self.r, 0.0, 1.0e6)
    }
}

/// The reward of each learned DOF (paper section III-C).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Rewards {
    pub sway: QuadraticCost,
    pub yaw: QuadraticCost,
}

impl Rewards {
    pub fn of(&self, dof: crate::Dof) -> &QuadraticCost {
        match dof {
            crate::Dof::Sway => &self.sway,
            crate::Dof::Yaw => &self.yaw,
        }
    }
}

impl Default for Rewards {
    fn default() -> Self {
        Rewards {
            sway: QuadraticCost {
                q: [1.1, 0.2],
                r: 0.01,
            },
            yaw: QuadraticCost {
                q: [2.0, 0.25],
                r: 0.01,
            },
        }
    }
}

impl Validate for Rewards {
    fn validate(&self, key: &str) -> Result<(), Invalid> {
        self.sway.validate(&join(key, "sway"))?;
        self.yaw.validate(&join(key, "yaw"))
    }
}

/// The surge rule: drive forward while the cable is centred.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SurgeParams {
    pub speed_m_s: f64,
    /// Centred means |x_g| < x_g_max and |Theta| < theta_max_deg.
    pub x_g_max: f64,
    pub theta_max_deg: f64,
}

impl Default for SurgeParams {
    fn default() -> Self {
        SurgeParams {
            speed_m_s: 0.3,
            x_g_max: 0.15,
            theta_max_deg: 15.0,
        }
    }
}

impl Validate for SurgeParams {
    fn validate(&self, key: &str) -> Result<(), Invalid> {
        in_range(key, "speed_m_s", self.speed_m_s, 0.0, 5.0)?;
        in_range(key, "x_g_max", self.x_g_max, 0.0, 0.5)?;
        in_range(key, "theta_max_deg", self.theta_max_deg, 0.0, 90.0)
    }
}

/// One horizontal thruster: where it sits in the body frame and which way positive thrust pushes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ThrusterParams {
    pub name: String,
    pub x_m: f64,
    pub y_m: f64,
    /// Direction of positive thrust in the body frame, from x (forward) towards y (starboard).
    pub heading_deg: f64,
}

/// The most thrusters a layout may have (messages carry a fixed-size setpoint array).
pub const MAX_THRUSTERS: usize = 8;

/// The vehicle's horizontal thrusters (the vertical ones are unused: constant altitude).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Thrusters {
    pub thruster: Vec<ThrusterParams>,
}

impl Default for Thrusters {
    fn default() -> Self {
        let t = |name: &str, x_m, y_m, heading_deg| ThrusterParams {
            name: name.into(),
            x_m,
            y_m,
            heading_deg,
        };
        Thrusters {
            thruster: vec![
                t("port", 0.0, -0.3, 0.0),
                t("starboard", 0.0, 0.3, 0.0),
                t("lateral", 0.0, 0.0, 90.0),
            ],
        }
    }
}

impl Thrusters {
    /// Each thruster's unit generalised force (surge, sway, yaw moment) per unit setpoint.
    pub fn columns(&self) -> Vec<[f64; 3]> {
        self.thruster
            .iter()
            .map(|t| {
                let (s, c) = t.heading_deg.to_radians().sin_cos();
                [c, s, t.x_m * s - t.y_m * c]
            })
            .collect()
    }
}

impl Validate for Thrusters {
    fn validate(&self, key: &str) -> Result<(), Invalid> {
        if self.thruster.is_empty() || self.thruster.len() > MAX_THRUSTERS {
            return Err(Invalid::new(
                join(key, "thruster"),
                self.thruster.len(),
                format!("the layout needs between 1 and {MAX_THRUSTERS} thrusters"),
            ));
        }
        for (i, t) in self.thruster.iter().enumerate() {
            let section = format!("{}[{i}]", join(key, "thruster"));
            finite(&section, "x_m", t.x_m)?;
            finite(&section, "y_m", t.y_m)?;
            finite(&section, "heading_deg", t.heading_deg)?;
            if self.thruster[..i].iter().any(|o| o.name == t.name) {
                return Err(Invalid::new(
                    join(&section, "name"),
                    &t.name,
                    "thruster names must be unique",
                ));
            }
        }
        // The layout must reach all three DOFs: the Gram matrix B B' of the 3 x n layout is invertible.
        let cols = self.columns();
        let mut g = [[0.0; 3]; 3];
        for c in &cols {
            for i in 0..3 {
                for j in 0..3 {
                    g[i][j] += c[i] * c[j];
                }
            }
        }
        let det = g[0][0] * (g[1][1] * g[2][2] - g[1][2] * g[2][1])
            - g[0][1] * (g[1][0] * g[2][2] - g[1][2] * g[2][0])
            + g[0][2] * (g[1][0] * g[2][1] - g[1][1] * g[2][0]);
        if det.abs() < 1e-9 {
            return Err(Invalid::new(
                join(key, "thruster"),
                format!("{} thrusters", cols.len()),
                "the layout cannot produce independent surge, sway and yaw forces",
            ));
        }
        Ok(())
    }
}
