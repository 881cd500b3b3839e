//! Design of a hexapod's double-ball-bar calibration: from candidate circles (table-ball
//! positions over the workspace, heights, bar lengths, bar tilts, platform tilts and swing),
//! the set of a given size whose identification predicts the smallest pose error after
//! calibration — what `design` does for test cuts, for seed 000's circles.
//!
//! # Criterion
//!
//! Each circle contributes an information matrix `Mⱼ = AⱼᵀAⱼ` over the 24 solved parameters
//! (scaled, whitened rows of [`super::hexapod_calibrate`]'s Jacobian, linearised at the
//! nominal machine; 24 samples per circle weighted to its readings). Without a jig the
//! circle's table-ball centre is estimated with the parameters, so its three unknowns are
//! eliminated: `Mⱼ = ÃⱼᵀÃⱼ` with `Ãⱼ = (I − Pⱼ)·Aⱼ`, `Pⱼ` the projection onto the ball's
//! columns `Bⱼ` (the Schur complement `AⱼᵀAⱼ − AⱼᵀBⱼ·(BⱼᵀBⱼ)⁺·BⱼᵀAⱼ`: what removing the
//! centre offset costs, circle by circle). A plan's rank, condition number and covariance
//! `C = M⁺` in the determined subspace come from the singular values of its stacked rows
//! `Ãⱼ` (never from `M`'s eigenvalues, which square the condition number).
//!
//! The criterion is the **mean predicted variance of the tool position error after
//! calibration** over check poses of the workspace (a 5 × 5 × 3 level grid and pivot poses
//! tilted ±min(tilt, 15°) about a and b at five points): `E·C·Eᵀ`, `E` the check poses'
//! position sensitivity `∂p/∂P` with, without a jig, the rigid motion the table calibration
//! fits on the workspace's reference corners removed (what that calibration leaves; the six
//! base-frame gauge directions have `E·g = 0`, so the criterion is the same in every
//! gauge). This is I-optimality (integrated prediction variance): it weights a parameter
//! direction by what it does to the pose, which is what the calibration is for; D-optimality
//! would weight every scaled direction alike — rewarding, for instance, a base joint moved
//! along its strut against that strut's reference length, which the pose barely feels — and,
//! without a jig, depends on the gauge chosen for the base frame. The report gives the
//! predicted worst and RMS σ of the position error over the check poses, the largest
//! parameter σ (in the report's gauge) and the condition number beside the fixed plan's.
//!
//! # Selection
//!
//! Greedy forward selection of `circles` candidates (each step adds the candidate lowering
//! the criterion most; while directions are still unseen a weak prior of the realistic
//! magnitudes — one scaled unit — keeps the criterion finite), then Fedorov exchange passes
//! (replace a chosen circle by a candidate while that lowers the criterion by more than
//! 1e-9 of it) until none improves or after [`MAX_EXCHANGE_PASSES`]. A candidate the nominal
//! machine cannot run (any of 72 angles out of stroke, past a joint cone or singular) is
//! rejected before selection. Ties go to the lower candidate index: deterministic whatever
//! the thread count (candidates are scored in parallel, the choice is made in order).
//!
//! **Invariant:** reads hexapods and circles; never touches files; a plan is returned only
//! with every circle reachable on the nominal machine.

use crate::calibration::goodness::RankMargin;
use crate::calibration::hexapod_calibrate::{
    BALL_MAGNITUDE_MM, JOINT_MAGNITUDE_MM, PIVOT_TILT_DEG, Plan, Procedure, RANK_TOLERANCE, SOLVED,
    STRUT_MAGNITUDE_MM, plate_balls, rigid_fields, solved_parameters, table_points, xy_circle,
};
use crate::machine::hexapod::{Hexapod, HexapodError, Pose};
use crate::machine::hexapod_accuracy::Workspace;
use crate::math::{Real, Vector3};
use crate::metrology::hexapod_dbb::DbbCircle;
use nalgebra::{DMatrix, SMatrix};
use rayon::prelude::*;
use serde::Serialize;

/// A 24 × 24 information or covariance matrix over the solved parameters (scaled units).
pub type Information = SMatrix<Real, SOLVED, SOLVED>;

