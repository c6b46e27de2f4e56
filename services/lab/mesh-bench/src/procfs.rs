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
    /// What the scheduler and the memory manager did to it, every thread summed.
    #[serde(default)]
    pub sched: SchedCounts,
}

/// Context switches, migrations between CPUs and page faults: where a process's time goes besides
/// its own work (`sched` and `stat` of each task).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SchedCounts {
    /// Switches away because it blocked (waiting for its next message) or was preempted.
    pub voluntary: u64,
    pub involuntary: u64,
    /// Moves from one CPU to another.
    pub migrations: u64,
    /// Page faults served without I/O (first touch of a page, copy-on-write).
    pub minor_faults: u64,
}

impl SchedCounts {
    /// The counts of one task directory (`/proc/<pid>/task/<tid>` or `/proc/thread-self`).
    pub fn of_task(dir: &Path) -> SchedCounts {
        let sched = std::fs::read_to_string(dir.join("sched")).unwrap_or_default();
        let stat = std::fs::read_to_string(dir.join("stat")).unwrap_or_default();
        SchedCounts {
            voluntary: sched_field(&sched, "nr_voluntary_switches").unwrap_or(0),
            involuntary: sched_field(&sched, "nr_involuntary_switches").unwrap_or(0),
            migrations: sched_field(&sched, "se.nr_migrations").unwrap_or(0),
            minor_faults: parse_stat_field(&stat, 10).unwrap_or(0),
        }
    }

    /// The calling thread's counts.
    pub fn this_thread() -> SchedCounts {
        Self::of_task(Path::new("/proc/thread-self"))
    }

    pub fn add(&mut self, o: &SchedCounts) {
        self.voluntary += o.voluntary;
        self.involuntary += o.involuntary;
        self.migrations += o.migrations;
        self.minor_faults += o.minor_faults;
    }

    /// What happened between `earlier` and this reading.
    pub fn since(&self, earlier: &SchedCounts) -> SchedCounts {
        SchedCounts {
            voluntary: self.voluntary.saturating_sub(earlier.voluntary),
            involuntary: self.involuntary.saturating_sub(earlier.involuntary),
            migrations: self.migrations.saturating_sub(earlier.migrations),
            minor_faults: self.minor_faults.saturating_sub(earlier.minor_faults),
        }
    }
}

/// A `name : value` line of `sched`.
fn sched_field(sched: &str, name: &str) -> Option<u64> {
    sched.lines().find_map(|l| {
        let (k, v) = l.split_once(':')?;
        (k.trim() == name).then(|| v.trim().parse().ok())?
    })
}

/// Field `n` (1-based, as `proc(5)` numbers them) of a `stat` line.
fn parse_stat_field(stat: &str, n: usize) -> Option<u64> {
    let after_name = &stat[stat.rfind(')')? + 1..];
    // Fields after the name start with field 3.
    after_name
        .split_whitespace()
        .nth(n.checked_sub(3)?)?
        .parse()
        .ok()
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
    let mut sched = SchedCounts::default();
    for task in std::fs::read_dir(dir.join("task")).ok()?.flatten() {
        if let Ok(s) = std::fs::read_to_string(task.path().join("schedstat")) {
            cpu_ns += parse_schedstat(&s).unwrap_or(0);
        }
        sched.add(&SchedCounts::of_task(&task.path()));
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
        sched,
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
        assert_eq!(parse_stat_field(stat, 10), Some(100));
        assert_eq!(parse_stat_field(stat, 14), Some(17));
        let sched = "camera (42, #threads: 1)\n---\nse.nr_migrations   :   7\nnr_voluntary_switches :  30\nnr_involuntary_switches : 2\n";
        assert_eq!(sched_field(sched, "se.nr_migrations"), Some(7));
        assert_eq!(sched_field(sched, "nr_voluntary_switches"), Some(30));
        assert_eq!(sched_field(sched, "nr_switches"), None);
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
        // Reading /proc blocks on nothing, but this test's threads have run and faulted pages in.
        assert!(me.sched.minor_faults > 0 && me.sched.voluntary + me.sched.involuntary > 0);
        let t = SchedCounts::this_thread();
        assert!(t.minor_faults > 0 && t.since(&t) == SchedCounts::default());
        assert!(thread_cpu_ns() > 0);
        assert!(clock_ticks_per_s() > 0);
        assert!(machine_busy_ns() > 0 && own_cpu_ns() > 0);
    }
}
