//! The camera's compressed stream in the flight record, end to end: the vehicle twin streams
//! RTP/H.264 (`vehicle-twin --video`, x264), the camera decodes it (`camera --source rtp:...`) and
//! publishes its access units beside its frames, the recorder writes both; the test answers each
//! frame as the mesh would. Then:
//!
//! - the MCAP project's Python reader (`mcap`, `mcap-protobuf-support`) finds `/camera_video` with
//!   the `foxglove.CompressedVideo` schema in protobuf, one access unit a message, `h264`, every
//!   keyframe with its SPS and PPS;
//! - GStreamer's decoder (`avdec_h264`) decodes the units Python read into one whole picture
//!   each, at the stream's size;
//! - replay's decoding of the record (`replay::video`, the camera's pipeline fed from the record)
//!   gives every frame the mesh received live, byte for byte (the probe's copies and the images
//!   the record keeps), and replay's frames of a record that keeps only every 4th image are the
//!   frames of the dive.
//!
//! Needs the camera and the twin built with `--features video` and the recorder (CI builds them
//! before this test), the Python reader (`scripts/install-mcap-py`) and GStreamer
//! (`scripts/install-gstreamer`).
#![cfg(feature = "video")]

use adapters::twin::TwinThrusterSink;
use adapters::{Stamp, ThrusterSink};
use messages::{CameraFrameHeader, Endpoint, FrameInbox, VideoUnit, topics};
use recorder::Recorded;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};
use testkit::{Namespace, Probe, Process};
use video::h264::{self, nal};

const T: Duration = Duration::from_secs(60);
/// Frames of the dive: three keyframes at the twin's default of one every 10 frames.
const STEPS: usize = 25;

fn python() -> PathBuf {
    testkit::venv_python("MCAP_VENV", "mcap-venv", "scripts/install-mcap-py")
}

/// A free UDP port on loopback (taken from the kernel, released for the camera to bind).
fn free_port() -> u16 {
    testkit::free_udp_port()
}

fn next_frame(probe: &Probe, frames: &FrameInbox, after: u64) -> (CameraFrameHeader, Vec<u8>) {
    let end = Instant::now() + T;
    loop {
        while let Some((h, image)) = frames.receive_with(|h, d| (*h, d.to_vec())).unwrap() {
            if h.stamp.seq > after {
                return (h, image);
            }
        }
        let left = end
            .checked_duration_since(Instant::now())
            .expect("a frame from the camera in time");
        probe.block_on(frames.listener(), left);
    }
}

fn hash(bytes: &[u8]) -> u32 {
    crc32fast::hash(bytes)
}

/// A recorded dive: the frames the probe received live (time, hash of the image), and the
/// records.
struct Dive {
    _dir: tempfile::TempDir,
    record: PathBuf,
    sparse: PathBuf,
    live: Vec<(u64, u32)>,
}

fn record_a_dive() -> Dive {
    let ns = Namespace::new("rpvid");
    let dir = tempfile::tempdir().unwrap();
    let record = dir.path().join("dive.mcap");
    let sparse = dir.path().join("sparse.mcap");
    let probe = testkit::probe(&ns, Endpoint::Vehicle);
    let frames = probe.frame_inbox();
    let status = probe.inbox(&topics::RECORDER_STATUS);
    let mut sink = TwinThrusterSink::open(probe.node(), 3).unwrap();
    // Two recorders: every image, and every 4th once the stream is there.
    let recorder = |out: &Path, every: &str| {
        Process::start(
            &ns,
            &testkit::binary("recorder"),
            &[
                "--endpoint",
                "vehicle",
                "--out",
                &out.display().to_string(),
                "--flush-ms",
                "100",
                "--video-frame-every",
                every,
            ],
        )
    };
    let mut recorders = [recorder(&record, "1"), recorder(&sparse, "4")];
    // Both subscribed before the stream starts (a unit published before is not kept for them):
    // each one's first status comes after its subscriptions are open.
    for _ in 0..2 {
        probe
            .wait_for(&status, T, |s| s.seq == 1)
            .expect("each recorder's first status");
    }
    let port = free_port();
    let rtp = format!("rtp:127.0.0.1:{port}");
    let mut camera = Process::start(
        &ns,
        &testkit::binary("camera"),
        &["--endpoint", "vehicle", "--source", &rtp],
    );
    let mut twin = Process::start(
        &ns,
        &testkit::binary("vehicle-twin"),
        &[
            "--endpoint",
            "vehicle",
            "--seed",
            "6",
            "--lockstep",
            "--video",
            &rtp,
            "--video-size",
            "1280x720",
        ],
    );
    let mut live = Vec::new();
    let mut last = 0;
    for k in 0..STEPS {
        let (h, image) = next_frame(&probe, &frames, last);
        last = h.stamp.seq;
        assert_eq!(image.len(), 320 * 240, "step {k}");
        live.push((h.stamp.time_ns, hash(&image)));
        let s = &h.stamp;
        sink.write(
            &Stamp::new(9, s.time_ns, s.episode, s.step, s.status()),
            &[0.4, 0.0, 0.0],
        )
        .unwrap();
    }
    assert!(twin.terminate(T).success(), "{}", twin.log());
    assert!(camera.terminate(T).success(), "{}", camera.log());
    for r in &mut recorders {
        assert!(r.terminate(T).success(), "{}", r.log());
    }
    Dive {
        _dir: dir,
        record,
        sparse,
        live,
    }
}

