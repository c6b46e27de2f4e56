//! `vehicle-twin`: the vehicle's hardware for the vehicle endpoint, on a machine without a vehicle.
//! Publishes the twin camera's frames on `cabletrack/twin/frame`, takes the thruster setpoints from
//! `cabletrack/twin/thrusters`, and runs trials as on the real vehicle. Real time by default
//! (5 Hz), `--speed K` times faster, or `--lockstep` with the mesh (see `vehicle_twin::driver`).
//! With `--autopilot URL` the thrusters are a stand-in ArduSub's motors, commanded over MAVLink
//! (see `vehicle_twin::ardusub`; the loop is `autopilot.rs`).

mod autopilot;

use adapters::replay::{DiveWriter, ImageFormat};
use adapters::twin::{TwinCameraPort, TwinThrusterPort};
use anyhow::Context;
use clap::Parser;
use config::TwinParams;
use records::latency;
use runtime::lockstep::{Cause, Closed, Limits, Lockstep, Plant, Shell};
use runtime::{CommonArgs, Flow, Timer};
use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};
use vehicle_twin::Twin;
use vehicle_twin::driver::{RealTime, Tick};
use vehicle_twin::latency::LatencyMeter;
use vehicle_twin::twin::{Shot, TrialEnd};

#[derive(Parser)]
#[command(
    version,
    about = "The vehicle twin: the plant behind the vehicle endpoint's camera and thrusters, with the reality gap of config/twin.toml."
)]
struct Args {
    #[command(flatten)]
    common: CommonArgs,
    /// The twin's reality gap [default: CONFIG/twin.toml].
    #[arg(long, value_name = "FILE")]
    twin_config: Option<PathBuf>,
    /// Run K times faster than real time (a frame every sample period / K of wall time: 0.2/K s).
    #[arg(long, default_value_t = 1.0, value_name = "K")]
    speed: f64,
    /// Lockstep with the mesh: publish a frame, wait for the setpoints answering it, integrate.
    /// Deterministic for a seed, as fast as the mesh answers; --speed is not used.
    #[arg(long)]
    lockstep: bool,
    /// Lockstep: re-publish an unanswered frame after this long.
    #[arg(long, default_value_t = 100, value_name = "MS")]
    resend_ms: u64,
    /// Lockstep: once the mesh runs, a frame unanswered for this long is integrated without an
    /// answer (the thrusters hold, then the watchdog stops them).
    #[arg(long, default_value_t = 2000, value_name = "MS")]
    deadline_ms: u64,
    /// Stop after this many trials (0: run until SIGINT/SIGTERM).
    #[arg(long, default_value_t = 0, value_name = "N")]
    trials: u32,
    /// Record the dive: every frame published, as a replayable dive (adapters::replay) in DIR.
    #[arg(long, value_name = "DIR")]
    record: Option<PathBuf>,
    /// Write every frame's camera-to-thruster latency here (CSV:
    /// seq,trial,step,time_ns,sent_ns,latency_ns): from the frame's publication (with --video, its
    /// last packet sent; sent_ns on the monotonic clock) to the arrival of the setpoints answering
    /// it; with --autopilot (real time only), to the first MANUAL_CONTROL carrying its command read
    /// off the autopilot's socket.
    #[arg(long, value_name = "FILE")]
    latency: Option<PathBuf>,
    /// Stand in for a BlueROV2's ArduSub autopilot on this MAVLink port (`udpin:HOST:PORT`,
    /// `udpout:HOST:PORT`): the thrusters are its motors, commanded by MANUAL_CONTROL; without it
    /// the thrusters take setpoints from the twin's thruster topic.
    #[arg(long, value_name = "URL")]
    autopilot: Option<vehicle_twin::ardusub::Url>,
    /// With --autopilot: inject a fault, `link-cut:AT:FOR` (nothing in or out) or `restart:AT:FOR`
    /// (the autopilot silent, then back disarmed in MANUAL), seconds after the start; repeatable.
    #[arg(long, value_name = "KIND:AT:FOR", requires = "autopilot")]
    fault: Vec<vehicle_twin::ardusub::Fault>,
    /// With --autopilot: an ArduSub parameter set over the twin config's `[autopilot.params]`,
    /// `NAME=VALUE` (e.g. `MAV_GCS_SYSID=254` for a vehicle set up for the stack, docs/bluerov2.md;
    /// `MOT_3_DIRECTION=-1` for a reversed thruster); checked as the file's are. Repeatable.
    #[arg(long = "param", value_name = "NAME=VALUE", requires = "autopilot", value_parser = parse_param)]
    params: Vec<(String, f64)>,
    #[command(flatten)]
    video: VideoArgs,
}

