//! `twinmill ballbar` and `twinmill calibrate` on a hexapod scene: the virtual double ball
//! bar's circle with its ISO 230-4 figures, and seed 000's calibration run on the twin
//! (measure, identify, compare with what the scene injected, pose errors before and after),
//! optionally over seeded trials of random deviations. Nothing is written here.

use super::hexapod::HexapodCommandError;
use crate::calibration::hexapod_calibrate::{
    CircleReadings, DEFAULT_POINTS, HexapodCalibration, Plan, PoseErrors, Procedure,
    TableCalibration, WORK, WorkTime, calibrate_commanded, calibrate_commanded_with,
    calibrated_model, default_plan, measured_model, pose_errors, true_deviations, work_time,
};
use crate::calibration::hexapod_design::{CircleDesign, design};
use crate::machine::hexapod::{Hexapod, ParameterId};
use crate::machine::hexapod_accuracy::Workspace;
use crate::math::{CounterRng, Real, Vector3};
use crate::metrology::ballbar::Turns;
use crate::metrology::circular::{CircularFigures, CircularOptions, evaluate};
use crate::metrology::hexapod_dbb::DbbPlane;
use crate::metrology::hexapod_dbb::{DbbCircle, DbbInstrument, RecordedCircle, measure};
use crate::report::plots::polar_plot;
use crate::scene::HexapodScene;
use crate::scene::{SceneError, line_col, read_text};
use serde::Serialize;
use std::path::Path;

fn error(scene: &HexapodScene, message: impl Into<String>) -> HexapodCommandError {
    HexapodCommandError {
        path: scene.path.display().to_string(),
        message: message.into(),
    }
}

/// What `twinmill ballbar` made.
#[derive(Clone, Debug, Serialize)]
pub struct BallbarOutcome {
    /// The ISO 230-4 figures of the trace.
    pub figures: CircularFigures,
    /// The trace file (`circular`'s CSV).
    #[serde(skip)]
    pub csv: String,
    /// The trace.
    #[serde(skip)]
    pub samples: Vec<crate::metrology::circular::Sample>,
    /// The polar plot (PNG bytes).
    #[serde(skip)]
    pub png: Vec<u8>,
    /// The summary text.
    #[serde(skip)]
    pub summary: String,
}

/// Runs `circle` with `instrument` on the scene's machine (the controller on its parameters,
/// nominal unless calibrated; the machine on the actual ones) and evaluates the trace.
pub fn ballbar(
    scene: &HexapodScene,
    circle: &DbbCircle,
    instrument: &DbbInstrument,
) -> Result<BallbarOutcome, HexapodCommandError> {
    let m = measure(&scene.controller, &scene.actual, circle, instrument)
        .map_err(|e| error(scene, e.to_string()))?;
    let opts = CircularOptions {
        radius_mm: circle.radius_mm,
        pitch_mm: None,
    };
    let figures =
        evaluate(&m.samples, &opts, &scene.path).map_err(|e| error(scene, e.to_string()))?;
    let title = format!("{}: DBB {}", scene.name, circle.plane.name());
    let img = polar_plot(&m.samples, &figures, &title).map_err(|e| error(scene, e.to_string()))?;
    let mut png = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .map_err(|e| error(scene, format!("PNG: {e}")))?;
    let comments = vec![
        format!("twinmill ballbar on {}", scene.name),
        circle.describe(),
        format!(
            "table ball at ({:.4}, {:.4}, {:.4}) mm; noise σ {} mm, seed {}",
            m.table_ball_mm.x,
            m.table_ball_mm.y,
            m.table_ball_mm.z,
            instrument.noise_sigma_mm,
            instrument.seed
        ),
    ];
    let summary = ballbar_summary(&scene.name, circle, &figures);
    Ok(BallbarOutcome {
        figures,
        csv: m.csv(&comments),
        samples: m.samples,
        png,
        summary,
    })
}

/// Length noise σ of the calibration's DBB (mm): the ±0.5 µm class.
pub const CALIBRATION_NOISE_MM: Real = 0.5e-3;
/// Largest table-ball mounting error of the jig-free set-ups (mm, uniform per coordinate).
pub const MOUNT_ERROR_MM: Real = 0.05;
/// Random deviations of the trials: base joints uniform in ± this (mm).
pub const TRIAL_JOINT_MM: Real = 0.5;
/// Random deviations of the trials: reference lengths uniform in ± this (mm).
pub const TRIAL_STRUT_MM: Real = 0.2;
/// Most trials a command runs.
pub const MAX_TRIALS: usize = 10_000;

/// One parameter: identified, σ, and the truth in the same gauge.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ParameterRow {
    /// Name.
    pub name: String,
    /// Injected deviation in the report's gauge (mm).
    pub injected_mm: Real,
    /// Identified deviation (mm).
    pub identified_mm: Real,
    /// Standard uncertainty (mm).
    pub sigma_mm: Real,
}

/// One calibration on the twin.
#[derive(Clone, Debug, Serialize)]
pub struct CalibrationRun {
    /// The identification.
    pub calibration: HexapodCalibration,
    /// Per parameter, identified beside injected.
    pub parameters: Vec<ParameterRow>,
    /// The largest |identified − injected| / σ.
    pub worst_normalised_error: Real,
    /// Pose errors with the scene's controller (nominal unless calibrated).
    pub before: PoseErrors,
    /// Pose errors with the calibrated controller (jig-free: the base frame placed by the
    /// tool table calibration, [`TableCalibration::Tool`]).
    pub after: PoseErrors,
    /// Jig-free: the pose errors with the base frame placed instead by the identified base
    /// joints best-fitted onto the actual ones ([`TableCalibration::Joints`]).
    pub after_joint_fit: Option<PoseErrors>,
    /// Jig-free: the table calibration's rotation (µrad) and largest joint displacement (mm).
    pub table_alignment: Option<(Real, Real)>,
    /// The calibrated controller whose pose errors are `after`: the identified parameters,
    /// jig-free with the base frame the tool table calibration placed.
    #[serde(skip)]
    pub controller: Hexapod,
}

