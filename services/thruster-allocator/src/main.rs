//! `thruster-allocator`: the three DOF commands of a step in, thruster setpoints out on the setpoint
//! topic. One allocator at a time: the topic refuses a second live publisher, so a second allocator
//! exits with an error naming the first. On the vehicle the thruster driver takes the setpoints to
//! the thrusters.

use clap::Parser;
use messages::topics;
use runtime::{BadValues, CommonArgs, Flow, Timer};
use std::process::ExitCode;
use std::time::{Duration, Instant};
use thruster_allocator::Allocator;
use thruster_allocator::step::{self, Event, Input, StepAllocator};

#[derive(Parser)]
#[command(
    version,
    about = "Maps the surge, sway and yaw commands of each step to thruster setpoints."
)]
struct Args {
    #[command(flatten)]
    common: CommonArgs,
    /// A step's three commands must arrive within this time of its first; a missing one counts as 0.
    #[arg(long, default_value_t = 1000)]
    deadline_ms: u64,
}

fn main() -> ExitCode {
    let args = Args::parse();
    runtime::run("thruster-allocator", &args.common, |rt| {
        // The setpoint topic first: a second allocator stops here, before it touches anything.
        let out = rt.outbox(&topics::THRUSTER_SETPOINTS)?;
        let allocator = Allocator::new(&rt.scenario().thrusters);
        let screen = rt.screen("the behaviours' commands");
        let mut steps =
            StepAllocator::new(allocator, Duration::from_millis(args.deadline_ms), screen);
        let inputs = [
            (Input::Surge, rt.inbox(&topics::SURGE_COMMAND)?),
            (Input::Sway, rt.inbox(&topics::SWAY_COMMAND)?),
            (Input::Yaw, rt.inbox(&topics::YAW_COMMAND)?),
        ];
        let mut bad = BadValues::new("the behaviours' commands");
        let clock = *rt.clock();
        let mut act = |event: Event| -> anyhow::Result<()> {
            let (msg, fixes) = match event {
                Event::Idle | Event::Refused(_) => return Ok(()),
                Event::Send { setpoints, fixes } => (setpoints, fixes),
                Event::Overtaken(p) => {
                    tracing::warn!(seq = p.seq, missing = ?step::missing(&p), "step incomplete: a newer step arrived");
                    return Ok(());
                }
                Event::Overdue {
                    partial,
                    setpoints,
                    fixes,
                } => {
                    tracing::warn!(seq = partial.seq, missing = ?step::missing(&partial), "step incomplete: deadline passed, missing commands count as 0");
                    (setpoints, fixes)
                }
            };
            bad.note(fixes, msg.stamp.seq, clock.now_ns());
            out.send(msg)?;
            Ok(())
        };
        tracing::info!(setpoints = %out.service(), "ready");
        let listeners = inputs.each_ref().map(|(_, i)| i.listener());
        rt.serve(&listeners, Timer::Timeout(steps.deadline() / 4), |_| {
            for (input, inbox) in &inputs {
                for cmd in inbox.drain()? {
                    act(steps.on_command(*input, cmd, Instant::now(), clock.now_ns()))?;
                }
            }
            act(steps.on_time(Instant::now(), clock.now_ns()))?;
            Ok(Flow::Continue)
        })?;
        Ok(())
    })
}
