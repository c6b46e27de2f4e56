//! The behaviour as a process: cable observations in, the DOF's command and, per episode, its
//! learning statistics out.
//!
//! Start-up picks the agent: the behaviour's own `--checkpoint` when it exists (or its `.prev`, see
//! [`crate::store`]), else the step-one `--initial` checkpoint's entry for this DOF, else a fresh
//! agent. Then it serves its observations in lockstep (`Runtime::serve_steps`: each new `seq` once; a
//! repeated `seq` gets the command already computed, the agent is not stepped twice). While learning, the
//! checkpoint is saved every `--save-every` episodes and when SIGINT or SIGTERM stops the process.
//! With `--step-two` (the vehicle mesh) it runs step two's protocol ([`crate::step_two`]).

use crate::core::{Behaviour, new_agent, resume_seed};
use crate::step_two::StepTwo;
use crate::store::{CheckpointFile, chain};
use anyhow::{Context, bail};
use clap::{CommandFactory, FromArgMatches, Parser};
use config::Dof;
use learning::{Agent, AgentState, Algorithm, Checkpoint, LearnerState};
use messages::CableObservationMsg;
use messages::topics;
use runtime::{Answer, BadValues, CommonArgs, Flow, Runtime, Stopped};
use std::path::PathBuf;
use std::process::ExitCode;

/// The command line of `sway-behaviour` and `yaw-behaviour`.
#[derive(Parser, Clone, Debug)]
#[command(version)]
pub struct Args {
    #[command(flatten)]
    pub common: CommonArgs,
    /// The learner of a fresh agent [default: nac]. A loaded checkpoint keeps its own learner; given
    /// explicitly, this must name it.
    #[arg(long, value_name = "nac|gpomdp")]
    pub algorithm: Option<Algorithm>,
    /// Act with the policy but learn nothing; no checkpoint is written.
    #[arg(long)]
    pub act_only: bool,
    /// This behaviour's own checkpoint: resumed from when it exists (FILE.prev if FILE is refused),
    /// saved every --save-every episodes and at shutdown (the previous file kept as FILE.prev).
    #[arg(long, value_name = "FILE")]
    pub checkpoint: Option<PathBuf>,
    /// A step-one checkpoint (e.g. the trainer's, with both DOFs) to start from while --checkpoint
    /// does not exist yet; this DOF's entry is used.
    #[arg(long, value_name = "FILE")]
    pub initial: Option<PathBuf>,
    /// Save --checkpoint every N episodes (0: only at shutdown); with --step-two also after every
    /// judged evaluation.
    #[arg(long, value_name = "N", default_value_t = 10)]
    pub save_every: u64,
    /// Run step two's protocol with the checkpoint's learning parameters (learning.toml's
    /// [evaluation] and [safety]): evaluation trials between the learning ones, every actor update
    /// bounded and kept in the stable set, the best policy restored when a new one evaluates worse.
    /// Acting only, every trial is an evaluation trial.
    #[arg(long)]
    pub step_two: bool,
}

/// The process name of a DOF's behaviour.
pub fn name(dof: Dof) -> &'static str {
    match dof {
        Dof::Sway => "sway-behaviour",
        Dof::Yaw => "yaw-behaviour",
    }
}

/// The whole of `sway-behaviour`'s and `yaw-behaviour`'s `main`.
pub fn main(dof: Dof) -> ExitCode {
    let name = name(dof);
    let command = Args::command().name(name).about(match dof {
        Dof::Sway => "The sway behaviour: learns to keep the cable centred (x_g) with the Natural Actor-Critic (or OLPOMDP, --algorithm gpomdp).",
        Dof::Yaw => "The yaw behaviour: learns to keep the cable aligned (Theta) with the Natural Actor-Critic (or OLPOMDP, --algorithm gpomdp).",
    });
    let args = Args::from_arg_matches(&command.get_matches()).unwrap_or_else(|e| e.exit());
    runtime::run(name, &args.common, |rt| serve(rt, dof, &args))
}

fn actor_updates(state: &AgentState) -> u64 {
    match &state.learner {
        LearnerState::Nac(s) => s.actor_updates,
        LearnerState::Gpomdp(s) => s.actor_updates,
    }
}

