//! The orthogonal least-squares circle in 3-D: its result ([`CircleFit`]), its model for
//! the solver (centre, normal in two tangent-plane angles, radius; two residuals a point),
//! and the plain and robust fits ([`fit_circle`], [`fit_circle_robust`]) from the plane
//! fit and a Kåsa circle in it.

use super::error::{FitError, check_input};
use super::moments::canonical_sign;
use super::plane::fit_checked;
use super::robust::{RobustRule, Trimmable, trim_and_refit};
use super::solver::{Model, Sums, levenberg_marquardt};
use super::start::{Spread, kasa_circles, rotate, tangent_basis};
use crate::math::{Point3, Real, UnitVector3, Vector3};
use nalgebra::SVector;

#[cfg(doc)]
use super::plane::fit_plane;

/// Result of a circle fit. Standard uncertainties from the residuals: σ² (JᵀJ)⁻¹ with
/// σ² = Σr²/(m − p) (m = 2n residuals: out-of-plane and in-plane radial; p = 6
/// parameters); infinite when n = 3.
#[derive(Clone, Debug, PartialEq)]
pub struct CircleFit {
    /// Centre (mm).
    pub centre: Point3,
    /// Unit normal of the circle's plane, oriented so that its largest-magnitude component
    /// is positive (the first of x, y, z on a tie).
    pub normal: UnitVector3,
    /// Radius (mm).
    pub radius: Real,
    /// Standard uncertainty of the centre's x, y, z (mm).
    pub centre_sigma_mm: [Real; 3],
    /// Standard uncertainty of the radius (mm).
    pub radius_sigma_mm: Real,
    /// Standard uncertainty of the normal's tilt (rad) in its worst direction: the root of
    /// the largest eigenvalue of its 2×2 covariance (for a full circle both directions are
    /// equal).
    pub normal_sigma_rad: Real,
    /// RMS distance of the used points from the circle (mm), √(Σ(h² + (ρ−r)²)/n).
    pub rms_mm: Real,
    /// Largest distance of a used point from the circle (mm).
    pub max_abs_mm: Real,
    /// Number of points in the final fit.
    pub n_used: usize,
    /// Number of input points rejected as outliers (0 for [`fit_circle`]).
    pub n_rejected: usize,
    /// Levenberg–Marquardt iterations (accepted steps) of the final fit.
    pub iterations: usize,
}

/// Minimum points for a circle: three non-collinear points determine it.
const CIRCLE_MIN_POINTS: usize = 3;

/// Circle state: centre (3, additive), normal (2 tangent-plane angles), radius.
#[derive(Clone, Copy, Debug)]
struct CircleModel {
    c: Point3,
    n: UnitVector3,
    e1: Vector3,
    e2: Vector3,
    r: Real,
}

impl CircleModel {
    fn new(c: Point3, n: UnitVector3, r: Real) -> Self {
        let (e1, e2) = tangent_basis(&n);
        Self { c, n, e1, e2, r }
    }
}

impl Model<6> for CircleModel {
    const RESIDUALS_PER_POINT: usize = 2;

    #[inline]
    fn accumulate(&self, p: &Point3, acc: &mut Sums<6>) {
        let d = p - self.c;
        let h = self.n.dot(&d);
        let w = d - self.n.into_inner() * h;
        let rho = w.norm();
        let t = if rho > 0.0 {
            w * rho.recip()
        } else {
            Vector3::zeros()
        };
        let (d1, d2) = (self.e1.dot(&d), self.e2.dot(&d));
        let (t1, t2) = (self.e1.dot(&t), self.e2.dot(&t));
        let n = &self.n;
        acc.push(&[-n.x, -n.y, -n.z, d1, d2, 0.0], h);
        let b = rho - self.r;
        acc.push(&[-t.x, -t.y, -t.z, -h * t1, -h * t2, -1.0], b);
        acc.max_abs = acc.max_abs.max((h * h + b * b).sqrt());
    }

    fn step(&self, delta: &SVector<Real, 6>) -> Self {
        let n = rotate(&self.n, &(self.e1 * delta[3] + self.e2 * delta[4]));
        Self::new(self.c + delta.fixed_rows::<3>(0), n, self.r + delta[5])
    }

    fn to_length(scale: Real) -> SVector<Real, 6> {
        SVector::<Real, 6>::new(1.0, 1.0, 1.0, scale, scale, 1.0)
    }
}

/// Orthogonal least-squares circle in 3-D: minimises the sum of squared distances of the
/// points from the circle, Σ(hᵢ² + (ρᵢ − r)²) with hᵢ the height above the circle's plane
/// and ρᵢ the in-plane distance from the centre.
///
/// Needs at least 3 finite, non-collinear points. Starts from [`fit_plane`] and a Kåsa
/// circle in that plane, refines by Levenberg–Marquardt. Deterministic and bit-identical
/// for any thread count.
pub fn fit_circle(points: &[Point3]) -> Result<CircleFit, FitError> {
    check_input(points, CIRCLE_MIN_POINTS)?;
    circle_checked(points, None)
}

/// Circle fit with iterative outlier rejection (see [`RobustRule`]; the residual is the
/// point's distance from the circle); each refit starts from the previous fit.
///
/// Errors as [`fit_circle`] on the full set; once an initial fit exists it never fails.
/// `n_used + n_rejected == points.len()`.
pub fn fit_circle_robust(points: &[Point3], rule: &RobustRule) -> Result<CircleFit, FitError> {
    let fit = fit_circle(points)?;
    Ok(trim_and_refit(points, rule, fit, |subset, prev| {
        circle_checked(subset, Some(prev))
    }))
}

