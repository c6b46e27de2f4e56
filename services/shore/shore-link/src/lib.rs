//! The shore link's core: which services cross (an allow-list generated from the messages topic
//! table), the zenoh settings (explicit endpoints, no scouting, mutual TLS: [`security`]), what the
//! shore shows of the telemetry (never a stale step as new: [`Shown`]), the bad network of the demo
//! ([`impair`]), and the demo's report computed from what each side recorded. Plain data; `main.rs`
//! runs the link over iceoryx2's zenoh tunnel.

pub mod impair;
pub mod security;

use messages::topics::{self, Endpoint, health, shore};
use messages::{Qos, Stamp};
use runtime::screen::{Screen, ScreenLimits, Verdict};
use security::Security;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::time::Duration;

/// The services that cross the link: telemetry up from the vehicle, commands down from the shore.
/// The tunnel's filter is one predicate for both directions, so the two directions are kept apart
/// by name: telemetry lives in `cabletrack/vehicle/...`, commands in `cabletrack/shore/...`.
#[derive(Clone, Debug, PartialEq)]
pub struct AllowList {
    /// Vehicle to shore: exact service names, with the topic's QoS.
    pub up: Vec<(String, Qos)>,
    /// The heartbeats, `cabletrack/<endpoint>/heartbeat/` and a process name.
    pub heartbeats: String,
    /// Shore to vehicle: exact service names, with the topic's QoS.
    pub down: Vec<(String, Qos)>,
}

impl AllowList {
    /// The telemetry of `endpoint` (state, observations, learning reports, the autopilot's telemetry
    /// where a driver pilots one over MAVLink, heartbeats), the camera
    /// frames only when `frames`, and the shore's mission commands. Never the per-DOF commands, the
    /// thruster setpoints or the hardware topics: the vehicle's control loop stays on the vehicle. A
    /// bridged service gets a publisher of the link on this host, so a bridged actuator topic could be
    /// driven from the other host (and the setpoints take one publisher only: the allocator's).
    pub fn new(endpoint: Endpoint, frames: bool) -> AllowList {
        let mut up = vec![
            (
                topics::VEHICLE_STATE.service_name(endpoint),
                topics::VEHICLE_STATE.qos,
            ),
            (
                topics::CABLE_OBSERVATION.service_name(endpoint),
                topics::CABLE_OBSERVATION.qos,
            ),
            (
                topics::SWAY_LEARNING.service_name(endpoint),
                topics::SWAY_LEARNING.qos,
            ),
            (
                topics::YAW_LEARNING.service_name(endpoint),
                topics::YAW_LEARNING.qos,
            ),
            (
                topics::AUTOPILOT_STATE.service_name(endpoint),
                topics::AUTOPILOT_STATE.qos,
            ),
            (
                topics::AUTOPILOT_ATTITUDE.service_name(endpoint),
                topics::AUTOPILOT_ATTITUDE.qos,
            ),
            (
                topics::AUTOPILOT_DEPTH.service_name(endpoint),
                topics::AUTOPILOT_DEPTH.qos,
            ),
            (
                topics::AUTOPILOT_SERVO_OUTPUTS.service_name(endpoint),
                topics::AUTOPILOT_SERVO_OUTPUTS.qos,
            ),
            (
                topics::AUTOPILOT_STATUS_TEXT.service_name(endpoint),
                topics::AUTOPILOT_STATUS_TEXT.qos,
            ),
        ];
        if frames {
            up.push((
                topics::CAMERA_FRAME.service_name(endpoint),
                topics::CAMERA_FRAME.qos,
            ));
        }
        AllowList {
            up,
            heartbeats: health::service_name(endpoint, ""),
            down: vec![(shore::service_name(&shore::MISSION), shore::MISSION.qos)],
        }
    }

    /// Whether the service `name` may cross.
    pub fn admits(&self, name: &str) -> bool {
        self.up.iter().chain(&self.down).any(|(s, _)| s == name)
            || name
                .strip_prefix(&self.heartbeats)
                .is_some_and(|rest| !rest.is_empty() && !rest.contains('/'))
    }
}

/// Which end of the link this process is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Side {
    /// Listens on its endpoint; the vehicle never depends on the shore being there.
    Vehicle,
    /// Connects to the vehicle's endpoint, retrying while it is unreachable.
    Shore,
}

