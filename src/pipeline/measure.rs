//! `twinmill measure`: a virtual instrument on a scene's deviated machine — the laser
//! interferometer's ISO 230-2 test cycle, the ball bar's ISO 230-4 circles (a serial chain's
//! telescoping bar, or a hexapod's double ball bar), seed 003's ball sensor and the touch
//! probe on the rotary axes — evaluated as its standard says. The request is plain values
//! (options not given are `None`); the outcome is the readings file's text, the page, the
//! plot and the summary, ready to write and print. Reads the scene; writes nothing.

use super::dbb::{BallbarOutcome, ballbar as dbb_ballbar};
use super::evaluate::{circular_summary, plot_bytes, positioning_summary};
use crate::math::{Real, Vector3};
use crate::metrology::ballbar::Turns;
use crate::metrology::circular::{CircularOptions, TraceError, evaluate as evaluate_circular};
use crate::metrology::hexapod_dbb::{DbbCircle, DbbInstrument, DbbPlane};
use crate::metrology::positioning::evaluate as evaluate_positioning;
use crate::nc::AxisLetter;
use crate::report::html::render_page;
use crate::report::pages;
use crate::scene::HexapodScene;
use crate::scene::{MemoryBudget, Scene, SceneError};
use std::path::{Path, PathBuf};

/// The instruments of `measure`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MeasureInstrument {
    /// Laser interferometer: ISO 230-2's test cycle of one linear axis.
    Laser,
    /// Ball bar: ISO 230-4's circular test (a hexapod's double ball bar).
    Ballbar,
    /// Seed 003's non-contact ball sensor on the rotary axes.
    BallSensor,
    /// A touch probe finding a calibration sphere at rotary indices.
    Probe,
}

impl MeasureInstrument {
    /// The name in messages and file names.
    pub fn name(self) -> &'static str {
        match self {
            MeasureInstrument::Laser => "laser",
            MeasureInstrument::Ballbar => "ballbar",
            MeasureInstrument::BallSensor => "ball-sensor",
            MeasureInstrument::Probe => "probe",
        }
    }
}

/// The laser interferometer's options.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LaserOptions {
    /// The linear axis measured (a letter).
    pub axis: Option<String>,
    /// First target (mm).
    pub from: Option<Real>,
    /// Last target (mm).
    pub to: Option<Real>,
    /// Number of evenly spaced targets.
    pub targets: Option<usize>,
    /// The targets as a list (mm).
    pub target_list: Option<Vec<Real>>,
    /// Bidirectional runs.
    pub runs: Option<usize>,
    /// The retroreflector's offset DX,DY,DZ from the tool point (mm).
    pub abbe: Option<Vec<Real>>,
    /// Linear drift of the readings (µm per run).
    pub drift: Option<Real>,
    /// The other axes' values `AXIS=VALUE,…`.
    pub at: Option<String>,
    /// A LinuxCNC compensation file (`COMP_FILE_TYPE = 1`) the controller applies to the
    /// measured axis.
    pub comp: Option<PathBuf>,
}

/// The ball bar's options (a serial machine's; the hexapod's where said).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BallbarOptions {
    /// The plane's name: XY, YZ or ZX.
    pub plane: Option<String>,
    /// The centre: `AXIS=VALUE,…` (serial) or `X,Y,Z` (hexapod, mm).
    pub centre: Option<String>,
    /// The bar's nominal length (mm).
    pub radius: Option<Real>,
    /// The directions run.
    pub direction: Option<Turns>,
    /// The programmed feed (mm/min).
    pub feed: Option<Real>,
    /// Samples per revolution.
    pub points: Option<usize>,
    /// The tool ball's offset DX,DY,DZ from the tool point (mm).
    pub tool_ball: Option<Vec<Real>>,
    /// The centre (table) ball's mounting offset DX,DY,DZ (mm).
    pub mount: Option<Vec<Real>>,
    /// Screw lead for the cyclic-error terms (mm).
    pub pitch: Option<Real>,
    /// Hexapod: the bar's elevation out of the plane (degrees).
    pub tilt: Option<Real>,
    /// Hexapod: the platform's orientation A,B,C during the circle (degrees).
    pub orientation: Option<Vec<Real>>,
    /// Hexapod: the platform's swing along the bar (degrees).
    pub swing: Option<Real>,
}

