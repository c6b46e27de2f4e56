//! The measurements, one run each: the mesh (without the probe, for its pace and each process's CPU
//! and memory; with it, for the latencies), the bare ring (likewise), and the same cores in one
//! process. Every run of processes gets an iceoryx2 namespace of its own, removed afterwards.

use crate::probe::{self, Observed, Probe, Progress};
use crate::procfs::{self, ProcSample, SchedCounts};
use crate::ring::{self, NodeReport, RingOptions, Role, Shape};
use crate::timeline::HopLatencies;
use anyhow::{Context, Result, bail};
use messages::Endpoint;
use runtime::Namespace;
use runtime::clock::monotonic_ns;
use runtime::process::{Child, Placement, Spawn};
use serde::{Deserialize, Serialize};
use stats::Summary;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// How often the processes are read and the mesh's step is asked while it runs without the probe.
const TICK: Duration = Duration::from_millis(20);
/// How often the probe asks whether the run is over.
const PROBE_POLL: Duration = Duration::from_millis(50);
/// The longest any one run may take.
const RUN_LIMIT: Duration = Duration::from_secs(600);

/// Where the mesh file puts the loop's services (its simulator's placement, its defaults filled):
/// the bare ring's nodes run there too, so the limit is measured as the mesh runs.
pub fn loop_placement(mesh_file: &Path) -> Result<Placement> {
    let mesh = supervisor::MeshFile::load(mesh_file)?;
    let commands = mesh.commands(&Default::default(), mesh_file)?;
    Ok(commands
        .into_iter()
        .find(|c| c.name == "simulator")
        .map(|c| c.placement)
        .unwrap_or_default())
}

/// Starts a process of a run: its output in `log`, stopped if the bench dies.
pub fn spawn(
    name: &str,
    program: &Path,
    args: &[String],
    env: &[(&str, String)],
    log: PathBuf,
) -> Result<Child> {
    Spawn::new(program)
        .name(name)
        .args(args)
        .envs(env.iter().map(|(k, v)| (k, v)))
        .log(log)
        .die_with_parent()
        .start()
        .with_context(|| format!("starting {}", program.display()))
}

/// Where a run of the vehicle mesh after a brief step one finds its configuration and its two mesh
/// files: options of `mesh-bench vehicle` and of `fault-drill`.
#[derive(clap::Args, Clone, Debug)]
pub struct VehicleFiles {
    /// Directory holding scenario.toml, learning.toml and twin.toml.
    #[arg(long, default_value = "config")]
    pub config: PathBuf,
    /// Step one's mesh file, in simulation.
    #[arg(long, default_value = "config/sim-mesh.toml")]
    pub sim_mesh: PathBuf,
    /// The vehicle's mesh file.
    #[arg(long, default_value = "config/vehicle.toml")]
    pub vehicle_mesh: PathBuf,
}

impl VehicleFiles {
    /// The three made absolute (the processes started run from elsewhere); a missing one is named.
    pub fn canonical(&self) -> Result<VehicleFiles> {
        let canon = |p: &Path, what: &str| {
            p.canonicalize()
                .with_context(|| format!("{what} {}", p.display()))
        };
        Ok(VehicleFiles {
            config: canon(&self.config, "the config directory")?,
            sim_mesh: canon(&self.sim_mesh, "the mesh file")?,
            vehicle_mesh: canon(&self.vehicle_mesh, "the mesh file")?,
        })
    }
}

/// A run of the vehicle mesh after a brief step one (the vehicle bench's, the fault drill's): where
/// its programs and files are, the experiment's seed and step one's length.
#[derive(Clone, Debug)]
pub struct VehicleRunSetup {
    /// The programs' directory (the supervisor's and the services').
    pub bin_dir: PathBuf,
    /// Absolute ([`VehicleFiles::canonical`]).
    pub files: VehicleFiles,
    pub seed: u64,
    /// Step one's episodes in simulation.
    pub sim_episodes: u32,
}

impl VehicleRunSetup {
    /// The run of `files` (made absolute), with the programs beside the running one.
    pub fn new(files: &VehicleFiles, seed: u64, sim_episodes: u32) -> Result<Self> {
        let exe = std::env::current_exe()?;
        Ok(VehicleRunSetup {
            bin_dir: exe.parent().context("the program's directory")?.to_owned(),
            files: files.canonical()?,
            seed,
            sim_episodes,
        })
    }

