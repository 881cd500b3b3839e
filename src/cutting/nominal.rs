//! The part a program cuts on the nominal machine, read as a signed distance near the
//! surface of the part the deviated machine cut: what the deviation colours are measured
//! from, without sweeping the program a second time.
//!
//! The nominal part is the stock less the tool swept along the program on the nominal
//! machine. Near a point `p` of the cut part's surface its signed distance (mm; + outside,
//! − inside) is `max(F_stock(p), −F_swept(p))`:
//!
//! - `F_swept(p)` is the least, over the moves and their poses `T(λ)` on the nominal machine,
//!   of the tool's signed distance at `T(λ)⁻¹·p` ([`crate::cutting::tool::Tool::signed_distance`]).
//!   Outside the swept volume that is the exact distance from it. Inside, it is the depth
//!   into the deepest single pose, which differs from the depth into the union of poses by
//!   terms of second order in the depth (the union's surface is the envelope of the poses,
//!   touching the deepest one's surface where it is nearest `p`).
//! - `F_stock(p)` is the stock's own signed distance ([`NominalStock`]: its box, and the
//!   cylinder or closed mesh within it), exact: both machines start from the same stock, and
//!   a face only one of them cuts is still the other's face.
//!
//! **Which moves.** Every crossing of the cut part carries the NC line that made it. The
//! two machines differ by deviations of micrometres, so the moves that made the cut part's
//! surface around `p` are nearly always the ones that make the nominal part's surface
//! there: the moves of the lines of the crossings on the rays within [`NEAR`] indices of
//! `p` in the three grids are read first, and give the least so far. They are not enough:
//! where several moves cut nearly the same surface (a side cut's passes, turn after turn),
//! the deviated machine's deepest there can be another than the nominal machine's by a
//! micrometre. So every other move whose swept tool could come nearer than the least so far
//! is read too: a tree of the moves' swept-tool boxes (`MoveTree`) and each move's capsule
//! bound (the nearest kept axis less the tool's radius and `D/2`) leave only the moves whose
//! tool passes within about `D/2` of `p`. The least is over every move; none is missed.
//!
//! **Within a move.** Each move's poses at `λ = k/`[`KEPT`] are kept, with `D`, a bound on
//! how far a tool point moves between consecutive kept poses (the tool's reach about its
//! middle times the turn, plus the middle's travel, the largest over the move — a bound on
//! every point's chord — grown for the bow of the path: by a quarter where the kept poses
//! turn by 45° or less, doubled beyond). The tool's signed distance at `p` is evaluated at the
//! kept poses; each move's values between two kept poses are at least the mean of the two
//! less `D/2` (the distance moves no more than the tool does), and the moves whose bound is
//! below the best value so far are refined, least bound first, by Brent's method over the
//! two intervals beside the least sample, until the tool moves less than [`DISTANCE_TOL`]
//! across the bracket.
//!
//! **Poses** are the nominal machine's own at the axis values the controller interpolates
//! (linear in `λ`; arcs are cut as the sweep's chords): a chain's through the envelope's
//! [`MovePath`] (the chain's fixed factors folded, one rotation a turning axis: the same
//! poses to rounding), a pose source's from the source. A pose the machine cannot take drops
//! its move from the candidates.
//!
//! **Invariant:** reads the cut part's crossings and the nominal machine's poses, never
//! changes either; the same inputs give the same distance bit for bit, whatever the thread
//! count.

use crate::cutting::envelope::MovePath;
use crate::cutting::shape::{ClosedMesh, Cylinder};
use crate::cutting::stock::TriDexel;
use crate::cutting::sweep::as_chords;
use crate::cutting::tool::Tool;
use crate::machine::PoseSource;
use crate::machine::chain::Chain;
use crate::math::{Aabb, Isometry3, Point3, Real, Vector3};
use crate::nc::Move;
use std::collections::BTreeMap;

/// Intervals each move is kept at (kept poses at `λ = k/KEPT`, `k = 0..=KEPT`).
pub const KEPT: usize = 8;

/// Rays on each side of a point whose crossings name its candidate moves and its stock face.
pub const NEAR: usize = 2;

/// The nominal machine: a serial chain, or a machine read pose by pose.
pub enum NominalMachine {
    /// A serial chain (its nominal form).
    Chain(Chain),
    /// A machine read pose by pose (a hexapod with its nominal parameters).
    Poses(Box<dyn PoseSource + Send>),
}

impl std::fmt::Debug for NominalMachine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            NominalMachine::Chain(c) => f.debug_tuple("Chain").field(c).finish(),
            NominalMachine::Poses(_) => f.write_str("Poses(..)"),
        }
    }
}

impl NominalMachine {
    /// The tool's pose at fraction `lambda` of `mv` (whose chain path is `path`, for a
    /// chain), if the machine can take it.
    fn pose(&self, mv: &Move, path: Option<&MovePath>, lambda: Real) -> Option<Isometry3> {
        match (self, path) {
            (NominalMachine::Chain(_), Some(path)) => Some(path.w_from_t(lambda)),
            (NominalMachine::Chain(c), None) => Some(c.w_from_t(&mv.point_at(lambda))),
            (NominalMachine::Poses(src), _) => src
                .w_from_t(&src.interpolate(&mv.start, &mv.end, lambda))
                .ok(),
        }
    }
}

/// The stock both machines start from, as a signed distance: its box, and the solid it
/// holds (a cylinder or a closed mesh) where it is not the box itself.
pub struct NominalStock {
    bounds: Aabb,
    solid: StockSolid,
}

enum StockSolid {
    Box,
    Cylinder(Cylinder),
    /// The mesh with its pseudo-normals (inside or outside at its edges and corners too).
    Mesh(Box<parry3d_f64::shape::TriMesh>),
}

