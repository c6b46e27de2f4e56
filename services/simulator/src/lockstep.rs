//! The simulator as a plant of the lockstep protocol (`runtime::lockstep`): the protocol's state
//! machine is `runtime::lockstep::Lockstep<SimPlant>`; this module says what the simulator publishes
//! (the vehicle state of step `seq`), how setpoints name the step they answer (its `seq`), and that
//! a step unanswered past its deadline is integrated with zero thrust.
//!
//! `seq` counts published steps from 1 across episodes; after a terminal step the setpoints answering
//! it start the next episode (see [`Simulator::step`]), exactly as the in-process trainer does.

use crate::{SimStep, Simulator};
use config::{MAX_THRUSTERS, StepStatus};
use messages::{Stamp, VehicleStateMsg};
use runtime::lockstep::{Advanced, Plant};

/// A step as published: its sequence number and the simulator's step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Published {
    pub seq: u64,
    pub step: SimStep,
}

impl Published {
    /// The step's stamp: `seq`, simulated time (ns), episode, step and status.
    pub fn stamp(&self) -> Stamp {
        let time_ns = (self.step.time_s * 1e9).round() as u64;
        Stamp::new(
            self.seq,
            time_ns,
            self.step.episode,
            self.step.step,
            self.step.status,
        )
    }

    /// The message on the vehicle-state topic; the pose rate is the state's own (still water).
    pub fn message(&self) -> VehicleStateMsg {
        let state = &self.step.state;
        VehicleStateMsg::new(self.stamp(), state, &state.pose_rate())
    }
}

/// An episode that ended (its terminal step was answered).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EpisodeEnd {
    pub episode: u32,
    /// Steps taken (the terminal step's index).
    pub steps: u32,
    /// [`StepStatus::Lost`] or [`StepStatus::TimeLimit`].
    pub status: StepStatus,
}

/// Zero thrust, for a step whose setpoints never came.
const ZERO_THRUST: [f64; MAX_THRUSTERS] = [0.0; MAX_THRUSTERS];

/// The simulator, published step by step.
pub struct SimPlant {
    sim: Simulator,
    current: Published,
}

impl SimPlant {
    pub fn new(sim: Simulator) -> Self {
        let current = Published {
            seq: 0,
            step: *sim.current(),
        };
        SimPlant { sim, current }
    }

    pub fn simulator(&self) -> &Simulator {
        &self.sim
    }

    fn end(&self) -> EpisodeEnd {
        let step = &self.current.step;
        EpisodeEnd {
            episode: step.episode,
            steps: step.step,
            status: step.status,
        }
    }
}

impl Plant for SimPlant {
    type Step = Published;
    type End = EpisodeEnd;

    fn answers(step: &Published, seq: u64) -> bool {
        step.seq == seq
    }

    fn is_terminal(step: &Published) -> bool {
        step.step.status.is_terminal()
    }

    fn start(&mut self) -> Advanced<Self> {
        self.current = Published {
            seq: 1,
            step: self.sim.reset(),
        };
        Advanced {
            step: self.current,
            passed: 0,
            ended: Vec::new(),
        }
    }

    fn advance(&mut self, answer: Option<&[f64]>) -> Advanced<Self> {
        let ended = if self.current.step.status.is_terminal() {
            vec![self.end()]
        } else {
            Vec::new()
        };
        // After a terminal step this starts the next episode and ignores the setpoints.
        let step = self.sim.step(answer.unwrap_or(&ZERO_THRUST));
        self.current = Published {
            seq: self.current.seq + 1,
            step,
        };
        Advanced {
            step: self.current,
            passed: 0,
            ended,
        }
    }

