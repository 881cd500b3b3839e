//! Geometry helpers (a tangent basis of a unit vector, its rotation by a small rotation
//! vector) and what the closed-form starting values of the iterative fits are made of: the
//! points' principal axes ([`Spread`]), a small scaled linear solve, and the Kåsa circles in
//! given planes (the sphere's algebraic start and the cylinder's best axis are in their
//! shapes' files).

use super::error::FitError;
use super::moments::{
    DEGENERATE_RATIO, EIGEN_ITERATIONS, canonical_sign, centred_moments, chunked_sum,
};
use super::solver::{Normal, Scaled, Sums, rank_deficient};
use crate::math::{Point3, Real, UnitVector3, Vector3};
use nalgebra::{SMatrix, SVector, SymmetricEigen};

#[cfg(doc)]
use super::solver::RANK_RATIO;

/// Orthonormal (e1, e2) with e1 × e2 = n: e1 ⟂ n built from the coordinate axis of n's
/// smallest component (|n × e| ≥ √(2/3), never ill-conditioned).
pub(super) fn tangent_basis(n: &UnitVector3) -> (Vector3, Vector3) {
    let mut e = Vector3::zeros();
    e[n.iamin()] = 1.0;
    let e1 = n.cross(&e).normalize();
    (e1, n.cross(&e1))
}

/// `n` rotated by the rotation vector `w` (⟂ n): n cos|w| + ŵ sin|w|.
pub(super) fn rotate(n: &UnitVector3, w: &Vector3) -> UnitVector3 {
    let angle = w.norm();
    if angle == 0.0 {
        return *n;
    }
    UnitVector3::new_normalize(n.into_inner() * angle.cos() + w * (angle.sin() / angle))
}

/// Centroid, principal axes and RMS spread of a point set.
pub(super) struct Spread {
    pub(super) centroid: Point3,
    /// Eigenvalues of the centred second-moment sum, ascending.
    values: [Real; 3],
    /// The matching unit eigenvectors.
    pub(super) axes: [UnitVector3; 3],
    /// RMS distance of the points from the centroid (mm), > 0.
    pub(super) rms: Real,
}

impl Spread {
    pub(super) fn of(points: &[Point3]) -> Result<Self, FitError> {
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
    pub(super) fn collinear(&self) -> bool {
        self.values[1] <= DEGENERATE_RATIO * self.values[2]
    }

    /// Whether the points are coplanar within [`DEGENERATE_RATIO`].
    pub(super) fn coplanar(&self) -> bool {
        self.values[0] <= DEGENERATE_RATIO * self.values[2]
    }
}

/// Solves the symmetric positive-definite `a·x = b` (unknowns of comparable units) after
/// Jacobi scaling; None if `a` is non-finite, not positive definite or rank-deficient
/// within [`RANK_RATIO`].
pub(super) fn solve_spd<const N: usize>(
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

/// The algebraic (Kåsa) circles x²+y² + Dx + Ey + F = 0 of the points projected on the
/// planes through the centroid with unit normals `ws` (one pass for all K), in
/// coordinates scaled by the RMS spread. Each: the centre (in that plane) and the radius,
/// None if the projected points are collinear.
pub(super) fn kasa_circles<const K: usize>(
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
