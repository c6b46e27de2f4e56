//! The vehicle endpoint's benchmark (`mesh-bench vehicle`): camera-to-thruster latency at the
//! vehicle's 5 Hz over many steps, and each service's CPU and resident memory.
//!
//! The run is what the vehicle does in step two: the step-one policy is learned first through the
//! simulation mesh (`config/sim-mesh.toml`, ideal perception, fast), then `config/vehicle.toml` runs
//! the vehicle services against the twin, paced by its clock, learning online. The twin times every
//! frame from its publication to the arrival of the setpoints answering it (`vehicle-twin --latency`,
//! see `vehicle_twin::latency`): the whole vehicle path, both hardware adapters and every wake-up
//! included. Meanwhile the bench reads each process in `/proc` every [`TICK`].
//!
//! With `--mavlink` the same run follows over MAVLink, a BlueROV2 under ArduSub
//! (`config/bluerov2.toml`, the camera on the twin's frame topic): the thruster driver pilots the
//! twin's ArduSub stand-in with MANUAL_CONTROL on UDP loopback, and the twin times every frame from
//! its publication to the moment its autopilot reads the first MANUAL_CONTROL carrying the frame's
//! command off its socket (the wire's far end: the driver's socket, the kernel's and the autopilot's
//! wake-up included). The driver sends MANUAL_CONTROL at a steady 20 Hz, holding the last command
//! between steps; held repeats are not answers, the one sent at once for a new step is.
//!
//! With `--video` the camera comes as a BlueROV2's does, RTP/H.264 on UDP loopback: the twin encodes
//! its frames (`vehicle-twin --video`) and the camera decodes them (`camera --source rtp:...`), both
//! built with the `video` feature. Each frame is then timed from its last packet sent, and a
//! subscriber of the bench's also times it to its cable observation (perception's answer; the
//! subscriber's own wake-up included, as any consumer's would be).

use crate::procfs;
use crate::runs::{ProcessUse, RingRun, Tick, VehicleRunSetup, usage};
use anyhow::{Context, Result, bail};
use runtime::Namespace;
use runtime::clock::monotonic_ns;
use serde::{Deserialize, Serialize};
use stats::Summary;
use std::fmt::Write as _;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// How often the processes are read.
const TICK: Duration = Duration::from_secs(1);
/// How often progress is printed.
const PROGRESS: Duration = Duration::from_secs(60);

/// Which vehicle path a run measures.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum VehiclePath {
    /// `config/vehicle.toml`: the twin's thrusters on shared memory.
    #[default]
    Twin,
    /// `config/bluerov2.toml`: the twin's ArduSub stand-in, piloted with MANUAL_CONTROL over UDP.
    Mavlink,
    /// `config/vehicle.toml` with the camera over RTP/H.264 (`--video`).
    Video,
}

impl VehiclePath {
    /// What the run's latency runs to.
    pub fn what(self) -> &'static str {
        match self {
            VehiclePath::Twin => {
                "twin frame published → setpoints at the twin's thrusters (shared memory)"
            }
            VehiclePath::Mavlink => {
                "twin frame published → first MANUAL_CONTROL carrying its command, read by the twin's ArduSub stand-in (MAVLink, UDP loopback)"
            }
            VehiclePath::Video => {
                "twin frame's last RTP/H.264 packet sent → setpoints at the twin's thrusters (the camera decoding the stream)"
            }
        }
    }
}

/// What to run.
#[derive(Clone, Debug)]
pub struct VehicleSetup {
    pub path: VehiclePath,
    pub run: VehicleRunSetup,
    /// Frames to time, at least.
    pub steps: u64,
    /// Times real time (1: the vehicle's 5 Hz).
    pub speed: f64,
    /// The twin's steps per trial and dropped-frame probability, and the control period (s).
    pub steps_per_trial: u32,
    pub drop_probability: f64,
    pub period_s: f64,
    /// Where to keep every frame's latency (the twin's CSV), if anywhere.
    pub keep_latencies: Option<PathBuf>,
    /// The twin's stream on the [`VehiclePath::Video`] path.
    pub video: VideoStream,
}

/// The twin's RTP/H.264 stream (`vehicle-twin --video-kbps`, `--video-size`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct VideoStream {
    pub kbps: u32,
    /// WIDTHxHEIGHT.
    pub size: String,
}

