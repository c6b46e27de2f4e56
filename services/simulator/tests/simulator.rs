//! The simulator as a process: it publishes states over iceoryx2 and answers setpoints with the next
//! state; the test plays the rest of the mesh.

use config::{Scenario, derive_seed};
use messages::{Endpoint, Stamp, StepStatus, ThrusterSetpoints, VehicleStateMsg, topics};
use simulator::Simulator;
use simulator::lockstep::Published;
use std::path::Path;
use std::time::{Duration, Instant};
use testkit::{Namespace, Process};

const T: Duration = Duration::from_secs(10);
const SEED: u64 = 7;

fn scenario() -> Scenario {
    config::load(&testkit::config_dir().join("scenario.toml")).expect("the repository's scenario")
}

/// The test's own simulator core, on the stream the process draws from.
fn twin(scenario: &Scenario) -> Simulator {
    Simulator::new(scenario, derive_seed(SEED, "simulator"))
}

fn setpoints(seq: u64, values: [f64; 3]) -> ThrusterSetpoints {
    let mut msg = ThrusterSetpoints {
        stamp: Stamp::new(seq, 0, 0, 0, StepStatus::Running),
        count: 3,
        scale: 1.0,
        ..Default::default()
    };
    msg.values[..3].copy_from_slice(&values);
    msg
}

/// Every field, bit for bit (`==` on floats would let 0.0 and -0.0 pass).
fn bits(m: &VehicleStateMsg) -> (Stamp, [u64; 9]) {
    (
        m.stamp,
        [
            m.x, m.y, m.psi, m.u, m.v, m.r, m.x_rate, m.y_rate, m.psi_rate,
        ]
        .map(f64::to_bits),
    )
}

fn assert_bitwise(got: &VehicleStateMsg, want: &VehicleStateMsg) {
    assert_eq!(bits(got), bits(want), "\n got {got:?}\nwant {want:?}");
}

fn expected(seq: u64, step: simulator::SimStep) -> VehicleStateMsg {
    Published { seq, step }.message()
}

fn start(ns: &Namespace, args: &[&str]) -> Process {
    let seed = SEED.to_string();
    let mut all = vec!["--endpoint", "sim", "--seed", &seed];
    all.extend_from_slice(args);
    Process::start(ns, &testkit::binary("simulator"), &all)
}

#[test]
fn answers_setpoints_with_the_state_its_core_predicts() {
    let ns = Namespace::new("sima");
    let probe = testkit::probe(&ns, Endpoint::Sim);
    let states = probe.inbox(&topics::VEHICLE_STATE);
    let out = probe.outbox(&topics::THRUSTER_SETPOINTS);
    let _sim = start(&ns, &[]);

    let scenario = scenario();
    let mut core = twin(&scenario);
    let first = probe
        .wait_for(&states, T, |_| true)
        .expect("the first state");
    assert_bitwise(&first, &expected(1, core.reset()));
    assert_eq!(
        (first.stamp.episode, first.stamp.step, first.stamp.status()),
        (0, 0, StepStatus::Running)
    );

    for (seq, values) in [
        (1, [0.6, 0.2, -0.4]),
        (2, [-0.3, 0.9, 0.1]),
        (3, [1.0, -1.0, 0.5]),
    ] {
        out.send(setpoints(seq, values)).unwrap();
        let next = probe
            .wait_for(&states, T, |m| m.stamp.seq > seq)
            .expect("the next state");
        assert_bitwise(&next, &expected(seq + 1, core.step(&values)));
        assert_eq!(next.stamp.time_ns, (seq * 200_000_000), "simulated time");
    }

    // Setpoints of another step are ignored: only the current step comes again (re-sent).
    out.send(setpoints(2, [1.0; 3])).unwrap();
    out.send(setpoints(9, [1.0; 3])).unwrap();
    let again = probe.wait_for(&states, T, |_| true).unwrap();
    assert_eq!(again.stamp.seq, 4);
    let again = probe.wait_for(&states, T, |_| true).unwrap();
    assert_eq!(again.stamp.seq, 4, "still waiting for step 4's setpoints");
    out.send(setpoints(4, [0.0, 0.5, 0.0])).unwrap();
    let fifth = probe
        .wait_for(&states, T, |m| m.stamp.seq > 4)
        .expect("step 5");
    assert_bitwise(&fifth, &expected(5, core.step(&[0.0, 0.5, 0.0])));
}

#[test]
fn re_sends_the_state_until_the_mesh_answers_and_never_times_out_before() {
    let ns = Namespace::new("simr");
    let probe = testkit::probe(&ns, Endpoint::Sim);
    let states = probe.inbox(&topics::VEHICLE_STATE);
    // A deadline far shorter than the wait below: before the mesh ever answered it does not apply.
    let _sim = start(&ns, &["--resend-ms", "30", "--deadline-ms", "50"]);
    let first = probe
        .wait_for(&states, T, |_| true)
        .expect("the first state");
    let t0 = Instant::now();
    for _ in 0..6 {
        let again = probe.wait_for(&states, T, |_| true).expect("a re-send");
        assert_bitwise(&again, &first);
    }
    // Six re-sends 30 ms apart: well past the 50 ms deadline, still step 1.
    assert!(
        t0.elapsed() >= Duration::from_millis(100),
        "{:?}",
        t0.elapsed()
    );
}

