//! `camera`: on the sim endpoint, each vehicle state in, its camera frame out (the image rendered
//! straight into shared memory, the geometric truth in the header); one frame per step: a re-sent
//! state gets the same frame again, an older one nothing. On the vehicle endpoint, each frame of the
//! vehicle's frame source out, stamped for the mesh (`camera::vehicle`).

use adapters::replay::{Pacing, ReplaySource};
use adapters::twin::TwinFrameSource;
use adapters::{AdapterError, Frame, FrameSource, Wake};
use camera::SimCamera;
use camera::vehicle::{
    Publish, SeqMap, SourceSpec, UnitInfo, UnitVerdict, VehicleCamera, VideoUnits,
};
use clap::Parser;
use config::Eyes;
use messages::{Endpoint, topics};
use runtime::{CommonArgs, Flow, Input, Runtime, Tally, Timer};
use std::convert::Infallible;
use std::process::ExitCode;
use std::time::{Duration, Instant};

#[derive(Parser)]
#[command(
    version,
    about = "The downward camera: a frame for each simulated vehicle state (sim endpoint), or the vehicle's frame source's frames (vehicle endpoint)."
)]
struct Args {
    #[command(flatten)]
    common: CommonArgs,
    /// Sim endpoint: `ideal`: frames carry the geometric truth only; `images`: a rendered image too.
    #[arg(long, default_value = "ideal", value_name = "ideal|images")]
    eyes: Eyes,
    /// Vehicle endpoint: the frame source, `twin` (the vehicle twin's camera), `replay:DIR` (a
    /// recorded dive) or `rtp:ADDR:PORT` (an RTP/H.264 stream, e.g. `rtp:0.0.0.0:5600` for a
    /// BlueROV2's camera; built with `--features video`) [default: twin].
    #[arg(long, value_name = "twin|replay:DIR|rtp:ADDR:PORT")]
    source: Option<SourceSpec>,
    /// Vehicle endpoint, replay: play the dive K times faster than recorded.
    #[arg(long, value_name = "K")]
    speed: Option<f64>,
}

fn main() -> ExitCode {
    let args = Args::parse();
    runtime::run("camera", &args.common, |rt| match rt.endpoint() {
        Endpoint::Sim => {
            if args.source.is_some() || args.speed.is_some() {
                anyhow::bail!(
                    "--source and --speed are for the `vehicle` endpoint; on `sim` the camera \
                     renders the simulator's states"
                );
            }
            serve_sim(rt, &args)
        }
        Endpoint::Vehicle => serve_vehicle(rt, &args),
    })
}

fn serve_sim(rt: &Runtime, args: &Args) -> anyhow::Result<()> {
    let mut camera = SimCamera::new(rt.scenario(), args.eyes, rt.stream_seed("render"))?;
    // The frame publisher first: once the state subscriber is seen, frames can flow.
    let frames = rt.frame_outbox()?;
    let states = rt.inbox(&topics::VEHICLE_STATE)?;
    tracing::info!(eyes = ?args.eyes, "ready");
    rt.serve_steps(
        &states,
        &mut camera,
        |_, state| Ok(Some(*state)),
        |camera, answer| {
            // A repeat is rendered again: the same seed and frame index give the same bytes.
            let state = answer.output();
            frames.send_with(camera.header(state), camera.image_len(), |image| {
                camera.render(state, image)
            })??;
            Ok(Flow::Continue)
        },
    )?;
    Ok(())
}

/// With a live source, say so when no frame came for this long.
const QUIET_NOTE: Duration = Duration::from_secs(5);

