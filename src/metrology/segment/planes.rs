//! Planar segmentation of a whole cloud: [`segment_planes`], which checks its options
//! (`options`) and runs the five steps of the module documentation in order (`cells`,
//! `grow`, `assign`, `region_fit`).

use super::cells::Cells;
use super::grow::LivePlane;
use super::input::{PLANE_FIT_MIN, SegmentError};
use super::options::{PlaneSegment, PlaneSegmentOptions};
use super::region_fit::fit_regions;
use crate::math::Point3;

#[cfg(doc)]
use super::cells::MAX_GRID_CELLS;
#[cfg(doc)]
use super::select::select_region_from_seed;
#[cfg(doc)]
use crate::metrology::fit::fit_plane_robust;

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
