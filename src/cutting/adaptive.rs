//! Adaptive surface mesh of the cut stock: few, large triangles where the part is flat, a
//! sharp edge where two flat faces meet, and the dexel-resolution contour of [`super::mesh`]
//! only where neither describes the surface within a stated distance.
//!
//! **Why not simplify the fine mesh.** A 100 × 100 × 20 mm part at 0.05 mm has 23 million
//! dexel-resolution triangles, nearly all of them on flat faces; building them and
//! simplifying afterwards costs tens of CPU-seconds and gigabytes. Here flat regions are
//! recognised on the lattice itself, before any triangle exists.
//!
//! **Octree of lattice blocks.** The lattice of [`super::mesh`] (ray centres, grown by one
//! layer) is covered by root blocks of [`ROOT`]³ cells. A block is a leaf when
//! - no lattice point in its closed box differs in sign from another (*empty*);
//! - *planar*: the crossings on its sign-changing lattice edges all lie within
//!   `plane_tol_mm` of one plane (normal the mean of their normals, which agree within
//!   [`GROUP_DEGREES`]), and every lattice point's inside/outside (read on its z ray, as
//!   the fine mesher does) is what that plane's half-space predicts;
//! - *edge*: the same with two planes (two groups of normals), the points predicted by the
//!   intersection (a convex edge) or the union (a concave edge) of the two half-spaces;
//! - *fine*: a single cell, meshed as [`super::mesh`] does (marching-cubes polygons,
//!   fanned around the quadratic-error point where the crossings' normals disagree).
//!
//! Otherwise it splits into eight. The sign test is exact (every lattice point of the
//! closed box is compared, one column word at a time), so a leaf's surface crosses its
//! box as its plane(s) do.
//!
//! **Closed and oriented by construction.** The surface meets a block's faces in the
//! marching-cubes segments of the lattice points on them, which depend on those points
//! alone. Each face shared by two leaves is taken at the size of the smaller one (the
//! *minimal face*); both leaves build its polyline from the lattice data of that face only,
//! in one canonical direction (each takes it in its own sense), and simplify it the same way
//! (Douglas–Peucker within `chain_tol_mm`, ends and sharp corners kept). A leaf links the
//! polylines of its minimal faces into closed loops and triangulates each loop with edges
//! inside the block only. So every mesh edge on a block face is used once in each
//! direction, whatever the leaves decide inside. [`TriMesh::check_watertight`] verifies it.
//!
//! **Sharp edges are exact.** On a face segment whose two crossings' normals differ by more
//! than [`CORNER_DEGREES`] in the face, the point where their tangent lines meet is added
//! (when it lies in that cell face) — computed from the face's data, so both neighbours add
//! the same point. An edge leaf's loop then passes through the two points where the edge
//! line leaves the block; it is split there and each half fanned in its plane.
//!
//! **Bound.** Every crossing of a planar or edge leaf lies within `plane_tol_mm` of its
//! plane; the leaf's triangles lie within `plane_tol_mm` of it too and span the same
//! outline up to the `chain_tol_mm` of the simplified face polylines. So every crossing of
//! the tri-dexel lies within [`AdaptiveOptions::bound_mm`] = 2·plane_tol + chain_tol of the
//! mesh (tested against the exact crossings), and every mesh vertex is an exact crossing, a
//! tangent-line corner, or a fan centre within `plane_tol_mm` of its plane. A triangulation
//! that would fold (a triangle facing against its plane's normal) or a loop that is not as
//! expected makes the leaf split, in rounds, until none does; single cells never fail.
//!
//! **Determinism.** Vertices are named by lattice keys (the lattice edge of a crossing, the
//! cell face of a corner, the leaf of a fan centre) and numbered in key order at the end;
//! triangles are joined in root-block order: the mesh is identical for any thread count.
//!
//! **Invariant:** reads the stock only, as [`super::mesh`] does.

use super::mesh::{Frame, MeshError, Qef, TriMesh};
use crate::cutting::stock::TriDexel;
use crate::math::{Point3, Real, Vector3};
use rayon::prelude::*;

/// Root block edge in cells (a power of two; masks of `ROOT + 1` bits fit a word).
pub const ROOT: usize = 32;
/// Crossings whose normals agree within this angle (degrees) may share a plane.
pub const GROUP_DEGREES: Real = 20.0;
/// A face segment whose crossings' in-face normals differ by more than this (degrees) gets
/// the corner where their tangent lines meet.
pub const CORNER_DEGREES: Real = 30.0;

/// Tolerances of the adaptive mesh.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdaptiveOptions {
    /// How far a crossing may lie from its leaf's plane (mm).
    pub plane_tol_mm: Real,
    /// How far a dropped vertex of a face polyline may lie from the kept chord (mm).
    pub chain_tol_mm: Real,
}

impl Default for AdaptiveOptions {
    fn default() -> Self {
        Self {
            plane_tol_mm: 1.5e-3,
            chain_tol_mm: 1.5e-3,
        }
    }
}

impl AdaptiveOptions {
    /// The stated bound on the distance from any crossing of the tri-dexel to the mesh (mm).
    pub fn bound_mm(&self) -> Real {
        2.0 * self.plane_tol_mm + self.chain_tol_mm
    }
}

/// What the adaptive mesher made.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AdaptiveReport {
    /// Distance bound from every crossing to the mesh (mm), see [`AdaptiveOptions::bound_mm`].
    pub bound_mm: Real,
    /// Leaves meshed as one plane.
    pub planar_leaves: usize,
    /// Leaves meshed as two planes meeting at a sharp edge.
    pub edge_leaves: usize,
    /// Single cells meshed at dexel resolution.
    pub fine_cells: usize,
    /// Tangent-line corners added on face segments.
    pub corner_points: usize,
    /// Fine cells' polygons fanned around their quadratic-error point.
    pub feature_vertices: usize,
    /// Rounds of splitting leaves whose triangulation failed its checks.
    pub split_rounds: usize,
    /// Largest distance of a crossing from its leaf's plane (mm).
    pub max_plane_residual_mm: Real,
}

// ---------------------------------------------------------------------------------------
// Vertex keys: 2-bit tag, then fields. Crossings: axis and lattice point; corners: face
// axis, slot and the cell face's lower lattice point; fan centres: tree, node, piece.

type Key = u128;
const TAG_CORNER: Key = 1 << 126;
const TAG_LOCAL: Key = 2 << 126;

fn point_bits(p: [isize; 3]) -> Key {
    p.iter()
        .fold(0, |acc, &c| acc << 32 | (c + 1) as u32 as Key)
}

fn crossing_key(axis: usize, p: [isize; 3]) -> Key {
    (axis as Key) << 96 | point_bits(p)
}

fn corner_key(n: usize, slot: usize, p: [isize; 3]) -> Key {
    TAG_CORNER | (n as Key) << 96 | (slot as Key) << 98 | point_bits(p)
}

fn local_key(tree: usize, node: usize, piece: usize) -> Key {
    TAG_LOCAL | (tree as Key) << 64 | (node as Key) << 32 | piece as Key
}

#[derive(Clone, Copy, Debug)]
struct Vtx {
    key: Key,
    p: Point3,
    n: Vector3,
    corner: bool,
}

// ---------------------------------------------------------------------------------------
// The lattice read from the z rays, a column word at a time.

struct Lat<'a> {
    f: Frame<'a>,
}

/// Bits `lo..=hi` set (hi − lo ≤ 63).
fn bit_range(lo: usize, hi: usize) -> u64 {
    let w = hi - lo + 1;
    (if w >= 64 { u64::MAX } else { (1u64 << w) - 1 }) << lo
}

fn point(n: usize, c: isize, u: isize, v: isize) -> [isize; 3] {
    let mut p = [0; 3];
    p[n] = c;
    p[(n + 1) % 3] = u;
    p[(n + 2) % 3] = v;
    p
}

