//! `twinmill measure --instrument ball-sensor|probe`: a rotary-axis test on the scene's
//! machine — the ISO 10791-6 motion test read by seed 003's ball sensor, or a calibration
//! sphere probed at rotary indices — its per-sweep figures, and the identification of the
//! rotary axes' ISO 230-7 location errors from it through `calibrate`, with what the test
//! cannot determine named.
//!
//! The scene's `chain` is the machine that moves; its `model` (nominal plus the deviations
//! known a priori) is what the controller computes with. The identification's model is the
//! scene's machine with everything but the terms it identifies (deviations, error motions,
//! reversals), those at their known values: the identified values are the location errors
//! *relative to the known values*, with the rest of the machine as the scene has it.

use super::PipelineError;
use crate::calibration::calibrate::{
    IsoTerm, Model, Registration, ball_features, identify as solve,
};
use crate::calibration::goodness::{FitCheck, RankMargin};
use crate::cutting::tool::{Tool, ToolKind};
use crate::machine::chain::Chain;
use crate::math::{Point3, Real, Vector3};
use crate::metrology::ball_sensor::BallSensor;
use crate::metrology::rotary_test::{
    Sample, Setup, Sweep, SweepFigures, default_sweeps, figures, probe_test, sensor_test, trace_csv,
};
use crate::scene::Scene;
use serde::Serialize;
use std::collections::BTreeMap;

/// The instrument of a rotary-axis test.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RotaryInstrument {
    /// Seed 003's sensor on the table, its master ball in the spindle, read `height_mm`
    /// above the sheets of light.
    BallSensor {
        /// The sensor.
        sensor: BallSensor,
        /// The ball's nominal height above the sheets (mm).
        height_mm: Real,
    },
    /// A touch probe finding a sphere's centre, repeatable to `sigma_mm` per axis.
    Probe {
        /// Repeatability (standard deviation per linear axis value, mm).
        sigma_mm: Real,
    },
}

/// Whether an ISO term (or a combination led by one) is a tilt (rad): `E<A|B|C>0…`; else
/// an offset (mm).
pub fn is_angle_term(name: &str) -> bool {
    matches!(name.as_bytes().get(1), Some(b'A' | b'B' | b'C'))
}

/// What to run.
#[derive(Clone, Debug, PartialEq)]
pub struct RotaryRequest {
    /// The instrument.
    pub instrument: RotaryInstrument,
    /// The sweeps; empty: [`default_sweeps`] of the chain.
    pub sweeps: Vec<Sweep>,
    /// Where the balls are and the noise seed.
    pub setup: Setup,
    /// The terms to identify; empty: every rotary axis's location terms
    /// ([`crate::machine::chain::Chain::rotary_location_terms`]); `None`: do not identify.
    pub identify: Option<Vec<String>>,
}

/// One identified term.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TermReport {
    /// ISO name (`EX0C`) or a combination of them.
    pub name: String,
    /// Value (mm or rad).
    pub value: Real,
    /// Standard uncertainty.
    pub sigma: Real,
    /// The value injected into the simulated machine by the scene, when it names this term.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub injected: Option<Real>,
}

/// The identification's account.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct LocationReport {
    /// The terms solved for.
    pub terms: Vec<String>,
    /// Terms identified on their own.
    pub identified: Vec<TermReport>,
    /// Determined combinations of terms that are not single terms.
    pub combinations: Vec<TermReport>,
    /// Directions the test does not determine (named), held at the model's values.
    pub not_determined: Vec<String>,
    /// Terms no measurement depends on at all.
    pub no_data: Vec<String>,
    /// Singular values of the scaled, whitened Jacobian (descending).
    pub singular_values: Vec<Real>,
    /// How clearly the determined subspace was decided: the gap between the last
    /// determined and the first undetermined singular value.
    pub margin: RankMargin,
    /// The table-side point as estimated (workpiece frame, mm) and its uncertainty.
    pub fixed_point_mm: [Real; 3],
    /// Standard uncertainty of each coordinate (mm).
    pub fixed_point_sigma_mm: [Real; 3],
    /// Weighted sum of squared residuals after the solve, and its degrees of freedom.
    pub chi2: Real,
    /// Degrees of freedom.
    pub dof: usize,
    /// Goodness of fit: the ball centres' residuals at the instrument's stated σ, whole
    /// and sample by sample.
    pub fit: FitCheck,
}

