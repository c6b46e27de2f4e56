//! The flight record's file, in one process: what the writer puts in is what an MCAP reader that is
//! not the writer's code path (the `mcap` crate's summary and streaming reader) and our own reader
//! take out; rotation splits it into complete parts; a file cut anywhere reads up to the cut.

use messages::{
    CableObservationData, CableObservationMsg, CameraFrameHeader, DofCommand, LearningStats, Stamp,
    StepStatus, ThrusterSetpoints,
};
use recorder::{Channel, CommandDof, FlightRecorder, Options, Recorded};
use std::collections::BTreeMap;
use std::path::Path;

const W: u32 = 32;
const H: u32 = 24;

/// A step of a made-up dive: distinct images (so chunks do not compress to nothing).
struct Step {
    header: CameraFrameHeader,
    image: Vec<u8>,
    observation: CableObservationMsg,
    commands: [DofCommand; 3],
    setpoints: ThrusterSetpoints,
}

fn step(k: u64) -> Step {
    let stamp = Stamp::new(
        1000 + k,
        k * 200_000_000,
        (k / 50) as u32,
        (k % 50) as u32,
        if k % 50 == 49 {
            StepStatus::TimeLimit
        } else {
            StepStatus::Running
        },
    );
    let mut state = k.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let image = (0..W * H)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 56) as u8
        })
        .collect();
    let observation = CableObservationData {
        found: !k.is_multiple_of(7) as u8,
        rho: 3.0 - k as f64 * 0.01,
        theta: 0.2 * (k as f64 * 0.1).sin(),
        x_g: 0.05 * (k as f64).cos(),
        ..Default::default()
    };
    let mut values = [0.0; config::MAX_THRUSTERS];
    values[..3].copy_from_slice(&[0.5, -0.25 * k as f64 / 100.0, 1.0 / 3.0]);
    Step {
        header: CameraFrameHeader {
            stamp,
            width: W,
            height: H,
            truth: observation,
            ..Default::default()
        },
        image,
        observation: CableObservationMsg { stamp, observation },
        commands: [0.9, -0.1 * (k as f64).sin(), 0.3].map(|value| DofCommand { stamp, value }),
        setpoints: ThrusterSetpoints {
            stamp,
            count: 3,
            missing: 0,
            values,
            scale: 1.0,
            ..Default::default()
        },
    }
}

fn record(rec: &mut FlightRecorder, s: &Step) {
    rec.frame(&s.header, &s.image);
    rec.log(&Recorded::Observation(s.observation));
    for (dof, c) in CommandDof::ALL.into_iter().zip(s.commands) {
        rec.log(&Recorded::Command(dof, c));
    }
    rec.log(&Recorded::Setpoints(s.setpoints));
}

fn write(path: &Path, steps: u64, opts: impl FnOnce(&mut Options)) -> recorder::Totals {
    let mut o = Options::new(path);
    opts(&mut o);
    let mut rec = FlightRecorder::create(o, BTreeMap::from([("seed".into(), "3".into())])).unwrap();
    for k in 0..steps {
        let s = step(k);
        record(&mut rec, &s);
        // A re-send of the step: recorded once.
        rec.log(&Recorded::Setpoints(s.setpoints));
        if k % 50 == 49 {
            rec.log(&Recorded::Learning(
                config::Dof::Yaw,
                LearningStats {
                    stamp: s.header.stamp,
                    episode_return: -1.0 - k as f64,
                    steps: 49,
                    ..Default::default()
                },
            ));
        }
        rec.rotate_if_due().unwrap();
    }
    rec.close().unwrap()
}

