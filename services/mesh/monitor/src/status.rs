//! The status view's core: what an operator reads of a running mesh, per service (node state, age of
//! the last heartbeat, restarts), per topic (rate and last stamp) and per learner (gains, returns).
//! Plain records filled by the `status` binary and printed as a table or JSON.

use messages::{AutopilotDepth, AutopilotState, LearningStats, ServoOutputs, Stamp, StatusText};
use serde::Serialize;
use std::fmt::Write;

/// A service's node as `Node::list` reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum NodeState {
    Alive,
    /// Gone without cleaning up (killed): its resources wait for removal.
    Dead,
    /// No node of that name here: not started, or on another host (seen through the shore link).
    Absent,
}

/// One service's health.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ServiceStatus {
    pub name: String,
    pub node: NodeState,
    /// Seconds since its last heartbeat, if one came within the observation.
    pub heartbeat_age_s: Option<f64>,
    /// The restart count its heartbeat carries.
    pub restarts: Option<usize>,
}

/// One topic's traffic over the observation.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TopicStatus {
    pub topic: String,
    pub messages: u64,
    pub rate_hz: f64,
    pub last_seq: Option<u64>,
    pub last_episode: Option<u32>,
    pub last_step: Option<u32>,
}

impl TopicStatus {
    /// `messages` received in `window_s`, the last one's stamp.
    pub fn new(topic: &str, messages: u64, window_s: f64, last: Option<&Stamp>) -> Self {
        TopicStatus {
            topic: topic.to_owned(),
            messages,
            rate_hz: if window_s > 0.0 {
                messages as f64 / window_s
            } else {
                0.0
            },
            last_seq: last.map(|s| s.seq),
            last_episode: last.map(|s| s.episode),
            last_step: last.map(|s| s.step),
        }
    }
}

/// A learner's latest report.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct LearnerStatus {
    pub dof: String,
    pub episode: u32,
    pub gain: [f64; 2],
    pub episode_return: f64,
    pub actor_updates: u64,
    pub learning: bool,
}

impl LearnerStatus {
    pub fn new(dof: config::Dof, s: &LearningStats) -> Self {
        LearnerStatus {
            dof: dof.to_string(),
            episode: s.stamp.episode,
            gain: s.gain,
            episode_return: s.episode_return,
            actor_updates: s.actor_updates,
            learning: s.learning != 0,
        }
    }
}

/// The autopilot a thruster driver pilots over MAVLink (a vehicle under ArduSub), from its
/// telemetry topics (`cabletrack/vehicle/autopilot/*`): the latest of each.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct AutopilotStatus {
    /// Its state reports received over the observation (one per autopilot heartbeat, 1 Hz).
    pub reports: u64,
    pub heartbeat: bool,
    pub armed: bool,
    /// ArduSub's mode name (or its number).
    pub mode: String,
    pub battery_v: Option<f64>,
    pub frames_refused: u64,
    pub pilot_gain: Option<f64>,
    pub depth_m: Option<f64>,
    pub heading_deg: Option<f64>,
    /// The first six outputs' pulses (us): the BlueROV2's thrusters.
    pub pwm_us: Option<Vec<u16>>,
    /// The autopilot's last text and its severity.
    pub last_text: Option<(u8, String)>,
}

fn finite(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}

impl AutopilotStatus {
    /// From the latest message of each topic; `None` when the autopilot said nothing.
    pub fn new(
        reports: u64,
        state: Option<&AutopilotState>,
        depth: Option<&AutopilotDepth>,
        servos: Option<&ServoOutputs>,
        text: Option<&StatusText>,
    ) -> Option<Self> {
        if state.is_none() && depth.is_none() && servos.is_none() && text.is_none() {
            return None;
        }
        let mut s = AutopilotStatus {
            reports,
            ..Default::default()
        };
        if let Some(a) = state {
            s.heartbeat = a.heartbeat == 1;
            s.armed = a.armed == 1;
            s.mode = if s.heartbeat {
                messages::ardusub_mode_name(a.mode)
            } else {
                "unknown".into()
            };
            s.battery_v = finite(a.battery_v);
            s.frames_refused = a.frames_refused;
            s.pilot_gain = finite(a.pilot_gain);
        }
        if let Some(d) = depth {
            s.depth_m = finite(d.depth_m);
            s.heading_deg = finite(d.heading_deg);
        }
        s.pwm_us = servos.map(|o| o.pwm_us[..usize::from(o.count).min(6)].to_vec());
        s.last_text = text.map(|t| (t.severity, t.text()));
        Some(s)
    }
}

/// The whole view.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Status {
    pub endpoint: String,
    pub window_s: f64,
    pub services: Vec<ServiceStatus>,
    pub topics: Vec<TopicStatus>,
    pub learners: Vec<LearnerStatus>,
    /// The autopilot, where a driver pilots one over MAVLink.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub autopilot: Option<AutopilotStatus>,
}

fn opt<T: std::fmt::Display>(v: Option<T>) -> String {
    v.map_or_else(|| "-".to_owned(), |v| v.to_string())
}

