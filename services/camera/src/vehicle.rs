//! The camera on the vehicle endpoint: it reads the vehicle's frame source (`adapters`: the twin's
//! camera, or a recorded dive) and publishes each frame on the vehicle's camera topic, stamped for
//! the mesh.
//!
//! **The stamp.** `time_ns`, the trial (as the episode), the step and the status are the source's,
//! unchanged: the behaviours end their episodes on the source's status, and the twin matches the
//! setpoints answering a frame by its time. `seq` is the camera's own ([`SeqMap`]): the source's frame
//! counter, so gaps in the source's count (dropped frames) show as gaps in `seq`; when the source's
//! count goes back (the device restarted), a base moves up so `seq` keeps increasing. The camera
//! numbers its frames in an *epoch* of its own, new at each start (`Stamp::epoch`), and stamps
//! each with the vehicle clock when it read the frame (`Stamp::clock_ns`, the machine's monotonic
//! clock): a restarted camera starts a new epoch, which its consumers follow whatever its `seq`, and
//! no wall clock (which has no RTC or NTP under water) is read at all. A frame published again (the
//! source repeated it) keeps its `seq` and takes the time of its new publication, so a consumer that
//! missed it judges it fresh.
//!
//! **Pacing** is the source's: the twin's clock (the camera blocks on the twin's frame topic) or the
//! dive's timestamps (the camera wakes at the dive's pace). The camera itself never sleeps.

use adapters::{FrameMeta, FrameSource, Read};
use messages::{CameraFrameHeader, Stamp, VideoUnit};
use std::net::SocketAddr;
use std::path::PathBuf;

/// Which frame source the vehicle's camera reads.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum SourceSpec {
    /// The vehicle twin's camera (`cabletrack/twin/frame`).
    Twin,
    /// A recorded dive in this directory (`adapters::replay`).
    Replay(PathBuf),
    /// An RTP/H.264 stream received on this address (a BlueROV2's camera as BlueOS sends it, or
    /// the twin's with `--video`): `video::source`, built with the `video` feature.
    Rtp(SocketAddr),
}

