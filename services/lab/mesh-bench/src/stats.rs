//! The clock every process reads, and latency summaries.

use serde::{Deserialize, Serialize};

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

/// A latency distribution in nanoseconds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    pub n: usize,
    pub p50: u64,
    pub p99: u64,
    pub max: u64,
    pub mean: f64,
}

impl Summary {
    /// The summary of `values` (nearest-rank percentiles); all zero when empty.
    pub fn of(values: &[u64]) -> Summary {
        if values.is_empty() {
            return Summary::default();
        }
        let mut v = values.to_vec();
        v.sort_unstable();
        Summary {
            n: v.len(),
            p50: percentile(&v, 0.50),
            p99: percentile(&v, 0.99),
            max: v[v.len() - 1],
            mean: v.iter().map(|&x| x as f64).sum::<f64>() / v.len() as f64,
        }
    }
}

/// The nearest-rank percentile `q` (0..=1) of sorted `v` (not empty).
fn percentile(v: &[u64], q: f64) -> u64 {
    let rank = (q * v.len() as f64).ceil() as usize;
    v[rank.clamp(1, v.len()) - 1]
}

/// The median of `v` (the upper one of an even count); NaN when empty.
pub fn median(v: impl IntoIterator<Item = f64>) -> f64 {
    let mut v: Vec<f64> = v.into_iter().collect();
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// The median of the runs' summaries, field by field (the max is the largest of all runs).
pub fn median_summary(runs: &[Summary]) -> Summary {
    let runs: Vec<&Summary> = runs.iter().filter(|s| s.n > 0).collect();
    if runs.is_empty() {
        return Summary::default();
    }
    Summary {
        n: runs.iter().map(|s| s.n).sum(),
        p50: median(runs.iter().map(|s| s.p50 as f64)) as u64,
        p99: median(runs.iter().map(|s| s.p99 as f64)) as u64,
        max: runs.iter().map(|s| s.max).max().unwrap_or(0),
        mean: median(runs.iter().map(|s| s.mean)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_rank_percentiles() {
        let v: Vec<u64> = (1..=100).rev().collect();
        let s = Summary::of(&v);
        assert_eq!((s.n, s.p50, s.p99, s.max), (100, 50, 99, 100));
        assert_eq!(s.mean, 50.5);
        let one = Summary::of(&[7]);
        assert_eq!((one.p50, one.p99, one.max), (7, 7, 7));
        assert_eq!(Summary::of(&[]), Summary::default());
    }

    #[test]
    fn medians_of_runs() {
        assert_eq!(median([3.0, 1.0, 2.0]), 2.0);
        assert!(median([]).is_nan());
        let a = Summary::of(&[10, 20, 30]);
        let b = Summary::of(&[1, 2, 300]);
        let c = Summary::of(&[5, 6, 7]);
        let m = median_summary(&[a, b, c, Summary::default()]);
        assert_eq!((m.n, m.p50, m.p99, m.max), (9, 6, 30, 300));
    }

    #[test]
    fn the_clock_moves_forward() {
        let a = now_ns();
        let b = now_ns();
        assert!(b >= a && a > 0);
    }
}
