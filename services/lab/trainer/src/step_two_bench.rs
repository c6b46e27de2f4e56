//! The step-two benchmark: over many seeds, step one in simulation, then step two on a twin in one
//! process (`TwinWorld`, the vehicle mesh's algorithm), measured by the evaluation protocol against
//! the simulation policy and the twin's limit.
//!
//! Per seed: step one is the trainer's `sim_episodes` episodes in simulation, seeing through
//! `sim_eyes` (the main job's step one sees images: `--sim-eyes images` gives its simulation policy,
//! the same one its service mesh learns); step two is a learning session of `trials` learning trials
//! on the twin with the seed (its evaluations are the protocol's, on the seed's evaluation set: the
//! simulation policy before the first learning trial, then after every `evaluation.learning_trials`).
//! Besides, the policy after every learning trial is evaluated on the same set (a measurement only:
//! the session does not see it), which gives the trials needed to close half the gap; the twin's
//! limit is evaluated on the same set; and the simulation policy, the final one and the limit are
//! evaluated on `held_out` other sets (other starts, floors and noise: what the vehicle will meet),
//! with the cables they lose there; the spread of `after - sim` over those sets is the evaluation's
//! noise.
//!
//! **The limit is a limit**: each DOF's limit is its return under its own pair (the bench's limit
//! is a pair per DOF: [`twin_limit`]). Every policy a seed evaluated (the simulation policy, each
//! evaluation of the session, each policy after a learning trial, the final one) is a candidate;
//! where one evaluates above a DOF's limit by more than twice the check's noise (the largest spread
//! over the held-out sets of a difference between the simulation policy, the final one and the
//! DOF's bench limit pair, of those that kept the cable there: [`twin_limit::check_noise`]), that
//! DOF's search goes on from it ([`twin_limit::find_in`], on the seed's own search set) and the
//! seed's row reports that limit if less beaten; where no round found the policy's return, the
//! policy's own gains are the row's limit. A row's limit still beaten then is marked in the table.
//!
//! **Shards**: a seed's row depends on its seed alone (and the bench's limit, searched from a fixed
//! seed), so seeds run in any order, on any thread or machine: `--shard K/N` runs every N-th seed
//! from the K-th ([`Shard`]) and [`merge`] puts the shards' files together into the file (and
//! table) the unsplit run gives.

use crate::Perceiver;
use crate::evaluation::{Evaluation, evaluate, gap_closed, policy_checkpoint};
use crate::experiment::parallel_map_on;
use crate::progress::Progress;
use crate::twin_limit::{self, Beaten, Candidate, Check, LimitGains, Round, SearchParams};
use crate::twin_world::{FromCheckpointError, Mode, TrialResult, TwinWorld};
use crate::world::World;
use config::{Dof, Eyes, LearningParams, PerDof, Scenario, TwinParams, derive_seed};
use learning::{Algorithm, Checkpoint};
use serde::{Deserialize, Deserializer, Serialize};
use std::path::PathBuf;

/// What the benchmark runs.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BenchParams {
    pub seeds: Vec<u64>,
    /// Learning trials of step two.
    pub trials: u32,
    /// Episodes of step one.
    pub sim_episodes: usize,
    /// How step two's behaviours see the cable on the twin (and the limit's search).
    pub eyes: Eyes,
    /// How step one's behaviours see it in simulation.
    pub sim_eyes: Eyes,
    /// Independent evaluation sets for the noise and the held-out returns (0: none).
    pub held_out: u32,
    /// Evaluate the policy after every learning trial (for the trials to half the gap).
    pub every_trial: bool,
    /// The limit's search (its `eyes` are the bench's): the bench's limit is searched with it from
    /// the LQR gains, and a seed's search goes on with it from its own search set.
    pub limit_search: SearchParams,
    /// Rounds of a limit search at most.
    pub limit_rounds: usize,
    /// The bench's limit is searched as `trainer twin-limit --seed limit_seed` searches it (its
    /// search set's seed derived from it, checked on its evaluation set).
    pub limit_seed: u64,
}

impl BenchParams {
    /// The search of seed `seed`'s limit, where its policies beat the bench's.
    pub fn seed_search(&self, seed: u64) -> SearchParams {
        SearchParams {
            seed: derive_seed(seed, "twin-limit/search"),
            eyes: self.eyes,
            ..self.limit_search.clone()
        }
    }
}

/// One point of an evaluation curve: the policy after `learning_trials` learning trials.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CurvePoint {
    pub learning_trials: u32,
    /// The policy evaluated.
    pub gains: PerDof<[f64; 2]>,
    /// Its evaluated return, and the trials of the evaluation that lost the cable.
    pub evaluated: PerDof<f64>,
    pub lost: u32,
    /// The evaluated return of the policy in force after the evaluation (the best one where it was
    /// restored), and where it was.
    pub in_force: PerDof<f64>,
    pub rolled_back: PerDof<bool>,
    /// The pair's score both behaviours judged the evaluation on (-2 for the session's first,
    /// higher is better; `learning::pair_score`); none for an evaluation the session did not judge.
    #[serde(default)]
    pub pair_score: Option<f64>,
}

/// Cables lost on the held-out sets, per policy.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct HeldOutLost {
    pub sim: u32,
    pub after: u32,
    pub limit: u32,
}

