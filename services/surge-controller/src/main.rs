//! `surge-controller`: cable observations in, the surge command out: the cruise thrust while the
//! cable is centred, 0 otherwise (the rule is the library's [`SurgeController`]).

use clap::Parser;
use messages::{DofCommand, topics};
use runtime::lockstep::{Once, Outcome};
use runtime::{CommonArgs, Flow, Timer};
use std::process::ExitCode;
use surge_controller::SurgeController;

#[derive(Parser)]
#[command(
    version,
    about = "Commands the cruise surge thrust while the cable is centred in the image, 0 otherwise."
)]
struct Args {
    #[command(flatten)]
    common: CommonArgs,
}

fn main() -> ExitCode {
    let args = Args::parse();
    runtime::run("surge-controller", &args.common, |rt| {
        let scenario = rt.scenario();
        let controller = SurgeController::new(&scenario.surge, &scenario.model.surge);
        let observations = rt.inbox(&topics::CABLE_OBSERVATION)?;
        let commands = rt.outbox(&topics::SURGE_COMMAND)?;
        let mut once = Once::<DofCommand>::new();
        let mut on_input = || -> anyhow::Result<Flow> {
            for msg in observations.drain()? {
                let outcome = once.step(msg.stamp.seq, || {
                    Ok::<_, anyhow::Error>(DofCommand {
                        stamp: msg.stamp,
                        value: controller.command(&msg.observation()),
                    })
                })?;
                match outcome {
                    // A repeated step gets the command computed for it the first time.
                    Outcome::Fresh(cmd) | Outcome::Repeat(cmd) => {
                        commands.send(cmd)?;
                    }
                    Outcome::Stale => {
                        tracing::debug!(seq = msg.stamp.seq, "stale observation ignored")
                    }
                }
            }
            Ok(Flow::Continue)
        };
        rt.serve(&[observations.listener()], Timer::None, |_| on_input())?;
        Ok(())
    })
}
