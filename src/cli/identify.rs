//! `twinmill identify`: a machine's deviations from what was measured — a serial machine's
//! from the faces of its cut part (the scene's simulated scan, or a given cloud), a
//! hexapod's from double-ball-bar traces (its calibration: on the twin, or from traces
//! measured on the machine). `calibrate` is the hidden old name of the hexapod's.

use super::{
    Loaded, SceneArgs, accept_misfit, bars, fail, load, load_machine, print_out, procedure_arg,
    write, write_report_and_cloud,
};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use twinmill::metrology::cloud::read_cloud_file;
use twinmill::nc::Program;
use twinmill::pipeline::dbb::{calibrate_measured, calibrate_scene, load_plan};
use twinmill::pipeline::hexapod_probe::joint_page;
use twinmill::pipeline::instrument_pages::{calibrate_page, measured_calibrate_page};
use twinmill::pipeline::measurements::{
    IdentifyRequest, MeasurementKind, PartFaces, identify_measurements,
};
use twinmill::pipeline::pages::identify_page;
use twinmill::pipeline::{identify_location_files, identify_scene, part_faces};
use twinmill::scene::HexapodScene;
use twinmill::scene::{MemoryBudget, Need, Scene, SceneError};

/// Identify the deviations: from cut faces, or a hexapod's DBB traces.
///
/// Serial machine: identify the scene's `[identify] parameters` from its faces (any number,
/// flanks and floors) in its simulated scan or in a given cloud: identifiability (singular
/// values, what is and is not determined), values with uncertainties, the model-correction
/// loop; write identify.json and cloud.ply.
///
/// Serial machine, with --measurement: identify its deviations, location terms, error
/// motions and reversals from laser readings, ball-bar traces, ball-sensor or probe traces
/// and cut parts, in one solve (values with σ, what is not determined), refusing data the
/// stated noise cannot explain; --deviations-out writes the identified machine for
/// --deviations.
///
/// Hexapod: seed 000's double-ball-bar calibration — measure the procedure's (or the plan's)
/// circles on the twin, identify with what is not determined, pose errors before and after;
/// or, with --readings, identify from traces measured on the machine (docs/hexapod.md).
#[derive(clap::Args)]
pub struct IdentifyArgs {
    #[command(flatten)]
    args: SceneArgs,
    /// Identify from this cloud (PLY, XYZ/CSV, PTS; workpiece or scanner frame) instead
    /// of the scene's simulated scan.
    #[arg(long)]
    cloud: Option<PathBuf>,
    /// Monte-Carlo trials over scanner noise (simulated scans only; default: the
    /// scene's [identify] monte_carlo.trials); with --measurement (or a hexapod's
    /// --readings), trials at the solution over the files' stated noise (default: none),
    /// each identified value's spread beside its σ.
    #[arg(long, value_name = "N")]
    monte_carlo: Option<usize>,
    #[command(flatten)]
    hexapod: CalibrateOptions,
    #[command(flatten)]
    instruments: InstrumentOptions,
}

// A serial machine from its instruments' files.
#[derive(clap::Args)]
#[command(next_help_heading = "Serial machine from laser and ball-bar files")]
pub struct InstrumentOptions {
    /// Identify the machine's deviations, location terms, error motions and reversals from
    /// this laser readings, ball-bar, ball-sensor or probe trace file (as `measure
    /// --instrument …` writes it), repeatable, all in one solve: [KIND:]FILE with KIND
    /// laser[:AXIS], ballbar[:PLANE], ball-sensor or probe (without a kind, the file's
    /// set-up record says what it is); or part:SCENE[:CLOUD], the faces of the part SCENE's
    /// program cuts on this machine, in CLOUD, else in SCENE's simulated scan.
    #[arg(long, value_name = "[KIND:]FILE")]
    measurement: Vec<String>,
    /// With --measurement: the parameters to identify, by the scene's names
    /// (EXX.polynomial[1], EYX.periodic[0], EBX.table[1], EC(0X)Y, EX0C, dy_AY,
    /// reversal.X; default: every one the scene models, and with traces or parts every
    /// rotary axis's location terms).
    #[arg(long, value_name = "NAME,…", value_delimiter = ',')]
    parameters: Vec<String>,
    /// With --measurement: write the identified machine (the scene's [deviations],
    /// [error_motions] and [reversal] sections, with an [identified] record and
    /// [identified.sigma]) into this file, which --deviations reads.
    #[arg(long, value_name = "FILE")]
    deviations_out: Option<PathBuf>,
    /// With --measurement: identify from the files and the faces of the part the scene's
    /// program cuts, in one solve — the part's cloud from --cloud, else the scene's
    /// simulated scan.
    #[arg(long)]
    part: bool,
}

