//! The orthogonal least-squares sphere: its result ([`SphereFit`]), its model for the
//! solver (centre and radius), and the plain and robust fits ([`fit_sphere`],
//! [`fit_sphere_robust`]) from the algebraic start.

use super::error::{FitError, check_input};
use super::moments::chunked_sum;
use super::robust::{RobustRule, Trimmable, trim_and_refit};
use super::solver::{Model, Sums, levenberg_marquardt};
use super::start::{Spread, solve_spd};
use crate::math::{Point3, Real, Vector3};
use nalgebra::{SMatrix, SVector};

/// Result of a sphere fit. Standard uncertainties from the residuals: σ² (JᵀJ)⁻¹ with
/// σ² = Σr²/(m − p) (m = n residuals, p = 4 parameters); infinite when n = 4.
#[derive(Clone, Debug, PartialEq)]
pub struct SphereFit {
    /// Centre (mm).
    pub centre: Point3,
    /// Radius (mm).
    pub radius: Real,
    /// Standard uncertainty of the centre's x, y, z (mm).
    pub centre_sigma_mm: [Real; 3],
    /// Standard uncertainty of the radius (mm).
    pub radius_sigma_mm: Real,
    /// RMS of the residuals |p − c| − r of the used points (mm), divided by n.
    pub rms_mm: Real,
    /// Largest |residual| of the used points (mm).
    pub max_abs_mm: Real,
    /// Number of points in the final fit.
    pub n_used: usize,
    /// Number of input points rejected as outliers (0 for [`fit_sphere`]).
    pub n_rejected: usize,
    /// Levenberg–Marquardt iterations (accepted steps) of the final fit.
    pub iterations: usize,
}

/// Minimum points for a sphere: four non-coplanar points determine it.
const SPHERE_MIN_POINTS: usize = 4;

/// Sphere state: parameters centre (3, additive) and radius.
#[derive(Clone, Copy, Debug)]
pub(super) struct SphereModel {
    pub(super) c: Point3,
    pub(super) r: Real,
}

impl Model<4> for SphereModel {
    const RESIDUALS_PER_POINT: usize = 1;

    #[inline]
    fn accumulate(&self, p: &Point3, acc: &mut Sums<4>) {
        let d = p - self.c;
        let rho = d.norm();
        let u = if rho > 0.0 {
            d * rho.recip()
        } else {
            Vector3::zeros()
        };
        let res = rho - self.r;
        acc.push(&[-u.x, -u.y, -u.z, -1.0], res);
        acc.max_abs = acc.max_abs.max(res.abs());
    }

    fn step(&self, delta: &SVector<Real, 4>) -> Self {
        Self {
            c: self.c + delta.fixed_rows::<3>(0),
            r: self.r + delta[3],
        }
    }

    fn to_length(_scale: Real) -> SVector<Real, 4> {
        SVector::repeat(1.0)
    }
}

/// Orthogonal least-squares sphere: minimises Σ(|pᵢ − c| − r)².
///
/// Needs at least 4 finite, non-coplanar points. Starts from the algebraic fit and
/// refines by Levenberg–Marquardt. Deterministic and bit-identical for any thread count.
pub fn fit_sphere(points: &[Point3]) -> Result<SphereFit, FitError> {
    check_input(points, SPHERE_MIN_POINTS)?;
    sphere_checked(points, None)
}

/// Sphere fit with iterative outlier rejection (see [`RobustRule`]); each refit starts from
/// the previous fit.
///
/// Errors as [`fit_sphere`] on the full set; once an initial fit exists it never fails.
/// `n_used + n_rejected == points.len()`.
pub fn fit_sphere_robust(points: &[Point3], rule: &RobustRule) -> Result<SphereFit, FitError> {
    let fit = fit_sphere(points)?;
    Ok(trim_and_refit(points, rule, fit, |subset, prev| {
        sphere_checked(subset, Some(prev))
    }))
}