impl VehicleSetup {
    /// Trials enough for `steps` answered frames, with a margin for dropped frames.
    pub fn trials(&self) -> u32 {
        let per_trial = (self.steps_per_trial as f64 + 1.0) * (1.0 - self.drop_probability) * 0.97;
        (self.steps as f64 / per_trial).ceil().max(1.0) as u32
    }
}

/// The results of one run.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct VehicleRun {
    #[serde(default)]
    pub path: VehiclePath,
    pub speed: f64,
    pub trials: u32,
    pub wall_s: f64,
    /// Camera-to-thruster latency per answered frame (ns).
    pub latency: Summary,
    /// The latency's p99 95% confidence interval (ns), from the frames' order statistics; `None`
    /// with too few frames to bound it.
    #[serde(default)]
    pub p99_interval: Option<[u64; 2]>,
    /// Each process's CPU (per step: per control period) and memory.
    pub processes: Vec<ProcessUse>,
    /// Cores busy with other work meanwhile.
    pub other_cores: f64,
    /// Restarts the supervisor logged (should be none).
    pub restarts: usize,
    /// Shared-memory files left after the run (should be none).
    pub leftovers: usize,
    /// The flight record's size (every part, every frame), bytes, and the frames timed with it.
    pub record_bytes: u64,
    /// The vehicle's limit on the same machine, measured after the run (`--limit`).
    #[serde(default)]
    pub limit: Option<VehicleLimit>,
    /// The same over MAVLink, run after this one (`--mavlink`).
    #[serde(default)]
    pub mavlink: Option<Box<VehicleRun>>,
    /// Over RTP/H.264: the stream, and per answered frame the time from its last packet sent to
    /// its cable observation at the bench's subscriber (ns).
    #[serde(default)]
    pub video: Option<VideoStream>,
    #[serde(default)]
    pub to_observation: Option<Summary>,
    /// The dive's length in the record (s): the twin's trials at the control period.
    #[serde(default)]
    pub dive_s: f64,
}

/// What the vehicle's path costs on this machine without the vehicle's work: the bare ring in the
/// vehicle's shape at the same pace (every process and hop of the path, nothing perceived), and
/// perception's core alone at that pace, the one piece of the path's work the ring leaves out (the
/// behaviours', allocator's and driver's arithmetic takes microseconds).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct VehicleLimit {
    pub ring: RingRun,
    /// Perception tracking along a path on one thread, the frames a period apart (ns per frame).
    pub perception: Summary,
}

impl VehicleLimit {
    /// The limit's p50: the ring's plus perception's.
    pub fn p50_ns(&self) -> u64 {
        self.ring.step.p50 + self.perception.p50
    }
}

/// Perception's core at the vehicle's pace: `frames` frames along a tracking path, each taken
/// `dt_s` after the last (the scenario's sample time) and perceived `pause` after it.
pub fn perception_at_pace(
    scenario: &config::Scenario,
    frames: usize,
    dt_s: f64,
    pause: Duration,
) -> Result<Summary> {
    let mut renderer = vision::Renderer::from_scenario(scenario, 1)?;
    let path = vision::pace::tracking_path(frames, dt_s);
    let sequence = vision::pace::render_path(&mut renderer, &path);
    let mut perception = vision::Perception::from_scenario(scenario)?;
    let us = vision::pace::perceive_paced(&mut perception, &sequence, dt_s, Some(pause));
    let ns: Vec<u64> = us.iter().map(|u| (u * 1e3).round() as u64).collect();
    Ok(Summary::of(&ns))
}

