//! The downward pinhole camera as geometry.
//!
//! Image coordinates are *centred*: the origin is the image centre, columns grow to the right
//! (starboard) and rows grow downwards (rows at the top are ahead of the vehicle), in pixels. Pixel
//! (column i, row j) of a `W x H` frame covers `[i - W/2, i + 1 - W/2] x [j - H/2, j + 1 - H/2]`.
//!
//! The cable's line in the image is given as in the paper's eq. (2): `rho = x cos(Theta) + y sin(Theta)`
//! with Theta in (-pi/2, pi/2] the angle of the cable's direction from the image's vertical axis,
//! positive when its top end leans right (so Theta = -psi for the default cable along the pool's x
//! axis). x_g and y_g are the mid point of the line's two crossings of the image border, as fractions
//! of the width and height (0 at the centre, positive right and down).

use crate::{Cable, Pose, PoseRate, VehicleState, wrap_half_pi};
use config::{CameraParams, ObservationLimits};
use serde::{Deserialize, Serialize};

/// The camera's geometry: intrinsics, altitude and mounting point on the vehicle.
#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    width: f64,
    height: f64,
    focal_px: f64,
    altitude_m: f64,
    mount: [f64; 2],
    min_visible_px: f64,
}

/// Where the cable's centre line falls in the image.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CableLine {
    /// Distance of the line from the image centre along its normal (pixels).
    pub rho: f64,
    /// Angle of the cable from the image's vertical axis (rad, in (-pi/2, pi/2]).
    pub theta: f64,
    /// Mid point of the border crossings, as fractions of width and height in [-0.5, 0.5].
    pub x_g: f64,
    pub y_g: f64,
    /// The two border crossings in centred pixel coordinates, the upper one first.
    pub ends: [[f64; 2]; 2],
}

impl CableLine {
    /// The line of eq. (2), `rho = x cos(theta) + y sin(theta)` in centred pixel coordinates, as it
    /// crosses a `width x height` image; `None` when it misses the image.
    pub fn from_polar(rho: f64, theta: f64, width: f64, height: f64) -> Option<CableLine> {
        let (st, ct) = theta.sin_cos();
        let q0 = [rho * ct, rho * st];
        // The direction pointing up (or right when horizontal), as `Camera::view` orients it.
        let e = if -ct < 0.0 || (ct == 0.0 && st > 0.0) {
            [st, -ct]
        } else {
            [-st, ct]
        };
        let (t0, t1) = clip_line(q0, e, 0.5 * width, 0.5 * height)?;
        let upper = [q0[0] + t1 * e[0], q0[1] + t1 * e[1]];
        let lower = [q0[0] + t0 * e[0], q0[1] + t0 * e[1]];
        Some(CableLine {
            rho,
            theta,
            x_g: 0.5 * (upper[0] + lower[0]) / width,
            y_g: 0.5 * (upper[1] + lower[1]) / height,
            ends: [upper, lower],
        })
    }

    /// Length of the visible part of the line (pixels).
    pub fn visible_px(&self) -> f64 {
        let [a, b] = self.ends;
        ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt()
    }
}

/// What the behaviours observe of the cable in one frame: the line, its rates and whether it was found.
/// Produced by the geometric camera (ideal perception) and by `vision`'s perception alike.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CableObservation {
    pub found: bool,
    pub rho: f64,
    pub theta: f64,
    pub x_g: f64,
    pub y_g: f64,
    /// dx_g/dt (1/s), clipped to the observation box.
    pub x_g_rate: f64,
    /// dTheta/dt (rad/s), clipped to the observation box.
    pub theta_rate: f64,
    /// 1 for the geometric camera; the detector's confidence in [0, 1] for perception.
    pub confidence: f64,
}

impl CableObservation {
    /// The sway behaviour's state (x_g, dx_g/dt).
    pub fn sway_state(&self) -> [f64; 2] {
        [self.x_g, self.x_g_rate]
    }

