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
//! **Cells.** No tool point moves faster than `M = ω·ρ + v` per unit `λ` (`ω` the total
//! rotation in rad, `ρ` a bound on the distance of any tool point from the rotary axes during
//! the move, `v` the linear travel; with several rotary axes `ρ` is widened like the sub-step
//! bound of [`crate::cutting::sweep`]). The move is split into `N` cells of width `h` with
//! `δ = M·h/2 ≤ R/8`: the tool anywhere in a cell lies inside the tool at the cell's middle
//! grown by `δ`. A ray that misses the grown tool misses the cell. The ray is evaluated
//! exactly at the ends and middle of every cell it may meet; in each half-cell (the tool
//! moves by at most `R/8`) a sign change of a rate or of `φ` is solved for by the Illinois
//! variant of regula falsi, and the pose found is offered. A half-cell whose ends both miss
//! may hide a touch: the tool lies in capsules of radius `R` about four pieces of its axis,
//! each with its own speed bound `M_k`, and a touch deeper than [`ENVELOPE_TOL`] needs some
//! piece to travel from both ends to the ray (`d_k(a) + d_k(b) + 2·tol ≤ M_k·w`, `d_k` the
//! ray's distance from the capsule); while one can, the half-cell is bisected, the middle
//! checked against the tool grown by `M·w/2 − tol`. A half-cell with one end inside and a
//! rate that points to an extreme before the ray leaves is bisected until the extreme is
//! bracketed.
//!
//! **Span.** The stock asks only about the material's extent along a ray
//! ([`Cutter::ray_cuts_in_span`]): cells whose grown tool meets the ray only outside it are
//! skipped, and an interval end already beyond it is not refined (it stays beyond it).
//!
//! **Accuracy.** Every interval end is the exact interval of some pose, so nothing is cut
//! that the tool does not reach. A smooth extreme is solved until
//! `min(|dt/dλ|) · w ≤` [`SOLVE_TOL`] over the final bracket `w`, which bounds the distance to
//! the true extreme on a convex stretch; an edge crossing until `w` times the larger rate at
//! the bracket ends is below it. A touch between two missing poses is ignored only when it
//! reaches less than [`ENVELOPE_TOL`] into the ray (measured normal to the tool's surface).
//! The documented bound is [`ENVELOPE_TOL`] = 0.1 µm.
//!
//! **Known limit.** Within one half-cell each rate and each `φ` is taken to change sign at
//! most once, and a ray inside the tool at both ends of a half-cell to be inside in between.
//! A ray that leaves the tool and meets it again while the tool moves by less than `R/8`, or
//! crosses an edge circle twice in that motion, can only be grazing it.
//!
//! Normals at the interval ends are the tool's outward normal of the face that bounds the
//! interval (side, end plane, or sphere) at that point and pose.
//!
//! **Invariant:** the envelope knows only the tool's shape, the chain's poses and one move;
//! it never reads programs, stock or files.

use crate::cutting::stock::{Cutter, RayCut};
use crate::cutting::tool::{Tool, ToolKind};
use crate::machine::chain::{AxisKind, Chain};
use crate::machine::error_motion::{self, AxisErrorMotions, Directions};
use crate::math::{Aabb, Isometry3, Matrix3, Point3, Real, Vector3, tol};
use crate::nc::AxisValues;
use std::cell::Cell;

/// Bound (mm) on the distance of the envelope's interval ends from the true swept surface
/// along a ray: 0.1 µm, the µm-metrology budget with a factor ten to spare; the solver
/// reaches [`SOLVE_TOL`] (see the module docs).
pub const ENVELOPE_TOL: Real = 1e-7;

/// Distance (mm) to which the solver brings an interval end to the true extreme: a tenth
/// of [`ENVELOPE_TOL`].
pub const SOLVE_TOL: Real = 1e-8;

/// Largest grown distance `δ` as a fraction of the tool radius: cells move the tool by at
/// most twice that, a quarter of its radius, half-cells by an eighth.
const CELL_GROWTH: Real = 0.125;

/// Pieces of the tool's axis for the separation test between poses that miss the ray.
const PARTS: usize = 4;

/// Most cells for one move; beyond this the move is refused (the caller falls back).
const MAX_CELLS: usize = 1 << 16;

/// Regula falsi steps before a solve gives up (each step at least halves the bracket every
/// third step, so 200 steps reach far below any `λ` resolution).
const MAX_SOLVE_STEPS: usize = 200;

/// Recursion depth of the half-cell refinement; each level halves the width, so 60 levels
/// reach below `f64` resolution of `λ`.
const MAX_DEPTH: u32 = 60;

/// The pose of the tool along one move and its rate of change, evaluated without rebuilding
/// the chain: fixed transforms and linear axes between rotary axes are folded into one
/// factor whose translation is linear in `λ`.
#[derive(Clone, Debug)]
pub struct MovePath {
    factors: Vec<Factor>,
}

#[derive(Clone, Debug)]
enum Factor {
    /// `x ↦ rot·x + t0 + λ·t1`.
    Affine {
        rot: Matrix3,
        t0: Vector3,
        t1: Vector3,
    },
    /// Rotation by `th0 + λ·dth` (rad) about the unit `dir` through `origin`; `cross` and
    /// `outer` are `[dir]×` and `dir·dirᵀ` for Rodrigues' formula.
    Rotary {
        dir: Vector3,
        origin: Vector3,
        th0: Real,
        dth: Real,
        cross: Matrix3,
        outer: Matrix3,
    },
    /// The error motions of an axis that moves from `q0` by `dq`, turning about `centre`,
    /// with its reversal share moving from `off0` toward `target` at the commanded rate.
    Error {
        motions: Box<AxisErrorMotions>,
        centre: Point3,
        q0: Real,
        dq: Real,
        off0: Real,
        target: Real,
    },
}

/// A pose and its rate of change per unit `λ`.
#[derive(Clone, Copy, Debug)]
struct Sample {
    /// `w_from_t` rotation (columns: the tool axes in W).
    rot: Matrix3,
    /// The tool tip in W.
    tip: Point3,
    /// Angular velocity, in tool coordinates.
    w_t: Vector3,
    /// Velocity of the tool point at the tip, in tool coordinates: the point `q` (tool
    /// coordinates) moves at `w_t × q + v_t`.
    v_t: Vector3,
}

impl MovePath {
    /// The path of the move from `start` to `end` on `chain`, every axis that moves settled
    /// in the direction of its motion (no lost motion taken up during the move).
    pub fn new(chain: &Chain, start: &AxisValues, end: &AxisValues) -> Self {
        let state = chain.reversal_state(&Directions::default().after_move(start, end));
        Self::with_state(chain, start, end, &state)
    }

