//! Rotary-axis location errors identified from the ISO 10791-6 motion test read by the ball
//! sensor and from probed sphere positions: injected errors come back within their reported
//! uncertainties, and the report names what a test cannot determine.

use crate::{
    builtin, draw, inject, mounting, rotary_sweeps as sweeps, setup, terms,
    trunnion_chain as trunnion,
};
use twinmill::calibration::calibrate::{Model, Registration, ball_features, identify};
use twinmill::cutting::tool::{Tool, ToolKind};
use twinmill::machine::chain::Chain;
use twinmill::math::{CounterRng, Real, Vector3};
use twinmill::metrology::ball_sensor::BallSensor;
use twinmill::metrology::rotary_test::{probe_test, sensor_test};
use twinmill::scene::Scene;

/// Runs `trials` identifications with `measure` giving the samples of a trial, and checks
/// that every identified term is within 3 of its standard uncertainties of the truth (the
/// values this test drew and injected) in at least 95 % of them, that the spread of its
/// errors matches its reported σ both ways (`crate::assert_spread_matches_sigma`: the RMS
/// of (value − truth)/σ within the χ² bounds of the trial count, [0.774, 1.238] for 100),
/// and that the table's offset along itself and angle zero are named as not determined.
fn coverage(
    trials: u64,
    measure: impl Fn(&Chain, &Chain, u64, Vector3) -> Vec<twinmill::metrology::rotary_test::Sample>,
) {
    let nominal = trunnion();
    let (names, terms) = terms(&nominal);
    let tool = Tool::try_new(ToolKind::Flat, 6.0, 20.0).expect("tool");
    let rng = CounterRng::new(10791);
    let mut inside = vec![0usize; names.len()];
    let mut z: Vec<Vec<Real>> = vec![Vec::new(); names.len()];
    for trial in 0..trials {
        let truth = draw(&rng, trial, &names);
        let actual = inject(&nominal, &names, &truth);
        let samples = measure(&actual, &nominal, trial, mounting(&rng, trial));
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
        let mut undetermined: Vec<&str> = r
            .identifiability
            .undetermined_combinations
            .iter()
            .map(|c| c.name.as_str())
            .collect();
        undetermined.sort();
        assert_eq!(undetermined, ["EC0C", "EZ0C"], "trial {trial}");
        assert_eq!(r.parameters.len(), 8, "trial {trial}");
        for e in &r.parameters {
            let k = names.iter().position(|n| *n == e.name).expect("named");
            if (e.value - truth[k]).abs() <= 3.0 * e.sigma {
                inside[k] += 1;
            }
            z[k].push((e.value - truth[k]) / e.sigma);
        }
    }
    for (n, c) in names.iter().zip(&inside) {
        if n == "EZ0C" || n == "EC0C" {
            continue;
        }
        assert!(
            *c as u64 * 100 >= 95 * trials,
            "{n}: within 3σ in {c} of {trials} trials"
        );
    }
    let seen: Vec<usize> = (0..names.len())
        .filter(|&k| names[k] != "EZ0C" && names[k] != "EC0C")
        .collect();
    crate::assert_spread_matches_sigma(
        &seen.iter().map(|&k| names[k].clone()).collect::<Vec<_>>(),
        &seen.iter().map(|&k| z[k].clone()).collect::<Vec<_>>(),
    );
}

#[test]
fn the_ball_sensor_motion_test_identifies_the_trunnion_location_errors_within_3_sigma() {
    let sensor = BallSensor::seed003(8.0);
    coverage(100, |actual, nominal, trial, m| {
        sensor_test(actual, nominal, &sensor, 1.0, &setup(trial, m), &sweeps()).expect("trace")
    });
}

#[test]
fn probed_sphere_positions_identify_the_trunnion_location_errors_within_3_sigma() {
    // A touch probe repeatable to 1 µm (2σ).
    coverage(100, |actual, _, trial, m| {
        probe_test(actual, 0.5e-3, &setup(trial, m), &sweeps()).expect("probed")
    });
}

#[test]
fn an_offset_a_line_moves_the_ball_as_derived() {
    // A's line offset by e along Y (EY0A): with C = 0 the tool point is L·Rx(a)·L⁻¹·t and the
    // controller sets t = Rx(a)⁻¹·s about the nominal line, so the ball ends at
    // s + (I − Rx(a))·e·ŷ about the line: deviation e·(0, 1 − cos a, −sin a).
    let nominal = trunnion();
    let e = 0.03;
    let actual = inject(&nominal, &["EY0A".to_string()], &[e]);
    let mut sensor = BallSensor::seed003(8.0);
    sensor.accuracy_mm = 1e-12;
    let sweep = vec![sweeps().swap_remove(2)];
    let samples = sensor_test(
        &actual,
        &nominal,
        &sensor,
        1.0,
        &setup(1, Vector3::zeros()),
        &sweep,
    )
    .expect("trace");
    assert_eq!(samples.len(), 9);
    for s in &samples {
        let a = s.angle_deg.to_radians();
        let expect = [0.0, e * (1.0 - a.cos()), -e * a.sin()];
        for k in 0..3 {
            assert!(
                (s.deviation_mm[k] - expect[k]).abs() < 1e-9,
                "A = {}: {:?} vs {expect:?}",
                s.angle_deg,
                s.deviation_mm
            );
        }
    }
}

