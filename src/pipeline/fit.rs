//! `fit`: shapes in any point cloud — every planar face with the distances and angles
//! between near-parallel pairs, or one plane, sphere, cylinder or circle in a selection.

use super::PipelineError;
use crate::math::Aabb;
use crate::math::{Point3, Real};
use crate::metrology::cloud::PointCloud;
use crate::metrology::fit::{
    RobustRule, fit_circle, fit_circle_robust, fit_cylinder, fit_cylinder_robust, fit_plane,
    fit_plane_robust, fit_sphere, fit_sphere_robust, plane_distance_and_angle,
};
use crate::metrology::segment::{
    PlaneSegmentOptions, RansacOptions, estimate_normals, ransac_cylinder, ransac_sphere,
    segment_planes, select_box, select_region_from_seed,
};
use crate::report::{
    CircleReport, CylinderReport, FitFileReport, PlanePair, PlaneReport, SphereReport,
};

/// Which shape [`fit_cloud`] looks for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Shape {
    /// Every planar face (segmentation), with the distance and angle between each pair.
    Planes,
    /// One plane through the selection.
    Plane,
    /// One sphere.
    Sphere,
    /// One cylinder.
    Cylinder,
    /// One circle in 3-D.
    Circle,
}

/// Which points [`fit_cloud`] uses.
#[derive(Clone, Debug, PartialEq)]
pub enum Selection {
    /// All of them.
    All,
    /// Those inside a box.
    Box(Aabb),
    /// The planar region grown from the point nearest this one.
    Seed(Point3),
}

/// A request to [`fit_cloud`].
#[derive(Clone, Debug, PartialEq)]
pub struct FitRequest {
    /// The shape.
    pub shape: Shape,
    /// The points.
    pub selection: Selection,
    /// Outlier rejection (σ trimming) on the final least-squares fit.
    pub robust: bool,
    /// Segmentation settings (planes, seed regions).
    pub segment: PlaneSegmentOptions,
    /// RANSAC settings (a sphere or cylinder in an unselected cloud).
    pub ransac: RansacOptions,
    /// Neighbours for normal estimation (cylinders).
    pub normal_neighbours: usize,
}

/// Planes closer than this to parallel (rad, 10°) get a distance as well as an angle.
const PARALLEL_RAD: Real = 0.1745;

