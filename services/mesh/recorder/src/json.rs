//! The JSON form of every payload recorded as JSON, and its JSON Schema: the payload's fields without
//! its padding, in the payload's units (radians, normalised commands, nanoseconds). Reading a form
//! back gives the very payload written: numbers are written in their shortest exact form and read
//! with `serde_json`'s exact parser, so a replay can compare bit for bit.
//!
//! JSON has no NaN or infinity: a non-finite number is written as `null` and read back as NaN.

use config::MAX_THRUSTERS;
use messages::{
    CableObservationData, CableObservationMsg, CameraFrameHeader, DofCommand, LearningStats,
    RecorderStatus, ServiceEvent, Stamp, SupervisorEvent, ThrusterSetpoints, VehicleStateMsg,
};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

/// A number as recorded: finite, or `null` (read back as NaN).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(transparent)]
pub struct Num(pub f64);

impl<'de> Deserialize<'de> for Num {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        Ok(Num(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN)))
    }
}

fn num_schema(description: &str) -> Value {
    json!({"type": ["number", "null"], "description": description})
}

fn int_schema(description: &str) -> Value {
    json!({"type": "integer", "minimum": 0, "description": description})
}

fn object_schema(properties: Value) -> Value {
    let required: Vec<String> = properties
        .as_object()
        .map(|p| p.keys().cloned().collect())
        .unwrap_or_default();
    json!({"type": "object", "properties": properties, "required": required})
}

/// A whole channel's schema: draft 2020-12, titled with the schema's name.
fn document(title: &str, description: &str, body: Value) -> Value {
    let mut doc = json!({
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": title,
        "description": description,
    });
    if let (Some(d), Some(b)) = (doc.as_object_mut(), body.as_object()) {
        d.extend(b.clone());
    }
    doc
}

/// A [`Stamp`]: the control step a message belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct StampJson {
    pub seq: u64,
    pub time_ns: u64,
    #[serde(default)]
    pub clock_ns: u64,
    #[serde(default)]
    pub epoch: u32,
    pub episode: u32,
    pub step: u32,
    pub status: u8,
}

impl From<&Stamp> for StampJson {
    fn from(s: &Stamp) -> Self {
        StampJson {
            seq: s.seq,
            time_ns: s.time_ns,
            clock_ns: s.clock_ns,
            epoch: s.epoch,
            episode: s.episode,
            step: s.step,
            status: s.status,
        }
    }
}

impl From<&StampJson> for Stamp {
    fn from(s: &StampJson) -> Self {
        Stamp {
            seq: s.seq,
            time_ns: s.time_ns,
            clock_ns: s.clock_ns,
            epoch: s.epoch,
            episode: s.episode,
            step: s.step,
            status: s.status,
            _reserved: [0; 3],
        }
    }
}

fn stamp_schema() -> Value {
    object_schema(json!({
        "seq": int_schema("the control step's sequence number, increasing over the run"),
        "time_ns": int_schema("the step's time (ns): simulated time on the sim endpoint, the frame source's clock on the vehicle"),
        "clock_ns": int_schema("the vehicle's monotonic clock (ns) when the frame was read (0 on the sim endpoint)"),
        "epoch": int_schema("the producer's epoch: new at each start of the process"),
        "episode": int_schema("the episode (a trial on the vehicle), from 0"),
        "step": int_schema("the step within the episode, 0 at its start"),
        "status": {"type": "integer", "enum": [0, 1, 2], "description": "0 running, 1 cable lost, 2 time limit"},
    }))
}

/// The vehicle's state ([`VehicleStateMsg`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct VehicleStateJson {
    pub stamp: StampJson,
    pub x: Num,
    pub y: Num,
    pub psi: Num,
    pub u: Num,
    pub v: Num,
    pub r: Num,
    pub x_rate: Num,
    pub y_rate: Num,
    pub psi_rate: Num,
}

impl From<&VehicleStateMsg> for VehicleStateJson {
    fn from(m: &VehicleStateMsg) -> Self {
        VehicleStateJson {
            stamp: (&m.stamp).into(),
            x: Num(m.x),
            y: Num(m.y),
            psi: Num(m.psi),
            u: Num(m.u),
            v: Num(m.v),
            r: Num(m.r),
            x_rate: Num(m.x_rate),
            y_rate: Num(m.y_rate),
            psi_rate: Num(m.psi_rate),
        }
    }
}

