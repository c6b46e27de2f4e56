//! Processes this program starts, managed in one place for the supervisor, the tests and the
//! benchmarks: spawned with their output in a log file (or inherited), optionally bound to die with
//! their parent; signalled only while they are this program's unreaped children (never pid 0, never
//! a pid the kernel may have given to someone else); stopped with SIGTERM, a grace period, then
//! SIGKILL; their exit awaited by blocking on a pidfd, not by polling. A child started with
//! [`Spawn::ready_pipe`] says when it is ready ([`notify_ready`]), and its starter can block on it
//! ([`Child::wait_ready`]).
//!
//! Linux only: `prctl(PR_SET_PDEATHSIG)`, `pidfd_open(2)` (kernel 5.3 or later), `/proc`.

use std::ffi::OsStr;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::os::unix::process::{CommandExt, ExitStatusExt};
use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

/// The environment variable holding the file descriptor a child started with
/// [`Spawn::ready_pipe`] writes to once it is ready.
pub const READY_FD: &str = "CABLETRACK_READY_FD";

/// How to start a process.
pub struct Spawn {
    name: String,
    cmd: Command,
    log: Option<PathBuf>,
    stdout: Option<Stdio>,
    die_with_parent: bool,
    ready_pipe: bool,
    placement: Placement,
}

/// Where and how the scheduler runs a process: its scheduling class and the CPUs it may run on.
/// Set before the program starts (every thread it makes inherits it).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Placement {
    pub scheduling: Scheduling,
    /// The CPUs it may run on (empty: any).
    pub cpus: Vec<usize>,
}

/// A process's scheduling class.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Scheduling {
    /// The normal time-sharing class (`SCHED_OTHER`).
    #[default]
    Normal,
    /// Runs only on a CPU nothing else wants (`SCHED_IDLE`): background work, such as the flight
    /// recorder's compression, that must never delay the loop; any other process that wakes takes
    /// the CPU from it at once.
    Idle,
}

impl std::str::FromStr for Scheduling {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "normal" => Ok(Scheduling::Normal),
            "idle" => Ok(Scheduling::Idle),
            other => Err(format!("`{other}` is not `normal` or `idle`")),
        }
    }
}

/// A list of CPUs as `taskset -c` writes it: `0`, `0,2`, `0-3`, `0-1,3`; empty: none.
pub fn parse_cpus(text: &str) -> Result<Vec<usize>, String> {
    let mut cpus = Vec::new();
    for part in text.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        let num = |t: &str| {
            t.trim()
                .parse::<usize>()
                .map_err(|_| format!("`{t}` in `{text}` is not a CPU number"))
        };
        match part.split_once('-') {
            Some((a, b)) => {
                let (a, b) = (num(a)?, num(b)?);
                if a > b {
                    return Err(format!("`{part}` in `{text}` is an empty range"));
                }
                cpus.extend(a..=b);
            }
            None => cpus.push(num(part)?),
        }
    }
    cpus.sort_unstable();
    cpus.dedup();
    Ok(cpus)
}

impl Placement {
    /// Why this placement cannot be had on this machine (a CPU it does not have).
    pub fn check(&self) -> Result<(), String> {
        // SAFETY: sysconf has no preconditions.
        let online = unsafe { libc::sysconf(libc::_SC_NPROCESSORS_ONLN) }.max(1) as usize;
        match self
            .cpus
            .iter()
            .find(|&&c| c >= online || c >= libc::CPU_SETSIZE as usize)
        {
            Some(c) => Err(format!(
                "this machine has CPUs 0 to {}, not {c}",
                online.saturating_sub(1)
            )),
            None => Ok(()),
        }
    }

