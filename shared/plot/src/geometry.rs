//! Clipping in data coordinates: plotters does not clip to the plotting area, so lines and bands
//! that leave a fixed `y_range` are cut here before they are drawn.

pub(crate) type Point = (f64, f64);

/// An axis-aligned rectangle in data coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Rect {
    pub x: (f64, f64),
    pub y: (f64, f64),
}

impl Rect {
    fn contains(&self, p: Point) -> bool {
        p.0 >= self.x.0 && p.0 <= self.x.1 && p.1 >= self.y.0 && p.1 <= self.y.1
    }
}

/// Splits `points` into runs of consecutive points where `keep` holds (e.g. finite samples).
pub(crate) fn runs<T: Copy>(points: &[T], keep: impl Fn(&T) -> bool) -> Vec<Vec<T>> {
    let mut out = Vec::new();
    let mut current = Vec::new();
    for p in points {
        if keep(p) {
            current.push(*p);
        } else if !current.is_empty() {
            out.push(std::mem::take(&mut current));
        }
    }
    if !current.is_empty() {
        out.push(current);
    }
    out
}

/// Clips the segment `a`-`b` to `r` (Liang-Barsky); `None` if it lies entirely outside.
fn clip_segment(a: Point, b: Point, r: &Rect) -> Option<(Point, Point)> {
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let mut t0 = 0.0_f64;
    let mut t1 = 1.0_f64;
    for (p, q) in [
        (-dx, a.0 - r.x.0),
        (dx, r.x.1 - a.0),
        (-dy, a.1 - r.y.0),
        (dy, r.y.1 - a.1),
    ] {
        if p == 0.0 {
            if q < 0.0 {
                return None;
            }
        } else {
            let t = q / p;
            if p < 0.0 {
                t0 = t0.max(t);
            } else {
                t1 = t1.min(t);
            }
        }
    }
    if t0 > t1 {
        return None;
    }
    let at = |t: f64| (a.0 + dx * t, a.1 + dy * t);
    Some((at(t0), at(t1)))
}

/// Clips a polyline to `r`; the parts inside are returned as separate polylines. A single point is
/// kept as a one-point polyline if it lies inside.
pub(crate) fn clip_polyline(points: &[Point], r: &Rect) -> Vec<Vec<Point>> {
    if points.len() == 1 {
        return if r.contains(points[0]) {
            vec![points.to_vec()]
        } else {
            Vec::new()
        };
    }
    let mut out: Vec<Vec<Point>> = Vec::new();
    let mut current: Vec<Point> = Vec::new();
    for pair in points.windows(2) {
        match clip_segment(pair[0], pair[1], r) {
            Some((a, b)) => {
                if current.last() != Some(&a) {
                    if !current.is_empty() {
                        out.push(std::mem::take(&mut current));
                    }
                    current.push(a);
                }
                current.push(b);
            }
            None => {
                if !current.is_empty() {
                    out.push(std::mem::take(&mut current));
                }
            }
        }
    }
    if !current.is_empty() {
        out.push(current);
    }
    out
}

/// Clips a polygon to `r` (Sutherland-Hodgman). A concave polygon may come back with edges running
/// along the border of `r`, which does not matter for filling.
pub(crate) fn clip_polygon(points: &[Point], r: &Rect) -> Vec<Point> {
    type Inside = fn(Point, &Rect) -> bool;
    type Cross = fn(Point, Point, &Rect) -> Point;
    let edges: [(Inside, Cross); 4] = [
        (
            |p, r| p.0 >= r.x.0,
            |a, b, r| (r.x.0, a.1 + (b.1 - a.1) * (r.x.0 - a.0) / (b.0 - a.0)),
        ),
        (
            |p, r| p.0 <= r.x.1,
            |a, b, r| (r.x.1, a.1 + (b.1 - a.1) * (r.x.1 - a.0) / (b.0 - a.0)),
        ),
        (
            |p, r| p.1 >= r.y.0,
            |a, b, r| (a.0 + (b.0 - a.0) * (r.y.0 - a.1) / (b.1 - a.1), r.y.0),
        ),
        (
            |p, r| p.1 <= r.y.1,
            |a, b, r| (a.0 + (b.0 - a.0) * (r.y.1 - a.1) / (b.1 - a.1), r.y.1),
        ),
    ];
    let mut poly = points.to_vec();
    for (inside, cross) in edges {
        if poly.is_empty() {
            break;
        }
        let input = std::mem::take(&mut poly);
        let mut prev = *input.last().expect("not empty");
        for &p in &input {
            match (inside(p, r), inside(prev, r)) {
                (true, true) => poly.push(p),
                (true, false) => {
                    poly.push(cross(prev, p, r));
                    poly.push(p);
                }
                (false, true) => poly.push(cross(prev, p, r)),
                (false, false) => {}
            }
            prev = p;
        }
    }
    poly
}

#[cfg(test)]
mod tests {
    use super::*;

    const UNIT: Rect = Rect {
        x: (0.0, 1.0),
        y: (0.0, 1.0),
    };

    #[test]
    fn runs_split_at_rejected_items() {
        let v = [1.0, f64::NAN, 2.0, 3.0, f64::NAN, f64::NAN];
        assert_eq!(runs(&v, |x| x.is_finite()), vec![vec![1.0], vec![2.0, 3.0]]);
    }

    #[test]
    fn polyline_leaving_and_reentering_is_split() {
        let line = [(0.0, 0.5), (0.5, 2.0), (1.0, 0.5)];
        let parts = clip_polyline(&line, &UNIT);
        assert_eq!(parts.len(), 2);
        assert!(parts.iter().flatten().all(|p| UNIT.contains(*p)));
    }

    #[test]
    fn polygon_is_cut_to_the_box() {
        let square = [(-1.0, -1.0), (2.0, -1.0), (2.0, 2.0), (-1.0, 2.0)];
        let clipped = clip_polygon(&square, &UNIT);
        assert_eq!(clipped.len(), 4);
        assert!(clipped.iter().all(|p| UNIT.contains(*p)));
        assert!(clip_polygon(&[(3.0, 3.0), (4.0, 3.0), (4.0, 4.0)], &UNIT).is_empty());
    }
}
