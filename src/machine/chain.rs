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

use crate::machine::error_motion::{self, AxisErrorMotions, Direction, Directions};
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
    /// Error motions or an ISO name for an axis the chain does not have.
    #[error("'{name}' names axis {axis}, which this machine does not have (axes: {axes})")]
    MissingAxis {
        /// The name as given.
        name: String,
        /// The axis letter.
        axis: char,
        /// The chain's axes.
        axes: String,
    },
    /// A location or squareness name that is not one twinmill maps.
    #[error("unknown location or squareness name '{name}' ({expected})")]
    UnknownIsoName {
        /// The name as given.
        name: String,
        /// What is accepted.
        expected: String,
    },
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

pub use crate::machine::Component;

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

    /// The six values of a rigid transform: the inverse of [`Deviation::transform`] (angles
    /// within ±90° about y, as deviations are).
    pub fn from_transform(t: &Isometry3) -> Self {
        let r = t.rotation.to_rotation_matrix().into_inner();
        // R = Rx(α)·Ry(β)·Rz(γ): R02 = sin β, R12 = −sin α cos β, R22 = cos α cos β,
        // R01 = −cos β sin γ, R00 = cos β cos γ.
        let beta = r[(0, 2)].clamp(-1.0, 1.0).asin();
        let alpha = (-r[(1, 2)]).atan2(r[(2, 2)]);
        let gamma = (-r[(0, 1)]).atan2(r[(0, 0)]);
        let d = t.translation.vector;
        Self {
            values: [d.x, d.y, d.z, alpha, beta, gamma],
        }
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
    /// Error motions per axis, in chain order (`None`: none).
    errors: Vec<Option<AxisErrorMotions>>,
}

impl Chain {
    /// A nominal Cartesian machine: three linear axes, each along its letter's unit
    /// direction (X along x, Y along y, Z along z; origin 0, no deviations), listed from the
    /// workpiece to the tool in `order`, ending at the spindle S. A rotary letter has no such
    /// direction ([`KinematicsError::BadDirection`]); a repeated one is refused as by
    /// [`Chain::new`].
    pub fn cartesian(order: [AxisLetter; 3]) -> Result<Self, KinematicsError> {
        let axes = order
            .iter()
            .map(|&letter| {
                let mut d = Vector3::zeros();
                *d.get_mut(letter.index())
                    .ok_or(KinematicsError::BadDirection(letter.as_char()))? = 1.0;
                Ok(Axis {
                    letter,
                    kind: AxisKind::Linear,
                    direction: UnitVector3::new_normalize(d),
                    origin: Point3::origin(),
                })
            })
            .collect::<Result<Vec<_>, KinematicsError>>()?;
        Self::new(axes, "S")
    }

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
            errors: vec![None; n],
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

    /// The same chain with every deviation zero and no error motions: the nominal machine.
    pub fn nominal(&self) -> Chain {
        Chain {
            deviations: vec![Deviation::default(); self.axes.len()],
            errors: vec![None; self.axes.len()],
            ..self.clone()
        }
    }

    /// The same chain without error motions (deviations kept).
    pub fn without_error_motions(&self) -> Chain {
        Chain {
            errors: vec![None; self.axes.len()],
            ..self.clone()
        }
    }

    /// The same chain with the error motions of `other` (a chain of the same axes).
    pub fn with_error_motions_of(&self, other: &Chain) -> Chain {
        let mut out = self.clone();
        if other.axes.len() == out.axes.len() {
            out.errors = other.errors.clone();
        }
        out
    }

    fn missing_axis(&self, name: &str, letter: AxisLetter) -> KinematicsError {
        KinematicsError::MissingAxis {
            name: name.to_string(),
            axis: letter.as_char(),
            axes: self
                .axes
                .iter()
                .map(|a| a.letter.as_char().to_string())
                .collect::<Vec<_>>()
                .join(" "),
        }
    }

