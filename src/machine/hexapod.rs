//! The hexapod (Stewart platform): six struts of variable length between six base joints
//! `b_i` (base frame) and six platform joints `a_i` (platform frame), in the conventions of
//! LinuxCNC's genhexkins.
//!
//! A pose is `(x, y, z, a, b, c)`: the tool point's position in the base frame (mm) and the
//! platform's orientation `R = Rz(c)·Ry(b)·Rx(a)` (degrees at the interfaces, radians
//! inside). With `o` the tool point in the platform frame (the tool offset; zero in
//! genhexkins), strut i is
//!
//! ```text
//! L_i = |t + R·(a_i − o) − b_i|
//! ```
//!
//! The drives read `s_i = L_i − l0_i`: `l0_i` is the strut's reference length, its length
//! where its encoder reads zero (set at homing). The 42 kinematic parameters are the 18
//! base-joint coordinates `bx_i, by_i, bz_i`, the 18 platform-joint coordinates
//! `ax_i, ay_i, az_i` and the six reference lengths `l0_i` (i = 1…6); a deviation of `l0_i`
//! is a strut-length offset (the strut is that much longer than the controller believes for
//! every reading). The controller turns a command into readings on the nominal parameters;
//! the machine moves to the pose those readings give on its actual parameters:
//! `pose = FK_actual(IK_nominal(command))` ([`twin_pose`]).
//!
//! Inverse kinematics is closed form; forward kinematics is Newton–Raphson from a nearby
//! pose (a general 6-6 platform has up to 40 assembly modes: the one nearest the start is
//! found). The Jacobians are analytic: strut lengths with respect to the pose
//! ([`Hexapod::strut_jacobian`]), the pose rates from strut rates (its inverse,
//! [`Hexapod::output_jacobian`]), the readings with respect to the 42 parameters
//! ([`Hexapod::parameter_jacobian`]) and the pose with respect to the parameters at fixed
//! readings ([`Hexapod::pose_parameter_jacobian`]).
//!
//! **Invariant:** a `Hexapod` is finite by construction; forward kinematics returns a pose
//! whose strut residual is at most [`tol::STRUT_RESIDUAL`], or an error saying why not
//! (no convergence, a singular Jacobian, a strut out of its stroke, a joint past its limit),
//! never a number it did not solve. Knows nothing of files, scenes or NC programs.

use crate::machine::chain::Chain;
use crate::machine::{PoseError, PoseSource};
use crate::math::{Isometry3, Matrix3, Real, UnitVector3, Vector3, tol};
use crate::nc::{AxisLetter, AxisValues};
use nalgebra::{Matrix6, SMatrix, Vector6};
use std::fmt;

/// Number of struts.
pub const STRUTS: usize = 6;
/// Number of kinematic parameters: 18 base-joint, 18 platform-joint coordinates, 6 reference
/// lengths.
pub const PARAMETERS: usize = 42;
/// Newton–Raphson iterations forward kinematics may take (genhexkins' limit).
pub const FK_MAX_ITERATIONS: usize = 120;

/// Strut lengths or readings, strut 1 first (mm).
pub type Struts = [Real; STRUTS];
/// The readings' or the pose's derivatives with respect to the 42 parameters.
pub type ParameterJacobian = SMatrix<Real, 6, PARAMETERS>;

/// Errors of the hexapod's kinematics and parameter names.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum HexapodError {
    /// A parameter name that is not one of the 42.
    #[error("unknown hexapod parameter '{name}' (expected bx_1 … bz_6, ax_1 … az_6, l0_1 … l0_6)")]
    UnknownParameter {
        /// The name as given.
        name: String,
    },
    /// A coordinate, length, pose or limit is NaN or infinite.
    #[error("{0} must be finite")]
    NonFinite(String),
    /// A geometry that cannot be a hexapod (coincident joints, an empty stroke, …).
    #[error("{0}")]
    Geometry(String),
    /// Newton–Raphson did not reach the strut tolerance.
    #[error(
        "forward kinematics did not converge in {iterations} iterations (strut residual {residual_mm:.3e} mm): start nearer the pose"
    )]
    NotConverged {
        /// Iterations taken.
        iterations: usize,
        /// Largest strut residual at the end (mm; infinite if it diverged).
        residual_mm: Real,
    },
    /// The strut Jacobian is singular (or nearly) at a pose: the platform can move with the
    /// struts locked, or the orientation is at b = ±90° where the angles are not unique.
    #[error("singular pose {pose}: the strut Jacobian has no inverse there")]
    Singular {
        /// The pose (mm, degrees).
        pose: String,
    },
    /// A strut length outside its stroke.
    #[error("strut {strut} length {length_mm:.4} mm is outside its stroke [{min_mm}, {max_mm}] mm")]
    OutOfStroke {
        /// 1-based strut.
        strut: usize,
        /// The length (mm).
        length_mm: Real,
        /// Shortest length (mm).
        min_mm: Real,
        /// Longest length (mm).
        max_mm: Real,
    },
    /// A joint bent past its limit.
    #[error("{joint} joint {strut} bends {angle_deg:.2}°, past its limit of {limit_deg}°")]
    JointLimit {
        /// `base` or `platform`.
        joint: &'static str,
        /// 1-based strut.
        strut: usize,
        /// The joint angle (degrees).
        angle_deg: Real,
        /// The limit (degrees).
        limit_deg: Real,
    },
}

/// A pose of the tool frame in the base frame: position (mm) and the angles a, b, c (rad)
/// of `R = Rz(c)·Ry(b)·Rx(a)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    /// The tool point (mm, base frame).
    pub position: Vector3,
    /// a, b, c (rad).
    pub angles: Vector3,
}

