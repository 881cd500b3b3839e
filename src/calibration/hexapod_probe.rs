//! Seed 001's calibration of a hexapod (§5, "标定实例"): gauge blocks and a touch probe
//! measure the two calibration items — translational positioning at grid points with the
//! platform level, and pivot accuracy ("空间聚点性": the tool tip held at a fixed point while
//! the orientation swings) — the kinematic parameters those readings see are identified, the
//! controller is updated with them, and a second round re-measures on the corrected
//! controller and calibrates again.
//!
//! # The measurement
//!
//! Every commanded pose `T` is driven through the **controller's** inverse kinematics and
//! the **actual** machine's forward kinematics ([`twin_pose`]); the probe sees the tool
//! point `p(T)` it reaches. A touch probe against gauge blocks reads a displacement along
//! its probing direction; each point is probed along the table frame's x, y and z (three
//! readings a point, each with independent Gaussian noise of σ):
//!
//! - **positioning**, platform level at the grid points of [`ProbePlan::positioning`]: the
//!   reading is `e_k·(p(T) − t)` (`t` the commanded point; the gauge blocks stacked from
//!   the table's datum give the commanded point in the table frame, which is the base
//!   frame);
//! - **pivot**, at each fixed point of [`ProbePlan::pivots`] the probe is zeroed with the
//!   platform level and read at each swung orientation: `e_k·(p(T_ab) − p(T_level))`, the
//!   tip's travel.
//!
//! # The identification
//!
//! The unknowns are the 42 parameters of the actual machine (the scene's `[deviations]`
//! names, [`ParameterId`]), starting at the controller's values, with realistic magnitudes
//! (joints 0.5 mm, reference lengths 0.2 mm); the readings are predicted by the same
//! controller-IK / actual-FK model. The solve, the identifiability report (what is
//! identified on its own, determined combinations, what is not determined) and the
//! goodness of fit are [`crate::calibration::engine`]'s. Tool-point readings never see the
//! platform joints turned rigidly about the tool point (the tool point reaches the same
//! place, only the orientation differs): three directions always stay at the controller's
//! values, named as not determined. The controller is then updated with the solution
//! (undetermined directions unchanged).
//!
//! **Invariant:** plain functions of the hexapods, plan and options given; never touches
//! files; the same inputs and seed give the same readings and outcome, bit for bit; a
//! direction the readings do not determine is named, never valued.

use crate::calibration::engine::{Block, Forward, Outcome, Problem, Unknown, solve};
use crate::calibration::goodness::FitCheck;
use crate::calibration::hexapod_calibrate::pivot_survey_points;
use crate::machine::hexapod::{Hexapod, HexapodError, PARAMETERS, ParameterId, Pose, twin_pose};
use crate::machine::hexapod_accuracy::{Workspace, level_positioning};
use crate::math::{CounterRng, Real, Vector3};
use serde::Serialize;

/// Readings per probed point: the displacement along the table's x, y and z.
pub const DIRECTIONS: usize = 3;

/// Errors of the probe calibration.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ProbeError {
    /// Bad options or readings that do not match the plan.
    #[error("probe calibration: {0}")]
    Input(String),
    /// A commanded pose the controller or the machine cannot reach.
    #[error("probe calibration: {what}: {source}")]
    Kinematics {
        /// Which pose.
        what: String,
        /// Why.
        source: HexapodError,
    },
    /// The identification failed.
    #[error("probe calibration: {0}")]
    Identification(String),
    /// The readings cannot come from the machine at the stated noise.
    #[error("{0}")]
    Misfit(String),
}

/// One pivot swing: a fixed point and the orientations the tool is swung to about it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PivotSwing {
    /// The fixed point (mm, base frame).
    pub point_mm: [Real; 3],
    /// The swung orientations a, b (degrees; c = 0); the probe is zeroed level.
    pub angles_deg: Vec<[Real; 2]>,
}

impl PivotSwing {
    /// The pose swung to `a_deg`, `b_deg` about the fixed point (c = 0).
    pub fn pose(&self, a_deg: Real, b_deg: Real) -> Pose {
        let p = self.point_mm;
        Pose::from_mm_deg([p[0], p[1], p[2], a_deg, b_deg, 0.0])
    }
}