impl LocationReport {
    /// The identification as text: each term with its σ (offsets in µm, tilts in µrad)
    /// and the value the scene injects where it names the term, what is not determined,
    /// the fit, the fixed point and the rank's margin.
    pub fn summary(&self) -> String {
        use std::fmt::Write as _;
        let mut s = String::new();
        let _ = writeln!(
            s,
            "identified    location errors (offsets µm, tilts µrad; ± one standard uncertainty):"
        );
        for t in self.identified.iter().chain(&self.combinations) {
            let k = if is_angle_term(&t.name) { 1e6 } else { 1e3 };
            let inj = t.injected.map_or(String::new(), |v| {
                format!("   (scene injects {:+.3})", v * k)
            });
            let _ = writeln!(
                s,
                "  {:<24} {:+10.3} ± {:.3}{inj}",
                t.name,
                t.value * k,
                t.sigma * k
            );
        }
        if !self.not_determined.is_empty() {
            let _ = writeln!(
                s,
                "not determined {} (held at the model's values; a table-side point cannot see them)",
                self.not_determined.join(", ")
            );
        }
        if !self.no_data.is_empty() {
            let _ = writeln!(
                s,
                "no data       {} (no measurement depends on them: add sweeps of their axis)",
                self.no_data.join(", ")
            );
        }
        let _ = writeln!(
            s,
            "fit           {}; the point at ({:.4}, {:.4}, {:.4}) mm",
            self.fit.describe(),
            self.fixed_point_mm[0],
            self.fixed_point_mm[1],
            self.fixed_point_mm[2]
        );
        let _ = writeln!(s, "rank          {}", self.margin.describe());
        s
    }
}

/// The report of a rotary-axis test.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RotaryReport {
    /// Set when the measurements do not fit the model at the instrument's noise and the
    /// misfit was accepted on request: the report's first word.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub warning: Option<String>,
    /// Scene name.
    pub scene: String,
    /// `ball-sensor` or `probe`.
    pub instrument: String,
    /// Number of measurements.
    pub samples: usize,
    /// ISO 10791-6 figures per sweep (for the probe: zero, it finds the sphere instead).
    pub sweeps: Vec<SweepFigures>,
    /// The identification, when asked for.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub identification: Option<LocationReport>,
}

/// Everything a rotary-axis test made.
#[derive(Clone, Debug)]
pub struct RotaryOutcome {
    /// The report.
    pub report: RotaryReport,
    /// The measurements.
    pub samples: Vec<Sample>,
    /// The trace as CSV.
    pub trace_csv: String,
}

/// Runs the test of `req` on `scene`'s machine and identifies the location terms.
pub fn rotary_test(scene: &Scene, req: &RotaryRequest) -> Result<RotaryOutcome, PipelineError> {
    let err = |message: String| PipelineError::Rotary {
        path: scene.path.display().to_string(),
        message,
    };
    let sweeps = if req.sweeps.is_empty() {
        default_sweeps(scene.chain())
    } else {
        req.sweeps.clone()
    };
    if sweeps.is_empty() {
        return Err(err(
            "the machine has no rotary axis: a rotary-axis test needs one".into(),
        ));
    }
    let (samples, instrument) = match req.instrument {
        RotaryInstrument::BallSensor { sensor, height_mm } => (
            sensor_test(
                scene.chain(),
                scene.model(),
                &sensor,
                height_mm,
                &req.setup,
                &sweeps,
            ),
            "ball-sensor",
        ),
        RotaryInstrument::Probe { sigma_mm } => (
            probe_test(scene.chain(), sigma_mm, &req.setup, &sweeps),
            "probe",
        ),
    };
    let samples = samples.map_err(|e| err(e.to_string()))?;
    let identification = match &req.identify {
        None => None,
        Some(names) => Some(identify_location(scene, names, &samples, &req.setup).map_err(err)?),
    };
    let report = RotaryReport {
        warning: identification.as_ref().and_then(|i| i.fit.accepted_line()),
        scene: scene.name.clone(),
        instrument: instrument.into(),
        samples: samples.len(),
        sweeps: figures(&samples),
        identification,
    };
    Ok(RotaryOutcome {
        trace_csv: trace_csv(scene.chain(), &samples, &req.setup, instrument),
        report,
        samples,
    })
}

