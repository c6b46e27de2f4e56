//! The camera and perception in one loop, for step one with images instead of ideal geometry.

use crate::error::VisionError;
use crate::image::ImageView;
use crate::perception::{Detection, Perception};
use crate::render::Renderer;
use config::Scenario;
use model::{CableObservation, VehicleState};

/// Renders the vehicle's view and runs perception on it: a drop-in for
/// [`model::Camera::observe_state`] in a training loop.
///
/// ```no_run
/// # let scenario = config::Scenario::default();
/// # let state = model::VehicleState::default();
/// let mut eye = vision::SimulatedVision::new(&scenario, config::derive_seed(7, "render")).unwrap();
/// eye.reset(); // at each episode start
/// let obs = eye.observe(&state); // each step: render frame k, perceive it
/// if !obs.found { /* the episode ends: the cable is lost */ }
/// ```
pub struct SimulatedVision {
    renderer: Renderer,
    perception: Perception,
    frame: Vec<u8>,
    frame_index: u64,
    dt_s: f64,
    times: StageTimes,
}

/// Where the loop's time went: wall time spent rendering and perceiving (on one thread, its CPU
/// time), over `frames` frames. Benchmarks compare it with the same stages run as processes.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StageTimes {
    pub frames: u64,
    pub render_ns: u64,
    pub perceive_ns: u64,
}

impl SimulatedVision {
    /// The scenario's renderer and perception; `seed` fixes the floor, clutter and noise.
    pub fn new(scenario: &Scenario, seed: u64) -> Result<Self, VisionError> {
        let renderer = Renderer::from_scenario(scenario, seed)?;
        let perception = Perception::from_scenario(scenario)?;
        let frame = vec![0; renderer.width() * renderer.height()];
        Ok(SimulatedVision {
            renderer,
            perception,
            frame,
            frame_index: 0,
            dt_s: scenario.timing.sample_time_s,
            times: StageTimes::default(),
        })
    }

    /// A new episode: perception forgets its track (the frame counter runs on, so no two frames of a
    /// run share their noise).
    pub fn reset(&mut self) {
        self.perception.reset();
    }

    /// Renders the next frame seen from `state` (moving at its velocity, for blur) and perceives it,
    /// one sample time after the previous frame.
    pub fn observe(&mut self, state: &VehicleState) -> CableObservation {
        let rate = state.pose_rate();
        let start = std::time::Instant::now();
        self.renderer
            .render(&state.pose, &rate, self.frame_index, &mut self.frame)
            .expect("the frame buffer has the camera's size");
        let rendered = std::time::Instant::now();
        self.frame_index += 1;
        let view = ImageView::new(&self.frame, self.renderer.width(), self.renderer.height())
            .expect("the frame buffer has the camera's size");
        let obs = self
            .perception
            .process(view, self.dt_s)
            .expect("perception is set up for the renderer's camera");
        self.times.frames += 1;
        self.times.render_ns += (rendered - start).as_nanos() as u64;
        self.times.perceive_ns += rendered.elapsed().as_nanos() as u64;
        obs
    }

    /// The time spent in each stage since it was made.
    pub fn stage_times(&self) -> StageTimes {
        self.times
    }

    /// The last rendered frame.
    pub fn frame(&self) -> ImageView<'_> {
        ImageView::new(&self.frame, self.renderer.width(), self.renderer.height())
            .expect("checked size")
    }

    /// The index of the next frame (its noise); settable to replay a run.
    pub fn frame_index(&self) -> u64 {
        self.frame_index
    }

    pub fn set_frame_index(&mut self, index: u64) {
        self.frame_index = index;
    }

    /// The last frame's raw detection (before filtering), if the cable was found in it.
    pub fn last_detection(&self) -> Option<&Detection> {
        self.perception.last_detection()
    }

    pub fn renderer(&self) -> &Renderer {
        &self.renderer
    }

    pub fn perception(&self) -> &Perception {
        &self.perception
    }
}
