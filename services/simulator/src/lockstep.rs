//! The simulator's side of the data-driven lockstep (DESIGN.md, "Lockstep and time"), as a plain
//! state machine: no IPC and no clock of its own (every call is given `now`), so the protocol is
//! unit-tested here and the `simulator` binary only binds it to its two ports.
//!
//! The simulator publishes step `seq` and waits for the thruster setpoints answering `seq`; then it
//! integrates one control period and publishes `seq + 1`. While it waits it re-publishes the same step
//! every `resend` (a consumer answers a repeat from its cache), which heals a consumer that was not
//! listening yet and a lost wake-up. Before the mesh has ever answered it waits indefinitely
//! ([`Phase::Connecting`]); once it runs, a step unanswered for `deadline` is integrated with zero
//! thrust (logged by the shell): the mesh never hangs on one missing message. Setpoints of any other
//! step are ignored.
//!
//! `seq` counts published steps from 1 across episodes; after a terminal step the setpoints answering
//! it start the next episode (see [`Simulator::step`]), exactly as the in-process trainer does.

use crate::{SimStep, Simulator, Status};
use config::MAX_THRUSTERS;
use messages::{Stamp, StepStatus, VehicleStateMsg};
use std::time::{Duration, Instant};

/// The protocol's time limits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Timing {
    /// Re-publish the current step after this long without its setpoints.
    pub resend: Duration,
    /// Once running, integrate with zero thrust after this long without the step's setpoints.
    pub deadline: Duration,
    /// While the mesh has never answered, say so this often.
    pub waiting_note: Duration,
}

impl Timing {
    pub fn new(resend: Duration, deadline: Duration) -> Self {
        Timing {
            resend,
            deadline,
            waiting_note: Duration::from_secs(5),
        }
    }

    /// How long the shell may block without input before asking [`Lockstep::on_time`] again: half
    /// the shorter limit, so each fires at most half a period late.
    pub fn tick(&self) -> Duration {
        (self.resend.min(self.deadline) / 2).max(Duration::from_millis(1))
    }
}

/// A step as published: its sequence number and the simulator's step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Published {
    pub seq: u64,
    pub step: SimStep,
}

impl Published {
    /// The step's stamp: `seq`, simulated time (ns), episode, step and status.
    pub fn stamp(&self) -> Stamp {
        let status = match self.step.status {
            Status::Running => StepStatus::Running,
            Status::Lost => StepStatus::Lost,
            Status::TimeLimit => StepStatus::TimeLimit,
        };
        let time_ns = (self.step.time_s * 1e9).round() as u64;
        Stamp::new(self.seq, time_ns, self.step.episode, self.step.step, status)
    }

    /// The message on the vehicle-state topic; the pose rate is the state's own (still water).
    pub fn message(&self) -> VehicleStateMsg {
        let state = &self.step.state;
        VehicleStateMsg::new(self.stamp(), state, &state.pose_rate())
    }
}

/// Where the protocol stands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    /// No setpoints have arrived yet: re-send the first step, never time out.
    Connecting,
    /// The mesh answers: re-send, and step with zero thrust after the deadline.
    Running,
    /// The requested episodes are done: nothing more is published.
    Finished,
}

/// What the protocol's clock says is due.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Due {
    /// Nothing yet.
    Idle,
    /// The mesh runs and the current step went unanswered past the deadline: close it without an
    /// answer.
    Deadline,
    /// Publish the current step again; `waiting_for_mesh` is set (to the time waited since the
    /// start) every [`Timing::waiting_note`] while the mesh has never answered.
    Resend { waiting_for_mesh: Option<Duration> },
}

/// The protocol's clock, the same for every plant run in lockstep (the simulator here, the vehicle
/// twin with `--lockstep`): when to re-send the current step, when its deadline has passed, when to
/// say the mesh has not answered yet. Plain state fed `now`.
#[derive(Clone, Copy, Debug)]
pub struct Deadlines {
    timing: Timing,
    phase: Phase,
    started_at: Instant,
    /// When the current step was first published, and last (re-)published.
    first_sent: Instant,
    last_sent: Instant,
    last_note: Instant,
}

impl Deadlines {
    /// The first step was published at `now`; the mesh has not answered yet.
    pub fn start(timing: Timing, now: Instant) -> Self {
        Deadlines {
            timing,
            phase: Phase::Connecting,
            started_at: now,
            first_sent: now,
            last_sent: now,
            last_note: now,
        }
    }

