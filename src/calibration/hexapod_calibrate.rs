//! Calibration of a hexapod's kinematic parameters from double-ball-bar lengths (seed 000,
//! eq. 1–4): `r_k = f(P, T_k)`, identified on the one engine ([`crate::calibration::engine`])
//! with the lengths as its forward model ([`DbbLengths`]).
//!
//! # Model
//!
//! Reading `k` is the bar length between the tool ball (the tool point of the pose
//! `FK_P(IK_nominal(T_k))`: the controller's readings on the machine with parameters `P`)
//! and its circle's table ball `c_j`: `f = |p_k(P) − c_j|`. Its row of `A` is
//! `∂f/∂P = uᵀ·∂p/∂P` (`u` the bar's unit vector, `∂p/∂P` the position rows of
//! [`Hexapod::pose_parameter_jacobian`]) and `∂f/∂c_j = −uᵀ`. Residuals are whitened by the
//! length noise σ; columns are scaled by realistic magnitudes (joints 0.5 mm, reference
//! lengths 0.2 mm, ball centres 0.5 mm).
//!
//! **Solved:** the 18 base-joint coordinates and the 6 reference lengths (24). The 18
//! platform-joint coordinates are taken as known (measured on a CMM, as in seed 000 §2-1).
//!
//! **Procedures.** *Jig-free* (seed 000 §3): each circle has its own table ball whose centre
//! is not known (its mounting error shows as a centre offset), so its three coordinates are
//! estimated with the parameters (the offset "removed in the calculation"). A DBB reads
//! lengths only: moving every base joint and every table ball by one rigid motion leaves
//! every reading unchanged, so the base frame's six degrees of freedom are not observable —
//! the Jacobian has rank (unknowns − 6), its null space exactly those six named gauge
//! directions. The 24 parameters are reported in the gauge where the base joints' deviations
//! carry no rigid motion (the base joints best-fitted to the nominal ones): 18 determined
//! combinations; the rigid part is what seed 000's separate table calibration fixes.
//! *Ball plate* (seed 000 §4): the 7 balls' centres are known in the table frame, so no
//! centre is estimated and the table frame fixes the gauge: all 24 parameters determined.
//!
//! **Identifiability and solve.** The engine's: the parameters' columns of the scaled,
//! whitened Jacobian (closed-form, so the gauge comes out at rounding, about 1e-16 of the
//! largest singular value, never at a difference quotient's noise) with the table balls'
//! columns projected out; a direction is determined when its σ is below
//! [`DETERMINED_FRACTION`] of its magnitude, and the rest — without a jig exactly the six
//! gauge directions — is held at the prior (nominal) value, never given a value.
//! Levenberg–Marquardt runs in the determined subspace and the balls' directions. The
//! report adds the whole spectrum (parameters and balls) at the solution, its rank and
//! margin, and names as *weak* any undetermined direction outside the gauge (with the
//! default circles, all tilted, there is none) and any borderline one. The parameters' σ
//! are the engine's, scaled by the residuals' σ over the stated one.
//!
//! **Goodness of fit.** The engine's: the lengths' residuals at the stated σ after the
//! solve, whole and circle by circle (one block a circle, [`crate::calibration::goodness`]): readings that cannot come from the
//! machine at that noise — a circle's file swapped with another's, another plan's circles —
//! are named in [`HexapodCalibration::fit`] for the caller to refuse.
//!
//! **Invariant:** reads readings and hexapods; never touches files; a parameter direction
//! the readings do not determine is named, never valued.

use crate::calibration::calibrate::{DETERMINED_FRACTION, Identifiability};
use crate::calibration::engine::{self, Block, Forward, Problem, Unknown};
use crate::calibration::goodness::{FitCheck, RankMargin};
use crate::machine::hexapod::{
    Hexapod, HexapodError, PARAMETERS, ParameterId, ParameterKind, Pose, twin_pose,
};
use crate::machine::hexapod_accuracy::{Workspace, level_positioning, pivot_test};
use crate::math::{Matrix3, Real, Vector3};
use crate::metrology::ballbar::Turns;
use crate::metrology::hexapod_dbb::{DbbCircle, DbbPlane};
use nalgebra::DMatrix;
use rayon::prelude::*;
use serde::Serialize;

/// Realistic magnitude of a joint coordinate's deviation (mm): the scale of its column.
pub const JOINT_MAGNITUDE_MM: Real = 0.5;
/// Realistic magnitude of a reference length's deviation (mm).
pub const STRUT_MAGNITUDE_MM: Real = 0.2;
/// Realistic magnitude of a table ball's mounting error (mm).
pub const BALL_MAGNITUDE_MM: Real = 0.5;
/// Relative singular value below which a direction of the scaled, whitened Jacobian is
/// numerically null (the design's rank, and the same circles with the balls known in
/// [`HexapodCalibration::centre_removal_cost`]): far above the rounding of the lengths'
/// Jacobian (FK to 1e-9 mm on 1e3 mm struts; a direct SVD puts the gauge near 1e-16), far
/// below any direction a circle sees (the weakest about 1e-4 of the largest).
pub const RANK_TOLERANCE: Real = 1e-7;

/// The noise seed of [`calibrate_commanded_with`]'s Monte-Carlo trials.
pub const MONTE_CARLO_SEED: u64 = 1;
/// The 24 solved parameters: base joints (0–17) and reference lengths (36–41).
pub fn solved_parameters() -> Vec<ParameterId> {
    (0..18)
        .chain(36..PARAMETERS)
        .filter_map(ParameterId::new)
        .collect()
}

/// Number of solved parameters.
pub const SOLVED: usize = 24;

/// The two procedures of seed 000.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Procedure {
    /// 15 circles, each about its own table ball of unknown centre (§3).
    JigFree,
    /// 7 circles about the balls of a plate whose centres are known in the table frame (§4).
    BallPlate,
}

impl Procedure {
    /// `jig-free` or `ball-plate`.
    pub fn from_name(name: &str) -> Option<Procedure> {
        match name {
            "jig-free" => Some(Procedure::JigFree),
            "ball-plate" => Some(Procedure::BallPlate),
            _ => None,
        }
    }

