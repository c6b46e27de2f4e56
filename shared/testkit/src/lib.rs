//! The harness of every test that starts real processes (each service's `tests/` and the top-level
//! `tests/`), so that each test reads as the specification of one behaviour:
//!
//! - [`Namespace`]: an iceoryx2 prefix and root of the test's own, so tests run in parallel without
//!   meeting; dropping it removes the root and the prefix's shared-memory files.
//! - [`Process`]: a service binary started in a namespace, stopped with SIGTERM (then SIGKILL) when
//!   dropped; its log is kept and shown when the test fails.
//! - [`Probe`]: the test's own node, to publish to and receive from the processes, waiting in a
//!   WaitSet with a deadline (never a sleep).

use iceoryx2::prelude::*;
use messages::ports::Payload;
use messages::{Endpoint, FrameInbox, FrameOutbox, Inbox, Outbox, Topic};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};

/// The repository's root (this crate is `shared/testkit`).
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../..")
        .canonicalize()
        .expect("the repository")
}

/// The repository's `config/` directory.
pub fn config_dir() -> PathBuf {
    repo_root().join("config")
}

/// A release binary of the workspace (`scripts/test` builds them all before the tests run).
pub fn binary(name: &str) -> PathBuf {
    // Tests run from target/release/deps/; the binaries sit in target/release/.
    let exe = std::env::current_exe().expect("the test binary's path");
    let dir = exe
        .parent()
        .and_then(Path::parent)
        .expect("target/<profile>/");
    let path = dir.join(name);
    assert!(
        path.exists(),
        "{} is not built: run `cargo build --release --workspace --bins` first (scripts/test does)",
        path.display()
    );
    path
}

static NEXT: AtomicU32 = AtomicU32::new(0);

/// An isolated iceoryx2 namespace for one test.
pub struct Namespace {
    pub prefix: String,
    pub root: PathBuf,
}

impl Namespace {
    /// A fresh namespace; `label` (a few letters) helps find leftovers.
    pub fn new(label: &str) -> Self {
        let n = NEXT.fetch_add(1, Ordering::Relaxed);
        // Short: root + prefix must fit a socket path (runtime checks 63 bytes).
        let prefix = format!(
            "t{}{}{}_",
            label.chars().take(4).collect::<String>(),
            std::process::id() % 100_000,
            n
        );
        let root = PathBuf::from(format!("/tmp/ctt/{prefix}/"));
        let _ = std::fs::remove_dir_all(&root);
        Namespace { prefix, root }
    }

    /// The settings a process needs to join (as `runtime` reads them from the environment).
    pub fn env(&self) -> [(&'static str, String); 2] {
        [
            ("CABLETRACK_IOX_PREFIX", self.prefix.clone()),
            ("CABLETRACK_IOX_ROOT", self.root.display().to_string()),
        ]
    }

    pub fn settings(&self) -> runtime::IoxSettings {
        runtime::IoxSettings {
            prefix: self.prefix.clone(),
            root: self.root.display().to_string(),
        }
    }

    /// The test's own node in this namespace.
    pub fn probe(&self, endpoint: Endpoint) -> Probe {
        let cfg = self.settings().config().expect("a valid namespace");
        let node = NodeBuilder::new()
            .name(&NodeName::new("test-probe").unwrap())
            .config(&cfg)
            .create::<ipc::Service>()
            .expect("the probe's node");
        // Install iceoryx2's signal handler now, like the services do.
        let _ = node.wait(Duration::ZERO);
        Probe { node, endpoint }
    }

    /// Shared-memory files of this namespace still in /dev/shm.
    pub fn shm_files(&self) -> Vec<String> {
        runtime::shm_files(&self.prefix)
    }

    /// Files of this namespace that outlive its processes (see [`runtime::shm_leftovers`]).
    pub fn leftovers(&self) -> Vec<String> {
        runtime::shm_leftovers(&self.prefix)
    }
}

impl Drop for Namespace {
    fn drop(&mut self) {
        for f in self.shm_files() {
            let _ = std::fs::remove_file(Path::new("/dev/shm").join(f));
        }
        let _ = std::fs::remove_dir_all(&self.root);
    }
}

/// A service process started for a test.
pub struct Process {
    name: String,
    child: Option<Child>,
    log: PathBuf,
}

impl Process {
    /// Starts `binary` in `ns` with the repository's config and `args`; its stdout and stderr go to
    /// a log file in the namespace's root.
    pub fn start(ns: &Namespace, binary: &Path, args: &[&str]) -> Process {
        Self::start_with_env(ns, binary, args, &[])
    }

