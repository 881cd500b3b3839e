//! One naming everywhere: an ISO 230-7 location term (`EY0C`, `EX0B`) names one parameter
//! in `[identify] parameters`, `design --params` and the identification they run, as it
//! does in `[deviations]` and `known`; a name the machine does not have is refused in one
//! line naming the file and line or the option.

use crate::{Sandbox, builtin};
use std::path::Path;
use twinmill::calibration::calibrate::IsoTerm;
use twinmill::calibration::design::{DesignOptions, design, design_with};
use twinmill::machine::chain::Chain;
use twinmill::pipeline::identify_scene;
use twinmill::progress::NoProgress;
use twinmill::scene::Scene;

/// The C-table step scene (`dy_CX = 13 µm` injected) identifying `params`, written with its
/// program into `dir`.
fn c_table(dir: &Path, params: &str) -> Scene {
    let toml = builtin("c-table-step.toml").replace(
        "known = {}",
        &format!("known = {{}}\nparameters = [{params}]"),
    );
    std::fs::create_dir_all(dir).expect("temp dir");
    std::fs::write(dir.join("c-table-step.ngc"), builtin("c-table-step.ngc")).expect("program");
    let path = dir.join("c-table-step.toml");
    std::fs::write(&path, toml).expect("scene");
    Scene::load(&path).expect("the scene loads")
}

#[test]
fn identify_values_a_table_location_term_as_one_parameter() {
    // C is first in the chain with its line through the origin: `EY0C = v` moves C's line
    // by L = Trans(0, v, 0), and the joint after C becomes L⁻¹·E_CX, i.e. dy_CX = −v (the
    // L before C only moves the workpiece zero). The scene injects dy_CX = 0.013 mm, so
    // EY0C is −0.013 mm; the halves cut at C = 0° and 180° step by 2·EY0C.
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("iso-names-identify");
    let iso = c_table(&dir.join("iso"), "\"EY0C\"");
    let joint = c_table(&dir.join("joint"), "\"dy_CX\"");
    let program = iso.load_program().expect("parses");
    let by_iso = identify_scene(&iso, &program, None, Some(0), &NoProgress).expect("identifies");
    let by_joint =
        identify_scene(&joint, &program, None, Some(0), &NoProgress).expect("identifies");
    let value = |r: &twinmill::report::IdentifyReport, name: &str| {
        r.identified
            .iter()
            .find(|e| e.name == name)
            .map(|e| (e.value, e.sigma))
            .unwrap_or_else(|| panic!("{name} identified: {:?}", r.identified))
    };
    let (v, s) = value(&by_iso.report, "EY0C");
    let (j, sj) = value(&by_joint.report, "dy_CX");
    let truth = -0.013;
    assert!(
        (v - truth).abs() <= 4.0 * s,
        "EY0C = {v:.6} ± {s:.1e}, expected {truth}"
    );
    assert!((v + j).abs() < 1e-9, "EY0C {v} is not −dy_CX {j}");
    assert!((s - sj).abs() < 1e-9 * sj.max(1.0), "σ {s} against {sj}");
    // An offset term is printed in mm, as its joint is.
    let line = by_iso
        .report
        .summary()
        .lines()
        .find(|l| l.contains("EY0C") && l.contains("identified"))
        .map(str::to_string)
        .expect("a line for EY0C");
    assert!(line.trim_end().ends_with(" mm"), "{line}");
    // The report's truth for the term is the scene's, under its ISO name.
    let injected = by_iso
        .report
        .identified
        .iter()
        .find(|e| e.name == "EY0C")
        .and_then(|e| e.injected);
    assert_eq!(injected, None, "the scene injects dy_CX, not EY0C");
    // The twin carries the term: its joint after C is −EY0C.
    let twin_dy = by_iso
        .twin
        .deviation(by_iso.twin.deviation_id("dy_CX").expect("known"));
    assert!(
        (twin_dy + v).abs() < 1e-12,
        "twin dy_CX {twin_dy}, EY0C {v}"
    );
}

/// The chain of the head-table scene (B head about Y, pivot 150 mm above the tip).
fn head_table() -> Chain {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("iso-names-head");
    std::fs::create_dir_all(&dir).expect("temp dir");
    std::fs::write(dir.join("head-table.ngc"), builtin("head-table.ngc")).expect("program");
    let path = dir.join("head-table.toml");
    std::fs::write(&path, builtin("head-table.toml")).expect("scene");
    Scene::load(&path).expect("loads").model().clone()
}

