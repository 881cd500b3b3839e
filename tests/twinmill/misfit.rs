//! A misfit is refused, not calibrated: every identification path — the 0°/180° faces of
//! `run`, general identification from faces (`identify`), the rotary axes' location from
//! the ball sensor and the probe (`measure`), the hexapod's DBB calibration (`calibrate`,
//! on the twin and from `--readings`) — refuses data that cannot come from its model at the
//! stated noise, in one line naming the statistic and the files, circles, faces or samples
//! out of line, and writes nothing; `--accept-misfit` keeps the result and says so first.
//! Good data at the stated noise pass in all but a thousandth of seeded trials. And measured
//! readings never meet the scene's simulated machine.

use super::{
    HEXAPOD_CENTRE, Sandbox, dbb_readings, draw, hexapod_centre as centre, inject, mounting,
    rotary_sweeps, setup, terms, trunnion_chain,
};
use std::path::{Path, PathBuf};
use twinmill::calibration::calibrate::{
    Feature, Model, Registration, ball_features, identify, synthetic_plane_feature,
};
use twinmill::calibration::goodness::{REFUSE_P, ScanNoise, face_rms_check};
use twinmill::calibration::hexapod_calibrate::{
    DEFAULT_POINTS, Plan, Procedure, calibrate, default_plan,
};
use twinmill::calibration::hexapod_design::design;
use twinmill::cutting::tool::{Tool, ToolKind};
use twinmill::machine::hexapod::Hexapod;
use twinmill::math::{CounterRng, Point3, Real, UnitVector3, Vector3};
use twinmill::metrology::ball_sensor::BallSensor;
use twinmill::metrology::fit::{Plane, RobustRule, fit_plane_robust};
use twinmill::metrology::hexapod_dbb::{DbbInstrument, measure};
use twinmill::metrology::rotary_test::{probe_test, sensor_test};
use twinmill::pipeline::dbb::{CALIBRATION_NOISE_MM, trial_machine};
use twinmill::pipeline::{RotaryInstrument, RotaryRequest, default_setup, rotary_test};
use twinmill::scene::HexapodScene;
use twinmill::scene::Scene;

const ROOT: &str = env!("CARGO_MANIFEST_DIR");

fn centre_path() -> PathBuf {
    PathBuf::from(HEXAPOD_CENTRE)
}

/// The circles of `plan` measured on `actual` with the DBB's noise (seed `seed`), each
/// written as `twinmill ballbar --out` writes a trace: with `header`, the circle it ran
/// recorded in its `#` lines; without, a bare `# measured` (a trace from another program).
fn write_traces(
    sb: &Sandbox,
    s: &HexapodScene,
    actual: &Hexapod,
    plan: &Plan,
    seed: u64,
    prefix: &str,
    header: bool,
) -> Vec<String> {
    plan.circles
        .iter()
        .enumerate()
        .map(|(j, c)| {
            let inst = DbbInstrument {
                mount_mm: Vector3::zeros(),
                noise_sigma_mm: CALIBRATION_NOISE_MM,
                seed,
                stream: (j as u64) << 32,
            };
            let m = measure(&s.nominal, actual, c, &inst).expect("measures");
            let comments = if header {
                vec![format!("twinmill ballbar on {}", s.name), c.describe()]
            } else {
                vec!["measured".to_string()]
            };
            let name = format!("{prefix}{}.csv", j + 1);
            std::fs::write(sb.dir.join(&name), m.csv(&comments)).expect("writes");
            name
        })
        .collect()
}

fn calibrate_readings(
    sb: &Sandbox,
    scene: &Path,
    procedure: &str,
    files: &[String],
    extra: &[&str],
) -> (i32, String, String) {
    let list = files.join(",");
    let mut args = vec![
        "calibrate",
        scene.to_str().expect("utf-8"),
        "--procedure",
        procedure,
        "--readings",
        &list,
    ];
    args.extend(extra);
    sb.run(&args)
}

/// A refusal: non-zero exit, one line on stderr naming the statistic, no panic, nothing on
/// stdout.
fn assert_refused(code: i32, out: &str, err: &str, what: &str) {
    assert_ne!(code, 0, "{what}: accepted\n{out}");
    assert!(!err.contains("panicked"), "{what}: {err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{what}: {err}");
    assert!(out.is_empty(), "{what}: {out}");
}

/// The χ² quantile at upper-tail probability 1e-6 by the Wilson–Hilferty cube (an
/// approximation of the test's own, independent of the library's incomplete gamma
/// function): `k (1 − 2/(9k) + z √(2/(9k)))³`, z = 4.7534 the normal's 1e-6 quantile. Its
/// relative error is below 0.22/k at that tail (1 % at 20 dof, 0.02 % at 600).
fn limit_at_one_in_a_million(dof: Real) -> Real {
    wilson_hilferty(dof, 4.753_424_308_822_899)
}

