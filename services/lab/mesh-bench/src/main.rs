//! `mesh-bench`: the service mesh's benchmark (see the library's docs). `scripts/bench-mesh` builds
//! and runs it.

use anyhow::{Context, Result};
use clap::{Args, Parser, Subcommand};
use mesh_bench::report::{Machine, Results, calibrate, load, thousands};
use mesh_bench::ring::{self, RingOptions, Role, Shape};
use mesh_bench::runs::{self, MeshSetup};
use mesh_bench::vehicle::{VehiclePath, VehicleSetup};
use runtime::CommonArgs;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    version,
    about = "Benchmarks the service mesh: steps/s with images, latency per hop and per step, CPU and memory per process, against the limit (the same cores in one process + a bare iceoryx2 ring).",
    args_conflicts_with_subcommands = true
)]
struct Cli {
    #[command(flatten)]
    bench: Bench,
    #[command(subcommand)]
    command: Option<Hidden>,
}

#[derive(Args)]
struct Bench {
    /// Episodes per run (the first one is the warm-up).
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u32).range(2..))]
    episodes: u32,
    /// Repeats of the whole set of runs; medians are reported (a run of the mesh can differ from
    /// the next by 10 to 20% on a 2-core VM, as the scheduler places its processes).
    #[arg(long, default_value_t = 7, value_parser = clap::value_parser!(u64).range(1..))]
    repeats: u64,
    /// Seed of the first repeat (the next ones take the next seeds).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Directory holding scenario.toml and learning.toml.
    #[arg(long, default_value = "config")]
    config: PathBuf,
    /// The mesh file the supervisor runs.
    #[arg(long, default_value = "config/sim-mesh.toml")]
    mesh: PathBuf,
    /// Run the probe's thread at this SCHED_FIFO priority (0: normal scheduling).
    #[arg(long, default_value_t = 0)]
    probe_fifo: i32,
    /// Write every run's figures here as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Write the Markdown report here too.
    #[arg(long)]
    markdown: Option<PathBuf>,
}

#[derive(Args)]
struct VehicleArgs {
    /// Frames to time, at least (at 5 Hz, 10,000 take 35 minutes).
    #[arg(long, default_value_t = 10_000, value_parser = clap::value_parser!(u64).range(1..))]
    steps: u64,
    /// Times real time (1: the vehicle's 5 Hz).
    #[arg(long, default_value_t = 1.0)]
    speed: f64,
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Step one's episodes in simulation, before the vehicle run.
    #[arg(long, default_value_t = 100)]
    sim_episodes: u32,
    #[command(flatten)]
    files: runs::VehicleFiles,
    /// Write the figures here as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Write the Markdown report here too.
    #[arg(long)]
    markdown: Option<PathBuf>,
    /// Keep every frame's latency here (CSV: seq,trial,step,time_ns,sent_ns,latency_ns), to look
    /// into the tail.
    #[arg(long)]
    latencies: Option<PathBuf>,
    /// Then measure the vehicle's limit at the same pace: the bare ring in the vehicle's shape (as
    /// many frames as were timed, at most 1,000) and perception's core alone (100 frames).
    #[arg(long)]
    limit: bool,
    /// Then the same over MAVLink: the BlueROV2's mesh (`--mavlink-mesh`, its `--mavlink-config`)
    /// with the twin as ArduSub stand-in, each frame timed to the first MANUAL_CONTROL carrying its
    /// command, as the autopilot reads it off its socket; reported beside this run.
    #[arg(long)]
    mavlink: bool,
    /// The MAVLink run's configuration directory.
    #[arg(long, default_value = "config/bluerov2")]
    mavlink_config: PathBuf,
    /// The MAVLink run's mesh file.
    #[arg(long, default_value = "config/bluerov2.toml")]
    mavlink_mesh: PathBuf,
    /// The camera over RTP/H.264 as a BlueROV2's: the twin streams its frames on UDP loopback and
    /// the camera decodes them (both built with `--features video`); each frame is also timed from
    /// its last packet sent to its cable observation. Not with --mavlink.
    #[arg(long, conflicts_with = "mavlink")]
    video: bool,
    /// --video: the twin's bitrate (kbit/s).
    #[arg(long, default_value_t = 4000, requires = "video")]
    video_kbps: u32,
    /// --video: the size the twin sends, WIDTHxHEIGHT.
    #[arg(long, default_value = "1920x1080", requires = "video")]
    video_size: String,
}

