//! The exact ray/sweep interval of any revolved tool translating along a segment.
//!
//! A tool is the union of convex revolved pieces ([`ConvexPiece`]); its swept volume is the
//! union of the pieces' swept volumes, each convex (a convex set ⊕ a segment). Along a ray
//! each piece gives one interval; the tool's set is their union, merged (it may have several
//! intervals when the profile is not convex).
//!
//! **Closed form** for frusta (cylinders, cones) and sphere zones: with `t` the ray parameter
//! and `s ∈ [0, 1]` the move parameter, a piece's set of `(t, s)` is bounded by one conic
//! (`r² = (r0 + k(h − h0))²` or `|p − c|² = ρ²`) and straight lines (its end planes and
//! `s = 0, 1`). The extremes of `t` over that convex 2-D set lie on the conic's own
//! `t`-extremes (∂Q/∂s = 0), on line ∩ conic or on line ∩ line points, each from a
//! quadratic formula; the feasible candidates' smallest and largest `t` are the interval.
//!
//! **Torus zones** (outward arcs whose centre is off the axis: the bull-nose corner) have no
//! quadric form. They are solved numerically on φ(t) = min over s ∈ [0, 1] of a convex gauge
//! of x(t) − s·d (distance to the zone's generating disk minus ρ, and its end planes): φ is
//! convex in t and ≤ 0 exactly on the swept zone. Closed-form sweeps of the zone's
//! circumscribed cylinder (rejects misses, brackets the ends) and inscribed chord frustum
//! (gives an interior point) start the search; Brent's method looks for a point with φ ≤ 0
//! when the chord frustum is missed, and each end is then found by a sign-bracketing root search
//! (Illinois regula falsi) to [`NUMERIC_T_TOL`]; the inner minimum over s is also taken by
//! Brent's method (`NUMERIC_S_TOL`). The tests check this path against the closed forms on
//! the pieces both solve ([`NUMERIC_AGREEMENT`]).
//!
//! **Invariant:** the cutter knows only tool geometry and straight moves; it never reads
//! moves, machines or files.

use crate::cutting::stock::{Cutter, RayCut};
use crate::cutting::tool::{ConvexPiece, Tool};
use crate::math::{Aabb, Point3, Real, UnitVector3, Vector3, tol};
use std::sync::Arc;

/// Agreement (mm) between numeric and closed-form interval ends on the
/// same piece, asserted by the tests: 1 nm, a thousandth of the µm scale the twin resolves
/// and ten bracket widths ([`NUMERIC_T_TOL`]), leaving room for grazing rays.
pub const NUMERIC_AGREEMENT: Real = 1e-6;

/// Distance (mm) outside the circumscribed cylinder's interval at which the numeric search
/// starts, so both ends of its bracket are strictly outside the piece: 1 µm, far above the
/// closed form's rounding and small enough to cost the root search two or three steps.
const BOX_MARGIN: Real = 1e-3;

/// Width (mm) of the final root bracket of a numerically solved interval end: 0.1 nm,
/// as [`tol::FEASIBILITY`], far below the µm scale and above rounding at 1,000 mm.
pub const NUMERIC_T_TOL: Real = 1e-10;

/// Relative width of Brent's final bracket (of the move parameter s ∈ [0, 1] in φ). The
/// gauge has slope ≤ |d| in s, so where its minimum over s is a kink φ errs by at most
/// ~4·|d|·1e-9 mm (4e-8 mm for a 10 mm move); at a smooth minimum the error is quadratic
/// and negligible. Smaller values cost Brent many forced minimal steps.
const NUMERIC_S_TOL: Real = 1e-9;

/// How the pieces are solved.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum PieceMethod {
    /// Closed forms for frusta and sphere zones, the numeric search for torus zones.
    #[default]
    ClosedForm,
    /// The numeric search for every piece (cross-checks and the bench).
    Numeric,
}

/// A tool with its tip moving from `tip` to `tip + d`, axis `v`, as a [`Cutter`].
#[derive(Clone, Debug)]
pub struct SweptTool {
    pieces: Arc<[ConvexPiece]>,
    tip: Point3,
    d: Vector3,
    v: UnitVector3,
    /// A unit vector perpendicular to `v` (the radial direction for axial support queries).
    perp: Vector3,
    boxes: Vec<Aabb>,
    bounds: Aabb,
    method: PieceMethod,
    /// Whether tip, move and axis are finite; a non-finite sweep cuts nothing.
    finite: bool,
}

impl SweptTool {
    /// The sweep of `tool` with its tip from `tip` to `tip + d`, axis `v`, closed forms
    /// where they exist.
    pub fn new(tool: &Tool, tip: Point3, d: Vector3, v: UnitVector3) -> Self {
        Self::with_method(tool, tip, d, v, PieceMethod::ClosedForm)
    }

    /// As [`SweptTool::new`] with the piece method chosen.
    pub fn with_method(
        tool: &Tool,
        tip: Point3,
        d: Vector3,
        v: UnitVector3,
        method: PieceMethod,
    ) -> Self {
        let pieces = tool.pieces().clone();
        let vv = v.into_inner();
        let boxes: Vec<Aabb> = pieces
            .iter()
            .map(|p| {
                let (h0, h1) = p.heights();
                let rm = p.max_radius();
                let ext = Vector3::from_fn(|k, _| rm * (1.0 - vv[k] * vv[k]).max(0.0).sqrt());
                let mut b = Aabb::empty();
                for base in [tip, tip + d] {
                    for h in [h0, h1] {
                        let c = base + vv * h;
                        b.grow(&(c - ext));
                        b.grow(&(c + ext));
                    }
                }
                b
            })
            .collect();
        let mut bounds = Aabb::empty();
        for b in &boxes {
            bounds.grow(&b.min);
            bounds.grow(&b.max);
        }
        let helper = if vv.x.abs() < 0.9 {
            Vector3::x()
        } else {
            Vector3::y()
        };
        let perp = (helper - vv * vv.dot(&helper)).normalize();
        let finite = tip
            .coords
            .iter()
            .chain(d.iter())
            .chain(vv.iter())
            .all(|x| x.is_finite());
        Self {
            pieces,
            tip,
            d,
            v,
            perp,
            boxes,
            bounds,
            method,
            finite,
        }
    }

