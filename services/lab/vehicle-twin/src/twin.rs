//! The twin as the vehicle's hardware sees it: a camera taking a frame every control period of the
//! plant, thrusters taking setpoints, and trials as on the real vehicle. No IPC: the `vehicle-twin`
//! binary publishes what [`Twin`] says and feeds it the setpoints it receives; [`crate::TwinWorld`]
//! composes it with the vehicle's service cores in one process.
//!
//! **Frames.** A frame is taken every `sample_time_s` of twin time ([`Shot`]): the device counts
//! every frame (`seq`, from 1), so a dropped frame leaves a gap. Its camera is mounted off the
//! centre of rotation; its image is rendered with the twin's harsher [`config::RenderParams`]. A frame
//! is dropped with the configured probability, except a trial's last one (its status is how the
//! vehicle side learns that the trial ended).
//!
//! **Frame noise per start mark.** The image noise and the dropped frames are drawn per start mark
//! (see [`Shot::mark`]) and step: trials from the same mark meet the same frame noise, so what tells
//! them apart is the policy and its exploration (common random numbers: two policies evaluated from
//! the same marks compare, and an evaluation is repeatable).
//!
//! **Thrusters.** The setpoints answering a frame drive the plant until the next frame; with a
//! camera-to-command latency of L frames (`[latency]`), they reach the thrusters L periods later and
//! drive the plant for the period after that. Without an answer (a dropped frame, a late mesh) the
//! thrusters hold the last setpoints, until the watchdog stops them after `watchdog_s` of twin time
//! without any.
//!
//! **The autopilot.** With `twin.toml [autopilot]` the thrusters are a stand-in ArduSub's motors
//! ([`crate::ardusub`]), driven by its attitude loop at every sub-step of the plant from the pilot
//! input it holds: the vehicle behind its autopilot, as the stack meets a BlueROV2. The pilot is
//! the stack either way. On the twin's thruster topic ([`Twin::advance`]) the twin does what a
//! MAVLink companion does: it takes off in `scenario.toml [pilot]`'s mode and turns the setpoints
//! answering a frame into the pilot's sticks (`model::pilot`, with `[pilot]`'s fractions, as the
//! `ardusub` thruster sink does over MAVLink); a failsafe stop is neutral sticks,
//! and the autopilot's own pilot-input failsafe replaces the thrusters' watchdog. Over MAVLink
//! (`vehicle-twin --autopilot URL`, [`Twin::advance_piloted`]) the stack's side sends the sticks
//! and commands itself. The plant is the vehicle's own model (`scenario.toml [model]`), at full
//! thrust.
//!
//! **Trials.** A trial lasts `duration_s` of twin time (its last step has status `TimeLimit`) or
//! ends when the cable leaves the image (`Lost`). The answer to a trial's last frame is not applied:
//! the vehicle is repositioned (a random pose with the cable in view, velocities and thrust 0) and
//! the next trial's first frame (step 0) is taken.

use crate::ardusub::{self, ArduSub, mixer};
use crate::plant::TwinPlant;
use adapters::FrameMeta;
use config::{MAX_THRUSTERS, PilotParams, ResetParams, Scenario, TwinParams, derive_seed};
use messages::{CableObservationData, StepStatus};
use model::{Cable, Camera, PoseRate, VehicleState};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use std::collections::VecDeque;
use std::time::{Duration, Instant};
use vision::{Renderer, VisionError};

/// Why a twin cannot be built.
#[derive(Debug, thiserror::Error)]
pub enum TwinError {
    #[error(transparent)]
    Vision(#[from] VisionError),
    /// The scenario, the twin's config and the autopilot do not fit together.
    #[error("the twin's autopilot: {0}")]
    Autopilot(String),
}

/// The vehicle's autopilot and how the twin's thruster topic pilots it.
pub struct Autopilot {
    core: ArduSub,
    pilot: PilotParams,
    /// The twin time's origin as the autopilot's clock.
    epoch: Instant,
    /// Whether the twin has taken off itself (its thruster topic pilots the autopilot).
    piloting: bool,
}

impl Autopilot {
    pub fn core(&self) -> &ArduSub {
        &self.core
    }

    pub fn core_mut(&mut self) -> &mut ArduSub {
        &mut self.core
    }

    pub fn pilot(&self) -> &PilotParams {
        &self.pilot
    }

    /// The autopilot's clock at twin time `time_s`.
    fn at(&self, time_s: f64) -> Instant {
        self.epoch + Duration::from_secs_f64(time_s.max(0.0))
    }
}

/// One frame's answer on its way to the thrusters (`None`: no answer came).
type InFlight = Option<[f64; MAX_THRUSTERS]>;

/// One frame the twin's camera takes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Shot {
    /// The camera's frame counter, from 1; dropped frames count.
    pub seq: u64,
    /// Twin time since the start (s).
    pub time_s: f64,
    /// Trials count from 0, steps from 0 at the trial's start.
    pub trial: u32,
    pub step: u32,
    /// The trial's start mark: the index of its start pose in the cycle (the trial itself when every
    /// trial starts anew).
    pub mark: u32,
    pub status: StepStatus,
    /// The plant when the frame was taken, and its pose's rate (the current included).
    pub state: VehicleState,
    pub rate: PoseRate,
    /// What the mounted camera truly sees (the line and its exact rates).
    pub truth: CableObservationData,
    /// Lost on the way: the vehicle side never sees this frame.
    pub dropped: bool,
}