/// Samples per circle for its information (weighted to the circle's readings): the rows
/// vary with the angle as low-order trigonometric polynomials, which 24 samples integrate
/// to well below a percent.
pub const DESIGN_SAMPLES: usize = 24;
/// Angles checked per candidate for reachability.
pub const REACH_SAMPLES: usize = 72;
/// Exchange passes at most.
pub const MAX_EXCHANGE_PASSES: usize = 4;
/// Most circles a design selects.
pub const MAX_CIRCLES: usize = 60;

/// Errors of the design.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum DesignError {
    /// The request cannot be met.
    #[error("calibration design: {0}")]
    Request(String),
    /// The kinematics failed at a reachable pose (a singular check pose).
    #[error("calibration design: {0}")]
    Kinematics(#[from] HexapodError),
}

fn scale(c: usize) -> Real {
    if c < 18 {
        JOINT_MAGNITUDE_MM
    } else {
        STRUT_MAGNITUDE_MM
    }
}

/// Whether the nominal machine can run `circle`: every one of [`REACH_SAMPLES`] commands in
/// stroke, within the joint cones and not singular.
pub fn reachable(nominal: &Hexapod, circle: &DbbCircle) -> bool {
    circle.validate().is_ok()
        && (0..REACH_SAMPLES).all(|k| {
            let t = std::f64::consts::TAU * k as Real / REACH_SAMPLES as Real;
            let cmd = circle.command(t);
            nominal.check_pose(&cmd).is_ok() && nominal.output_jacobian(&cmd).is_ok()
        })
}

/// The information `circle` gives on the 24 solved parameters (scaled, whitened by
/// `sigma_mm`), its table ball eliminated unless `balls_known`: `rowsᵀ·rows` of
/// [`circle_rows`].
pub fn circle_information(
    nominal: &Hexapod,
    circle: &DbbCircle,
    balls_known: bool,
    sigma_mm: Real,
) -> Result<Information, HexapodError> {
    let rows = circle_rows(nominal, circle, balls_known, sigma_mm)?;
    let m = rows.transpose() * rows;
    Ok(Information::from_fn(|i, j| m[(i, j)]))
}

/// The rows of `circle`'s whitened, scaled Jacobian over the 24 solved parameters
/// ([`DESIGN_SAMPLES`] of them, weighted to its readings), with — unless `balls_known` —
/// its table ball's three columns projected out, so that `rowsᵀ·rows` is its information
/// (the Schur complement of [`circle_information`]). Stacked over a plan, these rows are
/// what its rank is decided on, by their own singular values.
pub fn circle_rows(
    nominal: &Hexapod,
    circle: &DbbCircle,
    balls_known: bool,
    sigma_mm: Real,
) -> Result<DMatrix<Real>, HexapodError> {
    let idx: Vec<usize> = solved_parameters().iter().map(|id| id.index()).collect();
    let readings = (circle.points * circle.turns.runs().len()) as Real;
    let weight = (readings / DESIGN_SAMPLES as Real).sqrt();
    let mut a = DMatrix::zeros(DESIGN_SAMPLES, SOLVED);
    let mut b = DMatrix::zeros(DESIGN_SAMPLES, 3);
    for k in 0..DESIGN_SAMPLES {
        let theta = std::f64::consts::TAU * k as Real / DESIGN_SAMPLES as Real;
        let cmd = circle.command(theta);
        let jp = nominal.pose_parameter_jacobian(&cmd)?;
        let d = cmd.position - circle.centre_mm;
        let u = d / d.norm();
        for (c, &i) in idx.iter().enumerate() {
            a[(k, c)] =
                (u.x * jp[(0, i)] + u.y * jp[(1, i)] + u.z * jp[(2, i)]) * scale(c) / sigma_mm;
        }
        for q in 0..3 {
            b[(k, q)] = -u[q] * BALL_MAGNITUDE_MM / sigma_mm;
        }
    }
    a *= weight;
    if balls_known {
        return Ok(a);
    }
    // Project out the ball's columns (a level bar sees its ball's z only to second order:
    // a direction of B below BALL_RANK_EPS of its largest is not one).
    let svd = b.svd(true, false);
    let big = svd.singular_values.amax();
    if let Some(u) = svd.u {
        for k in 0..3 {
            if svd.singular_values[k] > big * BALL_RANK_EPS {
                let uk = u.column(k);
                let proj = uk.transpose() * &a;
                a -= uk * proj;
            }
        }
    }
    Ok(a)
}

