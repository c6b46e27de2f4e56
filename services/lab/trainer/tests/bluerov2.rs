//! The BlueROV2 (config/bluerov2): step one learns on the model of what the stack's commands do
//! through ArduSub, and its policy flies the vehicle twin, the physical BlueROV2 behind its stand-in
//! ArduSub, in one process (no IPC, no sockets).

use config::{Dof, Eyes, PerDof, Preset, TwinParams};
use learning::Algorithm;
use std::path::{Path, PathBuf};
use trainer::Setup;
use trainer::experiment::{self, Curve};
use trainer::progress::Progress;
use trainer::step_two_bench::{BenchParams, run};
use trainer::twin_limit::{SearchParams, search};

fn dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../config/bluerov2")
}

fn setup() -> Setup {
    Setup::load(&dir(), Preset::Default).unwrap()
}

/// How much worse than the LQR limit NAC's late mean return may be. `trainer --config
/// config/bluerov2 fig5` (the same runs as this test, seed 1): sway -0.4164 against -0.4256 (2.2%
/// better), yaw -4.4452 against -4.4125 (0.7% worse). Over seeds 1 to 10 sway lay between 4.2%
/// better and 7.2% worse, yaw between 10.4% better and 0.8% worse (NAC maximises the undiscounted
/// return the figure shows; the LQR the discounted cost). The bounds are those worst seeds plus
/// about 2.5 points: a last-bit difference of another machine can carry a run anywhere in that
/// spread.
fn worse_bound(dof: Dof) -> f64 {
    match dof {
        Dof::Sway => 0.10,
        Dof::Yaw => 0.05,
    }
}

/// Fig. 5 on the BlueROV2: after 100 episodes, over 100 runs, NAC's mean returns are no worse than
/// the LQR limit by more than the bounds above, above the baseline's, and the cable stays in view in
/// the late episodes.
#[test]
fn nac_reaches_the_lqr_limit_on_the_bluerov2() {
    let setup = setup();
    let (runs, episodes, late) = (100, 100, 10);
    let hidden = Progress::hidden();
    let nac = experiment::learning_runs(&setup, Algorithm::Nac, runs, episodes, 1, &hidden);
    let gpomdp = experiment::learning_runs(&setup, Algorithm::Gpomdp, runs, episodes, 1, &hidden);
    let limit = experiment::limit(&setup, 4000, 1, &hidden).unwrap();
    for dof in Dof::ALL {
        let (n, g) = (Curve::of(&nac, dof), Curve::of(&gpomdp, dof));
        let (n_late, g_late, lim) = (
            n.tail_mean(late),
            g.tail_mean(late),
            *limit.mean_return.get(dof),
        );
        println!("{dof}: NAC {n_late:.4}, OLPOMDP {g_late:.4}, limit {lim:.4}");
        assert!(
            n_late >= lim - worse_bound(dof) * lim.abs(),
            "{dof}: NAC {n_late} more than {:.0}% below the limit {lim}",
            100.0 * worse_bound(dof)
        );
        assert!(
            n_late > g_late,
            "{dof}: NAC {n_late} not above OLPOMDP {g_late}"
        );
    }
    // Measured: none of the 1,000 late episodes loses the cable (nor any over seeds 1 to 10); two
    // are the margin for another machine's last bits.
    let lost = experiment::late_loss_fraction(&nac, late);
    assert!(
        lost <= 2.0 / (runs * late) as f64,
        "NAC lost the cable in {:.1}% of late episodes",
        100.0 * lost
    );
}

/// The step-one policy on the BlueROV2's twin, through its ArduSub stand-in (the twin turns the
/// allocator's setpoints into the pilot's sticks): over the evaluation sets of seeds 1 to 3 it never
/// loses the cable, nor does step two, and it starts within reach of the twin's limit (each DOF's
/// best return over all four gains, searched first), the gap (J_limit - J_sim) / |J_sim| measured
/// here at 3.5%, 14% and 25% in yaw, 50%, 16% and 22% in sway (whose returns are small: -0.132
/// against -0.066 on seed 1). Bounds: the largest measured and a third more.
#[test]
fn the_simulation_policy_flies_the_bluerov2_twin_close_to_its_limit() {
    let s = setup();
    let twin: TwinParams = config::load(&dir().join("twin.toml")).unwrap();
    assert!(twin.autopilot.is_some() && s.scenario.pilot.is_some());
    let limit = PerDof::from_fn(|dof| {
        search(
            &s.scenario,
            &s.learning,
            &twin,
            dof,
            experiment::lqr_gains(&s).unwrap(),
            &[],
            &SearchParams {
                eyes: Eyes::Ideal,
                ..SearchParams::default()
            },
            &Progress::hidden(),
        )
        .unwrap()
        .gains
    });
    let params = BenchParams {
        seeds: vec![1, 2, 3],
        trials: 20,
        sim_episodes: 100,
        eyes: Eyes::Ideal,
        sim_eyes: Eyes::Ideal,
        held_out: 0,
        every_trial: false,
        limit_search: SearchParams {
            eyes: Eyes::Ideal,
            ..SearchParams::default()
        },
        limit_rounds: 1,
        limit_seed: 1,
    };
    let results = run(
        &s.scenario,
        &s.learning,
        &twin,
        &limit,
        &params,
        &params.seeds,
        0,
        &Progress::hidden(),
    )
    .unwrap();
    print!("{}", trainer::step_two_bench::table(&results, &params));
    let bound = PerDof {
        sway: 0.67,
        yaw: 0.33,
    };
    for r in &results {
        assert_eq!(r.lost, 0, "seed {}: the cable was lost on the twin", r.seed);
        for dof in Dof::ALL {
            let (sim, lim) = (*r.sim.get(dof), *r.limit.get(dof));
            let gap = (lim - sim) / sim.abs();
            assert!(
                gap.is_finite() && gap <= *bound.get(dof),
                "seed {} {dof}: the simulation policy {sim} {:.0}% below the twin's limit {lim}",
                r.seed,
                100.0 * gap
            );
        }
    }
}
