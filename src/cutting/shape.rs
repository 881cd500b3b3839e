//! Solids that stock, fixtures and design models are made of: a box, a cylinder along any
//! direction, and closed triangle meshes read from OBJ or STL text. Each answers the one
//! question the tri-dexel asks: the exact intervals of an axis-parallel ray inside it.
//!
//! **Meshes.** A mesh is accepted only if it is *closed and consistently oriented*: every
//! edge is used exactly once in each direction (so there are no boundary edges, no edge shared
//! by three or more triangles, no neighbours wound against each other) and every vertex is
//! finite. A mesh wound inwards (negative enclosed volume) is turned outwards. Anything else
//! is refused with the file, what is wrong, how often and one example (vertex indices are
//! 1-based as in the OBJ file).
//!
//! **Ray crossings of a mesh, robust at edges and vertices.** A ray along axis k is a point
//! `p` in the (u, v) plane of the other two axes. It crosses a triangle iff `p` is on the same
//! side of its three projected edges. Each edge's side test is computed once per *undirected*
//! edge (endpoints in index order) and negated for the other direction, so the two triangles
//! sharing an edge always disagree about `p` exactly; a point exactly on an edge or vertex is
//! moved symbolically by `(ε, ε²)` (simulation of simplicity), which decides every tie by the
//! edge's direction alone. Hence a ray through an edge or a vertex is counted in exactly one
//! of the triangles around it, and a ray along a face (projected area zero) in none: the
//! crossing count of a closed mesh is always consistent. Crossings are sorted along the ray
//! and the winding number (+1 entering a triangle wound clockwise seen along the ray, −1
//! leaving) gives the inside intervals (winding > 0). The position along the ray comes from the
//! barycentric weights relative to the first vertex, so a ray through a face parallel to the
//! grid gets that face's coordinate exactly, and is clamped to the triangle's extent.
//!
//! **Invariant:** shapes know nothing about tools, machines or programs; loaders read text or
//! bytes they are given (the path only names the file in messages) and never panic.

use crate::math::{Aabb, Point3, Real, UnitVector3, Vector3, tol};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// One interval of an axis-parallel ray inside a solid, with the solid's *outward* unit
/// normals at both ends.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SolidSpan {
    /// Entry coordinate along the ray (mm).
    pub t_in: Real,
    /// Exit coordinate along the ray (mm, ≥ `t_in`).
    pub t_out: Real,
    /// Outward normal at the entry (against the ray).
    pub n_in: Vector3,
    /// Outward normal at the exit (along the ray).
    pub n_out: Vector3,
}

/// A closed solid that can list its intervals along axis-parallel rays.
pub trait Solid: Sync {
    /// A box containing the solid.
    fn bounds(&self) -> Aabb;
    /// Appends to `out` the intervals of the axis-parallel ray through `origin` inside the
    /// solid, sorted and disjoint; `t` is the coordinate along `axis` (the ray is
    /// `origin + (t − origin[axis])·e_axis`).
    fn ray_spans(&self, origin: &Point3, axis: usize, out: &mut Vec<SolidSpan>);
}

/// Errors in building a shape or reading a mesh file.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ShapeError {
    /// A cylinder with a non-positive or non-finite size, or a zero axis.
    #[error(
        "cylinder needs a finite positive radius and length and a non-zero axis (radius {radius} mm, length {length} mm)"
    )]
    BadCylinder {
        /// Radius (mm).
        radius: Real,
        /// Length (mm).
        length: Real,
    },
    /// The text of a mesh file could not be read.
    #[error("{}:{line}:{column}: {message} '{word}'", path.display())]
    Syntax {
        /// File.
        path: PathBuf,
        /// 1-based line.
        line: usize,
        /// 1-based column of the word.
        column: usize,
        /// The offending word.
        word: String,
        /// What is wrong.
        message: String,
    },
    /// A vertex coordinate is NaN or infinite.
    #[error("{}:{line}: vertex {vertex} is not finite ({coords})", path.display())]
    NotFinite {
        /// File.
        path: PathBuf,
        /// 1-based line of the vertex (OBJ), or of the facet (STL).
        line: usize,
        /// 1-based vertex index.
        vertex: usize,
        /// The coordinates as read.
        coords: String,
    },
    /// The file holds no triangles.
    #[error("{}: the mesh has no triangles", path.display())]
    Empty {
        /// File.
        path: PathBuf,
    },
    /// The mesh is not closed and consistently oriented.
    #[error(
        "{}: the mesh is not a closed, consistently oriented surface: {boundary} boundary edges, {non_manifold} edges shared by more than two triangles, {misoriented} edges wound the same way in both triangles; for example edge {}-{} ({what})",
        path.display(), example.0, example.1
    )]
    NotClosed {
        /// File.
        path: PathBuf,
        /// Edges used by one triangle only (holes).
        boundary: usize,
        /// Edges used by three or more triangles.
        non_manifold: usize,
        /// Edges used twice in the same direction (neighbours wound against each other).
        misoriented: usize,
        /// One offending edge (1-based vertex indices).
        example: (usize, usize),
        /// What is wrong with the example edge.
        what: &'static str,
    },
    /// The mesh encloses no volume.
    #[error("{}: the mesh encloses no volume", path.display())]
    NoVolume {
        /// File.
        path: PathBuf,
    },
}

