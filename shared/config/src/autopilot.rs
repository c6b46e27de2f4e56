//! `twin.toml [autopilot]`: the vehicle twin standing in for a BlueROV2's ArduSub autopilot over
//! MAVLink (`vehicle-twin --autopilot URL`).
//!
//! The parameter table is ArduSub's, by name, with ArduSub's defaults and ranges (ArduSub's
//! `Parameters.cpp`, `libraries/GCS_MAVLink/GCS.cpp`, `libraries/AP_Motors/AP_Motors6DOF.cpp`):
//! `[autopilot.params]` sets some of them, the others keep their defaults. The ground station's
//! system id is a parameter of the GCS library from ArduSub 4.7 on (`MAV_GCS_SYSID`, with
//! `MAV_GCS_SYSID_HI` for a range) and of the vehicle before (`SYSID_MYGCS`);
//! [`ArduSubGeneration`] picks which the twin emulates, and a parameter of the other generation is
//! refused by name.

use crate::{Invalid, Validate, in_range, join};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Which ArduSub the twin emulates: the names of its ground-station id parameters differ.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum ArduSubGeneration {
    /// ArduSub 4.7 and later: `MAV_SYSID`, `MAV_GCS_SYSID`, `MAV_GCS_SYSID_HI`.
    #[default]
    #[serde(rename = "4.7")]
    V4_7,
    /// Before 4.7 (BlueOS's 4.1 and 4.5): `SYSID_THISMAV`, `SYSID_MYGCS`.
    #[serde(rename = "4.5")]
    V4_5,
}

impl ArduSubGeneration {
    pub fn name(self) -> &'static str {
        match self {
            ArduSubGeneration::V4_7 => "4.7",
            ArduSubGeneration::V4_5 => "4.5",
        }
    }
}

/// How ArduSub stores a parameter (it sends the value as a float with this type).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ParamKind {
    Int8,
    Int16,
    Real32,
}

/// Which generations have a parameter.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Since {
    Both,
    Only(ArduSubGeneration),
}

/// One ArduSub parameter the twin emulates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ParamSpec {
    pub name: &'static str,
    pub default: f64,
    pub min: f64,
    pub max: f64,
    pub kind: ParamKind,
    pub since: Since,
}

const fn p(name: &'static str, default: f64, min: f64, max: f64, kind: ParamKind) -> ParamSpec {
    ParamSpec {
        name,
        default,
        min,
        max,
        kind,
        since: Since::Both,
    }
}

const fn only(spec: ParamSpec, generation: ArduSubGeneration) -> ParamSpec {
    ParamSpec {
        since: Since::Only(generation),
        ..spec
    }
}

use ArduSubGeneration::{V4_5, V4_7};
use ParamKind::{Int8, Int16, Real32};

