//! Surface mesh of the cut stock: a closed, oriented triangle mesh of the tri-dexel's
//! material boundary whose vertices are the exact dexel crossings, and writers for binary
//! STL, OBJ and binary PLY.
//!
//! This is the *dexel-resolution contour*: one polygon per lattice cell the surface
//! crosses, tens of millions of triangles for a large part at a fine pitch. The commands
//! write and draw the adaptive mesh of [`super::adaptive`] instead, which meshes single cells
//! as this module does and is checked against this one's vertices.
//!
//! **Lattice.** The three dexel grids of a [`TriDexel`] share their spacings per axis, so
//! their rays lie on the lines of one lattice of points `P(i,j,k)` (the ray centres), and
//! each lattice edge lies on exactly one ray. The lattice is grown by one layer of points
//! outside the box on every side, so the stock's own faces are crossed by lattice edges too.
//!
//! **Inside/outside** of a lattice point is read on its z ray (one source, so it is
//! consistent). A lattice edge whose ends differ is *sign-changing*; its mesh vertex is the
//! crossing of the ray it lies on inside the edge: the exact position along the ray and the
//! stored normal. Should that ray disagree with the z rays (a sliver at rounding level seen
//! by one grid and not another), the edge midpoint is used and counted in
//! [`MeshReport::fallback_edges`].
//!
//! **Topology: closed, edge-manifold, oriented, by construction.** Each lattice cell holds
//! the marching-cubes polygons of its corner signs, built (not tabulated by hand) from one
//! rule per cell face: a face with two sign-changing edges joins them; a face with four (the
//! ambiguous case) joins the two edges at each inside corner, keeping inside corners apart.
//! The rule depends only on the face's four corners, so the two cells sharing a face draw
//! the same segments there, each oriented counter-clockwise about the outward normal (seen
//! from outside the cell, the inside corner is on the segment's right) and therefore in
//! opposite directions in the two cells. Every polygon side is such a segment, so every mesh
//! edge on a cell face is used once in each direction. Polygons are triangulated with edges
//! that no other cell can have: a triangle; a quadrilateral split along a diagonal whose ends
//! are not on one face of the cell; otherwise a fan around an added vertex of that polygon
//! alone. Hence every edge of the mesh is shared by exactly two triangles, once in each
//! direction, whatever the stock: thin walls, rays with several segments, islands, the box
//! faces. [`TriMesh::check_watertight`] verifies it.
//!
//! **Geometry.** Crossing vertices lie on the true surface (to rounding). Where a polygon's
//! crossing normals constrain two or three directions (an edge or corner of the part), its
//! triangles fan around the point minimising the squared distances to the crossings' tangent
//! planes (dual contouring's quadratic error; directions with eigenvalue below [`QEF_RANK`]
//! of the largest are taken from the crossings' mean), clamped to the cell: box corners come
//! out exact and sharp edges are cut only between lattice planes. Not guaranteed: freedom
//! from self-intersection (a clamped feature vertex can fold a triangle), and features
//! thinner than the lattice spacing between lattice points (a wall no lattice point lies in
//! is not seen; two walls closer than a spacing may merge).
//!
//! **Accuracy of the enclosed volume.** Planar faces are exact. Along a sharp edge the mesh
//! cuts a corner of at most (h/2)²/2 per unit length at each lattice plane across the edge,
//! about a third of that on average; a curved face is replaced by chords between exact points
//! `h` apart, an error ≈ h²·κ/12 per unit area (κ the curvature).
//!
//! **Determinism.** Work is split by rows of lattice columns and joined in row order: the
//! mesh is identical for any thread count.
//!
//! **Invariant:** meshing reads the stock only; it knows nothing about tools, moves or
//! machines. Writers take any `Write` and refuse non-finite coordinates before writing.

use crate::cutting::stock::{Segment, TriDexel};
use crate::math::{Point3, Real, Vector3};
use rayon::prelude::*;
use std::io::Write;

/// Relative eigenvalue below which a direction of a polygon's quadratic error is treated as
/// unconstrained (dual contouring's usual 0.1): crossings on one gently curved patch
/// (normals within ~18°) constrain one direction only, so the polygon is not a feature and
/// any added vertex stays near the crossings' mean instead of being pulled to a far,
/// ill-conditioned intersection of nearly parallel planes.
pub const QEF_RANK: Real = 0.1;

/// Errors of meshing and writing.
#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    /// A vertex coordinate is NaN or infinite.
    #[error("mesh vertex {vertex} is not finite")]
    NotFinite {
        /// Index of the vertex.
        vertex: usize,
    },
    /// A triangle names a vertex that does not exist.
    #[error("triangle {triangle} refers to vertex {vertex}, but the mesh has {count} vertices")]
    BadIndex {
        /// Index of the triangle.
        triangle: usize,
        /// The offending vertex index.
        vertex: u32,
        /// Number of vertices.
        count: usize,
    },
    /// Too many triangles or vertices for the format.
    #[error("{count} {what} do not fit the {format} format")]
    TooLarge {
        /// What overflowed.
        what: &'static str,
        /// How many there are.
        count: usize,
        /// The format.
        format: &'static str,
    },
    /// A mesh edge is not shared by exactly one triangle in each direction.
    #[error(
        "mesh edge {from}→{to} is used {forward} times, {to}→{from} {backward} times (closed and oriented needs 1 and 1)"
    )]
    NotWatertight {
        /// First vertex.
        from: u32,
        /// Second vertex.
        to: u32,
        /// Uses from→to.
        forward: usize,
        /// Uses to→from.
        backward: usize,
    },
    /// The adaptive mesher met a case it cannot mesh (a defect, not bad input).
    #[error("the adaptive mesher could not close {what}")]
    Unresolved {
        /// What it could not close.
        what: &'static str,
    },
    /// Writing failed.
    #[error("writing the mesh: {0}")]
    Io(#[from] std::io::Error),
}

/// An indexed triangle mesh (mm, workpiece frame); triangles wound counter-clockwise seen
/// from outside.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriMesh {
    /// Vertex positions.
    pub vertices: Vec<Point3>,
    /// Triangles as vertex indices.
    pub triangles: Vec<[u32; 3]>,
}