/// One seed's step two.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SeedResult {
    pub seed: u64,
    pub sim_gains: PerDof<[f64; 2]>,
    pub after_gains: PerDof<[f64; 2]>,
    /// The session's own evaluations (the protocol), before learning and after every few trials.
    pub curve: Vec<CurvePoint>,
    /// The policy after every learning trial, evaluated on the same set (a measurement).
    pub every_trial: Vec<CurvePoint>,
    pub sim: PerDof<f64>,
    pub after: PerDof<f64>,
    /// Each DOF's limit: its return under its own pair.
    pub limit: PerDof<f64>,
    /// The row's limit, each DOF's pair: the bench's, or where a policy of the seed beat it in the
    /// DOF, the one its search found going on from there if less beaten than the bench's, or that
    /// policy's own gains (`limit_candidate`) where no round found its return (`limit_rounds`: the
    /// searches' rounds, each naming its DOF; none when the bench's held).
    pub limit_gains: LimitGains,
    pub limit_rounds: Vec<Round>,
    /// The bench's limit evaluated on the seed's set (the row's `limit` where its search did not go
    /// on).
    pub bench_limit: PerDof<f64>,
    /// A policy of the seed still above the row's limit beyond the noise, per DOF.
    pub limit_beaten: PerDof<Option<Beaten>>,
    /// Per DOF, the policy of the seed whose own gains are the row's limit, where no round of the
    /// search found its return ([`twin_limit::DofLimit::candidate`]).
    #[serde(default)]
    pub limit_candidate: PerDof<Option<String>>,
    /// The noise the limit's check allowed ([`twin_limit::check_noise`] of the simulation policy,
    /// step two's and the DOF's bench limit pair on the held-out sets; NaN without them).
    #[serde(default = "unmeasured", deserialize_with = "nan_per_dof")]
    pub check_noise: PerDof<f64>,
    #[serde(deserialize_with = "nan_per_dof")]
    pub gap_closed: PerDof<f64>,
    /// The first learning trial after which the policy closed half the gap.
    pub trials_to_half: PerDof<Option<u32>>,
    /// Trials (learning and evaluation) of the session, and those that lost the cable.
    pub session_trials: u32,
    pub lost: u32,
    pub rollbacks: PerDof<u64>,
    pub refused: PerDof<u64>,
    pub bounded: PerDof<u64>,
    /// On the held-out sets: the simulation policy's, the final policy's and the row's limit's
    /// evaluated returns (each DOF's under its own pair), and the cables they lost there (of
    /// `held_out_trials` trials each; the limit's: both pairs').
    pub held_out_sim: PerDof<Vec<f64>>,
    pub held_out_after: PerDof<Vec<f64>>,
    pub held_out_limit: PerDof<Vec<f64>>,
    pub held_out_lost: HeldOutLost,
    pub held_out_trials: u32,
}

fn unmeasured() -> PerDof<f64> {
    PerDof::both(f64::NAN)
}

/// A `PerDof<f64>` whose values may have been written as `null` (JSON has no NaN).
fn nan_per_dof<'de, D: Deserializer<'de>>(d: D) -> Result<PerDof<f64>, D::Error> {
    let v = PerDof::<Option<f64>>::deserialize(d)?;
    Ok(PerDof {
        sway: v.sway.unwrap_or(f64::NAN),
        yaw: v.yaw.unwrap_or(f64::NAN),
    })
}

impl SeedResult {
    /// The spread of `after - sim` over the held-out sets: the evaluation's noise on the
    /// improvement.
    pub fn difference_noise(&self, dof: Dof) -> f64 {
        *twin_limit::difference_noise(&[&self.held_out_sim, &self.held_out_after]).get(dof)
    }

    /// The noise on the mean improvement over the held-out sets: [`Self::difference_noise`] over
    /// the root of their number (the mean's standard error).
    pub fn held_out_standard_error(&self, dof: Dof) -> f64 {
        let sets = self.held_out_sim.get(dof).len() as f64;
        self.difference_noise(dof) / sets.sqrt()
    }

    /// The mean improvement `after - sim` over the held-out sets (none without them).
    pub fn held_out_improvement(&self, dof: Dof) -> Option<f64> {
        let (after, sim) = (self.held_out_after.get(dof), self.held_out_sim.get(dof));
        (!after.is_empty()).then(|| stats::mean(after.iter().zip(sim).map(|(a, s)| a - s)))
    }

    /// The gap closed on the held-out sets: their mean returns' `(after - sim) / (limit - sim)`.
    pub fn held_out_gap_closed(&self, dof: Dof) -> f64 {
        let m = |v: &PerDof<Vec<f64>>| stats::mean(v.get(dof).iter().copied());
        gap_closed(
            m(&self.held_out_sim),
            m(&self.held_out_after),
            m(&self.held_out_limit),
        )
    }

    /// The session's evaluation whose pair is the final one (the last evaluation's, or the one it
    /// restored), with the row's J_after its returns.
    pub fn final_pair(&self) -> Option<&CurvePoint> {
        final_pair(&self.curve, self.after_gains, self.after)
    }

    /// Whether the row's search for `dof`'s limit went on from a policy of the seed.
    pub fn limit_searched_on(&self, dof: Dof) -> bool {
        self.limit_rounds.iter().any(|r| r.found.dof == dof)
    }

    /// Whether the row's limit is below a policy it evaluated beyond the noise.
    pub fn limit_is_beaten(&self) -> bool {
        self.limit_beaten.sway.is_some() || self.limit_beaten.yaw.is_some()
    }
}