/// Relative singular value below which a direction of a circle's ball columns is not seen
/// (the square root of the 1e-12 its information's eigenvalues are cut at).
const BALL_RANK_EPS: Real = 1e-6;

/// The check poses of the criterion: a 5 × 5 × 3 level grid of the workspace and, at its
/// centre and four points half way to its corners (mid height), a and b at −t, 0, +t
/// (t = min(tilt, [`PIVOT_TILT_DEG`])); the poses the nominal machine cannot reach are
/// left out.
pub fn check_poses(nominal: &Hexapod, ws: &Workspace) -> Vec<Pose> {
    let lin = |r: (Real, Real), n: usize| -> Vec<Real> {
        (0..n)
            .map(|k| r.0 + (r.1 - r.0) * k as Real / (n - 1) as Real)
            .collect()
    };
    let mut out = Vec::new();
    for z in lin(ws.z_mm, 3) {
        for y in lin(ws.y_mm, 5) {
            for x in lin(ws.x_mm, 5) {
                out.push(Pose::from_mm_deg([x, y, z, 0.0, 0.0, 0.0]));
            }
        }
    }
    let (xc, yc) = (0.5 * (ws.x_mm.0 + ws.x_mm.1), 0.5 * (ws.y_mm.0 + ws.y_mm.1));
    let (hx, hy) = (0.5 * (ws.x_mm.1 - ws.x_mm.0), 0.5 * (ws.y_mm.1 - ws.y_mm.0));
    let z = 0.5 * (ws.z_mm.0 + ws.z_mm.1);
    let t = ws.tilt_deg.min(PIVOT_TILT_DEG);
    for (fx, fy) in [
        (0.0, 0.0),
        (0.5, 0.5),
        (-0.5, 0.5),
        (-0.5, -0.5),
        (0.5, -0.5),
    ] {
        for a in [-t, 0.0, t] {
            for b in [-t, 0.0, t] {
                if a == 0.0 && b == 0.0 {
                    continue;
                }
                out.push(Pose::from_mm_deg([
                    xc + fx * hx,
                    yc + fy * hy,
                    z,
                    a,
                    b,
                    0.0,
                ]));
            }
        }
    }
    out.retain(|p| nominal.check_pose(p).is_ok() && nominal.output_jacobian(p).is_ok());
    out
}

/// The check poses' position sensitivity to the 24 solved parameters (mm per scaled unit,
/// 3 rows a pose), without a jig with the rigid motion fitted on the table calibration's
/// reference corners removed.
pub fn check_sensitivity(
    nominal: &Hexapod,
    ws: &Workspace,
    table_calibration: bool,
) -> Result<DMatrix<Real>, HexapodError> {
    let idx: Vec<usize> = solved_parameters().iter().map(|id| id.index()).collect();
    let rows = |poses: &[Pose]| -> Result<DMatrix<Real>, HexapodError> {
        let mut s = DMatrix::zeros(3 * poses.len(), SOLVED);
        for (k, p) in poses.iter().enumerate() {
            let jp = nominal.pose_parameter_jacobian(p)?;
            for r in 0..3 {
                for (c, &i) in idx.iter().enumerate() {
                    s[(3 * k + r, c)] = jp[(r, i)] * scale(c);
                }
            }
        }
        Ok(s)
    };
    let checks = check_poses(nominal, ws);
    let s = rows(&checks)?;
    if !table_calibration {
        return Ok(s);
    }
    let table = table_points(nominal, ws);
    if table.len() < 4 {
        return Err(HexapodError::Geometry(format!(
            "the table calibration reaches {} of the workspace's 8 reference corners: fewer than 4",
            table.len()
        )));
    }
    let st = rows(&table)?;
    let pos = |p: &[Pose]| p.iter().map(|q| q.position).collect::<Vec<Vector3>>();
    let rt = rigid_fields(&pos(&table));
    let rc = rigid_fields(&pos(&checks));
    // Least-squares rigid fit on the corners: r = (RtᵀRt)⁻¹Rtᵀ·e_t.
    let rtr = (rt.transpose() * &rt)
        .try_inverse()
        .ok_or_else(|| HexapodError::Geometry("the workspace's corners are degenerate".into()))?;
    Ok(&s - rc * (rtr * rt.transpose() * st))
}

