use crate::wait::{Stopped, Timer, Wake};
use config::{LearningParams, Scenario};
use iceoryx2::config::Config as IoxConfig;
use iceoryx2::node::NodeView;
use iceoryx2::prelude::*;
use messages::{
    Endpoint, FrameInbox, FrameOutbox, FrameTap, Heartbeat, Inbox, Outbox, PortError, Tap, Topic,
    VideoOutbox, VideoTap, ports::Payload,
};
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

/// The arguments every service takes (flatten them into its own `clap` parser).
#[derive(clap::Args, Clone, Debug)]
pub struct CommonArgs {
    /// Which mesh to join: `sim` (the simulator drives) or `vehicle` (the camera's clock drives).
    #[arg(long, default_value = "sim")]
    pub endpoint: Endpoint,
    #[command(flatten)]
    pub run: RunArgs,
}

/// What every process of a run shares: the configuration, the experiment's seed and the iceoryx2
/// namespace (the supervisor takes them and passes them on to its services, [`RunArgs::env`]).
#[derive(clap::Args, Clone, Debug, PartialEq, Eq)]
pub struct RunArgs {
    /// The configuration directory: scenario.toml, learning.toml (and the twin's twin.toml).
    #[arg(long, default_value = "config", env = "CABLETRACK_CONFIG")]
    pub config: PathBuf,
    /// The experiment's seed; each process draws from its own stream of it.
    #[arg(long, default_value_t = 1, env = "CABLETRACK_SEED")]
    pub seed: u64,
    #[command(flatten)]
    pub iox: IoxSettings,
}

impl RunArgs {
    /// The environment that gives a child process these (as [`CommonArgs`] reads it).
    pub fn env(&self) -> [(&'static str, String); 4] {
        let [prefix, root] = self.iox.env();
        [
            ("CABLETRACK_CONFIG", self.config.display().to_string()),
            ("CABLETRACK_SEED", self.seed.to_string()),
            prefix,
            root,
        ]
    }
}

/// Where the iceoryx2 resources live. Processes with another prefix and root never meet: tests run
/// isolated and in parallel.
#[derive(clap::Args, Clone, Debug, PartialEq, Eq)]
pub struct IoxSettings {
    /// Prefix of every shared-memory file and socket.
    #[arg(
        long = "iox-prefix",
        default_value = "ct_",
        env = "CABLETRACK_IOX_PREFIX"
    )]
    pub prefix: String,
    /// Directory of iceoryx2's sockets and node records.
    #[arg(
        long = "iox-root",
        default_value = "/tmp/cabletrack/",
        env = "CABLETRACK_IOX_ROOT"
    )]
    pub root: String,
}

/// The command line that runs a mesh: the `supervisor` parses it (flattened into its own options),
/// and a program that starts a supervisor (a test, a benchmark) writes it with
/// [`MeshArgs::command_line`], so the two never disagree.
#[derive(clap::Args, Clone, Debug, PartialEq, Eq)]
pub struct MeshArgs {
    /// The mesh file (e.g. config/sim-mesh.toml).
    #[arg(long)]
    pub mesh: PathBuf,
    /// A placeholder's value in the mesh file, KEY=VALUE (repeatable; `{seed}` is the seed's
    /// unless set).
    #[arg(long = "set", value_parser = parse_key_value)]
    pub set: Vec<(String, String)>,
    /// Passed on to every service.
    #[command(flatten)]
    pub run: RunArgs,
}

impl MeshArgs {
    /// `mesh` with the experiment's `seed` and the configuration in `config`, in the iceoryx2
    /// namespace `iox`; no placeholder set yet.
    pub fn new(mesh: &Path, config: &Path, seed: u64, iox: &IoxSettings) -> MeshArgs {
        MeshArgs {
            mesh: mesh.to_owned(),
            set: Vec::new(),
            run: RunArgs {
                config: config.to_owned(),
                seed,
                iox: iox.clone(),
            },
        }
    }