    pub fn start_with_env(
        ns: &Namespace,
        binary: &Path,
        args: &[&str],
        env: &[(&str, &str)],
    ) -> Process {
        let name = binary.file_name().unwrap().to_string_lossy().into_owned();
        std::fs::create_dir_all(&ns.root).expect("the namespace root");
        let log = ns.root.join(format!(
            "{name}-{}.log",
            NEXT.fetch_add(1, Ordering::Relaxed)
        ));
        let file = std::fs::File::create(&log).expect("the log file");
        let mut cmd = Command::new(binary);
        cmd.args(args)
            .env("CABLETRACK_CONFIG", config_dir())
            .envs(ns.env())
            .envs(env.iter().copied())
            .stdin(Stdio::null())
            .stdout(file.try_clone().unwrap())
            .stderr(file);
        let child = cmd
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {}: {e}", binary.display()));
        Process {
            name,
            child: Some(child),
            log,
        }
    }

    pub fn pid(&self) -> i32 {
        self.child.as_ref().map_or(0, |c| c.id() as i32)
    }

    /// What the process has logged so far.
    pub fn log(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    /// Sends `signal` (e.g. `libc::SIGTERM`).
    pub fn signal(&self, signal: i32) {
        // SAFETY: kill(2) with the pid of a child we own.
        unsafe {
            libc::kill(self.pid(), signal);
        }
    }

    /// SIGTERM, then waits up to `timeout` for the exit (SIGKILL after it).
    pub fn terminate(&mut self, timeout: Duration) -> ExitStatus {
        self.signal(libc::SIGTERM);
        self.wait(timeout).unwrap_or_else(|| {
            self.signal(libc::SIGKILL);
            self.wait(Duration::from_secs(5))
                .expect("a killed process exits")
        })
    }

    /// SIGKILL: the process gets no chance to clean up.
    pub fn kill9(&mut self) -> ExitStatus {
        self.signal(libc::SIGKILL);
        self.wait(Duration::from_secs(5))
            .expect("a killed process exits")
    }

    /// Waits up to `timeout` for the process to exit on its own.
    pub fn wait(&mut self, timeout: Duration) -> Option<ExitStatus> {
        let child = self.child.as_mut()?;
        let end = Instant::now() + timeout;
        loop {
            if let Ok(Some(status)) = child.try_wait() {
                self.child = None;
                return Some(status);
            }
            if Instant::now() >= end {
                return None;
            }
            // Polling a child's exit status has no event to block on; 10 ms is far below any timeout.
            std::thread::park_timeout(Duration::from_millis(10));
        }
    }

    pub fn is_running(&mut self) -> bool {
        matches!(self.child.as_mut().map(|c| c.try_wait()), Some(Ok(None)))
    }
}

impl Drop for Process {
    fn drop(&mut self) {
        if self.child.is_some() {
            self.terminate(Duration::from_secs(5));
        }
        if std::thread::panicking() {
            eprintln!("----- log of {} -----\n{}", self.name, self.log());
        }
    }
}

/// The test's side of the IPC.
pub struct Probe {
    node: Node<ipc::Service>,
    endpoint: Endpoint,
}

impl Probe {
    pub fn node(&self) -> &Node<ipc::Service> {
        &self.node
    }

