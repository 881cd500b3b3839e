//! NC correction: the corrected program, simulated on the deviated machine, cuts the
//! nominal faces. Measured here from the dexel crossings against the nominal face of the
//! independent 4 × 4 derivation, not with the correction module's own measurement.

use crate::{Sandbox, builtin, exact_face, scene, set_deviation};
use std::path::Path;
use twinmill::cutting::stock::TriDexel;
use twinmill::cutting::sweep::{SweepOptions, sweep_program};
use twinmill::math::Real;
use twinmill::nc::Move;
use twinmill::pipeline::run;
use twinmill::progress::NoProgress;
use twinmill::scene::Scene;

/// Sweeps `moves` on the scene's (deviated) machine and returns, per face (A0 upper half,
/// A180 lower half), the signed distances of the face's crossings from the nominal face
/// Y_W = −22 (from `exact_face` with zero deviations), positive into the material.
fn face_distances(s: &Scene, moves: &[Move]) -> [Vec<Real>; 2] {
    let mut stock = TriDexel::new_box(s.stock_box, s.pitch_mm, 4e9).expect("fits");
    let opts = SweepOptions {
        rotary_step_bound_mm: 1e-5,
    };
    sweep_program(&mut stock, s.chain(), &s.tool, moves, &opts, &NoProgress).expect("sweeps");
    let zero = [[0.0; 6]; 4];
    let (n, d) = exact_face(&zero, -25.0, 0.0, s.tool.radius());
    let mut out = [Vec::new(), Vec::new()];
    for (k, (z0, z1)) in [(1.5, 8.5), (-8.5, -1.5)].into_iter().enumerate() {
        for g in stock.grids() {
            g.for_each_crossing(|p, c| {
                if p.x.abs() <= 18.0
                    && p.z >= z0
                    && p.z <= z1
                    && (p.y + 22.0).abs() <= 1.8
                    && c.normal().y < -0.9
                {
                    // n points to +Y (into the material); d is the face's offset.
                    out[k].push(n.dot(&p.coords) - d);
                }
            });
        }
    }
    out
}

fn mean(v: &[Real]) -> Real {
    v.iter().sum::<Real>() / v.len() as Real
}

fn max_abs(v: &[Real]) -> Real {
    v.iter().fold(0.0, |m, x| m.max(x.abs()))
}

#[test]
fn corrected_program_leaves_no_step_on_the_paper_scene() {
    let s = scene();
    let program = s.load_program().expect("parses");
    // Sanity of the measurement: the program as given leaves the paper's 1 mm step.
    let [a0, a180] = face_distances(&s, &program.moves);
    let step = mean(&a180) - mean(&a0);
    assert!((step.abs() - 1.0).abs() < 1e-6, "uncorrected step {step}");

    let out =
        twinmill::pipeline::correct(&s, &program, s.chain(), 1e-3, &NoProgress).expect("corrects");
    assert!(out.report.met, "{}", out.report.status);
    let [a0, a180] = face_distances(&s, &out.corrected.moves);
    assert!(a0.len() > 5000 && a180.len() > 5000);
    let step = mean(&a180) - mean(&a0);
    assert!(step.abs() < 1e-3, "corrected step {step} mm");
    assert!(max_abs(&a0) < 1e-3 && max_abs(&a180) < 1e-3);
    // In fact at the G-code's resolution.
    assert!(step.abs() < 1e-5, "corrected step {step} mm");

    // The emitted program is the simulated one: read back, it gives the same moves.
    let mut text = Vec::new();
    twinmill::calibration::correct::write_gcode(&out.corrected, &out.header, &mut text)
        .expect("writes");
    let text = String::from_utf8(text).expect("utf-8");
    assert!(text.contains("G21 G90 G94") && text.contains("(src line 9)"));
    assert!(text.contains("(src line 14)") && text.contains("F600"));
    // The minimal reader has no G94 (the default mode it assumes): drop the word.
    let parsed = twinmill::nc::parse_program(
        &text.replace(" G94", ""),
        Path::new("corrected.ngc"),
        s.home(),
    )
    .expect("the corrected program parses");
    assert_eq!(parsed.moves.len(), out.corrected.moves.len());
    for (a, b) in parsed.moves.iter().zip(&out.corrected.moves) {
        assert_eq!((a.kind, a.start, a.end), (b.kind, b.start, b.end));
        assert_eq!(a.feed_mm_per_min, b.feed_mm_per_min);
    }
}

