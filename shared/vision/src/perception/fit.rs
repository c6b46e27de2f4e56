//! The least-squares fit of a cable's two edges as two parallel lines: one common direction (the
//! pooled scatter of both edges' points, each about its own mean: total least squares), one offset
//! per edge. Points are gated by gradient direction and by distance, with the gate shrinking over a few
//! iterations.

use super::edges::EdgePoint;
use super::hough::Hypothesis;

/// The fitted pair: centre line `normal . p = centre`, signed half width (see [`Hypothesis`]), the
/// number of points on each edge (the edge whose gradient points along `normal` first) and the RMS
/// distance of the points from their edge.
#[derive(Clone, Copy, Debug)]
pub(crate) struct PairFit {
    pub normal: [f64; 2],
    pub centre: f64,
    pub half: f64,
    pub counts: [usize; 2],
    pub rms: f64,
}

/// Along-line segments for [`coverage`].
pub(crate) const SEGMENTS: usize = 16;

#[derive(Clone, Copy, Default)]
struct Sums {
    n: f64,
    x: f64,
    y: f64,
    xx: f64,
    xy: f64,
    yy: f64,
}

impl Sums {
    fn add(&mut self, x: f64, y: f64) {
        self.n += 1.0;
        self.x += x;
        self.y += y;
        self.xx += x * x;
        self.xy += x * y;
        self.yy += y * y;
    }

    fn mean(&self) -> [f64; 2] {
        [self.x / self.n, self.y / self.n]
    }

    /// The scatter matrix about the mean: (sxx, sxy, syy).
    fn scatter(&self) -> [f64; 3] {
        let [mx, my] = self.mean();
        [
            self.xx - self.n * mx * mx,
            self.xy - self.n * mx * my,
            self.yy - self.n * my * my,
        ]
    }
}

/// Fits the pair starting from `start`; `cos_tol` is the cosine of the largest angle between a point's
/// gradient and the edge normal, `radii` the distance gates of the successive iterations (pixels).
/// `None` when an edge has fewer than `min_points` points or the polarity flips.
pub(crate) fn fit_pair(
    edges: &[EdgePoint],
    start: &Hypothesis,
    cos_tol: f64,
    radii: &[f64],
    min_points: usize,
) -> Option<PairFit> {
    let (mut n, mut centre, mut half) = (start.normal, start.centre, start.half);
    let min_points = min_points.max(3);
    for &radius in radii {
        let sums = gather(edges, n, centre, half, cos_tol, radius, |_, _, _| {});
        if (sums[0].n as usize) < min_points || (sums[1].n as usize) < min_points {
            return None;
        }
        let [a, b] = [sums[0].scatter(), sums[1].scatter()];
        let (sxx, sxy, syy) = (a[0] + b[0], a[1] + b[1], a[2] + b[2]);
        // The direction of largest spread is the edges' direction; the normal is perpendicular.
        let phi = 0.5 * (2.0 * sxy).atan2(sxx - syy);
        let mut m = [-phi.sin(), phi.cos()];
        if m[0] * n[0] + m[1] * n[1] < 0.0 {
            m = [-m[0], -m[1]];
        }
        let (ma, mb) = (sums[0].mean(), sums[1].mean());
        let oa = m[0] * ma[0] + m[1] * ma[1];
        let ob = m[0] * mb[0] + m[1] * mb[1];
        let new_half = 0.5 * (oa - ob);
        if new_half * half <= 0.0 {
            return None;
        }
        n = m;
        centre = 0.5 * (oa + ob);
        half = new_half;
    }
    let last = *radii.last()?;
    let mut sq = 0.0;
    let sums = gather(edges, n, centre, half, cos_tol, last, |_, r, _| sq += r * r);
    let total = sums[0].n + sums[1].n;
    Some(PairFit {
        normal: n,
        centre,
        half,
        counts: [sums[0].n as usize, sums[1].n as usize],
        rms: if total > 0.0 {
            (sq / total).sqrt()
        } else {
            0.0
        },
    })
}