/// Step one: the trainer's episodes seeing through `eyes`, as the checkpoint step two loads (with
/// images, the checkpoint the service mesh's step one writes for the same seed).
pub fn step_one(
    scenario: &Scenario,
    learning: &LearningParams,
    episodes: usize,
    eyes: Eyes,
    seed: u64,
) -> Result<Checkpoint, FromCheckpointError> {
    let perceiver = Perceiver::for_run(scenario, eyes, seed)?;
    let mut world = World::new(scenario, learning, Algorithm::Nac, perceiver, seed);
    for _ in 0..episodes {
        world.run_episode();
    }
    let agents = world.into_agents();
    let mut c = Checkpoint::single(agents.sway.checkpoint());
    c.insert(agents.yaw.checkpoint());
    Ok(c)
}

/// The gains of a checkpoint's policies.
pub fn gains(c: &Checkpoint) -> PerDof<[f64; 2]> {
    let g = |dof| c.get(dof).map_or([f64::NAN; 2], |s| s.policy.gain);
    PerDof::from_fn(g)
}

/// A session's learning and evaluation trials (started from the policy `initial`): the curve of
/// its evaluations.
pub fn curve(trials: &[TrialResult], initial: PerDof<[f64; 2]>) -> Vec<CurvePoint> {
    let mut learned = 0;
    let mut points = Vec::new();
    let mut evaluated_policy = initial;
    let mut lost = 0;
    for (i, t) in trials.iter().enumerate() {
        if !t.evaluation {
            learned += 1;
        } else if i == 0 || !trials[i - 1].evaluation {
            // An evaluation begins: it judges the policy the trials before it left.
            evaluated_policy = if i == 0 { initial } else { trials[i - 1].gains };
            lost = 0;
        }
        if t.evaluation && t.lost {
            lost += 1;
        }
        if t.evaluated.sway.is_finite() || t.evaluated.yaw.is_finite() {
            points.push(CurvePoint {
                learning_trials: learned,
                gains: evaluated_policy,
                evaluated: t.evaluated,
                lost,
                in_force: t.in_force(),
                rolled_back: t.rolled_back,
                pair_score: t.pair_score.is_finite().then_some(t.pair_score),
            });
        }
    }
    points
}

/// The evaluation of `curve` whose pair is the final one, `after_gains` with the returns `after`:
/// the last one, or the one it restored.
fn final_pair(
    curve: &[CurvePoint],
    after_gains: PerDof<[f64; 2]>,
    after: PerDof<f64>,
) -> Option<&CurvePoint> {
    curve.iter().rev().find(|p| {
        p.gains == after_gains
            && Dof::ALL
                .iter()
                .all(|&d| p.evaluated.get(d).to_bits() == after.get(d).to_bits())
    })
}

/// The policies a seed's row evaluated on its set, as candidates the limit must not be below: the
/// simulation policy, each evaluation of the session, each policy after a learning trial, and the
/// final one (with its in-force return, the row's `J_after`).
pub fn candidates(
    curve: &[CurvePoint],
    every_trial: &[CurvePoint],
    after_gains: PerDof<[f64; 2]>,
    after: PerDof<f64>,
) -> Vec<Candidate> {
    let mut c = Vec::new();
    for p in curve {
        let name = if p.learning_trials == 0 {
            "the simulation policy".to_owned()
        } else {
            format!("the evaluation after {} learning trials", p.learning_trials)
        };
        c.push(Candidate {
            name,
            gains: p.gains,
            evaluated: p.evaluated,
            lost: p.lost,
        });
    }
    for p in every_trial {
        c.push(Candidate {
            name: format!("the policy after learning trial {}", p.learning_trials),
            gains: p.gains,
            evaluated: p.evaluated,
            lost: p.lost,
        });
    }
    // The final policy's return in force and its lost trials: those of the evaluation that
    // evaluated it (the last one, or the one it restored: the best, or the simulation policies).
    let lost = final_pair(curve, after_gains, after).map_or(0, |p| p.lost);
    c.push(Candidate {
        name: "step two's final policy".to_owned(),
        gains: after_gains,
        evaluated: after,
        lost,
    });
    c
}

