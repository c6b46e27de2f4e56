//! The one rule for bad values, wherever a number crosses into the vehicle's control (a DOF command
//! before allocation, a setpoint before a thruster, a force before the model, an observation before a
//! learner): a value that is not finite becomes 0 (a broken computation must not run a thruster at
//! full power, as clamping an infinity would), and a finite value outside its range is clamped to it
//! (per DOF, per thruster, per observed quantity). Both are counted ([`Fixes`]); the process that
//! receives the value logs them.

/// What [`bounded`] did to a value.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fix {
    /// In range: unchanged.
    Kept,
    /// NaN or infinite: replaced by 0.
    NonFinite,
    /// Finite but out of range: clamped.
    Clamped,
}

/// `value` under the rule, within `[lo, hi]` (which must hold 0), and what was done to it.
pub fn bounded(value: f64, lo: f64, hi: f64) -> (f64, Fix) {
    if !value.is_finite() {
        (0.0, Fix::NonFinite)
    } else if value < lo {
        (lo, Fix::Clamped)
    } else if value > hi {
        (hi, Fix::Clamped)
    } else {
        (value, Fix::Kept)
    }
}

/// `value` under the rule within `[-limit, limit]`.
pub fn symmetric(value: f64, limit: f64) -> (f64, Fix) {
    bounded(value, -limit, limit)
}

/// A normalised force or a thruster setpoint under the rule, within [-1, 1].
pub fn unit(value: f64) -> (f64, Fix) {
    bounded(value, -1.0, 1.0)
}

/// How many values the rule changed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Fixes {
    pub non_finite: u64,
    pub clamped: u64,
}

impl Fixes {
    /// Counts one value's fix and returns the value.
    pub fn note(&mut self, (value, fix): (f64, Fix)) -> f64 {
        match fix {
            Fix::Kept => {}
            Fix::NonFinite => self.non_finite += 1,
            Fix::Clamped => self.clamped += 1,
        }
        value
    }

    /// Values changed.
    pub fn total(&self) -> u64 {
        self.non_finite + self.clamped
    }

    pub fn is_empty(&self) -> bool {
        self.total() == 0
    }

    /// Adds another count.
    pub fn add(&mut self, other: Fixes) {
        self.non_finite += other.non_finite;
        self.clamped += other.clamped;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn non_finite_is_zero_and_out_of_range_is_clamped() {
        assert_eq!(unit(0.3), (0.3, Fix::Kept));
        assert_eq!(unit(1.0), (1.0, Fix::Kept));
        assert_eq!(unit(1.7), (1.0, Fix::Clamped));
        assert_eq!(unit(-50.0), (-1.0, Fix::Clamped));
        assert_eq!(unit(f64::NAN), (0.0, Fix::NonFinite));
        assert_eq!(unit(f64::INFINITY), (0.0, Fix::NonFinite));
        assert_eq!(unit(f64::NEG_INFINITY), (0.0, Fix::NonFinite));
        assert_eq!(symmetric(0.7, 0.5), (0.5, Fix::Clamped));
        assert_eq!(bounded(-0.2, -0.1, 0.4), (-0.1, Fix::Clamped));
        let mut fixes = Fixes::default();
        let values: Vec<f64> = [0.5, f64::NAN, 3.0, -0.2]
            .into_iter()
            .map(|v| fixes.note(unit(v)))
            .collect();
        assert_eq!(values, vec![0.5, 0.0, 1.0, -0.2]);
        assert_eq!(
            fixes,
            Fixes {
                non_finite: 1,
                clamped: 1
            }
        );
        assert_eq!(fixes.total(), 2);
    }
}
