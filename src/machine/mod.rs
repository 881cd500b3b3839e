//! **The machine**: what turns axis values into tool poses. A serial machine is a kinematic
//! chain of linear and rotary axes from the workpiece to the tool, with an exact rigid
//! deviation at every joint ([`chain`]) and, optionally, error motions of each axis as
//! functions of its position ([`error_motion`]); a parallel machine is a hexapod (Stewart
//! platform) of six struts with its 42 kinematic parameters ([`hexapod`]), and seed 001's
//! accuracy measures on it ([`hexapod_accuracy`]). A scene describes either as data, never
//! as code. A serial machine's controller may run tool-centre-point programs, which it
//! turns into joint moves through the nominal chain ([`tcp`]).
//!
//! Owns the chain, the deviation names (`dy_AY`, `gamma_YX`, …), the six components of a
//! deviation ([`Component`]), the error-motion names (`EXX`, `EBX`, …) and their exact
//! transforms; the hexapod, its parameter names (`bx_1`, `ax_1`, `l0_1`, …) and
//! kinematics.
//! May use [`crate::math`] and [`crate::nc`] (axis letters and values). Knows nothing of
//! tools, stock, measurements or files.

pub mod error_motion;
pub mod chain;
pub mod hexapod;
pub mod hexapod_accuracy;
pub mod tcp;

use crate::math::{Isometry3, Real};
use crate::nc::{AxisLetter, AxisValues};

/// Why a machine cannot take some axis values (out of its workspace, no forward solution).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct PoseError(pub String);

/// A machine the tool sweep reads pose by pose along a move instead of through a serial
/// chain (a hexapod): the controller interpolates every axis value linearly between a move's
/// ends, and the machine puts the tool where its own kinematics take it. Implemented by
/// [`hexapod::HexapodTwin`]; the sweep bounds the error of cutting such a move from the poses
/// it samples ([`crate::cutting::sweep`]).
pub trait PoseSource: Sync {
    /// Whether the machine has the axis.
    fn has_axis(&self, axis: AxisLetter) -> bool;
    /// The tool's pose (tool frame to workpiece frame: the tip at the tool frame's origin,
    /// the tool axis its +z) at the axis values `q`, or why the machine cannot take them.
    fn w_from_t(&self, q: &AxisValues) -> Result<Isometry3, PoseError>;
    /// The pose the controller commands at `q` (where a perfect machine puts the tool).
    fn commanded(&self, q: &AxisValues) -> Isometry3;
    /// Whether the move `start → end` is a pure translation of the tool with its tip linear
    /// in the move's parameter (then its two end poses define it exactly).
    fn is_translation(&self, start: &AxisValues, end: &AxisValues) -> bool;
    /// Every axis value `lambda` of the way from `start` to `end` (the controller's
    /// interpolation).
    fn interpolate(&self, start: &AxisValues, end: &AxisValues, lambda: Real) -> AxisValues {
        let mut q = *start;
        for l in AxisLetter::ALL {
            let (a, b) = (start.get(l), end.get(l));
            q.set(l, a + (b - a) * lambda);
        }
        q
    }
}

/// The six components of a deviation.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Component {
    /// Offset along x (mm).
    Dx,
    /// Offset along y (mm).
    Dy,
    /// Offset along z (mm).
    Dz,
    /// Rotation about x (rad).
    Alpha,
    /// Rotation about y (rad).
    Beta,
    /// Rotation about z (rad).
    Gamma,
}

impl Component {
    /// All six, in storage order.
    pub const ALL: [Component; 6] = [
        Component::Dx,
        Component::Dy,
        Component::Dz,
        Component::Alpha,
        Component::Beta,
        Component::Gamma,
    ];

    /// The prefix used in names (`dx`, …, `gamma`).
    pub fn prefix(self) -> &'static str {
        match self {
            Component::Dx => "dx",
            Component::Dy => "dy",
            Component::Dz => "dz",
            Component::Alpha => "alpha",
            Component::Beta => "beta",
            Component::Gamma => "gamma",
        }
    }

    /// Whether the component is an angle (rad) rather than an offset (mm).
    pub fn is_angle(self) -> bool {
        matches!(self, Component::Alpha | Component::Beta | Component::Gamma)
    }
}
