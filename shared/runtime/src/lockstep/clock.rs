//! The plant's clock: when to re-send the current step, when its deadline has passed, when to say
//! the mesh has not answered yet.

use std::time::{Duration, Instant};

/// The protocol's time limits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// Re-publish the current step after this long without its answer.
    pub resend: Duration,
    /// Once the mesh runs, integrate without an answer after this long.
    pub deadline: Duration,
    /// While the mesh has never answered, say so this often.
    pub waiting_note: Duration,
}

impl Limits {
    pub fn new(resend: Duration, deadline: Duration) -> Self {
        Limits {
            resend,
            deadline,
            waiting_note: Duration::from_secs(5),
        }
    }

    /// How long the shell may block without input before asking the clock again: half the shorter
    /// limit, so each fires at most half a period late.
    pub fn tick(&self) -> Duration {
        (self.resend.min(self.deadline) / 2).max(Duration::from_millis(1))
    }
}

/// Where the protocol stands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    /// No answer has arrived yet: re-send the first step, never time out.
    Connecting,
    /// The mesh answers: re-send, and integrate without an answer after the deadline.
    Running,
    /// The requested episodes are done: nothing more is published.
    Finished,
}

/// What the clock says is due.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Due {
    /// Nothing yet.
    Idle,
    /// The mesh runs and the current step went unanswered past the deadline: close it without an
    /// answer.
    Deadline,
    /// Publish the current step again; `waiting_for_mesh` is set (to the time waited since the
    /// start) every [`Limits::waiting_note`] while the mesh has never answered.
    Resend { waiting_for_mesh: Option<Duration> },
}

/// The clock of a plant in lockstep. Plain state fed `now`.
#[derive(Clone, Copy, Debug)]
pub struct Deadlines {
    limits: Limits,
    phase: Phase,
    started_at: Instant,
    /// When the current step was first published, and last (re-)published.
    first_sent: Instant,
    last_sent: Instant,
    last_note: Instant,
}

impl Deadlines {
    /// The first step was published at `now`; the mesh has not answered yet.
    pub fn start(limits: Limits, now: Instant) -> Self {
        Deadlines {
            limits,
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

    pub fn limits(&self) -> &Limits {
        &self.limits
    }

    /// How long the current step has waited for its answer.
    pub fn waited(&self, now: Instant) -> Duration {
        now.saturating_duration_since(self.first_sent)
    }

    /// The next step was published at `now` (the mesh answered, or the deadline closed one).
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
            Phase::Running if self.waited(now) >= self.limits.deadline => Due::Deadline,
            Phase::Connecting | Phase::Running => {
                if now.saturating_duration_since(self.last_sent) < self.limits.resend {
                    return Due::Idle;
                }
                self.last_sent = now;
                let waiting_for_mesh = (self.phase == Phase::Connecting
                    && now.saturating_duration_since(self.last_note) >= self.limits.waiting_note)
                    .then(|| {
                        self.last_note = now;
                        now.saturating_duration_since(self.started_at)
                    });
                Due::Resend { waiting_for_mesh }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: Duration = Duration::from_millis(1);

    #[test]
    fn connecting_re_sends_forever_and_notes_the_wait() {
        let t0 = Instant::now();
        let mut clock = Deadlines::start(Limits::new(100 * MS, 2000 * MS), t0);
        assert_eq!(clock.on_time(t0 + 50 * MS), Due::Idle);
        let mut notes = 0;
        // Ten minutes in steps of 100 ms: a re-send each time, never a deadline, a note every 5 s.
        for k in 1..=6000u32 {
            match clock.on_time(t0 + k * 100 * MS) {
                Due::Resend { waiting_for_mesh } => {
                    if let Some(w) = waiting_for_mesh {
                        notes += 1;
                        assert_eq!(w, k * 100 * MS);
                    }
                }
                other => panic!("{other:?}"),
            }
        }
        assert_eq!(notes, 120);
        assert_eq!(clock.phase(), Phase::Connecting);
    }

    #[test]
    fn running_re_sends_then_the_deadline_passes_and_restarts_with_the_next_step() {
        let t0 = Instant::now();
        let mut clock = Deadlines::start(Limits::new(100 * MS, 2000 * MS), t0);
        let t1 = t0 + 10 * MS;
        clock.published(t1);
        assert_eq!(clock.on_time(t1 + 99 * MS), Due::Idle);
        assert_eq!(
            clock.on_time(t1 + 100 * MS),
            Due::Resend {
                waiting_for_mesh: None
            }
        );
        assert_eq!(clock.on_time(t1 + 150 * MS), Due::Idle);
        assert!(matches!(clock.on_time(t1 + 1999 * MS), Due::Resend { .. }));
        assert_eq!(clock.on_time(t1 + 2000 * MS), Due::Deadline);
        assert_eq!(clock.waited(t1 + 2000 * MS), 2000 * MS);
        // The deadline runs from the next step's publication.
        clock.published(t1 + 2000 * MS);
        assert!(matches!(clock.on_time(t1 + 2100 * MS), Due::Resend { .. }));
        clock.finish();
        assert_eq!(clock.on_time(t1 + 60_000 * MS), Due::Idle);
    }

    #[test]
    fn the_tick_serves_the_shorter_limit() {
        assert_eq!(Limits::new(100 * MS, 2000 * MS).tick(), 50 * MS);
        assert_eq!(Limits::new(100 * MS, 30 * MS).tick(), 15 * MS);
        assert_eq!(Limits::new(Duration::ZERO, 30 * MS).tick(), MS);
    }
}
