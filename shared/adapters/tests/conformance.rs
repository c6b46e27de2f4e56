//! Every frame source and every thruster sink passes the same conformance suite
//! (`adapters::conformance`). The twin's adapters run over real iceoryx2 topics, each test in its own
//! namespace (testkit), with the twin's side of the wire played by the test.

use adapters::conformance::{self, Arrived, SinkRig, SourceRig, sample_frames};
use adapters::record::{NullSink, RecordSink, read_record};
use adapters::replay::{DiveWriter, ImageFormat, Pacing, ReplaySource};
use adapters::twin::{TwinCameraPort, TwinFrameSource, TwinThrusterPort, TwinThrusterSink};
use adapters::{AdapterError, Frame, FrameMeta, Stamp, StepStatus};
use messages::{CameraFrameHeader, Endpoint};
use std::path::{Path, PathBuf};
use testkit::{Namespace, Probe};

// ---------------------------------------------------------------- frame sources

/// The twin's camera, with the test publishing as the twin.
struct TwinSourceRig {
    _ns: Namespace,
    probe: Probe,
    port: Option<TwinCameraPort>,
    frames: Vec<Frame>,
}

impl TwinSourceRig {
    fn new() -> Self {
        let ns = Namespace::new("adts");
        let probe = testkit::probe(&ns, Endpoint::Vehicle);
        TwinSourceRig {
            _ns: ns,
            probe,
            port: None,
            frames: Vec::new(),
        }
    }

    /// A fresh source and twin camera (a new publisher has no history to replay).
    fn fresh(&mut self) -> Result<TwinFrameSource, AdapterError> {
        self.port = None;
        let source = TwinFrameSource::open(self.probe.node(), 40, 30)?;
        self.port = Some(TwinCameraPort::open(self.probe.node(), 40 * 30)?);
        Ok(source)
    }

    fn send(&self, frame: &Frame) {
        self.port
            .as_ref()
            .unwrap()
            .send(&frame.meta, |image| image.copy_from_slice(&frame.image))
            .unwrap();
    }

    fn send_raw(&self, header: CameraFrameHeader, len: usize) {
        self.port
            .as_ref()
            .unwrap()
            .send_raw(header, len, |_| Ok::<_, ()>(()))
            .unwrap()
            .unwrap();
    }
}

const TWIN_BAD: [&str; 4] = [
    "an unknown status",
    "an image shorter than its size",
    "a frame of another size",
    "an empty frame",
];

impl SourceRig for TwinSourceRig {
    type Source = TwinFrameSource;

    fn name(&self) -> String {
        "twin frame source".into()
    }

    fn live(&self) -> bool {
        true
    }

    fn speed(&self) -> Option<f64> {
        None
    }

    fn open(&mut self, frames: &[Frame]) -> Result<TwinFrameSource, AdapterError> {
        self.frames = frames.to_vec();
        self.fresh()
    }

    fn deliver(&mut self, k: usize) {
        self.send(&self.frames[k].clone());
    }

    fn bad_inputs(&self) -> Vec<String> {
        TWIN_BAD.iter().map(|s| s.to_string()).collect()
    }

    fn open_bad(&mut self, k: usize) -> Result<TwinFrameSource, AdapterError> {
        let source = self.fresh()?;
        let good = sample_frames(40, 30).remove(0);
        let mut h = adapters::twin::header(&good.meta);
        match k {
            0 => {
                h.stamp.status = 9;
                self.send_raw(h, 40 * 30);
            }
            1 => self.send_raw(h, 100),
            2 => {
                (h.width, h.height) = (20, 10);
                self.send_raw(h, 200);
            }
            _ => {
                (h.width, h.height) = (0, 0);
                self.send_raw(h, 0);
            }
        }
        self.send(&good);
        Ok(source)
    }
}

#[test]
fn the_twin_frame_source_conforms() {
    conformance::frame_source(&mut TwinSourceRig::new());
}

/// A recorded dive, written by the DiveWriter and replayed at 50 times real time.
struct ReplayRig {
    dir: tempfile::TempDir,
    dives: usize,
}

impl ReplayRig {
    fn new() -> Self {
        ReplayRig {
            dir: tempfile::tempdir().unwrap(),
            dives: 0,
        }
    }

    fn new_dir(&mut self) -> PathBuf {
        self.dives += 1;
        self.dir.path().join(format!("dive-{}", self.dives))
    }

    /// A dive of `frames`, the first `broken` of them replaced by `bytes` on disk.
    fn dive(&mut self, frames: &[Frame], format: ImageFormat) -> Result<PathBuf, AdapterError> {
        let dir = self.new_dir();
        let mut w = DiveWriter::create(&dir, 40, 30, true, format)?;
        for f in frames {
            w.write(&f.meta, &f.image)?;
        }
        w.finish()?;
        Ok(dir)
    }
}

const SPEED: f64 = 50.0;