/// The rotary-axis tests' options.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RotaryOptions {
    /// The sweeps `AXIS:FROM:TO:N…`.
    pub sweep: Vec<String>,
    /// The table-side point X,Y,Z (mm).
    pub point: Option<Vec<Real>>,
    /// The sensor's or sphere's mounting error DX,DY,DZ (mm).
    pub mounting: Option<Vec<Real>>,
    /// The spindle-side ball's offset DX,DY,DZ (mm).
    pub stylus: Option<Vec<Real>>,
    /// Ball sensor: the ball's height above the sheets (mm).
    pub height: Option<Real>,
    /// Ball sensor: the width of each light band (mm).
    pub band: Option<Real>,
    /// The terms to identify.
    pub identify: Option<Vec<String>>,
    /// Only measure.
    pub no_identify: bool,
}

/// What to measure, and how.
#[derive(Clone, Debug, PartialEq)]
pub struct MeasureRequest {
    /// The scene file; only its machine is used.
    pub scene: PathBuf,
    /// The instrument.
    pub instrument: MeasureInstrument,
    /// The readings or trace file (default `<scene name>-<instrument>.csv`).
    pub out: Option<PathBuf>,
    /// The plot's file, if one is asked for.
    pub png: Option<PathBuf>,
    /// The page's file (default: the readings file's name with `.html`).
    pub html: Option<PathBuf>,
    /// Seed of the noise.
    pub seed: u64,
    /// Noise σ or accuracy bound (µm); `None`: the instrument's default.
    pub noise_um: Option<Real>,
    /// Laser: overshoot (mm); ball bar: feed-in and feed-out arcs (degrees).
    pub overshoot: Option<Real>,
    /// The laser's options.
    pub laser: LaserOptions,
    /// The ball bar's options.
    pub ballbar: BallbarOptions,
    /// The rotary tests' options.
    pub rotary: RotaryOptions,
    /// Keep an identification whose residuals the stated noise cannot explain (its report
    /// then says so first) instead of refusing it.
    pub accept_misfit: bool,
    /// An identified machine's deviations file replacing the scene's deviation model
    /// ([`Scene::apply_deviations_file`]); serial machines only.
    pub deviations: Option<PathBuf>,
    /// A hexapod controller's calibrated parameters (a `[controller]` file,
    /// [`HexapodScene::apply_controller_file`]) the circle is run with; hexapods only.
    pub controller: Option<PathBuf>,
}

/// What an instrument measured, evaluated and ready to write (in this order: the readings,
/// the page, the plot) and print.
#[derive(Clone, Debug)]
pub struct Measured {
    /// The readings or trace file and its text.
    pub file: PathBuf,
    /// The readings or trace file's text.
    pub text: String,
    /// The page's file.
    pub html_file: PathBuf,
    /// The page.
    pub html: String,
    /// The plot's file and PNG bytes, when asked for.
    pub png: Option<(PathBuf, Vec<u8>)>,
    /// The summary.
    pub summary: String,
    /// The figures as `evaluate --json` prints them.
    pub json: String,
}

/// What one instrument made before the files are named.
struct Reading {
    text: String,
    plot: Option<Result<image::RgbImage, crate::report::render::RenderError>>,
    summary: String,
    json: Result<String, serde_json::Error>,
    html: String,
}