#[test]
fn what_is_written_is_what_the_mcap_crate_and_our_reader_read() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("dive.mcap");
    let totals = write(&path, 100, |o| o.frame_every = 5);

    // The mcap crate's summary (the index written at close): channels, schemas, counts.
    let bytes = std::fs::read(&path).unwrap();
    let summary = mcap::Summary::read(&bytes)
        .unwrap()
        .expect("a closed file has a summary");
    let stats = summary.stats.as_ref().expect("statistics");
    let by_topic: BTreeMap<&str, (u64, &str, &str, &str)> = summary
        .channels
        .values()
        .map(|ch| {
            let schema = ch.schema.as_ref().expect("every channel has a schema");
            (
                ch.topic.as_str(),
                (
                    stats.channel_message_counts[&ch.id],
                    schema.name.as_str(),
                    schema.encoding.as_str(),
                    ch.message_encoding.as_str(),
                ),
            )
        })
        .collect();
    let want = BTreeMap::from([
        (
            "/camera_frame/header",
            (100, "cabletrack.CameraFrameHeader", "jsonschema", "json"),
        ),
        // Steps 0, 5, ..., 45 of each of the two episodes.
        (
            "/camera_frame",
            (20, "foxglove.RawImage", "protobuf", "protobuf"),
        ),
        (
            "/cable_observation",
            (100, "cabletrack.CableObservation", "jsonschema", "json"),
        ),
        (
            "/cable_observation/overlay",
            (20, "foxglove.ImageAnnotations", "protobuf", "protobuf"),
        ),
        (
            "/command/surge",
            (100, "cabletrack.DofCommand", "jsonschema", "json"),
        ),
        (
            "/command/sway",
            (100, "cabletrack.DofCommand", "jsonschema", "json"),
        ),
        (
            "/command/yaw",
            (100, "cabletrack.DofCommand", "jsonschema", "json"),
        ),
        (
            "/thruster_setpoints",
            (100, "cabletrack.ThrusterSetpoints", "jsonschema", "json"),
        ),
        (
            "/learning/yaw",
            (2, "cabletrack.LearningStats", "jsonschema", "json"),
        ),
    ]);
    assert_eq!(by_topic, want);
    assert!(
        summary
            .chunk_indexes
            .iter()
            .all(|c| c.compression == "zstd")
    );
    assert_eq!(totals.messages, want.values().map(|v| v.0).sum::<u64>());
    assert_eq!(totals.counts[&Channel::Setpoints].repeats, 100);

    // The mcap crate's streaming reader: the payloads, at the stamp's time.
    let mut headers = 0;
    for m in mcap::io::MessageReader::new(std::io::Cursor::new(&bytes)) {
        let m = m.unwrap();
        if m.channel.topic == "/camera_frame/header" {
            let v: serde_json::Value = serde_json::from_slice(&m.data).unwrap();
            assert_eq!(v["stamp"]["time_ns"].as_u64(), Some(m.log_time));
            assert_eq!(m.log_time, headers * 200_000_000);
            headers += 1;
        }
    }
    assert_eq!(headers, 100);

    // Our reader: the very messages written.
    let mut got = Vec::new();
    let read = recorder::read(&path, |m| got.push(m)).unwrap();
    assert!(read.cut.is_empty() && read.unknown.is_empty());
    let observations: Vec<CableObservationMsg> = got
        .iter()
        .filter_map(|m| match &m.item {
            Recorded::Observation(o) => Some(*o),
            _ => None,
        })
        .collect();
    assert_eq!(
        observations,
        (0..100).map(|k| step(k).observation).collect::<Vec<_>>()
    );
    let images: Vec<(u64, Vec<u8>)> = got
        .iter()
        .filter_map(|m| match &m.item {
            Recorded::Image(i) => Some((i.time_ns, i.data.clone())),
            _ => None,
        })
        .collect();
    let want_images: Vec<(u64, Vec<u8>)> = (0..100)
        .filter(|k| k % 50 % 5 == 0)
        .map(|k| (k * 200_000_000, step(k).image))
        .collect();
    assert_eq!(images, want_images);
    let yaw: Vec<f64> = got
        .iter()
        .filter_map(|m| match &m.item {
            Recorded::Command(CommandDof::Yaw, c) => Some(c.value),
            _ => None,
        })
        .collect();
    assert_eq!(yaw, vec![0.3; 100]);
}