/// The camera as a BlueROV2 delivers it: RTP/H.264 on UDP instead of the iceoryx2 frame topic.
#[derive(clap::Args)]
struct VideoArgs {
    /// Send the camera's frames as RTP/H.264 (payload type 96) to this UDP address, as a BlueROV2's
    /// camera does (`camera --source rtp:ADDR:PORT` receives them); nothing is published on the
    /// frame topic then. Built with `--features video`.
    #[arg(long, value_name = "rtp:HOST:PORT")]
    video: Option<String>,
    /// --video: the size sent (the rendered frames are scaled up to it), as WIDTHxHEIGHT.
    #[arg(long, default_value = "1920x1080", value_name = "WxH")]
    video_size: String,
    /// --video: the encoder's bitrate.
    #[arg(long, default_value_t = 4000, value_name = "KBPS")]
    video_kbps: u32,
    /// --video: frames between two keyframes.
    #[arg(long, default_value_t = 10, value_name = "N")]
    video_key_int: u32,
    /// --video: the probability that a packet is lost on the way (drawn from the seed).
    #[arg(long, default_value_t = 0.0, value_name = "P")]
    video_loss: f64,
    /// --video: the largest RTP payload.
    #[arg(long, default_value_t = 1200, value_name = "BYTES")]
    video_max_payload: usize,
}

/// Where the twin's camera sends its frames.
enum CameraOut {
    /// The iceoryx2 frame topic (`cabletrack/twin/frame`).
    Topic(Box<TwinCameraPort>),
    /// RTP/H.264 on UDP.
    #[cfg(feature = "video")]
    Rtp(Box<video::sender::RtpSender>),
}

impl CameraOut {
    fn open(
        rt: &runtime::Runtime,
        args: &VideoArgs,
        size: (u32, u32),
        fps: f64,
    ) -> anyhow::Result<Self> {
        let Some(spec) = &args.video else {
            return Ok(CameraOut::Topic(Box::new(TwinCameraPort::open(
                rt.node(),
                size.0 as usize * size.1 as usize,
            )?)));
        };
        let addr = spec
            .strip_prefix("rtp:")
            .ok_or_else(|| anyhow::anyhow!("--video {spec}: expected rtp:HOST:PORT"))?;
        let destination = std::net::ToSocketAddrs::to_socket_addrs(addr)
            .with_context(|| format!("--video {spec}: not a HOST:PORT"))?
            .next()
            .ok_or_else(|| anyhow::anyhow!("--video {spec}: {addr} has no address"))?;
        let output = parse_size(&args.video_size)
            .with_context(|| format!("--video-size {}", args.video_size))?;
        Self::rtp(rt, args, destination, size, output, fps)
    }

    #[cfg(feature = "video")]
    fn rtp(
        rt: &runtime::Runtime,
        args: &VideoArgs,
        destination: std::net::SocketAddr,
        size: (u32, u32),
        output: (u32, u32),
        fps: f64,
    ) -> anyhow::Result<Self> {
        use video::sender::{Encoding, RtpSender, SenderConfig};
        let mut config = SenderConfig::new(destination, size);
        config.output = Some(output);
        config.fps = fps.round().max(1.0) as u32;
        config.encoding = Encoding::Bitrate {
            kbps: args.video_kbps,
            profile: "constrained-baseline".into(),
        };
        config.key_interval = args.video_key_int;
        config.loss = args.video_loss;
        config.max_payload = args.video_max_payload;
        config.seed = config::derive_seed(rt.seed(), "video");
        Ok(CameraOut::Rtp(Box::new(RtpSender::open(config)?)))
    }

    #[cfg(not(feature = "video"))]
    fn rtp(
        _rt: &runtime::Runtime,
        _args: &VideoArgs,
        destination: std::net::SocketAddr,
        _size: (u32, u32),
        _output: (u32, u32),
        _fps: f64,
    ) -> anyhow::Result<Self> {
        anyhow::bail!(
            "--video rtp:{destination}: this twin was built without the RTP/H.264 video path; \
             install GStreamer (scripts/install-gstreamer) and build it with `cargo build --release \
             -p vehicle-twin --features video`"
        )
    }

