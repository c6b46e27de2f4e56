//! Poses that put the cable where a test or a data set wants it in the image.

use crate::rng::SplitMix64;
use model::{Cable, Camera, Pose, PoseRate, Velocity};

/// The pose, at `along_m` metres along the cable, from which the camera sees the cable at `x_g`
/// (fraction of the width) and `theta` (rad); `None` when no such pose exists. See
/// [`Camera::pose_for`].
pub fn pose_for_line(
    camera: &Camera,
    cable: &Cable,
    x_g: f64,
    theta: f64,
    along_m: f64,
) -> Option<Pose> {
    camera.pose_for(cable, x_g, theta, along_m)
}

/// Draws poses with the cable in view: x_g ~ U[-x_g_max, x_g_max], Theta ~ U[-theta_max, theta_max]
/// (rad), anywhere along the cable, and body velocities for motion blur.
pub struct PoseSampler {
    rng: SplitMix64,
    pub x_g_max: f64,
    pub theta_max: f64,
    pub along_m: f64,
    /// Velocities ~ U[-max, max] per axis, surge ~ U[0, max].
    pub max_velocity: Velocity,
}

/// One sampled view: the pose, a velocity, and what the geometric camera says.
#[derive(Clone, Copy, Debug)]
pub struct SampledPose {
    pub pose: Pose,
    pub velocity: Velocity,
    pub rate: PoseRate,
}

impl PoseSampler {
    /// The accuracy tests' range, wider than the episodes' starts: x_g in [-0.4, 0.4], Theta in
    /// [-60, 60] degrees, velocities up to the scenario's (surge 0.3 m/s, sway 0.15 m/s, yaw rate 0.3 rad/s).
    pub fn new(seed: u64) -> Self {
        PoseSampler {
            rng: SplitMix64::new(seed),
            x_g_max: 0.4,
            theta_max: 60f64.to_radians(),
            along_m: 5.0,
            max_velocity: Velocity {
                u: 0.3,
                v: 0.15,
                r: 0.3,
            },
        }
    }

    /// A pose with the cable in view at a random x_g and Theta.
    pub fn with_cable(&mut self, camera: &Camera, cable: &Cable) -> SampledPose {
        loop {
            let x_g = self.rng.uniform(-self.x_g_max, self.x_g_max);
            let theta = self.rng.uniform(-self.theta_max, self.theta_max);
            let along = self.rng.uniform(-self.along_m, self.along_m);
            if let Some(pose) = pose_for_line(camera, cable, x_g, theta, along) {
                return self.with_velocity(pose);
            }
        }
    }

    /// A pose from which the cable is far out of view (at least `min_distance_m` off it).
    pub fn without_cable(
        &mut self,
        camera: &Camera,
        cable: &Cable,
        min_distance_m: f64,
    ) -> SampledPose {
        loop {
            let side = if self.rng.next_f64() < 0.5 { -1.0 } else { 1.0 };
            let across = side * self.rng.uniform(min_distance_m, 2.0 * min_distance_m);
            let p = cable.point(self.rng.uniform(-self.along_m, self.along_m), across);
            let psi = self
                .rng
                .uniform(-std::f64::consts::PI, std::f64::consts::PI);
            let pose = Pose {
                x: p[0],
                y: p[1],
                psi,
            };
            if camera.view(&pose, cable).is_none() {
                return self.with_velocity(pose);
            }
        }
    }

    fn with_velocity(&mut self, pose: Pose) -> SampledPose {
        let m = self.max_velocity;
        let velocity = Velocity {
            u: self.rng.uniform(0.0, m.u),
            v: self.rng.uniform(-m.v, m.v),
            r: self.rng.uniform(-m.r, m.r),
        };
        let rate = model::VehicleState { pose, velocity }.pose_rate();
        SampledPose {
            pose,
            velocity,
            rate,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use config::{CableParams, CameraParams};

    #[test]
    fn poses_put_the_cable_where_asked() {
        let cam = Camera::new(&CameraParams::default());
        let cable = Cable::new(&CableParams {
            x_m: 1.0,
            y_m: -0.5,
            heading_deg: 20.0,
            width_m: 0.05,
        });
        for (x_g, theta_deg) in [(0.0, 0.0), (0.3, -40.0), (-0.4, 60.0), (0.1, 70.0)] {
            let theta = f64::to_radians(theta_deg);
            let pose = pose_for_line(&cam, &cable, x_g, theta, 2.0).unwrap();
            let line = cam.view(&pose, &cable).unwrap();
            assert!(
                (line.x_g - x_g).abs() < 1e-6 && (line.theta - theta).abs() < 1e-9,
                "{line:?}"
            );
        }
        assert!(pose_for_line(&cam, &cable, 0.6, 0.0, 0.0).is_none());
        let mut s = PoseSampler::new(1);
        for _ in 0..100 {
            let p = s.with_cable(&cam, &cable);
            let line = cam.view(&p.pose, &cable).unwrap();
            assert!(line.x_g.abs() <= 0.4 + 1e-6 && line.theta.abs() <= s.theta_max + 1e-9);
            let q = s.without_cable(&cam, &cable, 1.0);
            assert!(cam.view(&q.pose, &cable).is_none());
        }
    }
}