#[test]
fn a_record_rotates_into_complete_parts_and_a_new_run_continues_it() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("dive.mcap");
    // Every frame's image (~0.8 kB); parts of about 40 kB.
    let totals = write(&path, 300, |o| {
        o.rotate_bytes = 40_000;
        o.chunk_bytes = 8_000;
    });
    assert!(totals.parts.len() >= 3, "{:?}", totals.parts);
    let mut headers = 0;
    for part in &totals.parts {
        let bytes = std::fs::read(part).unwrap();
        let summary = mcap::Summary::read(&bytes)
            .unwrap()
            .unwrap_or_else(|| panic!("{} is complete", part.display()));
        // Each part has its own schemas and channels.
        assert!(summary.channels.values().all(|c| c.schema.is_some()));
        let id = summary
            .channels
            .values()
            .find(|c| c.topic == "/camera_frame/header")
            .unwrap()
            .id;
        headers += summary.stats.unwrap().channel_message_counts[&id];
    }
    assert_eq!(headers, 300, "every step in exactly one part");
    let mut seqs = Vec::new();
    let read = recorder::read(&path, |m| {
        if let Recorded::FrameHeader(h) = m.item {
            seqs.push(h.stamp.seq)
        }
    })
    .unwrap();
    assert_eq!(read.parts, totals.parts);
    assert_eq!(seqs, (1000..1300).collect::<Vec<_>>());

    // A second run to the same record (a restarted recorder) continues it with the next part.
    let again = write(&path, 10, |_| {});
    assert_eq!(
        again.parts,
        vec![recorder::part_path(&path, totals.parts.len() as u32)]
    );
}

#[test]
fn a_file_cut_anywhere_reads_in_order_up_to_the_cut() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("dive.mcap");
    write(&path, 200, |o| o.chunk_bytes = 16_000);
    let bytes = std::fs::read(&path).unwrap();
    let mut all = Vec::new();
    recorder::read(&path, |m| all.push(m)).unwrap();
    let cut_path = dir.path().join("cut.mcap");
    let mut previous = 0;
    for permille in [5, 100, 333, 500, 750, 900, 999] {
        let at = bytes.len() * permille / 1000;
        std::fs::write(&cut_path, &bytes[..at]).unwrap();
        assert!(
            mcap::Summary::read(&bytes[..at]).is_err(),
            "a cut file has no index"
        );
        let mut got = Vec::new();
        let read = recorder::read(&cut_path, |m| got.push(m))
            .unwrap_or_else(|e| panic!("cut at {permille}/1000: {e}"));
        assert_eq!(read.cut.len(), 1, "cut at {permille}/1000: reported");
        assert_eq!(read.cut[0].messages, got.len() as u64);
        // A prefix of what was written, exactly, and longer the later the cut.
        assert_eq!(got[..], all[..got.len()], "cut at {permille}/1000");
        assert!(got.len() >= previous, "cut at {permille}/1000");
        previous = got.len();
    }
    assert!(previous > all.len() / 2);
}

/// `recorder::holes` and `recorder::totals` read back the steps the totals say were missed: none for a whole run, the
/// step whose setpoints never came for a run with that hole, and nothing to say for a file with no
/// totals (cut before its close).
#[test]
fn holes_reads_the_missed_steps_from_the_totals() {
    let dir = tempfile::tempdir().unwrap();
    let whole = dir.path().join("whole.mcap");
    let totals = write(&whole, 20, |_| {});
    assert!(totals.counts.values().all(|c| c.holes == 0));
    assert_eq!(recorder::holes(&whole).unwrap(), Some(0));

    let gap = dir.path().join("gap.mcap");
    let mut rec =
        FlightRecorder::create(Options::new(&gap), BTreeMap::new()).expect("a new record");
    for k in 0..20 {
        let s = step(k);
        if k == 10 {
            // Every message of step 10 but its setpoints.
            rec.frame(&s.header, &s.image);
            rec.log(&Recorded::Observation(s.observation));
            for (dof, c) in CommandDof::ALL.into_iter().zip(s.commands) {
                rec.log(&Recorded::Command(dof, c));
            }
        } else {
            record(&mut rec, &s);
        }
    }
    let totals = rec.close().unwrap();
    let want: u64 = totals.counts.values().map(|c| c.holes).sum();
    assert!(want > 0, "{:?}", totals.counts);
    assert_eq!(recorder::holes(&gap).unwrap(), Some(want));
    // Per channel, as the recorder counted them: the setpoints' one hole among 19 written.
    let read = recorder::totals(&gap)
        .unwrap()
        .expect("the totals of a closed record");
    assert_eq!(read.len(), totals.counts.len());
    for (c, n) in &totals.counts {
        assert_eq!(read[c.topic()], *n, "{c:?}");
    }
    let setpoints = read[recorder::Channel::Setpoints.topic()];
    assert_eq!((setpoints.written, setpoints.holes), (19, 1));

    let bytes = std::fs::read(&whole).unwrap();
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    assert!(matches!(recorder::holes(&cut), Ok(None) | Err(_)));
    assert!(recorder::holes(&dir.path().join("none.mcap")).is_err());
}
