//! The `twinmill hexapod` commands on a loaded hexapod scene: the amplification map with its
//! CSV and PNG and the strut resolution it demands, the homing check with the effect of a
//! wrong index, the pivot test with the positioning survey. Each returns its report and its
//! summary text and writes nothing.
//!
//! **Invariant:** the same scene and request give the same outcome (sequential, no random
//! numbers).

use crate::machine::hexapod::{Amplification, Pose};
use crate::machine::hexapod_accuracy::{
    AmplificationMap, HomingSetup, LevelPositioning, PivotReport, ResolutionBudget, StrutHoming,
    Workspace, WrongIndex, amplification_map, homing_check, level_positioning, pivot_test,
    resolution_budget, wrong_index_effects,
};
use crate::math::{Real, Vector3};
use crate::report::hexapod::{
    amplification_csv, amplification_png, amplification_summary, homing_summary, pivot_summary,
};
use crate::report::render::encode_png;
use crate::scene::HexapodScene;
use serde::Serialize;

/// What the scene's controller runs on, for the JSON: `"nominal"`, `"[controller]"` (the
/// scene's section) or the controller file's path.
pub fn controller_name(scene: &HexapodScene) -> String {
    match (&scene.controller_file, scene.calibrated_controller()) {
        (Some(p), _) => p.display().to_string(),
        (None, true) => "[controller]".into(),
        (None, false) => "nominal".into(),
    }
}

/// The most grid points along one axis of a map or pivot test.
pub const MAX_STEPS: usize = 401;

/// A hexapod command's failure: the scene file and what went wrong, one line.
#[derive(Debug, thiserror::Error)]
#[error("{path}: {message}")]
pub struct HexapodCommandError {
    /// The scene file.
    pub path: String,
    /// What went wrong.
    pub message: String,
}

fn error(scene: &HexapodScene, message: impl Into<String>) -> HexapodCommandError {
    HexapodCommandError {
        path: scene.path.display().to_string(),
        message: message.into(),
    }
}

fn check_steps(
    scene: &HexapodScene,
    steps: &[usize],
    what: &str,
) -> Result<(), HexapodCommandError> {
    match steps.iter().find(|s| **s == 0 || **s > MAX_STEPS) {
        Some(s) => Err(error(
            scene,
            format!("{what} {s} must lie in 1..={MAX_STEPS}"),
        )),
        None => Ok(()),
    }
}

/// What `twinmill hexapod amplification` maps.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AmplificationRequest {
    /// The region; `None`: the scene's `[workspace]`.
    pub workspace: Option<Workspace>,
    /// Grid points along x, y, z.
    pub steps: [usize; 3],
    /// Required position resolution of the tool (mm).
    pub position_resolution_mm: Real,
    /// Required angle resolution of the tool (degrees).
    pub angle_resolution_deg: Real,
}

/// The amplification map and what it demands.
#[derive(Clone, Debug, Serialize)]
pub struct AmplificationOutcome {
    /// The machine mapped: always `"nominal"` — the design parameters (seed 001's factors
    /// are a property of the design); the scene's `[deviations]` are not used.
    pub machine: &'static str,
    /// Every pose.
    pub map: AmplificationMap,
    /// The largest K_p and K_a.
    pub general: Option<Amplification>,
    /// Required (position mm, angle degrees) output resolution.
    pub required: (Real, Real),
    /// The strut resolution they demand.
    pub budget: Option<ResolutionBudget>,
    /// The drives' resolution (`[drives]` lead / counts), mm.
    pub drive_resolution_mm: Option<Real>,
    /// The map as CSV.
    #[serde(skip)]
    pub csv: String,
    /// The two heat maps as PNG.
    #[serde(skip)]
    pub png: Vec<u8>,
    /// The summary text.
    #[serde(skip)]
    pub summary: String,
}

/// The resolution amplification map of the scene's nominal machine (its design parameters;
/// the scene's `[deviations]` are not used).
pub fn hexapod_amplification(
    scene: &HexapodScene,
    req: &AmplificationRequest,
) -> Result<AmplificationOutcome, HexapodCommandError> {
    let ws = req.workspace.or(scene.workspace).ok_or_else(|| {
        error(
            scene,
            "amplification needs a region: [workspace] x_mm, y_mm, z_mm in the scene, or --x, --y, --z",
        )
    })?;
    ws.validate().map_err(|e| error(scene, e))?;
    check_steps(scene, &req.steps, "--steps")?;
    for (v, what) in [
        (req.position_resolution_mm, "--resolution-mm"),
        (req.angle_resolution_deg, "--resolution-deg"),
    ] {
        if !(v.is_finite() && v > 0.0) {
            return Err(error(scene, format!("{what} must be positive, got {v}")));
        }
    }
    let map = amplification_map(&scene.nominal, &ws, req.steps);
    let general = map.worst();
    let required = (req.position_resolution_mm, req.angle_resolution_deg);
    let budget = general
        .as_ref()
        .map(|k| resolution_budget(k, required.0, required.1));
    let drive_resolution_mm = scene.drives.map(|d| d.resolution_mm());
    let title = format!("{}: resolution amplification", scene.name);
    let png = amplification_png(&map, &title)
        .and_then(|img| encode_png(&img))
        .map_err(|e| error(scene, format!("amplification map: {e}")))?;
    let summary = amplification_summary(
        &scene.name,
        &map,
        general.as_ref(),
        budget.as_ref(),
        required,
        drive_resolution_mm,
    );
    Ok(AmplificationOutcome {
        machine: "nominal",
        csv: amplification_csv(&map),
        map,
        general,
        required,
        budget,
        drive_resolution_mm,
        png,
        summary,
    })
}

