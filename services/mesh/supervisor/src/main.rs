//! `supervisor`: runs a mesh of services from a file in `config/`. Starts every service (an observer
//! such as the flight recorder first, the others once it is ready), restarts one that dies (after
//! removing its iceoryx2 leftovers, with backoff and a limit) when the file says so, stops when the
//! services named in `stop_when` are done, and on SIGINT/SIGTERM stops them all: SIGTERM to each, a
//! grace period, then SIGKILL (`runtime::process`), the observers last. Every start, exit, restart
//! and stop is logged and published on the endpoint's `supervisor/events` topic.
//!
//! With `--own-namespace` the mesh runs in an iceoryx2 namespace of the run's own (a prefix and a
//! root no other run uses, `runtime::Namespace`), printed at start; when the run ends the supervisor
//! checks that its services left no shared memory behind (the run fails if they did) and removes
//! the namespace.

use anyhow::{Context, Result, bail};
use clap::Parser;
use iceoryx2::prelude::{Node, ipc};
use messages::{Endpoint, Outbox, ServiceEvent, SupervisorEvent, topics};
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

mod watch;

#[derive(Parser)]
#[command(
    version,
    about = "Runs a mesh of cabletrack services described by a file in config/."
)]
struct Args {
    #[command(flatten)]
    launch: runtime::MeshArgs,
    /// Where the service programs are (default: beside this one).
    #[arg(long)]
    bin_dir: Option<PathBuf>,
    /// Seconds services get to stop after SIGTERM before SIGKILL.
    #[arg(long, default_value_t = 10.0)]
    stop_timeout_s: f64,
    /// Seconds an observer (`observer = true`) gets to say it is ready before the mesh is given up.
    #[arg(long, default_value_t = 30.0)]
    ready_timeout_s: f64,
    /// Run in an iceoryx2 namespace of this run's own instead of --iox-prefix and --iox-root: a
    /// prefix and a root no other run uses, printed at start, removed when the run ends (the run
    /// fails if the services left shared memory behind).
    #[arg(long)]
    own_namespace: bool,
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
    /// The other end, for the health watch's wake-ups.
    write: UnixStream,
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
        signal_hook::low_level::pipe::register(signal_hook::consts::SIGCHLD, write.try_clone()?)?;
        write.set_nonblocking(true)?;
        Ok(Signals { wake, write, stop })
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

/// Publishes the supervisor's events; a failure to publish is logged once and never stops the mesh.
struct Events {
    outbox: Option<Outbox<SupervisorEvent>>,
    seq: u64,
    failed: bool,
}

impl Events {
    fn open(node: &Node<ipc::Service>, endpoint: Endpoint) -> Events {
        let outbox = match Outbox::open(node, endpoint, &topics::SUPERVISOR_EVENTS) {
            Ok(o) => Some(o),
            Err(e) => {
                tracing::warn!("the supervisor's events are not published: {e}");
                None
            }
        };
        Events {
            outbox,
            seq: 0,
            failed: false,
        }
    }