    /// The scenario of the run's configuration.
    pub fn scenario(&self) -> Result<config::Scenario> {
        Ok(config::load(&self.files.config.join("scenario.toml"))?)
    }

    /// Runs step one in simulation, briefly and with ideal perception, in `ns`: the policy a vehicle
    /// run starts from (a policy, not a good one). Returns the directory of its checkpoints.
    pub fn step_one(&self, ns: &Namespace, who: &str) -> Result<PathBuf> {
        let scratch = ns.scratch();
        let step_one = scratch.join("step-one");
        let episodes = self.sim_episodes;
        let args =
            runtime::MeshArgs::new(&self.files.sim_mesh, &self.files.config, self.seed, &ns.iox)
                .with_sets(&[
                    ("episodes", episodes.to_string()),
                    ("eyes", "ideal".into()),
                    ("state", step_one.display().to_string()),
                    ("json", step_one.join("run.json").display().to_string()),
                ])
                .command_line();
        eprintln!("{who}: step one, {episodes} episodes in simulation");
        let mut sup = spawn(
            "supervisor (step one)",
            &self.bin_dir.join("supervisor"),
            &args,
            &[],
            scratch.join("step-one.log"),
        )?;
        if !sup
            .wait_timeout(Duration::from_secs(600))
            .is_some_and(|s| s.success())
        {
            bail!("step one failed\n{}", sup.tail(30));
        }
        Ok(step_one)
    }

    /// Starts the vehicle mesh in `ns` under its supervisor, with `sets` and `env`, its output in
    /// `log`.
    pub fn start_vehicle(
        &self,
        ns: &Namespace,
        sets: &[(&str, String)],
        env: &[(&str, String)],
        log: PathBuf,
    ) -> Result<Child> {
        let args = runtime::MeshArgs::new(
            &self.files.vehicle_mesh,
            &self.files.config,
            self.seed,
            &ns.iox,
        )
        .with_sets(sets)
        .command_line();
        spawn(
            "supervisor (vehicle)",
            &self.bin_dir.join("supervisor"),
            &args,
            env,
            log,
        )
    }
}

/// One reading while a run goes on: the step the loop is at and its processes.
#[derive(Clone, Debug)]
pub struct Tick {
    pub t_ns: u64,
    pub seq: u64,
    pub procs: Vec<ProcSample>,
    /// The whole machine's busy CPU time and the bench's own (ns).
    pub busy_ns: u64,
    pub own_ns: u64,
}

/// The steady part of a run: from the first reading past the warm-up to the last reading after
/// which the loop still moved on (so both ends fall while it runs, not in its start or stop).
pub fn window(ticks: &[Tick], warmup: u64) -> Option<(usize, usize)> {
    let a = ticks.iter().position(|t| t.seq > warmup)?;
    let b = (0..ticks.len().saturating_sub(1))
        .rev()
        .find(|&i| ticks[i + 1].seq > ticks[i].seq)?;
    (b > a && ticks[b].t_ns > ticks[a].t_ns).then_some((a, b))
}

/// One process's use of the machine in a run.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ProcessUse {
    pub name: String,
    /// CPU time over the whole run (start-up included), at its last reading.
    pub cpu_ms: f64,
    /// CPU time per step in the steady window.
    pub cpu_us_per_step: f64,
    /// The system (kernel) share of its CPU time.
    pub sys_share: f64,
    /// Resident memory at its last reading, its peak, and the shared-memory part of it (MiB).
    pub rss_mib: f64,
    pub hwm_mib: f64,
    pub shmem_mib: f64,
    /// Per step of the steady window: context switches, migrations, minor page faults.
    #[serde(default)]
    pub per_step: SchedRates,
}

/// [`SchedCounts`] per step.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SchedRates {
    pub voluntary: f64,
    pub involuntary: f64,
    pub migrations: f64,
    pub minor_faults: f64,
}

impl SchedRates {
    pub fn of(c: &SchedCounts, steps: f64) -> SchedRates {
        let s = steps.max(1.0);
        SchedRates {
            voluntary: c.voluntary as f64 / s,
            involuntary: c.involuntary as f64 / s,
            migrations: c.migrations as f64 / s,
            minor_faults: c.minor_faults as f64 / s,
        }
    }
}

