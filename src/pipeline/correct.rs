//! `correct`: the correction loop of seed 002 Fig. 1 — correct the program for a model of
//! the machine, simulate the corrected program on the scene's machine, measure faces, path
//! and whole part, refine — and the model identified by `run` to correct for.

use super::{PipelineError, machine_part};
use crate::calibration::correct::{
    CorrectError, CorrectOptions, CorrectedProgram, correct_program, face_errors, in_tcp,
    part_error, path_error, uncorrected,
};
use crate::cutting::sweep::{SweepOptions, SweepReport};
use crate::machine::chain::Chain;
use crate::machine::tcp::Controller;
use crate::math::Real;
use crate::nc::Program;
use crate::progress::Progress;
use crate::report::{CorrectIteration, CorrectReport, Report, UncorrectableReport};
use crate::scene::Scene;
use std::collections::BTreeMap;
use std::time::Instant;

/// Largest number of correction passes: each refines the subdivision fourfold; exact
/// kinematic inversion meets any reachable accuracy in the first or second.
const MAX_CORRECT_PASSES: usize = 4;

/// The verification sweep's rotary sub-step bound, as a fraction of the accuracy: its own
/// approximation must not eat the error budget.
const SWEEP_BOUND_FRACTION: Real = 0.1;

/// What `correct` produces.
#[derive(Clone, Debug)]
pub struct CorrectOutcome {
    /// The report.
    pub report: CorrectReport,
    /// The final corrected program.
    pub corrected: CorrectedProgram,
    /// Comment lines for the head of the emitted program.
    pub header: Vec<String>,
}

fn nonzero_deviations(chain: &Chain) -> BTreeMap<String, Real> {
    chain
        .deviation_names()
        .into_iter()
        .filter_map(|n| {
            let v = chain.deviation(chain.deviation_id(&n).ok()?);
            // What rounds to nothing at the printed resolution (the rounding of an ISO
            // term composed onto the joints) is not a deviation corrected for.
            (crate::report::deviation_value(&n, v) != "0").then_some((n, v))
        })
        .collect()
}