impl From<&VehicleStateJson> for VehicleStateMsg {
    fn from(j: &VehicleStateJson) -> Self {
        VehicleStateMsg {
            stamp: (&j.stamp).into(),
            x: j.x.0,
            y: j.y.0,
            psi: j.psi.0,
            u: j.u.0,
            v: j.v.0,
            r: j.r.0,
            x_rate: j.x_rate.0,
            y_rate: j.y_rate.0,
            psi_rate: j.psi_rate.0,
        }
    }
}

pub fn vehicle_state_schema() -> Value {
    document(
        "cabletrack.VehicleState",
        "The vehicle's pose in the pool frame (x along the pool, y to the right seen from above, psi from x towards y), its body velocities and its pose's rate.",
        object_schema(json!({
            "stamp": stamp_schema(),
            "x": num_schema("m"),
            "y": num_schema("m"),
            "psi": num_schema("heading, rad"),
            "u": num_schema("surge velocity, m/s"),
            "v": num_schema("sway velocity, m/s"),
            "r": num_schema("yaw rate, rad/s"),
            "x_rate": num_schema("dx/dt, m/s (current included)"),
            "y_rate": num_schema("dy/dt, m/s (current included)"),
            "psi_rate": num_schema("dpsi/dt, rad/s"),
        })),
    )
}

/// A cable observation's numbers ([`CableObservationData`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ObservationJson {
    pub found: bool,
    pub rho: Num,
    pub theta: Num,
    pub x_g: Num,
    pub y_g: Num,
    pub x_g_rate: Num,
    pub theta_rate: Num,
    pub confidence: Num,
}

impl From<&CableObservationData> for ObservationJson {
    fn from(o: &CableObservationData) -> Self {
        ObservationJson {
            found: o.found != 0,
            rho: Num(o.rho),
            theta: Num(o.theta),
            x_g: Num(o.x_g),
            y_g: Num(o.y_g),
            x_g_rate: Num(o.x_g_rate),
            theta_rate: Num(o.theta_rate),
            confidence: Num(o.confidence),
        }
    }
}

impl From<&ObservationJson> for CableObservationData {
    fn from(j: &ObservationJson) -> Self {
        CableObservationData {
            found: j.found as u8,
            _reserved: [0; 7],
            rho: j.rho.0,
            theta: j.theta.0,
            x_g: j.x_g.0,
            y_g: j.y_g.0,
            x_g_rate: j.x_g_rate.0,
            theta_rate: j.theta_rate.0,
            confidence: j.confidence.0,
        }
    }
}

fn observation_schema() -> Value {
    object_schema(json!({
        "found": {"type": "boolean", "description": "the cable is in view (found)"},
        "rho": num_schema("the line's distance from the image centre along its normal, pixels"),
        "theta": num_schema("Theta: the cable's angle from the image's vertical axis, rad, positive when its top leans right"),
        "x_g": num_schema("the mid point of the line's border crossings, fraction of the width, positive right"),
        "y_g": num_schema("the same, fraction of the height, positive down"),
        "x_g_rate": num_schema("dx_g/dt, 1/s"),
        "theta_rate": num_schema("dTheta/dt, rad/s"),
        "confidence": num_schema("the detector's confidence in [0, 1] (1 for the geometric camera)"),
    }))
}

/// A camera frame's header ([`CameraFrameHeader`]); the image is on its own channel.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameHeaderJson {
    pub stamp: StampJson,
    pub width: u32,
    pub height: u32,
    /// The image is not whole (lost video data); absent in records made before it existed.
    #[serde(default)]
    pub damaged: bool,
    pub truth: ObservationJson,
}

impl From<&CameraFrameHeader> for FrameHeaderJson {
    fn from(h: &CameraFrameHeader) -> Self {
        FrameHeaderJson {
            stamp: (&h.stamp).into(),
            width: h.width,
            height: h.height,
            damaged: h.is_damaged(),
            truth: (&h.truth).into(),
        }
    }
}

impl From<&FrameHeaderJson> for CameraFrameHeader {
    fn from(j: &FrameHeaderJson) -> Self {
        CameraFrameHeader {
            stamp: (&j.stamp).into(),
            width: j.width,
            height: j.height,
            flags: if j.damaged {
                CameraFrameHeader::DAMAGED
            } else {
                0
            },
            truth: (&j.truth).into(),
            ..Default::default()
        }
    }
}

