//! The recorder's decisions, without I/O: which message to write and at which log time, which frame's
//! image to keep, and what was missed.
//!
//! - **Once per step.** A step's message seen again (a re-send in lockstep, a topic's history after
//!   a restart) is counted as a repeat and not written again: per channel, a `seq` not above the last
//!   one written is a repeat.
//! - **Log time** is the stamp's time: simulated time on the sim endpoint, the frame source's clock
//!   on the vehicle. A message of no step (the supervisor's events, the recorder's status) is logged
//!   at the time of the newest step recorded before it (0 before the first), so it sits where it
//!   happened in the dive's timeline; its wall clock is in the message.
//! - **Frames.** Every frame's header is written; its image only for steps `step % frame_every == 0`
//!   (every frame by default), and perception's overlay for exactly the frames whose image was written.
//!   A frame the record's compressed stream can give (its unit recorded, [`Keeper::video`], and
//!   decodable from the record, [`Continuity`]) has its image decimated by `video_frame_every`
//!   instead (0: no image at all): the stream holds those frames, the images a few to look at and
//!   to check the stream's decoding against. So a frame the stream cannot give (before the
//!   stream's first keyframe in the record, after units missing from it, after the camera's decoder
//!   started afresh) keeps following `frame_every`, and replay has its image. So does a frame with
//!   several units of its time before it (the source sent the frame again, and the camera
//!   published the picture of a later copy): the stream does not say which picture the camera
//!   published.
//! - **Video units.** Each unit once, by its number within the camera's epoch (a repeat: the same
//!   number seen again; a restarted camera starts a new epoch).
//! - **Holes.** A step a channel of the loop missed while another channel recorded it, and the
//!   channel has recorded a later step since (so a step still in flight at the stop is not one): the
//!   recorder's buffer overflowed, or the step was never published on that topic (a command that
//!   missed its deadline).

use crate::channels::Channel;
use messages::{Stamp, VideoUnit};
use std::collections::{BTreeMap, VecDeque};

/// Steps remembered for finding holes; older ones are settled.
const WINDOW: usize = 4096;
/// Recent frames whose image was written (an overlay follows its image within a few steps).
const IMAGED: usize = 64;
/// Recent video units remembered for their frames (a frame follows its unit within the drain; the
/// camera's topic holds 64 frames in the recorder's buffer).
const UNITS: usize = 256;

/// Whether the units of a record, fed to a decoder in their order, decode to each unit's frame as
/// the camera's decoder did: from a keyframe on, with no unit of the camera's epoch missing since,
/// and the camera's decoder not started afresh since (`VideoUnit::DECODER_RESTARTED`). A unit
/// after one missing (the recorder's buffer overflowed, the recorder restarted, the camera dropped
/// a unit too large), the units before the record's first keyframe, and those after a restarted
/// camera or decoder, up to the next keyframe, are not: the camera's decoder held what the
/// record's does not. The recorder keeps those frames' images; replay takes them from the images.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Continuity {
    /// The last unit seen: its epoch and number.
    last: Option<(u32, u64)>,
    intact: bool,
}

impl Continuity {
    /// Whether `unit`, the next in the record, decodes as it did on the vehicle.
    pub fn next(&mut self, unit: &VideoUnit) -> bool {
        let follows = self
            .last
            .is_some_and(|(e, n)| e == unit.epoch && n.checked_add(1) == Some(unit.number));
        self.intact = unit.is_keyframe()
            || (self.intact && follows && unit.flags & VideoUnit::DECODER_RESTARTED == 0);
        self.last = Some((unit.epoch, unit.number));
        self.intact
    }
}

/// What to do with one message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Keep {
    /// Write it at this log time.
    Write { log_time: u64 },
    /// Seen before: not written again.
    Repeat,
}

/// Whether perception's overlay of a step is drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Overlay {
    /// Its frame's image was written: draw it now.
    Draw,
    /// Its frame has not been seen yet (the estimate overtook it in the recorder's buffers): ask
    /// again after the next frame.
    Later,
    /// Its frame was written without an image.
    Never,
}

