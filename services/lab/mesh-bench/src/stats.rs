//! The clock every process reads (the summaries of what it measures are `stats::Summary`).

/// `CLOCK_MONOTONIC` in nanoseconds: one clock for every process on the host, so a time taken in one
/// process can be compared with a time taken in another.
pub fn now_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes one timespec we own; CLOCK_MONOTONIC always exists on Linux.
    unsafe {
        libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts);
    }
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

pub use stats::{Summary, median};
