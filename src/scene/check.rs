//! The bounds a scene's geometry is checked against on reading: coordinates within 100 m,
//! rotary positions within a hundred turns, directions of a sensible length, and linear axes
//! that span space. Shared by the serial and the hexapod machine.

use crate::machine::chain::{Axis, AxisKind};
use crate::math::{Real, UnitVector3, Vector3};

/// The largest coordinate a machine may have (mm): 100 m, beyond any machine tool's travel.
/// A `home` position, an axis origin or a joint beyond it is refused.
pub const MAX_COORDINATE_MM: Real = 1e5;

/// The largest rotary-axis position a scene may give (degrees): a hundred turns.
pub const MAX_ANGLE_DEG: Real = 36_000.0;

/// A direction vector's length must lie in `[1 / DIRECTION_SCALE, DIRECTION_SCALE]`: it is
/// normalised on reading, and a component a million times another's is a typing error, not
/// a direction.
pub const DIRECTION_SCALE: Real = 1e3;

/// The smallest angle between two linear axes (and between a linear axis and the plane of
/// two others), degrees: axes closer to parallel do not span the space a machine moves in.
pub const MIN_AXIS_ANGLE_DEG: Real = 1.0;

/// A direction given as `[dx, dy, dz]`, normalised; the key names it in messages.
pub fn check_direction(v: [Real; 3], key: &str) -> Result<UnitVector3, String> {
    let d = Vector3::new(v[0], v[1], v[2]);
    // the length without overflow: [1, 1e308, 0] is 1e308 long, not infinite
    let big = d.amax();
    let n = if big > 0.0 && big.is_finite() {
        big * (d / big).norm()
    } else {
        big
    };
    if !(n.is_finite() && (1.0 / DIRECTION_SCALE..=DIRECTION_SCALE).contains(&n)) {
        return Err(format!(
            "{key}: got {v:?} (length {n:e}), expected a direction of length {} to {}",
            1.0 / DIRECTION_SCALE,
            DIRECTION_SCALE
        ));
    }
    Ok(UnitVector3::new_normalize(d))
}

/// A machine coordinate (mm), at most [`MAX_COORDINATE_MM`] from the origin.
pub fn check_coordinate(v: Real, key: &str) -> Result<Real, String> {
    if v.is_finite() && v.abs() <= MAX_COORDINATE_MM {
        Ok(v)
    } else {
        Err(format!(
            "{key}: got {v:e} mm, expected within ±{MAX_COORDINATE_MM} mm (100 m, beyond \
             any machine's travel)"
        ))
    }
}

/// Checks that the linear axes among `axes` span space: no two within
/// [`MIN_AXIS_ANGLE_DEG`] of parallel, three not within it of one plane.
pub(super) fn linear_axes_span(axes: &[Axis]) -> Result<(), String> {
    let lin: Vec<&Axis> = axes.iter().filter(|a| a.kind == AxisKind::Linear).collect();
    let min_sin = MIN_AXIS_ANGLE_DEG.to_radians().sin();
    for (i, a) in lin.iter().enumerate() {
        for b in &lin[..i] {
            let sin = a.direction.cross(&b.direction).norm();
            if sin < min_sin {
                return Err(format!(
                    "axes {} and {} are {:.3}° from parallel, expected linear axes at least \
                     {MIN_AXIS_ANGLE_DEG}° apart",
                    b.letter.as_char(),
                    a.letter.as_char(),
                    sin.min(1.0).asin().to_degrees()
                ));
            }
        }
    }
    if let [a, b, c] = lin[..] {
        let det = a.direction.dot(&b.direction.cross(&c.direction)).abs();
        if det < min_sin {
            return Err(format!(
                "axes {}, {} and {} lie {:.3}° from one plane, expected linear axes that \
                 span space (at least {MIN_AXIS_ANGLE_DEG}° from a common plane)",
                a.letter.as_char(),
                b.letter.as_char(),
                c.letter.as_char(),
                det.min(1.0).asin().to_degrees()
            ));
        }
    }
    Ok(())
}
