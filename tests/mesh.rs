//! The service mesh of DESIGN.md: seven processes (plus the monitor) over iceoryx2 shared
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

/// What one 20-episode run with images showed late: the mean |x_g| and |Theta| (rad) of the
/// observations of the second half of the last five episodes.
struct Late {
    x_g: f64,
    theta: f64,
}

/// Runs 20 episodes with images on `seed`: the returns rise in both DOFs, no late episode loses the
/// cable, nothing is left in shared memory. Returns the late centring.
fn twenty_episodes(seed: u64) -> Late {
    let ns = Namespace::new(&format!("ms{seed}"));
    let run = run_mesh(
        &ns,
        &MeshOptions {
            episodes: 20,
            seed,
            eyes: "images",
            watch: true,
            timeout: Duration::from_secs(120),
            loop_cpus: None,
        },
    );
    let r = &run.record;
    assert_eq!(r.episodes, 20, "{}", run.log);
    for (dof, returns) in [("yaw", &r.yaw), ("sway", &r.sway)] {
        let (first, last) = (mean(&returns[..5]), mean(&returns[15..]));
        println!("seed {seed}, {dof}: first 5 episodes {first:.3}, last 5 {last:.3}");
        assert!(
            last > first,
            "seed {seed}, {dof}: the returns must rise: {first} -> {last}"
        );
    }
    assert!(
        r.lost[15..].iter().all(|l| !l),
        "seed {seed}: the cable was lost in a late episode: {:?}",
        r.lost
    );
    // The second half of the late episodes, as perception saw it.
    let late: Vec<(f64, f64)> = run
        .seen
        .iter()
        .filter(|s| s.episode >= 15 && s.step >= 100 && s.found)
        .map(|s| (s.x_g.abs(), s.theta.abs()))
        .collect();
    assert!(
        late.len() >= 100,
        "seed {seed}: too few late observations seen: {}",
        late.len()
    );
    assert!(
        ns.leftovers().is_empty(),
        "seed {seed}: shared memory left behind: {:?}",
        ns.leftovers()
    );
    let x_g: Vec<f64> = late.iter().map(|v| v.0).collect();
    let theta: Vec<f64> = late.iter().map(|v| v.1).collect();
    let late = Late {
        x_g: mean(&x_g),
        theta: mean(&theta),
    };
    println!(
        "seed {seed}: late |x_g| {:.5}, late |Theta| {:.3} deg",
        late.x_g,
        late.theta.to_degrees()
    );
    late
}

/// Seeds 1 to 3, each run learns, and late in the run the cable is centred: the median over the
/// seeds and the worst seed of the late mean |x_g| and |Theta| stay within the figures docs/results.md
/// publishes for these seeds, plus the margin the noise needs.
///
/// The noise, measured: the same seed run again differs by up to 0.0006 in |x_g| and 0.01 degree in
/// |Theta| (the test's probe, outside the lockstep, may miss a few observations); from one seed to
/// another the figures vary far more. Over seeds 1 to 18 taken three at a time (six runs of this
/// test with other seeds) the median of three ranged 0.0066 to 0.0089 in |x_g| and 0.19 to 0.34
/// degree in |Theta|, the worst of three 0.0069 to 0.0138 and 0.23 to 0.47 degree. Each margin is
/// that range's width.
#[test]
fn over_three_seeds_twenty_episodes_learn_and_keep_the_cable_centred() {
    let late: Vec<Late> = [1, 2, 3].into_iter().map(twenty_episodes).collect();
    let x_g: Vec<f64> = late.iter().map(|l| l.x_g).collect();
    let theta: Vec<f64> = late.iter().map(|l| l.theta.to_degrees()).collect();
    let (x_g_median, x_g_worst) = (stats::median(x_g.iter().copied()), max(&x_g));
    let (theta_median, theta_worst) = (stats::median(theta.iter().copied()), max(&theta));
    // Published: median 0.0066, worst 0.0105; margins 0.0023 and 0.0070 (see above).
    assert!(x_g_median < 0.0066 + 0.0023, "median late |x_g| {x_g:?}");
    assert!(x_g_worst < 0.0105 + 0.0070, "worst late |x_g| {x_g:?}");
    // Published: median 0.31 degree, worst 0.37; margins 0.16 and 0.24 degree (see above).
    assert!(
        theta_median < 0.31 + 0.16,
        "median late |Theta| {theta:?} deg"
    );
    assert!(
        theta_worst < 0.37 + 0.24,
        "worst late |Theta| {theta:?} deg"
    );
}

fn max(values: &[f64]) -> f64 {
    values.iter().copied().fold(f64::NEG_INFINITY, f64::max)
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

/// Runs the mesh and the in-process trainer on the same seed and asserts the same returns, bit for
/// bit (the monitor's JSON record carries each f64 exactly: serde_json's `float_roundtrip`).
fn assert_mesh_equals_trainer(
    label: &str,
    eyes: Eyes,
    seed: u64,
    episodes: usize,
    loop_cpus: Option<&'static str>,
) {
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
            loop_cpus,
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
            assert_eq!(
                m.to_bits(),
                t.to_bits(),
                "{dof} episode {e}: mesh {m} vs trainer {t}"
            );
        }
    }
}

/// With ideal perception the mesh and the in-process trainer run the same cores on the same random
/// streams in the same order: the returns are the same to the last bit.
#[test]
fn the_mesh_and_the_trainer_agree_with_ideal_perception() {
    assert_mesh_equals_trainer("mti", Eyes::Ideal, 7, 10, None);
}

/// With rendered images and perception in the loop, the mesh renders the trainer's frames (same
/// seed stream, same frame numbers) and runs the same perception: the returns are the same to the
/// last bit too, a stronger check than "statistically the same". The loop runs on one CPU, as the
/// mesh file places it for speed (the ideal test above runs it on any CPU): where the processes run
/// changes no bit.
#[test]
fn the_mesh_and_the_trainer_agree_with_image_perception() {
    assert_mesh_equals_trainer("mtm", Eyes::Images, 3, 4, Some("0"));
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
