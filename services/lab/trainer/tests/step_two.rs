//! Step two in one process (the twin and the vehicle endpoint's cores, no IPC), as the paper's
//! section IV-B, measured by the evaluation protocol: over several seeds, learning on the harsh twin
//! closes most of the gap between the simulation policy and the twin's limit and leaves no seed worse
//! than it found it; the limit search finds the LQR gain where the gap is off.
//!
//! Ideal perception (the camera's exact line and rates) keeps these tests to seconds; docs/results.md's
//! benchmark (`trainer --eyes images step-two-bench`) runs the same with images and perception in
//! the loop, as on the vehicle.

use config::{Dof, Eyes, PerDof, TwinParams};
use trainer::evaluation::{evaluate, policy_checkpoint};
use trainer::progress::Progress;
use trainer::step_two_bench::{
    BenchFile, BenchParams, SeedResult, Shard, Timing, candidates, merge, run, summary,
};
use trainer::twin_limit::{LimitGains, SearchParams, search};
use trainer::twin_world::{Mode, TwinWorld};
use trainer::{Setup, experiment};

fn setup() -> Setup {
    Setup::load(&testkit::config_dir(), config::Preset::Default).unwrap()
}

fn twin(file: &str) -> TwinParams {
    config::load(&testkit::config_dir().join(file)).unwrap()
}

/// The bench's parameters with ideal perception.
fn ideal_params(seeds: Vec<u64>, trials: u32, sim_episodes: usize, held_out: u32) -> BenchParams {
    BenchParams {
        seeds,
        trials,
        sim_episodes,
        eyes: Eyes::Ideal,
        sim_eyes: Eyes::Ideal,
        held_out,
        every_trial: false,
        limit_search: SearchParams {
            eyes: Eyes::Ideal,
            ..SearchParams::default()
        },
        limit_rounds: 3,
        limit_seed: 1,
    }
}

/// Each DOF's limit pair on `twin`: its search from `start` (no candidates).
fn limit_pairs(
    s: &Setup,
    twin: &TwinParams,
    start: PerDof<[f64; 2]>,
    params: &SearchParams,
) -> LimitGains {
    PerDof::from_fn(|dof| {
        search(
            &s.scenario,
            &s.learning,
            twin,
            dof,
            start,
            &[],
            params,
            &Progress::hidden(),
        )
        .unwrap()
        .gains
    })
}

/// Step two over seeds 1 to 8 on `twin` (ideal perception, 20 learning trials each, 2 held-out
/// sets for the noise), against the twin's limit searched first; the table is printed.
fn eight_seeds(s: &Setup, twin: &TwinParams) -> Vec<SeedResult> {
    let params = ideal_params((1..=8).collect(), 20, 100, 2);
    let limit = limit_pairs(
        s,
        twin,
        experiment::lqr_gains(s).unwrap(),
        &params.limit_search,
    );
    let results = run(
        &s.scenario,
        &s.learning,
        twin,
        &limit,
        &params,
        &params.seeds,
        0,
        &Progress::hidden(),
    )
    .unwrap();
    print!("{}", trainer::step_two_bench::table(&results, &params));
    results
}

/// No row shows a limit below a policy it evaluated on its set by more than twice the noise its
/// check allowed (the largest spread over its held-out sets of a difference between its simulation
/// policy, step two's and the bench's limit): not the simulation policy, not step two's final one,
/// not any policy its session evaluated.
fn assert_every_limit_is_a_limit(results: &[SeedResult]) {
    for r in results {
        assert!(
            !r.limit_is_beaten(),
            "seed {}: the row says its limit is beaten: {:?}",
            r.seed,
            r.limit_beaten
        );
        for c in candidates(&r.curve, &r.every_trial, r.after_gains, r.after) {
            for dof in Dof::ALL {
                let noise = *r.check_noise.get(dof);
                let noise = if noise.is_finite() { noise } else { 0.0 };
                assert!(
                    r.limit.get(dof) >= &(c.evaluated.get(dof) - 2.0 * noise),
                    "seed {} {dof}: the limit {} is below {} ({}) beyond twice the noise {noise}",
                    r.seed,
                    r.limit.get(dof),
                    c.name,
                    c.evaluated.get(dof)
                );
            }
        }
    }
}

