//! Planes ([`Plane`]: distance, projection, intersection with a line, orientation), the
//! orthogonal least-squares plane fit, plain and robust ([`fit_plane`],
//! [`fit_plane_robust`]), and the distance and angle of two planes
//! ([`plane_distance_and_angle`]).

use super::error::{FitError, check_input};
use super::moments::{
    DEGENERATE_RATIO, EIGEN_ITERATIONS, canonical_sign, centred_moments, chunked_sum,
};
use super::robust::{RobustRule, Trimmable, trim_and_refit};
use crate::math::{Point3, Real, UnitVector3, Vector3};
use nalgebra::SymmetricEigen;

/// A plane {x : normal · x = offset}.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Plane {
    /// Unit normal.
    pub normal: UnitVector3,
    /// Signed distance of the plane from the origin along `normal` (mm).
    pub offset: Real,
}

impl Plane {
    /// The plane through `point` with the given `normal`.
    pub fn through(point: &Point3, normal: UnitVector3) -> Plane {
        Plane {
            normal,
            offset: normal.dot(&point.coords),
        }
    }

    /// Signed distance of `p` from the plane (mm), positive on the side `normal` points to.
    pub fn signed_distance(&self, p: &Point3) -> Real {
        self.normal.dot(&p.coords) - self.offset
    }

    /// Orthogonal projection of `p` onto the plane.
    pub fn project(&self, p: &Point3) -> Point3 {
        p - self.normal.into_inner() * self.signed_distance(p)
    }

    /// Intersection of the line p + t·dir with the plane (None if parallel within 1e-12 relative).
    ///
    /// "Parallel" means |normal · dir| ≤ 1e-12 · |dir|; a non-finite result is also `None`.
    pub fn intersect_line(&self, p: &Point3, dir: &Vector3) -> Option<Point3> {
        let denom = self.normal.dot(dir);
        if denom.abs() <= 1e-12 * dir.norm() || !denom.is_finite() {
            return None;
        }
        let t = -self.signed_distance(p) / denom;
        let x = p + dir * t;
        x.coords.iter().all(|c| c.is_finite()).then_some(x)
    }

    /// The same plane with normal flipped if needed so that normal·towards >= 0.
    pub fn oriented_towards(&self, towards: &Vector3) -> Plane {
        if self.normal.dot(towards) < 0.0 {
            Plane {
                normal: -self.normal,
                offset: -self.offset,
            }
        } else {
            *self
        }
    }
}

/// Result of a plane fit.
#[derive(Clone, Debug, PartialEq)]
pub struct PlaneFit {
    /// The fitted plane. Its normal is oriented so that its largest-magnitude component is
    /// positive (ties: the first such component of x, y, z); re-orient with
    /// [`Plane::oriented_towards`].
    pub plane: Plane,
    /// Centroid of the points used (lies on the plane).
    pub centroid: Point3,
    /// Number of points in the final fit.
    pub n_used: usize,
    /// Number of input points rejected as outliers (0 for [`fit_plane`]).
    pub n_rejected: usize,
    /// Root-mean-square perpendicular residual of the used points (mm), divided by `n`.
    pub rms_mm: Real,
    /// Largest absolute perpendicular residual of the used points (mm).
    pub max_abs_mm: Real,
    /// Standard uncertainty of the offset at the centroid (mm): σ/√n with
    /// σ = √(Σr²/(n−3)) (three fitted parameters). Infinite when n = 3.
    pub offset_sigma_mm: Real,
    /// Standard uncertainty of the normal's tilt (rad) towards each of the two in-plane
    /// principal axes: σ/√(Σ(aₖ·(pᵢ−c))²), i.e. σ over the root of the k-th in-plane
    /// eigenvalue of the second-moment sum. Index 0 is the major axis (largest spread:
    /// tilt in the direction of the major axis, a rotation about the minor axis), index 1
    /// the minor axis. Infinite when n = 3.
    pub tilt_sigma_rad: [Real; 2],
}

/// Minimum points for a plane: three non-collinear points span it.
const PLANE_MIN_POINTS: usize = 3;

