//! The plant's side of the lockstep: publish a step, wait for its answer, integrate, publish the
//! next. One state machine for every plant (the simulator, the vehicle twin), fed `now`.

use super::clock::{Deadlines, Due, Limits, Phase};
use crate::Flow;
use std::fmt::Debug;
use std::time::{Duration, Instant};

/// A plant that the mesh drives in lockstep.
pub trait Plant {
    /// A step as published (the simulator's state, the twin's frame).
    type Step: Copy + Debug + PartialEq;
    /// How an episode (a trial on the vehicle) ended.
    type End: Clone + Debug + PartialEq;

    /// Whether an answer carrying `key` (the stamp field the plant matches answers by: the
    /// simulator's `seq`, the twin's frame time) answers `step`.
    fn answers(step: &Self::Step, key: u64) -> bool;
    /// Whether the answer to `step` ends its episode.
    fn is_terminal(step: &Self::Step) -> bool;
    /// The first step to publish.
    fn start(&mut self) -> Advanced<Self>;
    /// Integrates one control period under `answer` (`None`: the step went unanswered past its
    /// deadline) and takes the next step to publish. After a terminal step this starts the next
    /// episode; the episode that ended is in [`Advanced::ended`].
    fn advance(&mut self, answer: Option<&[f64]>) -> Advanced<Self>;
    /// Closes the last requested episode (its terminal step was answered): no next step.
    fn finish(&mut self) -> Vec<Self::End>;
}

/// What the plant publishes next, and what happened on the way.
pub struct Advanced<P: Plant + ?Sized> {
    pub step: P::Step,
    /// Steps integrated on the way that are never published (the twin's dropped frames).
    pub passed: u32,
    /// Episodes that ended on the way.
    pub ended: Vec<P::End>,
}

/// Why the current step was closed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Cause {
    /// The first step.
    Start,
    /// Its answer arrived.
    Answered,
    /// No answer within the deadline.
    Deadline,
}

/// What the shell does after an event.
pub enum Reaction<P: Plant> {
    /// Nothing (an answer to another step, or no limit reached).
    Idle,
    /// Publish the current step again; `waiting_for_mesh` is set (to the time waited since the
    /// start) every [`Limits::waiting_note`] while the mesh has never answered.
    Resend {
        step: P::Step,
        waiting_for_mesh: Option<Duration>,
    },
    /// Publish `next`. `closed` is the step it follows (`None` at the start) and `waited` how long
    /// that step waited for its answer.
    Publish {
        closed: Option<P::Step>,
        next: P::Step,
        cause: Cause,
        waited: Duration,
        passed: u32,
        ended: Vec<P::End>,
    },
    /// The requested episodes are done: stop.
    Finished {
        closed: P::Step,
        cause: Cause,
        waited: Duration,
        ended: Vec<P::End>,
    },
}

// By hand: a derive would ask the plant itself to be `Debug`, not only its steps and ends.
impl<P: Plant> std::fmt::Debug for Reaction<P> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Reaction::Idle => f.write_str("Idle"),
            Reaction::Resend {
                step,
                waiting_for_mesh,
            } => f
                .debug_struct("Resend")
                .field("step", step)
                .field("waiting_for_mesh", waiting_for_mesh)
                .finish(),
            Reaction::Publish {
                closed,
                next,
                cause,
                waited,
                passed,
                ended,
            } => f
                .debug_struct("Publish")
                .field("closed", closed)
                .field("next", next)
                .field("cause", cause)
                .field("waited", waited)
                .field("passed", passed)
                .field("ended", ended)
                .finish(),
            Reaction::Finished {
                closed,
                cause,
                waited,
                ended,
            } => f
                .debug_struct("Finished")
                .field("closed", closed)
                .field("cause", cause)
                .field("waited", waited)
                .field("ended", ended)
                .finish(),
        }
    }
}

