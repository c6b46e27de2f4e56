//! `scenario.toml [pilot]`: the stack flies the vehicle through its autopilot (a BlueROV2 under
//! ArduSub) as a pilot does, with MANUAL_CONTROL's stick axes, instead of driving the thrusters.
//!
//! The stack's command of 1 on a DOF stands for a fraction of the pilot's full stick on that axis
//! (at joystick gain 1): the axis is `command x fraction x 1000 / gain` (`model::pilot`), into which
//! the vehicle twin, whose thrusters are the autopilot's, turns the setpoints it receives, and which
//! the `ardusub` thruster sink sends, in `[pilot]`'s mode. What a stick does depends on the autopilot's mode: in MANUAL
//! every axis is thrust; in STABILIZE and ALT_HOLD (ArduSub's `mode_althold.cpp`) forward and
//! lateral stay thrust while the yaw stick is a yaw-rate command that ArduSub's own fast rate loop
//! follows. [`PilotParams::commanded`] is the model of what the stack's commands then do to the
//! vehicle, from the vehicle's own model: the model step one learns on.
//!
//! The ArduSub parameters that model assumes are named in `[pilot.autopilot]` (by ArduSub's names;
//! the others are taken at ArduSub's defaults): an operator sets them on the vehicle, the twin's
//! autopilot boots with them.

use crate::{
    ARDUSUB_PARAMS, DofModel, Invalid, ModelParams, ParamSpec, Since, Validate, in_range, join,
    param_value_ok,
};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// The ArduSub mode the mesh flies the vehicle in (ArduSub's mode numbers in `ArduSub/mode.h`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PilotMode {
    /// Every stick axis is thrust; heave is left to the vehicle's buoyancy.
    Manual,
    /// The yaw stick is a yaw rate (and the heading held when released); no depth hold.
    Stabilize,
    /// STABILIZE with the depth held by the autopilot (needs a depth sensor).
    AltHold,
}

impl PilotMode {
    pub fn name(self) -> &'static str {
        match self {
            PilotMode::Manual => "manual",
            PilotMode::Stabilize => "stabilize",
            PilotMode::AltHold => "alt_hold",
        }
    }

    /// Whether the yaw stick is a yaw-rate command (the stabilised modes).
    pub fn yaw_is_rate(self) -> bool {
        self != PilotMode::Manual
    }
}

/// Per DOF, the fraction of the pilot's full stick (at joystick gain 1) that the stack's command
/// of 1 stands for.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PilotFractions {
    pub surge: f64,
    pub sway: f64,
    pub yaw: f64,
}

/// How the stack pilots the vehicle's autopilot.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PilotParams {
    pub mode: PilotMode,
    pub fraction: PilotFractions,
    /// The stabilised modes only: the time constant (s) of the yaw rate's response to the yaw
    /// stick, autopilot and vehicle together (identified, like the vehicle's model).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub yaw_rate_time_constant_s: Option<f64>,
    /// ArduSub parameters the commanded model assumes, by name; the others at ArduSub's defaults.
    #[serde(default)]
    pub autopilot: BTreeMap<String, f64>,
}

/// The yaw stick's full deflection as ArduSub reads it (centidegrees: `ROLL_PITCH_INPUT_MAX`);
/// `get_pilot_desired_yaw_rate` multiplies it by `ACRO_YAW_P` to centidegrees per second.
pub const FULL_STICK_CDEG: f64 = 4500.0;
/// `ACRO_YAW_P`'s default, against which MANUAL mode scales the yaw stick (`mode_manual.cpp`).
pub const ACRO_YAW_P_DEFAULT: f64 = 4.5;

