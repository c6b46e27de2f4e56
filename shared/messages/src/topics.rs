//! Topic names and their QoS, defined once for every process.

use crate::payload::*;
use std::marker::PhantomData;

/// Which side of the two-step learning a process serves; it selects the topics' namespace.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Endpoint {
    /// The all-in-simulation mesh: driven by the simulator, data-driven lockstep.
    Sim,
    /// The vehicle (or its twin): driven by the camera's clock.
    Vehicle,
}

/// The services of the control path, camera to thruster allocator, as their processes, nodes and
/// heartbeats are named: both endpoints run them.
pub const CONTROL_PATH: [&str; 6] = [
    "camera",
    "perception",
    "sway-behaviour",
    "yaw-behaviour",
    "surge-controller",
    "thruster-allocator",
];

impl Endpoint {
    pub fn name(self) -> &'static str {
        match self {
            Endpoint::Sim => "sim",
            Endpoint::Vehicle => "vehicle",
        }
    }

    /// The services a mesh of this endpoint runs: the control path and, in simulation, the simulator
    /// and the monitor; on the vehicle the thruster driver and the monitor. Beside them run observers
    /// (the flight recorder) and, against the twin, the vehicle twin in the hardware's place.
    pub const fn services(self) -> [&'static str; 8] {
        let [camera, perception, sway, yaw, surge, allocator] = CONTROL_PATH;
        let own = match self {
            Endpoint::Sim => "simulator",
            Endpoint::Vehicle => "thruster-driver",
        };
        [
            camera, perception, sway, yaw, surge, allocator, own, "monitor",
        ]
    }
}

impl std::fmt::Display for Endpoint {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Endpoint {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "sim" => Ok(Endpoint::Sim),
            "vehicle" => Ok(Endpoint::Vehicle),
            other => Err(format!(
                "unknown endpoint `{other}` (expected `sim` or `vehicle`)"
            )),
        }
    }
}

/// A topic's quality of service.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Qos {
    /// Samples a subscriber that connects late still receives (1: the latest, so a restarted
    /// process picks up the current step at once).
    pub history: usize,
    /// Samples a subscriber can hold unread; the oldest is overwritten when full (publishers never
    /// block: a slow process must not stall the vehicle).
    pub buffer: usize,
    /// Samples a recording subscriber (`ports::Tap`: the flight recorder) can hold unread. It is
    /// woken once per step, not per message, so it needs more slack than a consumer of the loop;
    /// when it falls behind further, its oldest samples are overwritten and it counts the holes.
    pub recorder_buffer: usize,
    pub max_publishers: usize,
    pub max_subscribers: usize,
    pub max_nodes: usize,
}

/// The lockstep topics: one step in flight, a little slack for re-sends.
const STEP: Qos = Qos {
    history: 1,
    buffer: 4,
    // About 55 ms of the accelerated simulation (2,300 steps/s); 26 s at the vehicle's 5 Hz.
    recorder_buffer: 128,
    // The producing service, plus its restarted successor while the dead one is being cleaned up.
    max_publishers: 2,
    // The consumers, a recorder or monitor, and a test's probe.
    max_subscribers: 8,
    max_nodes: 16,
};

/// A named topic carrying payloads of type `P`.
#[derive(Debug)]
pub struct Topic<P: ?Sized> {
    /// The name below `cabletrack/<endpoint>/`.
    pub name: &'static str,
    pub qos: Qos,
    _payload: PhantomData<fn() -> Box<P>>,
}

impl<P: ?Sized> Clone for Topic<P> {
    fn clone(&self) -> Self {
        *self
    }
}

impl<P: ?Sized> Copy for Topic<P> {}

impl<P: ?Sized> Topic<P> {
    pub const fn new(name: &'static str, qos: Qos) -> Self {
        Topic {
            name,
            qos,
            _payload: PhantomData,
        }
    }

    /// The iceoryx2 service name on an endpoint.
    pub fn service_name(&self, endpoint: Endpoint) -> String {
        format!("cabletrack/{}/{}", endpoint.name(), self.name)
    }
}