pub fn frame_header_schema() -> Value {
    document(
        "cabletrack.CameraFrameHeader",
        "A camera frame's step, size and the true line where the source knows it (the simulator, the twin; found = false otherwise).",
        object_schema(json!({
            "stamp": stamp_schema(),
            "width": int_schema("pixels"),
            "height": int_schema("pixels"),
            "damaged": {"type": "boolean", "description": "the image is not whole: video data was lost in it or in a frame it references"},
            "truth": observation_schema(),
        })),
    )
}

/// Perception's estimate ([`CableObservationMsg`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CableObservationJson {
    pub stamp: StampJson,
    pub observation: ObservationJson,
}

impl From<&CableObservationMsg> for CableObservationJson {
    fn from(m: &CableObservationMsg) -> Self {
        CableObservationJson {
            stamp: (&m.stamp).into(),
            observation: (&m.observation).into(),
        }
    }
}

impl From<&CableObservationJson> for CableObservationMsg {
    fn from(j: &CableObservationJson) -> Self {
        CableObservationMsg {
            stamp: (&j.stamp).into(),
            observation: (&j.observation).into(),
        }
    }
}

pub fn observation_msg_schema() -> Value {
    document(
        "cabletrack.CableObservation",
        "What perception found in a frame: an estimate of the cable's line and its rates.",
        object_schema(json!({"stamp": stamp_schema(), "observation": observation_schema()})),
    )
}

/// One DOF's command ([`DofCommand`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CommandJson {
    pub stamp: StampJson,
    pub value: Num,
}

impl From<&DofCommand> for CommandJson {
    fn from(c: &DofCommand) -> Self {
        CommandJson {
            stamp: (&c.stamp).into(),
            value: Num(c.value),
        }
    }
}

impl From<&CommandJson> for DofCommand {
    fn from(j: &CommandJson) -> Self {
        DofCommand {
            stamp: (&j.stamp).into(),
            value: j.value.0,
        }
    }
}

pub fn command_schema() -> Value {
    document(
        "cabletrack.DofCommand",
        "A behaviour's command for one DOF: the normalised generalised force.",
        object_schema(json!({"stamp": stamp_schema(), "value": num_schema("in [-1, 1]")})),
    )
}

/// The thruster setpoints ([`ThrusterSetpoints`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SetpointsJson {
    pub stamp: StampJson,
    pub values: Vec<Num>,
    pub missing: u32,
    pub scale: Num,
    /// A failsafe stop's cause (0: the answer to a step).
    #[serde(default)]
    pub stop: u32,
}

impl From<&ThrusterSetpoints> for SetpointsJson {
    fn from(s: &ThrusterSetpoints) -> Self {
        SetpointsJson {
            stamp: (&s.stamp).into(),
            values: s.as_slice().iter().map(|&v| Num(v)).collect(),
            missing: s.missing,
            scale: Num(s.scale),
            stop: s.stop,
        }
    }
}

impl From<&SetpointsJson> for ThrusterSetpoints {
    fn from(j: &SetpointsJson) -> Self {
        let mut values = [0.0; MAX_THRUSTERS];
        let count = j.values.len().min(MAX_THRUSTERS);
        for (v, n) in values.iter_mut().zip(&j.values) {
            *v = n.0;
        }
        ThrusterSetpoints {
            stamp: (&j.stamp).into(),
            count: count as u32,
            missing: j.missing,
            stop: j.stop,
            _reserved: 0,
            values,
            scale: j.scale.0,
        }
    }
}

pub fn setpoints_schema() -> Value {
    document(
        "cabletrack.ThrusterSetpoints",
        "The thruster allocator's setpoints, one per thruster of the layout (port, starboard, lateral).",
        object_schema(json!({
            "stamp": stamp_schema(),
            "values": {"type": "array", "items": num_schema("in [-1, 1]"), "maxItems": MAX_THRUSTERS},
            "missing": int_schema("bit k set: DOF k's command (0 surge, 1 sway, 2 yaw) missed its deadline and counted as 0"),
            "scale": num_schema("the factor applied to keep every setpoint within [-1, 1]"),
            "stop": {"type": "integer", "enum": [0, 1, 2, 3, 4, 255], "description": "0 the answer to a step; a failsafe stop of the thrusters: 1 driver started, 2 deadline, 3 shutdown, 4 allocator dead, 255 unknown"},
        })),
    )
}

/// A behaviour's episode report ([`LearningStats`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LearningJson {
    pub stamp: StampJson,
    pub episode_return: Num,
    pub gain: [Num; 2],
    pub actor_updates: u64,
    pub steps: u32,
    pub failed: bool,
    pub learning: bool,
    #[serde(default)]
    pub evaluation: bool,
    #[serde(default)]
    pub rolled_back: bool,
    #[serde(default)]
    pub bounded: u64,
    #[serde(default)]
    pub refused: u64,
    #[serde(default)]
    pub rollbacks: u64,
    #[serde(default = "no_number")]
    pub evaluated: Num,
    #[serde(default = "no_number")]
    pub best_evaluated: Num,
}

