//! What every entry point shares: the limits on the input ([`MAX_COORD_MM`],
//! [`MAX_POINTS`]), the error type ([`SegmentError`]), the check of the points with their
//! bounding box in one pass, and folds and gathers over fixed chunks of points (so results
//! do not depend on the thread count).

use crate::math::{Aabb, Point3, Real};
use crate::metrology::fit::CHUNK;
use rayon::prelude::*;

#[cfg(doc)]
use super::{segment_planes, select_region_from_seed};

/// Largest coordinate magnitude accepted (mm): 1,000 km. No scanner measures beyond it;
/// squared distances of larger coordinates lose the µm digits, and the k-d tree reserves
/// the largest finite value as a sentinel.
pub const MAX_COORD_MM: Real = 1e9;

/// Most points a cloud may have: indices are stored as `u32` (4 bytes instead of 8 per
/// index keeps the cell lists of a 1.3 M-point scan in cache).
pub const MAX_POINTS: usize = u32::MAX as usize;

/// Fewest points an orthogonal plane fit accepts.
pub(super) const PLANE_FIT_MIN: usize = 3;

/// Why a neighbourhood, normal, segmentation or RANSAC query could not be answered.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SegmentError {
    /// The point set is empty.
    #[error("no points")]
    NoPoints,
    /// A point has a NaN or infinite coordinate — or, except for [`segment_planes`] and
    /// [`select_region_from_seed`] (whose grid limit refuses such clouds), one beyond
    /// ±[`MAX_COORD_MM`].
    #[error("point {index} has a non-finite coordinate (or one beyond ±1e9 mm)")]
    NonFinite {
        /// Index of the first offending point.
        index: usize,
    },
    /// The points hold nothing of what was asked: no planar region of `min_points`, fewer
    /// RANSAC inliers than `min_inliers`, or too few points for the model at all.
    #[error("nothing found")]
    NothingFound,
    /// Options (or the input's size) that cannot be used; the message says why and what to
    /// change.
    #[error("bad options: {0}")]
    BadOptions(String),
}

pub(super) fn is_valid(p: &Point3) -> bool {
    // NaN fails the comparison.
    p.coords.iter().all(|c| c.abs() <= MAX_COORD_MM)
}

/// Checks the points (non-empty, at most [`MAX_POINTS`], all valid) and returns their
/// bounding box, in one parallel pass over fixed chunks.
pub(super) fn check_and_bound(points: &[Point3]) -> Result<Aabb, SegmentError> {
    if points.is_empty() {
        return Err(SegmentError::NoPoints);
    }
    if points.len() > MAX_POINTS {
        return Err(SegmentError::BadOptions(format!(
            "{} points: at most {MAX_POINTS} are supported",
            points.len()
        )));
    }
    let parts: Vec<(Option<usize>, Aabb)> = points
        .par_chunks(CHUNK)
        .enumerate()
        .map(|(ci, chunk)| {
            let mut b = Aabb::empty();
            for (j, p) in chunk.iter().enumerate() {
                if !is_valid(p) {
                    return (Some(ci * CHUNK + j), b);
                }
                b.grow(p);
            }
            (None, b)
        })
        .collect();
    let mut bbox = Aabb::empty();
    for (bad, b) in parts {
        if let Some(index) = bad {
            return Err(SegmentError::NonFinite { index });
        }
        bbox.grow(&b.min);
        bbox.grow(&b.max);
    }
    Ok(bbox)
}

/// Sum of `f` over fixed chunks of `0..n`, combined in chunk order (thread-count
/// independent).
pub(super) fn chunked_fold<T, F, G>(n: usize, zero: T, f: F, add: G) -> T
where
    T: Send,
    F: Fn(std::ops::Range<usize>) -> T + Sync + Send,
    G: Fn(T, T) -> T,
{
    let parts: Vec<T> = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| f(c * CHUNK..((c + 1) * CHUNK).min(n)))
        .collect();
    parts.into_iter().fold(zero, add)
}

pub(super) fn gather(points: &[Point3], idx: &[u32]) -> Vec<Point3> {
    idx.par_iter()
        .filter_map(|&i| points.get(i as usize).copied())
        .collect()
}