#[derive(Args)]
struct RecordArgs {
    /// Episodes per run (the first one is the warm-up).
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u32).range(2..))]
    episodes: u32,
    /// Pairs of runs (recorder off, recorder on); medians are reported.
    #[arg(long, default_value_t = 7, value_parser = clap::value_parser!(u64).range(1..))]
    repeats: u64,
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// The recorder keeps the images of every K-th step (the sim mesh's default: 10).
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u32).range(1..))]
    frame_every: u32,
    /// Directory holding scenario.toml and learning.toml.
    #[arg(long, default_value = "config")]
    config: PathBuf,
    /// The mesh file the supervisor runs.
    #[arg(long, default_value = "config/sim-mesh.toml")]
    mesh: PathBuf,
    /// Write every run's figures here as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
}

#[derive(Args)]
struct CutsArgs {
    /// SIGKILLs of the processes that write files (the recorder, the behaviours, the monitor).
    #[arg(long, default_value_t = 100)]
    cuts: u32,
    /// Seed of the random choices and of the mesh.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// The shortest and longest time between two cuts, in seconds.
    #[arg(long, num_args = 2, default_values_t = [0.3, 1.5], value_name = "S")]
    between: Vec<f64>,
    /// Put the vehicle's files on a tmpfs of this many MiB of its own (a mount namespace of the
    /// run's; needs root), which the flight record fills.
    #[arg(long, value_name = "MIB")]
    disk_mb: Option<u64>,
    /// Step one's episodes in simulation, before the vehicle run.
    #[arg(long, default_value_t = 10)]
    sim_episodes: u32,
    #[command(flatten)]
    files: runs::VehicleFiles,
    /// The Python interpreter with the `mcap` package (scripts/install-mcap-py).
    #[arg(long, default_value = "target/mcap-venv/bin/python")]
    python: PathBuf,
    /// The script that reads records with it.
    #[arg(
        long,
        default_value = "services/mesh/recorder/tests/read_cut_records.py"
    )]
    reader: PathBuf,
    /// Write the figures here as JSON (and the vehicle mesh's log beside it, as .log).
    #[arg(long)]
    json: Option<PathBuf>,
}

#[derive(Args)]
struct RingArgs {
    /// The path the ring takes.
    #[arg(long, value_enum, default_value_t = Shape::Vehicle)]
    shape: Shape,
    /// Milliseconds between steps (0: each step as soon as the last is answered); default: the
    /// scenario's sample time (the vehicle's camera period).
    #[arg(long)]
    period_ms: Option<f64>,
    /// Steps timed per run.
    #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u64).range(1..))]
    steps: u64,
    /// Steps not timed at the start of each run.
    #[arg(long, default_value_t = 10)]
    warmup: u64,
    /// Runs; each is reported, and all their steps together.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..))]
    repeats: u64,
    /// Directory holding scenario.toml.
    #[arg(long, default_value = "config")]
    config: PathBuf,
    /// Write every run's figures here as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Keep every step's latency in this directory, a file per run (ring-1.csv, ...; the vehicle's
    /// CSV: `mesh-bench latencies DIR/*.csv` pools them).
    #[arg(long)]
    latencies: Option<PathBuf>,
}