/// The correction loop of seed 002 Fig. 1 on a scene: correct `program` for the deviated
/// chain `model` (the scene's injected deviations, or identified ones), simulate the
/// corrected program on the scene's machine (`scene.chain()`), measure the milled faces and the
/// tool path against the nominal ones, and refine the subdivision until both are within
/// `accuracy_mm` — or report what stays out and why. Pass 0 is the program as given.
pub fn correct(
    scene: &Scene,
    program: &Program,
    model: &Chain,
    accuracy_mm: Real,
    progress: &dyn Progress,
) -> Result<CorrectOutcome, PipelineError> {
    let spath = scene.path.display().to_string();
    let cerr = |source: CorrectError| {
        let location = match source.line() {
            Some(line) => format!("{}:{line}", program.path.display()),
            None => spath.clone(),
        };
        PipelineError::Correct { location, source }
    };
    if !(accuracy_mm.is_finite() && accuracy_mm > 0.0) {
        return Err(cerr(CorrectError::BadAccuracy(accuracy_mm)));
    }
    let start = program.moves.first().map_or(scene.home(), |m| m.start);
    let nominal = scene.chain().nominal();
    let mut timings: Vec<(String, Real)> = Vec::new();
    let mut sweep_scene = scene.clone();
    sweep_scene.sweep = SweepOptions {
        rotary_step_bound_mm: scene
            .sweep
            .rotary_step_bound_mm
            .min(accuracy_mm * SWEEP_BOUND_FRACTION),
    };
    // The nominal part: the program as given on the nominal machine.
    let nominal_part = {
        let mut nominal_scene = sweep_scene.clone();
        if let Some(m) = nominal_scene.serial_mut() {
            m.chain = nominal.clone();
        }
        machine_part(&nominal_scene, program, progress)?
    };
    timings.extend(
        nominal_part
            .timings
            .iter()
            .map(|(n, t)| (format!("{n} nominal"), *t)),
    );
    // Simulate and measure one program on the scene's machine.
    let measure = |iteration: usize,
                   tol: Option<Real>,
                   cp: &CorrectedProgram,
                   timings: &mut Vec<(String, Real)>|
     -> Result<CorrectIteration, PipelineError> {
        let part = cut_corrected(&sweep_scene, program, cp, iteration, timings, progress)?;
        let clock = Instant::now();
        let faces = face_errors(
            &part.stock,
            &nominal,
            &scene.tool,
            &program.moves,
            &scene.faces,
            &scene.stock_box,
            &scene.face_options,
        )
        .map_err(cerr)?;
        let path = path_error(scene.chain(), &scene.tool, program, cp);
        let whole = part_error(&part.stock, &nominal_part.stock);
        timings.push((
            format!("measure {iteration}"),
            clock.elapsed().as_secs_f64(),
        ));
        Ok(CorrectIteration {
            iteration,
            path_tolerance_mm: tol,
            blocks: cp.blocks.len(),
            path,
            part: whole,
            predicted_error_mm: faces.max_abs_mm(),
            faces,
            sweep: part.sweep,
        })
    };

    let mut opts = CorrectOptions::for_accuracy(accuracy_mm);
    let clock = Instant::now();
    let mut next = Some(correct_program(model, &scene.tool, program, &start, &opts).map_err(cerr)?);
    timings.push(("correct 1".into(), clock.elapsed().as_secs_f64()));
    // Pass 0, the program as given. Its faces may be too far off to find: then no figure.
    let given = uncorrected(scene.chain(), program, &start).map_err(cerr)?;
    let mut iterations = vec![match measure(0, None, &given, &mut timings) {
        Ok(it) => it,
        Err(PipelineError::Correct {
            source: CorrectError::Face { .. },
            ..
        }) => CorrectIteration {
            iteration: 0,
            path_tolerance_mm: None,
            blocks: given.blocks.len(),
            path: path_error(scene.chain(), &scene.tool, program, &given),
            part: crate::calibration::correct::PartError::default(),
            faces: crate::calibration::correct::FaceCheck {
                faces: Vec::new(),
                step_mm: None,
            },
            predicted_error_mm: None,
            sweep: SweepReport::default(),
        },
        Err(e) => return Err(e),
    }];
    let mut status = String::new();
    let mut met = false;
    let mut last = None;
    for pass in 1..=MAX_CORRECT_PASSES {
        let cp = match next.take() {
            Some(cp) => cp,
            None => {
                let clock = Instant::now();
                let cp =
                    correct_program(model, &scene.tool, program, &start, &opts).map_err(cerr)?;
                timings.push((format!("correct {pass}"), clock.elapsed().as_secs_f64()));
                cp
            }
        };
        let it = measure(pass, Some(opts.path_tolerance_mm), &cp, &mut timings)?;
        let residual = cp.summary.residual_max_mm;
        // The same path on the model corrected for: what the correction itself leaves.
        let on_model = path_error(model, &scene.tool, program, &cp).max_mm - residual;
        let it_has_faces = it.predicted_error_mm.is_some();
        let faces_ok = it.predicted_error_mm.is_none_or(|e| e <= accuracy_mm);
        let path_ok = it.path.max_mm <= accuracy_mm;
        // Path error beyond what no command can remove: subdivision, rounding, the model.
        let correctable = it.path.max_mm - residual;
        iterations.push(it);
        last = Some(cp);
        if faces_ok && path_ok {
            met = true;
            let what = if it_has_faces {
                "faces and path"
            } else {
                "path (no faces named)"
            };
            status = format!("met in {pass} pass(es): {what} within {accuracy_mm} mm");
            break;
        }
        if correctable <= accuracy_mm && faces_ok {
            let faces = if it_has_faces {
                format!("faces within {accuracy_mm} mm; ")
            } else {
                String::new()
            };
            status = format!(
                "{faces}the path is off by up to {residual:.6} mm at the flute's ends \
                 because of deviations these axes cannot correct (see uncorrectable)"
            );
            break;
        }
        if correctable <= accuracy_mm {
            status = format!(
                "the faces are off by up to {:.6} mm although the path is within reach; \
                 the model corrected for differs from the simulated machine, or deviations these \
                 axes cannot correct reach the faces (see uncorrectable)",
                iterations
                    .last()
                    .and_then(|i| i.predicted_error_mm)
                    .unwrap_or(Real::NAN)
            );
            break;
        }
        if on_model <= accuracy_mm {
            // Finer sub-moves cannot remove what they did not cause.
            status = format!(
                "the path is off by {correctable:.6} mm beyond the uncorrectable residual \
                 on the simulated machine but only {on_model:.6} mm on the model corrected for: \
                 the model differs from the simulated machine"
            );
            break;
        }
        opts.path_tolerance_mm /= 4.0;
        status = format!(
            "after {pass} pass(es) the path is still off by {correctable:.6} mm beyond the residual"
        );
    }
    let corrected = last.unwrap_or(given);
    // A TCP controller gets the corrected poses as tool-tip coordinates.
    let tcp = scene.controller() == Controller::Tcp;
    let corrected = if tcp {
        in_tcp(&corrected, &nominal)
    } else {
        corrected
    };
    // Each deviation alone: what no axis command removes.
    let clock = Instant::now();
    let mut uncorrectable = Vec::new();
    for (name, value) in nonzero_deviations(model) {
        let mut alone = model.nominal();
        if let Ok(id) = alone.deviation_id(&name) {
            alone.set_deviation(id, value);
        }
        let cp = correct_program(
            &alone,
            &scene.tool,
            program,
            &start,
            &CorrectOptions::for_accuracy(accuracy_mm),
        )
        .map_err(cerr)?;
        uncorrectable.push(UncorrectableReport {
            deviation: name,
            value,
            residual_rms_mm: cp.summary.residual_rms_mm,
            residual_max_mm: cp.summary.residual_max_mm,
        });
    }
    timings.push(("uncorrectable".into(), clock.elapsed().as_secs_f64()));
    let corrected_for = nonzero_deviations(model);
    let file = format!("{}-corrected.ngc", scene.name);
    let fin = iterations.last().cloned();
    let mut header = vec![
        format!(
            "twinmill correct: {} corrected for the machine of scene {}",
            program.path.display(),
            scene.name
        ),
        format!(
            "deviations corrected for, mm and rad: {}",
            if corrected_for.is_empty() {
                "none".to_string()
            } else {
                corrected_for
                    .iter()
                    .map(|(k, v)| format!("{k} = {}", crate::report::deviation_value(k, *v)))
                    .collect::<Vec<_>>()
                    .join(", ")
            }
        ),
    ];
    if let Some(f) = &fin {
        let faces = match f.predicted_error_mm {
            Some(e) => format!("faces within {e:.6} mm, "),
            None => String::new(),
        };
        header.push(format!(
            "predicted on the twin: {faces}path within {:.6} mm, accuracy asked {} mm",
            f.path.max_mm, accuracy_mm
        ));
    }
    if tcp {
        header.push(
            "tool-centre-point program (machine.controller = tcp): X Y Z the tool tip in the \
             workpiece frame, A B C the rotary axes, through the nominal kinematics"
                .into(),
        );
    }
    header.push("each block names its source line, subdivided moves also their part k/n".into());
    let report = CorrectReport {
        warning: None,
        scene: scene.name.clone(),
        program: program.path.display().to_string(),
        corrected_program: file,
        corrected_for,
        simulated: scene.injected().clone(),
        accuracy_mm,
        met,
        status,
        iterations,
        correction: corrected.summary,
        uncorrectable,
        moves: corrected.per_move.clone(),
        timings_s: timings,
    };
    Ok(CorrectOutcome {
        report,
        corrected,
        header,
    })
}