impl TriMesh {
    /// Enclosed volume (mm³) by the divergence theorem: positive for a closed, outward
    /// oriented mesh.
    pub fn signed_volume(&self) -> Real {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| self.vertices[i as usize].coords);
                a.dot(&b.cross(&c))
            })
            .sum::<Real>()
            / 6.0
    }

    /// Total area (mm²).
    pub fn area(&self) -> Real {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| self.vertices[i as usize]);
                (b - a).cross(&(c - a)).norm() / 2.0
            })
            .sum()
    }

    /// Checks that every edge is used exactly once in each direction: closed (watertight),
    /// edge-manifold and consistently oriented. Also checks the indices.
    pub fn check_watertight(&self) -> Result<(), MeshError> {
        self.check_indices()?;
        let mut edges: Vec<(u32, u32)> = self
            .triangles
            .iter()
            .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
            .collect();
        edges.par_sort_unstable();
        let count = |e: (u32, u32)| {
            let lo = edges.partition_point(|x| *x < e);
            let hi = edges.partition_point(|x| *x <= e);
            hi - lo
        };
        for w in edges.chunk_by(|a, b| a == b) {
            let (from, to) = w[0];
            let backward = count((to, from));
            if w.len() != 1 || backward != 1 {
                return Err(MeshError::NotWatertight {
                    from,
                    to,
                    forward: w.len(),
                    backward,
                });
            }
        }
        Ok(())
    }

    /// Euler characteristic V − E + F over the vertices used by triangles (2 for each
    /// closed surface of genus 0, 0 for a torus).
    pub fn euler_characteristic(&self) -> i64 {
        let mut used = vec![false; self.vertices.len()];
        for t in &self.triangles {
            for &i in t {
                used[i as usize] = true;
            }
        }
        let v = used.iter().filter(|u| **u).count() as i64;
        // The distinct edges counted part by part, each part the edges whose lower vertex
        // lies in its share of the indices: every edge in exactly one part, and a part's
        // edges (about EDGES_PER_PART, or a sixteenth) held at a time instead of all 3·F.
        const EDGES_PER_PART: usize = 1 << 17;
        let n = self.vertices.len().max(1);
        let parts = (3 * self.triangles.len())
            .div_ceil(EDGES_PER_PART)
            .clamp(1, 16)
            .min(n);
        let e: usize = (0..parts)
            .into_par_iter()
            .map(|k| {
                let (lo, hi) = ((k * n / parts) as u32, ((k + 1) * n / parts) as u32);
                let mut edges: Vec<(u32, u32)> = self
                    .triangles
                    .iter()
                    .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
                    .map(|(a, b)| (a.min(b), a.max(b)))
                    .filter(|&(a, _)| (lo..hi).contains(&a))
                    .collect();
                edges.sort_unstable();
                edges.dedup();
                edges.len()
            })
            .sum();
        v - e as i64 + self.triangles.len() as i64
    }

    fn check_indices(&self) -> Result<(), MeshError> {
        let count = self.vertices.len();
        for (triangle, t) in self.triangles.iter().enumerate() {
            if let Some(&vertex) = t.iter().find(|&&i| i as usize >= count) {
                return Err(MeshError::BadIndex {
                    triangle,
                    vertex,
                    count,
                });
            }
        }
        Ok(())
    }

    fn validate(&self) -> Result<(), MeshError> {
        if let Some(vertex) = self
            .vertices
            .iter()
            .position(|p| !p.coords.iter().all(|c| c.is_finite()))
        {
            return Err(MeshError::NotFinite { vertex });
        }
        self.check_indices()
    }

    /// Binary STL (little endian, f32 coordinates in mm, facet normals from the winding).
    pub fn write_stl<W: Write>(&self, mut w: W) -> Result<(), MeshError> {
        self.validate()?;
        let n = u32::try_from(self.triangles.len()).map_err(|_| MeshError::TooLarge {
            what: "triangles",
            count: self.triangles.len(),
            format: "binary STL",
        })?;
        let mut header = [b' '; 80];
        let text = b"twinmill stock surface, units mm";
        header[..text.len()].copy_from_slice(text);
        w.write_all(&header)?;
        w.write_all(&n.to_le_bytes())?;
        let mut buf = Vec::with_capacity(50 * 4096);
        for t in &self.triangles {
            let [a, b, c] = t.map(|i| self.vertices[i as usize]);
            let nrm = (b - a)
                .cross(&(c - a))
                .try_normalize(0.0)
                .unwrap_or_else(Vector3::zeros);
            for v in [nrm, a.coords, b.coords, c.coords] {
                for k in 0..3 {
                    buf.extend_from_slice(&(v[k] as f32).to_le_bytes());
                }
            }
            buf.extend_from_slice(&0u16.to_le_bytes());
            if buf.len() >= 50 * 4096 {
                w.write_all(&buf)?;
                buf.clear();
            }
        }
        w.write_all(&buf)?;
        w.flush()?;
        Ok(())
    }

    /// Wavefront OBJ (text, `v` lines with shortest round-trip f64 digits, 1-based `f`).
    pub fn write_obj<W: Write>(&self, w: W) -> Result<(), MeshError> {
        self.validate()?;
        let mut w = std::io::BufWriter::new(w);
        writeln!(w, "# twinmill stock surface, units mm")?;
        for p in &self.vertices {
            writeln!(w, "v {} {} {}", p.x, p.y, p.z)?;
        }
        for t in &self.triangles {
            writeln!(w, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1)?;
        }
        w.flush()?;
        Ok(())
    }

    /// Binary little-endian PLY: `double` x y z per vertex, `uchar`-counted `int` indices
    /// per face (readable by CloudCompare and Open3D).
    pub fn write_ply<W: Write>(&self, w: W) -> Result<(), MeshError> {
        self.validate()?;
        if i32::try_from(self.vertices.len()).is_err() {
            return Err(MeshError::TooLarge {
                what: "vertices",
                count: self.vertices.len(),
                format: "PLY with int indices",
            });
        }
        let mut w = std::io::BufWriter::new(w);
        write!(
            w,
            "ply\nformat binary_little_endian 1.0\ncomment twinmill stock surface, units mm\n\
             element vertex {}\nproperty double x\nproperty double y\nproperty double z\n\
             element face {}\nproperty list uchar int vertex_indices\nend_header\n",
            self.vertices.len(),
            self.triangles.len()
        )?;
        for p in &self.vertices {
            for k in 0..3 {
                w.write_all(&p[k].to_le_bytes())?;
            }
        }
        for t in &self.triangles {
            w.write_all(&[3u8])?;
            for &i in t {
                w.write_all(&(i as i32).to_le_bytes())?;
            }
        }
        w.flush()?;
        Ok(())
    }
}

// ---------------------------------------------------------------------------------------
// Cell tables.

