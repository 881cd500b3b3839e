//! Neighbourhoods, normals and segmentation of scanned point clouds (mm).
//!
//! * **Neighbourhoods.** [`KdIndex`] is a k-d tree over a cloud, built once, answering
//!   k-nearest-neighbour and radius queries. [`estimate_normals`] fits a plane (PCA) to each
//!   point's k nearest neighbours.
//! * **Planar segmentation of a whole cloud** ([`segment_planes`]) needs no per-point
//!   normals: it works on a uniform grid of cubic cells of edge `cell_mm`, centred on the
//!   cloud's first point.
//!   1. *Bin and sum* (one pass over the points). Each fixed chunk of points finds each
//!      point's cell and sums count, first and second moments per cell (about the cell
//!      centre) in a small hash table — consecutive points of a scan mostly share a cell,
//!      so runs are summed in registers. The chunks' sums are then added cell by cell in
//!      chunk order (cells numbered by first appearance), which is what makes every bit
//!      independent of the threads; a dense table over the grid's bounding box maps cells
//!      to their numbers.
//!   2. *Cell planes.* Each occupied cell's centred second moments give its plane: the
//!      eigenvector of the smallest eigenvalue λ₀ is the normal. A cell is *planar* when it
//!      holds at least [`MIN_CELL_POINTS`] points, its flatness λ₀/(λ₀+λ₁+λ₂) is at most
//!      [`MAX_CELL_FLATNESS`], its rms residual √(λ₀/n) is at most [`CELL_RMS_FRACTION`] of
//!      `max_distance_mm`, and its points spread in both in-plane directions (rms at least
//!      [`MIN_CELL_SPREAD_FRACTION`] of the cell edge), so its normal is determined.
//!   3. *Grow.* From the flattest unassigned planar cell, a region grows breadth-first over
//!      the 26 neighbouring cells. A planar neighbour b of region cell a joins when the two
//!      cell normals agree within `max_angle_rad`, the two cell planes are within
//!      `max_distance_mm` of each other at the midpoint of the cell centroids (the shared
//!      boundary), and b agrees with the region's own plane (normal within `max_angle_rad`,
//!      centroid within `max_distance_mm`). The region plane comes from the summed moments
//!      of its cells and is refreshed whenever the region doubles, so growth cannot creep
//!      round a curved surface. Regions whose planar cells hold fewer than `min_points`
//!      points are dissolved.
//!   4. *Assign* (second pass over the points). Every point of every cell — planar or not,
//!      such as cells across an edge or a step — goes to the nearest plane among the
//!      regions of its own and its 26 neighbouring cells, if that plane is within
//!      `max_distance_mm` (ties: the lower region number).
//!   5. *Fit.* Each region's points get the robust orthogonal fit of [`fit_plane_robust`]
//!      with the caller's [`RobustRule`] — its σ-trimming rounds replayed on moments, only
//!      the points near the threshold re-tested, then [`fit_plane`] on the set they settle
//!      on (see [`fit_plane_robust`]'s rule; equal to its result up to rounding). Regions
//!      with fewer than `min_points` points are dropped.
//!
//!   [`select_region_from_seed`] runs the same steps for the one region grown from the cell
//!   of the point nearest a seed.
//! * **RANSAC** ([`ransac_plane`], [`ransac_sphere`], [`ransac_cylinder`]) finds one shape
//!   in a (sub)set of points: minimal samples, scoring by inlier count, then rounds of
//!   least-squares refit and re-selection of the inliers.
//! * **Selection** ([`select_box`]) picks the points in an axis-aligned box.
//!
//! Invariant: every result depends only on the points, the options and the seed — never on
//! the rayon thread count or timing. Parallel work runs over fixed chunks (or per cell,
//! per point, per RANSAC iteration) and is combined in index order; floating-point sums
//! always run in one fixed order; RANSAC samples come from [`CounterRng`] keyed by
//! (seed, iteration). No input makes a function here panic: bad points or options are a
//! [`SegmentError`].

use crate::math::{Aabb, CounterRng, Matrix3, Point3, Real, UnitVector3, Vector3, tol};
use crate::metrology::fit::{CHUNK, Plane, PlaneFit, RobustRule, fit_plane, fit_plane_robust};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rayon::prelude::*;
use std::num::NonZeroUsize;

/// Largest coordinate magnitude accepted (mm): 1,000 km. No scanner measures beyond it;
/// squared distances of larger coordinates lose the µm digits, and the k-d tree reserves
/// the largest finite value as a sentinel.
pub const MAX_COORD_MM: Real = 1e9;

/// Most points a cloud may have: indices are stored as `u32` (4 bytes instead of 8 per
/// index keeps the cell lists of a 1.3 M-point scan in cache).
pub const MAX_POINTS: usize = u32::MAX as usize;

/// Most grid cells [`segment_planes`] lays over a cloud's bounding box: 2²⁶. Its dense
/// per-cell tables take 4 bytes a cell each (256 MiB at this size); a grid this fine means
/// cells far below the point spacing of any scan that fits in memory.
pub const MAX_GRID_CELLS: usize = 1 << 26;

/// Fewest points for a planar cell: twice the three parameters of a plane, so a cell plane
/// is over-determined and its smallest eigenvalue measures noise, not chance. A 1 mm cell
/// on a face scanned at 0.185 mm spacing holds about 29 points.
pub const MIN_CELL_POINTS: usize = 6;

/// Largest flatness λ₀/(λ₀+λ₁+λ₂) of a planar cell. A face cell of edge h with noise σ
/// along its normal scores about 6σ²/h² (0.004 at h = 1 mm, σ = 0.025 mm; 0.015 at
/// h = 0.5 mm); a cell split evenly by a 90° edge between two faces scores 0.077.
pub const MAX_CELL_FLATNESS: Real = 0.05;

/// A planar cell's rms residual is at most this fraction of `max_distance_mm`: with the
/// membership distance set to about 4σ, a face cell's residual is σ, while a cell across
/// a 90° edge or a 1 mm step has 0.1–0.5 mm.
pub const CELL_RMS_FRACTION: Real = 0.5;

/// A planar cell's points spread, in the in-plane direction of least spread, with rms at
/// least this fraction of the cell edge (a strip at least 0.52 mm wide in a 1 mm cell):
/// a narrower sliver of a face clipped by the cell leaves its tilt about the sliver's
/// axis set by noise. Such cells' points are still assigned by distance.
pub const MIN_CELL_SPREAD_FRACTION: Real = 0.15;

/// Below this gap (λ₁ − λ₀)/(λ₂ − λ₀) the closed-form eigenvector (cross products of the
/// rows of A − λ₀I, error ≈ ε/gap) would lose more than half its digits: the iterative
/// solver is used instead.
const EIGEN_GAP_EPS: Real = 1e-6;

/// Most Newton steps for the smallest eigenvalue before the closed form takes over: from
/// λ = 0 the steps reach λ₀ in two or three when λ₀ is well separated (a planar cell), in
/// more only for nearly round point sets, whose cells are not planar anyway.
const NEWTON_STEPS: usize = 8;

/// Largest λ₂²/(λ₀λ₁) for which the Newton value of λ₀ is kept. det(A − λI) near λ₀
/// carries a rounding error of about ε·λ₂³, so λ₀ is good to ε·λ₂²/(λ₀λ₁) relative: at
/// most 1e3·ε (2e-13) here — a noisy 1 mm face cell has about 130 (λ₂/λ₀ at σ = 0.025 mm);
/// flatter or needle-like sets go to the closed form, good to ε·λ₂ absolute.
const NEWTON_MAX_CONDITION: Real = 1e3;

/// Newton has converged when a step is below this fraction of the trace: a few f64 ulps
/// of the largest eigenvalue, the accuracy of the closed form too.
const NEWTON_TOL: Real = 1e-14;

/// A minimal RANSAC sample whose spanning sine is below this is degenerate and skipped: a
/// triangle with an angle under 3° (plane), or two normals within 3° of parallel
/// (cylinder axis n₁ × n₂), fixes its model with noise amplified twentyfold.
pub const MIN_SAMPLE_SIN: Real = 0.05;

/// Four points whose tetrahedron has |det| below this fraction of its Hadamard bound
/// (product of the edge lengths from the first point) are within 0.1 % of coplanar: the
/// sphere through them is fixed by noise more than by shape, and the sample is skipped.
pub const MIN_SAMPLE_DET_RATIO: Real = 1e-3;

/// Random index draws per RANSAC sample before the iteration gives up on finding distinct
/// points (only clouds of a handful of points need more than a few).
const MAX_SAMPLE_DRAWS: u64 = 32;

/// Re-splits of a region's points into core and fringe before [`fit_region`] gives up
/// on its shortcut and runs [`fit_plane_robust`] itself: one is needed when the first
/// fit is pulled off the region plane (by a neighbouring face's edge points), a second
/// only for faces whose form departs from a plane by more than the noise.
const MAX_RESPLITS: usize = 2;

/// Rounds of least-squares refit and re-selection after RANSAC: each round re-selects by
/// distance to the refitted model; it stops earlier when the inliers no longer change
/// (usually after one or two rounds).
const REFINE_ROUNDS: usize = 5;

/// Core distance of a region, as a fraction of `k_sigma` times the pooled rms residual
/// of its cells (≈ 0.93σ with ~22 points a cell): for the default rule (k = 3) points
/// within 2.1σ of the cell-level plane are core — 96 % of them, each safely inside every
/// threshold σ-trimming reaches (≈ 2.9σ), so only 4 % are re-tested per round.
const CORE_FRACTION: Real = 0.75;

/// Second-smallest over largest eigenvalue below which points count as collinear: the
/// bound of [`fit_plane`] (an aspect ratio of 1e-6), so both refuse the same sets.
const DEGENERATE_RATIO: Real = 1e-12;

/// Fewest points an orthogonal plane fit accepts.
const PLANE_FIT_MIN: usize = 3;

/// Cells per parallel work item in per-cell passes: small enough to balance, large enough
/// to amortise the scheduling.
const CELL_BLOCK: usize = 64;

/// "No cell / no region" in the `u32` tables.
const NONE: u32 = u32::MAX;

/// Why a neighbourhood, normal, segmentation or RANSAC query could not be answered.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SegmentError {
    /// The point set is empty.
    #[error("no points")]
    NoPoints,
    /// A point has a NaN or infinite coordinate — or, except for [`segment_planes`] and
    /// [`select_region_from_seed`] (whose grid limit refuses such clouds), one beyond
    /// ±[`MAX_COORD_MM`].
    #[error("point {index} has a non-finite coordinate (or one beyond ±1e9 mm)")]
    NonFinite {
        /// Index of the first offending point.
        index: usize,
    },
    /// The points hold nothing of what was asked: no planar region of `min_points`, fewer
    /// RANSAC inliers than `min_inliers`, or too few points for the model at all.
    #[error("nothing found")]
    NothingFound,
    /// Options (or the input's size) that cannot be used; the message says why and what to
    /// change.
    #[error("bad options: {0}")]
    BadOptions(String),
}

fn is_valid(p: &Point3) -> bool {
    // NaN fails the comparison.
    p.coords.iter().all(|c| c.abs() <= MAX_COORD_MM)
}

/// Checks the points (non-empty, at most [`MAX_POINTS`], all valid) and returns their
/// bounding box, in one parallel pass over fixed chunks.
fn check_and_bound(points: &[Point3]) -> Result<Aabb, SegmentError> {
    if points.is_empty() {
        return Err(SegmentError::NoPoints);
    }
    if points.len() > MAX_POINTS {
        return Err(SegmentError::BadOptions(format!(
            "{} points: at most {MAX_POINTS} are supported",
            points.len()
        )));
    }
    let parts: Vec<(Option<usize>, Aabb)> = points
        .par_chunks(CHUNK)
        .enumerate()
        .map(|(ci, chunk)| {
            let mut b = Aabb::empty();
            for (j, p) in chunk.iter().enumerate() {
                if !is_valid(p) {
                    return (Some(ci * CHUNK + j), b);
                }
                b.grow(p);
            }
            (None, b)
        })
        .collect();
    let mut bbox = Aabb::empty();
    for (bad, b) in parts {
        if let Some(index) = bad {
            return Err(SegmentError::NonFinite { index });
        }
        bbox.grow(&b.min);
        bbox.grow(&b.max);
    }
    Ok(bbox)
}

/// Sum of `f` over fixed chunks of `0..n`, combined in chunk order (thread-count
/// independent).
fn chunked_fold<T, F, G>(n: usize, zero: T, f: F, add: G) -> T
where
    T: Send,
    F: Fn(std::ops::Range<usize>) -> T + Sync + Send,
    G: Fn(T, T) -> T,
{
    let parts: Vec<T> = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| f(c * CHUNK..((c + 1) * CHUNK).min(n)))
        .collect();
    parts.into_iter().fold(zero, add)
}

// ---------------------------------------------------------------------------------------
// Small linear algebra
// ---------------------------------------------------------------------------------------

/// Symmetric 3×3 moments (xx, xy, xz, yy, yz, zz) of `d` added to `m` with weight 1.
fn add_outer(m: &mut [Real; 6], d: &Vector3) {
    m[0] += d.x * d.x;
    m[1] += d.x * d.y;
    m[2] += d.x * d.z;
    m[3] += d.y * d.y;
    m[4] += d.y * d.z;
    m[5] += d.z * d.z;
}

fn sym_matrix(m: &[Real; 6]) -> Matrix3 {
    Matrix3::new(
        m[0], m[1], m[2], //
        m[1], m[3], m[4], //
        m[2], m[4], m[5],
    )
}

/// Eigenvalues (ascending) of the symmetric matrix `m` (xx, xy, xz, yy, yz, zz) and a unit
/// eigenvector of the smallest; `None` when an entry is not finite.
///
/// The smallest eigenvalue λ₀ comes from Newton's method on det(A − λI) from λ = 0 — for
/// a positive semi-definite matrix the determinant is positive, decreasing and convex
/// left of λ₀, so the iterates rise monotonically to it, in two or three steps for a
/// noisy planar cell — and the other two from the remaining quadratic; when that is not
/// accurate ([`NEWTON_MAX_CONDITION`]), all three come from the closed (trigonometric)
/// form, good to a few ε·λ₂ — except for two eigenvalues that nearly coincide against λ₂
/// (a needle, never a plane), which keep about √ε·λ₂. The eigenvector is the largest cross product
/// of two rows of A − λ₀I; when λ₀ is nearly double ([`EIGEN_GAP_EPS`]) the iterative
/// solver of nalgebra decides. A multiple of the identity gets the z axis.
fn eigen_sym3(m: &[Real; 6]) -> Option<([Real; 3], Vector3)> {
    if !m.iter().all(|v| v.is_finite()) {
        return None;
    }
    newton_eigen(m).or_else(|| closed_form_eigen(m))
}

/// The Newton path of [`eigen_sym3`]; `None` when it does not converge, or the
/// eigenvector is ill-determined.
fn newton_eigen(m: &[Real; 6]) -> Option<([Real; 3], Vector3)> {
    let [a00, a01, a02, a11, a12, a22] = *m;
    let tr = a00 + a11 + a22;
    let c1 = a00 * a11 - a01 * a01 + a00 * a22 - a02 * a02 + a11 * a22 - a12 * a12;
    let det = a00 * (a11 * a22 - a12 * a12) - a01 * (a01 * a22 - a12 * a02)
        + a02 * (a01 * a12 - a11 * a02);
    if !(tr > 0.0 && c1 > 0.0) {
        return None;
    }
    let mut l: Real = 0.0;
    let mut converged = false;
    for _ in 0..NEWTON_STEPS {
        let f = ((tr - l) * l - c1) * l + det;
        let fp = (2.0 * tr - 3.0 * l) * l - c1;
        let descending = fp < 0.0;
        if !descending {
            return None;
        }
        let step = f / fp;
        l -= step;
        if step.abs() <= NEWTON_TOL * tr {
            converged = true;
            break;
        }
    }
    if !converged {
        return None;
    }
    let s = tr - l;
    let prod = c1 - l * s;
    let root = (s * s - 4.0 * prod).max(0.0).sqrt();
    let l_max = 0.5 * (s + root);
    let l_mid = if l_max > 0.0 { prod / l_max } else { 0.0 };
    let accurate = l_max * l_max <= NEWTON_MAX_CONDITION * l * l_mid;
    if !accurate {
        return None;
    }
    let v = cross_eigenvector(m, l, l_max)?;
    Some(([l, l_mid, l_max], v))
}