    /// The merged intervals of the ray `origin + t·e` (`e` unit) inside the swept volume,
    /// sorted, appended to `out`. Normals are the remaining material's (into the cut).
    pub fn intervals(&self, origin: &Point3, e: &Vector3, out: &mut Vec<RayCut>) {
        let ray_finite = origin.coords.iter().chain(e.iter()).all(|x| x.is_finite());
        if !(self.finite && ray_finite) {
            return;
        }
        // Up to 8 pieces (every catalogue tool) without allocating; profiles with more
        // pieces (chorded concave arcs) spill into a vector.
        let mut fixed = [RawCut::EMPTY; 8];
        let mut spill: Vec<RawCut> = Vec::new();
        let mut n = 0;
        for (piece, bx) in self.pieces.iter().zip(&self.boxes) {
            let Some((b0, b1)) = bx.ray_interval(origin, e) else {
                continue;
            };
            let cut = match (self.method, piece) {
                (PieceMethod::ClosedForm, ConvexPiece::Frustum { .. }) => {
                    self.closed_form(piece, origin, e)
                }
                (PieceMethod::ClosedForm, ConvexPiece::Zone { c, .. }) if c[0] == 0.0 => {
                    self.closed_form(piece, origin, e)
                }
                _ => self.numeric(piece, origin, e, b0, b1),
            };
            if let Some(c) = cut {
                if n < fixed.len() {
                    fixed[n] = c;
                } else {
                    if spill.is_empty() {
                        spill.extend_from_slice(&fixed);
                    }
                    spill.push(c);
                }
                n += 1;
            }
        }
        if spill.is_empty() {
            merge_into(&mut fixed[..n], out);
        } else {
            merge_into(&mut spill, out);
        }
    }

    /// Closed-form interval of a frustum or sphere zone's sweep.
    fn closed_form(&self, piece: &ConvexPiece, origin: &Point3, e: &Vector3) -> Option<RawCut> {
        let v = self.v.into_inner();
        let w0 = origin - self.tip;
        let md = -self.d;
        // Height above the tip: h(t, s) = av + t·ae + s·ad.
        let (av, ae, ad) = (v.dot(&w0), v.dot(e), v.dot(&md));
        let (h0, h1) = piece.heights();
        let s_lines = [
            Line::new(0.0, -1.0, 0.0, tol::PARAMETER, None),
            Line::new(0.0, 1.0, -1.0, tol::PARAMETER, None),
        ];
        let lines = [
            s_lines[0],
            s_lines[1],
            Line::new(-ae, -ad, h0 - av, tol::FEASIBILITY, Some(-v)),
            Line::new(ae, ad, av - h1, tol::FEASIBILITY, Some(v)),
        ];
        let (quad, radial) = match *piece {
            ConvexPiece::Frustum { h0, h1, r0, r1 } => {
                let perp = |x: Vector3| x - v * v.dot(&x);
                let (pw, pe, pd) = (perp(w0), perp(*e), perp(md));
                let k = (r1 - r0) / (h1 - h0);
                // Radius bound L(t, s) = l0 + lt·t + ls·s.
                let (l0, lt, ls) = (r0 + k * (av - h0), k * ae, k * ad);
                let rm = r0.max(r1);
                (
                    Quadric {
                        a: pe.dot(&pe) - lt * lt,
                        b: pe.dot(&pd) - lt * ls,
                        c: pd.dot(&pd) - ls * ls,
                        d: pw.dot(&pe) - l0 * lt,
                        e: pw.dot(&pd) - l0 * ls,
                        f: pw.dot(&pw) - l0 * l0,
                        tol: tol::FEASIBILITY * (1.0 + rm * rm),
                    },
                    Radial::Cone { k },
                )
            }
            ConvexPiece::Zone { c, rho, .. } => {
                let wc = w0 - v * c[1];
                (
                    Quadric {
                        a: e.dot(e),
                        b: e.dot(&md),
                        c: md.dot(&md),
                        d: wc.dot(e),
                        e: wc.dot(&md),
                        f: wc.dot(&wc) - rho * rho,
                        tol: tol::FEASIBILITY * (1.0 + rho * rho),
                    },
                    Radial::Sphere { hc: c[1] },
                )
            }
        };
        let (t0, s0, t1, s1) = t_extremes(&quad, &lines)?;
        let normal = |t: Real, s: Real, entry: bool| {
            let p = w0 + e * t + md * s;
            let mut best: Option<Vector3> = None;
            let score = |n: &Vector3| if entry { n.dot(e) } else { -n.dot(e) };
            let mut offer = |n: Option<Vector3>| {
                if let Some(n) = n
                    && best.is_none_or(|b| score(&n) < score(&b))
                {
                    best = Some(n);
                }
            };
            if quad.eval(t, s).abs() <= quad.tol.max(tol::ON_SURFACE) {
                offer(match radial {
                    Radial::Cone { k } => {
                        let rad = p - v * v.dot(&p);
                        rad.try_normalize(0.0)
                            .map(|rh| (rh - v * k) / (1.0 + k * k).sqrt())
                    }
                    Radial::Sphere { hc } => (p - v * hc).try_normalize(0.0),
                });
            }
            for l in &lines[2..] {
                if l.eval(t, s).abs() <= tol::ON_SURFACE {
                    offer(l.normal);
                }
            }
            best.unwrap_or(if entry { -e } else { *e })
        };
        Some(RawCut {
            t0,
            n0: normal(t0, s0, true),
            t1,
            n1: normal(t1, s1, false),
        })
    }

    /// A piece without a closed form: φ(t) (see [`SweptTool::phi`]) is convex along the ray.
    /// Closed-form sweeps of a circumscribed cylinder and an inscribed chord frustum bracket
    /// it and usually give an interior point; otherwise Brent's method looks for one
    /// (stopping at the first φ ≤ 0). Each end then by a sign-bracketing root search.
    fn numeric(
        &self,
        piece: &ConvexPiece,
        origin: &Point3,
        e: &Vector3,
        b0: Real,
        b1: Real,
    ) -> Option<RawCut> {
        if !(b0.is_finite() && b1.is_finite()) {
            return None;
        }
        let phi = |t: Real| self.phi(piece, &(origin + e * t));
        // Closed-form brackets: the circumscribed cylinder (radius the piece's largest, same
        // heights) holds the piece, the chord frustum through its ends lies inside it (an
        // outward arc stands outside its chord). A ray missing the cylinder's sweep misses;
        // one inside the chord frustum's sweep has an interior point.
        let (h0, h1) = piece.heights();
        let rm = piece.max_radius();
        let outer = ConvexPiece::Frustum {
            h0,
            h1,
            r0: rm,
            r1: rm,
        };
        let oc = self.closed_form(&outer, origin, e)?;
        let (a, b) = (oc.t0 - BOX_MARGIN, oc.t1 + BOX_MARGIN);
        let inner = match *piece {
            ConvexPiece::Zone { c, rho, th0, th1 } => ConvexPiece::Frustum {
                h0,
                h1,
                r0: (c[0] + rho * th0.cos()).max(0.0),
                r1: (c[0] + rho * th1.cos()).max(0.0),
            },
            frustum => frustum,
        };
        let chord_mid = self
            .closed_form(&inner, origin, e)
            .map(|c| 0.5 * (c.t0 + c.t1))
            .filter(|&t| phi(t).0 <= 0.0);
        let mid = match chord_mid {
            Some(t) => t,
            None => {
                let (t, f) = brent_min(a, b, |t| phi(t).0, NUMERIC_S_TOL, true);
                if f > 0.0 {
                    // No interior point: a miss, or a grazing touch thinner than the tolerances.
                    return None;
                }
                t
            }
        };
        let at_mid = phi(mid);
        let (t0, s0) = refine(&phi, mid, at_mid, a, a);
        let (t1, s1) = refine(&phi, mid, at_mid, b, b);
        let x0 = origin + e * t0 - self.tip - self.d * s0;
        let x1 = origin + e * t1 - self.tip - self.d * s1;
        Some(RawCut {
            t0,
            n0: self.piece_normal(piece, &x0, e, true),
            t1,
            n1: self.piece_normal(piece, &x1, e, false),
        })
    }