    fn index_of(&self, letter: AxisLetter) -> Option<usize> {
        self.axes.iter().position(|a| a.letter == letter)
    }

    /// Sets the error motions of the axis `letter` (zero ones are dropped, so a chain given
    /// only zero error motions computes exactly as one without).
    pub fn set_error_motions(
        &mut self,
        letter: AxisLetter,
        motions: AxisErrorMotions,
    ) -> Result<(), KinematicsError> {
        let i = self
            .index_of(letter)
            .ok_or_else(|| self.missing_axis(&format!("E?{}", letter.as_char()), letter))?;
        self.errors[i] = (!motions.is_zero()).then_some(motions);
        Ok(())
    }

    /// The error motions of the axis `letter`, if it has any.
    pub fn error_motions(&self, letter: AxisLetter) -> Option<&AxisErrorMotions> {
        self.index_of(letter).and_then(|i| self.errors[i].as_ref())
    }

    /// The error motions of every axis, in chain order.
    pub fn error_motions_all(&self) -> &[Option<AxisErrorMotions>] {
        &self.errors
    }

    /// Whether any axis has error motions (or a reversal).
    pub fn has_error_motions(&self) -> bool {
        self.errors.iter().any(Option::is_some)
    }

    /// The six error-motion values of the axis `letter` at `q` after moving in `dir`
    /// (`EX? EY? EZ?` mm, `EA? EB? EC?` rad); zero for an axis without error motions.
    pub fn error_motion_values(&self, letter: AxisLetter, q: Real, dir: Direction) -> [Real; 6] {
        self.error_motions(letter)
            .map_or([0.0; 6], |e| e.values(q, dir))
    }

    /// The centre the angular error motions of axis `i` turn about: the rotary axis's
    /// origin, the frame origin of a linear axis.
    pub fn error_centre(&self, i: usize) -> Point3 {
        match self.axes[i].kind {
            AxisKind::Rotary => self.axes[i].origin,
            AxisKind::Linear => Point3::origin(),
        }
    }

    /// The error-motion transform `Err_i` of axis `i` at `q` after moving in `dir`, `None`
    /// for an axis without error motions.
    pub fn error_transform(&self, i: usize, q: Real, dir: Direction) -> Option<Isometry3> {
        self.errors[i]
            .as_ref()
            .map(|e| error_motion::transform(&e.values(q, dir), &self.error_centre(i)))
    }

    /// Applies an ISO 230-1 / 230-7 location or squareness term by its name, composed
    /// exactly onto the joint deviations around the axis it names (see docs/scenes.md):
    ///
    /// - location of a rotary axis: `EY0A`/`Y0A`, `EZ0A`, `EB0A`, `EC0A` for A (offsets of
    ///   its line across it, mm; tilts of its line, rad), likewise `EX0B`, `EZ0B`, `EA0B`,
    ///   `EC0B` and `EX0C`, `EY0C`, `EA0C`, `EB0C`;
    /// - squareness of a linear axis to another: `EC(0X)Y` (or `EC0XY`): Y's line of motion
    ///   turned by the value (rad) about +Z, X the reference; any `E<r>(0<ref>)<axis>` with
    ///   `<r>` the rotation about the third direction.
    ///
    /// The term is the transform `L` (offset or tilt about the axis origin) that takes the
    /// nominal line to the actual one: the axis motion becomes `L·M·L⁻¹`, so the joint
    /// before the axis becomes `E·L` and the joint after it `L⁻¹·E`. For the first axis of
    /// the chain the `L` next to the workpiece frame only moves that frame (the workpiece
    /// zero) and is left out.
    pub fn apply_iso_term(&mut self, name: &str, value: Real) -> Result<(), KinematicsError> {
        let (i, values) = self.iso_term(name, value)?;
        self.apply_term_values(i, &values);
        Ok(())
    }

