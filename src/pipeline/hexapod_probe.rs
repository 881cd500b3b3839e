//! `twinmill hexapod probe-calibrate` on a loaded hexapod scene: seed 001's two-round
//! calibration from gauge-block / touch-probe readings
//! ([`crate::calibration::hexapod_probe`]), its two figures before and after each round, the
//! parameters identified with σ, what is not determined, and the corrected parameters as a
//! `[deviations]` fragment. Writes nothing.
//!
//! **Invariant:** the same scene and request give the same outcome, bit for bit (the
//! noise from a counter-based generator of the given seed).

use crate::calibration::hexapod_probe::{ProbeCalibration, ProbeOptions, calibrate};
use crate::machine::hexapod::{PARAMETERS, ParameterId};
use crate::math::Real;
use crate::pipeline::hexapod::HexapodCommandError;
use crate::scene::HexapodScene;
use serde::Serialize;
use std::fmt::Write as _;

/// What the calibration reports.
#[derive(Clone, Debug, Serialize)]
pub struct ProbeOutcome {
    /// The scene's name.
    pub scene: String,
    /// The calibration, round by round.
    pub calibration: ProbeCalibration,
    /// Per parameter: the scene's deviation, the final controller's deviation from nominal,
    /// and the last round's σ along the determined subspace (mm).
    pub parameters: Vec<ProbeParameterRow>,
    /// The final controller as a `[controller]` file (deviations from nominal, σ in
    /// comments).
    #[serde(skip)]
    pub fragment: String,
    /// The summary text.
    #[serde(skip)]
    pub summary: String,
}

/// One parameter's line of the report.
#[derive(Clone, Debug, Serialize)]
pub struct ProbeParameterRow {
    /// Name (`bx_1`, `l0_3`, …).
    pub name: String,
    /// The scene's deviation (the machine as built; mm).
    pub injected_mm: Real,
    /// The final controller's deviation from nominal (mm).
    pub identified_mm: Real,
    /// The last round's σ of it (mm).
    pub sigma_mm: Real,
}

/// Runs seed 001's calibration on the scene's machine (its controller — nominal unless a
/// `[controller]` section or file says otherwise — the actual machine and `[workspace]`);
/// the fragment is a controller file for `--controller`.
pub fn hexapod_probe_calibrate(
    scene: &HexapodScene,
    options: &ProbeOptions,
) -> Result<ProbeOutcome, HexapodCommandError> {
    let error = |message: String| HexapodCommandError {
        path: scene.path.display().to_string(),
        message,
    };
    let ws = scene.workspace.ok_or_else(|| {
        error("probe-calibrate needs [workspace] (the region the probe measures)".into())
    })?;
    let options = ProbeOptions {
        accept_misfit: options.accept_misfit || scene.accept_misfit,
        ..*options
    };
    let cal = calibrate(&scene.controller, &scene.actual, &ws, &options)
        .map_err(|e| error(e.to_string()))?;
    let last = cal
        .rounds
        .last()
        .ok_or_else(|| error("no round ran".into()))?;
    let controller = cal
        .controller
        .clone()
        .ok_or_else(|| error("no controller".into()))?;
    let pn = scene.nominal.parameters();
    let pc = controller.parameters();
    let pa = scene.actual.parameters();
    let parameters: Vec<ProbeParameterRow> = ParameterId::all()
        .map(|id| ProbeParameterRow {
            name: id.name(),
            injected_mm: pa[id.index()] - pn[id.index()],
            identified_mm: pc[id.index()] - pn[id.index()],
            sigma_mm: last.identification.parameter_sigma[id.index()],
        })
        .collect();
    let mut fragment = format!(
        "# Corrected parameters of {} identified by `twinmill hexapod probe-calibrate`\n\
         # ({} rounds of gauge-block / touch-probe readings, σ {} µm, seed {}).\n\
         # The controller's parameters as deviations from nominal (mm), for --controller;\n\
         # σ of the last round along what the readings determine. Directions they do not\n\
         # determine keep the starting controller's values.\n[controller]\n",
        scene.name,
        options.rounds,
        options.sigma_mm * 1e3,
        options.seed
    );
    for r in &parameters {
        let _ = writeln!(
            fragment,
            "{} = {:.7}   # σ {:.7}",
            r.name, r.identified_mm, r.sigma_mm
        );
    }
    let summary = summary(scene, &cal, &parameters);
    Ok(ProbeOutcome {
        scene: scene.name.clone(),
        calibration: cal,
        parameters,
        fragment,
        summary,
    })
}