#[derive(Subcommand)]
enum Hidden {
    /// The flight recorder's cost: the mesh's steps/s with the recorder off and on (pairs of runs,
    /// swapping places every repeat), the recorder's CPU per step and the record's bytes per step.
    Record(RecordArgs),
    /// SIGKILLs at random moments of the processes that write files (the recorder, the behaviours,
    /// the monitor), optionally on a small file system that fills; every file read afterwards by
    /// readers that are not the project's.
    Cuts(CutsArgs),
    /// The vehicle endpoint: camera-to-thruster latency at 5 Hz over many steps, CPU and memory of
    /// every service (step one runs first, in simulation, for the policy the vehicle starts from).
    Vehicle(VehicleArgs),
    /// Several invocations' figures (their `--json` files) side by side, with the median and the
    /// range over them.
    Spread {
        #[arg(required = true, num_args = 1..)]
        files: Vec<PathBuf>,
    },
    /// Several vehicle runs' latencies (their `vehicle --latencies` files): each run's p50, p99 with
    /// its 95% confidence interval and max, and all their frames together.
    Latencies {
        #[arg(required = true, num_args = 1..)]
        files: Vec<PathBuf>,
    },
    /// The bare ring alone, by default in the vehicle's shape at the vehicle's 5 Hz: what the
    /// vehicle's processes and IPC cost a frame before any perceiving (the vehicle's limit).
    Ring(RingArgs),
    /// One node of the bare ring (started by the bench itself).
    #[command(hide = true)]
    RingNode {
        #[arg(long, value_enum)]
        role: Role,
        #[arg(long, value_enum, default_value_t = Shape::Mesh)]
        shape: Shape,
        /// A new step every this many microseconds (none: as soon as the last is answered).
        #[arg(long)]
        period_us: Option<u64>,
        /// The simulator node: keep every timed step's latency here (CSV).
        #[arg(long)]
        latencies: Option<PathBuf>,
        /// Steps not measured at the start.
        #[arg(long, default_value_t = 201)]
        warmup: u64,
        /// Steps measured (the simulator node stops after warmup + steps).
        #[arg(long)]
        steps: u64,
        #[command(flatten)]
        common: CommonArgs,
    },
}

fn main() -> ExitCode {
    let Cli {
        bench: args,
        command,
    } = Cli::parse();
    let result = match command {
        // A ring node is a process of the ring: `runtime::run` sets it up and reports how it ended.
        Some(Hidden::RingNode {
            role,
            shape,
            period_us,
            latencies: keep,
            warmup,
            steps,
            common,
        }) => {
            let options = RingOptions {
                shape,
                warmup,
                steps,
                period: period_us.map(std::time::Duration::from_micros),
                latencies: keep,
            };
            return runtime::run(role.name(), &common, |rt| {
                let report = ring::run(rt, role, &options)?;
                cli::outln!("{}", serde_json::to_string(&report)?)?;
                Ok(())
            });
        }
        // Reading files of runs already made: nothing to log.
        Some(Hidden::Spread { files }) => spread(&files),
        Some(Hidden::Latencies { files }) => latencies(&files),
        Some(Hidden::Record(a)) => logged(|| record(&a)),
        Some(Hidden::Vehicle(a)) => logged(|| vehicle(&a)),
        Some(Hidden::Cuts(a)) => logged(|| cuts(&a)),
        Some(Hidden::Ring(a)) => logged(|| bare_ring(&a)),
        None => logged(|| bench(&args)),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => cli::fail("mesh-bench", err.as_ref()),
    }
}

/// Runs a benchmark with its progress logged.
fn logged(bench: impl FnOnce() -> Result<()>) -> Result<()> {
    runtime::init_tracing();
    bench()
}

