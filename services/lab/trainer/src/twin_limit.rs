//! The twin's limit: for each DOF, the best return a linear policy can have on a given twin, found by
//! direct policy search on the twin itself (in one process). The DOFs interact through the
//! allocator, the current and the camera's mount, so a DOF's best return is searched over all four
//! gains, and each DOF has its own limit pair: where the DOFs pull apart (sway's best gains cost yaw)
//! no single pair is best in both, and a pair whose gains are each DOF's best answer to the other's
//! can sit below a pair of other gains in one DOF. The limit per DOF is above every pair by
//! construction: the gap a policy closes is always a share of a real gap (which no pair need close
//! in both DOFs at once).
//!
//! **The method**: per DOF, the cross-entropy method over the four gains, started at the LQR gains
//! of the identified model. Each generation samples a population of gain vectors from a Gaussian
//! (the current mean among them), evaluates every one by the evaluation protocol on one *search set*
//! ([`crate::evaluation`]: the same starts, the same frame and exploration noise for all, so the
//! candidates differ by their gains only), and refits the Gaussian to the quarter best for that DOF
//! (its own return).
//!
//! Why this method: the objective is a simulation with clipping, saturation and a cable that can be
//! lost (a cliff in the return), so it has no useful gradient and is not smooth; the cross-entropy
//! method needs neither, is robust to what noise remains, evaluates a whole population in parallel
//! on every core, and needs no step size (its spread shrinks as it converges). Nelder-Mead would
//! evaluate one point at a time and can stall on the return's kinks.
//!
//! The search set is not the evaluation set: the limit is reported on the evaluation set, so its
//! return is not flattered by the noise it was selected on.
//!
//! **A limit is a limit** ([`find`]): every policy evaluated beside it (the simulation policy, each
//! policy step two evaluated) is a *candidate*. The candidates join the search's first generation,
//! so the search starts from the best of them, and the search never ends below the best first
//! member on the search set. A DOF's limit found is then checked on the evaluation set against
//! every candidate: where one beats it by more than twice the evaluation's noise on a difference,
//! that DOF's search goes on from it (a new round: the beaters in its first generation, a fresh
//! search set twice the size, which tells policies apart that the last could not). The DOF's limit
//! is then the round's limit least beaten on the evaluation set (a larger search set need not
//! evaluate higher there). Still beaten, the candidate above that round's limit is itself a linear
//! policy evaluated on that set: its own gains are the limit ([`DofLimit::candidate`]) where that is
//! less beaten (a search can end on a pair that keeps the cable on its own set and loses it on the
//! evaluation set). Still beaten then, it says so ([`DofLimit::beaten`]): the report shows by what
//! and by how much. The noise the check allows is [`check_noise`]'s: how much a difference between
//! two policies of different gains moves over held-out sets.

use crate::evaluation::{Evaluation, evaluate, policy_checkpoint, spread};
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
    /// The mean's return on the search set, and the trials in which it lost the cable.
    pub mean_return: PerDof<f64>,
    pub mean_lost: u32,
}

/// What the search found: the pair of gains best for one DOF.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Found {
    /// The DOF whose return the search ranked by.
    pub dof: Dof,
    pub start: PerDof<[f64; 2]>,
    pub gains: PerDof<[f64; 2]>,
    /// The found gains' return on the search set, and the trials in which they lost the cable.
    pub search_return: PerDof<f64>,
    pub search_lost: u32,
    pub generations: Vec<Generation>,
    /// Policies evaluated.
    pub evaluations: usize,
}

/// The twin's limit's gains: per DOF, the pair best for it.
pub type LimitGains = PerDof<PerDof<[f64; 2]>>;

fn to_vec(g: &PerDof<[f64; 2]>) -> [f64; 4] {
    [g.sway[0], g.sway[1], g.yaw[0], g.yaw[1]]
}

fn to_gains(v: &[f64; 4]) -> PerDof<[f64; 2]> {
    PerDof {
        sway: [v[0], v[1]],
        yaw: [v[2], v[3]],
    }
}

/// A policy's returns on a set, and the trials in which it lost the cable.
type Scored = (PerDof<f64>, u32);

