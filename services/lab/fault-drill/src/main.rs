//! `fault-drill`: the fault drill of the vehicle's safety layer (see the library's docs).
//! `scripts/fault-drill` builds and runs it.

use anyhow::Result;
use clap::Parser;
use fault_drill::DrillSetup;
use mesh_bench::runs::VehicleRunSetup;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    version,
    about = "The fault drill of the vehicle's safety layer: kills, stalls, a second allocator, a camera with its clock stepped back and a rogue publisher, in one run of the vehicle mesh against the twin at 5 Hz."
)]
struct Args {
    /// Random SIGKILLs across the vehicle services.
    #[arg(long, default_value_t = 100)]
    kills: u32,
    /// Seed of the random choices and of the mesh.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Step one's episodes in simulation, before the vehicle run (the drill needs a policy, not a
    /// good one).
    #[arg(long, default_value_t = 10)]
    sim_episodes: u32,
    #[command(flatten)]
    files: mesh_bench::runs::VehicleFiles,
    /// Write the figures here as JSON (and the vehicle mesh's log beside it, as .log).
    #[arg(long)]
    json: Option<PathBuf>,
}

fn main() -> ExitCode {
    let args = Args::parse();
    runtime::init_tracing();
    match drill(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => cli::fail("fault-drill", err.as_ref()),
    }
}

fn drill(args: &Args) -> Result<()> {
    let run = VehicleRunSetup::new(&args.files, args.seed, args.sim_episodes)?;
    let setup = DrillSetup {
        period_s: run.scenario()?.timing.sample_time_s,
        run,
        kills: args.kills,
        keep_log: args.json.as_ref().map(|j| j.with_extension("log")),
    };
    let run = fault_drill::run(&setup)?;
    cli::outln!("{}", serde_json::to_string_pretty(&run)?)?;
    mesh_bench::report::publish(
        "fault-drill",
        &run,
        &run.markdown(),
        args.json.as_deref(),
        None,
    )
}
