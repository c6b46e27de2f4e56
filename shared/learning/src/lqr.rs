//! Reference controllers: what a learned linear policy should converge to when the plant is linear.
//!
//! - [`discretize_zoh`]: the exact zero-order-hold discretisation of `dx/dt = Ac x + Bc u` over `dt`,
//!   from the matrix exponential of `[[Ac, Bc], [0, 0]] dt` ([`expm`]).
//! - [`discounted_lqr`]: the gain minimising `sum gamma^t (x'Qx + u'Ru)` for `x' = A x + B u`, by
//!   iterating the discounted Riccati equation; `u = K x`, the sign convention of the policy's mean.
//! - [`scalar_discounted_lqr`]: the closed form of the same for a scalar system.
//!
//! None of this runs per step; it is for tests, reports and initial gains.

use nalgebra::{DMatrix, SMatrix, SVector};

/// Why a reference controller could not be computed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LqrError {
    /// An argument is out of its domain (named in the message).
    #[error("invalid input: {0}")]
    Invalid(String),
    /// The Riccati iteration kept changing.
    #[error(
        "the discounted Riccati iteration did not converge in {iterations} iterations (last relative change {change:e})"
    )]
    NotConverged {
        /// Iterations run.
        iterations: usize,
        /// The last relative change of `P`.
        change: f64,
    },
    /// The Riccati iteration blew up: the discounted system is not stabilisable.
    #[error(
        "the discounted Riccati iteration diverged after {iterations} iterations (not stabilisable with this discount)"
    )]
    Diverged {
        /// Iterations run before `P` overflowed (0 for the closed form).
        iterations: usize,
    },
    /// `R + gamma B'PB` cannot be inverted (e.g. `R` singular and `B'PB` too).
    #[error("R + gamma B'PB is singular after {iterations} iterations")]
    Singular {
        /// Iterations run (0 for the closed form).
        iterations: usize,
    },
}

/// A discrete-time linear system `x' = a x + b u`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DiscreteSystem<const S: usize, const M: usize> {
    /// State transition.
    pub a: SMatrix<f64, S, S>,
    /// Input matrix.
    pub b: SMatrix<f64, S, M>,
}

impl<const S: usize, const M: usize> DiscreteSystem<S, M> {
    /// The state after one period from `x` under the input `u`: `a x + b u`.
    pub fn next(&self, x: [f64; S], u: [f64; M]) -> [f64; S] {
        (self.a * SVector::from(x) + self.b * SVector::from(u)).into()
    }
}

/// A discounted LQR solution.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Lqr<const S: usize, const M: usize> {
    /// The optimal gain: `u = gain x`.
    pub gain: SMatrix<f64, M, S>,
    /// The cost-to-go `x'Px` of the optimal policy (the reward-to-go is its negative).
    pub p: SMatrix<f64, S, S>,
    /// Riccati iterations used.
    pub iterations: usize,
}

/// The scalar discounted LQR solution.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScalarLqr {
    /// The optimal gain: `u = gain x`.
    pub gain: f64,
    /// The cost-to-go `p x^2`.
    pub p: f64,
}

/// Degree of the diagonal Pade approximant. With the argument scaled to norm <= 1/2 the truncation error
/// is below 1e-20 (Golub and Van Loan, Matrix Computations, section 11.3): far under rounding.
const PADE_DEGREE: usize = 8;

/// The matrix exponential `e^M`, by scaling and squaring with a diagonal Pade approximant.
pub fn expm(m: &DMatrix<f64>) -> Result<DMatrix<f64>, LqrError> {
    let n = m.nrows();
    if m.ncols() != n {
        return Err(LqrError::Invalid(format!(
            "expm of a non-square {}x{} matrix",
            n,
            m.ncols()
        )));
    }
    if !m.iter().all(|v| v.is_finite()) {
        return Err(LqrError::Invalid(
            "expm of a matrix with non-finite entries".into(),
        ));
    }
    // Scale by 2^-j so that the infinity norm is at most 1/2; e^M = (e^(M/2^j))^(2^j).
    let norm = (0..n)
        .map(|i| m.row(i).iter().map(|v| v.abs()).sum::<f64>())
        .fold(0.0, f64::max);
    let j = if norm > 0.5 {
        (norm / 0.5).log2().ceil() as i32
    } else {
        0
    };
    let a = m * 2f64.powi(-j);

    let q = PADE_DEGREE;
    let mut c = 1.0;
    let mut x = DMatrix::<f64>::identity(n, n);
    let mut num = DMatrix::<f64>::identity(n, n);
    let mut den = DMatrix::<f64>::identity(n, n);
    for k in 1..=q {
        c *= (q - k + 1) as f64 / ((2 * q - k + 1) * k) as f64;
        x = &a * &x;
        num += &x * c;
        den += &x * if k % 2 == 0 { c } else { -c };
    }
    // den is close to the identity (|a| <= 1/2), so LU is safe here.
    let mut f = den
        .lu()
        .solve(&num)
        .ok_or_else(|| LqrError::Invalid("Pade denominator is singular".into()))?;
    for _ in 0..j {
        f = &f * &f;
    }
    Ok(f)
}