    /// The path of the move from `start` to `end` on `chain` starting from the reversal
    /// shares `state` ([`Chain::reversal_state`]): an axis that reverses takes up its lost
    /// motion over the first `|B|` of its travel.
    pub fn with_state(
        chain: &Chain,
        start: &AxisValues,
        end: &AxisValues,
        state: &[Real; 6],
    ) -> Self {
        let mut factors = Vec::new();
        let (mut rot, mut t0, mut t1) = (Matrix3::identity(), Vector3::zeros(), Vector3::zeros());
        for (i, (axis, dev)) in chain.axes().iter().zip(chain.deviations()).enumerate() {
            let (q0, q1) = (start.get(axis.letter), end.get(axis.letter));
            match axis.kind {
                AxisKind::Linear => {
                    t0 += rot * (axis.direction.into_inner() * q0);
                    t1 += rot * (axis.direction.into_inner() * (q1 - q0));
                }
                AxisKind::Rotary if q0 == q1 => {
                    let m = axis.motion(q0);
                    t0 += rot * m.translation.vector;
                    rot *= m.rotation.to_rotation_matrix().into_inner();
                }
                AxisKind::Rotary => {
                    if !(rot == Matrix3::identity() && t0 == Vector3::zeros() && t1 == t0) {
                        factors.push(Factor::Affine { rot, t0, t1 });
                    }
                    let dir = axis.direction.into_inner();
                    factors.push(Factor::Rotary {
                        dir,
                        origin: axis.origin.coords,
                        th0: q0.to_radians(),
                        dth: (q1 - q0).to_radians(),
                        cross: dir.cross_matrix(),
                        outer: dir * dir.transpose(),
                    });
                    (rot, t0, t1) = (Matrix3::identity(), Vector3::zeros(), Vector3::zeros());
                }
            }
            if let Some(e) = &chain.error_motions_all()[i] {
                let (q0, q1) = (start.get(axis.letter), end.get(axis.letter));
                let off0 = state[axis.letter.index()];
                let centre = chain.error_centre(i);
                if q0 == q1 {
                    let g = error_motion::transform(&e.values_with_offset(q0, off0), &centre);
                    t0 += rot * g.translation.vector;
                    rot *= g.rotation.to_rotation_matrix().into_inner();
                } else {
                    if !(rot == Matrix3::identity() && t0 == Vector3::zeros() && t1 == t0) {
                        factors.push(Factor::Affine { rot, t0, t1 });
                    }
                    factors.push(Factor::Error {
                        motions: Box::new(e.clone()),
                        centre,
                        q0,
                        dq: q1 - q0,
                        off0,
                        target: e.reversal * (q1 - q0).signum() / 2.0,
                    });
                    (rot, t0, t1) = (Matrix3::identity(), Vector3::zeros(), Vector3::zeros());
                }
            }
            let d = dev.transform();
            t0 += rot * d.translation.vector;
            rot *= d.rotation.to_rotation_matrix().into_inner();
        }
        factors.push(Factor::Affine { rot, t0, t1 });
        Self { factors }
    }

    /// The tool's pose in the workpiece frame at fraction `lambda` of the move.
    pub fn w_from_t(&self, lambda: Real) -> Isometry3 {
        let s = self.sample(lambda);
        let rot = nalgebra::Rotation3::from_matrix_unchecked(s.rot);
        Isometry3::from_parts(
            s.tip.coords.into(),
            nalgebra::UnitQuaternion::from_rotation_matrix(&rot),
        )
    }

    /// The pose at `lambda` and its spatial rate (angular velocity `w` and the velocity `v`
    /// of the W point at the origin, so a point `x` of the tool moves at `w × x + v`).
    fn sample(&self, lambda: Real) -> Sample {
        let (mut r, mut t) = (Matrix3::identity(), Vector3::zeros());
        let (mut w, mut v) = (Vector3::zeros(), Vector3::zeros());
        for f in &self.factors {
            match f {
                Factor::Affine { rot, t0, t1 } => {
                    v += r * t1;
                    t += r * (t0 + t1 * lambda);
                    r *= rot;
                }
                Factor::Rotary {
                    dir,
                    origin,
                    th0,
                    dth,
                    cross,
                    outer,
                } => {
                    let omega = (r * dir) * *dth;
                    let centre = r * origin + t;
                    w += omega;
                    v -= omega.cross(&centre);
                    let (sin, cos) = (th0 + dth * lambda).sin_cos();
                    let mut rt = cross * sin + outer * (1.0 - cos);
                    for k in 0..3 {
                        rt[(k, k)] += cos;
                    }
                    t += r * (origin - rt * origin);
                    r *= rt;
                }
                Factor::Error {
                    motions,
                    centre,
                    q0,
                    dq,
                    off0,
                    target,
                } => {
                    let q = q0 + dq * lambda;
                    let (mut vals, mut slopes) = motions.values_and_slopes(q);
                    for s in &mut slopes {
                        *s *= dq;
                    }
                    if let Some(p) = motions.positioning {
                        let (gap, done) = (target - off0, (dq * lambda).abs());
                        if done < gap.abs() {
                            vals[p as usize] += off0 + gap.signum() * done;
                            slopes[p as usize] += gap.signum() * dq.abs();
                        } else {
                            vals[p as usize] += target;
                        }
                    }
                    let g = error_motion::transform(&vals, centre);
                    let (wl, ul) = error_motion::twist(&vals, &slopes, centre);
                    let ww = r * wl;
                    w += ww;
                    v += r * ul - ww.cross(&t);
                    t += r * g.translation.vector;
                    r *= g.rotation.to_rotation_matrix().into_inner();
                }
            }
        }
        Sample {
            rot: r,
            tip: Point3::from(t),
            w_t: r.tr_mul(&w),
            v_t: r.tr_mul(&(w.cross(&t) + v)),
        }
    }
}

/// Distance from the line `p + t·u` (`u` unit) to the segment of the z axis from `z0` to `z1`.
fn line_segment_distance(p: &Vector3, u: &Vector3, z0: Real, z1: Real) -> Real {
    // For the axis point (0, 0, z) the squared distance to the line is |w|² − (w·u)² with
    // w = (0, 0, z) − p: a convex quadratic in z, least at z* (clamped to the segment).
    let a = -p.dot(u);
    let k = 1.0 - u.z * u.z;
    let z = if k > tol::RELATIVE_EPS {
        ((p.z + u.z * a) / k).clamp(z0, z1)
    } else {
        z0
    };
    let wu = a + z * u.z;
    let d2 = p.x * p.x + p.y * p.y + (z - p.z) * (z - p.z) - wu * wu;
    d2.max(0.0).sqrt()
}

/// The convex tools the envelope solves in closed form.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Shape {
    Flat,
    /// A ball end mill reaching at least one diameter above its tip.
    Ball,
}

/// Which face bounds an interval end (tool frame).
#[derive(Clone, Copy, Debug, PartialEq)]
enum Face {
    Side,
    Bottom,
    Top,
    Sphere,
    /// The ray runs inside the infinite cylinder: no face (only for grown tools).
    None,
}

impl Face {
    /// Faces that meet smoothly (the sphere and the side of a ball end mill are tangent)
    /// share a family: the rate of an interval end is continuous within one family.
    fn family(self) -> u8 {
        match self {
            Face::Side | Face::Sphere => 0,
            Face::Bottom => 1,
            Face::Top => 2,
            Face::None => 3,
        }
    }
}

/// The exact tool interval along a ray at one pose (the rate of each end: [`Probe::g_in`],
/// [`Probe::g_out`]).
#[derive(Clone, Copy, Debug)]
struct Hit {
    t_in: Real,
    face_in: Face,
    t_out: Real,
    face_out: Face,
}

/// A ray evaluated at one pose: its interval (if any) and, per edge circle (bottom, top),
/// `φ` = the radius where the ray crosses the edge's plane minus `R` (`+∞` for no edge or a
/// ray parallel to the plane).
#[derive(Clone, Debug)]
struct Probe {
    lambda: Real,
    hit: Option<Hit>,
    phi: [Real; 2],
    /// The ray's origin and direction in the tool frame.
    p: Vector3,
    u: Vector3,
    /// The pose's rotation (`w_from_t`).
    rot: Matrix3,
    /// The pose's angular velocity and tip velocity (tool frame), for the rates.
    w_t: Vector3,
    v_t: Vector3,
    /// `dt_in/dλ` and `dt_out/dλ` of the hit, each worked out when first read (bit `k` of
    /// `known`): many are never read, the ray's end being outside the material there.
    rates: Cell<[Real; 2]>,
    known: Cell<u8>,
}

impl Probe {
    /// `dt_in/dλ` of the hit (the tool radius `r`).
    #[inline(always)]
    fn g_in(&self, r: Real) -> Real {
        self.rate(0, r)
    }

    /// `dt_out/dλ` of the hit.
    #[inline(always)]
    fn g_out(&self, r: Real) -> Real {
        self.rate(1, r)
    }