/// ArduSub's parameters as the twin emulates them, in the order PARAM_REQUEST_LIST sends them.
pub const ARDUSUB_PARAMS: &[ParamSpec] = &[
    // The vehicle's own system id and the ground stations' (GCS.cpp from 4.7; Parameters.cpp before).
    only(p("MAV_SYSID", 1.0, 1.0, 255.0, Int16), V4_7),
    only(p("MAV_GCS_SYSID", 255.0, 1.0, 255.0, Int16), V4_7),
    only(p("MAV_GCS_SYSID_HI", 0.0, 0.0, 255.0, Int16), V4_7),
    only(p("SYSID_THISMAV", 1.0, 1.0, 255.0, Int16), V4_5),
    only(p("SYSID_MYGCS", 255.0, 1.0, 255.0, Int16), V4_5),
    // The pilot-input failsafe (failsafe.cpp): 0 disabled, 1 warn only, 2 disarm; the controls go to
    // neutral in both 1 and 2.
    p("FS_PILOT_INPUT", 2.0, 0.0, 2.0, Int8),
    p("FS_PILOT_TIMEOUT", 3.0, 0.1, 3.0, Real32),
    // The joystick's gain (joystick.cpp): the gain at boot is JS_GAIN_DEFAULT within
    // [JS_GAIN_MIN, JS_GAIN_MAX]; the axes are scaled by 0.4 x gain around 1500 us.
    p("JS_GAIN_DEFAULT", 0.5, 0.1, 1.0, Real32),
    p("JS_GAIN_MAX", 1.0, 0.2, 1.0, Real32),
    p("JS_GAIN_MIN", 0.25, 0.1, 0.8, Real32),
    p("JS_GAIN_STEPS", 4.0, 1.0, 10.0, Int8),
    p("JS_THR_GAIN", 1.0, 0.5, 4.0, Real32),
    // The frame: 1 is the BlueROV2's vectored frame, the only one the twin mixes.
    p("FRAME_CONFIG", 1.0, 1.0, 1.0, Int8),
    // Motor directions (AP_Motors6DOF.cpp): 1 normal, -1 reversed.
    p("MOT_1_DIRECTION", 1.0, -1.0, 1.0, Int8),
    p("MOT_2_DIRECTION", 1.0, -1.0, 1.0, Int8),
    p("MOT_3_DIRECTION", 1.0, -1.0, 1.0, Int8),
    p("MOT_4_DIRECTION", 1.0, -1.0, 1.0, Int8),
    p("MOT_5_DIRECTION", 1.0, -1.0, 1.0, Int8),
    p("MOT_6_DIRECTION", 1.0, -1.0, 1.0, Int8),
    // Forward/vertical decoupling of the vectored frame.
    p("MOT_FV_CPLNG_K", 1.0, 0.0, 1.5, Real32),
    // The pilot's yaw rate per stick in the stabilised modes (deg/s per 45 deg of stick: 4.5
    // gives 202.5 deg/s at full stick and full gain).
    p("ACRO_YAW_P", 4.5, 1.0, 10.0, Real32),
    // The dead zone of the yaw channel (us around 1500; radio.cpp: 40 for the yaw channel), which
    // the stabilised modes scale by the joystick gain (`mode_althold.cpp`).
    p("RC4_DZ", 40.0, 0.0, 200.0, Int16),
    // The yaw attitude loop (AC_AttitudeControl_Sub.h's defaults): heading error to yaw rate
    // (1/s); the acceleration limit of the pilot's yaw rate (cdeg/s/s, 0: none); the rate
    // controller's P and I (yaw output per rad/s, per rad), its integrator's limit and its
    // target filter (Hz, 0: none).
    p("ATC_ANG_YAW_P", 6.0, 0.0, 12.0, Real32),
    p("ATC_ACCEL_Y_MAX", 110_000.0, 0.0, 180_000.0, Real32),
    p("ATC_RAT_YAW_P", 0.18, 0.0, 2.5, Real32),
    p("ATC_RAT_YAW_I", 0.018, 0.0, 1.0, Real32),
    p("ATC_RAT_YAW_IMAX", 0.222, 0.0, 1.0, Real32),
    p("ATC_RAT_YAW_FLTT", 5.0, 0.0, 100.0, Real32),
];

/// The stand-in autopilot's setup.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AutopilotParams {
    /// Which ArduSub's ground-station id parameters the twin emulates.
    pub generation: ArduSubGeneration,
    /// The depth the vehicle keeps (m): VFR_HUD's `alt` is `-depth_m` (heave is not modelled).
    pub depth_m: f64,
    /// Whether a depth sensor is connected: ArduSub refuses ALT_HOLD without one.
    pub depth_sensor: bool,
    /// The battery SYS_STATUS reports: voltage (V) and current (A).
    pub battery_v: f64,
    pub battery_a: f64,
    /// ArduSub parameters set on the autopilot, by name; the others keep ArduSub's defaults.
    pub params: BTreeMap<String, f64>,
}

impl Default for AutopilotParams {
    fn default() -> Self {
        AutopilotParams {
            generation: ArduSubGeneration::V4_7,
            depth_m: 1.0,
            depth_sensor: true,
            // A BlueROV2's 4S battery (14.8 V nominal), charged.
            battery_v: 15.6,
            battery_a: 2.0,
            params: BTreeMap::new(),
        }
    }
}