impl std::fmt::Debug for NominalStock {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let solid = match &self.solid {
            StockSolid::Box => "box".to_string(),
            StockSolid::Cylinder(c) => format!("{c:?}"),
            StockSolid::Mesh(m) => format!("mesh of {} triangles", m.num_triangles()),
        };
        f.debug_struct("NominalStock")
            .field("bounds", &self.bounds)
            .field("solid", &solid)
            .finish()
    }
}

impl NominalStock {
    /// The box `bounds`.
    pub fn boxed(bounds: Aabb) -> Self {
        Self {
            bounds,
            solid: StockSolid::Box,
        }
    }

    /// The cylinder `c` within the box `bounds`.
    pub fn cylinder(bounds: Aabb, c: Cylinder) -> Self {
        Self {
            bounds,
            solid: StockSolid::Cylinder(c),
        }
    }

    /// The closed mesh `m` within the box `bounds`; `None` if parry refuses the mesh.
    pub fn mesh(bounds: Aabb, m: &ClosedMesh) -> Option<Self> {
        use parry3d_f64::shape::{TriMesh, TriMeshFlags};
        let mesh = TriMesh::with_flags(
            m.vertices().to_vec(),
            m.triangles().to_vec(),
            TriMeshFlags::ORIENTED,
        )
        .ok()?;
        Some(Self {
            bounds,
            solid: StockSolid::Mesh(Box::new(mesh)),
        })
    }

    /// The signed distance of `p` from the stock's surface and the outward normal at its
    /// nearest point: the box's and the solid's, the larger (the stock is both).
    pub fn nearest(&self, p: &Point3) -> Nearest {
        let b = box_nearest(&self.bounds, p);
        let s = match &self.solid {
            StockSolid::Box => return b,
            StockSolid::Cylinder(c) => cylinder_nearest(c, p),
            StockSolid::Mesh(m) => mesh_nearest(m, p),
        };
        if s.distance >= b.distance { s } else { b }
    }
}

/// The signed distance of `p` from the box `b` and the outward normal at its nearest point.
fn box_nearest(b: &Aabb, p: &Point3) -> Nearest {
    let below = b.min - p;
    let above = p - b.max;
    let out = below.sup(&above).sup(&Vector3::zeros());
    let d = out.norm();
    if d > 0.0 {
        // Outside: towards `p` from the nearest point.
        return Nearest {
            distance: d,
            normal: Vector3::from_fn(|k, _| {
                if below[k] > 0.0 {
                    -below[k]
                } else {
                    above[k].max(0.0)
                }
            }) / d,
        };
    }
    // Inside or on: the nearest face's plane.
    let mut best = (Real::NEG_INFINITY, Vector3::zeros());
    for k in 0..3 {
        let mut e = Vector3::zeros();
        for (v, sign) in [(below[k], -1.0), (above[k], 1.0)] {
            if v > best.0 {
                e[k] = sign;
                best = (v, e);
            }
        }
    }
    Nearest {
        distance: best.0,
        normal: best.1,
    }
}

/// The signed distance of `p` from the cylinder `c` and the outward normal at its nearest
/// point: in the plane of `p` and the axis, the distance from a rectangle (radius by length).
fn cylinder_nearest(c: &Cylinder, p: &Point3) -> Nearest {
    let a = c.axis().into_inner();
    let w = p - c.base();
    let h = w.dot(&a);
    let radial = w - a * h;
    let r = radial.norm();
    let u = if r > 0.0 {
        radial / r
    } else {
        // On the axis every radial direction is nearest: one across the axis.
        let k = a.iamin();
        a.cross(&Vector3::from_fn(|i, _| Real::from(u8::from(i == k))))
            .normalize()
    };
    let dr = r - c.radius();
    let (dh, cap) = if h < c.length() - h {
        (-h, -a)
    } else {
        (h - c.length(), a)
    };
    if dr > 0.0 || dh > 0.0 {
        let (x, y) = (dr.max(0.0), dh.max(0.0));
        let d = x.hypot(y);
        return Nearest {
            distance: d,
            normal: (u * x + cap * y) / d,
        };
    }
    if dr >= dh {
        Nearest {
            distance: dr,
            normal: u,
        }
    } else {
        Nearest {
            distance: dh,
            normal: cap,
        }
    }
}

/// The signed distance of `p` from the closed mesh `m` (inside by its pseudo-normals) and
/// the outward normal at its nearest point (the triangle's own where `p` is on it).
fn mesh_nearest(m: &parry3d_f64::shape::TriMesh, p: &Point3) -> Nearest {
    use parry3d_f64::query::PointQueryWithLocation;
    let (proj, (part, _)) = m.project_local_point_and_get_location(p, false);
    let v = p - proj.point;
    let d = v.norm();
    let sign = if proj.is_inside { -1.0 } else { 1.0 };
    let normal = if d > 1e-12 {
        v * (sign / d)
    } else {
        m.triangle(part)
            .normal()
            .map_or(Vector3::z(), |n| n.into_inner())
    };
    Nearest {
        distance: sign * d,
        normal,
    }
}

/// A move's kept poses and the motion between them.
#[derive(Clone, Debug)]
struct Kept {
    /// A chain's move as the envelope reads it: the chain with its fixed factors folded, one
    /// rotation a turning axis (the same poses as the chain's, a fraction of the cost).
    path: Option<MovePath>,
    poses: [Isometry3; KEPT + 1],
    /// Bound on how far a tool point moves between consecutive kept poses (mm).
    step: Real,
    /// The refinement's bracket width in `λ`: [`DISTANCE_TOL`] over the tool's speed.
    lambda_tol: Real,
    /// The middle kept pose's axis (tip, unit direction) and how far every kept axis lies
    /// from it at most (mm): one capsule holding every kept one ([`Kept::hull_bound`]).
    hull: (Point3, Vector3, Real),
}