/// The zenoh settings, as (key, JSON5 value): peer mode (client mode would give up when the
/// vehicle is unreachable at start), one explicit endpoint, no multicast or gossip scouting (zenoh's
/// defaults would join any peer on the network and bridge with it), and `security`'s protocol and
/// checks ([`security::tls_settings`]).
pub fn zenoh_settings(
    side: Side,
    endpoint: &str,
    security: &Security,
) -> Vec<(&'static str, String)> {
    let one = format!("[{}]", serde_json::Value::from(endpoint));
    let (listen, connect) = match side {
        Side::Vehicle => (one, "[]".to_owned()),
        Side::Shore => ("[]".to_owned(), one),
    };
    let mut settings = vec![
        ("mode", "\"peer\"".to_owned()),
        ("listen/endpoints", listen),
        ("connect/endpoints", connect),
        ("scouting/multicast/enabled", "false".to_owned()),
        ("scouting/gossip/enabled", "false".to_owned()),
    ];
    settings.extend(security::tls_settings(side == Side::Vehicle, security));
    settings
}

/// How the shore judges the telemetry's stamps: the mesh's one rule ([`Screen`]) on order (a step
/// not newer than the newest shown of its epoch is refused; a returning older epoch is judged
/// against its own last step), with limits for a link rather than a control loop. Age is not
/// judged: over a slow link a late step that is still the newest is shown, with its latency; only
/// an hour's stall would make it "too old". `seq` may advance as fast as a producer at 100 Hz (the
/// demo runs the vehicle faster than real time), so a forged huge `seq` cannot lock out the live
/// steps.
pub const SHORE_MAX_AGE: Duration = Duration::from_secs(3600);

pub fn shore_limits() -> ScreenLimits {
    ScreenLimits {
        max_age: SHORE_MAX_AGE,
        max_ahead: SHORE_MAX_AGE,
        period: Duration::from_millis(10),
    }
}

/// What the shore shows of one stamped topic: a step the screen finds new is shown; a repeat, an
/// older step or one flagged by the screen is refused and counted, never shown as new.
#[derive(Clone, Debug)]
pub struct Shown {
    screen: Screen,
    pub shown: u64,
    pub refused: u64,
}

impl Shown {
    pub fn new(topic: &str) -> Self {
        Shown {
            screen: Screen::new(topic, shore_limits()),
            shown: 0,
            refused: 0,
        }
    }

    /// Whether the step stamped `stamp`, arriving at `now_ns` (this host's monotonic clock), is
    /// shown.
    pub fn judge(&mut self, stamp: &Stamp, now_ns: u64) -> bool {
        // The vehicle clock is signed; a monotonic reading fits it for centuries.
        let now_ns = now_ns as i64;
        match self.screen.check(stamp, now_ns) {
            Verdict::New => {
                self.screen.accept(stamp, now_ns);
                self.shown += 1;
                true
            }
            Verdict::Repeat | Verdict::Refused(_) => {
                self.refused += 1;
                false
            }
        }
    }
}

/// One arrival on the shore as the operator recorded it: its step and whether it was shown.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Judged {
    pub epoch: u32,
    pub seq: u64,
    pub shown: bool,
}

/// The shore's order, recomputed from the operator's record independently of [`Shown`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Order {
    /// Arrivals not newer than the newest step of their epoch shown before them.
    pub stale_arrivals: u64,
    /// Of those, shown anyway: stale data shown as new (must be 0).
    pub stale_shown: u64,
    /// Arrivals refused (stale, or flagged by the screen's other rules).
    pub refused: u64,
}

pub fn order(arrivals: &[Judged]) -> Order {
    let mut newest: BTreeMap<u32, u64> = BTreeMap::new();
    let mut o = Order::default();
    for a in arrivals {
        let stale = newest.get(&a.epoch).is_some_and(|&n| a.seq <= n);
        o.stale_arrivals += u64::from(stale);
        o.stale_shown += u64::from(stale && a.shown);
        o.refused += u64::from(!a.shown);
        if a.shown {
            let n = newest.entry(a.epoch).or_insert(a.seq);
            *n = (*n).max(a.seq);
        }
    }
    o
}

/// One telemetry sample as a side saw it arrive: its step's sequence number and the arrival on the
/// machine's monotonic clock (ns; both namespaces of the demo share one kernel, so one clock).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Arrival {
    pub seq: u64,
    pub at_ns: u64,
}

