//! The vehicle twin standing in for a BlueROV2's ArduSub autopilot over MAVLink: a plain state
//! machine fed `now` and the frames received, returning the messages to send and the motors'
//! outputs (no sockets; the `vehicle-twin` binary binds it to a UDP port with `--autopilot URL`).
//!
//! What it emulates, from ArduSub's source (`ArduSub/`, `libraries/GCS_MAVLink`,
//! `libraries/AP_Motors/AP_Motors6DOF.cpp`):
//!
//! - HEARTBEAT at 1 Hz as system `MAV_SYSID` (`SYSID_THISMAV` before 4.7), component 1: a
//!   submarine, ArduPilot, base mode STABILIZE | MANUAL_INPUT | CUSTOM_MODE (| SAFETY_ARMED), custom
//!   mode ArduSub's mode number; system status CRITICAL while a failsafe is on, ACTIVE armed,
//!   STANDBY disarmed.
//! - Parameters ([`config::ARDUSUB_PARAMS`]): PARAM_REQUEST_READ by name or index,
//!   PARAM_REQUEST_LIST, PARAM_SET, each answered with PARAM_VALUE.
//! - COMMAND_LONG: arm/disarm, DO_SET_MODE (MANUAL, STABILIZE, ALT_HOLD), SET_MESSAGE_INTERVAL,
//!   REQUEST_MESSAGE, each with its COMMAND_ACK (UNSUPPORTED for any other command); the SET_MODE
//!   message, acknowledged as ArduPilot does (COMMAND_ACK with command 11).
//! - MANUAL_CONTROL only from a ground station's system id (`MAV_GCS_SYSID`..`MAV_GCS_SYSID_HI`,
//!   or `SYSID_MYGCS`) and addressed to this system; others are dropped silently and counted. The
//!   axes become RC overrides as `joystick.cpp` makes them (0.4 x gain around 1500 us); the motors
//!   act on them only while armed.
//! - The pilot-input failsafe (`failsafe.cpp`): no MANUAL_CONTROL for `FS_PILOT_TIMEOUT` ->
//!   "Lost manual control" (CRITICAL), the controls to neutral, and with `FS_PILOT_INPUT` = 2 a
//!   disarm; once per loss (it latches until pilot input comes back).
//! - MANUAL passes the axes through; STABILIZE and ALT_HOLD keep forward and lateral as thrust and
//!   make yaw a rate command (`ACRO_YAW_P`, the yaw dead zone `RC4_DZ` scaled by the joystick
//!   gain), followed as ArduSub's attitude controller does: the pilot's rate, limited in
//!   acceleration (`ATC_ACCEL_Y_MAX`), is fed forward and integrated into a target heading; the
//!   heading error (`ATC_ANG_YAW_P`) adds to it; a PI controller on the yaw rate
//!   (`ATC_RAT_YAW_P`, `_I`, `_IMAX`, its target filtered at `ATC_RAT_YAW_FLTT`) gives the yaw
//!   output. 250 ms after the yaw stick is released the heading then is held. Not emulated: the
//!   input shaping's time constants and the square-root shaping of large heading errors.
//! - The vectored mixer ([`mixer`]) with `MOT_n_DIRECTION`, PWM 1100..1900.
//! - Telemetry at the requested intervals: SYS_STATUS, ATTITUDE, VFR_HUD, SERVO_OUTPUT_RAW;
//!   STATUSTEXT on arming, disarming and failsafe.
//! - Faults for tests and drills ([`Fault`]): the link cut (nothing in, nothing out), the
//!   autopilot restarted (silent, motors stopped, then back disarmed in MANUAL).
//!
//! Not emulated: depth control and the vertical thrusters' effect (heave is not modelled), roll and
//! pitch, joystick buttons, the other modes, missions, the GCS heartbeat failsafe, signing.

pub mod mixer;
pub mod wire;

use config::{ArduSubGeneration, AutopilotParams, ParamKind, PilotMode, param_value_ok};
use mavlink::dialects::ardupilotmega::{
    ATTITUDE_DATA, HEARTBEAT_DATA, MavAutopilot, MavMessage, MavModeFlag, MavParamType, MavResult,
    MavSeverity, MavState, MavSysStatusSensor, MavType, PARAM_VALUE_DATA, SERVO_OUTPUT_RAW_DATA,
    STATUSTEXT_DATA, SYS_STATUS_DATA, VFR_HUD_DATA,
};
use mixer::{Inputs, MOTORS};
use model::pilot::Axes;
use std::collections::BTreeMap;
use std::time::{Duration, Instant};
use wire::{CommandLong, Frame};

/// ArduSub's mode numbers (`ArduSub/mode.h`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    Stabilize,
    AltHold,
    Manual,
}

impl Mode {
    pub fn number(self) -> u32 {
        match self {
            Mode::Stabilize => 0,
            Mode::AltHold => 2,
            Mode::Manual => 19,
        }
    }

    pub fn from_number(n: u32) -> Option<Mode> {
        match n {
            0 => Some(Mode::Stabilize),
            2 => Some(Mode::AltHold),
            19 => Some(Mode::Manual),
            _ => None,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Mode::Stabilize => "STABILIZE",
            Mode::AltHold => "ALT_HOLD",
            Mode::Manual => "MANUAL",
        }
    }
}

impl From<PilotMode> for Mode {
    fn from(m: PilotMode) -> Mode {
        match m {
            PilotMode::Manual => Mode::Manual,
            PilotMode::Stabilize => Mode::Stabilize,
            PilotMode::AltHold => Mode::AltHold,
        }
    }
}