fn identify_location(
    scene: &Scene,
    names: &[String],
    samples: &[Sample],
    setup: &Setup,
) -> Result<LocationReport, String> {
    identify_location_with(scene, names, samples, setup, &[])
}

/// The location terms `names` (empty: every rotary axis's) identified in one solve from the
/// rotary test's `samples` and the faces `planes` of a part cut on the same machine and
/// scanned (plane features, as `identify` extracts them, e.g. from `design`'s part): the
/// balls with their fixed point, the faces with the scan's registration estimated, both
/// predicted by the one model of the machine. Either may be empty.
pub fn identify_location_with(
    scene: &Scene,
    names: &[String],
    samples: &[Sample],
    setup: &Setup,
    planes: &[crate::calibration::calibrate::Feature],
) -> Result<LocationReport, String> {
    let traces: Vec<(&[Sample], Vector3, &str)> = if samples.is_empty() {
        Vec::new()
    } else {
        vec![(samples, setup.tool_offset, "")]
    };
    Ok(identify_location_traces(scene, names, &traces, planes, "measure")?.0)
}

/// [`identify_location_with`] from any number of traces, each with its spindle-side ball
/// (`tool_offset`), its own fixed point and its file's name (which prefixes its samples' in
/// the fit, so a misfit names the file; empty for one trace of the twin): the report, and
/// the full solved vector of the terms in the report's order (undetermined directions at
/// their start). `what` is the command a refusal names.
fn identify_location_traces(
    scene: &Scene,
    names: &[String],
    traces: &[(&[Sample], Vector3, &str)],
    planes: &[crate::calibration::calibrate::Feature],
    what: &str,
) -> Result<(LocationReport, Vec<Real>), String> {
    let names = if names.is_empty() {
        scene.model().rotary_location_terms()
    } else {
        names.to_vec()
    };
    let terms = names
        .iter()
        .map(|n| IsoTerm::parse(scene.model(), n).map_err(|e| e.to_string()))
        .collect::<Result<Vec<_>, _>>()?;
    let mut features: Vec<_> = traces
        .iter()
        .enumerate()
        .flat_map(|(k, (samples, tool_offset, file))| {
            let mut f = ball_features(samples, *tool_offset, k);
            if !file.is_empty() {
                for b in &mut f {
                    if let crate::calibration::calibrate::Feature::Ball(b) = b {
                        b.name = format!("{file}: {}", b.name);
                    }
                }
            }
            f
        })
        .collect();
    features.extend(planes.iter().cloned());
    // Ball features do not use the tool; plane features use the scene's, which cut them.
    let tool = if planes.is_empty() {
        Tool::try_new(ToolKind::Ball, 1.0, 1.0).map_err(|e| e.to_string())?
    } else {
        scene.tool.clone()
    };
    let chain = test_model(scene, &terms).map_err(|e| e.to_string())?;
    let model = Model {
        chain: &chain,
        ids: &[],
        iso_terms: &terms,
        tool: &tool,
        features: &features,
        // The scan's placement is unknown: estimated (used only by plane features).
        registration: if planes.is_empty() {
            Registration::Workpiece
        } else {
            Registration::Estimate
        },
    };
    let mut r = solve(&model).map_err(|e| format!("identification: {e}"))?;
    r.fit
        .enforce(what, scene.accept_misfit)
        .map_err(|e| e.to_string())?;
    let injected = |n: &str| scene.injected().get(n).copied();
    let term = |e: &crate::calibration::calibrate::Estimate| TermReport {
        name: e.name.clone(),
        value: e.value,
        sigma: e.sigma,
        injected: injected(&e.name),
    };
    let (p, s) = r
        .anchors
        .first()
        .copied()
        .unwrap_or((Point3::origin(), [Real::NAN; 3]));
    let ident = &r.identifiability;
    let report = LocationReport {
        terms: names,
        identified: r.parameters.iter().map(term).collect(),
        combinations: r.combinations.iter().map(term).collect(),
        not_determined: ident
            .undetermined_combinations
            .iter()
            .map(|c| c.name.clone())
            .collect(),
        no_data: ident.no_data.clone(),
        singular_values: ident.singular_values.clone(),
        margin: ident.margin,
        fixed_point_mm: [p.x, p.y, p.z],
        fixed_point_sigma_mm: s,
        chi2: r.solver.chi2,
        dof: r.solver.dof,
        fit: r.fit.clone(),
    };
    Ok((report, r.solution))
}