/// `identify --measurement`: the scene's serial machine from laser and ball-bar files, or
/// its rotary axes' location terms from ball-sensor and probe traces (and a cut part).
fn identify_instruments(a: &IdentifyArgs) -> ExitCode {
    let mut measurements = Vec::with_capacity(a.instruments.measurement.len());
    let mut parts: Vec<PartFaces> = Vec::new();
    let mut part_scenes: Vec<(String, PathBuf, Option<PathBuf>)> = Vec::new();
    for spec in &a.instruments.measurement {
        if let Some(rest) = spec
            .get(..5)
            .filter(|k| k.eq_ignore_ascii_case("part:"))
            .map(|_| &spec[5..])
        {
            let (scene, cloud) = match rest.split_once(':') {
                Some((s, c)) if !c.is_empty() => (s, Some(PathBuf::from(c))),
                _ => (rest, None),
            };
            if scene.is_empty() {
                return fail(format!(
                    "--measurement '{spec}': expected part:SCENE.toml[:CLOUD]"
                ));
            }
            part_scenes.push((spec.clone(), PathBuf::from(scene), cloud));
            continue;
        }
        let (kind, path) = match MeasurementKind::parse_spec(spec) {
            Ok(k) => k,
            Err(e) => return fail(e),
        };
        let kind = match kind {
            Some(k) => k,
            None => match MeasurementKind::of_file(&path) {
                Ok(k) => k,
                Err(e) => return fail(e),
            },
        };
        measurements.push((kind, path));
    }
    let rotary = measurements
        .iter()
        .filter(|(k, _)| *k == MeasurementKind::Rotary)
        .count();
    if rotary == measurements.len() && part_scenes.is_empty() && a.monte_carlo.is_none() {
        return identify_traces(a, &measurements);
    }
    if let Some(option) = a.hexapod.first_given() {
        return fail(format!(
            "{option} cannot go with a serial machine's measurement files (laser, ball bar, \
             ball sensor, probe, parts)"
        ));
    }
    let with_part = a.instruments.part || a.cloud.is_some();
    let why = "a hexapod is identified from its double-ball-bar traces (--readings)";
    let scene = if with_part {
        let needs: &[Need] = if a.cloud.is_some() {
            &[]
        } else {
            &[Need::Scanner]
        };
        match load(&a.args, "identify --measurement", needs) {
            Ok(Loaded::Serial(scene, program)) => {
                match part_of(&scene, &program, a.cloud.as_deref(), a.args.json) {
                    Ok(p) => parts.insert(0, p),
                    Err(e) => return fail(e),
                }
                *scene
            }
            Ok(Loaded::Hexapod(path)) => {
                return fail(format!("{}: {why}", path.display()));
            }
            Err(code) => return code,
        }
    } else {
        match load_machine(&a.args, "identify --measurement", why) {
            Ok(s) => s,
            Err(code) => return code,
        }
    };
    for (spec, path, cloud) in &part_scenes {
        match other_part(&scene, spec, path, cloud.as_deref(), a.args.json) {
            Ok(p) => parts.push(p),
            Err(e) => return fail(e),
        }
    }
    let parameters = &a.instruments.parameters;
    let faces: usize = parts.iter().map(|p| p.features.len()).sum();
    let request = IdentifyRequest {
        measurements,
        parameters: (!parameters.is_empty()).then(|| parameters.clone()),
        accept_misfit: accept_misfit(),
        parts,
        monte_carlo: a.monte_carlo,
    };
    let o = match identify_measurements(&scene, &request) {
        Ok(o) => o,
        Err(e) => return fail(e),
    };
    print_identified(
        a,
        &o.file,
        || {
            let mut s = o.report.summary();
            if faces > 0 {
                s.push_str(&format!("  part faces    {faces}\n"));
            }
            s
        },
        || serde_json::to_string_pretty(&o.report),
    )
}

