//! Culling: a cheap, conservative test of whether a move can change a ray's material, run
//! before the ray's envelope is solved.
//!
//! The move's poses at `λ = k/(C·N)`, `k = 0..=C·N` (`N` cells, `C` = [`CULL_STEPS`] poses a
//! cell), are kept. Every `λ` lies within `1/(2·C·N)` of one of them, and no tool point
//! moves faster than the speed bound `M` per unit `λ`, so the tool at any `λ` lies inside
//! the tool at the nearest kept pose grown by `g = M/(2·C·N)` (plus [`CULL_MARGIN`] for the
//! rounding of the interval arithmetic). Along a ray the swept volume therefore lies inside
//! the union of the grown tools' intervals. When none of those meets a material segment
//! (open intervals, as [`crate::cutting::stock`] subtracts them), every interval the
//! envelope returns misses the material too and the ray comes out unchanged: skipping its
//! solve changes nothing, bit for bit. (The envelope joins intervals less than
//! [`tol::SLIVER`] apart; a material segment is at least that long, so it cannot lie in
//! such a gap clear of both grown ends.)
//!
//! A cell's middle pose grown by the envelope's `δ` holds the tool over the whole cell: a
//! ray whose material that misses is culled for the cell at once. Likewise the kept pose in
//! the middle of each half-cell (`λ` within `1/(4N)` of it) grown by `M/(4N)` holds the tool
//! over that half: where it misses the material, the half's inner kept poses need no test.
//!
//! **Consecutive moves** ([`GroupHull`]): each cell's tool lies in its middle pose's tool
//! grown by `δ`, and that in the tool at one reference pose grown further by how far any
//! tool point lies between the two poses: `|Δc| + ‖ΔR‖₂·ρ`, with `c` the middle of the tool's
//! axis, `ρ = √(R² + (L/2)²)` the largest distance of a tool point from it, and `‖ΔR‖₂` the
//! spectral norm of the rotations' difference (for two rotations `‖ΔR‖_F/√2`: its two
//! non-zero singular values are equal). A ray whose material the reference tool grown by
//! the largest of these misses is changed by none of the moves: the stock skips them all
//! at once ([`crate::cutting::stock::GroupCull`]).
//!
//! **Invariant:** a ray is culled only when the exact envelope could not change it.

use super::*;
use crate::cutting::stock::Segment;

/// Kept poses per cell for the cull test.
pub(super) const CULL_STEPS: usize = 8;

/// Added to the grown distance of the cull test (mm): far above the rounding of poses and
/// intervals in a workpiece a metre across, far below a dexel pitch.
pub(super) const CULL_MARGIN: Real = 1e-9;

/// The poses of the cull test and their growth.
#[derive(Clone, Debug)]
pub(super) struct CullPoses {
    pub(super) poses: Vec<Sample>,
    /// Each kept pose's [`axis_dirs`].
    dirs: Vec<[Vector3; 3]>,
    pub(super) grow: Real,
    /// The growth of a half-cell's middle pose that holds the tool over the half-cell.
    pub(super) half_grow: Real,
}

impl CullPoses {
    /// The kept poses of `path` for `cells` cells with speed bound `speed`.
    pub(super) fn new(path: &MovePath, cells: usize, speed: Real) -> Self {
        let n = CULL_STEPS * cells;
        let poses: Vec<Sample> = (0..=n)
            .map(|k| path.sample(k as Real / n as Real))
            .collect();
        Self {
            dirs: poses.iter().map(axis_dirs).collect(),
            poses,
            grow: speed / (2 * n) as Real + CULL_MARGIN,
            half_grow: speed / (4 * cells) as Real + CULL_MARGIN,
        }
    }
}

/// The directions of the x, y and z axes in a pose's tool frame (`rot.tr_mul(e_a)`), kept so
/// that the cull test of an axis ray need not transform its direction.
pub(super) fn axis_dirs(s: &Sample) -> [Vector3; 3] {
    std::array::from_fn(|a| s.rot.tr_mul(&Vector3::ith(a, 1.0)))
}

/// Whether a (grown) tool's interval along a ray meets any of the ray's material `segs`
/// (open intervals, as the stock subtracts them).
#[cfg(test)]
pub(super) fn meets_material(interval: Option<(Real, Face, Real, Face)>, segs: &[Segment]) -> bool {
    interval.is_some_and(|(t0, _, t1, _)| segs.iter().any(|m| t0 < m.hi.t && t1 > m.lo.t))
}