/// ArduSub's other mode numbers: real modes the twin does not fly.
const OTHER_MODES: [u32; 8] = [1, 3, 4, 7, 9, 16, 20, 21];

/// The MAVLink commands handled.
const CMD_DO_SET_MODE: u16 = 176;
const CMD_ARM_DISARM: u16 = 400;
const CMD_SET_MESSAGE_INTERVAL: u16 = 511;
const CMD_REQUEST_MESSAGE: u16 = 512;
/// SET_MODE's message id, which ArduPilot puts in its COMMAND_ACK.
const SET_MODE_ID: u16 = 11;

/// Telemetry the twin can stream, by message id, and ArduSub-like default intervals.
const HEARTBEAT_ID: u32 = 0;
const SYS_STATUS_ID: u32 = 1;
const ATTITUDE_ID: u32 = 30;
const SERVO_OUTPUT_RAW_ID: u32 = 36;
const VFR_HUD_ID: u32 = 74;
const DEFAULT_STREAMS: [(u32, u64); 5] = [
    (HEARTBEAT_ID, 1000),
    (SYS_STATUS_ID, 1000),
    (ATTITUDE_ID, 250),
    (SERVO_OUTPUT_RAW_ID, 500),
    (VFR_HUD_ID, 250),
];

/// Released yaw stick: the heading is taken this long after, once the turn has slowed.
const YAW_RELEASE_S: f64 = 0.25;

/// A fault the twin injects, at a time after its start, for a while.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fault {
    pub kind: FaultKind,
    pub at: Duration,
    pub lasting: Duration,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FaultKind {
    /// Nothing reaches the autopilot and nothing leaves it; it keeps running.
    LinkCut,
    /// The autopilot restarts: silent, motors stopped, then back disarmed in its default mode.
    Restart,
}

impl std::str::FromStr for Fault {
    type Err = String;
    /// `link-cut:AT:FOR` or `restart:AT:FOR`, in seconds after the start.
    fn from_str(s: &str) -> Result<Fault, String> {
        let parts: Vec<&str> = s.split(':').collect();
        let [kind, at, lasting] = parts[..] else {
            return Err(format!(
                "`{s}`: expected KIND:AT:FOR (KIND link-cut or restart, seconds)"
            ));
        };
        let kind = match kind {
            "link-cut" => FaultKind::LinkCut,
            "restart" => FaultKind::Restart,
            other => return Err(format!("`{other}` is not a fault (link-cut or restart)")),
        };
        let secs = |v: &str| -> Result<Duration, String> {
            let x: f64 = v
                .parse()
                .map_err(|_| format!("`{v}` is not a number of seconds"))?;
            if !(x.is_finite() && x >= 0.0) {
                return Err(format!("`{v}` must be >= 0 seconds"));
            }
            Ok(Duration::from_secs_f64(x))
        };
        Ok(Fault {
            kind,
            at: secs(at)?,
            lasting: secs(lasting)?,
        })
    }
}

/// What the autopilot knows of the vehicle (its AHRS).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Vehicle {
    /// Heading (rad), from north (the pool's x axis) towards east (its y axis).
    pub heading: f64,
    /// Yaw rate (rad/s).
    pub yaw_rate: f64,
    /// Speed over ground (m/s).
    pub ground_speed: f64,
}

/// What the autopilot's AHRS reports of the vehicle's state.
pub fn vehicle_of(state: &model::VehicleState, rate: &model::PoseRate) -> Vehicle {
    Vehicle {
        heading: state.pose.psi,
        yaw_rate: state.velocity.r,
        ground_speed: rate.x.hypot(rate.y),
    }
}

/// A message to send.
#[derive(Clone, Debug, PartialEq)]
pub enum Out {
    Message(Box<MavMessage>),
    /// A COMMAND_ACK whose command the dialect's enum cannot hold (SET_MODE's 11, unknown commands).
    Ack {
        command: u16,
        result: MavResult,
        target_system: u8,
        target_component: u8,
    },
}

/// The lockstep tag of the stack's side: `NAMED_VALUE_INT { name: "ct_step", time_boot_ms, value }`
/// after the MANUAL_CONTROL answering the frame of that time.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StepTag {
    /// The frame's time in ms (`frame_time_ns / 1_000_000`, truncated to u32).
    pub frame_time_ms: u32,
    pub step: i32,
}

/// The name of the lockstep tag.
pub const STEP_TAG: &str = "ct_step";

/// What was refused or dropped, by cause (the shell logs them).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counters {
    /// MANUAL_CONTROL from a system id that is not a ground station's.
    pub not_from_gcs: u64,
    /// MANUAL_CONTROL addressed to another system.
    pub not_for_us: u64,
    /// Frames whose fields did not decode (an invalid enum value).
    pub undecodable: u64,
    /// Frames dropped while the link was cut or the autopilot restarting.
    pub dropped_in: u64,
    /// Messages not sent while the link was cut or the autopilot restarting.
    pub dropped_out: u64,
    /// Pilot-input failsafes.
    pub failsafes: u64,
}

/// The RC override channels the joystick sets (us).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Sticks {
    pub throttle: u16,
    pub yaw: u16,
    pub forward: u16,
    pub lateral: u16,
}

impl Sticks {
    pub const NEUTRAL: Sticks = Sticks {
        throttle: 1500,
        yaw: 1500,
        forward: 1500,
        lateral: 1500,
    };