/// The vehicle's state, from the simulator (or the vehicle twin).
pub const VEHICLE_STATE: Topic<VehicleStateMsg> = Topic::new("vehicle_state", STEP);

/// Camera frames: an 8-bit image as a `[u8]` slice with a [`CameraFrameHeader`].
pub const CAMERA_FRAME: Topic<[u8]> = Topic::new(
    "camera_frame",
    Qos {
        // Each subscriber's buffer and history cost a frame of shared memory: keep them small. The
        // recorder's 64 frames (4.9 MB at 320x240) hold 28 ms of the accelerated simulation, what a
        // recorder draining every 10 ms on the CPU the loop leaves free needs to lose none.
        max_subscribers: 4,
        buffer: 2,
        recorder_buffer: 64,
        ..STEP
    },
);

/// The camera's compressed video, where its source has one (an RTP/H.264 stream): each access
/// unit it decodes, as it arrived (Annex B), as a `[u8]` slice with a [`VideoUnit`] header, for
/// the flight recorder. At most [`MAX_ACCESS_UNIT`] bytes a unit: the camera does not publish a
/// larger one, nor the units after it up to the next keyframe (they reference it).
pub const CAMERA_VIDEO: Topic<[u8]> = Topic::new(
    "camera_video",
    Qos {
        // A late recorder starts at a keyframe, not with history: none.
        history: 0,
        buffer: 8,
        // 13 s at the twin's 5 frames/s, 2 s of a 30 frames/s camera. The shared memory grows
        // with the largest unit sent (`ports`), so it costs little at the twin's sizes.
        recorder_buffer: 64,
        max_publishers: 2,
        // The recorder, a test's probe.
        max_subscribers: 4,
        max_nodes: 16,
    },
);

/// The largest access unit published on [`CAMERA_VIDEO`]: a 1080p keyframe of a camera at
/// 10 Mbit/s is about 300 kB.
pub const MAX_ACCESS_UNIT: usize = 2 << 20;

/// What perception found in each frame.
pub const CABLE_OBSERVATION: Topic<CableObservationMsg> = Topic::new("cable_observation", STEP);

/// The behaviours' commands, one topic per DOF.
pub const SURGE_COMMAND: Topic<DofCommand> = Topic::new("command/surge", STEP);
pub const SWAY_COMMAND: Topic<DofCommand> = Topic::new("command/sway", STEP);
pub const YAW_COMMAND: Topic<DofCommand> = Topic::new("command/yaw", STEP);

/// The command topic of a learned DOF.
pub fn command(dof: config::Dof) -> Topic<DofCommand> {
    match dof {
        config::Dof::Sway => SWAY_COMMAND,
        config::Dof::Yaw => YAW_COMMAND,
    }
}

/// Thruster setpoints: exactly one publisher (the allocator) may command the thrusters; a second one
/// is refused while the first is alive (`ports`). A late subscriber still receives the last
/// setpoints (history 1): the thruster driver judges their age and never acts on stale ones.
pub const THRUSTER_SETPOINTS: Topic<ThrusterSetpoints> = Topic::new(
    "thruster_setpoints",
    Qos {
        max_publishers: 1,
        ..STEP
    },
);

/// Learning statistics, one topic per learned DOF, one sample per episode. A large buffer: a monitor
/// must not miss an episode.
const STATS: Qos = Qos {
    history: 1,
    buffer: 256,
    recorder_buffer: 256,
    // The behaviour, and its restarted successor while the dead one is being cleaned up.
    max_publishers: 2,
    // The monitor, the flight recorder, the shore link's mirror, `status`, the other behaviour,
    // a test's probe, with room.
    max_subscribers: 8,
    max_nodes: 16,
};
pub const SWAY_LEARNING: Topic<LearningStats> = Topic::new("learning/sway", STATS);
pub const YAW_LEARNING: Topic<LearningStats> = Topic::new("learning/yaw", STATS);

/// The learning-statistics topic of a learned DOF.
pub fn learning(dof: config::Dof) -> Topic<LearningStats> {
    match dof {
        config::Dof::Sway => SWAY_LEARNING,
        config::Dof::Yaw => YAW_LEARNING,
    }
}

