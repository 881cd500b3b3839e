//! What the features determine: the deviations' realistic magnitudes, and the model's
//! whitened Jacobian handed to [`crate::calibration::determined::identifiability_of`].
//!
//! **Invariant:** a parameter or combination is called determined only from the scaled
//! Jacobian's spectrum, never from the solved values.

use super::*;

/// The realistic magnitude of a deviation, used to scale the Jacobian before deciding
/// what is determined: 0.5 mm for offsets, 5e-4 rad for angles (the sizes of
/// assembly deviations of small machines).
pub fn magnitude(id: DeviationId) -> Real {
    component_magnitude(id.component)
}

/// The realistic magnitude of a component (see [`magnitude`]).
pub fn component_magnitude(c: crate::machine::Component) -> Real {
    if c.is_angle() {
        ANGLE_MAGNITUDE_RAD
    } else {
        OFFSET_MAGNITUDE_MM
    }
}

/// Realistic size of an offset deviation (mm).
pub const OFFSET_MAGNITUDE_MM: Real = 0.5;
/// Realistic size of an angular deviation (rad).
pub const ANGLE_MAGNITUDE_RAD: Real = 5e-4;
/// Decides what the features determine, at the deviation values `x` (see the module
/// documentation).
pub fn identifiability(
    model: &Model,
    x: &DVector<Real>,
) -> Result<Identifiability, CalibrateError> {
    let j = model.jacobian(x).ok_or_else(|| {
        CalibrateError::Degenerate(
            model
                .features
                .first()
                .map_or(String::new(), |f| f.name().to_string()),
        )
    })?;
    Ok(identifiability_of(
        &j,
        &model.param_names(),
        &model.param_scales(),
        &model.nuisance_names(),
    ))
}