/// The circle fit proper; points finite and at least 3.
fn circle_checked(points: &[Point3], warm: Option<&CircleFit>) -> Result<CircleFit, FitError> {
    let sp = Spread::of(points)?;
    if sp.collinear() {
        return Err(FitError::Degenerate);
    }
    let start = match warm {
        Some(f) => CircleModel::new(f.centre, f.normal, f.radius),
        None => {
            let normal = fit_checked(points)?.plane.normal;
            let [circle] = kasa_circles(points, &sp, &[normal]);
            let (c, r) = circle.ok_or(FitError::Degenerate)?;
            CircleModel::new(c, normal, r)
        }
    };
    let sol = levenberg_marquardt(points, start, sp.rms)?;
    let m = sol.model;
    if !(m.r > 0.0 && m.r.is_finite()) {
        return Err(FitError::Degenerate);
    }
    let normal = UnitVector3::new_unchecked(canonical_sign(m.n.into_inner()));
    Ok(CircleFit {
        centre: m.c,
        normal,
        radius: m.r,
        centre_sigma_mm: [sol.sigma(0), sol.sigma(1), sol.sigma(2)],
        radius_sigma_mm: sol.sigma(5),
        normal_sigma_rad: sol.sigma_pair(3)[0],
        rms_mm: sol.rms(),
        max_abs_mm: sol.normal.max_abs,
        n_used: points.len(),
        n_rejected: 0,
        iterations: sol.iterations,
    })
}

impl Trimmable for CircleFit {
    const MIN_POINTS: usize = CIRCLE_MIN_POINTS;
    fn rms(&self) -> Real {
        self.rms_mm
    }
    fn distance(&self, p: &Point3) -> Real {
        let d = p - self.centre;
        let h = self.normal.dot(&d);
        let rho = (d - self.normal.into_inner() * h).norm();
        h.hypot(rho - self.radius)
    }
    fn n_used(&self) -> usize {
        self.n_used
    }
    fn set_rejected(&mut self, n: usize) {
        self.n_rejected = n;
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests::{
        EXACT_REL, NOISE, TRIALS, Tally, angle, arc_for, check_rejections, check_tilts,
        contaminate, shape, within,
    };
    use super::*;
    use std::f64::consts::{PI, TAU};

    #[test]
    fn exact_circles_in_random_poses() {
        for seed in 0..24u64 {
            let s = shape(seed);
            let count = 3 + (seed as usize * 2131) % 12_000;
            let pts = s.circle(count, arc_for(seed), 0.0, 0);
            let fit = fit_circle(&pts).unwrap_or_else(|e| panic!("seed {seed}: {e}"));
            let r = s.radius;
            let dc = (fit.centre - s.centre).norm() / r;
            let dr = (fit.radius - r).abs() / r;
            let dn = angle(&fit.normal, &s.axis);
            assert!(
                dc <= EXACT_REL && dr <= EXACT_REL && dn <= EXACT_REL,
                "seed {seed}: {dc:e} {dr:e} {dn:e}"
            );
            assert!(fit.rms_mm <= 1e-11 * r && fit.max_abs_mm <= 1e-10 * r);
            assert!(fit.normal[fit.normal.iamax()] > 0.0);
            assert_eq!((fit.n_used, fit.n_rejected), (count, 0));
        }
    }

    #[test]
    fn circle_uncertainties_match_monte_carlo() {
        for (name, s, arc, count) in [
            ("full circle", shape(103).with_radius(10.0), TAU, 300),
            ("180° arc", shape(104).with_radius(20.0), PI, 400),
        ] {
            let mut t: [Tally; 4] = Default::default();
            let mut tilts = vec![];
            let mut s_tilt = 0.0;
            for trial in 0..TRIALS {
                let pts = s.circle(count, arc, NOISE, 20_000 + trial);
                let f = fit_circle(&pts).expect("fit");
                for (k, tk) in t.iter_mut().take(3).enumerate() {
                    tk.push(f.centre[k] - s.centre[k], f.centre_sigma_mm[k]);
                }
                t[3].push(f.radius - s.radius, f.radius_sigma_mm);
                tilts.push(s.tilt(&f.normal));
                s_tilt += f.normal_sigma_rad / TRIALS as Real;
            }
            for (k, q) in ["centre x", "centre y", "centre z", "radius"]
                .iter()
                .enumerate()
            {
                t[k].check(&format!("{name} {q}"));
            }
            check_tilts(name, &tilts, [s_tilt, Real::NAN]);
        }
    }

    #[test]
    fn robust_circle_rejects_gross_outliers() {
        let s = shape(202).with_radius(20.0);
        let count = 20_000;
        let clean = s.circle(count, 1.5 * PI, NOISE, 6);
        let (dirty, n_out) = contaminate(&clean, |p| {
            let d = p - s.centre;
            (d - s.axis.into_inner() * s.axis.dot(&d)).normalize()
        });
        let plain = fit_circle(&dirty).expect("plain");
        let f = fit_circle_robust(&dirty, &RobustRule::default()).expect("robust");
        check_rejections(f.n_rejected, f.n_used, n_out, count);
        for k in 0..3 {
            within("centre", f.centre[k] - s.centre[k], f.centre_sigma_mm[k]);
        }
        within("radius", f.radius - s.radius, f.radius_sigma_mm);
        let t = s.tilt(&f.normal);
        within(
            "normal",
            t[0].hypot(t[1]),
            f.normal_sigma_rad * 2.0_f64.sqrt(),
        );
        assert!(f.rms_mm < 0.05 && plain.rms_mm > 0.2);
    }
}
