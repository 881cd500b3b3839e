//! `twinmill design`: what to measure so that the deviations are determined — test cuts
//! for a serial machine (the program, the scene that cuts, scans and identifies them), the
//! double-ball-bar circles for a hexapod (the plan `identify --plan` reads).
//! `calibrate-design` is the hidden old name of the hexapod's.

use super::{Loaded, SceneArgs, bars, fail, load, print_out, procedure_arg, write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use twinmill::calibration::calibrate::IsoTerm;
use twinmill::calibration::hexapod_calibrate::Procedure;
use twinmill::output::{json_bytes, write_files};
use twinmill::pipeline::dbb::{CalibrationDesignOutcome, calibration_design};
use twinmill::pipeline::design_scene;
use twinmill::pipeline::pages::design_page;
use twinmill::scene::HexapodScene;
use twinmill::scene::Need;

/// Design test cuts or a hexapod's DBB circles that show the deviations.
///
/// Serial machine: design test cuts that make the given deviations (--params) observable on
/// the scene's machine; write design.ngc, design.toml (a scene that cuts, scans and
/// identifies them) and design.json into <out>/<scene>-design/.
///
/// Hexapod: design the double-ball-bar calibration — choose the circles (ball positions,
/// bar lengths and tilts, platform tilts and swing) that predict the smallest pose error
/// after calibration, beside the fixed plan; write the plan `identify --plan` reads into
/// <out>/<scene>-design/plan.toml (docs/hexapod.md).
#[derive(clap::Args)]
pub struct DesignArgs {
    #[command(flatten)]
    args: SceneArgs,
    /// Deviations to make observable, comma separated (e.g. dy_AY,gamma_YX); serial
    /// machines.
    #[arg(long, value_delimiter = ',', num_args = 1)]
    params: Option<Vec<String>>,
    #[command(flatten)]
    hexapod: CircleOptions,
}

// The hexapod's circle-design options.
#[derive(clap::Args)]
#[command(next_help_heading = "Hexapod (double-ball-bar circles)")]
pub struct CircleOptions {
    /// jig-free or ball-plate; default ball-plate.
    #[arg(long)]
    procedure: Option<String>,
    /// Circles to select (1–60); default the fixed plan's count (15 jig-free, 7 ball plate).
    #[arg(long)]
    circles: Option<usize>,
}

/// `calibrate-design`, the hidden old name of `design` on a hexapod.
#[derive(clap::Args)]
pub struct CalibrateDesignArgs {
    /// The hexapod scene file (needs [workspace]).
    scene: PathBuf,
    #[command(flatten)]
    options: CircleOptions,
    /// Write the plan (TOML) here.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Print the outcome as JSON.
    #[arg(long)]
    json: bool,
}

/// The hexapod's circle design, and the scene's name.
fn circles(scene: &Path, a: &CircleOptions) -> Result<(String, CalibrationDesignOutcome), String> {
    let procedure = procedure_arg(a.procedure.as_deref())?;
    let circles = a.circles.unwrap_or(match procedure {
        Procedure::JigFree => 15,
        Procedure::BallPlate => 7,
    });
    let s = HexapodScene::load(scene).map_err(|e| e.to_string())?;
    let o = calibration_design(&s, procedure, circles).map_err(|e| e.to_string())?;
    Ok((s.name, o))
}

/// `twinmill calibrate-design` (hidden): the hexapod's circle design as before.
pub fn exec_calibrate_design(a: CalibrateDesignArgs) -> ExitCode {
    let o = match circles(&a.scene, &a.options) {
        Ok((_, o)) => o,
        Err(e) => return fail(e),
    };
    if let Some(out) = &a.out
        && let Err(e) = write(out, o.plan_toml.as_bytes())
    {
        return fail(e);
    }
    print_out(
        || o.summary.clone(),
        a.json.then(|| serde_json::to_string_pretty(&o)),
    )
}

/// `design` on a hexapod scene: the circles, the plan written into
/// `<out>/<scene stem>-design/plan.toml`.
fn design_hexapod(path: &Path, a: &DesignArgs) -> ExitCode {
    if a.params.is_some() {
        return fail(format!(
            "{}: --params names a serial machine's deviations for test cuts; a hexapod's design \
             chooses double-ball-bar circles for all its parameters (--procedure, --circles)",
            path.display()
        ));
    }
    let (name, o) = match circles(path, &a.hexapod) {
        Ok(x) => x,
        Err(e) => return fail(e),
    };
    let dir = a.args.out.join(format!("{name}-design"));
    if let Err(e) = write_files(&dir, &[("plan.toml", o.plan_toml.clone().into_bytes())]) {
        return fail(e);
    }
    print_out(
        || format!("{}  wrote         {}/plan.toml\n", o.summary, dir.display()),
        a.args.json.then(|| serde_json::to_string_pretty(&o)),
    )
}

/// `twinmill design`.
pub fn exec(a: DesignArgs) -> ExitCode {
    let h = &a.hexapod;
    let hexapod = [
        ("--procedure", h.procedure.is_some()),
        ("--circles", h.circles.is_some()),
    ];
    let scene = match load(&a.args, "design", &[Need::Scanner]) {
        Ok(Loaded::Serial(scene, _)) => *scene,
        Ok(Loaded::Hexapod(path)) => return design_hexapod(&path, &a),
        Err(code) => return code,
    };
    if let Some((option, _)) = hexapod.iter().find(|(_, given)| *given) {
        return fail(format!(
            "{}: {option} is an option of a hexapod's double-ball-bar circles; a serial machine's \
         design is test cuts for --params",
            scene.path.display()
        ));
    }
    let params = match &a.params {
        Some(p) => p.clone(),
        None => {
            return fail(format!(
                "{}: design needs --params, the deviations the test cuts must make observable (e.g. \
         --params dy_AY,gamma_YX)",
                scene.path.display()
            ));
        }
    };
    // Joint deviations (`dy_AY`) and ISO location and squareness terms (`EX0C`, `EC(0X)Y`),
    // each one parameter, as the scene's `[identify] parameters` take them.
    let mut ids = Vec::new();
    let mut iso: Vec<IsoTerm> = Vec::new();
    for p in &params {
        let parsed = if p.contains('_') {
            scene.model().deviation_id(p).map(|id| ids.push(id))
        } else {
            IsoTerm::parse(scene.model(), p).map(|t| iso.push(t))
        };
        if let Err(e) = parsed {
            return fail(format!("--params: {e}"));
        }
    }
    let name = format!("{}-design", scene.name);
    let outcome = match design_scene(&scene, &params, &ids, &iso, &name, &bars(a.args.json)) {
        Ok(o) => o,
        Err(e) => return fail(e),
    };
    let report = &outcome.report;
    let dir = a.args.out.join(&name);
    let html = match design_page(&scene, report, &outcome.verified) {
        Ok(h) => h,
        Err(e) => return fail(e),
    };
    let files = json_bytes(report, &dir.join("design.json"))
        .map(|j| {
            vec![
                ("design.json", j),
                ("design.ngc", outcome.design.program.clone().into_bytes()),
                ("design.toml", outcome.scene_toml.clone().into_bytes()),
                ("report.html", html.into_bytes()),
            ]
        })
        .and_then(|files| write_files(&dir, &files));
    if let Err(e) = files {
        return fail(e);
    }
    print_out(
        || {
            format!(
                "{}  wrote         {}/{{design.ngc, design.toml, design.json, report.html}}\n",
                report.summary(),
                dir.display()
            )
        },
        a.args.json.then(|| serde_json::to_string_pretty(report)),
    )
}
