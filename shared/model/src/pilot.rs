//! The stack's commands as the sticks of an autopilot's pilot (`scenario.toml [pilot]`): the
//! conversion the vehicle twin applies to the setpoints of its thruster topic (its autopilot takes
//! them as MANUAL_CONTROL's axes), and the one a MAVLink companion must send for the vehicle to do
//! what step one's model says (the `ardusub` thruster sink sends the same axes, with the gain the
//! autopilot reports).
//!
//! The allocator's setpoints become the generalised forces they make with the scenario's layout
//! ([`ThrusterLayout::forces`]): each DOF's command as the behaviours and the surge rule gave it
//! (scaled down together where a thruster saturated). Each becomes its MANUAL_CONTROL axis, x
//! surge, y sway (positive to starboard), r yaw (positive clockwise seen from above): `command x
//! fraction x 1000 / gain`, rounded and held within +-1000, where `fraction` is the share of the
//! pilot's full stick (at joystick gain 1) that the command of 1 stands for and `gain` the
//! autopilot's joystick gain (ArduSub scales every axis by it: `joystick.cpp`). z (heave, 0..1000)
//! stays at its neutral 500. A command reaches its full meaning only while fraction <= gain.

use crate::{Forces, ThrusterLayout};
use config::PilotParams;

/// MANUAL_CONTROL's axes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Axes {
    pub x: i16,
    pub y: i16,
    pub z: i16,
    pub r: i16,
}

/// A full stick axis.
pub const FULL_AXIS: f64 = 1000.0;
/// Heave's neutral: the middle of its 0..1000.
pub const Z_NEUTRAL: i16 = 500;

impl Axes {
    /// Every stick centred.
    pub const NEUTRAL: Axes = Axes {
        x: 0,
        y: 0,
        z: Z_NEUTRAL,
        r: 0,
    };
}

/// One DOF's axis: `command x fraction x 1000 / gain`, rounded, within +-1000 (a command that is
/// not finite is 0, as every command is). The MAVLink companion sends its axes with this very
/// function, so that the twin's conversion and the wire's round alike.
pub fn axis(command: f64, fraction: f64, gain: f64) -> i16 {
    let c = crate::bounds::unit(command).0;
    (c * fraction * FULL_AXIS / gain)
        .round()
        .clamp(-FULL_AXIS, FULL_AXIS) as i16
}

/// The axes for the stack's per-DOF commands `forces` under `pilot`, at joystick gain `gain`
/// (ArduSub keeps it within 0.1..1).
pub fn axes(forces: &Forces, pilot: &PilotParams, gain: f64) -> Axes {
    let f = &pilot.fraction;
    Axes {
        x: axis(forces.surge, f.surge, gain),
        y: axis(forces.sway, f.sway, gain),
        z: Z_NEUTRAL,
        r: axis(forces.yaw, f.yaw, gain),
    }
}

/// The axes for the allocator's `setpoints`: their forces through `layout`, then [`axes`].
pub fn setpoint_axes(
    layout: &ThrusterLayout,
    setpoints: &[f64],
    pilot: &PilotParams,
    gain: f64,
) -> Axes {
    axes(&layout.forces(setpoints), pilot, gain)
}

#[cfg(test)]
mod tests {
    use super::*;
    use config::{PilotFractions, PilotMode, Thrusters};

    fn pilot() -> PilotParams {
        PilotParams {
            mode: PilotMode::AltHold,
            fraction: PilotFractions {
                surge: 0.05,
                sway: 0.08,
                yaw: 0.2,
            },
            yaw_rate_time_constant_s: Some(0.1),
            autopilot: Default::default(),
        }
    }

    fn f(surge: f64, sway: f64, yaw: f64) -> Forces {
        Forces { surge, sway, yaw }
    }

    /// A command on one DOF moves that axis only, by command x fraction x 1000 / gain, with the
    /// command's sign; heave stays neutral.
    #[test]
    fn each_dof_drives_its_own_axis_scaled_by_its_fraction_and_the_gain() {
        let p = pilot();
        for (forces, want) in [
            (f(1.0, 0.0, 0.0), (100, 0, 0)),
            (f(-0.5, 0.0, 0.0), (-50, 0, 0)),
            (f(0.0, 1.0, 0.0), (0, 160, 0)),
            (f(0.0, -0.25, 0.0), (0, -40, 0)),
            (f(0.0, 0.0, 1.0), (0, 0, 400)),
            (f(0.0, 0.0, -0.3), (0, 0, -120)),
            (f(0.2, -0.5, 0.7), (20, -80, 280)),
        ] {
            let a = axes(&forces, &p, 0.5);
            assert_eq!((a.x, a.y, a.r), want, "{forces:?}");
            assert_eq!(a.z, Z_NEUTRAL);
        }
        // At full gain the same command is half the axis; rounding is to the nearest.
        assert_eq!(axes(&f(0.0, 0.0, 1.0), &p, 1.0).r, 200);
        assert_eq!(axes(&f(0.0, 0.0, 0.0024), &p, 1.0).r, 0);
        assert_eq!(axes(&f(0.0, 0.0, 0.0026), &p, 1.0).r, 1);
        // Beyond the gain's reach the axis is full; a broken command is neutral.
        let mut wide = p.clone();
        wide.fraction.yaw = 0.8;
        assert_eq!(axes(&f(0.0, 0.0, 1.0), &wide, 0.5).r, 1000);
        assert_eq!(axes(&f(0.0, 0.0, -1.0), &wide, 0.5).r, -1000);
        assert_eq!(axes(&f(f64::NAN, 0.0, 0.0), &p, 0.5), Axes::NEUTRAL);
    }

    /// Setpoints a layout's pseudo-inverse made from per-DOF commands give those commands' axes:
    /// the BlueROV2's four vectored thrusters, each DOF alone and together.
    #[test]
    fn setpoints_through_the_vectored_layout_give_the_commands_axes() {
        let t = |name: &str, x_m, y_m, heading_deg| config::ThrusterParams {
            name: name.into(),
            x_m,
            y_m,
            heading_deg,
        };
        let layout = ThrusterLayout::new(&Thrusters {
            thruster: vec![
                t("front_right", 0.156, 0.111, 135.0),
                t("front_left", 0.156, -0.111, -135.0),
                t("rear_right", -0.156, 0.111, 45.0),
                t("rear_left", -0.156, -0.111, -45.0),
            ],
        });
        let b = layout.matrix();
        let pinv = b.clone().pseudo_inverse(1e-12).unwrap();
        let p = pilot();
        for command in [
            f(0.4, 0.0, 0.0),
            f(0.0, -0.6, 0.0),
            f(0.0, 0.0, 0.5),
            f(0.3, 0.2, -0.1),
        ] {
            let tau = nalgebra::Vector3::new(command.surge, command.sway, command.yaw);
            let setpoints: Vec<f64> = (pinv.clone() * tau).iter().copied().collect();
            assert!(setpoints.iter().all(|s| s.abs() <= 1.0), "{setpoints:?}");
            assert_eq!(
                setpoint_axes(&layout, &setpoints, &p, 0.5),
                axes(&command, &p, 0.5),
                "{command:?}"
            );
        }
        // Sway to starboard: every thruster's share is lateral; the axis is positive y.
        let tau = nalgebra::Vector3::new(0.0, 0.5, 0.0);
        let setpoints: Vec<f64> = (pinv * tau).iter().copied().collect();
        assert_eq!(
            setpoint_axes(&layout, &setpoints, &p, 0.5),
            Axes {
                y: 80,
                ..Axes::NEUTRAL
            }
        );
    }
}
