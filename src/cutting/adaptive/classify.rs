//! Classification of a lattice block: empty, one plane, two planes meeting at a sharp edge,
//! or a single fine cell; the root blocks that hold any surface and the octree grown from
//! them.
//!
//! **Invariant:** the sign test is exact: a block is a plane or edge leaf only if every
//! lattice point of its closed box is on the side its plane(s) predict.

use super::*;

// ---------------------------------------------------------------------------------------
// Classification.

#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Plane {
    pub(super) n: Vector3,
    pub(super) d: Real,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Kind {
    Empty,
    Planar(Plane),
    /// Two planes; `true`: material where both are inside (a convex edge).
    Edge(Plane, Plane, bool),
    Fine,
}

/// Where a leaf reads the signs of the lattice points on its faces; every source gives the
/// lattice's own signs, so two leaves sharing a face see the same.
pub(super) enum Signs<'a> {
    /// A planar or edge leaf: its plane(s), with the arithmetic of [`predicted_mask`]
    /// (equal to the lattice's signs by the classification's test). `k0`: the leaf's lowest
    /// lattice k, `s` its size.
    Predict(&'a Kind, isize, usize),
    /// A single cell at `o`: its four column words (2 bits each), column (a, b) at a + 2b.
    Cell([isize; 3], [u64; 4]),
}

