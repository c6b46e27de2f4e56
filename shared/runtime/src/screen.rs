//! Judging a step's stamp before a consumer acts on it: one rule for every consumer of the mesh.
//!
//! **Epochs.** A stamp's `epoch` is its producer's session. A stamp of an epoch never accepted before
//! starts afresh: a restarted producer numbers its steps from wherever it likes, and its consumers
//! follow it instead of dropping its `seq` as old. The last steps of the few epochs accepted before
//! the current one are remembered ([`EPOCHS_REMEMBERED`]), and a stamp of one of them is judged
//! against that epoch's last step, not taken for a new epoch: a publisher of another epoch between
//! two steps of the live one (a second producer, a forged stamp) must not make the live epoch's
//! next stamp, whatever its `seq`, a fresh start, nor its genuine steps then look older.
//!
//! **Order.** Within an epoch, a step is new when its `seq` is above the last accepted one, the same
//! `seq` is a repeat (answered with the output already computed), a lower one is refused.
//!
//! **Time** (timed stamps, the vehicle's: [`messages::Stamp::clock_ns`]; the sim endpoint's are
//! untimed and judged by order alone, so its lockstep stays deterministic). A consumer learns each
//! epoch's *offset*, the smallest (arrival on the consumer's vehicle clock minus the stamp's clock)
//! seen: how far the producer's clock is behind, plus the fastest delivery. A step arriving more
//! than [`ScreenLimits::max_age`] later than that (a stalled producer's backlog, a topic's history
//! from long ago) is refused as too old; one arriving more than [`ScreenLimits::max_ahead`] earlier
//! (a stamp from the future) as ahead, unless it agrees with the consumer's own clock (then the
//! epoch's earlier steps came late, and its offset is learned again). A new epoch's first step is
//! accepted when its clock agrees with the consumer's within those limits; otherwise it is refused
//! and the next step of that epoch settles it: accepted when their offsets agree within half a
//! period (a producer whose clock is behind, e.g. restarted with its time base stepped back, but
//! whose steps come at their pace; a backlog read at once is a period apart per step).
//!
//! **Absurd numbers.** A step's `seq` may not jump further than the steps its producer could have
//! taken since the last one (`8 + 2 x` the elapsed sample periods on its clock: frames dropped on
//! the way leave gaps, a huge number is a corrupt or forged stamp), and a later step may not carry
//! an earlier clock.
//!
//! Refusals are counted and logged at WARN, rate-limited ([`crate::Tally`]).

use crate::tally::Tally;
use messages::Stamp;
use std::time::Duration;

/// Epochs remembered besides the current one (see the module docs): a producer restarts rarely,
/// so a few cover every epoch that can still be alive. When more come, the one with the fewest
/// accepted steps is forgotten first: a burst of one-step epochs does not push out a live one.
pub const EPOCHS_REMEMBERED: usize = 4;

/// Untimed stamps (the sim endpoint's) may jump this far: the lockstep never skips more than a few.
pub const MAX_UNTIMED_JUMP: u64 = 10_000;

/// How a consumer judges the age of timed stamps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ScreenLimits {
    /// A step arriving later than this (relative to its epoch's fastest delivery) is refused.
    pub max_age: Duration,
    /// A step arriving earlier than this (relative to its epoch's fastest delivery) is refused.
    pub max_ahead: Duration,
    /// The producer's sample period: bounds how far `seq` may jump.
    pub period: Duration,
}

impl ScreenLimits {
    /// The limits of the control loop at `sample_time_s`: a step older than two sample periods is
    /// stale, one a period ahead absurd. (The thruster driver's age limit is its failsafe deadline,
    /// three periods: `thruster_driver::limits`.)
    pub fn control(sample_time_s: f64) -> Self {
        let period = Duration::from_secs_f64(sample_time_s);
        ScreenLimits {
            max_age: 2 * period,
            max_ahead: period,
            period,
        }
    }
}