/// `measure`: loads the scene's machine (serial or hexapod), runs the instrument on it,
/// evaluates what it measured, and names the files. Checks everything before anything could
/// be written: the caller writes [`Measured`] whole.
pub fn measure(r: &MeasureRequest) -> Result<Measured, String> {
    // Only the machine is used: the program is not read and no stock is built, so the
    // stock's memory budget does not apply.
    let budget = MemoryBudget {
        bytes: f64::INFINITY,
        source: "measure builds no stock".into(),
    };
    let default_file = |name: &str| {
        r.out
            .clone()
            .unwrap_or_else(|| PathBuf::from(format!("{name}-{}.csv", r.instrument.name())))
    };
    let (file, m) = match Scene::load_with(&r.scene, &budget) {
        Err(SceneError::Hexapod { path }) => {
            if let Some(d) = &r.deviations {
                return Err(format!(
                    "{}: --deviations replaces a serial machine's deviations; {} is a hexapod \
                     scene",
                    d.display(),
                    path.display()
                ));
            }
            if r.instrument != MeasureInstrument::Ballbar {
                return Err(format!(
                    "{}: --instrument {} does not apply to a hexapod (its struts are not \
                     axes one can sweep one at a time): a hexapod is measured with \
                     --instrument ballbar, the double ball bar",
                    path.display(),
                    r.instrument.name()
                ));
            }
            refuse_given(
                &[
                    ("--overshoot", r.overshoot.is_some()),
                    ("--feed", r.ballbar.feed.is_some()),
                    ("--tool-ball", r.ballbar.tool_ball.is_some()),
                    ("--pitch", r.ballbar.pitch.is_some()),
                ],
                "a serial machine's ball bar, not of a hexapod's double ball bar",
            )?;
            let request = DbbRequest::of_measure(r)?;
            let mut scene = HexapodScene::load(&r.scene).map_err(|e| e.to_string())?;
            if let Some(c) = &r.controller {
                scene.apply_controller_file(c).map_err(|e| e.to_string())?;
            }
            let file = default_file(&scene.name);
            let o = hexapod_ballbar(&scene, &request)?;
            let reading = Reading {
                html: super::instrument_pages::hexapod_ballbar_page(&scene.name, &o),
                text: o.csv.clone(),
                plot: None,
                json: serde_json::to_string_pretty(&o),
                summary: o.summary.clone(),
            };
            let png = r.png.clone().map(|p| (p, o.png));
            return named(r, file, reading, png);
        }
        Err(e) => return Err(e.to_string()),
        Ok(scene) => {
            let mut scene = Scene {
                accept_misfit: r.accept_misfit,
                ..scene
            };
            if let Some(c) = &r.controller {
                return Err(format!(
                    "{}: --controller gives a hexapod controller's calibrated parameters; {} is a serial machine (its identified deviations go with --deviations)",
                    c.display(),
                    r.scene.display()
                ));
            }
            if let Some(d) = &r.deviations {
                scene.apply_deviations_file(d).map_err(|e| e.to_string())?;
            }
            scene.require("measure", &[]).map_err(|e| e.to_string())?;
            refuse_given(
                &[
                    ("--tilt", r.ballbar.tilt.is_some()),
                    ("--orientation", r.ballbar.orientation.is_some()),
                    ("--swing", r.ballbar.swing.is_some()),
                ],
                "a hexapod's double ball bar, not of a serial machine's ball bar",
            )?;
            let file = default_file(&scene.name);
            let m = match r.instrument {
                MeasureInstrument::Laser => measure_laser(&scene, r, &file),
                MeasureInstrument::Ballbar => measure_ballbar(&scene, r, &file),
                MeasureInstrument::BallSensor | MeasureInstrument::Probe => {
                    measure_rotary(&scene, r)
                }
            }?;
            (file, m)
        }
    };
    let png = match (&r.png, m.plot) {
        (Some(png), Some(drawn)) => Some(plot_bytes(png, drawn)?),
        _ => None,
    };
    let reading = Reading { plot: None, ..m };
    named(r, file, reading, png)
}

/// The first option of `given` that was given, refused as an option of `whose`.
fn refuse_given(given: &[(&str, bool)], whose: &str) -> Result<(), String> {
    match given.iter().find(|(_, g)| *g) {
        Some((option, _)) => Err(format!("{option} is an option of {whose}")),
        None => Ok(()),
    }
}

