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
//! **The swept cull** ([`SweptPoses`], used instead of the kept poses on a move whose axes
//! all move at constant rates: no error motions, not read pose by pose). The tool is
//! symmetric about its axis, so of the rigid motion from a pose `λm` to `λ` only the
//! translation of the axis's middle `c` and the tilt of the axis matter. In the tool frame
//! at `λm`, over `|λ − λm| ≤ s`:
//!
//! - `c` moves by `(λ − λm)·V + e`, `V = v_t + w_t × c` its velocity at `λm`, `|e| ≤ A·s²/2`
//!   with `A` a bound on its acceleration;
//! - the axis turns by `θ ≤ s·|w_⊥| + 0.75·Ω²·s²` (`w_⊥` the angular velocity's part across
//!   the axis at `λm`, which changes by at most `1.5·Ω²` per unit `λ`, `Ω` the total turn:
//!   `|ω'| ≤ Ω²/2` and the axis turns at `|ω|`), and the tool turned by `θ` about `c` lies
//!   in the tool about `c` with radius `r + (l/2)·θ` and end planes `r·θ` further out.
//!
//! So the tool lies in the tool at `λm` translated along `τ·D`, `τ ∈ [−1, 1]`, `D = s·V`,
//! and grown by `max(l/2, r)·θ + A·s²/2` (plus the margins): a cylinder swept along a
//! segment, whose width across the motion is exact, where the kept poses' growth `M·s`
//! covers the translation too. With every axis at a constant rate the spatial twist's rate
//! is the sum of the brackets of the pairs of joint twists; the field of a bracket at a
//! point is `ω_j × X_k − ω_k × X_j`, at most `ω_j·ω_k·(ρ_j + ρ_k)` for two rotary axes (`ρ`
//! the point's distance from their lines) and `ω_j·v_k` for a rotary and a linear one, in
//! all at most `Ω·P` with `P` the point's per-axis speed bound; `ω × ẋ` adds at most `Ω·P`:
//! `A = 2·Ω·P`. Per cell the swept cell (about its middle sample, `s = h/2`) is tested,
//! then its halves (about the quarter poses, `s = h/4`): a ray whose material misses the
//! swept cell, or both swept halves, is not changed by the cell.
//!
//! **The height-aware test** (`AxisSweep`, one per cell of the swept cull). The growth
//! `max(l/2, r)·θ` holds the whole tool turning about its middle; a ray across the tool
//! meets it within a short band of heights, and the tilt's first-order motion is a
//! translation that grows linearly with height. Turning about the axis point `c_h` at any
//! height `h` instead: the point moves by `τ·D(h) + e`, `D(h) = D + (h − l/2)·s·(w_t × ẑ)`
//! (the reach at that height; `|e| ≤ A'·s²/2` with `A' = 2·Ω·P'` and `P'` the per-axis
//! speed bound of any axis point), and a tool point at height `z` lies within
//! `r + θ·|z − h|` of the axis through the moved `c_h` across it (a point turned by `θ`
//! about an axis square to the tool's moves by at most `|z − h|·sin θ` across it, its
//! height by at most `r·θ + |z − h|·θ²/2`). So for a ray's stretch of material within the
//! end planes (grown by `r·θ + l·θ²/2 + e + |D_z|`) and within the swept pose's own clip
//! radius of the axis, whose heights span `h ± b` (`h` its middle, kept on the axis), the
//! tool lies within `r + g` of the segment `τ·D(h)`, `g = (r + θ·(b + |D_z| + e))/(1 − θ²)
//! − r + e`: a growth of a micrometre or so where the swept pose's is tens. A ball's
//! sphere turns into itself, so only its centre's path `τ·D(r)`, grown by `e`, matters.
//! Used on rays crossing the tool (`|u_z| < 1/2` in the tool frame) whose material the swept
//! cell meets but does not reach `r − g` deep into (deeper, no finer test would clear it),
//! instead of the swept halves; rays along the tool keep the halves.
//!
//! **Consecutive moves** ([`GroupHull`]): each cell's tool lies in its middle pose's tool
//! grown by `δ`, and that in the tool at one reference pose grown further by how far any
//! tool point lies between the two poses: `|Δc| + ‖ΔR‖₂·ρ`, with `c` the middle of the tool's
//! axis, `ρ = √(R² + (L/2)²)` the largest distance of a tool point from it, and `‖ΔR‖₂` the
//! spectral norm of the rotations' difference (for two rotations `‖ΔR‖_F/√2`: its two
//! non-zero singular values are equal). A ray whose material the reference tool grown by
//! the largest of these misses is changed by none of the moves: the stock skips them all
//! at once ([`crate::cutting::stock::GroupCull`]). Where every move has the swept cull, the
//! hull is swept too: each cell's swept tool is the reference tool translated by the cell's
//! axis-middle segment and grown by the cell's growth and by its tilt from the reference;
//! the reference tool swept along the segment from the first cell's start to the last
//! cell's end, grown by the largest of those plus each cell segment's distance from that
//! one, holds them all (`GroupHull::swept`).
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

