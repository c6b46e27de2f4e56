//! `perception`: each camera frame in (read in place from shared memory), its cable observation out.
//! One observation per step: a re-sent frame gets the same observation again, an older one nothing.

use clap::Parser;
use config::Eyes;
use messages::topics;
use perception::{Observed, Observer};
use runtime::{Answer, CommonArgs, Flow};
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
    #[arg(long, default_value = "ideal", value_name = "ideal|images")]
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
        rt.serve_steps(
            &frames,
            &mut observer,
            |observer, (header, image)| Ok(observer.observe(header, image)),
            |_, answer| {
                let observed = answer.output();
                if let Answer::New(Observed {
                    bad_frame: Some(why),
                    msg,
                }) = answer
                {
                    tracing::warn!(
                        seq = msg.stamp.seq,
                        "bad frame, reported as not found: {why}"
                    );
                }
                out.send(observed.msg)?;
                Ok(Flow::Continue)
            },
        )?;
        Ok(())
    })
}
