//! `flight-figure`: a dive at a glance from its flight record, as PNG (see `recorder::figure`).

use anyhow::Context;
use clap::Parser;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    version,
    about = "Draws a flight record as PNG: a camera frame with the cable perception found, and x_g, Theta, the commands and the thruster setpoints against time."
)]
struct Args {
    /// The flight record (its first part; the others are found beside it).
    record: PathBuf,
    /// The PNG to write.
    #[arg(long, value_name = "FILE.png")]
    out: PathBuf,
    /// Show the recorded frame nearest this many seconds after the first (default: the middle).
    #[arg(long, value_name = "S")]
    at: Option<f64>,
}

fn main() -> ExitCode {
    let args = Args::parse();
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => cli::fail("flight-figure", err.as_ref()),
    }
}

fn run(args: &Args) -> anyhow::Result<()> {
    let dive = recorder::figure::dive(&args.record, args.at)?;
    dive.figure
        .save_png(&args.out)
        .with_context(|| format!("drawing {}", args.record.display()))?;
    match dive.frame {
        Some((seq, trial, step, t)) => cli::outln!(
            "flight-figure: wrote {} ({} steps; the frame of step seq {seq}, trial {trial}, step {step}, {t:.1} s)",
            args.out.display(),
            dive.steps
        )?,
        None => cli::outln!(
            "flight-figure: wrote {} ({} steps; the record has no image)",
            args.out.display(),
            dive.steps
        )?,
    }
    Ok(())
}
