//! RANSAC for one plane, sphere or cylinder in a (sub)set of points: minimal samples drawn
//! from a [`CounterRng`] keyed by (seed, iteration), scored by inlier count (ties to the
//! earliest iteration), then rounds of least-squares refit on the inliers and re-selection.

use super::input::{PLANE_FIT_MIN, SegmentError, check_and_bound, chunked_fold, gather};
use super::linalg::{add_outer, basis_perpendicular, eigen_sym3};
use crate::math::{Aabb, CounterRng, Matrix3, Point3, Real, UnitVector3, Vector3};
use crate::metrology::fit::{Plane, fit_plane};
use rayon::prelude::*;

#[cfg(doc)]
use super::neighbours::estimate_normals;

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

/// Rounds of least-squares refit and re-selection after RANSAC: each round re-selects by
/// distance to the refitted model; it stops earlier when the inliers no longer change
/// (usually after one or two rounds).
const REFINE_ROUNDS: usize = 5;

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
    use super::super::estimate_normals;
    use super::super::tests::{SIGMA, line_angle, ransac_opts, sphere_points};
    use super::*;

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
}
