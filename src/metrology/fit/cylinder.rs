//! The orthogonal least-squares cylinder: its result ([`CylinderFit`]), its model for the
//! solver (axis point kept at the foot of the points' centroid, axis in two tangent-plane
//! angles, radius), and the plain and robust fits ([`fit_cylinder`],
//! [`fit_cylinder_robust`]) from the best principal axis or the caller's.

use super::error::{FitError, check_input};
use super::moments::canonical_sign;
use super::moments::chunked_sum;
use super::robust::{RobustRule, Trimmable, trim_and_refit};
use super::solver::{Model, Sums, levenberg_marquardt};
use super::start::{Spread, kasa_circles, rotate, tangent_basis};
use crate::math::{Point3, Real, UnitVector3, Vector3};
use nalgebra::{SMatrix, SVector};

/// Result of a cylinder fit. Standard uncertainties from the residuals: σ² (JᵀJ)⁻¹ with
/// σ² = Σr²/(m − p) (m = n residuals, p = 5 parameters); infinite when n = 5.
#[derive(Clone, Debug, PartialEq)]
pub struct CylinderFit {
    /// The point of the axis closest to the used points' centroid (mm).
    pub axis_point: Point3,
    /// Unit axis direction, oriented so that its largest-magnitude component is positive
    /// (the first of x, y, z on a tie).
    pub axis: UnitVector3,
    /// Radius (mm).
    pub radius: Real,
    /// Standard uncertainty of `axis_point`'s x, y, z (mm), including the motion of the
    /// centroid's foot along the axis when the axis tilts.
    pub axis_point_sigma_mm: [Real; 3],
    /// Standard uncertainty of the axis's tilt (rad) about two directions perpendicular to
    /// the axis: the roots of the eigenvalues of its 2×2 covariance, largest first (equal
    /// for a full circumference).
    pub axis_sigma_rad: [Real; 2],
    /// Standard uncertainty of the radius (mm).
    pub radius_sigma_mm: Real,
    /// RMS of the residuals (distance from the axis − r) of the used points (mm), divided by n.
    pub rms_mm: Real,
    /// Largest |residual| of the used points (mm).
    pub max_abs_mm: Real,
    /// Number of points in the final fit.
    pub n_used: usize,
    /// Number of input points rejected as outliers (0 for [`fit_cylinder`]).
    pub n_rejected: usize,
    /// Levenberg–Marquardt iterations (accepted steps) of the final fit.
    pub iterations: usize,
}

/// Minimum points for a cylinder: five parameters, five residuals.
const CYLINDER_MIN_POINTS: usize = 5;

/// Cylinder state: axis point (2, moved in the plane ⟂ axis), axis direction (2
/// tangent-plane angles), radius. The point is kept at the foot of `pivot` (the points'
/// centroid) on the axis, so tilts turn the axis about the middle of the data.
#[derive(Clone, Copy, Debug)]
pub(super) struct CylinderModel {
    a: Point3,
    v: UnitVector3,
    e1: Vector3,
    e2: Vector3,
    r: Real,
    pivot: Point3,
}

impl CylinderModel {
    pub(super) fn new(a: Point3, v: UnitVector3, r: Real, pivot: Point3) -> Self {
        let a = a + v.into_inner() * v.dot(&(pivot - a));
        let (e1, e2) = tangent_basis(&v);
        Self {
            a,
            v,
            e1,
            e2,
            r,
            pivot,
        }
    }
}

impl Model<5> for CylinderModel {
    const RESIDUALS_PER_POINT: usize = 1;

    #[inline]
    fn accumulate(&self, p: &Point3, acc: &mut Sums<5>) {
        let d = p - self.a;
        let h = self.v.dot(&d);
        // In-plane coordinates: w = d − h·v = w1·e1 + w2·e2, so t·eₖ = wₖ/ρ.
        let (w1, w2) = (self.e1.dot(&d), self.e2.dot(&d));
        let rho = (w1 * w1 + w2 * w2).sqrt();
        let inv = if rho > 0.0 { rho.recip() } else { 0.0 };
        let (t1, t2) = (w1 * inv, w2 * inv);
        let res = rho - self.r;
        acc.push(&[-t1, -t2, -h * t1, -h * t2, -1.0], res);
        acc.max_abs = acc.max_abs.max(res.abs());
    }

    fn step(&self, delta: &SVector<Real, 5>) -> Self {
        let a = self.a + self.e1 * delta[0] + self.e2 * delta[1];
        let v = rotate(&self.v, &(self.e1 * delta[2] + self.e2 * delta[3]));
        Self::new(a, v, self.r + delta[4], self.pivot)
    }

    fn to_length(scale: Real) -> SVector<Real, 5> {
        SVector::<Real, 5>::new(1.0, 1.0, scale, scale, 1.0)
    }
}