/// The faces of the part `scene`'s program cuts: in `cloud` (a scan of the real part),
/// else in the scene's simulated scan of its cut.
fn part_of(
    scene: &Scene,
    program: &Program,
    cloud: Option<&Path>,
    json: bool,
) -> Result<PartFaces, String> {
    let given = match cloud {
        Some(path) => Some((
            read_cloud_file(path).map_err(|e| e.to_string())?,
            path.display().to_string(),
        )),
        None => None,
    };
    let (features, source) = part_faces(
        scene,
        program,
        given.as_ref().map(|(c, s)| (c, s.as_str())),
        &bars(json),
    )
    .map_err(|e| e.to_string())?;
    // A simulated scan is named by the scene whose part it scans.
    let source = match cloud {
        Some(_) => source,
        None => format!("{} ({source})", scene.path.display()),
    };
    Ok(PartFaces {
        source,
        features,
        tool: scene.tool.clone(),
    })
}

/// A second part (`--measurement part:SCENE[:CLOUD]`): the part `SCENE`'s program cuts,
/// with its tool, stock and `[identify] faces`, on the machine of the identification's
/// scene (refused when `SCENE` describes another); in `CLOUD`, else in `SCENE`'s simulated
/// scan.
fn other_part(
    machine: &Scene,
    spec: &str,
    path: &Path,
    cloud: Option<&Path>,
    json: bool,
) -> Result<PartFaces, String> {
    let scene = match Scene::load_with(path, &MemoryBudget::installed()) {
        Err(SceneError::Hexapod { path }) => {
            return Err(format!(
                "{}: --measurement '{spec}': a part is cut by a serial machine; this is a \
                 hexapod scene",
                path.display()
            ));
        }
        r => r.map_err(|e| e.to_string())?,
    };
    let bare = |s: &Scene| s.chain().nominal();
    if bare(&scene) != bare(machine) {
        return Err(format!(
            "{}: --measurement '{spec}': its machine is not the one identified ({})",
            path.display(),
            machine.path.display()
        ));
    }
    let needs: &[Need] = if cloud.is_some() {
        &[]
    } else {
        &[Need::Scanner]
    };
    scene
        .require("identify --measurement part:", needs)
        .map_err(|e| e.to_string())?;
    let program = scene.load_program().map_err(|e| e.to_string())?;
    part_of(&scene, &program, cloud, json)
}

/// Writes the identified machine to `--deviations-out` (if given), then prints `summary`
/// with the file it wrote, or the JSON.
fn print_identified(
    a: &IdentifyArgs,
    file: &str,
    summary: impl FnOnce() -> String,
    json: impl FnOnce() -> serde_json::Result<String>,
) -> ExitCode {
    let out = &a.instruments.deviations_out;
    if let Some(out) = out
        && let Err(e) = write(out, file.as_bytes())
    {
        return fail(e);
    }
    print_out(
        || {
            let mut s = summary();
            if let Some(out) = out {
                s.push_str(&format!("  wrote         {}\n", out.display()));
            }
            s
        },
        a.args.json.then(json),
    )
}

/// `identify --measurement ball-sensor:FILE …`: the rotary axes' location terms from
/// the traces, with the cut part's faces when `--part` (or `--cloud`) is given.
fn identify_traces(a: &IdentifyArgs, files: &[(MeasurementKind, PathBuf)]) -> ExitCode {
    let with_part = a.instruments.part || a.cloud.is_some();
    if let Some(option) = a.hexapod.first_given() {
        return fail(format!(
            "{option} cannot go with ball-sensor or probe traces (a serial machine's rotary \
             axes identified from them and a cut part)"
        ));
    }
    let needs: &[Need] = match (&a.cloud, with_part) {
        (None, true) => &[Need::Scanner],
        _ => &[],
    };
    let (scene, program) = match load(&a.args, "identify --measurement", needs) {
        Ok(Loaded::Serial(scene, program)) => (*scene, program),
        Ok(Loaded::Hexapod(path)) => {
            return fail(format!(
                "{}: a ball-sensor or probe trace identifies a serial machine's rotary axes; \
                 a hexapod is identified from its double-ball-bar traces (--readings)",
                path.display()
            ));
        }
        Err(code) => return code,
    };
    let given = match &a.cloud {
        Some(path) => match read_cloud_file(path) {
            Ok(c) => Some((c, path.display().to_string())),
            Err(e) => return fail(e),
        },
        None => None,
    };
    let (planes, source) = if with_part {
        match part_faces(
            &scene,
            &program,
            given.as_ref().map(|(c, s)| (c, s.as_str())),
            &bars(a.args.json),
        ) {
            Ok((f, s)) => (f, Some(s)),
            Err(e) => return fail(e),
        }
    } else {
        (Vec::new(), None)
    };
    let paths: Vec<PathBuf> = files.iter().map(|(_, p)| p.clone()).collect();
    let o = match identify_location_files(
        &scene,
        &a.instruments.parameters,
        &paths,
        &planes,
        source.as_deref(),
    ) {
        Ok(o) => o,
        Err(e) => return fail(e),
    };
    print_identified(
        a,
        &o.file,
        || {
            let mut s = String::new();
            if let Some(w) = o.report.fit.accepted_line() {
                s.push_str(&format!("{w}\n"));
            }
            s.push_str(&format!("scene         {}\n", scene.name));
            s.push_str(&format!("from          {}\n", o.sources.join(", ")));
            if with_part {
                s.push_str(&format!("part          {} faces\n", o.faces));
            }
            s.push_str(&o.report.summary());
            s
        },
        || serde_json::to_string_pretty(&o.report),
    )
}