impl Kept {
    /// The tool's axis at kept pose `k`: its tip and unit direction (W).
    fn axis(&self, k: usize) -> (Point3, Vector3) {
        let t = &self.poses[k];
        (
            Point3::from(t.translation.vector),
            t.rotation * Vector3::z(),
        )
    }

    /// A box holding the tool (radius `tool.radius()`, the tip to `tool.length()` up its
    /// axis) at every pose of the move: the kept poses' axes' ends, grown by the radius and
    /// `D/2` (every tool point between two kept poses lies within `D/2` of its place at
    /// one of them).
    fn swept_box(&self, tool: &Tool) -> Aabb {
        let mut b = Aabb::empty();
        for k in 0..=KEPT {
            let (a, u) = self.axis(k);
            b.grow(&a);
            b.grow(&(a + u * tool.length()));
        }
        b.inflated(tool.radius() + 0.5 * self.step)
    }

    /// The middle kept pose's axis and the farthest any kept axis lies from it (the
    /// distance from a segment is convex along another: its ends' farthest).
    fn hull(&self, length: Real) -> (Point3, Vector3, Real) {
        let (a, u) = self.axis(KEPT / 2);
        let rho = (0..=KEPT)
            .flat_map(|k| {
                let (b, v) = self.axis(k);
                [b, b + v * length]
            })
            .map(|q| segment_distance2(&q, &a, &u, length))
            .fold(0.0, Real::max)
            .sqrt();
        (a, u, rho)
    }

    /// A lower bound on the tool's signed distance at `p` over the move from one capsule:
    /// every kept axis within `ρ` of the middle one's, so no nearer than that axis less the
    /// radius, `ρ` and `D/2` (a looser bound than [`Kept::capsule_bound`], at a ninth of
    /// its cost).
    fn hull_bound(&self, p: &Point3, radius: Real, length: Real) -> Real {
        let (a, u, rho) = &self.hull;
        segment_distance2(p, a, u, length).sqrt() - radius - rho - 0.5 * self.step
    }

    /// A lower bound on the tool's signed distance at `p` over the move: the tool lies in
    /// the capsule of its radius about its axis, and between two kept poses within `D/2` of
    /// one of theirs, so no nearer than the nearest kept axis less the radius and `D/2`.
    fn capsule_bound(&self, p: &Point3, radius: Real, length: Real) -> Real {
        (0..=KEPT)
            .map(|k| {
                let (a, u) = self.axis(k);
                segment_distance2(p, &a, &u, length)
            })
            .fold(Real::INFINITY, Real::min)
            .sqrt()
            - radius
            - 0.5 * self.step
    }
}

/// The squared radius within which a crossing is around a point: crossings farther than the
/// [`NEAR`] window's half-width (its corner) are not.
fn near_radius2(cut: &TriDexel) -> Real {
    (cut.max_spacing() * (NEAR as Real + 0.5)).powi(2) * 3.0
}

/// The squared distance of `p` from the segment from `a` along the unit `u` for `length`.
fn segment_distance2(p: &Point3, a: &Point3, u: &Vector3, length: Real) -> Real {
    let w = p - a;
    let h = w.dot(u).clamp(0.0, length);
    (w - u * h).norm_squared()
}

/// The moves' swept-tool boxes ([`Kept::swept_box`]) as a bounding-volume tree: halves by
/// the median of the boxes' centres along their widest spread, four moves a leaf. A search
/// visits every move whose box's distance from a point is below a threshold (inside a box
/// counts as below every threshold), the threshold lowered as moves are read.
#[derive(Debug, Default)]
struct MoveTree {
    /// Depth first: an inner node's first child follows it, `next` is its second; a leaf's
    /// moves are `order[next..next + count]`.
    nodes: Vec<TreeNode>,
    order: Vec<u32>,
}

#[derive(Debug)]
struct TreeNode {
    bounds: Aabb,
    next: u32,
    /// Moves of a leaf; 0 for an inner node.
    count: u32,
}

/// Most moves in a leaf of [`MoveTree`].
const LEAF_MOVES: usize = 4;

impl MoveTree {
    /// The tree of `boxes` (move, its box).
    fn new(boxes: impl Iterator<Item = (u32, Aabb)>) -> Self {
        let mut items: Vec<(u32, Aabb)> = boxes.collect();
        let mut tree = Self {
            nodes: Vec::with_capacity(2 * items.len() / LEAF_MOVES + 1),
            order: Vec::with_capacity(items.len()),
        };
        if !items.is_empty() {
            tree.build(&mut items);
        }
        tree
    }

    fn build(&mut self, items: &mut [(u32, Aabb)]) {
        let mut bounds = Aabb::empty();
        let mut centres = Aabb::empty();
        for (_, b) in items.iter() {
            bounds.grow(&b.min);
            bounds.grow(&b.max);
            centres.grow(&nalgebra::center(&b.min, &b.max));
        }
        let at = self.nodes.len();
        if items.len() <= LEAF_MOVES {
            self.nodes.push(TreeNode {
                bounds,
                next: self.order.len() as u32,
                count: items.len() as u32,
            });
            self.order.extend(items.iter().map(|(m, _)| *m));
            return;
        }
        self.nodes.push(TreeNode {
            bounds,
            next: 0,
            count: 0,
        });
        let spread = centres.max - centres.min;
        let axis = spread.imax();
        let mid = items.len() / 2;
        let centre = |b: &Aabb| b.min[axis] + b.max[axis];
        items.select_nth_unstable_by(mid, |a, b| {
            centre(&a.1).total_cmp(&centre(&b.1)).then(a.0.cmp(&b.0))
        });
        let (left, right) = items.split_at_mut(mid);
        self.build(left);
        self.nodes[at].next = self.nodes.len() as u32;
        self.build(right);
    }