    /// φ(x) = min over s ∈ [0, 1] of the piece's gauge at x − s·d, and the minimising s:
    /// convex along any ray, ≤ 0 exactly on the swept piece.
    fn phi(&self, piece: &ConvexPiece, x: &Point3) -> (Real, Real) {
        let v = self.v.into_inner();
        let w = x - self.tip;
        let f = |s: Real| piece_gauge(piece, &(w - self.d * s), &v);
        if self.d.norm() <= tol::LENGTH_EPS {
            (f(0.0), 0.0)
        } else {
            let (s, fs) = brent_min(0.0, 1.0, f, NUMERIC_S_TOL, false);
            (fs, s)
        }
    }

    /// The piece's outward normal at the point `p` (relative to the tip, on or in the piece):
    /// the gradient of the active constraint, the one most against (entry) or along (exit)
    /// the ray among those within [`tol::ON_SURFACE`] of the largest.
    fn piece_normal(&self, piece: &ConvexPiece, p: &Vector3, e: &Vector3, entry: bool) -> Vector3 {
        let v = self.v.into_inner();
        let h = v.dot(p);
        let radial = p - v * h;
        let rhat = radial.try_normalize(0.0).unwrap_or(self.perp);
        let r = radial.norm();
        let (h0, h1) = piece.heights();
        let side = match *piece {
            ConvexPiece::Frustum { h0, h1, r0, r1 } => {
                let k = (r1 - r0) / (h1 - h0);
                (
                    (r - (r0 + k * (h - h0))) / (1.0 + k * k).sqrt(),
                    (rhat - v * k) / (1.0 + k * k).sqrt(),
                )
            }
            ConvexPiece::Zone { c, rho, .. } => {
                let dr = if c[0] > 0.0 {
                    (r - c[0]).max(0.0)
                } else {
                    r - c[0]
                };
                let dh = h - c[1];
                let len = dr.hypot(dh);
                let n = if len > 0.0 {
                    (rhat * dr + v * dh) / len
                } else {
                    rhat
                };
                (len - rho, n)
            }
        };
        let cands = [(h0 - h, -v), (h - h1, v), side];
        let top = cands
            .iter()
            .map(|c| c.0)
            .fold(Real::NEG_INFINITY, Real::max);
        let score = |n: &Vector3| if entry { n.dot(e) } else { -n.dot(e) };
        cands
            .iter()
            .filter(|c| c.0 >= top - tol::ON_SURFACE)
            .map(|c| c.1)
            .min_by(|a, b| score(a).total_cmp(&score(b)))
            .unwrap_or(if entry { -e } else { *e })
    }
}

/// The end of the interval on the side of `far` (a parameter outside the piece's box), from
/// an estimate `g` and a parameter `inside` with φ(inside) = `at_inside` ≤ 0: a sign
/// bracket of the convex φ(t) shrunk by the Illinois variant of regula falsi (superlinear,
/// never leaves the bracket) to [`NUMERIC_T_TOL`]. Returns the inside end of the final
/// bracket and its move parameter.
fn refine(
    phi: &dyn Fn(Real) -> (Real, Real),
    inside: Real,
    at_inside: (Real, Real),
    g: Real,
    far: Real,
) -> (Real, Real) {
    let dir = (far - inside).signum();
    // g is normally outside already; step out by doubling steps if it is inside.
    let mut out = g;
    let mut f_out = phi(out).0;
    let mut step = NUMERIC_T_TOL;
    while f_out <= 0.0 {
        out += dir * step;
        step *= 2.0;
        if (out - far) * dir >= 0.0 {
            out = far;
            f_out = phi(far).0;
            break;
        }
        f_out = phi(out).0;
    }
    if f_out <= 0.0 {
        return (out, phi(out).1);
    }
    let (mut inn, (mut f_in, mut s_in)) = (inside, at_inside);
    let mut last = 0i8;
    for _ in 0..200 {
        if (out - inn).abs() <= NUMERIC_T_TOL {
            break;
        }
        let mut m = inn - f_in * (out - inn) / (f_out - f_in);
        if !(m.is_finite() && (m - inn) * dir > 0.0 && (out - m) * dir > 0.0) {
            m = 0.5 * (inn + out);
        }
        if m == inn || m == out {
            // Far from the origin the bracket cannot shrink below one ulp.
            break;
        }
        let (f_m, s_m) = phi(m);
        if f_m <= 0.0 {
            inn = m;
            f_in = f_m;
            s_in = s_m;
            if last == -1 {
                f_out *= 0.5;
            }
            last = -1;
        } else {
            out = m;
            f_out = f_m;
            if last == 1 {
                f_in *= 0.5;
            }
            last = 1;
        }
    }
    (inn, s_in)
}

/// A convex function of the point `p` (relative to the tip) that is ≤ 0 exactly on the
/// piece, with slope at most 1 per mm (a distance, or the larger of distances to planes).
fn piece_gauge(piece: &ConvexPiece, p: &Vector3, v: &Vector3) -> Real {
    let h = v.dot(p);
    let r = (p - v * h).norm();
    let (h0, h1) = piece.heights();
    let side = match *piece {
        ConvexPiece::Frustum { h0, h1, r0, r1 } => {
            let k = (r1 - r0) / (h1 - h0);
            (r - (r0 + k * (h - h0))) / (1.0 + k * k).sqrt()
        }
        ConvexPiece::Zone { c, rho, .. } => {
            // Distance to the disk (or, for a centre left of the axis, to the ring) minus ρ.
            let dr = if c[0] > 0.0 {
                (r - c[0]).max(0.0)
            } else {
                r - c[0]
            };
            dr.hypot(h - c[1]) - rho
        }
    };
    side.max(h0 - h).max(h - h1)
}

