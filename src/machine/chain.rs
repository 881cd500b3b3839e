//! The machine as a kinematic chain with assembly deviations (seed 002's shape-generation
//! function; conventions in docs/scenes.md).
//!
//! A chain is an ordered list of axes from the workpiece to the tool. Between adjacent
//! bodies sits a deviation E_j = Trans(dx,dy,dz)·Rx(alpha)·Ry(beta)·Rz(gamma), exact, never
//! linearised. The tool's pose in the workpiece frame is
//!
//! ```text
//! w_from_t(q) = M_1(q_1)·E_1·M_2(q_2)·E_2 ··· M_n(q_n)·E_n
//! ```
//!
//! where M_i is the motion of axis i (a translation along its direction, or a rotation
//! about its line) and E_i the deviation between body i and the next one (the last is the
//! spindle). For the MDX-50 this is `RotX(a)·E_AY·Ty·E_YX·Tx·E_XZ·Tz·E_ZS`.
//!
//! **Invariant:** the chain knows nothing about files, G-code text or stock; it maps axis
//! values to poses, and names deviations.

use crate::math::{Isometry3, Point3, Real, Rotation3, UnitVector3, Vector3};
use crate::nc::{AxisLetter, AxisValues};
use std::fmt;

/// Errors in building a chain or naming a deviation.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum KinematicsError {
    /// A deviation name that is not `<component>_<from><to>` for adjacent bodies.
    #[error("unknown deviation '{name}' (expected one of: {expected})")]
    UnknownDeviation {
        /// The name as given.
        name: String,
        /// The valid names, comma separated.
        expected: String,
    },
    /// Two axes with the same letter, or an axis named like the spindle.
    #[error("axis '{0}' appears twice in the chain")]
    DuplicateAxis(char),
    /// An axis direction of zero or non-finite length.
    #[error("axis '{0}' has a zero or non-finite direction")]
    BadDirection(char),
    /// A chain without axes.
    #[error("the chain has no axes")]
    Empty,
}

/// Whether an axis translates or rotates.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AxisKind {
    /// Moves along its direction; value in mm.
    Linear,
    /// Turns about the line through `origin` along its direction (right hand); value in degrees.
    Rotary,
}

/// One axis of the chain.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Axis {
    /// The NC letter that drives it.
    pub letter: AxisLetter,
    /// Linear or rotary.
    pub kind: AxisKind,
    /// Direction of motion (linear) or of the rotation axis (rotary), in the frame of the
    /// body before it in the chain.
    pub direction: UnitVector3,
    /// A point on a rotary axis line (ignored for linear axes), mm.
    pub origin: Point3,
}

impl Axis {
    /// The axis motion for value `q` (mm or degrees).
    pub fn motion(&self, q: Real) -> Isometry3 {
        match self.kind {
            AxisKind::Linear => Isometry3::translation(
                self.direction.x * q,
                self.direction.y * q,
                self.direction.z * q,
            ),
            AxisKind::Rotary => {
                let rot = Rotation3::from_axis_angle(&self.direction, q.to_radians());
                let o = self.origin.coords;
                // Trans(o)·Rot·Trans(−o)
                Isometry3::from_parts((o - rot * o).into(), rot)
            }
        }
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

/// A deviation between two adjacent bodies: offsets in mm, angles in rad.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Deviation {
    /// dx, dy, dz (mm), alpha, beta, gamma (rad), in `Component::ALL` order.
    pub values: [Real; 6],
}

impl Deviation {
    /// The exact rigid transform Trans(dx,dy,dz)·Rx(alpha)·Ry(beta)·Rz(gamma).
    pub fn transform(&self) -> Isometry3 {
        let [dx, dy, dz, alpha, beta, gamma] = self.values;
        let rx = Rotation3::from_axis_angle(&Vector3::x_axis(), alpha);
        let ry = Rotation3::from_axis_angle(&Vector3::y_axis(), beta);
        let rz = Rotation3::from_axis_angle(&Vector3::z_axis(), gamma);
        Isometry3::from_parts(Vector3::new(dx, dy, dz).into(), rx * ry * rz)
    }

    /// Whether all six values are zero.
    pub fn is_zero(&self) -> bool {
        self.values.iter().all(|v| *v == 0.0)
    }
}

/// Names one deviation parameter of a chain: joint `joint` (between body `joint` and
/// `joint + 1`), one component.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct DeviationId {
    /// Index of the joint: 0 is between the first axis and the second body.
    pub joint: usize,
    /// Which of the six numbers.
    pub component: Component,
}

