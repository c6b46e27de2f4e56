//! Edge points: Sobel gradients, a noise-adaptive threshold, non-maximum suppression along the
//! gradient (thin edges, as Canny) and sub-pixel positions from a parabola through the magnitudes.

/// One edge point in centred full-resolution pixel coordinates, with its unit gradient direction
/// (pointing from dark to bright).
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct EdgePoint {
    pub x: f32,
    pub y: f32,
    pub gx: f32,
    pub gy: f32,
}

/// Gradient images of one resolution level, reused from frame to frame. Only the magnitude is kept
/// for every pixel (the threshold needs them all): the gradient's two components are computed again
/// at the few pixels above the threshold, which leaves a frame two images fewer to write and read.
pub(crate) struct Gradients {
    width: usize,
    height: usize,
    /// Smooth with a 3x3 binomial before the Sobel operator (a 5x5 derivative-of-binomial kernel).
    smooth: bool,
    smoothed: Vec<u16>,
    mag: Vec<u16>,
    hist: Vec<u32>,
    nms_spans: Vec<Span>,
    sobel_spans: Vec<Span>,
    smooth_spans: Vec<Span>,
}

/// Columns `[lo, hi]` of one row (empty when `lo > hi`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Span {
    pub lo: u16,
    pub hi: u16,
}

impl Span {
    pub const EMPTY: Span = Span { lo: 1, hi: 0 };

    fn is_empty(self) -> bool {
        self.lo > self.hi
    }

    /// The smallest span holding both.
    fn union(self, other: Span) -> Span {
        if self.is_empty() {
            other
        } else if other.is_empty() {
            self
        } else {
            Span {
                lo: self.lo.min(other.lo),
                hi: self.hi.max(other.hi),
            }
        }
    }

    /// One more column on each side, within `[lo, hi]`.
    fn widened(self, lo: usize, hi: usize) -> Span {
        if self.is_empty() {
            return self;
        }
        let s = Span {
            lo: (self.lo as usize).saturating_sub(1).max(lo) as u16,
            hi: (self.hi as usize + 1).min(hi) as u16,
        };
        if s.lo > s.hi { Span::EMPTY } else { s }
    }
}

/// For each row, the union of `inner`'s spans of the row and its two neighbours, one column wider,
/// within columns and rows `[border, size - 1 - border]`.
fn grow(inner: &[Span], out: &mut [Span], width: usize, border: usize) {
    let h = inner.len();
    for (j, o) in out.iter_mut().enumerate() {
        *o = Span::EMPTY;
        if j < border || j + border >= h {
            continue;
        }
        let mut s = inner[j];
        if j > 0 {
            s = s.union(inner[j - 1]);
        }
        if j + 1 < h {
            s = s.union(inner[j + 1]);
        }
        *o = s.widened(border, width - 1 - border);
    }
}

/// How a level's pixels map to full-resolution centred coordinates: `x = scale * (i + 0.5) - W/2`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct LevelMap {
    pub scale: f32,
    pub half_width: f32,
    pub half_height: f32,
}

/// The outcome of one extraction.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct EdgeStats {
    /// The point budget ran out before the region was scanned.
    pub saturated: bool,
}

const HIST_SHIFT: u32 = 2;
const HIST_BINS: usize = (2040 >> HIST_SHIFT) + 1;

impl Gradients {
    pub fn new(width: usize, height: usize, smooth: bool) -> Self {
        Gradients {
            width,
            height,
            smooth,
            smoothed: if smooth {
                vec![0; width * height]
            } else {
                Vec::new()
            },
            mag: vec![0; width * height],
            hist: vec![0; HIST_BINS],
            nms_spans: vec![Span::EMPTY; height],
            sobel_spans: vec![Span::EMPTY; height],
            smooth_spans: vec![Span::EMPTY; height],
        }
    }