    /// `transform_manual_control_to_rc_override`: x, y, r in [-1000, 1000] scaled by 0.4 x gain
    /// around 1500, z in [0, 1000] by 0.8 x gain x JS_THR_GAIN around its base (500 is neutral);
    /// each channel truncated to an integer and kept within 1100..1900.
    pub fn from_joystick(x: i16, y: i16, z: i16, r: i16, gain: f64, thr_gain: f64) -> Sticks {
        let rpy = 0.4 * gain;
        let thr = 0.8 * gain * thr_gain;
        let base = (1500.0 - 500.0 * thr).trunc();
        let ch = |v: f64| (v.trunc() as i64).clamp(1100, 1900) as u16;
        Sticks {
            throttle: ch(z as f64 * thr + base),
            yaw: ch(r as f64 * rpy + 1500.0),
            forward: ch(x as f64 * rpy + 1500.0),
            lateral: ch(y as f64 * rpy + 1500.0),
        }
    }
}

/// A channel's normalised input: (pwm - trim) / range, trim 1500, range 400, within [-1, 1].
pub fn norm_input(pwm: u16) -> f64 {
    ((pwm as f64 - 1500.0) / 400.0).clamp(-1.0, 1.0)
}

/// The yaw channel as an angle (centidegrees, +-4500) with a dead zone of `dz` us around 1500, in
/// `RC_Channel::pwm_to_angle_dz_trim`'s integer arithmetic (the dead zone truncated to whole us).
pub fn yaw_angle(pwm: u16, dz: f64) -> f64 {
    let (p, dz) = (pwm as i32, dz.max(0.0) as i32);
    let (high, low) = (1500 + dz, 1500 - dz);
    let angle = if p > high && high != 1900 {
        4500 * (p - high) / (1900 - high)
    } else if p < low && low != 1100 {
        4500 * (p - low) / (low - 1100)
    } else {
        0
    };
    angle as f64
}

/// `v` moved towards `target` by at most `step` (no limit when `step` is not positive).
fn approach(v: f64, target: f64, step: f64) -> f64 {
    if step > 0.0 {
        v + (target - v).clamp(-step, step)
    } else {
        target
    }
}

/// The joystick gain at boot (`init_joystick`).
pub fn boot_gain(default: f64, min: f64, max: f64, steps: f64) -> f64 {
    let steps = steps.max(1.0);
    let g = if steps == 1.0 || (default < max + 0.01 && default > min - 0.01) {
        default.clamp(min, max)
    } else {
        min + ((steps as i64 / 2 - 1) as f64) * (max - min) / (steps - 1.0)
    };
    g.clamp(0.1, 1.0)
}

fn wrap_pi(a: f64) -> f64 {
    let two_pi = std::f64::consts::TAU;
    let w = (a + std::f64::consts::PI).rem_euclid(two_pi) - std::f64::consts::PI;
    if w <= -std::f64::consts::PI {
        w + two_pi
    } else {
        w
    }
}

/// A parameter as the autopilot holds it.
#[derive(Clone, Debug)]
struct Param {
    name: &'static str,
    value: f64,
    kind: ParamKind,
    spec: &'static config::ParamSpec,
}

/// The stand-in ArduSub.
pub struct ArduSub {
    config: AutopilotParams,
    params: Vec<Param>,
    faults: Vec<Fault>,
    started: Instant,
    boot: Instant,
    /// Restarting until then: silent, motors stopped.
    down_until: Option<Instant>,
    armed: bool,
    mode: Mode,
    gain: f64,
    sticks: Sticks,
    last_pilot_input: Instant,
    failsafe: bool,
    streams: BTreeMap<u32, (Duration, Instant)>,
    vehicle: Vehicle,
    yaw: YawLoop,
    /// Whether mode changes and arming are logged (not when the twin's own pilot takes off).
    announce: bool,
    out: Vec<Out>,
    counters: Counters,
}

impl ArduSub {
    /// The autopilot, booted at `now`.
    pub fn new(config: &AutopilotParams, faults: Vec<Fault>, now: Instant) -> ArduSub {
        let params = config
            .specs()
            .map(|spec| Param {
                name: spec.name,
                value: config.value(spec.name).expect("a spec of this generation"),
                kind: spec.kind,
                spec,
            })
            .collect();
        let mut a = ArduSub {
            config: config.clone(),
            params,
            faults,
            started: now,
            boot: now,
            down_until: None,
            armed: false,
            mode: Mode::Manual,
            gain: 0.5,
            sticks: Sticks::NEUTRAL,
            last_pilot_input: now,
            failsafe: false,
            streams: BTreeMap::new(),
            vehicle: Vehicle::default(),
            yaw: YawLoop::default(),
            announce: true,
            out: Vec::new(),
            counters: Counters::default(),
        };
        a.boot(now);
        a
    }

    /// Boots (again): disarmed, MANUAL, neutral controls, the default streams, the gain from the
    /// parameters.
    fn boot(&mut self, now: Instant) {
        self.boot = now;
        self.armed = false;
        self.mode = Mode::Manual;
        self.sticks = Sticks::NEUTRAL;
        self.last_pilot_input = now;
        self.failsafe = false;
        self.yaw = YawLoop::at(self.vehicle.heading);
        self.gain = boot_gain(
            self.param("JS_GAIN_DEFAULT"),
            self.param("JS_GAIN_MIN"),
            self.param("JS_GAIN_MAX"),
            self.param("JS_GAIN_STEPS"),
        );
        self.streams = DEFAULT_STREAMS
            .iter()
            .map(|&(id, ms)| (id, (Duration::from_millis(ms), now)))
            .collect();
    }

