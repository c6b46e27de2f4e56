//! A gradient-directed Hough transform over signed line normals, and the pairing of its peaks into
//! cable hypotheses.
//!
//! Each edge point votes only near its own gradient direction `phi` (in [0, 2 pi): the polarity is
//! kept), for `rho = x cos(phi) + y sin(phi)`. A dark cable of width w on a light floor then shows as
//! two peaks with opposite normals whose rhos add up to +w (its two edges' gradients point outwards);
//! a light cable's add up to -w.

use super::edges::EdgePoint;
use config::CablePolarity;
use std::f64::consts::{PI, TAU};

#[derive(Clone, Copy, Debug)]
pub(crate) struct Peak {
    pub votes: u32,
    pub angle: usize,
    pub rho: usize,
}

/// A cable hypothesis: the centre line `normal . p = centre`, and the signed half width `half`: the
/// edge whose gradient points along `normal` lies at `centre + half` (so `half > 0` for a dark cable).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Hypothesis {
    pub normal: [f64; 2],
    pub centre: f64,
    pub half: f64,
    pub score: u32,
}

pub(crate) struct Hough {
    n_angle: usize,
    n_rho: usize,
    angle_step: f64,
    rho_step: f64,
    rho_max: f64,
    cos: Vec<f32>,
    sin: Vec<f32>,
    acc: Vec<u16>,
    /// Per angle cell, the rho cells voted in since the accumulator was last cleared (`lo > hi`:
    /// none). A tracking band's points touch a few rows of the accumulator: clearing it and looking
    /// for peaks visit only these cells, everything else is zero.
    touched: Vec<RhoRange>,
    peaks: Vec<Peak>,
}

#[derive(Clone, Copy, Debug)]
struct RhoRange {
    lo: usize,
    hi: usize,
}

impl RhoRange {
    const NONE: RhoRange = RhoRange {
        lo: usize::MAX,
        hi: 0,
    };
}

impl Hough {
    /// An accumulator of `angle_step_deg` x `rho_step` cells for |rho| <= `rho_max`.
    pub fn new(angle_step_deg: f64, rho_step: f64, rho_max: f64) -> Self {
        let n_angle = (360.0 / angle_step_deg).round().max(8.0) as usize;
        let angle_step = TAU / n_angle as f64;
        let n_rho = (2.0 * rho_max / rho_step).ceil() as usize + 1;
        Hough {
            n_angle,
            n_rho,
            angle_step,
            rho_step,
            rho_max,
            cos: (0..n_angle)
                .map(|a| (a as f64 * angle_step).cos() as f32)
                .collect(),
            sin: (0..n_angle)
                .map(|a| (a as f64 * angle_step).sin() as f32)
                .collect(),
            acc: vec![0; n_angle * n_rho],
            touched: vec![RhoRange::NONE; n_angle],
            peaks: Vec::with_capacity(64),
        }
    }

    pub fn angle_of(&self, a: usize) -> f64 {
        a as f64 * self.angle_step
    }

    pub fn rho_of(&self, r: usize) -> f64 {
        r as f64 * self.rho_step - self.rho_max
    }

    /// Clears the accumulator and lets every point vote for `spread` angle cells either side of its
    /// gradient's.
    pub fn vote(&mut self, edges: &[EdgePoint], spread: usize) {
        let nr = self.n_rho;
        for (a, t) in self.touched.iter_mut().enumerate() {
            if t.lo <= t.hi {
                self.acc[a * nr + t.lo..=a * nr + t.hi].fill(0);
            }
            *t = RhoRange::NONE;
        }
        let n = self.n_angle as isize;
        let inv_angle = (1.0 / self.angle_step) as f32;
        let inv_rho = (1.0 / self.rho_step) as f32;
        let offset = (self.rho_max / self.rho_step) as f32 + 0.5;
        let last = (self.n_rho - 1) as f32;
        let n_angle = self.n_angle;
        for p in edges {
            let phi = fast_atan2(p.gy, p.gx);
            let a0 = (phi * inv_angle).round() as isize;
            // The angle cells a0 - spread ..= a0 + spread, wrapped: one division per point.
            let mut a = (a0 - spread as isize).rem_euclid(n) as usize;
            for _ in 0..=2 * spread {
                let rho = p.x * self.cos[a] + p.y * self.sin[a];
                let r = (rho * inv_rho + offset).clamp(0.0, last) as usize;
                let cell = &mut self.acc[a * nr + r];
                *cell = cell.saturating_add(1);
                let t = &mut self.touched[a];
                t.lo = t.lo.min(r);
                t.hi = t.hi.max(r);
                a += 1;
                if a == n_angle {
                    a = 0;
                }
            }
        }
    }