    /// Applies it to the calling thread (in a child before exec: async-signal-safe, no allocation).
    fn apply(&self, cpus: &libc::cpu_set_t) -> std::io::Result<()> {
        let policy = match self.scheduling {
            Scheduling::Normal => None,
            Scheduling::Idle => Some(libc::SCHED_IDLE),
        };
        // SAFETY: plain syscalls on the calling thread with valid pointers.
        unsafe {
            if let Some(policy) = policy {
                let param = libc::sched_param { sched_priority: 0 };
                if libc::sched_setscheduler(0, policy, &param) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
            }
            if !self.cpus.is_empty()
                && libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), cpus) != 0
            {
                return Err(std::io::Error::last_os_error());
            }
        }
        Ok(())
    }

    fn cpu_set(&self) -> libc::cpu_set_t {
        // SAFETY: an all-zero cpu_set_t is the empty set; CPU_SET stays inside it (checked above).
        unsafe {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            for &c in &self.cpus {
                if c < libc::CPU_SETSIZE as usize {
                    libc::CPU_SET(c, &mut set);
                }
            }
            set
        }
    }
}

impl Spawn {
    /// `program`, named after its file name, with stdin closed and output inherited.
    pub fn new(program: impl AsRef<Path>) -> Spawn {
        let program = program.as_ref();
        let name = program
            .file_name()
            .unwrap_or(program.as_os_str())
            .to_string_lossy()
            .into_owned();
        Spawn {
            name,
            cmd: Command::new(program),
            log: None,
            stdout: None,
            die_with_parent: false,
            ready_pipe: false,
            placement: Placement::default(),
        }
    }

    /// Its scheduling class and CPUs.
    pub fn placement(mut self, placement: Placement) -> Self {
        self.placement = placement;
        self
    }

    /// The name logs and errors use (default: the program's file name).
    pub fn name(mut self, name: impl Into<String>) -> Self {
        self.name = name.into();
        self
    }

    pub fn arg(mut self, arg: impl AsRef<OsStr>) -> Self {
        self.cmd.arg(arg);
        self
    }

    pub fn args<S: AsRef<OsStr>>(mut self, args: impl IntoIterator<Item = S>) -> Self {
        self.cmd.args(args);
        self
    }

    pub fn env(mut self, key: impl AsRef<OsStr>, value: impl AsRef<OsStr>) -> Self {
        self.cmd.env(key, value);
        self
    }

    pub fn envs<K: AsRef<OsStr>, V: AsRef<OsStr>>(
        mut self,
        vars: impl IntoIterator<Item = (K, V)>,
    ) -> Self {
        self.cmd.envs(vars);
        self
    }

    /// Stdout and stderr both go to this file (created, or truncated).
    pub fn log(mut self, path: impl Into<PathBuf>) -> Self {
        self.log = Some(path.into());
        self
    }

    /// Stdout goes to `out` instead (e.g. a pipe); with [`Spawn::log`] the log keeps stderr.
    pub fn stdout(mut self, out: impl Into<Stdio>) -> Self {
        self.stdout = Some(out.into());
        self
    }

    /// The process gets SIGTERM when this one dies, so nothing runs on as an orphan.
    pub fn die_with_parent(mut self) -> Self {
        self.die_with_parent = true;
        self
    }

    /// The process gets the write end of a pipe (its number in [`READY_FD`]) to say it is ready
    /// ([`notify_ready`]); [`Child::wait_ready`] blocks on the read end.
    pub fn ready_pipe(mut self) -> Self {
        self.ready_pipe = true;
        self
    }

