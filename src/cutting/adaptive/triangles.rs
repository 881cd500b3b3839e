//! Leaves to triangles: each leaf's face polylines linked into closed loops, fanned in its
//! plane(s) (an edge leaf's loop split where the edge leaves the block), fine cells as
//! the dexel-resolution mesher meshes them; every leaf of a tree in node order (a tree meshed
//! again after a split keeps the triangles of the leaves the split did not touch).
//!
//! **Invariant:** triangles only join vertices of the leaf's own loops and fan centres
//! inside its block, so every edge on a block face is used once in each direction.

use super::*;

// ---------------------------------------------------------------------------------------
// Leaves to triangles.

#[derive(Default)]
pub(super) struct Out {
    /// The triangles by their corners' keys, while the tree is meshed.
    pub(super) tris: Vec<[Key; 3]>,
    /// The vertices named by the tree's leaves, while the tree is meshed.
    pub(super) verts: Vec<(Key, Point3)>,
    /// The tree's vertices, one per key, in key order (once the tree is meshed; `verts` is
    /// then empty): their keys, and their points in the same order (apart, the pair's
    /// alignment padding is not kept while every tree's output waits to be joined).
    pub(super) keys: Vec<Key>,
    pub(super) points: Vec<Point3>,
    /// The triangles as indices into the tree's vertices (`keys`, `points`; once the tree
    /// is meshed, `tris` then empty): a quarter of their keys' size while every tree's
    /// output waits to be joined.
    pub(super) faces: Vec<[u32; 3]>,
    /// Leaves whose triangulation failed: node, origin, size.
    pub(super) failed: Vec<(usize, [isize; 3], usize)>,
    /// What each leaf added, in node order (every leaf but the empty ones, which add
    /// nothing, and those that failed), while leaves may still split: a tree meshed again
    /// keeps the triangles of the leaves no split touched ([`Reuse`]). Emptied once no leaf
    /// fails.
    pub(super) leaves: Vec<LeafOut>,
    /// The tree's node count when it was meshed: the nodes below it that are leaves now
    /// were those leaves then (a split leaf becomes a split node, its children added after).
    pub(super) nodes: usize,
    /// Whether `leaves` holds the record of every leaf that did not fail (a count too large
    /// for its field leaves the tree to be meshed again in full).
    pub(super) reusable: bool,
    pub(super) planar: usize,
    pub(super) edge: usize,
    pub(super) fine: usize,
    pub(super) corners: usize,
    pub(super) features: usize,
}

impl Out {
    /// Counts a leaf of `kind` meshed without failing (planar, edge or fine).
    fn count(&mut self, kind: &Kind) {
        match kind {
            Kind::Planar(_) => self.planar += 1,
            Kind::Edge(..) => self.edge += 1,
            Kind::Fine => self.fine += 1,
            Kind::Empty => {}
        }
    }
}

/// What one leaf added to its tree's output: its triangles (the next `tris` of the tree's
/// `faces`, in node order), its tangent-line corners and its feature points (4 bytes a
/// leaf while every tree's output waits).
#[derive(Clone, Copy, Debug)]
pub(super) struct LeafOut {
    tris: u16,
    corners: u8,
    features: u8,
}

impl LeafOut {
    /// The record of a leaf that added `tris` triangles, `corners` corners and `features`
    /// feature points; none where one does not fit its field.
    fn of(tris: usize, corners: usize, features: usize) -> Option<Self> {
        Some(Self {
            tris: tris.try_into().ok()?,
            corners: corners.try_into().ok()?,
            features: features.try_into().ok()?,
        })
    }
}

/// A tree meshed again after some of its leaves (or a neighbouring tree's leaves on their
/// common root face) split: its output before, and the boxes (origin, size) of the leaves
/// that split. A leaf's triangles depend on its own data and on the sizes of the leaves
/// across its faces only (its minimal faces), so a leaf whose closed box touches none of
/// those boxes triangulates as before: its triangles are taken from `old` instead, in
/// their place in node order, and the tree's output is the same as meshing every leaf.
pub(super) struct Reuse<'a> {
    pub(super) old: &'a Out,
    pub(super) split: &'a [([isize; 3], usize)],
}

