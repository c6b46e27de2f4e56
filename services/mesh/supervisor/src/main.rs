//! `supervisor`: runs a mesh of services from a file in `config/`. Starts every service, restarts one
//! that dies (after removing its iceoryx2 leftovers, with backoff and a limit) when the file says so,
//! stops when the services named in `stop_when` are done, and on SIGINT/SIGTERM stops them all:
//! SIGTERM, a grace period, then SIGKILL. Every start, exit and restart is logged.

use anyhow::{Context, Result, bail};
use clap::Parser;
use std::collections::BTreeMap;
use std::os::fd::AsRawFd;
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitCode, ExitStatus};
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
            eprintln!("supervisor: error: {err:#}");
            ExitCode::FAILURE
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
                s.state = State::Running {
                    child: spawn(&s.program, &s.cmd.args, &env)
                        .with_context(|| format!("starting `{}`", s.cmd.name))?,
                    since: now,
                };
                if let State::Running { child, .. } = &s.state {
                    tracing::info!(service = %s.cmd.name, pid = child.id(), args = ?s.cmd.args, "started");
                }
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
            let Ok(Some(status)) = child.try_wait() else {
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

    stop_all(
        &mut services,
        &signals,
        Duration::from_secs_f64(args.stop_timeout_s),
    );
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

fn spawn(program: &Path, args: &[String], env: &[(&str, String)]) -> std::io::Result<Child> {
    use std::os::unix::process::CommandExt;
    let mut cmd = Command::new(program);
    cmd.args(args).envs(env.iter().map(|(k, v)| (k, v)));
    // SAFETY: prctl in the child before exec, async-signal-safe. If the supervisor itself is killed,
    // its services get SIGTERM instead of running on as orphans.
    unsafe {
        cmd.pre_exec(|| {
            libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM);
            Ok(())
        });
    }
    cmd.spawn()
}

/// SIGTERM to every running service, up to `grace` for them to exit, SIGKILL for the rest.
fn stop_all(services: &mut [Service], signals: &Signals, grace: Duration) {
    for s in services.iter() {
        if let State::Running { child, .. } = &s.state {
            // SAFETY: kill(2) on our own child.
            unsafe {
                libc::kill(child.id() as i32, libc::SIGTERM);
            }
        }
    }
    let end = Instant::now() + grace;
    loop {
        for s in services.iter_mut() {
            if let State::Running { child, .. } = &mut s.state
                && let Ok(Some(status)) = child.try_wait()
            {
                tracing::info!(service = %s.cmd.name, %status, "stopped");
                s.state = State::Exited(status);
            }
        }
        let running = services
            .iter()
            .filter(|s| matches!(s.state, State::Running { .. }))
            .count();
        let left = end.saturating_duration_since(Instant::now());
        if running == 0 {
            return;
        }
        if left.is_zero() {
            break;
        }
        signals.wait(Some(left));
    }
    for s in services.iter_mut() {
        if let State::Running { child, .. } = &mut s.state {
            tracing::warn!(service = %s.cmd.name, "did not stop in time: killing it");
            let _ = child.kill();
            if let Ok(status) = child.wait() {
                s.state = State::Exited(status);
            }
        }
    }
}