impl Lat<'_> {
    fn pos(&self, p: [isize; 3]) -> Point3 {
        Point3::new(
            self.f.coord(0, p[0]),
            self.f.coord(1, p[1]),
            self.f.coord(2, p[2]),
        )
    }

    /// The first lattice k whose z is at or above `t`.
    fn first_at_or_above(&self, t: Real) -> isize {
        let nz = self.f.n[2] as isize;
        let g = ((t - self.f.o[2]) / self.f.h[2]).ceil();
        let mut k = if g.is_finite() {
            (g.clamp(-2.0, (nz + 2) as Real)) as isize
        } else {
            0
        };
        while self.f.coord(2, k - 1) >= t && k > -2 {
            k -= 1;
        }
        while self.f.coord(2, k) < t && k < nz + 2 {
            k += 1;
        }
        k
    }

    /// Bit `t` (0 ≤ t ≤ s ≤ 63): lattice point (i, j, k0 + t) is inside, read on its z ray
    /// (lo ≤ z < hi; points off the rays or outside 0 ≤ k < nz are outside), as
    /// [`super::mesh`] reads it.
    fn column(&self, i: isize, j: isize, k0: isize, s: usize) -> u64 {
        let [nx, ny, nz] = self.f.n;
        if i < 0 || j < 0 || i >= nx as isize || j >= ny as isize {
            return 0;
        }
        let klo = k0.max(0);
        let khi = (k0 + s as isize).min(nz as isize - 1);
        if klo > khi {
            return 0;
        }
        let mut m = 0;
        for seg in self.f.stock.grids()[2].ray(i as usize, j as usize) {
            let a = self.first_at_or_above(seg.lo.t).max(klo);
            let b = (self.first_at_or_above(seg.hi.t) - 1).min(khi);
            if a <= b {
                m |= bit_range((a - k0) as usize, (b - k0) as usize);
            }
        }
        m
    }

    fn crossing(&self, axis: usize, p: [isize; 3], inside_low: bool) -> (Vtx, bool) {
        let (q, n, found) = self.f.crossing(axis, p, inside_low);
        (
            Vtx {
                key: crossing_key(axis, p),
                p: q,
                n,
                corner: false,
            },
            found,
        )
    }
}

// ---------------------------------------------------------------------------------------
// Classification.

#[derive(Clone, Copy, Debug, PartialEq)]
struct Plane {
    n: Vector3,
    d: Real,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Kind {
    Empty,
    Planar(Plane),
    /// Two planes; `true`: material where both are inside (a convex edge).
    Edge(Plane, Plane, bool),
    Fine,
}

/// Where a leaf reads the signs of the lattice points on its faces; every source gives the
/// lattice's own signs, so two leaves sharing a face see the same.
enum Signs<'a> {
    /// A planar or edge leaf: its plane(s), with the arithmetic of [`predicted_mask`]
    /// (equal to the lattice's signs by the classification's test). `k0`: the leaf's lowest
    /// lattice k, `s` its size.
    Predict(&'a Kind, isize, usize),
    /// A single cell at `o`: its four column words (2 bits each), column (a, b) at a + 2b.
    Cell([isize; 3], [u64; 4]),
}

impl Signs<'_> {
    /// Column word over the leaf's k range (bit t: k0 + t) of lattice column (i, j).
    fn column(&self, lat: &Lat, i: isize, j: isize) -> (u64, isize) {
        match self {
            Signs::Predict(kind, k0, s) => {
                let m = |pl: &Plane| {
                    let x = lat.pos([i, j, *k0]);
                    plane_mask(pl.n.dot(&x.coords) - pl.d, pl.n.z * lat.f.h[2], *s)
                };
                let w = match kind {
                    Kind::Planar(p) => m(p),
                    Kind::Edge(p, q, true) => m(p) & m(q),
                    Kind::Edge(p, q, false) => m(p) | m(q),
                    Kind::Empty | Kind::Fine => 0,
                };
                (w, *k0)
            }
            Signs::Cell(o, m) => (m[(i - o[0]) as usize | ((j - o[1]) as usize) << 1], o[2]),
        }
    }

    /// Whether the face square (axis `n`, lower point `f0`, size `q`) certainly has one sign
    /// throughout: each plane is at least 1e-9 mm from all four corners on one side.
    fn uniform(&self, lat: &Lat, n: usize, f0: [isize; 3], q: usize) -> bool {
        let Signs::Predict(kind, _, _) = self else {
            return false;
        };
        let (u, v) = ((n + 1) % 3, (n + 2) % 3);
        let q = q as isize;
        let side = |pl: &Plane| {
            let vals = [(0, 0), (q, 0), (0, q), (q, q)].map(|(a, b)| {
                let x = lat.pos(point(n, f0[n], f0[u] + a, f0[v] + b));
                pl.n.dot(&x.coords) - pl.d
            });
            vals.iter().all(|&x| x > 1e-9) || vals.iter().all(|&x| x < -1e-9)
        };
        match kind {
            Kind::Planar(p) => side(p),
            Kind::Edge(p, q, _) => side(p) && side(q),
            Kind::Empty | Kind::Fine => true,
        }
    }

    /// The signs of the face square's (q + 1)² points, point (a, b) at a + b·(q + 1).
    fn face(&self, lat: &Lat, n: usize, f0: [isize; 3], q: usize) -> Vec<bool> {
        let (u, v) = ((n + 1) % 3, (n + 2) % 3);
        let w = q + 1;
        let mut out = vec![false; w * w];
        let bit = |m: u64, k0: isize, k: isize| m >> (k - k0) & 1 == 1;
        match n {
            // z face: one point per column.
            2 => {
                for b in 0..w {
                    for a in 0..w {
                        let p = point(n, f0[n], f0[u] + a as isize, f0[v] + b as isize);
                        let (m, k0) = self.column(lat, p[0], p[1]);
                        out[a + b * w] = bit(m, k0, p[2]);
                    }
                }
            }
            // x face (u = y, v = z) or y face (u = z, v = x): one column per y or per x.
            _ => {
                let along = if n == 0 { u } else { v };
                for c in 0..w {
                    let mut p = f0;
                    p[along] += c as isize;
                    let (m, k0) = self.column(lat, p[0], p[1]);
                    for t in 0..w {
                        let k = f0[2] + t as isize;
                        let (a, b) = if n == 0 { (c, t) } else { (t, c) };
                        out[a + b * w] = bit(m, k0, k);
                    }
                }
            }
        }
        out
    }
}

#[derive(Clone, Copy, Debug)]
enum Node {
    Leaf(Kind),
    /// Children at these eight consecutive nodes (child c at offset (c & 1, c >> 1 & 1,
    /// c >> 2 & 1) halves).
    Split(u32),
}

struct Tree {
    /// Index of the root block (row-major x, y, z).
    root: usize,
    origin: [isize; 3],
    nodes: Vec<Node>,
}

/// Which root blocks hold lattice points of both signs, per root block (row-major x, y, z):
/// one pass over each z ray's segment ends instead of a column word per block.
fn occupied_roots(lat: &Lat, rn: [usize; 3]) -> Vec<bool> {
    let nz = lat.f.n[2] as isize;
    let rows: Vec<Vec<bool>> = (0..rn[0] * rn[1])
        .into_par_iter()
        .map(|r| {
            let o = [
                (r % rn[0] * ROOT) as isize - 1,
                (r / rn[0] * ROOT) as isize - 1,
            ];
            // Per z block: the sign first seen, and whether two signs were seen.
            let mut first: Vec<Option<bool>> = vec![None; rn[2]];
            let mut mixed = vec![false; rn[2]];
            let mut ts: Vec<isize> = Vec::new();
            for b in 0..=ROOT as isize {
                for a in 0..=ROOT as isize {
                    let (i, j) = (o[0] + a, o[1] + b);
                    ts.clear();
                    if i >= 0 && j >= 0 && i < lat.f.n[0] as isize && j < lat.f.n[1] as isize {
                        for seg in lat.f.stock.grids()[2].ray(i as usize, j as usize) {
                            let ka = lat.first_at_or_above(seg.lo.t).max(0);
                            let kb = lat.first_at_or_above(seg.hi.t).min(nz);
                            if ka < kb {
                                ts.push(ka);
                                ts.push(kb);
                            }
                        }
                    }
                    for rz in 0..rn[2] {
                        let k0 = (rz * ROOT) as isize - 1;
                        let k1 = k0 + ROOT as isize;
                        // Transitions at T: points T − 1 and T differ.
                        if ts.iter().any(|&t| t > k0 && t <= k1) {
                            mixed[rz] = true;
                            continue;
                        }
                        let inside = ts.iter().filter(|&&t| t <= k0).count() % 2 == 1;
                        match first[rz] {
                            None => first[rz] = Some(inside),
                            Some(f) if f != inside => mixed[rz] = true,
                            Some(_) => {}
                        }
                    }
                }
            }
            mixed
        })
        .collect();
    let mut out = vec![false; rn[0] * rn[1] * rn[2]];
    for (r, mixed) in rows.into_iter().enumerate() {
        for (rz, m) in mixed.into_iter().enumerate() {
            out[rz * rn[0] * rn[1] + r] = m;
        }
    }
    out
}

