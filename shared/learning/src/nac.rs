//! The Natural Actor-Critic with LSTD-Q(lambda): the paper's Algorithm 1, step by step.
//!
//! The critic fits `Q(x, u) ~ phi(x)'v + grad log pi(u|x)'w` by least-squares temporal differences
//! with eligibility traces; with this compatible advantage term, `w` is the natural policy gradient.
//! The actor moves along `w` only when two consecutive estimates agree in direction, and the critic's
//! statistics are then partly forgotten, because they were gathered under the old policy.
//!
//! Sizes are compile-time constants (`S` state dimensions, `N` unknowns), so a step is a few hundred
//! flops on stack values and never allocates: the trainer runs millions of steps.
//!
//! **Regularisation.** `A` is singular at first (rank one after one transition) and not symmetric.
//! The critic solves `A [v; w] = b` as a Tikhonov least-squares problem on column-equilibrated
//! unknowns, `min |A D y - b|^2 + mu^2 |y|^2`, `[v; w] = D y`, where `D` scales `A`'s columns to unit
//! norm and `mu^2 = ridge^2` per non-zero column (`NacParams::ridge`, 1e-6). Its normal matrix is
//! symmetric positive definite for any `mu > 0`, so the Cholesky factorisation never meets a zero pivot
//! (a shifted `A + mu I` can be singular: `A` may have an eigenvalue near `-mu`). The solution is
//! unchanged when `A` and `b` are scaled together (forgetting, the reward's units), and its bias is
//! `O(ridge^2)` when `A` is well conditioned.
//!
//! **Damping.** Where a state component is barely excited (the yaw rate never exceeds 0.08 rad/s in
//! a box of 1 rad/s), the score's entry for its gain is tiny and a few samples "explain" the advantage
//! with a huge `w` along it: the actor would leap on noise into an unstable gain. `NacParams::damping`
//! adds `damping * m` to the diagonal of A's natural-gradient block, `m` the transitions the
//! statistics hold (forgotten with them, so the solution stays invariant to forgetting): the
//! Levenberg-Marquardt damping of natural-gradient methods, a prior of "no change" that the data
//! override where they carry information. It leaves the critic's value weights unbiased.
//!
//! **The angle test.** `w_{t+1}` is compared with `w_{t-tau}`, the estimate `tau + 1` steps earlier,
//! whether or not those steps updated the actor (`NacParams::tau`; 0 compares consecutive
//! estimates). Consecutive estimates come from nearly the same statistics and agree even while both
//! are noise; with a lag they come from different data, so the actor moves only once the gradient
//! is consistent, and while it waits no forgetting happens and the statistics keep growing. Until
//! there is an estimate `tau + 1` steps old, and for a zero `w` (no direction), there is no update.
//! With one gain (`S = 1`) the test reduces to "same sign".

use crate::learner::{PolicyLearner, Transition};
use crate::policy::LinearGaussian;
use config::{Dof, MAX_ANGLE_LAG, NacParams};
use nalgebra::{SMatrix, SVector};

/// Number of critic basis functions for an `s`-dimensional state: every product `x_i x_j` (i <= j)
/// and a constant. For `s = 2` that is `[x1^2, x1 x2, x2^2, 1]`; for `s = 1`, `[x^2, 1]`.
pub const fn basis_len(s: usize) -> usize {
    s * (s + 1) / 2 + 1
}

/// Number of unknowns `[v; w]` of NAC on an `s`-dimensional state with a linear policy.
pub const fn unknowns(s: usize) -> usize {
    basis_len(s) + s
}

/// Relative ridge used when the configured one is too small to make the critic's normal matrix
/// positive definite in floating point (e.g. `ridge = 0` while A is still singular).
const RIDGE_FLOOR: f64 = 1e-7;

/// NAC's parameters for one DOF (the per-DOF learning rate resolved from [`NacParams`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NacConfig {
    /// Actor learning rate.
    pub alpha: f64,
    /// Forgetting factor applied to `z`, `A`, `b` after each actor update.
    pub beta: f64,
    /// Discount factor.
    pub gamma: f64,
    /// Eligibility rate.
    pub lambda: f64,
    /// Largest angle (degrees) between `w_{t+1}` and `w_{t-tau}` that allows an actor update.
    pub epsilon_deg: f64,
    /// The angle test's lag (see the module docs); at most `MAX_ANGLE_LAG - 1`.
    pub tau: usize,
    /// Damping of the natural-gradient block per transition of statistics (see the module docs).
    pub damping: f64,
    /// Tikhonov regularisation of the critic's solve, relative to the scale of A's columns
    /// (see the module docs).
    pub ridge: f64,
}