/// Measures the plan's circles on `actual`, identifies, and evaluates before and after.
pub fn calibration_run(
    scene: &HexapodScene,
    actual: &Hexapod,
    plan: &Plan,
    ws: &Workspace,
    seed: u64,
) -> Result<CalibrationRun, HexapodCommandError> {
    let procedure = plan.procedure;
    let rng = CounterRng::new(seed ^ 0x006d_6f75_6e74);
    let mut readings = Vec::with_capacity(plan.circles.len());
    for (j, c) in plan.circles.iter().enumerate() {
        let mount = if plan.balls_known() {
            Vector3::zeros()
        } else {
            Vector3::from_fn(|k, _| MOUNT_ERROR_MM * (2.0 * rng.uniform(j as u64, k as u64) - 1.0))
        };
        let inst = DbbInstrument {
            mount_mm: mount,
            noise_sigma_mm: CALIBRATION_NOISE_MM,
            seed,
            stream: (j as u64) << 32,
        };
        let m = measure(&scene.controller, actual, c, &inst)
            .map_err(|e| error(scene, format!("circle {}: {e}", j + 1)))?;
        readings.push(CircleReadings {
            lengths_mm: m.lengths_mm(c.radius_mm),
            commands: m.commands,
        });
    }
    let mut cal = calibrate_commanded(
        &scene.controller,
        &scene.nominal,
        actual,
        plan,
        &readings,
        CALIBRATION_NOISE_MM,
    )
    .map_err(|e| error(scene, e.to_string()))?;
    cal.fit
        .enforce("calibrate", scene.accept_misfit)
        .map_err(|e| error(scene, e.to_string()))?;
    let truth = true_deviations(&scene.nominal, actual, procedure);
    let parameters: Vec<ParameterRow> = cal
        .estimates
        .iter()
        .zip(&truth)
        .map(|(e, (_, t))| ParameterRow {
            name: e.name.clone(),
            injected_mm: *t,
            identified_mm: e.value_mm,
            sigma_mm: e.sigma_mm,
        })
        .collect();
    let worst_normalised_error = parameters
        .iter()
        .filter(|p| p.sigma_mm > 0.0)
        .map(|p| (p.identified_mm - p.injected_mm).abs() / p.sigma_mm)
        .fold(0.0, Real::max);
    let (model, table_alignment) =
        calibrated_model(&cal, actual, actual, ws, TableCalibration::Tool)
            .map_err(|e| error(scene, e.to_string()))?;
    let before = pose_errors(&scene.controller, actual, ws)
        .map_err(|e| error(scene, format!("pose errors before: {e}")))?;
    let after = pose_errors(&model, actual, ws)
        .map_err(|e| error(scene, format!("pose errors after: {e}")))?;
    let after_joint_fit = if cal.procedure == Procedure::JigFree {
        let (m, _) = calibrated_model(&cal, actual, actual, ws, TableCalibration::Joints)
            .map_err(|e| error(scene, e.to_string()))?;
        Some(
            pose_errors(&m, actual, ws)
                .map_err(|e| error(scene, format!("pose errors after: {e}")))?,
        )
    } else {
        None
    };
    Ok(CalibrationRun {
        calibration: cal,
        parameters,
        worst_normalised_error,
        before,
        after,
        after_joint_fit,
        table_alignment: table_alignment.map(|(a, t)| (a * 1e6, t)),
        controller: model,
    })
}

/// The actual machine of trial `seed`: the scene's nominal machine with its platform
/// joints as the scene has them (known from a CMM) and random base-joint and
/// reference-length deviations (uniform ±[`TRIAL_JOINT_MM`], ±[`TRIAL_STRUT_MM`]).
pub fn trial_machine(scene: &HexapodScene, seed: u64) -> Result<Hexapod, HexapodCommandError> {
    let rng = CounterRng::new(seed);
    let mut p = scene.actual.parameters();
    let pn = scene.nominal.parameters();
    for id in (0..18).chain(36..42).filter_map(ParameterId::new) {
        let k = id.index();
        let span = if k < 18 {
            TRIAL_JOINT_MM
        } else {
            TRIAL_STRUT_MM
        };
        p[k] = pn[k] + span * (2.0 * rng.uniform(k as u64, 0) - 1.0);
    }
    scene
        .actual
        .with_parameters(&p)
        .map_err(|e| error(scene, e.to_string()))
}

/// Figures over seeded trials.
#[derive(Clone, Debug, Serialize)]
pub struct TrialSummary {
    /// Trials run.
    pub trials: usize,
    /// Parameters compared in all (trials × 24).
    pub compared: usize,
    /// Fraction of them within 3σ of the truth.
    pub within_3_sigma: Real,
    /// Fraction of trials with every parameter within 3σ.
    pub trials_all_within_3_sigma: Real,
    /// Largest position error before, over the trials (mm).
    pub before_position_mm: Real,
    /// Largest pivot error before (mm).
    pub before_pivot_mm: Real,
    /// Largest position error after (mm).
    pub after_position_mm: Real,
    /// Largest pivot error after (mm).
    pub after_pivot_mm: Real,
    /// Jig-free: the largest position and pivot errors after with the joint-space table
    /// calibration ([`TableCalibration::Joints`]) instead (mm).
    pub after_joint_fit_mm: Option<(Real, Real)>,
}

