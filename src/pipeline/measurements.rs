//! Identification of a serial machine from several instruments' files at once: laser
//! interferometer readings, ball-bar traces and rotary-axis traces (ball sensor, probe),
//! each with the set-up its file records, and cut parts' faces, identified together ([`crate::calibration::instruments`] on
//! [`crate::calibration::engine`]), checked against the noise the files state, and written
//! back as the scene's deviation sections.
//!
//! **Invariant:** reads only the files the request names (through [`scene::read_text`]),
//! writes nothing; a misfit is refused naming the file it is blamed on unless the request
//! accepts it.

use crate::calibration::calibrate::{Feature, ball_features};
use crate::calibration::engine::{self, MonteCarlo, Outcome};
use crate::calibration::instruments::{
    self, IdentifiedRecord, MachineParameter, Measurement, Slot, Target, identified_file,
};
use crate::cutting::tool::{Tool, ToolKind};
use crate::machine::chain::Chain;
use crate::math::Real;
use crate::metrology::ballbar::{BallBarSetup, Plane};
use crate::metrology::circular::parse_trace;
use crate::metrology::interferometer::LaserSetup;
use crate::metrology::positioning::parse_readings;
use crate::metrology::table::SETUP_MARKER;
use crate::nc::AxisLetter;
use crate::scene::{self, Scene, SceneError};
use std::path::{Path, PathBuf};

/// What a measurement file is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MeasurementKind {
    /// ISO 230-2 readings of `measure --instrument laser`; the axis, when given, is the
    /// user's word for which axis was measured (it overrides the file's record).
    Laser(Option<AxisLetter>),
    /// An ISO 230-4 trace of `measure --instrument ballbar`; the plane, when given,
    /// overrides the file's record.
    Ballbar(Option<Plane>),
    /// A rotary-axis test's trace of `measure --instrument ball-sensor|probe` (its set-up
    /// record says which): the rotary axes' location terms, with a cut part's faces if given.
    Rotary,
}

impl MeasurementKind {
    /// `laser`, `laser:X`, `ballbar`, `ballbar:XY` (any case).
    pub fn parse(s: &str) -> Result<Self, String> {
        let (kind, rest) = match s.split_once(':') {
            Some((k, r)) => (k, Some(r)),
            None => (s, None),
        };
        match (kind.to_ascii_lowercase().as_str(), rest) {
            ("laser", None) => Ok(Self::Laser(None)),
            ("laser", Some(a)) => {
                let mut c = a.chars();
                match (c.next().map(|c| c.to_ascii_uppercase()), c.next()) {
                    (Some(c), None) => AxisLetter::from_char(c)
                        .map(|l| Self::Laser(Some(l)))
                        .ok_or_else(|| format!("'{s}': '{a}' is not an axis letter")),
                    _ => Err(format!("'{s}': '{a}' is not an axis letter")),
                }
            }
            ("ballbar", None) => Ok(Self::Ballbar(None)),
            ("ball-sensor" | "probe", None) => Ok(Self::Rotary),
            ("ballbar", Some(p)) => Plane::from_name(p)
                .map(|p| Self::Ballbar(Some(p)))
                .ok_or_else(|| format!("'{s}': '{p}' is not a plane (XY, YZ or ZX)")),
            _ => Err(format!(
                "'{s}': the kinds are laser[:AXIS], ballbar[:PLANE], ball-sensor and probe"
            )),
        }
    }
}

impl MeasurementKind {
    /// `[KIND:]FILE` of `--measurement`: `laser:X:run.csv`, `ballbar:run.csv`, `run.csv`
    /// (no kind: [`MeasurementKind::of_file`] decides).
    pub fn parse_spec(spec: &str) -> Result<(Option<Self>, PathBuf), String> {
        let lower = spec.to_ascii_lowercase();
        let Some(kind) = ["laser", "ballbar", "ball-sensor", "probe"]
            .into_iter()
            .find(|k| lower.starts_with(&format!("{k}:")))
        else {
            return Ok((None, PathBuf::from(spec)));
        };
        let rest = &spec[kind.len() + 1..];
        if let Some((qualifier, file)) = rest.split_once(':')
            && !file.is_empty()
            && let Ok(k) = Self::parse(&format!("{kind}:{qualifier}"))
        {
            return Ok((Some(k), PathBuf::from(file)));
        }
        if rest.is_empty() {
            return Err(format!(
                "--measurement '{spec}': expected [KIND:]FILE (KIND laser[:AXIS], ballbar[:PLANE], \
                 ball-sensor or probe)"
            ));
        }
        Ok((Some(Self::parse(kind)?), PathBuf::from(rest)))
    }

