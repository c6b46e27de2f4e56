//! Counting recoverable misbehaviour and saying so without flooding the log: the first occurrence
//! is logged at once, later ones at most once per interval with how many came since.

use model::bounds::Fixes;
use std::time::Duration;

/// How often a repeated warning may be logged.
pub const WARN_EVERY: Duration = Duration::from_secs(5);

/// Counts occurrences and decides when one is to be logged. Plain state fed the time (ns, the
/// vehicle clock: signed).
#[derive(Clone, Debug)]
pub struct Tally {
    every_ns: i64,
    total: u64,
    unreported: u64,
    last_logged: Option<i64>,
}

impl Default for Tally {
    fn default() -> Self {
        Self::new(WARN_EVERY)
    }
}

impl Tally {
    pub fn new(every: Duration) -> Self {
        Tally {
            every_ns: every.as_nanos().min(i64::MAX as u128) as i64,
            total: 0,
            unreported: 0,
            last_logged: None,
        }
    }

    /// One more at `now_ns`: `Some(n)` when it is to be logged now, `n` being how many went
    /// unlogged before it.
    pub fn count(&mut self, now_ns: i64) -> Option<u64> {
        self.total += 1;
        if self.due(now_ns) {
            let earlier = self.unreported;
            self.unreported = 0;
            self.last_logged = Some(now_ns);
            Some(earlier)
        } else {
            self.unreported += 1;
            None
        }
    }

    /// Occurrences not logged yet, once the interval since the last log has passed (then they count
    /// as reported).
    pub fn flush(&mut self, now_ns: i64) -> Option<u64> {
        if self.unreported == 0 || !self.due(now_ns) {
            return None;
        }
        self.last_logged = Some(now_ns);
        Some(std::mem::take(&mut self.unreported))
    }

    fn due(&self, now_ns: i64) -> bool {
        self.last_logged
            .is_none_or(|t| now_ns.saturating_sub(t) >= self.every_ns)
    }

    /// Occurrences so far.
    pub fn total(&self) -> u64 {
        self.total
    }
}

/// The bad values of one input (see `model::bounds`): counted, and logged at WARN, rate-limited.
#[derive(Clone, Debug)]
pub struct BadValues {
    input: String,
    tally: Tally,
    fixes: Fixes,
}

impl BadValues {
    /// The bad values received on `input` (a topic name, for the log).
    pub fn new(input: impl Into<String>) -> Self {
        BadValues {
            input: input.into(),
            tally: Tally::default(),
            fixes: Fixes::default(),
        }
    }

    /// What the rule changed in the message of step `seq`, at `now_ns`.
    pub fn note(&mut self, fixes: Fixes, seq: u64, now_ns: i64) {
        if fixes.is_empty() {
            return;
        }
        self.fixes.add(fixes);
        if let Some(earlier) = self.tally.count(now_ns) {
            tracing::warn!(
                input = %self.input,
                seq,
                non_finite = fixes.non_finite,
                out_of_range = fixes.clamped,
                earlier_messages = earlier,
                total_non_finite = self.fixes.non_finite,
                total_out_of_range = self.fixes.clamped,
                "bad values: not finite made 0, out of range clamped"
            );
        }
    }

    /// Values changed so far.
    pub fn fixes(&self) -> Fixes {
        self.fixes
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_first_is_logged_then_at_most_once_per_interval() {
        let s: i64 = 1_000_000_000;
        let mut t = Tally::new(Duration::from_secs(5));
        assert_eq!(t.count(s), Some(0));
        assert_eq!(t.count(2 * s), None);
        assert_eq!(t.count(3 * s), None);
        assert_eq!(t.flush(4 * s), None, "not yet");
        assert_eq!(t.flush(6 * s), Some(2));
        assert_eq!(t.flush(20 * s), None, "nothing left");
        assert_eq!(t.count(21 * s), Some(0));
        assert_eq!(t.count(22 * s), None);
        assert_eq!(t.count(27 * s), Some(1));
        assert_eq!(t.total(), 6);
    }
}