    /// The rate of the hit's end `end` (0 in, 1 out): the end's normal speed over the
    /// normal's component along the ray; NaN without a normal or a hit.
    #[inline(always)]
    fn rate(&self, end: usize, r: Real) -> Real {
        if self.known.get() & (1 << end) == 0 {
            let g = match self.hit {
                Some(h) => {
                    let (t, face) = if end == 0 {
                        (h.t_in, h.face_in)
                    } else {
                        (h.t_out, h.face_out)
                    };
                    let q = self.p + self.u * t;
                    match tool_normal(&q, face, r) {
                        Some(n) => n.dot(&(self.w_t.cross(&q) + self.v_t)) / n.dot(&self.u),
                        None => Real::NAN,
                    }
                }
                None => Real::NAN,
            };
            let mut rates = self.rates.get();
            rates[end] = g;
            self.rates.set(rates);
            self.known.set(self.known.get() | 1 << end);
        }
        self.rates.get()[end]
    }
}

/// A ray `o + t·e` with `e` a unit vector, and the span of `t` where the answer matters.
struct Ray<'a> {
    o: &'a Point3,
    e: &'a Vector3,
    span: (Real, Real),
}

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
    /// Poses at λ = k/(2N), k = 0..=2N: cell ends at even k, middles at odd k.
    samples: Vec<Sample>,
    /// Poses halfway between consecutive samples, with their λ: where every ray's first
    /// bisection and touch test look (computed once per move instead of once per ray; the
    /// same pose bit for bit, see [`RotaryEnvelope::sample_at`]).
    quarters: Vec<(Real, Sample)>,
    /// Box of each cell's grown tool.
    cell_boxes: Vec<Aabb>,
    bounds: Aabb,
}

impl RotaryEnvelope {
    /// The envelope of `tool` on the move `start → end` of `chain` (moving axes settled in
    /// their direction of motion, see [`MovePath::new`]).
    pub fn new(
        chain: &Chain,
        tool: &Tool,
        start: &AxisValues,
        end: &AxisValues,
    ) -> Result<Self, EnvelopeError> {
        let state = chain.reversal_state(&Directions::default().after_move(start, end));
        Self::with_state(chain, tool, start, end, &state)
    }

    /// The envelope of `tool` on the move `start → end` of `chain` from the reversal
    /// shares `state` (see [`MovePath::with_state`]).
    pub fn with_state(
        chain: &Chain,
        tool: &Tool,
        start: &AxisValues,
        end: &AxisValues,
        state: &[Real; 6],
    ) -> Result<Self, EnvelopeError> {
        let shape = match tool.kind() {
            ToolKind::Flat => Shape::Flat,
            ToolKind::Ball if tool.length() >= 2.0 * tool.radius() => Shape::Ball,
            _ => return Err(EnvelopeError::UnsupportedTool),
        };
        let (r, l) = (tool.radius(), tool.length());
        let path = MovePath::with_state(chain, start, end, state);
        let speed = speed_bound(chain, l / 2.0, tool.reach_from(l / 2.0), start, end, state);
        // The capsule of radius R about the axis segment [z0, l] holds the tool; its pieces
        // and their own speed bounds.
        let z0 = match shape {
            Shape::Flat => 0.0,
            Shape::Ball => r,
        };
        let part_z: [Real; PARTS + 1] =
            std::array::from_fn(|k| z0 + (l - z0) * k as Real / PARTS as Real);
        let part_speed: [Real; PARTS] = std::array::from_fn(|k| {
            let half = (part_z[k + 1] - part_z[k]) / 2.0;
            speed_bound(chain, part_z[k] + half, half + r, start, end, state)
        });
        let want = speed / (2.0 * CELL_GROWTH * r);
        if !(want.is_finite() && want <= MAX_CELLS as Real) {
            return Err(EnvelopeError::TooManyCells(want));
        }
        let cells = (want.ceil() as usize).max(1);
        let h = 1.0 / cells as Real;
        let delta = speed * h / 2.0 + tol::FEASIBILITY;
        let samples: Vec<Sample> = (0..=2 * cells)
            .map(|k| path.sample(k as Real / (2 * cells) as Real))
            .collect();
        // Every λ lies within h/4 of a sample, where the tool has moved by at most M·h/4.
        let margin = speed * h / 4.0 + tol::FEASIBILITY;
        let mut bounds = Aabb::empty();
        for s in &samples {
            let b = frame_box(s, shape, r, l, margin);
            bounds.grow(&b.min);
            bounds.grow(&b.max);
        }
        let cell_boxes = (0..cells)
            .map(|j| frame_box(&samples[2 * j + 1], shape, r, l, delta))
            .collect();
        let lambda_of = |k: usize| k as Real / (2 * cells) as Real;
        let quarters = (0..2 * cells)
            .map(|k| {
                let mid = 0.5 * (lambda_of(k) + lambda_of(k + 1));
                (mid, path.sample(mid))
            })
            .collect();
        Ok(Self {
            shape,
            r,
            l,
            path,
            cells,
            delta,
            speed,
            part_z,
            part_speed,
            samples,
            quarters,
            cell_boxes,
            bounds,
        })
    }

    /// Number of cells the move is split into.
    pub fn cells(&self) -> usize {
        self.cells
    }

    /// The bound on any tool point's speed per unit of the move parameter (mm).
    pub fn speed_bound(&self) -> Real {
        self.speed
    }

    fn lambda_of(&self, k: usize) -> Real {
        k as Real / (2 * self.cells) as Real
    }

    /// Whether the ray meets the tool at a pose grown by `grow` (mm) within the ray's span.
    #[inline(always)]
    fn meets_grown(&self, s: &Sample, ray: &Ray, grow: Real) -> bool {
        let p = s.rot.tr_mul(&(ray.o - s.tip));
        let u = s.rot.tr_mul(ray.e);
        let meets = |(t0, _, t1, _): (Real, Face, Real, Face)| t1 >= ray.span.0 && t0 <= ray.span.1;
        // A ball's interval holds its sphere's: when that meets the span so does the tool's
        // (the shank's cylinder, with its divisions, is then not needed for the answer)
        if self.shape == Shape::Ball && ball_sphere(self.r, &p, &u, grow).is_some_and(meets) {
            return true;
        }
        tool_interval(self.shape, self.r, self.l, &p, &u, grow).is_some_and(meets)
    }

    /// The ray evaluated exactly at a pose.
    #[inline(always)]
    fn probe(&self, s: &Sample, lambda: Real, ray: &Ray) -> Probe {
        let p = s.rot.tr_mul(&(ray.o - s.tip));
        let u = s.rot.tr_mul(ray.e);
        let hit =
            tool_interval(self.shape, self.r, self.l, &p, &u, 0.0).map(|(t0, f0, t1, f1)| Hit {
                t_in: t0,
                face_in: f0,
                t_out: t1,
                face_out: f1,
            });
        let phi = |h: Real| {
            if u.z.abs() <= tol::RELATIVE_EPS {
                return Real::INFINITY;
            }
            let q = p + u * ((h - p.z) / u.z);
            (q.x * q.x + q.y * q.y).sqrt() - self.r
        };
        let bottom = match self.shape {
            Shape::Flat => phi(0.0),
            Shape::Ball => Real::INFINITY,
        };
        Probe {
            lambda,
            hit,
            phi: [bottom, phi(self.l)],
            p,
            u,
            rot: s.rot,
            w_t: s.w_t,
            v_t: s.v_t,
            rates: Cell::new([Real::NAN; 2]),
            known: Cell::new(0),
        }
    }

    #[inline(always)]
    fn probe_at(&self, lambda: Real, ray: &Ray) -> Probe {
        self.probe(&self.sample_at(lambda), lambda, ray)
    }

    /// The pose at `lambda`: the stored one when `lambda` is exactly a quarter point (the
    /// midpoint of two consecutive samples as [`Self::refine`] computes it), else computed.
    #[inline(always)]
    fn sample_at(&self, lambda: Real) -> Sample {
        let k = ((lambda * (4 * self.cells) as Real - 1.0) / 2.0).round();
        if k >= 0.0
            && let Some((at, s)) = self.quarters.get(k as usize)
            && *at == lambda
        {
            return *s;
        }
        self.path.sample(lambda)
    }