/// The rotary axes' location terms identified from trace files (as `measure --instrument
/// ball-sensor|probe` writes them) and, when given, a cut part's faces.
#[derive(Clone, Debug)]
pub struct TraceIdentification {
    /// The identification's account.
    pub report: LocationReport,
    /// The trace files, then the part's source when faces were used.
    pub sources: Vec<String>,
    /// How many faces of the part took part.
    pub faces: usize,
    /// The identified machine as a deviations file (`--deviations` reads it).
    pub file: String,
}

/// Reads the trace `files` of `scene`'s machine and identifies the location terms `names`
/// (empty: every rotary axis's) from them and the part's faces `planes` (from
/// `part_source`), in one solve: each trace with its own fixed point, the faces with
/// their scan's registration. A misfit is refused naming the file and sample.
pub fn identify_location_files(
    scene: &Scene,
    names: &[String],
    files: &[std::path::PathBuf],
    planes: &[crate::calibration::calibrate::Feature],
    part_source: Option<&str>,
) -> Result<TraceIdentification, PipelineError> {
    let err = |path: &std::path::Path, message: String| PipelineError::Rotary {
        path: path.display().to_string(),
        message,
    };
    let mut traces = Vec::with_capacity(files.len());
    for f in files {
        let text = crate::scene::read_text(f).map_err(|e| err(f, e.to_string()))?;
        // The reader's errors name the file, line and column themselves.
        let t =
            crate::metrology::rotary_test::parse_trace(&text, f, scene.chain()).map_err(|e| {
                PipelineError::Rotary {
                    path: format!("{}:{}:{}", e.path.display(), e.line, e.column),
                    message: e.message,
                }
            })?;
        traces.push((f.display().to_string(), t));
    }
    if traces.is_empty() && planes.is_empty() {
        return Err(err(
            &scene.path,
            "no trace and no face to identify the location terms from".into(),
        ));
    }
    let inputs: Vec<(&[Sample], Vector3, &str)> = traces
        .iter()
        .map(|(name, t)| (t.samples.as_slice(), t.setup.tool_offset, name.as_str()))
        .collect();
    let (report, solution) = identify_location_traces(scene, names, &inputs, planes, "identify")
        .map_err(|m| err(&scene.path, m))?;
    let mut sources: Vec<String> = traces.iter().map(|(n, _)| n.clone()).collect();
    sources.extend(part_source.map(str::to_string));
    let file =
        location_file(scene, &report, &solution, &sources).map_err(|m| err(&scene.path, m))?;
    Ok(TraceIdentification {
        report,
        sources,
        faces: planes.len(),
        file,
    })
}

/// A solved change below this (mm or rad) is the solver's rounding, not a value: far
/// below any σ of a location term (µm and µrad), far above rounding near zero.
const UNMOVED: Real = 1e-12;

