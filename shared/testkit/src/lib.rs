//! The harness of every test that starts real processes (each service's `tests/` and the top-level
//! `tests/`), so that each test reads as the specification of one behaviour:
//!
//! - [`Namespace`]: an iceoryx2 prefix and root of the test's own, so tests run in parallel without
//!   meeting; dropping it removes the root and the prefix's shared-memory files.
//! - [`Process`]: a service binary started in a namespace (`runtime::process`), stopped with
//!   SIGTERM (then SIGKILL) when dropped; its log is kept and shown when the test fails.
//! - [`Probe`]: the test's own node, to publish to and receive from the processes. Receiving blocks
//!   in iceoryx2 with a deadline; a publisher's or subscriber's arrival has no event in iceoryx2,
//!   so those waits look again every 5 ms until their deadline.

use iceoryx2::node::NodeCreationFailure;
use iceoryx2::prelude::*;
use messages::ports::Payload;
use messages::{Endpoint, FrameInbox, FrameOutbox, Inbox, Outbox, Topic};
use runtime::process::{Child, Spawn};
use std::path::{Path, PathBuf};
use std::process::ExitStatus;
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

/// The Python of a virtual environment a project script installs (`install`, e.g.
/// scripts/install-mcap-py): the one `env_var` names, else `target/DIR` of the repository.
pub fn venv_python(env_var: &str, dir: &str, install: &str) -> PathBuf {
    let venv = std::env::var_os(env_var)
        .map(PathBuf::from)
        .unwrap_or_else(|| repo_root().join("target").join(dir));
    let python = venv.join("bin/python");
    assert!(
        python.exists(),
        "{} is missing: run {install} (CI does)",
        python.display()
    );
    python
}

/// A UDP port on loopback free now: the kernel's pick, released for the process under test to bind.
pub fn free_udp_port() -> u16 {
    std::net::UdpSocket::bind("127.0.0.1:0")
        .and_then(|s| s.local_addr())
        .expect("a free UDP port on loopback")
        .port()
}

/// A release binary of the workspace (`scripts/test` builds them all before the tests run), built
/// from the current source: a binary older than one of its source files (cargo's dependency file
/// beside it lists them) fails the test with the command that rebuilds it.
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
    if let Some(source) = newer_source(&path) {
        panic!(
            "{} is older than its source {}: run `cargo build --release --workspace --bins` \
             (scripts/test does) so the test runs the current code",
            path.display(),
            source.display()
        );
    }
    path
}

/// A source file of `binary` modified after it was built, from cargo's dependency file
/// (`<binary>.d`: `<binary>: <source> <source> ...`, spaces in paths escaped); `None` when all are
/// older or there is no dependency file.
pub fn newer_source(binary: &Path) -> Option<PathBuf> {
    let built = std::fs::metadata(binary).and_then(|m| m.modified()).ok()?;
    let deps = std::fs::read_to_string(binary.with_extension("d")).ok()?;
    let line = deps.lines().next()?;
    let (_, sources) = line.split_once(": ")?;
    let mut paths = Vec::new();
    let mut current = String::new();
    let mut chars = sources.chars();
    while let Some(c) = chars.next() {
        match c {
            '\\' => current.extend(chars.next()),
            ' ' => paths.push(std::mem::take(&mut current)),
            c => current.push(c),
        }
    }
    paths.push(current);
    paths
        .into_iter()
        .filter(|p| !p.is_empty())
        .map(PathBuf::from)
        .find(|p| {
            std::fs::metadata(p)
                .and_then(|m| m.modified())
                .is_ok_and(|t| t > built)
        })
}

/// An isolated iceoryx2 namespace for one test (the runtime's: removed with everything in it when
/// dropped).
pub use runtime::Namespace;

/// The children of process `pid`: (pid, program name), e.g. a supervisor's services.
pub use runtime::process::children;

/// A service process started for a test: its output in a log file in the namespace's root, shown
/// when the test fails; stopped (SIGTERM, then SIGKILL) when dropped.
pub struct Process {
    child: Child,
}

impl Process {
    /// Starts `binary` in `ns` with the repository's config and `args`.
    pub fn start(ns: &Namespace, binary: &Path, args: &[&str]) -> Process {
        Self::start_with_env(ns, binary, args, &[])
    }

    pub fn start_with_env(
        ns: &Namespace,
        binary: &Path,
        args: &[&str],
        env: &[(&str, &str)],
    ) -> Process {
        static NEXT: AtomicU32 = AtomicU32::new(0);
        let name = binary.file_name().unwrap().to_string_lossy().into_owned();
        let log = ns.scratch().join(format!(
            "{name}-{}.log",
            NEXT.fetch_add(1, Ordering::Relaxed)
        ));
        let child = Spawn::new(binary)
            .args(args)
            .env("CABLETRACK_CONFIG", config_dir())
            .envs(ns.env())
            .envs(env.iter().copied())
            .log(log)
            .die_with_parent()
            .start()
            .unwrap_or_else(|e| panic!("cannot start {}: {e}", binary.display()));
        Process { child }
    }

    /// The pid it was started with.
    pub fn pid(&self) -> u32 {
        self.child.started_pid()
    }

    /// What the process has logged so far.
    pub fn log(&self) -> String {
        self.child.log()
    }