    /// [`Chain::apply_iso_term`], taking also the two terms of a rotary axis that are not
    /// location errors — its offset along its own line and the zero of its angle — as
    /// [`Chain::iso_term_id`] takes them for identification: what an identification that
    /// solved for them applies (on the first axis they move the rest of the machine against
    /// the workpiece frame; elsewhere they leave the motion unchanged).
    pub fn apply_identified_term(
        &mut self,
        name: &str,
        value: Real,
    ) -> Result<(), KinematicsError> {
        let (i, values) = self.iso_term_with(name, value, true)?;
        self.apply_term_values(i, &values);
        Ok(())
    }

    fn apply_term_values(&mut self, i: usize, values: &[Real; 6]) {
        let l = error_motion::transform(values, &self.error_centre(i));
        let after = l.inverse() * self.deviations[i].transform();
        self.deviations[i] = Deviation::from_transform(&after);
        if i > 0 {
            let before = self.deviations[i - 1].transform() * l;
            self.deviations[i - 1] = Deviation::from_transform(&before);
        }
    }

    /// The joint an ISO location or squareness term acts on and its component of `L`: the
    /// axis index `i` and the component (offset across the axis or tilt), as
    /// [`Chain::apply_iso_term`] applies it — for parameterising an identification by the
    /// names users know (`EX0C`, `EB0C`, `EC(0X)Y`).
    ///
    /// For identification it also takes the two terms of a rotary axis that are not location
    /// errors — the offset along its own line and the zero of its angle (`EZ0C`, `EC0C`) —
    /// so a report can say what a test cannot determine: on the first axis of the chain they
    /// move the rest of the machine against the workpiece frame; elsewhere they leave the
    /// motion unchanged (`L` commutes with the rotation).
    pub fn iso_term_id(&self, name: &str) -> Result<(usize, Component), KinematicsError> {
        let (i, v) = self.iso_term_with(name, 1.0, true)?;
        let c = Component::ALL
            .into_iter()
            .find(|c| v[*c as usize] != 0.0)
            .unwrap_or(Component::Dx);
        Ok((i, c))
    }

    /// The ISO 230-7 location terms of every rotary axis of the chain, in chain order: per
    /// rotary axis the two offsets across it and the two tilts of its line (`EX0C`,
    /// `EY0C`, `EA0C`, `EB0C` for C; `EY0A`, `EZ0A`, `EB0A`, `EC0A` for A; …). For a rotary
    /// axis first in the chain (a table carrying the workpiece) also its offset along
    /// itself and the zero of its angle (`EZ0C`, `EC0C`): not location errors, but what a
    /// user asks about and a table-side test cannot see — an identification names them
    /// as not determined. Elsewhere those two leave the motion unchanged and are left out.
    pub fn rotary_location_terms(&self) -> Vec<String> {
        let letters = ['X', 'Y', 'Z', 'A', 'B', 'C'];
        let mut out = Vec::new();
        for (i, a) in self.axes.iter().enumerate() {
            if a.kind != AxisKind::Rotary || !a.letter.is_rotary() {
                continue;
            }
            let own = a.letter.index() - 3;
            for (k, c) in letters.iter().enumerate() {
                if k % 3 != own || i == 0 {
                    out.push(format!("E{c}0{}", a.letter.as_char()));
                }
            }
        }
        out
    }

