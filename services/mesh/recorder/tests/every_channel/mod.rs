//! A short synthetic record with a message on every channel, and what a reader of the file sees of
//! it: per channel its topic, encodings, schema name, the property paths of its JSON Schema with their
//! types, and its first message decoded. The reader's view is the record's contract with the outside
//! (Foxglove, Lichtblick, scripts): `reader_view.rs` keeps it in a fixture, `outside_reader.rs` reads
//! the same record with the MCAP project's own Python reader.

#![allow(dead_code)]

use messages::{
    CableObservationData, CableObservationMsg, CameraFrameHeader, DofCommand, LearningStats,
    ServiceEvent, Stamp, StepStatus, SupervisorEvent, ThrusterSetpoints, VehicleStateMsg,
};
use recorder::{CommandDof, FlightRecorder, Options, Recorded};
use serde_json::{Value, json};
use std::collections::BTreeMap;
use std::path::Path;

pub const W: u32 = 8;
pub const H: u32 = 6;
pub const STEPS: u64 = 3;

fn stamp(k: u64) -> Stamp {
    Stamp::new(
        40 + k,
        1_000_000_000 + k * 200_000_000,
        2,
        k as u32,
        if k + 1 == STEPS {
            StepStatus::Lost
        } else {
            StepStatus::Running
        },
    )
    .timed(7, 5_000_000_123 + k as i64)
}

/// Numbers that test the exact round trip: not short in decimal, tiny, negative zero, and one
/// that is not finite (written as `null`).
fn observation(k: u64) -> CableObservationData {
    CableObservationData {
        found: (k != 1) as u8,
        rho: -12.25 + k as f64,
        theta: 0.1 + 0.2,
        x_g: -1.0 / 3.0,
        y_g: 1e-300,
        x_g_rate: f64::MIN_POSITIVE,
        theta_rate: -0.0,
        confidence: if k == 2 { f64::NAN } else { 0.875 },
        ..Default::default()
    }
}

/// The messages of step `k` as the mesh publishes them.
pub struct Step {
    pub state: VehicleStateMsg,
    pub header: CameraFrameHeader,
    pub image: Vec<u8>,
    pub observation: CableObservationMsg,
    pub commands: [DofCommand; 3],
    pub setpoints: ThrusterSetpoints,
}

pub fn step(k: u64) -> Step {
    let stamp = stamp(k);
    let mut values = [0.0; config::MAX_THRUSTERS];
    values[..3].copy_from_slice(&[0.61, -1.0, 1.0 / 7.0]);
    Step {
        state: VehicleStateMsg {
            stamp,
            x: 1.5 + k as f64,
            y: -0.1,
            psi: std::f64::consts::PI,
            u: 0.3,
            v: 1e-17,
            r: -2.5e-3,
            x_rate: 0.30000000000000004,
            y_rate: f64::INFINITY,
            psi_rate: 7.0,
        },
        header: CameraFrameHeader {
            stamp,
            width: W,
            height: H,
            flags: CameraFrameHeader::DAMAGED * (k % 2) as u32,
            _reserved: [0; 4],
            truth: observation(k),
        },
        image: (0..W * H).map(|i| (i as u64 * 37 + k * 11) as u8).collect(),
        observation: CableObservationMsg {
            stamp,
            observation: observation(k),
        },
        commands: [0.9, -0.7071067811865475, 1e-9].map(|value| DofCommand { stamp, value }),
        setpoints: ThrusterSetpoints {
            stamp,
            count: 3,
            missing: 0b101,
            values,
            scale: 0.9,
            ..Default::default()
        },
    }
}

pub fn learning(dof: config::Dof) -> LearningStats {
    LearningStats {
        stamp: stamp(STEPS - 1),
        episode_return: -11.57,
        gain: [4.65, -6.54 * (dof == config::Dof::Yaw) as u8 as f64],
        actor_updates: 12,
        steps: STEPS as u32 - 1,
        failed: 1,
        learning: 1,
        evaluation: 0,
        rolled_back: 1,
        bounded: 3,
        refused: 1,
        rollbacks: 2,
        evaluated: f64::NAN,
        best_evaluated: -8.5,
    }
}

pub fn event() -> SupervisorEvent {
    SupervisorEvent {
        pid: 4242,
        status: -9,
        restarts: 2,
        detail: 1,
        ..SupervisorEvent::new(
            4,
            1_763_781_234_567_890_123,
            ServiceEvent::Stopped,
            "sway-behaviour",
        )
    }
}