/// The nine deviations of seed 002 Fig. 3, with the size each is set to.
const NINE_SIZED: [(&str, Real); 9] = [
    ("dy_AY", 0.5),
    ("dz_AY", 0.5),
    ("beta_AY", 5e-4),
    ("gamma_AY", 5e-4),
    ("alpha_YX", 5e-4),
    ("gamma_YX", 5e-4),
    ("beta_XZ", 5e-4),
    ("alpha_ZS", 5e-4),
    ("beta_ZS", 5e-4),
];

#[test]
fn mixed_deviation_sets_are_corrected_to_within_1_um_on_the_faces() {
    let rng = twinmill::math::CounterRng::new(2002);
    let program = scene().load_program().expect("parses");
    for set in 0..12u64 {
        let mut s = scene();
        set_deviation(&mut s, "dy_AY", 0.0);
        let mut beta = 0.0;
        let mut any = false;
        for (k, (name, size)) in NINE_SIZED.iter().enumerate() {
            // Each deviation in two sets of three, with a random sign; the last set all.
            if set == 11 || rng.uniform(set, k as u64) < 2.0 / 3.0 {
                let sign = if rng.uniform(set, 100 + k as u64) < 0.5 {
                    -1.0
                } else {
                    1.0
                };
                set_deviation(&mut s, name, sign * size);
                any = true;
                if name.starts_with("beta") {
                    beta += sign * size;
                }
            }
        }
        assert!(any);
        let out = twinmill::pipeline::correct(&s, &program, s.chain(), 1e-3, &NoProgress)
            .expect("corrects");
        let [a0, a180] = face_distances(&s, &out.corrected.moves);
        assert!(a0.len() > 5000 && a180.len() > 5000, "set {set}");
        let (m0, m1) = (max_abs(&a0), max_abs(&a180));
        assert!(
            m0 < 1e-3 && m1 < 1e-3,
            "set {set} {:?}: faces off by {m0} and {m1} mm",
            s.injected()
        );
        // And every cut surface of the part, against the program as given on the nominal
        // machine, ray by ray: no floor or other surface shows the uncorrectable tilt.
        let last = out.report.iterations.last().expect("a pass");
        assert!(
            last.part.crossings > 50_000 && last.part.unmatched_rays == 0,
            "set {set}"
        );
        assert!(last.part.max_mm < 1e-3, "set {set}: part {:?}", last.part);
        // What four axes cannot correct: the tool's tilt about Y, the beta sum. The best
        // line through the tilted axis crosses the nominal one mid-flute: RMS |β|·L/√12.
        let expect = beta.abs() * s.tool.length() / 12.0_f64.sqrt();
        let got = out.report.correction.residual_rms_mm;
        assert!(
            // Second-order products of the angles (2.5e-7 rad) add up to 2e-6 mm.
            (got - expect).abs() <= 0.01 * expect + 1e-5,
            "set {set}: residual {got} vs {expect}"
        );
        // It tilts the tool in the plane of the cut direction (X) and the tool axis: the
        // flank, parallel to both, does not move — hence the faces above are exact anyway.
        // With a beta sum the tool's ends stay |β|·L/2 ≥ 6 µm off the nominal path: the
        // report says the accuracy is met on the faces, not on the path.
        let no_tilt = beta.abs() < 1e-12;
        assert_eq!(out.report.met, no_tilt, "set {set}: {}", out.report.status);
        assert!(
            out.report
                .status
                .contains(if no_tilt { "met in" } else { "faces within" })
        );
    }
}

#[test]
fn correcting_for_identified_deviations_closes_the_loop() {
    // Seed 002 Fig. 1: scan the part, identify, correct for what was identified, and cut
    // again on the (unchanged) machine. The scanner's noise leaves dy_AY a fraction of a µm
    // off, and the step after correction is that error twice.
    let s = scene();
    let program = s.load_program().expect("parses");
    let run_out = run(&s, &program, &NoProgress).expect("runs");
    let model = twinmill::pipeline::identified_model(&s, &run_out.report).expect("identified");
    let dy = model.deviation(model.deviation_id("dy_AY").expect("known"));
    assert_eq!(dy, run_out.report.identified["dy_AY"]);
    let out =
        twinmill::pipeline::correct(&s, &program, &model, 1e-3, &NoProgress).expect("corrects");
    let [a0, a180] = face_distances(&s, &out.corrected.moves);
    let step = mean(&a180) - mean(&a0);
    let expect = 2.0 * (dy + 0.5);
    assert!(
        (step.abs() - expect.abs()).abs() < 1e-5,
        "step {step} vs {expect}"
    );
    assert!(
        step.abs() < 1e-3,
        "step {step} mm after correcting for dy_AY = {dy}"
    );
}