const REPLAY_BAD: [&str; 9] = [
    "a missing dive",
    "an index of another format",
    "an index row with a field missing",
    "an index whose time goes back",
    "an index with a frame outside the dive",
    "a missing frame file",
    "a corrupt frame file",
    "a truncated frame file",
    "a frame file of another size",
];

fn first_frame_file(dir: &Path) -> PathBuf {
    let index = std::fs::read_to_string(dir.join("index.csv")).unwrap();
    let row = index.lines().nth(3).unwrap();
    dir.join(row.split(',').nth(5).unwrap())
}

impl SourceRig for ReplayRig {
    type Source = ReplaySource;

    fn name(&self) -> String {
        "replay frame source".into()
    }

    fn live(&self) -> bool {
        false
    }

    fn speed(&self) -> Option<f64> {
        Some(SPEED)
    }

    fn open(&mut self, frames: &[Frame]) -> Result<ReplaySource, AdapterError> {
        // Alternate the two image formats.
        let format = if self.dives.is_multiple_of(2) {
            ImageFormat::Pgm
        } else {
            ImageFormat::Png
        };
        let dir = self.dive(frames, format)?;
        ReplaySource::open(&dir, Pacing::Speed(SPEED))
    }

    fn deliver(&mut self, _k: usize) {}

    fn bad_inputs(&self) -> Vec<String> {
        REPLAY_BAD.iter().map(|s| s.to_string()).collect()
    }

    fn open_bad(&mut self, k: usize) -> Result<ReplaySource, AdapterError> {
        let good: Vec<Frame> = sample_frames(40, 30).into_iter().take(2).collect();
        let dir = self.dive(&good, ImageFormat::Pgm)?;
        let index = dir.join("index.csv");
        let text = std::fs::read_to_string(&index).unwrap();
        let rows: Vec<&str> = text.lines().collect();
        let edit_row = |f: &dyn Fn(&str) -> String| {
            let mut rows = rows.clone();
            let edited = f(rows[3]);
            rows[3] = &edited;
            std::fs::write(&index, rows.join("\n") + "\n").unwrap();
        };
        match k {
            0 => return ReplaySource::open(&dir.join("nowhere"), Pacing::Speed(SPEED)),
            1 => std::fs::write(&index, text.replace("dive v1", "dive v7")).unwrap(),
            2 => edit_row(&|r| r.rsplit_once(',').unwrap().0.to_owned()),
            3 => edit_row(&|r| r.replacen(",0,", ",999999999,", 1)),
            4 => edit_row(&|r| r.replace("frames/", "../")),
            5 => std::fs::remove_file(first_frame_file(&dir)).unwrap(),
            6 => std::fs::write(first_frame_file(&dir), b"not an image at all").unwrap(),
            7 => {
                let f = first_frame_file(&dir);
                let bytes = std::fs::read(&f).unwrap();
                std::fs::write(&f, &bytes[..bytes.len() / 2]).unwrap();
            }
            _ => {
                let small = vision::Frame::new(20, 10).unwrap();
                small.write(&first_frame_file(&dir)).unwrap();
            }
        }
        ReplaySource::open(&dir, Pacing::Speed(SPEED))
    }
}

#[test]
fn the_replay_frame_source_conforms() {
    conformance::frame_source(&mut ReplayRig::new());
}

/// A dive replayed unpaced, and one without the true line, read back as written.
#[test]
fn a_dive_without_truth_and_an_unpaced_replay() {
    let tmp = tempfile::tempdir().unwrap();
    let frames = sample_frames(40, 30);
    let mut w = DiveWriter::create(tmp.path(), 40, 30, false, ImageFormat::Pgm).unwrap();
    for f in &frames {
        w.write(&f.meta, &f.image).unwrap();
    }
    assert_eq!(w.finish().unwrap(), frames.len() as u64);
    // A second writer refuses to overwrite the dive.
    assert!(DiveWriter::create(tmp.path(), 40, 30, false, ImageFormat::Pgm).is_err());
    let source = ReplaySource::open(tmp.path(), Pacing::Unpaced).unwrap();
    let now = std::time::Instant::now();
    let mut out = Frame::default();
    for f in &frames {
        assert_eq!(
            adapters::FrameSource::read(&source, now, &mut out).unwrap(),
            adapters::Read::Frame
        );
        assert_eq!(
            out.meta,
            FrameMeta {
                truth: None,
                ..f.meta
            }
        );
        assert_eq!(out.image, f.image);
    }
    assert_eq!(
        adapters::FrameSource::read(&source, now, &mut out).unwrap(),
        adapters::Read::End
    );
    assert!(ReplaySource::open(tmp.path(), Pacing::Speed(0.0)).is_err());
    assert!(ReplaySource::open(tmp.path(), Pacing::Speed(f64::NAN)).is_err());
}

// ---------------------------------------------------------------- thruster sinks