/// What is measured.
#[derive(Clone, Debug, PartialEq)]
pub struct ProbePlan {
    /// Level poses at grid points (the positioning item).
    pub positioning: Vec<Pose>,
    /// Pivot swings (the pivot item).
    pub pivots: Vec<PivotSwing>,
}

impl ProbePlan {
    /// Readings in all.
    pub fn readings(&self) -> usize {
        DIRECTIONS
            * (self.positioning.len()
                + self
                    .pivots
                    .iter()
                    .map(|s| s.angles_deg.len())
                    .sum::<usize>())
    }
}

/// The default plan on `ws`, every pose reachable by `controller`: positioning at a
/// 4 × 4 × 3 grid (x and y at ±0.25 and ±0.75 of the half-widths about the centre, z at
/// 1/6, 1/2 and 5/6 of the range) with the platform level; pivot swings about five points
/// (the centre at 0.4 of the height and four at ±0.6 of the half-widths, alternately at 0.25
/// and 0.75 of the height) to eight orientations on the circle of radius `tilt` in (a, b)
/// (every 45°). None of these poses is one of [`survey`]'s.
pub fn default_plan(controller: &Hexapod, ws: &Workspace) -> ProbePlan {
    let at = |r: (Real, Real), f: Real| r.0 + (r.1 - r.0) * f;
    let mut positioning = Vec::new();
    for fz in [1.0 / 6.0, 0.5, 5.0 / 6.0] {
        for fy in [0.125, 0.375, 0.625, 0.875] {
            for fx in [0.125, 0.375, 0.625, 0.875] {
                let p = Pose::from_mm_deg([
                    at(ws.x_mm, fx),
                    at(ws.y_mm, fy),
                    at(ws.z_mm, fz),
                    0.0,
                    0.0,
                    0.0,
                ]);
                if controller.check_pose(&p).is_ok() {
                    positioning.push(p);
                }
            }
        }
    }
    let t = ws.tilt_deg;
    let mut pivots = Vec::new();
    for (fx, fy, fz) in [
        (0.5, 0.5, 0.4),
        (0.8, 0.8, 0.25),
        (0.2, 0.8, 0.75),
        (0.2, 0.2, 0.25),
        (0.8, 0.2, 0.75),
    ] {
        let swing = PivotSwing {
            point_mm: [at(ws.x_mm, fx), at(ws.y_mm, fy), at(ws.z_mm, fz)],
            angles_deg: Vec::new(),
        };
        if t == 0.0 || controller.check_pose(&swing.pose(0.0, 0.0)).is_err() {
            continue;
        }
        let angles: Vec<[Real; 2]> = (0..8)
            .map(|k| {
                let phi = (45.0 * k as Real).to_radians();
                [t * phi.cos(), t * phi.sin()]
            })
            .filter(|ab| controller.check_pose(&swing.pose(ab[0], ab[1])).is_ok())
            .collect();
        if !angles.is_empty() {
            pivots.push(PivotSwing {
                angles_deg: angles,
                ..swing
            });
        }
    }
    ProbePlan {
        positioning,
        pivots,
    }
}

/// The readings of one measurement (mm), in plan order: three per positioning point, then
/// three per swung orientation of each pivot.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ProbeReadings {
    /// Positioning: x, y, z displacement of the tool point from the commanded point.
    pub positioning_mm: Vec<[Real; 3]>,
    /// Pivot: per swing, per orientation, the tip's travel from its level position.
    pub pivot_mm: Vec<Vec<[Real; 3]>>,
    /// The probe's noise σ (mm).
    pub sigma_mm: Real,
}

impl ProbeReadings {
    /// All readings in plan order.
    pub fn flat(&self) -> Vec<Real> {
        self.positioning_mm
            .iter()
            .chain(self.pivot_mm.iter().flatten())
            .flat_map(|v| v.iter().copied())
            .collect()
    }

    /// The largest positioning error read (the length of a point's three readings, mm).
    pub fn positioning_max_mm(&self) -> Real {
        let n = |v: &[Real; 3]| Vector3::from(*v).norm();
        self.positioning_mm.iter().map(n).fold(0.0, Real::max)
    }