/// What happened to one channel's messages.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counts {
    pub written: u64,
    pub repeats: u64,
    pub holes: u64,
    /// Images not written because of the decimation (`frame_every`, `video_frame_every`).
    pub decimated: u64,
}

/// The recorder's core.
#[derive(Debug)]
pub struct Keeper {
    frame_every: u32,
    /// The images' decimation for the frames the stream gives (0: none kept).
    video_frame_every: u32,
    /// The last video unit written: its camera's epoch and number.
    last_unit: Option<(u32, u64)>,
    continuity: Continuity,
    /// Recent units written: their frame (epoch, time) and whether the record decodes it.
    units: VecDeque<((u32, u64), bool)>,
    last_seq: BTreeMap<Channel, u64>,
    /// Recent steps: which per-step channels recorded each.
    seen: BTreeMap<u64, u64>,
    imaged: VecDeque<u64>,
    /// The newest step recorded: (seq, time).
    newest: Option<(u64, u64)>,
    counts: BTreeMap<Channel, Counts>,
}

const _: () = assert!(
    Channel::ALL.len() <= 64,
    "a step's channels are bits of a u64"
);

fn bit(c: Channel) -> u64 {
    1 << Channel::ALL.iter().position(|x| *x == c).unwrap_or(63)
}

impl Keeper {
    /// Keeps the image of every `frame_every`-th step of an episode (1: every frame).
    pub fn new(frame_every: u32) -> Self {
        Keeper {
            frame_every: frame_every.max(1),
            video_frame_every: frame_every.max(1),
            last_unit: None,
            continuity: Continuity::default(),
            units: VecDeque::new(),
            last_seq: BTreeMap::new(),
            seen: BTreeMap::new(),
            imaged: VecDeque::new(),
            newest: None,
            counts: BTreeMap::new(),
        }
    }

    /// Keeps the image of every `n`-th step of the frames the recorded stream gives (0: none).
    pub fn with_video_frame_every(mut self, n: u32) -> Self {
        self.video_frame_every = n;
        self
    }

    /// The decimation of the image of the frame of `stamp` (0: none kept): `video_frame_every` where
    /// the record's stream gives the frame, else `frame_every`.
    pub fn frame_every(&self, stamp: &Stamp) -> u32 {
        let frame = (stamp.epoch, stamp.time_ns);
        let mut units = self.units.iter().filter(|(f, _)| *f == frame);
        match (units.next(), units.next()) {
            (Some((_, true)), None) => self.video_frame_every,
            _ => self.frame_every,
        }
    }

    /// Whether to write the video unit `unit`: not when it was written before (the recorder's
    /// buffer gave it twice).
    pub fn video(&mut self, unit: &VideoUnit) -> bool {
        if let Some((e, n)) = self.last_unit
            && e == unit.epoch
            && unit.number <= n
        {
            self.count(Channel::Video).repeats += 1;
            return false;
        }
        self.last_unit = Some((unit.epoch, unit.number));
        let decodable = self.continuity.next(unit);
        self.units
            .push_back(((unit.epoch, unit.time_ns), decodable));
        if self.units.len() > UNITS {
            self.units.pop_front();
        }
        self.count(Channel::Video).written += 1;
        true
    }

    fn count(&mut self, c: Channel) -> &mut Counts {
        self.counts.entry(c).or_default()
    }

    /// A message of a stamped channel (every per-step channel, and the learners' episode reports).
    pub fn stamped(&mut self, channel: Channel, stamp: &Stamp) -> Keep {
        if self.last_seq.get(&channel).is_some_and(|&l| stamp.seq <= l) {
            self.count(channel).repeats += 1;
            return Keep::Repeat;
        }
        self.last_seq.insert(channel, stamp.seq);
        self.count(channel).written += 1;
        if self.newest.is_none_or(|(seq, _)| stamp.seq >= seq) {
            self.newest = Some((stamp.seq, stamp.time_ns));
        }
        if channel.per_step() {
            *self.seen.entry(stamp.seq).or_default() |= bit(channel);
            while self.seen.len() > WINDOW {
                if let Some((seq, mask)) = self.seen.pop_first() {
                    self.settle(seq, mask);
                }
            }
        }
        Keep::Write {
            log_time: stamp.time_ns,
        }
    }

