//! The hexapod: inverse kinematics against genhexkins' formula written out here, forward
//! kinematics inverting it over 10,000+ seeded poses, the Jacobians against central
//! differences, the amplification factors of a hand-derived platform, homing, pivot, the
//! scene's bad input and the command line.

use super::{Sandbox, builtin};
use nalgebra::Matrix3;
use std::path::Path;
use twinmill::machine::hexapod::{
    Hexapod, HexapodError, Limits, PARAMETERS, ParameterId, Pose, STRUTS, twin_pose,
};
use twinmill::machine::hexapod_accuracy::{
    HomingSetup, homing_check, index_latched, pivot_test, wrong_index_effects,
};
use twinmill::math::{CounterRng, Real, Vector3};
use twinmill::scene::HexapodScene;
use twinmill::scene::{Scene, SceneError};

fn scene_path(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes")
        .join(name)
}

fn genhexkins() -> HexapodScene {
    HexapodScene::load(&scene_path("hexapod-genhexkins.toml")).expect("genhexkins scene loads")
}

fn centre() -> HexapodScene {
    HexapodScene::load(&scene_path("hexapod-machining-centre.toml"))
        .expect("machining-centre scene loads")
}

/// genhexkins' rotation, written out from its roll-pitch-yaw convention: roll a about x,
/// pitch b about y, yaw c about z, applied in that order (R = Rz·Ry·Rx).
fn rpy(a: Real, b: Real, c: Real) -> Matrix3<Real> {
    let rx = Matrix3::new(1.0, 0.0, 0.0, 0.0, a.cos(), -a.sin(), 0.0, a.sin(), a.cos());
    let ry = Matrix3::new(b.cos(), 0.0, b.sin(), 0.0, 1.0, 0.0, -b.sin(), 0.0, b.cos());
    let rz = Matrix3::new(c.cos(), -c.sin(), 0.0, c.sin(), c.cos(), 0.0, 0.0, 0.0, 1.0);
    rz * ry * rx
}

