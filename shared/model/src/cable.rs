//! The straight cable lying on the pool floor.

use config::CableParams;

/// An infinite straight line on the floor, with a width for rendering.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cable {
    /// A point of the cable in the pool frame.
    pub origin: [f64; 2],
    /// The cable's direction in the pool frame (rad, from x towards y).
    pub heading: f64,
    pub width_m: f64,
}

impl Cable {
    pub fn new(params: &CableParams) -> Self {
        Cable {
            origin: [params.x_m, params.y_m],
            heading: params.heading_deg.to_radians(),
            width_m: params.width_m,
        }
    }

    /// Unit vector along the cable.
    pub fn direction(&self) -> [f64; 2] {
        let (s, c) = self.heading.sin_cos();
        [c, s]
    }

    /// Unit vector across the cable, to its right seen from above when looking along `direction`.
    pub fn normal(&self) -> [f64; 2] {
        let (s, c) = self.heading.sin_cos();
        [-s, c]
    }

    /// The point at `along` metres from the origin, offset `across` metres along [`Cable::normal`].
    pub fn point(&self, along: f64, across: f64) -> [f64; 2] {
        let d = self.direction();
        let n = self.normal();
        [
            self.origin[0] + along * d[0] + across * n[0],
            self.origin[1] + along * d[1] + across * n[1],
        ]
    }

    /// Signed distance of `p` from the cable's centre line, positive on the [`Cable::normal`] side.
    pub fn offset(&self, p: [f64; 2]) -> f64 {
        let n = self.normal();
        (p[0] - self.origin[0]) * n[0] + (p[1] - self.origin[1]) * n[1]
    }
}

impl Default for Cable {
    fn default() -> Self {
        Cable::new(&CableParams::default())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn offset_is_signed_distance() {
        let c = Cable {
            origin: [1.0, 2.0],
            heading: std::f64::consts::FRAC_PI_2,
            width_m: 0.05,
        };
        // Heading +y: the normal points to -x.
        assert!((c.offset([0.0, 5.0]) - 1.0).abs() < 1e-12);
        let p = c.point(3.0, -0.5);
        assert!((c.offset(p) + 0.5).abs() < 1e-12);
    }
}
