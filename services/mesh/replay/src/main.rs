//! `replay`: plays a flight record's frames into the mesh on the camera's topic, in lockstep (each
//! frame once the mesh answered the one before: as fast as it answers) or at the recorded pace
//! (`--speed K`: K times it, never faster than the mesh answers), then compares the mesh's outputs
//! with the recorded ones and reports (`--report FILE`, and the log).

use anyhow::{Context, bail};
use clap::Parser;
use config::Dof;
use messages::topics;
use recorder::{CommandDof, Recorded};
use replay::{Frames, Outputs, Played, ReplayPlant, Report};
use runtime::lockstep::{Closed, Limits, Lockstep, Reaction, Shell};
use runtime::{CommonArgs, Flow, Runtime, Timer};
use std::collections::BTreeSet;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

#[derive(Parser)]
#[command(
    version,
    about = "Plays a flight record's camera frames into the mesh and compares the mesh's outputs with the recorded ones."
)]
struct Args {
    #[command(flatten)]
    common: CommonArgs,
    /// The flight record (its first part; the others are found beside it).
    #[arg(long, value_name = "FILE.mcap")]
    record: PathBuf,
    /// Play each frame once the previous one is answered (the default: as fast as the mesh answers).
    #[arg(long, conflicts_with = "speed")]
    lockstep: bool,
    /// Play at K times the recorded pace (1: as recorded), never before the previous frame is
    /// answered.
    #[arg(long, value_name = "K")]
    speed: Option<f64>,
    /// Re-publish an unanswered frame after this long.
    #[arg(long, default_value_t = 100, value_name = "MS")]
    resend_ms: u64,
    /// Once the mesh runs, a frame unanswered for this long is given up (counted as missing).
    #[arg(long, default_value_t = 2000, value_name = "MS")]
    deadline_ms: u64,
    /// Write the comparison here as JSON.
    #[arg(long, value_name = "FILE")]
    report: Option<PathBuf>,
    /// Exit with an error when the outputs differ from the record.
    #[arg(long)]
    fail_on_difference: bool,
}

fn main() -> ExitCode {
    let args = Args::parse();
    runtime::run("replay", &args.common, |rt| replay(rt, &args))
}

/// The mesh's outputs, as the replay reads them.
struct Taps {
    observations: messages::Tap<messages::CableObservationMsg>,
    commands: Vec<(CommandDof, messages::Tap<messages::DofCommand>)>,
    setpoints: messages::Tap<messages::ThrusterSetpoints>,
    learning: Vec<(Dof, messages::Tap<messages::LearningStats>)>,
}

impl Taps {
    fn open(rt: &Runtime) -> anyhow::Result<Taps> {
        Ok(Taps {
            observations: rt.tap(&topics::CABLE_OBSERVATION)?,
            commands: CommandDof::ALL
                .into_iter()
                .map(|d| Ok((d, rt.tap(&d.topic())?)))
                .collect::<anyhow::Result<_>>()?,
            setpoints: rt.tap(&topics::THRUSTER_SETPOINTS)?,
            learning: Dof::ALL
                .into_iter()
                .map(|d| Ok((d, rt.tap(&topics::learning(d))?)))
                .collect::<anyhow::Result<_>>()?,
        })
    }

    /// Everything unread into `out`; returns the setpoints read (the lockstep's answers).
    fn drain(&self, out: &mut Outputs) -> anyhow::Result<Vec<messages::ThrusterSetpoints>> {
        while let Some(m) = self.observations.receive()? {
            out.add(&Recorded::Observation(m));
        }
        for (d, tap) in &self.commands {
            while let Some(m) = tap.receive()? {
                out.add(&Recorded::Command(*d, m));
            }
        }
        let mut answers = Vec::new();
        while let Some(m) = self.setpoints.receive()? {
            out.add(&Recorded::Setpoints(m));
            answers.push(m);
        }
        for (d, tap) in &self.learning {
            while let Some(m) = tap.receive()? {
                out.add(&Recorded::Learning(*d, m));
            }
        }
        Ok(answers)
    }
}

/// What the replay does between wake-ups.
struct Player {
    frames_out: messages::FrameOutbox,
    speed: Option<f64>,
    /// When the first frame went out, and its recorded time.
    origin: Option<(Instant, u64)>,
    /// A frame answered early, waiting for its recorded time (`--speed`).
    held: Option<(Played, Instant)>,
    played: BTreeSet<u64>,
    done: bool,
    /// The replay is the camera of this mesh: a recorded vehicle frame goes out in the replay's own
    /// epoch, read now on the vehicle clock (its consumers judge a stamp's age by that clock, and the
    /// dive's clock readings are long past). `seq`, trial, step and time stay the recorded ones.
    clock: runtime::VehicleClock,
    epoch: u32,
    /// The stamp the frame published last went out with (a re-send repeats it).
    last_stamp: Option<messages::Stamp>,
}

