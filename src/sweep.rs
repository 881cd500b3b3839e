//! Tool sweep: every move's swept volume, through the deviated chain, removed from the stock.
//!
//! **Straight moves at constant rotary values are exact.** In any chain of linear and rotary
//! axes, holding the rotary values fixed makes the tool's orientation constant and its
//! position an affine function of the linear axis values, so a linearly interpolated move is
//! a pure translation of the tool in the workpiece frame. Flat and ball end mills are convex,
//! so the swept volume is convex, and its interval along a ray is found in closed form: with
//! `t` the ray parameter and `s ∈ [0, 1]` the move parameter, the set of `(t, s)` where the
//! ray point lies inside the tool at `s` is bounded by one convex quadric (the tool's radius)
//! and straight lines (its end faces and `s = 0, 1`). The extremes of `t` over that 2-D
//! convex set lie on one of a handful of candidate points (the quadric's own extremes, line
//! ∩ quadric, line ∩ line), each computed by a quadratic formula.
//!
//! **Moves that turn a rotary axis** with a flat or ball end mill are cut by the exact
//! per-ray envelope of [`crate::envelope`] (interval ends within
//! [`crate::envelope::ENVELOPE_TOL`] = 0.1 µm of the true swept surface, the bound
//! reported). Other tools, or a bound asked tighter than that, fall back to sub-steps:
//!
//! such a move is split into `N` sub-steps, each swept as a
//! translation with the mid-step orientation, its mid-height point `c` moving straight
//! between its exact positions at the sub-step's ends. The distance between any tool point
//! on the true and on the approximate motion is at most
//! `ε(N) = ω·ρ_tool/(2N) + (ω²·ρ_axis + 2·ω·v)/(8N²)`, with `ω` the total rotation (rad),
//! `ρ_tool` the largest distance of a tool point from `c`, `ρ_axis` the largest distance of
//! `c` from a rotary axis point and `v` the linear travel: the first term is the orientation
//! held fixed over a sub-step, the second the chord error of `c`'s curved path
//! (`|c''| ≤ ω²ρ_axis + 2ωv`). `N` is the smallest that meets the bound asked for, and the
//! achieved bound is reported.
//!
//! **Invariant:** the sweep reads moves and poses; it never parses text or touches files.

use crate::cutter::{Line, Quadric, SweptTool, t_extremes};
use crate::envelope::{ENVELOPE_TOL, RotaryEnvelope};
use crate::kinematics::{AxisKind, Chain};
use crate::math::{Aabb, Isometry3, Point3, Real, UnitVector3, Vector3, tol};
use crate::nc::{AxisLetter, AxisValues, Move, MoveKind};
use crate::progress::Progress;
use crate::stock::{Cutter, RayCut, TriDexel};
use crate::tool::{Tool, ToolKind};

/// Options of the sweep.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SweepOptions {
    /// Largest allowed distance (mm) between the true and the simulated tool motion on moves
    /// that turn a rotary axis. Valid: (0, 1]. Typical: 1e-4 (0.1 µm).
    pub rotary_step_bound_mm: Real,
}

/// Errors of the sweep.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SweepError {
    /// A move names an axis the machine does not have.
    #[error("the machine has no {axis} axis")]
    MissingAxis {
        /// Source line.
        line: usize,
        /// Axis letter.
        axis: char,
    },
    /// A rotary move would need an absurd number of sub-steps for the requested bound.
    #[error(
        "meeting the rotary bound of {bound_mm} mm needs {steps:.3e} sub-steps; raise rotary_step_bound_mm"
    )]
    TooManySubsteps {
        /// Source line.
        line: usize,
        /// The bound asked for (mm).
        bound_mm: Real,
        /// The sub-steps it would need.
        steps: Real,
    },
    /// The bound is not in (0, 1] mm.
    #[error("rotary_step_bound_mm must be in (0, 1], got {0}")]
    BadBound(Real),
}

impl SweepError {
    /// The NC line the error is about, if any.
    pub fn line(&self) -> Option<usize> {
        match self {
            SweepError::MissingAxis { line, .. } | SweepError::TooManySubsteps { line, .. } => {
                Some(*line)
            }
            SweepError::BadBound(_) => None,
        }
    }
}

