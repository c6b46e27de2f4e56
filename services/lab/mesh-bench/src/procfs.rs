//! What Linux says of a running process: its CPU time and resident memory (`/proc/<pid>/...`).

use serde::{Deserialize, Serialize};
use std::path::Path;

/// One reading of one process.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ProcSample {
    pub pid: i32,
    /// The program's file name (argv\[0\] without its directory).
    pub name: String,
    /// Time on a CPU, every thread summed (`task/*/schedstat`, nanosecond resolution).
    pub cpu_ns: u64,
    /// User and system time (`stat` fields 14 and 15, in clock ticks of `CLK_TCK`).
    pub utime_ticks: u64,
    pub stime_ticks: u64,
    /// Resident memory now and at its peak, and the shared-memory part of it (kB, `status`).
    pub rss_kb: u64,
    pub hwm_kb: u64,
    pub shmem_kb: u64,
}

/// The clock ticks per second of `utime`/`stime`.
pub fn clock_ticks_per_s() -> u64 {
    // SAFETY: sysconf has no preconditions.
    let t = unsafe { libc::sysconf(libc::_SC_CLK_TCK) };
    if t > 0 { t as u64 } else { 100 }
}

/// Reads `pid` now; `None` once it has exited.
pub fn sample(pid: i32) -> Option<ProcSample> {
    let dir = Path::new("/proc").join(pid.to_string());
    let cmdline = std::fs::read(dir.join("cmdline")).ok()?;
    // A zombie (exited, not yet reaped) has no command line and no memory: nothing to read.
    let argv0 = cmdline
        .split(|&b| b == 0)
        .next()
        .filter(|a| !a.is_empty())?;
    let name = Path::new(&*String::from_utf8_lossy(argv0))
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let (utime_ticks, stime_ticks) =
        parse_stat_times(&std::fs::read_to_string(dir.join("stat")).ok()?)?;
    let status = std::fs::read_to_string(dir.join("status")).ok()?;
    let mut cpu_ns = 0;
    for task in std::fs::read_dir(dir.join("task")).ok()?.flatten() {
        if let Ok(s) = std::fs::read_to_string(task.path().join("schedstat")) {
            cpu_ns += parse_schedstat(&s).unwrap_or(0);
        }
    }
    Some(ProcSample {
        pid,
        name,
        cpu_ns,
        utime_ticks,
        stime_ticks,
        rss_kb: status_kb(&status, "VmRSS").unwrap_or(0),
        hwm_kb: status_kb(&status, "VmHWM").unwrap_or(0),
        shmem_kb: status_kb(&status, "RssShmem").unwrap_or(0),
    })
}

/// The calling thread's own time on a CPU (ns).
pub fn thread_cpu_ns() -> u64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| parse_schedstat(&s))
        .unwrap_or(0)
}

/// The time every CPU of the machine has been busy with anything (ns, `/proc/stat`), and this
/// process's own time on a CPU, every thread summed: the difference over a run is what else ran.
pub fn machine_busy_ns() -> u64 {
    let stat = std::fs::read_to_string("/proc/stat").unwrap_or_default();
    let ticks = stat.lines().next().map_or(0, parse_cpu_busy);
    ticks * 1_000_000_000 / clock_ticks_per_s()
}

/// This process's time on a CPU (ns), every thread summed.
pub fn own_cpu_ns() -> u64 {
    sample(std::process::id() as i32).map_or(0, |s| s.cpu_ns)
}

/// Busy ticks of the `cpu` line of `/proc/stat`: user, nice, system, irq, softirq, steal (guest time
/// is inside user).
fn parse_cpu_busy(line: &str) -> u64 {
    let f: Vec<u64> = line
        .split_whitespace()
        .skip(1)
        .map(|x| x.parse().unwrap_or(0))
        .collect();
    [0, 1, 2, 5, 6, 7].iter().filter_map(|&i| f.get(i)).sum()
}

/// The children of `pid` (see `runtime::process::children`).
pub fn children(pid: i32) -> Vec<i32> {
    runtime::process::children(pid as u32)
        .into_iter()
        .map(|(p, _)| p as i32)
        .collect()
}

/// `utime` and `stime` from `/proc/<pid>/stat` (the command name in parentheses may hold spaces).
fn parse_stat_times(stat: &str) -> Option<(u64, u64)> {
    let after_name = &stat[stat.rfind(')')? + 1..];
    // Fields after the name start with field 3 (state); utime and stime are fields 14 and 15.
    let fields: Vec<&str> = after_name.split_whitespace().collect();
    Some((fields.get(11)?.parse().ok()?, fields.get(12)?.parse().ok()?))
}

/// The first field of `schedstat`: nanoseconds spent on a CPU.
fn parse_schedstat(s: &str) -> Option<u64> {
    s.split_whitespace().next()?.parse().ok()
}

/// A `Key:   123 kB` line of `/proc/<pid>/status`.
fn status_kb(status: &str, key: &str) -> Option<u64> {
    status.lines().find_map(|l| {
        let rest = l.strip_prefix(key)?.strip_prefix(':')?;
        rest.split_whitespace().next()?.parse().ok()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_proc_files() {
        let stat = "4242 (a (b) c) S 1 4242 4242 0 -1 4194560 100 0 0 0 17 5 0 0 20 0 1 0 999";
        assert_eq!(parse_stat_times(stat), Some((17, 5)));
        assert_eq!(parse_schedstat("123456 789 10\n"), Some(123456));
        let status = "Name:\tx\nVmHWM:\t   2048 kB\nVmRSS:\t   1024 kB\nRssShmem:\t  300 kB\n";
        assert_eq!(status_kb(status, "VmRSS"), Some(1024));
        assert_eq!(status_kb(status, "VmHWM"), Some(2048));
        assert_eq!(status_kb(status, "RssShmem"), Some(300));
        assert_eq!(status_kb(status, "VmSwap"), None);
        assert_eq!(
            parse_cpu_busy("cpu  10 1 5 1000 7 2 3 4 0 0"),
            10 + 1 + 5 + 2 + 3 + 4
        );
    }

    #[test]
    fn reads_this_process() {
        let me = sample(std::process::id() as i32).expect("this process");
        assert!(me.rss_kb > 0 && me.hwm_kb >= me.rss_kb);
        assert!(me.cpu_ns > 0);
        assert!(thread_cpu_ns() > 0);
        assert!(clock_ticks_per_s() > 0);
        assert!(machine_busy_ns() > 0 && own_cpu_ns() > 0);
    }
}
