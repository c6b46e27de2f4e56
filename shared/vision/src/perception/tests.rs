//! The tracker over rendered sequences: it follows a moving line in the band, re-acquires after a
//! loss, and its rates are filtered.

use super::*;
use crate::Renderer;
use model::{Cable, Pose, PoseRate, VehicleState, Velocity};

const DT: f64 = 0.2;

struct Rig {
    scenario: Scenario,
    renderer: Renderer,
    perception: Perception,
    camera: Camera,
    cable: Cable,
}

fn rig() -> Rig {
    let scenario = Scenario::default();
    let renderer = Renderer::from_scenario(&scenario, 3).unwrap();
    let perception = Perception::from_scenario(&scenario).unwrap();
    let camera = renderer.camera().clone();
    let cable = *renderer.cable();
    Rig {
        scenario,
        renderer,
        perception,
        camera,
        cable,
    }
}

/// A vehicle moving at a constant body velocity, sampled every DT (sub-stepped kinematics).
fn trajectory(start: Pose, velocity: Velocity, frames: usize) -> Vec<(Pose, PoseRate)> {
    let mut state = VehicleState {
        pose: start,
        velocity,
    };
    let mut out = Vec::new();
    for _ in 0..frames {
        out.push((state.pose, state.pose_rate()));
        for _ in 0..20 {
            let rate = state.pose_rate();
            state.pose = state.pose.advanced(&rate, DT / 20.0);
        }
    }
    out
}

#[test]
fn tracks_a_moving_line_in_the_band_with_rates_close_to_the_truth() {
    let mut r = rig();
    let start = Pose {
        x: 0.0,
        y: -0.1,
        psi: -0.2,
    };
    let path = trajectory(
        start,
        Velocity {
            u: 0.2,
            v: 0.04,
            r: 0.05,
        },
        40,
    );
    let mut in_band = 0;
    for (k, (pose, rate)) in path.iter().enumerate() {
        let truth = r
            .camera
            .observe(pose, rate, &r.cable, &r.scenario.observation);
        assert!(
            truth.found,
            "the test's path keeps the cable in view (frame {k})"
        );
        let frame = r.renderer.render_frame(pose, rate, k as u64);
        let obs = r.perception.process(frame.view(), DT).unwrap();
        assert!(obs.found, "frame {k}");
        assert!(
            wrap_half_pi(obs.theta - truth.theta).abs() < 1f64.to_radians(),
            "frame {k}"
        );
        assert!((obs.x_g - truth.x_g).abs() < 0.005, "frame {k}");
        let d = r.perception.last_detection().unwrap();
        if k > 0 && !d.full_search {
            in_band += 1;
        }
        // After the filter has settled, the rates follow the truth.
        if k >= 8 {
            assert!(
                (obs.x_g_rate - truth.x_g_rate).abs() < 0.02,
                "frame {k}: {} vs {}",
                obs.x_g_rate,
                truth.x_g_rate
            );
            assert!(
                (obs.theta_rate - truth.theta_rate).abs() < 0.02,
                "frame {k}: {} vs {}",
                obs.theta_rate,
                truth.theta_rate
            );
        }
    }
    assert!(
        in_band >= 38,
        "only {in_band} of 39 frames were found in the tracking band"
    );
}

#[test]
fn reports_coasting_then_lost_and_re_acquires_with_a_full_search() {
    let mut r = rig();
    let coast = r.scenario.perception.tracking.coast_frames as usize;
    let still = PoseRate::default();
    let on = Pose {
        x: 0.0,
        y: 0.05,
        psi: 0.1,
    };
    let off = Pose {
        x: 0.0,
        y: 2.0,
        psi: 0.1,
    };
    let mut k = 0u64;
    let mut step = |r: &mut Rig, pose: &Pose| {
        let frame = r.renderer.render_frame(pose, &still, k);
        k += 1;
        r.perception.process(frame.view(), DT).unwrap()
    };
    for _ in 0..5 {
        assert!(step(&mut r, &on).found);
    }
    let tracked = step(&mut r, &on);
    // The cable leaves the image: the prediction is reported for `coast` frames, with falling confidence.
    let mut last_confidence = tracked.confidence;
    for i in 0..coast {
        let obs = step(&mut r, &off);
        assert!(obs.found, "coasting frame {i}");
        assert!(obs.confidence < last_confidence);
        last_confidence = obs.confidence;
        assert!(r.perception.last_detection().is_none());
    }
    for _ in 0..3 {
        let obs = step(&mut r, &off);
        assert!(!obs.found);
        assert_eq!(obs, CableObservation::default());
    }
    // Back over the cable: found at once by a search of the whole frame, the rates start from rest.
    let obs = step(&mut r, &on);
    assert!(obs.found);
    assert!(r.perception.last_detection().unwrap().full_search);
    assert_eq!((obs.x_g_rate, obs.theta_rate), (0.0, 0.0));
    // reset() forgets the track.
    r.perception.reset();
    assert!(r.perception.last_detection().is_none());
}

