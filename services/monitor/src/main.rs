//! `monitor`: prints each episode's returns as the mesh learns, and writes the run's record.

use clap::Parser;
use config::Dof;
use messages::topics;
use monitor::Episodes;
use runtime::{CommonArgs, Flow, Timer};
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
    /// Write {"episodes","yaw","sway","steps","wall_s","lost"} here when stopping.
    #[arg(long)]
    json: Option<PathBuf>,
}

fn main() -> ExitCode {
    let args = Args::parse();
    runtime::run("monitor", &args.common, |rt| {
        let inboxes = [
            (Dof::Sway, rt.inbox(&topics::SWAY_LEARNING)?),
            (Dof::Yaw, rt.inbox(&topics::YAW_LEARNING)?),
        ];
        let mut episodes = Episodes::new();
        let start = Instant::now();
        let listeners = [inboxes[0].1.listener(), inboxes[1].1.listener()];
        println!(
            "episode | steps | lost |  yaw return | sway return | yaw K              | sway K"
        );
        rt.serve(&listeners, Timer::Timeout(Duration::from_secs(10)), |_| {
            for (dof, inbox) in &inboxes {
                for stats in inbox.drain()? {
                    if let Some(r) = episodes.add(*dof, stats) {
                        println!(
                            "{:7} | {:5} | {:4} | {:11.3} | {:11.4} | [{:7.3}, {:7.3}] | [{:7.3}, {:7.3}]",
                            r.episode, r.steps, if r.lost { "yes" } else { "" }, r.yaw, r.sway, r.yaw_gain[0], r.yaw_gain[1], r.sway_gain[0], r.sway_gain[1]
                        );
                    }
                }
            }
            let done = episodes.done().len();
            Ok(if args.episodes > 0 && done >= args.episodes { Flow::Stop } else { Flow::Continue })
        })?;
        let record = episodes.record(start.elapsed().as_secs_f64());
        tracing::info!(
            episodes = record.episodes,
            steps = record.steps,
            wall_s = record.wall_s,
            "run recorded"
        );
        if let Some(path) = &args.json {
            let tmp = path.with_extension("json.tmp");
            std::fs::write(&tmp, serde_json::to_string(&record)?)?;
            std::fs::rename(&tmp, path)?;
            tracing::info!("wrote {}", path.display());
        }
        Ok(())
    })
}
