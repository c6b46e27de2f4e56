//! `monitor`: prints each episode's returns as the mesh learns, and writes the run's record.

use anyhow::Context;
use clap::Parser;
use config::Dof;
use messages::topics;
use monitor::{Episodes, TracePoint};
use runtime::{CommonArgs, Flow, Timer};
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
    /// Stop after this many episodes (0: until SIGTERM).
    #[arg(long, default_value_t = 0)]
    episodes: usize,
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
        let mut episodes = Episodes::new();
        let start = Instant::now();
        let mut listeners = vec![inboxes[0].1.listener(), inboxes[1].1.listener()];
        if let Some(observations) = &trace_in {
            listeners.push(observations.listener());
        }
        cli::outln!(
            "episode | steps | lost | eval |  yaw return | sway return | yaw K              | sway K"
        )?;
        let sample_time = rt.scenario().timing.sample_time_s;
        rt.serve(&listeners, Timer::Timeout(Duration::from_secs(10)), |_| {
            if let (Some(observations), Some(out)) = (&trace_in, &mut trace_out) {
                for o in observations.drain()? {
                    let line = TracePoint::new(&o, sample_time);
                    serde_json::to_writer(&mut *out, &line)?;
                    out.write_all(b"\n")?;
                }
            }
            for (dof, inbox) in &inboxes {
                for stats in inbox.drain()? {
                    if let Some(r) = episodes.add(*dof, stats) {
                        cli::outln!(
                            "{:7} | {:5} | {:4} | {:4} | {:11.3} | {:11.4} | [{:7.3}, {:7.3}] | [{:7.3}, {:7.3}]",
                            r.episode, r.steps, if r.lost { "yes" } else { "" }, if r.evaluation { "yes" } else { "" },
                            r.yaw, r.sway, r.yaw_gain[0], r.yaw_gain[1], r.sway_gain[0], r.sway_gain[1]
                        )?;
                    }
                }
            }
            let done = episodes.done().len();
            Ok(if args.episodes > 0 && done >= args.episodes { Flow::Stop } else { Flow::Continue })
        })?;
        if let Some(out) = &mut trace_out {
            out.flush()?;
        }
        let record = episodes.record(start.elapsed().as_secs_f64());
        tracing::info!(
            episodes = record.episodes,
            steps = record.steps,
            wall_s = record.wall_s,
            "run recorded"
        );
        if let Some(path) = &args.json {
            let tmp = path.with_extension("json.tmp");
            std::fs::write(&tmp, serde_json::to_string(&record)?)
                .with_context(|| format!("writing {}", tmp.display()))?;
            std::fs::rename(&tmp, path)
                .with_context(|| format!("renaming {} to {}", tmp.display(), path.display()))?;
            tracing::info!("wrote {}", path.display());
        }
        Ok(())
    })
}