#[test]
fn a_test_that_never_tilts_a_names_its_terms_as_without_data() {
    let nominal = trunnion();
    let (names, terms) = terms(&nominal);
    let actual = inject(&nominal, &names, &draw(&CounterRng::new(3), 0, &names));
    let sensor = BallSensor::seed003(8.0);
    let only_c = vec![sweeps().swap_remove(0)];
    let samples = sensor_test(
        &actual,
        &nominal,
        &sensor,
        1.0,
        &setup(5, Vector3::zeros()),
        &only_c,
    )
    .expect("trace");
    let feats = ball_features(&samples, Vector3::zeros(), 0);
    let tool = Tool::try_new(ToolKind::Flat, 6.0, 20.0).expect("tool");
    let model = Model {
        chain: &nominal,
        ids: &[],
        iso_terms: &terms,
        tool: &tool,
        features: &feats,
        registration: Registration::Workpiece,
    };
    let r = identify(&model).expect("identifies");
    assert_eq!(r.identifiability.no_data, ["EY0A", "EZ0A", "EB0A", "EC0A"]);
    let alone: Vec<&str> = r.parameters.iter().map(|e| e.name.as_str()).collect();
    assert_eq!(alone, ["EX0C", "EY0C", "EA0C", "EB0C"]);
}

#[test]
fn measure_ball_sensor_identifies_the_scene_s_location_errors_and_writes_the_trace() {
    let sb = crate::Sandbox::new("measure-rotary");
    sb.write("trunnion-ac.toml", builtin("trunnion-ac.toml").as_bytes());
    for instrument in ["ball-sensor", "probe"] {
        let (code, stdout, stderr) = sb.run(&[
            "measure",
            "trunnion-ac.toml",
            "--instrument",
            instrument,
            "--out",
            "t.csv",
            "--png",
            "t.png",
            "--json",
        ]);
        assert_eq!(code, 0, "{stderr}");
        let v: serde_json::Value = serde_json::from_str(&stdout).expect("json");
        assert_eq!(v["instrument"], instrument);
        let id = &v["identification"];
        let mut unseen: Vec<&str> = id["not_determined"]
            .as_array()
            .expect("list")
            .iter()
            .filter_map(|x| x.as_str())
            .collect();
        unseen.sort();
        assert_eq!(unseen, ["EC0C", "EZ0C"]);
        let identified = id["identified"].as_array().expect("list");
        assert_eq!(identified.len(), 8);
        // Each injected term recovered within 4 of its uncertainties (one seed: a single
        // 3σ miss among 16 would not be a fault). The truth: the scene file's own
        // [deviations], read here, not the report's "injected".
        let file: toml::Table = builtin("trunnion-ac.toml").parse().expect("toml");
        let truth = file["deviations"].as_table().expect("[deviations]");
        for t in identified {
            let (value, sigma) = (
                t["value"].as_f64().expect("v"),
                t["sigma"].as_f64().expect("s"),
            );
            let name = t["name"].as_str().expect("name");
            let injected = truth
                .get(name)
                .and_then(toml::Value::as_float)
                .expect("the scene injects every term");
            assert_eq!(t["injected"].as_f64(), Some(injected), "{name}");
            assert!(
                (value - injected).abs() <= 4.0 * sigma,
                "{instrument} {}: {value} vs {injected} ± {sigma}",
                t["name"]
            );
        }
        let csv = std::fs::read_to_string(sb.dir.join("t.csv")).expect("trace");
        // The set-up record, the header, and the default test's 12 + 12 + 9 + 13 positions.
        assert_eq!(csv.lines().count(), 2 + 46);
        let mut lines = csv.lines();
        let record = lines.next().expect("record");
        assert!(
            record.starts_with(&format!("# set-up: {instrument} point_mm=60.0,0.0,30.0 ")),
            "{record}"
        );
        assert!(
            lines
                .next()
                .expect("header")
                .starts_with("sweep,axis,angle_deg,C_deg,A_deg,Y_mm,X_mm,Z_mm,dx_mm")
        );
        assert!(sb.dir.join("t.png").exists());
    }
}

