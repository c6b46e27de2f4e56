//! The thruster layout: from setpoints to the model's normalised forces.
//!
//! Each thruster contributes, per unit setpoint, a generalised force (surge, sway, yaw moment) given
//! by its position and direction. The model's forces are normalised so that each DOF reaches 1 when
//! every thruster pushes that DOF as hard as it can: row k of the layout matrix is divided by the sum
//! of |B_ki|. With DESIGN.md's layout this gives tau_surge = (T_port + T_starboard)/2,
//! tau_yaw = (T_port - T_starboard)/2 and tau_sway = T_lateral.

use crate::Forces;
use config::Thrusters;
use nalgebra::{Dyn, OMatrix, U3};

/// The 3 x n matrix from thruster setpoints to normalised forces.
pub type LayoutMatrix = OMatrix<f64, U3, Dyn>;

#[derive(Clone, Debug, PartialEq)]
pub struct ThrusterLayout {
    names: Vec<String>,
    matrix: LayoutMatrix,
}

impl ThrusterLayout {
    /// The layout of a validated thruster configuration.
    pub fn new(thrusters: &Thrusters) -> Self {
        let columns = thrusters.columns();
        let mut matrix = LayoutMatrix::zeros(columns.len());
        for (j, c) in columns.iter().enumerate() {
            for k in 0..3 {
                matrix[(k, j)] = c[k];
            }
        }
        for k in 0..3 {
            let reach: f64 = matrix.row(k).iter().map(|b| b.abs()).sum();
            if reach > 0.0 {
                matrix.row_mut(k).scale_mut(1.0 / reach);
            }
        }
        ThrusterLayout {
            names: thrusters.thruster.iter().map(|t| t.name.clone()).collect(),
            matrix,
        }
    }

    /// The number of thrusters.
    pub fn len(&self) -> usize {
        self.names.len()
    }

    pub fn is_empty(&self) -> bool {
        self.names.is_empty()
    }

    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// Setpoints to normalised forces: rows surge, sway, yaw.
    pub fn matrix(&self) -> &LayoutMatrix {
        &self.matrix
    }

    /// The forces the setpoints produce; each setpoint is put under the rule for bad values first
    /// ([`crate::bounds`]: within [-1, 1], a value that is not finite 0).
    /// Missing setpoints count as 0, extra ones are ignored.
    pub fn forces(&self, setpoints: &[f64]) -> Forces {
        let mut f = [0.0; 3];
        for (j, &t) in setpoints.iter().take(self.len()).enumerate() {
            let t = crate::bounds::unit(t).0;
            for (k, fk) in f.iter_mut().enumerate() {
                *fk += self.matrix[(k, j)] * t;
            }
        }
        Forces {
            surge: f[0],
            sway: f[1],
            yaw: f[2],
        }
    }
}

impl Default for ThrusterLayout {
    fn default() -> Self {
        ThrusterLayout::new(&Thrusters::default())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_layout_gives_design_md_forces() {
        let layout = ThrusterLayout::default();
        let f = layout.forces(&[1.0, 0.0, 0.0]); // port forward
        assert!(
            (f.surge - 0.5).abs() < 1e-12 && (f.yaw - 0.5).abs() < 1e-12 && f.sway.abs() < 1e-12
        );
        let f = layout.forces(&[0.0, 1.0, 0.0]); // starboard forward turns the bow to port
        assert!((f.surge - 0.5).abs() < 1e-12 && (f.yaw + 0.5).abs() < 1e-12);
        let f = layout.forces(&[0.0, 0.0, -1.0]); // lateral pushes to port
        assert!((f.sway + 1.0).abs() < 1e-12 && f.surge.abs() < 1e-12 && f.yaw.abs() < 1e-12);
        let f = layout.forces(&[1.0, 1.0, 0.0]);
        assert!((f.surge - 1.0).abs() < 1e-12 && f.yaw.abs() < 1e-12);
    }

    #[test]
    fn setpoints_are_clipped() {
        let layout = ThrusterLayout::default();
        assert_eq!(
            layout.forces(&[5.0, 5.0, f64::NAN]),
            layout.forces(&[1.0, 1.0, 0.0])
        );
    }
}