impl Pose {
    /// The pose of `[x, y, z, a, b, c]` in mm and degrees.
    pub fn from_mm_deg(v: [Real; 6]) -> Pose {
        Pose {
            position: Vector3::new(v[0], v[1], v[2]),
            angles: Vector3::new(v[3].to_radians(), v[4].to_radians(), v[5].to_radians()),
        }
    }

    /// `[x, y, z, a, b, c]` in mm and degrees.
    pub fn to_mm_deg(&self) -> [Real; 6] {
        let (p, a) = (self.position, self.angles);
        [
            p.x,
            p.y,
            p.z,
            a.x.to_degrees(),
            a.y.to_degrees(),
            a.z.to_degrees(),
        ]
    }

    /// The pose as the vector `(x, y, z, a, b, c)` in mm and rad (the Jacobians' order).
    pub fn to_vector(&self) -> Vector6<Real> {
        Vector6::new(
            self.position.x,
            self.position.y,
            self.position.z,
            self.angles.x,
            self.angles.y,
            self.angles.z,
        )
    }

    /// The pose of the vector `(x, y, z, a, b, c)` in mm and rad.
    pub fn from_vector(v: &Vector6<Real>) -> Pose {
        Pose {
            position: Vector3::new(v[0], v[1], v[2]),
            angles: Vector3::new(v[3], v[4], v[5]),
        }
    }

    /// Whether all six numbers are finite.
    pub fn is_finite(&self) -> bool {
        self.to_vector().iter().all(|c| c.is_finite())
    }

    /// `R = Rz(c)·Ry(b)·Rx(a)`.
    pub fn rotation(&self) -> Matrix3 {
        Trig::of(&self.angles).rotation()
    }
}

impl fmt::Display for Pose {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let v = self.to_mm_deg();
        write!(
            f,
            "({:.4}, {:.4}, {:.4} mm, {:.4}, {:.4}, {:.4}°)",
            v[0], v[1], v[2], v[3], v[4], v[5]
        )
    }
}

/// Sines and cosines of a, b, c, and what is built from them.
struct Trig {
    sa: Real,
    ca: Real,
    sb: Real,
    cb: Real,
    sc: Real,
    cc: Real,
}

impl Trig {
    fn of(angles: &Vector3) -> Trig {
        let (sa, ca) = angles.x.sin_cos();
        let (sb, cb) = angles.y.sin_cos();
        let (sc, cc) = angles.z.sin_cos();
        Trig {
            sa,
            ca,
            sb,
            cb,
            sc,
            cc,
        }
    }

    /// `Rz(c)·Ry(b)·Rx(a)`.
    fn rotation(&self) -> Matrix3 {
        let Trig {
            sa,
            ca,
            sb,
            cb,
            sc,
            cc,
        } = *self;
        Matrix3::new(
            cc * cb,
            cc * sb * sa - sc * ca,
            cc * sb * ca + sc * sa,
            sc * cb,
            sc * sb * sa + cc * ca,
            sc * sb * ca - cc * sa,
            -sb,
            cb * sa,
            cb * ca,
        )
    }

    /// The world axes the three angles turn about: ∂R/∂a·p = ω_a × R·p, likewise for b
    /// (ω_b = Rz(c)·e_y) and c (ω_c = e_z).
    fn axes(&self) -> [Vector3; 3] {
        [
            Vector3::new(self.cc * self.cb, self.sc * self.cb, -self.sb),
            Vector3::new(-self.sc, self.cc, 0.0),
            Vector3::z(),
        ]
    }
}

/// Which of the three kinds a parameter is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum ParameterKind {
    /// A base-joint coordinate (`bx_i`, `by_i`, `bz_i`; mm, base frame).
    BaseJoint,
    /// A platform-joint coordinate (`ax_i`, `ay_i`, `az_i`; mm, platform frame).
    PlatformJoint,
    /// A strut reference length (`l0_i`; mm).
    Reference,
}

/// One of the 42 parameters, by index: 0–17 the base joints (`bx_1, by_1, bz_1, bx_2, …`),
/// 18–35 the platform joints (`ax_1, …, az_6`), 36–41 the reference lengths (`l0_1, …`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ParameterId(usize);

impl ParameterId {
    /// The parameter of index `index` (< 42).
    pub fn new(index: usize) -> Option<ParameterId> {
        (index < PARAMETERS).then_some(ParameterId(index))
    }

    /// All 42, in index order.
    pub fn all() -> impl Iterator<Item = ParameterId> {
        (0..PARAMETERS).map(ParameterId)
    }

    /// The index (0–41).
    pub fn index(self) -> usize {
        self.0
    }

    /// Its kind.
    pub fn kind(self) -> ParameterKind {
        match self.0 {
            0..18 => ParameterKind::BaseJoint,
            18..36 => ParameterKind::PlatformJoint,
            _ => ParameterKind::Reference,
        }
    }

    /// The 1-based strut it belongs to.
    pub fn strut(self) -> usize {
        match self.kind() {
            ParameterKind::Reference => self.0 - 36 + 1,
            _ => (self.0 % 18) / 3 + 1,
        }
    }

    /// The coordinate (0, 1, 2 for x, y, z) of a joint parameter; `None` for `l0_i`.
    pub fn coordinate(self) -> Option<usize> {
        (self.0 < 36).then_some(self.0 % 3)
    }

    /// Its name: `bx_1`, …, `az_6`, `l0_1`, ….
    pub fn name(self) -> String {
        let i = self.strut();
        match (self.kind(), self.coordinate()) {
            (ParameterKind::Reference, _) | (_, None) => format!("l0_{i}"),
            (ParameterKind::BaseJoint, Some(k)) => format!("b{}_{i}", ['x', 'y', 'z'][k]),
            (ParameterKind::PlatformJoint, Some(k)) => format!("a{}_{i}", ['x', 'y', 'z'][k]),
        }
    }

