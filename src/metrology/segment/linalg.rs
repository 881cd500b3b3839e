//! Small linear algebra: sums of first and second moments of displacements
//! ([`Moments`]), and the symmetric 3 × 3 eigenproblem of a cell, a region or a
//! neighbourhood ([`eigen_sym3`]: Newton on the characteristic polynomial, the closed
//! trigonometric form, nalgebra's iterative solver as the last resort), with the
//! orientation rule of plane normals and a perpendicular basis.

use crate::math::{Matrix3, Real, Vector3};

/// Below this gap (λ₁ − λ₀)/(λ₂ − λ₀) the closed-form eigenvector (cross products of the
/// rows of A − λ₀I, error ≈ ε/gap) would lose more than half its digits: the iterative
/// solver is used instead.
const EIGEN_GAP_EPS: Real = 1e-6;

/// Most Newton steps for the smallest eigenvalue before the closed form takes over: from
/// λ = 0 the steps reach λ₀ in two or three when λ₀ is well separated (a planar cell), in
/// more only for nearly round point sets, whose cells are not planar anyway.
const NEWTON_STEPS: usize = 8;

/// Largest λ₂²/(λ₀λ₁) for which the Newton value of λ₀ is kept. det(A − λI) near λ₀
/// carries a rounding error of about ε·λ₂³, so λ₀ is good to ε·λ₂²/(λ₀λ₁) relative: at
/// most 1e3·ε (2e-13) here — a noisy 1 mm face cell has about 130 (λ₂/λ₀ at σ = 0.025 mm);
/// flatter or needle-like sets go to the closed form, good to ε·λ₂ absolute.
const NEWTON_MAX_CONDITION: Real = 1e3;

/// Newton has converged when a step is below this fraction of the trace: a few f64 ulps
/// of the largest eigenvalue, the accuracy of the closed form too.
const NEWTON_TOL: Real = 1e-14;

/// Symmetric 3×3 moments (xx, xy, xz, yy, yz, zz) of `d` added to `m` with weight 1.
pub(super) fn add_outer(m: &mut [Real; 6], d: &Vector3) {
    m[0] += d.x * d.x;
    m[1] += d.x * d.y;
    m[2] += d.x * d.z;
    m[3] += d.y * d.y;
    m[4] += d.y * d.z;
    m[5] += d.z * d.z;
}

fn sym_matrix(m: &[Real; 6]) -> Matrix3 {
    Matrix3::new(
        m[0], m[1], m[2], //
        m[1], m[3], m[4], //
        m[2], m[4], m[5],
    )
}

/// Eigenvalues (ascending) of the symmetric matrix `m` (xx, xy, xz, yy, yz, zz) and a unit
/// eigenvector of the smallest; `None` when an entry is not finite.
///
/// The smallest eigenvalue λ₀ comes from Newton's method on det(A − λI) from λ = 0 — for
/// a positive semi-definite matrix the determinant is positive, decreasing and convex
/// left of λ₀, so the iterates rise monotonically to it, in two or three steps for a
/// noisy planar cell — and the other two from the remaining quadratic; when that is not
/// accurate ([`NEWTON_MAX_CONDITION`]), all three come from the closed (trigonometric)
/// form, good to a few ε·λ₂ — except for two eigenvalues that nearly coincide against λ₂
/// (a needle, never a plane), which keep about √ε·λ₂. The eigenvector is the largest cross product
/// of two rows of A − λ₀I; when λ₀ is nearly double ([`EIGEN_GAP_EPS`]) the iterative
/// solver of nalgebra decides. A multiple of the identity gets the z axis.
pub(super) fn eigen_sym3(m: &[Real; 6]) -> Option<([Real; 3], Vector3)> {
    if !m.iter().all(|v| v.is_finite()) {
        return None;
    }
    newton_eigen(m).or_else(|| closed_form_eigen(m))
}