impl PilotParams {
    fn spec(name: &str) -> Option<&'static ParamSpec> {
        ARDUSUB_PARAMS
            .iter()
            .find(|s| s.name == name && s.since == Since::Both)
    }

    /// The value the commanded model assumes for ArduSub parameter `name`: the configured one or
    /// ArduSub's default. Panics for a name outside the emulated table (a programming error).
    pub fn param(&self, name: &str) -> f64 {
        let spec = Self::spec(name).unwrap_or_else(|| panic!("{name} is an ArduSub parameter"));
        self.autopilot.get(name).copied().unwrap_or(spec.default)
    }

    /// The stabilised modes' yaw rate at the pilot's full stick (rad/s): 45 degrees of stick times
    /// `ACRO_YAW_P` per second.
    pub fn full_stick_yaw_rate(&self) -> f64 {
        (FULL_STICK_CDEG / 100.0 * self.param("ACRO_YAW_P")).to_radians()
    }

    /// The yaw rate the stack's yaw command of 1 asks for in the stabilised modes (rad/s).
    pub fn yaw_rate_max(&self) -> f64 {
        self.fraction.yaw * self.full_stick_yaw_rate()
    }

    /// The model of what the stack's commands do to a vehicle whose own model is `vehicle`: surge
    /// and sway (and yaw in MANUAL) are that DOF's thrust scaled by its fraction; in the stabilised
    /// modes yaw is the autopilot's closed rate loop, `dr/dt = (r_max u - r) / tau`, i.e.
    /// alpha = r_max / tau, gamma = 1 / tau, no quadratic damping and no bias.
    pub fn commanded(&self, vehicle: &ModelParams) -> ModelParams {
        let scaled = |m: DofModel, f: f64| DofModel {
            alpha: m.alpha * f,
            ..m
        };
        let yaw = match self.yaw_rate_time_constant_s {
            Some(tau) if self.mode.yaw_is_rate() => DofModel {
                alpha: self.yaw_rate_max() / tau,
                beta: 0.0,
                gamma: 1.0 / tau,
                delta: 0.0,
            },
            _ => scaled(
                vehicle.yaw,
                self.fraction.yaw * self.param("ACRO_YAW_P") / ACRO_YAW_P_DEFAULT,
            ),
        };
        ModelParams {
            surge: scaled(vehicle.surge, self.fraction.surge),
            sway: scaled(vehicle.sway, self.fraction.sway),
            yaw,
            max_substep_s: vehicle.max_substep_s,
        }
    }
}