/// Names the page beside the readings file and checks it does not overwrite them.
fn named(
    r: &MeasureRequest,
    file: PathBuf,
    m: Reading,
    png: Option<(PathBuf, Vec<u8>)>,
) -> Result<Measured, String> {
    let html_file = r
        .html
        .clone()
        .unwrap_or_else(|| file.with_extension("html"));
    if html_file == file {
        return Err(format!(
            "{}: the page would overwrite the readings file: give --out or --html another name",
            html_file.display()
        ));
    }
    Ok(Measured {
        file,
        text: m.text,
        html_file,
        html: m.html,
        png,
        summary: m.summary,
        json: m.json.map_err(|e| e.to_string())?,
    })
}

/// One circle of a hexapod's double ball bar; `None`: the default.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DbbRequest {
    /// The table ball's nominal centre (mm); default the home tool point less the bar.
    pub centre: Option<Vector3>,
    /// The bar length (mm); default 100.
    pub radius_mm: Option<Real>,
    /// The plane; default XY.
    pub plane: Option<DbbPlane>,
    /// The bar's elevation out of the plane (degrees); default 0.
    pub tilt_deg: Option<Real>,
    /// The platform's orientation A,B,C (degrees); default level.
    pub orientation_deg: Option<Vector3>,
    /// The platform's swing along the bar (degrees); default 0.
    pub swing_deg: Option<Real>,
    /// The directions; default both.
    pub turns: Option<Turns>,
    /// Samples per revolution; default 360.
    pub points: Option<usize>,
    /// The table ball's mounting error (mm); default 0.
    pub mount_mm: Option<Vector3>,
    /// Length noise σ (µm); default 0.5.
    pub noise_um: Option<Real>,
    /// Noise seed; default 1.
    pub seed: Option<u64>,
}

impl DbbRequest {
    /// The double ball bar's circle as `measure --instrument ballbar` gives it.
    fn of_measure(r: &MeasureRequest) -> Result<DbbRequest, String> {
        let b = &r.ballbar;
        let vector = |option: &str, v: &Option<Vec<Real>>| {
            v.as_ref().map(|v| offset3(option, v)).transpose()
        };
        Ok(DbbRequest {
            centre: b
                .centre
                .as_ref()
                .map(|c| {
                    let v: Result<Vec<Real>, _> =
                        c.split(',').map(|t| t.trim().parse::<Real>()).collect();
                    match v {
                        Ok(v) if v.len() == 3 && v.iter().all(|x| x.is_finite()) => {
                            Ok(Vector3::new(v[0], v[1], v[2]))
                        }
                        _ => Err(format!(
                            "--centre needs 3 finite comma-separated numbers X,Y,Z (mm) on a \
                             hexapod, got '{c}'"
                        )),
                    }
                })
                .transpose()?,
            radius_mm: b.radius,
            plane: b
                .plane
                .as_ref()
                .map(|p| {
                    DbbPlane::from_name(p)
                        .ok_or_else(|| format!("--plane must be XY, YZ or ZX, got '{p}'"))
                })
                .transpose()?,
            tilt_deg: b.tilt,
            orientation_deg: vector("--orientation", &b.orientation)?,
            swing_deg: b.swing,
            turns: b.direction,
            points: b.points,
            mount_mm: vector("--mount", &b.mount)?,
            noise_um: r.noise_um,
            seed: Some(r.seed),
        })
    }
}

