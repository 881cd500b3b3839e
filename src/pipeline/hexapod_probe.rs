//! `twinmill hexapod probe-calibrate` on a loaded hexapod scene: seed 001's two-round
//! calibration from gauge-block / touch-probe readings
//! ([`crate::calibration::hexapod_probe`]), its two figures before and after each round, the
//! parameters identified with σ, what is not determined, and the corrected parameters as a
//! `[deviations]` fragment. Writes nothing.
//!
//! **Invariant:** the same scene and request give the same outcome, bit for bit (the
//! noise from a counter-based generator of the given seed).

use crate::calibration::hexapod_calibrate::{Plan, Procedure};
use crate::calibration::hexapod_dbb_probe::{DbbData, ProbeData, identify_with};
use crate::calibration::hexapod_probe::{
    ProbeCalibration, ProbeIdentification, ProbeOptions, ProbePlan, ProbeReadings, calibrate,
    default_plan,
};
use crate::machine::hexapod::{PARAMETERS, ParameterId};
use crate::math::Real;
use crate::pipeline::dbb::{
    CALIBRATION_NOISE_MM, calibration_workspace, genhexkins_hal, measured_circles, procedure_plan,
};
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
    /// The first round's probe readings (taken through the starting controller) as a
    /// readings file ([`probe_readings_csv`]): what `identify --probe` reads.
    #[serde(skip)]
    pub readings_csv: String,
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
    let readings_csv = cal.rounds.first().map_or(String::new(), |r| {
        probe_readings_csv(
            &default_plan(&scene.controller, &ws),
            &r.readings,
            &[
                format!(
                    "Touch-probe readings of {} by `twinmill hexapod probe-calibrate` (round 1, through {}; σ {} µm, seed {}).",
                    scene.name,
                    scene.controller_label(),
                    options.sigma_mm * 1e3,
                    options.seed
                ),
                "positioning: the tool point's displacement from the commanded point, platform level; pivot: the tip's travel from its level position (mm).".into(),
            ],
        )
    });
    Ok(ProbeOutcome {
        scene: scene.name.clone(),
        calibration: cal,
        parameters,
        fragment,
        readings_csv,
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

/// The columns of a probe readings file.
pub const PROBE_READINGS_COLUMNS: &str =
    "item,point,x_mm,y_mm,z_mm,a_deg,b_deg,read_x_mm,read_y_mm,read_z_mm,sigma_mm";

/// A probe's readings of `plan` as a file: `#` lines of `header`, the column line
/// ([`PROBE_READINGS_COLUMNS`]), then one row a probed pose — `positioning` rows (the
/// commanded point, a = b = 0, the tool point's displacement from it), then `pivot` rows
/// (the fixed point, the swung a, b, the tip's travel from its level position) — each with
/// the probe's σ. Fixed decimals, so the same readings write the same bytes.
pub fn probe_readings_csv(plan: &ProbePlan, readings: &ProbeReadings, header: &[String]) -> String {
    let mut t = String::new();
    for h in header {
        let _ = writeln!(t, "# {h}");
    }
    let _ = writeln!(t, "{PROBE_READINGS_COLUMNS}");
    let row = |t: &mut String, item: &str, k: usize, p: [Real; 3], ab: [Real; 2], r: &[Real; 3]| {
        let _ = writeln!(
            t,
            "{item},{k},{:.6},{:.6},{:.6},{:.6},{:.6},{:.7},{:.7},{:.7},{}",
            p[0], p[1], p[2], ab[0], ab[1], r[0], r[1], r[2], readings.sigma_mm
        );
    };
    for (k, (pose, r)) in plan
        .positioning
        .iter()
        .zip(&readings.positioning_mm)
        .enumerate()
    {
        let p = pose.position;
        row(&mut t, "positioning", k + 1, [p.x, p.y, p.z], [0.0, 0.0], r);
    }
    for (k, (s, rs)) in plan.pivots.iter().zip(&readings.pivot_mm).enumerate() {
        for (ab, r) in s.angles_deg.iter().zip(rs) {
            row(&mut t, "pivot", k + 1, s.point_mm, *ab, r);
        }
    }
    t
}

/// Reads a probe readings file ([`probe_readings_csv`]) of `plan`: every row's item,
/// point, pose (to 1e-6 mm and degrees) in the plan's order, finite readings, one σ > 0
/// throughout. A bad file is one line naming `path`, the line and what is wrong.
pub fn parse_probe_readings(
    text: &str,
    path: &std::path::Path,
    plan: &ProbePlan,
) -> Result<ProbeReadings, String> {
    let at = |line: usize, m: String| format!("{}:{line}: {m}", path.display());
    // The expected rows: item, point, position, angles.
    let mut expected: Vec<(&str, usize, [Real; 3], [Real; 2])> = plan
        .positioning
        .iter()
        .enumerate()
        .map(|(k, p)| {
            let q = p.position;
            ("positioning", k + 1, [q.x, q.y, q.z], [0.0, 0.0])
        })
        .collect();
    for (k, s) in plan.pivots.iter().enumerate() {
        for ab in &s.angles_deg {
            expected.push(("pivot", k + 1, s.point_mm, *ab));
        }
    }
    let mut values: Vec<[Real; 3]> = Vec::with_capacity(expected.len());
    let mut sigma: Option<Real> = None;
    let mut header_seen = false;
    let mut last_line = 0;
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        last_line = line;
        let l = raw.trim();
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        if !header_seen {
            if l != PROBE_READINGS_COLUMNS {
                return Err(at(
                    line,
                    format!("expected the column line `{PROBE_READINGS_COLUMNS}`"),
                ));
            }
            header_seen = true;
            continue;
        }
        let f: Vec<&str> = l.split(',').map(str::trim).collect();
        if f.len() != 11 {
            return Err(at(line, format!("{} fields, expected 11", f.len())));
        }
        let Some(&(item, point, p, ab)) = expected.get(values.len()) else {
            return Err(at(
                line,
                format!("more rows than the plan's {} probed poses", expected.len()),
            ));
        };
        let num = |k: usize| -> Result<Real, String> {
            f[k].parse::<Real>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| {
                    at(
                        line,
                        format!("field {}: `{}` is not a finite number", k + 1, f[k]),
                    )
                })
        };
        if f[0] != item || f[1].parse::<usize>().ok() != Some(point) {
            return Err(at(
                line,
                format!(
                    "`{},{}`, but row {} of the plan is {item} {point}",
                    f[0],
                    f[1],
                    values.len() + 1
                ),
            ));
        }
        let pose = [num(2)?, num(3)?, num(4)?, num(5)?, num(6)?];
        let want = [p[0], p[1], p[2], ab[0], ab[1]];
        if pose.iter().zip(&want).any(|(a, b)| (a - b).abs() > 1e-6) {
            return Err(at(
                line,
                format!(
                    "the pose ({:.6}, {:.6}, {:.6}; a {:.6}°, b {:.6}°) is not the plan's ({:.6}, {:.6}, {:.6}; a {:.6}°, b {:.6}°)",
                    pose[0],
                    pose[1],
                    pose[2],
                    pose[3],
                    pose[4],
                    want[0],
                    want[1],
                    want[2],
                    want[3],
                    want[4]
                ),
            ));
        }
        let s = num(10)?;
        if s <= 0.0 {
            return Err(at(line, format!("σ {s} mm must be positive")));
        }
        match sigma {
            Some(s0) if s0 != s => {
                return Err(at(
                    line,
                    format!("σ {s} mm differs from the file's {s0} mm"),
                ));
            }
            _ => sigma = Some(s),
        }
        values.push([num(7)?, num(8)?, num(9)?]);
    }
    if !header_seen {
        return Err(at(
            last_line.max(1),
            format!("no column line `{PROBE_READINGS_COLUMNS}`"),
        ));
    }
    if values.len() != expected.len() {
        return Err(at(
            last_line,
            format!(
                "{} rows, but the plan probes {} poses",
                values.len(),
                expected.len()
            ),
        ));
    }
    let np = plan.positioning.len();
    let mut rest = values[np..].iter();
    let pivot_mm = plan
        .pivots
        .iter()
        .map(|s| rest.by_ref().take(s.angles_deg.len()).copied().collect())
        .collect();
    Ok(ProbeReadings {
        positioning_mm: values[..np].to_vec(),
        pivot_mm,
        sigma_mm: sigma.unwrap_or(Real::NAN),
    })
}

