//! Two hosts on one machine: `scripts/shore-link --demo` makes two network namespaces joined by a
//! veth pair (or, under `--netem` on a kernel without netem, two TUN devices and `shore-link impair`
//! between them), runs the vehicle's mesh against the twin, the link's vehicle end one of its
//! services, in one, the link's shore end and an operator in the other, and removes everything when
//! done. Needs root
//! (network namespaces) and the main workspace's binaries (`scripts/test-shore-link` builds both).
//!
//! Every run must keep the link's properties: the shore shows telemetry in order or not at all
//! (never a step older than one shown), sees nothing outside the allow-list, the vehicle misses no
//! step, and the shore's stop reaches the vehicle and is obeyed. With `--rogue`, shore ends without
//! a valid certificate read nothing and their stops never reach the vehicle, nor does a stop
//! published by a process on the vehicle itself.

use shore_link::Report;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::mpsc;
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

/// The demo watches for a few seconds; start-up, the stop and the clean-up need the rest. A loaded
/// 2-core machine starts the mesh's nine processes slowly: a minute of slack.
const T: Duration = Duration::from_secs(120);

/// One demo at a time: each runs a whole vehicle mesh on this 2-core machine.
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

fn one_at_a_time() -> MutexGuard<'static, ()> {
    ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner())
}

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../..")
}

/// Runs the demo with `args` (a 10 s watch, no cut) and returns its report and the directory of its
/// processes' logs. The twin runs at the vehicle's own pace (5 Hz): "no step missed" is a property of
/// the vehicle's loop as it runs, not of one driven five times faster on a shared 2-core machine.
fn demo(args: &[&str]) -> (Report, tempfile::TempDir) {
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("demo.json");
    let logs = dir.path().join("logs");
    let started = Instant::now();
    let mut demo = Command::new(repo().join("scripts/shore-link"))
        .args([
            "--demo",
            "--no-build",
            "--seconds",
            "10",
            "--cut",
            "0",
            "--speed",
            "1",
        ])
        .args(args)
        // The link as cargo built it for this test, in whatever profile the test runs.
        .env("SHORE_LINK_BIN", env!("CARGO_BIN_EXE_shore-link"))
        .arg("--json")
        .arg(&json)
        .arg("--logs")
        .arg(&logs)
        .current_dir(repo())
        .spawn()
        .expect("scripts/shore-link starts");
    let pid = demo.id();
    let (done, finished) = mpsc::channel();
    let waiter = std::thread::spawn(move || {
        let status = demo.wait();
        let _ = done.send(());
        status
    });
    if finished.recv_timeout(T).is_err() {
        // SIGTERM: the script's trap stops its processes and removes its namespaces.
        // SAFETY: kill(2) on the script this test started (a positive pid, never a group).
        unsafe { libc::kill(pid as libc::pid_t, libc::SIGTERM) };
        let _ = waiter.join();
        panic!("the demo {args:?} did not finish within {T:?}");
    }
    let status = waiter.join().unwrap().unwrap();
    assert!(status.success(), "the demo {args:?} failed: {status:?}");
    let report: Report = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    println!(
        "demo {args:?} ({:.0} s): {}",
        started.elapsed().as_secs_f64(),
        serde_json::to_string(&report).unwrap()
    );
    // The script removed its namespaces.
    let left = Command::new("ip").args(["netns", "list"]).output().unwrap();
    let left = String::from_utf8_lossy(&left.stdout);
    assert!(
        !left.contains(&format!("ctv{pid}")) && !left.contains(&format!("cts{pid}")),
        "namespaces left behind: {left}"
    );
    (report, dir)
}

/// A latency for the log: a run that shows telemetry has one.
fn ms(latency: Option<f64>) -> f64 {
    latency.unwrap_or(f64::NAN)
}

/// What every run must keep, whatever the network.
fn assert_the_links_properties(r: &Report) {
    assert!(
        r.received_on_shore > 0,
        "no telemetry shown on shore: {r:?}"
    );
    assert_eq!(
        r.order.stale_shown, 0,
        "stale telemetry shown as new: {r:?}"
    );
    assert_eq!(r.vehicle_steps_missed, 0, "the vehicle missed steps: {r:?}");
    assert_eq!(r.outside_allow_list_seen, 0, "{r:?}");
    assert!(
        r.stops_reached_vehicle > 0,
        "no stop of the shore reached the vehicle's mission topic: {r:?}"
    );
    assert!(
        r.stop_obeyed,
        "the vehicle did not stop on the shore's command: {r:?}"
    );
}

fn log(dir: &tempfile::TempDir, name: &str) -> String {
    std::fs::read_to_string(dir.path().join("logs").join(name)).unwrap()
}

/// The vehicle's log: its supervisor's, with its services' (the link's vehicle end among them).
const VEHICLE_LOG: &str = "supervisor.log";

