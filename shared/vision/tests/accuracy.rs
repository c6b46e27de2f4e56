//! Perception against the geometric camera's ground truth, over 1,000 random poses with the cable in
//! view (x_g in [-0.4, 0.4], Theta in [-60, 60] degrees), each frame on its own (no tracking), and
//! over 500 frames without a cable.

mod util;

use config::{RenderParams, Scenario};
use std::path::Path;
use util::{Accuracy, TABLE_HEADER, false_positives, false_positives_in, measure, measure_in};

const POSES: usize = 1000;

#[test]
fn clean_frames_are_measured_to_half_a_degree_and_half_a_percent() {
    let acc = measure(&RenderParams::clean(), POSES, 11);
    eprintln!("{TABLE_HEADER}\n{}", acc.row("clean"));
    assert!(
        acc.detection_rate() >= 0.999,
        "detected {}",
        acc.detection_rate()
    );
    let theta = Accuracy::percentile(&acc.theta_deg, 95.0);
    let x_g = Accuracy::percentile(&acc.x_g, 95.0);
    assert!(theta < 0.5, "p95 |Theta error| {theta} deg");
    assert!(x_g < 0.005, "p95 |x_g error| {x_g}");
}

#[test]
fn with_every_effect_on_the_cable_is_found_in_98_percent_within_2_degrees() {
    let acc = measure(&RenderParams::default(), POSES, 12);
    eprintln!("{TABLE_HEADER}\n{}", acc.row("all effects"));
    assert!(
        acc.detection_rate() >= 0.98,
        "detected {}",
        acc.detection_rate()
    );
    let theta = Accuracy::percentile(&acc.theta_deg, 95.0);
    assert!(theta < 2.0, "p95 |Theta error| {theta} deg");
    // Not asked for with effects on, but held to the clean bound all the same.
    let x_g = Accuracy::percentile(&acc.x_g, 95.0);
    assert!(x_g < 0.005, "p95 |x_g error| {x_g}");
}

#[test]
fn without_a_cable_found_is_reported_in_under_1_percent() {
    let n = 500;
    let found = false_positives(&RenderParams::default(), n, 13);
    eprintln!("no cable: found in {found} of {n} frames");
    assert!(
        (found as f64) < 0.01 * n as f64,
        "found in {found} of {n} frames"
    );
}

/// `testdata/stress.toml`: a dimmer cable, more clutter, stronger vignetting, noise 12, a longer
/// exposure. Not a requirement of the issue: a guard against losing robustness.
fn stress() -> Scenario {
    config::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("testdata/stress.toml")).unwrap()
}

#[test]
fn under_stress_the_cable_is_still_found_in_95_percent_within_2_degrees() {
    let s = stress();
    let acc = measure_in(&s, &s.render, POSES, 14);
    eprintln!("{TABLE_HEADER}\n{}", acc.row("stress"));
    assert!(
        acc.detection_rate() >= 0.95,
        "detected {}",
        acc.detection_rate()
    );
    let theta = Accuracy::percentile(&acc.theta_deg, 95.0);
    assert!(theta < 2.0, "p95 |Theta error| {theta} deg");
    let found = false_positives_in(&s, &s.render, 500, 15);
    eprintln!("stress, no cable: found in {found} of 500 frames");
    assert!(found < 5, "found in {found} of 500 frames");
}