/// The χ² quantile of `dof` degrees of freedom where the normal's is `z` (Wilson–Hilferty).
fn wilson_hilferty(dof: Real, z: Real) -> Real {
    let a = 2.0 / (9.0 * dof);
    dof * (1.0 - a + z * a.sqrt()).powi(3)
}

/// A fit's limit is the χ² its degrees of freedom reach once in a million.
fn assert_limit(limit: Real, dof: Real, what: &str) {
    let want = limit_at_one_in_a_million(dof);
    assert!(
        (limit / want - 1.0).abs() < 0.3 / dof + 1e-3,
        "{what}: limit {limit} for {dof} dof, the 1e-6 quantile is {want}"
    );
}

/// The statistic of a refusal's line: `χ² C for D dof (p P; at the stated noise χ² stays
/// below L)`, checked: C beyond L, P below 1e-6, L the 1e-6 quantile of D dof.
fn assert_refused_statistic(err: &str, what: &str) -> (Real, Real) {
    let num = |s: &str| -> Real {
        s.trim()
            .parse()
            .unwrap_or_else(|_| panic!("{what}: a number, not {s:?}: {err}"))
    };
    let after = |key: &str| {
        err.split_once(key)
            .unwrap_or_else(|| panic!("{what}: no {key:?} in {err}"))
            .1
    };
    let chi2 = num(after("χ² ").split(" for ").next().expect("χ²"));
    let dof = num(after(" for ").split(" dof").next().expect("dof"));
    let p = num(after("(p ").split(';').next().expect("p"));
    let limit = num(after("stays below ").split(')').next().expect("limit"));
    assert!(chi2 > limit && p < 1e-6, "{what}: {err}");
    assert_limit(limit, dof, what);
    (chi2, dof)
}

/// Good fits over many trials: each limit is the 1e-6 quantile of its dof, and the pooled
/// χ² over the pooled dof is 1 within five of its standard deviations (√(2/Σdof)), so a
/// σ stated 20 % off (a ratio of 0.69 or 1.44) or a misweighted residual cannot pass.
fn assert_pooled_chi2(fits: &[(Real, Real, Real)], what: &str) {
    let (mut chi2, mut dof) = (0.0, 0.0);
    for &(c, d, l) in fits {
        assert_limit(l, d, what);
        chi2 += c;
        dof += d;
    }
    let sd = (2.0 / dof).sqrt();
    assert!(
        (chi2 / dof - 1.0).abs() < 5.0 * sd,
        "{what}: pooled χ²/dof {} over {} trials (1 ± {:.4} expected)",
        chi2 / dof,
        fits.len(),
        5.0 * sd
    );
}

/// The whole χ², its dof and limit of a fit that has them.
fn statistic(fit: &twinmill::calibration::goodness::FitCheck) -> (Real, Real, Real) {
    (fit.chi2.expect("χ²"), fit.dof, fit.limit.expect("a limit"))
}

#[test]
fn ball_plate_readings_with_two_files_swapped_are_refused_naming_them() {
    let sb = Sandbox::new("misfit-swapped");
    let s = centre();
    let plan = default_plan(
        Procedure::BallPlate,
        &s.workspace.expect("ws"),
        DEFAULT_POINTS,
    );
    let files = write_traces(&sb, &s, &s.actual, &plan, 21, "plate-", false);
    // In order: accepted.
    let (code, _, err) = calibrate_readings(&sb, &centre_path(), "ball-plate", &files, &[]);
    assert_eq!(code, 0, "{err}");
    // Circles 2 and 5 swapped (same layout: the files alone cannot tell).
    let mut swapped = files.clone();
    swapped.swap(1, 4);
    let corrected = ["--corrected", "corrected.toml"];
    let (code, out, err) =
        calibrate_readings(&sb, &centre_path(), "ball-plate", &swapped, &corrected);
    assert_refused(code, &out, &err, "swapped");
    assert!(err.contains("χ²") && err.contains("dof"), "{err}");
    // The two swapped files are the first named.
    let named = err
        .split("out of line, worst first: ")
        .nth(1)
        .unwrap_or_else(|| panic!("names the parts: {err}"));
    let first_two: Vec<&str> = named.split("), ").take(2).collect();
    for f in ["plate-2.csv", "plate-5.csv"] {
        assert!(
            first_two.iter().any(|p| p.contains(f)),
            "{f} not first in: {err}"
        );
    }
    assert!(
        !sb.dir.join("corrected.toml").exists(),
        "a refusal writes nothing"
    );
    // Accepted on request: the result is written, and says so first.
    let mut extra = corrected.to_vec();
    extra.extend(["--accept-misfit", "--json"]);
    let (code, out, err) = calibrate_readings(&sb, &centre_path(), "ball-plate", &swapped, &extra);
    assert_eq!(code, 0, "{err}");
    assert!(
        out.starts_with("{\n  \"warning\": \"MISFIT ACCEPTED"),
        "{out:.200}"
    );
    let v: serde_json::Value = serde_json::from_str(&out).expect("json");
    assert_eq!(v["calibration"]["fit"]["misfit_accepted"], true);
    assert!(sb.dir.join("corrected.toml").exists());
    let (code, out, _) = calibrate_readings(
        &sb,
        &centre_path(),
        "ball-plate",
        &swapped,
        &["--accept-misfit"],
    );
    assert_eq!(code, 0);
    assert!(
        out.lines()
            .next()
            .is_some_and(|l| l.contains("MISFIT ACCEPTED")),
        "{out}"
    );
}

