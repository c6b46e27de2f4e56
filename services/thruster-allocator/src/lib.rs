//! The thruster allocator's core: maps the behaviours' DOF commands (normalised surge, sway and yaw
//! forces) to thruster setpoints in [-1, 1].
//!
//! Each DOF's command is first put under the rule for bad values (`model::bounds`: within [-1, 1],
//! a value that is not finite 0), DOF by DOF, so one absurd command (a sway of 50) cannot squeeze the
//! others out of the scaling below. The layout's matrix `B` (setpoints to normalised forces, see
//! [`model::thrusters`]) has full row rank, so its Moore-Penrose pseudo-inverse `B' (B B')^-1` gives
//! the least-norm setpoints for a force. When a setpoint exceeds 1 the whole vector is scaled down by
//! the largest magnitude: the vehicle then pushes in the commanded direction, only less hard
//! (clipping each thruster alone would turn a pure surge-plus-yaw command into a different mix).
//!
//! [`step::StepAllocator`] is the allocator's side of the lockstep: it judges each command's stamp
//! (`runtime::screen::Screen`), gathers the three commands of one step, answers each step once,
//! and allocates a step whose commands did not all arrive within the deadline with the missing ones
//! as 0. The allocator only publishes its setpoints; on the vehicle the thruster driver
//! (`thruster-driver`) owns the thrusters.

pub mod step;

use config::{MAX_THRUSTERS, Thrusters};
use model::{Forces, ThrusterLayout};
use nalgebra::{Dyn, OMatrix, U3};

/// Thruster setpoints, one per thruster of the layout, each in [-1, 1].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Setpoints {
    values: [f64; MAX_THRUSTERS],
    len: usize,
}

impl Setpoints {
    pub fn as_slice(&self) -> &[f64] {
        &self.values[..self.len]
    }
}

/// The result of one allocation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Allocation {
    pub setpoints: Setpoints,
    /// The factor applied to keep every setpoint within [-1, 1] (1 when nothing saturated).
    pub scale: f64,
    /// The commands the rule for bad values changed before allocation.
    pub fixes: model::bounds::Fixes,
}

pub struct Allocator {
    layout: ThrusterLayout,
    pseudo_inverse: OMatrix<f64, Dyn, U3>,
}

impl Allocator {
    /// The allocator of a validated thruster layout (validation guarantees full row rank).
    pub fn new(thrusters: &Thrusters) -> Self {
        let layout = ThrusterLayout::new(thrusters);
        let b = layout.matrix();
        let gram = b * b.transpose();
        let gram_inv = gram
            .try_inverse()
            .expect("a validated layout reaches all three DOFs");
        let pseudo_inverse = b.transpose() * gram_inv;
        Allocator {
            layout,
            pseudo_inverse,
        }
    }

    pub fn layout(&self) -> &ThrusterLayout {
        &self.layout
    }

