//! General identification of a machine's deviations from measured features (see
//! docs/identification-and-correction.md): any chain, any set of features, any choice of
//! deviations to solve for.
//!
//! **Features.** A [`Feature`] is one measured quantity group with its uncertainty:
//! [`PlaneFeature`], a face cut by a straight move of a flat (or ball) end mill and fitted in
//! a scan — its *flank* (tangent to the tool cylinder, containing the tool axis and the path:
//! an exact plane) or, for flat end mills, its *floor*; and [`BallFeature`], a ball centre: the
//! tool-side point (a probe's stylus ball, a master ball in the spindle) at known axis values,
//! measured relative to a point fixed on the table (a calibration sphere a probe touched, a
//! ball sensor's origin). Ball-bar lengths and interferometer readings are modelled in
//! [`crate::calibration::instruments`], which also takes these features into one solve with
//! them (the chain's error-motion coefficients then solved with the location terms).
//!
//! **Error motions.** A chain's ISO 230-1 error motions (known values, every axis as last
//! moved in +) are in every pose, composed as [`Chain::w_from_t`] composes them.
//!
//! **Parameters.** The unknowns are joint deviations (`dy_AY`) and, on top of the chain's
//! current values, ISO 230-7 location and squareness terms ([`IsoTerm`]: `EX0C`, `EB0A`,
//! `EC(0X)Y`) applied exactly as [`Chain::apply_iso_term`] does — the names a user of
//! KinematicsOpt or CYCLE996 reads.
//!
//! **Balls.** Residual: `(p(q) − (a_k + m))/σ` per coordinate, `p(q)` the tool-side point in
//! the workpiece frame, `m` the measured offset from the fixed point `k` (zero when a probe
//! found the sphere's centre, the sensor's reading otherwise) and `a_k` the fixed point's
//! position, estimated jointly (3 nuisance parameters per fixed point): where a sphere sits on
//! the table is never known well enough to take as given.
//!
//! **Floors.** The bottom disc of a flat end mill translating along `u` sweeps an exact plane
//! only when the tool axis `v` is perpendicular to `u`. With `t = u·v ≠ 0` the disc's rim
//! leaves an elliptic cylinder along `u` whose depth below the plane through the tip line
//! (containing `u` and the cross-feed direction `e₂ ⟂ u, v`) is exactly `|t|·√(R² − x₂²)`
//! at cross-feed coordinate `x₂`. The predicted floor is the least-squares plane of that
//! surface over the cross-feed range the measured points cover (uniform in `x₂`): depth
//! `|t|·F₀` at the tip line and tilt `|t|·F₂` about `u`, with `F₀, F₂` the intercept at
//! `x₂ = 0` and the slope of the least-squares line of `√(R² − x₂²)` there. The along-feed tilt enters a floor only through `|t|` (second order
//! and sign-blind); floors therefore inform the across-feed tilt and the path's slope.
//!
//! **Residuals.** Per plane: the predicted plane's signed distance at the measured centroid
//! divided by its standard uncertainty there, and the two slopes of the predicted normal
//! relative to the measured one along the face's in-plane basis, whitened by the fit's
//! design (scatter of the points, residual σ inflated for correlation: [`FaceDesign`]).
//!
//! **Registration.** A scan is not in the workpiece frame: by default a rigid registration
//! `s_from_w = Trans·Rx·Ry·Rz` (6 nuisance parameters) is estimated jointly, so only the
//! relative geometry of the faces identifies deviations. `Registration::Workpiece` trusts the
//! W frame instead.
//!
//! **Jacobian.** Forward-mode automatic differentiation: the chain and the feature
//! predictions are written once for a generic scalar ([`Scalar`]), evaluated in `f64` for the
//! residuals and in dual numbers, one parameter per pass, for the Jacobian's columns.
//!
//! **Identifiability.** The whitened Jacobian of the deviations, with the registration's
//! and the fixed points' columns projected out, is scaled by each parameter's realistic
//! magnitude ([`magnitude`]: 0.5 mm, 5e-4 rad) and decomposed
//! ([`crate::calibration::determined`]: what is determined, identified on its own, named
//! combinations, not determined — held at its prior value and never given a value).
//!
//! **Solve.** [`crate::calibration::engine`] on the model ([`FeatureForward`]: the features'
//! whitened residuals with their closed-form Jacobian; registration and fixed points its
//! nuisance unknowns): Levenberg–Marquardt only in the determined subspace.
//!
//! **Invariant:** reads features and a chain; never runs the sweep or the scanner, never
//! touches files; never gives a value to a parameter or combination the features do not
//! determine.
//!
//! **Files.** This one holds the error; `scalar` the generic scalar and the chain's pose in
//! it, `features` the features and their predictions, `model` the least-squares model,
//! `identifiability` the magnitudes and what the features determine, `solve` the
//! identification on the engine and its fit check, `tests` the unit tests.