/// Why a stamp was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Refusal {
    /// A step below the last accepted one of its epoch.
    Older { seq: u64, last: u64 },
    /// A jump of `seq` its producer cannot have made.
    SeqJump { seq: u64, last: u64, allowed: u64 },
    /// A later step with an earlier clock.
    ClockBack {
        seq: u64,
        clock_ns: i64,
        last_clock_ns: i64,
    },
    /// Arrived `late` after its epoch's pace allows.
    TooOld { seq: u64, late: Duration },
    /// Arrived `by` ahead of its epoch's pace: a stamp from the future.
    Ahead { seq: u64, by: Duration },
    /// A message its consumer cannot use (a truncated frame): refused by the consumer's core.
    Unusable { seq: u64 },
}

impl std::fmt::Display for Refusal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Refusal::Older { seq, last } => write!(f, "seq {seq} is older than {last}"),
            Refusal::SeqJump { seq, last, allowed } => write!(
                f,
                "seq {seq} jumps {} past {last}, at most {allowed} can have passed",
                seq.wrapping_sub(*last)
            ),
            Refusal::ClockBack {
                seq,
                clock_ns,
                last_clock_ns,
            } => write!(
                f,
                "seq {seq} was taken at {clock_ns} ns, before the last step ({last_clock_ns} ns)"
            ),
            Refusal::TooOld { seq, late } => write!(f, "seq {seq} is {late:?} too old"),
            Refusal::Ahead { seq, by } => write!(f, "seq {seq} is {by:?} ahead of its clock"),
            Refusal::Unusable { seq } => write!(f, "seq {seq}: the message cannot be used"),
        }
    }
}

/// What a stamp is to the consumer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    /// A step to act on.
    New,
    /// The step accepted last, again.
    Repeat,
    /// Not to be acted on.
    Refused(Refusal),
}

#[derive(Clone, Copy, Debug)]
struct Last {
    epoch: u32,
    timed: bool,
    seq: u64,
    clock_ns: i64,
    /// The epoch's offset (timed stamps): the smallest arrival minus stamp clock seen.
    offset_ns: i128,
    /// Steps accepted in the epoch.
    steps: u64,
}

/// One consumer input's judge of stamps. Plain state fed the consumer's vehicle clock (ns).
#[derive(Clone, Debug)]
pub struct Screen {
    input: String,
    limits: ScreenLimits,
    last: Option<Last>,
    /// The last accepted steps of the epochs accepted before `last`'s, newest first.
    earlier: Vec<Last>,
    /// A new epoch's first step that could not be judged: (epoch, offset).
    unsettled: Option<(u32, i128)>,
    refused: Tally,
}

impl Screen {
    /// The judge of the stamps arriving on `input` (a topic name, for the log).
    pub fn new(input: impl Into<String>, limits: ScreenLimits) -> Self {
        Screen {
            input: input.into(),
            limits,
            last: None,
            earlier: Vec::new(),
            unsettled: None,
            refused: Tally::default(),
        }
    }

    pub fn limits(&self) -> &ScreenLimits {
        &self.limits
    }

    /// Stamps refused so far.
    pub fn refused(&self) -> u64 {
        self.refused.total()
    }

    /// The last accepted step: (epoch, seq).
    pub fn last(&self) -> Option<(u32, u64)> {
        self.last.map(|l| (l.epoch, l.seq))
    }

    /// Judges `stamp` arriving at `now_ns`; a refusal is counted and logged. Nothing is accepted
    /// until [`Screen::accept`].
    pub fn check(&mut self, stamp: &Stamp, now_ns: i64) -> Verdict {
        if let Some(earlier) = self.refused.flush(now_ns) {
            tracing::warn!(input = %self.input, refused = earlier, total = self.refused.total(), "stale or absurd stamps refused since the last warning");
        }
        let verdict = self.judge(stamp, now_ns);
        if let Verdict::Refused(why) = verdict
            && let Some(earlier) = self.refused.count(now_ns)
        {
            tracing::warn!(
                input = %self.input,
                epoch = stamp.epoch,
                earlier_unlogged = earlier,
                total = self.refused.total(),
                "stamp refused: {why}"
            );
        }
        verdict
    }