    /// What the file at `path` is, from its set-up record (`# set-up: laser …` or
    /// `# set-up: ballbar …`): an error naming the file when it has none, or both.
    pub fn of_file(path: &Path) -> Result<Self, MeasurementsError> {
        let text = scene::read_text(path)?;
        let mut found: Vec<(usize, &str)> = Vec::new();
        for (k, l) in text.lines().enumerate() {
            if let Some(rest) = l.trim().strip_prefix(SETUP_MARKER)
                && let Some(w) = rest.split_whitespace().next()
                && !found.iter().any(|(_, f)| *f == w)
            {
                found.push((k + 1, w));
            }
        }
        match found[..] {
            [(_, "laser")] => Ok(Self::Laser(None)),
            [(_, "ballbar")] => Ok(Self::Ballbar(None)),
            [(_, "ball-sensor" | "probe")] => Ok(Self::Rotary),
            [] => Err(file_error(
                path,
                None,
                "no set-up record (a '# set-up: laser|ballbar|ball-sensor|probe …' line, as \
                 `twinmill measure` writes): give the kind, laser[:AXIS]:FILE, \
                 ballbar[:PLANE]:FILE, ball-sensor:FILE or probe:FILE"
                    .into(),
            )),
            [(line, w)] => Err(file_error(
                path,
                Some(line),
                format!(
                    "the set-up record is of the {w}: `identify --measurement` takes laser \
                     readings, ball-bar traces and ball-sensor or probe traces"
                ),
            )),
            [_, (line, w), ..] => Err(file_error(
                path,
                Some(line),
                format!(
                    "a second set-up record ({w}): the file's kind is ambiguous; give it, \
                     laser[:AXIS]:FILE or ballbar[:PLANE]:FILE"
                ),
            )),
        }
    }
}

/// An identification from measurement files.
#[derive(Clone, Debug, PartialEq)]
pub struct IdentifyRequest {
    /// The files and what each is.
    pub measurements: Vec<(MeasurementKind, PathBuf)>,
    /// The parameters to identify by name (`EXX.polynomial[1]`, `EC(0X)Y`, `reversal.X`,
    /// `dy_AY`); `None`: every one the scene models.
    pub parameters: Option<Vec<String>>,
    /// Take a misfit anyway (the fit check then says so).
    pub accept_misfit: bool,
    /// Cut parts' faces, identified with the files (each in its scan's registration).
    pub parts: Vec<PartFaces>,
    /// Monte-Carlo trials at the solution over the stated noise (none: no trials), with
    /// the scene's `[identify] monte_carlo` seed.
    pub monte_carlo: Option<usize>,
}

/// The faces of one cut part, as its scan gives them.
#[derive(Clone, Debug, PartialEq)]
pub struct PartFaces {
    /// Where they come from (the cloud's file, or the simulated scan of a scene).
    pub source: String,
    /// The plane features.
    pub features: Vec<Feature>,
    /// The tool that cut them.
    pub tool: Tool,
}

/// What the identification gives.
#[derive(Clone, Debug, PartialEq)]
pub struct MeasurementsOutcome {
    /// The engine's outcome: values with σ, what is not determined, the fit.
    pub outcome: Outcome,
    /// The parameters in solve order.
    pub parameters: Vec<String>,
    /// The identified machine as the scene's `[deviations]`, `[error_motions]` and
    /// `[reversal]` sections.
    pub fragment: String,
    /// The deviations file (`--deviations-out`): the fragment and its `[identified]` and
    /// `[identified.sigma]` sections, read back by [`Scene::apply_deviations_file`].
    pub file: String,
    /// The report: values with σ and the scene's values, what is not determined.
    pub report: MeasurementsReport,
}