/// Minimum of `f` on [lo, hi]: (argument, value). Brent's method (parabolic steps where `f`
/// is smooth and finite, golden-section steps otherwise, so `+∞` may stand for "undefined";
/// R. P. Brent, *Algorithms for Minimization without Derivatives*, 1973, ch. 5) until the
/// bracket is below `rel_tol` relative to (|x| + hi − lo), then compared with both ends (a
/// minimum at an end is exact). With `stop_at_nonpositive` it returns at the first value ≤ 0.
/// Exact for convex `f`; for others a local minimum.
pub(crate) fn brent_min(
    lo: Real,
    hi: Real,
    f: impl Fn(Real) -> Real,
    rel_tol: Real,
    stop_at_nonpositive: bool,
) -> (Real, Real) {
    const C: Real = 0.381_966_011_250_105_1; // (3 − √5)/2
    let (mut a, mut b): (Real, Real) = (lo, hi);
    let scale = hi - lo;
    let mut x = a + C * (b - a);
    let (mut w, mut v) = (x, x);
    let mut fx = f(x);
    let (mut fw, mut fv) = (fx, fx);
    let (mut d, mut e): (Real, Real) = (0.0, 0.0);
    for _ in 0..300 {
        let m = 0.5 * (a + b);
        if stop_at_nonpositive && fx <= 0.0 {
            return (x, fx);
        }
        let tol1 = rel_tol * (x.abs() + scale);
        let tol2 = 2.0 * tol1;
        if (x - m).abs() <= tol2 - 0.5 * (b - a) {
            break;
        }
        let mut golden = true;
        if e.abs() > tol1 && fx.is_finite() && fw.is_finite() && fv.is_finite() {
            let r = (x - w) * (fx - fv);
            let mut q = (x - v) * (fx - fw);
            let mut p = (x - v) * q - (x - w) * r;
            q = 2.0 * (q - r);
            if q > 0.0 {
                p = -p;
            } else {
                q = -q;
            }
            let e_old = e;
            e = d;
            if p.abs() < (0.5 * q * e_old).abs() && p > q * (a - x) && p < q * (b - x) {
                d = p / q;
                let u = x + d;
                if u - a < tol2 || b - u < tol2 {
                    d = if x < m { tol1 } else { -tol1 };
                }
                golden = false;
            }
        }
        if golden {
            e = if x < m { b - x } else { a - x };
            d = C * e;
        }
        let u = if d.abs() >= tol1 {
            x + d
        } else if d > 0.0 {
            x + tol1
        } else {
            x - tol1
        };
        let fu = f(u);
        if fu <= fx {
            if u < x {
                b = x;
            } else {
                a = x;
            }
            (v, fv, w, fw, x, fx) = (w, fw, x, fx, u, fu);
        } else {
            if u < x {
                a = u;
            } else {
                b = u;
            }
            if fu <= fw || w == x {
                (v, fv, w, fw) = (w, fw, u, fu);
            } else if fu <= fv || v == x || v == w {
                (v, fv) = (u, fu);
            }
        }
    }
    [(lo, f(lo)), (hi, f(hi)), (x, fx)]
        .into_iter()
        .min_by(|p, q| p.1.total_cmp(&q.1))
        .unwrap_or((x, fx))
}

impl Cutter for SweptTool {
    fn bounds(&self) -> Aabb {
        self.bounds
    }

    /// The hull of the ray's intervals (exact for convex tools; the stock uses
    /// [`Cutter::ray_cuts`], which keeps the gaps of non-convex ones).
    fn ray_cut(&self, origin: &Point3, axis: usize) -> Option<RayCut> {
        let mut e = Vector3::zeros();
        e[axis] = 1.0;
        let mut out = Vec::new();
        self.intervals(origin, &e, &mut out);
        RayCut::hull(&out)
    }

    fn ray_cuts(&self, origin: &Point3, axis: usize, out: &mut Vec<RayCut>) {
        let mut e = Vector3::zeros();
        e[axis] = 1.0;
        self.intervals(origin, &e, out);
    }
}

/// One piece's interval with the tool's outward normals at its ends.
#[derive(Clone, Copy, Debug)]
struct RawCut {
    t0: Real,
    n0: Vector3,
    t1: Real,
    n1: Vector3,
}

impl RawCut {
    const EMPTY: RawCut = RawCut {
        t0: 0.0,
        n0: Vector3::new(0.0, 0.0, 0.0),
        t1: 0.0,
        n1: Vector3::new(0.0, 0.0, 0.0),
    };
}

/// Sorts the pieces' intervals, merges those that overlap or leave less than
/// [`tol::SLIVER`] between them, and appends the results as material cuts.
fn merge_into(list: &mut [RawCut], out: &mut Vec<RayCut>) {
    list.sort_by(|a, b| a.t0.total_cmp(&b.t0).then(a.t1.total_cmp(&b.t1)));
    let mut cur: Option<RawCut> = None;
    let emit = |c: RawCut, out: &mut Vec<RayCut>| {
        if c.t1 - c.t0 > tol::LENGTH_EPS {
            out.push(RayCut {
                t_in: c.t0,
                t_out: c.t1,
                // Material normals point into the removed region: opposite the tool's.
                n_in: -c.n0,
                n_out: -c.n1,
            });
        }
    };
    for c in list.iter() {
        cur = Some(match cur {
            Some(mut m) if c.t0 <= m.t1 + tol::SLIVER => {
                if c.t1 > m.t1 {
                    m.t1 = c.t1;
                    m.n1 = c.n1;
                }
                m
            }
            Some(m) => {
                emit(m, out);
                *c
            }
            None => *c,
        });
    }
    if let Some(m) = cur {
        emit(m, out);
    }
}

#[derive(Clone, Copy, Debug)]
enum Radial {
    /// Frustum side of slope `k = dr/dh`.
    Cone { k: Real },
    /// Sphere about the axis point at height `hc`.
    Sphere { hc: Real },
}

/// A conic constraint `Q(t,s) = a t² + 2b ts + c s² + 2d t + 2e s + f ≤ 0`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Quadric {
    pub(crate) a: Real,
    pub(crate) b: Real,
    pub(crate) c: Real,
    pub(crate) d: Real,
    pub(crate) e: Real,
    pub(crate) f: Real,
    pub(crate) tol: Real,
}

impl Quadric {
    pub(crate) fn eval(&self, t: Real, s: Real) -> Real {
        self.a * t * t
            + 2.0 * self.b * t * s
            + self.c * s * s
            + 2.0 * self.d * t
            + 2.0 * self.e * s
            + self.f
    }
}

/// A linear constraint `p t + q s + r ≤ 0` with the tool-outward normal of the face it bounds.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Line {
    pub(crate) p: Real,
    pub(crate) q: Real,
    pub(crate) r: Real,
    pub(crate) tol: Real,
    pub(crate) normal: Option<Vector3>,
}