    fn judge(&mut self, stamp: &Stamp, now_ns: i64) -> Verdict {
        let seq = stamp.seq;
        let timed = stamp.is_timed();
        let offset = now_ns as i128 - stamp.clock_ns as i128;
        let max_age = self.limits.max_age.as_nanos() as i128;
        let max_ahead = self.limits.max_ahead.as_nanos() as i128;
        let same_epoch = self
            .last
            .filter(|l| l.epoch == stamp.epoch && l.timed == timed);
        // An epoch accepted before the current one: judged against its own last step. Its last
        // step again is no repeat to answer (the answer kept is the current epoch's).
        let earlier = self
            .earlier
            .iter()
            .find(|l| l.epoch == stamp.epoch && l.timed == timed)
            .copied();
        if let Some(last) = earlier
            && seq == last.seq
        {
            return Verdict::Refused(Refusal::Older {
                seq,
                last: last.seq,
            });
        }
        let Some(last) = same_epoch.or(earlier) else {
            // A new epoch (or the first step this consumer sees).
            if !timed || (-max_ahead..=max_age).contains(&offset) {
                self.unsettled = None;
                return Verdict::New;
            }
            // Steps at their pace arrive with the same offset; a backlog read at once (a consumer
            // that restarted behind its input) arrives a period apart per step and is not taken
            // for a clock that is behind.
            let pace = self.limits.period.as_nanos() as i128 / 2;
            if let Some((epoch, first)) = self.unsettled
                && epoch == stamp.epoch
                && (offset - first).abs() <= pace
            {
                return Verdict::New;
            }
            self.unsettled = Some((stamp.epoch, offset));
            return Verdict::Refused(if offset > max_age {
                Refusal::TooOld {
                    seq,
                    late: nanos(offset),
                }
            } else {
                Refusal::Ahead {
                    seq,
                    by: nanos(-offset),
                }
            });
        };
        if seq == last.seq {
            return Verdict::Repeat;
        }
        if seq < last.seq {
            return Verdict::Refused(Refusal::Older {
                seq,
                last: last.seq,
            });
        }
        let allowed = if timed {
            if stamp.clock_ns < last.clock_ns {
                return Verdict::Refused(Refusal::ClockBack {
                    seq,
                    clock_ns: stamp.clock_ns,
                    last_clock_ns: last.clock_ns,
                });
            }
            let periods = stamp.clock_ns.abs_diff(last.clock_ns)
                / self.limits.period.as_nanos().max(1) as u64;
            8u64.saturating_add(periods.saturating_mul(2))
        } else {
            MAX_UNTIMED_JUMP
        };
        if seq - last.seq > allowed {
            return Verdict::Refused(Refusal::SeqJump {
                seq,
                last: last.seq,
                allowed,
            });
        }
        if timed {
            let late = offset - last.offset_ns;
            if late > max_age {
                return Verdict::Refused(Refusal::TooOld {
                    seq,
                    late: nanos(late),
                });
            }
            // Earlier than the epoch's pace so far: a stamp from the future, unless the step agrees
            // with this consumer's own clock (the epoch's first steps then came late, e.g. a backlog
            // read at start, and the epoch's offset is learned again from this one).
            if late < -max_ahead && !(-max_ahead..=max_age).contains(&offset) {
                return Verdict::Refused(Refusal::Ahead {
                    seq,
                    by: nanos(-late),
                });
            }
        }
        Verdict::New
    }

    /// The epoch's offset once `stamp`, arriving at `now_ns`, is accepted.
    fn offset_after(&self, stamp: &Stamp, now_ns: i64) -> i128 {
        let offset = now_ns as i128 - stamp.clock_ns as i128;
        let known = self
            .last
            .iter()
            .chain(&self.earlier)
            .find(|l| l.epoch == stamp.epoch && l.timed == stamp.is_timed());
        match known {
            Some(l) => l.offset_ns.min(offset),
            None => match self.unsettled {
                // The epoch's first step told how far behind its clock is: keep the smaller.
                Some((epoch, first)) if epoch == stamp.epoch => first.min(offset),
                _ => offset,
            },
        }
    }