#[test]
fn a_head_location_term_is_one_parameter_over_two_joints() {
    // `EX0B = v` offsets the head's line by L = Trans(v, 0, 0): the joint before B becomes
    // E_ZB·L and the one after L⁻¹·E_BS, two joint values (dx_ZB = v, dx_BS = −v on the
    // nominal chain). As a parameter it is one: the term, its axis and its component.
    let chain = head_table();
    let t = IsoTerm::parse(&chain, "EX0B").expect("a location term of B");
    let b = chain
        .axes()
        .iter()
        .position(|a| a.letter.as_char() == 'B')
        .expect("B");
    assert_eq!(t.axis, b);
    let mut moved = chain.nominal();
    moved.apply_iso_term("EX0B", 0.01).expect("applies");
    let dx = |c: &Chain, n: &str| c.deviation(c.deviation_id(n).expect("known"));
    assert!((dx(&moved, "dx_ZB") - 0.01).abs() < 1e-15);
    assert!((dx(&moved, "dx_BS") + 0.01).abs() < 1e-15);
}

#[test]
fn design_takes_a_location_term_as_the_joint_it_moves() {
    // On the MDX-50 (A first in the chain, its line through the origin) EY0A and EZ0A move
    // the joint after A by −v: a design for them sees exactly what one for dy_AY and dz_AY
    // sees (same cuts, same singular values).
    let s = crate::scene();
    let model = s.model();
    let ids: Vec<_> = ["dy_AY", "dz_AY"]
        .iter()
        .map(|n| model.deviation_id(n).expect("known"))
        .collect();
    let terms: Vec<IsoTerm> = ["EY0A", "EZ0A"]
        .iter()
        .map(|n| IsoTerm::parse(model, n).expect("a term of A"))
        .collect();
    let o = DesignOptions::standard();
    let joint = design(model, &s.tool, &ids, &o).expect("a design");
    let iso = design_with(model, &s.tool, &[], &terms, &o, &Default::default()).expect("a design");
    let cuts = |d: &twinmill::calibration::design::Design| {
        d.cuts
            .iter()
            .map(|c| (c.name.clone(), c.index_deg))
            .collect::<Vec<_>>()
    };
    assert_eq!(cuts(&iso), cuts(&joint));
    assert_eq!(iso.identifiability.rank, 2);
    assert_eq!(
        iso.identifiability.identified,
        vec!["EY0A".to_string(), "EZ0A".to_string()]
    );
    for (a, b) in iso
        .identifiability
        .singular_values
        .iter()
        .zip(&joint.identifiability.singular_values)
    {
        assert!((a - b).abs() <= 1e-9 * b, "singular value {a} against {b}");
    }
}

#[test]
fn every_scene_command_takes_an_iso_name_in_identify_parameters() {
    // `simulate` never uses [identify]; a scene naming EX0C there is a valid scene.
    let sb = Sandbox::new("iso-names-simulate");
    sb.write("c-table-step.ngc", builtin("c-table-step.ngc").as_bytes());
    let scene = |params: &str| {
        builtin("c-table-step.toml").replace(
            "known = {}",
            &format!("known = {{}}\nparameters = [{params}]"),
        )
    };
    sb.write("ok.toml", scene("\"EX0C\", \"EY0C\"").as_bytes());
    let (code, _, stderr) = sb.run(&["simulate", "ok.toml", "--out", "ok-out"]);
    assert_eq!(code, 0, "{stderr}");
    // A name the machine does not have: one line naming the file and the line.
    let text = scene("\"EX0C\", \"EQ0C\"");
    let line = text
        .lines()
        .position(|l| l.contains("EQ0C"))
        .expect("the line")
        + 1;
    for (file, body, want) in [
        ("bad.toml", text.clone(), "EQ0C".to_string()),
        (
            "twice.toml",
            scene("\"EX0C\", \"EC0XY\", \"EC(0X)Y\""),
            "EC0XY".to_string(),
        ),
        ("axis.toml", scene("\"EX0A\""), "axis A".to_string()),
    ] {
        sb.write(file, body.as_bytes());
        let (code, stdout, stderr) = sb.run(&["simulate", file, "--out", "bad-out"]);
        assert_ne!(code, 0, "{file}");
        assert!(stdout.is_empty(), "{file}: {stdout}");
        assert_eq!(stderr.trim_end().lines().count(), 1, "{file}: {stderr}");
        assert!(
            stderr.contains(file) && stderr.contains(&want),
            "{file}: {stderr}"
        );
        if file == "bad.toml" {
            assert!(stderr.contains(&format!("{file}:{line}")), "{stderr}");
        }
        assert!(!sb.dir.join("bad-out").exists(), "nothing written");
    }
}

