//! Display geometry: what the report's picture and 3-D view show of a part and a cloud.
//!
//! **The display mesh.** The cut part's surface mesh ([`crate::cutting::mesh`]) has two
//! triangles per dexel cell of surface: a million for a 40 mm part at 0.1 mm, far more than
//! a page should carry. [`simplify`] reduces it with meshoptimizer's edge-collapse
//! simplifier (`meshopt`), which keeps a subset of the original vertices — every display
//! vertex is an exact vertex of the cut surface — and reports how far the simplified surface
//! may lie from the original. First pass: only collapses that move the surface less than
//! [`FIRST_PASS_ERROR_MM`] by meshoptimizer's measure: flat faces shrink to a
//! few triangles, curved ones keep most of their dexel resolution; if that leaves more than
//! the budget, a second pass collapses to the budget and the error it needed is added to the
//! reported one ([`DisplayMesh::error_mm`]). meshoptimizer's measure is not a strict bound on
//! the distance between the surfaces: on a finely meshed sphere the display triangles'
//! centroids lie up to about twice the reported error inside it.
//!
//! **In pieces.** A mesh of more than [`CHUNKED_ABOVE`] triangles takes the first pass in
//! pieces of `PIECE_TRIANGLES` consecutive triangles in Morton order of their centroids,
//! side by side, each with the vertices it shares with another piece locked (the pieces
//! still meet, closed), then once more joined, within the same bound, so that the seams
//! collapse too; the two passes' errors add up. The simplifier's working memory is then that
//! of a piece and the joined result, not of the whole mesh (whose ~80 MB for 660 k triangles
//! set the simulate command's peak).
//!
//! **Deviations** ([`deviations`]) are measured for each display triangle at its three
//! corners, along the triangle's normal: from a point just inside the corner (1 % of the way
//! to the centroid), the nearest crossing of the normal line with the reference surface
//! (the design model, or the part the same program cuts on the nominal machine), signed +
//! where the part lies outside the reference (material left) and − inside (a gouge). Per
//! triangle, not per vertex, because a vertex on an edge of the part belongs to faces with
//! different deviations (a face cut 0.5 mm too deep meets an uncut face along an edge that
//! lies on the reference); along the normal, not to the closest point, because near an edge
//! the closest point of the reference is on the neighbouring face, and a large display
//! triangle would spread that edge value over the whole face. Both corners of a triangle then
//! lie on one face, and for planar faces the deviation is linear across it, so the colours
//! interpolated between the corners are exact. A face with no counterpart in the reference
//! (a ledge the nominal part does not have) has no crossing near it along its normal: where
//! the crossing is more than twice as far (plus 1 µm) as the reference is from the
//! triangle's centroid, or missing, the corner takes the centroid's closest-point distance
//! instead. The crossing is looked for on the side the reference lies: ahead along the
//! outward normal when the triangle's centroid is inside the reference, behind it when
//! outside, either when on it.
//!
//! **Sag.** A display triangle is a chord of the cut surface: on a curved face its centroid
//! lies under the part, by up to the simplification's bound and more (tens of µm on a
//! bar's round face), and a tangent plane at its middle lies under its corners by as much.
//! The centroid's closest distance is therefore taken less the centroid's own distance from
//! the cut part (from the tangent plane of the part's crossing nearest it on a face like the
//! triangle's), and a corner measured from a plane near the centroid (the program on the
//! nominal machine, [`path_deviations`]) is measured from the two parts' tangent planes at
//! one place, the difference of the two: what remains is the two surfaces' offset, not the
//! display's sag. A corner measured from its own vertex shows that vertex's own error (the
//! source mesh places some, at edges, a µm or two off the part).
//!
//! **Invariant:** deterministic (meshoptimizer is sequential, the pieces are fixed by the mesh
//! and joined in order; distances run in fixed chunks joined in order); reads meshes and
//! clouds, never changes them.

use crate::cutting::mesh::TriMesh;
use crate::cutting::nominal::NominalPath;
use crate::cutting::stock::TriDexel;
use crate::math::{Aabb, Point3, Real, UnitVector3, Vector3};
use crate::report::render::nice_ceil;
use parry3d_f64::query::{PointQuery, Ray, RayCast};
use rayon::prelude::*;

/// Largest display mesh (triangles): about 3 MB of GLB, 4 MB in the page.
pub const MAX_TRIANGLES: usize = 120_000;
/// Largest displayed cloud (points).
pub const MAX_POINTS: usize = 40_000;
/// The first pass's bound (mm): far below a pixel of a part tens of millimetres across
/// (0.05 mm or more), and large enough for meshoptimizer's error measure, which is not zero
/// even for collapses within a plane, to let flat faces collapse (at 1e-4 mm it stalls with
/// most of a flat face's triangles left).
pub const FIRST_PASS_ERROR_MM: Real = 0.01;
/// Meshes of more triangles than this take [`simplify`]'s first pass in pieces.
pub const CHUNKED_ABOVE: usize = 200_000;
/// Triangles of one piece of the first pass.
const PIECE_TRIANGLES: usize = 50_000;
/// Triangles per parallel chunk of the deviation queries.
const CHUNK: usize = 1024;
/// How far towards the centroid a corner's deviation is measured from (fraction).
const CORNER_PULL: Real = 0.01;
/// Slack of the counterpart test (mm): a crossing along the normal counts as the face's
/// counterpart within twice the centroid's closest distance plus this (1 µm, so faces that
/// lie on the reference keep their along-normal value).
const COUNTERPART_SLACK_MM: Real = 1e-3;

/// A part's surface for display.
#[derive(Clone, Debug, PartialEq)]
pub struct DisplayMesh {
    /// Vertices (mm, W): a subset of the source mesh's.
    pub vertices: Vec<Point3>,
    /// Triangles, counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
    /// Triangles of the source mesh.
    pub source_triangles: usize,
    /// How far the display surface may lie from the source surface (mm), as meshoptimizer
    /// measures it.
    pub error_mm: Real,
}

/// The display mesh of `mesh`, at most `max_triangles` (see the module docs). An empty mesh
/// stays empty.
pub fn simplify(mesh: &TriMesh, max_triangles: usize) -> DisplayMesh {
    simplify_in(mesh, max_triangles, CHUNKED_ABOVE)
}

/// [`simplify`], its first pass in pieces above `pieces_above` triangles.
fn simplify_in(mesh: &TriMesh, max_triangles: usize, pieces_above: usize) -> DisplayMesh {
    let source_triangles = mesh.triangles.len();
    if mesh.vertices.is_empty() || mesh.triangles.is_empty() {
        return DisplayMesh {
            vertices: Vec::new(),
            triangles: Vec::new(),
            source_triangles,
            error_mm: 0.0,
        };
    }
    let mut b = Aabb::empty();
    for p in &mesh.vertices {
        b.grow(p);
    }
    let centre = nalgebra::center(&b.min, &b.max);
    // f32 about the centre: meshoptimizer's input; the output keeps the f64 originals.
    let positions: Vec<[f32; 3]> = mesh
        .vertices
        .iter()
        .map(|p| {
            let d = p - centre;
            [d.x as f32, d.y as f32, d.z as f32]
        })
        .collect();
    let abs = meshopt::SimplifyOptions::ErrorAbsolute;
    let (mut out, mut error_mm) = first_pass(mesh, &positions, pieces_above);
    if out.len() / 3 > max_triangles {
        let diagonal = (b.max - b.min).norm() as f32;
        let mut err2 = 0.0f32;
        out = meshopt::simplify_decoder(
            &out,
            &positions,
            max_triangles * 3,
            diagonal,
            abs,
            Some(&mut err2),
        );
        // Measured from the first pass's surface: the two moves add up.
        error_mm += Real::from(err2);
    }
    // Compact: used vertices in index order.
    let mut map = vec![u32::MAX; mesh.vertices.len()];
    let mut used: Vec<u32> = out.clone();
    used.sort_unstable();
    used.dedup();
    let vertices: Vec<Point3> = used
        .iter()
        .enumerate()
        .map(|(k, &i)| {
            map[i as usize] = k as u32;
            mesh.vertices[i as usize]
        })
        .collect();
    let triangles = out
        .chunks_exact(3)
        .map(|t| [map[t[0] as usize], map[t[1] as usize], map[t[2] as usize]])
        .collect();
    DisplayMesh {
        vertices,
        triangles,
        source_triangles,
        error_mm,
    }
}