#[test]
fn measure_rotary_refuses_bad_input_naming_the_problem_and_writes_nothing() {
    let sb = crate::Sandbox::new("measure-rotary-bad");
    sb.write("trunnion-ac.toml", builtin("trunnion-ac.toml").as_bytes());
    sb.write("xyz.toml", builtin("xyz-error-motions.toml").as_bytes());
    let cases: &[(&str, &[&str], &str)] = &[
        (
            "trunnion-ac.toml",
            &["--sweep", "X:0:90:4"],
            "axis X is not a rotary axis",
        ),
        ("trunnion-ac.toml", &["--sweep", "C:0:90:1"], "at least 2"),
        (
            "trunnion-ac.toml",
            &["--sweep", "C:0:nan:4"],
            "not a finite number",
        ),
        (
            "trunnion-ac.toml",
            &["--height", "3"],
            "height above the sheets",
        ),
        ("trunnion-ac.toml", &["--band", "2"], "--band"),
        ("trunnion-ac.toml", &["--mounting", "5,0,0"], "micrometer"),
        (
            "trunnion-ac.toml",
            &["--point", "1,2"],
            "--point needs three numbers",
        ),
        ("trunnion-ac.toml", &["--noise", "0"], "--noise"),
        (
            "trunnion-ac.toml",
            &["--identify", "EQ0C"],
            "unknown location",
        ),
        (
            "trunnion-ac.toml",
            &["--radius", "100"],
            "--radius is an option of",
        ),
        ("xyz.toml", &[], "no rotary axis"),
    ];
    for (scene, extra, want) in cases {
        let mut args = vec!["measure", scene, "--instrument", "ball-sensor"];
        args.extend(extra.iter().copied());
        args.extend(["--out", "t.csv", "--png", "p.png"]);
        let (code, stdout, stderr) = sb.run(&args);
        assert_ne!(code, 0, "{args:?}");
        assert!(stdout.is_empty(), "{args:?}: {stdout}");
        assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
        assert_eq!(stderr.trim_end().lines().count(), 1, "{args:?}: {stderr}");
        assert!(stderr.contains(want), "{args:?}: '{want}' not in {stderr}");
        assert!(!sb.dir.join("t.csv").exists() && !sb.dir.join("p.png").exists());
    }
    let (code, _, stderr) = sb.run(&[
        "measure",
        "trunnion-ac.toml",
        "--instrument",
        "probe",
        "--band",
        "8",
    ]);
    assert_ne!(code, 0);
    assert!(
        stderr.contains("--band is an option of --instrument ball-sensor"),
        "{stderr}"
    );
}

/// The motion test's model carries the scene's other deviations: with an X–Y squareness and
/// a spindle tilt in the scene besides the location errors, the location terms still come
/// back within their reported uncertainties of the values this test injects (20 seeds: no
/// term beyond 4.5σ, the normalised errors' RMS near 1) and χ² fits its degrees of freedom.
#[test]
fn location_terms_are_unbiased_with_a_squareness_and_a_spindle_tilt_in_the_scene() {
    use twinmill::pipeline::{RotaryInstrument, RotaryRequest, default_setup, rotary_test};
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/trunnion-ac.toml");
    let mut doc: toml::Table = builtin("trunnion-ac.toml").parse().expect("toml");
    let truth: [(&str, Real); 8] = [
        ("EX0C", 0.020),
        ("EY0C", -0.015),
        ("EA0C", 40e-6),
        ("EB0C", -30e-6),
        ("EY0A", 0.030),
        ("EZ0A", -0.025),
        ("EB0A", 60e-6),
        ("EC0A", 25e-6),
    ];
    let mut devs = toml::Table::new();
    for (n, v) in truth {
        devs.insert(n.into(), toml::Value::Float(v));
    }
    // Not identified: the scene's X–Y squareness and a spindle tilt about X.
    devs.insert("EC0XY".into(), toml::Value::Float(40e-6));
    devs.insert("alpha_ZS".into(), toml::Value::Float(50e-6));
    doc.insert("deviations".into(), toml::Value::Table(devs));
    let scene = Scene::parse(&doc.to_string(), &path).expect("scene");
    let (mut z2, mut n, mut worst, mut chi2, mut dof) = (0.0, 0usize, (0.0, ""), 0.0, 0usize);
    for seed in 0..20 {
        let req = RotaryRequest {
            instrument: RotaryInstrument::BallSensor {
                sensor: BallSensor::seed003(8.0),
                height_mm: 1.0,
            },
            sweeps: Vec::new(),
            setup: default_setup(seed),
            identify: Some(Vec::new()),
        };
        let out = rotary_test(&scene, &req).expect("test runs");
        let id = out.report.identification.expect("identified");
        assert_eq!(id.identified.len(), 8, "seed {seed}");
        for t in &id.identified {
            let &(name, want) = truth
                .iter()
                .find(|(n, _)| *n == t.name)
                .expect("a location term");
            let z = (t.value - want) / t.sigma;
            z2 += z * z;
            n += 1;
            if z.abs() > worst.0 {
                worst = (z.abs(), name);
            }
        }
        chi2 += id.chi2;
        dof += id.dof;
    }
    let rms = (z2 / n as Real).sqrt();
    assert!(worst.0 < 4.5, "{} off by {:.1}σ", worst.1, worst.0);
    assert!((0.75..1.3).contains(&rms), "normalised errors' RMS {rms}");
    // χ² of 20 fits: mean dof·20 with σ √(2·dof·20) ≈ 71; 5σ either way.
    let sd = (2.0 * dof as Real).sqrt();
    assert!(
        (chi2 - dof as Real).abs() < 5.0 * sd,
        "χ² {chi2} for {dof} dof"
    );
}