/// What the sweep did.
#[derive(Clone, Copy, Debug, PartialEq, Default, serde::Serialize)]
pub struct SweepReport {
    /// Moves processed.
    pub moves: usize,
    /// Moves that removed material.
    pub cutting_moves: usize,
    /// Moves that turned a rotary axis.
    pub rotary_moves: usize,
    /// Sweeps evaluated (1 per straight move, 1 per rotary move cut by the envelope, N per
    /// rotary move cut in sub-steps, pruned ones excluded).
    pub sweeps: usize,
    /// Largest bound on the error of rotary moves (envelope tolerance or sub-step bound) over
    /// all rotary moves (mm); 0 if none.
    pub rotary_error_bound_mm: Real,
}

/// Largest number of sub-steps for one rotary move.
const MAX_SUBSTEPS: Real = 5e7;
/// Sub-steps per coarse interval used to skip parts of a rotary move far from the stock.
const COARSE: usize = 64;

/// The tool translated from `start` (tip position) by `d`, with constant axis `v`.
/// Flat and ball end mills use the closed form below; every other shape the piecewise
/// exact sweep of [`crate::cutter`].
#[derive(Clone, Debug)]
pub struct TranslatedTool {
    tool: Tool,
    start: Point3,
    d: Vector3,
    v: UnitVector3,
    bounds: Aabb,
    general: Option<SweptTool>,
}

impl TranslatedTool {
    /// The tool with its tip moving from `start` to `start + d`, axis `v`.
    pub fn new(tool: Tool, start: Point3, d: Vector3, v: UnitVector3) -> Self {
        let mut bounds = tool_bounds(&tool, &start, &v);
        let b1 = tool_bounds(&tool, &(start + d), &v);
        bounds.grow(&b1.min);
        bounds.grow(&b1.max);
        // The closed form below takes the ball as a whole sphere: exact only if the tool
        // reaches above it (L ≥ 2R).
        let closed = match tool.kind() {
            ToolKind::Flat => true,
            ToolKind::Ball => tool.length() >= 2.0 * tool.radius(),
            _ => false,
        };
        let general = (!closed).then(|| SweptTool::new(&tool, start, d, v));
        Self {
            tool,
            start,
            d,
            v,
            bounds,
            general,
        }
    }
}

/// Bounding box of the tool with its tip at `tip` and axis `v`.
fn tool_bounds(tool: &Tool, tip: &Point3, v: &UnitVector3) -> Aabb {
    let top = tip + v.into_inner() * tool.length();
    let mut b = Aabb::empty();
    let ext = Vector3::from_fn(|k, _| tool.radius() * (1.0 - v[k] * v[k]).max(0.0).sqrt());
    for p in [tip, &top] {
        b.grow(&(p - ext));
        b.grow(&(p + ext));
    }
    if tool.kind() == ToolKind::Ball {
        // The hemisphere reaches one radius below its centre in every direction.
        let c = tip + v.into_inner() * tool.radius();
        b.grow(&(c - Vector3::repeat(tool.radius())));
    }
    b
}

/// One convex piece of the tool (a cylinder part or the ball) swept along `d`.
#[derive(Clone, Copy)]
struct Piece {
    quad: Quadric,
    lines: [Line; 4],
    n_lines: usize,
    /// Radial normal from the 3-D point at (t, s).
    radial: Radial,
}

#[derive(Clone, Copy)]
enum Radial {
    /// Cylinder about the line `base + s·d + h·v`.
    Cylinder { base: Point3, v: Vector3 },
    /// Sphere about `centre + s·d`.
    Sphere { centre: Point3 },
}