/// One parameter's value as reported.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ParameterReport {
    /// Its name (or a determined combination's).
    pub name: String,
    /// The identified value.
    pub value: f64,
    /// Its standard uncertainty.
    pub sigma: f64,
    /// The units of value and σ (`mm`, `rad`, `mm/mm^2`).
    pub unit: String,
    /// The value the scene gives it (injected into the twin that the measurements were
    /// simulated on, when they were); none for a combination.
    pub injected: Option<f64>,
    /// Its spread over the Monte-Carlo trials, when they ran (`--monte-carlo`).
    pub monte_carlo_spread: Option<f64>,
}

/// What `identify --measurement` reports.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct MeasurementsReport {
    /// The first line when a misfit was accepted (`--accept-misfit`), else none.
    pub misfit_accepted: Option<String>,
    /// The scene's name.
    pub scene: String,
    /// The machine's name.
    pub machine: String,
    /// The machine's axes, from the workpiece.
    pub axes: Vec<String>,
    /// The measurement files, in the order given.
    pub sources: Vec<String>,
    /// The parameters determined on their own, with σ.
    pub identified: Vec<ParameterReport>,
    /// Determined combinations of parameters not determined on their own.
    pub combinations: Vec<ParameterReport>,
    /// The parameters the measurements do not determine on their own: no value is reported.
    pub not_determined: Vec<String>,
    /// Of those, the ones no measurement sees at all.
    pub no_data: Vec<String>,
    /// The goodness of fit, in one line.
    pub fit: String,
    /// The whitened, magnitude-scaled Jacobian's singular values.
    pub singular_values: Vec<f64>,
    /// Its condition number.
    pub condition_number: f64,
    /// Monte-Carlo trials run at the solution over the stated noise (0: none).
    pub monte_carlo_trials: usize,
}

impl MeasurementsReport {
    /// The summary printed by `identify --measurement` (the accepted misfit first).
    pub fn summary(&self) -> String {
        use std::fmt::Write as _;
        let mut s = String::new();
        if let Some(l) = &self.misfit_accepted {
            let _ = writeln!(s, "{l}");
        }
        let _ = writeln!(
            s,
            "twinmill identify: {} ({}, axes {}) from {} measurement files",
            self.scene,
            self.machine,
            self.axes.join(" "),
            self.sources.len()
        );
        for f in &self.sources {
            let _ = writeln!(s, "  measurement   {f}");
        }
        let line = |e: &ParameterReport| {
            let mut t = format!("{:+.6e} ± {:.2e} {}", e.value, e.sigma, e.unit);
            if let Some(i) = e.injected {
                let _ = write!(t, " [injected {i:+.6e}]");
            }
            if let Some(m) = e.monte_carlo_spread {
                let _ = write!(t, " (Monte Carlo ±{m:.2e})");
            }
            t
        };
        for e in &self.identified {
            let _ = writeln!(s, "  identified    {:<28} {}", e.name, line(e));
        }
        for e in &self.combinations {
            let _ = writeln!(s, "  combination   {:<28} {}", e.name, line(e));
        }
        for n in &self.not_determined {
            let why = if self.no_data.contains(n) {
                "no measurement sees it"
            } else {
                "not determined on its own"
            };
            let _ = writeln!(s, "  not determined {n} ({why})");
        }
        let _ = writeln!(s, "  fit           {}", self.fit);
        if self.monte_carlo_trials > 0 {
            let _ = writeln!(
                s,
                "  monte carlo   {} trials at the solution over the files' stated noise",
                self.monte_carlo_trials
            );
        }
        let _ = writeln!(
            s,
            "  jacobian      condition {:.3e}; singular values {}",
            self.condition_number,
            self.singular_values
                .iter()
                .map(|v| format!("{v:.3e}"))
                .collect::<Vec<_>>()
                .join(" ")
        );
        s
    }
}