    /// The parameter named `name`.
    pub fn from_name(name: &str) -> Result<ParameterId, HexapodError> {
        let unknown = || HexapodError::UnknownParameter {
            name: name.to_string(),
        };
        let (head, strut) = name.split_once('_').ok_or_else(unknown)?;
        let i = match strut {
            "1" | "2" | "3" | "4" | "5" | "6" => strut.parse::<usize>().map_err(|_| unknown())? - 1,
            _ => return Err(unknown()),
        };
        let index = match head {
            "l0" => 36 + i,
            _ => {
                let mut c = head.chars();
                let base = match c.next() {
                    Some('b') => 0,
                    Some('a') => 18,
                    _ => return Err(unknown()),
                };
                let k = match (c.next(), c.next()) {
                    (Some('x'), None) => 0,
                    (Some('y'), None) => 1,
                    (Some('z'), None) => 2,
                    _ => return Err(unknown()),
                };
                base + 3 * i + k
            }
        };
        Ok(ParameterId(index))
    }
}

impl fmt::Display for ParameterId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.name())
    }
}

/// Where the struts and joints may go. Stroke and joint limits are optional (`None`: no
/// limit).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Limits {
    /// Shortest and longest strut length (mm), the same for every strut.
    pub stroke_mm: Option<(Real, Real)>,
    /// The base joints' axis (base frame): the strut direction at zero joint angle.
    pub base_axis: UnitVector3,
    /// The largest angle between a strut and the base joints' axis (rad).
    pub base_max_rad: Option<Real>,
    /// The platform joints' axis (platform frame), pointing from the platform joint towards
    /// the base joint at zero joint angle.
    pub platform_axis: UnitVector3,
    /// The largest angle between a strut and the platform joints' axis (rad).
    pub platform_max_rad: Option<Real>,
}

impl Limits {
    /// No limits (joint axes +z for the base, −z for the platform).
    pub fn none() -> Limits {
        Limits {
            stroke_mm: None,
            base_axis: Vector3::z_axis(),
            base_max_rad: None,
            platform_axis: -Vector3::z_axis(),
            platform_max_rad: None,
        }
    }
}

/// The result of forward kinematics: the pose and how it was found.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FkSolution {
    /// The pose.
    pub pose: Pose,
    /// Newton iterations taken.
    pub iterations: usize,
    /// Largest |L_i(pose) − L_i| at the pose (mm).
    pub residual_mm: Real,
}

/// Resolution amplification factors at a pose (seed 001): the root sum of squares of the
/// input→output Jacobian's position rows and of its angle rows.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Amplification {
    /// K_p: position output per strut input (mm/mm).
    pub position_mm_per_mm: Real,
    /// K_a: angle output per strut input (°/mm).
    pub angle_deg_per_mm: Real,
}

/// A Stewart platform: joints, reference lengths, tool offset and limits (see the module
/// docs for the conventions and the parameter names).
#[derive(Clone, Debug, PartialEq)]
pub struct Hexapod {
    base: [Vector3; STRUTS],
    platform: [Vector3; STRUTS],
    reference: Struts,
    tool: Vector3,
    limits: Limits,
}

impl Hexapod {
    /// A hexapod from its base joints `b_i` (base frame, mm), platform joints `a_i`
    /// (platform frame, mm), reference lengths `l0_i` (mm), the tool point in the platform
    /// frame (mm) and the limits. Every number must be finite, a stroke must have
    /// `0 < min < max`, joint limits must lie in (0°, 180°]. Joints may coincide (genhexkins'
    /// default geometry pairs its base joints); a geometry that cannot hold a pose shows as
    /// a singular Jacobian there.
    pub fn try_new(
        base: [Vector3; STRUTS],
        platform: [Vector3; STRUTS],
        reference: Struts,
        tool: Vector3,
        limits: Limits,
    ) -> Result<Hexapod, HexapodError> {
        let finite = |v: &Vector3| v.iter().all(|c| c.is_finite());
        for i in 0..STRUTS {
            if !finite(&base[i]) {
                return Err(HexapodError::NonFinite(format!("base joint {}", i + 1)));
            }
            if !finite(&platform[i]) {
                return Err(HexapodError::NonFinite(format!("platform joint {}", i + 1)));
            }
            if !reference[i].is_finite() {
                return Err(HexapodError::NonFinite(format!("l0_{}", i + 1)));
            }
        }
        if !finite(&tool) {
            return Err(HexapodError::NonFinite("the tool offset".into()));
        }
        if let Some((lo, hi)) = limits.stroke_mm
            && !(lo.is_finite() && hi.is_finite() && 0.0 < lo && lo < hi)
        {
            return Err(HexapodError::Geometry(format!(
                "the stroke [{lo}, {hi}] mm must have 0 < min < max"
            )));
        }
        for (what, m) in [
            ("base joint limit", limits.base_max_rad),
            ("platform joint limit", limits.platform_max_rad),
        ] {
            if let Some(m) = m
                && !(m.is_finite() && m > 0.0 && m <= std::f64::consts::PI)
            {
                return Err(HexapodError::Geometry(format!(
                    "the {what} {}° must lie in (0°, 180°]",
                    m.to_degrees()
                )));
            }
        }
        Ok(Hexapod {
            base,
            platform,
            reference,
            tool,
            limits,
        })
    }

    /// The base joints `b_i` (base frame, mm).
    pub fn base_joints(&self) -> &[Vector3; STRUTS] {
        &self.base
    }

    /// The platform joints `a_i` (platform frame, mm).
    pub fn platform_joints(&self) -> &[Vector3; STRUTS] {
        &self.platform
    }

