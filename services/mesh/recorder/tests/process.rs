//! The recorder as a process: a short sim-mesh run recorded through the real supervisor and read back
//! with the `mcap` crate (not the writer's code path: its index and its streaming reader), every
//! step on every channel; a recording cut by SIGKILL readable up to its last complete chunk; the
//! live view seen by a real WebSocket client.

use mcap::records::Record;
use messages::{
    CableObservationData, CableObservationMsg, CameraFrameHeader, Endpoint, Stamp, StepStatus,
    ThrusterSetpoints, topics,
};
use std::collections::BTreeMap;
use std::path::Path;
use std::time::{Duration, Instant};
use testkit::{Namespace, Process};

const T: Duration = Duration::from_secs(60);

fn scenario() -> config::Scenario {
    config::load(&testkit::config_dir().join("scenario.toml")).unwrap()
}

/// The recorder's `recorder` metadata record (its totals at close), by topic.
fn totals(bytes: &[u8], summary: &mcap::Summary) -> BTreeMap<String, String> {
    summary
        .metadata_indexes
        .iter()
        .filter(|i| i.name == "recorder")
        .map(|i| mcap::read::metadata(bytes, i).unwrap().metadata)
        .next()
        .expect("the recorder's totals")
}

#[test]
fn a_recorded_sim_mesh_run_holds_every_step_on_every_channel() {
    let ns = Namespace::new("rsim");
    let dir = tempfile::tempdir().unwrap();
    let record = dir.path().join("sim.mcap");
    let json = dir.path().join("run.json");
    let frame_every = 10u32;
    let mut supervisor = testkit::supervisor(
        &ns,
        &testkit::config_dir().join("sim-mesh.toml"),
        2,
        &[
            ("episodes", "3".into()),
            ("eyes", "images".into()),
            ("json", json.display().to_string()),
            ("state", dir.path().join("state").display().to_string()),
            ("record", record.display().to_string()),
            ("frame_every", frame_every.to_string()),
        ],
    );
    let status = supervisor
        .wait(T)
        .unwrap_or_else(|| panic!("the mesh did not finish in {T:?}:\n{}", supervisor.log()));
    assert!(status.success(), "{}", supervisor.log());
    let run: records::RunRecord =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(run.episodes, 3);
    // Every episode's published steps: its transitions and its terminal step.
    let steps: u64 = run.episode_steps.iter().map(|&s| s as u64 + 1).sum();
    let imaged: u64 = run
        .episode_steps
        .iter()
        .map(|&s| (0..=s).filter(|k| k % frame_every == 0).count() as u64)
        .sum();

    let bytes = std::fs::read(&record).unwrap();
    let summary = mcap::Summary::read(&bytes)
        .unwrap()
        .expect("a cleanly stopped recorder leaves an index");
    let counts = &summary.stats.as_ref().unwrap().channel_message_counts;
    let channels: BTreeMap<&str, (&str, &str, u64)> = summary
        .channels
        .values()
        .map(|c| {
            let s = c.schema.as_ref().expect("a schema per channel");
            (
                c.topic.as_str(),
                (s.name.as_str(), s.encoding.as_str(), counts[&c.id]),
            )
        })
        .collect();
    let per_step = |schema| (schema, "jsonschema", steps);
    let want = BTreeMap::from([
        ("/vehicle_state", per_step("cabletrack.VehicleState")),
        (
            "/camera_frame/header",
            per_step("cabletrack.CameraFrameHeader"),
        ),
        ("/camera_frame", ("foxglove.RawImage", "protobuf", imaged)),
        (
            "/cable_observation",
            per_step("cabletrack.CableObservation"),
        ),
        (
            "/cable_observation/overlay",
            ("foxglove.ImageAnnotations", "protobuf", imaged),
        ),
        ("/command/surge", per_step("cabletrack.DofCommand")),
        ("/command/sway", per_step("cabletrack.DofCommand")),
        ("/command/yaw", per_step("cabletrack.DofCommand")),
        (
            "/thruster_setpoints",
            per_step("cabletrack.ThrusterSetpoints"),
        ),
        (
            "/learning/sway",
            ("cabletrack.LearningStats", "jsonschema", 3),
        ),
        (
            "/learning/yaw",
            ("cabletrack.LearningStats", "jsonschema", 3),
        ),
    ]);
    for (topic, w) in &want {
        assert_eq!(channels.get(topic), Some(w), "{topic}: {channels:#?}");
    }
    let events = channels
        .get("/supervisor/events")
        .expect("the supervisor's events");
    assert_eq!(events.0, "cabletrack.SupervisorEvent");
    let t = totals(&bytes, &summary);
    assert!(
        t.iter()
            .filter(|(k, _)| k.starts_with('/'))
            .all(|(_, v)| v.contains("holes 0")),
        "no step missed: {t:?}"
    );

    // The streaming reader: the steps in order, each at its stamp's time; the services' starts.
    let mut seqs = Vec::new();
    let mut started = Vec::new();
    for m in mcap::io::MessageReader::new(std::io::Cursor::new(&bytes)) {
        let m = m.unwrap();
        let v: serde_json::Value = match m.channel.message_encoding.as_str() {
            "json" => serde_json::from_slice(&m.data).unwrap(),
            _ => continue,
        };
        match m.channel.topic.as_str() {
            "/cable_observation" => {
                assert_eq!(v["stamp"]["time_ns"].as_u64(), Some(m.log_time));
                seqs.push(v["stamp"]["seq"].as_u64().unwrap());
            }
            "/supervisor/events" if v["kind"] == "started" => {
                started.push(v["service"].as_str().unwrap().to_owned())
            }
            _ => {}
        }
    }
    assert_eq!(
        seqs,
        (1..=steps).collect::<Vec<_>>(),
        "every step, once, in order"
    );
    started.sort();
    assert_eq!(
        started,
        [
            "camera",
            "monitor",
            "perception",
            "recorder",
            "simulator",
            "surge-controller",
            "sway-behaviour",
            "thruster-allocator",
            "yaw-behaviour"
        ]
    );
    assert!(ns.leftovers().is_empty(), "{:?}", ns.leftovers());
}

