//! Orthogonal least-squares fits of planes, spheres, circles in 3-D and cylinders, plain and
//! with iterative outlier rejection.
//!
//! **Plane.** The fit minimises the sum of squared perpendicular distances: the normal is
//! the eigenvector of the smallest eigenvalue of the centred second-moment matrix. Numerics
//! are arranged for 0.1 µm / 1 µrad resolution on faces 20–300 mm from the origin:
//!
//! * the mean is accumulated relative to the first point (differences of at most the
//!   patch size, not absolute coordinates), then corrected by the mean residual of a second
//!   pass (the classical corrected two-pass algorithm);
//! * the second moments are accumulated about that centroid;
//! * all sums run over fixed chunks of [`CHUNK`] points in parallel (rayon) and the partial
//!   sums are combined in chunk order, so results are bit-identical for any thread count.
//!
//! **Sphere, circle, cylinder.** These minimise the sum of squared *orthogonal* (geometric)
//! distances by damped Gauss–Newton (Levenberg–Marquardt with Marquardt's diagonal scaling)
//! on the normal equations: each iteration accumulates JᵀJ and Jᵀr of the analytic
//! Jacobian over the same fixed chunks, so no m × p Jacobian is ever stored, 400,000 points
//! cost a few passes of arithmetic, and every result bit is independent of the thread
//! count. Orientations are updated in a minimal local parameterisation (two small rotation
//! angles in the tangent plane of the current normal or axis, re-linearised each
//! iteration). Starting values are closed-form:
//!
//! * sphere: the algebraic fit x²+y²+z² + Dx + Ey + Fz + G = 0 (linear least squares in
//!   centred, scaled coordinates); residual |p − c| − r;
//! * circle: the plane of [`fit_plane`], then the algebraic (Kåsa) circle of the points
//!   projected into it; two residuals per point, n·(p − c) and |P(p − c)| − r with P the
//!   projection onto the plane, so √(sum of both squared) is the point's distance from
//!   the circle;
//! * cylinder: the caller's axis direction if given, otherwise each of the three principal
//!   axes of the points' covariance as a candidate; a Kåsa circle of the points projected
//!   on the plane perpendicular to each candidate, keeping the candidate with the smallest
//!   RMS circle residual; residual = distance from the axis − r. The axis pivot is kept at
//!   the foot of the points' centroid, which decouples tilt from translation.
//!
//! Uncertainties are σ²(JᵀJ)⁻¹ with σ² = Σr²/(m − p) (m residuals, p parameters) at the
//! solution: standard uncertainties for independent Gaussian noise of equal variance in
//! every residual (checked by Monte Carlo in the tests to within 20 %). They are the
//! honest measure of conditioning: partial arcs shorter than about 90° determine the
//! radius and the centre (the axis) poorly; the fit still converges but the reported σ
//! grow steeply, roughly as the inverse square of the arc angle for the radius (a 10 mm
//! circle or cylinder with 0.025 mm noise: σ_r ≈ 0.006 mm at 90°, 0.025 mm at 45°, 0.12
//! mm at 20°). Below about 30° the linearisation itself starts to show: the observed
//! spread exceeds the reported σ by some 10 % and the radius is biased high by about 0.2 σ.
//! Rank-deficient problems (points on one circle for a cylinder, coplanar points
//! for a sphere, collinear points for a circle) are refused as [`FitError::Degenerate`]; a
//! solver that does not converge within [`MAX_ITERATIONS`] reports
//! [`FitError::NotConverged`], never a number.
//!
//! The code, one idea a file: `error` ([`FitError`] and the input check every fit starts
//! with), `moments` (fixed-chunk sums, centroid and centred second moments), `plane` (the
//! plane, its fit and plane pairs), `robust` ([`RobustRule`] and the trim-and-refit loop
//! all shapes share), `solver` (Levenberg–Marquardt on accumulated normal equations),
//! `start` (geometry helpers and closed-form starting values), then `sphere`, `circle` and
//! `cylinder`, each a result, its model and its plain and robust fits.

mod error;
mod moments;
mod plane;
mod robust;
mod solver;
mod start;
mod sphere;
mod circle;
mod cylinder;
#[cfg(test)]
mod tests;

pub use circle::{CircleFit, fit_circle, fit_circle_robust};
pub use cylinder::{CylinderFit, fit_cylinder, fit_cylinder_robust};
pub use error::FitError;
pub use moments::CHUNK;
pub use plane::{Plane, PlaneFit, fit_plane, fit_plane_robust, plane_distance_and_angle};
pub use robust::RobustRule;
pub use solver::MAX_ITERATIONS;
pub use sphere::{SphereFit, fit_sphere, fit_sphere_robust};