    /// The strongest local maxima (at most `max_peaks`) with at least `min_votes` votes, strongest first.
    /// An untouched cell holds zero votes and is never a peak, so only the touched cells are scanned
    /// (in the order of the whole accumulator's scan: the same peaks, in the same order).
    pub fn peaks(&mut self, min_votes: u32, max_peaks: usize) -> &[Peak] {
        self.peaks.clear();
        let (na, nr) = (self.n_angle, self.n_rho);
        for a in 0..na {
            let RhoRange { lo, hi } = self.touched[a];
            if lo > hi {
                continue;
            }
            let prev = (a + na - 1) % na;
            let next = (a + 1) % na;
            for r in lo..=hi {
                let v = self.acc[a * nr + r];
                if (v as u32) < min_votes {
                    continue;
                }
                let at = |aa: usize, rr: isize| -> u16 {
                    if rr < 0 || rr >= nr as isize {
                        0
                    } else {
                        self.acc[aa * nr + rr as usize]
                    }
                };
                let ri = r as isize;
                // Strictly above the cells scanned before, at least the ones after (one peak per plateau).
                let before = [
                    at(prev, ri - 1),
                    at(prev, ri),
                    at(prev, ri + 1),
                    at(a, ri - 1),
                ];
                let after = [
                    at(a, ri + 1),
                    at(next, ri - 1),
                    at(next, ri),
                    at(next, ri + 1),
                ];
                if before.iter().any(|&b| b >= v) || after.iter().any(|&b| b > v) {
                    continue;
                }
                let peak = Peak {
                    votes: v as u32,
                    angle: a,
                    rho: r,
                };
                if self.peaks.len() < max_peaks {
                    self.peaks.push(peak);
                } else if let Some(weakest) = self.peaks.iter_mut().min_by_key(|p| p.votes)
                    && weakest.votes < peak.votes
                {
                    *weakest = peak;
                }
            }
        }
        self.peaks
            .sort_unstable_by_key(|p| std::cmp::Reverse(p.votes));
        &self.peaks
    }

    /// Pairs of the last peaks that can be a cable's two edges: antiparallel within `parallel_tol`
    /// (rad), rhos adding up to the expected width within `width_tol` (relative) and the polarity.
    /// The best `max` by total votes go to `out`, best first.
    #[allow(clippy::too_many_arguments)]
    pub fn pairs(
        &self,
        width_px: f64,
        width_tol: f64,
        parallel_tol: f64,
        polarity: CablePolarity,
        max: usize,
        out: &mut Vec<Hypothesis>,
    ) {
        out.clear();
        let slack = self.rho_step;
        let (lo, hi) = (
            width_px * (1.0 - width_tol) - slack,
            width_px * (1.0 + width_tol) + slack,
        );
        let peaks = &self.peaks;
        for (i, a) in peaks.iter().enumerate() {
            for b in &peaks[i + 1..] {
                let (phi_a, phi_b) = (self.angle_of(a.angle), self.angle_of(b.angle));
                let d = wrap_pi(phi_b - phi_a - PI);
                if d.abs() > parallel_tol + 0.5 * self.angle_step {
                    continue;
                }
                let sum = self.rho_of(a.rho) + self.rho_of(b.rho);
                let ok = match polarity {
                    CablePolarity::Dark => (lo..=hi).contains(&sum),
                    CablePolarity::Bright => (lo..=hi).contains(&-sum),
                    CablePolarity::Any => (lo..=hi).contains(&sum.abs()),
                };
                if !ok {
                    continue;
                }
                let phi = phi_a + 0.5 * d;
                let h = Hypothesis {
                    normal: [phi.cos(), phi.sin()],
                    centre: 0.5 * (self.rho_of(a.rho) - self.rho_of(b.rho)),
                    half: 0.5 * sum,
                    score: a.votes + b.votes,
                };
                if out.len() < max {
                    out.push(h);
                } else if let Some(worst) = out.iter_mut().min_by_key(|h| h.score)
                    && worst.score < h.score
                {
                    *worst = h;
                }
            }
        }
        out.sort_unstable_by_key(|h| std::cmp::Reverse(h.score));
    }
}

fn wrap_pi(a: f64) -> f64 {
    let w = a.rem_euclid(TAU);
    if w > PI { w - TAU } else { w }
}