    /// The yaw behaviour's state (Theta, dTheta/dt).
    pub fn yaw_state(&self) -> [f64; 2] {
        [self.theta, self.theta_rate]
    }

    /// The learned DOF's state.
    pub fn state(&self, dof: config::Dof) -> [f64; 2] {
        match dof {
            config::Dof::Sway => self.sway_state(),
            config::Dof::Yaw => self.yaw_state(),
        }
    }
}

/// The half-width of the time window of the central difference behind the ideal rates (s).
const RATE_EPSILON_S: f64 = 1e-4;

impl Camera {
    pub fn new(params: &CameraParams) -> Self {
        let width = params.width as f64;
        Camera {
            width,
            height: params.height as f64,
            focal_px: 0.5 * width / (0.5 * params.hfov_deg.to_radians()).tan(),
            altitude_m: params.altitude_m,
            mount: [params.mount_x_m, params.mount_y_m],
            min_visible_px: params.min_visible_px,
        }
    }

    pub fn width(&self) -> f64 {
        self.width
    }

    pub fn height(&self) -> f64 {
        self.height
    }

    /// Focal length in pixels.
    pub fn focal_px(&self) -> f64 {
        self.focal_px
    }

    /// Floor metres per image pixel.
    pub fn metres_per_px(&self) -> f64 {
        self.altitude_m / self.focal_px
    }

    /// The camera's position on the floor (pool frame) for a vehicle pose.
    pub fn position(&self, pose: &Pose) -> [f64; 2] {
        let (s, c) = pose.psi.sin_cos();
        [
            pose.x + c * self.mount[0] - s * self.mount[1],
            pose.y + s * self.mount[0] + c * self.mount[1],
        ]
    }

    /// A floor point (pool frame) in centred image coordinates.
    pub fn floor_to_image(&self, pose: &Pose, p: [f64; 2]) -> [f64; 2] {
        let cam = self.position(pose);
        let (s, c) = pose.psi.sin_cos();
        let (dx, dy) = (p[0] - cam[0], p[1] - cam[1]);
        let forward = c * dx + s * dy;
        let starboard = -s * dx + c * dy;
        let k = self.focal_px / self.altitude_m;
        [k * starboard, -k * forward]
    }

    /// The floor point (pool frame) seen at centred image coordinates `q`.
    pub fn image_to_floor(&self, pose: &Pose, q: [f64; 2]) -> [f64; 2] {
        let cam = self.position(pose);
        let k = self.altitude_m / self.focal_px;
        let (starboard, forward) = (k * q[0], -k * q[1]);
        let (s, c) = pose.psi.sin_cos();
        [
            cam[0] + c * forward - s * starboard,
            cam[1] + s * forward + c * starboard,
        ]
    }

    /// The cable's line in the image, or `None` when less than `min_visible_px` of it is in view.
    pub fn view(&self, pose: &Pose, cable: &Cable) -> Option<CableLine> {
        let q0 = self.floor_to_image(pose, cable.origin);
        // The cable's direction in the image: rotate into the body frame, then (starboard, -forward).
        let rel = cable.heading - pose.psi;
        let (s, c) = rel.sin_cos();
        let mut e = [s, -c];
        // Orient it upwards (or to the right when horizontal) so Theta is in (-pi/2, pi/2].
        if e[1] > 0.0 || (e[1] == 0.0 && e[0] < 0.0) {
            e = [-e[0], -e[1]];
        }
        let theta = wrap_half_pi(e[0].atan2(-e[1]));
        let (st, ct) = theta.sin_cos();
        let rho = q0[0] * ct + q0[1] * st;

        let (t0, t1) = clip_line(q0, e, 0.5 * self.width, 0.5 * self.height)?;
        // e points up, so the larger t is the upper crossing.
        let upper = [q0[0] + t1 * e[0], q0[1] + t1 * e[1]];
        let lower = [q0[0] + t0 * e[0], q0[1] + t0 * e[1]];
        let line = CableLine {
            rho,
            theta,
            x_g: 0.5 * (upper[0] + lower[0]) / self.width,
            y_g: 0.5 * (upper[1] + lower[1]) / self.height,
            ends: [upper, lower],
        };
        (line.visible_px() >= self.min_visible_px).then_some(line)
    }

