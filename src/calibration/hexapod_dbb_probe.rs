//! One identification of a hexapod from double-ball-bar lengths (seed 000) and touch-probe
//! readings (seed 001) together: one [`crate::calibration::engine`] problem with a block
//! per circle and per probe item, one identifiability report, one goodness of fit that
//! refuses a misfit naming the file it is blamed on.
//!
//! **The unknowns.** The 42 parameters of the actual machine (base joints, platform joints,
//! reference lengths; the scene's `[deviations]` names), starting at the controller's
//! values, magnitudes as the two calibrations take them (joints 0.5 mm, reference lengths
//! 0.2 mm); without a jig, three coordinates of each circle's table ball as nuisance
//! unknowns (magnitude 0.5 mm).
//!
//! **The model.** Every commanded pose is driven through the controller's inverse and the
//! machine's forward kinematics ([`twin_pose`]): a bar reads `|p − c_j|`
//! ([`DbbLengths`]), the probe `p − t` (positioning) and `p(T_ab) − p(T_level)` (pivot)
//! along the table's x, y, z. Both in closed form: the tool point's derivatives are the
//! position rows of [`Hexapod::pose_parameter_jacobian`].
//!
//! **What each sees.** Neither instrument sees the platform joints turned rigidly about
//! the tool point (the tool point reaches the same place): three directions stay
//! undetermined whatever the data. Lengths alone without a jig do not see the base frame
//! (its six rigid motions with the table balls); the probe's positioning, read against the
//! table's datum, does — together the base frame is fixed by the probe and the strut
//! geometry by the bar's thousands of readings, so directions the probe alone sees too
//! weakly (a base joint along its strut against that strut's reference length) are
//! determined.
//!
//! **Invariant:** plain functions of the hexapods, plans and readings given; never touches
//! files; a direction the readings do not determine is named, never valued.

use crate::calibration::engine::{
    Block, Forward, Problem, Unknown, mean_and_spread, monte_carlo, solve,
};
use crate::calibration::hexapod_calibrate::{
    CircleReadings, DbbLengths, Plan, ball_unknowns, magnitude,
};
use crate::calibration::hexapod_probe::{
    ProbeError, ProbeIdentification, ProbePlan, ProbeReadings, identification_of,
};
use crate::machine::hexapod::{Hexapod, PARAMETERS, ParameterId, ParameterJacobian, twin_pose};
use crate::math::{Real, Vector3};
use nalgebra::DMatrix;

/// A bar's readings: the plan's circles and their lengths, one file a circle.
#[derive(Clone, Copy, Debug)]
pub struct DbbData<'a> {
    /// The circles (the procedure says whether the table balls are known).
    pub plan: &'a Plan,
    /// One entry per circle.
    pub readings: &'a [CircleReadings],
    /// The file (or name) of each circle's readings, in the plan's order.
    pub files: &'a [String],
    /// The bar's length noise σ (mm).
    pub sigma_mm: Real,
}

/// The probe's readings of a plan, from one file.
#[derive(Clone, Copy, Debug)]
pub struct ProbeData<'a> {
    /// What was probed.
    pub plan: &'a ProbePlan,
    /// The readings (with their σ).
    pub readings: &'a ProbeReadings,
    /// The file (or name) they came from.
    pub file: &'a str,
}

/// The probe's readings as rows of the model: positioning, then pivot swing by swing.
struct ProbeRows<'a> {
    controller: &'a Hexapod,
    plan: &'a ProbePlan,
}