    /// Frame sources listening: on RTP, nobody says, and a camera streams regardless.
    fn listeners(&self) -> usize {
        match self {
            CameraOut::Topic(port) => port.subscribers(),
            #[cfg(feature = "video")]
            CameraOut::Rtp(_) => 1,
        }
    }

    fn send(&mut self, meta: &adapters::FrameMeta, image: &[u8]) -> anyhow::Result<()> {
        match self {
            CameraOut::Topic(port) => port.send(meta, |out| out.copy_from_slice(image))?,
            #[cfg(feature = "video")]
            CameraOut::Rtp(sender) => {
                sender.send(Some(meta), image)?;
            }
        }
        Ok(())
    }
}

/// `WIDTHxHEIGHT`.
fn parse_size(s: &str) -> anyhow::Result<(u32, u32)> {
    let (w, h) = s
        .split_once('x')
        .ok_or_else(|| anyhow::anyhow!("expected WIDTHxHEIGHT, e.g. 1920x1080"))?;
    Ok((w.trim().parse()?, h.trim().parse()?))
}

/// Times each published frame until its answer (`--latency`).
pub(crate) struct Latency {
    meter: LatencyMeter,
    out: std::io::BufWriter<std::fs::File>,
    path: PathBuf,
    samples: u64,
    max: Duration,
}

impl Latency {
    fn create(path: &std::path::Path) -> anyhow::Result<Latency> {
        let file = std::fs::File::create(path)
            .with_context(|| format!("creating the latency file {}", path.display()))?;
        let mut out = std::io::BufWriter::new(file);
        writeln!(out, "{}", latency::HEADER)?;
        Ok(Latency {
            meter: LatencyMeter::new(),
            out,
            path: path.to_owned(),
            samples: 0,
            max: Duration::ZERO,
        })
    }

    fn answered(&mut self, time_ns: u64) -> anyhow::Result<()> {
        let sample = self.meter.answered(time_ns, Instant::now());
        self.write(sample)
    }

    /// Over MAVLink: the autopilot took a MANUAL_CONTROL read at `at`.
    pub(crate) fn stick(&mut self, at: Instant) {
        self.meter.stick(at);
    }

    /// Over MAVLink: a step tag naming the frame of `frame_time_ms` came.
    pub(crate) fn tagged(&mut self, frame_time_ms: u32) -> anyhow::Result<()> {
        let sample = self.meter.tagged(frame_time_ms);
        self.write(sample)
    }

    fn write(&mut self, sample: Option<latency::Sample>) -> anyhow::Result<()> {
        if let Some(s) = sample {
            latency::write_sample(&mut self.out, &s)?;
            self.samples += 1;
            self.max = self.max.max(s.latency);
        }
        Ok(())
    }

    fn finish(mut self) -> anyhow::Result<()> {
        self.out
            .flush()
            .with_context(|| format!("writing {}", self.path.display()))?;
        tracing::info!(
            file = %self.path.display(),
            frames = self.samples,
            max_us = self.max.as_micros() as u64,
            "frame-to-answer latencies written"
        );
        Ok(())
    }
}

/// Publishes the twin's frames (and records them).
pub(crate) struct Camera {
    port: CameraOut,
    image: Vec<u8>,
    size: (u32, u32),
    recorder: Option<DiveWriter>,
}

impl Camera {
    /// Whether a frame source is listening.
    pub(crate) fn listening(&self) -> bool {
        self.port.listeners() > 0
    }

    pub(crate) fn publish(
        &mut self,
        twin: &mut Twin,
        shot: &Shot,
        again: bool,
        latency: &mut Option<Latency>,
    ) -> anyhow::Result<()> {
        twin.render(&mut self.image)?;
        let meta = shot.meta(self.size.0, self.size.1);
        self.port.send(&meta, &self.image)?;
        // Timed from the send: rendering is the camera hardware's work, not the vehicle's.
        if !again && let Some(l) = latency.as_mut() {
            l.meter
                .published(shot, Instant::now(), runtime::clock::monotonic_ns());
        }
        if !again && let Some(r) = self.recorder.as_mut() {
            r.write(&meta, &self.image)?;
        }
        Ok(())
    }
}