    /// The ideal observation: the line and its exact rates for a pose moving at `rate`, the rates
    /// clipped to the observation box. `found` is false when the cable is not in view.
    pub fn observe(
        &self,
        pose: &Pose,
        rate: &PoseRate,
        cable: &Cable,
        limits: &ObservationLimits,
    ) -> CableObservation {
        let Some(line) = self.view(pose, cable) else {
            return CableObservation::default();
        };
        // Central difference of the geometry along the motion: exact to O(eps^2), and it keeps this
        // function the single definition of x_g and Theta (no second, analytic formula to drift apart).
        let eps = RATE_EPSILON_S;
        let ahead = self.view(&pose.advanced(rate, eps), cable);
        let behind = self.view(&pose.advanced(rate, -eps), cable);
        let (a, b, span) = match (ahead, behind) {
            (Some(a), Some(b)) => (a, b, 2.0 * eps),
            (Some(a), None) => (a, line, eps),
            (None, Some(b)) => (line, b, eps),
            (None, None) => (line, line, eps),
        };
        let x_g_rate = (a.x_g - b.x_g) / span;
        let theta_rate = wrap_half_pi(a.theta - b.theta) / span;
        CableObservation {
            found: true,
            rho: line.rho,
            theta: line.theta,
            x_g: line.x_g,
            y_g: line.y_g,
            x_g_rate: x_g_rate.clamp(-limits.x_g_rate_max, limits.x_g_rate_max),
            theta_rate: theta_rate.clamp(-limits.theta_rate_max, limits.theta_rate_max),
            confidence: 1.0,
        }
    }