    /// The sorted, disjoint intervals of the ray `o + t·e` (`e` unit) inside the swept volume,
    /// with material normals, appended to `out`.
    pub fn intervals(&self, o: &Point3, e: &Vector3, out: &mut Vec<RayCut>) {
        self.intervals_in(o, e, (Real::NEG_INFINITY, Real::INFINITY), out);
    }

    /// Like [`RotaryEnvelope::intervals`] where only `span` along the ray matters (the
    /// material's extent): interval ends outside it are left unrefined (they stay outside
    /// it) and parts of the move whose grown tool meets the ray only outside it are skipped.
    pub fn intervals_in(&self, o: &Point3, e: &Vector3, span: (Real, Real), out: &mut Vec<RayCut>) {
        // a dexel ray's box tests need no divisions (the same results)
        let axis = Aabb::unit_axis(e);
        let box_meets = |b: &Aabb| match axis {
            Some(a) => b.axis_ray_interval(o, a),
            None => b.ray_interval(o, e),
        };
        if box_meets(&self.bounds).is_none() {
            return;
        }
        let ray = Ray { o, e, span };
        let n = self.cells;
        SCRATCH.with_borrow_mut(|scratch| {
            let Scratch {
                grown,
                slot,
                probes,
                comp_of,
                comps,
                cuts,
            } = scratch;
            grown.clear();
            grown.extend((0..n).map(|j| {
                box_meets(&self.cell_boxes[j]).is_some_and(|(t0, t1)| t1 >= span.0 && t0 <= span.1)
                    && self.meets_grown(&self.samples[2 * j + 1], &ray, self.delta)
            }));
            if !grown.iter().any(|&g| g) {
                return;
            }
            // The probes at the samples of the cells that may meet the ray, each once:
            // `slot[k]` indexes sample k's probe in `probes` (NO_PROBE: not evaluated).
            slot.clear();
            slot.resize(2 * n + 1, NO_PROBE);
            probes.clear();
            for j in (0..n).filter(|&j| grown[j]) {
                for (k, at) in slot.iter_mut().enumerate().skip(2 * j).take(3) {
                    if *at == NO_PROBE {
                        *at = probes.len() as u32;
                        probes.push(self.probe(&self.samples[k], self.lambda_of(k), &ray));
                    }
                }
            }
            let at = |k: usize| probes.get(slot[k] as usize);
            // Connected sets of poses: runs of samples inside the tool joined by half-cells
            // of cells that may meet the ray; each starts from its samples' extremes.
            comp_of.clear();
            comp_of.resize(2 * n + 1, None);
            comps.clear();
            for k in 0..=2 * n {
                let Some(p) = at(k).filter(|p| p.hit.is_some()) else {
                    continue;
                };
                let id = match (k > 0 && grown[(k - 1) / 2])
                    .then(|| comp_of[k - 1])
                    .flatten()
                {
                    Some(id) => id,
                    None => {
                        comps.push(None);
                        comps.len() - 1
                    }
                };
                comp_of[k] = Some(id);
                offer(&mut comps[id], p);
            }
            // Extremes between the samples, half-cell by half-cell.
            for k in (0..2 * n).filter(|k| grown[k / 2]) {
                let (Some(a), Some(b)) = (at(k), at(k + 1)) else {
                    continue;
                };
                match comp_of[k].or(comp_of[k + 1]) {
                    Some(id) => self.refine(&ray, a, b, &mut comps[id], 0),
                    None => {
                        let mut touch = None;
                        self.refine(&ray, a, b, &mut touch, 0);
                        comps.push(touch);
                    }
                }
            }
            cuts.clear();
            cuts.extend(comps.drain(..).flatten());
            self.merge_and_emit(cuts, out);
        });
    }

    /// Sorts the intervals, merges those that overlap and emits them with their normals.
    fn merge_and_emit(&self, cuts: &mut [RawEnd], out: &mut Vec<RayCut>) {
        cuts.sort_by(|a, b| a.lo.t.total_cmp(&b.lo.t));
        let mut merged: Option<RawEnd> = None;
        for &c in cuts.iter() {
            merged = Some(match merged {
                Some(mut m) if c.lo.t <= m.hi.t + tol::SLIVER => {
                    if c.hi.t > m.hi.t {
                        m.hi = c.hi;
                    }
                    m
                }
                Some(m) => {
                    emit(&m, self.r, out);
                    c
                }
                None => c,
            });
        }
        if let Some(m) = merged {
            emit(&m, self.r, out);
        }
    }

    /// Offers to `acc` every extreme of the ray's interval strictly between the probes `a`
    /// and `b` (see the module docs).
    fn refine(&self, ray: &Ray, a: &Probe, b: &Probe, acc: &mut Option<RawEnd>, depth: u32) {
        let w = b.lambda - a.lambda;
        if depth > MAX_DEPTH || self.speed * w <= SOLVE_TOL {
            return;
        }
        let bisect = |acc: &mut Option<RawEnd>| {
            let m = self.probe_at(0.5 * (a.lambda + b.lambda), ray);
            offer(acc, &m);
            self.refine(ray, a, &m, acc, depth + 1);
            self.refine(ray, &m, b, acc, depth + 1);
        };
        let (ha, hb) = (a.hit, b.hit);
        if ha.is_none() && hb.is_none() {
            // A touch between two missing poses needs the tool to travel to the ray from both.
            let z = &self.part_z;
            let sep =
                |p: &Probe, k: usize| line_segment_distance(&p.p, &p.u, z[k], z[k + 1]) - self.r;
            let apart = (0..PARTS)
                .all(|k| sep(a, k) + sep(b, k) + 2.0 * ENVELOPE_TOL > self.part_speed[k] * w);
            if apart {
                return;
            }
            // Between two misses the ray can only come to meet the tool where it passes
            // through an edge circle or touches the tool's smooth part (the capsule of radius
            // R about the axis from `z[0]` to the top, which holds the tool). An edge crossing
            // is solved for like one between hits: the ray meets the tool there, if at all.
            let mut crossing = false;
            for edge in 0..2 {
                let (fa, fb) = (a.phi[edge], b.phi[edge]);
                if !fa.is_nan() && !fb.is_nan() && (fa < 0.0) != (fb < 0.0) {
                    let phi = move |p: &Probe| Some(p.phi[edge]);
                    if let Some((lo, hi)) = self.solve(ray, a, b, phi, Stop::Crossing, acc) {
                        self.refine(ray, a, &lo, acc, depth + 1);
                        self.refine(ray, &hi, b, acc, depth + 1);
                        return;
                    }
                    crossing = true;
                }
            }
            // Without one, a ray that stays inside the capsule (its distance from the axis
            // segment below R at both ends, by more than the segment can move) touches no
            // smooth face in between: it misses throughout.
            let inside = |p: &Probe| self.r - line_segment_distance(&p.p, &p.u, z[0], self.l);
            if !crossing && inside(a) + inside(b) > self.speed * w {
                return;
            }
            // And the grown tool about the middle to meet it.
            let mid = 0.5 * (a.lambda + b.lambda);
            let s = self.sample_at(mid);
            let grow = self.speed * w / 2.0 - ENVELOPE_TOL;
            if grow > 0.0 && self.meets_grown(&s, ray, grow) {
                let m = self.probe(&s, mid, ray);
                offer(acc, &m);
                self.refine(ray, a, &m, acc, depth + 1);
                self.refine(ray, &m, b, acc, depth + 1);
            }
            return;
        }
        // Ends already beyond the span need no refinement.
        let (in_done, out_done) = acc.map_or((false, false), |c| {
            (c.lo.t < ray.span.0, c.hi.t > ray.span.1)
        });
        if in_done && out_done {
            return;
        }
        // The ray crosses an edge circle: a kink or the ray leaving through the edge.
        for edge in 0..2 {
            let (fa, fb) = (a.phi[edge], b.phi[edge]);
            if !fa.is_nan() && !fb.is_nan() && (fa < 0.0) != (fb < 0.0) {
                let phi = move |p: &Probe| Some(p.phi[edge]);
                match self.solve(ray, a, b, phi, Stop::Crossing, acc) {
                    Some((lo, hi)) => {
                        self.refine(ray, a, &lo, acc, depth + 1);
                        self.refine(ray, &hi, b, acc, depth + 1);
                    }
                    None => bisect(acc),
                }
                return;
            }
        }
        let r = self.r;
        match (ha, hb) {
            (Some(x), Some(y)) => {
                if x.face_in.family() != y.face_in.family()
                    || x.face_out.family() != y.face_out.family()
                {
                    return bisect(acc);
                }
                if !in_done && a.g_in(r) < 0.0 && b.g_in(r) > 0.0 {
                    let g = |p: &Probe| p.hit.map(|_| p.g_in(r));
                    if self.solve(ray, a, b, g, Stop::Extreme, acc).is_none() {
                        return bisect(acc);
                    }
                }
                if !out_done && a.g_out(r) > 0.0 && b.g_out(r) < 0.0 {
                    let g = |p: &Probe| p.hit.map(|_| p.g_out(r));
                    if self.solve(ray, a, b, g, Stop::Extreme, acc).is_none() {
                        bisect(acc);
                    }
                }
            }
            // Into a touch t_in rises and t_out falls: an end moving the other way on the
            // inside has an extreme before the ray leaves.
            (Some(_), None) if (!in_done && a.g_in(r) < 0.0) || (!out_done && a.g_out(r) > 0.0) => {
                bisect(acc)
            }
            (None, Some(_)) if (!in_done && b.g_in(r) > 0.0) || (!out_done && b.g_out(r) < 0.0) => {
                bisect(acc)
            }
            _ => {}
        }
    }