    /// Makes `stamp` (judged [`Verdict::New`] at `now_ns`) the last accepted step.
    pub fn accept(&mut self, stamp: &Stamp, now_ns: i64) {
        let timed = stamp.is_timed();
        let offset_ns = self.offset_after(stamp, now_ns);
        self.unsettled = None;
        let same = |l: &Last| l.epoch == stamp.epoch && l.timed == timed;
        let steps = self
            .last
            .iter()
            .chain(&self.earlier)
            .find(|l| same(l))
            .map_or(0, |l| l.steps);
        let next = Last {
            epoch: stamp.epoch,
            timed,
            seq: stamp.seq,
            clock_ns: stamp.clock_ns,
            offset_ns,
            steps: steps.saturating_add(1),
        };
        // The epoch accepted now leaves the earlier ones; the one it replaces joins them.
        self.earlier.retain(|l| !same(l));
        if let Some(prev) = self.last.replace(next)
            && !same(&prev)
        {
            self.earlier.insert(0, prev);
            if self.earlier.len() > EPOCHS_REMEMBERED {
                // The fewest steps, the oldest of those on a tie.
                let k = (0..self.earlier.len())
                    .rev()
                    .min_by_key(|&k| self.earlier[k].steps)
                    .expect("not empty");
                self.earlier.remove(k);
            }
        }
    }

    /// The arrival time (consumer's clock, ns) up to which the step accepted last is fresh:
    /// its clock plus the epoch's offset plus `max_age`; `None` for untimed stamps.
    pub fn fresh_until(&self) -> Option<i64> {
        let l = self.last.filter(|l| l.timed)?;
        Some(self.until(l.clock_ns, l.offset_ns))
    }

    /// [`Screen::fresh_until`] as it will be once `stamp` (judged new at `now_ns`) is accepted.
    pub fn fresh_until_if_accepted(&self, stamp: &Stamp, now_ns: i64) -> Option<i64> {
        stamp
            .is_timed()
            .then(|| self.until(stamp.clock_ns, self.offset_after(stamp, now_ns)))
    }

    fn until(&self, clock_ns: i64, offset_ns: i128) -> i64 {
        let t = clock_ns as i128 + offset_ns + self.limits.max_age.as_nanos() as i128;
        t.clamp(i64::MIN as i128, i64::MAX as i128) as i64
    }
}