/// Runs step one in simulation, then the vehicle mesh at `speed`, and measures it.
pub fn run(setup: &VehicleSetup) -> Result<VehicleRun> {
    let ns = Namespace::new("v");
    let scratch = ns.scratch();
    // Step one: the policy the vehicle starts from.
    let step_one = setup.run.step_one(&ns, "mesh-bench: vehicle")?;

    // Step two on the twin, at the vehicle's pace.
    let trials = setup.trials();
    let latency_file = scratch.join("latency.csv");
    let sets = [
        ("trials", trials.to_string()),
        ("pacing", format!("--speed={}", setup.speed)),
        ("initial", step_one.display().to_string()),
        ("state", scratch.join("step-two").display().to_string()),
        (
            "json",
            scratch.join("step-two/run.json").display().to_string(),
        ),
        (
            "trace",
            scratch.join("step-two/trace.jsonl").display().to_string(),
        ),
        ("latency", format!("--latency={}", latency_file.display())),
        ("mavlink", String::new()),
        ("video", String::new()),
        ("source", String::new()),
        // The flight record, as a vehicle keeps it (every frame), in the run's own directory.
        (
            "record",
            scratch.join("record/flight.mcap").display().to_string(),
        ),
    ];
    let sets: Vec<(&str, String)> = match setup.path {
        VehiclePath::Twin => sets.into_iter().filter(|(_, v)| !v.is_empty()).collect(),
        // The autopilot's port on loopback; the camera on the twin's frame topic (a default build
        // has no GStreamer), so that both paths differ only in how the commands leave the driver.
        VehiclePath::Mavlink => {
            let port = std::net::UdpSocket::bind("127.0.0.1:0")?
                .local_addr()?
                .port();
            sets.into_iter()
                .map(|(k, v)| match k {
                    "mavlink" => (k, format!("127.0.0.1:{port}")),
                    "source" => (k, "twin".into()),
                    _ => (k, v),
                })
                .collect()
        }
        // The stream on a free loopback port.
        VehiclePath::Video => {
            let port = std::net::UdpSocket::bind("127.0.0.1:0")?
                .local_addr()?
                .port();
            sets.into_iter()
                .map(|(k, v)| match k {
                    "video" => (k, format!("--video=rtp:127.0.0.1:{port}")),
                    "source" => (k, format!("rtp:127.0.0.1:{port}")),
                    _ => (k, v),
                })
                .chain([
                    ("video_kbps", setup.video.kbps.to_string()),
                    ("video_size", setup.video.size.clone()),
                ])
                .filter(|(_, v)| !v.is_empty())
                .collect()
        }
    };
    // Over RTP/H.264, each frame's cable observation as a subscriber of the bench's takes it.
    let observations = (setup.path == VehiclePath::Video)
        .then(|| ObservationWatch::start(&ns.iox))
        .transpose()?;
    std::fs::create_dir_all(scratch.join("record"))?;
    let expected_s =
        trials as f64 * (setup.steps_per_trial + 1) as f64 * setup.period_s / setup.speed;
    eprintln!(
        "mesh-bench: vehicle: {trials} trials on the twin at {}x real time, about {:.0} s",
        setup.speed, expected_s
    );
    let started = Instant::now();
    let mut sup = setup
        .run
        .start_vehicle(&ns, &sets, &[], scratch.join("vehicle.log"))?;
    let sup_pid = sup.started_pid() as i32;
    let limit = Duration::from_secs_f64(expected_s * 1.5 + 120.0);
    let period_ns = setup.period_s / setup.speed * 1e9;
    let t0 = monotonic_ns();
    let mut ticks = Vec::new();
    let mut last_progress = Instant::now();
    while sup.try_status().is_none() {
        let mut pids = procfs::children(sup_pid);
        pids.push(sup_pid);
        let t_ns = monotonic_ns();
        ticks.push(Tick {
            t_ns,
            // Control periods so far: the clock paces the loop, so CPU per period is CPU per step.
            seq: ((t_ns - t0) as f64 / period_ns) as u64,
            procs: pids.into_iter().filter_map(procfs::sample).collect(),
            busy_ns: procfs::machine_busy_ns(),
            own_ns: procfs::own_cpu_ns(),
        });
        if started.elapsed() > limit {
            bail!(
                "the vehicle run took longer than {limit:?}\n{}",
                sup.tail(30)
            );
        }
        if last_progress.elapsed() >= PROGRESS {
            last_progress = Instant::now();
            eprintln!(
                "mesh-bench: vehicle: {:.0} s of about {:.0} s",
                started.elapsed().as_secs_f64(),
                expected_s
            );
        }
        // The supervisor's exit has nothing to block on here; readings are due every TICK anyway.
        if sup.wait_timeout(TICK).is_some() {
            break;
        }
    }
    let status = sup.try_status();
    let wall_s = started.elapsed().as_secs_f64();
    let observed = observations.map(ObservationWatch::stop).transpose()?;
    if !status.is_some_and(|s| s.success()) {
        bail!("the vehicle mesh failed ({status:?})\n{}", sup.tail(40));
    }
    let text = std::fs::read_to_string(&latency_file)
        .with_context(|| format!("reading {}", latency_file.display()))?;
    if let Some(keep) = &setup.keep_latencies {
        std::fs::write(keep, &text).with_context(|| format!("writing {}", keep.display()))?;
    }
    let samples = records::latency::read_samples(&text)
        .map_err(|e| anyhow::anyhow!("{}: {e}", latency_file.display()))?;
    let latencies: Vec<u64> = samples
        .iter()
        .map(|s| s.latency.as_nanos() as u64)
        .collect();
    let to_observation = observed.map(|seen| {
        let times = to_observation(&samples, &seen);
        eprintln!(
            "mesh-bench: vehicle: {} of {} answered frames' observations seen",
            times.len(),
            samples.len()
        );
        Summary::of(&times)
    });
    // The steady window: every service up, from 10 s in (start-up and the first trial's set-up out),
    // to the last reading with every process still there (they stop one by one).
    let skip = (10.0e9 / period_ns).ceil() as u64;
    let everyone = ticks.iter().map(|t| t.procs.len()).max().unwrap_or(0);
    let all_up = |t: &&Tick| t.procs.len() >= everyone;
    let a = ticks
        .iter()
        .position(|t| t.seq > skip && all_up(&t))
        .or_else(|| ticks.iter().position(|t| all_up(&t)))
        .unwrap_or(0);
    let b = ticks.iter().rposition(|t| all_up(&t)).unwrap_or(a);
    let (processes, other_cores) = if b > a {
        (
            usage(&ticks, (a, b)),
            crate::runs::other_cores(&ticks, (a, b)),
        )
    } else {
        (Vec::new(), f64::NAN)
    };
    let restarts = sup.log().matches("restarting").count();
    let mut record_bytes = 0;
    for entry in std::fs::read_dir(scratch.join("record"))? {
        record_bytes += entry?.metadata()?.len();
    }
    Ok(VehicleRun {
        path: setup.path,
        mavlink: None,
        video: (setup.path == VehiclePath::Video).then(|| setup.video.clone()),
        to_observation,
        dive_s: trials as f64 * (setup.steps_per_trial + 1) as f64 * setup.period_s,
        record_bytes,
        speed: setup.speed,
        trials,
        wall_s,
        latency: Summary::of(&latencies),
        p99_interval: p99_interval(&latencies),
        processes,
        other_cores,
        restarts,
        leftovers: ns.leftovers().len(),
        limit: None,
    })
}