    /// Brackets the sign change of `f` between `a` and `b` by the Illinois variant of regula
    /// falsi (a bisection every third step that did not halve the bracket), offering every
    /// pose it evaluates. `None` where `f` is undefined (the ray missed a pose).
    fn solve(
        &self,
        ray: &Ray,
        a: &Probe,
        b: &Probe,
        f: impl Fn(&Probe) -> Option<Real>,
        stop: Stop,
        acc: &mut Option<RawEnd>,
    ) -> Option<(Probe, Probe)> {
        let (mut lo, mut hi) = (a.clone(), b.clone());
        let (Some(f_lo), Some(f_hi)) = (f(&lo), f(&hi)) else {
            return None;
        };
        let neg_lo = f_lo < 0.0;
        // Secant weights (halved by Illinois) and the true values.
        let (mut wlo, mut whi) = (f_lo, f_hi);
        let (mut flo, mut fhi) = (f_lo, f_hi);
        let mut last_side = 0i8;
        let mut width = hi.lambda - lo.lambda;
        for step in 0..MAX_SOLVE_STEPS {
            let w = hi.lambda - lo.lambda;
            if stop.reached(self, &lo, &hi, flo, fhi, w) {
                break;
            }
            let mut m = (lo.lambda * whi - hi.lambda * wlo) / (whi - wlo);
            if step % 3 == 2 {
                if w > 0.5 * width {
                    m = 0.5 * (lo.lambda + hi.lambda);
                }
                width = w;
            }
            if !(m > lo.lambda && m < hi.lambda) {
                m = 0.5 * (lo.lambda + hi.lambda);
                if !(m > lo.lambda && m < hi.lambda) {
                    break;
                }
            }
            let p = self.probe_at(m, ray);
            offer(acc, &p);
            let fm = f(&p)?;
            if fm.is_nan() {
                return None;
            }
            if (fm < 0.0) == neg_lo {
                (lo, flo, wlo) = (p, fm, fm);
                if last_side < 0 {
                    whi *= 0.5;
                }
                last_side = -1;
            } else {
                (hi, fhi, whi) = (p, fm, fm);
                if last_side > 0 {
                    wlo *= 0.5;
                }
                last_side = 1;
            }
        }
        Some((lo, hi))
    }
}

/// When a solve's bracket is fine enough.
#[derive(Clone, Copy, Debug)]
enum Stop {
    /// A smooth extreme of an interval end: `f` is its rate; the end is within
    /// `min |rate| · w` of the extreme on a convex stretch.
    Extreme,
    /// An edge crossing: `t` moves by at most the larger rate at the bracket ends times `w`.
    Crossing,
}

impl Stop {
    /// Whether the bracket `lo`–`hi` (width `w` in λ, `f` there `flo`, `fhi`) of `env`'s
    /// solve is fine enough.
    fn reached(
        self,
        env: &RotaryEnvelope,
        lo: &Probe,
        hi: &Probe,
        flo: Real,
        fhi: Real,
        w: Real,
    ) -> bool {
        let slope = match self {
            Stop::Extreme => flo.abs().min(fhi.abs()),
            Stop::Crossing => {
                let rates = [lo, hi]
                    .into_iter()
                    .filter(|p| p.hit.is_some())
                    .flat_map(|p| [p.g_in(env.r).abs(), p.g_out(env.r).abs()])
                    .filter(|g| g.is_finite())
                    .fold(Real::NEG_INFINITY, Real::max);
                if rates.is_finite() { rates } else { env.speed }
            }
        };
        slope * w <= SOLVE_TOL || w <= 4.0 * Real::EPSILON
    }
}

fn emit(c: &RawEnd, r: Real, out: &mut Vec<RayCut>) {
    if c.hi.t - c.lo.t > tol::LENGTH_EPS {
        out.push(RayCut {
            t_in: c.lo.t,
            t_out: c.hi.t,
            n_in: c.lo.normal(r),
            n_out: c.hi.normal(r),
        });
    }
}

/// `Scratch::slot` of a sample not evaluated.
const NO_PROBE: u32 = u32::MAX;

/// Per-thread buffers of [`RotaryEnvelope::intervals_in`], reused from ray to ray.
#[derive(Default)]
struct Scratch {
    grown: Vec<bool>,
    /// Per sample, its probe's index in `probes` or [`NO_PROBE`].
    slot: Vec<u32>,
    probes: Vec<Probe>,
    comp_of: Vec<Option<usize>>,
    comps: Vec<Option<RawEnd>>,
    cuts: Vec<RawEnd>,
}

thread_local! {
    static SCRATCH: std::cell::RefCell<Scratch> = std::cell::RefCell::new(Scratch::default());
}

/// One end of an interval and where it was found: its normal is worked out only for the
/// ends that are kept (the same arithmetic as at the probe, so the same bits).
#[derive(Clone, Copy, Debug)]
struct End {
    t: Real,
    face: Face,
    /// The end's point and the ray's direction in the tool frame, and the pose's rotation.
    q: Vector3,
    u: Vector3,
    rot: Matrix3,
}

impl End {
    fn at(p: &Probe, t: Real, face: Face) -> Self {
        Self {
            t,
            face,
            q: p.p + p.u * t,
            u: p.u,
            rot: p.rot,
        }
    }

    /// The material normal (W): the tool's inward normal at the end, the ray where no face
    /// (`r` the tool radius).
    fn normal(&self, r: Real) -> Vector3 {
        match tool_normal(&self.q, self.face, r) {
            Some(n) => -(self.rot * n),
            None => self.rot * self.u,
        }
    }
}

/// An interval: its lower and upper ends.
#[derive(Clone, Copy, Debug)]
struct RawEnd {
    lo: End,
    hi: End,
}

/// Widens `best` by the interval of the probe, if the ray meets the tool there.
#[inline(always)]
fn offer(best: &mut Option<RawEnd>, p: &Probe) {
    let Some(h) = p.hit else {
        return;
    };
    match best {
        None => {
            *best = Some(RawEnd {
                lo: End::at(p, h.t_in, h.face_in),
                hi: End::at(p, h.t_out, h.face_out),
            })
        }
        Some(c) => {
            if h.t_in < c.lo.t {
                c.lo = End::at(p, h.t_in, h.face_in);
            }
            if h.t_out > c.hi.t {
                c.hi = End::at(p, h.t_out, h.face_out);
            }
        }
    }
}