/// Unit eigenvector for the eigenvalue `l` of `m`, from the largest cross product of two
/// rows of A − lI; `None` when that is too small against the spread `l_max − l`.
fn cross_eigenvector(m: &[Real; 6], l: Real, l_max: Real) -> Option<Vector3> {
    let [a00, a01, a02, a11, a12, a22] = *m;
    let r0 = Vector3::new(a00 - l, a01, a02);
    let r1 = Vector3::new(a01, a11 - l, a12);
    let r2 = Vector3::new(a02, a12, a22 - l);
    let mut best = r0.cross(&r1);
    for c in [r0.cross(&r2), r1.cross(&r2)] {
        if c.norm_squared() > best.norm_squared() {
            best = c;
        }
    }
    let spread = (l_max - l) * (l_max - l);
    let nsq = best.norm_squared();
    (nsq.is_finite() && nsq > 0.0 && nsq.sqrt() > EIGEN_GAP_EPS * spread).then(|| best / nsq.sqrt())
}

/// The closed-form path of [`eigen_sym3`] (entries finite).
fn closed_form_eigen(m: &[Real; 6]) -> Option<([Real; 3], Vector3)> {
    let [a00, a01, a02, a11, a12, a22] = *m;
    let q = (a00 + a11 + a22) / 3.0;
    let (b00, b11, b22) = (a00 - q, a11 - q, a22 - q);
    let off = a01 * a01 + a02 * a02 + a12 * a12;
    let p2 = b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * off;
    if !p2.is_finite() {
        return None;
    }
    let p = (p2 / 6.0).sqrt();
    if p <= 0.0 {
        return Some(([q; 3], Vector3::z()));
    }
    let inv = 1.0 / p;
    let (c00, c01, c02, c11, c12, c22) = (
        b00 * inv,
        a01 * inv,
        a02 * inv,
        b11 * inv,
        a12 * inv,
        b22 * inv,
    );
    let det = c00 * (c11 * c22 - c12 * c12) - c01 * (c01 * c22 - c12 * c02)
        + c02 * (c01 * c12 - c11 * c02);
    let phi = (det / 2.0).clamp(-1.0, 1.0).acos() / 3.0;
    let third = std::f64::consts::TAU / 3.0;
    let l_max = q + 2.0 * p * phi.cos();
    let l_min = q + 2.0 * p * (phi + third).cos();
    let l_mid = 3.0 * q - l_max - l_min;
    if let Some(v) = cross_eigenvector(m, l_min, l_max) {
        return Some(([l_min, l_mid, l_max], v));
    }
    let eig = nalgebra::SymmetricEigen::try_new(sym_matrix(m), Real::EPSILON, 10_000)?;
    let mut order = [0usize, 1, 2];
    order.sort_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]));
    let v: Vector3 = eig.eigenvectors.column(order[0]).into_owned();
    let norm = v.norm();
    if !(norm > 0.0 && norm.is_finite()) {
        return None;
    }
    Some((order.map(|i| eig.eigenvalues[i]), v / norm))
}

/// `n` flipped if needed so that its largest-magnitude component (the first on a tie) is
/// positive: the orientation rule of [`crate::metrology::fit::PlaneFit`].
fn canonical(n: Vector3) -> Vector3 {
    let mut k_big = 0;
    for k in 1..3 {
        if n[k].abs() > n[k_big].abs() {
            k_big = k;
        }
    }
    if n[k_big] < 0.0 { -n } else { n }
}

/// Two unit vectors completing the unit vector `a` to a right-handed orthonormal basis.
fn basis_perpendicular(a: &Vector3) -> (Vector3, Vector3) {
    let e = if a.x.abs() < 0.6 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let u = a.cross(&e).normalize();
    (u, a.cross(&u))
}

// ---------------------------------------------------------------------------------------
// k-d tree and normals
// ---------------------------------------------------------------------------------------

/// One neighbour found by a [`KdIndex`] query.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Neighbour {
    /// Index of the point in the indexed slice.
    pub index: u32,
    /// Euclidean distance from the query point (mm).
    pub distance_mm: Real,
}

/// A k-d tree over a cloud's points (kiddo's immutable tree), built once, queried many
/// times, from any number of threads.
///
/// The tree is always built serially, so its layout — and the choice among neighbours at
/// equal distance — is the same for any thread count. Results come sorted by distance,
/// then index.
pub struct KdIndex {
    tree: ImmutableKdTree<Real, 3>,
    len: usize,
}

impl KdIndex {
    /// Builds the index. Errors: [`SegmentError::NoPoints`], [`SegmentError::NonFinite`],
    /// more than [`MAX_POINTS`] points ([`SegmentError::BadOptions`]).
    pub fn new(points: &[Point3]) -> Result<Self, SegmentError> {
        check_and_bound(points)?;
        let coords: Vec<[Real; 3]> = points.par_iter().map(|p| [p.x, p.y, p.z]).collect();
        let tree = ImmutableKdTree::<Real, 3>::builder()
            .with_serial_construction()
            .build_from_slice(&coords)
            .map_err(|e| SegmentError::BadOptions(format!("k-d tree: {e}")))?;
        Ok(Self {
            tree,
            len: points.len(),
        })
    }

    /// Number of indexed points.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the index is empty (never, as built by [`KdIndex::new`]).
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The `k` nearest indexed points to `query` (all of them if fewer), nearest first,
    /// the query point itself included when it is indexed. Empty for `k = 0` or a
    /// non-finite query.
    pub fn nearest(&self, query: &Point3, k: usize) -> Vec<Neighbour> {
        let Some(k) = NonZeroUsize::new(k.min(self.len)) else {
            return Vec::new();
        };
        if !is_valid(query) {
            return Vec::new();
        }
        let q = [query.x, query.y, query.z];
        let found = self
            .tree
            .query(&q)
            .nearest_n::<SquaredEuclidean<Real>>(k)
            .execute();
        Self::sorted(found.iter().map(|r| (r.item, r.distance)))
    }

    /// All indexed points within `radius_mm` of `query` (inclusive), nearest first. Empty
    /// for a negative or non-finite radius or query.
    pub fn within(&self, query: &Point3, radius_mm: Real) -> Vec<Neighbour> {
        if !(is_valid(query) && (0.0..=MAX_COORD_MM).contains(&radius_mm)) {
            return Vec::new();
        }
        let q = [query.x, query.y, query.z];
        let found = self
            .tree
            .query(&q)
            .within::<SquaredEuclidean<Real>>(radius_mm * radius_mm)
            .execute();
        Self::sorted(found.iter().map(|r| (r.item, r.distance)))
    }

    fn sorted(items: impl Iterator<Item = (u32, Real)>) -> Vec<Neighbour> {
        let mut v: Vec<Neighbour> = items
            .map(|(index, d2)| Neighbour {
                index,
                distance_mm: d2.sqrt(),
            })
            .collect();
        v.sort_unstable_by(|a, b| {
            a.distance_mm
                .total_cmp(&b.distance_mm)
                .then(a.index.cmp(&b.index))
        });
        v
    }
}

/// Unit normal of each point: the smallest-eigenvalue direction (PCA) of its `k` nearest
/// neighbours (itself included), from the centred second moments.
///
/// With a `viewpoint` each normal points towards it (n · (viewpoint − p) ≥ 0); without,
/// its largest-magnitude component is positive (the rule of [`PlaneFit`]). `k` above the
/// number of points uses all points. A neighbourhood that is collinear or coincident gets
/// an arbitrary but deterministic normal.
///
/// Errors: [`SegmentError::NoPoints`], [`SegmentError::NonFinite`], `k < 3` or a
/// non-finite viewpoint ([`SegmentError::BadOptions`]), fewer than 3 points
/// ([`SegmentError::NothingFound`]).
pub fn estimate_normals(
    points: &[Point3],
    k: usize,
    viewpoint: Option<Point3>,
) -> Result<Vec<UnitVector3>, SegmentError> {
    check_and_bound(points)?;
    if k < PLANE_FIT_MIN {
        return Err(SegmentError::BadOptions(format!(
            "k = {k}: a normal needs at least {PLANE_FIT_MIN} neighbours"
        )));
    }
    if viewpoint.is_some_and(|v| !is_valid(&v)) {
        return Err(SegmentError::BadOptions(
            "the viewpoint is not finite".to_string(),
        ));
    }
    if points.len() < PLANE_FIT_MIN {
        return Err(SegmentError::NothingFound);
    }
    let index = KdIndex::new(points)?;
    Ok(points
        .par_iter()
        .map(|p| {
            let nb = index.nearest(p, k);
            let n = neighbourhood_normal(points, p, &nb);
            let flip = match viewpoint {
                Some(v) => n.dot(&(v - p)) < 0.0,
                None => canonical(n) != n,
            };
            UnitVector3::new_unchecked(if flip { -n } else { n })
        })
        .collect())
}

/// PCA normal of the neighbours `nb` of `p` (unit; z for an empty or non-finite set).
fn neighbourhood_normal(points: &[Point3], p: &Point3, nb: &[Neighbour]) -> Vector3 {
    let pts = nb.iter().filter_map(|q| points.get(q.index as usize));
    let (count, sum) = pts
        .clone()
        .fold((0usize, Vector3::zeros()), |(c, s), q| (c + 1, s + (q - p)));
    if count == 0 {
        return Vector3::z();
    }
    let c = p.coords + sum / count as Real;
    let mut m = [0.0; 6];
    for q in pts {
        add_outer(&mut m, &(q.coords - c));
    }
    eigen_sym3(&m).map_or(Vector3::z(), |(_, v)| v)
}

// ---------------------------------------------------------------------------------------
// Planar segmentation
// ---------------------------------------------------------------------------------------

/// Options of [`segment_planes`] and [`select_region_from_seed`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlaneSegmentOptions {
    /// Grid cell edge (mm). A few point spacings: 1.0 mm holds ~29 points of a face
    /// scanned at 0.185 mm. Faces narrower than about two cells are found only as parts
    /// of edge cells.
    pub cell_mm: Real,
    /// Largest angle (rad) between the normals of neighbouring cells, and between a cell's
    /// normal and its region's, when growing; in (0, π/2].
    pub max_angle_rad: Real,
    /// Largest point-to-plane distance (mm) for membership, and largest gap between
    /// neighbouring cell planes when growing; about 4σ of the scanner noise.
    pub max_distance_mm: Real,
    /// Fewest points of a returned segment (a plane fit needs 3, so fewer acts as 3).
    pub min_points: usize,
    /// Outlier rejection of each segment's final fit.
    pub robust: RobustRule,
}

impl Default for PlaneSegmentOptions {
    /// For the structured-light scanner (0.185 mm spacing, σ = 0.025 mm): 1 mm cells,
    /// 0.15 rad (8.6°: ten times the rms angle between noisy 1 mm cell normals), 0.1 mm
    /// (4σ), 500 points (a 4 × 4 mm patch), default [`RobustRule`].
    fn default() -> Self {
        Self {
            cell_mm: 1.0,
            max_angle_rad: 0.15,
            max_distance_mm: 0.1,
            min_points: 500,
            robust: RobustRule::default(),
        }
    }
}

/// One planar face found by [`segment_planes`] or [`select_region_from_seed`].
#[derive(Clone, Debug, PartialEq)]
pub struct PlaneSegment {
    /// The robust fit of the segment's points by the caller's [`RobustRule`]: what
    /// [`fit_plane_robust`] returns for them, up to rounding (see the module
    /// documentation, step 5); `fit.n_used + fit.n_rejected == indices.len()`.
    pub fit: PlaneFit,
    /// Indices of the segment's points, sorted ascending.
    pub indices: Vec<u32>,
}

fn check_plane_options(opts: &PlaneSegmentOptions) -> Result<(), SegmentError> {
    let bad = |s: String| Err(SegmentError::BadOptions(s));
    if !(opts.cell_mm.is_finite() && opts.cell_mm > 0.0) {
        return bad(format!(
            "cell_mm = {}: must be a positive length",
            opts.cell_mm
        ));
    }
    if !(opts.max_angle_rad > 0.0 && opts.max_angle_rad <= std::f64::consts::FRAC_PI_2) {
        return bad(format!(
            "max_angle_rad = {}: must be in (0, π/2]",
            opts.max_angle_rad
        ));
    }
    if !(opts.max_distance_mm.is_finite() && opts.max_distance_mm > 0.0) {
        return bad(format!(
            "max_distance_mm = {}: must be a positive length",
            opts.max_distance_mm
        ));
    }
    if !(opts.robust.k_sigma.is_finite() && opts.robust.k_sigma > 0.0) {
        return bad(format!(
            "robust.k_sigma = {}: must be positive",
            opts.robust.k_sigma
        ));
    }
    Ok(())
}

/// The cell suggested when a grid is too fine is enlarged by this factor (1 %), so that it
/// still fits after the message rounds it.
const SUGGEST_MARGIN: Real = 1.01;

/// Adding this to a double below 2⁵¹ in magnitude leaves its nearest integer in the low
/// mantissa bits (1.5·2⁵²: the exponent stays fixed for the whole range), a floor for
/// x − ½ with no float-to-integer conversion.
const ROUND_MAGIC: Real = 6_755_399_441_055_744.0;

/// Largest distance from the anchor, in cells, binned exactly: 2⁵⁰, far inside the range
/// of [`ROUND_MAGIC`]. A point further out means a grid beyond [`MAX_GRID_CELLS`].
const MAX_CELL_SPAN: Real = 1_125_899_906_842_624.0;

/// Integer cell coordinates of `p` on the grid of edge `1 / inv_cell` through `anchor`
/// (each ⌊(p − anchor)·inv_cell⌋, except that a point exactly on a cell face may go to
/// either side); `None` beyond [`MAX_CELL_SPAN`] cells.
fn cell_triple(p: &Point3, anchor: &Point3, inv_cell: Real) -> Option<[i64; 3]> {
    let magic = ROUND_MAGIC.to_bits() as i64;
    let mut t = [0i64; 3];
    for (k, tk) in t.iter_mut().enumerate() {
        let x = (p[k] - anchor[k]) * inv_cell;
        let near = x.abs() < MAX_CELL_SPAN;
        if !near {
            return None;
        }
        *tk = (x - 0.5 + ROUND_MAGIC).to_bits() as i64 - magic;
    }
    Some(t)
}

/// The uniform grid: cells of edge `cell` aligned on `anchor` (half a cell below the
/// cloud's first point on each axis),
/// spanning the occupied cells `lo..lo + dims`; x-major keys `(ix·ny + iy)·nz + iz` of
/// coordinates relative to `lo`.
struct Grid {
    anchor: Point3,
    cell: Real,
    inv_cell: Real,
    lo: [i64; 3],
    dims: [usize; 3],
}

