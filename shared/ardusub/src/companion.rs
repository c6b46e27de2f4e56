//! The companion: everything the stack says to ArduSub and makes of its answers, as one state
//! machine fed the time and the frames received, giving back the messages to send, what to log and
//! the telemetry to publish. No sockets, no clock: the sink ([`crate::ArduSubSink`]) binds it to a
//! link, and the tests drive it by hand.
//!
//! Its life: it beats its own heartbeat (1 Hz, MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID);
//! waits for the autopilot's (a submarine's); asks for telemetry and reads the parameters
//! ([`crate::params`]), refusing to go on when ArduSub would ignore its MANUAL_CONTROL or has its
//! pilot-input failsafe off; sets the mode and arms (a fresh start only; [`crate::spec::Arming`]),
//! each command carried to its end ([`crate::command`]); then pilots: each step's forces as
//! MANUAL_CONTROL at once, held at the steady rate, neutral on a stop ([`crate::pilot`]), each
//! followed by its lockstep tag. From the autopilot's first heartbeat on, it sends MANUAL_CONTROL at
//! the steady rate (neutral until commanded), so the pilot input is fresh when it arms. Closing, it
//! goes neutral and disarms. The autopilot's state comes from its heartbeat alone; a disarm the
//! companion did not ask for is reported, never undone.

use crate::autopilot::{Address, Change, Status, Watch};
use crate::command::{Action, Command, Failure, Progress};
use crate::params::{self, Reader, Settings, Unanswered};
use crate::pilot::{self, Axes, Clipped, Pilot, Reach};
use crate::spec::{Arming, Options, Timing, mode_name};
use crate::telemetry::{self, Battery, Telemetry};
use crate::wire::Frame;
use mavlink::dialects::ardupilotmega::{
    HEARTBEAT_DATA, MavAutopilot, MavCmd, MavMessage, MavModeFlag, MavResult, MavState, MavType,
    NAMED_VALUE_INT_DATA, PARAM_REQUEST_READ_DATA,
};
use messages::{AutopilotState, Stamp, StopCause};
use model::Forces;
use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// The lockstep tag's names: after the MANUAL_CONTROL answering a step, and after a stop's.
pub const STEP_TAG: &str = "ct_step";
pub const STOP_TAG: &str = "ct_stop";

/// Where the companion is in its life.
#[derive(Clone, Debug, PartialEq)]
pub enum Phase {
    /// Waiting for the autopilot's first heartbeat, until the given time.
    Connecting {
        until: Instant,
    },
    /// Reading the parameters; then deciding with the autopilot's state (given up at `until` if
    /// its heartbeat is lost meanwhile).
    Reading {
        until: Instant,
    },
    /// Setting the mode and arming, one command after the other.
    Preparing,
    /// Piloting.
    Running,
    /// Disarming.
    Closing,
    Closed,
}

/// Why the companion cannot go on.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(
        "no heartbeat from an ArduSub autopilot within {waited:?} (is the vehicle on, and this the address its MAVLink router serves?)"
    )]
    NoHeartbeat { waited: Duration },
    #[error(transparent)]
    Unanswered(#[from] Unanswered),
    /// A parameter makes piloting unsafe or useless: the text names it and the value to set.
    #[error("{0}")]
    Refused(String),
    #[error(transparent)]
    Command(#[from] Failure),
}

/// What happened, for the log.
#[derive(Clone, Debug, PartialEq)]
pub enum Event {
    Found {
        autopilot: Address,
        status: Status,
    },
    Lost {
        silent: Duration,
    },
    Back {
        status: Status,
    },
    Read(Settings),
    /// The pilot gain changed (a ground station's gain buttons): commands are rescaled.
    Gain {
        from: f64,
        to: f64,
    },
    /// A command beyond what ArduSub's gain lets an axis give (told once).
    Clipped {
        clipped: Clipped,
        gain: f64,
        settings: Option<Settings>,
    },
    ModeSet(u32),
    Armed,
    /// Piloting starts.
    Running {
        status: Status,
        restarted: bool,
    },
    /// A restarted driver found the vehicle disarmed and leaves it so.
    NotArmedAfterRestart,
    /// A restarted driver leaves the mode a ground station chose.
    ModeKept {
        mode: u32,
    },
    /// `arm=manual`: the pilot arms.
    WaitingForPilot,
    AlreadyArmed,
    /// The autopilot disarmed without being asked by this driver.
    DisarmedByAutopilot {
        text: Option<String>,
    },
    /// Someone else (a ground station) armed the vehicle.
    ArmedElsewhere,
    ModeChanged {
        from: u32,
        to: u32,
    },
    Disarmed,
    AlreadyDisarmed,
    /// A telemetry request the autopilot did not accept.
    IntervalRefused(MavResult),
    /// The autopilot's own text.
    Text {
        severity: u8,
        text: String,
    },
}

/// How loud an event is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Level {
    Info,
    Warn,
    Error,
}

impl Event {
    pub fn level(&self) -> Level {
        match self {
            Event::Lost { .. }
            | Event::Back { .. }
            | Event::Clipped { .. }
            | Event::NotArmedAfterRestart
            | Event::ModeKept { .. }
            | Event::DisarmedByAutopilot { .. }
            | Event::ModeChanged { .. }
            | Event::IntervalRefused(_) => Level::Warn,
            // MAV_SEVERITY: 0..3 emergency to error, 4 warning.
            Event::Text { severity, .. } if *severity <= 3 => Level::Error,
            Event::Text { severity: 4, .. } => Level::Warn,
            _ => Level::Info,
        }
    }
}

fn state(s: &Status) -> String {
    format!(
        "{}, {}",
        if s.armed { "armed" } else { "disarmed" },
        mode_name(s.mode)
    )
}

/// The likely cause of a disarm nobody here asked for, from the autopilot's last text.
fn disarm_cause(text: &Option<String>) -> &'static str {
    let t = text.as_deref().unwrap_or("").to_lowercase();
    if t.contains("manual control") {
        "its pilot-input failsafe (no MANUAL_CONTROL for FS_PILOT_TIMEOUT, with FS_PILOT_INPUT = 2)"
    } else if t.contains("leak") {
        "its leak failsafe"
    } else if t.contains("battery") {
        "its battery failsafe"
    } else if t.contains("crash") {
        "its crash check"
    } else if t.contains("ekf") {
        "its EKF failsafe"
    } else if t.contains("gcs") || t.contains("heartbeat") {
        "its ground-station failsafe"
    } else {
        "a ground station's disarm or one of its failsafes (most likely the pilot-input one, FS_PILOT_INPUT, if this driver's messages stopped reaching it)"
    }
}