#[test]
fn correct_rejects_bad_accuracy_and_unreachable_poses() {
    let s = scene();
    let program = s.load_program().expect("parses");
    for acc in [0.0, -1.0, Real::NAN, Real::INFINITY] {
        let e = twinmill::pipeline::correct(&s, &program, s.chain(), acc, &NoProgress)
            .expect_err("bad accuracy");
        assert!(e.to_string().contains("accuracy"), "{e}");
    }
    let mut far = s.chain().clone();
    far.set_deviation(far.deviation_id("dz_AY").expect("known"), 50.0);
    let e = twinmill::pipeline::correct(&s, &program, &far, 1e-3, &NoProgress)
        .expect_err("unreachable");
    assert!(e.to_string().contains("not reachable"), "{e}");
    assert!(e.to_string().contains("mdx50-step.ngc:"), "{e}");
}

#[test]
fn cli_correct_writes_program_and_report_or_nothing() {
    let sb = Sandbox::new("correct");
    sb.write("s.toml", builtin("mdx50-step.toml").as_bytes());
    sb.write("mdx50-step.ngc", builtin("mdx50-step.ngc").as_bytes());
    let (code, stdout, stderr) = sb.run(&["correct", "s.toml", "--out", "c", "--json"]);
    assert_eq!(code, 0, "{stderr}");
    let report: serde_json::Value = serde_json::from_str(&stdout).expect("json");
    assert_eq!(report["met"], serde_json::Value::Bool(true));
    let its = report["iterations"].as_array().expect("iterations");
    assert!(its.len() >= 2);
    assert!(
        its[0]["faces"]["step_mm"]
            .as_f64()
            .is_some_and(|x| (x.abs() - 1.0).abs() < 1e-6)
    );
    let ngc = std::fs::read_to_string(sb.dir.join("c/mdx50-step-corrected.ngc")).expect("ngc");
    assert!(
        ngc.starts_with("%\n(")
            && ngc.contains("Y-24.500000")
            && ngc.trim_end().ends_with("M30\n%")
    );
    assert!(sb.dir.join("c/mdx50-step-correct.json").exists());
    // Bad input: a clear one-line error, no files.
    for (args, words) in [
        (
            vec!["correct", "s.toml", "--out", "bad", "--accuracy-mm", "0"],
            "accuracy",
        ),
        (
            vec!["correct", "s.toml", "--out", "bad", "--accuracy-mm", "-1"],
            "accuracy",
        ),
        (
            vec!["correct", "s.toml", "--out", "bad", "--accuracy-mm", "nan"],
            "accuracy",
        ),
    ] {
        let (code, _, stderr) = sb.run(&args);
        assert_ne!(code, 0);
        assert!(
            stderr.contains(words) && !stderr.contains("panicked"),
            "{stderr}"
        );
        assert_eq!(stderr.trim_end().lines().count(), 1, "{stderr}");
    }
    // The nine deviations: faces met, the path not (the beta tilt): exit code 2, files
    // written, the reason on stderr.
    let mut nine = builtin("mdx50-step.toml");
    for (name, size) in NINE_SIZED.iter().skip(1) {
        nine = nine.replace("dy_AY = -0.50", &format!("dy_AY = -0.50\n{name} = {size}"));
    }
    sb.write("nine.toml", nine.as_bytes());
    let (code, stdout, stderr) = sb.run(&["correct", "nine.toml", "--out", "nine"]);
    assert_eq!(code, 2, "{stdout}{stderr}");
    assert!(
        stderr.contains("not met") && stderr.contains("cannot correct"),
        "{stderr}"
    );
    assert!(stdout.contains("beta_ZS") && sb.dir.join("nine/mdx50-step-corrected.ngc").exists());
    sb.write(
        "far.toml",
        builtin("mdx50-step.toml")
            .replace("dy_AY = -0.50", "dy_AY = -40.0")
            .as_bytes(),
    );
    let (code, _, stderr) = sb.run(&["correct", "far.toml", "--out", "bad"]);
    assert_ne!(code, 0);
    assert!(
        stderr.contains("not reachable") && !stderr.contains("panicked"),
        "{stderr}"
    );
    assert!(
        !sb.dir.join("bad").exists()
            || std::fs::read_dir(sb.dir.join("bad"))
                .expect("dir")
                .next()
                .is_none()
    );
}