/// A closed step, as the shell hears of it: for its logs and trial records.
#[derive(Debug)]
pub struct Closed<P: Plant> {
    /// The step closed (`None` for the start, which closes none).
    pub step: Option<P::Step>,
    /// The step published next (`None` once the requested episodes are done).
    pub next: Option<P::Step>,
    pub cause: Cause,
    /// How long the closed step waited for its answer.
    pub waited: Duration,
    /// Steps integrated on the way and never published (the twin's dropped frames).
    pub passed: u32,
    /// Episodes that ended on the way.
    pub ended: Vec<P::End>,
}

/// A plant's process (the simulator, the vehicle twin, replay): how it carries the protocol's
/// reactions out, through its own ports. The dispatch over [`Reaction`] is written once, in
/// [`Lockstep::carry_out`]; a process's loop only hands it answers ([`Lockstep::answer`]) and
/// wake-ups ([`Lockstep::tick`]).
pub trait Shell<P: Plant> {
    /// Puts `step` out (the simulator's state, the twin's frame); `again` when the step is re-sent
    /// because the mesh has not answered it yet.
    fn publish(&mut self, plant: &mut P, step: &P::Step, again: bool) -> anyhow::Result<()>;
    /// A step was closed (before its successor is published).
    fn closed(&mut self, lockstep: &Lockstep<P>, closed: Closed<P>) {
        let _ = (lockstep, closed);
    }
    /// The mesh has never answered, `waited` since the start (every [`Limits::waiting_note`]).
    fn waiting(&mut self, step: &P::Step, waited: Duration) {
        let _ = (step, waited);
    }
}

/// A plant in lockstep with the mesh.
pub struct Lockstep<P: Plant> {
    plant: P,
    clock: Deadlines,
    /// Episodes to run; 0 runs forever.
    episodes: u32,
    done: u32,
    current: P::Step,
}

impl<P: Plant> Lockstep<P> {
    /// Starts `plant`: publish the step in the returned reaction at `now`.
    pub fn start(mut plant: P, limits: Limits, episodes: u32, now: Instant) -> (Self, Reaction<P>) {
        let first = plant.start();
        let lockstep = Lockstep {
            plant,
            clock: Deadlines::start(limits, now),
            episodes,
            done: first.ended.len() as u32,
            current: first.step,
        };
        let reaction = Reaction::Publish {
            closed: None,
            next: first.step,
            cause: Cause::Start,
            waited: Duration::ZERO,
            passed: first.passed,
            ended: first.ended,
        };
        (lockstep, reaction)
    }

    /// The step published last (waiting for its answer unless finished).
    pub fn current(&self) -> &P::Step {
        &self.current
    }

    pub fn phase(&self) -> Phase {
        self.clock.phase()
    }

    pub fn limits(&self) -> &Limits {
        self.clock.limits()
    }

    pub fn plant(&self) -> &P {
        &self.plant
    }

    pub fn plant_mut(&mut self) -> &mut P {
        &mut self.plant
    }

    /// The plant, once the lockstep is over.
    pub fn into_plant(self) -> P {
        self.plant
    }

    /// Episodes ended so far.
    pub fn episodes_done(&self) -> u32 {
        self.done
    }

    /// The episodes requested (0: forever).
    pub fn episodes(&self) -> u32 {
        self.episodes
    }

    /// An answer carrying `key` arrived at `now`: the current step's answer advances the plant; any
    /// other is ignored.
    pub fn on_answer(&mut self, key: u64, answer: &[f64], now: Instant) -> Reaction<P> {
        if self.phase() == Phase::Finished || !P::answers(&self.current, key) {
            return Reaction::Idle;
        }
        self.advance(Some(answer), Cause::Answered, now)
    }

    /// Time passed (the shell calls this on every wake-up): re-send, or close the step past its
    /// deadline.
    pub fn on_time(&mut self, now: Instant) -> Reaction<P> {
        match self.clock.on_time(now) {
            Due::Idle => Reaction::Idle,
            Due::Deadline => self.advance(None, Cause::Deadline, now),
            Due::Resend { waiting_for_mesh } => Reaction::Resend {
                step: self.current,
                waiting_for_mesh,
            },
        }
    }

