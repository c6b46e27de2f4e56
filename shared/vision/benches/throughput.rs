//! Frames per second of the renderer and of perception on one core, 320x240, clean and with every
//! effect on: the median of several runs over the same frames.
//!
//!     cargo bench -p vision --bench throughput            # or, pinned: taskset -c 1 cargo bench ...
//!
//! Perception is measured two ways: each frame on its own (a search of the whole frame every time,
//! the worst case: first frame and after a loss) and tracking along a moving vehicle's path (the band
//! search, the steady state). Then tracking once more, frame by frame, with the frames 200 ms apart
//! as on the vehicle (each frame finds the caches cold) against back to back.

use config::{RenderParams, Scenario};
use model::{Pose, PoseRate, VehicleState, Velocity};
use std::hint::black_box;
use std::time::{Duration, Instant};
use vision::sampling::PoseSampler;
use vision::{Frame, Perception, Renderer, SimulatedVision, pace};

const FRAMES: usize = 200;
const RUNS: usize = 9;

/// Median frames per second over `RUNS` runs of `run`, which processes `FRAMES` frames.
fn fps(mut run: impl FnMut()) -> f64 {
    run(); // warm-up
    let rates: Vec<f64> = (0..RUNS)
        .map(|_| {
            let start = Instant::now();
            run();
            FRAMES as f64 / start.elapsed().as_secs_f64()
        })
        .collect();
    stats::median(rates)
}

fn main() -> std::process::ExitCode {
    // Output stops quietly when its reader goes away (`cargo bench ... | head -1`).
    match run() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => cli::fail("throughput", &e),
    }
}

fn run() -> std::io::Result<()> {
    let scenario = Scenario::default();
    let camera = model::Camera::new(&scenario.camera);
    let cable = model::Cable::new(&scenario.cable);
    let mut sampler = PoseSampler::new(2024);
    let poses: Vec<(Pose, PoseRate)> = (0..FRAMES)
        .map(|_| {
            let s = sampler.with_cable(&camera, &cable);
            (s.pose, s.rate)
        })
        .collect();
    // A path along the cable at 0.3 m/s with some sway and yaw: the tracking case.
    let path = pace::tracking_path(FRAMES, 0.2);

    cli::outln!("| what (320x240, one core) | clean: frames/s | all effects: frames/s |")?;
    cli::outln!("|---|---|---|")?;
    let mut rows: Vec<(&str, [f64; 2])> = Vec::new();
    let configs = [RenderParams::clean(), scenario.render.clone()];

    let mut render_fps = [0.0; 2];
    let mut single_fps = [0.0; 2];
    let mut track_fps = [0.0; 2];
    let mut loop_fps = [0.0; 2];
    let mut paced = None;
    for (c, params) in configs.iter().enumerate() {
        let mut renderer = Renderer::new(params, &scenario.camera, &scenario.cable, 1).unwrap();
        let mut out = vec![0u8; 320 * 240];
        render_fps[c] = fps(|| {
            for (k, (pose, rate)) in poses.iter().enumerate() {
                renderer.render(pose, rate, k as u64, &mut out).unwrap();
                black_box(&out);
            }
        });

        let frames: Vec<Frame> = poses
            .iter()
            .enumerate()
            .map(|(k, (pose, rate))| renderer.render_frame(pose, rate, k as u64))
            .collect();
        let mut perception = Perception::from_scenario(&scenario).unwrap();
        single_fps[c] = fps(|| {
            for f in &frames {
                perception.reset();
                black_box(perception.process(f.view(), 0.2).unwrap());
            }
        });

        let sequence: Vec<Frame> = pace::render_path(&mut renderer, &path);
        track_fps[c] = fps(|| {
            perception.reset();
            for f in &sequence {
                black_box(perception.process(f.view(), 0.2).unwrap());
            }
        });
        perception.reset();
        let found = sequence
            .iter()
            .filter(|f| perception.process(f.view(), 0.2).unwrap().found)
            .count();
        assert_eq!(found, FRAMES, "the tracking benchmark lost the cable");
        if c == 1 {
            paced = Some(paced_tracking(&mut perception, &sequence));
        }

        let scenario_c = Scenario {
            render: params.clone(),
            ..scenario.clone()
        };
        let mut eye = SimulatedVision::new(&scenario_c, 1).unwrap();
        loop_fps[c] = fps(|| {
            eye.reset();
            for (pose, rate) in &path {
                // The state whose pose rate is `rate` (velocity in the body frame).
                let (s, co) = pose.psi.sin_cos();
                let velocity = Velocity {
                    u: rate.x * co + rate.y * s,
                    v: -rate.x * s + rate.y * co,
                    r: rate.psi,
                };
                black_box(eye.observe(&VehicleState {
                    pose: *pose,
                    velocity,
                }));
            }
        });
    }
    rows.push(("renderer", render_fps));
    rows.push((
        "perception, each frame on its own (whole-frame search)",
        single_fps,
    ));
    rows.push(("perception, tracking along a path (band search)", track_fps));
    rows.push(("render + perceive (SimulatedVision::observe)", loop_fps));
    for (name, [clean, effects]) in rows {
        cli::outln!("| {name} | {clean:.0} | {effects:.0} |")?;
    }
    cli::outln!("\n(median of {RUNS} runs of {FRAMES} frames each)")?;
    if let Some([apart, back_to_back]) = paced {
        cli::outln!(
            "\n| perception, tracking, all effects: µs per frame | p50 | p90 |\n|---|---|---|"
        )?;
        cli::outln!(
            "| frames {} ms apart (the vehicle's pace: cold caches) | {:.0} | {:.0} |",
            PACE.as_millis(),
            apart[0],
            apart[1]
        )?;
        cli::outln!(
            "| frames back to back | {:.0} | {:.0} |",
            back_to_back[0],
            back_to_back[1]
        )?;
        cli::outln!("\n({PACED} frames each)")?;
    }
    Ok(())
}

/// The vehicle's frame period.
const PACE: Duration = Duration::from_millis(200);
/// Frames timed one by one at each pace.
const PACED: usize = 50;

/// Perception's time per frame (p50, p90 in µs) tracking along `sequence`, the frames `PACE` apart
/// (between two, the thread sleeps and the caches go cold, as on the vehicle) and back to back.
fn paced_tracking(perception: &mut Perception, sequence: &[Frame]) -> [[f64; 2]; 2] {
    let mut time = |pause: Option<Duration>| {
        let us = pace::perceive_paced(perception, &sequence[..PACED], 0.2, pause);
        [
            stats::median(us.iter().copied()),
            stats::percentile(us, 0.9),
        ]
    };
    let apart = time(Some(PACE));
    time(None); // warm-up
    [apart, time(None)]
}