/// The model to correct for from a run's identification: the scene's identification model
/// (nominal plus known deviations) with the identified values set. A combination such as
/// `gamma_AY+gamma_YX` sets its first deviation so that the sum is the identified value,
/// the others staying at their known values. Errors if nothing was identified.
pub fn identified_model(scene: &Scene, report: &Report) -> Result<Chain, PipelineError> {
    let err = |message: String| PipelineError::Measure {
        path: scene.path.display().to_string(),
        message,
    };
    if report.identified.is_empty() {
        return Err(err(format!(
            "no deviation was identified from the scan (not identifiable: {})",
            report.not_identified.join(", ")
        )));
    }
    let mut model = scene.model().clone();
    for (name, value) in &report.identified {
        let mut parts = name.split('+');
        let first = parts.next().unwrap_or_default();
        let mut rest = 0.0;
        for other in parts {
            let id = model.deviation_id(other).map_err(|e| err(e.to_string()))?;
            rest += model.deviation(id);
        }
        let id = model.deviation_id(first).map_err(|e| err(e.to_string()))?;
        model.set_deviation(id, value - rest);
    }
    Ok(model)
}

/// The correction of a hexapod scene's program (see
/// [`crate::calibration::correct::correct_hexapod_program`]): every commanded pose rewritten
/// so that the machine as built, driven by the scene's controller, reaches the nominal pose
/// in all six degrees of freedom; the corrected program simulated on the scene's machine,
/// its path and whole part measured against the nominal ones (the program as given on the
/// nominal machine), the subdivision refined until within `accuracy_mm`. Pass 0 is the
/// program as given. Six struts correct every deviation of the 42 parameters: nothing is
/// uncorrectable inside the workspace. A scene with table axes is refused.
pub fn correct_hexapod(
    scene: &Scene,
    program: &Program,
    accuracy_mm: Real,
    progress: &dyn Progress,
) -> Result<CorrectOutcome, PipelineError> {
    use crate::calibration::correct::{correct_hexapod_program, hexapod_path_error};
    use crate::scene::Machine;
    let spath = scene.path.display().to_string();
    let cerr = |source: CorrectError| {
        let location = match source.line() {
            Some(line) => format!("{}:{line}", program.path.display()),
            None => spath.clone(),
        };
        PipelineError::Correct { location, source }
    };
    if !(accuracy_mm.is_finite() && accuracy_mm > 0.0) {
        return Err(cerr(CorrectError::BadAccuracy(accuracy_mm)));
    }
    let Machine::Hexapod(hex) = &scene.machine else {
        return correct(scene, program, scene.chain(), accuracy_mm, progress);
    };
    let twin = &hex.twin;
    if twin.table.is_some() {
        return Err(cerr(CorrectError::Unsupported(
            "[table_axes]: correct of a hexapod with table axes is not supported: the platform \
             holds the table's angle at home, five commanded degrees of freedom for a six-degree \
             correction"
                .into(),
        )));
    }
    let start = program.moves.first().map_or(scene.home(), |m| m.start);
    let mut timings: Vec<(String, Real)> = Vec::new();
    let mut sweep_scene = scene.clone();
    sweep_scene.sweep = SweepOptions {
        rotary_step_bound_mm: scene
            .sweep
            .rotary_step_bound_mm
            .min(accuracy_mm * SWEEP_BOUND_FRACTION),
    };
    // The nominal part: the program as given on the design (controller and machine both
    // nominal).
    let nominal_part = {
        let mut nominal_scene = sweep_scene.clone();
        if let Machine::Hexapod(h) = &mut nominal_scene.machine {
            h.twin.controller = h.twin.nominal.clone();
            h.twin.actual = h.twin.nominal.clone();
        }
        machine_part(&nominal_scene, program, progress)?
    };
    timings.extend(
        nominal_part
            .timings
            .iter()
            .map(|(n, t)| (format!("{n} nominal"), *t)),
    );
    let no_faces = || crate::calibration::correct::FaceCheck {
        faces: Vec::new(),
        step_mm: None,
    };
    let measure = |iteration: usize,
                   tol: Option<Real>,
                   cp: &CorrectedProgram,
                   timings: &mut Vec<(String, Real)>|
     -> Result<CorrectIteration, PipelineError> {
        let part = cut_corrected(&sweep_scene, program, cp, iteration, timings, progress)?;
        let clock = Instant::now();
        let path = hexapod_path_error(twin, &scene.tool, program, cp).map_err(cerr)?;
        let whole = part_error(&part.stock, &nominal_part.stock);
        timings.push((
            format!("measure {iteration}"),
            clock.elapsed().as_secs_f64(),
        ));
        Ok(CorrectIteration {
            iteration,
            path_tolerance_mm: tol,
            blocks: cp.blocks.len(),
            path,
            predicted_error_mm: None,
            part: whole,
            faces: no_faces(),
            sweep: part.sweep,
        })
    };
    let given = uncorrected(scene.chain(), program, &start).map_err(cerr)?;
    let mut iterations = vec![measure(0, None, &given, &mut timings)?];
    let mut opts = CorrectOptions::for_accuracy(accuracy_mm);
    let mut status = String::new();
    let mut met = false;
    let mut last = None;
    for pass in 1..=MAX_CORRECT_PASSES {
        let clock = Instant::now();
        let cp =
            correct_hexapod_program(twin, &scene.tool, program, &start, &opts).map_err(cerr)?;
        timings.push((format!("correct {pass}"), clock.elapsed().as_secs_f64()));
        let it = measure(pass, Some(opts.path_tolerance_mm), &cp, &mut timings)?;
        let (path_mm, part_mm) = (it.path.max_mm, it.part.max_mm);
        iterations.push(it);
        last = Some(cp);
        if path_mm <= accuracy_mm && part_mm <= accuracy_mm {
            met = true;
            status = format!(
                "met in {pass} pass(es): path and part within {accuracy_mm} mm (all six degrees \
                 of freedom corrected)"
            );
            break;
        }
        opts.path_tolerance_mm /= 4.0;
        status = format!(
            "after {pass} pass(es) the path is off by {path_mm:.6} mm and the part by \
             {part_mm:.6} mm"
        );
    }
    let corrected = last.unwrap_or(given);
    let corrected_for = scene.injected().clone();
    let file = format!("{}-corrected.ngc", scene.name);
    let mut header = vec![
        format!(
            "twinmill correct: {} corrected for the hexapod of scene {}",
            program.path.display(),
            scene.name
        ),
        format!(
            "deviations of the machine as built, mm: {}",
            if corrected_for.is_empty() {
                "none".to_string()
            } else {
                corrected_for
                    .iter()
                    .map(|(k, v)| format!("{k} = {v}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            }
        ),
        format!(
            "the controller's kinematics: {}",
            if twin.controller == twin.nominal {
                "the nominal machine's".to_string()
            } else {
                "calibrated parameters (poses corrected for this controller only)".to_string()
            }
        ),
    ];
    if let Some(f) = iterations.last() {
        header.push(format!(
            "predicted on the twin: path within {:.6} mm, part within {:.6} mm, accuracy asked {} mm",
            f.path.max_mm, f.part.max_mm, accuracy_mm
        ));
    }
    header.push(
        "X Y Z the tool point in the base frame, A B C the platform's angles, turned about z \
         by C, then y by B, then x by A; each block names its source line, subdivided moves \
         also their part k/n"
            .into(),
    );
    let report = CorrectReport {
        warning: None,
        scene: scene.name.clone(),
        program: program.path.display().to_string(),
        corrected_program: file,
        corrected_for,
        simulated: scene.injected().clone(),
        accuracy_mm,
        met,
        status,
        iterations,
        correction: corrected.summary,
        uncorrectable: Vec::new(),
        moves: corrected.per_move.clone(),
        timings_s: timings,
    };
    Ok(CorrectOutcome {
        report,
        corrected,
        header,
    })
}

/// The corrected program `cp` (in the place of `program`) cut on `scene`'s machine, its
/// timings recorded under `iteration`.
fn cut_corrected(
    scene: &Scene,
    program: &Program,
    cp: &CorrectedProgram,
    iteration: usize,
    timings: &mut Vec<(String, Real)>,
    progress: &dyn Progress,
) -> Result<super::Part, PipelineError> {
    let as_program = Program {
        path: program.path.clone(),
        moves: cp.moves.clone(),
        axes_used: cp.axes.clone(),
        ended_by: program.ended_by,
    };
    let part = machine_part(scene, &as_program, progress)?;
    timings.extend(
        part.timings
            .iter()
            .map(|(n, t)| (format!("{n} {iteration}"), *t)),
    );
    Ok(part)
}