// The hexapod's calibration options.
#[derive(clap::Args)]
#[command(next_help_heading = "Hexapod (double-ball-bar traces)")]
pub struct CalibrateOptions {
    /// jig-free (15 circles, 18 parameters) or ball-plate (7 circles, 24); default
    /// ball-plate.
    #[arg(long)]
    procedure: Option<String>,
    /// Also run this many seeded trials of random deviations (joints ±0.5 mm, struts
    /// ±0.2 mm).
    #[arg(long, default_value_t = 0)]
    trials: usize,
    /// Measure these circles instead of the procedure's fixed ones (a plan file written by
    /// `design`).
    #[arg(long)]
    plan: Option<PathBuf>,
    /// Write the page (self-contained HTML: the identified parameters with σ, the singular
    /// values, what is not determined and why, the pose errors before and after) into this
    /// file.
    #[arg(long, value_name = "FILE")]
    html: Option<PathBuf>,
    /// Identify from bar readings measured on the machine instead of measuring on the twin:
    /// one trace file per circle of the plan (`--plan`, or the procedure's fixed one), in
    /// its order, in the format `measure --instrument ballbar` writes.
    #[arg(long, value_name = "FILE,…", value_delimiter = ',')]
    readings: Vec<PathBuf>,
    /// With --readings: also the touch probe's readings of positioning and pivot accuracy
    /// (the file `hexapod probe-calibrate --readings-out` writes), identified together with
    /// the bar's in one identification of all 42 parameters (--html and --corrected write
    /// its page and its controller and genhexkins files).
    #[arg(long, value_name = "FILE")]
    probe: Option<PathBuf>,
    /// Write the calibrated controller (a `[controller]` file: the identified parameters as
    /// deviations from nominal, for `--controller FILE` or the scene) into this file, and
    /// its LinuxCNC genhexkins joint coordinates beside it (`FILE` with `.hal`).
    #[arg(long, value_name = "FILE")]
    corrected: Option<PathBuf>,
}

impl CalibrateOptions {
    /// The first of these options given on the command line (for a refusal naming it).
    fn first_given(&self) -> Option<&'static str> {
        [
            ("--procedure", self.procedure.is_some()),
            ("--trials", self.trials != 0),
            ("--plan", self.plan.is_some()),
            ("--html", self.html.is_some()),
            ("--readings", !self.readings.is_empty()),
            ("--probe", self.probe.is_some()),
            ("--corrected", self.corrected.is_some()),
        ]
        .into_iter()
        .find_map(|(o, given)| given.then_some(o))
    }
}

/// `calibrate`, the hidden old name of `identify` on a hexapod.
#[derive(clap::Args)]
pub struct CalibrateArgs {
    /// The hexapod scene file (needs [workspace]).
    scene: PathBuf,
    #[command(flatten)]
    options: CalibrateOptions,
    /// Print the outcome as JSON.
    #[arg(long)]
    json: bool,
}

/// `twinmill calibrate` (hidden): the hexapod's calibration as before.
pub fn exec_calibrate(a: CalibrateArgs) -> ExitCode {
    calibrate(&a.scene, &a.options, None, None, a.json).unwrap_or_else(fail)
}

