//! The behaviours as processes: `sway-behaviour` and `yaw-behaviour`, each started alone in its own
//! namespace and fed cable observations over iceoryx2. Every test runs for both binaries.
//!
//! The reference is an agent in the test, built from the `learning` crate the way the in-process
//! trainer builds it, stepped by the trainer's rule: the processes must answer with exactly its
//! actions, returns and checkpoints (bitwise), for the same seed.

use config::{Dof, LearningParams, Scenario};
use learning::{Agent, AgentState, Algorithm, Checkpoint, EpisodeSummary, LearnerState};
use messages::{
    CableObservationData, CableObservationMsg, DofCommand, Endpoint, Inbox, LearningStats, Outbox,
    Stamp, StepStatus, topics,
};
use std::path::{Path, PathBuf};
use std::time::Duration;
use testkit::{Namespace, Probe, Process};

const T: Duration = Duration::from_secs(10);
const SEED: u64 = 7;

fn scenario() -> Scenario {
    config::load(&testkit::config_dir().join("scenario.toml")).unwrap()
}

fn learning() -> LearningParams {
    config::load(&testkit::config_dir().join("learning.toml")).unwrap()
}

fn binary(dof: Dof) -> PathBuf {
    testkit::binary(&format!("{dof}-behaviour"))
}

fn stream_seed(dof: Dof) -> u64 {
    config::derive_seed(SEED, dof.name())
}

/// The agent the trainer would build for `dof` with the experiment seed [`SEED`].
fn trainer_agent(dof: Dof, algorithm: Algorithm, params: &LearningParams) -> Agent {
    let s = scenario();
    Agent::new(
        dof,
        algorithm,
        params,
        *s.reward.of(dof),
        s.state_max(dof),
        stream_seed(dof),
    )
}

/// The in-test behaviour: an agent stepped by the trainer's rule (`trainer::world::behave`).
struct Reference(Agent);

impl Reference {
    fn fresh(dof: Dof, algorithm: Algorithm) -> Self {
        Reference(trainer_agent(dof, algorithm, &learning()))
    }

    /// An agent resumed from `state` as the behaviours resume (their documented seed rule).
    fn resumed(state: &AgentState) -> Self {
        let seed = behaviour::resume_seed(stream_seed(state.dof), state);
        Reference(Agent::from_state(state.clone(), seed).unwrap())
    }

    fn step(&mut self, msg: &CableObservationMsg) -> (f64, Option<EpisodeSummary>) {
        let obs = msg.observation();
        let kind = msg.stamp.status();
        if !obs.found && kind == StepStatus::Running {
            return (self.0.skip(), None);
        }
        let s = self.0.step(obs.state(self.0.dof()), kind);
        (s.action, s.episode)
    }
}

/// Observations of one episode: `len` running steps (those in `missed` without the cable), then
/// one with status `end`. `seq` counts on from `first_seq`.
fn episode(
    first_seq: u64,
    episode: u32,
    len: u32,
    end: StepStatus,
    missed: &[u32],
) -> Vec<CableObservationMsg> {
    (0..=len)
        .map(|step| {
            let seq = first_seq + step as u64;
            let t = seq as f64;
            let status = if step == len {
                end
            } else {
                StepStatus::Running
            };
            CableObservationMsg {
                stamp: Stamp::new(seq, seq * 200_000_000, episode, step, status),
                observation: CableObservationData {
                    found: !missed.contains(&step) as u8,
                    x_g: 0.35 * (0.37 * t).sin(),
                    x_g_rate: 0.3 * (0.37 * t).cos(),
                    theta: 0.7 * (0.23 * t + 1.0).sin(),
                    theta_rate: 0.4 * (0.23 * t + 1.0).cos(),
                    ..Default::default()
                },
            }
        })
        .collect()
}