impl Shot {
    /// Twin time in nanoseconds (the frames' clock).
    pub fn time_ns(&self) -> u64 {
        (self.time_s * 1e9).round() as u64
    }

    /// The index of this frame's image noise: its start mark and step (a re-sent frame is the same
    /// image, and every trial from a mark meets the same noise).
    pub fn noise_index(&self) -> u64 {
        ((self.mark as u64) << 32) | self.step as u64
    }

    /// The frame's metadata as the camera adapters carry it.
    pub fn meta(&self, width: u32, height: u32) -> FrameMeta {
        FrameMeta {
            seq: self.seq,
            time_ns: self.time_ns(),
            width,
            height,
            trial: self.trial,
            step: self.step,
            status: self.status,
            truth: Some(self.truth),
            damaged: false,
        }
    }
}

/// The twin's camera: the mounted geometry, the renderer, the frame drops.
pub struct TwinEye {
    camera: Camera,
    cable: Cable,
    limits: config::ObservationLimits,
    renderer: Option<Renderer>,
    drop_rate: f64,
    drops: StdRng,
    seed: u64,
    width: u32,
    height: u32,
}

impl TwinEye {
    /// The twin's camera; `images` builds the renderer (without it, frames carry no image).
    pub fn new(
        scenario: &Scenario,
        twin: &TwinParams,
        seed: u64,
        images: bool,
    ) -> Result<Self, VisionError> {
        let params = mounted(scenario, twin);
        let renderer = if images {
            Some(Renderer::new(
                &twin.render,
                &params,
                &scenario.cable,
                derive_seed(seed, "twin/render"),
            )?)
        } else {
            None
        };
        Ok(TwinEye {
            camera: Camera::new(&params),
            cable: Cable::new(&scenario.cable),
            limits: scenario.observation.clone(),
            renderer,
            drop_rate: twin.frames.dropped.rate(),
            drops: StdRng::seed_from_u64(derive_seed(seed, "twin/drops/0")),
            seed,
            width: scenario.camera.width,
            height: scenario.camera.height,
        })
    }

    /// The mounted camera's geometry.
    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    pub fn cable(&self) -> &Cable {
        &self.cable
    }

    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    pub fn has_images(&self) -> bool {
        self.renderer.is_some()
    }

    /// What the camera truly sees from a state moving at `rate`.
    pub fn truth(&self, state: &VehicleState, rate: &PoseRate) -> CableObservationData {
        CableObservationData::from(&self.camera.observe(
            &state.pose,
            rate,
            &self.cable,
            &self.limits,
        ))
    }

    /// Restarts the drops' stream at the start of a trial from `mark`.
    fn start_drops(&mut self, mark: u32) {
        self.drops = StdRng::seed_from_u64(derive_seed(self.seed, &format!("twin/drops/{mark}")));
    }

    /// Draws whether the next frame is lost (one draw per frame, terminal or not, so the drops of
    /// a trial do not depend on when it ends).
    fn draw_drop(&mut self) -> bool {
        let u: f64 = self.drops.random();
        u < self.drop_rate
    }

    /// Renders `shot`'s image into `out` (`width * height` bytes). The noise is the frame's own
    /// ([`Shot::noise_index`]), so a re-sent frame is the same image.
    pub fn render(&mut self, shot: &Shot, out: &mut [u8]) -> Result<(), VisionError> {
        match &mut self.renderer {
            Some(r) => r.render(&shot.state.pose, &shot.rate, shot.noise_index(), out),
            None => Err(VisionError::Config {
                what: "twin camera",
                invalid: config::Invalid::new("images", false, "the twin was built without images"),
            }),
        }
    }
}

/// The scenario's camera, mounted where the twin's is.
pub fn mounted(scenario: &Scenario, twin: &TwinParams) -> config::CameraParams {
    let [x, y] = twin.camera.offset();
    config::CameraParams {
        mount_x_m: x,
        mount_y_m: y,
        ..scenario.camera.clone()
    }
}

/// How the twin ended a trial.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrialEnd {
    pub trial: u32,
    /// Control steps taken in the trial.
    pub steps: u32,
    pub status: StepStatus,
    /// Frames of the trial lost on the way.
    pub dropped: u32,
}

/// The vehicle twin: plant, camera, thrusters' hold and watchdog, trials.
pub struct Twin {
    plant: TwinPlant,
    eye: TwinEye,
    reposition: ResetParams,
    resets: StdRng,
    /// The cycle of start poses (empty: a new pose every trial).
    cycle: Vec<model::Pose>,
    cycle_len: usize,
    dt: f64,
    steps_per_trial: u32,
    watchdog_s: f64,
    /// Answers not yet at the thrusters, oldest first, and how many periods each waits.
    in_flight: VecDeque<InFlight>,
    latency: usize,
    held: Vec<f64>,
    /// Twin time since the last setpoints arrived at the thrusters.
    since_answer_s: f64,
    current: Option<Shot>,
    /// The current trial's start mark.
    mark: u32,
    trial_dropped: u32,
    dropped: u64,
    autopilot: Option<Autopilot>,
}

