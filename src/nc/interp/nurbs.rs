//! The curve maths of G5, G5.1 and G5.2/G5.3 as LinuxCNC 2.9 does it: a rational B-spline
//! of order k over the control points (X, Y, weight) with LinuxCNC's knot vector (k zeros,
//! 1 … n−k+1, k times n−k+2; n + 1 points), evaluated at 4·(n + 1) equal steps of the
//! parameter, each step joined by a biarc (two arcs meeting with a common tangent at a
//! point between them, or a straight piece where an arc degenerates).
//!
//! The interpreter hands the control points to the canon as one call (`NURBS_FEED`); the
//! pieces are what LinuxCNC's task makes of it (`emccanon.cc` `NURBS_FEED`, `biarc`, `arc`,
//! with the basis and tangent of `nurbs_additional_functions.cc`): the same arithmetic in
//! the same order, so the pieces agree with LinuxCNC's to the last bit or so. In
//! particular the basis functions use closed intervals (a parameter on an inner knot
//! counts on both sides), the tangent is a central difference over ±1e-5 of the
//! parameter, and a biarc whose quadratic has no usable root makes no move at all. The
//! evaluation keeps only the basis functions that can be non-zero at a parameter, so a
//! curve costs O(points × order²) instead of LinuxCNC's recursion.
//!
//! Numbers are in the program's units and coordinates (the units matter only for the
//! threshold below which an arc counts as straight).

use crate::math::Real;

/// Half-width of the parameter step of LinuxCNC's central-difference tangent.
const TANGENT_DU: Real = 1e-5;
/// Below this |2·(chord × tangent)| (program units) an arc piece is straight
/// (LinuxCNC's `arc()`).
const STRAIGHT_DEN: Real = 0.000001;
/// Parameter steps per control point.
const STEPS_PER_POINT: usize = 4;

/// A control point: X, Y (program units) and weight.
pub(crate) type ControlPoint = [Real; 3];

/// One piece of a curve, as LinuxCNC's task issues it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Piece {
    /// `ARC_FEED` to `end` about `center`; `rotation` +1 counter-clockwise, −1 clockwise.
    Arc {
        /// End point (X, Y).
        end: [Real; 2],
        /// Centre (X, Y).
        center: [Real; 2],
        /// +1 or −1.
        rotation: i32,
    },
    /// `STRAIGHT_FEED` to `end`.
    Line {
        /// End point (X, Y).
        end: [Real; 2],
    },
}

impl Piece {
    /// All coordinates are finite (LinuxCNC issues pieces to non-finite points too: a
    /// biarc between parallel tangents divides by zero).
    pub(crate) fn is_finite(&self) -> bool {
        match self {
            Piece::Arc { end, center, .. } => {
                end.iter().chain(center.iter()).all(|v| v.is_finite())
            }
            Piece::Line { end } => end.iter().all(|v| v.is_finite()),
        }
    }

    /// End point.
    pub(crate) fn end(&self) -> [Real; 2] {
        match self {
            Piece::Arc { end, .. } | Piece::Line { end } => *end,
        }
    }
}

/// A rational B-spline in LinuxCNC's form.
pub(crate) struct Nurbs<'a> {
    points: &'a [ControlPoint],
    order: usize,
    /// Knot values (integers, as LinuxCNC's `unsigned int` knots).
    knots: Vec<u64>,
    /// Largest parameter, n − k + 2.
    umax: Real,
}