/// Publishes a made-up step on the frame, observation and setpoint topics (the setpoints wake the
/// recorder).
struct Stepper {
    frames: messages::FrameOutbox,
    observations: messages::Outbox<CableObservationMsg>,
    setpoints: messages::Outbox<ThrusterSetpoints>,
    seq: u64,
    width: u32,
    height: u32,
}

impl Stepper {
    fn new(probe: &testkit::Probe) -> Stepper {
        let c = scenario().camera;
        Stepper {
            frames: probe.frame_outbox((c.width * c.height) as usize),
            observations: probe.outbox(&topics::CABLE_OBSERVATION),
            setpoints: probe.outbox(&topics::THRUSTER_SETPOINTS),
            seq: 0,
            width: c.width,
            height: c.height,
        }
    }

    fn step(&mut self) {
        self.seq += 1;
        let k = self.seq;
        let stamp = Stamp::new(k, k * 200_000_000, 0, k as u32, StepStatus::Running);
        let header = CameraFrameHeader {
            stamp,
            width: self.width,
            height: self.height,
            ..Default::default()
        };
        let len = (self.width * self.height) as usize;
        self.frames
            .send_with(header, len, |img| {
                for (i, p) in img.iter_mut().enumerate() {
                    *p = ((i as u64 * 31 + k * 7) % 251) as u8;
                }
                Ok::<_, std::convert::Infallible>(())
            })
            .unwrap()
            .unwrap();
        self.observations
            .send(CableObservationMsg {
                stamp,
                observation: CableObservationData {
                    found: 1,
                    rho: 10.0,
                    theta: 0.1,
                    x_g: 0.03,
                    ..Default::default()
                },
            })
            .unwrap();
        self.setpoints
            .send(ThrusterSetpoints {
                stamp,
                count: 3,
                ..Default::default()
            })
            .unwrap();
    }
}

/// Messages in the complete chunks of `bytes`, counted record by record (the `mcap` crate's linear
/// reader and chunk reader, not the message reader under test).
fn messages_in_complete_chunks(bytes: &[u8]) -> (u64, u64) {
    let (mut chunks, mut messages) = (0, 0);
    for record in mcap::read::LinearReader::new(bytes).unwrap() {
        let Ok(Record::Chunk { header, data }) = record else {
            if record.is_err() {
                break;
            }
            continue;
        };
        chunks += 1;
        for inner in mcap::read::ChunkReader::new(header, &data).unwrap() {
            if let Record::Message { .. } = inner.unwrap() {
                messages += 1;
            }
        }
    }
    (chunks, messages)
}