#[test]
fn design_params_refuse_a_name_the_machine_lacks_in_one_line() {
    let sb = Sandbox::new("iso-names-design");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/mdx50-step.toml");
    let scene = scene.to_str().expect("utf-8");
    for (params, want) in [("EY0A,EQ0A", "EQ0A"), ("EX0C", "axis C")] {
        let (code, stdout, stderr) = sb.run(&["design", scene, "--params", params, "--out", "d"]);
        assert_ne!(code, 0, "{params}");
        assert!(stdout.is_empty(), "{params}: {stdout}");
        assert_eq!(stderr.trim_end().lines().count(), 1, "{params}: {stderr}");
        assert!(
            stderr.contains("--params") && stderr.contains(want),
            "{params}: {stderr}"
        );
        assert!(!sb.dir.join("d").exists(), "nothing written");
    }
}

/// The value and σ a command's summary prints for `name` (`  EX0B  +9.964 ± 0.105 …` or
/// `identified  EC(0X)Y  +2.0e-5 ± 1.0e-8 rad`).
fn printed(stdout: &str, name: &str) -> (f64, f64) {
    let line = stdout
        .lines()
        .find(|l| l.split_whitespace().any(|w| w == name))
        .unwrap_or_else(|| panic!("no line for {name}: {stdout}"));
    let words: Vec<&str> = line.split_whitespace().collect();
    let pm = words.iter().position(|w| *w == "±").expect("value ± sigma");
    let num = |w: &str| w.parse::<f64>().unwrap_or_else(|_| panic!("{line}"));
    (num(words[pm - 1]), num(words[pm + 1]))
}

#[test]
fn measure_identifies_a_head_location_term_as_one_parameter() {
    // The head-table scene offsets B's line by EX0B = 10 µm and EZ0B = −30 µm: two joint
    // values each (the joints before and after B); the ball-sensor test identifies each
    // term as one parameter, within 4σ of the scene's value.
    let sb = Sandbox::new("iso-names-measure");
    sb.write("head-table.toml", builtin("head-table.toml").as_bytes());
    sb.write("head-table.ngc", builtin("head-table.ngc").as_bytes());
    let args = [
        "measure",
        "head-table.toml",
        "--instrument",
        "ball-sensor",
        "--identify",
        "EX0B,EZ0B",
        "--out",
        "t.csv",
    ];
    let (code, stdout, stderr) = sb.run(&args);
    assert_eq!(code, 0, "{stderr}");
    for (name, truth_um) in [("EX0B", 10.0), ("EZ0B", -30.0)] {
        let (v, s) = printed(&stdout, name);
        assert!(
            (v - truth_um).abs() <= 4.0 * s && s > 0.0,
            "{name} = {v} ± {s} µm, scene {truth_um}"
        );
    }
}

#[test]
fn identify_parameters_take_a_squareness_name() {
    // A ball-bar circle in XY sees X-to-Y squareness as the ellipse's axis along ±45°:
    // EC(0X)Y = 20 µrad in the measured machine is what `identify --parameters "EC(0X)Y"`
    // recovers on a model without it.
    let sb = Sandbox::new("iso-names-parameters");
    sb.write("xyz.toml", builtin("xyz-error-motions.toml").as_bytes());
    sb.write("xyz-pocket.ngc", builtin("xyz-pocket.ngc").as_bytes());
    let (code, _, stderr) = sb.run(&[
        "measure",
        "xyz.toml",
        "--instrument",
        "ballbar",
        "--plane",
        "XY",
        "--out",
        "bb-XY.csv",
    ]);
    assert_eq!(code, 0, "{stderr}");
    // Identified on the machine without it: the solve starts from zero.
    let square = builtin("xyz-error-motions.toml");
    let line = square
        .lines()
        .find(|l| l.starts_with("\"EC(0X)Y\""))
        .expect("the scene's squareness");
    sb.write("xyz0.toml", square.replace(line, "").as_bytes());
    let (code, stdout, stderr) = sb.run(&[
        "identify",
        "xyz0.toml",
        "--measurement",
        "bb-XY.csv",
        "--parameters",
        "EC(0X)Y",
        "--deviations-out",
        "d.toml",
    ]);
    assert_eq!(code, 0, "{stderr}");
    let (v, s) = printed(&stdout, "EC(0X)Y");
    assert!(
        (v - 20e-6).abs() <= 4.0 * s && s > 0.0,
        "EC(0X)Y = {v} ± {s}"
    );
}