    /// The name.
    pub fn name(self) -> &'static str {
        match self {
            Procedure::JigFree => "jig-free",
            Procedure::BallPlate => "ball-plate",
        }
    }
}

/// A calibration's circles: each circle's table ball (nominal centre: `circle.centre_mm`),
/// and whether the balls' centres are known.
#[derive(Clone, Debug, PartialEq)]
pub struct Plan {
    /// The procedure.
    pub procedure: Procedure,
    /// The circles, one table ball each.
    pub circles: Vec<DbbCircle>,
}

impl Plan {
    /// Whether the table balls' centres are known (the ball plate).
    pub fn balls_known(&self) -> bool {
        self.procedure == Procedure::BallPlate
    }

    /// Readings in all.
    pub fn readings(&self) -> usize {
        self.circles
            .iter()
            .map(|c| c.points * c.turns.runs().len())
            .sum()
    }
}

/// Samples per circle of the default plans (one a degree).
pub const DEFAULT_POINTS: usize = 360;

/// Seed 000's plans on a workspace, with t = 0.6 × the workspace's tilt: `jig-free` 15
/// circles (five positions in x–y — the centre and ±0.4 of the half-widths — at three
/// heights; per height the platform level, tilted 0.5·t = 0.3·tilt about x, tilted
/// −0.3·tilt about y, the bar at 20°, 30° and 45° so that every table ball's z is seen;
/// every circle swung by 0.6·t = 0.36·tilt along the bar while it runs — seed 000's arcs run
/// while the tilt changes), `ball-plate` 7 circles about a plate's centre ball and six balls
/// on a hexagon, the bar tilted 45° for z sensitivity, the platform level at the centre and
/// tilted ±t about x and y at the others. Radius 100 mm (less on a small workspace).
pub fn default_plan(procedure: Procedure, ws: &Workspace, points: usize) -> Plan {
    let (xc, yc) = (0.5 * (ws.x_mm.0 + ws.x_mm.1), 0.5 * (ws.y_mm.0 + ws.y_mm.1));
    let (hx, hy) = (0.5 * (ws.x_mm.1 - ws.x_mm.0), 0.5 * (ws.y_mm.1 - ws.y_mm.0));
    let (z0, z1) = ws.z_mm;
    let r = (0.4 * hx.min(hy)).clamp(1.0, 100.0);
    let t = 0.6 * ws.tilt_deg;
    let circle = |x: Real, y: Real, z: Real, tilt: Real, o: [Real; 3], swing: Real| {
        let lift = r * tilt.to_radians().sin();
        xy_circle(Vector3::new(x, y, z - lift), r, tilt, o, swing, points)
    };
    let mut circles = Vec::new();
    match procedure {
        Procedure::JigFree => {
            let layers = [
                (z0 + 0.25 * (z1 - z0), 20.0, [0.0, 0.0, 0.0]),
                (0.5 * (z0 + z1), 30.0, [0.5 * t, 0.0, 0.0]),
                (z0 + 0.7 * (z1 - z0), 45.0, [0.0, -0.5 * t, 0.0]),
            ];
            for (z, tilt, o) in layers {
                for (fx, fy) in [
                    (0.0, 0.0),
                    (0.4, 0.4),
                    (-0.4, 0.4),
                    (-0.4, -0.4),
                    (0.4, -0.4),
                ] {
                    circles.push(circle(xc + fx * hx, yc + fy * hy, z, tilt, o, 0.6 * t));
                }
            }
        }
        Procedure::BallPlate => {
            let orient = [
                [0.0; 3],
                [t, 0.0, 0.0],
                [0.0, t, 0.0],
                [-t, 0.0, 0.0],
                [0.0, -t, 0.0],
                [t, t, 0.0],
                [-t, -t, 0.0],
            ];
            for (ball, o) in plate_balls(ws).into_iter().zip(orient) {
                circles.push(xy_circle(ball, r, 45.0, o, 0.0, points));
            }
        }
    }
    Plan { procedure, circles }
}

/// A counter-clockwise circle in the XY plane about the table ball `centre`.
pub fn xy_circle(
    centre: Vector3,
    radius_mm: Real,
    tilt_deg: Real,
    orientation_deg: [Real; 3],
    swing_deg: Real,
    points: usize,
) -> DbbCircle {
    DbbCircle {
        centre_mm: centre,
        radius_mm,
        plane: DbbPlane::XY,
        tilt_deg,
        orientation_deg,
        swing_deg,
        turns: Turns::Ccw,
        points,
    }
}

/// The 7-ball plate's ball centres on `ws`: the centre and six on a hexagon at 0.6 of the
/// half-widths, at the height of the fixed plan's bar (0.4 of the smaller half-width, at
/// most 100 mm) tilted 45° below a quarter of the height range.
pub fn plate_balls(ws: &Workspace) -> Vec<Vector3> {
    let (xc, yc) = (0.5 * (ws.x_mm.0 + ws.x_mm.1), 0.5 * (ws.y_mm.0 + ws.y_mm.1));
    let (hx, hy) = (0.5 * (ws.x_mm.1 - ws.x_mm.0), 0.5 * (ws.y_mm.1 - ws.y_mm.0));
    let r = (0.4 * hx.min(hy)).clamp(1.0, 100.0);
    let z = ws.z_mm.0 + 0.25 * (ws.z_mm.1 - ws.z_mm.0) - r * 45f64.to_radians().sin();
    let mut out = vec![Vector3::new(xc, yc, z)];
    for k in 0..6 {
        let ang = std::f64::consts::TAU * k as Real / 6.0;
        out.push(Vector3::new(
            xc + 0.6 * hx * ang.cos(),
            yc + 0.6 * hy * ang.sin(),
            z,
        ));
    }
    out
}

/// The measured lengths of one circle.
#[derive(Clone, Debug, PartialEq)]
pub struct CircleReadings {
    /// The commanded poses.
    pub commands: Vec<Pose>,
    /// The bar lengths read (mm).
    pub lengths_mm: Vec<Real>,
}