/// Corner `c` of a cell is at offset (c & 1, c >> 1 & 1, c >> 2 & 1).
/// Edge `e`: along axis `e / 4`; its lower corner is offset by (e & 1, e >> 1 & 1) along
/// the other two axes in cyclic order (x: y, z; y: z, x; z: x, y).
fn edge_corners(e: usize) -> (usize, usize) {
    let axis = e / 4;
    let mut off = [0usize; 3];
    off[(axis + 1) % 3] = e & 1;
    off[(axis + 2) % 3] = (e >> 1) & 1;
    let c0 = off[0] | off[1] << 1 | off[2] << 2;
    off[axis] = 1;
    let c1 = off[0] | off[1] << 1 | off[2] << 2;
    (c0, c1)
}

/// The local index of the edge along `axis` whose lower corner is offset (a, b) along the
/// other two axes (cyclic order).
fn edge_index(axis: usize, a: usize, b: usize) -> usize {
    axis * 4 + a + 2 * b
}

fn corner_point(c: usize) -> Vector3 {
    Vector3::new((c & 1) as Real, (c >> 1 & 1) as Real, (c >> 2 & 1) as Real)
}

fn edge_midpoint(e: usize) -> Vector3 {
    let (a, b) = edge_corners(e);
    (corner_point(a) + corner_point(b)) / 2.0
}

/// The six faces of a cell: outward normal, corners in cyclic order, and the edges
/// between them (edge k joins corners k and k + 1).
fn cell_faces() -> Vec<(Vector3, [usize; 4], [usize; 4])> {
    let mut faces = Vec::new();
    for n in 0..3 {
        for s in 0..2 {
            let (u, v) = ((n + 1) % 3, (n + 2) % 3);
            let corner = |a: usize, b: usize| {
                let mut off = [0usize; 3];
                off[n] = s;
                off[u] = a;
                off[v] = b;
                off[0] | off[1] << 1 | off[2] << 2
            };
            let cs = [corner(0, 0), corner(1, 0), corner(1, 1), corner(0, 1)];
            // Along u the other axes in cyclic order are (v, n); along v they are (n, u).
            let es = [
                edge_index(u, 0, s),
                edge_index(v, s, 1),
                edge_index(u, 1, s),
                edge_index(v, s, 0),
            ];
            let mut normal = Vector3::zeros();
            normal[n] = if s == 0 { -1.0 } else { 1.0 };
            faces.push((normal, cs, es));
        }
    }
    faces
}

/// Whether two local edges lie on a common face of the cell.
fn share_face(faces: &[(Vector3, [usize; 4], [usize; 4])], a: usize, b: usize) -> bool {
    faces
        .iter()
        .any(|(_, _, es)| es.contains(&a) && es.contains(&b))
}

/// One surface polygon of a cell: its sign-changing edges in order, counter-clockwise seen
/// from outside the material, and which of its two diagonals (if it has four corners) may
/// be used without two cells sharing it.
#[derive(Clone, Debug, Default)]
struct Polygon {
    edges: Vec<u8>,
    /// For a quadrilateral: diagonal 0–2 allowed, diagonal 1–3 allowed.
    diagonals: [bool; 2],
}

/// For each corner mask (bit c = corner c inside): the cell's polygons.
fn polygon_table() -> Vec<Vec<Polygon>> {
    let faces = cell_faces();
    (0..256usize)
        .map(|mask| {
            let inside = |c: usize| mask >> c & 1 == 1;
            let changes = |e: usize| {
                let (a, b) = edge_corners(e);
                inside(a) != inside(b)
            };
            let mut next = [usize::MAX; 12];
            for (normal, cs, es) in &faces {
                let active: Vec<usize> = (0..4).filter(|&k| changes(es[k])).collect();
                // Segments on this face with an inside corner on their cut-off side.
                let mut segs: Vec<(usize, usize, usize)> = Vec::new();
                match active.len() {
                    2 => {
                        let c = *cs.iter().find(|&&c| inside(c)).unwrap_or(&cs[0]);
                        segs.push((es[active[0]], es[active[1]], c));
                    }
                    4 => {
                        // Ambiguous face: inside corners stay apart (the same rule on both
                        // cells that share the face).
                        for k in 0..4 {
                            if inside(cs[k]) {
                                segs.push((es[(k + 3) % 4], es[k], cs[k]));
                            }
                        }
                    }
                    _ => {}
                }
                for (a, b, c) in segs {
                    // Counter-clockwise about the outward surface normal: seen from outside
                    // the cell through this face, the inside corner is on the right.
                    let d = edge_midpoint(b) - edge_midpoint(a);
                    let w = corner_point(c) - edge_midpoint(a);
                    let (from, to) = if d.cross(&w).dot(normal) < 0.0 {
                        (a, b)
                    } else {
                        (b, a)
                    };
                    next[from] = to;
                }
            }
            let mut seen = [false; 12];
            let mut polys = Vec::new();
            for e0 in 0..12 {
                if !changes(e0) || seen[e0] {
                    continue;
                }
                let mut edges = Vec::new();
                let mut e = e0;
                while !seen[e] && e != usize::MAX {
                    seen[e] = true;
                    edges.push(e as u8);
                    e = next[e];
                }
                let diagonals = if edges.len() == 4 {
                    let e = |k: usize| edges[k] as usize;
                    [
                        !share_face(&faces, e(0), e(2)),
                        !share_face(&faces, e(1), e(3)),
                    ]
                } else {
                    [false, false]
                };
                polys.push(Polygon { edges, diagonals });
            }
            polys
        })
        .collect()
}

// ---------------------------------------------------------------------------------------
// The mesher.

/// What the mesher found, for reports.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MeshReport {
    /// Sign-changing lattice edges (one vertex each, on the exact crossing).
    pub crossing_vertices: usize,
    /// Polygons fanned around an added vertex (features, or more than four sides).
    pub feature_vertices: usize,
    /// Cells with more than one polygon (thin features or ambiguous faces).
    pub split_cells: usize,
    /// Sign-changing edges whose ray had no crossing there (midpoint used).
    pub fallback_edges: usize,
}

/// The lattice of a tri-dexel's ray centres (see the module documentation): lattice index
/// `i` along an axis is at `o + i·h`; indices `−1` and `n` are the grown layer outside the
/// box. Shared with the adaptive mesher ([`super::adaptive`]).
#[derive(Clone, Copy)]
pub(super) struct Frame<'a> {
    pub(super) stock: &'a TriDexel,
    /// Rays per axis (lattice indices `0..n` carry rays).
    pub(super) n: [usize; 3],
    /// Coordinate of lattice index 0 and spacing, per axis.
    pub(super) o: [Real; 3],
    pub(super) h: [Real; 3],
}