/// The calibrated `controller` as a controller file (`--controller FILE`, or pasted into the
/// scene): `#` lines of `header`, then `[controller]` with every parameter the calibration
/// solved — as its deviation from the scene's nominal machine (mm), its σ as a comment — and
/// the platform joints where the scene's (the CMM's, which the calibration takes) differ
/// from nominal. Parameters in index order; fixed decimals, so the same calibration writes
/// the same bytes.
pub fn controller_fragment(
    scene: &HexapodScene,
    controller: &Hexapod,
    cal: &HexapodCalibration,
    header: &[String],
) -> String {
    use std::fmt::Write as _;
    let mut t = String::new();
    for h in header {
        let mut line = String::from("#");
        for w in h.split_whitespace() {
            if line.len() + 1 + w.len() > 92 && line.len() > 1 {
                let _ = writeln!(t, "{line}");
                line = String::from("#");
            }
            line.push(' ');
            line.push_str(w);
        }
        let _ = writeln!(t, "{line}");
    }
    t.push_str(
        "# The parameters the controller's kinematics take, as deviations from the scene's nominal\n\
         # machine (mm; σ: the identification's standard uncertainty). Use it with --controller FILE\n\
         # (hexapod ik, fk, pivot, homing; measure, simulate, identify) or paste it into the scene.\n\
         [controller]\n",
    );
    let solved: std::collections::BTreeMap<&str, Real> = cal
        .estimates
        .iter()
        .map(|e| (e.name.as_str(), e.sigma_mm))
        .collect();
    for id in ParameterId::all() {
        let name = id.name();
        let value = controller.parameter(id) - scene.nominal.parameter(id);
        match solved.get(name.as_str()) {
            Some(sigma) => {
                let _ = writeln!(t, "{name} = {value:.7}   # σ {sigma:.7}");
            }
            None if value != 0.0 => {
                let _ = writeln!(t, "{name} = {value:.7}   # the scene's (CMM)");
            }
            None => {}
        }
    }
    t
}

/// The calibrated `controller` as LinuxCNC genhexkins takes it: HAL `setp` lines of its
/// input pins `genhexkins.base.N.x|y|z` (the base joints `b_i`, N = i − 1) and
/// `genhexkins.platform.N.x|y|z` (the platform joints less the tool offset, `a_i − o`:
/// genhexkins' pose is the platform origin's, so the origin is moved to the tool point), and
/// the reference lengths as the joints' `[JOINT_N] HOME_OFFSET` in comments (the strut
/// length at the home index, which the INI file holds). The names are those of
/// `src/emc/kinematics/genhexkins.c` (pins created as `%s.base.%d.x` with the prefix
/// `genhexkins`, LinuxCNC 2.9 and master). `#` lines of `header` on top.
pub fn genhexkins_hal(controller: &Hexapod, header: &[String]) -> String {
    use std::fmt::Write as _;
    let mut t = String::new();
    for h in header {
        let _ = writeln!(t, "# {h}");
    }
    t.push_str(
        "# LinuxCNC genhexkins: base and platform joint coordinates (mm) for the HAL file, with\n\
         # genhexkins.spindle-offset and genhexkins.tool-offset at 0 (the platform joints are\n\
         # given relative to the tool point).\n",
    );
    let o = controller.tool_offset();
    for (i, b) in controller.base_joints().iter().enumerate() {
        for (k, c) in ["x", "y", "z"].iter().enumerate() {
            let _ = writeln!(t, "setp genhexkins.base.{i}.{c} {:.7}", b[k]);
        }
    }
    for (i, a) in controller.platform_joints().iter().enumerate() {
        for (k, c) in ["x", "y", "z"].iter().enumerate() {
            let _ = writeln!(t, "setp genhexkins.platform.{i}.{c} {:.7}", a[k] - o[k]);
        }
    }
    t.push_str(
        "# The struts' reference lengths: each joint's position at its home index (INI file).\n",
    );
    for (i, l) in controller.reference_lengths().iter().enumerate() {
        let _ = writeln!(t, "# [JOINT_{i}] HOME_OFFSET = {l:.7}");
    }
    t
}

/// `twinmill calibrate`'s outcome.
#[derive(Clone, Debug, Serialize)]
pub struct CalibrateOutcome {
    /// Set when the lengths do not fit the model at the stated noise and the misfit was
    /// accepted on request: the outcome's first word.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub warning: Option<String>,
    /// The procedure.
    pub procedure: Procedure,
    /// The calibration of the scene's machine.
    pub run: CalibrationRun,
    /// Working time of both procedures.
    pub work: [WorkTime; 2],
    /// With trials: their figures.
    pub trials: Option<TrialSummary>,
    /// The calibrated controller (the one `run.after` is measured with) as a controller
    /// file ([`controller_fragment`]).
    #[serde(skip)]
    pub fragment: String,
    /// The same controller as LinuxCNC genhexkins' HAL pins ([`genhexkins_hal`]).
    #[serde(skip)]
    pub genhexkins: String,
    /// The summary text.
    #[serde(skip)]
    pub summary: String,
}

/// Summarises seeded trials `1..=n` of `plan`.
pub fn calibration_trials(
    scene: &HexapodScene,
    plan: &Plan,
    ws: &Workspace,
    n: usize,
) -> Result<TrialSummary, HexapodCommandError> {
    let mut s = TrialSummary {
        trials: n,
        compared: 0,
        within_3_sigma: 0.0,
        trials_all_within_3_sigma: 0.0,
        before_position_mm: 0.0,
        before_pivot_mm: 0.0,
        after_position_mm: 0.0,
        after_pivot_mm: 0.0,
        after_joint_fit_mm: None,
    };
    let (mut within, mut all) = (0usize, 0usize);
    for t in 1..=n as u64 {
        let actual = trial_machine(scene, t)?;
        let r = calibration_run(scene, &actual, plan, ws, 1000 + t)?;
        for p in &r.parameters {
            s.compared += 1;
            if (p.identified_mm - p.injected_mm).abs() <= 3.0 * p.sigma_mm {
                within += 1;
            }
        }
        if r.worst_normalised_error <= 3.0 {
            all += 1;
        }
        s.before_position_mm = s.before_position_mm.max(r.before.position_mm);
        s.before_pivot_mm = s.before_pivot_mm.max(r.before.pivot_mm);
        s.after_position_mm = s.after_position_mm.max(r.after.position_mm);
        s.after_pivot_mm = s.after_pivot_mm.max(r.after.pivot_mm);
        if let Some(j) = r.after_joint_fit {
            let (p, v) = s.after_joint_fit_mm.unwrap_or((0.0, 0.0));
            s.after_joint_fit_mm = Some((p.max(j.position_mm), v.max(j.pivot_mm)));
        }
    }
    s.within_3_sigma = within as Real / s.compared.max(1) as Real;
    s.trials_all_within_3_sigma = all as Real / n.max(1) as Real;
    Ok(s)
}