impl Reuse<'_> {
    /// Whether the leaf at `o` of size `s` touches a leaf that split (closed boxes).
    fn touched(&self, o: [isize; 3], s: usize) -> bool {
        self.split
            .iter()
            .any(|&(d, ds)| (0..3).all(|a| o[a] <= d[a] + ds as isize && d[a] <= o[a] + s as isize))
    }
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

/// A leaf's closed loops, vertex by vertex (loop `k` is `v[ranges[k]]`), and the working
/// buffers that build them: one per thread, reused from leaf to leaf and tree to tree.
#[derive(Default)]
pub(super) struct Loops {
    v: Vec<Vtx>,
    ranges: Vec<std::ops::Range<usize>>,
    /// The face polylines' vertices and the polylines.
    pool: Vec<Vtx>,
    chains: Vec<Chain>,
    /// The open polylines (by their first key) and which are linked.
    open: Vec<Chain>,
    used: Vec<bool>,
    faces: Vec<([isize; 3], usize)>,
}

impl Loops {
    fn len(&self) -> usize {
        self.ranges.len()
    }

    fn get(&self, k: usize) -> &[Vtx] {
        &self.v[self.ranges[k].clone()]
    }

    fn iter(&self) -> impl Iterator<Item = &[Vtx]> {
        self.ranges.iter().map(|r| &self.v[r.clone()])
    }

    /// Appends the pool's vertices `r` as a loop.
    fn push(&mut self, r: std::ops::Range<usize>) {
        let start = self.v.len();
        self.v.extend_from_slice(&self.pool[r]);
        self.ranges.push(start..self.v.len());
    }
}