/// The stretch of a line `p + t·u` (tool frame) between the end planes of the tool of
/// `shape` (radius `r`, length `l`) moved `g` further out (the bottom plane of a flat end
/// mill, the ball's equator for a ball end mill, and the top), from `p.z` and `inv_z`, the
/// reciprocal of `u.z` (`None` where the line is parallel to the planes: all of it between
/// them, or none). An empty stretch is `(∞, −∞)`.
#[inline(always)]
fn end_slab(
    shape: Shape,
    (r, l): (Real, Real),
    g: Real,
    p_z: Real,
    inv_z: Option<Real>,
) -> (Real, Real) {
    let h0 = match shape {
        Shape::Flat => -g,
        Shape::Ball => r - g,
    };
    let h1 = l + g;
    match inv_z {
        None if !(h0 <= p_z && p_z <= h1) => (Real::INFINITY, Real::NEG_INFINITY),
        None => (Real::NEG_INFINITY, Real::INFINITY),
        Some(k) => {
            let (a, b) = ((h0 - p_z) * k, (h1 - p_z) * k);
            (a.min(b), a.max(b))
        }
    }
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
    let inv_z = (u.z.abs() > tol::RELATIVE_EPS).then(|| 1.0 / u.z);
    let (s0, s1) = end_slab(shape, (r, l), g, p.z, inv_z);
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

/// Below this `(uu·dd − ud²)/(uu·dd)` (the squared sine of the angle between the ray and
/// the reach) [`least_distance2`] takes the least over the box's edges, less what the
/// interior can lie below them (the closest pair of nearly parallel lines is ill
/// conditioned).
const PARALLEL: Real = 1e-8;

/// A ray's direction `u` against one swept pose's reach `D`, for the least distance between
/// the ray's stretches and the reach's segment ([`least_distance2`]): `ud = u·D`,
/// `dd = D·D`, the reciprocals of `u·u` and `dd` (0 where not positive), that of
/// `uu·dd − ud²` where the two are not nearly parallel (else 0), and then the slack
/// `2·PARALLEL·uu` per squared length of the stretch.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Pair {
    u: Vector3,
    d: Vector3,
    ud: Real,
    dd: Real,
    inv_uu: Real,
    inv_dd: Real,
    inv_den: Real,
    slack: Real,
}

impl Pair {
    pub(super) fn new(u: Vector3, d: Vector3) -> Self {
        let (uu, ud, dd) = (u.dot(&u), u.dot(&d), d.dot(&d));
        let inv = |x: Real| if x > Real::MIN_POSITIVE { 1.0 / x } else { 0.0 };
        let den = uu * dd - ud * ud;
        let apart = den > PARALLEL * uu * dd;
        Self {
            u,
            d,
            ud,
            dd,
            inv_uu: inv(uu),
            inv_dd: inv(dd),
            inv_den: if apart { inv(den) } else { 0.0 },
            slack: if apart { 0.0 } else { 2.0 * PARALLEL * uu },
        }
    }
}

impl Pair {
    /// [`Pair::new`] from `u` with `u·u` and its reciprocal known, `d`, `u·d` and `d·d`
    /// (one division where the two are apart).
    #[inline(always)]
    fn across((u, uu, inv_uu): (Vector3, Real, Real), d: Vector3, ud: Real, dd: Real) -> Self {
        let den = uu * dd - ud * ud;
        let both = dd * den;
        if den > PARALLEL * uu * dd && both > Real::MIN_POSITIVE {
            let x = 1.0 / both;
            return Self {
                u,
                d,
                ud,
                dd,
                inv_uu,
                inv_dd: den * x,
                inv_den: dd * x,
                slack: 0.0,
            };
        }
        let mut pair = Self::new(u, d);
        pair.inv_uu = inv_uu;
        pair
    }
}