#[test]
fn a_recording_cut_by_sigkill_reads_up_to_its_last_complete_chunk() {
    let ns = Namespace::new("rkil");
    let dir = tempfile::tempdir().unwrap();
    let record = dir.path().join("dive.mcap");
    let probe = testkit::probe(&ns, Endpoint::Vehicle);
    let status = probe.inbox(&topics::RECORDER_STATUS);
    let mut stepper = Stepper::new(&probe);
    let mut recorder = Process::start(
        &ns,
        &testkit::binary("recorder"),
        &[
            "--endpoint",
            "vehicle",
            "--out",
            &record.display().to_string(),
            "--flush-ms",
            "50",
            "--chunk-kb",
            "256",
        ],
    );
    // Steps until two flushes have put a few hundred messages in complete chunks, then more steps
    // into the open chunk, then the kill.
    let end = Instant::now() + T;
    let mut flushed = 0;
    let mut reports = 0;
    while flushed < 300 || reports < 2 {
        assert!(
            Instant::now() < end,
            "no flush reported:\n{}",
            recorder.log()
        );
        for _ in 0..20 {
            stepper.step();
        }
        if let Some(s) = probe.wait_for(&status, Duration::from_millis(200), |_| true) {
            flushed = s.flushed_messages;
            reports += 1;
        }
    }
    for _ in 0..10 {
        stepper.step();
    }
    recorder.kill9();

    let bytes = std::fs::read(&record).unwrap();
    assert!(
        matches!(mcap::Summary::read(&bytes), Ok(None)),
        "a killed recorder writes no index, but its file ends in a footer"
    );
    let (chunks, in_chunks) = messages_in_complete_chunks(&bytes);
    let mut yielded = 0u64;
    let mut end_error = None;
    for m in mcap::io::MessageReader::new(std::io::Cursor::new(&bytes)) {
        match m {
            Ok(m) => {
                if m.channel.message_encoding == "json" {
                    serde_json::from_slice::<serde_json::Value>(&m.data).unwrap();
                }
                yielded += 1;
            }
            Err(e) => {
                end_error = Some(e);
                break;
            }
        }
    }
    println!(
        "{chunks} complete chunks, {in_chunks} messages in them; {yielded} read; {flushed} reported flushed; ended by {end_error:?}"
    );
    assert!(chunks >= 2, "{chunks} complete chunks");
    assert!(
        end_error.is_none(),
        "the file is read to its end without an error: {end_error:?}"
    );
    assert!(
        yielded == in_chunks && in_chunks >= flushed,
        "every chunk is read ({yielded} of {in_chunks}), and every flushed message is in one ({flushed})"
    );
    // Our reader says the same and that the part was cut.
    let read = recorder::read(&record, |_| {}).unwrap();
    assert_eq!(read.messages, yielded);
    assert_eq!(read.cut.len(), 1);
}

/// A free port on this machine's loopback (the recorder is given it; nothing else takes it between).
fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