    /// The reference lengths `l0_i` (mm).
    pub fn reference_lengths(&self) -> &Struts {
        &self.reference
    }

    /// The tool point in the platform frame (mm).
    pub fn tool_offset(&self) -> Vector3 {
        self.tool
    }

    /// The limits.
    pub fn limits(&self) -> &Limits {
        &self.limits
    }

    /// The value of one parameter (mm).
    pub fn parameter(&self, id: ParameterId) -> Real {
        let (i, k) = (id.strut() - 1, id.coordinate());
        match (id.kind(), k) {
            (ParameterKind::BaseJoint, Some(k)) => self.base[i][k],
            (ParameterKind::PlatformJoint, Some(k)) => self.platform[i][k],
            _ => self.reference[i],
        }
    }

    /// Sets one parameter (mm); a non-finite value is refused.
    pub fn set_parameter(&mut self, id: ParameterId, value: Real) -> Result<(), HexapodError> {
        if !value.is_finite() {
            return Err(HexapodError::NonFinite(id.name()));
        }
        let (i, k) = (id.strut() - 1, id.coordinate());
        match (id.kind(), k) {
            (ParameterKind::BaseJoint, Some(k)) => self.base[i][k] = value,
            (ParameterKind::PlatformJoint, Some(k)) => self.platform[i][k] = value,
            _ => self.reference[i] = value,
        }
        Ok(())
    }

    /// The value of the parameter named `name` (mm).
    pub fn parameter_by_name(&self, name: &str) -> Result<Real, HexapodError> {
        Ok(self.parameter(ParameterId::from_name(name)?))
    }

    /// Adds `delta` to the parameter named `name`: a deviation of the actual machine from
    /// the nominal one (mm).
    pub fn add_deviation(&mut self, name: &str, delta: Real) -> Result<(), HexapodError> {
        let id = ParameterId::from_name(name)?;
        self.set_parameter(id, self.parameter(id) + delta)
    }

    /// All 42 parameters in index order (mm).
    pub fn parameters(&self) -> [Real; PARAMETERS] {
        let mut p = [0.0; PARAMETERS];
        for id in ParameterId::all() {
            p[id.index()] = self.parameter(id);
        }
        p
    }

    /// The same machine with all 42 parameters replaced (mm); non-finite values are refused.
    pub fn with_parameters(&self, p: &[Real; PARAMETERS]) -> Result<Hexapod, HexapodError> {
        let mut h = self.clone();
        for id in ParameterId::all() {
            h.set_parameter(id, p[id.index()])?;
        }
        Ok(h)
    }

    /// The platform joint i in the base frame at `pose`, as `R·(a_i − o)` plus `t`.
    fn joint_offsets(&self, r: &Matrix3) -> [Vector3; STRUTS] {
        std::array::from_fn(|i| r * (self.platform[i] - self.tool))
    }

    /// The strut vectors `t + R·(a_i − o) − b_i` (base frame, mm).
    pub fn strut_vectors(&self, pose: &Pose) -> [Vector3; STRUTS] {
        let r = pose.rotation();
        let w = self.joint_offsets(&r);
        std::array::from_fn(|i| pose.position + w[i] - self.base[i])
    }

    /// Inverse kinematics, closed form: the strut lengths `L_i` at `pose` (mm), without
    /// limit checks ([`Hexapod::check_pose`] checks them).
    pub fn strut_lengths(&self, pose: &Pose) -> Struts {
        let d = self.strut_vectors(pose);
        std::array::from_fn(|i| d[i].norm())
    }

    /// The drives' readings at `pose`: `L_i − l0_i` (mm).
    pub fn readings(&self, pose: &Pose) -> Struts {
        let l = self.strut_lengths(pose);
        std::array::from_fn(|i| l[i] - self.reference[i])
    }

    /// The strut lengths of `readings` (`l0_i + s_i`, mm).
    pub fn lengths_of_readings(&self, readings: &Struts) -> Struts {
        std::array::from_fn(|i| self.reference[i] + readings[i])
    }

    /// The joint angles at `pose` (rad): for each strut, the angle between it and the base
    /// joint's axis, and between it and the platform joint's axis.
    pub fn joint_angles(&self, pose: &Pose) -> ([Real; STRUTS], [Real; STRUTS]) {
        let d = self.strut_vectors(pose);
        let pa = pose.rotation() * self.limits.platform_axis.into_inner();
        let angle = |u: &Vector3, axis: &Vector3| u.dot(axis).clamp(-1.0, 1.0).acos();
        let units: [Vector3; STRUTS] = std::array::from_fn(|i| d[i] / d[i].norm());
        (
            std::array::from_fn(|i| angle(&units[i], &self.limits.base_axis)),
            std::array::from_fn(|i| angle(&-units[i], &pa)),
        )
    }

    /// Checks strut lengths against the stroke.
    pub fn check_lengths(&self, lengths: &Struts) -> Result<(), HexapodError> {
        for (i, &l) in lengths.iter().enumerate() {
            if !l.is_finite() {
                return Err(HexapodError::NonFinite(format!("strut {} length", i + 1)));
            }
            if let Some((lo, hi)) = self.limits.stroke_mm
                && !(lo..=hi).contains(&l)
            {
                return Err(HexapodError::OutOfStroke {
                    strut: i + 1,
                    length_mm: l,
                    min_mm: lo,
                    max_mm: hi,
                });
            }
        }
        Ok(())
    }