/// A lower bound, exact where the two are not nearly parallel, on the squared distance
/// between the stretch `p + t·u`, `t ∈ [lo, hi]`, and the segment `τ·D`, `τ ∈ [−1, 1]` (`u`,
/// `D` and their products in `q`): the least of the convex quadratic `|p + t·u − τ·D|²`
/// over the box.
///
/// - **Apart.** `t` from the lines' closest pair clamped to the stretch, `τ` nearest to
///   that point clamped to the segment, and where `τ` was clamped `t` nearest to that end
///   (the closest points of two segments, after Ericson, *Real-Time Collision Detection*,
///   §5.1.9).
/// - **Nearly parallel.** The least over the box's four edges (each a clamp in closed
///   form), which is the least over the box unless the lines' closest pair lies inside it;
///   then the quadratic along the valley `k·(t − t*)²`, `k = (uu·dd − ud²)/dd ≤ PARALLEL·uu`
///   (rounding aside), meets an edge within the stretch's length of `t*`, so the edges
///   exceed the least by at most `k·(hi − lo)²`: that is taken off, doubled.
#[inline(always)]
pub(super) fn least_distance2(p: &Vector3, q: &Pair, (lo, hi): (Real, Real)) -> Real {
    let (pu, pd) = (p.dot(&q.u), p.dot(&q.d));
    if q.inv_den > 0.0 {
        let t = ((q.ud * pd - q.dd * pu) * q.inv_den).clamp(lo, hi);
        let tau = (pd + q.ud * t) * q.inv_dd;
        let (t, tau) = if tau < -1.0 {
            (((-q.ud - pu) * q.inv_uu).clamp(lo, hi), -1.0)
        } else if tau > 1.0 {
            (((q.ud - pu) * q.inv_uu).clamp(lo, hi), 1.0)
        } else {
            (t, tau)
        };
        return (p + q.u * t - q.d * tau).norm_squared();
    }
    // The edges t = lo, hi (τ nearest) and τ = ±1 (t nearest).
    let across = |t: Real| {
        let tau = ((pd + q.ud * t) * q.inv_dd).clamp(-1.0, 1.0);
        (p + q.u * t - q.d * tau).norm_squared()
    };
    let along = |tau: Real| {
        let t = ((q.ud * tau - pu) * q.inv_uu).clamp(lo, hi);
        (p + q.u * t - q.d * tau).norm_squared()
    };
    let least = across(lo).min(across(hi)).min(along(-1.0)).min(along(1.0));
    (least - q.slack * (hi - lo) * (hi - lo)).max(0.0)
}

/// Entries of [`SweptPoses`] per cell: the cell and its two halves.
const SWEPT_PER_CELL: usize = 3;

/// One pose of the swept cull: the tool there, translated along `τ·reach` (`τ ∈ [−1, 1]`,
/// tool frame) and grown by `grow`, holds the tool over a stretch of `λ` about it.
#[derive(Clone, Copy, Debug)]
pub(super) struct SweptPose {
    pub(super) rot: Matrix3,
    pub(super) tip: Point3,
    pub(super) reach: Vector3,
    pub(super) grow: Real,
    /// Per axis ray: its direction's reciprocal component along the tool axis (`None`:
    /// parallel to the end planes) and its pairs with the reach across the axis and in
    /// full.
    axes: [(Option<Real>, Pair, Pair); 3],
}

impl SweptPose {
    /// The swept pose that holds the tool (radius and length `r`, `l`) over `λ` within
    /// `half` of the pose `s`'s, on a move of total turn `omega` whose tool axis's middle
    /// point accelerates by at most `accel` (see the module docs).
    fn about(s: &Sample, half: Real, (r, l): (Real, Real), (omega, accel): (Real, Real)) -> Self {
        let centre = Vector3::new(0.0, 0.0, l / 2.0);
        let tilt = turn_bound(s, half, omega);
        let reach = (s.v_t + s.w_t.cross(&centre)) * half;
        let grow = (l / 2.0).max(r) * tilt + accel * half * half / 2.0;
        let grow = (grow + HULL_ROUNDING * reach.norm()) * (1.0 + HULL_ROUNDING) + CULL_MARGIN;
        Self::new(s, reach, grow)
    }