fn vehicle(args: &VehicleArgs) -> Result<()> {
    if !(args.speed.is_finite() && args.speed > 0.0) {
        anyhow::bail!("--speed {} must be a number > 0", args.speed);
    }
    let exe = std::env::current_exe()?;
    let path = if args.video {
        VehiclePath::Video
    } else {
        VehiclePath::Twin
    };
    let setup = vehicle_setup(args, &args.files, path)?;
    let scenario = setup.run.scenario()?;
    let mut run = mesh_bench::vehicle::run(&setup)?;
    if args.limit {
        let period = std::time::Duration::from_secs_f64(setup.period_s / setup.speed);
        let frames = (run.latency.n as u64).clamp(1, 1000);
        eprintln!(
            "mesh-bench: vehicle: its limit, the bare ring ({frames} frames, one every {period:?}) and perception's core"
        );
        let options = RingOptions {
            shape: Shape::Vehicle,
            warmup: 10,
            steps: frames,
            period: Some(period),
            latencies: None,
        };
        let ring = runs::ring(
            &exe,
            &setup.run.files.config,
            &options,
            false,
            None,
            &Default::default(),
        )
        .context("the vehicle's limit: the bare ring")?;
        let perception =
            mesh_bench::vehicle::perception_at_pace(&scenario, 100, setup.period_s, period)
                .context("the vehicle's limit: perception's core")?;
        run.limit = Some(mesh_bench::vehicle::VehicleLimit { ring, perception });
    }
    if args.mavlink {
        let files = runs::VehicleFiles {
            config: args.mavlink_config.clone(),
            sim_mesh: args.files.sim_mesh.clone(),
            vehicle_mesh: args.mavlink_mesh.clone(),
        };
        let mut setup = vehicle_setup(args, &files, VehiclePath::Mavlink)?;
        // Its frames kept beside the first run's: NAME-mavlink.csv.
        setup.keep_latencies = args.latencies.as_ref().map(|p| {
            let stem = p.file_stem().unwrap_or_default().to_string_lossy();
            p.with_file_name(format!("{stem}-mavlink.csv"))
        });
        eprintln!("mesh-bench: vehicle: the same over MAVLink");
        run.mavlink = Some(Box::new(mesh_bench::vehicle::run(&setup)?));
    }
    let markdown = run.markdown(args.steps);
    report(
        &run,
        &markdown,
        args.json.as_deref(),
        args.markdown.as_deref(),
    )
}

/// The run of `files` on `path`, its trials sized from the configuration's twin.
fn vehicle_setup(
    args: &VehicleArgs,
    files: &runs::VehicleFiles,
    path: VehiclePath,
) -> Result<VehicleSetup> {
    let run = runs::VehicleRunSetup::new(files, args.seed, args.sim_episodes)?;
    let scenario = run.scenario()?;
    let twin: config::TwinParams = config::load(&run.files.config.join("twin.toml"))?;
    Ok(VehicleSetup {
        run,
        path,
        steps: args.steps,
        speed: args.speed,
        steps_per_trial: (twin.trials.duration_s / scenario.timing.sample_time_s).round() as u32,
        drop_probability: twin.frames.dropped.rate(),
        period_s: scenario.timing.sample_time_s,
        keep_latencies: args.latencies.clone(),
        video: mesh_bench::vehicle::VideoStream {
            kbps: args.video_kbps,
            size: args.video_size.clone(),
        },
    })
}