/// genhexkins' kinematicsInverse: for each strut, the platform joint turned by the pose's
/// rotation, moved by its translation, minus the base joint; the strut is that vector's
/// length. `tool` is subtracted from the platform joints first (zero in genhexkins).
fn formula(
    base: &[[Real; 3]; 6],
    platform: &[[Real; 3]; 6],
    tool: [Real; 3],
    v: [Real; 6],
) -> [Real; 6] {
    let r = rpy(v[3].to_radians(), v[4].to_radians(), v[5].to_radians());
    std::array::from_fn(|i| {
        let a = Vector3::new(
            platform[i][0] - tool[0],
            platform[i][1] - tool[1],
            platform[i][2] - tool[2],
        );
        let p = r * a;
        let d = [
            p.x + v[0] - base[i][0],
            p.y + v[1] - base[i][1],
            p.z + v[2] - base[i][2],
        ];
        (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
    })
}

/// A uniform deviate in [lo, hi] from stream `i`, word `k`.
fn uniform(rng: &CounterRng, i: u64, k: u64, lo: Real, hi: Real) -> Real {
    lo + (hi - lo) * rng.uniform(i, k)
}

#[test]
fn ik_equals_the_genhexkins_formula_on_its_default_geometry() {
    let s = genhexkins();
    // The geometry exactly as LinuxCNC's genhexkins.h lists its defaults.
    let base = [
        [-22.950, 13.250, 0.0],
        [22.950, 13.250, 0.0],
        [22.950, 13.250, 0.0],
        [0.0, -26.500, 0.0],
        [0.0, -26.500, 0.0],
        [-22.950, 13.250, 0.0],
    ];
    let platform = [
        [-1.000, 11.500, 0.0],
        [1.000, 11.500, 0.0],
        [10.459, -4.884, 0.0],
        [9.459, -6.616, 0.0],
        [-9.459, -6.616, 0.0],
        [-10.459, -4.884, 0.0],
    ];
    for i in 0..STRUTS {
        assert_eq!(s.nominal.base_joints()[i], Vector3::from(base[i]));
        assert_eq!(s.nominal.platform_joints()[i], Vector3::from(platform[i]));
    }
    assert_eq!(s.home.to_mm_deg(), [0.0, 0.0, 25.0, 0.0, 0.0, 0.0]);
    let rng = CounterRng::new(11);
    for n in 0..1000u64 {
        let v = [
            uniform(&rng, n, 0, -5.0, 5.0),
            uniform(&rng, n, 1, -5.0, 5.0),
            uniform(&rng, n, 2, 20.0, 30.0),
            uniform(&rng, n, 3, -15.0, 15.0),
            uniform(&rng, n, 4, -15.0, 15.0),
            uniform(&rng, n, 5, -30.0, 30.0),
        ];
        let got = s.nominal.strut_lengths(&Pose::from_mm_deg(v));
        let want = formula(&base, &platform, [0.0; 3], v);
        for i in 0..STRUTS {
            assert!(
                (got[i] - want[i]).abs() < 1e-12,
                "pose {v:?} strut {}",
                i + 1
            );
        }
    }
}

#[test]
fn ik_equals_the_formula_on_a_general_6_6_geometry_with_tool_offset() {
    let s = centre();
    // The actual machine: every joint moved, a tool offset: a general 6-6 platform.
    let h = &s.actual;
    let base: [[Real; 3]; 6] = std::array::from_fn(|i| h.base_joints()[i].into());
    let platform: [[Real; 3]; 6] = std::array::from_fn(|i| h.platform_joints()[i].into());
    assert_eq!(h.tool_offset(), Vector3::new(0.0, 0.0, -200.0));
    let rng = CounterRng::new(12);
    for n in 0..1000u64 {
        let v = [
            uniform(&rng, n, 0, -250.0, 250.0),
            uniform(&rng, n, 1, -250.0, 250.0),
            uniform(&rng, n, 2, 150.0, 450.0),
            uniform(&rng, n, 3, -25.0, 25.0),
            uniform(&rng, n, 4, -25.0, 25.0),
            uniform(&rng, n, 5, -180.0, 180.0),
        ];
        let got = h.strut_lengths(&Pose::from_mm_deg(v));
        let want = formula(&base, &platform, [0.0, 0.0, -200.0], v);
        for i in 0..STRUTS {
            assert!(
                (got[i] - want[i]).abs() < 1e-9,
                "pose {v:?} strut {}",
                i + 1
            );
        }
        // Readings are the lengths less the reference lengths.
        let r = h.readings(&Pose::from_mm_deg(v));
        assert!((r[0] - (got[0] - h.reference_lengths()[0])).abs() < 1e-12);
    }
}

/// FK ∘ IK over `count` accepted random poses (inside the workspace, reachable), Newton
/// starting from home.
fn fk_round_trip(h: &Hexapod, home: &Pose, seed: u64, ranges: [(Real, Real); 6], count: usize) {
    let rng = CounterRng::new(seed);
    let (mut accepted, mut n) = (0, 0u64);
    let (mut worst_mm, mut worst_rad) = (0.0 as Real, 0.0 as Real);
    while accepted < count {
        n += 1;
        assert!(n < 10 * count as u64, "too few reachable poses");
        let v: [Real; 6] =
            std::array::from_fn(|k| uniform(&rng, n, k as u64, ranges[k].0, ranges[k].1));
        let pose = Pose::from_mm_deg(v);
        let Ok(lengths) = h.inverse(&pose) else {
            continue;
        };
        let sol = h
            .forward(&lengths, home)
            .unwrap_or_else(|e| panic!("pose {v:?}: {e}"));
        worst_mm = worst_mm.max((sol.pose.position - pose.position).amax());
        worst_rad = worst_rad.max((sol.pose.angles - pose.angles).amax());
        assert!(sol.residual_mm <= 1e-9);
        accepted += 1;
    }
    assert!(worst_mm <= 1e-9, "position error {worst_mm:e} mm");
    assert!(worst_rad <= 1e-12, "angle error {worst_rad:e} rad");
}

#[test]
fn fk_inverts_ik_over_ten_thousand_poses_of_the_machining_centre() {
    let s = centre();
    fk_round_trip(
        &s.nominal,
        &s.home,
        21,
        [
            (-250.0, 250.0),
            (-250.0, 250.0),
            (150.0, 450.0),
            (-25.0, 25.0),
            (-25.0, 25.0),
            (-30.0, 30.0),
        ],
        10_000,
    );
}

#[test]
fn fk_inverts_ik_over_ten_thousand_poses_of_genhexkins() {
    let s = genhexkins();
    fk_round_trip(
        &s.nominal,
        &s.home,
        22,
        [
            (-5.0, 5.0),
            (-5.0, 5.0),
            (20.0, 30.0),
            (-15.0, 15.0),
            (-15.0, 15.0),
            (-20.0, 20.0),
        ],
        10_000,
    );
}

#[test]
fn jacobians_match_central_differences() {
    let s = centre();
    let h = &s.actual;
    let pose = Pose::from_mm_deg([40.0, -70.0, 320.0, 8.0, -12.0, 20.0]);
    let x = pose.to_vector();
    // Strut lengths w.r.t. the pose (angles in rad).
    let j = h.strut_jacobian(&pose);
    let hstep = 1e-6;
    for k in 0..6 {
        let mut p = x;
        p[k] += hstep;
        let up = h.strut_lengths(&Pose::from_vector(&p));
        p[k] -= 2.0 * hstep;
        let down = h.strut_lengths(&Pose::from_vector(&p));
        for i in 0..STRUTS {
            let d = (up[i] - down[i]) / (2.0 * hstep);
            assert!((j[(i, k)] - d).abs() < 1e-6, "∂L{}/∂x{k}", i + 1);
        }
    }
    // The output Jacobian is its inverse.
    let jo = h.output_jacobian(&pose).expect("regular");
    assert!((jo * j - nalgebra::Matrix6::identity()).amax() < 1e-9);
    // Readings w.r.t. the 42 parameters.
    let jp = h.parameter_jacobian(&pose);
    for id in ParameterId::all() {
        let mut up = h.clone();
        up.set_parameter(id, h.parameter(id) + hstep)
            .expect("finite");
        let mut down = h.clone();
        down.set_parameter(id, h.parameter(id) - hstep)
            .expect("finite");
        let (ru, rd) = (up.readings(&pose), down.readings(&pose));
        for i in 0..STRUTS {
            let d = (ru[i] - rd[i]) / (2.0 * hstep);
            assert!((jp[(i, id.index())] - d).abs() < 1e-6, "∂s{}/∂{id}", i + 1);
        }
    }
    // The pose w.r.t. the parameters at fixed readings, through forward kinematics.
    let jpp = h.pose_parameter_jacobian(&pose).expect("regular");
    let readings = h.readings(&pose);
    let hp = 1e-4;
    for id in ParameterId::all() {
        let fk = |delta: Real| {
            let mut m = h.clone();
            m.set_parameter(id, h.parameter(id) + delta)
                .expect("finite");
            m.forward_unchecked(&m.lengths_of_readings(&readings), &pose)
                .expect("converges")
                .pose
                .to_vector()
        };
        let d = (fk(hp) - fk(-hp)) / (2.0 * hp);
        for k in 0..6 {
            assert!(
                (jpp[(k, id.index())] - d[k]).abs() < 1e-7,
                "∂pose{k}/∂{id}: {} vs {}",
                jpp[(k, id.index())],
                d[k]
            );
        }
    }
    assert_eq!(PARAMETERS, 42);
}

#[test]
fn amplification_of_the_hand_derived_orthogonal_platform() {
    // Struts 1–3 meet at the platform origin along x, y, z; strut 4 acts along z at
    // (0, r, 0), strut 5 along x at (0, 0, r), strut 6 along y at (r, 0, 0). At the zero pose
    // the strut Jacobian's rows are (u_i, a_i × u_i):
    //   J = [[I, 0], [P, r·I]],  P = [[0,0,1],[1,0,0],[0,1,0]],
    //   J⁻¹ = [[I, 0], [−P/r, I/r]],
    // so K_p = √3 mm/mm and K_a = √(3/r² + 3/r²) = √6/r rad/mm.
    let r = 50.0;
    let len = 300.0;
    let a = [
        Vector3::zeros(),
        Vector3::zeros(),
        Vector3::zeros(),
        Vector3::new(0.0, r, 0.0),
        Vector3::new(0.0, 0.0, r),
        Vector3::new(r, 0.0, 0.0),
    ];
    let u = [
        Vector3::x(),
        Vector3::y(),
        Vector3::z(),
        Vector3::z(),
        Vector3::x(),
        Vector3::y(),
    ];
    let b: [Vector3; 6] = std::array::from_fn(|i| a[i] - len * u[i]);
    let h = Hexapod::try_new(b, a, [len; 6], Vector3::zeros(), Limits::none()).expect("valid");
    let pose = Pose::from_mm_deg([0.0; 6]);
    assert_eq!(h.strut_lengths(&pose), [len; 6]);
    let k = h.amplification(&pose).expect("regular");
    assert!((k.position_mm_per_mm - 3.0_f64.sqrt()).abs() < 1e-12);
    let ka = (6.0_f64.sqrt() / r).to_degrees();
    assert!(
        (k.angle_deg_per_mm - ka).abs() < 1e-12,
        "{} vs {ka}",
        k.angle_deg_per_mm
    );
}

#[test]
fn the_twin_pose_is_fk_actual_of_ik_nominal() {
    let s = centre();
    let cmd = Pose::from_mm_deg([100.0, 50.0, 300.0, 5.0, -5.0, 10.0]);
    let got = twin_pose(&s.nominal, &s.actual, &cmd).expect("reachable");
    // The actual struts are the nominal readings plus the actual reference lengths.
    let lengths = s.actual.strut_lengths(&got);
    let readings = s.nominal.readings(&cmd);
    for i in 0..STRUTS {
        let want = readings[i] + s.actual.reference_lengths()[i];
        assert!((lengths[i] - want).abs() < 1e-9, "strut {}", i + 1);
    }
    // Without deviations the twin goes where it is told.
    let exact = twin_pose(&s.nominal, &s.nominal, &cmd).expect("reachable");
    assert!((exact.position - cmd.position).amax() < 1e-9);
    // A common shift of the six base joints moves the whole machine by it: the tool point
    // lands shifted by the same vector, whatever the orientation, so the tip does not
    // travel while the orientation swings (pivot error zero, tip error the shift).
    let shift = Vector3::new(0.03, -0.04, 0.0);
    let mut moved = s.nominal.clone();
    for i in 1..=6 {
        moved
            .add_deviation(&format!("bx_{i}"), shift.x)
            .expect("name");
        moved
            .add_deviation(&format!("by_{i}"), shift.y)
            .expect("name");
    }
    let point = Vector3::new(0.0, 0.0, 300.0);
    let p = pivot_test(&s.nominal, &moved, &point, 15.0, 5).expect("reachable");
    assert!(p.pivot_error_mm < 1e-9, "{}", p.pivot_error_mm);
    assert!((p.max_deviation_mm - 0.05).abs() < 1e-9);
}

#[test]
fn homing_latches_the_right_index_only_inside_the_margin_and_the_band_check_flags_strut_4() {
    let s = centre();
    let setup: HomingSetup = s.homing.expect("[homing]");
    assert_eq!(setup.lead_mm, 6.0);
    let checks = homing_check(&setup);
    let flagged: Vec<usize> = checks
        .iter()
        .filter(|c| !c.in_band)
        .map(|c| c.strut)
        .collect();
    assert_eq!(flagged, vec![4]);
    // S = 1.2 of T = 6: S/T = 0.2, margin 1.2 mm; with σ = 0.3 mm the next-index tail
    // P(e > S) = P(Z > 4) = 3.1671e-5 and the previous-index tail P(Z > 16) is negligible.
    let c4 = checks[3];
    assert!((c4.fraction - 0.2).abs() < 1e-12);
    assert!((c4.margin_mm - 1.2).abs() < 1e-12);
    assert!((c4.wrong_index_probability - 3.1671e-5).abs() < 1e-8);
    // The latch: the right index while the trip error lies in (S − T, S].
    for (e, k) in [(1.19, 0), (1.21, 1), (-4.79, 0), (-4.81, -1)] {
        assert_eq!(index_latched(6.0, 1.2, e), k, "error {e}");
    }
    // A wrong index makes that strut one lead longer or shorter than the controller
    // believes: the pose reached has exactly that strut ±T and the others unchanged.
    let effects = wrong_index_effects(&s.nominal, &s.actual, &s.home, 6.0).expect("home");
    assert_eq!(effects.len(), 12);
    let right = twin_pose(&s.nominal, &s.actual, &s.home).expect("home");
    let right_lengths = s.actual.strut_lengths(&right);
    for e in &effects {
        let dp = e.position_error_mm.expect("assembles");
        let da = e.angle_error_deg.expect("assembles");
        let pose = Pose {
            position: right.position + Vector3::from(dp),
            angles: right.angles + Vector3::from(da).map(Real::to_radians),
        };
        let l = s.actual.strut_lengths(&pose);
        for i in 0..STRUTS {
            let want = right_lengths[i]
                + if i + 1 == e.strut {
                    e.index_offset as Real * 6.0
                } else {
                    0.0
                };
            assert!((l[i] - want).abs() < 1e-6, "strut {} of {:?}", i + 1, e);
        }
        // Millimetres, not microns: a lead off is never subtle.
        assert!(e.position_error_norm_mm.expect("assembles") > 1.0);
    }
}

#[test]
fn hexapod_scenes_refuse_bad_input_with_file_line_column() {
    let text = builtin("hexapod-genhexkins.toml");
    let parse = |t: &str| HexapodScene::parse(t, Path::new("h.toml"));
    let check = |t: String, want: &str| match parse(&t) {
        Err(SceneError::Invalid { line, message, .. }) => {
            assert!(line > 0);
            assert!(message.contains(want), "{message} lacks '{want}'");
        }
        Err(e) => panic!("{e}"),
        Ok(_) => panic!("accepted: {want}"),
    };
    // The platform in the base plane: singular home.
    check(
        text.replace("home = [0.0, 0.0, 25.0", "home = [0.0, 0.0, 0.0"),
        "singular",
    );
    // A stroke the home struts (33.31 mm) do not fit.
    check(
        text.replace("home = [", "stroke_mm = [10.0, 30.0]\nhome = ["),
        "outside its stroke",
    );
    check(
        text.replace("25.0, 0.0, 0.0, 0.0]", "nan, 0.0, 0.0, 0.0]"),
        "finite",
    );
    check(
        format!("{text}\n[deviations]\nbx_7 = 0.1\n"),
        "unknown hexapod parameter 'bx_7'",
    );
    check(text.replace("[-10.459, -4.884, 0.0],\n", ""), "six joints");
    check(
        text.replace("kind = \"hexapod\"", "kind = \"hexapodd\""),
        "hexapod",
    );
    // A deviation so large the machine cannot reach home.
    check(
        format!("{text}\n[deviations]\nl0_1 = 1e6\n"),
        "does not reach home",
    );
    // Deviations add to the nominal parameter.
    let ok = parse(&format!("{text}\n[deviations]\nbx_3 = 0.2\n")).expect("valid");
    let id = ParameterId::from_name("bx_3").expect("name");
    assert!((ok.actual.parameter(id) - ok.nominal.parameter(id) - 0.2).abs() < 1e-15);
    assert_eq!(ok.injected.get("bx_3"), Some(&0.2));
}

#[test]
fn serial_commands_refuse_a_hexapod_scene_and_serial_scenes_still_load() {
    match Scene::load(&scene_path("hexapod-genhexkins.toml")) {
        Err(SceneError::Hexapod { .. }) => {}
        other => panic!(
            "expected the hexapod refusal, got {:?}",
            other.map(|s| s.name)
        ),
    }
    for name in [
        "mdx50-step.toml",
        "xyz-pocket.toml",
        "vmc-4th-axis-step.toml",
    ] {
        Scene::load(&scene_path(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
    }
    // `kind = "serial"` is accepted, anything else refused with its position.
    let text = builtin("xyz-pocket.toml").replace("[machine]\n", "[machine]\nkind = \"serial\"\n");
    let dir = scene_path("");
    Scene::parse(&text, &dir.join("x.toml")).expect("serial kind accepted");
    let bad = text.replace("kind = \"serial\"", "kind = \"delta\"");
    match Scene::parse(&bad, &dir.join("x.toml")) {
        Err(SceneError::Invalid { message, .. }) => assert_eq!(
            message,
            "machine.kind: got \"delta\", expected \"serial\" or \"hexapod\""
        ),
        other => panic!("{:?}", other.map(|s| s.name)),
    }
    // A singular pose is an error from the kinematics, not a number.
    let s = genhexkins();
    assert!(matches!(
        s.nominal.forward(&[33.0; 6], &Pose::from_mm_deg([0.0; 6])),
        Err(HexapodError::Singular { .. })
    ));
}

#[test]
fn cli_ik_fk_round_trip_and_bad_input() {
    let sb = Sandbox::new("hexapod");
    let scene = scene_path("hexapod-machining-centre.toml");
    let scene = scene.to_str().expect("utf-8 path");
    let gen_path = scene_path("hexapod-genhexkins.toml");
    let gen_scene = gen_path.to_str().expect("utf-8 path");
    let (code, out, err) = sb.run(&[
        "hexapod",
        "ik",
        scene,
        "--pose",
        "-20,35.5,310,4,-3,12",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).expect("json");
    let struts: Vec<f64> = v["struts_mm"]
        .as_array()
        .expect("array")
        .iter()
        .map(|x| x.as_f64().expect("number"))
        .collect();
    assert_eq!(struts.len(), 6);
    let list = struts
        .iter()
        .map(|x| format!("{x:?}"))
        .collect::<Vec<_>>()
        .join(",");
    let (code, out, err) = sb.run(&["hexapod", "fk", scene, "--struts", &list, "--json"]);
    assert_eq!(code, 0, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).expect("json");
    let pose: Vec<f64> = v["pose"]
        .as_array()
        .expect("array")
        .iter()
        .map(|x| x.as_f64().expect("number"))
        .collect();
    for (got, want) in pose.iter().zip([-20.0, 35.5, 310.0, 4.0, -3.0, 12.0]) {
        assert!((got - want).abs() < 1e-9, "{pose:?}");
    }
    // Bad input: one line, non-zero, nothing written, no panic.
    for args in [
        vec!["hexapod", "ik", scene, "--pose", "1,2,3"],
        vec!["hexapod", "ik", scene, "--pose", "0,0,nan,0,0,0"],
        vec!["hexapod", "ik", scene, "--pose", "0,0,5000,0,0,0"],
        vec!["hexapod", "fk", scene, "--struts", "1,1,1,1,1,1"],
        vec![
            "hexapod",
            "fk",
            scene,
            "--struts",
            "900,900,900,900,900,900",
            "--near",
            "0,0",
        ],
        vec!["hexapod", "ik", "nowhere.toml", "--pose", "0,0,300,0,0,0"],
        vec![
            "hexapod",
            "amplification",
            scene,
            "--steps",
            "0",
            "--out",
            "map.csv",
            "--png",
            "map.png",
        ],
        vec!["hexapod", "homing", gen_scene],
        vec!["simulate", scene],
    ] {
        let (code, out, err) = sb.run(&args);
        assert_ne!(code, 0, "{args:?}");
        assert!(out.is_empty(), "{args:?}: {out}");
        assert_eq!(err.lines().count(), 1, "{args:?}: {err}");
        assert!(err.starts_with("twinmill: error: "), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
    }
    assert!(super::files_in(&sb.dir).is_empty());
    let (_, _, err) = sb.run(&["run", scene]);
    assert!(
        err.contains("`run` does not apply to a hexapod") && err.contains("identify"),
        "{err}"
    );
    let (_, _, err) = sb.run(&["simulate", scene]);
    assert!(err.contains("needs program, [tool] and [stock]"), "{err}");
    // The map writes its CSV and PNG.
    let (code, out, err) = sb.run(&[
        "hexapod",
        "amplification",
        scene,
        "--steps",
        "5",
        "--out",
        "map.csv",
        "--png",
        "map.png",
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("K_p"), "{out}");
    let csv = std::fs::read_to_string(sb.dir.join("map.csv")).expect("csv");
    assert_eq!(csv.lines().count(), 1 + 5 * 5 * 3 * 5);
    assert!(
        std::fs::read(sb.dir.join("map.png"))
            .expect("png")
            .starts_with(b"\x89PNG")
    );
}

/// Seed 001's amplification factors are those of the nominal machine (its design): the map
/// is the same whatever the scene's `[deviations]` — none, as written, ten times larger —
/// and it says so; the as-built machine's factors differ (so the comparison can fail).
#[test]
fn amplification_maps_the_nominal_machine_whatever_the_deviations() {
    use twinmill::machine::hexapod::Pose;
    use twinmill::pipeline::hexapod::{AmplificationRequest, hexapod_amplification};
    let path = scene_path("hexapod-machining-centre.toml");
    let text = std::fs::read_to_string(&path).expect("scene");
    let mut doc: toml::Table = text.parse().expect("toml");
    let scaled = |k: f64| {
        let mut d = doc.clone();
        let devs = d["deviations"].as_table_mut().expect("deviations");
        for (_, v) in devs.iter_mut() {
            *v = toml::Value::Float(v.as_float().expect("number") * k);
        }
        HexapodScene::parse(&d.to_string(), &path).expect("scene")
    };
    let req = AmplificationRequest {
        workspace: None,
        steps: [3, 3, 2],
        position_resolution_mm: 1e-3,
        angle_resolution_deg: 1e-3,
    };
    let factors = |s: &HexapodScene| {
        let o = hexapod_amplification(s, &req).expect("map");
        assert!(o.summary.contains("nominal machine"), "{}", o.summary);
        let j = serde_json::to_value(&o).expect("json");
        assert_eq!(j["machine"], "nominal");
        o.map
            .samples
            .iter()
            .map(|m| (m.pose, m.factors))
            .collect::<Vec<_>>()
    };
    let as_written = scaled(1.0);
    let reference = factors(&as_written);
    assert_eq!(factors(&scaled(10.0)), reference);
    doc.remove("deviations");
    let bare = HexapodScene::parse(&doc.to_string(), &path).expect("scene");
    assert_eq!(bare.nominal, bare.actual, "no deviations: one machine");
    assert_eq!(factors(&bare), reference);
    // The as-built machine's factors at a mapped pose are not the reported ones.
    let (pose, k) = reference
        .iter()
        .find_map(|(p, k)| k.map(|k| (*p, k)))
        .expect("a reachable pose");
    let built = as_written
        .actual
        .amplification(&Pose::from_mm_deg(pose))
        .expect("regular");
    assert!(
        (built.position_mm_per_mm - k.position_mm_per_mm).abs() > 1e-9,
        "{built:?} vs {k:?}"
    );
}

/// The fixed jig-free plan is the one docs/hexapod.md describes: five x–y positions (the
/// centre and ±0.4 of the half-widths) at three heights; per height the bar at 20°, 30°,
/// 45° with the platform level, tilted +0.3·tilt about x, tilted −0.3·tilt about y; every
/// circle swung by 0.36·tilt along the bar.
#[test]
fn the_fixed_jig_free_plan_tilts_and_swings_the_platform_as_documented() {
    use twinmill::calibration::hexapod_calibrate::{DEFAULT_POINTS, Procedure, default_plan};
    let s = centre();
    let ws = s.workspace.expect("workspace");
    let plan = default_plan(Procedure::JigFree, &ws, DEFAULT_POINTS);
    assert_eq!(plan.circles.len(), 15);
    let t = ws.tilt_deg;
    let (cx, cy) = (0.5 * (ws.x_mm.0 + ws.x_mm.1), 0.5 * (ws.y_mm.0 + ws.y_mm.1));
    let (hx, hy) = (0.5 * (ws.x_mm.1 - ws.x_mm.0), 0.5 * (ws.y_mm.1 - ws.y_mm.0));
    let near = |a: Real, b: Real| (a - b).abs() < 1e-9;
    for (k, c) in plan.circles.iter().enumerate() {
        let (bar, orientation) = match k / 5 {
            0 => (20.0, [0.0, 0.0, 0.0]),
            1 => (30.0, [0.3 * t, 0.0, 0.0]),
            _ => (45.0, [0.0, -0.3 * t, 0.0]),
        };
        assert!(near(c.tilt_deg, bar), "circle {k}: bar {}", c.tilt_deg);
        for (got, want) in c.orientation_deg.iter().zip(orientation) {
            assert!(near(*got, want), "circle {k}: {:?}", c.orientation_deg);
        }
        assert!(
            near(c.swing_deg, 0.36 * t),
            "circle {k}: swing {}",
            c.swing_deg
        );
        let (fx, fy) = ((c.centre_mm.x - cx) / hx, (c.centre_mm.y - cy) / hy);
        assert!(
            [
                (0.0, 0.0),
                (0.4, 0.4),
                (-0.4, 0.4),
                (-0.4, -0.4),
                (0.4, -0.4)
            ]
            .iter()
            .any(|(x, y)| near(fx, *x) && near(fy, *y)),
            "circle {k} at {fx}, {fy} of the half-widths"
        );
    }
}