/// The sphere fit proper; points finite and at least 4.
fn sphere_checked(points: &[Point3], warm: Option<&SphereFit>) -> Result<SphereFit, FitError> {
    let sp = Spread::of(points)?;
    if sp.coplanar() {
        return Err(FitError::Degenerate);
    }
    let start = match warm {
        Some(f) => SphereModel {
            c: f.centre,
            r: f.radius,
        },
        None => algebraic_sphere(points, &sp).ok_or(FitError::Degenerate)?,
    };
    let sol = levenberg_marquardt(points, start, sp.rms)?;
    let m = sol.model;
    if !(m.r > 0.0 && m.r.is_finite()) {
        return Err(FitError::Degenerate);
    }
    Ok(SphereFit {
        centre: m.c,
        radius: m.r,
        centre_sigma_mm: [sol.sigma(0), sol.sigma(1), sol.sigma(2)],
        radius_sigma_mm: sol.sigma(3),
        rms_mm: sol.rms(),
        max_abs_mm: sol.normal.max_abs,
        n_used: points.len(),
        n_rejected: 0,
        iterations: sol.iterations,
    })
}

/// The algebraic sphere x²+y²+z² + Dx + Ey + Fz + G = 0 of the points, solved in
/// coordinates centred on the centroid and scaled by the RMS spread.
pub(super) fn algebraic_sphere(points: &[Point3], sp: &Spread) -> Option<SphereModel> {
    let (g, s) = (sp.centroid, sp.rms);
    let zero = (SMatrix::<Real, 4, 4>::zeros(), SVector::<Real, 4>::zeros());
    let (a, b) = chunked_sum(
        points,
        |c| {
            let (mut a, mut b) = zero;
            for p in c {
                let q = (p - g) / s;
                let z = SVector::<Real, 4>::new(q.x, q.y, q.z, 1.0);
                a.ger(1.0, &z, &z, 1.0);
                b.axpy(q.norm_squared(), &z, 1.0);
            }
            (a, b)
        },
        zero,
        |(a, b), (c, d)| (a + c, b + d),
    );
    let x = solve_spd(&a, &(-b))?;
    let cq = Vector3::new(x[0], x[1], x[2]) * -0.5;
    let r2 = cq.norm_squared() - x[3];
    let model = SphereModel {
        c: g + cq * s,
        r: r2.sqrt() * s,
    };
    (r2 > 0.0 && model.r.is_finite()).then_some(model)
}

impl Trimmable for SphereFit {
    const MIN_POINTS: usize = SPHERE_MIN_POINTS;
    fn rms(&self) -> Real {
        self.rms_mm
    }
    fn distance(&self, p: &Point3) -> Real {
        ((p - self.centre).norm() - self.radius).abs()
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
        EXACT_REL, NOISE, TRIALS, Tally, arc_for, check_rejections, contaminate, shape, within,
    };
    use super::*;
    use std::f64::consts::PI;

    #[test]
    fn exact_spheres_in_random_poses() {
        for seed in 0..24u64 {
            let s = shape(seed);
            let cap = arc_for(seed) / 2.0;
            let count = 4 + (seed as usize * 2131) % 12_000;
            let pts = s.sphere(count, cap, 0.0, 0);
            let fit = fit_sphere(&pts).unwrap_or_else(|e| panic!("seed {seed}: {e}"));
            let r = s.radius;
            let dc = (fit.centre - s.centre).norm() / r;
            let dr = (fit.radius - r).abs() / r;
            assert!(
                dc <= EXACT_REL && dr <= EXACT_REL,
                "seed {seed}: {dc:e} {dr:e}"
            );
            assert!(fit.rms_mm <= 1e-11 * r && fit.max_abs_mm <= 1e-10 * r);
            assert_eq!((fit.n_used, fit.n_rejected), (count, 0));
            assert!(
                fit.iterations <= 3,
                "seed {seed}: {} iterations",
                fit.iterations
            );
            if count == 4 {
                assert!(fit.radius_sigma_mm.is_infinite());
            }
        }
    }