    /// With `--set KEY=VALUE` for each of `sets` too.
    pub fn with_sets<'a>(mut self, sets: impl IntoIterator<Item = &'a (&'a str, String)>) -> Self {
        self.set
            .extend(sets.into_iter().map(|(k, v)| ((*k).to_owned(), v.clone())));
        self
    }

    /// The arguments that parse back to these (the program's name not included).
    pub fn command_line(&self) -> Vec<String> {
        let mut args: Vec<String> = vec![
            "--mesh".into(),
            self.mesh.display().to_string(),
            "--config".into(),
            self.run.config.display().to_string(),
            "--seed".into(),
            self.run.seed.to_string(),
            "--iox-prefix".into(),
            self.run.iox.prefix.clone(),
            "--iox-root".into(),
            self.run.iox.root.clone(),
        ];
        for (k, v) in &self.set {
            args.extend(["--set".into(), format!("{k}={v}")]);
        }
        args
    }
}

fn parse_key_value(s: &str) -> Result<(String, String), String> {
    s.split_once('=')
        .map(|(k, v)| (k.to_owned(), v.to_owned()))
        .ok_or_else(|| format!("`{s}` is not KEY=VALUE"))
}

/// An event socket is `<root><prefix><up to 39 digits>.event` and must fit in 108 bytes.
const MAX_ROOT_AND_PREFIX: usize = 63;

impl IoxSettings {
    /// The environment a child process needs to join this namespace (as [`CommonArgs`] reads it).
    pub fn env(&self) -> [(&'static str, String); 2] {
        [
            ("CABLETRACK_IOX_PREFIX", self.prefix.clone()),
            ("CABLETRACK_IOX_ROOT", self.root.clone()),
        ]
    }

    /// The iceoryx2 configuration for these settings.
    pub fn config(&self) -> Result<IoxConfig, RuntimeError> {
        let root = if self.root.ends_with('/') {
            self.root.clone()
        } else {
            format!("{}/", self.root)
        };
        if root.len() + self.prefix.len() > MAX_ROOT_AND_PREFIX {
            return Err(RuntimeError::Iox(format!(
                "--iox-root `{root}` and --iox-prefix `{}` are {} bytes together; at most {MAX_ROOT_AND_PREFIX} fit in a socket path",
                self.prefix,
                root.len() + self.prefix.len()
            )));
        }
        let mut cfg = IoxConfig::default();
        cfg.global.prefix = FileName::new(self.prefix.as_bytes())
            .map_err(|e| RuntimeError::Iox(format!("--iox-prefix `{}`: {e:?}", self.prefix)))?;
        cfg.global.set_root_path(
            &iceoryx2::prelude::Path::new(root.as_bytes())
                .map_err(|e| RuntimeError::Iox(format!("--iox-root `{root}`: {e:?}")))?,
        );
        Ok(cfg)
    }
}

#[derive(Debug, thiserror::Error)]
pub enum RuntimeError {
    #[error(transparent)]
    Config(#[from] config::ConfigError),
    #[error("iceoryx2: {0}")]
    Iox(String),
    #[error(transparent)]
    Port(#[from] PortError),
    #[error("vehicle clock: {0}")]
    Clock(String),
}

/// A running service: its node, its configuration, its identity.
pub struct Runtime {
    name: &'static str,
    endpoint: Endpoint,
    seed: u64,
    config_dir: PathBuf,
    scenario: Scenario,
    learning: LearningParams,
    iox: IoxConfig,
    node: Node<ipc::Service>,
    /// Beats from every wait loop ([`Runtime::serve`]): the supervisor restarts a process that falls
    /// silent.
    heartbeat: Heartbeat,
    clock: crate::VehicleClock,
}

/// Sets up logging once per process: `RUST_LOG` (default `info`) filters, colours on a terminal only;
/// iceoryx2's own level from `IOX2_LOG_LEVEL` (default `warn`).
pub fn init_tracing() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    // A second call (tests) keeps the first subscriber.
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal())
        .try_init();
    set_log_level_from_env_or(LogLevel::Warn);
}

/// Runs a service: sets up tracing, starts the runtime, calls `body`, and turns an error into a
/// logged chain and a non-zero exit (standard output's reader gone: a quiet, successful exit, see
/// `cli`).
pub fn run(
    name: &'static str,
    args: &CommonArgs,
    body: impl FnOnce(&Runtime) -> anyhow::Result<()>,
) -> ExitCode {
    init_tracing();
    let span = tracing::info_span!("service", name);
    let _entered = span.enter();
    let result = Runtime::start(name, args)
        .map_err(anyhow::Error::from)
        .and_then(|rt| {
            tracing::info!(endpoint = %rt.endpoint, seed = rt.seed, config = %rt.config_dir.display(), "started");
            let r = body(&rt);
            if r.is_ok() {
                tracing::info!("stopped");
            }
            r
        });
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) if cli::reader_gone(err.as_ref()) => ExitCode::SUCCESS,
        Err(err) => {
            tracing::error!("{err:#}");
            cli::fail(name, err.as_ref())
        }
    }
}