    fn new(s: &Sample, reach: Vector3, grow: Real) -> Self {
        let dxy = Vector3::new(reach.x, reach.y, 0.0);
        let axes = axis_dirs(s).map(|u| {
            let uxy = Vector3::new(u.x, u.y, 0.0);
            let inv_z = (u.z.abs() > tol::RELATIVE_EPS).then(|| 1.0 / u.z);
            (inv_z, Pair::new(uxy, dxy), Pair::new(u, reach))
        });
        Self {
            rot: s.rot,
            tip: s.tip,
            reach,
            grow,
            axes,
        }
    }

    /// Whether this swept pose of a tool of `shape` (radius `r`, length `l`) meets any of
    /// the material `segs` of the ray `o + t·e_axis`. Along the tool axis the translation
    /// is taken into the growth (the end planes `|reach_z|` further out); across it, the
    /// ray's stretch within the end planes' slab comes within `r + grow` of the segment
    /// `±reach_xy` somewhere. A ball's sphere is swept in full: the ray's material within
    /// `r + grow` of the segment `(0, 0, r) ± reach`.
    #[inline(always)]
    fn meets(
        &self,
        shape: Shape,
        rl: (Real, Real),
        o: &Point3,
        axis: usize,
        segs: &[Segment],
    ) -> bool {
        let p = self.rot.tr_mul(&(o - self.tip));
        self.reach_at(shape, rl, &p, axis, segs) != Reach::Miss
    }

    /// [`Self::meets`] for the ray's origin `p` in the pose's tool frame, telling a ray
    /// whose material comes within `r − grow` of the segment `±reach_xy` ([`Reach::Deep`]:
    /// the pose's own tool meets it there, so no finer test would clear it) from one that
    /// only comes within `r + grow` ([`Reach::Near`]).
    #[inline(always)]
    fn reach_at(
        &self,
        shape: Shape,
        (r, l): (Real, Real),
        p: &Vector3,
        axis: usize,
        segs: &[Segment],
    ) -> Reach {
        let (inv_z, across, full) = &self.axes[axis];
        let g = self.grow;
        let (s0, s1) = end_slab(shape, (r, l), g + self.reach.z.abs(), p.z, *inv_z);
        let rad2 = (r + g) * (r + g);
        let deep2 = if g < r { (r - g) * (r - g) } else { -1.0 };
        let pxy = Vector3::new(p.x, p.y, 0.0);
        for m in segs {
            let (lo, hi) = (s0.max(m.lo.t), s1.min(m.hi.t));
            if lo <= hi {
                let d2 = least_distance2(&pxy, across, (lo, hi));
                if d2 <= rad2 {
                    return if d2 <= deep2 {
                        Reach::Deep
                    } else {
                        Reach::Near
                    };
                }
            }
        }
        if shape == Shape::Ball && self.sphere_meets(r, p, full, segs) {
            Reach::Near
        } else {
            Reach::Miss
        }
    }

    /// Whether the ball's swept sphere (centre `(0, 0, r) ± reach`, radius `r + grow`)
    /// meets the material `segs` along `p + t·u` (tool frame).
    fn sphere_meets(&self, r: Real, p: &Vector3, full: &Pair, segs: &[Segment]) -> bool {
        let rad2 = (r + self.grow) * (r + self.grow);
        let w = p - Vector3::new(0.0, 0.0, r);
        segs.iter()
            .any(|m| least_distance2(&w, full, (m.lo.t, m.hi.t)) <= rad2)
    }
}

/// The bound `θ ≤ h·|w_⊥| + 0.75·Ω²·h²` on the turn of the tool's axis over `λ` within
/// `half` (`h`) of the sample `s` on a move of total turn `omega` (see the module docs).
fn turn_bound(s: &Sample, half: Real, omega: Real) -> Real {
    let tilt_rate = (s.w_t.x * s.w_t.x + s.w_t.y * s.w_t.y).sqrt();
    half * tilt_rate + 0.75 * omega * omega * half * half
}

/// How a swept pose's tool meets a ray's material ([`SweptPose::reach_at`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Reach {
    Miss,
    Near,
    Deep,
}

/// The rates of a move whose axes all move at constant rates, for its swept cull: the total
/// turn `omega` (rad) and bounds on the acceleration of the tool axis's middle point
/// (`accel`) and of any point of the axis (`axis_accel`), in mm per unit λ².
#[derive(Clone, Copy, Debug)]
pub(super) struct SweptRates {
    pub(super) omega: Real,
    pub(super) accel: Real,
    pub(super) axis_accel: Real,
}