#[test]
fn the_recorded_stream_is_read_by_outside_tools_and_replays_the_live_frames() {
    let dive = record_a_dive();

    // What the record holds, read by our reader.
    let mut units: Vec<VideoUnit> = Vec::new();
    let mut data: Vec<Vec<u8>> = Vec::new();
    let mut images = BTreeMap::new();
    recorder::read(&dive.record, |m| match m.item {
        Recorded::VideoHeader(h) => units.push(h),
        Recorded::Video(v) => {
            assert_eq!(v.time_ns, units.last().unwrap().time_ns);
            data.push(v.data)
        }
        Recorded::Image(i) => {
            images.insert(i.time_ns, hash(&i.data));
        }
        _ => {}
    })
    .unwrap();
    assert_eq!(units.len(), data.len());
    assert!(units.len() >= STEPS, "{} units", units.len());
    assert!(units.windows(2).all(|w| w[1].number > w[0].number));
    assert!(
        units[0].is_keyframe(),
        "the record's stream starts at a keyframe"
    );
    assert!(units.iter().all(|u| u.flags & VideoUnit::DAMAGED == 0));

    // The Python reader: the channel, its schema, each unit.
    let json = dive.record.with_extension("json");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../recorder/tests/read_with_mcap.py");
    let out = Command::new("timeout")
        .arg("120")
        .arg(python())
        .arg(&script)
        .arg(&dive.record)
        .arg(&json)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let read: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let channel = &read["channels"]["/camera_video"];
    assert_eq!(channel["schema_name"], "foxglove.CompressedVideo");
    assert_eq!(channel["schema_encoding"], "protobuf");
    assert_eq!(channel["message_encoding"], "protobuf");
    assert_eq!(channel["count"], units.len() as u64);
    assert_eq!(
        read["channels"]["/camera_video/header"]["schema_name"],
        "cabletrack.VideoUnit"
    );
    assert_eq!(read["invalid"].as_array().map(Vec::len), Some(0));
    let messages = read["messages"]["/camera_video"].as_array().unwrap();
    assert_eq!(messages.len(), units.len());
    let mut python_units = Vec::new();
    let mut keyframes = 0;
    for (m, unit) in messages.iter().zip(&units) {
        let v = &m["value"];
        assert_eq!(
            (v["format"].as_str(), v["frame_id"].as_str()),
            (Some("h264"), Some("camera"))
        );
        let t = &v["timestamp"];
        let ns = t[0].as_u64().unwrap() * 1_000_000_000 + t[1].as_u64().unwrap();
        assert_eq!(ns, unit.time_ns);
        assert_eq!(m["log_time"].as_u64(), Some(unit.time_ns));
        let au = hex(v["data_hex"].as_str().unwrap());
        assert!(
            au.starts_with(&[0, 0, 0, 1]) || au.starts_with(&[0, 0, 1]),
            "Annex B"
        );
        let types = h264::nal_types(&au);
        // A picture's first slice starts at macroblock 0 (first_mb_in_slice, ue(v): the bit 1).
        let pictures = h264::nal_units(&au)
            .filter(|u| matches!(h264::nal_type(u[0]), nal::IDR | nal::SLICE))
            .filter(|u| u.get(1).is_some_and(|b| b & 0x80 != 0))
            .count();
        assert_eq!(pictures, 1, "one picture a message: {types:?}");
        if types.contains(&nal::IDR) {
            keyframes += 1;
            assert!(unit.is_keyframe());
            assert!(
                types.contains(&nal::SPS) && types.contains(&nal::PPS),
                "a keyframe carries its SPS and PPS: {types:?}"
            );
        }
        python_units.push(au);
    }
    assert!(keyframes >= 3, "{keyframes} keyframes");

    // GStreamer's decoder (avdec_h264) on the units as Python read them: a whole picture for each
    // unit, at the stream's own size (h264parse, which would split a plain file, is in
    // plugins-bad, which the project does not install).
    let mut gst = video::decode::StreamDecoder::start(
        1280,
        720,
        python_units
            .into_iter()
            .enumerate()
            .map(|(k, au)| (k as u64 + 1, au))
            .collect::<Vec<_>>(),
    )
    .unwrap();
    let mut pictures = 0u64;
    while let Some(p) = gst.next(T).unwrap() {
        pictures += 1;
        assert_eq!(p.key, pictures, "a picture for each unit, in order");
        assert!(!p.corrupted && p.image.len() == 1280 * 720);
    }
    assert_eq!(pictures, units.len() as u64);

    // Replay's decoding of the record: the frames of the dive, bit for bit.
    let mut frames = replay::video::VideoFrames::open(&dive.record, 320, 240).unwrap();
    for &(time_ns, live) in &dive.live {
        let d = frames
            .frame_at(time_ns)
            .unwrap()
            .unwrap_or_else(|| panic!("no picture of the frame at {time_ns} ns"));
        assert_eq!(hash(&d.image), live, "the frame at {time_ns} ns");
        assert_eq!(
            images.get(&time_ns),
            Some(&live),
            "the record's image at {time_ns} ns"
        );
    }

    // A record keeping every 4th image replays every frame from its stream, each image kept
    // checked against its decoding.
    let mut sparse = replay::Frames::open(&dive.sparse).unwrap();
    let mut replayed = Vec::new();
    while let Some(f) = sparse.next_frame().unwrap() {
        replayed.push((f.header.stamp.time_ns, hash(&f.image)));
    }
    // The camera may have published one frame more than the test answered before it stopped.
    assert!(replayed.len() >= STEPS, "{} frames", replayed.len());
    assert_eq!(replayed[..STEPS], dive.live[..]);
    assert_eq!(sparse.from_stream, replayed.len() as u64);
    assert!(
        sparse.checked >= 2 && sparse.checked < STEPS as u64 / 2,
        "{} images kept",
        sparse.checked
    );
}

fn hex(s: &str) -> Vec<u8> {
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}