/// A kinematic chain with its deviations.
#[derive(Clone, Debug, PartialEq)]
pub struct Chain {
    axes: Vec<Axis>,
    spindle: String,
    deviations: Vec<Deviation>,
}

impl Chain {
    /// A chain of `axes` from workpiece to tool, ending at the body `spindle`, with all
    /// deviations zero.
    pub fn new(axes: Vec<Axis>, spindle: &str) -> Result<Self, KinematicsError> {
        if axes.is_empty() {
            return Err(KinematicsError::Empty);
        }
        for (i, a) in axes.iter().enumerate() {
            if axes[..i].iter().any(|b| b.letter == a.letter)
                || spindle.eq_ignore_ascii_case(&a.letter.as_char().to_string())
            {
                return Err(KinematicsError::DuplicateAxis(a.letter.as_char()));
            }
            let d = a.direction.into_inner();
            if !d.iter().all(|c| c.is_finite()) || !a.origin.coords.iter().all(|c| c.is_finite()) {
                return Err(KinematicsError::BadDirection(a.letter.as_char()));
            }
        }
        let n = axes.len();
        Ok(Self {
            axes,
            spindle: spindle.to_string(),
            deviations: vec![Deviation::default(); n],
        })
    }

    /// The axes in chain order.
    pub fn axes(&self) -> &[Axis] {
        &self.axes
    }

    /// The deviations, one per joint (joint i follows axis i).
    pub fn deviations(&self) -> &[Deviation] {
        &self.deviations
    }

    /// The name of joint `j`, e.g. `AY` or `ZS`.
    pub fn joint_name(&self, j: usize) -> String {
        let from = self.axes[j].letter.as_char();
        match self.axes.get(j + 1) {
            Some(next) => format!("{from}{}", next.letter.as_char()),
            None => format!("{from}{}", self.spindle),
        }
    }

    /// The name of a deviation parameter, e.g. `dy_AY`.
    pub fn deviation_name(&self, id: DeviationId) -> String {
        format!("{}_{}", id.component.prefix(), self.joint_name(id.joint))
    }

    /// All deviation parameter names of this chain, in joint then component order.
    pub fn deviation_names(&self) -> Vec<String> {
        (0..self.axes.len())
            .flat_map(|joint| {
                Component::ALL
                    .iter()
                    .map(move |&component| DeviationId { joint, component })
            })
            .map(|id| self.deviation_name(id))
            .collect()
    }

    /// Looks up a deviation by name (`dy_AY`, `gamma_YX`, …).
    pub fn deviation_id(&self, name: &str) -> Result<DeviationId, KinematicsError> {
        for joint in 0..self.axes.len() {
            for &component in &Component::ALL {
                let id = DeviationId { joint, component };
                if self.deviation_name(id) == name {
                    return Ok(id);
                }
            }
        }
        Err(KinematicsError::UnknownDeviation {
            name: name.to_string(),
            expected: self.deviation_names().join(", "),
        })
    }

    /// The value of one deviation parameter.
    pub fn deviation(&self, id: DeviationId) -> Real {
        self.deviations[id.joint].values[id.component as usize]
    }

    /// Sets one deviation parameter (mm or rad).
    pub fn set_deviation(&mut self, id: DeviationId, value: Real) {
        self.deviations[id.joint].values[id.component as usize] = value;
    }

    /// The same chain with every deviation zero: the nominal machine.
    pub fn nominal(&self) -> Chain {
        Chain {
            deviations: vec![Deviation::default(); self.axes.len()],
            ..self.clone()
        }
    }

    /// Whether the axis for `letter` is in the chain.
    pub fn has_axis(&self, letter: AxisLetter) -> bool {
        self.axes.iter().any(|a| a.letter == letter)
    }

    /// The tool's pose in the workpiece frame for axis values `q` (mm, degrees).
    pub fn w_from_t(&self, q: &AxisValues) -> Isometry3 {
        let mut pose = Isometry3::identity();
        for (axis, dev) in self.axes.iter().zip(&self.deviations) {
            pose = pose * axis.motion(q.get(axis.letter)) * dev.transform();
        }
        pose
    }

    /// The rotary axes as lines in the workpiece frame for axis values `q`: a point on each
    /// and its unit direction (used to bound the speed and curvature of rotary moves).
    pub fn rotary_lines_in_w(&self, q: &AxisValues) -> Vec<(Point3, Vector3)> {
        let mut pose = Isometry3::identity();
        let mut out = Vec::new();
        for (axis, dev) in self.axes.iter().zip(&self.deviations) {
            if axis.kind == AxisKind::Rotary {
                out.push((
                    pose * axis.origin,
                    pose.rotation * axis.direction.into_inner(),
                ));
            }
            pose = pose * axis.motion(q.get(axis.letter)) * dev.transform();
        }
        out
    }
}