/// `identify` on a hexapod scene: refuses the options of a serial machine's, then
/// calibrates.
fn calibrate_hexapod(path: &Path, a: &IdentifyArgs) -> ExitCode {
    let serial = [
        ("--cloud", a.cloud.is_some()),
        (
            "--monte-carlo",
            a.monte_carlo.is_some() && a.hexapod.readings.is_empty(),
        ),
    ];
    if let Some((option, _)) = serial.iter().find(|(_, given)| *given) {
        return fail(format!(
            "{}: {option} identifies a serial machine from cut faces; a hexapod is identified \
             from double-ball-bar traces (--readings, or on the twin)",
            path.display()
        ));
    }
    calibrate(
        path,
        &a.hexapod,
        a.args.controller.as_deref(),
        a.monte_carlo,
        a.args.json,
    )
    .unwrap_or_else(fail)
}

/// The hexapod's double-ball-bar calibration: on the twin, or from measured traces; the
/// circles run by the scene's controller or `controller`'s.
fn calibrate(
    scene: &Path,
    a: &CalibrateOptions,
    controller: Option<&Path>,
    monte_carlo: Option<usize>,
    json: bool,
) -> Result<ExitCode, String> {
    let procedure = procedure_arg(a.procedure.as_deref())?;
    let mut s = HexapodScene {
        accept_misfit: super::accept_misfit(),
        ..HexapodScene::load(scene).map_err(|e| e.to_string())?
    };
    if let Some(c) = controller {
        s.apply_controller_file(c).map_err(|e| e.to_string())?;
    }
    let plan = match &a.plan {
        None => None,
        Some(p) => Some(load_plan(p).map_err(|e| e.to_string())?),
    };
    let procedure = match (&plan, a.procedure.is_some()) {
        (Some(p), false) => p.procedure,
        _ => procedure,
    };
    if a.probe.is_some() && a.readings.is_empty() {
        return Err(
            "--probe goes with --readings (the bar's trace files of the same machine)".into(),
        );
    }
    if !a.readings.is_empty() {
        if a.trials > 0 {
            return Err("--trials runs on the twin; it cannot go with --readings".into());
        }
        let mut files = Vec::with_capacity(a.readings.len());
        for p in &a.readings {
            let text = twinmill::scene::read_text(p).map_err(|e| e.to_string())?;
            files.push((p.clone(), text));
        }
        if let Some(probe) = &a.probe {
            let text = twinmill::scene::read_text(probe).map_err(|e| e.to_string())?;
            let o = twinmill::pipeline::hexapod_probe::identify_dbb_and_probe(
                &s,
                procedure,
                plan,
                &files,
                &(probe.clone(), text),
                monte_carlo,
            )
            .map_err(|e| e.to_string())?;
            let page = a.html.as_ref().map(|h| (h, joint_page(&o)));
            let wrote =
                write_calibration_files(a.corrected.as_deref(), &o.fragment, &o.genhexkins, page)?;
            return Ok(print_out(
                || o.summary.clone() + &wrote,
                json.then(|| serde_json::to_string_pretty(&o)),
            ));
        }
        let o = calibrate_measured(&s, procedure, plan, &files, monte_carlo)
            .map_err(|e| e.to_string())?;
        let page = a
            .html
            .as_ref()
            .map(|h| (h, measured_calibrate_page(&s.name, &o)));
        let wrote =
            write_calibration_files(a.corrected.as_deref(), &o.fragment, &o.genhexkins, page)?;
        return Ok(print_out(
            || o.summary.clone() + &wrote,
            json.then(|| serde_json::to_string_pretty(&o)),
        ));
    }
    let o = calibrate_scene(&s, procedure, plan, a.trials).map_err(|e| e.to_string())?;
    let page = a.html.as_ref().map(|h| (h, calibrate_page(&s.name, &o)));
    let wrote = write_calibration_files(a.corrected.as_deref(), &o.fragment, &o.genhexkins, page)?;
    Ok(print_out(
        || o.summary.clone() + &wrote,
        json.then(|| serde_json::to_string_pretty(&o)),
    ))
}