    /// Calls `visit(move, threshold)` for every move whose box's distance from `p` is below
    /// the threshold (starting at `threshold`; each call returns it, lowered or not).
    fn search(&self, p: &Point3, mut threshold: Real, mut visit: impl FnMut(u32, Real) -> Real) {
        if self.nodes.is_empty() {
            return;
        }
        let below = |b: &Aabb, threshold: Real| {
            let d2: Real = (0..3)
                .map(|k| (b.min[k] - p[k]).max(p[k] - b.max[k]).max(0.0).powi(2))
                .sum();
            // Inside the box: any depth may be inside the tool.
            d2 == 0.0 || d2.sqrt() < threshold
        };
        // The tree halves its moves at each level: 2⁶⁴ moves would not reach this depth.
        let mut stack = [0u32; 64];
        let mut len = 1;
        while len > 0 {
            len -= 1;
            let i = stack[len];
            let node = &self.nodes[i as usize];
            if !below(&node.bounds, threshold) {
                continue;
            }
            if node.count > 0 {
                let first = node.next as usize;
                for &m in &self.order[first..first + node.count as usize] {
                    threshold = visit(m, threshold);
                }
            } else {
                stack[len] = node.next;
                stack[len + 1] = i + 1;
                len += 2;
            }
        }
    }
}

/// The program on the nominal machine, as a signed distance near a cut part's surface (see
/// the module docs).
#[derive(Debug)]
pub struct NominalPath {
    tool: Tool,
    machine: NominalMachine,
    stock: NominalStock,
    moves: Vec<Move>,
    /// Per move (arcs as chords): its kept poses, `None` where the machine cannot take one.
    kept: Vec<Option<Kept>>,
    /// The moves of each NC line.
    by_line: BTreeMap<u32, Vec<u32>>,
    /// The moves' swept tools' boxes as a tree: every move that could reach a point.
    tree: MoveTree,
}

impl NominalPath {
    /// The program `moves` cut by `tool` on `machine` from `stock`, arcs as chords within
    /// `chord_mm` (the sweep's `rotary_step_bound_mm`, so the chords are the sweep's own).
    pub fn new(
        tool: &Tool,
        machine: NominalMachine,
        stock: NominalStock,
        moves: &[Move],
        chord_mm: Real,
    ) -> Self {
        use rayon::prelude::*;
        let moves = as_chords(moves, chord_mm).into_owned();
        let middle = Point3::new(0.0, 0.0, tool.length() / 2.0);
        let reach = tool.reach_from(tool.length() / 2.0);
        let kept: Vec<Option<Kept>> = moves
            .par_iter()
            .map(|mv| {
                let path = match &machine {
                    NominalMachine::Chain(c) => Some(MovePath::new(c, &mv.start, &mv.end)),
                    NominalMachine::Poses(_) => None,
                };
                let poses: Vec<Isometry3> = (0..=KEPT)
                    .map(|k| machine.pose(mv, path.as_ref(), k as Real / KEPT as Real))
                    .collect::<Option<_>>()?;
                let (chord, turn) = poses
                    .windows(2)
                    .map(|w| {
                        let turn = w[0].rotation.angle_to(&w[1].rotation);
                        ((w[1] * middle - w[0] * middle).norm() + turn * reach, turn)
                    })
                    .fold((0.0, 0.0), |a: (Real, Real), b| {
                        (a.0.max(b.0), a.1.max(b.1))
                    });
                // A point's path between kept poses is longer than its chord by the bow of
                // its turn: an arc of 45° is 2.6 % longer than its chord, of 180° 57 %.
                let bow = if turn <= std::f64::consts::FRAC_PI_4 {
                    1.25
                } else {
                    2.0
                };
                let mut kept = Kept {
                    path,
                    poses: poses.try_into().ok()?,
                    step: bow * chord,
                    lambda_tol: (DISTANCE_TOL / (KEPT as Real * chord)).clamp(1e-12, 1e-4),
                    hull: (Point3::origin(), Vector3::z(), 0.0),
                };
                kept.hull = kept.hull(tool.length());
                Some(kept)
            })
            .collect();
        let mut by_line: BTreeMap<u32, Vec<u32>> = BTreeMap::new();
        for (k, mv) in moves.iter().enumerate() {
            by_line.entry(mv.line as u32).or_default().push(k as u32);
        }
        let tree = MoveTree::new(
            kept.iter()
                .enumerate()
                .filter_map(|(m, k)| Some((m as u32, k.as_ref()?.swept_box(tool)))),
        );
        Self {
            tool: tool.clone(),
            machine,
            stock,
            moves,
            kept,
            by_line,
            tree,
        }
    }

    /// The signed distance (mm; + outside, − inside) of `p`, a point on or near the surface
    /// of `cut` (the part the program cut on the deviated machine), from the nominal part's
    /// surface, with that surface's outward normal at its point nearest `p`; `None` where
    /// `cut` has no crossing near `p` (see the module docs).
    pub fn nearest(&self, cut: &TriDexel, p: &Point3) -> Option<Nearest> {
        SCRATCH.with_borrow_mut(|scratch| self.nearest_with(cut, p, scratch))
    }