    /// Finds the edge points of `img` (this level's size) within `spans` (one per row; `None` for the
    /// whole image) and appends them to `out`, at most `max_points` in all.
    ///
    /// The threshold on the gradient magnitude `|gx| + |gy|` (Sobel units: a sharp step of c grey
    /// levels gives 4c) is the larger of `min_threshold` and `median_factor` times the median
    /// magnitude of the scanned pixels (the median is the noise's and the texture's level: edges are
    /// few).
    #[allow(clippy::too_many_arguments)]
    pub fn extract(
        &mut self,
        img: &[u8],
        spans: Option<&[Span]>,
        min_threshold: f64,
        median_factor: f64,
        map: LevelMap,
        max_points: usize,
        out: &mut Vec<EdgePoint>,
    ) -> EdgeStats {
        let (w, h) = (self.width, self.height);
        debug_assert_eq!(img.len(), w * h);
        // Gradients exist `border` pixels in from the image's edge.
        let border = if self.smooth { 2 } else { 1 };
        for (j, o) in self.nms_spans.iter_mut().enumerate() {
            *o = if j < border || j + border >= h {
                Span::EMPTY
            } else {
                let s = spans.map_or(
                    Span {
                        lo: 0,
                        hi: (w - 1) as u16,
                    },
                    |s| s[j],
                );
                if s.is_empty() {
                    Span::EMPTY
                } else {
                    let c = Span {
                        lo: s.lo.max(border as u16),
                        hi: s.hi.min((w - 1 - border) as u16),
                    };
                    if c.is_empty() { Span::EMPTY } else { c }
                }
            };
        }
        // Gradients wherever non-maximum suppression looks; smoothed pixels wherever Sobel looks.
        grow(&self.nms_spans, &mut self.sobel_spans, w, border);
        if self.smooth {
            grow(&self.sobel_spans, &mut self.smooth_spans, w, 1);
            for j in 1..h - 1 {
                let s = self.smooth_spans[j];
                if !s.is_empty() {
                    self.smooth_row(img, j, s.lo as usize, s.hi as usize);
                }
            }
        }
        for j in border..h - border {
            let s = self.sobel_spans[j];
            if s.is_empty() {
                continue;
            }
            if self.smooth {
                self.magnitude_row_smoothed(j, s.lo as usize, s.hi as usize);
            } else {
                self.magnitude_row(img, j, s.lo as usize, s.hi as usize);
            }
        }

        // The threshold from the median of the magnitudes under the spans.
        self.hist.fill(0);
        let mut count = 0u64;
        for (j, s) in self.nms_spans.iter().enumerate() {
            if s.is_empty() {
                continue;
            }
            for &m in &self.mag[j * w + s.lo as usize..=j * w + s.hi as usize] {
                self.hist[(m.min(2040) >> HIST_SHIFT) as usize] += 1;
            }
            count += (s.hi - s.lo + 1) as u64;
        }
        let mut median = 0u32;
        let mut seen = 0u64;
        for (b, &n) in self.hist.iter().enumerate() {
            seen += n as u64;
            if 2 * seen >= count {
                median = ((b as u32) << HIST_SHIFT) + (1 << HIST_SHIFT) / 2;
                break;
            }
        }
        let threshold = (min_threshold.max(median_factor * median as f64)).min(4000.0) as u16;
        let mut stats = EdgeStats { saturated: false };

        // Non-maximum suppression and sub-pixel positions.
        for j in border..h - border {
            let s = self.nms_spans[j];
            if s.is_empty() {
                continue;
            }
            let row = j * w;
            for i in s.lo as usize..=s.hi as usize {
                let k = row + i;
                let m = self.mag[k];
                if m < threshold {
                    continue;
                }
                let (gx, gy) = if self.smooth {
                    sobel_smoothed(&self.smoothed, w, k)
                } else {
                    sobel(img, w, k)
                };
                let (ax, ay) = (gx.abs(), gy.abs());
                // Neighbours along the gradient, quantised to 8 directions (tan 22.5 deg ~ 5/12).
                let (sx, sy): (isize, isize) = if 12 * ay < 5 * ax {
                    (1, 0)
                } else if 12 * ax < 5 * ay {
                    (0, 1)
                } else if (gx > 0) == (gy > 0) {
                    (1, 1)
                } else {
                    (1, -1)
                };
                let step = sy * w as isize + sx;
                let before = self.mag[(k as isize - step) as usize];
                let after = self.mag[(k as isize + step) as usize];
                if !(m > before && m >= after) {
                    continue;
                }
                if out.len() >= max_points {
                    stats.saturated = true;
                    return stats;
                }
                let (mb, m0, ma) = (before as f32, m as f32, after as f32);
                let denom = mb - 2.0 * m0 + ma;
                let delta = if denom < 0.0 {
                    (0.5 * (mb - ma) / denom).clamp(-0.5, 0.5)
                } else {
                    0.0
                };
                let norm = ((gx * gx + gy * gy) as f32).sqrt();
                out.push(EdgePoint {
                    x: map.scale * (i as f32 + 0.5 + delta * sx as f32) - map.half_width,
                    y: map.scale * (j as f32 + 0.5 + delta * sy as f32) - map.half_height,
                    gx: gx as f32 / norm,
                    gy: gy as f32 / norm,
                });
            }
        }
        stats
    }