/// Writes the controller file (and the genhexkins file beside it: the same name with
/// `.hal`) and the page, all of them or none ([`twinmill::output::write_paths`]: two of them
/// naming one file, or one that cannot be written, leaves nothing written); returns the
/// summary's lines naming them.
fn write_calibration_files(
    corrected: Option<&Path>,
    fragment: &str,
    genhexkins: &str,
    page: Option<(&PathBuf, String)>,
) -> Result<String, String> {
    let mut wrote = String::new();
    let mut files: Vec<(PathBuf, &[u8])> = Vec::new();
    if let Some(out) = corrected {
        let hal = out.with_extension("hal");
        if hal == out {
            return Err(format!(
                "--corrected {}: the genhexkins file beside it would take the same name (give the controller file a .toml name)",
                out.display()
            ));
        }
        wrote += &format!(
            "  wrote         {} (controller), {} (LinuxCNC genhexkins)\n",
            out.display(),
            hal.display()
        );
        files.push((out.to_path_buf(), fragment.as_bytes()));
        files.push((hal, genhexkins.as_bytes()));
    }
    if let Some((path, html)) = &page {
        wrote += &format!("  wrote         {}\n", path.display());
        files.push((path.to_path_buf(), html.as_bytes()));
    }
    let files: Vec<(&Path, &[u8])> = files.iter().map(|(p, b)| (p.as_path(), *b)).collect();
    twinmill::output::write_paths(&files).map_err(|e| e.to_string())?;
    Ok(wrote)
}

/// `twinmill identify`.
pub fn exec(a: IdentifyArgs) -> ExitCode {
    let i = &a.instruments;
    if !i.measurement.is_empty() {
        return identify_instruments(&a);
    }
    if let Some(option) = [
        ("--parameters", !i.parameters.is_empty()),
        ("--deviations-out", i.deviations_out.is_some()),
        ("--part", i.part),
    ]
    .iter()
    .find_map(|(o, given)| given.then_some(o))
    {
        return fail(format!(
            "{option} goes with --measurement (a serial machine identified from laser and \
             ball-bar files)"
        ));
    }
    // A simulated scan needs the scanner; a given cloud does not.
    let identify_needs: &[Need] = match a.cloud {
        Some(_) => &[Need::Parameters],
        None => &[Need::Parameters, Need::Scanner],
    };
    let (scene, program) = match load(&a.args, "identify", identify_needs) {
        Ok(Loaded::Serial(scene, program)) => {
            if let Some(option) = a.hexapod.first_given() {
                return fail(format!(
                    "{}: {option} is an option of a hexapod's identification from double-ball-bar \
                 traces; a serial machine is identified from the faces of its cut part",
                    scene.path.display()
                ));
            }
            (*scene, program)
        }
        Ok(Loaded::Hexapod(path)) => return calibrate_hexapod(&path, &a),
        Err(code) => return code,
    };
    let given = match &a.cloud {
        Some(path) => match read_cloud_file(path) {
            Ok(c) => Some((c, path.display().to_string())),
            Err(e) => return fail(e),
        },
        None => None,
    };
    let bars = bars(a.args.json);
    let outcome = match identify_scene(
        &scene,
        &program,
        given.as_ref().map(|(c, s)| (c, s.as_str())),
        a.monte_carlo,
        &bars,
    ) {
        Ok(o) => o,
        Err(e) => return fail(e),
    };
    let dir = a.args.out.join(format!("{}-identify", scene.name));
    let html = match identify_page(
        &scene,
        &outcome.report,
        &outcome.cloud.points,
        &outcome.features,
    ) {
        Ok(h) => h,
        Err(e) => return fail(e),
    };
    let files =
        write_report_and_cloud(&dir, "identify.json", &outcome.report, &outcome.cloud, html);
    if let Err(e) = files {
        return fail(e);
    }
    let code = print_out(
        || {
            format!(
                "{}  wrote         {}/{{identify.json, cloud.ply, report.html}}\n",
                outcome.report.summary(),
                dir.display()
            )
        },
        a.args
            .json
            .then(|| serde_json::to_string_pretty(&outcome.report)),
    );
    if code == ExitCode::SUCCESS && !outcome.report.converged {
        // Written and reported, but the twin does not reproduce the measured faces.
        let worst = outcome
            .report
            .rounds
            .last()
            .map_or(f64::NAN, |r| r.worst_face_mm);
        let _ = writeln!(
            std::io::stderr(),
            "twinmill: the model-correction loop did not converge: after {} rounds the \
                     twin's faces still differ from the measured ones by up to {worst:.4} mm \
                     (deviations outside the identified set, or the wrong faces)",
            outcome.report.rounds.len()
        );
        return ExitCode::from(2);
    }
    code
}