/// Fits shapes to any cloud — the library behind `twinmill fit`.
pub fn fit_cloud(
    cloud: &PointCloud,
    req: &FitRequest,
    source: &str,
) -> Result<FitFileReport, PipelineError> {
    let err = |message: String| PipelineError::Measure {
        path: source.to_string(),
        message,
    };
    let pts = &cloud.points;
    let selected: Vec<Point3> = match &req.selection {
        Selection::All => pts.clone(),
        Selection::Box(b) => select_box(pts, &b.min, &b.max)
            .iter()
            .map(|&i| pts[i as usize])
            .collect(),
        Selection::Seed(p) => select_region_from_seed(pts, p, &req.segment)
            .map_err(|e| err(e.to_string()))?
            .indices
            .iter()
            .map(|&i| pts[i as usize])
            .collect(),
    };
    let rule = RobustRule::default();
    let mut report = FitFileReport {
        cloud: source.to_string(),
        points: pts.len(),
        selected: selected.len(),
        planes: Vec::new(),
        pairs: Vec::new(),
        sphere: None,
        cylinder: None,
        circle: None,
    };
    // RANSAC first on an unselected cloud: the shape is somewhere in it.
    let candidates = |found: Result<Vec<u32>, SearchError>| -> Result<Vec<Point3>, PipelineError> {
        let idx = found.map_err(|e| err(e.to_string()))?;
        Ok(idx.iter().map(|&i| selected[i as usize]).collect())
    };
    match req.shape {
        Shape::Planes => {
            let segs = segment_planes(&selected, &req.segment).map_err(|e| err(e.to_string()))?;
            report.planes = segs.iter().map(|s| PlaneReport::of(&s.fit)).collect();
            for (i, a) in segs.iter().enumerate() {
                for (j, b) in segs.iter().enumerate().skip(i + 1) {
                    let at = Point3::from((a.fit.centroid.coords + b.fit.centroid.coords) / 2.0);
                    if let Some((distance_mm, angle_rad)) =
                        plane_distance_and_angle(&a.fit.plane, &b.fit.plane, &at)
                    {
                        report.pairs.push(PlanePair {
                            planes: [i, j],
                            distance_mm: (angle_rad < PARALLEL_RAD).then_some(distance_mm),
                            angle_rad,
                        });
                    }
                }
            }
        }
        Shape::Plane => {
            let fit = if req.robust {
                fit_plane_robust(&selected, &rule)
            } else {
                fit_plane(&selected)
            };
            report.planes = vec![PlaneReport::of(&fit.map_err(|e| err(e.to_string()))?)];
        }
        Shape::Sphere => {
            let pts = match req.selection {
                Selection::All => candidates(
                    ransac_sphere(&selected, &req.ransac)
                        .map(|m| m.inliers)
                        .map_err(|e| nothing_found(e, "sphere", &selected, &req.ransac)),
                )?,
                _ => selected.clone(),
            };
            let fit = if req.robust {
                fit_sphere_robust(&pts, &rule)
            } else {
                fit_sphere(&pts)
            };
            report.sphere = Some(SphereReport::of(&fit.map_err(|e| err(e.to_string()))?));
        }
        Shape::Cylinder => {
            let normals = estimate_normals(&selected, req.normal_neighbours, None)
                .map_err(|e| err(e.to_string()))?;
            let found = ransac_cylinder(&selected, &normals, &req.ransac)
                .map_err(|e| nothing_found(e, "cylinder", &selected, &req.ransac))
                .map_err(|e| err(e.to_string()))?;
            let axis = found.model.axis;
            let pts = candidates(Ok(found.inliers))?;
            let fit = if req.robust {
                fit_cylinder_robust(&pts, Some(axis), &rule)
            } else {
                fit_cylinder(&pts, Some(axis))
            };
            report.cylinder = Some(CylinderReport::of(&fit.map_err(|e| err(e.to_string()))?));
        }
        Shape::Circle => {
            let fit = if req.robust {
                fit_circle_robust(&selected, &rule)
            } else {
                fit_circle(&selected)
            };
            report.circle = Some(CircleReport::of(&fit.map_err(|e| err(e.to_string()))?));
        }
    }
    Ok(report)
}

/// Why a RANSAC search failed, in words that say what the points are and what the search
/// needed (`SegmentError::NothingFound` alone says nothing of either).
#[derive(Debug)]
struct SearchError(String);

impl std::fmt::Display for SearchError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

fn nothing_found(
    e: crate::metrology::segment::SegmentError,
    shape: &str,
    points: &[Point3],
    opts: &crate::metrology::segment::RansacOptions,
) -> SearchError {
    use crate::metrology::segment::SegmentError;
    if e != SegmentError::NothingFound {
        return SearchError(e.to_string());
    }
    let n = points.len();
    // RMS distance from the points' best plane: the smallest principal spread
    let thickness = if n >= 3 {
        let mean = points
            .iter()
            .fold(crate::math::Vector3::zeros(), |a, p| a + p.coords)
            / n as Real;
        let cov = points
            .iter()
            .fold(nalgebra::Matrix3::<Real>::zeros(), |a, p| {
                let d = p.coords - mean;
                a + d * d.transpose()
            })
            / n as Real;
        cov.symmetric_eigenvalues().min().max(0.0).sqrt()
    } else {
        0.0
    };
    if n >= 3 && thickness <= opts.distance_mm {
        SearchError(format!(
            "no {shape} found: the {n} points lie in one plane (RMS {thickness:.3e} mm off it, \
             within the {} mm tolerance), expected points on a {shape}, off any one plane",
            opts.distance_mm
        ))
    } else {
        SearchError(format!(
            "no {shape} found: none holds {} of the {n} points within {} mm (--distance), \
             expected points on a {shape}",
            opts.min_inliers, opts.distance_mm
        ))
    }
}