/// One identification from the bar's trace files and a probe's readings file together.
#[derive(Clone, Debug, Serialize)]
pub struct JointOutcome {
    /// The scene's name.
    pub scene: String,
    /// The procedure of the circles.
    pub procedure: Procedure,
    /// The bar's trace files, one a circle in the plan's order.
    pub dbb_files: Vec<String>,
    /// The probe's readings file.
    pub probe_file: String,
    /// The identification (the 42 parameters, deviations from the controller's).
    pub identification: ProbeIdentification,
    /// The identified controller as a `[controller]` file (deviations from nominal, σ in
    /// comments).
    #[serde(skip)]
    pub fragment: String,
    /// The same controller as LinuxCNC genhexkins' HAL pins ([`genhexkins_hal`]).
    #[serde(skip)]
    pub genhexkins: String,
    /// The bar's and the probe's readings and σ (mm), for the page.
    #[serde(skip)]
    pub instruments: [(usize, Real); 2],
    /// The summary text.
    #[serde(skip)]
    pub summary: String,
}

/// Identifies the scene's machine from the bar's trace `dbb` (one a circle of `plan` or the
/// procedure's fixed plan, σ [`CALIBRATION_NOISE_MM`]) and the probe's readings `probe` of
/// the default probe plan (its σ in the file), both taken through the scene's controller:
/// one identification ([`crate::calibration::hexapod_dbb_probe`]), refused naming the file
/// that does not fit unless the scene accepts misfits.
pub fn identify_dbb_and_probe(
    scene: &HexapodScene,
    procedure: Procedure,
    plan: Option<Plan>,
    dbb: &[(std::path::PathBuf, String)],
    probe: &(std::path::PathBuf, String),
    monte_carlo: Option<usize>,
) -> Result<JointOutcome, HexapodCommandError> {
    let error = |message: String| HexapodCommandError {
        path: scene.path.display().to_string(),
        message,
    };
    let ws = calibration_workspace(scene)?;
    let plan = procedure_plan(scene, procedure, plan, &ws)?;
    let circles = measured_circles(scene, &plan, dbb)?;
    let probe_plan = default_plan(&scene.controller, &ws);
    // The reader's `FILE:LINE: what` as the error's place and message.
    let probed = parse_probe_readings(&probe.1, &probe.0, &probe_plan).map_err(|m| {
        let file = probe.0.display().to_string();
        match m
            .strip_prefix(&format!("{file}:"))
            .and_then(|r| r.split_once(": "))
        {
            Some((line, what)) => HexapodCommandError {
                path: format!("{file}:{line}"),
                message: what.to_string(),
            },
            None => HexapodCommandError {
                path: file,
                message: m,
            },
        }
    })?;
    let files: Vec<String> = dbb.iter().map(|(p, _)| p.display().to_string()).collect();
    let probe_file = probe.0.display().to_string();
    let id = identify_with(
        &scene.controller,
        Some(DbbData {
            plan: &plan,
            readings: &circles,
            files: &files,
            sigma_mm: CALIBRATION_NOISE_MM,
        }),
        Some(ProbeData {
            plan: &probe_plan,
            readings: &probed,
            file: &probe_file,
        }),
        scene.accept_misfit,
        monte_carlo.unwrap_or(0),
    )
    .map_err(|e| error(e.to_string()))?;
    let pn = scene.nominal.parameters();
    let title = format!(
        "The calibrated controller of {} identified by `twinmill identify --readings … --probe {probe_file}`",
        scene.name
    );
    let mut fragment = format!(
        "# {title}\n\
         # ({} circles, {}, and the touch probe's readings) as deviations from nominal (mm), for\n\
         # --controller; σ along what the readings determine. Directions they do not determine keep\n\
         # the controller's values.\n[controller]\n",
        plan.circles.len(),
        plan.procedure.name()
    );
    let identified = scene
        .controller
        .with_parameters(&id.parameters)
        .map_err(|e| error(format!("the identified controller: {e}")))?;
    let genhexkins = genhexkins_hal(&identified, &[title]);
    for k in ParameterId::all() {
        let i = k.index();
        let _ = writeln!(
            fragment,
            "{} = {:.7}   # σ {:.7}",
            k.name(),
            id.parameters[i] - pn[i],
            id.parameter_sigma[i]
        );
    }
    let mut summary = id
        .fit
        .accepted_line()
        .map_or(String::new(), |w| format!("twinmill: {w}\n"));
    let _ = writeln!(
        summary,
        "twinmill: identify {} from {} measured circles ({}) and the probe's {}\n  readings      {} ({} bar lengths at σ {:.2} µm, {} probe readings at σ {:.2} µm)\n  determined    rank {} of {PARAMETERS}; {} parameters on their own, {} combinations",
        scene.name,
        plan.circles.len(),
        plan.procedure.name(),
        probe_file,
        id.readings,
        plan.readings(),
        CALIBRATION_NOISE_MM * 1e3,
        probe_plan.readings(),
        probed.sigma_mm * 1e3,
        id.rank,
        id.identified.len(),
        id.combinations.len()
    );
    for n in &id.not_determined {
        let _ = writeln!(
            summary,
            "  not determined  {n} (held at the controller's value)"
        );
    }
    for n in &id.borderline {
        let _ = writeln!(summary, "  borderline      {n}");
    }
    let _ = writeln!(summary, "  fit           {}", id.fit.describe());
    let mc = id.parameter_spread.is_some();
    let _ = writeln!(
        summary,
        "  parameter     controller (mm)   σ (µm){}",
        if mc { "   Monte Carlo (µm)" } else { "" }
    );
    for k in ParameterId::all() {
        let i = k.index();
        let spread = id
            .parameter_spread
            .map_or(String::new(), |s| format!("   {:8.3}", s[i] * 1e3));
        let _ = writeln!(
            summary,
            "  {:<12} {:+12.5}    {:8.3}{spread}",
            k.name(),
            id.parameters[i] - pn[i],
            id.parameter_sigma[i] * 1e3
        );
    }
    if let Some(n) = monte_carlo.filter(|_| mc) {
        let _ = writeln!(
            summary,
            "  monte carlo   {n} trials at the solution over the stated σ of both instruments"
        );
    }
    Ok(JointOutcome {
        scene: scene.name.clone(),
        procedure: plan.procedure,
        dbb_files: files,
        probe_file,
        identification: id,
        fragment,
        genhexkins,
        instruments: [
            (plan.readings(), CALIBRATION_NOISE_MM),
            (probe_plan.readings(), probed.sigma_mm),
        ],
        summary,
    })
}

