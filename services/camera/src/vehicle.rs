//! The camera on the vehicle endpoint: it reads the vehicle's frame source (`adapters`: the twin's
//! camera, or a recorded dive) and publishes each frame on the vehicle's camera topic, stamped for
//! the mesh.
//!
//! **The stamp.** `time_ns`, the trial (as the episode), the step and the status are the source's,
//! unchanged: the behaviours end their episodes on the source's status, and the twin matches the
//! setpoints answering a frame by its time. `seq` is the camera's own ([`SeqMap`]): the source's frame
//! counter plus a base fixed when the camera starts, the time since the Unix epoch in microseconds.
//! So gaps in the source's count (dropped frames) show as gaps in `seq`, and a restarted camera
//! starts above every `seq` it published before (it published fewer frames than microseconds went
//! by): the consumers, which drop a `seq` not above the last they saw, take its frames at once.
//! When the source's count goes back (the device restarted), the base moves up so `seq` keeps
//! increasing.
//!
//! **Pacing** is the source's: the twin's clock (the camera blocks on the twin's frame topic) or the
//! dive's timestamps (the camera wakes at the dive's pace). The camera itself never sleeps.

use adapters::{FrameMeta, FrameSource, Read};
use messages::{CameraFrameHeader, Stamp};
use std::path::PathBuf;
use std::time::{SystemTime, UNIX_EPOCH};

/// Which frame source the vehicle's camera reads.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum SourceSpec {
    /// The vehicle twin's camera (`cabletrack/twin/frame`).
    Twin,
    /// A recorded dive in this directory (`adapters::replay`).
    Replay(PathBuf),
}

impl std::str::FromStr for SourceSpec {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "twin" => Ok(SourceSpec::Twin),
            _ => match s.strip_prefix("replay:") {
                Some(dir) if !dir.is_empty() => Ok(SourceSpec::Replay(PathBuf::from(dir))),
                _ => Err(format!(
                    "unknown frame source `{s}` (expected `twin` or `replay:DIR`)"
                )),
            },
        }
    }
}

/// The camera's sequence numbers: the source's frame counter plus a base (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SeqMap {
    base: u64,
    last: Option<(u64, u64)>,
}

impl SeqMap {
    pub fn new(base: u64) -> Self {
        SeqMap { base, last: None }
    }

    /// The base of a camera starting now: microseconds since the Unix epoch.
    pub fn starting_now() -> Self {
        let us = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| d.as_micros() as u64);
        SeqMap::new(us)
    }

    /// The camera's `seq` for the source's new frame `source_seq`: increasing, whatever the source.
    pub fn next(&mut self, source_seq: u64) -> u64 {
        let mut out = self.base.saturating_add(source_seq);
        if let Some((_, last_out)) = self.last
            && out <= last_out
        {
            // The source's count went back: move the base up past what was published.
            self.base = last_out + 1 - source_seq.min(last_out + 1);
            out = self.base + source_seq;
        }
        self.last = Some((source_seq, out));
        out
    }

    /// The last `seq` given out.
    pub fn last(&self) -> Option<u64> {
        self.last.map(|(_, out)| out)
    }
}

/// The header of a source's frame published with the camera's `seq`.
pub fn header(meta: &FrameMeta, seq: u64) -> CameraFrameHeader {
    CameraFrameHeader {
        stamp: Stamp::new(seq, meta.time_ns, meta.trial, meta.step, meta.status),
        width: meta.width,
        height: meta.height,
        // The truth is passed on where the source knows it (ideal perception can use it).
        truth: meta.truth.unwrap_or_default(),
    }
}

/// What the camera does with one read of its source.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Publish {
    /// A new frame: publish it with this header.
    New(CameraFrameHeader),
    /// The source sent its last frame again: publish the last header again (consumers answer a
    /// repeated `seq` from their cache).
    Again(CameraFrameHeader),
    /// Nothing now.
    Wait,
    /// The source ended.
    End,
}

/// The vehicle camera's core: sequence numbers and the frame size check, no IPC.
pub struct VehicleCamera {
    seq: SeqMap,
    size: (u32, u32),
    last: Option<CameraFrameHeader>,
    published: u64,
}