/// The agent to start with (see the module docs), and the seed of its exploration noise.
fn start_agent(
    rt: &Runtime,
    dof: Dof,
    args: &Args,
    store: Option<&mut CheckpointFile>,
) -> anyhow::Result<(Agent, u64)> {
    let stream_seed = rt.stream_seed(dof.name());
    let own = match store {
        Some(store) => store.load(dof)?.map(|l| (l.state, l.from)),
        None => None,
    };
    let loaded = match (own, &args.initial) {
        (Some(own), initial) => {
            if let Some(initial) = initial {
                tracing::info!(initial = %initial.display(), "--initial not used: resuming from the behaviour's own checkpoint");
            }
            Some(own)
        }
        (None, Some(initial)) => {
            let state = Checkpoint::load_dof(initial, dof)
                .map_err(|e| anyhow::anyhow!("{}", chain(&e)))
                .context("cannot start from the step-one checkpoint (--initial)")?;
            Some((state, initial.clone()))
        }
        (None, None) => None,
    };
    let Some((state, from)) = loaded else {
        let algorithm = args.algorithm.unwrap_or(Algorithm::Nac);
        let agent = new_agent(dof, algorithm, rt.scenario(), rt.learning(), stream_seed);
        tracing::info!(
            %algorithm,
            gain = ?agent.gain(),
            seed = stream_seed,
            "no checkpoint: starting fresh"
        );
        return Ok((agent, stream_seed));
    };
    if let Some(asked) = args.algorithm
        && asked != state.algorithm()
    {
        bail!(
            "checkpoint {} holds a {} learner, but --algorithm asks for {asked}",
            from.display(),
            state.algorithm()
        );
    }
    let differs = [
        (state.params != *rt.learning(), "learning parameters"),
        (state.cost != *rt.scenario().reward.of(dof), "reward"),
        (
            state.state_max != rt.scenario().state_max(dof),
            "observation box",
        ),
    ];
    for (_, what) in differs.iter().filter(|(d, _)| *d) {
        tracing::warn!(path = %from.display(), "the checkpoint's {what} differ from the configuration's: the checkpoint's are used");
    }
    let (gain, episodes, steps, updates) = (
        state.policy.gain,
        state.episodes,
        state.steps,
        actor_updates(&state),
    );
    let seed = resume_seed(stream_seed, &state);
    let algorithm = state.algorithm();
    let agent = Agent::from_state(state, seed)
        .with_context(|| format!("cannot resume from {}", from.display()))?;
    tracing::info!(
        path = %from.display(),
        %algorithm,
        ?gain,
        episodes,
        steps,
        actor_updates = updates,
        seed,
        "checkpoint loaded"
    );
    Ok((agent, seed))
}

fn save(store: &mut CheckpointFile, behaviour: &Behaviour) -> anyhow::Result<()> {
    let state = behaviour.checkpoint();
    store
        .save(&state)
        .map_err(|e| anyhow::anyhow!("{}", chain(&e)))?;
    tracing::info!(
        path = %store.path().display(),
        gain = ?state.policy.gain,
        episodes = state.episodes,
        steps = state.steps,
        actor_updates = actor_updates(&state),
        "checkpoint saved"
    );
    Ok(())
}