/// A solid circular cylinder: base centre, unit axis, radius and length (mm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cylinder {
    base: Point3,
    axis: UnitVector3,
    radius: Real,
    length: Real,
}

impl Cylinder {
    /// The cylinder from `base` (centre of one end face) along `axis` (any non-zero
    /// direction), of `radius` and `length` (mm).
    pub fn try_new(
        base: Point3,
        axis: Vector3,
        radius: Real,
        length: Real,
    ) -> Result<Self, ShapeError> {
        let bad = ShapeError::BadCylinder { radius, length };
        let finite = base.coords.iter().chain(axis.iter()).all(|c| c.is_finite());
        if !(finite && radius.is_finite() && radius > 0.0 && length.is_finite() && length > 0.0) {
            return Err(bad);
        }
        let axis = UnitVector3::try_new(axis, tol::LENGTH_EPS).ok_or(bad)?;
        Ok(Self {
            base,
            axis,
            radius,
            length,
        })
    }

    /// Radius (mm).
    pub fn radius(&self) -> Real {
        self.radius
    }

    /// Length (mm).
    pub fn length(&self) -> Real {
        self.length
    }

    /// Centre of the base face.
    pub fn base(&self) -> Point3 {
        self.base
    }

    /// Unit axis from the base to the top face.
    pub fn axis(&self) -> UnitVector3 {
        self.axis
    }
}

impl Solid for Cylinder {
    fn bounds(&self) -> Aabb {
        let a = self.axis.into_inner();
        let ext = Vector3::from_fn(|k, _| self.radius * (1.0 - a[k] * a[k]).max(0.0).sqrt());
        let mut b = Aabb::empty();
        for p in [self.base, self.base + a * self.length] {
            b.grow(&(p - ext));
            b.grow(&(p + ext));
        }
        b
    }

    fn ray_spans(&self, origin: &Point3, axis: usize, out: &mut Vec<SolidSpan>) {
        let mut e = Vector3::zeros();
        e[axis] = 1.0;
        let a = self.axis.into_inner();
        let mut o = *origin;
        o[axis] = 0.0;
        let w = o - self.base;
        let (aw, ae) = (a.dot(&w), a.dot(&e));
        let pw = w - a * aw;
        let pe = e - a * ae;
        // Radial constraint |pw + t·pe|² ≤ r²: A t² + 2B t + C ≤ 0.
        let (qa, qb, qc) = (
            pe.dot(&pe),
            pw.dot(&pe),
            pw.dot(&pw) - self.radius * self.radius,
        );
        let (mut t0, mut t1) = (Real::NEG_INFINITY, Real::INFINITY);
        let (mut n0, mut n1) = (-e, e);
        if qa <= tol::RELATIVE_EPS {
            // Ray parallel to the axis: inside the disc or not at all.
            if qc > 0.0 {
                return;
            }
        } else {
            let disc = qb * qb - qa * qc;
            if disc <= 0.0 {
                return;
            }
            let sq = disc.sqrt();
            t0 = (-qb - sq) / qa;
            t1 = (-qb + sq) / qa;
            n0 = (pw + pe * t0) / self.radius;
            n1 = (pw + pe * t1) / self.radius;
        }
        // Axial constraint 0 ≤ aw + t·ae ≤ L.
        if ae.abs() <= tol::RELATIVE_EPS {
            if aw < 0.0 || aw > self.length {
                return;
            }
        } else {
            let (ta, tb) = (-aw / ae, (self.length - aw) / ae);
            let (lo, hi, nlo, nhi) = if ae > 0.0 {
                (ta, tb, -a, a)
            } else {
                (tb, ta, a, -a)
            };
            if lo > t0 {
                t0 = lo;
                n0 = nlo;
            }
            if hi < t1 {
                t1 = hi;
                n1 = nhi;
            }
        }
        if t1 - t0 >= tol::SLIVER {
            out.push(SolidSpan {
                t_in: t0,
                t_out: t1,
                n_in: n0,
                n_out: n1,
            });
        }
    }
}

impl Solid for Aabb {
    fn bounds(&self) -> Aabb {
        *self
    }

    fn ray_spans(&self, origin: &Point3, axis: usize, out: &mut Vec<SolidSpan>) {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        let inside = |k: usize| self.min[k] <= origin[k] && origin[k] <= self.max[k];
        if inside(u) && inside(v) && self.max[axis] - self.min[axis] >= tol::SLIVER {
            let mut e = Vector3::zeros();
            e[axis] = 1.0;
            out.push(SolidSpan {
                t_in: self.min[axis],
                t_out: self.max[axis],
                n_in: -e,
                n_out: e,
            });
        }
    }
}