/// The tool's outward normal (tool frame) on `face` at the tool-frame point `q` (`r` the
/// tool radius).
#[inline(always)]
fn tool_normal(q: &Vector3, face: Face, r: Real) -> Option<Vector3> {
    match face {
        Face::Side => Vector3::new(q.x, q.y, 0.0).try_normalize(0.0),
        Face::Bottom => Some(-Vector3::z()),
        Face::Top => Some(Vector3::z()),
        Face::Sphere => (q - Vector3::new(0.0, 0.0, r)).try_normalize(0.0),
        Face::None => None,
    }
}

/// A bound on the speed (mm per unit λ) of any point within `reach` of the tool-axis point at
/// height `mid` on the move: the rotation `ω` (rad) times the largest distance `ρ` of such a
/// point from a rotary axis, plus the linear travel. `ρ` is taken at both ends (distance of
/// the axis point from each rotary axis line, plus `reach`) and grown by the travel, which is
/// the most it can change while the rotation turns points about the axis; several rotary
/// axes widen it by `(1 + ω)` as the sub-step bound does. Error motions add their own
/// speed ([`error_motion_speed`]).
fn speed_bound(
    chain: &Chain,
    mid: Real,
    reach: Real,
    start: &AxisValues,
    end: &AxisValues,
    state: &[Real; 6],
) -> Real {
    let (mut omega, mut travel) = (0.0, 0.0);
    let mut rotaries = 0;
    for axis in chain.axes() {
        let dq = (end.get(axis.letter) - start.get(axis.letter)).abs();
        match axis.kind {
            AxisKind::Rotary => {
                omega += dq.to_radians();
                rotaries += 1;
            }
            AxisKind::Linear => travel += dq,
        }
    }
    let mid = Point3::new(0.0, 0.0, mid);
    let mut rho: Real = 0.0;
    for q in [start, end] {
        let c = chain.w_from_t(q) * mid;
        for (p, d) in chain.rotary_lines_in_w(q) {
            let r = c - p;
            rho = rho.max((r - d * r.dot(&d)).norm());
        }
    }
    rho += reach + travel;
    if rotaries > 1 {
        rho *= 1.0 + omega;
    }
    let base = omega * rho + travel;
    if chain.has_error_motions() {
        base + error_motion_speed(chain, &mid, reach, start, end, state).0
    } else {
        base
    }
}

/// What error motions add to the speed of points within `reach` of the tool point `mid`
/// (tool frame) on the move `start → end` from the reversal shares `state`, per unit λ, and
/// the rate of the orientation they turn (rad per unit λ): for each axis `i` that moves by
/// `Δq_i`, `|Δq_i|·(s_δ + r + s_θ·ρ_i)` with `s_δ`, `s_θ` bounds on its offset and angular
/// slopes over the move, `r` 1 when its lost motion is taken up during the move, and `ρ_i`
/// a bound on the distance of the points from the axis's error centre (its distance at
/// both ends plus `reach`, the travel and 1 mm for the error offsets themselves, widened by
/// `(1 + ω)` when a rotary axis turns). A point of the frame after the axis moves at
/// `w × (x − c) + δ'` relative to the frame before it, `|w| ≤ s_θ·|Δq|`, `|δ'| ≤ (s_δ + r)·|Δq|`.
pub fn error_motion_speed(
    chain: &Chain,
    mid: &Point3,
    reach: Real,
    start: &AxisValues,
    end: &AxisValues,
    state: &[Real; 6],
) -> (Real, Real) {
    let (mut omega, mut travel) = (0.0, 0.0);
    for axis in chain.axes() {
        let dq = (end.get(axis.letter) - start.get(axis.letter)).abs();
        match axis.kind {
            AxisKind::Rotary => omega += dq.to_radians(),
            AxisKind::Linear => travel += dq,
        }
    }
    let (mut speed, mut turn) = (0.0, 0.0);
    for (i, axis) in chain.axes().iter().enumerate() {
        let Some(e) = &chain.error_motions_all()[i] else {
            continue;
        };
        let (q0, q1) = (start.get(axis.letter), end.get(axis.letter));
        let dq = (q1 - q0).abs();
        if dq == 0.0 {
            continue;
        }
        let (sd, sa) = e.slope_bounds(q0.min(q1), q0.max(q1));
        let ramp = if e.reversal != 0.0 { 1.0 } else { 0.0 };
        let mut rho: Real = 0.0;
        for q in [start, end] {
            let c = centre_in_w(chain, i, q, state);
            rho = rho.max((chain.w_from_t_state(q, state) * mid - c).norm());
        }
        rho = (rho + reach + travel + 1.0) * (1.0 + omega);
        speed += dq * (sd + ramp + sa * rho);
        turn += dq * sa;
    }
    (speed, turn)
}

/// The error centre of axis `i` in W at `q` (the frame after its motion).
fn centre_in_w(chain: &Chain, i: usize, q: &AxisValues, state: &[Real; 6]) -> Point3 {
    let mut pose = Isometry3::identity();
    for (j, (axis, dev)) in chain.axes().iter().zip(chain.deviations()).enumerate() {
        let qj = q.get(axis.letter);
        pose *= axis.motion(qj);
        if j == i {
            return pose * chain.error_centre(i);
        }
        if let Some(e) = &chain.error_motions_all()[j] {
            let v = e.values_with_offset(qj, state[axis.letter.index()]);
            pose *= error_motion::transform(&v, &chain.error_centre(j));
        }
        pose *= dev.transform();
    }
    pose * Point3::origin()
}

/// Box of the tool (grown by `margin`) at a pose.
fn frame_box(f: &Sample, shape: Shape, r: Real, l: Real, margin: Real) -> Aabb {
    let v = f.rot.column(2).into_owned();
    let ext = Vector3::from_fn(|k, _| r * (1.0 - v[k] * v[k]).max(0.0).sqrt() + margin);
    let mut b = Aabb::empty();
    let lo = if shape == Shape::Ball { r } else { 0.0 };
    for h in [lo, l] {
        let c = f.tip + v * h;
        b.grow(&(c - ext));
        b.grow(&(c + ext));
    }
    if shape == Shape::Ball {
        let c = f.tip + v * r;
        b.grow(&(c - Vector3::repeat(r + margin)));
        b.grow(&(c + Vector3::repeat(r + margin)));
    }
    b
}

/// Interval of the line `p + t·u` (tool frame, `u` unit) inside the infinite cylinder of
/// radius `rad` about the z axis: `None` if it misses, infinite ends if parallel inside.
#[inline(always)]
fn cylinder(p: &Vector3, u: &Vector3, rad: Real) -> Option<(Real, Real)> {
    let a = u.x * u.x + u.y * u.y;
    let b = p.x * u.x + p.y * u.y;
    let c = p.x * p.x + p.y * p.y - rad * rad;
    if a <= tol::RELATIVE_EPS {
        return (c <= 0.0).then_some((Real::NEG_INFINITY, Real::INFINITY));
    }
    let disc = b * b - a * c;
    if disc < 0.0 {
        return None;
    }
    let q = -(b + b.signum() * disc.sqrt());
    let (x0, x1) = if q == 0.0 { (0.0, 0.0) } else { (q / a, c / q) };
    Some((x0.min(x1), x0.max(x1)))
}

/// Interval of the line inside the slab `h0 ≤ z ≤ h1`, with the face at each end.
#[inline(always)]
fn slab(pz: Real, uz: Real, h0: Real, h1: Real) -> Option<(Real, Face, Real, Face)> {
    if uz.abs() <= tol::RELATIVE_EPS {
        return (h0 <= pz && pz <= h1).then_some((
            Real::NEG_INFINITY,
            Face::None,
            Real::INFINITY,
            Face::None,
        ));
    }
    let (a, b) = ((h0 - pz) / uz, (h1 - pz) / uz);
    Some(if uz > 0.0 {
        (a, Face::Bottom, b, Face::Top)
    } else {
        (b, Face::Top, a, Face::Bottom)
    })
}