impl Validate for PilotParams {
    fn validate(&self, key: &str) -> Result<(), Invalid> {
        let fraction = join(key, "fraction");
        for (name, f) in [
            ("surge", self.fraction.surge),
            ("sway", self.fraction.sway),
            ("yaw", self.fraction.yaw),
        ] {
            if !(f.is_finite() && f > 0.0 && f <= 1.0) {
                return Err(Invalid::new(
                    join(&fraction, name),
                    f,
                    "must be within (0, 1]: a fraction of the pilot's full stick",
                ));
            }
        }
        let params = join(key, "autopilot");
        for (name, &value) in &self.autopilot {
            let spec = Self::spec(name).ok_or_else(|| {
                Invalid::new(
                    join(&params, name),
                    value,
                    "not an ArduSub parameter the twin emulates in every generation",
                )
            })?;
            param_value_ok(spec, value).map_err(|r| Invalid::new(join(&params, name), value, r))?;
        }
        match (self.mode.yaw_is_rate(), self.yaw_rate_time_constant_s) {
            (true, None) => {
                return Err(Invalid::new(
                    join(key, "yaw_rate_time_constant_s"),
                    "missing",
                    format!(
                        "{} makes the yaw stick a yaw rate: its loop's time constant is needed",
                        self.mode.name()
                    ),
                ));
            }
            (false, Some(tau)) => {
                return Err(Invalid::new(
                    join(key, "yaw_rate_time_constant_s"),
                    tau,
                    "only the stabilised modes close a yaw-rate loop (mode is manual)",
                ));
            }
            (true, Some(tau)) => in_range(key, "yaw_rate_time_constant_s", tau, 0.001, 10.0)?,
            (false, None) => {}
        }
        // The yaw channel's dead zone (RC4_DZ x gain us around 1500) makes every smaller yaw
        // stick a release in the stabilised modes: the commanded model has no dead zone.
        let dz = self.param("RC4_DZ");
        if self.mode.yaw_is_rate() && dz != 0.0 {
            return Err(Invalid::new(
                join(&params, "RC4_DZ"),
                dz,
                "must be 0 in the stabilised modes: the yaw dead zone would swallow the stack's \
                 small yaw-rate commands (ArduSub's default is 40)",
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{ConfigError, Scenario};
    use std::path::Path;

    const ALT_HOLD: &str = "[pilot]\nmode = \"alt_hold\"\nfraction = { surge = 0.05, sway = 0.07, yaw = 0.2 }\nyaw_rate_time_constant_s = 0.1\n[pilot.autopilot]\nACRO_YAW_P = 1.0\nRC4_DZ = 0\n";

    fn parse(text: &str) -> Result<Scenario, ConfigError> {
        crate::parse(text, Path::new("config/bluerov2/scenario.toml"))
    }

    fn refused(text: &str) -> String {
        let err = parse(text).unwrap_err().to_string();
        assert!(err.contains("config/bluerov2/scenario.toml"), "{err}");
        err
    }

    #[test]
    fn the_section_is_optional_and_loads_when_given() {
        assert_eq!(parse("").unwrap().pilot, None);
        let s = parse(ALT_HOLD).unwrap();
        let p = s.pilot.unwrap();
        assert_eq!(p.mode, PilotMode::AltHold);
        assert_eq!(
            p.fraction,
            PilotFractions {
                surge: 0.05,
                sway: 0.07,
                yaw: 0.2
            }
        );
        assert_eq!(p.yaw_rate_time_constant_s, Some(0.1));
        assert_eq!((p.param("ACRO_YAW_P"), p.param("RC4_DZ")), (1.0, 0.0));
        assert_eq!(p.param("JS_GAIN_DEFAULT"), 0.5, "ArduSub's default");
    }

    #[test]
    fn unknown_keys_and_bad_values_are_refused_naming_file_and_key() {
        let err = refused(&ALT_HOLD.replace("fraction =", "fractoin ="));
        assert!(err.contains("fractoin"), "{err}");
        let err = refused(&ALT_HOLD.replace("yaw = 0.2", "yaw = 0.2, heave = 0.1"));
        assert!(err.contains("heave"), "{err}");
        let err = refused(&ALT_HOLD.replace("\"alt_hold\"", "\"acro\""));
        assert!(err.contains("acro"), "{err}");
        let err = refused(&ALT_HOLD.replace("sway = 0.07", "sway = 1.5"));
        assert!(err.contains("pilot.fraction.sway"), "{err}");
        let err = refused(&ALT_HOLD.replace("surge = 0.05", "surge = 0"));
        assert!(err.contains("pilot.fraction.surge"), "{err}");
        let err = refused(&ALT_HOLD.replace("RC4_DZ = 0", "RC4_DZ = 0\nNOT_A_PARAM = 1"));
        assert!(err.contains("pilot.autopilot.NOT_A_PARAM"), "{err}");
        let err = refused(&ALT_HOLD.replace("ACRO_YAW_P = 1.0", "ACRO_YAW_P = 0.5"));
        assert!(err.contains("pilot.autopilot.ACRO_YAW_P"), "{err}");
        // A generation's own parameter belongs to the twin's [autopilot.params].
        let err = refused(&ALT_HOLD.replace("RC4_DZ = 0", "RC4_DZ = 0\nMAV_GCS_SYSID = 255"));
        assert!(err.contains("pilot.autopilot.MAV_GCS_SYSID"), "{err}");
        // ArduSub's default yaw dead zone is refused in the stabilised modes.
        let err = refused(&ALT_HOLD.replace("RC4_DZ = 0\n", ""));
        assert!(
            err.contains("pilot.autopilot.RC4_DZ") && err.contains("40"),
            "{err}"
        );
        let err = refused(&ALT_HOLD.replace("yaw_rate_time_constant_s = 0.1\n", ""));
        assert!(err.contains("pilot.yaw_rate_time_constant_s"), "{err}");
        let err = refused(&ALT_HOLD.replace("\"alt_hold\"", "\"manual\""));
        assert!(err.contains("pilot.yaw_rate_time_constant_s"), "{err}");
        let err = refused(&ALT_HOLD.replace("= 0.1\n", "= 0\n"));
        assert!(err.contains("pilot.yaw_rate_time_constant_s"), "{err}");
    }

    /// Surge and sway: the vehicle's thrust times the fraction, its damping as it is. Yaw in the
    /// stabilised modes: the rate loop, r_max = fraction x 45 deg x ACRO_YAW_P per second.
    #[test]
    fn the_commanded_model_scales_thrust_and_closes_the_yaw_rate_loop() {
        let s = parse(ALT_HOLD).unwrap();
        let vehicle = &s.model;
        let m = s.pilot.as_ref().unwrap().commanded(vehicle);
        assert_eq!(m.surge.alpha, 0.05 * vehicle.surge.alpha);
        assert_eq!(m.sway.alpha, 0.07 * vehicle.sway.alpha);
        assert_eq!(
            (m.sway.beta, m.sway.gamma, m.sway.delta),
            (vehicle.sway.beta, vehicle.sway.gamma, vehicle.sway.delta)
        );
        let r_max = 0.2 * 45f64.to_radians();
        assert!((m.yaw.alpha - r_max / 0.1).abs() < 1e-12);
        assert_eq!((m.yaw.beta, m.yaw.gamma, m.yaw.delta), (0.0, 10.0, 0.0));
        assert!((m.yaw.steady_velocity(1.0) - r_max).abs() < 1e-12);
        assert_eq!(m.max_substep_s, vehicle.max_substep_s);
        assert_eq!(s.commanded_model(), m);
        // MANUAL: yaw is thrust too, scaled by ACRO_YAW_P against its default.
        let manual = parse(
            &ALT_HOLD
                .replace("\"alt_hold\"", "\"manual\"")
                .replace("yaw_rate_time_constant_s = 0.1\n", ""),
        )
        .unwrap();
        let m = manual.commanded_model();
        assert!((m.yaw.alpha - 0.2 / 4.5 * vehicle.yaw.alpha).abs() < 1e-12);
        assert_eq!(m.yaw.gamma, vehicle.yaw.gamma);
        // Without [pilot] the stack commands the model itself.
        assert_eq!(
            Scenario::default().commanded_model(),
            Scenario::default().model
        );
    }
}
