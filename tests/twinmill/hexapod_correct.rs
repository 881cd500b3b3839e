//! `twinmill correct` on a hexapod, end to end through the command line: the written
//! program's block ends driven through the controller's inverse kinematics and the actual
//! machine's forward kinematics (the independent oracle of `hexapod_cut.rs`) reach the
//! nominal poses; the step experiment's faces meet after correction; a corrected pose out
//! of the stroke is refused in one line.

use super::Sandbox;
use super::hexapod_cut::{Oracle, face_height, load, reached, rpy, scene_path, z_top};
use nalgebra::Vector6;
use twinmill::math::{Real, Vector3};
use twinmill::pipeline::machine_part;
use twinmill::progress::NoProgress;

/// One block of a written program: its end (X Y Z mm, A B C degrees), source line and part
/// `(k, n)` (`None` for the positioning block).
type WrittenBlock = ([Real; 6], Option<(usize, usize, usize)>);

/// The G0/G1 blocks of a corrected program's text, read here (not by the interpreter).
fn written_blocks(text: &str) -> Vec<WrittenBlock> {
    let mut out = Vec::new();
    for line in text.lines() {
        if !(line.starts_with("G0 ") || line.starts_with("G1 ")) {
            continue;
        }
        let (code, comment) = line.split_once('(').expect("a comment on every block");
        let mut q = [Real::NAN; 6];
        for w in code.split_whitespace().skip(1) {
            let (l, v) = w.split_at(1);
            if let Some(k) = "XYZABC".find(l) {
                q[k] = v.parse().expect("a number");
            }
        }
        assert!(q.iter().all(|v| v.is_finite()), "{line}");
        let source = comment.strip_prefix("src line ").map(|rest| {
            let rest = rest.trim_end_matches(')');
            match rest.split_once(", ") {
                Some((l, part)) => {
                    let (k, n) = part.split_once('/').expect("k/n");
                    (
                        l.parse().expect("line"),
                        k.parse().expect("k"),
                        n.parse().expect("n"),
                    )
                }
                None => (rest.parse().expect("line"), 1, 1),
            }
        });
        out.push((q, source));
    }
    out
}

/// The source program's blocks by line: start and end (mm, degrees), from the text of a
/// program in absolute mode where every block names the axes it moves (the previous
/// block's values for the others).
fn source_moves(text: &str, home: [Real; 6]) -> Vec<(usize, [Real; 6], [Real; 6])> {
    let mut at = home;
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let code = line.split('(').next().unwrap_or("");
        let words: Vec<&str> = code.split_whitespace().collect();
        if !words.iter().any(|w| *w == "G0" || *w == "G1") {
            continue;
        }
        let mut end = at;
        for w in &words {
            let (l, v) = w.split_at(1);
            if let Some(k) = "XYZABC".find(l) {
                end[k] = v.parse().expect("a number");
            }
        }
        out.push((i + 1, at, end));
        at = end;
    }
    out
}

/// The reached pose of every written block end against the nominal pose at its part of
/// its source move: position (mm) and orientation (rad), the largest of each. `controller`
/// computes the readings, `actual` is the machine.
fn block_end_errors(
    written: &str,
    source: &str,
    home: [Real; 6],
    controller: &Oracle,
    actual: &Oracle,
) -> (Real, Real, usize) {
    let moves = source_moves(source, home);
    let (mut dp, mut da, mut n) = (0.0 as Real, 0.0 as Real, 0);
    for (q, src) in written_blocks(written) {
        let Some((line, k, parts)) = src else {
            continue;
        };
        let (_, a, b) = moves
            .iter()
            .find(|m| m.0 == line)
            .copied()
            .unwrap_or_else(|| panic!("source line {line}"));
        let s = k as Real / parts as Real;
        let want: [Real; 6] = std::array::from_fn(|i| a[i] + (b[i] - a[i]) * s);
        let got = reached(controller, actual, q);
        let pos =
            (Vector3::new(got[0], got[1], got[2]) - Vector3::new(want[0], want[1], want[2])).norm();
        let (rg, rw) = (
            rpy(got[3], got[4], got[5]),
            rpy(
                want[3].to_radians(),
                want[4].to_radians(),
                want[5].to_radians(),
            ),
        );
        // The rotation between them: its angle, from its skew part (sin of the angle, exact
        // to rounding for small angles, where the trace's acos is not).
        let d = rg.transpose() * rw;
        let angle = (Vector3::new(
            d[(2, 1)] - d[(1, 2)],
            d[(0, 2)] - d[(2, 0)],
            d[(1, 0)] - d[(0, 1)],
        )
        .norm()
            / 2.0)
            .asin();
        dp = dp.max(pos);
        da = da.max(angle);
        n += 1;
    }
    (dp, da, n)
}