fn serve_vehicle(rt: &Runtime, args: &Args) -> anyhow::Result<()> {
    let c = &rt.scenario().camera;
    let spec = args.source.clone().unwrap_or(SourceSpec::Twin);
    let (source, units, at_exit): Opened = match &spec {
        SourceSpec::Twin => {
            if args.speed.is_some() {
                anyhow::bail!("--speed paces a replay; the twin's pace is the twin's own");
            }
            let twin = TwinFrameSource::open(rt.node(), c.width, c.height)?;
            (Box::new(twin), None, None)
        }
        SourceSpec::Replay(dir) => {
            let speed = args.speed.unwrap_or(1.0);
            (
                Box::new(ReplaySource::open(dir, Pacing::Speed(speed))?),
                None,
                None,
            )
        }
        SourceSpec::Rtp(addr) => {
            if args.speed.is_some() {
                anyhow::bail!("--speed paces a replay; a live stream's pace is the camera's own");
            }
            rtp_source(*addr, c.width, c.height)?
        }
    };
    let clock = *rt.clock();
    let mut camera = VehicleCamera::new((c.width, c.height), SeqMap::new(0), clock.new_epoch());
    camera.check(source.as_ref()).map_err(anyhow::Error::msg)?;
    // A compressed source's stream as it arrived, for the flight record.
    let mut video = match units {
        Some(units) => Some(Video {
            units,
            outbox: rt.video_outbox()?,
            gate: VideoUnits::new(camera.epoch(), messages::topics::MAX_ACCESS_UNIT),
        }),
        None => None,
    };
    let frames = rt.frame_outbox()?;
    let (inputs, timer) = match source.wake() {
        Wake::Listener(l) => (vec![Input::Listener(l)], Timer::Timeout(QUIET_NOTE)),
        Wake::Readable(fd) => (vec![Input::Readable(fd)], Timer::Timeout(QUIET_NOTE)),
        Wake::Every(period) => (Vec::new(), Timer::Interval(period)),
    };
    tracing::info!(source = %source.describe(), epoch = camera.epoch(), "ready");
    let mut frame = Frame::default();
    let mut last_frame = Instant::now();
    let mut refusals = Tally::default();
    rt.serve_inputs(&inputs, timer, |_| {
        // The units decoded so far first: a frame is published after the unit it decodes from.
        if let Some(v) = &mut video {
            v.publish(clock.now_ns())?;
        }
        // Every frame due now, in order: the mesh answers each step once.
        loop {
            let now = Instant::now();
            let read = match source.read(now, &mut frame) {
                Ok(r) => r,
                Err(e @ AdapterError::BadPacket { .. }) => {
                    // Refused packets come in bursts (garbage on the port, another stream): said
                    // once, then at most every few seconds with the count since, never per packet.
                    if let Some(earlier) = refusals.count(clock.now_ns()) {
                        tracing::warn!(source = %source.describe(), reports_not_logged = earlier, "{e}");
                    }
                    continue;
                }
                Err(e) => {
                    // A broken frame is skipped; the vehicle's loop goes on with the next.
                    tracing::warn!(source = %source.describe(), "frame skipped: {e}");
                    continue;
                }
            };
            // A repeat refills the frame with the repeated image.
            let header = match camera.on_read(read, &frame.meta, clock.now_ns()) {
                Publish::New(h) | Publish::Again(h) => h,
                Publish::Wait => {
                    if !inputs.is_empty() && last_frame.elapsed() >= QUIET_NOTE {
                        tracing::info!(source = %source.describe(), published = camera.published(), "no frame from the source for 5 s");
                        last_frame = Instant::now();
                    }
                    return Ok(Flow::Continue);
                }
                Publish::End => {
                    tracing::info!(source = %source.describe(), published = camera.published(), "the source ended");
                    return Ok(Flow::Stop);
                }
            };
            last_frame = Instant::now();
            frames.send_with(header, frame.image.len(), |out| {
                out.copy_from_slice(&frame.image);
                Ok::<_, Infallible>(())
            })??;
        }
    })?;
    if let Some(say) = at_exit {
        say(camera.published());
    }
    Ok(())
}

/// What a source says of itself when the camera stops, given the frames published.
type AtExit = Box<dyn Fn(u64)>;

