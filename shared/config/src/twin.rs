//! `twin.toml`: the vehicle twin, the plant behind the vehicle endpoint's hardware adapters.
//!
//! The identified model of `scenario.toml` leaves things out on purpose (the paper dropped quadratic
//! damping and assumed low speed). The twin puts them back: this file is the *reality gap*
//! (DESIGN.md). Every effect has an `enabled` switch, so each can be studied alone; the image effects
//! are the `enabled` switches of the twin's own `[render]` table (harsher than the simulator's).
//! [`TwinParams::ideal`] switches everything off: the twin then behaves as the simulator does.

use crate::{Invalid, RenderParams, ResetParams, Validate, in_range, join, positive};
use serde::{Deserialize, Serialize};

/// Everything that makes the twin differ from the identified model.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TwinParams {
    pub trials: TrialParams,
    pub damping: DampingParams,
    pub thrusters: ThrusterGap,
    pub current: CurrentParams,
    pub camera: MountParams,
    pub frames: FrameParams,
    pub latency: LatencyParams,
    /// The twin camera's image: its own effects, harsher than the simulator's `[render]`.
    pub render: RenderParams,
    /// The vehicle's autopilot, a stand-in ArduSub (`[autopilot]`): the thrusters are its motors,
    /// whether the stack pilots it over MAVLink (`vehicle-twin --autopilot URL`) or through the
    /// twin's thruster topic (the setpoints turned into its pilot's sticks, `scenario.toml
    /// [pilot]`). Without it the thrusters take the setpoints themselves.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub autopilot: Option<crate::AutopilotParams>,
}

/// Trials, as on the real vehicle (paper section IV-B): a trial lasts `duration_s` of twin time or
/// until the cable leaves the image; then the vehicle is repositioned and the next trial begins.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrialParams {
    pub duration_s: f64,
    /// Where a trial starts: a random pose around the cable with the cable in view.
    pub reposition: ResetParams,
    /// 0: every trial starts from a new random pose. N > 0: the trials cycle through N random
    /// poses drawn when the twin starts (a pool protocol: the operator puts the vehicle back at the
    /// same few starts, so trials far apart compare, e.g. the first N with the last N).
    pub cycle: u32,
}

/// Quadratic damping, put back: each DOF's `dv/dt` gets `- beta v|v|`. The identified model fitted a
/// linear drag `gamma v` to a vehicle whose drag is partly quadratic; it matched at the speeds of the
/// identification runs. The twin keeps the identified drag at that speed and splits it:
/// `gamma_twin = gamma - beta * identified_at`, so the twin is as fast as the model at full thrust
/// but less damped at low speed (where the cable is tracked) and more above.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DampingParams {
    pub enabled: bool,
    pub surge: DofDamping,
    pub sway: DofDamping,
    pub yaw: DofDamping,
}

/// One DOF's quadratic damping.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DofDamping {
    /// The quadratic coefficient (1/m for surge and sway, 1/rad for yaw).
    pub beta: f64,
    /// The speed (m/s, rad/s for yaw) at which the identified linear drag matched the vehicle's.
    pub identified_at: f64,
}

impl DofDamping {
    /// The twin's linear and quadratic damping for a DOF identified as `gamma` (linear only).
    pub fn split(&self, gamma: f64) -> (f64, f64) {
        ((gamma - self.beta * self.identified_at).max(0.0), self.beta)
    }
}

/// The thrusters as they are: stronger or weaker than identified, slow, with a dead band, weaker in
/// reverse, stopped by a watchdog.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ThrusterGap {
    pub gain: GainParams,
    pub lag: LagParams,
    pub dead_band: DeadBandParams,
    pub asymmetry: AsymmetryParams,
    /// Thrusters stop when no setpoints have arrived for this long (twin time, s); until then they
    /// hold the last setpoints (a dropped frame gets no answer).
    pub watchdog_s: f64,
}

/// Thrust per unit of setpoint against the identified model's: `factor` > 1 is a vehicle more
/// responsive than identified (the identification underestimated its thrust), < 1 a weaker one.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GainParams {
    pub enabled: bool,
    pub factor: f64,
}

impl GainParams {
    /// The thrust factor; 1 when disabled.
    pub fn factor(&self) -> f64 {
        if self.enabled { self.factor } else { 1.0 }
    }
}

/// First-order lag: the thrust follows its setpoint with this time constant.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LagParams {
    pub enabled: bool,
    pub time_constant_s: f64,
}