#[test]
fn the_live_view_serves_frames_and_the_estimate_over_them_to_a_websocket_client() {
    use tungstenite::client::IntoClientRequest;
    use tungstenite::{Message, http::HeaderValue};

    let ns = Namespace::new("rlive");
    let dir = tempfile::tempdir().unwrap();
    let probe = testkit::probe(&ns, Endpoint::Sim);
    let status = probe.inbox(&topics::RECORDER_STATUS);
    let port = free_port();
    let recorder = Process::start(
        &ns,
        &testkit::binary("recorder"),
        &[
            "--out",
            &dir.path().join("live.mcap").display().to_string(),
            &format!("--live=127.0.0.1:{port}"),
            "--flush-ms",
            "50",
        ],
    );
    let mut stepper = Stepper::new(&probe);
    // The server is up before the recorder's first report.
    stepper.step();
    probe
        .wait_for(&status, T, |_| true)
        .unwrap_or_else(|| panic!("the recorder never reported:\n{}", recorder.log()));

    let connect = |protocol: &str| {
        let mut req = format!("ws://127.0.0.1:{port}")
            .into_client_request()
            .unwrap();
        req.headers_mut().insert(
            "Sec-WebSocket-Protocol",
            HeaderValue::from_str(protocol).unwrap(),
        );
        tungstenite::connect(req)
    };
    let (mut ws, response) = connect("foxglove.sdk.v1").expect("the live view accepts a client");
    assert_eq!(
        response.headers()["sec-websocket-protocol"],
        "foxglove.sdk.v1"
    );
    if let tungstenite::stream::MaybeTlsStream::Plain(tcp) = ws.get_ref() {
        tcp.set_read_timeout(Some(Duration::from_millis(100)))
            .unwrap();
    }

    // The advertised channels: topic -> (id, schema).
    let mut advertised: BTreeMap<String, (u64, String)> = BTreeMap::new();
    let mut subscribed = false;
    let (mut image, mut overlay) = (None, None);
    let end = Instant::now() + T;
    while image.is_none() || overlay.is_none() {
        assert!(
            Instant::now() < end,
            "no frame and overlay received; advertised {advertised:?}\n{}",
            recorder.log()
        );
        // The live view has no history: keep the mesh going while waiting.
        stepper.step();
        let msg = match ws.read() {
            Ok(m) => m,
            Err(tungstenite::Error::Io(e))
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                continue;
            }
            Err(e) => panic!("the connection failed: {e}"),
        };
        match msg {
            Message::Text(text) => {
                let v: serde_json::Value = serde_json::from_str(&text).unwrap();
                if v["op"] == "advertise" {
                    for c in v["channels"].as_array().unwrap() {
                        advertised.insert(
                            c["topic"].as_str().unwrap().to_owned(),
                            (
                                c["id"].as_u64().unwrap(),
                                c["schemaName"].as_str().unwrap().to_owned(),
                            ),
                        );
                    }
                }
                let wanted = ["/camera_frame", "/cable_observation/overlay"];
                if !subscribed && wanted.iter().all(|t| advertised.contains_key(*t)) {
                    let subs: Vec<serde_json::Value> = wanted
                        .iter()
                        .enumerate()
                        .map(|(i, t)| serde_json::json!({"id": i, "channelId": advertised[*t].0}))
                        .collect();
                    let sub = serde_json::json!({"op": "subscribe", "subscriptions": subs});
                    ws.send(Message::Text(sub.to_string().into())).unwrap();
                    subscribed = true;
                }
            }
            // MessageData: opcode 1, subscription id, log time, payload.
            Message::Binary(b) if b.first() == Some(&1) => {
                let sub = u32::from_le_bytes(b[1..5].try_into().unwrap());
                let log_time = u64::from_le_bytes(b[5..13].try_into().unwrap());
                let payload = &b[13..];
                match sub {
                    0 => {
                        image = Some((
                            log_time,
                            <foxglove::messages::RawImage as prost::Message>::decode(payload)
                                .unwrap(),
                        ))
                    }
                    _ => {
                        overlay = Some((
                            log_time,
                            <foxglove::messages::ImageAnnotations as prost::Message>::decode(
                                payload,
                            )
                            .unwrap(),
                        ))
                    }
                }
            }
            _ => {}
        }
    }
    assert_eq!(advertised["/camera_frame"].1, "foxglove.RawImage");
    assert_eq!(
        advertised["/cable_observation/overlay"].1,
        "foxglove.ImageAnnotations"
    );
    assert!(advertised.contains_key("/thruster_setpoints"));
    let (t, image) = image.unwrap();
    let c = scenario().camera;
    assert_eq!(
        (image.width, image.height, image.encoding.as_str()),
        (c.width, c.height, "mono8")
    );
    assert_eq!(image.data.len(), (c.width * c.height) as usize);
    assert_eq!(
        image.timestamp.map(|ts| ts.total_nanos()),
        Some(t),
        "log time = the stamp's time"
    );
    let (_, overlay) = overlay.unwrap();
    assert_eq!(overlay.points[0].points.len(), 2, "the cable's line");
    // The old protocol name is refused: viewers that only speak it (older Lichtblick) cannot connect.
    assert!(connect("foxglove.websocket.v1").is_err());
    drop(ws);
    assert!(Path::new(&dir.path().join("live.mcap")).exists());
}
