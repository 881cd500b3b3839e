//! The exact swept volume of a flat or ball end mill on a move that turns a rotary axis,
//! ray by ray: the per-ray envelope.
//!
//! On a move from `q0` to `q1` every axis value is linear in `λ ∈ [0, 1]` and the tool's pose
//! is `T(λ) = chain.w_from_t(q(λ))`, a rotation and a translation that both vary. Along a ray
//! `o + t·e` the tool at one `λ` is convex, so it occupies one interval `[t_in(λ), t_out(λ)]`
//! (or none), found in closed form in the tool frame: the ray `T(λ)⁻¹(o + t·e)` against the
//! cylinder `r ≤ R` between the end planes, and for a ball end mill the sphere of radius `R`
//! about the axis point at height `R`. The swept volume along the ray is the union over `λ`:
//! one interval `[min t_in, max t_out]` for every connected set of `λ` where the ray meets
//! the tool (the intervals move continuously), possibly several disjoint intervals.
//!
//! **Where the extremes are.** The least `t_in` (greatest `t_out`) over a connected set of
//! poses is at one of: a move end; a smooth extreme, where the active face's rate
//! `dt/dλ = (n·V)/(n·e)` (outward normal `n`, the tool's velocity `V` at the point) changes
//! sign; or a pose where the ray passes through an edge circle of the tool (bottom and top
//! edges of a flat end mill, the top edge of a ball end mill), which is where the active face
//! changes (a kink) or where the ray leaves the tool with finite slope. Where the ray merely
//! touches a smooth face (`t_in = t_out`), `t_in` rises and `t_out` falls with infinite slope
//! into the touch, so no extreme sits there. Each pose is evaluated in closed form with the
//! rate of both ends and, for every edge, `φ = ρ − R`, the radius at which the ray crosses
//! the edge's plane; an edge crossing is a sign change of `φ`.
//!
//! **Cells.** No tool point moves faster than `M = Σ_k ω_k·ρ_k + v` per unit `λ` (`ω_k` the
//! turn of rotary axis `k` in rad, `ρ_k` a bound on the distance of any tool point from its
//! line during the move, grown by what the axes after it in the chain can move the point;
//! `v` the linear travel), nor faster than the total turn times the largest such distance
//! (see `path::speed_bound`). The move is split into `N` cells of width `h` with
//! `δ = M·h/2 ≤ R/8`: the tool anywhere in a cell lies inside the tool at the cell's middle
//! grown by `δ`. A ray that misses the grown tool misses the cell. The ray is evaluated
//! exactly at the ends and middle of every cell it may meet; in each half-cell (the tool
//! moves by at most `R/8`) a sign change of a rate or of `φ` is solved for by the Illinois
//! variant of regula falsi, and the pose found is offered. For a rate its steps are
//! guesses where one falls inside the bracket: the extreme of the cubic through the end's
//! positions and rates at the bracket's ends (Hermite), and a step closer to a bracket end
//! than half the width the stop needs is moved out to that distance, so that it lands past
//! the root and the bracket closes. The guesses choose where to look, not what is
//! accepted: the bracket and the stop are those of the regula falsi. An edge crossing is
//! guided likewise, by Newton's step on `φ` from the bracket end where `|φ|` is least
//! (`dφ/dλ` in closed form, `RotaryEnvelope::phi_rate`); which side of its kink the kept end
//! comes from no longer changes its normal (see **Normals**). A half-cell
//! whose ends both miss may hide a touch: the tool lies in capsules of radius `R` about
//! four pieces of its axis, each with its own speed bound `M_k`, and a touch deeper than
//! the tolerance `τ` needs some piece to travel from both ends to the ray
//! (`d_k(a) + d_k(b) + 2·τ ≤ M_k·w`, `d_k` the ray's distance from the capsule); while one
//! can, the half-cell is bisected, the middle checked against the tool grown by
//! `M·w/2 − τ`. Before bisecting, where every axis moves at a constant rate, a second-order
//! test shows the tool missing an axis ray throughout the half-cell when its capsule (or,
//! for a flat end mill, its cylinder) stays farther than `R` from the ray: the distance
//! vectors taken to first order from each end, their bilinear patch's hull, less the
//! acceleration's share (`RotaryEnvelope::touch_ruled_out`). The bisection would then find
//! nothing, so skipping it changes no bit. A tool passing along a ray at a small, nearly
//! constant distance (the side cut's wall and floor rays) is settled at once instead of by
//! bisecting until the tool moves less than that distance. A half-cell with one end inside
//! and a rate that points to an extreme before the ray leaves is bisected until the extreme
//! is bracketed.
//!
//! **Span.** The stock asks only about the material's extent along a ray
//! ([`Cutter::ray_cuts_in_span`]): cells whose grown tool meets the ray only outside it are
//! skipped, and an interval end already beyond it is not refined (it stays beyond it). It
//! asks only about rays the cull kept, so a move of one cell is probed without that grown
//! test: after the swept cull it nearly always passes, and a cell it would have skipped
//! gives no interval reaching into the span. Such a move (most small moves) has its three
//! probes, their components and the touches between them on the stack
//! (`RotaryEnvelope::one_cell`); the general path, with per-thread buffers sized by the
//! cells, takes the same steps in the same order for any number of cells.
//!
//! **Accuracy.** Every interval end is the exact interval of some pose, so nothing is cut
//! that the tool does not reach. A smooth extreme is solved until
//! `min(|dt/dλ|) · w ≤ τ/10` ([`SOLVE_SHARE`]) over the final bracket `w`, which bounds the
//! distance to the true extreme on a convex stretch; an edge crossing until `w` times the
//! larger rate at the bracket ends is below it. A touch between two missing poses is
//! ignored only when it reaches less than `τ` into the ray (measured normal to the tool's
//! surface). The bound is the tolerance `τ`: [`ENVELOPE_TOL`] = 1e-7 mm (0.1 nm) as built,
//! or what the sweep's own bound allows ([`RotaryEnvelope::with_tolerance`]; the sweep
//! gives its envelopes the user's `rotary_step_bound_mm`, so a looser bound buys fewer
//! solve steps and fewer bisections, never a different cull or a different pose model).
//!
//! **Known limit.** Within one half-cell each rate and each `φ` is taken to change sign at
//! most once, and a ray inside the tool at both ends of a half-cell to be inside in between.
//! A ray that leaves the tool and meets it again while the tool moves by less than `R/8`, or
//! crosses an edge circle twice in that motion, can only be grazing it.
//!
//! **Normals.** The normal at an interval end is the swept volume's: on a face, the tool's
//! outward normal of the face that bounds the interval (side, end plane, or sphere) at that
//! point and pose; within 1 µm of an edge circle, the normal of the surface the edge sweeps,
//! `τ × V` (`τ` the edge's tangent, `V` the edge point's velocity), taken within the edge's
//! normal cone (between its two faces' normals). At a kink, where the ray's end is farthest
//! as it passes through the edge, that is neither face's normal, and the kept end's pose,
//! on one side of the kink or the other, no longer changes it; on a face next to the edge it
//! tends to the face's own. Where no normal of the cone is across `V` (or `V` runs along
//! the edge) the face's normal is kept.
//!
//! **Pose sources.** A machine read pose by pose (a hexapod) has no chain: its move is the
//! smooth curve through its pilot poses ([`SampledPath`], [`RotaryEnvelope::sampled`]), with
//! rates in closed form and speed bounds from the curve; everything above applies to it.
//!
//! **Invariant:** the envelope knows only the tool's shape, the chain's poses (or a pose
//! source's pilot poses) and one move; it never reads programs, stock or files.
//!
//! **Files.** This one holds the tolerances, the error and [`RotaryEnvelope`] as a
//! [`Cutter`]; `path` the move's poses and speed bounds, `probe` the tool at one pose against
//! a ray, `solve` the envelope's construction and the per-ray solve, `cull` the test that skips
//! rays the move cannot change, `sampled` the curve through a pose source's pilot poses,
//! `tests` the unit tests.

