//! The identified 3-DOF model (paper Table I) and the kinematics in the pool frame.
//!
//! Each DOF follows `dv/dt = alpha*tau - beta*v*|v| - gamma*v + delta`. The control period (0.2 s) is
//! split into sub-steps of at most `max_substep_s`. Within a sub-step a DOF without quadratic damping
//! (beta = 0, the identified model) is advanced by its exact solution; with quadratic damping (the
//! vehicle twin) by classical Runge-Kutta. The pose follows the mean body velocity of the sub-step at
//! the mid-point heading.

use config::{DofModel, ModelParams};
use serde::{Deserialize, Serialize};

/// Position and heading in the pool frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    pub x: f64,
    pub y: f64,
    /// Heading from the pool's x axis towards its y axis (rad).
    pub psi: f64,
}

/// Body-frame velocities: surge u and sway v (m/s), yaw rate r (rad/s).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Velocity {
    pub u: f64,
    pub v: f64,
    pub r: f64,
}

/// The time derivative of a [`Pose`], in the pool frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PoseRate {
    pub x: f64,
    pub y: f64,
    pub psi: f64,
}

impl Pose {
    /// This pose advanced by `rate` for `dt` seconds (a straight-line step, for small `dt`).
    pub fn advanced(&self, rate: &PoseRate, dt: f64) -> Pose {
        Pose {
            x: self.x + rate.x * dt,
            y: self.y + rate.y * dt,
            psi: self.psi + rate.psi * dt,
        }
    }
}

/// The vehicle's pose and body velocity.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct VehicleState {
    pub pose: Pose,
    pub velocity: Velocity,
}

impl VehicleState {
    /// The pose's rate of change in still water.
    pub fn pose_rate(&self) -> PoseRate {
        let (s, c) = self.pose.psi.sin_cos();
        let Velocity { u, v, r } = self.velocity;
        PoseRate {
            x: u * c - v * s,
            y: u * s + v * c,
            psi: r,
        }
    }
}

/// The model's normalised generalised forces, each in [-1, 1].
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Forces {
    pub surge: f64,
    pub sway: f64,
    pub yaw: f64,
}

impl Forces {
    /// Each force under the rule for bad values ([`crate::bounds`]): within [-1, 1], a value that is
    /// not finite 0 (a broken command must not move the vehicle).
    pub fn clamped(self) -> Forces {
        self.bounded(&mut crate::bounds::Fixes::default())
    }

    /// Like [`Forces::clamped`], counting what the rule changed, DOF by DOF.
    pub fn bounded(self, fixes: &mut crate::bounds::Fixes) -> Forces {
        let mut c = |f: f64| fixes.note(crate::bounds::unit(f));
        Forces {
            surge: c(self.surge),
            sway: c(self.sway),
            yaw: c(self.yaw),
        }
    }
}

/// Integrates the model.
#[derive(Clone, Debug)]
pub struct Dynamics {
    params: ModelParams,
}

impl Dynamics {
    pub fn new(params: ModelParams) -> Self {
        Dynamics { params }
    }

    pub fn params(&self) -> &ModelParams {
        &self.params
    }

    /// The state after `dt` seconds of constant forces (clipped to [-1, 1]) in still water.
    pub fn step(&self, state: &VehicleState, forces: Forces, dt: f64) -> VehicleState {
        self.step_in_current(state, forces, dt, [0.0, 0.0])
    }

    /// Like [`Dynamics::step`], with the water moving at `current` (m/s, pool frame): the body
    /// velocities are relative to the water, so the current adds to the pose's drift.
    pub fn step_in_current(
        &self,
        state: &VehicleState,
        forces: Forces,
        dt: f64,
        current: [f64; 2],
    ) -> VehicleState {
        if dt <= 0.0 {
            return *state;
        }
        let forces = forces.clamped();
        let n = (dt / self.params.max_substep_s).ceil().max(1.0);
        let h = dt / n;
        let surge = DofStepper::new(&self.params.surge, forces.surge, h);
        let sway = DofStepper::new(&self.params.sway, forces.sway, h);
        let yaw = DofStepper::new(&self.params.yaw, forces.yaw, h);

        let mut s = *state;
        for _ in 0..n as usize {
            let v0 = s.velocity;
            let v1 = Velocity {
                u: surge.advance(v0.u),
                v: sway.advance(v0.v),
                r: yaw.advance(v0.r),
            };
            let mean = Velocity {
                u: 0.5 * (v0.u + v1.u),
                v: 0.5 * (v0.v + v1.v),
                r: 0.5 * (v0.r + v1.r),
            };
            let (sin, cos) = (s.pose.psi + 0.5 * h * mean.r).sin_cos();
            s.pose.x += h * (mean.u * cos - mean.v * sin + current[0]);
            s.pose.y += h * (mean.u * sin + mean.v * cos + current[1]);
            s.pose.psi += h * mean.r;
            s.velocity = v1;
        }
        s.pose.psi = crate::wrap_pi(s.pose.psi);
        s
    }
}

