//! Fixtures shared by the fit tests (random unit vectors and poses, points on spheres,
//! circles and cylinders, Monte Carlo tallies, outlier contamination), and the tests that
//! span every shape: error cases, random point sets, bit-identity across thread counts.

use super::*;
use crate::math::{CounterRng, Point3, Real, UnitVector3, Vector3};
use proptest::prelude::*;
use std::f64::consts::{PI, TAU};

pub(super) fn unit(rng: &CounterRng, i: u64) -> UnitVector3 {
    UnitVector3::new_normalize(Vector3::new(
        rng.normal(3 * i),
        rng.normal(3 * i + 1),
        rng.normal(3 * i + 2),
    ))
}

/// Orthonormal in-plane axes (a, b) for normal `n`, rotated by `angle`.
pub(super) fn axes(n: &UnitVector3, angle: Real) -> (Vector3, Vector3) {
    let e = if n.x.abs() < 0.6 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let a0 = n.cross(&e).normalize();
    let b0 = n.cross(&a0);
    let a = a0 * angle.cos() + b0 * angle.sin();
    (a, n.cross(&a))
}

pub(super) fn std_dev(v: &[Real]) -> Real {
    let m = v.iter().sum::<Real>() / v.len() as Real;
    (v.iter().map(|x| (x - m).powi(2)).sum::<Real>() / (v.len() - 1) as Real).sqrt()
}

/// A random pose: centre up to 300 mm from the origin, axis (sphere cap / circle normal
/// / cylinder axis), perpendicular basis, radius 1–50 mm.
pub(super) struct Shape {
    pub(super) centre: Point3,
    pub(super) axis: UnitVector3,
    pub(super) a: Vector3,
    b: Vector3,
    pub(super) radius: Real,
}

pub(super) fn shape(seed: u64) -> Shape {
    let rng = CounterRng::new(1_000 + seed);
    let axis = unit(&rng, 0);
    let centre = Point3::from(unit(&rng, 1).into_inner() * (300.0 * rng.uniform(10, 0)));
    let radius = 1.0 + 49.0 * rng.uniform(11, 0);
    let (a, b) = axes(&axis, TAU * rng.uniform(12, 0));
    Shape {
        centre,
        axis,
        a,
        b,
        radius,
    }
}

impl Shape {
    pub(super) fn with_radius(mut self, r: Real) -> Self {
        self.radius = r;
        self
    }

    /// Unit radial direction at azimuth `phi`, polar angle `theta` from the axis.
    fn dir(&self, theta: Real, phi: Real) -> Vector3 {
        self.axis.into_inner() * theta.cos()
            + (self.a * phi.cos() + self.b * phi.sin()) * theta.sin()
    }

    /// Points on a cap of polar half-angle `cap` (π: the full sphere), area-uniform,
    /// with Gaussian noise `noise` along the normal.
    pub(super) fn sphere(
        &self,
        count: usize,
        cap: Real,
        noise: Real,
        noise_seed: u64,
    ) -> Vec<Point3> {
        let pos = CounterRng::new(42);
        let nz = CounterRng::new(noise_seed);
        (0..count as u64)
            .map(|i| {
                let cos_t = 1.0 - (1.0 - cap.cos()) * pos.uniform(i, 0);
                let u = self.dir(cos_t.clamp(-1.0, 1.0).acos(), TAU * pos.uniform(i, 1));
                self.centre + u * (self.radius + noise * nz.normal(i))
            })
            .collect()
    }

    /// Points on an arc of `arc` rad of the circle (centre, normal = axis), with
    /// Gaussian noise `noise` both in-plane radially and along the normal.
    pub(super) fn circle(
        &self,
        count: usize,
        arc: Real,
        noise: Real,
        noise_seed: u64,
    ) -> Vec<Point3> {
        let pos = CounterRng::new(43);
        let nz = CounterRng::new(noise_seed);
        (0..count as u64)
            .map(|i| {
                let u = self.dir(PI / 2.0, arc * pos.uniform(i, 0));
                self.centre
                    + u * (self.radius + noise * nz.normal(2 * i))
                    + self.axis.into_inner() * (noise * nz.normal(2 * i + 1))
            })
            .collect()
    }

