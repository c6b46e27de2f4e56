//! `shore-link impair`: the demo's bad network where the kernel has no `sch_netem`. One TUN device
//! in each network namespace stands for the wire; this process carries every IP packet from one to
//! the other through [`Impairment`] (netem's rules), one per direction, and sends it when due.

use anyhow::{Context, Result, anyhow, bail};
use runtime::clock::monotonic_ns;
use shore_link::impair::{Counts, Impairment, Settings, netem_args};
use std::fs::File;
use std::io::Write;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::sync::atomic::{AtomicBool, Ordering};

/// `TUNSETIFF`, `IFF_TUN`, `IFF_NO_PI` (linux/if_tun.h).
const TUNSETIFF: libc::c_ulong = 0x4004_54ca;
const IFF_TUN: libc::c_short = 0x0001;
const IFF_NO_PI: libc::c_short = 0x1000;

/// `struct ifreq` as TUNSETIFF reads it: the name, then the flags.
#[repr(C)]
struct IfReq {
    name: [u8; libc::IFNAMSIZ],
    flags: libc::c_short,
    _rest: [u8; 22],
}

static STOP: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(_: libc::c_int) {
    STOP.store(true, Ordering::SeqCst);
}

fn os_error(what: String) -> anyhow::Error {
    anyhow!("{what}: {}", std::io::Error::last_os_error())
}

/// Enters the network namespace `ns` (by `ip netns`' name) on this thread.
fn enter(ns: &File, name: &str) -> Result<()> {
    // SAFETY: setns(2) on an open namespace file.
    if unsafe { libc::setns(ns.as_raw_fd(), libc::CLONE_NEWNET) } != 0 {
        return Err(os_error(format!("entering the network namespace {name}")));
    }
    Ok(())
}

/// Attaches to the TUN device of `spec` (NAMESPACE/DEVICE), made beforehand with
/// `ip -n NAMESPACE tuntap add dev DEVICE mode tun`.
fn attach(spec: &str) -> Result<OwnedFd> {
    let (ns, dev) = spec
        .split_once('/')
        .ok_or_else(|| anyhow!("`{spec}`: expected NAMESPACE/DEVICE"))?;
    if dev.is_empty() || dev.len() >= libc::IFNAMSIZ {
        bail!("`{spec}`: a device name has 1 to 15 characters");
    }
    let path = format!("/var/run/netns/{ns}");
    let file = File::open(&path).with_context(|| format!("`{spec}`: no namespace {path}"))?;
    enter(&file, ns)?;
    // SAFETY: open(2) of a path literal.
    let fd = unsafe {
        libc::open(
            c"/dev/net/tun".as_ptr(),
            libc::O_RDWR | libc::O_NONBLOCK | libc::O_CLOEXEC,
        )
    };
    if fd < 0 {
        return Err(os_error("opening /dev/net/tun".into()));
    }
    // SAFETY: a descriptor just opened and owned by nobody else.
    let fd = unsafe { OwnedFd::from_raw_fd(fd) };
    let mut req = IfReq {
        name: [0; libc::IFNAMSIZ],
        flags: IFF_TUN | IFF_NO_PI,
        _rest: [0; 22],
    };
    req.name[..dev.len()].copy_from_slice(dev.as_bytes());
    // SAFETY: TUNSETIFF reads an ifreq we own.
    if unsafe { libc::ioctl(fd.as_raw_fd(), TUNSETIFF, &mut req) } != 0 {
        return Err(os_error(format!(
            "attaching to the TUN device {dev} in {ns}"
        )));
    }
    Ok(fd)
}

/// One direction: packets read from `from`, impaired, written to `to`.
struct Direction {
    name: &'static str,
    from: OwnedFd,
    to: i32,
    impairment: Impairment<Vec<u8>>,
    /// Packets the other device did not take (it was down: the demo's cut).
    unwritten: u64,
}

impl Direction {
    /// Reads every waiting packet.
    fn read(&mut self, buf: &mut [u8]) -> Result<()> {
        loop {
            // SAFETY: read(2) into a buffer we own.
            let n =
                unsafe { libc::read(self.from.as_raw_fd(), buf.as_mut_ptr().cast(), buf.len()) };
            if n < 0 {
                let e = std::io::Error::last_os_error();
                return match e.kind() {
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::Interrupted => Ok(()),
                    _ => Err(anyhow!("{}: reading a packet: {e}", self.name)),
                };
            }
            let n = n as usize;
            self.impairment.offer(monotonic_ns(), buf[..n].to_vec(), n);
        }
    }