    fn param(&self, name: &str) -> f64 {
        self.params
            .iter()
            .find(|p| p.name == name)
            .map(|p| p.value)
            .unwrap_or_else(|| panic!("{name} is in the parameter table"))
    }

    /// This autopilot's system id.
    pub fn system_id(&self) -> u8 {
        let name = match self.config.generation {
            ArduSubGeneration::V4_7 => "MAV_SYSID",
            ArduSubGeneration::V4_5 => "SYSID_THISMAV",
        };
        self.param(name) as u8
    }

    /// Whether `sysid` is a ground station's (`GCS::sysid_is_gcs`; `SYSID_MYGCS` before 4.7).
    pub fn is_gcs(&self, sysid: u8) -> bool {
        match self.config.generation {
            ArduSubGeneration::V4_7 => {
                let (lo, hi) = (self.param("MAV_GCS_SYSID"), self.param("MAV_GCS_SYSID_HI"));
                let s = sysid as f64;
                if hi <= lo {
                    s == lo
                } else {
                    s >= lo && s <= hi
                }
            }
            ArduSubGeneration::V4_5 => sysid as f64 == self.param("SYSID_MYGCS"),
        }
    }

    pub fn armed(&self) -> bool {
        self.armed
    }

    /// Which ArduSub this one emulates.
    pub fn generation(&self) -> ArduSubGeneration {
        self.config.generation
    }

    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// The joystick gain in use.
    pub fn gain(&self) -> f64 {
        self.gain
    }

    pub fn sticks(&self) -> Sticks {
        self.sticks
    }

    pub fn counters(&self) -> &Counters {
        &self.counters
    }

    pub fn failsafe(&self) -> bool {
        self.failsafe
    }

    /// Adds faults to inject (times after the autopilot's first boot).
    pub fn inject(&mut self, faults: impl IntoIterator<Item = Fault>) {
        self.faults.extend(faults);
    }

    /// Whether the autopilot is running (not restarting) at `now`.
    pub fn up(&self, now: Instant) -> bool {
        self.down_until.is_none_or(|t| now >= t) && !self.in_fault(FaultKind::Restart, now)
    }

    /// Whether the link carries anything at `now`.
    pub fn link_up(&self, now: Instant) -> bool {
        !self.in_fault(FaultKind::LinkCut, now)
    }

    fn in_fault(&self, kind: FaultKind, now: Instant) -> bool {
        let t = now.saturating_duration_since(self.started);
        self.faults
            .iter()
            .any(|f| f.kind == kind && t >= f.at && t < f.at + f.lasting)
    }

    fn time_boot_ms(&self, now: Instant) -> u32 {
        now.saturating_duration_since(self.boot).as_millis() as u32
    }

    fn text(&mut self, severity: MavSeverity, text: &str) {
        self.out.push(Out::Message(Box::new(MavMessage::STATUSTEXT(
            STATUSTEXT_DATA {
                severity,
                text: text.into(),
                ..Default::default()
            },
        ))));
    }

    /// The messages to send now (none while the link is cut or the autopilot restarting).
    pub fn take_out(&mut self, now: Instant) -> Vec<Out> {
        let out = std::mem::take(&mut self.out);
        if !self.link_up(now) || !self.up(now) {
            self.counters.dropped_out += out.len() as u64;
            return Vec::new();
        }
        out
    }

    /// A frame arrived at `now`. Returns the lockstep tag when it is one (from a ground station).
    pub fn receive(&mut self, now: Instant, frame: &Frame) -> Option<StepTag> {
        self.on_time(now);
        if !self.link_up(now) || !self.up(now) {
            self.counters.dropped_in += 1;
            return None;
        }
        if frame.message_id == wire::COMMAND_LONG {
            self.command(now, CommandLong::decode(&frame.payload), frame);
            return None;
        }
        let msg = match frame.message() {
            Ok(m) => m,
            Err(e) => {
                self.counters.undecodable += 1;
                tracing::debug!(id = frame.message_id, "undecodable message: {e}");
                return None;
            }
        };
        match msg {
            MavMessage::MANUAL_CONTROL(m) => {
                if !self.is_gcs(frame.system_id) {
                    self.counters.not_from_gcs += 1;
                    return None;
                }
                if m.target != self.system_id() {
                    self.counters.not_for_us += 1;
                    return None;
                }
                self.pilot(
                    now,
                    Axes {
                        x: m.x,
                        y: m.y,
                        z: m.z,
                        r: m.r,
                    },
                );
            }
            MavMessage::NAMED_VALUE_INT(v) => {
                let name = v.name.to_str().unwrap_or("");
                if name == STEP_TAG && self.is_gcs(frame.system_id) {
                    return Some(StepTag {
                        frame_time_ms: v.time_boot_ms,
                        step: v.value,
                    });
                }
            }
            MavMessage::PARAM_REQUEST_LIST(r) if self.for_us(r.target_system) => {
                for k in 0..self.params.len() {
                    self.param_value(k);
                }
            }
            MavMessage::PARAM_REQUEST_READ(r) if self.for_us(r.target_system) => {
                let k = if r.param_index >= 0 {
                    Some(r.param_index as usize).filter(|&k| k < self.params.len())
                } else {
                    let name = r.param_id.to_str().unwrap_or("");
                    self.params.iter().position(|p| p.name == name)
                };
                match k {
                    Some(k) => self.param_value(k),
                    None => tracing::debug!(
                        index = r.param_index,
                        name = r.param_id.to_str().unwrap_or("?"),
                        "PARAM_REQUEST_READ for a parameter the twin does not have"
                    ),
                }
            }
            MavMessage::PARAM_SET(s) if self.for_us(s.target_system) => {
                let name = s.param_id.to_str().unwrap_or("").to_string();
                if let Some(k) = self.params.iter().position(|p| p.name == name) {
                    let v = s.param_value as f64;
                    match param_value_ok(self.params[k].spec, v) {
                        Ok(()) => {
                            tracing::info!(%name, value = v, "parameter set");
                            self.params[k].value = v;
                        }
                        Err(reason) => {
                            tracing::warn!(%name, value = v, "PARAM_SET refused: {reason}")
                        }
                    }
                    self.param_value(k);
                }
            }
            // Deprecated by MAVLink, still handled by ArduPilot (and sent by some ground stations).
            #[allow(deprecated)]
            MavMessage::SET_MODE(s) if self.for_us(s.target_system) => {
                let result = self.set_mode_common(s.base_mode.bits() as f32, s.custom_mode);
                self.out.push(Out::Ack {
                    command: SET_MODE_ID,
                    result,
                    target_system: frame.system_id,
                    target_component: frame.component_id,
                });
            }
            _ => {}
        }
        None
    }

