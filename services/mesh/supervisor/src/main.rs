//! `supervisor`: runs a mesh of services from a file in `config/`. Starts every service, restarts one
//! that dies (after removing its iceoryx2 leftovers, with backoff and a limit) when the file says so,
//! stops when the services named in `stop_when` are done, and on SIGINT/SIGTERM stops them all at
//! once: SIGTERM to each, a grace period, then SIGKILL (`runtime::process`). Every start, exit and
//! restart is logged.

use anyhow::{Context, Result, bail};
use clap::Parser;
use runtime::process::{self, Child, Spawn};
use std::collections::BTreeMap;
use std::os::fd::AsRawFd;
use std::os::unix::net::UnixStream;
use std::path::PathBuf;
use std::process::{ExitCode, ExitStatus};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};
use supervisor::{MeshFile, ServiceCommand};

#[derive(Parser)]
#[command(
    version,
    about = "Runs a mesh of cabletrack services described by a file in config/."
)]
struct Args {
    /// The mesh file (e.g. config/sim-mesh.toml).
    #[arg(long)]
    mesh: PathBuf,
    /// A placeholder's value in the mesh file, KEY=VALUE (repeatable).
    #[arg(long = "set", value_parser = parse_key_value)]
    set: Vec<(String, String)>,
    /// Where the service programs are (default: beside this one).
    #[arg(long)]
    bin_dir: Option<PathBuf>,
    /// Seconds services get to stop after SIGTERM before SIGKILL.
    #[arg(long, default_value_t = 10.0)]
    stop_timeout_s: f64,
    /// The configuration directory, passed to every service.
    #[arg(long, default_value = "config", env = "CABLETRACK_CONFIG")]
    config: PathBuf,
    /// The experiment's seed, passed to every service (and as `{seed}`).
    #[arg(long, default_value_t = 1, env = "CABLETRACK_SEED")]
    seed: u64,
    #[command(flatten)]
    iox: runtime::IoxSettings,
}

fn parse_key_value(s: &str) -> Result<(String, String), String> {
    s.split_once('=')
        .map(|(k, v)| (k.to_owned(), v.to_owned()))
        .ok_or_else(|| format!("`{s}` is not KEY=VALUE"))
}

fn main() -> ExitCode {
    runtime::init_tracing();
    let span = tracing::info_span!("supervisor");
    let _entered = span.enter();
    match run(Args::parse()) {
        Ok(code) => code,
        Err(err) => {
            tracing::error!("{err:#}");
            cli::fail("supervisor", err.as_ref())
        }
    }
}

/// A service's place in the mesh.
enum State {
    Running {
        child: Child,
        since: Instant,
    },
    /// Dead; restarts at this time.
    Restarting {
        at: Instant,
    },
    /// Exited and not to be restarted.
    Exited(ExitStatus),
}

struct Service {
    cmd: ServiceCommand,
    program: PathBuf,
    state: State,
    /// When it was restarted.
    restarts: Vec<Instant>,
}

/// Wakes the supervisor's poll on SIGCHLD, SIGINT and SIGTERM.
struct Signals {
    wake: UnixStream,
    stop: Arc<AtomicBool>,
}

impl Signals {
    fn install() -> Result<Signals> {
        let (wake, write) = UnixStream::pair()?;
        wake.set_nonblocking(true)?;
        let stop = Arc::new(AtomicBool::new(false));
        for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
            signal_hook::flag::register(sig, Arc::clone(&stop))?;
            signal_hook::low_level::pipe::register(sig, write.try_clone()?)?;
        }
        signal_hook::low_level::pipe::register(signal_hook::consts::SIGCHLD, write)?;
        Ok(Signals { wake, stop })
    }

    /// Blocks until a signal arrives or `timeout` passes (`None`: no timeout).
    fn wait(&self, timeout: Option<Duration>) {
        let mut fd = libc::pollfd {
            fd: self.wake.as_raw_fd(),
            events: libc::POLLIN,
            revents: 0,
        };
        let ms = timeout.map_or(-1, |t| t.as_millis().min(i32::MAX as u128) as i32);
        // SAFETY: one valid pollfd; EINTR just returns early.
        unsafe {
            libc::poll(&mut fd, 1, ms);
        }
        let mut buf = [0u8; 64];
        while std::io::Read::read(&mut &self.wake, &mut buf).is_ok_and(|n| n > 0) {}
    }

    fn stop_requested(&self) -> bool {
        self.stop.load(Ordering::Relaxed)
    }
}