/// How good a policy is for one DOF on a set: a policy that lost the cable in fewer trials is
/// better, whatever its return (a lost cable is a failed policy, as step two's safety layer counts
/// it); among those that lost it alike, the higher return.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Score {
    lost: u32,
    ret: f64,
}

impl Score {
    fn of(result: &Scored, dof: Dof) -> Score {
        Score {
            lost: result.1,
            ret: *result.0.get(dof),
        }
    }

    fn cmp(&self, other: &Score) -> std::cmp::Ordering {
        other
            .lost
            .cmp(&self.lost)
            .then(self.ret.total_cmp(&other.ret))
    }

    fn beats(&self, other: &Score) -> bool {
        self.cmp(other) == std::cmp::Ordering::Greater
    }
}

/// Searches the pair of linear policies best for `dof` on `twin` from `start` (see the module
/// docs); `candidates` join the first generation.
#[allow(clippy::too_many_arguments)]
pub fn search(
    scenario: &Scenario,
    learning: &LearningParams,
    twin: &TwinParams,
    dof: Dof,
    start: PerDof<[f64; 2]>,
    candidates: &[PerDof<[f64; 2]>],
    params: &SearchParams,
    progress: &Progress,
) -> Result<Found, FromCheckpointError> {
    // The search set: `trials` distinct start marks.
    let mut search_twin = twin.clone();
    search_twin.trials.cycle = params.trials;
    let evaluate_gains = |v: &[f64; 4]| -> Result<Scored, FromCheckpointError> {
        let c = policy_checkpoint(scenario, learning, to_gains(v));
        let e = evaluate(
            scenario,
            &search_twin,
            params.eyes,
            &c,
            params.seed,
            params.trials,
        )?;
        Ok((e.mean(), e.lost))
    };
    let mut rng = StdRng::seed_from_u64(config::derive_seed(
        params.seed,
        &format!("twin-limit/sampling/{dof}"),
    ));
    let mut mean = to_vec(&start);
    let mut spread: [f64; 4] = std::array::from_fn(|i| 0.5 * mean[i].abs() + 1.0);
    let population = params.population.max(4);
    let elite = (population / 3).max(2);
    let mut generations = Vec::new();
    let mut evaluations = 0;
    let mut mean_score = None;
    // The best of the start and the candidates for the DOF (its gains and score), on the search set.
    let mut first_best: Option<([f64; 4], Scored)> = None;
    for g in 0..params.generations.max(1) {
        // The mean first; in the first generation the candidates next, then the samples.
        let given: Vec<[f64; 4]> = if g == 0 {
            candidates.iter().map(to_vec).collect()
        } else {
            Vec::new()
        };
        let members: Vec<[f64; 4]> = std::iter::once(mean)
            .chain(given)
            .chain((1..population).map(|_| {
                std::array::from_fn(|i| {
                    let n: f64 = StandardNormal.sample(&mut rng);
                    mean[i] + spread[i] * n
                })
            }))
            .collect();
        let results = parallel_map(members.len(), &Progress::hidden(), |k| {
            evaluate_gains(&members[k])
        });
        evaluations += members.len();
        let results = results.into_iter().collect::<Result<Vec<_>, _>>()?;
        if g == 0 {
            let given = 1 + candidates.len();
            for (m, r) in members[..given].iter().zip(&results) {
                if first_best
                    .is_none_or(|(_, best)| Score::of(r, dof).beats(&Score::of(&best, dof)))
                {
                    first_best = Some((*m, *r));
                }
            }
        }
        mean_score = Some(results[0]);
        generations.push(Generation {
            mean: to_gains(&mean),
            spread: to_gains(&spread),
            mean_return: results[0].0,
            mean_lost: results[0].1,
        });
        tracing::info!(
            %dof,
            generation = g + 1,
            sway = ?to_gains(&mean).sway,
            yaw = ?to_gains(&mean).yaw,
            sway_return = results[0].0.sway,
            yaw_return = results[0].0.yaw,
            lost = results[0].1,
            "twin limit: search"
        );
        progress.tick();
        if spread.iter().all(|s| *s < params.tolerance) {
            break;
        }
        let mut order: Vec<usize> = (0..members.len()).collect();
        // The best first: a policy that lost the cable ranks below every one that kept it (a trial
        // cut short by a lost cable costs less than 90 s of poor tracking).
        order.sort_by(|a, b| Score::of(&results[*b], dof).cmp(&Score::of(&results[*a], dof)));
        for i in 0..4 {
            let values: Vec<f64> = order[..elite].iter().map(|&k| members[k][i]).collect();
            let m = stats::mean(values.iter().copied());
            let sd = (stats::mean(values.iter().map(|v| (v - m).powi(2)))).sqrt();
            // Smoothed, so one lucky generation does not collapse the spread; and never below the
            // step the mean just took, so the search keeps its reach while it still travels (the
            // cross-entropy method's known failure is to shrink before it arrives).
            let step = (m - mean[i]).abs();
            spread[i] = 0.5 * spread[i] + 0.5 * sd.max(step).max(0.5 * params.tolerance);
            mean[i] = m;
        }
    }
    // The last generation's mean; evaluated once more if it moved after its last evaluation.
    let last = generations.last().expect("one generation at least");
    let mut search_score = if to_vec(&last.mean) == mean {
        mean_score.expect("evaluated")
    } else {
        evaluations += 1;
        evaluate_gains(&mean)?
    };
    // Never worse than where it began: a search that ended below the best of the start and the
    // candidates on the search set (a population that drifted into losing the cable) keeps that
    // policy's gains.
    if let Some((gains, best)) = first_best
        && Score::of(&best, dof).beats(&Score::of(&search_score, dof))
    {
        tracing::warn!(
            %dof,
            start_or_candidate = best.0.get(dof),
            start_or_candidate_lost = best.1,
            found = search_score.0.get(dof),
            found_lost = search_score.1,
            "twin limit: the search ended worse than its start or a candidate; that policy's gains are kept"
        );
        // The same set evaluates alike: its first evaluation is its score.
        (mean, search_score) = (gains, best);
    }
    Ok(Found {
        dof,
        start,
        gains: to_gains(&mean),
        search_return: search_score.0,
        search_lost: search_score.1,
        generations,
        evaluations,
    })
}