    fn for_us(&self, target_system: u8) -> bool {
        target_system == 0 || target_system == self.system_id()
    }

    fn param_value(&mut self, k: usize) {
        let p = &self.params[k];
        let param_type = match p.kind {
            ParamKind::Int8 => MavParamType::MAV_PARAM_TYPE_INT8,
            ParamKind::Int16 => MavParamType::MAV_PARAM_TYPE_INT16,
            ParamKind::Real32 => MavParamType::MAV_PARAM_TYPE_REAL32,
        };
        let msg = MavMessage::PARAM_VALUE(PARAM_VALUE_DATA {
            param_value: p.value as f32,
            param_count: self.params.len() as u16,
            param_index: k as u16,
            param_id: p.name.into(),
            param_type,
        });
        self.out.push(Out::Message(Box::new(msg)));
    }

    fn command(&mut self, now: Instant, c: CommandLong, frame: &Frame) {
        if !self.for_us(c.target_system) {
            return;
        }
        let p = c.params;
        let result = match c.command {
            CMD_ARM_DISARM => {
                if p[0] == 1.0 {
                    if !self.armed {
                        self.arm();
                    }
                    MavResult::MAV_RESULT_ACCEPTED
                } else if p[0] == 0.0 {
                    if self.armed {
                        self.disarm("commanded");
                    }
                    MavResult::MAV_RESULT_ACCEPTED
                } else {
                    MavResult::MAV_RESULT_UNSUPPORTED
                }
            }
            CMD_DO_SET_MODE => self.set_mode_common(p[0], p[1] as u32),
            CMD_SET_MESSAGE_INTERVAL => self.set_message_interval(p[0] as u32, p[1] as i64, now),
            CMD_REQUEST_MESSAGE => {
                if self.send_now(p[0] as u32, now) {
                    MavResult::MAV_RESULT_ACCEPTED
                } else {
                    MavResult::MAV_RESULT_FAILED
                }
            }
            other => {
                tracing::debug!(command = other, "COMMAND_LONG not emulated");
                MavResult::MAV_RESULT_UNSUPPORTED
            }
        };
        self.out.push(Out::Ack {
            command: c.command,
            result,
            target_system: frame.system_id,
            target_component: frame.component_id,
        });
    }

    /// `_set_mode_common`: only custom modes; a mode ArduSub has but the twin does not fly fails.
    fn set_mode_common(&mut self, base_mode: f32, custom_mode: u32) -> MavResult {
        let custom = MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED.bits() as u32;
        if (base_mode as u32) & custom == 0 {
            return MavResult::MAV_RESULT_DENIED;
        }
        let Some(mode) = Mode::from_number(custom_mode) else {
            if OTHER_MODES.contains(&custom_mode) {
                tracing::warn!(
                    mode = custom_mode,
                    "mode change refused: not emulated by the twin"
                );
            }
            return MavResult::MAV_RESULT_FAILED;
        };
        if self.set_mode(mode) {
            MavResult::MAV_RESULT_ACCEPTED
        } else {
            MavResult::MAV_RESULT_FAILED
        }
    }

    /// `Sub::set_mode`: the same mode succeeds at once; ALT_HOLD needs the depth sensor; MANUAL's
    /// init neutralises the controls; the stabilised modes take the current heading.
    fn set_mode(&mut self, mode: Mode) -> bool {
        if mode == self.mode {
            return true;
        }
        if mode == Mode::AltHold && !self.config.depth_sensor {
            self.text(
                MavSeverity::MAV_SEVERITY_WARNING,
                "Depth sensor is not connected.",
            );
            return false;
        }
        match mode {
            Mode::Manual => self.sticks = Sticks::NEUTRAL,
            Mode::AltHold | Mode::Stabilize => self.yaw = YawLoop::at(self.vehicle.heading),
        }
        if self.announce {
            tracing::info!(from = self.mode.name(), to = mode.name(), "mode changed");
        }
        self.mode = mode;
        true
    }

