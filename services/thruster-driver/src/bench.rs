//! The props-off bench check of a BlueROV2 under ArduSub (`bench-check`, `scripts/bench-check`):
//! each axis the stack commands (surge, sway, yaw) is driven in turn at low thrust through the
//! vehicle's own path (setpoints to the thruster driver, MANUAL_CONTROL to ArduSub), and the sign of
//! each thruster's pulse, read back from SERVO_OUTPUT_RAW, is held against the vectored frame's.
//! Plain data and decisions here; the binary publishes and reads.
//!
//! The expected signs are ArduSub's mixer factors for `SUB_FRAME_VECTORED` (`AP_Motors6DOF.cpp`),
//! with every `MOT_n_DIRECTION` at 1, its default: motor 1 front right, 2 front left, 3 rear right,
//! 4 rear left, 5 and 6 vertical. A thruster that turns the other way from what its factor says
//! (wired or configured reversed) shows as the wrong sign on every axis that moves it. On a vehicle
//! whose propellers make a reversed direction right for some thrusters, name them (`reversed`).
//! Heave is not checked: the stack never commands it (its MANUAL_CONTROL holds z at neutral), so
//! the vertical thrusters must stay at rest while each horizontal axis is driven.

use std::fmt;

/// The axes the stack commands, in the order they are driven.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Axis {
    Surge,
    Sway,
    Yaw,
}

impl Axis {
    pub const ALL: [Axis; 3] = [Axis::Surge, Axis::Sway, Axis::Yaw];

    pub fn name(self) -> &'static str {
        match self {
            Axis::Surge => "surge",
            Axis::Sway => "sway",
            Axis::Yaw => "yaw",
        }
    }
}

/// The vectored frame's motors: ArduSub's numbering (SERVO_OUTPUT_RAW's servo1..servo6).
pub const MOTORS: usize = 6;

/// Where each motor sits.
pub const MOTOR_NAMES: [&str; MOTORS] = [
    "front right",
    "front left",
    "rear right",
    "rear left",
    "vertical right",
    "vertical left",
];

/// The sign each motor's thrust takes for a positive command on an axis (forward, to starboard,
/// clockwise seen from above): ArduSub's factors of `SUB_FRAME_VECTORED`, forward, lateral and yaw
/// columns.
pub fn expected(axis: Axis) -> [i8; MOTORS] {
    match axis {
        Axis::Surge => [-1, -1, 1, 1, 0, 0],
        Axis::Sway => [1, -1, 1, -1, 0, 0],
        Axis::Yaw => [1, -1, -1, 1, 0, 0],
    }
}

/// A pulse within this of 1500 us counts as at rest: ArduSub's own output for a neutral stick is
/// exactly 1500, and a low-thrust command moves a thruster by tens of microseconds.
pub const REST_US: u16 = 10;

/// The sign a pulse shows.
pub fn sign(pwm_us: u16) -> i8 {
    let d = i32::from(pwm_us) - 1500;
    if d.unsigned_abs() <= u32::from(REST_US) {
        0
    } else {
        d.signum() as i8
    }
}

/// One motor on one axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Reading {
    pub axis: Axis,
    /// 0-based.
    pub motor: usize,
    pub expected: i8,
    /// The median pulse over the hold; None when no SERVO_OUTPUT_RAW carried it.
    pub pwm_us: Option<u16>,
}

impl Reading {
    pub fn seen(&self) -> Option<i8> {
        self.pwm_us.map(sign)
    }

    pub fn right(&self) -> bool {
        self.seen() == Some(self.expected)
    }
}

fn word(sign: i8) -> &'static str {
    match sign {
        1 => "forward (+)",
        -1 => "reverse (-)",
        _ => "at rest",
    }
}

impl fmt::Display for Reading {
    /// What went wrong, naming the thruster and the axis.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let m = self.motor;
        match self.pwm_us {
            None => write!(
                f,
                "thruster {} ({}) on {}: no SERVO_OUTPUT_RAW carried it",
                m + 1,
                MOTOR_NAMES[m],
                self.axis.name()
            ),
            Some(pwm) => write!(
                f,
                "thruster {} ({}) on {}: expected {}, saw {} ({pwm} us)",
                m + 1,
                MOTOR_NAMES[m],
                self.axis.name(),
                word(self.expected),
                word(sign(pwm))
            ),
        }
    }
}

