//! The consumers' side: one output per step, never two steps mixed.
//!
//! Messages are delivered at least once: a producer that hears nothing back re-sends its step (at
//! start-up a consumer may not have been listening yet), and a restarted process receives the last
//! sample of each topic. A consumer therefore calls its core once per `seq` and answers a repeated
//! `seq` with the output it already computed ([`Once`]), so a learner never learns twice from one
//! step and the mesh stays deterministic.

use std::time::{Duration, Instant};

/// What [`Once::step`] did.
#[derive(Clone, Debug, PartialEq)]
pub enum Outcome<O> {
    /// A new step: the core was called.
    Fresh(O),
    /// The step just processed again: the same output, the core not called.
    Repeat(O),
    /// An older step: ignore it.
    Stale,
}

impl<O> Outcome<O> {
    /// The output to send, for a fresh or repeated step.
    pub fn output(self) -> Option<O> {
        match self {
            Outcome::Fresh(o) | Outcome::Repeat(o) => Some(o),
            Outcome::Stale => None,
        }
    }
}

/// Calls a core once per step.
#[derive(Debug)]
pub struct Once<O> {
    last: Option<(u64, O)>,
}

impl<O: Clone> Default for Once<O> {
    fn default() -> Self {
        Self::new()
    }
}

impl<O: Clone> Once<O> {
    pub fn new() -> Self {
        Once { last: None }
    }

    /// Runs `core` for a step seen for the first time; answers the last step again with its output.
    pub fn step<E>(
        &mut self,
        seq: u64,
        core: impl FnOnce() -> Result<O, E>,
    ) -> Result<Outcome<O>, E> {
        match &self.last {
            Some((last, out)) if *last == seq => return Ok(Outcome::Repeat(out.clone())),
            Some((last, _)) if *last > seq => return Ok(Outcome::Stale),
            _ => {}
        }
        let out = core()?;
        self.last = Some((seq, out.clone()));
        Ok(Outcome::Fresh(out))
    }

    /// The last step processed.
    pub fn last_seq(&self) -> Option<u64> {
        self.last.as_ref().map(|(s, _)| *s)
    }
}

/// Collects one value from each of `N` inputs for the same step.
#[derive(Debug)]
pub struct Gather<T, const N: usize> {
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
            seq: None,
            slots: [None; N],
            first_at: None,
        }
    }

    /// Puts input `i`'s value for step `seq`. Returns the whole set once every input has given its
    /// value for that step. A newer step drops an incomplete older one (returned as `Err` so the
    /// caller can log it); an older step is ignored.
    pub fn put(
        &mut self,
        i: usize,
        seq: u64,
        value: T,
        now: Instant,
    ) -> Result<Option<(u64, [T; N])>, Partial<T, N>> {
        let mut dropped = None;
        match self.seq {
            Some(s) if seq < s => return Ok(None),
            Some(s) if seq > s => {
                // Only an older step that had started is dropped; a completed one left no values.
                if self.slots.iter().any(Option::is_some) {
                    dropped = Some(Partial {
                        seq: s,
                        values: self.slots,
                    });
                }
                self.reset(seq, now);
            }
            None => self.reset(seq, now),
            _ => {}
        }
        self.slots[i] = Some(value);
        if let Some(partial) = dropped {
            return Err(partial);
        }
        Ok(self.complete())
    }

    fn reset(&mut self, seq: u64, now: Instant) {
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

    #[test]
    fn once_calls_the_core_once_per_step() {
        let mut once = Once::new();
        let mut calls = 0;
        let mut run = |seq| {
            once.step(seq, || {
                calls += 1;
                Ok::<_, ()>(seq * 10)
            })
            .unwrap()
        };
        assert_eq!(run(1), Outcome::Fresh(10));
        assert_eq!(run(1), Outcome::Repeat(10));
        assert_eq!(run(0), Outcome::Stale);
        assert_eq!(run(2), Outcome::Fresh(20));
        assert_eq!(calls, 2);
    }

    #[test]
    fn gather_completes_a_step_and_never_mixes_two() {
        let t0 = Instant::now();
        let mut g = Gather::<f64, 3>::new();
        assert_eq!(g.put(0, 5, 1.0, t0), Ok(None));
        assert_eq!(g.put(2, 5, 3.0, t0), Ok(None));
        assert_eq!(g.put(1, 5, 2.0, t0), Ok(Some((5, [1.0, 2.0, 3.0]))));
        // An old step is ignored; a newer one drops the incomplete step.
        assert_eq!(g.put(0, 6, 1.0, t0), Ok(None));
        assert_eq!(g.put(1, 4, 9.0, t0), Ok(None));
        let dropped = g.put(1, 7, 2.0, t0).unwrap_err();
        assert_eq!(dropped.seq, 6);
        assert_eq!(dropped.values, [Some(1.0), None, None]);
        assert_eq!(g.put(0, 7, 1.0, t0), Ok(None));
        assert_eq!(g.put(2, 7, 3.0, t0), Ok(Some((7, [1.0, 2.0, 3.0]))));
    }

    #[test]
    fn an_incomplete_step_becomes_overdue() {
        let t0 = Instant::now();
        let mut g = Gather::<f64, 2>::new();
        assert!(g.take_overdue(Duration::ZERO, t0).is_none());
        g.put(0, 1, 1.0, t0).unwrap();
        let p = g.take_overdue(Duration::ZERO, t0).unwrap();
        assert_eq!((p.seq, p.values), (1, [Some(1.0), None]));
        assert!(g.take_overdue(Duration::ZERO, t0).is_none());
        g.put(0, 2, 1.0, t0).unwrap();
        assert!(g.take_overdue(Duration::from_secs(3600), t0).is_none());
    }

    #[test]
    fn a_completed_step_is_not_reported_as_dropped() {
        let t0 = Instant::now();
        let mut g = Gather::<f64, 2>::new();
        g.put(0, 1, 1.0, t0).unwrap();
        assert_eq!(g.put(1, 1, 2.0, t0), Ok(Some((1, [1.0, 2.0]))));
        assert_eq!(
            g.put(0, 2, 1.0, t0),
            Ok(None),
            "no spurious partial for the completed step 1"
        );
        let _ = g.take_overdue(Duration::ZERO, t0).unwrap();
        assert_eq!(
            g.put(0, 3, 1.0, t0),
            Ok(None),
            "nor for an overdue step already taken"
        );
    }
}