/// Writes the synthetic record at `path`: every channel, the image of every step.
pub fn write(path: &Path) {
    let mut rec = FlightRecorder::create(
        Options::new(path),
        BTreeMap::from([("seed".into(), "3".into())]),
    )
    .unwrap();
    for k in 0..STEPS {
        let s = step(k);
        rec.log(&Recorded::State(s.state));
        rec.frame(&s.header, &s.image);
        rec.log(&Recorded::Observation(s.observation));
        for (dof, c) in CommandDof::ALL.into_iter().zip(s.commands) {
            rec.log(&Recorded::Command(dof, c));
        }
        rec.log(&Recorded::Setpoints(s.setpoints));
    }
    for dof in config::Dof::ALL {
        rec.log(&Recorded::Learning(dof, learning(dof)));
    }
    rec.log(&Recorded::Event(event()));
    rec.status();
    rec.close().unwrap();
}

/// The property paths of a JSON Schema with their types (`a.b`, `a.c[]`), following `$ref`s into
/// `$defs`; a property not listed in `required` is marked `optional`.
pub fn property_paths(schema: &Value) -> BTreeMap<String, String> {
    fn resolve<'a>(root: &'a Value, s: &'a Value) -> &'a Value {
        match s.get("$ref").and_then(Value::as_str) {
            Some(r) => {
                let name = r.rsplit('/').next().unwrap_or(r);
                resolve(root, &root["$defs"][name])
            }
            None => s,
        }
    }
    fn types(s: &Value) -> String {
        let mut t: Vec<String> = match &s["type"] {
            Value::String(t) => vec![t.clone()],
            Value::Array(ts) => ts
                .iter()
                .filter_map(Value::as_str)
                .map(Into::into)
                .collect(),
            _ => vec!["?".into()],
        };
        t.sort();
        t.join("|")
    }
    fn walk(root: &Value, s: &Value, prefix: &str, out: &mut BTreeMap<String, String>) {
        let s = resolve(root, s);
        if let Some(props) = s["properties"].as_object() {
            let required: Vec<&str> = s["required"]
                .as_array()
                .into_iter()
                .flatten()
                .filter_map(Value::as_str)
                .collect();
            for (k, sub) in props {
                let path = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                let sub = resolve(root, sub);
                let mut t = types(sub);
                if !required.contains(&k.as_str()) {
                    t.push_str(" optional");
                }
                out.insert(path.clone(), t);
                walk(root, sub, &path, out);
            }
        }
        if let Some(items) = s.get("items") {
            let path = format!("{prefix}[]");
            let items = resolve(root, items);
            out.insert(path.clone(), types(items));
            walk(root, items, &path, out);
        }
    }
    let mut out = BTreeMap::new();
    walk(schema, schema, "", &mut out);
    out
}

/// What a reader sees of the record at `path` (read with the `mcap` crate, not our reader): per
/// topic, its encodings, its schema's name and property paths, and its first message with its log
/// time. The recorder's status carries the wall clock and the file's size: those two are masked.
pub fn reader_view(path: &Path) -> Value {
    let bytes = std::fs::read(path).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().expect("a summary");
    let mut first: BTreeMap<String, (u64, Vec<u8>)> = BTreeMap::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        first
            .entry(m.channel.topic.clone())
            .or_insert((m.log_time, m.data.into_owned()));
    }
    let mut view = serde_json::Map::new();
    for ch in summary.channels.values() {
        let schema = ch.schema.as_ref().expect("every channel has a schema");
        let (log_time, data) = &first[&ch.topic];
        let mut entry = json!({
            "message_encoding": ch.message_encoding,
            "schema_name": schema.name,
            "schema_encoding": schema.encoding,
            "log_time": log_time,
        });
        if schema.encoding == "jsonschema" {
            let s: Value = serde_json::from_slice(&schema.data).unwrap();
            entry["schema_dialect"] = s["$schema"].clone();
            entry["schema_title"] = s["title"].clone();
            entry["properties"] = json!(property_paths(&s));
            let mut message: Value = serde_json::from_slice(data).unwrap();
            if ch.topic == "/recorder/status" {
                message["wall_time_ns"] = json!("<wall clock>");
                message["bytes"] = json!("<file size>");
            }
            entry["message"] = message;
        } else {
            use prost::Message as _;
            entry["message"] = match schema.name.as_str() {
                "foxglove.RawImage" => {
                    let m = foxglove::messages::RawImage::decode(&data[..]).unwrap();
                    json!({
                        "timestamp": m.timestamp.map(|t| (t.sec(), t.nsec())),
                        "frame_id": m.frame_id,
                        "width": m.width,
                        "height": m.height,
                        "encoding": m.encoding,
                        "step": m.step,
                        "data": m.data.to_vec(),
                    })
                }
                "foxglove.ImageAnnotations" => {
                    let m = foxglove::messages::ImageAnnotations::decode(&data[..]).unwrap();
                    json!(format!("{m:?}"))
                }
                other => panic!("{}: unexpected protobuf schema {other}", ch.topic),
            };
        }
        view.insert(ch.topic.clone(), entry);
    }
    Value::Object(view)
}