/// Setpoints smaller than this in magnitude do not turn the propeller (no thrust).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DeadBandParams {
    pub enabled: bool,
    pub setpoint: f64,
}

/// Forward/reverse asymmetry: a propeller pushes this fraction as hard in reverse as forward.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AsymmetryParams {
    pub enabled: bool,
    pub reverse_gain: f64,
}

/// A uniform water current (pool frame).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CurrentParams {
    pub enabled: bool,
    pub speed_m_s: f64,
    /// The direction the water flows to, from the pool's x axis towards its y axis.
    pub direction_deg: f64,
}

impl CurrentParams {
    /// The current's velocity (pool frame, m/s); zero when disabled.
    pub fn velocity(&self) -> [f64; 2] {
        if !self.enabled {
            return [0.0, 0.0];
        }
        let (s, c) = self.direction_deg.to_radians().sin_cos();
        [self.speed_m_s * c, self.speed_m_s * s]
    }
}

/// The camera mounted off the centre of rotation (body frame: forward, starboard).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MountParams {
    pub enabled: bool,
    pub mount_x_m: f64,
    pub mount_y_m: f64,
}

impl MountParams {
    /// The mounting offset (forward, starboard); zero when disabled.
    pub fn offset(&self) -> [f64; 2] {
        if self.enabled {
            [self.mount_x_m, self.mount_y_m]
        } else {
            [0.0, 0.0]
        }
    }
}

/// What happens to frames between the camera and the vehicle's computer.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FrameParams {
    pub dropped: DropParams,
}

/// Frames lost on the way: each frame is dropped with this probability (a trial's last frame, which
/// tells the vehicle side that the trial ended, is never dropped).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DropParams {
    pub enabled: bool,
    pub probability: f64,
}

impl DropParams {
    /// The probability of dropping a frame; 0 when disabled.
    pub fn rate(&self) -> f64 {
        if self.enabled { self.probability } else { 0.0 }
    }
}

/// Camera-to-command latency: exposure, transfer and processing take time, so the setpoints answering
/// a frame reach the thrusters `frames` control periods after the frame was taken instead of at once.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LatencyParams {
    pub enabled: bool,
    pub frames: u32,
}

impl LatencyParams {
    /// The periods an answer waits before it is applied; 0 when disabled.
    pub fn periods(&self) -> usize {
        if self.enabled {
            self.frames as usize
        } else {
            0
        }
    }
}

/// The longest camera-to-command latency the twin models, in control periods.
pub const MAX_LATENCY_FRAMES: u32 = 10;

impl Default for TwinParams {
    fn default() -> Self {
        TwinParams {
            trials: TrialParams::default(),
            damping: DampingParams::default(),
            thrusters: ThrusterGap::default(),
            current: CurrentParams::default(),
            camera: MountParams::default(),
            frames: FrameParams::default(),
            latency: LatencyParams::default(),
            render: TwinParams::default_render(),
            autopilot: None,
        }
    }
}

impl TwinParams {
    /// The twin camera's image: the simulator's effects, harsher (more noise, longer exposure, a
    /// stronger lamp fall-off, more clutter).
    pub fn default_render() -> RenderParams {
        let mut r = RenderParams::default();
        r.clutter.coverage = 0.22;
        r.lighting.vignetting = 0.55;
        r.lighting.gradient = 0.4;
        r.noise.std_dn = 12.0;
        r.blur.exposure_s = 0.08;
        r
    }

    /// Every effect of the reality gap off (the trials and the watchdog stay): the twin's plant is
    /// the identified model, its camera the simulator's (clean images).
    pub fn ideal() -> Self {
        let mut t = TwinParams::default();
        t.damping.enabled = false;
        t.thrusters.gain.enabled = false;
        t.thrusters.lag.enabled = false;
        t.thrusters.dead_band.enabled = false;
        t.thrusters.asymmetry.enabled = false;
        t.current.enabled = false;
        t.camera.enabled = false;
        t.frames.dropped.enabled = false;
        t.latency.enabled = false;
        t.render = RenderParams::clean();
        t
    }
}

impl Default for TrialParams {
    fn default() -> Self {
        TrialParams {
            duration_s: 90.0,
            reposition: ResetParams::default(),
            cycle: 5,
        }
    }
}

impl Default for DampingParams {
    fn default() -> Self {
        DampingParams {
            enabled: true,
            surge: DofDamping {
                beta: 0.8,
                identified_at: 0.3,
            },
            sway: DofDamping {
                beta: 0.8,
                identified_at: 0.3,
            },
            yaw: DofDamping {
                beta: 38.0,
                identified_at: 0.08,
            },
        }
    }
}

