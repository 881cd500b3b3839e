//! Selections: the planar region at a seed point ([`select_region_from_seed`](super::select_region_from_seed): the steps
//! of [`segment_planes`](super::segment_planes) for the one region grown from the seed's cell) and the points in
//! an axis-aligned box ([`select_box`]).

use super::cells::Cells;
use super::grow::LivePlane;
use super::input::{SegmentError, chunked_fold, is_valid};
use super::options::{PlaneSegment, PlaneSegmentOptions};
use super::region_fit::fit_regions;
use crate::math::{Aabb, Point3, Real};
use rayon::prelude::*;

/// The planar region at `seed`: grown (as in [`segment_planes`](super::segment_planes)) from the cell holding the
/// point nearest `seed` — or, when that cell is not planar, from the neighbouring planar
/// cell whose plane passes nearest that point — then assigned and fitted alone (no other
/// region competes for edge points).
///
/// Errors: as [`segment_planes`](super::segment_planes); a non-finite seed is [`SegmentError::BadOptions`]; no
/// planar cell at the seed, or a region of fewer than `min_points` points, is
/// [`SegmentError::NothingFound`].
pub fn select_region_from_seed(
    points: &[Point3],
    seed: &Point3,
    opts: &PlaneSegmentOptions,
) -> Result<PlaneSegment, SegmentError> {
    if !is_valid(seed) {
        return Err(SegmentError::BadOptions(
            "the seed point is not finite".to_string(),
        ));
    }
    let cells = Cells::build(points, opts)?;
    let nearest = chunked_fold(
        points.len(),
        None,
        |r| {
            let mut best: Option<(Real, usize)> = None;
            for i in r {
                let d = (points[i] - seed).norm_squared();
                if best.is_none_or(|(bd, _)| d < bd) {
                    best = Some((d, i));
                }
            }
            best
        },
        |a, b| match (a, b) {
            (Some(x), Some(y)) => Some(if y.0 < x.0 { y } else { x }),
            (x, y) => x.or(y),
        },
    );
    let (_, i) = nearest.ok_or(SegmentError::NoPoints)?;
    let p = points[i];
    let c = cells.cell_of(&p).ok_or(SegmentError::NothingFound)?;
    let start = if cells.stats[c].planar {
        Some(c)
    } else {
        let mut best: Option<(Real, usize)> = None;
        for &b in cells.neighbours(c) {
            let s = &cells.stats[b as usize];
            if s.planar {
                let d = s.normal.dot(&(p - s.centroid)).abs();
                if best.is_none_or(|(bd, _)| d < bd) {
                    best = Some((d, b as usize));
                }
            }
        }
        best.map(|(_, b)| b)
    };
    let start = start.ok_or(SegmentError::NothingFound)?;
    let (region, accs) = cells.grow(&[start as u32], opts);
    let live: Vec<Option<LivePlane>> = accs
        .iter()
        .map(|a| a.live(opts.robust.k_sigma, &cells))
        .collect();
    let shares = cells.assign(points, &region, &live, opts.max_distance_mm);
    fit_regions(points, shares, &live, opts)
        .into_iter()
        .next()
        .ok_or(SegmentError::NothingFound)
}

/// Indices (ascending) of the points inside the box `[min, max]` (faces included). Points
/// with a NaN coordinate are never inside.
pub fn select_box(points: &[Point3], min: &Point3, max: &Point3) -> Vec<u32> {
    let b = Aabb {
        min: *min,
        max: *max,
    };
    points
        .par_iter()
        .enumerate()
        .filter(|(_, p)| b.contains(p))
        .filter_map(|(i, _)| u32::try_from(i).ok())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::super::tests::{SIGMA, line_angle, majority, step_cloud, step_opts};
    use super::*;
    use crate::math::{Isometry3, Vector3};

    #[test]
    fn seed_region_and_box() {
        let c = step_cloud(SIGMA, &Isometry3::identity());
        let opts = step_opts();
        // Near the middle of face B, a little off the surface.
        let seg = select_region_from_seed(&c.points, &Point3::new(20.0, 1.3, -5.0), &opts)
            .expect("region");
        assert_eq!(majority(&seg, &c.labels), 1);
        assert!(seg.indices.iter().all(|&i| c.labels[i as usize] != 0));
        let face_b = c.labels.iter().filter(|&&l| l == 1).count();
        assert!(seg.indices.len() * 100 >= face_b * 97);
        assert!(line_angle(&seg.fit.plane.normal, &Vector3::y()) < 1e-3);
        // Seed on the top face's edge cell still finds a planar neighbour.
        let top = select_region_from_seed(&c.points, &Point3::new(20.0, 0.0, 10.0), &opts)
            .expect("edge seed");
        assert!(matches!(majority(&top, &c.labels), 0 | 2));
        // A seed far away picks the nearest point's region.
        assert!(select_region_from_seed(&c.points, &Point3::new(1e6, 0.0, 0.0), &opts).is_ok());
        // Box: only points inside, in order.
        let (lo, hi) = (Point3::new(5.0, -1.0, 1.0), Point3::new(10.0, 0.5, 4.0));
        let sel = select_box(&c.points, &lo, &hi);
        let want: Vec<u32> = (0..c.points.len() as u32)
            .filter(|&i| {
                let p = c.points[i as usize];
                (0..3).all(|k| lo[k] <= p[k] && p[k] <= hi[k])
            })
            .collect();
        assert_eq!(sel, want);
        assert!(!sel.is_empty() && sel.iter().all(|&i| c.labels[i as usize] == 0));
        let mut with_nan = c.points.clone();
        with_nan[sel[0] as usize].x = Real::NAN;
        assert_eq!(select_box(&with_nan, &lo, &hi).len(), sel.len() - 1);
    }
}
