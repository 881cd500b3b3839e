//! What `twinmill fit` reports: fitted planes and the pairs of near-parallel planes,
//! spheres, cylinders and circles, with their uncertainties.

use serde::Serialize;
use std::fmt::Write as _;

fn arr(v: &crate::math::Vector3) -> [f64; 3] {
    [v.x, v.y, v.z]
}

/// A fitted plane, as `twinmill fit` reports it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PlaneReport {
    /// Unit normal.
    pub normal: [f64; 3],
    /// normal · x = offset (mm).
    pub offset_mm: f64,
    /// Centroid of the points used (mm).
    pub centroid_mm: [f64; 3],
    /// Points used and rejected.
    pub points: [usize; 2],
    /// RMS and largest absolute residual (mm).
    pub rms_mm: f64,
    /// Largest absolute residual (mm).
    pub max_abs_mm: f64,
    /// Standard uncertainty of the offset at the centroid (mm).
    pub offset_sigma_mm: f64,
    /// Standard uncertainties of the normal's tilt about the in-plane principal axes (rad).
    pub tilt_sigma_rad: [f64; 2],
}

impl PlaneReport {
    /// From a fit.
    pub fn of(f: &crate::metrology::fit::PlaneFit) -> Self {
        Self {
            normal: arr(&f.plane.normal),
            offset_mm: f.plane.offset,
            centroid_mm: arr(&f.centroid.coords),
            points: [f.n_used, f.n_rejected],
            rms_mm: f.rms_mm,
            max_abs_mm: f.max_abs_mm,
            offset_sigma_mm: f.offset_sigma_mm,
            tilt_sigma_rad: f.tilt_sigma_rad,
        }
    }
}

/// Distance and angle between two fitted planes, the way seed 002 reports them.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PlanePair {
    /// Indices into the plane list.
    pub planes: [usize; 2],
    /// Signed distance from the first to the second along the first's normal, through the
    /// midpoint of their centroids (mm); only for planes within 10° of parallel, where a
    /// distance means something.
    pub distance_mm: Option<f64>,
    /// Angle between the normals (rad).
    pub angle_rad: f64,
}

/// A fitted sphere.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SphereReport {
    /// Centre (mm) and its standard uncertainties.
    pub centre_mm: [f64; 3],
    /// Standard uncertainties of the centre (mm).
    pub centre_sigma_mm: [f64; 3],
    /// Radius and its standard uncertainty (mm).
    pub radius_mm: [f64; 2],
    /// Points used and rejected.
    pub points: [usize; 2],
    /// RMS residual (mm).
    pub rms_mm: f64,
}

impl SphereReport {
    /// From a fit.
    pub fn of(f: &crate::metrology::fit::SphereFit) -> Self {
        Self {
            centre_mm: arr(&f.centre.coords),
            centre_sigma_mm: f.centre_sigma_mm,
            radius_mm: [f.radius, f.radius_sigma_mm],
            points: [f.n_used, f.n_rejected],
            rms_mm: f.rms_mm,
        }
    }
}

/// A fitted cylinder.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CylinderReport {
    /// The axis point nearest the points' centroid (mm).
    pub axis_point_mm: [f64; 3],
    /// Its standard uncertainties (mm).
    pub axis_point_sigma_mm: [f64; 3],
    /// Unit axis direction.
    pub axis: [f64; 3],
    /// Standard uncertainties of the axis tilt (rad).
    pub axis_sigma_rad: [f64; 2],
    /// Radius and its standard uncertainty (mm).
    pub radius_mm: [f64; 2],
    /// Points used and rejected.
    pub points: [usize; 2],
    /// RMS residual (mm).
    pub rms_mm: f64,
}

impl CylinderReport {
    /// From a fit.
    pub fn of(f: &crate::metrology::fit::CylinderFit) -> Self {
        Self {
            axis_point_mm: arr(&f.axis_point.coords),
            axis_point_sigma_mm: f.axis_point_sigma_mm,
            axis: arr(&f.axis),
            axis_sigma_rad: f.axis_sigma_rad,
            radius_mm: [f.radius, f.radius_sigma_mm],
            points: [f.n_used, f.n_rejected],
            rms_mm: f.rms_mm,
        }
    }
}