/// What a plan predicts.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Prediction {
    /// Rank of the information over the 24 parameters (18 without a jig: the base frame's
    /// six rigid motions are the gauge; 24 with the plate).
    pub rank: usize,
    /// Condition number of the information's determined part (scaled units).
    pub condition_number: Real,
    /// How clearly the rank was decided: the stacked rows' singular values either side of
    /// [`RANK_TOLERANCE`] of the largest.
    pub margin: RankMargin,
    /// The largest predicted σ of the tool position error after calibration over the check
    /// poses (3-D, mm).
    pub worst_position_sigma_mm: Real,
    /// Its RMS over the check poses (mm).
    pub rms_position_sigma_mm: Real,
    /// The largest σ of a parameter in the report's gauge (mm).
    pub max_parameter_sigma_mm: Real,
}

/// `(m + ridge·I)⁻¹` for the selection's criterion (a unit prior: positive definite, so no
/// rank is decided here; plans are predicted by [`predict`] on their rows).
fn regularised_inverse(m: &Information, ridge: Real) -> Information {
    let e = (m + Information::identity() * ridge).symmetric_eigen();
    let big = e.eigenvalues.amax().max(0.0);
    let tol = big * RANK_TOLERANCE * RANK_TOLERANCE;
    let mut c = Information::zeros();
    for k in 0..SOLVED {
        let l = e.eigenvalues[k];
        if l > tol && l > 0.0 {
            let v = e.eigenvectors.column(k);
            c += v * v.transpose() / l;
        }
    }
    c
}

/// The prediction of a plan whose stacked Jacobian rows ([`circle_rows`]) are `rows` (no
/// prior) through the check sensitivity `e`: its rank and covariance from the rows' own
/// singular values.
pub fn predict(
    rows: &DMatrix<Real>,
    e: &DMatrix<Real>,
    jig_free: bool,
    nominal: &Hexapod,
) -> Prediction {
    let svd = rows.clone().svd(false, true);
    let mut order: Vec<usize> = (0..svd.singular_values.len()).collect();
    order.sort_by(|a, b| svd.singular_values[*b].total_cmp(&svd.singular_values[*a]));
    let sv: Vec<Real> = order.iter().map(|&k| svd.singular_values[k]).collect();
    let big = sv.first().copied().unwrap_or(0.0);
    let cut = big * RANK_TOLERANCE;
    let rank = sv.iter().filter(|s| **s > cut && **s > 0.0).count();
    let mut cd = DMatrix::zeros(SOLVED, SOLVED);
    if let Some(vt) = &svd.v_t {
        for &k in order.iter().take(rank) {
            let s = svd.singular_values[k];
            let v = vt.row(k).transpose();
            cd += &v * v.transpose() / (s * s);
        }
    }
    let condition_number = match rank.checked_sub(1) {
        Some(last) if sv[last] > 0.0 => big / sv[last],
        _ => Real::INFINITY,
    };
    let margin = RankMargin::new(&sv, rank, cut);
    let ec = e * &cd;
    let k = e.nrows() / 3;
    let mut worst: Real = 0.0;
    let mut sum = 0.0;
    for p in 0..k {
        let mut v = 0.0;
        for r in 3 * p..3 * p + 3 {
            v += ec.row(r).dot(&e.row(r));
        }
        worst = worst.max(v);
        sum += v;
    }
    // The report's gauge: the base joints' rigid motion projected out (jig-free).
    let mut proj = DMatrix::<Real>::identity(SOLVED, SOLVED);
    if jig_free {
        let q = rigid_fields(nominal.base_joints()).qr().q();
        let pb = DMatrix::<Real>::identity(18, 18) - &q * q.transpose();
        proj.view_mut((0, 0), (18, 18)).copy_from(&pb);
    }
    let cg = &proj * cd * proj.transpose();
    let max_parameter_sigma_mm = (0..SOLVED)
        .map(|i| cg[(i, i)].max(0.0).sqrt() * scale(i))
        .fold(0.0, Real::max);
    Prediction {
        rank,
        condition_number,
        margin,
        worst_position_sigma_mm: worst.sqrt(),
        rms_position_sigma_mm: (sum / k.max(1) as Real).sqrt(),
        max_parameter_sigma_mm,
    }
}

