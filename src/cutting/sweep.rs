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
//! per-ray envelope of [`crate::cutting::envelope`] (interval ends within
//! [`crate::cutting::envelope::ENVELOPE_TOL`] = 0.1 µm of the true swept surface, the bound
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
//! **One driver.** [`sweep_observed`] runs a program: arcs become chords (their exact
//! sagitta reported), consecutive collinear straight moves are joined into one sweep (a
//! rapid always starts a new run), rotary moves go to the envelope or to sub-steps. The plain
//! sweep ([`sweep_program`]) and the collision checks ([`crate::cutting::collide`], through the
//! [`SweepObserver`] trait) both use it, so they remove the same material bit for bit.
//!
//! **Invariant:** the sweep reads moves and poses; it never parses text or touches files; an
//! observer only reads the stock.

use crate::cutting::cutter::{Line, Quadric, SweptTool, t_extremes};
use crate::cutting::envelope::{ENVELOPE_TOL, MovePath, RotaryEnvelope, error_motion_speed};
use crate::cutting::stock::{Cutter, RayCut, TriDexel};
use crate::cutting::tool::{Tool, ToolKind};
use crate::machine::PoseSource;
use crate::machine::chain::{AxisKind, Chain};
use crate::machine::error_motion::Directions;
use crate::math::{Aabb, Isometry3, Point3, Real, Rotation3, UnitVector3, Vector3, tol};
use crate::nc::{AxisLetter, AxisValues, Move, MoveKind};
use crate::progress::Progress;

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
    /// The machine cannot take a pose of the move (a pose source: out of the workspace, no
    /// forward solution).
    #[error("the machine cannot follow the move: {message}")]
    Pose {
        /// Source line.
        line: usize,
        /// Where along the move, the axis values and why.
        message: String,
    },
}

impl SweepError {
    /// The NC line the error is about, if any.
    pub fn line(&self) -> Option<usize> {
        match self {
            SweepError::MissingAxis { line, .. }
            | SweepError::TooManySubsteps { line, .. }
            | SweepError::Pose { line, .. } => Some(*line),
            SweepError::BadBound(_) => None,
        }
    }
}

/// What the sweep did.
#[derive(Clone, Copy, Debug, PartialEq, Default, serde::Serialize)]
pub struct SweepReport {
    /// Moves processed.
    pub moves: usize,
    /// Moves that removed material. Moves swept as one joined run count when a cut of the
    /// run that removed material names them at one of its ends.
    pub cutting_moves: usize,
    /// Moves that turned a rotary axis.
    pub rotary_moves: usize,
    /// Moves at fixed rotary values swept as curved moves because an axis with error
    /// motions moves (cut like rotary moves; absent from the report when 0).
    #[serde(skip_serializing_if = "is_zero")]
    pub curved_moves: usize,
    /// Sweeps evaluated (1 per run of joined straight moves, 1 per rotary move cut by the
    /// envelope, N per rotary move cut in sub-steps, pruned ones excluded).
    pub sweeps: usize,
    /// Largest bound on the error of rotary moves (envelope tolerance or sub-step bound) over
    /// all rotary moves (mm); 0 if none.
    pub rotary_error_bound_mm: Real,
    /// Largest distance of the chords that replace arcs from their arcs (mm): the exact
    /// sagitta `r·(1 − cos(θ/2))` of the widest chord; 0 if no arcs.
    pub chord_error_bound_mm: Real,
    /// Largest distance between the true and the simulated tool motion over all moves (mm):
    /// per move its chord sagitta plus its rotary bound, the largest over the moves.
    pub error_bound_mm: Real,
    /// A machine driven pose by pose ([`Kinematics::Poses`]): the largest distance of the
    /// tool tip from where the controller commands it, over the sampled poses (mm; absent
    /// from the report for a chain).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tip_error_mm: Option<Real>,
    /// A machine driven pose by pose: the largest distance of the tool tip's path from the
    /// straight line between the move's reached ends, over the sampled poses of every move
    /// that turns no angle (mm): how far the deviations curve the controller's straight
    /// moves.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub path_bow_mm: Option<Real>,
}

fn is_zero(n: &usize) -> bool {
    *n == 0
}

/// The machine the sweep drives: a serial chain (every pose through the chain, rotary moves
/// by the envelope or bounded sub-steps), or a machine read pose by pose (a hexapod), each
/// of whose moves is sampled at [`PILOT_STEPS`] + 1 poses and, unless it is an exact
/// translation, cut in sub-steps bounded from those samples (see [`SampledBound`]).
#[derive(Clone, Copy)]
pub enum Kinematics<'a> {
    /// A serial chain.
    Chain(&'a Chain),
    /// A machine read pose by pose.
    Poses(&'a dyn PoseSource),
}

impl<'a> From<&'a Chain> for Kinematics<'a> {
    fn from(chain: &'a Chain) -> Self {
        Kinematics::Chain(chain)
    }
}

impl Kinematics<'_> {
    fn has_axis(&self, l: AxisLetter) -> bool {
        match self {
            Kinematics::Chain(c) => c.has_axis(l),
            Kinematics::Poses(p) => p.has_axis(l),
        }
    }
}

/// Intervals a move of a pose source is sampled in before it is cut: its workspace is
/// checked at these poses and its sub-step bound estimated from them.
pub const PILOT_STEPS: usize = 64;

/// Safety factor on the rates a pose source's samples show (the largest angular speed and
/// path curvature between samples may exceed those at the samples).
pub const SAMPLED_BOUND_FACTOR: Real = 2.0;

/// The sub-step bound of a move read pose by pose, from its pilot samples `P_j` at
/// `λ = j/M`: with the tool's mid-height point `c` and orientation `R`, the largest angular
/// speed `Ω = max_j angle(R_j, R_{j+1})·M` (rad per unit λ) and curvature
/// `C = max_j |c_{j−1} − 2c_j + c_{j+1}|·M²` (mm per unit λ²) give the bound of sub-steps as
/// for rotary moves: a sub-step of width `h` held at its mid orientation, `c` moving
/// straight, is off the true motion by at most `ρ_tool·Ω·h/2 + C·h²/8`, so
/// `ε(N) = a/N + b/N²` with `a = F·Ω·ρ_tool/2`, `b = F·C/8` and the safety factor
/// `F` = [`SAMPLED_BOUND_FACTOR`] on rates estimated from samples.
pub struct SampledBound;

impl SampledBound {
    /// The bound of `tool` moved through the pilot poses `pilot` (at least three, evenly
    /// spaced in λ from 0 to 1).
    pub fn of(tool: &Tool, pilot: &[Isometry3]) -> RotaryBound {
        let m = (pilot.len() - 1) as Real;
        let mid = mid_point(tool);
        let c: Vec<Point3> = pilot.iter().map(|p| p * mid).collect();
        let omega = pilot
            .windows(2)
            .map(|w| w[0].rotation.angle_to(&w[1].rotation) * m)
            .fold(0.0, Real::max);
        let curvature = c
            .windows(3)
            .map(|w| (w[0].coords - 2.0 * w[1].coords + w[2].coords).norm() * m * m)
            .fold(0.0, Real::max);
        let rho = tool.reach_from(tool.length() / 2.0);
        RotaryBound {
            a: SAMPLED_BOUND_FACTOR * omega * rho / 2.0,
            b: SAMPLED_BOUND_FACTOR * curvature / 8.0,
        }
    }
}

/// Largest number of sub-steps for one rotary move.
const MAX_SUBSTEPS: Real = 5e7;
/// Sub-steps per coarse interval used to skip parts of a rotary move far from the stock.
const COARSE: usize = 64;

/// The tool translated from `start` (tip position) by `d`, with constant axis `v`.
/// Flat and ball end mills use the closed form below; every other shape the piecewise
/// exact sweep of [`crate::cutting::cutter`].
#[derive(Clone, Debug)]
pub struct TranslatedTool {
    tool: Tool,
    start: Point3,
    d: Vector3,
    v: UnitVector3,
    bounds: Aabb,
    general: Option<SweptTool>,
    /// For a run of joined moves: each move's end parameter along `d` and its NC line.
    parts: Vec<(Real, u32)>,
    /// The grid axis the tool axis lies on, when the move is square to it (`d` has no
    /// component along it): rays along it then have the short closed form
    /// [`TranslatedTool::along_axis_cut`].
    square_axis: Option<usize>,
}

