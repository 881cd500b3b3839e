//! Neighbourhoods, normals and segmentation of scanned point clouds (mm).
//!
//! * **Neighbourhoods.** [`KdIndex`] is a k-d tree over a cloud, built once, answering
//!   k-nearest-neighbour and radius queries. [`estimate_normals`] fits a plane (PCA) to each
//!   point's k nearest neighbours.
//! * **Planar segmentation of a whole cloud** ([`segment_planes`]) needs no per-point
//!   normals: it works on a uniform grid of cubic cells of edge `cell_mm`, centred on the
//!   cloud's first point.
//!   1. *Bin and sum* (one pass over the points). Each fixed chunk of points finds each
//!      point's cell and sums count, first and second moments per cell (about the cell
//!      centre) in a small hash table — consecutive points of a scan mostly share a cell,
//!      so runs are summed in registers. The chunks' sums are then added cell by cell in
//!      chunk order (cells numbered by first appearance), which is what makes every bit
//!      independent of the threads; a dense table over the grid's bounding box maps cells
//!      to their numbers.
//!   2. *Cell planes.* Each occupied cell's centred second moments give its plane: the
//!      eigenvector of the smallest eigenvalue λ₀ is the normal. A cell is *planar* when it
//!      holds at least [`MIN_CELL_POINTS`] points, its flatness λ₀/(λ₀+λ₁+λ₂) is at most
//!      [`MAX_CELL_FLATNESS`], its rms residual √(λ₀/n) is at most [`CELL_RMS_FRACTION`] of
//!      `max_distance_mm`, and its points spread in both in-plane directions (rms at least
//!      [`MIN_CELL_SPREAD_FRACTION`] of the cell edge), so its normal is determined.
//!   3. *Grow.* From the flattest unassigned planar cell, a region grows breadth-first over
//!      the 26 neighbouring cells. A planar neighbour b of region cell a joins when the two
//!      cell normals agree within `max_angle_rad`, the two cell planes are within
//!      `max_distance_mm` of each other at the midpoint of the cell centroids (the shared
//!      boundary), and b agrees with the region's own plane (normal within `max_angle_rad`,
//!      centroid within `max_distance_mm`). The region plane comes from the summed moments
//!      of its cells and is refreshed whenever the region doubles, so growth cannot creep
//!      round a curved surface. Regions whose planar cells hold fewer than `min_points`
//!      points are dissolved.
//!   4. *Assign* (second pass over the points). Every point of every cell — planar or not,
//!      such as cells across an edge or a step — goes to the nearest plane among the
//!      regions of its own and its 26 neighbouring cells, if that plane is within
//!      `max_distance_mm` (ties: the lower region number).
//!   5. *Fit.* Each region's points get the robust orthogonal fit of [`fit_plane_robust`]
//!      with the caller's [`RobustRule`] — its σ-trimming rounds replayed on moments, only
//!      the points near the threshold re-tested, then [`fit_plane`] on the set they settle
//!      on (see [`fit_plane_robust`]'s rule; equal to its result up to rounding). Regions
//!      with fewer than `min_points` points are dropped.
//!
//!   [`select_region_from_seed`] runs the same steps for the one region grown from the cell
//!   of the point nearest a seed.
//! * **RANSAC** ([`ransac_plane`], [`ransac_sphere`], [`ransac_cylinder`]) finds one shape
//!   in a (sub)set of points: minimal samples, scoring by inlier count, then rounds of
//!   least-squares refit and re-selection of the inliers.
//! * **Selection** ([`select_box`]) picks the points in an axis-aligned box.
//!
//! Invariant: every result depends only on the points, the options and the seed — never on
//! the rayon thread count or timing. Parallel work runs over fixed chunks (or per cell,
//! per point, per RANSAC iteration) and is combined in index order; floating-point sums
//! always run in one fixed order; RANSAC samples come from [`CounterRng`] keyed by
//! (seed, iteration). No input makes a function here panic: bad points or options are a
//! [`SegmentError`].
//!
//! The code, one idea a file: `input` (limits, [`SegmentError`], the check of the points,
//! fixed-chunk folds), `linalg` (moment sums and the symmetric 3 × 3 eigenproblem),
//! `neighbours` (the k-d tree and PCA normals), `options` (what segmentation is asked and
//! returns), then the steps of [`segment_planes`]: `cells` (1, 2: the grid, binning, cell
//! planes), `grow` (3: region growing), `assign` (4: points to planes), `region_fit` (5: the
//! robust fit of each region on moments); `select` (by seed point or box), `planes` (the
//! steps in order) and `ransac`. Each file uses only the files before it.

mod input;
mod linalg;
mod neighbours;
mod options;
mod cells;
mod grow;
mod assign;
mod region_fit;
mod select;
mod planes;
mod ransac;
#[cfg(test)]
mod tests;

pub use cells::{
    CELL_RMS_FRACTION, MAX_CELL_FLATNESS, MAX_GRID_CELLS, MIN_CELL_POINTS, MIN_CELL_SPREAD_FRACTION,
};
pub use input::{MAX_COORD_MM, MAX_POINTS, SegmentError};
pub use neighbours::{KdIndex, Neighbour, estimate_normals};
pub use options::{PlaneSegment, PlaneSegmentOptions};
pub use planes::segment_planes;
pub use ransac::{
    CylinderModel, MIN_SAMPLE_DET_RATIO, MIN_SAMPLE_SIN, RansacOptions, ShapeMatch, SphereModel,
    ransac_cylinder, ransac_plane, ransac_sphere,
};
pub use select::{select_box, select_region_from_seed};

#[cfg(doc)]
use crate::math::CounterRng;
#[cfg(doc)]
use crate::metrology::fit::{RobustRule, fit_plane, fit_plane_robust};