/// Where a process is listed: the loop's order (the plant, the control path, the thruster driver),
/// then the processes beside it; any other last.
fn rank(name: &str) -> usize {
    const PLANT: [&str; 2] = ["simulator", "vehicle-twin"];
    const BESIDE: [&str; 4] = ["thruster-driver", "monitor", "recorder", "supervisor"];
    let order = || {
        PLANT
            .iter()
            .chain(&messages::topics::CONTROL_PATH)
            .chain(&BESIDE)
    };
    order().position(|o| *o == name).unwrap_or(order().count())
}

/// Each process's use from the readings, with the steady window `(a, b)`.
pub fn usage(ticks: &[Tick], (a, b): (usize, usize)) -> Vec<ProcessUse> {
    let steps = ticks[b].seq.saturating_sub(ticks[a].seq).max(1) as f64;
    let mut pids: Vec<i32> = ticks
        .iter()
        .flat_map(|t| t.procs.iter().map(|p| p.pid))
        .collect();
    pids.sort_unstable();
    pids.dedup();
    let find = |tick: &Tick, pid: i32| tick.procs.iter().find(|p| p.pid == pid).cloned();
    let mut out: Vec<ProcessUse> = pids
        .into_iter()
        .filter_map(|pid| {
            let last = ticks.iter().rev().find_map(|t| find(t, pid))?;
            let (steady, per_step) = match (find(&ticks[a], pid), find(&ticks[b], pid)) {
                (Some(x), Some(y)) => (
                    y.cpu_ns.saturating_sub(x.cpu_ns) as f64 / steps / 1e3,
                    SchedRates::of(&y.sched.since(&x.sched), steps),
                ),
                _ => (f64::NAN, SchedRates::default()),
            };
            let ticks_total = (last.utime_ticks + last.stime_ticks).max(1) as f64;
            const MIB: f64 = 1024.0;
            Some(ProcessUse {
                name: last.name.clone(),
                cpu_ms: last.cpu_ns as f64 / 1e6,
                cpu_us_per_step: steady,
                sys_share: last.stime_ticks as f64 / ticks_total,
                rss_mib: last.rss_kb as f64 / MIB,
                hwm_mib: last.hwm_kb as f64 / MIB,
                shmem_mib: last.shmem_kb as f64 / MIB,
                per_step,
            })
        })
        .collect();
    out.sort_by(|x, y| rank(&x.name).cmp(&rank(&y.name)).then(x.name.cmp(&y.name)));
    out
}

/// The CPUs busy with anything but the watched processes and the bench itself over the window, in
/// cores (another user's build shows here).
pub fn other_cores(ticks: &[Tick], (a, b): (usize, usize)) -> f64 {
    let (x, y) = (&ticks[a], &ticks[b]);
    let watched: u64 = y
        .procs
        .iter()
        .filter_map(|p| {
            let before = x.procs.iter().find(|q| q.pid == p.pid)?;
            Some(p.cpu_ns.saturating_sub(before.cpu_ns))
        })
        .sum();
    let busy = y.busy_ns.saturating_sub(x.busy_ns) as f64;
    let ours = (watched + y.own_ns.saturating_sub(x.own_ns)) as f64;
    ((busy - ours) / (y.t_ns - x.t_ns).max(1) as f64).max(0.0)
}

/// Reads the step and `pids()`'s processes every [`TICK`] until `done()`.
fn watch(
    node: &iceoryx2::prelude::Node<iceoryx2::prelude::ipc::Service>,
    progress: &mut Progress,
    pids: impl Fn() -> Vec<i32>,
    mut done: impl FnMut() -> bool,
) -> Result<Vec<Tick>> {
    let start = Instant::now();
    let mut ticks = Vec::new();
    loop {
        let seq = progress.latest_seq()?;
        let procs = pids().into_iter().filter_map(procfs::sample).collect();
        ticks.push(Tick {
            t_ns: monotonic_ns(),
            seq,
            procs,
            busy_ns: procfs::machine_busy_ns(),
            own_ns: procfs::own_cpu_ns(),
        });
        if done() {
            return Ok(ticks);
        }
        if start.elapsed() > RUN_LIMIT {
            bail!("the run took longer than {RUN_LIMIT:?}");
        }
        if node.wait(TICK).is_err() {
            bail!("interrupted");
        }
    }
}

/// How the bench follows a run: the probe on every topic, or only the step it is at.
enum Watcher {
    Probe(Box<Probe>),
    Progress(Progress),
}