impl Status {
    /// The table an operator reads.
    pub fn table(&self) -> String {
        let mut out = String::new();
        let _ = writeln!(
            out,
            "{} mesh, observed for {:.1} s",
            self.endpoint, self.window_s
        );
        let _ = writeln!(out, "service             | node   | heartbeat | restarts");
        for s in &self.services {
            let node = match s.node {
                NodeState::Alive => "alive",
                NodeState::Dead => "dead",
                NodeState::Absent => "-",
            };
            let age = s
                .heartbeat_age_s
                .map_or_else(|| "none".to_owned(), |a| format!("{:.2} s", a));
            let _ = writeln!(
                out,
                "{:19} | {:6} | {:>9} | {}",
                s.name,
                node,
                age,
                opt(s.restarts)
            );
        }
        let _ = writeln!(
            out,
            "topic               |   rate Hz | last seq | episode | step"
        );
        for t in &self.topics {
            let _ = writeln!(
                out,
                "{:19} | {:9.2} | {:>8} | {:>7} | {:>4}",
                t.topic,
                t.rate_hz,
                opt(t.last_seq),
                opt(t.last_episode),
                opt(t.last_step)
            );
        }
        let _ = writeln!(
            out,
            "learner | episode | K                  | return     | updates"
        );
        for l in &self.learners {
            let _ = writeln!(
                out,
                "{:7} | {:7} | [{:7.3}, {:7.3}] | {:10.3} | {}{}",
                l.dof,
                l.episode,
                l.gain[0],
                l.gain[1],
                l.episode_return,
                l.actor_updates,
                if l.learning { "" } else { " (acting only)" }
            );
        }
        if let Some(a) = &self.autopilot {
            let f = |v: Option<f64>, unit: &str| {
                v.map_or_else(|| "-".into(), |v| format!("{v:.2}{unit}"))
            };
            let _ = writeln!(
                out,
                "autopilot | heartbeat {} | {} | {} | battery {} | gain {} | depth {} | heading {} | {} frames refused | {} reports",
                if a.heartbeat { "yes" } else { "LOST" },
                if a.armed { "armed" } else { "disarmed" },
                a.mode,
                f(a.battery_v, " V"),
                f(a.pilot_gain, ""),
                f(a.depth_m, " m"),
                f(a.heading_deg, " deg"),
                a.frames_refused,
                a.reports
            );
            if let Some(p) = &a.pwm_us {
                let _ = writeln!(out, "autopilot outputs (us) | {p:?}");
            }
            if let Some((severity, text)) = &a.last_text {
                let _ = writeln!(out, "autopilot said (severity {severity}) | {text}");
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rates_and_stamps_come_from_what_was_received() {
        let stamp = Stamp::new(42, 0, 3, 7, config::StepStatus::Running);
        let t = TopicStatus::new("cable_observation", 10, 2.0, Some(&stamp));
        assert_eq!(t.rate_hz, 5.0);
        assert_eq!(
            (t.last_seq, t.last_episode, t.last_step),
            (Some(42), Some(3), Some(7))
        );
        let silent = TopicStatus::new("vehicle_state", 0, 2.0, None);
        assert_eq!((silent.rate_hz, silent.last_seq), (0.0, None));
    }

    #[test]
    fn the_table_shows_every_service_topic_and_learner() {
        let stats = LearningStats {
            episode_return: -1.5,
            gain: [0.25, -0.5],
            learning: 1,
            ..Default::default()
        };
        let status = Status {
            endpoint: "vehicle".into(),
            window_s: 2.0,
            services: vec![
                ServiceStatus {
                    name: "perception".into(),
                    node: NodeState::Alive,
                    heartbeat_age_s: Some(0.02),
                    restarts: Some(1),
                },
                ServiceStatus {
                    name: "camera".into(),
                    node: NodeState::Dead,
                    heartbeat_age_s: None,
                    restarts: None,
                },
            ],
            topics: vec![TopicStatus::new("camera_frame", 10, 2.0, None)],
            learners: vec![LearnerStatus::new(config::Dof::Yaw, &stats)],
            autopilot: AutopilotStatus::new(
                3,
                Some(&AutopilotState {
                    heartbeat: 1,
                    armed: 1,
                    mode: 19,
                    battery_v: 15.6,
                    pilot_gain: f64::NAN,
                    ..Default::default()
                }),
                None,
                Some(&ServoOutputs {
                    count: 8,
                    pwm_us: [
                        1580, 1420, 1500, 1500, 1500, 1500, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,
                    ],
                    ..Default::default()
                }),
                Some(&StatusText::new(2, "Lost manual control")),
            ),
        };
        let table = status.table();
        for want in [
            "perception",
            "alive",
            "0.02 s",
            "camera",
            "dead",
            "none",
            "camera_frame",
            "5.00",
            "0.250",
            "-1.500",
            "armed | MANUAL | battery 15.60 V | gain -",
            "[1580, 1420, 1500, 1500, 1500, 1500]",
            "Lost manual control",
        ] {
            assert!(table.contains(want), "`{want}` missing from\n{table}");
        }
        let json = serde_json::to_value(&status).unwrap();
        assert_eq!(json["services"][1]["node"], "dead");
        assert_eq!(json["autopilot"]["mode"], "MANUAL");
        assert_eq!(AutopilotStatus::new(0, None, None, None, None), None);
        let lost = AutopilotStatus::new(1, Some(&AutopilotState::default()), None, None, None);
        assert_eq!(lost.unwrap().mode, "unknown");
    }
}
