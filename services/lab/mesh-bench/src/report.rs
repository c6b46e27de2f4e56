//! The repeats' results, their medians, and the Markdown tables.

use crate::ring::Shape;
use crate::runs::{InProcessRun, MeshRun, ProcessUse, RingRun};
use crate::timeline::{HOPS, SLOWEST, SlowStep};
use anyhow::{Context, Result};
use serde::{Deserialize, Serialize};
use stats::{Summary, median};
use std::fmt::Write;
use std::path::Path;

/// Prints a report in Markdown and writes it and the figures (JSON) where asked; `who` is the
/// program that says so.
pub fn publish(
    who: &str,
    figures: &impl Serialize,
    markdown: &str,
    json: Option<&Path>,
    md: Option<&Path>,
) -> Result<()> {
    cli::outln!("{markdown}")?;
    if let Some(path) = json {
        std::fs::write(path, serde_json::to_string_pretty(figures)?)
            .with_context(|| format!("writing {}", path.display()))?;
        eprintln!("{who}: wrote {}", path.display());
    }
    if let Some(path) = md {
        std::fs::write(path, markdown).with_context(|| format!("writing {}", path.display()))?;
        eprintln!("{who}: wrote {}", path.display());
    }
    Ok(())
}

/// The machine the bench ran on.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Machine {
    pub cores: usize,
    pub cpu: String,
    pub kernel: String,
    /// `/proc/loadavg`'s 1-minute figure before and after the bench.
    pub load_before: f64,
    pub load_after: f64,
    /// The machine's speed: the fixed calibration loop's time (ms, median of 5) before the bench
    /// and after it. Figures of two days compare once scaled by it.
    #[serde(default)]
    pub calibration_ms: [f64; 2],
}

/// A fixed amount of integer and floating-point work on one core, the same on every machine and
/// every day: its time (ms, median of 5 passes) is the machine's speed as the bench's figures see it.
pub fn calibrate() -> f64 {
    let pass = || {
        let start = std::time::Instant::now();
        let (mut x, mut acc) = (0x9e37_79b9_7f4a_7c15_u64, 0.0f64);
        for _ in 0..20_000_000u32 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            acc = acc * 0.999_999 + (x >> 40) as f64;
        }
        std::hint::black_box(acc);
        start.elapsed().as_secs_f64() * 1e3
    };
    median((0..5).map(|_| pass()))
}

impl Machine {
    pub fn read() -> Machine {
        let cpu = std::fs::read_to_string("/proc/cpuinfo")
            .ok()
            .and_then(|s| {
                s.lines()
                    .find_map(|l| l.strip_prefix("model name"))
                    .map(|l| l.trim_start_matches([' ', '\t', ':']).trim().to_owned())
            })
            .unwrap_or_default();
        Machine {
            cores: std::thread::available_parallelism().map_or(1, |n| n.get()),
            cpu,
            kernel: std::fs::read_to_string("/proc/sys/kernel/osrelease")
                .map(|s| s.trim().to_owned())
                .unwrap_or_default(),
            load_before: load(),
            load_after: f64::NAN,
            calibration_ms: [f64::NAN; 2],
        }
    }
}

/// The 1-minute load average.
pub fn load() -> f64 {
    std::fs::read_to_string("/proc/loadavg")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse().ok())
        .unwrap_or(f64::NAN)
}

/// Everything one bench measured.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Results {
    pub machine: Machine,
    pub episodes: u32,
    pub repeats: usize,
    pub seed: u64,
    /// Steps per episode at most, and the warm-up (not measured).
    pub episode_steps: u64,
    pub warmup: u64,
    pub mesh: Vec<MeshRun>,
    pub mesh_probe: Vec<MeshRun>,
    pub in_process: Vec<InProcessRun>,
    pub ring: Vec<RingRun>,
    pub ring_probe: Vec<RingRun>,
    /// The CPUs the loop's services ran on (the mesh file's; empty: any), the ring's nodes too.
    #[serde(default)]
    pub loop_cpus: Vec<usize>,
}