impl std::fmt::Display for Event {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Event::Found { autopilot, status } => write!(
                f,
                "ArduSub found: system {}, component {} ({})",
                autopilot.system,
                autopilot.component,
                state(status)
            ),
            Event::Lost { silent } => write!(
                f,
                "ArduSub's heartbeat lost ({silent:?} without one): its state is unknown until it comes back"
            ),
            Event::Back { status } => write!(f, "ArduSub's heartbeat is back ({})", state(status)),
            Event::Read(s) => write!(f, "ArduSub's parameters: {s}"),
            Event::Gain { from, to } => write!(
                f,
                "ArduSub's pilot gain changed from {from} to {to} (a ground station's gain buttons?): commands are scaled by the new one"
            ),
            Event::Clipped {
                clipped,
                gain,
                settings,
            } => {
                write!(
                    f,
                    "a {} command of {:.3} is beyond what ArduSub lets the pilot give ({:.3} of full thrust at pilot gain {gain}): it is sent as the full axis. ",
                    clipped.dof, clipped.command, clipped.reach
                )?;
                match settings {
                    Some(s) if s.gain.at_boot() < 1.0 || *gain < 1.0 => write!(
                        f,
                        "Set {} to 1.0 (and {} to 1.0; now {} and {}) so that every command up to full thrust is reachable",
                        params::GAIN_DEFAULT,
                        params::GAIN_MAX,
                        s.gain.default,
                        s.gain.max
                    ),
                    _ => write!(
                        f,
                        "Set {} to {} (now {}) so that full yaw is reachable",
                        params::YAW_P,
                        params::YAW_P_DEFAULT,
                        settings.and_then(|s| s.yaw_p).unwrap_or(f64::NAN)
                    ),
                }
            }
            Event::ModeSet(m) => write!(f, "ArduSub is in {}", mode_name(*m)),
            Event::Armed => f.write_str("ArduSub armed"),
            Event::Running { status, restarted } => write!(
                f,
                "piloting ArduSub ({}{})",
                state(status),
                if *restarted { ", after a restart" } else { "" }
            ),
            Event::NotArmedAfterRestart => f.write_str(
                "ArduSub is disarmed and this driver, restarted, does not arm it again (it may have disarmed on a failsafe while the driver was down): arm it from the ground station once it is safe",
            ),
            Event::ModeKept { mode } => write!(
                f,
                "ArduSub is in {}: a restarted driver does not change the mode a ground station chose",
                mode_name(*mode)
            ),
            Event::WaitingForPilot => {
                f.write_str("ArduSub is disarmed: with arm=manual the pilot arms it from a ground station")
            }
            Event::AlreadyArmed => f.write_str("ArduSub was armed already (by a ground station)"),
            Event::DisarmedByAutopilot { text } => {
                write!(
                    f,
                    "ArduSub disarmed without being asked by this driver: likely {}",
                    disarm_cause(text)
                )?;
                if let Some(t) = text {
                    write!(f, " (its last message: \"{t}\")")?;
                }
                f.write_str(". The stack does not arm it again: arm it from the ground station once it is safe")
            }
            Event::ArmedElsewhere => f.write_str("ArduSub was armed by someone else (a ground station)"),
            Event::ModeChanged { from, to } => write!(
                f,
                "ArduSub's mode changed from {} to {} (not by this driver)",
                mode_name(*from),
                mode_name(*to)
            ),
            Event::Disarmed => f.write_str("ArduSub disarmed"),
            Event::AlreadyDisarmed => f.write_str("ArduSub was disarmed already"),
            Event::IntervalRefused(r) => write!(
                f,
                "ArduSub answered a telemetry request (MAV_CMD_SET_MESSAGE_INTERVAL) with {r:?}: that telemetry comes at its stream rates"
            ),
            Event::Text { text, .. } => write!(f, "ArduSub says: {text}"),
        }
    }
}

/// What the companion has to send, log and publish.
#[derive(Debug, Default)]
pub struct Output {
    pub send: Vec<MavMessage>,
    pub events: Vec<Event>,
    /// Telemetry with the time its message arrived.
    pub telemetry: Vec<(Instant, Telemetry)>,
    /// The autopilot's state, when it changed or its heartbeat came (or was lost).
    pub state: Vec<(Instant, AutopilotState)>,
}

pub struct Companion {
    options: Options,
    timing: Timing,
    restarted: bool,
    phase: Phase,
    watch: Watch,
    /// The autopilot's last known state, kept through a loss (to tell what changed meanwhile).
    known: Option<Status>,
    params: Reader,
    settings: Option<Settings>,
    plan: VecDeque<Action>,
    command: Option<Command>,
    pilot: Pilot,
    /// The gain ArduSub reports (NAMED_VALUE_FLOAT `PilotGain`), once it did.
    live_gain: Option<f64>,
    clip_told: bool,
    next_heartbeat: Instant,
    battery: Battery,
    last_text: Option<String>,
    out: Output,
}

impl Companion {
    /// A companion starting at `now`; `restarted` when the supervisor restarted this driver.
    pub fn new(options: Options, timing: Timing, restarted: bool, now: Instant) -> Self {
        Companion {
            pilot: Pilot::new(options.period(), Reach::new(1.0, 1.0)),
            options,
            timing,
            restarted,
            phase: Phase::Connecting {
                until: now + timing.connect,
            },
            watch: Watch::new(timing.lost),
            known: None,
            params: Reader::new(timing.param_retry, timing.param_tries),
            settings: None,
            plan: VecDeque::new(),
            command: None,
            live_gain: None,
            clip_told: false,
            next_heartbeat: now,
            battery: Battery::default(),
            last_text: None,
            out: Output::default(),
        }
    }

    pub fn phase(&self) -> &Phase {
        &self.phase
    }

    pub fn is_running(&self) -> bool {
        self.phase == Phase::Running
    }

    pub fn is_closed(&self) -> bool {
        self.phase == Phase::Closed
    }

    pub fn autopilot(&self) -> Option<Address> {
        self.watch.address()
    }

    /// The autopilot's state now (`None`: unknown).
    pub fn status(&self) -> Option<Status> {
        self.watch.status()
    }

    pub fn settings(&self) -> Option<&Settings> {
        self.settings.as_ref()
    }

    /// The pilot gain commands are scaled by.
    pub fn gain(&self) -> f64 {
        self.live_gain
            .or(self.settings.map(|s| s.gain.at_boot()))
            .unwrap_or(1.0)
    }

    /// What a full axis gives now.
    pub fn reach(&self) -> Reach {
        self.pilot.reach()
    }

    /// Takes what is to be sent, logged and published.
    pub fn take(&mut self) -> Output {
        std::mem::take(&mut self.out)
    }

    fn send(&mut self, m: MavMessage) {
        self.out.send.push(m);
    }

    fn tell(&mut self, e: Event) {
        self.out.events.push(e);
    }

    fn publish_state(&mut self, at: Instant) {
        let status = self.watch.status();
        self.out.state.push((
            at,
            AutopilotState {
                heartbeat: status.is_some() as u8,
                armed: status.is_some_and(|s| s.armed) as u8,
                mode: status.map_or(0, |s| s.mode),
                system_status: status.map_or(0, |s| s.system_status),
                battery_v: self.battery.volts,
                battery_a: self.battery.amperes,
                battery_remaining: self.battery.remaining,
                pilot_gain: self.gain(),
                ..Default::default()
            },
        ));
    }

