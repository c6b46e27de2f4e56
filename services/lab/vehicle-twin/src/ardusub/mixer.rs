//! The BlueROV2's vectored frame as ArduSub mixes it (`AP_Motors6DOF`, `SUB_FRAME_VECTORED`): four
//! horizontal thrusters at 45 degrees (1 front right, 2 front left, 3 rear right, 4 rear left) and
//! two vertical ones (5 right, 6 left).
//!
//! Each motor's thrust is `direction * (rpy + linear)`, clamped to [-1, 1], where `rpy` is the roll,
//! pitch and yaw inputs times the motor's factors and `linear` the throttle, forward and lateral
//! ones; the vectored frame limits the "rear" thrusters' forward share while the throttle is high
//! (`MOT_FV_CPLNG_K`). There is no normalisation: a motor saturates on its own. The PWM is
//! `1500 + 400 * thrust` (1100..1900 us).

/// The motors of the vectored frame.
pub const MOTORS: usize = 6;
/// The horizontal ones, motors 1..4 (the twin's plant moves in the horizontal plane only).
pub const HORIZONTAL: usize = 4;

/// Per motor: roll, pitch, yaw, throttle, forward, lateral factors (`SUB_FRAME_VECTORED`).
pub const FACTORS: [[f64; 6]; MOTORS] = [
    [0.0, 0.0, 1.0, 0.0, -1.0, 1.0],
    [0.0, 0.0, -1.0, 0.0, -1.0, -1.0],
    [0.0, 0.0, -1.0, 0.0, 1.0, 1.0],
    [0.0, 0.0, 1.0, 0.0, 1.0, -1.0],
    [1.0, 0.0, 0.0, -1.0, 0.0, 0.0],
    [-1.0, 0.0, 0.0, -1.0, 0.0, 0.0],
];

/// Which motors' forward share the coupling limit applies to, by the sign of the forward command
/// (the front pair when reversing, the rear pair when going forward).
const FORWARD_COUPLING: [i8; MOTORS] = [-1, -1, 1, 1, 0, 0];

/// The inputs ArduSub's modes give the motors, each in [-1, 1].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Inputs {
    pub roll: f64,
    pub pitch: f64,
    pub yaw: f64,
    /// Vertical thrust, bidirectional (0: neutral).
    pub throttle: f64,
    pub forward: f64,
    pub lateral: f64,
}

/// Each motor's thrust in [-1, 1].
pub fn mix(inputs: &Inputs, directions: &[f64; MOTORS], fv_coupling: f64) -> [f64; MOTORS] {
    let i = inputs;
    let limit = (1.0 - fv_coupling * i.throttle.abs()).max(0.0);
    let mut out = [0.0; MOTORS];
    for (m, o) in out.iter_mut().enumerate() {
        let f = FACTORS[m];
        let rpy = i.roll * f[0] + i.pitch * f[1] + i.yaw * f[2];
        let mut forward = i.forward;
        let c = FORWARD_COUPLING[m];
        if forward != 0.0 && c != 0 && (forward < 0.0) == (c < 0) {
            forward = forward.clamp(-limit, limit);
        }
        let linear = i.throttle * f[3] + forward * f[4] + i.lateral * f[5];
        *o = (directions[m] * (rpy + linear)).clamp(-1.0, 1.0);
    }
    out
}

/// A motor's PWM for its thrust (`calc_thrust_to_pwm`, MOT_PWM_MIN/MAX 1100/1900).
pub fn pwm(thrust: f64) -> u16 {
    (1500.0 + thrust.clamp(-1.0, 1.0) * 400.0) as u16
}

/// What an ESC makes of a PWM: the thruster's setpoint in [-1, 1].
pub fn setpoint(pwm: u16) -> f64 {
    ((pwm as f64 - 1500.0) / 400.0).clamp(-1.0, 1.0)
}

