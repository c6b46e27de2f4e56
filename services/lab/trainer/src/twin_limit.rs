//! The twin's limit: the best linear policy of each DOF on a given twin, found by direct policy search
//! on the twin itself (in one process), both DOFs together since they interact through the
//! allocator, the current and the camera's mount.
//!
//! **The method**: the cross-entropy method over the four gains, started at the LQR gains of the
//! identified model. Each generation samples a population of gain vectors from a Gaussian (the
//! current mean among them), evaluates every one by the evaluation protocol on one *search set*
//! ([`crate::evaluation`]: the same starts, the same frame and exploration noise for all, so the
//! candidates differ by their gains only), and refits the Gaussian to the best quarter. Each DOF's
//! two gains are refitted to the candidates best *for that DOF* (its own return), so each DOF
//! converges to its best answer to the other's policy, with no weighting of the two returns.
//!
//! Why this method: the objective is a simulation with clipping, saturation and a cable that can be
//! lost (a cliff in the return), so it has no useful gradient and is not smooth; the cross-entropy
//! method needs neither, is robust to what noise remains, evaluates a whole population in parallel
//! on every core, and needs no step size (its spread shrinks as it converges). Nelder-Mead would
//! evaluate one point at a time and can stall on the return's kinks.
//!
//! The search set is not the evaluation set: the limit is reported on the evaluation set, so its
//! return is not flattered by the noise it was selected on.

use crate::evaluation::{Evaluation, evaluate, policy_checkpoint};
use crate::experiment::parallel_map;
use crate::progress::Progress;
use crate::twin_world::FromCheckpointError;
use config::{Dof, Eyes, LearningParams, PerDof, Scenario, TwinParams};
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

/// How the search runs.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SearchParams {
    /// Candidates per generation (the mean among them).
    pub population: usize,
    /// Generations at most.
    pub generations: usize,
    /// Trials of the search set (distinct start marks).
    pub trials: u32,
    /// The search set's seed.
    pub seed: u64,
    /// The search stops once every gain's spread is below this.
    pub tolerance: f64,
    pub eyes: Eyes,
}

impl Default for SearchParams {
    fn default() -> Self {
        SearchParams {
            population: 12,
            generations: 16,
            trials: 10,
            seed: 1,
            tolerance: 0.05,
            eyes: Eyes::Images,
        }
    }
}

/// One generation of the search.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Generation {
    /// The sampling distribution's mean and spread, (sway K, yaw K).
    pub mean: PerDof<[f64; 2]>,
    pub spread: PerDof<[f64; 2]>,
    /// The mean's return on the search set.
    pub mean_return: PerDof<f64>,
}

/// What the search found.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Found {
    pub start: PerDof<[f64; 2]>,
    pub gains: PerDof<[f64; 2]>,
    /// The found gains' return on the search set.
    pub search_return: PerDof<f64>,
    pub generations: Vec<Generation>,
    /// Policies evaluated.
    pub evaluations: usize,
}

fn to_vec(g: &PerDof<[f64; 2]>) -> [f64; 4] {
    [g.sway[0], g.sway[1], g.yaw[0], g.yaw[1]]
}

fn to_gains(v: &[f64; 4]) -> PerDof<[f64; 2]> {
    PerDof {
        sway: [v[0], v[1]],
        yaw: [v[2], v[3]],
    }
}

/// The gains' indices in the search vector, per DOF.
fn indices(dof: Dof) -> [usize; 2] {
    match dof {
        Dof::Sway => [0, 1],
        Dof::Yaw => [2, 3],
    }
}