/// Softer starts beside the LQR gains `lqr`, for the first generation of a search from them: the
/// LQR gains halved and quartered. A twin whose vehicle is more responsive than identified, or whose
/// commands come late, wants less gain than the identified model's LQR; the cross-entropy method
/// shrinks its spread as it goes and can settle before it gets there (measured with images on the
/// harsh twin: from the LQR gains alone it ended at sway K (1.8, 8.7), -7.1 per trial on its search
/// set, where the search from the seeds' learned policies found (0.9, 3.1 to 3.5), -1.0 to -1.2).
pub fn softer_starts(lqr: PerDof<[f64; 2]>) -> Vec<(String, PerDof<[f64; 2]>)> {
    [
        ("the LQR gains halved", 0.5),
        ("the LQR gains quartered", 0.25),
    ]
    .map(|(name, k)| {
        (
            name.to_owned(),
            PerDof {
                sway: lqr.sway.map(|g| k * g),
                yaw: lqr.yaw.map(|g| k * g),
            },
        )
    })
    .to_vec()
}

/// A policy the limit must not be below: one evaluated beside it (the simulation policy, a policy
/// of step two), with its evaluated return on the evaluation set and the trials of that evaluation
/// in which it lost the cable.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Candidate {
    pub name: String,
    pub gains: PerDof<[f64; 2]>,
    pub evaluated: PerDof<f64>,
    pub lost: u32,
}

/// A policy that evaluated above the limit on the evaluation set.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Beaten {
    /// The candidate's name.
    pub by: String,
    /// By how much its evaluated return is above the limit's.
    pub margin: f64,
    /// The evaluation's noise on a difference it was judged against (beaten beyond it: `margin >
    /// 2 noise`).
    pub noise: f64,
}