/// The exact zero-order-hold discretisation of `dx/dt = ac x + bc u` over `dt`: `u` held constant
/// over the step. `A = e^(Ac dt)`, `B = int_0^dt e^(Ac s) ds Bc`, both blocks of one exponential.
pub fn discretize_zoh<const S: usize, const M: usize>(
    ac: &SMatrix<f64, S, S>,
    bc: &SMatrix<f64, S, M>,
    dt: f64,
) -> Result<DiscreteSystem<S, M>, LqrError> {
    if !(dt.is_finite() && dt >= 0.0) {
        return Err(LqrError::Invalid(format!(
            "time step {dt} must be finite and >= 0"
        )));
    }
    let mut aug = DMatrix::<f64>::zeros(S + M, S + M);
    aug.view_mut((0, 0), (S, S)).copy_from(&(ac * dt));
    aug.view_mut((0, S), (S, M)).copy_from(&(bc * dt));
    let e = expm(&aug)?;
    Ok(DiscreteSystem {
        a: e.fixed_view::<S, S>(0, 0).into_owned(),
        b: e.fixed_view::<S, M>(0, S).into_owned(),
    })
}

/// Largest number of Riccati iterations before [`LqrError::NotConverged`].
const MAX_RICCATI_ITERATIONS: usize = 200_000;
/// Convergence: the largest change of `P` relative to its largest entry.
const RICCATI_TOLERANCE: f64 = 1e-13;

/// Discounted discrete-time LQR: minimises `sum_t gamma^t (x'Qx + u'Ru)` subject to `x' = a x + b u`.
///
/// Iterates `P <- Q + g A'PA - g^2 A'PB (R + g B'PB)^-1 B'PA` from `P = Q` until it stops changing;
/// the gain is `K = -g (R + g B'PB)^-1 B'PA`, so that `u = K x`.
pub fn discounted_lqr<const S: usize, const M: usize>(
    sys: &DiscreteSystem<S, M>,
    q: &SMatrix<f64, S, S>,
    r: &SMatrix<f64, M, M>,
    gamma: f64,
) -> Result<Lqr<S, M>, LqrError> {
    if !(gamma > 0.0 && gamma <= 1.0) {
        return Err(LqrError::Invalid(format!(
            "discount {gamma} must be in (0, 1]"
        )));
    }
    let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
    if !(finite(sys.a.as_slice())
        && finite(sys.b.as_slice())
        && finite(q.as_slice())
        && finite(r.as_slice()))
    {
        return Err(LqrError::Invalid(
            "non-finite entries in A, B, Q or R".into(),
        ));
    }
    let (a, b) = (&sys.a, &sys.b);
    let gain_at = |p: &SMatrix<f64, S, S>, iterations: usize| {
        let g = r + b.transpose() * p * b * gamma;
        let inv = g.try_inverse().ok_or(LqrError::Singular { iterations })?;
        let btpa = b.transpose() * p * a;
        Ok::<_, LqrError>((inv, btpa))
    };
    let mut p = *q;
    let mut change = f64::INFINITY;
    for iteration in 1..=MAX_RICCATI_ITERATIONS {
        let (inv, btpa) = gain_at(&p, iteration)?;
        let mut next =
            q + a.transpose() * p * a * gamma - btpa.transpose() * inv * btpa * (gamma * gamma);
        // Keep P exactly symmetric: rounding would otherwise make it drift.
        next = (next + next.transpose()) * 0.5;
        if !finite(next.as_slice()) {
            return Err(LqrError::Diverged {
                iterations: iteration,
            });
        }
        let scale = next.amax().max(1.0);
        change = (next - p).amax() / scale;
        p = next;
        if change <= RICCATI_TOLERANCE {
            let (inv, btpa) = gain_at(&p, iteration)?;
            return Ok(Lqr {
                gain: -(inv * btpa) * gamma,
                p,
                iterations: iteration,
            });
        }
    }
    Err(LqrError::NotConverged {
        iterations: MAX_RICCATI_ITERATIONS,
        change,
    })
}