/// The tool's interval along the line `p + t·u` (tool frame), the tool grown by `g`.
#[inline(always)]
fn tool_interval(
    shape: Shape,
    r: Real,
    l: Real,
    p: &Vector3,
    u: &Vector3,
    g: Real,
) -> Option<(Real, Face, Real, Face)> {
    let h0 = match shape {
        Shape::Flat => -g,
        Shape::Ball => r - g,
    };
    let cyl = cylinder(p, u, r + g).and_then(|(c0, c1)| {
        let (s0, f0, s1, f1) = slab(p.z, u.z, h0, l + g)?;
        let (t0, face0) = if c0 >= s0 { (c0, Face::Side) } else { (s0, f0) };
        let (t1, face1) = if c1 <= s1 { (c1, Face::Side) } else { (s1, f1) };
        (t0 <= t1).then_some((t0, face0, t1, face1))
    });
    if shape == Shape::Flat {
        return cyl;
    }
    match (cyl, ball_sphere(r, p, u, g)) {
        (Some(a), Some(b)) => {
            let (t0, f0) = if a.0 <= b.0 { (a.0, a.1) } else { (b.0, b.1) };
            let (t1, f1) = if a.2 >= b.2 { (a.2, a.3) } else { (b.2, b.3) };
            Some((t0, f0, t1, f1))
        }
        (a, b) => a.or(b),
    }
}

/// The interval of the line `p + t·u` (tool frame, `u` unit) in a ball end mill's sphere
/// (about (0, 0, r), radius r + g): part of [`tool_interval`], which is its hull with the
/// shank's interval.
#[inline(always)]
fn ball_sphere(r: Real, p: &Vector3, u: &Vector3, g: Real) -> Option<(Real, Face, Real, Face)> {
    let w = p - Vector3::new(0.0, 0.0, r);
    let rad = r + g;
    let b = w.dot(u);
    let c = w.dot(&w) - rad * rad;
    let disc = b * b - c;
    (disc >= 0.0).then(|| {
        let sq = disc.sqrt();
        (-b - sq, Face::Sphere, -b + sq, Face::Sphere)
    })
}

impl Cutter for RotaryEnvelope {
    fn bounds(&self) -> Aabb {
        self.bounds
    }

    /// The hull of the ray's intervals; the stock uses [`Cutter::ray_cuts`].
    fn ray_cut(&self, origin: &Point3, axis: usize) -> Option<RayCut> {
        let mut out = Vec::new();
        self.ray_cuts(origin, axis, &mut out);
        let (first, last) = (out.first()?, out.last()?);
        Some(RayCut {
            t_in: first.t_in,
            t_out: last.t_out,
            n_in: first.n_in,
            n_out: last.n_out,
        })
    }

    fn ray_cuts(&self, origin: &Point3, axis: usize, out: &mut Vec<RayCut>) {
        let mut e = Vector3::zeros();
        e[axis] = 1.0;
        self.intervals(origin, &e, out);
    }

    fn costly_rays(&self) -> bool {
        true
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
        self.intervals_in(origin, &e, span, out);
        lines.resize(lines.len() + out.len() - before, [line, line]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cutting::cutter::SweptTool;
    use crate::nc::AxisLetter;
    use proptest::prelude::*;

    fn deviated() -> Chain {
        let mut c = crate::machine::chain::mdx50_for_tests();
        for (name, v) in [
            ("dy_AY", -0.3),
            ("dz_AY", 0.2),
            ("beta_AY", 2e-4),
            ("gamma_AY", -3e-4),
            ("alpha_YX", 4e-4),
            ("beta_XZ", -2e-4),
            ("alpha_ZS", 1e-4),
            ("beta_ZS", -5e-4),
        ] {
            let id = c.deviation_id(name).expect("known");
            c.set_deviation(id, v);
        }
        c
    }

    fn q(x: Real, y: Real, z: Real, a: Real) -> AxisValues {
        AxisValues::default()
            .with(AxisLetter::X, x)
            .with(AxisLetter::Y, y)
            .with(AxisLetter::Z, z)
            .with(AxisLetter::A, a)
    }

    #[test]
    fn move_path_is_the_chain_pose() {
        let c = deviated();
        let (a, b) = (q(1.0, -2.0, 8.0, 10.0), q(4.0, -2.0, 7.0, 47.0));
        let path = MovePath::new(&c, &a, &b);
        for k in 0..=10 {
            let l = k as Real / 10.0;
            let mut qq = a;
            for axis in c.axes() {
                let (u, w) = (a.get(axis.letter), b.get(axis.letter));
                qq.set(axis.letter, u + (w - u) * l);
            }
            let d = path.w_from_t(l).to_homogeneous() - c.w_from_t(&qq).to_homogeneous();
            assert!(d.abs().max() < 1e-12, "λ = {l}: {d}");
        }
    }

    /// The tool's interval along the ray at λ from the cutter's sweep of the standing tool
    /// (an independent closed form), on the library chain's pose.
    fn exact_at(
        c: &Chain,
        tool: &Tool,
        a: &AxisValues,
        b: &AxisValues,
        l: Real,
        o: &Point3,
        e: &Vector3,
    ) -> Option<(Real, Real)> {
        let mut qq = *a;
        for axis in c.axes() {
            let (u, w) = (a.get(axis.letter), b.get(axis.letter));
            qq.set(axis.letter, u + (w - u) * l);
        }
        let pose = c.w_from_t(&qq);
        let v = nalgebra::Unit::new_normalize(pose.rotation * Vector3::z());
        let st = SweptTool::new(tool, pose * Point3::origin(), Vector3::zeros(), v);
        let mut out = Vec::new();
        st.intervals(o, e, &mut out);
        Some((out.first()?.t_in, out.last()?.t_out))
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 64, failure_persistence: None, rng_seed: proptest::test_runner::RngSeed::Fixed(0x5eed), ..ProptestConfig::default() })]