/// Judges one axis: `pwm[m]` the median pulse of motor m while the axis was driven with a positive
/// command; `reversed[m]` a motor meant to run reversed (its expected sign flipped).
pub fn judge(axis: Axis, pwm: &[Option<u16>; MOTORS], reversed: &[bool; MOTORS]) -> Vec<Reading> {
    let want = expected(axis);
    (0..MOTORS)
        .map(|m| Reading {
            axis,
            motor: m,
            expected: if reversed[m] { -want[m] } else { want[m] },
            pwm_us: pwm[m],
        })
        .collect()
}

/// The median of pulses (the lower middle one of an even count); None for none.
pub fn median(mut v: Vec<u16>) -> Option<u16> {
    v.sort_unstable();
    v.get(v.len().saturating_sub(1) / 2).copied()
}

/// The table of what was seen: a row per axis, a column per motor.
pub fn table(readings: &[Reading]) -> String {
    let mut out = String::from("axis   ");
    for m in 0..MOTORS {
        out.push_str(&format!(" | {:>13}", format!("{} {}", m + 1, short(m))));
    }
    out.push('\n');
    for axis in Axis::ALL {
        out.push_str(&format!("{:<7}", axis.name()));
        for r in readings.iter().filter(|r| r.axis == axis) {
            let cell = match r.pwm_us {
                None => "none".to_string(),
                Some(p) => format!(
                    "{p} {}{}",
                    sign_char(sign(p)),
                    if r.right() { "" } else { " WRONG" }
                ),
            };
            out.push_str(&format!(" | {cell:>13}"));
        }
        out.push('\n');
    }
    out
}

fn short(m: usize) -> &'static str {
    ["FR", "FL", "RR", "RL", "VR", "VL"][m]
}

fn sign_char(s: i8) -> char {
    match s {
        1 => '+',
        -1 => '-',
        _ => '0',
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pulses(signs: [i8; MOTORS]) -> [Option<u16>; MOTORS] {
        signs.map(|s| Some((1500 + 80 * i32::from(s)) as u16))
    }

    /// The expected signs are the vectored frame's geometry: forward pushes the rear pair forward
    /// and the front pair back (their thrust points the other way), starboard and clockwise likewise.
    #[test]
    fn each_axis_is_right_with_the_frames_signs_and_wrong_with_one_reversed() {
        let none = [false; MOTORS];
        for axis in Axis::ALL {
            let r = judge(axis, &pulses(expected(axis)), &none);
            assert!(r.iter().all(Reading::right), "{axis:?}: {r:?}");
            let mut flipped = expected(axis);
            flipped[2] = -flipped[2];
            let r = judge(axis, &pulses(flipped), &none);
            let wrong: Vec<_> = r.iter().filter(|r| !r.right()).collect();
            assert_eq!(wrong.len(), 1, "{axis:?}");
            assert_eq!(wrong[0].motor, 2);
            let said = wrong[0].to_string();
            assert!(
                said.starts_with(&format!("thruster 3 (rear right) on {}", axis.name())),
                "{said}"
            );
        }
        // A thruster meant to run reversed is right reversed.
        let mut reversed = none;
        reversed[2] = true;
        let mut flipped = expected(Axis::Surge);
        flipped[2] = -flipped[2];
        assert!(
            judge(Axis::Surge, &pulses(flipped), &reversed)
                .iter()
                .all(Reading::right)
        );
    }

    #[test]
    fn a_pulse_near_1500_is_at_rest_and_a_missing_one_is_wrong() {
        assert_eq!((sign(1500), sign(1510), sign(1490)), (0, 0, 0));
        assert_eq!((sign(1511), sign(1489)), (1, -1));
        let mut p = pulses(expected(Axis::Yaw));
        p[4] = Some(1600);
        p[0] = None;
        let r = judge(Axis::Yaw, &p, &[false; MOTORS]);
        assert!(!r[0].right() && !r[4].right() && r[1].right());
        assert!(r[0].to_string().contains("no SERVO_OUTPUT_RAW"));
        assert!(
            r[4].to_string()
                .contains("expected at rest, saw forward (+)")
        );
        let t = table(&r);
        assert!(t.contains("none") && t.contains("1600 + WRONG"), "{t}");
    }

    #[test]
    fn median_of_pulses() {
        assert_eq!(median(vec![]), None);
        assert_eq!(median(vec![1580, 1420, 1500]), Some(1500));
        assert_eq!(median(vec![1, 2, 3, 4]), Some(2));
    }
}
