//! Orthogonal least-squares fits of planes, spheres, circles in 3-D and cylinders, plain and
//! with iterative outlier rejection.
//!
//! **Plane.** The fit minimises the sum of squared perpendicular distances: the normal is
//! the eigenvector of the smallest eigenvalue of the centred second-moment matrix. Numerics
//! are arranged for 0.1 µm / 1 µrad resolution on faces 20–300 mm from the origin:
//!
//! * the mean is accumulated relative to the first point (differences of at most the
//!   patch size, not absolute coordinates), then corrected by the mean residual of a second
//!   pass (the classical corrected two-pass algorithm);
//! * the second moments are accumulated about that centroid;
//! * all sums run over fixed chunks of [`CHUNK`] points in parallel (rayon) and the partial
//!   sums are combined in chunk order, so results are bit-identical for any thread count.
//!
//! **Sphere, circle, cylinder.** These minimise the sum of squared *orthogonal* (geometric)
//! distances by damped Gauss–Newton (Levenberg–Marquardt with Marquardt's diagonal scaling)
//! on the normal equations: each iteration accumulates JᵀJ and Jᵀr of the analytic
//! Jacobian over the same fixed chunks, so no m × p Jacobian is ever stored, 400,000 points
//! cost a few passes of arithmetic, and every result bit is independent of the thread
//! count. Orientations are updated in a minimal local parameterisation (two small rotation
//! angles in the tangent plane of the current normal or axis, re-linearised each
//! iteration). Starting values are closed-form:
//!
//! * sphere: the algebraic fit x²+y²+z² + Dx + Ey + Fz + G = 0 (linear least squares in
//!   centred, scaled coordinates); residual |p − c| − r;
//! * circle: the plane of [`fit_plane`], then the algebraic (Kåsa) circle of the points
//!   projected into it; two residuals per point, n·(p − c) and |P(p − c)| − r with P the
//!   projection onto the plane, so √(sum of both squared) is the point's distance from
//!   the circle;
//! * cylinder: the caller's axis direction if given, otherwise each of the three principal
//!   axes of the points' covariance as a candidate; a Kåsa circle of the points projected
//!   on the plane perpendicular to each candidate, keeping the candidate with the smallest
//!   RMS circle residual; residual = distance from the axis − r. The axis pivot is kept at
//!   the foot of the points' centroid, which decouples tilt from translation.
//!
//! Uncertainties are σ²(JᵀJ)⁻¹ with σ² = Σr²/(m − p) (m residuals, p parameters) at the
//! solution: standard uncertainties for independent Gaussian noise of equal variance in
//! every residual (checked by Monte Carlo in the tests to within 20 %). They are the
//! honest measure of conditioning: partial arcs shorter than about 90° determine the
//! radius and the centre (the axis) poorly; the fit still converges but the reported σ
//! grow steeply, roughly as the inverse square of the arc angle for the radius (a 10 mm
//! circle or cylinder with 0.025 mm noise: σ_r ≈ 0.006 mm at 90°, 0.025 mm at 45°, 0.12
//! mm at 20°). Below about 30° the linearisation itself starts to show: the observed
//! spread exceeds the reported σ by some 10 % and the radius is biased high by about 0.2 σ.
//! Rank-deficient problems (points on one circle for a cylinder, coplanar points
//! for a sphere, collinear points for a circle) are refused as [`FitError::Degenerate`]; a
//! solver that does not converge within [`MAX_ITERATIONS`] reports
//! [`FitError::NotConverged`], never a number.

use crate::math::{Matrix3, Point3, Real, UnitVector3, Vector3, tol};
use nalgebra::{Cholesky, SMatrix, SVector, SymmetricEigen};
use rayon::prelude::*;

/// Points per parallel work item. Fixed (never derived from the thread count) so that the
/// floating-point summation order, and hence every result bit, is independent of threads.
pub const CHUNK: usize = 4096;

/// A plane {x : normal · x = offset}.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Plane {
    /// Unit normal.
    pub normal: UnitVector3,
    /// Signed distance of the plane from the origin along `normal` (mm).
    pub offset: Real,
}

impl Plane {
    /// The plane through `point` with the given `normal`.
    pub fn through(point: &Point3, normal: UnitVector3) -> Plane {
        Plane {
            normal,
            offset: normal.dot(&point.coords),
        }
    }

    /// Signed distance of `p` from the plane (mm), positive on the side `normal` points to.
    pub fn signed_distance(&self, p: &Point3) -> Real {
        self.normal.dot(&p.coords) - self.offset
    }

    /// Orthogonal projection of `p` onto the plane.
    pub fn project(&self, p: &Point3) -> Point3 {
        p - self.normal.into_inner() * self.signed_distance(p)
    }

    /// Intersection of the line p + t·dir with the plane (None if parallel within 1e-12 relative).
    ///
    /// "Parallel" means |normal · dir| ≤ 1e-12 · |dir|; a non-finite result is also `None`.
    pub fn intersect_line(&self, p: &Point3, dir: &Vector3) -> Option<Point3> {
        let denom = self.normal.dot(dir);
        if denom.abs() <= 1e-12 * dir.norm() || !denom.is_finite() {
            return None;
        }
        let t = -self.signed_distance(p) / denom;
        let x = p + dir * t;
        x.coords.iter().all(|c| c.is_finite()).then_some(x)
    }

    /// The same plane with normal flipped if needed so that normal·towards >= 0.
    pub fn oriented_towards(&self, towards: &Vector3) -> Plane {
        if self.normal.dot(towards) < 0.0 {
            Plane {
                normal: -self.normal,
                offset: -self.offset,
            }
        } else {
            *self
        }
    }
}

/// Result of a plane fit.
#[derive(Clone, Debug, PartialEq)]
pub struct PlaneFit {
    /// The fitted plane. Its normal is oriented so that its largest-magnitude component is
    /// positive (ties: the first such component of x, y, z); re-orient with
    /// [`Plane::oriented_towards`].
    pub plane: Plane,
    /// Centroid of the points used (lies on the plane).
    pub centroid: Point3,
    /// Number of points in the final fit.
    pub n_used: usize,
    /// Number of input points rejected as outliers (0 for [`fit_plane`]).
    pub n_rejected: usize,
    /// Root-mean-square perpendicular residual of the used points (mm), divided by `n`.
    pub rms_mm: Real,
    /// Largest absolute perpendicular residual of the used points (mm).
    pub max_abs_mm: Real,
    /// Standard uncertainty of the offset at the centroid (mm): σ/√n with
    /// σ = √(Σr²/(n−3)) (three fitted parameters). Infinite when n = 3.
    pub offset_sigma_mm: Real,
    /// Standard uncertainty of the normal's tilt (rad) towards each of the two in-plane
    /// principal axes: σ/√(Σ(aₖ·(pᵢ−c))²), i.e. σ over the root of the k-th in-plane
    /// eigenvalue of the second-moment sum. Index 0 is the major axis (largest spread:
    /// tilt in the direction of the major axis, a rotation about the minor axis), index 1
    /// the minor axis. Infinite when n = 3.
    pub tilt_sigma_rad: [Real; 2],
}

/// Outlier rejection rule: iteratively drop points with |residual| > k_sigma · rms and refit, until nothing changes or max_iterations.
///
/// Residuals of all input points are re-evaluated against each new fit, so a point
/// dropped early can return. The threshold never falls below 1 pm
/// ([`tol::LENGTH_EPS`]), so exact data lose nothing to rounding. A refit that would
/// fail (fewer points than the shape needs, degenerate, not converged) ends the iteration
/// with the previous fit. The same rule, through one shared loop, serves planes, spheres,
/// circles (residual: the point's distance from the circle) and cylinders.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RobustRule {
    /// Rejection threshold in multiples of the current fit's rms residual.
    pub k_sigma: Real,
    /// Maximum number of reject-and-refit rounds.
    pub max_iterations: usize,
}

impl Default for RobustRule {
    /// k_sigma 3.0, max_iterations 10.
    fn default() -> Self {
        Self {
            k_sigma: 3.0,
            max_iterations: 10,
        }
    }
}

/// Why a shape could not be fitted.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum FitError {
    /// Fewer points than the shape needs.
    #[error("fit needs at least {needed} points, got {got}")]
    TooFewPoints {
        /// Minimum number of points: plane 3, sphere 4, circle 3, cylinder 5.
        needed: usize,
        /// Number supplied.
        got: usize,
    },
    /// The points do not determine the shape: collinear or coincident for a plane or a
    /// circle, coplanar for a sphere, collinear (or, e.g., all on one circle) for a
    /// cylinder; a rank-deficient Jacobian at the solution; or coordinates so large their
    /// moments overflow.
    #[error("degenerate point configuration: the points do not determine a unique fit")]
    Degenerate,
    /// A point has a NaN or infinite coordinate.
    #[error("point {index} has a non-finite coordinate")]
    NonFinite {
        /// Index of the first offending point.
        index: usize,
    },
    /// The iterative (sphere, circle, cylinder) solver did not converge.
    #[error("the least-squares solver did not converge after {iterations} iterations")]
    NotConverged {
        /// Iterations done (accepted steps) before giving up.
        iterations: usize,
    },
}

/// Smallest over largest eigenvalue ratio below which the points count as degenerate: an
/// aspect ratio of 1e-6 (40 nm across a 40 mm line). Applied to the second-smallest
/// eigenvalue it detects collinear points (plane, circle, cylinder), to the smallest
/// coplanar points (sphere).
const DEGENERATE_RATIO: Real = 1e-12;

/// Iteration cap of the symmetric eigensolver on the 3×3 to 6×6 matrices here: it
/// converges in tens of sweeps on any finite input; the cap only bounds pathological input.
const EIGEN_ITERATIONS: usize = 10_000;

/// Smallest over largest eigenvalue of the normal matrix JᵀJ, with angles expressed as
/// lengths (times the points' RMS spread), below which the fit counts as rank-deficient:
/// a singular-value ratio of 1e-6 of the Jacobian, i.e. noise amplified a million-fold
/// into some parameter combination (25 nm of noise becoming 25 mm of uncertainty): a
/// guess, not a fit.
const RANK_RATIO: Real = 1e-12;

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

/// Minimum points for a plane: three non-collinear points span it.
const PLANE_MIN_POINTS: usize = 3;
/// Minimum points for a sphere: four non-coplanar points determine it.
const SPHERE_MIN_POINTS: usize = 4;
/// Minimum points for a circle: three non-collinear points determine it.
const CIRCLE_MIN_POINTS: usize = 3;
/// Minimum points for a cylinder: five parameters, five residuals.
const CYLINDER_MIN_POINTS: usize = 5;

/// Refuses too few points, then the first non-finite point.
fn check_input(points: &[Point3], needed: usize) -> Result<(), FitError> {
    if points.len() < needed {
        return Err(FitError::TooFewPoints {
            needed,
            got: points.len(),
        });
    }
    if let Some(index) = points
        .par_iter()
        .position_first(|p| !p.coords.iter().all(|c| c.is_finite()))
    {
        return Err(FitError::NonFinite { index });
    }
    Ok(())
}

/// Orthogonal least-squares plane: minimises the sum of squared perpendicular distances (smallest eigenvector of the centred covariance).
///
/// The normal is oriented so that its largest-magnitude component is positive (the
/// first of x, y, z on a tie); callers choose a side with [`Plane::oriented_towards`].
/// Needs at least 3 finite points that are not collinear. Deterministic and bit-identical
/// for any rayon thread count.
pub fn fit_plane(points: &[Point3]) -> Result<PlaneFit, FitError> {
    check_input(points, PLANE_MIN_POINTS)?;
    fit_checked(points)
}

/// Symmetric second moments and first moments of a chunk about a centre.
#[derive(Clone, Copy, Default)]
struct Moments {
    s: [Real; 3],
    /// xx, xy, xz, yy, yz, zz.
    m: [Real; 6],
}

