//! The hexapod's controller apart from the machine: `hexapod fk --actual` where the real
//! machine goes for commanded lengths or encoder counts (a symmetric platform worked out by
//! hand), the calibration's controller file applied with `--controller` — the pose errors
//! it leaves worked out by this test's own kinematics and compared with what `identify`
//! promised, for both procedures — the genhexkins pins it writes beside it, and bad input.

use super::hexapod_calibration::{
    Geometry, ball_plate_readings, identify_ball_plate, own_pose_errors,
};
use super::{HEXAPOD_CENTRE, Sandbox, hexapod_centre as centre};
use std::path::Path;
use twinmill::machine::hexapod::{Hexapod, ParameterId};
use twinmill::math::{Real, Vector3};

/// The controller a controller file describes, as this test reads it: the nominal
/// machine's parameters plus the `[controller]` values, by name.
pub(super) fn controller_of(nominal: &Hexapod, fragment: &str) -> Hexapod {
    let t: toml::Table = fragment.parse().expect("the controller file is TOML");
    let mut h = nominal.clone();
    for (k, v) in t["controller"].as_table().expect("[controller]") {
        let id = ParameterId::from_name(k).expect("a parameter name");
        let d = v.as_float().expect("a number");
        h.set_parameter(id, nominal.parameter(id) + d)
            .expect("finite");
    }
    h
}

/// The pivot error at `p` (tilts ±15°, five steps each, as `hexapod pivot` runs it) of
/// `actual` driven by `controller`, by this test's own kinematics: the tip's largest travel
/// from where it is with the tool level (mm).
fn own_pivot(controller: &Hexapod, actual: &Hexapod, p: [Real; 3]) -> Real {
    let (c, m) = (Geometry::of(controller), Geometry::of(actual));
    let tip = |v: [Real; 6]| {
        let r = m.reached(&c.readings(&v), &v);
        Vector3::new(r[0], r[1], r[2])
    };
    let level = tip([p[0], p[1], p[2], 0.0, 0.0, 0.0]);
    let t = 15.0_f64.to_radians();
    let lin = |k: usize| -t + 2.0 * t * k as Real / 4.0;
    (0..25)
        .map(|n| (tip([p[0], p[1], p[2], lin(n % 5), lin(n / 5), 0.0]) - level).norm())
        .fold(0.0, Real::max)
}

fn json(out: &str) -> serde_json::Value {
    serde_json::from_str(out).unwrap_or_else(|e| panic!("json: {e}: {out}"))
}

fn num(v: &serde_json::Value) -> Real {
    v.as_f64().unwrap_or_else(|| panic!("a number: {v}"))
}

/// Calibrate on the twin → `--corrected` → `hexapod pivot --controller`: the pose errors the
/// calibrated controller leaves on the machine are what `identify` reported as "after",
/// both by this test's own kinematics and by `pivot`; the nominal controller's are the
/// scene's 0.3–0.5 mm.
#[test]
fn the_calibrated_controller_shows_what_identify_promised_for_both_procedures() {
    let sb = Sandbox::new("hexapod-controller-twin");
    let s = centre();
    let ws = s.workspace.expect("workspace");
    let home = s.home.position;
    // The nominal controller, by the test's kinematics and by the command.
    let nominal_pivot = own_pivot(&s.nominal, &s.actual, [home.x, home.y, home.z]);
    assert!(nominal_pivot > 0.3, "nominal pivot {nominal_pivot}");
    let (code, out, err) = sb.run(&["hexapod", "pivot", HEXAPOD_CENTRE, "--json"]);
    assert_eq!(code, 0, "{err}");
    let v = json(&out);
    assert!((num(&v["pivot"]["pivot_error_mm"]) - nominal_pivot).abs() < 1e-6);
    assert_eq!(v["controller"], "nominal");
    for procedure in ["ball-plate", "jig-free"] {
        let file = format!("{procedure}.toml");
        let (code, out, err) = sb.run(&[
            "identify",
            HEXAPOD_CENTRE,
            "--procedure",
            procedure,
            "--corrected",
            &file,
            "--json",
        ]);
        assert_eq!(code, 0, "{procedure}: {err}");
        let v = json(&out);
        let after = &v["run"]["after"];
        let (after_pos, after_piv) = (num(&after["position_mm"]), num(&after["pivot_mm"]));
        let fragment = std::fs::read_to_string(sb.dir.join(&file)).expect("written");
        let controller = controller_of(&s.nominal, &fragment);
        let (pos, piv) = own_pose_errors(&s.nominal, &controller, &s.actual, &ws);
        // The file's values are rounded to 1e-7 mm; the pose feels them amplified ~2×.
        assert!(
            (pos - after_pos).abs() < 2e-6 && (piv - after_piv).abs() < 2e-6,
            "{procedure}: own {pos} / {piv}, identify's after {after_pos} / {after_piv}"
        );
        // The calibration's class: µm, not the nominal controller's tenths of a mm.
        assert!(pos < 0.02 && piv < 0.02, "{procedure}: {pos} / {piv}");
        let (code, out, err) = sb.run(&[
            "hexapod",
            "pivot",
            HEXAPOD_CENTRE,
            "--controller",
            &file,
            "--json",
        ]);
        assert_eq!(code, 0, "{procedure}: {err}");
        let p = json(&out);
        let cli_piv = num(&p["pivot"]["pivot_error_mm"]);
        let cli_pos = num(&p["level_positioning"]["max_error_mm"]);
        let own = own_pivot(&controller, &s.actual, [home.x, home.y, home.z]);
        assert!(
            (cli_piv - own).abs() < 1e-6,
            "{procedure}: {cli_piv} vs {own}"
        );
        // Home is the workspace's centre, one of identify's five pivot points; the survey
        // is identify's 5 × 5 × 5 level grid.
        assert!(
            cli_piv <= after_piv + 1e-9,
            "{procedure}: {cli_piv} > {after_piv}"
        );
        assert!(
            (cli_pos - after_pos).abs() < 2e-6,
            "{procedure}: {cli_pos} vs {after_pos}"
        );
        assert!(p["controller"].as_str().is_some_and(|c| c.ends_with(&file)));
    }
}