    /// Carries `reaction` out through `shell`; [`Flow::Stop`] once the requested episodes are done.
    pub fn carry_out<S: Shell<P>>(
        &mut self,
        shell: &mut S,
        reaction: Reaction<P>,
    ) -> anyhow::Result<Flow> {
        match reaction {
            Reaction::Idle => {}
            Reaction::Resend {
                step,
                waiting_for_mesh,
            } => {
                if let Some(waited) = waiting_for_mesh {
                    shell.waiting(&step, waited);
                }
                shell.publish(&mut self.plant, &step, true)?;
            }
            Reaction::Publish {
                closed,
                next,
                cause,
                waited,
                passed,
                ended,
            } => {
                let report = Closed {
                    step: closed,
                    next: Some(next),
                    cause,
                    waited,
                    passed,
                    ended,
                };
                shell.closed(self, report);
                shell.publish(&mut self.plant, &next, false)?;
            }
            Reaction::Finished {
                closed,
                cause,
                waited,
                ended,
            } => {
                let report = Closed {
                    step: Some(closed),
                    next: None,
                    cause,
                    waited,
                    passed: 0,
                    ended,
                };
                shell.closed(self, report);
                return Ok(Flow::Stop);
            }
        }
        Ok(Flow::Continue)
    }

    /// An answer carrying `key` arrived at `now` ([`Lockstep::on_answer`]), carried out by `shell`.
    pub fn answer<S: Shell<P>>(
        &mut self,
        shell: &mut S,
        key: u64,
        answer: &[f64],
        now: Instant,
    ) -> anyhow::Result<Flow> {
        let reaction = self.on_answer(key, answer, now);
        self.carry_out(shell, reaction)
    }

    /// A wake-up at `now` ([`Lockstep::on_time`]), carried out by `shell`.
    pub fn tick<S: Shell<P>>(&mut self, shell: &mut S, now: Instant) -> anyhow::Result<Flow> {
        let reaction = self.on_time(now);
        self.carry_out(shell, reaction)
    }

