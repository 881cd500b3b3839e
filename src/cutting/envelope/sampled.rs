//! The path of a move read pose by pose (a hexapod: each pose a forward-kinematics solve),
//! as a smooth curve through its pilot poses that the envelope can evaluate anywhere with
//! its rates ([`SampledPath`]), the speed bounds the envelope needs, and an estimate of how
//! far the curve is from the machine's own path.
//!
//! **The curve.** The pilot poses `P_j = (R_j, p_j)` at `λ_j = j/M` are joined segment by
//! segment by cubic Hermite curves: the tip `p(u) = h00·p_j + h10·d_j + h01·p_{j+1} +
//! h11·d_{j+1}` (`u = M·λ − j`) with Catmull–Rom tangents `d_j = (p_{j+1} − p_{j−1})/2`
//! (second-order one-sided at the ends), and the orientation `R(u) = R_j·exp([ρ(u)]×)`
//! with `ρ` the Hermite cubic from `0` to `log(R_jᵀR_{j+1})` whose end tangents are the
//! same central differences taken in `R_j`'s frame. The curve passes through every pilot
//! pose exactly and is continuous; its rates are its own derivatives in closed form (the
//! body angular velocity `J_r(ρ)·ρ'`, `J_r` the right Jacobian of SO(3)), so the envelope's
//! extremes are those of the curve.
//!
//! **How far from the machine.** A Catmull–Rom curve's error falls as `h³`. The same curve
//! through every other pilot pose is compared with the machine at the poses it skips (no
//! forward solve beyond the pilot's): its largest distance — the tip's, plus the
//! orientation's angle times the tool's reach — bounds the error of a curve with twice the
//! nodes by a factor of eight to spare ([`SampledPath::error_estimate`]).
//!
//! **Speed.** No tool point is taken to move faster per unit `λ` than
//! [`SAMPLED_BOUND_FACTOR`] times the largest speed the curve shows at its nodes, segment
//! middles and quarters (the same safety factor as the sub-steps of a pose source,
//! [`crate::cutting::sweep::SampledBound`]): the envelope's cells, its growths and its
//! touch tests rest on it.
//!
//! **Invariant:** a function of the pilot poses alone; the same poses give the same curve,
//! bit for bit.

use super::path::Sample;
use crate::math::{Isometry3, Matrix3, Point3, Real, Vector3};

/// Safety factor on the rates a pose source's samples show (the largest angular speed and
/// path curvature between samples may exceed those at the samples): on the sub-steps of a
/// pose source ([`crate::cutting::sweep::SampledBound`]) and on the speed of its curve
/// ([`SampledPath::speed_bound`]).
pub const SAMPLED_BOUND_FACTOR: Real = 2.0;

/// A smooth curve through the pilot poses of a move (see the module docs).
#[derive(Clone, Debug)]
pub struct SampledPath {
    /// Per node: the orientation (`w_from_t` rotation) and the tip.
    rot: Vec<Matrix3>,
    tip: Vec<Vector3>,
    /// Per node: the tip's tangent per unit segment parameter.
    d: Vec<Vector3>,
    /// Per segment `j`: `log(R_jᵀR_{j+1})` and the tangents of `ρ` at its two ends, in
    /// `R_j`'s frame, per unit segment parameter.
    rho1: Vec<Vector3>,
    m0: Vec<Vector3>,
    m1: Vec<Vector3>,
}

/// The rotation vector of the rotation `r` (angle below π): `θ` from `atan2(sin θ, cos θ)`,
/// both read off the matrix, well conditioned down to the smallest angles (an arc cosine of
/// the trace is not: it loses half the digits near the identity).
fn log(r: &Matrix3) -> Vector3 {
    let v = Vector3::new(
        r[(2, 1)] - r[(1, 2)],
        r[(0, 2)] - r[(2, 0)],
        r[(1, 0)] - r[(0, 1)],
    ) * 0.5;
    let s = v.norm();
    let c = 0.5 * (r.trace() - 1.0);
    if s <= Real::EPSILON {
        return v;
    }
    v * (s.atan2(c) / s)
}

/// `exp([v]×)` by Rodrigues' formula, and the right Jacobian `J_r(v)`.
fn exp_and_jacobian(v: &Vector3) -> (Matrix3, Matrix3) {
    let th2 = v.norm_squared();
    let k = v.cross_matrix();
    let k2 = k * k;
    // sin θ/θ, (1 − cos θ)/θ², (θ − sin θ)/θ³; series below 1e-4 rad (errors < 1e-17).
    let (a, b, c) = if th2 < 1e-8 {
        (1.0 - th2 / 6.0, 0.5 - th2 / 24.0, 1.0 / 6.0 - th2 / 120.0)
    } else {
        let th = th2.sqrt();
        let (s, co) = th.sin_cos();
        (s / th, (1.0 - co) / th2, (th - s) / (th2 * th))
    };
    let id = Matrix3::identity();
    (id + k * a + k2 * b, id - k * b + k2 * c)
}

/// Tangents of values `x_j` on a uniform grid: central differences inside, second-order
/// one-sided at the ends (`x` has at least three values).
fn tangents(x: &[Vector3]) -> Vec<Vector3> {
    let n = x.len();
    (0..n)
        .map(|j| {
            if j == 0 {
                (x[1] * 4.0 - x[0] * 3.0 - x[2]) / 2.0
            } else if j == n - 1 {
                (x[n - 1] * 3.0 - x[n - 2] * 4.0 + x[n - 3]) / 2.0
            } else {
                (x[j + 1] - x[j - 1]) / 2.0
            }
        })
        .collect()
}

