//! Two hosts on one machine: `scripts/shore-link --demo` makes two network namespaces joined by a
//! veth pair, runs the vehicle's mesh against the twin and the link's vehicle end in one, the link's
//! shore end and an operator in the other, and removes everything when done. The shore must receive
//! the allowed telemetry, see nothing outside the allow-list, and its stop must stop the vehicle.
//! Needs root (network namespaces) and the main workspace's binaries (`scripts/test-shore-link`
//! builds both).

use std::path::Path;
use std::process::Command;
use std::sync::mpsc;
use std::time::Duration;

/// The demo watches for a few seconds; start-up, the stop and the clean-up need the rest. A loaded
/// 2-core machine starts the mesh's nine processes slowly: a minute of slack.
const T: Duration = Duration::from_secs(90);

#[test]
fn the_shore_gets_the_allowed_telemetry_only_and_its_stop_is_obeyed() {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../..");
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("demo.json");
    let mut demo = Command::new(repo.join("scripts/shore-link"))
        .args([
            "--demo",
            "--no-build",
            "--seconds",
            "8",
            "--cut",
            "0",
            "--speed",
            "5",
            "--json",
        ])
        .arg(&json)
        .current_dir(&repo)
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
        panic!("the demo did not finish within {T:?}");
    }
    let status = waiter.join().unwrap().unwrap();
    assert!(status.success(), "the demo failed: {status:?}");
    let report: shore_link::Report =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    println!("{report:?}");
    assert!(
        report.received_on_shore > 0,
        "no telemetry reached the shore: {report:?}"
    );
    // On a quiet link every observation sent while the shore watched arrives; one may be in flight
    // when the operator stops watching.
    assert!(
        report.received_on_shore + 1 >= report.sent,
        "telemetry lost on a quiet link: {report:?}"
    );
    assert_eq!(report.outside_allow_list_seen, 0, "{report:?}");
    assert!(
        report.stop_obeyed,
        "the vehicle did not stop on the shore's command: {report:?}"
    );
    // The script removed its namespaces.
    let left = Command::new("ip").args(["netns", "list"]).output().unwrap();
    let left = String::from_utf8_lossy(&left.stdout);
    assert!(
        !left.contains(&format!("ctv{pid}")) && !left.contains(&format!("cts{pid}")),
        "namespaces left behind: {left}"
    );
}
