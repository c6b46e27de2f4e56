//! `monitor`: prints each episode's returns as the mesh learns, and writes the run's record (after
//! every episode, so a restarted monitor carries on from it). Reports whose stamp is refused
//! (`runtime::screen::Screen`) or that cannot be true (`monitor::check`) are not recorded.

use anyhow::Context;
use clap::Parser;
use config::Dof;
use messages::topics;
use monitor::Episodes;
use records::{RunRecord, TracePoint};
use runtime::screen::{Screen, ScreenLimits, Verdict};
use runtime::{CommonArgs, Flow, Tally, Timer};
use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

#[derive(Parser)]
#[command(
    version,
    about = "Reports the behaviours' per-episode returns and writes a JSON record of the run."
)]
struct Args {
    #[command(flatten)]
    common: CommonArgs,
    /// Stop after the episode numbered N - 1 (from 0) is recorded (0: until SIGTERM).
    #[arg(long, default_value_t = 0)]
    episodes: u32,
    /// When one behaviour reported the last episode, wait this long for the other's report; then
    /// take it as lost and stop.
    #[arg(long, default_value_t = 10.0, value_name = "S")]
    linger_s: f64,
    /// Write the run's record here when stopping: per episode its returns, steps, whether the cable
    /// was lost, whether it was an evaluation trial, the gains; the evaluations; the safety counts.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Also record every observation, one JSON line each: {"episode","step","time_s","found","x_g","theta"}.
    #[arg(long)]
    trace: Option<PathBuf>,
}