/// A hexapod's double ball bar: the circle of `r` (defaults filled in) on the scene's
/// machine, its trace and ISO 230-4 figures.
pub fn hexapod_ballbar(s: &HexapodScene, r: &DbbRequest) -> Result<BallbarOutcome, String> {
    let radius = r.radius_mm.unwrap_or(100.0);
    let tilt = r.tilt_deg.unwrap_or(0.0);
    let plane = r.plane.unwrap_or(DbbPlane::XY);
    let (_, _, n) = plane.basis();
    let lift = radius * tilt.to_radians().sin();
    let o = r.orientation_deg.unwrap_or_else(Vector3::zeros);
    let circle = DbbCircle {
        centre_mm: r.centre.unwrap_or(s.home.position - lift * n),
        radius_mm: radius,
        plane,
        tilt_deg: tilt,
        orientation_deg: [o.x, o.y, o.z],
        swing_deg: r.swing_deg.unwrap_or(0.0),
        turns: r.turns.unwrap_or(Turns::Both),
        points: r.points.unwrap_or(360),
    };
    let instrument = DbbInstrument {
        mount_mm: r.mount_mm.unwrap_or_else(Vector3::zeros),
        noise_sigma_mm: r.noise_um.unwrap_or(0.5) * 1e-3,
        seed: r.seed.unwrap_or(1),
        stream: 0,
    };
    dbb_ballbar(s, &circle, &instrument).map_err(|e| e.to_string())
}

/// Axis values `X=1,Y=-2.5` for axes of `chain`, as the option `option` gives them.
fn axis_values(
    option: &str,
    text: &str,
    chain: &crate::machine::chain::Chain,
) -> Result<Vec<(AxisLetter, f64)>, String> {
    let axes: Vec<String> = chain
        .axes()
        .iter()
        .map(|a| a.letter.as_char().to_string())
        .collect();
    let mut out: Vec<(AxisLetter, f64)> = Vec::new();
    for item in text.split(',').map(str::trim) {
        let (name, value) = item
            .split_once('=')
            .map(|(n, v)| (n.trim(), v.trim()))
            .ok_or_else(|| format!("{option}: '{item}': expected AXIS=VALUE, e.g. Y=100"))?;
        let mut chars = name.chars();
        let letter = match (chars.next(), chars.next()) {
            (Some(c), None) => AxisLetter::from_char(c).filter(|l| chain.has_axis(*l)),
            _ => None,
        }
        .ok_or_else(|| {
            format!(
                "{option}: '{name}' is not an axis of this machine (axes: {})",
                axes.join(" ")
            )
        })?;
        let v: f64 = match value.parse::<f64>() {
            Ok(v) if v.is_finite() => v,
            Ok(v) => return Err(format!("{option}: {name} = {v} is not finite")),
            Err(_) => return Err(format!("{option}: {name} = '{value}' is not a number")),
        };
        if out.iter().any(|(l, _)| *l == letter) {
            return Err(format!("{option}: {name} is given twice"));
        }
        out.push((letter, v));
    }
    Ok(out)
}

/// A vector given as `DX,DY,DZ` (mm) by `option`.
fn offset3(option: &str, v: &[f64]) -> Result<crate::math::Vector3, String> {
    match v {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok(crate::math::Vector3::new(*x, *y, *z)),
        [_, _, _] => Err(format!("{option}: {v:?} must be finite numbers (mm)")),
        _ => Err(format!(
            "{option} needs three numbers DX,DY,DZ (mm), got {}",
            v.len()
        )),
    }
}