/// The whole-part figure is a distance between surfaces: on a 3-axis machine whose X joint
/// sits 50 µm off, every cut surface of the program as given is the nominal one moved
/// rigidly by t = (0.05, 0, 0) mm, so its distance from the nominal surface is |n·t| —
/// 50 µm on the walls across X, 0 on the floors. Two slots side by side at different depths
/// leave a 0.4 mm step whose edge moves 50 µm across the z rays: there a ray meets the upper
/// floor in one part and the lower in the other, which is not a surface error of 0.4 mm.
#[test]
fn whole_part_error_is_the_distance_between_surfaces_not_the_height_of_a_moved_edge() {
    let sb = Sandbox::new("correct-part-error");
    let text = "program = \"p.ngc\"\n\
        [machine]\n\
        axes = [\n\
          { name = \"X\", kind = \"linear\", direction = [1, 0, 0] },\n\
          { name = \"Y\", kind = \"linear\", direction = [0, 1, 0] },\n\
          { name = \"Z\", kind = \"linear\", direction = [0, 0, 1] },\n\
        ]\n\
        home = { X = 0, Y = 0, Z = 20 }\n\
        [deviations]\ndx_XY = 0.05\n\
        [tool]\nkind = \"flat\"\ndiameter_mm = 6.0\nlength_mm = 10.0\n\
        [stock]\nmin = [-8.0, -4.0, -2.0]\nmax = [8.0, 4.0, 0.0]\npitch_mm = 0.04\n";
    // Slot A: x in [-6, 0], floor z = -0.2 (line 5); slot B: x in [0, 6], floor z = -0.6
    // (line 9); both through the stock along Y.
    let program = "G21 G90\nG0 Z5\nG0 X-3 Y-10\nG0 Z-0.2\nG1 Y10 F600\nG0 Z5\nG0 X3 Y-10\n\
                   G0 Z-0.6\nG1 Y10 F600\nG0 Z5\nM30\n";
    sb.write("s.toml", text.as_bytes());
    sb.write("p.ngc", program.as_bytes());
    let s = Scene::load(&sb.dir.join("s.toml")).expect("scene");
    let program = s.load_program().expect("program");
    let out =
        twinmill::pipeline::correct(&s, &program, s.chain(), 1e-3, &NoProgress).expect("corrects");
    let given = &out.report.iterations[0];
    assert_eq!(given.iteration, 0);
    // The path is off by |t| everywhere.
    assert!((given.path.max_mm - 0.05).abs() < 1e-9, "{:?}", given.path);
    // Every compared surface within |t|, the walls across X at |t|: on an x ray a wall's
    // crossing moves by exactly 0.05 mm.
    let part = given.part;
    assert!(part.crossings > 10_000, "{part:?}");
    assert!((part.max_mm - 0.05).abs() < 1e-9, "{part:?}");
    assert!(part.rms_mm <= 0.05 + 1e-12, "{part:?}");
    // The step's edge crossed z rays (pitch 0.04 < 0.05): seen, counted, not compared.
    assert!(part.other_surface_crossings > 0, "{part:?}");
    // Corrected, the part is the nominal one.
    let last = out.report.iterations.last().expect("a pass");
    assert!(last.part.max_mm < 1e-6, "{:?}", last.part);
}

/// Rotations about x, y, z by `t` (rad), written out.
fn rx(t: Real) -> nalgebra::Matrix3<Real> {
    nalgebra::Matrix3::new(1.0, 0.0, 0.0, 0.0, t.cos(), -t.sin(), 0.0, t.sin(), t.cos())
}
fn ry(t: Real) -> nalgebra::Matrix3<Real> {
    nalgebra::Matrix3::new(t.cos(), 0.0, t.sin(), 0.0, 1.0, 0.0, -t.sin(), 0.0, t.cos())
}
fn rz(t: Real) -> nalgebra::Matrix3<Real> {
    nalgebra::Matrix3::new(t.cos(), -t.sin(), 0.0, t.sin(), t.cos(), 0.0, 0.0, 0.0, 1.0)
}