    /// Starts the process.
    pub fn start(mut self) -> std::io::Result<Child> {
        self.cmd.stdin(Stdio::null());
        let mut ready = None;
        let mut write_end = None;
        if self.ready_pipe {
            let mut fds = [0; 2];
            // SAFETY: pipe2 fills two new fds; both close on exec unless cleared below.
            if unsafe { libc::pipe2(fds.as_mut_ptr(), libc::O_CLOEXEC) } != 0 {
                return Err(std::io::Error::last_os_error());
            }
            // SAFETY: the two fds were just created and are owned by nobody else.
            let (read, write) =
                unsafe { (OwnedFd::from_raw_fd(fds[0]), OwnedFd::from_raw_fd(fds[1])) };
            let fd = write.as_raw_fd();
            self.cmd.env(READY_FD, fd.to_string());
            // SAFETY: fcntl in the child before exec is async-signal-safe; only this child keeps the
            // write end open across exec (every other child of ours gets it closed).
            unsafe {
                self.cmd.pre_exec(move || {
                    if libc::fcntl(fd, libc::F_SETFD, 0) == -1 {
                        return Err(std::io::Error::last_os_error());
                    }
                    Ok(())
                });
            }
            ready = Some(read);
            write_end = Some(write);
        }
        if let Some(log) = &self.log {
            let file = std::fs::File::create(log)?;
            self.cmd.stdout(file.try_clone()?).stderr(file);
        }
        if let Some(out) = self.stdout.take() {
            self.cmd.stdout(out);
        }
        if self.die_with_parent {
            // SAFETY: prctl in the child before exec is async-signal-safe.
            unsafe {
                self.cmd.pre_exec(|| {
                    libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM);
                    Ok(())
                });
            }
        }
        if self.placement != Placement::default() {
            let placement = self.placement.clone();
            let cpus = placement.cpu_set();
            // SAFETY: `apply` makes two syscalls and allocates nothing.
            unsafe {
                self.cmd.pre_exec(move || placement.apply(&cpus));
            }
        }
        let inner = self.cmd.spawn()?;
        // Our copy of the write end goes: the pipe then ends (reads 0) when the child exits.
        drop(write_end);
        let pidfd = pidfd_open(inner.id());
        Ok(Child {
            name: self.name,
            inner,
            pidfd,
            status: None,
            log: self.log,
            ready,
        })
    }
}

/// Says to whoever started this process with [`Spawn::ready_pipe`] that it is ready (once; later
/// calls, and a process started otherwise, do nothing).
pub fn notify_ready() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let Some(fd) = std::env::var(READY_FD)
            .ok()
            .and_then(|v| v.parse::<i32>().ok())
            .filter(|&fd| fd > 2)
        else {
            return;
        };
        // SAFETY: the fd was left open across exec by our parent for exactly this message; it is
        // taken over here once (the `Once`) and closed after the write.
        let mut pipe = unsafe { std::fs::File::from_raw_fd(fd) };
        if let Err(e) = std::io::Write::write_all(&mut pipe, b"ready\n") {
            tracing::warn!("cannot tell the parent that this process is ready: {e}");
        }
    });
}

/// Why [`Child::wait_ready`] returned without the child being ready.
#[derive(Debug, thiserror::Error)]
pub enum ReadyError {
    #[error("{name} was not started with a ready pipe")]
    NoPipe { name: String },
    #[error("{name} did not say it was ready within {timeout:?}")]
    Timeout { name: String, timeout: Duration },
    #[error("{name} ended (or closed its ready pipe) before saying it was ready")]
    Ended { name: String },
}

/// A pidfd of `pid`: readable once the process has exited. `None` on kernels without pidfd_open
/// (the waits then poll).
fn pidfd_open(pid: u32) -> Option<OwnedFd> {
    // SAFETY: pidfd_open(2) with a pid and no flags; the result is a new fd or -1.
    let fd = unsafe { libc::syscall(libc::SYS_pidfd_open, pid as libc::c_long, 0 as libc::c_long) };
    // SAFETY: a non-negative result is an fd this process now owns.
    (fd >= 0).then(|| unsafe { OwnedFd::from_raw_fd(fd as i32) })
}

/// A process this program started.
pub struct Child {
    name: String,
    inner: std::process::Child,
    pidfd: Option<OwnedFd>,
    /// Set once the exit has been collected: from then on the pid is not ours.
    status: Option<ExitStatus>,
    log: Option<PathBuf>,
    /// The read end of the ready pipe, until the child said it is ready.
    ready: Option<OwnedFd>,
}