#[test]
fn a_trace_whose_header_records_another_circle_is_refused_before_fitting() {
    let sb = Sandbox::new("misfit-header");
    let s = centre();
    let plan = default_plan(
        Procedure::BallPlate,
        &s.workspace.expect("ws"),
        DEFAULT_POINTS,
    );
    let mut files = write_traces(&sb, &s, &s.actual, &plan, 22, "c", true);
    let (code, _, err) = calibrate_readings(&sb, &centre_path(), "ball-plate", &files, &[]);
    assert_eq!(code, 0, "headers of the plan's own circles: {err}");
    files.swap(1, 4);
    let (code, out, err) = calibrate_readings(&sb, &centre_path(), "ball-plate", &files, &[]);
    assert_refused(code, &out, &err, "header");
    // The first file out of place, its header's line, and what differs.
    assert!(err.contains("c5.csv:2:"), "{err}");
    assert!(err.contains("circle 2 of the plan"), "{err}");
    assert!(err.contains("platform a"), "{err}");
}

#[test]
fn the_designed_plans_traces_given_to_the_fixed_plan_are_refused() {
    let sb = Sandbox::new("misfit-designed");
    let s = centre();
    let ws = s.workspace.expect("ws");
    let fixed = default_plan(Procedure::BallPlate, &ws, DEFAULT_POINTS);
    let d = design(
        &s.nominal,
        Procedure::BallPlate,
        &ws,
        7,
        DEFAULT_POINTS,
        CALIBRATION_NOISE_MM,
        &fixed,
    )
    .expect("designs");
    assert_ne!(
        d.plan.circles, fixed.circles,
        "the designed plan is another"
    );
    let files = write_traces(&sb, &s, &s.actual, &d.plan, 23, "designed-", false);
    let (code, out, err) = calibrate_readings(&sb, &centre_path(), "ball-plate", &files, &[]);
    assert_refused(code, &out, &err, "another plan's files");
    assert!(err.contains("designed-"), "{err}");
    // The statistic's degrees of freedom: the fixed plan's samples less its unknowns (at
    // most the 42 joint and length deviations and three coordinates of each circle's ball).
    let (_, dof) = assert_refused_statistic(&err, "another plan's files");
    let samples: usize = fixed.circles.iter().map(|c| c.angles().len()).sum();
    let unknowns = 42 + 3 * fixed.circles.len();
    assert!(
        dof <= samples as Real && dof >= (samples - unknowns) as Real,
        "{dof} dof for {samples} samples: {err}"
    );
    // With the headers `ballbar --out` writes, the first file is refused before any fit,
    // naming its header's line and the plan's circle it should have been.
    let files = write_traces(&sb, &s, &s.actual, &d.plan, 23, "headed-", true);
    let (code, out, err) = calibrate_readings(&sb, &centre_path(), "ball-plate", &files, &[]);
    assert_refused(code, &out, &err, "another plan's headed files");
    assert!(
        err.contains(
            "headed-1.csv:2: the trace's header records another circle than circle 1 of the plan"
        ),
        "{err}"
    );
    assert!(!err.contains("χ²"), "refused before fitting: {err}");
}

#[test]
fn jig_free_files_in_reverse_order_are_refused() {
    let sb = Sandbox::new("misfit-reversed");
    let s = centre();
    let plan = default_plan(
        Procedure::JigFree,
        &s.workspace.expect("ws"),
        DEFAULT_POINTS,
    );
    let mut files = write_traces(&sb, &s, &s.actual, &plan, 24, "j", false);
    let (code, _, err) = calibrate_readings(&sb, &centre_path(), "jig-free", &files, &[]);
    assert_eq!(code, 0, "in order: {err}");
    files.reverse();
    let (code, out, err) = calibrate_readings(
        &sb,
        &centre_path(),
        "jig-free",
        &files,
        &["--corrected", "c.toml"],
    );
    assert_refused(code, &out, &err, "reversed");
    assert!(err.contains(".csv"), "{err}");
    assert_refused_statistic(&err, "reversed");
    assert!(!sb.dir.join("c.toml").exists());
    // Headed traces reversed: the first file holds the last circle, named from its header.
    let mut files = write_traces(&sb, &s, &s.actual, &plan, 24, "h", true);
    files.reverse();
    let last = plan.circles.len();
    let (code, out, err) = calibrate_readings(&sb, &centre_path(), "jig-free", &files, &[]);
    assert_refused(code, &out, &err, "reversed headed");
    assert!(
        err.contains(&format!(
            "h{last}.csv:2: the trace's header records another circle than circle 1 of the plan"
        )),
        "{err}"
    );
}