/// The scene's `[workspace]`, which a calibration needs.
pub(crate) fn calibration_workspace(
    scene: &HexapodScene,
) -> Result<Workspace, HexapodCommandError> {
    scene.workspace.ok_or_else(|| {
        error(
            scene,
            "calibrate needs [workspace] (where to place the circles)",
        )
    })
}

/// The circles of a calibration by `procedure`: `plan` (a designed one, whose procedure
/// must agree) or the procedure's fixed plan.
pub(crate) fn procedure_plan(
    scene: &HexapodScene,
    procedure: Procedure,
    plan: Option<Plan>,
    ws: &Workspace,
) -> Result<Plan, HexapodCommandError> {
    match plan {
        Some(p) if p.procedure != procedure => Err(error(
            scene,
            format!(
                "the plan is for the {} procedure, not {}",
                p.procedure.name(),
                procedure.name()
            ),
        )),
        Some(p) => Ok(p),
        None => Ok(default_plan(procedure, ws, DEFAULT_POINTS)),
    }
}

/// Seed 000's calibration of the scene's machine by `procedure` — its fixed plan, or `plan`
/// (a designed one, whose procedure must agree) — and `trials` seeded trials of random
/// deviations.
pub fn calibrate_scene(
    scene: &HexapodScene,
    procedure: Procedure,
    plan: Option<Plan>,
    trials: usize,
) -> Result<CalibrateOutcome, HexapodCommandError> {
    let ws = calibration_workspace(scene)?;
    if trials > MAX_TRIALS {
        return Err(error(
            scene,
            format!("--trials {trials} must lie in 0..={MAX_TRIALS}"),
        ));
    }
    let plan = procedure_plan(scene, procedure, plan, &ws)?;
    let run = calibration_run(scene, &scene.actual, &plan, &ws, 1)?;
    let work = [Procedure::JigFree, Procedure::BallPlate].map(|p| {
        if p == procedure {
            work_time(&plan, &WORK)
        } else {
            work_time(&default_plan(p, &ws, DEFAULT_POINTS), &WORK)
        }
    });
    let trials = if trials > 0 {
        Some(calibration_trials(scene, &plan, &ws, trials)?)
    } else {
        None
    };
    let warning = run.calibration.fit.accepted_line();
    let mut header = vec![format!(
        "The calibrated controller of {} identified by `twinmill identify` on the twin ({}, {} circles measured on the scene's machine, σ {} µm).",
        scene.name,
        plan.procedure.name(),
        plan.circles.len(),
        CALIBRATION_NOISE_MM * 1e3
    )];
    if let Some((angle, shift)) = run.table_alignment {
        header.push(format!(
            "Jig-free: the base frame placed by the table calibration on the tool (taken as exact): turned {angle:.2} µrad, joints moved up to {shift:.4} mm."
        ));
    }
    let fragment = controller_fragment(scene, &run.controller, &run.calibration, &header);
    let genhexkins = genhexkins_hal(&run.controller, &header[..1]);
    let mut summary = calibration_summary(&scene.name, procedure, &run, &work, trials.as_ref());
    if let Some(w) = &warning {
        summary.insert_str(0, &format!("twinmill: {w}\n"));
    }
    Ok(CalibrateOutcome {
        warning,
        procedure,
        run,
        work,
        trials,
        fragment,
        genhexkins,
        summary,
    })
}

fn ballbar_summary(scene: &str, circle: &DbbCircle, f: &CircularFigures) -> String {
    use std::fmt::Write as _;
    let mut t = format!(
        "twinmill: ballbar on {scene}\n  circle        {}\n",
        circle.describe()
    );
    for d in &f.directions {
        let _ = writeln!(
            t,
            "  {:<13} G {:.4} mm, F {:+.4} … {:+.4} mm, centre ({:+.4}, {:+.4}) mm, radius {:+.4} mm",
            format!("{:?}", d.direction).to_lowercase(),
            d.g,
            d.f_min,
            d.f_max,
            d.centre_mm[0],
            d.centre_mm[1],
            d.radius_deviation_mm
        );
    }
    if let Some(h) = f.h {
        let _ = writeln!(t, "  hysteresis    H {h:.4} mm");
    }
    t
}