    fn arm(&mut self) {
        self.armed = true;
        self.yaw = YawLoop::at(self.vehicle.heading);
        self.text(MavSeverity::MAV_SEVERITY_INFO, "Arming motors");
        if self.announce {
            tracing::info!(mode = self.mode.name(), "armed");
        }
    }

    fn disarm(&mut self, why: &str) {
        self.armed = false;
        self.yaw = YawLoop::at(self.vehicle.heading);
        self.text(MavSeverity::MAV_SEVERITY_INFO, "Disarming motors");
        tracing::info!(why, "disarmed");
    }

    /// `set_message_interval`: 0 restores the default, -1 stops, below 1 ms is 1 ms; a message the
    /// twin cannot send fails.
    fn set_message_interval(&mut self, id: u32, interval_us: i64, now: Instant) -> MavResult {
        let Some(&(_, default_ms)) = DEFAULT_STREAMS.iter().find(|(m, _)| *m == id) else {
            return MavResult::MAV_RESULT_FAILED;
        };
        let ms = match interval_us {
            0 => default_ms,
            -1 => {
                self.streams.remove(&id);
                return MavResult::MAV_RESULT_ACCEPTED;
            }
            us if us < 1000 => 1,
            us if us > 60_000_000 => 60_000,
            us => (us / 1000) as u64,
        };
        self.streams.insert(id, (Duration::from_millis(ms), now));
        MavResult::MAV_RESULT_ACCEPTED
    }

    /// Sends the message `id` now; false when the twin cannot produce it.
    fn send_now(&mut self, id: u32, now: Instant) -> bool {
        let t = self.time_boot_ms(now);
        let v = self.vehicle;
        let msg = match id {
            HEARTBEAT_ID => self.heartbeat(),
            SYS_STATUS_ID => {
                let sensors = MavSysStatusSensor::MAV_SYS_STATUS_SENSOR_3D_GYRO
                    | MavSysStatusSensor::MAV_SYS_STATUS_SENSOR_3D_ACCEL
                    | MavSysStatusSensor::MAV_SYS_STATUS_SENSOR_3D_MAG
                    | MavSysStatusSensor::MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
                    | MavSysStatusSensor::MAV_SYS_STATUS_SENSOR_BATTERY;
                let b = &self.config;
                MavMessage::SYS_STATUS(SYS_STATUS_DATA {
                    onboard_control_sensors_present: sensors,
                    onboard_control_sensors_enabled: sensors,
                    onboard_control_sensors_health: sensors,
                    load: 200,
                    voltage_battery: (b.battery_v * 1000.0) as u16,
                    current_battery: (b.battery_a * 100.0) as i16,
                    battery_remaining: 80,
                    ..Default::default()
                })
            }
            ATTITUDE_ID => MavMessage::ATTITUDE(ATTITUDE_DATA {
                time_boot_ms: t,
                roll: 0.0,
                pitch: 0.0,
                yaw: wrap_pi(v.heading) as f32,
                rollspeed: 0.0,
                pitchspeed: 0.0,
                yawspeed: v.yaw_rate as f32,
            }),
            VFR_HUD_ID => {
                let deg = v.heading.to_degrees().rem_euclid(360.0);
                let throttle = self.inputs().throttle;
                MavMessage::VFR_HUD(VFR_HUD_DATA {
                    airspeed: v.ground_speed as f32,
                    groundspeed: v.ground_speed as f32,
                    // ArduSub sends its altitude above the surface: negative under water.
                    alt: -self.config.depth_m as f32,
                    climb: 0.0,
                    heading: (deg as i16) % 360,
                    throttle: (50.0 * (throttle + 1.0)).round() as u16,
                })
            }
            SERVO_OUTPUT_RAW_ID => {
                let p = self.pwm();
                MavMessage::SERVO_OUTPUT_RAW(SERVO_OUTPUT_RAW_DATA {
                    time_usec: now.saturating_duration_since(self.boot).as_micros() as u32,
                    servo1_raw: p[0],
                    servo2_raw: p[1],
                    servo3_raw: p[2],
                    servo4_raw: p[3],
                    servo5_raw: p[4],
                    servo6_raw: p[5],
                    servo7_raw: 0,
                    servo8_raw: 0,
                    port: 0,
                    ..Default::default()
                })
            }
            _ => return false,
        };
        self.out.push(Out::Message(Box::new(msg)));
        true
    }