    /// [`Self::nearest`] with the scratch buffers `scratch`.
    fn nearest_with(&self, cut: &TriDexel, p: &Point3, scratch: &mut Scratch) -> Option<Nearest> {
        let Scratch { lines, cands, seen } = scratch;
        lines.clear();
        let mut near = false;
        let radius2 = near_radius2(cut);
        for g in cut.grids() {
            g.for_each_crossing_near(p, NEAR, |q, c| {
                if (q - p).norm_squared() > radius2 {
                    return;
                }
                near = true;
                if c.line != 0 {
                    lines.push(c.line);
                }
            });
        }
        if !near {
            return None;
        }
        lines.sort_unstable();
        lines.dedup();
        let stock = self.stock.nearest(p);
        // Where the stock's surface is farther out than the swept volume's, the part's
        // surface is the stock's: a move whose distance is not below the stock's negated
        // does not matter. Inside the swept volume is outside the part: the part's distance
        // is the negated one, its outward normal the tool's inward one.
        let limit = -stock.distance;
        let swept = self
            .swept_distance(p, lines, limit, cands, seen)
            .map(|(d, n)| Nearest {
                distance: -d,
                normal: -n,
            });
        Some(match swept {
            Some(w) if w.distance > stock.distance => w,
            _ => stock,
        })
    }

    /// The least signed distance of `p` from the tool over the moves, with the tool's
    /// outward normal there (`None` without a move below `limit`, beyond which the value
    /// does not matter to the caller). The moves of `lines` first; then every other move
    /// whose swept tool could come closer than the least so far (or `limit`), found by
    /// [`MoveTree`] and each move's capsule bound.
    fn swept_distance(
        &self,
        p: &Point3,
        lines: &[u32],
        limit: Real,
        scratch: &mut Vec<Candidate>,
        seen: &mut Vec<u32>,
    ) -> Option<(Real, Vector3)> {
        scratch.clear();
        scratch.extend(
            lines
                .iter()
                .filter_map(|l| self.by_line.get(l))
                .flatten()
                .filter_map(|&m| self.candidate(m, p)),
        );
        let best = self.refine_candidates(p, scratch, None);
        // Every other move that could reach below the least so far: a move is no nearer
        // than its box ([`MoveTree`]) nor than its capsules ([`Kept::capsule_bound`]).
        seen.clear();
        seen.extend(scratch.iter().map(|c| c.3));
        seen.sort_unstable();
        scratch.clear();
        let (radius, length) = (self.tool.radius(), self.tool.length());
        let start = best.map_or(limit, |b| b.0.min(limit));
        self.tree.search(p, start, |m, threshold| {
            if seen.binary_search(&m).is_ok() {
                return threshold;
            }
            let Some(kept) = self.kept[m as usize].as_ref() else {
                return threshold;
            };
            if kept.hull_bound(p, radius, length) >= threshold
                || kept.capsule_bound(p, radius, length) >= threshold
            {
                return threshold;
            }
            match self.candidate(m, p) {
                Some(c) => {
                    let least = c.1.0;
                    scratch.push(c);
                    threshold.min(least)
                }
                None => threshold,
            }
        });
        self.refine_candidates(p, scratch, best)
    }

    /// Move `m`'s candidate at `p`: its kept poses' signed distances, the least of them and a
    /// lower bound over the move (`None` where the machine cannot take its poses). Between
    /// consecutive kept poses no tool point moves by more than `D`, and the signed distance
    /// moves no more than the point: the interval's values are at least the mean of its
    /// ends' less `D/2`.
    fn candidate(&self, m: u32, p: &Point3) -> Option<Candidate> {
        let kept = self.kept[m as usize].as_ref()?;
        let f: [(Real, Vector3); KEPT + 1] =
            std::array::from_fn(|k| self.tool_distance(&kept.poses[k], p));
        let (k, s) = f
            .iter()
            .enumerate()
            .min_by(|a, b| a.1.0.total_cmp(&b.1.0))?;
        let bound = f
            .windows(2)
            .map(|w| 0.5 * (w[0].0 + w[1].0 - kept.step))
            .fold(Real::INFINITY, Real::min);
        Some((bound, *s, k, m))
    }

    /// The least of `best` and the candidates' values: least bound first, each candidate
    /// whose bound is below the least so far refined ([`Self::refine`]).
    fn refine_candidates(
        &self,
        p: &Point3,
        cands: &mut [Candidate],
        best: Option<(Real, Vector3)>,
    ) -> Option<(Real, Vector3)> {
        cands.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.3.cmp(&b.3)));
        let mut best = cands
            .iter()
            .map(|c| c.1)
            .chain(best)
            .min_by(|a, b| a.0.total_cmp(&b.0))?;
        for &(bound, s, k, m) in cands.iter() {
            if bound >= best.0 {
                break;
            }
            let r = self.refine(m as usize, k, s, p);
            if r.0 < best.0 {
                best = r;
            }
        }
        Some(best)
    }

    /// The tool's signed distance at `p` in pose `t`, with its outward normal (W).
    fn tool_distance(&self, t: &Isometry3, p: &Point3) -> (Real, Vector3) {
        let (d, n) = self.tool.signed_distance(&t.inverse_transform_point(p));
        (d, t.rotation * n)
    }

    /// The least signed distance of `p` from the tool on move `m` over the two intervals
    /// beside kept pose `k` (whose value is `fk`), by Brent's method (golden section with
    /// parabolic steps, until the tool moves less than [`DISTANCE_TOL`] across the bracket), with
    /// the tool's normal there.
    fn refine(&self, m: usize, k: usize, fk: (Real, Vector3), p: &Point3) -> (Real, Vector3) {
        let mv = &self.moves[m];
        let path = self.kept[m].as_ref().and_then(|k| k.path.as_ref());
        let at = |lambda: Real| {
            self.machine
                .pose(mv, path, lambda)
                .map_or((Real::INFINITY, Vector3::z()), |t| {
                    self.tool_distance(&t, p)
                })
        };
        let step = 1.0 / KEPT as Real;
        let x0 = k as Real * step;
        let (a, b) = ((x0 - step).max(0.0), (x0 + step).min(1.0));
        let tol = self.kept[m].as_ref().map_or(1e-12, |k| k.lambda_tol);
        brent(at, (a, b), (x0, fk), tol)
    }
}

