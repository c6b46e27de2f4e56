//! `vision`: render camera frames, find the cable in images, make data sets.
//!
//! - `vision render --pose X,Y,PSI --out FILE`: the frame seen from a pose (pool frame, PSI in degrees).
//! - `vision detect FILE_OR_DIR...`: one JSON line per image with the cable found in it.
//! - `vision dataset --n N --out DIR`: rendered frames with the geometric camera's ground truth.
//!
//! Output stops quietly when its reader goes away (`vision detect DIR | head -3`: see `cli`).

use clap::{Args, Parser, Subcommand};
use config::{CameraParams, RenderParams, Scenario};
use model::{Pose, VehicleState, Velocity};
use serde::Serialize;
use serde_json::{Value, json};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;
use vision::sampling::PoseSampler;
use vision::{Frame, Perception, Renderer};

#[derive(Parser)]
#[command(
    name = "vision",
    about = "Camera frames of the pool floor and the cable found in them"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Write the frame the camera sees from a pose.
    Render(RenderArgs),
    /// Find the cable in PGM/PNG images; prints one JSON line per image.
    Detect(DetectArgs),
    /// Write rendered frames with ground truth (truth.jsonl) for checking detectors.
    Dataset(DatasetArgs),
}

#[derive(Args)]
struct ScenarioArg {
    /// The scenario file (camera, cable, [render], [perception]); the defaults without it.
    #[arg(long)]
    scenario: Option<PathBuf>,
}

impl ScenarioArg {
    fn load(&self) -> Fallible<Scenario> {
        Ok(match &self.scenario {
            Some(path) => config::load(path)?,
            None => Scenario::default(),
        })
    }
}

#[derive(Args)]
struct RenderArgs {
    /// Vehicle pose in the pool frame: x (m), y (m), heading psi (degrees, from x towards y).
    #[arg(long, value_parser = triple, allow_hyphen_values = true)]
    pose: [f64; 3],
    /// Body velocity for motion blur: surge u (m/s), sway v (m/s), yaw rate r (degrees/s).
    #[arg(long, value_parser = triple, allow_hyphen_values = true, default_value = "0,0,0")]
    velocity: [f64; 3],
    /// Seed of the floor, clutter and noise.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Frame index (selects the noise).
    #[arg(long, default_value_t = 0)]
    frame: u64,
    /// Every effect off: uniform floor and the cable.
    #[arg(long)]
    clean: bool,
    /// Output file, .pgm or .png.
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    scenario: ScenarioArg,
}

#[derive(Args)]
struct DetectArgs {
    /// Image files, or directories whose .pgm/.png files are taken in name order.
    #[arg(required = true)]
    inputs: Vec<PathBuf>,
    /// Track from image to image in the given order (default: each image on its own).
    #[arg(long)]
    track: bool,
    /// Seconds between images when tracking (default: the scenario's sample time).
    #[arg(long)]
    dt: Option<f64>,
    /// Print the time spent in perception (files already read) to stderr as JSON.
    #[arg(long)]
    timing: bool,
    #[command(flatten)]
    scenario: ScenarioArg,
}

#[derive(Args)]
struct DatasetArgs {
    /// Number of frames.
    #[arg(long)]
    n: usize,
    /// Output directory (created).
    #[arg(long)]
    out: PathBuf,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Every effect off.
    #[arg(long)]
    clean: bool,
    /// Poses from which the cable is out of view (for false-positive rates).
    #[arg(long)]
    no_cable: bool,
    /// Image format: pgm or png.
    #[arg(long, default_value = "pgm")]
    format: String,
    #[command(flatten)]
    scenario: ScenarioArg,
}

