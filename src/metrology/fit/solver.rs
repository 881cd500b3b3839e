//! Levenberg–Marquardt on accumulated normal equations: each iteration sums JᵀJ and Jᵀr of
//! a shape's analytic Jacobian over fixed chunks (no m × p Jacobian is stored), solves the
//! Jacobi-scaled damped system, and a converged fit gets its covariance σ²(JᵀJ)⁻¹. A shape
//! takes part by implementing [`Model`].

use super::error::FitError;
use super::moments::{EIGEN_ITERATIONS, chunked_sum};
use crate::math::{Point3, Real};
use nalgebra::{Cholesky, SMatrix, SVector, SymmetricEigen};

/// Smallest over largest eigenvalue of the normal matrix JᵀJ, with angles expressed as
/// lengths (times the points' RMS spread), below which the fit counts as rank-deficient:
/// a singular-value ratio of 1e-6 of the Jacobian, i.e. noise amplified a million-fold
/// into some parameter combination (25 nm of noise becoming 25 mm of uncertainty): a
/// guess, not a fit.
pub(super) const RANK_RATIO: Real = 1e-12;

/// Relative Gauss–Newton step below which an iterative fit has converged: the largest
/// length-equivalent component of the step (angles times the points' RMS spread) under
/// 1e-12 of that spread. A thousand times below the 1e-9 relative accuracy promised on
/// exact data, and still 1e4 above f64 rounding (2.2e-16).
const STEP_TOL: Real = 1e-12;

/// Predicted relative decrease of the sum of squares below which an iterative fit has
/// converged even if [`STEP_TOL`] is not met (noisy data): the step then moves each
/// parameter by at most √(2e-12·(m−p)) of its standard uncertainty (0.1 % at 400,000
/// points), and such a decrease is within a few hundred ulps of the sum, where comparing
/// costs stops being meaningful.
const COST_TOL: Real = 1e-12;

/// Iteration cap of the iterative fits (accepted steps). The closed-form starts converge
/// in under ten on measured surfaces; a hundred means the problem has no minimum nearby
/// (a cylinder on planar points drifting to infinite radius).
pub const MAX_ITERATIONS: usize = 100;

/// Initial Marquardt damping, relative to the unit diagonal of the Jacobi-scaled normal
/// matrix: small, because the closed-form start is usually within the Gauss–Newton basin.
const LAMBDA_START: Real = 1e-4;

/// Factor by which the damping grows after a rejected step and shrinks after an accepted one.
const LAMBDA_FACTOR: Real = 10.0;

/// Damping never falls below this: keeps the damped system positive definite when JᵀJ
/// is merely semi-definite in rounding, and is 1e-12 of the unit diagonal, so it does not
/// slow Gauss–Newton convergence measurably.
const LAMBDA_FLOOR: Real = 1e-12;

/// Damping beyond which a step of 1e-10 of the steepest-descent length still does not
/// reduce the sum of squares: the solver is stuck and gives up.
const LAMBDA_MAX: Real = 1e10;

/// Running sums of the normal equations over a chunk: the upper triangle of JᵀJ (plain
/// arrays, so the per-point update unrolls to P(P+1)/2 multiply-adds), Jᵀr and the
/// residual sums.
#[derive(Clone, Copy, Debug)]
pub(super) struct Sums<const P: usize> {
    jtj: [[Real; P]; P],
    jtr: [Real; P],
    ss: Real,
    pub(super) max_abs: Real,
}

impl<const P: usize> Sums<P> {
    pub(super) fn zero() -> Self {
        Self {
            jtj: [[0.0; P]; P],
            jtr: [0.0; P],
            ss: 0.0,
            max_abs: 0.0,
        }
    }

    /// Adds one residual `r` with Jacobian row `j`.
    #[inline(always)]
    pub(super) fn push(&mut self, j: &[Real; P], r: Real) {
        for (a, ((row, g), &ja)) in self.jtj.iter_mut().zip(&mut self.jtr).zip(j).enumerate() {
            *g += ja * r;
            for (h, &jb) in row.iter_mut().zip(j).skip(a) {
                *h += ja * jb;
            }
        }
        self.ss += r * r;
    }

    /// The chunk's sums as normal equations (JᵀJ symmetrised).
    pub(super) fn normal(&self) -> Normal<P> {
        Normal {
            jtj: SMatrix::from_fn(|a, b| self.jtj[a.min(b)][a.max(b)]),
            jtr: SVector::from(self.jtr),
            ss: self.ss,
            max_abs: self.max_abs,
        }
    }
}