/// The demo's result.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Report {
    /// `tls` or `insecure`.
    pub security: String,
    /// The network's impairment (netem's arguments), if any.
    pub netem: Option<String>,
    /// Cable observations published on the vehicle while the shore was watching.
    pub sent: usize,
    /// Of those, shown on shore.
    pub received_on_shore: usize,
    pub received_share: f64,
    /// Added by the link: arrival on shore minus arrival on the vehicle, same step.
    pub latency_ms: Latency,
    /// The order of what the shore received and showed.
    pub order: Order,
    /// Steps the vehicle missed while the shore watched (see [`steps_missed`]).
    pub vehicle_steps_missed: u64,
    /// From the link's return to the first telemetry on shore (none: no cut, or never back).
    pub shore_back_after_s: Option<f64>,
    /// Messages or services outside the allow-list seen on the shore.
    pub outside_allow_list_seen: u64,
    /// The operator's stops that reached the vehicle's mission topic.
    pub stops_reached_vehicle: u64,
    pub stop_obeyed: bool,
    /// Operators under a shore end without a valid certificate.
    pub rogues: Vec<Rogue>,
    /// Whether a process on the vehicle was refused a publisher on the mission topic (if tried).
    pub local_forger_refused: Option<bool>,
    /// Per topic received on shore: messages and payload bytes per second of the watch.
    pub topics: BTreeMap<String, TopicRate>,
    /// Everything the vehicle's network interface sent per second of the watch (payloads, zenoh's
    /// framing and keep-alives, TCP/IP headers).
    pub link_bytes_per_s: Option<f64>,
}

/// What an operator behind a rogue shore end got, and what its stops did.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Rogue {
    /// Observations received.
    pub received: u64,
    pub stops_sent: u64,
    /// Of its stops, those that reached the vehicle's mission topic (matched by the sender's
    /// clock stamp).
    pub stops_reached_vehicle: u64,
}

/// What the operator received of one topic.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TopicTraffic {
    pub messages: u64,
    pub bytes: u64,
}

impl TopicTraffic {
    pub fn add(&mut self, bytes: usize) {
        self.messages += 1;
        self.bytes += bytes as u64;
    }
}

/// One topic's rate on shore.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct TopicRate {
    pub per_s: f64,
    pub bytes_per_s: f64,
}

/// The per-topic rates from the operator's summary (`topics`, `watched_s`).
pub fn rates(summary: &serde_json::Value) -> BTreeMap<String, TopicRate> {
    let watched = summary["watched_s"].as_f64().filter(|s| *s > 0.0);
    let topics: BTreeMap<String, TopicTraffic> =
        serde_json::from_value(summary["topics"].clone()).unwrap_or_default();
    match watched {
        Some(s) => topics
            .into_iter()
            .map(|(name, t)| {
                let rate = TopicRate {
                    per_s: t.messages as f64 / s,
                    bytes_per_s: t.bytes as f64 / s,
                };
                (name, rate)
            })
            .collect(),
        None => BTreeMap::new(),
    }
}

/// What the link adds to a step's way from the vehicle to the shore, in ms; `None` when no step
/// arrived on shore (the report then reads back as it was written: JSON has no NaN).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Latency {
    pub p50: Option<f64>,
    pub p99: Option<f64>,
}

/// Joins the two sides' arrivals: `sent` counts the vehicle's arrivals within the shore's
/// observation (from the shore's first to its last arrival's step), the latency is per matched step.
pub fn link_figures(vehicle: &[Arrival], shore: &[Arrival]) -> (usize, usize, Latency) {
    let (Some(first), Some(last)) = (
        shore.iter().map(|a| a.seq).min(),
        shore.iter().map(|a| a.seq).max(),
    ) else {
        return (
            vehicle.len(),
            0,
            Latency {
                p50: None,
                p99: None,
            },
        );
    };
    let sent = vehicle
        .iter()
        .filter(|a| (first..=last).contains(&a.seq))
        .count();
    let by_seq: std::collections::HashMap<u64, u64> =
        vehicle.iter().map(|a| (a.seq, a.at_ns)).collect();
    let added: Vec<f64> = shore
        .iter()
        .filter_map(|a| {
            by_seq
                .get(&a.seq)
                .map(|&v| (a.at_ns as f64 - v as f64) / 1e6)
        })
        .collect();
    let at = |q| (!added.is_empty()).then(|| stats::percentile(added.iter().copied(), q));
    let latency = Latency {
        p50: at(0.5),
        p99: at(0.99),
    };
    (sent, shore.len(), latency)
}

/// Seconds from `link_up_ns` to the first shore arrival at or after it.
pub fn back_after(shore: &[Arrival], link_up_ns: u64) -> Option<f64> {
    shore
        .iter()
        .map(|a| a.at_ns)
        .filter(|&t| t >= link_up_ns)
        .min()
        .map(|t| (t - link_up_ns) as f64 / 1e9)
}