/// A frame source opened: itself, its access units for the record, what it says at exit.
type Opened = (Box<dyn FrameSource>, Option<Units>, Option<AtExit>);

/// The access units a compressed source gave its decoder.
type Units = std::sync::mpsc::Receiver<DecodedUnit>;

/// The camera's video for the record: the source's units published on `topics::CAMERA_VIDEO`.
struct Video {
    units: Units,
    outbox: messages::VideoOutbox,
    gate: VideoUnits,
}

impl Video {
    /// Publishes every unit waiting.
    fn publish(&mut self, clock_ns: i64) -> anyhow::Result<()> {
        while let Ok(unit) = self.units.try_recv() {
            let (info, bytes) = unit_parts(unit);
            match self.gate.next(&info, clock_ns) {
                UnitVerdict::Publish(header) => {
                    self.outbox.send_with(header, bytes.len(), |out| {
                        out.copy_from_slice(&bytes);
                        Ok::<_, Infallible>(())
                    })??;
                }
                UnitVerdict::TooLarge { number, len } => tracing::warn!(
                    number,
                    bytes = len,
                    max = messages::topics::MAX_ACCESS_UNIT,
                    "an access unit too large for the video topic: it and the units up to the next keyframe are left out of the record"
                ),
                UnitVerdict::Skipped => {}
            }
        }
        Ok(())
    }
}

/// How many access units wait for the camera's loop at most; a full queue loses units (the
/// source counts them), never the stream.
#[cfg(feature = "video")]
const UNITS_QUEUED: usize = 64;

#[cfg(feature = "video")]
use video::source::DecodedUnit;

#[cfg(feature = "video")]
fn unit_parts(u: DecodedUnit) -> (UnitInfo, Vec<u8>) {
    let info = UnitInfo {
        len: u.unit.bytes.len(),
        keyframe: u.unit.keyframe,
        damaged: u.unit.damaged,
        decoder_restarted: u.decoder_restarted,
        time_ns: u.time_ns,
        session: u.unit.session,
    };
    (info, u.unit.bytes)
}

/// The RTP/H.264 source on `addr`, frames scaled to the scenario's camera, and its access units.
#[cfg(feature = "video")]
fn rtp_source(addr: std::net::SocketAddr, width: u32, height: u32) -> anyhow::Result<Opened> {
    let (tx, rx) = std::sync::mpsc::sync_channel(UNITS_QUEUED);
    let mut config = video::source::SourceConfig::new(addr, width, height);
    config.access_units = Some(tx);
    let source = video::source::RtpSource::open(config)?;
    let watch = source.watch();
    // The stream's counts once the camera stops: what was received, decoded and handed over (a
    // benchmark divides the process's CPU by them).
    let at_exit: AtExit = Box::new(move |published| {
        let s = watch.stats();
        tracing::info!(
            published,
            access_units = s.stream.access_units,
            keyframes = s.stream.keyframes,
            lost_packets = s.stream.lost,
            damaged = s.stream.damaged,
            decoded = s.decoded,
            handed_over = s.yielded,
            replaced = s.replaced,
            skipped = s.skipped,
            "the stream's counts"
        );
    });
    Ok((Box::new(source), Some(rx), Some(at_exit)))
}

/// Without the video path there are no units.
#[cfg(not(feature = "video"))]
enum DecodedUnit {}

#[cfg(not(feature = "video"))]
fn unit_parts(u: DecodedUnit) -> (UnitInfo, Vec<u8>) {
    match u {}
}

#[cfg(not(feature = "video"))]
fn rtp_source(addr: std::net::SocketAddr, _width: u32, _height: u32) -> anyhow::Result<Opened> {
    anyhow::bail!(
        "--source rtp:{addr}: this camera was built without the RTP/H.264 video path; install \
         GStreamer (scripts/install-gstreamer) and build it with `cargo build --release -p camera \
         --features video`"
    )
}