impl Signs<'_> {
    /// Column word over the leaf's k range (bit t: k0 + t) of lattice column (i, j).
    pub(super) fn column(&self, lat: &Lat, i: isize, j: isize) -> (u64, isize) {
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

    /// Whether lattice point (i, j, k) of the leaf is inside: bit `k − k0` of
    /// [`Self::column`], the plane(s) evaluated at that point alone.
    fn inside(&self, lat: &Lat, i: isize, j: isize, k: isize) -> bool {
        match self {
            Signs::Predict(kind, k0, _) => {
                let t = k - *k0;
                let m = |pl: &Plane| {
                    let x = lat.pos([i, j, *k0]);
                    plane_inside(pl.n.dot(&x.coords) - pl.d, pl.n.z * lat.f.h[2], t as usize)
                };
                match kind {
                    Kind::Planar(p) => m(p),
                    Kind::Edge(p, q, true) => m(p) && m(q),
                    Kind::Edge(p, q, false) => m(p) || m(q),
                    Kind::Empty | Kind::Fine => false,
                }
            }
            Signs::Cell(..) => {
                let (m, k0) = self.column(lat, i, j);
                m >> (k - k0) & 1 == 1
            }
        }
    }

    /// Whether the face square (axis `n`, lower point `f0`, size `q`) certainly has one sign
    /// throughout: each plane is at least 1e-9 mm from all four corners on one side.
    pub(super) fn uniform(&self, lat: &Lat, n: usize, f0: [isize; 3], q: usize) -> bool {
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

    /// The signs of the face square's (q + 1)² points, point (a, b) at a + b·(q + 1), into
    /// `out`.
    pub(super) fn face(&self, lat: &Lat, n: usize, f0: [isize; 3], q: usize, out: &mut Vec<bool>) {
        let (u, v) = ((n + 1) % 3, (n + 2) % 3);
        let w = q + 1;
        out.clear();
        out.resize(w * w, false);
        let bit = |m: u64, k0: isize, k: isize| m >> (k - k0) & 1 == 1;
        match n {
            // z face: one point per column.
            2 => {
                for b in 0..w {
                    for a in 0..w {
                        let p = point(n, f0[n], f0[u] + a as isize, f0[v] + b as isize);
                        out[a + b * w] = self.inside(lat, p[0], p[1], p[2]);
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
    }
}

/// A node of a root block's octree, in 8 bytes: a planar or edge leaf's planes are kept
/// beside the nodes ([`Tree::planes`]), so a walk down the tree reads a few cache lines.
#[derive(Clone, Copy, Debug)]
pub(super) enum Node {
    Empty,
    Fine,
    /// A planar leaf, its plane at this index of the tree's planes.
    Planar(u32),
    /// An edge leaf, its two planes at this index of the tree's planes and the next
    /// ([`Kind::Edge`], with its flag).
    Edge(u32, bool),
    /// Children at these eight consecutive nodes (child c at offset (c & 1, c >> 1 & 1,
    /// c >> 2 & 1) halves).
    Split(u32),
}

pub(super) struct Tree {
    /// Index of the root block (row-major x, y, z).
    pub(super) root: usize,
    pub(super) origin: [isize; 3],
    pub(super) nodes: Vec<Node>,
    /// The planes of the planar and edge leaves ([`Node::Planar`], [`Node::Edge`]): one
    /// or two each, not a [`Kind`] each (which has room for two).
    pub(super) planes: Vec<Plane>,
}

impl Tree {
    /// The kind of leaf `node`; None for a split node.
    pub(super) fn leaf(&self, node: usize) -> Option<Kind> {
        match self.nodes[node] {
            Node::Empty => Some(Kind::Empty),
            Node::Fine => Some(Kind::Fine),
            Node::Planar(k) => Some(Kind::Planar(self.planes[k as usize])),
            Node::Edge(k, convex) => Some(Kind::Edge(
                self.planes[k as usize],
                self.planes[k as usize + 1],
                convex,
            )),
            Node::Split(_) => None,
        }
    }
}

/// Which root blocks hold lattice points of both signs, per root block (row-major x, y, z):
/// one pass over each z ray's segment ends instead of a column word per block.
pub(super) fn occupied_roots(lat: &Lat, rn: [usize; 3]) -> Vec<bool> {
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

/// The column words of a block (origin `o`, size `s`) inside the root block whose column
/// words ([`Lat::column`] over the root's `ROOT + 1` points, from its origin `r0`) are
/// `root`: `(s + 1)²` columns, column (a, b) at `a + b·(s + 1)`. A block's k range lies in
/// its root's, so its words are the root's shifted down to its first k and cut to `s + 1`
/// bits: the same words [`Lat::column`] reads, without reading the rays again.
fn block_masks(root: &[u64], r0: [isize; 3], o: [isize; 3], s: usize, m: &mut Vec<u64>) {
    let w = ROOT + 1;
    let (di, dj) = ((o[0] - r0[0]) as usize, (o[1] - r0[1]) as usize);
    let shift = (o[2] - r0[2]) as usize;
    let keep = bit_range(0, s);
    m.clear();
    for b in 0..=s {
        let row = &root[(dj + b) * w + di..][..=s];
        m.extend(row.iter().map(|&c| c >> shift & keep));
    }
}

/// Whether A + B·t < 0: bit `t` (0 ≤ t ≤ s) of [`plane_mask`]`(a, b, s)`, which holds the
/// points where that holds (A + B·t is monotone in t, rounding included), and all or none
/// of them as at t = 0 where the crossing is not finite.
pub(super) fn plane_inside(a: Real, b: Real, t: usize) -> bool {
    let pred = |t: usize| a + b * (t as Real) < 0.0;
    if b == 0.0 || !(a / b).is_finite() {
        return pred(0);
    }
    pred(t)
}

/// Bits t = 0..=s where A + B·t < 0 (a plane's inside along a column).
pub(super) fn plane_mask(a: Real, b: Real, s: usize) -> u64 {
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
fn fit_plane(hits: &[Vtx], group: &[u32]) -> (Plane, Real) {
    let each = || group.iter().map(|&i| &hits[i as usize]);
    let n = each()
        .fold(Vector3::zeros(), |s, h| s + h.n)
        .try_normalize(0.0)
        .unwrap_or_else(Vector3::z);
    let d = each().map(|h| n.dot(&h.p.coords)).sum::<Real>() / group.len() as Real;
    let r = each()
        .map(|h| (n.dot(&h.p.coords) - d).abs())
        .fold(0.0, Real::max);
    (Plane { n, d }, r)
}

/// The working buffers of [`classify`], kept by the [`Grower`] from block to block: the
/// block's crossings and the two groups of their normals (indices into the crossings).
#[derive(Default)]
pub(super) struct ClassifyBuffers {
    hits: Vec<Vtx>,
    groups: [Vec<u32>; 2],
}

/// The leaf a block is, or None if it must split. Also returns the plane residual.
fn classify(
    lat: &Lat,
    masks: &[u64],
    (o, s): ([isize; 3], usize),
    tol: Real,
    bufs: &mut ClassifyBuffers,
) -> (Option<Kind>, Real) {
    let w = s + 1;
    let full = bit_range(0, s);
    if masks.iter().all(|&m| m == 0) || masks.iter().all(|&m| m == full) {
        return (Some(Kind::Empty), 0.0);
    }
    if s == 1 {
        return (Some(Kind::Fine), 0.0);
    }
    let ClassifyBuffers {
        hits,
        groups: [g0, g1],
    } = bufs;
    hits.clear();
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
    g0.clear();
    g1.clear();
    for (i, h) in hits.iter().enumerate() {
        if h.n.dot(&n0) >= cos {
            g0.push(i as u32);
        } else {
            match second {
                None => {
                    second = Some(h.n);
                    g1.push(i as u32);
                }
                Some(r) if h.n.dot(&r) >= cos => g1.push(i as u32),
                Some(_) => return (None, 0.0),
            }
        }
    }
    let (p, r0) = fit_plane(hits, g0);
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
    let (q, r1) = fit_plane(hits, g1);
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

pub(super) fn child_origin(o: [isize; 3], s: usize, c: usize) -> [isize; 3] {
    let h = (s / 2) as isize;
    [
        o[0] + (c & 1) as isize * h,
        o[1] + (c >> 1 & 1) as isize * h,
        o[2] + (c >> 2 & 1) as isize * h,
    ]
}

/// A tree's nodes and its planar and edge leaves' planes, as [`Grower`] grows them.
pub(super) type TreeParts<'t> = (&'t mut Vec<Node>, &'t mut Vec<Plane>);

/// Grows a root block's tree: classifies blocks, splitting until every part is a leaf;
/// keeps the largest plane residual of the leaves it made.
pub(super) struct Grower<'a, 'b> {
    lat: &'a Lat<'b>,
    tol: Real,
    pub(super) resid: Real,
    /// The root block's origin and its column words ([`Lat::column`] over its `ROOT + 1`
    /// points, column (a, b) at `a + b·(ROOT + 1)`), read once for all its blocks.
    r0: [isize; 3],
    root: Vec<u64>,
    /// The block being classified's column words.
    masks: Vec<u64>,
    bufs: ClassifyBuffers,
}

impl<'a, 'b> Grower<'a, 'b> {
    /// A grower of the tree of the root block at `r0`, with the plane tolerance `tol`.
    pub(super) fn new(lat: &'a Lat<'b>, tol: Real, r0: [isize; 3]) -> Self {
        let w = ROOT as isize;
        let root = (0..=w)
            .flat_map(|b| (0..=w).map(move |a| (a, b)))
            .map(|(a, b)| lat.column(r0[0] + a, r0[1] + b, r0[2], ROOT))
            .collect();
        Self {
            lat,
            tol,
            resid: 0.0,
            r0,
            root,
            masks: Vec::new(),
            bufs: ClassifyBuffers::default(),
        }
    }

    /// Classifies the block at `nodes[at]` (origin `o`, size `s`), a planar or edge leaf's
    /// planes appended to `planes`.
    pub(super) fn grow(&mut self, t: TreeParts, at: usize, o: [isize; 3], s: usize) {
        block_masks(&self.root, self.r0, o, s, &mut self.masks);
        let (kind, r) = classify(self.lat, &self.masks, (o, s), self.tol, &mut self.bufs);
        let (nodes, planes) = t;
        match kind {
            Some(k) => {
                let next = planes.len() as u32;
                nodes[at] = match k {
                    Kind::Empty => Node::Empty,
                    Kind::Fine => Node::Fine,
                    Kind::Planar(p) => {
                        planes.push(p);
                        Node::Planar(next)
                    }
                    Kind::Edge(p, q, convex) => {
                        planes.extend([p, q]);
                        Node::Edge(next, convex)
                    }
                };
                self.resid = self.resid.max(r);
            }
            None => self.split((nodes, planes), at, o, s),
        }
    }

    /// Makes `nodes[at]` a split node and grows its eight children.
    pub(super) fn split(&mut self, t: TreeParts, at: usize, o: [isize; 3], s: usize) {
        let (nodes, planes) = t;
        let first = nodes.len();
        nodes.extend([Node::Empty; 8]);
        nodes[at] = Node::Split(first as u32);
        for c in 0..8 {
            self.grow((nodes, planes), first + c, child_origin(o, s, c), s / 2);
        }
    }
}
