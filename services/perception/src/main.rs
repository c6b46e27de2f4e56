//! `perception`: each camera frame in (read in place from shared memory), its cable observation out.
//! One observation per step: a re-sent frame gets the same observation again, an older one nothing.

use clap::Parser;
use messages::topics;
use perception::{Eyes, Observed, Observer};
use runtime::lockstep::{Once, Outcome};
use runtime::{CommonArgs, Flow, Timer};
use std::convert::Infallible;
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    version,
    about = "Finds the cable in each camera frame (or passes the geometric truth on) and publishes the observation."
)]
struct Args {
    #[command(flatten)]
    common: CommonArgs,
    /// `ideal`: pass the frame's geometric truth on; `images`: find the cable in the image.
    #[arg(long, value_enum, default_value = "ideal")]
    eyes: Eyes,
}

fn main() -> ExitCode {
    let args = Args::parse();
    runtime::run("perception", &args.common, |rt| {
        let mut observer = Observer::new(rt.scenario(), args.eyes)?;
        // The frame subscriber first: once the observation publisher is seen, frames are received.
        let frames = rt.frame_inbox()?;
        let out = rt.outbox(&topics::CABLE_OBSERVATION)?;
        tracing::info!(eyes = ?args.eyes, "ready");
        let mut once = Once::<Observed>::new();
        let mut on_input = || -> anyhow::Result<Flow> {
            // Every frame in order: the tracker must see each step once, and a repeat is cheap.
            while let Some(outcome) = frames.receive_with(|header, image| {
                let Ok(outcome) = once.step(header.stamp.seq, || {
                    Ok::<_, Infallible>(observer.observe(header, image))
                });
                (header.stamp, outcome)
            })? {
                match outcome {
                    (_, Outcome::Fresh(observed)) => {
                        if let Some(why) = &observed.bad_frame {
                            tracing::warn!(
                                seq = observed.msg.stamp.seq,
                                "bad frame, reported as not found: {why}"
                            );
                        }
                        out.send(observed.msg)?;
                    }
                    (_, Outcome::Repeat(observed)) => {
                        out.send(observed.msg)?;
                    }
                    (stamp, Outcome::Stale) => {
                        tracing::debug!(seq = stamp.seq, "an older frame: dropped");
                    }
                }
            }
            Ok(Flow::Continue)
        };
        rt.serve(&[frames.listener()], Timer::None, |_| on_input())?;
        Ok(())
    })
}