impl fmt::Display for Chain {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (j, axis) in self.axes.iter().enumerate() {
            let m = match axis.kind {
                AxisKind::Linear => "T",
                AxisKind::Rotary => "R",
            };
            write!(f, "{m}{}·E_{}", axis.letter.as_char(), self.joint_name(j))?;
            if j + 1 < self.axes.len() {
                write!(f, "·")?;
            }
        }
        Ok(())
    }
}

/// The MDX-50 chain of seed 002 (A, Y, X, Z from the workpiece; spindle S), nominal: the
/// chain the unit tests of several modules build on.
#[cfg(test)]
pub(crate) fn mdx50_for_tests() -> Chain {
    let ax = |letter, kind, d: Vector3| Axis {
        letter,
        kind,
        direction: UnitVector3::new_normalize(d),
        origin: Point3::origin(),
    };
    Chain::new(
        vec![
            ax(AxisLetter::A, AxisKind::Rotary, Vector3::x()),
            ax(AxisLetter::Y, AxisKind::Linear, Vector3::y()),
            ax(AxisLetter::X, AxisKind::Linear, Vector3::x()),
            ax(AxisLetter::Z, AxisKind::Linear, Vector3::z()),
        ],
        "S",
    )
    .expect("valid chain")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mdx50() -> Chain {
        super::mdx50_for_tests()
    }

    #[test]
    fn names_follow_seed_002() {
        let c = mdx50();
        assert_eq!(c.joint_name(0), "AY");
        assert_eq!(c.joint_name(3), "ZS");
        let id = c.deviation_id("gamma_YX").expect("known");
        assert_eq!(id.joint, 1);
        assert_eq!(id.component, Component::Gamma);
        assert!(c.deviation_id("dy_AX").is_err());
    }

    #[test]
    fn nominal_chain_places_tip_at_programmed_point() {
        let c = mdx50();
        let q = AxisValues::default()
            .with(AxisLetter::X, 1.0)
            .with(AxisLetter::Y, 2.0)
            .with(AxisLetter::Z, 3.0);
        let p = c.w_from_t(&q) * Point3::origin();
        assert!((p - Point3::new(1.0, 2.0, 3.0)).norm() < 1e-15);
        // A = 180° about +X: y and z change sign.
        let p = c.w_from_t(&q.with(AxisLetter::A, 180.0)) * Point3::origin();
        assert!((p - Point3::new(1.0, -2.0, -3.0)).norm() < 1e-12);
    }

    #[test]
    fn positive_a_is_right_handed_about_x() {
        let c = mdx50();
        let q = AxisValues::default()
            .with(AxisLetter::Y, 1.0)
            .with(AxisLetter::A, 90.0);
        let p = c.w_from_t(&q) * Point3::origin();
        // +90° about +X takes +Y to +Z.
        assert!((p - Point3::new(0.0, 0.0, 1.0)).norm() < 1e-12);
    }

    #[test]
    fn deviation_matches_first_order_matrix() {
        // E ≈ I + [[0,−γ,β,δx],[γ,0,−α,δy],[−β,α,0,δz]] (seed 002 eq. 2).
        let d = Deviation {
            values: [0.1, -0.2, 0.3, 1e-6, -2e-6, 3e-6],
        };
        let m = d.transform().to_homogeneous();
        let (a, b, g) = (1e-6, -2e-6, 3e-6);
        let expect = nalgebra::Matrix4::new(
            1.0, -g, b, 0.1, g, 1.0, -a, -0.2, -b, a, 1.0, 0.3, 0.0, 0.0, 0.0, 1.0,
        );
        assert!((m - expect).abs().max() < 1e-11);
    }

    #[test]
    fn dy_ay_shifts_a0_and_a180_opposite() {
        let mut c = mdx50();
        c.set_deviation(c.deviation_id("dy_AY").expect("known"), -0.5);
        let q = AxisValues::default().with(AxisLetter::Y, -25.0);
        let p0 = c.w_from_t(&q) * Point3::origin();
        assert!((p0.y - (-25.5)).abs() < 1e-12);
        let q = AxisValues::default()
            .with(AxisLetter::Y, 25.0)
            .with(AxisLetter::A, 180.0);
        let p1 = c.w_from_t(&q) * Point3::origin();
        assert!((p1.y - (-24.5)).abs() < 1e-12);
    }
}