impl Twin {
    /// A twin of `scenario` with the reality gap of `twin`, its random streams (repositions, frame
    /// drops, image noise) drawn from `seed`. Call [`Twin::start`] for the first frame.
    pub fn new(
        scenario: &Scenario,
        twin: &TwinParams,
        seed: u64,
        images: bool,
    ) -> Result<Self, TwinError> {
        let dt = scenario.timing.sample_time_s;
        let plant = TwinPlant::new(scenario, twin);
        let n = plant.layout().len();
        let autopilot = match (&twin.autopilot, &scenario.pilot) {
            (None, None) => None,
            (None, Some(_)) => {
                return Err(TwinError::Autopilot(
                    "the scenario pilots an autopilot ([pilot]) but the twin's config has no \
                     [autopilot]"
                        .into(),
                ));
            }
            (Some(_), None) => {
                return Err(TwinError::Autopilot(
                    "the twin's config has an [autopilot] but the scenario does not say how the \
                     stack pilots it ([pilot])"
                        .into(),
                ));
            }
            (Some(params), Some(pilot)) => {
                let params = params
                    .flown_by(pilot, "autopilot")
                    .map_err(|e| TwinError::Autopilot(e.to_string()))?;
                let m = plant.layout().matrix();
                let columns: Vec<[f64; 3]> = (0..m.ncols())
                    .map(|j| [m[(0, j)], m[(1, j)], m[(2, j)]])
                    .collect();
                mixer::check_layout(&columns).map_err(|e| {
                    TwinError::Autopilot(format!("needs the BlueROV2's vectored layout: {e}"))
                })?;
                let epoch = Instant::now();
                let core = ArduSub::new(&params, Vec::new(), epoch);
                let gain = core.gain();
                let f = &pilot.fraction;
                if f.surge.max(f.sway).max(f.yaw) > gain {
                    tracing::warn!(
                        gain,
                        fractions = ?f,
                        "a [pilot] fraction is above the joystick gain: the stack's full commands \
                         are clipped to the full stick"
                    );
                }
                Some(Autopilot {
                    core,
                    pilot: pilot.clone(),
                    epoch,
                    piloting: false,
                })
            }
        };
        Ok(Twin {
            eye: TwinEye::new(scenario, twin, seed, images)?,
            plant,
            reposition: twin.trials.reposition.clone(),
            resets: StdRng::seed_from_u64(derive_seed(seed, "twin/reset")),
            cycle: Vec::new(),
            cycle_len: twin.trials.cycle as usize,
            dt,
            steps_per_trial: ((twin.trials.duration_s / dt).round() as u32).max(1),
            watchdog_s: twin.thrusters.watchdog_s,
            in_flight: VecDeque::with_capacity(twin.latency.periods() + 1),
            latency: twin.latency.periods(),
            held: vec![0.0; n],
            since_answer_s: 0.0,
            current: None,
            mark: 0,
            trial_dropped: 0,
            dropped: 0,
            autopilot,
        })
    }

    /// The vehicle's autopilot, when the thrusters are its motors.
    pub fn autopilot(&self) -> Option<&Autopilot> {
        self.autopilot.as_ref()
    }

    pub fn autopilot_mut(&mut self) -> Option<&mut Autopilot> {
        self.autopilot.as_mut()
    }

    pub fn plant(&self) -> &TwinPlant {
        &self.plant
    }

    pub fn eye(&self) -> &TwinEye {
        &self.eye
    }

    pub fn eye_mut(&mut self) -> &mut TwinEye {
        &mut self.eye
    }

    /// Control steps in a full trial.
    pub fn steps_per_trial(&self) -> u32 {
        self.steps_per_trial
    }

    pub fn sample_time_s(&self) -> f64 {
        self.dt
    }

    /// Thrusters in the layout.
    pub fn thrusters(&self) -> usize {
        self.held.len()
    }

    /// Frames lost so far.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }

    /// The frame being answered, once started.
    pub fn current(&self) -> Option<&Shot> {
        self.current.as_ref()
    }

    /// The vehicle side stopped the thrusters (a failsafe stop, not an answer to a frame): they hold
    /// 0 from now on, until setpoints come again. Behind an autopilot: neutral sticks.
    pub fn stop_thrusters(&mut self) {
        let time_s = self.current.map_or(0.0, |s| s.time_s);
        match &mut self.autopilot {
            Some(a) => {
                let now = a.at(time_s);
                a.core.pilot(now, model::pilot::Axes::NEUTRAL);
            }
            None => self.held.iter_mut().for_each(|h| *h = 0.0),
        }
    }

    /// Takes the first trial's first frame (again, if called twice: it restarts nothing).
    pub fn start(&mut self) -> Shot {
        if let Some(s) = self.current {
            return s;
        }
        self.begin_trial(0, 1, 0.0)
    }

    /// The next frame: the current one's answer (`None`: none arrived) drives the plant for one
    /// period; after a trial's last frame the next trial starts instead. Returns the new frame and,
    /// when a trial just closed, how it ended.
    pub fn advance(&mut self, answer: Option<&[f64]>) -> (Shot, Option<TrialEnd>) {
        if self.autopilot.is_some() {
            return self.next(|twin| {
                let arrived = twin.arrive(answer);
                twin.pilot_with(arrived);
                twin.fly_period();
            });
        }
        self.next(|twin| {
            match twin.arrive(answer) {
                Some(sp) => {
                    twin.held.iter_mut().zip(sp).for_each(|(h, v)| *h = v);
                    twin.since_answer_s = 0.0;
                }
                None => twin.since_answer_s += twin.dt,
            }
            if twin.since_answer_s >= twin.watchdog_s - 1e-9 {
                twin.held.iter_mut().for_each(|h| *h = 0.0);
            }
            twin.plant.step(&twin.held, twin.dt);
        })
    }