    /// The scaling of the axes: under the scenario's `[pilot]` its fractions over the gain;
    /// otherwise the gain on each, and in MANUAL the yaw's ACRO_YAW_P / 4.5.
    fn update_reach(&mut self) {
        if let Some(fractions) = &self.options.fractions {
            self.pilot
                .set_reach(Reach::of_pilot(self.gain(), fractions));
            return;
        }
        let yaw_scale = match (self.options.mode, self.settings.and_then(|s| s.yaw_p)) {
            (crate::spec::Mode::Manual, Some(p)) if p > 0.0 => p / params::YAW_P_DEFAULT,
            _ => 1.0,
        };
        self.pilot.set_reach(Reach::new(self.gain(), yaw_scale));
    }

    /// A frame arrived at `at`.
    pub fn on_frame(&mut self, at: Instant, frame: &Frame) {
        let from = Address {
            system: frame.system,
            component: frame.component,
        };
        if let MavMessage::HEARTBEAT(hb) = &frame.message {
            if let Some(change) = self.watch.on_heartbeat(at, from, hb) {
                self.on_change(change);
            }
            if self.watch.is_from(from) {
                self.publish_state(at);
            }
            return;
        }
        if !self.watch.is_from(from) {
            return;
        }
        match &frame.message {
            MavMessage::PARAM_VALUE(p) => {
                if let Ok(name) = p.param_id.to_str() {
                    self.params.on_value(name, p.param_value);
                }
            }
            MavMessage::COMMAND_ACK(ack) => {
                // An acknowledgement addressed to someone else (a ground station's command) is not
                // ours; firmware without the extension fields sends 0.
                if ack.target_system != 0 && ack.target_system != self.options.system {
                    return;
                }
                if ack.command == MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL {
                    if ack.result != MavResult::MAV_RESULT_ACCEPTED {
                        self.tell(Event::IntervalRefused(ack.result));
                    }
                } else if let Some(c) = &mut self.command {
                    c.on_ack(at, ack, self.last_text.as_deref());
                }
            }
            MavMessage::NAMED_VALUE_FLOAT(v) => {
                if v.name.to_str() == Ok("PilotGain") {
                    let to = f64::from(v.value);
                    if self.live_gain != Some(to) {
                        let from = self.gain();
                        self.live_gain = Some(to);
                        if self.settings.is_some() {
                            if (from - to).abs() > 1e-6 {
                                self.tell(Event::Gain { from, to });
                            }
                            self.update_reach();
                        }
                    }
                }
            }
            MavMessage::SYS_STATUS(s) => self.battery = telemetry::battery(s),
            message => {
                if let Some(t) = telemetry::decode(message) {
                    if let Telemetry::Text(text) = &t {
                        self.last_text = Some(text.text());
                        self.tell(Event::Text {
                            severity: text.severity,
                            text: text.text(),
                        });
                    }
                    self.out.telemetry.push((at, t));
                }
            }
        }
    }

    fn on_change(&mut self, change: Change) {
        match change {
            Change::Found(autopilot, status) => {
                self.known = Some(status);
                self.tell(Event::Found { autopilot, status });
            }
            Change::Lost { silent } => self.tell(Event::Lost { silent }),
            Change::Back(status) => {
                self.tell(Event::Back { status });
                self.judge(status);
            }
            Change::Changed { to, .. } => self.judge(to),
        }
    }

    /// The autopilot's state as it now is, against what it was: while piloting, a disarm or a mode
    /// change not made here is reported (and never undone).
    fn judge(&mut self, now: Status) {
        let before = self.known.replace(now);
        if self.phase != Phase::Running {
            return;
        }
        let Some(before) = before else { return };
        if before.armed && !now.armed {
            let text = self.last_text.clone();
            self.tell(Event::DisarmedByAutopilot { text });
        } else if !before.armed && now.armed {
            self.tell(Event::ArmedElsewhere);
        }
        if before.mode != now.mode {
            self.tell(Event::ModeChanged {
                from: before.mode,
                to: now.mode,
            });
        }
    }

