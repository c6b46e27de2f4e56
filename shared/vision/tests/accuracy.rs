//! Perception against the geometric camera's ground truth, over 1,000 random poses with the cable in
//! view (x_g in [-0.4, 0.4], Theta in [-60, 60] degrees), each frame on its own (no tracking), and
//! over 500 frames without a cable.
//!
//! Each bound is the figure docs/results.md publishes for the test's seed plus the margin the noise
//! needs: the width of the range the same figure took over seeds 11 to 30 (20 runs of 1,000 poses),
//! so that another seed, or a change that merely draws other random numbers, still passes, while a
//! real loss of accuracy does not.

mod util;

use config::{RenderParams, Scenario};
use std::path::Path;
use util::{Accuracy, TABLE_HEADER, false_positives, false_positives_in, measure, measure_in};

const POSES: usize = 1000;

#[test]
fn clean_frames_find_every_cable_within_the_published_p95_errors() {
    let acc = measure(&RenderParams::clean(), POSES, 11);
    eprintln!("{TABLE_HEADER}\n{}", acc.row("clean"));
    // Published 100.0%; 100% for every seed: one frame in 1,000 of margin.
    assert!(
        acc.detection_rate() >= 0.999,
        "detected {}",
        acc.detection_rate()
    );
    let theta = Accuracy::percentile(&acc.theta_deg, 95.0);
    let x_g = Accuracy::percentile(&acc.x_g, 95.0);
    // Published 0.013 degree; over the seeds 0.0100 to 0.0129: margin 0.003.
    assert!(theta < 0.013 + 0.003, "p95 |Theta error| {theta} deg");
    // Published 0.0001 of the width; over the seeds 0.000052 to 0.000067: margin 0.00002.
    assert!(x_g < 0.0001 + 0.00002, "p95 |x_g error| {x_g}");
}

#[test]
fn with_every_effect_on_the_cable_is_found_within_the_published_rate_and_p95_errors() {
    let acc = measure(&RenderParams::default(), POSES, 12);
    eprintln!("{TABLE_HEADER}\n{}", acc.row("all effects"));
    // Published 100.0%; over the seeds 98.5% to 100%: margin 1.5%.
    assert!(
        acc.detection_rate() >= 1.0 - 0.015,
        "detected {}",
        acc.detection_rate()
    );
    let theta = Accuracy::percentile(&acc.theta_deg, 95.0);
    // Published 0.051 degree; over the seeds 0.048 to 0.091: margin 0.043.
    assert!(theta < 0.051 + 0.043, "p95 |Theta error| {theta} deg");
    let x_g = Accuracy::percentile(&acc.x_g, 95.0);
    // Published 0.0002 of the width; over the seeds 0.00019 to 0.00041: margin 0.00022.
    assert!(x_g < 0.0002 + 0.00022, "p95 |x_g error| {x_g}");
}

#[test]
fn without_a_cable_nothing_is_found_in_500_frames() {
    let n = 500;
    let found = false_positives(&RenderParams::default(), n, 13);
    eprintln!("no cable: found in {found} of {n} frames");
    // Published 0 of 500; 0 for every seed: no margin.
    assert_eq!(found, 0, "found in {found} of {n} frames");
}

/// `testdata/stress.toml`: a dimmer cable, more clutter, stronger vignetting, noise 12, a longer
/// exposure: harsher than the scenario's images, a guard against losing robustness.
fn stress() -> Scenario {
    config::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("testdata/stress.toml")).unwrap()
}

#[test]
fn under_stress_the_cable_is_found_in_95_percent_within_the_published_p95_error() {
    let s = stress();
    let acc = measure_in(&s, &s.render, POSES, 14);
    eprintln!("{TABLE_HEADER}\n{}", acc.row("stress"));
    // Published 99.7%; over the seeds 93.7% to 99.8%. The bound stays at 95%, tighter than the
    // seeds' range would need: this seed's figure is fixed, and 95% is what a guard must keep.
    assert!(
        acc.detection_rate() >= 0.95,
        "detected {}",
        acc.detection_rate()
    );
    let theta = Accuracy::percentile(&acc.theta_deg, 95.0);
    // Published 0.091 degree; over the seeds 0.091 to 0.200: margin 0.109.
    assert!(theta < 0.091 + 0.109, "p95 |Theta error| {theta} deg");
    let found = false_positives_in(&s, &s.render, 500, 15);
    eprintln!("stress, no cable: found in {found} of 500 frames");
    // Published 0 of 500; over the seeds 0 to 2: margin 2.
    assert!(found <= 2, "found in {found} of 500 frames");
}