    /// The setpoints for the commanded forces, each DOF's command put under the rule for bad values
    /// first (a broken behaviour cannot drive the thrusters, nor crowd out the other DOFs).
    pub fn allocate(&self, command: Forces) -> Allocation {
        let mut fixes = model::bounds::Fixes::default();
        let command = command.bounded(&mut fixes);
        let tau = [command.surge, command.sway, command.yaw];
        let n = self.layout.len();
        let mut values = [0.0; MAX_THRUSTERS];
        for (i, value) in values.iter_mut().take(n).enumerate() {
            *value = (0..3).map(|k| self.pseudo_inverse[(i, k)] * tau[k]).sum();
        }
        let peak = values[..n].iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let scale = if peak > 1.0 { 1.0 / peak } else { 1.0 };
        for v in &mut values[..n] {
            *v *= scale;
        }
        Allocation {
            setpoints: Setpoints { values, len: n },
            scale,
            fixes,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use config::ThrusterParams;

    fn close(a: Forces, b: Forces) -> bool {
        (a.surge - b.surge).abs() < 1e-12
            && (a.sway - b.sway).abs() < 1e-12
            && (a.yaw - b.yaw).abs() < 1e-12
    }

    #[test]
    fn feasible_commands_map_back_exactly() {
        let alloc = Allocator::new(&Thrusters::default());
        for cmd in [
            Forces {
                surge: 0.5,
                sway: -0.3,
                yaw: 0.2,
            },
            Forces {
                surge: -0.2,
                sway: 1.0,
                yaw: -0.7,
            },
            Forces::default(),
        ] {
            let a = alloc.allocate(cmd);
            assert_eq!(a.scale, 1.0);
            assert!(close(alloc.layout().forces(a.setpoints.as_slice()), cmd));
        }
    }

    #[test]
    fn the_default_layout_matches_design_md() {
        let alloc = Allocator::new(&Thrusters::default());
        let a = alloc.allocate(Forces {
            surge: 0.4,
            sway: 0.1,
            yaw: 0.2,
        });
        // port = surge + yaw, starboard = surge - yaw, lateral = sway.
        let s = a.setpoints.as_slice();
        assert!(
            (s[0] - 0.6).abs() < 1e-12 && (s[1] - 0.2).abs() < 1e-12 && (s[2] - 0.1).abs() < 1e-12
        );
    }

    #[test]
    fn saturation_keeps_the_direction() {
        let alloc = Allocator::new(&Thrusters::default());
        let cmd = Forces {
            surge: 1.0,
            sway: 0.5,
            yaw: 1.0,
        };
        let a = alloc.allocate(cmd);
        assert!(a.scale < 1.0);
        assert!(
            a.setpoints
                .as_slice()
                .iter()
                .all(|v| v.abs() <= 1.0 + 1e-12)
        );
        assert!(
            a.setpoints
                .as_slice()
                .iter()
                .any(|v| (v.abs() - 1.0).abs() < 1e-12)
        );
        let got = alloc.layout().forces(a.setpoints.as_slice());
        let want = Forces {
            surge: cmd.surge * a.scale,
            sway: cmd.sway * a.scale,
            yaw: cmd.yaw * a.scale,
        };
        assert!(close(got, want));
    }

    #[test]
    fn a_redundant_layout_uses_the_least_norm_setpoints() {
        // Four thrusters: two forward, two lateral fore and aft.
        let t = |name: &str, x_m, y_m, heading_deg| ThrusterParams {
            name: name.into(),
            x_m,
            y_m,
            heading_deg,
        };
        let layout = Thrusters {
            thruster: vec![
                t("port", 0.0, -0.3, 0.0),
                t("starboard", 0.0, 0.3, 0.0),
                t("bow", 0.4, 0.0, 90.0),
                t("stern", -0.4, 0.0, 90.0),
            ],
        };
        let alloc = Allocator::new(&layout);
        let cmd = Forces {
            surge: 0.2,
            sway: 0.4,
            yaw: 0.1,
        };
        let a = alloc.allocate(cmd);
        assert!(close(alloc.layout().forces(a.setpoints.as_slice()), cmd));
        // Least norm: no component in the layout's null space.
        let b = alloc.layout().matrix();
        let x = nalgebra::DVector::from_column_slice(a.setpoints.as_slice());
        let null_part = &x - b.transpose() * (b * b.transpose()).try_inverse().unwrap() * (b * &x);
        assert!(null_part.norm() < 1e-12);
    }

    #[test]
    fn nan_commands_give_zero_thrust() {
        let alloc = Allocator::new(&Thrusters::default());
        let a = alloc.allocate(Forces {
            surge: f64::NAN,
            sway: f64::INFINITY,
            yaw: 0.0,
        });
        assert!(a.setpoints.as_slice().iter().all(|v| *v == 0.0));
        assert_eq!((a.fixes.non_finite, a.fixes.clamped), (2, 0));
    }

    /// An absurd command on one DOF is clamped on its own: the other DOFs keep their thrust.
    #[test]
    fn each_dof_is_clamped_before_allocation() {
        let alloc = Allocator::new(&Thrusters::default());
        let wild = alloc.allocate(Forces {
            surge: 0.5,
            sway: 50.0,
            yaw: 0.2,
        });
        let tame = alloc.allocate(Forces {
            surge: 0.5,
            sway: 1.0,
            yaw: 0.2,
        });
        assert_eq!(wild.setpoints, tame.setpoints);
        assert_eq!((wild.fixes.non_finite, wild.fixes.clamped), (0, 1));
        let f = alloc.layout().forces(wild.setpoints.as_slice());
        assert!(
            (f.surge - 0.5).abs() < 1e-12 && (f.yaw - 0.2).abs() < 1e-12,
            "{f:?}"
        );
    }
}
