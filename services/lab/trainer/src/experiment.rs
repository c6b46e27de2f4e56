//! Experiments over many independent runs: learning curves (Fig. 5), the learning-rate sweep and
//! the LQR yardstick. Runs are spread over all cores; each run's random streams come from the
//! experiment seed and the run's index, so a result does not depend on how runs were scheduled.

use crate::Setup;
use crate::progress::Progress;
use crate::world::{EpisodeResult, World};
use config::{Dof, PerDof, derive_seed};
use learning::Algorithm;
use learning::agent::Agent;
use learning::lqr::discounted_lqr;
use nalgebra::{Matrix1, Matrix2, Vector2};
use serde::Serialize;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

/// The seed of run `run` of an experiment.
pub fn run_seed(seed: u64, run: usize) -> u64 {
    derive_seed(seed, &format!("run-{run}"))
}

/// Maps `f` over `0..n` on all cores, in order, ticking `progress` once per item.
pub fn parallel_map<T: Send>(
    n: usize,
    progress: &Progress,
    f: impl Fn(usize) -> T + Sync,
) -> Vec<T> {
    parallel_map_on(0, n, progress, f)
}

/// [`parallel_map`] on `threads` threads (0: one per core). Each item is computed alone, so the
/// result does not depend on the threads.
pub fn parallel_map_on<T: Send>(
    threads: usize,
    n: usize,
    progress: &Progress,
    f: impl Fn(usize) -> T + Sync,
) -> Vec<T> {
    let cores = std::thread::available_parallelism().map_or(1, |p| p.get());
    let workers = if threads == 0 { cores } else { threads }.min(n.max(1));
    let next = AtomicUsize::new(0);
    let slots: Mutex<Vec<Option<T>>> = Mutex::new((0..n).map(|_| None).collect());
    std::thread::scope(|scope| {
        for _ in 0..workers {
            scope.spawn(|| {
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    if i >= n {
                        break;
                    }
                    let value = f(i);
                    slots.lock().expect("a worker panicked")[i] = Some(value);
                    progress.tick();
                }
            });
        }
    });
    slots
        .into_inner()
        .expect("a worker panicked")
        .into_iter()
        .map(|v| v.expect("every index was computed"))
        .collect()
}

/// One run: a fresh pair of learners for `episodes` episodes.
pub fn learning_run(
    setup: &Setup,
    algorithm: Algorithm,
    episodes: usize,
    seed: u64,
) -> Vec<EpisodeResult> {
    let mut world = World::new(
        &setup.scenario,
        &setup.learning,
        algorithm,
        setup.perceiver(seed),
        seed,
    );
    (0..episodes).map(|_| world.run_episode()).collect()
}

/// `runs` independent learning runs.
pub fn learning_runs(
    setup: &Setup,
    algorithm: Algorithm,
    runs: usize,
    episodes: usize,
    seed: u64,
    progress: &Progress,
) -> Vec<Vec<EpisodeResult>> {
    parallel_map(runs, progress, |r| {
        learning_run(setup, algorithm, episodes, run_seed(seed, r))
    })
}

/// Per-episode mean and standard deviation over runs.
#[derive(Clone, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct Curve {
    pub mean: Vec<f64>,
    pub std: Vec<f64>,
}

impl Curve {
    /// The curve of one DOF's returns over runs (all runs have the same length).
    pub fn of(runs: &[Vec<EpisodeResult>], dof: Dof) -> Curve {
        let episodes = runs.iter().map(Vec::len).min().unwrap_or(0);
        let mut mean = Vec::with_capacity(episodes);
        let mut std = Vec::with_capacity(episodes);
        for e in 0..episodes {
            let values: Vec<f64> = runs.iter().map(|run| *run[e].returns.get(dof)).collect();
            let (m, s) = mean_std(&values);
            mean.push(m);
            std.push(s);
        }
        Curve { mean, std }
    }

    /// The mean of the last `n` episodes' means.
    pub fn tail_mean(&self, n: usize) -> f64 {
        let n = n.min(self.mean.len()).max(1);
        mean_std(&self.mean[self.mean.len().saturating_sub(n)..]).0
    }