/// The column words of a block: `(s + 1)²` columns, column (a, b) at `a + b·(s + 1)`.
fn block_masks(lat: &Lat, o: [isize; 3], s: usize) -> Vec<u64> {
    let mut m = Vec::with_capacity((s + 1) * (s + 1));
    for b in 0..=s as isize {
        for a in 0..=s as isize {
            m.push(lat.column(o[0] + a, o[1] + b, o[2], s));
        }
    }
    m
}

/// Bits t = 0..=s where A + B·t < 0 (a plane's inside along a column).
fn plane_mask(a: Real, b: Real, s: usize) -> u64 {
    let full = bit_range(0, s);
    let pred = |t: usize| a + b * (t as Real) < 0.0;
    if b == 0.0 || !(a / b).is_finite() {
        return if pred(0) { full } else { 0 };
    }
    let ts = -a / b;
    let top = (s + 1) as Real;
    if b > 0.0 {
        let mut c = ts.ceil().clamp(0.0, top) as usize;
        while c > 0 && !pred(c - 1) {
            c -= 1;
        }
        while c <= s && pred(c) {
            c += 1;
        }
        if c == 0 { 0 } else { bit_range(0, c - 1) }
    } else {
        let mut f = (ts.floor() + 1.0).clamp(0.0, top) as usize;
        while f > 0 && pred(f - 1) {
            f -= 1;
        }
        while f <= s && !pred(f) {
            f += 1;
        }
        if f > s { 0 } else { bit_range(f, s) }
    }
}

fn predicted_mask(lat: &Lat, p: &Plane, o: [isize; 3], a: isize, b: isize, s: usize) -> u64 {
    let x = lat.pos([o[0] + a, o[1] + b, o[2]]);
    let a0 = p.n.dot(&x.coords) - p.d;
    plane_mask(a0, p.n.z * lat.f.h[2], s)
}

/// Fits a plane to crossings: the mean normal, the mean offset, and the largest residual.
fn fit_plane(hits: &[&Vtx]) -> (Plane, Real) {
    let n = hits
        .iter()
        .fold(Vector3::zeros(), |s, h| s + h.n)
        .try_normalize(0.0)
        .unwrap_or_else(Vector3::z);
    let d = hits.iter().map(|h| n.dot(&h.p.coords)).sum::<Real>() / hits.len() as Real;
    let r = hits
        .iter()
        .map(|h| (n.dot(&h.p.coords) - d).abs())
        .fold(0.0, Real::max);
    (Plane { n, d }, r)
}

/// The leaf a block is, or None if it must split. Also returns the plane residual.
fn classify(lat: &Lat, o: [isize; 3], s: usize, tol: Real) -> (Option<Kind>, Real) {
    let masks = block_masks(lat, o, s);
    let w = s + 1;
    let full = bit_range(0, s);
    if masks.iter().all(|&m| m == 0) || masks.iter().all(|&m| m == full) {
        return (Some(Kind::Empty), 0.0);
    }
    if s == 1 {
        return (Some(Kind::Fine), 0.0);
    }
    let mut hits = Vec::new();
    let mut push = |axis: usize, p: [isize; 3], inside_low: bool| -> bool {
        let (v, found) = lat.crossing(axis, p, inside_low);
        hits.push(v);
        found
    };
    for b in 0..w {
        for a in 0..w {
            let m = masks[a + b * w];
            let mut ch = (m ^ (m >> 1)) & bit_range(0, s - 1);
            while ch != 0 {
                let t = ch.trailing_zeros() as usize;
                ch &= ch - 1;
                let p = [o[0] + a as isize, o[1] + b as isize, o[2] + t as isize];
                if !push(2, p, m >> t & 1 == 1) {
                    return (None, 0.0);
                }
            }
            for (axis, next) in [(0usize, (a + 1, b)), (1, (a, b + 1))] {
                if next.0 > s || next.1 > s {
                    continue;
                }
                let m1 = masks[next.0 + next.1 * w];
                let mut ch = m ^ m1;
                while ch != 0 {
                    let t = ch.trailing_zeros() as usize;
                    ch &= ch - 1;
                    let p = [o[0] + a as isize, o[1] + b as isize, o[2] + t as isize];
                    if !push(axis, p, m >> t & 1 == 1) {
                        return (None, 0.0);
                    }
                }
            }
        }
    }
    let cos = GROUP_DEGREES.to_radians().cos();
    let n0 = hits[0].n;
    let mut second: Option<Vector3> = None;
    let (mut g0, mut g1) = (Vec::new(), Vec::new());
    for h in &hits {
        if h.n.dot(&n0) >= cos {
            g0.push(h);
        } else {
            match second {
                None => {
                    second = Some(h.n);
                    g1.push(h);
                }
                Some(r) if h.n.dot(&r) >= cos => g1.push(h),
                Some(_) => return (None, 0.0),
            }
        }
    }
    let (p, r0) = fit_plane(&g0);
    if r0 > tol {
        return (None, 0.0);
    }
    let matches = |kind: &Kind| {
        (0..w).all(|b| {
            (0..w).all(|a| {
                let (ai, bi) = (a as isize, b as isize);
                let pred = match kind {
                    Kind::Planar(p) => predicted_mask(lat, p, o, ai, bi, s),
                    Kind::Edge(p, q, convex) => {
                        let mp = predicted_mask(lat, p, o, ai, bi, s);
                        let mq = predicted_mask(lat, q, o, ai, bi, s);
                        if *convex { mp & mq } else { mp | mq }
                    }
                    Kind::Empty | Kind::Fine => return false,
                };
                pred == masks[a + b * w]
            })
        })
    };
    if g1.is_empty() {
        let k = Kind::Planar(p);
        return if matches(&k) {
            (Some(k), r0)
        } else {
            (None, 0.0)
        };
    }
    let (q, r1) = fit_plane(&g1);
    if r1 > tol {
        return (None, 0.0);
    }
    for convex in [true, false] {
        let k = Kind::Edge(p, q, convex);
        if matches(&k) {
            return (Some(k), r0.max(r1));
        }
    }
    (None, 0.0)
}

fn child_origin(o: [isize; 3], s: usize, c: usize) -> [isize; 3] {
    let h = (s / 2) as isize;
    [
        o[0] + (c & 1) as isize * h,
        o[1] + (c >> 1 & 1) as isize * h,
        o[2] + (c >> 2 & 1) as isize * h,
    ]
}

/// Grows a root block's tree: classifies blocks, splitting until every part is a leaf;
/// keeps the largest plane residual of the leaves it made.
struct Grower<'a, 'b> {
    lat: &'a Lat<'b>,
    tol: Real,
    resid: Real,
}

impl Grower<'_, '_> {
    /// Classifies the block at `nodes[at]` (origin `o`, size `s`).
    fn grow(&mut self, nodes: &mut Vec<Node>, at: usize, o: [isize; 3], s: usize) {
        let (kind, r) = classify(self.lat, o, s, self.tol);
        match kind {
            Some(k) => {
                nodes[at] = Node::Leaf(k);
                self.resid = self.resid.max(r);
            }
            None => self.split(nodes, at, o, s),
        }
    }

    /// Makes `nodes[at]` a split node and grows its eight children.
    fn split(&mut self, nodes: &mut Vec<Node>, at: usize, o: [isize; 3], s: usize) {
        let first = nodes.len();
        nodes.extend([Node::Leaf(Kind::Empty); 8]);
        nodes[at] = Node::Split(first as u32);
        for c in 0..8 {
            self.grow(nodes, first + c, child_origin(o, s, c), s / 2);
        }
    }
}

