//! The vehicle's mesh (`config/vehicle.toml`) under its supervisor, against the twin in lockstep:
//! a learning behaviour killed with SIGKILL mid-learning is restarted, resumes from its own last
//! checkpoint (the policy's K and the counters exactly as saved, not the step-one policy), and the
//! loop goes on; SIGTERM to the supervisor then leaves no process and no shared-memory file.

use config::Dof;
use messages::{Endpoint, topics};
use std::path::Path;
use std::time::Duration;
use system_tests::step_one;
use testkit::Namespace;

const T: Duration = Duration::from_secs(40);
const STEP_ONE_EPISODES: u64 = 10;

/// What a "checkpoint saved" or "checkpoint loaded" log line says: K and the counters.
#[derive(Debug, PartialEq)]
struct Logged {
    gain: String,
    episodes: u64,
    steps: u64,
    actor_updates: u64,
}

fn logged(line: &str) -> Logged {
    let value = |key: &str| -> &str {
        let start = line
            .find(&format!(" {key}="))
            .unwrap_or_else(|| panic!("no {key} in {line}"))
            + key.len()
            + 2;
        let rest = &line[start..];
        let end = if rest.starts_with('[') {
            rest.find(']').unwrap() + 1
        } else {
            rest.find(' ').unwrap_or(rest.len())
        };
        &rest[..end]
    };
    Logged {
        gain: value("gain").to_owned(),
        episodes: value("episodes").parse().unwrap(),
        steps: value("steps").parse().unwrap(),
        actor_updates: value("actor_updates").parse().unwrap(),
    }
}

#[test]
fn a_behaviour_killed_mid_learning_on_the_vehicle_resumes_from_its_last_checkpoint() {
    let ns = Namespace::new("veh");
    let dir = tempfile::tempdir().unwrap();
    let (initial, state) = (dir.path().join("step-one"), dir.path().join("state"));
    step_one(&initial, STEP_ONE_EPISODES, 4);
    let probe = testkit::probe(&ns, Endpoint::Vehicle);
    let reports = probe.inbox(&topics::learning(Dof::Sway));
    let setpoints = probe.inbox(&topics::THRUSTER_SETPOINTS);
    let path = |p: &Path| p.display().to_string();
    let mut supervisor = testkit::supervisor(
        &ns,
        &testkit::config_dir().join("vehicle.toml"),
        4,
        &[
            ("trials", "0".into()),
            ("pacing", "--lockstep".into()),
            ("eyes", "ideal".into()),
            ("initial", path(&initial)),
            ("state", path(&state)),
            ("json", path(&dir.path().join("run.json"))),
            ("trace", path(&dir.path().join("trace.jsonl"))),
            ("record", path(&dir.path().join("flight.mcap"))),
        ],
    );

    // Learning on the vehicle: two trials done, then the sway behaviour dies in the middle of the
    // third (far from its end-of-trial save).
    let before = probe
        .wait_for(&setpoints, T, |s| {
            s.stamp.episode >= 2 && s.stamp.step >= 200
        })
        .unwrap_or_else(|| panic!("the mesh does not run:\n{}", supervisor.log()));
    let sway = supervisor
        .signal_service("sway-behaviour", libc::SIGKILL)
        .expect("sway-behaviour is one of the supervisor's children");
    // The loop goes on: a newer trial is reported by the restarted behaviour.
    probe
        .wait_for(&reports, T, |s| s.stamp.episode >= before.stamp.episode + 2)
        .unwrap_or_else(|| panic!("the loop did not resume:\n{}", supervisor.log()));
    let restarted = supervisor
        .service("sway-behaviour")
        .expect("sway-behaviour was restarted");
    assert_ne!(restarted, sway);

    drop(reports);
    drop(setpoints);
    drop(probe);
    let status = supervisor.terminate(T);
    let log = supervisor.log();
    assert!(
        status.success(),
        "the supervisor stops cleanly: {status:?}\n{log}"
    );
    assert!(
        ns.leftovers().is_empty(),
        "shared memory left behind: {:?}",
        ns.leftovers()
    );

    // What the killed process saved last, and what the restarted one loaded.
    let own = state.join("sway.ckpt").display().to_string();
    let sway_line = |l: &str| l.contains("service{name=\"sway-behaviour\"}");
    assert!(
        log.lines()
            .any(|l| l.contains("died") && l.contains("service=sway-behaviour")),
        "the death is logged:\n{log}"
    );
    let lines: Vec<&str> = log
        .lines()
        .filter(|l| sway_line(l) || l.contains("died"))
        .collect();
    let died = lines
        .iter()
        .position(|l| l.contains("died") && l.contains("service=sway-behaviour"))
        .unwrap();
    let saved = lines[..died]
        .iter()
        .rfind(|l| l.contains("checkpoint saved"))
        .unwrap_or_else(|| panic!("a checkpoint was saved before the kill:\n{log}"));
    let loaded = lines[died..]
        .iter()
        .find(|l| l.contains("checkpoint loaded"))
        .unwrap_or_else(|| panic!("the restarted behaviour loaded a checkpoint:\n{log}"));
    // Its own checkpoint, not step one's. (Had the kill fallen inside a save, FILE would be missing
    // and FILE.prev, the last complete save, would be loaded, with a warning saying so.)
    let interrupted_save = log.contains("a save was interrupted");
    assert!(
        loaded.contains(&format!("path={own} "))
            || (interrupted_save && loaded.contains(&format!("path={own}.prev "))),
        "it resumed from its own checkpoint, not step one's: {loaded}"
    );
    assert!(log.contains("restarting"), "the restart is logged");
    let (saved, loaded) = (logged(saved), logged(loaded));
    assert_eq!(loaded, saved, "K and the counters as saved");
    assert!(
        loaded.episodes > STEP_ONE_EPISODES,
        "it had learned on the vehicle: {loaded:?}"
    );
}
