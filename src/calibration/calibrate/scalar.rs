//! The arithmetic the predictions are written in: [`Scalar`] (`f64` for values, [`Dual`]
//! numbers for one directional derivative alongside), small 3-vectors of it, rigid
//! transforms, and the deviated chain's pose with the parameters solved for applied.
//!
//! **Invariant:** written once, generic in the scalar: a prediction's derivative is that of
//! the very expression that gives its value.

use super::*;

// ---------------------------------------------------------------------------------------
// Generic scalar: f64 for values, dual numbers for derivatives.

/// The arithmetic the predictions are written in: `f64` gives values, [`Dual`] one
/// directional derivative alongside.
pub trait Scalar:
    Copy
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
{
    /// A constant.
    fn c(x: Real) -> Self;
    /// The value part.
    fn value(self) -> Real;
    /// Square root.
    fn sqrt(self) -> Self;
    /// Sine.
    fn sin(self) -> Self;
    /// Cosine.
    fn cos(self) -> Self;
    /// Absolute value (derivative: the sign; 0 at 0).
    fn abs(self) -> Self;
}

impl Scalar for Real {
    fn c(x: Real) -> Self {
        x
    }
    fn value(self) -> Real {
        self
    }
    fn sqrt(self) -> Self {
        Real::sqrt(self)
    }
    fn sin(self) -> Self {
        Real::sin(self)
    }
    fn cos(self) -> Self {
        Real::cos(self)
    }
    fn abs(self) -> Self {
        Real::abs(self)
    }
}

/// A dual number `v + d·ε`, ε² = 0: forward-mode automatic differentiation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Dual {
    /// Value.
    pub v: Real,
    /// Derivative along the seeded direction.
    pub d: Real,
}

impl Add for Dual {
    type Output = Dual;
    fn add(self, o: Dual) -> Dual {
        Dual {
            v: self.v + o.v,
            d: self.d + o.d,
        }
    }
}
impl Sub for Dual {
    type Output = Dual;
    fn sub(self, o: Dual) -> Dual {
        Dual {
            v: self.v - o.v,
            d: self.d - o.d,
        }
    }
}
impl Mul for Dual {
    type Output = Dual;
    fn mul(self, o: Dual) -> Dual {
        Dual {
            v: self.v * o.v,
            d: self.d * o.v + self.v * o.d,
        }
    }
}
impl Div for Dual {
    type Output = Dual;
    fn div(self, o: Dual) -> Dual {
        Dual {
            v: self.v / o.v,
            d: (self.d * o.v - self.v * o.d) / (o.v * o.v),
        }
    }
}
impl Neg for Dual {
    type Output = Dual;
    fn neg(self) -> Dual {
        Dual {
            v: -self.v,
            d: -self.d,
        }
    }
}
impl Scalar for Dual {
    fn c(x: Real) -> Self {
        Dual { v: x, d: 0.0 }
    }
    fn value(self) -> Real {
        self.v
    }
    fn sqrt(self) -> Self {
        let s = self.v.sqrt();
        Dual {
            v: s,
            d: self.d / (2.0 * s),
        }
    }
    fn sin(self) -> Self {
        Dual {
            v: self.v.sin(),
            d: self.d * self.v.cos(),
        }
    }
    fn cos(self) -> Self {
        Dual {
            v: self.v.cos(),
            d: -self.d * self.v.sin(),
        }
    }
    fn abs(self) -> Self {
        if self.v < 0.0 {
            -self
        } else if self.v > 0.0 {
            self
        } else {
            Dual::c(0.0)
        }
    }
}

pub(super) type V3<T> = [T; 3];