/// Errors of the calibration.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum HexapodCalibrationError {
    /// The readings do not match the plan, or a value is not finite.
    #[error("calibration: {0}")]
    Input(String),
    /// The kinematics failed at a reading during the solve.
    #[error("calibration: circle {circle}, reading {reading}: {source}")]
    Kinematics {
        /// 1-based circle.
        circle: usize,
        /// 0-based reading.
        reading: usize,
        /// Why.
        source: HexapodError,
    },
    /// The identification failed (a model evaluation at a reading, or no data).
    #[error("calibration: {0}")]
    Identification(String),
}

/// One solved parameter in the report's gauge.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ParameterEstimate {
    /// Name (`bx_1`, `l0_3`, …).
    pub name: String,
    /// Identified deviation from nominal (mm).
    pub value_mm: Real,
    /// Its standard uncertainty (mm).
    pub sigma_mm: Real,
    /// Its spread over Monte-Carlo trials at the solution (mm; [`engine::monte_carlo`] at
    /// the residuals' σ, each trial in the same gauge), when they ran.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub monte_carlo_spread_mm: Option<Real>,
}

/// What the readings determine.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct HexapodIdentifiability {
    /// Unknowns: the 24 parameters and, without a jig, three per table ball.
    pub unknowns: usize,
    /// Table-ball coordinates among them.
    pub ball_unknowns: usize,
    /// Dimension of the determined subspace: the parameters' directions determined and
    /// the balls' directions the readings constrain.
    pub rank: usize,
    /// Rank of the 24 parameters' part in the report's gauge (18 without a jig, 24 with
    /// the plate): the engine's determined directions.
    pub parameters_determined: usize,
    /// Singular values of the scaled, whitened Jacobian of every unknown at the solution
    /// (descending), from its SVD.
    pub singular_values: Vec<Real>,
    /// How clearly the rank was decided: the last kept and first dropped of
    /// `singular_values`; the cut is the engine's (σ a tenth of the magnitude: singular
    /// value [`DETERMINED_FRACTION`]⁻¹), which it applies to the parameters' columns with
    /// the balls' projected out.
    pub margin: RankMargin,
    /// Condition number within the determined subspace (the parameters', balls projected
    /// out).
    pub condition_number: Real,
    /// The named gauge directions (the base frame's rigid motions), when the table balls
    /// are estimated.
    pub gauge: Vec<String>,
    /// The largest part of an undetermined direction outside the gauge span (0: the
    /// undetermined subspace is exactly the named gauge).
    pub undetermined_outside_gauge: Real,
    /// Directions the readings see too weakly to determine — undetermined outside the
    /// gauge, σ above [`DETERMINED_FRACTION`] of the magnitude (named by their largest
    /// terms, scaled units), held at nominal — and those near the cut (borderline).
    pub weak: Vec<String>,
}

/// The outcome of a calibration.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct HexapodCalibration {
    /// The procedure.
    pub procedure: Procedure,
    /// What is determined.
    pub identifiability: HexapodIdentifiability,
    /// The 24 parameters: deviations from nominal, in the gauge where the base joints'
    /// deviations carry no rigid motion (jig-free) or in the table frame (ball plate).
    pub estimates: Vec<ParameterEstimate>,
    /// The full parameter vector identified (platform joints as given), before any gauge.
    #[serde(skip)]
    pub parameters: [Real; PARAMETERS],
    /// RMS of the length residuals (mm).
    pub residual_rms_mm: Real,
    /// σ used for the uncertainties: the residuals' (mm).
    pub sigma_mm: Real,
    /// Levenberg–Marquardt steps accepted.
    pub iterations: usize,
    /// Jig-free: RMS σ of the 24 parameters with the ball centres estimated over the same
    /// with them known (what removing the centre offsets costs).
    pub centre_removal_cost: Option<Real>,
    /// Whether the lengths can come from the identified machine at the stated σ, circle by
    /// circle ([`crate::calibration::goodness`]); callers refuse a misfit with
    /// [`FitCheck::enforce`].
    pub fit: FitCheck,
}

/// The six rigid motions of the base (translations x, y, z; rotations about x, y, z through
/// the origin) as displacement fields of the points `pts`: 6 columns, 3 rows per point.
pub fn rigid_fields(pts: &[Vector3]) -> DMatrix<Real> {
    let mut g = DMatrix::zeros(3 * pts.len(), 6);
    for (i, p) in pts.iter().enumerate() {
        for k in 0..3 {
            g[(3 * i + k, k)] = 1.0;
            let e = Vector3::ith(k, 1.0);
            let w = e.cross(p);
            for r in 0..3 {
                g[(3 * i + r, 3 + k)] = w[r];
            }
        }
    }
    g
}

/// The names of the six gauge directions.
pub fn gauge_names() -> Vec<String> {
    [
        "translation x",
        "translation y",
        "translation z",
        "rotation about x",
        "rotation about y",
        "rotation about z",
    ]
    .iter()
    .map(|s| format!("base frame {s} (every base joint and table ball moved together)"))
    .collect()
}

/// The rotation and translation best fitting `from` onto `to` (least squares, Kabsch):
/// `to_i ≈ q·from_i + t`.
pub fn best_fit(from: &[Vector3], to: &[Vector3]) -> (Matrix3, Vector3) {
    let n = from.len().max(1) as Real;
    let cf = from.iter().sum::<Vector3>() / n;
    let ct = to.iter().sum::<Vector3>() / n;
    let mut h = Matrix3::zeros();
    for (f, t) in from.iter().zip(to) {
        h += (f - cf) * (t - ct).transpose();
    }
    let svd = h.svd(true, true);
    let (Some(u), Some(vt)) = (svd.u, svd.v_t) else {
        return (Matrix3::identity(), ct - cf);
    };
    let v = vt.transpose();
    let d = (v * u.transpose()).determinant().signum();
    let q = v * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d)) * u.transpose();
    (q, ct - q * cf)
}

/// The base joints of `p` moved by the rigid motion that best fits them to `onto`.
pub fn aligned_base(p: &[Real; PARAMETERS], onto: &[Vector3]) -> [Real; PARAMETERS] {
    let b: Vec<Vector3> = (0..6)
        .map(|i| Vector3::new(p[3 * i], p[3 * i + 1], p[3 * i + 2]))
        .collect();
    let (q, t) = best_fit(&b, onto);
    let mut out = *p;
    for (i, bi) in b.iter().enumerate() {
        let m = q * bi + t;
        out[3 * i..3 * i + 3].copy_from_slice(m.as_slice());
    }
    out
}