use crate::cutting::stock::{Cutter, RayCut, Segment};
use crate::cutting::tool::{Tool, ToolKind};
use crate::machine::chain::{AxisKind, Chain};
use crate::machine::error_motion::{self, AxisErrorMotions, Directions};
use crate::math::{Aabb, Isometry3, Matrix3, Point3, Real, Vector3, tol};
use crate::nc::AxisValues;
use std::cell::Cell;

mod cull;
mod path;
mod probe;
mod sampled;
mod solve;

pub use cull::GroupHull;
pub use path::{MovePath, error_motion_speed, rotation_and_travel};
use path::{Sample, axis_speed_bounds, speed_bound};
use probe::{
    EdgeSign, Face, Hit, Probe, Ray, Shape, ball_sphere, end_slab, frame_box,
    line_segment_distance, tool_interval, tool_interval_in, tool_normal,
};
pub use sampled::{SAMPLED_BOUND_FACTOR, SampledPath};

/// The finest bound (mm) on the distance of the envelope's interval ends from the true
/// swept surface along a ray, and the one an envelope is built with: 1e-7 mm (0.1 nm), far
/// below the µm-metrology budget. A sweep whose bound allows more loosens it
/// ([`RotaryEnvelope::with_tolerance`]); the solver brings an end to a tenth of it
/// ([`SOLVE_SHARE`]).
pub const ENVELOPE_TOL: Real = 1e-7;

