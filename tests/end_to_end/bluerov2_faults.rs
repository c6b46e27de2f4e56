//! The fault drill over the MAVLink path: the BlueROV2's mesh (`config/bluerov2.toml`) under its
//! supervisor at the vehicle's 5 Hz, the twin standing in for ArduSub with a fault injected
//! (`vehicle-twin --fault`), the stack watched through the autopilot's state topic and the logs.
//!
//! - The link to the autopilot cut for longer than `FS_PILOT_TIMEOUT`: the autopilot's pilot-input
//!   failsafe disarms it; the driver loses its heartbeat and says so, finds it back disarmed, says
//!   the stack will not arm it again, and does not.
//! - The autopilot restarted: its heartbeat lost and back (it boots disarmed); the driver says so and
//!   does not arm it again.
//! - The driver killed: the supervisor restarts it, and the restarted driver pilots the autopilot as
//!   it finds it, without arming it again or changing its mode.
//!
//! Not repeated here, shown elsewhere against pymavlink: garbage and broken frames to the driver
//! (`tests/ardusub.rs`) and to the twin (`services/lab/vehicle-twin/tests/ardusub.rs`), counted and
//! refused; the pilot-input failsafe when the pilot's MANUAL_CONTROL stops, and a restarted driver
//! leaving a disarmed vehicle disarmed (the same two files).

use messages::{AutopilotState, Endpoint, topics};
use std::path::Path;
use std::time::Duration;
use system_tests::step_one_in;
use testkit::{Namespace, Probe, Process};

/// Long enough for the mesh to start, and for a fault to come and go, on a busy machine.
const T: Duration = Duration::from_secs(60);
/// Autopilot state reports (one per heartbeat, 1 Hz) watched after a fault to see nothing re-arm.
const WATCH_REPORTS: u64 = 4;

fn free_port() -> u16 {
    testkit::free_udp_port()
}

struct Mesh {
    _dir: tempfile::TempDir,
    ns: Namespace,
    probe: Probe,
    supervisor: Process,
}

/// The BlueROV2's mesh at 5 Hz with the twin's `fault` (empty: none).
fn mesh(tag: &str, fault: &str) -> Mesh {
    let ns = Namespace::new(tag);
    let dir = tempfile::tempdir().unwrap();
    let (initial, state) = (dir.path().join("step-one"), dir.path().join("state"));
    step_one_in(&testkit::config_dir().join("bluerov2"), &initial, 10, 5);
    let probe = testkit::probe(&ns, Endpoint::Vehicle);
    let path = |p: &Path| p.display().to_string();
    let supervisor = testkit::supervisor(
        &ns,
        &testkit::config_dir().join("bluerov2.toml"),
        5,
        &[
            ("trials", "0".into()),
            ("pacing", "--speed=1".into()),
            ("mavlink", format!("127.0.0.1:{}", free_port())),
            ("video", String::new()),
            ("source", "twin".into()),
            ("eyes", "ideal".into()),
            ("fault", fault.into()),
            ("initial", path(&initial)),
            ("state", path(&state)),
            ("json", path(&dir.path().join("run.json"))),
            ("trace", path(&dir.path().join("trace.jsonl"))),
            ("record", String::new()),
        ],
    );
    Mesh {
        _dir: dir,
        ns,
        probe,
        supervisor,
    }
}

impl Mesh {
    /// Waits for an autopilot state `want` accepts, failing with the mesh's log.
    fn wait_state(
        &self,
        inbox: &messages::Inbox<AutopilotState>,
        what: &str,
        want: impl FnMut(&AutopilotState) -> bool,
    ) -> AutopilotState {
        self.probe
            .wait_for(inbox, T, want)
            .unwrap_or_else(|| panic!("{what}: never seen\n{}", self.supervisor.log()))
    }

    /// The next `WATCH_REPORTS` reports of a present autopilot all say disarmed.
    fn stays_disarmed(&self, inbox: &messages::Inbox<AutopilotState>) {
        let mut seen = 0;
        self.wait_state(inbox, "reports after the fault", |s| {
            assert!(
                s.heartbeat == 0 || s.armed == 0,
                "the autopilot was armed again: {s:?}\n{}",
                self.supervisor.log()
            );
            seen += u64::from(s.heartbeat);
            seen >= WATCH_REPORTS
        });
    }

    /// Stops the mesh; its log.
    fn stop(mut self) -> String {
        let status = self.supervisor.terminate(T);
        let log = self.supervisor.log();
        assert!(
            status.success(),
            "the supervisor stops cleanly: {status:?}\n{log}"
        );
        drop(self.probe);
        assert!(
            self.ns.leftovers().is_empty(),
            "shared memory left behind: {:?}",
            self.ns.leftovers()
        );
        log
    }
}

fn lines_of<'a>(log: &'a str, service: &str) -> Vec<&'a str> {
    let tag = format!("service{{name=\"{service}\"}}");
    log.lines().filter(|l| l.contains(&tag)).collect()
}

fn count(lines: &[&str], text: &str) -> usize {
    lines.iter().filter(|l| l.contains(text)).count()
}

