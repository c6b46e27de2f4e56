//! The monitor's core: pairs the sway and yaw behaviours' episode reports into one record per
//! episode (they arrive separately, in any order) and keeps the run's totals.
//!
//! A report that cannot be true (a return that is not finite or above 0: rewards are costs, a gain
//! that is not finite) is refused ([`check`]). A monitor restarted mid-run resumes from the record
//! it wrote ([`Episodes::resume`]), and a run with a report lost on the way (its behaviour or the
//! monitor restarting as the episode ended) still ends: the run is done once its last episode is
//! recorded, or reported by one behaviour while the other's report never came
//! ([`Episodes::finished`]).

pub mod status;

use config::PerDof;
use messages::LearningStats;
use records::{EvaluationRecord, RunRecord, SafetyCounts};
use serde::Serialize;
use std::collections::BTreeMap;

/// One finished episode, as both behaviours reported it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct EpisodeRecord {
    pub episode: u32,
    pub steps: u32,
    pub lost: bool,
    pub yaw: f64,
    pub sway: f64,
    pub yaw_gain: [f64; 2],
    pub sway_gain: [f64; 2],
    /// An evaluation trial of step two (both behaviours acted without learning).
    pub evaluation: bool,
    /// Each behaviour's safety counts after the episode.
    pub safety: PerDof<SafetyCounts>,
    /// The mean returns of the evaluation this episode closed (NaN when none).
    pub evaluated: PerDof<f64>,
    /// Which behaviours restored a policy after that evaluation (the best, or before one, the
    /// simulation policies).
    pub rolled_back: PerDof<bool>,
    /// The evaluated return of the policy a rollback restores: the best so far, or before one, the
    /// simulation policies' (NaN before the first evaluation).
    pub best: PerDof<f64>,
}

/// The lowest return a behaviour's report can carry, per transition it counts: every transition at
/// the worst reward over the observation box and the action range, and at most one failure reward.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReturnFloor {
    pub worst_step: f64,
    pub failure: f64,
}

impl ReturnFloor {
    /// The floor of `dof`'s reports under `scenario`'s reward and `learning`'s discount.
    pub fn of(
        dof: config::Dof,
        scenario: &config::Scenario,
        learning: &config::LearningParams,
    ) -> Self {
        let cost = scenario.reward.of(dof);
        let state_max = scenario.state_max(dof);
        ReturnFloor {
            worst_step: cost.reward(state_max, 1.0),
            failure: learning::failure_reward(cost, state_max, learning.nac.gamma),
        }
    }

    /// The lowest return of `steps` transitions.
    pub fn lowest(&self, steps: u32) -> f64 {
        f64::from(steps) * self.worst_step.min(0.0) + self.failure.min(0.0)
    }
}

/// Why a report was refused: its return is not a sum of `steps` costs (never below `floor`), it
/// counts no transition (a behaviour reports none without one), or a gain is not finite.
pub fn check(stats: &LearningStats, floor: &ReturnFloor) -> Result<(), String> {
    if !(stats.episode_return.is_finite() && stats.episode_return <= 0.0) {
        return Err(format!(
            "return {} (a sum of costs: finite, at most 0)",
            stats.episode_return
        ));
    }
    if stats.steps == 0 {
        return Err("no transition in the episode".into());
    }
    let lowest = floor.lowest(stats.steps);
    if stats.episode_return < lowest {
        return Err(format!(
            "return {} is below {lowest}, the lowest {} transitions can sum",
            stats.episode_return, stats.steps
        ));
    }
    if !stats.gain.iter().all(|g| g.is_finite()) {
        return Err(format!("gain {:?} is not finite", stats.gain));
    }
    Ok(())
}

/// The evaluations among `episodes` (in order).
fn evaluations(episodes: &[EpisodeRecord]) -> Vec<EvaluationRecord> {
    let finite = |v: f64| v.is_finite().then_some(v);
    let mut learned = 0;
    let mut out = Vec::new();
    for d in episodes {
        learned += !d.evaluation as u32;
        if !(d.evaluated.sway.is_finite() || d.evaluated.yaw.is_finite()) {
            continue;
        }
        let in_force = |dof: config::Dof| {
            if *d.rolled_back.get(dof) {
                finite(*d.best.get(dof))
            } else {
                finite(*d.evaluated.get(dof))
            }
        };
        out.push(EvaluationRecord {
            trial: d.episode,
            learning_trials: learned,
            evaluated: PerDof {
                sway: finite(d.evaluated.sway),
                yaw: finite(d.evaluated.yaw),
            },
            in_force: PerDof {
                sway: in_force(config::Dof::Sway),
                yaw: in_force(config::Dof::Yaw),
            },
            rolled_back: d.rolled_back,
        });
    }
    out
}