/// Runs one seed (see the module docs); `limit` is the bench's limit (each DOF's pair).
pub fn run_seed(
    scenario: &Scenario,
    learning: &LearningParams,
    twin: &TwinParams,
    limit: &LimitGains,
    params: &BenchParams,
    seed: u64,
) -> Result<SeedResult, FromCheckpointError> {
    let sim = step_one(
        scenario,
        learning,
        params.sim_episodes,
        params.sim_eyes,
        seed,
    )?;
    let e = learning.evaluation.trials;
    let session = behaviour::session_trials(&learning.evaluation, params.trials);
    let mut world =
        TwinWorld::from_checkpoint(scenario, twin, &sim, params.eyes, seed, Mode::Learn)?;
    let mut run = Vec::new();
    let mut every_trial = Vec::new();
    let mut learned = 0;
    for _ in 0..session {
        let r = world.run_trial();
        if !r.evaluation {
            learned += 1;
            if params.every_trial {
                let c = policy_checkpoint(scenario, learning, r.gains);
                let ev = evaluate(scenario, twin, params.eyes, &c, seed, e)?;
                every_trial.push(CurvePoint {
                    learning_trials: learned,
                    gains: r.gains,
                    evaluated: ev.mean(),
                    lost: ev.lost,
                    in_force: ev.mean(),
                    rolled_back: PerDof::default(),
                    pair_score: None,
                });
            }
        }
        run.push(r);
    }
    let sim_gains = gains(&sim);
    let curve = curve(&run, sim_gains);
    let first = curve.first().map(|p| p.in_force);
    let last = curve.last().map(|p| p.in_force);
    let (Some(j_sim), Some(j_after)) = (first, last) else {
        panic!("a session of {session} trials evaluates at least twice (evaluation.trials = {e})");
    };
    let final_gains = run.last().expect("one trial at least").gains;
    let after_checkpoint = policy_checkpoint(scenario, learning, final_gains);

    // The held-out sets: the simulation policy and the final one (the noise on their difference).
    let sets: Vec<u64> = (0..params.held_out)
        .map(|h| derive_seed(seed, &format!("held-out/{h}")))
        .collect();
    let on_sets = |c: &Checkpoint| -> Result<Vec<Evaluation>, FromCheckpointError> {
        sets.iter()
            .map(|&set| evaluate(scenario, twin, params.eyes, c, set, e))
            .collect()
    };
    let (held_sim, held_after) = (on_sets(&sim)?, on_sets(&after_checkpoint)?);
    let means = |evals: &[Evaluation]| PerDof {
        sway: evals.iter().map(|v| v.mean().sway).collect::<Vec<_>>(),
        yaw: evals.iter().map(|v| v.mean().yaw).collect::<Vec<_>>(),
    };
    let lost = |evals: &[Evaluation]| -> u32 { evals.iter().map(|v| v.lost).sum() };
    // The bench's limit: each DOF's pair, on the held-out sets and on the seed's set.
    let bench_pairs = limit.map(|_, g| policy_checkpoint(scenario, learning, *g));
    let held_bench_limit = PerDof {
        sway: on_sets(&bench_pairs.sway)?,
        yaw: on_sets(&bench_pairs.yaw)?,
    };
    let (held_sim_j, held_after_j) = (means(&held_sim), means(&held_after));
    // Each DOF's check compares its own pair with the seed's policies: the noise of that DOF from
    // them (the other DOF's pair, far from them in this DOF, would only widen it).
    let noise = PerDof::from_fn(|dof| {
        let pair = held_bench_limit.get(dof);
        *twin_limit::check_noise(&[
            (&held_sim_j, lost(&held_sim)),
            (&held_after_j, lost(&held_after)),
            (&means(pair), lost(pair)),
        ])
        .get(dof)
    });
    let bench_limit = PerDof {
        sway: evaluate(scenario, twin, params.eyes, &bench_pairs.sway, seed, e)?,
        yaw: evaluate(scenario, twin, params.eyes, &bench_pairs.yaw, seed, e)?,
    };
    let bench_j = bench_limit.map(|dof, v| *v.mean().get(dof));

    // Each DOF's limit: the bench's, unless a policy of this row beats it beyond the noise.
    let candidates = candidates(&curve, &every_trial, final_gains, j_after);
    let mut limit_gains = *limit;
    let mut j_limit = bench_j;
    let mut limit_rounds = Vec::new();
    let mut limit_beaten = PerDof::default();
    let mut limit_candidate = PerDof::default();
    let mut held_limit = PerDof::default();
    for dof in Dof::ALL {
        let bench_pair = bench_limit.get(dof);
        let beaten = twin_limit::beaten_in(
            dof,
            *bench_j.get(dof),
            bench_pair.lost,
            &candidates,
            *noise.get(dof),
        );
        *limit_beaten.get_mut(dof) = beaten.clone();
        *held_limit.get_mut(dof) = held_bench_limit.get(dof).clone();
        if beaten.is_none() {
            continue;
        }
        let found = twin_limit::find_in(
            scenario,
            learning,
            twin,
            dof,
            *limit.get(dof),
            &candidates,
            &params.seed_search(seed),
            &Check {
                seed,
                trials: e,
                noise,
            },
            params.limit_rounds,
            &Progress::hidden(),
        )?;
        limit_rounds.extend(found.rounds.iter().cloned());
        let j = *found.evaluation.mean().get(dof);
        // The search's every round can end further below a candidate than the bench's limit was
        // (a larger search set need not evaluate higher here): the less beaten stays.
        if twin_limit::shortfall(j, found.beaten.as_ref())
            < twin_limit::shortfall(*bench_j.get(dof), beaten.as_ref())
        {
            *limit_gains.get_mut(dof) = found.gains;
            *j_limit.get_mut(dof) = j;
            *limit_beaten.get_mut(dof) = found.beaten;
            *limit_candidate.get_mut(dof) = found.candidate;
            *held_limit.get_mut(dof) =
                on_sets(&policy_checkpoint(scenario, learning, found.gains))?;
        }
    }

    let closed = |dof: Dof| gap_closed(*j_sim.get(dof), *j_after.get(dof), *j_limit.get(dof));
    let to_half = |dof: Dof| {
        let half = |p: &CurvePoint| {
            gap_closed(*j_sim.get(dof), *p.in_force.get(dof), *j_limit.get(dof)) >= 0.5
        };
        let points = if every_trial.is_empty() {
            &curve
        } else {
            &every_trial
        };
        points.iter().find(|p| half(p)).map(|p| p.learning_trials)
    };
    let last_trial = run.last().expect("one trial at least");
    let trials_to_half = PerDof::from_fn(to_half);
    Ok(SeedResult {
        seed,
        sim_gains,
        after_gains: final_gains,
        curve,
        every_trial,
        sim: j_sim,
        after: j_after,
        limit: j_limit,
        limit_gains,
        limit_rounds,
        bench_limit: bench_j,
        limit_beaten,
        limit_candidate,
        check_noise: noise,
        gap_closed: PerDof::from_fn(closed),
        trials_to_half,
        session_trials: session,
        lost: run.iter().filter(|t| t.lost).count() as u32,
        rollbacks: last_trial.rollbacks,
        refused: last_trial.refused,
        bounded: last_trial.bounded,
        held_out_sim: held_sim_j,
        held_out_after: held_after_j,
        held_out_limit: PerDof::from_fn(|dof| means(held_limit.get(dof)).get(dof).clone()),
        held_out_lost: HeldOutLost {
            sim: lost(&held_sim),
            after: lost(&held_after),
            limit: lost(&held_limit.sway) + lost(&held_limit.yaw),
        },
        held_out_trials: params.held_out * e,
    })
}

