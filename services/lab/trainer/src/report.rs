//! The two-step job's report: the paper's figures and a table of returns, from what the runs left in
//! one directory (`scripts/two-step-learning` lays it out):
//!
//! ```text
//! DIR/fig5/fig5.json                 step one's learning curves over 100 runs (trainer fig5)
//! DIR/step-one/run.json, *.ckpt      step one through the mesh: per-episode returns, the policies
//! DIR/eval-sim/run.json              the simulation policy on the twin with its reality gap off
//!                                    (the simulation from the vehicle's starts), not learning
//! DIR/eval/run.json, trace.jsonl     the simulation policy on the vehicle (twin), not learning
//! DIR/step-two/run.json, trace.jsonl, *.ckpt   online learning on the vehicle: per trial
//! ```
//!
//! It writes `DIR/report/report.md` with its PNG figures, and `DIR/summary.json`.

use crate::figures::{Fig5, PolicyMap, write_json};
use anyhow::{Context, Result};
use config::{Dof, Scenario};
use learning::checkpoint::Checkpoint;
use monitor::{RunRecord, TracePoint};
use plot::{Figure, LineChart, Panel, Series};
use serde::Serialize;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// `DIR/summary.json`: per-episode returns in simulation, per-trial returns on the vehicle.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Summary {
    pub sim: Returns,
    pub vehicle: Returns,
    /// The simulation policy on the vehicle before learning there (Figs. 8, 9).
    pub vehicle_before_learning: Returns,
    /// The simulation policy from the vehicle's starts with the reality gap off, when it was run.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sim_from_vehicle_starts: Option<Returns>,
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Returns {
    pub yaw: Vec<f64>,
    pub sway: Vec<f64>,
}

impl From<&RunRecord> for Returns {
    fn from(r: &RunRecord) -> Self {
        Returns {
            yaw: r.yaw.clone(),
            sway: r.sway.clone(),
        }
    }
}

fn read_json<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    serde_json::from_str(&text).with_context(|| format!("parsing {}", path.display()))
}

/// The traces of a run, by episode.
fn read_trace(path: &Path) -> Result<BTreeMap<u32, Vec<TracePoint>>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let mut by_episode: BTreeMap<u32, Vec<TracePoint>> = BTreeMap::new();
    for (i, line) in text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
    {
        let p: TracePoint = serde_json::from_str(line)
            .with_context(|| format!("{}: line {}", path.display(), i + 1))?;
        by_episode.entry(p.episode).or_default().push(p);
    }
    for points in by_episode.values_mut() {
        points.sort_by_key(|p| p.step);
        points.dedup_by_key(|p| p.step);
    }
    Ok(by_episode)
}

/// For each trial of `trials`, the attempt of `attempts` that started from the same pose (the same
/// first observation, to 0.01 in x_g and in Theta), if any: the twin's trials cycle through a few
/// start poses, so an attempt of the simulation policy and a learning trial can start alike.
pub fn same_starts(
    trials: &BTreeMap<u32, Vec<TracePoint>>,
    attempts: &BTreeMap<u32, Vec<TracePoint>>,
    n_trials: usize,
) -> Vec<Option<usize>> {
    let start = |points: &Vec<TracePoint>| points.first().map(|p| (p.x_g, p.theta));
    (0..n_trials as u32)
        .map(|t| {
            let (x, th) = trials.get(&t).and_then(start)?;
            attempts
                .iter()
                .filter_map(|(e, p)| start(p).map(|s| (*e as usize, s)))
                .find(|(_, (ax, ath))| (ax - x).abs() < 0.01 && (ath - th).abs() < 0.01)
                .map(|(e, _)| e)
        })
        .collect()
}

fn gains(path: &Path) -> Result<Vec<(Dof, [f64; 2])>> {
    let ckpt = Checkpoint::load(path)?;
    Ok(Dof::ALL
        .iter()
        .filter_map(|&d| ckpt.get(d).map(|s| (d, s.policy.gain)))
        .collect())
}