    /// The largest pivot error read (the length of a tip travel's three readings, mm).
    pub fn pivot_max_mm(&self) -> Real {
        let n = |v: &[Real; 3]| Vector3::from(*v).norm();
        self.pivot_mm.iter().flatten().map(n).fold(0.0, Real::max)
    }
}

/// Noise-free readings: positioning, then pivot swing by swing.
type PredictedReadings = (Vec<[Real; 3]>, Vec<Vec<[Real; 3]>>);

/// The noise-free readings of `plan` on `actual` commanded through `controller`.
fn predicted(
    controller: &Hexapod,
    actual: &Hexapod,
    plan: &ProbePlan,
) -> Result<PredictedReadings, ProbeError> {
    let reach = |pose: &Pose, what: &dyn Fn() -> String| {
        twin_pose(controller, actual, pose)
            .map(|p| p.position)
            .map_err(|source| ProbeError::Kinematics {
                what: what(),
                source,
            })
    };
    let arr = |v: Vector3| [v.x, v.y, v.z];
    let positioning = plan
        .positioning
        .iter()
        .map(|p| {
            Ok(arr(
                reach(p, &|| format!("positioning at {p}"))? - p.position
            ))
        })
        .collect::<Result<Vec<_>, ProbeError>>()?;
    let mut pivot = Vec::with_capacity(plan.pivots.len());
    for s in &plan.pivots {
        let level_pose = s.pose(0.0, 0.0);
        let level = reach(&level_pose, &|| format!("pivot zero at {level_pose}"))?;
        let mut v = Vec::with_capacity(s.angles_deg.len());
        for ab in &s.angles_deg {
            let pose = s.pose(ab[0], ab[1]);
            v.push(arr(reach(&pose, &|| format!("pivot at {pose}"))? - level));
        }
        pivot.push(v);
    }
    Ok((positioning, pivot))
}

/// The probe's readings of `plan` on `actual` commanded through `controller`, each with
/// Gaussian noise of `sigma_mm` (counter-based generator: `seed`, one stream a reading).
pub fn measure(
    controller: &Hexapod,
    actual: &Hexapod,
    plan: &ProbePlan,
    sigma_mm: Real,
    seed: u64,
) -> Result<ProbeReadings, ProbeError> {
    if !(sigma_mm.is_finite() && sigma_mm >= 0.0) {
        return Err(ProbeError::Input(format!(
            "the probe noise σ {sigma_mm} mm must be finite and ≥ 0"
        )));
    }
    let (mut positioning_mm, mut pivot_mm) = predicted(controller, actual, plan)?;
    let rng = CounterRng::new(seed);
    let mut k = 0u64;
    for v in positioning_mm
        .iter_mut()
        .chain(pivot_mm.iter_mut().flatten())
    {
        for c in v.iter_mut() {
            *c += sigma_mm * rng.normal(k);
            k += 1;
        }
    }
    Ok(ProbeReadings {
        positioning_mm,
        pivot_mm,
        sigma_mm,
    })
}

/// The realistic magnitude of a parameter's deviation (mm): the engine's column scale.
pub use crate::calibration::hexapod_calibrate::magnitude;

/// The readings as the engine's forward model: the 42 parameters of the machine.
struct ProbeModel<'a> {
    controller: &'a Hexapod,
    plan: &'a ProbePlan,
}

impl Forward for ProbeModel<'_> {
    fn predict(&self, x: &[Real]) -> Result<Vec<Real>, String> {
        let p: [Real; PARAMETERS] = x
            .try_into()
            .map_err(|_| format!("{} parameters for a hexapod of {PARAMETERS}", x.len()))?;
        let machine = self
            .controller
            .with_parameters(&p)
            .map_err(|e| e.to_string())?;
        let (pos, piv) =
            predicted(self.controller, &machine, self.plan).map_err(|e| e.to_string())?;
        Ok(pos
            .iter()
            .chain(piv.iter().flatten())
            .flat_map(|v| v.iter().copied())
            .collect())
    }
}

/// One parameter or combination identified, as a deviation of the actual machine from the
/// controller the readings were taken with.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ProbeEstimate {
    /// `bx_1`, `l0_3`, or a combination's name.
    pub name: String,
    /// The actual value less the controller's (mm).
    pub value_mm: Real,
    /// Its standard uncertainty (mm).
    pub sigma_mm: Real,
    /// Its spread over Monte-Carlo trials at the solution (mm), when they ran.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub monte_carlo_spread_mm: Option<Real>,
}