fn parse_param(s: &str) -> Result<(String, f64), String> {
    let (name, value) = s
        .split_once('=')
        .ok_or_else(|| format!("`{s}` is not NAME=VALUE"))?;
    let value = value
        .parse()
        .map_err(|e| format!("`{s}`: the value is not a number: {e}"))?;
    Ok((name.to_owned(), value))
}

fn main() -> ExitCode {
    let args = Args::parse();
    runtime::run("vehicle-twin", &args.common, |rt| {
        if !(args.speed.is_finite() && args.speed > 0.0) {
            anyhow::bail!("--speed {} must be a number > 0", args.speed);
        }
        let path = args
            .twin_config
            .clone()
            .unwrap_or_else(|| rt.config_dir().join("twin.toml"));
        let mut params: TwinParams = config::load(&path)?;
        if !args.params.is_empty() {
            let Some(autopilot) = params.autopilot.as_mut() else {
                anyhow::bail!(
                    "--param: {} has no [autopilot] section: this twin stands in for no autopilot",
                    path.display()
                );
            };
            autopilot.params.extend(args.params.iter().cloned());
            config::Validate::validate(&*autopilot, "--param")
                .map_err(|e| anyhow::anyhow!("{e}"))?;
            tracing::info!(params = ?args.params, "autopilot parameters set on the command line");
        }
        let scenario = rt.scenario();
        let twin = Twin::new(scenario, &params, rt.seed(), true)?;
        let size = (scenario.camera.width, scenario.camera.height);
        let len = size.0 as usize * size.1 as usize;
        if args.autopilot.is_some() && args.lockstep && args.latency.is_some() {
            anyhow::bail!(
                "--latency with --autopilot times real-time runs (--speed), not --lockstep: there the step tag, not the clock, paces the twin"
            );
        }
        let recorder = match &args.record {
            Some(dir) => Some(
                DiveWriter::create(dir, size.0, size.1, true, ImageFormat::Pgm)
                    .with_context(|| format!("cannot record the dive in {}", dir.display()))?,
            ),
            None => None,
        };
        let fps = 1.0 / scenario.timing.sample_time_s;
        let mut camera = Camera {
            port: CameraOut::open(rt, &args.video, size, fps)?,
            image: vec![0; len],
            size,
            recorder,
        };
        let period = Duration::from_secs_f64(scenario.timing.sample_time_s / args.speed);
        tracing::info!(
            config = %path.display(),
            mode = if args.lockstep { "lockstep" } else { "clock" },
            speed = args.speed,
            trials = args.trials,
            trial_steps = twin.steps_per_trial(),
            record = ?args.record,
            video = ?args.video.video,
            "ready"
        );
        let mut latency = args.latency.as_deref().map(Latency::create).transpose()?;
        let mut log = TrialLog::new(twin.steps_per_trial());
        let limits = Limits::new(
            Duration::from_millis(args.resend_ms),
            Duration::from_millis(args.deadline_ms),
        );
        if let Some(url) = args.autopilot {
            let setup = autopilot::Setup {
                url,
                faults: args.fault.clone(),
                lockstep: args.lockstep.then_some(limits),
                period,
                trials: args.trials,
            };
            autopilot::run(rt, setup, twin, &mut camera, &mut log, &mut latency)?;
            return finish(latency.take(), &mut camera);
        }
        let thrusters = TwinThrusterPort::open(rt.node())?;
        if args.lockstep {
            let (mut lockstep, first) = Lockstep::start(twin, limits, args.trials, Instant::now());
            let mut shell = Frames {
                camera: &mut camera,
                log: &mut log,
                latency: &mut latency,
            };
            if lockstep.carry_out(&mut shell, first)? == Flow::Continue {
                rt.serve(
                    &[thrusters.listener()],
                    Timer::Timeout(limits.tick()),
                    |_| {
                        while let Some(sp) = thrusters.receive()? {
                            if let Some(cause) = sp.stop_cause() {
                                // A failsafe stop answers no frame: the thrusters hold 0 from now on.
                                tracing::debug!(%cause, "the vehicle stopped the thrusters");
                                lockstep.plant_mut().stop_thrusters();
                                continue;
                            }
                            if let Some(l) = shell.latency.as_mut() {
                                l.answered(sp.stamp.time_ns)?;
                            }
                            let now = Instant::now();
                            if lockstep.answer(&mut shell, sp.stamp.time_ns, sp.as_slice(), now)?
                                == Flow::Stop
                            {
                                return Ok(Flow::Stop);
                            }
                        }
                        lockstep.tick(&mut shell, Instant::now())
                    },
                )?;
            }
        } else {
            let mut clock = RealTime::new(twin, period, args.trials);
            // The interval timer wakes the loop; the clock decides when a period is due (a wake-up
            // for setpoints and the timer's may coincide).
            let tick = (period / 4).max(Duration::from_millis(1));
            rt.serve(&[thrusters.listener()], Timer::Interval(tick), |_| {
                while let Some(sp) = thrusters.receive()? {
                    // A failsafe stop's zeros are applied like setpoints, but answer no frame.
                    if sp.stop == 0
                        && let Some(l) = latency.as_mut()
                    {
                        l.answered(sp.stamp.time_ns)?;
                    }
                    clock.on_setpoints(sp.as_slice());
                }
                match clock.on_time(Instant::now(), camera.listening()) {
                    Tick::Publish { shot, ended, .. } => {
                        log.closed(&ended, 0, false, &shot);
                        camera.publish(clock.twin_mut(), &shot, false, &mut latency)?;
                    }
                    Tick::Finished { ended } => {
                        let shot = *clock.twin().current().expect("started");
                        log.closed(&ended, 0, false, &shot);
                        return Ok(Flow::Stop);
                    }
                    Tick::Idle => {}
                }
                Ok(Flow::Continue)
            })?;
        }
        finish(latency.take(), &mut camera)
    })
}

