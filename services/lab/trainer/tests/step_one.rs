//! Step one's promises, measured: NAC with the default settings reaches the LQR limit within 100
//! episodes, beats the baseline at its best step size, keeps the cable in view, and a run is
//! reproducible. These run the real trainer library in one process (no IPC).

use config::Eyes;
use config::{Dof, Preset};
use learning::Algorithm;
use std::path::Path;
use trainer::Setup;
use trainer::experiment::{self, Curve};
use trainer::progress::Progress;

fn setup() -> Setup {
    Setup::load(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../config"),
        Preset::Default,
    )
    .unwrap()
}

/// How far from the LQR limit NAC's late mean return lies in docs/results.md's Fig. 5 table (`trainer
/// fig5`, the same runs as this test): yaw -6.66 against -6.33 (5.2%), sway -0.406 against -0.404
/// (0.5%); each bound is that figure plus one percentage point. The runs are seeded, so on one
/// machine the figures are exact; the point is for another machine's floating-point last bits (its
/// libm), which through 100 episodes of learning can move a mean by a fraction of a percent.
fn gap_bound(dof: Dof) -> f64 {
    match dof {
        Dof::Yaw => 0.052 + 0.01,
        Dof::Sway => 0.005 + 0.01,
    }
}

/// What step one must reach: after 100 episodes, over 100 independent runs, NAC's mean returns are
/// as close to the LQR limit as docs/results.md publishes (the paper's criterion, within 10%, with room
/// to spare) and above the baseline's, and the cable stays in view in late episodes.
#[test]
fn nac_reaches_the_lqr_limit_within_100_episodes_and_beats_the_baseline() {
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
        println!(
            "{dof}: NAC {n_late:.4}, OLPOMDP {g_late:.4}, limit {lim:.4}; NAC within 10% from episode {:?}",
            n.first_within(lim, 0.1, 5)
        );
        assert!(
            (n_late - lim).abs() <= gap_bound(dof) * lim.abs(),
            "{dof}: NAC {n_late} not within {:.1}% of the limit {lim}",
            100.0 * gap_bound(dof)
        );
        assert!(
            n_late > g_late,
            "{dof}: NAC {n_late} not above OLPOMDP {g_late}"
        );
    }
    // The README: none of the 1,000 late episodes loses the cable; two are the margin for another
    // machine's last bits.
    let lost = experiment::late_loss_fraction(&nac, late);
    assert!(
        lost <= 2.0 / (runs * late) as f64,
        "NAC lost the cable in {:.1}% of late episodes",
        100.0 * lost
    );
}

/// The paper's alpha learns, only slowly: the preset exists and its runs improve.
#[test]
fn the_paper_preset_learns_slowly() {
    let paper = Setup::load(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../config"),
        Preset::Paper,
    )
    .unwrap();
    let runs = experiment::learning_runs(&paper, Algorithm::Nac, 20, 100, 3, &Progress::hidden());
    let yaw = Curve::of(&runs, Dof::Yaw);
    let first: f64 = yaw.mean[..10].iter().sum::<f64>() / 10.0;
    assert!(
        yaw.tail_mean(10) > first,
        "returns must rise: {first} -> {}",
        yaw.tail_mean(10)
    );
}

#[test]
fn a_run_is_reproducible_for_a_seed() {
    let setup = setup();
    let a = experiment::learning_run(&setup, Algorithm::Nac, 20, 42);
    let b = experiment::learning_run(&setup, Algorithm::Nac, 20, 42);
    let c = experiment::learning_run(&setup, Algorithm::Nac, 20, 43);
    assert_eq!(a, b);
    assert_ne!(a, c);
}

/// Runs spread over the cores give the same results as one after another.
#[test]
fn parallel_runs_equal_sequential_runs() {
    let setup = setup();
    let parallel =
        experiment::learning_runs(&setup, Algorithm::Gpomdp, 4, 5, 9, &Progress::hidden());
    for (r, run) in parallel.iter().enumerate() {
        assert_eq!(
            run,
            &experiment::learning_run(&setup, Algorithm::Gpomdp, 5, experiment::run_seed(9, r))
        );
    }
}

/// Step one with rendered images and perception in the loop instead of the geometry still learns.
#[test]
fn learning_with_images_and_perception_in_the_loop_improves_the_returns() {
    let setup = setup().with_eyes(Eyes::Images).unwrap();
    let runs = experiment::learning_runs(&setup, Algorithm::Nac, 2, 30, 5, &Progress::hidden());
    for dof in Dof::ALL {
        let c = Curve::of(&runs, dof);
        let first: f64 = c.mean[..5].iter().sum::<f64>() / 5.0;
        let last = c.tail_mean(10);
        println!("{dof}: first 5 episodes {first:.3}, last 10 {last:.3}");
        assert!(
            last > first,
            "{dof}: returns must rise with images in the loop: {first} -> {last}"
        );
    }
}