    /// Points on an arc of `arc` rad of the cylinder (axis through centre), `length`
    /// mm long, with Gaussian noise `noise` along the normal.
    pub(super) fn cylinder(
        &self,
        count: usize,
        arc: Real,
        length: Real,
        noise: Real,
        noise_seed: u64,
    ) -> Vec<Point3> {
        let pos = CounterRng::new(44);
        let nz = CounterRng::new(noise_seed);
        (0..count as u64)
            .map(|i| {
                let u = self.dir(PI / 2.0, arc * pos.uniform(i, 0));
                let t = length * (pos.uniform(i, 1) - 0.5);
                self.centre + self.axis.into_inner() * t + u * (self.radius + noise * nz.normal(i))
            })
            .collect()
    }

    /// The foot on the true axis of the centroid of `pts`.
    pub(super) fn foot(&self, pts: &[Point3]) -> Point3 {
        let g = pts.iter().fold(Vector3::zeros(), |s, p| s + p.coords) / pts.len() as Real;
        let v = self.axis.into_inner();
        self.centre + v * v.dot(&(g - self.centre.coords))
    }

    /// Tilt of `n` (oriented like the axis) towards a and b (rad).
    pub(super) fn tilt(&self, n: &UnitVector3) -> [Real; 2] {
        let n = if n.dot(&self.axis) < 0.0 { -*n } else { *n };
        [n.dot(&self.a), n.dot(&self.b)]
    }
}

pub(super) fn angle(u: &UnitVector3, v: &UnitVector3) -> Real {
    u.cross(v).norm()
}

/// Arc for exact-data case `seed`: every third full, else 120°–360°.
pub(super) fn arc_for(seed: u64) -> Real {
    if seed.is_multiple_of(3) {
        TAU
    } else {
        TAU / 3.0 + (TAU - TAU / 3.0) * CounterRng::new(seed).uniform(0, 5)
    }
}

pub(super) const EXACT_REL: Real = 1e-9;

/// Monte Carlo summary of one scalar: errors against the truth and reported σ.
#[derive(Default)]
pub(super) struct Tally {
    err: Vec<Real>,
    sigma: Vec<Real>,
}

impl Tally {
    pub(super) fn push(&mut self, err: Real, sigma: Real) {
        self.err.push(err);
        self.sigma.push(sigma);
    }

    /// Unbiased within 3 standard errors; observed spread within 20 % of the mean σ.
    pub(super) fn check(&self, name: &str) {
        let n = self.err.len() as Real;
        let mean = self.err.iter().sum::<Real>() / n;
        let sd = std_dev(&self.err);
        let pred = self.sigma.iter().sum::<Real>() / n;
        assert!(
            mean.abs() < 3.0 * sd / n.sqrt(),
            "{name}: bias {mean:e}, std {sd:e}"
        );
        let ratio = sd / pred;
        assert!(
            (0.8..=1.2).contains(&ratio),
            "{name}: observed {sd:e} predicted {pred:e}"
        );
    }
}