impl Grid {
    /// The grid spanning the cells `lo..=hi`, refused beyond [`MAX_GRID_CELLS`].
    fn new(anchor: Point3, cell: Real, lo: [i64; 3], hi: [i64; 3]) -> Result<Self, SegmentError> {
        let span = [0, 1, 2].map(|k| (hi[k] as Real - lo[k] as Real) + 1.0);
        let total: Real = span.iter().product();
        let fits = total <= MAX_GRID_CELLS as Real;
        if !fits {
            let ext = span.map(|s| s * cell);
            let suggest = cell * (total / MAX_GRID_CELLS as Real).cbrt() * SUGGEST_MARGIN;
            return Err(SegmentError::BadOptions(format!(
                "cell_mm = {cell} lays {total:.3e} cells over the cloud's {:.1} × {:.1} × \
                 {:.1} mm bounding box (limit 2^26 = {MAX_GRID_CELLS}): use a cell of at \
                 least {suggest:.3} mm",
                ext[0], ext[1], ext[2]
            )));
        }
        Ok(Self {
            anchor,
            cell,
            inv_cell: 1.0 / cell,
            lo,
            dims: span.map(|s| s as usize),
        })
    }

    fn len(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }

    /// Grid coordinates of `p` (clamped into the grid).
    fn coords(&self, p: &Point3) -> [usize; 3] {
        let t = cell_triple(p, &self.anchor, self.inv_cell).unwrap_or(self.lo);
        let mut c = [0usize; 3];
        for (k, ck) in c.iter_mut().enumerate() {
            *ck = (t[k].saturating_sub(self.lo[k]).max(0) as usize).min(self.dims[k] - 1);
        }
        c
    }

    fn key(&self, c: [usize; 3]) -> usize {
        (c[0] * self.dims[1] + c[1]) * self.dims[2] + c[2]
    }

    /// Centre of the cell with integer coordinates `t` (relative to the anchor).
    fn centre_of_triple(anchor: &Point3, cell: Real, t: [i64; 3]) -> Point3 {
        anchor + Vector3::new(t[0] as Real + 0.5, t[1] as Real + 0.5, t[2] as Real + 0.5) * cell
    }

    /// Centre of the cell with grid coordinates `c`.
    fn centre(&self, c: [usize; 3]) -> Point3 {
        let t = [0, 1, 2].map(|k| c[k] as i64 + self.lo[k]);
        Self::centre_of_triple(&self.anchor, self.cell, t)
    }
}

/// Count, sum and second moments of displacements from some reference point.
#[derive(Clone, Copy, Debug)]
struct Moments {
    n: usize,
    s: Vector3,
    /// xx, xy, xz, yy, yz, zz.
    m: [Real; 6],
}

impl Moments {
    const ZERO: Moments = Moments {
        n: 0,
        s: Vector3::new(0.0, 0.0, 0.0),
        m: [0.0; 6],
    };

    fn push(&mut self, d: &Vector3) {
        self.n += 1;
        self.s += d;
        add_outer(&mut self.m, d);
    }

    fn merge(&mut self, o: &Moments) {
        self.n += o.n;
        self.s += o.s;
        for (a, b) in self.m.iter_mut().zip(&o.m) {
            *a += b;
        }
    }

    /// Mean displacement and the scatter Σ (d − mean)(d − mean)ᵀ (`None` when empty).
    fn centred(&self) -> Option<(Vector3, [Real; 6])> {
        if self.n == 0 {
            return None;
        }
        let n = self.n as Real;
        let mean = self.s / n;
        let mut mm = [0.0; 6];
        add_outer(&mut mm, &mean);
        let mut c = self.m;
        for (a, b) in c.iter_mut().zip(mm) {
            *a -= n * b;
        }
        Some((mean, c))
    }
}

/// Moments and plane of one occupied cell.
#[derive(Clone, Copy, Debug)]
struct CellStat {
    n: u32,
    centroid: Point3,
    /// Σ (p − c)(p − c)ᵀ about the centroid: xx, xy, xz, yy, yz, zz.
    scatter: [Real; 6],
    /// Unit normal of the cell plane (either sign).
    normal: Vector3,
    /// Residual sum of squares about the cell plane (λ₀ ≥ 0).
    rss: Real,
    /// λ₀ / (λ₀ + λ₁ + λ₂).
    flatness: Real,
    planar: bool,
}

impl CellStat {
    /// From the moments `mo` of the cell's points about the cell centre `centre`.
    fn of(mo: &Moments, centre: &Point3, cell_mm: Real, max_distance: Real) -> Self {
        let mut stat = CellStat {
            n: mo.n as u32,
            centroid: *centre,
            scatter: [0.0; 6],
            normal: Vector3::z(),
            rss: 0.0,
            flatness: 1.0,
            planar: false,
        };
        let Some((mean, scatter)) = mo.centred() else {
            return stat;
        };
        stat.centroid = centre + mean;
        stat.scatter = scatter;
        if mo.n < MIN_CELL_POINTS {
            // Never planar; its plane is never used.
            return stat;
        }
        if let Some((l, v)) = eigen_sym3(&scatter) {
            let n = mo.n as Real;
            let l0 = l[0].max(0.0);
            let sum = l0 + l[1] + l[2];
            stat.normal = v;
            stat.rss = l0;
            if sum > 0.0 {
                stat.flatness = l0 / sum;
            }
            let rms_max = CELL_RMS_FRACTION * max_distance;
            let spread_min = MIN_CELL_SPREAD_FRACTION * cell_mm;
            stat.planar = sum > 0.0
                && stat.flatness <= MAX_CELL_FLATNESS
                && l0 / n <= rms_max * rms_max
                && l[1] / n >= spread_min * spread_min;
        }
        stat
    }
}

/// Margin (in cells) of a region's bounding box beyond its cells and their neighbours: a
/// point exactly on a cell face may be binned on either side ([`cell_triple`]), and the
/// box corners are rounded; a thousandth of a cell covers both by far.
const CELL_BOX_SLACK: Real = 1e-3;

/// Slots of the per-chunk hash table of cells: a power of two at least twice [`CHUNK`],
/// so the table is at most half full.
const CHUNK_TABLE: usize = 2 * CHUNK;

/// log₂ of [`CHUNK_TABLE`].
const TABLE_BITS: u32 = CHUNK_TABLE.trailing_zeros();

/// The spatial-hash primes of Teschner et al. (2003), one per axis.
const HASH_PRIMES: [i64; 3] = [73_856_093, 19_349_663, 83_492_791];

/// 2⁶⁴/φ: Fibonacci hashing spreads the hash's high bits over the table.
const FIBONACCI: u64 = 0x9e37_79b9_7f4a_7c15;

/// One chunk's cells: integer coordinates and moments of its points about each cell's
/// centre, in order of first appearance in the chunk; and the first non-finite point.
struct ChunkCells {
    cells: Vec<([i64; 3], Moments)>,
    invalid: Option<usize>,
    /// A point lies beyond [`MAX_CELL_SPAN`] cells from the anchor.
    too_far: bool,
}

/// Bins one chunk: writes each point's record number (its cell among the chunk's) to
/// `rec` and sums the moments. Consecutive points of a scan mostly share a cell, so a run
/// of them is summed in registers and added to its cell's record when the cell changes.
/// `table` is a hash table of [`CHUNK_TABLE`] slots, all [`NONE`], left so.
fn chunk_cells(
    chunk: &[Point3],
    anchor: &Point3,
    cell: Real,
    rec: &mut [u16],
    table: &mut [u32],
) -> ChunkCells {
    let inv = 1.0 / cell;
    let mut out = ChunkCells {
        cells: Vec::with_capacity(CHUNK / MIN_CELL_POINTS),
        invalid: None,
        too_far: false,
    };
    let mut cur = ([i64::MIN; 3], usize::MAX, Point3::origin());
    let mut run = Moments::ZERO;
    let mut used: Vec<usize> = Vec::with_capacity(CHUNK / MIN_CELL_POINTS);
    let mut unbinnable = false;
    for (p, r) in chunk.iter().zip(rec.iter_mut()) {
        let Some(t) = cell_triple(p, anchor, inv) else {
            unbinnable = true;
            break;
        };
        if t != cur.0 {
            if let Some(c) = out.cells.get_mut(cur.1) {
                c.1.merge(&run);
            }
            run = Moments::ZERO;
            // Spatial hash of the coordinates, Fibonacci-mixed; linear probing.
            let h = (t[0].wrapping_mul(HASH_PRIMES[0]) ^ t[1].wrapping_mul(HASH_PRIMES[1]))
                ^ t[2].wrapping_mul(HASH_PRIMES[2]);
            let mut slot = ((h as u64).wrapping_mul(FIBONACCI) >> (u64::BITS - TABLE_BITS))
                as usize
                % CHUNK_TABLE;
            let r = loop {
                let r = table[slot];
                if r == NONE {
                    table[slot] = out.cells.len() as u32;
                    used.push(slot);
                    out.cells.push((t, Moments::ZERO));
                    break out.cells.len() - 1;
                }
                if out.cells[r as usize].0 == t {
                    break r as usize;
                }
                slot = (slot + 1) % CHUNK_TABLE;
            };
            cur = (t, r, Grid::centre_of_triple(anchor, cell, t));
        }
        *r = cur.1 as u16;
        run.push(&(p - cur.2));
    }
    if unbinnable {
        // A non-finite point, or one too far to bin (the grid would be refused).
        out.invalid = chunk
            .iter()
            .position(|p| !p.coords.iter().all(|c| c.is_finite()));
        out.too_far = out.invalid.is_none();
    }
    if let Some(c) = out.cells.get_mut(cur.1) {
        c.1.merge(&run);
    }
    for s in used {
        table[s] = NONE;
    }
    out
}

/// The cloud binned into grid cells, with each cell's plane and neighbours.
struct Cells {
    grid: Grid,
    /// Dense over the grid: key → occupied cell, or [`NONE`].
    lookup: Vec<u32>,
    /// Per occupied cell (numbered in order of first appearance in the cloud): grid
    /// coordinates.
    coords: Vec<[u32; 3]>,
    /// Per occupied cell: moments and plane.
    stats: Vec<CellStat>,
    /// Occupied 26-neighbours of each cell (in key order): `nbrs[nbr_start[c]..nbr_start[c + 1]]`.
    nbr_start: Vec<u32>,
    nbrs: Vec<u32>,
    /// Per point: its cell's record number in its chunk.
    rec: Vec<u16>,
    /// Per chunk: record number → cell.
    rec_cell: Vec<Vec<u32>>,
}

/// A flat list of per-item lists built over fixed blocks of items in parallel:
/// `(start, items)` with `items[start[i]..start[i + 1]]` for item i.
fn flat_lists(n: usize, f: impl Fn(usize, &mut Vec<u32>) + Sync) -> (Vec<u32>, Vec<u32>) {
    let blocks: Vec<(Vec<u32>, Vec<u32>)> = (0..n.div_ceil(CELL_BLOCK))
        .into_par_iter()
        .map(|b| {
            let mut ends = Vec::with_capacity(CELL_BLOCK);
            let mut list = Vec::new();
            for i in b * CELL_BLOCK..((b + 1) * CELL_BLOCK).min(n) {
                f(i, &mut list);
                ends.push(list.len() as u32);
            }
            (ends, list)
        })
        .collect();
    let mut start = Vec::with_capacity(n + 1);
    let mut flat = Vec::with_capacity(blocks.iter().map(|b| b.1.len()).sum());
    start.push(0u32);
    for (ends, list) in blocks {
        let base = flat.len() as u32;
        start.extend(ends.iter().map(|e| base + e));
        flat.extend(list);
    }
    (start, flat)
}

impl Cells {
    /// Steps 1 and 2: bin and cell planes. Each fixed chunk of points checks its points
    /// and sums their moments per cell (about the cell centre); the partial sums are
    /// added cell by cell in chunk order, so every bit is independent of the threads.
    fn build(points: &[Point3], opts: &PlaneSegmentOptions) -> Result<Self, SegmentError> {
        check_plane_options(opts)?;
        if points.len() > MAX_POINTS {
            return Err(SegmentError::BadOptions(format!(
                "{} points: at most {MAX_POINTS} are supported",
                points.len()
            )));
        }
        let first = points.first().ok_or(SegmentError::NoPoints)?;
        let cell = opts.cell_mm;
        // Cells centred on the first point, whose surface then lies mid-cell rather than
        // on a cell face (where its points would split between two layers of cells).
        let anchor = first - Vector3::repeat(0.5 * cell);
        let mut rec = vec![0u16; points.len()];
        let parts: Vec<ChunkCells> = points
            .par_chunks(CHUNK)
            .zip(rec.par_chunks_mut(CHUNK))
            .map_init(
                || vec![NONE; CHUNK_TABLE],
                |table, (chunk, rec)| chunk_cells(chunk, &anchor, cell, rec, table),
            )
            .collect();
        let mut lo = [i64::MAX; 3];
        let mut hi = [i64::MIN; 3];
        if let Some((ci, j)) = parts
            .iter()
            .enumerate()
            .find_map(|(ci, part)| part.invalid.map(|j| (ci, j)))
        {
            return Err(SegmentError::NonFinite {
                index: ci * CHUNK + j,
            });
        }
        if parts.iter().any(|part| part.too_far) {
            lo = [0; 3];
            hi = [MAX_CELL_SPAN as i64; 3];
        }
        for part in &parts {
            for (t, _) in &part.cells {
                for k in 0..3 {
                    lo[k] = lo[k].min(t[k]);
                    hi[k] = hi[k].max(t[k]);
                }
            }
        }
        let grid = Grid::new(anchor, cell, lo, hi)?;
        let mut lookup = vec![NONE; grid.len()];
        let mut moments: Vec<Moments> = Vec::new();
        let mut coords: Vec<[u32; 3]> = Vec::new();
        let mut rec_cell: Vec<Vec<u32>> = Vec::with_capacity(parts.len());
        for part in &parts {
            let mut map = Vec::with_capacity(part.cells.len());
            for (t, mo) in &part.cells {
                let c = [0, 1, 2].map(|k| (t[k] - lo[k]) as usize);
                let id = &mut lookup[grid.key(c)];
                if *id == NONE {
                    *id = moments.len() as u32;
                    moments.push(*mo);
                    coords.push(c.map(|v| v as u32));
                } else {
                    moments[*id as usize].merge(mo);
                }
                map.push(*id);
            }
            rec_cell.push(map);
        }
        drop(parts);
        let stats: Vec<CellStat> = moments
            .par_iter()
            .zip(coords.par_iter())
            .with_min_len(CELL_BLOCK)
            .map(|(mo, c)| {
                let centre = grid.centre(c.map(|v| v as usize));
                CellStat::of(mo, &centre, opts.cell_mm, opts.max_distance_mm)
            })
            .collect();
        let mut cells = Self {
            grid,
            lookup,
            coords,
            stats,
            nbr_start: Vec::new(),
            nbrs: Vec::new(),
            rec,
            rec_cell,
        };
        let (nbr_start, nbrs) = flat_lists(cells.len(), |c, out| {
            cells.scan_neighbours(c, |b| out.push(b as u32));
        });
        cells.nbr_start = nbr_start;
        cells.nbrs = nbrs;
        Ok(cells)
    }

    fn len(&self) -> usize {
        self.coords.len()
    }

    /// The occupied cell holding `p` (`None` for a point that was not binned).
    fn cell_of(&self, p: &Point3) -> Option<usize> {
        let id = *self.lookup.get(self.grid.key(self.grid.coords(p)))?;
        (id != NONE).then_some(id as usize)
    }

    /// Calls `f` for each occupied cell among the 26 neighbours of cell `c`, in key order,
    /// from the grid.
    fn scan_neighbours(&self, c: usize, mut f: impl FnMut(usize)) {
        let [x, y, z] = self.coords[c].map(|v| v as usize);
        let [dx, dy, dz] = self.grid.dims;
        let (z0, z1) = (z.saturating_sub(1), (z + 1).min(dz - 1));
        for ix in x.saturating_sub(1)..=(x + 1).min(dx - 1) {
            for iy in y.saturating_sub(1)..=(y + 1).min(dy - 1) {
                let row = (ix * dy + iy) * dz;
                let Some(column) = self.lookup.get(row + z0..=row + z1) else {
                    continue;
                };
                let centre = (ix, iy) == (x, y);
                for (iz, &id) in (z0..).zip(column) {
                    if id != NONE && !(centre && iz == z) {
                        f(id as usize);
                    }
                }
            }
        }
    }