/// Good readings at the stated σ: 1,000 seeded trials of the ball plate (36 samples a
/// circle, each trial its own machine and noise) are accepted in all but one at most (the
/// threshold refuses one good fit in a million).
#[test]
fn good_dbb_readings_are_accepted_in_999_of_1000_trials() {
    let s = centre();
    let plan = default_plan(Procedure::BallPlate, &s.workspace.expect("ws"), 36);
    let mut refused = Vec::new();
    let mut stats = Vec::new();
    for t in 0..1000u64 {
        let actual = trial_machine(&s, 5000 + t).expect("machine");
        let readings = dbb_readings(
            &s.nominal,
            &actual,
            &plan.circles,
            CALIBRATION_NOISE_MM,
            9000 + t,
            |_| Vector3::zeros(),
        );
        let cal =
            calibrate(&s.nominal, &actual, &plan, &readings, CALIBRATION_NOISE_MM).expect("solves");
        if !cal.fit.fits {
            refused.push((t, cal.fit.describe()));
        }
        stats.push(statistic(&cal.fit));
    }
    assert_pooled_chi2(&stats, "ball plate");
    assert!(
        refused.len() <= 1,
        "{} of 1000 refused: {refused:?}",
        refused.len()
    );
}

/// `calibrate --readings` without a jig: the printed correction, the parameters and the
/// fragment come from the readings (and the scene's CMM platform joints) alone, the same
/// whether the scene's simulated base-joint and strut deviations are as written, removed or
/// ten times larger.
#[test]
fn jig_free_readings_do_not_depend_on_the_scene_s_simulated_deviations() {
    let sb = Sandbox::new("misfit-jig-free-leak");
    let s = centre();
    let plan = default_plan(
        Procedure::JigFree,
        &s.workspace.expect("ws"),
        DEFAULT_POINTS,
    );
    let files = write_traces(&sb, &s, &s.actual, &plan, 25, "m", false);
    let text = std::fs::read_to_string(centre_path()).expect("reads");
    // Base joints (bx_i, by_i, bz_i) and reference lengths (l0_i) are what the calibration
    // identifies; the platform joints (ax_i…) are the CMM's and stay.
    let simulated = |l: &str| {
        l.split_once('=').is_some_and(|(k, _)| {
            let k = k.trim();
            let digit = k.len() == 4 && k.as_bytes()[3].is_ascii_digit();
            digit
                && (k.starts_with("bx_")
                    || k.starts_with("by_")
                    || k.starts_with("bz_")
                    || k.starts_with("l0_"))
        })
    };
    let variant = |name: &str, f: &dyn Fn(&str) -> Option<String>| {
        let out: Vec<String> = text
            .lines()
            .filter_map(|l| if simulated(l) { f(l) } else { Some(l.into()) })
            .collect();
        sb.write(name, out.join("\n").as_bytes())
    };
    let removed = variant("removed.toml", &|_| None);
    let tenfold = variant("tenfold.toml", &|l| {
        let (k, v) = l.split_once('=')?;
        let v: Real = v.split('#').next()?.trim().parse().ok()?;
        Some(format!("{k}= {}", 10.0 * v))
    });
    let as_is = sb.write("as-is.toml", text.as_bytes());
    let mut outputs = Vec::new();
    for scene in [&as_is, &removed, &tenfold] {
        let frag = format!("{}.frag", scene.display());
        let (code, out, err) = calibrate_readings(
            &sb,
            scene,
            "jig-free",
            &files,
            &["--json", "--corrected", &frag],
        );
        assert_eq!(code, 0, "{}: {err}", scene.display());
        let v: serde_json::Value = serde_json::from_str(&out).expect("json");
        let fragment = std::fs::read_to_string(&frag).expect("fragment");
        // The fragment's lines after its header (which names the scene file's name).
        let body: Vec<String> = fragment
            .lines()
            .filter(|l| !l.starts_with('#'))
            .map(String::from)
            .collect();
        outputs.push((
            v["predicted_correction"].clone(),
            v["calibration"]["estimates"].clone(),
            body,
        ));
    }
    assert!(
        outputs[0].0["position_mm"].as_f64().expect("position") > 0.05,
        "{:?}",
        outputs[0].0
    );
    for (k, o) in outputs.iter().enumerate().skip(1) {
        assert_eq!(
            o, &outputs[0],
            "variant {k} differs from the scene as written"
        );
    }
}