/// Tilt pairs: unbiased per component; the roots of the observed 2×2 covariance's
/// eigenvalues within 20 % of the reported (largest-first) σ pair (`pred[1]` NaN: only
/// the largest is reported).
pub(super) fn check_tilts(name: &str, tilts: &[[Real; 2]], pred: [Real; 2]) {
    let n = tilts.len() as Real;
    let col = |k: usize| tilts.iter().map(|t| t[k]).collect::<Vec<_>>();
    let (x, y) = (col(0), col(1));
    for (c, v) in [("a", &x), ("b", &y)] {
        let mean = v.iter().sum::<Real>() / n;
        let sd = std_dev(v);
        assert!(
            mean.abs() < 3.0 * sd / n.sqrt(),
            "{name} tilt {c}: bias {mean:e}, std {sd:e}"
        );
    }
    let (mx, my) = (x.iter().sum::<Real>() / n, y.iter().sum::<Real>() / n);
    let cxx = x.iter().map(|v| (v - mx).powi(2)).sum::<Real>() / (n - 1.0);
    let cyy = y.iter().map(|v| (v - my).powi(2)).sum::<Real>() / (n - 1.0);
    let cxy = x
        .iter()
        .zip(&y)
        .map(|(a, b)| (a - mx) * (b - my))
        .sum::<Real>()
        / (n - 1.0);
    let (mean, half) = (0.5 * (cxx + cyy), (0.5 * (cxx - cyy)).hypot(cxy));
    let obs = [(mean + half).sqrt(), (mean - half).sqrt()];
    for k in 0..2 {
        if pred[k].is_nan() {
            continue;
        }
        let ratio = obs[k] / pred[k];
        assert!(
            (0.8..=1.2).contains(&ratio),
            "{name} tilt σ{k}: observed {:e} predicted {:e}",
            obs[k],
            pred[k]
        );
    }
}

pub(super) const TRIALS: u64 = 200;

pub(super) const NOISE: Real = 0.025;

/// Moves 5 % of the points (chosen by seed) by ±1 mm along `normal_of(p)`; returns
/// the dirty set and the number moved.
pub(super) fn contaminate(
    clean: &[Point3],
    normal_of: impl Fn(&Point3) -> Vector3,
) -> (Vec<Point3>, usize) {
    let rng = CounterRng::new(77);
    let mut n_out = 0;
    let dirty = clean
        .iter()
        .enumerate()
        .map(|(i, q)| {
            if rng.uniform(i as u64, 0) < 0.05 {
                n_out += 1;
                let sign = if rng.uniform(i as u64, 1) < 0.5 {
                    -1.0
                } else {
                    1.0
                };
                q + normal_of(q) * sign
            } else {
                *q
            }
        })
        .collect();
    (dirty, n_out)
}

pub(super) fn within(name: &str, err: Real, sigma: Real) {
    assert!(
        err.abs() <= 3.0 * sigma,
        "{name}: error {err:e}, σ {sigma:e}"
    );
}

pub(super) fn check_rejections(n_rejected: usize, n_used: usize, n_out: usize, count: usize) {
    assert!(
        n_rejected >= n_out && n_rejected < n_out + count / 100,
        "{n_rejected} rejected, {n_out} outliers"
    );
    assert_eq!(n_used + n_rejected, count);
}