    fn heartbeat(&self) -> MavMessage {
        MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            custom_mode: 0,
            mavtype: MavType::MAV_TYPE_ONBOARD_CONTROLLER,
            autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
            base_mode: MavModeFlag::empty(),
            system_status: MavState::MAV_STATE_ACTIVE,
            mavlink_version: 3,
        })
    }

    /// Time passed: heartbeats, the steady MANUAL_CONTROL, retries, and the next step of the
    /// companion's life. An error ends it (while opening or closing).
    pub fn on_time(&mut self, now: Instant) -> Result<(), Error> {
        if self.phase == Phase::Closed {
            return Ok(());
        }
        if now >= self.next_heartbeat {
            let hb = self.heartbeat();
            self.send(hb);
            self.next_heartbeat = now + self.timing.heartbeat;
        }
        if let Some(change) = self.watch.on_time(now) {
            self.on_change(change);
            self.publish_state(now);
        }
        if let Some(target) = self.watch.address()
            && let Some(axes) = self.pilot.due(now)
        {
            self.send(pilot::manual_control(&axes, target.system));
        }
        match self.phase.clone() {
            Phase::Connecting { until } => match self.watch.address() {
                Some(target) => {
                    for m in telemetry::requests(target) {
                        self.send(m);
                    }
                    self.phase = Phase::Reading {
                        until: now + self.timing.connect,
                    };
                    self.read(now, target)?;
                }
                None if now >= until => {
                    return Err(Error::NoHeartbeat {
                        waited: self.timing.connect,
                    });
                }
                None => {}
            },
            Phase::Reading { until } => {
                if let Some(target) = self.watch.address() {
                    self.read(now, target)?;
                }
                if matches!(self.phase, Phase::Reading { .. }) && now >= until {
                    return Err(Error::NoHeartbeat {
                        waited: self.timing.connect,
                    });
                }
            }
            Phase::Preparing => self.prepare(now)?,
            Phase::Closing => self.disarming(now)?,
            Phase::Running | Phase::Closed => {}
        }
        Ok(())
    }

    /// Reading the parameters: requests, and once all are in, the checks and the plan.
    fn read(&mut self, now: Instant, target: Address) -> Result<(), Error> {
        for name in self.params.due(now) {
            self.send(MavMessage::PARAM_REQUEST_READ(PARAM_REQUEST_READ_DATA {
                param_index: -1,
                target_system: target.system,
                target_component: target.component,
                param_id: name.into(),
            }));
        }
        if !self.params.done(now) {
            return Ok(());
        }
        // The plan depends on the autopilot's state: wait while its heartbeat is lost.
        let Some(status) = self.watch.status() else {
            return Ok(());
        };
        let settings = self.params.settings()?;
        self.tell(Event::Read(settings));
        if let Some(refusal) = settings.refusal(&self.options) {
            return Err(Error::Refused(refusal));
        }
        self.settings = Some(settings);
        self.update_reach();
        let wanted = self.options.mode.custom_mode();
        if self.restarted {
            if status.mode != wanted {
                self.tell(Event::ModeKept { mode: status.mode });
            }
            if !status.armed {
                self.tell(Event::NotArmedAfterRestart);
            }
        } else {
            if status.mode != wanted {
                self.plan.push_back(Action::SetMode(self.options.mode));
            }
            match (self.options.arm, status.armed) {
                (_, true) => self.tell(Event::AlreadyArmed),
                (Arming::Auto, false) => self.plan.push_back(Action::Arm),
                (Arming::Manual, false) => self.tell(Event::WaitingForPilot),
            }
        }
        self.phase = Phase::Preparing;
        self.prepare(now)
    }

    /// Setting the mode and arming: each command to its end, then piloting.
    fn prepare(&mut self, now: Instant) -> Result<(), Error> {
        loop {
            if self.command.is_none() {
                let Some(action) = self.plan.pop_front() else {
                    self.phase = Phase::Running;
                    let status = self.watch.status().or(self.known);
                    if let Some(status) = status {
                        self.known = Some(status);
                        self.tell(Event::Running {
                            status,
                            restarted: self.restarted,
                        });
                    }
                    return Ok(());
                };
                self.command = Some(Command::new(action, self.target(), self.timing));
            }
            match self.step_command(now)? {
                Progress::Done => {
                    let action = self.command.take().map(|c| c.action());
                    // The heartbeat showed it: take its state as the one before piloting.
                    self.known = self.watch.status().or(self.known);
                    match action {
                        Some(Action::SetMode(m)) => self.tell(Event::ModeSet(m.custom_mode())),
                        Some(Action::Arm) => self.tell(Event::Armed),
                        _ => {}
                    }
                }
                _ => return Ok(()),
            }
        }
    }

    fn target(&self) -> Address {
        self.watch.address().unwrap_or(Address {
            system: 1,
            component: 1,
        })
    }

    /// Sends the command in flight if due and judges it.
    fn step_command(&mut self, now: Instant) -> Result<Progress, Error> {
        let status = self.watch.status();
        let text = self.last_text.clone();
        let Some(c) = &mut self.command else {
            return Ok(Progress::Done);
        };
        let msg = c.due(now);
        let progress = c.on_time(now, status, text.as_deref());
        if let Some(m) = msg {
            self.send(m);
        }
        match progress {
            Progress::Failed(f) => {
                self.command = None;
                Err(f.into())
            }
            p => Ok(p),
        }
    }

    fn disarming(&mut self, now: Instant) -> Result<(), Error> {
        match self.step_command(now) {
            Ok(Progress::Done) => {
                self.command = None;
                self.phase = Phase::Closed;
                self.tell(Event::Disarmed);
                Ok(())
            }
            Ok(_) => Ok(()),
            Err(e) => {
                self.phase = Phase::Closed;
                Err(e)
            }
        }
    }

    /// The lockstep tag after a MANUAL_CONTROL: the step's time (ms) and `value`.
    fn tag(&mut self, name: &str, stamp: &Stamp, value: i32) {
        self.send(MavMessage::NAMED_VALUE_INT(NAMED_VALUE_INT_DATA {
            time_boot_ms: (stamp.time_ns / 1_000_000) as u32,
            value,
            name: name.into(),
        }));
    }

    /// A step's forces: its MANUAL_CONTROL at once (held until the next step or a stop), then its
    /// lockstep tag. Returns the axes sent.
    pub fn command(&mut self, forces: &Forces, stamp: &Stamp) -> Option<Axes> {
        let target = self.watch.address()?;
        if self.phase == Phase::Closed {
            return None;
        }
        let (axes, clipped) = self.pilot.command(forces);
        self.send(pilot::manual_control(&axes, target.system));
        self.tag(STEP_TAG, stamp, stamp.step as i32);
        if let Some(clipped) = clipped
            && !self.clip_told
        {
            self.clip_told = true;
            let (gain, settings) = (self.gain(), self.settings);
            self.tell(Event::Clipped {
                clipped,
                gain,
                settings,
            });
        }
        Some(axes)
    }

    /// A stop: neutral at once, held, then the stop's tag (the last step's time, the cause).
    pub fn stop(&mut self, stamp: &Stamp, cause: StopCause) {
        let Some(target) = self.watch.address() else {
            return;
        };
        let axes = self.pilot.neutral();
        self.send(pilot::manual_control(&axes, target.system));
        self.tag(STOP_TAG, stamp, cause as u32 as i32);
    }

    /// Closing: disarms unless the autopilot is known to be disarmed (or was never found). The
    /// caller stops the thrusters first.
    pub fn close(&mut self, now: Instant) -> Result<(), Error> {
        if matches!(self.phase, Phase::Closing | Phase::Closed) {
            return Ok(());
        }
        self.plan.clear();
        self.command = None;
        if self.watch.address().is_none() {
            self.phase = Phase::Closed;
            return Ok(());
        }
        if self.watch.status().is_some_and(|s| !s.armed) {
            self.tell(Event::AlreadyDisarmed);
            self.phase = Phase::Closed;
            return Ok(());
        }
        self.command = Some(Command::new(Action::Disarm, self.target(), self.timing));
        self.phase = Phase::Closing;
        self.disarming(now)
    }

    /// When [`Companion::on_time`] has something to do next.
    pub fn next_wake(&self) -> Instant {
        let mut t = self.next_heartbeat;
        let mut consider = |c: Option<Instant>| {
            if let Some(c) = c {
                t = t.min(c);
            }
        };
        if self.watch.address().is_some() {
            consider(self.pilot.next_due());
        }
        consider(self.watch.deadline());
        match &self.phase {
            Phase::Connecting { until } => consider(Some(*until)),
            Phase::Reading { until } => {
                consider(self.params.next_deadline());
                consider(Some(*until));
            }
            _ => {}
        }
        consider(self.command.as_ref().and_then(|c| c.next_deadline()));
        t
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::autopilot::tests::heartbeat;
    use crate::params::*;
    use crate::pilot::Z_NEUTRAL;
    use crate::spec::Mode;
    use mavlink::dialects::ardupilotmega::{
        COMMAND_ACK_DATA, MavSeverity, NAMED_VALUE_FLOAT_DATA, PARAM_VALUE_DATA, STATUSTEXT_DATA,
    };
    use messages::StepStatus;

    const MS: Duration = Duration::from_millis(1);
    const AP: Address = Address {
        system: 1,
        component: 1,
    };
    const SUB: MavType = MavType::MAV_TYPE_SUBMARINE;

    /// A scripted ArduSub: answers what the companion sends, as the real one does.
    struct Autopilot {
        armed: bool,
        mode: u32,
        params: Vec<(&'static str, f32)>,
        /// Answer to arming.
        arm_result: MavResult,
        /// Commands received.
        commands: Vec<(MavCmd, f32, f32)>,
        answer: bool,
    }

    fn ardusub_47() -> Vec<(&'static str, f32)> {
        vec![
            (GCS_SYSID, 254.0),
            (GCS_SYSID_HI, 255.0),
            (PILOT_INPUT, 2.0),
            (PILOT_TIMEOUT, 3.0),
            (GAIN_DEFAULT, 1.0),
            (GAIN_MIN, 0.25),
            (GAIN_MAX, 1.0),
            (GAIN_STEPS, 4.0),
            (YAW_P, 4.5),
        ]
    }

    impl Autopilot {
        fn new(params: Vec<(&'static str, f32)>) -> Self {
            Autopilot {
                armed: false,
                mode: 0,
                params,
                arm_result: MavResult::MAV_RESULT_ACCEPTED,
                commands: Vec::new(),
                answer: true,
            }
        }

        fn frame(&self, message: MavMessage) -> Frame {
            Frame {
                system: AP.system,
                component: AP.component,
                sequence: 0,
                message,
            }
        }

        fn heartbeat(&self) -> Frame {
            self.frame(MavMessage::HEARTBEAT(heartbeat(SUB, self.armed, self.mode)))
        }

        /// Its answers to what `c` sent.
        fn answer(&mut self, sent: &[MavMessage]) -> Vec<Frame> {
            let mut out = Vec::new();
            if !self.answer {
                return out;
            }
            for m in sent {
                match m {
                    MavMessage::PARAM_REQUEST_READ(r) => {
                        let name = r.param_id.to_str().unwrap();
                        if let Some((n, v)) = self.params.iter().find(|(n, _)| *n == name) {
                            out.push(self.frame(MavMessage::PARAM_VALUE(PARAM_VALUE_DATA {
                                param_value: *v,
                                param_id: (*n).into(),
                                ..Default::default()
                            })));
                        }
                    }
                    MavMessage::COMMAND_LONG(c) => {
                        self.commands.push((c.command, c.param1, c.param2));
                        let mut result = MavResult::MAV_RESULT_ACCEPTED;
                        match c.command {
                            MavCmd::MAV_CMD_COMPONENT_ARM_DISARM if c.param1 == 1.0 => {
                                result = self.arm_result;
                                if result == MavResult::MAV_RESULT_ACCEPTED {
                                    self.armed = true;
                                }
                            }
                            MavCmd::MAV_CMD_COMPONENT_ARM_DISARM => self.armed = false,
                            MavCmd::MAV_CMD_DO_SET_MODE => self.mode = c.param2 as u32,
                            _ => {}
                        }
                        out.push(self.frame(MavMessage::COMMAND_ACK(COMMAND_ACK_DATA {
                            command: c.command,
                            result,
                            target_system: 254,
                            target_component: 191,
                            ..Default::default()
                        })));
                        out.push(self.heartbeat());
                    }
                    _ => {}
                }
            }
            out
        }
    }

    /// Runs the companion against `ap` from `t` in steps of 10 ms until `until` says so or `limit`
    /// passes; returns everything it output and the time reached.
    fn run(
        c: &mut Companion,
        ap: &mut Autopilot,
        t: &mut Instant,
        limit: Duration,
        until: impl Fn(&Companion) -> bool,
    ) -> (Output, Result<(), Error>) {
        let end = *t + limit;
        let mut all = Output::default();
        while *t < end {
            let r = c.on_time(*t);
            let out = c.take();
            for f in ap.answer(&out.send) {
                c.on_frame(*t, &f);
            }
            all.send.extend(out.send);
            all.events.extend(out.events);
            all.state.extend(out.state);
            all.telemetry.extend(out.telemetry);
            if r.is_err() || until(c) {
                let extra = c.take();
                all.send.extend(extra.send);
                all.events.extend(extra.events);
                return (all, r);
            }
            *t += 10 * MS;
        }
        (all, Ok(()))
    }

    fn opened(
        ap: &mut Autopilot,
        restarted: bool,
        options: Options,
    ) -> (Companion, Instant, Output) {
        let mut t = Instant::now();
        let mut c = Companion::new(options, Timing::default(), restarted, t);
        c.on_time(t).unwrap();
        let first = c.take();
        assert!(
            matches!(&first.send[..], [MavMessage::HEARTBEAT(_)]),
            "{:?}",
            first.send
        );
        c.on_frame(t, &ap.heartbeat());
        let (out, r) = run(&mut c, ap, &mut t, Duration::from_secs(20), |c| {
            c.is_running()
        });
        r.unwrap();
        assert!(c.is_running(), "{:?}", c.phase());
        (c, t, out)
    }

    fn commands(out: &Output) -> Vec<(MavCmd, f32, f32)> {
        out.send
            .iter()
            .filter_map(|m| match m {
                MavMessage::COMMAND_LONG(c)
                    if c.command != MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL =>
                {
                    Some((c.command, c.param1, c.param2))
                }
                _ => None,
            })
            .collect()
    }

    #[test]
    fn a_fresh_start_reads_checks_sets_the_mode_and_arms_then_pilots() {
        let mut ap = Autopilot::new(ardusub_47());
        let (c, _, out) = opened(&mut ap, false, Options::default());
        assert_eq!(
            commands(&out),
            vec![
                (MavCmd::MAV_CMD_DO_SET_MODE, 1.0, 19.0),
                (MavCmd::MAV_CMD_COMPONENT_ARM_DISARM, 1.0, 0.0)
            ],
            "mode first, then arm"
        );
        assert!(ap.armed && ap.mode == 19);
        let asked: Vec<String> = out
            .send
            .iter()
            .filter_map(|m| match m {
                MavMessage::PARAM_REQUEST_READ(r) => Some(r.param_id.to_str().unwrap().to_string()),
                _ => None,
            })
            .collect();
        for p in [
            GCS_SYSID,
            GCS_SYSID_HI,
            PILOT_INPUT,
            PILOT_TIMEOUT,
            GAIN_DEFAULT,
        ] {
            assert!(asked.iter().any(|a| a == p), "{p} asked: {asked:?}");
        }
        // Telemetry was requested, and neutral sticks were sent before arming.
        assert_eq!(
            out.send
                .iter()
                .filter(|m| matches!(m, MavMessage::COMMAND_LONG(c) if c.command == MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL))
                .count(),
            4
        );
        let first_arm = out
            .send
            .iter()
            .position(|m| matches!(m, MavMessage::COMMAND_LONG(c) if c.command == MavCmd::MAV_CMD_COMPONENT_ARM_DISARM))
            .unwrap();
        assert!(out.send[..first_arm].iter().any(|m| matches!(m, MavMessage::MANUAL_CONTROL(mc) if mc.x == 0 && mc.z == 500 && mc.target == 1)));
        assert!(out.events.contains(&Event::Armed));
        assert!(out.events.iter().any(|e| matches!(
            e,
            Event::Running {
                restarted: false,
                ..
            }
        )));
        assert_eq!(c.gain(), 1.0);
    }

    #[test]
    fn a_restarted_driver_neither_arms_nor_changes_the_mode() {
        let mut ap = Autopilot::new(ardusub_47());
        ap.mode = 0;
        let (_, _, out) = opened(&mut ap, true, Options::default());
        assert_eq!(commands(&out), vec![], "no command");
        assert!(!ap.armed);
        assert!(out.events.contains(&Event::NotArmedAfterRestart));
        assert!(out.events.contains(&Event::ModeKept { mode: 0 }));
        // Armed already (the autopilot kept going while the driver restarted): it drives on.
        let mut ap = Autopilot::new(ardusub_47());
        ap.armed = true;
        ap.mode = 19;
        let (_, _, out) = opened(&mut ap, true, Options::default());
        assert!(!out.events.contains(&Event::NotArmedAfterRestart));
        assert!(
            out.events
                .iter()
                .any(|e| matches!(e, Event::Running { restarted: true, status } if status.armed))
        );
    }

    #[test]
    fn arm_manual_leaves_arming_to_the_pilot() {
        let mut ap = Autopilot::new(ardusub_47());
        ap.mode = 19;
        let options = Options {
            arm: Arming::Manual,
            ..Options::default()
        };
        let (_, _, out) = opened(&mut ap, false, options);
        assert_eq!(commands(&out), vec![]);
        assert!(out.events.contains(&Event::WaitingForPilot));
    }

    fn refused(params: Vec<(&'static str, f32)>) -> String {
        let mut ap = Autopilot::new(params);
        let mut t = Instant::now();
        let mut c = Companion::new(Options::default(), Timing::default(), false, t);
        c.on_frame(t, &ap.heartbeat());
        let (out, r) = run(&mut c, &mut ap, &mut t, Duration::from_secs(20), |c| {
            c.is_running()
        });
        assert!(
            commands(&out).is_empty(),
            "nothing commanded before the check"
        );
        assert!(!ap.armed);
        match r {
            Err(Error::Refused(s)) => s,
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn ardusub_that_would_ignore_the_stick_or_never_stop_is_refused_before_arming() {
        let mut p = ardusub_47();
        p[0].1 = 255.0;
        p[1].1 = 0.0;
        let r = refused(p);
        assert!(
            r.contains("MAV_GCS_SYSID to 254 and MAV_GCS_SYSID_HI to 255"),
            "{r}"
        );
        // Before 4.7: SYSID_MYGCS.
        let mut p: Vec<_> = ardusub_47().into_iter().skip(2).collect();
        p.push((MYGCS, 255.0));
        let r = refused(p);
        assert!(
            r.contains("SYSID_MYGCS = 255") && r.contains("set SYSID_MYGCS to 254"),
            "{r}"
        );
        let mut p = ardusub_47();
        p[2].1 = 0.0;
        let r = refused(p);
        assert!(r.contains("FS_PILOT_INPUT = 0"), "{r}");
    }

    #[test]
    fn a_failed_arm_ends_the_opening_with_the_autopilots_reason() {
        let mut ap = Autopilot::new(ardusub_47());
        ap.mode = 19;
        ap.arm_result = MavResult::MAV_RESULT_FAILED;
        let mut t = Instant::now();
        let mut c = Companion::new(Options::default(), Timing::default(), false, t);
        c.on_frame(t, &ap.heartbeat());
        c.on_frame(
            t,
            &ap.frame(MavMessage::STATUSTEXT(STATUSTEXT_DATA {
                severity: MavSeverity::MAV_SEVERITY_CRITICAL,
                text: "PreArm: Leak Detected".into(),
                ..Default::default()
            })),
        );
        let (_, r) = run(&mut c, &mut ap, &mut t, Duration::from_secs(20), |c| {
            c.is_running()
        });
        let e = r.unwrap_err().to_string();
        assert!(
            e.contains("MAV_RESULT_FAILED") && e.contains("PreArm: Leak Detected"),
            "{e}"
        );
    }

    #[test]
    fn no_autopilot_no_open() {
        let t0 = Instant::now();
        let mut c = Companion::new(Options::default(), Timing::default(), false, t0);
        c.on_time(t0).unwrap();
        // A ground station's heartbeat is no autopilot.
        c.on_frame(
            t0,
            &Frame {
                system: 255,
                component: 190,
                sequence: 0,
                message: MavMessage::HEARTBEAT(heartbeat(MavType::MAV_TYPE_GCS, false, 0)),
            },
        );
        assert!(c.on_time(t0 + Duration::from_secs(9)).is_ok());
        assert_eq!(
            c.next_wake(),
            t0 + Duration::from_secs(9) + Duration::from_secs(1)
        );
        match c.on_time(t0 + Duration::from_secs(10)) {
            Err(Error::NoHeartbeat { .. }) => {}
            other => panic!("{other:?}"),
        }
        // Its heartbeats went out, one at each due time (0, 9 and 10 s here); no stick without an
        // autopilot to address.
        let out = c.take();
        assert!(out.send.iter().all(|m| matches!(m, MavMessage::HEARTBEAT(h) if h.mavtype == MavType::MAV_TYPE_ONBOARD_CONTROLLER && h.autopilot == MavAutopilot::MAV_AUTOPILOT_INVALID)));
        assert_eq!(out.send.len(), 3);
    }

    fn stamp(step: u32) -> Stamp {
        Stamp::new(
            u64::from(step),
            u64::from(step) * 200_000_000 + 7_000_000,
            0,
            step,
            StepStatus::Running,
        )
    }

    #[test]
    fn steps_are_sent_at_once_with_their_tag_and_held_at_the_rate_until_a_stop() {
        let mut ap = Autopilot::new(ardusub_47());
        let (mut c, mut t, _) = opened(&mut ap, false, Options::default());
        let axes = c
            .command(
                &Forces {
                    surge: 0.4,
                    sway: -0.2,
                    yaw: 0.1,
                },
                &stamp(5),
            )
            .unwrap();
        assert_eq!(
            axes,
            Axes {
                x: 400,
                y: -200,
                z: Z_NEUTRAL,
                r: 100
            }
        );
        let out = c.take();
        match &out.send[..] {
            [
                MavMessage::MANUAL_CONTROL(m),
                MavMessage::NAMED_VALUE_INT(tag),
            ] => {
                assert_eq!((m.x, m.y, m.z, m.r, m.target), (400, -200, 500, 100, 1));
                assert_eq!(&tag.name[..7], STEP_TAG.as_bytes());
                assert_eq!((tag.time_boot_ms, tag.value), (1_007, 5));
            }
            other => panic!("{other:?}"),
        }
        // Held: one MANUAL_CONTROL every 50 ms, one heartbeat a second.
        let start = t;
        let mut held = 0;
        let mut heartbeats = 0;
        while t < start + Duration::from_secs(1) {
            c.on_time(t).unwrap();
            for m in c.take().send {
                match m {
                    MavMessage::MANUAL_CONTROL(m) => {
                        assert_eq!((m.x, m.y, m.r), (400, -200, 100));
                        held += 1;
                    }
                    MavMessage::HEARTBEAT(_) => heartbeats += 1,
                    other => panic!("{other:?}"),
                }
            }
            t += MS;
        }
        assert_eq!(held, 20);
        assert_eq!(heartbeats, 1);
        c.stop(&stamp(5), StopCause::Deadline);
        match &c.take().send[..] {
            [
                MavMessage::MANUAL_CONTROL(m),
                MavMessage::NAMED_VALUE_INT(tag),
            ] => {
                assert_eq!((m.x, m.y, m.z, m.r), (0, 0, 500, 0));
                assert_eq!(&tag.name[..7], STOP_TAG.as_bytes());
                assert_eq!(tag.value, StopCause::Deadline as i32);
            }
            other => panic!("{other:?}"),
        }
        c.on_time(t + 100 * MS).unwrap();
        assert!(
            c.take()
                .send
                .iter()
                .all(|m| !matches!(m, MavMessage::MANUAL_CONTROL(m) if m.x != 0)),
            "held neutral"
        );
    }

    /// The companion as the thruster driver's failsafe drives it, without the link: a write's three
    /// setpoints taken as the forces (surge, sway, yaw) its MANUAL_CONTROL carries (the layout's
    /// mixing is the sink's, tested with it), a stop neutral.
    struct Piloting(Companion);

    impl adapters::ThrusterSink for Piloting {
        fn describe(&self) -> String {
            "the companion".into()
        }
        fn thrusters(&self) -> usize {
            3
        }
        fn write(
            &mut self,
            stamp: &Stamp,
            setpoints: &[f64],
        ) -> Result<adapters::Applied, adapters::AdapterError> {
            let applied = adapters::apply("the companion", 3, setpoints)?;
            let v = applied.as_slice();
            let forces = Forces {
                surge: v[0],
                sway: v[1],
                yaw: v[2],
            };
            self.0.command(&forces, stamp);
            Ok(applied)
        }
        fn stop(&mut self, stamp: &Stamp, cause: StopCause) -> Result<(), adapters::AdapterError> {
            self.0.stop(stamp, cause);
            Ok(())
        }
        fn flush(&mut self) -> Result<(), adapters::AdapterError> {
            Ok(())
        }
        fn close(&mut self) -> Result<(), adapters::AdapterError> {
            Ok(())
        }
    }

    #[test]
    fn the_stick_is_held_through_one_missed_frame_and_neutral_at_the_second() {
        use adapters::failsafe::{Failsafe, deadline};
        let mut ap = Autopilot::new(ardusub_47());
        let (c, start, _) = opened(&mut ap, false, Options::default());
        const PERIOD: Duration = Duration::from_millis(200);
        // Camera to the driver: a slow frame's.
        const LATENCY: Duration = Duration::from_millis(20);
        let mut failsafe = Failsafe::new(Piloting(c), deadline(PERIOD));
        // The vehicle clock (ns) reads 1000 s at `start`; frame k is taken k periods after it.
        let clock = |at: Instant| 1_000_000_000_000 + at.duration_since(start).as_nanos() as i64;
        let taken = |k: u32| start + PERIOD * k;
        let missed = [2, 4, 5];
        // Frame k's stick: surge 0.1 (k + 1).
        let x = |k: u32| 100 * (k as i16 + 1);
        let mut sticks: Vec<(Duration, i16)> = Vec::new();
        let mut k = 0;
        let mut t = start;
        while t < taken(7) {
            if k < 7 && t == taken(k) + LATENCY {
                if !missed.contains(&k) {
                    let mut st = stamp(k);
                    st = st.timed(1, clock(taken(k)));
                    let until = failsafe.fresh_until(st.clock_ns);
                    let force = 0.1 * f64::from(k + 1);
                    failsafe.apply(&st, &[force, 0.0, 0.0], until).unwrap();
                }
                k += 1;
            }
            failsafe.on_time(clock(t)).unwrap();
            failsafe.sink_mut().0.on_time(t).unwrap();
            for m in failsafe.sink_mut().0.take().send {
                if let MavMessage::MANUAL_CONTROL(m) = m {
                    sticks.push((t.duration_since(start), m.x));
                }
            }
            t += MS;
        }
        // At the steady rate from frame 0's setpoints on, each carrying the newest step's stick,
        // frame 1's through the missed frame 2 until frame 3's come; neutral from three periods
        // after frame 3 was taken (frames 4 and 5 missed), before frame 6's setpoints arrive; frame
        // 6's drive again.
        let neutral_from = PERIOD * 3 + deadline(PERIOD);
        assert_eq!(neutral_from, Duration::from_millis(1200));
        let want = |at: Duration| -> i16 {
            if at >= neutral_from && at < PERIOD * 6 + LATENCY {
                return 0;
            }
            let newest = (0..7)
                .filter(|k| !missed.contains(k) && PERIOD * *k + LATENCY <= at)
                .max()
                .expect("after frame 0");
            x(newest)
        };
        let driven: Vec<_> = sticks
            .iter()
            .filter(|(at, _)| *at >= LATENCY)
            .copied()
            .collect();
        assert!(driven.len() >= 20 * 7 / 5, "{driven:?}");
        for (at, got) in &driven {
            assert_eq!(
                *got,
                want(*at),
                "the stick {at:?} after frame 0 was taken: {driven:?}"
            );
        }
        assert!(
            driven.iter().any(|(at, x)| *at > PERIOD * 2 + LATENCY
                && *at < PERIOD * 3 + LATENCY
                && *x == 200)
        );
        assert_eq!(
            driven.iter().find(|(_, x)| *x == 0).map(|(at, _)| *at),
            Some(neutral_from),
            "the stop's MANUAL_CONTROL, at once"
        );
    }

    #[test]
    fn the_pilot_gain_is_divided_out_a_clip_is_told_once_and_a_new_gain_rescales() {
        let mut p = ardusub_47();
        p[4].1 = 0.5; // JS_GAIN_DEFAULT
        let mut ap = Autopilot::new(p);
        let (mut c, t, _) = opened(&mut ap, false, Options::default());
        assert_eq!(c.gain(), 0.5);
        let f = |surge| Forces {
            surge,
            sway: 0.0,
            yaw: 0.0,
        };
        assert_eq!(c.command(&f(0.25), &stamp(1)).unwrap().x, 500);
        assert!(c.take().events.is_empty());
        assert_eq!(c.command(&f(0.8), &stamp(2)).unwrap().x, 1000);
        let events = c.take().events;
        match &events[..] {
            [e @ Event::Clipped { .. }] => {
                let s = e.to_string();
                assert!(
                    s.contains("JS_GAIN_DEFAULT to 1.0") && s.contains("surge"),
                    "{s}"
                );
                assert_eq!(e.level(), Level::Warn);
            }
            other => panic!("{other:?}"),
        }
        c.command(&f(0.9), &stamp(3));
        assert!(c.take().events.is_empty(), "told once");
        // A ground station's gain buttons: ArduSub reports the new gain.
        c.on_frame(
            t,
            &ap.frame(MavMessage::NAMED_VALUE_FLOAT(NAMED_VALUE_FLOAT_DATA {
                value: 1.0,
                name: "PilotGain".into(),
                ..Default::default()
            })),
        );
        assert_eq!(c.take().events, vec![Event::Gain { from: 0.5, to: 1.0 }]);
        assert_eq!(c.command(&f(0.8), &stamp(4)).unwrap().x, 800);
    }

    #[test]
    fn manual_mode_scales_yaw_by_acro_yaw_p() {
        let mut p = ardusub_47();
        p[8].1 = 9.0; // ACRO_YAW_P: twice the default
        let mut ap = Autopilot::new(p);
        let (mut c, _, _) = opened(&mut ap, false, Options::default());
        let yaw = Forces {
            surge: 0.0,
            sway: 0.0,
            yaw: 0.5,
        };
        assert_eq!(c.command(&yaw, &stamp(1)).unwrap().r, 250);
        // In ALT_HOLD the yaw stick is a rate demand: no such scale.
        let mut ap = Autopilot::new(
            ardusub_47()
                .into_iter()
                .map(|(n, v)| (n, if n == YAW_P { 9.0 } else { v }))
                .collect(),
        );
        let options = Options {
            mode: Mode::AltHold,
            ..Options::default()
        };
        let (mut c, _, out) = opened(&mut ap, false, options);
        assert!(commands(&out).contains(&(MavCmd::MAV_CMD_DO_SET_MODE, 1.0, 2.0)));
        assert_eq!(c.command(&yaw, &stamp(1)).unwrap().r, 500);
    }

    #[test]
    fn a_disarm_by_the_autopilot_is_told_and_never_undone() {
        let mut ap = Autopilot::new(ardusub_47());
        let (mut c, mut t, _) = opened(&mut ap, false, Options::default());
        ap.armed = false;
        c.on_frame(
            t,
            &ap.frame(MavMessage::STATUSTEXT(STATUSTEXT_DATA {
                severity: MavSeverity::MAV_SEVERITY_CRITICAL,
                text: "Lost manual control".into(),
                ..Default::default()
            })),
        );
        c.on_frame(t, &ap.heartbeat());
        let out = c.take();
        let told: Vec<&Event> = out
            .events
            .iter()
            .filter(|e| matches!(e, Event::DisarmedByAutopilot { .. }))
            .collect();
        assert_eq!(told.len(), 1);
        let s = told[0].to_string();
        assert!(
            s.contains("pilot-input failsafe")
                && s.contains("Lost manual control")
                && s.contains("does not arm it again"),
            "{s}"
        );
        assert_eq!(
            out.state.last().map(|(_, s)| (s.heartbeat, s.armed)),
            Some((1, 0))
        );
        // Nothing re-arms it, however long it pilots on.
        let (out, r) = run(&mut c, &mut ap, &mut t, Duration::from_secs(10), |_| false);
        r.unwrap();
        assert_eq!(commands(&out), vec![]);
        assert!(!ap.armed);
    }

    #[test]
    fn a_lost_heartbeat_is_told_both_ways_and_a_disarm_meanwhile_is_reported() {
        let mut ap = Autopilot::new(ardusub_47());
        let (mut c, t, _) = opened(&mut ap, false, Options::default());
        c.take();
        let lost_at = t + Duration::from_secs(3);
        c.on_time(lost_at).unwrap();
        let out = c.take();
        assert!(
            matches!(out.events[..], [Event::Lost { .. }]),
            "{:?}",
            out.events
        );
        assert_eq!(out.state.last().map(|(_, s)| s.heartbeat), Some(0));
        assert_eq!(c.status(), None);
        // Sticks go on meanwhile (ArduSub may hear us even when we do not hear it).
        assert!(
            out.send
                .iter()
                .any(|m| matches!(m, MavMessage::MANUAL_CONTROL(_)))
        );
        ap.armed = false;
        c.on_frame(lost_at + Duration::from_secs(2), &ap.heartbeat());
        let events = c.take().events;
        assert!(matches!(events[0], Event::Back { .. }), "{events:?}");
        assert!(
            matches!(events[1], Event::DisarmedByAutopilot { .. }),
            "{events:?}"
        );
    }

    #[test]
    fn closing_goes_neutral_and_disarms_until_acknowledged() {
        let mut ap = Autopilot::new(ardusub_47());
        let (mut c, mut t, _) = opened(&mut ap, false, Options::default());
        c.command(
            &Forces {
                surge: 0.3,
                sway: 0.0,
                yaw: 0.0,
            },
            &stamp(9),
        );
        c.stop(&stamp(9), StopCause::Shutdown);
        c.take();
        // The first disarm is lost: sent again.
        ap.answer = false;
        c.close(t).unwrap();
        let out = c.take();
        assert_eq!(
            commands(&out),
            vec![(MavCmd::MAV_CMD_COMPONENT_ARM_DISARM, 0.0, 0.0)]
        );
        ap.answer = true;
        let (out, r) = run(&mut c, &mut ap, &mut t, Duration::from_secs(10), |c| {
            c.is_closed()
        });
        r.unwrap();
        assert_eq!(
            commands(&out),
            vec![(MavCmd::MAV_CMD_COMPONENT_ARM_DISARM, 0.0, 0.0)]
        );
        assert!(out.events.contains(&Event::Disarmed));
        assert!(!ap.armed);
        // Closed: nothing more goes out.
        c.on_time(t + Duration::from_secs(5)).unwrap();
        assert!(c.take().send.is_empty());
        // A disarmed autopilot is not disarmed again; one that never answers fails the close.
        let mut ap = Autopilot::new(ardusub_47());
        let (mut c, t, _) = opened(&mut ap, true, Options::default());
        c.close(t).unwrap();
        assert!(c.is_closed());
        assert!(c.take().events.contains(&Event::AlreadyDisarmed));
        let mut ap = Autopilot::new(ardusub_47());
        let (mut c, mut t, _) = opened(&mut ap, false, Options::default());
        ap.answer = false;
        c.close(t).unwrap();
        let (_, r) = run(&mut c, &mut ap, &mut t, Duration::from_secs(30), |c| {
            c.is_closed()
        });
        assert!(
            matches!(r, Err(Error::Command(Failure::NoAck { tries: 5, .. }))),
            "{r:?}"
        );
        assert!(c.is_closed());
    }
}