/// Triangles of one ray direction, binned on a uniform grid of the (u, v) plane.
#[derive(Clone, Debug)]
struct Bins {
    min: [Real; 2],
    cell: [Real; 2],
    n: [usize; 2],
    offsets: Vec<u32>,
    tris: Vec<u32>,
}

impl Bins {
    fn cell_of(&self, x: Real, d: usize) -> usize {
        let c = ((x - self.min[d]) / self.cell[d]).floor();
        if c.is_nan() || c < 0.0 {
            0
        } else {
            (c as usize).min(self.n[d] - 1)
        }
    }

    fn build(vertices: &[Point3], triangles: &[[u32; 3]], axis: usize, bounds: &Aabb) -> Self {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        let side = ((triangles.len() as Real / 2.0).sqrt().ceil() as usize).clamp(1, 1024);
        let ext = |k: usize| (bounds.max[k] - bounds.min[k]).max(tol::LENGTH_EPS);
        let mut bins = Self {
            min: [bounds.min[u], bounds.min[v]],
            cell: [ext(u) / side as Real, ext(v) / side as Real],
            n: [side, side],
            offsets: vec![0; side * side + 1],
            tris: Vec::new(),
        };
        let range = |bins: &Self, t: &[u32; 3]| {
            let (mut lo, mut hi) = ([Real::INFINITY; 2], [Real::NEG_INFINITY; 2]);
            for &i in t {
                let p = vertices[i as usize];
                for (d, k) in [u, v].into_iter().enumerate() {
                    lo[d] = lo[d].min(p[k]);
                    hi[d] = hi[d].max(p[k]);
                }
            }
            (
                [bins.cell_of(lo[0], 0), bins.cell_of(lo[1], 1)],
                [bins.cell_of(hi[0], 0), bins.cell_of(hi[1], 1)],
            )
        };
        // Counting pass, then filling pass (CSR layout).
        for t in triangles {
            let (lo, hi) = range(&bins, t);
            for j in lo[1]..=hi[1] {
                for i in lo[0]..=hi[0] {
                    bins.offsets[j * side + i + 1] += 1;
                }
            }
        }
        for c in 0..side * side {
            bins.offsets[c + 1] += bins.offsets[c];
        }
        let mut fill = bins.offsets.clone();
        bins.tris = vec![0; bins.offsets[side * side] as usize];
        for (ti, t) in triangles.iter().enumerate() {
            let (lo, hi) = range(&bins, t);
            for j in lo[1]..=hi[1] {
                for i in lo[0]..=hi[0] {
                    let c = j * side + i;
                    bins.tris[fill[c] as usize] = ti as u32;
                    fill[c] += 1;
                }
            }
        }
        bins
    }
}

/// A closed, consistently and outwardly oriented triangle mesh (mm), with what it needs for
/// exact axis-parallel ray queries.
#[derive(Clone, Debug)]
pub struct ClosedMesh {
    vertices: Vec<Point3>,
    triangles: Vec<[u32; 3]>,
    bounds: Aabb,
    bins: [Bins; 3],
}

/// Counts of the edge problems of a triangle soup, with one example.
struct EdgeProblems {
    boundary: usize,
    non_manifold: usize,
    misoriented: usize,
    example: Option<((u32, u32), &'static str)>,
}

fn edge_problems(triangles: &[[u32; 3]]) -> EdgeProblems {
    let mut uses: HashMap<(u32, u32), (usize, usize)> = HashMap::new();
    for t in triangles {
        for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
            let e = uses.entry((a.min(b), a.max(b))).or_default();
            if a < b {
                e.0 += 1;
            } else {
                e.1 += 1;
            }
        }
    }
    let mut keys: Vec<_> = uses.into_iter().collect();
    keys.sort_unstable();
    let mut p = EdgeProblems {
        boundary: 0,
        non_manifold: 0,
        misoriented: 0,
        example: None,
    };
    for (edge, (f, b)) in keys {
        let what = match (f, b) {
            (1, 1) => continue,
            _ if f + b == 1 => {
                p.boundary += 1;
                "used by one triangle only"
            }
            _ if f + b > 2 => {
                p.non_manifold += 1;
                "shared by more than two triangles"
            }
            _ => {
                p.misoriented += 1;
                "wound the same way by both of its triangles"
            }
        };
        p.example.get_or_insert((edge, what));
    }
    p
}