/// Frames enough for a 95% confidence interval of a p99 within the samples (0.99^n <= 0.025).
pub const P99_FRAMES: usize = 368;

/// The 95% confidence interval of the p99 of `latencies` (any order), as two of them.
pub fn p99_interval(latencies: &[u64]) -> Option<[u64; 2]> {
    let (lo, hi) = stats::quantile_interval(latencies.len(), 0.99, 0.95)?;
    let mut v = latencies.to_vec();
    v.sort_unstable();
    Some([v[lo], v[hi]])
}

/// Each frame's time from its last packet sent (the twin's `sent_ns`) to its cable observation's
/// first arrival at the bench's subscriber, matched by the frame's time; frames whose observation
/// was not seen are left out.
pub fn to_observation(samples: &[records::latency::Sample], seen: &[(u64, u64)]) -> Vec<u64> {
    let arrival: std::collections::HashMap<u64, u64> = seen.iter().rev().copied().collect();
    samples
        .iter()
        .filter_map(|s| {
            arrival
                .get(&s.time_ns)
                .map(|&at| at.saturating_sub(s.sent_ns))
        })
        .collect()
}

/// A subscriber to the vehicle's cable observations on a thread of its own, noting when each
/// arrives (its stamp's `time_ns`, the monotonic clock when taken).
struct ObservationWatch {
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    thread: std::thread::JoinHandle<Result<Vec<(u64, u64)>>>,
}