/// The twin's thrusters, with the test listening as the twin.
struct TwinSinkRig {
    _ns: Namespace,
    probe: Probe,
    port: Option<TwinThrusterPort>,
}

impl SinkRig for TwinSinkRig {
    type Sink = TwinThrusterSink;

    fn name(&self) -> String {
        "twin thruster sink".into()
    }

    fn open(&mut self, thrusters: usize) -> Result<TwinThrusterSink, AdapterError> {
        self.port = Some(TwinThrusterPort::open(self.probe.node())?);
        TwinThrusterSink::open(self.probe.node(), thrusters)
    }

    fn received(&mut self, _sink: &mut TwinThrusterSink) -> Option<Vec<Arrived>> {
        let port = self.port.as_ref().unwrap();
        let mut got = Vec::new();
        while let Some(m) = port.receive().unwrap() {
            got.push(Arrived {
                stamp: m.stamp,
                values: m.as_slice().to_vec(),
                stop: m.stop_cause(),
            });
        }
        Some(got)
    }
}

#[test]
fn the_twin_thruster_sink_conforms() {
    let ns = Namespace::new("adtk");
    let probe = testkit::probe(&ns, Endpoint::Vehicle);
    conformance::thruster_sink(&mut TwinSinkRig {
        _ns: ns,
        probe,
        port: None,
    });
}

/// A record file, read back with `read_record`.
struct RecordRig {
    dir: tempfile::TempDir,
    opened: usize,
    path: PathBuf,
    seen: usize,
}

impl SinkRig for RecordRig {
    type Sink = RecordSink;

    fn name(&self) -> String {
        "record thruster sink".into()
    }

    fn open(&mut self, thrusters: usize) -> Result<RecordSink, AdapterError> {
        self.opened += 1;
        self.path = self
            .dir
            .path()
            .join(format!("sub/record-{}.csv", self.opened));
        self.seen = 0;
        let names: Vec<String> = (0..thrusters).map(|i| format!("t{i}")).collect();
        RecordSink::create(&self.path, &names)
    }

    fn received(&mut self, _sink: &mut RecordSink) -> Option<Vec<Arrived>> {
        let (_, records) = read_record(&self.path).unwrap();
        let new = records[self.seen..]
            .iter()
            .map(|r| Arrived {
                stamp: r.stamp,
                values: r.values.clone(),
                stop: r.stop,
            })
            .collect();
        self.seen = records.len();
        Some(new)
    }
}

#[test]
fn the_record_thruster_sink_conforms() {
    conformance::thruster_sink(&mut RecordRig {
        dir: tempfile::tempdir().unwrap(),
        opened: 0,
        path: PathBuf::new(),
        seen: 0,
    });
}

struct NullRig;

impl SinkRig for NullRig {
    type Sink = NullSink;

    fn name(&self) -> String {
        "null thruster sink".into()
    }

    fn open(&mut self, thrusters: usize) -> Result<NullSink, AdapterError> {
        NullSink::new(thrusters)
    }

    fn received(&mut self, _sink: &mut NullSink) -> Option<Vec<Arrived>> {
        None
    }
}

#[test]
fn the_null_thruster_sink_conforms() {
    conformance::thruster_sink(&mut NullRig);
}

/// A record file names its thrusters and keeps each write's times; a broken one is refused by line.
#[test]
fn a_record_file_keeps_the_layout_and_the_times() {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("dive.csv");
    let names: Vec<String> = ["port", "starboard", "lateral"].map(String::from).to_vec();
    let mut sink = RecordSink::create(&path, &names).unwrap();
    let st = Stamp::new(41, 8_000_000_000, 3, 40, StepStatus::TimeLimit).timed(9, 123_456);
    adapters::ThrusterSink::write(&mut sink, &st, &[0.61, 0.2, -0.05]).unwrap();
    drop(sink); // closes: stops the thrusters
    let (got_names, records) = read_record(&path).unwrap();
    assert_eq!(got_names, names);
    assert_eq!(records.len(), 2);
    assert_eq!(records[0].stamp, st);
    assert_eq!(records[0].values, vec![0.61, 0.2, -0.05]);
    assert_eq!(records[0].stop, None);
    assert_eq!(records[1].stop, Some(adapters::StopCause::Shutdown));
    assert_eq!(records[1].values, vec![0.0; 3]);
    assert!(records[0].written_unix_ns > 1_600_000_000_000_000_000);

    let text = std::fs::read_to_string(&path).unwrap();
    std::fs::write(&path, text.replace("time_limit", "sunk")).unwrap();
    match read_record(&path) {
        Err(AdapterError::Format {
            line: 3, reason, ..
        }) => assert!(reason.contains("sunk")),
        other => panic!("{other:?}"),
    }
    std::fs::write(&path, text.replace("shutdown", "panic")).unwrap();
    match read_record(&path) {
        Err(AdapterError::Format {
            line: 4, reason, ..
        }) => assert!(reason.contains("panic")),
        other => panic!("{other:?}"),
    }
}