/// The candidate circles of `procedure` on `ws` (before the reachability check).
///
/// *Jig-free:* the tool ring's centre at x, y ∈ {−0.6, 0, +0.6} of the half-widths and z at
/// 0.2, 0.5 and 0.8 of the height range, the table ball below it by the bar's lift; bar
/// lengths 100, 175 and 250 mm; bar tilts 20°, 40° and 60°; the platform level or tilted
/// ±0.6·tilt about x or y; held or swung 0.6·tilt along the bar. *Ball plate:* the plate's
/// seven balls ([`plate_balls`], where the fixed plan has them) (fixed heights),
/// with the same bar lengths, tilts, platform orientations and swings.
pub fn candidates(procedure: Procedure, ws: &Workspace, points: usize) -> Vec<DbbCircle> {
    let (xc, yc) = (0.5 * (ws.x_mm.0 + ws.x_mm.1), 0.5 * (ws.y_mm.0 + ws.y_mm.1));
    let (hx, hy) = (0.5 * (ws.x_mm.1 - ws.x_mm.0), 0.5 * (ws.y_mm.1 - ws.y_mm.0));
    let (z0, z1) = ws.z_mm;
    let t = 0.6 * ws.tilt_deg;
    let orientations = [
        [0.0, 0.0, 0.0],
        [t, 0.0, 0.0],
        [-t, 0.0, 0.0],
        [0.0, t, 0.0],
        [0.0, -t, 0.0],
    ];
    let radii: [Real; 3] = [100.0, 175.0, 250.0];
    let tilts: [Real; 3] = [20.0, 40.0, 60.0];
    let swings = [0.0, t];
    let circle = |ball: Vector3, r: Real, tilt: Real, o: [Real; 3], swing: Real| {
        xy_circle(ball, r, tilt, o, swing, points)
    };
    let mut out = Vec::new();
    match procedure {
        Procedure::JigFree => {
            for fz in [0.2, 0.5, 0.8] {
                for fy in [-0.6, 0.0, 0.6] {
                    for fx in [-0.6, 0.0, 0.6] {
                        for &r in &radii {
                            for &tilt in &tilts {
                                let ring =
                                    Vector3::new(xc + fx * hx, yc + fy * hy, z0 + fz * (z1 - z0));
                                let lift = r * tilt.to_radians().sin();
                                for o in orientations {
                                    for &s in &swings {
                                        out.push(circle(ring - lift * Vector3::z(), r, tilt, o, s));
                                    }
                                }
                            }
                        }
                    }
                }
            }
        }
        Procedure::BallPlate => {
            for ball in plate_balls(ws) {
                for &r in &radii {
                    for &tilt in &tilts {
                        for o in orientations {
                            for &s in &swings {
                                out.push(circle(ball, r, tilt, o, s));
                            }
                        }
                    }
                }
            }
        }
    }
    out
}

/// A designed plan and what it and the fixed plan predict.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CircleDesign {
    /// The designed plan.
    #[serde(skip)]
    pub plan: Plan,
    /// Candidates generated.
    pub candidates: usize,
    /// Candidates the nominal machine cannot run.
    pub rejected: usize,
    /// Exchanges made after the greedy selection.
    pub exchanges: usize,
    /// The designed plan's prediction.
    pub predicted: Prediction,
    /// The fixed plan's (as given to [`design`]).
    pub fixed: Prediction,
}