/// atan2 in [0, 2 pi) to within 0.005 rad (enough to pick a Hough cell of a degree or more).
fn fast_atan2(y: f32, x: f32) -> f32 {
    use std::f32::consts::{FRAC_PI_2, FRAC_PI_4, PI, TAU};
    let (ax, ay) = (x.abs(), y.abs());
    let big = ax.max(ay);
    if big == 0.0 {
        return 0.0;
    }
    let z = ax.min(ay) / big;
    // atan(z) on [0, 1] (Rajan et al. 2006), max error 0.0015 rad.
    let mut a = FRAC_PI_4 * z + 0.273 * z * (1.0 - z);
    if ay > ax {
        a = FRAC_PI_2 - a;
    }
    if x < 0.0 {
        a = PI - a;
    }
    if y < 0.0 {
        a = TAU - a;
    }
    if a >= TAU { a - TAU } else { a }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_atan2_is_close() {
        for k in 0..3600 {
            let t = k as f64 * TAU / 3600.0;
            let (y, x) = ((3.0 * t.sin()) as f32, (3.0 * t.cos()) as f32);
            let a = fast_atan2(y, x) as f64;
            assert!(wrap_pi(a - t).abs() < 0.005, "{t} {a}");
        }
    }

    /// Voting clears only the cells the last vote touched: after a vote over one set of points, the
    /// accumulator and the peaks of a vote over another are those of a fresh transform, spreads
    /// wrapping past angle 0 included.
    #[test]
    fn a_vote_leaves_nothing_of_the_last_one() {
        let line = |x0: f32, gx: f32, gy: f32| -> Vec<EdgePoint> {
            (-80..80)
                .map(|k| EdgePoint {
                    x: x0 + 0.1 * k as f32,
                    y: k as f32,
                    gx,
                    gy,
                })
                .collect()
        };
        let first: Vec<EdgePoint> = [line(-30.0, 1.0, 0.0), line(40.0, 0.6, 0.8)].concat();
        // Gradients just either side of angle 0, whose votes wrap around the accumulator.
        let second: Vec<EdgePoint> = [line(10.0, 0.9995, -0.03), line(25.0, 0.9995, 0.03)].concat();
        let mut reused = Hough::new(2.0, 2.0, 200.0);
        reused.vote(&first, 2);
        assert!(!reused.peaks(20, 16).is_empty());
        reused.vote(&second, 3);
        let mut fresh = Hough::new(2.0, 2.0, 200.0);
        fresh.vote(&second, 3);
        assert!(reused.acc == fresh.acc, "cells of the first vote remain");
        let key = |p: &Peak| (p.votes, p.angle, p.rho);
        let a: Vec<_> = reused.peaks(20, 16).iter().map(key).collect();
        let b: Vec<_> = fresh.peaks(20, 16).iter().map(key).collect();
        assert!(!a.is_empty() && a == b, "{a:?} against {b:?}");
        assert!(
            a.iter().any(|&(_, angle, _)| angle > 170),
            "the votes wrapped past angle 0: {a:?}"
        );
    }

    /// Two antiparallel edges 14 px apart (a dark vertical cable centred at x = 10) pair up.
    #[test]
    fn a_dark_cable_is_a_pair_of_peaks() {
        let mut edges = Vec::new();
        for y in -100..100 {
            let y = y as f32;
            edges.push(EdgePoint {
                x: 3.0,
                y,
                gx: -1.0,
                gy: 0.0,
            });
            edges.push(EdgePoint {
                x: 17.0,
                y,
                gx: 1.0,
                gy: 0.0,
            });
        }
        let mut h = Hough::new(2.0, 2.0, 200.0);
        h.vote(&edges, 1);
        assert_eq!(h.peaks(20, 16).len(), 2);
        let mut out = Vec::new();
        h.pairs(
            14.0,
            0.3,
            5f64.to_radians(),
            CablePolarity::Dark,
            4,
            &mut out,
        );
        assert_eq!(out.len(), 1);
        let c = out[0];
        // The centre line x = 10, in the normal's own sign.
        let along_x = c.normal[0].signum();
        assert!((c.centre * along_x - 10.0).abs() < 1.5, "{c:?}");
        assert!((c.half - 7.0).abs() < 1.5 && c.half > 0.0);
        h.pairs(
            14.0,
            0.3,
            5f64.to_radians(),
            CablePolarity::Bright,
            4,
            &mut out,
        );
        assert!(out.is_empty());
    }
}