// ---------------------------------------------------------------------------------------
// The forest of root blocks and leaf lookup.

struct Forest<'a> {
    lat: Lat<'a>,
    /// Root blocks per axis.
    rn: [usize; 3],
    /// Tree index of each root block (row-major x, y, z), or None if it is empty.
    roots: Vec<Option<u32>>,
    trees: Vec<Tree>,
}

#[derive(Clone, Copy)]
struct LeafRef {
    tree: usize,
    node: usize,
    o: [isize; 3],
    s: usize,
    kind: Kind,
}

impl Forest<'_> {
    /// The leaf holding cell `c`; None outside the roots or in an empty root.
    fn leaf_at(&self, c: [isize; 3]) -> Option<LeafRef> {
        let mut r = [0usize; 3];
        for a in 0..3 {
            if c[a] < -1 {
                return None;
            }
            r[a] = (c[a] + 1) as usize / ROOT;
            if r[a] >= self.rn[a] {
                return None;
            }
        }
        let tree = self.roots[(r[2] * self.rn[1] + r[1]) * self.rn[0] + r[0]]? as usize;
        let t = &self.trees[tree];
        let (mut node, mut o, mut s) = (0usize, t.origin, ROOT);
        loop {
            match t.nodes[node] {
                Node::Leaf(kind) => {
                    return Some(LeafRef {
                        tree,
                        node,
                        o,
                        s,
                        kind,
                    });
                }
                Node::Split(first) => {
                    let h = (s / 2) as isize;
                    let ch = usize::from(c[0] - o[0] >= h)
                        | usize::from(c[1] - o[1] >= h) << 1
                        | usize::from(c[2] - o[2] >= h) << 2;
                    o = child_origin(o, s, ch);
                    s /= 2;
                    node = first as usize + ch;
                }
            }
        }
    }

    /// The minimal faces on one side of a leaf: (lower lattice point of the square, size).
    fn minimal_faces(
        &self,
        leaf: &LeafRef,
        n: usize,
        upper: bool,
        out: &mut Vec<([isize; 3], usize)>,
    ) {
        let (u, v) = ((n + 1) % 3, (n + 2) % 3);
        let c = leaf.o[n] + if upper { leaf.s as isize } else { 0 };
        let beyond = if upper { c } else { c - 1 };
        let mut stack = vec![(leaf.o[u], leaf.o[v], leaf.s)];
        while let Some((a, b, q)) = stack.pop() {
            let nb = self.leaf_at(point(n, beyond, a, b));
            if q == 1 || nb.is_none_or(|l| l.s >= q) {
                out.push((point(n, c, a, b), q));
            } else {
                let h = (q / 2) as isize;
                for (da, db) in [(0, 0), (h, 0), (0, h), (h, h)] {
                    stack.push((a + da, b + db, q / 2));
                }
            }
        }
        // Fixed order whatever the stack did.
        out.sort_unstable();
    }
}

// ---------------------------------------------------------------------------------------
// Face polylines.

/// A polyline of a minimal face in canonical direction (as the leaf below the face's plane
/// sees it); `closed`: a loop lying inside the face.
struct Chain {
    v: Vec<Vtx>,
    closed: bool,
}

/// The corner where the tangent lines of `a` and `b` meet in the face plane (axis `n`,
/// coordinate from the points), if the normals turn by more than [`CORNER_DEGREES`] there
/// and the corner lies inside the cell face `[lo, hi]` (in-face coordinates).
fn tangent_corner(n: usize, a: &Vtx, b: &Vtx, lo: [Real; 2], hi: [Real; 2]) -> Option<Point3> {
    let (u, v) = ((n + 1) % 3, (n + 2) % 3);
    let ta = [a.n[u], a.n[v]];
    let tb = [b.n[u], b.n[v]];
    let la = (ta[0] * ta[0] + ta[1] * ta[1]).sqrt();
    let lb = (tb[0] * tb[0] + tb[1] * tb[1]).sqrt();
    if la < 0.3 || lb < 0.3 {
        return None;
    }
    let (ta, tb) = ([ta[0] / la, ta[1] / la], [tb[0] / lb, tb[1] / lb]);
    if ta[0] * tb[0] + ta[1] * tb[1] > CORNER_DEGREES.to_radians().cos() {
        return None;
    }
    let det = ta[0] * tb[1] - ta[1] * tb[0];
    if det.abs() < 1e-6 {
        return None;
    }
    let ra = ta[0] * a.p[u] + ta[1] * a.p[v];
    let rb = tb[0] * b.p[u] + tb[1] * b.p[v];
    let x = [
        (ra * tb[1] - rb * ta[1]) / det,
        (ta[0] * rb - tb[0] * ra) / det,
    ];
    let margin = [(hi[0] - lo[0]) * 1e-6, (hi[1] - lo[1]) * 1e-6];
    for k in 0..2 {
        if !(x[k] > lo[k] + margin[k] && x[k] < hi[k] - margin[k]) {
            return None;
        }
    }
    let mut p = a.p;
    p[u] = x[0];
    p[v] = x[1];
    Some(p)
}

/// The oriented segments of one cell face (corners in cyclic order `cs`, signs `inside`):
/// (from edge, to edge, slot), canonical direction (seen from the cell below the plane).
fn cell_face_segments(inside: [bool; 4]) -> ([(usize, usize, usize); 2], usize) {
    // Edge k joins corners k and k + 1; midpoints and corners in face units.
    const MID: [[Real; 2]; 4] = [[0.5, 0.0], [1.0, 0.5], [0.5, 1.0], [0.0, 0.5]];
    const CORNER: [[Real; 2]; 4] = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]];
    let mut active = [0usize; 4];
    let mut n_active = 0;
    for k in 0..4 {
        if inside[k] != inside[(k + 1) % 4] {
            active[n_active] = k;
            n_active += 1;
        }
    }
    let mut segs = [(0, 0, 0); 2];
    let mut count = 0;
    let mut add = |a: usize, b: usize, c: usize, slot: usize| {
        let d = [MID[b][0] - MID[a][0], MID[b][1] - MID[a][1]];
        let w = [CORNER[c][0] - MID[a][0], CORNER[c][1] - MID[a][1]];
        let cross = d[0] * w[1] - d[1] * w[0];
        segs[count] = if cross < 0.0 {
            (a, b, slot)
        } else {
            (b, a, slot)
        };
        count += 1;
    };
    match n_active {
        2 => {
            let c = (0..4).find(|&c| inside[c]).unwrap_or(0);
            add(active[0], active[1], c, 0);
        }
        4 => {
            for (k, _) in inside.iter().enumerate().filter(|(_, i)| **i) {
                add((k + 3) % 4, k, k, k / 2);
            }
        }
        _ => {}
    }
    (segs, count)
}