/// The deviations file of a location identification: the scene's `[deviations]` with each
/// solved term at its value (the model's known value plus the solved change; a term the
/// data do not determine on its own is written at that value and said to be not
/// identified), the scene's error motions and reversals unchanged, and the `[identified]`
/// record.
fn location_file(
    scene: &Scene,
    report: &LocationReport,
    solution: &[Real],
    sources: &[String],
) -> Result<String, String> {
    let model = scene.model();
    let terms = report
        .terms
        .iter()
        .map(|n| IsoTerm::parse(model, n).map_err(|e| e.to_string()))
        .collect::<Result<Vec<_>, _>>()?;
    let same = |name: &str, t: &IsoTerm| {
        !name.contains('_')
            && model
                .iso_term_id(name)
                .is_ok_and(|(a, c)| a == t.axis && c == t.component)
    };
    let mut deviations: BTreeMap<String, Real> = scene
        .injected()
        .iter()
        .filter(|(n, _)| !terms.iter().any(|t| same(n, t)))
        .map(|(n, v)| (n.clone(), *v))
        .collect();
    let mut notes = Vec::new();
    for ((name, t), x) in report.terms.iter().zip(&terms).zip(solution) {
        let start = super::identify::iso_value(model, scene.known(), t);
        let identified = report.identified.iter().any(|e| &e.name == name);
        // A direction the data do not determine stays at its start; a term held there
        // (the C table's zero, its offset along itself) is written only if it has a value.
        if identified || x.abs() > UNMOVED || start != 0.0 {
            deviations.insert(name.clone(), start + x);
        }
        let note = match report.identified.iter().find(|e| &e.name == name) {
            Some(e) => format!("{name}: σ {:.3e}", e.sigma),
            None if report.no_data.contains(name) => {
                format!("{name}: no measurement sees it, the model's value kept")
            }
            None => format!("{name}: not determined on its own, not identified"),
        };
        notes.push((name.clone(), note));
    }
    let fragment = crate::calibration::instruments::machine_sections(
        scene.chain(),
        &deviations,
        &notes,
        sources,
    );
    let axes: Vec<String> = scene
        .chain()
        .axes()
        .iter()
        .map(|a| a.letter.as_char().to_string())
        .collect();
    let not_determined: Vec<String> = report
        .terms
        .iter()
        .filter(|n| !report.identified.iter().any(|e| &e.name == *n))
        .cloned()
        .collect();
    let sigma: Vec<(String, Real)> = report
        .identified
        .iter()
        .map(|e| (e.name.clone(), e.sigma))
        .collect();
    Ok(crate::calibration::instruments::identified_file(
        &fragment,
        &crate::calibration::instruments::IdentifiedRecord {
            machine: scene.machine_name(),
            scene: &scene.name,
            axes: &axes,
            sources,
            misfit_accepted: report.fit.misfit_accepted,
            not_determined: &not_determined,
            sigma: &sigma,
        },
    ))
}

/// The chain the identification fits: the scene's machine with everything it has — its
/// error motions and reversals and every deviation `[deviations]` injects — except the
/// `terms` being identified, which start from their values in the scene's model (`[identify]
/// known`, else zero). A term counts as identified under any of its names (`EC0XY`,
/// `EC(0X)Y`). The deviations are applied as a scene applies them: joint deviations first,
/// then ISO terms, each in name order.
fn test_model(
    scene: &Scene,
    terms: &[IsoTerm],
) -> Result<Chain, crate::machine::chain::KinematicsError> {
    let identified = |name: &str| {
        !name.contains('_')
            && scene
                .model()
                .iso_term_id(name)
                .is_ok_and(|(axis, component)| {
                    terms
                        .iter()
                        .any(|t| t.axis == axis && t.component == component)
                })
    };
    let mut deviations: BTreeMap<&str, Real> = scene
        .injected()
        .iter()
        .filter(|(n, _)| !identified(n))
        .map(|(n, v)| (n.as_str(), *v))
        .collect();
    for (n, v) in scene.known().iter().filter(|(n, _)| identified(n)) {
        deviations.insert(n, *v);
    }
    let mut chain = scene.model().nominal().with_error_motions_of(scene.model());
    for iso in [false, true] {
        for (name, v) in deviations.iter().filter(|(n, _)| n.contains('_') != iso) {
            if iso {
                chain.apply_iso_term(name, *v)?;
            } else {
                let id = chain.deviation_id(name)?;
                chain.set_deviation(id, *v);
            }
        }
    }
    Ok(chain)
}

/// The default setup: the table-side point at (60, 0, 30) mm in the workpiece frame (off
/// the rotary lines of the built-in machines, so their offsets and tilts show), mounted
/// exactly, the ball at the tool point.
pub fn default_setup(seed: u64) -> Setup {
    Setup {
        point_w: Point3::new(60.0, 0.0, 30.0),
        mounting_mm: Vector3::zeros(),
        tool_offset: Vector3::zeros(),
        seed,
    }
}