impl Player {
    fn send(&mut self, plant: &ReplayPlant, step: &Played) -> anyhow::Result<()> {
        let image = plant.image();
        let mut header = step.header;
        if header.stamp.is_timed() {
            header.stamp = match self.last_stamp {
                Some(s) if s.seq == header.stamp.seq => s,
                _ => header.stamp.timed(self.epoch, self.clock.now_ns()),
            };
            self.last_stamp = Some(header.stamp);
        }
        self.frames_out
            .send_with(header, image.len(), |out| {
                out.copy_from_slice(image);
                Ok::<_, std::convert::Infallible>(())
            })?
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        self.origin
            .get_or_insert((Instant::now(), step.header.stamp.time_ns));
        self.played.insert(step.header.stamp.seq);
        Ok(())
    }

    /// When `step` is due at the recorded pace.
    fn due(&self, step: &Played) -> Option<Instant> {
        let (speed, (start, t0)) = (self.speed?, self.origin?);
        let after = step.header.stamp.time_ns.saturating_sub(t0) as f64 / 1e9 / speed;
        Some(start + Duration::from_secs_f64(after))
    }

    /// Publishes the held frame once it is due.
    fn release(&mut self, lockstep: &Lockstep<ReplayPlant>) -> anyhow::Result<()> {
        if let Some((step, due)) = self.held
            && Instant::now() >= due
        {
            self.held = None;
            self.send(lockstep.plant(), &step)?;
        }
        Ok(())
    }
}

/// The replay's side of the lockstep: a frame goes out when the mesh answered the one before (held
/// until its recorded time with `--speed`); the record's end ends the replay.
impl Shell<ReplayPlant> for Player {
    fn publish(
        &mut self,
        plant: &mut ReplayPlant,
        step: &Played,
        again: bool,
    ) -> anyhow::Result<()> {
        if again {
            if self.held.is_none() && !step.end {
                self.send(plant, step)?;
            }
        } else if step.end {
            self.done = true;
        } else if let Some(due) = self.due(step).filter(|d| *d > Instant::now()) {
            self.held = Some((*step, due));
        } else {
            self.send(plant, step)?;
        }
        Ok(())
    }

    fn closed(&mut self, _: &Lockstep<ReplayPlant>, closed: Closed<ReplayPlant>) {
        if closed.next.is_none() {
            self.done = true;
        }
    }

    fn waiting(&mut self, _: &Played, waited: Duration) {
        tracing::info!(
            waited_s = waited.as_secs(),
            "waiting for the mesh to answer the first frame"
        );
    }
}