impl NacConfig {
    /// The parameters `params` give the learner of `dof`.
    pub fn for_dof(params: &NacParams, dof: Dof) -> Self {
        NacConfig {
            alpha: *params.alpha.get(dof),
            beta: params.beta,
            gamma: params.gamma,
            lambda: params.lambda,
            epsilon_deg: params.epsilon_deg,
            tau: (params.tau as usize).min(MAX_ANGLE_LAG - 1),
            damping: params.damping,
            ridge: params.ridge,
        }
    }
}

/// The learner's state, for checkpoints and statistics: everything but the configuration.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NacStatistics<const S: usize, const N: usize> {
    /// LSTD's `A` (not symmetric).
    pub a: SMatrix<f64, N, N>,
    /// LSTD's `b`.
    pub b: SVector<f64, N>,
    /// The eligibility trace.
    pub z: SVector<f64, N>,
    /// The last critic solution `[v; w]`.
    pub theta: SVector<f64, N>,
    /// The natural gradients of the last steps, for the angle test.
    pub w_history: GradientHistory<S>,
    /// How many transitions the statistics hold, forgotten like them (it scales the damping).
    pub mass: f64,
    /// Transitions learned from.
    pub steps: u64,
    /// Actor updates made.
    pub actor_updates: u64,
}

impl<const S: usize, const N: usize> NacStatistics<S, N> {
    /// The state of a learner that has seen nothing.
    pub fn zeros() -> Self {
        NacStatistics {
            a: SMatrix::zeros(),
            b: SVector::zeros(),
            z: SVector::zeros(),
            theta: SVector::zeros(),
            w_history: GradientHistory::new(),
            mass: 0.0,
            steps: 0,
            actor_updates: 0,
        }
    }
}

/// The last [`MAX_ANGLE_LAG`] natural-gradient estimates, newest last (a ring: no allocation).
/// Two histories are equal when they hold the same estimates in the same order.
#[derive(Clone, Copy, Debug)]
pub struct GradientHistory<const S: usize> {
    ring: [SVector<f64, S>; MAX_ANGLE_LAG],
    /// Where the next estimate goes.
    head: usize,
    len: usize,
}

impl<const S: usize> GradientHistory<S> {
    /// No estimates yet.
    pub fn new() -> Self {
        GradientHistory {
            ring: [SVector::zeros(); MAX_ANGLE_LAG],
            head: 0,
            len: 0,
        }
    }

    /// A history holding `estimates`, oldest first (only the newest [`MAX_ANGLE_LAG`] are kept).
    pub fn from_oldest_first(estimates: impl IntoIterator<Item = SVector<f64, S>>) -> Self {
        let mut h = Self::new();
        for w in estimates {
            h.push(w);
        }
        h
    }

    /// Records the newest estimate, dropping the oldest when full.
    pub fn push(&mut self, w: SVector<f64, S>) {
        self.ring[self.head] = w;
        self.head = (self.head + 1) % MAX_ANGLE_LAG;
        self.len = (self.len + 1).min(MAX_ANGLE_LAG);
    }

    /// The estimate `steps` steps back: 1 is the newest.
    pub fn back(&self, steps: usize) -> Option<SVector<f64, S>> {
        (steps >= 1 && steps <= self.len)
            .then(|| self.ring[(self.head + MAX_ANGLE_LAG - steps) % MAX_ANGLE_LAG])
    }

    /// Number of estimates held.
    pub fn len(&self) -> usize {
        self.len
    }

    /// No estimates yet.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The estimates, oldest first.
    pub fn oldest_first(&self) -> impl Iterator<Item = SVector<f64, S>> + '_ {
        (1..=self.len).rev().filter_map(|k| self.back(k))
    }
}

impl<const S: usize> PartialEq for GradientHistory<S> {
    fn eq(&self, other: &Self) -> bool {
        self.len == other.len && self.oldest_first().eq(other.oldest_first())
    }
}

impl<const S: usize> Default for GradientHistory<S> {
    fn default() -> Self {
        Self::new()
    }
}

/// NAC with LSTD-Q(lambda) on an `S`-dimensional state; `N` must be [`unknowns`]`(S)`
/// (checked at compile time): `Nac<2, 6>` for the cable task, `Nac<1, 3>` for a scalar system.
///
/// The unknowns are ordered `[v; w]`: `v` weighs the critic basis (see [`basis_len`]), `w` is the
/// natural gradient, one entry per policy gain.
#[derive(Clone, Debug, PartialEq)]
pub struct Nac<const S: usize, const N: usize> {
    config: NacConfig,
    /// `cos(epsilon)`: the angle test compares cosines, which avoids an `acos` per step.
    cos_epsilon: f64,
    stats: NacStatistics<S, N>,
}