impl ObservationWatch {
    /// Subscribed once this returns (before the mesh starts, so no observation is missed).
    fn start(iox: &runtime::IoxSettings) -> Result<Self> {
        use std::sync::atomic::{AtomicBool, Ordering};
        let stop = std::sync::Arc::new(AtomicBool::new(false));
        let (ready_tx, ready) = std::sync::mpsc::channel();
        let iox = iox.clone();
        let flag = stop.clone();
        let thread = std::thread::spawn(move || -> Result<Vec<(u64, u64)>> {
            use iceoryx2::prelude::*;
            let opened = crate::probe::node(&iox, "mesh-bench-obs").and_then(|node| {
                let inbox = messages::Inbox::<messages::CableObservationMsg>::open(
                    &node,
                    messages::Endpoint::Vehicle,
                    &messages::topics::CABLE_OBSERVATION,
                )?;
                Ok((node, inbox))
            });
            let (_node, inbox) = match opened {
                Ok(o) => {
                    let _ = ready_tx.send(Ok(()));
                    o
                }
                Err(e) => {
                    let _ = ready_tx.send(Err(anyhow::anyhow!("{e:#}")));
                    return Ok(Vec::new());
                }
            };
            let waitset = WaitSetBuilder::new()
                .create::<ipc::Service>()
                .map_err(|e| anyhow::anyhow!("cannot create a WaitSet: {e:?}"))?;
            let _guard = waitset
                .attach_notification(inbox.listener())
                .map_err(|e| anyhow::anyhow!("cannot attach a listener: {e:?}"))?;
            let mut seen = Vec::new();
            let mut last = None;
            while !flag.load(Ordering::Relaxed) {
                waitset
                    .wait_and_process_once_with_timeout(
                        |_| CallbackProgression::Continue,
                        Duration::from_millis(100),
                    )
                    .map_err(|e| anyhow::anyhow!("the observations' wait: {e:?}"))?;
                let _ = inbox.listener().try_wait(|_| {});
                while let Some(m) = inbox.receive()? {
                    let t = monotonic_ns();
                    // A re-sent frame's observation again: its first arrival counts.
                    if last != Some(m.stamp.time_ns) {
                        seen.push((m.stamp.time_ns, t));
                        last = Some(m.stamp.time_ns);
                    }
                }
            }
            Ok(seen)
        });
        ready
            .recv()
            .context("the observations' subscriber")?
            .context("the observations' subscriber")?;
        Ok(ObservationWatch { stop, thread })
    }

    fn stop(self) -> Result<Vec<(u64, u64)>> {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        self.thread
            .join()
            .map_err(|_| anyhow::anyhow!("the observations' subscriber panicked"))?
    }
}

/// Several runs' latencies (ns; each a name and its frames) as a Markdown table: each run's frames,
/// p50, p99 with its 95% interval and max, then all the frames together.
pub fn latency_table(runs: &[(String, Vec<u64>)]) -> String {
    let mut md = String::from(
        "| run | frames | p50 (µs) | p99 (µs) | p99, 95% interval (µs) | max (µs) |\n\
         |---|---:|---:|---:|---:|---:|\n",
    );
    let all: Vec<u64> = runs.iter().flat_map(|(_, v)| v.iter().copied()).collect();
    let together = format!("all {} together", runs.len());
    for (name, v) in runs
        .iter()
        .map(|(n, v)| (n.as_str(), v))
        .chain([(together.as_str(), &all)])
    {
        let s = Summary::of(v);
        let interval = p99_interval(v).map_or_else(
            || "too few frames".to_owned(),
            |[lo, hi]| format!("{:.0} – {:.0}", lo as f64 / 1e3, hi as f64 / 1e3),
        );
        let _ = writeln!(
            md,
            "| {name} | {} | {:.0} | {:.0} | {interval} | {:.0} |",
            s.n,
            s.p50 as f64 / 1e3,
            s.p99 as f64 / 1e3,
            s.max as f64 / 1e3
        );
    }
    md.push_str(
        "\nTogether, the frames are taken as draws from one distribution: if the machine's speed \
         moved between the runs, the runs' own intervals say more than the pooled one.\n",
    );
    md
}

