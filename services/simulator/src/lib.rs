//! The simulator's core: the identified model of the vehicle (paper Table I) in the pool with the
//! cable, driven by thruster setpoints, cut into episodes.
//!
//! An episode starts at a random pose around the cable with the cable in view (DESIGN.md: x_g and
//! Theta uniform in the reset box, all velocities 0) and ends when the cable leaves the image
//! ([`StepStatus::Lost`]) or after `max_steps` steps ([`StepStatus::TimeLimit`]). The loop is data-driven:
//! [`Simulator::step`] advances one control period with the setpoints of the current step.
//!
//! [`lockstep`] is the simulator's side of the mesh's protocol (publish a step, wait for its
//! setpoints, re-send, deadline), also without IPC; the `simulator` binary binds it to iceoryx2. The
//! trainer composes [`Simulator`] directly, in one process.

pub mod lockstep;

use config::{ResetParams, Scenario, StepStatus, Timing};
use model::{Cable, Camera, Dynamics, ThrusterLayout, VehicleState};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

/// One step of an episode: its identifiers, the vehicle's state and the episode's status.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SimStep {
    /// Episodes count from 0.
    pub episode: u32,
    /// Steps count from 0 (the reset) within the episode.
    pub step: u32,
    /// Simulated time since the start of the run (s).
    pub time_s: f64,
    pub state: VehicleState,
    pub status: StepStatus,
}

/// The simulated world.
pub struct Simulator {
    dynamics: Dynamics,
    layout: ThrusterLayout,
    camera: Camera,
    cable: Cable,
    timing: Timing,
    reset: ResetParams,
    rng: StdRng,
    current: SimStep,
    started: bool,
    /// Control periods integrated since the start of the run: the clock. Simulated time is this
    /// count times the sample time, not a sum of sample times, whose rounding grows with the run
    /// (after 14,796 periods of 0.2 s the sum's nanoseconds step by 199,999,999, and the mesh's
    /// perception, which takes its period from the stamps, no longer saw the trainer's 0.2 s).
    periods: u64,
}

impl Simulator {
    /// A simulator of `scenario` whose resets draw from `seed`; call [`Simulator::reset`] to start.
    pub fn new(scenario: &Scenario, seed: u64) -> Self {
        Simulator {
            dynamics: Dynamics::new(scenario.commanded_model()),
            layout: ThrusterLayout::new(&scenario.thrusters),
            camera: Camera::new(&scenario.camera),
            cable: Cable::new(&scenario.cable),
            timing: scenario.timing.clone(),
            reset: scenario.reset.clone(),
            rng: StdRng::seed_from_u64(seed),
            current: SimStep {
                episode: 0,
                step: 0,
                time_s: 0.0,
                state: VehicleState::default(),
                status: StepStatus::Running,
            },
            started: false,
            periods: 0,
        }
    }

    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    pub fn cable(&self) -> &Cable {
        &self.cable
    }

    pub fn layout(&self) -> &ThrusterLayout {
        &self.layout
    }

    /// The current step.
    pub fn current(&self) -> &SimStep {
        &self.current
    }

    /// Starts the next episode at a random pose with the cable in view.
    pub fn reset(&mut self) -> SimStep {
        let rng = &mut self.rng;
        let pose = model::start_pose(&self.camera, &self.cable, &self.reset, |range| {
            rng.random_range(range)
        });
        let episode = if self.started {
            self.current.episode + 1
        } else {
            0
        };
        self.started = true;
        self.current = SimStep {
            episode,
            step: 0,
            time_s: self.current.time_s,
            state: VehicleState {
                pose,
                ..VehicleState::default()
            },
            status: StepStatus::Running,
        };
        self.current
    }

