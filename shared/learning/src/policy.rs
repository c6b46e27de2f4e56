//! The actor: a linear Gaussian policy `u ~ N(Kx, sigma^2)` (paper, section III-C).
//!
//! Everything here is a handful of flops on stack values: the policy is evaluated on every control step.

use nalgebra::SVector;
use rand::Rng;
use rand_distr::StandardNormal;

/// A linear Gaussian policy over an `S`-dimensional state: `u ~ N(K x, sigma^2)`.
///
/// The sampled action is unbounded; clipping to the actuator range is the caller's business, and the
/// gradient must be taken at the *sampled* action (that is what the likelihood ratio is about).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LinearGaussian<const S: usize> {
    /// The gain `K`: the mean action is `K . x`.
    pub gain: SVector<f64, S>,
    /// Standard deviation of the exploration noise (fixed, not learned).
    pub sigma: f64,
}

impl<const S: usize> LinearGaussian<S> {
    /// A policy with gain `gain` and exploration `sigma` (> 0).
    pub fn new(gain: SVector<f64, S>, sigma: f64) -> Self {
        debug_assert!(
            sigma > 0.0 && sigma.is_finite(),
            "sigma must be finite and > 0, got {sigma}"
        );
        LinearGaussian { gain, sigma }
    }

    /// The mean action `K x`.
    #[inline]
    pub fn mean(&self, x: &SVector<f64, S>) -> f64 {
        self.gain.dot(x)
    }

    /// Draws an action from `N(K x, sigma^2)`: the sampled, unclipped action.
    #[inline]
    pub fn sample<R: Rng + ?Sized>(&self, x: &SVector<f64, S>, rng: &mut R) -> f64 {
        let n: f64 = rng.sample(StandardNormal);
        self.mean(x) + self.sigma * n
    }

    /// The score `d/dK log pi(u | x) = (u - K x) x / sigma^2`.
    #[inline]
    pub fn grad_log(&self, x: &SVector<f64, S>, u: f64) -> SVector<f64, S> {
        x * ((u - self.mean(x)) / (self.sigma * self.sigma))
    }

    /// `log pi(u | x)`, the log density of `u` (used by tests and diagnostics).
    pub fn log_prob(&self, x: &SVector<f64, S>, u: f64) -> f64 {
        let e = (u - self.mean(x)) / self.sigma;
        -0.5 * e * e - self.sigma.ln() - 0.5 * (2.0 * std::f64::consts::PI).ln()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector2;
    use rand::SeedableRng;
    use rand::rngs::StdRng;

    #[test]
    fn grad_log_matches_finite_differences_of_log_prob() {
        let p = LinearGaussian::new(Vector2::new(-0.7, 0.3), 0.1);
        let x = Vector2::new(0.2, -0.4);
        let u = 0.05;
        let g = p.grad_log(&x, u);
        let h = 1e-6;
        for i in 0..2 {
            let mut plus = p;
            let mut minus = p;
            plus.gain[i] += h;
            minus.gain[i] -= h;
            let fd = (plus.log_prob(&x, u) - minus.log_prob(&x, u)) / (2.0 * h);
            assert!(
                (fd - g[i]).abs() < 1e-5 * (1.0 + g[i].abs()),
                "component {i}: fd {fd}, analytic {}",
                g[i]
            );
        }
    }

    #[test]
    fn samples_have_the_policy_mean_and_spread() {
        let p = LinearGaussian::new(Vector2::new(1.0, -2.0), 0.1);
        let x = Vector2::new(0.3, 0.1);
        let mut rng = StdRng::seed_from_u64(7);
        let n = 100_000;
        let samples: Vec<f64> = (0..n).map(|_| p.sample(&x, &mut rng)).collect();
        let mean = samples.iter().sum::<f64>() / n as f64;
        let var = samples.iter().map(|u| (u - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
        assert!((mean - p.mean(&x)).abs() < 0.002, "mean {mean}");
        assert!((var.sqrt() - 0.1).abs() < 0.002, "std {}", var.sqrt());
    }
}
