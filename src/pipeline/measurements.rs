//! Identification of a serial machine from several instruments' files at once: laser
//! interferometer readings and ball-bar traces, each with the set-up its file records,
//! identified together ([`crate::calibration::instruments`] on
//! [`crate::calibration::engine`]), checked against the noise the files state, and written
//! back as the scene's deviation sections.
//!
//! **Invariant:** reads only the files the request names (through [`scene::read_text`]),
//! writes nothing; a misfit is refused naming the file it is blamed on unless the request
//! accepts it.

use crate::calibration::engine::Outcome;
use crate::calibration::instruments::{self, MachineParameter, Measurement};
use crate::metrology::ballbar::{BallBarSetup, Plane};
use crate::metrology::circular::parse_trace;
use crate::metrology::interferometer::LaserSetup;
use crate::metrology::positioning::parse_readings;
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
            ("ballbar", Some(p)) => Plane::from_name(p)
                .map(|p| Self::Ballbar(Some(p)))
                .ok_or_else(|| format!("'{s}': '{p}' is not a plane (XY, YZ or ZX)")),
            _ => Err(format!(
                "'{s}': the kinds are laser[:AXIS] and ballbar[:PLANE]"
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

/// Reads one file as `kind`.
pub fn read_measurement(
    kind: MeasurementKind,
    path: &Path,
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
    }
}

/// Identifies the scene's machine from the request's files (see the module documentation).
pub fn identify_measurements(
    scene: &Scene,
    request: &IdentifyRequest,
) -> Result<MeasurementsOutcome, MeasurementsError> {
    if request.measurements.is_empty() {
        return Err(MeasurementsError::Identify(
            "no measurement file given".into(),
        ));
    }
    let measurements = request
        .measurements
        .iter()
        .map(|(k, p)| read_measurement(*k, p))
        .collect::<Result<Vec<_>, _>>()?;
    let chain = scene.chain();
    let params: Vec<MachineParameter> = match &request.parameters {
        Some(names) => names
            .iter()
            .map(|n| MachineParameter::parse(chain, scene.injected(), n))
            .collect::<Result<_, _>>(),
        None => instruments::scene_parameters(chain, scene.injected()),
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
        .collect();
    let fragment = instruments::fragment(&model, scene.injected(), &outcome, &sources)
        .map_err(MeasurementsError::Identify)?;
    Ok(MeasurementsOutcome {
        outcome,
        parameters,
        fragment,
    })
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
        };
        let o = identify_measurements(&start, &request).expect("identifies");
        // The fragment in the scene: the same measurements again, noise free, differ from the
        // files by the noise alone (χ² per value near 1, nowhere beyond 5σ).
        let refit =
            Scene::parse(&with_sections(&text, &o.fragment), &path).expect("fragment loads");
        let sigma = NOISE_UM * 1e-3;
        let (mut chi2, mut n) = (0.0, 0usize);
        for (kind, p) in &measured {
            let m = read_measurement(*kind, p).expect("reads");
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
        let e = read_measurement(MeasurementKind::Ballbar(None), &laser).expect_err("refused");
        assert!(e.to_string().contains("laser-X.csv"), "{e}");
        let request = IdentifyRequest {
            measurements: measured,
            parameters: Some(vec!["EAA.polynomial[1]".into()]),
            accept_misfit: false,
        };
        let e = identify_measurements(&scene, &request).expect_err("refused");
        assert!(e.to_string().contains("axis A"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