/// The swept cull of a move whose axes all move at constant rates (see the module docs):
/// per cell, [`SWEPT_PER_CELL`] swept poses, the cell about its middle sample and its
/// halves about the quarter poses, each with its height-aware test ([`AxisSweep`]).
#[derive(Clone, Debug)]
pub(super) struct SweptPoses {
    pub(super) poses: Vec<SweptPose>,
    axis: Vec<AxisSweep>,
}

impl SweptPoses {
    /// The swept poses of a move of `cells = (samples.len() − 1)/2` cells from its
    /// `samples` and `quarters`, for a tool of `shape`, radius `r` and length `l`, and the
    /// move's `rates`.
    pub(super) fn new(
        (samples, quarters): (&[Sample], &[(Real, Sample)]),
        (shape, r, l): (Shape, Real, Real),
        rates: SweptRates,
    ) -> Self {
        let cells = (samples.len() - 1) / 2;
        let h = 1.0 / cells as Real;
        let mut poses = Vec::with_capacity(SWEPT_PER_CELL * cells);
        let mut axis = Vec::with_capacity(cells);
        let about =
            |s: &Sample, half: Real| SweptPose::about(s, half, (r, l), (rates.omega, rates.accel));
        for j in 0..cells {
            let s = &samples[2 * j + 1];
            let pose = about(s, h / 2.0);
            axis.push(AxisSweep::about(s, &pose, h / 2.0, (shape, r, l), rates));
            poses.push(pose);
            for q in &quarters[2 * j..2 * j + 2] {
                poses.push(about(&q.1, h / 4.0));
            }
        }
        Self { poses, axis }
    }

    /// Whether the move may change the material `segs` of the ray `o + t·e_axis` (tool of
    /// `shape`, radius and length `rl`): false only when, in every cell, the swept cell or
    /// both its swept halves miss the material; on a ray across the tool whose material the
    /// swept cell meets but not deeply, its height-aware test ([`AxisSweep`]) decides
    /// instead of the halves.
    fn may_cut(
        &self,
        shape: Shape,
        rl: (Real, Real),
        o: &Point3,
        axis: usize,
        segs: &[Segment],
    ) -> bool {
        let meets = |s: &SweptPose| s.meets(shape, rl, o, axis, segs);
        self.poses
            .chunks_exact(SWEPT_PER_CELL)
            .zip(self.axis.iter())
            .any(|(c, tight)| {
                let p = c[0].rot.tr_mul(&(o - c[0].tip));
                match c[0].reach_at(shape, rl, &p, axis, segs) {
                    Reach::Miss => false,
                    Reach::Deep => true,
                    Reach::Near if tight.across(axis) => {
                        let (inv_z, _, full) = &c[0].axes[axis];
                        tight.meets((shape, rl.0, rl.1), (&p, full.u.z, *inv_z), axis, segs)
                    }
                    Reach::Near => meets(&c[1]) || meets(&c[2]),
                }
            })
    }
}

#[cfg(test)]
impl SweptPoses {
    /// [`Self::may_cut`] by the swept poses alone, every cell by its swept halves (the
    /// height-aware test left out): what the cull was without it.
    pub(super) fn may_cut_by_halves(
        &self,
        (shape, r, l): (Shape, Real, Real),
        o: &Point3,
        axis: usize,
        segs: &[Segment],
    ) -> bool {
        let meets = |s: &SweptPose| s.meets(shape, (r, l), o, axis, segs);
        self.poses
            .chunks_exact(SWEPT_PER_CELL)
            .any(|c| meets(&c[0]) && (meets(&c[1]) || meets(&c[2])))
    }
}