fn calibration_summary(
    scene: &str,
    procedure: Procedure,
    run: &CalibrationRun,
    work: &[WorkTime; 2],
    trials: Option<&TrialSummary>,
) -> String {
    use std::fmt::Write as _;
    let c = &run.calibration;
    let id = &c.identifiability;
    let mut t = format!(
        "twinmill: calibrate on {scene} ({}: {} circles, {} readings, σ {:.2} µm)\n",
        procedure.name(),
        work[usize::from(procedure == Procedure::BallPlate)].circles,
        work[usize::from(procedure == Procedure::BallPlate)].readings,
        CALIBRATION_NOISE_MM * 1e3
    );
    let _ = writeln!(
        t,
        "  unknowns      {} (24 parameters{}), rank {}, condition {:.3e}",
        id.unknowns,
        if id.ball_unknowns > 0 {
            format!(" + {} table-ball coordinates", id.ball_unknowns)
        } else {
            String::new()
        },
        id.rank,
        id.condition_number
    );
    let _ = writeln!(
        t,
        "  determined    {} of the 24 parameters; platform joints taken from the CMM",
        id.parameters_determined
    );
    if id.gauge.is_empty() {
        let _ = writeln!(
            t,
            "  gauge         none: the plate's balls fix the table frame"
        );
    } else {
        let _ = writeln!(
            t,
            "  not determined  the base frame's 6 rigid motions (lengths only; {:.1e} outside them):",
            id.undetermined_outside_gauge
        );
        for g in &id.gauge {
            let _ = writeln!(t, "                {g}");
        }
        let _ = writeln!(
            t,
            "  gauge         base joints reported with their rigid motion removed (best fit to nominal)"
        );
        if let Some(k) = c.centre_removal_cost {
            let _ = writeln!(
                t,
                "  centre offsets  estimated per circle: σ of the parameters ×{k:.2} against known centres"
            );
        }
    }
    for w in &id.weak {
        let _ = writeln!(t, "  weak          {w}");
    }
    let _ = writeln!(t, "  rank          {}", id.margin.describe());
    let _ = writeln!(
        t,
        "  residual      rms {:.3} µm after {} Levenberg–Marquardt steps",
        c.residual_rms_mm * 1e3,
        c.iterations
    );
    let _ = writeln!(t, "  fit           {}", c.fit.describe());
    let _ = writeln!(t, "  parameter     injected mm  identified mm   σ µm");
    for p in &run.parameters {
        let _ = writeln!(
            t,
            "  {:<12} {:+12.5} {:+14.5} {:7.3}",
            p.name,
            p.injected_mm,
            p.identified_mm,
            p.sigma_mm * 1e3
        );
    }
    let _ = writeln!(
        t,
        "  worst         |identified − injected| = {:.2} σ",
        run.worst_normalised_error
    );
    if let Some((rot, tr)) = run.table_alignment {
        let _ = writeln!(
            t,
            "  table calibration  the tool at the workspace's reference corners (taken as exact): turns the base frame {rot:.1} µrad, moves its joints ≤ {tr:.4} mm"
        );
    }
    let _ = writeln!(
        t,
        "  pose error    before: position {:.4} mm, pivot {:.4} mm; after: {:.2} µm, {:.2} µm",
        run.before.position_mm,
        run.before.pivot_mm,
        run.after.position_mm * 1e3,
        run.after.pivot_mm * 1e3
    );
    if let Some(j) = run.after_joint_fit {
        let _ = writeln!(
            t,
            "  (base frame fitted on the joints instead: {:.2} µm, {:.2} µm)",
            j.position_mm * 1e3,
            j.pivot_mm * 1e3
        );
    }
    for w in work {
        let _ = writeln!(
            t,
            "  work {:<10} {} circles, {} readings, {:.0} mm of path: {:.0} min set-up + {:.1} min measuring = {:.0} min",
            w.procedure.name(),
            w.circles,
            w.readings,
            w.path_mm,
            w.setup_min,
            w.measuring_min,
            w.total_min
        );
    }
    if let Some(s) = trials {
        let _ = writeln!(
            t,
            "  trials        {}: {:.1} % of parameters within 3σ, {:.0} % of trials all within; worst before {:.3} / {:.3} mm, after {:.2} / {:.2} µm (position / pivot)",
            s.trials,
            100.0 * s.within_3_sigma,
            100.0 * s.trials_all_within_3_sigma,
            s.before_position_mm,
            s.before_pivot_mm,
            s.after_position_mm * 1e3,
            s.after_pivot_mm * 1e3
        );
        if let Some((p, v)) = s.after_joint_fit_mm {
            let _ = writeln!(
                t,
                "                (base frame fitted on the joints instead: after {:.2} / {:.2} µm)",
                p * 1e3,
                v * 1e3
            );
        }
    }
    t
}

/// Most circles a plan file may hold.
pub const MAX_PLAN_CIRCLES: usize = 1000;

