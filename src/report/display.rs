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
//! set the simulate command's peak); every pass reads the one f32 copy of the positions
//! (meshoptimizer's `_decoder` forms would copy them all on each call), and a piece's
//! result is kept at its own size while the others are simplified.
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
//! What is read at the centroid (its closest distance, and for the program on the nominal
//! machine, [`path_deviations`], the value of a corner whose own vertex does not serve) is
//! therefore read at the cut part's crossing nearest the centroid on a face like the
//! triangle's, within two pitches: a point of the cut surface itself. A corner measured
//! from its own vertex shows that vertex's own error (the source mesh places some, at
//! edges, a µm or two off the part).
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
        out = meshopt::simplify(
            &out,
            &vertex_data(&positions),
            max_triangles * 3,
            diagonal,
            abs,
            Some(&mut err2),
        );
        // Measured from the first pass's surface: the two moves add up.
        error_mm += Real::from(err2);
    }
    drop(positions);
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

/// `positions` as meshoptimizer reads them, borrowed: each call of its `_decoder` forms
/// would copy every vertex's position (4 MB for a mesh of 330 k vertices), on every piece.
fn vertex_data(positions: &[[f32; 3]]) -> meshopt::VertexDataAdapter<'_> {
    meshopt::VertexDataAdapter::new(
        meshopt::typed_to_bytes(positions),
        std::mem::size_of::<[f32; 3]>(),
        0,
    )
    .expect("whole [f32; 3] positions, position at offset 0")
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
    let data = vertex_data(positions);
    let whole = |indices: &[u32], opts| {
        let mut err = 0.0f32;
        let mut out = meshopt::simplify(indices, &data, 0, bound, opts, Some(&mut err));
        out.shrink_to_fit();
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
            let mut out = meshopt::simplify_with_locks(
                &indices,
                &data,
                &locked,
                0,
                bound,
                opts,
                Some(&mut err),
            );
            // Kept until every piece is done: not at the input's length, which meshopt
            // allocates and truncates to what is left (a small part of it).
            out.shrink_to_fit();
            (out, err)
        })
        .collect();
    let err_pieces = simplified
        .iter()
        .map(|(_, e)| Real::from(*e))
        .fold(0.0, Real::max);
    let mut joined: Vec<u32> = Vec::with_capacity(simplified.iter().map(|(o, _)| o.len()).sum());
    for (out, _) in simplified {
        joined.extend_from_slice(&out);
    }
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
/// closest distance is read at the cut part's crossing nearest it on a face like the
/// triangle's (within two pitches): on a curved face the centroid of a display triangle
/// lies under the part by the display's sag, which is not the part's deviation.
pub fn deviations(
    mesh: &DisplayMesh,
    reference: &ReferenceSurface,
    cut: &TriDexel,
) -> Vec<[Real; 3]> {
    per_triangle(mesh, |_, p, n, centre| {
        let at = near_crossing(cut, &centre, &n).map_or(centre, |(x, _)| x);
        let n = UnitVector3::new_unchecked(n);
        let nearest = reference.signed_distance(&at);
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

/// The point a display triangle's centroid `centre` (`n` the triangle's unit normal) is read
/// at: the cut part's crossing nearest it on a face like the triangle's (within
/// [`SAME_FACE_COS`]) and within twice the stock's pitch — a point of the cut surface,
/// where the centroid of a chord of a curved face lies under it by the display's sag — with
/// its outward normal; `None` without one.
fn near_crossing(cut: &TriDexel, centre: &Point3, n: &Vector3) -> Option<(Point3, Vector3)> {
    cut.nearest_crossing(centre, 2.0 * cut.pitch(), |m| n.dot(m) >= SAME_FACE_COS)
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
        // an edge): the deviation at the cut part's crossing nearest the centroid on a
        // face like the triangle's (`near_crossing`), a point of the cut surface itself,
        // where the nominal part faces like the triangle too. Not the centroid's: the
        // triangle is a chord of the cut surface, whose inside lies under a curved face,
        // and a tangent plane at its middle under its corners, by the display's sag (up
        // to tens of µm). Where the two parts' planes there are nearly parallel, the gap
        // between them along the normal line from the pulled corner; else the deviation
        // at the crossing. Without such a crossing, the centroid's tangent plane, and its
        // distance for the counterpart test.
        let at_crossing = near_crossing(cut, &centre, &n).and_then(|(x, m)| {
            let f = path.nearest(cut, &x)?;
            let cos = n.dot(&f.normal);
            (within(f.distance) && cos >= SAME_FACE_COS).then_some((x, m, f, cos))
        });
        if let Some((x, m, f, face_cos)) = at_crossing {
            return std::array::from_fn(|k| {
                along[k].unwrap_or_else(|| {
                    if m.dot(&f.normal) < PARALLEL_COS {
                        return f.distance / face_cos;
                    }
                    // The two parts' tangent planes there, nearly parallel: their gap
                    // along the normal line from the pulled corner (the deviation's
                    // slope across the face kept).
                    let q = &pulled[k];
                    let nominal = (q - x).dot(&f.normal) + f.distance;
                    nominal / face_cos - (q - x).dot(&m) / n.dot(&m)
                })
            });
        }
        let central = plane_at(&centre);
        for k in 0..3 {
            if along[k].is_none() {
                along[k] = facing(central, &pulled[k]);
            }
        }
        let nearest = central.map(|(x, big_n)| (centre - x).dot(&big_n));
        along.map(|along| counterpart(along, nearest))
    })
}

/// Least cosine between the cut part's normal at a crossing and the nominal part's at its
/// nearest point for [`path_deviations`] to take the two tangent planes as one face's, its
/// deviation's slope with them (0.5°: a machine's deviations tilt a face by far less; the
/// passes that meet at a crease differ by more).
const PARALLEL_COS: Real = 0.999_96;

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
/// the tangent plane of the nearest crossing ([`TriDexel::nearest_offset`]), read at the cut
/// part `cut`'s crossing nearest the centroid; the same
/// counterpart test. A corner with neither within [`PART_REACH_MM`] is NaN (not coloured).
pub fn part_deviations(mesh: &DisplayMesh, part: &TriDexel, cut: &TriDexel) -> Vec<[Real; 3]> {
    per_triangle(mesh, |_, p, n, centre| {
        let at = near_crossing(cut, &centre, &n).map_or(centre, |(x, _)| x);
        let nearest = part.nearest_offset(&at, PART_REACH_MM);
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
mod tests;