/// The controller's interpolation between the written block ends at ¼, ½ and ¾ of every
/// block against the nominal pose at the same parameter of its source move: the largest
/// distance of the tool tip or the flute's end (`flute` mm up the tool axis) (mm), and the
/// number of blocks that are parts of a split move.
fn chord_error(
    written: &str,
    source: &str,
    home: [Real; 6],
    controller: &Oracle,
    actual: &Oracle,
    flute: Real,
) -> (Real, usize) {
    let moves = source_moves(source, home);
    let blocks = written_blocks(written);
    let (mut worst, mut split) = (0.0 as Real, 0);
    let axis_points = |p: &Vector6<Real>| {
        let tip = Vector3::new(p[0], p[1], p[2]);
        [
            tip,
            tip + rpy(p[3], p[4], p[5]) * Vector3::new(0.0, 0.0, flute),
        ]
    };
    for w in blocks.windows(2) {
        let (from, (to, src)) = (w[0].0, w[1]);
        let Some((line, k, parts)) = src else {
            continue;
        };
        split += usize::from(parts > 1);
        let (_, a, b) = moves
            .iter()
            .find(|m| m.0 == line)
            .copied()
            .unwrap_or_else(|| panic!("source line {line}"));
        for t in [0.25, 0.5, 0.75] {
            let cmd: [Real; 6] = std::array::from_fn(|i| from[i] + (to[i] - from[i]) * t);
            let s = (k as Real - 1.0 + t) / parts as Real;
            let want: [Real; 6] = std::array::from_fn(|i| a[i] + (b[i] - a[i]) * s);
            let want = Vector6::new(
                want[0],
                want[1],
                want[2],
                want[3].to_radians(),
                want[4].to_radians(),
                want[5].to_radians(),
            );
            let got = reached(controller, actual, cmd);
            for (g, n) in axis_points(&got).iter().zip(axis_points(&want)) {
                worst = worst.max((g - n).norm());
            }
        }
    }
    (worst, split)
}

fn oracle(h: &twinmill::machine::hexapod::Hexapod) -> Oracle {
    Oracle::new(&h.parameters(), h.tool_offset())
}

/// The orientation the written angles can hold: each printed to 1e-7° (rounding up to
/// 8.7e-10 rad), three of them.
const ANGLE_PRINTED_RAD: Real = 3e-9;

const HOME: [Real; 6] = [0.0, 0.0, 300.0, 0.0, 0.0, 0.0];

fn report(sb: &Sandbox, name: &str) -> serde_json::Value {
    let text = std::fs::read_to_string(sb.dir.join("out").join(format!("{name}-correct.json")))
        .expect("report written");
    serde_json::from_str(&text).expect("json")
}