impl VehicleRun {
    /// The report as Markdown.
    pub fn markdown(&self, target_steps: u64) -> String {
        let mut md = String::new();
        let us = |ns: u64| ns as f64 / 1e3;
        let _ = writeln!(
            md,
            "### Vehicle endpoint{}: camera-to-thruster latency at {}x real time\n",
            if self.path == VehiclePath::Mavlink {
                " over MAVLink"
            } else {
                ""
            },
            self.speed
        );
        let _ = writeln!(
            md,
            "{} trials of step two on the twin (learning online from the step-one policy), {:.0} s; {} frames timed{}; \
             other load {:.2} cores; restarts {}; shared-memory files left {}.\n",
            self.trials,
            self.wall_s,
            self.latency.n,
            if (self.latency.n as u64) < target_steps {
                format!(" (fewer than the {target_steps} asked: trials ended early)")
            } else {
                String::new()
            },
            self.other_cores,
            self.restarts,
            self.leftovers
        );
        let _ = writeln!(
            md,
            "| camera-to-thruster latency | p50 | p99 | max | mean |\n|---|---:|---:|---:|---:|"
        );
        let _ = writeln!(
            md,
            "| {} | {:.0} µs | {:.0} µs | {:.0} µs | {:.0} µs |",
            self.path.what(),
            us(self.latency.p50),
            us(self.latency.p99),
            us(self.latency.max),
            self.latency.mean / 1e3
        );
        if let Some(o) = &self.to_observation {
            let _ = writeln!(
                md,
                "| twin frame's last RTP/H.264 packet sent → its cable observation at a subscriber ({} frames) | {:.0} µs | {:.0} µs | {:.0} µs | {:.0} µs |",
                o.n,
                us(o.p50),
                us(o.p99),
                us(o.max),
                o.mean / 1e3
            );
        }
        md.push('\n');
        if let Some(v) = &self.video {
            let _ = writeln!(
                md,
                "The twin's stream: RTP/H.264 on UDP loopback, {}, {} kbit/s.\n",
                v.size, v.kbps
            );
        }
        let _ = match self.p99_interval {
            Some([lo, hi]) => writeln!(
                md,
                "The p99's 95% confidence interval, from the frames' order statistics: {:.0} – {:.0} µs. \
                 One run's p99 is known to this much; pool several runs' `--latencies` files with \
                 `mesh-bench latencies FILE...` for a narrower one.\n",
                us(lo),
                us(hi)
            ),
            None => writeln!(
                md,
                "Too few frames to bound the p99 (a 95% interval needs at least {P99_FRAMES}).\n"
            ),
        };
        let _ = writeln!(
            md,
            "| process | CPU per step (µs) | CPU in the run (ms) | RSS (MiB) | peak RSS (MiB) |\n|---|---:|---:|---:|---:|"
        );
        for p in &self.processes {
            let _ = writeln!(
                md,
                "| {} | {:.0} | {:.0} | {:.1} | {:.1} |",
                p.name, p.cpu_us_per_step, p.cpu_ms, p.rss_mib, p.hwm_mib
            );
        }
        if let Some(limit) = &self.limit {
            let ring = &limit.ring.step;
            let interval = limit.ring.step_p99_interval.map_or_else(
                || "too few frames to bound it".to_owned(),
                |[lo, hi]| format!("95% interval {:.0} – {:.0} µs", us(lo), us(hi)),
            );
            let _ = writeln!(
                md,
                "The vehicle's limit on this machine, measured after the run at the same pace: \
                 the bare ring in the vehicle's shape (`mesh-bench ring`, {} frames, {} missed) \
                 p50 {:.0} µs, p99 {:.0} µs ({interval}); perception's core alone p50 {:.0} µs \
                 ({} frames). The vehicle's p50 is {:.2}x the ring's plus perception's ({:.0} µs); \
                 its p99 {:.2}x the ring's.\n",
                ring.n,
                limit.ring.missed,
                us(ring.p50),
                us(ring.p99),
                us(limit.perception.p50),
                limit.perception.n,
                self.latency.p50 as f64 / limit.p50_ns().max(1) as f64,
                us(limit.p50_ns()),
                self.latency.p99 as f64 / ring.p99.max(1) as f64,
            );
        }
        // A minute at the vehicle's pace is 60 / period frames; the timed frames are the answered ones.
        let frames = (self.latency.n as f64).max(1.0);
        if self.video.is_some() {
            // The stream holds every frame; the raw images are thinned (the recorder's
            // --video-frame-every).
            let _ = writeln!(
                md,
                "\nFlight record (the stream, raw images thinned): {:.1} MB over a dive of {:.0} s, {:.2} MB per minute of dive.",
                self.record_bytes as f64 / 1e6,
                self.dive_s,
                self.record_bytes as f64 / (self.dive_s / 60.0).max(1e-9) / 1e6,
            );
        } else {
            let _ = writeln!(
                md,
                "\nFlight record (every frame): {:.1} MB, {:.1} kB per frame timed, {:.1} MB per minute at 5 Hz.",
                self.record_bytes as f64 / 1e6,
                self.record_bytes as f64 / frames / 1e3,
                self.record_bytes as f64 / frames * 300.0 / 1e6,
            );
        }
        if let Some(mavlink) = &self.mavlink {
            md.push('\n');
            md.push_str(&self.paths_table(mavlink));
            md.push('\n');
            md.push_str(&mavlink.markdown(target_steps));
        }
        md
    }

