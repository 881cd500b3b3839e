//! Outlier rejection shared by all shapes: the [`RobustRule`] and the one trim-and-refit
//! loop every robust fit runs through ([`Trimmable`] is what the loop needs of a fit).

use super::error::FitError;
use crate::math::{Point3, Real, tol};
use rayon::prelude::*;

/// Outlier rejection rule: iteratively drop points with |residual| > k_sigma · rms and refit, until nothing changes or max_iterations.
///
/// Residuals of all input points are re-evaluated against each new fit, so a point
/// dropped early can return. The threshold never falls below 1 pm
/// ([`tol::LENGTH_EPS`]), so exact data lose nothing to rounding. A refit that would
/// fail (fewer points than the shape needs, degenerate, not converged) ends the iteration
/// with the previous fit. The same rule, through one shared loop, serves planes, spheres,
/// circles (residual: the point's distance from the circle) and cylinders.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RobustRule {
    /// Rejection threshold in multiples of the current fit's rms residual.
    pub k_sigma: Real,
    /// Maximum number of reject-and-refit rounds.
    pub max_iterations: usize,
}

impl Default for RobustRule {
    /// k_sigma 3.0, max_iterations 10.
    fn default() -> Self {
        Self {
            k_sigma: 3.0,
            max_iterations: 10,
        }
    }
}

/// What the trim-and-refit loop needs of a fit.
pub(super) trait Trimmable: Sized + Sync {
    /// Fewest points a refit accepts.
    const MIN_POINTS: usize;
    /// RMS residual of the used points (mm).
    fn rms(&self) -> Real;
    /// Orthogonal distance of `p` from the fitted shape (mm, ≥ 0).
    fn distance(&self, p: &Point3) -> Real;
    /// Points used in the fit.
    fn n_used(&self) -> usize;
    /// Records the number of rejected input points.
    fn set_rejected(&mut self, n: usize);
}

/// The [`RobustRule`] loop: drop points farther than k·rms from the current fit, refit the
/// rest with `refit(subset, previous)`, until the kept set stops changing, the rule's
/// iteration cap is reached, or a refit fails (then the previous fit stands).
pub(super) fn trim_and_refit<F, R>(points: &[Point3], rule: &RobustRule, mut fit: F, refit: R) -> F
where
    F: Trimmable,
    R: Fn(&[Point3], &F) -> Result<F, FitError>,
{
    let mut keep = vec![true; points.len()];
    for _ in 0..rule.max_iterations {
        let threshold = (rule.k_sigma * fit.rms()).max(tol::LENGTH_EPS);
        let current = &fit;
        let new_keep: Vec<bool> = points
            .par_iter()
            .map(|p| current.distance(p) <= threshold)
            .collect();
        if new_keep == keep {
            break;
        }
        let subset: Vec<Point3> = points
            .iter()
            .zip(&new_keep)
            .filter_map(|(p, &k)| k.then_some(*p))
            .collect();
        if subset.len() < F::MIN_POINTS {
            break;
        }
        match refit(&subset, &fit) {
            Ok(f) => {
                fit = f;
                keep = new_keep;
            }
            Err(_) => break,
        }
    }
    let rejected = points.len() - fit.n_used();
    fit.set_rejected(rejected);
    fit
}
