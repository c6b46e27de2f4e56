//! `camera`: each vehicle state in, its camera frame out (the image rendered straight into shared
//! memory, the geometric truth in the header). One frame per step: a re-sent state gets the same
//! frame again, an older one nothing.

use camera::{Eyes, SimCamera};
use clap::Parser;
use messages::{CameraFrameHeader, Endpoint, topics};
use runtime::lockstep::{Once, Outcome};
use runtime::{CommonArgs, Flow, Timer};
use std::convert::Infallible;
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    version,
    about = "The simulated downward camera: a frame (geometric truth, rendered image) for each vehicle state."
)]
struct Args {
    #[command(flatten)]
    common: CommonArgs,
    /// `ideal`: frames carry the geometric truth only; `images`: a rendered image too.
    #[arg(long, value_enum, default_value = "ideal")]
    eyes: Eyes,
}

fn main() -> ExitCode {
    let args = Args::parse();
    runtime::run("camera", &args.common, |rt| {
        if rt.endpoint() != Endpoint::Sim {
            anyhow::bail!(
                "the camera serves the `sim` endpoint only for now: on the `vehicle` endpoint it \
                 reads a frame source, which is not built yet"
            );
        }
        let mut camera = SimCamera::new(rt.scenario(), args.eyes, rt.stream_seed("render"))?;
        // The frame publisher first: once the state subscriber is seen, frames can flow.
        let frames = rt.frame_outbox()?;
        let states = rt.inbox(&topics::VEHICLE_STATE)?;
        tracing::info!(eyes = ?args.eyes, "ready");
        let mut once = Once::<CameraFrameHeader>::new();
        let mut on_input = || -> anyhow::Result<Flow> {
            // Only the newest state matters: the simulator waits on it, older ones were answered
            // (or overtaken by a deadline).
            let Some(state) = states.drain()?.into_iter().max_by_key(|s| s.stamp.seq) else {
                return Ok(Flow::Continue);
            };
            let header = match once.step(state.stamp.seq, || {
                Ok::<_, Infallible>(camera.header(&state))
            }) {
                Ok(Outcome::Fresh(h) | Outcome::Repeat(h)) => h,
                Ok(Outcome::Stale) => {
                    tracing::debug!(seq = state.stamp.seq, "an older state: dropped");
                    return Ok(Flow::Continue);
                }
            };
            // A repeat is rendered again: the same seed and frame index give the same bytes.
            frames.send_with(header, camera.image_len(), |image| {
                camera.render(&state, image)
            })??;
            Ok(Flow::Continue)
        };
        rt.serve(&[states.listener()], Timer::None, |_| on_input())?;
        Ok(())
    })
}