/// Whether the tool of `shape` (radius `r`, length `l`) grown by `g` meets any of the
/// material `segs` along the line `p + t·u` (tool frame, `u` unit): the same answer as
/// [`tool_interval`] against the segments, but without the interval's roots. Within a
/// segment and the grown end planes' slab, the line meets the grown cylinder `x² + y² ≤
/// (r + g)²` where the quadratic `a·t² + 2b·t + c` is at most zero somewhere, so at the
/// vertex `−b/a` clamped to that stretch (likewise the ball's sphere). A stretch touched at
/// one end only may answer yes where the interval test says no: the test stays
/// conservative, and the growth holds [`CULL_MARGIN`] for the rounding.
#[inline(always)]
pub(super) fn grown_meets(
    shape: Shape,
    (r, l): (Real, Real),
    p: &Vector3,
    u: &Vector3,
    g: Real,
    segs: &[Segment],
) -> bool {
    let h0 = match shape {
        Shape::Flat => -g,
        Shape::Ball => r - g,
    };
    let h1 = l + g;
    let (s0, s1) = if u.z.abs() <= tol::RELATIVE_EPS {
        if !(h0 <= p.z && p.z <= h1) {
            (Real::INFINITY, Real::NEG_INFINITY)
        } else {
            (Real::NEG_INFINITY, Real::INFINITY)
        }
    } else {
        let (a, b) = ((h0 - p.z) / u.z, (h1 - p.z) / u.z);
        (a.min(b), a.max(b))
    };
    let rad2 = (r + g) * (r + g);
    let a = u.x * u.x + u.y * u.y;
    let b = p.x * u.x + p.y * u.y;
    let c = p.x * p.x + p.y * p.y - rad2;
    let vertex = if a <= tol::RELATIVE_EPS {
        None
    } else {
        Some(-b / a)
    };
    // The ball's sphere about (0, 0, r): `t² + 2·bs·t + cs`.
    let w = Vector3::new(p.x, p.y, p.z - r);
    let (bs, cs) = (w.dot(u), w.dot(&w) - rad2);
    segs.iter().any(|m| {
        let (lo, hi) = (s0.max(m.lo.t), s1.min(m.hi.t));
        let side = lo <= hi
            && match vertex {
                None => c <= 0.0,
                Some(v) => {
                    let t = v.clamp(lo, hi);
                    (a * t + 2.0 * b) * t + c <= 0.0
                }
            };
        side || (shape == Shape::Ball && {
            let t = (-bs).clamp(m.lo.t, m.hi.t);
            (t + 2.0 * bs) * t + cs <= 0.0
        })
    })
}

impl RotaryEnvelope {
    /// Whether the move may change the material `segs` of the ray `o + t·e_axis`:
    /// false only when no grown kept pose meets any segment (see the module docs). Each
    /// cell is first tested whole, by its middle pose grown by `δ` (which holds the tool
    /// throughout the cell); its kept poses only when that meets the material, the cell's
    /// ends first (where a move that cuts the ray usually meets its material), then the
    /// inner ones of each half-cell whose middle pose, grown to hold the half, meets it.
    pub fn may_cut(&self, o: &Point3, axis: usize, segs: &[Segment]) -> bool {
        let meets = |s: &Sample, u: &[Vector3; 3], g: Real| {
            let p = s.rot.tr_mul(&(o - s.tip));
            grown_meets(self.shape, (self.r, self.l), &p, &u[axis], g, segs)
        };
        let (g, half) = (self.cull.grow, self.cull.half_grow);
        const H: usize = CULL_STEPS / 2;
        (0..self.cells).any(|j| {
            let first = j * CULL_STEPS;
            let at = |i: usize, g: Real| {
                meets(&self.cull.poses[first + i], &self.cull.dirs[first + i], g)
            };
            // Half 0 holds kept poses 0..=H (0 tested already), half 1 H..=2H (H and 2H
            // tested already).
            let inner = |h: usize| {
                let mut range = if h == 0 { 1..=H } else { H + 1..=2 * H - 1 };
                at(h * H + H / 2, half) && range.any(|i| at(i, g))
            };
            meets(
                &self.samples[2 * j + 1],
                &self.sample_dirs[2 * j + 1],
                self.delta + CULL_MARGIN,
            ) && (at(0, g) || at(CULL_STEPS, g) || inner(0) || inner(1))
        })
    }
}

/// Relative allowance on a group hull's growth for the rounding of its poses' differences
/// (far above it; the absolute allowance is [`CULL_MARGIN`]).
const HULL_ROUNDING: Real = 1e-9;

/// The tools of consecutive envelope moves held in one grown tool (see the module docs): a
/// ray whose material it misses is changed by none of the moves.
#[derive(Clone, Debug)]
pub struct GroupHull {
    shape: Shape,
    r: Real,
    l: Real,
    /// The reference pose: the middle sample of the group's middle move, and its
    /// [`axis_dirs`].
    reference: Sample,
    dirs: [Vector3; 3],
    /// The growth that holds every move's tool (mm).
    grow: Real,
}

impl GroupHull {
    /// The hull of the moves `group` (one tool; not empty).
    pub fn of(group: &[&RotaryEnvelope]) -> Self {
        let mid = group[group.len() / 2];
        let reference = mid.samples[mid.samples.len() / 2];
        let (r, l) = (mid.r, mid.l);
        let axis_mid = Vector3::new(0.0, 0.0, l / 2.0);
        let rho = (r * r + l * l / 4.0).sqrt();
        let centre = reference.rot * axis_mid + reference.tip.coords;
        let grow = group
            .iter()
            .flat_map(|env| {
                (0..env.cells).map(|j| {
                    let s = &env.samples[2 * j + 1];
                    let moved = (s.rot * axis_mid + s.tip.coords - centre).norm();
                    let turned = (s.rot - reference.rot).norm() / std::f64::consts::SQRT_2;
                    env.delta + moved + turned * rho
                })
            })
            .fold(0.0, Real::max);
        Self {
            shape: mid.shape,
            r,
            l,
            reference,
            dirs: axis_dirs(&reference),
            grow: grow * (1.0 + HULL_ROUNDING) + CULL_MARGIN,
        }
    }

    /// The growth of the reference tool that holds every move's tool (mm).
    pub fn grow(&self) -> Real {
        self.grow
    }
}

impl crate::cutting::stock::GroupCull for GroupHull {
    /// False only when the grown reference tool's interval along the ray misses every
    /// material segment.
    fn may_cut(&self, o: &Point3, axis: usize, segs: &[Segment]) -> bool {
        let p = self.reference.rot.tr_mul(&(o - self.reference.tip));
        grown_meets(
            self.shape,
            (self.r, self.l),
            &p,
            &self.dirs[axis],
            self.grow,
            segs,
        )
    }
}