    pub fn phase(&self) -> Phase {
        self.phase
    }

    pub fn timing(&self) -> &Timing {
        &self.timing
    }

    /// How long the current step has waited for its answer.
    pub fn waited(&self, now: Instant) -> Duration {
        now.saturating_duration_since(self.first_sent)
    }

    /// The next step was published at `now` (the mesh answers, or the deadline closed one).
    pub fn published(&mut self, now: Instant) {
        self.phase = Phase::Running;
        self.first_sent = now;
        self.last_sent = now;
    }

    /// Nothing more is published.
    pub fn finish(&mut self) {
        self.phase = Phase::Finished;
    }

    /// Time passed: what is due at `now`.
    pub fn on_time(&mut self, now: Instant) -> Due {
        match self.phase {
            Phase::Finished => Due::Idle,
            Phase::Running if self.waited(now) >= self.timing.deadline => Due::Deadline,
            Phase::Connecting | Phase::Running => {
                if now.saturating_duration_since(self.last_sent) < self.timing.resend {
                    return Due::Idle;
                }
                self.last_sent = now;
                let waiting_for_mesh = (self.phase == Phase::Connecting
                    && now.saturating_duration_since(self.last_note) >= self.timing.waiting_note)
                    .then(|| {
                        self.last_note = now;
                        now.saturating_duration_since(self.started_at)
                    });
                Due::Resend { waiting_for_mesh }
            }
        }
    }
}

/// Why a step was integrated.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Cause {
    /// Its setpoints arrived.
    Answered,
    /// Its setpoints did not arrive within the deadline: zero thrust.
    Deadline,
}

/// An episode that ended (its terminal step was answered).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EpisodeEnd {
    pub episode: u32,
    /// Steps taken (the terminal step's index).
    pub steps: u32,
    /// [`Status::Lost`] or [`Status::TimeLimit`].
    pub status: Status,
    /// Episodes ended since the start, this one included.
    pub done: u32,
}

/// The current step was closed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Advance {
    /// The step that was closed.
    pub closed: Published,
    pub cause: Cause,
    /// How long the closed step waited for its setpoints.
    pub waited: Duration,
    /// The episode that ended with it, if it was terminal.
    pub ended: Option<EpisodeEnd>,
    /// The next step to publish; `None` when the requested episodes are done (stop).
    pub next: Option<Published>,
}

/// What the shell does after an event.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Reaction {
    /// Nothing (setpoints of another step, or no limit reached).
    Idle,
    /// Publish the current step again; `waiting_for_mesh` is set (to the time waited since the start)
    /// every [`Timing::waiting_note`] while the mesh has never answered.
    Resend {
        step: Published,
        waiting_for_mesh: Option<Duration>,
    },
    /// The current step was closed: publish `next`, or stop when there is none.
    Advanced(Advance),
}

/// The simulator in lockstep with the mesh.
pub struct Lockstep {
    sim: Simulator,
    clock: Deadlines,
    /// Episodes to run; 0 runs forever.
    episodes: u32,
    episodes_done: u32,
    current: Published,
}

/// Zero thrust, for a step whose setpoints never came.
const ZERO_THRUST: [f64; MAX_THRUSTERS] = [0.0; MAX_THRUSTERS];

impl Lockstep {
    /// Resets `sim` to its first episode: the caller publishes [`Lockstep::current`] at `now`.
    pub fn start(mut sim: Simulator, timing: Timing, episodes: u32, now: Instant) -> Self {
        let step = sim.reset();
        Lockstep {
            sim,
            clock: Deadlines::start(timing, now),
            episodes,
            episodes_done: 0,
            current: Published { seq: 1, step },
        }
    }

    /// The step published last (waiting for its setpoints unless finished).
    pub fn current(&self) -> Published {
        self.current
    }

    pub fn phase(&self) -> Phase {
        self.clock.phase()
    }

    pub fn timing(&self) -> &Timing {
        self.clock.timing()
    }

    /// Episodes ended so far.
    pub fn episodes_done(&self) -> u32 {
        self.episodes_done
    }

    /// The episodes requested (0: forever).
    pub fn episodes(&self) -> u32 {
        self.episodes
    }

    /// Setpoints answering step `seq` arrived at `now`.
    pub fn on_setpoints(&mut self, seq: u64, setpoints: &[f64], now: Instant) -> Reaction {
        if self.phase() == Phase::Finished || seq != self.current.seq {
            return Reaction::Idle;
        }
        self.advance(setpoints, Cause::Answered, now)
    }