impl Forest<'_> {
    /// The polylines of the minimal face with lower lattice point `f0` (axis `n`) and size
    /// `q`, from the signs `inside` gives for its lattice points (which must be the
    /// lattice's own). Simplified within `tol` when `q > 1`.
    fn face_chains(
        &self,
        n: usize,
        f0: [isize; 3],
        q: usize,
        signs: &Signs,
        tol: Real,
    ) -> (Vec<Chain>, usize) {
        let lat = &self.lat;
        if signs.uniform(lat, n, f0, q) {
            return (Vec::new(), 0);
        }
        let (u, v) = ((n + 1) % 3, (n + 2) % 3);
        let (c, u0, v0) = (f0[n], f0[u], f0[v]);
        let w = q + 1;
        let signs = signs.face(lat, n, f0, q);
        if signs.iter().all(|&x| x == signs[0]) {
            return (Vec::new(), 0);
        }
        // Segments: (from, corner, to).
        let mut segs: Vec<(Vtx, Option<Vtx>, Vtx)> = Vec::new();
        let mut corners = 0;
        for b in 0..q {
            for a in 0..q {
                let cs = [(a, b), (a + 1, b), (a + 1, b + 1), (a, b + 1)];
                let ins = cs.map(|(x, y)| signs[x + y * w]);
                if ins.iter().all(|&x| x == ins[0]) {
                    continue;
                }
                let (list, count) = cell_face_segments(ins);
                if count == 0 {
                    continue;
                }
                // Edge k: lower point and axis.
                let edge = |k: usize| -> (usize, [isize; 3], bool) {
                    let (x, y, axis) = match k {
                        0 => (a, b, u),
                        1 => (a + 1, b, v),
                        2 => (a, b + 1, u),
                        _ => (a, b, v),
                    };
                    let p = point(n, c, u0 + x as isize, v0 + y as isize);
                    (axis, p, signs[x + y * w])
                };
                let p00 = point(n, c, u0 + a as isize, v0 + b as isize);
                let lo = lat.pos(p00);
                let hi = lat.pos(point(n, c, u0 + a as isize + 1, v0 + b as isize + 1));
                for &(ea, eb, slot) in &list[..count] {
                    let (axa, pa, ia) = edge(ea);
                    let (axb, pb, ib) = edge(eb);
                    let (va, _) = lat.crossing(axa, pa, ia);
                    let (vb, _) = lat.crossing(axb, pb, ib);
                    let corner =
                        tangent_corner(n, &va, &vb, [lo[u], lo[v]], [hi[u], hi[v]]).map(|p| Vtx {
                            key: corner_key(n, slot, p00),
                            p,
                            n: Vector3::zeros(),
                            corner: true,
                        });
                    corners += usize::from(corner.is_some());
                    segs.push((va, corner, vb));
                }
            }
        }
        // Link into polylines.
        let mut by_from: Vec<(Key, usize)> =
            segs.iter().enumerate().map(|(i, s)| (s.0.key, i)).collect();
        by_from.sort_unstable();
        let mut tos: Vec<Key> = segs.iter().map(|s| s.2.key).collect();
        tos.sort_unstable();
        let next_of = |key: Key| -> Option<usize> {
            let i = by_from.partition_point(|x| x.0 < key);
            (i < by_from.len() && by_from[i].0 == key).then(|| by_from[i].1)
        };
        let mut used = vec![false; segs.len()];
        let mut chains = Vec::new();
        let follow = |start: usize, used: &mut Vec<bool>| -> Vec<Vtx> {
            let mut out = Vec::new();
            let mut i = start;
            loop {
                used[i] = true;
                let (a, corner, _) = &segs[i];
                out.push(*a);
                if let Some(cv) = corner {
                    out.push(*cv);
                }
                match next_of(segs[i].2.key) {
                    Some(j) if !used[j] => i = j,
                    _ => {
                        out.push(segs[i].2);
                        return out;
                    }
                }
            }
        };
        // Open polylines start where no segment ends.
        for (i, seg) in segs.iter().enumerate() {
            if tos.binary_search(&seg.0.key).is_err() {
                let v = follow(i, &mut used);
                chains.push(Chain { v, closed: false });
            }
        }
        for i in 0..segs.len() {
            if !used[i] {
                let mut v = follow(i, &mut used);
                // The walk ends back at its first vertex: drop the repeat.
                if v.len() > 1 && v[v.len() - 1].key == v[0].key {
                    v.pop();
                }
                chains.push(Chain { v, closed: true });
            }
        }
        if q > 1 {
            for ch in &mut chains {
                simplify(ch, tol);
            }
        }
        (chains, corners)
    }
}