impl Moments {
    fn of(points: &[Point3], c: &Vector3) -> Self {
        let mut acc = Moments::default();
        for p in points {
            let d = p.coords - c;
            acc.s[0] += d.x;
            acc.s[1] += d.y;
            acc.s[2] += d.z;
            acc.m[0] += d.x * d.x;
            acc.m[1] += d.x * d.y;
            acc.m[2] += d.x * d.z;
            acc.m[3] += d.y * d.y;
            acc.m[4] += d.y * d.z;
            acc.m[5] += d.z * d.z;
        }
        acc
    }

    fn add(mut self, o: &Moments) -> Self {
        for k in 0..3 {
            self.s[k] += o.s[k];
        }
        for k in 0..6 {
            self.m[k] += o.m[k];
        }
        self
    }
}

/// Sum of `f` over fixed chunks, combined in chunk order (thread-count independent).
fn chunked_sum<T, F, G>(points: &[Point3], f: F, zero: T, add: G) -> T
where
    T: Send + Copy,
    F: Fn(&[Point3]) -> T + Sync + Send,
    G: Fn(T, &T) -> T,
{
    let partial: Vec<T> = points.par_chunks(CHUNK).map(f).collect();
    partial.iter().fold(zero, add)
}

/// Centroid and centred second-moment sum (corrected two-pass); `points` is non-empty.
fn centred_moments(points: &[Point3]) -> Result<(Point3, Matrix3), FitError> {
    let nr = points.len() as Real;
    let p0 = points
        .first()
        .ok_or(FitError::TooFewPoints { needed: 3, got: 0 })?;
    let p0 = p0.coords;

    // Pass 1: mean relative to the first point.
    let sum_d = chunked_sum(
        points,
        |c| c.iter().fold(Vector3::zeros(), |s, p| s + (p.coords - p0)),
        Vector3::zeros(),
        |a, b| a + b,
    );
    let c1 = p0 + sum_d / nr;

    // Pass 2: moments about c1, corrected for the residual mean.
    let mo = chunked_sum(
        points,
        |c| Moments::of(c, &c1),
        Moments::default(),
        |a, b| a.add(b),
    );
    let s = Vector3::new(mo.s[0], mo.s[1], mo.s[2]);
    let centroid = Point3::from(c1 + s / nr);
    let m = &mo.m;
    let cov = Matrix3::new(
        m[0], m[1], m[2], //
        m[1], m[3], m[4], //
        m[2], m[4], m[5],
    ) - s * s.transpose() / nr;
    Ok((centroid, cov))
}

/// `v` flipped if needed so that its largest-magnitude component is positive (the first of
/// x, y, z on a tie).
fn canonical_sign(v: Vector3) -> Vector3 {
    let mut k_big = 0;
    for k in 1..3 {
        if v[k].abs() > v[k_big].abs() {
            k_big = k;
        }
    }
    if v[k_big] < 0.0 { -v } else { v }
}

/// The fit proper; `points` has at least 3 entries, all finite.
fn fit_checked(points: &[Point3]) -> Result<PlaneFit, FitError> {
    let n = points.len();
    let nr = n as Real;
    let (centroid, cov) = centred_moments(points)?;
    if !cov.iter().all(|v| v.is_finite()) {
        return Err(FitError::Degenerate);
    }
    let eig = SymmetricEigen::try_new(cov, Real::EPSILON, EIGEN_ITERATIONS)
        .ok_or(FitError::Degenerate)?;
    let mut order = [0usize, 1, 2];
    order.sort_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]));
    let [i_min, i_mid, i_max] = order;
    let (l_mid, l_max) = (eig.eigenvalues[i_mid], eig.eigenvalues[i_max]);
    let spans_plane = l_max > 0.0 && l_mid > DEGENERATE_RATIO * l_max;
    if !spans_plane {
        return Err(FitError::Degenerate);
    }
    let normal = canonical_sign(eig.eigenvectors.column(i_min).into_owned());
    let normal = UnitVector3::try_new(normal, 0.0).ok_or(FitError::Degenerate)?;
    let plane = Plane::through(&centroid, normal);

    // Pass 3: residuals.
    let (ss, max_abs) = chunked_sum(
        points,
        |c| {
            c.iter().fold((0.0, 0.0), |(s, m): (Real, Real), p| {
                let r = normal.dot(&(p - centroid));
                (s + r * r, m.max(r.abs()))
            })
        },
        (0.0, 0.0),
        |(s, m), (ps, pm)| (s + ps, m.max(*pm)),
    );
    let rms_mm = (ss / nr).sqrt();
    let (offset_sigma_mm, tilt_sigma_rad) = if n > 3 {
        let sigma = (ss / (n - 3) as Real).sqrt();
        (
            sigma / nr.sqrt(),
            [sigma / l_max.sqrt(), sigma / l_mid.sqrt()],
        )
    } else {
        (Real::INFINITY, [Real::INFINITY; 2])
    };
    Ok(PlaneFit {
        plane,
        centroid,
        n_used: n,
        n_rejected: 0,
        rms_mm,
        max_abs_mm: max_abs,
        offset_sigma_mm,
        tilt_sigma_rad,
    })
}

/// Plane fit with iterative outlier rejection (see [`RobustRule`]).
///
/// Errors as [`fit_plane`] on the full set; once an initial fit exists it never fails.
/// `n_used + n_rejected == points.len()`.
pub fn fit_plane_robust(points: &[Point3], rule: &RobustRule) -> Result<PlaneFit, FitError> {
    let fit = fit_plane(points)?;
    Ok(trim_and_refit(points, rule, fit, |subset, _| {
        fit_checked(subset)
    }))
}

// ---------------------------------------------------------------------------------------
// Outlier rejection shared by all shapes.

/// What the trim-and-refit loop needs of a fit.
trait Trimmable: Sized + Sync {
    /// Fewest points a refit accepts.
    const MIN_POINTS: usize;
    /// RMS residual of the used points (mm).
    fn rms(&self) -> Real;
    /// Orthogonal distance of `p` from the fitted shape (mm, ≥ 0).
    fn distance(&self, p: &Point3) -> Real;
    /// Points used in the fit.
    fn n_used(&self) -> usize;
    /// Records the number of rejected input points.
    fn set_rejected(&mut self, n: usize);
}

/// The [`RobustRule`] loop: drop points farther than k·rms from the current fit, refit the
/// rest with `refit(subset, previous)`, until the kept set stops changing, the rule's
/// iteration cap is reached, or a refit fails (then the previous fit stands).
fn trim_and_refit<F, R>(points: &[Point3], rule: &RobustRule, mut fit: F, refit: R) -> F
where
    F: Trimmable,
    R: Fn(&[Point3], &F) -> Result<F, FitError>,
{
    let mut keep = vec![true; points.len()];
    for _ in 0..rule.max_iterations {
        let threshold = (rule.k_sigma * fit.rms()).max(tol::LENGTH_EPS);
        let current = &fit;
        let new_keep: Vec<bool> = points
            .par_iter()
            .map(|p| current.distance(p) <= threshold)
            .collect();
        if new_keep == keep {
            break;
        }
        let subset: Vec<Point3> = points
            .iter()
            .zip(&new_keep)
            .filter_map(|(p, &k)| k.then_some(*p))
            .collect();
        if subset.len() < F::MIN_POINTS {
            break;
        }
        match refit(&subset, &fit) {
            Ok(f) => {
                fit = f;
                keep = new_keep;
            }
            Err(_) => break,
        }
    }
    let rejected = points.len() - fit.n_used();
    fit.set_rejected(rejected);
    fit
}

impl Trimmable for PlaneFit {
    const MIN_POINTS: usize = PLANE_MIN_POINTS;
    fn rms(&self) -> Real {
        self.rms_mm
    }
    fn distance(&self, p: &Point3) -> Real {
        self.plane.normal.dot(&(p - self.centroid)).abs()
    }
    fn n_used(&self) -> usize {
        self.n_used
    }
    fn set_rejected(&mut self, n: usize) {
        self.n_rejected = n;
    }
}

// ---------------------------------------------------------------------------------------
// Levenberg–Marquardt on accumulated normal equations.

/// Running sums of the normal equations over a chunk: the upper triangle of JᵀJ (plain
/// arrays, so the per-point update unrolls to P(P+1)/2 multiply-adds), Jᵀr and the
/// residual sums.
#[derive(Clone, Copy, Debug)]
struct Sums<const P: usize> {
    jtj: [[Real; P]; P],
    jtr: [Real; P],
    ss: Real,
    max_abs: Real,
}

impl<const P: usize> Sums<P> {
    fn zero() -> Self {
        Self {
            jtj: [[0.0; P]; P],
            jtr: [0.0; P],
            ss: 0.0,
            max_abs: 0.0,
        }
    }

    /// Adds one residual `r` with Jacobian row `j`.
    #[inline(always)]
    fn push(&mut self, j: &[Real; P], r: Real) {
        for (a, ((row, g), &ja)) in self.jtj.iter_mut().zip(&mut self.jtr).zip(j).enumerate() {
            *g += ja * r;
            for (h, &jb) in row.iter_mut().zip(j).skip(a) {
                *h += ja * jb;
            }
        }
        self.ss += r * r;
    }