/// The height-aware test of one swept pose (see the module docs): the tool turned by `θ`
/// about its axis point at height `z_c`, whose path is `τ·D(z_c)` to first order, lies in
/// the tool about that path with radius `r + θ·|z − z_c|` (and the second-order terms) at
/// height `z`. A ray's stretch spans a band of heights about its middle `z_c`: across a
/// tool the band is far narrower than the tool, so the growth is far smaller than the
/// swept pose's `max(l/2, r)·θ`, which holds the whole tool about its middle.
#[derive(Clone, Debug)]
struct AxisSweep {
    /// The axis middle's reach across the axis, `D_xy`, and its change per unit height:
    /// the axis point at height `z` is reached by `D + (z − l/2)·tilt` (`tilt` lies across
    /// the axis, so `D_z` is the same for every height).
    reach: Vector3,
    tilt: Vector3,
    /// `|D_xy|²`, `D_xy·tilt` and `|tilt|²`: `|D(z)_xy|²` as a quadratic in height.
    dd: Real,
    dt: Real,
    tt: Real,
    /// The growth for a stretch spanning heights `z_c ± b`: `grow.0 + grow.1·b` (mm), the
    /// rounding's allowances included.
    grow: (Real, Real),
    /// The end planes' growth, the reach along the axis included (mm).
    slab: Real,
    /// Per axis ray: whether it crosses the tool (`|u_z| <` [`ACROSS_COS`]), where this
    /// test is used instead of the swept halves, and what the test needs of its direction.
    rays: [Option<AcrossRay>; 3],
    /// For a ball end mill, per axis ray: its pair with the sphere centre's reach `D(r)`
    /// (the sphere turns into itself: only its centre's path matters), and the sphere's
    /// growth.
    sphere: Option<Box<([Pair; 3], Real)>>,
}

/// An axis ray's direction `u` in a swept pose's tool frame, for the height-aware test:
/// its part across the axis, `|u_xy|²` and its reciprocal, the half-length of its longest
/// stretch within the clip radius of the axis (`(r + g + |D_xy|)/|u_xy|`, from the swept
/// pose's own bound), and `u_xy·D_xy`, `u_xy·tilt`.
#[derive(Clone, Copy, Debug)]
struct AcrossRay {
    u: Vector3,
    uu: Real,
    inv_uu: Real,
    half: Real,
    ud: Real,
    ut: Real,
}

impl AxisSweep {
    /// The height-aware test of the swept pose `pose` about the sample `s` over `λ` within
    /// `half` of it, for a tool of `shape`, radius `r` and length `l`, on a move of `rates`.
    fn about(
        s: &Sample,
        pose: &SweptPose,
        half: Real,
        (shape, r, l): (Shape, Real, Real),
        rates: SweptRates,
    ) -> Self {
        let theta = turn_bound(s, half, rates.omega);
        let drift = rates.axis_accel * half * half / 2.0;
        let tilt = Vector3::new(s.w_t.y, -s.w_t.x, 0.0) * half;
        let reach = Vector3::new(pose.reach.x, pose.reach.y, 0.0);
        let reach_z = pose.reach.z.abs();
        // The rounding of any axis point's reach and of the quantities built on it.
        let round = HULL_ROUNDING * (pose.reach.norm() + tilt.norm() * l.max(r) + r);
        // Across the axis: g = (r + θ·(b + |D_z| + e))/(1 − θ²) − r + e, e the drift.
        let inv = 1.0 / (1.0 - theta * theta);
        let grow0 = (r + theta * (reach_z + drift)) * inv - r + drift;
        let grow = (
            (grow0 + round) * (1.0 + HULL_ROUNDING) + CULL_MARGIN,
            theta * inv * (1.0 + HULL_ROUNDING),
        );
        // A point at radius r turns along the axis by r·θ, one at height z from the turn's
        // centre by z·θ²/2; the centre drifts by `drift` and moves by |D_z| along it.
        let slab = r * theta + l * theta * theta / 2.0 + drift + reach_z;
        let slab = (slab + round) * (1.0 + HULL_ROUNDING) + CULL_MARGIN;
        let clip = r + pose.grow + reach.norm() + CULL_MARGIN;
        let dirs = axis_dirs(s);
        let rays = dirs.map(|u| {
            let uxy = Vector3::new(u.x, u.y, 0.0);
            let uu = uxy.norm_squared();
            (u.z.abs() < ACROSS_COS).then(|| AcrossRay {
                u: uxy,
                uu,
                inv_uu: 1.0 / uu,
                half: clip / uu.sqrt(),
                ud: uxy.dot(&reach),
                ut: uxy.dot(&tilt),
            })
        });
        let sphere = (shape == Shape::Ball).then(|| {
            let d = pose.reach + tilt * (r - l / 2.0);
            let g = (drift + round) * (1.0 + HULL_ROUNDING) + CULL_MARGIN;
            Box::new((dirs.map(|u| Pair::new(u, d)), g))
        });
        Self {
            reach,
            tilt,
            dd: reach.norm_squared(),
            dt: reach.dot(&tilt),
            tt: tilt.norm_squared(),
            grow,
            slab,
            rays,
            sphere,
        }
    }