/// Health: every process of a mesh notifies its heartbeat event service at least every
/// [`HEARTBEAT_PERIOD`], from its wait loop (`runtime`), so a process that is alive but stuck (stopped,
/// or spinning inside one step) misses the service's [`HEARTBEAT_DEADLINE`]. The supervisor and the
/// status command listen. An event service, not a topic: a heartbeat carries no data.
pub mod health {
    use super::Endpoint;
    use std::time::Duration;

    /// The longest a process goes without notifying its heartbeat. A process beats from whatever
    /// wakes it (at most every half period), so only an idle process wakes for a beat; longer than
    /// the vehicle's 200 ms step, so a process with steps to do never does.
    pub const HEARTBEAT_PERIOD: Duration = Duration::from_millis(250);
    /// The event service's deadline: a beat may come 50 ms late (a process descheduled on a loaded
    /// machine) before a deadline is missed; the supervisor waits for two in a row (600 ms of
    /// silence) before it calls a service stuck.
    pub const HEARTBEAT_DEADLINE: Duration = Duration::from_millis(300);
    /// The process itself, and its restarted successor while the stuck one is being removed; the
    /// shore link's notifier when the heartbeat is bridged.
    pub const MAX_NOTIFIERS: usize = 4;
    /// The supervisor, a status command, the shore link, a test's probe.
    pub const MAX_LISTENERS: usize = 8;
    pub const MAX_NODES: usize = 16;
    /// A heartbeat's event id is the process's restart count, up to this (iceoryx2's default
    /// largest event id).
    pub const MAX_RESTARTS_ID: usize = 255;

    /// The heartbeat event service of the process `name` on `endpoint`:
    /// `cabletrack/<endpoint>/heartbeat/<name>`.
    pub fn service_name(endpoint: Endpoint, name: &str) -> String {
        format!("cabletrack/{}/heartbeat/{name}", endpoint.name())
    }
}

/// The shore: what an operator's computer sends to the vehicle over the shore link. Its own
/// namespace, `cabletrack/shore/<topic>`, apart from the vehicle's telemetry (`cabletrack/vehicle/...`),
/// so the link's allow-list keeps the two directions apart by name.
pub mod shore {
    use super::{Qos, Topic};
    use crate::payload::MissionCommand;

    /// Start/stop commands for the vehicle's mesh; its supervisor obeys them.
    pub const MISSION: Topic<MissionCommand> = Topic::new(
        "mission",
        Qos {
            // A subscriber that connects after the command (the link, the supervisor) still gets it.
            history: 1,
            buffer: 4,
            recorder_buffer: 4,
            // On the shore, the operator. On the vehicle, the link's mirror of the shore's
            // publisher and the link's guard, which holds the other place so that no process of
            // the vehicle can publish a command as if it came from the shore.
            max_publishers: 2,
            // The supervisor, the link, a test's probe.
            max_subscribers: 4,
            max_nodes: 16,
        },
    );

    /// `cabletrack/shore/<topic>`.
    pub fn service_name<P: ?Sized>(topic: &Topic<P>) -> String {
        format!("cabletrack/shore/{}", topic.name)
    }
}
/// The supervisor's events: a service started, exited, is restarted, or was stopped with the mesh.
/// A few a minute at most; the history lets a restarted recorder see the latest ones.
pub const SUPERVISOR_EVENTS: Topic<SupervisorEvent> = Topic::new(
    "supervisor/events",
    Qos {
        history: 16,
        buffer: 64,
        recorder_buffer: 64,
        // The supervisor, and a successor while a killed one's port is being cleaned up.
        max_publishers: 2,
        max_subscribers: 4,
        max_nodes: 16,
    },
);

/// The flight recorder's progress, after each flush of its file: what is on disk, what it missed.
pub const RECORDER_STATUS: Topic<RecorderStatus> = Topic::new(
    "recorder/status",
    Qos {
        history: 1,
        buffer: 16,
        recorder_buffer: 16,
        max_publishers: 2,
        max_subscribers: 4,
        max_nodes: 16,
    },
);