/// Medians over the repeats.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Medians {
    pub mesh_steps_per_s: f64,
    pub mesh_probe_steps_per_s: f64,
    pub in_process_steps_per_s: f64,
    pub ring_steps_per_s: f64,
    pub ring_probe_steps_per_s: f64,
    /// Mesh time per step over (in-process + ring) time per step, median of the repeats' ratios.
    pub ratio: f64,
    /// The time per step the probe adds, as a fraction: medians of the repeats' own (paired) figures.
    pub probe_cost_mesh: f64,
    pub probe_cost_ring: f64,
}

/// One stage's CPU per step in the mesh (its process) and in one process (its core's calls), µs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StageCost {
    pub in_mesh: f64,
    pub in_process: f64,
}

impl StageCost {
    pub fn ratio(&self) -> f64 {
        self.in_mesh / self.in_process
    }
}

impl Results {
    /// The camera's and perception's cost per step, medians over the repeats.
    pub fn stages(&self) -> [StageCost; 2] {
        let in_mesh = |name: &str| {
            median(self.mesh.iter().flat_map(|r| {
                r.processes
                    .iter()
                    .filter(|p| p.name == name)
                    .map(|p| p.cpu_us_per_step)
            }))
        };
        [
            StageCost {
                in_mesh: in_mesh("camera"),
                in_process: median(self.in_process.iter().map(|r| r.render_us_per_step)),
            },
            StageCost {
                in_mesh: in_mesh("perception"),
                in_process: median(self.in_process.iter().map(|r| r.perceive_us_per_step)),
            },
        ]
    }

    pub fn medians(&self) -> Medians {
        let ratios = self
            .mesh
            .iter()
            .zip(&self.in_process)
            .zip(&self.ring)
            .map(|((m, a), b)| (1.0 / m.steps_per_s) / (1.0 / a.steps_per_s + 1.0 / b.steps_per_s));
        Medians {
            mesh_steps_per_s: median(self.mesh.iter().map(|r| r.steps_per_s)),
            mesh_probe_steps_per_s: median(self.mesh_probe.iter().map(|r| r.steps_per_s)),
            in_process_steps_per_s: median(self.in_process.iter().map(|r| r.steps_per_s)),
            ring_steps_per_s: median(self.ring.iter().map(|r| r.steps_per_s)),
            ring_probe_steps_per_s: median(self.ring_probe.iter().map(|r| r.steps_per_s)),
            ratio: median(ratios),
            probe_cost_mesh: median(
                self.mesh
                    .iter()
                    .zip(&self.mesh_probe)
                    .map(|(a, b)| a.steps_per_s / b.steps_per_s - 1.0),
            ),
            probe_cost_ring: median(
                self.ring
                    .iter()
                    .zip(&self.ring_probe)
                    .map(|(a, b)| a.steps_per_s / b.steps_per_s - 1.0),
            ),
        }
    }