/// `measure --instrument ball-sensor | probe`: the rotary-axis test, its ISO 10791-6
/// figures, and the location errors identified from it.
fn measure_rotary(scene: &Scene, r: &MeasureRequest) -> Result<Reading, String> {
    use super::rotary::{RotaryInstrument, RotaryRequest, default_setup, rotary_test};
    use crate::metrology::ball_sensor::BallSensor;
    use crate::metrology::rotary_test::Sweep;
    use std::fmt::Write as _;
    let o = &r.rotary;
    if r.overshoot.is_some() {
        return Err(format!(
            "--overshoot is not an option of --instrument {}",
            r.instrument.name()
        ));
    }
    let sweeps = o
        .sweep
        .iter()
        .map(|t| Sweep::parse(t).map_err(|e| format!("--{e}")))
        .collect::<Result<Vec<_>, _>>()?;
    let mut setup = default_setup(r.seed);
    if let Some(v) = &o.point {
        setup.point_w = offset3("--point", v)?.into();
    }
    if let Some(v) = &o.mounting {
        setup.mounting_mm = offset3("--mounting", v)?;
    }
    if let Some(v) = &o.stylus {
        setup.tool_offset = offset3("--stylus", v)?;
    }
    let noise_um = r.noise_um.unwrap_or(0.5);
    if !(noise_um.is_finite() && noise_um > 0.0) {
        return Err(format!(
            "--noise: must be a positive number of µm, got {noise_um}"
        ));
    }
    let instrument = match r.instrument {
        MeasureInstrument::Probe => RotaryInstrument::Probe {
            sigma_mm: noise_um * 1e-3,
        },
        _ => {
            let band = o.band.unwrap_or(8.0);
            if !(band.is_finite() && band >= 6.0) {
                return Err(format!(
                    "--band: the light band must be at least the 6 mm measuring range, got {band}"
                ));
            }
            let mut sensor = BallSensor::seed003(band);
            sensor.accuracy_mm = noise_um * 1e-3;
            RotaryInstrument::BallSensor {
                sensor,
                height_mm: o.height.unwrap_or(1.0),
            }
        }
    };
    let request = RotaryRequest {
        instrument,
        sweeps,
        setup,
        identify: if o.no_identify {
            None
        } else {
            Some(o.identify.clone().unwrap_or_default())
        },
    };
    let out = rotary_test(scene, &request).map_err(|e| e.to_string())?;
    let rep = &out.report;
    let plot = r.png.as_ref().map(|_| {
        crate::report::plots::rotary_trace_plot(
            &out.samples,
            &rep.sweeps,
            &format!("ISO 10791-6 {} - {}", rep.instrument, rep.scene),
        )
    });
    let mut s = String::new();
    if let Some(w) = &rep.warning {
        let _ = writeln!(s, "{w}");
    }
    let _ = writeln!(s, "scene         {}", rep.scene);
    let _ = writeln!(
        s,
        "instrument    {} ({} measurements)",
        rep.instrument, rep.samples
    );
    if matches!(r.instrument, MeasureInstrument::BallSensor) {
        let _ = writeln!(s, "ISO 10791-6   deviation ranges of the ball (µm):");
        for f in &rep.sweeps {
            let _ = writeln!(
                s,
                "  sweep {}: {} {} … {}°  X {:.3}  Y {:.3}  Z {:.3}  (max distance {:.3})",
                f.sweep,
                f.axis,
                f.range_deg[0],
                f.range_deg[1],
                f.deviation_range_mm[0] * 1e3,
                f.deviation_range_mm[1] * 1e3,
                f.deviation_range_mm[2] * 1e3,
                f.max_distance_mm * 1e3
            );
        }
    }
    if let Some(id) = &rep.identification {
        s.push_str(&id.summary());
    }
    Ok(Reading {
        text: out.trace_csv.clone(),
        plot,
        html: super::instrument_pages::rotary_page(&out, &s),
        summary: s,
        json: serde_json::to_string_pretty(rep),
    })
}

