//! Why a fit fails ([`FitError`]) and the check of the input points every fit starts
//! with: enough of them, all finite.

use crate::math::Point3;
use rayon::prelude::*;

/// Why a shape could not be fitted.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum FitError {
    /// Fewer points than the shape needs.
    #[error("fit needs at least {needed} points, got {got}")]
    TooFewPoints {
        /// Minimum number of points: plane 3, sphere 4, circle 3, cylinder 5.
        needed: usize,
        /// Number supplied.
        got: usize,
    },
    /// The points do not determine the shape: collinear or coincident for a plane or a
    /// circle, coplanar for a sphere, collinear (or, e.g., all on one circle) for a
    /// cylinder; a rank-deficient Jacobian at the solution; or coordinates so large their
    /// moments overflow.
    #[error("degenerate point configuration: the points do not determine a unique fit")]
    Degenerate,
    /// A point has a NaN or infinite coordinate.
    #[error("point {index} has a non-finite coordinate")]
    NonFinite {
        /// Index of the first offending point.
        index: usize,
    },
    /// The iterative (sphere, circle, cylinder) solver did not converge.
    #[error("the least-squares solver did not converge after {iterations} iterations")]
    NotConverged {
        /// Iterations done (accepted steps) before giving up.
        iterations: usize,
    },
}

/// Refuses too few points, then the first non-finite point.
pub(super) fn check_input(points: &[Point3], needed: usize) -> Result<(), FitError> {
    if points.len() < needed {
        return Err(FitError::TooFewPoints {
            needed,
            got: points.len(),
        });
    }
    if let Some(index) = points
        .par_iter()
        .position_first(|p| !p.coords.iter().all(|c| c.is_finite()))
    {
        return Err(FitError::NonFinite { index });
    }
    Ok(())
}
