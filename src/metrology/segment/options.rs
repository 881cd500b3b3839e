//! What planar segmentation is asked and what it returns: the options
//! ([`PlaneSegmentOptions`], checked by `check_plane_options`) of [`segment_planes`](super::segment_planes) and
//! [`select_region_from_seed`](super::select_region_from_seed), and a segment ([`PlaneSegment`]).

use super::input::SegmentError;
use crate::math::Real;
use crate::metrology::fit::{PlaneFit, RobustRule};

#[cfg(doc)]
use crate::metrology::fit::fit_plane_robust;

/// Options of [`segment_planes`](super::segment_planes) and [`select_region_from_seed`](super::select_region_from_seed).
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

/// One planar face found by [`segment_planes`](super::segment_planes) or [`select_region_from_seed`](super::select_region_from_seed).
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
