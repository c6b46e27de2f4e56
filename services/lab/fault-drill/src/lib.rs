//! The fault drill (`fault-drill`, `scripts/fault-drill`): the vehicle mesh against the twin
//! under the supervisor at the vehicle's 5 Hz, and, in one run, every fault the vehicle's safety
//! layer is there for, with what reached the twin's thrusters as the evidence:
//!
//! 1. `kills` random SIGKILLs across every vehicle service (a service again only after the
//!    supervisor's restart window, 60 s: 8 kills a minute at most): each must be restarted; the steps the
//!    loop missed (gaps in the camera's `seq` answered at the thrusters) and the time from the
//!    restarted process's appearance to the next setpoints at the thrusters are measured.
//! 2. A stall (SIGSTOP for 2 s, then SIGCONT) of perception and of each behaviour: the thrusters
//!    must stop (a failsafe stop) within the deadline, and the loop must come back.
//! 3. A second allocator: it must refuse to start while the first is alive.
//! 4. The camera restarted with its time base stepped back an hour (its clock offset through
//!    `runtime::clock`'s offset file; the machine's clock is never touched): the loop must come
//!    back.
//! 5. A rogue node publishing on every topic of the loop: NaN, infinity and out-of-range values,
//!    huge, older, stale and future stamps, truncated frames, and an attempt to publish setpoints.
//!    Each rogue message carries a marker in its `time_ns`; a bad stamp is refused when its marker
//!    never reaches the thrusters, a bad value is made safe when what reaches the thrusters with its
//!    marker is finite and within [-1, 1].
//!
//! Afterwards the supervisor is stopped (SIGTERM) and the drill counts panics in the services' logs,
//! processes left running, shared-memory files left, and trials missing from the monitor's record.
//!
//! How it starts a mesh and watches it (step one in brief, a supervisor's process, a node of its
//! own) is the mesh benchmark's (`mesh_bench`), used as it is.

use anyhow::{Context, Result, bail};
use iceoryx2::prelude::*;
use mesh_bench::probe;
use mesh_bench::runs::{VehicleRunSetup, spawn};
use messages::{
    CableObservationData, CableObservationMsg, CameraFrameHeader, DofCommand, Endpoint,
    FrameOutbox, LearningStats, Outbox, Stamp, StepStatus, topics,
};
use runtime::process::{Child, children, is_named};
use runtime::{Namespace, VehicleClock};
use serde::Serialize;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

/// The services the drill kills (every vehicle service; the twin is the plant, not the vehicle).
pub const SERVICES: [&str; 8] = messages::topics::Endpoint::Vehicle.services();
/// The services stalled.
pub const STALLED: [&str; 3] = ["perception", "sway-behaviour", "yaw-behaviour"];
/// How long a stall lasts.
pub const STALL: Duration = Duration::from_secs(2);
/// How long the loop runs undisturbed after a fault is over, before the next one.
const SETTLE: Duration = Duration::from_millis(1000);
/// How long any one thing may take before the drill gives up on it.
const PATIENCE: Duration = Duration::from_secs(20);
/// The marker in the `time_ns` of the rogue's messages (its low bits number them).
const ROGUE: u64 = 0xBAD0_0000_0000_0000;

