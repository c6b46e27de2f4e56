//! Replay as the regression test of perception and the behaviours on a dive: a vehicle dive (the
//! vehicle mesh against the twin, images and perception in the loop, the behaviours learning from a
//! step-one policy) is kept by the flight recorder; its frames replayed through perception and the
//! behaviours (`config/replay.toml`) with the same seed and start give the recorded observations,
//! commands, setpoints and episode reports bit for bit; with another seed (the behaviours' exploration
//! changed, perception not) the report finds the commands differing and the observations equal.

use replay::Report;
use std::path::{Path, PathBuf};
use std::time::Duration;
use system_tests::step_one;
use testkit::Namespace;

const SEED: u64 = 7;
const T: Duration = Duration::from_secs(90);

/// The twin's reality gap with 30-second trials (150 frames), to keep the dive short.
fn short_trials(dir: &Path) -> PathBuf {
    let text = std::fs::read_to_string(testkit::config_dir().join("twin.toml"))
        .unwrap()
        .replace("duration_s = 90.0", "duration_s = 30.0");
    let path = dir.join("twin-short.toml");
    std::fs::write(&path, text).unwrap();
    path
}

fn run(label: &str, mesh: &str, seed: u64, sets: &[(&str, String)]) {
    let ns = Namespace::new(label);
    let mut supervisor = testkit::supervisor(&ns, &testkit::config_dir().join(mesh), seed, sets);
    let status = supervisor
        .wait(T)
        .unwrap_or_else(|| panic!("{mesh} did not finish in {T:?}:\n{}", supervisor.log()));
    assert!(status.success(), "{mesh} failed:\n{}", supervisor.log());
    assert!(ns.leftovers().is_empty(), "{:?}", ns.leftovers());
}

fn report(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

#[test]
fn a_recorded_dive_replays_bit_for_bit_and_a_changed_behaviour_is_located() {
    let dir = tempfile::tempdir().unwrap();
    let path = |p: &Path| p.display().to_string();
    let initial = dir.path().join("step-one");
    step_one(&initial, 10, 4);
    let record = dir.path().join("dive.mcap");
    run(
        "rpd",
        "vehicle.toml",
        SEED,
        &[
            ("trials", "2".into()),
            ("pacing", "--lockstep".into()),
            ("eyes", "images".into()),
            ("initial", path(&initial)),
            ("state", path(&dir.path().join("state"))),
            ("json", path(&dir.path().join("run.json"))),
            ("trace", path(&dir.path().join("trace.jsonl"))),
            (
                "twin",
                format!("--twin-config={}", path(&short_trials(dir.path()))),
            ),
            ("record", path(&record)),
        ],
    );
    let replay = |label: &str, seed: u64, name: &str, check: &str| {
        let out = dir.path().join(format!("{name}.json"));
        run(
            label,
            "replay.toml",
            seed,
            &[
                ("record", path(&record)),
                ("report", path(&out)),
                ("check", check.into()),
                ("state", path(&dir.path().join(format!("{name}-state")))),
                (
                    "sway_initial",
                    format!("--initial={}", path(&initial.join("sway.ckpt"))),
                ),
                (
                    "yaw_initial",
                    format!("--initial={}", path(&initial.join("yaw.ckpt"))),
                ),
            ],
        );
        report(&out)
    };

    // The same seed and start: every output equal to the record. The run fails on a difference
    // (--fail-on-difference), and the report says why.
    let same = replay("rps", SEED, "same", "--fail-on-difference");
    assert_eq!(same["identical"], true, "{same:#}");
    let frames = same["frames"].as_u64().unwrap();
    assert!(
        frames > 250,
        "two trials of 150 frames, 3% dropped: {frames}"
    );
    for topic in [
        "/cable_observation",
        "/command/surge",
        "/command/sway",
        "/command/yaw",
        "/thruster_setpoints",
    ] {
        let t = &same["topics"][topic];
        assert_eq!(t["recorded"], frames, "{topic}: {t}");
        assert_eq!(t["equal"], frames, "{topic}: {t}");
    }
    for topic in ["/learning/sway", "/learning/yaw"] {
        assert_eq!(
            same["topics"][topic]["equal"], 2,
            "both trials' reports: {same:#}"
        );
    }

    // Another seed: the behaviours explore differently; perception is the same code on the same
    // frames.
    let other: Report = serde_json::from_value(replay("rpo", SEED + 1, "other", "")).unwrap();
    assert!(!other.identical);
    let obs = &other.topics["/cable_observation"];
    assert_eq!(
        (obs.compared, obs.equal),
        (frames, frames),
        "{}",
        other.text()
    );
    let surge = &other.topics["/command/surge"];
    assert_eq!(surge.differing, 0, "surge follows the observation only");
    for dof in ["/command/sway", "/command/yaw"] {
        let t = &other.topics[dof];
        assert!(t.differing > frames / 2, "{dof}: {}", other.text());
        assert!(t.max_abs_difference["value"] > 0.0);
    }
    let first = other.first_difference.as_ref().expect("located");
    assert!(
        first.topic.starts_with("/command/") && first.field == "value",
        "{}",
        other.text()
    );
    assert_eq!(
        (first.episode, first.step),
        (0, 0),
        "from the first frame on"
    );
}