    /// The pose `along` metres down the cable from which this camera sees the cable at `x_g` and
    /// `theta`, if the image can show it there (a large x_g with a nearly horizontal line cannot be).
    ///
    /// Theta fixes the heading; x_g then fixes the offset across the cable, found by bisection on the
    /// camera's own geometry (x_g falls monotonically as the vehicle moves to the cable's right), so
    /// the pose is exact for any mounting of the camera.
    pub fn pose_for(&self, cable: &Cable, x_g: f64, theta: f64, along: f64) -> Option<Pose> {
        let psi = crate::wrap_pi(cable.heading - theta);
        let pose_at = |across: f64| {
            let p = cable.point(along, across);
            Pose {
                x: p[0],
                y: p[1],
                psi,
            }
        };
        // The offset at which the camera (not the vehicle's centre) is over the cable.
        let centre = -cable.offset(self.position(&pose_at(0.0)));
        // Out of view the cable is past the border on one side.
        let x_g_at = |across: f64| match self.view(&pose_at(across), cable) {
            Some(line) => line.x_g,
            None if across > centre => -1.0,
            None => 1.0,
        };
        let reach = self.width.hypot(self.height) * self.metres_per_px();
        let (mut lo, mut hi) = (centre - reach, centre + reach); // x_g_at(lo) > x_g > x_g_at(hi)
        for _ in 0..80 {
            let mid = 0.5 * (lo + hi);
            if x_g_at(mid) > x_g {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let pose = pose_at(0.5 * (lo + hi));
        let line = self.view(&pose, cable)?;
        ((line.x_g - x_g).abs() < 1e-6 && wrap_half_pi(line.theta - theta).abs() < 1e-9)
            .then_some(pose)
    }

    /// [`Camera::observe`] for a vehicle state in still water.
    pub fn observe_state(
        &self,
        state: &VehicleState,
        cable: &Cable,
        limits: &ObservationLimits,
    ) -> CableObservation {
        self.observe(&state.pose, &state.pose_rate(), cable, limits)
    }
}

/// Clips the line `q0 + t e` to the rectangle `|x| <= hw, |y| <= hh` (Liang-Barsky): the parameter
/// interval inside it, or `None` when the line misses the rectangle.
fn clip_line(q0: [f64; 2], e: [f64; 2], hw: f64, hh: f64) -> Option<(f64, f64)> {
    let mut t0 = f64::NEG_INFINITY;
    let mut t1 = f64::INFINITY;
    for (p, d, half) in [(q0[0], e[0], hw), (q0[1], e[1], hh)] {
        if d.abs() < 1e-15 {
            if p.abs() > half {
                return None;
            }
            continue;
        }
        let (a, b) = ((-half - p) / d, (half - p) / d);
        t0 = t0.max(a.min(b));
        t1 = t1.min(a.max(b));
    }
    (t1 > t0).then_some((t0, t1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::FRAC_PI_4;

    fn camera() -> Camera {
        Camera::new(&CameraParams::default())
    }

    #[test]
    fn focal_length_follows_the_field_of_view() {
        // 320 px across 60 degrees: f = 160 / tan(30 deg).
        assert!((camera().focal_px() - 160.0 / 30f64.to_radians().tan()).abs() < 1e-9);
    }

    #[test]
    fn projection_round_trips_and_keeps_the_conventions() {
        let cam = camera();
        let pose = Pose {
            x: 1.0,
            y: -2.0,
            psi: 0.3,
        };
        for q in [[0.0, 0.0], [100.0, -50.0], [-160.0, 120.0]] {
            let p = cam.image_to_floor(&pose, q);
            let back = cam.floor_to_image(&pose, p);
            assert!((back[0] - q[0]).abs() < 1e-9 && (back[1] - q[1]).abs() < 1e-9);
        }
        // Straight ahead of the vehicle is up in the image; to starboard is right.
        let at_origin = Pose::default();
        let ahead = cam.floor_to_image(&at_origin, [0.5, 0.0]);
        let starboard = cam.floor_to_image(&at_origin, [0.0, 0.5]);
        assert!(ahead[1] < 0.0 && ahead[0].abs() < 1e-12);
        assert!(starboard[0] > 0.0 && starboard[1].abs() < 1e-12);
    }

    /// Hand-computed cases. The floor seen at 1 m is 2 tan(30 deg) = 1.1547 m wide (320 px), so one
    /// pixel is 3.608 mm.
    #[test]
    fn hand_computed_lines() {
        let cam = camera();
        let cable = Cable::default(); // along the pool's x axis through the origin
        let floor_width = 2.0 * 30f64.to_radians().tan();

        // Centred and aligned: a vertical line through the centre.
        let line = cam.view(&Pose::default(), &cable).unwrap();
        assert!(line.theta.abs() < 1e-12 && line.x_g.abs() < 1e-12 && line.y_g.abs() < 1e-12);
        assert!((line.visible_px() - 240.0).abs() < 1e-9);

        // The vehicle 0.2 m to starboard of the cable, aligned: the cable appears to the left,
        // 0.2 / 1.1547 of the width from the centre.
        let line = cam
            .view(
                &Pose {
                    x: 0.0,
                    y: 0.2,
                    psi: 0.0,
                },
                &cable,
            )
            .unwrap();
        assert!(
            (line.x_g + 0.2 / floor_width).abs() < 1e-12,
            "x_g {}",
            line.x_g
        );
        assert!(line.theta.abs() < 1e-12);
        assert!((line.rho + 0.2 / floor_width * 320.0).abs() < 1e-9);

        // Heading 45 degrees to starboard, over the cable: Theta = -45 degrees (the top end leans
        // left), the line through the centre crosses the top and bottom borders at +-120 px rows.
        let line = cam
            .view(
                &Pose {
                    x: 0.0,
                    y: 0.0,
                    psi: FRAC_PI_4,
                },
                &cable,
            )
            .unwrap();
        assert!((line.theta + FRAC_PI_4).abs() < 1e-12);
        assert!(line.x_g.abs() < 1e-12 && line.rho.abs() < 1e-9);
        assert!((line.ends[0][0] + 120.0).abs() < 1e-9 && (line.ends[0][1] + 120.0).abs() < 1e-9);

        // Heading -30 degrees, 0.1 m to port: cable to the right, top leaning right (Theta = +30 deg).
        // The line crosses the centre row at column 0.1 / cos(30 deg) m, so x_g = that / floor width.
        let line = cam
            .view(
                &Pose {
                    x: 0.0,
                    y: -0.1,
                    psi: -30f64.to_radians(),
                },
                &cable,
            )
            .unwrap();
        assert!((line.theta - 30f64.to_radians()).abs() < 1e-12);
        let expected = 0.1 / 30f64.to_radians().cos() / floor_width;
        assert!(
            (line.x_g - expected).abs() < 1e-12,
            "x_g {} vs {expected}",
            line.x_g
        );
    }

    /// A line that leaves through a side border: its mid point is the mid point of the two crossings.
    #[test]
    fn mid_point_of_a_line_crossing_a_side_border() {
        let cam = camera();
        let cable = Cable::default();
        // Heading 60 degrees: in the image the line has slope 60 degrees from vertical and, passing
        // 0.3 m to the right of the centre, leaves through the right border.
        let pose = Pose {
            x: 0.0,
            y: -0.3,
            psi: 60f64.to_radians(),
        };
        let line = cam.view(&pose, &cable).unwrap();
        let [a, b] = line.ends;
        let on_border =
            |p: [f64; 2]| (p[0].abs() - 160.0).abs() < 1e-9 || (p[1].abs() - 120.0).abs() < 1e-9;
        assert!(on_border(a) && on_border(b));
        assert!(
            a[0].abs() > 159.999 || b[0].abs() > 159.999,
            "one crossing is on a side: {a:?} {b:?}"
        );
        assert!((line.x_g - 0.5 * (a[0] + b[0]) / 320.0).abs() < 1e-12);
        // Both crossings lie on the line of eq. (2).
        for p in [a, b] {
            assert!((p[0] * line.theta.cos() + p[1] * line.theta.sin() - line.rho).abs() < 1e-9);
        }
    }

    #[test]
    fn not_in_view_when_the_cable_leaves_the_image() {
        let cam = camera();
        let cable = Cable::default();
        // Half the floor width is 0.577 m: at 0.6 m off the cable, aligned, it is outside.
        assert!(
            cam.view(
                &Pose {
                    x: 0.0,
                    y: 0.6,
                    psi: 0.0
                },
                &cable
            )
            .is_none()
        );
        assert!(
            cam.view(
                &Pose {
                    x: 0.0,
                    y: 0.55,
                    psi: 0.0
                },
                &cable
            )
            .is_some()
        );
        // Just clipping a corner: less than min_visible_px inside.
        let corner = cam.image_to_floor(&Pose::default(), [160.0 - 3.0, -120.0]);
        // Through (157, -120) going down-right: it leaves through the right border after 3 px.
        let tiny = Cable {
            origin: corner,
            heading: -FRAC_PI_4,
            width_m: 0.05,
        };
        assert!(cam.view(&Pose::default(), &tiny).is_none());
        let obs = cam.observe_state(
            &VehicleState {
                pose: Pose {
                    x: 0.0,
                    y: 0.7,
                    psi: 0.0,
                },
                ..Default::default()
            },
            &cable,
            &ObservationLimits::default(),
        );
        assert!(!obs.found);
    }

    #[test]
    fn rates_match_the_motion() {
        let cam = camera();
        let cable = Cable::default();
        let floor_width = 2.0 * 30f64.to_radians().tan();
        // Swaying to starboard at 0.1 m/s: the cable moves left at 0.1 / floor width per second.
        let state = VehicleState {
            pose: Pose {
                x: 0.0,
                y: 0.1,
                psi: 0.0,
            },
            velocity: crate::Velocity {
                u: 0.0,
                v: 0.1,
                r: 0.0,
            },
        };
        let obs = cam.observe_state(&state, &cable, &ObservationLimits::default());
        assert!(
            (obs.x_g_rate + 0.1 / floor_width).abs() < 1e-6,
            "{}",
            obs.x_g_rate
        );
        assert!(obs.theta_rate.abs() < 1e-9);
        // Turning to starboard at 0.05 rad/s: Theta = -psi decreases at 0.05 rad/s.
        let state = VehicleState {
            pose: Pose::default(),
            velocity: crate::Velocity {
                u: 0.0,
                v: 0.0,
                r: 0.05,
            },
        };
        let obs = cam.observe_state(&state, &cable, &ObservationLimits::default());
        assert!((obs.theta_rate + 0.05).abs() < 1e-6, "{}", obs.theta_rate);
        // Rates are clipped to the observation box.
        let fast = VehicleState {
            pose: Pose::default(),
            velocity: crate::Velocity {
                u: 0.0,
                v: 2.0,
                r: 3.0,
            },
        };
        let obs = cam.observe_state(&fast, &cable, &ObservationLimits::default());
        assert_eq!((obs.x_g_rate, obs.theta_rate), (-0.5, -1.0));
    }

    #[test]
    fn a_line_from_polar_coordinates_is_the_line_the_camera_sees() {
        let cam = camera();
        let cable = Cable::default();
        for (y, psi) in [
            (0.0, 0.0),
            (0.2, 0.3),
            (-0.3, 60f64.to_radians()),
            (0.1, -80f64.to_radians()),
        ] {
            let seen = cam.view(&Pose { x: 0.0, y, psi }, &cable).unwrap();
            let from = CableLine::from_polar(seen.rho, seen.theta, 320.0, 240.0).unwrap();
            assert!((from.x_g - seen.x_g).abs() < 1e-12 && (from.y_g - seen.y_g).abs() < 1e-12);
            for k in 0..2 {
                assert!(
                    (from.ends[k][0] - seen.ends[k][0]).abs() < 1e-9
                        && (from.ends[k][1] - seen.ends[k][1]).abs() < 1e-9
                );
            }
        }
        assert!(CableLine::from_polar(500.0, 0.0, 320.0, 240.0).is_none());
    }

    #[test]
    fn pose_for_inverts_the_view_for_any_mounting() {
        let cable = Cable {
            origin: [2.0, -1.0],
            heading: 30f64.to_radians(),
            width_m: 0.05,
        };
        for mount in [(0.0, 0.0), (0.15, 0.05)] {
            let cam = Camera::new(&CameraParams {
                mount_x_m: mount.0,
                mount_y_m: mount.1,
                ..CameraParams::default()
            });
            for (x_g, theta_deg) in [(0.0, 0.0), (0.3, -40.0), (-0.35, 45.0), (0.1, 10.0)] {
                let theta = f64::to_radians(theta_deg);
                let pose = cam.pose_for(&cable, x_g, theta, 1.5).expect("reachable");
                let line = cam.view(&pose, &cable).unwrap();
                assert!(
                    (line.x_g - x_g).abs() < 1e-6 && (line.theta - theta).abs() < 1e-9,
                    "mount {mount:?}"
                );
            }
        }
        // A mid point outside the image cannot be seen.
        assert!(camera().pose_for(&cable, 0.6, 0.0, 0.0).is_none());
    }

    #[test]
    fn an_off_centre_camera_sees_the_cable_shifted() {
        let params = CameraParams {
            mount_x_m: 0.0,
            mount_y_m: 0.1,
            ..CameraParams::default()
        };
        let cam = Camera::new(&params);
        // Over the cable, the camera is 0.1 m to starboard: the cable appears left of centre.
        let line = cam.view(&Pose::default(), &Cable::default()).unwrap();
        let floor_width = 2.0 * 30f64.to_radians().tan();
        assert!((line.x_g + 0.1 / floor_width).abs() < 1e-12);
    }
}