/// The Newton path of [`eigen_sym3`]; `None` when it does not converge, or the
/// eigenvector is ill-determined.
fn newton_eigen(m: &[Real; 6]) -> Option<([Real; 3], Vector3)> {
    let [a00, a01, a02, a11, a12, a22] = *m;
    let tr = a00 + a11 + a22;
    let c1 = a00 * a11 - a01 * a01 + a00 * a22 - a02 * a02 + a11 * a22 - a12 * a12;
    let det = a00 * (a11 * a22 - a12 * a12) - a01 * (a01 * a22 - a12 * a02)
        + a02 * (a01 * a12 - a11 * a02);
    if !(tr > 0.0 && c1 > 0.0) {
        return None;
    }
    let mut l: Real = 0.0;
    let mut converged = false;
    for _ in 0..NEWTON_STEPS {
        let f = ((tr - l) * l - c1) * l + det;
        let fp = (2.0 * tr - 3.0 * l) * l - c1;
        let descending = fp < 0.0;
        if !descending {
            return None;
        }
        let step = f / fp;
        l -= step;
        if step.abs() <= NEWTON_TOL * tr {
            converged = true;
            break;
        }
    }
    if !converged {
        return None;
    }
    let s = tr - l;
    let prod = c1 - l * s;
    let root = (s * s - 4.0 * prod).max(0.0).sqrt();
    let l_max = 0.5 * (s + root);
    let l_mid = if l_max > 0.0 { prod / l_max } else { 0.0 };
    let accurate = l_max * l_max <= NEWTON_MAX_CONDITION * l * l_mid;
    if !accurate {
        return None;
    }
    let v = cross_eigenvector(m, l, l_max)?;
    Some(([l, l_mid, l_max], v))
}

/// Unit eigenvector for the eigenvalue `l` of `m`, from the largest cross product of two
/// rows of A − lI; `None` when that is too small against the spread `l_max − l`.
fn cross_eigenvector(m: &[Real; 6], l: Real, l_max: Real) -> Option<Vector3> {
    let [a00, a01, a02, a11, a12, a22] = *m;
    let r0 = Vector3::new(a00 - l, a01, a02);
    let r1 = Vector3::new(a01, a11 - l, a12);
    let r2 = Vector3::new(a02, a12, a22 - l);
    let mut best = r0.cross(&r1);
    for c in [r0.cross(&r2), r1.cross(&r2)] {
        if c.norm_squared() > best.norm_squared() {
            best = c;
        }
    }
    let spread = (l_max - l) * (l_max - l);
    let nsq = best.norm_squared();
    (nsq.is_finite() && nsq > 0.0 && nsq.sqrt() > EIGEN_GAP_EPS * spread).then(|| best / nsq.sqrt())
}

/// The closed-form path of [`eigen_sym3`] (entries finite).
fn closed_form_eigen(m: &[Real; 6]) -> Option<([Real; 3], Vector3)> {
    let [a00, a01, a02, a11, a12, a22] = *m;
    let q = (a00 + a11 + a22) / 3.0;
    let (b00, b11, b22) = (a00 - q, a11 - q, a22 - q);
    let off = a01 * a01 + a02 * a02 + a12 * a12;
    let p2 = b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * off;
    if !p2.is_finite() {
        return None;
    }
    let p = (p2 / 6.0).sqrt();
    if p <= 0.0 {
        return Some(([q; 3], Vector3::z()));
    }
    let inv = 1.0 / p;
    let (c00, c01, c02, c11, c12, c22) = (
        b00 * inv,
        a01 * inv,
        a02 * inv,
        b11 * inv,
        a12 * inv,
        b22 * inv,
    );
    let det = c00 * (c11 * c22 - c12 * c12) - c01 * (c01 * c22 - c12 * c02)
        + c02 * (c01 * c12 - c11 * c02);
    let phi = (det / 2.0).clamp(-1.0, 1.0).acos() / 3.0;
    let third = std::f64::consts::TAU / 3.0;
    let l_max = q + 2.0 * p * phi.cos();
    let l_min = q + 2.0 * p * (phi + third).cos();
    let l_mid = 3.0 * q - l_max - l_min;
    if let Some(v) = cross_eigenvector(m, l_min, l_max) {
        return Some(([l_min, l_mid, l_max], v));
    }
    let eig = nalgebra::SymmetricEigen::try_new(sym_matrix(m), Real::EPSILON, 10_000)?;
    let mut order = [0usize, 1, 2];
    order.sort_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]));
    let v: Vector3 = eig.eigenvectors.column(order[0]).into_owned();
    let norm = v.norm();
    if !(norm > 0.0 && norm.is_finite()) {
        return None;
    }
    Some((order.map(|i| eig.eigenvalues[i]), v / norm))
}