/// Orthogonal least-squares plane: minimises the sum of squared perpendicular distances (smallest eigenvector of the centred covariance).
///
/// The normal is oriented so that its largest-magnitude component is positive (the
/// first of x, y, z on a tie); callers choose a side with [`Plane::oriented_towards`].
/// Needs at least 3 finite points that are not collinear. Deterministic and bit-identical
/// for any rayon thread count.
pub fn fit_plane(points: &[Point3]) -> Result<PlaneFit, FitError> {
    check_input(points, PLANE_MIN_POINTS)?;
    fit_checked(points)
}

/// The fit proper; `points` has at least 3 entries, all finite.
pub(super) fn fit_checked(points: &[Point3]) -> Result<PlaneFit, FitError> {
    let n = points.len();
    let nr = n as Real;
    let (centroid, cov) = centred_moments(points)?;
    if !cov.iter().all(|v| v.is_finite()) {
        return Err(FitError::Degenerate);
    }
    let eig = SymmetricEigen::try_new(cov, Real::EPSILON, EIGEN_ITERATIONS)
        .ok_or(FitError::Degenerate)?;
    let mut order = [0usize, 1, 2];
    order.sort_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]));
    let [i_min, i_mid, i_max] = order;
    let (l_mid, l_max) = (eig.eigenvalues[i_mid], eig.eigenvalues[i_max]);
    let spans_plane = l_max > 0.0 && l_mid > DEGENERATE_RATIO * l_max;
    if !spans_plane {
        return Err(FitError::Degenerate);
    }
    let normal = canonical_sign(eig.eigenvectors.column(i_min).into_owned());
    let normal = UnitVector3::try_new(normal, 0.0).ok_or(FitError::Degenerate)?;
    let plane = Plane::through(&centroid, normal);

    // Pass 3: residuals.
    let (ss, max_abs) = chunked_sum(
        points,
        |c| {
            c.iter().fold((0.0, 0.0), |(s, m): (Real, Real), p| {
                let r = normal.dot(&(p - centroid));
                (s + r * r, m.max(r.abs()))
            })
        },
        (0.0, 0.0),
        |(s, m), (ps, pm)| (s + ps, m.max(*pm)),
    );
    let rms_mm = (ss / nr).sqrt();
    let (offset_sigma_mm, tilt_sigma_rad) = if n > 3 {
        let sigma = (ss / (n - 3) as Real).sqrt();
        (
            sigma / nr.sqrt(),
            [sigma / l_max.sqrt(), sigma / l_mid.sqrt()],
        )
    } else {
        (Real::INFINITY, [Real::INFINITY; 2])
    };
    Ok(PlaneFit {
        plane,
        centroid,
        n_used: n,
        n_rejected: 0,
        rms_mm,
        max_abs_mm: max_abs,
        offset_sigma_mm,
        tilt_sigma_rad,
    })
}

/// Plane fit with iterative outlier rejection (see [`RobustRule`]).
///
/// Errors as [`fit_plane`] on the full set; once an initial fit exists it never fails.
/// `n_used + n_rejected == points.len()`.
pub fn fit_plane_robust(points: &[Point3], rule: &RobustRule) -> Result<PlaneFit, FitError> {
    let fit = fit_plane(points)?;
    Ok(trim_and_refit(points, rule, fit, |subset, _| {
        fit_checked(subset)
    }))
}

impl Trimmable for PlaneFit {
    const MIN_POINTS: usize = PLANE_MIN_POINTS;
    fn rms(&self) -> Real {
        self.rms_mm
    }
    fn distance(&self, p: &Point3) -> Real {
        self.plane.normal.dot(&(p - self.centroid)).abs()
    }
    fn n_used(&self) -> usize {
        self.n_used
    }
    fn set_rejected(&mut self, n: usize) {
        self.n_rejected = n;
    }
}