fn base_of(h: &Hexapod) -> Vec<Vector3> {
    h.base_joints().to_vec()
}

/// Identifies the 24 parameters from `readings` of `plan` (one entry per circle), the
/// controller computing on `nominal`, the platform joints taken from `known` (CMM),
/// `sigma_mm` the length noise assumed for the design.
pub fn calibrate(
    nominal: &Hexapod,
    known: &Hexapod,
    plan: &Plan,
    readings: &[CircleReadings],
    sigma_mm: Real,
) -> Result<HexapodCalibration, HexapodCalibrationError> {
    calibrate_commanded(nominal, nominal, known, plan, readings, sigma_mm)
}

/// Predicted readings and, when asked for, their rows of the Jacobian.
type Rows = (Vec<Real>, DMatrix<Real>);

/// Double-ball-bar lengths as the engine's forward model ([`Forward`]): the unknowns are
/// the `solved` parameters of `machine` (its others as given), then — when the table balls
/// are estimated — three coordinates (mm, base frame) per circle's ball from `balls_at`
/// on; further unknowns (another instrument's) are not the bar's and have zero columns.
/// Reading `k` of circle `j` is `|p_k(P) − c_j|`, `p_k` the tool point of
/// `FK_P(IK_controller(T_k))`; its derivatives are closed-form (`uᵀ·∂p/∂P` and `−uᵀ`).
pub struct DbbLengths<'a> {
    /// The controller that ran the circles (its inverse kinematics gives the readings).
    pub controller: &'a Hexapod,
    /// The machine whose `solved` parameters are unknowns (the rest known).
    pub machine: &'a Hexapod,
    /// The parameters solved, in the unknowns' order (the first unknowns).
    pub solved: Vec<ParameterId>,
    /// The circles, one table ball each (nominal centre `centre_mm`).
    pub circles: &'a [DbbCircle],
    /// Their readings, one entry per circle.
    pub readings: &'a [CircleReadings],
    /// Index of the first ball coordinate among the unknowns (`None`: the balls are known,
    /// at the circles' centres).
    pub balls_at: Option<usize>,
}

impl DbbLengths<'_> {
    /// Readings in all.
    pub fn len(&self) -> usize {
        self.readings.iter().map(|r| r.lengths_mm.len()).sum()
    }

    /// Whether there is no reading.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The machine and the table balls at the unknowns `x`.
    fn at(&self, x: &[Real]) -> Result<(Hexapod, Vec<Vector3>), String> {
        let mut p = self.machine.parameters();
        for (c, id) in self.solved.iter().enumerate() {
            p[id.index()] = x[c];
        }
        let balls = self
            .circles
            .iter()
            .enumerate()
            .map(|(j, c)| match self.balls_at {
                None => c.centre_mm,
                Some(b) => Vector3::new(x[b + 3 * j], x[b + 3 * j + 1], x[b + 3 * j + 2]),
            })
            .collect();
        let m = self
            .machine
            .with_parameters(&p)
            .map_err(|e| format!("the machine at the unknowns: {e}"))?;
        Ok((m, balls))
    }

    /// Circle `j`'s lengths and, if `with_jacobian`, their rows (physical units, `n`
    /// columns).
    fn circle(
        &self,
        model: &Hexapod,
        ball: &Vector3,
        j: usize,
        n: usize,
        with_jacobian: bool,
    ) -> Result<Rows, String> {
        let r = &self.readings[j];
        let rows = if with_jacobian { r.commands.len() } else { 0 };
        let mut a = DMatrix::zeros(rows, n);
        let mut f = Vec::with_capacity(r.commands.len());
        for (k, cmd) in r.commands.iter().enumerate() {
            let at = |e: HexapodError| format!("circle {}, reading {k}: {e}", j + 1);
            let reached = twin_pose(self.controller, model, cmd).map_err(at)?;
            let d = reached.position - ball;
            let l = d.norm();
            f.push(l);
            if with_jacobian {
                let u = d / l;
                let jp = model.pose_parameter_jacobian(&reached).map_err(at)?;
                for (c, id) in self.solved.iter().enumerate() {
                    let pi = id.index();
                    a[(k, c)] = u.x * jp[(0, pi)] + u.y * jp[(1, pi)] + u.z * jp[(2, pi)];
                }
                if let Some(b) = self.balls_at {
                    for q in 0..3 {
                        a[(k, b + 3 * j + q)] = -u[q];
                    }
                }
            }
        }
        Ok((f, a))
    }

    fn evaluate(&self, x: &[Real], with_jacobian: bool) -> Result<Rows, String> {
        let (model, balls) = self.at(x)?;
        let parts: Vec<Result<Rows, String>> = (0..self.circles.len())
            .into_par_iter()
            .map(|j| self.circle(&model, &balls[j], j, x.len(), with_jacobian))
            .collect();
        let m = self.len();
        let mut f = Vec::with_capacity(m);
        let mut a = DMatrix::zeros(if with_jacobian { m } else { 0 }, x.len());
        for part in parts {
            let (fj, aj) = part?;
            if with_jacobian {
                a.view_mut((f.len(), 0), (aj.nrows(), aj.ncols()))
                    .copy_from(&aj);
            }
            f.extend(fj);
        }
        Ok((f, a))
    }
}

impl Forward for DbbLengths<'_> {
    fn predict(&self, x: &[Real]) -> Result<Vec<Real>, String> {
        self.evaluate(x, false).map(|(f, _)| f)
    }

    fn jacobian(&self, x: &[Real]) -> Option<Result<DMatrix<Real>, String>> {
        Some(self.evaluate(x, true).map(|(_, a)| a))
    }
}

/// The realistic magnitude of a parameter's deviation (mm): joints
/// [`JOINT_MAGNITUDE_MM`], reference lengths [`STRUT_MAGNITUDE_MM`].
pub fn magnitude(id: ParameterId) -> Real {
    match id.kind() {
        ParameterKind::Reference => STRUT_MAGNITUDE_MM,
        _ => JOINT_MAGNITUDE_MM,
    }
}