/// The first pass of [`simplify`] (collapses within [`FIRST_PASS_ERROR_MM`]): its indices
/// into `positions` (the mesh's vertices, f32 about a centre) and the error it reports (mm).
/// A mesh of more than `pieces_above` triangles is cut into pieces of consecutive
/// triangles in Morton order of their centroids, [`PIECE_TRIANGLES`] each, simplified side by
/// side with the vertices they share locked (so the pieces still meet), and the joined
/// result simplified once more within the same bound, which lets the seams collapse: the
/// simplifier's working memory is that of a piece, not of the whole mesh. The two bounds
/// add up.
fn first_pass(mesh: &TriMesh, positions: &[[f32; 3]], pieces_above: usize) -> (Vec<u32>, Real) {
    let abs = meshopt::SimplifyOptions::ErrorAbsolute;
    // Pieces, and the joined pieces, use a few of the vertices: their working memory is
    // then that of the vertices they use (`Sparse`).
    let opts = abs | meshopt::SimplifyOptions::Sparse;
    let bound = FIRST_PASS_ERROR_MM as f32;
    let whole = |indices: &[u32], opts| {
        let mut err = 0.0f32;
        let out = meshopt::simplify_decoder(indices, positions, 0, bound, opts, Some(&mut err));
        (out, Real::from(err))
    };
    if mesh.triangles.len() <= pieces_above {
        let indices: Vec<u32> = mesh.triangles.iter().flatten().copied().collect();
        return whole(&indices, abs);
    }
    // Morton order of the centroids on a 2^21 grid over the box of the positions; ties in
    // triangle order (a stable sort): the pieces depend on the mesh only.
    let (mut lo, mut hi) = ([f32::MAX; 3], [f32::MIN; 3]);
    for p in positions {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    let cells = Real::from((1u32 << 21) - 1);
    let morton = |t: &[u32; 3]| -> u64 {
        let c: [u64; 3] = std::array::from_fn(|a| {
            let mean = t
                .iter()
                .map(|&i| Real::from(positions[i as usize][a]))
                .sum::<Real>()
                / 3.0;
            let span = Real::from(hi[a] - lo[a]).max(Real::MIN_POSITIVE);
            (((mean - Real::from(lo[a])) / span).clamp(0.0, 1.0) * cells) as u64
        });
        (0..21).fold(0, |m, bit| {
            m | (0..3).fold(0, |b, a| b | ((c[a] >> bit) & 1) << (3 * bit + a))
        })
    };
    let keys: Vec<u64> = mesh.triangles.par_iter().map(morton).collect();
    let mut order: Vec<u32> = (0..mesh.triangles.len() as u32).collect();
    order.par_sort_by_key(|&t| keys[t as usize]);
    drop(keys);
    // A vertex used by two pieces is locked in both.
    let pieces: Vec<&[u32]> = order.chunks(PIECE_TRIANGLES).collect();
    let mut owner = vec![u32::MAX; positions.len()];
    let mut locked = vec![false; positions.len()];
    for (k, piece) in pieces.iter().enumerate() {
        for &t in *piece {
            for &v in &mesh.triangles[t as usize] {
                let o = &mut owner[v as usize];
                if *o == u32::MAX {
                    *o = k as u32;
                } else if *o != k as u32 {
                    locked[v as usize] = true;
                }
            }
        }
    }
    drop(owner);
    let simplified: Vec<(Vec<u32>, f32)> = pieces
        .par_iter()
        .map(|piece| {
            let indices: Vec<u32> = piece
                .iter()
                .flat_map(|&t| mesh.triangles[t as usize])
                .collect();
            let mut err = 0.0f32;
            let out = meshopt::simplify_with_locks_decoder(
                &indices,
                positions,
                &locked,
                0,
                bound,
                opts,
                Some(&mut err),
            );
            (out, err)
        })
        .collect();
    let err_pieces = simplified
        .iter()
        .map(|(_, e)| Real::from(*e))
        .fold(0.0, Real::max);
    let joined: Vec<u32> = simplified.into_iter().flat_map(|(out, _)| out).collect();
    let (out, err) = whole(&joined, opts);
    (out, err_pieces + err)
}

/// A surface deviations are measured from: a triangle mesh (mm, W) indexed for ray casts.
pub struct ReferenceSurface {
    shape: parry3d_f64::shape::TriMesh,
    reach: Real,
}

impl std::fmt::Debug for ReferenceSurface {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ReferenceSurface")
            .field("triangles", &self.shape.num_triangles())
            .finish()
    }
}

impl ReferenceSurface {
    /// The surface of a triangle mesh; `None` if it has no triangles or parry refuses it.
    pub fn new(vertices: Vec<Point3>, triangles: Vec<[u32; 3]>) -> Option<Self> {
        let mut b = Aabb::empty();
        for p in &vertices {
            b.grow(p);
        }
        let shape = parry3d_f64::shape::TriMesh::new(vertices, triangles).ok()?;
        Some(Self {
            shape,
            reach: (b.max - b.min).norm().max(1.0),
        })
    }

    /// The signed deviation of the surface point `p` with outward normal `n` (see the
    /// module docs): + material left, − gouge, `None` without a crossing within reach.
    /// `side` is which side of the reference the face lies on (− inside, + outside, 0 on
    /// it or unknown): inside, the counterpart lies ahead along `n`; outside, behind; on
    /// it, whichever is nearer.
    pub fn deviation_along(&self, p: &Point3, n: &UnitVector3, side: Real) -> Option<Real> {
        let cast = |dir: Vector3| {
            self.shape
                .cast_local_ray(&Ray::new(*p, dir), self.reach, false)
        };
        let ahead = || cast(n.into_inner()).map(|t| -t);
        let behind = || cast(-n.into_inner());
        if side < 0.0 {
            ahead()
        } else if side > 0.0 {
            behind()
        } else {
            match (ahead(), behind()) {
                (Some(a), Some(b)) => Some(if -a <= b { a } else { b }),
                (a, b) => a.or(b),
            }
        }
    }
}

impl ReferenceSurface {
    /// Distance of `p` from the surface (mm), signed by the outward normal of the nearest
    /// triangle when the nearest point lies inside one (+ outside), unsigned at its edges
    /// and corners.
    pub fn signed_distance(&self, p: &Point3) -> Real {
        let (proj, feature) = self.shape.project_local_point_and_get_feature(p);
        let d = (p - proj.point).norm();
        match feature {
            parry3d_f64::shape::FeatureId::Face(i) => {
                let n = self.shape.num_triangles() as u32;
                let t = self.shape.triangle(i % n.max(1));
                let normal = (t.b - t.a).cross(&(t.c - t.a));
                if (p - proj.point).dot(&normal) < 0.0 {
                    -d
                } else {
                    d
                }
            }
            _ => d,
        }
    }
}

/// The signed distance of each point from `reference` (mm, see
/// [`ReferenceSurface::signed_distance`]).
pub fn distances(points: &[Point3], reference: &ReferenceSurface) -> Vec<Real> {
    points
        .par_chunks(CHUNK)
        .flat_map_iter(|c| c.iter().map(|p| reference.signed_distance(p)))
        .collect()
}

/// The deviation at each corner of each display triangle of the cut part `cut` from
/// `reference` (mm; see the module docs); NaN for a degenerate triangle. The centroid's
/// closest distance is taken less its distance from the cut part's own surface (the
/// tangent plane of the cut part's crossing nearest it on a face like the triangle's): the
/// display triangle's sag on a curved face, which is not the part's.
pub fn deviations(
    mesh: &DisplayMesh,
    reference: &ReferenceSurface,
    cut: &TriDexel,
) -> Vec<[Real; 3]> {
    per_triangle(mesh, |_, p, n, centre| {
        let sag = sag(cut, &centre, &n);
        let n = UnitVector3::new_unchecked(n);
        let nearest = reference.signed_distance(&centre) - sag;
        let side = if nearest.abs() <= COUNTERPART_SLACK_MM {
            0.0
        } else {
            nearest
        };
        p.map(|q| {
            let pulled = q + (centre - q) * CORNER_PULL;
            match reference.deviation_along(&pulled, &n, side) {
                Some(d) if d.abs() <= 2.0 * nearest.abs() + COUNTERPART_SLACK_MM => d,
                _ => nearest,
            }
        })
    })
}

/// How far `centre` (a display triangle's centroid, `n` its unit normal) lies outside the
/// cut part `cut` (mm; − under it, as a chord of a curved face does): its distance from the
/// tangent plane of the cut part's crossing nearest it on a face like the triangle's (within
/// [`SAME_FACE_COS`]); 0 without one within [`PART_REACH_MM`].
fn sag(cut: &TriDexel, centre: &Point3, n: &Vector3) -> Real {
    cut.nearest_crossing(centre, PART_REACH_MM, |m| n.dot(m) >= SAME_FACE_COS)
        .map_or(0.0, |(x, m)| (centre - x).dot(&m))
}

