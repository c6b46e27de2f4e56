//! The `vision` tool end to end: render a frame, detect the cable in it, write a data set.

use serde_json::Value;
use std::process::Command;

fn vision(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_vision"))
        .args(args)
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8(out.stdout).unwrap(),
        String::from_utf8(out.stderr).unwrap(),
    )
}

#[test]
fn render_then_detect_agrees_with_the_printed_ground_truth() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["frame.pgm", "frame.png"] {
        let path = dir.path().join(name);
        let path = path.to_str().unwrap();
        // 0.1 m to starboard of the cable, heading 20 degrees, surging: Theta = -20 degrees.
        let (ok, out, err) = vision(&[
            "render",
            "--pose",
            "1,0.1,20",
            "--velocity",
            "0.3,0,0",
            "--seed",
            "5",
            "--out",
            path,
        ]);
        assert!(ok, "{err}");
        let truth: Value = serde_json::from_str(out.trim()).unwrap();
        assert_eq!(truth["in_view"], true);
        assert!((truth["theta"].as_f64().unwrap() + 20f64.to_radians()).abs() < 1e-9);

        let (ok, out, err) = vision(&["detect", path]);
        assert!(ok, "{err}");
        let found: Value = serde_json::from_str(out.trim()).unwrap();
        assert_eq!(found["file"], path);
        assert_eq!(found["found"], true);
        for key in ["theta", "x_g", "y_g"] {
            let (a, b) = (found[key].as_f64().unwrap(), truth[key].as_f64().unwrap());
            assert!((a - b).abs() < 0.003, "{key}: {a} vs {b}");
        }
        assert!(found["confidence"].as_f64().unwrap() > 0.5);
        // The keys in the documented order.
        let keys: Vec<&str> = out
            .split('"')
            .skip(1)
            .step_by(2)
            .filter(|k| ["file", "found", "rho", "theta", "x_g", "y_g", "confidence"].contains(k))
            .collect();
        assert_eq!(
            keys,
            ["file", "found", "rho", "theta", "x_g", "y_g", "confidence"]
        );
    }
}

#[test]
fn a_data_set_has_frames_and_truth_and_detect_reads_directories() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().to_str().unwrap();
    let (ok, _, err) = vision(&["dataset", "--n", "5", "--out", d, "--seed", "3"]);
    assert!(ok, "{err}");
    let truth = std::fs::read_to_string(dir.path().join("truth.jsonl")).unwrap();
    assert_eq!(truth.lines().count(), 5);
    let (ok, out, err) = vision(&["detect", "--track", d]);
    assert!(ok, "{err}");
    let lines: Vec<Value> = out
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), 5);
    assert!(
        lines
            .iter()
            .all(|l| l["found"] == true && l.get("x_g_rate").is_some())
    );
}

#[test]
fn bad_files_are_reported_and_fail_the_run() {
    let dir = tempfile::tempdir().unwrap();
    let short = dir.path().join("short.pgm");
    std::fs::write(&short, b"P5\n320 240\n255\nabc").unwrap();
    let (ok, out, _) = vision(&["detect", short.to_str().unwrap()]);
    assert!(!ok);
    let line: Value = serde_json::from_str(out.trim()).unwrap();
    assert_eq!(line["found"], false);
    assert!(
        line["error"]
            .as_str()
            .unwrap()
            .contains("shorter than the header says")
    );
    let (ok, _, err) = vision(&["render", "--pose", "0,0", "--out", "x.pgm"]);
    assert!(
        !ok && err.contains("three comma-separated numbers"),
        "{err}"
    );
}