/// Distance between two planes "the way seed 002 reports it": signed distance from plane `a` to plane `b` measured along a's normal through `at` (the intersection points of the line at + t·n_a with both planes), and the angle between the normals (rad, 0..π/2 after orienting b like a).
///
/// The distance is (x_b − x_a)·n_a with x_a, x_b the intersections of the line with `a`
/// and `b` ([`Plane::intersect_line`]): positive when `b` lies on the side of `a` its
/// normal points to. `None` if the line is parallel to `b` (the planes are perpendicular
/// within 1e-12) or anything is non-finite.
pub fn plane_distance_and_angle(a: &Plane, b: &Plane, at: &Point3) -> Option<(Real, Real)> {
    let n = a.normal.into_inner();
    let xa = a.intersect_line(at, &n)?;
    let xb = b.intersect_line(at, &n)?;
    let distance = (xb - xa).dot(&n);
    let nb = b.oriented_towards(&n).normal;
    let angle = n.cross(&nb).norm().atan2(n.dot(&nb));
    (distance.is_finite() && angle.is_finite()).then_some((distance, angle))
}

#[cfg(test)]
mod tests {
    use super::super::tests::{axes, std_dev, unit};
    use super::*;
    use crate::math::CounterRng;

    /// A plane pose: normal, offset, in-plane axes, patch centre.
    struct Pose {
        n: UnitVector3,
        offset: Real,
        a: Vector3,
        b: Vector3,
        centre: Point3,
    }

    fn pose(seed: u64) -> Pose {
        let rng = CounterRng::new(seed);
        let n = unit(&rng, 0);
        let offset = 300.0 * (2.0 * rng.uniform(10, 0) - 1.0);
        let (a, b) = axes(&n, std::f64::consts::TAU * rng.uniform(11, 0));
        let ca = 150.0 * (2.0 * rng.uniform(12, 0) - 1.0);
        let cb = 150.0 * (2.0 * rng.uniform(13, 0) - 1.0);
        let centre = Point3::from(n.into_inner() * offset + a * ca + b * cb);
        Pose {
            n,
            offset,
            a,
            b,
            centre,
        }
    }

    /// `count` points on a 40 × 20 mm patch of the pose's plane, with Gaussian noise of
    /// `noise` mm along the normal from `noise_seed`.
    fn patch(p: &Pose, count: usize, noise: Real, noise_seed: u64) -> Vec<Point3> {
        let pos = CounterRng::new(99);
        let nz = CounterRng::new(noise_seed);
        (0..count as u64)
            .map(|i| {
                let s = 40.0 * (pos.uniform(i, 0) - 0.5);
                let t = 20.0 * (pos.uniform(i, 1) - 0.5);
                p.centre + p.a * s + p.b * t + p.n.into_inner() * (noise * nz.normal(i))
            })
            .collect()
    }

    #[test]
    fn exact_planes_in_random_poses() {
        for seed in 0..24u64 {
            let p = pose(seed);
            let count = 1000 + (seed as usize * 2131) % 49_001;
            let pts = patch(&p, count, 0.0, 0);
            let fit = fit_plane(&pts).expect("fit");
            let pl = fit.plane.oriented_towards(&p.n);
            let angle = pl.normal.cross(&p.n).norm();
            assert!(angle <= 1e-12, "seed {seed}: angle {angle:e}");
            let doff = (pl.offset - p.offset).abs();
            assert!(doff <= 1e-10, "seed {seed}: offset error {doff:e}");
            assert!(fit.rms_mm < 1e-12 && fit.max_abs_mm < 1e-11);
            assert_eq!((fit.n_used, fit.n_rejected), (count, 0));
            // Deterministic orientation rule.
            let k = fit.plane.normal.iamax();
            assert!(fit.plane.normal[k] > 0.0);
        }
    }

    #[test]
    fn uncertainties_match_monte_carlo() {
        let p = pose(7);
        let (trials, count, noise) = (200u64, 2000, 0.025);
        let (mut off, mut ta, mut tb) = (vec![], vec![], vec![]);
        let (mut s_off, mut s_ta, mut s_tb) = (0.0, 0.0, 0.0);
        for t in 0..trials {
            let pts = patch(&p, count, noise, 1000 + t);
            let fit = fit_plane(&pts).expect("fit");
            let pl = fit.plane.oriented_towards(&p.n);
            off.push(p.n.dot(&fit.centroid.coords) - p.offset);
            ta.push(pl.normal.dot(&p.a));
            tb.push(pl.normal.dot(&p.b));
            s_off += fit.offset_sigma_mm / trials as Real;
            s_ta += fit.tilt_sigma_rad[0] / trials as Real;
            s_tb += fit.tilt_sigma_rad[1] / trials as Real;
        }
        for (name, obs, pred) in [
            ("offset", std_dev(&off), s_off),
            ("tilt major", std_dev(&ta), s_ta),
            ("tilt minor", std_dev(&tb), s_tb),
        ] {
            let ratio = obs / pred;
            assert!(
                (0.8..=1.2).contains(&ratio),
                "{name}: observed {obs:e} predicted {pred:e}"
            );
        }
    }

