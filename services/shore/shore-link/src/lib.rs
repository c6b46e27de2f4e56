//! The shore link's core: which services cross (an allow-list generated from the messages topic
//! table), the zenoh settings (explicit endpoints, no scouting), and the demo's report computed from
//! what each side recorded. Plain data; `main.rs` runs the link over iceoryx2's zenoh tunnel.

use messages::Qos;
use messages::topics::{self, Endpoint, health, shore};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

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
    /// The telemetry of `endpoint` (state, observations, learning reports, heartbeats), the camera
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
/// defaults would join any peer on the network and bridge with it).
pub fn zenoh_settings(side: Side, endpoint: &str) -> Vec<(&'static str, String)> {
    let one = format!("[{}]", serde_json::Value::from(endpoint));
    let (listen, connect) = match side {
        Side::Vehicle => (one, "[]".to_owned()),
        Side::Shore => ("[]".to_owned(), one),
    };
    vec![
        ("mode", "\"peer\"".to_owned()),
        ("listen/endpoints", listen),
        ("connect/endpoints", connect),
        ("scouting/multicast/enabled", "false".to_owned()),
        ("scouting/gossip/enabled", "false".to_owned()),
    ]
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
    /// Cable observations published on the vehicle while the shore was watching.
    pub sent: usize,
    pub received_on_shore: usize,
    /// Added by the link: arrival on shore minus arrival on the vehicle, same step.
    pub latency_ms: Latency,
    /// Steps the vehicle missed while the shore watched (see [`steps_missed`]).
    pub vehicle_steps_missed: u64,
    /// From the link's return to the first telemetry on shore (none: no cut, or never back).
    pub shore_back_after_s: Option<f64>,
    /// Messages or services outside the allow-list seen on the shore.
    pub outside_allow_list_seen: u64,
    pub stop_obeyed: bool,
    /// Per topic received on shore: messages and payload bytes per second of the watch.
    pub topics: BTreeMap<String, TopicRate>,
    /// Everything the vehicle's network interface sent per second of the watch (payloads, zenoh's
    /// framing and keep-alives, TCP/IP headers).
    pub link_bytes_per_s: Option<f64>,
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

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Latency {
    pub p50: f64,
    pub p99: f64,
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
                p50: f64::NAN,
                p99: f64::NAN,
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
    let latency = Latency {
        p50: stats::percentile(added.iter().copied(), 0.5),
        p99: stats::percentile(added.iter().copied(), 0.99),
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
/// received): frames that reached the vehicle but were answered by no setpoints, and setpoints that
/// lacked a command. `frames` are the frames' step numbers; `steps` the vehicle's setpoints, as (seq,
/// commands missing). A frame lost before the vehicle (the twin drops some, as a real link does) is
/// no step of the vehicle's. Start-up and the stop are outside the window: the link is not running
/// then.
pub fn steps_missed(frames: &[u64], steps: &[(u64, u64)], shore: &[Arrival]) -> u64 {
    let (Some(first), Some(last)) = (
        shore.iter().map(|a| a.seq).min(),
        shore.iter().map(|a| a.seq).max(),
    ) else {
        return 0;
    };
    let window = first..=last;
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
    }

    #[test]
    fn the_vehicle_listens_the_shore_connects_and_nobody_scouts() {
        let v = zenoh_settings(Side::Vehicle, "tcp/10.0.0.1:7447");
        let s = zenoh_settings(Side::Shore, "tcp/10.0.0.1:7447");
        let get =
            |c: &[(&str, String)], k: &str| c.iter().find(|(key, _)| *key == k).unwrap().1.clone();
        assert_eq!(get(&v, "listen/endpoints"), r#"["tcp/10.0.0.1:7447"]"#);
        assert_eq!(get(&v, "connect/endpoints"), "[]");
        assert_eq!(get(&s, "connect/endpoints"), r#"["tcp/10.0.0.1:7447"]"#);
        for c in [&v, &s] {
            assert_eq!(get(c, "scouting/multicast/enabled"), "false");
            assert_eq!(get(c, "scouting/gossip/enabled"), "false");
        }
    }

    #[test]
    fn figures_join_the_two_sides_by_step() {
        let ms = 1_000_000;
        let vehicle: Vec<Arrival> = (0..10)
            .map(|s| Arrival {
                seq: s,
                at_ns: s * 200 * ms,
            })
            .collect();
        // The shore saw steps 2..=8 except 5, each 3 ms later.
        let shore: Vec<Arrival> = (2..=8)
            .filter(|&s| s != 5)
            .map(|s| Arrival {
                seq: s,
                at_ns: s * 200 * ms + 3 * ms,
            })
            .collect();
        let (sent, received, latency) = link_figures(&vehicle, &shore);
        assert_eq!((sent, received), (7, 6));
        assert!((latency.p50 - 3.0).abs() < 1e-9 && (latency.p99 - 3.0).abs() < 1e-9);
        assert_eq!(back_after(&shore, 1000 * ms), Some(0.203));
        assert_eq!(back_after(&shore, 10_000 * ms), None);
    }
}