    /// The next frame, the period driven by the autopilot from the pilot input it holds (the
    /// stack's MANUAL_CONTROL over MAVLink, received by the caller through
    /// [`Twin::autopilot_mut`]); the trials run as with [`Twin::advance`]. Without an autopilot the
    /// thrusters hold their setpoints.
    pub fn advance_piloted(&mut self) -> (Shot, Option<TrialEnd>) {
        if self.autopilot.is_none() {
            return self.advance(None);
        }
        self.next(|twin| twin.fly_period())
    }

    /// The twin's thruster topic as the autopilot's pilot: the setpoints that reached the
    /// thrusters become the sticks (at the frame's time), the autopilot taking off first; then the
    /// autopilot keeps its time (its pilot-input failsafe).
    fn pilot_with(&mut self, arrived: InFlight) {
        let time_s = self.current.map_or(0.0, |s| s.time_s);
        let n = self.held.len();
        let layout = self.plant.layout();
        let a = self.autopilot.as_mut().expect("piloted");
        let now = a.at(time_s);
        if let Some(sp) = arrived {
            if !a.core.armed() {
                // Taking off (or again, after the autopilot's failsafe disarmed it), as a
                // MAVLink companion does before it sends sticks.
                if let Err(e) = a.core.fly(a.pilot.mode.into())
                    && !a.piloting
                {
                    tracing::warn!("the twin's pilot cannot take off: {e}");
                }
                a.piloting = true;
            }
            let axes = model::pilot::setpoint_axes(layout, &sp[..n], &a.pilot, a.core.gain());
            a.core.pilot(now, axes);
        }
        a.core.on_time(now);
        // Nobody listens on the twin's thruster topic for the autopilot's messages.
        drop(a.core.take_out(now));
    }

    /// One period with the autopilot driving the thrusters at every sub-step of the plant.
    fn fly_period(&mut self) {
        let n = (self.dt / self.plant.max_substep_s()).ceil().max(1.0);
        let h = self.dt / n;
        let a = self.autopilot.as_mut().expect("piloted");
        for _ in 0..n as usize {
            let v = ardusub::vehicle_of(self.plant.state(), &self.plant.pose_rate());
            let pwm = a.core.control(h, v);
            for (o, p) in self.held.iter_mut().zip(&pwm[..mixer::HORIZONTAL]) {
                *o = mixer::setpoint(*p);
            }
            self.plant.step(&self.held, h);
        }
        self.since_answer_s = 0.0;
    }

    /// Takes the next frame after `actuate` has integrated one period (not called after a trial's
    /// last frame: the next trial starts instead).
    fn next(&mut self, actuate: impl FnOnce(&mut Twin)) -> (Shot, Option<TrialEnd>) {
        let Some(now) = self.current else {
            return (self.start(), None);
        };
        let seq = now.seq + 1;
        // From the frame count, not summed: every period is the same number of nanoseconds.
        let time_s = (seq - 1) as f64 * self.dt;
        if now.status.is_terminal() {
            let end = TrialEnd {
                trial: now.trial,
                steps: now.step,
                status: now.status,
                dropped: self.trial_dropped,
            };
            return (self.begin_trial(now.trial + 1, seq, time_s), Some(end));
        }
        actuate(self);
        let step = now.step + 1;
        let state = *self.plant.state();
        let status = if self.eye.camera.view(&state.pose, &self.eye.cable).is_none() {
            StepStatus::Lost
        } else if step >= self.steps_per_trial {
            StepStatus::TimeLimit
        } else {
            StepStatus::Running
        };
        (self.take(seq, time_s, now.trial, step, status), None)
    }

    /// The answer that reaches the thrusters now: `answer` itself without latency, else the one
    /// sent `latency` frames ago (none in a trial's first `latency` periods).
    fn arrive(&mut self, answer: Option<&[f64]>) -> InFlight {
        let answer = answer.map(|sp| {
            let mut v = [0.0; MAX_THRUSTERS];
            v.iter_mut().zip(sp).for_each(|(d, s)| *d = *s);
            v
        });
        if self.latency == 0 {
            return answer;
        }
        self.in_flight.push_back(answer);
        if self.in_flight.len() > self.latency {
            self.in_flight.pop_front().flatten()
        } else {
            None
        }
    }

    /// The start mark of trial `trial`: its place in the cycle of start poses, or the trial itself
    /// when every trial starts anew.
    pub fn mark_of(&self, trial: u32) -> u32 {
        if self.cycle_len > 0 {
            trial % self.cycle_len as u32
        } else {
            trial
        }
    }

    /// Where trial `trial` starts: a new random pose, or the next of the cycle.
    fn start_pose(&mut self, trial: u32) -> model::Pose {
        let k = if self.cycle_len > 0 {
            trial as usize % self.cycle_len
        } else {
            0
        };
        if self.cycle_len > 0 && k < self.cycle.len() {
            return self.cycle[k];
        }
        let resets = &mut self.resets;
        let pose = model::start_pose(&self.eye.camera, &self.eye.cable, &self.reposition, |r| {
            resets.random_range(r)
        });
        if self.cycle_len > 0 {
            self.cycle.push(pose);
        }
        pose
    }