impl Watcher {
    /// Opened before the run's processes start, so the first step is seen.
    fn open(
        node: &iceoryx2::prelude::Node<iceoryx2::prelude::ipc::Service>,
        probe: bool,
    ) -> Result<Watcher> {
        Ok(if probe {
            Watcher::Probe(Box::new(Probe::open(node, Endpoint::Sim)?))
        } else {
            Watcher::Progress(Progress::open(node, Endpoint::Sim)?)
        })
    }
}

/// What the probe cost and saw.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ProbeUse {
    /// The probe thread's CPU time and wake-ups per step.
    pub cpu_us_per_step: f64,
    pub wakeups_per_step: f64,
    /// Reception minus the sender's send time (the bare ring only, where senders stamp it).
    pub delay: Option<Summary>,
}

/// The probe's use over a run of `steps` steps; in the ring, its delay from step `first` on.
fn probe_use(seen: &Observed, steps: u64, ring_from: Option<u64>) -> ProbeUse {
    let steps = steps.max(1) as f64;
    ProbeUse {
        cpu_us_per_step: seen.cpu_ns as f64 / 1e3 / steps,
        wakeups_per_step: seen.wakeups as f64 / steps,
        delay: ring_from.map(|first| seen.delay(first)),
    }
}

/// Where the mesh's programs and files are, and what to run.
#[derive(Clone, Debug)]
pub struct MeshSetup {
    pub bin_dir: PathBuf,
    pub config_dir: PathBuf,
    pub mesh_file: PathBuf,
    pub episodes: u32,
    pub seed: u64,
    /// Steps not measured at the start (the first episode).
    pub warmup: u64,
    /// Run the probe at this real-time (`SCHED_FIFO`) priority; `None`: the normal one.
    pub probe_fifo: Option<i32>,
    /// Keep a flight record of the run (the recorder on, with the images of every K-th step).
    pub record_frame_every: Option<u32>,
}

/// One run of the real mesh.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MeshRun {
    pub probe_attached: bool,
    /// Closed-loop steps per second in the steady window, and the steps in it.
    pub steps_per_s: f64,
    pub steps: u64,
    /// From the supervisor's start to its exit.
    pub wall_s: f64,
    /// Without the probe: each process's CPU and memory.
    pub processes: Vec<ProcessUse>,
    /// Without the probe: cores busy with other work meanwhile (see [`other_cores`]).
    pub other_cores: f64,
    /// With the probe: latency per hop, per step and per cycle.
    pub hops: Option<HopLatencies>,
    pub probe: Option<ProbeUse>,
    /// Shared-memory files left after the run (should be none).
    pub leftovers: usize,
    /// With the recorder on: the flight record's size (every part), bytes.
    pub record_bytes: u64,
    /// With the recorder on: the steps it missed, every channel summed (its totals at close).
    #[serde(default)]
    pub record_holes: u64,
    /// Without the probe: the last step seen (the run's steps, the warm-up included).
    pub last_seq: u64,
}

