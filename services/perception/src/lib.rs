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
//! makes: a truncated frame) is refused with the reason, and the tracker is left as it was: the
//! step stays unanswered (an intact copy of it can still be perceived), and the loop goes on with
//! the next frame. A frame marked damaged (`CameraFrameHeader::DAMAGED`: compressed video decoded
//! with data missing) is not tracked on: the tracker coasts on its prediction, as for a frame
//! without the cable, and loses the cable after `coast_frames` of them. The truth passed on by ideal perception is put under the rule for bad values
//! (`CableObservationData::bounded`) and what it changed is reported ([`Observed::fixes`]).

use config::{Eyes, ObservationLimits, Scenario};
use messages::{CableObservationData, CableObservationMsg, CameraFrameHeader, Stamp};
use model::bounds::Fixes;
use vision::{ImageView, Perception, VisionError};

/// One frame's result.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Observed {
    /// The observation, stamped with the frame's stamp.
    pub msg: CableObservationMsg,
    /// What the rule for bad values changed in the truth passed on (ideal perception).
    pub fixes: Fixes,
}

/// The perception stage of the loop.
pub struct Observer {
    tracker: Option<Perception>,
    limits: ObservationLimits,
    /// The camera's frame size.
    size: (usize, usize),
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
            limits: scenario.observation.clone(),
            size: (
                scenario.camera.width as usize,
                scenario.camera.height as usize,
            ),
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

    /// The observation of one frame (call it once per step: the tracker moves on with each call),
    /// or why the frame cannot be used (the tracker then left as it was).
    pub fn observe(
        &mut self,
        header: &CameraFrameHeader,
        image: &[u8],
    ) -> Result<Observed, VisionError> {
        let stamp = header.stamp;
        let Some(tracker) = &mut self.tracker else {
            let (observation, fixes) = header.truth.bounded(&self.limits);
            return Ok(Observed {
                msg: CableObservationMsg { stamp, observation },
                fixes,
            });
        };
        // Checked before the tracker sees it: a broken frame must not reset or move the track.
        let view = ImageView::new(image, header.width as usize, header.height as usize)?;
        if (view.width(), view.height()) != self.size {
            return Err(VisionError::SizeMismatch {
                what: "perception",
                width: self.size.0,
                height: self.size.1,
                got_width: view.width(),
                got_height: view.height(),
            });
        }
        let new_episode = stamp.step == 0 || self.last.is_none_or(|l| l.episode != stamp.episode);
        if new_episode {
            tracker.reset();
            self.last = None;
        }
        let dt = match self.last {
            Some(l) if stamp.time_ns > l.time_ns => (stamp.time_ns - l.time_ns) as f64 / 1e9,
            _ => self.sample_time_s,
        };
        // A damaged image (video data lost) is not looked at: the track coasts on its prediction.
        let obs = if header.is_damaged() {
            tracker.coast(dt)
        } else {
            tracker.process(view, dt)?
        };
        self.last = Some(stamp);
        Ok(Observed {
            msg: CableObservationMsg {
                stamp,
                observation: CableObservationData::from(&obs),
            },
            fixes: Fixes::default(),
        })
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
            ..Default::default()
        }
    }

    #[test]
    fn ideal_eyes_pass_the_truth_on() {
        let mut o = Observer::new(&Scenario::default(), Eyes::Ideal).unwrap();
        let h = header(4, 0, 3);
        let got = o.observe(&h, &[]).unwrap();
        assert_eq!(got.msg.stamp, h.stamp);
        assert_eq!(got.msg.observation, h.truth);
        assert!(got.fixes.is_empty());
        // A broken truth is put under the rule: not finite is 0, out of range clamped.
        let broken = CameraFrameHeader {
            truth: CableObservationData {
                x_g: f64::NAN,
                theta: 9.0,
                ..h.truth
            },
            ..h
        };
        let got = o.observe(&broken, &[]).unwrap();
        assert_eq!(got.msg.observation.x_g, 0.0);
        assert_eq!(got.msg.observation.theta, std::f64::consts::FRAC_PI_2);
        assert_eq!((got.fixes.non_finite, got.fixes.clamped), (1, 1));
    }

    /// A damaged frame's image is not looked at: the observation is the tracker's coast, what a
    /// frame without the cable gives, not what the image shows.
    #[test]
    fn a_damaged_frame_is_not_tracked_on() {
        let scenario = Scenario::default();
        let mut renderer = vision::Renderer::from_scenario(&scenario, 5).unwrap();
        let still = model::PoseRate::default();
        let at = |y| model::Pose {
            x: 0.0,
            y,
            psi: 0.05,
        };
        let here = renderer.render_frame(&at(0.0), &still, 0);
        let there = renderer.render_frame(&at(0.15), &still, 1);
        let blank = vec![0u8; 320 * 240];
        let mut seen = Vec::new();
        for second in [there.data(), &blank[..], there.data()] {
            let mut o = Observer::new(&scenario, Eyes::Images).unwrap();
            let first = o.observe(&header(1, 0, 0), here.data()).unwrap();
            assert_eq!(first.msg.observation.found, 1);
            let mut h = header(2, 0, 1);
            if seen.len() == 2 {
                h.flags = CameraFrameHeader::DAMAGED;
            }
            seen.push(o.observe(&h, second).unwrap().msg.observation);
        }
        let (moved, missed, damaged) = (seen[0], seen[1], seen[2]);
        assert_eq!(
            damaged, missed,
            "a damaged frame coasts like one without the cable"
        );
        assert!(damaged.confidence < 1.0 && damaged.found == 1);
        assert!(
            (moved.x_g - damaged.x_g).abs() > 0.05,
            "the damaged image was not looked at: {moved:?} vs {damaged:?}"
        );
        // Ideal eyes pass the truth on whatever the image.
        let mut ideal = Observer::new(&scenario, Eyes::Ideal).unwrap();
        let mut h = header(3, 0, 2);
        h.flags = CameraFrameHeader::DAMAGED;
        assert_eq!(ideal.observe(&h, &[]).unwrap().msg.observation, h.truth);
    }

    #[test]
    fn a_bad_frame_is_refused_with_the_reason() {
        let mut o = Observer::new(&Scenario::default(), Eyes::Images).unwrap();
        let h = header(2, 0, 1);
        assert!(matches!(
            o.observe(&h, &[0; 100]),
            Err(VisionError::LengthMismatch { got: 100, .. })
        ));
        let other_size = CameraFrameHeader {
            width: 160,
            height: 120,
            ..h
        };
        assert!(matches!(
            o.observe(&other_size, &[0; 160 * 120]),
            Err(VisionError::SizeMismatch { .. })
        ));
        let absurd = CameraFrameHeader {
            width: 0,
            height: u32::MAX,
            ..h
        };
        assert!(o.observe(&absurd, &[]).is_err());
    }
}