/// Writes what the run leaves behind: the latencies, the recorded dive.
fn finish(latency: Option<Latency>, camera: &mut Camera) -> anyhow::Result<()> {
    if let Some(l) = latency {
        l.finish()?;
    }
    if let Some(r) = camera.recorder.take() {
        let dir = r.dir().to_owned();
        let frames = r.finish()?;
        tracing::info!(dir = %dir.display(), frames, "dive recorded");
    }
    Ok(())
}

/// Logs trial ends and unanswered frames.
/// The twin's side of the lockstep, over shared memory or behind the ArduSub stand-in: each frame
/// to the camera, each closed frame to the trial log.
pub(crate) struct Frames<'a> {
    pub(crate) camera: &'a mut Camera,
    pub(crate) log: &'a mut TrialLog,
    pub(crate) latency: &'a mut Option<Latency>,
}

impl Shell<Twin> for Frames<'_> {
    fn publish(&mut self, twin: &mut Twin, shot: &Shot, again: bool) -> anyhow::Result<()> {
        self.camera.publish(twin, shot, again, self.latency)
    }

    fn closed(&mut self, _: &Lockstep<Twin>, closed: Closed<Twin>) {
        self.log.closed_step(&closed);
    }

    fn waiting(&mut self, shot: &Shot, waited: Duration) {
        tracing::info!(
            seq = shot.seq,
            waited_s = waited.as_secs(),
            frame_sources = self.camera.port.listeners(),
            "waiting for the mesh: no setpoints yet"
        );
    }
}

pub(crate) struct TrialLog {
    steps_per_trial: u32,
    started: Instant,
    frames: u64,
}

impl TrialLog {
    fn new(steps_per_trial: u32) -> Self {
        TrialLog {
            steps_per_trial,
            started: Instant::now(),
            frames: 0,
        }
    }

    /// A frame closed in lockstep: the trial log's line, from the frame published next (the last
    /// one at the end).
    pub(crate) fn closed_step<P: Plant<Step = Shot, End = TrialEnd>>(&mut self, c: &Closed<P>) {
        let Some(shot) = c.next.as_ref().or(c.step.as_ref()) else {
            return;
        };
        let deadline = c.next.is_some() && c.cause == Cause::Deadline;
        self.closed(&c.ended, c.passed, deadline, shot);
    }

    pub(crate) fn closed(&mut self, ended: &[TrialEnd], passed: u32, deadline: bool, shot: &Shot) {
        self.frames += 1 + passed as u64;
        if deadline {
            tracing::warn!(
                seq = shot.seq,
                "no setpoints within the deadline: the thrusters hold"
            );
        }
        for end in ended {
            let how = end.status.describe();
            tracing::info!(
                trial = end.trial,
                steps = end.steps,
                of = self.steps_per_trial,
                end = how,
                dropped_frames = end.dropped,
                frames_per_s = (self.frames as f64 / self.started.elapsed().as_secs_f64().max(1e-9))
                    .round() as u64,
                "trial ended"
            );
        }
    }
}