    /// The L1 magnitude of the Sobel gradient ([`sobel`]) of row `j`, columns `lo..=hi` (all within
    /// the border), computed a row at a time.
    fn magnitude_row(&mut self, img: &[u8], j: usize, lo: usize, hi: usize) {
        let w = self.width;
        let n = hi + 1 - lo;
        let (r0, r1, r2) = (
            &img[(j - 1) * w..j * w],
            &img[j * w..(j + 1) * w],
            &img[(j + 1) * w..(j + 2) * w],
        );
        let (a0, c0, b0) = (
            &r0[lo - 1..lo - 1 + n],
            &r0[lo..lo + n],
            &r0[lo + 1..lo + 1 + n],
        );
        let (a1, b1) = (&r1[lo - 1..lo - 1 + n], &r1[lo + 1..lo + 1 + n]);
        let (a2, c2, b2) = (
            &r2[lo - 1..lo - 1 + n],
            &r2[lo..lo + n],
            &r2[lo + 1..lo + 1 + n],
        );
        let mag = &mut self.mag[j * w + lo..j * w + lo + n];
        for k in 0..n {
            let x = (b0[k] as i16 - a0[k] as i16)
                + 2 * (b1[k] as i16 - a1[k] as i16)
                + (b2[k] as i16 - a2[k] as i16);
            let y = (a2[k] as i16 + 2 * c2[k] as i16 + b2[k] as i16)
                - (a0[k] as i16 + 2 * c0[k] as i16 + b0[k] as i16);
            mag[k] = x.unsigned_abs() + y.unsigned_abs();
        }
    }

    /// The 3x3 binomial sum (16 times the mean) of row `j`, columns `lo..=hi` (within the border).
    fn smooth_row(&mut self, img: &[u8], j: usize, lo: usize, hi: usize) {
        let w = self.width;
        let n = hi + 1 - lo;
        let (r0, r1, r2) = (
            &img[(j - 1) * w..j * w],
            &img[j * w..(j + 1) * w],
            &img[(j + 1) * w..(j + 2) * w],
        );
        let out = &mut self.smoothed[j * w + lo..j * w + lo + n];
        let col = |r: &[u8], k: usize| r[k] as u16;
        let (r0, r1, r2) = (
            &r0[lo - 1..lo + n + 1],
            &r1[lo - 1..lo + n + 1],
            &r2[lo - 1..lo + n + 1],
        );
        for (k, o) in out.iter_mut().enumerate() {
            let v = |d: usize| col(r0, k + d) + 2 * col(r1, k + d) + col(r2, k + d);
            *o = v(0) + 2 * v(1) + v(2);
        }
    }