/// Orthogonal least-squares cylinder: minimises Σ(dᵢ − r)² with dᵢ the distance of point i
/// from the axis.
///
/// Needs at least 5 finite, non-collinear points. `initial_axis`, if given, is the
/// starting axis direction; otherwise each principal axis of the points' covariance is
/// tried (a Kåsa circle of the points projected along it) and the best is refined by
/// Levenberg–Marquardt. Arcs of less than about 90° are poorly conditioned: the fit
/// converges but `radius_sigma_mm` and `axis_point_sigma_mm` grow steeply. Deterministic
/// and bit-identical for any thread count.
pub fn fit_cylinder(
    points: &[Point3],
    initial_axis: Option<UnitVector3>,
) -> Result<CylinderFit, FitError> {
    check_input(points, CYLINDER_MIN_POINTS)?;
    cylinder_checked(points, initial_axis, None)
}

/// Cylinder fit with iterative outlier rejection (see [`RobustRule`]); each refit starts
/// from the previous fit.
///
/// Errors as [`fit_cylinder`] on the full set; once an initial fit exists it never fails.
/// `n_used + n_rejected == points.len()`.
pub fn fit_cylinder_robust(
    points: &[Point3],
    initial_axis: Option<UnitVector3>,
    rule: &RobustRule,
) -> Result<CylinderFit, FitError> {
    let fit = fit_cylinder(points, initial_axis)?;
    Ok(trim_and_refit(points, rule, fit, |subset, prev| {
        cylinder_checked(subset, None, Some(prev))
    }))
}

/// The cylinder fit proper; points finite and at least 5.
fn cylinder_checked(
    points: &[Point3],
    initial_axis: Option<UnitVector3>,
    warm: Option<&CylinderFit>,
) -> Result<CylinderFit, FitError> {
    let sp = Spread::of(points)?;
    if sp.collinear() {
        return Err(FitError::Degenerate);
    }
    let start = match warm {
        Some(f) => CylinderModel::new(f.axis_point, f.axis, f.radius, sp.centroid),
        None => match initial_axis {
            Some(axis) => best_axis(points, &sp, &[axis]),
            None => best_axis(points, &sp, &sp.axes),
        }
        .ok_or(FitError::Degenerate)?,
    };
    let sol = levenberg_marquardt(points, start, sp.rms)?;
    let m = sol.model;
    if !(m.r > 0.0 && m.r.is_finite()) {
        return Err(FitError::Degenerate);
    }
    // axis_point = a + δ0 e1 + δ1 e2 + ((g − a)·(δ2 e1 + δ3 e2)) v to first order.
    let axis_point_sigma_mm = match sol.covariance {
        Some(c) => {
            let off = m.pivot - m.a;
            let v = m.v.into_inner();
            let g = SMatrix::<Real, 3, 5>::from_columns(&[
                m.e1,
                m.e2,
                v * off.dot(&m.e1),
                v * off.dot(&m.e2),
                Vector3::zeros(),
            ]);
            let ca = g * c * g.transpose();
            [0, 1, 2].map(|k| ca[(k, k)].max(0.0).sqrt())
        }
        None => [Real::INFINITY; 3],
    };
    let axis = UnitVector3::new_unchecked(canonical_sign(m.v.into_inner()));
    Ok(CylinderFit {
        axis_point: m.a,
        axis,
        radius: m.r,
        axis_point_sigma_mm,
        axis_sigma_rad: sol.sigma_pair(2),
        radius_sigma_mm: sol.sigma(4),
        rms_mm: sol.rms(),
        max_abs_mm: sol.normal.max_abs,
        n_used: points.len(),
        n_rejected: 0,
        iterations: sol.iterations,
    })
}

/// For each candidate (centre, axis w, radius): the RMS over the points of (distance from
/// the line centre + t·w) − r; one pass for all K, +∞ for a missing candidate.
fn line_circle_rms<const K: usize>(
    points: &[Point3],
    ws: &[UnitVector3; K],
    circles: &[Option<(Point3, Real)>; K],
) -> [Real; K] {
    let ss = chunked_sum(
        points,
        |c| {
            let mut acc = [0.0; K];
            for p in c {
                for ((a, w), circle) in acc.iter_mut().zip(ws).zip(circles) {
                    if let Some((centre, r)) = circle {
                        let d = p - centre;
                        let res = (d - w.into_inner() * w.dot(&d)).norm() - r;
                        *a += res * res;
                    }
                }
            }
            acc
        },
        [0.0; K],
        |mut t, o| {
            for (a, b) in t.iter_mut().zip(o) {
                *a += b;
            }
            t
        },
    );
    let mut out = [Real::INFINITY; K];
    for ((o, s), circle) in out.iter_mut().zip(ss).zip(circles) {
        if circle.is_some() {
            *o = (s / points.len() as Real).sqrt();
        }
    }
    out
}

/// The best cylinder start among candidate axes `ws`: smallest RMS of the Kåsa circle of
/// the points projected along the axis.
pub(super) fn best_axis<const K: usize>(
    points: &[Point3],
    sp: &Spread,
    ws: &[UnitVector3; K],
) -> Option<CylinderModel> {
    let circles = kasa_circles(points, sp, ws);
    let rms = line_circle_rms(points, ws, &circles);
    let mut best: Option<(Real, CylinderModel)> = None;
    for ((w, circle), e) in ws.iter().zip(&circles).zip(rms) {
        if let Some((c, r)) = circle
            && e.is_finite()
            && best.is_none_or(|(b, _)| e < b)
        {
            best = Some((e, CylinderModel::new(*c, *w, *r, sp.centroid)));
        }
    }
    best.map(|(_, m)| m)
}