/// Keeping the best keeps a pair evaluated together: every row's final policies (after its last
/// evaluation, the best pair restored where it was worse) are the pair one of its session's
/// evaluations evaluated, without losing the cable, and the row's J_after is that evaluation's
/// return in both DOFs, bit for bit. (Each DOF keeping the best of its own returns could end with
/// one evaluation's yaw and another's sway, flown together nowhere in the session.)
fn assert_the_final_pair_was_evaluated_together(results: &[SeedResult]) {
    for r in results {
        let together = r.curve.iter().find(|p| {
            p.gains == r.after_gains
                && p.lost == 0
                && Dof::ALL
                    .iter()
                    .all(|&d| p.evaluated.get(d).to_bits() == r.after.get(d).to_bits())
        });
        assert!(
            together.is_some(),
            "seed {}: the final pair {:?} (J_after {:?}) is no evaluation's pair: {:?}",
            r.seed,
            r.after_gains,
            r.after,
            r.curve
        );
    }
}

/// Keeping the best pair: no seed ends with a pair worse than its simulation policies on its own
/// evaluation set, on the score both behaviours judge (the evaluations are repeatable, so this holds
/// exactly): the session's first evaluation scores -2, and the final pair at least -2 less the
/// tolerance (a pair kept within the tolerance of the best). One DOF alone may end below its
/// simulation policy where the other gained more (seed 1 on the harsh twin: yaw -3% of its gap
/// closed, sway 126%).
fn assert_no_pair_ends_worse(s: &Setup, results: &[SeedResult]) {
    let tolerance = s.learning.safety.rollback.tolerance;
    for r in results {
        assert_eq!(r.curve[0].pair_score, Some(-2.0), "seed {}", r.seed);
        let last = r.final_pair().expect("the final pair was evaluated");
        let score = last.pair_score.expect("the session judged it");
        assert!(
            score >= -2.0 * (1.0 + tolerance),
            "seed {}: the final pair scores {score}",
            r.seed
        );
    }
}

/// Each DOF's search, from a quarter of the LQR gains, on the twin with its reality gap off (the
/// identified model), ends no more than 2% below the LQR gains in its DOF on held-out sets, and
/// sway's comes back to the LQR sway gains. (The LQR gains are each DOF's best alone; over all four gains a DOF
/// can do better where the other steers less: measured here, yaw's best pair turns sway's position
/// gain off and beats the LQR gains in yaw by -0.1% (seed 1) to 5.3% on seeds 1 to 3, since both
/// DOFs share the thrusters.)
#[test]
fn the_limit_search_is_never_below_the_lqr_gains_with_the_gap_off() {
    let s = setup();
    let ideal = twin("twin-ideal.toml");
    let lqr = experiment::lqr_gains(&s).unwrap();
    let start = PerDof {
        sway: lqr.sway.map(|k| 0.25 * k),
        yaw: lqr.yaw.map(|k| 0.25 * k),
    };
    let params = SearchParams {
        eyes: Eyes::Ideal,
        seed: 101,
        ..SearchParams::default()
    };
    // Each DOF's search ranks all four gains by that DOF's return.
    let found = limit_pairs(&s, &ideal, start, &params);
    let e = s.learning.evaluation.trials;
    for seed in [1, 2, 3] {
        let j = |gains| {
            evaluate(
                &s.scenario,
                &ideal,
                Eyes::Ideal,
                &policy_checkpoint(&s.scenario, &s.learning, gains),
                seed,
                e,
            )
            .unwrap()
            .mean()
        };
        let (lqr_j, start_j) = (j(lqr), j(start));
        for dof in Dof::ALL {
            let found_j = j(*found.get(dof));
            let (f, l, st) = (*found_j.get(dof), *lqr_j.get(dof), *start_j.get(dof));
            eprintln!("seed {seed} {dof}: found {f:.4}, LQR {l:.4}, start {st:.4}");
            // Each DOF's search ranks all four gains by its return, so it can end above the LQR
            // gains (each DOF's LQR is optimal for its own discounted cost alone); it must not end
            // below: 2% allows for the search set's noise.
            assert!(f >= l - 0.02 * l.abs(), "{dof}: found {f} below LQR {l}");
            assert!(st < l - 0.02 * l.abs(), "{dof}: the start is clearly worse");
        }
    }
    // Sway's own gains, from its search: measured within 5% of the LQR's (the undiscounted 90 s
    // return is flat there); the bound adds the search's spread.
    let (f, l) = (found.sway.sway, lqr.sway);
    eprintln!("found {found:?}, LQR {lqr:?}");
    for i in 0..2 {
        assert!((f[i] / l[i] - 1.0).abs() < 0.4, "{f:?} vs {l:?}");
    }
}