    /// The occupied 26-neighbours of cell `c`, in key order.
    fn neighbours(&self, c: usize) -> &[u32] {
        let (a, b) = (self.nbr_start[c] as usize, self.nbr_start[c + 1] as usize);
        self.nbrs.get(a..b).unwrap_or_default()
    }

    /// Planar cells, flattest first (ties: lower cell).
    fn seeds(&self) -> Vec<u32> {
        let mut s: Vec<(u64, u32)> = self
            .stats
            .par_iter()
            .enumerate()
            .filter(|(_, s)| s.planar)
            // Flatness is finite and ≥ 0, so its bits order as the values do.
            .map(|(i, s)| (s.flatness.to_bits(), i as u32))
            .collect();
        s.sort_unstable();
        s.into_iter().map(|(_, i)| i).collect()
    }

    /// Step 3: regions grown from `seeds` in order; returns each cell's region (or
    /// [`NONE`]) and each region's accumulated moments.
    fn grow(&self, seeds: &[u32], opts: &PlaneSegmentOptions) -> (Vec<u32>, Vec<RegionAcc>) {
        let cos_max = opts.max_angle_rad.cos();
        let max_d = opts.max_distance_mm;
        let mut region = vec![NONE; self.len()];
        let mut accs: Vec<RegionAcc> = Vec::new();
        let mut queue: Vec<u32> = Vec::new();
        for &s in seeds {
            let s = s as usize;
            if region[s] != NONE || !self.stats[s].planar {
                continue;
            }
            let rid = accs.len() as u32;
            let mut acc = RegionAcc::new(&self.stats[s], self.coords[s]);
            let mut plane = RegionPlane {
                centroid: self.stats[s].centroid,
                normal: self.stats[s].normal,
            };
            let mut refresh_at = 2;
            region[s] = rid;
            queue.clear();
            queue.push(s as u32);
            let mut head = 0;
            while let Some(&a) = queue.get(head) {
                head += 1;
                let sa = &self.stats[a as usize];
                for &b in self.neighbours(a as usize) {
                    let b = b as usize;
                    if region[b] != NONE {
                        continue;
                    }
                    let sb = &self.stats[b];
                    if !sb.planar || !joins(sa, sb, &plane, cos_max, max_d) {
                        continue;
                    }
                    region[b] = rid;
                    queue.push(b as u32);
                    acc.add(sb, self.coords[b]);
                    if acc.cells >= refresh_at {
                        if let Some(p) = acc.plane() {
                            plane = p;
                        }
                        refresh_at *= 2;
                    }
                }
            }
            accs.push(acc);
        }
        (region, accs)
    }

    /// Bounding box of the cells from `lo` to `hi` (grid coordinates) grown by one cell
    /// and [`CELL_BOX_SLACK`]: it holds every point of those cells and of their neighbours.
    fn cell_box(&self, lo: [u32; 3], hi: [u32; 3]) -> Aabb {
        let g = &self.grid;
        let corner = |c: [u32; 3], shift: Real| {
            let t = [0, 1, 2].map(|k| (c[k] as i64 + g.lo[k]) as Real + shift);
            g.anchor + Vector3::new(t[0], t[1], t[2]) * g.cell
        };
        Aabb {
            min: corner(lo, -1.0 - CELL_BOX_SLACK),
            max: corner(hi, 2.0 + CELL_BOX_SLACK),
        }
    }

    /// Step 4: every point goes to the nearest live plane within `max_d` among the live
    /// regions of its cell and the 26 neighbours (ties: the lower region). One streaming
    /// pass over fixed chunks of points; each chunk's share of a region (point indices,
    /// split into core and fringe, and the core's moments) is appended in chunk order.
    fn assign(
        &self,
        points: &[Point3],
        region: &[u32],
        live: &[Option<LivePlane>],
        max_d: Real,
    ) -> Vec<RegionShare> {
        let is_live = |r: u32| r != NONE && live.get(r as usize).is_some_and(Option::is_some);
        let (cand_start, cand) = flat_lists(self.len(), |c, out| {
            let first = out.len();
            for r in std::iter::once(region[c])
                .chain(self.neighbours(c).iter().map(|&b| region[b as usize]))
            {
                if is_live(r) && !out[first..].contains(&r) {
                    out.push(r);
                }
            }
            out[first..].sort_unstable();
        });
        let parts: Vec<Vec<RegionShare>> = points
            .par_chunks(CHUNK)
            .enumerate()
            .map(|(ci, chunk)| {
                let mut shares: Vec<RegionShare> = Vec::new();
                let map = self.rec_cell.get(ci).map_or(&[][..], Vec::as_slice);
                let recs = self.rec.get(ci * CHUNK..).unwrap_or_default();
                let mut last_rec = u16::MAX;
                let mut cands: &[u32] = &[];
                // The share being filled and its core moments, summed in registers.
                let mut cur = (NONE, 0usize);
                let mut run = Moments::ZERO;
                for (j, (p, &rec)) in chunk.iter().zip(recs).enumerate() {
                    if rec != last_rec {
                        last_rec = rec;
                        cands = match map.get(rec as usize) {
                            Some(&c) => {
                                let (a, b) = (cand_start[c as usize], cand_start[c as usize + 1]);
                                cand.get(a as usize..b as usize).unwrap_or_default()
                            }
                            None => &[],
                        };
                    }
                    let mut best: Option<(u32, &LivePlane, Real)> = None;
                    for &r in cands {
                        let Some(Some(lp)) = live.get(r as usize) else {
                            continue;
                        };
                        let d = lp.plane.distance(p);
                        if d <= max_d && best.is_none_or(|(_, _, bd)| d < bd) {
                            best = Some((r, lp, d));
                        }
                    }
                    let Some((r, lp, d)) = best else {
                        continue;
                    };
                    if r != cur.0 {
                        if let Some(s) = shares.get_mut(cur.1) {
                            s.core_moments.merge(&run);
                        }
                        run = Moments::ZERO;
                        let k = match shares.iter().position(|s| s.region == r) {
                            Some(k) => k,
                            None => {
                                let mut share = RegionShare::new(r);
                                share.all.reserve(chunk.len());
                                share.core.reserve(chunk.len());
                                shares.push(share);
                                shares.len() - 1
                            }
                        };
                        cur = (r, k);
                    }
                    let i = (ci * CHUNK + j) as u32;
                    if let Some(s) = shares.get_mut(cur.1) {
                        s.all.push(i);
                        if d <= lp.core_mm {
                            s.core.push(i);
                            run.push(&(p - lp.plane.centroid));
                        } else {
                            s.fringe.push(i);
                        }
                    }
                }
                if let Some(s) = shares.get_mut(cur.1) {
                    s.core_moments.merge(&run);
                }
                shares
            })
            .collect();
        let mut out: Vec<RegionShare> = (0..live.len() as u32).map(RegionShare::new).collect();
        out.par_iter_mut().for_each(|whole| {
            let mine = || parts.iter().flatten().filter(|s| s.region == whole.region);
            whole.all.reserve_exact(mine().map(|s| s.all.len()).sum());
            whole.core.reserve_exact(mine().map(|s| s.core.len()).sum());
            whole
                .fringe
                .reserve_exact(mine().map(|s| s.fringe.len()).sum());
            for s in mine() {
                whole.all.extend_from_slice(&s.all);
                whole.core.extend_from_slice(&s.core);
                whole.fringe.extend_from_slice(&s.fringe);
                whole.core_moments.merge(&s.core_moments);
            }
        });
        out
    }
}

/// Whether planar cell `b`, neighbour of region cell `a`, joins the region.
fn joins(a: &CellStat, b: &CellStat, region: &RegionPlane, cos_max: Real, max_d: Real) -> bool {
    if a.normal.dot(&b.normal).abs() < cos_max || region.normal.dot(&b.normal).abs() < cos_max {
        return false;
    }
    let mid = (a.centroid.coords + b.centroid.coords) * 0.5;
    let gap = a.normal.dot(&(mid - a.centroid.coords)).abs()
        + b.normal.dot(&(mid - b.centroid.coords)).abs();
    gap <= max_d && region.distance(&b.centroid) <= max_d
}

/// A plane through `centroid` with unit `normal` (either sign).
#[derive(Clone, Copy, Debug)]
struct RegionPlane {
    centroid: Point3,
    normal: Vector3,
}

impl RegionPlane {
    fn distance(&self, p: &Point3) -> Real {
        self.normal.dot(&(p - self.centroid)).abs()
    }
}

/// Summed moments of a region's cells, about the seed cell's centroid.
#[derive(Clone, Debug)]
struct RegionAcc {
    reference: Vector3,
    cells: usize,
    mo: Moments,
    /// Σ of the cells' residual sums of squares about their own planes.
    rss: Real,
    /// Range of the cells' grid coordinates.
    lo: [u32; 3],
    hi: [u32; 3],
}

impl RegionAcc {
    fn new(seed: &CellStat, at: [u32; 3]) -> Self {
        let mut acc = Self {
            reference: seed.centroid.coords,
            cells: 0,
            mo: Moments::ZERO,
            rss: 0.0,
            lo: at,
            hi: at,
        };
        acc.add(seed, at);
        acc
    }

    fn add(&mut self, c: &CellStat, at: [u32; 3]) {
        let w = c.n as Real;
        let d = c.centroid.coords - self.reference;
        self.mo.n += c.n as usize;
        self.cells += 1;
        self.rss += c.rss;
        self.mo.s += d * w;
        let mut dd = [0.0; 6];
        add_outer(&mut dd, &d);
        for ((m, sc), o) in self.mo.m.iter_mut().zip(&c.scatter).zip(dd) {
            *m += sc + w * o;
        }
        for ((lo, hi), a) in self.lo.iter_mut().zip(&mut self.hi).zip(at) {
            *lo = (*lo).min(a);
            *hi = (*hi).max(a);
        }
    }

    fn plane(&self) -> Option<RegionPlane> {
        let (mean, cov) = self.mo.centred()?;
        let (_, normal) = eigen_sym3(&cov)?;
        Some(RegionPlane {
            centroid: Point3::from(self.reference + mean),
            normal,
        })
    }

    /// The region's plane for assignment, its core distance (`CORE_FRACTION · k_sigma`
    /// times the pooled within-cell rms residual) and a box holding all its points.
    fn live(&self, k_sigma: Real, cells: &Cells) -> Option<LivePlane> {
        let plane = self.plane()?;
        let sigma = (self.rss / self.mo.n as Real).sqrt();
        Some(LivePlane {
            plane,
            core_mm: CORE_FRACTION * k_sigma * sigma,
            bbox: cells.cell_box(self.lo, self.hi),
        })
    }
}

/// A region taking part in the assignment.
#[derive(Clone, Copy, Debug)]
struct LivePlane {
    plane: RegionPlane,
    /// Points nearer the plane than this are *core*: expected inside every threshold of
    /// the robust rule (checked, see [`fit_region`]).
    core_mm: Real,
    /// Holds every point that can be assigned to the region.
    bbox: Aabb,
}

/// The points assigned to a region (or a chunk's share of them): indices of the core
/// and the fringe points (see [`fit_region`]), ascending, and the core's moments about
/// the region plane's centroid.
#[derive(Debug)]
struct RegionShare {
    region: u32,
    /// All indices, ascending.
    all: Vec<u32>,
    core: Vec<u32>,
    fringe: Vec<u32>,
    core_moments: Moments,
}

impl RegionShare {
    fn new(region: u32) -> Self {
        Self {
            region,
            all: Vec::new(),
            core: Vec::new(),
            fringe: Vec::new(),
            core_moments: Moments::ZERO,
        }
    }

    fn len(&self) -> usize {
        self.all.len()
    }
}

/// A plane fitted from moments, as [`fit_plane`] would fit it (up to rounding).
#[derive(Clone, Copy, Debug)]
struct MomentFit {
    plane: RegionPlane,
    rms: Real,
}

/// The orthogonal fit of the points whose moments about `reference` are `mo`; `None` when
/// [`fit_plane`] would refuse them (fewer than 3, collinear).
fn moment_fit(mo: &Moments, reference: &Point3) -> Option<MomentFit> {
    if mo.n < PLANE_FIT_MIN {
        return None;
    }
    let (mean, cov) = mo.centred()?;
    let (l, normal) = eigen_sym3(&cov)?;
    if !(l[2] > 0.0 && l[1] > DEGENERATE_RATIO * l[2]) {
        return None;
    }
    Some(MomentFit {
        plane: RegionPlane {
            centroid: reference + mean,
            normal,
        },
        rms: (l[0].max(0.0) / mo.n as Real).sqrt(),
    })
}

/// Largest difference between the distances of a point of `bbox` to planes `a` and `b`
/// (affine in the point, so largest at a corner).
fn plane_gap_bound(a: &RegionPlane, b: &RegionPlane, bbox: &Aabb) -> Real {
    let nb = if a.normal.dot(&b.normal) < 0.0 {
        -b.normal
    } else {
        b.normal
    };
    let mut worst: Real = 0.0;
    for corner in 0..8 {
        let x = Point3::new(
            if corner & 1 == 0 {
                bbox.min.x
            } else {
                bbox.max.x
            },
            if corner & 2 == 0 {
                bbox.min.y
            } else {
                bbox.max.y
            },
            if corner & 4 == 0 {
                bbox.min.z
            } else {
                bbox.max.z
            },
        );
        let gap = a.normal.dot(&(x - a.centroid)) - nb.dot(&(x - b.centroid));
        worst = worst.max(gap.abs());
    }
    worst
}

/// A region's points split for the σ-trimming rounds of [`fit_region`]: the *core*
/// (points within `core_mm` of `base`, inside every threshold while the check of
/// [`fit_region`] holds), summed once, and the *fringe*, re-tested each round.
struct Split {
    base: RegionPlane,
    core_mm: Real,
    /// Moments of the core about the region plane's centroid.
    core_moments: Moments,
    /// Fringe points, in index order.
    fringe: Vec<Point3>,
    /// After a re-split: all points in index order, and which are core (the fringe is the
    /// rest, in order). Before: the core is the assignment's.
    all: Option<(Vec<Point3>, Vec<bool>)>,
}

/// Membership of the points in the current subset of the rounds.
enum Members {
    /// The core and the fringe points kept.
    Split(Vec<bool>),
    /// Per point, in index order (from a re-split).
    Full(Vec<bool>),
}

/// Moments about `reference` of the points `pts[i]` with `keep(i)`, over fixed chunks.
fn moments_where(
    pts: &[Point3],
    reference: &Point3,
    keep: impl Fn(usize) -> bool + Sync,
) -> Moments {
    chunked_fold(
        pts.len(),
        Moments::ZERO,
        |r| {
            let mut m = Moments::ZERO;
            for i in r {
                if keep(i) {
                    m.push(&(pts[i] - reference));
                }
            }
            m
        },
        |mut a, b| {
            a.merge(&b);
            a
        },
    )
}

impl Split {
    /// Moments of the core and the fringe points kept (all fringe points for `None`).
    fn moments(&self, keep: Option<&[bool]>, reference: &Point3) -> Moments {
        let mut mo = self.core_moments;
        mo.merge(&moments_where(&self.fringe, reference, |i| {
            keep.is_none_or(|k| k[i])
        }));
        mo
    }

    /// All points in index order.
    fn all_points(&self, points: &[Point3], share: &RegionShare) -> Vec<Point3> {
        match &self.all {
            Some((all, _)) => all.clone(),
            None => gather(points, &share.all),
        }
    }

