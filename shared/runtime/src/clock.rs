//! The clocks every process reads, read in one place.
//!
//! The vehicle clock: the machine's monotonic clock (`CLOCK_MONOTONIC`, [`monotonic_ns`]), which no
//! wall-clock setting, NTP or missing RTC ever steps. The vehicle camera stamps each step with it
//! ([`messages::Stamp::clock_ns`]) and every consumer judges a stamp's age against it
//! ([`crate::screen::Screen`]); the benchmarks time messages across processes with it. Its readings
//! are signed: a process whose clock is offset behind the machine's by more than the machine has
//! been up reads below zero, and its readings still advance at the clock's pace (a reading held at
//! zero would show none, and every consumer would refuse its steps as ever older). 0 is never a
//! reading: it marks an untimed stamp.
//!
//! The wall clock ([`unix_ns`]) only for what people read beside a run: the supervisor's events,
//! the recorder's status and parts, a record sink's lines. No step is ever judged by it.
//!
//! A process's clock may be offset from the machine's by the number of milliseconds in the file named
//! by `CABLETRACK_CLOCK_OFFSET_FILE`, read once at start: how the fault drill starts a service whose
//! time base is stepped back (a camera with a clock of its own that restarted), without touching the
//! machine's clock.

use crate::RuntimeError;
use std::path::Path;
use std::time::{SystemTime, UNIX_EPOCH};

/// The environment variable naming the offset file (see the module docs).
pub const OFFSET_FILE_ENV: &str = "CABLETRACK_CLOCK_OFFSET_FILE";

/// The machine's monotonic clock in nanoseconds.
pub fn monotonic_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime(2) writes one timespec; CLOCK_MONOTONIC always exists on Linux.
    unsafe {
        libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts);
    }
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// The wall clock in nanoseconds since 1970 (0 for a clock set before it).
pub fn unix_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

/// A process's view of the vehicle clock: the monotonic clock plus a fixed offset.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct VehicleClock {
    offset_ns: i64,
}

impl Default for VehicleClock {
    fn default() -> Self {
        Self::system()
    }
}

impl VehicleClock {
    /// The machine's clock, unchanged.
    pub fn system() -> Self {
        VehicleClock { offset_ns: 0 }
    }

    /// The machine's clock moved by `offset_ns` (negative: behind).
    pub fn with_offset(offset_ns: i64) -> Self {
        VehicleClock { offset_ns }
    }

    /// The clock of a process started now: offset by `CABLETRACK_CLOCK_OFFSET_FILE` if it is set
    /// and the file exists (a missing file: no offset).
    pub fn from_env() -> Result<Self, RuntimeError> {
        match std::env::var_os(OFFSET_FILE_ENV) {
            Some(path) => Self::from_file(Path::new(&path)),
            None => Ok(Self::system()),
        }
    }

    /// The clock offset by the milliseconds written in `path` (missing or empty: none).
    pub fn from_file(path: &Path) -> Result<Self, RuntimeError> {
        let text = match std::fs::read_to_string(path) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Self::system()),
            Err(e) => {
                return Err(RuntimeError::Clock(format!(
                    "{OFFSET_FILE_ENV}: cannot read {}: {e}",
                    path.display()
                )));
            }
        };
        let text = text.trim();
        if text.is_empty() {
            return Ok(Self::system());
        }
        let ms: i64 = text.parse().map_err(|e| {
            RuntimeError::Clock(format!(
                "{OFFSET_FILE_ENV}: {} holds `{text}`, not a whole number of milliseconds: {e}",
                path.display()
            ))
        })?;
        Ok(Self::with_offset(ms.saturating_mul(1_000_000)))
    }

    pub fn offset_ns(&self) -> i64 {
        self.offset_ns
    }

    /// Now on this clock (ns): below zero when the offset is behind by more than the machine's
    /// uptime; never 0 (a reading of exactly 0 reads 1 ns later).
    pub fn now_ns(&self) -> i64 {
        Self::reading(monotonic_ns(), self.offset_ns)
    }

    /// The reading of a clock `offset_ns` from the machine's when the machine's reads `machine_ns`.
    fn reading(machine_ns: u64, offset_ns: i64) -> i64 {
        let t = (machine_ns as i128 + offset_ns as i128).clamp(i64::MIN as i128, i64::MAX as i128);
        match t as i64 {
            0 => 1,
            t => t,
        }
    }

    /// A new epoch (a producer's session, [`messages::Stamp::epoch`]): a value a restarted process
    /// does not repeat (drawn from the clock's reading and the process id), never 0.
    pub fn new_epoch(&self) -> u32 {
        let seed = config::derive_seed(
            self.now_ns() as u64,
            &format!("epoch/{}", std::process::id()),
        );
        ((seed >> 32) as u32 ^ seed as u32).max(1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_clock_is_monotonic_and_its_offset_is_read_from_a_file() {
        let clock = VehicleClock::system();
        let a = clock.now_ns();
        let b = clock.now_ns();
        assert!(a != 0 && b >= a);
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("offset");
        assert_eq!(
            VehicleClock::from_file(&file).unwrap(),
            VehicleClock::system(),
            "no file: no offset"
        );
        std::fs::write(&file, "-1500\n").unwrap();
        let behind = VehicleClock::from_file(&file).unwrap();
        assert_eq!(behind.offset_ns(), -1_500_000_000);
        let (now, then) = (clock.now_ns(), behind.now_ns());
        assert!(now > then && now - then >= 1_500_000_000 - 1_000_000);
        std::fs::write(&file, "soon").unwrap();
        let err = VehicleClock::from_file(&file).unwrap_err().to_string();
        assert!(err.contains("soon") && err.contains("offset"), "{err}");
        assert_ne!(clock.new_epoch(), 0);
        assert_ne!(clock.new_epoch(), clock.new_epoch());
    }

    /// A machine up for 23 minutes and a clock an hour behind it: the readings go below zero and
    /// keep their pace; none is 0 (untimed) and none sticks at a bound.
    #[test]
    fn a_clock_behind_by_more_than_the_uptime_reads_below_zero_at_its_pace() {
        const S: u64 = 1_000_000_000;
        let hour_back = -3_600 * S as i64;
        let up = 1_403 * S;
        let readings: Vec<i64> = (0..5)
            .map(|k| VehicleClock::reading(up + k * S / 5, hour_back))
            .collect();
        assert_eq!(readings[0], (1_403 - 3_600) * S as i64);
        assert!(
            readings.windows(2).all(|w| w[1] - w[0] == (S / 5) as i64),
            "{readings:?}"
        );
        assert_eq!(
            VehicleClock::reading(5 * S, -5 * S as i64),
            1,
            "0 is no reading"
        );
        assert_eq!(VehicleClock::reading(5 * S, -5 * S as i64 - 1), -1);
        assert_eq!(VehicleClock::reading(u64::MAX, i64::MAX), i64::MAX);
        let behind = VehicleClock::with_offset(-(monotonic_ns() as i64) - 3_600 * S as i64);
        let (a, b) = (behind.now_ns(), behind.now_ns());
        assert!(a < 0 && b >= a, "{a} {b}");
    }

    #[test]
    fn the_wall_clock_reads_the_time_since_1970() {
        // 2020-09-13 in ns: a wall clock below it is not read in ns since 1970.
        assert!(unix_ns() > 1_600_000_000_000_000_000);
        let a = monotonic_ns();
        assert!(monotonic_ns() >= a && a > 0);
    }
}