/// What to run.
#[derive(Clone, Debug)]
pub struct DrillSetup {
    pub run: VehicleRunSetup,
    pub kills: u32,
    pub period_s: f64,
    /// Where to keep the vehicle mesh's log (every service's output), if anywhere.
    pub keep_log: Option<PathBuf>,
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct P50P99Max {
    pub p50: f64,
    pub p99: f64,
    pub max: f64,
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct P50P99 {
    pub p50: f64,
    pub p99: f64,
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Max {
    pub max: f64,
}

/// The drill's figures.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct DrillReport {
    pub kills: u32,
    pub restarted: u32,
    pub steps_missed_per_kill: P50P99Max,
    pub restart_to_command_ms: P50P99,
    pub stall_to_zero_thrust_ms: Max,
    pub bad_messages_sent: u64,
    pub bad_messages_refused: u64,
    pub panics: usize,
    pub leftover_processes: usize,
    pub leftover_shm: usize,
    pub trials_lost: usize,
    /// Of the bad messages: bad stamps never acted on, bad values made safe.
    pub bad_stamps_refused: u64,
    pub bad_values_made_safe: u64,
    /// Stalls after which the thrusters were not stopped within `PATIENCE` (should be none).
    pub stalls_without_stop: usize,
    pub second_allocator_refused: bool,
    /// From the stepped-back camera's appearance to the next setpoints at the thrusters.
    pub stepped_back_camera_to_command_ms: f64,
    /// Kills (by service) in the run.
    pub kills_by_service: Vec<(String, u32)>,
    pub wall_s: f64,
}

/// One arrival at the twin's thrusters.
#[derive(Clone, Copy, Debug)]
struct Arrival {
    at: Instant,
    stamp: Stamp,
    stop: bool,
    safe: bool,
}

/// What reached the twin's thrusters, in order, shared with the thread that receives it.
#[derive(Default)]
struct Seen {
    arrivals: Mutex<Vec<Arrival>>,
    changed: Condvar,
}

impl Seen {
    /// Waits up to `timeout` for an arrival at or after index `from` that `pred` accepts.
    fn wait_for(
        &self,
        from: usize,
        timeout: Duration,
        pred: impl Fn(&Arrival) -> bool,
    ) -> Option<(usize, Arrival)> {
        let end = Instant::now() + timeout;
        let mut got = self.arrivals.lock().expect("not poisoned");
        let mut next = from;
        loop {
            if let Some(k) = (next..got.len()).find(|&k| pred(&got[k])) {
                return Some((k, got[k]));
            }
            next = got.len();
            let left = end.checked_duration_since(Instant::now())?;
            got = self
                .changed
                .wait_timeout(got, left)
                .expect("not poisoned")
                .0;
        }
    }

    fn len(&self) -> usize {
        self.arrivals.lock().expect("not poisoned").len()
    }

    fn last_answer(&self) -> Option<Arrival> {
        let got = self.arrivals.lock().expect("not poisoned");
        got.iter().rev().find(|a| !a.stop).copied()
    }

    fn all(&self) -> Vec<Arrival> {
        self.arrivals.lock().expect("not poisoned").clone()
    }
}

/// Receives what reaches the twin's thrusters until `stop` is set.
fn watch_thrusters(
    iox: runtime::IoxSettings,
    seen: Arc<Seen>,
    ready: std::sync::mpsc::Sender<Result<()>>,
    stop: Arc<AtomicBool>,
) {
    let run = || -> Result<()> {
        let node = probe::node(&iox, "fault-drill-thrusters")?;
        let port = adapters::twin::TwinThrusterPort::open(&node)?;
        let waitset = WaitSetBuilder::new()
            .create::<ipc::Service>()
            .map_err(|e| anyhow::anyhow!("cannot create a WaitSet: {e:?}"))?;
        let _guard = waitset
            .attach_notification(port.listener())
            .map_err(|e| anyhow::anyhow!("cannot attach the thrusters' listener: {e:?}"))?;
        let _ = ready.send(Ok(()));
        while !stop.load(Ordering::Relaxed) {
            // Wakes on every arrival; the timeout only lets the thread see `stop`.
            let _ = waitset.wait_and_process_once_with_timeout(
                |_| CallbackProgression::Continue,
                Duration::from_millis(100),
            );
            let _ = messages::ports::take_notifications(port.listener());
            let mut fresh = Vec::new();
            while let Some(m) = port.receive()? {
                fresh.push(Arrival {
                    at: Instant::now(),
                    stamp: m.stamp,
                    stop: m.stop != 0,
                    safe: m.as_slice().iter().all(|v| v.is_finite() && v.abs() <= 1.0),
                });
            }
            if !fresh.is_empty() {
                seen.arrivals.lock().expect("not poisoned").extend(fresh);
                seen.changed.notify_all();
            }
        }
        Ok(())
    };
    if let Err(e) = run() {
        let _ = ready.send(Err(e));
    }
}

/// splitmix64: the drill's random choices, reproducible from the seed.
struct Choices(u64);

impl Choices {
    fn below(&mut self, n: usize) -> usize {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) % n as u64) as usize
    }
}

