//! One COMMAND_LONG to the autopilot, carried to its end: sent, sent again while unacknowledged,
//! its COMMAND_ACK judged, and its effect confirmed by the autopilot's heartbeat.
//!
//! What ArduSub answers (its GCS_MAVLink): ACCEPTED when done (arming, a mode change, a disarm);
//! FAILED when it would not (arming checks failed, with a "PreArm: ..." STATUSTEXT; a mode it cannot
//! enter, such as ALT_HOLD without a depth sensor); DENIED or UNSUPPORTED for a command it refuses or
//! lacks; TEMPORARILY_REJECTED when it is busy and the command may be tried again; IN_PROGRESS for a
//! long command still running. An accepted command counts once the heartbeat shows it (armed, the
//! mode), or at once for a disarm (its acknowledgement is what the close waits for).

use crate::autopilot::{Address, Status};
use crate::spec::{Mode, Timing};
use mavlink::dialects::ardupilotmega::{
    COMMAND_ACK_DATA, COMMAND_LONG_DATA, MavCmd, MavMessage, MavModeFlag, MavResult,
};
use std::time::{Duration, Instant};

/// What the command does.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Action {
    SetMode(Mode),
    Arm,
    Disarm,
}

impl Action {
    fn command(self) -> MavCmd {
        match self {
            Action::SetMode(_) => MavCmd::MAV_CMD_DO_SET_MODE,
            Action::Arm | Action::Disarm => MavCmd::MAV_CMD_COMPONENT_ARM_DISARM,
        }
    }

    fn params(self) -> (f32, f32) {
        match self {
            // param1: a custom mode follows; param2: ArduSub's mode number.
            Action::SetMode(m) => (
                MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED.bits() as f32,
                m.custom_mode() as f32,
            ),
            Action::Arm => (1.0, 0.0),
            Action::Disarm => (0.0, 0.0),
        }
    }

    /// Whether the autopilot's heartbeat shows the command's effect.
    fn shown_by(self, status: &Status) -> bool {
        match self {
            Action::SetMode(m) => status.mode == m.custom_mode(),
            Action::Arm => status.armed,
            Action::Disarm => !status.armed,
        }
    }
}

impl std::fmt::Display for Action {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Action::SetMode(m) => write!(f, "MAV_CMD_DO_SET_MODE ({})", m.name()),
            Action::Arm => f.write_str("MAV_CMD_COMPONENT_ARM_DISARM (arm)"),
            Action::Disarm => f.write_str("MAV_CMD_COMPONENT_ARM_DISARM (disarm)"),
        }
    }
}

/// Why a command did not do its job.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum Failure {
    #[error("ArduSub refused {action} ({result:?}){}", why(.text))]
    Refused {
        action: Action,
        result: MavResult,
        /// The autopilot's last STATUSTEXT, which usually says why.
        text: Option<String>,
    },
    #[error("no COMMAND_ACK for {action} after {tries} tries, {waited:?}{}", why(.text))]
    NoAck {
        action: Action,
        tries: u32,
        waited: Duration,
        text: Option<String>,
    },
    #[error("ArduSub accepted {action}, but its heartbeat did not show it within {waited:?}{}", why(.text))]
    NotShown {
        action: Action,
        waited: Duration,
        text: Option<String>,
    },
}

fn why(text: &Option<String>) -> String {
    match text {
        Some(t) => format!(": its last message: \"{t}\""),
        None => String::new(),
    }
}

/// Where a command stands.
#[derive(Clone, Debug, PartialEq)]
pub enum Progress {
    Pending,
    Done,
    Failed(Failure),
}

/// One command in flight.
pub struct Command {
    action: Action,
    target: Address,
    timing: Timing,
    /// Sends so far, and when the last one was made.
    tries: u32,
    sent: Option<Instant>,
    first_sent: Option<Instant>,
    /// When to send again (no answer yet, or the autopilot said to try again).
    resend_at: Option<Instant>,
    /// When the autopilot accepted it (or said it is in progress).
    accepted: Option<Instant>,
    outcome: Option<Progress>,
}

impl Command {
    pub fn new(action: Action, target: Address, timing: Timing) -> Self {
        Command {
            action,
            target,
            timing,
            tries: 0,
            sent: None,
            first_sent: None,
            resend_at: None,
            accepted: None,
            outcome: None,
        }
    }

    pub fn action(&self) -> Action {
        self.action
    }