/// Pairs reports by episode.
#[derive(Debug, Default)]
pub struct Episodes {
    pending: BTreeMap<u32, (Option<LearningStats>, Option<LearningStats>)>,
    done: Vec<EpisodeRecord>,
}

impl Episodes {
    pub fn new() -> Self {
        Self::default()
    }

    /// The episodes of a record written before (a restarted monitor carries on from it). The record
    /// holds the safety counts of its last episode only; the earlier ones read as 0.
    pub fn resume(record: &RunRecord) -> Self {
        let n = record.episodes;
        let nan = PerDof {
            sway: f64::NAN,
            yaw: f64::NAN,
        };
        let done = (0..n)
            .map(|k| {
                let episode = record.episode_numbers.get(k).copied().unwrap_or(k as u32);
                let closed = record.evaluations.iter().find(|e| e.trial == episode);
                let or_nan = |v: Option<f64>| v.unwrap_or(f64::NAN);
                EpisodeRecord {
                    episode,
                    steps: record.episode_steps.get(k).copied().unwrap_or(0),
                    lost: record.lost.get(k).copied().unwrap_or(false),
                    yaw: record.yaw.get(k).copied().unwrap_or(0.0),
                    sway: record.sway.get(k).copied().unwrap_or(0.0),
                    yaw_gain: record.yaw_gain.get(k).copied().unwrap_or([0.0; 2]),
                    sway_gain: record.sway_gain.get(k).copied().unwrap_or([0.0; 2]),
                    evaluation: record.evaluation.get(k).copied().unwrap_or(false),
                    safety: if k + 1 == n {
                        record.safety
                    } else {
                        PerDof::default()
                    },
                    evaluated: closed.map_or(nan, |e| PerDof {
                        sway: or_nan(e.evaluated.sway),
                        yaw: or_nan(e.evaluated.yaw),
                    }),
                    rolled_back: closed.map_or_else(PerDof::default, |e| e.rolled_back),
                    // Where a policy was restored, its return is the one in force after the evaluation.
                    best: closed.map_or(nan, |e| PerDof {
                        sway: or_nan(e.in_force.sway),
                        yaw: or_nan(e.in_force.yaw),
                    }),
                }
            })
            .collect();
        Episodes {
            pending: BTreeMap::new(),
            done,
        }
    }

    /// The run of `episodes` episodes (numbered from 0) is done: its last episode is recorded; or
    /// one behaviour reported it and `lingered` (the time since that report) is long enough for the
    /// other's to have come, had it not been lost.
    pub fn finished(
        &self,
        episodes: u32,
        lingered: Option<std::time::Duration>,
        linger: std::time::Duration,
    ) -> bool {
        let Some(last) = episodes.checked_sub(1) else {
            return false;
        };
        self.done.iter().any(|d| d.episode >= last)
            || (self.pending.keys().any(|&e| e >= last) && lingered.is_some_and(|t| t >= linger))
    }

    /// Whether a report of an episode at or past `episode` is waiting for its pair.
    pub fn pending_from(&self, episode: u32) -> bool {
        self.pending.keys().any(|&e| e >= episode)
    }

    /// Episodes below the newest recorded one that have no record (their reports were lost).
    pub fn gaps(&self) -> Vec<u32> {
        let recorded: std::collections::BTreeSet<u32> =
            self.done.iter().map(|d| d.episode).collect();
        let Some(&newest) = recorded.iter().next_back() else {
            return Vec::new();
        };
        let first = *recorded.iter().next().expect("not empty");
        (first..newest).filter(|e| !recorded.contains(e)).collect()
    }