    /// The Markdown report.
    pub fn markdown(&self) -> String {
        let m = self.medians();
        let mut out = String::new();
        let mc = &self.machine;
        let _ = writeln!(
            out,
            "### Mesh benchmark: {} repeats x {} episodes (first episode = warm-up), images, seeds {}..{}\n",
            self.repeats,
            self.episodes,
            self.seed,
            self.seed + self.repeats as u64 - 1
        );
        let _ = writeln!(
            out,
            "Machine: {} cores ({}), Linux {}; 1-minute load average {:.2} before, {:.2} after; \
             its speed, the fixed calibration loop on one core: {:.1} ms before, {:.1} ms after.\n",
            mc.cores,
            mc.cpu,
            mc.kernel,
            mc.load_before,
            mc.load_after,
            mc.calibration_ms[0],
            mc.calibration_ms[1]
        );
        let _ = writeln!(
            out,
            "The loop's seven services, and the bare ring's seven nodes, ran on {}.\n",
            match self.loop_cpus.as_slice() {
                [] => "any CPU".to_owned(),
                [one] => format!("CPU {one}"),
                many => format!(
                    "CPUs {}",
                    many.iter()
                        .map(|c| c.to_string())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            }
        );
        let us = |rate: f64| 1e6 / rate;
        let range = |v: &[f64]| {
            let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = v.iter().copied().fold(0.0, f64::max);
            format!("{} – {}", thousands(lo), thousands(hi))
        };
        let rates = |runs: &[MeshRun]| runs.iter().map(|r| r.steps_per_s).collect::<Vec<_>>();
        let _ = writeln!(
            out,
            "| what | steps/s (median) | min – max | time per step | other load (cores) |"
        );
        let _ = writeln!(out, "|---|---:|---:|---:|---:|");
        let row = |out: &mut String, what: &str, median: f64, all: Vec<f64>, other: Option<f64>| {
            let _ = writeln!(
                out,
                "| {what} | {} | {} | {:.0} µs | {} |",
                thousands(median),
                range(&all),
                us(median),
                other.map_or("–".into(), |o| format!("{o:.2}"))
            );
        };
        row(
            &mut out,
            "mesh: 7 service processes + monitor + supervisor, images (target ≥ 1,000)",
            m.mesh_steps_per_s,
            rates(&self.mesh),
            Some(median(self.mesh.iter().map(|r| r.other_cores))),
        );
        row(
            &mut out,
            "mesh with the latency probe attached",
            m.mesh_probe_steps_per_s,
            rates(&self.mesh_probe),
            None,
        );
        row(
            &mut out,
            "limit (a): the same cores in one process, one thread, no IPC",
            m.in_process_steps_per_s,
            self.in_process.iter().map(|r| r.steps_per_s).collect(),
            Some(median(self.in_process.iter().map(|r| r.other_cores))),
        );
        row(
            &mut out,
            "limit (b): bare iceoryx2 ring, same depth and messages, empty processes",
            m.ring_steps_per_s,
            self.ring.iter().map(|r| r.steps_per_s).collect(),
            Some(median(self.ring.iter().map(|r| r.other_cores))),
        );
        row(
            &mut out,
            "bare ring with the probe attached",
            m.ring_probe_steps_per_s,
            self.ring_probe.iter().map(|r| r.steps_per_s).collect(),
            None,
        );
        let _ = writeln!(
            out,
            "\n(Other load: CPU time the machine spent on anything but the bench and the processes measured, \
             in cores, median of the runs; another user's build shows here.)"
        );
        let sum = us(m.in_process_steps_per_s) + us(m.ring_steps_per_s);
        let _ = writeln!(
            out,
            "\nMesh time per step {:.0} µs against the limit's (a) + (b) = {:.0} + {:.0} = {:.0} µs: \
             ratio {:.2} (median of the repeats' own ratios); the mesh spends {:.0} µs per step beyond it.\n",
            us(m.mesh_steps_per_s),
            us(m.in_process_steps_per_s),
            us(m.ring_steps_per_s),
            sum,
            m.ratio,
            us(m.mesh_steps_per_s) - sum
        );

        // Latencies.
        let mesh_hops: Vec<Vec<Summary>> = (0..HOPS.len())
            .map(|k| {
                self.mesh_probe
                    .iter()
                    .filter_map(|r| r.hops.as_ref()?.hops.get(k).copied())
                    .collect()
            })
            .collect();
        let ring_hops: Vec<Vec<Summary>> = (0..HOPS.len())
            .map(|k| {
                self.ring_probe
                    .iter()
                    .filter_map(|r| r.probe_hops.as_ref()?.hops.get(k).copied())
                    .collect()
            })
            .collect();
        let _ = writeln!(
            out,
            "Latency per hop and per step, seen by the probe (p50 and p99: medians of the runs' own; max: of all runs), µs:\n"
        );
        let _ = writeln!(
            out,
            "| stage | span | mesh p50 | mesh p99 | mesh max | bare ring p50 | ring p99 | ring max |"
        );
        let _ = writeln!(out, "|---|---|---:|---:|---:|---:|---:|---:|");
        for (k, hop) in HOPS.iter().enumerate() {
            let a = Summary::median_of(&mesh_hops[k]);
            let b = Summary::median_of(&ring_hops[k]);
            let name = match hop.name {
                "step" => "**step** (target p99 < 5 ms)",
                other => other,
            };
            let _ = writeln!(
                out,
                "| {name} | {} | {} | {} | {} | {} | {} | {} |",
                hop.span,
                micros(a.p50),
                micros(a.p99),
                micros(a.max),
                micros(b.p50),
                micros(b.p99),
                micros(b.max)
            );
        }
        let missed: usize = self
            .mesh_probe
            .iter()
            .filter_map(|r| r.hops.as_ref().map(|h| h.missed))
            .sum();
        let reordered: usize = self
            .mesh_probe
            .iter()
            .filter_map(|r| r.hops.as_ref().map(|h| h.reordered))
            .sum();
        let mut slowest: Vec<&SlowStep> = self
            .mesh_probe
            .iter()
            .filter_map(|r| r.hops.as_ref())
            .flat_map(|h| &h.slowest)
            .collect();
        slowest.sort_by_key(|s| std::cmp::Reverse(s.step_ns));
        let slowest: Vec<String> = slowest
            .iter()
            .take(SLOWEST)
            .map(|s| {
                format!(
                    "{:.1} ms (episode {}, step {}: {} {:.1} ms)",
                    s.step_ns as f64 / 1e6,
                    s.episode,
                    s.step,
                    s.worst_stage,
                    s.worst_ns as f64 / 1e6
                )
            })
            .collect();
        let _ = writeln!(
            out,
            "\nThe slowest steps of all runs, with the stage that took longest in each: {}.",
            slowest.join("; ")
        );
        let measured: usize = self.mesh_probe.iter().map(|r| r.steps as usize).sum();
        let _ = writeln!(
            out,
            "Mesh steps measured: {measured} (steps the probe missed a message of: {missed}; hops read out of order, counted 0: {reordered})."
        );

        // What the probe adds.
        let delay = Summary::median_of(
            &self
                .ring_probe
                .iter()
                .filter_map(|r| r.probe.as_ref()?.delay)
                .collect::<Vec<_>>(),
        );
        let probe_cpu = median(
            self.mesh_probe
                .iter()
                .filter_map(|r| r.probe.as_ref().map(|p| p.cpu_us_per_step)),
        );
        let probe_wakes = median(
            self.mesh_probe
                .iter()
                .filter_map(|r| r.probe.as_ref().map(|p| p.wakeups_per_step)),
        );
        let _ = writeln!(
            out,
            "\nThe probe (one more subscriber and listener on every topic, a thread of the bench blocked in a WaitSet) \
             wakes {probe_wakes:.1} times per step and uses {probe_cpu:.0} µs of CPU per step. Its own wake-up delay, \
             measured in the bare ring where every sender stamps its send time: p50 {}, p99 {}, max {} µs; a hop is the \
             difference of two such delays. With it attached a step took {:+.1}% longer in the mesh, {:+.1}% in the bare ring \
             (medians of the repeats' pairs; the mesh's pace alone varies by 10 to 20% from run to run).\n",
            micros(delay.p50),
            micros(delay.p99),
            micros(delay.max),
            100.0 * m.probe_cost_mesh,
            100.0 * m.probe_cost_ring,
        );
        let ring_step = Summary::median_of(&self.ring.iter().map(|r| r.step).collect::<Vec<_>>());
        let _ = write!(
            out,
            "Bare ring without the probe, exact (sender-stamped) one-way latency per hop, p50/p99 µs: "
        );
        let parts: Vec<String> = Shape::Mesh
            .roles()
            .iter()
            .map(|role| {
                let s = Summary::median_of(
                    &self
                        .ring
                        .iter()
                        .filter_map(|r| r.hops.iter().find(|(x, _)| x == role).map(|(_, s)| *s))
                        .collect::<Vec<_>>(),
                );
                format!("{} {}/{}", role.hop(), micros(s.p50), micros(s.p99))
            })
            .collect();
        let _ = writeln!(
            out,
            "{}; step (state sent → setpoints received) {}/{}, max {}.\n",
            parts.join(", "),
            micros(ring_step.p50),
            micros(ring_step.p99),
            micros(ring_step.max)
        );

        // CPU and memory.
        let _ = writeln!(
            out,
            "Each process of the mesh (runs without the probe; medians; CPU per step over the steady window, \
             totals and memory at the last reading before it exited):\n"
        );
        let _ = writeln!(
            out,
            "| process | CPU per step (µs) | CPU in the run (ms) | kernel share | switches per step: blocked / preempted | migrations per step | page faults per step | RSS (MiB) | of it shared memory | peak RSS (MiB) |"
        );
        let _ = writeln!(out, "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
        let mut names: Vec<String> = Vec::new();
        for r in &self.mesh {
            for p in &r.processes {
                if !names.contains(&p.name) {
                    names.push(p.name.clone());
                }
            }
        }
        let mut total_step = 0.0;
        for name in &names {
            let of = |f: fn(&ProcessUse) -> f64| {
                median(
                    self.mesh
                        .iter()
                        .flat_map(|r| r.processes.iter().filter(|p| &p.name == name).map(f)),
                )
            };
            let per_step = of(|p| p.cpu_us_per_step);
            if per_step.is_finite() {
                total_step += per_step;
            }
            let _ = writeln!(
                out,
                "| {name} | {per_step:.0} | {:.0} | {:.0}% | {:.2} / {:.2} | {:.3} | {:.2} | {:.1} | {:.1} | {:.1} |",
                of(|p| p.cpu_ms),
                100.0 * of(|p| p.sys_share),
                of(|p| p.per_step.voluntary),
                of(|p| p.per_step.involuntary),
                of(|p| p.per_step.migrations),
                of(|p| p.per_step.minor_faults),
                of(|p| p.rss_mib),
                of(|p| p.shmem_mib),
                of(|p| p.hwm_mib),
            );
        }
        let ring_cpu = median(self.ring.iter().map(|r| r.cpu_us_per_step));
        let _ = writeln!(
            out,
            "| **all of the mesh** | **{total_step:.0}** | | | | | | | | |\n| bare ring, its 7 nodes together | {ring_cpu:.0} | | | | | | | | |"
        );
        let a = |f: fn(&InProcessRun) -> f64| median(self.in_process.iter().map(f));
        let _ = writeln!(
            out,
            "| limit (a), the loop's one thread | {:.0} | | | {:.2} / {:.2} | {:.3} | {:.2} | | | |",
            us(m.in_process_steps_per_s),
            a(|r| r.per_step.voluntary),
            a(|r| r.per_step.involuntary),
            a(|r| r.per_step.migrations),
            a(|r| r.per_step.minor_faults),
        );
        let [camera, perception] = self.stages();
        let _ = writeln!(
            out,
            "\nThe two stages that do the work, CPU per step in the mesh against the same core in one process \
             (limit (a), medians): camera {:.0} µs against rendering {:.0} µs ({:.2}x); perception {:.0} µs \
             against perceiving {:.0} µs ({:.2}x).",
            camera.in_mesh,
            camera.in_process,
            camera.ratio(),
            perception.in_mesh,
            perception.in_process,
            perception.ratio(),
        );
        let _ = writeln!(
            out,
            "\nShared-memory files left behind by all {} runs of processes: {}.",
            self.mesh.len() + self.mesh_probe.len() + self.ring.len() + self.ring_probe.len(),
            self.leftovers()
        );
        out
    }

    /// The shared-memory files all runs of processes left behind in their namespaces (a clean run:
    /// none).
    pub fn leftovers(&self) -> usize {
        self.mesh
            .iter()
            .chain(&self.mesh_probe)
            .map(|r| r.leftovers)
            .chain(
                self.ring
                    .iter()
                    .chain(&self.ring_probe)
                    .map(|r| r.leftovers),
            )
            .sum()
    }
}

/// Several invocations of the bench side by side, each with its medians, and the median and range
/// over them: how much a figure moves between two invocations on the same machine.
pub fn spread(invocations: &[(String, Results)]) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "| invocation | calibration loop (ms) | load before | mesh steps/s | limit (a) steps/s | limit (b) steps/s | mesh / ((a) + (b)) | camera in mesh / in one process | perception in mesh / in one process |"
    );
    let _ = writeln!(out, "|---|---:|---:|---:|---:|---:|---:|---:|---:|");
    let mut rows: Vec<[f64; 8]> = Vec::new();
    for (name, r) in invocations {
        let m = r.medians();
        let [c, p] = r.stages();
        let row = [
            r.machine.calibration_ms[0],
            r.machine.load_before,
            m.mesh_steps_per_s,
            m.in_process_steps_per_s,
            m.ring_steps_per_s,
            m.ratio,
            c.ratio(),
            p.ratio(),
        ];
        let _ = writeln!(
            out,
            "| {name} | {:.1} | {:.2} | {} | {} | {} | {:.2} | {:.2} | {:.2} |",
            row[0],
            row[1],
            thousands(row[2]),
            thousands(row[3]),
            thousands(row[4]),
            row[5],
            row[6],
            row[7]
        );
        rows.push(row);
    }
    let col = |k: usize| -> (f64, f64, f64) {
        let v: Vec<f64> = rows.iter().map(|r| r[k]).collect();
        let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        (median(v), lo, hi)
    };
    let f2 = |k: usize| {
        let (m, lo, hi) = col(k);
        format!("{m:.2} ({lo:.2} – {hi:.2})")
    };
    let big = |k: usize| {
        let (m, lo, hi) = col(k);
        format!("{} ({} – {})", thousands(m), thousands(lo), thousands(hi))
    };
    let (cal, cal_lo, cal_hi) = col(0);
    let _ = writeln!(
        out,
        "| **median (min – max) of {}** | {cal:.1} ({cal_lo:.1} – {cal_hi:.1}) | {} | {} | {} | {} | {} | {} | {} |",
        rows.len(),
        f2(1),
        big(2),
        big(3),
        big(4),
        f2(5),
        f2(6),
        f2(7)
    );
    out
}