fn dist_to_segment(p: &Point3, a: &Point3, b: &Point3) -> Real {
    let d = b - a;
    let l2 = d.norm_squared();
    let t = if l2 > 0.0 {
        ((p - a).dot(&d) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p - (a + d * t)).norm()
}

/// Douglas–Peucker within `tol`, keeping the ends (of an open polyline), corners, and for a
/// closed one its smallest key and the vertex farthest from it. Depends on the polyline
/// only, so both leaves of a face simplify it alike.
fn simplify(ch: &mut Chain, tol: Real) {
    let mut v = std::mem::take(&mut ch.v);
    if ch.closed {
        let first = (0..v.len()).min_by_key(|&i| v[i].key).unwrap_or(0);
        v.rotate_left(first);
        let v0 = v[0];
        v.push(v0);
    }
    let m = v.len();
    let mut keep = vec![false; m];
    keep[0] = true;
    keep[m - 1] = true;
    for (k, x) in v.iter().enumerate() {
        keep[k] |= x.corner;
    }
    if ch.closed && m > 2 {
        let far = (1..m - 1)
            .max_by(|&a, &b| {
                let da = (v[a].p - v[0].p).norm_squared();
                let db = (v[b].p - v[0].p).norm_squared();
                da.total_cmp(&db).then(b.cmp(&a))
            })
            .unwrap_or(1);
        keep[far] = true;
    }
    let anchors: Vec<usize> = (0..m).filter(|&k| keep[k]).collect();
    let mut stack: Vec<(usize, usize)> = anchors.windows(2).map(|w| (w[0], w[1])).collect();
    while let Some((a, b)) = stack.pop() {
        if b <= a + 1 {
            continue;
        }
        let (mut best, mut at) = (0.0, a);
        for k in a + 1..b {
            let d = dist_to_segment(&v[k].p, &v[a].p, &v[b].p);
            if d > best {
                best = d;
                at = k;
            }
        }
        if best > tol {
            keep[at] = true;
            stack.push((a, at));
            stack.push((at, b));
        }
    }
    if ch.closed {
        v.pop();
        keep.pop();
    }
    ch.v = v
        .into_iter()
        .zip(keep)
        .filter_map(|(x, k)| k.then_some(x))
        .collect();
}

// ---------------------------------------------------------------------------------------
// Leaves to triangles.

#[derive(Default)]
struct Out {
    tris: Vec<[Key; 3]>,
    verts: Vec<(Key, Point3)>,
    /// Leaves whose triangulation failed: node, origin, size.
    failed: Vec<(usize, [isize; 3], usize)>,
    planar: usize,
    edge: usize,
    fine: usize,
    corners: usize,
    features: usize,
}

/// Fans a polygon in a plane with normal `nrm`: from its first vertex if that gives no
/// degenerate or folded triangle, else around its centroid (key `centre`). None if
/// neither works.
fn fan_polygon(
    poly: &[Vtx],
    nrm: &Vector3,
    centre: Key,
) -> Option<(Vec<[Key; 3]>, Option<Point3>)> {
    let m = poly.len();
    if m < 3 {
        return None;
    }
    let good = |a: &Point3, b: &Point3, c: &Point3| {
        let x = (b - a).cross(&(c - a));
        let l = x.norm();
        l > 1e-12 && x.dot(nrm) > 0.5 * l
    };
    if (1..m - 1).all(|k| good(&poly[0].p, &poly[k].p, &poly[k + 1].p)) {
        let t = (1..m - 1)
            .map(|k| [poly[0].key, poly[k].key, poly[k + 1].key])
            .collect();
        return Some((t, None));
    }
    let c = Point3::from(poly.iter().fold(Vector3::zeros(), |s, x| s + x.p.coords) / m as Real);
    if (0..m).all(|k| good(&c, &poly[k].p, &poly[(k + 1) % m].p)) {
        let t = (0..m)
            .map(|k| [centre, poly[k].key, poly[(k + 1) % m].key])
            .collect();
        return Some((t, Some(c)));
    }
    None
}

impl Forest<'_> {
    /// The closed loops of a leaf's surface from the polylines of its minimal faces, each
    /// counter-clockwise about the outward normal. None if they do not close.
    fn loops(
        &self,
        leaf: &LeafRef,
        signs: &Signs,
        tol: Real,
        corners: &mut usize,
    ) -> Option<Vec<Vec<Vtx>>> {
        let mut open: Vec<Vec<Vtx>> = Vec::new();
        let mut loops = Vec::new();
        let mut faces = Vec::new();
        for n in 0..3 {
            for upper in [false, true] {
                faces.clear();
                self.minimal_faces(leaf, n, upper, &mut faces);
                for &(f0, q) in &faces {
                    let (chains, c) = self.face_chains(n, f0, q, signs, tol);
                    // A corner belongs to the face: count it once, from the leaf below.
                    if upper {
                        *corners += c;
                    }
                    for mut ch in chains {
                        if !upper {
                            ch.v.reverse();
                        }
                        if ch.closed {
                            loops.push(ch.v);
                        } else {
                            open.push(ch.v);
                        }
                    }
                }
            }
        }
        open.sort_unstable_by_key(|c| c[0].key);
        let mut used = vec![false; open.len()];
        for s in 0..open.len() {
            if used[s] {
                continue;
            }
            let start = open[s][0].key;
            let mut lp: Vec<Vtx> = Vec::new();
            let mut i = s;
            loop {
                used[i] = true;
                let c = &open[i];
                lp.extend_from_slice(&c[..c.len() - 1]);
                let end = c[c.len() - 1].key;
                if end == start {
                    break;
                }
                let j = open.partition_point(|c| c[0].key < end);
                if j >= open.len() || open[j][0].key != end || used[j] {
                    return None;
                }
                i = j;
            }
            loops.push(lp);
        }
        Some(loops)
    }

    fn mesh_leaf(&self, leaf: &LeafRef, tol: Real, plane_tol: Real, out: &mut Out) {
        match leaf.kind {
            Kind::Empty => {}
            Kind::Fine => self.mesh_cell(leaf, tol, out),
            Kind::Planar(_) | Kind::Edge(..) => {
                let signs = Signs::Predict(&leaf.kind, leaf.o[2], leaf.s);
                let mut corners = 0;
                let ok = self
                    .loops(leaf, &signs, tol, &mut corners)
                    .and_then(|loops| self.mesh_planes(leaf, &loops, plane_tol));
                match ok {
                    Some((tris, verts)) => {
                        out.tris.extend(tris);
                        out.verts.extend(verts);
                        out.corners += corners;
                        match leaf.kind {
                            Kind::Planar(_) => out.planar += 1,
                            _ => out.edge += 1,
                        }
                    }
                    None => out.failed.push((leaf.node, leaf.o, leaf.s)),
                }
            }
        }
    }

    #[allow(clippy::type_complexity)]
    fn mesh_planes(
        &self,
        leaf: &LeafRef,
        loops: &[Vec<Vtx>],
        plane_tol: Real,
    ) -> Option<(Vec<[Key; 3]>, Vec<(Key, Point3)>)> {
        let mut tris = Vec::new();
        let mut verts = Vec::new();
        let mut piece = 0;
        let mut emit = |poly: &[Vtx], nrm: &Vector3, tris: &mut Vec<[Key; 3]>| -> Option<()> {
            let centre = local_key(leaf.tree, leaf.node, piece);
            piece += 1;
            let (t, c) = fan_polygon(poly, nrm, centre)?;
            tris.extend(t);
            verts.extend(poly.iter().map(|x| (x.key, x.p)));
            if let Some(c) = c {
                verts.push((centre, c));
            }
            Some(())
        };
        match leaf.kind {
            Kind::Planar(p) => {
                for lp in loops {
                    if lp.iter().any(|x| x.corner) {
                        return None;
                    }
                    emit(lp, &p.n, &mut tris)?;
                }
            }
            Kind::Edge(p, q, _) => {
                if loops.len() != 1 {
                    return None;
                }
                let lp = &loops[0];
                let cs: Vec<usize> = (0..lp.len()).filter(|&k| lp[k].corner).collect();
                if cs.len() != 2 {
                    return None;
                }
                let (c1, c2) = (cs[0], cs[1]);
                let off = |pl: &Plane, x: &Vtx| (pl.n.dot(&x.p.coords) - pl.d).abs();
                // The corners (from the crossings' own tangents) must lie on both planes,
                // so the split line is the planes' edge and each half lies in its plane.
                if [c1, c2]
                    .iter()
                    .any(|&c| off(&p, &lp[c]) > plane_tol || off(&q, &lp[c]) > plane_tol)
                {
                    return None;
                }
                let a: Vec<Vtx> = lp[c1..=c2].to_vec();
                let b: Vec<Vtx> = lp[c2..].iter().chain(&lp[..=c1]).copied().collect();
                for half in [a, b] {
                    let probe = half.iter().find(|x| !x.corner)?;
                    let pl = if off(&p, probe) <= off(&q, probe) {
                        p
                    } else {
                        q
                    };
                    if half.iter().any(|x| off(&pl, x) > plane_tol) {
                        return None;
                    }
                    emit(&half, &pl.n, &mut tris)?;
                }
            }
            Kind::Empty | Kind::Fine => return None,
        }
        Some((tris, verts))
    }

    /// A single cell at dexel resolution, as [`super::mesh`] meshes it.
    fn mesh_cell(&self, leaf: &LeafRef, tol: Real, out: &mut Out) {
        let lat = &self.lat;
        let o = leaf.o;
        let mut m = [0u64; 4];
        for (q, mq) in m.iter_mut().enumerate() {
            *mq = lat.column(o[0] + (q & 1) as isize, o[1] + (q >> 1) as isize, o[2], 1);
        }
        let signs = Signs::Cell(o, m);
        let mut corners = 0;
        let Some(loops) = self.loops(leaf, &signs, tol, &mut corners) else {
            // Cannot happen for a single cell (its face segments always close); keep the
            // mesh closed by failing loudly in the report instead of guessing.
            out.failed.push((leaf.node, leaf.o, leaf.s));
            return;
        };
        out.fine += 1;
        out.corners += corners;
        let lo = lat.pos(o);
        let hi = lat.pos([o[0] + 1, o[1] + 1, o[2] + 1]);
        for (li, lp) in loops.iter().enumerate() {
            let mut qef = Qef::default();
            let mut any_corner = false;
            for x in lp {
                if x.corner {
                    any_corner = true;
                } else {
                    qef.add(&x.p, &x.n);
                }
            }
            out.verts.extend(lp.iter().map(|x| (x.key, x.p)));
            let feature = any_corner || qef.rank() >= 2;
            if !feature && lp.len() == 3 {
                out.tris.push([lp[0].key, lp[1].key, lp[2].key]);
                continue;
            }
            if !feature && lp.len() == 4 {
                let shares = |a: &Vtx, b: &Vtx| share_cell_face(a.key, b.key);
                let d02 = !shares(&lp[0], &lp[2]);
                let d13 = !shares(&lp[1], &lp[3]);
                if d02 || d13 {
                    let l02 = (lp[0].p - lp[2].p).norm_squared();
                    let l13 = (lp[1].p - lp[3].p).norm_squared();
                    let k = lp.iter().map(|x| x.key).collect::<Vec<_>>();
                    if d02 && (!d13 || l02 <= l13) {
                        out.tris.push([k[0], k[1], k[2]]);
                        out.tris.push([k[0], k[2], k[3]]);
                    } else {
                        out.tris.push([k[0], k[1], k[3]]);
                        out.tris.push([k[1], k[2], k[3]]);
                    }
                    continue;
                }
            }
            let centre = local_key(leaf.tree, leaf.node, li);
            out.features += 1;
            out.verts.push((centre, qef.solve(&lo, &hi)));
            for k in 0..lp.len() {
                out.tris
                    .push([centre, lp[k].key, lp[(k + 1) % lp.len()].key]);
            }
        }
    }
}

fn key_point(key: Key) -> [isize; 3] {
    let f = |s: u32| ((key >> s) as u32) as isize - 1;
    [f(64), f(32), f(0)]
}

/// Whether two crossing vertices of one cell lie on a common face of it.
fn share_cell_face(a: Key, b: Key) -> bool {
    let (aa, ab) = ((a >> 96 & 3) as usize, (b >> 96 & 3) as usize);
    let (pa, pb) = (key_point(a), key_point(b));
    (0..3).any(|m| m != aa && m != ab && pa[m] == pb[m])
}

// ---------------------------------------------------------------------------------------
// The mesher.