/// The supervisor's service `name`: its pid now.
fn pid_of(sup: &Child, name: &str) -> Option<u32> {
    sup.child(name)
}

/// Waits until the supervisor's service `name` runs as another process than `old`. The kernel
/// tells nobody but the parent when a process starts, so `/proc` is read every few milliseconds.
fn wait_restarted(sup: &Child, name: &str, old: u32, timeout: Duration) -> Option<(u32, Instant)> {
    let end = Instant::now() + timeout;
    while Instant::now() < end {
        if let Some(pid) = pid_of(sup, name).filter(|&p| p != old) {
            return Some((pid, Instant::now()));
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    None
}

fn signal(pid: u32, sig: i32) -> bool {
    let Ok(pid) = libc::pid_t::try_from(pid) else {
        return false;
    };
    if pid <= 0 {
        return false;
    }
    // SAFETY: kill(2) on a supervisor's child just read from /proc; never 0 or a group.
    unsafe { libc::kill(pid, sig) == 0 }
}

/// Runs step one briefly (for the policy the vehicle starts from), then the drill.
pub fn run(setup: &DrillSetup) -> Result<DrillReport> {
    let started = Instant::now();
    let ns = Namespace::new("fd");
    let scratch = ns.scratch();
    let step_one = setup.run.step_one(&ns, "fault-drill")?;

    // The vehicle mesh, with many trials: the drill stops it when done.
    let offset_file = scratch.join("camera-clock-offset-ms");
    let record = scratch.join("step-two/run.json");
    let sets = [
        ("trials", "1000".into()),
        ("pacing", "--speed=1".into()),
        ("initial", step_one.display().to_string()),
        ("state", scratch.join("step-two").display().to_string()),
        ("json", record.display().to_string()),
        (
            "trace",
            scratch.join("step-two/trace.jsonl").display().to_string(),
        ),
    ];
    let log = scratch.join("vehicle.log");
    let offset = [(
        runtime::clock::OFFSET_FILE_ENV,
        offset_file.display().to_string(),
    )];
    let mut sup = setup.run.start_vehicle(&ns, &sets, &offset, log.clone())?;
    let seen = Arc::new(Seen::default());
    let stop = Arc::new(AtomicBool::new(false));
    let (ready_tx, ready_rx) = std::sync::mpsc::channel();
    let watcher = {
        let (iox, seen, stop) = (ns.iox.clone(), seen.clone(), stop.clone());
        std::thread::spawn(move || watch_thrusters(iox, seen, ready_tx, stop))
    };
    ready_rx
        .recv_timeout(PATIENCE)
        .context("the thrusters' watcher did not start")??;
    let outcome = drill(setup, &ns, &mut sup, &seen, &offset_file);
    // Whatever happened: stop the mesh and the watcher.
    let mut pids: Vec<(u32, String)> = sup.pid().map(children).unwrap_or_default();
    let stopped = sup.stop(Duration::from_secs(10));
    stop.store(true, Ordering::Relaxed);
    let _ = watcher.join();
    if let Some(keep) = &setup.keep_log {
        std::fs::copy(&log, keep)
            .with_context(|| format!("keeping the log as {}", keep.display()))?;
        eprintln!("fault-drill: the vehicle mesh's log is {}", keep.display());
    }
    let mut report = outcome?;
    if !stopped.success() {
        eprintln!("fault-drill: the supervisor stopped with {stopped:?}");
    }
    let text = std::fs::read_to_string(&log).unwrap_or_default();
    report.panics = text.matches("panicked").count();
    pids.retain(|(pid, name)| {
        std::fs::read_to_string(format!("/proc/{pid}/comm")).is_ok_and(|c| is_named(c.trim(), name))
    });
    report.leftover_processes = pids.len();
    report.leftover_shm = ns.leftovers().len();
    report.trials_lost = match std::fs::read_to_string(&record) {
        Ok(text) => {
            let r: records::RunRecord = serde_json::from_str(&text)
                .with_context(|| format!("{} is not a run record", record.display()))?;
            let mut numbers = r.episode_numbers.clone();
            numbers.sort_unstable();
            numbers.dedup();
            match (numbers.first(), numbers.last()) {
                (Some(a), Some(b)) => (b - a + 1) as usize - numbers.len(),
                _ => 0,
            }
        }
        Err(e) => bail!("no run record at {}: {e}", record.display()),
    };
    report.wall_s = started.elapsed().as_secs_f64();
    Ok(report)
}

fn drill(
    setup: &DrillSetup,
    ns: &Namespace,
    sup: &mut Child,
    seen: &Seen,
    offset_file: &std::path::Path,
) -> Result<DrillReport> {
    let period = Duration::from_secs_f64(setup.period_s);
    let answer = |a: &Arrival| !a.stop;
    seen.wait_for(0, Duration::from_secs(120), answer)
        .with_context(|| format!("no setpoints reached the thrusters\n{}", sup.tail(40)))?;
    eprintln!("fault-drill: the vehicle mesh drives the thrusters");
    let mut report = DrillReport {
        kills: setup.kills,
        ..Default::default()
    };
    let mut choices = Choices(setup.run.seed);
    let mut missed = Vec::new();
    let mut restart_ms = Vec::new();
    let mut by_service = std::collections::BTreeMap::<&str, u32>::new();

    // 1. Kills. A service is killed again only after the supervisor's restart window: a crash loop
    // is the supervisor's to stop (it backs off, then gives up), not what the drill measures.
    let window = Duration::from_secs_f64(
        supervisor::MeshFile::load(&setup.run.files.vehicle_mesh)?
            .restart
            .window_s,
    );
    let mut last_kill: std::collections::BTreeMap<&str, Instant> = Default::default();
    for k in 0..setup.kills {
        let eligible = |at: Instant, last: &std::collections::BTreeMap<&str, Instant>| {
            SERVICES
                .iter()
                .copied()
                .filter(|n| last.get(n).is_none_or(|t| at.duration_since(*t) >= window))
                .collect::<Vec<_>>()
        };
        if eligible(Instant::now(), &last_kill).is_empty() {
            // Until the service killed longest ago may be killed again.
            let free_at = last_kill.values().min().copied().expect("all killed") + window;
            let left = free_at.saturating_duration_since(Instant::now());
            let _ = seen.wait_for(usize::MAX, left, |_| false);
        }
        let names = eligible(Instant::now(), &last_kill);
        let name = names[choices.below(names.len())];
        last_kill.insert(name, Instant::now());
        *by_service.entry(name).or_default() += 1;
        let Some(pid) = pid_of(sup, name) else {
            bail!("{name} is not running\n{}", sup.tail(40));
        };
        let before = seen.last_answer();
        let mark = seen.len();
        if !signal(pid, libc::SIGKILL) {
            bail!("cannot kill {name} ({pid})");
        }
        let Some((_, up)) = wait_restarted(sup, name, pid, PATIENCE) else {
            eprintln!("fault-drill: {name} was not restarted");
            continue;
        };
        report.restarted += 1;
        let Some((_, first)) = seen.wait_for(mark, PATIENCE, |a| !a.stop && a.at >= up) else {
            bail!("no setpoints after {name} was restarted\n{}", sup.tail(40));
        };
        restart_ms.push(first.at.duration_since(up).as_secs_f64() * 1e3);
        // Steps missed: the camera's frames between the last answered before the kill and the
        // first answered after it (a restarted camera numbers them on from the twin's count).
        let first_after = seen
            .wait_for(mark, Duration::ZERO, answer)
            .map(|(_, a)| a)
            .unwrap_or(first);
        if let Some(b) = before {
            missed.push(first_after.stamp.seq.saturating_sub(b.stamp.seq + 1) as f64);
        }
        if (k + 1) % 10 == 0 {
            eprintln!(
                "fault-drill: {} of {} kills, last {name}",
                k + 1,
                setup.kills
            );
        }
        let settle_until = Instant::now() + SETTLE;
        let _ = seen.wait_for(usize::MAX, settle_until - Instant::now(), |_| false);
    }

    // 2. Stalls.
    let mut stall_ms: Vec<f64> = Vec::new();
    for name in STALLED {
        let pid = pid_of(sup, name).with_context(|| format!("{name} is not running"))?;
        let mark = seen.len();
        let stalled = Instant::now();
        signal(pid, libc::SIGSTOP);
        let stopped = seen.wait_for(mark, STALL, |a| a.stop);
        // The stall lasts its full time whether or not the thrusters stopped already.
        if let Some(left) = (stalled + STALL).checked_duration_since(Instant::now()) {
            std::thread::sleep(left);
        }
        signal(pid, libc::SIGCONT);
        match stopped {
            Some((_, a)) => stall_ms.push(a.at.duration_since(stalled).as_secs_f64() * 1e3),
            None => report.stalls_without_stop += 1,
        }
        let resumed = seen.len();
        seen.wait_for(resumed, PATIENCE, answer)
            .with_context(|| format!("the loop did not come back after {name}'s stall"))?;
        eprintln!("fault-drill: stalled {name} for {STALL:?}");
        let _ = seen.wait_for(usize::MAX, SETTLE, |_| false);
    }

    // 3. A second allocator.
    let mut second = spawn(
        "second allocator",
        &setup.run.bin_dir.join("thruster-allocator"),
        &[
            "--endpoint".into(),
            "vehicle".into(),
            "--config".into(),
            setup.run.files.config.display().to_string(),
        ],
        &ns.env()
            .iter()
            .map(|(k, v)| (*k, v.clone()))
            .collect::<Vec<_>>(),
        ns.scratch().join("second-allocator.log"),
    )?;
    let status = second.wait_timeout(PATIENCE);
    report.second_allocator_refused =
        status.is_some_and(|s| !s.success()) && second.log().contains("one publisher at a time");
    if status.is_none() {
        second.kill();
    }
    eprintln!(
        "fault-drill: a second allocator {}",
        if report.second_allocator_refused {
            "was refused"
        } else {
            "was NOT refused"
        }
    );

    // 4. The camera restarted with its clock an hour behind.
    std::fs::write(offset_file, "-3600000").context("writing the camera's clock offset")?;
    let pid = pid_of(sup, "camera").context("the camera is not running")?;
    let mark = seen.len();
    signal(pid, libc::SIGKILL);
    let (_, up) =
        wait_restarted(sup, "camera", pid, PATIENCE).context("the camera was not restarted")?;
    let (_, first) = seen
        .wait_for(mark, PATIENCE, |a| !a.stop && a.at >= up)
        .context("no setpoints after the camera restarted with its clock stepped back")?;
    report.stepped_back_camera_to_command_ms = first.at.duration_since(up).as_secs_f64() * 1e3;
    std::fs::write(offset_file, "").context("clearing the camera's clock offset")?;
    eprintln!(
        "fault-drill: camera restarted an hour behind: setpoints again {:.0} ms after",
        report.stepped_back_camera_to_command_ms
    );
    let _ = seen.wait_for(usize::MAX, SETTLE, |_| false);

    // 5. The rogue.
    let mark = seen.len();
    let (sent, bad_stamps, bad_values) = rogue(ns, seen, setup.period_s)?;
    report.bad_messages_sent = sent;
    // Enough time for anything the rogue sent to go through the loop.
    let _ = seen.wait_for(usize::MAX, 4 * period + SETTLE, |_| false);
    let after: Vec<Arrival> = seen.all().split_off(mark);
    let reached = |marker: u64| after.iter().filter(move |a| a.stamp.time_ns == marker);
    report.bad_stamps_refused = bad_stamps
        .iter()
        .filter(|&&m| reached(m).next().is_none())
        .count() as u64
        + 1; // the setpoint topic refused the rogue's publisher
    report.bad_values_made_safe = bad_values
        .iter()
        .filter(|&&m| reached(m).all(|a| a.safe))
        .count() as u64;
    report.bad_messages_refused = report.bad_stamps_refused + report.bad_values_made_safe;
    seen.wait_for(seen.len(), PATIENCE, answer)
        .context("the loop did not go on after the rogue")?;

    report.steps_missed_per_kill = P50P99Max {
        p50: stats::percentile(missed.iter().copied(), 0.5),
        p99: stats::percentile(missed.iter().copied(), 0.99),
        max: missed.iter().copied().fold(f64::NAN, f64::max),
    };
    report.restart_to_command_ms = P50P99 {
        p50: stats::percentile(restart_ms.iter().copied(), 0.5),
        p99: stats::percentile(restart_ms.iter().copied(), 0.99),
    };
    report.stall_to_zero_thrust_ms = Max {
        max: stall_ms.iter().copied().fold(f64::NAN, f64::max),
    };
    report.kills_by_service = by_service
        .into_iter()
        .map(|(n, c)| (n.to_string(), c))
        .collect();
    Ok(report)
}

/// Publishes the rogue's bad messages on every topic of the loop. Returns how many it sent (the
/// refused attempt to publish setpoints included) and the markers of those with bad stamps and of
/// those with bad values.
fn rogue(ns: &Namespace, seen: &Seen, period_s: f64) -> Result<(u64, Vec<u64>, Vec<u64>)> {
    let node = probe::node(&ns.iox, "rogue")?;
    let vehicle = Endpoint::Vehicle;
    let clock = VehicleClock::system();
    let live = seen
        .last_answer()
        .context("no step to copy the camera's epoch from")?
        .stamp;
    let mut marker = ROGUE;
    let mut bad_stamps = Vec::new();
    let mut bad_values = Vec::new();
    let mut sent = 1; // the setpoints below
    // Stamps: (bad stamp?, stamp)
    let mut stamps = |k: u64| -> Vec<(bool, Stamp)> {
        let now = clock.now_ns();
        let period = (period_s * 1e9) as i64;
        let base = |seq: u64, epoch: u32, clock_ns: i64, m: u64| {
            Stamp::new(seq, m, live.episode, live.step, StepStatus::Running).timed(epoch, clock_ns)
        };
        let mut next = || {
            marker += 1;
            marker
        };
        vec![
            // Fresh, in a rogue's own epoch: only the values are bad.
            (false, base(1 + k, 0xBAD0 + k as u32, now, next())),
            // A huge seq in the camera's epoch.
            (true, base(live.seq + (1 << 40), live.epoch, now, next())),
            // An older seq in the camera's epoch.
            (
                true,
                base(live.seq.saturating_sub(50), live.epoch, now, next()),
            ),
            // Stale: taken ten seconds ago, in an epoch of its own.
            (
                true,
                base(1, 0xBAD1_0000 + k as u32, now - 50 * period, next()),
            ),
            // From the future: an hour ahead.
            (
                true,
                base(1, 0xBAD2_0000 + k as u32, now + 3_600_000_000_000, next()),
            ),
        ]
    };
    let values = [f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 50.0, -1e300];

    // Setpoints: refused while the allocator publishes.
    if Outbox::open(&node, vehicle, &topics::THRUSTER_SETPOINTS).is_ok() {
        bail!("the rogue could publish thruster setpoints beside the allocator");
    }
    let observations = Outbox::open(&node, vehicle, &topics::CABLE_OBSERVATION)?;
    let commands = [
        Outbox::open(&node, vehicle, &topics::SURGE_COMMAND)?,
        Outbox::open(&node, vehicle, &topics::SWAY_COMMAND)?,
        Outbox::open(&node, vehicle, &topics::YAW_COMMAND)?,
    ];
    let learning = [
        Outbox::open(&node, vehicle, &topics::SWAY_LEARNING)?,
        Outbox::open(&node, vehicle, &topics::YAW_LEARNING)?,
    ];
    let frames = FrameOutbox::open(&node, vehicle, 320 * 240)?;
    let mut note = |bad_stamp: bool, st: &Stamp| {
        sent += 1;
        if bad_stamp {
            bad_stamps.push(st.time_ns);
        } else {
            bad_values.push(st.time_ns);
        }
    };
    for (k, v) in values.iter().enumerate() {
        for (bad_stamp, st) in stamps(k as u64) {
            let obs = CableObservationData {
                found: 1,
                x_g: *v,
                theta: -*v,
                x_g_rate: *v,
                theta_rate: *v,
                confidence: *v,
                rho: *v,
                ..Default::default()
            };
            observations.send(CableObservationMsg {
                stamp: st,
                observation: obs,
            })?;
            note(bad_stamp, &st);
        }
        for (bad_stamp, st) in stamps(k as u64) {
            for out in &commands {
                out.send(DofCommand {
                    stamp: st,
                    value: *v,
                })?;
                note(bad_stamp, &st);
            }
        }
        for (bad_stamp, st) in stamps(k as u64) {
            for out in &learning {
                out.send(LearningStats {
                    stamp: st,
                    episode_return: *v,
                    gain: [*v, -*v],
                    ..Default::default()
                })?;
                note(bad_stamp, &st);
            }
        }
        // A truncated frame (its header says 320 x 240), with each stamp.
        for (bad_stamp, st) in stamps(k as u64) {
            let header = CameraFrameHeader {
                stamp: st,
                width: 320,
                height: 240,
                ..Default::default()
            };
            frames
                .send_with(header, 100, |_| Ok::<_, std::convert::Infallible>(()))?
                .expect("infallible");
            // A truncated frame is refused whatever its stamp.
            note(true, &st);
            let _ = bad_stamp;
        }
    }
    Ok((sent, bad_stamps, bad_values))
}

impl DrillReport {
    /// The report as Markdown.
    pub fn markdown(&self) -> String {
        format!(
            "### Fault drill\n\n\
             | figure | value |\n|---|---:|\n\
             | kills, restarted | {} of {} |\n\
             | steps missed per kill (p50 / p99 / max) | {} / {} / {} |\n\
             | restart to first setpoints (p50 / p99) | {:.0} / {:.0} ms |\n\
             | stall to zero thrust (max) | {:.0} ms |\n\
             | bad messages refused or made safe | {} of {} ({} bad stamps refused, {} bad values made safe) |\n\
             | second allocator refused | {} |\n\
             | camera restarted an hour behind: to first setpoints | {:.0} ms |\n\
             | panics, processes left, shared-memory files left, trials lost | {}, {}, {}, {} |\n\
             | wall time | {:.0} s |\n",
            self.restarted,
            self.kills,
            self.steps_missed_per_kill.p50,
            self.steps_missed_per_kill.p99,
            self.steps_missed_per_kill.max,
            self.restart_to_command_ms.p50,
            self.restart_to_command_ms.p99,
            self.stall_to_zero_thrust_ms.max,
            self.bad_messages_refused,
            self.bad_messages_sent,
            self.bad_stamps_refused,
            self.bad_values_made_safe,
            if self.second_allocator_refused {
                "yes"
            } else {
                "no"
            },
            self.stepped_back_camera_to_command_ms,
            self.panics,
            self.leftover_processes,
            self.leftover_shm,
            self.trials_lost,
            self.wall_s,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn choices_are_reproducible_and_cover_every_service() {
        let pick = |seed| {
            let mut c = Choices(seed);
            (0..200)
                .map(|_| c.below(SERVICES.len()))
                .collect::<Vec<_>>()
        };
        assert_eq!(pick(7), pick(7));
        assert_ne!(pick(7), pick(8));
        let got = pick(7);
        assert!((0..SERVICES.len()).all(|s| got.contains(&s)));
    }
}