fn nanos(v: i128) -> Duration {
    Duration::from_nanos(v.clamp(0, u64::MAX as i128) as u64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use messages::StepStatus;

    const MS: i64 = 1_000_000;
    const T0: i64 = 3_600_000 * MS;

    fn limits() -> ScreenLimits {
        ScreenLimits::control(0.2)
    }

    fn stamp(epoch: u32, seq: u64, clock_ns: i64) -> Stamp {
        Stamp::new(seq, seq * 200_000_000, 0, seq as u32, StepStatus::Running)
            .timed(epoch, clock_ns)
    }

    /// Feeds a step; accepts it when new.
    fn feed(s: &mut Screen, st: Stamp, now: i64) -> Verdict {
        let v = s.check(&st, now);
        if v == Verdict::New {
            s.accept(&st, now);
        }
        v
    }

    #[test]
    fn steps_in_order_repeats_and_older_ones() {
        let mut s = Screen::new("t", limits());
        assert_eq!(feed(&mut s, stamp(7, 10, T0), T0 + MS), Verdict::New);
        assert_eq!(
            feed(&mut s, stamp(7, 10, T0), T0 + 50 * MS),
            Verdict::Repeat
        );
        assert_eq!(
            feed(&mut s, stamp(7, 11, T0 + 200 * MS), T0 + 201 * MS),
            Verdict::New
        );
        assert_eq!(
            feed(&mut s, stamp(7, 9, T0 + 250 * MS), T0 + 251 * MS),
            Verdict::Refused(Refusal::Older { seq: 9, last: 11 })
        );
        // Frames dropped on the way: a small gap is fine.
        assert_eq!(
            feed(&mut s, stamp(7, 13, T0 + 600 * MS), T0 + 601 * MS),
            Verdict::New
        );
        assert_eq!(s.refused(), 1);
        assert_eq!(s.last(), Some((7, 13)));
    }

    #[test]
    fn a_huge_seq_is_refused_and_does_not_silence_the_producer() {
        let mut s = Screen::new("t", limits());
        feed(&mut s, stamp(7, 10, T0), T0 + MS);
        let huge = stamp(7, 10 + (1 << 40), T0 + 200 * MS);
        assert!(matches!(
            feed(&mut s, huge, T0 + 201 * MS),
            Verdict::Refused(Refusal::SeqJump { .. })
        ));
        assert_eq!(
            feed(&mut s, stamp(7, 11, T0 + 200 * MS), T0 + 202 * MS),
            Verdict::New
        );
        // A long pause allows a larger gap, in proportion.
        assert_eq!(
            feed(&mut s, stamp(7, 60, T0 + 10_000 * MS), T0 + 10_001 * MS),
            Verdict::New
        );
    }

    #[test]
    fn a_restarted_producer_starts_a_new_epoch_that_is_accepted() {
        let mut s = Screen::new("t", limits());
        feed(&mut s, stamp(7, 5000, T0), T0 + MS);
        // The producer restarted and counts from 1 again.
        assert_eq!(
            feed(&mut s, stamp(8, 1, T0 + 300 * MS), T0 + 301 * MS),
            Verdict::New
        );
        assert_eq!(
            feed(&mut s, stamp(8, 2, T0 + 500 * MS), T0 + 501 * MS),
            Verdict::New
        );
        assert_eq!(s.refused(), 0);
    }

    /// A rogue between two steps of the live epoch: each of its fresh epochs is followed, but a
    /// stamp in the live epoch is still judged against that epoch's last step, so a huge `seq` in it
    /// is refused and the live producer's next steps are accepted.
    #[test]
    fn other_epochs_between_steps_do_not_reopen_the_live_epoch() {
        let mut s = Screen::new("t", limits());
        let mut now = T0;
        for seq in 1..=20 {
            now = T0 + seq as i64 * 200 * MS;
            assert_eq!(feed(&mut s, stamp(7, seq, now), now + MS), Verdict::New);
        }
        // More one-step epochs than are remembered, each followed by a forged step of the live one.
        for k in 0..(2 * EPOCHS_REMEMBERED as u32) {
            let t = now + 10 * MS + i64::from(k) * MS;
            assert_eq!(feed(&mut s, stamp(100 + k, 1, t), t), Verdict::New);
            assert!(matches!(
                feed(&mut s, stamp(7, 20 + (1 << 40), t), t),
                Verdict::Refused(Refusal::SeqJump { .. })
            ));
            assert!(matches!(
                feed(&mut s, stamp(7, 10, t), t),
                Verdict::Refused(Refusal::Older { .. })
            ));
            // The live epoch's last step again is not a repeat to answer with another epoch's output.
            assert!(matches!(
                feed(&mut s, stamp(7, 20, t), t),
                Verdict::Refused(Refusal::Older { .. })
            ));
        }
        for seq in 21..=25 {
            let t = T0 + seq as i64 * 200 * MS;
            assert_eq!(
                feed(&mut s, stamp(7, seq, t), t + MS),
                Verdict::New,
                "step {seq}"
            );
        }
        assert_eq!(s.last(), Some((7, 25)));
        // A step of a forgotten rogue epoch is a new epoch again; a restarted producer still is.
        let t = T0 + 5_200 * MS;
        assert_eq!(feed(&mut s, stamp(8, 1, t), t + MS), Verdict::New);
        assert_eq!(
            feed(&mut s, stamp(8, 2, t + 200 * MS), t + 201 * MS),
            Verdict::New
        );
    }

    #[test]
    fn a_producer_whose_clock_stepped_back_is_accepted_from_its_second_step() {
        let mut s = Screen::new("t", limits());
        feed(&mut s, stamp(7, 100, T0), T0 + MS);
        let back = T0 - 1_800_000 * MS; // half an hour behind
        assert!(matches!(
            feed(&mut s, stamp(9, 1, back), T0 + 300 * MS),
            Verdict::Refused(Refusal::TooOld { .. })
        ));
        assert_eq!(
            feed(&mut s, stamp(9, 2, back + 200 * MS), T0 + 501 * MS),
            Verdict::New
        );
        assert_eq!(
            feed(&mut s, stamp(9, 3, back + 400 * MS), T0 + 700 * MS),
            Verdict::New
        );
        // A stalled step of that epoch is still too old.
        assert!(matches!(
            feed(&mut s, stamp(9, 4, back + 600 * MS), T0 + 1500 * MS),
            Verdict::Refused(Refusal::TooOld { .. })
        ));
    }

    /// The machine was booted 1,403 s ago and the camera restarted with its clock an hour behind:
    /// its readings lie below zero. The screen learns the epoch from its pace as for any clock behind,
    /// judges its steps' age and order on the signed clock, and a stall of that epoch still stops it.
    #[test]
    fn a_producer_whose_clock_stepped_back_past_zero_is_followed_at_its_pace() {
        let mut s = Screen::new("t", limits());
        let up = 1_403_000 * MS;
        let hour = 3_600_000 * MS;
        feed(&mut s, stamp(7, 985, up - 200 * MS), up - 199 * MS);
        let at = |k: i64| up + k * 200 * MS; // the consumer's clock when step k arrives
        let taken = |k: i64| at(k) - hour - MS; // the camera's, an hour behind: below zero
        assert!(taken(0) < 0);
        assert!(matches!(
            feed(&mut s, stamp(9, 986, taken(0)), at(0)),
            Verdict::Refused(Refusal::TooOld { .. })
        ));
        for k in 1..50 {
            assert_eq!(
                feed(&mut s, stamp(9, 986 + k as u64, taken(k)), at(k)),
                Verdict::New,
                "step {k}, taken at {} ns",
                taken(k)
            );
        }
        assert_eq!(s.last(), Some((9, 1035)));
        // Fresh until two periods after the fastest delivery, on the consumer's clock.
        assert_eq!(s.fresh_until(), Some(at(49) + 400 * MS));
        // A later step taken earlier, a step from the future, a stalled one: refused.
        assert!(matches!(
            feed(&mut s, stamp(9, 1036, taken(48)), at(50)),
            Verdict::Refused(Refusal::ClockBack { .. })
        ));
        assert!(matches!(
            feed(&mut s, stamp(9, 1036, taken(50) + 2_000 * MS), at(50)),
            Verdict::Refused(Refusal::Ahead { .. })
        ));
        assert!(matches!(
            feed(&mut s, stamp(9, 1036, taken(50)), at(50) + 1_000 * MS),
            Verdict::Refused(Refusal::TooOld { .. })
        ));
        // A stamp stuck at one reading (no pace) is never taken for a live clock.
        let mut s = Screen::new("t", limits());
        feed(&mut s, stamp(7, 985, up - 200 * MS), up - 199 * MS);
        for k in 0..10 {
            assert!(
                matches!(
                    feed(&mut s, stamp(11, 986 + k as u64, 1), at(k)),
                    Verdict::Refused(Refusal::TooOld { .. })
                ),
                "step {k}"
            );
        }
    }

    /// A consumer restarted behind its input reads a backlog at once: the stale steps are refused,
    /// and the fresh steps after them are accepted, never refused as ahead of the backlog's pace.
    #[test]
    fn a_backlog_read_at_start_is_refused_and_fresh_steps_follow() {
        let mut s = Screen::new("t", limits());
        let now = T0 + 2_000 * MS;
        for (seq, age) in [(1, 1000), (2, 800), (3, 600)] {
            assert!(
                matches!(
                    feed(&mut s, stamp(7, seq, now - age * MS), now),
                    Verdict::Refused(Refusal::TooOld { .. })
                ),
                "step {seq}, {age} ms old"
            );
        }
        for k in 4..10u64 {
            let taken = now + (k as i64 - 3) * 200 * MS;
            assert_eq!(
                feed(&mut s, stamp(7, k, taken), taken + MS),
                Verdict::New,
                "fresh step {k}"
            );
        }
        // Had a late step been accepted first, a fresh one re-bases the epoch's pace.
        let mut s = Screen::new("t", limits());
        let late = T0 + 1000 * MS;
        assert_eq!(feed(&mut s, stamp(8, 1, T0), T0 + 300 * MS), Verdict::New);
        assert_eq!(
            feed(&mut s, stamp(8, 2, late), late + 2 * MS),
            Verdict::New,
            "faster than before, and on the consumer's clock"
        );
        assert!(matches!(
            feed(&mut s, stamp(8, 3, late + 200 * MS), late + 700 * MS),
            Verdict::Refused(Refusal::TooOld { .. })
        ));
    }

    #[test]
    fn old_steps_and_stamps_from_the_future_are_refused() {
        let mut s = Screen::new("t", limits());
        // A topic's history from ten seconds ago is not acted on...
        assert!(matches!(
            feed(&mut s, stamp(7, 10, T0), T0 + 10_000 * MS),
            Verdict::Refused(Refusal::TooOld { .. })
        ));
        // ... a fresh step of the same epoch is.
        assert_eq!(
            feed(&mut s, stamp(7, 60, T0 + 10_000 * MS), T0 + 10_001 * MS),
            Verdict::New
        );
        // A backlog after a 2 s stall: too old.
        assert!(matches!(
            feed(&mut s, stamp(7, 61, T0 + 10_200 * MS), T0 + 12_300 * MS),
            Verdict::Refused(Refusal::TooOld { .. })
        ));
        // An hour ahead, or a later step taken earlier: absurd.
        assert!(matches!(
            feed(&mut s, stamp(7, 62, T0 + 3_600_000 * MS), T0 + 12_400 * MS),
            Verdict::Refused(Refusal::Ahead { .. })
        ));
        assert!(matches!(
            feed(&mut s, stamp(7, 62, T0 + 9_000 * MS), T0 + 12_400 * MS),
            Verdict::Refused(Refusal::ClockBack { .. })
        ));
        assert_eq!(
            feed(&mut s, stamp(7, 62, T0 + 12_399 * MS), T0 + 12_400 * MS),
            Verdict::New
        );
        assert_eq!(s.refused(), 4);
        assert_eq!(s.fresh_until(), Some(T0 + 12_399 * MS + MS + 400 * MS));
    }

    #[test]
    fn untimed_stamps_are_judged_by_order_alone() {
        let mut s = Screen::new("t", limits());
        let st = |seq| Stamp::new(seq, 0, 0, 0, StepStatus::Running);
        // Whatever the consumer's clock says.
        assert_eq!(feed(&mut s, st(1), T0), Verdict::New);
        assert_eq!(feed(&mut s, st(2), T0 + 3_600_000 * MS), Verdict::New);
        assert_eq!(feed(&mut s, st(2), 1), Verdict::Repeat);
        assert!(matches!(
            feed(&mut s, st(1), 1),
            Verdict::Refused(Refusal::Older { .. })
        ));
        assert!(matches!(
            feed(&mut s, st(2 + MAX_UNTIMED_JUMP + 1), 1),
            Verdict::Refused(Refusal::SeqJump { .. })
        ));
        assert_eq!(s.fresh_until(), None);
    }
}