/// The candidate most above a DOF's limit `limit` (whose pair lost the cable in `limit_lost`
/// trials of the set) in that DOF by more than twice `noise` (none: the limit holds). A candidate
/// that lost the cable in more trials than the limit is a failed policy and beats nothing, whatever
/// its return (a trial cut short costs less than a whole one). A noise that is not a number (not
/// measured) counts as none: any margin beats the limit.
pub fn beaten_in(
    dof: Dof,
    limit: f64,
    limit_lost: u32,
    candidates: &[Candidate],
    noise: f64,
) -> Option<Beaten> {
    let n = if noise.is_finite() { noise } else { 0.0 };
    candidates
        .iter()
        .filter(|c| c.lost <= limit_lost)
        .map(|c| (c, c.evaluated.get(dof) - limit))
        .filter(|(_, margin)| *margin > 2.0 * n)
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(c, margin)| Beaten {
            by: c.name.clone(),
            margin,
            noise: n,
        })
}

/// [`beaten_in`] for both DOFs: `limit` and `limit_lost` per DOF (each DOF's limit is its own pair).
pub fn beaten(
    limit: PerDof<f64>,
    limit_lost: PerDof<u32>,
    candidates: &[Candidate],
    noise: PerDof<f64>,
) -> PerDof<Option<Beaten>> {
    PerDof::from_fn(|dof| {
        beaten_in(
            dof,
            *limit.get(dof),
            *limit_lost.get(dof),
            candidates,
            *noise.get(dof),
        )
    })
}

/// The evaluation's noise on a difference between two policies, per DOF: the largest spread over
/// held-out sets of the difference between two of `policies`' returns (one return per set). The
/// check compares a limit with policies of other gains, and how much such a difference moves from
/// one set of starts to another grows with how far apart the gains are: a pair of alike policies
/// (step two kept the simulation policy: no difference on any set) measures nothing, so the most
/// different pair sets the noise. NaN without two policies on two sets.
pub fn difference_noise(policies: &[&PerDof<Vec<f64>>]) -> PerDof<f64> {
    let of = |dof: Dof| {
        let mut noise = f64::NAN;
        for (i, a) in policies.iter().enumerate() {
            for b in &policies[i + 1..] {
                let d: Vec<f64> = a
                    .get(dof)
                    .iter()
                    .zip(b.get(dof))
                    .map(|(x, y)| x - y)
                    .collect();
                let s = spread(&d);
                if s.is_finite() && (noise.is_nan() || s > noise) {
                    noise = s;
                }
            }
        }
        noise
    };
    PerDof::from_fn(of)
}

/// The noise the limit's check allows: [`difference_noise`] of `policies` (each policy's returns on
/// the held-out sets, with the cables it lost there) that kept the cable on every set. A trial cut
/// short by a lost cable moves a return by far more than the noise, and would let a limit far below
/// a policy pass as within the noise (measured in a test: a no-steering limit that lost the cable in
/// 6 of 20 held-out trials passed at sway -6.0 against a simulation policy at -0.75).
pub fn check_noise(policies: &[(&PerDof<Vec<f64>>, u32)]) -> PerDof<f64> {
    let kept: Vec<&PerDof<Vec<f64>>> = policies
        .iter()
        .filter(|(_, lost)| *lost == 0)
        .map(|(returns, _)| *returns)
        .collect();
    difference_noise(&kept)
}

/// Where the limit is checked: the evaluation set (`seed`, `trials`), and the evaluation's noise on
/// a difference between two policies there, per DOF.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Check {
    pub seed: u64,
    pub trials: u32,
    pub noise: PerDof<f64>,
}

/// One round of [`find`]: its search, the pair it found evaluated on the evaluation set (both DOFs,
/// and the trials that lost the cable), and the candidate that beat it there in the DOF beyond the
/// noise.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Round {
    pub search: SearchParams,
    pub found: Found,
    pub evaluated: PerDof<f64>,
    pub lost: u32,
    pub beaten: Option<Beaten>,
}

/// One DOF's limit, checked against the candidates: the pair best for it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DofLimit {
    pub gains: PerDof<[f64; 2]>,
    /// Its evaluation on the evaluation set (the DOF's limit is its return in the DOF).
    pub evaluation: Evaluation,
    pub rounds: Vec<Round>,
    /// A candidate still above it in the DOF beyond the noise.
    pub beaten: Option<Beaten>,
    /// Where no round found the return of the candidate that beat them: that candidate, whose own
    /// gains are the limit.
    #[serde(default)]
    pub candidate: Option<String>,
}

/// The twin's limit: each DOF's.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Limit(pub PerDof<DofLimit>);