/// A number a record of an older format does not hold.
fn no_number() -> Num {
    Num(f64::NAN)
}

impl From<&LearningStats> for LearningJson {
    fn from(s: &LearningStats) -> Self {
        LearningJson {
            stamp: (&s.stamp).into(),
            episode_return: Num(s.episode_return),
            gain: [Num(s.gain[0]), Num(s.gain[1])],
            actor_updates: s.actor_updates,
            steps: s.steps,
            failed: s.failed != 0,
            learning: s.learning != 0,
            evaluation: s.evaluation != 0,
            rolled_back: s.rolled_back != 0,
            bounded: s.bounded,
            refused: s.refused,
            rollbacks: s.rollbacks,
            evaluated: Num(s.evaluated),
            best_evaluated: Num(s.best_evaluated),
        }
    }
}

impl From<&LearningJson> for LearningStats {
    fn from(j: &LearningJson) -> Self {
        LearningStats {
            stamp: (&j.stamp).into(),
            episode_return: j.episode_return.0,
            gain: [j.gain[0].0, j.gain[1].0],
            actor_updates: j.actor_updates,
            steps: j.steps,
            failed: j.failed as u8,
            learning: j.learning as u8,
            evaluation: j.evaluation as u8,
            rolled_back: j.rolled_back as u8,
            bounded: j.bounded,
            refused: j.refused,
            rollbacks: j.rollbacks,
            evaluated: j.evaluated.0,
            best_evaluated: j.best_evaluated.0,
        }
    }
}

pub fn learning_schema() -> Value {
    document(
        "cabletrack.LearningStats",
        "A behaviour's report at the end of each episode.",
        object_schema(json!({
            "stamp": stamp_schema(),
            "episode_return": num_schema("the sum of the behaviour's rewards over the episode"),
            "gain": {"type": "array", "items": num_schema("K for (position, rate)"), "minItems": 2, "maxItems": 2},
            "actor_updates": int_schema("actor updates since the learner started"),
            "steps": int_schema("transitions in the episode"),
            "failed": {"type": "boolean", "description": "the episode ended with the cable lost"},
            "learning": {"type": "boolean", "description": "learning (false: acting only)"},
            "evaluation": {"type": "boolean", "description": "an evaluation trial of step two (acting without learning)"},
            "rolled_back": {"type": "boolean", "description": "this trial closed an evaluation that restored the best policy"},
            "bounded": int_schema("actor updates shortened by the trust region so far"),
            "refused": int_schema("actor updates refused by the stability guard so far"),
            "rollbacks": int_schema("policies replaced by the best one so far"),
            "evaluated": num_schema("the mean return of the evaluation this trial closed (null: none)"),
            "best_evaluated": num_schema("the best evaluated mean return so far (null: none yet)"),
        })),
    )
}

/// One of the supervisor's events ([`SupervisorEvent`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EventJson {
    pub seq: u64,
    pub wall_time_ns: u64,
    pub kind: String,
    pub service: String,
    pub pid: u32,
    pub status: i32,
    pub restarts: u32,
    pub detail: u32,
}

impl From<&SupervisorEvent> for EventJson {
    fn from(e: &SupervisorEvent) -> Self {
        EventJson {
            seq: e.seq,
            wall_time_ns: e.wall_time_ns,
            kind: e
                .kind()
                .map_or_else(|| format!("unknown-{}", e.kind), |k| k.name().to_owned()),
            service: e.service(),
            pid: e.pid,
            status: e.status,
            restarts: e.restarts,
            detail: e.detail,
        }
    }
}

impl From<&EventJson> for SupervisorEvent {
    fn from(j: &EventJson) -> Self {
        let kind = [
            ServiceEvent::Started,
            ServiceEvent::Exited,
            ServiceEvent::Restarting,
            ServiceEvent::Stopped,
        ]
        .into_iter()
        .find(|k| k.name() == j.kind);
        let mut e = SupervisorEvent::new(
            j.seq,
            j.wall_time_ns,
            kind.unwrap_or(ServiceEvent::Started),
            &j.service,
        );
        if kind.is_none() {
            e.kind = j
                .kind
                .strip_prefix("unknown-")
                .and_then(|n| n.parse().ok())
                .unwrap_or(0);
        }
        e.pid = j.pid;
        e.status = j.status;
        e.restarts = j.restarts;
        e.detail = j.detail;
        e
    }
}