/// The step experiment (strut 1 0.1 mm long): the uncorrected faces stand apart by the step
/// the oracle derives; after `correct` the written program's block ends reach their nominal
/// poses within 0.1 µm and 3e-9 rad (the printing: 1e-7° per angle), and the program cut on the deviated machine leaves both
/// faces at the commanded height: they meet within 1 µm.
#[test]
fn correct_makes_the_hexapod_step_faces_meet() {
    let path = scene_path("hexapod-step.toml");
    let (scene, hex) = load(&path);
    let (nominal, actual) = (oracle(&hex.nominal), oracle(&hex.actual));
    let r = scene.tool.radius();
    // The step as cut uncorrected, from the oracle (faces A and B as hexapod_cut.rs cuts them).
    let oa = face_height(
        &nominal,
        &actual,
        (-90.0, -4.0),
        (0.0, 159.0),
        [0.0, 0.0, -20.0],
        r,
        (-30.0, 0.0),
    );
    let ob = face_height(
        &nominal,
        &actual,
        (90.0, 4.0),
        (0.0, 159.0),
        [0.0, 0.0, 20.0],
        r,
        (30.0, 0.0),
    );
    assert!((ob - oa).abs() > 0.01, "uncorrected step {}", ob - oa);

    let sb = Sandbox::new("hexapod-correct-step");
    let scene_arg = path.to_str().expect("utf-8");
    let (code, out, err) = sb.run(&["correct", scene_arg, "--out", "out"]);
    // The exit code after the oracle's checks: they judge the written program themselves.
    let ran = format!("exit {code}: {out}\n{err}");
    let written = std::fs::read_to_string(sb.dir.join("out/hexapod-step-corrected.ngc"))
        .unwrap_or_else(|e| panic!("{e}: {ran}"));
    let source = std::fs::read_to_string(scene_path("hexapod-step.ngc")).expect("source");
    let (dp, da, n) = block_end_errors(&written, &source, HOME, &nominal, &actual);
    assert!(n >= 9, "{n} blocks checked");
    assert!(
        dp < 1e-4,
        "a block end reaches {dp} mm off its nominal pose"
    );
    assert!(
        da < ANGLE_PRINTED_RAD,
        "a block end is turned {da} rad off its nominal pose"
    );
    // Between them, the controller's interpolation: within the path tolerance (a quarter of
    // the 1 µm accuracy) plus the ends' printing (1 nm, 1e-7°), on moves split for it.
    let flute = scene.tool.length();
    let (chord, split) = chord_error(&written, &source, HOME, &nominal, &actual, flute);
    assert!(
        chord <= 0.25e-3 + 2e-6,
        "the interpolated path is {chord} mm off"
    );
    assert!(split > 0, "no move split");

    // The verification's own figures: the part as given off by the step's faces, the
    // corrected one within 1 µm.
    assert!(ran.starts_with("exit 0:"), "{ran}");
    let rep = report(&sb, "hexapod-step");
    assert_eq!(rep["met"], true, "{rep}");
    let its = rep["iterations"].as_array().expect("iterations");
    let given = its[0]["part"]["max_mm"].as_f64().expect("number");
    let worst = (oa - 159.0).abs().max((ob - 159.0).abs());
    assert!(
        given >= worst - 1e-3,
        "as given {given} vs the oracle's {worst}"
    );
    let last = its.last().expect("a pass");
    assert!(last["part"]["max_mm"].as_f64().expect("number") <= 1e-3);
    assert!(last["path"]["max_mm"].as_f64().expect("number") <= 1e-3);

    // The written program cut on the deviated machine: both faces at the commanded height.
    let corrected = scene.program_from_text(&written).expect("parses");
    let part = machine_part(&scene, &corrected, &NoProgress).expect("cuts");
    let (_, _, za) = z_top(&part.stock, -30.0, 0.0);
    let (_, _, zb) = z_top(&part.stock, 30.0, 0.0);
    assert!((za - 159.0).abs() < 1e-3, "face A at {za}");
    assert!((zb - 159.0).abs() < 1e-3, "face B at {zb}");
    assert!((zb - za).abs() < 1e-3, "step after correction {}", zb - za);
}