/// Runs `seeds` (of `params.seeds`, or all), one seed a task on `threads` threads (0: one per
/// core); the rows come in the order of `seeds`, and a row does not depend on the threads.
#[allow(clippy::too_many_arguments)]
pub fn run(
    scenario: &Scenario,
    learning: &LearningParams,
    twin: &TwinParams,
    limit: &LimitGains,
    params: &BenchParams,
    seeds: &[u64],
    threads: usize,
    progress: &Progress,
) -> Result<Vec<SeedResult>, FromCheckpointError> {
    parallel_map_on(threads, seeds.len(), progress, |i| {
        run_seed(scenario, learning, twin, limit, params, seeds[i])
    })
    .into_iter()
    .collect()
}

/// An evaluation, for the JSON of a command.
pub fn evaluation_json(e: &Evaluation) -> serde_json::Value {
    serde_json::json!({
        "seed": e.seed,
        "trials": e.trials,
        "returns": e.returns,
        "mean": e.mean(),
        "lost": e.lost,
    })
}

/// The benchmark's verdict over the seeds, per DOF.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DofSummary {
    /// The gap (J_limit - J_sim) relative to |J_sim|: median over seeds.
    pub median_gap: f64,
    pub median_gap_closed: f64,
    pub min_gap_closed: f64,
    /// The median over seeds of the trials to close half the gap (a seed that never did counts as
    /// more than the session's trials; `None` when half the seeds never did).
    pub median_trials_to_half: Option<f64>,
    /// Seeds whose final policy is worse than the simulation policy on their evaluation set (keeping
    /// the best pair never leaves the pair worse there, but one DOF can be where the other's gain
    /// outweighs its loss), and those whose mean improvement on the held-out sets is below
    /// minus twice their own noise on the difference (on the evaluation set without held-out sets).
    pub seeds_worse: usize,
    pub seeds_worse_beyond_noise: usize,
    /// The evaluation's noise on a difference (the median over seeds of the spread of
    /// `after - sim` over the held-out sets).
    pub difference_noise: f64,
    /// The mean improvement `after - sim` on the held-out sets, median over seeds.
    pub median_held_out_improvement: f64,
    /// The gap closed on the held-out sets (their mean returns), median over seeds.
    pub median_held_out_gap_closed: f64,
    /// Seeds whose policies beat the bench's limit beyond the noise (their search went on), those
    /// whose limit is then a policy of theirs, and those whose limit a policy of theirs still
    /// beats beyond it.
    pub limits_searched_on: usize,
    #[serde(default)]
    pub limits_from_candidates: usize,
    pub limits_beaten: usize,
}

/// The benchmark's verdict.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    pub seeds: usize,
    pub yaw: DofSummary,
    pub sway: DofSummary,
    /// Trials (learning and evaluation) that lost the cable, over all seeds.
    pub lost: u32,
    pub trials: u32,
    /// Cables lost on the held-out sets over all seeds, per policy, of `held_out_trials` each (the
    /// limit's: its two pairs', of twice as many).
    pub held_out_lost: HeldOutLost,
    pub held_out_trials: u32,
}