/// `identify --readings … --probe FILE`'s page: the readings of both instruments with their
/// files and σ, the identifiability (rank of the 42 parameters, the singular values of the
/// scaled, whitened Jacobian, what is not determined, borderline), the goodness of fit file
/// by file, and the controller's parameters with σ.
pub fn joint_page(o: &JointOutcome) -> String {
    use crate::report::html::{Section, render_page};
    use crate::report::pages as page;
    let id = &o.identification;
    let [(bar_n, bar_s), (probe_n, probe_s)] = o.instruments;
    let mut files: Vec<Vec<String>> = o
        .dbb_files
        .iter()
        .enumerate()
        .map(|(k, f)| vec![format!("double ball bar, circle {}", k + 1), f.clone()])
        .collect();
    files.push(vec!["touch probe".into(), o.probe_file.clone()]);
    let threshold = 1.0 / crate::calibration::calibrate::DETERMINED_FRACTION;
    let mut sections = vec![
        Section {
            heading: "Readings".into(),
            intro: "Both instruments' readings, identified together in one problem: each reading weighed by its instrument's standard uncertainty σ.".into(),
            columns: ["instrument", "readings", "σ (µm)"].map(String::from).to_vec(),
            rows: vec![
                vec!["double ball bar".into(), bar_n.to_string(), format!("{:.4}", bar_s * 1e3)],
                vec!["touch probe".into(), probe_n.to_string(), format!("{:.4}", probe_s * 1e3)],
            ],
        },
        Section {
            heading: "Files read".into(),
            intro: "One bar trace per circle of the plan, in its order, and the probe's readings.".into(),
            columns: vec!["instrument".into(), "file".into()],
            rows: files,
        },
    ];
    let mut sv = page::singular_value_rows(&id.singular_values, threshold);
    sv.push(vec![
        "rank".into(),
        format!("{} of {PARAMETERS}", id.rank),
        format!(
            "{} parameters on their own, {} determined combinations",
            id.identified.len(),
            id.combinations.len()
        ),
    ]);
    sections.push(Section {
        heading: "Identifiability".into(),
        intro: format!("Singular values of the Jacobian of both instruments' readings, each parameter scaled by its realistic magnitude and each reading whitened by its σ, the jig-free table balls projected out; a direction is determined from {threshold} (σ below a tenth of its magnitude)."),
        columns: vec!["#".into(), "singular value".into(), "".into()],
        rows: sv,
    });
    sections.extend(page::list_section(
        "Not determined",
        "Directions neither instrument determines, held at the controller's values.",
        &id.not_determined,
    ));
    sections.extend(page::list_section(
        "Borderline",
        "Directions near the threshold of determination: other readings may decide them the other way.",
        &id.borderline,
    ));
    sections.push(page::fit_section(&id.fit));
    let estimate_rows = |es: &[crate::calibration::hexapod_probe::ProbeEstimate]| {
        es.iter()
            .map(|e| {
                vec![
                    e.name.clone(),
                    format!("{:+.6}", e.value_mm),
                    format!("{:.4}", e.sigma_mm * 1e3),
                ]
            })
            .collect::<Vec<_>>()
    };
    let cols = ["parameter", "from the controller (mm)", "σ (µm)"]
        .map(String::from)
        .to_vec();
    sections.push(Section {
        heading: "Identified parameters".into(),
        intro: "Each parameter identified on its own: its deviation from the controller that took the readings, with its standard uncertainty σ.".into(),
        columns: cols.clone(),
        rows: estimate_rows(&id.identified),
    });
    if !id.combinations.is_empty() {
        sections.push(Section {
            heading: "Determined combinations".into(),
            intro:
                "Combinations the readings determine though their members are not determined alone."
                    .into(),
            columns: cols,
            rows: estimate_rows(&id.combinations),
        });
    }
    let plots = page::spectrum_plot(
        &id.singular_values,
        Some(threshold),
        "Singular values of the identification's Jacobian (both instruments): dark bars are determined directions; the platform's rotations about the tool point lie below the line.",
    )
    .into_iter()
    .collect();
    render_page(&page::instrument_page(
        format!(
            "twinmill identify --readings … --probe {}: {} ({})",
            o.probe_file,
            o.scene,
            o.procedure.name()
        ),
        o.summary.clone(),
        sections,
        plots,
        page::json(o),
    ))
}