    /// Adds one behaviour's report; returns the episode's record once both reported it.
    pub fn add(&mut self, dof: config::Dof, stats: LearningStats) -> Option<EpisodeRecord> {
        let episode = stats.stamp.episode;
        if self.done.iter().any(|d| d.episode == episode) {
            return None; // a repeated report (history on reconnect)
        }
        let slot = self.pending.entry(episode).or_default();
        match dof {
            config::Dof::Sway => slot.0 = Some(stats),
            config::Dof::Yaw => slot.1 = Some(stats),
        }
        if let (Some(sway), Some(yaw)) = *slot {
            self.pending.remove(&episode);
            let record = EpisodeRecord {
                episode,
                steps: sway.steps.max(yaw.steps),
                lost: sway.failed != 0 || yaw.failed != 0,
                yaw: yaw.episode_return,
                sway: sway.episode_return,
                yaw_gain: yaw.gain,
                sway_gain: sway.gain,
                evaluation: sway.evaluation != 0 && yaw.evaluation != 0,
                safety: PerDof {
                    sway: (&sway).into(),
                    yaw: (&yaw).into(),
                },
                evaluated: PerDof {
                    sway: sway.evaluated,
                    yaw: yaw.evaluated,
                },
                rolled_back: PerDof {
                    sway: sway.rolled_back != 0,
                    yaw: yaw.rolled_back != 0,
                },
                best: PerDof {
                    sway: sway.best_evaluated,
                    yaw: yaw.best_evaluated,
                },
            };
            if record.rolled_back.sway || record.rolled_back.yaw {
                tracing::warn!(
                    episode,
                    sway = record.rolled_back.sway,
                    yaw = record.rolled_back.yaw,
                    "a policy evaluated before was restored after this evaluation (the best, or before one, the simulation policies)"
                );
            }
            self.done.push(record);
            return Some(record);
        }
        None
    }

    pub fn done(&self) -> &[EpisodeRecord] {
        &self.done
    }

