//! The perception service's core: from a camera frame to the cable observation the behaviours
//! learn from, without IPC.
//!
//! With [`Eyes::Images`] the frame's image (borrowed in place: the `perception` binary passes the
//! shared-memory slice) goes through [`vision::Perception`], which finds the cable's two edges and
//! tracks the line from frame to frame. The tracker forgets its track at each episode's first step
//! (`stamp.step == 0`), and the time between two frames comes from their stamps (the scenario's sample
//! time when there is no earlier frame of the episode). With [`Eyes::Ideal`] the frame's geometric
//! truth is passed on as the observation.
//!
//! A frame perception cannot use (an image of another size than the header says, or than the camera
//! makes) gives a *not found* observation and the reason ([`Observed::bad_frame`]), never an error:
//! a broken frame must not stop the vehicle's loop.

use config::{Eyes, Scenario};
use messages::{CableObservationData, CableObservationMsg, CameraFrameHeader, Stamp};
use vision::{ImageView, Perception, VisionError};

/// One frame's result.
#[derive(Clone, Debug, PartialEq)]
pub struct Observed {
    /// The observation, stamped with the frame's stamp.
    pub msg: CableObservationMsg,
    /// Why the frame could not be used (the observation then says not found).
    pub bad_frame: Option<VisionError>,
}

/// The perception stage of the loop.
pub struct Observer {
    tracker: Option<Perception>,
    sample_time_s: f64,
    /// The last frame perceived in the current episode.
    last: Option<Stamp>,
}

impl Observer {
    /// The scenario's perception (its `[perception]`, `[camera]`, `[cable]` and `[observation]`).
    pub fn new(scenario: &Scenario, eyes: Eyes) -> Result<Self, VisionError> {
        let tracker = match eyes {
            Eyes::Ideal => None,
            Eyes::Images => Some(Perception::from_scenario(scenario)?),
        };
        Ok(Observer {
            tracker,
            sample_time_s: scenario.timing.sample_time_s,
            last: None,
        })
    }

    pub fn eyes(&self) -> Eyes {
        if self.tracker.is_some() {
            Eyes::Images
        } else {
            Eyes::Ideal
        }
    }

    /// The observation of one frame (call it once per step: the tracker moves on with each call).
    pub fn observe(&mut self, header: &CameraFrameHeader, image: &[u8]) -> Observed {
        let stamp = header.stamp;
        let Some(tracker) = &mut self.tracker else {
            return Observed {
                msg: CableObservationMsg {
                    stamp,
                    observation: header.truth,
                },
                bad_frame: None,
            };
        };
        let new_episode = stamp.step == 0 || self.last.is_none_or(|l| l.episode != stamp.episode);
        if new_episode {
            tracker.reset();
            self.last = None;
        }
        let dt = match self.last {
            Some(l) if stamp.time_ns > l.time_ns => (stamp.time_ns - l.time_ns) as f64 / 1e9,
            _ => self.sample_time_s,
        };
        let result = ImageView::new(image, header.width as usize, header.height as usize)
            .and_then(|view| tracker.process(view, dt));
        match result {
            Ok(obs) => {
                self.last = Some(stamp);
                Observed {
                    msg: CableObservationMsg {
                        stamp,
                        observation: CableObservationData::from(&obs),
                    },
                    bad_frame: None,
                }
            }
            Err(e) => Observed {
                msg: CableObservationMsg {
                    stamp,
                    observation: CableObservationData::default(),
                },
                bad_frame: Some(e),
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use messages::StepStatus;

    fn header(seq: u64, episode: u32, step: u32) -> CameraFrameHeader {
        CameraFrameHeader {
            stamp: Stamp::new(seq, seq * 200_000_000, episode, step, StepStatus::Running),
            width: 320,
            height: 240,
            truth: CableObservationData {
                found: 1,
                theta: 0.2,
                x_g: -0.1,
                ..Default::default()
            },
        }
    }

    #[test]
    fn ideal_eyes_pass_the_truth_on() {
        let mut o = Observer::new(&Scenario::default(), Eyes::Ideal).unwrap();
        let h = header(4, 0, 3);
        let got = o.observe(&h, &[]);
        assert_eq!(got.msg.stamp, h.stamp);
        assert_eq!(got.msg.observation, h.truth);
        assert!(got.bad_frame.is_none());
    }

    #[test]
    fn a_bad_frame_is_not_found_with_the_reason() {
        let mut o = Observer::new(&Scenario::default(), Eyes::Images).unwrap();
        let h = header(2, 0, 1);
        let short = o.observe(&h, &[0; 100]);
        assert_eq!(short.msg.stamp, h.stamp);
        assert_eq!(short.msg.observation.found, 0);
        assert!(matches!(
            short.bad_frame,
            Some(VisionError::LengthMismatch { got: 100, .. })
        ));
        let other_size = CameraFrameHeader {
            width: 160,
            height: 120,
            ..h
        };
        let small = o.observe(&other_size, &[0; 160 * 120]);
        assert!(matches!(
            small.bad_frame,
            Some(VisionError::SizeMismatch { .. })
        ));
        let absurd = CameraFrameHeader {
            width: 0,
            height: u32::MAX,
            ..h
        };
        assert!(o.observe(&absurd, &[]).bad_frame.is_some());
    }
}