/// A candidate move of [`NominalPath::swept_distance`]: the lower bound on its tool's
/// signed distance, its least kept sample (value and normal), that sample's index and the
/// move.
type Candidate = (Real, (Real, Vector3), usize, u32);

/// The buffers of [`NominalPath::nearest`], kept per thread: the candidate lines and moves
/// of each point, without an allocation a point (the colours read about 100 k points on
/// two threads, whose allocations would otherwise contend).
#[derive(Default)]
struct Scratch {
    lines: Vec<u32>,
    cands: Vec<Candidate>,
    /// The moves of the lines, sorted.
    seen: Vec<u32>,
}

thread_local! {
    static SCRATCH: std::cell::RefCell<Scratch> = std::cell::RefCell::new(Scratch::default());
}

/// How far (mm) a tool point may move within the bracket at which a move's refinement
/// stops: the distance found is within it of the least (exactly so where the least is at a
/// bracket end; far closer at a smooth minimum, where the distance is flat).
pub const DISTANCE_TOL: Real = 1e-6;

/// Most steps of a refinement (golden-section steps alone shrink the bracket by 0.618 a
/// step: 60 reach 3e-13 of it).
const BRENT_STEPS: usize = 60;

/// The least value of `f` over `[a, b]` found by Brent's method (Numerical Recipes' `brent`:
/// parabolic steps through the three best points, golden-section steps where a parabola
/// steps badly), starting from `x` with value `fx`, until the bracket is `tol` wide; `f`'s
/// value carries a payload (the normal) beside the number minimised.
fn brent<T: Copy>(
    f: impl Fn(Real) -> (Real, T),
    (mut a, mut b): (Real, Real),
    (x0, fx0): (Real, (Real, T)),
    tol: Real,
) -> (Real, T) {
    const CGOLD: Real = 0.381_966_011_250_105_1;
    let (mut x, mut w, mut v) = (x0, x0, x0);
    let mut best = fx0;
    let (mut fw, mut fv) = (fx0.0, fx0.0);
    let (mut d, mut e): (Real, Real) = (0.0, 0.0);
    for _ in 0..BRENT_STEPS {
        let xm = 0.5 * (a + b);
        let tol1 = tol * 0.5;
        let tol2 = 2.0 * tol1;
        if (x - xm).abs() <= tol2 - 0.5 * (b - a) {
            break;
        }
        let mut golden = true;
        if e.abs() > tol1 {
            // A parabola through x, w, v.
            let r = (x - w) * (best.0 - fv);
            let mut q = (x - v) * (best.0 - fw);
            let mut pp = (x - v) * q - (x - w) * r;
            q = 2.0 * (q - r);
            if q > 0.0 {
                pp = -pp;
            }
            q = q.abs();
            let etemp = e;
            e = d;
            if !(pp.abs() >= (0.5 * q * etemp).abs() || pp <= q * (a - x) || pp >= q * (b - x)) {
                d = pp / q;
                let u = x + d;
                if u - a < tol2 || b - u < tol2 {
                    d = tol1.copysign(xm - x);
                }
                golden = false;
            }
        }
        if golden {
            e = if x >= xm { a - x } else { b - x };
            d = CGOLD * e;
        }
        let u = if d.abs() >= tol1 {
            x + d
        } else {
            x + tol1.copysign(d)
        };
        let fu = f(u);
        if fu.0 <= best.0 {
            if u >= x {
                a = x;
            } else {
                b = x;
            }
            (v, fv) = (w, fw);
            (w, fw) = (x, best.0);
            (x, best) = (u, fu);
        } else {
            if u < x {
                a = u;
            } else {
                b = u;
            }
            if fu.0 <= fw || w == x {
                (v, fv) = (w, fw);
                (w, fw) = (u, fu.0);
            } else if fu.0 <= fv || v == x || v == w {
                (v, fv) = (u, fu.0);
            }
        }
    }
    best
}