/// Normal equations JᵀJ, Jᵀr of a set of points, with the residual sums.
#[derive(Clone, Copy, Debug)]
pub(super) struct Normal<const P: usize> {
    pub(super) jtj: SMatrix<Real, P, P>,
    pub(super) jtr: SVector<Real, P>,
    /// Σ r² over all residuals.
    pub(super) ss: Real,
    /// Largest distance of a point from the shape.
    pub(super) max_abs: Real,
}

impl<const P: usize> Normal<P> {
    fn zero() -> Self {
        Self {
            jtj: SMatrix::zeros(),
            jtr: SVector::zeros(),
            ss: 0.0,
            max_abs: 0.0,
        }
    }

    fn add(mut self, o: &Self) -> Self {
        self.jtj += o.jtj;
        self.jtr += o.jtr;
        self.ss += o.ss;
        self.max_abs = self.max_abs.max(o.max_abs);
        self
    }

    fn is_finite(&self) -> bool {
        self.ss.is_finite()
            && self.max_abs.is_finite()
            && self.jtj.iter().all(|v| v.is_finite())
            && self.jtr.iter().all(|v| v.is_finite())
    }
}

/// A shape in a local parameterisation with P parameters.
pub(super) trait Model<const P: usize>: Copy + Send + Sync {
    /// Residuals per point.
    const RESIDUALS_PER_POINT: usize;
    /// Adds the residuals of `p` and their Jacobian rows to `acc`, and its distance to
    /// `acc.max_abs`.
    fn accumulate(&self, p: &Point3, acc: &mut Sums<P>);
    /// The shape moved by the local parameter step `delta`.
    fn step(&self, delta: &SVector<Real, P>) -> Self;
    /// Per-parameter factors to length-equivalents (mm): 1 for lengths, `scale` for angles.
    fn to_length(scale: Real) -> SVector<Real, P>;
}

/// Sums of the normal equations over all points, in fixed chunks.
fn evaluate<const P: usize, M: Model<P>>(points: &[Point3], model: &M) -> Normal<P> {
    chunked_sum(
        points,
        |c| {
            let mut acc = Sums::zero();
            for p in c {
                model.accumulate(p, &mut acc);
            }
            acc.normal()
        },
        Normal::zero(),
        |a, b| a.add(b),
    )
}

/// The Jacobi-scaled system: H_s = D⁻¹ H D⁻¹ with D = √diag(H), g_s = D⁻¹ g.
pub(super) struct Scaled<const P: usize> {
    hs: SMatrix<Real, P, P>,
    gs: SVector<Real, P>,
    dinv: SVector<Real, P>,
}

impl<const P: usize> Scaled<P> {
    /// None if a diagonal entry of JᵀJ is zero or anything is non-finite.
    pub(super) fn new(ne: &Normal<P>) -> Option<Self> {
        let diag = ne.jtj.diagonal();
        if !diag.iter().all(|&d| d > 0.0 && d.is_finite()) || !ne.is_finite() {
            return None;
        }
        let dinv = diag.map(|d| 1.0 / d.sqrt());
        let hs = SMatrix::<Real, P, P>::from_fn(|i, j| ne.jtj[(i, j)] * dinv[i] * dinv[j]);
        let gs = ne.jtr.component_mul(&dinv);
        Some(Self { hs, gs, dinv })
    }

    /// The step δ solving (H + λ·diag H) δ = −g, None if not positive definite.
    pub(super) fn step(&self, lambda: Real) -> Option<SVector<Real, P>> {
        let a = self.hs + SMatrix::<Real, P, P>::identity() * lambda;
        let x = Cholesky::new(a)?.solve(&(-self.gs));
        let delta = x.component_mul(&self.dinv);
        delta.iter().all(|v| v.is_finite()).then_some(delta)
    }

    /// H⁻¹ (unscaled), None if not positive definite.
    fn inverse(&self) -> Option<SMatrix<Real, P, P>> {
        let inv = Cholesky::new(self.hs)?.inverse();
        let inv = SMatrix::<Real, P, P>::from_fn(|i, j| inv[(i, j)] * self.dinv[i] * self.dinv[j]);
        inv.iter().all(|v| v.is_finite()).then_some(inv)
    }
}

