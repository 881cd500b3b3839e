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
//! expected makes the leaf split, in rounds, until none does; single cells never fail. A
//! leaf's triangles depend on its own data and on the sizes of the leaves across its faces
//! only, so a tree meshed again after a round keeps those of every leaf that touches no
//! leaf that split, and meshes the rest: the same mesh as meshing every leaf again.
//!
//! **Determinism.** Vertices are named by lattice keys (the lattice edge of a crossing, the
//! cell face of a corner, the leaf of a fan centre) and numbered in key order at the end;
//! triangles are joined in root-block order: the mesh is identical for any thread count.
//!
//! **Invariant:** reads the stock only, as [`super::mesh`] does.
//!
//! **Files.** This one holds the options, the report and the mesher; `lattice` the vertex
//! keys and the lattice read from the z rays, `classify` the leaves and the octree,
//! `forest` the leaf lookup and the face polylines, `triangles` the leaves' triangles,
//! `tests` the unit tests.

use super::mesh::{Frame, MeshError, Qef, TriMesh};
use crate::cutting::stock::TriDexel;
use crate::math::{Point3, Real, Vector3};
use rayon::prelude::*;

mod classify;
mod forest;
mod lattice;
mod triangles;

use classify::{Grower, Kind, Node, Plane, Signs, Tree, child_origin, occupied_roots};
#[cfg(test)]
use classify::{plane_inside, plane_mask};
use forest::{Chain, Forest, LeafRef};
use lattice::{Key, Lat, Vtx, bit_range, corner_key, local_key, point};
use triangles::{Out, Reuse};

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
// The mesher.

/// Meshes the boundary of the stock's material adaptively. See the module documentation
/// for the guarantees. Fails only if the mesh would need 2³² vertices or more, or (a
/// defect, never seen) if a single lattice cell's face segments did not close.
pub fn mesh_stock_adaptive(
    stock: &TriDexel,
    opts: &AdaptiveOptions,
) -> Result<(TriMesh, AdaptiveReport), MeshError> {
    mesh_adaptive(stock, opts, true)
}