impl<'a> Frame<'a> {
    pub(super) fn of(stock: &'a TriDexel) -> Self {
        let gz = &stock.grids()[2];
        let gx = &stock.grids()[0];
        let (nx, ny) = gz.dims();
        let nz = gx.dims().1;
        let (hx, hy) = gz.pitches();
        let hz = gx.pitches().1;
        let o0 = gz.ray_origin(0, 0);
        let oz = gx.ray_origin(0, 0);
        Self {
            stock,
            n: [nx, ny, nz],
            o: [o0.x, o0.y, oz.z],
            h: [hx, hy, hz],
        }
    }

    pub(super) fn coord(&self, axis: usize, i: isize) -> Real {
        self.o[axis] + i as Real * self.h[axis]
    }

    /// The surface point and normal on the lattice edge from `p` along `axis`
    /// (`inside_low`: the lower end is inside). Returns whether the ray had a crossing.
    pub(super) fn crossing(
        &self,
        axis: usize,
        p: [isize; 3],
        inside_low: bool,
    ) -> (Point3, Vector3, bool) {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        let t0 = self.coord(axis, p[axis]);
        let t1 = t0 + self.h[axis];
        let mut point = Point3::origin();
        point[u] = self.coord(u, p[u]);
        point[v] = self.coord(v, p[v]);
        let segs: &[Segment] = self.stock.grids()[axis].ray(p[u] as usize, p[v] as usize);
        let mut any = None;
        let mut want = None;
        for s in segs {
            for (c, exit) in [(&s.lo, false), (&s.hi, true)] {
                if c.t >= t0 && c.t <= t1 {
                    any.get_or_insert(c);
                    if exit == inside_low && want.is_none() {
                        want = Some(c);
                    }
                }
            }
        }
        match want.or(any) {
            Some(c) => {
                point[axis] = c.t;
                (point, c.normal(), true)
            }
            None => {
                point[axis] = (t0 + t1) / 2.0;
                let mut n = Vector3::zeros();
                n[axis] = if inside_low { 1.0 } else { -1.0 };
                (point, n, false)
            }
        }
    }
}

struct Lattice<'a> {
    f: Frame<'a>,
    n: [usize; 3],
    /// Words per z column of occupancy bits; bit b is lattice k = b − 1.
    words: usize,
    occ: Vec<u64>,
}

impl Lattice<'_> {
    fn coord(&self, axis: usize, i: isize) -> Real {
        self.f.coord(axis, i)
    }

    /// Occupancy words of lattice column (i, j), or None outside the grid (all outside).
    fn column(&self, i: isize, j: isize) -> Option<&[u64]> {
        if i < 0 || j < 0 || i >= self.n[0] as isize || j >= self.n[1] as isize {
            return None;
        }
        let c = (j as usize * self.n[0] + i as usize) * self.words;
        Some(&self.occ[c..c + self.words])
    }

    fn inside(&self, i: isize, j: isize, k: isize) -> bool {
        let b = (k + 1) as usize;
        self.column(i, j)
            .is_some_and(|w| w[b / 64] >> (b % 64) & 1 == 1)
    }

    fn crossing(&self, axis: usize, p: [isize; 3], inside_low: bool) -> (Point3, Vector3, bool) {
        self.f.crossing(axis, p, inside_low)
    }
}

/// Shift a bit column down by one (bit b takes bit b + 1).
fn next_bits(w: &[u64], out: &mut [u64]) {
    for i in 0..w.len() {
        let hi = w.get(i + 1).map_or(0, |x| x << 63);
        out[i] = (w[i] >> 1) | hi;
    }
}

/// Number of set bits below bit `b`.
fn rank(w: &[u64], b: usize) -> u32 {
    let full: u32 = w[..b / 64].iter().map(|x| x.count_ones()).sum();
    full + (w[b / 64] & ((1u64 << (b % 64)) - 1)).count_ones()
}

/// Marks a triangle corner as a feature vertex (local index within its row) until the
/// rows are joined.
const FEATURE: u32 = 1 << 31;

impl Lattice<'_> {
    /// The sign-changing edges along `axis` whose lower end is in lattice column (i, j), as
    /// bits (bit b: lower end at k = b − 1); false if there are none by construction.
    fn edge_bits(&self, axis: usize, i: isize, j: isize, out: &mut [u64]) -> bool {
        let a = self.column(i, j);
        let (b, valid) = match axis {
            0 => (self.column(i + 1, j), (0..self.n[1] as isize).contains(&j)),
            1 => (self.column(i, j + 1), (0..self.n[0] as isize).contains(&i)),
            _ => (None, a.is_some()),
        };
        if !valid {
            return false;
        }
        let zero = |w: usize, c: Option<&[u64]>| c.map_or(0, |c| c[w]);
        if axis == 2 {
            if let Some(a) = a {
                next_bits(a, out);
                for (o, x) in out.iter_mut().zip(a) {
                    *o ^= x;
                }
            }
        } else {
            for (w, o) in out.iter_mut().enumerate() {
                *o = zero(w, a) ^ zero(w, b);
            }
        }
        true
    }
}