#[test]
fn rates_are_filtered_not_raw_differences() {
    let mut r = rig();
    // A heavier noise than the default, so the raw differences are visibly noisy.
    let mut params = r.scenario.render.clone();
    params.noise.std_dn = 16.0;
    let mut renderer = Renderer::new(&params, &r.scenario.camera, &r.scenario.cable, 9).unwrap();
    let path = trajectory(
        Pose {
            x: 0.0,
            y: 0.0,
            psi: 0.3,
        },
        Velocity {
            u: 0.2,
            v: 0.0,
            r: 0.0,
        },
        40,
    );
    let (mut raw_sq, mut filtered_sq, mut n) = (0.0, 0.0, 0.0);
    let mut previous: Option<f64> = None;
    for (k, (pose, rate)) in path.iter().enumerate() {
        let truth = r
            .camera
            .observe(pose, rate, &r.cable, &r.scenario.observation);
        let frame = renderer.render_frame(pose, rate, k as u64);
        let obs = r.perception.process(frame.view(), DT).unwrap();
        assert!(obs.found);
        if let Some(prev) = previous
            && k >= 10
        {
            let raw = wrap_half_pi(obs.theta - prev) / DT;
            raw_sq += (raw - truth.theta_rate).powi(2);
            filtered_sq += (obs.theta_rate - truth.theta_rate).powi(2);
            n += 1.0;
        }
        previous = Some(obs.theta);
    }
    let (raw, filtered) = ((raw_sq / n).sqrt(), (filtered_sq / n).sqrt());
    assert!(
        filtered < 0.6 * raw,
        "filtered rate error {filtered} vs raw differences {raw} (rad/s RMS)"
    );
}

#[test]
fn rates_are_clipped_to_the_observation_box() {
    let mut r = rig();
    let still = PoseRate::default();
    let limits = r.scenario.observation.clone();
    // Jump the vehicle sideways by 0.3 m between frames: a raw x_g rate of about 1.3 per second.
    let a = r.renderer.render_frame(
        &Pose {
            x: 0.0,
            y: -0.15,
            psi: 0.0,
        },
        &still,
        0,
    );
    let b = r.renderer.render_frame(
        &Pose {
            x: 0.0,
            y: 0.15,
            psi: 0.0,
        },
        &still,
        1,
    );
    r.perception.process(a.view(), DT).unwrap();
    let obs = r.perception.process(b.view(), 0.05).unwrap();
    assert!(obs.found);
    assert_eq!(obs.x_g_rate.abs(), limits.x_g_rate_max, "{obs:?}");
}

#[test]
fn a_frame_of_another_size_is_an_error() {
    let mut r = rig();
    let small = vec![0u8; 160 * 120];
    let view = ImageView::new(&small, 160, 120).unwrap();
    assert!(matches!(
        r.perception.process(view, DT),
        Err(VisionError::SizeMismatch {
            width: 320,
            height: 240,
            ..
        })
    ));
}

/// A damaged frame is not looked at: the track coasts exactly as on a frame without the cable,
/// with a decaying confidence, and is lost after `coast_frames` of them.
#[test]
fn coasting_is_a_frame_without_the_cable() {
    let mut r = rig();
    let mut blank = rig();
    let pose = Pose {
        x: 0.0,
        y: 0.05,
        psi: 0.1,
    };
    let still = PoseRate::default();
    for k in 0..3 {
        let frame = r.renderer.render_frame(&pose, &still, k);
        let a = r.perception.process(frame.view(), DT).unwrap();
        let b = blank.perception.process(frame.view(), DT).unwrap();
        assert!(a.found);
        assert_eq!(a, b);
    }
    let (w, h) = (r.scenario.camera.width, r.scenario.camera.height);
    let empty = crate::Frame::new(w as usize, h as usize).unwrap();
    let coast_frames = r.scenario.perception.tracking.coast_frames;
    let mut confidence = r.perception.last_detection().unwrap().confidence;
    for k in 0..=coast_frames {
        let coasted = r.perception.coast(DT);
        let missed = blank.perception.process(empty.view(), DT).unwrap();
        assert_eq!(coasted, missed, "coast {k}");
        assert!(r.perception.last_detection().is_none());
        if k < coast_frames {
            assert!(
                coasted.found && coasted.confidence < confidence,
                "coast {k}"
            );
            confidence = coasted.confidence;
        } else {
            assert!(!coasted.found, "lost after {coast_frames} frames");
        }
    }
}