/// Nanoseconds as microseconds, one decimal below 100 µs.
fn micros(ns: u64) -> String {
    let us = ns as f64 / 1e3;
    if us < 100.0 {
        format!("{us:.1}")
    } else {
        thousands(us)
    }
}

/// The bare ring's runs (`mesh-bench ring`): each run's step latency, with its p99's 95% interval,
/// the steps missed and the nodes' CPU; then each hop's p50 and p99, run by run.
pub fn ring_markdown(runs: &[RingRun]) -> String {
    let us = |ns: u64| format!("{:.0}", ns as f64 / 1e3);
    let mut md = String::from(
        "| run | steps | missed | step p50 (µs) | p99 (µs) | p99, 95% interval (µs) | max (µs) | CPU per step, all nodes (µs) | other load (cores) |\n\
         |---|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    for (i, r) in runs.iter().enumerate() {
        let interval = r.step_p99_interval.map_or_else(
            || "too few steps".to_owned(),
            |[lo, hi]| format!("{} – {}", us(lo), us(hi)),
        );
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} | {interval} | {} | {:.0} | {:.2} |",
            i + 1,
            r.step.n,
            r.missed,
            us(r.step.p50),
            us(r.step.p99),
            us(r.step.max),
            r.cpu_us_per_step,
            r.other_cores
        );
    }
    md.push_str("\n| hop | p50 / p99 (µs), run by run |\n|---|---|\n");
    let Some(first) = runs.first() else {
        return md;
    };
    for role in first.hops.iter().map(|(role, _)| *role) {
        let cells: Vec<String> = runs
            .iter()
            .filter_map(|r| r.hops.iter().find(|(x, _)| *x == role))
            .map(|(_, s)| format!("{} / {}", us(s.p50), us(s.p99)))
            .collect();
        let _ = writeln!(
            md,
            "| {} | {} |",
            role.hop_in(first.shape),
            cells.join(", ")
        );
    }
    md
}