/// Steps the vehicle missed while the shore watched (from the first to the last observation the shore
/// received) and its loop ran (from its first complete step on): frames that reached the vehicle but
/// were answered by no setpoints, and setpoints that lacked a command. `frames` are the frames' step
/// numbers; `steps` the vehicle's setpoints, as (seq, commands missing). A frame lost before the
/// vehicle (the twin drops some, as a real link does) is no step of the vehicle's. The mesh's
/// start-up (its first frames answered before every behaviour has joined, or not at all) and its
/// stop are outside the window: the link may already be up at start-up, but the loop is not.
pub fn steps_missed(frames: &[u64], steps: &[(u64, u64)], shore: &[Arrival]) -> u64 {
    let (Some(first), Some(last)) = (
        shore.iter().map(|a| a.seq).min(),
        shore.iter().map(|a| a.seq).max(),
    ) else {
        return 0;
    };
    let Some(running) = steps
        .iter()
        .filter(|&&(_, missing)| missing == 0)
        .map(|&(seq, _)| seq)
        .min()
    else {
        // The loop never answered a step completely while the shore watched: all of it missed.
        return frames
            .iter()
            .filter(|seq| (first..=last).contains(*seq))
            .count() as u64;
    };
    let window = first.max(running)..=last;
    let answered: std::collections::BTreeSet<u64> = steps.iter().map(|&(seq, _)| seq).collect();
    let unanswered = frames
        .iter()
        .filter(|seq| window.contains(seq) && !answered.contains(seq))
        .count() as u64;
    let incomplete = steps
        .iter()
        .filter(|(seq, missing)| window.contains(seq) && *missing != 0)
        .count() as u64;
    unanswered + incomplete
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_the_listed_telemetry_and_the_shore_commands_cross() {
        let allow = AllowList::new(Endpoint::Vehicle, false);
        for name in [
            "cabletrack/vehicle/cable_observation",
            "cabletrack/vehicle/learning/yaw",
            "cabletrack/vehicle/autopilot/state",
            "cabletrack/vehicle/autopilot/attitude",
            "cabletrack/vehicle/autopilot/depth",
            "cabletrack/vehicle/autopilot/servo_outputs",
            "cabletrack/vehicle/autopilot/status_text",
            "cabletrack/vehicle/heartbeat/perception",
            "cabletrack/shore/mission",
        ] {
            assert!(allow.admits(name), "{name}");
        }
        for name in [
            "cabletrack/vehicle/command/yaw",
            "cabletrack/vehicle/thruster_setpoints",
            "cabletrack/vehicle/camera_frame",
            "cabletrack/twin/thrusters",
            "cabletrack/sim/cable_observation",
            "cabletrack/vehicle/heartbeat/",
            "cabletrack/vehicle/heartbeat/a/b",
            "cabletrack/vehicle/cable_observation/x",
            "cabletrack/vehicle/autopilot/",
            "cabletrack/vehicle/autopilot/state/x",
        ] {
            assert!(!allow.admits(name), "{name}");
        }
        assert!(AllowList::new(Endpoint::Vehicle, true).admits("cabletrack/vehicle/camera_frame"));
    }

    #[test]
    fn steps_are_missed_only_inside_the_shores_watch() {
        let shore = [10, 11, 15].map(|seq| Arrival { seq, at_ns: 0 });
        // Frame 13 never reached the vehicle; frame 4, before the watch, was not answered either.
        let frames = [1, 4, 5, 10, 11, 12, 14, 15, 20];
        let steps = [(1, 2), (5, 0), (10, 0), (11, 1), (14, 0), (15, 0), (20, 3)];
        // Inside the watch, step 11 lacked a command and frame 12 was not answered.
        assert_eq!(steps_missed(&frames, &steps, &shore), 2);
        assert_eq!(steps_missed(&frames, &steps, &[]), 0);
        // The same steps with no frame lost or unanswered: only step 11 is missed.
        assert_eq!(steps_missed(&[10, 11, 14, 15], &steps, &shore), 1);
        // The shore watched from the mesh's start: steps 1 and 2 before its loop ran (2 unanswered,
        // 1 incomplete) are start-up, not misses; 4 unanswered and 5 incomplete after it are.
        let from_start = [1, 5].map(|seq| Arrival { seq, at_ns: 0 });
        let start_steps = [(1, 2), (3, 0), (5, 1)];
        assert_eq!(steps_missed(&[1, 2, 3, 4, 5], &start_steps, &from_start), 2);
        // A loop that never answered completely missed every frame of the watch.
        assert_eq!(steps_missed(&[1, 2, 3], &[(1, 1)], &from_start), 3);
    }

    #[test]
    fn the_vehicle_listens_the_shore_connects_and_nobody_scouts() {
        let v = zenoh_settings(Side::Vehicle, "tcp/10.0.0.1:7447", &Security::Insecure);
        let s = zenoh_settings(Side::Shore, "tcp/10.0.0.1:7447", &Security::Insecure);
        let get =
            |c: &[(&str, String)], k: &str| c.iter().find(|(key, _)| *key == k).unwrap().1.clone();
        assert_eq!(get(&v, "listen/endpoints"), r#"["tcp/10.0.0.1:7447"]"#);
        assert_eq!(get(&v, "connect/endpoints"), "[]");
        assert_eq!(get(&s, "connect/endpoints"), r#"["tcp/10.0.0.1:7447"]"#);
        for c in [&v, &s] {
            assert_eq!(get(c, "scouting/multicast/enabled"), "false");
            assert_eq!(get(c, "scouting/gossip/enabled"), "false");
            assert_eq!(get(c, "transport/link/protocols"), r#"["tcp"]"#);
        }
        let files = security::KeyFiles::in_dir(std::path::Path::new("/k/vehicle"));
        let tls = zenoh_settings(Side::Vehicle, "tls/10.0.0.1:7447", &Security::Tls(files));
        assert_eq!(get(&tls, "transport/link/protocols"), r#"["tls"]"#);
        assert_eq!(
            get(&tls, "transport/link/tls/listen_certificate"),
            r#""/k/vehicle/cert.pem""#
        );
    }

    /// A timed stamp; the vehicle's clock starts at 1 s (a clock of 0 means untimed).
    fn stamp(epoch: u32, seq: u64, clock_ms: u64) -> Stamp {
        let clock_ns = (1000 + clock_ms) * 1_000_000;
        Stamp::new(seq, clock_ns, 0, 0, messages::StepStatus::Running).timed(epoch, clock_ns as i64)
    }

    #[test]
    fn the_shore_shows_no_step_older_than_one_shown() {
        let ms = 1_000_000;
        let mut shown = Shown::new("cable_observation");
        // Steps 1..=6 of epoch 7, 200 ms apart, arriving 300 ms later with jitter, two reordered and
        // one repeated; then a restarted producer's epoch 9 from seq 1; then epoch 7's last step
        // again, a straggler of the old epoch.
        let arrivals = [
            (7, 1, 0, 300),
            (7, 3, 400, 680),
            (7, 2, 200, 690),
            (7, 4, 600, 900),
            (7, 4, 600, 905),
            (7, 6, 1000, 1300),
            (7, 5, 800, 1310),
            (9, 1, 1200, 1500),
            (9, 2, 1400, 1700),
            (7, 6, 1000, 1750),
        ];
        let judged: Vec<Judged> = arrivals
            .iter()
            .map(|&(epoch, seq, clock, at)| Judged {
                epoch,
                seq,
                shown: shown.judge(&stamp(epoch, seq, clock), at * ms),
            })
            .collect();
        let shown_steps: Vec<(u32, u64)> = judged
            .iter()
            .filter(|j| j.shown)
            .map(|j| (j.epoch, j.seq))
            .collect();
        assert_eq!(
            shown_steps,
            [(7, 1), (7, 3), (7, 4), (7, 6), (9, 1), (9, 2)]
        );
        assert_eq!((shown.shown, shown.refused), (6, 4));
        let o = order(&judged);
        assert_eq!(
            o,
            Order {
                stale_arrivals: 4,
                stale_shown: 0,
                refused: 4
            }
        );
        // The recomputation catches a stale step shown as new.
        let mut wrong = judged.clone();
        wrong[2].shown = true;
        assert_eq!(order(&wrong).stale_shown, 1);
    }

    #[test]
    fn a_late_step_still_newest_is_shown_and_a_forged_one_refused() {
        let ms = 1_000_000;
        let mut shown = Shown::new("cable_observation");
        assert!(shown.judge(&stamp(3, 1, 0), 300 * ms));
        // Step 2 comes 6 s late (a congested link): still the newest, shown.
        assert!(shown.judge(&stamp(3, 2, 200), 6_500 * ms));
        // A later step stamped before the last one: a forged or corrupt stamp, refused.
        assert!(!shown.judge(&stamp(3, 3, 100), 6_600 * ms));
        // A `seq` its producer cannot have reached (at most 8 + 2 per 10 ms of its clock).
        assert!(!shown.judge(&stamp(3, 1_000_000, 400), 6_700 * ms));
        assert!(shown.judge(&stamp(3, 4, 600), 6_900 * ms));
        assert_eq!((shown.shown, shown.refused), (3, 2));
    }
}