    /// Per point in index order: core, or the next fringe point's flag in `keep`.
    fn full(&self, share: &RegionShare, keep: &[bool]) -> Vec<bool> {
        let mut fringe = keep.iter();
        let mut next_fringe = || fringe.next().copied().unwrap_or(false);
        let mut out = Vec::with_capacity(keep.len() + share.core.len());
        match &self.all {
            Some((_, is_core)) => {
                for &c in is_core {
                    out.push(c || next_fringe());
                }
            }
            None => {
                let (core, fr) = (&share.core, &share.fringe);
                let (mut i, mut j) = (0, 0);
                while i < core.len() || j < fr.len() {
                    let from_core = match (core.get(i), fr.get(j)) {
                        (Some(a), Some(b)) => a < b,
                        (a, _) => a.is_some(),
                    };
                    if from_core {
                        out.push(true);
                        i += 1;
                    } else {
                        out.push(next_fringe());
                        j += 1;
                    }
                }
            }
        }
        out
    }

    /// The fringe part of a per-point membership.
    fn fringe_part(&self, full: &[bool]) -> Vec<bool> {
        match &self.all {
            Some((_, is_core)) => full
                .iter()
                .zip(is_core)
                .filter_map(|(&k, &c)| (!c).then_some(k))
                .collect(),
            None => Vec::new(),
        }
    }

    /// The current members as one buffer: core then kept fringe (both in index order)
    /// before a re-split, index order after.
    fn members(&self, points: &[Point3], share: &RegionShare, members: &Members) -> Vec<Point3> {
        let full = match (members, &self.all) {
            (Members::Split(keep), None) => {
                let mut pts = Vec::with_capacity(share.len());
                share
                    .core
                    .par_iter()
                    .map(|&i| points[i as usize])
                    .collect_into_vec(&mut pts);
                pts.extend(
                    self.fringe
                        .iter()
                        .zip(keep)
                        .filter_map(|(p, &k)| k.then_some(*p)),
                );
                return pts;
            }
            (Members::Split(keep), Some(_)) => self.full(share, keep),
            (Members::Full(full), _) => full.clone(),
        };
        let all = self.all_points(points, share);
        all.par_iter()
            .zip(&full)
            .filter_map(|(p, &k)| k.then_some(*p))
            .collect()
    }

    /// Re-splits all points around `plane` with core distance `CORE_FRACTION · t`.
    /// Returns the new split, the current membership (from `keep`) and the next (the
    /// points within `t` of `plane`), both per point in index order.
    fn resplit(
        &self,
        points: &[Point3],
        share: &RegionShare,
        keep: &[bool],
        plane: &RegionPlane,
        t: Real,
        reference: &Point3,
    ) -> (Split, Vec<bool>, Vec<bool>) {
        let current = self.full(share, keep);
        let all = self.all_points(points, share);
        let core_mm = CORE_FRACTION * t;
        let dist: Vec<Real> = all.par_iter().map(|p| plane.distance(p)).collect();
        let next: Vec<bool> = dist.par_iter().map(|&d| d <= t).collect();
        let is_core: Vec<bool> = dist.par_iter().map(|&d| d <= core_mm).collect();
        let core_moments = moments_where(&all, reference, |i| is_core[i]);
        let fringe: Vec<Point3> = all
            .iter()
            .zip(&is_core)
            .filter_map(|(p, &c)| (!c).then_some(*p))
            .collect();
        let split = Split {
            base: *plane,
            core_mm,
            core_moments,
            fringe,
            all: Some((all, is_core)),
        };
        (split, current, next)
    }
}

/// Step 5: the robust fit of a region's points — [`fit_plane_robust`]'s result, cheaply.
///
/// [`fit_plane_robust`] re-tests every point against each new plane, five passes over
/// the points per round, for the five or six rounds σ-trimming takes to settle. Here the
/// same rounds (threshold max(k·rms, [`tol::LENGTH_EPS`]), all points re-tested, until
/// the set repeats, a refit would fail, or `max_iterations`) run on moments: the *core*
/// points (nearer a base plane P₀ than `core_mm` — at first the region plane, summed
/// during assignment) provably stay inside every threshold t — checked each round as
/// `core_mm + max |dist(P) − dist(P₀)|` over the region's bounding box ≤ t — so only the
/// few *fringe* points are re-tested. When the check fails, all points are re-split
/// around the current plane (at most [`MAX_RESPLITS`] times; then [`fit_plane_robust`]
/// itself runs). The set the rounds end with is fitted by [`fit_plane`]: the fit
/// [`fit_plane_robust`] ends with, as it would find nothing more to reject (its planes
/// differ from the moment planes only by rounding, 1e-15 relative). `n_rejected` counts
/// against all assigned points.
fn fit_region(
    points: &[Point3],
    share: &RegionShare,
    lp: &LivePlane,
    rule: &RobustRule,
) -> Option<PlaneFit> {
    let total = share.len();
    let reference = lp.plane.centroid;
    let mut split = Split {
        base: lp.plane,
        core_mm: lp.core_mm,
        core_moments: share.core_moments,
        fringe: gather(points, &share.fringe),
        all: None,
    };
    let slow = |split: &Split| fit_plane_robust(&split.all_points(points, share), rule);
    let Some(mut fit) = moment_fit(&split.moments(None, &reference), &reference) else {
        return finish(slow(&split), total);
    };
    let mut members = Members::Split(vec![true; split.fringe.len()]);
    let mut resplits = 0;
    for _ in 0..rule.max_iterations {
        let t = (rule.k_sigma * fit.rms).max(tol::LENGTH_EPS);
        let bound = split.core_mm + plane_gap_bound(&split.base, &fit.plane, &lp.bbox);
        let keep = match &members {
            Members::Split(keep) => keep.clone(),
            Members::Full(full) => split.fringe_part(full),
        };
        let next = if bound + tol::LENGTH_EPS <= t {
            let next: Vec<bool> = split
                .fringe
                .par_iter()
                .map(|p| fit.plane.distance(p) <= t)
                .collect();
            if next == keep {
                break;
            }
            next
        } else {
            if resplits == MAX_RESPLITS {
                return finish(slow(&split), total);
            }
            resplits += 1;
            let (new_split, current, next) =
                split.resplit(points, share, &keep, &fit.plane, t, &reference);
            split = new_split;
            let settled = next == current;
            members = Members::Full(current);
            if settled {
                break;
            }
            split.fringe_part(&next)
        };
        // A refit that would fail ends the rounds with the previous fit.
        let Some(f) = moment_fit(&split.moments(Some(&next), &reference), &reference) else {
            break;
        };
        fit = f;
        members = Members::Split(next);
    }
    finish(fit_plane(&split.members(points, share, &members)), total)
}

/// The fit, with `n_rejected` counted against all `total` assigned points.
fn finish(
    fit: Result<PlaneFit, crate::metrology::fit::FitError>,
    total: usize,
) -> Option<PlaneFit> {
    let mut fit = fit.ok()?;
    fit.n_rejected = total - fit.n_used;
    Some(fit)
}

/// Step 5 for every live region; segments of at least `min_points` points, largest first
/// (ties: smallest first index).
fn fit_regions(
    points: &[Point3],
    shares: Vec<RegionShare>,
    live: &[Option<LivePlane>],
    opts: &PlaneSegmentOptions,
) -> Vec<PlaneSegment> {
    let min_points = opts.min_points.max(PLANE_FIT_MIN);
    let mut segments: Vec<PlaneSegment> = shares
        .into_par_iter()
        .zip(live)
        .filter_map(|(share, lp)| {
            let lp = lp.as_ref()?;
            if share.len() < min_points {
                return None;
            }
            let fit = fit_region(points, &share, lp, &opts.robust)?;
            Some(PlaneSegment {
                fit,
                indices: share.all,
            })
        })
        .collect();
    segments.sort_by(|a, b| {
        b.indices
            .len()
            .cmp(&a.indices.len())
            .then(a.indices.first().cmp(&b.indices.first()))
    });
    segments
}

/// All planar faces of a cloud, each with its robust orthogonal least-squares fit: see the
/// module documentation for the method (grid cells, cell planes, region growing, point
/// assignment by distance, [`fit_plane_robust`]).
///
/// Segments are sorted by size, largest first (ties: smallest first index); their
/// indices are disjoint. Points of no segment (edges, noise, faces below `min_points`)
/// are in none. Bit-identical for any rayon thread count.
///
/// Errors: [`SegmentError::NoPoints`], [`SegmentError::NonFinite`],
/// [`SegmentError::BadOptions`] (non-positive cell or distance, angle outside (0, π/2],
/// non-positive `robust.k_sigma`, more than [`MAX_GRID_CELLS`] cells over the bounding
/// box), [`SegmentError::NothingFound`] when no segment of `min_points` exists.
pub fn segment_planes(
    points: &[Point3],
    opts: &PlaneSegmentOptions,
) -> Result<Vec<PlaneSegment>, SegmentError> {
    let cells = Cells::build(points, opts)?;
    let (region, accs) = cells.grow(&cells.seeds(), opts);
    let min_points = opts.min_points.max(PLANE_FIT_MIN);
    let live: Vec<Option<LivePlane>> = accs
        .iter()
        .map(|a| {
            if a.mo.n >= min_points {
                a.live(opts.robust.k_sigma, &cells)
            } else {
                None
            }
        })
        .collect();
    let shares = cells.assign(points, &region, &live, opts.max_distance_mm);
    let segments = fit_regions(points, shares, &live, opts);
    if segments.is_empty() {
        return Err(SegmentError::NothingFound);
    }
    Ok(segments)
}

/// The planar region at `seed`: grown (as in [`segment_planes`]) from the cell holding the
/// point nearest `seed` — or, when that cell is not planar, from the neighbouring planar
/// cell whose plane passes nearest that point — then assigned and fitted alone (no other
/// region competes for edge points).
///
/// Errors: as [`segment_planes`]; a non-finite seed is [`SegmentError::BadOptions`]; no
/// planar cell at the seed, or a region of fewer than `min_points` points, is
/// [`SegmentError::NothingFound`].
pub fn select_region_from_seed(
    points: &[Point3],
    seed: &Point3,
    opts: &PlaneSegmentOptions,
) -> Result<PlaneSegment, SegmentError> {
    if !is_valid(seed) {
        return Err(SegmentError::BadOptions(
            "the seed point is not finite".to_string(),
        ));
    }
    let cells = Cells::build(points, opts)?;
    let nearest = chunked_fold(
        points.len(),
        None,
        |r| {
            let mut best: Option<(Real, usize)> = None;
            for i in r {
                let d = (points[i] - seed).norm_squared();
                if best.is_none_or(|(bd, _)| d < bd) {
                    best = Some((d, i));
                }
            }
            best
        },
        |a, b| match (a, b) {
            (Some(x), Some(y)) => Some(if y.0 < x.0 { y } else { x }),
            (x, y) => x.or(y),
        },
    );
    let (_, i) = nearest.ok_or(SegmentError::NoPoints)?;
    let p = points[i];
    let c = cells.cell_of(&p).ok_or(SegmentError::NothingFound)?;
    let start = if cells.stats[c].planar {
        Some(c)
    } else {
        let mut best: Option<(Real, usize)> = None;
        for &b in cells.neighbours(c) {
            let s = &cells.stats[b as usize];
            if s.planar {
                let d = s.normal.dot(&(p - s.centroid)).abs();
                if best.is_none_or(|(bd, _)| d < bd) {
                    best = Some((d, b as usize));
                }
            }
        }
        best.map(|(_, b)| b)
    };
    let start = start.ok_or(SegmentError::NothingFound)?;
    let (region, accs) = cells.grow(&[start as u32], opts);
    let live: Vec<Option<LivePlane>> = accs
        .iter()
        .map(|a| a.live(opts.robust.k_sigma, &cells))
        .collect();
    let shares = cells.assign(points, &region, &live, opts.max_distance_mm);
    fit_regions(points, shares, &live, opts)
        .into_iter()
        .next()
        .ok_or(SegmentError::NothingFound)
}

/// Indices (ascending) of the points inside the box `[min, max]` (faces included). Points
/// with a NaN coordinate are never inside.
pub fn select_box(points: &[Point3], min: &Point3, max: &Point3) -> Vec<u32> {
    let b = Aabb {
        min: *min,
        max: *max,
    };
    points
        .par_iter()
        .enumerate()
        .filter(|(_, p)| b.contains(p))
        .filter_map(|(i, _)| u32::try_from(i).ok())
        .collect()
}

// ---------------------------------------------------------------------------------------
// RANSAC
// ---------------------------------------------------------------------------------------

/// Options of the RANSAC functions.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RansacOptions {
    /// Largest distance (mm) of an inlier from the model surface; about 3–4σ of the noise.
    pub distance_mm: Real,
    /// Number of minimal samples tried.
    pub iterations: usize,
    /// Seed of the [`CounterRng`] that draws the samples: iteration i uses stream i.
    pub seed: u64,
    /// Fewest inliers of a result.
    pub min_inliers: usize,
}

/// A sphere found by [`ransac_sphere`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SphereModel {
    /// Centre (mm).
    pub centre: Point3,
    /// Radius (mm).
    pub radius: Real,
}

impl SphereModel {
    /// Distance of `p` from the sphere surface (mm, ≥ 0).
    pub fn distance(&self, p: &Point3) -> Real {
        ((p - self.centre).norm() - self.radius).abs()
    }
}

/// A cylinder found by [`ransac_cylinder`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CylinderModel {
    /// A point on the axis (mm).
    pub point: Point3,
    /// Axis direction.
    pub axis: UnitVector3,
    /// Radius (mm).
    pub radius: Real,
}

impl CylinderModel {
    /// Distance of `p` from the (infinite) cylinder surface (mm, ≥ 0).
    pub fn distance(&self, p: &Point3) -> Real {
        let d = p - self.point;
        let radial = d - self.axis.into_inner() * self.axis.dot(&d);
        (radial.norm() - self.radius).abs()
    }
}

/// A shape found by RANSAC: the model from the last least-squares refit and its inliers.
#[derive(Clone, Debug, PartialEq)]
pub struct ShapeMatch<M> {
    /// The model estimate.
    pub model: M,
    /// Indices of the points within `distance_mm` of the model, ascending.
    pub inliers: Vec<u32>,
}

fn check_ransac(points: &[Point3], opts: &RansacOptions) -> Result<Aabb, SegmentError> {
    let bbox = check_and_bound(points)?;
    if !(opts.distance_mm.is_finite() && opts.distance_mm > 0.0) {
        return Err(SegmentError::BadOptions(format!(
            "distance_mm = {}: must be a positive length",
            opts.distance_mm
        )));
    }
    if opts.iterations == 0 {
        return Err(SegmentError::BadOptions(
            "iterations = 0: RANSAC needs at least one sample".to_string(),
        ));
    }
    Ok(bbox)
}

/// `S` distinct indices below `n` for iteration `it`, or `None` after [`MAX_SAMPLE_DRAWS`].
fn draw_sample<const S: usize>(rng: &CounterRng, it: u64, n: usize) -> Option<[usize; S]> {
    let mut out = [0usize; S];
    let mut got = 0;
    for k in 0..MAX_SAMPLE_DRAWS {
        let i = ((rng.uniform(it, k) * n as Real) as usize).min(n - 1);
        if !out[..got].contains(&i) {
            out[got] = i;
            got += 1;
            if got == S {
                return Some(out);
            }
        }
    }
    None
}

/// The model of the best-scoring minimal sample: most inliers, ties to the earliest
/// iteration. Iterations run in parallel; the choice is order-independent.
fn ransac_best<M, const S: usize>(
    n: usize,
    opts: &RansacOptions,
    model: impl Fn(&[usize; S]) -> Option<M> + Sync,
    residual: impl Fn(&M, usize) -> Real + Sync,
) -> Option<M>
where
    M: Send,
{
    if n < S {
        return None;
    }
    let rng = CounterRng::new(opts.seed);
    (0..opts.iterations)
        .into_par_iter()
        .filter_map(|it| {
            let sample = draw_sample::<S>(&rng, it as u64, n)?;
            let m = model(&sample)?;
            let count = (0..n)
                .filter(|&i| residual(&m, i) <= opts.distance_mm)
                .count();
            Some((count, it, m))
        })
        .reduce_with(|a, b| {
            if b.0 > a.0 || (b.0 == a.0 && b.1 < a.1) {
                b
            } else {
                a
            }
        })
        .map(|(_, _, m)| m)
}

