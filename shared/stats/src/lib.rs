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

/// A confidence interval for the `q`-quantile of the distribution `n` independent samples were drawn
/// from, without assuming its shape: the 0-based indices `(lo, hi)` into the sorted samples such that
/// `v[lo] <= quantile <= v[hi]` with probability at least `confidence`. The number of samples below
/// the quantile is binomial (n, q); each end leaves at most `(1 - confidence) / 2` of that
/// distribution outside. `None` when `n` is too small for it (the interval would reach past the
/// smallest or the largest sample: 1,000 samples bound a p99 at 95%, 300 do not), or for `q` or
/// `confidence` outside (0, 1).
pub fn quantile_interval(n: usize, q: f64, confidence: f64) -> Option<(usize, usize)> {
    if n == 0 || !(q > 0.0 && q < 1.0) || !(confidence > 0.0 && confidence < 1.0) {
        return None;
    }
    let tail = 0.5 * (1.0 - confidence);
    // ln P(B = k) for B ~ binomial(n, q), by the ratio of consecutive terms (no factorials to
    // overflow), then scaled by the largest term before leaving the logarithms.
    let odds = (q / (1.0 - q)).ln();
    let mut ln_p = Vec::with_capacity(n + 1);
    let mut l = n as f64 * (1.0 - q).ln();
    for k in 0..=n {
        ln_p.push(l);
        l += ((n - k) as f64 / (k + 1) as f64).ln() + odds;
    }
    let top = ln_p.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let p: Vec<f64> = ln_p.iter().map(|&l| (l - top).exp()).collect();
    let total: f64 = p.iter().sum();
    // The sorted sample of index i (0-based) is at or below the quantile when B >= i + 1: the lower
    // end is the highest index with P(B <= lo) <= tail, the upper the lowest with P(B > hi) <= tail.
    let mut below = 0.0;
    let mut lo = None;
    for (i, &pk) in p.iter().enumerate().take(n) {
        below += pk / total;
        if below > tail {
            break;
        }
        lo = Some(i);
    }
    let mut above = 0.0;
    let mut hi = None;
    for i in (0..n).rev() {
        above += p[i + 1] / total;
        if above > tail {
            break;
        }
        hi = Some(i);
    }
    Some((lo?, hi?))
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
    fn quantile_intervals_come_from_the_binomial() {
        // The textbook 95% interval of the median of 100 samples: the 40th to the 61st.
        assert_eq!(quantile_interval(100, 0.5, 0.95), Some((39, 60)));
        // 1,000 samples bound their p99 (the 990th) at 95%; 300 do not (0.99^300 = 0.049 is the chance
        // that none is above it).
        let (lo, hi) = quantile_interval(1000, 0.99, 0.95).unwrap();
        assert!(lo < 989 && 989 < hi && hi < 999, "({lo}, {hi})");
        assert_eq!(quantile_interval(300, 0.99, 0.95), None);
        assert_eq!(quantile_interval(0, 0.5, 0.95), None);
        assert_eq!(quantile_interval(100, 1.0, 0.95), None);
        assert_eq!(quantile_interval(100, 0.5, 1.0), None);
        // A wider confidence, a wider interval.
        let (lo99, hi99) = quantile_interval(1000, 0.99, 0.99).unwrap();
        assert!(lo99 < lo && hi99 >= hi);
    }

    /// Samples of an exponential distribution (its q-quantile is -ln(1 - q)) from a xorshift
    /// generator: the p99's 95% interval over 1,000 samples holds the true p99 in 2,000 draws as
    /// often as the binomial says (its exact coverage, at least 95%), within three standard errors
    /// of the count; for three seeds.
    #[test]
    fn a_quantile_interval_holds_the_quantile_as_often_as_it_says() {
        let (n, q, draws) = (1000, 0.99, 2000);
        let (lo, hi) = quantile_interval(n, q, 0.95).unwrap();
        let truth = -(1.0f64 - q).ln();
        // The exact coverage P(lo < B <= hi) of B ~ binomial(n, q), summed in logarithms.
        let ln_pmf = |k: usize| {
            let ln_choose: f64 = (0..k).map(|i| ((n - i) as f64 / (i + 1) as f64).ln()).sum();
            ln_choose + k as f64 * q.ln() + (n - k) as f64 * (1.0 - q).ln()
        };
        let exact: f64 = (lo + 1..=hi).map(|k| ln_pmf(k).exp()).sum();
        assert!((0.95..0.99).contains(&exact), "{exact}");
        let se = (exact * (1.0 - exact) / draws as f64).sqrt();
        for seed in [
            0x9e37_79b9_7f4a_7c15_u64,
            0x2545_f491_4f6c_dd1d,
            0xdead_beef_cafe_f00d,
        ] {
            let mut state = seed;
            let mut uniform = || {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                (state >> 11) as f64 / (1u64 << 53) as f64
            };
            let mut held = 0;
            for _ in 0..draws {
                let mut v: Vec<f64> = (0..n).map(|_| -(1.0 - uniform()).ln()).collect();
                v.sort_by(f64::total_cmp);
                held += usize::from(v[lo] <= truth && truth <= v[hi]);
            }
            let coverage = held as f64 / draws as f64;
            assert!(
                (coverage - exact).abs() <= 3.0 * se,
                "seed {seed:#x}: held {coverage} against {exact} (se {se})"
            );
        }
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