impl Forest<'_> {
    /// The closed loops of a leaf's surface from the polylines of its minimal faces, each
    /// counter-clockwise about the outward normal, into `lp` (false if they do not close).
    fn loops(
        &self,
        leaf: &LeafRef,
        signs: &Signs,
        tol: Real,
        corners: &mut usize,
        lp: &mut Loops,
    ) -> bool {
        lp.v.clear();
        lp.ranges.clear();
        lp.pool.clear();
        lp.chains.clear();
        lp.open.clear();
        for n in 0..3 {
            for upper in [false, true] {
                lp.faces.clear();
                self.minimal_faces(leaf, n, upper, &mut lp.faces);
                for k in 0..lp.faces.len() {
                    let (f0, q) = lp.faces[k];
                    let first = lp.chains.len();
                    let c = self.face_chains((n, f0, q), signs, tol, &mut lp.pool, &mut lp.chains);
                    // A corner belongs to the face: count it once, from the leaf below.
                    if upper {
                        *corners += c;
                    }
                    for j in first..lp.chains.len() {
                        let ch = lp.chains[j];
                        if !upper {
                            lp.pool[ch.start..ch.end].reverse();
                        }
                        if ch.closed {
                            lp.push(ch.start..ch.end);
                        } else {
                            lp.open.push(ch);
                        }
                    }
                }
            }
        }
        let pool = &lp.pool;
        let key = |c: &Chain| pool[c.start].key;
        lp.open.sort_unstable_by_key(key);
        lp.used.clear();
        lp.used.resize(lp.open.len(), false);
        for s in 0..lp.open.len() {
            if lp.used[s] {
                continue;
            }
            let start = key(&lp.open[s]);
            let at = lp.v.len();
            let mut i = s;
            loop {
                lp.used[i] = true;
                let c = lp.open[i];
                lp.v.extend_from_slice(&lp.pool[c.start..c.end - 1]);
                let end = lp.pool[c.end - 1].key;
                if end == start {
                    break;
                }
                let j = lp.open.partition_point(|c| lp.pool[c.start].key < end);
                if j >= lp.open.len() || lp.pool[lp.open[j].start].key != end || lp.used[j] {
                    return false;
                }
                i = j;
            }
            lp.ranges.push(at..lp.v.len());
        }
        true
    }

    fn mesh_leaf(
        &self,
        leaf: &LeafRef,
        (tol, plane_tol): (Real, Real),
        out: &mut Out,
        loops: &mut Loops,
    ) {
        match leaf.kind {
            Kind::Empty => {}
            Kind::Fine => self.mesh_cell(leaf, tol, out, loops),
            Kind::Planar(_) | Kind::Edge(..) => {
                let signs = Signs::Predict(&leaf.kind, leaf.o[2], leaf.s);
                let mut corners = 0;
                let ok = self
                    .loops(leaf, &signs, tol, &mut corners, loops)
                    .then(|| self.mesh_planes(leaf, loops, plane_tol))
                    .flatten();
                match ok {
                    Some((tris, verts)) => {
                        out.tris.extend(tris);
                        out.verts.extend(verts);
                        out.corners += corners;
                        out.count(&leaf.kind);
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
        loops: &Loops,
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
                for lp in loops.iter() {
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
                let lp = loops.get(0);
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

    /// A single cell at dexel resolution, as [`crate::cutting::mesh`] meshes it.
    fn mesh_cell(&self, leaf: &LeafRef, tol: Real, out: &mut Out, loops: &mut Loops) {
        let lat = &self.lat;
        let o = leaf.o;
        let mut m = [0u64; 4];
        for (q, mq) in m.iter_mut().enumerate() {
            *mq = lat.column(o[0] + (q & 1) as isize, o[1] + (q >> 1) as isize, o[2], 1);
        }
        let signs = Signs::Cell(o, m);
        let mut corners = 0;
        if !self.loops(leaf, &signs, tol, &mut corners, loops) {
            // Cannot happen for a single cell (its face segments always close); keep the
            // mesh closed by failing loudly in the report instead of guessing.
            out.failed.push((leaf.node, leaf.o, leaf.s));
            return;
        }
        out.count(&leaf.kind);
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

impl Forest<'_> {
    /// Meshes every leaf of tree `ti`, in node order; with `reuse`, the leaves no split
    /// touched keep their triangles from the tree's output before (see [`Reuse`]).
    pub(super) fn mesh_tree(
        &self,
        ti: usize,
        t: &Tree,
        (tol, plane_tol): (Real, Real),
        reuse: Option<Reuse>,
    ) -> Out {
        TREE_SCRATCH
            .with_borrow_mut(|scratch| self.mesh_tree_in(ti, t, (tol, plane_tol), reuse, scratch))
    }

    /// [`Self::mesh_tree`] with the working buffers `scratch`: the tree's triangles and
    /// vertices are gathered there and copied out at their exact sizes, so a thread meshing
    /// tree after tree grows no vector once its buffers have reached the largest tree's.
    fn mesh_tree_in(
        &self,
        ti: usize,
        t: &Tree,
        (tol, plane_tol): (Real, Real),
        reuse: Option<Reuse>,
        scratch: &mut TreeScratch,
    ) -> Out {
        let TreeScratch {
            tris,
            verts,
            loops,
            stack,
            slots,
        } = scratch;
        let mut out = Out {
            tris: std::mem::take(tris),
            verts: std::mem::take(verts),
            ..Out::default()
        };
        out.tris.clear();
        out.verts.clear();
        // Old records are taken in node order: the leaves then that are leaves now come in
        // the same order (a split only puts a subtree in a leaf's place).
        let reuse = reuse.filter(|r| r.old.reusable);
        let (mut record, mut start) = (0, 0);
        out.reusable = true;
        out.nodes = t.nodes.len();
        stack.clear();
        stack.push((0usize, t.origin, ROOT));
        while let Some((node, o, s)) = stack.pop() {
            if let Node::Split(first) = t.nodes[node] {
                for c in (0..8).rev() {
                    stack.push((first as usize + c, child_origin(o, s, c), s / 2));
                }
                continue;
            }
            let Some(kind) = t.leaf(node) else {
                continue;
            };
            if matches!(kind, Kind::Empty) {
                continue;
            }
            // This leaf's record before, and where its triangles start: a leaf then.
            let then = reuse.as_ref().filter(|r| node < r.old.nodes).map(|r| {
                let rec = r.old.leaves[record];
                let at = (r.old, start, rec, !r.touched(o, s));
                record += 1;
                start += rec.tris as usize;
                at
            });
            let (tris, corners, features, failed) =
                (out.tris.len(), out.corners, out.features, out.failed.len());
            match then {
                Some((old, start, rec, true)) => {
                    // The leaf's triangles and their corners as meshing it gives them.
                    for f in &old.faces[start..start + rec.tris as usize] {
                        out.tris.push(f.map(|i| old.keys[i as usize]));
                        out.verts
                            .extend(f.map(|i| (old.keys[i as usize], old.points[i as usize])));
                    }
                    out.corners += rec.corners as usize;
                    out.features += rec.features as usize;
                    out.count(&kind);
                }
                _ => {
                    let leaf = LeafRef {
                        tree: ti,
                        node,
                        o,
                        s,
                        kind,
                    };
                    self.mesh_leaf(&leaf, (tol, plane_tol), &mut out, loops);
                }
            }
            let rec = LeafOut::of(
                out.tris.len() - tris,
                out.corners - corners,
                out.features - features,
            );
            // A leaf that failed is split before the tree is meshed again: no record.
            if out.failed.len() == failed {
                match rec {
                    Some(r) if out.reusable => out.leaves.push(r),
                    Some(_) => {}
                    None => out.reusable = false,
                }
            }
        }
        if !out.reusable {
            out.leaves = Vec::new();
        }
        out.leaves.shrink_to_fit();
        // Each vertex is named by every leaf that uses it: keep one per tree (equal keys
        // carry equal positions), so the trees' outputs stay near the mesh's size.
        out.verts.sort_unstable_by_key(|v| v.0);
        out.verts.dedup_by_key(|v| v.0);
        // Every corner's key is among the tree's vertices (each leaf adds those it uses):
        // its index is its place among them, found through a hash table.
        let index = KeyIndex::of(&out.verts, std::mem::take(slots));
        out.faces = out
            .tris
            .iter()
            .map(|t| t.each_ref().map(|k| index.find(&out.verts, *k)))
            .collect();
        // Kept until every tree is meshed: the vertices at their exact size, and the
        // triangles by index, not by key; the buffers go back for the next tree.
        out.keys = out.verts.iter().map(|v| v.0).collect();
        out.points = out.verts.iter().map(|v| v.1).collect();
        *verts = std::mem::take(&mut out.verts);
        *tris = std::mem::take(&mut out.tris);
        *slots = index.slots;
        out
    }
}

/// Per-thread working buffers of [`Forest::mesh_tree`], reused from tree to tree.
#[derive(Default)]
struct TreeScratch {
    tris: Vec<[Key; 3]>,
    verts: Vec<(Key, Point3)>,
    loops: Loops,
    stack: Vec<(usize, [isize; 3], usize)>,
    slots: Vec<u32>,
}

thread_local! {
    static TREE_SCRATCH: std::cell::RefCell<TreeScratch> =
        std::cell::RefCell::new(TreeScratch::default());
}

/// The places of distinct vertex keys, by open addressing: a key's slot run starts at its
/// hash and holds the index of each key placed there. Faster than a binary search over a
/// tree's vertices for each triangle corner; the index found is the key's place, whatever
/// the hash.
pub(super) struct KeyIndex {
    slots: Vec<u32>,
    mask: usize,
}

impl KeyIndex {
    /// The index of `verts`' keys (distinct), in a table at least twice their count, kept
    /// in `slots` (whose contents are dropped; its capacity is reused).
    pub(super) fn of(verts: &[(Key, Point3)], mut slots: Vec<u32>) -> Self {
        let size = (2 * verts.len()).next_power_of_two().max(2);
        slots.clear();
        slots.resize(size, u32::MAX);
        let mut t = Self {
            slots,
            mask: size - 1,
        };
        for (i, (k, _)) in verts.iter().enumerate() {
            let mut at = t.start(*k);
            while t.slots[at] != u32::MAX {
                at = (at + 1) & t.mask;
            }
            t.slots[at] = i as u32;
        }
        t
    }

    /// Where `k`'s run starts: its 128 bits folded and mixed (Fibonacci hashing).
    fn start(&self, k: Key) -> usize {
        let folded = (k as u64) ^ ((k >> 64) as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
        (folded.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 32) as usize & self.mask
    }

    /// The place of `k` among `verts`, the keys the index was made of.
    pub(super) fn find(&self, verts: &[(Key, Point3)], k: Key) -> u32 {
        let mut at = self.start(k);
        loop {
            let i = self.slots[at];
            if i == u32::MAX {
                // Not a key of the index (never: each leaf adds the vertices it uses): where
                // it would sort, as a binary search finds it.
                debug_assert!(false, "a corner's key is among the tree's vertices");
                return verts.partition_point(|v| v.0 < k) as u32;
            }
            if verts[i as usize].0 == k {
                return i;
            }
            at = (at + 1) & self.mask;
        }
    }
}