fn triple(s: &str) -> Result<[f64; 3], String> {
    let parts: Vec<&str> = s.split(',').collect();
    if parts.len() != 3 {
        return Err(format!("expected three comma-separated numbers, got `{s}`"));
    }
    let mut out = [0.0f64; 3];
    for (o, p) in out.iter_mut().zip(parts) {
        *o = p
            .trim()
            .parse()
            .map_err(|_| format!("`{p}` is not a number"))?;
        if !o.is_finite() {
            return Err(format!("`{p}` is not a finite number"));
        }
    }
    Ok(out)
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Render(a) => render(a),
        Command::Detect(a) => detect(a),
        Command::Dataset(a) => dataset(a),
    };
    match result {
        Ok(code) => code,
        Err(e) => cli::fail("vision", e.as_ref()),
    }
}

type Fallible<T> = Result<T, Box<dyn std::error::Error>>;

fn truth_json(scenario: &Scenario, pose: &Pose) -> Value {
    let camera = model::Camera::new(&scenario.camera);
    let cable = model::Cable::new(&scenario.cable);
    match camera.view(pose, &cable) {
        Some(l) => {
            json!({"in_view": true, "rho": l.rho, "theta": l.theta, "x_g": l.x_g, "y_g": l.y_g})
        }
        None => json!({"in_view": false, "rho": null, "theta": null, "x_g": null, "y_g": null}),
    }
}

fn render(a: RenderArgs) -> Fallible<ExitCode> {
    let scenario = a.scenario.load()?;
    let params = if a.clean {
        RenderParams::clean()
    } else {
        scenario.render.clone()
    };
    let mut renderer = Renderer::new(&params, &scenario.camera, &scenario.cable, a.seed)?;
    let pose = Pose {
        x: a.pose[0],
        y: a.pose[1],
        psi: a.pose[2].to_radians(),
    };
    let state = VehicleState {
        pose,
        velocity: Velocity {
            u: a.velocity[0],
            v: a.velocity[1],
            r: a.velocity[2].to_radians(),
        },
    };
    let frame = renderer.render_frame(&pose, &state.pose_rate(), a.frame);
    frame.write(&a.out)?;
    let mut truth = truth_json(&scenario, &pose);
    truth["file"] = json!(a.out.display().to_string());
    cli::outln!("{truth}")?;
    Ok(ExitCode::SUCCESS)
}

/// The image files of the inputs: files as given, directories' .pgm/.png files in name order.
fn image_files(inputs: &[PathBuf]) -> Fallible<Vec<PathBuf>> {
    let mut files = Vec::new();
    for input in inputs {
        if input.is_dir() {
            let mut found: Vec<PathBuf> = std::fs::read_dir(input)
                .map_err(|e| format!("cannot list {}: {e}", input.display()))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| {
                    let ext = p
                        .extension()
                        .and_then(|e| e.to_str())
                        .map(str::to_ascii_lowercase);
                    p.is_file() && matches!(ext.as_deref(), Some("pgm") | Some("png"))
                })
                .collect();
            found.sort();
            files.extend(found);
        } else {
            files.push(input.clone());
        }
    }
    Ok(files)
}

/// One line of `vision detect`'s output, in this key order.
#[derive(Default, Serialize)]
struct DetectLine<'a> {
    file: &'a str,
    found: bool,
    rho: Option<f64>,
    theta: Option<f64>,
    x_g: Option<f64>,
    y_g: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    confidence: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    x_g_rate: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    theta_rate: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    error: Option<String>,
}