    /// The values of the linear axes that put the point `point_t` of the tool frame at
    /// `target` (workpiece frame) with the rotary axes at their values in `q`, every axis as
    /// last moved in `dirs`: the
    /// inverse kinematics a controller runs (on the nominal chain) and the position a probe
    /// finds (on the actual one). With the rotary axes fixed the tool point is affine in the
    /// linear axes on a chain without error motions, so Newton's method converges in one
    /// step; error motions make it nonlinear and it iterates to 1e-10 mm. `None` when the
    /// linear axes do not span three directions or it does not converge.
    pub fn solve_linear_axes(
        &self,
        q: &AxisValues,
        point_t: &Point3,
        target: &Point3,
        dirs: &Directions,
    ) -> Option<AxisValues> {
        let linear: Vec<AxisLetter> = self
            .axes
            .iter()
            .filter(|a| a.kind == AxisKind::Linear)
            .map(|a| a.letter)
            .collect();
        if linear.len() != 3 {
            return None;
        }
        let mut q = *q;
        const STEP_MM: Real = 1.0;
        let at = |q: &AxisValues| self.w_from_t_dir(q, dirs) * point_t;
        for _ in 0..20 {
            let p = at(&q);
            let r = target - p;
            if r.norm() <= 1e-10 {
                return Some(q);
            }
            let mut j = crate::math::Matrix3::zeros();
            for (k, l) in linear.iter().enumerate() {
                let dp = at(&q.with(*l, q.get(*l) + STEP_MM)) - p;
                j.set_column(k, &(dp / STEP_MM));
            }
            let dq = j.lu().solve(&r)?;
            if !dq.iter().all(|v| v.is_finite()) {
                return None;
            }
            for (k, l) in linear.iter().enumerate() {
                q.set(*l, q.get(*l) + dq[k]);
            }
        }
        None
    }

    /// Parses a location or squareness name: the axis index and the six values of `L`.
    fn iso_term(&self, name: &str, value: Real) -> Result<(usize, [Real; 6]), KinematicsError> {
        self.iso_term_with(name, value, false)
    }

    /// [`Chain::iso_term`], taking a rotary axis's own-direction terms when `own` is set.
    fn iso_term_with(
        &self,
        name: &str,
        value: Real,
        own: bool,
    ) -> Result<(usize, [Real; 6]), KinematicsError> {
        let unknown = || KinematicsError::UnknownIsoName {
            name: name.to_string(),
            expected: "rotary axis location as EY0A, Y0A, EB0A …; squareness as EC(0X)Y, \
                       EB(0X)Z, EA(0Y)Z …; error motions as EXX, EBX … go in [error_motions]"
                .to_string(),
        };
        let letters: Vec<char> = name.chars().filter(|c| !matches!(c, '(' | ')')).collect();
        let letters: &[char] = match letters.first() {
            Some('E') => &letters[1..],
            _ => &letters[..],
        };
        let l = |c: char| AxisLetter::from_char(c);
        let mut v = [0.0; 6];
        match letters {
            // Location: <c>0<axis>, axis rotary, c across it.
            [c, '0', a] => {
                let (Some(c), Some(a)) = (l(*c), l(*a)) else {
                    return Err(unknown());
                };
                if !a.is_rotary() {
                    return Err(unknown());
                }
                // The rotary's own direction and rotation about it are not location terms.
                if c.index() % 3 == a.index() - 3 && !own {
                    return Err(unknown());
                }
                let i = self.index_of(a).ok_or_else(|| self.missing_axis(name, a))?;
                v[error_motion::component_of(c) as usize] = value;
                Ok((i, v))
            }
            // Squareness: <r>0<ref><axis>, r a rotation about the third direction.
            [r, '0', re, a] => {
                let (Some(r), Some(re), Some(a)) = (l(*r), l(*re), l(*a)) else {
                    return Err(unknown());
                };
                if !r.is_rotary() || re.is_rotary() || a.is_rotary() || re == a {
                    return Err(unknown());
                }
                if r.index() - 3 == re.index() || r.index() - 3 == a.index() {
                    return Err(unknown());
                }
                let i = self.index_of(a).ok_or_else(|| self.missing_axis(name, a))?;
                if !self.has_axis(re) {
                    return Err(self.missing_axis(name, re));
                }
                v[error_motion::component_of(r) as usize] = value;
                Ok((i, v))
            }
            _ => Err(unknown()),
        }
    }

