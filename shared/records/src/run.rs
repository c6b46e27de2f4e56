//! The run record: what the monitor writes of a mesh run (`monitor --json FILE`, after every
//! episode), and its trace of observations (`monitor --trace FILE`, one JSON line each).

use config::PerDof;
use messages::LearningStats;
use serde::{Deserialize, Serialize};

/// A behaviour's safety layer, counted (step two): actor updates shortened by the trust region or
/// refused by the stability guard, and rollbacks to the best policy.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SafetyCounts {
    pub bounded: u64,
    pub refused: u64,
    pub rollbacks: u64,
}

impl From<&LearningStats> for SafetyCounts {
    fn from(s: &LearningStats) -> Self {
        SafetyCounts {
            bounded: s.bounded,
            refused: s.refused,
            rollbacks: s.rollbacks,
        }
    }
}

/// One evaluation of step two: the trial that closed it, the learning trials before it, and each
/// DOF's evaluated return (`None`: that behaviour did not judge it, e.g. it was restarted during
/// the evaluation).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvaluationRecord {
    pub trial: u32,
    pub learning_trials: u32,
    pub evaluated: PerDof<Option<f64>>,
    /// The evaluated return of the policy in force after the evaluation: the evaluated one, or the
    /// best one where it was restored.
    pub in_force: PerDof<Option<f64>>,
    /// Which behaviours restored their best policy after it.
    pub rolled_back: PerDof<bool>,
}

/// The JSON record of a mesh run (`scripts/sim-mesh --json FILE`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
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
    /// Step two: which episodes were evaluation trials (the policy acted without learning).
    #[serde(default)]
    pub evaluation: Vec<bool>,
    /// Step two: each evaluation's mean returns, in order.
    #[serde(default)]
    pub evaluations: Vec<EvaluationRecord>,
    /// Each policy's gain after each episode.
    #[serde(default)]
    pub yaw_gain: Vec<[f64; 2]>,
    #[serde(default)]
    pub sway_gain: Vec<[f64; 2]>,
    /// Step two: each behaviour's safety counts at the end of the run.
    #[serde(default)]
    pub safety: PerDof<SafetyCounts>,
    /// Each record's episode number (a report lost on the way leaves a gap).
    #[serde(default)]
    pub episode_numbers: Vec<u32>,
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
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
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

#[cfg(test)]
mod tests {
    use super::*;
    use messages::{CableObservationData, CableObservationMsg, Stamp, StepStatus};

    /// A record written before step two (no evaluations, gains or safety counts) reads with those
    /// empty, and a whole record reads back as written.
    #[test]
    fn an_older_record_reads_with_defaults_and_a_whole_one_reads_back() {
        let old = r#"{"episodes":2,"yaw":[-1.5,-1.25],"sway":[-0.5,-0.25],"steps":90,
            "wall_s":3.5,"lost":[false,true]}"#;
        let r: RunRecord = serde_json::from_str(old).unwrap();
        assert_eq!((r.episodes, r.steps, r.lost[1]), (2, 90, true));
        assert!(r.episode_steps.is_empty() && r.evaluations.is_empty() && r.yaw_gain.is_empty());
        assert_eq!(r.safety, PerDof::default());
        assert_eq!(r.per_step(0..2), None, "no steps per episode in it");

        let whole = RunRecord {
            episode_steps: vec![40, 50],
            evaluation: vec![false, true],
            evaluations: vec![EvaluationRecord {
                trial: 1,
                learning_trials: 1,
                evaluated: PerDof {
                    sway: Some(-0.1),
                    yaw: None,
                },
                in_force: PerDof {
                    sway: Some(-0.1),
                    yaw: None,
                },
                rolled_back: PerDof {
                    sway: false,
                    yaw: true,
                },
            }],
            yaw_gain: vec![[1.0, 2.0]; 2],
            sway_gain: vec![[0.5, 1.0 / 3.0]; 2],
            episode_numbers: vec![0, 1],
            ..r
        };
        let text = serde_json::to_string(&whole).unwrap();
        assert_eq!(serde_json::from_str::<RunRecord>(&text).unwrap(), whole);
        let (yaw, sway) = whole.per_step(0..2).unwrap();
        assert_eq!((yaw, sway), (-2.75 / 90.0, -0.75 / 90.0));
    }

    #[test]
    fn a_trace_point_is_an_observation_at_its_step() {
        let o = CableObservationMsg {
            stamp: Stamp::new(7, 0, 3, 12, StepStatus::Running),
            observation: CableObservationData {
                found: 1,
                x_g: 0.25,
                theta: -0.5,
                ..Default::default()
            },
        };
        let p = TracePoint::new(&o, 0.2);
        assert_eq!(
            (p.episode, p.step, p.found, p.x_g, p.theta),
            (3, 12, true, 0.25, -0.5)
        );
        assert!((p.time_s - 2.4).abs() < 1e-12);
    }
}