use crate::calibration::goodness::{
    FitCheck, MODEL_ACCURACY_MM, PartFit, REFUSE_P, ScanNoise, face_rms_check, least_squares_check,
};
use crate::calibration::identify::{
    FaceDesign, FaceOptions, FaceSelection, FaceSpec, extent, face_design, fit_face, fit_selection,
    flank, select_face, used_points,
};
use crate::cutting::tool::{Tool, ToolKind};
use crate::machine::chain::{Chain, DeviationId};
use crate::machine::error_motion::Direction;
use crate::math::{Aabb, Point3, Real, UnitVector3, Vector3, tol};
use crate::metrology::fit::Plane;
use crate::nc::{AxisValues, Move};
use nalgebra::{DMatrix, DVector, Matrix2};
use std::ops::{Add, Div, Mul, Neg, Sub};

pub use crate::calibration::identify::FaceKind;

mod features;
mod identifiability;
mod model;
mod scalar;
mod solve;

pub use crate::calibration::determined::{
    BORDERLINE_FACTOR, COMBINATION_CUTOFF, Combination, DETERMINED_FRACTION, Estimate,
    Identifiability, LEAKAGE, estimates_of, identifiability_of,
};
use features::feature_residuals;
pub use features::{
    BallFeature, Feature, IsoTerm, PlaneFeature, ball_features, extract_plane_feature,
    plane_feature, predicted_plane, select_plane_face, synthetic_plane_feature,
};
pub use identifiability::{
    ANGLE_MAGNITUDE_RAD, OFFSET_MAGNITUDE_MM, component_magnitude, identifiability, magnitude,
};
pub use model::{Model, Registration};
pub use scalar::{Dual, Scalar};
use scalar::{Params, Rigid, V3, cross, dot, normalize, pose, v3, vadd, values, vscale, vsub};
pub use solve::{
    FeatureForward, Identification, SolveReport, face_rms_parts, feature_fit, identify,
    identify_with,
};

/// Errors of general identification.
#[derive(Debug, PartialEq, thiserror::Error)]
pub enum CalibrateError {
    /// Face extraction failed.
    #[error("{0}")]
    Face(#[from] crate::calibration::identify::IdentifyError),
    /// A floor was asked of a tool without a flat bottom.
    #[error("face '{0}': a floor needs a flat end mill")]
    FloorNeedsFlatTool(String),
    /// No parameter to solve for.
    #[error("no deviation to identify was given")]
    NoParameters,
    /// A parameter the chain does not have.
    #[error("{0}")]
    Parameter(String),
    /// No feature to solve from.
    #[error("no measured feature was given")]
    NoFeatures,
    /// A requested parameter is not informed by any feature at all.
    #[error("no data for {0}: no measured feature depends on it (add cuts that do, or drop it)")]
    NoData(String),
    /// A feature's prediction is degenerate (a cut along the tool axis, a zero-length move).
    #[error("feature '{0}': the model cannot predict it (degenerate cut)")]
    Degenerate(String),
    /// The solver did not converge.
    #[error("the solver did not converge: {0}")]
    NotConverged(String),
}

#[cfg(test)]
mod tests;