fn detect(a: DetectArgs) -> Fallible<ExitCode> {
    let scenario = a.scenario.load()?;
    let dt = a.dt.unwrap_or(scenario.timing.sample_time_s);
    let files = image_files(&a.inputs)?;
    // One tracker per image size: images from another camera keep the field of view, not the size.
    let mut trackers: HashMap<(usize, usize), Perception> = HashMap::new();
    let mut failures = 0usize;
    let mut seconds = 0.0;
    let mut frames = 0usize;
    for file in &files {
        let name = file.display().to_string();
        let frame = match Frame::read(file) {
            Ok(f) => f,
            Err(e) => {
                failures += 1;
                let line = DetectLine {
                    file: &name,
                    error: Some(cli::chain(&e)),
                    ..DetectLine::default()
                };
                cli::outln!("{}", serde_json::to_string(&line)?)?;
                continue;
            }
        };
        let size = (frame.width(), frame.height());
        if !trackers.contains_key(&size) {
            let camera = CameraParams {
                width: size.0 as u32,
                height: size.1 as u32,
                ..scenario.camera.clone()
            };
            let p = Perception::new(
                &scenario.perception,
                &camera,
                &scenario.cable,
                &scenario.observation,
            )?;
            if a.track {
                // A change of size ends the track.
                trackers.clear();
            }
            trackers.insert(size, p);
        }
        let perception = trackers.get_mut(&size).expect("inserted above");
        if !a.track {
            perception.reset();
        }
        let start = Instant::now();
        let obs = perception.process(frame.view(), dt)?;
        seconds += start.elapsed().as_secs_f64();
        frames += 1;
        let found = obs.found.then_some(obs);
        let line = DetectLine {
            file: &name,
            found: obs.found,
            rho: found.map(|o| o.rho),
            theta: found.map(|o| o.theta),
            x_g: found.map(|o| o.x_g),
            y_g: found.map(|o| o.y_g),
            confidence: Some(obs.confidence),
            x_g_rate: a.track.then_some(obs.x_g_rate),
            theta_rate: a.track.then_some(obs.theta_rate),
            error: None,
        };
        cli::outln!("{}", serde_json::to_string(&line)?)?;
    }
    if a.timing {
        let fps = if seconds > 0.0 {
            frames as f64 / seconds
        } else {
            0.0
        };
        eprintln!(
            "{}",
            json!({"frames": frames, "seconds": seconds, "frames_per_s": fps})
        );
    }
    if failures > 0 {
        eprintln!(
            "vision: {failures} of {} files could not be read",
            files.len()
        );
        return Ok(ExitCode::FAILURE);
    }
    Ok(ExitCode::SUCCESS)
}

fn dataset(a: DatasetArgs) -> Fallible<ExitCode> {
    let scenario = a.scenario.load()?;
    let ext = match a.format.as_str() {
        "pgm" | "png" => a.format.as_str(),
        other => return Err(format!("--format must be pgm or png, not `{other}`").into()),
    };
    let params = if a.clean {
        RenderParams::clean()
    } else {
        scenario.render.clone()
    };
    let mut renderer = Renderer::new(&params, &scenario.camera, &scenario.cable, a.seed)?;
    let camera = renderer.camera().clone();
    let cable = *renderer.cable();
    let mut sampler = PoseSampler::new(config::derive_seed(a.seed, "dataset-poses"));
    std::fs::create_dir_all(&a.out)
        .map_err(|e| format!("cannot create {}: {e}", a.out.display()))?;
    let mut truth = String::new();
    for k in 0..a.n {
        let s = if a.no_cable {
            sampler.without_cable(&camera, &cable, 1.0)
        } else {
            sampler.with_cable(&camera, &cable)
        };
        let frame = renderer.render_frame(&s.pose, &s.rate, k as u64);
        let name = format!("frame_{k:05}.{ext}");
        frame.write(&a.out.join(&name))?;
        let mut line = truth_json(&scenario, &s.pose);
        line["file"] = json!(name);
        line["pose"] = json!({"x": s.pose.x, "y": s.pose.y, "psi": s.pose.psi});
        line["velocity"] = json!({"u": s.velocity.u, "v": s.velocity.v, "r": s.velocity.r});
        truth.push_str(&line.to_string());
        truth.push('\n');
    }
    let path: &Path = &a.out.join("truth.jsonl");
    std::fs::write(path, truth).map_err(|e| format!("cannot write {}: {e}", path.display()))?;
    eprintln!("vision: wrote {} frames and {}", a.n, path.display());
    Ok(ExitCode::SUCCESS)
}