impl TranslatedTool {
    /// Whether `tool` has the closed form (flat, or ball reaching above its sphere); other
    /// shapes go through [`SweptTool`].
    pub fn has_closed_form(tool: &Tool) -> bool {
        match tool.kind() {
            ToolKind::Flat => true,
            // The closed form takes the ball as a whole sphere: exact only if the tool
            // reaches above it (L ≥ 2R).
            ToolKind::Ball => tool.length() >= 2.0 * tool.radius(),
            _ => false,
        }
    }

    /// Consecutive collinear moves swept as one: the tip moves from `start` to `start + d`;
    /// `parts` lists each move's end as a fraction of `d` (increasing, the last 1) with its
    /// NC line. Every crossing is tagged with the line of the earliest move whose tool
    /// position reaches it. Only for tools with [`TranslatedTool::has_closed_form`].
    pub fn joined(
        tool: Tool,
        start: Point3,
        d: Vector3,
        v: UnitVector3,
        parts: Vec<(Real, u32)>,
    ) -> Self {
        debug_assert!(Self::has_closed_form(&tool));
        Self {
            parts,
            ..Self::new(tool, start, d, v)
        }
    }

    /// The NC line of the move at parameter `s` (the first whose end is at or past `s`).
    fn line_at(&self, s: Real, line: u32) -> u32 {
        // The first part whose end is not below `s` (a binary search's partition point):
        // the parts are about evenly spaced, so the walk from the even guess is short.
        let n = self.parts.len();
        let mut k = if s > 0.0 {
            ((s * n as Real) as usize).min(n)
        } else {
            0
        };
        while k > 0 && self.parts[k - 1].0 >= s {
            k -= 1;
        }
        while k < n && self.parts[k].0 < s {
            k += 1;
        }
        self.parts
            .get(k)
            .or(self.parts.last())
            .map_or(line, |&(_, l)| l)
    }

    /// The tool with its tip moving from `start` to `start + d`, axis `v`.
    pub fn new(tool: Tool, start: Point3, d: Vector3, v: UnitVector3) -> Self {
        let mut bounds = tool_bounds(&tool, &start, &v);
        let b1 = tool_bounds(&tool, &(start + d), &v);
        bounds.grow(&b1.min);
        bounds.grow(&b1.max);
        let general = (!Self::has_closed_form(&tool)).then(|| SweptTool::new(&tool, start, d, v));
        Self {
            tool,
            start,
            d,
            v,
            bounds,
            general,
            parts: Vec::new(),
            square_axis: (0..3).find(|&k| {
                v[k].abs() == 1.0 && d[k] == 0.0 && (0..3).all(|j| j == k || v[j] == 0.0)
            }),
        }
    }
}