/// `measure --instrument laser`.
fn measure_laser(scene: &Scene, r: &MeasureRequest, file: &Path) -> Result<Reading, String> {
    use crate::metrology::interferometer::{self, LaserError, LaserSetup, Targets};
    let l = &r.laser;
    let chain = scene.chain();
    let linear: Vec<String> = chain
        .axes()
        .iter()
        .filter(|x| x.kind == crate::machine::chain::AxisKind::Linear)
        .map(|x| x.letter.as_char().to_string())
        .collect();
    let name = l.axis.as_deref().ok_or_else(|| {
        format!(
            "--instrument laser needs --axis (a linear axis of the machine: {})",
            linear.join(" ")
        )
    })?;
    let mut chars = name.trim().chars();
    let axis = match (chars.next(), chars.next()) {
        (Some(c), None) => AxisLetter::from_char(c),
        _ => None,
    }
    .ok_or_else(|| {
        format!(
            "--axis: '{name}' is not an axis letter (the machine's linear axes: {})",
            linear.join(" ")
        )
    })?;
    let targets = match (&l.target_list, l.from, l.to) {
        (Some(list), _, _) => Targets::List(list.clone()),
        (None, Some(from), Some(to)) => {
            // ISO 230-2: at least 5 targets per metre of travel, and 5 in all.
            let length = (to - from).abs();
            let count = l.targets.unwrap_or(if length.is_finite() {
                ((length / 1000.0 * 5.0).ceil() as usize).max(5)
            } else {
                5
            });
            Targets::Even {
                start_mm: from,
                end_mm: to,
                count,
            }
        }
        _ => {
            return Err(
                "--instrument laser needs --from and --to (the first and last target, \
                        mm), or --target-list"
                    .into(),
            );
        }
    };
    let mut held = scene.home();
    if let Some(at) = &l.at {
        for (letter, v) in axis_values("--at", at, chain)? {
            if letter == axis {
                return Err(format!(
                    "--at: {} is the measured axis (--from and --to give its targets)",
                    letter.as_char()
                ));
            }
            held.set(letter, v);
        }
    }
    let mut setup = LaserSetup::new(axis, targets, held);
    setup.runs = l.runs.unwrap_or(setup.runs);
    setup.overshoot_mm = r.overshoot.unwrap_or(setup.overshoot_mm);
    if let Some(v) = &l.abbe {
        setup.abbe_offset_mm = offset3("--abbe", v)?;
    }
    setup.noise_um = r.noise_um.unwrap_or(0.0);
    setup.drift_um_per_run = l.drift.unwrap_or(0.0);
    setup.seed = r.seed;
    if let Some(path) = &l.comp {
        let text = std::fs::read_to_string(path)
            .map_err(|e| format!("{}: cannot read: {e}", path.display()))?;
        setup.comp = Some(
            crate::metrology::comp_table::CompTable::parse(&text, path)
                .map_err(|e| e.to_string())?,
        );
    }
    let m = interferometer::measure(chain, &setup).map_err(|e| match e {
        LaserError::Axis(m) => format!("--axis {}: {m}", axis.as_char()),
        LaserError::Setup { name, message } => format!("--{name}: {message}"),
    })?;
    let figures = evaluate_positioning(&m.readings, file).map_err(|e| e.to_string())?;
    let described = setup.describe(chain);
    let u = m.beam;
    let mut comments = vec![
        format!(
            "twinmill measure {} --instrument laser ({})",
            scene.path.display(),
            scene.machine_name()
        ),
        described.clone(),
        format!(
            "beam along ({:?}, {:?}, {:?}) in the workpiece frame",
            u.x, u.y, u.z
        ),
        "deviation = position reached - target (mm), along the axis's commanded direction"
            .to_string(),
    ];
    if let (Some(path), Some(c)) = (&l.comp, &setup.comp) {
        comments.push(format!(
            "compensation: {} ({} entries) applied to {} as LinuxCNC applies [JOINT_n] \
             COMP_FILE with COMP_FILE_TYPE = 1",
            path.display(),
            c.entries().len(),
            axis.as_char()
        ));
    }
    comments.extend(m.notes.iter().map(|n| format!("note: {n}")));
    let title = format!(
        "twinmill measure: {} laser on {}",
        scene.path.display(),
        axis.as_char()
    );
    let mut extra = vec![("set-up", described)];
    if let Some(path) = &l.comp {
        extra.push(("compensation", path.display().to_string()));
    }
    extra.extend(m.notes.iter().map(|n| ("note", n.clone())));
    extra.push(("wrote", file.display().to_string()));
    let plot_title = format!("ISO 230-2: {} {}", scene.name, axis.as_char());
    let summary = positioning_summary(&title, &extra, &figures);
    Ok(Reading {
        text: m.csv(&comments),
        plot: r
            .png
            .as_ref()
            .map(|_| crate::report::plots::positioning_plot(&figures, &plot_title)),
        html: render_page(&pages::positioning_page(
            &title,
            &summary,
            &figures,
            &plot_title,
        )),
        summary,
        json: serde_json::to_string_pretty(&figures),
    })
}