/// A learned state: the reference agent after a few episodes.
fn trained(dof: Dof, gain: [f64; 2], episodes: u32) -> AgentState {
    let mut params = learning();
    *params.policy.initial_gain.get_mut(dof) = gain;
    let mut r = Reference(trainer_agent(dof, Algorithm::Nac, &params));
    let mut seq = 1000;
    for e in 0..episodes {
        for m in episode(seq, e, 25, StepStatus::TimeLimit, &[3]) {
            r.step(&m);
        }
        seq += 26;
    }
    let state = r.0.checkpoint();
    assert!(state.steps > 0 && state.episodes == episodes as u64);
    state
}

fn actor_updates(state: &AgentState) -> u64 {
    match &state.learner {
        LearnerState::Nac(s) => s.actor_updates,
        LearnerState::Gpomdp(s) => s.actor_updates,
    }
}

/// A behaviour process and the test's ports to it.
struct Rig {
    dof: Dof,
    probe: Probe,
    observations: Outbox<CableObservationMsg>,
    commands: Inbox<DofCommand>,
    stats: Inbox<LearningStats>,
    process: Process,
    _ns: Namespace,
}

impl Rig {
    fn start(dof: Dof, label: &str, args: &[&str]) -> Rig {
        let ns = Namespace::new(label);
        let probe = testkit::probe(&ns, Endpoint::Sim);
        let commands = probe.inbox(&topics::command(dof));
        let stats = probe.inbox(&topics::learning(dof));
        let observations = probe.outbox(&topics::CABLE_OBSERVATION);
        let seed = SEED.to_string();
        let mut all = vec!["--seed", &seed];
        all.extend_from_slice(args);
        let process = Process::start(&ns, &binary(dof), &all);
        assert!(
            probe.wait_for_publisher(&commands, T),
            "{dof}-behaviour never came up:\n{}",
            process.log()
        );
        assert!(probe.wait_for_subscribers(&observations, 1, T));
        Rig {
            dof,
            probe,
            observations,
            commands,
            stats,
            process,
            _ns: ns,
        }
    }

    /// Sends one observation and waits for the command of its step.
    fn command(&self, msg: &CableObservationMsg) -> f64 {
        self.observations.send(*msg).unwrap();
        let seq = msg.stamp.seq;
        self.probe
            .wait_for(&self.commands, T, |c| c.stamp.seq == seq)
            .unwrap_or_else(|| panic!("{}: no command for step {seq}", self.dof))
            .value
    }

    /// The next learning statistics.
    fn stats(&self) -> LearningStats {
        self.probe
            .wait_for(&self.stats, T, |_| true)
            .unwrap_or_else(|| panic!("{}: no learning statistics", self.dof))
    }

    /// Feeds `msgs` to the process and to `reference`: the commands must be the reference's
    /// actions, bit for bit, and each episode's statistics its summary.
    fn run(&self, reference: &mut Reference, msgs: &[CableObservationMsg]) -> Vec<LearningStats> {
        let mut stats = Vec::new();
        for m in msgs {
            let (action, episode) = reference.step(m);
            let command = self.command(m);
            assert_eq!(
                command.to_bits(),
                action.to_bits(),
                "{}: step {}: command {command}, the reference's {action}",
                self.dof,
                m.stamp.seq
            );
            if let Some(e) = episode {
                let s = self.stats();
                assert_eq!(s.stamp, m.stamp);
                assert_eq!(
                    s.episode_return.to_bits(),
                    e.return_.to_bits(),
                    "{}: return {} vs the reference's {}",
                    self.dof,
                    s.episode_return,
                    e.return_
                );
                assert_eq!(
                    (s.gain, s.actor_updates, s.steps, s.failed),
                    (e.gain, e.actor_updates, e.steps, e.failed as u8)
                );
                assert_eq!(s.learning, reference.0.is_learning() as u8);
                stats.push(s);
            }
        }
        stats
    }

    fn stop(&mut self) {
        let status = self.process.terminate(T);
        assert!(
            status.success(),
            "{}: exit {status:?}\n{}",
            self.dof,
            self.process.log()
        );
    }
}

fn save(path: &Path, states: impl IntoIterator<Item = AgentState>) {
    let mut c = Checkpoint::default();
    for s in states {
        c.insert(s);
    }
    c.save(path).unwrap();
}