/// The homing check and the effect of a wrong index.
#[derive(Clone, Debug, Serialize)]
pub struct HomingOutcome {
    /// The setup checked.
    pub setup: HomingSetup,
    /// Each strut's check.
    pub struts: Vec<StrutHoming>,
    /// The pose where the wrong index's effect is evaluated (mm, degrees).
    pub pose: [Real; 6],
    /// Each strut ±1 lead off.
    pub wrong_index: Vec<WrongIndex>,
    /// The summary text.
    #[serde(skip)]
    pub summary: String,
}

/// The homing check of the scene's `[homing]` setup (its lead and σ overridden when
/// given) and a wrong index's effect at `pose` (default: home).
pub fn hexapod_homing(
    scene: &HexapodScene,
    pose: Option<Pose>,
    trip_sigma_mm: Option<Real>,
) -> Result<HomingOutcome, HexapodCommandError> {
    let mut setup = scene.homing.ok_or_else(|| {
        error(
            scene,
            "homing needs [drives] lead_mm and [homing] switch_to_index_mm (six distances from the switch to the index, mm)",
        )
    })?;
    if let Some(s) = trip_sigma_mm {
        if !(s.is_finite() && s >= 0.0) {
            return Err(error(
                scene,
                format!("--sigma must not be negative, got {s}"),
            ));
        }
        setup.trip_sigma_mm = s;
    }
    let pose = pose.unwrap_or(scene.home);
    let struts = homing_check(&setup);
    let wrong_index = wrong_index_effects(&scene.controller, &scene.actual, &pose, setup.lead_mm)
        .map_err(|e| error(scene, format!("pose {pose}: {e}")))?;
    let summary = homing_summary(
        &scene.name,
        setup.lead_mm,
        setup.trip_sigma_mm,
        &struts,
        &wrong_index,
    );
    Ok(HomingOutcome {
        setup,
        struts,
        pose: pose.to_mm_deg(),
        wrong_index,
        summary,
    })
}

/// The pivot test and the level positioning survey.
#[derive(Clone, Debug, Serialize)]
pub struct PivotOutcome {
    /// What the controller runs on: `"nominal"`, `"[controller]"` (the scene's) or the
    /// controller file's path.
    pub controller: String,
    /// The pivot test.
    pub pivot: PivotReport,
    /// The largest positioning error with the tool level over the workspace grid (mm) and
    /// where; `None` without a workspace.
    pub level_positioning: Option<LevelPositioning>,
    /// The summary text.
    #[serde(skip)]
    pub summary: String,
}

/// The pivot test at `point` (default: home's position) over `steps × steps` tilts in
/// `[−tilt, tilt]` on the actual machine commanded through the scene's controller (nominal
/// unless calibrated: `[controller]` or a controller file), and the level positioning over
/// the scene's workspace (`survey_steps` per axis).
pub fn hexapod_pivot(
    scene: &HexapodScene,
    point: Option<Vector3>,
    tilt_deg: Real,
    steps: usize,
    survey_steps: usize,
) -> Result<PivotOutcome, HexapodCommandError> {
    check_steps(scene, &[steps, survey_steps], "--steps")?;
    if !(tilt_deg.is_finite() && (0.0..90.0).contains(&tilt_deg)) {
        return Err(error(
            scene,
            format!("--tilt {tilt_deg} must lie in [0, 90) degrees"),
        ));
    }
    let point = point.unwrap_or(scene.home.position);
    if !point.iter().all(|c| c.is_finite()) {
        return Err(error(scene, "--point must be finite"));
    }
    let pivot =
        pivot_test(&scene.controller, &scene.actual, &point, tilt_deg, steps).map_err(|e| {
            error(
                scene,
                format!("pivot at ({}, {}, {}) mm: {e}", point.x, point.y, point.z),
            )
        })?;
    let level_positioning = match &scene.workspace {
        Some(ws) => level_positioning(&scene.controller, &scene.actual, ws, [survey_steps; 3])
            .map_err(|e| error(scene, format!("positioning survey: {e}")))?,
        None => None,
    };
    let mut summary = pivot_summary(&scene.name, &pivot, level_positioning.as_ref());
    let at = summary.find('\n').map_or(summary.len(), |k| k + 1);
    summary.insert_str(
        at,
        &format!("  controller    {}\n", scene.controller_label()),
    );
    Ok(PivotOutcome {
        controller: controller_name(scene),
        pivot,
        level_positioning,
        summary,
    })
}
