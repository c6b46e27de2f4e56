//! The bare ring of `mesh-bench` (its limit (b), and `mesh-bench ring`, the vehicle's limit): every
//! node of each shape answers every step, each hop is measured, and a paced ring keeps its period.
//! Few steps, a timeout on the bench; no timing is judged here beyond the period the ring promises.

use mesh_bench::ring::{Role, Shape};
use mesh_bench::runs::RingRun;
use runtime::process::Spawn;
use std::time::Duration;
use testkit::Namespace;

/// Long enough to start nine processes and run a few dozen steps on a loaded 2-core machine.
const TIMEOUT: Duration = Duration::from_secs(120);

/// Runs `mesh-bench ring` with `args`; returns its runs as its `--json` file has them.
fn ring(ns: &Namespace, name: &str, args: &[&str]) -> Vec<RingRun> {
    let json = ns.scratch().join(format!("{name}.json"));
    let mut bench = Spawn::new(testkit::binary("mesh-bench"))
        .arg("ring")
        .args(args)
        .arg("--config")
        .arg(testkit::config_dir())
        .arg("--json")
        .arg(&json)
        .env("RUST_LOG", "warn")
        .log(ns.scratch().join(format!("{name}.log")))
        .die_with_parent()
        .start()
        .expect("starting mesh-bench ring");
    let status = bench.wait_timeout(TIMEOUT).unwrap_or_else(|| {
        panic!(
            "mesh-bench ring did not finish within {TIMEOUT:?}\n{}",
            bench.tail(20)
        )
    });
    assert!(status.success(), "{status:?}\n{}", bench.tail(20));
    let text = std::fs::read_to_string(&json).expect("the bench's --json file");
    serde_json::from_str(&text).expect("the runs of the ring")
}

/// Every node of `shape` measured each timed step once (the allocator: once per command).
fn every_hop_measured(run: &RingRun, shape: Shape, steps: u64) {
    let roles: Vec<Role> = run.hops.iter().map(|(r, _)| *r).collect();
    assert_eq!(roles, shape.roles(), "the nodes of the {shape:?} shape");
    for (role, hop) in &run.hops {
        let per_step = if *role == Role::Allocator { 3 } else { 1 };
        assert_eq!(hop.n, per_step * steps as usize, "{role:?}'s hops");
        assert!(hop.p50 > 0 && hop.p50 <= hop.p99, "{role:?}: {hop:?}");
    }
    assert_eq!(run.step.n, steps as usize);
    // A step crosses every hop in turn (the commands' three in parallel): it takes longer than any.
    let longest_hop = run.hops.iter().map(|(_, h)| h.p50).max().unwrap();
    assert!(
        run.step.p50 > longest_hop,
        "{:?} against {longest_hop}",
        run.step
    );
    assert_eq!(run.leftovers, 0, "shared memory left behind");
}

#[test]
fn each_shape_passes_every_step_through_each_of_its_nodes() {
    // The vehicle's shape has the thruster driver between the allocator and the twin; the mesh's not.
    for (shape, name) in [(Shape::Vehicle, "vehicle"), (Shape::Mesh, "mesh")] {
        let ns = Namespace::new("rs");
        let dir = ns.scratch().join("latencies");
        let runs = ring(
            &ns,
            name,
            &[
                "--shape",
                name,
                "--period-ms",
                "0",
                "--steps",
                "60",
                "--latencies",
                dir.to_str().unwrap(),
            ],
        );
        assert_eq!(runs.len(), 1);
        let run = &runs[0];
        assert_eq!(run.shape, shape);
        assert_eq!(run.missed, 0);
        every_hop_measured(run, shape, 60);
        // The steps' file, as the vehicle's latency file, holds the steps the summary was made of.
        let text = std::fs::read_to_string(dir.join("ring-1.csv")).expect("the run's latencies");
        let steps = records::latency::read_latencies(&text).expect("a latency file");
        assert_eq!(stats::Summary::of(&steps), run.step);
    }
}

#[test]
fn a_paced_ring_sends_a_step_per_period() {
    let ns = Namespace::new("rp");
    let (steps, period_ms) = (12, 50.0);
    let runs = ring(
        &ns,
        "paced",
        &[
            "--period-ms",
            &period_ms.to_string(),
            "--steps",
            &steps.to_string(),
            "--warmup",
            "3",
        ],
    );
    let run = &runs[0];
    // A step answered in 50 ms on a loaded machine: none missed, so each was timed.
    assert_eq!(run.missed, 0, "{run:?}");
    every_hop_measured(run, Shape::Vehicle, steps);
    // The timed steps span `steps` periods, less the half period a tick may come early: a ring that
    // did not wait would take a few milliseconds.
    let wall_ms = run.steps as f64 / run.steps_per_s * 1e3;
    let least = (steps as f64 - 0.5) * period_ms;
    assert!(wall_ms >= least, "{wall_ms:.1} ms for {steps} steps");
}