    /// The L1 magnitude of [`sobel_smoothed`] for row `j`, columns `lo..=hi`, a row at a time.
    fn magnitude_row_smoothed(&mut self, j: usize, lo: usize, hi: usize) {
        let w = self.width;
        let n = hi + 1 - lo;
        let s = &self.smoothed;
        let (r0, r1, r2) = (
            &s[(j - 1) * w + lo - 1..],
            &s[j * w + lo - 1..],
            &s[(j + 1) * w + lo - 1..],
        );
        let (r0, r1, r2) = (&r0[..n + 2], &r1[..n + 2], &r2[..n + 2]);
        let mag = &mut self.mag[j * w + lo..j * w + lo + n];
        for k in 0..n {
            let p = |r: &[u16], d: usize| r[k + d] as i32;
            let x = (p(r0, 2) - p(r0, 0)) + 2 * (p(r1, 2) - p(r1, 0)) + (p(r2, 2) - p(r2, 0));
            let y = (p(r2, 0) + 2 * p(r2, 1) + p(r2, 2)) - (p(r0, 0) + 2 * p(r0, 1) + p(r0, 2));
            let (x, y) = ((x + 8) >> 4, (y + 8) >> 4);
            mag[k] = (x.unsigned_abs() + y.unsigned_abs()) as u16;
        }
    }
}

/// The Sobel gradient (gx, gy) of `img` (rows of `w`, plain or smoothed pixels) at pixel `k`, which
/// is within the border. Its L1 magnitude is what [`Gradients::magnitude_row`] computes.
#[inline]
fn sobel<T: Copy + Into<i32>>(img: &[T], w: usize, k: usize) -> (i32, i32) {
    let p = |d: isize| img[(k as isize + d) as usize].into();
    let w = w as isize;
    let x = (p(1 - w) - p(-1 - w)) + 2 * (p(1) - p(-1)) + (p(1 + w) - p(-1 + w));
    let y = (p(w - 1) + 2 * p(w) + p(w + 1)) - (p(-w - 1) + 2 * p(-w) + p(-w + 1));
    (x, y)
}