/// Runs the mesh once through the supervisor, with images.
pub fn mesh(setup: &MeshSetup, with_probe: bool) -> Result<MeshRun> {
    let ns = Namespace::new(if with_probe { "p" } else { "m" });
    let scratch = ns.scratch();
    let node = probe::node(&ns.iox, "mesh-bench")?;
    let watcher = Watcher::open(&node, with_probe)?;
    let record_dir = scratch.join("record");
    let mut sets = vec![
        ("episodes", setup.episodes.to_string()),
        ("eyes", "images".to_owned()),
        ("json", scratch.join("run.json").display().to_string()),
        // A fresh state directory: the behaviours start from scratch, never from an earlier run.
        ("state", scratch.join("state").display().to_string()),
    ];
    if let Some(k) = setup.record_frame_every {
        std::fs::create_dir_all(&record_dir)
            .with_context(|| format!("creating {}", record_dir.display()))?;
        sets.push((
            "record",
            record_dir.join("flight.mcap").display().to_string(),
        ));
        sets.push(("frame_every", k.to_string()));
    }
    let args = runtime::MeshArgs::new(&setup.mesh_file, &setup.config_dir, setup.seed, &ns.iox)
        .with_sets(&sets)
        .command_line();
    let started = Instant::now();
    let mut sup = spawn(
        "supervisor",
        &setup.bin_dir.join("supervisor"),
        &args,
        &[],
        scratch.join("supervisor.log"),
    )?;
    let sup_pid = sup.started_pid() as i32;
    let mut run = MeshRun {
        probe_attached: with_probe,
        ..Default::default()
    };
    match watcher {
        Watcher::Progress(mut progress) => {
            let pids = || {
                let mut p = procfs::children(sup_pid);
                p.push(sup_pid);
                p
            };
            let ticks = watch(&node, &mut progress, pids, || sup.try_status().is_some())?;
            let w = window(&ticks, setup.warmup).with_context(|| {
                format!("the mesh never ran past its warm-up\n{}", sup.tail(30))
            })?;
            let (a, b) = (&ticks[w.0], &ticks[w.1]);
            run.steps = b.seq - a.seq;
            run.last_seq = ticks.last().map_or(0, |t| t.seq);
            run.steps_per_s = run.steps as f64 / ((b.t_ns - a.t_ns) as f64 * 1e-9);
            run.processes = usage(&ticks, w);
            run.other_cores = other_cores(&ticks, w);
        }
        Watcher::Probe(probe) => {
            probe::set_realtime(setup.probe_fifo)?;
            let seen = probe.run(PROBE_POLL, || sup.try_status().is_some());
            probe::set_realtime(None)?;
            let seen = seen?;
            let first = setup.warmup + 1;
            run.steps_per_s = seen.timeline.steps_per_s(first).unwrap_or(f64::NAN);
            let hops = seen.timeline.hops(first);
            run.steps = hops.hops.first().map_or(0, |h| h.n as u64);
            // The probe's cost per step over the whole run (its wake-ups start with the mesh).
            let all_steps = seen
                .timeline
                .last_seq(crate::timeline::Point::State)
                .unwrap_or(1);
            run.probe = Some(probe_use(&seen, all_steps, None));
            run.hops = Some(hops);
        }
    }
    let status = sup.wait_timeout(RUN_LIMIT);
    run.wall_s = started.elapsed().as_secs_f64();
    if !status.is_some_and(|s| s.success()) {
        bail!("the mesh failed ({status:?})\n{}", sup.tail(40));
    }
    drop(node);
    run.leftovers = ns.leftovers().len();
    if setup.record_frame_every.is_some() {
        // The record's parts: flight.mcap, flight.1.mcap, ...
        for entry in std::fs::read_dir(&record_dir)
            .with_context(|| format!("reading {}", record_dir.display()))?
        {
            run.record_bytes += entry?.metadata()?.len();
        }
        run.record_holes = recorder::holes(&record_dir.join("flight.mcap"))?
            .context("the flight record has no totals: the recorder did not stop cleanly")?;
    }
    Ok(run)
}

/// One run of the bare ring.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RingRun {
    pub probe_attached: bool,
    pub steps_per_s: f64,
    pub steps: u64,
    /// Each step from its state sent to its setpoints received, in the simulator node.
    pub step: Summary,
    /// Each node's input hop, one way (exact: senders stamp their send time).
    pub hops: Vec<(Role, Summary)>,
    /// Without the probe: CPU per step of the seven nodes together, and the cores busy with other
    /// work meanwhile.
    pub cpu_us_per_step: f64,
    pub other_cores: f64,
    /// With the probe: what it saw (its own delay) and cost.
    pub probe: Option<ProbeUse>,
    pub probe_hops: Option<HopLatencies>,
    pub leftovers: usize,
    #[serde(default)]
    pub shape: Shape,
    /// Paced: timed steps not answered before the next was due.
    #[serde(default)]
    pub missed: u64,
    /// The step latency's p99 95% confidence interval.
    #[serde(default)]
    pub step_p99_interval: Option<[u64; 2]>,
}

