//! The monitor's core: pairs the sway and yaw behaviours' episode reports into one record per
//! episode (they arrive separately, in any order) and keeps the run's totals.

pub mod status;

use messages::LearningStats;
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
}

/// The JSON record of a mesh run (`scripts/sim-mesh --json FILE`).
#[derive(Clone, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct RunRecord {
    pub episodes: usize,
    pub yaw: Vec<f64>,
    pub sway: Vec<f64>,
    pub steps: u64,
    pub wall_s: f64,
    pub lost: Vec<bool>,
    /// Each episode's transitions (episodes differ in length: a lost cable ends one early, a twin
    /// trial is 90 s against a simulated episode's 40 s); compare returns per step across them.
    #[serde(default)]
    pub episode_steps: Vec<u32>,
}

impl RunRecord {
    /// The mean return per step of episodes `range` (yaw, sway); `None` if they have no steps.
    pub fn per_step(&self, range: std::ops::Range<usize>) -> Option<(f64, f64)> {
        let steps: u64 = self
            .episode_steps
            .get(range.clone())?
            .iter()
            .map(|&s| s as u64)
            .sum();
        (steps > 0).then(|| {
            let sum = |v: &[f64]| v[range.clone()].iter().sum::<f64>() / steps as f64;
            (sum(&self.yaw), sum(&self.sway))
        })
    }
}

/// One observation of a trace (the state-trace figures: Theta and x_g over a trial).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct TracePoint {
    pub episode: u32,
    pub step: u32,
    /// Time since the episode started (s).
    pub time_s: f64,
    pub found: bool,
    pub x_g: f64,
    pub theta: f64,
}

impl TracePoint {
    pub fn new(o: &messages::CableObservationMsg, sample_time_s: f64) -> Self {
        TracePoint {
            episode: o.stamp.episode,
            step: o.stamp.step,
            time_s: o.stamp.step as f64 * sample_time_s,
            found: o.observation.found != 0,
            x_g: o.observation.x_g,
            theta: o.observation.theta,
        }
    }
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
            };
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
    }
}
