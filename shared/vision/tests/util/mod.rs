//! Shared harness: render frames at sampled poses, run perception on each frame on its own, compare
//! with the geometric camera.

#![allow(dead_code)]

use config::{RenderParams, Scenario};
use model::wrap_half_pi;
use vision::sampling::PoseSampler;
use vision::{Perception, Renderer};

/// Errors of the frames in which the cable was found, and how many frames there were.
pub struct Accuracy {
    pub frames: usize,
    pub found: usize,
    /// |Theta error| in degrees, |x_g error| as a fraction of the width, sorted.
    pub theta_deg: Vec<f64>,
    pub x_g: Vec<f64>,
}

impl Accuracy {
    pub fn detection_rate(&self) -> f64 {
        self.found as f64 / self.frames as f64
    }

    /// The q-th percentile (q in [0, 100]) of `values`: nearest rank.
    pub fn percentile(values: &[f64], q: f64) -> f64 {
        stats::percentile(values.iter().copied(), q / 100.0)
    }

    pub fn row(&self, name: &str) -> String {
        let p = Self::percentile;
        format!(
            "| {name} | {} | {:.1}% | {:.3} | {:.3} | {:.3} | {:.4} | {:.4} | {:.4} |",
            self.frames,
            100.0 * self.detection_rate(),
            p(&self.theta_deg, 50.0),
            p(&self.theta_deg, 95.0),
            self.theta_deg.last().copied().unwrap_or(f64::NAN),
            p(&self.x_g, 50.0),
            p(&self.x_g, 95.0),
            self.x_g.last().copied().unwrap_or(f64::NAN),
        )
    }
}

pub const TABLE_HEADER: &str = "| frames | n | detected | Theta p50 (deg) | p95 | max | x_g p50 | p95 | max |\n|---|---|---|---|---|---|---|---|---|";

/// Renders `n` frames at random poses with the cable in view (x_g in [-0.4, 0.4], Theta in
/// [-60, 60] degrees, random velocities for the blur) and detects each on its own.
pub fn measure(params: &RenderParams, n: usize, seed: u64) -> Accuracy {
    measure_in(&Scenario::default(), params, n, seed)
}

/// [`measure`] with another scenario's camera, cable and perception.
pub fn measure_in(scenario: &Scenario, params: &RenderParams, n: usize, seed: u64) -> Accuracy {
    let mut renderer = Renderer::new(params, &scenario.camera, &scenario.cable, seed).unwrap();
    let mut perception = Perception::from_scenario(scenario).unwrap();
    let camera = renderer.camera().clone();
    let cable = *renderer.cable();
    let mut sampler = PoseSampler::new(seed ^ 0x5eed);
    let mut acc = Accuracy {
        frames: n,
        found: 0,
        theta_deg: Vec::new(),
        x_g: Vec::new(),
    };
    for k in 0..n {
        let s = sampler.with_cable(&camera, &cable);
        let truth = camera
            .view(&s.pose, &cable)
            .expect("sampled with the cable in view");
        let frame = renderer.render_frame(&s.pose, &s.rate, k as u64);
        perception.reset();
        let obs = perception.process(frame.view(), 0.2).unwrap();
        if obs.found {
            acc.found += 1;
            acc.theta_deg
                .push(wrap_half_pi(obs.theta - truth.theta).abs().to_degrees());
            acc.x_g.push((obs.x_g - truth.x_g).abs());
        }
    }
    acc.theta_deg.sort_by(f64::total_cmp);
    acc.x_g.sort_by(f64::total_cmp);
    acc
}

/// Renders `n` frames from poses with the cable out of view and counts the frames reported found.
pub fn false_positives(params: &RenderParams, n: usize, seed: u64) -> usize {
    false_positives_in(&Scenario::default(), params, n, seed)
}

/// [`false_positives`] with another scenario's camera, cable and perception.
pub fn false_positives_in(
    scenario: &Scenario,
    params: &RenderParams,
    n: usize,
    seed: u64,
) -> usize {
    let mut renderer = Renderer::new(params, &scenario.camera, &scenario.cable, seed).unwrap();
    let mut perception = Perception::from_scenario(scenario).unwrap();
    let camera = renderer.camera().clone();
    let cable = *renderer.cable();
    let mut sampler = PoseSampler::new(seed ^ 0xfa15e);
    let mut found = 0;
    for k in 0..n {
        let s = sampler.without_cable(&camera, &cable, 1.0);
        let frame = renderer.render_frame(&s.pose, &s.rate, k as u64);
        perception.reset();
        if perception.process(frame.view(), 0.2).unwrap().found {
            found += 1;
        }
    }
    found
}
