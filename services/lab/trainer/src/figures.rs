//! The paper's simulation figures as data (JSON) and pictures (PNG).

use crate::experiment::Curve;
use config::{Dof, PerDof, Scenario};
use plot::{Figure, Heatmap, LineChart, Panel, RefLine, Series};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Fig. 5: the learning curves of NAC and the baseline over independent runs, with the LQR limit.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Fig5 {
    pub episodes: usize,
    pub runs: usize,
    pub seed: u64,
    pub nac: PerDof<Curve>,
    pub gpomdp: PerDof<Curve>,
    /// The LQR policy's mean return.
    pub limit: PerDof<f64>,
    /// The learning rates used.
    pub alpha: Alphas,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Alphas {
    pub nac: PerDof<f64>,
    pub gpomdp: PerDof<f64>,
}

impl Fig5 {
    /// Both DOFs' learning curves, side by side, as in the paper (which shows yaw).
    pub fn figure(&self) -> Figure {
        let panel = |dof: Dof| {
            let x: Vec<f64> = (1..=self.episodes).map(|e| e as f64).collect();
            // The band is the standard error of the mean: it shows whether the curves differ (the
            // spread of single runs, the std, is in fig5.json).
            let sqrt_runs = (self.runs.max(1) as f64).sqrt();
            let series = |name: String, c: &Curve| Series {
                name,
                x: x.clone(),
                y: c.mean.clone(),
                band: Some(c.std.iter().map(|s| s / sqrt_runs).collect()),
            };
            Panel::Lines(LineChart {
                title: format!(
                    "{dof}: mean return over {} runs (band: ±1 standard error)",
                    self.runs
                ),
                x_label: "episode".into(),
                y_label: "total reward per episode".into(),
                series: vec![
                    series(
                        format!("NAC (alpha {})", self.alpha.nac.get(dof)),
                        self.nac.get(dof),
                    ),
                    series(
                        format!("OLPOMDP (alpha {})", self.alpha.gpomdp.get(dof)),
                        self.gpomdp.get(dof),
                    ),
                ],
                ref_lines: vec![RefLine {
                    name: "LQR limit".into(),
                    y: *self.limit.get(dof),
                }],
                y_range: None,
            })
        };
        Figure {
            panels: vec![panel(Dof::Yaw), panel(Dof::Sway)],
            columns: 2,
            panel_size: (640, 440),
        }
    }
}

/// A policy's mean action over its state box (Figs. 6, 7, 12, 13).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PolicyMap {
    pub dof: Dof,
    pub gain: [f64; 2],
    /// The state box: position and rate ranges.
    pub x_range: (f64, f64),
    pub rate_range: (f64, f64),
    /// Mean action clipped to [-1, 1]; rows over the rate (first row = lowest), columns over position.
    pub actions: Vec<Vec<f64>>,
}

impl PolicyMap {
    pub fn new(dof: Dof, gain: [f64; 2], scenario: &Scenario, cells: usize) -> Self {
        let max = scenario.state_max(dof);
        let at = |i: usize, m: f64| -m + 2.0 * m * (i as f64 + 0.5) / cells as f64;
        let actions = (0..cells)
            .map(|row| {
                let rate = at(row, max[1]);
                (0..cells)
                    .map(|col| (gain[0] * at(col, max[0]) + gain[1] * rate).clamp(-1.0, 1.0))
                    .collect()
            })
            .collect();
        PolicyMap {
            dof,
            gain,
            x_range: (-max[0], max[0]),
            rate_range: (-max[1], max[1]),
            actions,
        }
    }

    pub fn panel(&self, title: &str) -> Panel {
        let (x_label, y_label) = match self.dof {
            Dof::Sway => ("x_g", "dx_g/dt (1/s)"),
            Dof::Yaw => ("Theta (rad)", "dTheta/dt (rad/s)"),
        };
        Panel::Heat(Heatmap {
            title: format!("{title}: K = [{:.3}, {:.3}]", self.gain[0], self.gain[1]),
            x_label: x_label.into(),
            y_label: y_label.into(),
            x_range: self.x_range,
            y_range: self.rate_range,
            values: self.actions.clone(),
            value_range: (-1.0, 1.0),
            value_label: format!("u_{}", self.dof),
        })
    }
}

/// Writes `value` as pretty JSON, atomically (a crash never leaves half a file).
pub fn write_json(path: &Path, value: &impl Serialize) -> std::io::Result<()> {
    let text = serde_json::to_string_pretty(value).map_err(std::io::Error::other)?;
    let tmp = path.with_extension("json.tmp");
    std::fs::write(&tmp, text)?;
    std::fs::rename(&tmp, path)
}