impl Limit {
    pub fn get(&self, dof: Dof) -> &DofLimit {
        self.0.get(dof)
    }

    pub fn gains(&self) -> LimitGains {
        self.0.map(|_, l| l.gains)
    }

    /// Each DOF's limit: its return under its own pair on the evaluation set.
    pub fn returns(&self) -> PerDof<f64> {
        self.0.map(|dof, l| *l.evaluation.mean().get(dof))
    }

    /// The trials of the evaluation set in which each DOF's pair lost the cable.
    pub fn lost(&self) -> PerDof<u32> {
        self.0.map(|_, l| l.evaluation.lost)
    }

    pub fn beaten(&self) -> PerDof<Option<Beaten>> {
        self.0.map(|_, l| l.beaten.clone())
    }

    /// The rounds of both DOFs' searches.
    pub fn rounds(&self) -> Vec<Round> {
        [&self.0.sway, &self.0.yaw]
            .into_iter()
            .flat_map(|l| l.rounds.iter().cloned())
            .collect()
    }
}

/// The twin's limit (see the module docs): each DOF's, from its pair in `start` (the same for both,
/// or one per DOF).
#[allow(clippy::too_many_arguments)]
pub fn find(
    scenario: &Scenario,
    learning: &LearningParams,
    twin: &TwinParams,
    start: LimitGains,
    candidates: &[Candidate],
    params: &SearchParams,
    check: &Check,
    rounds: usize,
    progress: &Progress,
) -> Result<Limit, FromCheckpointError> {
    let of = |dof: Dof| {
        find_in(
            scenario,
            learning,
            twin,
            dof,
            *start.get(dof),
            candidates,
            params,
            check,
            rounds,
            progress,
        )
    };
    Ok(Limit(PerDof {
        sway: of(Dof::Sway)?,
        yaw: of(Dof::Yaw)?,
    }))
}

/// `dof`'s limit: the search from `start` with `candidates` in its first generation, checked on
/// `check`'s evaluation set, and gone on with for up to `rounds` rounds in all while a candidate
/// beats it there in the DOF beyond the noise.
#[allow(clippy::too_many_arguments)]
pub fn find_in(
    scenario: &Scenario,
    learning: &LearningParams,
    twin: &TwinParams,
    dof: Dof,
    start: PerDof<[f64; 2]>,
    candidates: &[Candidate],
    params: &SearchParams,
    check: &Check,
    rounds: usize,
    progress: &Progress,
) -> Result<DofLimit, FromCheckpointError> {
    // A pair's evaluation on the evaluation set, and the candidate above it there in the DOF.
    let checked =
        |gains: PerDof<[f64; 2]>| -> Result<(Evaluation, Option<Beaten>), FromCheckpointError> {
            let policy = policy_checkpoint(scenario, learning, gains);
            let evaluation = evaluate(
                scenario,
                twin,
                params.eyes,
                &policy,
                check.seed,
                check.trials,
            )?;
            let j = *evaluation.mean().get(dof);
            let beaten = beaten_in(dof, j, evaluation.lost, candidates, *check.noise.get(dof));
            Ok((evaluation, beaten))
        };
    let mut start = start;
    let mut given: Vec<PerDof<[f64; 2]>> = candidates.iter().map(|c| c.gains).collect();
    let mut done = Vec::new();
    for r in 0..rounds.max(1) {
        let round = if r == 0 {
            params.clone()
        } else {
            SearchParams {
                seed: config::derive_seed(params.seed, &format!("twin-limit/round/{r}")),
                trials: params.trials << r.min(8),
                ..params.clone()
            }
        };
        let found = search(
            scenario, learning, twin, dof, start, &given, &round, progress,
        )?;
        let (evaluation, beaten) = checked(found.gains)?;
        let gains = found.gains;
        if let Some(b) = &beaten {
            tracing::warn!(
                round = r + 1,
                %dof,
                by = %b.by,
                margin = b.margin,
                noise = b.noise,
                "twin limit: a candidate evaluates above the limit beyond the noise"
            );
        }
        done.push((
            Round {
                search: round,
                found,
                evaluated: evaluation.mean(),
                lost: evaluation.lost,
                beaten: beaten.clone(),
            },
            evaluation,
        ));
        let Some(b) = beaten else {
            break;
        };
        // The next round: from this limit, with the candidate that beat it in its first generation.
        start = gains;
        given = candidates
            .iter()
            .filter(|c| c.name == b.by)
            .map(|c| c.gains)
            .collect();
    }
    // A later round searches a larger set but need not end higher on the evaluation set: the
    // limit is the round least beaten there.
    let (rounds, mut evaluations): (Vec<Round>, Vec<Evaluation>) = done.into_iter().unzip();
    let best = least_beaten(dof, &rounds);
    let mut limit = DofLimit {
        gains: rounds[best].found.gains,
        evaluation: evaluations.swap_remove(best),
        beaten: rounds[best].beaten.clone(),
        rounds,
        candidate: None,
    };
    // Still beaten: no round's search, ranked on its own set, ended above that candidate on this
    // one. The candidate is a linear policy evaluated on this set, so its own gains are the best
    // return known here: they are the limit, if less beaten.
    let beater = (limit.beaten.as_ref())
        .and_then(|b| candidates.iter().find(|c| c.name == b.by))
        .cloned();
    if let Some(c) = beater {
        let (evaluation, beaten) = checked(c.gains)?;
        let j = *evaluation.mean().get(dof);
        let before = *limit.evaluation.mean().get(dof);
        if shortfall(j, beaten.as_ref()) < shortfall(before, limit.beaten.as_ref()) {
            tracing::info!(
                %dof,
                candidate = %c.name,
                evaluated = j,
                searched = before,
                "twin limit: no round found the candidate's return; its own gains are the limit"
            );
            limit = DofLimit {
                gains: c.gains,
                evaluation,
                beaten,
                candidate: Some(c.name),
                ..limit
            };
        }
    }
    Ok(limit)
}