fn dof_summary(results: &[SeedResult], dof: Dof, learning_trials: u32) -> DofSummary {
    let closed: Vec<f64> = results.iter().map(|r| *r.gap_closed.get(dof)).collect();
    let noise = stats::median(results.iter().map(|r| r.difference_noise(dof)));
    let worse = |r: &SeedResult, margin: f64| {
        *r.after.get(dof) < *r.sim.get(dof) - if margin.is_finite() { margin } else { 0.0 }
    };
    // The evaluation set cannot show a seed worse beyond noise: keeping the best judged the final
    // pair on it. Other starts and noise can: their mean improvement below twice its standard
    // error (twice the spread itself would pass a seed worse on every set by a varying amount).
    let worse_held_out = |r: &SeedResult| match r.held_out_improvement(dof) {
        Some(improvement) => improvement < -2.0 * r.held_out_standard_error(dof),
        None => worse(r, 2.0 * r.difference_noise(dof)),
    };
    let halves: Vec<f64> = results
        .iter()
        .map(|r| {
            r.trials_to_half
                .get(dof)
                .map_or(f64::INFINITY, |t| t as f64)
        })
        .collect();
    let median_half = stats::median(halves.iter().copied());
    DofSummary {
        median_gap: stats::median(
            results
                .iter()
                .map(|r| (*r.limit.get(dof) - *r.sim.get(dof)) / r.sim.get(dof).abs()),
        ),
        median_gap_closed: stats::median(closed.iter().copied()),
        min_gap_closed: closed.iter().copied().fold(f64::INFINITY, f64::min),
        median_trials_to_half: (median_half <= learning_trials as f64).then_some(median_half),
        seeds_worse: results.iter().filter(|r| worse(r, 0.0)).count(),
        seeds_worse_beyond_noise: results.iter().filter(|r| worse_held_out(r)).count(),
        difference_noise: noise,
        median_held_out_improvement: stats::median(
            results
                .iter()
                .map(|r| r.held_out_improvement(dof).unwrap_or(f64::NAN)),
        ),
        median_held_out_gap_closed: stats::median(
            results.iter().map(|r| r.held_out_gap_closed(dof)),
        ),
        limits_searched_on: results.iter().filter(|r| r.limit_searched_on(dof)).count(),
        limits_from_candidates: results
            .iter()
            .filter(|r| r.limit_candidate.get(dof).is_some())
            .count(),
        limits_beaten: results
            .iter()
            .filter(|r| r.limit_beaten.get(dof).is_some())
            .count(),
    }
}

/// The verdict over `results`.
pub fn summary(results: &[SeedResult]) -> Summary {
    let learning_trials = results
        .first()
        .and_then(|r| r.curve.last())
        .map_or(0, |p| p.learning_trials);
    let held = |f: fn(&HeldOutLost) -> u32| results.iter().map(|r| f(&r.held_out_lost)).sum();
    Summary {
        seeds: results.len(),
        yaw: dof_summary(results, Dof::Yaw, learning_trials),
        sway: dof_summary(results, Dof::Sway, learning_trials),
        lost: results.iter().map(|r| r.lost).sum(),
        trials: results.iter().map(|r| r.session_trials).sum(),
        held_out_lost: HeldOutLost {
            sim: held(|l| l.sim),
            after: held(|l| l.after),
            limit: held(|l| l.limit),
        },
        held_out_trials: results.iter().map(|r| r.held_out_trials).sum(),
    }
}

/// The benchmark's table (Markdown) and its verdict.
pub fn table(results: &[SeedResult], params: &BenchParams) -> String {
    use std::fmt::Write as _;
    let mut t = String::new();
    let pct = |v: f64| format!("{:.0}%", 100.0 * v);
    let half = |v: Option<u32>| v.map_or("–".to_owned(), |v| v.to_string());
    // A row's limit: † where its search went on from a policy of the seed, § where that policy's
    // own gains are the limit, ‡ where one still beats it beyond the noise.
    let mark = |r: &SeedResult, dof: Dof| {
        if r.limit_beaten.get(dof).is_some() {
            "‡"
        } else if r.limit_candidate.get(dof).is_some() {
            "§"
        } else if r.limit_searched_on(dof) {
            "†"
        } else {
            ""
        }
    };
    let _ = writeln!(
        t,
        "| seed | yaw: sim | after | limit | closed | sway: sim | after | limit | closed | final pair: evaluated after, score | half (yaw, sway) | rollbacks | refused | lost | held out: lost (sim, after; the limit's two pairs) |"
    );
    let _ = writeln!(
        t,
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
    );
    for r in results {
        // Where the final pair was evaluated together (learning trials before), and its score.
        let pair = r.final_pair().map_or("none".to_owned(), |p| {
            let score = p.pair_score.map_or("–".to_owned(), |s| format!("{s:.3}"));
            format!("{}, {score}", p.learning_trials)
        });
        let _ = writeln!(
            t,
            "| {} | {:.3} | {:.3} | {:.3}{} | {} | {:.4} | {:.4} | {:.4}{} | {} | {pair} | {}, {} | {}, {} | {}, {} | {} | {}, {} of {}; {} of {} |",
            r.seed,
            r.sim.yaw,
            r.after.yaw,
            r.limit.yaw,
            mark(r, Dof::Yaw),
            pct(r.gap_closed.yaw),
            r.sim.sway,
            r.after.sway,
            r.limit.sway,
            mark(r, Dof::Sway),
            pct(r.gap_closed.sway),
            half(r.trials_to_half.yaw),
            half(r.trials_to_half.sway),
            r.rollbacks.yaw,
            r.rollbacks.sway,
            r.refused.yaw,
            r.refused.sway,
            r.lost,
            r.held_out_lost.sim,
            r.held_out_lost.after,
            r.held_out_trials,
            r.held_out_lost.limit,
            2 * r.held_out_trials,
        );
    }
    let s = summary(results);
    let _ = writeln!(
        t,
        "\n{} seeds, {} learning trials each ({} trials a session with the evaluations), step one with {} perception, step two with {}:",
        s.seeds,
        params.trials,
        results.first().map_or(0, |r| r.session_trials),
        params.sim_eyes,
        params.eyes
    );
    for (dof, d) in [(Dof::Yaw, &s.yaw), (Dof::Sway, &s.sway)] {
        let _ = writeln!(
            t,
            "{dof:>4}: gap (J_limit - J_sim)/|J_sim| median {}; gap closed median {}, worst {}; trials to half the gap median {}; \
             worse than the simulation policy on its set: {} seeds; on the held-out sets beyond twice the standard error of the seed's mean (its noise, median {:.4}, over the root of the sets): {}; held-out improvement median {:+.4}, \
             held-out gap closed median {}; the limit's search went on in {} seeds (†, § or ‡), of which the limit is a policy of the seed's in {} (§) and still beaten beyond the noise in {} (‡)",
            pct(d.median_gap),
            pct(d.median_gap_closed),
            pct(d.min_gap_closed),
            d.median_trials_to_half
                .map_or("> the session".to_owned(), |v| format!("{v}")),
            d.seeds_worse,
            d.difference_noise,
            d.seeds_worse_beyond_noise,
            d.median_held_out_improvement,
            pct(d.median_held_out_gap_closed),
            d.limits_searched_on,
            d.limits_from_candidates,
            d.limits_beaten,
        );
    }
    let _ = writeln!(
        t,
        "cable lost in {} of {} trials; on the held-out sets, of {} trials each: the simulation policy {}, step two's {}, the limit's two pairs {} (of twice as many)",
        s.lost,
        s.trials,
        s.held_out_trials,
        s.held_out_lost.sim,
        s.held_out_lost.after,
        s.held_out_lost.limit
    );
    t
}