/// Each DOF's limit is its own pair: on the harsh-cross twin (its current makes sway's gains cost
/// yaw), each DOF's search ends at a pair better in that DOF than the other DOF's pair, clearly, on
/// the evaluation sets of seeds 1 to 3. A search that ranked both DOFs alike, or a limit of one pair
/// for both, could not be.
#[test]
fn each_dofs_limit_is_its_own_pair_where_the_dofs_pull_apart() {
    let s = setup();
    let cross = twin("twin-harsh-cross.toml");
    let params = SearchParams {
        eyes: Eyes::Ideal,
        ..SearchParams::default()
    };
    let pairs = limit_pairs(&s, &cross, experiment::lqr_gains(&s).unwrap(), &params);
    eprintln!("pairs {pairs:?}");
    let e = s.learning.evaluation.trials;
    for seed in [1, 2, 3] {
        let j = pairs.map(|_, g| {
            evaluate(
                &s.scenario,
                &cross,
                Eyes::Ideal,
                &policy_checkpoint(&s.scenario, &s.learning, *g),
                seed,
                e,
            )
            .unwrap()
            .mean()
        });
        eprintln!(
            "seed {seed}: sway's pair {:?}, yaw's pair {:?}",
            j.sway, j.yaw
        );
        // Measured on seeds 1 to 3: sway's pair is 82% to 91% better in sway than yaw's pair, yaw's
        // 3.5% to 4.2% better in yaw than sway's (0.21 to 0.25 a trial). Bounds: 50% and 2%.
        let margin = PerDof {
            sway: 0.5,
            yaw: 0.02,
        };
        for (dof, other) in [(Dof::Sway, Dof::Yaw), (Dof::Yaw, Dof::Sway)] {
            let (own, theirs) = (*j.get(dof).get(dof), *j.get(other).get(dof));
            assert!(
                own > theirs + margin.get(dof) * theirs.abs(),
                "seed {seed} {dof}: its own pair {own}, the other DOF's {theirs}"
            );
        }
    }
}