impl Default for ThrusterGap {
    fn default() -> Self {
        ThrusterGap {
            // On by default: the default twin is more responsive than identified (the
            // identification underestimated its thrust); config/twin-mild.toml turns it off.
            gain: GainParams {
                enabled: true,
                factor: 2.5,
            },
            lag: LagParams {
                enabled: true,
                time_constant_s: 0.5,
            },
            dead_band: DeadBandParams {
                enabled: true,
                setpoint: 0.05,
            },
            asymmetry: AsymmetryParams {
                enabled: true,
                reverse_gain: 0.75,
            },
            watchdog_s: 1.0,
        }
    }
}

impl Default for GainParams {
    fn default() -> Self {
        ThrusterGap::default().gain
    }
}

impl Default for LagParams {
    fn default() -> Self {
        ThrusterGap::default().lag
    }
}

impl Default for DeadBandParams {
    fn default() -> Self {
        ThrusterGap::default().dead_band
    }
}

impl Default for AsymmetryParams {
    fn default() -> Self {
        ThrusterGap::default().asymmetry
    }
}

impl Default for CurrentParams {
    fn default() -> Self {
        CurrentParams {
            enabled: true,
            speed_m_s: 0.06,
            direction_deg: 180.0,
        }
    }
}

impl Default for MountParams {
    fn default() -> Self {
        MountParams {
            enabled: true,
            mount_x_m: 0.15,
            mount_y_m: 0.03,
        }
    }
}

impl Default for LatencyParams {
    fn default() -> Self {
        // On by default: the default twin's commands reach the thrusters one period after the frame
        // they answer (config/twin-mild.toml: off; config/twin-harsh.toml: two periods).
        LatencyParams {
            enabled: true,
            frames: 1,
        }
    }
}

impl Default for DropParams {
    fn default() -> Self {
        DropParams {
            enabled: true,
            probability: 0.03,
        }
    }
}

impl Validate for TwinParams {
    fn validate(&self, key: &str) -> Result<(), Invalid> {
        let k = join(key, "trials");
        in_range(&k, "duration_s", self.trials.duration_s, 0.2, 1.0e6)?;
        self.trials.reposition.validate(&join(&k, "reposition"))?;
        in_range(&k, "cycle", self.trials.cycle as f64, 0.0, 1.0e6)?;

        let k = join(key, "damping");
        for (field, d) in [
            ("surge", self.damping.surge),
            ("sway", self.damping.sway),
            ("yaw", self.damping.yaw),
        ] {
            let k = join(&k, field);
            in_range(&k, "beta", d.beta, 0.0, 1.0e3)?;
            in_range(&k, "identified_at", d.identified_at, 0.0, 10.0)?;
        }

        let t = &self.thrusters;
        let k = join(key, "thrusters");
        positive(&join(&k, "gain"), "factor", t.gain.factor)?;
        in_range(&join(&k, "gain"), "factor", t.gain.factor, 0.0, 10.0)?;
        positive(&join(&k, "lag"), "time_constant_s", t.lag.time_constant_s)?;
        in_range(
            &join(&k, "lag"),
            "time_constant_s",
            t.lag.time_constant_s,
            0.0,
            60.0,
        )?;
        in_range(
            &join(&k, "dead_band"),
            "setpoint",
            t.dead_band.setpoint,
            0.0,
            0.9,
        )?;
        in_range(
            &join(&k, "asymmetry"),
            "reverse_gain",
            t.asymmetry.reverse_gain,
            0.0,
            2.0,
        )?;
        positive(&k, "watchdog_s", t.watchdog_s)?;

        let k = join(key, "current");
        in_range(&k, "speed_m_s", self.current.speed_m_s, 0.0, 5.0)?;
        in_range(
            &k,
            "direction_deg",
            self.current.direction_deg,
            -360.0,
            360.0,
        )?;

        let k = join(key, "camera");
        in_range(&k, "mount_x_m", self.camera.mount_x_m, -10.0, 10.0)?;
        in_range(&k, "mount_y_m", self.camera.mount_y_m, -10.0, 10.0)?;

        // A probability of 1 would drop every frame but a trial's last: the vehicle would be blind.
        in_range(
            &join(key, "frames.dropped"),
            "probability",
            self.frames.dropped.probability,
            0.0,
            0.9,
        )?;

        in_range(
            &join(key, "latency"),
            "frames",
            self.latency.frames as f64,
            0.0,
            MAX_LATENCY_FRAMES as f64,
        )?;

        self.render.validate(&join(key, "render"))?;
        match &self.autopilot {
            Some(a) => a.validate(&join(key, "autopilot")),
            None => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ConfigError;
    use std::path::Path;

    #[test]
    fn the_shipped_file_equals_the_defaults() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/twin.toml");
        let t: TwinParams = crate::load(&path).unwrap();
        assert_eq!(t, TwinParams::default());
    }

    #[test]
    fn the_ideal_twin_file_is_the_gap_off_with_the_simulators_images() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config");
        let t: TwinParams = crate::load(&dir.join("twin-ideal.toml")).unwrap();
        let scenario: crate::Scenario = crate::load(&dir.join("scenario.toml")).unwrap();
        let want = TwinParams {
            render: scenario.render,
            ..TwinParams::ideal()
        };
        assert_eq!(t, want);
    }