impl Child {
    /// Blocks until the child says it is ready ([`notify_ready`]), or `timeout` passes, or it ends
    /// first.
    pub fn wait_ready(&mut self, timeout: Duration) -> Result<(), ReadyError> {
        let name = self.name.clone();
        let Some(fd) = self.ready.as_ref() else {
            return Err(ReadyError::NoPipe { name });
        };
        let end = Instant::now() + timeout;
        loop {
            let Some(left) = end.checked_duration_since(Instant::now()) else {
                return Err(ReadyError::Timeout { name, timeout });
            };
            let mut poll = libc::pollfd {
                fd: fd.as_raw_fd(),
                events: libc::POLLIN,
                revents: 0,
            };
            let ms = left.as_millis().clamp(1, i32::MAX as u128) as i32;
            // SAFETY: one valid pollfd for the call's duration; EINTR just returns early.
            let n = unsafe { libc::poll(&mut poll, 1, ms) };
            if n <= 0 {
                continue;
            }
            let mut buf = [0u8; 16];
            // SAFETY: reads into a buffer of this length from our own fd.
            let got = unsafe { libc::read(fd.as_raw_fd(), buf.as_mut_ptr().cast(), buf.len()) };
            match got {
                n if n > 0 => {
                    self.ready = None;
                    return Ok(());
                }
                0 => {
                    self.ready = None;
                    return Err(ReadyError::Ended { name });
                }
                _ => continue,
            }
        }
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    /// Its pid while it is ours (until its exit is collected).
    pub fn pid(&self) -> Option<u32> {
        self.status.is_none().then(|| self.inner.id())
    }

    /// Its pid as started, for the record (it may belong to another process by now).
    pub fn started_pid(&self) -> u32 {
        self.inner.id()
    }

    /// Sends `signal`; `false` once its exit has been collected (the pid may be another's by then).
    pub fn signal(&self, signal: i32) -> bool {
        let Some(pid) = self.pid() else {
            return false;
        };
        // A pid of 0 or below would signal a whole process group: never.
        let pid = libc::pid_t::try_from(pid).unwrap_or(0);
        if pid <= 0 {
            return false;
        }
        // SAFETY: kill(2) on our own child, not reaped yet (a zombie at worst), so the pid is ours.
        unsafe { libc::kill(pid, signal) == 0 }
    }

    /// The pid of its child process named `name` (a supervisor's service), if it has one now.
    pub fn child(&self, name: &str) -> Option<u32> {
        self.pid()
            .into_iter()
            .flat_map(children)
            .find(|(_, n)| is_named(n, name))
            .map(|(p, _)| p)
    }

    /// Sends `signal` to its child process named `name` (a supervisor's service): only a live child
    /// of a process of ours is ever signalled, never a process group. Returns the child's pid.
    pub fn signal_child(&self, name: &str, signal: i32) -> Option<u32> {
        let pid = self.child(name)?;
        let pid = libc::pid_t::try_from(pid).ok().filter(|&p| p > 0)?;
        // SAFETY: kill(2) on a process that is, as just read from /proc, a child of our own running
        // (unreaped) child; a pid of 0 or below (a process group) is never passed.
        (unsafe { libc::kill(pid, signal) } == 0).then_some(pid as u32)
    }

    /// Its exit status, if it has exited (collected now or earlier).
    pub fn try_status(&mut self) -> Option<ExitStatus> {
        if self.status.is_none()
            && let Ok(Some(status)) = self.inner.try_wait()
        {
            self.status = Some(status);
        }
        self.status
    }

    pub fn is_running(&mut self) -> bool {
        self.try_status().is_none()
    }

    /// Blocks until it exits or `timeout` passes.
    pub fn wait_timeout(&mut self, timeout: Duration) -> Option<ExitStatus> {
        let end = Instant::now() + timeout;
        loop {
            if let Some(status) = self.try_status() {
                return Some(status);
            }
            let left = end.checked_duration_since(Instant::now())?;
            wait_readable(&[self.pidfd.as_ref()], left);
        }
    }

    /// SIGTERM, up to `grace` to exit, then SIGKILL.
    pub fn stop(&mut self, grace: Duration) -> ExitStatus {
        stop_all(&mut [self], grace)[0].status
    }

    /// SIGKILL: no chance to clean up.
    pub fn kill(&mut self) -> ExitStatus {
        if self.try_status().is_none() {
            self.signal(libc::SIGKILL);
        }
        self.collect()
    }

    /// Blocks until its exit is collected.
    fn collect(&mut self) -> ExitStatus {
        if let Some(s) = self.status {
            return s;
        }
        let status = self
            .inner
            .wait()
            .unwrap_or_else(|_| ExitStatus::from_raw(libc::SIGKILL));
        self.status = Some(status);
        status
    }

    /// Its log file, if its output goes to one.
    pub fn log_path(&self) -> Option<&Path> {
        self.log.as_deref()
    }

    /// What it has logged so far (empty without a log file).
    pub fn log(&self) -> String {
        self.log
            .as_ref()
            .and_then(|p| std::fs::read_to_string(p).ok())
            .unwrap_or_default()
    }

    /// The last `n` lines of its log, headed by its name, for an error message.
    pub fn tail(&self, n: usize) -> String {
        let log = self.log();
        let lines: Vec<&str> = log.lines().collect();
        format!(
            "----- last lines of {}'s log -----\n{}",
            self.name,
            lines[lines.len().saturating_sub(n)..].join("\n")
        )
    }
}

impl Drop for Child {
    /// A child is never left running behind its handle.
    fn drop(&mut self) {
        if self.try_status().is_none() {
            self.stop(Duration::from_secs(5));
        }
    }
}

/// How a child ended when it was stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Stopped {
    pub status: ExitStatus,
    /// It outlived the grace period and was killed.
    pub killed: bool,
}