impl AutopilotParams {
    /// The specs of this generation's parameters, in table order.
    pub fn specs(&self) -> impl Iterator<Item = &'static ParamSpec> + '_ {
        ARDUSUB_PARAMS.iter().filter(|s| match s.since {
            Since::Both => true,
            Since::Only(g) => g == self.generation,
        })
    }

    /// The value of `name` at boot: the configured one, or ArduSub's default.
    pub fn value(&self, name: &str) -> Option<f64> {
        let spec = self.specs().find(|s| s.name == name)?;
        Some(self.params.get(name).copied().unwrap_or(spec.default))
    }
}

impl AutopilotParams {
    /// The autopilot as the stack that pilots it through `pilot` assumes it: the parameters of
    /// `[pilot.autopilot]` (the scenario's) set over these, as an operator sets them on the vehicle.
    /// A parameter this file sets to another value is refused (`key` names this section).
    pub fn flown_by(&self, pilot: &crate::PilotParams, key: &str) -> Result<Self, Invalid> {
        let mut a = self.clone();
        for (name, &value) in &pilot.autopilot {
            match a.params.insert(name.clone(), value) {
                Some(own) if own != value => {
                    return Err(Invalid::new(
                        join(&join(key, "params"), name),
                        own,
                        format!(
                            "the scenario's [pilot.autopilot] assumes {value}: set it there only"
                        ),
                    ));
                }
                _ => {}
            }
        }
        a.validate(key)?;
        Ok(a)
    }
}

/// Whether `value` is acceptable for `spec` (in range; whole for integers; a direction is +-1).
pub fn param_value_ok(spec: &ParamSpec, value: f64) -> Result<(), String> {
    if !(value.is_finite() && value >= spec.min && value <= spec.max) {
        return Err(format!("must be within [{}, {}]", spec.min, spec.max));
    }
    if spec.kind != ParamKind::Real32 && value.fract() != 0.0 {
        return Err("must be a whole number".into());
    }
    if spec.name.ends_with("_DIRECTION") && value == 0.0 {
        return Err("must be 1 (normal) or -1 (reversed)".into());
    }
    Ok(())
}