    /// Whether this test is used for the axis ray `axis` (it crosses the tool).
    fn across(&self, axis: usize) -> bool {
        self.rays[axis].is_some()
    }

    /// Whether the swept pose of a tool of `shape` (radius `r`, length `l`), seen by this
    /// test, meets any of the material `segs` of the axis ray `axis` (one that crosses the
    /// tool) whose origin is `p` and direction `u_z` along the axis in the pose's tool
    /// frame. Per segment, the stretch within the end planes and within the clip radius of
    /// the axis spans heights `z_c ± b` (`z_c` kept on the axis between 0 and `l`); the
    /// axis point at `z_c` moves along `τ·D(z_c)` and the tool about it lies within `r + g`
    /// of that segment, `g = (r + θ·(b + |D_z| + e))/(1 − θ²) − r + e` (`e` the drift). A
    /// ball's sphere turns into itself: its centre's path alone, grown by the drift.
    #[inline(always)]
    fn meets(
        &self,
        (shape, r, l): (Shape, Real, Real),
        (p, u_z, inv_z): (&Vector3, Real, Option<Real>),
        axis: usize,
        segs: &[Segment],
    ) -> bool {
        let Some(ray) = &self.rays[axis] else {
            return true;
        };
        let (s0, s1) = end_slab(shape, (r, l), self.slab, p.z, inv_z);
        // The stretch within the clip radius of the axis lies within the longest chord's
        // half-length of the point nearest the axis (widened for the rounding).
        let near = -(p.x * ray.u.x + p.y * ray.u.y) * ray.inv_uu;
        let pad = CLIP_PAD * (1.0 + near.abs() + ray.half);
        let (lo_c, hi_c) = (s0.max(near - ray.half - pad), s1.min(near + ray.half + pad));
        let pxy = Vector3::new(p.x, p.y, 0.0);
        segs.iter().any(|m| {
            let (lo, hi) = (lo_c.max(m.lo.t), hi_c.min(m.hi.t));
            if lo > hi {
                return false;
            }
            let (z0, z1) = (p.z + lo * u_z, p.z + hi * u_z);
            let zc = (0.5 * (z0 + z1)).clamp(0.0, l);
            let band = (z0 - zc).abs().max((z1 - zc).abs());
            if !band.is_finite() {
                return true;
            }
            let k = zc - l / 2.0;
            let g = self.grow.0 + self.grow.1 * band;
            let across = Pair::across(
                (ray.u, ray.uu, ray.inv_uu),
                self.reach + self.tilt * k,
                ray.ud + k * ray.ut,
                self.dd + k * (2.0 * self.dt + k * self.tt),
            );
            least_distance2(&pxy, &across, (lo, hi)) <= (r + g) * (r + g)
        }) || (shape == Shape::Ball && self.sphere_meets(r, p, axis, segs))
    }

    /// Whether the ball's sphere, its centre swept along `τ·D(r)` and grown by the drift,
    /// meets the material `segs` along the axis ray `axis` from `p` (tool frame).
    fn sphere_meets(&self, r: Real, p: &Vector3, axis: usize, segs: &[Segment]) -> bool {
        let Some(sphere) = &self.sphere else {
            return true;
        };
        let (pairs, g) = &**sphere;
        let rad2 = (r + g) * (r + g);
        let w = p - Vector3::new(0.0, 0.0, r);
        segs.iter()
            .any(|m| least_distance2(&w, &pairs[axis], (m.lo.t, m.hi.t)) <= rad2)
    }
}

/// Below this `|u_z|` (the cosine between an axis ray and the tool axis) a ray crosses the
/// tool and the height-aware test is used instead of the swept halves.
const ACROSS_COS: Real = 0.5;

/// The height-aware test widens a stretch's ends by this much per mm of their distance from
/// the ray's origin and of the chord's half-length (and this much, mm), for the rounding of
/// the nearest point and the half-length.
const CLIP_PAD: Real = 1e-9;