    /// Whether to write the image of the frame whose header `stamp` was just written (`has_image`:
    /// the frame carries one).
    pub fn image(&mut self, stamp: &Stamp, has_image: bool) -> bool {
        if !has_image {
            return false;
        }
        let every = self.frame_every(stamp);
        if every == 0 || !stamp.step.is_multiple_of(every) {
            self.count(Channel::Image).decimated += 1;
            return false;
        }
        self.count(Channel::Image).written += 1;
        self.imaged.push_back(stamp.seq);
        if self.imaged.len() > IMAGED {
            self.imaged.pop_front();
        }
        true
    }

    /// Whether to write perception's overlay for the observation of `stamp`: when its frame's image
    /// was written.
    pub fn overlay(&mut self, stamp: &Stamp) -> Overlay {
        if self.imaged.contains(&stamp.seq) {
            self.count(Channel::Annotation).written += 1;
            Overlay::Draw
        } else if self
            .last_seq
            .get(&Channel::FrameHeader)
            .is_some_and(|&l| l >= stamp.seq)
        {
            Overlay::Never
        } else {
            Overlay::Later
        }
    }

    /// A message of no step: the supervisor's event `seq` (`Events`) or the recorder's status.
    pub fn unstamped(&mut self, channel: Channel, seq: u64) -> Keep {
        if self.last_seq.get(&channel).is_some_and(|&l| seq <= l) {
            self.count(channel).repeats += 1;
            return Keep::Repeat;
        }
        self.last_seq.insert(channel, seq);
        self.count(channel).written += 1;
        Keep::Write {
            log_time: self.newest.map_or(0, |(_, t)| t),
        }
    }

    fn settle(&mut self, seq: u64, mask: u64) {
        let missed: Vec<Channel> = Channel::ALL
            .into_iter()
            .filter(|c| c.per_step() && mask & bit(*c) == 0)
            .filter(|c| self.last_seq.get(c).is_some_and(|&l| l > seq))
            .collect();
        for c in missed {
            self.count(c).holes += 1;
        }
    }

    /// Settles every step still remembered (at the end of a record).
    pub fn finish(&mut self) {
        while let Some((seq, mask)) = self.seen.pop_first() {
            self.settle(seq, mask);
        }
    }

    /// Each channel's counts so far (holes only for settled steps).
    pub fn counts(&self) -> &BTreeMap<Channel, Counts> {
        &self.counts
    }

    pub fn holes(&self) -> u64 {
        self.counts.values().map(|c| c.holes).sum()
    }

