//! The few statistics every report, test and benchmark uses, defined once.
//!
//! Conventions: an empty input gives NaN (or an all-zero [`Summary`]), never a panic; NaN inputs
//! sort last (`f64::total_cmp`); percentiles are nearest-rank, so a reported p99 is a value that was
//! actually observed.

use serde::{Deserialize, Serialize};

/// The arithmetic mean; NaN when empty.
pub fn mean(values: impl IntoIterator<Item = f64>) -> f64 {
    let (sum, n) = values
        .into_iter()
        .fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
    if n == 0 { f64::NAN } else { sum / n as f64 }
}

/// The median (the mean of the two middle values of an even count); NaN when empty.
pub fn median(values: impl IntoIterator<Item = f64>) -> f64 {
    let v = sorted(values);
    match v.len() {
        0 => f64::NAN,
        n if n % 2 == 1 => v[n / 2],
        n => 0.5 * (v[n / 2 - 1] + v[n / 2]),
    }
}

/// The nearest-rank percentile `q` in [0, 1] (0.5: the lower median, 1: the maximum); NaN when
/// empty.
pub fn percentile(values: impl IntoIterator<Item = f64>, q: f64) -> f64 {
    let v = sorted(values);
    if v.is_empty() {
        return f64::NAN;
    }
    v[rank(v.len(), q)]
}

/// The smallest and largest value; `None` when empty.
pub fn range(values: impl IntoIterator<Item = f64>) -> Option<(f64, f64)> {
    values.into_iter().fold(None, |r, v| match r {
        None => Some((v, v)),
        Some((lo, hi)) => Some((lo.min(v), hi.max(v))),
    })
}

fn sorted(values: impl IntoIterator<Item = f64>) -> Vec<f64> {
    let mut v: Vec<f64> = values.into_iter().collect();
    v.sort_by(f64::total_cmp);
    v
}

/// The index of the nearest-rank percentile `q` among `n` sorted values (`n > 0`).
fn rank(n: usize, q: f64) -> usize {
    ((q.clamp(0.0, 1.0) * n as f64).ceil() as usize).clamp(1, n) - 1
}

/// A distribution of durations or counts (nanoseconds, say): its size, median, 99th percentile,
/// maximum and mean.
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
            p50: v[rank(v.len(), 0.50)],
            p99: v[rank(v.len(), 0.99)],
            max: v[v.len() - 1],
            mean: v.iter().map(|&x| x as f64).sum::<f64>() / v.len() as f64,
        }
    }

    /// The median of several runs' summaries, field by field (the max is the largest of all runs;
    /// empty runs are left out).
    pub fn median_of(runs: &[Summary]) -> Summary {
        let runs: Vec<&Summary> = runs.iter().filter(|s| s.n > 0).collect();
        if runs.is_empty() {
            return Summary::default();
        }
        Summary {
            n: runs.iter().map(|s| s.n).sum(),
            p50: median(runs.iter().map(|s| s.p50 as f64)).round() as u64,
            p99: median(runs.iter().map(|s| s.p99 as f64)).round() as u64,
            max: runs.iter().map(|s| s.max).max().unwrap_or(0),
            mean: median(runs.iter().map(|s| s.mean)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn means_and_medians() {
        assert_eq!(mean([1.0, 2.0, 6.0]), 3.0);
        assert!(mean([]).is_nan());
        assert_eq!(median([3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median([4.0, 1.0, 2.0, 3.0]), 2.5);
        assert!(median([]).is_nan());
        assert_eq!(range([2.0, -1.0, 5.0]), Some((-1.0, 5.0)));
        assert_eq!(range([]), None);
    }

    #[test]
    fn nearest_rank_percentiles() {
        let v: Vec<f64> = (1..=100).rev().map(f64::from).collect();
        assert_eq!(percentile(v.iter().copied(), 0.5), 50.0);
        assert_eq!(percentile(v.iter().copied(), 0.99), 99.0);
        assert_eq!(percentile(v.iter().copied(), 1.0), 100.0);
        assert_eq!(percentile(v.iter().copied(), 0.0), 1.0);
        assert_eq!(percentile([7.0], 0.99), 7.0);
        assert!(percentile([], 0.5).is_nan());
        let s = Summary::of(&(1..=100).rev().collect::<Vec<u64>>());
        assert_eq!((s.n, s.p50, s.p99, s.max), (100, 50, 99, 100));
        assert_eq!(s.mean, 50.5);
        assert_eq!(Summary::of(&[]), Summary::default());
    }

    #[test]
    fn the_median_of_runs_takes_each_field_and_the_largest_max() {
        let runs = [
            Summary::of(&[1, 2, 3]),
            Summary::of(&[10, 20, 30]),
            Summary::of(&[5]),
        ];
        let m = Summary::median_of(&runs);
        assert_eq!((m.n, m.p50, m.max), (7, 5, 30));
        assert_eq!(Summary::median_of(&[]), Summary::default());
    }
}