fn run(args: Args) -> Result<ExitCode> {
    let mesh = MeshFile::load(&args.mesh)?;
    let mut vars: BTreeMap<String, String> = args.set.iter().cloned().collect();
    vars.entry("seed".into())
        .or_insert_with(|| args.seed.to_string());
    let commands = mesh.commands(&vars, &args.mesh)?;
    let bin_dir = match &args.bin_dir {
        Some(d) => d.clone(),
        None => std::env::current_exe()?
            .parent()
            .context("the supervisor's directory")?
            .to_owned(),
    };
    let config_dir = args
        .config
        .canonicalize()
        .with_context(|| format!("config directory {}", args.config.display()))?;
    let iox = args.iox.config()?;
    let signals = Signals::install()?;

    let env = [
        ("CABLETRACK_CONFIG", config_dir.display().to_string()),
        ("CABLETRACK_SEED", args.seed.to_string()),
        ("CABLETRACK_IOX_PREFIX", args.iox.prefix.clone()),
        ("CABLETRACK_IOX_ROOT", args.iox.root.clone()),
    ];
    let mut services = Vec::new();
    for cmd in commands {
        let program = bin_dir.join(&cmd.binary);
        if !program.exists() {
            bail!(
                "service `{}`: {} does not exist (build with cargo build --release)",
                cmd.name,
                program.display()
            );
        }
        services.push(Service {
            cmd,
            program,
            state: State::Restarting { at: Instant::now() },
            restarts: Vec::new(),
        });
    }
    tracing::info!(mesh = %args.mesh.display(), services = services.len(), "starting the mesh");
    let stop_when = mesh.mesh.stop_when.clone();
    let restart = mesh.restart.clone();

    let outcome = loop {
        // Start what is due.
        let now = Instant::now();
        for s in &mut services {
            if let State::Restarting { at } = s.state
                && at <= now
            {
                let child = Spawn::new(&s.program)
                    .name(&s.cmd.name)
                    .args(&s.cmd.args)
                    .envs(env.iter().map(|(k, v)| (k, v)))
                    // A restarted service may carry on from what it wrote (the monitor's record).
                    .env(runtime::RESTARTS_ENV, s.restarts.len().to_string())
                    // If the supervisor itself is killed, its services get SIGTERM instead of
                    // running on as orphans.
                    .die_with_parent()
                    .start()
                    .with_context(|| format!("starting `{}`", s.cmd.name))?;
                tracing::info!(service = %s.cmd.name, pid = child.started_pid(), args = ?s.cmd.args, "started");
                s.state = State::Running { child, since: now };
            }
        }
        if signals.stop_requested() {
            tracing::info!("termination requested: stopping the mesh");
            break Ok(());
        }
        // Reap and decide.
        let mut failure = None;
        for s in &mut services {
            let State::Running { child, since } = &mut s.state else {
                continue;
            };
            let Some(status) = child.try_status() else {
                continue;
            };
            let ran = since.elapsed().as_secs_f64();
            if status.success() {
                tracing::info!(service = %s.cmd.name, ran_s = ran, "exited");
                s.state = State::Exited(status);
                continue;
            }
            tracing::warn!(service = %s.cmd.name, %status, ran_s = ran, "died");
            let recent: Vec<f64> = s
                .restarts
                .iter()
                .map(|t| t.elapsed().as_secs_f64())
                .collect();
            match s.cmd.restart.then(|| restart.next_delay(&recent)).flatten() {
                Some(delay) => {
                    let cleaned = runtime::remove_dead_nodes(&iox);
                    tracing::info!(service = %s.cmd.name, delay_ms = delay.as_millis() as u64, cleaned, "restarting");
                    s.restarts.push(Instant::now() + delay);
                    s.state = State::Restarting {
                        at: Instant::now() + delay,
                    };
                }
                None => {
                    s.state = State::Exited(status);
                    failure = Some(format!(
                        "service `{}` died ({status}) and is not restarted",
                        s.cmd.name
                    ));
                }
            }
        }
        if let Some(why) = failure {
            break Err(why);
        }
        let done = |name: &String| {
            services.iter().any(|s| {
                &s.cmd.name == name && matches!(s.state, State::Exited(st) if st.success())
            })
        };
        if !stop_when.is_empty() && stop_when.iter().all(done) {
            tracing::info!(services = ?stop_when, "the mesh has done its job: stopping it");
            break Ok(());
        }
        // Sleep until a signal (a child's exit included) or the next restart.
        let next = services
            .iter()
            .filter_map(|s| match s.state {
                State::Restarting { at } => Some(at.saturating_duration_since(Instant::now())),
                _ => None,
            })
            .min();
        signals.wait(next);
    };

    stop_all(&mut services, Duration::from_secs_f64(args.stop_timeout_s));
    let cleaned = runtime::remove_dead_nodes(&iox);
    if cleaned > 0 {
        tracing::warn!(
            cleaned,
            "removed the leftovers of processes that had to be killed"
        );
    }
    match outcome {
        Ok(()) => {
            tracing::info!("mesh stopped");
            Ok(ExitCode::SUCCESS)
        }
        Err(why) => {
            tracing::error!("{why}");
            Ok(ExitCode::FAILURE)
        }
    }
}

/// SIGTERM to every running service, up to `grace` for them to exit, SIGKILL for the rest.
fn stop_all(services: &mut [Service], grace: Duration) {
    let mut running: Vec<(&str, &mut Child)> = services
        .iter_mut()
        .filter_map(|s| match &mut s.state {
            State::Running { child, .. } => Some((s.cmd.name.as_str(), child)),
            _ => None,
        })
        .collect();
    let mut children: Vec<&mut Child> = running.iter_mut().map(|(_, c)| &mut **c).collect();
    let stopped = process::stop_all(&mut children, grace);
    for ((name, _), s) in running.iter().zip(stopped) {
        if s.killed {
            tracing::warn!(service = %name, "did not stop in time: killed");
        } else {
            tracing::info!(service = %name, status = %s.status, "stopped");
        }
    }
}