/// Runs the bare ring once: `warmup` steps, then `steps` timed.
pub fn ring(
    exe: &Path,
    config_dir: &Path,
    options: &RingOptions,
    with_probe: bool,
    probe_fifo: Option<i32>,
    placement: &Placement,
) -> Result<RingRun> {
    let ns = Namespace::new(if with_probe { "q" } else { "r" });
    let node = probe::node(&ns.iox, "mesh-bench")?;
    let watcher = Watcher::open(&node, with_probe)?;
    let [prefix, root] = ns.env();
    let env = [
        ("CABLETRACK_CONFIG", config_dir.display().to_string()),
        prefix,
        root,
        ("RUST_LOG", "warn".to_owned()),
    ];
    let mut nodes = Vec::new();
    let (warmup, steps) = (options.warmup, options.steps);
    // The simulator last: the others are listening by then (it re-sends until answered anyway).
    for role in options.shape.roles().iter().rev() {
        let mut args: Vec<String> = [
            "ring-node",
            "--role",
            &format!("{role:?}").to_lowercase(),
            "--shape",
            &format!("{:?}", options.shape).to_lowercase(),
            "--warmup",
            &warmup.to_string(),
            "--steps",
            &steps.to_string(),
        ]
        .map(String::from)
        .into();
        if let Some(p) = options.period {
            args.extend(["--period-us".to_owned(), p.as_micros().to_string()]);
        }
        if let (Role::Simulator, Some(path)) = (role, &options.latencies) {
            args.extend(["--latencies".to_owned(), path.display().to_string()]);
        }
        let log = ns.scratch().join(format!("{}.log", role.name()));
        let node = Spawn::new(exe)
            .name(role.name())
            .args(&args)
            .envs(env.iter().map(|(k, v)| (k, v)))
            .log(log)
            .die_with_parent()
            .placement(placement.clone())
            .start()
            .with_context(|| format!("starting the ring's {}", role.name()))?;
        nodes.push((*role, node));
    }
    let driver = nodes.len() - 1;
    let mut run = RingRun {
        probe_attached: with_probe,
        ..Default::default()
    };
    {
        let (others, last) = nodes.split_at_mut(driver);
        let sim = &mut last[0].1;
        match watcher {
            Watcher::Progress(mut progress) => {
                let pids: Vec<i32> = others
                    .iter()
                    .map(|(_, s)| s.started_pid() as i32)
                    .chain([sim.started_pid() as i32])
                    .collect();
                let ticks = watch(
                    &node,
                    &mut progress,
                    || pids.clone(),
                    || sim.try_status().is_some(),
                )?;
                if let Some(w) = window(&ticks, warmup) {
                    run.cpu_us_per_step = usage(&ticks, w)
                        .iter()
                        .map(|p| p.cpu_us_per_step)
                        .filter(|c| c.is_finite())
                        .sum();
                    run.other_cores = other_cores(&ticks, w);
                }
            }
            Watcher::Probe(probe) => {
                probe::set_realtime(probe_fifo)?;
                let seen = probe.run(PROBE_POLL, || sim.try_status().is_some());
                probe::set_realtime(None)?;
                let seen = seen?;
                run.probe = Some(probe_use(&seen, warmup + steps, Some(warmup + 1)));
                run.probe_hops = Some(seen.timeline.hops(warmup + 1));
            }
        }
        let status = sim.wait_timeout(RUN_LIMIT);
        if !status.is_some_and(|s| s.success()) {
            bail!("the ring failed ({status:?})\n{}", sim.tail(20));
        }
    }
    let mut reports: Vec<NodeReport> = Vec::new();
    for (role, node) in &mut nodes {
        let status = node.stop(Duration::from_secs(5));
        if !status.success() {
            bail!("ring node {role:?} failed ({status:?})\n{}", node.tail(20));
        }
        reports.push(
            ring::parse_report(&node.log())
                .with_context(|| format!("ring node {role:?}\n{}", node.tail(20)))?,
        );
    }
    let sim = reports
        .iter()
        .find(|r| r.role == Role::Simulator)
        .context("the ring's simulator report")?;
    run.steps_per_s = sim.steps_per_s();
    run.steps = sim.steps;
    run.step = sim.step.unwrap_or_default();
    run.shape = options.shape;
    run.missed = sim.missed;
    run.step_p99_interval = sim.step_p99_interval;
    run.hops = options
        .shape
        .roles()
        .iter()
        .filter_map(|role| {
            reports
                .iter()
                .find(|r| r.role == *role)
                .map(|r| (*role, r.hop))
        })
        .collect();
    drop(nodes);
    drop(node);
    run.leftovers = ns.leftovers().len();
    Ok(run)
}

/// One run of the same cores in one process, no IPC.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct InProcessRun {
    pub steps_per_s: f64,
    pub steps: u64,
    /// Cores busy with other work meanwhile.
    pub other_cores: f64,
    /// Time per step spent rendering and perceiving (the camera's and perception's cores).
    #[serde(default)]
    pub render_us_per_step: f64,
    #[serde(default)]
    pub perceive_us_per_step: f64,
    /// The loop's thread, per step.
    #[serde(default)]
    pub per_step: SchedRates,
}