    /// Whether the axis for `letter` is in the chain.
    pub fn has_axis(&self, letter: AxisLetter) -> bool {
        self.axes.iter().any(|a| a.letter == letter)
    }

    /// The tool's pose in the workpiece frame for axis values `q` (mm, degrees), every
    /// axis taken as last moved in `+` (see [`Chain::w_from_t_dir`]).
    pub fn w_from_t(&self, q: &AxisValues) -> Isometry3 {
        self.w_from_t_dir(q, &Directions::default())
    }

    /// The tool's pose in the workpiece frame for axis values `q` with each axis's error
    /// motions at its value and its reversal for the direction in `dirs`:
    /// `Π M_i(q_i)·Err_i(q_i, dir_i)·E_i`. Without error motions it is `Π M_i(q_i)·E_i`,
    /// whatever `dirs`.
    pub fn w_from_t_dir(&self, q: &AxisValues, dirs: &Directions) -> Isometry3 {
        self.w_from_t_state(q, &self.reversal_state(dirs))
    }

    /// The reversal share each axis carries after last moving in `dirs`: `±B/2` per axis
    /// (indexed by [`AxisLetter::index`]; zero for axes without a reversal).
    pub fn reversal_state(&self, dirs: &Directions) -> [Real; 6] {
        let mut out = [0.0; 6];
        for (axis, e) in self.axes.iter().zip(&self.errors) {
            if let Some(e) = e {
                out[axis.letter.index()] = e.settled_offset(dirs.get(axis.letter));
            }
        }
        out
    }

    /// The reversal shares after the move `start → end` from `state`: each moving axis
    /// takes up its lost motion at the commanded rate
    /// ([`AxisErrorMotions::offset_after`]).
    pub fn reversal_after_move(
        &self,
        state: &[Real; 6],
        start: &AxisValues,
        end: &AxisValues,
    ) -> [Real; 6] {
        let mut out = *state;
        for (axis, e) in self.axes.iter().zip(&self.errors) {
            if let Some(e) = e {
                let l = axis.letter;
                out[l.index()] = e.offset_after(state[l.index()], end.get(l) - start.get(l));
            }
        }
        out
    }

    /// The tool's pose with each axis carrying the reversal share `state[letter]` (see
    /// [`Chain::reversal_state`]); the general form of [`Chain::w_from_t_dir`].
    pub fn w_from_t_state(&self, q: &AxisValues, state: &[Real; 6]) -> Isometry3 {
        let mut pose = Isometry3::identity();
        for (i, (axis, dev)) in self.axes.iter().zip(&self.deviations).enumerate() {
            let qi = q.get(axis.letter);
            pose *= axis.motion(qi);
            if let Some(e) = &self.errors[i] {
                let v = e.values_with_offset(qi, state[axis.letter.index()]);
                pose *= error_motion::transform(&v, &self.error_centre(i));
            }
            pose *= dev.transform();
        }
        pose
    }

    /// The tool tip (the origin of T) in the workpiece frame: what an instrument between
    /// the spindle and the table (laser, ball bar) follows.
    pub fn tool_point(&self, q: &AxisValues, dirs: &Directions) -> Point3 {
        self.w_from_t_dir(q, dirs) * Point3::origin()
    }