/// Over several seeds on the harsh twin (ideal perception): step two closes most of the gap to the
/// twin's limit, no seed ends with a pair worse than its simulation policies on its evaluation set,
/// every final pair was evaluated together, and no trial loses the cable.
#[test]
fn step_two_closes_the_gap_on_the_harsh_twin_and_never_leaves_a_seed_worse() {
    let s = setup();
    let harsh = twin("twin-harsh.toml");
    let results = eight_seeds(&s, &harsh);
    let verdict = summary(&results);
    for (dof, d) in [(Dof::Yaw, &verdict.yaw), (Dof::Sway, &verdict.sway)] {
        // The published benchmark (12 seeds, ideal perception, `scripts/bench-step-two --eyes
        // ideal`): median gap closed 85% for yaw (seeds 61% to 94%) and 99% for sway (94% to
        // 101%). The margin is what the spread over those seeds needs for 8 of them: the lowest
        // median any 8 of the 12 give is 76.4% for yaw and 98.4% for sway, so the bounds are 76%
        // and 98% (the test's limit is its own search's).
        let bound = match dof {
            Dof::Yaw => 0.76,
            Dof::Sway => 0.98,
        };
        assert!(
            d.median_gap_closed >= bound,
            "{dof}: median gap closed {}",
            d.median_gap_closed
        );
    }
    assert_eq!(verdict.lost, 0, "no trial loses the cable");
    assert_no_pair_ends_worse(&s, &results);
    assert_every_limit_is_a_limit(&results);
    assert_the_final_pair_was_evaluated_together(&results);
}

/// Over several seeds on the harsh twin with the current across the cable (ideal perception): no
/// trial of any session loses the cable, nor does any seed's final policy on a set of starts it never
/// learned on, and step two still closes most of the gap. (Before a lost cable counted as a failed
/// policy, seed 3 lost it in 18 of its 45 trials: its sway learner lowered the rate gain until the
/// lagging, late sway loop swung the cable out of the image, and since a trial cut short costs sway
/// less than 90 s of poor tracking, keeping the best kept the policy that lost it.)
#[test]
fn no_trial_loses_the_cable_on_the_harsh_twin_with_a_cross_current() {
    let s = setup();
    let cross = twin("twin-harsh-cross.toml");
    assert_eq!(cross.current.direction_deg, 90.0);
    let results = eight_seeds(&s, &cross);
    let verdict = summary(&results);
    let e = s.learning.evaluation.trials;
    for r in &results {
        // The worst seed: not one trial (learning or evaluation) lost the cable.
        assert_eq!(r.lost, 0, "seed {}: trials that lost the cable", r.seed);
        let after = policy_checkpoint(&s.scenario, &s.learning, r.after_gains);
        let held_out = config::derive_seed(r.seed, "held-out/0");
        let other = evaluate(&s.scenario, &cross, Eyes::Ideal, &after, held_out, e).unwrap();
        assert_eq!(
            other.lost, 0,
            "seed {}: the final policy loses the cable on other starts",
            r.seed
        );
    }
    assert_eq!(verdict.lost, 0);
    assert_every_limit_is_a_limit(&results);
    for (dof, d) in [(Dof::Yaw, &verdict.yaw), (Dof::Sway, &verdict.sway)] {
        // The published benchmark (12 seeds, ideal perception): median gap closed 85% for yaw
        // (seeds 6% to 96%) and 99% for sway (95% to 103%). The lowest median any 8 of those 12
        // seeds give is 71.7% for yaw and 97.9% for sway, so the bounds are 71% and 97%.
        let bound = match dof {
            Dof::Yaw => 0.71,
            Dof::Sway => 0.97,
        };
        assert!(
            d.median_gap_closed >= bound,
            "{dof}: median gap closed {}",
            d.median_gap_closed
        );
    }
    assert_no_pair_ends_worse(&s, &results);
    assert_the_final_pair_was_evaluated_together(&results);
}