/// The table balls' unknowns of `circles` (named `{prefix}ball3_x`): three coordinates
/// each, starting at the circle's nominal centre, magnitude [`BALL_MAGNITUDE_MM`].
pub fn ball_unknowns(circles: &[DbbCircle], prefix: &str) -> Vec<Unknown> {
    circles
        .iter()
        .enumerate()
        .flat_map(|(j, c)| {
            ["x", "y", "z"]
                .into_iter()
                .enumerate()
                .map(move |(q, axis)| Unknown {
                    name: format!("{prefix}ball{}_{axis}", j + 1),
                    start: c.centre_mm[q],
                    magnitude: BALL_MAGNITUDE_MM,
                })
        })
        .collect()
}

/// [`calibrate`] of circles run by a `controller` other than the nominal machine (a second
/// round, on a controller already calibrated): the readings are modelled as
/// `FK_P(IK_controller(T_k))`; the start, the estimates' deviations and the report's gauge
/// stay the `nominal` machine's. The identification is [`crate::calibration::engine`]'s on
/// [`DbbLengths`]: one block a circle (`circle 3`), the table balls as nuisance unknowns
/// without a jig.
pub fn calibrate_commanded(
    controller: &Hexapod,
    nominal: &Hexapod,
    known: &Hexapod,
    plan: &Plan,
    readings: &[CircleReadings],
    sigma_mm: Real,
) -> Result<HexapodCalibration, HexapodCalibrationError> {
    calibrate_commanded_with(controller, nominal, known, plan, readings, sigma_mm, 0)
}

/// [`calibrate_commanded`] with `trials` Monte-Carlo trials at the solution
/// ([`engine::monte_carlo`], seed [`MONTE_CARLO_SEED`]; none for 0): each estimate's
/// spread, every trial's machine taken through the same gauge as the estimates, scaled from
/// the stated σ to the residuals' as the estimates' σ are.
pub fn calibrate_commanded_with(
    controller: &Hexapod,
    nominal: &Hexapod,
    known: &Hexapod,
    plan: &Plan,
    readings: &[CircleReadings],
    sigma_mm: Real,
    trials: usize,
) -> Result<HexapodCalibration, HexapodCalibrationError> {
    let input = |m: String| Err(HexapodCalibrationError::Input(m));
    if readings.len() != plan.circles.len() {
        return input(format!(
            "{} circles of readings for a plan of {}",
            readings.len(),
            plan.circles.len()
        ));
    }
    if !(sigma_mm.is_finite() && sigma_mm > 0.0) {
        return input(format!("the noise σ {sigma_mm} mm must be positive"));
    }
    for (j, r) in readings.iter().enumerate() {
        if r.commands.len() != r.lengths_mm.len() || r.commands.is_empty() {
            return input(format!(
                "circle {}: {} poses and {} lengths",
                j + 1,
                r.commands.len(),
                r.lengths_mm.len()
            ));
        }
        if let Some(k) = r.lengths_mm.iter().position(|l| !l.is_finite()) {
            return input(format!("circle {}: length {} is not finite", j + 1, k + 1));
        }
    }
    let ids = solved_parameters();
    let nb = if plan.balls_known() {
        0
    } else {
        plan.circles.len()
    };
    // Start: nominal base joints and reference lengths, the known platform joints.
    let mut p0 = known.parameters();
    let pn = nominal.parameters();
    for id in &ids {
        p0[id.index()] = pn[id.index()];
    }
    let start =
        known
            .with_parameters(&p0)
            .map_err(|source| HexapodCalibrationError::Kinematics {
                circle: 1,
                reading: 0,
                source,
            })?;
    let model = DbbLengths {
        controller,
        machine: &start,
        solved: ids.clone(),
        circles: &plan.circles,
        readings,
        balls_at: (nb > 0).then_some(SOLVED),
    };
    let scale: Vec<Real> = ids.iter().map(|&id| magnitude(id)).collect();
    let problem = Problem {
        parameters: ids
            .iter()
            .zip(&scale)
            .map(|(id, &magnitude)| Unknown {
                name: id.name(),
                start: p0[id.index()],
                magnitude,
            })
            .collect(),
        nuisance: if nb > 0 {
            ball_unknowns(&plan.circles, "")
        } else {
            Vec::new()
        },
        blocks: readings
            .iter()
            .enumerate()
            .map(|(j, r)| Block {
                name: format!("circle {}", j + 1),
                values: r.lengths_mm.clone(),
                sigma: vec![sigma_mm; r.lengths_mm.len()],
            })
            .collect(),
        forward: &model,
        statistic: format!("bar lengths at the stated σ {} µm", sigma_mm * 1e3),
    };
    let o = engine::solve(&problem)
        .map_err(|e| HexapodCalibrationError::Identification(e.to_string()))?;
    let n = SOLVED + 3 * nb;
    let m = model.len();
    let x: Vec<Real> = o.solution.iter().chain(&o.nuisance).copied().collect();
    // The whole spectrum (parameters and balls, scaled, whitened) at the solution.
    let jac = model
        .jacobian(&x)
        .unwrap_or_else(|| Err("no Jacobian".into()))
        .map_err(HexapodCalibrationError::Identification)?
        / sigma_mm;
    let mut scaled = jac;
    for (c, mut col) in scaled.column_iter_mut().enumerate() {
        col *= scale.get(c).copied().unwrap_or(BALL_MAGNITUDE_MM);
    }
    let mut all_sv: Vec<Real> = scaled.singular_values().iter().copied().collect();
    all_sv.sort_by(|a, b| b.total_cmp(a));
    let ident = &o.identifiability;
    let rank = ident.rank + o.nuisance_rank;
    let chi2 = o.chi2_history.last().copied().unwrap_or(0.0);
    let dof = m.saturating_sub(rank).max(1);
    let residual_rms_mm = (chi2 / m as Real).sqrt() * sigma_mm;
    let sigma_post = (chi2 / dof as Real).sqrt() * sigma_mm;
    let inflate = sigma_post / sigma_mm;
    // The gauge: the base joints' rigid motions (scaled units of the 24), without a jig.
    let (solved_machine, _) = model
        .at(&x)
        .map_err(HexapodCalibrationError::Identification)?;
    let gauge_scaled = if nb > 0 {
        let g = rigid_fields(&base_of(&start));
        let mut gs = DMatrix::zeros(SOLVED, 6);
        gs.view_mut((0, 0), (18, 6))
            .copy_from(&(g / JOINT_MAGNITUDE_MM));
        gs.qr().q()
    } else {
        DMatrix::zeros(SOLVED, 0)
    };
    let (weak, outside) = undetermined_outside(ident, &gauge_scaled, &scale);
    let mut weak = weak;
    weak.extend(
        ident
            .borderline
            .iter()
            .map(|(c, s)| format!("{} (borderline: singular value {s:.3})", c.name)),
    );
    let parameters = solved_machine.parameters();
    let shown = if nb > 0 {
        aligned_base(&parameters, &base_of(nominal))
    } else {
        parameters
    };
    let spread = if trials > 0 {
        let mc = engine::monte_carlo(&problem, &o, trials, MONTE_CARLO_SEED)
            .map_err(|e| HexapodCalibrationError::Identification(e.to_string()))?;
        let mut shown_k = Vec::with_capacity(trials);
        for x in &mc.solutions {
            let p = model
                .at(x)
                .map_err(HexapodCalibrationError::Identification)?
                .0
                .parameters();
            shown_k.push(if nb > 0 {
                aligned_base(&p, &base_of(nominal))
            } else {
                p
            });
        }
        ids.iter()
            .map(|id| {
                let v: Vec<Real> = shown_k.iter().map(|p| p[id.index()]).collect();
                Some(engine::mean_and_spread(&v).1 * inflate)
            })
            .collect()
    } else {
        vec![None; ids.len()]
    };
    let estimates = ids
        .iter()
        .enumerate()
        .map(|(c, id)| ParameterEstimate {
            name: id.name(),
            value_mm: shown[id.index()] - pn[id.index()],
            sigma_mm: o.solution_sigma[c] * inflate,
            monte_carlo_spread_mm: spread[c],
        })
        .collect();
    // What removing the centre offsets costs: the same circles with the centres known (the
    // parameters' columns alone), in the same gauge.
    let centre_removal_cost = if nb > 0 {
        let sub = scaled.columns(0, SOLVED).into_owned().svd(false, true);
        let vt = sub.v_t.unwrap_or_else(|| DMatrix::zeros(0, SOLVED));
        let cut = sub.singular_values.amax() * RANK_TOLERANCE;
        let proj =
            DMatrix::<Real>::identity(SOLVED, SOLVED) - &gauge_scaled * gauge_scaled.transpose();
        let mut known_var = 0.0;
        for (i, s) in sub.singular_values.iter().enumerate() {
            if *s > cut {
                let v = &proj * vt.row(i).transpose();
                known_var += (0..SOLVED).map(|p| (v[p] * scale[p]).powi(2)).sum::<Real>() / (s * s);
            }
        }
        let removed_var: Real = o.solution_sigma.iter().map(|s| s * s).sum();
        (known_var > 0.0).then(|| (removed_var / known_var).sqrt())
    } else {
        None
    };
    Ok(HexapodCalibration {
        procedure: plan.procedure,
        identifiability: HexapodIdentifiability {
            unknowns: n,
            ball_unknowns: 3 * nb,
            rank,
            parameters_determined: ident.rank,
            margin: RankMargin::new(&all_sv, rank, 1.0 / DETERMINED_FRACTION),
            singular_values: all_sv,
            condition_number: ident.condition_number_determined,
            gauge: if nb > 0 { gauge_names() } else { Vec::new() },
            undetermined_outside_gauge: outside,
            weak,
        },
        estimates,
        parameters,
        residual_rms_mm,
        sigma_mm: sigma_post,
        iterations: o.chi2_history.len().saturating_sub(1),
        centre_removal_cost,
        fit: o.fit,
    })
}