    /// The rotary axes as lines in the workpiece frame for axis values `q`: a point on each
    /// and its unit direction (used to bound the speed and curvature of rotary moves).
    pub fn rotary_lines_in_w(&self, q: &AxisValues) -> Vec<(Point3, Vector3)> {
        let mut pose = Isometry3::identity();
        let mut out = Vec::new();
        for (i, (axis, dev)) in self.axes.iter().zip(&self.deviations).enumerate() {
            if axis.kind == AxisKind::Rotary {
                out.push((
                    pose * axis.origin,
                    pose.rotation * axis.direction.into_inner(),
                ));
            }
            let qi = q.get(axis.letter);
            pose *= axis.motion(qi);
            if let Some(err) = self.error_transform(i, qi, Direction::Positive) {
                pose *= err;
            }
            pose *= dev.transform();
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

/// The location errors of `scenes/trunnion-ac.toml` in the chain's names.
#[cfg(test)]
pub(crate) const TRUNNION_DEVIATIONS: [(&str, Real); 8] = [
    ("dx_CA", 0.020),
    ("dy_CA", -0.015),
    ("alpha_CA", 40e-6),
    ("beta_CA", -30e-6),
    ("dy_AY", 0.030),
    ("dz_AY", -0.025),
    ("beta_AY", 60e-6),
    ("gamma_AY", 25e-6),
];

/// The trunnion of `scenes/trunnion-ac.toml`: C table on the A cradle (A's line 50 mm below
/// the table), spindle on Y, X, Z; C's line offset and tilted (`*_CA`), A's line offset and
/// tilted (`*_AY`) by [`TRUNNION_DEVIATIONS`]: the chain the unit tests of simultaneous
/// 5-axis moves build on.
#[cfg(test)]
pub(crate) fn trunnion_for_tests() -> Chain {
    let ax = |letter, kind, d: Vector3, o: Point3| Axis {
        letter,
        kind,
        direction: UnitVector3::new_normalize(d),
        origin: o,
    };
    let o = Point3::origin();
    let mut c = Chain::new(
        vec![
            ax(AxisLetter::C, AxisKind::Rotary, Vector3::z(), o),
            ax(
                AxisLetter::A,
                AxisKind::Rotary,
                Vector3::x(),
                Point3::new(0.0, 0.0, -50.0),
            ),
            ax(AxisLetter::Y, AxisKind::Linear, Vector3::y(), o),
            ax(AxisLetter::X, AxisKind::Linear, Vector3::x(), o),
            ax(AxisLetter::Z, AxisKind::Linear, Vector3::z(), o),
        ],
        "S",
    )
    .expect("valid chain");
    for (n, v) in TRUNNION_DEVIATIONS {
        c.set_deviation(c.deviation_id(n).expect("known"), v);
    }
    c
}

/// A 3-axis mill, X, Y, Z from the workpiece (spindle S), nominal: the chain the
/// instruments' unit tests build on.
#[cfg(test)]
pub(crate) fn xyz_for_tests() -> Chain {
    Chain::cartesian([AxisLetter::X, AxisLetter::Y, AxisLetter::Z]).expect("valid chain")
}

/// A chain read pose by pose, as a hexapod is: the sweep sees only its poses.
#[cfg(test)]
pub(crate) struct ChainPoses(pub Chain);

#[cfg(test)]
impl crate::machine::PoseSource for ChainPoses {
    fn has_axis(&self, axis: AxisLetter) -> bool {
        self.0.has_axis(axis)
    }

    fn w_from_t(&self, q: &AxisValues) -> Result<Isometry3, crate::machine::PoseError> {
        Ok(self.0.w_from_t(q))
    }

    fn commanded(&self, q: &AxisValues) -> Isometry3 {
        self.0.w_from_t(q)
    }

    fn is_translation(&self, start: &AxisValues, end: &AxisValues) -> bool {
        AxisLetter::ALL
            .into_iter()
            .all(|l| !l.is_rotary() || start.get(l) == end.get(l))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cartesian_chain_puts_the_tip_at_the_axis_values_and_refuses_bad_letters() {
        use AxisLetter::{A, X, Y, Z};
        for order in [[X, Y, Z], [Y, X, Z], [Z, X, Y]] {
            let c = Chain::cartesian(order).expect("valid");
            let q = AxisValues::from_array([1.5, -2.25, 3.0, 0.0, 0.0, 0.0]);
            let t = c.w_from_t(&q);
            assert_eq!(t.translation.vector, Vector3::new(1.5, -2.25, 3.0));
            assert_eq!(t.rotation, nalgebra::UnitQuaternion::identity());
        }
        assert_eq!(
            Chain::cartesian([X, A, Z]).err(),
            Some(KinematicsError::BadDirection('A'))
        );
        assert_eq!(
            Chain::cartesian([X, Y, X]).err(),
            Some(KinematicsError::DuplicateAxis('X'))
        );
    }

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

    /// `Tx·Err_X·Ty·Tz` built here from 4×4 matrices of the definition.
    #[test]
    fn error_motions_enter_the_pose_exactly() {
        use crate::machine::error_motion::{AxisErrorMotions, Term};
        let ax = |letter, d: Vector3| Axis {
            letter,
            kind: AxisKind::Linear,
            direction: UnitVector3::new_normalize(d),
            origin: Point3::origin(),
        };
        let mut c = Chain::new(
            vec![
                ax(AxisLetter::X, Vector3::x()),
                ax(AxisLetter::Y, Vector3::y()),
                ax(AxisLetter::Z, Vector3::z()),
            ],
            "S",
        )
        .expect("valid");
        let plain = c.clone();
        let mut e = AxisErrorMotions::for_axis(AxisLetter::X);
        e.functions[0].terms = vec![Term::polynomial(vec![0.01, 1e-4]).expect("valid")];
        e.functions[4].terms = vec![Term::polynomial(vec![2e-4]).expect("valid")];
        e.reversal = -0.004;
        c.set_error_motions(AxisLetter::X, e).expect("axis");
        let q = AxisValues::default()
            .with(AxisLetter::X, 20.0)
            .with(AxisLetter::Y, 5.0)
            .with(AxisLetter::Z, 30.0);
        let t = |x: Real, y: Real, z: Real| {
            let mut m = nalgebra::Matrix4::identity();
            m[(0, 3)] = x;
            m[(1, 3)] = y;
            m[(2, 3)] = z;
            m
        };
        let (s, co) = (2e-4 as Real).sin_cos();
        let mut ry = nalgebra::Matrix4::identity();
        ry[(0, 0)] = co;
        ry[(0, 2)] = s;
        ry[(2, 0)] = -s;
        ry[(2, 2)] = co;
        for (dir, half) in [(Direction::Positive, -0.002), (Direction::Negative, 0.002)] {
            let err = t(0.01 + 1e-4 * 20.0 + half, 0.0, 0.0) * ry;
            let want = t(20.0, 0.0, 0.0) * err * t(0.0, 5.0, 0.0) * t(0.0, 0.0, 30.0);
            let dirs = Directions::default().with(AxisLetter::X, dir);
            let got = c.w_from_t_dir(&q, &dirs).to_homogeneous();
            assert!((got - want).abs().max() < 1e-12, "{dir:?}");
        }
        // Abbe: the tip 30 above the X frame's origin moves by 30·sin(β) in X.
        let tip = c.tool_point(&q, &Directions::default());
        assert!((tip.x - (20.0 + 0.012 - 0.002 + 30.0 * s)).abs() < 1e-12);
        // Zero error motions are dropped: the chain computes as one without, bit for bit.
        let mut z = plain.clone();
        z.set_error_motions(AxisLetter::X, AxisErrorMotions::for_axis(AxisLetter::X))
            .expect("axis");
        assert!(!z.has_error_motions());
        assert_eq!(z.w_from_t(&q), plain.w_from_t(&q));
        assert!(
            c.set_error_motions(AxisLetter::A, AxisErrorMotions::for_axis(AxisLetter::A))
                .is_err()
        );
    }

    #[test]
    fn deviation_from_transform_inverts_transform() {
        let d = Deviation {
            values: [0.1, -0.2, 0.3, 1e-3, -2e-3, 3e-3],
        };
        let back = Deviation::from_transform(&d.transform());
        for k in 0..6 {
            assert!((back.values[k] - d.values[k]).abs() < 1e-15, "{k}");
        }
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