/// The fraction of the visible line, from `from` to `to` (its two border crossings) cut into
/// [`SEGMENTS`] segments, in which both edges of `fit` have points: a cable crosses the image, a
/// blob with two short parallel sides does not.
pub(crate) fn coverage(
    edges: &[EdgePoint],
    fit: &PairFit,
    cos_tol: f64,
    radius: f64,
    from: [f64; 2],
    to: [f64; 2],
) -> f64 {
    let d = [to[0] - from[0], to[1] - from[1]];
    let len2 = d[0] * d[0] + d[1] * d[1];
    if len2 < 1.0 {
        return 0.0;
    }
    let mut seen = [0u32; 2];
    gather(
        edges,
        fit.normal,
        fit.centre,
        fit.half,
        cos_tol,
        radius,
        |edge, _, p| {
            let t = ((p[0] - from[0]) * d[0] + (p[1] - from[1]) * d[1]) / len2;
            let k = (t * SEGMENTS as f64)
                .floor()
                .clamp(0.0, (SEGMENTS - 1) as f64) as u32;
            seen[edge] |= 1 << k;
        },
    );
    (seen[0] & seen[1]).count_ones() as f64 / SEGMENTS as f64
}

/// The sums of the points of each edge within `radius` of where the model puts that edge; `each` sees
/// every accepted point's edge, residual and position.
fn gather(
    edges: &[EdgePoint],
    n: [f64; 2],
    centre: f64,
    half: f64,
    cos_tol: f64,
    radius: f64,
    mut each: impl FnMut(usize, f64, [f64; 2]),
) -> [Sums; 2] {
    let mut sums = [Sums::default(); 2];
    let (nx, ny) = (n[0] as f32, n[1] as f32);
    let cos_tol = cos_tol as f32;
    for p in edges {
        let dot = p.gx * nx + p.gy * ny;
        let edge = if dot >= cos_tol {
            0
        } else if dot <= -cos_tol {
            1
        } else {
            continue;
        };
        let (x, y) = (p.x as f64, p.y as f64);
        let expected = if edge == 0 {
            centre + half
        } else {
            centre - half
        };
        let r = n[0] * x + n[1] * y - expected;
        if r.abs() <= radius {
            sums[edge].add(x, y);
            each(edge, r, [x, y]);
        }
    }
    sums
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_a_tilted_pair() {
        // A dark cable: centre line through (5, -3) at 20 degrees from vertical, 14 px wide.
        let t = 20f64.to_radians();
        let e = [t.sin(), -t.cos()];
        let n = [t.cos(), t.sin()];
        let c0 = [5.0, -3.0];
        let mut edges = Vec::new();
        for k in -100..100 {
            let s = k as f64;
            for (side, g) in [(7.0, 1.0), (-7.0, -1.0)] {
                // A little deterministic jitter across the edge.
                let jitter = 0.3 * ((k * 7 + side as i32) as f64).sin();
                let x = c0[0] + s * e[0] + (side + jitter) * n[0];
                let y = c0[1] + s * e[1] + (side + jitter) * n[1];
                edges.push(EdgePoint {
                    x: x as f32,
                    y: y as f32,
                    gx: (g * n[0]) as f32,
                    gy: (g * n[1]) as f32,
                });
            }
        }
        // Clutter that must be gated out.
        edges.push(EdgePoint {
            x: 40.0,
            y: 0.0,
            gx: 1.0,
            gy: 0.0,
        });
        let start = Hypothesis {
            normal: [(t + 0.03).cos(), (t + 0.03).sin()],
            centre: n[0] * c0[0] + n[1] * c0[1] + 2.0,
            half: 6.0,
            score: 0,
        };
        let fit = fit_pair(&edges, &start, 0.8, &[6.0, 3.0, 1.5], 10).unwrap();
        assert!(
            (fit.normal[0] - n[0]).abs() < 1e-3 && (fit.normal[1] - n[1]).abs() < 1e-3,
            "{fit:?}"
        );
        assert!(
            (fit.centre - (n[0] * c0[0] + n[1] * c0[1])).abs() < 0.05,
            "{fit:?}"
        );
        assert!((fit.half - 7.0).abs() < 0.05);
        assert_eq!(fit.counts, [200, 200]);
    }
}