/// Indices (ascending) with residual within `d`.
fn select_within(n: usize, d: Real, residual: impl Fn(usize) -> Real + Sync) -> Vec<u32> {
    (0..n)
        .into_par_iter()
        .filter(|&i| residual(i) <= d)
        .map(|i| i as u32)
        .collect()
}

/// Rounds of refit on the inliers and re-selection, until the inliers repeat, a refit
/// fails, or [`REFINE_ROUNDS`].
fn refine<M>(
    mut model: M,
    min_sample: usize,
    select: impl Fn(&M) -> Vec<u32>,
    refit: impl Fn(&[u32], &M) -> Option<M>,
) -> (M, Vec<u32>) {
    let mut inliers = select(&model);
    for _ in 0..REFINE_ROUNDS {
        if inliers.len() < min_sample {
            break;
        }
        let Some(m) = refit(&inliers, &model) else {
            break;
        };
        let next = select(&m);
        if next.len() < min_sample {
            break;
        }
        model = m;
        if next == inliers {
            break;
        }
        inliers = next;
    }
    (model, inliers)
}

fn gather(points: &[Point3], idx: &[u32]) -> Vec<Point3> {
    idx.par_iter()
        .filter_map(|&i| points.get(i as usize).copied())
        .collect()
}

fn found<M>(
    (model, inliers): (M, Vec<u32>),
    opts: &RansacOptions,
    sample: usize,
) -> Result<ShapeMatch<M>, SegmentError> {
    if inliers.len() < opts.min_inliers.max(sample) {
        return Err(SegmentError::NothingFound);
    }
    Ok(ShapeMatch { model, inliers })
}

/// The plane through three points, `None` for a triangle with an angle under
/// [`MIN_SAMPLE_SIN`].
fn plane_through(a: &Point3, b: &Point3, c: &Point3) -> Option<Plane> {
    let (u, v) = (b - a, c - a);
    let n = u.cross(&v);
    let nn = n.norm();
    if !(nn > MIN_SAMPLE_SIN * u.norm() * v.norm() && nn.is_finite()) {
        return None;
    }
    Some(Plane::through(a, UnitVector3::new_unchecked(n / nn)))
}

/// Inlier indices (ascending) of the plane with most points within `distance_mm`: RANSAC
/// on triangles, then rounds of [`fit_plane`] on the inliers and re-selection by distance.
///
/// Errors: [`SegmentError::NoPoints`], [`SegmentError::NonFinite`],
/// [`SegmentError::BadOptions`] (non-positive distance, no iterations),
/// [`SegmentError::NothingFound`] (fewer than `min_inliers` inliers, or no valid sample).
pub fn ransac_plane(points: &[Point3], opts: &RansacOptions) -> Result<Vec<u32>, SegmentError> {
    check_ransac(points, opts)?;
    let n = points.len();
    let d = opts.distance_mm;
    let best = ransac_best::<Plane, 3>(
        n,
        opts,
        |s| plane_through(&points[s[0]], &points[s[1]], &points[s[2]]),
        |pl, i| pl.signed_distance(&points[i]).abs(),
    )
    .ok_or(SegmentError::NothingFound)?;
    let result = refine(
        best,
        PLANE_FIT_MIN,
        |pl| select_within(n, d, |i| pl.signed_distance(&points[i]).abs()),
        |idx, _| fit_plane(&gather(points, idx)).ok().map(|f| f.plane),
    );
    found(result, opts, PLANE_FIT_MIN).map(|m| m.inliers)
}

/// The sphere through four points, `None` when nearly coplanar
/// ([`MIN_SAMPLE_DET_RATIO`]) or larger than `max_radius`.
fn sphere_through(p: [&Point3; 4], max_radius: Real) -> Option<SphereModel> {
    let d = [p[1] - p[0], p[2] - p[0], p[3] - p[0]];
    let a = Matrix3::new(
        d[0].x, d[0].y, d[0].z, //
        d[1].x, d[1].y, d[1].z, //
        d[2].x, d[2].y, d[2].z,
    ) * 2.0;
    let b = Vector3::new(
        d[0].norm_squared(),
        d[1].norm_squared(),
        d[2].norm_squared(),
    );
    let hadamard = 8.0 * d[0].norm() * d[1].norm() * d[2].norm();
    let det = a.determinant();
    if !(det.abs() > MIN_SAMPLE_DET_RATIO * hadamard && det.is_finite()) {
        return None;
    }
    let x = a.lu().solve(&b)?;
    let radius = x.norm();
    (radius <= max_radius).then(|| SphereModel {
        centre: p[0] + x,
        radius,
    })
}

/// Algebraic least-squares sphere (|q|² = 2 q·c + ρ about the inliers' mean).
fn sphere_lsq(points: &[Point3], idx: &[u32], max_radius: Real) -> Option<SphereModel> {
    let first = points.get(*idx.first()? as usize)?.coords;
    let sum = chunked_fold(
        idx.len(),
        Vector3::zeros(),
        |r| {
            idx[r].iter().fold(Vector3::zeros(), |s, &i| {
                s + (points[i as usize].coords - first)
            })
        },
        |a, b| a + b,
    );
    let mean = first + sum / idx.len() as Real;
    type Acc = (nalgebra::Matrix4<Real>, nalgebra::Vector4<Real>);
    let zero: Acc = (nalgebra::Matrix4::zeros(), nalgebra::Vector4::zeros());
    let (a, b) = chunked_fold(
        idx.len(),
        zero,
        |r| {
            let mut acc = zero;
            for &i in &idx[r] {
                let q = points[i as usize].coords - mean;
                let row = nalgebra::Vector4::new(2.0 * q.x, 2.0 * q.y, 2.0 * q.z, 1.0);
                acc.0 += row * row.transpose();
                acc.1 += row * q.norm_squared();
            }
            acc
        },
        |x, y| (x.0 + y.0, x.1 + y.1),
    );
    let x = a.lu().solve(&b)?;
    let c = Vector3::new(x[0], x[1], x[2]);
    let r2 = x[3] + c.norm_squared();
    let radius = r2.sqrt();
    (r2 > 0.0 && radius <= max_radius).then(|| SphereModel {
        centre: Point3::from(mean + c),
        radius,
    })
}

/// The sphere with most points within `distance_mm`: RANSAC on four points, then rounds
/// of algebraic least-squares refit and re-selection. Spheres larger than the points'
/// bounding-box diagonal are not determined by them and never returned.
///
/// Errors: as [`ransac_plane`].
pub fn ransac_sphere(
    points: &[Point3],
    opts: &RansacOptions,
) -> Result<ShapeMatch<SphereModel>, SegmentError> {
    let bbox = check_ransac(points, opts)?;
    let max_radius = (bbox.max - bbox.min).norm();
    let n = points.len();
    let d = opts.distance_mm;
    let best = ransac_best::<SphereModel, 4>(
        n,
        opts,
        |s| sphere_through(s.map(|i| &points[i]), max_radius),
        |m, i| m.distance(&points[i]),
    )
    .ok_or(SegmentError::NothingFound)?;
    let result = refine(
        best,
        4,
        |m| select_within(n, d, |i| m.distance(&points[i])),
        |idx, _| sphere_lsq(points, idx, max_radius),
    );
    found(result, opts, 4)
}

/// The cylinder through two points with normals: axis n₁ × n₂; the centre where the two
/// normal lines meet in the plane across the axis; radius the mean distance of the two
/// points from it. `None` for normals within [`MIN_SAMPLE_SIN`] of parallel or a radius
/// above `max_radius`.
fn cylinder_through(
    p1: &Point3,
    n1: &Vector3,
    p2: &Point3,
    n2: &Vector3,
    max_radius: Real,
) -> Option<CylinderModel> {
    let a = n1.cross(n2);
    let s = a.norm();
    if !(s >= MIN_SAMPLE_SIN && s.is_finite()) {
        return None;
    }
    let a = a / s;
    let d = p2 - p1;
    let d = d - a * a.dot(&d);
    // t·n₁ − u·n₂ = d in the plane across the axis (n₁, n₂ ⟂ a).
    let c = n1.dot(n2);
    let (e1, e2) = (n1.dot(&d), n2.dot(&d));
    let t = (e1 - c * e2) / (1.0 - c * c);
    let u = c * t - e2;
    let centre = (n1 * t + d + n2 * u) * 0.5;
    let radius = 0.5 * (t.abs() + u.abs());
    (radius.is_finite() && radius <= max_radius).then(|| CylinderModel {
        point: p1 + centre,
        axis: UnitVector3::new_unchecked(a),
        radius,
    })
}

/// Least-squares cylinder on the inliers: axis from the normals (smallest eigenvector of
/// Σ nnᵀ), then an algebraic circle fit across it.
fn cylinder_lsq(
    points: &[Point3],
    normals: &[UnitVector3],
    idx: &[u32],
    prev: &CylinderModel,
    max_radius: Real,
) -> Option<CylinderModel> {
    let first = points.get(*idx.first()? as usize)?.coords;
    let (m, sum) = chunked_fold(
        idx.len(),
        ([0.0; 6], Vector3::zeros()),
        |r| {
            let mut acc = ([0.0; 6], Vector3::zeros());
            for &i in &idx[r] {
                add_outer(&mut acc.0, &normals[i as usize]);
                acc.1 += points[i as usize].coords - first;
            }
            acc
        },
        |mut x, y| {
            for (a, b) in x.0.iter_mut().zip(y.0) {
                *a += b;
            }
            (x.0, x.1 + y.1)
        },
    );
    let (_, mut axis) = eigen_sym3(&m)?;
    if axis.dot(&prev.axis) < 0.0 {
        axis = -axis;
    }
    let mean = first + sum / idx.len() as Real;
    let (u, w) = basis_perpendicular(&axis);
    let (a, b) = chunked_fold(
        idx.len(),
        (Matrix3::zeros(), Vector3::zeros()),
        |r| {
            let mut acc = (Matrix3::zeros(), Vector3::zeros());
            for &i in &idx[r] {
                let q = points[i as usize].coords - mean;
                let (x, y) = (q.dot(&u), q.dot(&w));
                let row = Vector3::new(2.0 * x, 2.0 * y, 1.0);
                acc.0 += row * row.transpose();
                acc.1 += row * (x * x + y * y);
            }
            acc
        },
        |x, y| (x.0 + y.0, x.1 + y.1),
    );
    let x = a.lu().solve(&b)?;
    let r2 = x[2] + x[0] * x[0] + x[1] * x[1];
    let radius = r2.sqrt();
    (r2 > 0.0 && radius <= max_radius).then(|| CylinderModel {
        point: Point3::from(mean + u * x[0] + w * x[1]),
        axis: UnitVector3::new_unchecked(axis),
        radius,
    })
}