impl Runtime {
    /// Loads the configuration, removes the resources of dead processes, creates the node and
    /// installs the termination-signal handler.
    pub fn start(name: &'static str, args: &CommonArgs) -> Result<Runtime, RuntimeError> {
        let scenario: Scenario = config::load(&args.run.config.join("scenario.toml"))?;
        let learning: LearningParams = config::load(&args.run.config.join("learning.toml"))?;
        let iox = args.run.iox.config()?;
        let clock = crate::VehicleClock::from_env()?;
        if clock.offset_ns() != 0 {
            tracing::warn!(
                offset_ms = clock.offset_ns() / 1_000_000,
                "this process's vehicle clock is offset from the machine's"
            );
        }
        remove_dead_nodes(&iox);
        let node = create_node(name, &iox)?;
        // iceoryx2 installs its SIGINT/SIGTERM handler on the first wait; install it now, so a signal
        // during start-up is seen and not fatal.
        let _ = node.wait(Duration::ZERO);
        // Set by the supervisor when it restarts this service; the heartbeat carries it.
        let heartbeat = Heartbeat::open(&node, args.endpoint, name, restarts() as usize)?;
        Ok(Runtime {
            name,
            endpoint: args.endpoint,
            seed: args.run.seed,
            config_dir: args.run.config.clone(),
            scenario,
            learning,
            iox,
            node,
            heartbeat,
            clock,
        })
    }

    /// The vehicle clock: every stamp is taken and judged on it.
    pub fn clock(&self) -> &crate::VehicleClock {
        &self.clock
    }

    /// The judge of the stamps arriving on `input` (a topic name), with the control loop's limits.
    pub fn screen(&self, input: impl Into<String>) -> crate::screen::Screen {
        crate::screen::Screen::new(
            input,
            crate::screen::ScreenLimits::control(self.scenario.timing.sample_time_s),
        )
    }