/// What one identification found.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ProbeIdentification {
    /// Readings used.
    pub readings: usize,
    /// Dimension of the determined subspace (of 42).
    pub rank: usize,
    /// Parameters identified on their own: deviation from the controller's value, with σ.
    pub identified: Vec<ProbeEstimate>,
    /// Determined combinations that are not single parameters, with σ.
    pub combinations: Vec<ProbeEstimate>,
    /// Directions not determined (held at the controller's values), named.
    pub not_determined: Vec<String>,
    /// Directions near the threshold of determination.
    pub borderline: Vec<String>,
    /// Singular values of the scaled, whitened Jacobian (descending).
    pub singular_values: Vec<Real>,
    /// χ² at the start and after each accepted step.
    pub chi2_history: Vec<Real>,
    /// Why the solve stopped.
    pub termination: String,
    /// Whether the readings can come from the identified machine at the stated σ, part
    /// by part (the positioning grid, each pivot point).
    pub fit: FitCheck,
    /// The identified machine's 42 parameters (undetermined directions at the controller's
    /// values): the updated controller.
    #[serde(skip)]
    pub parameters: [Real; PARAMETERS],
    /// Their σ along the determined subspace (mm).
    #[serde(skip)]
    pub parameter_sigma: [Real; PARAMETERS],
    /// Their spread over Monte-Carlo trials at the solution (mm), when they ran.
    #[serde(skip)]
    pub parameter_spread: Option<[Real; PARAMETERS]>,
}

fn engine_outcome(
    controller: &Hexapod,
    plan: &ProbePlan,
    readings: &ProbeReadings,
) -> Result<Outcome, ProbeError> {
    if !(readings.sigma_mm.is_finite() && readings.sigma_mm > 0.0) {
        return Err(ProbeError::Input(format!(
            "the probe noise σ {} mm must be positive to weigh the readings",
            readings.sigma_mm
        )));
    }
    if readings.positioning_mm.len() != plan.positioning.len()
        || readings.pivot_mm.len() != plan.pivots.len()
        || readings
            .pivot_mm
            .iter()
            .zip(&plan.pivots)
            .any(|(r, s)| r.len() != s.angles_deg.len())
    {
        return Err(ProbeError::Input(
            "the readings do not match the plan's points".into(),
        ));
    }
    let start = controller.parameters();
    let parameters: Vec<Unknown> = ParameterId::all()
        .map(|id| Unknown {
            name: id.name(),
            start: start[id.index()],
            magnitude: magnitude(id),
        })
        .collect();
    let flat3 = |v: &[[Real; 3]]| v.iter().flatten().copied().collect::<Vec<Real>>();
    let block = |name: String, values: Vec<Real>| Block {
        sigma: vec![readings.sigma_mm; values.len()],
        name,
        values,
    };
    let mut blocks = vec![block(
        "positioning grid".into(),
        flat3(&readings.positioning_mm),
    )];
    for (s, r) in plan.pivots.iter().zip(&readings.pivot_mm) {
        let p = s.point_mm;
        blocks.push(block(
            format!("pivot at ({:.1}, {:.1}, {:.1}) mm", p[0], p[1], p[2]),
            flat3(r),
        ));
    }
    let model = ProbeModel { controller, plan };
    let problem = Problem {
        parameters,
        nuisance: Vec::new(),
        blocks,
        forward: &model,
        statistic: format!(
            "probe readings at the stated σ {} µm",
            readings.sigma_mm * 1e3
        ),
    };
    solve(&problem).map_err(|e| ProbeError::Identification(e.to_string()))
}

/// Identifies the parameters `readings` of `plan` see, the readings taken on the machine
/// commanded through `controller`; refuses readings the identified machine cannot explain
/// at their σ unless `accept_misfit`.
pub fn identify(
    controller: &Hexapod,
    plan: &ProbePlan,
    readings: &ProbeReadings,
    accept_misfit: bool,
) -> Result<ProbeIdentification, ProbeError> {
    let mut o = engine_outcome(controller, plan, readings)?;
    o.fit
        .enforce("probe calibration", accept_misfit)
        .map_err(|m| ProbeError::Misfit(m.to_string()))?;
    Ok(identification_of(
        o,
        &controller.parameters(),
        plan.readings(),
    ))
}