/// The cylinder with most points within `distance_mm` of its surface: RANSAC on pairs of
/// points with their normals (axis n₁ × n₂, the standard minimal sample), then rounds of
/// least-squares refit (axis from the inliers' normals, circle fit across it) and
/// re-selection. `normals[i]` belongs to `points[i]` (e.g. from [`estimate_normals`]);
/// their sign does not matter. Cylinders wider than the points' bounding-box diagonal are
/// never returned.
///
/// Errors: as [`ransac_plane`]; `normals` of another length, or a non-finite normal, is
/// [`SegmentError::BadOptions`].
pub fn ransac_cylinder(
    points: &[Point3],
    normals: &[UnitVector3],
    opts: &RansacOptions,
) -> Result<ShapeMatch<CylinderModel>, SegmentError> {
    let bbox = check_ransac(points, opts)?;
    if normals.len() != points.len() {
        return Err(SegmentError::BadOptions(format!(
            "{} normals for {} points",
            normals.len(),
            points.len()
        )));
    }
    if let Some(i) = normals
        .par_iter()
        .position_first(|n| !n.iter().all(|c| c.is_finite()))
    {
        return Err(SegmentError::BadOptions(format!(
            "normal {i} is not finite"
        )));
    }
    let max_radius = (bbox.max - bbox.min).norm();
    let n = points.len();
    let d = opts.distance_mm;
    let best = ransac_best::<CylinderModel, 2>(
        n,
        opts,
        |s| {
            cylinder_through(
                &points[s[0]],
                &normals[s[0]],
                &points[s[1]],
                &normals[s[1]],
                max_radius,
            )
        },
        |m, i| m.distance(&points[i]),
    )
    .ok_or(SegmentError::NothingFound)?;
    let result = refine(
        best,
        2,
        |m| select_within(n, d, |i| m.distance(&points[i])),
        |idx, prev| cylinder_lsq(points, normals, idx, prev, max_radius),
    );
    found(result, opts, 2)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::{Isometry3, Rotation3};
    use proptest::prelude::*;

    /// Scanner noise (mm) and point spacing (mm) of the structured-light scanner.
    const SIGMA: Real = 0.025;
    const PITCH: Real = 0.185;

    /// Viewing direction of the scene's camera (from (0, −330, 80) towards the face).
    fn view() -> Vector3 {
        Vector3::new(0.0, 308.0, -80.0).normalize()
    }

    /// A rectangle `origin + s·u + t·v`, s ∈ [0, lu], t ∈ [0, lv], rastered at `pitch`.
    struct Face {
        origin: Point3,
        u: Vector3,
        v: Vector3,
        lu: Real,
        lv: Real,
    }

    /// Raster points of `face` with Gaussian noise of `noise` mm along the view, labelled.
    fn raster(face: &Face, label: u8, noise: Real, pitch: Real, cloud: &mut Labelled) {
        let rng = CounterRng::new(17);
        let (nu, nv) = ((face.lu / pitch) as usize, (face.lv / pitch) as usize);
        for j in 0..nv {
            for i in 0..nu {
                let k = cloud.points.len() as u64;
                let p = face.origin
                    + face.u * ((i as Real + 0.5) * pitch)
                    + face.v * ((j as Real + 0.5) * pitch);
                cloud.points.push(p + view() * (noise * rng.normal(k)));
                cloud.labels.push(label);
            }
        }
    }

    #[derive(Default)]
    struct Labelled {
        points: Vec<Point3>,
        labels: Vec<u8>,
        planes: Vec<Plane>,
    }

    /// The step experiment: face A (y = 0, z ∈ [0, 10]), face B 1 mm back (y = 1,
    /// z ∈ [−10, 0]), both 40 mm wide, and the top face (z = 10, y ∈ [0, 10]) at 90°;
    /// moved by `pose`.
    fn step_cloud(noise: Real, pose: &Isometry3) -> Labelled {
        let (x, y, z) = (Vector3::x(), Vector3::y(), Vector3::z());
        let faces = [
            (
                Face {
                    origin: Point3::new(0.0, 0.0, 0.0),
                    u: x,
                    v: z,
                    lu: 40.0,
                    lv: 10.0,
                },
                y,
                0.0,
            ),
            (
                Face {
                    origin: Point3::new(0.0, 1.0, -10.0),
                    u: x,
                    v: z,
                    lu: 40.0,
                    lv: 10.0,
                },
                y,
                1.0,
            ),
            (
                Face {
                    origin: Point3::new(0.0, 0.0, 10.0),
                    u: x,
                    v: y,
                    lu: 40.0,
                    lv: 10.0,
                },
                z,
                10.0,
            ),
        ];
        let mut c = Labelled::default();
        for (label, (face, normal, offset)) in faces.iter().enumerate() {
            raster(face, label as u8, noise, PITCH, &mut c);
            let n = UnitVector3::new_normalize(pose.rotation * normal);
            let on = pose * Point3::from(normal * *offset);
            c.planes.push(Plane::through(&on, n));
        }
        for p in &mut c.points {
            *p = pose * *p;
        }
        c
    }

    fn step_opts() -> PlaneSegmentOptions {
        PlaneSegmentOptions {
            min_points: 1000,
            ..PlaneSegmentOptions::default()
        }
    }

    fn tilted_pose() -> Isometry3 {
        Isometry3::from_parts(
            Vector3::new(150.0, -80.0, 60.0).into(),
            Rotation3::from_axis_angle(
                &UnitVector3::new_normalize(Vector3::new(1.0, 2.0, 3.0)),
                0.7,
            ),
        )
    }

    /// Angle (rad) between two lines.
    fn line_angle(a: &Vector3, b: &Vector3) -> Real {
        a.normalize().cross(&b.normalize()).norm()
    }

    /// The face each segment holds most points of.
    fn majority(seg: &PlaneSegment, labels: &[u8]) -> u8 {
        let mut count = [0usize; 3];
        for &i in &seg.indices {
            count[labels[i as usize] as usize] += 1;
        }
        (0..3).max_by_key(|&k| count[k]).unwrap_or(0) as u8
    }

    /// Checks the segmentation of a step cloud; returns the segments' faces.
    fn check_step(c: &Labelled, segs: &[PlaneSegment], opts: &PlaneSegmentOptions, exact: bool) {
        assert_eq!(segs.len(), 3, "three segments");
        let mut seen = [false; 3];
        for s in segs {
            let f = majority(s, &c.labels) as usize;
            assert!(!seen[f], "two segments on face {f}");
            seen[f] = true;
            let truth = &c.planes[f];
            let face_points = c.labels.iter().filter(|&&l| l as usize == f).count();
            assert!(
                s.indices.len() * 100 >= face_points * 97,
                "face {f}: {} of {face_points} points",
                s.indices.len()
            );
            let angle = line_angle(&s.fit.plane.normal, &truth.normal);
            let offset = truth.signed_distance(&s.fit.centroid).abs();
            if exact {
                assert!(angle <= 1e-9, "face {f}: angle {angle:e}");
                assert!(offset <= 1e-9, "face {f}: offset {offset:e}");
            } else {
                let n = s.fit.n_used as Real;
                assert!(angle <= 1e-3, "face {f}: angle {angle:e}");
                assert!(
                    offset <= 3.0 * 5.0 * SIGMA / n.sqrt(),
                    "face {f}: offset {offset:e}"
                );
            }
            assert!(s.indices.windows(2).all(|w| w[0] < w[1]), "sorted, unique");
            assert_eq!(s.fit.n_used + s.fit.n_rejected, s.indices.len());
            for &i in &s.indices {
                let (p, l) = (&c.points[i as usize], c.labels[i as usize] as usize);
                if l != f {
                    let d = truth.signed_distance(p).abs();
                    assert!(
                        d <= 2.0 * opts.max_distance_mm,
                        "point {i} of face {l} in face {f}'s segment, {d} mm from its plane"
                    );
                }
            }
        }
        for w in segs.windows(2) {
            assert!(w[0].indices.len() >= w[1].indices.len(), "largest first");
        }
    }

    #[test]
    fn step_experiment_gives_three_faces() {
        let c = step_cloud(SIGMA, &Isometry3::identity());
        let opts = step_opts();
        let segs = segment_planes(&c.points, &opts).expect("segments");
        check_step(&c, &segs, &opts, false);
        // The two parallel faces 1 mm apart never share a point.
        let a = segs
            .iter()
            .find(|s| majority(s, &c.labels) == 0)
            .expect("A");
        assert!(a.indices.iter().all(|&i| c.labels[i as usize] != 1));
        // Tilted and far from the origin: the same.
        let c = step_cloud(SIGMA, &tilted_pose());
        let segs = segment_planes(&c.points, &opts).expect("segments");
        check_step(&c, &segs, &opts, false);
    }

    #[test]
    fn exact_planes_are_fitted_to_1e9() {
        for pose in [Isometry3::identity(), tilted_pose()] {
            let c = step_cloud(0.0, &pose);
            let opts = step_opts();
            let segs = segment_planes(&c.points, &opts).expect("segments");
            check_step(&c, &segs, &opts, true);
            for s in &segs {
                // A corner point of another face may come along (within max_distance of
                // this plane); the robust fit rejects it.
                assert!(s.fit.rms_mm < 1e-12 && s.fit.n_rejected <= 4, "{:?}", s.fit);
            }
        }
    }

    #[test]
    fn segment_fits_equal_fit_plane_robust_of_their_points() {
        let c = step_cloud(SIGMA, &tilted_pose());
        let rules = [
            RobustRule::default(),
            RobustRule {
                k_sigma: 3.0,
                max_iterations: 0,
            },
            RobustRule {
                k_sigma: 2.0,
                max_iterations: 2,
            },
            RobustRule {
                k_sigma: 1.0,
                max_iterations: 10,
            },
        ];
        for robust in rules {
            let opts = PlaneSegmentOptions {
                robust,
                ..step_opts()
            };
            for s in segment_planes(&c.points, &opts).expect("segments") {
                let pts: Vec<Point3> = s.indices.iter().map(|&i| c.points[i as usize]).collect();
                let want = fit_plane_robust(&pts, &robust).expect("fit");
                let got = &s.fit;
                assert_eq!((got.n_used, got.n_rejected), (want.n_used, want.n_rejected));
                let pl = got.plane.oriented_towards(&want.plane.normal);
                assert!(line_angle(&pl.normal, &want.plane.normal) < 1e-12);
                assert!((pl.offset - want.plane.offset).abs() < 1e-10);
                assert!((got.rms_mm - want.rms_mm).abs() < 1e-12);
                assert!((got.offset_sigma_mm / want.offset_sigma_mm - 1.0).abs() < 1e-9);
            }
        }
    }

    fn in_pool<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool")
            .install(f)
    }

    fn fit_bits(f: &PlaneFit) -> Vec<u64> {
        let mut v = vec![
            f.plane.offset.to_bits(),
            f.rms_mm.to_bits(),
            f.max_abs_mm.to_bits(),
        ];
        v.extend(f.plane.normal.iter().map(|c| c.to_bits()));
        v.extend(f.centroid.iter().map(|c| c.to_bits()));
        v
    }

    #[test]
    fn bit_identical_for_one_and_two_threads() {
        let c = step_cloud(SIGMA, &tilted_pose());
        let opts = step_opts();
        let one = in_pool(1, || segment_planes(&c.points, &opts).expect("one"));
        let two = in_pool(2, || segment_planes(&c.points, &opts).expect("two"));
        assert_eq!(one, two);
        for (a, b) in one.iter().zip(&two) {
            assert_eq!(fit_bits(&a.fit), fit_bits(&b.fit));
        }
        let seed = c.points[c.points.len() / 2];
        let r1 = in_pool(1, || select_region_from_seed(&c.points, &seed, &opts));
        let r2 = in_pool(2, || select_region_from_seed(&c.points, &seed, &opts));
        assert_eq!(r1, r2);
        let sub = &c.points[..5000];
        let n1 = in_pool(1, || estimate_normals(sub, 12, None).expect("n1"));
        let n2 = in_pool(2, || estimate_normals(sub, 12, None).expect("n2"));
        assert_eq!(n1, n2);
        let ro = RansacOptions {
            distance_mm: 0.1,
            iterations: 50,
            seed: 9,
            min_inliers: 100,
        };
        let p1 = in_pool(1, || ransac_plane(&c.points, &ro));
        let p2 = in_pool(2, || ransac_plane(&c.points, &ro));
        assert_eq!(p1, p2);
    }

    #[test]
    fn seed_region_and_box() {
        let c = step_cloud(SIGMA, &Isometry3::identity());
        let opts = step_opts();
        // Near the middle of face B, a little off the surface.
        let seg = select_region_from_seed(&c.points, &Point3::new(20.0, 1.3, -5.0), &opts)
            .expect("region");
        assert_eq!(majority(&seg, &c.labels), 1);
        assert!(seg.indices.iter().all(|&i| c.labels[i as usize] != 0));
        let face_b = c.labels.iter().filter(|&&l| l == 1).count();
        assert!(seg.indices.len() * 100 >= face_b * 97);
        assert!(line_angle(&seg.fit.plane.normal, &Vector3::y()) < 1e-3);
        // Seed on the top face's edge cell still finds a planar neighbour.
        let top = select_region_from_seed(&c.points, &Point3::new(20.0, 0.0, 10.0), &opts)
            .expect("edge seed");
        assert!(matches!(majority(&top, &c.labels), 0 | 2));
        // A seed far away picks the nearest point's region.
        assert!(select_region_from_seed(&c.points, &Point3::new(1e6, 0.0, 0.0), &opts).is_ok());
        // Box: only points inside, in order.
        let (lo, hi) = (Point3::new(5.0, -1.0, 1.0), Point3::new(10.0, 0.5, 4.0));
        let sel = select_box(&c.points, &lo, &hi);
        let want: Vec<u32> = (0..c.points.len() as u32)
            .filter(|&i| {
                let p = c.points[i as usize];
                (0..3).all(|k| lo[k] <= p[k] && p[k] <= hi[k])
            })
            .collect();
        assert_eq!(sel, want);
        assert!(!sel.is_empty() && sel.iter().all(|&i| c.labels[i as usize] == 0));
        let mut with_nan = c.points.clone();
        with_nan[sel[0] as usize].x = Real::NAN;
        assert_eq!(select_box(&with_nan, &lo, &hi).len(), sel.len() - 1);
    }

    /// Points on the sphere |p − centre| = radius by the Fibonacci lattice (about `pitch`
    /// apart), those with (p − centre)·dir ≥ cos_cap · radius, with radial noise.
    fn sphere_points(centre: Point3, radius: Real, cos_cap: Real, noise: Real) -> Vec<Point3> {
        let rng = CounterRng::new(5);
        let area = 2.0 * std::f64::consts::TAU * radius * radius;
        let n = (area / (PITCH * PITCH)) as usize;
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        (0..n)
            .filter_map(|i| {
                let z = 1.0 - 2.0 * (i as Real + 0.5) / n as Real;
                let r = (1.0 - z * z).sqrt();
                let phi = golden * i as Real;
                let dir = Vector3::new(r * phi.cos(), r * phi.sin(), z);
                (z >= cos_cap).then(|| centre + dir * (radius + noise * rng.normal(i as u64)))
            })
            .collect()
    }

    #[test]
    fn normals_on_a_sphere_are_radial() {
        let centre = Point3::new(12.0, -7.0, 30.0);
        let pts = sphere_points(centre, 10.0, -1.0, SIGMA);
        let normals = estimate_normals(&pts, 100, None).expect("normals");
        let two_deg = 2f64.to_radians();
        for (p, n) in pts.iter().zip(&normals) {
            let a = line_angle(n, &(p - centre));
            assert!(a <= two_deg.sin(), "{} deg", a.asin().to_degrees());
            let k = n.iamax();
            assert!(n[k] > 0.0, "canonical sign");
        }
        // Towards a viewpoint far above: outward on the upper cap.
        let cap = sphere_points(centre, 10.0, 0.3, SIGMA);
        let eye = centre + Vector3::z() * 1000.0;
        let normals = estimate_normals(&cap, 30, Some(eye)).expect("normals");
        for (p, n) in cap.iter().zip(&normals) {
            assert!(n.dot(&(p - centre)) > 0.0);
        }
    }

    #[test]
    fn kd_index_matches_brute_force() {
        let rng = CounterRng::new(3);
        let pts: Vec<Point3> = (0..3000u64)
            .map(|i| {
                // Coarse coordinates: many equal distances.
                let c = |k| (rng.uniform(i, k) * 20.0).round() * 0.5;
                Point3::new(c(0), c(1), c(2))
            })
            .collect();
        let index = KdIndex::new(&pts).expect("index");
        assert_eq!(index.len(), pts.len());
        let brute = |q: &Point3| {
            let mut v: Vec<(Real, u32)> = pts
                .iter()
                .enumerate()
                .map(|(i, p)| ((p - q).norm(), i as u32))
                .collect();
            v.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            v
        };
        for i in 0..40u64 {
            let q = Point3::new(rng.uniform(i, 7) * 10.0, rng.uniform(i, 8) * 10.0, 5.0);
            let want = brute(&q);
            let got = index.nearest(&q, 10);
            assert_eq!(got.len(), 10);
            for (g, w) in got.iter().zip(&want) {
                assert!((g.distance_mm - w.0).abs() < 1e-12);
            }
            // The k-th distance is right; ties at it may pick any of the tied points.
            let r = 1.7;
            let within: Vec<u32> = index.within(&q, r).iter().map(|n| n.index).collect();
            let want_within: Vec<u32> = want.iter().filter(|w| w.0 <= r).map(|w| w.1).collect();
            assert_eq!(within, want_within);
        }
        assert!(
            index
                .nearest(&Point3::new(Real::NAN, 0.0, 0.0), 3)
                .is_empty()
        );
        assert!(index.nearest(&Point3::origin(), 0).is_empty());
        assert_eq!(index.nearest(&Point3::origin(), 5000).len(), pts.len());
        assert!(index.within(&Point3::origin(), -1.0).is_empty());
    }

    fn ransac_opts(seed: u64) -> RansacOptions {
        RansacOptions {
            distance_mm: 4.0 * SIGMA,
            iterations: 200,
            seed,
            min_inliers: 500,
        }
    }

    /// Fraction of `truth` (sorted) in `found` (sorted).
    fn recall(found: &[u32], truth: &[u32]) -> Real {
        let hit = truth
            .iter()
            .filter(|t| found.binary_search(t).is_ok())
            .count();
        hit as Real / truth.len() as Real
    }

    #[test]
    fn ransac_plane_with_30_percent_outliers() {
        let rng = CounterRng::new(11);
        let n = UnitVector3::new_normalize(Vector3::new(0.2, -0.3, 1.0));
        let (a, b) = basis_perpendicular(&n);
        let centre = Point3::new(40.0, 25.0, -12.0);
        let mut pts = Vec::new();
        let mut truth = Vec::new();
        for i in 0..10_000u64 {
            if rng.uniform(i, 0) < 0.3 {
                let q = Vector3::new(rng.uniform(i, 1), rng.uniform(i, 2), rng.uniform(i, 3));
                pts.push(centre + (q - Vector3::repeat(0.5)) * 40.0);
            } else {
                let (s, t) = (rng.uniform(i, 1) - 0.5, rng.uniform(i, 2) - 0.5);
                truth.push(pts.len() as u32);
                pts.push(centre + a * (40.0 * s) + b * (40.0 * t) + *n * (SIGMA * rng.normal(i)));
            }
        }
        for seed in [1, 2, 3] {
            let found = ransac_plane(&pts, &ransac_opts(seed)).expect("plane");
            assert!(
                recall(&found, &truth) >= 0.95,
                "seed {seed}: {}",
                recall(&found, &truth)
            );
            // Outliers inside the ±0.1 mm slab are few (0.5 % of 3,000).
            assert!(
                found.len() <= truth.len() + 60,
                "seed {seed}: {}",
                found.len()
            );
            assert_eq!(
                found,
                ransac_plane(&pts, &ransac_opts(seed)).expect("again")
            );
        }
        let none = RansacOptions {
            min_inliers: 9000,
            ..ransac_opts(1)
        };
        assert_eq!(ransac_plane(&pts, &none), Err(SegmentError::NothingFound));
    }

    #[test]
    fn ransac_sphere_finds_the_ball() {
        let centre = Point3::new(30.0, -20.0, 15.0);
        let mut pts = sphere_points(centre, 12.5, 0.2, SIGMA);
        let n_true = pts.len();
        let rng = CounterRng::new(23);
        for i in 0..(n_true / 4) as u64 {
            let q = Vector3::new(rng.uniform(i, 0), rng.uniform(i, 1), rng.uniform(i, 2));
            pts.push(centre + (q - Vector3::repeat(0.5)) * 30.0);
        }
        let truth: Vec<u32> = (0..n_true as u32).collect();
        for seed in [4, 5] {
            let m = ransac_sphere(&pts, &ransac_opts(seed)).expect("sphere");
            assert!(
                recall(&m.inliers, &truth) >= 0.95,
                "recall {}",
                recall(&m.inliers, &truth)
            );
            assert!(
                (m.model.radius - 12.5).abs() < 0.01,
                "radius {}",
                m.model.radius
            );
            assert!((m.model.centre - centre).norm() < 0.01);
            assert_eq!(Ok(m), ransac_sphere(&pts, &ransac_opts(seed)));
        }
    }

    #[test]
    fn ransac_cylinder_with_estimated_normals() {
        let axis = UnitVector3::new_normalize(Vector3::new(1.0, 0.2, 0.1));
        let (u, w) = basis_perpendicular(&axis);
        let base = Point3::new(10.0, 5.0, -3.0);
        let (radius, length, pitch) = (8.0, 30.0, 0.25);
        let rng = CounterRng::new(31);
        let mut pts = Vec::new();
        // The half facing +w, as a scanner sees it.
        let arc = std::f64::consts::PI * radius;
        for j in 0..(length / pitch) as usize {
            for i in 0..(arc / pitch) as usize {
                let phi = (i as Real + 0.5) * pitch / radius;
                let k = pts.len() as u64;
                let r = radius + SIGMA * rng.normal(k);
                let along = (j as Real + 0.5) * pitch;
                pts.push(base + *axis * along + (u * phi.cos() + w * phi.sin()) * r);
            }
        }
        let n_true = pts.len();
        for i in 0..(n_true / 5) as u64 {
            let q = Vector3::new(rng.uniform(i, 1), rng.uniform(i, 2), rng.uniform(i, 3));
            pts.push(base + *axis * (q.x * length) + (u * (q.y - 0.5) + w * q.z) * 20.0);
        }
        let eye = base + *axis * (0.5 * length) + w * 300.0;
        let normals = estimate_normals(&pts, 30, Some(eye)).expect("normals");
        let truth: Vec<u32> = (0..n_true as u32).collect();
        for seed in [6, 7] {
            let m = ransac_cylinder(&pts, &normals, &ransac_opts(seed)).expect("cylinder");
            assert!(
                recall(&m.inliers, &truth) >= 0.95,
                "recall {}",
                recall(&m.inliers, &truth)
            );
            assert!(
                (m.model.radius - radius).abs() < 0.02,
                "radius {}",
                m.model.radius
            );
            assert!(line_angle(&m.model.axis, &axis) < 2e-3);
            let off = m.model.point - base;
            assert!((off - *axis * axis.dot(&off)).norm() < 0.02);
            assert_eq!(Ok(m), ransac_cylinder(&pts, &normals, &ransac_opts(seed)));
        }
        assert!(matches!(
            ransac_cylinder(&pts, &normals[1..], &ransac_opts(6)),
            Err(SegmentError::BadOptions(_))
        ));
    }

    #[test]
    fn errors() {
        let c = step_cloud(SIGMA, &Isometry3::identity());
        let opts = step_opts();
        assert_eq!(segment_planes(&[], &opts), Err(SegmentError::NoPoints));
        let mut bad = c.points.clone();
        bad[7000].y = Real::NAN;
        bad[9000].z = Real::INFINITY;
        assert_eq!(
            segment_planes(&bad, &opts),
            Err(SegmentError::NonFinite { index: 7000 })
        );
        bad[100].x = 2e9;
        assert_eq!(
            estimate_normals(&bad, 8, None),
            Err(SegmentError::NonFinite { index: 100 })
        );
        assert_eq!(
            ransac_plane(&bad, &ransac_opts(1)),
            Err(SegmentError::NonFinite { index: 100 })
        );
        assert!(matches!(
            KdIndex::new(&bad),
            Err(SegmentError::NonFinite { index: 100 })
        ));
        for o in [
            PlaneSegmentOptions {
                cell_mm: 0.0,
                ..opts
            },
            PlaneSegmentOptions {
                cell_mm: Real::NAN,
                ..opts
            },
            PlaneSegmentOptions {
                max_angle_rad: 0.0,
                ..opts
            },
            PlaneSegmentOptions {
                max_angle_rad: 2.0,
                ..opts
            },
            PlaneSegmentOptions {
                max_distance_mm: -1.0,
                ..opts
            },
            PlaneSegmentOptions {
                robust: RobustRule {
                    k_sigma: Real::NAN,
                    max_iterations: 3,
                },
                ..opts
            },
        ] {
            assert!(matches!(
                segment_planes(&c.points, &o),
                Err(SegmentError::BadOptions(_))
            ));
        }
        let fine = PlaneSegmentOptions {
            cell_mm: 1e-4,
            ..opts
        };
        match segment_planes(&c.points, &fine) {
            Err(SegmentError::BadOptions(m)) => {
                assert!(m.contains("use a cell of at least"), "{m}")
            }
            other => panic!("{other:?}"),
        }
        let far = [
            Point3::origin(),
            Point3::new(1e9, -1e9, 1e9),
            Point3::new(1.0, 2.0, 3.0),
        ];
        assert!(matches!(
            segment_planes(&far, &opts),
            Err(SegmentError::BadOptions(_))
        ));
        let tiny = PlaneSegmentOptions {
            cell_mm: 1e-300,
            ..opts
        };
        assert!(matches!(
            segment_planes(&far, &tiny),
            Err(SegmentError::BadOptions(_))
        ));
        // Nothing planar: a line, or too few points.
        let line: Vec<Point3> = (0..5000)
            .map(|i| Point3::new(i as Real * 0.01, 0.0, 0.0))
            .collect();
        assert_eq!(
            segment_planes(&line, &opts),
            Err(SegmentError::NothingFound)
        );
        let big = PlaneSegmentOptions {
            min_points: 20_000,
            ..opts
        };
        assert_eq!(
            segment_planes(&c.points, &big),
            Err(SegmentError::NothingFound)
        );
        assert!(matches!(
            select_region_from_seed(&c.points, &Point3::new(Real::NAN, 0.0, 0.0), &opts),
            Err(SegmentError::BadOptions(_))
        ));
        assert!(matches!(
            estimate_normals(&c.points, 2, None),
            Err(SegmentError::BadOptions(_))
        ));
        assert_eq!(
            estimate_normals(&c.points[..2], 5, None),
            Err(SegmentError::NothingFound)
        );
        assert!(matches!(
            ransac_plane(
                &c.points,
                &RansacOptions {
                    iterations: 0,
                    ..ransac_opts(1)
                }
            ),
            Err(SegmentError::BadOptions(_))
        ));
        assert!(matches!(
            ransac_sphere(
                &c.points,
                &RansacOptions {
                    distance_mm: 0.0,
                    ..ransac_opts(1)
                }
            ),
            Err(SegmentError::BadOptions(_))
        ));
        assert_eq!(
            ransac_sphere(&c.points[..3], &ransac_opts(1)),
            Err(SegmentError::NothingFound)
        );
    }

    /// Small awkward point sets: duplicates, collinear and coplanar runs, NaN, ±∞, huge.
    fn awkward_points() -> impl Strategy<Value = Vec<Point3>> {
        let coord = prop_oneof![
            8 => (-3i32..4).prop_map(|v| v as Real * 0.5),
            1 => Just(Real::NAN),
            1 => Just(Real::INFINITY),
            1 => Just(1e12),
            1 => -1e3..1e3f64,
        ];
        let point =
            (coord.clone(), coord.clone(), coord).prop_map(|(x, y, z)| Point3::new(x, y, z));
        prop_oneof![
            proptest::collection::vec(point.clone(), 0..60),
            // Mostly finite, with long duplicate and collinear runs.
            (proptest::collection::vec(point, 1..8), 1usize..40).prop_map(|(base, reps)| {
                let mut v = Vec::new();
                for (k, p) in base.iter().enumerate() {
                    for r in 0..reps {
                        let shift = if k % 2 == 0 { 0.0 } else { r as Real * 0.1 };
                        v.push(Point3::new(p.x + shift, p.y, p.z));
                    }
                }
                v
            }),
        ]
    }

    fn check_indices(idx: &[u32], n: usize) {
        assert!(idx.windows(2).all(|w| w[0] < w[1]));
        assert!(idx.iter().all(|&i| (i as usize) < n));
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(1024))]

        #[test]
        fn awkward_inputs_never_panic(
            pts in awkward_points(),
            cell in prop_oneof![Just(0.3), Just(1.0), Just(7.0), Just(1e-7), Just(-1.0), Just(Real::NAN)],
            min_points in 0usize..12,
            k in 0usize..12,
            iterations in 0usize..30,
            seed in any::<u64>(),
        ) {
            let opts = PlaneSegmentOptions {
                cell_mm: cell,
                max_angle_rad: 0.3,
                max_distance_mm: 0.2,
                min_points,
                robust: RobustRule::default(),
            };
            if let Ok(segs) = segment_planes(&pts, &opts) {
                let mut all: Vec<u32> = Vec::new();
                for s in &segs {
                    check_indices(&s.indices, pts.len());
                    prop_assert_eq!(s.fit.n_used + s.fit.n_rejected, s.indices.len());
                    all.extend(&s.indices);
                }
                all.sort_unstable();
                prop_assert!(all.windows(2).all(|w| w[0] < w[1]), "disjoint");
            }
            let seed_point = pts.first().copied().unwrap_or_else(Point3::origin);
            if let Ok(s) = select_region_from_seed(&pts, &seed_point, &opts) {
                check_indices(&s.indices, pts.len());
            }
            if let Ok(n) = estimate_normals(&pts, k, Some(Point3::new(0.0, 0.0, 50.0))) {
                prop_assert_eq!(n.len(), pts.len());
                prop_assert!(n.iter().all(|v| (v.norm() - 1.0).abs() < 1e-9));
            }
            let ro = RansacOptions { distance_mm: 0.2, iterations, seed, min_inliers: min_points };
            if let Ok(i) = ransac_plane(&pts, &ro) {
                check_indices(&i, pts.len());
            }
            if let Ok(m) = ransac_sphere(&pts, &ro) {
                check_indices(&m.inliers, pts.len());
            }
            let normals = vec![UnitVector3::new_normalize(Vector3::new(0.3, 0.4, 1.0)); pts.len()];
            if let Ok(m) = ransac_cylinder(&pts, &normals, &ro) {
                check_indices(&m.inliers, pts.len());
            }
            if let Ok(index) = KdIndex::new(&pts) {
                let q = pts[pts.len() / 2];
                prop_assert!(index.nearest(&q, k).len() <= k);
                let _ = index.within(&q, cell.abs());
            }
            check_indices(&select_box(&pts, &Point3::new(-1.0, -1.0, -1.0), &Point3::new(1.0, 1.0, 1.0)), pts.len());
        }
    }

    /// Up to three random rectangular patches of random planes, with noise and outliers.
    fn random_planes(seed: u64, n_planes: usize, per_plane: usize, noise: Real) -> Vec<Point3> {
        let rng = CounterRng::new(seed);
        let mut pts = Vec::new();
        for k in 0..n_planes as u64 {
            let n = UnitVector3::new_normalize(Vector3::new(
                rng.normal(100 + 3 * k),
                rng.normal(101 + 3 * k),
                rng.normal(102 + 3 * k),
            ));
            let (a, b) = basis_perpendicular(&n);
            let centre = Point3::new(
                60.0 * rng.uniform(200 + k, 0),
                60.0 * rng.uniform(200 + k, 1),
                60.0 * rng.uniform(200 + k, 2),
            );
            let size = 5.0 + 25.0 * rng.uniform(300 + k, 0);
            for i in 0..per_plane as u64 {
                let j = 1000 * (k + 1) + i;
                let (s, u) = (rng.uniform(j, 0) - 0.5, rng.uniform(j, 1) - 0.5);
                let q = centre + a * (size * s) + b * (size * u) + *n * (noise * rng.normal(j));
                pts.push(q);
                if rng.uniform(j, 2) < 0.02 {
                    pts.push(q + *n * (0.5 + rng.uniform(j, 3)));
                }
            }
        }
        pts
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(48))]

        #[test]
        fn random_planes_segment_consistently(
            seed in any::<u64>(),
            n_planes in 1usize..4,
            per_plane in 200usize..3000,
            noise in prop_oneof![Just(0.0), 0.001..0.05f64],
            cell in 0.5..3.0f64,
            k_sigma in 1.5..4.0f64,
            max_iterations in 0usize..12,
        ) {
            let pts = random_planes(seed, n_planes, per_plane, noise);
            let robust = RobustRule { k_sigma, max_iterations };
            let opts = PlaneSegmentOptions {
                cell_mm: cell,
                max_angle_rad: 0.2,
                max_distance_mm: (4.0 * noise).max(0.01),
                min_points: 50,
                robust,
            };
            if let Ok(segs) = segment_planes(&pts, &opts) {
                let mut all: Vec<u32> = Vec::new();
                for s in &segs {
                    check_indices(&s.indices, pts.len());
                    all.extend(&s.indices);
                    let own: Vec<Point3> = s.indices.iter().map(|&i| pts[i as usize]).collect();
                    let want = fit_plane_robust(&own, &robust).expect("fit");
                    prop_assert_eq!((s.fit.n_used, s.fit.n_rejected), (want.n_used, want.n_rejected));
                    let pl = s.fit.plane.oriented_towards(&want.plane.normal);
                    prop_assert!(line_angle(&pl.normal, &want.plane.normal) < 1e-10);
                    prop_assert!((pl.offset - want.plane.offset).abs() < 1e-9);
                }
                all.sort_unstable();
                prop_assert!(all.windows(2).all(|w| w[0] < w[1]), "disjoint");
                for w in segs.windows(2) {
                    prop_assert!(w[0].indices.len() >= w[1].indices.len());
                }
            }
        }
    }

    #[test]
    fn eigen_fast_path_agrees_with_nalgebra() {
        let rng = CounterRng::new(41);
        for i in 0..2000u64 {
            // Random symmetric PSD matrices of every conditioning.
            let a = Matrix3::from_fn(|r, c| rng.normal(i * 9 + (3 * r + c) as u64));
            let scale = Vector3::new(
                1.0,
                10f64.powf(-6.0 * rng.uniform(i, 1)),
                10f64.powf(-12.0 * rng.uniform(i, 2)),
            );
            let m = a * Matrix3::from_diagonal(&scale) * a.transpose();
            let six = [
                m[(0, 0)],
                m[(0, 1)],
                m[(0, 2)],
                m[(1, 1)],
                m[(1, 2)],
                m[(2, 2)],
            ];
            let (l, v) = eigen_sym3(&six).expect("finite");
            let eig = nalgebra::SymmetricEigen::new(m);
            let mut want = [eig.eigenvalues[0], eig.eigenvalues[1], eig.eigenvalues[2]];
            want.sort_by(Real::total_cmp);
            let top = want[2].abs();
            // The closed form keeps about √ε of λ₂ for two eigenvalues that nearly
            // coincide against λ₂ (needles, not planes).
            for k in 0..3 {
                assert!(
                    (l[k] - want[k]).abs() <= 1e-9 * top,
                    "{i}: {l:?} vs {want:?}"
                );
            }
            assert!((v.norm() - 1.0).abs() < 1e-12);
            // Residual of the eigenvector, relative to the spread it is resolved against.
            let res = (m * v - v * l[0]).norm();
            assert!(res <= 1e-10 * top, "{i}: residual {res:e}");
        }
        assert_eq!(eigen_sym3(&[0.0; 6]), Some(([0.0; 3], Vector3::z())));
        assert_eq!(eigen_sym3(&[Real::NAN, 0.0, 0.0, 1.0, 0.0, 1.0]), None);
    }
}