/// A part of a benchmark's seeds: every `n`-th seed of the list from the `k`-th (`k` from 1), so
/// that shards of a list in seed order take alike.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Shard {
    pub k: usize,
    pub n: usize,
}

impl Shard {
    /// The seeds of `all` this shard runs.
    pub fn seeds(&self, all: &[u64]) -> Vec<u64> {
        all.iter()
            .enumerate()
            .filter(|(i, _)| i % self.n == self.k - 1)
            .map(|(_, s)| *s)
            .collect()
    }
}

impl std::str::FromStr for Shard {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        let bad = || format!("`{text}` is not a shard K/N with 1 <= K <= N (e.g. 2/4)");
        let (k, n) = text.split_once('/').ok_or_else(bad)?;
        let (k, n): (usize, usize) = (
            k.trim().parse().map_err(|_| bad())?,
            n.trim().parse().map_err(|_| bad())?,
        );
        if k == 0 || k > n {
            return Err(bad());
        }
        Ok(Shard { k, n })
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.k, self.n)
    }
}

/// How long a run took: its wall time, and on how many threads (a merged file: the sum of its
/// shards' wall times, and each shard's).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Timing {
    pub wall_s: f64,
    pub threads: usize,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub shards_wall_s: Vec<f64>,
}

/// The benchmark's JSON file: what ran, on what, the rows and the verdict. A shard's holds its own
/// rows and the whole run's parameters.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BenchFile {
    /// The twin's file as given, and what it held.
    pub twin: PathBuf,
    pub twin_params: TwinParams,
    pub scenario: Scenario,
    pub learning: LearningParams,
    pub params: BenchParams,
    /// The bench's limit, each DOF's pair (every row's, unless the row's search went on).
    pub limit: LimitGains,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shard: Option<Shard>,
    /// Recomputed from the rows when a file is read.
    #[serde(skip_deserializing)]
    pub summary: Summary,
    pub seeds: Vec<SeedResult>,
    pub timing: Timing,
}

impl BenchFile {
    /// The table of the file's rows.
    pub fn table(&self) -> String {
        table(&self.seeds, &self.params)
    }

    /// The file as JSON, without its timing (two runs of the same work compare equal by it).
    pub fn without_timing(&self) -> serde_json::Value {
        let mut v = serde_json::to_value(self).expect("a bench file serialises");
        if let Some(o) = v.as_object_mut() {
            o.remove("timing");
        }
        v
    }
}

/// Why shards do not merge.
#[derive(Debug, thiserror::Error)]
pub enum MergeError {
    #[error("no shard to merge")]
    Empty,
    #[error("{0}: not a shard (it ran every seed: nothing to merge it with)")]
    NotAShard(String),
    #[error("{file}: shard {shard}, but the first file is a shard of {n}")]
    OtherSplit {
        file: String,
        shard: Shard,
        n: usize,
    },
    #[error("{file}: shard {shard} again (also in {first})")]
    Twice {
        file: String,
        first: String,
        shard: Shard,
    },
    #[error("shard {0} is missing")]
    Missing(Shard),
    #[error(
        "{file}: its {what} differ from the first file's: shards of one run must run the same benchmark"
    )]
    Differs { file: String, what: &'static str },
    #[error("{file}: seed {seed} is not one of its shard's seeds")]
    StraySeed { file: String, seed: u64 },
    #[error("{file}: seed {seed} of its shard has no row")]
    MissingSeed { file: String, seed: u64 },
}