/// A number rounded, with thousands separated by commas.
pub fn thousands(x: f64) -> String {
    if !x.is_finite() {
        return "–".into();
    }
    let s = format!("{:.0}", x.abs());
    let mut out = String::new();
    for (i, c) in s.chars().enumerate() {
        if i > 0 && (s.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(c);
    }
    if x < -0.5 { format!("-{out}") } else { out }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ring::Role;

    #[test]
    fn numbers_read_well() {
        assert_eq!(thousands(1234567.4), "1,234,567");
        assert_eq!(thousands(999.6), "1,000");
        assert_eq!(thousands(12.0), "12");
        assert_eq!(thousands(-4321.0), "-4,321");
        assert_eq!(thousands(f64::NAN), "–");
        assert_eq!(micros(21_340), "21.3");
        assert_eq!(micros(4_321_000), "4,321");
    }

    #[test]
    fn the_ring_table_names_the_vehicles_hops_and_says_when_a_p99_is_unbounded() {
        let hop = |p50: u64| Summary {
            n: 100,
            p50,
            p99: 2 * p50,
            ..Default::default()
        };
        let run = |p50: u64, interval| RingRun {
            shape: Shape::Vehicle,
            step: Summary {
                n: 1000,
                p50,
                p99: 4 * p50,
                max: 9 * p50,
                ..Default::default()
            },
            step_p99_interval: interval,
            missed: 2,
            hops: vec![(Role::Camera, hop(98_000)), (Role::Driver, hop(57_000))],
            ..Default::default()
        };
        let md = ring_markdown(&[
            run(510_000, Some([1_787_000, 2_052_000])),
            run(603_000, None),
        ]);
        assert!(
            md.contains("| 1 | 1000 | 2 | 510 | 2040 | 1787 – 2052 | 4590 |"),
            "{md}"
        );
        assert!(
            md.contains("| 2 | 1000 | 2 | 603 | 2412 | too few steps |"),
            "{md}"
        );
        assert!(
            md.contains("| twin/frame → camera | 98 / 196, 98 / 196 |"),
            "{md}"
        );
        assert!(md.contains("| thruster_setpoints → thruster-driver | 57 / 114, 57 / 114 |"));
        assert!(ring_markdown(&[]).lines().count() < 6);
    }

    #[test]
    fn the_ratio_compares_times_per_step() {
        let r = Results {
            mesh: vec![MeshRun {
                steps_per_s: 1000.0,
                processes: vec![
                    ProcessUse {
                        name: "camera".into(),
                        cpu_us_per_step: 220.0,
                        ..Default::default()
                    },
                    ProcessUse {
                        name: "perception".into(),
                        cpu_us_per_step: 150.0,
                        ..Default::default()
                    },
                ],
                ..Default::default()
            }],
            in_process: vec![InProcessRun {
                steps_per_s: 2000.0,
                steps: 1,
                render_us_per_step: 200.0,
                perceive_us_per_step: 100.0,
                ..Default::default()
            }],
            ring: vec![RingRun {
                steps_per_s: 4000.0,
                ..Default::default()
            }],
            ..Default::default()
        };
        // 1000 µs against 500 + 250 µs.
        assert!((r.medians().ratio - 1000.0 / 750.0).abs() < 1e-12);
        let md = r.markdown();
        assert!(md.contains("ratio 1.33"));
        assert!(
            md.contains("camera 220 µs against rendering 200 µs (1.10x)"),
            "{md}"
        );
        assert!(
            md.contains("perception 150 µs against perceiving 100 µs (1.50x)"),
            "{md}"
        );
    }
}