impl Trimmable for CylinderFit {
    const MIN_POINTS: usize = CYLINDER_MIN_POINTS;
    fn rms(&self) -> Real {
        self.rms_mm
    }
    fn distance(&self, p: &Point3) -> Real {
        let d = p - self.axis_point;
        let w = d - self.axis.into_inner() * self.axis.dot(&d);
        (w.norm() - self.radius).abs()
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
    use crate::math::CounterRng;
    use std::f64::consts::{PI, TAU};

    #[test]
    fn exact_cylinders_in_random_poses() {
        for seed in 0..24u64 {
            let s = shape(seed);
            let length = s.radius * (0.5 + 4.0 * CounterRng::new(seed).uniform(1, 7));
            // Five points admit up to six cylinders: exact recovery needs more.
            let count = 50 + (seed as usize * 2131) % 12_000;
            let pts = s.cylinder(count, arc_for(seed), length, 0.0, 0);
            // Every other case with a caller's starting axis 0.05 rad off the truth.
            let initial = (seed % 2 == 1).then(|| rotate(&s.axis, &(s.a * 0.05)));
            let fit = fit_cylinder(&pts, initial).unwrap_or_else(|e| panic!("seed {seed}: {e}"));
            let r = s.radius;
            let dp = (fit.axis_point - s.foot(&pts)).norm() / r;
            let dr = (fit.radius - r).abs() / r;
            let dv = angle(&fit.axis, &s.axis);
            assert!(
                dp <= EXACT_REL && dr <= EXACT_REL && dv <= EXACT_REL,
                "seed {seed}: {dp:e} {dr:e} {dv:e}"
            );
            assert!(fit.rms_mm <= 1e-11 * r && fit.max_abs_mm <= 1e-10 * r);
            assert!(fit.axis[fit.axis.iamax()] > 0.0);
            assert_eq!((fit.n_used, fit.n_rejected), (count, 0));
        }
    }

    #[test]
    fn cylinder_uncertainties_match_monte_carlo() {
        for (name, s, arc, length, count) in [
            (
                "full cylinder",
                shape(105).with_radius(10.0),
                TAU,
                40.0,
                600,
            ),
            ("180° cylinder", shape(106).with_radius(15.0), PI, 30.0, 800),
        ] {
            let mut t: [Tally; 4] = Default::default();
            let mut tilts = vec![];
            let mut s_tilt = [0.0; 2];
            for trial in 0..TRIALS {
                let pts = s.cylinder(count, arc, length, NOISE, 30_000 + trial);
                let f = fit_cylinder(&pts, None).expect("fit");
                let foot = s.foot(&pts);
                for (k, tk) in t.iter_mut().take(3).enumerate() {
                    tk.push(f.axis_point[k] - foot[k], f.axis_point_sigma_mm[k]);
                }
                t[3].push(f.radius - s.radius, f.radius_sigma_mm);
                tilts.push(s.tilt(&f.axis));
                for (acc, sigma) in s_tilt.iter_mut().zip(f.axis_sigma_rad) {
                    *acc += sigma / TRIALS as Real;
                }
            }
            for (k, q) in ["point x", "point y", "point z", "radius"]
                .iter()
                .enumerate()
            {
                t[k].check(&format!("{name} {q}"));
            }
            check_tilts(name, &tilts, s_tilt);
        }
    }

    #[test]
    fn robust_cylinder_rejects_gross_outliers() {
        let s = shape(203).with_radius(12.0);
        let count = 20_000;
        let clean = s.cylinder(count, TAU, 50.0, NOISE, 7);
        let (dirty, n_out) = contaminate(&clean, |p| {
            let d = p - s.centre;
            (d - s.axis.into_inner() * s.axis.dot(&d)).normalize()
        });
        let plain = fit_cylinder(&dirty, None).expect("plain");
        let f = fit_cylinder_robust(&dirty, None, &RobustRule::default()).expect("robust");
        check_rejections(f.n_rejected, f.n_used, n_out, count);
        // The axis point is the foot of the used points' centroid: compare its offset from
        // the true axis.
        let v = s.axis.into_inner();
        let off = f.axis_point - s.centre;
        let off = off - v * v.dot(&off);
        for k in 0..3 {
            within("axis point", off[k], f.axis_point_sigma_mm[k]);
        }
        within("radius", f.radius - s.radius, f.radius_sigma_mm);
        let t = s.tilt(&f.axis);
        within(
            "axis",
            t[0].hypot(t[1]),
            f.axis_sigma_rad[0].hypot(f.axis_sigma_rad[1]),
        );
        assert!(f.rms_mm < 0.03 && plain.rms_mm > 0.15);
    }
}