    /// The COMMAND_LONG to send now, if one is due.
    pub fn due(&mut self, now: Instant) -> Option<MavMessage> {
        if self.outcome.is_some()
            || self.accepted.is_some()
            || self.tries >= self.timing.command_tries
        {
            return None;
        }
        if self.sent.is_some() && self.resend_at.is_some_and(|t| now < t) {
            return None;
        }
        let (param1, param2) = self.action.params();
        let msg = MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
            param1,
            param2,
            command: self.action.command(),
            target_system: self.target.system,
            target_component: self.target.component,
            // MAVLink: 0 for the first send, then counts the resends.
            confirmation: self.tries.min(255) as u8,
            ..Default::default()
        });
        self.tries += 1;
        self.sent = Some(now);
        self.first_sent.get_or_insert(now);
        self.resend_at = Some(now + self.timing.ack);
        Some(msg)
    }

    /// A COMMAND_ACK from the autopilot (for this driver: the caller checks its target).
    pub fn on_ack(&mut self, now: Instant, ack: &COMMAND_ACK_DATA, text: Option<&str>) {
        if ack.command != self.action.command() || self.outcome.is_some() {
            return;
        }
        match ack.result {
            MavResult::MAV_RESULT_ACCEPTED => {
                self.accepted.get_or_insert(now);
                // A disarm's acknowledgement is its confirmation.
                if self.action == Action::Disarm {
                    self.outcome = Some(Progress::Done);
                }
            }
            MavResult::MAV_RESULT_IN_PROGRESS => {
                self.accepted.get_or_insert(now);
            }
            MavResult::MAV_RESULT_TEMPORARILY_REJECTED => {
                // Try again after the usual wait, if tries are left.
                self.resend_at = Some(now + self.timing.ack);
            }
            result => {
                self.outcome = Some(Progress::Failed(Failure::Refused {
                    action: self.action,
                    result,
                    text: text.map(str::to_owned),
                }))
            }
        }
    }

    /// Time passed, the autopilot's state as its heartbeat shows it now (`None`: unknown).
    pub fn on_time(
        &mut self,
        now: Instant,
        status: Option<Status>,
        text: Option<&str>,
    ) -> Progress {
        if let Some(p) = &self.outcome {
            return p.clone();
        }
        // Shown by the heartbeat: done, even if the acknowledgement was lost.
        if self.sent.is_some() && status.is_some_and(|s| self.action.shown_by(&s)) {
            self.outcome = Some(Progress::Done);
            return Progress::Done;
        }
        let text = text.map(str::to_owned);
        let failure = match (self.accepted, self.sent) {
            (Some(at), _) if now >= at + self.timing.confirm => Some(Failure::NotShown {
                action: self.action,
                waited: self.timing.confirm,
                text,
            }),
            (None, Some(_))
                if self.tries >= self.timing.command_tries
                    && self.resend_at.is_some_and(|t| now >= t) =>
            {
                Some(Failure::NoAck {
                    action: self.action,
                    tries: self.tries,
                    waited: now.saturating_duration_since(self.first_sent.unwrap_or(now)),
                    text,
                })
            }
            _ => None,
        };
        match failure {
            Some(f) => {
                self.outcome = Some(Progress::Failed(f.clone()));
                Progress::Failed(f)
            }
            None => Progress::Pending,
        }
    }

    /// When the command needs time to pass next (a resend, or giving up).
    pub fn next_deadline(&self) -> Option<Instant> {
        if self.outcome.is_some() {
            return None;
        }
        match self.accepted {
            Some(at) => Some(at + self.timing.confirm),
            None => self.resend_at,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const AP: Address = Address {
        system: 1,
        component: 1,
    };

    fn timing() -> Timing {
        Timing {
            ack: Duration::from_millis(100),
            command_tries: 3,
            confirm: Duration::from_millis(500),
            ..Timing::default()
        }
    }

    fn ack(command: MavCmd, result: MavResult) -> COMMAND_ACK_DATA {
        COMMAND_ACK_DATA {
            command,
            result,
            ..Default::default()
        }
    }

    fn status(armed: bool, mode: u32) -> Status {
        Status {
            armed,
            mode,
            system_status: 3,
        }
    }

    const MS: Duration = Duration::from_millis(1);
    const ARM: MavCmd = MavCmd::MAV_CMD_COMPONENT_ARM_DISARM;

    #[test]
    fn an_arm_is_resent_until_acknowledged_then_confirmed_by_the_heartbeat() {
        let t0 = Instant::now();
        let mut c = Command::new(Action::Arm, AP, timing());
        match c.due(t0) {
            Some(MavMessage::COMMAND_LONG(m)) => {
                assert_eq!(m.command, ARM);
                assert_eq!((m.param1, m.target_system, m.target_component), (1.0, 1, 1));
                assert_eq!(m.confirmation, 0);
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(c.due(t0 + 50 * MS), None, "not before the ack time");
        match c.due(t0 + 100 * MS) {
            Some(MavMessage::COMMAND_LONG(m)) => assert_eq!(m.confirmation, 1, "a resend"),
            other => panic!("{other:?}"),
        }
        c.on_ack(
            t0 + 120 * MS,
            &ack(ARM, MavResult::MAV_RESULT_ACCEPTED),
            None,
        );
        assert_eq!(c.due(t0 + 300 * MS), None, "accepted: no more sends");
        assert_eq!(
            c.on_time(t0 + 300 * MS, Some(status(false, 19)), None),
            Progress::Pending,
            "the heartbeat does not show it yet"
        );
        assert_eq!(
            c.on_time(t0 + 400 * MS, Some(status(true, 19)), None),
            Progress::Done
        );
    }

    #[test]
    fn a_refusal_fails_at_once_with_the_autopilots_reason() {
        let t0 = Instant::now();
        let mut c = Command::new(Action::Arm, AP, timing());
        c.due(t0);
        c.on_ack(
            t0 + MS,
            &ack(ARM, MavResult::MAV_RESULT_FAILED),
            Some("PreArm: Leak Detected"),
        );
        match c.on_time(t0 + 2 * MS, Some(status(false, 19)), None) {
            Progress::Failed(f @ Failure::Refused { .. }) => {
                let s = f.to_string();
                assert!(
                    s.contains("MAV_RESULT_FAILED") && s.contains("PreArm: Leak Detected"),
                    "{s}"
                );
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn temporarily_rejected_is_tried_again_and_silence_gives_up_after_the_last_try() {
        let t0 = Instant::now();
        let mode = Action::SetMode(Mode::AltHold);
        let mut c = Command::new(mode, AP, timing());
        match c.due(t0) {
            Some(MavMessage::COMMAND_LONG(m)) => {
                assert_eq!(m.command, MavCmd::MAV_CMD_DO_SET_MODE);
                assert_eq!((m.param1, m.param2), (1.0, 2.0));
            }
            other => panic!("{other:?}"),
        }
        c.on_ack(
            t0 + 10 * MS,
            &ack(
                MavCmd::MAV_CMD_DO_SET_MODE,
                MavResult::MAV_RESULT_TEMPORARILY_REJECTED,
            ),
            None,
        );
        assert_eq!(c.due(t0 + 50 * MS), None);
        assert!(c.due(t0 + 110 * MS).is_some(), "tried again");
        assert!(c.due(t0 + 210 * MS).is_some(), "and again");
        assert_eq!(c.due(t0 + 310 * MS), None, "three tries");
        assert_eq!(
            c.on_time(t0 + 309 * MS, Some(status(false, 19)), None),
            Progress::Pending
        );
        match c.on_time(t0 + 310 * MS, Some(status(false, 19)), None) {
            Progress::Failed(Failure::NoAck { tries: 3, .. }) => {}
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn a_lost_acknowledgement_is_forgiven_when_the_heartbeat_shows_the_effect() {
        let t0 = Instant::now();
        let mut c = Command::new(Action::SetMode(Mode::Manual), AP, timing());
        c.due(t0);
        assert_eq!(
            c.on_time(t0 + 30 * MS, Some(status(false, 19)), None),
            Progress::Done
        );
    }

    #[test]
    fn an_accepted_command_the_heartbeat_never_shows_fails() {
        let t0 = Instant::now();
        let mut c = Command::new(Action::Arm, AP, timing());
        c.due(t0);
        c.on_ack(t0 + MS, &ack(ARM, MavResult::MAV_RESULT_ACCEPTED), None);
        assert_eq!(c.next_deadline(), Some(t0 + 501 * MS));
        match c.on_time(
            t0 + 501 * MS,
            Some(status(false, 19)),
            Some("Arm: Throttle too high"),
        ) {
            Progress::Failed(f @ Failure::NotShown { .. }) => {
                assert!(f.to_string().contains("Throttle too high"))
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn a_disarm_is_done_when_acknowledged() {
        let t0 = Instant::now();
        let mut c = Command::new(Action::Disarm, AP, timing());
        match c.due(t0) {
            Some(MavMessage::COMMAND_LONG(m)) => assert_eq!((m.command, m.param1), (ARM, 0.0)),
            other => panic!("{other:?}"),
        }
        // Another command's acknowledgement is not this one's.
        c.on_ack(
            t0 + MS,
            &ack(MavCmd::MAV_CMD_DO_SET_MODE, MavResult::MAV_RESULT_ACCEPTED),
            None,
        );
        assert_eq!(c.on_time(t0 + 2 * MS, None, None), Progress::Pending);
        c.on_ack(t0 + 3 * MS, &ack(ARM, MavResult::MAV_RESULT_ACCEPTED), None);
        assert_eq!(c.on_time(t0 + 4 * MS, None, None), Progress::Done);
    }
}