    /// The first episode (counting from 1) from which the `window`-episode moving average of the mean
    /// stays within `fraction` of `target`, if any.
    pub fn first_within(&self, target: f64, fraction: f64, window: usize) -> Option<usize> {
        let avg = moving_average(&self.mean, window);
        let ok: Vec<bool> = avg
            .iter()
            .map(|v| (v - target).abs() <= fraction * target.abs())
            .collect();
        (0..ok.len())
            .find(|&i| ok[i..].iter().all(|&b| b))
            .map(|i| i + 1)
    }
}

/// A trailing moving average (shorter windows at the start).
pub fn moving_average(values: &[f64], window: usize) -> Vec<f64> {
    let window = window.max(1);
    (0..values.len())
        .map(|i| {
            let start = (i + 1).saturating_sub(window);
            mean_std(&values[start..=i]).0
        })
        .collect()
}

/// Mean and (population) standard deviation; (NaN, NaN) for no values.
pub fn mean_std(values: &[f64]) -> (f64, f64) {
    if values.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
    (mean, var.sqrt())
}

/// Fraction of episodes in which the cable was lost, over the last `n` episodes of every run.
pub fn late_loss_fraction(runs: &[Vec<EpisodeResult>], n: usize) -> f64 {
    let late: Vec<bool> = runs
        .iter()
        .flat_map(|run| run[run.len().saturating_sub(n)..].iter().map(|e| e.lost))
        .collect();
    late.iter().filter(|&&l| l).count() as f64 / late.len().max(1) as f64
}

/// The LQR yardstick: the optimal linear policy of each DOF on the identified model.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Limit {
    /// The LQR gain K (u = K x) of each DOF.
    pub gain: PerDof<[f64; 2]>,
    /// Its mean episode return under the task's resets and exploration noise.
    pub mean_return: PerDof<f64>,
    /// The standard error of those means.
    pub std_error: PerDof<f64>,
    /// Fraction of episodes in which the cable was lost.
    pub lost_fraction: f64,
    pub episodes: usize,
}

/// The LQR gains: the discounted Riccati solution on the exact discretisation of each DOF's
/// decoupled linear dynamics, with the task's Q, R and gamma.
pub fn lqr_gains(setup: &Setup) -> Result<PerDof<[f64; 2]>, learning::lqr::LqrError> {
    let s = &setup.scenario;
    let gain = |dof: Dof| {
        let sys = behaviour::identified_model(s, dof)?;
        let cost = s.reward.of(dof);
        let q = Matrix2::from_diagonal(&Vector2::new(cost.q[0], cost.q[1]));
        let lqr = discounted_lqr(&sys, &q, &Matrix1::new(cost.r), setup.learning.nac.gamma)?;
        Ok([lqr.gain[(0, 0)], lqr.gain[(0, 1)]])
    };
    Ok(PerDof {
        sway: gain(Dof::Sway)?,
        yaw: gain(Dof::Yaw)?,
    })
}

/// Evaluates fixed gains (no learning) over `episodes` episodes with the task's resets and noise.
pub fn evaluate(
    setup: &Setup,
    gains: PerDof<[f64; 2]>,
    episodes: usize,
    seed: u64,
    progress: &Progress,
) -> Evaluation {
    const CHUNK: usize = 50;
    let chunks = episodes.div_ceil(CHUNK);
    let results: Vec<Vec<EpisodeResult>> = parallel_map(chunks, progress, |c| {
        let seed = run_seed(seed, c);
        let agents = fixed_agents(setup, gains, seed);
        let mut world = World::with_agents(&setup.scenario, agents, setup.perceiver(seed), seed);
        let n = CHUNK.min(episodes - c * CHUNK);
        (0..n).map(|_| world.run_episode()).collect()
    });
    let all: Vec<&EpisodeResult> = results.iter().flatten().collect();
    let stats = |dof: Dof| {
        let v: Vec<f64> = all.iter().map(|e| *e.returns.get(dof)).collect();
        let (m, s) = mean_std(&v);
        (m, s / (v.len() as f64).sqrt())
    };
    let (sway, yaw) = (stats(Dof::Sway), stats(Dof::Yaw));
    Evaluation {
        mean_return: PerDof {
            sway: sway.0,
            yaw: yaw.0,
        },
        std_error: PerDof {
            sway: sway.1,
            yaw: yaw.1,
        },
        lost_fraction: all.iter().filter(|e| e.lost).count() as f64 / all.len().max(1) as f64,
        episodes: all.len(),
    }
}