/// The directions the engine left undetermined outside the orthonormal `gauge` (scaled
/// units, columns): named by their largest terms, and the largest part of an undetermined
/// direction outside the gauge's span (0: the undetermined subspace lies in the gauge).
fn undetermined_outside(
    ident: &Identifiability,
    gauge: &DMatrix<Real>,
    scale: &[Real],
) -> (Vec<String>, Real) {
    let np = scale.len();
    let b = &ident.determined_basis;
    let mut undetermined = DMatrix::<Real>::identity(np, np);
    if b.ncols() > 0 {
        undetermined -= b * b.transpose();
    }
    if gauge.ncols() > 0 {
        undetermined = &undetermined - gauge * (gauge.transpose() * &undetermined);
    }
    let svd = undetermined.svd(false, true);
    let outside = svd.singular_values.amax();
    let vt = svd.v_t.unwrap_or_else(|| DMatrix::zeros(0, np));
    let mut named = Vec::new();
    for (i, s) in svd.singular_values.iter().enumerate() {
        if *s <= 0.5 {
            continue;
        }
        let v = vt.row(i);
        let big = v.amax();
        let mut terms: Vec<(Real, usize)> = (0..np)
            .filter(|&c| v[c].abs() >= 0.2 * big)
            .map(|c| (v[c], c))
            .collect();
        terms.sort_by(|a, b| b.0.abs().total_cmp(&a.0.abs()));
        let t: Vec<String> = terms
            .iter()
            .take(4)
            .map(|(x, c)| format!("{:+.2}·{}", x, ident.parameters[*c]))
            .collect();
        named.push(format!("{} (not determined: held at nominal)", t.join(" ")));
    }
    (named, outside)
}

/// The true deviations of the 24 parameters in the report's gauge (jig-free: the actual
/// base joints best-fitted to the nominal ones; ball plate: as they are), by name (mm).
pub fn true_deviations(
    nominal: &Hexapod,
    actual: &Hexapod,
    procedure: Procedure,
) -> Vec<(String, Real)> {
    let pn = nominal.parameters();
    let pa = match procedure {
        Procedure::JigFree => aligned_base(&actual.parameters(), &base_of(nominal)),
        Procedure::BallPlate => actual.parameters(),
    };
    solved_parameters()
        .iter()
        .map(|id| (id.name(), pa[id.index()] - pn[id.index()]))
        .collect()
}