    pub fn name(&self) -> &'static str {
        self.name
    }

    pub fn endpoint(&self) -> Endpoint {
        self.endpoint
    }

    pub fn seed(&self) -> u64 {
        self.seed
    }

    /// This process's random stream (see `config::derive_seed`).
    pub fn stream_seed(&self, stream: &str) -> u64 {
        config::derive_seed(self.seed, stream)
    }

    pub fn config_dir(&self) -> &Path {
        &self.config_dir
    }

    pub fn scenario(&self) -> &Scenario {
        &self.scenario
    }

    pub fn learning(&self) -> &LearningParams {
        &self.learning
    }

    pub fn node(&self) -> &Node<ipc::Service> {
        &self.node
    }

    pub fn iox_config(&self) -> &IoxConfig {
        &self.iox
    }

    pub fn outbox<P: Payload>(&self, topic: &Topic<P>) -> Result<Outbox<P>, PortError> {
        Outbox::open(&self.node, self.endpoint, topic)
    }

    pub fn inbox<P: Payload>(&self, topic: &Topic<P>) -> Result<Inbox<P>, PortError> {
        Inbox::open(&self.node, self.endpoint, topic)
    }

    /// A frame publisher for the scenario's camera size.
    pub fn frame_outbox(&self) -> Result<FrameOutbox, PortError> {
        let c = &self.scenario.camera;
        FrameOutbox::open(&self.node, self.endpoint, (c.width * c.height) as usize)
    }

    pub fn frame_inbox(&self) -> Result<FrameInbox, PortError> {
        FrameInbox::open(&self.node, self.endpoint)
    }

    /// A recording subscriber of `topic` (see [`messages::Tap`]).
    pub fn tap<P: Payload>(&self, topic: &Topic<P>) -> Result<Tap<P>, PortError> {
        Tap::open(&self.node, self.endpoint, topic)
    }

    /// A recording subscriber of the camera's frames.
    pub fn frame_tap(&self) -> Result<FrameTap, PortError> {
        FrameTap::open(&self.node, self.endpoint)
    }

    /// The camera's video publisher (`topics::CAMERA_VIDEO`).
    pub fn video_outbox(&self) -> Result<VideoOutbox, PortError> {
        VideoOutbox::open(&self.node, self.endpoint)
    }

    /// A recording subscriber of the camera's video.
    pub fn video_tap(&self) -> Result<VideoTap, PortError> {
        VideoTap::open(&self.node, self.endpoint)
    }

    /// A listener notified after each message on `topic`, without a subscriber.
    pub fn listener<P: ?Sized>(
        &self,
        topic: &Topic<P>,
    ) -> Result<iceoryx2::port::listener::Listener<ipc::Service>, PortError> {
        messages::ports::open_listener(&self.node, &topic.service_name(self.endpoint), &topic.qos)
    }

    /// Tells the supervisor that this service is ready (its ports are open), where it waits for that
    /// ([`crate::process::notify_ready`]).
    pub fn ready(&self) {
        crate::process::notify_ready();
    }

    /// Blocks until one of `inputs` is notified or the timer fires, calls `on_wake`, and repeats
    /// until `on_wake` says stop or a termination signal arrives. Never spins: between wake-ups the
    /// process sleeps in the kernel.
    pub fn serve(
        &self,
        inputs: &[&iceoryx2::port::listener::Listener<ipc::Service>],
        timer: Timer,
        on_wake: impl FnMut(Wake) -> anyhow::Result<crate::Flow>,
    ) -> anyhow::Result<Stopped> {
        let inputs: Vec<crate::Input<'_>> =
            inputs.iter().map(|l| crate::Input::Listener(l)).collect();
        crate::wait::serve(&inputs, timer, &self.heartbeat, on_wake)
    }

    /// [`Runtime::serve`] on inputs that may be file descriptors too (a device's eventfd beside
    /// the listeners: see [`crate::Input`]).
    pub fn serve_inputs(
        &self,
        inputs: &[crate::Input<'_>],
        timer: Timer,
        on_wake: impl FnMut(Wake) -> anyhow::Result<crate::Flow>,
    ) -> anyhow::Result<Stopped> {
        crate::wait::serve(inputs, timer, &self.heartbeat, on_wake)
    }

    /// Serves one watched input, a watchdog's loop: wakes when `input` is notified (telling data
    /// from a publisher's death), when nothing was notified on it for `deadline` (iceoryx2's
    /// deadline attachment), and at the latest after the time `on_wake` returns (the
    /// core's own deadline); until `on_wake` returns `None` or SIGINT/SIGTERM arrives.
    pub fn serve_watched(
        &self,
        input: &iceoryx2::port::listener::Listener<ipc::Service>,
        deadline: Duration,
        on_wake: impl FnMut(crate::Watch) -> anyhow::Result<Option<Duration>>,
    ) -> anyhow::Result<Stopped> {
        crate::wait::serve_watched(input, deadline, &self.heartbeat, on_wake)
    }
}

