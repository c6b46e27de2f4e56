//! Baxter and Bartlett's OLPOMDP, the online form of GPOMDP: the vanilla policy gradient baseline of
//! the paper's Fig. 5, on the same policy and transitions as NAC.
//!
//! Per transition: `z = beta z + grad log pi(u|x)`, then `K += alpha r z`. No critic: the reward itself
//! weighs the trace, which is why it needs a smaller step and more samples than NAC.

use crate::learner::{PolicyLearner, Transition};
use crate::policy::LinearGaussian;
use config::{Dof, GpomdpParams};
use nalgebra::SVector;

/// OLPOMDP's parameters for one DOF.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GpomdpConfig {
    /// Step size.
    pub alpha: f64,
    /// Discount of the eligibility trace (its bias-variance knob).
    pub beta: f64,
}

impl GpomdpConfig {
    /// The parameters `params` give the learner of `dof`.
    pub fn for_dof(params: &GpomdpParams, dof: Dof) -> Self {
        GpomdpConfig {
            alpha: *params.alpha.get(dof),
            beta: params.beta,
        }
    }
}

/// OLPOMDP on an `S`-dimensional state.
#[derive(Clone, Debug, PartialEq)]
pub struct Gpomdp<const S: usize> {
    config: GpomdpConfig,
    z: SVector<f64, S>,
    steps: u64,
    actor_updates: u64,
}

impl<const S: usize> Gpomdp<S> {
    /// A learner with an empty trace.
    pub fn new(config: GpomdpConfig) -> Self {
        Self::with_trace(config, SVector::zeros(), 0, 0)
    }

    /// A learner resuming from a saved trace and counters.
    pub fn with_trace(
        config: GpomdpConfig,
        z: SVector<f64, S>,
        steps: u64,
        actor_updates: u64,
    ) -> Self {
        Gpomdp {
            config,
            z,
            steps,
            actor_updates,
        }
    }

    /// One OLPOMDP step; the policy changes on every transition, so this always returns `true`.
    pub fn update(&mut self, policy: &mut LinearGaussian<S>, t: &Transition<S>) -> bool {
        let c = self.config;
        self.z.axpy(1.0, &policy.grad_log(&t.x, t.u), c.beta);
        policy.gain.axpy(c.alpha * t.reward, &self.z, 1.0);
        self.steps += 1;
        self.actor_updates += 1;
        true
    }

    /// The episode is over: the trace is cleared.
    pub fn end_episode(&mut self) {
        self.z = SVector::zeros();
    }

    /// The configuration.
    pub fn config(&self) -> &GpomdpConfig {
        &self.config
    }

    /// The eligibility trace.
    pub fn z(&self) -> &SVector<f64, S> {
        &self.z
    }

    /// Transitions learned from.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// Actor updates made (one per transition).
    pub fn actor_updates(&self) -> u64 {
        self.actor_updates
    }
}

impl<const S: usize> PolicyLearner<S> for Gpomdp<S> {
    fn update(&mut self, policy: &mut LinearGaussian<S>, transition: &Transition<S>) -> bool {
        Gpomdp::update(self, policy, transition)
    }
    fn end_episode(&mut self) {
        Gpomdp::end_episode(self)
    }
    fn steps(&self) -> u64 {
        Gpomdp::steps(self)
    }
    fn actor_updates(&self) -> u64 {
        Gpomdp::actor_updates(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testkit::{Scalar, run_episodes};
    use nalgebra::{Vector1, Vector2};

    #[test]
    fn update_is_olpomdp() {
        let mut l = Gpomdp::<2>::new(GpomdpConfig {
            alpha: 0.1,
            beta: 0.5,
        });
        let mut p = LinearGaussian::new(Vector2::new(0.2, 0.0), 0.1);
        let x = Vector2::new(1.0, 2.0);
        let g1 = p.grad_log(&x, 0.3);
        l.update(
            &mut p,
            &Transition {
                x,
                u: 0.3,
                reward: -2.0,
                next: Some(x),
            },
        );
        assert!((l.z() - g1).norm() < 1e-12);
        let k1 = Vector2::new(0.2, 0.0) - 0.2 * g1; // alpha r = 0.1 * -2
        assert!((p.gain - k1).norm() < 1e-12);
        let g2 = p.grad_log(&x, -0.1);
        l.update(
            &mut p,
            &Transition {
                x,
                u: -0.1,
                reward: -1.0,
                next: None,
            },
        );
        let z2 = 0.5 * g1 + g2;
        assert!((l.z() - z2).norm() < 1e-12);
        assert!((p.gain - (k1 - 0.1 * z2)).norm() < 1e-12); // alpha r = 0.1 * -1
        l.end_episode();
        assert_eq!(*l.z(), Vector2::zeros());
        assert_eq!((l.steps(), l.actor_updates()), (2, 2));
    }

    /// Sanity check of the baseline: on the scalar problem the returns rise and the gain moves towards
    /// the optimum (GPOMDP is too noisy to pin the optimum down in a short test).
    #[test]
    fn gpomdp_improves_the_gain_on_a_scalar_system() {
        let problem = Scalar::standard();
        let k_star = problem.optimal_gain();
        for seed in 0..3 {
            let mut l = Gpomdp::<1>::new(GpomdpConfig {
                alpha: problem.gpomdp_alpha,
                beta: problem.gpomdp_beta,
            });
            let mut p = LinearGaussian::new(Vector1::new(0.0), problem.sigma);
            let returns = run_episodes(&problem, &mut l, &mut p, problem.gpomdp_episodes, seed);
            let window = returns.len() / 10;
            let first = returns[..window].iter().sum::<f64>() / window as f64;
            let last = returns[returns.len() - window..].iter().sum::<f64>() / window as f64;
            let k = p.gain[0];
            assert!(
                last > first,
                "seed {seed}: mean return {first:.3} -> {last:.3}"
            );
            assert!(
                (k - k_star).abs() < 0.3 * k_star.abs(),
                "seed {seed}: K = {k:.3} should have moved from 0 most of the way to K* = {k_star:.3}"
            );
        }
    }
}