/// The joint `j`'s deviation `E = Trans(d)·Rx(α)·Ry(β)·Rz(γ)` applied to `p`, its six
/// numbers read from `chain` by name (`dx_CX` … `gamma_CX`).
fn hand_joint(
    chain: &twinmill::machine::chain::Chain,
    j: &str,
    p: nalgebra::Vector3<Real>,
) -> nalgebra::Vector3<Real> {
    let v = |n: &str| chain.deviation(chain.deviation_id(&format!("{n}_{j}")).expect("known"));
    rx(v("alpha")) * ry(v("beta")) * rz(v("gamma")) * p
        + nalgebra::Vector3::new(v("dx"), v("dy"), v("dz"))
}

/// The head-table machine of `scenes/head-table.toml` written out by hand from the 30 numbers
/// of its joints' deviations (read by name, composed here, not by `Chain`):
/// `RotZ(c)·E_CX·T(x)·E_XY·T(y)·E_YZ·T(z)·E_ZB·[T(p)·RotY(b)·T(−p)]·E_BS`, p = (0, 0, 150),
/// `E = Trans(d)·Rx(α)·Ry(β)·Rz(γ)`; the point at height `h` on the tool axis.
fn head_table_oracle(chain: &twinmill::machine::chain::Chain, q: &[Real; 5], h: Real) -> [Real; 3] {
    use nalgebra::Vector3 as V;
    let e = |j: &str, p: V<Real>| hand_joint(chain, j, p);
    let [c, x, y, z, b] = *q;
    let pivot = V::new(0.0, 0.0, 150.0);
    let p = e("BS", V::new(0.0, 0.0, h));
    let p = ry(b.to_radians()) * (p - pivot) + pivot;
    let p = e("ZB", p) + V::new(0.0, 0.0, z);
    let p = e("YZ", p) + V::new(0.0, y, 0.0);
    let p = e("XY", p) + V::new(x, 0.0, 0.0);
    let p = rz(c.to_radians()) * e("CX", p);
    [p.x, p.y, p.z]
}

/// The scene's program corrected to 1 µm on its machine, how far the corrected program
/// leaves the nominal path, and how far the program as given does, in mm: at nine points of
/// every block, the tip, mid-flute and flute end, each pose mapped through `oracle` (a
/// chain written out by hand, given the axis values in `order`).
fn corrected_path_errors(
    s: &Scene,
    order: [twinmill::nc::AxisLetter; 5],
    oracle: fn(&twinmill::machine::chain::Chain, &[Real; 5], Real) -> [Real; 3],
) -> (twinmill::calibration::correct::CorrectedProgram, Real, Real) {
    let program = s.load_program().expect("parses");
    let start = program.moves.first().map_or(s.home(), |m| m.start);
    let opts = twinmill::calibration::correct::CorrectOptions::for_accuracy(1e-3);
    let cp = twinmill::calibration::correct::correct_program(
        s.chain(),
        &s.tool,
        &program,
        &start,
        &opts,
    )
    .expect("corrects");
    let nominal = s.chain().nominal();
    let axes = |a: &twinmill::nc::AxisValues| order.map(|l| a.get(l));
    let l = s.tool.length();
    let (mut worst, mut given): (Real, Real) = (0.0, 0.0);
    let mut at = cp.start;
    for b in &cp.blocks {
        let from = at;
        at = b.end;
        let Some(src) = b.source.map(|i| &program.moves[i]) else {
            continue;
        };
        for i in 0..=8 {
            let t = i as Real / 8.0;
            let (f, e) = (from.to_array(), b.end.to_array());
            let q = twinmill::nc::AxisValues::from_array(std::array::from_fn(|k| {
                f[k] + (e[k] - f[k]) * t
            }));
            let cmd = twinmill::calibration::correct::path_point(src, b.s.0 + (b.s.1 - b.s.0) * t);
            for h in [0.0, l / 2.0, l] {
                let d = oracle(s.chain(), &axes(&q), h);
                let n = oracle(&nominal, &axes(&cmd), h);
                let g = oracle(s.chain(), &axes(&cmd), h);
                let dist = |a: [Real; 3], b: [Real; 3]| {
                    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
                };
                worst = worst.max(dist(d, n));
                given = given.max(dist(g, n));
            }
        }
    }
    (cp, worst, given)
}