/// Meshes the boundary of the stock's material. See the module documentation for the
/// guarantees. Fails only if the mesh would need 2³¹ vertices or more.
pub fn mesh_stock(stock: &TriDexel) -> Result<(TriMesh, MeshReport), MeshError> {
    let f = Frame::of(stock);
    let gz = &stock.grids()[2];
    let [nx, ny, nz] = f.n;
    let (o, h) = (f.o, f.h);
    let hz = h[2];
    let words = (nz + 2).div_ceil(64);
    let n = f.n;

    // Occupancy of every lattice point from its z ray (lo ≤ z < hi).
    let mut occ = vec![0u64; nx * ny * words];
    occ.par_chunks_mut(nx * words)
        .enumerate()
        .for_each(|(j, row)| {
            for i in 0..nx {
                let col = &mut row[i * words..(i + 1) * words];
                for s in gz.ray(i, j) {
                    let k0 = ((s.lo.t - o[2]) / hz).floor().max(0.0);
                    let k1 = ((s.hi.t - o[2]) / hz).ceil().min((nz - 1) as Real);
                    if k1 < k0 {
                        continue;
                    }
                    for k in k0 as usize..=k1 as usize {
                        let z = o[2] + k as Real * hz;
                        if s.lo.t <= z && z < s.hi.t {
                            let b = k + 1;
                            col[b / 64] |= 1 << (b % 64);
                        }
                    }
                }
            }
        });
    let lat = Lattice { f, n, words, occ };
    let table = polygon_table();
    // Lower lattice columns (i, j) ∈ [−1, nx) × [−1, ny), row-major; stored at
    // (j + 1)·(nx + 1) + i + 1.
    let ex = nx + 1;
    let col_index = |i: isize, j: isize| (j + 1) as usize * ex + (i + 1) as usize;

    // Edge ids: per lower column, x then y then z edges, bits ascending.
    let counts: Vec<[u32; 3]> = (0..ny + 1)
        .into_par_iter()
        .flat_map_iter(|rj| {
            let mut bits = vec![0u64; words];
            let lat = &lat;
            (0..ex).map(move |ri| {
                let (i, j) = (ri as isize - 1, rj as isize - 1);
                std::array::from_fn(|axis| {
                    if lat.edge_bits(axis, i, j, &mut bits) {
                        bits.iter().map(|x| x.count_ones()).sum()
                    } else {
                        0
                    }
                })
            })
        })
        .collect();
    let mut base = Vec::with_capacity(counts.len());
    let mut total = 0u32;
    for c in &counts {
        base.push([total, total + c[0], total + c[0] + c[1]]);
        total += c[0] + c[1] + c[2];
        // Ids below 2³¹ (the top bit marks feature vertices until rows are joined).
        if total >= FEATURE {
            return Err(too_many(total as usize));
        }
    }
    drop(counts);
    let edge_id = |axis: usize, p: [isize; 3], bits: &mut [u64]| -> u32 {
        lat.edge_bits(axis, p[0], p[1], bits);
        base[col_index(p[0], p[1])][axis] + rank(bits, (p[2] + 1) as usize)
    };

    // Crossing vertices, in id order.
    let rows: Vec<(Vec<Point3>, Vec<Vector3>, usize)> = (0..ny + 1)
        .into_par_iter()
        .map(|rj| {
            let mut bits = vec![0u64; words];
            let (mut pts, mut nrm, mut fallback) = (Vec::new(), Vec::new(), 0);
            let j = rj as isize - 1;
            for ri in 0..ex {
                let i = ri as isize - 1;
                for axis in 0..3 {
                    if !lat.edge_bits(axis, i, j, &mut bits) {
                        continue;
                    }
                    for (w, &word) in bits.iter().enumerate() {
                        let mut x = word;
                        while x != 0 {
                            let b = w * 64 + x.trailing_zeros() as usize;
                            x &= x - 1;
                            let k = b as isize - 1;
                            let (p, nv, found) = lat.crossing(axis, [i, j, k], lat.inside(i, j, k));
                            pts.push(p);
                            nrm.push(nv);
                            fallback += usize::from(!found);
                        }
                    }
                }
            }
            (pts, nrm, fallback)
        })
        .collect();
    let mut report = MeshReport::default();
    let mut vertices = Vec::with_capacity(total as usize);
    let mut normals = Vec::with_capacity(total as usize);
    for (p, nv, f) in rows {
        vertices.extend(p);
        normals.extend(nv);
        report.fallback_edges += f;
    }
    report.crossing_vertices = vertices.len();

    // Polygons of the active cells, row by row: triangles and feature vertices.
    let zeros = vec![0u64; words];
    let col = |i: isize, j: isize| lat.column(i, j).unwrap_or(&zeros);
    let cell_rows: Vec<(Vec<[u32; 3]>, Vec<Point3>, usize)> = (0..ny + 1)
        .into_par_iter()
        .map(|rj| {
            let cj = rj as isize - 1;
            let mut tris = Vec::new();
            let mut feats = Vec::new();
            let mut split = 0;
            let mut bits = vec![0u64; words];
            let mut nb = vec![0u64; words];
            let mut nd = vec![0u64; words];
            let mut diff = vec![0u64; words];
            for ri in 0..ex {
                let ci = ri as isize - 1;
                let c = [
                    col(ci, cj),
                    col(ci + 1, cj),
                    col(ci, cj + 1),
                    col(ci + 1, cj + 1),
                ];
                for (w, d) in diff.iter_mut().enumerate() {
                    *d = (c[0][w] ^ c[1][w]) | (c[0][w] ^ c[2][w]) | (c[0][w] ^ c[3][w]);
                }
                next_bits(&diff, &mut nd);
                next_bits(c[0], &mut nb);
                for w in 0..words {
                    let mut act = diff[w] | nd[w] | (c[0][w] ^ nb[w]);
                    while act != 0 {
                        let b = w * 64 + act.trailing_zeros() as usize;
                        act &= act - 1;
                        if b > nz {
                            continue;
                        }
                        // Cell k = b − 1 has its corners on lattice bits b and b + 1.
                        let bit = |x: &[u64], b: usize| (x[b / 64] >> (b % 64) & 1) as usize;
                        let mut mask = 0usize;
                        for (q, cq) in c.iter().enumerate() {
                            mask |= bit(cq, b) << q;
                            mask |= bit(cq, b + 1) << (q | 4);
                        }
                        let polys = &table[mask];
                        if polys.len() > 1 {
                            split += 1;
                        }
                        let ck = b as isize - 1;
                        let lo = Point3::new(lat.coord(0, ci), lat.coord(1, cj), lat.coord(2, ck));
                        let hi = lo + Vector3::new(h[0], h[1], h[2]);
                        for poly in polys {
                            let ids: Vec<u32> = poly
                                .edges
                                .iter()
                                .map(|&e| {
                                    let (c0, _) = edge_corners(e as usize);
                                    let p = [
                                        ci + (c0 & 1) as isize,
                                        cj + (c0 >> 1 & 1) as isize,
                                        ck + (c0 >> 2 & 1) as isize,
                                    ];
                                    edge_id(e as usize / 4, p, &mut bits)
                                })
                                .collect();
                            let mut q = Qef::default();
                            for &id in &ids {
                                q.add(&vertices[id as usize], &normals[id as usize]);
                            }
                            let feature = q.rank() >= 2;
                            let at = |k: usize| vertices[ids[k] as usize];
                            if !feature && ids.len() == 3 {
                                tris.push([ids[0], ids[1], ids[2]]);
                                continue;
                            }
                            if !feature && ids.len() == 4 && poly.diagonals.iter().any(|d| *d) {
                                let d02 = (at(0) - at(2)).norm_squared();
                                let d13 = (at(1) - at(3)).norm_squared();
                                let use02 = poly.diagonals[0] && (!poly.diagonals[1] || d02 <= d13);
                                if use02 {
                                    tris.push([ids[0], ids[1], ids[2]]);
                                    tris.push([ids[0], ids[2], ids[3]]);
                                } else {
                                    tris.push([ids[0], ids[1], ids[3]]);
                                    tris.push([ids[1], ids[2], ids[3]]);
                                }
                                continue;
                            }
                            let centre = FEATURE | feats.len() as u32;
                            feats.push(q.solve(&lo, &hi));
                            for k in 0..ids.len() {
                                tris.push([centre, ids[k], ids[(k + 1) % ids.len()]]);
                            }
                        }
                    }
                }
            }
            (tris, feats, split)
        })
        .collect();
    let features: usize = cell_rows.iter().map(|r| r.1.len()).sum();
    if vertices.len() + features >= FEATURE as usize {
        return Err(too_many(vertices.len() + features));
    }
    let mut triangles = Vec::new();
    for (tris, feats, split) in cell_rows {
        let first = vertices.len() as u32;
        triangles.extend(tris.into_iter().map(|t| {
            t.map(|v| {
                if v & FEATURE != 0 {
                    first + (v & !FEATURE)
                } else {
                    v
                }
            })
        }));
        report.feature_vertices += feats.len();
        report.split_cells += split;
        vertices.extend(feats);
    }
    Ok((
        TriMesh {
            vertices,
            triangles,
        },
        report,
    ))
}

