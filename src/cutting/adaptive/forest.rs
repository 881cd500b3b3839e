//! The forest of root blocks with its leaf lookup, and the polylines of the minimal faces
//! between leaves (tangent-line corners added, simplified by Douglas–Peucker).
//!
//! **Invariant:** a face's polyline is built from that face's lattice data only, in one
//! canonical direction, so both leaves beside it get the same polyline.

use super::*;

// ---------------------------------------------------------------------------------------
// The forest of root blocks and leaf lookup.

pub(super) struct Forest<'a> {
    pub(super) lat: Lat<'a>,
    /// Root blocks per axis.
    pub(super) rn: [usize; 3],
    /// Tree index of each root block (row-major x, y, z), or None if it is empty.
    pub(super) roots: Vec<Option<u32>>,
    pub(super) trees: Vec<Tree>,
}

#[derive(Clone, Copy)]
pub(super) struct LeafRef {
    pub(super) tree: usize,
    pub(super) node: usize,
    pub(super) o: [isize; 3],
    pub(super) s: usize,
    pub(super) kind: Kind,
}

impl Forest<'_> {
    /// The size of the leaf holding cell `c`; None outside the roots or in an empty root.
    fn leaf_size_at(&self, c: [isize; 3]) -> Option<usize> {
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
        while let Node::Split(first) = t.nodes[node] {
            let h = (s / 2) as isize;
            let ch = usize::from(c[0] - o[0] >= h)
                | usize::from(c[1] - o[1] >= h) << 1
                | usize::from(c[2] - o[2] >= h) << 2;
            o = child_origin(o, s, ch);
            s /= 2;
            node = first as usize + ch;
        }
        Some(s)
    }

    /// The minimal faces on one side of a leaf: (lower lattice point of the square, size).
    pub(super) fn minimal_faces(
        &self,
        leaf: &LeafRef,
        n: usize,
        upper: bool,
        out: &mut Vec<([isize; 3], usize)>,
    ) {
        let (u, v) = ((n + 1) % 3, (n + 2) % 3);
        let c = leaf.o[n] + if upper { leaf.s as isize } else { 0 };
        let beyond = if upper { c } else { c - 1 };
        // Squares still to look at: at most three per level of a tree ROOT cells deep.
        let mut stack = [(0, 0, 0); 4 * (ROOT.trailing_zeros() as usize + 1)];
        stack[0] = (leaf.o[u], leaf.o[v], leaf.s);
        let mut depth = 1;
        while depth > 0 {
            depth -= 1;
            let (a, b, q) = stack[depth];
            let nb = self.leaf_size_at(point(n, beyond, a, b));
            if q == 1 || nb.is_none_or(|size| size >= q) {
                out.push((point(n, c, a, b), q));
            } else {
                let h = (q / 2) as isize;
                for (da, db) in [(0, 0), (h, 0), (0, h), (h, h)] {
                    stack[depth] = (a + da, b + db, q / 2);
                    depth += 1;
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
/// sees it): its vertices `start..end` of the pool they were appended to; `closed`: a loop
/// lying inside the face.
#[derive(Clone, Copy, Debug)]
pub(super) struct Chain {
    pub(super) start: usize,
    pub(super) end: usize,
    pub(super) closed: bool,
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
    /// lattice's own), simplified within `tol` when `q > 1`: their vertices appended to
    /// `pool`, the polylines to `chains`. Returns the tangent-line corners added.
    pub(super) fn face_chains(
        &self,
        (n, f0, q): (usize, [isize; 3], usize),
        signs: &Signs,
        tol: Real,
        pool: &mut Vec<Vtx>,
        chains: &mut Vec<Chain>,
    ) -> usize {
        let lat = &self.lat;
        if signs.uniform(lat, n, f0, q) {
            return 0;
        }
        FACE_SCRATCH.with_borrow_mut(|scratch| {
            self.face_chains_in((n, f0, q), signs, tol, (pool, chains), scratch)
        })
    }

    /// [`Self::face_chains`] with its working buffers `scratch`.
    fn face_chains_in(
        &self,
        (n, f0, q): (usize, [isize; 3], usize),
        signs: &Signs,
        tol: Real,
        (pool, chains): (&mut Vec<Vtx>, &mut Vec<Chain>),
        scratch: &mut FaceScratch,
    ) -> usize {
        let lat = &self.lat;
        let FaceScratch {
            signs: face_signs,
            segs,
            by_from,
            tos,
            used,
            keep,
            stack,
            line,
        } = scratch;
        let (u, v) = ((n + 1) % 3, (n + 2) % 3);
        let (c, u0, v0) = (f0[n], f0[u], f0[v]);
        let w = q + 1;
        signs.face(lat, n, f0, q, face_signs);
        let signs = &*face_signs;
        if signs.iter().all(|&x| x == signs[0]) {
            return 0;
        }
        // Segments: (from, corner, to).
        segs.clear();
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
        by_from.clear();
        by_from.extend(segs.iter().enumerate().map(|(i, s)| (s.0.key, i)));
        by_from.sort_unstable();
        tos.clear();
        tos.extend(segs.iter().map(|s| s.2.key));
        tos.sort_unstable();
        let segs = &*segs;
        let next_of = |key: Key| -> Option<usize> {
            let i = by_from.partition_point(|x| x.0 < key);
            (i < by_from.len() && by_from[i].0 == key).then(|| by_from[i].1)
        };
        used.clear();
        used.resize(segs.len(), false);
        // Walks from segment `start` to where the polyline ends, its vertices appended to
        // `out`.
        let follow = |start: usize, used: &mut Vec<bool>, out: &mut Vec<Vtx>| {
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
                        return;
                    }
                }
            }
        };
        // Each polyline simplified (when q > 1) and appended to the pool.
        let mut add = |line: &mut Vec<Vtx>, closed: bool| {
            if q > 1 {
                simplify(line, closed, tol, keep, stack);
            }
            let start = pool.len();
            pool.extend_from_slice(line);
            chains.push(Chain {
                start,
                end: pool.len(),
                closed,
            });
        };
        // Open polylines start where no segment ends.
        for (i, seg) in segs.iter().enumerate() {
            if tos.binary_search(&seg.0.key).is_err() {
                line.clear();
                follow(i, used, line);
                add(line, false);
            }
        }
        for i in 0..segs.len() {
            if !used[i] {
                line.clear();
                follow(i, used, line);
                // The walk ends back at its first vertex: drop the repeat.
                if line.len() > 1 && line[line.len() - 1].key == line[0].key {
                    line.pop();
                }
                add(line, true);
            }
        }
        corners
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

/// Douglas–Peucker within `tol` of the polyline `v` (a loop when `closed`), keeping the ends
/// (of an open polyline), corners, and for a closed one its smallest key and the vertex
/// farthest from it. Depends on the polyline only, so both leaves of a face simplify it
/// alike. `keep` and `stack` are working buffers.
fn simplify(
    v: &mut Vec<Vtx>,
    closed: bool,
    tol: Real,
    keep: &mut Vec<bool>,
    stack: &mut Vec<(usize, usize)>,
) {
    if closed {
        let first = (0..v.len()).min_by_key(|&i| v[i].key).unwrap_or(0);
        v.rotate_left(first);
        let v0 = v[0];
        v.push(v0);
    }
    let m = v.len();
    keep.clear();
    keep.resize(m, false);
    keep[0] = true;
    keep[m - 1] = true;
    for (k, x) in v.iter().enumerate() {
        keep[k] |= x.corner;
    }
    if closed && m > 2 {
        let far = (1..m - 1)
            .max_by(|&a, &b| {
                let da = (v[a].p - v[0].p).norm_squared();
                let db = (v[b].p - v[0].p).norm_squared();
                da.total_cmp(&db).then(b.cmp(&a))
            })
            .unwrap_or(1);
        keep[far] = true;
    }
    // The spans between consecutive anchors, the last first (as the stack pops them).
    stack.clear();
    let mut prev = None;
    for k in (0..m).filter(|&k| keep[k]) {
        if let Some(a) = prev {
            stack.push((a, k));
        }
        prev = Some(k);
    }
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
    if closed {
        v.pop();
        keep.pop();
    }
    let mut k = keep.iter();
    v.retain(|_| k.next().copied().unwrap_or(false));
}

/// Working buffers of [`Forest::face_chains`], per thread, reused from face to face: the
/// face's signs, its segments, their starts and ends sorted, which are linked, the polyline
/// being walked, and Douglas–Peucker's kept vertices and spans.
#[derive(Default)]
pub(super) struct FaceScratch {
    signs: Vec<bool>,
    segs: Vec<(Vtx, Option<Vtx>, Vtx)>,
    by_from: Vec<(Key, usize)>,
    tos: Vec<Key>,
    used: Vec<bool>,
    line: Vec<Vtx>,
    keep: Vec<bool>,
    stack: Vec<(usize, usize)>,
}

thread_local! {
    static FACE_SCRATCH: std::cell::RefCell<FaceScratch> =
        std::cell::RefCell::new(FaceScratch::default());
}
