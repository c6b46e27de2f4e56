//! `recorder`: the mesh's flight recorder. Subscribes to every topic of its endpoint with the
//! recorder's own buffers (`messages::Tap`), drains them 10 ms after a step's thruster setpoints
//! or the supervisor's events wake it, writes what it drained into the MCAP record, flushes it
//! every second and publishes its progress; SIGTERM or SIGINT drains once more and closes the file
//! with its index. With `--live` the same channels are served to a viewer.

use clap::Parser;
use messages::topics;
use recorder::{Drain, FlightRecorder, Options};
use runtime::{CommonArgs, Flow, Runtime, Timer};
use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

#[derive(Parser)]
#[command(
    version,
    about = "The flight recorder: every topic of the endpoint into an MCAP file (Foxglove, Lichtblick), optionally served live."
)]
struct Args {
    #[command(flatten)]
    common: CommonArgs,
    /// The record's file (its next parts are FILE's stem with .1, .2, ...). An existing record is
    /// continued with a new part.
    #[arg(long, value_name = "FILE.mcap")]
    out: PathBuf,
    /// Keep the image of every N-th step of an episode (1: every frame). Headers, estimates and
    /// everything else are kept at every step.
    #[arg(long, default_value_t = 1, value_name = "N")]
    frame_every: u32,
    /// Of the frames the recorded compressed stream gives (`/camera_video`), keep the image of
    /// every N-th step only; 0: none (the stream alone holds them). The frames it cannot give
    /// (before its first keyframe, after a unit missing) follow --frame-every.
    #[arg(long, default_value_t = 25, value_name = "N")]
    video_frame_every: u32,
    /// Start a new part when the current one reaches this size.
    #[arg(long, default_value_t = 1024, value_name = "MB")]
    rotate_mb: u64,
    /// Close a chunk at this uncompressed size (and at every flush).
    #[arg(long, default_value_t = 1024, value_name = "KB")]
    chunk_kb: u64,
    /// Flush the file this often: a SIGKILL loses at most what came since.
    #[arg(long, default_value_t = 1000, value_name = "MS")]
    flush_ms: u64,
    /// Serve the channels live (foxglove WebSocket protocol) on HOST:PORT: `--live` alone listens on
    /// this machine only (127.0.0.1:8765); port 0 takes a free one.
    #[arg(long, num_args = 0..=1, require_equals = true, default_missing_value = "127.0.0.1:8765", value_name = "HOST:PORT")]
    live: Option<SocketAddr>,
}

/// The recorder drains its taps this long after a step's last message wakes it: at the vehicle's
/// 5 Hz once per step, after the step is done; the accelerated sim mesh's thousands of steps a second
/// in batches, since a wake-up per step would cost the mesh more than the recording. Each
/// tap holds at least 64 messages (`Qos::recorder_buffer`), so nothing is lost below 6,400 steps/s
/// when it runs in time (in the idle class, while a CPU is free).
const DRAIN_EVERY: Duration = Duration::from_millis(10);

fn main() -> ExitCode {
    let args = Args::parse();
    runtime::run("recorder", &args.common, |rt| record(rt, &args))
}

/// Every topic of the endpoint, read by the recorder.
struct Taps {
    /// The camera's compressed stream (an RTP/H.264 source's).
    video: messages::VideoTap,
    frames: messages::FrameTap,
    /// Every other topic the recorder records as it is (`recorder::channels`).
    plain: Vec<Box<dyn Drain>>,
}

impl Taps {
    fn open(rt: &Runtime) -> anyhow::Result<Taps> {
        Ok(Taps {
            video: rt.video_tap()?,
            frames: rt.frame_tap()?,
            plain: recorder::taps(rt)?,
        })
    }

    /// Everything unread, into the record: the video units, the frames (a step's estimate is drawn
    /// over its frame's image once that is written), then the other topics in the table's order.
    fn drain(&self, rec: &mut FlightRecorder) -> anyhow::Result<()> {
        // The units before the frames they decode to: whether a frame's image is kept depends on
        // its unit. The camera publishes a frame after its unit, so the units are read again
        // before each frame: a unit that came after the first read is in by then.
        let units = |rec: &mut FlightRecorder| -> anyhow::Result<()> {
            while self
                .video
                .receive_with(|unit, bytes| rec.video(unit, bytes))?
                .is_some()
            {}
            Ok(())
        };
        units(rec)?;
        while let Some(read) = self.frames.receive_with(|header, image| {
            units(rec)?;
            rec.frame(header, image);
            anyhow::Ok(())
        })? {
            read?;
        }
        for tap in &self.plain {
            tap.drain(rec)?;
        }
        Ok(())
    }
}

fn flush_every(args: &Args) -> Duration {
    Duration::from_millis(args.flush_ms.max(1))
}