/// An evaluation of step two's session is the protocol: the session's first evaluation (before any
/// learning) gives the returns of the simulation policy evaluated on its own, bit for bit, and so
/// does an evaluation after learning for the policy it evaluated.
#[test]
fn a_sessions_evaluations_are_the_protocols() {
    let s = setup();
    let mut harsh = twin("twin-harsh.toml");
    harsh.trials.duration_s = 30.0;
    let sim =
        trainer::step_two_bench::step_one(&s.scenario, &s.learning, 60, Eyes::Ideal, 4).unwrap();
    let e = s.learning.evaluation.trials;
    let seed = 4;
    let mut world =
        TwinWorld::from_checkpoint(&s.scenario, &harsh, &sim, Eyes::Ideal, seed, Mode::Learn)
            .unwrap();
    let session: Vec<_> = (0..behaviour::session_trials(&s.learning.evaluation, 10))
        .map(|_| world.run_trial())
        .collect();
    let evaluations: Vec<_> = session
        .iter()
        .filter(|t| t.evaluated.yaw.is_finite())
        .collect();
    assert_eq!(evaluations.len(), 3);
    let alone = evaluate(&s.scenario, &harsh, Eyes::Ideal, &sim, seed, e)
        .unwrap()
        .mean();
    assert_eq!(evaluations[0].evaluated.yaw.to_bits(), alone.yaw.to_bits());
    assert_eq!(
        evaluations[0].evaluated.sway.to_bits(),
        alone.sway.to_bits()
    );
    // The policy the second evaluation judged: the gains after the learning trials before it.
    let k = s.learning.evaluation.learning_trials;
    let judged = session[(e + k - 1) as usize].gains;
    assert!(!session[(e + k - 1) as usize].evaluation && session[(e + k) as usize].evaluation);
    let again = evaluate(
        &s.scenario,
        &harsh,
        Eyes::Ideal,
        &policy_checkpoint(&s.scenario, &s.learning, judged),
        seed,
        e,
    )
    .unwrap()
    .mean();
    assert_eq!(evaluations[1].evaluated.yaw.to_bits(), again.yaw.to_bits());
    assert_eq!(
        evaluations[1].evaluated.sway.to_bits(),
        again.sway.to_bits()
    );
}

/// The in-process step two is reproducible: the same seed, the same trials.
#[test]
fn the_same_seed_gives_the_same_trials() {
    let s = setup();
    let sim =
        trainer::step_two_bench::step_one(&s.scenario, &s.learning, 10, Eyes::Ideal, 3).unwrap();
    let run = || {
        let mut w = TwinWorld::from_checkpoint(
            &s.scenario,
            &TwinParams::default(),
            &sim,
            Eyes::Images,
            3,
            Mode::Learn,
        )
        .unwrap();
        (0..2).map(|_| w.run_trial()).collect::<Vec<_>>()
    };
    let (a, b) = (run(), run());
    assert_eq!(format!("{a:?}"), format!("{b:?}"));
}

/// Learning parameters for the safety tests: a learning rate far beyond the swept one (each actor
/// update a long step), with only the named parts of the safety layer on.
fn reckless(s: &Setup, stability: bool, rollback: bool) -> config::LearningParams {
    let mut l = s.learning.clone();
    // About 1,900 times the swept rate for sway and 90 times for yaw (sway's rewards are the
    // smaller): long enough steps to leave the stable set within a few trials.
    l.nac.alpha = PerDof {
        sway: 4000.0,
        yaw: 200.0,
    };
    l.safety.trust_region.enabled = false;
    l.safety.stability.enabled = stability;
    l.safety.rollback.enabled = rollback;
    // The steps these tests measure were sized with step one's eligibility rate: the safety layer
    // is what they test, not the rate.
    l.step_two.lambda = l.nac.lambda;
    l
}

/// A short step-two session from the LQR gains on the twin with its gap off, over several seeds.
fn reckless_sessions(
    s: &Setup,
    learning: &config::LearningParams,
) -> Vec<Vec<trainer::twin_world::TrialResult>> {
    let mut twin = twin("twin-ideal.toml");
    twin.trials.duration_s = 30.0;
    let start = policy_checkpoint(&s.scenario, learning, experiment::lqr_gains(s).unwrap());
    [1, 2, 3]
        .into_iter()
        .map(|seed| {
            let mut w = TwinWorld::from_checkpoint(
                &s.scenario,
                &twin,
                &start,
                Eyes::Ideal,
                seed,
                Mode::Learn,
            )
            .unwrap();
            (0..behaviour::session_trials(&learning.evaluation, 10))
                .map(|_| w.run_trial())
                .collect()
        })
        .collect()
}