/// The vehicle's autopilot, as the thruster driver that pilots it over MAVLink sees it (the ArduSub
/// thruster sink): telemetry beside the loop, a few messages a second per topic.
const AUTOPILOT: Qos = Qos {
    history: 1,
    buffer: 16,
    recorder_buffer: 64,
    // The driver, and its restarted successor while the dead one is being cleaned up.
    max_publishers: 2,
    max_subscribers: 4,
    max_nodes: 16,
};

/// The autopilot's state (armed, mode, heartbeat, battery). One thruster driver at a time pilots
/// the autopilot: the state topic takes one publisher, and the driver opens it before it touches the
/// autopilot, so a second driver stops there (the place of a dead one is freed by itself).
pub const AUTOPILOT_STATE: Topic<AutopilotState> = Topic::new(
    "autopilot/state",
    Qos {
        max_publishers: 1,
        ..AUTOPILOT
    },
);
/// The autopilot's attitude.
pub const AUTOPILOT_ATTITUDE: Topic<AutopilotAttitude> =
    Topic::new("autopilot/attitude", AUTOPILOT);
/// The vehicle's depth and heading, from the autopilot.
pub const AUTOPILOT_DEPTH: Topic<AutopilotDepth> = Topic::new("autopilot/depth", AUTOPILOT);
/// The autopilot's outputs to the thrusters.
pub const AUTOPILOT_SERVO_OUTPUTS: Topic<ServoOutputs> =
    Topic::new("autopilot/servo_outputs", AUTOPILOT);
/// The autopilot's texts; a subscriber that connects late still sees the last few.
pub const AUTOPILOT_STATUS_TEXT: Topic<StatusText> = Topic::new(
    "autopilot/status_text",
    Qos {
        history: 16,
        buffer: 32,
        ..AUTOPILOT
    },
);

// A recorder's subscriber holds at least what a consumer of the loop holds (checked when building).
const _: () = {
    let qos = [
        VEHICLE_STATE.qos,
        CAMERA_FRAME.qos,
        CAMERA_VIDEO.qos,
        CABLE_OBSERVATION.qos,
        THRUSTER_SETPOINTS.qos,
        STATS,
        SUPERVISOR_EVENTS.qos,
        RECORDER_STATUS.qos,
        AUTOPILOT_STATE.qos,
        AUTOPILOT_STATUS_TEXT.qos,
    ];
    let mut i = 0;
    while i < qos.len() {
        assert!(qos[i].recorder_buffer >= qos[i].buffer);
        i += 1;
    }
};

/// The hardware level: topics between a device (or the vehicle twin standing in for the vehicle) and
/// its adapters on the vehicle endpoint (`shared/adapters`). They live outside the `sim` and
/// `vehicle` namespaces, in `cabletrack/<device>/<topic>`: the services of the vehicle endpoint never
/// see them, only the camera's frame source and the thruster driver's thruster sink do.
pub mod hardware {
    use super::{Qos, Topic};
    use crate::payload::ThrusterSetpoints;

    /// The namespace of the vehicle twin's devices: `cabletrack/twin/...`.
    pub const TWIN: &str = "twin";

    /// The twin's camera: each frame as a `[u8]` image with a [`crate::CameraFrameHeader`] whose stamp
    /// is the twin's (its frame counter, its clock, the trial as the episode, the step and status).
    pub const TWIN_FRAME: Topic<[u8]> = Topic::new(
        "frame",
        Qos {
            history: 1,
            // A frame source reads each frame at once; a few frames of slack cost little memory.
            buffer: 4,
            recorder_buffer: 4,
            // One camera (the twin); a subscriber per frame source, a recorder, a test's probe.
            max_publishers: 1,
            max_subscribers: 4,
            max_nodes: 16,
        },
    );

    /// The twin's thrusters: the setpoints written by the vehicle's thruster sink. As on the vehicle
    /// endpoint, one process at a time drives the thrusters. No history: thrusters that connect late
    /// never receive old setpoints, however they judge them.
    pub const TWIN_THRUSTERS: Topic<ThrusterSetpoints> = Topic::new(
        "thrusters",
        Qos {
            history: 0,
            buffer: 4,
            recorder_buffer: 4,
            max_publishers: 1,
            max_subscribers: 4,
            max_nodes: 16,
        },
    );