fn too_many(count: usize) -> MeshError {
    MeshError::TooLarge {
        what: "vertices",
        count,
        format: "the mesher's 31-bit vertex indices",
    }
}

/// Quadratic error of a point to tangent planes: Σ (n·(x − p))².
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Qef {
    ata: [Real; 6],
    atb: Vector3,
    mass: Vector3,
    count: u32,
}

impl Qef {
    pub(super) fn add(&mut self, p: &Point3, n: &Vector3) {
        let d = n.dot(&p.coords);
        self.ata[0] += n.x * n.x;
        self.ata[1] += n.x * n.y;
        self.ata[2] += n.x * n.z;
        self.ata[3] += n.y * n.y;
        self.ata[4] += n.y * n.z;
        self.ata[5] += n.z * n.z;
        self.atb += n * d;
        self.mass += p.coords;
        self.count += 1;
    }

    fn matrix(&self) -> nalgebra::Matrix3<Real> {
        let a = &self.ata;
        nalgebra::Matrix3::new(a[0], a[1], a[2], a[1], a[3], a[4], a[2], a[4], a[5])
    }

    /// Number of constrained directions (eigenvalues above [`QEF_RANK`] of the largest).
    pub(super) fn rank(&self) -> usize {
        let e = self.matrix().symmetric_eigenvalues();
        let top = e.iter().copied().fold(0.0, Real::max);
        e.iter().filter(|&&l| l > QEF_RANK * top).count()
    }

    /// The minimiser nearest the crossings' mean, clamped to the cell [lo, hi].
    pub(super) fn solve(&self, lo: &Point3, hi: &Point3) -> Point3 {
        let m = self.mass / self.count.max(1) as Real;
        let a = self.matrix();
        let r = self.atb - a * m;
        let eig = a.symmetric_eigen();
        let top = eig.eigenvalues.iter().copied().fold(0.0, Real::max);
        let mut x = m;
        for k in 0..3 {
            let lam = eig.eigenvalues[k];
            if lam > QEF_RANK * top {
                let u = eig.eigenvectors.column(k);
                x += u * (u.dot(&r) / lam);
            }
        }
        Point3::from(x).sup(lo).inf(hi)
    }
}

/// Parts for the meshers' tests: box stock, cuts, random parts, the closedness check.
#[cfg(test)]
pub(super) mod test_parts {
    use super::TriMesh;
    use crate::cutting::stock::TriDexel;
    use crate::cutting::sweep::TranslatedTool;
    use crate::cutting::tool::{Tool, ToolKind};
    use crate::math::{Aabb, CounterRng, Point3, Real, UnitVector3, Vector3};

    /// A box stock from the origin to `size` at `pitch`.
    pub fn stock(size: [Real; 3], pitch: Real) -> TriDexel {
        let b = Aabb {
            min: Point3::origin(),
            max: Point3::new(size[0], size[1], size[2]),
        };
        TriDexel::new_box(b, pitch, 1e9).expect("fits")
    }

    /// Cuts a straight move of a tool of `kind` and diameter `dia` with its axis along
    /// `axis`, tip from `a` to `b`.
    pub fn cut_along(
        s: &mut TriDexel,
        kind: ToolKind,
        dia: Real,
        a: [Real; 3],
        b: [Real; 3],
        axis: Vector3,
    ) {
        let tool = Tool::try_new(kind, dia, 40.0).expect("valid");
        let a = Point3::new(a[0], a[1], a[2]);
        let d = Point3::new(b[0], b[1], b[2]) - a;
        s.remove(
            &TranslatedTool::new(tool, a, d, UnitVector3::new_normalize(axis)),
            1,
        );
    }

    /// The same with the tool axis along +z.
    pub fn cut(s: &mut TriDexel, kind: ToolKind, dia: Real, a: [Real; 3], b: [Real; 3]) {
        cut_along(s, kind, dia, a, b, Vector3::z());
    }

    /// A 4 × 3 × 2 mm box at a random pitch (0.15–0.35 mm) cut by six random flat and
    /// ball moves (tool axes tilted up to about 25° with `tilted`): thin walls, slivers and
    /// tiny islands included.
    pub fn random_part(seed: u64, case: u64, tilted: bool) -> TriDexel {
        let rng = CounterRng::new(seed);
        let u = |k: u64| rng.uniform(case, k);
        let pitch = 0.15 + 0.2 * u(0);
        let mut s = stock([4.0, 3.0, 2.0], pitch);
        for c in 0..6u64 {
            let kind = if u(10 + c) < 0.5 {
                ToolKind::Flat
            } else {
                ToolKind::Ball
            };
            let p = |k: u64| {
                [
                    4.5 * u(k) - 0.25,
                    3.5 * u(k + 1) - 0.25,
                    0.3 + 2.0 * u(k + 2),
                ]
            };
            let d = 0.2 + 1.2 * u(20 + c);
            let axis = if tilted {
                Vector3::new(u(50 + c) - 0.5, u(60 + c) - 0.5, 1.5)
            } else {
                Vector3::z()
            };
            cut_along(&mut s, kind, d, p(30 + 10 * c), p(35 + 10 * c), axis);
        }
        s
    }

    /// Radius, length and depth of the stadium pocket of [`stadium_stages`].
    pub const STADIUM: (Real, Real, Real) = (1.5, 5.0, 2.0);