/// The share of the envelope's tolerance to which the solver brings an interval end to the
/// true extreme (1e-8 mm at [`ENVELOPE_TOL`]).
pub const SOLVE_SHARE: Real = 0.1;

/// Largest grown distance `δ` as a fraction of the tool radius: cells move the tool by at
/// most twice that, a quarter of its radius, half-cells by an eighth.
const CELL_GROWTH: Real = 0.125;

/// Pieces of the tool's axis for the separation test between poses that miss the ray.
const PARTS: usize = 4;

/// Most cells for one move; beyond this the move is refused (the caller falls back).
const MAX_CELLS: usize = 1 << 16;

/// Regula falsi steps before a solve gives up (every third step halves the bracket unless,
/// for a rate's extreme, the least `|f|` at its ends fell sixteenfold over the last three,
/// which rounding ends within a few dozen steps, so 200 steps reach far below any `λ`
/// resolution).
const MAX_SOLVE_STEPS: usize = 200;

/// Recursion depth of the half-cell refinement; each level halves the width, so 60 levels
/// reach below `f64` resolution of `λ`.
const MAX_DEPTH: u32 = 60;
/// Errors of building an envelope (the caller sweeps such a move another way).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum EnvelopeError {
    /// The tool has no closed form here (not flat, or a ball shorter than its diameter).
    #[error("the envelope solves flat end mills and ball end mills at least a diameter long")]
    UnsupportedTool,
    /// The move would need more cells than allowed (an absurd rotation or travel).
    #[error("the move needs {0:.3e} envelope cells")]
    TooManyCells(Real),
}