impl ClosedMesh {
    /// Validates a triangle soup as a closed solid (see the module docs); `path` names the
    /// source in messages and `vertex_lines[i]` is the 1-based line of vertex i (0 if none).
    pub fn try_new(
        vertices: Vec<Point3>,
        mut triangles: Vec<[u32; 3]>,
        path: &Path,
        vertex_lines: &[usize],
    ) -> Result<Self, ShapeError> {
        if let Some(i) = vertices
            .iter()
            .position(|p| !p.coords.iter().all(|c| c.is_finite()))
        {
            let p = vertices[i];
            return Err(ShapeError::NotFinite {
                path: path.to_path_buf(),
                line: vertex_lines.get(i).copied().unwrap_or(0),
                vertex: i + 1,
                coords: format!("{} {} {}", p.x, p.y, p.z),
            });
        }
        if triangles.is_empty() {
            return Err(ShapeError::Empty {
                path: path.to_path_buf(),
            });
        }
        if triangles
            .iter()
            .any(|t| t.iter().any(|&i| i as usize >= vertices.len()))
        {
            return Err(ShapeError::Syntax {
                path: path.to_path_buf(),
                line: 0,
                column: 0,
                word: String::new(),
                message: "a triangle names a vertex that does not exist".into(),
            });
        }
        let p = edge_problems(&triangles);
        if let Some(((a, b), what)) = p.example {
            return Err(ShapeError::NotClosed {
                path: path.to_path_buf(),
                boundary: p.boundary,
                non_manifold: p.non_manifold,
                misoriented: p.misoriented,
                example: (a as usize + 1, b as usize + 1),
                what,
            });
        }
        let volume = signed_volume(&vertices, &triangles);
        let mut bounds = Aabb::empty();
        for t in &triangles {
            for &i in t {
                bounds.grow(&vertices[i as usize]);
            }
        }
        let scale = (bounds.max - bounds.min).norm();
        if volume
            .abs()
            .partial_cmp(&(tol::RELATIVE_EPS * scale * scale * scale))
            != Some(std::cmp::Ordering::Greater)
        {
            return Err(ShapeError::NoVolume {
                path: path.to_path_buf(),
            });
        }
        if volume < 0.0 {
            for t in &mut triangles {
                t.swap(1, 2);
            }
        }
        let bins = [0, 1, 2].map(|k| Bins::build(&vertices, &triangles, k, &bounds));
        Ok(Self {
            vertices,
            triangles,
            bounds,
            bins,
        })
    }

    /// Vertex positions (mm).
    pub fn vertices(&self) -> &[Point3] {
        &self.vertices
    }

    /// Triangles, wound counter-clockwise seen from outside.
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }

    /// Enclosed volume (mm³, positive).
    pub fn volume(&self) -> Real {
        signed_volume(&self.vertices, &self.triangles)
    }

    /// The mesh as a parry3d shape (oriented, with pseudo-normals for inside tests), for
    /// collision and distance queries.
    pub fn to_parry(&self) -> Option<parry3d_f64::shape::TriMesh> {
        parry3d_f64::shape::TriMesh::with_flags(
            self.vertices.clone(),
            self.triangles.clone(),
            parry3d_f64::shape::TriMeshFlags::ORIENTED,
        )
        .ok()
    }

    /// Whether `p` is inside the solid (points on the surface may go either way), by the
    /// winding number of the z ray through it.
    pub fn contains(&self, p: &Point3) -> bool {
        let mut spans = Vec::new();
        self.ray_spans(p, 2, &mut spans);
        spans.iter().any(|s| s.t_in <= p.z && p.z <= s.t_out)
    }

    /// The side of the directed projected edge i→j for point (pu, pv), consistent for both
    /// directions and never zero unless the edge projects to a point.
    fn side(&self, i: u32, j: u32, u: usize, v: usize, pu: Real, pv: Real) -> i8 {
        let (a, b, flip) = if i < j { (i, j, 1) } else { (j, i, -1) };
        let (pa, pb) = (self.vertices[a as usize], self.vertices[b as usize]);
        let (du, dv) = (pb[u] - pa[u], pb[v] - pa[v]);
        let f = du * (pv - pa[v]) - dv * (pu - pa[u]);
        // Simulation of simplicity: p moved by (ε, ε²) decides a tie.
        let s = if f != 0.0 {
            f.signum()
        } else if dv != 0.0 {
            -dv.signum()
        } else if du != 0.0 {
            du.signum()
        } else {
            return 0;
        };
        (s as i8) * flip
    }

    /// Crossings (t, winding step, outward normal) of the ray, unsorted.
    fn crossings(&self, origin: &Point3, axis: usize, out: &mut Vec<(Real, i8, Vector3)>) {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        let (pu, pv) = (origin[u], origin[v]);
        if !(self.bounds.min[u] <= pu
            && pu <= self.bounds.max[u]
            && self.bounds.min[v] <= pv
            && pv <= self.bounds.max[v])
        {
            return;
        }
        let bins = &self.bins[axis];
        let c = bins.cell_of(pv, 1) * bins.n[0] + bins.cell_of(pu, 0);
        for &ti in &bins.tris[bins.offsets[c] as usize..bins.offsets[c + 1] as usize] {
            let [ia, ib, ic] = self.triangles[ti as usize];
            let s = self.side(ia, ib, u, v, pu, pv);
            if s == 0
                || self.side(ib, ic, u, v, pu, pv) != s
                || self.side(ic, ia, u, v, pu, pv) != s
            {
                continue;
            }
            let [a, b, c] = [ia, ib, ic].map(|i| self.vertices[i as usize]);
            let edge =
                |p: &Point3, q: &Point3| (q[u] - p[u]) * (pv - p[v]) - (q[v] - p[v]) * (pu - p[u]);
            let (wa, wb, wc) = (edge(&b, &c), edge(&c, &a), edge(&a, &b));
            let sum = wa + wb + wc;
            let lo = a[axis].min(b[axis]).min(c[axis]);
            let hi = a[axis].max(b[axis]).max(c[axis]);
            let mut t = if sum != 0.0 {
                a[axis] + (wb * (b[axis] - a[axis]) + wc * (c[axis] - a[axis])) / sum
            } else {
                a[axis]
            };
            if !t.is_finite() {
                t = a[axis];
            }
            let t = t.clamp(lo, hi);
            let mut e = Vector3::zeros();
            e[axis] = 1.0;
            let n = (b - a)
                .cross(&(c - a))
                .try_normalize(0.0)
                .unwrap_or(e * Real::from(s));
            // Counter-clockwise in (u, v) = normal along +ray = leaving the solid.
            out.push((t, -s, n));
        }
    }
}