/// SIGTERM to each running child, up to `grace` for all to exit (blocking on their pidfds), then
/// SIGKILL for the rest. Every exit is collected; the result is in the children's order.
pub fn stop_all(children: &mut [&mut Child], grace: Duration) -> Vec<Stopped> {
    for c in children.iter_mut() {
        if c.try_status().is_none() {
            c.signal(libc::SIGTERM);
        }
    }
    wait_all(children, grace);
    children
        .iter_mut()
        .map(|c| {
            let killed = c.try_status().is_none();
            if killed {
                c.signal(libc::SIGKILL);
            }
            Stopped {
                status: c.collect(),
                killed,
            }
        })
        .collect()
}

/// Blocks until every child has exited or `timeout` passes; `true` if all exited.
pub fn wait_all(children: &mut [&mut Child], timeout: Duration) -> bool {
    let end = Instant::now() + timeout;
    loop {
        let running: Vec<Option<&OwnedFd>> = children
            .iter_mut()
            .filter_map(|c| {
                c.try_status()
                    .is_none()
                    .then_some(())
                    .map(|_| c.pidfd.as_ref())
            })
            .collect();
        if running.is_empty() {
            return true;
        }
        let Some(left) = end.checked_duration_since(Instant::now()) else {
            return false;
        };
        wait_readable(&running, left);
    }
}

/// Blocks until one of the pidfds is readable (its process exited) or `timeout` passes. Without a
/// pidfd (a kernel older than 5.3) it naps 5 ms: the caller checks again.
fn wait_readable(fds: &[Option<&OwnedFd>], timeout: Duration) {
    if fds.iter().any(Option::is_none) {
        std::thread::park_timeout(timeout.min(Duration::from_millis(5)));
        return;
    }
    let mut polls: Vec<libc::pollfd> = fds
        .iter()
        .flatten()
        .map(|fd| libc::pollfd {
            fd: fd.as_raw_fd(),
            events: libc::POLLIN,
            revents: 0,
        })
        .collect();
    let ms = timeout.as_millis().clamp(1, i32::MAX as u128) as i32;
    // SAFETY: valid pollfds for the call's duration; EINTR just returns early.
    unsafe {
        libc::poll(polls.as_mut_ptr(), polls.len() as libc::nfds_t, ms);
    }
}