#[test]
fn head_table_programs_at_b_zero_are_corrected_not_refused() {
    use twinmill::nc::AxisLetter as L;
    let s = Scene::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/head-table.toml"))
        .expect("loads");
    // Every move, 3+2 at B = 0 (C parallel to the tool), at B = 30, and C and B turning
    // while cutting, corrects; before, every pose failed with a C correction of −86°.
    let (cp, worst, given) =
        corrected_path_errors(&s, [L::C, L::X, L::Y, L::Z, L::B], head_table_oracle);
    assert!(given > 0.02, "the program as given is {given} mm off");
    // Tip, mid-flute and flute end within 1 µm of the nominal path: the tilts about X that
    // no axis takes at B = 0 (EA0C + EA0B ≈ −5 µrad … 75 µrad) cost at most |δv|·L/2.
    assert!(worst < 1e-3, "corrected path off by {worst} mm");
    // Rotary values stay next to the commanded ones: no flip.
    assert!(
        cp.summary.max_rotary_correction_deg < 0.2,
        "{:?}",
        cp.summary
    );
    assert!(cp.summary.axis_angle_rad > 0.0 && cp.summary.axis_angle_rad < 1e-4);
}

/// The length LinuxCNC applies F to (its interpreter's `find_straight_length`): the XYZ
/// length when not zero, else the A B C length (degrees). Written here from LinuxCNC's rule,
/// independently of the correction's own.
fn linuxcnc_length(a: &[Real; 6], b: &[Real; 6]) -> Real {
    let d = |r: std::ops::Range<usize>| r.map(|k| (b[k] - a[k]).powi(2)).sum::<Real>().sqrt();
    let xyz = d(0..3);
    if xyz > 0.0 { xyz } else { d(3..6) }
}

/// `src` corrected to 2 µm on the trunnion scene: the correction, the written program and
/// the scene's home.
fn corrected_on_the_trunnion(
    src: &str,
) -> (
    twinmill::calibration::correct::CorrectedProgram,
    String,
    twinmill::nc::AxisValues,
) {
    use twinmill::calibration::correct::{CorrectOptions, correct_program, write_gcode};
    let s = Scene::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/trunnion-ac.toml"))
        .expect("loads");
    let home = s.home();
    let program = twinmill::nc::parse_program(src, Path::new("move.ngc"), home).expect("parses");
    let cp = correct_program(
        s.chain(),
        &s.tool,
        &program,
        &home,
        &CorrectOptions::for_accuracy(0.002),
    )
    .expect("corrects");
    let mut text = Vec::new();
    write_gcode(&cp, &[], &mut text).expect("writes");
    (cp, String::from_utf8(text).expect("utf-8"), home)
}