    fn begin_trial(&mut self, trial: u32, seq: u64, time_s: f64) -> Shot {
        let pose = self.start_pose(trial);
        self.mark = self.mark_of(trial);
        self.eye.start_drops(self.mark);
        self.plant.place(VehicleState {
            pose,
            ..Default::default()
        });
        self.held.iter_mut().for_each(|h| *h = 0.0);
        if let Some(a) = &mut self.autopilot {
            // The operator puts the vehicle back; the pilot's sticks stay as they were (a
            // MAVLink companion keeps sending its last ones until the next step's).
            let v = ardusub::vehicle_of(self.plant.state(), &self.plant.pose_rate());
            a.core.repositioned(v);
        }
        // What was on its way answered the last trial's frames.
        self.in_flight.clear();
        self.since_answer_s = 0.0;
        self.trial_dropped = 0;
        self.take(seq, time_s, trial, 0, StepStatus::Running)
    }

    fn take(&mut self, seq: u64, time_s: f64, trial: u32, step: u32, status: StepStatus) -> Shot {
        let state = *self.plant.state();
        let rate = self.plant.pose_rate();
        let lost = self.eye.draw_drop();
        let dropped = lost && !status.is_terminal();
        if dropped {
            self.dropped += 1;
            self.trial_dropped += 1;
        }
        let shot = Shot {
            seq,
            time_s,
            trial,
            step,
            mark: self.mark,
            status,
            state,
            rate,
            truth: self.eye.truth(&state, &rate),
            dropped,
        };
        self.current = Some(shot);
        shot
    }

