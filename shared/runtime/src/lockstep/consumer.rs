//! The consumers' side: one output per step, never two steps mixed, no stale step acted on.
//!
//! Messages are delivered at least once: a producer that hears nothing back re-sends its step (at
//! start-up a consumer may not have been listening yet), and a restarted process receives the last
//! sample of each topic. A consumer therefore calls its core once per step and answers a repeated
//! step with the output it already computed ([`Once`]), so a learner never learns twice from one
//! step and the mesh stays deterministic; and it judges every stamp first ([`Screen`]): a new epoch
//! is followed, an older, stale or absurd step refused.

use crate::screen::{Refusal, Screen, Verdict};
use messages::Stamp;
use std::time::{Duration, Instant};

/// What [`Once::step`] did.
#[derive(Clone, Debug, PartialEq)]
pub enum Outcome<O> {
    /// A new step: the core was called.
    Fresh(O),
    /// The step just processed again: the same output, the core not called.
    Repeat(O),
    /// Refused (an older, stale or absurd step): ignore it.
    Refused(Refusal),
}

impl<O> Outcome<O> {
    /// The output to send, for a fresh or repeated step.
    pub fn output(self) -> Option<O> {
        match self {
            Outcome::Fresh(o) | Outcome::Repeat(o) => Some(o),
            Outcome::Refused(_) => None,
        }
    }
}

/// Calls a core once per step, on steps its [`Screen`] accepts.
#[derive(Debug)]
pub struct Once<O> {
    screen: Screen,
    last: Option<O>,
}

impl<O: Clone> Once<O> {
    pub fn new(screen: Screen) -> Self {
        Once { screen, last: None }
    }

    /// Judges `stamp` arriving at `now_ns` (the consumer's vehicle clock): the cached output for a
    /// repeat, `Ok(())` for a new step, the refusal otherwise (counted and logged by the screen).
    pub fn check(&mut self, stamp: &Stamp, now_ns: i64) -> Result<Option<O>, Refusal> {
        match self.screen.check(stamp, now_ns) {
            Verdict::New => Ok(None),
            Verdict::Repeat => Ok(self.last.clone()),
            Verdict::Refused(r) => Err(r),
        }
    }

    /// Records `out` as the output of the new step `stamp` (judged by [`Once::check`]).
    pub fn commit(&mut self, stamp: &Stamp, now_ns: i64, out: O) {
        self.screen.accept(stamp, now_ns);
        self.last = Some(out);
    }

    /// Runs `core` for a new step; answers the last step again with its output; refuses the rest.
    /// A step whose core fails is not accepted (the same step may come again, intact).
    pub fn step<E>(
        &mut self,
        stamp: &Stamp,
        now_ns: i64,
        core: impl FnOnce() -> Result<O, E>,
    ) -> Result<Outcome<O>, E> {
        match self.check(stamp, now_ns) {
            Err(r) => return Ok(Outcome::Refused(r)),
            Ok(Some(out)) => return Ok(Outcome::Repeat(out)),
            Ok(None) => {}
        }
        let out = core()?;
        self.commit(stamp, now_ns, out.clone());
        Ok(Outcome::Fresh(out))
    }

    /// The last step accepted: (epoch, seq).
    pub fn last(&self) -> Option<(u32, u64)> {
        self.screen.last()
    }

    pub fn screen(&self) -> &Screen {
        &self.screen
    }
}

/// Collects one value from each of `N` inputs for the same step. Steps are keyed by (epoch, seq): a
/// step of another epoch than the one being gathered is newer (its producer restarted).
#[derive(Debug)]
pub struct Gather<T, const N: usize> {
    epoch: u32,
    seq: Option<u64>,
    slots: [Option<T>; N],
    first_at: Option<Instant>,
}

impl<T: Copy, const N: usize> Default for Gather<T, N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<T: Copy, const N: usize> Gather<T, N> {
    pub fn new() -> Self {
        Gather {
            epoch: 0,
            seq: None,
            slots: [None; N],
            first_at: None,
        }
    }

    /// Puts input `i`'s value for step `seq` of `epoch`. Returns the whole set once every input has
    /// given its value for that step. A newer step drops an incomplete older one (returned as `Err`
    /// so the caller can log it); an older step is ignored.
    pub fn put(
        &mut self,
        i: usize,
        (epoch, seq): (u32, u64),
        value: T,
        now: Instant,
    ) -> Result<Option<(u64, [T; N])>, Partial<T, N>> {
        let mut dropped = None;
        // Another epoch counts as newer.
        let seq_here = self.seq.filter(|_| self.epoch == epoch);
        match (self.seq, seq_here) {
            (Some(_), Some(s)) if seq < s => return Ok(None),
            (Some(s), here) if here.is_none_or(|h| seq > h) => {
                // Only an older step that had started is dropped; a completed one left no values.
                if self.slots.iter().any(Option::is_some) {
                    dropped = Some(Partial {
                        seq: s,
                        values: self.slots,
                    });
                }
                self.reset(epoch, seq, now);
            }
            (None, _) => self.reset(epoch, seq, now),
            _ => {}
        }
        self.slots[i] = Some(value);
        if let Some(partial) = dropped {
            return Err(partial);
        }
        Ok(self.complete())
    }

    fn reset(&mut self, epoch: u32, seq: u64, now: Instant) {
        self.epoch = epoch;
        self.seq = Some(seq);
        self.slots = [None; N];
        self.first_at = Some(now);
    }