/// With long actor steps, learning proposes gains outside the set the identified model says is
/// stable with its margin (shown with the guard off); with the guard on, every such update is
/// refused, counted, and the gains never leave the set, in every seed.
#[test]
fn a_destabilising_update_is_refused() {
    let s = setup();
    let guarded = reckless(&s, true, false);
    let set = |dof| {
        behaviour::step_two::guard(&s.scenario, &guarded, dof)
            .unwrap()
            .stable_set
            .unwrap()
    };
    let outside = |runs: &[Vec<trainer::twin_world::TrialResult>], dof: Dof| {
        runs.iter()
            .flatten()
            .filter(|t| !set(dof).contains(*t.gains.get(dof)))
            .count()
    };
    let free = reckless_sessions(&s, &reckless(&s, false, false));
    let kept = reckless_sessions(&s, &guarded);
    for dof in Dof::ALL {
        // The unguarded learner leaves the set in some trial of every seed: the updates the guard
        // must refuse do happen.
        for run in &free {
            assert!(
                outside(std::slice::from_ref(run), dof) > 0,
                "{dof}: never left the set"
            );
            assert_eq!(run.last().unwrap().refused.get(dof), &0);
        }
        assert_eq!(outside(&kept, dof), 0, "{dof}: a guarded gain left the set");
        for run in &kept {
            assert!(
                *run.last().unwrap().refused.get(dof) > 0,
                "{dof}: nothing refused"
            );
        }
    }
}

/// Keeping the best: with long actor steps and no guard, some evaluation of every seed finds the
/// learned pair worse than the best beyond the tolerance; both behaviours then restore the policies
/// of one and the same earlier evaluation (the best pair), which the protocol, evaluating that pair
/// alone, scores exactly at the best returns in both DOFs.
#[test]
fn a_rollback_restores_the_best_pair() {
    let s = setup();
    let learning = reckless(&s, false, true);
    let mut twin = twin("twin-ideal.toml");
    twin.trials.duration_s = 30.0;
    let e = learning.evaluation.trials;
    assert!(e > 1);
    for (i, run) in reckless_sessions(&s, &learning).iter().enumerate() {
        let seed = i as u64 + 1;
        let mut restored = 0;
        for (t, trial) in run.iter().enumerate() {
            let rolled = trial.rolled_back;
            assert_eq!(
                rolled.sway, rolled.yaw,
                "seed {seed} trial {t}: one DOF alone"
            );
            if !rolled.yaw {
                continue;
            }
            restored += 1;
            // The best's evaluation: the one whose returns are the best ones, in both DOFs.
            let c = (0..t)
                .rev()
                .find(|&c| {
                    Dof::ALL
                        .iter()
                        .all(|&d| run[c].evaluated.get(d).to_bits() == trial.best.get(d).to_bits())
                })
                .expect("the best pair was evaluated before");
            // The pair it evaluated: the gains in its trials (no learning there).
            let pair = run[c - 1].gains;
            assert_eq!(trial.gains, pair, "seed {seed}: the best pair is in force");
            assert_ne!(
                run[t - 1].gains,
                pair,
                "seed {seed}: the policies were replaced"
            );
            let alone = evaluate(
                &s.scenario,
                &twin,
                Eyes::Ideal,
                &policy_checkpoint(&s.scenario, &learning, pair),
                seed,
                e,
            )
            .unwrap()
            .mean();
            for dof in Dof::ALL {
                assert_eq!(
                    alone.get(dof).to_bits(),
                    trial.best.get(dof).to_bits(),
                    "seed {seed} {dof}: the restored pair is the best one"
                );
            }
        }
        assert!(restored > 0, "seed {seed}: no rollback");
        assert!(run.last().unwrap().rollbacks.sway + run.last().unwrap().rollbacks.yaw > 0);
    }
}

