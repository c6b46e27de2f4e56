//! A record as the plant of the lockstep protocol (`runtime::lockstep`): its "step" is the next
//! recorded frame, whatever the mesh answered (the record is the world: the mesh's answers change
//! nothing in it). So the lockstep's re-sends, deadlines and wait for a mesh that is not up yet are
//! the simulator's and the twin's, written once.

use crate::frames::{Frame, Frames, ReplayError};
use messages::CameraFrameHeader;
use runtime::lockstep::{Advanced, Plant};

/// A frame as the lockstep publishes it (the image stays in the plant: a step is `Copy`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Played {
    /// Frames before it in the record.
    pub index: u64,
    pub header: CameraFrameHeader,
    /// The record has no more frames: nothing to publish, the replay is over.
    pub end: bool,
}

/// The record's frames, one step at a time.
pub struct ReplayPlant {
    frames: Frames,
    current: Option<Frame>,
    played: Played,
    error: Option<ReplayError>,
}

impl ReplayPlant {
    pub fn new(frames: Frames) -> Self {
        ReplayPlant {
            frames,
            current: None,
            played: Played {
                index: 0,
                header: CameraFrameHeader::default(),
                end: true,
            },
            error: None,
        }
    }

    /// The image of the frame published last.
    pub fn image(&self) -> &[u8] {
        self.current.as_ref().map_or(&[], |f| &f.image)
    }

    /// The error that ended the frames early, if one did (taken once).
    pub fn take_error(&mut self) -> Option<ReplayError> {
        self.error.take()
    }

    pub fn into_frames(self) -> Frames {
        self.frames
    }

    fn next(&mut self) -> Advanced<Self> {
        let index = if self.current.is_some() {
            self.played.index + 1
        } else {
            self.played.index
        };
        match self.frames.next_frame() {
            Ok(Some(frame)) => {
                self.played = Played {
                    index,
                    header: frame.header,
                    end: false,
                };
                self.current = Some(frame);
            }
            Ok(None) => self.played.end = true,
            Err(e) => {
                self.error = Some(e);
                self.played.end = true;
            }
        }
        Advanced {
            step: self.played,
            passed: 0,
            ended: Vec::new(),
        }
    }
}

impl Plant for ReplayPlant {
    type Step = Played;
    /// The episode (trial) that ended.
    type End = u32;

    /// The allocator's setpoints carry the frame's `seq`.
    fn answers(step: &Played, seq: u64) -> bool {
        !step.end && step.header.stamp.seq == seq
    }

    fn is_terminal(step: &Played) -> bool {
        step.header.stamp.status().is_terminal()
    }

    fn start(&mut self) -> Advanced<Self> {
        self.next()
    }

    fn advance(&mut self, _answer: Option<&[f64]>) -> Advanced<Self> {
        let ended = Self::is_terminal(&self.played).then_some(self.played.header.stamp.episode);
        let mut a = self.next();
        a.ended.extend(ended);
        a
    }

    fn finish(&mut self) -> Vec<u32> {
        Vec::new()
    }
}