#[test]
fn shape_error_cases() {
    let s = shape(5);
    let sphere = s.sphere(50, PI, 0.0, 0);
    let circle = s.circle(50, TAU, 0.0, 0);
    let cylinder = s.cylinder(50, TAU, 30.0, 0.0, 0);
    let few = |needed, got| Some(FitError::TooFewPoints { needed, got });
    assert_eq!(fit_sphere(&sphere[..3]).err(), few(4, 3));
    assert_eq!(fit_circle(&circle[..2]).err(), few(3, 2));
    assert_eq!(fit_cylinder(&cylinder[..4], None).err(), few(5, 4));
    let rule = RobustRule::default();
    assert_eq!(fit_sphere_robust(&[], &rule).err(), few(4, 0));
    assert_eq!(fit_circle_robust(&[], &rule).err(), few(3, 0));
    assert_eq!(fit_cylinder_robust(&[], None, &rule).err(), few(5, 0));
    // Non-finite.
    let nan = |mut v: Vec<Point3>| {
        v[7].z = Real::NAN;
        v
    };
    let bad = Some(FitError::NonFinite { index: 7 });
    assert_eq!(fit_sphere(&nan(sphere.clone())).err(), bad);
    assert_eq!(fit_circle(&nan(circle.clone())).err(), bad);
    assert_eq!(fit_cylinder(&nan(cylinder.clone()), None).err(), bad);
    let mut inf = cylinder.clone();
    inf[3].x = Real::INFINITY;
    assert_eq!(
        fit_cylinder_robust(&inf, None, &rule).err(),
        Some(FitError::NonFinite { index: 3 })
    );
    // Degenerate: a sphere on coplanar points, a circle or cylinder on collinear
    // points, a cylinder on one circle, coincident points.
    assert_eq!(fit_sphere(&circle), Err(FitError::Degenerate));
    let dir = Vector3::new(0.3, -0.7, 0.2);
    let line: Vec<Point3> = (0..100)
        .map(|i| Point3::new(120.0, 40.0, -80.0) + dir * (i as Real * 0.37))
        .collect();
    assert_eq!(fit_circle(&line), Err(FitError::Degenerate));
    assert_eq!(fit_cylinder(&line, None), Err(FitError::Degenerate));
    assert_eq!(fit_cylinder(&circle, None), Err(FitError::Degenerate));
    let same = [Point3::new(1.0, 2.0, 3.0); 10];
    assert_eq!(fit_sphere(&same), Err(FitError::Degenerate));
    assert_eq!(fit_circle(&same), Err(FitError::Degenerate));
    assert_eq!(fit_cylinder(&same, None), Err(FitError::Degenerate));
    // Points on a plane have no finite best cylinder: an error, never a number.
    let rng = CounterRng::new(3);
    let flat: Vec<Point3> = (0..200)
        .map(|i| Point3::new(40.0 * rng.uniform(i, 0), 30.0 * rng.uniform(i, 1), 5.0))
        .collect();
    let r = fit_cylinder(&flat, None);
    assert!(
        matches!(r, Err(FitError::NotConverged { .. } | FitError::Degenerate)),
        "{r:?}"
    );
    let huge = [
        Point3::new(1e300, 0.0, 0.0),
        Point3::new(-1e300, 1e300, 0.0),
        Point3::new(0.0, -1e300, 0.0),
        Point3::new(0.0, 0.0, 1e300),
        Point3::new(1e300, 1e300, 1e300),
    ];
    assert_eq!(fit_sphere(&huge), Err(FitError::Degenerate));
    assert_eq!(fit_circle(&huge), Err(FitError::Degenerate));
    assert_eq!(fit_cylinder(&huge, None), Err(FitError::Degenerate));
    // Minimal sets fit exactly with infinite uncertainties.
    let c3 = fit_circle(&circle[..3]).expect("three points");
    assert!((c3.radius - s.radius).abs() <= EXACT_REL * s.radius);
    assert!(c3.radius_sigma_mm.is_infinite() && c3.normal_sigma_rad.is_infinite());
    let messages = [
        FitError::TooFewPoints { needed: 4, got: 3 }.to_string(),
        FitError::NotConverged { iterations: 100 }.to_string(),
    ];
    assert!(messages[0].contains("at least 4") && messages[1].contains("100"));
}

