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
//!   frames of the dive; the same record written again without one unit keeps the images of the
//!   frames up to the next keyframe, and replays every frame of the dive;
//! - in a second dive, a record that keeps no image beside its stream (`--video-frame-every 0`)
//!   holds none (but of a frame the twin sent again: which copy the camera published, the stream
//!   does not say), and replay's frames of it are the frames of the dive, from the stream;
//! - a recorder started in the middle of that dive, between two keyframes, keeps the images of the
//!   frames before the first keyframe it records (its stream cannot give them), none after, and
//!   replay's frames of its record are those of the dive from where it started.
//!
//! Needs the camera and the twin built with `--features video` and the recorder (CI builds them
//! before this test), the Python reader (`scripts/install-mcap-py`) and GStreamer
//! (`scripts/install-gstreamer`).
#![cfg(feature = "video")]

use adapters::twin::TwinThrusterSink;
use adapters::{Stamp, ThrusterSink};
use messages::{CameraFrameHeader, Endpoint, FrameInbox, VideoUnit, topics};
use recorder::Recorded;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};
use testkit::{Namespace, Probe, Process};
use video::h264::{self, nal};

const T: Duration = Duration::from_secs(60);
/// Frames of the dive: three keyframes at the twin's default of one every 10 frames.
const STEPS: usize = 25;
/// The frames answered before the late recorder starts (between the first two keyframes).
const LATE: usize = 3;

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
/// records, in the order asked for.
struct Dive {
    _dir: tempfile::TempDir,
    records: Vec<PathBuf>,
    live: Vec<(u64, u32)>,
}

/// A recorder of the dive: its file's name, its `--video-frame-every`, and the frame before which
/// it starts (0: before the stream). At most two: the recorder's status topic takes two publishers.
struct Recording {
    name: &'static str,
    video_frame_every: &'static str,
    from: usize,
}

fn record_a_dive(recordings: &[Recording]) -> Dive {
    let ns = Namespace::new("rpvid");
    let dir = tempfile::tempdir().unwrap();
    let records: Vec<PathBuf> = recordings
        .iter()
        .map(|r| dir.path().join(format!("{}.mcap", r.name)))
        .collect();
    let probe = testkit::probe(&ns, Endpoint::Vehicle);
    let frames = probe.frame_inbox();
    let status = probe.inbox(&topics::RECORDER_STATUS);
    let mut sink = TwinThrusterSink::open(probe.node(), 3).unwrap();
    let mut recorders = Vec::new();
    // A recorder started, once subscribed (its first status comes after its subscriptions are
    // open; the others' first statuses were read before).
    let start = |k: usize, recorders: &mut Vec<Process>| {
        for (r, out) in recordings.iter().zip(&records).filter(|(r, _)| r.from == k) {
            recorders.push(Process::start(
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
                    r.video_frame_every,
                ],
            ));
            probe
                .wait_for(&status, T, |s| s.seq == 1)
                .unwrap_or_else(|| panic!("{}'s first status", r.name));
        }
    };
    // Subscribed before the stream starts (a unit published before is not kept for them).
    start(0, &mut recorders);
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
        if k > 0 {
            // In the middle of the dive: the twin waits for this step's answer meanwhile.
            start(k, &mut recorders);
        }
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
        records,
        live,
    }
}