    fn finish(&mut self) -> Vec<EpisodeEnd> {
        vec![self.end()]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use config::Scenario;
    use runtime::lockstep::{Cause, Limits, Lockstep, Reaction};
    use std::time::{Duration, Instant};

    const MS: Duration = Duration::from_millis(1);

    fn limits() -> Limits {
        Limits::new(100 * MS, 2000 * MS)
    }

    fn scenario(max_steps: u32) -> Scenario {
        let mut s = Scenario::default();
        s.timing.max_steps = max_steps;
        s
    }

    fn start(s: &Scenario, seed: u64, episodes: u32) -> (Lockstep<SimPlant>, Published) {
        let (ls, first) = Lockstep::start(
            SimPlant::new(Simulator::new(s, seed)),
            limits(),
            episodes,
            Instant::now(),
        );
        (ls, next(first))
    }

    fn next(r: Reaction<SimPlant>) -> Published {
        match r {
            Reaction::Publish { next, .. } => next,
            other => panic!("expected a next step, got {other:?}"),
        }
    }

    #[test]
    fn answered_steps_follow_the_simulator_and_count_up() {
        let s = scenario(200);
        let t0 = Instant::now();
        let (mut ls, first) = start(&s, 3, 0);
        let mut reference = Simulator::new(&s, 3);
        assert_eq!(first.step, reference.reset());
        assert_eq!(first.seq, 1);
        for k in 1..=5u64 {
            let sp = [0.1 * k as f64, -0.2, 0.3];
            let p = next(ls.on_answer(k, &sp, t0 + k as u32 * MS));
            assert_eq!(p.seq, k + 1);
            assert_eq!(p.step, reference.step(&sp));
        }
    }

    #[test]
    fn a_step_past_its_deadline_is_integrated_with_zero_thrust() {
        let s = scenario(200);
        let t0 = Instant::now();
        let (mut ls, first) = start(&s, 5, 0);
        let mut reference = Simulator::new(&s, 5);
        reference.reset();
        next(ls.on_answer(first.seq, &[0.5, 0.5, 0.5], t0));
        reference.step(&[0.5, 0.5, 0.5]);
        match ls.on_time(t0 + 2000 * MS) {
            Reaction::Publish { next, cause, .. } => {
                assert_eq!(cause, Cause::Deadline);
                assert_eq!(next.seq, 3);
                assert_eq!(next.step, reference.step(&[0.0; 3]));
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn a_terminal_step_starts_the_next_episode_and_the_last_one_stops() {
        let s = scenario(2);
        let t0 = Instant::now();
        let (mut ls, first) = start(&s, 9, 2);
        let mut reference = Simulator::new(&s, 9);
        reference.reset();
        let mut ends = Vec::new();
        let mut seq = first.seq;
        loop {
            match ls.on_answer(seq, &[0.2, 0.2, 0.0], t0) {
                Reaction::Publish { next, ended, .. } => {
                    ends.extend(ended);
                    assert_eq!(next.step, reference.step(&[0.2, 0.2, 0.0]));
                    assert_eq!(next.seq, seq + 1);
                    seq = next.seq;
                }
                Reaction::Finished { ended, .. } => {
                    ends.extend(ended);
                    break;
                }
                other => panic!("{other:?}"),
            }
        }
        // Episode 0: seq 1..=3 (steps 0..=2); episode 1: seq 4..=6; the answer to seq 6 stops.
        assert_eq!(seq, 6);
        let end = |episode| EpisodeEnd {
            episode,
            steps: 2,
            status: StepStatus::TimeLimit,
        };
        assert_eq!(ends, vec![end(0), end(1)]);
        assert_eq!(ls.episodes_done(), 2);
    }

    #[test]
    fn stamps_carry_the_step() {
        let s = scenario(200);
        let t0 = Instant::now();
        let (mut ls, _) = start(&s, 2, 0);
        for k in 1..=3 {
            next(ls.on_answer(k, &[0.0; 3], t0));
        }
        let p = *ls.current();
        let msg = p.message();
        assert_eq!(
            msg.stamp,
            Stamp::new(4, 600_000_000, 0, 3, StepStatus::Running)
        );
        assert_eq!(msg.state(), p.step.state);
        assert_eq!(msg.pose_rate(), p.step.state.pose_rate());
    }
}
