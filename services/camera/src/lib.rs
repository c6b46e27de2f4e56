//! The camera service's core: from the vehicle's state to a camera frame, without IPC.
//!
//! On the sim endpoint the camera is the simulator's downward camera. Every frame carries the
//! geometric truth ([`model::Camera::observe`]: the cable's line and its exact rates for the state's
//! pose and pose rate), so ideal perception can pass it on and image perception can be checked
//! against it. With [`Eyes::Images`] the frame also carries the image, rendered by
//! [`vision::Renderer`] into the caller's buffer (the `camera` binary hands it the loaned
//! shared-memory slice, so the image is never copied). With [`Eyes::Ideal`] the image is empty.
//!
//! Frames are reproducible: frame `k` of a run (the state with `seq = k + 1`, see [`frame_index`])
//! has the noise of frame index `k` of the renderer seeded with the run's `render` stream, exactly
//! the frame the in-process trainer's `vision::SimulatedVision` renders for the same step. A state
//! re-sent by the simulator therefore renders to the same bytes again.
//!
//! On the vehicle endpoint the camera reads a frame source instead ([`vehicle`]).

use config::{Eyes, ObservationLimits, Scenario};
use messages::{CableObservationData, CameraFrameHeader, Stamp, VehicleStateMsg};
use model::{Cable, Camera};
use vision::{Renderer, VisionError};

/// The renderer's frame index of a step: the run's steps counted from 0. `seq` counts from 1, and
/// the trainer's `SimulatedVision` numbers the frames of a run from 0, so both render the same frame
/// for the same step.
pub fn frame_index(stamp: &Stamp) -> u64 {
    stamp.seq.saturating_sub(1)
}

/// The simulated downward camera.
pub struct SimCamera {
    geometry: Camera,
    cable: Cable,
    limits: ObservationLimits,
    width: u32,
    height: u32,
    renderer: Option<Renderer>,
}

impl SimCamera {
    /// The scenario's camera; `render_seed` fixes the floor, the clutter and the noise of the images.
    pub fn new(scenario: &Scenario, eyes: Eyes, render_seed: u64) -> Result<Self, VisionError> {
        let renderer = match eyes {
            Eyes::Ideal => None,
            Eyes::Images => Some(Renderer::from_scenario(scenario, render_seed)?),
        };
        Ok(SimCamera {
            geometry: Camera::new(&scenario.camera),
            cable: Cable::new(&scenario.cable),
            limits: scenario.observation.clone(),
            width: scenario.camera.width,
            height: scenario.camera.height,
            renderer,
        })
    }

    pub fn eyes(&self) -> Eyes {
        if self.renderer.is_some() {
            Eyes::Images
        } else {
            Eyes::Ideal
        }
    }

    /// The geometric camera's observation of a state (the frame's truth).
    pub fn truth(&self, state: &VehicleStateMsg) -> CableObservationData {
        let obs =
            self.geometry
                .observe(&state.pose(), &state.pose_rate(), &self.cable, &self.limits);
        CableObservationData::from(&obs)
    }

    /// The frame's header: the state's stamp unchanged, the camera's size, the truth.
    pub fn header(&self, state: &VehicleStateMsg) -> CameraFrameHeader {
        CameraFrameHeader {
            stamp: state.stamp,
            width: self.width,
            height: self.height,
            truth: self.truth(state),
            ..Default::default()
        }
    }

    /// The image's length in bytes: `width * height` with images, 0 without.
    pub fn image_len(&self) -> usize {
        match self.renderer {
            Some(_) => self.width as usize * self.height as usize,
            None => 0,
        }
    }

    /// Renders the state's frame into `out` ([`SimCamera::image_len`] bytes; nothing to do without
    /// images). The pose's rate blurs the image.
    pub fn render(&mut self, state: &VehicleStateMsg, out: &mut [u8]) -> Result<(), VisionError> {
        match &mut self.renderer {
            Some(r) => r.render(
                &state.pose(),
                &state.pose_rate(),
                frame_index(&state.stamp),
                out,
            ),
            None if out.is_empty() => Ok(()),
            None => Err(VisionError::LengthMismatch {
                width: 0,
                height: 0,
                expected: 0,
                got: out.len(),
            }),
        }
    }
}

pub mod vehicle;

#[cfg(test)]
mod tests {
    use super::*;
    use messages::StepStatus;
    use model::{Pose, VehicleState, Velocity};
    use vision::SimulatedVision;

    fn state(seq: u64, pose: Pose, velocity: Velocity) -> VehicleStateMsg {
        let s = VehicleState { pose, velocity };
        VehicleStateMsg::new(
            Stamp::new(seq, 0, 0, seq as u32, StepStatus::Running),
            &s,
            &s.pose_rate(),
        )
    }

    fn moving() -> VehicleStateMsg {
        state(
            5,
            Pose {
                x: 0.4,
                y: 0.08,
                psi: 0.3,
            },
            Velocity {
                u: 0.25,
                v: -0.05,
                r: 0.1,
            },
        )
    }

    #[test]
    fn the_header_carries_the_stamp_and_the_geometric_truth() {
        let s = Scenario::default();
        let cam = SimCamera::new(&s, Eyes::Ideal, 1).unwrap();
        let st = moving();
        let h = cam.header(&st);
        assert_eq!(h.stamp, st.stamp);
        assert_eq!((h.width, h.height), (320, 240));
        let want = Camera::new(&s.camera).observe_state(
            &st.state(),
            &Cable::new(&s.cable),
            &s.observation,
        );
        assert!(want.found);
        assert_eq!(h.truth, CableObservationData::from(&want));
        assert_eq!(cam.image_len(), 0);
        let mut cam = cam;
        assert!(cam.render(&st, &mut []).is_ok());
        assert!(cam.render(&st, &mut [0; 4]).is_err());
    }

    #[test]
    fn out_of_view_the_truth_says_not_found() {
        let cam = SimCamera::new(&Scenario::default(), Eyes::Ideal, 1).unwrap();
        let far = state(
            1,
            Pose {
                x: 0.0,
                y: 5.0,
                psi: 0.0,
            },
            Velocity::default(),
        );
        assert_eq!(cam.truth(&far).found, 0);
    }

    /// The frame of step `seq` is the trainer's frame of the same step.
    #[test]
    fn images_are_the_trainers_frames() {
        let s = Scenario::default();
        let seed = config::derive_seed(3, "render");
        let mut cam = SimCamera::new(&s, Eyes::Images, seed).unwrap();
        assert_eq!(cam.image_len(), 320 * 240);
        let mut eye = SimulatedVision::new(&s, seed).unwrap();
        let mut buf = vec![0; cam.image_len()];
        for seq in 1..=3 {
            let st = moving();
            let st = VehicleStateMsg {
                stamp: Stamp { seq, ..st.stamp },
                ..st
            };
            eye.observe(&st.state());
            cam.render(&st, &mut buf).unwrap();
            assert_eq!(buf, eye.frame().data(), "frame of seq {seq}");
        }
        // A repeat renders the same bytes.
        let again = buf.clone();
        cam.render(
            &VehicleStateMsg {
                stamp: Stamp {
                    seq: 3,
                    ..moving().stamp
                },
                ..moving()
            },
            &mut buf,
        )
        .unwrap();
        assert_eq!(buf, again);
    }
}