/// Readings measured on the machine → `identify --readings … --corrected --html`: the
/// controller file applied leaves the µm class (this test's kinematics), `pivot` agrees; the
/// page is written; the genhexkins pins beside the file give the controller's strut lengths
/// by genhexkins' own formula.
#[test]
fn readings_calibrate_the_controller_and_write_its_page_and_genhexkins_pins() {
    let sb = Sandbox::new("hexapod-controller-readings");
    let s = centre();
    let ws = s.workspace.expect("workspace");
    let list = ball_plate_readings(&sb, &s.controller, &s.actual, &ws, 5, "c", "").join(",");
    let (code, out, err) = identify_ball_plate(
        &sb,
        HEXAPOD_CENTRE,
        &list,
        &["--corrected", "cal.toml", "--html", "cal.html", "--json"],
    );
    assert_eq!(code, 0, "{err}");
    let v = json(&out);
    assert!(num(&v["predicted_correction"]["position_mm"]) > 0.05);
    let page = std::fs::read_to_string(sb.dir.join("cal.html")).expect("page written");
    assert!(page.contains("identify --readings") && page.contains("bx_1"));
    let fragment = std::fs::read_to_string(sb.dir.join("cal.toml")).expect("written");
    let controller = controller_of(&s.nominal, &fragment);
    let (pos, piv) = own_pose_errors(&s.nominal, &controller, &s.actual, &ws);
    let (pos0, piv0) = own_pose_errors(&s.nominal, &s.nominal, &s.actual, &ws);
    // Ball plate, σ 0.5 µm: the 5 / 10 µm class of the round trips, from 0.3–0.5 mm.
    assert!(pos < 0.005 && piv < 0.010, "after {pos} / {piv}");
    assert!(pos0 > 0.2 && piv0 > 0.2, "before {pos0} / {piv0}");
    let home = s.home.position;
    let (code, out, err) = sb.run(&[
        "hexapod",
        "pivot",
        HEXAPOD_CENTRE,
        "--controller",
        "cal.toml",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let own = own_pivot(&controller, &s.actual, [home.x, home.y, home.z]);
    assert!((num(&json(&out)["pivot"]["pivot_error_mm"]) - own).abs() < 1e-6);

    // genhexkins: `setp genhexkins.base.N.x v` … and `platform.N.x` (platform joints about
    // the tool point), N = 0…5; its inverse kinematics L_i = |t + R·a_i − b_i|.
    let hal = std::fs::read_to_string(sb.dir.join("cal.hal")).expect("genhexkins file");
    let pins = hal_pins(&hal);
    let pin = |kind: &str, i: usize| {
        Vector3::from_fn(|k, _| pins[&format!("genhexkins.{kind}.{i}.{}", ["x", "y", "z"][k])])
    };
    for pose in [
        [0.0_f64, 0.0, 300.0, 0.0, 0.0, 0.0],
        [120.0, -80.0, 220.0, 10.0, -8.0, 5.0],
    ] {
        let (code, out, err) = sb.run(&[
            "hexapod",
            "ik",
            HEXAPOD_CENTRE,
            "--pose",
            &pose.map(|x| x.to_string()).join(","),
            "--controller",
            "cal.toml",
            "--json",
        ]);
        assert_eq!(code, 0, "{err}");
        let l = json(&out)["struts_mm"].clone();
        let r = super::hexapod_calibration::rotation(
            pose[3].to_radians(),
            pose[4].to_radians(),
            pose[5].to_radians(),
        );
        let t = Vector3::new(pose[0], pose[1], pose[2]);
        for i in 0..6 {
            let genhex = (t + r * pin("platform", i) - pin("base", i)).norm();
            assert!(
                (genhex - num(&l[i])).abs() < 1e-6,
                "strut {}: {genhex} vs {}",
                i + 1,
                l[i]
            );
        }
    }
    // The reference lengths as each joint's home offset.
    for i in 0..6 {
        let v = home_offset(&hal, i);
        let l0 = controller.reference_lengths()[i];
        assert!((v - l0).abs() < 1e-6, "joint {i}: {v} vs {l0}");
    }
}

/// A platform symmetric under 120° turns and a mirror (base joints on a 100 mm circle at
/// 75°, 105°, 195°, 225°, 315°, 345°; platform joints on a 50 mm circle each 30° from its
/// base joint), home level at z = 80 mm; every strut spans r² = 100² + 50² − 2·100·50·cos 30°
/// horizontally. Equal strut lengths L keep it level and centred (the symmetry), at
/// z = √(L² − r²).
fn symmetric_scene(extra: &str) -> String {
    let at = |r: Real, deg: Real| {
        let t = deg.to_radians();
        format!("[{:.17}, {:.17}, 0.0]", r * t.cos(), r * t.sin())
    };
    let base = [75.0, 105.0, 195.0, 225.0, 315.0, 345.0].map(|d| at(100.0, d));
    let platform = [45.0, 135.0, 165.0, 255.0, 285.0, 15.0].map(|d| at(50.0, d));
    format!(
        "name = \"symmetric\"\n[machine]\nkind = \"hexapod\"\nbase_joints = [{}]\n\
         platform_joints = [{}]\nhome = [0.0, 0.0, 80.0, 0.0, 0.0, 0.0]\n\
         [drives]\nlead_mm = 5.0\ncounts_per_rev = 1000\n{extra}",
        base.join(", "),
        platform.join(", ")
    )
}

/// `hexapod fk --actual`: every strut 0.3 mm longer than the controller believes
/// (`l0_i = 0.3`). Commanded the home lengths, the controller puts the tool at home and the
/// machine goes √((L + δ)² − r²) high; commanded 200 counts of a 5 mm lead / 1000 counts
/// (1 mm on every strut), √((L + 1)² − r²) and √((L + δ + 1)² − r²). A controller that
/// knows the offset (`--controller` with `l0_i = 0.3`) commands the same lengths (`ik`:
/// √(r² + z²)) and sends the machine where commanded.
#[test]
fn fk_actual_is_where_the_machine_goes_for_commanded_lengths_and_counts() {
    let sb = Sandbox::new("hexapod-fk-actual");
    let delta = 0.3;
    let devs: String = (1..=6).map(|i| format!("l0_{i} = {delta}\n")).collect();
    let scene = sb.write(
        "sym.toml",
        symmetric_scene(&format!("[deviations]\n{devs}")).as_bytes(),
    );
    let scene = scene.to_str().expect("utf-8");
    let ctrl = sb.write("ctrl.toml", format!("[controller]\n{devs}").as_bytes());
    let ctrl = ctrl.to_str().expect("utf-8");
    let r2 =
        100.0_f64.powi(2) + 50.0_f64.powi(2) - 2.0 * 100.0 * 50.0 * 30.0_f64.to_radians().cos();
    let l_home = (r2 + 80.0_f64.powi(2)).sqrt();
    let z_of = |l: Real| (l * l - r2).sqrt();
    let struts = vec![format!("{l_home:.15}"); 6].join(",");
    let counts = ["200"; 6].join(",");
    let run = |args: &[&str]| {
        let (code, out, err) = sb.run(args);
        assert_eq!(code, 0, "{args:?}: {err}");
        let p = json(&out)["pose"].clone();
        [0, 1, 2, 3, 4, 5].map(|k| num(&p[k]))
    };
    let level_at = |p: [Real; 6], z: Real, what: &str| {
        let want = [0.0, 0.0, z, 0.0, 0.0, 0.0];
        for k in 0..6 {
            assert!(
                (p[k] - want[k]).abs() < 1e-9,
                "{what}: {p:?}, expected {want:?}"
            );
        }
    };
    let fk = ["hexapod", "fk", scene];
    level_at(
        run(&[&fk[..], &["--struts", &struts, "--json"]].concat()),
        80.0,
        "controller",
    );
    level_at(
        run(&[&fk[..], &["--struts", &struts, "--actual", "--json"]].concat()),
        z_of(l_home + delta),
        "actual",
    );
    level_at(
        run(&[&fk[..], &["--counts", &counts, "--json"]].concat()),
        z_of(l_home + 1.0),
        "counts, controller",
    );
    level_at(
        run(&[&fk[..], &["--counts", &counts, "--actual", "--json"]].concat()),
        z_of(l_home + delta + 1.0),
        "counts, actual",
    );
    // The controller that knows the offsets: ik's lengths put the machine where commanded.
    let (code, out, err) = sb.run(&[
        "hexapod",
        "ik",
        scene,
        "--pose",
        "0,0,90,0,0,0",
        "--controller",
        ctrl,
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let l = json(&out)["struts_mm"].clone();
    for i in 0..6 {
        // Lengths are geometry: the reference lengths only turn them into readings.
        assert!((num(&l[i]) - (r2 + 8100.0).sqrt()).abs() < 1e-9, "{l}");
    }
    let lengths: Vec<String> = (0..6).map(|i| format!("{:.15}", num(&l[i]))).collect();
    level_at(
        run(&[
            &fk[..],
            &[
                "--struts",
                &lengths.join(","),
                "--actual",
                "--controller",
                ctrl,
                "--json",
            ],
        ]
        .concat()),
        90.0,
        "calibrated controller, actual",
    );
    // Counts need [drives]; fractions of a count are refused.
    let no_drives = sb.write(
        "nodrives.toml",
        symmetric_scene("")
            .replace("[drives]\nlead_mm = 5.0\ncounts_per_rev = 1000\n", "")
            .as_bytes(),
    );
    for (args, expect) in [
        (
            vec![
                "hexapod",
                "fk",
                no_drives.to_str().expect("utf-8"),
                "--counts",
                &counts,
            ],
            "--counts needs [drives]",
        ),
        (
            vec!["hexapod", "fk", scene, "--counts", "1,2,3,4,5,6.5"],
            "whole encoder counts",
        ),
    ] {
        let (code, out, err) = sb.run(&args);
        assert_ne!(code, 0, "{args:?}");
        assert!(out.is_empty() && err.trim().lines().count() == 1, "{err}");
        assert!(err.contains(expect), "{err}");
    }
}

/// Bad controller files name file, line and column; `--controller` on a serial scene is one
/// line; nothing is written.
#[test]
fn bad_controller_files_and_misplaced_controllers_are_one_line() {
    let sb = Sandbox::new("hexapod-controller-bad");
    let cases = [
        (
            "unknown.toml",
            "[controller]\nbx_1 = 0.1\ndx_C = 0.2\n",
            "unknown.toml:3:",
        ),
        ("nan.toml", "[controller]\nl0_2 = nan\n", "nan.toml:2:"),
        (
            "section.toml",
            "[deviations]\nbx_1 = 0.1\n",
            "section.toml:1:",
        ),
        ("far.toml", "[controller]\nbx_1 = 5000.0\n", "far.toml:2:"),
    ];
    for (name, text, expect) in cases {
        sb.write(name, text.as_bytes());
        for args in [
            vec!["hexapod", "pivot", HEXAPOD_CENTRE, "--controller", name],
            vec![
                "hexapod",
                "ik",
                HEXAPOD_CENTRE,
                "--pose",
                "0,0,300,0,0,0",
                "--controller",
                name,
            ],
            vec![
                "measure",
                HEXAPOD_CENTRE,
                "--instrument",
                "ballbar",
                "--controller",
                name,
                "--out",
                "bb.csv",
            ],
        ] {
            let (code, out, err) = sb.run(&args);
            assert_ne!(code, 0, "{args:?}");
            assert!(out.is_empty(), "{args:?}: {out}");
            assert_eq!(err.trim().lines().count(), 1, "{args:?}: {err}");
            assert!(err.contains(expect), "{args:?}: {err}");
            assert!(!err.contains("panicked"), "{err}");
        }
    }
    assert!(!sb.dir.join("bb.csv").exists());
    // A serial machine has no hexapod controller.
    let serial = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/mdx50-step.toml");
    sb.write("ok.toml", b"[controller]\nbx_1 = 0.1\n");
    for args in [
        vec![
            "simulate",
            serial.to_str().expect("utf-8"),
            "--controller",
            "ok.toml",
        ],
        vec![
            "measure",
            serial.to_str().expect("utf-8"),
            "--instrument",
            "laser",
            "--axis",
            "X",
            "--controller",
            "ok.toml",
        ],
    ] {
        let (code, _, err) = sb.run(&args);
        assert_ne!(code, 0, "{args:?}");
        assert_eq!(err.trim().lines().count(), 1, "{args:?}: {err}");
        assert!(err.contains("serial machine"), "{args:?}: {err}");
    }
    assert!(!sb.dir.join("out").exists());
    // The scene's own [controller] section is read the same way.
    let text = std::fs::read_to_string(Path::new(HEXAPOD_CENTRE)).expect("reads");
    let with = sb.write(
        "with-controller.toml",
        format!("{text}\n[controller]\nby_9 = 0.1\n").as_bytes(),
    );
    let (code, _, err) = sb.run(&["hexapod", "pivot", with.to_str().expect("utf-8")]);
    assert_ne!(code, 0);
    assert!(
        err.contains("with-controller.toml:") && err.contains("by_9"),
        "{err}"
    );
}

/// Seed 001's probe calibration → `controller.toml` → `--controller`: the file holds the
/// calibrated controller (this test's kinematics: the µm class from the nominal
/// controller's 0.3 mm), `hexapod pivot` runs on it, and a further `probe-calibrate` starts
/// from it (its "before" is the calibrated level, not the nominal one).
#[test]
fn the_probe_calibration_writes_a_controller_file_the_machine_runs_on() {
    let sb = Sandbox::new("hexapod-controller-probe");
    let s = centre();
    let ws = s.workspace.expect("workspace");
    let home = s.home.position;
    let (code, out, err) = sb.run(&[
        "hexapod",
        "probe-calibrate",
        HEXAPOD_CENTRE,
        "--out",
        "probe",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let first = json(&out);
    let fragment = std::fs::read_to_string(sb.dir.join("probe/controller.toml")).expect("written");
    let controller = controller_of(&s.nominal, &fragment);
    let (pos, piv) = own_pose_errors(&s.nominal, &controller, &s.actual, &ws);
    let (pos0, piv0) = own_pose_errors(&s.nominal, &s.nominal, &s.actual, &ws);
    assert!(
        pos0 > 0.3 && piv0 > 0.3,
        "nominal controller {pos0} / {piv0}"
    );
    assert!(
        pos < 0.015 && piv < 0.02,
        "calibrated controller {pos} / {piv}"
    );
    let (code, out, err) = sb.run(&[
        "hexapod",
        "pivot",
        HEXAPOD_CENTRE,
        "--controller",
        "probe/controller.toml",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let own = own_pivot(&controller, &s.actual, [home.x, home.y, home.z]);
    let cli = num(&json(&out)["pivot"]["pivot_error_mm"]);
    assert!((cli - own).abs() < 1e-6, "{cli} vs {own}");
    assert!(cli < 0.02, "{cli}");
    // A third round on the calibrated controller starts where the file left the machine.
    let (code, out, err) = sb.run(&[
        "hexapod",
        "probe-calibrate",
        HEXAPOD_CENTRE,
        "--controller",
        "probe/controller.toml",
        "--rounds",
        "1",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let again = json(&out);
    let before = num(&again["calibration"]["before"]["positioning_mm"]);
    let nominal_before = num(&first["calibration"]["before"]["positioning_mm"]);
    assert!(nominal_before > 0.3, "{nominal_before}");
    assert!(
        before < 0.015,
        "starts from the file's controller: {before}"
    );
}

/// The genhexkins pins of a `.hal` file (every line not a comment is `setp PIN VALUE`):
/// the 36 base and platform joint coordinates, by pin name.
pub fn hal_pins(hal: &str) -> std::collections::BTreeMap<String, Real> {
    let mut pins = std::collections::BTreeMap::new();
    for l in hal.lines().filter(|l| !l.starts_with('#')) {
        let w: Vec<&str> = l.split_whitespace().collect();
        assert_eq!((w.len(), w[0]), (3, "setp"), "{l}");
        pins.insert(w[1].to_string(), w[2].parse::<Real>().expect("a number"));
    }
    assert_eq!(pins.len(), 36);
    pins
}

/// Joint `i`'s home offset as the genhexkins file `hal` states it (its
/// `# [JOINT_i] HOME_OFFSET = …` line).
pub fn home_offset(hal: &str, i: usize) -> Real {
    let line = format!("# [JOINT_{i}] HOME_OFFSET = ");
    hal.lines()
        .find_map(|l| l.strip_prefix(line.as_str()))
        .expect("home offset")
        .parse()
        .expect("number")
}