/// Selects `circles` circles for `procedure` on the `nominal` machine over `ws` (length
/// noise `sigma_mm`, `points` readings per circle), and predicts them beside `fixed`.
pub fn design(
    nominal: &Hexapod,
    procedure: Procedure,
    ws: &Workspace,
    circles: usize,
    points: usize,
    sigma_mm: Real,
    fixed: &Plan,
) -> Result<CircleDesign, DesignError> {
    if !(1..=MAX_CIRCLES).contains(&circles) {
        return Err(DesignError::Request(format!(
            "{circles} circles: must lie in 1..={MAX_CIRCLES}"
        )));
    }
    if !(sigma_mm.is_finite() && sigma_mm > 0.0) {
        return Err(DesignError::Request(format!(
            "the noise σ {sigma_mm} mm must be positive"
        )));
    }
    let jig_free = procedure == Procedure::JigFree;
    let balls_known = !jig_free;
    let all = candidates(procedure, ws, points);
    let generated = all.len();
    let usable: Vec<DbbCircle> = all
        .into_par_iter()
        .filter(|c| reachable(nominal, c))
        .collect();
    let rejected = generated - usable.len();
    if usable.len() < circles {
        return Err(DesignError::Request(format!(
            "only {} of {generated} candidate circles are reachable: fewer than the {circles} asked",
            usable.len()
        )));
    }
    let infos: Vec<Information> = usable
        .par_iter()
        .map(|c| circle_information(nominal, c, balls_known, sigma_mm))
        .collect::<Result<_, _>>()?;
    let e = check_sensitivity(nominal, ws, jig_free)?;
    if e.nrows() == 0 {
        return Err(DesignError::Request(
            "no check pose of the workspace is reachable".into(),
        ));
    }
    let w = {
        let w = e.transpose() * &e / (e.nrows() / 3) as Real;
        Information::from_fn(|i, j| w[(i, j)])
    };
    // I-criterion with a unit prior (scaled units): finite while directions are unseen.
    let score = |m: &Information| -> Real { regularised_inverse(m, 1.0).component_mul(&w).sum() };
    let mut chosen: Vec<usize> = Vec::with_capacity(circles);
    let mut m = Information::zeros();
    for _ in 0..circles {
        let best = best_addition(&infos, &chosen, &m, &score);
        chosen.push(best);
        m += infos[best];
    }
    let mut current = score(&m);
    let mut exchanges = 0;
    for _ in 0..MAX_EXCHANGE_PASSES {
        let mut improved = false;
        for slot in 0..chosen.len() {
            let without = m - infos[chosen[slot]];
            let others: Vec<usize> = chosen
                .iter()
                .enumerate()
                .filter(|&(s, _)| s != slot)
                .map(|(_, &c)| c)
                .collect();
            let best = best_addition(&infos, &others, &without, &score);
            let trial = score(&(without + infos[best]));
            if best != chosen[slot] && trial < current * (1.0 - 1e-9) {
                chosen[slot] = best;
                m = without + infos[best];
                current = trial;
                exchanges += 1;
                improved = true;
            }
        }
        if !improved {
            break;
        }
    }
    chosen.sort_unstable();
    let plan = Plan {
        procedure,
        circles: chosen.iter().map(|&k| usable[k].clone()).collect(),
    };
    let stacked = |circles: &[DbbCircle]| -> Result<DMatrix<Real>, HexapodError> {
        let mut out = DMatrix::zeros(DESIGN_SAMPLES * circles.len(), SOLVED);
        for (j, c) in circles.iter().enumerate() {
            let r = circle_rows(nominal, c, balls_known, sigma_mm)?;
            out.view_mut((DESIGN_SAMPLES * j, 0), (DESIGN_SAMPLES, SOLVED))
                .copy_from(&r);
        }
        Ok(out)
    };
    let predicted = predict(&stacked(&plan.circles)?, &e, jig_free, nominal);
    let fixed = predict(&stacked(&fixed.circles)?, &e, jig_free, nominal);
    Ok(CircleDesign {
        plan,
        candidates: generated,
        rejected,
        exchanges,
        predicted,
        fixed,
    })
}

/// The candidate (not in `taken`) whose information added to `m` scores lowest; ties to
/// the lower index.
fn best_addition(
    infos: &[Information],
    taken: &[usize],
    m: &Information,
    score: &(dyn Fn(&Information) -> Real + Sync),
) -> usize {
    let scores: Vec<Real> = infos
        .par_iter()
        .enumerate()
        .map(|(k, i)| {
            if taken.contains(&k) {
                Real::INFINITY
            } else {
                score(&(m + i))
            }
        })
        .collect();
    let mut best = 0;
    for (k, s) in scores.iter().enumerate() {
        if *s < scores[best] {
            best = k;
        }
    }
    best
}