    /// Integrates one control period under `setpoints`; after a terminal step it starts the next
    /// episode instead (the setpoints answering a terminal step are not applied).
    pub fn step(&mut self, setpoints: &[f64]) -> SimStep {
        if !self.started || self.current.status.is_terminal() {
            return self.reset();
        }
        let forces = self.layout.forces(setpoints);
        let dt = self.timing.sample_time_s;
        let state = self.dynamics.step(&self.current.state, forces, dt);
        let step = self.current.step + 1;
        self.periods += 1;
        let status = if self.camera.view(&state.pose, &self.cable).is_none() {
            StepStatus::Lost
        } else if step >= self.timing.max_steps {
            StepStatus::TimeLimit
        } else {
            StepStatus::Running
        };
        self.current = SimStep {
            episode: self.current.episode,
            step,
            time_s: self.periods as f64 * dt,
            state,
            status,
        };
        self.current
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scenario() -> Scenario {
        Scenario::default()
    }

    #[test]
    fn resets_put_the_cable_where_the_reset_box_says() {
        let s = scenario();
        let mut sim = Simulator::new(&s, 7);
        for _ in 0..500 {
            let start = sim.reset();
            assert_eq!(start.step, 0);
            assert_eq!(start.state.velocity, model::Velocity::default());
            let line = sim
                .camera()
                .view(&start.state.pose, sim.cable())
                .expect("cable in view at reset");
            assert!(line.x_g.abs() <= s.reset.x_g_max + 1e-6);
            assert!(line.theta.abs() <= s.reset.theta_max_deg.to_radians() + 1e-9);
        }
    }

    #[test]
    fn episodes_end_at_the_time_limit_or_when_the_cable_is_lost() {
        let mut s = scenario();
        s.timing.max_steps = 10;
        let mut sim = Simulator::new(&s, 1);
        let first = sim.reset();
        let mut last = first;
        for _ in 0..10 {
            last = sim.step(&[0.0, 0.0, 0.0]);
        }
        assert_eq!(
            (last.episode, last.step, last.status),
            (0, 10, StepStatus::TimeLimit)
        );
        // The next call starts episode 1 and ignores its setpoints.
        let next = sim.step(&[1.0, 1.0, 1.0]);
        assert_eq!(
            (next.episode, next.step, next.status),
            (1, 0, StepStatus::Running)
        );
        assert_eq!(next.state.velocity, model::Velocity::default());

        // Full lateral thrust drives the vehicle off the cable well within 200 steps.
        s.timing.max_steps = 200;
        let mut sim = Simulator::new(&s, 2);
        sim.reset();
        let mut step = sim.step(&[0.0, 0.0, 1.0]);
        while step.status == StepStatus::Running {
            step = sim.step(&[0.0, 0.0, 1.0]);
        }
        assert_eq!(step.status, StepStatus::Lost);
        assert!(step.step < 200);
        assert!(sim.camera().view(&step.state.pose, sim.cable()).is_none());
    }

    #[test]
    fn the_same_seed_gives_the_same_episodes() {
        let s = scenario();
        let run = |seed| {
            let mut sim = Simulator::new(&s, seed);
            (0..20).map(|_| sim.reset().state.pose).collect::<Vec<_>>()
        };
        assert_eq!(run(3), run(3));
        assert_ne!(run(3), run(4));
    }

    #[test]
    fn time_advances_by_the_sample_time() {
        let s = scenario();
        let mut sim = Simulator::new(&s, 1);
        sim.reset();
        let st = sim.step(&[0.0; 3]);
        assert!((st.time_s - 0.2).abs() < 1e-12);
    }

    /// Over a long run (200 episodes of 200 steps, more than the 100 of step one), the stamps of
    /// consecutive steps are exactly one sample time apart in nanoseconds, as perception reads its
    /// period from them; summing 0.2 s per step, they were 199,999,999 ns apart from step 14,796 on.
    #[test]
    fn the_clock_keeps_exact_periods_over_a_long_run() {
        let s = scenario();
        let period_ns = (s.timing.sample_time_s * 1e9).round() as u64;
        let mut sim = Simulator::new(&s, 1);
        let mut last = lockstep::Published {
            seq: 0,
            step: sim.reset(),
        };
        for seq in 1..=40_000 {
            let step = sim.step(&[0.0; 3]);
            let now = lockstep::Published { seq, step };
            if step.step > 0 {
                assert_eq!(
                    now.stamp().time_ns - last.stamp().time_ns,
                    period_ns,
                    "step {seq}"
                );
            } else {
                assert_eq!(
                    now.stamp().time_ns,
                    last.stamp().time_ns,
                    "a reset takes no time"
                );
            }
            last = now;
        }
        assert!(last.step.episode >= 100, "{} episodes", last.step.episode);
    }
}