/// The engine's outcome on the 42 parameters (started at `start`, the controller's) as a
/// [`ProbeIdentification`] of `readings` readings: values as deviations from the start.
pub fn identification_of(
    mut o: Outcome,
    start: &[Real; PARAMETERS],
    readings: usize,
) -> ProbeIdentification {
    let ident = &o.identifiability;
    let mut parameters = [0.0; PARAMETERS];
    parameters.copy_from_slice(&o.solution);
    let mut parameter_sigma = [0.0; PARAMETERS];
    parameter_sigma.copy_from_slice(&o.solution_sigma);
    let combination_value = |e: &crate::calibration::calibrate::Estimate| {
        // A combination's value less the controller's.
        let c0: Real = e.coefficients.iter().zip(start).map(|(c, s)| c * s).sum();
        e.value - c0
    };
    ProbeIdentification {
        readings,
        rank: ident.rank,
        identified: o
            .parameters
            .iter()
            .map(|e| ProbeEstimate {
                name: e.name.clone(),
                value_mm: combination_value(e),
                sigma_mm: e.sigma,
                monte_carlo_spread_mm: None,
            })
            .collect(),
        combinations: o
            .combinations
            .iter()
            .map(|e| ProbeEstimate {
                name: e.name.clone(),
                value_mm: combination_value(e),
                sigma_mm: e.sigma,
                monte_carlo_spread_mm: None,
            })
            .collect(),
        not_determined: ident
            .undetermined_combinations
            .iter()
            .map(|c| c.name.clone())
            .collect(),
        borderline: ident
            .borderline
            .iter()
            .map(|(c, s)| format!("{} (singular value {s:.3})", c.name))
            .collect(),
        singular_values: ident.singular_values.clone(),
        chi2_history: std::mem::take(&mut o.chi2_history),
        termination: o.termination.clone(),
        fit: o.fit,
        parameters,
        parameter_sigma,
        parameter_spread: None,
    }
}

/// The two calibration items over a workspace: seed 001's figures.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Accuracy {
    /// The largest positioning error with the platform level (mm).
    pub positioning_mm: Real,
    /// The largest pivot error: the tip's travel from its level position (mm).
    pub pivot_mm: Real,
}

/// Grid points per axis of [`survey`]'s positioning grid.
pub const SURVEY_STEPS: usize = 5;

/// The two items on the twin without noise, on a pose set none of [`default_plan`]'s
/// poses belongs to: positioning over the 5 × 5 × 5 grid spanning `ws` (the corners
/// included), pivot at the centre and the four points half way to the corners at mid
/// height, a and b each over 5 values in ±`ws.tilt_deg` (25 orientations; those the
/// controller cannot reach skipped).
pub fn survey(
    controller: &Hexapod,
    actual: &Hexapod,
    ws: &Workspace,
) -> Result<Accuracy, ProbeError> {
    let kin = |what: &str| {
        let what = what.to_string();
        move |source| ProbeError::Kinematics { what, source }
    };
    let positioning_mm = level_positioning(controller, actual, ws, [SURVEY_STEPS; 3])
        .map_err(kin("survey positioning"))?
        .map_or(Real::NAN, |l| l.max_error_mm);
    let mut pivot_mm: Real = 0.0;
    let lin = |k: usize| -ws.tilt_deg + 2.0 * ws.tilt_deg * k as Real / (SURVEY_STEPS - 1) as Real;
    for p in pivot_survey_points(ws) {
        let swing = PivotSwing {
            point_mm: [p.x, p.y, p.z],
            angles_deg: Vec::new(),
        };
        let level = twin_pose(controller, actual, &swing.pose(0.0, 0.0))
            .map_err(kin("survey pivot, level"))?
            .position;
        for n in 0..SURVEY_STEPS * SURVEY_STEPS {
            let pose = swing.pose(lin(n % SURVEY_STEPS), lin(n / SURVEY_STEPS));
            if controller.check_pose(&pose).is_err() {
                continue;
            }
            let tip = twin_pose(controller, actual, &pose).map_err(kin("survey pivot"))?;
            pivot_mm = pivot_mm.max((tip.position - level).norm());
        }
    }
    Ok(Accuracy {
        positioning_mm,
        pivot_mm,
    })
}