    /// The BlueROV2's gap-off twin keeps its twin's trials and stand-in ArduSub: only the gap goes.
    #[test]
    fn the_bluerov2_ideal_twin_is_its_twin_with_the_gap_off_and_the_simulators_images() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/bluerov2");
        let t: TwinParams = crate::load(&dir.join("twin-ideal.toml")).unwrap();
        let twin: TwinParams = crate::load(&dir.join("twin.toml")).unwrap();
        let scenario: crate::Scenario = crate::load(&dir.join("scenario.toml")).unwrap();
        let want = TwinParams {
            trials: twin.trials.clone(),
            render: scenario.render,
            autopilot: twin.autopilot.clone(),
            ..TwinParams::ideal()
        };
        assert!(want.autopilot.is_some());
        assert_eq!(t, want);
    }

    #[test]
    fn the_default_twin_is_responsive_and_late_and_the_mild_one_is_neither() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config");
        let d = TwinParams::default();
        assert_eq!((d.thrusters.gain.factor(), d.latency.periods()), (2.5, 1));
        let mild: TwinParams = crate::load(&dir.join("twin-mild.toml")).unwrap();
        let mut want = TwinParams::default();
        want.thrusters.gain.enabled = false;
        want.latency.enabled = false;
        assert_eq!(mild, want);
        assert_eq!(
            (mild.thrusters.gain.factor(), mild.latency.periods()),
            (1.0, 0)
        );
    }

    #[test]
    fn the_harsh_twin_is_the_default_with_a_second_frame_of_latency_and_a_faster_lag() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/twin-harsh.toml");
        let t: TwinParams = crate::load(&path).unwrap();
        let mut want = TwinParams::default();
        want.thrusters.lag.time_constant_s = 0.4;
        want.latency.frames = 2;
        assert_eq!(t, want);
        assert_eq!((t.thrusters.gain.factor(), t.latency.periods()), (2.5, 2));
    }

    #[test]
    fn the_harsh_cross_twin_is_the_harsh_one_with_the_current_across_the_cable() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config");
        let t: TwinParams = crate::load(&dir.join("twin-harsh-cross.toml")).unwrap();
        let mut want: TwinParams = crate::load(&dir.join("twin-harsh.toml")).unwrap();
        want.current.direction_deg = 90.0;
        assert_eq!(t, want);
    }

    #[test]
    fn defaults_are_valid_and_harsher_than_the_simulators_images() {
        TwinParams::default().validate("").unwrap();
        TwinParams::ideal().validate("").unwrap();
        let (twin, sim) = (TwinParams::default().render, RenderParams::default());
        assert!(twin.noise.std_dn > sim.noise.std_dn);
        assert!(twin.blur.exposure_s > sim.blur.exposure_s);
        assert!(twin.lighting.vignetting > sim.lighting.vignetting);
    }

    #[test]
    fn every_effect_has_a_switch() {
        let i = TwinParams::ideal();
        assert_eq!(i.current.velocity(), [0.0, 0.0]);
        assert_eq!(i.camera.offset(), [0.0, 0.0]);
        assert_eq!(i.frames.dropped.rate(), 0.0);
        assert_eq!((i.thrusters.gain.factor(), i.latency.periods()), (1.0, 0));
        assert!(!i.damping.enabled && !i.thrusters.lag.enabled);
        assert!(!i.thrusters.dead_band.enabled && !i.thrusters.asymmetry.enabled);
        assert!(!i.render.noise.enabled && !i.render.blur.enabled && !i.render.lighting.enabled);
        let d = TwinParams::default();
        let v = d.current.velocity();
        assert!((v[0] + 0.06).abs() < 1e-12 && v[1].abs() < 1e-12);
    }

    #[test]
    fn bad_values_and_unknown_keys_are_refused_by_name() {
        let err = crate::parse::<TwinParams>(
            "[thrusters.dead_band]\nsetpoint = 1.5\n",
            Path::new("twin.toml"),
        )
        .unwrap_err();
        let ConfigError::Invalid { invalid, .. } = &err else {
            panic!("{err}")
        };
        assert_eq!(invalid.key, "thrusters.dead_band.setpoint");
        assert!(err.to_string().contains("twin.toml"), "{err}");

        let err =
            crate::parse::<TwinParams>("[current]\nspeeed_m_s = 0.1\n", Path::new("twin.toml"))
                .unwrap_err();
        assert!(err.to_string().contains("speeed_m_s"), "{err}");

        let err = crate::parse::<TwinParams>(
            "[frames.dropped]\nprobability = 1.0\n",
            Path::new("twin.toml"),
        )
        .unwrap_err();
        assert!(
            err.to_string().contains("frames.dropped.probability"),
            "{err}"
        );

        let err = crate::parse::<TwinParams>(
            "[thrusters.lag]\ntime_constant_s = 0.0\n",
            Path::new("twin.toml"),
        )
        .unwrap_err();
        assert!(
            err.to_string().contains("thrusters.lag.time_constant_s"),
            "{err}"
        );

        let err = crate::parse::<TwinParams>("[thrusters.gain]\nfactor = 0\n", Path::new("t.toml"))
            .unwrap_err();
        assert!(err.to_string().contains("thrusters.gain.factor"), "{err}");
        let err = crate::parse::<TwinParams>("[latency]\nframes = 11\n", Path::new("t.toml"))
            .unwrap_err();
        assert!(err.to_string().contains("latency.frames"), "{err}");

        let err = crate::parse::<TwinParams>("[render.noise]\nstd_dn = -2\n", Path::new("t.toml"))
            .unwrap_err();
        assert!(err.to_string().contains("render.noise.std_dn"), "{err}");
    }

    /// The BlueROV2's files load: its twin carries the autopilot, without the twin's own quadratic
    /// damping (the identified model has it), and its scenario the four vectored thrusters.
    #[test]
    fn the_bluerov2_files_load() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/bluerov2");
        let t: TwinParams = crate::load(&dir.join("twin.toml")).unwrap();
        let s: crate::Scenario = crate::load(&dir.join("scenario.toml")).unwrap();
        let _: crate::LearningParams = crate::load(&dir.join("learning.toml")).unwrap();
        assert!(!t.damping.enabled);
        let autopilot = t
            .autopilot
            .as_ref()
            .expect("the BlueROV2 flies under ArduSub");
        assert_eq!(autopilot.value("MAV_GCS_SYSID"), Some(255.0));
        assert_eq!(autopilot.value("FS_PILOT_TIMEOUT"), Some(3.0));
        assert_eq!(s.thrusters.thruster.len(), 4);
        assert!(s.model.yaw.beta > 0.0 && s.model.sway.beta > 0.0);
        // The stack's full commands: 0.5 m/s of sway and surge, 0.15 rad/s of yaw, within the
        // joystick gain's reach; the autopilot it assumes is the twin's.
        let pilot = s
            .pilot
            .as_ref()
            .expect("the BlueROV2 is flown through ArduSub");
        let m = s.commanded_model();
        assert!((m.sway.steady_velocity(1.0) - 0.5).abs() < 0.002);
        assert!((m.surge.steady_velocity(1.0) - 0.5).abs() < 0.002);
        assert!((m.yaw.steady_velocity(1.0) - 0.15).abs() < 0.001);
        let flown = autopilot.flown_by(pilot, "autopilot").unwrap();
        assert_eq!(flown.value("ACRO_YAW_P"), Some(1.0));
        assert_eq!(flown.value("RC4_DZ"), Some(0.0));
        let gain = flown.value("JS_GAIN_DEFAULT").unwrap();
        let f = pilot.fraction;
        assert!(f.surge.max(f.sway).max(f.yaw) <= gain);
    }

    #[test]
    fn missing_keys_take_their_defaults() {
        let t: TwinParams =
            crate::parse("[current]\nenabled = false\n", Path::new("t.toml")).unwrap();
        assert!(!t.current.enabled);
        assert_eq!(t.current.speed_m_s, CurrentParams::default().speed_m_s);
        assert_eq!(t.thrusters, ThrusterGap::default());
    }
}