impl<const S: usize, const N: usize> Nac<S, N> {
    /// Evaluated (and so checked) when a `Nac<S, N>` is built: a wrong `N` does not compile.
    const SHAPE_OK: () = assert!(
        N == unknowns(S) && S > 0,
        "Nac<S, N> needs N = S(S+1)/2 + 1 + S (critic basis + one natural-gradient entry per gain)"
    );

    /// Number of critic basis functions (the length of `v`).
    pub const BASIS_LEN: usize = basis_len(S);

    /// A learner that has seen nothing (`z = A = b = 0`, paper's initialisation).
    pub fn new(config: NacConfig) -> Self {
        Self::with_statistics(config, NacStatistics::zeros())
    }

    /// A learner resuming from saved statistics.
    pub fn with_statistics(config: NacConfig, stats: NacStatistics<S, N>) -> Self {
        #[allow(clippy::let_unit_value)]
        let () = Self::SHAPE_OK;
        Nac {
            cos_epsilon: config.epsilon_deg.to_radians().cos(),
            config,
            stats,
        }
    }

    /// One iteration of Algorithm 1 for `transition`; returns `true` when the actor was updated.
    pub fn update(&mut self, policy: &mut LinearGaussian<S>, t: &Transition<S>) -> bool {
        let c = self.config;
        let s = &mut self.stats;

        // phi_hat = [phi(x); grad log pi(u|x)], with the score at the sampled action.
        let mut phi_hat = critic_features::<S, N>(&t.x);
        phi_hat
            .fixed_rows_mut::<S>(N - S)
            .copy_from(&policy.grad_log(&t.x, t.u));
        // d = phi_hat - gamma phi_tilde, phi_tilde = [phi(x'); 0]; an absorbing end has phi_tilde = 0.
        let mut d = phi_hat;
        if let Some(next) = &t.next {
            d.axpy(-c.gamma, &critic_features::<S, N>(next), 1.0);
        }

        s.z.axpy(1.0, &phi_hat, c.lambda);
        s.a.ger(1.0, &s.z, &d, 1.0);
        s.b.axpy(t.reward, &s.z, 1.0);
        s.steps += 1;
        s.mass += 1.0;

        // Without a solution (no data yet, or statistics poisoned by a non-finite input) there is no
        // new gradient: keep the previous one and do not update, or a stale w would pass its own test.
        let solution = if c.damping > 0.0 {
            let mut damped = s.a;
            for i in N - S..N {
                damped[(i, i)] += c.damping * s.mass;
            }
            solve_regularised(&damped, &s.b, c.ridge)
        } else {
            solve_regularised(&s.a, &s.b, c.ridge)
        };
        let Some(theta) = solution else {
            return false;
        };
        s.theta = theta;
        let w: SVector<f64, S> = s.theta.fixed_rows::<S>(N - S).into_owned();

        // The angle test against w_{t-tau}; without an estimate that old there is no update.
        let before = s.w_history.back(c.tau + 1).unwrap_or_else(SVector::zeros);
        let (nw, np) = (w.norm(), before.norm());
        let agree =
            nw > 0.0 && np > 0.0 && nw.is_finite() && w.dot(&before) >= self.cos_epsilon * nw * np;
        s.w_history.push(w);
        if !agree {
            return false;
        }
        policy.gain.axpy(c.alpha, &w, 1.0);
        s.z *= c.beta;
        s.a *= c.beta;
        s.b *= c.beta;
        s.mass *= c.beta;
        s.actor_updates += 1;
        true
    }

    /// The episode is over: the trace is cleared so credit does not flow across the reset;
    /// `A` and `b` persist.
    pub fn end_episode(&mut self) {
        self.stats.z = SVector::zeros();
    }

    /// Drops the statistics (`z = A = b = 0`, no gradient history), keeping the counters: the
    /// learner starts afresh from the policy it is given next.
    pub fn forget(&mut self) {
        let (steps, actor_updates) = (self.stats.steps, self.stats.actor_updates);
        self.stats = NacStatistics::zeros();
        self.stats.steps = steps;
        self.stats.actor_updates = actor_updates;
    }

    /// Sets the eligibility rate from now on (step two's, [`config::StepTwoParams`]); the trace
    /// so far stays.
    pub fn set_lambda(&mut self, lambda: f64) {
        self.config.lambda = lambda;
    }

    /// The configuration.
    pub fn config(&self) -> &NacConfig {
        &self.config
    }

    /// The whole learner state (for checkpoints).
    pub fn statistics(&self) -> &NacStatistics<S, N> {
        &self.stats
    }

    /// LSTD's `A`.
    pub fn a(&self) -> &SMatrix<f64, N, N> {
        &self.stats.a
    }