/// The Sobel gradient of the smoothed image at pixel `k`, scaled back to plain Sobel units (rounded:
/// the smoothed image is 16 times the binomial mean). Its L1 magnitude is what
/// [`Gradients::magnitude_row_smoothed`] computes.
#[inline]
fn sobel_smoothed(s: &[u16], w: usize, k: usize) -> (i32, i32) {
    let (x, y) = sobel(s, w, k);
    ((x + 8) >> 4, (y + 8) >> 4)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A vertical step between columns 20 and 21 of a 40x30 image: one edge point per inner row, at
    /// the step (x = 21 - 20 = 1 in centred coordinates), gradient pointing right (dark to bright).
    #[test]
    fn a_step_gives_one_thin_edge_at_the_step() {
        let (w, h) = (40, 30);
        let img: Vec<u8> = (0..w * h)
            .map(|k| if k % w < 21 { 50 } else { 150 })
            .collect();
        let mut g = Gradients::new(w, h, false);
        let mut out = Vec::new();
        let map = LevelMap {
            scale: 1.0,
            half_width: 20.0,
            half_height: 15.0,
        };
        g.extract(&img, None, 30.0, 3.0, map, 10_000, &mut out);
        assert_eq!(out.len(), h - 2);
        for p in &out {
            assert!((p.x - 1.0).abs() < 1e-6, "{p:?}");
            assert!(p.gx > 0.99);
        }
        // A quarter-covered pixel moves the edge by a quarter pixel.
        let img: Vec<u8> = (0..w * h)
            .map(|k| match k % w {
                c if c < 20 => 50,
                20 => 75,
                _ => 150,
            })
            .collect();
        out.clear();
        g.extract(&img, None, 30.0, 3.0, map, 10_000, &mut out);
        let mean = out.iter().map(|p| p.x).sum::<f32>() / out.len() as f32;
        // Column 20 is a quarter bright: the step is at 20.75 - 20 = 0.75.
        assert!((mean - 0.75).abs() < 1e-6, "{mean}");
    }

    /// With smoothing (a 5x5 derivative of a binomial), a step between two pixels is still found
    /// exactly there, and a quarter-covered pixel still moves it by a quarter pixel.
    #[test]
    fn smoothing_keeps_the_edge_where_it_is() {
        let (w, h) = (40, 30);
        let map = LevelMap {
            scale: 1.0,
            half_width: 20.0,
            half_height: 15.0,
        };
        let mut g = Gradients::new(w, h, true);
        for (partial, expected) in [(50u8, 1.0f32), (75, 0.75)] {
            let img: Vec<u8> = (0..w * h)
                .map(|k| match k % w {
                    c if c < 20 => 50,
                    20 => partial,
                    _ => 150,
                })
                .collect();
            let mut out = Vec::new();
            g.extract(&img, None, 30.0, 3.0, map, 10_000, &mut out);
            // One point per row away from the border rows.
            assert_eq!(out.len(), h - 4);
            let mean = out.iter().map(|p| p.x).sum::<f32>() / out.len() as f32;
            assert!((mean - expected).abs() < 0.05, "{mean} vs {expected}");
        }
    }

    /// The gradient computed again at an edge point is the one whose magnitude was kept for it: the
    /// row functions and the per-pixel ones agree at every pixel, smoothed or not.
    #[test]
    fn the_gradient_at_a_pixel_matches_the_magnitude_kept() {
        let (w, h) = (37, 23);
        // A noisy, textured image with strong steps, so every sign and size of gradient occurs.
        let mut state = 0x2545_f491_u32;
        let img: Vec<u8> = (0..w * h)
            .map(|k| {
                state ^= state << 13;
                state ^= state >> 17;
                state ^= state << 5;
                let step = if (k % w) * 3 + (k / w) * 2 > 60 {
                    180
                } else {
                    20
                };
                (step + (state % 60) as i32 - 30).clamp(0, 255) as u8
            })
            .collect();
        let map = LevelMap {
            scale: 1.0,
            half_width: w as f32 / 2.0,
            half_height: h as f32 / 2.0,
        };
        for smooth in [false, true] {
            let mut g = Gradients::new(w, h, smooth);
            let mut out = Vec::new();
            g.extract(&img, None, 0.0, 0.0, map, usize::MAX, &mut out);
            let border = if smooth { 2 } else { 1 };
            let mut checked = 0;
            for j in border..h - border {
                for i in border..w - border {
                    let k = j * w + i;
                    let (gx, gy) = if smooth {
                        sobel_smoothed(&g.smoothed, w, k)
                    } else {
                        sobel(&img, w, k)
                    };
                    assert_eq!(
                        (gx.abs() + gy.abs()) as u16,
                        g.mag[k],
                        "smooth {smooth}, pixel ({i}, {j})"
                    );
                    checked += 1;
                }
            }
            assert_eq!(checked, (w - 2 * border) * (h - 2 * border));
            assert!(!out.is_empty());
        }
    }

    #[test]
    fn spans_restrict_the_search_and_the_budget_holds() {
        let (w, h) = (40, 30);
        let img: Vec<u8> = (0..w * h)
            .map(|k| if k % w < 21 { 50 } else { 150 })
            .collect();
        let mut g = Gradients::new(w, h, false);
        let map = LevelMap {
            scale: 1.0,
            half_width: 20.0,
            half_height: 15.0,
        };
        let mut out = Vec::new();
        let away = vec![Span { lo: 1, hi: 10 }; h];
        g.extract(&img, Some(&away), 30.0, 3.0, map, 10_000, &mut out);
        assert!(out.is_empty());
        let stats = g.extract(&img, None, 30.0, 3.0, map, 5, &mut out);
        assert!(stats.saturated && out.len() == 5);
    }
}