impl Solid for ClosedMesh {
    fn bounds(&self) -> Aabb {
        self.bounds
    }

    fn ray_spans(&self, origin: &Point3, axis: usize, out: &mut Vec<SolidSpan>) {
        let mut xs = Vec::new();
        self.crossings(origin, axis, &mut xs);
        xs.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let mut winding = 0i32;
        let mut open: Option<(Real, Vector3)> = None;
        for (t, step, n) in xs {
            let before = winding;
            winding += i32::from(step);
            if before <= 0 && winding > 0 {
                open = Some((t, n));
            } else if before > 0
                && winding <= 0
                && let Some((t0, n0)) = open.take()
            {
                push_span(out, t0, t, n0, n);
            }
        }
    }
}

/// Appends a span, merging it with the previous one across a gap thinner than a sliver and
/// dropping it if it is itself a sliver.
fn push_span(out: &mut Vec<SolidSpan>, t0: Real, t1: Real, n0: Vector3, n1: Vector3) {
    if let Some(last) = out.last_mut()
        && t0 - last.t_out < tol::SLIVER
    {
        if t1 > last.t_out {
            last.t_out = t1;
            last.n_out = n1;
        }
        return;
    }
    if t1 - t0 >= tol::SLIVER {
        out.push(SolidSpan {
            t_in: t0,
            t_out: t1,
            n_in: n0,
            n_out: n1,
        });
    }
}

fn signed_volume(vertices: &[Point3], triangles: &[[u32; 3]]) -> Real {
    triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| vertices[i as usize].coords);
            a.dot(&b.cross(&c))
        })
        .sum::<Real>()
        / 6.0
}

fn syntax(path: &Path, line: usize, column: usize, word: &str, message: &str) -> ShapeError {
    ShapeError::Syntax {
        path: path.to_path_buf(),
        line,
        column,
        word: word.chars().take(40).collect(),
        message: message.into(),
    }
}

/// Words of a line with their 1-based columns.
fn words(line: &str) -> impl Iterator<Item = (usize, &str)> {
    line.split_whitespace()
        .map(move |w| (w.as_ptr() as usize - line.as_ptr() as usize + 1, w))
}

/// Reads a closed mesh from Wavefront OBJ text: `v x y z [w]` and `f` lines (indices may be
/// negative and carry `/vt/vn`; polygons are fanned from their first corner); every other
/// statement is ignored. Coordinates are read as f64.
pub fn read_obj(text: &str, path: &Path) -> Result<ClosedMesh, ShapeError> {
    let mut vertices = Vec::new();
    let mut lines = Vec::new();
    let mut triangles = Vec::new();
    for (ln, raw) in text.lines().enumerate() {
        let ln = ln + 1;
        let line = raw.split('#').next().unwrap_or("");
        let mut it = words(line);
        match it.next() {
            Some((_, "v")) => {
                let mut c = [0.0; 3];
                for ck in &mut c {
                    let (col, w) = it
                        .next()
                        .ok_or_else(|| syntax(path, ln, raw.len() + 1, "", "vertex needs x y z"))?;
                    *ck = w
                        .parse()
                        .map_err(|_| syntax(path, ln, col, w, "not a number"))?;
                }
                vertices.push(Point3::new(c[0], c[1], c[2]));
                lines.push(ln);
            }
            Some((_, "f")) => {
                let mut idx = Vec::new();
                for (col, w) in it {
                    let first = w.split('/').next().unwrap_or("");
                    let i: i64 = first
                        .parse()
                        .map_err(|_| syntax(path, ln, col, w, "not a vertex index"))?;
                    let n = vertices.len() as i64;
                    let k = if i > 0 { i - 1 } else { n + i };
                    if i == 0 || k < 0 || k >= n || k > u32::MAX as i64 {
                        return Err(syntax(path, ln, col, w, "vertex index out of range"));
                    }
                    idx.push(k as u32);
                }
                if idx.len() < 3 {
                    return Err(syntax(path, ln, 1, "f", "a face needs at least 3 vertices"));
                }
                for k in 1..idx.len() - 1 {
                    triangles.push([idx[0], idx[k], idx[k + 1]]);
                }
            }
            _ => {}
        }
    }
    ClosedMesh::try_new(vertices, triangles, path, &lines)
}