/// Theta and x_g over time for some episodes of a trace: the paper's state-trace figures.
fn traces(title: &str, fig: (&str, &str), episodes: &[(String, &Vec<TracePoint>)]) -> Figure {
    let series = |f: fn(&TracePoint) -> f64| {
        episodes
            .iter()
            .map(|(name, points)| {
                let seen: Vec<&TracePoint> = points.iter().filter(|p| p.found).collect();
                Series::new(
                    name.clone(),
                    seen.iter().map(|p| p.time_s).collect(),
                    seen.iter().map(|p| f(p)).collect(),
                )
            })
            .collect()
    };
    let chart = |label: &str, y: &str, s| {
        let mut c = LineChart::new(format!("{label}: {title}"), "time (s)", y);
        c.series = s;
        Panel::Lines(c)
    };
    Figure::new(
        vec![
            chart(fig.0, "Theta (deg)", series(|p| p.theta.to_degrees())),
            chart(fig.1, "x_g", series(|p| p.x_g)),
        ],
        2,
    )
}

fn mean(v: &[f64]) -> f64 {
    stats::mean(v.iter().copied())
}

/// Writes the report of `dir`; returns the path of `report.md`.
pub fn write(dir: &Path, scenario: &Scenario) -> Result<PathBuf> {
    let out = dir.join("report");
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let sim: RunRecord = read_json(&dir.join("step-one/run.json"))?;
    let eval: RunRecord = read_json(&dir.join("eval/run.json"))?;
    let vehicle: RunRecord = read_json(&dir.join("step-two/run.json"))?;
    let mut md = String::new();
    writeln!(md, "# Two-step NAC learning for cable tracking: report\n")?;
    writeln!(
        md,
        "Step one: {} episodes in simulation, every service a process. Step two: the simulation policy on the \
         vehicle (its twin) for {} trials without learning, then {} trials of online learning.\n",
        sim.episodes, eval.episodes, vehicle.episodes
    )?;

    // Fig. 5.
    let fig5_json = dir.join("fig5/fig5.json");
    if fig5_json.exists() {
        let fig5: Fig5 = read_json(&fig5_json)?;
        fig5.figure().save_png(&out.join("fig5.png"))?;
        writeln!(md, "## Fig. 5: learning curves in simulation\n")?;
        writeln!(
            md,
            "NAC against Baxter and Bartlett's policy gradient, {} runs of {} episodes (in one process), with the \
             LQR limit.\n\n![Fig. 5](fig5.png)\n",
            fig5.runs, fig5.episodes
        )?;
    }
    let step_one = |dof: Dof, r: &RunRecord| {
        let v = if dof == Dof::Yaw { &r.yaw } else { &r.sway };
        let mut c = LineChart::new(
            format!("{dof}: return per episode"),
            "episode",
            "total reward",
        );
        c.series = vec![Series::from_y("step one, the mesh", v.clone())];
        Panel::Lines(c)
    };
    Figure::new(vec![step_one(Dof::Yaw, &sim), step_one(Dof::Sway, &sim)], 2)
        .save_png(&out.join("step-one.png"))?;
    writeln!(
        md,
        "Step one through the service mesh (this run):\n\n![step one](step-one.png)\n"
    )?;

    // Figs. 6, 7, 12, 13: the policies.
    let maps = |ckpt_dir: &Path,
                figs: (&str, &str),
                when: &str,
                file: &str,
                md: &mut String|
     -> Result<()> {
        let mut panels = Vec::new();
        for (dof, file_name) in [(Dof::Sway, "sway.ckpt"), (Dof::Yaw, "yaw.ckpt")] {
            for (d, gain) in gains(&ckpt_dir.join(file_name))? {
                if d == dof {
                    let fig = if dof == Dof::Sway { figs.0 } else { figs.1 };
                    panels.push(
                        PolicyMap::new(dof, gain, scenario, 41)
                            .panel(&format!("{fig}, {dof} {when}")),
                    );
                }
            }
        }
        Figure::new(panels, 2).save_png(&out.join(file))?;
        writeln!(md, "![{when}]({file})\n")?;
        Ok(())
    };
    writeln!(md, "## Figs. 6 and 7: the policies learned in simulation\n")?;
    maps(
        &dir.join("step-one"),
        ("Fig. 6", "Fig. 7"),
        "after simulation",
        "policy-sim.png",
        &mut md,
    )?;

    // Figs. 8, 9: the simulation policy on the vehicle.
    let eval_trace = read_trace(&dir.join("eval/trace.jsonl"))?;
    let eps: Vec<(String, &Vec<TracePoint>)> = eval_trace
        .iter()
        .map(|(e, p)| (format!("attempt {}", e + 1), p))
        .collect();
    traces(
        "simulation policy on the vehicle",
        ("Fig. 8", "Fig. 9"),
        &eps,
    )
    .save_png(&out.join("twin-sim-policy.png"))?;
    writeln!(
        md,
        "## Figs. 8 and 9: the simulation policy on the vehicle\n"
    )?;
    let sim_tail = sim.episodes.saturating_sub(10)..sim.episodes;
    let sim_per_step = sim.per_step(sim_tail.clone());
    let eval_per_step = eval.per_step(0..eval.episodes);
    let per_step = |v: Option<f64>| v.map_or("–".to_owned(), |v| format!("{v:.5}"));
    let eval_sim_json = dir.join("eval-sim/run.json");
    let eval_sim: Option<RunRecord> = if eval_sim_json.exists() {
        Some(read_json(&eval_sim_json)?)
    } else {
        None
    };
    writeln!(
        md,
        "Mean return per attempt: yaw {:.3}, sway {:.4}; cable lost in {} of {} attempts.\n",
        mean(&eval.yaw),
        mean(&eval.sway),
        eval.lost.iter().filter(|l| **l).count(),
        eval.episodes,
    )?;
    match &eval_sim {
        Some(es) => writeln!(
            md,
            "The same policy from the same starts with the reality gap off (the twin as the identified model with \
             the simulator's images): yaw {:.3}, sway {:.4} per attempt. Per step, vehicle against simulation: \
             yaw {} against {}, sway {} against {}.\n",
            mean(&es.yaw),
            mean(&es.sway),
            per_step(eval_per_step.map(|p| p.0)),
            per_step(es.per_step(0..es.episodes).map(|p| p.0)),
            per_step(eval_per_step.map(|p| p.1)),
            per_step(es.per_step(0..es.episodes).map(|p| p.1)),
        )?,
        None => writeln!(
            md,
            "Per step, on the vehicle against the last {} episodes of step one in simulation (other starts): yaw {} \
             against {}, sway {} against {}.\n",
            sim_tail.len(),
            per_step(eval_per_step.map(|p| p.0)),
            per_step(sim_per_step.map(|p| p.0)),
            per_step(eval_per_step.map(|p| p.1)),
            per_step(sim_per_step.map(|p| p.1)),
        )?,
    }
    writeln!(md, "![Figs. 8 and 9](twin-sim-policy.png)\n")?;

    // Figs. 10, 11: improvement over trials.
    let trial_trace = read_trace(&dir.join("step-two/trace.jsonl"))?;
    let n = vehicle.episodes.max(1) as u32;
    let mut picks: Vec<u32> = vec![0, n / 4, n / 2, n - 1];
    picks.dedup();
    let eps: Vec<(String, &Vec<TracePoint>)> = picks
        .iter()
        .filter_map(|e| trial_trace.get(e).map(|p| (format!("trial {}", e + 1), p)))
        .collect();
    traces("learning on the vehicle", ("Fig. 10", "Fig. 11"), &eps)
        .save_png(&out.join("step-two-traces.png"))?;
    let starts = same_starts(&trial_trace, &eval_trace, vehicle.episodes);
    let per_trial = |dof: Dof| {
        let v = if dof == Dof::Yaw {
            &vehicle.yaw
        } else {
            &vehicle.sway
        };
        let x: Vec<f64> = (1..=v.len()).map(|t| t as f64).collect();
        let mut c = LineChart::new(
            format!("{dof}: return per trial on the vehicle"),
            "trial",
            "total reward",
        );
        let before = if dof == Dof::Yaw {
            &eval.yaw
        } else {
            &eval.sway
        };
        c.series = vec![Series::new("online learning", x.clone(), v.clone())];
        // Returns depend most on where a trial starts: beside each trial, the simulation policy's
        // attempt from the same start; without one, its mean.
        let matched: Vec<(f64, f64)> = x
            .iter()
            .zip(&starts)
            .filter_map(|(t, m)| m.and_then(|e| before.get(e)).map(|r| (*t, *r)))
            .collect();
        if matched.len() == v.len() {
            c.series.push(Series::new(
                "simulation policy from the same start, not learning",
                matched.iter().map(|m| m.0).collect(),
                matched.iter().map(|m| m.1).collect(),
            ));
        } else {
            c.ref_lines = vec![plot::RefLine::new(
                "simulation policy, not learning (mean)",
                mean(before),
            )];
        }
        Panel::Lines(c)
    };
    Figure::new(vec![per_trial(Dof::Yaw), per_trial(Dof::Sway)], 2)
        .save_png(&out.join("step-two-returns.png"))?;
    let k = (vehicle.episodes / 4).max(1);
    writeln!(
        md,
        "## Figs. 10 and 11: policy improvement on the vehicle\n"
    )?;
    writeln!(
        md,
        "Mean return of the first {k} trials: yaw {:.3}, sway {:.4}; of the last {k}: yaw {:.3}, sway {:.4}.\n\n\
         ![Figs. 10 and 11](step-two-traces.png)\n\n![returns per trial](step-two-returns.png)\n",
        mean(&vehicle.yaw[..k]),
        mean(&vehicle.sway[..k]),
        mean(&vehicle.yaw[vehicle.yaw.len() - k..]),
        mean(&vehicle.sway[vehicle.sway.len() - k..]),
    )?;
    writeln!(
        md,
        "## Figs. 12 and 13: the policies after learning on the vehicle\n"
    )?;
    maps(
        &dir.join("step-two"),
        ("Fig. 12", "Fig. 13"),
        "after vehicle learning",
        "policy-vehicle.png",
        &mut md,
    )?;

    writeln!(md, "## Returns per trial on the vehicle\n")?;
    writeln!(
        md,
        "| trial | steps | cable lost | yaw return | sway return | simulation policy from the same start: yaw | sway |\n\
         |---:|---:|:---:|---:|---:|---:|---:|"
    )?;
    for t in 0..vehicle.episodes {
        let steps = trial_trace.get(&(t as u32)).map_or(0, |p| p.len());
        let (same_yaw, same_sway) = match starts.get(t).copied().flatten() {
            Some(e) => (
                format!("{:.3}", eval.yaw[e]),
                format!("{:.4}", eval.sway[e]),
            ),
            None => ("–".to_owned(), "–".to_owned()),
        };
        writeln!(
            md,
            "| {} | {} | {} | {:.3} | {:.4} | {same_yaw} | {same_sway} |",
            t + 1,
            steps,
            if vehicle.lost[t] { "yes" } else { "" },
            vehicle.yaw[t],
            vehicle.sway[t]
        )?;
    }
    let path = out.join("report.md");
    std::fs::write(&path, md).with_context(|| format!("writing {}", path.display()))?;
    let summary = Summary {
        sim: (&sim).into(),
        vehicle: (&vehicle).into(),
        vehicle_before_learning: (&eval).into(),
        sim_from_vehicle_starts: eval_sim.as_ref().map(Into::into),
    };
    write_json(&dir.join("summary.json"), &summary).with_context(|| "writing summary.json")?;
    Ok(path)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn trace(starts: &[(f64, f64)]) -> BTreeMap<u32, Vec<TracePoint>> {
        starts
            .iter()
            .enumerate()
            .map(|(e, &(x_g, theta))| {
                let p = |step: u32| TracePoint {
                    episode: e as u32,
                    step,
                    time_s: step as f64 * 0.2,
                    found: true,
                    x_g: x_g + step as f64,
                    theta,
                };
                (e as u32, vec![p(0), p(1)])
            })
            .collect()
    }

    #[test]
    fn trials_are_matched_to_the_attempt_from_the_same_start() {
        let attempts = trace(&[(0.1, 0.3), (-0.2, -0.5)]);
        // Cycling through the two starts, a perception error away; the last start is new.
        let trials = trace(&[(0.1004, 0.2999), (-0.2, -0.501), (0.1, 0.3), (0.3, 0.3)]);
        assert_eq!(
            same_starts(&trials, &attempts, 5),
            vec![Some(0), Some(1), Some(0), None, None]
        );
    }
}