/// How the calibration runs.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ProbeOptions {
    /// Calibration rounds (each: measure on the current controller, identify, update).
    pub rounds: usize,
    /// The probe's noise σ (mm), the readings' stated uncertainty.
    pub sigma_mm: Real,
    /// Seed of the noise.
    pub seed: u64,
    /// Keep an identification whose residuals the noise cannot explain.
    pub accept_misfit: bool,
}

/// The most rounds a calibration may run.
pub const MAX_ROUNDS: usize = 10;

/// One round.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ProbeRound {
    /// 1-based.
    pub round: usize,
    /// What the probe read at the round's start (noisy, on the plan's poses).
    pub measured: Accuracy,
    /// The identification.
    pub identification: ProbeIdentification,
    /// The twin's figures after the round (noise-free survey, independent poses).
    pub after: Accuracy,
    /// The probe's readings of the round (on the controller it started with).
    #[serde(skip)]
    pub readings: ProbeReadings,
}

/// The whole calibration.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ProbeCalibration {
    /// The options.
    pub options: ProbeOptions,
    /// The plan's size: positioning points, pivot points, swung orientations, readings.
    pub plan_points: [usize; 4],
    /// The twin's figures before calibration (survey).
    pub before: Accuracy,
    /// Every round.
    pub rounds: Vec<ProbeRound>,
    /// What the probe reads after the last round (a check measurement, not used).
    pub measured_after: Accuracy,
    /// The final controller's 42 parameters.
    #[serde(skip)]
    pub controller: Option<Hexapod>,
}