/// A plan as TOML: `procedure` and one `[[circle]]` table per circle (the table ball's
/// nominal centre, bar length, plane, tilt, platform orientation, swing, direction and
/// samples), with `comments` as `#` lines above; what [`parse_plan`] reads back exactly.
pub fn plan_toml(plan: &Plan, comments: &[String]) -> String {
    use std::fmt::Write as _;
    let mut t = String::new();
    for c in comments {
        let _ = writeln!(t, "# {c}");
    }
    let _ = writeln!(t, "procedure = \"{}\"", plan.procedure.name());
    for c in &plan.circles {
        let v = |x: Real| format!("{x:?}");
        let _ = writeln!(t, "\n[[circle]]");
        let _ = writeln!(
            t,
            "centre_mm = [{}, {}, {}]",
            v(c.centre_mm.x),
            v(c.centre_mm.y),
            v(c.centre_mm.z)
        );
        let _ = writeln!(t, "radius_mm = {}", v(c.radius_mm));
        let _ = writeln!(t, "plane = \"{}\"", c.plane.name());
        let _ = writeln!(t, "tilt_deg = {}", v(c.tilt_deg));
        let o = c.orientation_deg;
        let _ = writeln!(
            t,
            "orientation_deg = [{}, {}, {}]",
            v(o[0]),
            v(o[1]),
            v(o[2])
        );
        let _ = writeln!(t, "swing_deg = {}", v(c.swing_deg));
        let dir = match c.turns {
            Turns::Ccw => "ccw",
            Turns::Cw => "cw",
            Turns::Both => "both",
        };
        let _ = writeln!(t, "direction = \"{dir}\"");
        let _ = writeln!(t, "points = {}", c.points);
    }
    t
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct PlanFile {
    procedure: toml::Spanned<String>,
    #[serde(default)]
    circle: Vec<toml::Spanned<CircleFile>>,
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct CircleFile {
    centre_mm: [Real; 3],
    radius_mm: Real,
    #[serde(default)]
    plane: Option<String>,
    #[serde(default)]
    tilt_deg: Option<Real>,
    #[serde(default)]
    orientation_deg: Option<[Real; 3]>,
    #[serde(default)]
    swing_deg: Option<Real>,
    #[serde(default)]
    direction: Option<String>,
    #[serde(default)]
    points: Option<usize>,
}

/// Reads a plan written by [`plan_toml`] (or by hand: `plane` XY, `tilt_deg` and
/// `swing_deg` 0, level, `direction` ccw and 360 `points` by default). Every value is
/// checked as `twinmill ballbar` checks it; an error names the file, line and column.
pub fn parse_plan(text: &str, path: &Path) -> Result<Plan, SceneError> {
    let err = |at: usize, message: String| {
        let (line, column) = line_col(text, at);
        SceneError::Invalid {
            path: path.to_path_buf(),
            line,
            column,
            message,
        }
    };
    let file: PlanFile =
        toml::from_str(text).map_err(|e| crate::scene::toml_error(text, path, &e))?;
    let procedure = Procedure::from_name(file.procedure.get_ref()).ok_or_else(|| {
        err(
            file.procedure.span().start,
            format!(
                "procedure must be jig-free or ball-plate, got '{}'",
                file.procedure.get_ref()
            ),
        )
    })?;
    if file.circle.is_empty() || file.circle.len() > MAX_PLAN_CIRCLES {
        return Err(err(
            0,
            format!(
                "a plan needs 1 to {MAX_PLAN_CIRCLES} [[circle]] tables, found {}",
                file.circle.len()
            ),
        ));
    }
    let mut circles = Vec::with_capacity(file.circle.len());
    for (j, c) in file.circle.iter().enumerate() {
        let at = c.span().start;
        let f = c.get_ref();
        let bad = |m: String| err(at, format!("circle {}: {m}", j + 1));
        let plane = match &f.plane {
            None => DbbPlane::XY,
            Some(p) => DbbPlane::from_name(p)
                .ok_or_else(|| bad(format!("plane must be XY, YZ or ZX, got '{p}'")))?,
        };
        let turns = match f.direction.as_deref() {
            None | Some("ccw") => Turns::Ccw,
            Some("cw") => Turns::Cw,
            Some("both") => Turns::Both,
            Some(d) => return Err(bad(format!("direction must be ccw, cw or both, got '{d}'"))),
        };
        let circle = DbbCircle {
            centre_mm: Vector3::from(f.centre_mm),
            radius_mm: f.radius_mm,
            plane,
            tilt_deg: f.tilt_deg.unwrap_or(0.0),
            orientation_deg: f.orientation_deg.unwrap_or([0.0; 3]),
            swing_deg: f.swing_deg.unwrap_or(0.0),
            turns,
            points: f.points.unwrap_or(DEFAULT_POINTS),
        };
        circle.validate().map_err(|e| bad(e.to_string()))?;
        circles.push(circle);
    }
    Ok(Plan { procedure, circles })
}

/// Reads a plan file ([`parse_plan`]).
pub fn load_plan(path: &Path) -> Result<Plan, SceneError> {
    parse_plan(&read_text(path)?, path)
}

/// `twinmill calibrate-design`'s outcome.
#[derive(Clone, Debug, Serialize)]
pub struct CalibrationDesignOutcome {
    /// The procedure.
    pub procedure: Procedure,
    /// The design and both predictions.
    pub design: CircleDesign,
    /// The designed plan's circles, one line each.
    pub circles: Vec<String>,
    /// The working time of the designed plan and of the fixed one.
    pub work: [WorkTime; 2],
    /// The plan file ([`plan_toml`]).
    #[serde(skip)]
    pub plan_toml: String,
    /// The summary text.
    #[serde(skip)]
    pub summary: String,
}

/// Designs `circles` circles of `procedure` for the scene's machine ([`design`]) and
/// compares them with the fixed plan.
pub fn calibration_design(
    scene: &HexapodScene,
    procedure: Procedure,
    circles: usize,
) -> Result<CalibrationDesignOutcome, HexapodCommandError> {
    let ws = scene.workspace.ok_or_else(|| {
        error(
            scene,
            "calibrate-design needs [workspace] (where to place the circles)",
        )
    })?;
    let fixed = default_plan(procedure, &ws, DEFAULT_POINTS);
    let d = design(
        &scene.nominal,
        procedure,
        &ws,
        circles,
        DEFAULT_POINTS,
        CALIBRATION_NOISE_MM,
        &fixed,
    )
    .map_err(|e| error(scene, e.to_string()))?;
    let work = [work_time(&d.plan, &WORK), work_time(&fixed, &WORK)];
    let lines: Vec<String> = d.plan.circles.iter().map(DbbCircle::describe).collect();
    let comments = vec![
        format!(
            "twinmill calibrate-design on {}: {} circles, {}",
            scene.name,
            circles,
            procedure.name()
        ),
        format!(
            "predicted after calibration (σ {:.2} µm): worst position σ {:.3} µm, RMS {:.3} µm (fixed plan: {:.3}, {:.3} µm)",
            CALIBRATION_NOISE_MM * 1e3,
            d.predicted.worst_position_sigma_mm * 1e3,
            d.predicted.rms_position_sigma_mm * 1e3,
            d.fixed.worst_position_sigma_mm * 1e3,
            d.fixed.rms_position_sigma_mm * 1e3
        ),
        format!(
            "use: twinmill calibrate {} --procedure {} --plan THIS_FILE",
            scene.path.display(),
            procedure.name()
        ),
    ];
    let plan_toml = plan_toml(&d.plan, &comments);
    let summary = design_summary(&scene.name, procedure, &d, &lines, &work);
    Ok(CalibrationDesignOutcome {
        procedure,
        design: d,
        circles: lines,
        work,
        plan_toml,
        summary,
    })
}

fn design_summary(
    scene: &str,
    procedure: Procedure,
    d: &CircleDesign,
    lines: &[String],
    work: &[WorkTime; 2],
) -> String {
    use std::fmt::Write as _;
    let mut t = format!(
        "twinmill: calibrate-design on {scene} ({}: {} circles from {} candidates, {} unreachable; {} exchanges)\n",
        procedure.name(),
        d.plan.circles.len(),
        d.candidates,
        d.rejected,
        d.exchanges
    );
    for (k, l) in lines.iter().enumerate() {
        let _ = writeln!(t, "  circle {:<3}   {l}", k + 1);
    }
    let _ = writeln!(
        t,
        "  predicted     σ {:.2} µm per reading; position error after calibration over the check poses:",
        CALIBRATION_NOISE_MM * 1e3
    );
    for (name, p, w) in [
        ("designed", &d.predicted, &work[0]),
        ("fixed", &d.fixed, &work[1]),
    ] {
        let _ = writeln!(
            t,
            "  {name:<13} worst σ {:.3} µm, RMS σ {:.3} µm; largest parameter σ {:.2} µm; rank {}, condition {:.3e}; {} circles, {:.0} min",
            p.worst_position_sigma_mm * 1e3,
            p.rms_position_sigma_mm * 1e3,
            p.max_parameter_sigma_mm * 1e3,
            p.rank,
            p.condition_number,
            w.circles,
            w.total_min
        );
    }
    t
}

/// A calibration from bar readings measured on the real machine: the identification, the
/// corrected parameters as a scene fragment, and the summary.
#[derive(Clone, Debug, Serialize)]
pub struct MeasuredCalibrationOutcome {
    /// Set when the lengths do not fit the model at the stated noise and the misfit was
    /// accepted on request: the outcome's first word.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub warning: Option<String>,
    /// The procedure.
    pub procedure: Procedure,
    /// The trace file read for each circle, in the plan's order.
    pub files: Vec<String>,
    /// The identification.
    pub calibration: HexapodCalibration,
    /// How far the identified machine's tool is from where the nominal controller puts it
    /// (largest level positioning and pivot errors over the workspace): the error the
    /// calibration removes, if the identified machine is the real one. Jig-free with the
    /// base frame — which lengths cannot see — placed so that the tool at the table
    /// calibration's reference corners is where the nominal controller puts it, on
    /// average ([`measured_model`]): the readings alone decide it, never the scene's
    /// simulated machine.
    pub predicted_correction: PoseErrors,
    /// The calibrated controller as a controller file ([`controller_fragment`]): the
    /// identified machine's parameters (jig-free, placed as above) for `--controller FILE`.
    pub fragment: String,
    /// The same controller as LinuxCNC genhexkins' HAL pins ([`genhexkins_hal`]).
    pub genhexkins: String,
    /// What the CLI prints.
    pub summary: String,
}

/// The bar readings of `plan`'s circles from their trace files (one a circle, in the plan's
/// order; see [`calibrate_measured`]): each file's header, sample count, turns and angles
/// checked against its circle, a mismatch one line naming the file (and line).
pub fn measured_circles(
    scene: &HexapodScene,
    plan: &Plan,
    files: &[(std::path::PathBuf, String)],
) -> Result<Vec<CircleReadings>, HexapodCommandError> {
    use crate::metrology::circular::parse_trace;
    if files.len() != plan.circles.len() {
        return Err(error(
            scene,
            format!(
                "--readings names {} file(s) for a plan of {} circles (one trace per circle, in the plan's order)",
                files.len(),
                plan.circles.len()
            ),
        ));
    }
    let mut readings = Vec::with_capacity(files.len());
    for (j, ((path, text), c)) in files.iter().zip(&plan.circles).enumerate() {
        let at = path.display();
        if let Some(rec) = RecordedCircle::from_header(text) {
            let diffs = rec.differences(c);
            if !diffs.is_empty() {
                return Err(error(
                    scene,
                    format!(
                        "{at}:{}: the trace's header records another circle than circle {} of the plan: {}",
                        rec.line,
                        j + 1,
                        diffs.join("; ")
                    ),
                ));
            }
        }
        let samples = parse_trace(text, path).map_err(|e| error(scene, e.to_string()))?;
        let angles = c.angles();
        if samples.len() != angles.len() {
            return Err(error(
                scene,
                format!(
                    "{at}: {} samples, but circle {} of the plan has {} ({} points per turn, {:?})",
                    samples.len(),
                    j + 1,
                    angles.len(),
                    c.points,
                    c.turns
                ),
            ));
        }
        for (i, (s, &(turn, theta))) in samples.iter().zip(&angles).enumerate() {
            let d = (s.angle_rad - theta).rem_euclid(std::f64::consts::TAU);
            let off = d.min(std::f64::consts::TAU - d);
            if s.turn != turn || off > 1e-6 {
                return Err(error(
                    scene,
                    format!(
                        "{at}: sample {} is {:?} at {:.6}°, but circle {} of the plan runs {:?} at {:.6}° there",
                        i + 1,
                        s.turn,
                        s.angle_rad.to_degrees(),
                        j + 1,
                        turn,
                        theta.to_degrees()
                    ),
                ));
            }
        }
        readings.push(CircleReadings {
            lengths_mm: samples
                .iter()
                .map(|s| c.radius_mm + s.deviation_mm)
                .collect(),
            commands: angles.iter().map(|&(_, t)| c.command(t)).collect(),
        });
    }
    Ok(readings)
}

/// Seed 000's calibration from readings measured on the machine: one trace file per circle
/// of the plan (`plan`, whose procedure must agree, or `procedure`'s fixed plan), in its
/// order, in the format `twinmill ballbar --out` writes (`circular`'s
/// CSV: turn, angle, deviation = bar length − radius). Each file must hold the circle's
/// samples in the plan's order (its turns and angles, to 1e-6 rad), and a file whose header
/// records its circle (as `ballbar --out` writes it) must record the plan's circle; the
/// platform joints are taken from the scene (known from a CMM, as in seed 000), nothing else
/// of the scene's machine is used. The identification is refused when the lengths cannot
/// come from the identified machine at the DBB's σ ([`crate::calibration::goodness`]),
/// naming the files out of line, unless the scene accepts misfits.
pub fn calibrate_measured(
    scene: &HexapodScene,
    procedure: Procedure,
    plan: Option<Plan>,
    files: &[(std::path::PathBuf, String)],
    monte_carlo: Option<usize>,
) -> Result<MeasuredCalibrationOutcome, HexapodCommandError> {
    use std::fmt::Write as _;
    let ws = calibration_workspace(scene)?;
    let plan = &procedure_plan(scene, procedure, plan, &ws)?;
    let readings = measured_circles(scene, plan, files)?;
    // The platform joints (the CMM's) are the scene's; nothing else of its machine is used.
    let mut cal = calibrate_commanded_with(
        &scene.controller,
        &scene.nominal,
        &scene.actual,
        plan,
        &readings,
        CALIBRATION_NOISE_MM,
        monte_carlo.unwrap_or(0),
    )
    .map_err(|e| error(scene, e.to_string()))?;
    cal.fit.rename_parts(|name| {
        let k = name.strip_prefix("circle ")?.parse::<usize>().ok()?;
        let (path, _) = files.get(k.checked_sub(1)?)?;
        Some(format!("circle {k} ({})", path.display()))
    });
    cal.fit
        .enforce("calibrate --readings", scene.accept_misfit)
        .map_err(|e| error(scene, e.to_string()))?;
    // The identified machine stands in for the real one: its tool against the nominal
    // controller's is the correction the calibration makes.
    let (identified, placement) = measured_model(&cal, &scene.actual, &scene.controller, &ws)
        .map_err(|e| error(scene, e.to_string()))?;
    let predicted_correction = pose_errors(&scene.controller, &identified, &ws)
        .map_err(|e| error(scene, format!("pose errors of the identified machine: {e}")))?;
    let sources = files
        .iter()
        .map(|(p, _)| p.display().to_string())
        .collect::<Vec<_>>()
        .join(", ");
    let mut header = vec![
        format!(
            "The calibrated controller of {} identified by `twinmill identify --readings` ({}, {} circles)",
            scene.name,
            plan.procedure.name(),
            plan.circles.len()
        ),
        format!("from {sources}."),
    ];
    if let Some((angle, shift)) = placement {
        header.push(format!(
            "Jig-free: lengths do not see the base frame; it is placed so that the tool, commanded through the controller that ran the circles to the workspace's eight reference corners, fits the commanded positions (turned {:.2} µrad, joints moved up to {shift:.4} mm): the table frame the machine was aligned in. A table calibration replaces this placement.",
            angle * 1e6
        ));
    }
    let fragment = controller_fragment(scene, &identified, &cal, &header);
    let genhexkins = genhexkins_hal(&identified, &header[..1]);
    let warning = cal.fit.accepted_line();
    let mut summary = warning
        .as_ref()
        .map_or(String::new(), |w| format!("twinmill: {w}\n"));
    summary += &format!(
        "twinmill: calibrate {} from {} measured circles ({})\n  unknowns      {}, rank {}, condition {:.3e}\n  determined    {} of the {} parameters\n",
        scene.name,
        plan.circles.len(),
        plan.procedure.name(),
        cal.identifiability.unknowns,
        cal.identifiability.rank,
        cal.identifiability.condition_number,
        cal.identifiability.parameters_determined,
        cal.estimates.len()
    );
    for g in &cal.identifiability.gauge {
        let _ = writeln!(summary, "  not determined  {g}");
    }
    let _ = writeln!(
        summary,
        "  rank          {}",
        cal.identifiability.margin.describe()
    );
    let _ = writeln!(
        summary,
        "  residual      rms {:.3} µm after {} Levenberg–Marquardt steps",
        cal.residual_rms_mm * 1e3,
        cal.iterations
    );
    let _ = writeln!(summary, "  fit           {}", cal.fit.describe());
    for e in &cal.estimates {
        let mc = e.monte_carlo_spread_mm.map_or(String::new(), |m| {
            format!(" (Monte Carlo ±{:.4} µm)", m * 1e3)
        });
        let _ = writeln!(
            summary,
            "  {:<12}  {:+.4} µm ± {:.4} µm{mc}",
            e.name,
            e.value_mm * 1e3,
            e.sigma_mm * 1e3
        );
    }
    if let Some(n) = monte_carlo.filter(|n| *n > 0) {
        let _ = writeln!(
            summary,
            "  monte carlo   {n} trials at the solution over the residuals' σ"
        );
    }
    let _ = writeln!(
        summary,
        "  correction    {} is off by up to {:.4} mm (position), {:.4} mm (pivot) on the identified machine; the calibrated controller (--corrected) removes it",
        scene.controller_label(),
        predicted_correction.position_mm,
        predicted_correction.pivot_mm
    );
    Ok(MeasuredCalibrationOutcome {
        warning,
        procedure: plan.procedure,
        files: files.iter().map(|(p, _)| p.display().to_string()).collect(),
        calibration: cal,
        predicted_correction,
        fragment,
        genhexkins,
        summary,
    })
}