/// The trainer's `World` with images and both NAC learners on one thread: the first episode is the
/// warm-up, the others are timed. A step is one pass of the loop, as in the mesh (an episode of
/// `n` transitions has `n + 1`: its terminal step is observed too).
pub fn in_process(config_dir: &Path, episodes: u32, seed: u64) -> Result<InProcessRun> {
    let setup = trainer::Setup::load(config_dir, config::Preset::Default)?
        .with_eyes(config::Eyes::Images)?;
    let mut world = trainer::world::World::new(
        &setup.scenario,
        &setup.learning,
        learning::Algorithm::Nac,
        setup.perceiver(seed),
        seed,
    );
    world.run_episode();
    let stage_times = |w: &trainer::world::World| match w.perceiver() {
        trainer::Perceiver::Images(v) => v.stage_times(),
        trainer::Perceiver::Ideal(_) => vision::StageTimes::default(),
    };
    let warm = stage_times(&world);
    let counts = SchedCounts::this_thread();
    let (busy, own) = (procfs::machine_busy_ns(), procfs::own_cpu_ns());
    let start = Instant::now();
    let steps: u64 = (1..episodes.max(2))
        .map(|_| world.run_episode().steps as u64 + 1)
        .sum();
    let wall = start.elapsed();
    let counts = SchedCounts::this_thread().since(&counts);
    let others = procfs::machine_busy_ns().saturating_sub(busy) as f64
        - procfs::own_cpu_ns().saturating_sub(own) as f64;
    let t = stage_times(&world);
    let per_step = |ns: u64| ns as f64 / 1e3 / steps.max(1) as f64;
    Ok(InProcessRun {
        steps_per_s: steps as f64 / wall.as_secs_f64(),
        steps,
        other_cores: (others / wall.as_nanos().max(1) as f64).max(0.0),
        render_us_per_step: per_step(t.render_ns - warm.render_ns),
        perceive_us_per_step: per_step(t.perceive_ns - warm.perceive_ns),
        per_step: SchedRates::of(&counts, steps as f64),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tick(t_ms: u64, seq: u64, cpu_ms: u64) -> Tick {
        Tick {
            t_ns: t_ms * 1_000_000,
            seq,
            procs: vec![ProcSample {
                pid: 7,
                name: "camera".into(),
                cpu_ns: cpu_ms * 1_000_000,
                utime_ticks: 3,
                stime_ticks: 1,
                rss_kb: 2048,
                hwm_kb: 4096,
                shmem_kb: 1024,
                sched: SchedCounts {
                    voluntary: 2 * seq,
                    minor_faults: 5,
                    ..Default::default()
                },
            }],
            // The machine busy twice the camera's time plus 1 ms per tick of the bench.
            busy_ns: (2 * cpu_ms + t_ms / 20) * 1_000_000,
            own_ns: t_ms / 20 * 1_000_000,
        }
    }

    #[test]
    fn the_window_is_the_steady_part() {
        // Start-up (seq 0), warm-up up to 201, running, then stopped at 900.
        let ticks = [
            tick(0, 0, 10),
            tick(20, 100, 12),
            tick(40, 250, 14),
            tick(60, 500, 20),
            tick(80, 800, 26),
            tick(100, 900, 28),
            tick(120, 900, 29),
            tick(140, 900, 29),
        ];
        let w = window(&ticks, 201).unwrap();
        assert_eq!(w, (2, 4));
        let u = usage(&ticks, w);
        assert_eq!(u.len(), 1);
        // 12 ms over 550 steps; the totals from the last reading.
        assert!((u[0].cpu_us_per_step - 12e3 / 550.0).abs() < 1e-9);
        assert_eq!(u[0].cpu_ms, 29.0);
        assert_eq!(
            (u[0].rss_mib, u[0].hwm_mib, u[0].shmem_mib),
            (2.0, 4.0, 1.0)
        );
        assert_eq!(u[0].sys_share, 0.25);
        // Two switches per step, no new page faults in the window.
        assert_eq!(u[0].per_step.voluntary, 2.0);
        assert_eq!(u[0].per_step.minor_faults, 0.0);
        assert!(window(&ticks[..3], 201).is_none());
        // 12 ms of other work over 40 ms.
        assert!((other_cores(&ticks, w) - 0.3).abs() < 1e-9);
    }
}
