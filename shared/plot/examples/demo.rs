//! Draws an example figure of made-up data shaped like the reproduction's results: learning curves of
//! yaw and sway with ±std bands and the LQR limit, Theta traces of several trials, and a sway policy
//! map.
//!
//! `cargo run -p plot --release --example demo [-- OUT.png]` (default `/tmp/plot-demo.png`).

use plot::{Figure, Heatmap, LineChart, Panel, RefLine, Series};
use std::path::PathBuf;

/// A small deterministic noise source (xorshift), so the example needs no random-number crate.
struct Noise(u64);

impl Noise {
    /// Roughly standard normal (sum of uniforms).
    fn normal(&mut self) -> f64 {
        (0..12)
            .map(|_| {
                self.0 ^= self.0 << 13;
                self.0 ^= self.0 >> 7;
                self.0 ^= self.0 << 17;
                (self.0 >> 11) as f64 / (1u64 << 53) as f64
            })
            .sum::<f64>()
            - 6.0
    }
}

/// Mean and std over runs of a return that rises from `start` towards `limit` at `rate` per episode.
fn learning(
    noise: &mut Noise,
    episodes: usize,
    start: f64,
    limit: f64,
    rate: f64,
) -> (Vec<f64>, Vec<f64>) {
    let gap = limit - start;
    let mean = (0..episodes)
        .map(|e| limit - gap * (-(e as f64) * rate).exp() + 0.6 * noise.normal())
        .collect();
    let std = (0..episodes)
        .map(|e| {
            2.0 + 0.25 * gap.abs() * (-(e as f64) * rate * 0.8).exp() + 0.3 * noise.normal().abs()
        })
        .collect();
    (mean, std)
}

fn learning_chart(noise: &mut Noise, dof: &str, limit: f64) -> LineChart {
    let episodes = 300;
    let (nac, nac_std) = learning(noise, episodes, limit - 90.0, limit - 1.5, 1.0 / 35.0);
    let (gpomdp, gpomdp_std) = learning(noise, episodes, limit - 90.0, limit - 12.0, 1.0 / 110.0);
    LineChart {
        series: vec![
            Series::from_y("NAC", nac).with_band(nac_std),
            Series::from_y("OLPOMDP", gpomdp).with_band(gpomdp_std),
        ],
        ref_lines: vec![RefLine::new("LQR optimum", limit)],
        ..LineChart::new(format!("{dof}: learning"), "Episode", "Mean return")
    }
}

fn theta_traces(noise: &mut Noise) -> LineChart {
    let dt = 0.1;
    let series = (0..5)
        .map(|trial| {
            let theta0 = 0.5 * noise.normal().clamp(-1.8, 1.8);
            let (t, theta): (Vec<f64>, Vec<f64>) = (0..300)
                .map(|k| {
                    let t = k as f64 * dt;
                    let decay = (-t / 5.0).exp();
                    (t, theta0 * decay * (0.9 * t).cos() + 0.01 * noise.normal())
                })
                .unzip();
            Series::new(format!("trial {}", trial + 1), t, theta)
        })
        .collect();
    LineChart {
        series,
        ..LineChart::new("Yaw: Theta after learning", "Time [s]", "Theta [rad]")
    }
}

fn sway_policy() -> Heatmap {
    let (x_range, y_range) = ((-0.5, 0.5), (-0.5, 0.5));
    Heatmap {
        title: "Sway: learned policy".into(),
        x_label: "x_g".into(),
        y_label: "dx_g/dt".into(),
        x_range,
        y_range,
        values: Heatmap::sample(x_range, y_range, (60, 60), |x, dx| {
            (-2.6 * x - 1.4 * dx).tanh()
        }),
        value_range: (-1.0, 1.0),
        value_label: "Action".into(),
    }
}

fn main() {
    let out = std::env::args_os()
        .nth(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("/tmp/plot-demo.png"));
    let mut noise = Noise(0x9e37_79b9_7f4a_7c15);
    let figure = Figure::new(
        vec![
            Panel::Lines(learning_chart(&mut noise, "Yaw", -18.0)),
            Panel::Lines(learning_chart(&mut noise, "Sway", -31.0)),
            Panel::Lines(theta_traces(&mut noise)),
            Panel::Heat(sway_policy()),
        ],
        2,
    );
    let start = std::time::Instant::now();
    if let Err(e) = figure.save_png(&out) {
        eprintln!("error: {e}");
        std::process::exit(1);
    }
    println!("wrote {} in {:.0?}", out.display(), start.elapsed());
}