impl std::str::FromStr for SourceSpec {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        if s == "twin" {
            return Ok(SourceSpec::Twin);
        }
        if let Some(dir) = s.strip_prefix("replay:")
            && !dir.is_empty()
        {
            return Ok(SourceSpec::Replay(PathBuf::from(dir)));
        }
        if let Some(addr) = s.strip_prefix("rtp:") {
            return addr.parse().map(SourceSpec::Rtp).map_err(|e| {
                format!("frame source `{s}`: `{addr}` is not an ADDR:PORT to listen on ({e})")
            });
        }
        Err(format!(
            "unknown frame source `{s}` (expected `twin`, `replay:DIR` or `rtp:ADDR:PORT`)"
        ))
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

/// The header of a source's frame published with the camera's `seq` in its `epoch`, read at
/// `clock_ns` on the vehicle clock.
pub fn header(meta: &FrameMeta, seq: u64, epoch: u32, clock_ns: i64) -> CameraFrameHeader {
    CameraFrameHeader {
        stamp: Stamp::new(seq, meta.time_ns, meta.trial, meta.step, meta.status)
            .timed(epoch, clock_ns),
        width: meta.width,
        height: meta.height,
        // A damaged image (lost video data) is marked: perception does not track on it.
        flags: if meta.damaged {
            CameraFrameHeader::DAMAGED
        } else {
            0
        },
        // The truth is passed on where the source knows it (ideal perception can use it).
        truth: meta.truth.unwrap_or_default(),
        ..Default::default()
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

/// The vehicle camera's core: sequence numbers, stamps and the frame size check, no IPC.
pub struct VehicleCamera {
    seq: SeqMap,
    epoch: u32,
    size: (u32, u32),
    last: Option<CameraFrameHeader>,
    published: u64,
}

impl VehicleCamera {
    /// A camera publishing frames of `size` (the scenario's camera), numbering them with `seq` in
    /// its `epoch` (new at each start, never 0).
    pub fn new(size: (u32, u32), seq: SeqMap, epoch: u32) -> Self {
        VehicleCamera {
            seq,
            epoch,
            size,
            last: None,
            published: 0,
        }
    }

    pub fn epoch(&self) -> u32 {
        self.epoch
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

    /// What to publish for a read's outcome at `clock_ns` on the vehicle clock (`meta` is the frame
    /// read, for `Frame` and `Repeat`).
    pub fn on_read(&mut self, read: Read, meta: &FrameMeta, clock_ns: i64) -> Publish {
        match read {
            Read::Frame => {
                let h = header(meta, self.seq.next(meta.seq), self.epoch, clock_ns);
                self.last = Some(h);
                self.published += 1;
                Publish::New(h)
            }
            Read::Repeat => match self.last {
                Some(mut h) => {
                    h.stamp.clock_ns = clock_ns;
                    Publish::Again(h)
                }
                // A repeat of a frame this camera never read (it started after it): a new frame.
                None => self.on_read(Read::Frame, meta, clock_ns),
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

/// An access unit the camera's decoder got, as the frame source hands it over for the record.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct UnitInfo {
    pub len: usize,
    pub keyframe: bool,
    pub damaged: bool,
    pub decoder_restarted: bool,
    /// The time of the frame it decodes to (`FrameMeta::time_ns`).
    pub time_ns: u64,
    pub session: u64,
}

/// The camera's video units for the record (`topics::CAMERA_VIDEO`): numbered in the order its
/// decoder got them, at most `max_len` bytes. A larger unit is not published, nor are the units
/// after it up to the next keyframe (they reference it): the record's stream stays decodable, and
/// the gap shows in the numbers.
pub struct VideoUnits {
    epoch: u32,
    max_len: usize,
    number: u64,
    /// A unit was too large: waiting for a keyframe.
    skipping: bool,
    /// Units not published.
    pub dropped: u64,
}

/// What to do with one unit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UnitVerdict {
    Publish(VideoUnit),
    /// Larger than the topic takes (said once per stretch, by the caller).
    TooLarge {
        number: u64,
        len: usize,
    },
    /// After a unit too large, before the next keyframe.
    Skipped,
}

impl VideoUnits {
    pub fn new(epoch: u32, max_len: usize) -> Self {
        VideoUnits {
            epoch,
            max_len,
            number: 0,
            skipping: false,
            dropped: 0,
        }
    }

    /// The verdict on the decoder's next unit, read at `clock_ns` on the vehicle clock.
    pub fn next(&mut self, unit: &UnitInfo, clock_ns: i64) -> UnitVerdict {
        self.number += 1;
        if unit.len > self.max_len {
            self.skipping = true;
            self.dropped += 1;
            return UnitVerdict::TooLarge {
                number: self.number,
                len: unit.len,
            };
        }
        if self.skipping && !unit.keyframe {
            self.dropped += 1;
            return UnitVerdict::Skipped;
        }
        self.skipping = false;
        let flags = [
            (unit.keyframe, VideoUnit::KEYFRAME),
            (unit.damaged, VideoUnit::DAMAGED),
            (unit.decoder_restarted, VideoUnit::DECODER_RESTARTED),
        ]
        .iter()
        .filter(|(on, _)| *on)
        .fold(0, |f, (_, bit)| f | bit);
        UnitVerdict::Publish(VideoUnit {
            number: self.number,
            time_ns: unit.time_ns,
            clock_ns,
            epoch: self.epoch,
            flags,
            session: unit.session,
        })
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
            damaged: false,
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
        assert_eq!(
            "rtp:0.0.0.0:5600".parse(),
            Ok(SourceSpec::Rtp("0.0.0.0:5600".parse().unwrap()))
        );
        assert_eq!(
            "rtp:[::1]:5602".parse(),
            Ok(SourceSpec::Rtp("[::1]:5602".parse().unwrap()))
        );
        for bad in [
            "rtp:",
            "rtp:5600",
            "rtp:localhost:5600",
            "rtp:1.2.3.4:99999",
        ] {
            let e = bad.parse::<SourceSpec>().unwrap_err();
            assert!(e.contains(bad), "{e}");
        }
    }

    /// The source's gaps stay gaps; a device restart does not make `seq` go back.
    #[test]
    fn seq_grows_across_gaps_and_device_restarts() {
        let mut m = SeqMap::new(0);
        assert_eq!(m.next(1), 1);
        assert_eq!(m.next(2), 2);
        assert_eq!(m.next(5), 5, "frames 3 and 4 were dropped");
        // The device restarted: its count starts again at 1.
        assert_eq!(m.next(1), 6);
        assert_eq!(m.next(2), 7);
        assert_eq!(m.last(), Some(7));
    }

    #[test]
    fn the_stamp_is_the_sources_with_the_cameras_seq_epoch_and_clock() {
        let mut cam = VehicleCamera::new((320, 240), SeqMap::new(100), 42);
        let m = meta(7, 1400);
        let Publish::New(h) = cam.on_read(Read::Frame, &m, 9_000) else {
            panic!()
        };
        assert_eq!(
            h.stamp,
            Stamp::new(107, 1_400_000_000, 2, 7, StepStatus::Running).timed(42, 9_000)
        );
        assert_eq!((h.width, h.height), (320, 240));
        assert_eq!(h.truth, m.truth.unwrap());
        // Published again: the same step, stamped with the time of its new publication.
        let mut again = h;
        again.stamp.clock_ns = 9_500;
        assert_eq!(cam.on_read(Read::Repeat, &m, 9_500), Publish::Again(again));
        assert_eq!(
            cam.on_read(Read::Pending { until: None }, &m, 9_600),
            Publish::Wait
        );
        assert_eq!(cam.on_read(Read::End, &m, 9_700), Publish::End);
        let unknown = FrameMeta { truth: None, ..m };
        assert_eq!(header(&unknown, 1, 42, 1).truth.found, 0);
        assert!(!h.is_damaged());
        let damaged = FrameMeta { damaged: true, ..m };
        assert!(header(&damaged, 1, 42, 1).is_damaged());
        assert_eq!(cam.published(), 1);
    }

    /// Units are numbered in the decoder's order; one too large is left out with the units that
    /// reference it, up to the next keyframe.
    #[test]
    fn a_unit_too_large_is_left_out_up_to_the_next_keyframe() {
        let mut v = VideoUnits::new(7, 1000);
        let unit = |len, keyframe| UnitInfo {
            len,
            keyframe,
            time_ns: len as u64,
            session: 1,
            ..Default::default()
        };
        let UnitVerdict::Publish(first) = v.next(&unit(900, true), 5) else {
            panic!()
        };
        assert_eq!(
            first,
            VideoUnit {
                number: 1,
                time_ns: 900,
                clock_ns: 5,
                epoch: 7,
                flags: VideoUnit::KEYFRAME,
                session: 1
            }
        );
        assert!(
            matches!(v.next(&unit(10, false), 6), UnitVerdict::Publish(u) if u.number == 2 && u.flags == 0)
        );
        assert_eq!(
            v.next(&unit(1001, false), 7),
            UnitVerdict::TooLarge {
                number: 3,
                len: 1001
            }
        );
        assert_eq!(v.next(&unit(10, false), 8), UnitVerdict::Skipped);
        let UnitVerdict::Publish(key) = v.next(&unit(20, true), 9) else {
            panic!()
        };
        assert_eq!((key.number, key.is_keyframe()), (5, true));
        assert_eq!(v.dropped, 2);
        let restarted = UnitInfo {
            damaged: true,
            decoder_restarted: true,
            ..unit(10, false)
        };
        assert!(matches!(v.next(&restarted, 10), UnitVerdict::Publish(u)
            if u.flags == VideoUnit::DAMAGED | VideoUnit::DECODER_RESTARTED));
    }
}