#[test]
fn corrected_rotary_moves_keep_their_duration_in_inverse_time() {
    let (cp, text, home) = corrected_on_the_trunnion("G21 G90 G94\nG1 X10 A10 C30 F600\nM30\n");
    // By hand: LinuxCNC feeds the XYZ length, 10 mm at 600 mm/min: 1/60 min (1 s).
    let nominal_min = 10.0 / 600.0;
    // Inverse time around the corrected move, units per minute again after it.
    let g93 = text.find("\nG93\n").expect("G93");
    let g94 = text.rfind("\nG94\n").expect("G94 restored");
    assert!(g93 < g94 && text[g94..].contains("M30"), "{text}");
    assert!(cp.summary.inverse_time_blocks >= 1, "{:?}", cp.summary);

    // Durations of the feed moves as a controller runs them: G93 blocks take 1/F.
    let durations = |moves: &[Move]| -> Vec<Real> {
        moves
            .iter()
            .filter_map(|m| {
                let f = m.feed_mm_per_min?;
                Some(linuxcnc_length(&m.start.to_array(), &m.end.to_array()) / f)
            })
            .collect()
    };
    let read = twinmill::nc::parse_program(&text, Path::new("corrected.ngc"), home)
        .expect("the corrected program parses");
    let d = durations(&read.moves);
    let total: Real = d.iter().sum();
    assert!(
        (total - nominal_min).abs() < 1e-12,
        "corrected move takes {total} min, nominal {nominal_min} min"
    );
    // Every part takes its share: the source move is split into equal parameter parts.
    for x in &d {
        assert!((x * d.len() as Real - nominal_min).abs() < 1e-12, "{d:?}");
    }
    // At the programmed 600 mm/min instead, the corrected chords would take another time.
    let g94_total: Real = read
        .moves
        .iter()
        .filter(|m| m.feed_mm_per_min.is_some())
        .map(|m| linuxcnc_length(&m.start.to_array(), &m.end.to_array()) / 600.0)
        .sum();
    assert!(
        (g94_total - nominal_min).abs() > 1e-6 * nominal_min,
        "G94 would keep the duration too: {g94_total}"
    );

    // The same through `twinmill nc motion`: its JSON (positions and feeds to 1e-6).
    let sb = crate::Sandbox::new("inverse-time");
    sb.write("corrected.ngc", text.as_bytes());
    let (code, stdout, stderr) = sb.run(&["nc", "motion", "corrected.ngc", "--jsonl"]);
    assert_eq!(code, 0, "{stderr}");
    let point = |v: &serde_json::Value| -> [Real; 6] {
        std::array::from_fn(|k| {
            let key = ["x", "y", "z", "a", "b", "c"][k];
            v.get(key)
                .or_else(|| v.get(k))
                .and_then(serde_json::Value::as_f64)
                .unwrap_or(0.0)
        })
    };
    let mut nc_total = 0.0;
    let mut parts = 0;
    for line in stdout.lines() {
        let v: serde_json::Value = serde_json::from_str(line).expect("JSON line");
        if let Some(f) = v["feed"].as_f64() {
            let dur = linuxcnc_length(&point(&v["start"]), &point(&v["end"])) / f;
            assert!(
                (dur * d.len() as Real - nominal_min).abs() < 1e-6 * nominal_min,
                "{line}"
            );
            nc_total += dur;
            parts += 1;
        }
    }
    assert_eq!(parts, d.len());
    assert!(
        (nc_total - nominal_min).abs() < 1e-6 * nominal_min,
        "{nc_total}"
    );
}

/// LinuxCNC's `find_arc_length`, written here from its rule: the start radius times the
/// angle turned, with the travel along the arc's axis as the other side of a right triangle.
fn linuxcnc_arc_length(radius: Real, turned_rad: Real, along: Real) -> Real {
    if along == 0.0 {
        radius * turned_rad.abs()
    } else {
        (radius * turned_rad).hypot(along)
    }
}

#[test]
fn a_corrected_arc_that_turns_a_rotary_axis_keeps_its_helix_duration() {
    // A half turn of radius 5 mm in XY, 2 mm down in Z, while C turns 30°, at 600 mm/min.
    let (_, text, home) = corrected_on_the_trunnion(
        "G21 G90 G94 G17\nG0 X0 Y0 Z10\nG3 X10 Y0 Z8 I5 J0 C30 F600\nM30\n",
    );
    // By hand: the helix 5π mm around and 2 mm along, at 600 mm/min.
    let nominal_min = linuxcnc_arc_length(5.0, std::f64::consts::PI, 2.0) / 600.0;
    assert!(text.contains("\nG93\n"), "{text}");
    let read = twinmill::nc::parse_program(&text, Path::new("corrected.ngc"), home)
        .expect("the corrected program parses");
    // The corrected blocks of the arc: every feed move (the move before it is a rapid).
    let arc: Vec<&Move> = read
        .moves
        .iter()
        .filter(|m| m.feed_mm_per_min.is_some())
        .collect();
    assert!(arc.len() > 1, "the arc is written as chords: {text}");
    let total: Real = arc
        .iter()
        .map(|m| {
            linuxcnc_length(&m.start.to_array(), &m.end.to_array())
                / m.feed_mm_per_min.expect("feed")
        })
        .sum();
    assert!(
        (total - nominal_min).abs() < 1e-9 * nominal_min,
        "the corrected arc takes {total} min, the helix {nominal_min} min"
    );
}