    /// Checks that `pose` lies in the workspace: finite, every strut in its stroke, every
    /// joint within its limit, and not singular.
    pub fn check_pose(&self, pose: &Pose) -> Result<(), HexapodError> {
        if !pose.is_finite() {
            return Err(HexapodError::NonFinite("the pose".into()));
        }
        self.check_lengths(&self.strut_lengths(pose))?;
        let (base, platform) = self.joint_angles(pose);
        for (joint, angles, limit) in [
            ("base", base, self.limits.base_max_rad),
            ("platform", platform, self.limits.platform_max_rad),
        ] {
            if let Some(m) = limit
                && let Some(i) = angles.iter().position(|a| *a > m)
            {
                return Err(HexapodError::JointLimit {
                    joint,
                    strut: i + 1,
                    angle_deg: angles[i].to_degrees(),
                    limit_deg: m.to_degrees(),
                });
            }
        }
        self.output_jacobian(pose).map(|_| ())
    }

    /// Inverse kinematics with the workspace check: the strut lengths at `pose`, or why the
    /// pose cannot be reached.
    pub fn inverse(&self, pose: &Pose) -> Result<Struts, HexapodError> {
        self.check_pose(pose)?;
        Ok(self.strut_lengths(pose))
    }

    /// The lengths and the strut Jacobian `∂L/∂(x, y, z, a, b, c)` (angles in rad) at `pose`.
    fn lengths_and_jacobian(&self, pose: &Pose) -> (Vector6<Real>, Matrix6<Real>) {
        let trig = Trig::of(&pose.angles);
        let r = trig.rotation();
        let axes = trig.axes();
        let mut l = Vector6::zeros();
        let mut j = Matrix6::zeros();
        for i in 0..STRUTS {
            let w = r * (self.platform[i] - self.tool);
            let d = pose.position + w - self.base[i];
            let len = d.norm();
            let u = d / len;
            let m = w.cross(&u);
            l[i] = len;
            j[(i, 0)] = u.x;
            j[(i, 1)] = u.y;
            j[(i, 2)] = u.z;
            j[(i, 3)] = axes[0].dot(&m);
            j[(i, 4)] = axes[1].dot(&m);
            j[(i, 5)] = axes[2].dot(&m);
        }
        (l, j)
    }

    /// The strut Jacobian `∂L_i/∂(x, y, z, a, b, c)` at `pose` (mm/mm and mm/rad): the
    /// inverse kinematics' Jacobian. Row i is strut i's unit vector `u_i` and
    /// `ω_k · (R·(a_i − o) × u_i)` for the three angle axes ω_a, ω_b, ω_c.
    pub fn strut_jacobian(&self, pose: &Pose) -> Matrix6<Real> {
        self.lengths_and_jacobian(pose).1
    }

    /// The input→output Jacobian `∂(x, y, z, a, b, c)/∂L` at `pose` (mm/mm and rad/mm): the
    /// pose rates from strut rates, the inverse of [`Hexapod::strut_jacobian`]; an error at
    /// a singular pose.
    pub fn output_jacobian(&self, pose: &Pose) -> Result<Matrix6<Real>, HexapodError> {
        let j = self.strut_jacobian(pose);
        let lu = j.lu();
        if !well_conditioned(&lu) {
            return Err(HexapodError::Singular {
                pose: pose.to_string(),
            });
        }
        lu.try_inverse().ok_or_else(|| HexapodError::Singular {
            pose: pose.to_string(),
        })
    }

    /// The resolution amplification factors at `pose` (seed 001): K_p, the root sum of
    /// squares of the output Jacobian's three position rows (mm/mm), and K_a, of its three
    /// angle rows (°/mm).
    pub fn amplification(&self, pose: &Pose) -> Result<Amplification, HexapodError> {
        let jo = self.output_jacobian(pose)?;
        let rows =
            |r: std::ops::Range<usize>| r.map(|k| jo.row(k).norm_squared()).sum::<Real>().sqrt();
        Ok(Amplification {
            position_mm_per_mm: rows(0..3),
            angle_deg_per_mm: rows(3..6).to_degrees(),
        })
    }

    /// The readings' Jacobian with respect to the 42 parameters at `pose`:
    /// `∂s_i/∂b_i = −u_i`, `∂s_i/∂a_i = Rᵀ·u_i`, `∂s_i/∂l0_i = −1`, zero elsewhere.
    pub fn parameter_jacobian(&self, pose: &Pose) -> ParameterJacobian {
        let r = pose.rotation();
        let d = self.strut_vectors(pose);
        let mut jp = ParameterJacobian::zeros();
        for i in 0..STRUTS {
            let u = d[i] / d[i].norm();
            let ru = r.transpose() * u;
            for k in 0..3 {
                jp[(i, 3 * i + k)] = -u[k];
                jp[(i, 18 + 3 * i + k)] = ru[k];
            }
            jp[(i, 36 + i)] = -1.0;
        }
        jp
    }

    /// How the pose moves when a parameter changes and the readings stay:
    /// `∂pose/∂P = −(∂L/∂pose)⁻¹·∂s/∂P` at `pose` (rows x, y, z in mm/mm, a, b, c in
    /// rad/mm). The Jacobian the double-ball-bar calibration builds on.
    pub fn pose_parameter_jacobian(&self, pose: &Pose) -> Result<ParameterJacobian, HexapodError> {
        let jo = self.output_jacobian(pose)?;
        Ok(-(jo * self.parameter_jacobian(pose)))
    }

    /// Forward kinematics: the pose whose struts have `lengths`, by Newton–Raphson from
    /// `near`. Checks the lengths against the stroke first and the pose's joints after;
    /// errors if the iteration does not reach [`tol::STRUT_RESIDUAL`] in
    /// [`FK_MAX_ITERATIONS`] or meets a singular Jacobian.
    pub fn forward(&self, lengths: &Struts, near: &Pose) -> Result<FkSolution, HexapodError> {
        self.check_lengths(lengths)?;
        let sol = self.forward_unchecked(lengths, near)?;
        self.check_pose(&sol.pose)?;
        Ok(sol)
    }

