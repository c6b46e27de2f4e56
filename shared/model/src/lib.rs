//! The vehicle and its world, as plain geometry and physics (no I/O; random draws come from the
//! caller).
//!
//! - [`dynamics`]: the identified 3-DOF model of the paper's Table I and the kinematics in the pool frame.
//! - [`cable`]: the straight cable on the pool floor.
//! - [`camera`]: the downward pinhole camera as geometry: where the cable's line falls in the image
//!   (rho, Theta, x_g, y_g), whether it is in view, and its rates. This is the ground truth the
//!   renderer and perception of `vision` are checked against, and the ideal perception of the trainer.
//! - [`thrusters`]: the thruster layout, mapping setpoints to the model's normalised forces.
//! - [`pilot`]: the stack's commands as an autopilot's pilot sticks (MANUAL_CONTROL's axes).
//! - [`linear`]: the decoupled linear sway and yaw dynamics in observation coordinates (for LQR).
//! - [`bounds`]: the one rule for bad values (non-finite is 0, out of range is clamped, both counted).
//!
//! Conventions (DESIGN.md): pool frame x forward along the pool, y to the right seen from above, z down,
//! heading psi from x towards y. Body frame x forward (surge u), y starboard (sway v), yaw rate r.

pub mod bounds;
pub mod cable;
pub mod camera;
pub mod dynamics;
pub mod linear;
pub mod pilot;
pub mod thrusters;

pub use cable::Cable;
pub use camera::{CableLine, CableObservation, Camera};
pub use dynamics::{Dynamics, Forces, Pose, PoseRate, VehicleState, Velocity};
pub use thrusters::ThrusterLayout;

use config::ResetParams;
use std::ops::RangeInclusive;

/// Wraps an angle to (-pi, pi].
pub fn wrap_pi(a: f64) -> f64 {
    let w = a.rem_euclid(std::f64::consts::TAU);
    if w > std::f64::consts::PI {
        w - std::f64::consts::TAU
    } else {
        w
    }
}

/// Wraps a line's angle to (-pi/2, pi/2]: a line has no direction, so angles are equal modulo pi.
pub fn wrap_half_pi(a: f64) -> f64 {
    use std::f64::consts::{FRAC_PI_2, PI};
    let w = a.rem_euclid(PI);
    if w > FRAC_PI_2 { w - PI } else { w }
}

/// A start pose with the cable seen at x_g ~ U[-x_g_max, x_g_max] and Theta ~ U[-theta_max,
/// theta_max], the episode resets of the simulator and the twin's repositionings. `uniform(range)`
/// draws uniformly from `range` (the caller's random stream: the model itself draws nothing).
///
/// The pose comes from [`Camera::pose_for`], exact in the camera's own geometry; a draw the image
/// cannot show (e.g. a large x_g with a nearly horizontal line) is drawn again.
pub fn start_pose(
    camera: &Camera,
    cable: &Cable,
    reset: &ResetParams,
    mut uniform: impl FnMut(RangeInclusive<f64>) -> f64,
) -> Pose {
    let theta_max = reset.theta_max_deg.to_radians();
    for _ in 0..1000 {
        let x_g = uniform(-reset.x_g_max..=reset.x_g_max);
        let theta = uniform(-theta_max..=theta_max);
        let along = uniform(-reset.along_cable_m..=reset.along_cable_m);
        if let Some(pose) = camera.pose_for(cable, x_g, theta, along) {
            return pose;
        }
    }
    // Unreachable with a validated reset box; a pose over the cable is the safe answer.
    let p = cable.point(0.0, 0.0);
    Pose {
        x: p[0],
        y: p[1],
        psi: cable.heading,
    }
}