    /// Writes every packet due.
    fn send_due(&mut self) {
        while let Some(p) = self.impairment.pop_due(monotonic_ns()) {
            // SAFETY: write(2) of a buffer we own.
            let n = unsafe { libc::write(self.to, p.as_ptr().cast(), p.len()) };
            if n < 0 {
                self.unwritten += 1;
            }
        }
    }

    fn counts(&self) -> (Counts, u64) {
        (self.impairment.counts, self.unwritten)
    }
}

/// Runs the bad network until SIGTERM or SIGINT.
pub fn impair(vehicle: &str, shore: &str, netem: &str, seed: u64) -> Result<()> {
    let args = netem_args(netem);
    let settings: Settings = args
        .parse()
        .map_err(|e| anyhow!("--netem `{netem}`: {e}"))?;
    // Signals wait blocked until ppoll lets them in, so a stop cannot slip in between the check and
    // the wait.
    // SAFETY: plain signal-mask and sigaction calls with structures we own.
    unsafe {
        let mut mask: libc::sigset_t = std::mem::zeroed();
        libc::sigemptyset(&mut mask);
        libc::sigaddset(&mut mask, libc::SIGTERM);
        libc::sigaddset(&mut mask, libc::SIGINT);
        libc::sigprocmask(libc::SIG_BLOCK, &mask, std::ptr::null_mut());
        let mut action: libc::sigaction = std::mem::zeroed();
        action.sa_sigaction = on_signal as *const () as usize;
        libc::sigaction(libc::SIGTERM, &action, std::ptr::null_mut());
        libc::sigaction(libc::SIGINT, &action, std::ptr::null_mut());
    }
    let home = File::open("/proc/self/ns/net").context("this process's network namespace")?;
    let v = attach(vehicle)?;
    let s = attach(shore)?;
    enter(&home, "of this process")?;
    let (v_raw, s_raw) = (v.as_raw_fd(), s.as_raw_fd());
    let mut dirs = [
        Direction {
            name: "up",
            from: v,
            to: s_raw,
            impairment: Impairment::new(settings, seed),
            unwritten: 0,
        },
        Direction {
            name: "down",
            from: s,
            to: v_raw,
            impairment: Impairment::new(settings, seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ 1),
            unwritten: 0,
        },
    ];
    tracing::info!(netem = args, "impairing {vehicle} <-> {shore}");
    println!("ready");
    std::io::stdout().flush()?;
    let mut buf = vec![0u8; 65_536];
    // SAFETY: an empty signal set to wait with.
    let open: libc::sigset_t = unsafe {
        let mut m: libc::sigset_t = std::mem::zeroed();
        libc::sigemptyset(&mut m);
        m
    };
    while !STOP.load(Ordering::SeqCst) {
        for d in &mut dirs {
            d.send_due();
        }
        let now = monotonic_ns();
        let next = dirs
            .iter()
            .filter_map(|d| d.impairment.next_departure())
            .min();
        let wait_ns = next.map_or(1_000_000_000, |t| t.saturating_sub(now));
        let timeout = libc::timespec {
            tv_sec: (wait_ns / 1_000_000_000) as libc::time_t,
            tv_nsec: (wait_ns % 1_000_000_000) as libc::c_long,
        };
        let mut fds = [
            libc::pollfd {
                fd: v_raw,
                events: libc::POLLIN,
                revents: 0,
            },
            libc::pollfd {
                fd: s_raw,
                events: libc::POLLIN,
                revents: 0,
            },
        ];
        // SAFETY: ppoll(2) on descriptors we own, with a timeout and mask we own.
        let r = unsafe { libc::ppoll(fds.as_mut_ptr(), 2, &timeout, &open) };
        if r < 0 {
            let e = std::io::Error::last_os_error();
            if e.kind() == std::io::ErrorKind::Interrupted {
                continue;
            }
            bail!("waiting for packets: {e}");
        }
        for (d, f) in dirs.iter_mut().zip(fds) {
            if f.revents & libc::POLLIN != 0 {
                d.read(&mut buf)?;
            }
        }
    }
    for d in &dirs {
        let (c, unwritten) = d.counts();
        tracing::info!(
            direction = d.name,
            offered = c.offered,
            lost = c.lost,
            overflow = c.overflow,
            reordered = c.reordered,
            sent = c.sent,
            unwritten,
            waiting = d.impairment.waiting(),
            "impairment done"
        );
    }
    Ok(())
}