/// Reach (mm) of the search for a display corner's counterpart on a reference part's
/// tri-dexel ([`part_deviations`]): deviations beyond it are not measured.
pub const PART_REACH_MM: Real = 2.0;

/// What a part's deviations are measured from: a surface (the design model) or the program
/// on the nominal machine (read as a distance near the cut part, not swept).
#[derive(Debug)]
pub enum ReferenceModel {
    /// A triangle mesh ([`deviations`]).
    Surface(ReferenceSurface),
    /// The program on the nominal machine ([`path_deviations`]).
    Path(NominalPath),
}

impl ReferenceModel {
    /// The deviations of `mesh`'s triangle corners (the display mesh of the cut part `cut`)
    /// from this reference.
    pub fn deviations(&self, mesh: &DisplayMesh, cut: &TriDexel) -> Vec<[Real; 3]> {
        match self {
            ReferenceModel::Surface(s) => deviations(mesh, s, cut),
            ReferenceModel::Path(p) => path_deviations(mesh, cut, p),
        }
    }
}

/// `f(corner indices, corners, unit normal, centroid)` for every display triangle, in
/// parallel chunks joined in order; NaN corners for a degenerate triangle.
fn per_triangle(
    mesh: &DisplayMesh,
    f: impl Fn(&[u32; 3], [Point3; 3], Vector3, Point3) -> [Real; 3] + Sync + Send,
) -> Vec<[Real; 3]> {
    mesh.triangles
        .par_chunks(CHUNK)
        .flat_map_iter(|c| {
            c.iter().map(|t| {
                corners_of(mesh, t).map_or([Real::NAN; 3], |(p, n, centre)| f(t, p, n, centre))
            })
        })
        .collect()
}

/// A display triangle's corners, unit normal and centroid; `None` for a degenerate one.
fn corners_of(mesh: &DisplayMesh, t: &[u32; 3]) -> Option<([Point3; 3], Vector3, Point3)> {
    let p = t.map(|i| mesh.vertices[i as usize]);
    let n = (p[1] - p[0]).cross(&(p[2] - p[0]));
    if n.norm() == 0.0 || !n.norm().is_finite() {
        return None;
    }
    let centre = Point3::from((p[0].coords + p[1].coords + p[2].coords) / 3.0);
    Some((p, n.normalize(), centre))
}

/// A corner's deviation from its counterpart along the normal (`along`) and the centroid's
/// closest distance (`nearest`): the counterpart when it lies within twice the closest
/// distance (plus [`COUNTERPART_SLACK_MM`]), else the closest distance; NaN with neither.
fn counterpart(along: Option<Real>, nearest: Option<Real>) -> Real {
    match (along, nearest) {
        (Some(d), Some(c)) if d.abs() <= 2.0 * c.abs() + COUNTERPART_SLACK_MM => d,
        (_, Some(c)) => c,
        (Some(d), None) => d,
        (None, None) => Real::NAN,
    }
}

/// The deviations of `mesh`'s triangle corners (the display mesh of the cut part `cut`) from
/// the part `path` cuts on the nominal machine, as [`deviations`] measures them from a
/// reference mesh, read from the nominal part's distance near the cut surface
/// ([`NominalPath::nearest`]) instead of a mesh of it. At each display vertex the nominal
/// part's nearest point and its normal `N` give its tangent plane there; a corner's
/// counterpart along the triangle's normal `n` is that plane's crossing with the normal line
/// from the pulled corner, where the plane faces like the triangle (`n·N ≥`
/// [`SAME_FACE_COS`]). A triangle whose three corners have such a plane takes their
/// counterparts. Elsewhere (a corner at an edge of the nominal part, whose nearest point is
/// on the other face) the corner takes the centroid's tangent plane instead, and the
/// centroid's signed distance is the closest distance of the counterpart test. A corner
/// with neither within [`PART_REACH_MM`] is NaN (not coloured).
pub fn path_deviations(mesh: &DisplayMesh, cut: &TriDexel, path: &NominalPath) -> Vec<[Real; 3]> {
    let within = |d: Real| d.abs() <= PART_REACH_MM;
    // The nominal part's nearest point to `v` and its outward normal there.
    let plane_at = |v: &Point3| {
        path.nearest(cut, v)
            .filter(|f| within(f.distance))
            .map(|f| (v - f.normal * f.distance, f.normal))
    };
    let at_vertex: Vec<Option<(Point3, Vector3)>> = mesh
        .vertices
        .par_chunks(CHUNK)
        .flat_map_iter(|c| c.iter().map(plane_at))
        .collect();
    per_triangle(mesh, |t, p, n, centre| {
        // A corner's counterpart on the vertex's tangent plane, where it faces like
        // the triangle.
        let facing = |plane: Option<(Point3, Vector3)>, q: &Point3| {
            plane.and_then(|(x, big_n): (Point3, Vector3)| {
                let facing = n.dot(&big_n);
                (facing >= SAME_FACE_COS)
                    .then(|| (q - x).dot(&big_n) / facing)
                    .filter(|d| within(*d))
            })
        };
        let pulled: [Point3; 3] = std::array::from_fn(|k| p[k] + (centre - p[k]) * CORNER_PULL);
        let mut along: [Option<Real>; 3] =
            std::array::from_fn(|k| facing(at_vertex[t[k] as usize], &pulled[k]));
        if along.iter().all(Option::is_some) {
            return along.map(|d| d.unwrap_or(Real::NAN));
        }
        // A vertex whose nearest point lies on another face of the nominal part (at
        // an edge): a tangent plane near the centroid instead, and its distance for the
        // counterpart test, each less the same measure of the cut part's own tangent
        // plane there. The triangle is a chord of the cut surface: on a curved face its
        // inside (the centroid) lies under the surface, and its corners above a tangent
        // plane at the middle, by the display's sag (up to tens of µm); measured from
        // the two parts' planes at one place (the cut part's crossing nearest the
        // centroid on a face like the triangle's, and the nominal part's nearest point
        // to that crossing), the sag is in both and cancels, leaving the two surfaces'
        // offset. Without such a crossing, the nominal part's plane at the centroid alone.
        let actual = cut.nearest_crossing(&centre, PART_REACH_MM, |m| n.dot(m) >= SAME_FACE_COS);
        let central = plane_at(actual.as_ref().map_or(&centre, |(x, _)| x));
        let from_actual = |q: &Point3| actual.map_or(0.0, |(x, m)| (q - x).dot(&m) / n.dot(&m));
        for k in 0..3 {
            if along[k].is_none() {
                along[k] = facing(central, &pulled[k]).map(|d| d - from_actual(&pulled[k]));
            }
        }
        let nearest = central.map(|(x, big_n)| {
            (centre - x).dot(&big_n) - actual.map_or(0.0, |(x, m)| (centre - x).dot(&m))
        });
        along.map(|along| counterpart(along, nearest))
    })
}

/// Least cosine between a display triangle's normal and the nominal part's normal at a
/// corner's nearest point for [`path_deviations`] to take that point's tangent plane as the
/// triangle's face (20°: creases between passes of a tool stay within it; the two faces of
/// an edge of the part do not).
pub const SAME_FACE_COS: Real = 0.94;

/// The deviations of `mesh`'s triangle corners from the surface of the cut part `part`, as
/// [`deviations`] measures them from a reference mesh, read from the part's crossings
/// instead of a mesh of it: a corner's counterpart along the triangle's normal is the
/// part's surface along the dexel rays most nearly along the normal
/// ([`TriDexel::offset_along`], the crossings facing like the triangle, interpolated
/// between the four rays around the corner); the centroid's closest distance is that from
/// the tangent plane of the nearest crossing ([`TriDexel::nearest_offset`]); the same
/// counterpart test. A corner with neither within [`PART_REACH_MM`] is NaN (not coloured).
pub fn part_deviations(mesh: &DisplayMesh, part: &TriDexel, cut: &TriDexel) -> Vec<[Real; 3]> {
    per_triangle(mesh, |_, p, n, centre| {
        let nearest = part
            .nearest_offset(&centre, PART_REACH_MM)
            .map(|d| d - sag(cut, &centre, &n));
        p.map(|q| {
            let pulled = q + (centre - q) * CORNER_PULL;
            counterpart(part.offset_along(&pulled, &n, PART_REACH_MM), nearest)
        })
    })
}