/// The mean returns of a fixed policy.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Evaluation {
    pub mean_return: PerDof<f64>,
    pub std_error: PerDof<f64>,
    pub lost_fraction: f64,
    pub episodes: usize,
}

/// Agents acting with fixed gains, learning off.
pub fn fixed_agents(setup: &Setup, gains: PerDof<[f64; 2]>, seed: u64) -> PerDof<Agent> {
    let mut learning = setup.learning.clone();
    learning.policy.initial_gain = gains;
    let (_, seeds) = crate::world::stream_seeds(seed);
    let agent = |dof: Dof| {
        let mut a = behaviour::new_agent(
            dof,
            Algorithm::Nac,
            &setup.scenario,
            &learning,
            *seeds.get(dof),
        );
        a.set_learning(false);
        a
    };
    PerDof {
        sway: agent(Dof::Sway),
        yaw: agent(Dof::Yaw),
    }
}

/// `trainer limit`: the LQR gains and their mean returns.
pub fn limit(
    setup: &Setup,
    episodes: usize,
    seed: u64,
    progress: &Progress,
) -> Result<Limit, learning::lqr::LqrError> {
    let gain = lqr_gains(setup)?;
    let eval = evaluate(setup, gain, episodes, derive_seed(seed, "limit"), progress);
    Ok(Limit {
        gain,
        mean_return: eval.mean_return,
        std_error: eval.std_error,
        lost_fraction: eval.lost_fraction,
        episodes: eval.episodes,
    })
}

/// One row of a learning-rate sweep.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SweepRow {
    pub alpha: f64,
    /// Mean return over all episodes and runs (the area under the learning curve).
    pub mean_return: PerDof<f64>,
    /// Mean return over the last quarter of the episodes.
    pub late_return: PerDof<f64>,
    /// Fraction of late episodes that lost the cable.
    pub late_lost: f64,
}

/// The sweep: the same runs at each learning rate (both DOFs use it).
pub fn sweep(
    setup: &Setup,
    algorithm: Algorithm,
    alphas: &[f64],
    runs: usize,
    episodes: usize,
    seed: u64,
    progress: &Progress,
) -> Vec<SweepRow> {
    let cells = alphas.len() * runs;
    let results = parallel_map(cells, progress, |i| {
        let (a, r) = (i / runs, i % runs);
        let mut s = setup.clone();
        s.set_alpha(algorithm, PerDof::both(alphas[a]));
        learning_run(&s, algorithm, episodes, run_seed(seed, r))
    });
    let late = (episodes / 4).max(1);
    alphas
        .iter()
        .enumerate()
        .map(|(a, &alpha)| {
            let block = &results[a * runs..(a + 1) * runs];
            let over = |dof: Dof, from: usize| {
                let v: Vec<f64> = block
                    .iter()
                    .flat_map(|run| run[from..].iter().map(|e| *e.returns.get(dof)))
                    .collect();
                mean_std(&v).0
            };
            SweepRow {
                alpha,
                mean_return: PerDof {
                    sway: over(Dof::Sway, 0),
                    yaw: over(Dof::Yaw, 0),
                },
                late_return: PerDof {
                    sway: over(Dof::Sway, episodes - late),
                    yaw: over(Dof::Yaw, episodes - late),
                },
                late_lost: late_loss_fraction(block, late),
            }
        })
        .collect()
}

/// The best learning rate of each DOF in a sweep: the highest late return (what Fig. 5's end shows).
pub fn best_alpha(rows: &[SweepRow]) -> PerDof<f64> {
    let best = |dof: Dof| {
        rows.iter()
            .filter(|r| r.late_return.get(dof).is_finite())
            .max_by(|a, b| a.late_return.get(dof).total_cmp(b.late_return.get(dof)))
            .map_or(f64::NAN, |r| r.alpha)
    };
    PerDof {
        sway: best(Dof::Sway),
        yaw: best(Dof::Yaw),
    }
}