/// Searches the best linear policies on `twin` from `start` (see the module docs).
pub fn search(
    scenario: &Scenario,
    learning: &LearningParams,
    twin: &TwinParams,
    start: PerDof<[f64; 2]>,
    params: &SearchParams,
    progress: &Progress,
) -> Result<Found, FromCheckpointError> {
    // The search set: `trials` distinct start marks.
    let mut search_twin = twin.clone();
    search_twin.trials.cycle = params.trials;
    let evaluate_gains = |v: &[f64; 4]| -> Result<Evaluation, FromCheckpointError> {
        let c = policy_checkpoint(scenario, learning, to_gains(v));
        evaluate(
            scenario,
            &search_twin,
            params.eyes,
            &c,
            params.seed,
            params.trials,
        )
    };
    let mut rng = StdRng::seed_from_u64(config::derive_seed(params.seed, "twin-limit/sampling"));
    let mut mean = to_vec(&start);
    let mut spread: [f64; 4] = std::array::from_fn(|i| 0.5 * mean[i].abs() + 1.0);
    let population = params.population.max(4);
    let elite = (population / 3).max(2);
    let mut generations = Vec::new();
    let mut evaluations = 0;
    let mut mean_return = None;
    for g in 0..params.generations.max(1) {
        let candidates: Vec<[f64; 4]> = (0..population)
            .map(|k| {
                if k == 0 {
                    mean
                } else {
                    std::array::from_fn(|i| {
                        let n: f64 = StandardNormal.sample(&mut rng);
                        mean[i] + spread[i] * n
                    })
                }
            })
            .collect();
        let results = parallel_map(population, &Progress::hidden(), |k| {
            evaluate_gains(&candidates[k]).map(|e| e.mean())
        });
        evaluations += population;
        let results = results.into_iter().collect::<Result<Vec<_>, _>>()?;
        mean_return = Some(results[0]);
        generations.push(Generation {
            mean: to_gains(&mean),
            spread: to_gains(&spread),
            mean_return: results[0],
        });
        tracing::info!(
            generation = g + 1,
            sway = ?to_gains(&mean).sway,
            yaw = ?to_gains(&mean).yaw,
            sway_return = results[0].sway,
            yaw_return = results[0].yaw,
            "twin limit: search"
        );
        progress.tick();
        if spread.iter().all(|s| *s < params.tolerance) {
            break;
        }
        for dof in Dof::ALL {
            let mut order: Vec<usize> = (0..population).collect();
            order.sort_by(|a, b| results[*b].get(dof).total_cmp(results[*a].get(dof)));
            for i in indices(dof) {
                let values: Vec<f64> = order[..elite].iter().map(|&k| candidates[k][i]).collect();
                let m = stats::mean(values.iter().copied());
                let sd = (stats::mean(values.iter().map(|v| (v - m).powi(2)))).sqrt();
                // Smoothed, so one lucky generation does not collapse the spread; and never below
                // the step the mean just took, so the search keeps its reach while it still travels
                // (the cross-entropy method's known failure is to shrink before it arrives).
                let step = (m - mean[i]).abs();
                spread[i] = 0.5 * spread[i] + 0.5 * sd.max(step).max(0.5 * params.tolerance);
                mean[i] = m;
            }
        }
    }
    // The last generation's mean; evaluated once more if it moved after its last evaluation.
    let last = generations.last().expect("one generation at least");
    let mut search_return = if to_vec(&last.mean) == mean {
        mean_return.expect("evaluated")
    } else {
        evaluations += 1;
        evaluate_gains(&mean)?.mean()
    };
    // Never worse than the start: a DOF whose search ended below its start's return on the search
    // set (a population that drifted into losing the cable) keeps the start's gains.
    let first = generations[0].mean_return;
    let mut kept_start = false;
    for dof in Dof::ALL {
        if first.get(dof) > search_return.get(dof) {
            tracing::warn!(
                %dof,
                start = first.get(dof),
                found = search_return.get(dof),
                "twin limit: the search ended worse than its start; the start's gains are kept"
            );
            for i in indices(dof) {
                mean[i] = to_vec(&start)[i];
            }
            kept_start = true;
        }
    }
    if kept_start {
        evaluations += 1;
        search_return = evaluate_gains(&mean)?.mean();
    }
    Ok(Found {
        start,
        gains: to_gains(&mean),
        search_return,
        generations,
        evaluations,
    })
}