    /// LSTD's `b`.
    pub fn b(&self) -> &SVector<f64, N> {
        &self.stats.b
    }

    /// The eligibility trace `z`.
    pub fn z(&self) -> &SVector<f64, N> {
        &self.stats.z
    }

    /// The last critic solution `[v; w]`.
    pub fn theta(&self) -> &SVector<f64, N> {
        &self.stats.theta
    }

    /// The critic's value weights `v` (one per basis function).
    pub fn v(&self) -> &[f64] {
        &self.stats.theta.as_slice()[..N - S]
    }

    /// The last natural gradient estimate `w`.
    pub fn w(&self) -> SVector<f64, S> {
        self.stats.theta.fixed_rows::<S>(N - S).into_owned()
    }

    /// The critic's value estimate `V(x) = phi(x)'v`.
    pub fn value(&self, x: &SVector<f64, S>) -> f64 {
        critic_features::<S, N>(x).dot(&self.stats.theta)
    }

    /// Transitions learned from.
    pub fn steps(&self) -> u64 {
        self.stats.steps
    }

    /// Actor updates made.
    pub fn actor_updates(&self) -> u64 {
        self.stats.actor_updates
    }
}

impl<const S: usize, const N: usize> PolicyLearner<S> for Nac<S, N> {
    fn update(&mut self, policy: &mut LinearGaussian<S>, transition: &Transition<S>) -> bool {
        Nac::update(self, policy, transition)
    }
    fn end_episode(&mut self) {
        Nac::end_episode(self)
    }
    fn steps(&self) -> u64 {
        Nac::steps(self)
    }
    fn actor_updates(&self) -> u64 {
        Nac::actor_updates(self)
    }
}

/// `[phi(x); 0]`: the critic basis of `x` in the first [`basis_len`]`(S)` entries, zeros after
/// (`N` must be at least `basis_len(S)`).
pub fn critic_features<const S: usize, const N: usize>(x: &SVector<f64, S>) -> SVector<f64, N> {
    let mut out = SVector::<f64, N>::zeros();
    let mut k = 0;
    for i in 0..S {
        for j in i..S {
            out[k] = x[i] * x[j];
            k += 1;
        }
    }
    out[k] = 1.0;
    out
}

/// Solves `A theta = b` for the critic, regularised so that it never divides by a singular matrix.
///
/// Tikhonov in its least-squares form, on column-equilibrated unknowns: with `D` scaling each column of
/// `A` to unit norm, `y = argmin |A D y - b|^2 + mu^2 |y|^2` and `theta = D y`, i.e.
/// `(D A'A D + mu^2 I) y = D A'b`.
///
/// - `A` is not symmetric (LSTD), and a shifted `A + mu I` can itself be singular when A has an
///   eigenvalue near `-mu`; `D A'A D + mu^2 I` is symmetric positive definite for any `mu > 0`, so its
///   Cholesky factorisation cannot meet a zero pivot.
/// - The features differ in scale by orders of magnitude (`x^2`, the constant, the score); equilibrating
///   keeps the normal matrix as well conditioned as the data allow and makes the ridge relative to
///   each unknown's own scale. The equilibrated matrix has unit-norm columns, so
///   `mu = ridge sqrt(non-zero columns)` is `ridge` times its Frobenius norm, and the condition number is at most about `1 + 1/ridge^2`.
/// - Scaling `A` and `b` together (the forgetting step) leaves the solution unchanged, as does the
///   reward's scale. When A is well conditioned the bias is `O(ridge^2)`.
///
/// A column of zeros (an unknown the data have not touched yet) gets 0. Returns `None` when there is
/// nothing to solve (`A = 0`) or the statistics are not finite.
///
/// Hand-rolled on arrays rather than `nalgebra`'s generic decompositions: this runs on every step and
/// is most of the step's cost.
fn solve_regularised<const N: usize>(
    a: &SMatrix<f64, N, N>,
    b: &SVector<f64, N>,
    ridge: f64,
) -> Option<SVector<f64, N>> {
    // Columns as fixed-size arrays: with the bounds known the loops unroll and vectorise.
    let cols: [[f64; N]; N] = std::array::from_fn(|j| std::array::from_fn(|k| a[(k, j)]));
    let dot = |u: &[f64; N], v: &[f64; N]| {
        let mut s = 0.0;
        for k in 0..N {
            s += u[k] * v[k];
        }
        s
    };

    // The normal matrix A'A (lower triangle) and A'b.
    let mut normal = [[0.0; N]; N];
    let mut rhs = [0.0; N];
    let bv: [f64; N] = (*b).into();
    for i in 0..N {
        for j in 0..=i {
            normal[i][j] = dot(&cols[i], &cols[j]);
        }
        rhs[i] = dot(&cols[i], &bv);
    }
    // Column scales from its diagonal.
    let mut scale = [1.0; N];
    let mut nonzero = 0usize;
    for i in 0..N {
        let n2 = normal[i][i];
        if !n2.is_finite() || !rhs[i].is_finite() {
            return None;
        }
        if n2 > 0.0 {
            nonzero += 1;
            scale[i] = 1.0 / n2.sqrt();
        }
    }
    if nonzero == 0 {
        return None;
    }
    for i in 0..N {
        for j in 0..=i {
            normal[i][j] *= scale[i] * scale[j];
        }
        rhs[i] *= scale[i];
    }
    // The floor only matters for a configured ridge too small for floating point (0 included).
    for relative in [ridge, ridge.max(RIDGE_FLOOR)] {
        let mu2 = relative * relative * nonzero as f64;
        if let Some(y) = cholesky_solve(&normal, mu2, &rhs) {
            let mut theta = SVector::<f64, N>::zeros();
            for i in 0..N {
                theta[i] = y[i] * scale[i];
            }
            if theta.iter().all(|t| t.is_finite()) {
                return Some(theta);
            }
        }
    }
    None
}