    /// A 10 × 10 × 5 mm box at 0.2 mm after each of four cuts, with the Euler characteristic
    /// its surface must have: a blind flat stadium pocket (Ø3 mm from (3, 3) to (7, 6), 2 mm
    /// deep; a sphere, 2), a ball groove sloping into its floor (2), a hole through the
    /// whole height (genus 1: 0), a slot through the side under the top, z rays with two
    /// segments (genus 2: −2).
    pub fn stadium_stages() -> Vec<(TriDexel, i64)> {
        let (r, _, depth) = STADIUM;
        let mut s = stock([10.0, 10.0, 5.0], 0.2);
        let z = 5.0 - depth;
        cut(
            &mut s,
            ToolKind::Flat,
            2.0 * r,
            [3.0, 3.0, z],
            [7.0, 6.0, z],
        );
        let mut out = vec![(s.clone(), 2)];
        cut(
            &mut s,
            ToolKind::Ball,
            2.0,
            [3.0, 7.0, 3.5],
            [7.0, 7.5, 2.5],
        );
        out.push((s.clone(), 2));
        cut(
            &mut s,
            ToolKind::Flat,
            2.5,
            [5.0, 5.0, -1.0],
            [5.0, 5.0, -0.5],
        );
        out.push((s.clone(), 0));
        cut_along(
            &mut s,
            ToolKind::Flat,
            1.0,
            [-1.0, 2.0, 1.0],
            [11.0, 2.0, 1.0],
            Vector3::y(),
        );
        assert!(s.grids()[2].ray(25, 12).len() == 2, "slot under material");
        out.push((s, -2));
        out
    }

    /// Every check a closed, oriented surface must pass, and its Euler characteristic.
    pub fn closed(m: &TriMesh) -> i64 {
        m.check_watertight().expect("watertight and oriented");
        m.euler_characteristic()
    }
}

#[cfg(test)]
mod tests {
    use super::test_parts::{STADIUM, closed, cut, random_part, stadium_stages, stock};
    use super::*;
    use crate::cutting::tool::ToolKind;

    #[test]
    fn every_cell_case_gives_closed_oriented_polygons() {
        // Each sign-changing edge is in exactly one polygon; consecutive polygon edges share
        // a face; no polygon edge is on a face with an unchanged corner pair.
        let faces = cell_faces();
        for (mask, polys) in polygon_table().iter().enumerate() {
            let mut seen = [0; 12];
            for p in polys {
                assert!(p.edges.len() >= 3, "mask {mask}");
                for (k, &e) in p.edges.iter().enumerate() {
                    seen[e as usize] += 1;
                    let next = p.edges[(k + 1) % p.edges.len()] as usize;
                    assert!(share_face(&faces, e as usize, next), "mask {mask}");
                }
            }
            for (e, &count) in seen.iter().enumerate() {
                let (a, b) = edge_corners(e);
                let changes = (mask >> a & 1) != (mask >> b & 1);
                assert_eq!(count, usize::from(changes), "mask {mask} edge {e}");
            }
        }
    }

    #[test]
    fn box_mesh_is_a_closed_sphere_within_the_edge_notch_bound() {
        let s = stock([4.0, 3.0, 2.0], 0.25);
        let (m, report) = mesh_stock(&s).expect("meshes");
        assert_eq!(closed(&m), 2);
        assert_eq!(report.fallback_edges, 0);
        // Faces are exact (crossings on the box faces) and the corners are feature vertices
        // at the exact corners; the edges are notched between lattice planes: per unit length
        // at most the chamfer (h/2)²/2 of a lattice plane, on average a third of it.
        let h = 0.25;
        let edges = 4.0 * (4.0 + 3.0 + 2.0);
        let bound = edges * h * h / 8.0;
        let v = m.signed_volume();
        assert!(v <= 24.0 + 1e-9 && 24.0 - v <= bound, "volume {v}");
        // Every vertex on the box surface.
        for p in &m.vertices {
            let on =
                (0..3).any(|k| p[k].abs() < 1e-12 || (p[k] - [4.0, 3.0, 2.0][k]).abs() < 1e-12);
            assert!(on, "{p:?}");
        }
    }

    #[test]
    fn pocket_through_hole_and_slot_have_the_right_topology() {
        // Blind flat pocket, exact volume (stadium area × depth): still a sphere.
        let stages = stadium_stages();
        let s = &stages[0].0;
        let (r, len, depth) = STADIUM;
        let (m, _) = mesh_stock(s).expect("meshes");
        assert_eq!(closed(&m), 2);
        let exact = 500.0 - (2.0 * r * len + std::f64::consts::PI * r * r) * depth;
        // Bound: sharp edges (box 100 mm, pocket rim and floor edge 2·(2·len + 2πr)) lose at
        // most (h/2)²/2 per unit length; the wall (taken whole, 2·(len + πr)·depth) is
        // replaced by chords within a cell, sagitta at most 3h²κ/8 with κ = 1/r.
        let h = 0.2;
        let sharp = 100.0 + 2.0 * (2.0 * len + 2.0 * std::f64::consts::PI * r);
        let wall = 2.0 * (len + std::f64::consts::PI * r) * depth;
        let bound = sharp * h * h / 8.0 + wall * 3.0 * h * h / (8.0 * r);
        let v = m.signed_volume();
        assert!((v - exact).abs() <= bound, "{v} vs {exact} (bound {bound})");
        assert!(
            (v - s.volume()).abs() <= bound,
            "{v} vs tri-dexel {}",
            s.volume()
        );
        // The ball groove, the through hole, the side slot: the topology of each.
        for (s, euler) in &stages[1..] {
            let (m, _) = mesh_stock(s).expect("meshes");
            assert_eq!(closed(&m), *euler);
        }
    }

    #[test]
    fn random_cuts_always_give_a_closed_oriented_mesh() {
        // Thin walls, slivers and tiny islands included: the topology guarantee holds for
        // any stock.
        for case in 0..60u64 {
            let s = random_part(3, case, false);
            let (m, _) = mesh_stock(&s).expect("meshes");
            m.check_watertight()
                .unwrap_or_else(|e| panic!("case {case}: {e}"));
            let v = m.signed_volume();
            assert!(v > 0.0 || s.volume() == 0.0, "case {case}: outward");
        }
    }

    #[test]
    fn mesh_is_identical_for_one_and_two_threads() {
        let mut s = stock([10.0, 10.0, 5.0], 0.2);
        cut(
            &mut s,
            ToolKind::Ball,
            3.0,
            [2.0, 3.0, 3.0],
            [8.0, 6.0, 3.5],
        );
        let run = |threads| crate::math::in_pool(threads, || mesh_stock(&s).expect("meshes").0);
        assert_eq!(run(1), run(2));
    }

