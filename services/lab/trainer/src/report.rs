//! The two-step job's report: the paper's figures and a table of returns, from what the runs left in
//! one directory (`scripts/two-step-learning` lays it out):
//!
//! ```text
//! DIR/fig5/fig5.json                 step one's learning curves over 100 runs (trainer fig5)
//! DIR/step-one/run.json, *.ckpt      step one through the mesh: per-episode returns, the policies
//! DIR/twin-limit/limit.json          the twin's limit (trainer twin-limit: searched with images,
//! DIR/twin-limit/{sway,yaw}/*.ckpt   each DOF's pair; checked against the simulation policy and
//!                                    step two's; the policies on held-out sets, with the cables lost)
//! DIR/eval-sim/run.json              evaluations through the vehicle mesh (the evaluation set: the
//! DIR/eval/run.json, trace.jsonl     twin's first start marks, fixed noise, not learning): the
//! DIR/eval-limit-sway/run.json       simulation policy with the reality gap off, the simulation
//! DIR/eval-limit-yaw/run.json        policy on the vehicle (twin), each DOF's limit pair on it,
//! DIR/eval-after/run.json            the policy step two ended with
//! DIR/step-two/run.json, trace.jsonl, *.ckpt   step two on the vehicle: learning trials and the
//!                                    session's own evaluations
//! ```
//!
//! It writes `DIR/report/report.md` with its PNG figures, and `DIR/summary.json`.

use crate::evaluation::gap_closed;
use crate::figures::{Fig5, PolicyMap, write_json};
use crate::twin_limit::{Beaten, Candidate, LimitGains, beaten};
use anyhow::{Context, Result, bail};
use config::{Dof, PerDof, Scenario};
use learning::checkpoint::Checkpoint;
use plot::{Figure, LineChart, Panel, RefLine, Series};
use records::{EvaluationRecord, RunRecord, SafetyCounts, TracePoint};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// The job's three policies as the summary names them (`evaluation.PART`, `held_out.PART`), with
/// each DOF's policy directory in the job's directory (the limit's: each DOF's own pair).
pub const POLICIES: [(&str, PerDof<&str>); 3] = [
    (
        "sim_policy",
        PerDof {
            sway: "step-one",
            yaw: "step-one",
        },
    ),
    (
        "limit",
        PerDof {
            sway: "twin-limit/sway",
            yaw: "twin-limit/yaw",
        },
    ),
    (
        "after",
        PerDof {
            sway: "step-two",
            yaw: "step-two",
        },
    ),
];

/// The name of `dof`'s limit pair among the held-out policies `twin-limit/limit.json` records.
pub fn held_out_limit_name(dof: Dof) -> String {
    format!("limit for {dof}")
}

/// `DIR/summary.json`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Summary {
    /// Step one: each episode's returns in simulation.
    pub sim: Returns,
    /// Step two: each learning trial's returns (the policy learning as it acted).
    pub learning_trials: Returns,
    /// The simulation policy on the vehicle before learning there, trial by trial (Figs. 8, 9).
    pub vehicle_before_learning: Returns,
    /// The simulation policy from the vehicle's starts with the reality gap off, when it was run.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sim_from_vehicle_starts: Option<Returns>,
    /// The twin's limit: its evaluated returns and each DOF's pair.
    pub twin_limit: TwinLimit,
    /// The evaluations (the protocol: the evaluation set, not learning).
    pub evaluation: Evaluations,
    /// `(J_after - J_sim) / (J_limit - J_sim)` per DOF.
    pub gap_closed: PerDof<f64>,
    /// Where `|J_limit - J_sim|` is under 5% of `|J_sim|` the ratio is noise.
    pub gap_is_noise: PerDof<bool>,
    /// The simulation policy, step two's and the limit on held-out sets (other starts, floors and
    /// noise), with the gap closed there; when the limit's run evaluated them.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub held_out: Option<HeldOutSummary>,
    /// Whether the limit is above the policies evaluated beside it, beyond the evaluation's noise.
    pub limit_check: LimitCheck,
    /// Each behaviour's safety layer over step two.
    pub safety: PerDof<SafetyCounts>,
    /// Trials of step two that lost the cable: learning trials, evaluation trials.
    pub lost: Lost,
}