/// A flat or ball end mill on one move of a chain, as a [`Cutter`]: exact per-ray envelope.
#[derive(Clone, Debug)]
pub struct RotaryEnvelope {
    shape: Shape,
    r: Real,
    l: Real,
    path: MovePath,
    cells: usize,
    /// Grown distance δ of a cell (mm).
    delta: Real,
    /// Bound on a tool point's speed per unit λ (mm).
    speed: Real,
    /// Heights bounding the pieces of the axis segment whose capsules (radius R) hold the tool.
    part_z: [Real; PARTS + 1],
    /// Speed bound of each capsule piece's points per unit λ (mm).
    part_speed: [Real; PARTS],
    /// Where every axis moves at a constant rate: the bounds of the second-order touch test
    /// (`RotaryEnvelope::touch_ruled_out`).
    touch: Option<TouchBounds>,
    /// Poses at λ = k/(2N), k = 0..=2N: cell ends at even k, middles at odd k.
    samples: Vec<Sample>,
    /// Each sample's directions of the x, y and z axes in its tool frame (`cull::axis_dirs`).
    sample_dirs: Vec<[Vector3; 3]>,
    /// Poses halfway between consecutive samples, with their λ: where every ray's first
    /// bisection and touch test look (computed once per move instead of once per ray; the
    /// same pose bit for bit, see [`RotaryEnvelope::sample_at`]).
    quarters: Vec<(Real, Sample)>,
    /// Each quarter pose's directions of the x, y and z axes in its tool frame.
    quarter_dirs: Vec<[Vector3; 3]>,
    /// Box of each cell's grown tool.
    cell_boxes: Vec<Aabb>,
    bounds: Aabb,
    /// The poses of the cull test ([`RotaryEnvelope::may_cut`]).
    cull: cull::CullPoses,
    /// The swept cull's poses, where every axis moves at a constant rate (used instead of
    /// `cull`).
    swept: Option<cull::SweptPoses>,
    /// The bound (mm) on the interval ends' distance from the true swept surface: a touch
    /// shallower than this is ignored, and an end is solved to [`SOLVE_SHARE`] of it.
    tol: Real,
    /// The sign of an edge's `φ` from a probe's squared radius ([`Probe::phi`]).
    edge: EdgeSign,
}

/// The bounds of the second-order touch test between two poses that miss a ray, on a move
/// whose axes all move at constant rates (see `RotaryEnvelope::touch_ruled_out`).
#[derive(Clone, Copy, Debug)]
struct TouchBounds {
    /// The total turn Ω (rad per unit λ): no direction turns faster.
    omega: Real,
    /// A bound on the acceleration of the axis points from `part_z[0]` to the top (mm per
    /// unit λ²).
    capsule_accel: Real,
    /// For a flat end mill, the per-axis speed bound `P` of every point within
    /// `R +` [`SLAB_REACH`] of its axis (mm per unit λ).
    slab_speed: Option<Real>,
}

/// How far beyond the tool's radius (mm) the slab test's speed bound holds: the test is
/// used only where a ray point cannot drift farther over the half-cell.
const SLAB_REACH: Real = 1.0;

/// The least `|cos|` of the angle between a ray and the tool's axis for the slab test.
const SLAB_MIN_COS: Real = 0.25;

impl Cutter for RotaryEnvelope {
    fn bounds(&self) -> Aabb {
        self.bounds
    }

    /// The hull of the ray's intervals; the stock uses [`Cutter::ray_cuts`].
    fn ray_cut(&self, origin: &Point3, axis: usize) -> Option<RayCut> {
        let mut out = Vec::new();
        self.ray_cuts(origin, axis, &mut out);
        RayCut::hull(&out)
    }

    fn ray_cuts(&self, origin: &Point3, axis: usize, out: &mut Vec<RayCut>) {
        let mut e = Vector3::zeros();
        e[axis] = 1.0;
        self.intervals(origin, &e, out);
    }

    fn costly_rays(&self) -> bool {
        true
    }

    fn may_cut(&self, origin: &Point3, axis: usize, segs: &[Segment]) -> bool {
        RotaryEnvelope::may_cut(self, origin, axis, segs)
    }

    fn ray_cuts_in_span(
        &self,
        origin: &Point3,
        axis: usize,
        span: (Real, Real),
        line: u32,
        out: &mut Vec<RayCut>,
        lines: &mut Vec<[u32; 2]>,
    ) {
        let mut e = Vector3::zeros();
        e[axis] = 1.0;
        let before = out.len();
        // The stock asks only about rays that passed the cull (`stock::cut_ray`).
        self.intervals_near(origin, &e, span, true, out);
        lines.resize(lines.len() + out.len() - before, [line, line]);
    }
}

#[cfg(test)]
mod tests;