/// How the base frame's six rigid motions — which lengths cannot see — are fixed after a
/// jig-free calibration (both modelled as exact).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum TableCalibration {
    /// The identified base joints best-fitted onto the actual ones: an alignment in joint
    /// space no instrument performs; the identification's errors along the weak joint
    /// directions tilt and shift the fitted frame, and the tool, 1.3 m below the base
    /// joints, carries that tilt as a position error.
    Joints,
    /// The tool's reached positions at eight reference corners of the workspace (platform
    /// level, [`table_points`]) best-fitted onto the commanded ones: what a table calibration sees (a dial gauge or
    /// touch probe on reference points of the table measures the tool, not the joints).
    Tool,
}

/// The table calibration's reference points: the eight corners of the box at 0.8 of the
/// workspace's half-ranges about its centre, platform level, those `machine` can reach.
pub fn table_points(machine: &Hexapod, ws: &Workspace) -> Vec<Pose> {
    let mid = |r: (Real, Real)| 0.5 * (r.0 + r.1);
    let half = |r: (Real, Real)| 0.4 * (r.1 - r.0);
    let mut out = Vec::with_capacity(8);
    for sz in [-1.0, 1.0] {
        for sy in [-1.0, 1.0] {
            for sx in [-1.0, 1.0] {
                let p = Pose::from_mm_deg([
                    mid(ws.x_mm) + sx * half(ws.x_mm),
                    mid(ws.y_mm) + sy * half(ws.y_mm),
                    mid(ws.z_mm) + sz * half(ws.z_mm),
                    0.0,
                    0.0,
                    0.0,
                ]);
                if machine.check_pose(&p).is_ok() {
                    out.push(p);
                }
            }
        }
    }
    out
}

/// The controller `model` with its base moved by the rigid motion `(q, t)`: commanding
/// `T` through it reaches what commanding `(q, t)⁻¹·T` through `model` reached.
fn moved_base(model: &Hexapod, q: &Matrix3, t: &Vector3) -> Result<Hexapod, HexapodError> {
    let mut p = model.parameters();
    for (i, b) in model.base_joints().iter().enumerate() {
        let m = q * b + t;
        p[3 * i..3 * i + 3].copy_from_slice(m.as_slice());
    }
    model.with_parameters(&p)
}

/// The tool table calibration ([`TableCalibration::Tool`]): the controller `model`'s base
/// moved by the rigid motion that best maps the commanded reference points onto the
/// reached ones (three passes; the map is rigid to first order, so the second pass leaves
/// nanometres). Returns the model and the total rotation (rad) and translation (mm).
pub fn tool_table_calibration(
    model: &Hexapod,
    actual: &Hexapod,
    ws: &Workspace,
) -> Result<(Hexapod, Real, Real), HexapodError> {
    let points = table_points(model, ws);
    if points.len() < 4 {
        return Err(HexapodError::Geometry(format!(
            "the table calibration reaches {} of the workspace's 8 reference corners: fewer than 4",
            points.len()
        )));
    }
    let commanded: Vec<Vector3> = points.iter().map(|p| p.position).collect();
    let mut m = model.clone();
    for _ in 0..3 {
        let reached = points
            .iter()
            .map(|p| twin_pose(&m, actual, p).map(|r| r.position))
            .collect::<Result<Vec<_>, _>>()?;
        let (q, t) = best_fit(&commanded, &reached);
        m = moved_base(&m, &q, &t)?;
    }
    let b0: Vec<Vector3> = base_of(model);
    let (q, t) = best_fit(&b0, &base_of(&m));
    let angle = nalgebra::Rotation3::from_matrix_unchecked(q).angle();
    let shift = (0..6)
        .map(|i| (q * b0[i] + t - b0[i]).norm())
        .fold(0.0, Real::max);
    Ok((m, angle, shift))
}

/// The controller's model after calibration: the identified parameters; jig-free, with the
/// base frame then placed by an exact table calibration of the kind `table` (the six rigid
/// degrees of freedom the DBB cannot see). Also returns that table calibration's rotation
/// (rad) and largest joint displacement (mm).
pub fn calibrated_model(
    identified: &HexapodCalibration,
    known: &Hexapod,
    actual: &Hexapod,
    ws: &Workspace,
    table: TableCalibration,
) -> Result<(Hexapod, Option<(Real, Real)>), HexapodError> {
    match identified.procedure {
        Procedure::BallPlate => Ok((known.with_parameters(&identified.parameters)?, None)),
        Procedure::JigFree => {
            let p = &identified.parameters;
            match table {
                TableCalibration::Joints => {
                    let b: Vec<Vector3> = (0..6)
                        .map(|i| Vector3::new(p[3 * i], p[3 * i + 1], p[3 * i + 2]))
                        .collect();
                    let (q, t) = best_fit(&b, &base_of(actual));
                    let angle = nalgebra::Rotation3::from_matrix_unchecked(q).angle();
                    let aligned = aligned_base(p, &base_of(actual));
                    Ok((known.with_parameters(&aligned)?, Some((angle, t.norm()))))
                }
                TableCalibration::Tool => {
                    let identified = known.with_parameters(p)?;
                    let (m, angle, shift) = tool_table_calibration(&identified, actual, ws)?;
                    Ok((m, Some((angle, shift))))
                }
            }
        }
    }
}

