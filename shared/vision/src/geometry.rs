//! A detected line in the conventions of `model::camera`: centred pixel coordinates (origin at the
//! image centre, columns right, rows down), `rho = x cos(Theta) + y sin(Theta)` with Theta in
//! (-pi/2, pi/2] the angle of the line's direction from the image's vertical axis, and x_g, y_g the
//! mid point of the line's two crossings of the image border as fractions of width and height.

use model::{CableLine, wrap_half_pi};

/// The line `n . p = offset` (n a unit normal, either sign) in a `width x height` image, in the
/// conventions of [`model::CableLine`]; `None` when it misses the image.
pub fn line_from_normal(
    normal: [f64; 2],
    offset: f64,
    width: f64,
    height: f64,
) -> Option<CableLine> {
    let len = normal[0].hypot(normal[1]);
    if len.is_nan() || len <= 1e-12 || !offset.is_finite() {
        return None;
    }
    let n = [normal[0] / len, normal[1] / len];
    let offset = offset / len;
    let theta = wrap_half_pi(n[1].atan2(n[0]));
    let (st, ct) = theta.sin_cos();
    // Theta's normal is n or -n.
    let rho = if ct * n[0] + st * n[1] >= 0.0 {
        offset
    } else {
        -offset
    };
    line_from_polar(rho, theta, width, height)
}

/// The line of eq. (2) with `rho`, `theta` in a `width x height` image; `None` when it misses it.
pub fn line_from_polar(rho: f64, theta: f64, width: f64, height: f64) -> Option<CableLine> {
    CableLine::from_polar(rho, theta, width, height)
}

/// Centred pixel coordinates of the centre of pixel (column `i`, row `j`).
pub fn pixel_centre(i: f64, j: f64, width: f64, height: f64) -> [f64; 2] {
    [i + 0.5 - 0.5 * width, j + 0.5 - 0.5 * height]
}

#[cfg(test)]
mod tests {
    use super::*;
    use config::CameraParams;
    use model::{Cable, Camera, Pose};

    /// Perception's conversion from a fitted line agrees with the geometric camera on every pose.
    #[test]
    fn agrees_with_the_geometric_camera() {
        let cam = Camera::new(&CameraParams::default());
        let cable = Cable::default();
        let mut checked = 0;
        for k in 0..2000 {
            let f = k as f64;
            let pose = Pose {
                x: (f * 0.37).sin(),
                y: 0.7 * (f * 0.91).sin(),
                psi: 3.2 * (f * 0.13).sin(),
            };
            let Some(truth) = cam.view(&pose, &cable) else {
                continue;
            };
            // Any normal of the true line, either sign, and its offset.
            let sign = if k % 2 == 0 { 1.0 } else { -1.0 };
            let n = [sign * truth.theta.cos(), sign * truth.theta.sin()];
            let line = line_from_normal(n, sign * truth.rho, 320.0, 240.0).unwrap();
            assert!(
                (line.theta - truth.theta).abs() < 1e-9,
                "{line:?} {truth:?}"
            );
            assert!((line.rho - truth.rho).abs() < 1e-9);
            assert!((line.x_g - truth.x_g).abs() < 1e-9 && (line.y_g - truth.y_g).abs() < 1e-9);
            for e in 0..2 {
                for c in 0..2 {
                    assert!(
                        (line.ends[e][c] - truth.ends[e][c]).abs() < 1e-6,
                        "{line:?} {truth:?}"
                    );
                }
            }
            checked += 1;
        }
        assert!(checked > 500);
    }

    #[test]
    fn a_line_outside_the_image_is_none() {
        assert!(line_from_polar(500.0, 0.3, 320.0, 240.0).is_none());
        assert!(line_from_normal([0.0, 0.0], 1.0, 320.0, 240.0).is_none());
    }
}