/// The bench's small run on the harsh twin for the tests below: 3 seeds of short trials, ideal
/// perception, every learning trial evaluated, 2 held-out sets, a small limit search.
fn small_run() -> (Setup, TwinParams, BenchParams) {
    let s = setup();
    let mut harsh = twin("twin-harsh.toml");
    harsh.trials.duration_s = 20.0;
    let mut params = ideal_params(vec![1, 2, 3], 5, 20, 2);
    params.every_trial = true;
    params.limit_search.population = 6;
    params.limit_search.generations = 4;
    params.limit_search.trials = 5;
    (s, harsh, params)
}

/// A limit that is no limit (no steering at all, which every learned policy beats): each seed's
/// search goes on from its policies, and no row then shows a limit below a policy it evaluated
/// beyond the noise. Without the search going on, every row would (the first assertion).
#[test]
fn a_row_never_shows_a_limit_below_a_policy_it_evaluated() {
    let (s, harsh, params) = small_run();
    let poor = PerDof::both(PerDof::default());
    let results = run(
        &s.scenario,
        &s.learning,
        &harsh,
        &poor,
        &params,
        &params.seeds,
        0,
        &Progress::hidden(),
    )
    .unwrap();
    print!("{}", trainer::step_two_bench::table(&results, &params));
    let e = s.learning.evaluation.trials;
    for r in &results {
        let no_steering = policy_checkpoint(&s.scenario, &s.learning, PerDof::default());
        let given = evaluate(&s.scenario, &harsh, Eyes::Ideal, &no_steering, r.seed, e)
            .unwrap()
            .mean();
        assert!(
            given.yaw < r.sim.yaw && given.sway < r.sim.sway,
            "seed {}: the poor limit was no poorer than the simulation policy",
            r.seed
        );
        for dof in Dof::ALL {
            assert!(
                r.limit_searched_on(dof),
                "seed {} {dof}: the search did not go on",
                r.seed
            );
        }
    }
    assert_every_limit_is_a_limit(&results);
    assert_the_final_pair_was_evaluated_together(&results);
}

/// Seeds in parallel give the rows a sequential run gives, and shards merged give the unsplit run's
/// file and table: the unsplit run on 2 threads, shards 1/2 and 2/2 each on 1 thread and through
/// their JSON text (as `step-two-merge` reads them), merged.
#[test]
fn shards_merged_give_the_unsplit_table_and_threads_change_nothing() {
    let (s, harsh, params) = small_run();
    let limit = PerDof::both(experiment::lqr_gains(&s).unwrap());
    let file = |seeds: &[u64], threads, shard| {
        let rows = run(
            &s.scenario,
            &s.learning,
            &harsh,
            &limit,
            &params,
            seeds,
            threads,
            &Progress::hidden(),
        )
        .unwrap();
        BenchFile {
            twin: "twin-harsh.toml".into(),
            twin_params: harsh.clone(),
            scenario: s.scenario.clone(),
            learning: s.learning.clone(),
            params: params.clone(),
            limit,
            shard,
            summary: summary(&rows),
            seeds: rows,
            timing: Timing {
                wall_s: 1.0,
                threads,
                shards_wall_s: Vec::new(),
            },
        }
    };
    let unsplit = file(&params.seeds, 2, None);
    let shards: Vec<(String, BenchFile)> = [Shard { k: 2, n: 2 }, Shard { k: 1, n: 2 }]
        .into_iter()
        .map(|shard| {
            let f = file(&shard.seeds(&params.seeds), 1, Some(shard));
            let text = serde_json::to_string_pretty(&f).unwrap();
            (
                format!("shard {shard}"),
                serde_json::from_str(&text).unwrap(),
            )
        })
        .collect();
    assert_eq!(shards[1].1.seeds.len(), 2, "shard 1/2 runs seeds 1 and 3");
    let merged = merge(&shards).unwrap();
    print!("{}", merged.table());
    assert_eq!(merged.table(), unsplit.table());
    assert_eq!(merged.without_timing(), unsplit.without_timing());
    assert_eq!(merged.timing.shards_wall_s, vec![1.0, 1.0]);
    // A shard missing, or given twice, is refused.
    assert!(merge(&shards[..1]).is_err());
    assert!(merge(&[shards[0].clone(), shards[0].clone()]).is_err());
}

