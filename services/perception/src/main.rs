//! `perception`: each camera frame in (read in place from shared memory), its cable observation out.
//! One observation per step: a re-sent frame gets the same observation again, an older one nothing.

use clap::Parser;
use config::Eyes;
use messages::topics;
use perception::Observer;
use runtime::{BadValues, CommonArgs, Flow, Tally};
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
        let clock = *rt.clock();
        let mut bad_frames = Tally::default();
        let mut bad_values = BadValues::new(frames.service());
        rt.serve_steps(
            &frames,
            &mut observer,
            |observer, (header, image)| match observer.observe(header, image) {
                Ok(observed) => {
                    bad_values.note(observed.fixes, header.stamp.seq, clock.now_ns());
                    Ok(Some(observed))
                }
                Err(why) => {
                    // Refused: the step stays unanswered, the loop goes on with the next frame.
                    if let Some(earlier) = bad_frames.count(clock.now_ns()) {
                        tracing::warn!(
                            seq = header.stamp.seq,
                            earlier_unlogged = earlier,
                            total = bad_frames.total(),
                            "bad frame refused: {why}"
                        );
                    }
                    Ok(None)
                }
            },
            |_, answer| {
                out.send(answer.output().msg)?;
                Ok(Flow::Continue)
            },
        )?;
        Ok(())
    })
}