    /// Renders the current frame's image into `out`.
    pub fn render(&mut self, out: &mut [u8]) -> Result<(), VisionError> {
        let shot = self.current.expect("the twin has started");
        self.eye.render(&shot, out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn only(edit: impl FnOnce(&mut TwinParams)) -> TwinParams {
        let mut t = TwinParams::ideal();
        edit(&mut t);
        t
    }

    #[test]
    fn frames_are_counted_timed_and_trials_end_and_restart() {
        let s = Scenario::default();
        let mut t = only(|t| t.trials.duration_s = 1.0);
        t.frames.dropped.enabled = false;
        let mut twin = Twin::new(&s, &t, 3, false).unwrap();
        assert_eq!(twin.steps_per_trial(), 5);
        let first = twin.start();
        assert_eq!((first.seq, first.trial, first.step), (1, 0, 0));
        assert_eq!(first.status, StepStatus::Running);
        assert_eq!(first.state.velocity, model::Velocity::default());
        assert_eq!(
            first.truth.found, 1,
            "the cable is in view at a trial's start"
        );
        let mut last = first;
        let mut ends = Vec::new();
        for _ in 0..12 {
            let (shot, end) = twin.advance(Some(&[0.0; 3]));
            assert_eq!(shot.seq, last.seq + 1);
            assert!((shot.time_s - last.time_s - 0.2).abs() < 1e-12);
            ends.extend(end);
            last = shot;
        }
        // Trial 0: steps 0..=5 (seq 1..=6, the 6th a time limit); trial 1: seq 7..=12; trial 2.
        assert_eq!(
            ends.iter()
                .map(|e| (e.trial, e.steps, e.status))
                .collect::<Vec<_>>(),
            vec![(0, 5, StepStatus::TimeLimit), (1, 5, StepStatus::TimeLimit)]
        );
        assert_eq!((last.seq, last.trial, last.step), (13, 2, 0));
    }

    /// With a cycle of N, trial k starts where trial k - N started; without, every start is new.
    #[test]
    fn trials_cycle_through_their_start_poses() {
        let s = Scenario::default();
        let starts = |cycle: u32| {
            let mut t = TwinParams::default();
            t.trials.duration_s = 0.4;
            t.trials.cycle = cycle;
            t.frames.dropped.enabled = false;
            let mut twin = Twin::new(&s, &t, 9, false).unwrap();
            let mut poses = vec![twin.start().state.pose];
            while poses.len() < 12 {
                if let (shot, Some(_)) = twin.advance(Some(&[0.0; 3])) {
                    poses.push(shot.state.pose);
                }
            }
            poses
        };
        let cycled = starts(5);
        for k in 5..12 {
            assert_eq!(cycled[k], cycled[k - 5], "trial {k}");
        }
        assert!((1..5).all(|k| cycled[k] != cycled[0]));
        let fresh = starts(0);
        assert_eq!(fresh[..5], cycled[..5], "the same draws");
        assert!((5..12).all(|k| fresh[k] != fresh[k - 5]));
    }

    #[test]
    fn a_trial_ends_when_the_cable_leaves_the_image() {
        let s = Scenario::default();
        let mut twin = Twin::new(&s, &TwinParams::ideal(), 1, false).unwrap();
        twin.start();
        let mut shot = twin.start();
        while shot.status == StepStatus::Running {
            shot = twin.advance(Some(&[0.0, 0.0, 1.0])).0;
        }
        assert_eq!(shot.status, StepStatus::Lost);
        assert_eq!(shot.truth.found, 0);
        let (next, end) = twin.advance(Some(&[1.0; 3]));
        assert_eq!(end.unwrap().status, StepStatus::Lost);
        assert_eq!((next.trial, next.step), (1, 0));
        assert_eq!(
            twin.plant().thrust(),
            &[0.0; 3],
            "repositioned with the thrusters stopped"
        );
    }

    /// Without answers the thrusters hold the last setpoints, then the watchdog stops them.
    #[test]
    fn the_thrusters_hold_then_the_watchdog_stops_them() {
        let s = Scenario::default();
        let t = TwinParams::ideal();
        let mut twin = Twin::new(&s, &t, 1, false).unwrap();
        twin.start();
        twin.advance(Some(&[0.0, 0.0, 0.3]));
        assert_eq!(twin.plant().thrust()[2], 0.3);
        let periods = (t.thrusters.watchdog_s / 0.2).round() as usize;
        for k in 1..periods {
            twin.advance(None);
            assert_eq!(
                twin.plant().thrust()[2],
                0.3,
                "held after {k} missing answers"
            );
        }
        twin.advance(None);
        assert_eq!(twin.plant().thrust()[2], 0.0, "stopped by the watchdog");
        twin.advance(Some(&[0.0, 0.0, 0.1]));
        assert_eq!(twin.plant().thrust()[2], 0.1);
    }

    /// With a latency of L frames, the answer to frame t drives the plant from frame t + L on: the
    /// thrust history is the undelayed one shifted by L periods, and a trial starts with nothing in
    /// flight.
    #[test]
    fn a_latency_delays_each_answer_by_its_frames() {
        let s = Scenario::default();
        let thrusts = |latency: Option<u32>| {
            let mut t = TwinParams::ideal();
            t.trials.duration_s = 2.0;
            if let Some(frames) = latency {
                t.latency.enabled = true;
                t.latency.frames = frames;
            }
            let mut twin = Twin::new(&s, &t, 2, false).unwrap();
            twin.start();
            (0..25)
                .map(|k| {
                    let (shot, _) = twin.advance(Some(&[0.0, 0.0, 0.01 * (k + 1) as f64]));
                    (shot.step, twin.plant().thrust()[2])
                })
                .collect::<Vec<_>>()
        };
        let (now, late) = (thrusts(None), thrusts(Some(2)));
        assert_eq!(
            TwinParams::ideal().latency.periods(),
            0,
            "off in the ideal twin"
        );
        for k in 0..25 {
            let (step, thrust) = late[k];
            if step == 0 {
                continue; // the answer to a trial's last frame is never applied
            }
            // Step n's thrust answers frame n - 1 without latency, frame n - 3 with two frames.
            let want = if step >= 3 { now[k - 2].1 } else { 0.0 };
            assert_eq!(thrust, want, "frame {k} (step {step})");
        }
    }

    /// Frames are dropped at the configured rate, never a trial's last; off, none is.
    #[test]
    fn frames_are_dropped_at_the_configured_rate() {
        let s = Scenario::default();
        let mut t = only(|t| t.frames.dropped.enabled = true);
        t.frames.dropped.probability = 0.1;
        t.trials.duration_s = 4.0;
        let mut twin = Twin::new(&s, &t, 5, false).unwrap();
        twin.start();
        let n = 20_000;
        let (mut dropped, mut terminal) = (0, 0);
        for _ in 0..n {
            let (shot, _) = twin.advance(Some(&[0.0, 0.0, 0.0]));
            if shot.status.is_terminal() {
                terminal += 1;
                assert!(!shot.dropped, "a trial's last frame is never dropped");
            }
            dropped += shot.dropped as u64;
        }
        assert_eq!(dropped, twin.dropped());
        // Binomial: the rate over the frames that may drop, within 4 standard deviations.
        let m = (n - terminal) as f64;
        let rate = dropped as f64 / m;
        let sd = (0.1 * 0.9 / m).sqrt();
        assert!((rate - 0.1).abs() < 4.0 * sd, "rate {rate}");
        let mut off = Twin::new(&s, &TwinParams::ideal(), 5, false).unwrap();
        off.start();
        assert!((0..2000).all(|_| !off.advance(Some(&[0.0; 3])).0.dropped));
    }

    /// The camera mounted to starboard sees a centred cable to the left; mounted forward, it moves
    /// across the image when the vehicle turns.
    #[test]
    fn the_off_centre_camera_shifts_x_g() {
        let s = Scenario::default();
        let floor_width = 2.0 * 30f64.to_radians().tan();
        let t = only(|t| t.camera.enabled = true);
        let over_the_cable = VehicleState::default();
        let still = PoseRate::default();
        let eye = TwinEye::new(&s, &t, 1, false).unwrap();
        let centred = TwinEye::new(&s, &TwinParams::ideal(), 1, false).unwrap();
        let shifted = eye.truth(&over_the_cable, &still);
        assert!(centred.truth(&over_the_cable, &still).x_g.abs() < 1e-12);
        assert!(
            (shifted.x_g + t.camera.mount_y_m / floor_width).abs() < 1e-9,
            "{}",
            shifted.x_g
        );
        // Turning to starboard at r: the forward-mounted camera sweeps to starboard at
        // mount_x * r, so the cable moves left: dx_g/dt = -mount_x r / floor width.
        let r = 0.05;
        let turning = PoseRate { psi: r, ..still };
        let rate = eye.truth(&over_the_cable, &turning).x_g_rate;
        let want = -t.camera.mount_x_m * r / floor_width;
        assert!((rate - want).abs() < 1e-3 * want.abs(), "{rate} vs {want}");
        assert!(centred.truth(&over_the_cable, &turning).x_g_rate.abs() < 1e-9);
    }

    /// The twin's camera renders with its own effects: noise that changes from frame to frame, the
    /// lamp's fall-off to the corners; with the image effects off, a clean, steady image.
    #[test]
    fn the_twin_camera_renders_its_own_image_effects() {
        let s = Scenario::default();
        let render = |params: &TwinParams, seq: u64| {
            let mut eye = TwinEye::new(&s, params, 1, true).unwrap();
            let state = VehicleState::default();
            let shot = Shot {
                seq,
                time_s: 0.0,
                trial: 0,
                step: seq as u32,
                mark: 0,
                status: StepStatus::Running,
                state,
                rate: PoseRate::default(),
                truth: eye.truth(&state, &PoseRate::default()),
                dropped: false,
            };
            let mut out = vec![0u8; 320 * 240];
            eye.render(&shot, &mut out).unwrap();
            out
        };
        let diff_sd = |a: &[u8], b: &[u8]| {
            let d: Vec<f64> = a
                .iter()
                .zip(b)
                .map(|(&x, &y)| x as f64 - y as f64)
                .collect();
            let m = d.iter().sum::<f64>() / d.len() as f64;
            (d.iter().map(|v| (v - m).powi(2)).sum::<f64>() / d.len() as f64).sqrt()
        };
        let corner_vs_centre = |img: &[u8]| {
            let px = |i: usize, j: usize| img[j * 320 + i] as f64;
            let corners = (px(2, 2) + px(317, 2) + px(2, 237) + px(317, 237)) / 4.0;
            corners / px(100, 120)
        };
        let twin = TwinParams::default();
        let (a, b) = (render(&twin, 1), render(&twin, 2));
        // Two frames' noise: sqrt(2) times the sensor's.
        let sd = diff_sd(&a, &b) / 2f64.sqrt();
        assert!((sd - twin.render.noise.std_dn).abs() < 1.5, "noise {sd}");
        let clean = TwinParams::ideal();
        let (c, d) = (render(&clean, 1), render(&clean, 2));
        assert_eq!(c, d, "no noise");
        let mut no_noise = TwinParams::default();
        no_noise.render.noise.enabled = false;
        assert_eq!(render(&no_noise, 1), render(&no_noise, 2));
        assert!(
            corner_vs_centre(&render(&no_noise, 1)) < 0.8,
            "darker corners"
        );
        assert!((corner_vs_centre(&c) - 1.0).abs() < 1e-9, "even light");
    }

    /// Trials from the same start mark meet the same dropped frames and image noise; other marks
    /// other ones.
    #[test]
    fn frame_noise_is_drawn_per_start_mark() {
        let s = Scenario::default();
        let mut t = TwinParams::default();
        t.trials.duration_s = 20.0;
        t.frames.dropped.probability = 0.2;
        let mut twin = Twin::new(&s, &t, 4, false).unwrap();
        let mut trials: Vec<Vec<(u32, bool, u64)>> = vec![vec![]];
        let mut shot = twin.start();
        while trials.len() <= 7 {
            trials
                .last_mut()
                .unwrap()
                .push((shot.mark, shot.dropped, shot.noise_index()));
            let (next, end) = twin.advance(Some(&[0.2, 0.2, 0.05]));
            if end.is_some() {
                trials.push(vec![]);
            }
            shot = next;
        }
        let cycle = t.trials.cycle as usize;
        for k in cycle..7 {
            let (a, b) = (&trials[k], &trials[k - cycle]);
            assert_eq!(
                a[0].0,
                b[0].0,
                "trial {k} starts from the mark of trial {}",
                k - cycle
            );
            let n = a.len().min(b.len()) - 1; // a trial's last frame is never dropped
            assert_eq!(a[..n], b[..n], "trial {k}");
        }
        // A trial that loses the cable ends early: the two compared over what both have.
        let n = trials[0].len().min(trials[1].len()).min(50);
        assert!(n > 0);
        assert_ne!(trials[0][..n], trials[1][..n]);
        assert!(trials[0].iter().any(|f| f.1), "frames are dropped");
    }

    #[test]
    fn the_same_seed_gives_the_same_twin() {
        let s = Scenario::default();
        let t = TwinParams::default();
        let run = |seed| {
            let mut twin = Twin::new(&s, &t, seed, false).unwrap();
            twin.start();
            (0..600)
                .map(|k| {
                    twin.advance(Some(&[0.3, 0.2, 0.1 * ((k % 7) as f64 - 3.0)]))
                        .0
                })
                .collect::<Vec<_>>()
        };
        assert_eq!(run(4), run(4));
        assert_ne!(run(4), run(5));
    }

    fn bluerov2() -> (Scenario, TwinParams) {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../config/bluerov2");
        (
            config::load(&dir.join("scenario.toml")).unwrap(),
            config::load(&dir.join("twin.toml")).unwrap(),
        )
    }

    /// The scenario's yaw model is the stand-in's rate loop on the vehicle: from rest in ALT_HOLD,
    /// a yaw command u held, the yaw rate settles at u x r_max, and a first order fitted by least
    /// squares over the first second has the scenario's time constant (within 10%).
    #[test]
    fn the_scenarios_yaw_rate_loop_is_the_stand_ins() {
        let (scenario, twin) = bluerov2();
        let pilot = scenario.pilot.clone().unwrap();
        let tau = pilot.yaw_rate_time_constant_s.unwrap();
        let params = twin
            .autopilot
            .unwrap()
            .flown_by(&pilot, "autopilot")
            .unwrap();
        for u in [0.2, 0.5, 1.0] {
            let t0 = Instant::now();
            let mut core = ArduSub::new(&params, Vec::new(), t0);
            core.fly(pilot.mode.into()).unwrap();
            let command = model::Forces {
                yaw: u,
                ..Default::default()
            };
            core.pilot(t0, model::pilot::axes(&command, &pilot, core.gain()));
            let mut plant = TwinPlant::new(&scenario, &TwinParams::ideal());
            let (h, mut setpoints, mut rate) = (0.01, [0.0; 4], Vec::new());
            for k in 1..=300 {
                let v = ardusub::vehicle_of(plant.state(), &plant.pose_rate());
                let pwm = core.control(h, v);
                for (s, p) in setpoints.iter_mut().zip(&pwm[..4]) {
                    *s = mixer::setpoint(*p);
                }
                plant.step(&setpoints, h);
                rate.push((k as f64 * h, plant.state().velocity.r));
            }
            let settled = rate[250..].iter().map(|r| r.1).sum::<f64>() / 50.0;
            let want = u * pilot.yaw_rate_max();
            assert!(
                (settled - want).abs() < 0.03 * want,
                "u = {u}: {settled} rad/s against {want}"
            );
            let misfit = |tau: f64| -> f64 {
                rate[..100]
                    .iter()
                    .map(|&(t, r)| (r - settled * (1.0 - (-t / tau).exp())).powi(2))
                    .sum()
            };
            let fitted = (1..=500)
                .map(|i| i as f64 * 0.001)
                .min_by(|a, b| misfit(*a).total_cmp(&misfit(*b)))
                .unwrap();
            assert!(
                (fitted - tau).abs() < 0.1 * tau,
                "u = {u}: fitted {fitted} s against the scenario's {tau} s"
            );
        }
    }

    /// The same stack's commands reach the same vehicle whichever way they come: as setpoints on
    /// the twin's thruster topic (the twin turns them into sticks and takes off itself) or as a
    /// MAVLink companion sends them (the mode and arming commands, then MANUAL_CONTROL with the same
    /// conversion, received as frames from the ground station): the same motor outputs at every
    /// sub-step and the same frames, step for step.
    #[test]
    fn the_thruster_topic_and_mavlink_fly_the_same_vehicle() {
        use mavlink::Message;
        use mavlink::dialects::ardupilotmega::{
            COMMAND_LONG_DATA, MANUAL_CONTROL_DATA, MavCmd, MavMessage,
        };
        let (scenario, twin) = bluerov2();
        let pilot = scenario.pilot.clone().unwrap();
        let frame = |msg: &MavMessage| ardusub::wire::Frame {
            version: mavlink::MavlinkVersion::V2,
            sequence: 0,
            system_id: 255,
            component_id: 190,
            message_id: msg.message_id(),
            payload: ardusub::wire::payload(msg),
        };
        let command = |command, p1: f32, p2: f32| {
            MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
                param1: p1,
                param2: p2,
                command,
                target_system: 1,
                target_component: 1,
                ..Default::default()
            })
        };
        let mut topic = Twin::new(&scenario, &twin, 7, false).unwrap();
        let mut wire = Twin::new(&scenario, &twin, 7, false).unwrap();
        let (mut a, mut b) = (topic.start(), wire.start());
        assert_eq!(a, b);
        let layout = model::ThrusterLayout::new(&scenario.thrusters);
        let mut moved = 0.0f64;
        for k in 0..150 {
            // Some setpoints (the allocator's would do): every DOF in turn and together.
            let t = k as f64 * 0.2;
            let setpoints = [
                0.6 * (0.7 * t).sin(),
                -0.4 * (0.3 * t).cos(),
                0.5 * (0.5 * t).sin(),
                0.3,
            ];
            let answer = (!a.status.is_terminal()).then_some(&setpoints[..]);
            let (next_a, _) = topic.advance(answer);
            let ap = wire.autopilot_mut().unwrap();
            let now = ap.at(b.time_s);
            let core = ap.core_mut();
            if k == 0 {
                let mode = ardusub::Mode::from(pilot.mode).number() as f32;
                core.receive(
                    now,
                    &frame(&command(MavCmd::MAV_CMD_DO_SET_MODE, 1.0, mode)),
                );
                core.receive(
                    now,
                    &frame(&command(MavCmd::MAV_CMD_COMPONENT_ARM_DISARM, 1.0, 0.0)),
                );
            }
            if answer.is_some() {
                let axes = model::pilot::setpoint_axes(&layout, &setpoints, &pilot, core.gain());
                let msg = MavMessage::MANUAL_CONTROL(MANUAL_CONTROL_DATA {
                    x: axes.x,
                    y: axes.y,
                    z: axes.z,
                    r: axes.r,
                    target: 1,
                    ..Default::default()
                });
                core.receive(now, &frame(&msg));
            }
            let (next_b, _) = wire.advance_piloted();
            let (ca, cb) = (
                topic.autopilot().unwrap().core(),
                wire.autopilot().unwrap().core(),
            );
            assert!(ca.armed() && cb.armed() && ca.mode() == cb.mode());
            assert_eq!(ca.sticks(), cb.sticks(), "step {k}");
            assert_eq!(ca.pwm(), cb.pwm(), "step {k}");
            assert_eq!(next_a, next_b, "step {k}");
            moved = moved.max(next_a.state.velocity.v.abs());
            (a, b) = (next_a, next_b);
        }
        assert!(moved > 0.05, "the sticks moved the vehicle: {moved} m/s");
    }
}