// ---------------------------------------------------------------------------------------
// Rotary axes.

fn trunnion() -> Scene {
    Scene::load(&Path::new(ROOT).join("scenes/trunnion-ac.toml")).expect("trunnion loads")
}

fn request(instrument: RotaryInstrument) -> RotaryRequest {
    RotaryRequest {
        instrument,
        sweeps: Vec::new(),
        setup: default_setup(3),
        identify: Some(Vec::new()),
    }
}

fn sensor() -> RotaryInstrument {
    let mut sensor = BallSensor::seed003(8.0);
    sensor.accuracy_mm = 0.5e-3;
    RotaryInstrument::BallSensor {
        sensor,
        height_mm: 1.0,
    }
}

/// A machine with an X–Y squareness its identification does not model (the moving chain
/// has it, the model the controller and the identification start from does not): the ball
/// sensor and the probe both refuse, naming the statistic and the samples out of line; on
/// request the report keeps the result and says so first.
#[test]
fn a_rotary_test_the_model_cannot_explain_is_refused_naming_the_samples() {
    let mut scene = trunnion();
    scene
        .serial_mut()
        .expect("a serial machine")
        .chain
        .apply_iso_term("EC0XY", 40e-6)
        .expect("a squareness of the trunnion");
    for instrument in [sensor(), RotaryInstrument::Probe { sigma_mm: 0.5e-3 }] {
        let Err(err) = rotary_test(&scene, &request(instrument)) else {
            panic!("a squareness the model lacks was accepted");
        };
        let err = err.to_string();
        assert_eq!(err.lines().count(), 1, "{err}");
        assert!(err.contains("χ²") && err.contains("dof"), "{err}");
        assert!(err.contains("sweep "), "names samples: {err}");
        assert!(err.contains("--accept-misfit"), "{err}");
        let mut accepting = scene.clone();
        accepting.accept_misfit = true;
        let out = rotary_test(&accepting, &request(instrument)).expect("accepted on request");
        let json = serde_json::to_string(&out.report).expect("json");
        assert!(json.starts_with("{\"warning\":"), "{json:.80}");
        assert!(
            out.report
                .warning
                .as_deref()
                .is_some_and(|w| w.starts_with("MISFIT ACCEPTED"))
        );
    }
    // Without the squareness the same test fits.
    let out = rotary_test(&trunnion(), &request(sensor())).expect("fits");
    assert!(out.report.warning.is_none());
    let id = out.report.identification.expect("identified");
    assert!(id.fit.fits, "{}", id.fit.describe());
}

/// 1,000 seeded trials of each instrument on machines with random location errors
/// (offsets ±50 µm, tilts ±100 µrad, the sensor's point mounted ±0.2 mm off): all but one
/// at most fit.
#[test]
fn good_rotary_tests_are_accepted_in_999_of_1000_trials() {
    let nominal = trunnion_chain();
    let (names, terms) = terms(&nominal);
    let tool = Tool::try_new(ToolKind::Flat, 6.0, 20.0).expect("tool");
    let sensor = BallSensor::seed003(8.0);
    let rng = CounterRng::new(26);
    for probe in [false, true] {
        let mut refused = Vec::new();
        let mut stats = Vec::new();
        for t in 0..1000u64 {
            let actual = inject(&nominal, &names, &draw(&rng, t, &names));
            let setup = setup(77_000 + t, mounting(&rng, t));
            let samples = if probe {
                probe_test(&actual, 0.5e-3, &setup, &rotary_sweeps())
            } else {
                sensor_test(&actual, &nominal, &sensor, 1.0, &setup, &rotary_sweeps())
            }
            .expect("measured");
            let feats = ball_features(&samples, Vector3::zeros(), 0);
            let model = Model {
                chain: &nominal,
                ids: &[],
                iso_terms: &terms,
                tool: &tool,
                features: &feats,
                registration: Registration::Workpiece,
            };
            let r = identify(&model).expect("identifies");
            if !r.fit.fits {
                refused.push((t, r.fit.describe()));
            }
            stats.push(statistic(&r.fit));
        }
        assert_pooled_chi2(&stats, if probe { "probe" } else { "ball sensor" });
        assert!(
            refused.len() <= 1,
            "probe {probe}: {} of 1000 refused: {refused:?}",
            refused.len()
        );
    }
}

// ---------------------------------------------------------------------------------------
// Faces.

/// The scene of `studies/mdx50-nine.toml` (twelve faces of six shoulder cuts, the nine
/// deviations of seed 002) and its program.
fn nine() -> (Scene, twinmill::nc::Program) {
    let s = Scene::load(&Path::new(ROOT).join("studies/mdx50-nine.toml")).expect("loads");
    let p = s.load_program().expect("parses");
    (s, p)
}