fn summary(scene: &HexapodScene, cal: &ProbeCalibration, rows: &[ProbeParameterRow]) -> String {
    let o = &cal.options;
    let [np, nv, ns, nr] = cal.plan_points;
    let mut s = String::new();
    if let Some(w) = cal
        .rounds
        .iter()
        .find_map(|r| r.identification.fit.accepted_line())
    {
        let _ = writeln!(s, "twinmill: {w}");
    }
    let tilt = scene.workspace.map_or(0.0, |w| w.tilt_deg);
    let _ = writeln!(
        s,
        "twinmill: hexapod probe-calibrate {} (seed 001: gauge blocks and a touch probe, {} rounds)",
        scene.name, o.rounds
    );
    let _ = writeln!(
        s,
        "  probe        x, y, z readings a point, noise σ {} µm, seed {}; {np} level grid points, {nv} pivot points swung to {ns} orientations (±{tilt}°): {nr} readings a round",
        o.sigma_mm * 1e3,
        o.seed
    );
    let _ = writeln!(
        s,
        "  survey       twin without noise on poses not measured: level 5 × 5 × 5 grid, pivot at 5 points × 25 orientations (±{tilt}°)\n"
    );
    let _ = writeln!(
        s,
        "                 positioning error (mm)      pivot error (mm)\n                 probe       twin            probe       twin"
    );
    let row = |name: &str, measured: Option<(Real, Real)>, twin: (Real, Real)| {
        let m = |v: Option<Real>| v.map_or("    —   ".to_string(), |v| format!("{v:8.4}"));
        format!(
            "  {name:<14} {}    {:8.4}        {}    {:8.4}\n",
            m(measured.map(|x| x.0)),
            twin.0,
            m(measured.map(|x| x.1)),
            twin.1
        )
    };
    let pair = |a: &crate::calibration::hexapod_probe::Accuracy| (a.positioning_mm, a.pivot_mm);
    let first = cal.rounds.first().map(|r| pair(&r.measured));
    s += &row("before", first, pair(&cal.before));
    for (k, r) in cal.rounds.iter().enumerate() {
        let measured = cal
            .rounds
            .get(k + 1)
            .map(|n| pair(&n.measured))
            .unwrap_or(pair(&cal.measured_after));
        s += &row(
            &format!("after round {}", r.round),
            Some(measured),
            pair(&r.after),
        );
    }
    s.push('\n');
    for r in &cal.rounds {
        let id = &r.identification;
        let _ = writeln!(
            s,
            "  round {}      rank {} of {PARAMETERS}, χ² {:.1} → {:.1}, {}",
            r.round,
            id.rank,
            id.chi2_history.first().copied().unwrap_or(Real::NAN),
            id.chi2_history.last().copied().unwrap_or(Real::NAN),
            if id.fit.fits {
                "the readings fit at the stated σ"
            } else {
                "MISFIT accepted"
            }
        );
    }
    if let Some(last) = cal.rounds.last() {
        let id = &last.identification;
        let _ = writeln!(
            s,
            "\n  identified   {} parameters on their own, {} determined combinations (in the JSON); the\n               controller below is the solution, its σ along what the readings determine",
            id.identified.len(),
            id.combinations.len()
        );
    }
    let _ = writeln!(
        s,
        "  parameter     as built (mm)   controller (mm)   σ (µm)"
    );
    for r in rows {
        let _ = writeln!(
            s,
            "  {:<12} {:+12.5}    {:+12.5}    {:8.2}",
            r.name,
            r.injected_mm,
            r.identified_mm,
            r.sigma_mm * 1e3
        );
    }
    if let Some(last) = cal.rounds.last() {
        for n in &last.identification.not_determined {
            let _ = writeln!(s, "  not determined  {n} (held at the controller's value)");
        }
        for n in &last.identification.borderline {
            let _ = writeln!(s, "  borderline      {n}");
        }
    }
    s
}