/// Solves `(M + shift I) y = rhs` for symmetric `M` given by its lower triangle, by Cholesky;
/// `None` when a pivot is not positive (the matrix is not numerically positive definite).
// Index loops keep the textbook's subscripts visible; iterators would hide which triangle is read.
#[allow(clippy::needless_range_loop)]
fn cholesky_solve<const N: usize>(
    m: &[[f64; N]; N],
    shift: f64,
    rhs: &[f64; N],
) -> Option<[f64; N]> {
    // The factorisation is a chain of dependent operations; multiplying by the pivots' reciprocals
    // keeps divisions (slow, unpipelined) off most of it.
    let mut l = [[0.0; N]; N];
    let mut inv = [0.0; N];
    for i in 0..N {
        for j in 0..=i {
            let mut s = m[i][j];
            for k in 0..j {
                s -= l[i][k] * l[j][k];
            }
            if i == j {
                s += shift;
                if !(s > 0.0 && s.is_finite()) {
                    return None;
                }
                l[i][i] = s.sqrt();
                inv[i] = 1.0 / l[i][i];
            } else {
                l[i][j] = s * inv[j];
            }
        }
    }
    // L y' = rhs, then L' y = y'.
    let mut y = *rhs;
    for i in 0..N {
        for k in 0..i {
            y[i] -= l[i][k] * y[k];
        }
        y[i] *= inv[i];
    }
    for i in (0..N).rev() {
        for k in i + 1..N {
            y[i] -= l[k][i] * y[k];
        }
        y[i] *= inv[i];
    }
    Some(y)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testkit::{Scalar, run_episodes};
    use nalgebra::{Matrix2, SVector, Vector1, Vector2};

    fn config() -> NacConfig {
        NacConfig::for_dof(&NacParams::default(), Dof::Sway)
    }

    #[test]
    fn basis_is_the_papers() {
        let f: SVector<f64, 6> = critic_features::<2, 6>(&Vector2::new(2.0, 3.0));
        assert_eq!(f.as_slice(), &[4.0, 6.0, 9.0, 1.0, 0.0, 0.0]);
        let f: SVector<f64, 3> = critic_features::<1, 3>(&Vector1::new(-3.0));
        assert_eq!(f.as_slice(), &[9.0, 1.0, 0.0]);
        assert_eq!(unknowns(2), 6);
        assert_eq!(unknowns(1), 3);
    }

    #[test]
    fn first_step_builds_the_statistics_of_algorithm_1_and_does_not_update() {
        let mut nac = Nac::<2, 6>::new(config());
        let mut policy = LinearGaussian::new(Vector2::new(-0.5, -0.1), 0.1);
        let x = Vector2::new(0.2, -0.1);
        let next = Vector2::new(0.15, -0.05);
        let (u, r) = (-0.02, -0.3);
        let updated = nac.update(
            &mut policy,
            &Transition {
                x,
                u,
                reward: r,
                next: Some(next),
            },
        );
        assert!(!updated, "no previous gradient: the angle test cannot pass");
        assert_eq!(policy.gain, Vector2::new(-0.5, -0.1));

        let g = policy.grad_log(&x, u);
        let phi_hat = SVector::<f64, 6>::from_column_slice(&[0.04, -0.02, 0.01, 1.0, g[0], g[1]]);
        let phi_tilde =
            SVector::<f64, 6>::from_column_slice(&[0.0225, -0.0075, 0.0025, 1.0, 0.0, 0.0]);
        assert!((nac.z() - phi_hat).norm() < 1e-15);
        let a = phi_hat * (phi_hat - 0.95 * phi_tilde).transpose();
        assert!((nac.a() - a).norm() < 1e-12);
        assert!((nac.b() - phi_hat * r).norm() < 1e-15);

        // Second step: z = lambda z + phi_hat.
        let x2 = next;
        let u2 = 0.01;
        nac.update(
            &mut policy,
            &Transition {
                x: x2,
                u: u2,
                reward: r,
                next: None,
            },
        );
        let g2 = policy.grad_log(&x2, u2);
        let phi_hat2 =
            SVector::<f64, 6>::from_column_slice(&[0.0225, -0.0075, 0.0025, 1.0, g2[0], g2[1]]);
        let z = 0.8 * phi_hat + phi_hat2;
        assert!((nac.z() - z).norm() < 1e-12);
        let a2 = a + z * phi_hat2.transpose(); // absorbing: no -gamma phi_tilde term
        assert!((nac.a() - a2).norm() < 1e-12);
    }

    #[test]
    fn actor_moves_along_w_only_when_consecutive_gradients_agree_then_forgets() {
        // Two updates with the same data give the same direction of w: the second must update the actor.
        let mut nac = Nac::<1, 3>::new(NacConfig {
            alpha: 0.5,
            ..config()
        });
        let mut policy = LinearGaussian::new(Vector1::new(0.0), 0.5);
        let mut updated = Vec::new();
        let mut rng_u = [0.3, -0.2, 0.4, -0.5, 0.1, 0.25, -0.35, 0.45];
        for (i, u) in rng_u.iter_mut().enumerate() {
            let x = Vector1::new(1.0 - 0.1 * i as f64);
            let r = -(x[0] * x[0]) - (*u - 0.3 * x[0]).powi(2);
            let before = (*nac.a(), *nac.b(), *nac.z(), policy.gain);
            let w_prev = nac
                .statistics()
                .w_history
                .back(1)
                .unwrap_or_else(SVector::zeros);
            let up = nac.update(
                &mut policy,
                &Transition {
                    x,
                    u: *u,
                    reward: r,
                    next: Some(x * 0.9),
                },
            );
            let w = nac.w();
            let agree = w_prev[0] != 0.0 && w[0] != 0.0 && w[0].signum() == w_prev[0].signum();
            assert_eq!(
                up, agree,
                "step {i}: the update must follow the angle test (w {w}, previous {w_prev})"
            );
            if up {
                assert!(
                    (policy.gain - (before.3 + 0.5 * w)).norm() < 1e-15,
                    "K += alpha w"
                );
                // The forgotten statistics are beta times the updated ones: recompute the update.
                let g = LinearGaussian::new(before.3, 0.5).grad_log(&x, *u);
                let phi_hat = SVector::<f64, 3>::new(x[0] * x[0], 1.0, g[0]);
                let d = phi_hat - 0.95 * SVector::<f64, 3>::new(0.81 * x[0] * x[0], 1.0, 0.0);
                let z = 0.8 * before.2 + phi_hat;
                assert!((nac.z() - 0.9 * z).norm() < 1e-12);
                assert!((nac.a() - 0.9 * (before.0 + z * d.transpose())).norm() < 1e-9);
                assert!((nac.b() - 0.9 * (before.1 + z * r)).norm() < 1e-12);
            } else {
                assert_eq!(policy.gain, before.3);
            }
            updated.push(up);
        }
        assert!(!updated[0]);
        assert!(
            updated.iter().any(|&u| u),
            "some step must pass the angle test"
        );
    }

    #[test]
    fn angle_test_rejects_gradients_more_than_epsilon_apart() {
        // Two-dimensional w: set the statistics so that w_prev and the new w differ by a known angle.
        let cfg = NacConfig {
            epsilon_deg: 1.0,
            beta: 0.5,
            alpha: 1.0,
            ..config()
        };
        let mut policy = LinearGaussian::new(Vector2::zeros(), 0.1);
        // A = I, b chosen so that the solution's w is at angle 0.5 or 2 degrees from w_prev = (1, 0).
        for (deg, expect) in [(0.5_f64, true), (2.0, false)] {
            let mut stats = NacStatistics::<2, 6>::zeros();
            stats.a = SMatrix::identity() * 1e6; // a transition with zero features barely moves it
            stats.b[4] = deg.to_radians().cos() * 1e6;
            stats.b[5] = deg.to_radians().sin() * 1e6;
            stats.w_history.push(Vector2::new(1.0, 0.0));
            let mut nac = Nac::with_statistics(cfg, stats);
            let t = Transition {
                x: Vector2::zeros(),
                u: 0.0,
                reward: 0.0,
                next: None,
            };
            assert_eq!(nac.update(&mut policy, &t), expect, "{deg} degrees");
        }
    }

    /// With a lag, the test compares with the estimate tau + 1 steps back, not the previous one.
    #[test]
    fn angle_test_looks_back_tau_plus_one_steps() {
        let cfg = NacConfig {
            epsilon_deg: 1.0,
            tau: 2,
            alpha: 1.0,
            ..config()
        };
        let t = Transition {
            x: Vector2::zeros(),
            u: 0.0,
            reward: 0.0,
            next: None,
        };
        // The new w is (1, 0): it agrees with the estimate 3 steps back and disagrees with the last one.
        for (three_back, last, expect) in [
            ([1.0, 0.0], [0.0, 1.0], true),
            ([0.0, 1.0], [1.0, 0.0], false),
        ] {
            let mut stats = NacStatistics::<2, 6>::zeros();
            stats.a = SMatrix::identity() * 1e6;
            stats.b[4] = 1e6;
            for w in [three_back, [0.5, 0.5], last] {
                stats.w_history.push(Vector2::from(w));
            }
            let mut nac = Nac::with_statistics(cfg, stats);
            let mut policy = LinearGaussian::new(Vector2::zeros(), 0.1);
            assert_eq!(
                nac.update(&mut policy, &t),
                expect,
                "3 back {three_back:?}, last {last:?}"
            );
        }
        // Without an estimate that old, no update.
        let mut stats = NacStatistics::<2, 6>::zeros();
        stats.a = SMatrix::identity() * 1e6;
        stats.b[4] = 1e6;
        stats.w_history.push(Vector2::new(1.0, 0.0));
        let mut nac = Nac::with_statistics(cfg, stats);
        assert!(!nac.update(&mut LinearGaussian::new(Vector2::zeros(), 0.1), &t));
    }

    #[test]
    fn gradient_history_is_a_ring_of_the_newest_estimates() {
        let mut h = GradientHistory::<1>::new();
        assert_eq!(h.back(1), None);
        for i in 0..(MAX_ANGLE_LAG + 5) {
            h.push(Vector1::new(i as f64));
        }
        assert_eq!(h.len(), MAX_ANGLE_LAG);
        assert_eq!(h.back(1), Some(Vector1::new((MAX_ANGLE_LAG + 4) as f64)));
        assert_eq!(h.back(MAX_ANGLE_LAG), Some(Vector1::new(5.0)));
        assert_eq!(h.back(MAX_ANGLE_LAG + 1), None);
        // Rebuilt from its estimates it is equal, whatever the ring's rotation.
        let again = GradientHistory::from_oldest_first(h.oldest_first());
        assert_eq!(again, h);
        let mut shorter = again;
        shorter.push(Vector1::new(-1.0));
        assert_ne!(shorter, h);
    }

    #[test]
    fn trace_resets_at_episode_end_but_statistics_persist() {
        let mut nac = Nac::<2, 6>::new(config());
        let mut policy = LinearGaussian::new(Vector2::zeros(), 0.1);
        let x = Vector2::new(0.3, 0.1);
        nac.update(
            &mut policy,
            &Transition {
                x,
                u: 0.05,
                reward: -1.0,
                next: Some(x),
            },
        );
        let (a, b) = (*nac.a(), *nac.b());
        nac.end_episode();
        assert_eq!(*nac.z(), SVector::<f64, 6>::zeros());
        assert_eq!((*nac.a(), *nac.b()), (a, b));
    }

    #[test]
    fn regularised_solve_is_exact_for_a_regular_matrix_and_finite_for_a_singular_one() {
        let a = Matrix2::new(2.0, 1.0, -1.0, 3.0);
        let b = Vector2::new(1.0, 2.0);
        let x = solve_regularised(&a, &b, 1e-6).unwrap();
        assert!((a * x - b).norm() < 1e-9, "{x}");
        // Rank one (as A is after the first transition) but consistent: a bounded exact solution, not
        // an infinity, with or without a configured ridge.
        let a = Matrix2::new(1.0, 2.0, 2.0, 4.0);
        let b = Vector2::new(1.0, 2.0);
        for ridge in [1e-6, 0.0] {
            let x = solve_regularised(&a, &b, ridge).unwrap();
            assert!(
                (a * x - b).norm() < 1e-6 && x.norm() < 2.0,
                "ridge {ridge}: {x}"
            );
        }
        assert!(solve_regularised(&Matrix2::zeros(), &b, 1e-6).is_none());
    }

    #[test]
    fn solution_is_invariant_to_forgetting() {
        // Forgetting scales A and b alike; the relative ridge keeps theta unchanged, so forgetting only
        // changes the weight of the old data against the new.
        let a = Matrix2::new(1.0, 2.0, 2.0, 4.0001);
        let b = Vector2::new(1.0, 3.0);
        let x1 = solve_regularised(&a, &b, 1e-3).unwrap();
        let x2 = solve_regularised(&(a * 0.9), &(b * 0.9), 1e-3).unwrap();
        assert!((x1 - x2).norm() < 1e-9 * x1.norm());
    }

    /// The must-show test: on a scalar linear-quadratic problem NAC (real update rule, angle test and
    /// forgetting) converges to the discounted LQR gain, from K = 0, for several seeds.
    #[test]
    fn nac_converges_to_the_discounted_lqr_gain_on_a_scalar_system() {
        let problem = Scalar::standard();
        let k_star = problem.optimal_gain();
        for seed in 0..4 {
            let cfg = NacConfig {
                alpha: problem.nac_alpha,
                beta: problem.nac_beta,
                ..NacConfig::for_dof(&NacParams::default(), Dof::Sway)
            };
            let mut nac = Nac::<1, 3>::new(cfg);
            let mut policy = LinearGaussian::new(Vector1::new(0.0), problem.sigma);
            let returns = run_episodes(&problem, &mut nac, &mut policy, problem.nac_episodes, seed);
            let k = policy.gain[0];
            // The angle test did gate: some steps were refused.
            assert!(
                nac.actor_updates() < nac.steps(),
                "seed {seed}: every step updated the actor"
            );
            let err = (k - k_star).abs() / k_star.abs();
            assert!(
                err < 0.05,
                "seed {seed}: K = {k:.4}, K* = {k_star:.4} ({:.1}% off) after {} actor updates; returns {:.2} -> {:.2}",
                100.0 * err,
                nac.actor_updates(),
                returns[0],
                returns[returns.len() - 1]
            );
        }
    }

    /// NAC with the paper's parameters (alpha = 0.01, beta = 0.9, gamma = 0.95, lambda = 0.8,
    /// epsilon = 1 degree) on a 2-D linear-quadratic system, a damped double integrator like the
    /// vehicle's sway: here the angle test gates for real (about 60% of the steps are refused), and the
    /// gain converges from 0 to the discounted LQR gain.
    #[test]
    fn nac_with_the_papers_parameters_converges_to_the_lqr_gain_of_a_2d_system() {
        use crate::lqr::{discounted_lqr, discretize_zoh};
        use nalgebra::Matrix1;
        use rand::rngs::StdRng;
        use rand::{Rng, SeedableRng};
        use rand_distr::StandardNormal;

        let sys = discretize_zoh(
            &Matrix2::new(0.0, 1.0, 0.0, -0.5),
            &Vector2::new(0.0, 1.0),
            0.2,
        )
        .unwrap();
        let q = Matrix2::new(1.0, 0.0, 0.0, 0.1);
        let r = 0.1;
        // Algorithm 1 with the paper's numbers only: no damping (this project's addition).
        let params = NacParams {
            alpha: config::PerDof::both(0.01),
            damping: 0.0,
            ..NacParams::default()
        };
        let k_star = discounted_lqr(&sys, &q, &Matrix1::new(r), params.gamma)
            .unwrap()
            .gain
            .transpose();
        for seed in 0..3 {
            let mut nac = Nac::<2, 6>::new(NacConfig::for_dof(&params, Dof::Sway));
            assert_eq!(nac.config().alpha, 0.01, "the paper's learning rate");
            let mut policy = LinearGaussian::new(Vector2::zeros(), 0.2);
            let mut rng = StdRng::seed_from_u64(seed);
            for _ in 0..20_000 {
                let mut x = Vector2::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
                for _ in 0..20 {
                    let u = policy.sample(&x, &mut rng);
                    let reward = -(x.dot(&(q * x)) + r * u * u);
                    let noise: f64 = rng.sample(StandardNormal);
                    let next = sys.a * x + sys.b * u + Vector2::new(0.0, 0.02 * noise);
                    nac.update(
                        &mut policy,
                        &Transition {
                            x,
                            u,
                            reward,
                            next: Some(next),
                        },
                    );
                    x = next;
                }
                nac.end_episode();
            }
            let err = (policy.gain - k_star).norm() / k_star.norm();
            let refused = 1.0 - nac.actor_updates() as f64 / nac.steps() as f64;
            assert!(
                err < 0.05,
                "seed {seed}: K = {}, K* = {} ({:.1}% off)",
                policy.gain.transpose(),
                k_star.transpose(),
                100.0 * err
            );
            assert!(
                refused > 0.2,
                "seed {seed}: the angle test refused only {:.0}% of the steps",
                100.0 * refused
            );
        }
    }
}