    fn heartbeat(&self) -> MavMessage {
        let mut base = MavModeFlag::MAV_MODE_FLAG_STABILIZE_ENABLED
            | MavModeFlag::MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
            | MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED;
        if self.armed {
            base |= MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED;
        }
        let status = if self.failsafe {
            MavState::MAV_STATE_CRITICAL
        } else if self.armed {
            MavState::MAV_STATE_ACTIVE
        } else {
            MavState::MAV_STATE_STANDBY
        };
        MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            custom_mode: self.mode.number(),
            mavtype: MavType::MAV_TYPE_SUBMARINE,
            autopilot: MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
            base_mode: base,
            system_status: status,
            mavlink_version: 3,
        })
    }

    /// Time passed: faults begin and end, the pilot-input failsafe, the streams that are due.
    pub fn on_time(&mut self, now: Instant) {
        let restarting = self.in_fault(FaultKind::Restart, now);
        if restarting && self.down_until.is_none() {
            let end = self
                .faults
                .iter()
                .filter(|f| f.kind == FaultKind::Restart)
                .map(|f| self.started + f.at + f.lasting)
                .find(|&end| now < end)
                .unwrap_or(now);
            tracing::warn!(for_s = (end - now).as_secs_f64(), "the autopilot restarts");
            self.armed = false;
            self.sticks = Sticks::NEUTRAL;
            self.yaw = YawLoop::at(self.vehicle.heading);
            self.out.clear();
            self.down_until = Some(end);
        }
        if let Some(end) = self.down_until {
            if now < end || restarting {
                return;
            }
            self.down_until = None;
            self.boot(now);
            tracing::info!("the autopilot is back: disarmed, MANUAL");
        }
        self.failsafe_check(now);
        let due: Vec<u32> = self
            .streams
            .iter()
            .filter(|(_, (_, next))| now >= *next)
            .map(|(&id, _)| id)
            .collect();
        for id in due {
            let (interval, next) = self.streams[&id];
            // Keep the cadence; after a stall, start again from now.
            let mut n = next + interval;
            if n <= now {
                n = now + interval;
            }
            self.streams.insert(id, (interval, n));
            self.send_now(id, now);
        }
    }

    /// `failsafe_pilot_input_check`.
    fn failsafe_check(&mut self, now: Instant) {
        let action = self.param("FS_PILOT_INPUT");
        if action == 0.0 {
            self.failsafe = false;
            return;
        }
        let timeout = Duration::from_secs_f64(self.param("FS_PILOT_TIMEOUT"));
        if now < self.last_pilot_input + timeout {
            self.failsafe = false;
            return;
        }
        if self.failsafe {
            return;
        }
        self.failsafe = true;
        self.counters.failsafes += 1;
        tracing::warn!(
            armed = self.armed,
            action,
            "pilot-input failsafe: no MANUAL_CONTROL for FS_PILOT_TIMEOUT"
        );
        self.text(MavSeverity::MAV_SEVERITY_CRITICAL, "Lost manual control");
        self.sticks = Sticks::NEUTRAL;
        if action == 2.0 && self.armed {
            self.disarm("pilot-input failsafe");
        }
    }

    /// The yaw rate the pilot asks for in the stabilised modes (rad/s): the stick's angle, its dead
    /// zone scaled by the joystick gain, times ACRO_YAW_P.
    fn pilot_yaw_rate(&self) -> f64 {
        let angle = yaw_angle(self.sticks.yaw, self.param("RC4_DZ") * self.gain);
        // centidegrees x ACRO_YAW_P = centidegrees per second
        (angle * self.param("ACRO_YAW_P") / 100.0).to_radians()
    }

    /// The motor inputs of the current mode, with the last yaw output of the heading hold.
    fn inputs(&self) -> Inputs {
        let s = &self.sticks;
        let yaw = match self.mode {
            // mode_manual.cpp: yaw scaled by ACRO_YAW_P against its default.
            Mode::Manual => norm_input(s.yaw) * self.param("ACRO_YAW_P") / 4.5,
            Mode::Stabilize | Mode::AltHold => self.yaw.out,
        };
        Inputs {
            roll: 0.0,
            pitch: 0.0,
            yaw: yaw.clamp(-1.0, 1.0),
            throttle: norm_input(s.throttle),
            forward: norm_input(s.forward),
            lateral: norm_input(s.lateral),
        }
    }

    fn directions(&self) -> [f64; MOTORS] {
        let mut d = [1.0; MOTORS];
        for (m, dir) in d.iter_mut().enumerate() {
            *dir = self.param(&format!("MOT_{}_DIRECTION", m + 1));
        }
        d
    }

    /// Each motor's thrust now: neutral while disarmed or restarting.
    pub fn thrust(&self) -> [f64; MOTORS] {
        if !self.armed || self.down_until.is_some() {
            return [0.0; MOTORS];
        }
        mixer::mix(
            &self.inputs(),
            &self.directions(),
            self.param("MOT_FV_CPLNG_K"),
        )
    }

    /// Each motor's PWM now (what SERVO_OUTPUT_RAW reports).
    pub fn pwm(&self) -> [u16; MOTORS] {
        self.thrust().map(mixer::pwm)
    }

    /// Arms and holds forward stick `x` as a ground station would (for tests of what drives the
    /// twin).
    #[doc(hidden)]
    pub fn arm_for_test(&mut self, now: Instant, x: i16) {
        self.arm();
        self.pilot(now, Axes { x, ..Axes::NEUTRAL });
        self.out.clear();
    }

    /// The pilot's sticks arrive at `now` (a ground station's MANUAL_CONTROL, or the twin's own
    /// pilot on its thruster topic): RC overrides as `joystick.cpp` makes them.
    pub fn pilot(&mut self, now: Instant, axes: Axes) {
        self.sticks = Sticks::from_joystick(
            axes.x,
            axes.y,
            axes.z,
            axes.r,
            self.gain,
            self.param("JS_THR_GAIN"),
        );
        self.last_pilot_input = now;
    }

    /// Takes off in `mode` as a companion computer does: the mode set, then armed (the twin's own
    /// pilot on its thruster topic; over MAVLink the stack's side sends the commands). Fails as
    /// DO_SET_MODE would (ALT_HOLD without a depth sensor).
    pub fn fly(&mut self, mode: Mode) -> Result<(), String> {
        // The twin's own pilot takes off at every start (thousands of times in the trainer): the
        // log says so once, quietly.
        self.announce = false;
        let set = self.set_mode(mode);
        if set && !self.armed {
            self.arm();
        }
        self.announce = true;
        if !set {
            return Err(format!("ArduSub refused the mode {}", mode.name()));
        }
        tracing::debug!(mode = mode.name(), "the twin's pilot took off");
        Ok(())
    }

    /// The vehicle was put somewhere else (a reposition between trials, which an operator pilots):
    /// the attitude loop starts again from its heading.
    pub fn repositioned(&mut self, vehicle: Vehicle) {
        self.vehicle = vehicle;
        self.yaw = YawLoop::at(vehicle.heading);
    }

    /// What the autopilot's sensors say of the vehicle (for telemetry and the heading hold).
    pub fn observe(&mut self, vehicle: Vehicle) {
        self.vehicle = vehicle;
    }

    /// One step of the attitude loop, `h` seconds of twin time, from the vehicle's state: the yaw
    /// loop of the stabilised modes advances; returns each motor's PWM for the step.
    pub fn control(&mut self, h: f64, vehicle: Vehicle) -> [u16; MOTORS] {
        self.vehicle = vehicle;
        if self.mode != Mode::Manual {
            if !self.armed || self.down_until.is_some() {
                self.yaw = YawLoop::at(vehicle.heading);
            } else {
                let gains = YawGains {
                    angle_p: self.param("ATC_ANG_YAW_P"),
                    accel_max: self.param("ATC_ACCEL_Y_MAX").max(0.0) / 100.0 * DEG,
                    rate_p: self.param("ATC_RAT_YAW_P"),
                    rate_i: self.param("ATC_RAT_YAW_I"),
                    rate_imax: self.param("ATC_RAT_YAW_IMAX"),
                    filter_hz: self.param("ATC_RAT_YAW_FLTT"),
                };
                let pilot = self.pilot_yaw_rate();
                self.yaw.step(&gains, pilot, h, vehicle);
            }
        }
        self.pwm()
    }
}