    /// Forward kinematics without the stroke and joint checks (the pose a strut set gives,
    /// wherever it is). Still an error if Newton does not converge or the Jacobian is
    /// singular.
    pub fn forward_unchecked(
        &self,
        lengths: &Struts,
        near: &Pose,
    ) -> Result<FkSolution, HexapodError> {
        if !near.is_finite() {
            return Err(HexapodError::NonFinite("the start pose".into()));
        }
        if let Some(i) = lengths.iter().position(|l| !l.is_finite()) {
            return Err(HexapodError::NonFinite(format!("strut {} length", i + 1)));
        }
        let target = Vector6::from_column_slice(lengths);
        let mut x = near.to_vector();
        let mut residual = Real::INFINITY;
        for it in 0..FK_MAX_ITERATIONS {
            let pose = Pose::from_vector(&x);
            let (l, j) = self.lengths_and_jacobian(&pose);
            let res = l - target;
            let r = res.amax();
            if !r.is_finite() {
                residual = Real::INFINITY;
                break;
            }
            residual = r;
            if r <= tol::STRUT_ROUNDING {
                return Ok(FkSolution {
                    pose,
                    iterations: it,
                    residual_mm: r,
                });
            }
            let lu = j.lu();
            let dx = well_conditioned(&lu)
                .then(|| lu.solve(&res))
                .flatten()
                .ok_or_else(|| HexapodError::Singular {
                    pose: pose.to_string(),
                })?;
            if r <= tol::STRUT_RESIDUAL {
                // Converged. One more step makes the pose exact to rounding (Newton's
                // quadratic convergence); it is kept only if it does not worsen the residual.
                let polished = Pose::from_vector(&(x - dx));
                let pr = (self.lengths_vector(&polished) - target).amax();
                return Ok(if pr <= r {
                    FkSolution {
                        pose: polished,
                        iterations: it + 1,
                        residual_mm: pr,
                    }
                } else {
                    FkSolution {
                        pose,
                        iterations: it,
                        residual_mm: r,
                    }
                });
            }
            x -= dx;
        }
        Err(HexapodError::NotConverged {
            iterations: FK_MAX_ITERATIONS,
            residual_mm: residual,
        })
    }

    fn lengths_vector(&self, pose: &Pose) -> Vector6<Real> {
        Vector6::from_column_slice(&self.strut_lengths(pose))
    }

    /// Forward kinematics from readings: the pose where the struts are `l0_i + s_i`.
    pub fn forward_readings(
        &self,
        readings: &Struts,
        near: &Pose,
    ) -> Result<FkSolution, HexapodError> {
        self.forward(&self.lengths_of_readings(readings), near)
    }

    /// [`Self::forward_unchecked`] of many strut sets, each from its own start
    /// (`jobs[k] = (lengths, near)`), over rayon's pool in chunks of [`FK_BATCH_CHUNK`]:
    /// the same results in the same order as solving them one by one, whatever the thread
    /// count (the solves are independent and nothing is reduced across them).
    pub fn forward_unchecked_batch(
        &self,
        jobs: &[(Struts, Pose)],
    ) -> Vec<Result<FkSolution, HexapodError>> {
        use rayon::prelude::*;
        jobs.par_chunks(FK_BATCH_CHUNK)
            .flat_map_iter(|chunk| {
                chunk
                    .iter()
                    .map(|(lengths, near)| self.forward_unchecked(lengths, near))
            })
            .collect()
    }
}

/// Solves per rayon task of [`Hexapod::forward_unchecked_batch`]: about 0.3 ms of work, far
/// above the pool's scheduling cost, small enough to balance two to dozens of threads.
pub const FK_BATCH_CHUNK: usize = 256;

/// Whether an LU factorisation's smallest pivot is at least [`tol::JACOBIAN_CONDITION`]
/// of its largest.
fn well_conditioned(lu: &nalgebra::LU<Real, nalgebra::U6, nalgebra::U6>) -> bool {
    let u = lu.u();
    let (mut lo, mut hi) = (Real::INFINITY, 0.0 as Real);
    for k in 0..STRUTS {
        let d = u[(k, k)].abs();
        lo = lo.min(d);
        hi = hi.max(d);
    }
    hi.is_finite() && lo > hi * tol::JACOBIAN_CONDITION
}

/// The twin's pose for a command: the controller computes the readings on its parameters
/// (`controller`: the nominal machine, or the calibrated parameters a calibration gave it),
/// the `actual` machine moves to the pose they give (Newton from the command itself):
/// `FK_actual(l0_actual + IK_controller(command) − l0_controller)`, which is
/// `FK_actual(IK_controller(command))` when the reference lengths agree. The command must
/// lie in the controller's workspace; the reached pose is not held to the limits (it is
/// where the machine goes).
pub fn twin_pose(
    controller: &Hexapod,
    actual: &Hexapod,
    command: &Pose,
) -> Result<Pose, HexapodError> {
    controller.check_pose(command)?;
    let readings = controller.readings(command);
    actual
        .forward_unchecked(&actual.lengths_of_readings(&readings), command)
        .map(|s| s.pose)
}