    #[test]
    fn robust_fit_rejects_gross_outliers() {
        let p = pose(3);
        let count = 20_000;
        let clean = patch(&p, count, 0.025, 5);
        let rng = CounterRng::new(77);
        let mut dirty = clean.clone();
        let mut n_out = 0;
        for (i, q) in dirty.iter_mut().enumerate() {
            if rng.uniform(i as u64, 0) < 0.05 {
                let sign = if rng.uniform(i as u64, 1) < 0.5 {
                    -1.0
                } else {
                    1.0
                };
                *q += p.n.into_inner() * sign;
                n_out += 1;
            }
        }
        let clean_fit = fit_plane(&clean).expect("clean");
        let plain = fit_plane(&dirty).expect("plain");
        let robust = fit_plane_robust(&dirty, &RobustRule::default()).expect("robust");
        assert!(robust.n_rejected >= n_out && robust.n_rejected < n_out + count / 100);
        assert_eq!(robust.n_used + robust.n_rejected, count);
        let pl = robust.plane.oriented_towards(&p.n);
        let e_off = (p.n.dot(&robust.centroid.coords) - p.offset).abs();
        let e_a = pl.normal.dot(&p.a).abs();
        let e_b = pl.normal.dot(&p.b).abs();
        assert!(e_off <= 3.0 * clean_fit.offset_sigma_mm, "offset {e_off:e}");
        assert!(e_a <= 3.0 * clean_fit.tilt_sigma_rad[0], "tilt a {e_a:e}");
        assert!(e_b <= 3.0 * clean_fit.tilt_sigma_rad[1], "tilt b {e_b:e}");
        assert!(robust.rms_mm < 0.03 && plain.rms_mm > 0.15);
        // Clean exact data lose nothing.
        let exact = patch(&p, 500, 0.0, 0);
        let f = fit_plane_robust(&exact, &RobustRule::default()).expect("exact");
        assert_eq!(f.n_rejected, 0);
    }

    #[test]
    fn error_cases() {
        let dir = Vector3::new(0.3, -0.7, 0.2);
        let line: Vec<Point3> = (0..100)
            .map(|i| Point3::new(120.0, 40.0, -80.0) + dir * (i as Real * 0.37))
            .collect();
        assert_eq!(fit_plane(&line), Err(FitError::Degenerate));
        assert_eq!(
            fit_plane(&[Point3::new(1.0, 2.0, 3.0); 10]),
            Err(FitError::Degenerate)
        );
        let mut pts = patch(&pose(1), 10, 0.0, 0);
        pts[4].y = Real::NAN;
        assert_eq!(fit_plane(&pts), Err(FitError::NonFinite { index: 4 }));
        assert_eq!(
            fit_plane_robust(&pts, &RobustRule::default()),
            Err(FitError::NonFinite { index: 4 })
        );
        assert_eq!(
            fit_plane(&pts[..2]),
            Err(FitError::TooFewPoints { needed: 3, got: 2 })
        );
        assert_eq!(
            fit_plane(&[]),
            Err(FitError::TooFewPoints { needed: 3, got: 0 })
        );
        let huge = [
            Point3::new(1e300, 0.0, 0.0),
            Point3::new(-1e300, 1e300, 0.0),
            Point3::new(0.0, -1e300, 0.0),
        ];
        assert_eq!(fit_plane(&huge), Err(FitError::Degenerate));
        let three = fit_plane(&pts[5..8]).expect("three points");
        assert!(three.offset_sigma_mm.is_infinite());
    }

