//! A misfit is refused, not calibrated: every identification path — the 0°/180° faces of
//! `run`, general identification from faces (`identify`), the rotary axes' location from
//! the ball sensor and the probe (`measure`), the hexapod's DBB calibration (`calibrate`,
//! on the twin and from `--readings`) — refuses data that cannot come from its model at the
//! stated noise, in one line naming the statistic and the files, circles, faces or samples
//! out of line, and writes nothing; `--accept-misfit` keeps the result and says so first.
//! Good data at the stated noise pass in all but a thousandth of seeded trials. And measured
//! readings never meet the scene's simulated machine.

use super::Sandbox;
use std::path::{Path, PathBuf};
use twinmill::calibration::calibrate::{
    Feature, IsoTerm, Model, Registration, ball_features, identify, synthetic_plane_feature,
};
use twinmill::calibration::goodness::{REFUSE_P, ScanNoise, face_rms_check};
use twinmill::calibration::hexapod_calibrate::{
    CircleReadings, DEFAULT_POINTS, Plan, Procedure, calibrate, default_plan,
};
use twinmill::calibration::hexapod_design::design;
use twinmill::cutting::tool::{Tool, ToolKind};
use twinmill::hexapod_scene::HexapodScene;
use twinmill::machine::hexapod::Hexapod;
use twinmill::math::{CounterRng, Point3, Real, UnitVector3, Vector3};
use twinmill::metrology::ball_sensor::BallSensor;
use twinmill::metrology::fit::{Plane, RobustRule, fit_plane_robust};
use twinmill::metrology::hexapod_dbb::{DbbCircle, DbbInstrument, measure};
use twinmill::metrology::rotary_test::{Setup, Sweep, probe_test, sensor_test};
use twinmill::nc::{AxisLetter, AxisValues};
use twinmill::pipeline::dbb::{CALIBRATION_NOISE_MM, trial_machine};
use twinmill::pipeline::{RotaryInstrument, RotaryRequest, default_setup, rotary_test};
use twinmill::scene::Scene;

const ROOT: &str = env!("CARGO_MANIFEST_DIR");

fn centre_path() -> PathBuf {
    Path::new(ROOT).join("scenes/hexapod-machining-centre.toml")
}

fn centre() -> HexapodScene {
    HexapodScene::load(&centre_path()).expect("machining-centre scene loads")
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
    assert!(err.contains("χ²") && err.contains("designed-"), "{err}");
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
    assert!(err.contains("χ²") && err.contains(".csv"), "{err}");
    assert!(!sb.dir.join("c.toml").exists());
}

