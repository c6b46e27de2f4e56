//! The service mesh of the design card: seven processes (plus the monitor) over iceoryx2 shared
//! memory in data-driven lockstep, started by the real supervisor from `config/sim-mesh.toml`.

use config::Eyes;
use config::{Dof, Preset};
use learning::Algorithm;
use messages::{Endpoint, topics};
use std::time::Duration;
use system_tests::{MeshOptions, mean, run_mesh};
use testkit::{Namespace, Process};
use trainer::Setup;
use trainer::world::World;

fn setup(eyes: Eyes) -> Setup {
    Setup::load(&testkit::config_dir(), Preset::Default)
        .unwrap()
        .with_eyes(eyes)
        .unwrap()
}

/// The in-process trainer's returns for the same seed.
fn trainer_returns(eyes: Eyes, seed: u64, episodes: usize) -> (Vec<f64>, Vec<f64>) {
    let s = setup(eyes);
    let mut world = World::new(
        &s.scenario,
        &s.learning,
        Algorithm::Nac,
        s.perceiver(seed),
        seed,
    );
    let results: Vec<_> = (0..episodes).map(|_| world.run_episode()).collect();
    (
        results.iter().map(|r| *r.returns.get(Dof::Yaw)).collect(),
        results.iter().map(|r| *r.returns.get(Dof::Sway)).collect(),
    )
}

#[test]
fn twenty_episodes_learn_and_keep_the_cable_centred() {
    let ns = Namespace::new("msh");
    let run = run_mesh(
        &ns,
        &MeshOptions {
            episodes: 20,
            eyes: "images",
            watch: true,
            timeout: Duration::from_secs(120),
            ..Default::default()
        },
    );
    let r = &run.record;
    assert_eq!(r.episodes, 20, "{}", run.log);
    for (dof, returns) in [("yaw", &r.yaw), ("sway", &r.sway)] {
        let (first, last) = (mean(&returns[..5]), mean(&returns[15..]));
        println!("{dof}: first 5 episodes {first:.3}, last 5 {last:.3}");
        assert!(
            last > first,
            "{dof}: the returns must rise: {first} -> {last}"
        );
    }
    assert!(
        r.lost[15..].iter().all(|l| !l),
        "the cable was lost in a late episode: {:?}",
        r.lost
    );
    // In the second half of the late episodes the cable is centred in the image.
    let late: Vec<(f64, f64)> = run
        .seen
        .iter()
        .filter(|s| s.episode >= 15 && s.step >= 100 && s.found)
        .map(|s| (s.x_g.abs(), s.theta.abs()))
        .collect();
    assert!(
        late.len() >= 100,
        "too few late observations seen: {}",
        late.len()
    );
    let x_g: Vec<f64> = late.iter().map(|v| v.0).collect();
    let theta: Vec<f64> = late.iter().map(|v| v.1).collect();
    println!(
        "late |x_g| {:.4}, late |Theta| {:.2} deg",
        mean(&x_g),
        mean(&theta).to_degrees()
    );
    assert!(mean(&x_g) < 0.05, "late mean |x_g| {}", mean(&x_g));
    assert!(
        mean(&theta) < 5f64.to_radians(),
        "late mean |Theta| {} rad",
        mean(&theta)
    );
    assert!(
        ns.leftovers().is_empty(),
        "shared memory left behind: {:?}",
        ns.leftovers()
    );
}

#[test]
fn the_same_seed_gives_the_same_returns_twice() {
    let opts = MeshOptions {
        episodes: 3,
        seed: 5,
        eyes: "images",
        ..Default::default()
    };
    let a = run_mesh(&Namespace::new("mda"), &opts).record;
    let b = run_mesh(&Namespace::new("mdb"), &opts).record;
    assert_eq!((&a.yaw, &a.sway), (&b.yaw, &b.sway));
    let c = run_mesh(&Namespace::new("mdc"), &MeshOptions { seed: 6, ..opts }).record;
    assert_ne!(a.yaw, c.yaw, "another seed, other episodes");
}

/// Runs the mesh and the in-process trainer on the same seed and asserts the same returns.
fn assert_mesh_equals_trainer(label: &str, eyes: Eyes, seed: u64, episodes: usize) {
    let run = run_mesh(
        &Namespace::new(label),
        &MeshOptions {
            episodes,
            seed,
            eyes: if eyes == Eyes::Ideal {
                "ideal"
            } else {
                "images"
            },
            ..Default::default()
        },
    );
    let (yaw, sway) = trainer_returns(eyes, seed, episodes);
    for (dof, mesh, trainer) in [
        ("yaw", &run.record.yaw, &yaw),
        ("sway", &run.record.sway, &sway),
    ] {
        assert_eq!(mesh.len(), trainer.len());
        for (e, (m, t)) in mesh.iter().zip(trainer).enumerate() {
            assert!(
                (m - t).abs() <= 1e-9 * t.abs().max(1.0),
                "{dof} episode {e}: mesh {m} vs trainer {t}"
            );
        }
    }
}

/// With ideal perception the mesh and the in-process trainer run the same cores on the same random
/// streams in the same order: the returns are the same to the last bit.
#[test]
fn the_mesh_and_the_trainer_agree_with_ideal_perception() {
    assert_mesh_equals_trainer("mti", Eyes::Ideal, 7, 10);
}

/// With rendered images and perception in the loop, the mesh renders the trainer's frames (same
/// seed stream, same frame numbers) and runs the same perception: the returns agree exactly too, a
/// stronger check than "statistically the same".
#[test]
fn the_mesh_and_the_trainer_agree_with_image_perception() {
    assert_mesh_equals_trainer("mtm", Eyes::Images, 3, 4);
}

/// After every process of a mesh is killed with SIGKILL (no chance to clean up), the next run in the
/// same namespace removes the leftovers and runs normally.
#[test]
fn a_mesh_killed_with_sigkill_leaves_nothing_that_stops_the_next_run() {
    let ns = Namespace::new("mkl");
    let probe = testkit::probe(&ns, Endpoint::Sim);
    let observations = probe.inbox(&topics::CABLE_OBSERVATION);
    let mut processes: Vec<Process> = [
        ("simulator", vec![]),
        ("camera", vec!["--eyes", "ideal"]),
        ("perception", vec!["--eyes", "ideal"]),
        ("sway-behaviour", vec![]),
        ("yaw-behaviour", vec![]),
        ("surge-controller", vec![]),
        ("thruster-allocator", vec![]),
    ]
    .into_iter()
    .map(|(name, args)| Process::start(&ns, &testkit::binary(name), &args))
    .collect();
    // The mesh is running: observations of later steps keep coming.
    assert!(
        probe
            .wait_for(&observations, Duration::from_secs(30), |o| o.stamp.seq > 50)
            .is_some()
    );
    drop(observations);
    drop(probe);
    for p in &mut processes {
        p.kill9();
    }
    assert!(
        !ns.leftovers().is_empty(),
        "SIGKILL should have left shared memory behind"
    );
    let run = run_mesh(&ns, &MeshOptions::default());
    assert_eq!(run.record.episodes, 5);
    assert!(
        ns.leftovers().is_empty(),
        "left behind: {:?}",
        ns.leftovers()
    );
}