fn cuts(args: &CutsArgs) -> Result<()> {
    let setup = mesh_bench::cuts::CutsSetup {
        run: runs::VehicleRunSetup::new(&args.files, args.seed, args.sim_episodes)?,
        cuts: args.cuts,
        between_s: (args.between[0], args.between[1].max(args.between[0])),
        disk_mb: args.disk_mb,
        // Not resolved: the virtual environment's interpreter is a link to the system's.
        python: std::path::absolute(&args.python)?,
        reader: args
            .reader
            .canonicalize()
            .with_context(|| format!("the reader script {}", args.reader.display()))?,
        keep_log: args.json.as_ref().map(|j| j.with_extension("log")),
    };
    if !setup.python.exists() {
        anyhow::bail!(
            "{} is missing: run scripts/install-mcap-py",
            setup.python.display()
        );
    }
    let run = mesh_bench::cuts::run(&setup)?;
    cli::outln!("{}", serde_json::to_string_pretty(&run)?)?;
    cli::outln!("{}", run.markdown())?;
    if let Some(path) = &args.json {
        std::fs::write(path, serde_json::to_string_pretty(&run)?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}

/// Prints several invocations' figures (their `--json` files) side by side.
fn spread(files: &[PathBuf]) -> Result<()> {
    let all = read_runs(files, |f, text| {
        serde_json::from_str::<Results>(text)
            .with_context(|| format!("{}: not the figures of `mesh-bench --json`", f.display()))
    })?;
    cli::outln!("{}", mesh_bench::report::spread(&all))?;
    Ok(())
}

/// Prints the latency table of several vehicle runs' `--latencies` files.
fn latencies(files: &[PathBuf]) -> Result<()> {
    let runs = read_runs(files, |f, text| {
        records::latency::read_latencies(text).map_err(|e| anyhow::anyhow!("{}: {e}", f.display()))
    })?;
    cli::outln!("{}", mesh_bench::vehicle::latency_table(&runs))?;
    Ok(())
}

/// Each file read and parsed, named after its file name without the extension.
fn read_runs<T>(
    files: &[PathBuf],
    parse: impl Fn(&std::path::Path, &str) -> Result<T>,
) -> Result<Vec<(String, T)>> {
    files
        .iter()
        .map(|f| {
            let text =
                std::fs::read_to_string(f).with_context(|| format!("reading {}", f.display()))?;
            let name = f.file_stem().map_or_else(
                || f.display().to_string(),
                |s| s.to_string_lossy().into_owned(),
            );
            Ok((name, parse(f, &text)?))
        })
        .collect()
}

/// Prints the Markdown report and writes it and the figures (JSON) where asked.
fn report(
    figures: &impl serde::Serialize,
    markdown: &str,
    json: Option<&std::path::Path>,
    md: Option<&std::path::Path>,
) -> Result<()> {
    mesh_bench::report::publish("mesh-bench", figures, markdown, json, md)
}

fn bench(args: &Bench) -> Result<()> {
    let config_dir = args
        .config
        .canonicalize()
        .with_context(|| format!("the config directory {}", args.config.display()))?;
    let mesh_file = args
        .mesh
        .canonicalize()
        .with_context(|| format!("the mesh file {}", args.mesh.display()))?;
    let scenario: config::Scenario = config::load(&config_dir.join("scenario.toml"))?;
    let exe = std::env::current_exe()?;
    let bin_dir = exe.parent().context("the bench's directory")?.to_owned();
    // A step is one pass of the loop: an episode of at most max_steps transitions has max_steps + 1.
    let episode_steps = scenario.timing.max_steps as u64 + 1;
    let warmup = episode_steps;
    let ring_steps = (args.episodes as u64 - 1) * episode_steps;
    let mut results = Results {
        machine: Machine::read(),
        episodes: args.episodes,
        repeats: args.repeats as usize,
        seed: args.seed,
        episode_steps,
        warmup,
        ..Default::default()
    };
    let ring_options = RingOptions {
        shape: Shape::Mesh,
        warmup,
        steps: ring_steps,
        period: None,
        latencies: None,
    };
    let placement = runs::loop_placement(&mesh_file)?;
    results.loop_cpus = placement.cpus.clone();
    results.machine.calibration_ms[0] = calibrate();
    eprintln!(
        "mesh-bench: {} repeats of {} episodes on {} cores (load average {:.2})",
        args.repeats, args.episodes, results.machine.cores, results.machine.load_before
    );
    for r in 0..args.repeats {
        let setup = MeshSetup {
            bin_dir: bin_dir.clone(),
            config_dir: config_dir.clone(),
            mesh_file: mesh_file.clone(),
            episodes: args.episodes,
            seed: args.seed + r,
            warmup,
            probe_fifo: (args.probe_fifo > 0).then_some(args.probe_fifo),
            record_frame_every: None,
        };
        // The two mesh runs swap places every repeat, so a drift of the machine favours neither.
        let (mesh, mesh_probe) = if r % 2 == 0 {
            let m = runs::mesh(&setup, false).context("the mesh")?;
            (
                m,
                runs::mesh(&setup, true).context("the mesh with the probe")?,
            )
        } else {
            let p = runs::mesh(&setup, true).context("the mesh with the probe")?;
            (runs::mesh(&setup, false).context("the mesh")?, p)
        };
        let in_process = runs::in_process(&config_dir, args.episodes, setup.seed)
            .context("the cores in one process")?;
        let ring = runs::ring(&exe, &config_dir, &ring_options, false, None, &placement)
            .context("the ring")?;
        let ring_probe = runs::ring(
            &exe,
            &config_dir,
            &ring_options,
            true,
            setup.probe_fifo,
            &placement,
        )
        .context("the ring with the probe")?;
        let step_p99 = mesh_probe
            .hops
            .as_ref()
            .and_then(|h| h.hops.get(7))
            .map_or(0, |s| s.p99);
        eprintln!(
            "  repeat {}/{}: mesh {} steps/s (with probe {}, step p99 {:.2} ms); in one process {}; bare ring {} (with probe {}); other load {:.2}/{:.2}/{:.2} cores",
            r + 1,
            args.repeats,
            thousands(mesh.steps_per_s),
            thousands(mesh_probe.steps_per_s),
            step_p99 as f64 / 1e6,
            thousands(in_process.steps_per_s),
            thousands(ring.steps_per_s),
            thousands(ring_probe.steps_per_s),
            mesh.other_cores,
            in_process.other_cores,
            ring.other_cores,
        );
        results.mesh.push(mesh);
        results.mesh_probe.push(mesh_probe);
        results.in_process.push(in_process);
        results.ring.push(ring);
        results.ring_probe.push(ring_probe);
    }
    results.machine.load_after = load();
    results.machine.calibration_ms[1] = calibrate();
    let markdown = results.markdown();
    report(
        &results,
        &markdown,
        args.json.as_deref(),
        args.markdown.as_deref(),
    )?;
    left_nothing_behind(results.leftovers())
}

/// Fails a benchmark whose runs left shared-memory files behind (each run has a namespace of its
/// own and counts what is left of it before removing it).
fn left_nothing_behind(leftovers: usize) -> Result<()> {
    if leftovers > 0 {
        anyhow::bail!("the runs left {leftovers} shared-memory files behind (see the report)");
    }
    Ok(())
}

/// The bare ring alone, `--repeats` runs: each run's step latency and hops.
fn bare_ring(args: &RingArgs) -> Result<()> {
    let config_dir = args
        .config
        .canonicalize()
        .with_context(|| format!("the config directory {}", args.config.display()))?;
    let scenario: config::Scenario = config::load(&config_dir.join("scenario.toml"))?;
    let period_ms = args
        .period_ms
        .unwrap_or(1e3 * scenario.timing.sample_time_s);
    if !(period_ms.is_finite() && period_ms >= 0.0) {
        anyhow::bail!("--period-ms {period_ms} must be a number >= 0");
    }
    let mut options = RingOptions {
        shape: args.shape,
        warmup: args.warmup,
        steps: args.steps,
        period: (period_ms > 0.0).then(|| std::time::Duration::from_secs_f64(period_ms / 1e3)),
        latencies: None,
    };
    if let Some(dir) = &args.latencies {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let exe = std::env::current_exe()?;
    eprintln!(
        "mesh-bench: the bare ring in the {:?} shape, {} run(s) of {} steps{} (load average {:.2})",
        args.shape,
        args.repeats,
        args.steps,
        options
            .period
            .map_or(String::new(), |p| format!(", one every {p:?}")),
        Machine::read().load_before
    );
    let mut runs = Vec::new();
    for r in 0..args.repeats {
        options.latencies = args
            .latencies
            .as_ref()
            .map(|dir| dir.join(format!("ring-{}.csv", r + 1)));
        let run = runs::ring(
            &exe,
            &config_dir,
            &options,
            false,
            None,
            &Default::default(),
        )
        .with_context(|| format!("run {} of the ring", r + 1))?;
        eprintln!(
            "  run {}/{}: step p50 {:.0} µs, p99 {:.0} µs, {} missed; {:.0} µs of CPU per step; other load {:.2} cores",
            r + 1,
            args.repeats,
            run.step.p50 as f64 / 1e3,
            run.step.p99 as f64 / 1e3,
            run.missed,
            run.cpu_us_per_step,
            run.other_cores
        );
        runs.push(run);
    }
    let markdown = mesh_bench::report::ring_markdown(&runs);
    report(&runs, &markdown, args.json.as_deref(), None)
}

/// The recorder's cost, pairs of runs of the same seed.
fn record(args: &RecordArgs) -> Result<()> {
    let canon = |p: &PathBuf, what: &str| {
        p.canonicalize()
            .with_context(|| format!("{what} {}", p.display()))
    };
    let config_dir = canon(&args.config, "the config directory")?;
    let mesh_file = canon(&args.mesh, "the mesh file")?;
    let scenario: config::Scenario = config::load(&config_dir.join("scenario.toml"))?;
    let exe = std::env::current_exe()?;
    let episode_steps = scenario.timing.max_steps as u64 + 1;
    eprintln!(
        "mesh-bench record: {} pairs of runs of {} episodes, the recorder keeping the images of every {} steps (load average {:.2})",
        args.repeats,
        args.episodes,
        args.frame_every,
        load()
    );
    let mut pairs = Vec::new();
    for r in 0..args.repeats {
        let setup = MeshSetup {
            bin_dir: exe.parent().context("the bench's directory")?.to_owned(),
            config_dir: config_dir.clone(),
            mesh_file: mesh_file.clone(),
            episodes: args.episodes,
            seed: args.seed + r,
            warmup: episode_steps,
            probe_fifo: None,
            record_frame_every: None,
        };
        let on = MeshSetup {
            record_frame_every: Some(args.frame_every),
            ..setup.clone()
        };
        // The two runs swap places every repeat, so a drift of the machine favours neither.
        let (off, on) = if r % 2 == 0 {
            let off = runs::mesh(&setup, false).context("the mesh, recorder off")?;
            (
                off,
                runs::mesh(&on, false).context("the mesh, recorder on")?,
            )
        } else {
            let on = runs::mesh(&on, false).context("the mesh, recorder on")?;
            (
                runs::mesh(&setup, false).context("the mesh, recorder off")?,
                on,
            )
        };
        let rec = on.processes.iter().find(|p| p.name == "recorder");
        eprintln!(
            "  repeat {}/{}: recorder off {} steps/s, on {} steps/s ({:.3}); recorder {:.1} µs CPU per step; record {:.1} MB, {} steps missed",
            r + 1,
            args.repeats,
            thousands(off.steps_per_s),
            thousands(on.steps_per_s),
            on.steps_per_s / off.steps_per_s,
            rec.map_or(f64::NAN, |p| p.cpu_us_per_step),
            on.record_bytes as f64 / 1e6,
            on.record_holes,
        );
        pairs.push((off, on));
    }
    let median =
        |f: &dyn Fn(&(runs::MeshRun, runs::MeshRun)) -> f64| stats::median(pairs.iter().map(f));
    let off = median(&|p| p.0.steps_per_s);
    let on = median(&|p| p.1.steps_per_s);
    let ratio = median(&|p| p.1.steps_per_s / p.0.steps_per_s);
    let cpu = median(&|p| {
        p.1.processes
            .iter()
            .find(|u| u.name == "recorder")
            .map_or(f64::NAN, |u| u.cpu_us_per_step)
    });
    // Bytes per step over the whole run (every step is recorded, the warm-up too).
    let bytes_per_step = median(&|p| p.1.record_bytes as f64 / p.1.last_seq.max(1) as f64);
    let holes: u64 = pairs.iter().map(|p| p.1.record_holes).sum();
    let markdown = format!(
        "| flight recorder, {} pairs of runs x {} episodes, images of every {} steps | median |\n|---|---:|\n\
         | mesh, recorder off | {} steps/s |\n\
         | mesh, recorder on | {} steps/s |\n\
         | on / off (median of the pairs' ratios) | {:.3} |\n\
         | recorder's CPU per step | {:.1} µs |\n\
         | record per step | {:.1} kB |\n\
         | steps the recorder missed, all channels, all runs | {} |\n",
        args.repeats,
        args.episodes,
        args.frame_every,
        thousands(off),
        thousands(on),
        ratio,
        cpu,
        bytes_per_step / 1e3,
        holes,
    );
    report(&pairs, &markdown, args.json.as_deref(), None)?;
    left_nothing_behind(
        pairs
            .iter()
            .map(|(off, on)| off.leftovers + on.leftovers)
            .sum(),
    )
}