/// Where the `actual` machine goes when its drives are commanded to the strut `lengths` the
/// `controller` computed (its IK, [`Hexapod::inverse`]): the drives read
/// `s_i = L_i − l0_i` on the controller's reference lengths, the real struts are then
/// `l0_i(actual) + s_i` long, and the pose is their forward kinematics from `near`. The
/// controller's lengths are checked against its stroke, the pose reached is not held to the
/// limits (it is where the machine goes).
pub fn reached_by_lengths(
    controller: &Hexapod,
    actual: &Hexapod,
    lengths: &Struts,
    near: &Pose,
) -> Result<FkSolution, HexapodError> {
    controller.check_lengths(lengths)?;
    let readings: Struts = std::array::from_fn(|i| lengths[i] - controller.reference[i]);
    actual.forward_unchecked(&actual.lengths_of_readings(&readings), near)
}

/// Serial axes on the table side of a hexapod: the chain from the workpiece frame (the
/// part, carried by the table) to the base frame, as the controller knows it and as built
/// (with the deviations of its joints, named as for any chain: `dx_C`, `alpha_C`, …).
#[derive(Clone, Debug, PartialEq)]
pub struct TableAxes {
    /// The chain as the controller knows it.
    pub nominal: Chain,
    /// The chain as built.
    pub actual: Chain,
}

/// The hexapod as an NC program drives it: the controller interpolates the axis values
/// linearly (Cartesian interpolation) and runs inverse kinematics on its parameters
/// (`controller`: the nominal machine, or calibrated ones); the actual machine puts the tool
/// at `FK_actual(IK_controller(command))` ([`twin_pose`]). X, Y, Z and the angles A, B, C
/// are the platform's pose (the tool point in the base frame, `R = Rz(c)·Ry(b)·Rx(a)`),
/// except the letters of the table's axes: those turn the table, and the platform holds the
/// home pose's value of that angle. The tool's tip is the tool point, its axis the
/// platform's +z. The workpiece frame is the base frame, or with table axes the frame the
/// table carries.
///
/// Three machines: `nominal` (the design, what the commanded path means), `controller`
/// (what the kinematics compute with) and `actual` (as built). A calibration changes the
/// controller and nothing else: [`HexapodTwin::with_controller`] re-measures a machine
/// after its controller took the calibrated parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct HexapodTwin {
    /// The machine as designed: the parameters the commanded path is meant on.
    pub nominal: Hexapod,
    /// The parameters the controller's kinematics use (the nominal machine unless
    /// calibrated).
    pub controller: Hexapod,
    /// The machine as built.
    pub actual: Hexapod,
    /// The home pose: the platform's angles for the letters the table takes.
    pub home: Pose,
    /// Serial axes carrying the part, if any.
    pub table: Option<TableAxes>,
}

impl HexapodTwin {
    /// A machine whose controller runs on the `nominal` parameters: the controller is the
    /// design.
    pub fn nominal_controller(
        nominal: Hexapod,
        actual: Hexapod,
        home: Pose,
        table: Option<TableAxes>,
    ) -> HexapodTwin {
        HexapodTwin {
            controller: nominal.clone(),
            nominal,
            actual,
            home,
            table,
        }
    }

    /// The same machine with its controller running on `controller` (calibrated
    /// parameters): the actual machine and the table are unchanged.
    pub fn with_controller(&self, controller: Hexapod) -> HexapodTwin {
        HexapodTwin {
            controller,
            ..self.clone()
        }
    }

    /// The platform's commanded pose at the axis values `q`.
    pub fn platform_command(&self, q: &AxisValues) -> Pose {
        let mut angles = self.home.angles;
        for (k, l) in [AxisLetter::A, AxisLetter::B, AxisLetter::C]
            .into_iter()
            .enumerate()
        {
            if !self.table_has(l) {
                angles[k] = q.get(l).to_radians();
            }
        }
        Pose {
            position: Vector3::new(
                q.get(AxisLetter::X),
                q.get(AxisLetter::Y),
                q.get(AxisLetter::Z),
            ),
            angles,
        }
    }

    /// Whether a table axis takes the letter.
    pub fn table_has(&self, l: AxisLetter) -> bool {
        self.table.as_ref().is_some_and(|t| t.nominal.has_axis(l))
    }

    /// The axis values at home: the home pose's, the table's axes at 0.
    pub fn home_axis_values(&self) -> AxisValues {
        let h = self.home.to_mm_deg();
        let mut q = AxisValues::default();
        for (l, v) in AxisLetter::ALL.into_iter().zip(h) {
            q.set(l, if self.table_has(l) { 0.0 } else { v });
        }
        q
    }

    /// The controller's Cartesian kinematics as a chain of the machine's axis letters, from
    /// the workpiece to the tool: the table's axes (nominal), X, Y, Z along the base frame's
    /// axes, then the platform's C, B, A about z, y, x through the tool point
    /// (`Trans(x, y, z)·Rz(c)·Ry(b)·Rx(a)`, the pose convention). Without table axes its
    /// pose is the commanded pose ([`PoseSource::commanded`]); with them the angles the table
    /// takes are left out (the platform holds them at home). An error when a table axis
    /// repeats a letter or is named like the spindle.
    pub fn command_chain(&self) -> Result<Chain, crate::machine::chain::KinematicsError> {
        use crate::machine::chain::{Axis, AxisKind};
        let mut axes: Vec<Axis> = self
            .table
            .as_ref()
            .map_or_else(Vec::new, |t| t.nominal.axes().to_vec());
        let unit = |v: Vector3| UnitVector3::new_normalize(v);
        for (l, kind, d) in [
            (AxisLetter::X, AxisKind::Linear, Vector3::x()),
            (AxisLetter::Y, AxisKind::Linear, Vector3::y()),
            (AxisLetter::Z, AxisKind::Linear, Vector3::z()),
            (AxisLetter::C, AxisKind::Rotary, Vector3::z()),
            (AxisLetter::B, AxisKind::Rotary, Vector3::y()),
            (AxisLetter::A, AxisKind::Rotary, Vector3::x()),
        ] {
            if !self.table_has(l) {
                axes.push(Axis {
                    letter: l,
                    kind,
                    direction: unit(d),
                    origin: crate::math::Point3::origin(),
                });
            }
        }
        Chain::new(axes, "S")
    }