/// A symmetric colour range (mm) for `values`: the 99.5th percentile of |value| rounded up
/// to a 1-2-5 step in µm (at least 1 µm), so a few edge points do not wash out the rest;
/// 1 µm when none is finite.
pub fn colour_range_mm(values: &[Real]) -> Real {
    let mut a: Vec<Real> = values
        .iter()
        .filter(|v| v.is_finite())
        .map(|v| v.abs() * 1e3)
        .collect();
    if a.is_empty() {
        return 1e-3;
    }
    a.sort_by(Real::total_cmp);
    // Within 1 ppm of a step counts as the step (a 0.5 mm deviation computed as
    // 0.5000001 mm keeps the ±500 µm scale).
    let q = a[(a.len() - 1) * 995 / 1000] * (1.0 - 1e-6);
    nice_ceil(q.max(1.0)) * 1e-3
}

/// The colour range (mm) of a display mesh's corner deviations: as [`colour_range_mm`],
/// but the percentile weighs each corner by a third of its triangle's area, so the slivers
/// along edges and ledges (many corners, little surface) do not set the scale.
pub fn area_colour_range_mm(mesh: &DisplayMesh, deviations: &[[Real; 3]]) -> Real {
    let mut w: Vec<(Real, Real)> = Vec::new();
    for (t, d) in mesh.triangles.iter().zip(deviations) {
        let p = t.map(|i| mesh.vertices[i as usize]);
        let area = (p[1] - p[0]).cross(&(p[2] - p[0])).norm() / 6.0;
        w.extend(
            d.iter()
                .filter(|x| x.is_finite())
                .map(|x| (x.abs() * 1e3, area)),
        );
    }
    let total: Real = w.iter().map(|x| x.1).sum();
    if w.is_empty() || total <= 0.0 || !total.is_finite() {
        return colour_range_mm(&deviations.iter().flatten().copied().collect::<Vec<_>>());
    }
    w.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut acc = 0.0;
    let mut q = w[w.len() - 1].0;
    for (v, a) in &w {
        acc += a;
        if acc >= 0.995 * total {
            q = *v;
            break;
        }
    }
    nice_ceil((q * (1.0 - 1e-6)).max(1.0)) * 1e-3
}

/// The figures behind a display mesh's deviation colours.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfaceDeviation {
    /// Triangle corners with a deviation (3 per triangle counted).
    pub corners: usize,
    /// Largest corner deviation (mm), its corner and its triangle's centroid.
    pub max: Extreme,
    /// Smallest corner deviation (mm), likewise.
    pub min: Extreme,
    /// Mean over the surface (mm).
    pub mean_mm: Real,
    /// Root mean square over the surface (mm).
    pub rms_mm: Real,
}

/// Where a deviation figure is reached.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Extreme {
    /// The value (mm).
    pub value_mm: Real,
    /// The corner that has it.
    pub corner: Point3,
    /// The centroid of the corner's triangle: a point inside the face it lies on.
    pub centroid: Point3,
}

/// Corner values within this (mm) of an extreme reach it: of those, the largest triangle's
/// corner is named, so that a face cut a millimetre off is named rather than a sliver along
/// its edge with the same value.
const EXTREME_TIE_MM: Real = 1e-6;

/// The figures of a display mesh's corner deviations (`deviations`, as [`deviations`] gives
/// them): the largest and smallest corner value and where (of the corners within
/// `EXTREME_TIE_MM` of it, the one on the largest triangle), and the mean and RMS over the
/// surface with the deviation linear across each triangle between its corners — as the
/// colours interpolate it — integrated exactly: over a triangle of corners a, b, c the mean
/// is (a + b + c)/3 and the mean square (a² + b² + c² + ab + bc + ca)/6, weighted by its
/// area. Triangles with a corner that has no value (degenerate) are left out; `None` if none
/// has all three.
pub fn surface_deviation(mesh: &DisplayMesh, deviations: &[[Real; 3]]) -> Option<SurfaceDeviation> {
    let triangles: Vec<([Point3; 3], [Real; 3], Real)> = mesh
        .triangles
        .iter()
        .zip(deviations)
        .filter(|(_, d)| d.iter().all(|x| x.is_finite()))
        .map(|(t, d)| {
            let p = t.map(|i| mesh.vertices[i as usize]);
            (p, *d, 0.5 * (p[1] - p[0]).cross(&(p[2] - p[0])).norm())
        })
        .collect();
    let values = || triangles.iter().flat_map(|t| t.1);
    let hi = values().fold(Real::NEG_INFINITY, Real::max);
    let lo = values().fold(Real::INFINITY, Real::min);
    let at = |target: Real| {
        let mut best: Option<(Real, Extreme)> = None;
        for (p, d, a) in &triangles {
            for (v, q) in d.iter().zip(p) {
                if (v - target).abs() <= EXTREME_TIE_MM && best.is_none_or(|b| *a > b.0) {
                    let centroid = Point3::from((p[0].coords + p[1].coords + p[2].coords) / 3.0);
                    best = Some((
                        *a,
                        Extreme {
                            value_mm: target,
                            corner: *q,
                            centroid,
                        },
                    ));
                }
            }
        }
        best.map(|b| b.1)
    };
    let (max, min) = (at(hi)?, at(lo)?);
    let (mut area, mut sum, mut sum2) = (0.0, 0.0, 0.0);
    for (_, [x, y, z], a) in &triangles {
        area += a;
        sum += a * (x + y + z) / 3.0;
        sum2 += a * (x * x + y * y + z * z + x * y + y * z + z * x) / 6.0;
    }
    let (mean_mm, rms_mm) = if area > 0.0 {
        (sum / area, (sum2 / area).max(0.0).sqrt())
    } else {
        (0.0, 0.0)
    };
    Some(SurfaceDeviation {
        corners: 3 * triangles.len(),
        max,
        min,
        mean_mm,
        rms_mm,
    })
}

/// Whether the triangle lies on a face of `b` (within 1 nm): part of the stock as it was.
fn on_box(t: [Point3; 3], b: &Aabb) -> bool {
    const EPS: Real = 1e-6;
    (0..3).any(|k| {
        t.iter().all(|p| (p[k] - b.min[k]).abs() < EPS)
            || t.iter().all(|p| (p[k] - b.max[k]).abs() < EPS)
    })
}

/// The direction the part is best seen from (from the part towards the eye) and the
/// screen's up: the area-weighted mean outward normal of the machined surface (triangles
/// not on a face of `stock_box`), tilted 30° towards +z (or −y when it looks down) and a
/// little sideways so the walls beside a face show too. Without machined surface, or when
/// its normals cancel, an isometric view from (1, −1, 1).
pub fn view_direction(mesh: &DisplayMesh, stock_box: &Aabb) -> (UnitVector3, Vector3) {
    let mut sum = Vector3::zeros();
    let mut area = 0.0;
    for t in &mesh.triangles {
        let p = t.map(|i| mesh.vertices[i as usize]);
        if on_box(p, stock_box) {
            continue;
        }
        let n = (p[1] - p[0]).cross(&(p[2] - p[0])) * 0.5;
        sum += n;
        area += n.norm();
    }
    let z = Vector3::z();
    let d = if area > 0.0 && sum.norm() > 0.05 * area {
        sum.normalize()
    } else {
        return (UnitVector3::new_normalize(Vector3::new(1.0, -1.0, 1.0)), z);
    };
    // Tilt towards the screen's up, and a little sideways.
    let (up, tilt_to) = if d.z.abs() > 0.9 {
        (Vector3::y(), -Vector3::y() * d.z.signum())
    } else {
        (z, z)
    };
    let lift = (tilt_to - d * tilt_to.dot(&d)).normalize();
    let side = lift.cross(&d).normalize();
    let eye = UnitVector3::new_normalize(d + lift * 0.577 + side * 0.3);
    (eye, up)
}

/// The screen's up for a view from `eye` (from the part towards the eye): +z, or +y when
/// the view looks along z (within about 25°).
pub fn view_up(eye: &UnitVector3) -> Vector3 {
    if eye.z.abs() > 0.9 {
        Vector3::y()
    } else {
        Vector3::z()
    }
}