/// Why an identification from files failed.
#[derive(Debug, thiserror::Error)]
pub enum MeasurementsError {
    /// A file cannot be read.
    #[error(transparent)]
    Scene(#[from] SceneError),
    /// A file's content cannot be used (its line when known).
    #[error("{}{}: {message}", path.display(), line.map_or(String::new(), |l| format!(":{l}")))]
    File {
        /// The file.
        path: PathBuf,
        /// The line.
        line: Option<usize>,
        /// What is wrong.
        message: String,
    },
    /// A parameter the machine does not have.
    #[error("{}: --parameter {message}", path.display())]
    Parameter {
        /// The scene.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// The identification itself failed (the message names the file where one is at fault).
    #[error("{0}")]
    Identify(String),
    /// The data do not fit the model at the stated noise.
    #[error("{0}")]
    Misfit(String),
}

fn file_error(path: &Path, line: Option<usize>, message: String) -> MeasurementsError {
    MeasurementsError::File {
        path: path.to_path_buf(),
        line,
        message,
    }
}

/// Reads one file as `kind` (a rotary-axis trace names the axes of `chain`).
pub fn read_measurement(
    kind: MeasurementKind,
    path: &Path,
    chain: &Chain,
) -> Result<Measurement, MeasurementsError> {
    let text = scene::read_text(path)?;
    let name = path.display().to_string();
    let no_record = |what: &str| {
        file_error(
            path,
            None,
            format!(
                "no set-up record (a '# set-up: {what} …' line, as `twinmill measure` writes): \
                 the identification cannot model the test without it"
            ),
        )
    };
    match kind {
        MeasurementKind::Laser(axis) => {
            let readings = parse_readings(&text, path)
                .map_err(|e| file_error(path, None, format!("not laser readings: {e}")))?;
            let mut setup: LaserSetup = LaserSetup::from_record(&text, &readings)
                .ok_or_else(|| no_record("laser"))?
                .map_err(|(l, m)| file_error(path, Some(l), m))?;
            if let Some(a) = axis {
                setup.axis = a;
            }
            Ok(Measurement::Laser {
                name,
                setup,
                readings,
            })
        }
        MeasurementKind::Ballbar(plane) => {
            let samples = parse_trace(&text, path)
                .map_err(|e| file_error(path, None, format!("not a ball-bar trace: {e}")))?;
            let mut setup: BallBarSetup = BallBarSetup::from_record(&text)
                .ok_or_else(|| no_record("ballbar"))?
                .map_err(|(l, m)| file_error(path, Some(l), m))?;
            if let Some(p) = plane {
                setup.plane = p;
            }
            Ok(Measurement::BallBar {
                name,
                setup,
                samples,
            })
        }
        MeasurementKind::Rotary => {
            // The reader's errors name the line and column themselves.
            let t =
                crate::metrology::rotary_test::parse_trace(&text, path, chain).map_err(|e| {
                    MeasurementsError::File {
                        path: e.path.clone(),
                        line: Some(e.line),
                        message: format!("column {}: {}", e.column, e.message),
                    }
                })?;
            Ok(Measurement::Features {
                features: ball_features(&t.samples, t.setup.tool_offset, 0),
                name,
                // Ball centres do not use the tool.
                tool: Tool::try_new(ToolKind::Ball, 1.0, 1.0)
                    .map_err(|e| file_error(path, None, e.to_string()))?,
            })
        }
    }
}

/// Identifies the scene's machine from the request's files (see the module documentation).
pub fn identify_measurements(
    scene: &Scene,
    request: &IdentifyRequest,
) -> Result<MeasurementsOutcome, MeasurementsError> {
    if request.measurements.is_empty() && request.parts.is_empty() {
        return Err(MeasurementsError::Identify(
            "no measurement file given".into(),
        ));
    }
    let chain = scene.chain();
    let mut measurements = request
        .measurements
        .iter()
        .map(|(k, p)| read_measurement(*k, p, chain))
        .collect::<Result<Vec<_>, _>>()?;
    measurements.extend(request.parts.iter().map(|p| Measurement::Features {
        name: p.source.clone(),
        features: p.features.clone(),
        tool: p.tool.clone(),
    }));
    // Ball centres and faces see the rotary axes' location: their terms join the scene's
    // own parameters unless the request names them.
    let located = request
        .measurements
        .iter()
        .any(|(k, _)| *k == MeasurementKind::Rotary)
        || !request.parts.is_empty();
    let params: Vec<MachineParameter> = match &request.parameters {
        Some(names) => names
            .iter()
            .map(|n| MachineParameter::parse(chain, scene.injected(), n))
            .collect::<Result<_, _>>(),
        None => instruments::scene_parameters(chain, scene.injected()).and_then(|mut ps| {
            if located {
                for n in scene.model().rotary_location_terms() {
                    let p = MachineParameter::parse(chain, scene.injected(), &n)?;
                    let same = |q: &MachineParameter| {
                        q.name == n
                            || q.target == Target::Iso
                                && chain.iso_term_id(&q.name).ok() == chain.iso_term_id(&n).ok()
                    };
                    if !ps.iter().any(same) {
                        ps.push(p);
                    }
                }
            }
            Ok(ps)
        }),
    }
    .map_err(|message| MeasurementsError::Parameter {
        path: scene.path.clone(),
        message,
    })?;
    let parameters = params.iter().map(|p| p.name.clone()).collect();
    let (model, mut outcome) =
        instruments::identify(chain, params, measurements).map_err(MeasurementsError::Identify)?;
    outcome
        .fit
        .enforce("identify", request.accept_misfit)
        .map_err(|m| MeasurementsError::Misfit(m.0))?;
    let sources: Vec<String> = request
        .measurements
        .iter()
        .map(|(_, p)| p.display().to_string())
        .chain(request.parts.iter().map(|p| p.source.clone()))
        .collect();
    let fragment = instruments::fragment(&model, scene.injected(), &outcome, &sources)
        .map_err(MeasurementsError::Identify)?;
    let monte_carlo = match request.monte_carlo {
        Some(trials) if trials > 0 => Some(
            engine::monte_carlo(&model.problem(), &outcome, trials, scene.monte_carlo_seed)
                .map_err(|e| MeasurementsError::Identify(e.to_string()))?,
        ),
        _ => None,
    };
    let report = report_of(
        scene,
        model.parameters(),
        &outcome,
        &sources,
        monte_carlo.as_ref(),
    );
    let file = deviations_file(&fragment, &report, &outcome);
    Ok(MeasurementsOutcome {
        outcome,
        parameters,
        fragment,
        file,
        report,
    })
}

/// The units of a parameter's value.
fn unit_of(chain: &Chain, p: &MachineParameter) -> String {
    let angle = |a: bool| if a { "rad" } else { "mm" };
    match &p.target {
        Target::Deviation(id) => angle(id.component.is_angle()).into(),
        Target::Iso => angle(chain.iso_term_id(&p.name).is_ok_and(|(_, c)| c.is_angle())).into(),
        Target::Motion {
            component, slot, ..
        } => match slot {
            Slot::Polynomial(0) | Slot::Table(_) | Slot::Periodic(_) => {
                angle(component.is_angle()).into()
            }
            Slot::Polynomial(1) => format!("{}/mm", angle(component.is_angle())),
            Slot::Polynomial(k) => format!("{}/mm^{k}", angle(component.is_angle())),
        },
        Target::Reversal(_) => "mm".into(),
    }
}

/// The report of an identification: values only for what is determined.
fn report_of(
    scene: &Scene,
    params: &[MachineParameter],
    outcome: &Outcome,
    sources: &[String],
    monte_carlo: Option<&MonteCarlo>,
) -> MeasurementsReport {
    let chain = scene.chain();
    let identified: Vec<ParameterReport> = outcome
        .parameters
        .iter()
        .map(|e| {
            let p = params.iter().find(|p| p.name == e.name);
            ParameterReport {
                name: e.name.clone(),
                value: e.value,
                sigma: e.sigma,
                unit: p.map_or_else(String::new, |p| unit_of(chain, p)),
                injected: p.map(|p| p.start),
                monte_carlo_spread: monte_carlo
                    .and_then(|m| m.spread.iter().find(|(n, _)| *n == e.name).map(|(_, v)| *v)),
            }
        })
        .collect();
    let combinations = outcome
        .combinations
        .iter()
        .map(|e| ParameterReport {
            name: e.name.clone(),
            value: e.value,
            sigma: e.sigma,
            unit: String::new(),
            injected: None,
            monte_carlo_spread: None,
        })
        .collect();
    let not_determined: Vec<String> = params
        .iter()
        .filter(|p| !identified.iter().any(|e| e.name == p.name))
        .map(|p| p.name.clone())
        .collect();
    let no_data = not_determined
        .iter()
        .filter(|n| outcome.identifiability.no_data.contains(n))
        .cloned()
        .collect();
    MeasurementsReport {
        misfit_accepted: outcome.fit.accepted_line(),
        scene: scene.name.clone(),
        machine: scene.machine_name().to_string(),
        axes: chain
            .axes()
            .iter()
            .map(|a| a.letter.as_char().to_string())
            .collect(),
        sources: sources.to_vec(),
        identified,
        combinations,
        not_determined,
        no_data,
        fit: outcome.fit.describe(),
        singular_values: outcome.identifiability.singular_values.clone(),
        condition_number: outcome.identifiability.condition_number,
        monte_carlo_trials: monte_carlo.map_or(0, |m| m.trials),
    }
}

/// The deviations file: the fragment, then `[identified]` and `[identified.sigma]`.
fn deviations_file(fragment: &str, report: &MeasurementsReport, outcome: &Outcome) -> String {
    let sigma: Vec<(String, Real)> = report
        .identified
        .iter()
        .map(|e| (e.name.clone(), e.sigma))
        .collect();
    identified_file(
        fragment,
        &IdentifiedRecord {
            machine: &report.machine,
            scene: &report.scene,
            axes: &report.axes,
            sources: &report.sources,
            misfit_accepted: outcome.fit.misfit_accepted,
            not_determined: &report.not_determined,
            sigma: &sigma,
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrology::ballbar;
    use crate::metrology::interferometer::{self, Targets};
    use crate::nc::AxisValues;

    const NOISE_UM: f64 = 0.5;

    /// The scene's text with its deviation sections replaced by `fragment`.
    fn with_sections(scene_text: &str, fragment: &str) -> String {
        let mut out = String::new();
        let mut skip = false;
        for line in scene_text.lines() {
            let t = line.trim();
            if t.starts_with('[') && !t.starts_with("[[") {
                skip = matches!(t, "[deviations]" | "[error_motions]" | "[reversal]");
            }
            if !skip {
                out.push_str(line);
                out.push('\n');
            }
        }
        out.push('\n');
        out.push_str(fragment);
        out
    }

    /// The measurements of the volumetric set on `chain`, as `measure` writes them.
    fn files(chain: &crate::machine::chain::Chain, dir: &Path) -> Vec<(MeasurementKind, PathBuf)> {
        let mut out = Vec::new();
        for (k, axis) in [AxisLetter::X, AxisLetter::Y, AxisLetter::Z]
            .into_iter()
            .enumerate()
        {
            let mut s = LaserSetup::new(
                axis,
                Targets::Even {
                    start_mm: 0.0,
                    end_mm: 60.0,
                    count: 7,
                },
                AxisValues::default().with(AxisLetter::Z, 50.0),
            );
            s.noise_um = NOISE_UM;
            s.seed = 10 + k as u64;
            let m = interferometer::measure(chain, &s).expect("measures");
            let p = dir.join(format!("laser-{}.csv", axis.as_char()));
            std::fs::write(&p, m.csv(&[])).expect("writes");
            out.push((MeasurementKind::Laser(None), p));
        }
        for (k, plane) in [Plane::Xy, Plane::Yz, Plane::Zx].into_iter().enumerate() {
            let centre = AxisValues::default()
                .with(AxisLetter::X, 30.0)
                .with(AxisLetter::Y, 20.0)
                .with(AxisLetter::Z, 50.0);
            let mut s = BallBarSetup::new(plane, centre, 20.0);
            s.noise_um = NOISE_UM;
            s.seed = 20 + k as u64;
            s.mount_offset_mm = crate::math::Vector3::new(0.005, -0.004, 0.0);
            let m = ballbar::measure(chain, &s).expect("measures");
            let p = dir.join(format!("ballbar-{}.csv", plane.name()));
            std::fs::write(&p, m.csv(&[])).expect("writes");
            out.push((MeasurementKind::Ballbar(None), p));
        }
        out
    }

    fn scene_path() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/xyz-error-motions.toml")
    }

    #[test]
    fn the_identified_fragment_pasted_into_the_scene_resimulates_the_measurements_within_noise() {
        let path = scene_path();
        let text = std::fs::read_to_string(&path).expect("scene");
        let truth = Scene::parse(&text, &path).expect("loads");
        let dir =
            std::env::temp_dir().join(format!("twinmill-measurements-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        let measured = files(truth.chain(), &dir);
        // The twin before: the scene's terms at zero, the squareness forgotten, the pitch
        // (which no set-up here sees) known.
        let start_text = with_sections(
            &text,
            "[deviations]\n\"EC(0X)Y\" = 0.0\n[error_motions]\nEXX = { polynomial = [0.0, 0.0] }\n\
             EYX = { periodic = [{ amplitude = 0.0, period = 5.0 }] }\n\
             EBX = { table = { q = [0, 30, 60], values = [0.0, 20e-6, 0.0] } }\n\
             EZY = { polynomial = [0.0, 0.0, 0.0] }\n",
        );
        let start = Scene::parse(&start_text, &path).expect("start scene loads");
        let request = IdentifyRequest {
            measurements: measured.clone(),
            parameters: Some(
                [
                    "EC(0X)Y",
                    "EXX.polynomial[1]",
                    "EYX.periodic[0]",
                    "EZY.polynomial[2]",
                    "reversal.X",
                    "reversal.Y",
                ]
                .map(String::from)
                .to_vec(),
            ),
            accept_misfit: false,
            parts: Vec::new(),
            monte_carlo: None,
        };
        let o = identify_measurements(&start, &request).expect("identifies");
        // The fragment in the scene: the same measurements again, noise free, differ from the
        // files by the noise alone (χ² per value near 1, nowhere beyond 5σ).
        let refit =
            Scene::parse(&with_sections(&text, &o.fragment), &path).expect("fragment loads");
        let sigma = NOISE_UM * 1e-3;
        let (mut chi2, mut n) = (0.0, 0usize);
        for (kind, p) in &measured {
            let m = read_measurement(*kind, p, refit.chain()).expect("reads");
            let (sim, got): (Vec<f64>, Vec<f64>) = match m {
                Measurement::Laser {
                    setup, readings, ..
                } => {
                    let s = LaserSetup {
                        noise_um: 0.0,
                        ..setup
                    };
                    let r = interferometer::measure(refit.chain(), &s).expect("measures");
                    (
                        r.readings.iter().map(|x| x.deviation_mm).collect(),
                        readings.iter().map(|x| x.deviation_mm).collect(),
                    )
                }
                Measurement::BallBar { setup, samples, .. } => {
                    let s = BallBarSetup {
                        noise_um: 0.0,
                        mount_offset_mm: crate::math::Vector3::new(0.005, -0.004, 0.0),
                        ..setup
                    };
                    let r = ballbar::measure(refit.chain(), &s).expect("measures");
                    (
                        r.samples.iter().map(|x| x.deviation_mm).collect(),
                        samples.iter().map(|x| x.deviation_mm).collect(),
                    )
                }
                other => panic!("{}: not a laser or ball-bar file", other.name()),
            };
            for (a, b) in sim.iter().zip(&got) {
                assert!((a - b).abs() < 5.0 * sigma, "{}: {a} vs {b}", p.display());
                chi2 += ((a - b) / sigma).powi(2);
                n += 1;
            }
        }
        let per = chi2 / n as f64;
        assert!((0.7..1.3).contains(&per), "χ²/n {per}");
        // The fragment states σ for what it identified.
        assert!(o.fragment.contains("EC(0X)Y: σ"), "{}", o.fragment);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_file_of_the_wrong_kind_and_a_parameter_the_machine_lacks_are_refused_by_name() {
        let path = scene_path();
        let scene = Scene::load(&path).expect("loads");
        let dir =
            std::env::temp_dir().join(format!("twinmill-measurements-bad-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        let measured = files(scene.chain(), &dir);
        let laser = measured[0].1.clone();
        let e = read_measurement(MeasurementKind::Ballbar(None), &laser, scene.chain())
            .expect_err("refused");
        assert!(e.to_string().contains("laser-X.csv"), "{e}");
        let request = IdentifyRequest {
            measurements: measured,
            parameters: Some(vec!["EAA.polynomial[1]".into()]),
            accept_misfit: false,
            parts: Vec::new(),
            monte_carlo: None,
        };
        let e = identify_measurements(&scene, &request).expect_err("refused");
        assert!(e.to_string().contains("axis A"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