/// The machining centre's twelve deviations on the step program, run by a partly calibrated
/// controller (`--controller FILE`): the block ends reach the nominal poses through *that*
/// controller's inverse kinematics, and the twin's verification puts path and part within
/// 1 µm.
#[test]
fn correct_of_a_hexapod_with_several_deviations_and_a_calibrated_controller() {
    let centre =
        std::fs::read_to_string(scene_path("hexapod-machining-centre.toml")).expect("scene");
    let devs: String = centre
        .split("[deviations]\n")
        .nth(1)
        .and_then(|s| s.split("\n\n").next())
        .expect("the centre's deviations")
        .to_string();
    assert_eq!(devs.lines().count(), 12, "{devs}");
    let step = std::fs::read_to_string(scene_path("hexapod-step.toml")).expect("scene");
    let text = step.replace("l0_1 = 0.1", &devs);
    let sb = Sandbox::new("hexapod-correct-many");
    let path = sb.write("hexapod-many.toml", text.as_bytes());
    sb.write(
        "hexapod-step.ngc",
        &std::fs::read(scene_path("hexapod-step.ngc")).expect("program"),
    );
    // A controller calibrated on two parameters of twelve, one of them wrongly.
    let ctl = sb.write("ctl.toml", b"[controller]\nbx_1 = 0.15\nl0_1 = 0.02\n");
    let (code, out, err) = sb.run(&[
        "correct",
        path.to_str().expect("utf-8"),
        "--controller",
        ctl.to_str().expect("utf-8"),
        "--out",
        "out",
    ]);
    // The exit code after the oracle's checks: they judge the written program themselves.
    let ran = format!("exit {code}: {out}\n{err}");
    let (_, mut hex) = load(&path);
    hex.apply_controller_file(&ctl).expect("controller file");
    assert!(hex.calibrated_controller());
    let (controller, actual) = (oracle(&hex.controller), oracle(&hex.actual));
    let written = std::fs::read_to_string(sb.dir.join("out/hexapod-step-corrected.ngc"))
        .unwrap_or_else(|e| panic!("{e}: {ran}"));
    let source = std::fs::read_to_string(scene_path("hexapod-step.ngc")).expect("source");
    let (dp, da, n) = block_end_errors(&written, &source, HOME, &controller, &actual);
    assert!(n >= 9, "{n}");
    assert!(dp < 1e-4, "{dp} mm");
    assert!(da < ANGLE_PRINTED_RAD, "{da} rad");
    // The tool of hexapod-step.toml: 40 mm long.
    let (chord, split) = chord_error(&written, &source, HOME, &controller, &actual, 40.0);
    assert!(
        chord <= 0.25e-3 + 2e-6,
        "the interpolated path is {chord} mm off"
    );
    assert!(split > 0, "no move split");
    // The program as given misses by the deviations (tenths of a mm).
    let (dp0, _, _) = block_end_errors(
        &source_as_written(&source),
        &source,
        HOME,
        &controller,
        &actual,
    );
    assert!(dp0 > 0.05, "as given only {dp0} mm off");
    assert!(ran.starts_with("exit 0:"), "{ran}");
    let rep = report(&sb, "hexapod-step");
    assert_eq!(rep["met"], true, "{rep}");
    let last = rep["iterations"]
        .as_array()
        .and_then(|v| v.last().cloned())
        .expect("a pass");
    assert!(
        last["path"]["max_mm"].as_f64().expect("number") <= 1e-3,
        "{last}"
    );
    assert!(
        last["part"]["max_mm"].as_f64().expect("number") <= 1e-3,
        "{last}"
    );
}

/// The source program's blocks in the written form (every axis, the source line named), to
/// measure the program as given with the same oracle.
fn source_as_written(source: &str) -> String {
    source_moves(source, HOME)
        .iter()
        .map(|(line, _, e)| {
            format!(
                "G1 X{} Y{} Z{} A{} B{} C{} (src line {line})\n",
                e[0], e[1], e[2], e[3], e[4], e[5]
            )
        })
        .collect()
}

/// A level move up to Z 400 with the stroke's lower end 0.05 mm below the struts there:
/// the program as given stays in the stroke, but strut 1, 0.1 mm long, needs its
/// controller length 0.1 mm shorter: refused in one line naming the program's line, exit
/// non-zero, nothing written.
#[test]
fn correct_refuses_a_corrected_pose_out_of_the_stroke() {
    let (_, hex) = load(&scene_path("hexapod-step.toml"));
    let nominal = oracle(&hex.nominal);
    let top = Vector6::new(0.0, 0.0, 400.0, 0.0, 0.0, 0.0);
    // Lengths at Z 400 (readings plus reference lengths): equal within the joints'
    // rounding on this design.
    let lengths: Vec<Real> = (0..6)
        .map(|i| nominal.readings(&top)[i] + hex.nominal.reference_lengths()[i])
        .collect();
    let shortest = lengths.iter().cloned().fold(Real::INFINITY, Real::min);
    assert!(
        lengths.iter().all(|l| (l - shortest).abs() < 0.01),
        "{lengths:?}"
    );
    // Strut 1 corrected (0.1 mm shorter) falls below the stroke's lower end.
    assert!(lengths[0] - 0.1 < shortest - 0.05, "{lengths:?}");
    let text = std::fs::read_to_string(scene_path("hexapod-step.toml"))
        .expect("scene")
        .replace(
            "stroke_mm = [700.0, 1400.0]",
            &format!("stroke_mm = [{:.6}, 1400.0]", shortest - 0.05),
        );
    let sb = Sandbox::new("hexapod-correct-refuse");
    let path = sb.write("hexapod-high.toml", text.as_bytes());
    sb.write(
        "hexapod-step.ngc",
        b"G21 G90 G94\nG0 X0 Y0 Z300 A0 B0 C0\nG1 Z400 F600\nM2\n",
    );
    let (code, out, err) = sb.run(&["correct", path.to_str().expect("utf-8"), "--out", "out"]);
    assert_ne!(code, 0, "{out}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(err.contains("hexapod-step.ngc:3"), "{err}");
    assert!(err.contains("stroke"), "{err}");
    assert!(!sb.dir.join("out").exists(), "wrote on refusal");
}