    /// Sends `signal` (e.g. `libc::SIGTERM`) while it is running; `false` once it has exited.
    pub fn signal(&self, signal: i32) -> bool {
        self.child.signal(signal)
    }

    /// SIGTERM, up to `timeout` to exit, then SIGKILL.
    pub fn terminate(&mut self, timeout: Duration) -> ExitStatus {
        self.child.stop(timeout)
    }

    /// SIGKILL: the process gets no chance to clean up.
    pub fn kill9(&mut self) -> ExitStatus {
        self.child.kill()
    }

    /// Blocks until the process exits on its own, or `timeout` passes.
    pub fn wait(&mut self, timeout: Duration) -> Option<ExitStatus> {
        self.child.wait_timeout(timeout)
    }

    pub fn is_running(&mut self) -> bool {
        self.child.is_running()
    }

    /// The pid of this process's child named `name` (a supervisor's service), if it has one now.
    pub fn service(&self, name: &str) -> Option<u32> {
        self.child.child(name)
    }

    /// Sends `signal` to this process's child named `name` (a supervisor's service): only a live
    /// child of this test's own process is ever signalled. Returns its pid.
    pub fn signal_service(&self, name: &str, signal: i32) -> Option<u32> {
        self.child.signal_child(name, signal)
    }
}

impl Drop for Process {
    fn drop(&mut self) {
        if std::thread::panicking() {
            eprintln!("----- log of {} -----\n{}", self.child.name(), self.log());
        }
    }
}

/// Attempts at creating a probe's node. iceoryx2 0.10 now and then fails a node's creation with
/// `InternalError` while other threads of the same process create nodes at the same moment: the
/// tests run in parallel threads, each with its own probe, and about one run in 30 of a 22-test
/// binary met it. Outside the tests no process creates two nodes at once; a probe tries again.
const PROBE_ATTEMPTS: usize = 5;

/// The test's own node in namespace `ns`, on `endpoint`.
pub fn probe(ns: &Namespace, endpoint: Endpoint) -> Probe {
    let cfg = ns.iox.config().expect("a valid namespace");
    let create = || {
        NodeBuilder::new()
            .name(&NodeName::new("test-probe").unwrap())
            .config(&cfg)
            .create::<ipc::Service>()
    };
    let mut node = create();
    for _ in 1..PROBE_ATTEMPTS {
        match node {
            Err(NodeCreationFailure::InternalError) => node = create(),
            _ => break,
        }
    }
    let node = node.expect("the probe's node");
    // Install iceoryx2's signal handler now, like the services do.
    let _ = node.wait(Duration::ZERO);
    Probe { node, endpoint }
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

/// The sim mesh's placement on a machine shared with other meshes: the loop's services on any CPU
/// (pinned to one, every test's mesh would queue on that CPU), and the flight recorder scheduled
/// like any process (in the idle class it would fall behind the other tests' meshes and miss steps).
pub const SHARED_MACHINE: [(&str, &str); 2] =
    [("loop_cpus", ""), ("recorder_scheduling", "normal")];

/// The `supervisor` running `mesh` (a file of `config/`, or any path) in namespace `ns` with the
/// experiment's `seed` and `--set KEY=VALUE` for each of `sets`.
///
/// Tests run several meshes at once on a machine busy with other tests, so unless `sets` say
/// otherwise the sim mesh's placement for speed is undone ([`SHARED_MACHINE`]).
pub fn supervisor(ns: &Namespace, mesh: &Path, seed: u64, sets: &[(&str, String)]) -> Process {
    let mut sets = sets.to_vec();
    for (key, value) in SHARED_MACHINE {
        if !sets.iter().any(|(k, _)| *k == key) {
            sets.push((key, value.to_owned()));
        }
    }
    let args = runtime::MeshArgs::new(mesh, &config_dir(), seed, &ns.iox)
        .with_sets(&sets)
        .command_line();
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    Process::start(ns, &binary("supervisor"), &args)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A binary older than one of its sources is found out; one newer than all of them is not.
    #[test]
    fn a_binary_older_than_its_source_is_found() {
        let dir = tempfile::tempdir().unwrap();
        let (bin, old, new) = (
            dir.path().join("svc"),
            dir.path().join("old.rs"),
            dir.path().join("with space.rs"),
        );
        std::fs::write(&old, "").unwrap();
        std::fs::write(&bin, "").unwrap();
        std::fs::write(
            bin.with_extension("d"),
            format!(
                "{}: {} {}\n",
                bin.display(),
                old.display(),
                new.display().to_string().replace(' ', "\\ ")
            ),
        )
        .unwrap();
        std::fs::write(&new, "").unwrap();
        let hour = std::time::Duration::from_secs(3600);
        let now = std::time::SystemTime::now();
        let set = |p: &Path, t| {
            std::fs::File::options()
                .write(true)
                .open(p)
                .unwrap()
                .set_modified(t)
                .unwrap()
        };
        set(&old, now - 2 * hour);
        set(&bin, now - hour);
        set(&new, now);
        assert_eq!(newer_source(&bin), Some(new.clone()));
        set(&new, now - 2 * hour);
        assert_eq!(newer_source(&bin), None);
        assert_eq!(newer_source(&dir.path().join("missing")), None);
    }
}