    /// The chunk's sums as normal equations (JᵀJ symmetrised).
    fn normal(&self) -> Normal<P> {
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
struct Normal<const P: usize> {
    jtj: SMatrix<Real, P, P>,
    jtr: SVector<Real, P>,
    /// Σ r² over all residuals.
    ss: Real,
    /// Largest distance of a point from the shape.
    max_abs: Real,
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
trait Model<const P: usize>: Copy + Send + Sync {
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
struct Scaled<const P: usize> {
    hs: SMatrix<Real, P, P>,
    gs: SVector<Real, P>,
    dinv: SVector<Real, P>,
}

impl<const P: usize> Scaled<P> {
    /// None if a diagonal entry of JᵀJ is zero or anything is non-finite.
    fn new(ne: &Normal<P>) -> Option<Self> {
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
    fn step(&self, lambda: Real) -> Option<SVector<Real, P>> {
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
fn rank_deficient<const P: usize>(jtj: &SMatrix<Real, P, P>, to_length: &SVector<Real, P>) -> bool {
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
struct Solved<M, const P: usize> {
    model: M,
    normal: Normal<P>,
    iterations: usize,
    /// σ²·(JᵀJ)⁻¹ in the model's local parameters; None when there are no more residuals
    /// than parameters (all uncertainties infinite).
    covariance: Option<SMatrix<Real, P, P>>,
    /// Number of points.
    n: usize,
}

impl<M, const P: usize> Solved<M, P> {
    fn rms(&self) -> Real {
        (self.normal.ss / self.n as Real).sqrt()
    }

    /// Standard uncertainty of local parameter k.
    fn sigma(&self, k: usize) -> Real {
        self.covariance
            .map_or(Real::INFINITY, |c| c[(k, k)].max(0.0).sqrt())
    }

    /// Root of the largest and smallest eigenvalue of the 2×2 covariance block at (k, k).
    fn sigma_pair(&self, k: usize) -> [Real; 2] {
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
fn levenberg_marquardt<const P: usize, M: Model<P>>(
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

// ---------------------------------------------------------------------------------------
// Geometry helpers and closed-form starting values.

/// Orthonormal (e1, e2) with e1 × e2 = n: e1 ⟂ n built from the coordinate axis of n's
/// smallest component (|n × e| ≥ √(2/3), never ill-conditioned).
fn tangent_basis(n: &UnitVector3) -> (Vector3, Vector3) {
    let mut e = Vector3::zeros();
    e[n.iamin()] = 1.0;
    let e1 = n.cross(&e).normalize();
    (e1, n.cross(&e1))
}

/// `n` rotated by the rotation vector `w` (⟂ n): n cos|w| + ŵ sin|w|.
fn rotate(n: &UnitVector3, w: &Vector3) -> UnitVector3 {
    let angle = w.norm();
    if angle == 0.0 {
        return *n;
    }
    UnitVector3::new_normalize(n.into_inner() * angle.cos() + w * (angle.sin() / angle))
}

/// Centroid, principal axes and RMS spread of a point set.
struct Spread {
    centroid: Point3,
    /// Eigenvalues of the centred second-moment sum, ascending.
    values: [Real; 3],
    /// The matching unit eigenvectors.
    axes: [UnitVector3; 3],
    /// RMS distance of the points from the centroid (mm), > 0.
    rms: Real,
}

impl Spread {
    fn of(points: &[Point3]) -> Result<Self, FitError> {
        let (centroid, cov) = centred_moments(points)?;
        if !cov.iter().all(|v| v.is_finite()) {
            return Err(FitError::Degenerate);
        }
        let eig = SymmetricEigen::try_new(cov, Real::EPSILON, EIGEN_ITERATIONS)
            .ok_or(FitError::Degenerate)?;
        let mut order = [0usize, 1, 2];
        order.sort_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]));
        let values = order.map(|i| eig.eigenvalues[i]);
        let mut axes = [UnitVector3::new_unchecked(Vector3::x()); 3];
        for (axis, &i) in axes.iter_mut().zip(&order) {
            let v = canonical_sign(eig.eigenvectors.column(i).into_owned());
            *axis = UnitVector3::try_new(v, 0.0).ok_or(FitError::Degenerate)?;
        }
        let rms = (cov.trace() / points.len() as Real).sqrt();
        if !(rms > 0.0 && rms.is_finite() && values[2] > 0.0) {
            return Err(FitError::Degenerate);
        }
        Ok(Self {
            centroid,
            values,
            axes,
            rms,
        })
    }

    /// Whether the points are collinear (or coincident) within [`DEGENERATE_RATIO`].
    fn collinear(&self) -> bool {
        self.values[1] <= DEGENERATE_RATIO * self.values[2]
    }

    /// Whether the points are coplanar within [`DEGENERATE_RATIO`].
    fn coplanar(&self) -> bool {
        self.values[0] <= DEGENERATE_RATIO * self.values[2]
    }
}

/// Solves the symmetric positive-definite `a·x = b` (unknowns of comparable units) after
/// Jacobi scaling; None if `a` is non-finite, not positive definite or rank-deficient
/// within [`RANK_RATIO`].
fn solve_spd<const N: usize>(
    a: &SMatrix<Real, N, N>,
    b: &SVector<Real, N>,
) -> Option<SVector<Real, N>> {
    let ne = Normal::<N> {
        jtj: *a,
        jtr: -b,
        ss: 0.0,
        max_abs: 0.0,
    };
    if rank_deficient(a, &SVector::repeat(1.0)) {
        return None;
    }
    Scaled::new(&ne)?.step(0.0)
}

/// The algebraic sphere x²+y²+z² + Dx + Ey + Fz + G = 0 of the points, solved in
/// coordinates centred on the centroid and scaled by the RMS spread.
fn algebraic_sphere(points: &[Point3], sp: &Spread) -> Option<SphereModel> {
    let (g, s) = (sp.centroid, sp.rms);
    let zero = (SMatrix::<Real, 4, 4>::zeros(), SVector::<Real, 4>::zeros());
    let (a, b) = chunked_sum(
        points,
        |c| {
            let (mut a, mut b) = zero;
            for p in c {
                let q = (p - g) / s;
                let z = SVector::<Real, 4>::new(q.x, q.y, q.z, 1.0);
                a.ger(1.0, &z, &z, 1.0);
                b.axpy(q.norm_squared(), &z, 1.0);
            }
            (a, b)
        },
        zero,
        |(a, b), (c, d)| (a + c, b + d),
    );
    let x = solve_spd(&a, &(-b))?;
    let cq = Vector3::new(x[0], x[1], x[2]) * -0.5;
    let r2 = cq.norm_squared() - x[3];
    let model = SphereModel {
        c: g + cq * s,
        r: r2.sqrt() * s,
    };
    (r2 > 0.0 && model.r.is_finite()).then_some(model)
}

/// The algebraic (Kåsa) circles x²+y² + Dx + Ey + F = 0 of the points projected on the
/// planes through the centroid with unit normals `ws` (one pass for all K), in
/// coordinates scaled by the RMS spread. Each: the centre (in that plane) and the radius,
/// None if the projected points are collinear.
fn kasa_circles<const K: usize>(
    points: &[Point3],
    sp: &Spread,
    ws: &[UnitVector3; K],
) -> [Option<(Point3, Real)>; K] {
    let (g, s) = (sp.centroid, sp.rms);
    let bases = ws.map(|w| tangent_basis(&w));
    let zero = [(SMatrix::<Real, 3, 3>::zeros(), SVector::<Real, 3>::zeros()); K];
    let sums = chunked_sum(
        points,
        |c| {
            let mut acc = [Sums::<3>::zero(); K];
            for p in c {
                let d = (p - g) / s;
                for (a, (u, v)) in acc.iter_mut().zip(&bases) {
                    let (x, y) = (u.dot(&d), v.dot(&d));
                    a.push(&[x, y, 1.0], x * x + y * y);
                }
            }
            acc.map(|a| {
                let n = a.normal();
                (n.jtj, n.jtr)
            })
        },
        zero,
        |mut t, o| {
            for (a, b) in t.iter_mut().zip(o) {
                a.0 += b.0;
                a.1 += b.1;
            }
            t
        },
    );
    let mut out = [None; K];
    for ((o, (a, b)), (u, v)) in out.iter_mut().zip(&sums).zip(&bases) {
        let Some(x) = solve_spd(a, &(-b)) else {
            continue;
        };
        let (cx, cy) = (-0.5 * x[0], -0.5 * x[1]);
        let r2 = cx * cx + cy * cy - x[2];
        let centre = g + (u * cx + v * cy) * s;
        let r = r2.sqrt() * s;
        if r2 > 0.0 && r.is_finite() && centre.coords.iter().all(|c| c.is_finite()) {
            *o = Some((centre, r));
        }
    }
    out
}

/// For each candidate (centre, axis w, radius): the RMS over the points of (distance from
/// the line centre + t·w) − r; one pass for all K, +∞ for a missing candidate.
fn line_circle_rms<const K: usize>(
    points: &[Point3],
    ws: &[UnitVector3; K],
    circles: &[Option<(Point3, Real)>; K],
) -> [Real; K] {
    let ss = chunked_sum(
        points,
        |c| {
            let mut acc = [0.0; K];
            for p in c {
                for ((a, w), circle) in acc.iter_mut().zip(ws).zip(circles) {
                    if let Some((centre, r)) = circle {
                        let d = p - centre;
                        let res = (d - w.into_inner() * w.dot(&d)).norm() - r;
                        *a += res * res;
                    }
                }
            }
            acc
        },
        [0.0; K],
        |mut t, o| {
            for (a, b) in t.iter_mut().zip(o) {
                *a += b;
            }
            t
        },
    );
    let mut out = [Real::INFINITY; K];
    for ((o, s), circle) in out.iter_mut().zip(ss).zip(circles) {
        if circle.is_some() {
            *o = (s / points.len() as Real).sqrt();
        }
    }
    out
}

/// The best cylinder start among candidate axes `ws`: smallest RMS of the Kåsa circle of
/// the points projected along the axis.
fn best_axis<const K: usize>(
    points: &[Point3],
    sp: &Spread,
    ws: &[UnitVector3; K],
) -> Option<CylinderModel> {
    let circles = kasa_circles(points, sp, ws);
    let rms = line_circle_rms(points, ws, &circles);
    let mut best: Option<(Real, CylinderModel)> = None;
    for ((w, circle), e) in ws.iter().zip(&circles).zip(rms) {
        if let Some((c, r)) = circle
            && e.is_finite()
            && best.is_none_or(|(b, _)| e < b)
        {
            best = Some((e, CylinderModel::new(*c, *w, *r, sp.centroid)));
        }
    }
    best.map(|(_, m)| m)
}

// ---------------------------------------------------------------------------------------
// Sphere.

/// Result of a sphere fit. Standard uncertainties from the residuals: σ² (JᵀJ)⁻¹ with
/// σ² = Σr²/(m − p) (m = n residuals, p = 4 parameters); infinite when n = 4.
#[derive(Clone, Debug, PartialEq)]
pub struct SphereFit {
    /// Centre (mm).
    pub centre: Point3,
    /// Radius (mm).
    pub radius: Real,
    /// Standard uncertainty of the centre's x, y, z (mm).
    pub centre_sigma_mm: [Real; 3],
    /// Standard uncertainty of the radius (mm).
    pub radius_sigma_mm: Real,
    /// RMS of the residuals |p − c| − r of the used points (mm), divided by n.
    pub rms_mm: Real,
    /// Largest |residual| of the used points (mm).
    pub max_abs_mm: Real,
    /// Number of points in the final fit.
    pub n_used: usize,
    /// Number of input points rejected as outliers (0 for [`fit_sphere`]).
    pub n_rejected: usize,
    /// Levenberg–Marquardt iterations (accepted steps) of the final fit.
    pub iterations: usize,
}

/// Sphere state: parameters centre (3, additive) and radius.
#[derive(Clone, Copy, Debug)]
struct SphereModel {
    c: Point3,
    r: Real,
}

impl Model<4> for SphereModel {
    const RESIDUALS_PER_POINT: usize = 1;

    #[inline]
    fn accumulate(&self, p: &Point3, acc: &mut Sums<4>) {
        let d = p - self.c;
        let rho = d.norm();
        let u = if rho > 0.0 {
            d * rho.recip()
        } else {
            Vector3::zeros()
        };
        let res = rho - self.r;
        acc.push(&[-u.x, -u.y, -u.z, -1.0], res);
        acc.max_abs = acc.max_abs.max(res.abs());
    }

    fn step(&self, delta: &SVector<Real, 4>) -> Self {
        Self {
            c: self.c + delta.fixed_rows::<3>(0),
            r: self.r + delta[3],
        }
    }

    fn to_length(_scale: Real) -> SVector<Real, 4> {
        SVector::repeat(1.0)
    }
}

/// Orthogonal least-squares sphere: minimises Σ(|pᵢ − c| − r)².
///
/// Needs at least 4 finite, non-coplanar points. Starts from the algebraic fit and
/// refines by Levenberg–Marquardt. Deterministic and bit-identical for any thread count.
pub fn fit_sphere(points: &[Point3]) -> Result<SphereFit, FitError> {
    check_input(points, SPHERE_MIN_POINTS)?;
    sphere_checked(points, None)
}

/// Sphere fit with iterative outlier rejection (see [`RobustRule`]); each refit starts from
/// the previous fit.
///
/// Errors as [`fit_sphere`] on the full set; once an initial fit exists it never fails.
/// `n_used + n_rejected == points.len()`.
pub fn fit_sphere_robust(points: &[Point3], rule: &RobustRule) -> Result<SphereFit, FitError> {
    let fit = fit_sphere(points)?;
    Ok(trim_and_refit(points, rule, fit, |subset, prev| {
        sphere_checked(subset, Some(prev))
    }))
}

/// The sphere fit proper; points finite and at least 4.
fn sphere_checked(points: &[Point3], warm: Option<&SphereFit>) -> Result<SphereFit, FitError> {
    let sp = Spread::of(points)?;
    if sp.coplanar() {
        return Err(FitError::Degenerate);
    }
    let start = match warm {
        Some(f) => SphereModel {
            c: f.centre,
            r: f.radius,
        },
        None => algebraic_sphere(points, &sp).ok_or(FitError::Degenerate)?,
    };
    let sol = levenberg_marquardt(points, start, sp.rms)?;
    let m = sol.model;
    if !(m.r > 0.0 && m.r.is_finite()) {
        return Err(FitError::Degenerate);
    }
    Ok(SphereFit {
        centre: m.c,
        radius: m.r,
        centre_sigma_mm: [sol.sigma(0), sol.sigma(1), sol.sigma(2)],
        radius_sigma_mm: sol.sigma(3),
        rms_mm: sol.rms(),
        max_abs_mm: sol.normal.max_abs,
        n_used: points.len(),
        n_rejected: 0,
        iterations: sol.iterations,
    })
}

impl Trimmable for SphereFit {
    const MIN_POINTS: usize = SPHERE_MIN_POINTS;
    fn rms(&self) -> Real {
        self.rms_mm
    }
    fn distance(&self, p: &Point3) -> Real {
        ((p - self.centre).norm() - self.radius).abs()
    }
    fn n_used(&self) -> usize {
        self.n_used
    }
    fn set_rejected(&mut self, n: usize) {
        self.n_rejected = n;
    }
}

// ---------------------------------------------------------------------------------------
// Circle in 3-D.

/// Result of a circle fit. Standard uncertainties from the residuals: σ² (JᵀJ)⁻¹ with
/// σ² = Σr²/(m − p) (m = 2n residuals: out-of-plane and in-plane radial; p = 6
/// parameters); infinite when n = 3.
#[derive(Clone, Debug, PartialEq)]
pub struct CircleFit {
    /// Centre (mm).
    pub centre: Point3,
    /// Unit normal of the circle's plane, oriented so that its largest-magnitude component
    /// is positive (the first of x, y, z on a tie).
    pub normal: UnitVector3,
    /// Radius (mm).
    pub radius: Real,
    /// Standard uncertainty of the centre's x, y, z (mm).
    pub centre_sigma_mm: [Real; 3],
    /// Standard uncertainty of the radius (mm).
    pub radius_sigma_mm: Real,
    /// Standard uncertainty of the normal's tilt (rad) in its worst direction: the root of
    /// the largest eigenvalue of its 2×2 covariance (for a full circle both directions are
    /// equal).
    pub normal_sigma_rad: Real,
    /// RMS distance of the used points from the circle (mm), √(Σ(h² + (ρ−r)²)/n).
    pub rms_mm: Real,
    /// Largest distance of a used point from the circle (mm).
    pub max_abs_mm: Real,
    /// Number of points in the final fit.
    pub n_used: usize,
    /// Number of input points rejected as outliers (0 for [`fit_circle`]).
    pub n_rejected: usize,
    /// Levenberg–Marquardt iterations (accepted steps) of the final fit.
    pub iterations: usize,
}

/// Circle state: centre (3, additive), normal (2 tangent-plane angles), radius.
#[derive(Clone, Copy, Debug)]
struct CircleModel {
    c: Point3,
    n: UnitVector3,
    e1: Vector3,
    e2: Vector3,
    r: Real,
}

impl CircleModel {
    fn new(c: Point3, n: UnitVector3, r: Real) -> Self {
        let (e1, e2) = tangent_basis(&n);
        Self { c, n, e1, e2, r }
    }
}

impl Model<6> for CircleModel {
    const RESIDUALS_PER_POINT: usize = 2;

    #[inline]
    fn accumulate(&self, p: &Point3, acc: &mut Sums<6>) {
        let d = p - self.c;
        let h = self.n.dot(&d);
        let w = d - self.n.into_inner() * h;
        let rho = w.norm();
        let t = if rho > 0.0 {
            w * rho.recip()
        } else {
            Vector3::zeros()
        };
        let (d1, d2) = (self.e1.dot(&d), self.e2.dot(&d));
        let (t1, t2) = (self.e1.dot(&t), self.e2.dot(&t));
        let n = &self.n;
        acc.push(&[-n.x, -n.y, -n.z, d1, d2, 0.0], h);
        let b = rho - self.r;
        acc.push(&[-t.x, -t.y, -t.z, -h * t1, -h * t2, -1.0], b);
        acc.max_abs = acc.max_abs.max((h * h + b * b).sqrt());
    }

    fn step(&self, delta: &SVector<Real, 6>) -> Self {
        let n = rotate(&self.n, &(self.e1 * delta[3] + self.e2 * delta[4]));
        Self::new(self.c + delta.fixed_rows::<3>(0), n, self.r + delta[5])
    }

    fn to_length(scale: Real) -> SVector<Real, 6> {
        SVector::<Real, 6>::new(1.0, 1.0, 1.0, scale, scale, 1.0)
    }
}

/// Orthogonal least-squares circle in 3-D: minimises the sum of squared distances of the
/// points from the circle, Σ(hᵢ² + (ρᵢ − r)²) with hᵢ the height above the circle's plane
/// and ρᵢ the in-plane distance from the centre.
///
/// Needs at least 3 finite, non-collinear points. Starts from [`fit_plane`] and a Kåsa
/// circle in that plane, refines by Levenberg–Marquardt. Deterministic and bit-identical
/// for any thread count.
pub fn fit_circle(points: &[Point3]) -> Result<CircleFit, FitError> {
    check_input(points, CIRCLE_MIN_POINTS)?;
    circle_checked(points, None)
}

/// Circle fit with iterative outlier rejection (see [`RobustRule`]; the residual is the
/// point's distance from the circle); each refit starts from the previous fit.
///
/// Errors as [`fit_circle`] on the full set; once an initial fit exists it never fails.
/// `n_used + n_rejected == points.len()`.
pub fn fit_circle_robust(points: &[Point3], rule: &RobustRule) -> Result<CircleFit, FitError> {
    let fit = fit_circle(points)?;
    Ok(trim_and_refit(points, rule, fit, |subset, prev| {
        circle_checked(subset, Some(prev))
    }))
}

/// The circle fit proper; points finite and at least 3.
fn circle_checked(points: &[Point3], warm: Option<&CircleFit>) -> Result<CircleFit, FitError> {
    let sp = Spread::of(points)?;
    if sp.collinear() {
        return Err(FitError::Degenerate);
    }
    let start = match warm {
        Some(f) => CircleModel::new(f.centre, f.normal, f.radius),
        None => {
            let normal = fit_checked(points)?.plane.normal;
            let [circle] = kasa_circles(points, &sp, &[normal]);
            let (c, r) = circle.ok_or(FitError::Degenerate)?;
            CircleModel::new(c, normal, r)
        }
    };
    let sol = levenberg_marquardt(points, start, sp.rms)?;
    let m = sol.model;
    if !(m.r > 0.0 && m.r.is_finite()) {
        return Err(FitError::Degenerate);
    }
    let normal = UnitVector3::new_unchecked(canonical_sign(m.n.into_inner()));
    Ok(CircleFit {
        centre: m.c,
        normal,
        radius: m.r,
        centre_sigma_mm: [sol.sigma(0), sol.sigma(1), sol.sigma(2)],
        radius_sigma_mm: sol.sigma(5),
        normal_sigma_rad: sol.sigma_pair(3)[0],
        rms_mm: sol.rms(),
        max_abs_mm: sol.normal.max_abs,
        n_used: points.len(),
        n_rejected: 0,
        iterations: sol.iterations,
    })
}

impl Trimmable for CircleFit {
    const MIN_POINTS: usize = CIRCLE_MIN_POINTS;
    fn rms(&self) -> Real {
        self.rms_mm
    }
    fn distance(&self, p: &Point3) -> Real {
        let d = p - self.centre;
        let h = self.normal.dot(&d);
        let rho = (d - self.normal.into_inner() * h).norm();
        h.hypot(rho - self.radius)
    }
    fn n_used(&self) -> usize {
        self.n_used
    }
    fn set_rejected(&mut self, n: usize) {
        self.n_rejected = n;
    }
}

// ---------------------------------------------------------------------------------------
// Cylinder.

/// Result of a cylinder fit. Standard uncertainties from the residuals: σ² (JᵀJ)⁻¹ with
/// σ² = Σr²/(m − p) (m = n residuals, p = 5 parameters); infinite when n = 5.
#[derive(Clone, Debug, PartialEq)]
pub struct CylinderFit {
    /// The point of the axis closest to the used points' centroid (mm).
    pub axis_point: Point3,
    /// Unit axis direction, oriented so that its largest-magnitude component is positive
    /// (the first of x, y, z on a tie).
    pub axis: UnitVector3,
    /// Radius (mm).
    pub radius: Real,
    /// Standard uncertainty of `axis_point`'s x, y, z (mm), including the motion of the
    /// centroid's foot along the axis when the axis tilts.
    pub axis_point_sigma_mm: [Real; 3],
    /// Standard uncertainty of the axis's tilt (rad) about two directions perpendicular to
    /// the axis: the roots of the eigenvalues of its 2×2 covariance, largest first (equal
    /// for a full circumference).
    pub axis_sigma_rad: [Real; 2],
    /// Standard uncertainty of the radius (mm).
    pub radius_sigma_mm: Real,
    /// RMS of the residuals (distance from the axis − r) of the used points (mm), divided by n.
    pub rms_mm: Real,
    /// Largest |residual| of the used points (mm).
    pub max_abs_mm: Real,
    /// Number of points in the final fit.
    pub n_used: usize,
    /// Number of input points rejected as outliers (0 for [`fit_cylinder`]).
    pub n_rejected: usize,
    /// Levenberg–Marquardt iterations (accepted steps) of the final fit.
    pub iterations: usize,
}

/// Cylinder state: axis point (2, moved in the plane ⟂ axis), axis direction (2
/// tangent-plane angles), radius. The point is kept at the foot of `pivot` (the points'
/// centroid) on the axis, so tilts turn the axis about the middle of the data.
#[derive(Clone, Copy, Debug)]
struct CylinderModel {
    a: Point3,
    v: UnitVector3,
    e1: Vector3,
    e2: Vector3,
    r: Real,
    pivot: Point3,
}

impl CylinderModel {
    fn new(a: Point3, v: UnitVector3, r: Real, pivot: Point3) -> Self {
        let a = a + v.into_inner() * v.dot(&(pivot - a));
        let (e1, e2) = tangent_basis(&v);
        Self {
            a,
            v,
            e1,
            e2,
            r,
            pivot,
        }
    }
}

impl Model<5> for CylinderModel {
    const RESIDUALS_PER_POINT: usize = 1;

    #[inline]
    fn accumulate(&self, p: &Point3, acc: &mut Sums<5>) {
        let d = p - self.a;
        let h = self.v.dot(&d);
        // In-plane coordinates: w = d − h·v = w1·e1 + w2·e2, so t·eₖ = wₖ/ρ.
        let (w1, w2) = (self.e1.dot(&d), self.e2.dot(&d));
        let rho = (w1 * w1 + w2 * w2).sqrt();
        let inv = if rho > 0.0 { rho.recip() } else { 0.0 };
        let (t1, t2) = (w1 * inv, w2 * inv);
        let res = rho - self.r;
        acc.push(&[-t1, -t2, -h * t1, -h * t2, -1.0], res);
        acc.max_abs = acc.max_abs.max(res.abs());
    }

    fn step(&self, delta: &SVector<Real, 5>) -> Self {
        let a = self.a + self.e1 * delta[0] + self.e2 * delta[1];
        let v = rotate(&self.v, &(self.e1 * delta[2] + self.e2 * delta[3]));
        Self::new(a, v, self.r + delta[4], self.pivot)
    }

    fn to_length(scale: Real) -> SVector<Real, 5> {
        SVector::<Real, 5>::new(1.0, 1.0, scale, scale, 1.0)
    }
}

/// Orthogonal least-squares cylinder: minimises Σ(dᵢ − r)² with dᵢ the distance of point i
/// from the axis.
///
/// Needs at least 5 finite, non-collinear points. `initial_axis`, if given, is the
/// starting axis direction; otherwise each principal axis of the points' covariance is
/// tried (a Kåsa circle of the points projected along it) and the best is refined by
/// Levenberg–Marquardt. Arcs of less than about 90° are poorly conditioned: the fit
/// converges but `radius_sigma_mm` and `axis_point_sigma_mm` grow steeply. Deterministic
/// and bit-identical for any thread count.
pub fn fit_cylinder(
    points: &[Point3],
    initial_axis: Option<UnitVector3>,
) -> Result<CylinderFit, FitError> {
    check_input(points, CYLINDER_MIN_POINTS)?;
    cylinder_checked(points, initial_axis, None)
}

/// Cylinder fit with iterative outlier rejection (see [`RobustRule`]); each refit starts
/// from the previous fit.
///
/// Errors as [`fit_cylinder`] on the full set; once an initial fit exists it never fails.
/// `n_used + n_rejected == points.len()`.
pub fn fit_cylinder_robust(
    points: &[Point3],
    initial_axis: Option<UnitVector3>,
    rule: &RobustRule,
) -> Result<CylinderFit, FitError> {
    let fit = fit_cylinder(points, initial_axis)?;
    Ok(trim_and_refit(points, rule, fit, |subset, prev| {
        cylinder_checked(subset, None, Some(prev))
    }))
}

/// The cylinder fit proper; points finite and at least 5.
fn cylinder_checked(
    points: &[Point3],
    initial_axis: Option<UnitVector3>,
    warm: Option<&CylinderFit>,
) -> Result<CylinderFit, FitError> {
    let sp = Spread::of(points)?;
    if sp.collinear() {
        return Err(FitError::Degenerate);
    }
    let start = match warm {
        Some(f) => CylinderModel::new(f.axis_point, f.axis, f.radius, sp.centroid),
        None => match initial_axis {
            Some(axis) => best_axis(points, &sp, &[axis]),
            None => best_axis(points, &sp, &sp.axes),
        }
        .ok_or(FitError::Degenerate)?,
    };
    let sol = levenberg_marquardt(points, start, sp.rms)?;
    let m = sol.model;
    if !(m.r > 0.0 && m.r.is_finite()) {
        return Err(FitError::Degenerate);
    }
    // axis_point = a + δ0 e1 + δ1 e2 + ((g − a)·(δ2 e1 + δ3 e2)) v to first order.
    let axis_point_sigma_mm = match sol.covariance {
        Some(c) => {
            let off = m.pivot - m.a;
            let v = m.v.into_inner();
            let g = SMatrix::<Real, 3, 5>::from_columns(&[
                m.e1,
                m.e2,
                v * off.dot(&m.e1),
                v * off.dot(&m.e2),
                Vector3::zeros(),
            ]);
            let ca = g * c * g.transpose();
            [0, 1, 2].map(|k| ca[(k, k)].max(0.0).sqrt())
        }
        None => [Real::INFINITY; 3],
    };
    let axis = UnitVector3::new_unchecked(canonical_sign(m.v.into_inner()));
    Ok(CylinderFit {
        axis_point: m.a,
        axis,
        radius: m.r,
        axis_point_sigma_mm,
        axis_sigma_rad: sol.sigma_pair(2),
        radius_sigma_mm: sol.sigma(4),
        rms_mm: sol.rms(),
        max_abs_mm: sol.normal.max_abs,
        n_used: points.len(),
        n_rejected: 0,
        iterations: sol.iterations,
    })
}

impl Trimmable for CylinderFit {
    const MIN_POINTS: usize = CYLINDER_MIN_POINTS;
    fn rms(&self) -> Real {
        self.rms_mm
    }
    fn distance(&self, p: &Point3) -> Real {
        let d = p - self.axis_point;
        let w = d - self.axis.into_inner() * self.axis.dot(&d);
        (w.norm() - self.radius).abs()
    }
    fn n_used(&self) -> usize {
        self.n_used
    }
    fn set_rejected(&mut self, n: usize) {
        self.n_rejected = n;
    }
}

// ---------------------------------------------------------------------------------------
// Plane pairs.

/// Distance between two planes "the way seed 002 reports it": signed distance from plane `a` to plane `b` measured along a's normal through `at` (the intersection points of the line at + t·n_a with both planes), and the angle between the normals (rad, 0..π/2 after orienting b like a).
///
/// The distance is (x_b − x_a)·n_a with x_a, x_b the intersections of the line with `a`
/// and `b` ([`Plane::intersect_line`]): positive when `b` lies on the side of `a` its
/// normal points to. `None` if the line is parallel to `b` (the planes are perpendicular
/// within 1e-12) or anything is non-finite.
pub fn plane_distance_and_angle(a: &Plane, b: &Plane, at: &Point3) -> Option<(Real, Real)> {
    let n = a.normal.into_inner();
    let xa = a.intersect_line(at, &n)?;
    let xb = b.intersect_line(at, &n)?;
    let distance = (xb - xa).dot(&n);
    let nb = b.oriented_towards(&n).normal;
    let angle = n.cross(&nb).norm().atan2(n.dot(&nb));
    (distance.is_finite() && angle.is_finite()).then_some((distance, angle))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::CounterRng;
    use proptest::prelude::*;
    use std::f64::consts::{PI, TAU};

    fn unit(rng: &CounterRng, i: u64) -> UnitVector3 {
        UnitVector3::new_normalize(Vector3::new(
            rng.normal(3 * i),
            rng.normal(3 * i + 1),
            rng.normal(3 * i + 2),
        ))
    }

    /// Orthonormal in-plane axes (a, b) for normal `n`, rotated by `angle`.
    fn axes(n: &UnitVector3, angle: Real) -> (Vector3, Vector3) {
        let e = if n.x.abs() < 0.6 {
            Vector3::x()
        } else {
            Vector3::y()
        };
        let a0 = n.cross(&e).normalize();
        let b0 = n.cross(&a0);
        let a = a0 * angle.cos() + b0 * angle.sin();
        (a, n.cross(&a))
    }

    /// A plane pose: normal, offset, in-plane axes, patch centre.
    struct Pose {
        n: UnitVector3,
        offset: Real,
        a: Vector3,
        b: Vector3,
        centre: Point3,
    }

    fn pose(seed: u64) -> Pose {
        let rng = CounterRng::new(seed);
        let n = unit(&rng, 0);
        let offset = 300.0 * (2.0 * rng.uniform(10, 0) - 1.0);
        let (a, b) = axes(&n, std::f64::consts::TAU * rng.uniform(11, 0));
        let ca = 150.0 * (2.0 * rng.uniform(12, 0) - 1.0);
        let cb = 150.0 * (2.0 * rng.uniform(13, 0) - 1.0);
        let centre = Point3::from(n.into_inner() * offset + a * ca + b * cb);
        Pose {
            n,
            offset,
            a,
            b,
            centre,
        }
    }

    /// `count` points on a 40 × 20 mm patch of the pose's plane, with Gaussian noise of
    /// `noise` mm along the normal from `noise_seed`.
    fn patch(p: &Pose, count: usize, noise: Real, noise_seed: u64) -> Vec<Point3> {
        let pos = CounterRng::new(99);
        let nz = CounterRng::new(noise_seed);
        (0..count as u64)
            .map(|i| {
                let s = 40.0 * (pos.uniform(i, 0) - 0.5);
                let t = 20.0 * (pos.uniform(i, 1) - 0.5);
                p.centre + p.a * s + p.b * t + p.n.into_inner() * (noise * nz.normal(i))
            })
            .collect()
    }

    #[test]
    fn exact_planes_in_random_poses() {
        for seed in 0..24u64 {
            let p = pose(seed);
            let count = 1000 + (seed as usize * 2131) % 49_001;
            let pts = patch(&p, count, 0.0, 0);
            let fit = fit_plane(&pts).expect("fit");
            let pl = fit.plane.oriented_towards(&p.n);
            let angle = pl.normal.cross(&p.n).norm();
            assert!(angle <= 1e-12, "seed {seed}: angle {angle:e}");
            let doff = (pl.offset - p.offset).abs();
            assert!(doff <= 1e-10, "seed {seed}: offset error {doff:e}");
            assert!(fit.rms_mm < 1e-12 && fit.max_abs_mm < 1e-11);
            assert_eq!((fit.n_used, fit.n_rejected), (count, 0));
            // Deterministic orientation rule.
            let k = fit.plane.normal.iamax();
            assert!(fit.plane.normal[k] > 0.0);
        }
    }

    fn std_dev(v: &[Real]) -> Real {
        let m = v.iter().sum::<Real>() / v.len() as Real;
        (v.iter().map(|x| (x - m).powi(2)).sum::<Real>() / (v.len() - 1) as Real).sqrt()
    }

    #[test]
    fn uncertainties_match_monte_carlo() {
        let p = pose(7);
        let (trials, count, noise) = (200u64, 2000, 0.025);
        let (mut off, mut ta, mut tb) = (vec![], vec![], vec![]);
        let (mut s_off, mut s_ta, mut s_tb) = (0.0, 0.0, 0.0);
        for t in 0..trials {
            let pts = patch(&p, count, noise, 1000 + t);
            let fit = fit_plane(&pts).expect("fit");
            let pl = fit.plane.oriented_towards(&p.n);
            off.push(p.n.dot(&fit.centroid.coords) - p.offset);
            ta.push(pl.normal.dot(&p.a));
            tb.push(pl.normal.dot(&p.b));
            s_off += fit.offset_sigma_mm / trials as Real;
            s_ta += fit.tilt_sigma_rad[0] / trials as Real;
            s_tb += fit.tilt_sigma_rad[1] / trials as Real;
        }
        for (name, obs, pred) in [
            ("offset", std_dev(&off), s_off),
            ("tilt major", std_dev(&ta), s_ta),
            ("tilt minor", std_dev(&tb), s_tb),
        ] {
            let ratio = obs / pred;
            assert!(
                (0.8..=1.2).contains(&ratio),
                "{name}: observed {obs:e} predicted {pred:e}"
            );
        }
    }

    #[test]
    fn robust_fit_rejects_gross_outliers() {
        let p = pose(3);
        let count = 20_000;
        let clean = patch(&p, count, 0.025, 5);
        let rng = CounterRng::new(77);
        let mut dirty = clean.clone();
        let mut n_out = 0;
        for (i, q) in dirty.iter_mut().enumerate() {
            if rng.uniform(i as u64, 0) < 0.05 {
                let sign = if rng.uniform(i as u64, 1) < 0.5 {
                    -1.0
                } else {
                    1.0
                };
                *q += p.n.into_inner() * sign;
                n_out += 1;
            }
        }
        let clean_fit = fit_plane(&clean).expect("clean");
        let plain = fit_plane(&dirty).expect("plain");
        let robust = fit_plane_robust(&dirty, &RobustRule::default()).expect("robust");
        assert!(robust.n_rejected >= n_out && robust.n_rejected < n_out + count / 100);
        assert_eq!(robust.n_used + robust.n_rejected, count);
        let pl = robust.plane.oriented_towards(&p.n);
        let e_off = (p.n.dot(&robust.centroid.coords) - p.offset).abs();
        let e_a = pl.normal.dot(&p.a).abs();
        let e_b = pl.normal.dot(&p.b).abs();
        assert!(e_off <= 3.0 * clean_fit.offset_sigma_mm, "offset {e_off:e}");
        assert!(e_a <= 3.0 * clean_fit.tilt_sigma_rad[0], "tilt a {e_a:e}");
        assert!(e_b <= 3.0 * clean_fit.tilt_sigma_rad[1], "tilt b {e_b:e}");
        assert!(robust.rms_mm < 0.03 && plain.rms_mm > 0.15);
        // Clean exact data lose nothing.
        let exact = patch(&p, 500, 0.0, 0);
        let f = fit_plane_robust(&exact, &RobustRule::default()).expect("exact");
        assert_eq!(f.n_rejected, 0);
    }

    #[test]
    fn error_cases() {
        let dir = Vector3::new(0.3, -0.7, 0.2);
        let line: Vec<Point3> = (0..100)
            .map(|i| Point3::new(120.0, 40.0, -80.0) + dir * (i as Real * 0.37))
            .collect();
        assert_eq!(fit_plane(&line), Err(FitError::Degenerate));
        assert_eq!(
            fit_plane(&[Point3::new(1.0, 2.0, 3.0); 10]),
            Err(FitError::Degenerate)
        );
        let mut pts = patch(&pose(1), 10, 0.0, 0);
        pts[4].y = Real::NAN;
        assert_eq!(fit_plane(&pts), Err(FitError::NonFinite { index: 4 }));
        assert_eq!(
            fit_plane_robust(&pts, &RobustRule::default()),
            Err(FitError::NonFinite { index: 4 })
        );
        assert_eq!(
            fit_plane(&pts[..2]),
            Err(FitError::TooFewPoints { needed: 3, got: 2 })
        );
        assert_eq!(
            fit_plane(&[]),
            Err(FitError::TooFewPoints { needed: 3, got: 0 })
        );
        let huge = [
            Point3::new(1e300, 0.0, 0.0),
            Point3::new(-1e300, 1e300, 0.0),
            Point3::new(0.0, -1e300, 0.0),
        ];
        assert_eq!(fit_plane(&huge), Err(FitError::Degenerate));
        let three = fit_plane(&pts[5..8]).expect("three points");
        assert!(three.offset_sigma_mm.is_infinite());
    }

    #[test]
    fn bit_identical_across_thread_counts() {
        let pts = patch(&pose(11), 100_000, 0.025, 8);
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("pool");
            pool.install(|| {
                (
                    fit_plane(&pts).expect("fit"),
                    fit_plane_robust(&pts, &RobustRule::default()).expect("robust"),
                )
            })
        };
        let one = run(1);
        for threads in [2, 3, 8] {
            let other = run(threads);
            assert_eq!(one, other, "{threads} threads");
            let bits = |f: &PlaneFit| {
                [
                    f.plane.normal.x.to_bits(),
                    f.plane.normal.y.to_bits(),
                    f.plane.normal.z.to_bits(),
                    f.plane.offset.to_bits(),
                    f.rms_mm.to_bits(),
                    f.offset_sigma_mm.to_bits(),
                ]
            };
            assert_eq!(bits(&one.0), bits(&other.0));
            assert_eq!(bits(&one.1), bits(&other.1));
        }
    }

    #[test]
    fn plane_geometry() {
        let n = UnitVector3::new_normalize(Vector3::new(0.0, 0.0, 2.0));
        let pl = Plane::through(&Point3::new(5.0, 6.0, 10.0), n);
        assert_eq!(pl.offset, 10.0);
        assert_eq!(pl.signed_distance(&Point3::new(1.0, 2.0, 12.5)), 2.5);
        assert_eq!(
            pl.project(&Point3::new(1.0, 2.0, 12.5)),
            Point3::new(1.0, 2.0, 10.0)
        );
        let x = pl
            .intersect_line(&Point3::new(1.0, 1.0, 0.0), &Vector3::new(1.0, 0.0, 2.0))
            .expect("hit");
        assert_eq!(x, Point3::new(6.0, 1.0, 10.0));
        assert!(
            pl.intersect_line(&Point3::origin(), &Vector3::new(1.0, 1.0, 1e-13))
                .is_none()
        );
        assert!(
            pl.intersect_line(&Point3::origin(), &Vector3::zeros())
                .is_none()
        );
        let down = pl.oriented_towards(&-Vector3::z());
        assert_eq!(down.normal.z, -1.0);
        assert_eq!(down.offset, -10.0);
        assert_eq!(down.signed_distance(&Point3::new(0.0, 0.0, 12.5)), -2.5);
        assert_eq!(pl.oriented_towards(&Vector3::z()), pl);
    }

    // ---------------------------------------------------------------------------------
    // Spheres, circles, cylinders.

    /// A random pose: centre up to 300 mm from the origin, axis (sphere cap / circle normal
    /// / cylinder axis), perpendicular basis, radius 1–50 mm.
    struct Shape {
        centre: Point3,
        axis: UnitVector3,
        a: Vector3,
        b: Vector3,
        radius: Real,
    }

    fn shape(seed: u64) -> Shape {
        let rng = CounterRng::new(1_000 + seed);
        let axis = unit(&rng, 0);
        let centre = Point3::from(unit(&rng, 1).into_inner() * (300.0 * rng.uniform(10, 0)));
        let radius = 1.0 + 49.0 * rng.uniform(11, 0);
        let (a, b) = axes(&axis, TAU * rng.uniform(12, 0));
        Shape {
            centre,
            axis,
            a,
            b,
            radius,
        }
    }

    impl Shape {
        fn with_radius(mut self, r: Real) -> Self {
            self.radius = r;
            self
        }

        /// Unit radial direction at azimuth `phi`, polar angle `theta` from the axis.
        fn dir(&self, theta: Real, phi: Real) -> Vector3 {
            self.axis.into_inner() * theta.cos()
                + (self.a * phi.cos() + self.b * phi.sin()) * theta.sin()
        }

        /// Points on a cap of polar half-angle `cap` (π: the full sphere), area-uniform,
        /// with Gaussian noise `noise` along the normal.
        fn sphere(&self, count: usize, cap: Real, noise: Real, noise_seed: u64) -> Vec<Point3> {
            let pos = CounterRng::new(42);
            let nz = CounterRng::new(noise_seed);
            (0..count as u64)
                .map(|i| {
                    let cos_t = 1.0 - (1.0 - cap.cos()) * pos.uniform(i, 0);
                    let u = self.dir(cos_t.clamp(-1.0, 1.0).acos(), TAU * pos.uniform(i, 1));
                    self.centre + u * (self.radius + noise * nz.normal(i))
                })
                .collect()
        }

        /// Points on an arc of `arc` rad of the circle (centre, normal = axis), with
        /// Gaussian noise `noise` both in-plane radially and along the normal.
        fn circle(&self, count: usize, arc: Real, noise: Real, noise_seed: u64) -> Vec<Point3> {
            let pos = CounterRng::new(43);
            let nz = CounterRng::new(noise_seed);
            (0..count as u64)
                .map(|i| {
                    let u = self.dir(PI / 2.0, arc * pos.uniform(i, 0));
                    self.centre
                        + u * (self.radius + noise * nz.normal(2 * i))
                        + self.axis.into_inner() * (noise * nz.normal(2 * i + 1))
                })
                .collect()
        }

        /// Points on an arc of `arc` rad of the cylinder (axis through centre), `length`
        /// mm long, with Gaussian noise `noise` along the normal.
        fn cylinder(
            &self,
            count: usize,
            arc: Real,
            length: Real,
            noise: Real,
            noise_seed: u64,
        ) -> Vec<Point3> {
            let pos = CounterRng::new(44);
            let nz = CounterRng::new(noise_seed);
            (0..count as u64)
                .map(|i| {
                    let u = self.dir(PI / 2.0, arc * pos.uniform(i, 0));
                    let t = length * (pos.uniform(i, 1) - 0.5);
                    self.centre
                        + self.axis.into_inner() * t
                        + u * (self.radius + noise * nz.normal(i))
                })
                .collect()
        }

        /// The foot on the true axis of the centroid of `pts`.
        fn foot(&self, pts: &[Point3]) -> Point3 {
            let g = pts.iter().fold(Vector3::zeros(), |s, p| s + p.coords) / pts.len() as Real;
            let v = self.axis.into_inner();
            self.centre + v * v.dot(&(g - self.centre.coords))
        }

        /// Tilt of `n` (oriented like the axis) towards a and b (rad).
        fn tilt(&self, n: &UnitVector3) -> [Real; 2] {
            let n = if n.dot(&self.axis) < 0.0 { -*n } else { *n };
            [n.dot(&self.a), n.dot(&self.b)]
        }
    }

    fn angle(u: &UnitVector3, v: &UnitVector3) -> Real {
        u.cross(v).norm()
    }

    /// Arc for exact-data case `seed`: every third full, else 120°–360°.
    fn arc_for(seed: u64) -> Real {
        if seed.is_multiple_of(3) {
            TAU
        } else {
            TAU / 3.0 + (TAU - TAU / 3.0) * CounterRng::new(seed).uniform(0, 5)
        }
    }

    const EXACT_REL: Real = 1e-9;

    #[test]
    fn exact_spheres_in_random_poses() {
        for seed in 0..24u64 {
            let s = shape(seed);
            let cap = arc_for(seed) / 2.0;
            let count = 4 + (seed as usize * 2131) % 12_000;
            let pts = s.sphere(count, cap, 0.0, 0);
            let fit = fit_sphere(&pts).unwrap_or_else(|e| panic!("seed {seed}: {e}"));
            let r = s.radius;
            let dc = (fit.centre - s.centre).norm() / r;
            let dr = (fit.radius - r).abs() / r;
            assert!(
                dc <= EXACT_REL && dr <= EXACT_REL,
                "seed {seed}: {dc:e} {dr:e}"
            );
            assert!(fit.rms_mm <= 1e-11 * r && fit.max_abs_mm <= 1e-10 * r);
            assert_eq!((fit.n_used, fit.n_rejected), (count, 0));
            assert!(
                fit.iterations <= 3,
                "seed {seed}: {} iterations",
                fit.iterations
            );
            if count == 4 {
                assert!(fit.radius_sigma_mm.is_infinite());
            }
        }
    }

    #[test]
    fn exact_circles_in_random_poses() {
        for seed in 0..24u64 {
            let s = shape(seed);
            let count = 3 + (seed as usize * 2131) % 12_000;
            let pts = s.circle(count, arc_for(seed), 0.0, 0);
            let fit = fit_circle(&pts).unwrap_or_else(|e| panic!("seed {seed}: {e}"));
            let r = s.radius;
            let dc = (fit.centre - s.centre).norm() / r;
            let dr = (fit.radius - r).abs() / r;
            let dn = angle(&fit.normal, &s.axis);
            assert!(
                dc <= EXACT_REL && dr <= EXACT_REL && dn <= EXACT_REL,
                "seed {seed}: {dc:e} {dr:e} {dn:e}"
            );
            assert!(fit.rms_mm <= 1e-11 * r && fit.max_abs_mm <= 1e-10 * r);
            assert!(fit.normal[fit.normal.iamax()] > 0.0);
            assert_eq!((fit.n_used, fit.n_rejected), (count, 0));
        }
    }

    #[test]
    fn exact_cylinders_in_random_poses() {
        for seed in 0..24u64 {
            let s = shape(seed);
            let length = s.radius * (0.5 + 4.0 * CounterRng::new(seed).uniform(1, 7));
            // Five points admit up to six cylinders: exact recovery needs more.
            let count = 50 + (seed as usize * 2131) % 12_000;
            let pts = s.cylinder(count, arc_for(seed), length, 0.0, 0);
            // Every other case with a caller's starting axis 0.05 rad off the truth.
            let initial = (seed % 2 == 1).then(|| rotate(&s.axis, &(s.a * 0.05)));
            let fit = fit_cylinder(&pts, initial).unwrap_or_else(|e| panic!("seed {seed}: {e}"));
            let r = s.radius;
            let dp = (fit.axis_point - s.foot(&pts)).norm() / r;
            let dr = (fit.radius - r).abs() / r;
            let dv = angle(&fit.axis, &s.axis);
            assert!(
                dp <= EXACT_REL && dr <= EXACT_REL && dv <= EXACT_REL,
                "seed {seed}: {dp:e} {dr:e} {dv:e}"
            );
            assert!(fit.rms_mm <= 1e-11 * r && fit.max_abs_mm <= 1e-10 * r);
            assert!(fit.axis[fit.axis.iamax()] > 0.0);
            assert_eq!((fit.n_used, fit.n_rejected), (count, 0));
        }
    }

    /// Monte Carlo summary of one scalar: errors against the truth and reported σ.
    #[derive(Default)]
    struct Tally {
        err: Vec<Real>,
        sigma: Vec<Real>,
    }

    impl Tally {
        fn push(&mut self, err: Real, sigma: Real) {
            self.err.push(err);
            self.sigma.push(sigma);
        }

        /// Unbiased within 3 standard errors; observed spread within 20 % of the mean σ.
        fn check(&self, name: &str) {
            let n = self.err.len() as Real;
            let mean = self.err.iter().sum::<Real>() / n;
            let sd = std_dev(&self.err);
            let pred = self.sigma.iter().sum::<Real>() / n;
            assert!(
                mean.abs() < 3.0 * sd / n.sqrt(),
                "{name}: bias {mean:e}, std {sd:e}"
            );
            let ratio = sd / pred;
            assert!(
                (0.8..=1.2).contains(&ratio),
                "{name}: observed {sd:e} predicted {pred:e}"
            );
        }
    }

    /// Tilt pairs: unbiased per component; the roots of the observed 2×2 covariance's
    /// eigenvalues within 20 % of the reported (largest-first) σ pair (`pred[1]` NaN: only
    /// the largest is reported).
    fn check_tilts(name: &str, tilts: &[[Real; 2]], pred: [Real; 2]) {
        let n = tilts.len() as Real;
        let col = |k: usize| tilts.iter().map(|t| t[k]).collect::<Vec<_>>();
        let (x, y) = (col(0), col(1));
        for (c, v) in [("a", &x), ("b", &y)] {
            let mean = v.iter().sum::<Real>() / n;
            let sd = std_dev(v);
            assert!(
                mean.abs() < 3.0 * sd / n.sqrt(),
                "{name} tilt {c}: bias {mean:e}, std {sd:e}"
            );
        }
        let (mx, my) = (x.iter().sum::<Real>() / n, y.iter().sum::<Real>() / n);
        let cxx = x.iter().map(|v| (v - mx).powi(2)).sum::<Real>() / (n - 1.0);
        let cyy = y.iter().map(|v| (v - my).powi(2)).sum::<Real>() / (n - 1.0);
        let cxy = x
            .iter()
            .zip(&y)
            .map(|(a, b)| (a - mx) * (b - my))
            .sum::<Real>()
            / (n - 1.0);
        let (mean, half) = (0.5 * (cxx + cyy), (0.5 * (cxx - cyy)).hypot(cxy));
        let obs = [(mean + half).sqrt(), (mean - half).sqrt()];
        for k in 0..2 {
            if pred[k].is_nan() {
                continue;
            }
            let ratio = obs[k] / pred[k];
            assert!(
                (0.8..=1.2).contains(&ratio),
                "{name} tilt σ{k}: observed {:e} predicted {:e}",
                obs[k],
                pred[k]
            );
        }
    }

    const TRIALS: u64 = 200;
    const NOISE: Real = 0.025;

    #[test]
    fn sphere_uncertainties_match_monte_carlo() {
        for (name, s, cap, count) in [
            ("full sphere", shape(101).with_radius(10.0), PI, 400),
            ("120° cap", shape(102).with_radius(25.0), PI / 3.0, 1000),
        ] {
            let mut t: [Tally; 4] = Default::default();
            for trial in 0..TRIALS {
                let pts = s.sphere(count, cap, NOISE, 10_000 + trial);
                let f = fit_sphere(&pts).expect("fit");
                for (k, tk) in t.iter_mut().take(3).enumerate() {
                    tk.push(f.centre[k] - s.centre[k], f.centre_sigma_mm[k]);
                }
                t[3].push(f.radius - s.radius, f.radius_sigma_mm);
            }
            for (k, q) in ["centre x", "centre y", "centre z", "radius"]
                .iter()
                .enumerate()
            {
                t[k].check(&format!("{name} {q}"));
            }
        }
    }

    #[test]
    fn circle_uncertainties_match_monte_carlo() {
        for (name, s, arc, count) in [
            ("full circle", shape(103).with_radius(10.0), TAU, 300),
            ("180° arc", shape(104).with_radius(20.0), PI, 400),
        ] {
            let mut t: [Tally; 4] = Default::default();
            let mut tilts = vec![];
            let mut s_tilt = 0.0;
            for trial in 0..TRIALS {
                let pts = s.circle(count, arc, NOISE, 20_000 + trial);
                let f = fit_circle(&pts).expect("fit");
                for (k, tk) in t.iter_mut().take(3).enumerate() {
                    tk.push(f.centre[k] - s.centre[k], f.centre_sigma_mm[k]);
                }
                t[3].push(f.radius - s.radius, f.radius_sigma_mm);
                tilts.push(s.tilt(&f.normal));
                s_tilt += f.normal_sigma_rad / TRIALS as Real;
            }
            for (k, q) in ["centre x", "centre y", "centre z", "radius"]
                .iter()
                .enumerate()
            {
                t[k].check(&format!("{name} {q}"));
            }
            check_tilts(name, &tilts, [s_tilt, Real::NAN]);
        }
    }

    #[test]
    fn cylinder_uncertainties_match_monte_carlo() {
        for (name, s, arc, length, count) in [
            (
                "full cylinder",
                shape(105).with_radius(10.0),
                TAU,
                40.0,
                600,
            ),
            ("180° cylinder", shape(106).with_radius(15.0), PI, 30.0, 800),
        ] {
            let mut t: [Tally; 4] = Default::default();
            let mut tilts = vec![];
            let mut s_tilt = [0.0; 2];
            for trial in 0..TRIALS {
                let pts = s.cylinder(count, arc, length, NOISE, 30_000 + trial);
                let f = fit_cylinder(&pts, None).expect("fit");
                let foot = s.foot(&pts);
                for (k, tk) in t.iter_mut().take(3).enumerate() {
                    tk.push(f.axis_point[k] - foot[k], f.axis_point_sigma_mm[k]);
                }
                t[3].push(f.radius - s.radius, f.radius_sigma_mm);
                tilts.push(s.tilt(&f.axis));
                for (acc, sigma) in s_tilt.iter_mut().zip(f.axis_sigma_rad) {
                    *acc += sigma / TRIALS as Real;
                }
            }
            for (k, q) in ["point x", "point y", "point z", "radius"]
                .iter()
                .enumerate()
            {
                t[k].check(&format!("{name} {q}"));
            }
            check_tilts(name, &tilts, s_tilt);
        }
    }

    /// Moves 5 % of the points (chosen by seed) by ±1 mm along `normal_of(p)`; returns
    /// the dirty set and the number moved.
    fn contaminate(
        clean: &[Point3],
        normal_of: impl Fn(&Point3) -> Vector3,
    ) -> (Vec<Point3>, usize) {
        let rng = CounterRng::new(77);
        let mut n_out = 0;
        let dirty = clean
            .iter()
            .enumerate()
            .map(|(i, q)| {
                if rng.uniform(i as u64, 0) < 0.05 {
                    n_out += 1;
                    let sign = if rng.uniform(i as u64, 1) < 0.5 {
                        -1.0
                    } else {
                        1.0
                    };
                    q + normal_of(q) * sign
                } else {
                    *q
                }
            })
            .collect();
        (dirty, n_out)
    }

    fn within(name: &str, err: Real, sigma: Real) {
        assert!(
            err.abs() <= 3.0 * sigma,
            "{name}: error {err:e}, σ {sigma:e}"
        );
    }

    fn check_rejections(n_rejected: usize, n_used: usize, n_out: usize, count: usize) {
        assert!(
            n_rejected >= n_out && n_rejected < n_out + count / 100,
            "{n_rejected} rejected, {n_out} outliers"
        );
        assert_eq!(n_used + n_rejected, count);
    }

    #[test]
    fn robust_sphere_rejects_gross_outliers() {
        let s = shape(201).with_radius(20.0);
        let count = 20_000;
        let clean = s.sphere(count, PI, NOISE, 5);
        let (dirty, n_out) = contaminate(&clean, |p| (p - s.centre).normalize());
        let plain = fit_sphere(&dirty).expect("plain");
        let f = fit_sphere_robust(&dirty, &RobustRule::default()).expect("robust");
        check_rejections(f.n_rejected, f.n_used, n_out, count);
        for k in 0..3 {
            within("centre", f.centre[k] - s.centre[k], f.centre_sigma_mm[k]);
        }
        within("radius", f.radius - s.radius, f.radius_sigma_mm);
        assert!(f.rms_mm < 0.03 && plain.rms_mm > 0.15);
        let exact = s.sphere(500, PI, 0.0, 0);
        let e = fit_sphere_robust(&exact, &RobustRule::default()).expect("exact");
        assert_eq!(e.n_rejected, 0);
    }

    #[test]
    fn robust_circle_rejects_gross_outliers() {
        let s = shape(202).with_radius(20.0);
        let count = 20_000;
        let clean = s.circle(count, 1.5 * PI, NOISE, 6);
        let (dirty, n_out) = contaminate(&clean, |p| {
            let d = p - s.centre;
            (d - s.axis.into_inner() * s.axis.dot(&d)).normalize()
        });
        let plain = fit_circle(&dirty).expect("plain");
        let f = fit_circle_robust(&dirty, &RobustRule::default()).expect("robust");
        check_rejections(f.n_rejected, f.n_used, n_out, count);
        for k in 0..3 {
            within("centre", f.centre[k] - s.centre[k], f.centre_sigma_mm[k]);
        }
        within("radius", f.radius - s.radius, f.radius_sigma_mm);
        let t = s.tilt(&f.normal);
        within(
            "normal",
            t[0].hypot(t[1]),
            f.normal_sigma_rad * 2.0_f64.sqrt(),
        );
        assert!(f.rms_mm < 0.05 && plain.rms_mm > 0.2);
    }

    #[test]
    fn robust_cylinder_rejects_gross_outliers() {
        let s = shape(203).with_radius(12.0);
        let count = 20_000;
        let clean = s.cylinder(count, TAU, 50.0, NOISE, 7);
        let (dirty, n_out) = contaminate(&clean, |p| {
            let d = p - s.centre;
            (d - s.axis.into_inner() * s.axis.dot(&d)).normalize()
        });
        let plain = fit_cylinder(&dirty, None).expect("plain");
        let f = fit_cylinder_robust(&dirty, None, &RobustRule::default()).expect("robust");
        check_rejections(f.n_rejected, f.n_used, n_out, count);
        // The axis point is the foot of the used points' centroid: compare its offset from
        // the true axis.
        let v = s.axis.into_inner();
        let off = f.axis_point - s.centre;
        let off = off - v * v.dot(&off);
        for k in 0..3 {
            within("axis point", off[k], f.axis_point_sigma_mm[k]);
        }
        within("radius", f.radius - s.radius, f.radius_sigma_mm);
        let t = s.tilt(&f.axis);
        within(
            "axis",
            t[0].hypot(t[1]),
            f.axis_sigma_rad[0].hypot(f.axis_sigma_rad[1]),
        );
        assert!(f.rms_mm < 0.03 && plain.rms_mm > 0.15);
    }

    #[test]
    fn shape_error_cases() {
        let s = shape(5);
        let sphere = s.sphere(50, PI, 0.0, 0);
        let circle = s.circle(50, TAU, 0.0, 0);
        let cylinder = s.cylinder(50, TAU, 30.0, 0.0, 0);
        let few = |needed, got| Some(FitError::TooFewPoints { needed, got });
        assert_eq!(fit_sphere(&sphere[..3]).err(), few(4, 3));
        assert_eq!(fit_circle(&circle[..2]).err(), few(3, 2));
        assert_eq!(fit_cylinder(&cylinder[..4], None).err(), few(5, 4));
        let rule = RobustRule::default();
        assert_eq!(fit_sphere_robust(&[], &rule).err(), few(4, 0));
        assert_eq!(fit_circle_robust(&[], &rule).err(), few(3, 0));
        assert_eq!(fit_cylinder_robust(&[], None, &rule).err(), few(5, 0));
        // Non-finite.
        let nan = |mut v: Vec<Point3>| {
            v[7].z = Real::NAN;
            v
        };
        let bad = Some(FitError::NonFinite { index: 7 });
        assert_eq!(fit_sphere(&nan(sphere.clone())).err(), bad);
        assert_eq!(fit_circle(&nan(circle.clone())).err(), bad);
        assert_eq!(fit_cylinder(&nan(cylinder.clone()), None).err(), bad);
        let mut inf = cylinder.clone();
        inf[3].x = Real::INFINITY;
        assert_eq!(
            fit_cylinder_robust(&inf, None, &rule).err(),
            Some(FitError::NonFinite { index: 3 })
        );
        // Degenerate: a sphere on coplanar points, a circle or cylinder on collinear
        // points, a cylinder on one circle, coincident points.
        assert_eq!(fit_sphere(&circle), Err(FitError::Degenerate));
        let dir = Vector3::new(0.3, -0.7, 0.2);
        let line: Vec<Point3> = (0..100)
            .map(|i| Point3::new(120.0, 40.0, -80.0) + dir * (i as Real * 0.37))
            .collect();
        assert_eq!(fit_circle(&line), Err(FitError::Degenerate));
        assert_eq!(fit_cylinder(&line, None), Err(FitError::Degenerate));
        assert_eq!(fit_cylinder(&circle, None), Err(FitError::Degenerate));
        let same = [Point3::new(1.0, 2.0, 3.0); 10];
        assert_eq!(fit_sphere(&same), Err(FitError::Degenerate));
        assert_eq!(fit_circle(&same), Err(FitError::Degenerate));
        assert_eq!(fit_cylinder(&same, None), Err(FitError::Degenerate));
        // Points on a plane have no finite best cylinder: an error, never a number.
        let rng = CounterRng::new(3);
        let flat: Vec<Point3> = (0..200)
            .map(|i| Point3::new(40.0 * rng.uniform(i, 0), 30.0 * rng.uniform(i, 1), 5.0))
            .collect();
        let r = fit_cylinder(&flat, None);
        assert!(
            matches!(r, Err(FitError::NotConverged { .. } | FitError::Degenerate)),
            "{r:?}"
        );
        let huge = [
            Point3::new(1e300, 0.0, 0.0),
            Point3::new(-1e300, 1e300, 0.0),
            Point3::new(0.0, -1e300, 0.0),
            Point3::new(0.0, 0.0, 1e300),
            Point3::new(1e300, 1e300, 1e300),
        ];
        assert_eq!(fit_sphere(&huge), Err(FitError::Degenerate));
        assert_eq!(fit_circle(&huge), Err(FitError::Degenerate));
        assert_eq!(fit_cylinder(&huge, None), Err(FitError::Degenerate));
        // Minimal sets fit exactly with infinite uncertainties.
        let c3 = fit_circle(&circle[..3]).expect("three points");
        assert!((c3.radius - s.radius).abs() <= EXACT_REL * s.radius);
        assert!(c3.radius_sigma_mm.is_infinite() && c3.normal_sigma_rad.is_infinite());
        let messages = [
            FitError::TooFewPoints { needed: 4, got: 3 }.to_string(),
            FitError::NotConverged { iterations: 100 }.to_string(),
        ];
        assert!(messages[0].contains("at least 4") && messages[1].contains("100"));
    }

    /// Every reported number of an Ok fit is finite (σ may be +∞, never NaN), the radius
    /// positive and the counts add up.
    fn sane(values: &[Real], radius: Real, used: usize, rejected: usize, len: usize) -> bool {
        values.iter().all(|v| !v.is_nan())
            && radius > 0.0
            && radius.is_finite()
            && used + rejected == len
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(192))]

        #[test]
        fn random_point_sets_never_panic(
            raw in prop::collection::vec(
                (0u8..16, -400.0..400.0f64, -400.0..400.0f64, -400.0..400.0f64),
                0..28,
            ),
            flat in any::<bool>(),
        ) {
            let mut pts: Vec<Point3> = vec![];
            for (kind, x, y, z) in raw {
                let p = match kind {
                    0 => Point3::new(x, Real::NAN, z),
                    1 => Point3::new(x, y, Real::INFINITY),
                    2 => Point3::new(x, y, z) * 1e300,
                    3 => pts.last().copied().unwrap_or(Point3::new(x, y, z)),
                    4 => Point3::new(x, y, z) * 1e-300,
                    5 => Point3::new(x, 2.0 * x, -x),
                    6 => Point3::new(x, 2.0 * x, -x) + Vector3::new(y, z, x) * 1e-9,
                    7 => Point3::new(1e8 + x * 1e-3, y * 1e-3, z),
                    _ => Point3::new(x, y, z),
                };
                pts.push(if flat { Point3::new(p.x, p.y, 0.0) } else { p });
            }
            let rule = RobustRule::default();
            let len = pts.len();
            for f in [fit_sphere(&pts), fit_sphere_robust(&pts, &rule)].into_iter().flatten() {
                let mut v = vec![f.radius_sigma_mm, f.rms_mm, f.max_abs_mm];
                v.extend(f.centre.iter().chain(&f.centre_sigma_mm));
                prop_assert!(sane(&v, f.radius, f.n_used, f.n_rejected, len));
            }
            for f in [fit_circle(&pts), fit_circle_robust(&pts, &rule)].into_iter().flatten() {
                let mut v = vec![f.radius_sigma_mm, f.normal_sigma_rad, f.rms_mm, f.max_abs_mm];
                v.extend(f.centre.iter().chain(&f.centre_sigma_mm).chain(f.normal.iter()));
                prop_assert!(sane(&v, f.radius, f.n_used, f.n_rejected, len));
            }
            for f in [fit_cylinder(&pts, None), fit_cylinder_robust(&pts, None, &rule)]
                .into_iter()
                .flatten()
            {
                let mut v = vec![f.radius_sigma_mm, f.rms_mm, f.max_abs_mm];
                v.extend(f.axis_point.iter().chain(&f.axis_point_sigma_mm));
                v.extend(f.axis.iter().chain(&f.axis_sigma_rad));
                prop_assert!(sane(&v, f.radius, f.n_used, f.n_rejected, len));
            }
        }
    }

    #[test]
    fn shape_fits_bit_identical_across_thread_counts() {
        let s = shape(11).with_radius(15.0);
        let sphere = s.sphere(100_000, 0.8 * PI, NOISE, 8);
        let circle = s.circle(100_000, 1.2 * PI, NOISE, 8);
        let (cylinder, _) = contaminate(&s.cylinder(100_000, 1.5 * PI, 60.0, NOISE, 8), |p| {
            (p - s.centre).normalize()
        });
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("pool");
            pool.install(|| {
                (
                    fit_sphere(&sphere).expect("sphere"),
                    fit_circle(&circle).expect("circle"),
                    fit_cylinder(&cylinder, None).expect("cylinder"),
                    fit_cylinder_robust(&cylinder, None, &RobustRule::default())
                        .expect("robust cylinder"),
                )
            })
        };
        let one = run(1);
        let bits = |r: &(SphereFit, CircleFit, CylinderFit, CylinderFit)| {
            let mut v = vec![
                r.0.radius,
                r.0.radius_sigma_mm,
                r.1.radius,
                r.1.normal_sigma_rad,
            ];
            v.extend(
                r.0.centre
                    .iter()
                    .chain(r.1.centre.iter())
                    .chain(r.1.normal.iter()),
            );
            for c in [&r.2, &r.3] {
                v.extend([c.radius, c.rms_mm, c.radius_sigma_mm]);
                v.extend(
                    c.axis_point
                        .iter()
                        .chain(c.axis.iter())
                        .chain(&c.axis_sigma_rad),
                );
            }
            v.into_iter().map(Real::to_bits).collect::<Vec<_>>()
        };
        for threads in [2, 3] {
            let other = run(threads);
            assert_eq!(one, other, "{threads} threads");
            assert_eq!(bits(&one), bits(&other));
        }
        assert!(one.3.n_rejected > 0);
    }

    /// Cross-check against the `levenberg-marquardt` crate on a noisy partial sphere: both
    /// minimise the same sum of squares, so they agree far inside the uncertainty.
    #[test]
    fn sphere_agrees_with_levenberg_marquardt_crate() {
        use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
        use nalgebra::{DMatrix, DVector, Dyn, Owned, U4, Vector4};

        struct Problem<'a> {
            pts: &'a [Point3],
            x: Vector4<Real>,
        }
        impl LeastSquaresProblem<Real, Dyn, U4> for Problem<'_> {
            type ResidualStorage = Owned<Real, Dyn>;
            type JacobianStorage = Owned<Real, Dyn, U4>;
            type ParameterStorage = Owned<Real, U4>;
            fn set_params(&mut self, x: &Vector4<Real>) {
                self.x = *x;
            }
            fn params(&self) -> Vector4<Real> {
                self.x
            }
            fn residuals(&self) -> Option<DVector<Real>> {
                let c = Point3::new(self.x[0], self.x[1], self.x[2]);
                Some(DVector::from_iterator(
                    self.pts.len(),
                    self.pts.iter().map(|p| (p - c).norm() - self.x[3]),
                ))
            }
            fn jacobian(&self) -> Option<nalgebra::OMatrix<Real, Dyn, U4>> {
                let c = Point3::new(self.x[0], self.x[1], self.x[2]);
                let mut j = DMatrix::zeros(self.pts.len(), 4);
                for (i, p) in self.pts.iter().enumerate() {
                    let u = (p - c).normalize();
                    j[(i, 0)] = -u.x;
                    j[(i, 1)] = -u.y;
                    j[(i, 2)] = -u.z;
                    j[(i, 3)] = -1.0;
                }
                Some(j.fixed_columns::<4>(0).into_owned())
            }
        }
        let s = shape(301).with_radius(8.0);
        let pts = s.sphere(2000, 0.4 * PI, NOISE, 9);
        let ours = fit_sphere(&pts).expect("fit");
        let start = Vector4::new(s.centre.x + 0.3, s.centre.y - 0.2, s.centre.z, 8.5);
        let (solved, report) = LevenbergMarquardt::new().minimize(Problem {
            pts: &pts,
            x: start,
        });
        assert!(report.termination.was_successful(), "{report:?}");
        let x = solved.x;
        let dc = (Point3::new(x[0], x[1], x[2]) - ours.centre).norm();
        assert!(
            dc <= 1e-6 * ours.centre_sigma_mm[0],
            "centre differs by {dc:e}"
        );
        assert!((x[3] - ours.radius).abs() <= 1e-6 * ours.radius_sigma_mm);
    }

    #[test]
    fn distance_and_angle_of_two_planes() {
        let a = Plane::through(
            &Point3::new(0.0, 0.0, 10.0),
            UnitVector3::new_normalize(Vector3::z()),
        );
        let theta: Real = 0.01;
        // b through (0, 0, 12.5), tilted by θ about x, normal pointing down.
        let nb = UnitVector3::new_normalize(-Vector3::new(0.0, theta.sin(), theta.cos()));
        let b = Plane::through(&Point3::new(0.0, 0.0, 12.5), nb);
        let at = Point3::new(3.0, 4.0, -7.0);
        let (d, ang) = plane_distance_and_angle(&a, &b, &at).expect("measurable");
        // Line x = 3, y = 4: meets a at z = 10 and b at z = 12.5 − 4 tan θ.
        assert!((d - (2.5 - 4.0 * theta.tan())).abs() < 1e-13, "{d}");
        assert!((ang - theta).abs() < 1e-15, "{ang}");
        let (d2, ang2) = plane_distance_and_angle(&b, &a, &at).expect("measurable");
        assert!((ang2 - theta).abs() < 1e-15);
        // From b along b's (downward) normal through `at`, a lies on the positive side.
        assert!(d2 > 0.0 && (d2 - d * theta.cos()).abs() < 0.05 * d);
        // Parallel planes: the plain offset difference, angle 0.
        let c = Plane::through(&Point3::new(9.0, 9.0, 7.0), a.normal);
        assert_eq!(plane_distance_and_angle(&a, &c, &at), Some((-3.0, 0.0)));
        // Perpendicular planes cannot be measured this way.
        let side = Plane::through(&Point3::origin(), UnitVector3::new_normalize(Vector3::x()));
        assert_eq!(plane_distance_and_angle(&a, &side, &at), None);
        let nan = Point3::new(Real::NAN, 0.0, 0.0);
        assert_eq!(plane_distance_and_angle(&a, &b, &nan), None);
    }
}