        /// On random rotary moves (A turning with X, Z), every interval end agrees with a
        /// brute-force search over 4,000 poses: no pose reaches further than the envelope
        /// (to 0.1 µm), and the sampled poses come within the sampling error of each end;
        /// between intervals no pose touches the ray.
        #[test]
        fn envelope_agrees_with_brute_force(
            ball in any::<bool>(), a0 in -40.0..40.0f64, da in -30.0..30.0f64,
            x0 in -3.0..3.0f64, dx in -4.0..4.0f64, z0 in 4.0..9.0f64, dz in -2.0..2.0f64,
            y in -2.0..2.0f64, axis in 0usize..3, ou in -1.0..1.0f64, ov in -1.0..1.0f64,
            f0 in -0.2..0.6f64, f1 in 0.4..1.2f64,
        ) {
            let c = deviated();
            let kind = if ball { ToolKind::Ball } else { ToolKind::Flat };
            let tool = Tool::try_new(kind, 6.0, 12.0).expect("valid");
            let (a, b) = (q(x0, y, z0, a0), q(x0 + dx, y, z0 + dz, a0 + da));
            let env = RotaryEnvelope::new(&c, &tool, &a, &b).expect("supported");
            // A ray through the region the tool sweeps: aimed near the tool's middle at λ = ½.
            let mid = MovePath::new(&c, &a, &b).w_from_t(0.5) * Point3::new(0.0, 0.0, 3.0);
            let mut o = mid;
            o[(axis + 1) % 3] += 4.0 * ou;
            o[(axis + 2) % 3] += 4.0 * ov;
            let mut e = Vector3::zeros();
            e[axis] = 1.0;
            let mut cuts = Vec::new();
            env.intervals(&o, &e, &mut cuts);
            for w in cuts.windows(2) {
                prop_assert!(w[0].t_out < w[1].t_in, "not sorted/disjoint: {cuts:?}");
            }
            let n = 4000;
            let mut lo = Real::INFINITY;
            let mut hi = Real::NEG_INFINITY;
            let mut hits = Vec::new();
            for k in 0..=n {
                let l = k as Real / n as Real;
                if let Some((t0, t1)) = exact_at(&c, &tool, &a, &b, l, &o, &e) {
                    lo = lo.min(t0);
                    hi = hi.max(t1);
                    hits.push((t0, t1));
                }
            }
            // Around the poses reaching furthest either way, 4,000 poses more within ±1/n.
            let mut far = [(Real::INFINITY, 0.0), (Real::NEG_INFINITY, 0.0)];
            for k in 0..=n {
                let l = k as Real / n as Real;
                if let Some((t0, t1)) = exact_at(&c, &tool, &a, &b, l, &o, &e) {
                    if t0 < far[0].0 { far[0] = (t0, l); }
                    if t1 > far[1].0 { far[1] = (t1, l); }
                }
            }
            for &(_, l0) in &far {
                for k in 0..=n {
                    let l = (l0 + (2.0 * k as Real / n as Real - 1.0) / n as Real).clamp(0.0, 1.0);
                    if let Some(h) = exact_at(&c, &tool, &a, &b, l, &o, &e) {
                        hits.push(h);
                    }
                }
            }
            // Sampling error, worked out here and not from the envelope's own speed bound:
            // between consecutive sampled poses no tool point moves further than
            // M = max_k |Δc_k| + 2·sin(θ_k/2)·ρ (c the tool's mid point on its axis, θ_k
            // the rotation between the poses, ρ = √(R² + (L/2)²) the farthest a tool point
            // lies from c); an interval end moves along the ray by up to a few times that
            // where the ray meets the surface at a slant: 4·M, and 1 nm for rounding.
            let mid = Point3::new(0.0, 0.0, tool.length() / 2.0);
            let rho = tool.radius().hypot(tool.length() / 2.0);
            let pose = |l: Real| {
                let mut qq = a;
                for axis in c.axes() {
                    let (u, w) = (a.get(axis.letter), b.get(axis.letter));
                    qq.set(axis.letter, u + (w - u) * l);
                }
                c.w_from_t(&qq)
            };
            let mut step_max: Real = 0.0;
            let mut prev = pose(0.0);
            for k in 1..=n {
                let next = pose(k as Real / n as Real);
                let moved = ((next * mid) - (prev * mid)).norm()
                    + 2.0 * (next.rotation.angle_to(&prev.rotation) / 2.0).sin() * rho;
                step_max = step_max.max(moved);
                prev = next;
            }
            let samp = 4.0 * step_max + 1e-6;
            for &(t0, t1) in &hits {
                // Every pose's interval lies inside one of the envelope's intervals.
                let inside = cuts.iter().any(|c| c.t_in <= t0 + ENVELOPE_TOL && t1 <= c.t_out + ENVELOPE_TOL);
                prop_assert!(inside || t1 - t0 < 1e-6, "pose interval [{t0}, {t1}] not inside {cuts:?}");
            }
            for cut in &cuts {
                // Each end is reached by some pose, within the sampling error.
                let near_in = hits.iter().any(|h| (h.0 - cut.t_in).abs() <= samp);
                let near_out = hits.iter().any(|h| (h.1 - cut.t_out).abs() <= samp);
                prop_assert!(near_in && near_out, "{cut:?} not reached; sampled [{lo}, {hi}]");
            }
            if hits.is_empty() {
                prop_assert!(cuts.iter().all(|c| c.t_out - c.t_in < samp), "{cuts:?} but no pose hits");
            }
            // Within a span (the material's extent) the answer is the same.
            let span = (lo + f0 * (hi - lo), lo + f1 * (hi - lo));
            if span.0 < span.1 {
                let clip = |cs: &[RayCut]| -> Vec<(Real, Real)> {
                    cs.iter()
                        .map(|c| (c.t_in.max(span.0), c.t_out.min(span.1)))
                        .filter(|(a, b)| b - a > 1e-6)
                        .collect()
                };
                let mut part = Vec::new();
                env.intervals_in(&o, &e, span, &mut part);
                let (full, part) = (clip(&cuts), clip(&part));
                prop_assert_eq!(full.len(), part.len(), "{:?} vs {:?}", full, part);
                for (x, y) in full.iter().zip(&part) {
                    prop_assert!((x.0 - y.0).abs() <= 2.0 * ENVELOPE_TOL && (x.1 - y.1).abs() <= 2.0 * ENVELOPE_TOL, "{:?} vs {:?}", full, part);
                }
            }
        }
    }

    /// A case a random search found in an earlier, Brent-based envelope: a z ray the flat
    /// tool leaves through the edge of its top face while A turns. The farthest exit is where
    /// the ray passes through the top edge circle (λ ≈ 0.924), at the end of the poses that
    /// meet the ray; 20,001 independent poses must not reach beyond the envelope.
    #[test]
    fn envelope_reaches_the_farthest_pose_on_a_grazing_top_face_ray() {
        let c = deviated();
        let tool = Tool::try_new(ToolKind::Flat, 6.0, 12.0).expect("valid");
        let (a, b) = (
            q(
                0.0,
                0.094_409_715_186_335,
                7.462_192_328_664_928,
                -33.606_531_410_104_42,
            ),
            q(
                0.0,
                0.094_409_715_186_335,
                7.462_192_328_664_928 + 0.545_658_555_771_143_7,
                -33.606_531_410_104_42 + 23.179_489_768_036_89,
            ),
        );
        let env = RotaryEnvelope::new(&c, &tool, &a, &b).expect("supported");
        let mut o = MovePath::new(&c, &a, &b).w_from_t(0.5) * Point3::new(0.0, 0.0, 3.0);
        o.y += 4.0 * 0.768_904_124_454_249_4;
        let e = Vector3::z();
        let mut cuts = Vec::new();
        env.intervals(&o, &e, &mut cuts);
        let far = cuts.last().expect("the ray is cut").t_out;
        let n = 20_000;
        for k in 0..=n {
            let l = k as Real / n as Real;
            if let Some((_, t1)) = exact_at(&c, &tool, &a, &b, l, &o, &e) {
                assert!(
                    t1 <= far + ENVELOPE_TOL,
                    "pose λ = {l} exits at {t1}, envelope at {far}"
                );
            }
        }
    }

    #[test]
    fn a_half_turn_leaves_two_intervals_on_a_ray_the_tool_crosses_twice() {
        // Nominal chain, tool tip 5 mm from the A axis pointing away from it, A turning
        // 0 → 180°: a z ray at y = 0, x = 0 meets the tool at A = 0 (z ∈ [5, 15]) and at
        // A = 180° (z ∈ [−15, −5]); in between the tool swings through the y side.
        let c = crate::machine::chain::mdx50_for_tests();
        let tool = Tool::try_new(ToolKind::Flat, 2.0, 10.0).expect("valid");
        let (a, b) = (q(0.0, 0.0, 5.0, 0.0), q(0.0, 0.0, 5.0, 180.0));
        let env = RotaryEnvelope::new(&c, &tool, &a, &b).expect("supported");
        let mut cuts = Vec::new();
        env.intervals(&Point3::new(0.0, 0.0, 0.0), &Vector3::z(), &mut cuts);
        assert_eq!(cuts.len(), 2, "{cuts:?}");
        // The ray (y = 0) at angle a: the tool covers |y_t| ≤ 1 about its axis, so the
        // z extent at a = ±asin(1/z)… the extremes are ±(sqrt(15² + 1²))·cos… take the
        // exact: points (0, 0, z) inside the tool at some a ∈ [0, π]: |z|·|sin a| ≤ 1 and
        // 5 ≤ |z|·cos a (or −cos a) ≤ 15 → |z| ∈ [5, sqrt(15² + 1)].
        let far = (15.0f64 * 15.0 + 1.0).sqrt();
        assert!((cuts[0].t_in + far).abs() < ENVELOPE_TOL, "{cuts:?}");
        assert!((cuts[0].t_out + 5.0).abs() < ENVELOPE_TOL, "{cuts:?}");
        assert!((cuts[1].t_in - 5.0).abs() < ENVELOPE_TOL, "{cuts:?}");
        assert!((cuts[1].t_out - far).abs() < ENVELOPE_TOL, "{cuts:?}");
        // Material normals face into the cut: +z at the lower ends of each interval.
        assert!(cuts[1].n_in.z > 0.99 && cuts[0].n_in.z > 0.0, "{cuts:?}");
    }
}
