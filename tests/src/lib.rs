//! The harness of the system tests: runs the service mesh (`config/sim-mesh.toml`, through the real
//! `supervisor`) in a test's own iceoryx2 namespace and reads back what it recorded.

use config::{LearningParams, Scenario};
use learning::{Algorithm, Checkpoint};
use messages::{CableObservationMsg, Endpoint, topics};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use testkit::Namespace;
use trainer::Perceiver;
use trainer::world::World;

/// What the monitor recorded of a run (`scripts/sim-mesh --json`).
pub use records::RunRecord;

/// An observation seen by the test while the mesh ran.
#[derive(Clone, Copy, Debug)]
pub struct Seen {
    pub episode: u32,
    pub step: u32,
    pub found: bool,
    pub x_g: f64,
    pub theta: f64,
}

/// A finished mesh run.
pub struct MeshRun {
    pub record: RunRecord,
    /// The observations the test's probe received (it may miss some: it is not part of the lockstep).
    pub seen: Vec<Seen>,
    pub log: String,
}

/// How to run the mesh.
pub struct MeshOptions {
    pub episodes: usize,
    pub seed: u64,
    /// `ideal` or `images`.
    pub eyes: &'static str,
    /// Watch the observations.
    pub watch: bool,
    pub timeout: Duration,
    /// The loop's services on these CPUs, as the mesh file places them outside the tests (`None`:
    /// on any CPU, the tests' placement, `testkit::SHARED_MACHINE`).
    pub loop_cpus: Option<&'static str>,
}

impl Default for MeshOptions {
    fn default() -> Self {
        MeshOptions {
            episodes: 5,
            seed: 1,
            eyes: "ideal",
            watch: false,
            timeout: Duration::from_secs(60),
            loop_cpus: None,
        }
    }
}

/// Runs the mesh to the end in `ns` and returns what it recorded.
pub fn run_mesh(ns: &Namespace, opts: &MeshOptions) -> MeshRun {
    let dir = tempfile::tempdir().expect("a temporary directory");
    let json: PathBuf = dir.path().join("run.json");
    let probe = testkit::probe(ns, Endpoint::Sim);
    let observations = opts.watch.then(|| probe.inbox(&topics::CABLE_OBSERVATION));
    let mut sets = vec![
        ("episodes", opts.episodes.to_string()),
        ("eyes", opts.eyes.to_owned()),
        ("json", json.display().to_string()),
        ("state", dir.path().display().to_string()),
    ];
    if let Some(cpus) = opts.loop_cpus {
        sets.push(("loop_cpus", cpus.to_owned()));
    }
    let mut supervisor = testkit::supervisor(
        ns,
        &testkit::config_dir().join("sim-mesh.toml"),
        opts.seed,
        &sets,
    );
    let end = Instant::now() + opts.timeout;
    let mut seen = Vec::new();
    let status = loop {
        if let Some(inbox) = &observations {
            while let Some(o) = inbox.receive().expect("receiving") {
                seen.push(seen_of(&o));
            }
            probe.block_on(inbox.listener(), Duration::from_millis(50));
        }
        if let Some(status) = supervisor.wait(if observations.is_some() {
            Duration::ZERO
        } else {
            Duration::from_millis(100)
        }) {
            break status;
        }
        assert!(
            Instant::now() < end,
            "the mesh did not finish in {:?}:\n{}",
            opts.timeout,
            supervisor.log()
        );
    };
    let log = supervisor.log();
    assert!(status.success(), "the mesh failed ({status:?}):\n{log}");
    let text = std::fs::read_to_string(&json)
        .unwrap_or_else(|e| panic!("no run record at {}: {e}\n{log}", json.display()));
    MeshRun {
        record: serde_json::from_str(&text).expect("a run record"),
        seen,
        log,
    }
}

fn seen_of(o: &CableObservationMsg) -> Seen {
    Seen {
        episode: o.stamp.episode,
        step: o.stamp.step,
        found: o.observation.found != 0,
        x_g: o.observation.x_g,
        theta: o.observation.theta,
    }
}

/// The mean of `values`.
pub fn mean(values: &[f64]) -> f64 {
    stats::mean(values.iter().copied())
}

/// A short step one in one process (`episodes` episodes, ideal perception, `seed`), saved as the
/// mesh's behaviours save theirs: `DIR/sway.ckpt` and `DIR/yaw.ckpt`.
pub fn step_one(dir: &Path, episodes: u64, seed: u64) {
    step_one_in(&testkit::config_dir(), dir, episodes, seed)
}

/// [`step_one`] on the scenario and learning parameters of the configuration directory `config`
/// (`config/bluerov2`: the BlueROV2's).
pub fn step_one_in(config: &Path, dir: &Path, episodes: u64, seed: u64) {
    let scenario: Scenario = config::load(&config.join("scenario.toml")).unwrap();
    let learning: LearningParams = config::load(&config.join("learning.toml")).unwrap();
    let eyes = Perceiver::Ideal(scenario.observation.clone());
    let mut world = World::new(&scenario, &learning, Algorithm::Nac, eyes, seed);
    for _ in 0..episodes {
        world.run_episode();
    }
    let agents = world.into_agents();
    std::fs::create_dir_all(dir).unwrap();
    Checkpoint::single(agents.sway.checkpoint())
        .save(&dir.join("sway.ckpt"))
        .unwrap();
    Checkpoint::single(agents.yaw.checkpoint())
        .save(&dir.join("yaw.ckpt"))
        .unwrap();
}

/// A short main job: step one of 30 episodes with the camera's exact line, Fig. 5 of 2 runs, a
/// one-generation limit search of 4 candidates; enough to see that the pieces fit and agree.
const SHORT_JOB: [&str; 10] = [
    "--sim-episodes",
    "30",
    "--fig5-runs",
    "2",
    "--sim-eyes",
    "ideal",
    "--limit-generations",
    "1",
    "--limit-population",
    "4",
];

/// Runs the main job short ([`SHORT_JOB`]), `scripts/two-step-learning --no-build ... ARGS --out
/// OUT`, for at most `timeout` (then kills it and fails), fails unless it succeeded, and returns
/// what it printed.
pub fn two_step_job(args: &[&str], out: &Path, timeout: Duration) -> String {
    let repo = testkit::config_dir().parent().unwrap().to_owned();
    let log = out.with_extension("log");
    let mut job = runtime::process::Spawn::new(repo.join("scripts/two-step-learning"))
        .arg("--no-build")
        .args(SHORT_JOB)
        .args(args.iter().copied())
        .arg("--out")
        .arg(out)
        .log(&log)
        .die_with_parent()
        .start()
        .expect("starting scripts/two-step-learning");
    let status = job.wait_timeout(timeout).unwrap_or_else(|| {
        job.kill();
        panic!(
            "two-step-learning did not finish within {timeout:?}\n{}",
            job.tail(30)
        )
    });
    let stdout = job.log();
    assert!(status.success(), "{status:?}\n{stdout}");
    stdout
}