impl TranslatedTool {
    /// The convex pieces of the tool's sweep as 2-D problems for this ray: the cylinder, and
    /// for a ball end mill the swept ball. Returned in a fixed array (no allocation per ray).
    fn pieces(&self, origin: &Point3, e: &Vector3) -> ([Option<Piece>; 2], usize) {
        let mut out = [None, None];
        let mut count = 0;
        let v = self.v.into_inner();
        let r = self.tool.radius();
        let tol_q = tol::FEASIBILITY * (1.0 + r * r);
        let s_lines = [
            Line {
                p: 0.0,
                q: -1.0,
                r: 0.0,
                tol: tol::PARAMETER,
                normal: None,
            },
            Line {
                p: 0.0,
                q: 1.0,
                r: -1.0,
                tol: tol::PARAMETER,
                normal: None,
            },
        ];
        let h0 = match self.tool.kind() {
            ToolKind::Ball => r,
            _ => 0.0,
        };
        // Cylinder part between heights h0 and L above the tip.
        {
            let base = self.start;
            let w0 = origin - base;
            // projections perpendicular to v
            let perp = |x: Vector3| x - v * v.dot(&x);
            let (pw0, pe, pd) = (perp(w0), perp(*e), perp(-self.d));
            let quad = Quadric {
                a: pe.dot(&pe),
                b: pe.dot(&pd),
                c: pd.dot(&pd),
                d: pw0.dot(&pe),
                e: pw0.dot(&pd),
                f: pw0.dot(&pw0) - r * r,
                tol: tol_q,
            };
            // axial a(t,s) = v·w0 + t v·e − s v·d ∈ [h0, L]
            let (av, ae, ad) = (v.dot(&w0), v.dot(e), -v.dot(&self.d));
            let lines = [
                s_lines[0],
                s_lines[1],
                Line {
                    p: -ae,
                    q: -ad,
                    r: h0 - av,
                    tol: tol::FEASIBILITY,
                    normal: Some(-v),
                },
                Line {
                    p: ae,
                    q: ad,
                    r: av - self.tool.length(),
                    tol: tol::FEASIBILITY,
                    normal: Some(v),
                },
            ];
            out[count] = Some(Piece {
                quad,
                lines,
                n_lines: 4,
                radial: Radial::Cylinder { base, v },
            });
            count += 1;
        }
        if self.tool.kind() == ToolKind::Ball {
            let centre = self.start + v * r;
            let w0 = origin - centre;
            let md = -self.d;
            let quad = Quadric {
                a: e.dot(e),
                b: e.dot(&md),
                c: md.dot(&md),
                d: w0.dot(e),
                e: w0.dot(&md),
                f: w0.dot(&w0) - r * r,
                tol: tol_q,
            };
            let lines = [s_lines[0], s_lines[1], s_lines[0], s_lines[0]];
            out[count] = Some(Piece {
                quad,
                lines,
                n_lines: 2,
                radial: Radial::Sphere { centre },
            });
            count += 1;
        }
        (out, count)
    }

    /// Tool-outward normals active at (t, s) of a piece; picks the one most against (entry)
    /// or along (exit) the ray.
    fn normal_at(
        &self,
        piece: &Piece,
        origin: &Point3,
        e: &Vector3,
        t: Real,
        s: Real,
        entry: bool,
    ) -> Vector3 {
        let x = origin + e * t;
        let mut cands: [Option<Vector3>; 3] = [None; 3];
        if piece.quad.eval(t, s).abs() <= piece.quad.tol.max(tol::ON_SURFACE) {
            cands[0] = match piece.radial {
                Radial::Cylinder { base, v } => {
                    let w = x - (base + self.d * s);
                    let w = w - v * v.dot(&w);
                    w.try_normalize(0.0)
                }
                Radial::Sphere { centre } => (x - (centre + self.d * s)).try_normalize(0.0),
            };
        }
        for (k, l) in piece.lines[..piece.n_lines].iter().enumerate().skip(2) {
            if l.eval(t, s).abs() <= tol::ON_SURFACE {
                cands[k - 1] = l.normal;
            }
        }
        let score = |n: &Vector3| if entry { n.dot(e) } else { -n.dot(e) };
        cands
            .iter()
            .flatten()
            .min_by(|a, b| score(a).total_cmp(&score(b)))
            .copied()
            .unwrap_or(if entry { -e } else { *e })
    }
}

impl Cutter for TranslatedTool {
    fn bounds(&self) -> Aabb {
        self.bounds
    }