fn main() -> ExitCode {
    let args = Args::parse();
    runtime::run("monitor", &args.common, |rt| {
        let inboxes = [
            (Dof::Sway, rt.inbox(&topics::SWAY_LEARNING)?),
            (Dof::Yaw, rt.inbox(&topics::YAW_LEARNING)?),
        ];
        for path in args.json.iter().chain(&args.trace) {
            if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
                std::fs::create_dir_all(dir)
                    .with_context(|| format!("creating the directory {}", dir.display()))?;
            }
        }
        let (trace_in, mut trace_out) = match &args.trace {
            Some(path) => (
                Some(rt.inbox(&topics::CABLE_OBSERVATION)?),
                Some(std::io::BufWriter::new(
                    std::fs::File::create(path)
                        .with_context(|| format!("creating the trace {}", path.display()))?,
                )),
            ),
            None => (None, None),
        };
        let restarts = runtime::restarts();
        let mut episodes = match (&args.json, restarts) {
            (Some(path), n) if n > 0 && path.exists() => {
                let text = std::fs::read_to_string(path)
                    .with_context(|| format!("reading {}", path.display()))?;
                let record: RunRecord = serde_json::from_str(&text)
                    .with_context(|| format!("{} is not a run record", path.display()))?;
                tracing::info!(path = %path.display(), episodes = record.episodes, restarts = n, "restarted: resuming the run's record");
                Episodes::resume(&record)
            }
            _ => Episodes::new(),
        };
        // Reports are judged by order within their epoch alone (as untimed stamps): one comes per
        // trial, so its age says little, and a producer whose clock is behind (a camera restarted
        // with its time base stepped back) cannot show its pace before its next trial; timed,
        // every report of that epoch would be refused. A forged `seq` in the live epoch is still
        // refused: the jump is bounded (`screen::MAX_UNTIMED_JUMP` steps, many trials).
        let limits = ScreenLimits::control(rt.scenario().timing.sample_time_s);
        let untimed = |s: &messages::Stamp| messages::Stamp { clock_ns: 0, ..*s };
        let floors = inboxes
            .each_ref()
            .map(|(dof, _)| monitor::ReturnFloor::of(*dof, rt.scenario(), rt.learning()));
        let mut screens = inboxes
            .each_ref()
            .map(|(_, inbox)| Screen::new(inbox.service(), limits));
        let mut refused = Tally::default();
        let clock = *rt.clock();
        let linger = Duration::from_secs_f64(args.linger_s.max(0.0));
        let mut lingering: Option<Instant> = None;
        let start = Instant::now();
        let mut listeners = vec![inboxes[0].1.listener(), inboxes[1].1.listener()];
        if let Some(observations) = &trace_in {
            listeners.push(observations.listener());
        }
        cli::outln!(
            "episode | steps | lost | eval |  yaw return | sway return | yaw K              | sway K"
        )?;
        let sample_time = rt.scenario().timing.sample_time_s;
        // The run record replaces itself whole after every episode (`durable::replace`), so a
        // SIGKILL or a power cut leaves the last episode's record, never a torn one. A write that
        // fails (a full disk) is said once, and the run goes on: the next episode tries again.
        let mut outage = durable::Outage::default();
        let mut write = |episodes: &Episodes| -> anyhow::Result<()> {
            let Some(path) = &args.json else {
                return Ok(());
            };
            let record = episodes.record(start.elapsed().as_secs_f64());
            let json = serde_json::to_vec(&record)?;
            match durable::replace(path, &json) {
                Ok(()) => {
                    if let Some(failed) = outage.succeeded() {
                        tracing::info!(path = %path.display(), failed, "the run record is written again");
                    }
                }
                Err(e) => {
                    if outage.failed() {
                        let full = if e.is_disk_full() {
                            " (the disk is full)"
                        } else {
                            ""
                        };
                        tracing::error!(
                            "the run record is not written{full}: {:#}; the run goes on, each episode tries again, {} keeps the last record written",
                            anyhow::Error::from(e),
                            path.display()
                        );
                    }
                }
            }
            Ok(())
        };
        // Its inboxes are open: where it is an observer (the sim mesh, whose loop can run all its
        // episodes in less time than a process takes to start), the loop starts now, so no report
        // goes by before it listens.
        rt.ready();
        let mut trace_failed = false;
        rt.serve(&listeners, Timer::Timeout(Duration::from_secs(1)), |_| {
            if let (Some(observations), Some(out)) = (&trace_in, &mut trace_out) {
                let mut written = Ok(());
                for o in observations.drain()? {
                    let line = TracePoint::new(&o, sample_time);
                    written = written
                        .and_then(|()| serde_json::to_writer(&mut *out, &line).map_err(std::io::Error::from))
                        .and_then(|()| out.write_all(b"\n"));
                }
                if let Err(e) = written {
                    // A full disk ends the trace, not the run (nor the run record).
                    tracing::error!(path = ?args.trace, "the trace stops here: {e}");
                    trace_failed = true;
                }
            }
            if trace_failed {
                trace_out = None;
            }
            for (((dof, inbox), screen), floor) in inboxes.iter().zip(&mut screens).zip(&floors) {
                for stats in inbox.drain()? {
                    let now = clock.now_ns();
                    let stamp = untimed(&stats.stamp);
                    match screen.check(&stamp, now) {
                        Verdict::New => {}
                        Verdict::Repeat | Verdict::Refused(_) => continue,
                    }
                    if let Err(why) = monitor::check(&stats, floor) {
                        if let Some(earlier) = refused.count(now) {
                            tracing::warn!(dof = %dof, episode = stats.stamp.episode, earlier_unlogged = earlier, total = refused.total(), "report refused: {why}");
                        }
                        continue;
                    }
                    screen.accept(&stamp, now);
                    if let Some(r) = episodes.add(*dof, stats) {
                        cli::outln!(
                            "{:7} | {:5} | {:4} | {:4} | {:11.3} | {:11.4} | [{:7.3}, {:7.3}] | [{:7.3}, {:7.3}]",
                            r.episode, r.steps, if r.lost { "yes" } else { "" }, if r.evaluation { "yes" } else { "" },
                            r.yaw, r.sway, r.yaw_gain[0], r.yaw_gain[1], r.sway_gain[0], r.sway_gain[1]
                        )?;
                        write(&episodes)?;
                    }
                }
            }
            if args.episodes == 0 {
                return Ok(Flow::Continue);
            }
            if episodes.pending_from(args.episodes - 1) {
                lingering.get_or_insert_with(Instant::now);
            }
            if episodes.finished(args.episodes, lingering.map(|t| t.elapsed()), linger) {
                return Ok(Flow::Stop);
            }
            Ok(Flow::Continue)
        })?;
        if let Some(out) = &mut trace_out
            && let Err(e) = out.flush()
        {
            tracing::error!(path = ?args.trace, "the trace's end is not written: {e}");
        }
        let record = episodes.record(start.elapsed().as_secs_f64());
        let gaps = episodes.gaps();
        if !gaps.is_empty() {
            tracing::warn!(episodes = ?gaps, "episodes without a record: their reports were lost");
        }
        tracing::info!(
            episodes = record.episodes,
            steps = record.steps,
            wall_s = record.wall_s,
            "run recorded"
        );
        write(&episodes)?;
        if let Some(path) = &args.json {
            tracing::info!("wrote {}", path.display());
        }
        Ok(())
    })
}