/// Reads a closed mesh from STL, binary or ASCII (binary when the size matches the
/// triangle count in the header). Corners with bit-identical coordinates are one vertex.
pub fn read_stl(bytes: &[u8], path: &Path) -> Result<ClosedMesh, ShapeError> {
    let mut corners: Vec<(Point3, usize)> = Vec::new();
    let binary = bytes.len() >= 84
        && u32::from_le_bytes([bytes[80], bytes[81], bytes[82], bytes[83]]) as usize * 50 + 84
            == bytes.len();
    if binary {
        for (i, facet) in bytes[84..].chunks_exact(50).enumerate() {
            for k in 0..3 {
                let f = |j: usize| {
                    let o = 12 + 12 * k + 4 * j;
                    Real::from(f32::from_le_bytes([
                        facet[o],
                        facet[o + 1],
                        facet[o + 2],
                        facet[o + 3],
                    ]))
                };
                corners.push((Point3::new(f(0), f(1), f(2)), i + 1));
            }
        }
    } else {
        let text = std::str::from_utf8(bytes)
            .map_err(|_| syntax(path, 1, 1, "", "neither binary STL nor ASCII text"))?;
        for (ln, line) in text.lines().enumerate() {
            let mut it = words(line);
            if let Some((_, w)) = it.next()
                && w.eq_ignore_ascii_case("vertex")
            {
                let mut c = [0.0; 3];
                for ck in &mut c {
                    let (col, w) = it.next().ok_or_else(|| {
                        syntax(path, ln + 1, line.len() + 1, "", "vertex needs x y z")
                    })?;
                    *ck = w
                        .parse()
                        .map_err(|_| syntax(path, ln + 1, col, w, "not a number"))?;
                }
                corners.push((Point3::new(c[0], c[1], c[2]), ln + 1));
            }
        }
        if !corners.len().is_multiple_of(3) {
            return Err(syntax(
                path,
                0,
                0,
                "vertex",
                "the vertex count is not a multiple of 3",
            ));
        }
    }
    let mut index: HashMap<[u64; 3], u32> = HashMap::new();
    let mut vertices = Vec::new();
    let mut lines = Vec::new();
    let mut ids = Vec::with_capacity(corners.len());
    for (p, ln) in corners {
        // −0.0 and +0.0 are the same point.
        let key = [p.x + 0.0, p.y + 0.0, p.z + 0.0].map(Real::to_bits);
        let id = *index.entry(key).or_insert_with(|| {
            vertices.push(p);
            lines.push(ln);
            (vertices.len() - 1) as u32
        });
        ids.push(id);
    }
    let triangles = ids.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    ClosedMesh::try_new(vertices, triangles, path, &lines)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// OBJ text of the box [0, s]³ with every face split into n × n squares of two
    /// triangles, outward.
    pub(crate) fn cube_obj(s: Real, n: usize) -> String {
        let mut text = String::new();
        let mut count = 0usize;
        // For each face: origin corner and two in-face directions (u × v outward).
        let faces: [([Real; 3], [Real; 3], [Real; 3]); 6] = [
            ([0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]),
            ([0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
            ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]),
            ([0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]),
            ([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]),
            ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]),
        ];
        // Vertices are repeated per face; shared positions are merged by index below.
        let mut index: HashMap<[i64; 3], usize> = HashMap::new();
        let mut id = |p: [i64; 3], text: &mut String| {
            *index.entry(p).or_insert_with(|| {
                count += 1;
                let c = p.map(|k| k as Real * s / n as Real);
                text.push_str(&format!("v {} {} {}\n", c[0], c[1], c[2]));
                count
            })
        };
        let mut faces_text = String::new();
        for (o, u, v) in faces {
            for i in 0..n {
                for j in 0..n {
                    let at = |a: usize, b: usize| {
                        [0, 1, 2].map(|k| {
                            (o[k] * n as Real) as i64
                                + (u[k] as i64) * a as i64
                                + (v[k] as i64) * b as i64
                        })
                    };
                    let q = [at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)]
                        .map(|p| id(p, &mut text));
                    faces_text.push_str(&format!(
                        "f {} {} {}\nf {} {} {}\n",
                        q[0], q[1], q[2], q[0], q[2], q[3]
                    ));
                }
            }
        }
        text + &faces_text
    }

    fn spans(s: &dyn Solid, o: Point3, axis: usize) -> Vec<SolidSpan> {
        let mut out = Vec::new();
        s.ray_spans(&o, axis, &mut out);
        out
    }

    #[test]
    fn cylinder_chords_follow_the_circle() {
        let c =
            Cylinder::try_new(Point3::new(1.0, 2.0, -3.0), Vector3::z(), 5.0, 10.0).expect("valid");
        // An x ray at y offset 3 from the axis: chord ±4 about x = 1.
        let s = spans(&c, Point3::new(0.0, 5.0, 0.0), 0);
        assert_eq!(s.len(), 1);
        assert!((s[0].t_in + 3.0).abs() < 1e-12 && (s[0].t_out - 5.0).abs() < 1e-12);
        assert!((s[0].n_in - Vector3::new(-0.8, 0.6, 0.0)).norm() < 1e-12);
        // A z ray: the caps, outward normals −z and +z.
        let s = spans(&c, Point3::new(2.0, 2.0, 0.0), 2);
        assert_eq!((s[0].t_in, s[0].t_out), (-3.0, 7.0));
        assert_eq!((s[0].n_in, s[0].n_out), (-Vector3::z(), Vector3::z()));
        // Outside the radius, or beyond the caps: nothing.
        assert!(spans(&c, Point3::new(0.0, 7.5, 0.0), 0).is_empty());
        assert!(spans(&c, Point3::new(0.0, 2.0, 7.5), 0).is_empty());
    }

    #[test]
    fn tilted_cylinder_contains_its_axis_points_only_within_radius() {
        let axis = Vector3::new(1.0, 2.0, 2.0);
        let c = Cylinder::try_new(Point3::origin(), axis, 1.5, 9.0).expect("valid");
        let a = axis.normalize();
        let perp = a.cross(&Vector3::x()).normalize();
        for (h, r, inside) in [
            (4.0, 1.4, true),
            (4.0, 1.6, false),
            (8.9, 0.0, true),
            (9.1, 0.0, false),
        ] {
            let p = Point3::from(a * h + perp * r);
            for k in 0..3 {
                let hit = spans(&c, p, k)
                    .iter()
                    .any(|s| s.t_in <= p[k] && p[k] <= s.t_out);
                assert_eq!(hit, inside, "h {h} r {r} axis {k}");
            }
        }
        let b = c.bounds();
        assert!(b.contains(&Point3::from(a * 9.0)) && b.contains(&Point3::origin()));
    }

    #[test]
    fn rejects_bad_cylinders() {
        assert!(Cylinder::try_new(Point3::origin(), Vector3::zeros(), 1.0, 1.0).is_err());
        assert!(Cylinder::try_new(Point3::origin(), Vector3::z(), -1.0, 1.0).is_err());
        assert!(Cylinder::try_new(Point3::origin(), Vector3::z(), 1.0, Real::NAN).is_err());
    }

    #[test]
    fn rays_through_mesh_edges_and_vertices_count_once() {
        // Face vertices every 0.5 mm: rays at 0.5, 1.5, … pass through vertices and diagonals.
        let m = read_obj(&cube_obj(10.0, 20), Path::new("cube.obj")).expect("closed");
        assert!((m.volume() - 1000.0).abs() < 1e-9);
        for k in 0..3 {
            for i in 0..20 {
                for j in 0..20 {
                    let mut o = Point3::origin();
                    o[(k + 1) % 3] = 0.5 * i as Real;
                    o[(k + 2) % 3] = 0.5 * j as Real;
                    let s = spans(&m, o, k);
                    if i == 0 || j == 0 {
                        // On the box's own faces: either the face or nothing, never garbage.
                        assert!(s.len() <= 1, "{s:?}");
                        continue;
                    }
                    assert_eq!(s.len(), 1, "axis {k} at {o:?}: {s:?}");
                    assert_eq!((s[0].t_in, s[0].t_out), (0.0, 10.0));
                }
            }
        }
    }

    #[test]
    fn inward_mesh_is_turned_outwards() {
        let text = cube_obj(2.0, 1).replace("f ", "fx ");
        // Reverse each face's winding.
        let mut rev = String::new();
        for l in text.lines() {
            if let Some(rest) = l.strip_prefix("fx ") {
                let w: Vec<&str> = rest.split_whitespace().collect();
                rev.push_str(&format!("f {} {} {}\n", w[0], w[2], w[1]));
            } else {
                rev.push_str(l);
                rev.push('\n');
            }
        }
        let m = read_obj(&rev, Path::new("in.obj")).expect("closed");
        assert!((m.volume() - 8.0).abs() < 1e-12);
        assert!(m.contains(&Point3::new(1.0, 1.0, 1.0)));
        assert!(!m.contains(&Point3::new(1.0, 1.0, 3.0)));
    }

    #[test]
    fn open_mesh_is_refused_with_counts_and_an_edge() {
        let text = cube_obj(1.0, 1);
        let open: String = text
            .lines()
            .filter(|l| *l != "f 1 2 3")
            .map(|l| format!("{l}\n"))
            .collect();
        assert_ne!(open, text);
        let err = read_obj(&open, Path::new("parts/open.obj")).expect_err("open");
        let msg = err.to_string();
        assert!(msg.starts_with("parts/open.obj: "), "{msg}");
        assert!(msg.contains("3 boundary edges"), "{msg}");
        assert!(msg.contains("used by one triangle only"), "{msg}");
        match err {
            ShapeError::NotClosed {
                boundary, example, ..
            } => {
                assert_eq!(boundary, 3);
                let tri = [1usize, 2, 3];
                assert!(tri.contains(&example.0) && tri.contains(&example.1));
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn non_finite_vertex_is_refused_with_its_line() {
        let text = cube_obj(1.0, 1).replacen("v 0 0 0", "v 0 nan 0", 1);
        let err = read_obj(&text, Path::new("bad.obj")).expect_err("nan");
        assert_eq!(
            err.to_string(),
            "bad.obj:1: vertex 1 is not finite (0 NaN 0)"
        );
        let err = read_obj("v 1 x 2\n", Path::new("w.obj")).expect_err("word");
        assert_eq!(err.to_string(), "w.obj:1:5: not a number 'x'");
        let err = read_obj("v 0 0 0\nf 1 2 3\n", Path::new("i.obj")).expect_err("index");
        assert_eq!(err.to_string(), "i.obj:2:5: vertex index out of range '2'");
    }

    #[test]
    fn misoriented_and_non_manifold_are_named() {
        let text = cube_obj(1.0, 1).replacen("f 1 2 3", "f 1 3 2", 1);
        let msg = read_obj(&text, Path::new("m.obj"))
            .expect_err("bad")
            .to_string();
        assert!(msg.contains("3 edges wound the same way"), "{msg}");
        let text = cube_obj(1.0, 1) + "f 1 2 3\n";
        let msg = read_obj(&text, Path::new("n.obj"))
            .expect_err("bad")
            .to_string();
        assert!(
            msg.contains("3 edges shared by more than two triangles"),
            "{msg}"
        );
    }

    #[test]
    fn stl_binary_and_ascii_read_the_same_solid() {
        let m = read_obj(&cube_obj(3.0, 2), Path::new("c.obj")).expect("closed");
        let mut bin = vec![0u8; 80];
        bin.extend_from_slice(&(m.triangles().len() as u32).to_le_bytes());
        let mut ascii = String::from("solid c\n");
        for t in m.triangles() {
            bin.extend_from_slice(&[0u8; 12]);
            ascii.push_str("facet normal 0 0 0\nouter loop\n");
            for &i in t {
                let p = m.vertices()[i as usize];
                for k in 0..3 {
                    bin.extend_from_slice(&(p[k] as f32).to_le_bytes());
                }
                ascii.push_str(&format!("vertex {} {} {}\n", p.x, p.y, p.z));
            }
            bin.extend_from_slice(&[0u8; 2]);
            ascii.push_str("endloop\nendfacet\n");
        }
        ascii.push_str("endsolid c\n");
        for bytes in [bin, ascii.into_bytes()] {
            let s = read_stl(&bytes, Path::new("c.stl")).expect("closed");
            assert!((s.volume() - 27.0).abs() < 1e-9);
            assert_eq!(s.vertices().len(), m.vertices().len());
        }
    }

    mod props {
        use super::*;
        use proptest::prelude::*;

        proptest! {
            #![proptest_config(ProptestConfig::with_cases(200))]
            #[test]
            fn random_triangle_soups_never_panic(
                verts in proptest::collection::vec((-3i32..4, -3i32..4, -3i32..4, 0u8..20), 0..12),
                tris in proptest::collection::vec((-14i64..14, -14i64..14, -14i64..14), 0..20),
            ) {
                let mut text = String::new();
                for (x, y, z, kind) in &verts {
                    let w = match kind { 0 => "nan".to_string(), 1 => "inf".into(), _ => format!("{}", *z as f64 * 0.5) };
                    text.push_str(&format!("v {x} {y} {w}\n"));
                }
                for (a, b, c) in &tris {
                    text.push_str(&format!("f {a} {b} {c}\n"));
                }
                if let Ok(m) = read_obj(&text, Path::new("soup.obj")) {
                    for k in 0..3 {
                        for i in -8..8 {
                            let mut o = Point3::origin();
                            o[(k + 1) % 3] = i as Real * 0.5;
                            o[(k + 2) % 3] = i as Real * 0.25;
                            let s = spans(&m, o, k);
                            for w in s.windows(2) {
                                prop_assert!(w[0].t_out < w[1].t_in);
                            }
                        }
                    }
                }
                let _ = read_stl(text.as_bytes(), Path::new("soup.stl"));
            }

            #[test]
            fn random_bytes_as_stl_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
                let _ = read_stl(&bytes, Path::new("x.stl"));
            }
        }
    }
}