    /// This run's latency beside `mavlink`'s, the MAVLink run after it: p50 and p99 of each, and
    /// their ratios to this one's.
    pub fn paths_table(&self, mavlink: &VehicleRun) -> String {
        let ms = |ns: u64| ns as f64 / 1e6;
        let mut md = String::from(
            "### Both paths, one after the other\n\n\
             | path | frames | p50 | p99 | max |\n|---|---:|---:|---:|---:|\n",
        );
        for run in [self, mavlink] {
            let _ = writeln!(
                md,
                "| {} | {} | {:.2} ms | {:.2} ms | {:.2} ms |",
                run.path.what(),
                run.latency.n,
                ms(run.latency.p50),
                ms(run.latency.p99),
                ms(run.latency.max)
            );
        }
        let ratio = |a: u64, b: u64| a as f64 / b.max(1) as f64;
        let _ = writeln!(
            md,
            "\nOver MAVLink against shared memory: p50 {:.2}x, p99 {:.2}x.",
            ratio(mavlink.latency.p50, self.latency.p50),
            ratio(mavlink.latency.p99, self.latency.p99)
        );
        md
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trials_cover_the_steps_asked_with_dropped_frames() {
        let setup = VehicleSetup {
            run: VehicleRunSetup {
                bin_dir: PathBuf::new(),
                files: crate::runs::VehicleFiles {
                    config: PathBuf::new(),
                    sim_mesh: PathBuf::new(),
                    vehicle_mesh: PathBuf::new(),
                },
                seed: 1,
                sim_episodes: 100,
            },
            path: VehiclePath::Twin,
            steps: 10_000,
            speed: 1.0,
            steps_per_trial: 450,
            drop_probability: 0.03,
            period_s: 0.2,
            keep_latencies: None,
            video: VideoStream {
                kbps: 4000,
                size: "1920x1080".into(),
            },
        };
        let trials = setup.trials();
        // 451 frames a trial, 3% dropped: 437.5 answered frames a trial at most.
        assert!(trials as f64 * 437.5 >= 10_000.0, "{trials}");
        assert!(trials <= 25, "{trials}");
    }

    #[test]
    fn the_limit_is_the_ring_plus_perception_and_the_report_compares_with_it() {
        let scenario = config::Scenario::default();
        let perception = perception_at_pace(&scenario, 5, 0.2, Duration::from_millis(1)).unwrap();
        assert_eq!(perception.n, 5);
        assert!(perception.p50 > 0 && perception.p50 <= perception.max);

        let summary = |p50: u64, p99: u64| Summary {
            n: 1000,
            p50,
            p99,
            max: p99,
            ..Default::default()
        };
        let limit = VehicleLimit {
            ring: RingRun {
                step: summary(600_000, 2_000_000),
                step_p99_interval: Some([1_800_000, 2_300_000]),
                ..Default::default()
            },
            perception: Summary {
                n: 100,
                ..summary(400_000, 500_000)
            },
        };
        assert_eq!(limit.p50_ns(), 1_000_000);
        let run = VehicleRun {
            latency: summary(1_100_000, 2_500_000),
            limit: Some(limit),
            ..Default::default()
        };
        let md = run.markdown(1000);
        assert!(
            md.contains("p50 600 µs, p99 2000 µs (95% interval 1800 – 2300 µs)"),
            "{md}"
        );
        assert!(
            md.contains("perception's core alone p50 400 µs (100 frames)"),
            "{md}"
        );
        assert!(md.contains("The vehicle's p50 is 1.10x the ring's plus perception's (1000 µs); its p99 1.25x the ring's."), "{md}");
        let without = VehicleRun { limit: None, ..run };
        assert!(!without.markdown(1000).contains("limit"));
    }

    #[test]
    fn each_frame_is_timed_to_its_observations_first_arrival() {
        let sample = |time_ns: u64, sent_ns: u64| records::latency::Sample {
            seq: time_ns / 200_000_000,
            trial: 0,
            step: 0,
            time_ns,
            sent_ns,
            latency: Duration::from_millis(3),
        };
        let samples = [
            sample(200_000_000, 10_000_000),
            sample(400_000_000, 210_000_000),
            sample(600_000_000, 410_000_000),
        ];
        // The second frame's observation came twice (a re-send): its first arrival counts; the
        // third's never came; one observation answers no timed frame.
        let seen = [
            (200_000_000, 12_500_000),
            (400_000_000, 214_000_000),
            (400_000_000, 215_000_000),
            (800_000_000, 700_000_000),
        ];
        assert_eq!(to_observation(&samples, &seen), vec![2_500_000, 4_000_000]);
        let run = VehicleRun {
            path: VehiclePath::Video,
            latency: Summary::of(&[3_000_000]),
            to_observation: Some(Summary::of(&to_observation(&samples, &seen))),
            video: Some(VideoStream {
                kbps: 250,
                size: "640x360".into(),
            }),
            record_bytes: 3_000_000,
            dive_s: 120.0,
            ..Default::default()
        };
        let md = run.markdown(1);
        assert!(
            md.contains("its cable observation at a subscriber (2 frames)"),
            "{md}"
        );
        assert!(md.contains("640x360, 250 kbit/s"), "{md}");
        assert!(md.contains("1.50 MB per minute of dive"), "{md}");
    }

    #[test]
    fn the_mavlink_run_is_reported_beside_the_twins() {
        let summary = |p50: u64, p99: u64, max: u64| Summary {
            n: 2000,
            p50,
            p99,
            max,
            ..Default::default()
        };
        let mavlink = VehicleRun {
            path: VehiclePath::Mavlink,
            latency: summary(1_800_000, 4_500_000, 9_000_000),
            ..Default::default()
        };
        let twin = VehicleRun {
            latency: summary(1_200_000, 3_000_000, 6_000_000),
            mavlink: Some(Box::new(mavlink)),
            ..Default::default()
        };
        let md = twin.markdown(2000);
        assert!(
            md.contains(&format!(
                "| {} | 2000 | 1.20 ms | 3.00 ms | 6.00 ms |",
                VehiclePath::Twin.what()
            )),
            "{md}"
        );
        assert!(
            md.contains(&format!(
                "| {} | 2000 | 1.80 ms | 4.50 ms | 9.00 ms |",
                VehiclePath::Mavlink.what()
            )),
            "{md}"
        );
        assert!(
            md.contains("Over MAVLink against shared memory: p50 1.50x, p99 1.50x."),
            "{md}"
        );
        assert!(md.contains("### Vehicle endpoint over MAVLink:"), "{md}");
        let json = serde_json::to_string(&twin).unwrap();
        let back: VehicleRun = serde_json::from_str(&json).unwrap();
        assert_eq!(back, twin);
    }

    #[test]
    fn the_p99_is_given_with_its_interval_when_the_frames_bound_it() {
        assert!(p99_interval(&vec![1; P99_FRAMES - 1]).is_none());
        assert!(p99_interval(&vec![1; P99_FRAMES]).is_some());
        // 1 to 1,000 µs, shuffled: the interval is of the sorted values, around the p99 (990 µs).
        let run: Vec<u64> = (1..=1000u64)
            .map(|k| (k * 7919 % 1000 + 1) * 1000)
            .collect();
        let (lo, hi) = stats::quantile_interval(1000, 0.99, 0.95).unwrap();
        let [a, b] = p99_interval(&run).unwrap();
        assert_eq!([a, b], [(lo as u64 + 1) * 1000, (hi as u64 + 1) * 1000]);
        assert!(a < 990_000 && 990_000 < b);

        // A short run gets no interval; together the two runs' 1,300 frames do.
        let short: Vec<u64> = (1..=300u64).map(|k| k * 10_000).collect();
        let md = latency_table(&[("long".into(), run), ("short".into(), short)]);
        assert!(
            md.contains(&format!(
                "| long | 1000 | 500 | 990 | {} – {} | 1000 |",
                a / 1000,
                b / 1000
            )),
            "{md}"
        );
        assert!(
            md.contains("| short | 300 | 1500 | 2970 | too few frames | 3000 |"),
            "{md}"
        );
        let together = md
            .lines()
            .find(|l| l.starts_with("| all 2 together | 1300 |"));
        assert!(together.is_some_and(|l| !l.contains("too few")), "{md}");
    }
}