impl ProbeRows<'_> {
    /// The readings at `machine` and, if `with_jacobian`, their rows over the 42
    /// parameters (the first columns of `n`).
    fn evaluate(
        &self,
        machine: &Hexapod,
        n: usize,
        with_jacobian: bool,
    ) -> Result<(Vec<Real>, DMatrix<Real>), String> {
        let reach = |pose: &crate::machine::hexapod::Pose| {
            let reached = twin_pose(self.controller, machine, pose)
                .map_err(|e| format!("probe at {pose}: {e}"))?;
            let j = if with_jacobian {
                Some(
                    machine
                        .pose_parameter_jacobian(&reached)
                        .map_err(|e| format!("probe at {pose}: {e}"))?,
                )
            } else {
                None
            };
            Ok::<_, String>((reached.position, j))
        };
        let rows = if with_jacobian {
            self.plan.readings()
        } else {
            0
        };
        let mut a = DMatrix::zeros(rows, n);
        let mut f = Vec::with_capacity(self.plan.readings());
        let mut put =
            |f: &mut Vec<Real>,
             v: Vector3,
             j: Option<(&ParameterJacobian, Option<&ParameterJacobian>)>| {
                let row = f.len();
                for k in 0..3 {
                    f.push(v[k]);
                    if let Some((jp, minus)) = j {
                        for p in 0..PARAMETERS {
                            a[(row + k, p)] = jp[(k, p)] - minus.map_or(0.0, |m| m[(k, p)]);
                        }
                    }
                }
            };
        for pose in &self.plan.positioning {
            let (p, j) = reach(pose)?;
            put(&mut f, p - pose.position, j.as_ref().map(|j| (j, None)));
        }
        for s in &self.plan.pivots {
            let (level, jl) = reach(&s.pose(0.0, 0.0))?;
            for ab in &s.angles_deg {
                let (p, j) = reach(&s.pose(ab[0], ab[1]))?;
                put(
                    &mut f,
                    p - level,
                    j.as_ref().zip(jl.as_ref()).map(|(j, l)| (j, Some(l))),
                );
            }
        }
        Ok((f, a))
    }
}

/// Both instruments' readings from the 42 parameters (and the table balls).
struct Together<'a> {
    machine: &'a Hexapod,
    dbb: Option<DbbLengths<'a>>,
    probe: Option<ProbeRows<'a>>,
}

impl Together<'_> {
    fn evaluate(
        &self,
        x: &[Real],
        with_jacobian: bool,
    ) -> Result<(Vec<Real>, DMatrix<Real>), String> {
        let mut f = Vec::new();
        let mut rows: Vec<DMatrix<Real>> = Vec::new();
        if let Some(d) = &self.dbb {
            if with_jacobian {
                let a = d.jacobian(x).unwrap_or_else(|| Err("no Jacobian".into()))?;
                rows.push(a);
            }
            f.extend(d.predict(x)?);
        }
        if let Some(p) = &self.probe {
            let mut q = self.machine.parameters();
            q.copy_from_slice(&x[..PARAMETERS]);
            let machine = self
                .machine
                .with_parameters(&q)
                .map_err(|e| format!("the machine at the unknowns: {e}"))?;
            let (fp, a) = p.evaluate(&machine, x.len(), with_jacobian)?;
            f.extend(fp);
            rows.push(a);
        }
        let mut a = DMatrix::zeros(if with_jacobian { f.len() } else { 0 }, x.len());
        if with_jacobian {
            let mut at = 0;
            for r in rows {
                a.view_mut((at, 0), r.shape()).copy_from(&r);
                at += r.nrows();
            }
        }
        Ok((f, a))
    }
}

impl Forward for Together<'_> {
    fn predict(&self, x: &[Real]) -> Result<Vec<Real>, String> {
        self.evaluate(x, false).map(|(f, _)| f)
    }

    fn jacobian(&self, x: &[Real]) -> Option<Result<DMatrix<Real>, String>> {
        Some(self.evaluate(x, true).map(|(_, a)| a))
    }
}

/// Identifies the 42 parameters from the bar's readings, the probe's, or both at once,
/// every reading taken on the machine commanded through `controller` (the start); refuses
/// readings the identified machine cannot explain at their σ — naming the file — unless
/// `accept_misfit`. Values are deviations from the controller's.
pub fn identify(
    controller: &Hexapod,
    dbb: Option<DbbData>,
    probe: Option<ProbeData>,
    accept_misfit: bool,
) -> Result<ProbeIdentification, ProbeError> {
    identify_with(controller, dbb, probe, accept_misfit, 0)
}

/// The noise seed of [`identify_with`]'s Monte-Carlo trials.
pub const MONTE_CARLO_SEED: u64 = 1;