impl Validate for AutopilotParams {
    fn validate(&self, key: &str) -> Result<(), Invalid> {
        in_range(key, "depth_m", self.depth_m, 0.0, 300.0)?;
        in_range(key, "battery_v", self.battery_v, 0.0, 60.0)?;
        in_range(key, "battery_a", self.battery_a, 0.0, 300.0)?;
        let params = join(key, "params");
        for (name, &value) in &self.params {
            let spec = self.specs().find(|s| s.name == name).ok_or_else(|| {
                let other = ARDUSUB_PARAMS.iter().any(|s| s.name == name);
                let reason = if other {
                    format!(
                        "not a parameter of ArduSub {} (see `generation`)",
                        self.generation.name()
                    )
                } else {
                    "not an ArduSub parameter the twin emulates".to_string()
                };
                Invalid::new(join(&params, name), value, reason)
            })?;
            param_value_ok(spec, value).map_err(|r| Invalid::new(join(&params, name), value, r))?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn parse(text: &str) -> Result<AutopilotParams, crate::ConfigError> {
        #[derive(Deserialize)]
        #[serde(deny_unknown_fields)]
        struct File {
            autopilot: AutopilotParams,
        }
        impl Validate for File {
            fn validate(&self, key: &str) -> Result<(), Invalid> {
                self.autopilot.validate(&join(key, "autopilot"))
            }
        }
        crate::parse::<File>(text, Path::new("twin.toml")).map(|f| f.autopilot)
    }

    #[test]
    fn each_generation_has_its_own_ground_station_parameters() {
        let a = parse("[autopilot]\ngeneration = \"4.7\"\n[autopilot.params]\nMAV_GCS_SYSID_HI = 255\nMAV_GCS_SYSID = 200\n").unwrap();
        assert_eq!(a.value("MAV_GCS_SYSID"), Some(200.0));
        assert_eq!(a.value("MAV_GCS_SYSID_HI"), Some(255.0));
        assert_eq!(a.value("SYSID_MYGCS"), None);
        let b = parse("[autopilot]\ngeneration = \"4.5\"\n[autopilot.params]\nSYSID_MYGCS = 254\n")
            .unwrap();
        assert_eq!(b.value("SYSID_MYGCS"), Some(254.0));
        assert_eq!(b.value("MAV_GCS_SYSID"), None);
        assert_eq!(b.value("FS_PILOT_TIMEOUT"), Some(3.0), "ArduSub's default");

        let err =
            parse("[autopilot]\ngeneration = \"4.5\"\n[autopilot.params]\nMAV_GCS_SYSID = 1\n")
                .unwrap_err()
                .to_string();
        assert!(
            err.contains("autopilot.params.MAV_GCS_SYSID") && err.contains("ArduSub 4.5"),
            "{err}"
        );
    }

    #[test]
    fn bad_parameters_are_refused_by_name() {
        for (text, key) in [
            ("FS_PILOT_TIMEOUT = 5.0", "FS_PILOT_TIMEOUT"),
            ("FS_PILOT_INPUT = 1.5", "FS_PILOT_INPUT"),
            ("MOT_3_DIRECTION = 0", "MOT_3_DIRECTION"),
            ("JS_GAIN_DEFAULT = 2", "JS_GAIN_DEFAULT"),
            ("NOT_A_PARAM = 1", "NOT_A_PARAM"),
        ] {
            let err = parse(&format!("[autopilot.params]\n{text}\n"))
                .unwrap_err()
                .to_string();
            assert!(
                err.contains(&format!("autopilot.params.{key}")) && err.contains("twin.toml"),
                "{err}"
            );
        }
        let err = parse("[autopilot]\ngeneration = \"4.6\"\n")
            .unwrap_err()
            .to_string();
        assert!(err.contains("generation"), "{err}");
    }

    /// The scenario's [pilot.autopilot] is set over the twin's parameters; the twin setting one of
    /// them to another value is refused, naming its key.
    #[test]
    fn the_pilots_parameters_are_set_over_the_twins() {
        let pilot: crate::PilotParams = toml::from_str(
            "mode = \"alt_hold\"\nfraction = { surge = 0.1, sway = 0.1, yaw = 0.1 }\n\
             yaw_rate_time_constant_s = 0.05\n[autopilot]\nACRO_YAW_P = 1.0\nRC4_DZ = 0\n",
        )
        .unwrap();
        let twin = parse("[autopilot.params]\nJS_GAIN_DEFAULT = 0.8\n").unwrap();
        let flown = twin.flown_by(&pilot, "autopilot").unwrap();
        assert_eq!(flown.value("ACRO_YAW_P"), Some(1.0));
        assert_eq!(flown.value("RC4_DZ"), Some(0.0));
        assert_eq!(flown.value("JS_GAIN_DEFAULT"), Some(0.8));
        // The same value twice is no conflict.
        let same = parse("[autopilot.params]\nACRO_YAW_P = 1.0\n").unwrap();
        let flown = same.flown_by(&pilot, "autopilot").unwrap();
        assert_eq!(flown.value("ACRO_YAW_P"), Some(1.0));
        assert_eq!(flown.value("RC4_DZ"), Some(0.0));
        let other = parse("[autopilot.params]\nRC4_DZ = 40\n").unwrap();
        let err = other.flown_by(&pilot, "autopilot").unwrap_err();
        assert_eq!(err.key, "autopilot.params.RC4_DZ");
        assert!(err.reason.contains("[pilot.autopilot]"), "{err}");
    }

    #[test]
    fn the_defaults_are_ardusubs() {
        let a = AutopilotParams::default();
        a.validate("autopilot").unwrap();
        for s in ARDUSUB_PARAMS {
            param_value_ok(s, s.default).unwrap_or_else(|e| panic!("{}: {e}", s.name));
        }
        assert_eq!(a.value("FS_PILOT_INPUT"), Some(2.0));
        assert_eq!(a.value("JS_GAIN_DEFAULT"), Some(0.5));
        assert_eq!(a.value("MAV_GCS_SYSID"), Some(255.0));
        assert_eq!(a.specs().filter(|s| s.name.contains("SYSID")).count(), 3);
    }
}