impl Line {
    fn new(p: Real, q: Real, r: Real, tol: Real, normal: Option<Vector3>) -> Self {
        Self {
            p,
            q,
            r,
            tol,
            normal,
        }
    }

    pub(crate) fn eval(&self, t: Real, s: Real) -> Real {
        self.p * t + self.q * s + self.r
    }
}

/// Real roots of `A x² + 2B x + C = 0` (both if double).
pub(crate) fn roots(a: Real, b: Real, c: Real) -> [Option<Real>; 2] {
    let scale = a.abs().max(b.abs()).max(c.abs());
    if scale == 0.0 {
        return [None, None];
    }
    if a.abs() <= tol::RELATIVE_EPS * scale {
        return [(b != 0.0).then(|| -c / (2.0 * b)), None];
    }
    let disc = b * b - a * c;
    if disc < 0.0 {
        return [None, None];
    }
    let sq = disc.sqrt();
    let qv = -(b + b.signum() * sq);
    if qv == 0.0 {
        return [Some(0.0), Some(0.0)];
    }
    [Some(qv / a), Some(c / qv)]
}

/// Extremes of `t` over the convex set `{Q ≤ 0} ∩ lines`: (t_min, s there, t_max, s there),
/// the smallest such `s` among candidates tied on `t`.
/// Candidates: the conic's points with ∂Q/∂s = 0, line ∩ conic, line ∩ line; only feasible
/// ones count, so a spurious candidate can never widen the interval beyond tolerance.
pub(crate) fn t_extremes(q: &Quadric, lines: &[Line]) -> Option<(Real, Real, Real, Real)> {
    let mut best: Option<(Real, Real, Real, Real)> = None;
    let mut consider = |t: Real, s: Real| {
        if !(t.is_finite() && s.is_finite()) {
            return;
        }
        if q.eval(t, s) > q.tol || lines.iter().any(|l| l.eval(t, s) > l.tol) {
            return;
        }
        best = Some(match best {
            None => (t, s, t, s),
            Some((t0, s0, t1, s1)) => {
                // On a tie the smaller s: the earliest tool position reaching the extreme.
                let (t0, s0) = if t < t0 || (t == t0 && s < s0) {
                    (t, s)
                } else {
                    (t0, s0)
                };
                let (t1, s1) = if t > t1 || (t == t1 && s < s1) {
                    (t, s)
                } else {
                    (t1, s1)
                };
                (t0, s0, t1, s1)
            }
        });
    };
    // (a) ∂Q/∂s = 0 → s = −(b t + e)/c, substituted into Q = 0.
    let scale = q.a.abs().max(q.b.abs()).max(q.c.abs());
    if q.c.abs() > tol::RELATIVE_EPS * scale {
        let det = q.a * q.c - q.b * q.b;
        for t in roots(det, q.d * q.c - q.b * q.e, q.f * q.c - q.e * q.e)
            .into_iter()
            .flatten()
        {
            consider(t, -(q.b * t + q.e) / q.c);
        }
    }
    // (b) Each line ∩ the conic.
    for l in lines {
        if l.p == 0.0 && l.q == 0.0 {
            continue;
        }
        if l.q.abs() >= l.p.abs() {
            let (al, be) = (-l.p / l.q, -l.r / l.q);
            let a2 = q.a + 2.0 * q.b * al + q.c * al * al;
            let b2 = q.b * be + q.c * al * be + q.d + q.e * al;
            let c2 = q.c * be * be + 2.0 * q.e * be + q.f;
            for t in roots(a2, b2, c2).into_iter().flatten() {
                consider(t, al * t + be);
            }
        } else {
            let (al, be) = (-l.q / l.p, -l.r / l.p);
            let a2 = q.a * al * al + 2.0 * q.b * al + q.c;
            let b2 = q.a * al * be + q.b * be + q.d * al + q.e;
            let c2 = q.a * be * be + 2.0 * q.d * be + q.f;
            for s in roots(a2, b2, c2).into_iter().flatten() {
                consider(al * s + be, s);
            }
        }
    }
    // (c) Each pair of lines.
    for (i, l1) in lines.iter().enumerate() {
        for l2 in &lines[i + 1..] {
            let det = l1.p * l2.q - l1.q * l2.p;
            if det.abs() > tol::RELATIVE_EPS * (l1.p.abs() + l1.q.abs()) * (l2.p.abs() + l2.q.abs())
            {
                let t = (-l1.r * l2.q + l1.q * l2.r) / det;
                let s = (-l1.p * l2.r + l1.r * l2.p) / det;
                consider(t, s);
            }
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cutting::tool::ProfileStep;
    use proptest::prelude::*;

    /// Spatial resolution (mm) of the brute-force check: points the intervals call inside
    /// must lie in the tool dilated by δ at some sampled move parameter, points called
    /// outside must not lie in the tool eroded by δ at any sampled parameter. The move is
    /// sampled every δ, so sampling alone moves the brute force by at most δ/2.
    const DELTA: Real = 1e-3;

    /// A test tool with its profile radius r(h) written out by hand, independently of the
    /// library's profile code.
    struct Case {
        tool: Tool,
        r_of_h: Box<dyn Fn(Real) -> Option<Real>>,
    }

    fn form_cutter_steps() -> Vec<ProfileStep> {
        vec![
            ProfileStep::Line { to: [1.0, 0.0] },
            ProfileStep::Arc {
                to: [2.0, 1.0],
                center: [1.0, 1.0],
                convex: true,
            },
            ProfileStep::Arc {
                to: [1.2, 1.8],
                center: [2.0, 1.8],
                convex: false,
            },
            ProfileStep::Line { to: [1.2, 3.0] },
            ProfileStep::Line { to: [1.6, 3.0] },
            ProfileStep::Line { to: [2.5, 3.5] },
            ProfileStep::Line { to: [2.5, 5.0] },
            ProfileStep::Line { to: [0.0, 5.0] },
        ]
    }

    /// r(h) of the form cutter: torus corner, concave neck, step, cone, cylinder.
    fn form_cutter_r(h: Real) -> Option<Real> {
        Some(match h {
            h if !(0.0..=5.0).contains(&h) => return None,
            h if h <= 1.0 => 1.0 + (1.0 - (1.0 - h).powi(2)).max(0.0).sqrt(),
            h if h <= 1.8 => 2.0 - (0.64 - (h - 1.8).powi(2)).max(0.0).sqrt(),
            h if h < 3.0 => 1.2,
            h if h <= 3.5 => 1.6 + (h - 3.0) * 1.8,
            _ => 2.5,
        })
    }

    fn case(kind: usize, a: Real, b: Real) -> Case {
        // a ∈ [0, 1], b ∈ [0, 1] pick sizes within each family.
        let len = 8.0;
        match kind {
            0 => {
                let r = 1.0 + 2.0 * a;
                Case {
                    tool: Tool::try_new(crate::cutting::tool::ToolKind::Flat, 2.0 * r, len)
                        .expect("valid"),
                    r_of_h: Box::new(move |h| (0.0..=len).contains(&h).then_some(r)),
                }
            }
            1 => {
                let r = 1.0 + 2.0 * a;
                Case {
                    tool: Tool::try_new(crate::cutting::tool::ToolKind::Ball, 2.0 * r, len)
                        .expect("valid"),
                    r_of_h: Box::new(move |h| {
                        (0.0..=len).contains(&h).then(|| {
                            if h < r {
                                (r * r - (r - h).powi(2)).max(0.0).sqrt()
                            } else {
                                r
                            }
                        })
                    }),
                }
            }
            2 => {
                let r = 1.0 + 2.0 * a;
                let rc = (0.1 + 0.9 * b) * r;
                let c = r - rc;
                Case {
                    tool: Tool::try_bull_nose(2.0 * r, rc, len).expect("valid"),
                    r_of_h: Box::new(move |h| {
                        (0.0..=len).contains(&h).then(|| {
                            if h < rc {
                                c + (rc * rc - (rc - h).powi(2)).max(0.0).sqrt()
                            } else {
                                r
                            }
                        })
                    }),
                }
            }
            3 => {
                let rt = 0.3 + a;
                let deg: Real = 3.0 + 40.0 * b;
                let k = deg.to_radians().tan();
                Case {
                    tool: Tool::try_tapered_flat(2.0 * rt, deg, len).expect("valid"),
                    r_of_h: Box::new(move |h| (0.0..=len).contains(&h).then_some(rt + k * h)),
                }
            }
            4 => {
                let rho = 0.5 + a;
                let deg: Real = 3.0 + 40.0 * b;
                let al = deg.to_radians();
                // Tangency: where the circle's slope dr/dh equals tan α.
                let ht = rho - rho * al.sin();
                let rt = rho * al.cos();
                Case {
                    tool: Tool::try_tapered_ball(2.0 * rho, deg, len).expect("valid"),
                    r_of_h: Box::new(move |h| {
                        (0.0..=len).contains(&h).then(|| {
                            if h < ht {
                                (rho * rho - (rho - h).powi(2)).max(0.0).sqrt()
                            } else {
                                rt + (h - ht) * al.tan()
                            }
                        })
                    }),
                }
            }
            _ => Case {
                tool: Tool::try_profile(&form_cutter_steps()).expect("valid"),
                r_of_h: Box::new(form_cutter_r),
            },
        }
    }

    /// Largest and smallest r(h') over the box neighbourhood |h' − h| ≤ δ (9 samples).
    fn r_range(case: &Case, h: Real) -> (Option<Real>, Option<Real>) {
        let (mut lo, mut hi): (Option<Real>, Option<Real>) = (None, None);
        let mut all = true;
        for i in 0..=8 {
            let hh = h - DELTA + 2.0 * DELTA * i as Real / 8.0;
            match (case.r_of_h)(hh) {
                Some(r) => {
                    hi = Some(hi.map_or(r, |x: Real| x.max(r)));
                    lo = Some(lo.map_or(r, |x: Real| x.min(r)));
                }
                None => all = false,
            }
        }
        (hi, if all { lo } else { None })
    }

    /// Brute force: (inside the δ-dilated sweep, inside the δ-eroded sweep) at `x`.
    fn brute(case: &Case, tip: &Point3, d: &Vector3, v: &Vector3, x: &Point3) -> (bool, bool) {
        let m = (d.norm() / DELTA).ceil() as usize + 1;
        let (mut dil, mut ero) = (false, false);
        for i in 0..=m {
            let s = i as Real / m as Real;
            let w = x - (tip + d * s);
            let h = v.dot(&w);
            let r = (w - v * h).norm();
            let (hi, lo) = r_range(case, h);
            dil |= hi.is_some_and(|rad| r <= rad + DELTA);
            ero |= lo.is_some_and(|rad| r + DELTA <= rad);
            if dil && ero {
                break;
            }
        }
        (dil, ero)
    }

    fn inside(cuts: &[RayCut], t: Real) -> bool {
        cuts.iter().any(|c| c.t_in <= t && t <= c.t_out)
    }

    fn unit(x: Real, y: Real, z: Real) -> Vector3 {
        let v = Vector3::new(x, y, z);
        if v.norm() < 1e-3 {
            Vector3::z()
        } else {
            v.normalize()
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 96, ..ProptestConfig::default() })]

        /// Every tool kind: the merged intervals agree with the brute-force point-in-sweep
        /// test to δ, at random points on the ray and just inside/outside every interval end.
        #[test]
        fn intervals_agree_with_brute_force(
            kind in 0usize..6, a in 0.0..1.0f64, b in 0.0..1.0f64,
            vx in -0.5..0.5f64, vy in -0.5..0.5f64,
            dx in -6.0..6.0f64, dy in -6.0..6.0f64, dz in -3.0..3.0f64,
            ox in -4.0..4.0f64, oy in -4.0..4.0f64, oz in -1.0..7.0f64,
            ex in -1.0..1.0f64, ey in -1.0..1.0f64, ez in -1.0..1.0f64,
            axis_aligned in any::<bool>(),
        ) {
            let c = case(kind, a, b);
            let v = UnitVector3::new_normalize(Vector3::new(vx, vy, 1.0));
            let tip = Point3::new(0.0, 0.0, 0.0);
            let d = Vector3::new(dx, dy, dz);
            let e = if axis_aligned { let mut e = Vector3::zeros(); e[kind % 3] = 1.0; e } else { unit(ex, ey, ez) };
            let o = Point3::new(ox, oy, oz);
            let swept = SweptTool::new(&c.tool, tip, d, v);
            let mut cuts = Vec::new();
            swept.intervals(&o, &e, &mut cuts);
            for w in cuts.windows(2) {
                prop_assert!(w[0].t_out < w[1].t_in, "intervals not sorted/disjoint: {cuts:?}");
            }
            let mut ts: Vec<Real> = (0..40).map(|i| -15.0 + 30.0 * i as Real / 40.0 + 0.37).collect();
            for cut in &cuts {
                for t in [cut.t_in, cut.t_out] {
                    ts.push(t - 1e-9);
                    ts.push(t + 1e-9);
                }
            }
            for t in ts {
                let x = o + e * t;
                let (dil, ero) = brute(&c, &tip, &d, &v.into_inner(), &x);
                if inside(&cuts, t) {
                    prop_assert!(dil, "kind {kind}: t = {t} called inside, brute force outside; {cuts:?}");
                } else {
                    prop_assert!(!ero, "kind {kind}: t = {t} called outside, brute force inside; {cuts:?}");
                }
            }
        }

        /// Closed forms and the numeric search agree on every piece they both solve.
        #[test]
        fn closed_form_agrees_with_numeric(
            kind in 0usize..6, a in 0.0..1.0f64, b in 0.0..1.0f64,
            vx in -0.5..0.5f64, vy in -0.5..0.5f64,
            dx in -6.0..6.0f64, dy in -6.0..6.0f64, dz in -3.0..3.0f64,
            ox in -4.0..4.0f64, oy in -4.0..4.0f64, oz in -1.0..7.0f64,
            ex in -1.0..1.0f64, ey in -1.0..1.0f64, ez in -1.0..1.0f64,
        ) {
            let c = case(kind, a, b);
            let v = UnitVector3::new_normalize(Vector3::new(vx, vy, 1.0));
            let tip = Point3::new(0.3, -0.2, 0.1);
            let d = Vector3::new(dx, dy, dz);
            let e = unit(ex, ey, ez);
            let o = Point3::new(ox, oy, oz);
            let (mut c1, mut c2) = (Vec::new(), Vec::new());
            SweptTool::new(&c.tool, tip, d, v).intervals(&o, &e, &mut c1);
            SweptTool::with_method(&c.tool, tip, d, v, PieceMethod::Numeric).intervals(&o, &e, &mut c2);
            // Grazing rays may see a sliver one way and nothing the other: compare the
            // intervals longer than 1 µm.
            let long = |cs: &[RayCut]| cs.iter().filter(|c| c.t_out - c.t_in > 1e-3).copied().collect::<Vec<_>>();
            let (l1, l2) = (long(&c1), long(&c2));
            prop_assert_eq!(l1.len(), l2.len(), "{:?} vs {:?}", c1, c2);
            for (p, q) in l1.iter().zip(&l2) {
                prop_assert!((p.t_in - q.t_in).abs() < NUMERIC_AGREEMENT && (p.t_out - q.t_out).abs() < NUMERIC_AGREEMENT,
                    "closed form {p:?} vs numeric {q:?}");
            }
        }
    }

    #[test]
    fn side_cut_of_a_bull_nose_is_the_tangent_plane() {
        // Axis z, moving along x, radius 3, corner 1: a y ray above the corner sees ±3,
        // one through the corner at height h sees ±(2 + sqrt(1 − (1 − h)²)).
        let tool = Tool::try_bull_nose(6.0, 1.0, 20.0).expect("valid");
        let t = SweptTool::new(
            &tool,
            Point3::new(-10.0, 0.0, 0.0),
            Vector3::new(20.0, 0.0, 0.0),
            Vector3::z_axis(),
        );
        let c = t.ray_cut(&Point3::new(0.0, 0.0, 5.0), 1).expect("cuts");
        assert!(
            (c.t_in + 3.0).abs() < 1e-12 && (c.t_out - 3.0).abs() < 1e-12,
            "{c:?}"
        );
        assert!((c.n_in - Vector3::y()).norm() < 1e-9);
        let h: Real = 0.4;
        let want = 2.0 + (1.0 - (1.0 - h).powi(2)).sqrt();
        let c = t.ray_cut(&Point3::new(0.0, 0.0, h), 1).expect("cuts");
        assert!(
            (c.t_in + want).abs() < 1e-9 && (c.t_out - want).abs() < 1e-9,
            "{c:?} want ±{want}"
        );
        // The corner's material normal is the torus normal (radial −y, tilted up).
        let th = (1.0 - h).asin();
        let n = Vector3::new(0.0, th.cos(), th.sin());
        // The contact's move parameter is only pinned to ~sqrt of the bracket width at a
        // silhouette, so the normal is good to ~1e-6 rad (it is stored in f32 anyway).
        assert!((c.n_in - n).norm() < 1e-5, "{:?} vs {n:?}", c.n_in);
    }

    #[test]
    fn a_neck_leaves_two_intervals() {
        // The form cutter standing still, axis z: a z ray at r = 1.5 is inside for
        // h ∈ [h_a, h_b] (corner then neck) and again for h ≥ 3 (step and cone).
        let tool = Tool::try_profile(&form_cutter_steps()).expect("valid");
        let t = SweptTool::new(&tool, Point3::origin(), Vector3::zeros(), Vector3::z_axis());
        let mut out = Vec::new();
        t.intervals(&Point3::new(1.5, 0.0, 0.0), &Vector3::z(), &mut out);
        assert_eq!(out.len(), 2, "{out:?}");
        // Corner: 1 + sqrt(1 − (1 − h)²) = 1.5 → h = 1 − sqrt(0.75).
        let ha = 1.0 - 0.75f64.sqrt();
        // Neck: 2 − sqrt(0.64 − (h − 1.8)²) = 1.5 → h = 1.8 − sqrt(0.39); chords stand
        // proud by at most the concave-arc bound.
        let hb = 1.8 - 0.39f64.sqrt();
        assert!((out[0].t_in - ha).abs() < 1e-9, "{out:?}");
        assert!(
            (out[0].t_out - hb).abs() < 4.0 * crate::cutting::tool::CONCAVE_ARC_BOUND,
            "{out:?}"
        );
        assert!((out[1].t_in - 3.0).abs() < 1e-9 && (out[1].t_out - 5.0).abs() < 1e-9);
    }

    /// Removed volume of a straight horizontal slot, axis z, tip `depth` below the stock
    /// top, moving `len` along x: (K ∩ H) ⊕ segment with H the half-space below the top, so
    /// V = vol(K ∩ H) + len · area(K ∩ H projected along x) = π∫r² dh + len·2∫r dh.
    fn slot_volume(tool: &Tool, depth: Real, len: Real) -> Real {
        slot_volume_at(tool, depth, len, 0.1)
    }

    fn slot_volume_at(tool: &Tool, depth: Real, len: Real, pitch: Real) -> Real {
        let mut stock = crate::cutting::stock::TriDexel::new_box(
            Aabb {
                min: Point3::new(0.0, -6.0, 0.0),
                max: Point3::new(20.0, 6.0, 10.0),
            },
            pitch,
            1e9,
        )
        .expect("fits");
        let before = stock.volume();
        let cut = SweptTool::new(
            tool,
            Point3::new(5.0, 0.0, 10.0 - depth),
            Vector3::new(len, 0.0, 0.0),
            Vector3::z_axis(),
        );
        assert!(stock.remove(&cut, 1));
        before - stock.volume()
    }

    /// The dexel measure integrates each grid by the midpoint rule across its rays: exact
    /// along the rays, but the walls' staircase across them leaves an error that shrinks
    /// with the pitch (checked below); at a 0.1 mm pitch it stays below 0.1 % of these
    /// slots (a few 0.1 mm² cross-sections of wall × 0.1 mm / several hundred mm³).
    const SLOT_REL: Real = 1e-3;

    #[test]
    fn bull_nose_slot_volume_is_analytic() {
        let (r, rc, depth, len) = (3.0, 1.0, 4.0, 10.0);
        let a = r - rc;
        let pi = std::f64::consts::PI;
        // ∫₀^rc (a + sqrt(rc² − (rc − h)²)) dh = a rc + π rc²/4; above the corner r = R.
        let area = 2.0 * (a * rc + pi * rc * rc / 4.0 + r * (depth - rc));
        // ∫₀^rc (a + w)² dh = a² rc + 2a·π rc²/4 + (rc³ − rc³/3).
        let vol = pi
            * (a * a * rc + pi * a * rc * rc / 2.0 + 2.0 * rc.powi(3) / 3.0 + r * r * (depth - rc));
        let want = vol + len * area;
        let got = slot_volume(
            &Tool::try_bull_nose(2.0 * r, rc, 20.0).expect("valid"),
            depth,
            len,
        );
        assert!(
            ((got - want) / want).abs() < SLOT_REL,
            "got {got}, want {want}"
        );
    }

    #[test]
    fn tapered_flat_slot_volume_is_analytic() {
        let (rt, deg, depth, len): (Real, Real, Real, Real) = (1.0, 10.0, 4.0, 10.0);
        let k = deg.to_radians().tan();
        let area = 2.0 * (rt * depth + k * depth * depth / 2.0);
        let vol = std::f64::consts::PI
            * (rt * rt * depth + rt * k * depth * depth + k * k * depth.powi(3) / 3.0);
        let want = vol + len * area;
        let got = slot_volume(
            &Tool::try_tapered_flat(2.0 * rt, deg, 15.0).expect("valid"),
            depth,
            len,
        );
        // The discretisation error shrinks with the pitch.
        let tool = Tool::try_tapered_flat(2.0 * rt, deg, 15.0).expect("valid");
        let coarse = slot_volume_at(&tool, depth, len, 0.2) - want;
        let fine = slot_volume_at(&tool, depth, len, 0.05) - want;
        assert!(
            fine.abs() < coarse.abs() / 4.0,
            "coarse {coarse}, fine {fine}"
        );
        assert!(
            ((got - want) / want).abs() < SLOT_REL,
            "got {got}, want {want}"
        );
    }

    #[test]
    fn tapered_ball_slot_volume_is_analytic() {
        let (rho, deg, depth, len): (Real, Real, Real, Real) = (1.0, 10.0, 4.0, 10.0);
        let (al, pi) = (deg.to_radians(), std::f64::consts::PI);
        let (rt, ht) = (rho * al.cos(), rho * (1.0 - al.sin()));
        let k = al.tan();
        // Ball cap 0 ≤ h ≤ ht: ∫ sqrt(ρ² − (ρ − h)²) dh and ∫ (ρ² − (ρ − h)²) dh.
        let u0 = -rho;
        let u1 = ht - rho;
        let seg = |u: Real| {
            0.5 * (u * (rho * rho - u * u).max(0.0).sqrt() + rho * rho * (u / rho).asin())
        };
        let cap_area = seg(u1) - seg(u0);
        let cap_vol = rho * rho * (u1 - u0) - (u1.powi(3) - u0.powi(3)) / 3.0;
        // Cone ht ≤ h ≤ depth: r = rt + k (h − ht).
        let hc = depth - ht;
        let cone_area = rt * hc + k * hc * hc / 2.0;
        let cone_vol = rt * rt * hc + rt * k * hc * hc + k * k * hc.powi(3) / 3.0;
        let want = pi * (cap_vol + cone_vol) + len * 2.0 * (cap_area + cone_area);
        let got = slot_volume(
            &Tool::try_tapered_ball(2.0 * rho, deg, 15.0).expect("valid"),
            depth,
            len,
        );
        assert!(
            ((got - want) / want).abs() < SLOT_REL,
            "got {got}, want {want}"
        );
    }

    #[test]
    fn a_neck_leaves_a_ring_of_material() {
        // The form cutter plunged straight down 4 mm into the stock (axis z): material
        // remains in the neck, so a z ray at r = 1.5 keeps a segment between the corner and
        // the step: from the neck's h_b to h = 3 above the tip.
        let tool = Tool::try_profile(&form_cutter_steps()).expect("valid");
        let mut stock = crate::cutting::stock::TriDexel::new_box(
            Aabb {
                min: Point3::new(-5.0, -5.0, 0.0),
                max: Point3::new(5.0, 5.0, 10.0),
            },
            0.5,
            1e9,
        )
        .expect("fits");
        // Tip from z = 5 (below the top) with no move: the cutter stands in the stock.
        let cut = SweptTool::new(
            &tool,
            Point3::new(0.0, 0.0, 5.0),
            Vector3::zeros(),
            Vector3::z_axis(),
        );
        assert!(stock.remove(&cut, 3));
        let g = &stock.grids()[2];
        // Ray (iu, iv) at x = 1.25, y = 0.25: r = hypot(1.25, 0.25).
        let (iu, iv) = (12, 10);
        let o = g.ray_origin(iu, iv);
        let r = o.x.hypot(o.y);
        assert!((r - 1.5f64.hypot(0.0) * 0.0 - (1.25f64).hypot(0.25)).abs() < 1e-12);
        let segs = g.ray(iu, iv);
        // The tool's top is the stock's top: below the tool, and the neck ring.
        assert_eq!(segs.len(), 2, "{segs:?}");
        let hb = 1.8 - (0.64 - (2.0 - r).powi(2)).sqrt();
        assert!(
            (segs[1].lo.t - (5.0 + hb)).abs() < 4.0 * crate::cutting::tool::CONCAVE_ARC_BOUND,
            "{segs:?}"
        );
        assert!((segs[1].hi.t - 8.0).abs() < 1e-9, "{segs:?}");
    }

    #[test]
    fn non_finite_moves_cut_nothing() {
        for tool in [
            Tool::try_bull_nose(6.0, 1.0, 10.0).expect("valid"),
            Tool::try_tapered_ball(2.0, 10.0, 10.0).expect("valid"),
        ] {
            for (tip, d) in [
                (Point3::new(Real::NAN, 0.0, 0.0), Vector3::x()),
                (Point3::origin(), Vector3::new(Real::INFINITY, 0.0, 0.0)),
            ] {
                let t = SweptTool::new(&tool, tip, d, Vector3::z_axis());
                for axis in 0..3 {
                    assert!(t.ray_cut(&Point3::new(0.5, 0.5, 0.5), axis).is_none());
                }
            }
        }
    }
}