/// Checks that a thruster layout (surge, sway, yaw columns per thruster, in the model's convention)
/// is the vectored frame's: pure forward, lateral and yaw inputs through the mixer push the layout
/// along that axis only. Returns the axis that fails.
pub fn check_layout(columns: &[[f64; 3]]) -> Result<(), String> {
    if columns.len() != HORIZONTAL {
        return Err(format!(
            "the vectored frame has {HORIZONTAL} horizontal thrusters, the scenario's layout {}",
            columns.len()
        ));
    }
    let axes = [
        (
            "forward",
            0,
            Inputs {
                forward: 1.0,
                ..Default::default()
            },
        ),
        (
            "lateral",
            1,
            Inputs {
                lateral: 1.0,
                ..Default::default()
            },
        ),
        (
            "yaw",
            2,
            Inputs {
                yaw: 1.0,
                ..Default::default()
            },
        ),
    ];
    for (name, axis, inputs) in axes {
        let thrust = mix(&inputs, &[1.0; MOTORS], 0.0);
        let mut force = [0.0; 3];
        for (t, c) in thrust.iter().zip(columns) {
            for k in 0..3 {
                force[k] += t * c[k];
            }
        }
        let along = force[axis];
        let across = (0..3)
            .filter(|&k| k != axis)
            .map(|k| force[k].abs())
            .sum::<f64>();
        if along <= 0.0 || across > 1e-6 * along.abs().max(1.0) {
            return Err(format!(
                "a pure {name} input moves the scenario's layout by {force:?} (surge, sway, yaw): \
                 thrusters 1..4 must be front right, front left, rear right, rear left at 135, \
                 -135, 45 and -45 degrees"
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const NORMAL: [f64; MOTORS] = [1.0; MOTORS];

    fn only(f: impl FnOnce(&mut Inputs)) -> Inputs {
        let mut i = Inputs::default();
        f(&mut i);
        i
    }

    /// The factors per axis, and their signs at the PWM: forward runs the front pair in reverse and
    /// the rear pair forward (the BlueROV2's front thrusters face backwards).
    #[test]
    fn each_axis_drives_the_motors_with_the_vectored_frames_signs() {
        let cases: [(Inputs, [i32; MOTORS]); 4] = [
            (only(|i| i.forward = 0.5), [-1, -1, 1, 1, 0, 0]),
            (only(|i| i.lateral = 0.5), [1, -1, 1, -1, 0, 0]),
            (only(|i| i.yaw = 0.5), [1, -1, -1, 1, 0, 0]),
            (only(|i| i.throttle = 0.5), [0, 0, 0, 0, -1, -1]),
        ];
        for (inputs, signs) in cases {
            let t = mix(&inputs, &NORMAL, 0.0);
            for m in 0..MOTORS {
                assert_eq!(t[m], 0.5 * signs[m] as f64, "{inputs:?} motor {}", m + 1);
                let p = pwm(t[m]) as i32 - 1500;
                assert_eq!(p.signum(), signs[m], "{inputs:?} motor {} pwm", m + 1);
                if signs[m] != 0 {
                    assert_eq!(p.abs(), 200);
                }
            }
        }
        assert_eq!(mix(&Inputs::default(), &NORMAL, 1.0), [0.0; MOTORS]);
        assert_eq!(pwm(0.0), 1500);
        assert_eq!((pwm(1.0), pwm(-1.0), pwm(3.0)), (1900, 1100, 1900));
    }

    #[test]
    fn a_reversed_motor_inverts_only_its_own_thrust() {
        let mut dirs = NORMAL;
        dirs[2] = -1.0;
        let i = only(|i| i.forward = 0.4);
        let (n, r) = (mix(&i, &NORMAL, 0.0), mix(&i, &dirs, 0.0));
        for m in 0..MOTORS {
            assert_eq!(r[m], if m == 2 { -n[m] } else { n[m] }, "motor {}", m + 1);
        }
    }

    #[test]
    fn motors_saturate_one_by_one_and_the_throttle_limits_the_rear_pairs_forward_share() {
        // Full forward and full yaw: motors 1 and 3 cancel, 2 and 4 saturate.
        let t = mix(
            &only(|i| {
                i.forward = 1.0;
                i.yaw = 1.0
            }),
            &NORMAL,
            0.0,
        );
        assert_eq!(&t[..4], &[0.0, -1.0, 0.0, 1.0]);
        // Half throttle with the default coupling: forward is limited to 0.5 on the rear pair
        // going forward, untouched on the front pair.
        let t = mix(
            &only(|i| {
                i.forward = 0.8;
                i.throttle = 0.5
            }),
            &NORMAL,
            1.0,
        );
        assert_eq!(&t[..4], &[-0.8, -0.8, 0.5, 0.5]);
        let t = mix(
            &only(|i| {
                i.forward = -0.8;
                i.throttle = 0.5
            }),
            &NORMAL,
            1.0,
        );
        assert_eq!(&t[..4], &[0.5, 0.5, -0.8, -0.8]);
    }

    #[test]
    fn the_layout_check_accepts_the_bluerov2_and_refuses_a_swapped_thruster() {
        let column = |x: f64, y: f64, heading: f64| {
            let (s, c) = heading.to_radians().sin_cos();
            [c, s, x * s - y * c]
        };
        let mut layout = vec![
            column(0.156, 0.111, 135.0),
            column(0.156, -0.111, -135.0),
            column(-0.156, 0.111, 45.0),
            column(-0.156, -0.111, -45.0),
        ];
        check_layout(&layout).unwrap();
        layout.swap(0, 1);
        assert!(check_layout(&layout).is_err());
        assert!(check_layout(&layout[..3]).is_err());
    }
}