/// A policy on the held-out sets.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HeldOutPolicy {
    pub name: String,
    /// Each set's evaluated return.
    pub returns: PerDof<Vec<f64>>,
    pub mean: PerDof<f64>,
    pub lost: u32,
    pub trials: u32,
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct HeldOutSummary {
    /// The sets' seeds.
    pub sets: Vec<u64>,
    pub sim_policy: HeldOutPolicy,
    pub after: HeldOutPolicy,
    /// Each DOF's return under its own limit pair (the cables and trials: both pairs').
    pub limit: HeldOutPolicy,
    /// The gap closed on them (their mean returns).
    pub gap_closed: PerDof<f64>,
    /// The evaluation's noise on a difference the limit's check allowed: the largest spread over
    /// the sets of a difference between two policies its run evaluated there before its search.
    pub noise: PerDof<f64>,
}

/// The limit against the policies evaluated beside it on the evaluation set (J_sim, J_after).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct LimitCheck {
    /// The evaluation's noise on a difference (NaN: not measured, any margin counts).
    pub noise: PerDof<f64>,
    /// Per DOF, the policy above the limit by more than twice the noise, and by how much.
    pub beaten: PerDof<Option<Beaten>>,
    /// The perception the limit was searched with.
    pub searched_with: Option<String>,
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TwinLimit {
    pub yaw: f64,
    pub sway: f64,
    pub gains: LimitGains,
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Evaluations {
    /// Trials per evaluation.
    pub trials: usize,
    /// The simulation policy, the policy step two ended with and the twin's limit, each evaluated
    /// through the vehicle mesh.
    pub sim_policy: PerDof<f64>,
    pub after: PerDof<f64>,
    pub limit: PerDof<f64>,
    /// Step two's own evaluations: before learning, then after every few learning trials.
    pub curve: Vec<EvaluationRecord>,
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Lost {
    pub learning: usize,
    pub evaluation: usize,
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

/// The evaluated return of an evaluation run: the mean over its trials, per DOF.
pub fn evaluated(r: &RunRecord) -> PerDof<f64> {
    PerDof {
        sway: mean(&r.sway),
        yaw: mean(&r.yaw),
    }
}

/// Step two's learning trials (not the evaluation trials) of a session's record: their numbers in
/// the session.
pub fn learning_trials(r: &RunRecord) -> Vec<usize> {
    (0..r.episodes)
        .filter(|&t| !r.evaluation.get(t).copied().unwrap_or(false))
        .collect()
}

/// Whether the gap between `sim` and `limit` is too small for its ratio to mean anything: under 5%
/// of `|sim|`.
pub fn gap_is_noise(sim: f64, limit: f64) -> bool {
    (limit - sim).abs() < 0.05 * sim.abs()
}

/// The limit against the simulation policy and step two's on one set (each evaluated return with
/// the trials in which it lost the cable; the limit's per DOF, each its own pair's): per DOF, the
/// one above it by more than twice `noise` (see [`crate::twin_limit::beaten`]).
pub fn limit_check(
    sim: (PerDof<f64>, u32),
    after: (PerDof<f64>, u32),
    limit: (PerDof<f64>, PerDof<u32>),
    noise: PerDof<f64>,
) -> PerDof<Option<Beaten>> {
    let policies = [("the simulation policy", sim), ("step two's policy", after)].map(
        |(name, (evaluated, lost))| Candidate {
            name: name.to_owned(),
            gains: PerDof::default(),
            evaluated,
            lost,
        },
    );
    beaten(limit.0, limit.1, &policies, noise)
}

/// The trials of a run that lost the cable.
fn lost_in(r: &RunRecord) -> u32 {
    r.lost.iter().filter(|l| **l).count() as u32
}

/// What `twin-limit/limit.json` says of the held-out sets: the sets and each policy's returns.
fn read_held_out(limit_json: &serde_json::Value) -> Result<Option<(Vec<u64>, Vec<HeldOutPolicy>)>> {
    let h = &limit_json["held_out"];
    if h.is_null() || h["sets"].as_array().is_none_or(|s| s.is_empty()) {
        return Ok(None);
    }
    let sets: Vec<u64> = serde_json::from_value(h["sets"].clone())
        .context("twin-limit/limit.json: held_out.sets")?;
    let policies: Vec<HeldOutPolicy> = serde_json::from_value(h["policies"].clone())
        .context("twin-limit/limit.json: held_out.policies")?;
    Ok(Some((sets, policies)))
}

/// The limit on the held-out sets from each DOF's pair there: each DOF's returns under its own
/// pair, the cables and trials of both.
fn limit_on_sets(sway: &HeldOutPolicy, yaw: &HeldOutPolicy) -> HeldOutPolicy {
    HeldOutPolicy {
        name: "limit".to_owned(),
        returns: PerDof {
            sway: sway.returns.sway.clone(),
            yaw: yaw.returns.yaw.clone(),
        },
        mean: PerDof {
            sway: sway.mean.sway,
            yaw: yaw.mean.yaw,
        },
        lost: sway.lost + yaw.lost,
        trials: sway.trials + yaw.trials,
    }
}

/// The noise the limit's check allowed, as `limit.json` records it (`null`: not measured).
fn recorded_check_noise(limit_json: &serde_json::Value) -> Result<PerDof<f64>> {
    let n: PerDof<Option<f64>> = serde_json::from_value(limit_json["check"]["noise"].clone())
        .context("twin-limit/limit.json: check.noise")?;
    Ok(PerDof {
        sway: n.sway.unwrap_or(f64::NAN),
        yaw: n.yaw.unwrap_or(f64::NAN),
    })
}

/// Writes the report of `dir`; returns the path of `report.md`.
pub fn write(dir: &Path, scenario: &Scenario) -> Result<PathBuf> {
    let out = dir.join("report");
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let sim: RunRecord = read_json(&dir.join("step-one/run.json"))?;
    let eval: RunRecord = read_json(&dir.join("eval/run.json"))?;
    let eval_limit = PerDof {
        sway: read_json::<RunRecord>(&dir.join("eval-limit-sway/run.json"))?,
        yaw: read_json::<RunRecord>(&dir.join("eval-limit-yaw/run.json"))?,
    };
    let limit_lost = eval_limit.map(|_, r| lost_in(r));
    let eval_after: RunRecord = read_json(&dir.join("eval-after/run.json"))?;
    let session: RunRecord = read_json(&dir.join("step-two/run.json"))?;
    let limit_json: serde_json::Value = read_json(&dir.join("twin-limit/limit.json"))?;
    let limit_gains: LimitGains = serde_json::from_value(limit_json["gains"].clone())
        .context("twin-limit/limit.json: gains (each DOF's pair)")?;
    if session.evaluations.is_empty() {
        bail!(
            "{}: step two evaluated nothing (learning.toml's evaluation.trials is 0?)",
            dir.join("step-two/run.json").display()
        );
    }
    let learning = learning_trials(&session);
    let (j_sim, j_after, j_limit) = (
        evaluated(&eval),
        evaluated(&eval_after),
        eval_limit.map(|dof, r| *evaluated(r).get(dof)),
    );
    let closed = PerDof::from_fn(|d| gap_closed(*j_sim.get(d), *j_after.get(d), *j_limit.get(d)));
    let noise = PerDof {
        sway: gap_is_noise(j_sim.sway, j_limit.sway),
        yaw: gap_is_noise(j_sim.yaw, j_limit.yaw),
    };
    // The held-out sets, as the limit's run evaluated the job's policies on them (the job names them
    // sim, after, and the limit's pairs `limit for sway` and `limit for yaw`).
    let held_out = match read_held_out(&limit_json)? {
        Some((sets, policies)) => {
            let find = |name: &str| {
                policies
                    .iter()
                    .find(|p| p.name == name)
                    .cloned()
                    .with_context(|| format!("twin-limit/limit.json: no held-out policy `{name}`"))
            };
            let (s, a) = (find("sim")?, find("after")?);
            let l = limit_on_sets(
                &find(&held_out_limit_name(Dof::Sway))?,
                &find(&held_out_limit_name(Dof::Yaw))?,
            );
            Some(HeldOutSummary {
                gap_closed: PerDof::from_fn(|d| {
                    gap_closed(*s.mean.get(d), *a.mean.get(d), *l.mean.get(d))
                }),
                // The noise the limit's run checked with (its candidates and the search's start on
                // these sets), as it recorded it: the report judges as the run did.
                noise: recorded_check_noise(&limit_json)?,
                sets,
                sim_policy: s,
                after: a,
                limit: l,
            })
        }
        None => None,
    };
    let check_noise = held_out
        .as_ref()
        .map_or(PerDof::both(f64::NAN), |h| h.noise);
    let limit_check = LimitCheck {
        noise: check_noise,
        beaten: limit_check(
            (j_sim, lost_in(&eval)),
            (j_after, lost_in(&eval_after)),
            (j_limit, limit_lost),
            check_noise,
        ),
        searched_with: limit_json["eyes"].as_str().map(str::to_owned),
    };

    let mut md = String::new();
    writeln!(md, "# Two-step NAC learning for cable tracking: report\n")?;
    writeln!(
        md,
        "Step one: {} episodes in simulation, every service a process. Step two on the vehicle (its twin): {} learning \
         trials, with an evaluation of the policy before the first and after every few ({} evaluations of {} trials: {} \
         trials in all). An evaluation is the protocol every policy here is measured by: the policy acts without \
         learning over a fixed set of starts (the twin's first start marks) with fixed noise (the twin's frame noise \
         of each mark, the exploration noise of each evaluation trial), so evaluations compare.\n",
        sim.episodes,
        learning.len(),
        session.evaluations.len(),
        eval.episodes,
        session.episodes
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
    let per_step = |v: Option<f64>| v.map_or("–".to_owned(), |v| format!("{v:.5}"));
    let eval_sim_json = dir.join("eval-sim/run.json");
    let eval_sim: Option<RunRecord> = if eval_sim_json.exists() {
        Some(read_json(&eval_sim_json)?)
    } else {
        None
    };
    writeln!(
        md,
        "Evaluated return (mean per trial over the evaluation set): yaw {:.3}, sway {:.4}; cable lost in {} of {} trials.\n",
        j_sim.yaw,
        j_sim.sway,
        eval.lost.iter().filter(|l| **l).count(),
        eval.episodes,
    )?;
    if let Some(es) = &eval_sim {
        let (v, s) = (eval.per_step(0..eval.episodes), es.per_step(0..es.episodes));
        writeln!(
            md,
            "The same policy on the same set with the reality gap off (the twin as the identified model with the \
             simulator's images): yaw {:.3}, sway {:.4}. Per step, vehicle against simulation: yaw {} against {}, \
             sway {} against {}.\n",
            mean(&es.yaw),
            mean(&es.sway),
            per_step(v.map(|p| p.0)),
            per_step(s.map(|p| p.0)),
            per_step(v.map(|p| p.1)),
            per_step(s.map(|p| p.1)),
        )?;
    }
    writeln!(md, "![Figs. 8 and 9](twin-sim-policy.png)\n")?;

    // Figs. 10, 11: improvement over trials, by the evaluations.
    writeln!(
        md,
        "## Figs. 10 and 11: policy improvement on the vehicle\n"
    )?;
    let curve_panel = |dof: Dof| {
        let series = |name: &str, pick: fn(&EvaluationRecord) -> PerDof<Option<f64>>| {
            let (x, y): (Vec<f64>, Vec<f64>) = session
                .evaluations
                .iter()
                .filter_map(|e| pick(e).get(dof).map(|v| (e.learning_trials as f64, v)))
                .unzip();
            Series::new(name, x, y)
        };
        let mut c = LineChart::new(
            format!("{dof}: evaluated return against learning trials"),
            "learning trials on the vehicle",
            "evaluated return (mean per trial)",
        );
        c.series = vec![
            series("the policy learned", |e| e.evaluated),
            series("the policy in force (the best kept)", |e| e.in_force),
        ];
        c.ref_lines = vec![
            RefLine::new("simulation policy", *j_sim.get(dof)),
            RefLine::new("the twin's limit", *j_limit.get(dof)),
        ];
        Panel::Lines(c)
    };
    Figure::new(vec![curve_panel(Dof::Yaw), curve_panel(Dof::Sway)], 2)
        .save_png(&out.join("step-two-evaluations.png"))?;
    // The state traces of each evaluation's first trial: the same start, the same noise.
    let trial_trace = read_trace(&dir.join("step-two/trace.jsonl"))?;
    let firsts: Vec<(String, &Vec<TracePoint>)> = session
        .evaluations
        .iter()
        .filter_map(|e| {
            let first = e.trial + 1 - eval.episodes as u32;
            trial_trace.get(&first).map(|p| {
                let when = if e.learning_trials == 0 {
                    "before learning".to_owned()
                } else {
                    format!("after {} learning trials", e.learning_trials)
                };
                (when, p)
            })
        })
        .collect();
    traces(
        "an evaluation's first trial (same start, same noise)",
        ("Fig. 10", "Fig. 11"),
        &firsts,
    )
    .save_png(&out.join("step-two-traces.png"))?;
    writeln!(
        md,
        "The evaluations of step two against the learning trials before them, with the simulation policy and the \
         twin's limit (each evaluated through the vehicle mesh on the same set): the policy the learning produced, and \
         the one in force after each evaluation (the best so far is restored when a new one evaluates worse by more \
         than the tolerance).\n\n![evaluations](step-two-evaluations.png)\n\n\
         Each evaluation's first trial, from the same start with the same noise:\n\n![Figs. 10 and 11](step-two-traces.png)\n"
    )?;
    writeln!(
        md,
        "| DOF | simulation policy J_sim | after step two J_after | the twin's limit J_limit | gap closed |\n|---|---:|---:|---:|---:|"
    )?;
    for dof in [Dof::Yaw, Dof::Sway] {
        let note = if *noise.get(dof) {
            " (the gap is under 5% of J_sim: the ratio is noise)"
        } else {
            ""
        };
        writeln!(
            md,
            "| {dof} | {:.4} | {:.4} | {:.4} | {:.0}%{note} |",
            j_sim.get(dof),
            j_after.get(dof),
            j_limit.get(dof),
            100.0 * closed.get(dof)
        )?;
    }
    writeln!(
        md,
        "\nCable lost on the evaluation set: the simulation policy in {} of {} trials, after step two in {}, the twin's \
         limit pairs in {} (yaw's) and {} (sway's) (a trial cut short by a lost cable costs less than a whole one: a return with cables lost is a \
         failed policy's).",
        lost_in(&eval),
        eval.episodes,
        lost_in(&eval_after),
        limit_lost.yaw,
        limit_lost.sway
    )?;
    writeln!(
        md,
        "\nThe twin's limit is each DOF's best return over all four gains (direct policy search on the twin with {} \
         perception, the simulation policy and every policy step two evaluated in its first generation, \
         `twin-limit/limit.json`): where the DOFs pull apart, no pair has both, so no policy need close the gap in \
         both DOFs at once.\n",
        limit_check.searched_with.as_deref().unwrap_or("unknown")
    )?;
    for dof in [Dof::Yaw, Dof::Sway] {
        let g = limit_gains.get(dof);
        writeln!(
            md,
            "- {dof}'s limit pair: sway K = [{:.3}, {:.3}], yaw K = [{:.3}, {:.3}]",
            g.sway[0], g.sway[1], g.yaw[0], g.yaw[1]
        )?;
    }
    writeln!(md)?;
    for dof in [Dof::Yaw, Dof::Sway] {
        let n = *limit_check.noise.get(dof);
        let n_text = if n.is_finite() {
            format!("twice the evaluation's noise on a difference, 2 x {n:.4}")
        } else {
            "the noise was not measured: any margin".to_owned()
        };
        match limit_check.beaten.get(dof) {
            Some(b) => writeln!(
                md,
                "- {dof}: **the limit is beaten**: {} evaluates {:.4} above it ({n_text}); the gap closed is not a share of a real gap.",
                b.by, b.margin
            )?,
            None => writeln!(
                md,
                "- {dof}: the limit is not below the simulation policy nor step two's beyond {n_text}."
            )?,
        }
    }
    writeln!(md)?;
    if let Some(h) = &held_out {
        writeln!(
            md,
            "On {} held-out sets (other starts, floors and noise than the evaluation set's: what the vehicle will meet), \
             {} trials per policy:\n\n\
             | policy | yaw, mean | sway, mean | cable lost |\n|---|---:|---:|---:|",
            h.sets.len(),
            h.sim_policy.trials
        )?;
        for (name, p) in [
            ("simulation policy", &h.sim_policy),
            ("after step two", &h.after),
            ("the twin's limit", &h.limit),
        ] {
            writeln!(
                md,
                "| {name} | {:.4} | {:.4} | {} of {} |",
                p.mean.yaw, p.mean.sway, p.lost, p.trials
            )?;
        }
        writeln!(
            md,
            "\nGap closed on them: yaw {:.0}%, sway {:.0}%; the evaluation's noise on a difference (the largest spread over \
             the sets of a difference between two policies the limit's run evaluated there before its search): yaw {:.4}, sway {:.4}.\n",
            100.0 * h.gap_closed.yaw,
            100.0 * h.gap_closed.sway,
            h.noise.yaw,
            h.noise.sway
        )?;
    }
    writeln!(md, "Step two's evaluations:\n")?;
    writeln!(
        md,
        "| after learning trials | yaw evaluated | in force | sway evaluated | in force | best restored |\n|---:|---:|---:|---:|---:|:---:|"
    )?;
    let opt =
        |v: Option<f64>, digits: usize| v.map_or("–".to_owned(), |v| format!("{v:.digits$}"));
    for e in &session.evaluations {
        let restored: Vec<&str> = Dof::ALL
            .into_iter()
            .filter(|d| *e.rolled_back.get(*d))
            .map(Dof::name)
            .collect();
        writeln!(
            md,
            "| {} | {} | {} | {} | {} | {} |",
            e.learning_trials,
            opt(e.evaluated.yaw, 3),
            opt(e.in_force.yaw, 3),
            opt(e.evaluated.sway, 4),
            opt(e.in_force.sway, 4),
            restored.join(", ")
        )?;
    }
    writeln!(
        md,
        "\nThe safety layer over step two: actor updates shortened by the trust region: sway {}, yaw {}; refused by the \
         stability guard: sway {}, yaw {}; best policy restored: sway {}, yaw {}.\n",
        session.safety.sway.bounded,
        session.safety.yaw.bounded,
        session.safety.sway.refused,
        session.safety.yaw.refused,
        session.safety.sway.rollbacks,
        session.safety.yaw.rollbacks
    )?;

    // The learning trials, each beside the simulation policy from the same start.
    let learned = |v: &[f64]| -> Vec<f64> { learning.iter().map(|&t| v[t]).collect() };
    let (learn_yaw, learn_sway) = (learned(&session.yaw), learned(&session.sway));
    let starts = same_starts(&trial_trace, &eval_trace, session.episodes);
    let per_trial = |dof: Dof| {
        let (v, before) = match dof {
            Dof::Yaw => (&learn_yaw, &eval.yaw),
            Dof::Sway => (&learn_sway, &eval.sway),
        };
        let x: Vec<f64> = (1..=v.len()).map(|t| t as f64).collect();
        let mut c = LineChart::new(
            format!("{dof}: return per learning trial on the vehicle"),
            "learning trial",
            "total reward",
        );
        c.series = vec![Series::new("online learning", x.clone(), v.clone())];
        // Returns depend most on where a trial starts: beside each trial, the simulation policy's
        // evaluation trial from the same start.
        let matched: Vec<(f64, f64)> = x
            .iter()
            .zip(&learning)
            .filter_map(|(n, &t)| starts[t].and_then(|e| before.get(e)).map(|r| (*n, *r)))
            .collect();
        c.series.push(Series::new(
            "simulation policy from the same start, not learning",
            matched.iter().map(|m| m.0).collect(),
            matched.iter().map(|m| m.1).collect(),
        ));
        Panel::Lines(c)
    };
    Figure::new(vec![per_trial(Dof::Yaw), per_trial(Dof::Sway)], 2)
        .save_png(&out.join("step-two-returns.png"))?;
    writeln!(md, "![returns per learning trial](step-two-returns.png)\n")?;

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

    writeln!(md, "## Learning trials on the vehicle\n")?;
    writeln!(
        md,
        "Each learning trial beside the simulation policy's evaluation trial from the same start.\n\n\
         | learning trial | trial of the session | steps | cable lost | yaw return | sway return | simulation policy from the same start: yaw | sway |\n\
         |---:|---:|---:|:---:|---:|---:|---:|---:|"
    )?;
    for (n, &t) in learning.iter().enumerate() {
        let steps = session.episode_steps.get(t).copied().unwrap_or(0);
        let (same_yaw, same_sway) = match starts.get(t).copied().flatten() {
            Some(e) => (
                format!("{:.3}", eval.yaw[e]),
                format!("{:.4}", eval.sway[e]),
            ),
            None => ("–".to_owned(), "–".to_owned()),
        };
        writeln!(
            md,
            "| {} | {} | {} | {} | {:.3} | {:.4} | {same_yaw} | {same_sway} |",
            n + 1,
            t + 1,
            steps,
            if session.lost[t] { "yes" } else { "" },
            session.yaw[t],
            session.sway[t]
        )?;
    }
    let path = out.join("report.md");
    std::fs::write(&path, md).with_context(|| format!("writing {}", path.display()))?;
    let lost = |pick: bool| {
        (0..session.episodes)
            .filter(|&t| {
                session.lost[t] && session.evaluation.get(t).copied().unwrap_or(false) == pick
            })
            .count()
    };
    let summary = Summary {
        sim: (&sim).into(),
        learning_trials: Returns {
            yaw: learn_yaw.clone(),
            sway: learn_sway.clone(),
        },
        vehicle_before_learning: (&eval).into(),
        sim_from_vehicle_starts: eval_sim.as_ref().map(Into::into),
        twin_limit: TwinLimit {
            yaw: j_limit.yaw,
            sway: j_limit.sway,
            gains: limit_gains,
        },
        evaluation: Evaluations {
            trials: eval.episodes,
            sim_policy: j_sim,
            after: j_after,
            limit: j_limit,
            curve: session.evaluations.clone(),
        },
        gap_closed: closed,
        gap_is_noise: noise,
        held_out,
        limit_check,
        safety: session.safety,
        lost: Lost {
            learning: lost(false),
            evaluation: lost(true),
        },
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
    fn a_gap_under_five_percent_is_noise() {
        assert!(gap_is_noise(-10.0, -9.6));
        assert!(!gap_is_noise(-10.0, -9.4));
        assert!(!gap_is_noise(-1.0, -0.5));
    }

    /// The report's check of the limit names a policy above it beyond twice the noise, in that DOF
    /// only; within the noise, or for a policy that lost more cables than the limit, it does not.
    #[test]
    fn the_report_says_when_a_policy_beats_the_limit() {
        let j = |sway, yaw| PerDof { sway, yaw };
        let noise = j(0.01, 0.1);
        let limit = (j(-1.0, -5.0), PerDof::both(0));
        // The simulation policy above the limit in yaw by 0.3 > 2 x 0.1: beaten, by it.
        let c = limit_check((j(-1.5, -4.7), 0), (j(-1.1, -5.1), 0), limit, noise);
        assert!(c.sway.is_none());
        let yaw = c
            .yaw
            .expect("yaw: the limit is below the simulation policy");
        assert_eq!(yaw.by, "the simulation policy");
        assert!((yaw.margin - 0.3).abs() < 1e-12);
        // Step two's above it in sway by 0.05 > 2 x 0.01; yaw within the noise (0.15 < 0.2).
        let c = limit_check((j(-1.5, -6.0), 0), (j(-0.95, -4.85), 0), limit, noise);
        assert_eq!(c.sway.expect("sway").by, "step two's policy");
        assert!(c.yaw.is_none());
        // A policy that lost the cable where the limit kept it failed, whatever its return.
        let c = limit_check((j(-0.5, -3.0), 1), (j(-1.1, -5.1), 0), limit, noise);
        assert!(c.sway.is_none() && c.yaw.is_none());
        // Noise not measured: any margin beats the limit.
        let nan = PerDof::both(f64::NAN);
        let c = limit_check((j(-0.999, -6.0), 0), (j(-1.1, -5.1), 0), limit, nan);
        assert!(c.sway.is_some() && c.yaw.is_none());
    }

    /// The limit on the held-out sets takes each DOF's returns from that DOF's own pair, and counts
    /// the cables and trials of both pairs.
    #[test]
    fn the_held_out_limit_is_each_dofs_own_pair() {
        let pair = |name: &str, sway: f64, yaw: f64, lost| HeldOutPolicy {
            name: name.to_owned(),
            returns: PerDof {
                sway: vec![sway, sway - 1.0],
                yaw: vec![yaw, yaw - 1.0],
            },
            mean: PerDof {
                sway: sway - 0.5,
                yaw: yaw - 0.5,
            },
            lost,
            trials: 10,
        };
        let l = limit_on_sets(
            &pair("limit for sway", -1.0, -9.0, 1),
            &pair("limit for yaw", -7.0, -5.0, 2),
        );
        assert_eq!(l.returns.sway, vec![-1.0, -2.0]);
        assert_eq!(l.returns.yaw, vec![-5.0, -6.0]);
        assert_eq!((l.mean.sway, l.mean.yaw), (-1.5, -5.5));
        assert_eq!((l.lost, l.trials), (3, 20));
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