pub(super) fn v3<T: Scalar>(v: &Vector3) -> V3<T> {
    [T::c(v.x), T::c(v.y), T::c(v.z)]
}
pub(super) fn vadd<T: Scalar>(a: V3<T>, b: V3<T>) -> V3<T> {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
pub(super) fn vsub<T: Scalar>(a: V3<T>, b: V3<T>) -> V3<T> {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
pub(super) fn vscale<T: Scalar>(a: V3<T>, s: T) -> V3<T> {
    [a[0] * s, a[1] * s, a[2] * s]
}
pub(super) fn dot<T: Scalar>(a: V3<T>, b: V3<T>) -> T {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
pub(super) fn cross<T: Scalar>(a: V3<T>, b: V3<T>) -> V3<T> {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
pub(super) fn normalize<T: Scalar>(a: V3<T>) -> V3<T> {
    vscale(a, T::c(1.0) / dot(a, a).sqrt())
}
pub(super) fn values<T: Scalar>(a: V3<T>) -> Vector3 {
    Vector3::new(a[0].value(), a[1].value(), a[2].value())
}

/// A rigid transform in generic scalars: rotation (row-major) and translation.
#[derive(Clone, Copy)]
pub(super) struct Rigid<T> {
    pub(super) r: [[T; 3]; 3],
    pub(super) t: V3<T>,
}

impl<T: Scalar> Rigid<T> {
    fn from_isometry(iso: &crate::math::Isometry3) -> Self {
        let m = iso.rotation.to_rotation_matrix();
        let m = m.matrix();
        Rigid {
            r: std::array::from_fn(|i| std::array::from_fn(|j| T::c(m[(i, j)]))),
            t: v3(&iso.translation.vector),
        }
    }
    /// Trans(dx,dy,dz)·Rx(alpha)·Ry(beta)·Rz(gamma), exact.
    pub(super) fn deviation(p: &[T; 6]) -> Self {
        let (sa, ca) = (p[3].sin(), p[3].cos());
        let (sb, cb) = (p[4].sin(), p[4].cos());
        let (sg, cg) = (p[5].sin(), p[5].cos());
        let (o, z) = (T::c(1.0), T::c(0.0));
        let rx = [[o, z, z], [z, ca, -sa], [z, sa, ca]];
        let ry = [[cb, z, sb], [z, o, z], [-sb, z, cb]];
        let rz = [[cg, -sg, z], [sg, cg, z], [z, z, o]];
        Rigid {
            r: mat_mul(&mat_mul(&rx, &ry), &rz),
            t: [p[0], p[1], p[2]],
        }
    }
    fn compose(&self, o: &Rigid<T>) -> Rigid<T> {
        Rigid {
            r: mat_mul(&self.r, &o.r),
            t: vadd(self.rotate(o.t), self.t),
        }
    }
    pub(super) fn rotate(&self, v: V3<T>) -> V3<T> {
        std::array::from_fn(|i| self.r[i][0] * v[0] + self.r[i][1] * v[1] + self.r[i][2] * v[2])
    }
    fn inverse(&self) -> Rigid<T> {
        let r: [[T; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| self.r[j][i]));
        let t = std::array::from_fn(|i| {
            -(r[i][0] * self.t[0] + r[i][1] * self.t[1] + r[i][2] * self.t[2])
        });
        Rigid { r, t }
    }
}

fn mat_mul<T: Scalar>(a: &[[T; 3]; 3], b: &[[T; 3]; 3]) -> [[T; 3]; 3] {
    std::array::from_fn(|i| {
        std::array::from_fn(|j| a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j])
    })
}

/// The unknowns a pose depends on: joint deviations replaced by `p`, ISO terms `iso` with
/// values `t` composed on top (generic scalars).
#[derive(Clone, Copy)]
pub(super) struct Params<'a, T> {
    pub(super) ids: &'a [DeviationId],
    pub(super) p: &'a [T],
    pub(super) iso: &'a [IsoTerm],
    pub(super) t: &'a [T],
}

/// `w_from_t(q)` of `chain` with the deviations `ids` replaced by `p` and the ISO terms
/// applied (generic scalars): an axis with terms moves as `L·M·Err·L⁻¹` (`M·Err·L⁻¹` for
/// the first axis, whose `L` next to the workpiece frame only moves that frame), exactly as
/// [`Chain::apply_iso_term`] composes them onto the joints; `Err` is the axis's error
/// motions at `q` (as [`Chain::w_from_t`]: every axis last moved in +), known values.
pub(super) fn pose<T: Scalar>(chain: &Chain, x: &Params<T>, q: &AxisValues) -> Rigid<T> {
    let mut out = Rigid::from_isometry(&crate::math::Isometry3::identity());
    for (j, (axis, dev)) in chain.axes().iter().zip(chain.deviations()).enumerate() {
        let mut d: [T; 6] = std::array::from_fn(|k| T::c(dev.values[k]));
        for (id, v) in x.ids.iter().zip(x.p) {
            if id.joint == j {
                d[id.component as usize] = *v;
            }
        }
        // The axis's error motions (known values, every axis as last moved in +) ride on
        // its motion, inside the line's location `L` as the chain composes them.
        let qj = q.get(axis.letter);
        let motion = match chain.error_transform(j, qj, Direction::Positive) {
            Some(err) => axis.motion(qj) * err,
            None => axis.motion(qj),
        };
        let m = Rigid::from_isometry(&motion);
        let m = if x.iso.iter().any(|t| t.axis == j) {
            let mut v: [T; 6] = std::array::from_fn(|_| T::c(0.0));
            for (term, val) in x.iso.iter().zip(x.t) {
                if term.axis == j {
                    v[term.component as usize] = v[term.component as usize] + *val;
                }
            }
            let o = v3::<T>(&chain.error_centre(j).coords);
            let e = Rigid::deviation(&v);
            // L = Trans(o)·Trans(d)·R·Trans(−o)
            let l = Rigid {
                r: e.r,
                t: vsub(vadd(o, e.t), e.rotate(o)),
            };
            let ml = m.compose(&l.inverse());
            if j == 0 { ml } else { l.compose(&ml) }
        } else {
            m
        };
        out = out.compose(&m).compose(&Rigid::deviation(&d));
    }
    out
}