fn replay(rt: &Runtime, args: &Args) -> anyhow::Result<()> {
    if let Some(k) = args.speed
        && !(k.is_finite() && k > 0.0)
    {
        bail!("--speed {k} must be a finite number > 0");
    }
    let meta = recorder::metadata(&args.record)?;
    if let Some(seed) = meta.get("seed")
        && *seed != rt.seed().to_string()
    {
        tracing::warn!(record_seed = %seed, seed = rt.seed(), "the record was made with another seed: the behaviours' exploration differs");
    }
    if let Some(ep) = meta.get("endpoint")
        && *ep != rt.endpoint().to_string()
    {
        tracing::info!(record_endpoint = %ep, endpoint = %rt.endpoint(), "replaying into the other endpoint");
    }
    let frames = Frames::open(&args.record)?;
    let taps = Taps::open(rt)?;
    let answered = rt.listener(&topics::THRUSTER_SETPOINTS)?;
    let mut player = Player {
        frames_out: rt.frame_outbox()?,
        speed: args.speed,
        origin: None,
        held: None,
        played: BTreeSet::new(),
        done: false,
        clock: *rt.clock(),
        epoch: rt.clock().new_epoch(),
        last_stamp: None,
    };
    let limits = Limits::new(
        Duration::from_millis(args.resend_ms),
        Duration::from_millis(args.deadline_ms),
    );
    let (mut lockstep, first) =
        Lockstep::start(ReplayPlant::new(frames), limits, 0, Instant::now());
    let c = &rt.scenario().camera;
    if let Reaction::Publish { next, .. } = &first
        && !next.end
        && (next.header.width, next.header.height) != (c.width, c.height)
    {
        bail!(
            "{}: its frames are {}x{}, the scenario's camera is {}x{}",
            args.record.display(),
            next.header.width,
            next.header.height,
            c.width,
            c.height
        );
    }
    tracing::info!(record = %args.record.display(), pace = ?args.speed.map_or("lockstep".to_owned(), |k| format!("{k}x the recorded pace")), "replaying");
    lockstep.carry_out(&mut player, first)?;
    let mut replayed = Outputs::default();
    let tick = limits.tick().min(Duration::from_millis(10));
    let mut last_note = Instant::now();
    let stopped = if player.done {
        runtime::Stopped::Done
    } else {
        rt.serve(&[&answered], Timer::Timeout(tick), |_| {
            for s in taps.drain(&mut replayed)? {
                lockstep.answer(&mut player, s.stamp.seq, s.as_slice(), Instant::now())?;
            }
            lockstep.tick(&mut player, Instant::now())?;
            player.release(&lockstep)?;
            if last_note.elapsed() >= Duration::from_secs(10) {
                last_note = Instant::now();
                tracing::info!(frames = player.played.len(), "replaying");
            }
            Ok(if player.done {
                Flow::Stop
            } else {
                Flow::Continue
            })
        })?
    };
    // The episode reports of the last frames may still be on their way.
    let mut plant = lockstep.into_plant();
    if let Some(e) = plant.take_error() {
        return Err(e).context("reading the record");
    }
    let want_reports = |rec: &Outputs, rep: &Outputs| {
        Dof::ALL.iter().all(|d| {
            rec.learning.get(d).map_or(0, |m| m.len()) <= rep.learning.get(d).map_or(0, |m| m.len())
        })
    };
    let frames = plant.into_frames();
    let played_frames = frames.yielded();
    log_stream(&frames);
    let (recorded, read) = frames.finish()?;
    let recorded = recorded.only(|s| player.played.contains(&s));
    if stopped == runtime::Stopped::Done && !want_reports(&recorded, &replayed) {
        let listeners: Vec<_> = Dof::ALL
            .iter()
            .map(|d| rt.listener(&topics::learning(*d)))
            .collect::<Result<_, _>>()?;
        let refs: Vec<_> = listeners.iter().collect();
        rt.serve(&refs, Timer::Timeout(Duration::from_secs(2)), |wake| {
            taps.drain(&mut replayed)?;
            Ok(
                if want_reports(&recorded, &replayed) || wake == runtime::Wake::Timer {
                    Flow::Stop
                } else {
                    Flow::Continue
                },
            )
        })?;
    }
    taps.drain(&mut replayed)?;
    for cut in &read.cut {
        tracing::warn!(part = %cut.path.display(), messages = cut.messages, "the record was cut here ({}): replayed up to it", cut.reason);
    }
    let report = Report::compare(
        &args.record.display().to_string(),
        player.played.len() as u64,
        &recorded,
        &replayed.only(|s| player.played.contains(&s)),
    );
    tracing::info!(
        frames = played_frames,
        identical = report.identical,
        "replay done"
    );
    cli::outln!("{}", report.text())?;
    if let Some(path) = &args.report {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir)
                .with_context(|| format!("creating the directory {}", dir.display()))?;
        }
        std::fs::write(path, serde_json::to_string_pretty(&report)?)
            .with_context(|| format!("writing {}", path.display()))?;
        tracing::info!("wrote {}", path.display());
    }
    if args.fail_on_difference && !report.identical {
        bail!(
            "the replayed outputs differ from the record{}",
            report
                .first_difference
                .as_ref()
                .map_or(String::new(), |d| format!(
                    ": first at step seq {} ({} {})",
                    d.seq, d.topic, d.field
                ))
        );
    }
    Ok(())
}

/// Where the replayed frames' images came from, when the record has the camera's stream.
fn log_stream(frames: &Frames) {
    if frames.from_stream == 0 {
        return;
    }
    tracing::info!(
        from_stream = frames.from_stream,
        checked = frames.checked,
        from_images = frames.yielded().saturating_sub(frames.from_stream),
        "frames decoded from the record's stream, checked against the images it keeps"
    );
    if frames.checked == 0 {
        tracing::info!(
            "the record keeps no image of the frames its stream gives (recorder --video-frame-every 0): no decoded frame was compared with an image; the mesh's outputs, compared with the recorded ones, are the check"
        );
    }
    if frames.undecodable > 0 {
        tracing::warn!(
            frames = frames.undecodable,
            "frames decoded from units the record does not decode as the camera did (a unit missing before them, or the camera's decoder started afresh) and without an image: they may differ from the dive's"
        );
    }
}