    fn send(&mut self, kind: ServiceEvent, service: &Service, pid: u32, status: i32, detail: u32) {
        let Some(outbox) = &self.outbox else {
            return;
        };
        self.seq += 1;
        let wall = runtime::clock::unix_ns();
        let mut event = SupervisorEvent::new(self.seq, wall, kind, &service.cmd.name);
        event.pid = pid;
        event.status = status;
        event.restarts = service.restarts.len() as u32;
        event.detail = detail;
        if let Err(e) = outbox.send(event)
            && !self.failed
        {
            self.failed = true;
            tracing::warn!("cannot publish the supervisor's events: {e}");
        }
    }
}

/// An exit status as an event carries it: the code, or minus the signal.
fn status_code(status: ExitStatus) -> i32 {
    use std::os::unix::process::ExitStatusExt;
    status
        .code()
        .or_else(|| status.signal().map(|s| -s))
        .unwrap_or(0)
}

/// Starts `s` now.
fn start(s: &mut Service, env: &[(&str, String)], ready_pipe: bool) -> Result<Child> {
    let mut spawn = Spawn::new(&s.program)
        .name(&s.cmd.name)
        .args(&s.cmd.args)
        .envs(env.iter().map(|(k, v)| (k, v)))
        // A restarted service may carry on from what it wrote (the monitor's record).
        .env(runtime::RESTARTS_ENV, s.restarts.len().to_string())
        // If the supervisor itself is killed, its services get SIGTERM instead of running on as
        // orphans.
        .die_with_parent()
        .placement(s.cmd.placement.clone());
    if ready_pipe {
        spawn = spawn.ready_pipe();
    }
    let child = spawn
        .start()
        .with_context(|| format!("starting `{}`", s.cmd.name))?;
    tracing::info!(service = %s.cmd.name, pid = child.started_pid(), args = ?s.cmd.args, "started");
    Ok(child)
}

fn run(args: Args) -> Result<ExitCode> {
    let mesh = MeshFile::load(&args.launch.mesh)?;
    let endpoint: Endpoint = mesh
        .mesh
        .endpoint
        .parse()
        .map_err(anyhow::Error::msg)
        .with_context(|| format!("{}: mesh.endpoint", args.launch.mesh.display()))?;
    let mut vars: BTreeMap<String, String> = args.launch.set.iter().cloned().collect();
    vars.entry("seed".into())
        .or_insert_with(|| args.launch.run.seed.to_string());
    let commands = mesh.commands(&vars, &args.launch.mesh)?;
    let bin_dir = match &args.bin_dir {
        Some(d) => d.clone(),
        None => std::env::current_exe()?
            .parent()
            .context("the supervisor's directory")?
            .to_owned(),
    };
    // Every program is there before anything starts.
    let programs = commands
        .iter()
        .map(|c| c.program(&bin_dir))
        .collect::<Result<Vec<_>, _>>()?;
    // Dropped last: removes the run's own namespace whichever way the run ends.
    let own = args.own_namespace.then(|| runtime::Namespace::new("mesh"));
    // What every service is given: the configuration (absolute: a service may run from elsewhere),
    // the seed, the namespace.
    let given = &args.launch.run;
    // A mesh that names its configuration (a BlueROV2's: its model and layout) runs on it.
    let config = mesh
        .config_dir(&args.launch.mesh)
        .unwrap_or_else(|| given.config.clone());
    let run = runtime::RunArgs {
        config: config
            .canonicalize()
            .with_context(|| format!("config directory {}", config.display()))?,
        seed: given.seed,
        iox: match &own {
            Some(ns) => {
                cli::outln!(
                    "supervisor: this run's own namespace: --iox-prefix {} --iox-root {}",
                    ns.iox.prefix,
                    ns.iox.root
                )?;
                ns.iox.clone()
            }
            None => given.iox.clone(),
        },
    };
    let iox = run.iox.config()?;
    let signals = Signals::install()?;
    let node = runtime::create_node("supervisor", &iox)?;
    let mut events = Events::open(&node, endpoint);

    let env = run.env();
    let mut services = Vec::new();
    for (cmd, program) in commands.into_iter().zip(programs) {
        services.push(Service {
            cmd,
            program,
            state: State::Restarting { at: Instant::now() },
            restarts: Vec::new(),
        });
    }
    let watch = watch::Watch::start(
        &iox,
        endpoint,
        services.iter().map(|s| s.cmd.name.clone()).collect(),
        signals.write.try_clone()?,
    )?;
    tracing::info!(mesh = %args.launch.mesh.display(), services = services.len(), "starting the mesh");
    let stop_when = mesh.mesh.stop_when.clone();
    let restart = mesh.restart.clone();

    // The observers first: the others start once each has said it is ready, so an observer sees
    // the mesh's first message.
    let ready_timeout = Duration::from_secs_f64(args.ready_timeout_s);
    for s in services.iter_mut().filter(|s| s.cmd.observer) {
        let mut child = start(s, &env, true)?;
        events.send(ServiceEvent::Started, s, child.started_pid(), 0, 0);
        if let Err(e) = child.wait_ready(ready_timeout) {
            let tail = child.tail(20);
            child.stop(Duration::from_secs_f64(args.stop_timeout_s));
            bail!("observer `{}`: {e}\n{tail}", s.cmd.name);
        }
        tracing::info!(service = %s.cmd.name, "ready");
        s.state = State::Running {
            child,
            since: Instant::now(),
        };
    }

    let outcome = loop {
        // Start what is due.
        let now = Instant::now();
        for s in &mut services {
            if let State::Restarting { at } = s.state
                && at <= now
            {
                let child = start(s, &env, false)?;
                events.send(ServiceEvent::Started, s, child.started_pid(), 0, 0);
                s.state = State::Running { child, since: now };
            }
        }
        if signals.stop_requested() {
            tracing::info!("termination requested: stopping the mesh");
            break Ok(());
        }
        if watch.stop_commanded() {
            tracing::info!("the shore commands a stop: stopping the mesh");
            break Ok(());
        }
        // Reap and decide.
        let mut failure = None;
        for (i, s) in services.iter_mut().enumerate() {
            let State::Running { child, since } = &mut s.state else {
                continue;
            };
            // A service whose end ends the run (the monitor: it counts the run's episodes) is not
            // replaced for a silent heartbeat (a loaded machine can hold it past two deadlines while
            // it writes): its successor would count from nothing and the run would never end.
            let replace = s.cmd.restart && !stop_when.contains(&s.cmd.name);
            let Some(status) = child.try_status().or_else(|| {
                stuck(&watch.pulse(i), *since, &iox, child.started_pid(), replace, s.cmd.observer).map(
                    |silent| {
                        tracing::warn!(service = %s.cmd.name, silent_ms = silent.as_millis() as u64, "alive but its heartbeat is silent: killing it");
                        child.kill()
                    },
                )
            }) else {
                continue;
            };
            let ran = since.elapsed().as_secs_f64();
            let pid = child.started_pid();
            events.send(ServiceEvent::Exited, s, pid, status_code(status), 0);
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
                    events.send(
                        ServiceEvent::Restarting,
                        s,
                        pid,
                        status_code(status),
                        delay.as_millis() as u32,
                    );
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

    // The observers last: they see the others' last messages and the events of their stop.
    let grace = Duration::from_secs_f64(args.stop_timeout_s);
    stop_all(&mut services, false, grace, &mut events);
    stop_all(&mut services, true, grace, &mut events);
    drop(events);
    drop(watch);
    drop(node);
    let cleaned = runtime::remove_dead_nodes(&iox);
    if cleaned > 0 {
        tracing::warn!(
            cleaned,
            "removed the leftovers of processes that had to be killed"
        );
    }
    // The services are gone: what is still there of the run's own namespace they left behind.
    let left = own.as_ref().map_or_else(Vec::new, |ns| ns.leftovers());
    let outcome = match outcome {
        Ok(()) if !left.is_empty() => Err(format!(
            "the services left shared-memory files behind: {left:?}"
        )),
        Err(why) if !left.is_empty() => {
            tracing::error!(files = ?left, "the services left shared-memory files behind");
            Err(why)
        }
        outcome => outcome,
    };
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

/// How long a service that is to be restarted has been silent, if it is stuck: it has beaten since it
/// started, then missed its heartbeat's deadline [`watch::STUCK_AFTER_MISSES`] times in a row
/// ([`watch::OBSERVER_STUCK_AFTER_MISSES`] for an observer), and its node is alive (a dead node's
/// exit is reaped as such).
fn stuck(
    pulse: &watch::Pulse,
    since: Instant,
    iox: &iceoryx2::config::Config,
    pid: u32,
    restart: bool,
    observer: bool,
) -> Option<Duration> {
    let last = pulse.last.filter(|&l| l > since)?;
    pulse.missed?;
    if !watch::silent_too_long(pulse.misses, observer) {
        return None;
    }
    (restart && watch::node_alive(iox, pid) != Some(false)).then(|| last.elapsed())
}

/// SIGTERM to every running service that is (or is not) an observer, up to `grace` for them to
/// exit, SIGKILL for the rest.
fn stop_all(services: &mut [Service], observers: bool, grace: Duration, events: &mut Events) {
    let mut running: Vec<(usize, &mut Child)> = services
        .iter_mut()
        .enumerate()
        .filter(|(_, s)| s.cmd.observer == observers)
        .filter_map(|(i, s)| match &mut s.state {
            State::Running { child, .. } => Some((i, child)),
            _ => None,
        })
        .collect();
    let pids: Vec<u32> = running.iter().map(|(_, c)| c.started_pid()).collect();
    let mut children: Vec<&mut Child> = running.iter_mut().map(|(_, c)| &mut **c).collect();
    let stopped = process::stop_all(&mut children, grace);
    let which: Vec<usize> = running.iter().map(|(i, _)| *i).collect();
    for ((i, pid), st) in which.into_iter().zip(pids).zip(stopped) {
        let s = &mut services[i];
        if st.killed {
            tracing::warn!(service = %s.cmd.name, "did not stop in time: killed");
        } else {
            tracing::info!(service = %s.cmd.name, status = %st.status, "stopped");
        }
        events.send(
            ServiceEvent::Stopped,
            s,
            pid,
            status_code(st.status),
            st.killed as u32,
        );
        s.state = State::Exited(st.status);
    }
}