/// The environment variable in which the supervisor tells a restarted service how often it was
/// restarted (absent or 0 at its first start).
pub const RESTARTS_ENV: &str = "CABLETRACK_RESTARTS";

/// How often this process's service was restarted (see [`RESTARTS_ENV`]).
pub fn restarts() -> u32 {
    std::env::var(RESTARTS_ENV)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(0)
}

/// A node named `name` in the iceoryx2 namespace `iox` (for a program that is not a service, e.g. the
/// supervisor; a service gets its node from [`Runtime::start`]).
pub fn create_node(name: &str, iox: &IoxConfig) -> Result<Node<ipc::Service>, RuntimeError> {
    NodeBuilder::new()
        .name(
            &NodeName::new(name)
                .map_err(|e| RuntimeError::Iox(format!("node name `{name}`: {e:?}")))?,
        )
        .config(iox)
        .create::<ipc::Service>()
        .map_err(|e| RuntimeError::Iox(format!("cannot create node `{name}`: {e:?}")))
}

/// Removes what processes that died without cleaning up (e.g. `kill -9`) left in shared memory;
/// returns how many dead processes were cleaned up.
pub fn remove_dead_nodes(iox: &IoxConfig) -> usize {
    let mut removed = 0;
    let result = Node::<ipc::Service>::list(iox, |state| {
        if let NodeState::Dead(view) = state {
            let who = view
                .details()
                .as_ref()
                .map(|d| d.name().to_string())
                .unwrap_or_else(|| "?".into());
            match view.try_remove_stale_resources() {
                Ok(_) => {
                    removed += 1;
                    tracing::info!(node = %who, "removed the resources of a dead process");
                }
                Err(e) => {
                    tracing::warn!(node = %who, "cannot remove a dead process's resources: {e:?}")
                }
            }
        }
        CallbackProgression::Continue
    });
    if let Err(e) = result {
        // A fresh root has no node directory yet.
        tracing::debug!("listing nodes: {e:?}");
    }
    removed
}

/// The shared-memory files of the iceoryx2 namespace `prefix` now in `/dev/shm`.
pub fn shm_files(prefix: &str) -> Vec<String> {
    std::fs::read_dir("/dev/shm")
        .map(|d| {
            d.flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n.starts_with(prefix))
                .collect()
        })
        .unwrap_or_default()
}

/// The files of namespace `prefix` that outlive its processes, except iceoryx2's one 16-byte
/// `global_mgmt` record per prefix, which it keeps by design: after a clean stop, none.
pub fn shm_leftovers(prefix: &str) -> Vec<String> {
    shm_files(prefix)
        .into_iter()
        .filter(|n| !n.ends_with(".global_mgmt"))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Supervisor {
        #[command(flatten)]
        mesh: MeshArgs,
    }

    fn parse(args: &[String]) -> Result<MeshArgs, clap::Error> {
        Supervisor::try_parse_from(std::iter::once("supervisor".to_owned()).chain(args.to_vec()))
            .map(|s| s.mesh)
    }

    #[test]
    fn a_mesh_command_line_parses_back_to_what_wrote_it() {
        let iox = IoxSettings {
            prefix: "nx1_".into(),
            root: "/tmp/x y/".into(),
        };
        let args = MeshArgs::new(Path::new("config/sim-mesh.toml"), Path::new("/c"), 7, &iox)
            .with_sets(&[
                ("episodes", "3".to_owned()),
                // An empty value, and one holding `=`: both kept as they are.
                ("live", String::new()),
                ("twin", "--twin-config=a.toml".to_owned()),
            ]);
        assert_eq!(parse(&args.command_line()).unwrap(), args);
        let err = parse(&["--mesh".into(), "m.toml".into(), "--set".into(), "x".into()])
            .unwrap_err()
            .to_string();
        assert!(err.contains("`x` is not KEY=VALUE"), "{err}");
    }
}