    /// The run's record, episodes in order.
    pub fn record(&self, wall_s: f64) -> RunRecord {
        let mut done = self.done.clone();
        done.sort_by_key(|d| d.episode);
        RunRecord {
            episodes: done.len(),
            yaw: done.iter().map(|d| d.yaw).collect(),
            sway: done.iter().map(|d| d.sway).collect(),
            steps: done.iter().map(|d| d.steps as u64).sum(),
            wall_s,
            lost: done.iter().map(|d| d.lost).collect(),
            episode_steps: done.iter().map(|d| d.steps).collect(),
            evaluation: done.iter().map(|d| d.evaluation).collect(),
            evaluations: evaluations(&done),
            yaw_gain: done.iter().map(|d| d.yaw_gain).collect(),
            sway_gain: done.iter().map(|d| d.sway_gain).collect(),
            safety: done.last().map_or_else(PerDof::default, |d| d.safety),
            episode_numbers: done.iter().map(|d| d.episode).collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use config::Dof;
    use messages::{Stamp, StepStatus};

    fn stats(episode: u32, ret: f64, failed: bool) -> LearningStats {
        LearningStats {
            stamp: Stamp::new(1, 0, episode, 10, StepStatus::TimeLimit),
            episode_return: ret,
            steps: 10,
            failed: failed as u8,
            ..Default::default()
        }
    }

    #[test]
    fn pairs_reports_in_any_order_and_ignores_repeats() {
        let mut e = Episodes::new();
        assert!(e.add(Dof::Yaw, stats(1, -2.0, false)).is_none());
        assert!(e.add(Dof::Sway, stats(0, -0.5, false)).is_none());
        let r = e.add(Dof::Sway, stats(1, -0.3, true)).unwrap();
        assert_eq!((r.episode, r.yaw, r.sway, r.lost), (1, -2.0, -0.3, true));
        assert!(e.add(Dof::Yaw, stats(1, -9.0, false)).is_none(), "a repeat");
        e.add(Dof::Yaw, stats(0, -1.0, false)).unwrap();
        let rec = e.record(2.0);
        assert_eq!(rec.yaw, vec![-1.0, -2.0]);
        assert_eq!(rec.sway, vec![-0.5, -0.3]);
        assert_eq!((rec.episodes, rec.steps), (2, 20));
        assert_eq!(rec.episode_steps, vec![10, 10]);
        let (yaw, sway) = rec.per_step(0..2).unwrap();
        assert!((yaw - -3.0 / 20.0).abs() < 1e-12 && (sway - -0.8 / 20.0).abs() < 1e-12);
        assert_eq!(rec.per_step(1..3), None, "out of range");
        assert_eq!(rec.episode_numbers, vec![0, 1]);
    }

    #[test]
    fn impossible_reports_are_refused() {
        let scenario = config::Scenario::default();
        let floor = ReturnFloor::of(Dof::Sway, &scenario, &config::LearningParams::default());
        assert!(floor.worst_step < 0.0 && floor.failure < floor.worst_step);
        assert!(check(&stats(1, -2.0, false), &floor).is_ok());
        // Ten transitions at the worst reward, one of them the failure: the lowest possible.
        let lowest = 10.0 * floor.worst_step + floor.failure;
        assert!(check(&stats(1, lowest * 0.999, true), &floor).is_ok());
        for bad in [f64::NAN, f64::INFINITY, 50.0, lowest * 1.01, -1e300] {
            assert!(check(&stats(1, bad, false), &floor).is_err(), "{bad}");
        }
        let mut s = stats(1, -2.0, false);
        s.gain[1] = f64::NEG_INFINITY;
        assert!(check(&s, &floor).is_err());
        let mut none = stats(1, -2.0, false);
        none.steps = 0;
        assert!(check(&none, &floor).is_err(), "a report of no transition");
    }

    /// A restarted monitor resumes from its record; a lost report neither hangs the run nor
    /// hides: the run ends on its last episode, and the gap is known.
    #[test]
    fn a_restarted_monitor_resumes_and_a_lost_report_does_not_hang_the_run() {
        use std::time::Duration;
        let linger = Duration::from_secs(10);
        let mut e = Episodes::new();
        for ep in 0..2 {
            e.add(Dof::Sway, stats(ep, -0.5, false));
            e.add(Dof::Yaw, stats(ep, -1.0, false));
        }
        let mut e = Episodes::resume(&e.record(1.0));
        assert_eq!(e.done().len(), 2);
        assert!(
            e.add(Dof::Yaw, stats(1, -9.0, false)).is_none(),
            "recorded before the restart"
        );
        // Episode 2's sway report was lost; episode 3 is the last of a run of 4.
        e.add(Dof::Yaw, stats(2, -1.0, false));
        e.add(Dof::Sway, stats(3, -0.5, false));
        assert!(!e.finished(4, None, linger));
        assert!(e.pending_from(3));
        assert!(
            !e.finished(4, Some(Duration::from_secs(1)), linger),
            "its pair may still come"
        );
        assert!(
            e.finished(4, Some(linger), linger),
            "its pair was lost: the run ends"
        );
        e.add(Dof::Yaw, stats(3, -1.0, false));
        assert!(e.finished(4, None, linger));
        assert_eq!(e.gaps(), vec![2]);
        assert!(
            !e.finished(0, None, linger),
            "0 episodes: run until stopped"
        );
        let rec = e.record(2.0);
        assert_eq!(rec.episode_numbers, vec![0, 1, 3]);
    }

    /// Step two: evaluation trials, the evaluations they close (with the learning trials before
    /// them), a rollback, and the safety counts of the last report.
    #[test]
    fn evaluations_and_safety_counts_are_recorded() {
        let report = |episode: u32, evaluation: bool, evaluated: f64, rolled: bool, n: u64| {
            let mut s = stats(episode, -1.0, false);
            s.evaluation = evaluation as u8;
            s.evaluated = evaluated;
            s.best_evaluated = -2.0;
            s.rolled_back = rolled as u8;
            s.refused = n;
            s.rollbacks = rolled as u64;
            s
        };
        let mut e = Episodes::new();
        // Trials 0-1 evaluate (closing at 1), 2-3 learn, 4-5 evaluate (closing at 5, sway rolled back).
        for (t, ev, closes) in [
            (0, true, false),
            (1, true, true),
            (2, false, false),
            (3, false, false),
            (4, true, false),
            (5, true, true),
        ] {
            let value = if closes {
                -2.0 - t as f64 / 10.0
            } else {
                f64::NAN
            };
            e.add(Dof::Sway, report(t, ev, value, t == 5, t as u64));
            e.add(Dof::Yaw, report(t, ev, value, false, 0));
        }
        let rec = e.record(1.0);
        assert_eq!(rec.evaluation, vec![true, true, false, false, true, true]);
        assert_eq!(rec.evaluations.len(), 2);
        let (first, second) = (rec.evaluations[0], rec.evaluations[1]);
        assert_eq!((first.trial, first.learning_trials), (1, 0));
        assert_eq!((second.trial, second.learning_trials), (5, 2));
        assert_eq!(second.evaluated.sway, Some(-2.5));
        assert_eq!(second.in_force.sway, Some(-2.0), "the best one, restored");
        assert_eq!(second.in_force.yaw, Some(-2.5));
        assert!(second.rolled_back.sway && !second.rolled_back.yaw);
        assert_eq!((rec.safety.sway.refused, rec.safety.sway.rollbacks), (5, 1));
        let text = serde_json::to_string(&rec).unwrap();
        let back: RunRecord = serde_json::from_str(&text).unwrap();
        assert_eq!(back.evaluations, rec.evaluations);
    }
}