/// Good readings at the stated σ: 1,000 seeded trials of the ball plate (36 samples a
/// circle, each trial its own machine and noise) are accepted in all but one at most (the
/// threshold refuses one good fit in a million).
#[test]
fn good_dbb_readings_are_accepted_in_999_of_1000_trials() {
    let s = centre();
    let plan = default_plan(Procedure::BallPlate, &s.workspace.expect("ws"), 36);
    let mut refused = Vec::new();
    for t in 0..1000u64 {
        let actual = trial_machine(&s, 5000 + t).expect("machine");
        let readings: Vec<CircleReadings> = plan
            .circles
            .iter()
            .enumerate()
            .map(|(j, c)| {
                let inst = DbbInstrument {
                    mount_mm: Vector3::zeros(),
                    noise_sigma_mm: CALIBRATION_NOISE_MM,
                    seed: 9000 + t,
                    stream: (j as u64) << 32,
                };
                let m = measure(&s.nominal, &actual, c, &inst).expect("measures");
                CircleReadings {
                    lengths_mm: m.lengths_mm(c.radius_mm),
                    commands: m.commands,
                }
            })
            .collect();
        let cal =
            calibrate(&s.nominal, &actual, &plan, &readings, CALIBRATION_NOISE_MM).expect("solves");
        if !cal.fit.fits {
            refused.push((t, cal.fit.describe()));
        }
    }
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

fn letter(c: char) -> AxisLetter {
    AxisLetter::from_char(c).expect("letter")
}

/// The rotary location test of `rotary_location.rs`: C at A = 0 and −30°, A swept, A and C
/// together.
fn sweeps() -> Vec<Sweep> {
    let at = |a: Real| AxisValues::default().with(letter('A'), a);
    let sweep = |axis: char, from: Real, to: Real, positions: usize, a: Real| Sweep {
        axis: letter(axis),
        from,
        to,
        positions,
        at: at(a),
        also: vec![],
    };
    let mut both = sweep('A', -45.0, 45.0, 13, 0.0);
    both.also = vec![(letter('C'), 0.0, 180.0)];
    vec![
        sweep('C', 0.0, 330.0, 12, 0.0),
        sweep('C', 0.0, 330.0, 12, -30.0),
        sweep('A', -60.0, 60.0, 9, 0.0),
        both,
    ]
}

/// 1,000 seeded trials of each instrument on machines with random location errors
/// (offsets ±50 µm, tilts ±100 µrad, the sensor's point mounted ±0.2 mm off): all but one
/// at most fit.
#[test]
fn good_rotary_tests_are_accepted_in_999_of_1000_trials() {
    let nominal = trunnion().chain.nominal();
    let names = nominal.rotary_location_terms();
    let terms: Vec<IsoTerm> = names
        .iter()
        .map(|n| IsoTerm::parse(&nominal, n).expect("term"))
        .collect();
    let tool = Tool::try_new(ToolKind::Flat, 6.0, 20.0).expect("tool");
    let sensor = BallSensor::seed003(8.0);
    let rng = CounterRng::new(26);
    for probe in [false, true] {
        let mut refused = Vec::new();
        for t in 0..1000u64 {
            let mut actual = nominal.clone();
            for (k, n) in names.iter().enumerate() {
                let u = 2.0 * rng.uniform(t, k as u64) - 1.0;
                let v = match n.as_str() {
                    "EZ0C" | "EC0C" => 0.0,
                    _ if matches!(n.as_bytes()[1], b'A' | b'B' | b'C') => 100e-6 * u,
                    _ => 0.05 * u,
                };
                if v != 0.0 {
                    actual.apply_iso_term(n, v).expect("term");
                }
            }
            let setup = Setup {
                point_w: Point3::new(60.0, 0.0, 30.0),
                mounting_mm: Vector3::from_fn(|k, _| {
                    0.2 * (2.0 * rng.uniform(t, 100 + k as u64) - 1.0)
                }),
                tool_offset: Vector3::zeros(),
                seed: 77_000 + t,
            };
            let samples = if probe {
                probe_test(&actual, 0.5e-3, &setup, &sweeps())
            } else {
                sensor_test(&actual, &nominal, &sensor, 1.0, &setup, &sweeps())
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
        }
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
    let model = scene.chain.nominal();
    let ids: Vec<_> = scene
        .parameters
        .iter()
        .map(|n| model.deviation_id(n).expect("known"))
        .collect();
    let (sigma_off, sigma_slope) = (0.5e-3, [2e-5, 1e-4]);
    let rng = CounterRng::new(27);
    let mut refused = Vec::new();
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
    }
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
    let check = |pts: &[Point3]| {
        let fit = fit_plane_robust(pts, &robust).expect("a plane");
        face_rms_check("face", fit.rms_mm, fit.n_used, 1.0, &noise, REFUSE_P)
    };
    let refused = (0..1000u64)
        .filter(|&t| check(&grid(t, ray, sigma)).out_of_line)
        .count();
    assert!(refused <= 1, "{refused} of 1000 good faces refused");
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
    assert!(
        err.contains("χ²") && err.contains("a180-xm-d8-flank"),
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
    let quiet = DbbInstrument {
        mount_mm: Vector3::zeros(),
        noise_sigma_mm: 0.0,
        seed: 1,
        stream: 0,
    };
    let readings: Vec<CircleReadings> = plan
        .circles
        .iter()
        .map(|c: &DbbCircle| {
            let m = measure(&s.nominal, &s.actual, c, &quiet).expect("measures");
            CircleReadings {
                lengths_mm: m.lengths_mm(c.radius_mm),
                commands: m.commands,
            }
        })
        .collect();
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