/// Indices of at most `max` of `n` items, evenly strided (deterministic).
pub fn decimate(n: usize, max: usize) -> Vec<usize> {
    if max == 0 {
        return Vec::new();
    }
    if n <= max {
        return (0..n).collect();
    }
    let stride = n.div_ceil(max);
    (0..n).step_by(stride).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The closed surface of the cube [−10, 10]³ with an n × n grid on each face, two
    /// triangles per square, outward.
    fn cube(n: i32) -> TriMesh {
        let mut m = TriMesh::default();
        let mut ids = std::collections::HashMap::new();
        let h = 20.0 / Real::from(n);
        let mut id = |p: [i32; 3], m: &mut TriMesh| {
            *ids.entry(p).or_insert_with(|| {
                let c = |k: usize| Real::from(p[k]) * h - 10.0;
                m.vertices.push(Point3::new(c(0), c(1), c(2)));
                (m.vertices.len() - 1) as u32
            })
        };
        for axis in 0..3 {
            for side in [0, n] {
                let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
                for a in 0..n {
                    for b in 0..n {
                        let q = |da: i32, db: i32| {
                            let mut p = [0; 3];
                            p[axis] = side;
                            p[u] = a + da;
                            p[v] = b + db;
                            p
                        };
                        let t = [q(0, 0), q(1, 0), q(1, 1), q(0, 1)].map(|p| id(p, &mut m));
                        if side == n {
                            m.triangles.extend([[t[0], t[1], t[2]], [t[0], t[2], t[3]]]);
                        } else {
                            m.triangles.extend([[t[0], t[2], t[1]], [t[0], t[3], t[2]]]);
                        }
                    }
                }
            }
        }
        m
    }

    #[test]
    fn a_cube_of_small_triangles_simplifies_to_a_few_exact_ones() {
        let m = cube(40);
        assert_eq!(m.signed_volume().round(), 8000.0);
        let d = simplify(&m, MAX_TRIANGLES);
        assert!(d.triangles.len() <= 24, "{} triangles", d.triangles.len());
        assert!(d.error_mm <= FIRST_PASS_ERROR_MM);
        // Every display vertex is a source vertex; the solid is kept.
        assert!(d.vertices.iter().all(|p| m.vertices.contains(p)));
        let shown = TriMesh {
            vertices: d.vertices.clone(),
            triangles: d.triangles.clone(),
        };
        assert!((shown.signed_volume() - 8000.0).abs() < 1e-6);
        assert_eq!(d, simplify(&m, MAX_TRIANGLES));
    }

    /// Each directed edge of `tris` once and its reverse once: a closed, consistently
    /// oriented surface with no crack.
    fn closed(tris: &[[u32; 3]]) -> bool {
        let mut edges = std::collections::HashMap::new();
        for t in tris {
            for k in 0..3 {
                *edges.entry((t[k], t[(k + 1) % 3])).or_insert(0) += 1;
            }
        }
        edges
            .iter()
            .all(|(&(a, b), &n)| n == 1 && edges.get(&(b, a)) == Some(&1))
    }

    #[test]
    fn a_large_mesh_simplified_in_pieces_stays_closed_and_within_its_bound() {
        // A sphere of radius 10 mm (the cube's 190 × 190 face grids pushed out to it):
        // 433,200 triangles, so the first pass runs in pieces.
        let r = 10.0;
        let mut m = cube(190);
        for p in &mut m.vertices {
            p.coords *= r / p.coords.norm();
        }
        assert!(m.triangles.len() > CHUNKED_ABOVE);
        assert!(closed(&m.triangles));
        // How far the source's own triangles lie inside the sphere (their sagitta).
        let centroid = |v: &[Point3], t: &[u32; 3]| {
            (v[t[0] as usize].coords + v[t[1] as usize].coords + v[t[2] as usize].coords) / 3.0
        };
        let sag = m
            .triangles
            .iter()
            .map(|t| r - centroid(&m.vertices, t).norm())
            .fold(0.0, Real::max);
        let d = simplify(&m, MAX_TRIANGLES);
        // The pieces meet: their shared vertices were locked, so the surface has no crack.
        assert!(closed(&d.triangles), "the pieces leave a crack");
        assert!(
            d.vertices
                .iter()
                .all(|p| (p.coords.norm() - r).abs() < 1e-9)
        );
        assert!(d.triangles.len() < m.triangles.len() / 4);
        assert!(d.triangles.len() <= MAX_TRIANGLES);
        // Two passes of at most the first pass's bound each, by meshoptimizer's measure.
        assert!(d.error_mm <= 2.0 * FIRST_PASS_ERROR_MM, "{}", d.error_mm);
        // How far the display surface lies from the sphere (its triangles' centroids), beyond
        // the source's own sagitta: no more than half again what the whole mesh simplified
        // at once leaves. (meshoptimizer's measure is not a bound on this distance: the
        // whole mesh's triangles reach about twice its reported error.)
        let worst = |d: &DisplayMesh| {
            d.triangles
                .iter()
                .map(|t| (r - centroid(&d.vertices, t).norm()).abs())
                .fold(0.0, Real::max)
        };
        let whole = simplify_in(&m, MAX_TRIANGLES, usize::MAX);
        assert!(closed(&whole.triangles));
        let (w, w1) = (worst(&d), worst(&whole));
        assert!(w > sag && w1 > sag, "the simplification moved nothing");
        assert!(w - sag <= 1.5 * (w1 - sag), "in pieces {w}, whole {w1}");
        assert!(
            w <= 2.0 * FIRST_PASS_ERROR_MM + w1,
            "in pieces {w}, whole {w1}"
        );
        // The sphere's volume: 4/3·π·r³, less the source's facets and the simplification.
        let shown = TriMesh {
            vertices: d.vertices.clone(),
            triangles: d.triangles.clone(),
        };
        let ball = 4.0 / 3.0 * std::f64::consts::PI * r * r * r;
        let area = 4.0 * std::f64::consts::PI * r * r;
        let v = shown.signed_volume();
        assert!(v < ball && v > ball - area * w, "{v} vs {ball}");
        assert_eq!(d, simplify(&m, MAX_TRIANGLES));
    }

    #[test]
    fn a_large_cube_simplified_in_pieces_keeps_its_faces_exactly() {
        let m = cube(190);
        assert!(m.triangles.len() > CHUNKED_ABOVE);
        let d = simplify(&m, MAX_TRIANGLES);
        assert!(closed(&d.triangles));
        // The seams between the pieces collapse in the joined pass: a few triangles a face.
        assert!(
            d.triangles.len() <= 6 * 64,
            "{} triangles",
            d.triangles.len()
        );
        let shown = TriMesh {
            vertices: d.vertices.clone(),
            triangles: d.triangles.clone(),
        };
        assert!((shown.signed_volume() - 8000.0).abs() < 1e-6);
        assert!(d.vertices.iter().all(|p| m.vertices.contains(p)));
    }

    #[test]
    fn a_bumpy_surface_is_cut_to_the_budget_and_says_how_far_it_moved() {
        let mut m = cube(40);
        for (k, p) in m.vertices.iter_mut().enumerate() {
            p.coords *= 1.0 + 0.01 * ((k * 7919) % 13) as Real;
        }
        let d = simplify(&m, 500);
        assert!(d.triangles.len() <= 500);
        assert!(d.error_mm > FIRST_PASS_ERROR_MM);
        assert_eq!(d.source_triangles, 19200);
    }

    #[test]
    fn deviations_are_measured_along_each_face_normal_not_to_the_nearest_face() {
        // Reference: the cube [−10, 10]³. Part: the same cube with its −y face 0.5 mm
        // further in (a gouge) — shown by its −y face and its −z face.
        let r = cube(4);
        let reference = ReferenceSurface::new(r.vertices.clone(), r.triangles.clone()).unwrap();
        let d = DisplayMesh {
            vertices: vec![
                Point3::new(-10.0, -9.5, -10.0),
                Point3::new(10.0, -9.5, -10.0),
                Point3::new(10.0, -9.5, 10.0),
                Point3::new(10.0, 10.0, -10.0),
            ],
            // The −y face (normal −y) and a piece of the −z face (normal −z), sharing the
            // edge y = −9.5, z = −10, which lies on the reference's −z face.
            triangles: vec![[0, 1, 2], [0, 3, 1]],
            source_triangles: 2,
            error_mm: 0.0,
        };
        // The cut part behind the display triangles (their sag on it is zero: all plane).
        let part = TriDexel::new_box(
            Aabb {
                min: Point3::new(-10.0, -9.5, -10.0),
                max: Point3::new(10.0, 10.0, 10.0),
            },
            0.5,
            1e9,
        )
        .expect("fits");
        let dev = deviations(&d, &reference, &part);
        for c in dev[0] {
            assert!((c + 0.5).abs() < 1e-9, "{c}");
        }
        for c in dev[1] {
            assert!(c.abs() < 1e-9, "{c}");
        }
        // A ledge facing −z at z = 0, 0.4 mm outside the −y face: no counterpart along −z
        // (the reference's −z face is 10 mm away), so the distance from its centroid.
        let ledge = DisplayMesh {
            vertices: vec![
                Point3::new(-5.0, -10.4, 0.0),
                Point3::new(5.0, -10.4, 0.0),
                Point3::new(5.0, -10.3, 0.0),
            ],
            triangles: vec![[0, 2, 1]],
            source_triangles: 1,
            error_mm: 0.0,
        };
        let dev = deviations(&ledge, &reference, &part);
        let expected = 10.4 - 1.0 / 3.0 * 0.1 - 10.0;
        for c in dev[0] {
            assert!((c - expected).abs() < 1e-9, "{c} vs {expected}");
        }
    }

    /// A slot cut by a flat Ø6 mm end mill into the block [−10, 10]² × [0, 20] at pitch
    /// 0.1 mm: the tip at z = 12 moving from x = −15 to x = 2 along y = 0 (two walls, a
    /// floor, a half-round end), on the nominal pose and on the pose moved by `t`.
    fn slot(t: &crate::math::Isometry3) -> TriDexel {
        use crate::cutting::sweep::TranslatedTool;
        use crate::cutting::tool::{Tool, ToolKind};
        let b = Aabb {
            min: Point3::new(-10.0, -10.0, 0.0),
            max: Point3::new(10.0, 10.0, 20.0),
        };
        let mut s = TriDexel::new_box(b, 0.1, 1e9).expect("fits");
        let tool = Tool::try_new(ToolKind::Flat, 6.0, 30.0).expect("valid");
        let cut = TranslatedTool::new(
            tool,
            t * Point3::new(-15.0, 0.0, 12.0),
            t * Vector3::new(17.0, 0.0, 0.0),
            UnitVector3::new_normalize(t * Vector3::z()),
        );
        assert!(s.remove(&cut, 1));
        s
    }

    #[test]
    fn deviations_from_a_cut_part_are_its_displacement_along_the_normal() {
        // The part cut on a pose moved by the small rigid motion p ↦ R·p + e: every point of
        // its cut surface is the nominal one moved by u(p) = (R − I)·p + e, so its deviation
        // along the outward normal n is u(p)·n (to first order: the second-order terms,
        // |u|²/(tool radius) and |R − I|·|u|, are below 0.2 µm here); the stock's own
        // faces, cut by neither, deviate 0.
        use crate::cutting::adaptive::{AdaptiveOptions, mesh_stock_adaptive};
        use crate::math::Isometry3;
        let e = Vector3::new(0.012, 0.021, -0.017);
        let moved = Isometry3::new(e, Vector3::new(3e-4, -2e-4, 1e-4));
        let nominal = slot(&Isometry3::identity());
        let part = slot(&moved);
        let (mesh, _) = mesh_stock_adaptive(&part, &AdaptiveOptions::default()).expect("meshes");
        let shown = simplify(&mesh, MAX_TRIANGLES);
        let expected = |p: &Point3, n: &Vector3| {
            let on_stock = [p.x.abs() - 10.0, p.y.abs() - 10.0, p.z, p.z - 20.0]
                .iter()
                .any(|d| d.abs() < 1e-6);
            if on_stock {
                0.0
            } else {
                ((moved * p) - p).dot(n)
            }
        };
        // On the plane faces (the walls, the floor, the stock's faces: triangles whose normal
        // is within 0.01 rad of an axis) more than 0.3 mm from their edges, the formula
        // holds exactly (the display triangles lie in the faces).
        let from_part = part_deviations(&shown, &nominal, &part);
        let mut planar = 0;
        for (t, d) in shown.triangles.iter().zip(&from_part) {
            let p = t.map(|i| shown.vertices[i as usize]);
            let n = (p[1] - p[0]).cross(&(p[2] - p[0])).normalize();
            // The walls |y| = 3 and the floor z = 12 short of the half-round end (x < 2), the
            // stock's top away from the slot.
            let wall = |q: &Point3| {
                (q.y.abs() - 3.0).abs() < 0.05 && q.z > 12.3 && q.z < 19.7 && q.x < 1.7
            };
            let floor = |q: &Point3| (q.z - 12.0).abs() < 0.05 && q.y.abs() < 2.7 && q.x < 1.7;
            let top = |q: &Point3| (q.z - 20.0).abs() < 1e-6 && (q.y.abs() > 3.3 || q.x > 5.3);
            if n.amax() < 1.0 - 5e-5 {
                continue;
            }
            for (q, v) in p.iter().zip(d) {
                if q.x < -9.7 || ![wall, floor, top].iter().any(|face| face(q)) {
                    continue;
                }
                planar += 1;
                let want = expected(q, &n);
                assert!(
                    (v - want).abs() < 5e-4,
                    "at {q:?} normal {n:?}: {v} mm, want {want}"
                );
            }
        }
        assert!(planar >= 20, "{planar} corners on plane faces");
        // Everywhere (the half-round end, shown by chords, and the edges), the same values
        // as measured from the nominal part's mesh, within the two surfaces' own errors.
        let (nm, _) = mesh_stock_adaptive(&nominal, &AdaptiveOptions::default()).expect("meshes");
        let surface = ReferenceSurface::new(nm.vertices, nm.triangles).expect("closed");
        let from_mesh = deviations(&shown, &surface, &part);
        // Nine in ten corners of either within 5 µm of the displacement: the display's
        // chords of the half-round end lie up to tens of µm under the part (the sag of
        // meshoptimizer's bound), and a corner that takes its centroid's distance takes it
        // less the centroid's own distance from the part (see `sag`); the rest are edges.
        for from in [&from_mesh, &from_part] {
            let mut off: Vec<Real> = shown
                .triangles
                .iter()
                .zip(from)
                .flat_map(|(t, d)| {
                    let p = t.map(|i| shown.vertices[i as usize]);
                    let n = (p[1] - p[0]).cross(&(p[2] - p[0])).normalize();
                    (0..3).map(move |k| (d[k] - expected(&p[k], &n)).abs())
                })
                .collect();
            off.sort_by(Real::total_cmp);
            let p90 = off[off.len() * 9 / 10];
            assert!(p90 < 5e-3, "90th percentile {p90}");
        }
        let mut diff: Vec<Real> = from_part
            .iter()
            .zip(&from_mesh)
            .flat_map(|(a, b)| (0..3).map(move |k| (a[k] - b[k]).abs()))
            .collect();
        diff.sort_by(Real::total_cmp);
        // Half the corners within 1 µm; the 1 % worst, at the edges where the two pick
        // different counterparts, within half the displacement.
        assert!(
            diff[diff.len() / 2] < 1e-3,
            "median {}",
            diff[diff.len() / 2]
        );
        let p99 = diff[diff.len() * 99 / 100];
        assert!(p99 < 0.5 * e.norm(), "99th percentile {p99}");
    }

    /// The slot of [`slot`] as a program of one move (NC line 1) on a nominal 3-axis mill.
    fn slot_path() -> NominalPath {
        use crate::cutting::nominal::{NominalMachine, NominalStock};
        use crate::cutting::tool::{Tool, ToolKind};
        use crate::nc::{AxisValues, Move, MoveKind};
        let tool = Tool::try_new(ToolKind::Flat, 6.0, 30.0).expect("valid");
        let mv = Move {
            kind: MoveKind::Linear,
            start: AxisValues::from_array([-15.0, 0.0, 12.0, 0.0, 0.0, 0.0]),
            end: AxisValues::from_array([2.0, 0.0, 12.0, 0.0, 0.0, 0.0]),
            feed_mm_per_min: Some(600.0),
            line: 1,
        };
        let machine = NominalMachine::Chain(crate::machine::chain::xyz_for_tests());
        let block = Aabb {
            min: Point3::new(-10.0, -10.0, 0.0),
            max: Point3::new(10.0, 10.0, 20.0),
        };
        NominalPath::new(&tool, machine, NominalStock::boxed(block), &[mv], 1e-4)
    }

    #[test]
    fn deviations_from_the_nominal_path_are_exact_on_the_slots_plane_faces() {
        // The slot cut on the pose moved by p ↦ R·p + e. Display triangles placed in the
        // moved faces, away from their edges: the floor, both walls and the stock's top
        // (cut by neither). The nominal part's faces there are the planes z = 12, y = ±3 and
        // z = 20, so a pulled corner q of a triangle with normal n meets its face x_a = c
        // along n at (q_a − c)/n_a: exactly, with no first-order approximation.
        use crate::math::Isometry3;
        let e = Vector3::new(0.012, 0.021, -0.017);
        let moved = Isometry3::new(e, Vector3::new(3e-4, -2e-4, 1e-4));
        let part = slot(&moved);
        // (nominal centre, two in-face directions whose cross product is the outward normal,
        // whether the face is cut (moved) or the stock's, axis a and plane c).
        let faces = [
            (
                Point3::new(-5.0, 0.5, 12.0),
                Vector3::x(),
                Vector3::y(),
                true,
                2,
                12.0,
            ),
            (
                Point3::new(-4.0, 3.0, 16.0),
                Vector3::x(),
                Vector3::z(),
                true,
                1,
                3.0,
            ),
            (
                Point3::new(-6.0, -3.0, 15.0),
                Vector3::z(),
                Vector3::x(),
                true,
                1,
                -3.0,
            ),
            (
                Point3::new(-5.0, 7.0, 20.0),
                Vector3::x(),
                Vector3::y(),
                false,
                2,
                20.0,
            ),
        ];
        let mut vertices = Vec::new();
        let mut triangles = Vec::new();
        for (c, u, v, cut, _, _) in &faces {
            let place = |p: Point3| if *cut { moved * p } else { p };
            let k = vertices.len() as u32;
            vertices.extend([
                place(c - u * 0.4 - v * 0.3),
                place(c + u * 0.5 - v * 0.2),
                place(c + v * 0.45),
            ]);
            triangles.push([k, k + 1, k + 2]);
        }
        let shown = DisplayMesh {
            vertices,
            triangles,
            source_triangles: 4,
            error_mm: 0.0,
        };
        let from_path = path_deviations(&shown, &part, &slot_path());
        for ((t, d), (_, _, _, _, a, c)) in shown.triangles.iter().zip(&from_path).zip(&faces) {
            let p = t.map(|i| shown.vertices[i as usize]);
            let n = (p[1] - p[0]).cross(&(p[2] - p[0])).normalize();
            let centre = Point3::from((p[0].coords + p[1].coords + p[2].coords) / 3.0);
            for (q, v) in p.iter().zip(d) {
                let pulled = q + (centre - q) * CORNER_PULL;
                let want = (pulled[*a] - c) / n[*a];
                assert!(
                    (v - want).abs() < 1e-7,
                    "at {q:?} normal {n:?}: {v} mm, want {want}"
                );
            }
        }
        // Not vacuous: the cut faces deviate by micrometres, the floor by e_z and more.
        assert!(from_path[0].iter().all(|d| (d + 0.017).abs() < 3e-3));
        assert!(from_path[3].iter().all(|d| d.abs() < 1e-12));
    }

    /// The distance along `-n` from `q` to the surface of the nominal slot of [`slot`] that
    /// faces like `n` (the block less the slot: the tool's side |y| ≤ 3 up to x = 2 and its
    /// half-round end (x − 2)² + y² ≤ 9, above z = 12), nearest `q` within `reach`: the
    /// crossings found by stepping 1 µm and bisecting to 1e-12 mm, in closed form.
    fn exact_slot_along(q: &Point3, n: &Vector3, reach: Real) -> Option<Real> {
        let inside = |p: Point3| {
            let in_block = p.x.abs() <= 10.0 && p.y.abs() <= 10.0 && (0.0..=20.0).contains(&p.z);
            let in_slot = p.z >= 12.0
                && ((p.x <= 2.0 && p.y.abs() <= 3.0) || (p.x - 2.0).powi(2) + p.y * p.y <= 9.0);
            in_block && !in_slot
        };
        let at = |d: Real| inside(q - n * d);
        let step = 1e-3;
        let steps = (reach / step) as i64;
        let mut best: Option<Real> = None;
        for k in -steps..steps {
            let (a, b) = (k as Real * step, (k + 1) as Real * step);
            // Outside at the smaller d, inside at the larger: a face like n.
            if !at(a) && at(b) {
                let (mut lo, mut hi) = (a, b);
                while hi - lo > 1e-12 {
                    let mid = 0.5 * (lo + hi);
                    if at(mid) { hi = mid } else { lo = mid }
                }
                let d = 0.5 * (lo + hi);
                if best.is_none_or(|x: Real| d.abs() < x.abs()) {
                    best = Some(d);
                }
            }
        }
        best
    }

    #[test]
    fn deviations_from_the_nominal_path_match_the_exact_slot_closer_than_the_swept_part() {
        // The slot cut on the moved pose, every display corner: its deviation along the
        // triangle's normal from the exact nominal slot (closed form), against the
        // deviations measured from the program on the nominal machine (path_deviations)
        // and from the nominal part swept into a tri-dexel (part_deviations).
        use crate::cutting::adaptive::{AdaptiveOptions, mesh_stock_adaptive};
        use crate::math::Isometry3;
        let e = Vector3::new(0.012, 0.021, -0.017);
        let moved = Isometry3::new(e, Vector3::new(3e-4, -2e-4, 1e-4));
        let part = slot(&moved);
        let (mesh, _) = mesh_stock_adaptive(&part, &AdaptiveOptions::default()).expect("meshes");
        let shown = simplify(&mesh, MAX_TRIANGLES);
        let swept = part_deviations(&shown, &slot(&Isometry3::identity()), &part);
        let from_path = path_deviations(&shown, &part, &slot_path());
        let (mut err_path, mut err_swept) = (Vec::new(), Vec::new());
        for (t, (a, b)) in shown.triangles.iter().zip(from_path.iter().zip(&swept)) {
            let p = t.map(|i| shown.vertices[i as usize]);
            let n = (p[1] - p[0]).cross(&(p[2] - p[0])).normalize();
            let centre = Point3::from((p[0].coords + p[1].coords + p[2].coords) / 3.0);
            for k in 0..3 {
                let q = p[k] + (centre - p[k]) * CORNER_PULL;
                if let Some(want) = exact_slot_along(&q, &n, 0.1) {
                    err_path.push((a[k] - want).abs());
                    err_swept.push((b[k] - want).abs());
                }
            }
        }
        let stats = |v: &mut Vec<Real>| {
            v.sort_by(Real::total_cmp);
            let at = |f: Real| v[((v.len() - 1) as Real * f) as usize];
            [at(0.5), at(0.9), at(0.99)]
        };
        let (path, swept) = (stats(&mut err_path), stats(&mut err_swept));
        assert!(err_path.len() > 500, "{} corners", err_path.len());
        // Exact off the edges: half the corners within 1 nm, nine in ten within 0.1 µm (the
        // swept part's interpolation between rays leaves 0.2 µm at the median, 2 µm at the
        // 90th percentile).
        assert!(path[0] < 1e-6, "median {} (swept {})", path[0], swept[0]);
        assert!(
            path[1] < 1e-4,
            "90th percentile {} (swept {})",
            path[1],
            swept[1]
        );
        // At the edges, where the normal line meets the neighbouring face, both take the
        // centroid's closest distance: no farther than the swept part's.
        assert!(
            path[2] <= swept[2],
            "99th percentile {} vs {}",
            path[2],
            swept[2]
        );
    }

    #[test]
    fn the_nominal_paths_distance_is_the_exact_one_on_a_five_axis_cut() {
        // The trunnion with its location errors cutting a 16 mm cube's side while C turns
        // 5° a move through a turn, A swings ±5° and Z descends 2 mm. At display vertices of
        // the cut part, the nominal part's signed distance from the program on the nominal
        // machine (read as a chain, and pose by pose like the hexapod) against brute force
        // (every move's poses at 400 steps, the least refined by ternary search, and the
        // stock box's own distance).
        use crate::cutting::adaptive::{AdaptiveOptions, mesh_stock_adaptive};
        use crate::cutting::nominal::tests::five_axis_cut;
        use crate::cutting::nominal::{NominalMachine, NominalStock};
        use crate::machine::chain::ChainPoses;
        let cut = five_axis_cut();
        let (nominal, part) = (&cut.nominal, &cut.part);
        let (mesh, _) = mesh_stock_adaptive(part, &AdaptiveOptions::default()).expect("meshes");
        let shown = simplify(&mesh, MAX_TRIANGLES);
        let stock = || NominalStock::boxed(cut.stock);
        let as_chain = NominalPath::new(
            &cut.tool,
            NominalMachine::Chain(nominal.clone()),
            stock(),
            &cut.moves,
            1e-4,
        );
        let from_path = path_deviations(&shown, part, &as_chain);
        let pose_by_pose = NominalPath::new(
            &cut.tool,
            NominalMachine::Poses(Box::new(ChainPoses(nominal.clone()))),
            stock(),
            &cut.moves,
            1e-4,
        );
        let by_poses = path_deviations(&shown, part, &pose_by_pose);
        // Read pose by pose (the chain's own poses, not the envelope's folded path): the same
        // distance at every vertex within twice the refinement's tolerance (its bracket
        // lands elsewhere when the poses round differently); the display's corners alike
        // but for a few at edges, whose choice between their own plane and the centroid's
        // that may tip.
        for v in &shown.vertices {
            let a = as_chain.nearest(part, v).map(|f| f.distance);
            let b = pose_by_pose.nearest(part, v).map(|f| f.distance);
            assert!(
                a.zip(b).is_some_and(|(a, b)| (a - b).abs() < 2e-6),
                "{v:?}: {a:?} {b:?}"
            );
        }
        let differ = from_path
            .iter()
            .flatten()
            .zip(by_poses.iter().flatten())
            .filter(|(a, b)| !(a.is_nan() && b.is_nan() || (*a - *b).abs() < 2e-6))
            .count();
        assert!(
            differ * 1000 < 3 * from_path.len(),
            "{differ} corners differ"
        );
        let mut checked = 0;
        let mut deviating = 0;
        for v in shown
            .vertices
            .iter()
            .step_by(shown.vertices.len() / 100 + 1)
        {
            let want = cut.brute(v);
            if want.abs() > 0.5 {
                continue;
            }
            let got = as_chain.nearest(part, v).expect("near the cut").distance;
            assert!(
                (got - want).abs() < 1e-6,
                "at {v:?}: {got} mm, brute force {want}"
            );
            checked += 1;
            deviating += usize::from(want.abs() > 1e-3);
        }
        // Not vacuous: most vertices checked lie micrometres off the nominal part.
        assert!(
            checked > 60 && deviating > checked / 2,
            "{deviating} of {checked}"
        );
    }

    #[test]
    fn a_curved_uncut_face_deviates_zero_whatever_the_display_triangles_sag() {
        // A bar of radius 10 along x (length 40) and a slot along it by a flat Ø6 end mill,
        // on a machine whose Z sits 0.02 mm low: the part is the nominal one but for its
        // floor, 0.02 mm deeper. Its display mesh shows the bar's round face by chords whose
        // middles lie µm under it (meshoptimizer's 0.01 mm bound, and more at the rims).
        // Exact deviations, by construction: −0.02 mm on the floor, 0 on every other face
        // (the walls and the round face and ends, which both parts share).
        use crate::cutting::adaptive::{AdaptiveOptions, mesh_stock_adaptive};
        use crate::cutting::nominal::{NominalMachine, NominalStock};
        use crate::cutting::shape::Cylinder;
        use crate::cutting::sweep::TranslatedTool;
        use crate::cutting::tool::{Tool, ToolKind};
        use crate::nc::{AxisValues, Move, MoveKind};
        let (r, len, floor, dz) = (10.0, 40.0, 7.0, -0.02);
        let bar = Cylinder::try_new(Point3::origin(), Vector3::x(), r, len).expect("valid");
        let bounds = Aabb {
            min: Point3::new(0.0, -r, -r),
            max: Point3::new(len, r, r),
        };
        let mut part = TriDexel::from_solid(bounds, 0.2, 1e9, &bar).expect("fits");
        let tool = Tool::try_new(ToolKind::Flat, 6.0, 20.0).expect("valid");
        let (x0, x1) = (-10.0, 50.0);
        assert!(part.remove(
            &TranslatedTool::new(
                tool.clone(),
                Point3::new(x0, 0.0, floor + dz),
                Vector3::new(x1 - x0, 0.0, 0.0),
                UnitVector3::new_normalize(Vector3::z()),
            ),
            1
        ));
        let mv = Move {
            kind: MoveKind::Linear,
            start: AxisValues::from_array([x0, 0.0, floor, 0.0, 0.0, 0.0]),
            end: AxisValues::from_array([x1, 0.0, floor, 0.0, 0.0, 0.0]),
            feed_mm_per_min: Some(600.0),
            line: 1,
        };
        let path = NominalPath::new(
            &tool,
            NominalMachine::Chain(crate::machine::chain::xyz_for_tests()),
            NominalStock::cylinder(bounds, bar),
            &[mv],
            1e-4,
        );
        let (mesh, _) = mesh_stock_adaptive(&part, &AdaptiveOptions::default()).expect("meshes");
        let shown = simplify(&mesh, MAX_TRIANGLES);
        let dev = path_deviations(&shown, &part, &path);
        // The display's vertices are the source mesh's, which places some (at the rims,
        // and where it interpolates between rays) up to ~2 µm off the bar: a corner shows
        // its vertex's own error and the sag of the point it is measured from (1 % of the
        // way to the centroid: 1 % of the centroid's height under the bar's tangent plane at
        // the corner), both along the triangle's normal, to 0.05 µm, but not the triangle's
        // sag.
        let radius = |q: &Point3| q.y.hypot(q.z);
        let (mut round, mut sagging, mut on_floor) = (0, 0, 0);
        for (t, d) in shown.triangles.iter().zip(&dev) {
            let p = t.map(|i| shown.vertices[i as usize]);
            let n = (p[1] - p[0]).cross(&(p[2] - p[0])).normalize();
            let centre = Point3::from((p[0].coords + p[1].coords + p[2].coords) / 3.0);
            // Every corner within the exact range, to the source mesh's error.
            for v in d {
                assert!(
                    (dz - 2e-3..=2e-3).contains(v),
                    "{v} mm at {p:?} (normal {n:?})"
                );
            }
            // The round face (the ends' rims too): corners within 2 µm of it, the normal
            // within 20° of radial (not a sliver standing across it).
            let radial = |q: &Point3| Vector3::new(0.0, q.y, q.z) / radius(q);
            if p.iter().all(|q| (radius(q) - r).abs() < 2e-3)
                && n.dot(&radial(&centre)) >= SAME_FACE_COS
            {
                round += 1;
                sagging += usize::from(r - radius(&centre) > 2e-3);
                for (q, v) in p.iter().zip(d) {
                    let pull = CORNER_PULL * (centre - q).dot(&radial(q)).abs();
                    assert!(
                        v.abs() <= ((radius(q) - r).abs() + pull) / n.dot(&radial(q)) + 5e-5,
                        "{v} mm at {q:?}, {} mm off the bar; triangle {p:?} (normal {n:?})",
                        radius(q) - r
                    );
                }
            }
            // The floor.
            if n.z > 0.999 && p.iter().all(|q| (q.z - floor - dz).abs() < 1e-6) {
                on_floor += 1;
                assert!(d.iter().all(|v| (v - dz).abs() < 1e-4), "{d:?} at {p:?}");
            }
        }
        // Not vacuous: many chords of the round face sag by more than 2 µm.
        assert!(
            round > 100 && sagging > 20 && on_floor > 0,
            "{round} {sagging} {on_floor}"
        );
    }

    #[test]
    fn the_colour_range_ignores_a_few_outliers() {
        let mut v = vec![0.004; 1000];
        v[3] = 0.9;
        assert!((colour_range_mm(&v) - 0.005).abs() < 1e-15);
        assert_eq!(colour_range_mm(&[0.0; 4]), 1e-3);
        assert_eq!(colour_range_mm(&[]), 1e-3);
    }

    #[test]
    fn decimation_strides_evenly() {
        assert_eq!(decimate(5, 10), vec![0, 1, 2, 3, 4]);
        assert_eq!(decimate(10, 4), vec![0, 3, 6, 9]);
        assert!(decimate(10, 0).is_empty());
    }

    #[test]
    fn the_view_looks_at_the_machined_face() {
        // A face at y = -1 (normal -y) machined into a box [-2, 2]³: seen from -y, above.
        let b = Aabb {
            min: Point3::new(-2.0, -2.0, -2.0),
            max: Point3::new(2.0, 2.0, 2.0),
        };
        let d = DisplayMesh {
            vertices: vec![
                Point3::new(-1.0, -1.0, -1.0),
                Point3::new(1.0, -1.0, -1.0),
                Point3::new(1.0, -1.0, 1.0),
            ],
            triangles: vec![[0, 1, 2]],
            source_triangles: 1,
            error_mm: 0.0,
        };
        let (eye, up) = view_direction(&d, &b);
        assert!(eye.y < -0.7 && eye.z > 0.3, "{eye:?}");
        assert_eq!(up, Vector3::z());
    }
}