/// Merges the files of shards `1/N` to `N/N` of one run (named, for errors) into the file the
/// unsplit run writes: its rows in the run's seed order, its verdict over all of them.
pub fn merge(files: &[(String, BenchFile)]) -> Result<BenchFile, MergeError> {
    let (first_name, first) = files.first().ok_or(MergeError::Empty)?;
    let n = first
        .shard
        .ok_or_else(|| MergeError::NotAShard(first_name.clone()))?
        .n;
    let mut by_shard: Vec<Option<&(String, BenchFile)>> = vec![None; n];
    for f in files {
        let (name, file) = f;
        let shard = file
            .shard
            .ok_or_else(|| MergeError::NotAShard(name.clone()))?;
        if shard.n != n {
            return Err(MergeError::OtherSplit {
                file: name.clone(),
                shard,
                n,
            });
        }
        if let Some((other, _)) = by_shard[shard.k - 1] {
            return Err(MergeError::Twice {
                file: name.clone(),
                first: other.clone(),
                shard,
            });
        }
        for (what, same) in [
            ("benchmark parameters", file.params == first.params),
            ("twin parameters", file.twin_params == first.twin_params),
            ("scenario", file.scenario == first.scenario),
            ("learning parameters", file.learning == first.learning),
            ("limits", file.limit == first.limit),
        ] {
            if !same {
                return Err(MergeError::Differs {
                    file: name.clone(),
                    what,
                });
            }
        }
        let want = shard.seeds(&file.params.seeds);
        if let Some(r) = file.seeds.iter().find(|r| !want.contains(&r.seed)) {
            return Err(MergeError::StraySeed {
                file: name.clone(),
                seed: r.seed,
            });
        }
        if let Some(seed) = want
            .iter()
            .find(|s| !file.seeds.iter().any(|r| r.seed == **s))
        {
            return Err(MergeError::MissingSeed {
                file: name.clone(),
                seed: *seed,
            });
        }
        by_shard[shard.k - 1] = Some(f);
    }
    if let Some(k) = by_shard.iter().position(Option::is_none) {
        return Err(MergeError::Missing(Shard { k: k + 1, n }));
    }
    let rows: Vec<SeedResult> = first
        .params
        .seeds
        .iter()
        .map(|seed| {
            files
                .iter()
                .flat_map(|(_, f)| &f.seeds)
                .find(|r| r.seed == *seed)
                .expect("every shard's seeds were checked")
                .clone()
        })
        .collect();
    let shards_wall_s: Vec<f64> = by_shard
        .iter()
        .flatten()
        .map(|(_, f)| f.timing.wall_s)
        .collect();
    Ok(BenchFile {
        shard: None,
        summary: summary(&rows),
        seeds: rows,
        timing: Timing {
            wall_s: shards_wall_s.iter().sum(),
            threads: by_shard
                .iter()
                .flatten()
                .map(|(_, f)| f.timing.threads)
                .max()
                .unwrap_or(0),
            shards_wall_s,
        },
        ..first.clone()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A seed whose session kept a yaw policy at `after` against the simulation policy's `sim` on
    /// its own set, and which differs from it by `held_out` on each held-out set.
    fn seed(seed: u64, sim: f64, after: f64, held_out: [f64; 4]) -> SeedResult {
        let both = |yaw| PerDof { sway: -1.0, yaw };
        let sets = |shift: f64| PerDof {
            sway: vec![-1.0; 4],
            yaw: held_out.iter().map(|d| -10.0 + shift * d).collect(),
        };
        SeedResult {
            seed,
            sim_gains: PerDof::default(),
            after_gains: PerDof::default(),
            curve: Vec::new(),
            every_trial: Vec::new(),
            sim: both(sim),
            after: both(after),
            limit: both(-5.0),
            limit_gains: PerDof::default(),
            limit_rounds: Vec::new(),
            bench_limit: both(-5.0),
            limit_beaten: PerDof::default(),
            limit_candidate: PerDof::default(),
            check_noise: PerDof::both(f64::NAN),
            gap_closed: both(gap_closed(sim, after, -5.0)),
            trials_to_half: PerDof::default(),
            session_trials: 45,
            lost: 0,
            rollbacks: PerDof::default(),
            refused: PerDof::default(),
            bounded: PerDof::default(),
            held_out_sim: sets(0.0),
            held_out_after: sets(1.0),
            held_out_limit: sets(0.0),
            held_out_lost: HeldOutLost::default(),
            held_out_trials: 20,
        }
    }

    /// A seed is worse beyond noise where the held-out sets say so (mean improvement below minus
    /// twice its standard error), and not where they scatter around zero.
    #[test]
    fn a_seed_is_worse_beyond_noise_where_the_held_out_sets_say_so() {
        let results = [
            // Better on its set, clearly worse on the others: -0.4 against a spread of 0.02.
            seed(1, -8.0, -7.0, [-0.38, -0.40, -0.42, -0.40]),
            // Better on its set and on the others.
            seed(2, -8.0, -7.0, [0.9, 1.0, 1.1, 1.0]),
            // Kept its simulation policy; the others scatter around zero (mean -0.05, spread 0.35).
            seed(3, -8.0, -8.0, [0.3, -0.4, 0.2, -0.3]),
            // Worse on every set, by a varying amount: mean -5.65, spread 4.3, standard error 2.2.
            seed(4, -31.0, -11.0, [-8.4, -9.9, -0.4, -3.9]),
        ];
        let s = summary(&results);
        assert_eq!(s.yaw.seeds_worse, 0, "on their own sets none is worse");
        assert_eq!(
            s.yaw.seeds_worse_beyond_noise, 2,
            "seeds 1 and 4 on the held-out sets"
        );
        assert_eq!(s.sway.seeds_worse_beyond_noise, 0);
        assert!((s.yaw.median_held_out_improvement - (-0.05 - 0.4) / 2.0).abs() < 1e-12);
    }
}
