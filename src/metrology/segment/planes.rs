//! Planar segmentation of a whole cloud: its options ([`PlaneSegmentOptions`]), its
//! result ([`PlaneSegment`]) and [`segment_planes`], which runs the five steps of the
//! module documentation (`cells`, `grow`, `assign`, `region_fit`).

use super::cells::Cells;
use super::grow::LivePlane;
use super::input::{PLANE_FIT_MIN, SegmentError};
use super::region_fit::fit_regions;
use crate::math::{Point3, Real};
use crate::metrology::fit::{PlaneFit, RobustRule};

#[cfg(doc)]
use super::cells::MAX_GRID_CELLS;
#[cfg(doc)]
use super::select::select_region_from_seed;
#[cfg(doc)]
use crate::metrology::fit::fit_plane_robust;

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

pub(super) fn check_plane_options(opts: &PlaneSegmentOptions) -> Result<(), SegmentError> {
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

#[cfg(test)]
mod tests {
    use super::super::tests::{SIGMA, check_step, majority, step_cloud, step_opts, tilted_pose};
    use super::*;
    use crate::math::Isometry3;

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
}