/// 1,000 seeded trials of general identification from the twelve faces, each measured as
/// the chain with random deviations predicts it plus Gaussian noise at the faces' stated
/// offset and slope σ: all but one at most fit.
#[test]
fn good_faces_are_accepted_in_999_of_1000_trials() {
    let (scene, program) = nine();
    let model = scene.chain().nominal();
    let ids: Vec<_> = scene
        .parameters
        .iter()
        .map(|n| model.deviation_id(n).expect("known"))
        .collect();
    let (sigma_off, sigma_slope) = (0.5e-3, [2e-5, 1e-4]);
    let rng = CounterRng::new(27);
    let mut refused = Vec::new();
    let mut stats = Vec::new();
    for t in 0..1000u64 {
        let mut truth = model.clone();
        for (k, id) in ids.iter().enumerate() {
            let u = 2.0 * rng.uniform(t, k as u64) - 1.0;
            let size = if model.deviation_name(*id).starts_with('d') {
                0.2
            } else {
                2e-4
            };
            truth.set_deviation(*id, size * u);
        }
        let feats: Vec<Feature> = scene
            .faces
            .iter()
            .enumerate()
            .map(|(i, spec)| {
                let cut = program
                    .moves
                    .iter()
                    .find(|m| m.line == spec.line)
                    .expect("the face's cut");
                let mut f = synthetic_plane_feature(
                    spec,
                    cut,
                    &truth,
                    &model,
                    &scene.tool,
                    &scene.stock_box,
                    sigma_off,
                    sigma_slope,
                    (-2.0, 2.0),
                )
                .expect("a face");
                // Noise: the offset along the normal, the two slopes along the basis.
                let z = |k: u64| rng.normal(1_000_000 * (t + 1) + 3 * i as u64 + k);
                let n = f.plane.normal.into_inner();
                let tilted = n
                    + f.basis[0].into_inner() * (sigma_slope[0] * z(1))
                    + f.basis[1].into_inner() * (sigma_slope[1] * z(2));
                let centroid = f.centroid + n * (sigma_off * z(0));
                f.plane = Plane::through(&centroid, UnitVector3::new_normalize(tilted));
                f.centroid = centroid;
                Feature::Plane(f)
            })
            .collect();
        let m = Model {
            chain: &model,
            ids: &ids,
            iso_terms: &[],
            tool: &scene.tool,
            features: &feats,
            registration: Registration::Estimate,
        };
        let r = identify(&m).expect("identifies");
        if !r.fit.fits {
            refused.push((t, r.fit.describe()));
        }
        stats.push(statistic(&r.fit));
    }
    assert_pooled_chi2(&stats, "faces");
    assert!(
        refused.len() <= 1,
        "{} of 1000 refused: {refused:?}",
        refused.len()
    );
}

/// A plane's points with range noise along a viewing ray 30° off the normal, fitted as a
/// face is: the RMS check against the scanner's σ passes all but one of 1,000 trials, and
/// refuses a face whose points scatter 10 % more than the scanner's σ across it.
#[test]
fn good_face_points_pass_the_rms_check_in_999_of_1000_trials() {
    let sigma = 0.025;
    let ray = Vector3::new(0.5, 0.0, 3f64.sqrt() / 2.0);
    let noise = ScanNoise {
        sigma_mm: sigma,
        views: 1,
        translation_sigma_mm: 0.0,
        rotation_sigma_rad: 0.0,
        lever_mm: 0.0,
    };
    let robust = RobustRule {
        k_sigma: 3.0,
        max_iterations: 10,
    };
    let grid = |t: u64, along: Vector3, scale: Real| -> Vec<Point3> {
        let rng = CounterRng::new(28 + t);
        (0..4000u64)
            .map(|k| {
                let (u, v) = ((k % 80) as Real * 0.2, (k / 80) as Real * 0.2);
                Point3::new(u, v, 0.0) + along * (scale * rng.normal(k))
            })
            .collect()
    };
    let checked = |pts: &[Point3]| {
        let fit = fit_plane_robust(pts, &robust).expect("a plane");
        let c = face_rms_check("face", fit.rms_mm, fit.n_used, 1.0, &noise, REFUSE_P);
        (c, fit.n_used)
    };
    let check = |pts: &[Point3]| checked(pts).0;
    let refused = (0..1000u64)
        .filter(|&t| check(&grid(t, ray, sigma)).out_of_line)
        .count();
    assert!(refused <= 1, "{refused} of 1000 good faces refused");
    // Along the normal at the scanner's σ: n·RMS²/σ² is χ² with n − 3 dof (a little less
    // after the 3σ clipping), held at its quantile 5e-7 (half of 1e-6: the views' share
    // takes the other half) — normal quantile z = 4.8916 — so the RMS limit is
    // σ·√(q/n) in closed form, and 1,000 such faces are refused once at most.
    let mut refused = 0;
    for t in 0..1000u64 {
        let (c, n) = checked(&grid(t, Vector3::z(), sigma));
        refused += usize::from(c.out_of_line);
        if t < 10 {
            let q = wilson_hilferty((n - 3) as Real, 4.891_638_475_698_85);
            let want = sigma * (q / n as Real).sqrt();
            assert!(
                (c.limit / want - 1.0).abs() < 1e-3,
                "RMS limit {} for {n} points at σ {sigma}: {want} in closed form",
                c.limit
            );
        }
    }
    assert!(refused <= 1, "{refused} of 1000 faces at σ refused");
    // Across the face, 10 % above the scanner's σ: refused.
    let too_rough = (0..20u64)
        .filter(|&t| check(&grid(t, Vector3::z(), 1.1 * sigma)).out_of_line)
        .count();
    assert!(too_rough >= 19, "{too_rough} of 20 rough faces refused");
}