/// A fitted circle in 3-D.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CircleReport {
    /// Centre (mm).
    pub centre_mm: [f64; 3],
    /// Its standard uncertainties (mm).
    pub centre_sigma_mm: [f64; 3],
    /// Unit normal of the circle's plane, and its tilt uncertainty (rad) as a fourth number.
    pub normal: [f64; 4],
    /// Radius and its standard uncertainty (mm).
    pub radius_mm: [f64; 2],
    /// Points used and rejected.
    pub points: [usize; 2],
    /// RMS residual (mm).
    pub rms_mm: f64,
}

impl CircleReport {
    /// From a fit.
    pub fn of(f: &crate::metrology::fit::CircleFit) -> Self {
        Self {
            centre_mm: arr(&f.centre.coords),
            centre_sigma_mm: f.centre_sigma_mm,
            normal: [f.normal.x, f.normal.y, f.normal.z, f.normal_sigma_rad],
            radius_mm: [f.radius, f.radius_sigma_mm],
            points: [f.n_used, f.n_rejected],
            rms_mm: f.rms_mm,
        }
    }
}

/// What `twinmill fit` reports.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FitFileReport {
    /// The cloud file.
    pub cloud: String,
    /// Points in the cloud.
    pub points: usize,
    /// Points selected.
    pub selected: usize,
    /// Fitted planes (largest first for segmentation).
    pub planes: Vec<PlaneReport>,
    /// Distance and angle between each pair of planes.
    pub pairs: Vec<PlanePair>,
    /// A fitted sphere.
    pub sphere: Option<SphereReport>,
    /// A fitted cylinder.
    pub cylinder: Option<CylinderReport>,
    /// A fitted circle.
    pub circle: Option<CircleReport>,
}

impl FitFileReport {
    /// The short human summary.
    pub fn summary(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "twinmill fit: {} — {} points, {} selected",
            self.cloud, self.points, self.selected
        );
        for (i, p) in self.planes.iter().enumerate() {
            let n = p.normal;
            let _ = writeln!(
                s,
                "  plane {i}: n = ({:+.6}, {:+.6}, {:+.6}), offset {:+.5} ± {:.5} mm, {} points, rms {:.4} mm",
                n[0], n[1], n[2], p.offset_mm, p.offset_sigma_mm, p.points[0], p.rms_mm
            );
        }
        for p in &self.pairs {
            let (a, b) = (p.planes[0], p.planes[1]);
            let _ = match p.distance_mm {
                Some(d) => writeln!(
                    s,
                    "  planes {a}–{b}: distance {d:+.5} mm, angle {:.2} µrad",
                    p.angle_rad * 1e6
                ),
                None => writeln!(
                    s,
                    "  planes {a}–{b}: angle {:.4}°",
                    p.angle_rad.to_degrees()
                ),
            };
        }
        if let Some(c) = &self.sphere {
            let _ = writeln!(
                s,
                "  sphere: centre ({:.5}, {:.5}, {:.5}) mm, radius {:.5} ± {:.5} mm, rms {:.4} mm",
                c.centre_mm[0],
                c.centre_mm[1],
                c.centre_mm[2],
                c.radius_mm[0],
                c.radius_mm[1],
                c.rms_mm
            );
        }
        if let Some(c) = &self.cylinder {
            let _ = writeln!(
                s,
                "  cylinder: axis through ({:.5}, {:.5}, {:.5}) along ({:+.6}, {:+.6}, {:+.6}), radius {:.5} ± {:.5} mm, rms {:.4} mm",
                c.axis_point_mm[0],
                c.axis_point_mm[1],
                c.axis_point_mm[2],
                c.axis[0],
                c.axis[1],
                c.axis[2],
                c.radius_mm[0],
                c.radius_mm[1],
                c.rms_mm
            );
        }
        if let Some(c) = &self.circle {
            let _ = writeln!(
                s,
                "  circle: centre ({:.5}, {:.5}, {:.5}) mm, radius {:.5} ± {:.5} mm, rms {:.4} mm",
                c.centre_mm[0],
                c.centre_mm[1],
                c.centre_mm[2],
                c.radius_mm[0],
                c.radius_mm[1],
                c.rms_mm
            );
        }
        s
    }
}