impl RotaryEnvelope {
    /// Whether the move may change the material `segs` of the ray `o + t·e_axis`:
    /// false only when no grown kept pose meets any segment (see the module docs). Each
    /// cell is first tested whole, by its middle pose grown by `δ` (which holds the tool
    /// throughout the cell); its kept poses only when that meets the material, the cell's
    /// ends first (where a move that cuts the ray usually meets its material), then the
    /// inner ones of each half-cell whose middle pose, grown to hold the half, meets it.
    /// Where every axis moves at a constant rate the swept cull decides instead (see the
    /// module docs).
    pub fn may_cut(&self, o: &Point3, axis: usize, segs: &[Segment]) -> bool {
        if let Some(swept) = &self.swept {
            return swept.may_cut(self.shape, (self.r, self.l), o, axis, segs);
        }
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
    /// The reference pose, halfway through the group (the start of its middle move for an
    /// even count of moves, the middle move's middle sample for an odd one: the cells'
    /// tilts from it, which grow the hull most, are then the least), and its
    /// [`axis_dirs`].
    reference: Sample,
    dirs: [Vector3; 3],
    /// The growth that holds every move's tool (mm).
    grow: Real,
    /// Where every move has the swept cull: the reference tool swept along the group's
    /// path and grown to hold every cell's swept tool (used instead of `grow`).
    pub(super) swept: Option<SweptPose>,
}

impl GroupHull {
    /// The hull of the moves `group` (one tool; not empty).
    pub fn of(group: &[&RotaryEnvelope]) -> Self {
        let mid = group[group.len() / 2];
        let reference = if group.len().is_multiple_of(2) {
            mid.samples[0]
        } else {
            mid.samples[mid.samples.len() / 2]
        };
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
            swept: Self::swept(group, &reference, (r, l)),
        }
    }

    /// The swept hull of `group` about the pose `reference` (tool radius and length `r`,
    /// `l`), where every move has swept poses (see the module docs): each cell's swept tool
    /// is the reference tool translated by the cell's axis middle `Δc_j + τ·D_j` and grown
    /// by its own growth `g_j` and by its tilt from the reference `θ_j` (turning the grown
    /// tool about its middle adds `(max(l/2, r) + g_j)·θ_j`). Those translations lie within
    /// `e_j` of the segment from the first cell's start to the last cell's end (the
    /// distance of a segment's points from another is greatest at its ends), so the
    /// reference tool swept along that segment and grown by the largest
    /// `g_j + (max(l/2, r) + g_j)·θ_j + e_j` holds every cell.
    fn swept(
        group: &[&RotaryEnvelope],
        reference: &Sample,
        (r, l): (Real, Real),
    ) -> Option<SweptPose> {
        let mut cells = Vec::new();
        let rot = reference.rot;
        let axis_mid = Vector3::new(0.0, 0.0, l / 2.0);
        let centre = rot * axis_mid + reference.tip.coords;
        let axis = rot.column(2).into_owned();
        for env in group {
            for cell in env.swept.as_ref()?.poses.chunks_exact(SWEPT_PER_CELL) {
                let s = &cell[0];
                let moved = rot.tr_mul(&(s.rot * axis_mid + s.tip.coords - centre));
                let reach = rot.tr_mul(&(s.rot * s.reach));
                let chord = (s.rot.column(2) - axis).norm();
                let tilt = 2.0 * (0.5 * chord).min(1.0).asin();
                cells.push((moved, reach, s.grow, tilt));
            }
        }
        let (first, last) = (cells.first()?, cells.last()?);
        let (start, end) = (first.0 - first.1, last.0 + last.1);
        let (offset, reach) = ((start + end) / 2.0, (end - start) / 2.0);
        let rr = reach.norm_squared();
        let off_path = |x: Vector3| {
            let w = x - offset;
            let tau = if rr > 0.0 {
                (w.dot(&reach) / rr).clamp(-1.0, 1.0)
            } else {
                0.0
            };
            (w - reach * tau).norm()
        };
        let arm = (l / 2.0).max(r);
        let grow = cells
            .iter()
            .map(|&(moved, d, g, tilt)| {
                g + (arm + g) * tilt + off_path(moved - d).max(off_path(moved + d))
            })
            .fold(0.0, Real::max);
        let grow = (grow + HULL_ROUNDING * (reach.norm() + offset.norm())) * (1.0 + HULL_ROUNDING)
            + CULL_MARGIN;
        // The reference tool moved by the offset: its tip there.
        let at = Sample {
            tip: reference.tip + rot * offset,
            ..*reference
        };
        Some(SweptPose::new(&at, reach, grow))
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
        if let Some(s) = &self.swept {
            return s.meets(self.shape, (self.r, self.l), o, axis, segs);
        }
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