    #[test]
    fn bit_identical_across_thread_counts() {
        let pts = patch(&pose(11), 100_000, 0.025, 8);
        let run = |threads: usize| {
            crate::math::in_pool(threads, || {
                (
                    fit_plane(&pts).expect("fit"),
                    fit_plane_robust(&pts, &RobustRule::default()).expect("robust"),
                )
            })
        };
        let one = run(1);
        for threads in [2, 3, 8] {
            let other = run(threads);
            assert_eq!(one, other, "{threads} threads");
            let bits = |f: &PlaneFit| {
                [
                    f.plane.normal.x.to_bits(),
                    f.plane.normal.y.to_bits(),
                    f.plane.normal.z.to_bits(),
                    f.plane.offset.to_bits(),
                    f.rms_mm.to_bits(),
                    f.offset_sigma_mm.to_bits(),
                ]
            };
            assert_eq!(bits(&one.0), bits(&other.0));
            assert_eq!(bits(&one.1), bits(&other.1));
        }
    }

    #[test]
    fn plane_geometry() {
        let n = UnitVector3::new_normalize(Vector3::new(0.0, 0.0, 2.0));
        let pl = Plane::through(&Point3::new(5.0, 6.0, 10.0), n);
        assert_eq!(pl.offset, 10.0);
        assert_eq!(pl.signed_distance(&Point3::new(1.0, 2.0, 12.5)), 2.5);
        assert_eq!(
            pl.project(&Point3::new(1.0, 2.0, 12.5)),
            Point3::new(1.0, 2.0, 10.0)
        );
        let x = pl
            .intersect_line(&Point3::new(1.0, 1.0, 0.0), &Vector3::new(1.0, 0.0, 2.0))
            .expect("hit");
        assert_eq!(x, Point3::new(6.0, 1.0, 10.0));
        assert!(
            pl.intersect_line(&Point3::origin(), &Vector3::new(1.0, 1.0, 1e-13))
                .is_none()
        );
        assert!(
            pl.intersect_line(&Point3::origin(), &Vector3::zeros())
                .is_none()
        );
        let down = pl.oriented_towards(&-Vector3::z());
        assert_eq!(down.normal.z, -1.0);
        assert_eq!(down.offset, -10.0);
        assert_eq!(down.signed_distance(&Point3::new(0.0, 0.0, 12.5)), -2.5);
        assert_eq!(pl.oriented_towards(&Vector3::z()), pl);
    }

    #[test]
    fn distance_and_angle_of_two_planes() {
        let a = Plane::through(
            &Point3::new(0.0, 0.0, 10.0),
            UnitVector3::new_normalize(Vector3::z()),
        );
        let theta: Real = 0.01;
        // b through (0, 0, 12.5), tilted by θ about x, normal pointing down.
        let nb = UnitVector3::new_normalize(-Vector3::new(0.0, theta.sin(), theta.cos()));
        let b = Plane::through(&Point3::new(0.0, 0.0, 12.5), nb);
        let at = Point3::new(3.0, 4.0, -7.0);
        let (d, ang) = plane_distance_and_angle(&a, &b, &at).expect("measurable");
        // Line x = 3, y = 4: meets a at z = 10 and b at z = 12.5 − 4 tan θ.
        assert!((d - (2.5 - 4.0 * theta.tan())).abs() < 1e-13, "{d}");
        assert!((ang - theta).abs() < 1e-15, "{ang}");
        let (d2, ang2) = plane_distance_and_angle(&b, &a, &at).expect("measurable");
        assert!((ang2 - theta).abs() < 1e-15);
        // From b along b's (downward) normal through `at`, a lies on the positive side.
        assert!(d2 > 0.0 && (d2 - d * theta.cos()).abs() < 0.05 * d);
        // Parallel planes: the plain offset difference, angle 0.
        let c = Plane::through(&Point3::new(9.0, 9.0, 7.0), a.normal);
        assert_eq!(plane_distance_and_angle(&a, &c, &at), Some((-3.0, 0.0)));
        // Perpendicular planes cannot be measured this way.
        let side = Plane::through(&Point3::origin(), UnitVector3::new_normalize(Vector3::x()));
        assert_eq!(plane_distance_and_angle(&a, &side, &at), None);
        let nan = Point3::new(Real::NAN, 0.0, 0.0);
        assert_eq!(plane_distance_and_angle(&a, &b, &nan), None);
    }
}