/// The link's vehicle end ran as a service of the vehicle's mesh: its supervisor started it and
/// stopped it with the others once the shore's stop came.
fn assert_the_mesh_ran_the_link(logs: &tempfile::TempDir) {
    let text = log(logs, VEHICLE_LOG);
    for (what, event) in [("started", "started"), ("stopped", "stopped")] {
        assert!(
            text.lines()
                .any(|l| l.contains(event) && l.contains("service=shore-link")),
            "the vehicle's supervisor never {what} the link's vehicle end:\n{text}"
        );
    }
}

#[test]
fn only_the_real_shore_reads_and_stops_the_vehicle_and_tls_costs_little_against_plain_tcp() {
    let _one = one_at_a_time();
    // Plain TCP, by name only: it works, and both ends say at WARN what it lets in.
    let (plain, plain_logs) = demo(&["--insecure"]);
    assert_eq!(plain.security, "insecure");
    assert_the_links_properties(&plain);
    assert_the_mesh_ran_the_link(&plain_logs);
    for end in [VEHICLE_LOG, "link-shore.log"] {
        let text = log(&plain_logs, end);
        assert!(
            text.lines()
                .any(|l| l.contains("WARN") && l.contains("--insecure")),
            "{end} has no warning about --insecure:\n{text}"
        );
    }
    // TLS, with a rogue shore end dialling plain TCP and one with another CA's keys.
    let (tls, tls_logs) = demo(&["--rogue"]);
    assert_eq!(tls.security, "tls");
    assert_the_links_properties(&tls);
    assert_the_mesh_ran_the_link(&tls_logs);
    // On a quiet link every observation sent while the shore watched is shown; one may be in
    // flight when the operator stops watching.
    for r in [&plain, &tls] {
        assert!(
            r.received_on_shore + 1 >= r.sent,
            "telemetry lost on a quiet link: {r:?}"
        );
    }
    assert_eq!(tls.rogues.len(), 2, "{tls:?}");
    for rogue in &tls.rogues {
        assert_eq!(rogue.received, 0, "a rogue read telemetry: {tls:?}");
        assert!(rogue.stops_sent > 0, "{tls:?}");
        assert_eq!(
            rogue.stops_reached_vehicle, 0,
            "a rogue's stop reached the vehicle: {tls:?}"
        );
    }
    assert_eq!(
        tls.local_forger_refused,
        Some(true),
        "a process on the vehicle could publish on the mission topic: {tls:?}"
    );
    assert!(
        !log(&tls_logs, VEHICLE_LOG).contains("--insecure"),
        "the TLS run warned about --insecure"
    );
    // The figure, not a threshold: what TLS adds to the link's latency in this run.
    println!(
        "latency added by the link, p50 / p99: plain TCP {:.2} / {:.2} ms, TLS {:.2} / {:.2} ms",
        ms(plain.latency_ms.p50),
        ms(plain.latency_ms.p99),
        ms(tls.latency_ms.p50),
        ms(tls.latency_ms.p99)
    );
}

/// The demo under one of its netem presets: the properties hold, whatever share arrives.
fn under(setting: &str) {
    let _one = one_at_a_time();
    let (r, logs) = demo(&["--netem", setting]);
    let args = shore_link::impair::netem_args(setting);
    assert_eq!(r.netem.as_deref(), Some(args), "{r:?}");
    assert_the_links_properties(&r);
    // The impairment ran: tc's netem, or the emulator, which tells what it did to each direction's
    // packets (`offered=N lost=N ... reordered=N sent=N`).
    if let Ok(text) = std::fs::read_to_string(logs.path().join("logs/impair.log")) {
        let done: Vec<&str> = text
            .lines()
            .filter(|l| l.contains("impairment done"))
            .collect();
        assert_eq!(done.len(), 2, "{text}");
        let count = |line: &str, key: &str| -> u64 {
            line.split_whitespace()
                .find_map(|w| w.strip_prefix(&format!("{key}=")))
                .and_then(|n| n.parse().ok())
                .unwrap_or_else(|| panic!("no {key} in {line}"))
        };
        for line in done {
            assert!(count(line, "sent") > 0, "{line}");
            match setting {
                "loss" => assert!(count(line, "lost") > 0, "{line}"),
                "reorder" => assert!(count(line, "reordered") > 0, "{line}"),
                _ => {}
            }
        }
    }
    println!(
        "under \"{args}\": {} of {} shown ({:.1}%), latency p50 / p99 {:.1} / {:.1} ms, {} stale arrivals refused, steps missed {}, stop obeyed {}",
        r.received_on_shore,
        r.sent,
        100.0 * r.received_share,
        ms(r.latency_ms.p50),
        ms(r.latency_ms.p99),
        r.order.stale_arrivals,
        r.vehicle_steps_missed,
        r.stop_obeyed
    );
}

#[test]
fn under_5_percent_loss() {
    under("loss");
}

#[test]
fn under_300_ms_delay_with_jitter() {
    under("delay");
}

#[test]
fn under_reordering() {
    under("reorder");
}

#[test]
fn under_a_256_kbit_cap() {
    under("rate");
}