/// [`mesh_stock_adaptive`]; a tree meshed again after a split keeps the triangles of the
/// leaves the split did not touch where `reuse` (the same mesh either way), else every
/// leaf is meshed again.
fn mesh_adaptive(
    stock: &TriDexel,
    opts: &AdaptiveOptions,
    reuse: bool,
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
            let (mut nodes, mut planes) = (vec![Node::Empty], Vec::new());
            let mut g = Grower::new(&lat, tol, o);
            g.grow((&mut nodes, &mut planes), 0, o, ROOT);
            let resid = g.resid;
            let empty = matches!(nodes[0], Node::Empty);
            // The tree is kept while every tree is meshed: no spare capacity.
            nodes.shrink_to_fit();
            planes.shrink_to_fit();
            (
                (!empty).then_some(Tree {
                    root: r,
                    origin: o,
                    nodes,
                    planes,
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
    // those sharing a root face with them (whose minimal faces may have changed): in each,
    // the leaves touching a leaf that split, the others' triangles kept (`Reuse`).
    let mut outs: Vec<Option<Out>> = forest.trees.iter().map(|_| None).collect();
    // Per tree, the boxes (origin, size) of the leaves whose split it must see.
    let mut split: Vec<Vec<([isize; 3], usize)>> =
        forest.trees.iter().map(|_| Vec::new()).collect();
    let tols = (opts.chain_tol_mm, tol);
    loop {
        // Each tree's output replaced as soon as it is meshed again: the old one is freed
        // then, not held until every tree of the round is done.
        let f = &forest;
        outs.par_iter_mut()
            .enumerate()
            .zip(split.par_iter())
            .for_each(|((ti, out), split)| {
                let t = &f.trees[ti];
                let new = match out {
                    None => f.mesh_tree(ti, t, tols, None),
                    Some(old) if !split.is_empty() => {
                        f.mesh_tree(ti, t, tols, reuse.then_some(Reuse { old, split }))
                    }
                    Some(_) => return,
                };
                *out = Some(new);
            });
        split.iter_mut().for_each(Vec::clear);
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
                if nodes.is_empty() {
                    return 0.0;
                }
                let mut g = Grower::new(lat, tol, t.origin);
                for &(node, o, s) in nodes {
                    g.split((&mut t.nodes, &mut t.planes), node, o, s);
                }
                g.resid
            })
            .reduce(|| 0.0, Real::max);
        report.max_plane_residual_mm = report.max_plane_residual_mm.max(resid);
        for (ti, nodes) in failed.iter().enumerate() {
            if nodes.is_empty() {
                continue;
            }
            split[ti].extend(nodes.iter().map(|&(_, o, s)| (o, s)));
            let r = forest.trees[ti].root;
            let rc = [r % rn[0], r / rn[0] % rn[1], r / (rn[0] * rn[1])];
            let o = forest.trees[ti].origin;
            for axis in 0..3 {
                for step in [-1isize, 1] {
                    // Only a split leaf on this root face changes the neighbour's faces.
                    let on_face = |&(_, lo, s): &(usize, [isize; 3], usize)| {
                        if step < 0 {
                            lo[axis] == o[axis]
                        } else {
                            lo[axis] + s as isize == o[axis] + ROOT as isize
                        }
                    };
                    if !nodes.iter().any(on_face) {
                        continue;
                    }
                    let c = rc[axis] as isize + step;
                    if c < 0 || c >= rn[axis] as isize {
                        continue;
                    }
                    let mut nc = rc;
                    nc[axis] = c as usize;
                    let nr = (nc[2] * rn[1] + nc[1]) * rn[0] + nc[0];
                    if let Some(nt) = forest.roots[nr] {
                        split[nt as usize]
                            .extend(nodes.iter().filter(|n| on_face(n)).map(|&(_, o, s)| (o, s)));
                    }
                }
            }
        }
    }
    // The trees and the leaves' records are no longer needed: freed before the outputs
    // are joined (the peak).
    drop((forest, split));
    for o in outs.iter_mut().flatten() {
        o.leaves = Vec::new();
    }
    let mut outs: Vec<Out> = outs.into_iter().flatten().collect();
    for o in &outs {
        report.planar_leaves += o.planar;
        report.edge_leaves += o.edge;
        report.fine_cells += o.fine;
        report.corner_points += o.corners;
        report.feature_vertices += o.features;
    }
    // Number the vertices in key order (every tree's, one per key): the keys alone sorted
    // (not with their points), each tree's vertices found among them (its keys then
    // freed), the points placed, and the triangles joined in tree order, each tree's
    // renumbered.
    let mut keys: Vec<Key> = Vec::with_capacity(outs.iter().map(|o| o.keys.len()).sum());
    for o in &outs {
        keys.extend_from_slice(&o.keys);
    }
    keys.par_sort_unstable();
    keys.dedup();
    if keys.len() >= u32::MAX as usize {
        return Err(MeshError::TooLarge {
            what: "vertices",
            count: keys.len(),
            format: "32-bit vertex indices",
        });
    }
    let globals: Vec<Vec<u32>> = outs
        .par_iter_mut()
        .map(|o| {
            // A tree's vertices are in key order: each is found from the last one found.
            let mut at = 0;
            std::mem::take(&mut o.keys)
                .iter()
                .map(|k| {
                    at = gallop(&keys[at..], |x| x < k) + at;
                    at as u32
                })
                .collect()
        })
        .collect();
    let count = keys.len();
    drop(keys);
    // A key shared by trees is the same lattice point, found the same way in each: the
    // same point.
    let mut vertices = vec![Point3::origin(); count];
    for (o, global) in outs.iter_mut().zip(&globals) {
        for (p, &i) in o.points.iter().zip(global) {
            debug_assert!(
                vertices[i as usize] == Point3::origin() || vertices[i as usize] == *p,
                "a key shared by two trees with two points"
            );
            vertices[i as usize] = *p;
        }
        o.points = Vec::new();
    }
    let triangles: Vec<[u32; 3]> = outs
        .into_par_iter()
        .zip(globals)
        .map(|(o, global)| {
            o.faces
                .iter()
                .map(|f| f.map(|i| global[i as usize]))
                .collect::<Vec<[u32; 3]>>()
        })
        .flatten_iter()
        .collect();
    Ok((
        TriMesh {
            vertices,
            triangles,
        },
        report,
    ))
}

/// [`slice::partition_point`] for a point expected near the start: the bracket doubles from
/// the start until `pred` fails, then a binary search within it (the same index).
fn gallop<T>(xs: &[T], pred: impl Fn(&T) -> bool) -> usize {
    let mut hi = 1;
    while hi < xs.len() && pred(&xs[hi]) {
        hi *= 2;
    }
    let lo = hi / 2;
    let hi = hi.min(xs.len());
    lo + xs[lo..hi].partition_point(pred)
}

#[cfg(test)]
#[path = "../../../benches/support/p1.rs"]
#[allow(
    clippy::duplicate_mod,
    reason = "benchmark P1's program is shared by the unit tests of sweep, zmap and adaptive"
)]
mod p1;

#[cfg(test)]
mod tests;