/// The nominal part's surface as seen from a point: its signed distance and the outward
/// normal at its nearest point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Nearest {
    /// Signed distance (mm; + outside the part, − inside).
    pub distance: Real,
    /// The part's outward unit normal at the surface point nearest.
    pub normal: Vector3,
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::cutting::sweep::{Kinematics, SweepOptions, sweep_program};
    use crate::cutting::tool::ToolKind;
    use crate::machine::chain::trunnion_for_tests;
    use crate::nc::{AxisValues, MoveKind};
    use crate::progress::NoProgress;

    /// A five-axis cut and its nominal machine: the trunnion with its location errors
    /// cutting a 16 mm cube's side with a flat Ø6 mm end mill while C turns 5° a move through
    /// a turn, A swings ±5° (two periods) and Z descends 2 mm; 0.1 mm rays.
    pub(crate) struct FiveAxisCut {
        pub nominal: Chain,
        pub tool: Tool,
        pub moves: Vec<Move>,
        pub stock: Aabb,
        pub part: TriDexel,
    }

    pub(crate) fn five_axis_cut() -> FiveAxisCut {
        let chain = trunnion_for_tests();
        let tool = Tool::try_new(ToolKind::Flat, 6.0, 25.0).expect("valid");
        let at = |k: usize| {
            let f = k as Real / 72.0;
            AxisValues::from_array([
                0.0,
                -10.0,
                14.0 - 2.0 * f,
                5.0 * (std::f64::consts::TAU * 2.0 * f).sin(),
                0.0,
                360.0 * f,
            ])
        };
        let moves: Vec<Move> = (0..72)
            .map(|k| Move {
                kind: MoveKind::Linear,
                start: at(k),
                end: at(k + 1),
                feed_mm_per_min: Some(1000.0),
                line: k + 10,
            })
            .collect();
        let b = Aabb {
            min: Point3::new(-8.0, -8.0, 0.0),
            max: Point3::new(8.0, 8.0, 16.0),
        };
        let mut part = TriDexel::new_box(b, 0.1, 1e9).expect("fits");
        let opts = SweepOptions {
            rotary_step_bound_mm: 1e-4,
        };
        sweep_program(
            &mut part,
            Kinematics::Chain(&chain),
            &tool,
            &moves,
            &opts,
            &NoProgress,
        )
        .expect("cuts");
        FiveAxisCut {
            nominal: chain.nominal(),
            tool,
            moves,
            stock: b,
            part,
        }
    }

    impl FiveAxisCut {
        /// The tool's least signed distance at `v` over move `mv` on the nominal machine by
        /// brute force, an upper bound on the least: its poses at 400 steps, the least
        /// refined by ternary search.
        pub(crate) fn brute_move(&self, mv: &Move, v: &Point3) -> Real {
            let sd = |l: Real| {
                let t = self.nominal.w_from_t(&mv.point_at(l));
                self.tool.signed_distance(&t.inverse_transform_point(v)).0
            };
            let j = (0..=400)
                .min_by(|&a, &b| sd(a as Real / 4e2).total_cmp(&sd(b as Real / 4e2)))
                .expect("steps");
            let (mut lo, mut hi) = ((j.max(1) - 1) as Real / 4e2, (j + 1).min(400) as Real / 4e2);
            for _ in 0..60 {
                let (m1, m2) = (lo + (hi - lo) / 3.0, hi - (hi - lo) / 3.0);
                if sd(m1) <= sd(m2) {
                    hi = m2;
                } else {
                    lo = m1;
                }
            }
            sd(lo).min(sd(0.0)).min(sd(1.0))
        }

        /// The nominal part's signed distance at `v` by brute force (a lower bound: the
        /// swept volume's depth is an upper bound's negation): every move's
        /// [`Self::brute_move`] and the stock box's own distance.
        pub(crate) fn brute(&self, v: &Point3) -> Real {
            let least = self
                .moves
                .iter()
                .map(|mv| self.brute_move(mv, v))
                .fold(Real::INFINITY, Real::min);
            let to_box = [v.x + 8.0, 8.0 - v.x, v.y + 8.0, 8.0 - v.y, v.z, 16.0 - v.z]
                .into_iter()
                .fold(Real::INFINITY, Real::min);
            (-to_box).max(-least)
        }
    }

    /// The lines of the cut part's crossings around `p` that [`NominalPath::nearest`] reads
    /// first (its window and radius).
    fn lines_near(part: &TriDexel, p: &Point3) -> Vec<usize> {
        let radius2 = near_radius2(part);
        let mut lines = Vec::new();
        for g in part.grids() {
            g.for_each_crossing_near(p, NEAR, |q, c| {
                if (q - p).norm_squared() <= radius2 && c.line != 0 {
                    lines.push(c.line as usize);
                }
            });
        }
        lines
    }

    #[test]
    fn the_distance_is_the_brute_forces_where_the_deepest_move_tags_no_crossing_near() {
        // The five-axis cut along the stock's top edge (y = −8, z = 16), where the nominal
        // machine cuts the edge by micrometres more than the deviated one, and at every
        // twentieth vertex of the cut part's mesh: the nominal part's signed distance against
        // brute force (every move at 400 steps refined by ternary search, and the stock box)
        // to 1 µm, wherever the cut part has a crossing near.
        use crate::cutting::adaptive::{AdaptiveOptions, mesh_stock_adaptive};
        use rayon::prelude::*;
        let cut = five_axis_cut();
        let path = NominalPath::new(
            &cut.tool,
            NominalMachine::Chain(cut.nominal.clone()),
            NominalStock::boxed(cut.stock),
            &cut.moves,
            1e-4,
        );
        let (mesh, _) =
            mesh_stock_adaptive(&cut.part, &AdaptiveOptions::default()).expect("meshes");
        let points: Vec<Point3> = (0..125)
            .map(|i| Point3::new(-5.0 + i as Real * 0.008, -8.0, 16.0))
            .chain(mesh.vertices.iter().step_by(20).copied())
            .collect();
        // (point, got, want, whether the deepest nominal move's line tags a crossing near)
        let results: Vec<(Point3, Real, Real, bool)> = points
            .par_iter()
            .filter_map(|p| {
                let got = path.nearest(&cut.part, p)?.distance;
                let want = cut.brute(p);
                let deepest = cut
                    .moves
                    .iter()
                    .min_by(|a, b| cut.brute_move(a, p).total_cmp(&cut.brute_move(b, p)))
                    .expect("moves");
                let tagged = lines_near(&cut.part, p).contains(&deepest.line);
                (want.abs() < 0.5).then_some((*p, got, want, tagged))
            })
            .collect();
        for (p, got, want, _) in &results {
            assert!(
                (got - want).abs() < 1e-6,
                "at {p:?}: {got} mm, brute force {want}"
            );
        }
        // Not vacuous: hundreds of points, and at some the nominal machine's deepest move
        // there made none of the crossings around (the edge's).
        let untagged = results.iter().filter(|r| !r.3 && r.2 > 1e-4).count();
        assert!(
            results.len() > 500 && untagged >= 10,
            "{} points, {untagged} untagged",
            results.len()
        );
    }

    /// A closed mesh of the cylinder `c`: `n` sides, inscribed (its faces within
    /// `r·(1 − cos(π/n))` of the cylinder's surface), outward.
    fn cylinder_mesh(c: &Cylinder, n: usize) -> ClosedMesh {
        let a = c.axis().into_inner();
        let u = a
            .cross(&Vector3::x())
            .try_normalize(1e-6)
            .unwrap_or_else(|| a.cross(&Vector3::y()).normalize());
        let v = a.cross(&u);
        let ring = |k: usize, h: Real| {
            let t = std::f64::consts::TAU * k as Real / n as Real;
            c.base() + (u * t.cos() + v * t.sin()) * c.radius() + a * h
        };
        let mut vertices = vec![c.base(), c.base() + a * c.length()];
        for k in 0..n {
            vertices.push(ring(k, 0.0));
            vertices.push(ring(k, c.length()));
        }
        let lo = |k: usize| (2 + 2 * (k % n)) as u32;
        let hi = |k: usize| (3 + 2 * (k % n)) as u32;
        let mut triangles = Vec::new();
        for k in 0..n {
            triangles.push([0, lo(k + 1), lo(k)]);
            triangles.push([1, hi(k), hi(k + 1)]);
            triangles.push([lo(k), lo(k + 1), hi(k + 1)]);
            triangles.push([lo(k), hi(k + 1), hi(k)]);
        }
        ClosedMesh::try_new(vertices, triangles, std::path::Path::new("cylinder"), &[])
            .expect("closed")
    }

    #[test]
    fn the_stocks_distance_is_the_meshed_stocks() {
        // Box and cylinder stocks in closed form against the same solids as closed meshes,
        // whose distance parry computes (its nearest triangle, inside by pseudo-normals):
        // at points inside, outside and on both sides of edges, equal to rounding for the
        // box, within the meshing's sagitta for the cylinder; normals alike off the ties.
        use crate::cutting::shape::read_obj;
        use crate::cutting::shape::tests::cube_obj;
        use crate::math::CounterRng;
        let rng = CounterRng::new(7);
        let point = |i: u64, lo: Real, hi: Real| {
            Point3::from(Vector3::from_fn(|k, _| {
                lo + (hi - lo) * rng.uniform(i, k as u64)
            }))
        };
        let big = Aabb {
            min: Point3::new(-100.0, -100.0, -100.0),
            max: Point3::new(100.0, 100.0, 100.0),
        };
        // The box [0, 4]³.
        let cube = Aabb {
            min: Point3::origin(),
            max: Point3::new(4.0, 4.0, 4.0),
        };
        let boxed = NominalStock::boxed(cube);
        let meshed = NominalStock::mesh(
            big,
            &read_obj(&cube_obj(4.0, 2), std::path::Path::new("cube.obj")).expect("reads"),
        )
        .expect("parry takes it");
        let (mut inside, mut outside) = (0, 0);
        for i in 0..4000 {
            let p = point(i, -1.5, 5.5);
            let (a, b) = (boxed.nearest(&p), meshed.nearest(&p));
            assert!(
                (a.distance - b.distance).abs() < 1e-12,
                "{p:?}: {a:?} {b:?}"
            );
            // Off the ties between two faces (inside, equally near both).
            let faces = [p.x, 4.0 - p.x, p.y, 4.0 - p.y, p.z, 4.0 - p.z];
            let mut f = faces;
            f.sort_by(Real::total_cmp);
            if a.distance > 0.0 || f[1] - f[0] > 1e-9 {
                assert!((a.normal - b.normal).norm() < 1e-9, "{p:?}: {a:?} {b:?}");
            }
            inside += usize::from(a.distance < 0.0);
            outside += usize::from(a.distance > 0.0);
        }
        assert!(
            inside > 500 && outside > 2000,
            "{inside} inside, {outside} outside"
        );
        // A tilted cylinder, radius 5, length 12, within a box that does not clip it.
        let c = Cylinder::try_new(
            Point3::new(1.0, -2.0, 3.0),
            Vector3::new(0.3, -0.2, 1.0),
            5.0,
            12.0,
        )
        .expect("valid");
        let n = 2048;
        let sagitta = 5.0 * (1.0 - (std::f64::consts::PI / n as Real).cos());
        let closed = NominalStock::cylinder(big, c);
        let meshed = NominalStock::mesh(big, &cylinder_mesh(&c, n)).expect("parry takes it");
        let (mut inside, mut outside) = (0, 0);
        for i in 0..4000 {
            let p = point(i + 10_000, -4.0, 15.0);
            let (a, b) = (closed.nearest(&p), meshed.nearest(&p));
            assert!(
                (a.distance - b.distance).abs() <= sagitta * 1.01,
                "{p:?}: {a:?} {b:?}"
            );
            if a.distance.abs() > 0.05 && a.distance > 0.0 {
                assert!((a.normal - b.normal).norm() < 0.05, "{p:?}: {a:?} {b:?}");
            }
            inside += usize::from(a.distance < 0.0);
            outside += usize::from(a.distance > 0.0);
        }
        assert!(
            inside > 200 && outside > 2000,
            "{inside} inside, {outside} outside"
        );
        // Clipped by its box: the box's face where it is nearer.
        let clip = Aabb {
            min: Point3::new(-100.0, -100.0, -100.0),
            max: Point3::new(100.0, 100.0, 8.0),
        };
        let clipped = NominalStock::cylinder(clip, c).nearest(&Point3::new(1.5, -2.0, 7.9));
        assert!((clipped.distance + 0.1).abs() < 1e-12, "{clipped:?}");
        assert_eq!(clipped.normal, Vector3::z());
    }
}