    pub fn outbox<P: Payload>(&self, topic: &Topic<P>) -> Outbox<P> {
        Outbox::open(&self.node, self.endpoint, topic).expect("the probe's outbox")
    }

    pub fn inbox<P: Payload>(&self, topic: &Topic<P>) -> Inbox<P> {
        Inbox::open(&self.node, self.endpoint, topic).expect("the probe's inbox")
    }

    pub fn frame_outbox(&self, max_len: usize) -> FrameOutbox {
        FrameOutbox::open(&self.node, self.endpoint, max_len).expect("the probe's frame outbox")
    }

    pub fn frame_inbox(&self) -> FrameInbox {
        FrameInbox::open(&self.node, self.endpoint).expect("the probe's frame inbox")
    }

    /// Blocks until `inbox` yields a message accepted by `want`, or `timeout` passes (`None`).
    /// Other messages are skipped.
    pub fn wait_for<P: Payload>(
        &self,
        inbox: &Inbox<P>,
        timeout: Duration,
        mut want: impl FnMut(&P) -> bool,
    ) -> Option<P> {
        let end = Instant::now() + timeout;
        loop {
            while let Some(m) = inbox.receive().expect("receiving") {
                if want(&m) {
                    return Some(m);
                }
            }
            let left = end.checked_duration_since(Instant::now())?;
            self.block_on(inbox.listener(), left);
        }
    }

    /// Blocks until `producer` has at least one publisher connected, or `timeout` passes.
    pub fn wait_for_publisher<P: Payload>(&self, inbox: &Inbox<P>, timeout: Duration) -> bool {
        let end = Instant::now() + timeout;
        while inbox.publishers() == 0 {
            if Instant::now() >= end {
                return false;
            }
            // A publisher's arrival is not an event: check again every few milliseconds.
            let _ = self.node.wait(Duration::from_millis(5));
        }
        true
    }

    /// Blocks until `outbox` has at least `n` subscribers, or `timeout` passes.
    pub fn wait_for_subscribers<P: Payload>(
        &self,
        outbox: &Outbox<P>,
        n: usize,
        timeout: Duration,
    ) -> bool {
        let end = Instant::now() + timeout;
        while outbox.subscribers() < n {
            if Instant::now() >= end {
                return false;
            }
            let _ = self.node.wait(Duration::from_millis(5));
        }
        true
    }

    /// Blocks until `listener` is notified or `timeout` passes.
    pub fn block_on(
        &self,
        listener: &iceoryx2::port::listener::Listener<ipc::Service>,
        timeout: Duration,
    ) {
        let _ = listener.timed_wait(|_| {}, timeout);
    }
}

/// The children of process `pid`: (pid, program name), e.g. a supervisor's services.
pub fn children(pid: i32) -> Vec<(i32, String)> {
    std::fs::read_to_string(format!("/proc/{pid}/task/{pid}/children"))
        .unwrap_or_default()
        .split_whitespace()
        .filter_map(|p| p.parse().ok())
        .map(|p: i32| {
            let comm = std::fs::read_to_string(format!("/proc/{p}/comm")).unwrap_or_default();
            (p, comm.trim().to_owned())
        })
        .collect()
}

/// The `supervisor` running `mesh` (a file of `config/`, or any path) in namespace `ns` with the
/// experiment's `seed` and `--set KEY=VALUE` for each of `sets`.
pub fn supervisor(ns: &Namespace, mesh: &Path, seed: u64, sets: &[(&str, String)]) -> Process {
    let settings = ns.settings();
    let mut args = vec![
        "--mesh".to_owned(),
        mesh.display().to_string(),
        "--seed".into(),
        seed.to_string(),
        "--iox-prefix".into(),
        settings.prefix,
        "--iox-root".into(),
        settings.root,
    ];
    for (k, v) in sets {
        args.push("--set".into());
        args.push(format!("{k}={v}"));
    }
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    Process::start(ns, &binary("supervisor"), &args)
}