    fn advance(&mut self, answer: Option<&[f64]>, cause: Cause, now: Instant) -> Reaction<P> {
        let closed = self.current;
        let waited = self.clock.waited(now);
        let last = P::is_terminal(&closed) && self.episodes > 0 && self.done + 1 >= self.episodes;
        if last {
            let ended = self.plant.finish();
            self.done += ended.len() as u32;
            self.clock.finish();
            return Reaction::Finished {
                closed,
                cause,
                waited,
                ended,
            };
        }
        let next = self.plant.advance(answer);
        self.done += next.ended.len() as u32;
        self.current = next.step;
        self.clock.published(now);
        Reaction::Publish {
            closed: Some(closed),
            next: next.step,
            cause,
            waited,
            passed: next.passed,
            ended: next.ended,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: Duration = Duration::from_millis(1);

    /// A counter plant: each step is (episode, step, key); an episode lasts `len` steps; a step whose
    /// key is a multiple of 3 is lost on the way (passed) unless it is an episode's last, as the
    /// twin drops frames; the answers are recorded.
    struct Toy {
        len: u32,
        episode: u32,
        step: u32,
        key: u64,
        answers: Vec<Option<f64>>,
    }

    #[derive(Clone, Copy, Debug, PartialEq)]
    struct ToyStep {
        episode: u32,
        step: u32,
        key: u64,
        last: bool,
    }

    impl Toy {
        fn new(len: u32) -> Self {
            Toy {
                len,
                episode: 0,
                step: 0,
                key: 0,
                answers: Vec::new(),
            }
        }

        fn take(&mut self) -> ToyStep {
            self.key += 1;
            ToyStep {
                episode: self.episode,
                step: self.step,
                key: self.key,
                last: self.step + 1 >= self.len,
            }
        }

        fn tick(&mut self, ended: &mut Vec<u32>) {
            if self.step + 1 >= self.len {
                ended.push(self.episode);
                self.episode += 1;
                self.step = 0;
            } else {
                self.step += 1;
            }
        }
    }

    impl Plant for Toy {
        type Step = ToyStep;
        type End = u32;
        fn answers(step: &ToyStep, key: u64) -> bool {
            step.key == key
        }
        fn is_terminal(step: &ToyStep) -> bool {
            step.last
        }
        fn start(&mut self) -> Advanced<Self> {
            Advanced {
                step: self.take(),
                passed: 0,
                ended: vec![],
            }
        }
        fn advance(&mut self, answer: Option<&[f64]>) -> Advanced<Self> {
            self.answers.push(answer.map(|a| a[0]));
            let mut ended = Vec::new();
            self.tick(&mut ended);
            let mut step = self.take();
            let mut passed = 0;
            while step.key.is_multiple_of(3) && !step.last {
                passed += 1;
                self.tick(&mut ended);
                step = self.take();
            }
            Advanced {
                step,
                passed,
                ended,
            }
        }
        fn finish(&mut self) -> Vec<u32> {
            vec![self.episode]
        }
    }

    fn limits() -> Limits {
        Limits::new(100 * MS, 2000 * MS)
    }

    fn next(r: Reaction<Toy>) -> ToyStep {
        match r {
            Reaction::Publish { next, .. } => next,
            other => panic!("expected a step, got {other:?}"),
        }
    }

    #[test]
    fn answers_advance_the_plant_and_others_are_ignored() {
        let t0 = Instant::now();
        let (mut ls, first) = Lockstep::start(Toy::new(10), limits(), 0, t0);
        let first = next(first);
        assert_eq!(first.key, 1);
        assert_eq!(ls.phase(), Phase::Connecting);
        assert!(matches!(ls.on_answer(7, &[1.0], t0), Reaction::Idle));
        let second = next(ls.on_answer(1, &[0.5], t0 + MS));
        assert_eq!(ls.phase(), Phase::Running);
        // Key 3 was passed on the way (a dropped frame).
        assert_eq!(second.key, 2);
        match ls.on_answer(2, &[0.25], t0 + 2 * MS) {
            Reaction::Publish {
                closed,
                next,
                passed,
                cause,
                ..
            } => {
                assert_eq!(closed, Some(second));
                assert_eq!((next.key, passed, cause), (4, 1, Cause::Answered));
            }
            other => panic!("{other:?}"),
        }
        assert!(matches!(ls.on_answer(2, &[0.0], t0), Reaction::Idle));
        assert_eq!(ls.plant().answers, vec![Some(0.5), Some(0.25)]);
    }

    #[test]
    fn an_unanswered_step_is_re_sent_then_closed_without_an_answer_at_the_deadline() {
        let t0 = Instant::now();
        let (mut ls, first) = Lockstep::start(Toy::new(10), limits(), 0, t0);
        let first = next(first);
        // Connecting: re-sends, never a deadline.
        for k in 1..100u32 {
            match ls.on_time(t0 + k * 100 * MS) {
                Reaction::Resend { step, .. } => assert_eq!(step, first),
                other => panic!("{other:?}"),
            }
        }
        let t1 = t0 + 10_000 * MS;
        let second = next(ls.on_answer(first.key, &[1.0], t1));
        match ls.on_time(t1 + 2000 * MS) {
            Reaction::Publish {
                closed,
                cause,
                waited,
                ..
            } => {
                assert_eq!(closed, Some(second));
                assert_eq!((cause, waited), (Cause::Deadline, 2000 * MS));
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(ls.plant().answers, vec![Some(1.0), None]);
    }

    #[test]
    fn the_last_requested_episode_finishes_the_run() {
        let t0 = Instant::now();
        let (mut ls, first) = Lockstep::start(Toy::new(3), limits(), 2, t0);
        let mut current = next(first);
        let mut ends = Vec::new();
        loop {
            match ls.on_answer(current.key, &[0.0], t0) {
                Reaction::Publish { next, ended, .. } => {
                    ends.extend(ended);
                    current = next;
                }
                Reaction::Finished { closed, ended, .. } => {
                    assert_eq!(closed, current);
                    ends.extend(ended);
                    break;
                }
                other => panic!("{other:?}"),
            }
        }
        assert_eq!(ends, vec![0, 1]);
        assert_eq!(ls.episodes_done(), 2);
        assert_eq!(ls.phase(), Phase::Finished);
        assert!(matches!(ls.on_time(t0 + 60_000 * MS), Reaction::Idle));
        assert!(matches!(
            ls.on_answer(current.key, &[0.0], t0),
            Reaction::Idle
        ));
    }

    /// What a shell was asked to do, in order.
    #[derive(Debug, PartialEq)]
    enum Done {
        Published {
            key: u64,
            again: bool,
        },
        Closed {
            key: Option<u64>,
            next: Option<u64>,
            cause: Cause,
            passed: u32,
            ended: Vec<u32>,
        },
        Waiting {
            key: u64,
        },
    }

    #[derive(Default)]
    struct Recording(Vec<Done>);

    impl Shell<Toy> for Recording {
        fn publish(&mut self, _: &mut Toy, step: &ToyStep, again: bool) -> anyhow::Result<()> {
            self.0.push(Done::Published {
                key: step.key,
                again,
            });
            Ok(())
        }
        fn closed(&mut self, _: &Lockstep<Toy>, c: Closed<Toy>) {
            self.0.push(Done::Closed {
                key: c.step.map(|s| s.key),
                next: c.next.map(|s| s.key),
                cause: c.cause,
                passed: c.passed,
                ended: c.ended,
            });
        }
        fn waiting(&mut self, step: &ToyStep, _: Duration) {
            self.0.push(Done::Waiting { key: step.key });
        }
    }

    #[test]
    fn the_shell_hears_every_closed_step_before_its_successor_goes_out_and_stops_at_the_end() {
        let t0 = Instant::now();
        let mut shell = Recording::default();
        let (mut ls, first) = Lockstep::start(Toy::new(4), limits(), 1, t0);
        assert_eq!(ls.carry_out(&mut shell, first).unwrap(), Flow::Continue);
        // Before the mesh answers: re-sent, and the wait noted once it is long.
        let late = t0 + Limits::new(100 * MS, 2000 * MS).waiting_note;
        assert_eq!(ls.tick(&mut shell, late).unwrap(), Flow::Continue);
        // Another step's answer is ignored; the current one's advances (key 3 is passed on the way).
        assert_eq!(
            ls.answer(&mut shell, 9, &[0.0], late).unwrap(),
            Flow::Continue
        );
        assert_eq!(
            ls.answer(&mut shell, 1, &[0.0], late).unwrap(),
            Flow::Continue
        );
        assert_eq!(
            ls.answer(&mut shell, 2, &[0.0], late).unwrap(),
            Flow::Continue
        );
        assert_eq!(ls.answer(&mut shell, 4, &[0.0], late).unwrap(), Flow::Stop);
        use Done::*;
        assert_eq!(
            shell.0,
            vec![
                Closed {
                    key: None,
                    next: Some(1),
                    cause: Cause::Start,
                    passed: 0,
                    ended: vec![]
                },
                Published {
                    key: 1,
                    again: false
                },
                Waiting { key: 1 },
                Published {
                    key: 1,
                    again: true
                },
                Closed {
                    key: Some(1),
                    next: Some(2),
                    cause: Cause::Answered,
                    passed: 0,
                    ended: vec![]
                },
                Published {
                    key: 2,
                    again: false
                },
                Closed {
                    key: Some(2),
                    next: Some(4),
                    cause: Cause::Answered,
                    passed: 1,
                    ended: vec![]
                },
                Published {
                    key: 4,
                    again: false
                },
                Closed {
                    key: Some(4),
                    next: None,
                    cause: Cause::Answered,
                    passed: 0,
                    ended: vec![0]
                },
            ]
        );
    }
}