    /// The platform pose reached for the axis values `q` (base frame).
    pub fn reached(&self, q: &AxisValues) -> Result<Pose, HexapodError> {
        twin_pose(&self.controller, &self.actual, &self.platform_command(q))
    }
}

/// The tool frame of a platform pose in the base frame.
pub fn pose_isometry(pose: &Pose) -> Isometry3 {
    let r = nalgebra::Rotation3::from_matrix_unchecked(pose.rotation());
    Isometry3::from_parts(
        pose.position.into(),
        nalgebra::UnitQuaternion::from_rotation_matrix(&r),
    )
}

impl PoseSource for HexapodTwin {
    fn has_axis(&self, _axis: AxisLetter) -> bool {
        true
    }

    fn w_from_t(&self, q: &AxisValues) -> Result<Isometry3, PoseError> {
        let base = pose_isometry(&self.reached(q).map_err(|e| PoseError(e.to_string()))?);
        Ok(match &self.table {
            Some(t) => t.actual.w_from_t(q) * base,
            None => base,
        })
    }

    fn commanded(&self, q: &AxisValues) -> Isometry3 {
        let base = pose_isometry(&self.platform_command(q));
        match &self.table {
            Some(t) => t.nominal.w_from_t(q) * base,
            None => base,
        }
    }

    fn is_translation(&self, start: &AxisValues, end: &AxisValues) -> bool {
        let turns = [AxisLetter::A, AxisLetter::B, AxisLetter::C]
            .into_iter()
            .any(|l| start.get(l) != end.get(l));
        self.controller == self.actual
            && !turns
            && self.table.as_ref().is_none_or(|t| t.nominal == t.actual)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(x: Real, y: Real, z: Real) -> Vector3 {
        Vector3::new(x, y, z)
    }

    /// LinuxCNC's genhexkins default geometry.
    fn genhexkins() -> Hexapod {
        let base = [
            v(-22.950, 13.250, 0.0),
            v(22.950, 13.250, 0.0),
            v(22.950, 13.250, 0.0),
            v(0.0, -26.500, 0.0),
            v(0.0, -26.500, 0.0),
            v(-22.950, 13.250, 0.0),
        ];
        let platform = [
            v(-1.000, 11.500, 0.0),
            v(1.000, 11.500, 0.0),
            v(10.459, -4.884, 0.0),
            v(9.459, -6.616, 0.0),
            v(-9.459, -6.616, 0.0),
            v(-10.459, -4.884, 0.0),
        ];
        Hexapod::try_new(base, platform, [0.0; 6], Vector3::zeros(), Limits::none()).expect("valid")
    }

    #[test]
    fn parameter_names_round_trip() {
        for id in ParameterId::all() {
            assert_eq!(ParameterId::from_name(&id.name()), Ok(id));
        }
        assert_eq!(ParameterId::from_name("bx_1").map(|p| p.index()), Ok(0));
        assert_eq!(ParameterId::from_name("az_6").map(|p| p.index()), Ok(35));
        assert_eq!(ParameterId::from_name("l0_6").map(|p| p.index()), Ok(41));
        for bad in [
            "bx_0", "bx_7", "cx_1", "l0_", "bxx_1", "l1_1", "", "_1", "bx_1 ",
        ] {
            assert!(ParameterId::from_name(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn fk_inverts_ik_near_home() {
        let h = genhexkins();
        let target = Pose::from_mm_deg([1.0, -2.0, 26.0, 3.0, -2.0, 5.0]);
        let l = h.strut_lengths(&target);
        let home = Pose::from_mm_deg([0.0, 0.0, 25.0, 0.0, 0.0, 0.0]);
        let s = h.forward(&l, &home).expect("converges");
        assert!((s.pose.position - target.position).amax() < 1e-9);
        assert!((s.pose.angles - target.angles).amax() < 1e-12);
        assert!(s.residual_mm <= tol::STRUT_RESIDUAL);
    }

    /// The batch returns, in order, exactly what one-by-one solves return (a failing one
    /// included), on one thread as on two.
    #[test]
    fn fk_batch_equals_the_solves_one_by_one_on_any_thread_count() {
        let h = genhexkins();
        let home = Pose::from_mm_deg([0.0, 0.0, 25.0, 0.0, 0.0, 0.0]);
        let mut jobs: Vec<(Struts, Pose)> = (0..1000)
            .map(|k| {
                let f = k as Real / 1000.0;
                let t = Pose::from_mm_deg([
                    3.0 * f - 1.5,
                    2.0 - 4.0 * f,
                    24.0 + 2.0 * f,
                    5.0 * f,
                    -3.0 * f,
                    4.0 - 8.0 * f,
                ]);
                (h.strut_lengths(&t), home)
            })
            .collect();
        jobs[500].0[2] = Real::NAN;
        let one_by_one: Vec<_> = jobs
            .iter()
            .map(|(l, n)| h.forward_unchecked(l, n))
            .collect();
        for threads in [1, 2] {
            let batch = crate::math::in_pool(threads, || h.forward_unchecked_batch(&jobs));
            assert_eq!(batch, one_by_one, "{threads} threads");
        }
        assert!(one_by_one[500].is_err() && one_by_one[499].is_ok());
    }

    #[test]
    fn flat_platform_in_the_base_plane_is_singular() {
        let h = genhexkins();
        let flat = Pose::from_mm_deg([0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
        assert!(matches!(
            h.output_jacobian(&flat),
            Err(HexapodError::Singular { .. })
        ));
    }
}