fn arg(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Two episodes: a time limit with two missed frames, then a lost cable.
fn two_episodes() -> Vec<CableObservationMsg> {
    let mut v = episode(1, 0, 30, StepStatus::TimeLimit, &[4, 5]);
    v.extend(episode(32, 1, 17, StepStatus::Lost, &[9]));
    v
}

fn learns_like_an_in_test_agent(dof: Dof) {
    let rig = Rig::start(dof, "bln", &[]);
    let mut reference = Reference::fresh(dof, Algorithm::Nac);
    let stats = rig.run(&mut reference, &two_episodes());
    assert_eq!(stats.len(), 2);
    assert_eq!((stats[0].failed, stats[1].failed), (0, 1));
    assert!(
        stats.iter().all(|s| s.learning == 1),
        "learning is the default"
    );
    assert!(
        actor_updates(&reference.0.checkpoint()) > 0,
        "the run must reach an actor update to show learning"
    );
}

fn learns_with_gpomdp_when_asked(dof: Dof) {
    let rig = Rig::start(dof, "blg", &["--algorithm", "gpomdp"]);
    let mut reference = Reference::fresh(dof, Algorithm::Gpomdp);
    assert_eq!(rig.run(&mut reference, &two_episodes()).len(), 2);
    assert!(reference.0.gain() != *learning().policy.initial_gain.get(dof));
}

fn acts_only_with_the_initial_policy(dof: Dof) {
    let dir = tempfile::tempdir().unwrap();
    let (initial, own) = (
        dir.path().join("step-one.ckpt"),
        dir.path().join("own.ckpt"),
    );
    // The trainer's file holds both DOFs; each behaviour takes its own entry.
    let gain = [-1.5, -0.4];
    let state = trained(dof, gain, 2);
    let other = Dof::ALL.into_iter().find(|d| *d != dof).unwrap();
    save(&initial, [state.clone(), trained(other, [-3.0, -3.0], 1)]);
    let mut rig = Rig::start(
        dof,
        "bla",
        &[
            "--act-only",
            "--initial",
            arg(&initial),
            "--checkpoint",
            arg(&own),
        ],
    );
    let mut reference = Reference::resumed(&state);
    reference.0.set_learning(false);
    let k = state.policy.gain;
    let msgs = episode(1, 0, 20, StepStatus::TimeLimit, &[]);
    for m in &msgs[..msgs.len() - 1] {
        // Within the exploration noise (sigma = 0.1) of clip(K x).
        let x = m.observation().state(dof);
        let x = [
            x[0].clamp(-state.state_max[0], state.state_max[0]),
            x[1].clamp(-state.state_max[1], state.state_max[1]),
        ];
        let mean = (k[0] * x[0] + k[1] * x[1]).clamp(-1.0, 1.0);
        let (action, _) = reference.step(m);
        let command = rig.command(m);
        assert_eq!(command.to_bits(), action.to_bits());
        assert!(
            (command - mean).abs() <= 5.0 * 0.1,
            "{command} vs clip(Kx) = {mean}"
        );
    }
    let (_, e) = reference.step(msgs.last().unwrap());
    rig.command(msgs.last().unwrap());
    let s = rig.stats();
    assert_eq!(s.episode_return.to_bits(), e.unwrap().return_.to_bits());
    assert_eq!((s.learning, s.gain), (0, k), "nothing learned");
    assert_eq!(s.actor_updates, actor_updates(&state));
    rig.stop();
    assert!(!own.exists(), "acting only writes no checkpoint");
}

fn writes_its_checkpoint_on_sigterm(dof: Dof) {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join(format!("{dof}.ckpt"));
    let mut rig = Rig::start(
        dof,
        "bls",
        &["--checkpoint", arg(&file), "--save-every", "0"],
    );
    let mut reference = Reference::fresh(dof, Algorithm::Nac);
    let mut msgs = two_episodes();
    // And a few steps into a third episode.
    msgs.extend(
        episode(50, 2, 30, StepStatus::TimeLimit, &[])
            .into_iter()
            .take(6),
    );
    rig.run(&mut reference, &msgs);
    assert!(!file.exists(), "--save-every 0: only at shutdown");
    rig.stop();
    let saved = Checkpoint::load_dof(&file, dof).unwrap();
    let expected = reference.0.checkpoint();
    // Transitions: a missed frame closes the pending one, a second in a row has none to close.
    assert_eq!((saved.episodes, saved.steps), (2, (30 - 2) + (17 - 1) + 5));
    assert_eq!(
        saved, expected,
        "K, the critic's statistics and the counters as learned"
    );
    let log = rig.process.log();
    assert!(
        log.contains("checkpoint saved") && log.contains("termination signal"),
        "{log}"
    );
}

fn saves_every_n_episodes_keeping_the_previous(dof: Dof) {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join(format!("{dof}.ckpt"));
    let rig = Rig::start(
        dof,
        "ble",
        &["--checkpoint", arg(&file), "--save-every", "1"],
    );
    let mut reference = Reference::fresh(dof, Algorithm::Nac);
    let first = episode(1, 0, 12, StepStatus::TimeLimit, &[]);
    let second = episode(14, 1, 9, StepStatus::Lost, &[]);
    let next = episode(24, 2, 5, StepStatus::TimeLimit, &[]);
    rig.run(&mut reference, &first);
    let after_first = reference.0.checkpoint();
    rig.run(&mut reference, &second);
    let after_second = reference.0.checkpoint();
    // The save follows the episode's last command; the next step's command comes after it.
    rig.run(&mut reference, &next[..1]);
    assert_eq!(Checkpoint::load_dof(&file, dof).unwrap(), after_second);
    let prev = behaviour::CheckpointFile::prev_of(&file);
    assert_eq!(Checkpoint::load_dof(&prev, dof).unwrap(), after_first);
}

fn resumes_from_its_checkpoint(dof: Dof) {
    let dir = tempfile::tempdir().unwrap();
    let (file, initial) = (
        dir.path().join("own.ckpt"),
        dir.path().join("step-one.ckpt"),
    );
    let saved = trained(dof, [-1.0, -0.5], 3);
    save(&file, [saved.clone()]);
    // A step-one file is there too, but the behaviour's own checkpoint wins.
    save(&initial, [trained(dof, [-2.5, 0.0], 1)]);
    let mut rig = Rig::start(
        dof,
        "blr",
        &["--checkpoint", arg(&file), "--initial", arg(&initial)],
    );
    let mut reference = Reference::resumed(&saved);
    let stats = rig.run(
        &mut reference,
        &episode(1, 7, 15, StepStatus::TimeLimit, &[2]),
    );
    assert!(stats[0].actor_updates >= actor_updates(&saved));
    rig.stop();
    let now = Checkpoint::load_dof(&file, dof).unwrap();
    assert_eq!(now, reference.0.checkpoint());
    assert_eq!(
        (now.episodes, now.steps),
        (saved.episodes + 1, saved.steps + 14),
        "the counters go on"
    );
    let prev = behaviour::CheckpointFile::prev_of(&file);
    assert_eq!(Checkpoint::load_dof(&prev, dof).unwrap(), saved);
    assert!(rig.process.log().contains("checkpoint loaded"));
}

fn refuses_a_corrupt_checkpoint_and_uses_the_previous(dof: Dof) {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("own.ckpt");
    let prev = behaviour::CheckpointFile::prev_of(&file);
    let good = trained(dof, [-1.0, -0.5], 2);
    save(&prev, [good.clone()]);
    save(&file, [trained(dof, [-0.7, -0.1], 3)]);
    let mut bytes = std::fs::read(&file).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0x04;
    std::fs::write(&file, &bytes).unwrap();

    let mut rig = Rig::start(dof, "blc", &["--checkpoint", arg(&file)]);
    let log = rig.process.log();
    let refused = log
        .lines()
        .find(|l| l.contains("ERROR") && l.contains("checkpoint refused"))
        .unwrap_or_else(|| panic!("no ERROR for the corrupt file:\n{log}"));
    assert!(
        refused.contains(arg(&file)) && refused.contains("corrupt") && refused.contains("checksum"),
        "{refused}"
    );
    assert!(
        log.lines()
            .any(|l| l.contains("WARN") && l.contains(arg(&prev))),
        "{log}"
    );
    // It acts and learns from the previous checkpoint.
    let mut reference = Reference::resumed(&good);
    rig.run(&mut reference, &episode(1, 0, 8, StepStatus::Lost, &[]));
    rig.stop();
    // The corrupt file is replaced; the good previous one is kept.
    assert_eq!(
        Checkpoint::load_dof(&file, dof).unwrap(),
        reference.0.checkpoint()
    );
    assert_eq!(Checkpoint::load_dof(&prev, dof).unwrap(), good);
}

fn exits_with_both_reasons_when_no_checkpoint_loads(dof: Dof) {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("own.ckpt");
    let prev = behaviour::CheckpointFile::prev_of(&file);
    save(&file, [trained(dof, [-1.0, -0.5], 1)]);
    let bytes = std::fs::read(&file).unwrap();
    std::fs::write(&file, &bytes[..bytes.len() - 10]).unwrap();
    std::fs::write(&prev, b"# not a checkpoint\n").unwrap();
    let ns = Namespace::new("blx");
    let seed = SEED.to_string();
    let mut p = Process::start(
        &ns,
        &binary(dof),
        &["--seed", &seed, "--checkpoint", arg(&file)],
    );
    let status = p.wait(T).expect("it exits on its own");
    assert!(!status.success());
    let log = p.log();
    let error = log
        .lines()
        .find(|l| l.contains("error:") && l.contains("neither checkpoint"))
        .unwrap_or_else(|| panic!("no final error:\n{log}"));
    for needle in [
        arg(&file),
        arg(&prev),
        "truncated",
        "not a cabletrack checkpoint",
    ] {
        assert!(error.contains(needle), "`{needle}` in {error}");
    }
}

fn refuses_a_checkpoint_of_another_algorithm(dof: Dof) {
    let dir = tempfile::tempdir().unwrap();
    let initial = dir.path().join("step-one.ckpt");
    save(&initial, [trained(dof, [-1.0, -0.5], 1)]);
    let ns = Namespace::new("blq");
    let mut p = Process::start(
        &ns,
        &binary(dof),
        &["--algorithm", "gpomdp", "--initial", arg(&initial)],
    );
    assert!(!p.wait(T).expect("it exits on its own").success());
    assert!(
        p.log()
            .contains("holds a nac learner, but --algorithm asks for gpomdp"),
        "{}",
        p.log()
    );
}

fn a_repeated_observation_gets_the_same_command_and_no_second_step(dof: Dof) {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("own.ckpt");
    let mut rig = Rig::start(dof, "bld", &["--checkpoint", arg(&file)]);
    let mut reference = Reference::fresh(dof, Algorithm::Nac);
    let msgs = episode(1, 0, 10, StepStatus::TimeLimit, &[]);
    let (first, _) = reference.step(&msgs[0]);
    assert_eq!(rig.command(&msgs[0]).to_bits(), first.to_bits());
    // The same step again, even with other numbers: the same command, the agent not stepped.
    let mut again = msgs[0];
    again.observation.x_g = -0.4;
    again.observation.theta = -1.0;
    assert_eq!(rig.command(&again).to_bits(), first.to_bits());
    assert_eq!(rig.command(&msgs[0]).to_bits(), first.to_bits());
    // The next steps are the reference's: it has seen each step once.
    rig.run(&mut reference, &msgs[1..]);
    rig.stop();
    let saved = Checkpoint::load_dof(&file, dof).unwrap();
    assert_eq!(saved.steps, 10);
    assert_eq!(saved, reference.0.checkpoint());
}

fn sigint_saves_too(dof: Dof) {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("own.ckpt");
    let mut rig = Rig::start(dof, "bli", &["--checkpoint", arg(&file)]);
    let mut reference = Reference::fresh(dof, Algorithm::Nac);
    rig.run(&mut reference, &episode(1, 0, 5, StepStatus::Running, &[]));
    rig.process.signal(libc::SIGINT);
    let status = rig.process.wait(T).expect("SIGINT stops it");
    assert!(status.success(), "{}", rig.process.log());
    assert_eq!(
        Checkpoint::load_dof(&file, dof).unwrap(),
        reference.0.checkpoint()
    );
}

/// With `--step-two`, the pair's cost an evaluation is judged on counts the partner's commands,
/// read from the partner's command topic: the process keeps the best pair an in-test step-two
/// behaviour keeps when handed the same observations and partner commands, bit for bit, and not
/// the one it would keep without them.
fn step_two_counts_the_partners_commands(dof: Dof) {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join(format!("{dof}.ckpt"));
    let mut rig = Rig::start(
        dof,
        "blp",
        &[
            "--step-two",
            "--checkpoint",
            arg(&file),
            "--save-every",
            "0",
        ],
    );
    let partner = rig.probe.outbox(&topics::command(dof.partner()));
    assert!(
        rig.probe.wait_for_subscribers(&partner, 1, T),
        "{dof}-behaviour does not read its partner's commands"
    );
    let (params, scenario) = (learning(), scenario());
    let reference = || {
        let seed = stream_seed(dof);
        let agent = trainer_agent(dof, Algorithm::Nac, &params);
        let s = behaviour::StepTwo::new(&params, true, seed, seed);
        behaviour::Behaviour::for_step_two(agent, s, &scenario).unwrap()
    };
    let (mut with, mut without) = (reference(), reference());
    let mut seq = 1;
    for trial in 0..params.evaluation.trials {
        for m in episode(seq, trial, 20, StepStatus::TimeLimit, &[4]) {
            let command = rig.command(&m);
            let out = with.step(&m);
            without.step(&m);
            assert_eq!(command.to_bits(), out.command.value.to_bits(), "{m:?}");
            // The partner's command of this step, out before the next observation as in lockstep.
            let p = DofCommand {
                stamp: m.stamp,
                value: 0.6 * (0.3 * m.stamp.seq as f64).cos(),
            };
            partner.send(p).unwrap();
            with.partner_command(&p);
        }
        seq += 21;
    }
    rig.stop();
    let best = |s: &AgentState| s.safety.best.expect("the evaluation was judged");
    let saved = best(&Checkpoint::load_dof(&file, dof).unwrap());
    let (with, without) = (best(&with.checkpoint()), best(&without.checkpoint()));
    assert_eq!(saved.trial, params.evaluation.trials - 1);
    let bits = |c: config::PerDof<f64>| [c.sway.to_bits(), c.yaw.to_bits()];
    assert_eq!(bits(saved.cost), bits(with.cost));
    assert!(
        saved.cost.get(dof.partner()) > without.cost.get(dof.partner()),
        "{saved:?} against {without:?}"
    );
}

macro_rules! for_both_dofs {
    ($($test:ident),* $(,)?) => {
        mod sway {
            $( #[test] fn $test() { super::$test(config::Dof::Sway) } )*
        }
        mod yaw {
            $( #[test] fn $test() { super::$test(config::Dof::Yaw) } )*
        }
    };
}

for_both_dofs!(
    learns_like_an_in_test_agent,
    learns_with_gpomdp_when_asked,
    acts_only_with_the_initial_policy,
    writes_its_checkpoint_on_sigterm,
    sigint_saves_too,
    saves_every_n_episodes_keeping_the_previous,
    resumes_from_its_checkpoint,
    refuses_a_corrupt_checkpoint_and_uses_the_previous,
    exits_with_both_reasons_when_no_checkpoint_loads,
    refuses_a_checkpoint_of_another_algorithm,
    a_repeated_observation_gets_the_same_command_and_no_second_step,
    step_two_counts_the_partners_commands,
);