#[test]
fn the_link_to_the_autopilot_cut_disarms_it_and_the_stack_does_not_arm_it_again() {
    // Cut 12 s after the twin starts, for 6 s: longer than FS_PILOT_TIMEOUT (3 s) and the driver's
    // heartbeat timeout (3 s).
    let mesh = mesh("b2cut", "--fault=link-cut:12:6");
    let state = mesh.probe.inbox(&topics::AUTOPILOT_STATE);
    mesh.wait_state(&state, "armed by the driver", |s| {
        s.heartbeat == 1 && s.armed == 1
    });
    mesh.wait_state(&state, "the heartbeat lost", |s| s.heartbeat == 0);
    mesh.wait_state(&state, "back, disarmed", |s| {
        s.heartbeat == 1 && s.armed == 0
    });
    mesh.stays_disarmed(&state);
    drop(state);
    let log = mesh.stop();
    let (twin, driver) = (
        lines_of(&log, "vehicle-twin"),
        lines_of(&log, "thruster-driver"),
    );
    assert_eq!(
        count(&twin, "pilot-input failsafe: no MANUAL_CONTROL"),
        1,
        "the autopilot's failsafe fired once:\n{log}"
    );
    assert_eq!(count(&driver, "ArduSub's heartbeat lost"), 1, "{log}");
    assert_eq!(count(&driver, "ArduSub's heartbeat is back"), 1, "{log}");
    assert_eq!(
        count(
            &driver,
            "ArduSub disarmed without being asked by this driver"
        ),
        1,
        "the stack says so:\n{log}"
    );
    assert_eq!(
        count(&driver, "ArduSub armed"),
        1,
        "armed once, at the start:\n{log}"
    );
    assert!(!log.contains("panicked"), "{log}");
}

#[test]
fn a_restarted_autopilot_is_found_again_and_not_armed_again() {
    let mesh = mesh("b2rst", "--fault=restart:12:4");
    let state = mesh.probe.inbox(&topics::AUTOPILOT_STATE);
    mesh.wait_state(&state, "armed by the driver", |s| {
        s.heartbeat == 1 && s.armed == 1
    });
    mesh.wait_state(&state, "the heartbeat lost", |s| s.heartbeat == 0);
    // It boots again disarmed, in MANUAL (19).
    let back = mesh.wait_state(&state, "back", |s| s.heartbeat == 1);
    assert_eq!((back.armed, back.mode), (0, 19), "{back:?}");
    mesh.stays_disarmed(&state);
    drop(state);
    let log = mesh.stop();
    let driver = lines_of(&log, "thruster-driver");
    assert_eq!(count(&driver, "ArduSub's heartbeat lost"), 1, "{log}");
    assert_eq!(count(&driver, "ArduSub's heartbeat is back"), 1, "{log}");
    assert_eq!(
        count(
            &driver,
            "ArduSub disarmed without being asked by this driver"
        ),
        1,
        "the stack says so:\n{log}"
    );
    assert_eq!(
        count(&driver, "ArduSub armed"),
        1,
        "armed once, at the start:\n{log}"
    );
}

#[test]
fn a_killed_driver_is_restarted_and_pilots_on_without_arming_again() {
    let mesh = mesh("b2kill", "");
    let state = mesh.probe.inbox(&topics::AUTOPILOT_STATE);
    let setpoints = mesh.probe.inbox(&topics::THRUSTER_SETPOINTS);
    mesh.wait_state(&state, "armed by the driver", |s| {
        s.heartbeat == 1 && s.armed == 1
    });
    let before = mesh
        .probe
        .wait_for(&setpoints, T, |s| s.stamp.step >= 20)
        .unwrap_or_else(|| panic!("the mesh does not run:\n{}", mesh.supervisor.log()));
    let killed = mesh
        .supervisor
        .signal_service("thruster-driver", libc::SIGKILL)
        .expect("the driver is the supervisor's child");
    // The loop goes on through the restarted driver; the autopilot stays armed, in the scenario's
    // ALT_HOLD (2).
    mesh.probe
        .wait_for(&setpoints, T, |s| s.stamp.step >= before.stamp.step + 25)
        .unwrap_or_else(|| panic!("the loop did not go on:\n{}", mesh.supervisor.log()));
    let restarted = mesh
        .supervisor
        .service("thruster-driver")
        .expect("restarted");
    assert_ne!(restarted, killed);
    let mut reports = 0;
    mesh.wait_state(&state, "reports after the restart", |s| {
        assert!(s.heartbeat == 1 && s.armed == 1 && s.mode == 2, "{s:?}");
        reports += 1;
        reports >= WATCH_REPORTS
    });
    drop((state, setpoints));
    let log = mesh.stop();
    let driver = lines_of(&log, "thruster-driver");
    assert_eq!(
        count(&driver, "ArduSub armed"),
        1,
        "armed once, by the first driver:\n{log}"
    );
    assert!(
        count(&driver, "after a restart") >= 1,
        "the restarted driver says it pilots after a restart:\n{log}"
    );
    assert_eq!(
        count(&lines_of(&log, "vehicle-twin"), "pilot-input failsafe"),
        0,
        "{log}"
    );
}