/// The 0°/180° experiment with its first face re-cut 0.3 mm deeper (into the material)
/// over part of it: the
/// face is two planes, its points scatter far beyond the scanner's noise, and `run`
/// refuses, naming the face and its NC line, writing nothing.
#[test]
fn run_refuses_a_face_that_is_not_one_plane() {
    let sb = Sandbox::new("misfit-run");
    let scene = std::fs::read_to_string(Path::new(ROOT).join("scenes/mdx50-step.toml"))
        .expect("scene")
        .replace("program = \"mdx50-step.ngc\"", "program = \"recut.ngc\"");
    sb.write("step.toml", scene.as_bytes());
    let program = std::fs::read_to_string(Path::new(ROOT).join("scenes/mdx50-step.ngc"))
        .expect("program")
        .replace(
            "G0 A0\nM30",
            "G0 A0\nG0 X-30 Y-24.7\nG0 Z0\nG1 X0 F600 (re-cut half of face A0)\nG0 Z60\nM30",
        );
    assert!(program.contains("re-cut"), "the program was changed");
    sb.write("recut.ngc", program.as_bytes());
    let (code, out, err) = sb.run(&["run", "step.toml", "--out", "o"]);
    assert_refused(code, &out, &err, "run");
    assert!(err.contains("face 'A0' (NC line 9) RMS"), "{err}");
    assert!(!err.contains("face 'A180'"), "{err}");
    assert!(!sb.dir.join("o").exists(), "a refusal writes nothing");
    let (code, out, err) = sb.run(&["run", "step.toml", "--out", "o", "--accept-misfit"]);
    assert_eq!(code, 0, "{err}");
    assert!(
        out.lines()
            .next()
            .is_some_and(|l| l.contains("MISFIT ACCEPTED")),
        "{out}"
    );
    let json = std::fs::read_to_string(sb.dir.join("o/mdx50-step/report.json")).expect("report");
    assert!(
        json.starts_with("{\n  \"warning\": \"MISFIT ACCEPTED"),
        "{json:.200}"
    );
    let html = std::fs::read_to_string(sb.dir.join("o/mdx50-step/report.html")).expect("page");
    assert!(html.contains("MISFIT ACCEPTED") && html.contains("Goodness of fit"));
    assert!(html.contains("rank margin"));
}