    fn complete(&mut self) -> Option<(u64, [T; N])> {
        if self.slots.iter().all(Option::is_some) {
            let seq = self.seq?;
            let values = self.slots.map(|v| v.expect("all present"));
            self.slots = [None; N];
            self.first_at = None;
            return Some((seq, values));
        }
        None
    }

    /// The step being gathered has waited `deadline` or longer at `now` since its first value:
    /// returns what arrived, and forgets the step.
    pub fn take_overdue(&mut self, deadline: Duration, now: Instant) -> Option<Partial<T, N>> {
        let started = self.first_at?;
        if now.saturating_duration_since(started) < deadline {
            return None;
        }
        let partial = Partial {
            seq: self.seq?,
            values: self.slots,
        };
        self.slots = [None; N];
        self.first_at = None;
        Some(partial)
    }

    /// Time left at `now` before the current step is overdue, if one is being gathered.
    pub fn time_left(&self, deadline: Duration, now: Instant) -> Option<Duration> {
        self.first_at
            .map(|t| deadline.saturating_sub(now.saturating_duration_since(t)))
    }
}

/// An incomplete step: the values that arrived.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Partial<T, const N: usize> {
    pub seq: u64,
    pub values: [Option<T>; N],
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::screen::ScreenLimits;
    use messages::StepStatus;

    fn once() -> Once<u64> {
        Once::new(Screen::new("t", ScreenLimits::control(0.2)))
    }

    #[test]
    fn once_calls_the_core_once_per_step() {
        let mut once = once();
        let mut calls = 0;
        let mut run = |seq: u64| {
            let st = Stamp::new(seq, 0, 0, 0, StepStatus::Running);
            once.step(&st, 1, || {
                calls += 1;
                Ok::<_, ()>(seq * 10)
            })
            .unwrap()
        };
        assert_eq!(run(1), Outcome::Fresh(10));
        assert_eq!(run(1), Outcome::Repeat(10));
        assert_eq!(run(0), Outcome::Refused(Refusal::Older { seq: 0, last: 1 }));
        assert_eq!(run(2), Outcome::Fresh(20));
        assert_eq!(calls, 2);
    }

    #[test]
    fn a_step_whose_core_failed_is_not_accepted() {
        let mut once = once();
        let st = Stamp::new(4, 0, 0, 0, StepStatus::Running);
        assert_eq!(once.step(&st, 1, || Err::<u64, _>("broken")), Err("broken"));
        assert_eq!(
            once.step(&st, 1, || Ok::<_, ()>(40)),
            Ok(Outcome::Fresh(40))
        );
        assert_eq!(once.last(), Some((0, 4)));
    }

    #[test]
    fn gather_completes_a_step_and_never_mixes_two() {
        let t0 = Instant::now();
        let mut g = Gather::<f64, 3>::new();
        assert_eq!(g.put(0, (0, 5), 1.0, t0), Ok(None));
        assert_eq!(g.put(2, (0, 5), 3.0, t0), Ok(None));
        assert_eq!(g.put(1, (0, 5), 2.0, t0), Ok(Some((5, [1.0, 2.0, 3.0]))));
        // An old step is ignored; a newer one drops the incomplete step.
        assert_eq!(g.put(0, (0, 6), 1.0, t0), Ok(None));
        assert_eq!(g.put(1, (0, 4), 9.0, t0), Ok(None));
        let dropped = g.put(1, (0, 7), 2.0, t0).unwrap_err();
        assert_eq!(dropped.seq, 6);
        assert_eq!(dropped.values, [Some(1.0), None, None]);
        assert_eq!(g.put(0, (0, 7), 1.0, t0), Ok(None));
        assert_eq!(g.put(2, (0, 7), 3.0, t0), Ok(Some((7, [1.0, 2.0, 3.0]))));
        // A restarted producer's epoch is newer, whatever its seq.
        assert_eq!(g.put(0, (0, 8), 1.0, t0), Ok(None));
        let dropped = g.put(0, (3, 1), 1.0, t0).unwrap_err();
        assert_eq!(dropped.seq, 8);
        assert_eq!(g.put(1, (3, 1), 2.0, t0), Ok(None));
        assert_eq!(g.put(2, (3, 1), 3.0, t0), Ok(Some((1, [1.0, 2.0, 3.0]))));
    }

    #[test]
    fn an_incomplete_step_becomes_overdue() {
        let t0 = Instant::now();
        let mut g = Gather::<f64, 2>::new();
        assert!(g.take_overdue(Duration::ZERO, t0).is_none());
        g.put(0, (0, 1), 1.0, t0).unwrap();
        let p = g.take_overdue(Duration::ZERO, t0).unwrap();
        assert_eq!((p.seq, p.values), (1, [Some(1.0), None]));
        assert!(g.take_overdue(Duration::ZERO, t0).is_none());
        g.put(0, (0, 2), 1.0, t0).unwrap();
        assert!(g.take_overdue(Duration::from_secs(3600), t0).is_none());
    }

    #[test]
    fn a_completed_step_is_not_reported_as_dropped() {
        let t0 = Instant::now();
        let mut g = Gather::<f64, 2>::new();
        g.put(0, (0, 1), 1.0, t0).unwrap();
        assert_eq!(g.put(1, (0, 1), 2.0, t0), Ok(Some((1, [1.0, 2.0]))));
        assert_eq!(
            g.put(0, (0, 2), 1.0, t0),
            Ok(None),
            "no spurious partial for the completed step 1"
        );
        let _ = g.take_overdue(Duration::ZERO, t0).unwrap();
        assert_eq!(
            g.put(0, (0, 3), 1.0, t0),
            Ok(None),
            "nor for an overdue step already taken"
        );
    }
}