/// A candidate no search round finds is its own limit: each round's search ranks on its own set,
/// and where that settles elsewhere than the candidate best on the evaluation set, the limit would
/// be below it there. The case is made on purpose: gains around the LQR's, a search set of one
/// trial, a search that stops after its first generation (so it ends on the best of its start and
/// the candidates on the search set), and a search seed for which that is not the evaluation set's
/// best. The limit must then be that candidate's gains, and beaten by none.
#[test]
fn a_candidate_no_search_finds_is_its_own_limit() {
    use trainer::twin_limit::{Candidate, Check, find_in};
    let s = setup();
    let mut harsh = twin("twin-harsh.toml");
    harsh.trials.duration_s = 20.0;
    let lqr = experiment::lqr_gains(&s).unwrap();
    let e = s.learning.evaluation.trials;
    let (dof, check_seed) = (Dof::Yaw, 7);
    let scaled = |k: f64| PerDof {
        sway: lqr.sway,
        yaw: lqr.yaw.map(|g| k * g),
    };
    let j = |gains, seed, trials| {
        let mut t = harsh.clone();
        t.trials.cycle = trials;
        evaluate(
            &s.scenario,
            &t,
            Eyes::Ideal,
            &policy_checkpoint(&s.scenario, &s.learning, gains),
            seed,
            trials,
        )
        .unwrap()
    };
    let candidates: Vec<Candidate> = [0.5, 0.7, 1.0, 1.4, 2.0]
        .iter()
        .map(|&k| {
            let ev = j(scaled(k), check_seed, e);
            Candidate {
                name: format!("yaw x {k}"),
                gains: scaled(k),
                evaluated: ev.mean(),
                lost: ev.lost,
            }
        })
        .collect();
    let best_by = |scores: &[f64]| {
        (0..scores.len())
            .max_by(|&a, &b| scores[a].total_cmp(&scores[b]))
            .unwrap()
    };
    let on_check: Vec<f64> = candidates.iter().map(|c| *c.evaluated.get(dof)).collect();
    let best = best_by(&on_check);
    // A search seed whose one-trial set ranks another candidate first.
    let search_seed = (1..=60)
        .find(|&seed| {
            let on_search: Vec<f64> = candidates
                .iter()
                .map(|c| *j(c.gains, seed, 1).mean().get(dof))
                .collect();
            best_by(&on_search) != best
        })
        .expect("some one-trial search set ranks another candidate first");
    let params = SearchParams {
        eyes: Eyes::Ideal,
        population: 4,
        generations: 1,
        trials: 1,
        seed: search_seed,
        tolerance: 1e9,
    };
    let check = Check {
        seed: check_seed,
        trials: e,
        noise: PerDof::both(0.0),
    };
    let limit = find_in(
        &s.scenario,
        &s.learning,
        &harsh,
        dof,
        candidates[0].gains,
        &candidates,
        &params,
        &check,
        1,
        &Progress::hidden(),
    )
    .unwrap();
    let round = &limit.rounds[0];
    assert!(
        round.beaten.is_some(),
        "the search ended on the evaluation set's best: nothing to show ({round:?})"
    );
    assert_eq!(
        limit.candidate.as_deref(),
        Some(candidates[best].name.as_str())
    );
    assert_eq!(limit.gains, candidates[best].gains);
    assert!(limit.beaten.is_none(), "{:?}", limit.beaten);
    assert!(*limit.evaluation.mean().get(dof) >= on_check[best]);
}