const DEG: f64 = std::f64::consts::PI / 180.0;

/// The yaw attitude loop's gains (SI units).
struct YawGains {
    angle_p: f64,
    /// rad/s/s; 0: no limit.
    accel_max: f64,
    rate_p: f64,
    rate_i: f64,
    rate_imax: f64,
    filter_hz: f64,
}

/// The stabilised modes' yaw loop (`mode_althold.cpp` over `AC_AttitudeControl`): with the yaw
/// stick used, a rate command fed forward and integrated into the target heading; released, the
/// rate brought to 0 for 250 ms, then the heading of that moment held; a PI loop on the yaw rate.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct YawLoop {
    /// The attitude target's heading and its feedforward rate.
    target: f64,
    feedforward: f64,
    /// The heading to hold once released (`last_pilot_heading`) and the time since the stick was
    /// last used.
    hold: f64,
    since_input: f64,
    /// The rate controller: its filtered target, its integrator, its output.
    rate_target: f64,
    integrator: f64,
    out: f64,
}

impl YawLoop {
    /// At rest on `heading` (a mode entered, armed, disarmed, repositioned).
    fn at(heading: f64) -> YawLoop {
        YawLoop {
            target: heading,
            hold: heading,
            ..YawLoop::default()
        }
    }

    fn step(&mut self, g: &YawGains, pilot_rate: f64, h: f64, v: Vehicle) {
        let accel = g.accel_max * h;
        if pilot_rate != 0.0 || self.since_input + h < YAW_RELEASE_S {
            if pilot_rate != 0.0 {
                self.since_input = 0.0;
            } else {
                self.since_input += h;
            }
            self.feedforward = approach(self.feedforward, pilot_rate, accel);
            self.target = wrap_pi(self.target + self.feedforward * h);
            self.hold = v.heading;
        } else {
            self.since_input += h;
            self.feedforward = 0.0;
            self.target = self.hold;
        }
        let desired = self.feedforward + g.angle_p * wrap_pi(self.target - v.heading);
        let k = if g.filter_hz > 0.0 {
            let rc = 1.0 / (std::f64::consts::TAU * g.filter_hz);
            h / (h + rc)
        } else {
            1.0
        };
        self.rate_target += k * (desired - self.rate_target);
        let error = self.rate_target - v.yaw_rate;
        self.integrator = (self.integrator + g.rate_i * error * h).clamp(-g.rate_imax, g.rate_imax);
        self.out = (g.rate_p * error + self.integrator).clamp(-1.0, 1.0);
    }
}

/// Where the autopilot's MAVLink port is, in the `mavlink` crate's URL syntax.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Url {
    /// `udpin:HOST:PORT`: listen there, answer whoever sends (BlueOS's ground-station endpoint is
    /// UDP 14550).
    UdpIn(std::net::SocketAddr),
    /// `udpout:HOST:PORT`: send there (and answer whoever sends) from an ephemeral port.
    UdpOut(std::net::SocketAddr),
}

impl std::str::FromStr for Url {
    type Err = String;
    fn from_str(s: &str) -> Result<Url, String> {
        let (scheme, addr) = s
            .split_once(':')
            .ok_or_else(|| format!("`{s}`: expected udpin:HOST:PORT or udpout:HOST:PORT"))?;
        let addr: std::net::SocketAddr = addr
            .parse()
            .map_err(|e| format!("`{s}`: `{addr}` is not HOST:PORT ({e})"))?;
        match scheme {
            "udpin" => Ok(Url::UdpIn(addr)),
            "udpout" => Ok(Url::UdpOut(addr)),
            other => Err(format!(
                "`{s}`: `{other}` is not supported (udpin or udpout)"
            )),
        }
    }
}

#[cfg(test)]
mod tests;