/// `n` flipped if needed so that its largest-magnitude component (the first on a tie) is
/// positive: the orientation rule of [`crate::metrology::fit::PlaneFit`].
pub(super) fn canonical(n: Vector3) -> Vector3 {
    let mut k_big = 0;
    for k in 1..3 {
        if n[k].abs() > n[k_big].abs() {
            k_big = k;
        }
    }
    if n[k_big] < 0.0 { -n } else { n }
}

/// Two unit vectors completing the unit vector `a` to a right-handed orthonormal basis.
pub(super) fn basis_perpendicular(a: &Vector3) -> (Vector3, Vector3) {
    let e = if a.x.abs() < 0.6 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let u = a.cross(&e).normalize();
    (u, a.cross(&u))
}

/// Count, sum and second moments of displacements from some reference point.
#[derive(Clone, Copy, Debug)]
pub(super) struct Moments {
    pub(super) n: usize,
    pub(super) s: Vector3,
    /// xx, xy, xz, yy, yz, zz.
    pub(super) m: [Real; 6],
}

impl Moments {
    pub(super) const ZERO: Moments = Moments {
        n: 0,
        s: Vector3::new(0.0, 0.0, 0.0),
        m: [0.0; 6],
    };

    pub(super) fn push(&mut self, d: &Vector3) {
        self.n += 1;
        self.s += d;
        add_outer(&mut self.m, d);
    }

    pub(super) fn merge(&mut self, o: &Moments) {
        self.n += o.n;
        self.s += o.s;
        for (a, b) in self.m.iter_mut().zip(&o.m) {
            *a += b;
        }
    }

    /// Mean displacement and the scatter Σ (d − mean)(d − mean)ᵀ (`None` when empty).
    pub(super) fn centred(&self) -> Option<(Vector3, [Real; 6])> {
        if self.n == 0 {
            return None;
        }
        let n = self.n as Real;
        let mean = self.s / n;
        let mut mm = [0.0; 6];
        add_outer(&mut mm, &mean);
        let mut c = self.m;
        for (a, b) in c.iter_mut().zip(mm) {
            *a -= n * b;
        }
        Some((mean, c))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::CounterRng;

    #[test]
    fn eigen_fast_path_agrees_with_nalgebra() {
        let rng = CounterRng::new(41);
        for i in 0..2000u64 {
            // Random symmetric PSD matrices of every conditioning.
            let a = Matrix3::from_fn(|r, c| rng.normal(i * 9 + (3 * r + c) as u64));
            let scale = Vector3::new(
                1.0,
                10f64.powf(-6.0 * rng.uniform(i, 1)),
                10f64.powf(-12.0 * rng.uniform(i, 2)),
            );
            let m = a * Matrix3::from_diagonal(&scale) * a.transpose();
            let six = [
                m[(0, 0)],
                m[(0, 1)],
                m[(0, 2)],
                m[(1, 1)],
                m[(1, 2)],
                m[(2, 2)],
            ];
            let (l, v) = eigen_sym3(&six).expect("finite");
            let eig = nalgebra::SymmetricEigen::new(m);
            let mut want = [eig.eigenvalues[0], eig.eigenvalues[1], eig.eigenvalues[2]];
            want.sort_by(Real::total_cmp);
            let top = want[2].abs();
            // The closed form keeps about √ε of λ₂ for two eigenvalues that nearly
            // coincide against λ₂ (needles, not planes).
            for k in 0..3 {
                assert!(
                    (l[k] - want[k]).abs() <= 1e-9 * top,
                    "{i}: {l:?} vs {want:?}"
                );
            }
            assert!((v.norm() - 1.0).abs() < 1e-12);
            // Residual of the eigenvector, relative to the spread it is resolved against.
            let res = (m * v - v * l[0]).norm();
            assert!(res <= 1e-10 * top, "{i}: residual {res:e}");
        }
        assert_eq!(eigen_sym3(&[0.0; 6]), Some(([0.0; 3], Vector3::z())));
        assert_eq!(eigen_sym3(&[Real::NAN, 0.0, 0.0, 1.0, 0.0, 1.0]), None);
    }
}