pub fn event_schema() -> Value {
    document(
        "cabletrack.SupervisorEvent",
        "What happened to a service of the mesh. Logged at the mesh time of the last step recorded before it; its own time is the wall clock.",
        object_schema(json!({
            "seq": int_schema("events count from 1 in a supervisor's run"),
            "wall_time_ns": int_schema("ns since the Unix epoch"),
            "kind": {"type": "string", "description": "started, exited, restarting or stopped"},
            "service": {"type": "string"},
            "pid": int_schema("the service's process"),
            "status": {"type": "integer", "description": "exited/stopped: the exit code, or minus the signal"},
            "restarts": int_schema("restarts of the service so far"),
            "detail": int_schema("restarting: the delay before the restart (ms); stopped: 1 if it had to be killed"),
        })),
    )
}

/// The recorder's progress ([`RecorderStatus`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct StatusJson {
    pub seq: u64,
    pub wall_time_ns: u64,
    pub messages: u64,
    pub flushed_messages: u64,
    pub bytes: u64,
    pub holes: u64,
    pub repeats: u64,
    pub part: u32,
}

impl From<&RecorderStatus> for StatusJson {
    fn from(s: &RecorderStatus) -> Self {
        StatusJson {
            seq: s.seq,
            wall_time_ns: s.wall_time_ns,
            messages: s.messages,
            flushed_messages: s.flushed_messages,
            bytes: s.bytes,
            holes: s.holes,
            repeats: s.repeats,
            part: s.part,
        }
    }
}

impl From<&StatusJson> for RecorderStatus {
    fn from(j: &StatusJson) -> Self {
        RecorderStatus {
            seq: j.seq,
            wall_time_ns: j.wall_time_ns,
            messages: j.messages,
            flushed_messages: j.flushed_messages,
            bytes: j.bytes,
            holes: j.holes,
            repeats: j.repeats,
            part: j.part,
            _reserved: 0,
        }
    }
}

