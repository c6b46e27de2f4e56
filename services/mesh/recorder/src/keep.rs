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
//!   Once the camera's compressed stream is recorded (its units, [`Keeper::video`]), the images
//!   are decimated by `video_frame_every` instead: the stream holds every frame, the images a few
//!   to look at and to check the stream's decoding against.
//! - **Video units.** Each unit once, by its number within the camera's epoch (a repeat: the same
//!   number seen again; a restarted camera starts a new epoch).
//! - **Holes.** A step a channel of the loop missed while another channel recorded it, and the
//!   channel has recorded a later step since (so a step still in flight at the stop is not one): the
//!   recorder's buffer overflowed, or the step was never published on that topic (a command that
//!   missed its deadline).

use crate::channels::Channel;
use messages::Stamp;
use std::collections::{BTreeMap, VecDeque};

/// Steps remembered for finding holes; older ones are settled.
const WINDOW: usize = 4096;
/// Recent frames whose image was written (an overlay follows its image within a few steps).
const IMAGED: usize = 64;

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
    /// Images not written because of `frame_every`.
    pub decimated: u64,
}

/// The recorder's core.
#[derive(Debug)]
pub struct Keeper {
    frame_every: u32,
    /// The images' decimation once a video unit is recorded.
    video_frame_every: u32,
    /// The last video unit written: its camera's epoch and number.
    last_unit: Option<(u32, u64)>,
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
            last_seq: BTreeMap::new(),
            seen: BTreeMap::new(),
            imaged: VecDeque::new(),
            newest: None,
            counts: BTreeMap::new(),
        }
    }

    /// Keeps the image of every `n`-th step once the compressed stream is recorded.
    pub fn with_video_frame_every(mut self, n: u32) -> Self {
        self.video_frame_every = n.max(1);
        self
    }

    /// The images' decimation now.
    pub fn frame_every(&self) -> u32 {
        if self.last_unit.is_some() {
            self.video_frame_every
        } else {
            self.frame_every
        }
    }

    /// Whether to write the video unit `number` of the camera's `epoch`: not when it was
    /// written before (the recorder's buffer gave it twice).
    pub fn video(&mut self, epoch: u32, number: u64) -> bool {
        if let Some((e, n)) = self.last_unit
            && e == epoch
            && number <= n
        {
            self.count(Channel::Video).repeats += 1;
            return false;
        }
        self.last_unit = Some((epoch, number));
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
        if !stamp.step.is_multiple_of(self.frame_every()) {
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

    /// With the compressed stream recorded, the images thin out to `video_frame_every`; a unit
    /// is kept once per camera epoch and number.
    #[test]
    fn with_video_the_images_are_decimated_further() {
        let mut k = Keeper::new(1).with_video_frame_every(4);
        let image = |k: &mut Keeper, step: u32| {
            let s = stamp(100 + step as u64, step);
            k.stamped(Channel::FrameHeader, &s);
            k.image(&s, true)
        };
        assert!(
            (0..3).all(|step| image(&mut k, step)),
            "every image before the stream"
        );
        assert!(k.video(9, 1) && k.video(9, 2));
        assert!(!k.video(9, 2), "the same unit again");
        assert!(k.video(5, 1), "a restarted camera's first unit");
        let kept: Vec<u32> = (3..12).filter(|&step| image(&mut k, step)).collect();
        assert_eq!(kept, vec![4, 8]);
        assert_eq!(k.frame_every(), 4);
        let v = k.counts()[&Channel::Video];
        assert_eq!((v.written, v.repeats), (3, 1));
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