fn record(rt: &Runtime, args: &Args) -> anyhow::Result<()> {
    let taps = Taps::open(rt)?;
    // A step's thruster setpoints (its last message) wake it, and the supervisor's events, so a
    // restart is recorded when it happens.
    let step_done = rt.listener(&topics::THRUSTER_SETPOINTS)?;
    let event = rt.listener(&topics::SUPERVISOR_EVENTS)?;
    let status_out = rt.outbox(&topics::RECORDER_STATUS)?;
    let metadata = BTreeMap::from([
        ("endpoint".to_owned(), rt.endpoint().to_string()),
        ("seed".to_owned(), rt.seed().to_string()),
        (
            "log_time".to_owned(),
            match rt.endpoint() {
                messages::Endpoint::Sim => "the stamp's time: simulated ns since the run's start",
                messages::Endpoint::Vehicle => {
                    "the stamp's time: the frame source's clock in ns (the twin's time since its start)"
                }
            }
            .to_owned(),
        ),
        (
            "recorder".to_owned(),
            format!("cabletrack recorder {}", env!("CARGO_PKG_VERSION")),
        ),
    ]);
    let mut opts = Options::new(&args.out);
    opts.frame_every = args.frame_every;
    opts.video_frame_every = args.video_frame_every;
    opts.rotate_bytes = args.rotate_mb.saturating_mul(1 << 20);
    opts.chunk_bytes = args.chunk_kb.saturating_mul(1 << 10);
    let mut rec = match FlightRecorder::create(opts, metadata) {
        Ok(rec) => rec,
        // A recorder that exited would be restarted, again and again, and take the mesh down with
        // it: on a full disk it waits without recording instead.
        Err(e) if e.is_disk_full() => {
            tracing::error!(
                "{e}: the disk is full; the recorder waits without recording, the vehicle is not affected"
            );
            rt.ready();
            rt.serve(&[&event], Timer::Timeout(flush_every(args)), |_| {
                Ok(Flow::Continue)
            })?;
            return Ok(());
        }
        Err(e) => return Err(e.into()),
    };
    if let Some(addr) = args.live {
        let port = rec.serve_live(addr)?;
        if !addr.ip().is_loopback() {
            tracing::warn!(%addr, "the live view is reachable from other machines");
        }
        tracing::info!(
            url = %format!("ws://{}:{port}", addr.ip()),
            "live view: open it in Foxglove or Lichtblick (Open connection, Foxglove WebSocket)"
        );
    }
    tracing::info!(
        out = %args.out.display(),
        frame_every = args.frame_every,
        video_frame_every = args.video_frame_every,
        rotate_mb = args.rotate_mb,
        "recording every topic of the endpoint"
    );
    rt.ready();
    let flush_every = flush_every(args);
    let mut last_flush = Instant::now();
    let mut last_progress = Instant::now();
    // The timeout flushes and publishes progress while no step runs.
    let served = rt.serve(&[&step_done, &event], Timer::Timeout(flush_every), |_| {
        // Batching, not waiting for anything (what arrives meanwhile stays in the taps' buffers), and
        // out of the step's way: the drain, which copies and compresses a frame, starts after the
        // setpoints have reached the thrusters (a millisecond or two).
        std::thread::sleep(DRAIN_EVERY);
        taps.drain(&mut rec)?;
        if last_flush.elapsed() >= flush_every {
            last_flush = Instant::now();
            // A failed write (a full disk) stops the recording, not the recorder: said once,
            // here; the vehicle is not affected, and the live view and the status go on.
            if let Err(e) = rec.flush().and_then(|()| rec.rotate_if_due().map(drop)) {
                tracing::error!("{e}");
            }
            let status = rec.status();
            status_out.send(status)?;
            if last_progress.elapsed() >= Duration::from_secs(60) {
                last_progress = Instant::now();
                tracing::info!(
                    messages = status.messages,
                    mb = status.bytes as f64 / 1e6,
                    holes = status.holes,
                    "recording"
                );
            }
        }
        Ok(Flow::Continue)
    });
    // Whatever ended the loop, keep what is there: drain once more and close with the index.
    let drained = taps.drain(&mut rec);
    let status = rec.status();
    let totals = match rec.close() {
        Ok(totals) => totals,
        Err(e @ recorder::RecordError::Stopped { .. }) => {
            tracing::error!("{e}");
            served?;
            return drained;
        }
        Err(e) => return Err(e.into()),
    };
    let _ = status_out.send(status);
    let holes: u64 = totals.counts.values().map(|c| c.holes).sum();
    for (c, n) in &totals.counts {
        tracing::info!(
            topic = c.topic(),
            written = n.written,
            repeats = n.repeats,
            holes = n.holes,
            decimated = n.decimated,
            "recorded"
        );
    }
    if holes > 0 {
        tracing::warn!(
            holes,
            "some steps were missed on some topics (the recorder fell behind, or they were never published)"
        );
    }
    tracing::info!(
        parts = totals.parts.len(),
        complete = totals.stopped.is_none(),
        messages = totals.messages,
        mb = totals.bytes as f64 / 1e6,
        "flight record closed: {}",
        totals
            .parts
            .iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    );
    served?;
    drained
}