/// Seed 001's calibration: `options.rounds` rounds of probe measurement on the current
/// controller (starting at `controller`), identification and update, on `actual`.
pub fn calibrate(
    controller: &Hexapod,
    actual: &Hexapod,
    ws: &Workspace,
    options: &ProbeOptions,
) -> Result<ProbeCalibration, ProbeError> {
    if !(1..=MAX_ROUNDS).contains(&options.rounds) {
        return Err(ProbeError::Input(format!(
            "rounds {} must lie in 1..={MAX_ROUNDS}",
            options.rounds
        )));
    }
    if !(options.sigma_mm.is_finite() && options.sigma_mm > 0.0) {
        return Err(ProbeError::Input(format!(
            "the probe noise σ {} mm must be positive",
            options.sigma_mm
        )));
    }
    ws.validate().map_err(ProbeError::Input)?;
    let plan = default_plan(controller, ws);
    if plan.positioning.len() < 8 {
        return Err(ProbeError::Input(format!(
            "the controller reaches {} of the workspace's 48 positioning points: fewer than 8",
            plan.positioning.len()
        )));
    }
    let swung: usize = plan.pivots.iter().map(|s| s.angles_deg.len()).sum();
    let before = survey(controller, actual, ws)?;
    let read = |c: &Hexapod, round: u64| {
        measure(
            c,
            actual,
            &plan,
            options.sigma_mm,
            options.seed ^ round.wrapping_mul(0x9e37_79b9_7f4a_7c15),
        )
    };
    let figures = |r: &ProbeReadings| Accuracy {
        positioning_mm: r.positioning_max_mm(),
        pivot_mm: r.pivot_max_mm(),
    };
    let mut current = controller.clone();
    let mut rounds = Vec::with_capacity(options.rounds);
    for k in 1..=options.rounds {
        let readings = read(&current, k as u64)?;
        let identification =
            identify(&current, &plan, &readings, options.accept_misfit).map_err(|e| match e {
                ProbeError::Misfit(m) => ProbeError::Misfit(format!("round {k}: {m}")),
                other => other,
            })?;
        current = current
            .with_parameters(&identification.parameters)
            .map_err(|source| ProbeError::Kinematics {
                what: format!("the controller updated in round {k}"),
                source,
            })?;
        let after = survey(&current, actual, ws)?;
        rounds.push(ProbeRound {
            round: k,
            measured: figures(&readings),
            identification,
            after,
            readings,
        });
    }
    let check = read(&current, options.rounds as u64 + 1)?;
    Ok(ProbeCalibration {
        options: *options,
        plan_points: [
            plan.positioning.len(),
            plan.pivots.len(),
            swung,
            plan.readings(),
        ],
        before,
        rounds,
        measured_after: figures(&check),
        controller: Some(current),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Vector3;

    /// A small 6-6 hexapod (joints on circles, struts crossing) with no limits.
    fn machine() -> Hexapod {
        let ring = |r: Real, z: Real, off: Real| -> [Vector3; 6] {
            std::array::from_fn(|i| {
                let k = (i / 2) as Real;
                let s = if i % 2 == 0 { -1.0 } else { 1.0 };
                let ang = (120.0 * k + s * off).to_radians();
                Vector3::new(r * ang.cos(), r * ang.sin(), z)
            })
        };
        let build = |l0| {
            Hexapod::try_new(
                ring(600.0, 1500.0, 12.0),
                ring(200.0, 300.0, 48.0),
                l0,
                Vector3::new(0.0, 0.0, -200.0),
                crate::machine::hexapod::Limits::none(),
            )
            .expect("hexapod")
        };
        // Reference lengths: the struts at home (readings zero there).
        let home = Pose::from_mm_deg([0.0, 0.0, 300.0, 0.0, 0.0, 0.0]);
        build(build([0.0; 6]).strut_lengths(&home))
    }

    fn ws() -> Workspace {
        Workspace {
            x_mm: (-150.0, 150.0),
            y_mm: (-150.0, 150.0),
            z_mm: (200.0, 400.0),
            tilt_deg: 15.0,
        }
    }

    #[test]
    fn readings_on_the_nominal_machine_are_the_noise_alone() {
        let m = machine();
        let plan = default_plan(&m, &ws());
        let r = measure(&m, &m, &plan, 0.0, 1).expect("measures");
        assert!(r.flat().iter().all(|v| v.abs() < 1e-9), "{:?}", r.flat());
        // With noise: the sample σ of ~400 readings within 15 % of the stated one.
        let r = measure(&m, &m, &plan, 2e-3, 7).expect("measures");
        let f = r.flat();
        let s = (f.iter().map(|v| v * v).sum::<Real>() / f.len() as Real).sqrt();
        assert!((s / 2e-3 - 1.0).abs() < 0.15, "{s}");
    }

    #[test]
    fn an_l0_offset_reads_as_its_strut_direction_and_is_calibrated_out() {
        // A strut δ = 0.01 mm longer than the controller believes moves the tool point by
        // δ along the output Jacobian's column (second order: δ²·K_p²/L ≈ 1e-6 mm of it).
        let nominal = machine();
        let mut actual = nominal.clone();
        actual.add_deviation("l0_2", 0.01).expect("l0_2");
        let plan = default_plan(&nominal, &ws());
        let r = measure(&nominal, &actual, &plan, 0.0, 1).expect("measures");
        let pose = plan.positioning[5];
        let jo = nominal.output_jacobian(&pose).expect("jacobian");
        for (k, got) in r.positioning_mm[5].iter().enumerate() {
            let expect = 0.01 * jo[(k, 1)];
            assert!((got - expect).abs() < 2e-6, "{k}: {got} vs {expect}");
        }
        let mut actual = nominal.clone();
        actual.add_deviation("l0_2", 0.1).expect("l0_2");
        let r = measure(&nominal, &actual, &plan, 1e-3, 3).expect("measures");
        let id = identify(&nominal, &plan, &r, false).expect("identifies");
        assert!(id.fit.fits, "{}", id.fit.describe());
        // The platform turned about the tool point is invisible: at least three directions
        // are not determined.
        assert!(id.rank <= PARAMETERS - 3, "{:?}", id.not_determined);
        // The updated controller drives the machine to within a few σ of the commanded
        // points (before: 0.1 mm times the output Jacobian's entries).
        let before = survey(&nominal, &actual, &ws()).expect("survey");
        let updated = nominal.with_parameters(&id.parameters).expect("updated");
        let after = survey(&updated, &actual, &ws()).expect("survey");
        assert!(before.positioning_mm > 0.05, "{before:?}");
        assert!(
            after.positioning_mm < 0.01 && after.pivot_mm < 0.01,
            "{after:?}"
        );
    }
}