/// Whether a process's name as the kernel keeps it (`/proc/PID/comm`: at most 15 bytes) is `name`.
pub fn is_named(comm: &str, name: &str) -> bool {
    const COMM_LEN: usize = 15;
    comm == name
        || (name.len() > COMM_LEN && name.is_char_boundary(COMM_LEN) && comm == &name[..COMM_LEN])
}

/// The children of process `pid` (started by any of its threads), in pid order: (pid, program
/// name as the kernel keeps it, at most 15 bytes: see [`is_named`]), e.g. a supervisor's services.
pub fn children(pid: u32) -> Vec<(u32, String)> {
    let mut pids: Vec<u32> = std::fs::read_dir(format!("/proc/{pid}/task"))
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|task| std::fs::read_to_string(task.path().join("children")).ok())
        .flat_map(|s| {
            s.split_whitespace()
                .filter_map(|p| p.parse().ok())
                .collect::<Vec<u32>>()
        })
        .collect();
    pids.sort_unstable();
    pids.dedup();
    pids.into_iter()
        .map(|p| {
            let comm = std::fs::read_to_string(format!("/proc/{p}/comm")).unwrap_or_default();
            (p, comm.trim().to_owned())
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sh(script: &str) -> Spawn {
        Spawn::new("/bin/sh").arg("-c").arg(script)
    }

    /// The child reports its own scheduling class and CPUs (`/proc/self`), set before it started.
    #[test]
    fn a_placement_is_in_force_when_the_program_starts() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        let script = format!(
            "cut -d' ' -f41 /proc/self/stat > {o}; grep Cpus_allowed_list /proc/self/status >> {o}",
            o = out.display()
        );
        let placement = Placement {
            scheduling: Scheduling::Idle,
            cpus: vec![0],
        };
        assert!(placement.check().is_ok());
        let mut c = sh(&script).placement(placement).start().unwrap();
        let status = c.wait_timeout(Duration::from_secs(10)).expect("it exits");
        assert!(status.success());
        let text = std::fs::read_to_string(&out).unwrap();
        let mut lines = text.lines();
        assert_eq!(
            lines.next(),
            Some(libc::SCHED_IDLE.to_string().as_str()),
            "{text}"
        );
        assert_eq!(
            lines.next().map(|l| l.split_whitespace().last()),
            Some(Some("0")),
            "{text}"
        );
        // The default leaves both as they were.
        let mut c = sh(&script).start().unwrap();
        assert!(
            c.wait_timeout(Duration::from_secs(10))
                .expect("it exits")
                .success()
        );
        let text = std::fs::read_to_string(&out).unwrap();
        assert_eq!(text.lines().next(), Some("0"), "SCHED_OTHER: {text}");
    }

    #[test]
    fn placements_are_parsed_and_checked() {
        assert_eq!(parse_cpus(""), Ok(vec![]));
        assert_eq!(parse_cpus("0"), Ok(vec![0]));
        assert_eq!(parse_cpus("3, 0-1,1"), Ok(vec![0, 1, 3]));
        assert!(parse_cpus("a").unwrap_err().contains("`a`"));
        assert!(parse_cpus("2-1").unwrap_err().contains("empty range"));
        assert_eq!("idle".parse(), Ok(Scheduling::Idle));
        assert_eq!("normal".parse(), Ok(Scheduling::Normal));
        assert!("fifo".parse::<Scheduling>().unwrap_err().contains("`fifo`"));
        let far = Placement {
            cpus: vec![4096],
            ..Default::default()
        };
        assert!(far.check().unwrap_err().contains("not 4096"));
    }

    #[test]
    fn an_exit_is_awaited_without_polling_and_collected_once() {
        let mut c = sh("exit 3").start().unwrap();
        let status = c.wait_timeout(Duration::from_secs(10)).expect("it exits");
        assert_eq!(status.code(), Some(3));
        assert_eq!(c.pid(), None, "a collected child has no pid of ours");
        assert!(!c.signal(libc::SIGTERM), "and is never signalled");
        assert_eq!(c.try_status(), Some(status));
    }

    #[test]
    fn stop_sends_sigterm_then_sigkill_after_the_grace() {
        // Ignores SIGTERM: only SIGKILL ends it.
        let dir = tempfile::tempdir().unwrap();
        let ready = dir.path().join("ready");
        let mut c = sh(&format!(
            "trap '' TERM; touch {}; while :; do sleep 1; done",
            ready.display()
        ))
        .start()
        .unwrap();
        // The trap is set once the file exists: a sleep-free wait on its appearance.
        let end = Instant::now() + Duration::from_secs(10);
        while !ready.exists() {
            assert!(Instant::now() < end, "the shell did not start");
            std::thread::yield_now();
        }
        let t0 = Instant::now();
        let status = c.stop(Duration::from_millis(300));
        assert!(t0.elapsed() >= Duration::from_millis(300));
        assert_eq!(status.signal(), Some(libc::SIGKILL));
        let mut polite = sh("while :; do sleep 1; done").start().unwrap();
        assert_eq!(
            polite.stop(Duration::from_secs(10)).signal(),
            Some(libc::SIGTERM)
        );
    }

    #[test]
    fn a_child_says_when_it_is_ready() {
        // The shell writes to the fd it was given: it is ready.
        let mut c = sh(&format!("echo ready >&${}; exec sleep 30", READY_FD))
            .ready_pipe()
            .start()
            .unwrap();
        c.wait_ready(Duration::from_secs(10)).expect("it said so");
        c.stop(Duration::from_secs(5));
        // It ends without saying it: the wait ends at once, not at the timeout.
        let mut quiet = sh("exit 0").ready_pipe().start().unwrap();
        let t0 = Instant::now();
        assert!(matches!(
            quiet.wait_ready(Duration::from_secs(30)),
            Err(ReadyError::Ended { .. })
        ));
        assert!(t0.elapsed() < Duration::from_secs(10));
        // It says nothing and runs on: the timeout.
        let mut silent = sh("exec sleep 30").ready_pipe().start().unwrap();
        assert!(matches!(
            silent.wait_ready(Duration::from_millis(100)),
            Err(ReadyError::Timeout { .. })
        ));
        // A child started without the pipe is not given one.
        let mut other = sh(&format!("test -z \"${}\"", READY_FD)).start().unwrap();
        assert!(
            other
                .wait_timeout(Duration::from_secs(10))
                .unwrap()
                .success()
        );
        assert!(matches!(
            other.wait_ready(Duration::ZERO),
            Err(ReadyError::NoPipe { .. })
        ));
    }

    #[test]
    fn output_goes_to_the_log_and_a_dropped_child_is_stopped() {
        let dir = tempfile::tempdir().unwrap();
        let log = dir.path().join("out.log");
        let mut c = sh("echo hello; echo oops >&2").log(&log).start().unwrap();
        c.wait_timeout(Duration::from_secs(10)).unwrap();
        assert_eq!(c.log(), "hello\noops\n");
        assert!(c.tail(1).ends_with("oops"));
        let c = sh("while :; do sleep 1; done").start().unwrap();
        let pid = c.started_pid();
        drop(c);
        assert!(
            !Path::new(&format!("/proc/{pid}")).exists(),
            "the dropped child is stopped and collected"
        );
    }
}