/// Every reported number of an Ok fit is finite (σ may be +∞, never NaN), the radius
/// positive and the counts add up.
fn sane(values: &[Real], radius: Real, used: usize, rejected: usize, len: usize) -> bool {
    values.iter().all(|v| !v.is_nan())
        && radius > 0.0
        && radius.is_finite()
        && used + rejected == len
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(192))]

    #[test]
    fn random_point_sets_never_panic(
        raw in prop::collection::vec(
            (0u8..16, -400.0..400.0f64, -400.0..400.0f64, -400.0..400.0f64),
            0..28,
        ),
        flat in any::<bool>(),
    ) {
        let mut pts: Vec<Point3> = vec![];
        for (kind, x, y, z) in raw {
            let p = match kind {
                0 => Point3::new(x, Real::NAN, z),
                1 => Point3::new(x, y, Real::INFINITY),
                2 => Point3::new(x, y, z) * 1e300,
                3 => pts.last().copied().unwrap_or(Point3::new(x, y, z)),
                4 => Point3::new(x, y, z) * 1e-300,
                5 => Point3::new(x, 2.0 * x, -x),
                6 => Point3::new(x, 2.0 * x, -x) + Vector3::new(y, z, x) * 1e-9,
                7 => Point3::new(1e8 + x * 1e-3, y * 1e-3, z),
                _ => Point3::new(x, y, z),
            };
            pts.push(if flat { Point3::new(p.x, p.y, 0.0) } else { p });
        }
        let rule = RobustRule::default();
        let len = pts.len();
        for f in [fit_sphere(&pts), fit_sphere_robust(&pts, &rule)].into_iter().flatten() {
            let mut v = vec![f.radius_sigma_mm, f.rms_mm, f.max_abs_mm];
            v.extend(f.centre.iter().chain(&f.centre_sigma_mm));
            prop_assert!(sane(&v, f.radius, f.n_used, f.n_rejected, len));
        }
        for f in [fit_circle(&pts), fit_circle_robust(&pts, &rule)].into_iter().flatten() {
            let mut v = vec![f.radius_sigma_mm, f.normal_sigma_rad, f.rms_mm, f.max_abs_mm];
            v.extend(f.centre.iter().chain(&f.centre_sigma_mm).chain(f.normal.iter()));
            prop_assert!(sane(&v, f.radius, f.n_used, f.n_rejected, len));
        }
        for f in [fit_cylinder(&pts, None), fit_cylinder_robust(&pts, None, &rule)]
            .into_iter()
            .flatten()
        {
            let mut v = vec![f.radius_sigma_mm, f.rms_mm, f.max_abs_mm];
            v.extend(f.axis_point.iter().chain(&f.axis_point_sigma_mm));
            v.extend(f.axis.iter().chain(&f.axis_sigma_rad));
            prop_assert!(sane(&v, f.radius, f.n_used, f.n_rejected, len));
        }
    }
}

#[test]
fn shape_fits_bit_identical_across_thread_counts() {
    let s = shape(11).with_radius(15.0);
    let sphere = s.sphere(100_000, 0.8 * PI, NOISE, 8);
    let circle = s.circle(100_000, 1.2 * PI, NOISE, 8);
    let (cylinder, _) = contaminate(&s.cylinder(100_000, 1.5 * PI, 60.0, NOISE, 8), |p| {
        (p - s.centre).normalize()
    });
    let run = |threads: usize| {
        crate::math::in_pool(threads, || {
            (
                fit_sphere(&sphere).expect("sphere"),
                fit_circle(&circle).expect("circle"),
                fit_cylinder(&cylinder, None).expect("cylinder"),
                fit_cylinder_robust(&cylinder, None, &RobustRule::default())
                    .expect("robust cylinder"),
            )
        })
    };
    let one = run(1);
    let bits = |r: &(SphereFit, CircleFit, CylinderFit, CylinderFit)| {
        let mut v = vec![
            r.0.radius,
            r.0.radius_sigma_mm,
            r.1.radius,
            r.1.normal_sigma_rad,
        ];
        v.extend(
            r.0.centre
                .iter()
                .chain(r.1.centre.iter())
                .chain(r.1.normal.iter()),
        );
        for c in [&r.2, &r.3] {
            v.extend([c.radius, c.rms_mm, c.radius_sigma_mm]);
            v.extend(
                c.axis_point
                    .iter()
                    .chain(c.axis.iter())
                    .chain(&c.axis_sigma_rad),
            );
        }
        v.into_iter().map(Real::to_bits).collect::<Vec<_>>()
    };
    for threads in [2, 3] {
        let other = run(threads);
        assert_eq!(one, other, "{threads} threads");
        assert_eq!(bits(&one), bits(&other));
    }
    assert!(one.3.n_rejected > 0);
}
