//! `twinmill fit`: shapes fitted to any point cloud.

use super::{fail, print_out, set_threads};
use std::path::PathBuf;
use std::process::ExitCode;
use twinmill::math::{Aabb, Point3};
use twinmill::metrology::cloud::read_cloud_file;
use twinmill::metrology::segment::{PlaneSegmentOptions, RansacOptions};
use twinmill::pipeline::{FitRequest, Selection, Shape, fit_cloud};

/// Fit planes, a sphere, cylinder or circle to any point cloud.
///
/// Fit shapes to any point cloud (PLY, XYZ/CSV, PTS): every planar face with the distance
/// and angle between each pair (the default), or one plane, sphere, cylinder or circle, in
/// all points, a box, or the planar region around a seed point.
#[derive(clap::Args)]
pub struct FitArgs {
    /// The cloud file.
    cloud: PathBuf,
    /// Every planar face (segmentation) with pairwise distances and angles.
    #[arg(long, group = "shape")]
    planes: bool,
    /// One plane through the selected points.
    #[arg(long, group = "shape")]
    plane: bool,
    /// One sphere (found by RANSAC when nothing is selected).
    #[arg(long, group = "shape")]
    sphere: bool,
    /// One cylinder (found by RANSAC on estimated normals).
    #[arg(long, group = "shape")]
    cylinder: bool,
    /// One circle in 3-D through the selected points.
    #[arg(long, group = "shape")]
    circle: bool,
    /// Use only points in this box: xmin,ymin,zmin,xmax,ymax,zmax (mm).
    #[arg(
        long = "box",
        value_name = "X0,Y0,Z0,X1,Y1,Z1",
        value_delimiter = ',',
        num_args = 1,
        conflicts_with = "seed",
        allow_hyphen_values = true
    )]
    bbox: Option<Vec<f64>>,
    /// Use the planar region grown around the point nearest to x,y,z (mm).
    #[arg(
        long,
        value_name = "X,Y,Z",
        value_delimiter = ',',
        num_args = 1,
        allow_hyphen_values = true
    )]
    seed: Option<Vec<f64>>,
    /// Reject outliers (iterative 3σ trimming) in the final fit.
    #[arg(long)]
    robust: bool,
    /// Segmentation cell edge (mm).
    #[arg(long, default_value_t = 1.0)]
    cell: f64,
    /// Largest point-to-surface distance of a member or RANSAC inlier (mm).
    #[arg(long, default_value_t = 0.1)]
    distance: f64,
    /// Print the result as JSON.
    #[arg(long)]
    json: bool,
    /// Worker threads (default: all cores). Results do not depend on it.
    #[arg(long)]
    threads: Option<usize>,
}

/// `twinmill fit`.
pub fn exec(a: FitArgs) -> ExitCode {
    if let Err(code) = set_threads(a.threads) {
        return code;
    }
    let selection = match (a.bbox, a.seed) {
        (Some(b), _) if b.len() != 6 => {
            return fail("--box needs six numbers: x0,y0,z0,x1,y1,z1");
        }
        (Some(b), _) => match (finite_point(&b[..3], "box"), finite_point(&b[3..], "box")) {
            (Ok(min), Ok(max)) if (0..3).all(|k| min[k] < max[k]) => {
                Selection::Box(Aabb { min, max })
            }
            (Err(e), _) | (_, Err(e)) => return fail(e),
            _ => return fail("--box: each min must be below its max"),
        },
        (None, Some(p)) => match finite_point(&p, "seed") {
            Ok(p) => Selection::Seed(p),
            Err(e) => return fail(e),
        },
        (None, None) => Selection::All,
    };
    let shape = if a.plane {
        Shape::Plane
    } else if a.sphere {
        Shape::Sphere
    } else if a.cylinder {
        Shape::Cylinder
    } else if a.circle {
        Shape::Circle
    } else {
        // `--planes`, or nothing: every planar face.
        let _ = a.planes;
        Shape::Planes
    };
    let points = match read_cloud_file(&a.cloud) {
        Ok(c) => c,
        Err(e) => return fail(e),
    };
    let request = FitRequest {
        shape,
        selection,
        robust: a.robust,
        segment: PlaneSegmentOptions {
            cell_mm: a.cell,
            max_distance_mm: a.distance,
            ..PlaneSegmentOptions::default()
        },
        ransac: RansacOptions {
            distance_mm: a.distance,
            iterations: 2000,
            seed: 1,
            min_inliers: 10,
        },
        normal_neighbours: 12,
    };
    let report = match fit_cloud(&points, &request, &a.cloud.display().to_string()) {
        Ok(r) => r,
        Err(e) => return fail(e),
    };
    print_out(
        || report.summary(),
        a.json.then(|| serde_json::to_string_pretty(&report)),
    )
}

fn finite_point(v: &[f64], what: &str) -> Result<Point3, String> {
    match v {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok(Point3::new(*x, *y, *z)),
        _ => Err(format!("--{what} needs finite numbers")),
    }
}
