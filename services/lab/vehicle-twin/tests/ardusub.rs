//! The `vehicle-twin --autopilot` process against pymavlink, MAVLink's own implementation (not our
//! code): a ground station reads the parameters, sets MANUAL, arms, moves each axis and reads the
//! motors back, is ignored under another system id, sends garbage, and stops; a reversed motor
//! shows. pymavlink comes from `scripts/install-pymavlink` (CI runs it before the tests).

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;
use testkit::{Namespace, Process};

const T: Duration = Duration::from_secs(20);
/// The peer's own deadlines end it well before this.
const PEER_TIMEOUT: Duration = Duration::from_secs(90);

fn python() -> PathBuf {
    testkit::venv_python(
        "PYMAVLINK_VENV",
        "pymavlink-venv",
        "scripts/install-pymavlink",
    )
}

/// A UDP port free now (the twin binds it next).
fn free_port() -> u16 {
    testkit::free_udp_port()
}

/// The BlueROV2 twin's config with `params` added to its autopilot's parameters, in a directory of
/// its own (scenario and learning from config/bluerov2).
fn config_dir(dir: &Path, params: &str) -> PathBuf {
    let src = testkit::config_dir().join("bluerov2");
    for f in ["scenario.toml", "learning.toml"] {
        std::fs::copy(src.join(f), dir.join(f)).unwrap();
    }
    let twin = std::fs::read_to_string(src.join("twin.toml")).unwrap();
    let twin = twin.replace("FS_PILOT_TIMEOUT = 3.0", "FS_PILOT_TIMEOUT = 1.5");
    std::fs::write(dir.join("twin.toml"), format!("{twin}{params}\n")).unwrap();
    dir.to_owned()
}

/// Runs the peer to its end (coreutils' `timeout` kills it after `PEER_TIMEOUT`); its output.
fn peer(args: &[&str]) -> (bool, String) {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/ardusub_peer.py");
    let out = Command::new("timeout")
        .arg(format!("{}s", PEER_TIMEOUT.as_secs()))
        .arg(python())
        .arg(script)
        .args(args)
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (out.status.success(), text)
}

fn twin(ns: &Namespace, config: &Path, port: u16) -> Process {
    Process::start(
        ns,
        &testkit::binary("vehicle-twin"),
        &[
            "--endpoint",
            "vehicle",
            "--config",
            config.to_str().unwrap(),
            "--autopilot",
            &format!("udpin:127.0.0.1:{port}"),
        ],
    )
}

fn count(log: &str, key: &str) -> u64 {
    log.lines()
        .filter(|l| l.contains("MAVLink counts"))
        .filter_map(|l| {
            let at = l.find(&format!("{key}="))? + key.len() + 1;
            l[at..].split_whitespace().next()?.parse().ok()
        })
        .next_back()
        .unwrap_or(0)
}

#[test]
fn a_pymavlink_ground_station_flies_the_ardusub_stand_in() {
    let ns = Namespace::new("vtap");
    let tmp = tempfile::tempdir().unwrap();
    let config = config_dir(tmp.path(), "");
    let port = free_port();
    let mut process = twin(&ns, &config, port);
    let (ok, out) = peer(&[&port.to_string(), "full"]);
    let status = process.terminate(T);
    let log = process.log();
    assert!(ok, "the peer failed:\n{out}\nthe twin:\n{log}");
    assert!(out.contains("PASS"), "{out}");
    assert!(status.success(), "{log}");
    // Dropped and refused, and counted in the twin's log.
    assert!(count(&log, "manual_control_not_from_gcs") > 0, "{log}");
    assert!(count(&log, "bad_crc") >= 1, "{log}");
    assert!(count(&log, "garbage_bytes") > 0, "{log}");
    assert!(count(&log, "failsafes") >= 1, "{log}");
}

#[test]
fn a_reversed_motor_shows_in_servo_output_raw() {
    let ns = Namespace::new("vtrv");
    let tmp = tempfile::tempdir().unwrap();
    let config = config_dir(tmp.path(), "MOT_3_DIRECTION = -1");
    let port = free_port();
    let mut process = twin(&ns, &config, port);
    let (ok, out) = peer(&[&port.to_string(), "reversed", "3"]);
    process.terminate(T);
    assert!(ok, "the peer failed:\n{out}\nthe twin:\n{}", process.log());
}