impl<'a> Nurbs<'a> {
    /// The curve of `points` (at least `order` of them) of order `order` (≥ 1).
    pub(crate) fn new(points: &'a [ControlPoint], order: usize) -> Option<Nurbs<'a>> {
        if order == 0 || points.len() < order {
            return None;
        }
        let n = points.len() - 1;
        let k = order;
        let knots = (0..=n + k)
            .map(|i| {
                if i < k {
                    0
                } else if i <= n {
                    (i - k + 1) as u64
                } else {
                    (n + 2 - k) as u64
                }
            })
            .collect();
        Some(Nurbs {
            points,
            order,
            knots,
            umax: (n + 2 - k) as Real,
        })
    }

    /// The basis functions of order `order` at `u` that can be non-zero: `(first index,
    /// values)`. Bit for bit LinuxCNC's recursive `Nmix` (the ones left out are exactly 0
    /// there).
    fn basis(&self, u: Real) -> (usize, Vec<Real>) {
        let kv = &self.knots;
        let kvf = |i: usize| kv[i] as Real;
        let last = kv.len() - 1; // n + k
        // order 1: the (closed) knot intervals [kv[i], kv[i+1]], i < last, that hold u;
        // the knots do not decrease, so they are the i from the first with kv[i+1] >= u
        // to the last with kv[i] <= u
        let lo = kv[1..].partition_point(|&k| (k as Real) < u);
        let hi = kv[..last].partition_point(|&k| k as Real <= u);
        if u.is_nan() || hi == 0 || lo > hi - 1 {
            return (0, Vec::new());
        }
        let hi = hi - 1;
        // level j holds N(i, j) for i in [start, hi]
        let mut start = lo;
        let mut vals = vec![1.0; hi - lo + 1];
        for j in 2..=self.order {
            let new_start = start.saturating_sub(1);
            // N(i, j) exists for i + j <= n + k
            let new_end = hi.min(last - j);
            if new_end < new_start {
                return (0, Vec::new());
            }
            let prev = |i: usize| -> Real {
                if i >= start && i - start < vals.len() {
                    vals[i - start]
                } else {
                    0.0
                }
            };
            let mut next = Vec::with_capacity(new_end - new_start + 1);
            for i in new_start..=new_end {
                let d1 = kv[i + j - 1] - kv[i];
                let d2 = kv[i + j] - kv[i + 1];
                let v = if d1 == 0 && d2 != 0 {
                    ((kvf(i + j) - u) * prev(i + 1)) / d2 as Real
                } else if d2 == 0 && d1 != 0 {
                    ((u - kvf(i)) * prev(i)) / d1 as Real
                } else if d1 == 0 && d2 == 0 {
                    0.0
                } else {
                    ((u - kvf(i)) * prev(i)) / d1 as Real
                        + ((kvf(i + j) - u) * prev(i + 1)) / d2 as Real
                };
                next.push(v);
            }
            start = new_start;
            vals = next;
        }
        (start, vals)
    }

    /// The curve point at parameter `u` (LinuxCNC's `nurbs_point`).
    pub(crate) fn point(&self, u: Real) -> [Real; 2] {
        let (start, vals) = self.basis(u);
        let n = self.points.len() - 1;
        let mut den = 0.0;
        for (off, v) in vals.iter().enumerate() {
            let i = start + off;
            if i <= n {
                den += v * self.points[i][2];
            }
        }
        let (mut x, mut y) = (0.0, 0.0);
        for (off, v) in vals.iter().enumerate() {
            let i = start + off;
            if i <= n {
                let p = &self.points[i];
                x += p[0] * v * p[2] / den;
                y += p[1] * v * p[2] / den;
            }
        }
        [x, y]
    }

    /// The unit tangent at `u` (LinuxCNC's `nurbs_tangent`: a central difference over
    /// ±1e-5, one-sided at the ends).
    pub(crate) fn tangent(&self, u: Real) -> [Real; 2] {
        // std::max(0.0, u - DU) and std::min(umax, u + DU)
        let ulo = if 0.0 < u - TANGENT_DU {
            u - TANGENT_DU
        } else {
            0.0
        };
        let uhi = if u + TANGENT_DU < self.umax {
            u + TANGENT_DU
        } else {
            self.umax
        };
        let p1 = self.point(ulo);
        let p3 = self.point(uhi);
        unit([(p3[0] - p1[0]) / (uhi - ulo), (p3[1] - p1[1]) / (uhi - ulo)])
    }

    /// LinuxCNC's task segmentation of the curve (`NURBS_FEED`): the pieces in order,
    /// including any to a non-finite point.
    pub(crate) fn pieces(&self) -> Vec<Piece> {
        let div = self.points.len() * STEPS_PER_POINT;
        let mut out = Vec::with_capacity(2 * div);
        let mut p0 = self.point(0.0);
        let mut t0 = self.tangent(0.0);
        for i in 1..=div {
            let u = self.umax * i as Real / div as Real;
            let p1 = self.point(u);
            let t1 = self.tangent(u);
            biarc(&mut out, p0, t0, p1, t1);
            p0 = p1;
            t0 = t1;
        }
        out
    }
}

/// `v` scaled to length 1 (unchanged when its length is 0), as LinuxCNC's `unit`.
fn unit(v: [Real; 2]) -> [Real; 2] {
    let h = v[0].hypot(v[1]);
    if h != 0.0 { [v[0] / h, v[1] / h] } else { v }
}

/// LinuxCNC's `arc()`: from `p0` with tangent `d` to `p1`, an arc, or a straight piece when
/// the chord is (nearly) along the tangent.
fn arc(out: &mut Vec<Piece>, p0: [Real; 2], p1: [Real; 2], d: [Real; 2]) {
    let x = p1[0] - p0[0];
    let y = p1[1] - p0[1];
    let den = 2.0 * (y * d[0] - x * d[1]);
    if den.abs() > STRAIGHT_DEN {
        let r = -(x * x + y * y) / den;
        let i = d[1] * r;
        let j = -d[0] * r;
        out.push(Piece::Arc {
            end: p1,
            center: [p0[0] + i, p0[1] + j],
            rotation: if r < 0.0 { 1 } else { -1 },
        });
    } else {
        out.push(Piece::Line { end: p1 });
    }
}

/// LinuxCNC's `biarc()` (ratio 1) from `p0` with tangent `ts` to `p4` with tangent `te`;
/// nothing when its quadratic has no usable root.
fn biarc(out: &mut Vec<Piece>, p0: [Real; 2], ts: [Real; 2], p4: [Real; 2], te: [Real; 2]) {
    let r = 1.0;
    let ts = unit(ts);
    let te = unit(te);
    let vx = p0[0] - p4[0];
    let vy = p0[1] - p4[1];
    let c = vx * vx + vy * vy;
    let b = 2.0 * (vx * (r * ts[0] + te[0]) + vy * (r * ts[1] + te[1]));
    let a = 2.0 * r * (ts[0] * te[0] + ts[1] * te[1] - 1.0);
    let discr = b * b - 4.0 * a * c;
    if discr < 0.0 {
        return;
    }
    let disq = discr.sqrt();
    let beta1 = (-b - disq) / 2.0 / a;
    let beta2 = (-b + disq) / 2.0 / a;
    if beta1 > 0.0 && beta2 > 0.0 {
        return;
    }
    // LinuxCNC's max(): the second when the first is smaller, else the first (NaN stays)
    let beta = if beta1 < beta2 { beta2 } else { beta1 };
    let alpha = beta * r;
    let ab = alpha + beta;
    let p1 = [p0[0] + alpha * ts[0], p0[1] + alpha * ts[1]];
    let p3 = [p4[0] - beta * te[0], p4[1] - beta * te[1]];
    let p2 = [
        (p1[0] * beta + p3[0] * alpha) / ab,
        (p1[1] * beta + p3[1] * alpha) / ab,
    ];
    let tm = unit([p3[0] - p2[0], p3[1] - p2[1]]);
    arc(out, p0, p2, ts);
    arc(out, p2, p4, tm);
}