/// The round whose limit is least beaten in `dof` on the evaluation set (the first of equals).
fn least_beaten(dof: Dof, rounds: &[Round]) -> usize {
    let of = |r: &Round| shortfall(*r.evaluated.get(dof), r.beaten.as_ref());
    (0..rounds.len())
        .min_by(|&a, &b| of(&rounds[a]).total_cmp(&of(&rounds[b])))
        .expect("one round at least")
}

/// How far a DOF's limit evaluated at `evaluated` is `beaten` on the evaluation set: the
/// candidate's margin above it, relative to its return (0: not beaten).
pub fn shortfall(evaluated: f64, beaten: Option<&Beaten>) -> f64 {
    beaten.map_or(0.0, |b| b.margin / evaluated.abs().max(f64::MIN_POSITIVE))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn returns(sway: &[f64], yaw: &[f64]) -> PerDof<Vec<f64>> {
        PerDof {
            sway: sway.to_vec(),
            yaw: yaw.to_vec(),
        }
    }

    /// The check's noise is set by the pair of policies whose difference moves most over the sets;
    /// a policy and its copy (step two kept the simulation policy) measure nothing, and so does one
    /// set.
    #[test]
    fn the_noise_is_the_most_different_pairs() {
        let sim = returns(&[-1.0, -2.0, -1.5], &[-5.0, -6.0, -5.5]);
        let kept = sim.clone();
        let limit = returns(&[-0.5, -1.9, -1.2], &[-4.0, -5.8, -5.0]);
        alone_is_nothing(&[&sim, &kept]);
        let n = difference_noise(&[&sim, &kept, &limit]);
        // limit - sim: sway [0.5, 0.1, 0.3], yaw [1.0, 0.2, 0.5].
        assert!((n.sway - 0.2).abs() < 1e-12, "{n:?}");
        assert!((n.yaw - spread(&[1.0, 0.2, 0.5])).abs() < 1e-12, "{n:?}");
        let one_set = returns(&[-1.0], &[-5.0]);
        let n = difference_noise(&[&one_set, &returns(&[-0.5], &[-4.0])]);
        assert!(n.sway.is_nan() && n.yaw.is_nan(), "{n:?}");
    }

    fn round(evaluated: f64, margin: f64) -> Round {
        Round {
            search: SearchParams::default(),
            found: Found {
                dof: Dof::Yaw,
                start: PerDof::default(),
                gains: PerDof::default(),
                search_return: PerDof::both(0.0),
                search_lost: 0,
                generations: Vec::new(),
                evaluations: 0,
            },
            evaluated: PerDof {
                sway: -0.2,
                yaw: evaluated,
            },
            lost: 0,
            beaten: (margin > 0.0).then(|| Beaten {
                by: "a candidate".to_owned(),
                margin,
                noise: 0.0,
            }),
        }
    }

    /// A DOF's limit is the round least beaten in it, relative to its return, not the last one.
    #[test]
    fn the_limit_is_the_round_least_beaten() {
        let rounds = [
            round(-5.0, 0.5), // beaten by 10%
            round(-4.0, 0.3), // 7.5%
            round(-6.0, 0.3), // 5%: the least
            round(-3.0, 0.6), // 20%
        ];
        assert_eq!(least_beaten(Dof::Yaw, &rounds), 2);
        // In sway (-0.2 in every round) the smallest margin is the least beaten: the first of the
        // two at 0.3.
        assert_eq!(least_beaten(Dof::Sway, &rounds), 1);
        let unbeaten = round(-7.0, 0.0);
        assert_eq!(
            least_beaten(Dof::Yaw, &[rounds[0].clone(), unbeaten.clone()]),
            1
        );
        assert_eq!(least_beaten(Dof::Yaw, &[unbeaten.clone(), unbeaten]), 0);
    }

    /// Each DOF's limit is checked on its own pair: a candidate beats a DOF's limit by its return
    /// in that DOF, and only if it lost the cable in no more trials than that DOF's pair did.
    #[test]
    fn each_dof_is_checked_against_its_own_pair() {
        let candidate = |name: &str, sway: f64, yaw: f64, lost: u32| Candidate {
            name: name.to_owned(),
            gains: PerDof::default(),
            evaluated: PerDof { sway, yaw },
            lost,
        };
        let candidates = [
            candidate("sway's best", -0.5, -9.0, 0),
            candidate("yaw's best", -3.0, -4.0, 0),
            candidate("reckless", 0.0, 0.0, 2),
        ];
        // The limit pairs: sway's at -0.6 (its pair lost no cable), yaw's at -5.0 (its pair lost
        // two): the reckless policy counts against yaw's pair only.
        let limit = PerDof {
            sway: -0.6,
            yaw: -5.0,
        };
        let b = beaten(
            limit,
            PerDof { sway: 0, yaw: 2 },
            &candidates,
            PerDof::both(0.02),
        );
        let sway = b.sway.expect("sway's best is 0.1 above sway's limit");
        assert_eq!(sway.by, "sway's best");
        assert!((sway.margin - 0.1).abs() < 1e-12);
        let yaw = b.yaw.expect("the reckless policy is 5.0 above yaw's limit");
        assert_eq!(yaw.by, "reckless");
        // Within twice the noise (0.1 < 0.9): held; beyond it (1.0): beaten.
        let held = beaten(limit, PerDof::both(0), &candidates, PerDof::both(0.45));
        assert!(held.sway.is_none(), "{held:?}");
        assert_eq!(held.yaw.map(|b| b.by).as_deref(), Some("yaw's best"));
    }

    /// A policy that lost the cable on the held-out sets is left out of the check's noise.
    #[test]
    fn a_lost_cable_is_not_noise() {
        let sim = returns(&[-1.0, -2.0, -1.5], &[-5.0, -6.0, -5.5]);
        let after = returns(&[-0.5, -1.9, -1.2], &[-4.0, -5.8, -5.0]);
        let reckless = returns(&[-30.0, -1.0, -9.0], &[-50.0, -4.0, -20.0]);
        let n = check_noise(&[(&sim, 0), (&after, 0), (&reckless, 2)]);
        assert_eq!(n, difference_noise(&[&sim, &after]));
        let all = difference_noise(&[&sim, &after, &reckless]);
        assert!(all.sway > 10.0 * n.sway, "{all:?} vs {n:?}");
    }

    fn alone_is_nothing(policies: &[&PerDof<Vec<f64>>]) {
        let n = difference_noise(policies);
        assert_eq!((n.sway, n.yaw), (0.0, 0.0));
    }
}
