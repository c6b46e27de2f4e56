//! `surge-controller`: cable observations in, the surge command out: the cruise thrust while the
//! cable is centred, 0 otherwise (the rule is the library's [`SurgeController`]).

use clap::Parser;
use messages::{DofCommand, topics};
use runtime::{BadValues, CommonArgs, Flow};
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
        let controller = SurgeController::new(&scenario.surge, &scenario.commanded_model().surge);
        let observations = rt.inbox(&topics::CABLE_OBSERVATION)?;
        let commands = rt.outbox(&topics::SURGE_COMMAND)?;
        let limits = scenario.observation.clone();
        let mut bad = BadValues::new(observations.service());
        let clock = *rt.clock();
        rt.serve_steps(
            &observations,
            &mut (),
            |_, msg| {
                let (observation, fixes) = msg.observation.bounded(&limits);
                bad.note(fixes, msg.stamp.seq, clock.now_ns());
                Ok(Some(DofCommand {
                    stamp: msg.stamp,
                    value: controller.command(&(&observation).into()),
                }))
            },
            // A repeated step gets the command computed for it the first time.
            |_, answer| {
                commands.send(*answer.output())?;
                Ok(Flow::Continue)
            },
        )?;
        Ok(())
    })
}