/// Meshes the boundary of the stock's material adaptively. See the module documentation
/// for the guarantees. Fails only if the mesh would need 2³² vertices or more, or (a
/// defect, never seen) if a single lattice cell's face segments did not close.
pub fn mesh_stock_adaptive(
    stock: &TriDexel,
    opts: &AdaptiveOptions,
) -> Result<(TriMesh, AdaptiveReport), MeshError> {
    let lat = Lat {
        f: Frame::of(stock),
    };
    let n = lat.f.n;
    // Cells run from −1 to n − 1 on each axis.
    let rn: [usize; 3] = std::array::from_fn(|a| (n[a] + 1).div_ceil(ROOT));
    let tol = opts.plane_tol_mm;
    let origin = |r: usize| -> [isize; 3] {
        let rx = r % rn[0];
        let ry = r / rn[0] % rn[1];
        let rz = r / (rn[0] * rn[1]);
        [rx, ry, rz].map(|x| (x * ROOT) as isize - 1)
    };
    let occupied = occupied_roots(&lat, rn);
    let grown: Vec<(Option<Tree>, Real)> = (0..rn[0] * rn[1] * rn[2])
        .into_par_iter()
        .map(|r| {
            if !occupied[r] {
                return (None, 0.0);
            }
            let o = origin(r);
            let mut nodes = vec![Node::Leaf(Kind::Empty)];
            let mut g = Grower {
                lat: &lat,
                tol,
                resid: 0.0,
            };
            g.grow(&mut nodes, 0, o, ROOT);
            let resid = g.resid;
            let empty = matches!(nodes[0], Node::Leaf(Kind::Empty));
            (
                (!empty).then_some(Tree {
                    root: r,
                    origin: o,
                    nodes,
                }),
                resid,
            )
        })
        .collect();
    let mut report = AdaptiveReport {
        bound_mm: opts.bound_mm(),
        ..AdaptiveReport::default()
    };
    let mut roots = Vec::with_capacity(grown.len());
    let mut trees = Vec::new();
    for (t, r) in grown {
        report.max_plane_residual_mm = report.max_plane_residual_mm.max(r);
        roots.push(t.map(|t| {
            trees.push(t);
            (trees.len() - 1) as u32
        }));
    }
    let mut forest = Forest {
        lat,
        rn,
        roots,
        trees,
    };
    // Mesh every tree; after a round that split leaves, mesh again the trees that split and
    // those sharing a root face with them (whose minimal faces may have changed).
    let mut outs: Vec<Option<Out>> = forest.trees.iter().map(|_| None).collect();
    loop {
        let f = &forest;
        let fresh: Vec<Option<Out>> = f
            .trees
            .par_iter()
            .enumerate()
            .zip(outs.par_iter())
            .map(|((ti, t), old)| {
                old.is_none()
                    .then(|| f.mesh_tree(ti, t, opts.chain_tol_mm, tol))
            })
            .collect();
        for (o, n) in outs.iter_mut().zip(fresh) {
            if n.is_some() {
                *o = n;
            }
        }
        let failed: Vec<Vec<(usize, [isize; 3], usize)>> = outs
            .iter()
            .map(|o| o.as_ref().map_or_else(Vec::new, |o| o.failed.clone()))
            .collect();
        if failed.iter().all(Vec::is_empty) {
            break;
        }
        // Every round splits at least one leaf larger than a cell, so this ends; a single
        // cell cannot fail (its face segments always close), but if one did it would fail
        // forever: stop instead.
        report.split_rounds += 1;
        let cell_failed = failed.iter().flatten().any(|&(_, _, s)| s == 1);
        if cell_failed {
            return Err(MeshError::Unresolved {
                what: "a single lattice cell whose face segments do not close",
            });
        }
        let lat = &forest.lat;
        let resid: Real = forest
            .trees
            .par_iter_mut()
            .zip(&failed)
            .map(|(t, nodes)| {
                let mut g = Grower {
                    lat,
                    tol,
                    resid: 0.0,
                };
                for &(node, o, s) in nodes {
                    g.split(&mut t.nodes, node, o, s);
                }
                g.resid
            })
            .reduce(|| 0.0, Real::max);
        report.max_plane_residual_mm = report.max_plane_residual_mm.max(resid);
        for (ti, nodes) in failed.iter().enumerate() {
            if nodes.is_empty() {
                continue;
            }
            outs[ti] = None;
            let r = forest.trees[ti].root;
            let rc = [r % rn[0], r / rn[0] % rn[1], r / (rn[0] * rn[1])];
            for axis in 0..3 {
                for step in [-1isize, 1] {
                    let c = rc[axis] as isize + step;
                    if c < 0 || c >= rn[axis] as isize {
                        continue;
                    }
                    let mut nc = rc;
                    nc[axis] = c as usize;
                    let nr = (nc[2] * rn[1] + nc[1]) * rn[0] + nc[0];
                    if let Some(nt) = forest.roots[nr] {
                        outs[nt as usize] = None;
                    }
                }
            }
        }
    }
    let outs: Vec<Out> = outs.into_iter().flatten().collect();
    // Number the vertices in key order and join the triangles in tree order.
    let mut verts: Vec<(Key, Point3)> = Vec::new();
    let mut tris: Vec<[Key; 3]> = Vec::new();
    for o in outs {
        verts.extend(o.verts);
        tris.extend(o.tris);
        report.planar_leaves += o.planar;
        report.edge_leaves += o.edge;
        report.fine_cells += o.fine;
        report.corner_points += o.corners;
        report.feature_vertices += o.features;
    }
    verts.par_sort_unstable_by_key(|v| v.0);
    verts.dedup_by_key(|v| v.0);
    if verts.len() >= u32::MAX as usize {
        return Err(MeshError::TooLarge {
            what: "vertices",
            count: verts.len(),
            format: "32-bit vertex indices",
        });
    }
    let index = |k: &Key| verts.partition_point(|v| v.0 < *k) as u32;
    let triangles: Vec<[u32; 3]> = tris.par_iter().map(|t| t.each_ref().map(index)).collect();
    Ok((
        TriMesh {
            vertices: verts.into_iter().map(|v| v.1).collect(),
            triangles,
        },
        report,
    ))
}

impl Forest<'_> {
    /// Meshes every leaf of tree `ti`, in node order.
    fn mesh_tree(&self, ti: usize, t: &Tree, tol: Real, plane_tol: Real) -> Out {
        let mut out = Out::default();
        let mut stack = vec![(0usize, t.origin, ROOT)];
        while let Some((node, o, s)) = stack.pop() {
            match t.nodes[node] {
                Node::Leaf(kind) => {
                    let leaf = LeafRef {
                        tree: ti,
                        node,
                        o,
                        s,
                        kind,
                    };
                    self.mesh_leaf(&leaf, tol, plane_tol, &mut out);
                }
                Node::Split(first) => {
                    for c in (0..8).rev() {
                        stack.push((first as usize + c, child_origin(o, s, c), s / 2));
                    }
                }
            }
        }
        // Each vertex is named by every leaf that uses it: keep one per tree (equal keys
        // carry equal positions), so the trees' outputs stay near the mesh's size.
        out.verts.sort_unstable_by_key(|v| v.0);
        out.verts.dedup_by_key(|v| v.0);
        out
    }
}

#[cfg(test)]
#[path = "../../benches/support/p1.rs"]
#[allow(
    clippy::duplicate_mod,
    reason = "benchmark P1's program is shared by the unit tests of sweep, zmap and adaptive"
)]
mod p1;

#[cfg(test)]
mod tests {
    use super::p1;
    use super::*;
    use crate::cutting::mesh::mesh_stock;
    use crate::cutting::tool::{Tool, ToolKind};
    use crate::math::UnitVector3;
    use parry3d_f64::query::PointQuery;

    use crate::cutting::mesh::test_parts::{
        STADIUM, closed, cut, cut_along, random_part, stadium_stages, stock,
    };

    fn adaptive(s: &TriDexel) -> (TriMesh, AdaptiveReport) {
        mesh_stock_adaptive(s, &AdaptiveOptions::default()).expect("meshes")
    }