    #[test]
    fn sphere_uncertainties_match_monte_carlo() {
        for (name, s, cap, count) in [
            ("full sphere", shape(101).with_radius(10.0), PI, 400),
            ("120° cap", shape(102).with_radius(25.0), PI / 3.0, 1000),
        ] {
            let mut t: [Tally; 4] = Default::default();
            for trial in 0..TRIALS {
                let pts = s.sphere(count, cap, NOISE, 10_000 + trial);
                let f = fit_sphere(&pts).expect("fit");
                for (k, tk) in t.iter_mut().take(3).enumerate() {
                    tk.push(f.centre[k] - s.centre[k], f.centre_sigma_mm[k]);
                }
                t[3].push(f.radius - s.radius, f.radius_sigma_mm);
            }
            for (k, q) in ["centre x", "centre y", "centre z", "radius"]
                .iter()
                .enumerate()
            {
                t[k].check(&format!("{name} {q}"));
            }
        }
    }

    #[test]
    fn robust_sphere_rejects_gross_outliers() {
        let s = shape(201).with_radius(20.0);
        let count = 20_000;
        let clean = s.sphere(count, PI, NOISE, 5);
        let (dirty, n_out) = contaminate(&clean, |p| (p - s.centre).normalize());
        let plain = fit_sphere(&dirty).expect("plain");
        let f = fit_sphere_robust(&dirty, &RobustRule::default()).expect("robust");
        check_rejections(f.n_rejected, f.n_used, n_out, count);
        for k in 0..3 {
            within("centre", f.centre[k] - s.centre[k], f.centre_sigma_mm[k]);
        }
        within("radius", f.radius - s.radius, f.radius_sigma_mm);
        assert!(f.rms_mm < 0.03 && plain.rms_mm > 0.15);
        let exact = s.sphere(500, PI, 0.0, 0);
        let e = fit_sphere_robust(&exact, &RobustRule::default()).expect("exact");
        assert_eq!(e.n_rejected, 0);
    }

    /// Cross-check against the `levenberg-marquardt` crate on a noisy partial sphere: both
    /// minimise the same sum of squares, so they agree far inside the uncertainty.
    #[test]
    fn sphere_agrees_with_levenberg_marquardt_crate() {
        use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
        use nalgebra::{DMatrix, DVector, Dyn, Owned, U4, Vector4};

        struct Problem<'a> {
            pts: &'a [Point3],
            x: Vector4<Real>,
        }
        impl LeastSquaresProblem<Real, Dyn, U4> for Problem<'_> {
            type ResidualStorage = Owned<Real, Dyn>;
            type JacobianStorage = Owned<Real, Dyn, U4>;
            type ParameterStorage = Owned<Real, U4>;
            fn set_params(&mut self, x: &Vector4<Real>) {
                self.x = *x;
            }
            fn params(&self) -> Vector4<Real> {
                self.x
            }
            fn residuals(&self) -> Option<DVector<Real>> {
                let c = Point3::new(self.x[0], self.x[1], self.x[2]);
                Some(DVector::from_iterator(
                    self.pts.len(),
                    self.pts.iter().map(|p| (p - c).norm() - self.x[3]),
                ))
            }
            fn jacobian(&self) -> Option<nalgebra::OMatrix<Real, Dyn, U4>> {
                let c = Point3::new(self.x[0], self.x[1], self.x[2]);
                let mut j = DMatrix::zeros(self.pts.len(), 4);
                for (i, p) in self.pts.iter().enumerate() {
                    let u = (p - c).normalize();
                    j[(i, 0)] = -u.x;
                    j[(i, 1)] = -u.y;
                    j[(i, 2)] = -u.z;
                    j[(i, 3)] = -1.0;
                }
                Some(j.fixed_columns::<4>(0).into_owned())
            }
        }
        let s = shape(301).with_radius(8.0);
        let pts = s.sphere(2000, 0.4 * PI, NOISE, 9);
        let ours = fit_sphere(&pts).expect("fit");
        let start = Vector4::new(s.centre.x + 0.3, s.centre.y - 0.2, s.centre.z, 8.5);
        let (solved, report) = LevenbergMarquardt::new().minimize(Problem {
            pts: &pts,
            x: start,
        });
        assert!(report.termination.was_successful(), "{report:?}");
        let x = solved.x;
        let dc = (Point3::new(x[0], x[1], x[2]) - ours.centre).norm();
        assert!(
            dc <= 1e-6 * ours.centre_sigma_mm[0],
            "centre differs by {dc:e}"
        );
        assert!((x[3] - ours.radius).abs() <= 1e-6 * ours.radius_sigma_mm);
    }
}
