//! `simulator`: drives the simulated mesh. Publishes each step's vehicle state, waits for the thruster
//! setpoints answering it, integrates one control period and publishes the next (the protocol is
//! `simulator::lockstep`).

use clap::Parser;
use messages::{Endpoint, topics};
use runtime::lockstep::{Cause, Closed, Limits, Lockstep, Shell};
use runtime::{CommonArgs, Flow, Timer};
use simulator::Simulator;
use simulator::lockstep::{EpisodeEnd, Published, SimPlant};
use std::process::ExitCode;
use std::time::{Duration, Instant};

#[derive(Parser)]
#[command(
    version,
    about = "The simulated world: publishes each step's vehicle state and integrates the thruster setpoints answering it."
)]
struct Args {
    #[command(flatten)]
    common: CommonArgs,
    /// Re-publish the current state after this long without its setpoints (heals start-up races).
    #[arg(long, default_value_t = 100)]
    resend_ms: u64,
    /// Once the mesh runs, a step whose setpoints do not arrive within this time is integrated with
    /// zero thrust.
    #[arg(long, default_value_t = 2000)]
    deadline_ms: u64,
    /// Stop after this many episodes (0: run forever).
    #[arg(long, default_value_t = 0)]
    episodes: u32,
}

fn main() -> ExitCode {
    let args = Args::parse();
    runtime::run("simulator", &args.common, |rt| {
        if rt.endpoint() != Endpoint::Sim {
            anyhow::bail!(
                "the simulator serves the `sim` endpoint only; the `vehicle` endpoint is served by \
                 the vehicle twin behind the hardware adapters"
            );
        }
        let setpoints = rt.inbox(&topics::THRUSTER_SETPOINTS)?;
        let states = rt.outbox(&topics::VEHICLE_STATE)?;
        let limits = Limits::new(
            Duration::from_millis(args.resend_ms),
            Duration::from_millis(args.deadline_ms),
        );
        let sim = SimPlant::new(Simulator::new(rt.scenario(), rt.stream_seed("simulator")));
        let (mut lockstep, first) = Lockstep::start(sim, limits, args.episodes, Instant::now());
        tracing::info!(
            episodes = args.episodes,
            resend_ms = args.resend_ms,
            deadline_ms = args.deadline_ms,
            "publishing the first state; waiting for the mesh"
        );
        let mut shell = States {
            out: states,
            pace: Pace::default(),
        };
        if lockstep.carry_out(&mut shell, first)? == Flow::Stop {
            return Ok(());
        }
        rt.serve(
            &[setpoints.listener()],
            Timer::Timeout(limits.tick()),
            |_| {
                while let Some(sp) = setpoints.receive()? {
                    let flow =
                        lockstep.answer(&mut shell, sp.stamp.seq, sp.as_slice(), Instant::now())?;
                    if flow == Flow::Stop {
                        return Ok(Flow::Stop);
                    }
                }
                lockstep.tick(&mut shell, Instant::now())
            },
        )?;
        Ok(())
    })
}

/// The simulator's side of the lockstep: each step's state on its topic, and the run's log.
struct States {
    out: messages::Outbox<messages::VehicleStateMsg>,
    pace: Pace,
}

impl Shell<SimPlant> for States {
    fn publish(&mut self, _: &mut SimPlant, step: &Published, _again: bool) -> anyhow::Result<()> {
        self.out.send(step.message())?;
        Ok(())
    }

    fn closed(&mut self, lockstep: &Lockstep<SimPlant>, closed: Closed<SimPlant>) {
        if let Some(step) = closed.step {
            report(
                lockstep,
                &mut self.pace,
                &step,
                closed.cause,
                closed.waited,
                &closed.ended,
            );
        }
    }

    fn waiting(&mut self, step: &Published, waited: Duration) {
        tracing::info!(
            seq = step.seq,
            waited_s = waited.as_secs(),
            subscribers = self.out.subscribers(),
            "waiting for the mesh: no setpoints yet"
        );
    }
}

/// The mesh's pace since its first answer.
#[derive(Default)]
struct Pace {
    since: Option<(Instant, u64)>,
}

/// Logs a closed step: a missed deadline (WARN), an episode's end with the run's progress (INFO).
fn report(
    lockstep: &Lockstep<SimPlant>,
    pace: &mut Pace,
    closed: &Published,
    cause: Cause,
    waited: Duration,
    ended: &[EpisodeEnd],
) {
    let (since, first) = *pace.since.get_or_insert((Instant::now(), closed.seq));
    if cause == Cause::Deadline {
        tracing::warn!(
            seq = closed.seq,
            episode = closed.step.episode,
            step = closed.step.step,
            waited_ms = waited.as_millis() as u64,
            "no setpoints within the deadline: stepping with zero thrust"
        );
    }
    let of = match lockstep.episodes() {
        0 => "forever".to_owned(),
        n => n.to_string(),
    };
    for end in ended {
        // Every published step so far, re-sends not counted; the pace since the mesh answered.
        let steps = closed.seq;
        let steps_per_s = (steps - first) as f64 / since.elapsed().as_secs_f64().max(1e-9);
        tracing::info!(
            episode = end.episode,
            steps = end.steps,
            end = end.status.describe(),
            done = lockstep.episodes_done(),
            of = %of,
            total_steps = steps,
            steps_per_s = steps_per_s.round() as u64,
            "episode ended"
        );
    }
}
