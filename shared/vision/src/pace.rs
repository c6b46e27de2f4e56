//! Perception at the vehicle's pace: tracking the cable along a path frame by frame, the frames a
//! pause apart (between two the caches go cold, as on the vehicle at 5 Hz) or back to back. The
//! vision benchmark and the vehicle's limit in `mesh-bench vehicle --limit` time it the same way.

use crate::{Frame, Perception, Renderer};
use model::{Pose, PoseRate, VehicleState, Velocity};
use std::hint::black_box;
use std::time::{Duration, Instant};

/// `frames` poses `dt_s` apart along the cable: 0.3 m/s of surge with some sway and a slowly
/// swinging yaw rate, starting a little off the cable: the band search's steady state.
pub fn tracking_path(frames: usize, dt_s: f64) -> Vec<(Pose, PoseRate)> {
    let mut state = VehicleState {
        pose: Pose {
            x: 0.0,
            y: 0.05,
            psi: -0.15,
        },
        velocity: Velocity {
            u: 0.3,
            v: 0.02,
            r: 0.03,
        },
    };
    (0..frames)
        .map(|k| {
            state.velocity.r = 0.05 * (k as f64 * 0.1).sin();
            let rate = state.pose_rate();
            let now = (state.pose, rate);
            state.pose = state.pose.advanced(&rate, dt_s);
            now
        })
        .collect()
}

/// The frames `renderer` makes along `path` (frame index = position on the path).
pub fn render_path(renderer: &mut Renderer, path: &[(Pose, PoseRate)]) -> Vec<Frame> {
    path.iter()
        .enumerate()
        .map(|(k, (pose, rate))| renderer.render_frame(pose, rate, k as u64))
        .collect()
}

/// Perception's time per frame (µs) tracking along `frames` (taken `dt_s` apart) from a fresh
/// track, with the thread asleep for `pause` before each frame (`None`: back to back).
pub fn perceive_paced(
    perception: &mut Perception,
    frames: &[Frame],
    dt_s: f64,
    pause: Option<Duration>,
) -> Vec<f64> {
    perception.reset();
    frames
        .iter()
        .map(|f| {
            if let Some(p) = pause {
                std::thread::sleep(p);
            }
            let start = Instant::now();
            black_box(
                perception
                    .process(f.view(), dt_s)
                    .expect("the frames have the camera's size"),
            );
            start.elapsed().as_secs_f64() * 1e6
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use config::Scenario;

    #[test]
    fn perception_tracks_the_path_it_is_timed_on() {
        let scenario = Scenario::default();
        let mut renderer = Renderer::from_scenario(&scenario, 1).unwrap();
        let path = tracking_path(20, 0.2);
        // Surging along the cable at 0.3 m/s: 0.2 s moves about 6 cm.
        for w in path.windows(2) {
            let dx = w[1].0.x - w[0].0.x;
            assert!((0.05..0.07).contains(&dx), "{dx}");
        }
        let frames = render_path(&mut renderer, &path);
        let mut perception = Perception::from_scenario(&scenario).unwrap();
        let us = perceive_paced(
            &mut perception,
            &frames,
            0.2,
            Some(Duration::from_millis(1)),
        );
        assert_eq!(us.len(), 20);
        assert!(us.iter().all(|t| *t > 0.0));
        // Every frame of the path is found: the timing is of tracking, not of searching in vain.
        assert!(perception.last_detection().is_some());
        perception.reset();
        let found = frames
            .iter()
            .filter(|f| perception.process(f.view(), 0.2).unwrap().found)
            .count();
        assert_eq!(found, 20);
    }
}
