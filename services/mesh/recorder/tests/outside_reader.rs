//! A flight record read by a reader that shares no code with ours: the MCAP project's Python package
//! (`scripts/install-mcap-py` puts it, its protobuf support and a JSON Schema validator in
//! target/mcap-venv). It lists the channels and schemas, decodes every message, and validates every
//! JSON message against the JSON Schema its channel carries.

use crate::every_channel;

use every_channel::{H, STEPS, W};
use serde_json::{Value, json};
use std::path::{Path, PathBuf};
use std::time::Duration;

fn python() -> PathBuf {
    testkit::venv_python("MCAP_VENV", "mcap-venv", "scripts/install-mcap-py")
}

/// What the Python reader made of the record at `record`.
fn read_with_python(record: &Path, dir: &Path) -> Value {
    let out = dir.join("python.json");
    let log = dir.join("python.log");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/read_with_mcap.py");
    let mut child = runtime::process::Spawn::new(python())
        .arg(&script)
        .arg(record)
        .arg(&out)
        .log(&log)
        .die_with_parent()
        .start()
        .expect("python starts");
    let status = child
        .wait_timeout(Duration::from_secs(120))
        .unwrap_or_else(|| {
            panic!(
                "the Python reader did not finish in 120 s:\n{}",
                child.log()
            )
        });
    assert!(
        status.success(),
        "the Python reader failed:\n{}",
        child.log()
    );
    serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap()
}

fn values<'a>(read: &'a Value, topic: &str) -> Vec<&'a Value> {
    read["messages"][topic]
        .as_array()
        .unwrap_or_else(|| panic!("no messages on {topic}"))
        .iter()
        .map(|m| &m["value"])
        .collect()
}

#[test]
fn the_mcap_python_reader_lists_decodes_and_validates_every_channel() {
    let dir = tempfile::tempdir().unwrap();
    let record = dir.path().join("every-channel.mcap");
    every_channel::write(&record);
    let read = read_with_python(&record, dir.path());

    // The channels and their schemas, as the file's summary lists them.
    let channels = read["channels"].as_object().unwrap();
    let steps = STEPS as i64;
    let want = [
        ("/vehicle_state", "cabletrack.VehicleState", steps),
        (
            "/camera_frame/header",
            "cabletrack.CameraFrameHeader",
            steps,
        ),
        ("/camera_frame", "foxglove.RawImage", steps),
        ("/cable_observation", "cabletrack.CableObservation", steps),
        (
            "/cable_observation/overlay",
            "foxglove.ImageAnnotations",
            steps,
        ),
        ("/command/surge", "cabletrack.DofCommand", steps),
        ("/command/sway", "cabletrack.DofCommand", steps),
        ("/command/yaw", "cabletrack.DofCommand", steps),
        ("/thruster_setpoints", "cabletrack.ThrusterSetpoints", steps),
        ("/learning/sway", "cabletrack.LearningStats", 1),
        ("/learning/yaw", "cabletrack.LearningStats", 1),
        ("/supervisor/events", "cabletrack.SupervisorEvent", 1),
        ("/recorder/status", "cabletrack.RecorderStatus", 1),
    ];
    assert_eq!(channels.len(), want.len(), "{channels:#?}");
    for (topic, schema, count) in want {
        let c = &channels[topic];
        let (encoding, schema_encoding) = if schema.starts_with("foxglove.") {
            ("protobuf", "protobuf")
        } else {
            ("json", "jsonschema")
        };
        assert_eq!(
            c,
            &json!({"message_encoding": encoding, "schema_name": schema,
                    "schema_encoding": schema_encoding, "count": count}),
            "{topic}"
        );
        assert_eq!(
            read["messages"][topic].as_array().map(Vec::len),
            Some(count as usize),
            "{topic}"
        );
    }

    // Every JSON message conforms to its channel's schema, and the validator is not vacuous.
    assert_eq!(read["invalid"], json!([]), "messages against their schemas");
    let json_messages: i64 = want
        .iter()
        .filter(|w| w.1.starts_with("cabletrack."))
        .map(|w| w.2)
        .sum();
    assert_eq!(read["validated"], json!(json_messages));
    assert_eq!(read["tampered_rejected"], json!(true));

    // The numbers read back exactly (Python parses and prints the shortest exact form), a number
    // that is not finite is null, fixed arrays hold their used part, names are strings.
    for (k, state) in values(&read, "/vehicle_state").into_iter().enumerate() {
        let s = every_channel::step(k as u64).state;
        assert_eq!(state["stamp"]["seq"], json!(s.stamp.seq));
        assert_eq!(state["stamp"]["clock_ns"], json!(s.stamp.clock_ns));
        assert_eq!(state["x"].as_f64().map(f64::to_bits), Some(s.x.to_bits()));
        assert_eq!(state["v"].as_f64().map(f64::to_bits), Some(s.v.to_bits()));
        assert_eq!(state["y_rate"], Value::Null, "infinity");
    }
    for (k, o) in values(&read, "/cable_observation").into_iter().enumerate() {
        let want = every_channel::step(k as u64).observation.observation;
        let o = &o["observation"];
        assert_eq!(o["found"], json!(want.found != 0));
        assert_eq!(
            o["x_g"].as_f64().map(f64::to_bits),
            Some(want.x_g.to_bits())
        );
        assert_eq!(
            o["theta_rate"].as_f64().map(f64::to_bits),
            Some((-0.0f64).to_bits())
        );
        assert_eq!(
            o["confidence"].as_f64(),
            Some(want.confidence).filter(|c| c.is_finite())
        );
    }
    for s in values(&read, "/thruster_setpoints") {
        assert_eq!(s["values"], json!([0.61, -1.0, 1.0 / 7.0]));
        assert_eq!((&s["missing"], &s["stop"]), (&json!(5), &json!(0)));
    }
    let event = values(&read, "/supervisor/events")[0];
    assert_eq!(
        (&event["kind"], &event["service"], &event["status"]),
        (&json!("stopped"), &json!("sway-behaviour"), &json!(-9))
    );
    let learning = values(&read, "/learning/yaw")[0];
    assert_eq!(learning["gain"], json!([4.65, -6.54]));
    assert_eq!(learning["evaluated"], Value::Null);
    assert_eq!(learning["failed"], json!(true));

    // The images, decoded from the protobuf schema the file carries.
    for (k, image) in values(&read, "/camera_frame").into_iter().enumerate() {
        let s = every_channel::step(k as u64);
        assert_eq!(
            (&image["width"], &image["height"], &image["encoding"]),
            (&json!(W), &json!(H), &json!("mono8"))
        );
        assert_eq!(image["data"], json!(s.image));
        let t = s.header.stamp.time_ns;
        assert_eq!(
            image["timestamp"],
            json!([t / 1_000_000_000, t % 1_000_000_000])
        );
    }
    let overlays = values(&read, "/cable_observation/overlay");
    assert!(
        overlays
            .iter()
            .all(|o| o["timestamps"].as_array().is_some()),
        "{overlays:?}"
    );
}