/// Whether JᵀJ, with each parameter expressed as a length (`to_length`: the Jacobian's
/// columns in mm per mm), has an eigenvalue ratio below [`RANK_RATIO`] (or is not finite).
///
/// Physical rather than Jacobi scaling: a column that is rounding noise (the tilt of a
/// cylinder fitted to points on one circle) must stay small to be seen.
pub(super) fn rank_deficient<const P: usize>(
    jtj: &SMatrix<Real, P, P>,
    to_length: &SVector<Real, P>,
) -> bool {
    let h = nalgebra::DMatrix::from_fn(P, P, |i, j| jtj[(i, j)] / (to_length[i] * to_length[j]));
    if !h.iter().all(|v| v.is_finite()) {
        return true;
    }
    match SymmetricEigen::try_new(h, Real::EPSILON, EIGEN_ITERATIONS) {
        Some(e) => {
            let (lo, hi) = (e.eigenvalues.min(), e.eigenvalues.max());
            !(hi > 0.0 && lo > RANK_RATIO * hi)
        }
        None => true,
    }
}

/// A converged iterative fit.
pub(super) struct Solved<M, const P: usize> {
    pub(super) model: M,
    pub(super) normal: Normal<P>,
    pub(super) iterations: usize,
    /// σ²·(JᵀJ)⁻¹ in the model's local parameters; None when there are no more residuals
    /// than parameters (all uncertainties infinite).
    pub(super) covariance: Option<SMatrix<Real, P, P>>,
    /// Number of points.
    n: usize,
}

impl<M, const P: usize> Solved<M, P> {
    pub(super) fn rms(&self) -> Real {
        (self.normal.ss / self.n as Real).sqrt()
    }

    /// Standard uncertainty of local parameter k.
    pub(super) fn sigma(&self, k: usize) -> Real {
        self.covariance
            .map_or(Real::INFINITY, |c| c[(k, k)].max(0.0).sqrt())
    }

    /// Root of the largest and smallest eigenvalue of the 2×2 covariance block at (k, k).
    pub(super) fn sigma_pair(&self, k: usize) -> [Real; 2] {
        let Some(c) = self.covariance else {
            return [Real::INFINITY; 2];
        };
        let (a, b, d) = (c[(k, k)], c[(k, k + 1)], c[(k + 1, k + 1)]);
        let mean = 0.5 * (a + d);
        let half = (0.5 * (a - d)).hypot(b);
        [(mean + half).max(0.0).sqrt(), (mean - half).max(0.0).sqrt()]
    }
}

/// Levenberg–Marquardt from `start`; `scale` (mm) converts angles to lengths for the
/// convergence test.
pub(super) fn levenberg_marquardt<const P: usize, M: Model<P>>(
    points: &[Point3],
    start: M,
    scale: Real,
) -> Result<Solved<M, P>, FitError> {
    let to_length = M::to_length(scale);
    let mut model = start;
    let mut ne = evaluate(points, &model);
    let mut lambda = LAMBDA_START;
    let mut iterations = 0;
    loop {
        let sys = Scaled::new(&ne).ok_or(FitError::Degenerate)?;
        if let Some(gn) = sys.step(0.0) {
            let predicted_decrease = -ne.jtr.dot(&gn);
            if gn.component_mul(&to_length).amax() <= STEP_TOL * scale
                || predicted_decrease <= COST_TOL * ne.ss
            {
                let m = points.len() * M::RESIDUALS_PER_POINT;
                if rank_deficient(&ne.jtj, &to_length) {
                    return Err(FitError::Degenerate);
                }
                return finish_solve(points.len(), m, model, ne, &sys, iterations);
            }
        }
        let give_up = |ne: &Normal<P>, iterations| {
            if rank_deficient(&ne.jtj, &to_length) {
                FitError::Degenerate
            } else {
                FitError::NotConverged { iterations }
            }
        };
        if iterations >= MAX_ITERATIONS {
            return Err(give_up(&ne, iterations));
        }
        iterations += 1;
        loop {
            if let Some(delta) = sys.step(lambda) {
                let trial = model.step(&delta);
                let tn = evaluate(points, &trial);
                if tn.is_finite() && tn.ss < ne.ss {
                    model = trial;
                    ne = tn;
                    lambda = (lambda / LAMBDA_FACTOR).max(LAMBDA_FLOOR);
                    break;
                }
            }
            lambda *= LAMBDA_FACTOR;
            if lambda > LAMBDA_MAX {
                return Err(give_up(&ne, iterations));
            }
        }
    }
}

/// The covariance of a converged fit (Degenerate if JᵀJ cannot be inverted).
fn finish_solve<const P: usize, M>(
    n: usize,
    m: usize,
    model: M,
    normal: Normal<P>,
    sys: &Scaled<P>,
    iterations: usize,
) -> Result<Solved<M, P>, FitError> {
    let inv = sys.inverse().ok_or(FitError::Degenerate)?;
    let covariance = (m > P).then(|| inv * (normal.ss / (m - P) as Real));
    Ok(Solved {
        model,
        normal,
        iterations,
        covariance,
        n,
    })
}