/// The whole ray: the span of an exact cut.
const EVERYWHERE: (Real, Real) = (Real::NEG_INFINITY, Real::INFINITY);

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
struct ConvexSweep {
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
    fn pieces(&self, origin: &Point3, e: &Vector3) -> ([Option<ConvexSweep>; 2], usize) {
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
            out[count] = Some(ConvexSweep {
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
            out[count] = Some(ConvexSweep {
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
        piece: &ConvexSweep,
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

impl TranslatedTool {
    /// The cut of a ray along the tool axis when the move is square to it (`square_axis`).
    /// With `w` the ray's offset from the tip's path in the plane across the axis, the tool
    /// covers the ray for the move parameters `s` with `|w − s·d| ≤ R`: a flat end mill from
    /// its tip to its top, the earliest such `s` making both ends; a ball end mill reaches
    /// lowest where its centre passes nearest (`s*`), `R − sqrt(R² − |w − s*·d|²)` above
    /// the tip, and to its top.
    fn along_axis_cut(
        &self,
        origin: &Point3,
        axis: usize,
        span: (Real, Real),
    ) -> Option<(RayCut, Real, Real)> {
        let sigma = self.v[axis];
        let r = self.tool.radius();
        let w = {
            let mut w = origin - self.start;
            w[axis] = 0.0;
            w
        };
        let dd = self.d.norm_squared();
        let wd = w.dot(&self.d);
        let ww = w.norm_squared();
        // The s interval inside the radius, clipped to [0, 1].
        let (sa, sb) = if dd == 0.0 {
            if ww > r * r {
                return None;
            }
            (0.0, 1.0)
        } else {
            let disc = wd * wd - dd * (ww - r * r);
            if disc < 0.0 {
                return None;
            }
            let sq = disc.sqrt();
            ((wd - sq) / dd, (wd + sq) / dd)
        };
        let (sa, sb) = (sa.max(0.0), sb.min(1.0));
        if sa > sb {
            return None;
        }
        let mut e = Vector3::zeros();
        e[axis] = 1.0;
        let tip = self.start[axis];
        let top = tip + sigma * self.tool.length();
        // The end of the tool's tip side along the ray, its s, and the ball's centre there.
        let (t_tip, s_tip, centre) = match self.tool.kind() {
            ToolKind::Ball => {
                let s_star = if dd == 0.0 {
                    0.0
                } else {
                    (wd / dd).clamp(0.0, 1.0)
                };
                let rho2 = (w - self.d * s_star).norm_squared();
                let depth = (r * r - rho2).max(0.0).sqrt();
                let centre = self.start + self.v.into_inner() * r + self.d * s_star;
                (centre[axis] - sigma * depth, s_star, Some(centre))
            }
            _ => (tip, sa, None),
        };
        // The material normal at the tip side's end: against the ball's outward normal (the
        // ray if grazing), the ray for a flat end.
        let n_tip = || match centre {
            Some(centre) => {
                let mut x = *origin;
                x[axis] = t_tip;
                (centre - x).try_normalize(0.0).unwrap_or(e * sigma)
            }
            None => e * sigma,
        };
        let (t_in, t_out) = if sigma > 0.0 {
            (t_tip, top)
        } else {
            (top, t_tip)
        };
        // Not `t_out - t_in <= …`: a NaN length is no cut either.
        let long = t_out - t_in > tol::LENGTH_EPS;
        if !long || t_in >= span.1 || t_out <= span.0 {
            return None;
        }
        let (s_in, n_in, s_out, n_out) = if sigma > 0.0 {
            (s_tip, n_tip(), sa, -e)
        } else {
            (sa, e, s_tip, n_tip())
        };
        Some((
            RayCut {
                t_in,
                t_out,
                n_in,
                n_out,
            },
            s_in,
            s_out,
        ))
    }

    /// The cut of a ray across the tool axis when the move is square to it (`square_axis`
    /// = `a`). At the ray's height along the tool axis the tool is a disk of radius `ρ`
    /// (R, or the ball's section) whose centre moves straight from `c₀` to `c₀ + d`: the
    /// sweep's section is the set within `ρ` of that segment, bounded by the two end
    /// circles and the two sides parallel to `d`. The ray's extremes are among its points
    /// on the end circles and on the sides (foot parameter in [0, 1]), all inside the set.
    fn across_axis_cut(
        &self,
        origin: &Point3,
        axis: usize,
        a: usize,
    ) -> Option<(RayCut, Real, Real)> {
        let m = 3 - a - axis;
        let sigma = self.v[a];
        let r = self.tool.radius();
        let (ball, l) = (self.tool.kind() == ToolKind::Ball, self.tool.length());
        let h = sigma * (origin[a] - self.start[a]);
        if !(0.0..=l).contains(&h) {
            return None;
        }
        let in_ball = ball && h < r;
        let rho = if in_ball {
            (r * r - (r - h) * (r - h)).max(0.0).sqrt()
        } else {
            r
        };
        let (cx, cw, dx, dw, w) = (
            self.start[axis],
            self.start[m],
            self.d[axis],
            self.d[m],
            origin[m],
        );
        let (mut lo, mut hi) = ((Real::INFINITY, 0.0), (Real::NEG_INFINITY, 0.0));
        let mut offer = |t: Real, s: Real| {
            if t < lo.0 || (t == lo.0 && s < lo.1) {
                lo = (t, s);
            }
            if t > hi.0 || (t == hi.0 && s < hi.1) {
                hi = (t, s);
            }
        };
        for s in [0.0, 1.0] {
            let u = w - (cw + s * dw);
            if u.abs() <= rho {
                let half = (rho * rho - u * u).sqrt();
                let c = cx + s * dx;
                offer(c - half, s);
                offer(c + half, s);
            }
        }
        if dw != 0.0 {
            let len = dx.hypot(dw);
            // Unit normal of d in the section, (n_k, n_m).
            let (nk, nm) = (dw / len, -dx / len);
            for j in [-1.0, 1.0] {
                let s = (w - cw - j * rho * nm) / dw;
                if (0.0..=1.0).contains(&s) {
                    offer(cx + s * dx + j * rho * nk, s);
                }
            }
        }
        if hi.0 - lo.0 <= tol::LENGTH_EPS {
            return None;
        }
        // Material normal at (t, s): against the tool's outward normal there.
        let normal = |t: Real, s: Real, fallback: Vector3| {
            let mut x = *origin;
            x[axis] = t;
            let c = self.start + self.d * s;
            let out = if in_ball {
                x - (c + self.v.into_inner() * r)
            } else {
                let mut w = x - c;
                w[a] = 0.0;
                w
            };
            (-out).try_normalize(0.0).unwrap_or(fallback)
        };
        let mut e = Vector3::zeros();
        e[axis] = 1.0;
        Some((
            RayCut {
                t_in: lo.0,
                t_out: hi.0,
                n_in: normal(lo.0, lo.1, e),
                n_out: normal(hi.0, hi.1, -e),
            },
            lo.1,
            hi.1,
        ))
    }

    /// The closed form's cut of the ray with the move parameters `s` of its two ends; a cut
    /// along the tool axis wholly outside `span` may be left out.
    fn closed_cut(
        &self,
        origin: &Point3,
        axis: usize,
        span: (Real, Real),
    ) -> Option<(RayCut, Real, Real)> {
        match self.square_axis {
            Some(a) if a == axis => return self.along_axis_cut(origin, axis, span),
            Some(a) => return self.across_axis_cut(origin, axis, a),
            None => {}
        }
        let mut e = Vector3::zeros();
        e[axis] = 1.0;
        let (pieces, count) = self.pieces(origin, &e);
        let mut acc: Option<(Real, Vector3, Real, Real, Vector3, Real)> = None;
        for piece in pieces[..count].iter().flatten() {
            let Some((t0, s0, t1, s1)) = t_extremes(&piece.quad, &piece.lines[..piece.n_lines])
            else {
                continue;
            };
            let n_in = self.normal_at(piece, origin, &e, t0, s0, true);
            let n_out = self.normal_at(piece, origin, &e, t1, s1, false);
            acc = Some(match acc {
                None => (t0, n_in, s0, t1, n_out, s1),
                Some((a0, m0, r0, a1, m1, r1)) => {
                    // On a tie the earlier tool position, as within a piece.
                    let lo = if t0 < a0 || (t0 == a0 && s0 < r0) {
                        (t0, n_in, s0)
                    } else {
                        (a0, m0, r0)
                    };
                    let hi = if t1 > a1 || (t1 == a1 && s1 < r1) {
                        (t1, n_out, s1)
                    } else {
                        (a1, m1, r1)
                    };
                    (lo.0, lo.1, lo.2, hi.0, hi.1, hi.2)
                }
            });
        }
        let (t_in, tn_in, s_in, t_out, tn_out, s_out) = acc?;
        (t_out - t_in > tol::LENGTH_EPS).then_some((
            RayCut {
                t_in,
                t_out,
                // Material normals point into the removed region: opposite the tool's
                // outward normal.
                n_in: -tn_in,
                n_out: -tn_out,
            },
            s_in,
            s_out,
        ))
    }
}

impl Cutter for TranslatedTool {
    fn bounds(&self) -> Aabb {
        self.bounds
    }

    fn ray_cut(&self, origin: &Point3, axis: usize) -> Option<RayCut> {
        match &self.general {
            Some(g) => g.ray_cut(origin, axis),
            None => self.closed_cut(origin, axis, EVERYWHERE).map(|(c, _, _)| c),
        }
    }

    fn ray_cuts(&self, origin: &Point3, axis: usize, out: &mut Vec<RayCut>) {
        match &self.general {
            Some(g) => g.ray_cuts(origin, axis, out),
            None => out.extend(self.ray_cut(origin, axis)),
        }
    }

    fn ray_cuts_lined(
        &self,
        origin: &Point3,
        axis: usize,
        line: u32,
        out: &mut Vec<RayCut>,
        lines: &mut Vec<[u32; 2]>,
    ) {
        if let Some(g) = &self.general {
            g.ray_cuts_lined(origin, axis, line, out, lines);
        } else if let Some((c, s_in, s_out)) = self.closed_cut(origin, axis, EVERYWHERE) {
            out.push(c);
            lines.push([self.line_at(s_in, line), self.line_at(s_out, line)]);
        }
    }

    /// Exact, except that a cut along the tool axis that lies wholly outside `span` (so it
    /// cannot change the ray) is left out without working out its normals and NC lines.
    fn ray_cuts_in_span(
        &self,
        origin: &Point3,
        axis: usize,
        span: (Real, Real),
        line: u32,
        out: &mut Vec<RayCut>,
        lines: &mut Vec<[u32; 2]>,
    ) {
        if let Some(g) = &self.general {
            g.ray_cuts_lined(origin, axis, line, out, lines);
        } else if let Some((c, s_in, s_out)) = self.closed_cut(origin, axis, span) {
            out.push(c);
            let l_in = self.line_at(s_in, line);
            let l_out = if s_out == s_in {
                l_in
            } else {
                self.line_at(s_out, line)
            };
            lines.push([l_in, l_out]);
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
    /// The bound for a move on `chain` with `tool`, moving axes settled in their direction
    /// of motion.
    pub fn of(chain: &Chain, tool: &Tool, mv: &Move) -> Self {
        let state = chain.reversal_state(&Directions::default().after_move(&mv.start, &mv.end));
        Self::of_state(chain, tool, mv, &state)
    }

    /// The bound for a move on `chain` with `tool` from the reversal shares `state`. With
    /// error motions it adds `a_e/N + b_e/N²` (see docs/cutting.md#sweep-bounds):
    /// `a_e = E + ρ_tool·ω'/2` and `b_e = ((v + ω·ρ_axis)·ω' + ω·E)/2`, `E` the speed the
    /// error motions add to the mid point and `ω'` the rotation they turn
    /// ([`error_motion_speed`]).
    pub fn of_state(chain: &Chain, tool: &Tool, mv: &Move, state: &[Real; 6]) -> Self {
        let plain = Self::plain(chain, tool, mv);
        if !chain.has_error_motions() {
            return plain;
        }
        let (omega, v) = rotation_and_travel(chain, &mv.start, &mv.end);
        let reach = tool.reach_from(tool.length() / 2.0);
        let (e, turn) = error_motion_speed(chain, &mid_point(tool), 0.0, &mv.start, &mv.end, state);
        // ρ_axis from the plain bound's second term: b = (ω²ρ + 2ωv)/8.
        let rho_axis = if omega > 0.0 {
            ((8.0 * plain.b - 2.0 * omega * v) / (omega * omega)).max(0.0)
        } else {
            0.0
        };
        Self {
            a: plain.a + e + reach * turn / 2.0,
            b: plain.b + ((v + omega * rho_axis) * turn + omega * e) / 2.0,
        }
    }

    fn plain(chain: &Chain, tool: &Tool, mv: &Move) -> Self {
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
            for (axis_point, _) in chain.rotary_lines_in_w(q) {
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

fn pose_at(chain: &Chain, mv: &Move, lambda: Real) -> Isometry3 {
    let mut q = mv.start;
    for axis in chain.axes() {
        let (a, b) = (mv.start.get(axis.letter), mv.end.get(axis.letter));
        q.set(axis.letter, a + (b - a) * lambda);
    }
    chain.w_from_t(&q)
}

/// The poses along a move: the chain's at interpolated axis values, or, with error
/// motions, the exact [`MovePath`] from the reversal shares the move starts with.
enum Poses<'a> {
    Plain(&'a Chain, &'a Move),
    Path(MovePath),
}

impl<'a> Poses<'a> {
    /// The poses of `mv` on `chain` from the reversal shares `state`.
    fn of(chain: &'a Chain, mv: &'a Move, state: &[Real; 6]) -> Self {
        if chain.has_error_motions() {
            Poses::Path(MovePath::with_state(chain, &mv.start, &mv.end, state))
        } else {
            Poses::Plain(chain, mv)
        }
    }

    fn at(&self, lambda: Real) -> Isometry3 {
        match self {
            Poses::Plain(chain, mv) => pose_at(chain, mv, lambda),
            Poses::Path(p) => p.w_from_t(lambda),
        }
    }
}

/// The moves with every arc replaced by chords within `bound` (mm) of it: borrowed as they
/// are when there is no arc.
pub fn as_chords(moves: &[Move], bound: Real) -> std::borrow::Cow<'_, [Move]> {
    if moves.iter().any(|m| matches!(m.kind, MoveKind::Arc(_))) {
        std::borrow::Cow::Owned(moves.iter().flat_map(|m| m.chords(bound)).collect())
    } else {
        std::borrow::Cow::Borrowed(moves)
    }
}

/// One piece of a move as the driver cuts it, shown to a [`SweepObserver`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Piece {
    /// A pure translation of the tool: its tip moves from `tip` by `d` with the tool axis
    /// `axis` (W). A straight move at fixed rotary values, or one sub-step of a move that
    /// turns a rotary axis (see [`rotary_substeps`]), whose rotation is `rotation`.
    Translation {
        /// The tip at the start (W, mm).
        tip: Point3,
        /// The tip's travel (W, mm).
        d: Vector3,
        /// The tool's orientation (T to W); its +z is the tool axis.
        rotation: Rotation3,
    },
    /// A whole move that turns a rotary axis, or that moves an axis with error motions.
    /// `envelope`: cut at once by the exact [`RotaryEnvelope`] of the tool; else cut in
    /// sub-steps (each shown to [`SweepObserver::before_rapid`] as a
    /// [`Piece::Translation`]).
    Rotary {
        /// Whether the move was cut by the envelope.
        envelope: bool,
        /// The reversal shares the move starts from ([`Chain::reversal_state`]).
        state: [Real; 6],
    },
    /// A whole move of a machine read pose by pose ([`Kinematics::Poses`]) that is not a
    /// pure translation, cut in sub-steps (each shown to [`SweepObserver::before_rapid`] as
    /// a [`Piece::Translation`]).
    Sampled,
}

impl Piece {
    /// The tool axis of a translation (W).
    pub fn axis(rotation: &Rotation3) -> UnitVector3 {
        UnitVector3::new_normalize(rotation * Vector3::z())
    }
}

/// What the sweep driver shows of each move to code that checks it (collision checks):
/// the stock just before a rapid removes material, and just after each move's material is
/// removed. An observer only reads the stock, so the material removed is the same with any
/// observer.
pub trait SweepObserver {
    /// Before `piece` of the rapid (G0) `mv` is removed from `stock`. `k` is the move's index
    /// among the moves with arcs as chords. A rapid never joins the moves before it
    /// (see [`sweep_observed`]), so `stock` is the stock the rapid meets (for sub-steps: as
    /// the earlier sub-steps of the rapid left it). The default looks at nothing.
    fn before_rapid(
        &mut self,
        stock: &TriDexel,
        k: usize,
        mv: &Move,
        piece: &Piece,
    ) -> Result<(), SweepError> {
        let _ = (stock, k, mv, piece);
        Ok(())
    }

    /// After the material of move `k` was removed: `piece` is the move's translation for a
    /// straight move, [`Piece::Rotary`] for one that turns a rotary axis. For a run of
    /// joined moves, called for each move of the run in program order once the whole run
    /// is removed. The default looks at nothing.
    fn after_move(
        &mut self,
        stock: &TriDexel,
        k: usize,
        mv: &Move,
        piece: &Piece,
    ) -> Result<(), SweepError> {
        let _ = (stock, k, mv, piece);
        Ok(())
    }
}

/// The observer of the plain sweep: looks at nothing.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoObserver;

impl SweepObserver for NoObserver {}

/// The sub-steps of a move that turns a rotary axis: `n` translations (`n` a multiple of
/// 64, see [`RotaryBound::steps_for`]), in each of which the tool's mid-height point moves
/// straight between its true positions at the sub-step's ends, the tool held at the
/// mid-step orientation (the error bound of [`RotaryBound`]). The sub-steps come in 64
/// groups; `keep_group` sees each group as one coarse translation (tip, travel, rotation)
/// and skips the whole group when it says no; `each` gets every sub-step of a kept group
/// as (tip, travel, rotation), in order.
pub fn rotary_substeps<E>(
    chain: &Chain,
    tool: &Tool,
    mv: &Move,
    state: &[Real; 6],
    n: usize,
    keep_group: impl FnMut(Point3, Vector3, Rotation3) -> bool,
    each: impl FnMut(Point3, Vector3, Rotation3) -> Result<(), E>,
) -> Result<(), E> {
    let poses = Poses::of(chain, mv, state);
    substeps(tool, n, |l| Ok(poses.at(l)), keep_group, each)
}

/// The sub-steps of [`rotary_substeps`] for any pose function `pose_at(λ)` (fallible: a
/// pose source may be unable to take a pose).
fn substeps<E>(
    tool: &Tool,
    n: usize,
    pose_at: impl Fn(Real) -> Result<Isometry3, E>,
    mut keep_group: impl FnMut(Point3, Vector3, Rotation3) -> bool,
    mut each: impl FnMut(Point3, Vector3, Rotation3) -> Result<(), E>,
) -> Result<(), E> {
    let mid = mid_point(tool);
    let half = tool.length() / 2.0;
    let translation = |a: Point3, b: Point3, rotation: Rotation3| {
        let v = rotation * Vector3::z();
        (a - v * half, b - a, rotation)
    };
    let per = n / COARSE;
    for j in 0..COARSE {
        let (l0, l1) = (j as Real / COARSE as Real, (j + 1) as Real / COARSE as Real);
        let (a0, a1) = (pose_at(l0)? * mid, pose_at(l1)? * mid);
        let (tip, d, rot) = translation(a0, a1, pose_at((l0 + l1) / 2.0)?.rotation);
        if !keep_group(tip, d, rot) {
            continue;
        }
        let mut prev = a0;
        for k in 0..per {
            let i = j * per + k;
            let (la, lb) = (i as Real / n as Real, (i + 1) as Real / n as Real);
            let next = pose_at(lb)? * mid;
            let (tip, d, rot) = translation(prev, next, pose_at((la + lb) / 2.0)?.rotation);
            each(tip, d, rot)?;
            prev = next;
        }
    }
    Ok(())
}

/// The largest distance (mm) of the chords replacing the arc `mv` ([`Move::chords`] with
/// sagitta at most `bound`) from the arc: `r·(1 − cos(θ/2))` for chords spanning the angle
/// `θ` of an arc of radius `r` (the larger of its start and end radii for a spiral); 0 for
/// a straight move.
pub fn chord_sagitta(mv: &Move, bound: Real) -> Real {
    match &mv.kind {
        MoveKind::Arc(a) => {
            let r = a.radius.max(a.radius_end);
            let theta = a.sweep_deg.to_radians().abs() / mv.chord_count(bound) as Real;
            r * (1.0 - (theta / 2.0).cos())
        }
        _ => 0.0,
    }
}

/// Sweeps the tool through `moves` on the machine (a chain or a pose source), removing
/// material from `stock` (the plain sweep: [`sweep_observed`] with [`NoObserver`]).
pub fn sweep_program<'a>(
    stock: &mut TriDexel,
    machine: impl Into<Kinematics<'a>>,
    tool: &Tool,
    moves: &[Move],
    opts: &SweepOptions,
    progress: &dyn Progress,
) -> Result<SweepReport, SweepError> {
    sweep_observed(stock, machine, tool, moves, opts, progress, &mut NoObserver)
}

/// The sweep driver: sweeps the tool through `moves` on `chain`, removing material from
/// `stock`, and shows `observer` the stock before each rapid's pieces and after each move.
/// Arcs become chords ([`as_chords`]); consecutive collinear straight moves are joined into
/// one sweep, except that a rapid always starts a new run (so that its check sees the stock
/// before it); moves that turn a rotary axis are cut by the envelope or in sub-steps. The
/// stock comes out the same, bit for bit, whatever the observer. A machine read pose by
/// pose ([`Kinematics::Poses`]) has every move sampled ([`PILOT_STEPS`]): an exact
/// translation joins runs like a straight move, any other is cut in sub-steps within the
/// bound ([`SampledBound`]).
pub fn sweep_observed<'a>(
    stock: &mut TriDexel,
    machine: impl Into<Kinematics<'a>>,
    tool: &Tool,
    moves: &[Move],
    opts: &SweepOptions,
    progress: &dyn Progress,
    observer: &mut dyn SweepObserver,
) -> Result<SweepReport, SweepError> {
    let machine = machine.into();
    let bound = opts.rotary_step_bound_mm;
    if !(bound > 0.0 && bound <= 1.0) {
        return Err(SweepError::BadBound(bound));
    }
    // Each chord's sagitta, in the order of the chords (empty without arcs).
    let sagittas: Vec<Real> = if moves.iter().any(|m| matches!(m.kind, MoveKind::Arc(_))) {
        moves
            .iter()
            .flat_map(|m| std::iter::repeat_n(chord_sagitta(m, bound), m.chord_count(bound)))
            .collect()
    } else {
        Vec::new()
    };
    let moves = as_chords(moves, bound);
    let moves: &[Move] = &moves;
    debug_assert!(sagittas.is_empty() || sagittas.len() == moves.len());
    let mut report = SweepReport::default();
    progress.start("sweep", moves.len() as u64);
    let joinable = TranslatedTool::has_closed_form(tool);
    let mut run: Option<Run> = None;
    // Before the first move every axis is taken as last moved in +.
    let (errors, mut state) = match machine {
        Kinematics::Chain(chain) => (
            chain.has_error_motions(),
            chain.reversal_state(&Directions::default()),
        ),
        Kinematics::Poses(_) => (false, [0.0; 6]),
    };
    if let Kinematics::Poses(_) = machine {
        report.tip_error_mm = Some(0.0);
        report.path_bow_mm = Some(0.0);
    }
    for (k, mv) in moves.iter().enumerate() {
        if let Some(missing) = AxisLetter::ALL
            .into_iter()
            .find(|&l| !machine.has_axis(l) && mv.start.get(l) != mv.end.get(l))
        {
            flush(run.take(), stock, tool, moves, &mut report, observer)?;
            return Err(SweepError::MissingAxis {
                line: mv.line,
                axis: missing.as_char(),
            });
        }
        report.moves += 1;
        let sagitta = sagittas.get(k).copied().unwrap_or(0.0);
        report.chord_error_bound_mm = report.chord_error_bound_mm.max(sagitta);
        report.error_bound_mm = report.error_bound_mm.max(sagitta);
        let before = state;
        let step = match machine {
            Kinematics::Chain(chain) => {
                let (omega, _) = rotation_and_travel(chain, &mv.start, &mv.end);
                let curved = errors && moves_error_axis(chain, mv);
                if errors {
                    state = chain.reversal_after_move(&state, &mv.start, &mv.end);
                }
                if omega == 0.0 && !curved {
                    Step::Straight(if errors {
                        (
                            chain.w_from_t_state(&mv.start, &before),
                            chain.w_from_t_state(&mv.end, &state),
                        )
                    } else {
                        (chain.w_from_t(&mv.start), chain.w_from_t(&mv.end))
                    })
                } else {
                    Step::Curved {
                        rotary: omega != 0.0,
                        pilot: Vec::new(),
                    }
                }
            }
            Kinematics::Poses(src) => {
                let pilot = pilot_poses(src, mv, &mut report)?;
                if src.is_translation(&mv.start, &mv.end) {
                    Step::Straight((pilot[0], pilot[PILOT_STEPS]))
                } else {
                    let rotary = AxisLetter::ALL
                        .into_iter()
                        .any(|l| l.is_rotary() && mv.start.get(l) != mv.end.get(l));
                    Step::Curved { rotary, pilot }
                }
            }
        };
        if let Step::Straight((p0, p1)) = step {
            let tip0 = p0 * Point3::origin();
            let tip1 = p1 * Point3::origin();
            if let Some(r) = &mut run
                && joinable
                && mv.kind != MoveKind::Rapid
                && r.extend(k, mv, &tip1, &p0.rotation)
            {
                progress.advance(1);
                continue;
            }
            flush(run.take(), stock, tool, moves, &mut report, observer)?;
            run = Some(Run::new(k, mv, tip0, tip1, p0.rotation));
        } else if let Step::Curved { rotary, pilot } = step {
            flush(run.take(), stock, tool, moves, &mut report, observer)?;
            if rotary {
                report.rotary_moves += 1;
            } else {
                report.curved_moves += 1;
            }
            let e = match machine {
                Kinematics::Chain(chain) => sweep_rotary(
                    stock,
                    chain,
                    tool,
                    (k, mv),
                    &before,
                    bound,
                    &mut report,
                    observer,
                )?,
                Kinematics::Poses(src) => sweep_sampled(
                    stock,
                    src,
                    tool,
                    (k, mv),
                    &pilot,
                    bound,
                    &mut report,
                    observer,
                )?,
            };
            report.rotary_error_bound_mm = report.rotary_error_bound_mm.max(e);
            // A chord of an arc that also turns a rotary axis carries both errors.
            report.error_bound_mm = report.error_bound_mm.max(e + sagitta);
        }
        progress.advance(1);
    }
    flush(run.take(), stock, tool, moves, &mut report, observer)?;
    progress.finish();
    Ok(report)
}

/// How the driver cuts one move.
enum Step {
    /// A pure translation between two poses.
    Straight((Isometry3, Isometry3)),
    /// A curved move; for a pose source with its pilot poses.
    Curved { rotary: bool, pilot: Vec<Isometry3> },
}

/// The pilot poses of a move of a pose source (λ = j/[`PILOT_STEPS`]), its tip error and
/// bow recorded in `report`; a pose the machine cannot take is the error of the move's line.
fn pilot_poses(
    src: &dyn PoseSource,
    mv: &Move,
    report: &mut SweepReport,
) -> Result<Vec<Isometry3>, SweepError> {
    let mut pilot = Vec::with_capacity(PILOT_STEPS + 1);
    let mut tip_error: Real = 0.0;
    for j in 0..=PILOT_STEPS {
        let lambda = j as Real / PILOT_STEPS as Real;
        let q = src.interpolate(&mv.start, &mv.end, lambda);
        let pose = pose_of(src, mv, &q, lambda)?;
        let commanded = src.commanded(&q);
        tip_error = tip_error.max((pose.translation.vector - commanded.translation.vector).norm());
        pilot.push(pose);
    }
    let (a, b) = (
        pilot[0].translation.vector,
        pilot[PILOT_STEPS].translation.vector,
    );
    let chord = b - a;
    let bow = pilot
        .iter()
        .map(|p| {
            let w = p.translation.vector - a;
            let n2 = chord.norm_squared();
            if n2 > 0.0 {
                (w - chord * (w.dot(&chord) / n2).clamp(0.0, 1.0)).norm()
            } else {
                w.norm()
            }
        })
        .fold(0.0, Real::max);
    report.tip_error_mm = Some(report.tip_error_mm.unwrap_or(0.0).max(tip_error));
    // The bow of a straight move only: a move that turns an angle curves by design.
    let turns = AxisLetter::ALL
        .into_iter()
        .any(|l| l.is_rotary() && mv.start.get(l) != mv.end.get(l));
    if !turns {
        report.path_bow_mm = Some(report.path_bow_mm.unwrap_or(0.0).max(bow));
    }
    Ok(pilot)
}

/// The pose of a pose source at `q`, `lambda` of the way along `mv`, or the error naming
/// the move's line, the place and the axis values.
fn pose_of(
    src: &dyn PoseSource,
    mv: &Move,
    q: &AxisValues,
    lambda: Real,
) -> Result<Isometry3, SweepError> {
    src.w_from_t(q).map_err(|e| {
        let v = q.to_array();
        SweepError::Pose {
            line: mv.line,
            message: format!(
                "at {:.0} % of the move (X{:.4} Y{:.4} Z{:.4} A{:.4} B{:.4} C{:.4}): {e}",
                lambda * 100.0,
                v[0],
                v[1],
                v[2],
                v[3],
                v[4],
                v[5]
            ),
        }
    })
}

/// Cuts move `k` of a pose source in sub-steps within `bound` of its true motion (the
/// bound estimated from its pilot poses, [`SampledBound`]), counting it in `report`;
/// returns its error bound (mm).
#[expect(
    clippy::too_many_arguments,
    reason = "the driver's state, passed down for one move"
)]
fn sweep_sampled(
    stock: &mut TriDexel,
    src: &dyn PoseSource,
    tool: &Tool,
    (k, mv): (usize, &Move),
    pilot: &[Isometry3],
    bound: Real,
    report: &mut SweepReport,
    observer: &mut dyn SweepObserver,
) -> Result<Real, SweepError> {
    let rb = SampledBound::of(tool, pilot);
    let n = rb.steps_for(bound, mv.line)?;
    cut_substeps(
        stock,
        tool,
        (k, mv),
        (&rb, n),
        |l| pose_of(src, mv, &src.interpolate(&mv.start, &mv.end, l), l),
        report,
        observer,
    )?;
    observer.after_move(stock, k, mv, &Piece::Sampled)?;
    Ok(rb.at(n))
}

/// Cuts move `k` in the `n` sub-steps of the pose function `pose_at` ([`substeps`]),
/// skipping the groups whose tool, grown by the bound `rb` at 64 steps, misses the stock,
/// and showing a rapid's sub-steps to the observer; counts the move in `report` if it cut.
fn cut_substeps(
    stock: &mut TriDexel,
    tool: &Tool,
    (k, mv): (usize, &Move),
    (rb, n): (&RotaryBound, usize),
    pose_at: impl Fn(Real) -> Result<Isometry3, SweepError>,
    report: &mut SweepReport,
    observer: &mut dyn SweepObserver,
) -> Result<(), SweepError> {
    let line = mv.line as u32;
    let rapid = mv.kind == MoveKind::Rapid;
    // A coarse sub-step's box, grown by its own bound, holds every fine sub-step in it.
    let eps_c = rb.at(COARSE) + tol::SLIVER;
    let stock_box = *stock.bounds();
    let mut cut = false;
    substeps(
        tool,
        n,
        pose_at,
        |tip, d, rot| {
            TranslatedTool::new(tool.clone(), tip, d, Piece::axis(&rot))
                .bounds()
                .inflated(eps_c)
                .intersects(&stock_box)
        },
        |tip, d, rotation| {
            if rapid {
                observer.before_rapid(stock, k, mv, &Piece::Translation { tip, d, rotation })?;
            }
            let swept = TranslatedTool::new(tool.clone(), tip, d, Piece::axis(&rotation));
            report.sweeps += 1;
            cut |= stock.remove(&swept, line);
            Ok(())
        },
    )?;
    if cut {
        report.cutting_moves += 1;
    }
    Ok(())
}

/// Cuts move `k` that turns a rotary axis (the envelope, else sub-steps), counting it in
/// `report`; returns its error bound (mm).
#[expect(
    clippy::too_many_arguments,
    reason = "the driver's state, passed down for one move"
)]
fn sweep_rotary(
    stock: &mut TriDexel,
    chain: &Chain,
    tool: &Tool,
    (k, mv): (usize, &Move),
    state: &[Real; 6],
    bound: Real,
    report: &mut SweepReport,
    observer: &mut dyn SweepObserver,
) -> Result<Real, SweepError> {
    let line = mv.line as u32;
    let rapid = mv.kind == MoveKind::Rapid;
    // Flat and ball end mills: the exact per-ray envelope, unless a bound tighter than its
    // tolerance is asked for.
    let envelope = (bound >= ENVELOPE_TOL)
        .then(|| RotaryEnvelope::with_state(chain, tool, &mv.start, &mv.end, state).ok())
        .flatten();
    if let Some(env) = envelope {
        let piece = Piece::Rotary {
            envelope: true,
            state: *state,
        };
        if rapid {
            observer.before_rapid(stock, k, mv, &piece)?;
        }
        report.sweeps += 1;
        if stock.remove(&env, line) {
            report.cutting_moves += 1;
        }
        observer.after_move(stock, k, mv, &piece)?;
        return Ok(ENVELOPE_TOL);
    }
    let rb = RotaryBound::of_state(chain, tool, mv, state);
    let n = rb.steps_for(bound, mv.line)?;
    let poses = Poses::of(chain, mv, state);
    cut_substeps(
        stock,
        tool,
        (k, mv),
        (&rb, n),
        |l| Ok(poses.at(l)),
        report,
        observer,
    )?;
    observer.after_move(
        stock,
        k,
        mv,
        &Piece::Rotary {
            envelope: false,
            state: *state,
        },
    )?;
    Ok(rb.at(n))
}

/// Whether the move changes the value of an axis that has error motions (its pose then
/// follows a curved path: the move is swept like a rotary one).
fn moves_error_axis(chain: &Chain, mv: &Move) -> bool {
    chain
        .axes()
        .iter()
        .zip(chain.error_motions_all())
        .any(|(a, e)| e.is_some() && mv.start.get(a.letter) != mv.end.get(a.letter))
}

/// Largest distance (mm) of a move's end from the line of the run it joins. Far below any
/// length the stock resolves (crossings are exact to about this), so sweeping the joined
/// segment instead of its pieces moves no surface beyond rounding.
const JOIN_TOL: Real = tol::LENGTH_EPS;

/// Consecutive straight moves at the same rotary values along one line in one direction,
/// each starting where the previous ended: the union of their sweeps is the sweep of the
/// whole segment, so they are swept as one.
struct Run {
    /// Tip positions (W) at the run's start and current end.
    tip0: Point3,
    tip1: Point3,
    /// Tool orientation (T to W), the same for every move (same rotary values).
    rotation: Rotation3,
    /// The direction of travel, once a move of non-zero length fixed it.
    dir: Option<UnitVector3>,
    /// Axis values at the current end.
    end: AxisValues,
    /// Index of the run's first move.
    first: usize,
    /// Each move's end tip (W) and NC line.
    parts: Vec<(Point3, u32)>,
}

impl Run {
    fn new(k: usize, mv: &Move, tip0: Point3, tip1: Point3, rotation: Rotation3) -> Self {
        let d = tip1 - tip0;
        Self {
            tip0,
            tip1,
            rotation,
            dir: (d.norm() > JOIN_TOL).then(|| UnitVector3::new_normalize(d)),
            end: mv.end,
            first: k,
            parts: vec![(tip1, mv.line as u32)],
        }
    }

    /// Appends move `k` (tip ending at `tip1`, tool orientation `rotation`) if it continues
    /// the run.
    fn extend(&mut self, k: usize, mv: &Move, tip1: &Point3, rotation: &Rotation3) -> bool {
        if mv.start != self.end || rotation != &self.rotation || k != self.first + self.parts.len()
        {
            return false;
        }
        let d = tip1 - self.tip1;
        let along = match self.dir {
            Some(u) => {
                let from0 = tip1 - self.tip0;
                let off_line = (from0 - u.into_inner() * u.dot(&from0)).norm();
                (u.dot(&d) > 0.0 || d.norm() <= JOIN_TOL) && off_line <= JOIN_TOL
            }
            None => true,
        };
        if !along {
            return false;
        }
        if self.dir.is_none() && (tip1 - self.tip0).norm() > JOIN_TOL {
            self.dir = Some(UnitVector3::new_normalize(tip1 - self.tip0));
        }
        self.tip1 = *tip1;
        self.end = mv.end;
        self.parts.push((*tip1, mv.line as u32));
        true
    }
}

/// Sweeps a run of joined moves; counts the moves that removed material (for a run, the
/// moves a cut that removed material names at one of its ends). A run starting with a rapid
/// shows it to the observer first; after the removal, each of the run's moves.
fn flush(
    run: Option<Run>,
    stock: &mut TriDexel,
    tool: &Tool,
    moves: &[Move],
    report: &mut SweepReport,
    observer: &mut dyn SweepObserver,
) -> Result<(), SweepError> {
    let Some(run) = run else {
        return Ok(());
    };
    let piece = |j: usize| {
        let start = if j == 0 { run.tip0 } else { run.parts[j - 1].0 };
        Piece::Translation {
            tip: start,
            d: run.parts[j].0 - start,
            rotation: run.rotation,
        }
    };
    let axis = Piece::axis(&run.rotation);
    if moves[run.first].kind == MoveKind::Rapid {
        observer.before_rapid(stock, run.first, &moves[run.first], &piece(0))?;
    }
    let d = run.tip1 - run.tip0;
    let first = run.parts[0].1;
    let swept = if run.parts.len() == 1 {
        TranslatedTool::new(tool.clone(), run.tip0, d, axis)
    } else {
        let dd = d.norm_squared();
        let last = run.parts.len() - 1;
        let parts = run
            .parts
            .iter()
            .enumerate()
            .map(|(k, (tip, line))| {
                let s = if k == last || dd == 0.0 {
                    1.0
                } else {
                    (tip - run.tip0).dot(&d) / dd
                };
                (s, *line)
            })
            .collect();
        TranslatedTool::joined(tool.clone(), run.tip0, d, axis, parts)
    };
    report.sweeps += 1;
    let used = stock.remove_lines(&swept, first);
    report.cutting_moves += run
        .parts
        .iter()
        .filter(|(_, l)| used.binary_search(l).is_ok())
        .count();
    for j in 0..run.parts.len() {
        let k = run.first + j;
        observer.after_move(stock, k, &moves[k], &piece(j))?;
    }
    Ok(())
}

#[cfg(test)]
#[path = "../../benches/support/p1.rs"]
#[allow(
    clippy::duplicate_mod,
    reason = "benchmark P1's program is shared by the unit tests of sweep and zmap"
)]
mod p1;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cutting::stock::Crossing;
    use crate::progress::NoProgress;
    use proptest::prelude::*;

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

    /// The nominal 3-axis machine of benchmark P1 (Y table, X carriage, Z spindle).
    fn xyz_chain() -> Chain {
        Chain::cartesian([AxisLetter::Y, AxisLetter::X, AxisLetter::Z]).expect("valid chain")
    }

    fn linear(start: AxisValues, end: AxisValues, line: usize) -> Move {
        Move {
            kind: MoveKind::Linear,
            start,
            end,
            feed_mm_per_min: Some(600.0),
            line,
        }
    }

    fn opts() -> SweepOptions {
        SweepOptions {
            rotary_step_bound_mm: tol::ROTARY_STEP_BOUND,
        }
    }

    /// Every crossing of the stock with its point, in a fixed order.
    fn crossings(s: &TriDexel) -> Vec<(Point3, Crossing)> {
        let mut all = Vec::new();
        for g in s.grids() {
            g.for_each_crossing(|p, c| all.push((p, *c)));
        }
        all
    }

    /// Brute-force membership in a flat or ball end mill of radius `r`, length `l` (tip at
    /// the origin, axis +z), written out from the tool's definition and offset by `delta`
    /// (> 0 grows the tool, < 0 shrinks it: the flat's dilation is a superset of the true
    /// one, its erosion and both of the ball's are exact).
    fn in_tool(ball: bool, r: Real, l: Real, p: &Point3, delta: Real) -> bool {
        let rad = (p.x * p.x + p.y * p.y).sqrt();
        if p.z < -delta || p.z > l + delta {
            return false;
        }
        if ball && p.z < r {
            (rad * rad + (r - p.z) * (r - p.z)).sqrt() <= r + delta
        } else {
            rad <= r + delta && (delta >= 0.0 || p.z >= -delta)
        }
    }

    /// A move's tool poses sampled every `step` mm of tip travel (at least the two ends).
    fn sampled_poses(chain: &Chain, mv: &Move, step: Real) -> Vec<Isometry3> {
        let a = chain.w_from_t(&mv.start) * Point3::origin();
        let b = chain.w_from_t(&mv.end) * Point3::origin();
        let n = (((b - a).norm() / step).ceil() as usize).max(1);
        (0..=n)
            .map(|i| pose_at(chain, mv, i as Real / n as Real).inverse())
            .collect()
    }

    /// Is `x` in the sweep of a move (poses from [`sampled_poses`]), the tool offset by `delta`?
    fn in_sweep(
        poses: &[Isometry3],
        ball: bool,
        r: Real,
        l: Real,
        x: &Point3,
        delta: Real,
    ) -> bool {
        poses
            .iter()
            .any(|t_from_w| in_tool(ball, r, l, &(t_from_w * x), delta))
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

        /// Random programs of straight moves (some split into collinear pieces, which the
        /// sweep joins), flat or ball, tool axis tilted by a constant A: along every ray,
        /// points clear of the crossings agree with a brute-force point-in-sweep test, and
        /// every crossing names the earliest move whose tool reaches it.
        #[test]
        fn sweep_agrees_with_brute_force(
            ball in any::<bool>(),
            radius in 1.0..2.0f64,
            a_deg in prop_oneof![Just(0.0), -30.0..30.0f64],
            points in proptest::collection::vec((-4.0..4.0f64, -4.0..4.0f64, -2.0..3.0f64), 2..5),
            splits in proptest::collection::vec(1usize..4, 4),
        ) {
            let chain = crate::machine::chain::mdx50_for_tests();
            let kind = if ball { ToolKind::Ball } else { ToolKind::Flat };
            let (r, l) = (radius, 10.0);
            let tool = Tool::try_new(kind, 2.0 * r, l).expect("valid");
            let at = |p: &(Real, Real, Real)| {
                AxisValues::default()
                    .with(AxisLetter::X, p.0)
                    .with(AxisLetter::Y, p.1)
                    .with(AxisLetter::Z, p.2)
                    .with(AxisLetter::A, a_deg)
            };
            // Each leg between random points cut as 1 to 3 collinear pieces.
            let mut moves = Vec::new();
            for (w, &n) in points.windows(2).zip(&splits) {
                let (p, q) = (at(&w[0]), at(&w[1]));
                for k in 0..n {
                    let lerp = |f: Real| {
                        let mut v = p;
                        for axis in [AxisLetter::X, AxisLetter::Y, AxisLetter::Z] {
                            v.set(axis, p.get(axis) + (q.get(axis) - p.get(axis)) * f);
                        }
                        v
                    };
                    let (s0, s1) = (k as Real / n as Real, (k + 1) as Real / n as Real);
                    let start = if k == 0 { p } else { lerp(s0) };
                    let end = if k + 1 == n { q } else { lerp(s1) };
                    moves.push(linear(start, end, moves.len() + 1));
                }
            }
            let bounds = Aabb {
                min: Point3::new(-4.0, -4.0, -3.0),
                max: Point3::new(4.0, 4.0, 3.0),
            };
            let mut stock = TriDexel::new_box(bounds, 0.5, 1e9).expect("fits");
            let rep = sweep_program(&mut stock, &chain, &tool, &moves, &opts(), &NoProgress)
                .expect("sweeps");
            prop_assert_eq!(rep.moves, moves.len());
            prop_assert!(rep.sweeps < points.len());
            let delta = 0.02;
            let poses: Vec<_> = moves.iter().map(|m| sampled_poses(&chain, m, delta / 4.0)).collect();
            let near = |x: &Point3, k: usize| {
                let a = chain.w_from_t(&moves[k].start) * Point3::origin();
                let b = chain.w_from_t(&moves[k].end) * Point3::origin();
                let ab = b - a;
                let f = if ab.norm_squared() > 0.0 {
                    ((x - a).dot(&ab) / ab.norm_squared()).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                (x - (a + ab * f)).norm() <= l + r + 1.0
            };
            let deep = |x: &Point3, k: usize| near(x, k) && in_sweep(&poses[k], ball, r, l, x, -delta);
            let reached = |x: &Point3, k: usize| near(x, k) && in_sweep(&poses[k], ball, r, l, x, delta);
            for g in stock.grids() {
                let (nu, nv) = g.dims();
                let axis = g.axis();
                for iv in 0..nv {
                    for iu in 0..nu {
                        let o = g.ray_origin(iu, iv);
                        let segs = g.ray(iu, iv);
                        let mut t = bounds.min[axis] + 0.01;
                        while t < bounds.max[axis] {
                            let clear = segs.iter().all(|s| {
                                (s.lo.t - t).abs() > delta && (s.hi.t - t).abs() > delta
                            });
                            if clear {
                                let mut x = o;
                                x[axis] = t;
                                let material = segs.iter().any(|s| s.lo.t < t && t < s.hi.t);
                                if material {
                                    prop_assert!(
                                        !(0..moves.len()).any(|k| deep(&x, k)),
                                        "material at {x:?} lies inside the sweep"
                                    );
                                } else {
                                    prop_assert!(
                                        (0..moves.len()).any(|k| reached(&x, k)),
                                        "no material at {x:?} outside the sweep"
                                    );
                                }
                            }
                            t += 0.25;
                        }
                    }
                }
            }
            for (x, c) in crossings(&stock) {
                if c.line == 0 {
                    continue;
                }
                let k = c.line as usize - 1;
                prop_assert!(reached(&x, k), "crossing {x:?} of line {} off its move", c.line);
                prop_assert!(
                    !(0..k).any(|j| deep(&x, j)),
                    "crossing {x:?} of line {} lies inside an earlier move", c.line
                );
            }
        }
    }

    /// Joined sweeps of a tilted tool in fixed chunks: one and two worker threads give
    /// bit-identical stocks (every crossing's t, normal and line).
    #[test]
    fn sweep_is_bit_identical_for_one_and_two_threads() {
        let chain = crate::machine::chain::mdx50_for_tests();
        let tool = Tool::try_new(ToolKind::Ball, 3.0, 10.0).expect("valid");
        let at =
            |x: Real, y: Real, z: Real, a: Real| AxisValues::from_array([x, y, z, a, 0.0, 0.0]);
        let pts = [
            at(-6.0, -4.0, 4.0, 10.0),
            at(-6.0, -4.0, 1.0, 10.0),
            at(-3.0, -4.0, 1.0, 10.0),
            at(0.0, -4.0, 1.0, 10.0),
            at(6.0, -4.0, 1.0, 10.0),
            at(6.0, -2.5, 1.0, 10.0),
            at(-6.0, -2.5, 1.5, 10.0),
            at(2.0, 3.0, 0.0, 10.0),
        ];
        let moves: Vec<Move> = pts
            .windows(2)
            .enumerate()
            .map(|(k, w)| linear(w[0], w[1], k + 1))
            .collect();
        let run = |threads| {
            crate::math::in_pool(threads, || {
                let bounds = Aabb {
                    min: Point3::new(-8.0, -8.0, -4.0),
                    max: Point3::new(8.0, 8.0, 4.0),
                };
                let mut s = TriDexel::new_box(bounds, 0.05, 1e9).expect("fits");
                sweep_program(&mut s, &chain, &tool, &moves, &opts(), &NoProgress).expect("sweeps");
                crossings(&s)
            })
        };
        let one = run(1);
        assert!(one.iter().any(|(_, c)| c.line == 3), "the joined run cut");
        assert_eq!(one, run(2));
    }

    /// Benchmark P1-flat (docs/benchmarks.md) at 0.05 mm: the removed volume is 1.5 mm times
    /// the exact area of the 3 mm offset of the path, within 0.01 %.
    #[test]
    fn p1_flat_removes_the_offset_area_times_the_depth() {
        let tool = Tool::try_new(ToolKind::Flat, p1::TOOL_DIAMETER, 30.0).expect("valid");
        let mut s = TriDexel::new_box(p1::stock_box(), 0.05, 1e9).expect("fits");
        let v0 = s.volume();
        let moves = p1::moves();
        let rep = sweep_program(&mut s, &xyz_chain(), &tool, &moves, &opts(), &NoProgress)
            .expect("sweeps");
        assert_eq!(rep.moves, 3321);
        // The plunge and the 81 straight runs of the path.
        assert_eq!(rep.sweeps, 82);
        let truth = (20.0 - p1::Z_CUT) * p1::offset_area(p1::TOOL_DIAMETER / 2.0);
        let removed = v0 - s.volume();
        assert!(
            ((removed - truth) / truth).abs() < 1e-4,
            "removed {removed} mm³, truth {truth} mm³"
        );
    }

    /// Benchmark P1-ball at 0.05 mm: the z rays' top crossings lie on the analytic surface
    /// h(x, y) = min over the straight runs of z_tip + R − sqrt(R² − d²) (≤ 1 µm RMS); the
    /// scallop between rows 2 mm apart is R − sqrt(R² − 1) high (within 1 µm); and the
    /// tri-dexel holds at most 300 MB.
    #[test]
    fn p1_ball_surface_is_exact_in_bounded_memory() {
        let tool = Tool::try_new(ToolKind::Ball, p1::TOOL_DIAMETER, 30.0).expect("valid");
        // The box grown by half a pitch puts z rays on multiples of 0.05 mm, so on the crest
        // lines y = 11, 13, … between the rows.
        let mut bx = p1::stock_box();
        bx.min.x -= 0.025;
        bx.min.y -= 0.025;
        bx.max.x += 0.025;
        bx.max.y += 0.025;
        let mut s = TriDexel::new_box(bx, 0.05, 1e9).expect("fits");
        sweep_program(
            &mut s,
            &xyz_chain(),
            &tool,
            &p1::moves(),
            &opts(),
            &NoProgress,
        )
        .expect("sweeps");
        let r = p1::TOOL_DIAMETER / 2.0;
        let runs = p1::runs();
        let height = |x: Real, y: Real| {
            runs.iter()
                .filter_map(|&((x0, y0), (x1, y1))| {
                    let (dx, dy) = (x1 - x0, y1 - y0);
                    let f = (((x - x0) * dx + (y - y0) * dy) / (dx * dx + dy * dy)).clamp(0.0, 1.0);
                    let d = (x - x0 - f * dx).hypot(y - y0 - f * dy);
                    (d < r).then(|| p1::Z_CUT + r - (r * r - d * d).sqrt())
                })
                .fold(Real::INFINITY, Real::min)
        };
        let g = &s.grids()[2];
        let (nu, nv) = g.dims();
        let (mut sum2, mut n) = (0.0, 0usize);
        let mut crest: Real = 0.0;
        for iv in 0..nv {
            for iu in 0..nu {
                let o = g.ray_origin(iu, iv);
                let h = height(o.x, o.y);
                if h < 20.0 - tol::SLIVER {
                    let top = g
                        .ray(iu, iv)
                        .last()
                        .expect("material below the pocket")
                        .hi
                        .t;
                    sum2 += (top - h) * (top - h);
                    n += 1;
                    // Between rows, away from the step-overs.
                    if (20.0..=80.0).contains(&o.x) && (11.0..=89.0).contains(&o.y) {
                        crest = crest.max(top - p1::Z_CUT);
                    }
                }
            }
        }
        let rms = (sum2 / n as Real).sqrt();
        assert!(n > 2_000_000, "{n} rays in the pocket");
        assert!(rms <= 1e-3, "RMS {rms} mm");
        assert!(
            s.memory_bytes() <= 300_000_000,
            "{} bytes",
            s.memory_bytes()
        );
        let scallop = r - (r * r - 1.0).sqrt();
        assert!(
            (crest - scallop).abs() <= 1e-3,
            "scallop {crest} mm, formula {scallop} mm"
        );
    }
}