    /// The iceoryx2 service name of a hardware topic of `device`: `cabletrack/<device>/<topic>`.
    pub fn service_name<P: ?Sized>(device: &str, topic: &Topic<P>) -> String {
        format!("cabletrack/{device}/{}", topic.name)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_carry_the_endpoint() {
        assert_eq!(
            VEHICLE_STATE.service_name(Endpoint::Sim),
            "cabletrack/sim/vehicle_state"
        );
        assert_eq!(
            command(config::Dof::Yaw).service_name(Endpoint::Vehicle),
            "cabletrack/vehicle/command/yaw"
        );
        assert_eq!("vehicle".parse::<Endpoint>(), Ok(Endpoint::Vehicle));
        assert!("boat".parse::<Endpoint>().is_err());
    }

    #[test]
    fn hardware_topics_live_outside_the_endpoints() {
        assert_eq!(
            hardware::service_name(hardware::TWIN, &hardware::TWIN_FRAME),
            "cabletrack/twin/frame"
        );
        assert_eq!(
            hardware::service_name(hardware::TWIN, &hardware::TWIN_THRUSTERS),
            "cabletrack/twin/thrusters"
        );
        assert_eq!(hardware::TWIN_THRUSTERS.qos.max_publishers, 1);
        assert_eq!(hardware::TWIN_THRUSTERS.qos.history, 0);
    }

    #[test]
    fn a_heartbeat_deadline_spans_several_periods() {
        assert_eq!(
            health::service_name(Endpoint::Vehicle, "perception"),
            "cabletrack/vehicle/heartbeat/perception"
        );
        assert!(health::HEARTBEAT_DEADLINE > health::HEARTBEAT_PERIOD);
        // A stuck service is replaced within a second: two deadlines, the supervisor's look, a start.
        assert!(2 * health::HEARTBEAT_DEADLINE <= std::time::Duration::from_millis(600));
    }

    #[test]
    fn shore_commands_live_apart_from_the_telemetry() {
        assert_eq!(
            shore::service_name(&shore::MISSION),
            "cabletrack/shore/mission"
        );
    }

    #[test]
    fn only_one_process_drives_the_thrusters() {
        assert_eq!(THRUSTER_SETPOINTS.qos.max_publishers, 1);
        // Through an autopilot: one driver pilots it.
        assert_eq!(AUTOPILOT_STATE.qos.max_publishers, 1);
        assert_eq!(
            AUTOPILOT_STATE.service_name(Endpoint::Vehicle),
            "cabletrack/vehicle/autopilot/state"
        );
    }

    /// The names of the services a mesh file of the repository's `config/` runs, sorted, but for
    /// the flight recorder (an observer of every topic), the vehicle twin and the shore link (a
    /// program of its own workspace, without a heartbeat); the monitor counts, observer or not.
    fn mesh_file_services(file: &str) -> Vec<String> {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../config")
            .join(file);
        let text = std::fs::read_to_string(&path).unwrap();
        let mesh: toml::Table = toml::from_str(&text).unwrap();
        let mut names: Vec<String> = mesh["service"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|s| {
                s.get("observer").and_then(|o| o.as_bool()) != Some(true)
                    || s["name"].as_str() == Some("monitor")
            })
            .map(|s| s["name"].as_str().unwrap().to_string())
            .filter(|n| n != "vehicle-twin" && n != "shore-link")
            .collect();
        names.sort();
        names
    }

    #[test]
    fn each_endpoints_services_are_those_its_mesh_file_runs() {
        for (endpoint, file) in [
            (Endpoint::Sim, "sim-mesh.toml"),
            (Endpoint::Vehicle, "vehicle.toml"),
        ] {
            let mut services: Vec<String> =
                endpoint.services().iter().map(|s| s.to_string()).collect();
            services.sort();
            assert_eq!(services, mesh_file_services(file), "{file}");
        }
    }
}