/// `measure --instrument ballbar`.
fn measure_ballbar(scene: &Scene, r: &MeasureRequest, file: &Path) -> Result<Reading, String> {
    use crate::metrology::ballbar::{self, BallBarError, BallBarSetup, Plane};
    let b = &r.ballbar;
    let chain = scene.chain();
    let plane = match &b.plane {
        None => Plane::Xy,
        Some(p) => {
            Plane::from_name(p).ok_or_else(|| format!("--plane: '{p}': expected XY, YZ or ZX"))?
        }
    };
    let mut centre = scene.home();
    if let Some(c) = &b.centre {
        for (letter, v) in axis_values("--centre", c, chain)? {
            centre.set(letter, v);
        }
    }
    if let Some(p) = b.pitch
        && !(p.is_finite() && p > 0.0)
    {
        return Err(format!("--pitch: must be a positive lead (mm), got {p}"));
    }
    let mut setup = BallBarSetup::new(plane, centre, b.radius.unwrap_or(100.0));
    setup.turns = b.direction.unwrap_or(Turns::Both);
    setup.feed_mm_per_min = b.feed.unwrap_or(setup.feed_mm_per_min);
    setup.points = b.points.unwrap_or(setup.points);
    setup.overshoot_deg = r.overshoot.unwrap_or(setup.overshoot_deg);
    if let Some(v) = &b.tool_ball {
        setup.tool_ball_mm = offset3("--tool-ball", v)?;
    }
    if let Some(v) = &b.mount {
        setup.mount_offset_mm = offset3("--mount", v)?;
    }
    setup.noise_um = r.noise_um.unwrap_or(0.0);
    setup.seed = r.seed;
    let m = ballbar::measure(chain, &setup).map_err(|e| match e {
        BallBarError::Plane { plane, message } => format!("--plane {plane}: {message}"),
        BallBarError::Setup { name, message } => {
            format!("--{}: {message}", name.replace('_', "-"))
        }
    })?;
    let opts = CircularOptions {
        radius_mm: setup.radius_mm,
        pitch_mm: b.pitch,
    };
    let figures = evaluate_circular(&m.samples, &opts, file).map_err(|e| match e {
        TraceError::Unusable { message, .. } => {
            format!("the measured trace cannot be evaluated (ISO 230-4): {message}")
        }
        other => other.to_string(),
    })?;
    let described = setup.describe(chain);
    let c = m.centre_ball;
    let comments = vec![
        format!(
            "twinmill measure {} --instrument ballbar ({})",
            scene.path.display(),
            scene.machine_name()
        ),
        described.clone(),
        format!(
            "centre ball at ({:?}, {:?}, {:?}) in the workpiece frame",
            c.x, c.y, c.z
        ),
        format!(
            "deviation = bar length - {} mm; angle from {} towards {}; evaluate with \
             --radius {}",
            setup.radius_mm,
            plane.axes().0.as_char(),
            plane.axes().1.as_char(),
            setup.radius_mm
        ),
    ];
    let title = format!(
        "twinmill measure: {} ball bar in {}",
        scene.path.display(),
        plane.name()
    );
    let extra = vec![("set-up", described), ("wrote", file.display().to_string())];
    let plot_title = format!("ISO 230-4: {} {}", scene.name, plane.name());
    let summary = circular_summary(&title, &extra, &figures);
    Ok(Reading {
        text: m.csv(&comments),
        plot: r
            .png
            .as_ref()
            .map(|_| crate::report::plots::polar_plot(&m.samples, &figures, &plot_title)),
        html: render_page(&pages::circular_page(
            &title,
            &summary,
            &m.samples,
            &figures,
            &plot_title,
            pages::json(&figures),
        )),
        summary,
        json: serde_json::to_string_pretty(&figures),
    })
}
