//! Cutting tools as solids of revolution in the tool frame T: the tip at the origin, the
//! axis along +z (towards the spindle).
//!
//! **Invariant:** a `Tool` is always valid (finite, positive sizes); it is built only
//! through [`Tool::try_new`].

use crate::math::Real;

/// The shape of the cutting end.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ToolKind {
    /// Flat end mill: a cylinder of the tool radius from the tip up.
    Flat,
    /// Ball end mill: a hemisphere of the tool radius at the tip, then a cylinder.
    Ball,
}

/// Errors for impossible tool geometry.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ToolError {
    /// Radius not positive or not finite.
    #[error("tool diameter must be positive and finite, got {0} mm")]
    BadDiameter(Real),
    /// Length too short for the shape, or not finite.
    #[error("tool length must be finite and exceed the radius ({radius} mm), got {length} mm")]
    BadLength {
        /// The tool radius (mm).
        radius: Real,
        /// The given length (mm).
        length: Real,
    },
}

/// A cutting tool.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tool {
    kind: ToolKind,
    radius: Real,
    length: Real,
}

impl Tool {
    /// A tool of `kind` with `diameter` and cutting `length` from the tip (mm).
    pub fn try_new(kind: ToolKind, diameter: Real, length: Real) -> Result<Self, ToolError> {
        if !(diameter.is_finite() && diameter > 0.0) {
            return Err(ToolError::BadDiameter(diameter));
        }
        let radius = diameter / 2.0;
        if !(length.is_finite() && length > radius) {
            return Err(ToolError::BadLength { radius, length });
        }
        Ok(Self {
            kind,
            radius,
            length,
        })
    }

    /// Flat or ball.
    pub fn kind(&self) -> ToolKind {
        self.kind
    }

    /// Radius (mm).
    pub fn radius(&self) -> Real {
        self.radius
    }

    /// Cutting length from the tip (mm).
    pub fn length(&self) -> Real {
        self.length
    }

    /// The largest distance of a tool point from the tip (mm).
    pub fn reach(&self) -> Real {
        self.radius.hypot(self.length)
    }

    /// Whether the tool-frame point (radial distance `r`, height `h` above the tip) is inside.
    pub fn contains(&self, r: Real, h: Real) -> bool {
        if h > self.length || r > self.radius {
            return false;
        }
        match self.kind {
            ToolKind::Flat => h >= 0.0,
            ToolKind::Ball => {
                h >= self.radius || r * r + (h - self.radius).powi(2) <= self.radius * self.radius
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_degenerate_tools() {
        assert!(Tool::try_new(ToolKind::Flat, 0.0, 10.0).is_err());
        assert!(Tool::try_new(ToolKind::Flat, Real::NAN, 10.0).is_err());
        assert!(Tool::try_new(ToolKind::Ball, 6.0, 2.0).is_err());
        assert!(Tool::try_new(ToolKind::Ball, 6.0, Real::INFINITY).is_err());
    }

    #[test]
    fn ball_contains_follows_the_hemisphere() {
        let t = Tool::try_new(ToolKind::Ball, 6.0, 20.0).expect("valid");
        assert!(t.contains(0.0, 0.0));
        assert!(!t.contains(2.9, 0.1));
        assert!(t.contains(2.9, 3.0));
    }
}