/// The closed-form discounted LQR of the scalar system `x' = a x + b u`, cost `q x^2 + r u^2`.
///
/// The discounted Riccati equation reduces to `g b^2 p^2 + (r (1 - g a^2) - q g b^2) p - q r = 0`,
/// whose non-negative root is the cost-to-go; `K = -g a b p / (r + g b^2 p)`.
pub fn scalar_discounted_lqr(
    a: f64,
    b: f64,
    q: f64,
    r: f64,
    gamma: f64,
) -> Result<ScalarLqr, LqrError> {
    if !(gamma > 0.0 && gamma <= 1.0) {
        return Err(LqrError::Invalid(format!(
            "discount {gamma} must be in (0, 1]"
        )));
    }
    if !(a.is_finite() && b.is_finite() && q.is_finite() && q >= 0.0 && r.is_finite() && r >= 0.0) {
        return Err(LqrError::Invalid(format!(
            "need finite a, b and q, r >= 0 (a = {a}, b = {b}, q = {q}, r = {r})"
        )));
    }
    let p = if b == 0.0 {
        // Nothing to control: the cost-to-go of the free system, finite only if it decays fast enough.
        if gamma * a * a >= 1.0 {
            return Err(LqrError::Diverged { iterations: 0 });
        }
        q / (1.0 - gamma * a * a)
    } else {
        let c2 = gamma * b * b;
        let c1 = r * (1.0 - gamma * a * a) - q * gamma * b * b;
        let c0 = -q * r;
        let root = (c1 * c1 - 4.0 * c2 * c0).sqrt();
        // The two algebraically equal forms of the positive root; take the one without cancellation.
        if c1 >= 0.0 {
            -2.0 * c0 / (c1 + root)
        } else {
            (-c1 + root) / (2.0 * c2)
        }
    };
    let denom = r + gamma * b * b * p;
    if denom == 0.0 {
        return Err(LqrError::Singular { iterations: 0 });
    }
    Ok(ScalarLqr {
        gain: -gamma * a * b * p / denom,
        p,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix1, Matrix2, SMatrix, Vector2};

    fn close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol * (1.0 + a.abs().max(b.abs()))
    }

    #[test]
    fn expm_of_a_rotation_generator_is_a_rotation_even_for_large_angles() {
        for angle in [0.1, 1.0, 3.0, 25.0] {
            let m = DMatrix::from_row_slice(2, 2, &[0.0, -angle, angle, 0.0]);
            let e = expm(&m).unwrap();
            let (s, c) = f64::sin_cos(angle);
            let want = DMatrix::from_row_slice(2, 2, &[c, -s, s, c]);
            assert!((e - want).amax() < 1e-13 * angle.max(1.0), "angle {angle}");
        }
        assert_eq!(
            expm(&DMatrix::zeros(3, 3)).unwrap(),
            DMatrix::identity(3, 3)
        );
    }

    #[test]
    fn zoh_of_a_first_order_system_matches_the_closed_form() {
        // dv/dt = -c v + k u (the identified yaw model's linear part): A = e^(-c dt),
        // B = k (1 - e^(-c dt)) / c.
        let (c, k, dt) = (3.4628, 0.2878, 0.2);
        let d = discretize_zoh(&Matrix1::new(-c), &Matrix1::new(k), dt).unwrap();
        let e = (-c * dt).exp();
        assert!(close(d.a[0], e, 1e-14), "{} vs {e}", d.a[0]);
        assert!(
            close(d.b[0], k * (1.0 - e) / c, 1e-14),
            "{} vs {}",
            d.b[0],
            k * (1.0 - e) / c
        );
    }

    #[test]
    fn zoh_of_a_double_integrator_and_a_damped_one_match_the_closed_forms() {
        let dt = 0.2;
        let d = discretize_zoh(
            &Matrix2::new(0.0, 1.0, 0.0, 0.0),
            &Vector2::new(0.0, 1.0),
            dt,
        )
        .unwrap();
        assert!((d.a - Matrix2::new(1.0, dt, 0.0, 1.0)).amax() < 1e-15);
        assert!((d.b - Vector2::new(dt * dt / 2.0, dt)).amax() < 1e-15);

        // Position and velocity with linear damping: dp/dt = v, dv/dt = -c v + k u.
        let (c, k) = (0.2586, 0.1508);
        let d =
            discretize_zoh(&Matrix2::new(0.0, 1.0, 0.0, -c), &Vector2::new(0.0, k), dt).unwrap();
        let e = (-c * dt).exp();
        let a = Matrix2::new(1.0, (1.0 - e) / c, 0.0, e);
        let b = Vector2::new(k * (dt / c - (1.0 - e) / (c * c)), k * (1.0 - e) / c);
        assert!((d.a - a).amax() < 1e-14, "{} vs {a}", d.a);
        assert!((d.b - b).amax() < 1e-14, "{} vs {b}", d.b);
    }

    #[test]
    fn riccati_solution_satisfies_the_discounted_riccati_equation() {
        let sys = discretize_zoh(
            &Matrix2::new(0.0, 1.0, 0.0, -0.2586),
            &Vector2::new(0.0, 0.1508),
            0.2,
        )
        .unwrap();
        let q = Matrix2::new(1.1, 0.0, 0.0, 0.2);
        let r = Matrix1::new(0.01);
        let g = 0.95;
        let sol = discounted_lqr(&sys, &q, &r, g).unwrap();
        let (a, b, p) = (sys.a, sys.b, sol.p);
        let inv = (r + b.transpose() * p * b * g).try_inverse().unwrap();
        let rhs = q + a.transpose() * p * a * g
            - a.transpose() * p * b * inv * b.transpose() * p * a * (g * g);
        assert!(
            (rhs - p).amax() < 1e-10 * p.amax(),
            "residual {}",
            (rhs - p).amax()
        );
        // The gain is the minimiser of the one-step lookahead: its derivative vanishes.
        let k = sol.gain;
        let grad = (r * k + b.transpose() * p * (a + b * k) * g) * 2.0;
        assert!(grad.amax() < 1e-9 * p.amax(), "{grad}");
        // And it is stabilising for the discounted system.
        let closed = (a + b * k) * g.sqrt();
        let rho = closed
            .complex_eigenvalues()
            .iter()
            .map(|l| l.norm())
            .fold(0.0, f64::max);
        assert!(rho < 1.0, "spectral radius {rho}");
        // It beats nearby gains on the exact discounted cost of x0 = e1 (no noise): x'P_K x.
        let cost = |k: SMatrix<f64, 1, 2>| {
            let acl = a + b * k;
            let qk = q + k.transpose() * r * k;
            let mut pk = qk;
            for _ in 0..5000 {
                pk = qk + acl.transpose() * pk * acl * g;
            }
            pk[(0, 0)] + pk[(1, 1)]
        };
        let best = cost(k);
        for dk in [[0.05, 0.0], [-0.05, 0.0], [0.0, 0.05], [0.0, -0.05]] {
            assert!(cost(k + SMatrix::<f64, 1, 2>::new(dk[0], dk[1])) > best);
        }
    }

    #[test]
    fn scalar_closed_form_matches_the_iterative_solver() {
        for &(a, b, q, r, g) in &[
            (0.9, 0.5, 1.0, 0.5, 0.95),
            (1.2, 0.3, 1.0, 0.1, 0.9),
            (0.5, -2.0, 2.0, 0.01, 0.99),
            (1.0, 1.0, 0.0, 1.0, 0.95),
            (0.8, 0.0, 1.0, 1.0, 0.95),
        ] {
            let closed = scalar_discounted_lqr(a, b, q, r, g).unwrap();
            let sys = DiscreteSystem {
                a: Matrix1::new(a),
                b: Matrix1::new(b),
            };
            let iter = discounted_lqr(&sys, &Matrix1::new(q), &Matrix1::new(r), g).unwrap();
            assert!(
                close(closed.p, iter.p[0], 1e-10),
                "{a} {b}: p {} vs {}",
                closed.p,
                iter.p[0]
            );
            assert!(
                close(closed.gain, iter.gain[0], 1e-10),
                "{a} {b}: K {} vs {}",
                closed.gain,
                iter.gain[0]
            );
        }
    }

    #[test]
    fn an_unstabilisable_discounted_system_is_an_error() {
        // No input and a mode growing faster than 1/sqrt(gamma).
        let sys = DiscreteSystem {
            a: Matrix1::new(1.5),
            b: Matrix1::new(0.0),
        };
        let err = discounted_lqr(&sys, &Matrix1::new(1.0), &Matrix1::new(1.0), 0.95).unwrap_err();
        assert!(
            matches!(
                err,
                LqrError::Diverged { .. } | LqrError::NotConverged { .. }
            ),
            "{err}"
        );
        assert!(scalar_discounted_lqr(1.5, 0.0, 1.0, 1.0, 0.95).is_err());
        assert!(discounted_lqr(&sys, &Matrix1::new(1.0), &Matrix1::new(1.0), 1.5).is_err());
    }
}