/// The identified machine as measured readings alone give it, with no simulated truth: the
/// identified parameters; jig-free, with the base frame — which lengths cannot see — placed
/// so that the tool, commanded through the `nominal` controller to the table calibration's
/// reference corners ([`table_points`]), best fits the commanded positions (the table frame
/// the machine was aligned in before calibration). A rigid motion of the base moves every
/// reached pose by that motion, so one placement fits exactly; a second pass checks it.
/// Also returns the placement's rotation (rad) and largest joint displacement (mm).
pub fn measured_model(
    identified: &HexapodCalibration,
    known: &Hexapod,
    nominal: &Hexapod,
    ws: &Workspace,
) -> Result<(Hexapod, Option<(Real, Real)>), HexapodError> {
    let machine = known.with_parameters(&identified.parameters)?;
    if identified.procedure == Procedure::BallPlate {
        return Ok((machine, None));
    }
    let points = table_points(nominal, ws);
    if points.len() < 4 {
        return Err(HexapodError::Geometry(format!(
            "the table frame is fixed on {} of the workspace's 8 reference corners: fewer than 4",
            points.len()
        )));
    }
    let commanded: Vec<Vector3> = points.iter().map(|p| p.position).collect();
    let mut m = machine.clone();
    for _ in 0..2 {
        let reached = points
            .iter()
            .map(|p| twin_pose(nominal, &m, p).map(|r| r.position))
            .collect::<Result<Vec<_>, _>>()?;
        let (q, t) = best_fit(&reached, &commanded);
        m = moved_base(&m, &q, &t)?;
    }
    let b0 = base_of(&machine);
    let (q, t) = best_fit(&b0, &base_of(&m));
    let angle = nalgebra::Rotation3::from_matrix_unchecked(q).angle();
    let shift = (0..6)
        .map(|i| (q * b0[i] + t - b0[i]).norm())
        .fold(0.0, Real::max);
    Ok((m, Some((angle, shift))))
}

/// The pose errors a controller model leaves on the actual machine.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct PoseErrors {
    /// The largest level positioning error over a 5 × 5 × 5 grid of the workspace (mm).
    pub position_mm: Real,
    /// The largest pivot error at five points (the workspace's centre and four points half
    /// way to its corners, mid height), a and b over ±min(tilt, 15°) (mm).
    pub pivot_mm: Real,
}

/// Pivot tilt of the survey at most (degrees): seed 001's pivot check.
pub const PIVOT_TILT_DEG: Real = 15.0;

/// The points a pivot survey swings about: the workspace's centre and the four points half
/// way to its corners, at mid height (mm).
pub fn pivot_survey_points(ws: &Workspace) -> [Vector3; 5] {
    let (xc, yc) = (0.5 * (ws.x_mm.0 + ws.x_mm.1), 0.5 * (ws.y_mm.0 + ws.y_mm.1));
    let (hx, hy) = (0.5 * (ws.x_mm.1 - ws.x_mm.0), 0.5 * (ws.y_mm.1 - ws.y_mm.0));
    let z = 0.5 * (ws.z_mm.0 + ws.z_mm.1);
    [
        (0.0, 0.0),
        (0.5, 0.5),
        (-0.5, 0.5),
        (-0.5, -0.5),
        (0.5, -0.5),
    ]
    .map(|(fx, fy)| Vector3::new(xc + fx * hx, yc + fy * hy, z))
}

/// The pose errors of the `actual` machine commanded through `controller` over `ws`.
pub fn pose_errors(
    controller: &Hexapod,
    actual: &Hexapod,
    ws: &Workspace,
) -> Result<PoseErrors, HexapodError> {
    let position_mm =
        level_positioning(controller, actual, ws, [5, 5, 5])?.map_or(Real::NAN, |l| l.max_error_mm);
    let tilt = ws.tilt_deg.min(PIVOT_TILT_DEG);
    let mut pivot_mm: Real = 0.0;
    for pt in pivot_survey_points(ws) {
        let r = pivot_test(controller, actual, &pt, tilt, 5)?;
        pivot_mm = pivot_mm.max(r.pivot_error_mm);
    }
    Ok(PoseErrors {
        position_mm,
        pivot_mm,
    })
}

/// Assumptions of the working-time estimate (minutes and mm/min).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct WorkAssumptions {
    /// Jig-free: mounting and centring a table ball and fitting the bar, per circle (min).
    pub jig_free_setup_per_circle_min: Real,
    /// Jig-free: the table calibration afterwards (dial gauge over the table, min).
    pub table_calibration_min: Real,
    /// Ball plate: placing the plate against its stoppers, once (min).
    pub plate_setup_min: Real,
    /// Ball plate: moving the bar to the next ball and setting its tilt (min).
    pub plate_per_circle_min: Real,
    /// Feed of the circles (mm/min).
    pub feed_mm_per_min: Real,
}

/// The assumptions the reports use: a DBB set-up of a centre ball on a magnetic base is
/// about 8 min; a dial-gauge table calibration an hour; placing the plate 30 min and moving
/// the bar between its balls about 6 min; DBB circles at 1000 mm/min.
pub const WORK: WorkAssumptions = WorkAssumptions {
    jig_free_setup_per_circle_min: 8.0,
    table_calibration_min: 60.0,
    plate_setup_min: 30.0,
    plate_per_circle_min: 6.0,
    feed_mm_per_min: 1000.0,
};

/// A procedure's measurement count and working time.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct WorkTime {
    /// The procedure.
    pub procedure: Procedure,
    /// Circles (set-ups of the bar).
    pub circles: usize,
    /// Readings.
    pub readings: usize,
    /// Path length of the circles (mm).
    pub path_mm: Real,
    /// Set-up time (min).
    pub setup_min: Real,
    /// Measuring time at the feed (min).
    pub measuring_min: Real,
    /// The total (min).
    pub total_min: Real,
}

/// The working time of `plan` under `w`.
pub fn work_time(plan: &Plan, w: &WorkAssumptions) -> WorkTime {
    let circles = plan.circles.len();
    let path_mm: Real = plan.circles.iter().map(|c| c.path_length_mm()).sum();
    let setup_min = match plan.procedure {
        Procedure::JigFree => {
            circles as Real * w.jig_free_setup_per_circle_min + w.table_calibration_min
        }
        Procedure::BallPlate => w.plate_setup_min + circles as Real * w.plate_per_circle_min,
    };
    let measuring_min = path_mm / w.feed_mm_per_min;
    WorkTime {
        procedure: plan.procedure,
        circles,
        readings: plan.readings(),
        path_mm,
        setup_min,
        measuring_min,
        total_min: setup_min + measuring_min,
    }
}