/// Advances one DOF's velocity by one sub-step of length `h` under constant thrust.
struct DofStepper {
    model: DofModel,
    force: f64,
    h: f64,
    /// exp(-gamma h), for the exact solution when beta = 0.
    decay: f64,
}

impl DofStepper {
    fn new(model: &DofModel, tau: f64, h: f64) -> Self {
        DofStepper {
            model: *model,
            force: model.alpha * tau + model.delta,
            h,
            decay: (-model.gamma * h).exp(),
        }
    }

    fn advance(&self, v: f64) -> f64 {
        let m = &self.model;
        if m.beta == 0.0 {
            // dv/dt = force - gamma v: v(h) = v_inf + (v - v_inf) e^{-gamma h}.
            let v_inf = self.force / m.gamma;
            return v_inf + (v - v_inf) * self.decay;
        }
        let f = |v: f64| self.force - m.beta * v * v.abs() - m.gamma * v;
        let h = self.h;
        let k1 = f(v);
        let k2 = f(v + 0.5 * h * k1);
        let k3 = f(v + 0.5 * h * k2);
        let k4 = f(v + h * k3);
        v + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(dynamics: &Dynamics, forces: Forces, seconds: f64) -> Vec<VehicleState> {
        let mut s = VehicleState::default();
        let mut out = vec![s];
        for _ in 0..(seconds / 0.2).round() as usize {
            s = dynamics.step(&s, forces, 0.2);
            out.push(s);
        }
        out
    }

    /// Each DOF's step response from rest: v(t) = v_inf (1 - e^{-gamma t}), so v reaches 63.2% of its
    /// final value after one time constant 1/gamma, and its final value is (alpha + delta)/gamma.
    #[test]
    fn step_response_matches_the_analytic_solution_for_each_dof() {
        let params = ModelParams::default();
        let dynamics = Dynamics::new(params.clone());
        type Pick = fn(&Velocity) -> f64;
        let cases: [(&str, DofModel, Forces, Pick); 3] = [
            (
                "surge",
                params.surge,
                Forces {
                    surge: 1.0,
                    ..Forces::default()
                },
                |v| v.u,
            ),
            (
                "sway",
                params.sway,
                Forces {
                    sway: 1.0,
                    ..Forces::default()
                },
                |v| v.v,
            ),
            (
                "yaw",
                params.yaw,
                Forces {
                    yaw: 1.0,
                    ..Forces::default()
                },
                |v| v.r,
            ),
        ];
        for (name, m, forces, pick) in cases {
            let v_inf = (m.alpha + m.delta) / m.gamma;
            let trace = run(&dynamics, forces, 40.0);
            for (k, s) in trace.iter().enumerate() {
                let t = k as f64 * 0.2;
                let exact = v_inf * (1.0 - (-m.gamma * t).exp());
                assert!(
                    (pick(&s.velocity) - exact).abs() < 1e-9,
                    "{name} at t={t}: {} vs {exact}",
                    pick(&s.velocity)
                );
            }
            let last = pick(&trace.last().unwrap().velocity);
            assert!(
                (last - v_inf).abs() < 1e-3 * v_inf.abs(),
                "{name}: final {last} vs {v_inf}"
            );
            // The time constant read off the trace: the first time v crosses 63.2% of v_inf.
            let tc = 1.0 / m.gamma;
            let fine = Dynamics::new(params.clone());
            let mut s = VehicleState::default();
            let mut t = 0.0;
            while pick(&s.velocity).abs() < (1.0 - (-1.0f64).exp()) * v_inf.abs() {
                s = fine.step(&s, forces, 0.001);
                t += 0.001;
            }
            assert!(
                (t - tc).abs() < 0.002 + 0.002 * tc,
                "{name}: time constant {t} vs {tc}"
            );
        }
    }

    #[test]
    fn full_surge_thrust_gives_about_point_three_metres_per_second() {
        let m = ModelParams::default().surge;
        assert!((m.steady_velocity(1.0) - 0.31).abs() < 0.01);
    }

    /// With quadratic damping only, dv/dt = a - b v^2 has v(t) = sqrt(a/b) tanh(sqrt(a b) t).
    #[test]
    fn quadratic_damping_matches_its_closed_form() {
        let params = ModelParams {
            sway: DofModel {
                alpha: 0.15,
                beta: 0.6,
                gamma: 0.0,
                delta: 0.0,
            },
            ..ModelParams::default()
        };
        let dynamics = Dynamics::new(params);
        let trace = run(
            &dynamics,
            Forces {
                sway: 1.0,
                ..Forces::default()
            },
            10.0,
        );
        let (a, b) = (0.15f64, 0.6f64);
        for (k, s) in trace.iter().enumerate() {
            let t = k as f64 * 0.2;
            let exact = (a / b).sqrt() * ((a * b).sqrt() * t).tanh();
            assert!(
                (s.velocity.v - exact).abs() < 1e-8,
                "t={t}: {} vs {exact}",
                s.velocity.v
            );
        }
    }

    /// A single 0.2 s Euler step would overshoot the yaw rate's steady state (gamma*dt = 0.69);
    /// the sub-stepped integration must not.
    #[test]
    fn yaw_never_overshoots_its_steady_rate() {
        let params = ModelParams::default();
        let dynamics = Dynamics::new(params.clone());
        let v_inf = params.yaw.steady_velocity(1.0);
        for s in run(
            &dynamics,
            Forces {
                yaw: 1.0,
                ..Forces::default()
            },
            5.0,
        ) {
            assert!(s.velocity.r <= v_inf + 1e-12);
        }
    }

    /// Turning at a constant rate while surging traces a circle of radius u/r.
    #[test]
    fn kinematics_follow_a_circle_at_constant_speed_and_turn_rate() {
        let dynamics = Dynamics::new(ModelParams::default());
        let (u, r) = (0.2, 0.05); // within reach: full yaw thrust gives 0.083 rad/s
        // Hold the velocities at their steady state by choosing the thrust that sustains them.
        let p = dynamics.params().clone();
        let tau_u = (p.surge.gamma * u - p.surge.delta) / p.surge.alpha;
        let tau_r = (p.yaw.gamma * r - p.yaw.delta) / p.yaw.alpha;
        let tau_v = -p.sway.delta / p.sway.alpha;
        assert!(tau_u.abs() <= 1.0 && tau_r.abs() <= 1.0);
        let forces = Forces {
            surge: tau_u,
            sway: tau_v,
            yaw: tau_r,
        };
        let mut s = VehicleState {
            pose: Pose::default(),
            velocity: Velocity { u, v: 0.0, r },
        };
        let radius = u / r;
        for _ in 0..100 {
            s = dynamics.step(&s, forces, 0.2);
            // Centre of the circle is at (0, radius) for a starboard turn from the origin heading x.
            let d = (s.pose.x.powi(2) + (s.pose.y - radius).powi(2)).sqrt();
            assert!(
                (d - radius).abs() < 1e-6,
                "distance from centre {d} vs radius {radius}"
            );
        }
    }

    #[test]
    fn a_current_drifts_the_vehicle() {
        let dynamics = Dynamics::new(ModelParams::default());
        let s =
            dynamics.step_in_current(&VehicleState::default(), Forces::default(), 1.0, [0.0, 0.1]);
        assert!((s.pose.y - 0.1).abs() < 1e-3);
    }

    #[test]
    fn broken_commands_do_not_move_the_vehicle() {
        let dynamics = Dynamics::new(ModelParams::default());
        let f = Forces {
            surge: f64::NAN,
            sway: 5.0,
            yaw: -5.0,
        }
        .clamped();
        assert_eq!((f.surge, f.sway, f.yaw), (0.0, 1.0, -1.0));
        let s = dynamics.step(
            &VehicleState::default(),
            Forces {
                surge: f64::NAN,
                ..Forces::default()
            },
            0.2,
        );
        assert!(s.pose.x.is_finite() && s.velocity.u.is_finite());
    }
}