#[test]
fn the_recorded_stream_is_read_by_outside_tools_and_replays_the_live_frames() {
    // Every image, and every 4th once the stream is there.
    let dive = record_a_dive(&[
        Recording {
            name: "dive",
            video_frame_every: "1",
            from: 0,
        },
        Recording {
            name: "sparse",
            video_frame_every: "4",
            from: 0,
        },
    ]);
    let (record, sparse) = (&dive.records[0], &dive.records[1]);

    // What the record holds, read by our reader.
    let mut units: Vec<VideoUnit> = Vec::new();
    let mut data: Vec<Vec<u8>> = Vec::new();
    let mut images = BTreeMap::new();
    recorder::read(record, |m| match m.item {
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
    let json = record.with_extension("json");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../recorder/tests/read_with_mcap.py");
    let out = Command::new("timeout")
        .arg("120")
        .arg(python())
        .arg(&script)
        .arg(record)
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

    // Replay's decoding of the record: the frames of the dive, bit for bit (the first picture of a
    // frame's time unless the source sent the frame again before the camera read it).
    let mut frames = replay::video::VideoFrames::open(record, 320, 240).unwrap();
    let resent = resent(&units);
    for &(time_ns, live) in &dive.live {
        let d = frames
            .frame_at(time_ns)
            .unwrap()
            .unwrap_or_else(|| panic!("no picture of the frame at {time_ns} ns"));
        let pictures: Vec<u32> = std::iter::once(&d.image)
            .chain(&d.again)
            .map(|p| hash(p))
            .collect();
        assert_eq!(pictures.len() > 1, resent.contains(&time_ns));
        if pictures[0] != live {
            assert!(
                pictures.contains(&live),
                "the frame at {time_ns} ns, sent {} times",
                pictures.len()
            );
        }
        assert_eq!(
            images.get(&time_ns),
            Some(&live),
            "the record's image at {time_ns} ns"
        );
    }

    // A record keeping every 4th image replays every frame from its stream, each image kept
    // checked against its decoding.
    let mut sparse = replay::Frames::open(sparse).unwrap();
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

    // A unit missing from a record that keeps no image beside its stream (the recorder's buffer
    // overflowed): the record written again by the recorder's writer without the unit two after
    // the second keyframe. The images from its frame to the next keyframe's are kept, and replay
    // takes them rather than the decoder's pictures, which lack the missing unit's reference.
    let second_key = units
        .iter()
        .filter(|u| u.is_keyframe())
        .nth(1)
        .expect("a second keyframe");
    let missing = second_key.number + 2;
    let next_key = units
        .iter()
        .find(|u| u.is_keyframe() && u.number > missing)
        .expect("a keyframe after the missing unit")
        .number;
    let gap = record.with_file_name("gap.mcap");
    write_without_unit(record, &gap, missing);
    let (_, kept) = units_and_images(&gap);
    let not_decodable: BTreeSet<u64> = units
        .iter()
        .filter(|u| (missing..next_key).contains(&u.number))
        .map(|u| u.time_ns)
        .collect();
    let others = only_resent(&kept, &not_decodable, &resent);
    let (replayed, frames) = replay_frames(&gap);
    assert!(replayed.len() >= STEPS, "{} frames", replayed.len());
    assert_eq!(replayed[..STEPS], dive.live[..]);
    assert_eq!(
        (frames.from_stream, frames.checked, frames.undecodable),
        (
            (replayed.len() - not_decodable.len()) as u64,
            others as u64,
            0
        )
    );
}

/// The times of the frames the source sent more than once (several units of one time).
fn resent(units: &[VideoUnit]) -> BTreeSet<u64> {
    let mut seen = BTreeSet::new();
    units
        .iter()
        .filter(|u| !seen.insert(u.time_ns))
        .map(|u| u.time_ns)
        .collect()
}

/// Checks that the images a record keeps beside its stream are those of `expected`, and others
/// only of frames the source sent again (then the stream does not say which copy the camera
/// published); returns how many others.
fn only_resent(kept: &[u64], expected: &BTreeSet<u64>, resent: &BTreeSet<u64>) -> usize {
    let kept: BTreeSet<u64> = kept.iter().copied().collect();
    assert!(
        kept.is_superset(expected),
        "images kept {kept:?}, expected {expected:?}"
    );
    let others: Vec<u64> = kept.difference(expected).copied().collect();
    assert!(
        others.iter().all(|t| resent.contains(t)),
        "images of frames the stream gives: {others:?} (sent again: {resent:?})"
    );
    others.len()
}

/// `record` written again by the recorder's writer, every unit but `missing`, keeping no image of
/// the frames its stream gives.
fn write_without_unit(record: &Path, out: &Path, missing: u64) {
    let mut opts = recorder::Options::new(out);
    opts.video_frame_every = 0;
    let mut rec = recorder::FlightRecorder::create(opts, BTreeMap::new()).unwrap();
    let (mut unit, mut header) = (None, None);
    recorder::read(record, |m| match m.item {
        Recorded::VideoHeader(h) => unit = Some(h),
        Recorded::Video(v) => {
            let h: VideoUnit = unit.take().expect("a unit's header before it");
            if h.number != missing {
                rec.video(&h, &v.data);
            }
        }
        Recorded::FrameHeader(h) => header = Some(h),
        Recorded::Image(i) => {
            let h: CameraFrameHeader = header.take().expect("an image's header before it");
            assert_eq!(h.stamp.time_ns, i.time_ns);
            rec.frame(&h, &i.data);
        }
        _ => {}
    })
    .unwrap();
    rec.close().unwrap();
}

/// The frames of a record, replayed (time, hash of the image), with the counts of where they came
/// from.
fn replay_frames(record: &Path) -> (Vec<(u64, u32)>, replay::Frames) {
    let mut frames = replay::Frames::open(record).unwrap();
    let mut replayed = Vec::new();
    while let Some(f) = frames.next_frame().unwrap() {
        replayed.push((f.header.stamp.time_ns, hash(&f.image)));
    }
    (replayed, frames)
}

/// What a record holds of the camera: its units (in order) and the times of its images.
fn units_and_images(record: &Path) -> (Vec<VideoUnit>, Vec<u64>) {
    let (mut units, mut images) = (Vec::new(), Vec::new());
    recorder::read(record, |m| match m.item {
        Recorded::VideoHeader(h) => units.push(h),
        Recorded::Image(i) => images.push(i.time_ns),
        _ => {}
    })
    .unwrap();
    (units, images)
}

#[test]
fn a_record_without_images_beside_its_stream_replays_every_frame_of_the_dive() {
    // No image beside the stream: a recorder started with it, and one between two keyframes.
    let dive = record_a_dive(&[
        Recording {
            name: "none",
            video_frame_every: "0",
            from: 0,
        },
        Recording {
            name: "late",
            video_frame_every: "0",
            from: LATE,
        },
    ]);
    let (none, late) = (&dive.records[0], &dive.records[1]);

    // Started with the stream: no image at all, every frame replayed from the stream.
    let (units, images) = units_and_images(none);
    assert!(units.len() >= STEPS && units[0].is_keyframe());
    let others = only_resent(&images, &BTreeSet::new(), &resent(&units));
    let (replayed, frames) = replay_frames(none);
    assert!(replayed.len() >= STEPS, "{} frames", replayed.len());
    assert_eq!(replayed[..STEPS], dive.live[..]);
    assert_eq!(
        (frames.from_stream, frames.checked, frames.undecodable),
        (replayed.len() as u64, others as u64, 0)
    );

    // Started between two keyframes: the images up to its first keyframe, none after; every frame
    // it has is the dive's.
    let (units, images) = units_and_images(late);
    let first_key = units
        .iter()
        .find(|u| u.is_keyframe())
        .expect("a keyframe in the late record")
        .time_ns;
    assert!(
        !units[0].is_keyframe(),
        "the late record starts between keyframes"
    );
    let (replayed, frames) = replay_frames(late);
    let start = dive
        .live
        .iter()
        .position(|f| *f == replayed[0])
        .expect("the late record's first frame is a frame of the dive");
    assert!(start >= 1, "the late record starts at frame {start}");
    let frames_of_the_dive = &dive.live[start..];
    assert_eq!(replayed[..frames_of_the_dive.len()], frames_of_the_dive[..]);
    let before_key: BTreeSet<u64> = replayed
        .iter()
        .map(|f| f.0)
        .filter(|&t| t < first_key)
        .collect();
    assert!(!before_key.is_empty());
    let others = only_resent(&images, &before_key, &resent(&units));
    assert_eq!(frames.checked, others as u64);
    assert_eq!(frames.undecodable, 0);
    assert_eq!(
        frames.from_stream,
        (replayed.len() - before_key.len()) as u64,
        "every frame from its first keyframe on from the stream"
    );
}

fn hex(s: &str) -> Vec<u8> {
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}