    fn ray_cut(&self, origin: &Point3, axis: usize) -> Option<RayCut> {
        if let Some(g) = &self.general {
            return g.ray_cut(origin, axis);
        }
        let mut e = Vector3::zeros();
        e[axis] = 1.0;
        let (pieces, count) = self.pieces(origin, &e);
        let mut acc: Option<(Real, Vector3, Real, Vector3)> = None;
        for piece in pieces[..count].iter().flatten() {
            let Some((t0, s0, t1, s1)) = t_extremes(&piece.quad, &piece.lines[..piece.n_lines])
            else {
                continue;
            };
            let lo = (t0, piece, s0);
            let hi = (t1, piece, s1);
            let n_in = self.normal_at(lo.1, origin, &e, lo.0, lo.2, true);
            let n_out = self.normal_at(hi.1, origin, &e, hi.0, hi.2, false);
            acc = Some(match acc {
                None => (t0, n_in, t1, n_out),
                Some((a0, m0, a1, m1)) => {
                    let (a0, m0) = if t0 < a0 { (t0, n_in) } else { (a0, m0) };
                    let (a1, m1) = if t1 > a1 { (t1, n_out) } else { (a1, m1) };
                    (a0, m0, a1, m1)
                }
            });
        }
        let (t_in, tn_in, t_out, tn_out) = acc?;
        (t_out - t_in > tol::LENGTH_EPS).then_some(RayCut {
            t_in,
            t_out,
            // Material normals point into the removed region: opposite the tool's outward normal.
            n_in: -tn_in,
            n_out: -tn_out,
        })
    }

    fn ray_cuts(&self, origin: &Point3, axis: usize, out: &mut Vec<RayCut>) {
        match &self.general {
            Some(g) => g.ray_cuts(origin, axis, out),
            None => out.extend(self.ray_cut(origin, axis)),
        }
    }
}

/// Total rotation (rad) and linear travel (mm) of a move on this chain.
fn rotation_and_travel(chain: &Chain, a: &AxisValues, b: &AxisValues) -> (Real, Real) {
    let (mut omega, mut travel) = (0.0, 0.0);
    for axis in chain.axes() {
        let dq = (b.get(axis.letter) - a.get(axis.letter)).abs();
        match axis.kind {
            AxisKind::Rotary => omega += dq.to_radians(),
            AxisKind::Linear => travel += dq,
        }
    }
    (omega, travel)
}

/// The error bound of a rotary move's sub-steps: `ε(N) = a/N + b/N²` (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RotaryBound {
    /// First-order coefficient (mm): orientation held fixed over a sub-step.
    pub a: Real,
    /// Second-order coefficient (mm): chord error of the mid point's path.
    pub b: Real,
}

impl RotaryBound {
    /// The bound for a move on `chain` with `tool`.
    pub fn of(chain: &Chain, tool: &Tool, mv: &Move) -> Self {
        let (omega, v) = rotation_and_travel(chain, &mv.start, &mv.end);
        let rotaries = chain
            .axes()
            .iter()
            .filter(|a| a.kind == AxisKind::Rotary)
            .count();
        let mids =
            [chain.w_from_t(&mv.start), chain.w_from_t(&mv.end)].map(|p| p * mid_point(tool));
        let mut rho = 0.0;
        for (q, c) in [&mv.start, &mv.end].iter().zip(&mids) {
            for axis_point in chain.rotary_points_in_w(q) {
                rho = Real::max(rho, (c - axis_point).norm());
            }
        }
        if rotaries > 1 {
            // Several rotaries: distances may grow mid-move by at most the path length.
            rho = (rho + v) * (1.0 + omega);
        }
        Self {
            a: omega * tool.reach_from(tool.length() / 2.0) / 2.0,
            b: (omega * omega * rho + 2.0 * omega * v) / 8.0,
        }
    }

    /// The bound at `n` sub-steps (mm).
    pub fn at(&self, n: usize) -> Real {
        let n = n as Real;
        self.a / n + self.b / (n * n)
    }

    /// The smallest multiple of [`COARSE`] sub-steps meeting `bound`, if not absurd.
    pub fn steps_for(&self, bound: Real, line: usize) -> Result<usize, SweepError> {
        let n = (self.a + (self.a * self.a + 4.0 * self.b * bound).sqrt()) / (2.0 * bound);
        let n = ((n.ceil() / COARSE as Real).ceil() * COARSE as Real).max(COARSE as Real);
        if n.is_nan() || n > MAX_SUBSTEPS {
            return Err(SweepError::TooManySubsteps {
                line,
                bound_mm: bound,
                steps: n,
            });
        }
        Ok(n as usize)
    }
}

/// The tool's mid-height point on its axis, tool frame: the point whose path rotary
/// sub-steps interpolate.
fn mid_point(tool: &Tool) -> Point3 {
    Point3::new(0.0, 0.0, tool.length() / 2.0)
}