/// Runs the behaviour of `dof` until a termination signal.
pub fn serve(rt: &Runtime, dof: Dof, args: &Args) -> anyhow::Result<()> {
    let mut store = args.checkpoint.clone().map(CheckpointFile::new);
    let (mut agent, seed) = start_agent(rt, dof, args, store.as_mut())?;
    let learning = !args.act_only;
    agent.set_learning(learning);
    // Only a learner writes its checkpoint.
    let mut saver = store.filter(|_| learning);
    if let Some(dir) = saver
        .as_ref()
        .and_then(|s| s.path().parent())
        .filter(|d| !d.as_os_str().is_empty())
    {
        // Fail now rather than at the first save, hours of learning later.
        std::fs::create_dir_all(dir).with_context(|| {
            format!("cannot create the checkpoint's directory {}", dir.display())
        })?;
    }
    match (&args.checkpoint, learning) {
        (Some(path), false) => {
            tracing::info!(path = %path.display(), "acting only: the checkpoint is not written")
        }
        (None, true) => {
            tracing::warn!("learning without --checkpoint: what is learned is lost at exit")
        }
        _ => {}
    }
    let mut behaviour = if args.step_two {
        let step_two = StepTwo::new(agent.params(), learning, rt.stream_seed(dof.name()), seed);
        let b = Behaviour::for_step_two(agent, step_two, rt.scenario())
            .context("cannot build the stability guard from the identified model")?;
        let (a, p) = (b.agent(), b.agent().params());
        let bound = a.safety().action_change_bound;
        tracing::info!(
            evaluation_trials = p.evaluation.trials,
            learning_trials = p.evaluation.learning_trials,
            trust_region = p.safety.trust_region.enabled,
            action_change_bound = ?a.guard().trust_region.map(|t| t.in_force(bound)),
            min_action_change = p.safety.trust_region.min_action_change,
            max_action_change = p.safety.trust_region.max_action_change,
            stability_guard = p.safety.stability.enabled,
            rollback = p.safety.rollback.enabled,
            best = ?a.safety().best,
            "step two: evaluations, the safety guard and keeping the best"
        );
        b
    } else {
        Behaviour::new(agent)
    };

    let observations = rt.inbox(&topics::CABLE_OBSERVATION)?;
    // Step two's pair cost counts the partner's commands too.
    let partner = args
        .step_two
        .then(|| rt.inbox(&topics::command(dof.partner())))
        .transpose()?;
    let commands = rt.outbox(&topics::command(dof))?;
    let stats = rt.outbox(&topics::learning(dof))?;
    let limits = rt.scenario().observation.clone();
    let mut bad = BadValues::new(observations.service());
    let clock = *rt.clock();
    let mut outage = durable::Outage::default();
    let served = rt.serve_steps(
        &observations,
        &mut behaviour,
        |behaviour, msg| {
            // The partner's commands up to the last step are out before this step's observation.
            if let Some(partner) = &partner {
                while let Some(command) = partner.receive()? {
                    behaviour.partner_command(&command);
                }
            }
            // A learner never sees a value outside the observation box, nor a NaN.
            let (observation, fixes) = msg.observation.bounded(&limits);
            bad.note(fixes, msg.stamp.seq, clock.now_ns());
            Ok(Some(behaviour.step(&CableObservationMsg {
                stamp: msg.stamp,
                observation,
            })))
        },
        |behaviour, answer| {
            let out = answer.output();
            commands.send(out.command)?;
            // A trial cut short (its terminal step never came) is reported all the same.
            if let (Answer::New(_), Some(cut)) = (answer, out.cut) {
                stats.send(cut)?;
            }
            // A repeated step gets the command only: the episode's statistics went out once.
            let (Answer::New(_), Some(s)) = (answer, out.stats) else {
                return Ok(Flow::Continue);
            };
            stats.send(s)?;
            let episodes = behaviour.agent().episodes();
            tracing::debug!(
                episode = episodes,
                seq = s.stamp.seq,
                return_ = s.episode_return,
                steps = s.steps,
                gain = ?s.gain,
                actor_updates = s.actor_updates,
                evaluation = s.evaluation,
                bounded = s.bounded,
                refused = s.refused,
                rollbacks = s.rollbacks,
                "episode ended"
            );
            // Step two: every judged evaluation is saved at once, so that a restart resumes with
            // the best pair its partner keeps (the partner judged the same evaluation).
            let periodic = args.save_every > 0 && episodes.is_multiple_of(args.save_every);
            if let Some(store) = saver.as_mut()
                && (periodic || s.evaluated.is_finite())
            {
                match save(store, behaviour) {
                    Ok(()) => {
                        if let Some(failed) = outage.succeeded() {
                            tracing::info!(failed, "checkpoints are saved again");
                        }
                    }
                    // Keep controlling the vehicle; the next save tries again. Said once, not at
                    // every episode of a full disk.
                    Err(e) => {
                        if outage.failed() {
                            tracing::error!(
                                "periodic checkpoint failed: {e:#}; the behaviour goes on, each save tries again (the previous checkpoint {} is kept)",
                                store.prev().display()
                            );
                        }
                    }
                }
            }
            Ok(Flow::Continue)
        },
    );
    match &served {
        Ok(Stopped::Signal) => tracing::info!("termination signal"),
        // An error is reported once, by `runtime::run`, after the save.
        Ok(Stopped::Done) | Err(_) => {}
    }
    // Whatever stopped the loop, keep what was learned.
    let saved = match saver.as_mut() {
        Some(store) => save(store, &behaviour).context("the final checkpoint"),
        None => Ok(()),
    };
    served?;
    saved
}