/// A head-head machine (both rotary axes in the head: C about Z, then B about Y pivoting
/// 150 mm above the tool point), its chain written out by hand from the joints' deviations
/// (read by name, composed here, not by `Chain`):
/// `T(x)·E_XY·T(y)·E_YZ·T(z)·E_ZC·RotZ(c)·E_CB·[T(p)·RotY(b)·T(−p)]·E_BS`, p = (0, 0, 150);
/// the point at height `h` on the tool axis.
fn head_head_oracle(chain: &twinmill::machine::chain::Chain, q: &[Real; 5], h: Real) -> [Real; 3] {
    use nalgebra::Vector3 as V;
    let e = |j: &str, p: V<Real>| hand_joint(chain, j, p);
    let [x, y, z, c, b] = *q;
    let pivot = V::new(0.0, 0.0, 150.0);
    let p = e("BS", V::new(0.0, 0.0, h));
    let p = ry(b.to_radians()) * (p - pivot) + pivot;
    let p = rz(c.to_radians()) * e("CB", p);
    let p = e("ZC", p) + V::new(0.0, 0.0, z);
    let p = e("YZ", p) + V::new(0.0, y, 0.0);
    let p = e("XY", p) + V::new(x, 0.0, 0.0);
    [p.x, p.y, p.z]
}

/// `correct` on a head-head machine with the head-table scene's location errors moved to
/// the head (offsets and tilts of both head lines, and a squareness): a 3+2 program at B = 0
/// (C parallel to the tool), one at B = 30°, C = 45°, and B and C turning while cutting.
/// Judged by the hand-written chain above: the corrected path (tip, mid-flute, flute end)
/// within 1 µm of the nominal one, the program as given far off, no flip of a rotary axis.
#[test]
fn head_head_programs_are_corrected_to_a_micrometre() {
    use twinmill::nc::AxisLetter as L;
    let sb = Sandbox::new("head-head");
    let scene = "name = \"head-head\"\nprogram = \"hh.ngc\"\n\n[machine]\n\
        name = \"5-axis head-head: C head about Z, B head about Y\"\n\
        axes = [\n\
          { name = \"X\", kind = \"linear\", direction = [1, 0, 0] },\n\
          { name = \"Y\", kind = \"linear\", direction = [0, 1, 0] },\n\
          { name = \"Z\", kind = \"linear\", direction = [0, 0, 1] },\n\
          { name = \"C\", kind = \"rotary\", direction = [0, 0, 1] },\n\
          { name = \"B\", kind = \"rotary\", direction = [0, 1, 0], origin = [0, 0, 150] },\n\
        ]\nspindle = \"S\"\nhome = { X = 0, Y = 0, Z = 120, B = 0, C = 0 }\n\n\
        [deviations]\nEX0C = 0.015\nEY0C = -0.020\nEA0C = 35e-6\nEB0C = 25e-6\n\
        EX0B = 0.010\nEZ0B = -0.030\nEA0B = -40e-6\nEC0B = 30e-6\ngamma_XY = 20e-6\n\n\
        [tool]\nkind = \"flat\"\ndiameter_mm = 6.0\nlength_mm = 25.0\n\n\
        [stock]\nmin = [-20.0, -20.0, 0.0]\nmax = [20.0, 20.0, 40.0]\npitch_mm = 0.2\n";
    let program = "G21 G90 G94\nG0 X-30 Y-23 Z120 B0 C0\nG0 Z30\nG1 X30 F600\nG0 Z120\n\
        G0 X-20 Y-40 B30 C45\nG1 X20 Y-35 Z35 F600\nG1 X25 Y-30 B35 C60 F600\n\
        G1 X30 Y-25 B25 C20 F600\nG0 Z120\nM2\n";
    let path = sb.write("hh.toml", scene.as_bytes());
    sb.write("hh.ngc", program.as_bytes());
    let s = Scene::load(&path).expect("loads");
    let (cp, worst, given) =
        corrected_path_errors(&s, [L::X, L::Y, L::Z, L::C, L::B], head_head_oracle);
    assert!(given > 0.005, "the program as given is {given} mm off");
    assert!(worst < 1e-3, "corrected path off by {worst} mm");
    assert!(
        cp.summary.max_rotary_correction_deg < 0.2,
        "{:?}",
        cp.summary
    );
}