    /// Largest distance to the mesh (parry3d's closest point, independent of the mesher)
    /// from the crossings the lattice resolves: those on sign-changing lattice edges, the
    /// crossing vertices of the dexel-resolution contour ([`mesh_stock`]). With `all`,
    /// from every crossing of every ray instead.
    fn worst_distance(s: &TriDexel, m: &TriMesh, all: bool) -> Real {
        let shape = parry3d_f64::shape::TriMesh::new(m.vertices.clone(), m.triangles.clone())
            .expect("a valid triangle mesh");
        let mut pts = Vec::new();
        if all {
            for g in s.grids() {
                g.for_each_crossing(|p, _| pts.push(p));
            }
        } else {
            let (fine, r) = mesh_stock(s).expect("meshes");
            pts.extend_from_slice(&fine.vertices[..r.crossing_vertices]);
        }
        let (d, p) = pts
            .par_iter()
            .map(|p| ((shape.project_local_point(p, false).point - p).norm(), *p))
            .reduce(
                || (0.0, Point3::origin()),
                |a, b| if b.0 > a.0 { b } else { a },
            );
        assert!(p.coords.iter().all(|c| c.is_finite()));
        d
    }

    #[test]
    fn a_box_is_twelve_triangles_worth_of_exact_planes() {
        let s = stock([4.0, 3.0, 2.0], 0.25);
        let (m, r) = adaptive(&s);
        assert_eq!(closed(&m), 2);
        // The faces and the sharp edges are exact: the volume is the box's.
        assert!(
            (m.signed_volume() - 24.0).abs() < 1e-9,
            "{}",
            m.signed_volume()
        );
        assert!((m.area() - 52.0).abs() < 1e-9, "{}", m.area());
        for p in &m.vertices {
            let on = (0..3).any(|k| p[k].abs() < 1e-9 || (p[k] - [4.0, 3.0, 2.0][k]).abs() < 1e-9);
            assert!(on, "{p:?}");
        }
        // The dexel-resolution contour has hundreds; here only the corner cells are fine.
        let (fine, _) = mesh_stock(&s).expect("meshes");
        assert!(
            m.triangles.len() * 3 < fine.triangles.len(),
            "{} vs {}",
            m.triangles.len(),
            fine.triangles.len()
        );
        assert!(r.planar_leaves > 0 && r.edge_leaves > 0, "{r:?}");
        assert!(worst_distance(&s, &m, true) < 1e-9);
    }

    #[test]
    fn pocket_groove_hole_and_slot_keep_their_topology_and_volume() {
        let stages = stadium_stages();
        let (m, rep) = adaptive(&stages[0].0);
        assert_eq!(closed(&m), 2);
        // Blind stadium pocket: box minus stadium area × depth. Flat faces and sharp edges
        // are exact; only the curved wall is replaced by planes within the bound.
        let (r, len, depth) = STADIUM;
        let exact = 500.0 - (2.0 * r * len + std::f64::consts::PI * r * r) * depth;
        let wall = 2.0 * (len + std::f64::consts::PI * r) * depth;
        let v = m.signed_volume();
        assert!((v - exact).abs() <= rep.bound_mm * wall, "{v} vs {exact}");
        // Then the ball groove, the through hole and the side slot: topology and bound.
        for (s, euler) in &stages {
            let (m, rep) = adaptive(s);
            assert_eq!(closed(&m), *euler);
            assert!(worst_distance(s, &m, false) <= rep.bound_mm + 1e-9);
        }
    }

    #[test]
    fn random_cuts_always_give_a_closed_oriented_mesh_within_the_bound() {
        // Thin walls, slivers, tiny islands, tilted tools: the topology guarantee holds for
        // any stock, and the bound for every crossing the lattice resolves.
        for case in 0..40u64 {
            let s = random_part(5, case, true);
            let (m, rep) = adaptive(&s);
            m.check_watertight()
                .unwrap_or_else(|e| panic!("case {case}: {e}"));
            assert!(
                m.signed_volume() > 0.0 || s.volume() == 0.0,
                "case {case}: outward"
            );
            let d = worst_distance(&s, &m, false);
            assert!(d <= rep.bound_mm + 1e-9, "case {case}: {d}");
        }
    }

    #[test]
    fn tilted_flat_faces_become_few_triangles_within_the_bound() {
        // A flat end mill tilted 30° about x, run along x: a sloping flat face and a
        // sloping wall, neither on a lattice direction.
        let mut s = stock([12.0, 10.0, 6.0], 0.1);
        let axis = Vector3::new(
            0.0,
            -(30.0f64.to_radians()).sin(),
            30.0f64.to_radians().cos(),
        );
        cut_along(
            &mut s,
            ToolKind::Flat,
            8.0,
            [-2.0, 5.0, 4.5],
            [14.0, 5.0, 4.5],
            axis,
        );
        let (m, rep) = adaptive(&s);
        assert_eq!(closed(&m), 2);
        let (fine, _) = mesh_stock(&s).expect("meshes");
        assert!(
            m.triangles.len() * 10 < fine.triangles.len(),
            "{} vs {}",
            m.triangles.len(),
            fine.triangles.len()
        );
        assert!(rep.planar_leaves > 0, "{rep:?}");
        assert!(worst_distance(&s, &m, false) <= rep.bound_mm + 1e-9);
        // The sloping face is exact: its vertices (crossings and corners) on the plane
        // n·x = n·(tip) through the tool's end face.
        let tip = Vector3::new(0.0, 5.0, 4.5);
        let n = UnitVector3::new_normalize(axis);
        let on_face = m
            .vertices
            .iter()
            .filter(|p| (n.dot(&(p.coords - tip))).abs() < 1e-9)
            .count();
        assert!(on_face >= 4, "{on_face}");
        // Volume against the dexel-resolution contour: equal within the bound over the area.
        let dv = (m.signed_volume() - fine.signed_volume()).abs();
        assert!(dv <= 0.01 * fine.area() * 0.1, "{dv}");
    }

    #[test]
    fn the_p1_pocket_is_small_closed_and_within_the_bound() {
        let mut s = TriDexel::new_box(p1::stock_box(), 0.2, 1e9).expect("fits");
        let tool = Tool::try_new(ToolKind::Flat, p1::TOOL_DIAMETER, 30.0).expect("valid");
        let opts = crate::cutting::sweep::SweepOptions {
            rotary_step_bound_mm: crate::math::tol::ROTARY_STEP_BOUND,
        };
        crate::cutting::sweep::sweep_program(
            &mut s,
            &crate::machine::chain::xyz_for_tests(),
            &tool,
            &p1::moves(),
            &opts,
            &crate::progress::NoProgress,
        )
        .expect("sweeps");
        let (m, rep) = adaptive(&s);
        assert_eq!(closed(&m), 2);
        // Removed volume: 1.5 mm × the 3 mm offset of the path polyline (docs/benchmarks.md),
        // within the bound over the pocket's walls and floor.
        let removed = 100.0 * 100.0 * 20.0 - m.signed_volume();
        let truth = 1.5 * p1::offset_area(3.0);
        assert!((removed - truth).abs() < 0.5, "{removed} vs {truth}");
        assert!(m.triangles.len() < 60_000, "{}", m.triangles.len());
        // Here every crossing of every ray is resolved by the lattice.
        assert!(worst_distance(&s, &m, true) <= rep.bound_mm + 1e-9);
    }

    #[test]
    fn the_mesh_is_identical_on_one_and_two_threads() {
        let mut s = stock([10.0, 8.0, 5.0], 0.1);
        cut(
            &mut s,
            ToolKind::Ball,
            3.0,
            [1.0, 2.0, 4.0],
            [9.0, 6.0, 3.0],
        );
        cut(
            &mut s,
            ToolKind::Flat,
            2.0,
            [2.0, 6.0, 3.5],
            [8.0, 6.0, 3.5],
        );
        let run = |threads| crate::math::in_pool(threads, || adaptive(&s));
        let (a, ra) = run(1);
        let (b, rb) = run(2);
        assert_eq!(a, b);
        assert_eq!(ra, rb);
    }

    #[test]
    fn plane_masks_match_the_points_one_by_one() {
        for (a, b) in [
            (-3.2, 0.1),
            (2.0, -0.25),
            (0.0, 1.0),
            (-1.0, 0.0),
            (5.0, 0.0),
            (-0.5, 1e-30),
            (7.5, -0.25),
        ] {
            for s in [1usize, 4, 32] {
                let m = plane_mask(a, b, s);
                for t in 0..=s {
                    assert_eq!(
                        m >> t & 1 == 1,
                        a + b * (t as Real) < 0.0,
                        "{a} {b} {s} {t}"
                    );
                }
                assert_eq!(m >> (s + 1), 0);
            }
        }
    }
}