    /// Time passed (the shell calls this on every wake-up): re-send, or step past the deadline.
    pub fn on_time(&mut self, now: Instant) -> Reaction {
        match self.clock.on_time(now) {
            Due::Idle => Reaction::Idle,
            Due::Deadline => self.advance(&ZERO_THRUST, Cause::Deadline, now),
            Due::Resend { waiting_for_mesh } => Reaction::Resend {
                step: self.current,
                waiting_for_mesh,
            },
        }
    }

    fn advance(&mut self, setpoints: &[f64], cause: Cause, now: Instant) -> Reaction {
        let closed = self.current;
        let waited = self.clock.waited(now);
        let ended = closed.step.status.is_terminal().then(|| {
            self.episodes_done += 1;
            EpisodeEnd {
                episode: closed.step.episode,
                steps: closed.step.step,
                status: closed.step.status,
                done: self.episodes_done,
            }
        });
        if ended.is_some() && self.episodes > 0 && self.episodes_done >= self.episodes {
            self.clock.finish();
            return Reaction::Advanced(Advance {
                closed,
                cause,
                waited,
                ended,
                next: None,
            });
        }
        // After a terminal step this starts the next episode and ignores the setpoints.
        let step = self.sim.step(setpoints);
        self.current = Published {
            seq: closed.seq + 1,
            step,
        };
        self.clock.published(now);
        Reaction::Advanced(Advance {
            closed,
            cause,
            waited,
            ended,
            next: Some(self.current),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use config::Scenario;

    const MS: Duration = Duration::from_millis(1);

    fn timing() -> Timing {
        Timing::new(100 * MS, 2000 * MS)
    }

    fn scenario(max_steps: u32) -> Scenario {
        let mut s = Scenario::default();
        s.timing.max_steps = max_steps;
        s
    }

    fn next(r: Reaction) -> Published {
        match r {
            Reaction::Advanced(Advance { next: Some(p), .. }) => p,
            other => panic!("expected a next step, got {other:?}"),
        }
    }

    #[test]
    fn answered_steps_follow_the_core_and_count_up() {
        let s = scenario(200);
        let t0 = Instant::now();
        let mut ls = Lockstep::start(Simulator::new(&s, 3), timing(), 0, t0);
        let mut twin = Simulator::new(&s, 3);
        assert_eq!(ls.current().step, twin.reset());
        assert_eq!(ls.current().seq, 1);
        assert_eq!(ls.phase(), Phase::Connecting);
        for k in 1..=5u64 {
            let sp = [0.1 * k as f64, -0.2, 0.3];
            let p = next(ls.on_setpoints(k, &sp, t0 + k as u32 * MS));
            assert_eq!(p.seq, k + 1);
            assert_eq!(p.step, twin.step(&sp));
            assert_eq!(ls.phase(), Phase::Running);
        }
    }

    #[test]
    fn setpoints_of_other_steps_are_ignored() {
        let t0 = Instant::now();
        let mut ls = Lockstep::start(Simulator::new(&scenario(200), 1), timing(), 0, t0);
        assert_eq!(ls.on_setpoints(0, &[1.0; 3], t0), Reaction::Idle);
        assert_eq!(ls.on_setpoints(2, &[1.0; 3], t0), Reaction::Idle);
        next(ls.on_setpoints(1, &[1.0; 3], t0));
        assert_eq!(ls.on_setpoints(1, &[1.0; 3], t0), Reaction::Idle);
        assert_eq!(ls.current().seq, 2);
    }

    #[test]
    fn connecting_re_sends_forever_and_notes_the_wait() {
        let t0 = Instant::now();
        let mut ls = Lockstep::start(Simulator::new(&scenario(200), 1), timing(), 0, t0);
        let first = ls.current();
        assert_eq!(ls.on_time(t0 + 50 * MS), Reaction::Idle);
        let mut notes = 0;
        // Ten minutes in steps of 100 ms: a re-send each time, never a step, a note every 5 s.
        for k in 1..=6000u32 {
            match ls.on_time(t0 + k * 100 * MS) {
                Reaction::Resend {
                    step,
                    waiting_for_mesh,
                } => {
                    assert_eq!(step, first);
                    if let Some(w) = waiting_for_mesh {
                        notes += 1;
                        assert_eq!(w, k * 100 * MS);
                    }
                }
                other => panic!("{other:?}"),
            }
        }
        assert_eq!(notes, 120);
        assert_eq!(ls.phase(), Phase::Connecting);
    }

    #[test]
    fn running_re_sends_then_steps_with_zero_thrust_at_the_deadline() {
        let s = scenario(200);
        let t0 = Instant::now();
        let mut ls = Lockstep::start(Simulator::new(&s, 5), timing(), 0, t0);
        let mut twin = Simulator::new(&s, 5);
        twin.reset();
        let t1 = t0 + 10 * MS;
        let second = next(ls.on_setpoints(1, &[0.5, 0.5, 0.5], t1));
        twin.step(&[0.5, 0.5, 0.5]);
        assert_eq!(ls.on_time(t1 + 99 * MS), Reaction::Idle);
        assert!(matches!(
            ls.on_time(t1 + 100 * MS),
            Reaction::Resend { step, waiting_for_mesh: None } if step == second
        ));
        assert_eq!(ls.on_time(t1 + 150 * MS), Reaction::Idle);
        assert!(matches!(
            ls.on_time(t1 + 1999 * MS),
            Reaction::Resend { .. }
        ));
        match ls.on_time(t1 + 2000 * MS) {
            Reaction::Advanced(a) => {
                assert_eq!(a.cause, Cause::Deadline);
                assert_eq!(a.closed, second);
                assert_eq!(a.waited, 2000 * MS);
                let third = a.next.unwrap();
                assert_eq!(third.seq, 3);
                assert_eq!(third.step, twin.step(&[0.0; 3]));
            }
            other => panic!("{other:?}"),
        }
        // The deadline runs from the new step's publication.
        assert!(matches!(
            ls.on_time(t1 + 2100 * MS),
            Reaction::Resend { .. }
        ));
    }

    #[test]
    fn a_terminal_step_starts_the_next_episode_and_the_last_one_stops() {
        let s = scenario(2);
        let t0 = Instant::now();
        let mut ls = Lockstep::start(Simulator::new(&s, 9), timing(), 2, t0);
        let mut twin = Simulator::new(&s, 9);
        twin.reset();
        let mut ends = Vec::new();
        let mut seq = 1;
        loop {
            match ls.on_setpoints(seq, &[0.2, 0.2, 0.0], t0) {
                Reaction::Advanced(a) => {
                    ends.extend(a.ended);
                    let Some(p) = a.next else { break };
                    assert_eq!(p.step, twin.step(&[0.2, 0.2, 0.0]));
                    assert_eq!(p.seq, seq + 1);
                    seq = p.seq;
                }
                other => panic!("{other:?}"),
            }
        }
        // Episode 0: seq 1..=3 (steps 0..=2); episode 1: seq 4..=6; the answer to seq 6 stops.
        assert_eq!(seq, 6);
        assert_eq!(
            ends,
            vec![
                EpisodeEnd {
                    episode: 0,
                    steps: 2,
                    status: Status::TimeLimit,
                    done: 1
                },
                EpisodeEnd {
                    episode: 1,
                    steps: 2,
                    status: Status::TimeLimit,
                    done: 2
                },
            ]
        );
        assert_eq!(ls.phase(), Phase::Finished);
        assert_eq!(ls.on_time(t0 + 10_000 * MS), Reaction::Idle);
        assert_eq!(ls.on_setpoints(6, &[0.0; 3], t0), Reaction::Idle);
    }

    #[test]
    fn stamps_carry_the_step() {
        let s = scenario(200);
        let t0 = Instant::now();
        let mut ls = Lockstep::start(Simulator::new(&s, 2), timing(), 0, t0);
        for k in 1..=3 {
            next(ls.on_setpoints(k, &[0.0; 3], t0));
        }
        let p = ls.current();
        let msg = p.message();
        assert_eq!(
            msg.stamp,
            Stamp::new(4, 600_000_000, 0, 3, StepStatus::Running)
        );
        assert_eq!(msg.state(), p.step.state);
        assert_eq!(msg.pose_rate(), p.step.state.pose_rate());
    }

    #[test]
    fn the_tick_serves_the_shorter_limit() {
        assert_eq!(timing().tick(), 50 * MS);
        assert_eq!(Timing::new(100 * MS, 30 * MS).tick(), 15 * MS);
        assert_eq!(Timing::new(Duration::ZERO, 30 * MS).tick(), MS);
    }
}