impl VehicleCamera {
    /// A camera publishing frames of `size` (the scenario's camera), numbering them from `seq`.
    pub fn new(size: (u32, u32), seq: SeqMap) -> Self {
        VehicleCamera {
            seq,
            size,
            last: None,
            published: 0,
        }
    }

    /// Checks that a source's frames can be published (they have the camera's size).
    pub fn check(&self, source: &dyn FrameSource) -> Result<(), String> {
        if source.size() != self.size {
            return Err(format!(
                "{} gives {}x{} frames, the scenario's camera is {}x{}",
                source.describe(),
                source.size().0,
                source.size().1,
                self.size.0,
                self.size.1
            ));
        }
        Ok(())
    }

    /// What to publish for a read's outcome (`meta` is the frame read, for `Frame` and `Repeat`).
    pub fn on_read(&mut self, read: Read, meta: &FrameMeta) -> Publish {
        match read {
            Read::Frame => {
                let h = header(meta, self.seq.next(meta.seq));
                self.last = Some(h);
                self.published += 1;
                Publish::New(h)
            }
            Read::Repeat => match self.last {
                Some(h) => Publish::Again(h),
                // A repeat of a frame this camera never read (it started after it): a new frame.
                None => self.on_read(Read::Frame, meta),
            },
            Read::Pending { .. } => Publish::Wait,
            Read::End => Publish::End,
        }
    }

    /// Frames published so far (repeats not counted).
    pub fn published(&self) -> u64 {
        self.published
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use messages::{CableObservationData, StepStatus};

    fn meta(seq: u64, ms: u64) -> FrameMeta {
        FrameMeta {
            seq,
            time_ns: ms * 1_000_000,
            width: 320,
            height: 240,
            trial: 2,
            step: seq as u32,
            status: StepStatus::Running,
            truth: Some(CableObservationData {
                found: 1,
                x_g: 0.1,
                ..Default::default()
            }),
        }
    }

    #[test]
    fn sources_parse() {
        assert_eq!("twin".parse(), Ok(SourceSpec::Twin));
        assert_eq!(
            "replay:/data/dive-3".parse(),
            Ok(SourceSpec::Replay("/data/dive-3".into()))
        );
        assert!("replay:".parse::<SourceSpec>().is_err());
        assert!("usb0".parse::<SourceSpec>().is_err());
    }

    /// The source's gaps stay gaps; a restarted camera starts above all it published; a device
    /// restart does not make `seq` go back.
    #[test]
    fn seq_grows_across_gaps_and_restarts() {
        let mut m = SeqMap::new(1000);
        assert_eq!(m.next(1), 1001);
        assert_eq!(m.next(2), 1002);
        assert_eq!(m.next(5), 1005, "frames 3 and 4 were dropped");
        // The device restarted: its count starts again at 1.
        assert_eq!(m.next(1), 1006);
        assert_eq!(m.next(2), 1007);
        assert_eq!(m.last(), Some(1007));
        // A camera's base is its start time in microseconds since the epoch: a camera started a
        // second later starts a million above, more than it could publish in that second.
        let mut now = SeqMap::starting_now();
        assert!(now.next(1) > 1_700_000_000_000_000);
        let mut earlier = SeqMap::new(now.base - 1_000_000);
        let last = (1..=5_000).map(|k| earlier.next(k)).last().unwrap();
        assert!(now.next(2) > last);
    }

    #[test]
    fn the_stamp_is_the_sources_with_the_cameras_seq() {
        let mut cam = VehicleCamera::new((320, 240), SeqMap::new(100));
        let m = meta(7, 1400);
        let Publish::New(h) = cam.on_read(Read::Frame, &m) else {
            panic!()
        };
        assert_eq!(
            h.stamp,
            Stamp::new(107, 1_400_000_000, 2, 7, StepStatus::Running)
        );
        assert_eq!((h.width, h.height), (320, 240));
        assert_eq!(h.truth, m.truth.unwrap());
        assert_eq!(cam.on_read(Read::Repeat, &m), Publish::Again(h));
        assert_eq!(
            cam.on_read(Read::Pending { until: None }, &m),
            Publish::Wait
        );
        assert_eq!(cam.on_read(Read::End, &m), Publish::End);
        let unknown = FrameMeta { truth: None, ..m };
        assert_eq!(header(&unknown, 1).truth.found, 0);
        assert_eq!(cam.published(), 1);
    }
}