    fn sample_mesh() -> TriMesh {
        let mut s = stock([3.0, 2.0, 1.0], 0.25);
        cut(
            &mut s,
            ToolKind::Ball,
            1.0,
            [1.0, 1.0, 0.7],
            [2.2, 1.3, 0.6],
        );
        mesh_stock(&s).expect("meshes").0
    }

    #[test]
    fn stl_round_trip() {
        let m = sample_mesh();
        let mut buf = Vec::new();
        m.write_stl(&mut buf).expect("writes");
        assert_eq!(buf.len(), 84 + 50 * m.triangles.len());
        let n = u32::from_le_bytes(buf[80..84].try_into().expect("4 bytes")) as usize;
        assert_eq!(n, m.triangles.len());
        let f = |o: usize| f32::from_le_bytes(buf[o..o + 4].try_into().expect("4 bytes")) as Real;
        for (t, tri) in m.triangles.iter().enumerate() {
            let rec = 84 + 50 * t;
            for (c, &vi) in tri.iter().enumerate() {
                for k in 0..3 {
                    let got = f(rec + 12 + 12 * c + 4 * k);
                    assert_eq!(got, m.vertices[vi as usize][k] as f32 as Real);
                }
            }
            // Facet normal agrees with the winding.
            let [a, b, c] = tri.map(|i| m.vertices[i as usize]);
            let nrm = (b - a).cross(&(c - a));
            let stored = Vector3::new(f(rec), f(rec + 4), f(rec + 8));
            assert!(nrm.norm() == 0.0 || stored.dot(&nrm) > 0.0);
        }
    }

    #[test]
    fn ply_round_trip() {
        let m = sample_mesh();
        let mut buf = Vec::new();
        m.write_ply(&mut buf).expect("writes");
        let end = b"end_header\n";
        let at = buf
            .windows(end.len())
            .position(|w| w == end)
            .expect("header")
            + end.len();
        let header = std::str::from_utf8(&buf[..at]).expect("ascii");
        assert!(header.starts_with("ply\nformat binary_little_endian 1.0\n"));
        assert!(header.contains(&format!("element vertex {}\n", m.vertices.len())));
        assert!(header.contains(&format!("element face {}\n", m.triangles.len())));
        let mut o = at;
        let mut read = |len: usize| {
            let s = &buf[o..o + len];
            o += len;
            s
        };
        for p in &m.vertices {
            for k in 0..3 {
                let x = f64::from_le_bytes(read(8).try_into().expect("8 bytes"));
                assert_eq!(x, p[k]);
            }
        }
        for t in &m.triangles {
            assert_eq!(read(1), &[3u8]);
            for &i in t {
                let x = i32::from_le_bytes(read(4).try_into().expect("4 bytes"));
                assert_eq!(x as u32, i);
            }
        }
        assert_eq!(o, buf.len());
    }

    #[test]
    fn obj_round_trip_through_tobj() {
        let m = sample_mesh();
        let mut buf = Vec::new();
        m.write_obj(&mut buf).expect("writes");
        let (models, _) = tobj::load_obj_buf(
            &mut std::io::Cursor::new(&buf),
            &tobj::LoadOptions::default(),
            |_| Err(tobj::LoadError::OpenFileFailed),
        )
        .expect("tobj reads it");
        assert_eq!(models.len(), 1);
        let mesh = &models[0].mesh;
        // tobj renumbers vertices in the order faces use them: compare corner by corner.
        let idx: Vec<u32> = m.triangles.iter().flatten().copied().collect();
        assert_eq!(mesh.indices.len(), idx.len());
        for (&ours, &theirs) in idx.iter().zip(&mesh.indices) {
            let p = m.vertices[ours as usize];
            let q = &mesh.positions[3 * theirs as usize..3 * theirs as usize + 3];
            // tobj keeps f32 positions by default: equal to f32 rounding.
            for k in 0..3 {
                assert!((p[k] - q[k] as Real).abs() <= 1e-6 * (1.0 + p[k].abs()));
            }
        }
    }

    #[test]
    fn writers_refuse_non_finite_vertices() {
        let mut m = sample_mesh();
        m.vertices[3].y = Real::NAN;
        for r in [
            m.write_stl(Vec::new()),
            m.write_obj(Vec::new()),
            m.write_ply(Vec::new()),
        ] {
            assert!(matches!(r, Err(MeshError::NotFinite { vertex: 3 })));
        }
        let mut m = sample_mesh();
        m.triangles[0][1] = m.vertices.len() as u32;
        assert!(matches!(
            m.write_stl(Vec::new()),
            Err(MeshError::BadIndex { triangle: 0, .. })
        ));
    }

    #[test]
    fn euler_characteristic_counts_each_edge_once_over_many_parts() {
        // A torus of nu × nv quads (V = nu·nv, E = 3·nu·nv, F = 2·nu·nv: χ = 0), its
        // vertices numbered in a scrambled order so that its edges' lower ends spread over
        // every part, beside a tetrahedron (χ = 2) and a fan of three triangles on one
        // edge (V = 5, E = 7, F = 3: χ = 1, the shared edge counted once).
        let (nu, nv) = (400usize, 300usize);
        let n = nu * nv;
        // i ↦ (i·p) mod n, p coprime to n: a permutation.
        let p = 7919;
        let id = |i: usize, j: usize| (((i % nu) * nv + j % nv) * p % n) as u32;
        let mut m = TriMesh {
            vertices: vec![Point3::origin(); n],
            triangles: Vec::new(),
        };
        for i in 0..nu {
            for j in 0..nv {
                let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
                m.triangles.push([a, b, c]);
                m.triangles.push([a, c, d]);
            }
        }
        assert!(3 * m.triangles.len() > 4 << 17, "several parts");
        assert_eq!(m.euler_characteristic(), 0);
        let base = m.vertices.len() as u32;
        m.vertices.extend([Point3::origin(); 4]);
        for t in [[0, 1, 2], [0, 3, 1], [1, 3, 2], [2, 3, 0]] {
            m.triangles.push(t.map(|k| base + k));
        }
        assert_eq!(m.euler_characteristic(), 2);
        let base = m.vertices.len() as u32;
        m.vertices.extend([Point3::origin(); 5]);
        for t in [[0, 1, 2], [1, 0, 3], [0, 1, 4]] {
            m.triangles.push(t.map(|k| base + k));
        }
        assert_eq!(m.euler_characteristic(), 3);
    }
}