/// `identify --cloud` on a cloud of a part whose cut of one face was 0.3 mm off the
/// program's (the face's NC line is not what cut it): refused, naming that face among
/// those out of line; the cloud of the program's own part fits.
#[test]
fn identify_refuses_a_cloud_cut_by_another_line() {
    let sb = Sandbox::new("misfit-identify");
    let text =
        std::fs::read_to_string(Path::new(ROOT).join("studies/mdx50-nine.toml")).expect("scene");
    let program =
        std::fs::read_to_string(Path::new(ROOT).join("studies/mdx50-nine.ngc")).expect("program");
    sb.write("nine.ngc", program.as_bytes());
    let shifted = program
        .replacen("G0 X-44 Y-18\nG0 Z12", "G0 X-44 Y-18.3\nG0 Z12", 1)
        .replace(
            "G1 X31 Y-18 F600 (a180-xm-d8)",
            "G1 X31 Y-18.3 F600 (a180-xm-d8)",
        );
    assert!(
        shifted.contains("Y-18.3 F600 (a180-xm-d8)"),
        "the cut was moved"
    );
    sb.write("shifted.ngc", shifted.as_bytes());
    let with = |program: &str| {
        text.lines()
            .map(|l| {
                if l.starts_with("program") {
                    format!("program = \"{program}\"")
                } else {
                    l.to_string()
                }
            })
            .collect::<Vec<_>>()
            .join("\n")
    };
    sb.write("nine.toml", with("nine.ngc").as_bytes());
    sb.write("shifted.toml", with("shifted.ngc").as_bytes());
    let (code, _, err) = sb.run(&["scan", "shifted.toml", "--out", "s"]);
    assert_eq!(code, 0, "{err}");
    let cloud = "s/mdx50-nine-scan/cloud.ply";
    let (code, out, err) = sb.run(&["identify", "nine.toml", "--cloud", cloud, "--out", "o"]);
    assert_refused(code, &out, &err, "identify");
    assert_refused_statistic(&err, "identify");
    // The moved face is named first, in the group of the faces any one of which, left out,
    // leaves a fit (the flanks that alone tie the moved offset to the others).
    let named = err
        .split("out of line, worst first: ")
        .nth(1)
        .unwrap_or_else(|| panic!("names the faces: {err}"));
    let first = named.split(" (each alone explains").next().expect("first");
    assert!(
        first.contains("a180-xm-d8-flank") && !first.contains("-d8-face"),
        "{err}"
    );
    assert!(!sb.dir.join("o").exists(), "a refusal writes nothing");
    // The program's own part fits, and its report gives the rank margin and the fit.
    let (code, _, err) = sb.run(&["scan", "nine.toml", "--out", "g"]);
    assert_eq!(code, 0, "{err}");
    let (code, out, err) = sb.run(&[
        "identify",
        "nine.toml",
        "--cloud",
        "g/mdx50-nine-scan/cloud.ply",
        "--out",
        "o",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).expect("json");
    assert_eq!(v["fit"]["fits"], true, "{}", v["fit"]);
    assert!(v["margin"]["ratio"].as_f64().expect("margin") > 1.0);
}

// ---------------------------------------------------------------------------------------
// Rank.

/// Without a jig the six base-frame gauge directions are exactly null (a rigid motion of
/// the base and the balls changes no length): on the Jacobian's own SVD they are rounding
/// (below 1e-12 of the largest singular value), where the normal matrix's eigenvalues put
/// them near 1e-8. The margin reported is the gap between the 63rd and 64th singular value.
#[test]
fn without_a_jig_the_gauge_is_rounding_on_the_jacobians_own_svd() {
    let s = centre();
    let plan = default_plan(
        Procedure::JigFree,
        &s.workspace.expect("ws"),
        DEFAULT_POINTS,
    );
    let readings = dbb_readings(&s.nominal, &s.actual, &plan.circles, 0.0, 1, |_| {
        Vector3::zeros()
    });
    let cal = calibrate(
        &s.nominal,
        &s.actual,
        &plan,
        &readings,
        CALIBRATION_NOISE_MM,
    )
    .expect("solves");
    let id = &cal.identifiability;
    let sv = &id.singular_values;
    assert_eq!(id.rank, sv.len() - 6);
    for g in &sv[id.rank..] {
        assert!(
            *g < 1e-12 * sv[0],
            "a gauge direction at {:e} of the largest",
            g / sv[0]
        );
    }
    let m = id.margin;
    assert_eq!(m.last_kept, Some(sv[id.rank - 1]));
    assert_eq!(m.first_dropped, Some(sv[id.rank]));
    assert!(m.ratio > 1e8, "margin ×{:e}", m.ratio);
}

/// The C-table step experiment with its two cuts made as chamfers on opposite corners —
/// the first at C = 45°, the second at C = 225° from the same side — where the scene
/// expects one face cut twice: the second cut leaves nothing within the band of the face
/// it is declared to make, and `run` refuses naming that face and its NC line before any
/// step is measured, writing nothing.
#[test]
fn run_refuses_two_chamfers_declared_as_one_face() {
    let sb = Sandbox::new("misfit-chamfers");
    let scene = std::fs::read_to_string(Path::new(ROOT).join("scenes/c-table-step.toml"))
        .expect("scene")
        .replace("program = \"c-table-step.ngc\"", "program = \"two.ngc\"");
    sb.write("c.toml", scene.as_bytes());
    let program = std::fs::read_to_string(Path::new(ROOT).join("scenes/c-table-step.ngc"))
        .expect("program")
        .replace("G0 Z60 C0\n", "G0 Z60 C45\n")
        .replace("G0 X-30 Y25\nG0 C180", "G0 X-30 Y-25\nG0 C225");
    assert!(program.contains("C225"), "the program was changed");
    sb.write("two.ngc", program.as_bytes());
    let (code, out, err) = sb.run(&["run", "c.toml", "--out", "o"]);
    assert_refused(code, &out, &err, "run");
    assert!(
        err.contains("face 'C180': line 14 cut nothing inside the face region"),
        "{err}"
    );
    assert!(!sb.dir.join("o").exists(), "a refusal writes nothing");
}