/// A sub-step: the tool with axis `v` whose mid point moves from `a` to `b`.
fn substep(tool: &Tool, a: Point3, b: Point3, v: UnitVector3) -> TranslatedTool {
    TranslatedTool::new(
        tool.clone(),
        a - v.into_inner() * (tool.length() / 2.0),
        b - a,
        v,
    )
}

fn pose_at(chain: &Chain, mv: &Move, lambda: Real) -> Isometry3 {
    let mut q = mv.start;
    for axis in chain.axes() {
        let (a, b) = (mv.start.get(axis.letter), mv.end.get(axis.letter));
        q.set(axis.letter, a + (b - a) * lambda);
    }
    chain.w_from_t(&q)
}

/// Sweeps the tool through `moves` on `chain`, removing material from `stock`.
pub fn sweep_program(
    stock: &mut TriDexel,
    chain: &Chain,
    tool: &Tool,
    moves: &[Move],
    opts: &SweepOptions,
    progress: &dyn Progress,
) -> Result<SweepReport, SweepError> {
    let bound = opts.rotary_step_bound_mm;
    if !(bound > 0.0 && bound <= 1.0) {
        return Err(SweepError::BadBound(bound));
    }
    // Arcs are swept as chords within the rotary step bound.
    let chords: Vec<Move>;
    let moves: &[Move] = if moves.iter().any(|m| matches!(m.kind, MoveKind::Arc(_))) {
        chords = moves.iter().flat_map(|m| m.chords(bound)).collect();
        &chords
    } else {
        moves
    };
    let mut report = SweepReport::default();
    progress.start("sweep", moves.len() as u64);
    for mv in moves {
        if let Some(missing) = AxisLetter::ALL
            .into_iter()
            .find(|&l| !chain.has_axis(l) && mv.start.get(l) != mv.end.get(l))
        {
            return Err(SweepError::MissingAxis {
                line: mv.line,
                axis: missing.as_char(),
            });
        }
        let line = mv.line as u32;
        report.moves += 1;
        let (omega, _) = rotation_and_travel(chain, &mv.start, &mv.end);
        let mut cut = false;
        if omega == 0.0 {
            let p0 = chain.w_from_t(&mv.start);
            let p1 = chain.w_from_t(&mv.end);
            let tip0 = p0 * Point3::origin();
            let axis = UnitVector3::new_normalize(p0.rotation * Vector3::z());
            let swept = TranslatedTool::new(tool.clone(), tip0, p1 * Point3::origin() - tip0, axis);
            report.sweeps += 1;
            cut |= stock.remove(&swept, line);
        } else {
            report.rotary_moves += 1;
            // Flat and ball end mills: the exact per-ray envelope, unless a bound tighter
            // than its tolerance is asked for.
            let envelope = (bound >= ENVELOPE_TOL)
                .then(|| RotaryEnvelope::new(chain, tool, &mv.start, &mv.end).ok())
                .flatten();
            if let Some(env) = envelope {
                report.rotary_error_bound_mm = report.rotary_error_bound_mm.max(ENVELOPE_TOL);
                report.sweeps += 1;
                if stock.remove(&env, line) {
                    report.cutting_moves += 1;
                }
                progress.advance(1);
                continue;
            }
            let rb = RotaryBound::of(chain, tool, mv);
            let n = rb.steps_for(bound, mv.line)?;
            report.rotary_error_bound_mm = report.rotary_error_bound_mm.max(rb.at(n));
            let per = n / COARSE;
            // A coarse sub-step's box, grown by its own bound, holds every fine sub-step in it.
            let eps_c = rb.at(COARSE) + tol::SLIVER;
            let mid = mid_point(tool);
            for j in 0..COARSE {
                let (l0, l1) = (j as Real / COARSE as Real, (j + 1) as Real / COARSE as Real);
                let axis_at = |l: Real| {
                    UnitVector3::new_normalize(pose_at(chain, mv, l).rotation * Vector3::z())
                };
                let (a0, a1) = (pose_at(chain, mv, l0) * mid, pose_at(chain, mv, l1) * mid);
                let coarse = substep(tool, a0, a1, axis_at((l0 + l1) / 2.0))
                    .bounds()
                    .inflated(eps_c);
                if !coarse.intersects(stock.bounds()) {
                    continue;
                }
                let mut prev = a0;
                for k in 0..per {
                    let i = j * per + k;
                    let (la, lb) = (i as Real / n as Real, (i + 1) as Real / n as Real);
                    let next = pose_at(chain, mv, lb) * mid;
                    let swept = substep(tool, prev, next, axis_at((la + lb) / 2.0));
                    report.sweeps += 1;
                    cut |= stock.remove(&swept, line);
                    prev = next;
                }
            }
        }
        if cut {
            report.cutting_moves += 1;
        }
        progress.advance(1);
    }
    progress.finish();
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat(d: Real, l: Real) -> Tool {
        Tool::try_new(ToolKind::Flat, d, l).expect("valid")
    }

    /// Brute force: is `x` inside the tool translated to any s ∈ [0,1]? (dense s sampling)
    fn inside_brute(t: &TranslatedTool, x: &Point3, samples: usize) -> bool {
        (0..=samples).any(|i| {
            let s = i as Real / samples as Real;
            let w = x - (t.start + t.d * s);
            let h = t.v.dot(&w);
            let r = (w - t.v.into_inner() * h).norm();
            t.tool.contains(r, h)
        })
    }

    #[test]
    fn side_cut_interval_is_the_tangent_plane() {
        // Tool axis z, moving along x from (-10, 0, 0) to (10, 0, 0), radius 3.
        let t = TranslatedTool::new(
            flat(6.0, 20.0),
            Point3::new(-10.0, 0.0, 0.0),
            Vector3::new(20.0, 0.0, 0.0),
            Vector3::z_axis(),
        );
        let c = t.ray_cut(&Point3::new(0.0, 0.0, 5.0), 1).expect("cuts");
        assert_eq!((c.t_in, c.t_out), (-3.0, 3.0));
        assert!((c.n_in - Vector3::y()).norm() < 1e-12);
        // Below the tip: nothing.
        assert!(t.ray_cut(&Point3::new(0.0, 0.0, -0.5), 1).is_none());
        // A z ray through the floor: from the tip up to the top.
        let c = t.ray_cut(&Point3::new(5.0, 1.0, 0.0), 2).expect("cuts");
        assert!((c.t_in - 0.0).abs() < 1e-12 && (c.t_out - 20.0).abs() < 1e-12);
        // The material below the floor faces up, into the cut.
        assert!(
            (c.n_in - Vector3::z()).norm() < 1e-12,
            "floor normal {:?}",
            c.n_in
        );
    }

    #[test]
    fn ray_cut_agrees_with_brute_force_on_random_sweeps() {
        let rng = crate::math::CounterRng::new(11);
        let mut k = 0u64;
        let mut next = || {
            k += 1;
            rng.uniform(k, 0) * 2.0 - 1.0
        };
        for case in 0..30 {
            let kind = if case % 2 == 0 {
                ToolKind::Flat
            } else {
                ToolKind::Ball
            };
            let tool = Tool::try_new(kind, 4.0, 8.0).expect("valid");
            let v = UnitVector3::new_normalize(Vector3::new(next() * 0.6, next() * 0.6, 1.0));
            let start = Point3::new(next() * 3.0, next() * 3.0, next() * 3.0);
            let d = Vector3::new(next() * 8.0, next() * 8.0, next() * 4.0);
            let t = TranslatedTool::new(tool, start, d, v);
            for _ in 0..30 {
                let axis = (next().abs() * 3.0) as usize % 3;
                let o = Point3::new(next() * 8.0, next() * 8.0, next() * 8.0);
                let mut e = Vector3::zeros();
                e[axis] = 1.0;
                let cut = t.ray_cut(&o, axis);
                // Sample along the ray; points well inside/outside the interval must agree.
                for i in 0..200 {
                    let tt = -20.0 + 40.0 * i as Real / 200.0;
                    let x = o + e * tt;
                    let inside = inside_brute(&t, &x, 4000);
                    let margin = 0.02;
                    match cut {
                        Some(c) if tt > c.t_in + margin && tt < c.t_out - margin => {
                            assert!(inside, "case {case}: t={tt} should be inside {c:?}")
                        }
                        Some(c) if tt < c.t_in - margin || tt > c.t_out + margin => {
                            assert!(!inside, "case {case}: t={tt} should be outside {c:?}")
                        }
                        None => assert!(!inside, "case {case}: t={tt} inside but no cut"),
                        _ => {}
                    }
                }
            }
        }
    }
}