/// [`identify`] with `trials` Monte-Carlo trials at the solution ([`monte_carlo`], seed
/// [`MONTE_CARLO_SEED`]; none for 0): every parameter's spread and each identified one's.
pub fn identify_with(
    controller: &Hexapod,
    dbb: Option<DbbData>,
    probe: Option<ProbeData>,
    accept_misfit: bool,
    trials: usize,
) -> Result<ProbeIdentification, ProbeError> {
    let input = |m: String| Err(ProbeError::Input(m));
    if dbb.is_none() && probe.is_none() {
        return input("no readings: a bar's, a probe's or both are needed".into());
    }
    let ids: Vec<ParameterId> = ParameterId::all().collect();
    let start = controller.parameters();
    let mut blocks = Vec::new();
    let mut nuisance = Vec::new();
    let mut statistic = Vec::new();
    if let Some(d) = &dbb {
        if d.readings.len() != d.plan.circles.len() || d.files.len() != d.readings.len() {
            return input(format!(
                "{} circles of readings ({} files) for a plan of {}",
                d.readings.len(),
                d.files.len(),
                d.plan.circles.len()
            ));
        }
        if !(d.sigma_mm.is_finite() && d.sigma_mm > 0.0) {
            return input(format!(
                "the bar's noise σ {} mm must be positive",
                d.sigma_mm
            ));
        }
        for (j, (r, file)) in d.readings.iter().zip(d.files).enumerate() {
            if r.commands.len() != r.lengths_mm.len() || r.commands.is_empty() {
                return input(format!(
                    "{file}: {} poses and {} lengths",
                    r.commands.len(),
                    r.lengths_mm.len()
                ));
            }
            blocks.push(Block {
                name: format!("circle {} ({file})", j + 1),
                values: r.lengths_mm.clone(),
                sigma: vec![d.sigma_mm; r.lengths_mm.len()],
            });
        }
        if !d.plan.balls_known() {
            nuisance = ball_unknowns(&d.plan.circles, "");
        }
        statistic.push(format!("bar lengths at σ {} µm", d.sigma_mm * 1e3));
    }
    if let Some(p) = &probe {
        let r = p.readings;
        if !(r.sigma_mm.is_finite() && r.sigma_mm > 0.0) {
            return input(format!(
                "{}: the probe noise σ {} mm must be positive",
                p.file, r.sigma_mm
            ));
        }
        if r.positioning_mm.len() != p.plan.positioning.len()
            || r.pivot_mm.len() != p.plan.pivots.len()
            || r.pivot_mm
                .iter()
                .zip(&p.plan.pivots)
                .any(|(v, s)| v.len() != s.angles_deg.len())
        {
            return input(format!(
                "{}: the readings do not match the plan's points",
                p.file
            ));
        }
        let flat3 = |v: &[[Real; 3]]| v.iter().flatten().copied().collect::<Vec<Real>>();
        let block = |name: String, values: Vec<Real>| Block {
            sigma: vec![r.sigma_mm; values.len()],
            name,
            values,
        };
        blocks.push(block(
            format!("{}: positioning grid", p.file),
            flat3(&r.positioning_mm),
        ));
        for (s, v) in p.plan.pivots.iter().zip(&r.pivot_mm) {
            let q = s.point_mm;
            blocks.push(block(
                format!(
                    "{}: pivot at ({:.1}, {:.1}, {:.1}) mm",
                    p.file, q[0], q[1], q[2]
                ),
                flat3(v),
            ));
        }
        statistic.push(format!("probe readings at σ {} µm", r.sigma_mm * 1e3));
    }
    let model = Together {
        machine: controller,
        dbb: dbb.map(|d| DbbLengths {
            controller,
            machine: controller,
            solved: ids.clone(),
            circles: &d.plan.circles,
            readings: d.readings,
            balls_at: (!d.plan.balls_known()).then_some(PARAMETERS),
        }),
        probe: probe.map(|p| ProbeRows {
            controller,
            plan: p.plan,
        }),
    };
    let problem = Problem {
        parameters: ids
            .iter()
            .map(|&id| Unknown {
                name: id.name(),
                start: start[id.index()],
                magnitude: magnitude(id),
            })
            .collect(),
        nuisance,
        blocks,
        forward: &model,
        statistic: statistic.join(" and "),
    };
    let mut o = solve(&problem).map_err(|e| ProbeError::Identification(e.to_string()))?;
    o.fit
        .enforce("identify", accept_misfit)
        .map_err(|m| ProbeError::Misfit(m.to_string()))?;
    let readings = problem.blocks.iter().map(|b| b.values.len()).sum();
    let mc = (trials > 0)
        .then(|| monte_carlo(&problem, &o, trials, MONTE_CARLO_SEED))
        .transpose()
        .map_err(|e| ProbeError::Identification(e.to_string()))?;
    let mut id = identification_of(o, &start, readings);
    if let Some(mc) = mc {
        id.parameter_spread = Some(std::array::from_fn(|i| {
            mean_and_spread(&mc.solutions.iter().map(|x| x[i]).collect::<Vec<_>>()).1
        }));
        for e in &mut id.identified {
            e.monte_carlo_spread_mm = mc
                .spread
                .iter()
                .find(|(n, _)| *n == e.name)
                .map(|(_, v)| *v);
        }
    }
    Ok(id)
}