    pub fn repeats(&self) -> u64 {
        self.counts.values().map(|c| c.repeats).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use messages::StepStatus;

    fn stamp(seq: u64, step: u32) -> Stamp {
        Stamp::new(seq, seq * 200_000_000, 0, step, StepStatus::Running)
    }

    const LOOP: [Channel; 4] = [
        Channel::FrameHeader,
        Channel::Observation,
        Channel::SwayCommand,
        Channel::Setpoints,
    ];

    #[test]
    fn a_step_is_written_once_at_its_stamp_time() {
        let mut k = Keeper::new(1);
        let s = stamp(7, 7);
        assert_eq!(
            k.stamped(Channel::Observation, &s),
            Keep::Write {
                log_time: 1_400_000_000
            }
        );
        assert_eq!(k.stamped(Channel::Observation, &s), Keep::Repeat);
        assert_eq!(k.stamped(Channel::Observation, &stamp(6, 6)), Keep::Repeat);
        // Another channel's message of the same step is written.
        assert!(matches!(
            k.stamped(Channel::Setpoints, &s),
            Keep::Write { .. }
        ));
        let c = k.counts()[&Channel::Observation];
        assert_eq!((c.written, c.repeats), (1, 2));
        assert_eq!(k.repeats(), 2);
    }

    #[test]
    fn events_sit_at_the_newest_step_recorded() {
        let mut k = Keeper::new(1);
        assert_eq!(
            k.unstamped(Channel::Events, 1),
            Keep::Write { log_time: 0 },
            "before any step: 0"
        );
        k.stamped(Channel::FrameHeader, &stamp(3, 3));
        k.stamped(Channel::Observation, &stamp(2, 2));
        assert_eq!(
            k.unstamped(Channel::Events, 2),
            Keep::Write {
                log_time: 600_000_000
            }
        );
        assert_eq!(
            k.unstamped(Channel::Events, 2),
            Keep::Repeat,
            "history after a restart"
        );
    }

    #[test]
    fn images_are_decimated_by_step_and_overlays_follow_their_images() {
        let mut k = Keeper::new(5);
        // The estimate of step 0 overtakes its frame.
        assert_eq!(k.overlay(&stamp(100, 0)), Overlay::Later);
        let kept: Vec<u32> = (0..12)
            .filter(|&step| {
                let s = stamp(100 + step as u64, step);
                k.stamped(Channel::FrameHeader, &s);
                k.image(&s, true)
            })
            .collect();
        assert_eq!(kept, vec![0, 5, 10]);
        assert_eq!(k.overlay(&stamp(100, 0)), Overlay::Draw);
        assert_eq!(k.overlay(&stamp(105, 5)), Overlay::Draw);
        assert_eq!(k.overlay(&stamp(106, 6)), Overlay::Never);
        assert_eq!(k.overlay(&stamp(112, 12)), Overlay::Later);
        assert!(!k.image(&stamp(200, 0), false), "no image in the frame");
        let c = k.counts()[&Channel::Image];
        assert_eq!((c.written, c.decimated), (3, 9));
        assert_eq!(k.counts()[&Channel::Annotation].written, 2);
    }

    /// A unit of the camera's `epoch` for the frame of `step` (at `stamp(100 + step, step)`'s time).
    fn unit(epoch: u32, number: u64, step: u32, flags: u32) -> VideoUnit {
        VideoUnit {
            number,
            time_ns: stamp(100 + step as u64, step).time_ns,
            epoch,
            flags,
            ..Default::default()
        }
    }

    /// The camera's frame of `step` in its `epoch`: its header written, and whether its image is.
    fn image(k: &mut Keeper, epoch: u32, step: u32) -> bool {
        let s = stamp(100 + step as u64, step).timed(epoch, 1);
        k.stamped(Channel::FrameHeader, &s);
        k.image(&s, true)
    }

    const KEY: u32 = VideoUnit::KEYFRAME;

    /// The frames the recorded stream gives have their images thinned to `video_frame_every`,
    /// the others keep `frame_every`; a unit is kept once per camera epoch and number.
    #[test]
    fn the_images_of_frames_the_stream_gives_are_decimated_further() {
        let mut k = Keeper::new(1).with_video_frame_every(4);
        assert!(
            (0..3).all(|step| image(&mut k, 9, step)),
            "every image before the stream"
        );
        let mut kept = Vec::new();
        for step in 3..12 {
            let flags = if step == 3 { KEY } else { 0 };
            assert!(k.video(&unit(9, step as u64, step, flags)));
            if image(&mut k, 9, step) {
                kept.push(step);
            }
        }
        assert_eq!(kept, vec![4, 8]);
        assert!(!k.video(&unit(9, 11, 11, 0)), "the same unit again");
        assert!(
            image(&mut k, 8, 12),
            "a frame of another epoch, its unit not recorded"
        );
        let v = k.counts()[&Channel::Video];
        assert_eq!((v.written, v.repeats), (9, 1));
        let c = k.counts()[&Channel::Image];
        assert_eq!((c.written, c.decimated), (6, 7));
    }

    /// `video_frame_every` 0: no image of a frame the stream gives; the images of the frames it
    /// cannot give (before its first keyframe, after a unit missing, after the camera's decoder
    /// started afresh, a restarted camera's first units) follow `frame_every`.
    #[test]
    fn with_video_frame_every_0_only_the_frames_the_stream_cannot_give_keep_images() {
        let mut k = Keeper::new(2).with_video_frame_every(0);
        let restarted = VideoUnit::DECODER_RESTARTED | VideoUnit::DAMAGED;
        // (step, epoch, the unit's number and flags; None: no unit recorded)
        let dive = [
            (0, 9, None),
            (1, 9, None),
            // The recorder joined the stream between keyframes.
            (2, 9, Some((5, 0))),
            (3, 9, Some((6, 0))),
            (4, 9, Some((7, KEY))),
            (5, 9, Some((8, 0))),
            (6, 9, Some((9, 0))),
            // Unit 10 missing from the record.
            (8, 9, Some((11, 0))),
            (10, 9, Some((12, KEY))),
            // The camera's decoder started afresh.
            (12, 9, Some((13, restarted))),
            (14, 9, Some((14, 0))),
            (16, 9, Some((15, KEY))),
            // A restarted camera: a new epoch, its first unit no keyframe.
            (18, 3, Some((1, 0))),
            (20, 3, Some((2, KEY))),
            (22, 3, Some((3, 0))),
            // A frame whose unit is not recorded (the recorder's buffer overflowed).
            (24, 3, None),
        ];
        let mut kept = Vec::new();
        for (step, epoch, u) in dive {
            if let Some((number, flags)) = u {
                k.video(&unit(epoch, number, step, flags));
            }
            if image(&mut k, epoch, step) {
                kept.push(step);
            }
        }
        // Before the stream and where it cannot give the frame, every 2nd step.
        assert_eq!(kept, vec![0, 2, 8, 12, 14, 18, 24]);
        // The source sent a frame again: two units of its time before it.
        k.video(&unit(3, 5, 28, KEY));
        k.video(&unit(3, 6, 28, 0));
        assert!(
            image(&mut k, 3, 28),
            "which of two pictures the camera published"
        );
        k.video(&unit(3, 7, 30, 0));
        assert!(!image(&mut k, 3, 30));
    }

    #[test]
    fn the_record_decodes_a_unit_from_a_keyframe_on_with_none_missing() {
        let mut c = Continuity::default();
        let u = |epoch, number, flags| VideoUnit {
            number,
            epoch,
            flags,
            ..Default::default()
        };
        let seen: Vec<bool> = [
            u(1, 4, 0),
            u(1, 5, KEY),
            u(1, 6, VideoUnit::DAMAGED),
            u(1, 8, 0),
            u(1, 9, KEY),
            u(1, 10, VideoUnit::DECODER_RESTARTED),
            u(1, 11, 0),
            u(1, 12, KEY | VideoUnit::DECODER_RESTARTED),
            u(2, 13, 0),
            u(2, 14, KEY),
            u(2, 15, 0),
        ]
        .iter()
        .map(|x| c.next(x))
        .collect();
        assert_eq!(
            seen,
            [
                false, true, true, false, true, false, false, true, false, true, true
            ]
        );
    }

    #[test]
    fn a_hole_is_a_step_one_channel_missed_and_others_had() {
        let mut k = Keeper::new(1);
        for seq in 1..=10u64 {
            for c in LOOP {
                // The observation of step 4 is lost; the setpoints of step 10 are still in flight.
                if (c == Channel::Observation && seq == 4) || (c == Channel::Setpoints && seq == 10)
                {
                    continue;
                }
                k.stamped(c, &stamp(seq, seq as u32));
            }
        }
        // Steps 6 and 7 lost on every channel: no channel had them, nothing says they existed.
        k.finish();
        let holes: BTreeMap<Channel, u64> = k.counts().iter().map(|(c, n)| (*c, n.holes)).collect();
        assert_eq!(holes[&Channel::Observation], 1);
        assert_eq!(
            holes[&Channel::Setpoints],
            0,
            "the step in flight at the stop"
        );
        assert_eq!(holes[&Channel::FrameHeader], 0);
        assert_eq!(k.holes(), 1);
        // Channels that never had a message (the vehicle endpoint's vehicle state) have no holes.
        assert!(!k.counts().contains_key(&Channel::VehicleState));
    }

    #[test]
    fn old_steps_are_settled_as_the_window_moves() {
        let mut k = Keeper::new(1);
        for seq in 1..=(WINDOW as u64 + 10) {
            k.stamped(Channel::FrameHeader, &stamp(seq, 0));
            if seq != 2 {
                k.stamped(Channel::Observation, &stamp(seq, 0));
            }
        }
        assert_eq!(
            k.counts()[&Channel::Observation].holes,
            1,
            "settled without finish"
        );
        assert!(k.seen.len() <= WINDOW);
    }
}