impl SampledPath {
    /// The curve through `pilot` (at least three poses, evenly spaced in λ from 0 to 1).
    pub fn new(pilot: &[Isometry3]) -> Self {
        assert!(pilot.len() >= 3, "a sampled path needs three poses");
        let rot: Vec<Matrix3> = pilot
            .iter()
            .map(|p| p.rotation.to_rotation_matrix().into_inner())
            .collect();
        let tip: Vec<Vector3> = pilot.iter().map(|p| p.translation.vector).collect();
        let d = tangents(&tip);
        let n = rot.len();
        // The neighbours of node j seen from R_j: log(R_jᵀ R_k).
        let rel = |j: usize, k: usize| log(&(rot[j].transpose() * rot[k]));
        let tangent_at = |base: usize, j: usize| -> Vector3 {
            // ρ's tangent at node j in base's frame, from the nodes around j.
            let at = |k: usize| rel(base, k);
            if j == 0 {
                (at(1) * 4.0 - at(0) * 3.0 - at(2)) / 2.0
            } else if j == n - 1 {
                (at(n - 1) * 3.0 - at(n - 2) * 4.0 + at(n - 3)) / 2.0
            } else {
                (at(j + 1) - at(j - 1)) / 2.0
            }
        };
        let rho1 = (0..n - 1).map(|j| rel(j, j + 1)).collect();
        let m0 = (0..n - 1).map(|j| tangent_at(j, j)).collect();
        let m1 = (0..n - 1).map(|j| tangent_at(j, j + 1)).collect();
        Self {
            rot,
            tip,
            d,
            rho1,
            m0,
            m1,
        }
    }

    /// Segments of the curve.
    fn segments(&self) -> usize {
        self.rot.len() - 1
    }

    /// The pose at `lambda` and its rates per unit λ.
    pub(super) fn sample(&self, lambda: Real) -> Sample {
        let m = self.segments();
        let x = (lambda * m as Real).clamp(0.0, m as Real);
        let j = (x.floor() as usize).min(m - 1);
        let u = x - j as Real;
        let (u2, u3) = (u * u, u * u * u);
        let (h00, h10, h01, h11) = (
            2.0 * u3 - 3.0 * u2 + 1.0,
            u3 - 2.0 * u2 + u,
            -2.0 * u3 + 3.0 * u2,
            u3 - u2,
        );
        let (g00, g10, g01, g11) = (
            6.0 * u2 - 6.0 * u,
            3.0 * u2 - 4.0 * u + 1.0,
            -6.0 * u2 + 6.0 * u,
            3.0 * u2 - 2.0 * u,
        );
        let scale = m as Real;
        let tip = self.tip[j] * h00 + self.d[j] * h10 + self.tip[j + 1] * h01 + self.d[j + 1] * h11;
        let dtip =
            (self.tip[j] * g00 + self.d[j] * g10 + self.tip[j + 1] * g01 + self.d[j + 1] * g11)
                * scale;
        let rho = self.m0[j] * h10 + self.rho1[j] * h01 + self.m1[j] * h11;
        let drho = (self.m0[j] * g10 + self.rho1[j] * g01 + self.m1[j] * g11) * scale;
        let (e, jr) = exp_and_jacobian(&rho);
        let rot = self.rot[j] * e;
        Sample {
            rot,
            tip: Point3::from(tip),
            w_t: jr * drho,
            v_t: rot.tr_mul(&dtip),
        }
    }

    /// A bound on the speed per unit λ of any tool point within `reach` of the tool-axis
    /// point at height `mid` (see the module docs): [`SAMPLED_BOUND_FACTOR`] times the
    /// largest `|ω|·reach + |ω × c + v|` (`c` the axis point, tool frame) at the nodes and
    /// the quarters of every segment.
    pub fn speed_bound(&self, mid: Real, reach: Real) -> Real {
        let c = Vector3::new(0.0, 0.0, mid);
        let m = self.segments() * 4;
        let fastest = (0..=m)
            .map(|k| {
                let s = self.sample(k as Real / m as Real);
                s.w_t.norm() * reach + (s.w_t.cross(&c) + s.v_t).norm()
            })
            .fold(0.0, Real::max);
        SAMPLED_BOUND_FACTOR * fastest
    }

    /// An estimate (mm) of the largest distance of a tool point within `reach` of the tip
    /// from where the machine puts it, over the curve through `pilot` (see the module docs):
    /// the curve through the even poses against the machine at the odd ones.
    pub fn error_estimate(pilot: &[Isometry3], reach: Real) -> Real {
        if pilot.len() < 7 {
            return Real::INFINITY;
        }
        // An odd count of poses keeps both ends in the coarse curve.
        if !(pilot.len() - 1).is_multiple_of(2) {
            return Real::INFINITY;
        }
        let even: Vec<Isometry3> = pilot.iter().step_by(2).copied().collect();
        let coarse = Self::new(&even);
        let n = (pilot.len() - 1) as Real;
        pilot
            .iter()
            .enumerate()
            .skip(1)
            .step_by(2)
            .map(|(j, p)| {
                let s = coarse.sample(j as Real / n);
                let r = p.rotation.to_rotation_matrix().into_inner();
                let angle = log(&(r.transpose() * s.rot)).norm();
                (s.tip.coords - p.translation.vector).norm() + angle * reach
            })
            .fold(0.0, Real::max)
    }
}