/// What the Python reader made of each file (`read_cut_records.py`): per file, its messages'
/// sequence numbers or its error.
fn read_cut_records(files: &[PathBuf], dir: &Path) -> serde_json::Map<String, Value> {
    let out = dir.join("cut-records.json");
    let log = dir.join("cut-records.log");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/read_cut_records.py");
    let mut child = runtime::process::Spawn::new(python())
        .arg(&script)
        .arg(&out)
        .args(files)
        .log(&log)
        .die_with_parent()
        .start()
        .expect("python starts");
    let status = child
        .wait_timeout(Duration::from_secs(120))
        .unwrap_or_else(|| {
            panic!(
                "the Python reader did not finish in 120 s:\n{}",
                child.log()
            )
        });
    assert!(
        status.success(),
        "the Python reader failed:\n{}",
        child.log()
    );
    match serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap() {
        Value::Object(m) => m,
        other => panic!("{other}"),
    }
}

#[test]
fn a_record_cut_at_every_step_of_its_writing_opens_in_the_python_reader_up_to_its_last_commit() {
    use std::collections::BTreeMap;
    let dir = tempfile::tempdir().unwrap();
    let (sealed, journal) = recorder::seal::SealedFile::journaled(&dir.path().join("dive.mcap"));
    let file = sealed.shared();
    let mut w = recorder::writer::mcap_options(4096, 1)
        .create(sealed)
        .unwrap();
    let schema = w
        .add_schema("cabletrack.Test", "jsonschema", b"{}")
        .unwrap();
    let channel = w
        .add_channel(schema, "/test", "json", &BTreeMap::new())
        .unwrap();
    w.flush().unwrap();
    let mut visible = vec![0u64];
    let mut seq = 0u32;
    for _ in 0..5 {
        for _ in 0..60 {
            seq += 1;
            let data = format!(
                "{{\"seq\":{seq},\"x\":\"{}\"}}",
                "ab".repeat(seq as usize % 50)
            );
            let header = mcap::records::MessageHeader {
                channel_id: channel,
                sequence: seq,
                log_time: u64::from(seq),
                publish_time: u64::from(seq),
            };
            w.write_to_known_channel(&header, data.as_bytes()).unwrap();
        }
        w.flush().unwrap();
        visible.push(u64::from(seq));
    }
    file.closing();
    w.finish().unwrap();
    drop(w);

    let states = recorder::seal::crash_states(&journal);
    let cuts = dir.path().join("cuts");
    std::fs::create_dir(&cuts).unwrap();
    let files: Vec<PathBuf> = states
        .iter()
        .filter_map(|(_, s)| s.as_ref())
        .enumerate()
        .map(|(i, bytes)| {
            let path = cuts.join(format!("{i:03}.mcap"));
            std::fs::write(&path, bytes).unwrap();
            path
        })
        .collect();
    assert!(files.len() >= 5 * 6, "{} states", files.len());
    let read = read_cut_records(&files, dir.path());
    let mut last = 0;
    for path in &files {
        let r = &read[&path.display().to_string()];
        assert!(r.get("error").is_none(), "{}: {r}", path.display());
        let n = r["messages"].as_u64().unwrap();
        assert!(
            visible.contains(&n),
            "{}: {n} messages, not a commit's {visible:?}",
            path.display()
        );
        assert!(n >= last, "{}: {n} after {last}", path.display());
        assert_eq!(
            r["sequences"],
            json!((1..=n).collect::<Vec<_>>()),
            "{}",
            path.display()
        );
        last = n;
    }
    assert_eq!(last, u64::from(seq));
    // The closed file has its index, which the reader used.
    let closed = &read[&files.last().unwrap().display().to_string()];
    assert_eq!(closed["summary"], json!(true));
}
