//! The alpha-beta filter behind the rates: a constant-velocity predictor corrected by a fixed share
//! of each innovation (the steady state of a Kalman filter for that model). The rate it carries is a
//! smoothed estimate, not the raw difference of two noisy measurements.

#[derive(Clone, Copy, Debug)]
pub(crate) struct AlphaBeta {
    value: f64,
    rate: f64,
}

impl AlphaBeta {
    /// Starts at `value`, at rest.
    pub fn new(value: f64) -> Self {
        AlphaBeta { value, rate: 0.0 }
    }

    pub fn value(&self) -> f64 {
        self.value
    }

    pub fn rate(&self) -> f64 {
        self.rate
    }

    /// Where the value will be after `dt` seconds.
    pub fn predict(&self, dt: f64) -> f64 {
        self.value + self.rate * dt
    }

    /// Takes measurement `z` made `dt` seconds after the last one. With `dt = 0` (unknown) the value
    /// is corrected and the rate kept.
    pub fn update(&mut self, z: f64, dt: f64, alpha: f64, beta: f64) {
        let predicted = self.predict(dt);
        let innovation = z - predicted;
        self.value = predicted + alpha * innovation;
        if dt > 0.0 {
            self.rate += beta * innovation / dt;
        }
    }

    /// Advances `dt` seconds without a measurement.
    pub fn coast(&mut self, dt: f64) {
        self.value = self.predict(dt);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn converges_to_a_ramp_and_smooths_noise() {
        let mut f = AlphaBeta::new(0.0);
        let dt = 0.2;
        for k in 1..60 {
            // A ramp of 0.5 per second with +-0.01 alternating noise.
            let noise = if k % 2 == 0 { 0.01 } else { -0.01 };
            f.update(0.5 * k as f64 * dt + noise, dt, 0.6, 0.25);
        }
        assert!((f.rate() - 0.5).abs() < 0.05, "{}", f.rate());
        // The raw difference of two consecutive measurements would be off by 0.02 / 0.2 = 0.1.
    }
}