pub fn status_schema() -> Value {
    document(
        "cabletrack.RecorderStatus",
        "The flight recorder's progress after a flush. Logged at the mesh time of the last step recorded.",
        object_schema(json!({
            "seq": int_schema("reports count from 1"),
            "wall_time_ns": int_schema("ns since the Unix epoch"),
            "messages": int_schema("messages written so far"),
            "flushed_messages": int_schema("messages in complete chunks on disk"),
            "bytes": int_schema("bytes written so far, every part"),
            "holes": int_schema("steps a topic missed while others had them"),
            "repeats": int_schema("re-sent messages not written again"),
            "part": int_schema("the part being written (0: the file named)"),
        })),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use messages::StepStatus;

    /// Every key of `value` is a property of `schema` and every required property is there, down
    /// through nested objects and arrays: the schema describes what is written.
    fn conforms(value: &Value, schema: &Value, path: &str) {
        match value {
            Value::Object(map) => {
                let props = schema["properties"]
                    .as_object()
                    .unwrap_or_else(|| panic!("{path}: the schema has no properties"));
                for (k, v) in map {
                    let sub = props
                        .get(k)
                        .unwrap_or_else(|| panic!("{path}.{k}: not in the schema"));
                    conforms(v, sub, &format!("{path}.{k}"));
                }
                for r in schema["required"].as_array().into_iter().flatten() {
                    assert!(map.contains_key(r.as_str().unwrap()), "{path}.{r}: missing");
                }
            }
            Value::Array(items) => {
                for (i, v) in items.iter().enumerate() {
                    conforms(v, &schema["items"], &format!("{path}[{i}]"));
                }
            }
            Value::Number(n) => {
                let types = schema["type"].to_string();
                let integer = n.is_u64() || n.is_i64();
                assert!(
                    types.contains("number") || (integer && types.contains("integer")),
                    "{path}: {n} is not a {types}"
                );
            }
            Value::Bool(_) => assert_eq!(schema["type"], "boolean", "{path}"),
            Value::String(_) => assert_eq!(schema["type"], "string", "{path}"),
            Value::Null => assert!(schema["type"].to_string().contains("null"), "{path}"),
        }
    }

    fn stamp() -> Stamp {
        Stamp::new(
            1_700_000_000_123_456,
            9_400_000_000,
            3,
            47,
            StepStatus::Lost,
        )
    }

    fn obs() -> CableObservationData {
        CableObservationData {
            found: 1,
            rho: -12.25,
            theta: 0.1 + 0.2,
            x_g: -1.0 / 3.0,
            y_g: 1e-300,
            x_g_rate: f64::MIN_POSITIVE,
            theta_rate: -0.0,
            confidence: 0.875,
            ..Default::default()
        }
    }

    /// Writes `msg` as JSON, checks it against `schema`, reads it back: the same bytes.
    fn round_trip<P, J>(msg: &P, schema: &Value)
    where
        P: PartialEq + std::fmt::Debug,
        J: Serialize + for<'de> Deserialize<'de> + for<'a> From<&'a P>,
        for<'a> P: From<&'a J>,
    {
        let text = serde_json::to_string(&J::from(msg)).unwrap();
        conforms(&serde_json::from_str(&text).unwrap(), schema, "$");
        let back: J = serde_json::from_str(&text).unwrap();
        assert_eq!(&P::from(&back), msg, "{text}");
    }

    #[test]
    fn every_form_conforms_to_its_schema_and_reads_back_exactly() {
        let stamp = stamp();
        round_trip::<_, VehicleStateJson>(
            &VehicleStateMsg {
                stamp,
                x: 1.5,
                y: -0.1,
                psi: std::f64::consts::PI,
                u: 0.3,
                v: 1e-17,
                r: -2.5e-3,
                x_rate: 0.30000000000000004,
                y_rate: 0.0,
                psi_rate: 7.0,
            },
            &vehicle_state_schema(),
        );
        round_trip::<_, FrameHeaderJson>(
            &CameraFrameHeader {
                stamp,
                width: 320,
                height: 240,
                truth: obs(),
                ..Default::default()
            },
            &frame_header_schema(),
        );
        round_trip::<_, FrameHeaderJson>(
            &CameraFrameHeader {
                stamp,
                width: 320,
                height: 240,
                flags: CameraFrameHeader::DAMAGED,
                truth: obs(),
                ..Default::default()
            },
            &frame_header_schema(),
        );
        round_trip::<_, CableObservationJson>(
            &CableObservationMsg {
                stamp,
                observation: obs(),
            },
            &observation_msg_schema(),
        );
        round_trip::<_, CommandJson>(
            &DofCommand {
                stamp,
                value: -0.7071067811865475,
            },
            &command_schema(),
        );
        let mut values = [0.0; MAX_THRUSTERS];
        values[..3].copy_from_slice(&[0.61, -1.0, 1.0 / 7.0]);
        round_trip::<_, SetpointsJson>(
            &ThrusterSetpoints {
                stamp,
                count: 3,
                missing: 0b101,
                stop: 2,
                _reserved: 0,
                values,
                scale: 0.9,
            },
            &setpoints_schema(),
        );
        round_trip::<_, LearningJson>(
            &LearningStats {
                stamp,
                episode_return: -11.57,
                gain: [4.65, -6.54],
                actor_updates: 12,
                steps: 450,
                failed: 1,
                learning: 1,
                evaluation: 0,
                rolled_back: 1,
                bounded: 3,
                refused: 1,
                rollbacks: 2,
                evaluated: -9.25,
                best_evaluated: -8.5,
            },
            &learning_schema(),
        );
        let mut event = SupervisorEvent::new(
            4,
            1_763_781_234_567_890_123,
            ServiceEvent::Stopped,
            "camera",
        );
        event.pid = 4242;
        event.status = -9;
        event.restarts = 2;
        event.detail = 1;
        round_trip::<_, EventJson>(&event, &event_schema());
        round_trip::<_, StatusJson>(
            &RecorderStatus {
                seq: 2,
                wall_time_ns: 5,
                messages: 100,
                flushed_messages: 90,
                bytes: 1 << 20,
                holes: 1,
                repeats: 3,
                part: 1,
                _reserved: 0,
            },
            &status_schema(),
        );
    }

    #[test]
    fn a_number_that_is_not_finite_is_written_as_null_and_read_as_nan() {
        let c = DofCommand {
            stamp: stamp(),
            value: f64::INFINITY,
        };
        let text = serde_json::to_string(&CommandJson::from(&c)).unwrap();
        assert!(text.contains("\"value\":null"), "{text}");
        conforms(
            &serde_json::from_str(&text).unwrap(),
            &command_schema(),
            "$",
        );
        let back: CommandJson = serde_json::from_str(&text).unwrap();
        assert!(DofCommand::from(&back).value.is_nan());
    }
}