#[test]
fn a_step_without_setpoints_is_integrated_with_zero_thrust_after_the_deadline() {
    let ns = Namespace::new("simd");
    let probe = testkit::probe(&ns, Endpoint::Sim);
    let states = probe.inbox(&topics::VEHICLE_STATE);
    let out = probe.outbox(&topics::THRUSTER_SETPOINTS);
    let sim = start(&ns, &["--resend-ms", "50", "--deadline-ms", "300"]);
    let scenario = scenario();
    let mut core = twin(&scenario);
    core.reset();

    probe
        .wait_for(&states, T, |_| true)
        .expect("the first state");
    out.send(setpoints(1, [0.8, 0.8, 0.8])).unwrap();
    let second = probe.wait_for(&states, T, |m| m.stamp.seq == 2).unwrap();
    let t0 = Instant::now();
    assert_bitwise(&second, &expected(2, core.step(&[0.8, 0.8, 0.8])));
    // No setpoints for step 2: it is re-sent, then integrated with zero thrust.
    let mut resends = 0;
    let third = probe
        .wait_for(&states, T, |m| {
            resends += (m.stamp.seq == 2) as u32;
            m.stamp.seq == 3
        })
        .expect("the step after the deadline");
    let waited = t0.elapsed();
    assert_bitwise(&third, &expected(3, core.step(&[0.0; 3])));
    assert!(resends >= 2, "re-sent {resends} times while waiting");
    assert!(
        waited >= Duration::from_millis(200),
        "stepped after {waited:?}, before the 300 ms deadline"
    );
    let log = sim.log();
    assert!(
        log.contains("WARN") && log.contains("no setpoints within the deadline"),
        "the miss is logged:\n{log}"
    );
}

/// A copy of the repository's config with short episodes.
fn short_episodes(dir: &Path, max_steps: u32) {
    for file in ["scenario.toml", "learning.toml"] {
        let text = std::fs::read_to_string(testkit::config_dir().join(file)).unwrap();
        let text = if file == "scenario.toml" {
            let from = "max_steps = 200";
            assert!(text.contains(from), "scenario.toml sets {from}");
            text.replacen(from, &format!("max_steps = {max_steps}"), 1)
        } else {
            text
        };
        std::fs::write(dir.join(file), text).unwrap();
    }
}

#[test]
fn runs_the_requested_episodes_then_exits() {
    let ns = Namespace::new("sime");
    let dir = tempfile::tempdir().unwrap();
    short_episodes(dir.path(), 2);
    let probe = testkit::probe(&ns, Endpoint::Sim);
    let states = probe.inbox(&topics::VEHICLE_STATE);
    let out = probe.outbox(&topics::THRUSTER_SETPOINTS);
    let config_dir = dir.path().to_str().unwrap();
    let mut sim = start(&ns, &["--episodes", "2", "--config", config_dir]);

    let scenario: Scenario = config::load(&dir.path().join("scenario.toml")).unwrap();
    assert_eq!(scenario.timing.max_steps, 2);
    let mut core = twin(&scenario);
    let mut want = expected(1, core.reset());
    let values = [0.3, -0.3, 0.2];
    // Two episodes of steps 0, 1, 2 (the last one terminal): six states, each answered.
    for seq in 1..=6u64 {
        let got = probe
            .wait_for(&states, T, |m| m.stamp.seq == seq)
            .unwrap_or_else(|| panic!("state {seq}\n{}", sim.log()));
        assert_bitwise(&got, &want);
        let (episode, step) = ((seq - 1) / 3, (seq - 1) % 3);
        assert_eq!(
            (got.stamp.episode, got.stamp.step),
            (episode as u32, step as u32)
        );
        let status = if step == 2 {
            StepStatus::TimeLimit
        } else {
            StepStatus::Running
        };
        assert_eq!(got.stamp.status(), status);
        out.send(setpoints(seq, values)).unwrap();
        // After a terminal step the answer starts the next episode (its setpoints unused).
        want = expected(seq + 1, core.step(&values));
    }
    let status = sim
        .wait(T)
        .unwrap_or_else(|| panic!("still running after its episodes\n{}", sim.log()));
    assert!(status.success(), "exit status {status:?}\n{}", sim.log());
    // Nothing of a third episode was published.
    while let Some(m) = states.receive().unwrap() {
        assert!(m.stamp.seq <= 6, "published {m:?} after the last episode");
    }
    let log = sim.log();
    assert_eq!(log.matches("episode ended").count(), 2, "{log}");
}

#[test]
fn sigterm_stops_it_cleanly_and_leaves_nothing_behind() {
    let ns = Namespace::new("sims");
    let probe = testkit::probe(&ns, Endpoint::Sim);
    let states = probe.inbox(&topics::VEHICLE_STATE);
    let mut sim = start(&ns, &[]);
    probe
        .wait_for(&states, T, |_| true)
        .expect("the first state");
    let status = sim.terminate(T);
    assert!(status.success(), "exit status {status:?}\n{}", sim.log());
    assert!(sim.log().contains("stopped"));
    drop(states);
    drop(probe);
    assert_eq!(ns.leftovers(), Vec::<String>::new());
}

#[test]
fn refuses_the_vehicle_endpoint() {
    let ns = Namespace::new("simv");
    let mut sim = Process::start(
        &ns,
        &testkit::binary("simulator"),
        &["--endpoint", "vehicle"],
    );
    let status = sim.wait(T).expect("it exits");
    assert!(!status.success());
    assert!(
        sim.log().contains("`sim` endpoint only"),
        "a clear error:\n{}",
        sim.log()
    );
}
