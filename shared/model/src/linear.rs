//! The decoupled linear dynamics of the sway and yaw observations, for the LQR yardstick.
//!
//! Near the cable, with the vehicle aligned and the identified model's simplifications (no quadratic
//! damping, camera at the rotation centre, no surge coupling, delta neglected):
//!
//! - yaw: Theta = -psi, so with state (Theta, dTheta/dt) and `dr/dt = alpha tau - gamma r`,
//!   `d2Theta/dt2 = -gamma dTheta/dt - alpha tau`;
//! - sway: x_g = -y / W with W the floor width seen by the camera, so with state (x_g, dx_g/dt) and
//!   `dv/dt = alpha tau - gamma v`, `d2x_g/dt2 = -gamma dx_g/dt - (alpha / W) tau`.

use crate::Camera;
use config::{DofModel, ModelParams};
use nalgebra::{Matrix2, Vector2};

/// A continuous-time linear system `dx/dt = A x + B u` with a 2-D state and a scalar input.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LinearDof {
    pub a: Matrix2<f64>,
    pub b: Vector2<f64>,
}

fn second_order(m: &DofModel, gain: f64) -> LinearDof {
    LinearDof {
        a: Matrix2::new(0.0, 1.0, 0.0, -m.gamma),
        b: Vector2::new(0.0, -gain * m.alpha),
    }
}

/// The yaw observation's dynamics, state (Theta, dTheta/dt).
pub fn yaw(model: &ModelParams) -> LinearDof {
    second_order(&model.yaw, 1.0)
}

/// The sway observation's dynamics, state (x_g, dx_g/dt).
pub fn sway(model: &ModelParams, camera: &Camera) -> LinearDof {
    let floor_width = camera.width() * camera.metres_per_px();
    second_order(&model.sway, 1.0 / floor_width)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Cable, Dynamics, Forces, Pose, VehicleState};
    use config::{CameraParams, ObservationLimits};

    /// The linear models predict the first step of the full model from the aligned, centred pose.
    #[test]
    fn linear_models_match_the_full_model_near_the_cable() {
        let params = ModelParams {
            sway: DofModel {
                delta: 0.0,
                ..ModelParams::default().sway
            },
            yaw: DofModel {
                delta: 0.0,
                ..ModelParams::default().yaw
            },
            ..ModelParams::default()
        };
        let camera = Camera::new(&CameraParams::default());
        let dynamics = Dynamics::new(params.clone());
        let cable = Cable::default();
        let limits = ObservationLimits::default();
        let dt = 0.01;
        for (lin, forces, pick) in [
            (
                sway(&params, &camera),
                Forces {
                    sway: 0.5,
                    ..Forces::default()
                },
                0usize,
            ),
            (
                yaw(&params),
                Forces {
                    yaw: 0.5,
                    ..Forces::default()
                },
                1usize,
            ),
        ] {
            let start = VehicleState {
                pose: Pose::default(),
                ..Default::default()
            };
            let next = dynamics.step(&start, forces, dt);
            let obs = camera.observe_state(&next, &cable, &limits);
            let rate = if pick == 0 {
                obs.x_g_rate
            } else {
                obs.theta_rate
            };
            // From rest, d(rate)/dt = B u.
            let predicted = lin.b[1] * 0.5 * dt;
            assert!(
                (rate - predicted).abs() < 0.02 * predicted.abs(),
                "{rate} vs {predicted}"
            );
        }
    }
}
