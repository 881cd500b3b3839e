//! `design` on chains whose rotary axes are not the bar's (a table about W x first in the
//! chain): a C table, a head-table machine and a trunnion. On each, the designed block is
//! cut at several positions of every rotary axis, scanned and identified by the pipeline
//! `design` runs, and the identification recovers the scene's injected location errors
//! within 3 of its stated σ, naming as not determined exactly what the argument below says
//! it cannot see.
//!
//! **What a cut part cannot see (the hand argument).** The scan is registered to the part
//! with its six rigid degrees of freedom estimated, so anything that moves the part's frame
//! by the same rigid motion at every pose is absorbed by the registration. An ISO 230-7 term
//! of a rotary axis is the transform `L` that takes the nominal line to the actual one: the
//! axis's motion `M(θ)` becomes `L·M(θ)·L⁻¹`.
//!
//! - Its offset along its own line and the zero of its angle commute with `M(θ)`, so
//!   `L·M·L⁻¹ = M`: on any axis but the first they change nothing. On the first axis (a
//!   table carrying the part) the `L` next to the part frame is the part's own zero, left
//!   out, leaving `M(θ)·L⁻¹ = L⁻¹·M(θ)`: one rigid motion of the part frame at every pose,
//!   absorbed by the registration. So the C table's `EZ0C` and `EC0C` (in the joint names
//!   of the C-table scene: `dz_CX`, `gamma_CX`) are not determined, on every scene.
//! - The two offsets across a line and the two tilts of it change the motion by
//!   `L·M(θ)·L⁻¹·M(θ)⁻¹ = I + (I − R(θ))·δ…`: zero at θ = 0, and at θ and θ' different
//!   rigid motions (for an offset δ across the line, `(I − R(θ))·δ` spans the plane across
//!   it as θ takes 90°, 180°, 270° or ±90°). Faces cut at several positions of that axis,
//!   facing in different directions, see them: all determined.
//!
//! So on each scene: determined = every location term but `EZ0C`, `EC0C`; not determined =
//! exactly those two.

use std::path::{Path, PathBuf};
use twinmill::calibration::calibrate::IsoTerm;
use twinmill::machine::chain::AxisKind;
use twinmill::math::Real;
use twinmill::progress::NoProgress;
use twinmill::scene::Scene;

/// A `[scanner]` section aimed at the block's centre (0, 0, 20) from `position`, with a
/// field of view `fov` and the EinScan-class settings every scanner here shares (pitch
/// relaxed to 0.3 mm for CI, range noise 0.01 mm, seed 2002), then the lines `extra`.
macro_rules! scanner {
    ($position:literal, $fov:literal, $extra:literal) => {
        concat!(
            "\n[scanner]\nposition = ",
            $position,
            "\ntarget = [0.0, 0.0, 20.0]\nup = [0.0, 0.0, 1.0]\nbaseline_mm = 100.0\nfov_mm = ",
            $fov,
            "\npitch_mm = 0.3\nnoise_sigma_mm = 0.01\nseed = 2002\n",
            $extra
        )
    };
}

/// A scanner for the scenes that have none; `design` places its own views around the
/// block and keeps these settings.
const SCANNER: &str = scanner!("[0.0, -330.0, 80.0]", "[200.0, 150.0]", "");

/// The built-in scene `stem` (with a scanner appended when it has none), written with its
/// program into a directory of its own; its text is returned for the truth.
fn scene_with_scanner(stem: &str) -> (Scene, String) {
    let mut text = crate::builtin(&format!("{stem}.toml"));
    if !text.contains("[scanner]") {
        text.push_str(SCANNER);
    }
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("design-rotary-{stem}"));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let program = crate::builtin(&format!("{stem}.ngc"));
    std::fs::write(dir.join(format!("{stem}.ngc")), program).expect("program");
    let path: PathBuf = dir.join(format!("{stem}.toml"));
    std::fs::write(&path, &text).expect("scene");
    (Scene::load(&path).expect("the scene loads"), text)
}

/// The `[deviations]` of a scene's text, read here (name = value, comments dropped): the
/// truth, independent of the program's reading of the scene.
fn injected(text: &str) -> Vec<(String, Real)> {
    let mut inside = false;
    let mut out = Vec::new();
    for line in text.lines() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.starts_with('[') {
            inside = line == "[deviations]";
            continue;
        }
        if let (true, Some((k, v))) = (inside, line.split_once('=')) {
            out.push((
                k.trim().to_string(),
                v.trim().parse::<Real>().expect("a number"),
            ));
        }
    }
    out
}

/// Designs for `params` on the scene `stem` and checks the verified identification against
/// the scene's own injected values and the hand argument's undetermined set.
fn designed_and_recovered(
    stem: &str,
    params: &[&str],
    not_determined: &[&str],
    second_part: &[&str],
) {
    let (scene, text) = scene_with_scanner(stem);
    let truth = injected(&text);
    assert!(!truth.is_empty(), "{stem}: the scene injects deviations");
    let model = scene.model();
    let mut ids = Vec::new();
    let mut iso = Vec::new();
    for p in params {
        if p.contains('_') {
            ids.push(model.deviation_id(p).expect("a joint deviation"));
        } else {
            iso.push(IsoTerm::parse(model, p).expect("an ISO term"));
        }
    }
    let names: Vec<String> = params.iter().map(|s| s.to_string()).collect();
    let out = twinmill::pipeline::design_scene(
        &scene,
        &names,
        &ids,
        &iso,
        &format!("{stem}-design"),
        &NoProgress,
    )
    .unwrap_or_else(|e| panic!("{stem}: design: {e}"));
    // The cuts are at two or more positions of every rotary axis.
    for a in model.axes().iter().filter(|a| a.kind == AxisKind::Rotary) {
        let mut at: Vec<Real> = out
            .design
            .cuts
            .iter()
            .map(|c| c.cut.start.get(a.letter))
            .collect();
        at.sort_by(Real::total_cmp);
        at.dedup();
        assert!(
            at.len() >= 2,
            "{stem}: cuts at {:?} only of {}",
            at,
            a.letter.as_char()
        );
    }
    // The head's cuts at B ≠ 0 run along Y (the premise of the head-table argument).
    for c in out.design.cuts.iter().filter(|c| {
        model
            .axes()
            .iter()
            .any(|a| a.letter.as_char() == 'B' && c.cut.start.get(a.letter) != 0.0)
    }) {
        let (s, e) = (c.cut.start, c.cut.end);
        assert!(
            (s.get(twinmill::nc::AxisLetter::X) - e.get(twinmill::nc::AxisLetter::X)).abs() < 1e-9
                && (s.get(twinmill::nc::AxisLetter::Z) - e.get(twinmill::nc::AxisLetter::Z)).abs()
                    < 1e-9,
            "{stem}: {} does not run along Y",
            c.name
        );
    }
    let id = &out.verified.identification;
    let mut undetermined: Vec<&str> = id
        .identifiability
        .undetermined_combinations
        .iter()
        .map(|c| c.name.as_str())
        .collect();
    undetermined.sort_unstable();
    let mut expected = not_determined.to_vec();
    expected.sort_unstable();
    assert_eq!(undetermined, expected, "{stem}: not determined");
    assert_eq!(out.report.not_determined.len(), expected.len());
    // What a second block is offered for: the undetermined terms some cut could see, not
    // those no cut of the family sees (the argument at the top).
    let mut offered: Vec<&str> = out.report.second_part.iter().map(String::as_str).collect();
    offered.sort_unstable();
    assert_eq!(offered, second_part, "{stem}: second part");
    for p in params.iter().filter(|p| !not_determined.contains(p)) {
        let e = id
            .parameters
            .iter()
            .find(|e| e.name == *p)
            .unwrap_or_else(|| panic!("{stem}: {p} not valued"));
        let t = truth.iter().find(|(k, _)| k == p).map_or(0.0, |(_, v)| *v);
        assert!(
            (e.value - t).abs() <= 3.0 * e.sigma,
            "{stem}: {p} = {} ± {} against the scene's {t}",
            e.value,
            e.sigma
        );
        // A stated σ that means something: within a tenth of a realistic size (10 µm,
        // 100 µrad).
        let angle = ["alpha", "beta", "gamma"].iter().any(|a| p.contains(a))
            || (p.starts_with('E') && matches!(p.as_bytes()[1], b'A' | b'B' | b'C'));
        let scale = if angle { 1e-4 } else { 0.01 };
        assert!(e.sigma <= scale, "{stem}: {p} σ {}", e.sigma);
    }
    for p in not_determined {
        assert!(
            id.parameters.iter().all(|e| e.name != *p),
            "{stem}: {p} valued"
        );
    }
}

/// The C table (the scene's own offset of C's line, `dy_CX` = 13 µm, in its joint names):
/// the offsets and tilts of C's line across it are determined, the offset along it and its
/// zero are not.
#[test]
fn design_on_a_c_table_recovers_its_line() {
    designed_and_recovered(
        "c-table-step",
        &["dx_CX", "dy_CX", "dz_CX", "alpha_CX", "beta_CX", "gamma_CX"],
        &["dz_CX", "gamma_CX"],
        &[],
    );
}

/// The head-table machine: C's and B's location terms (the scene's eight). Besides the C
/// table's offset along itself and zero, the head's two tilts `EA0B`, `EC0B` stay
/// undetermined, by this argument: with B's line through the pivot p (150 mm above the
/// tip), a tilt ε about x turns the motion by `ε([x]×R_y(b) − R_y(b)[x]×)`, which moves the
/// tip (at `R_y(b)·(0, 0, −150)` from the pivot) by `−150·ε·(1 − cos b)·y` and turns the
/// tool axis by `ε·(1 − cos b)·y`; a tilt about z gives `−150·ε·sin b·y` and `ε·sin b·y`.
/// Both act along machine Y only, and at B ≠ 0 the designed cuts run along Y (checked
/// below): a shift or lean of the tool along the cut moves neither its flank nor its floor.
#[test]
fn design_on_a_head_table_machine_recovers_both_lines() {
    designed_and_recovered(
        "head-table",
        &[
            "EX0C", "EY0C", "EZ0C", "EA0C", "EB0C", "EC0C", "EX0B", "EZ0B", "EA0B", "EC0B",
        ],
        &["EA0B", "EC0B", "EC0C", "EZ0C"],
        &["EA0B", "EC0B"],
    );
    // The second block the design offers for them: its cuts along Z at B = ±90° (the tool
    // across Z, the flank facing ±Y) see the head's tilts, which shift and lean the tool
    // along Y by `(1 − cos b)` (EA0B) and `sin b` (EC0B): equal at +90°, opposite at −90°,
    // so both are determined; cut, scanned and identified, each lies within 3σ of the
    // scene's value.
    let (scene, text) = scene_with_scanner("head-table");
    let truth = injected(&text);
    let iso: Vec<IsoTerm> = ["EA0B", "EC0B"]
        .iter()
        .map(|n| IsoTerm::parse(scene.model(), n).expect("a term"))
        .collect();
    let names = vec!["EA0B".to_string(), "EC0B".to_string()];
    let out = twinmill::pipeline::design_scene(
        &scene,
        &names,
        &[],
        &iso,
        "head-table-second-design",
        &NoProgress,
    )
    .expect("the second part's design");
    let id = &out.verified.identification;
    for n in &names {
        let e = id
            .parameters
            .iter()
            .find(|e| &e.name == n)
            .unwrap_or_else(|| panic!("{n} not identified by the second part"));
        let t = truth.iter().find(|(k, _)| k == n).map_or(0.0, |(_, v)| *v);
        assert!(
            (e.value - t).abs() <= 3.0 * e.sigma && e.sigma <= 1e-4,
            "{n} = {} ± {} against {t}",
            e.value,
            e.sigma
        );
    }
    assert!(out.design.cuts.iter().any(|c| {
        let (s, e) = (c.cut.start, c.cut.end);
        s.get(twinmill::nc::AxisLetter::Z) != e.get(twinmill::nc::AxisLetter::Z)
    }));
}

/// The trunnion: C's and A's location terms (the scene's eight), with the C table's offset
/// along itself and zero named not determined.
#[test]
fn design_on_a_trunnion_recovers_both_lines() {
    designed_and_recovered(
        "trunnion-ac",
        &[
            "EX0C", "EY0C", "EZ0C", "EA0C", "EB0C", "EC0C", "EY0A", "EZ0A", "EB0A", "EC0A",
        ],
        &["EC0C", "EZ0C"],
        &[],
    );
}

/// The trunnion's ball-sensor test (as `measure --instrument ball-sensor` runs it: seed
/// 003's sensor, ±0.5 µm, the default sweeps and point, seed 1) and the part `design`
/// proposes for its location terms, cut and scanned, identified in one solve: the balls with
/// their fixed point and the faces with their scan's registration, one model of the machine.
///
/// Expected, independently of the program: both tests are blind to the C table's offset
/// along itself and zero (the argument at the top; the balls are read relative to a fixed
/// point that is estimated, the same rigid freedom), so the joint solve names the same two
/// not determined. Least squares with more data can only shrink the uncertainty: the joint
/// σ of every term is at most the smaller of the two alone, and strictly smaller than the
/// ball test's, since the part alone determines every term too. The joint estimate
/// and the ball test's alone share the balls' data; their difference has variance
/// σ_ball² − σ_joint² (the estimate with less data is the one with more plus independent
/// noise), so it lies within 3 of its square root — inside the ball test's own σ·3. Both
/// lie within 3σ of the scene's injected values, read from the scene's text.
#[test]
fn ball_sensor_and_the_designed_part_identify_the_trunnion_together() {
    use twinmill::metrology::ball_sensor::BallSensor;
    use twinmill::pipeline::{
        RotaryInstrument, RotaryRequest, TermReport, default_setup, identify_location_with,
        rotary_test,
    };
    let (scene, text) = scene_with_scanner("trunnion-ac");
    let truth = injected(&text);
    let model = scene.model();
    let names = model.rotary_location_terms();
    let request = RotaryRequest {
        instrument: RotaryInstrument::BallSensor {
            sensor: BallSensor::seed003(8.0),
            height_mm: 1.0,
        },
        sweeps: Vec::new(),
        setup: default_setup(1),
        identify: Some(Vec::new()),
    };
    let ball = rotary_test(&scene, &request).expect("the ball-sensor test");
    let alone = ball.report.identification.clone().expect("identified");
    let iso: Vec<IsoTerm> = names
        .iter()
        .map(|n| IsoTerm::parse(model, n).expect("a term"))
        .collect();
    let designed = twinmill::pipeline::design_scene(
        &scene,
        &names,
        &[],
        &iso,
        "trunnion-ac-design",
        &NoProgress,
    )
    .expect("a design");
    let planes = &designed.verified.features;
    assert!(planes.len() >= 4, "{} faces", planes.len());
    let both = identify_location_with(&scene, &[], &ball.samples, &request.setup, planes)
        .expect("the joint identification");
    let part =
        identify_location_with(&scene, &[], &[], &request.setup, planes).expect("the part alone");
    let sorted = |v: &[String]| {
        let mut v = v.to_vec();
        v.sort();
        v
    };
    for r in [&alone, &both, &part] {
        assert_eq!(sorted(&r.not_determined), ["EC0C", "EZ0C"]);
    }
    let find = |r: &[TermReport], n: &str| -> TermReport {
        r.iter()
            .find(|t| t.name == n)
            .cloned()
            .unwrap_or_else(|| panic!("{n} not identified"))
    };
    for n in names.iter().filter(|n| *n != "EZ0C" && *n != "EC0C") {
        let (a, b, p) = (
            find(&alone.identified, n),
            find(&both.identified, n),
            find(&part.identified, n),
        );
        let t = truth.iter().find(|(k, _)| k == n).map_or(0.0, |(_, v)| *v);
        for (what, e) in [("ball", &a), ("joint", &b)] {
            assert!(
                (e.value - t).abs() <= 3.0 * e.sigma,
                "{n} {what}: {} ± {} against {t}",
                e.value,
                e.sigma
            );
        }
        assert!(
            b.sigma <= 1.0001 * a.sigma.min(p.sigma),
            "{n}: joint σ {} against ball {} and part {}",
            b.sigma,
            a.sigma,
            p.sigma
        );
        let spread = (a.sigma * a.sigma - b.sigma * b.sigma).max(0.0).sqrt();
        assert!(
            (b.value - a.value).abs() <= 3.0 * spread + 1e-12,
            "{n}: joint {} against ball {} (σ of the difference {spread})",
            b.value,
            a.value
        );
        // The part sees every term, so it adds information to each.
        assert!(b.sigma < a.sigma, "{n}: the part adds nothing");
    }
}

/// A scanner that sees the trunnion's four shoulders: the block turned on a turntable to
/// four views (the views `design` places).
const TURNTABLE_SCANNER: &str = scanner!(
    "[0.0, -315.4, 240.8]",
    "[80.0, 80.0]",
    "working_range_mm = [290.0, 480.0]
grazing_limit_deg = 80.0
turntable = { axis_point = [0.0, 0.0, 20.0], axis = [0.0, 0.0, 1.0], angles_deg = [45.0, 135.0, 225.0, 315.0] }
"
);

/// The flanks of the four shoulders trunnion-ac.ngc cuts at C = 0, 90, 180, 270 (its feed
/// lines 10, 15, 20, 25).
const SHOULDER_FLANKS: &str = "
[identify]
faces = [
  { name = \"c0\", line = 10, kind = \"flank\" },
  { name = \"c90\", line = 15, kind = \"flank\" },
  { name = \"c180\", line = 20, kind = \"flank\" },
  { name = \"c270\", line = 25, kind = \"flank\" },
]
parameters = [\"EX0C\", \"EY0C\"]
registration = \"estimate\"
";

/// A report's terms as (name, value, σ), read from its JSON.
pub(crate) fn json_terms(v: &serde_json::Value) -> Vec<(String, Real, Real)> {
    v["identified"]
        .as_array()
        .expect("identified")
        .iter()
        .map(|t| {
            (
                t["name"].as_str().expect("name").to_string(),
                t["value"].as_f64().expect("value"),
                t["sigma"].as_f64().expect("sigma"),
            )
        })
        .collect()
}

/// The ball-sensor trace that `measure` writes, given back to `identify --measurement`
/// (alone, then with the part the scene's program cuts, `--part`), through the binary:
///
/// - alone it identifies exactly what `measure` identified from the same samples (the
///   file carries the test bit for bit: samples, stylus and fixed point);
/// - with the four shoulders (their flanks face machine −Y at C = 0, 90, 180, 270, so they
///   see the C line's offsets across it, by the argument at the top) every term lies
///   within 3σ of the scene's injected value, read from its text; no σ grows (least
///   squares with more data) and one at least shrinks by 5 %; the joint and the ball-alone
///   values differ within 3 of the σ of their difference; the same two are named not
///   determined;
/// - `--deviations-out` writes each identified value, not the undetermined two, and
///   `measure --deviations` runs on the identified machine;
/// - a second trace whose one sweep is bent by 10 µm is refused, naming that file; a
///   malformed trace, a trace given as a laser file and a hexapod's --readings are
///   refused in one line; nothing is written.
#[test]
fn ball_sensor_traces_and_the_cut_part_identify_through_the_binary() {
    let sb = crate::Sandbox::new("traces-and-part");
    let text = format!(
        "{}{TURNTABLE_SCANNER}{SHOULDER_FLANKS}",
        crate::builtin("trunnion-ac.toml")
    );
    let truth = injected(&text);
    sb.write("ts.toml", text.as_bytes());
    sb.write(
        "trunnion-ac.ngc",
        crate::builtin("trunnion-ac.ngc").as_bytes(),
    );
    let run_json = |args: &[&str]| -> serde_json::Value {
        let (code, out, err) = sb.run(args);
        assert_eq!(code, 0, "{args:?}: {err}");
        serde_json::from_str(&out).unwrap_or_else(|e| panic!("{args:?}: {e}: {out}"))
    };
    let measured = run_json(&[
        "measure",
        "ts.toml",
        "--instrument",
        "ball-sensor",
        "--out",
        "bs.csv",
        "--json",
    ]);
    let alone = run_json(&["identify", "ts.toml", "--measurement", "bs.csv", "--json"]);
    assert_eq!(
        json_terms(&alone),
        json_terms(&measured["identification"]),
        "the trace read back identifies as measure did"
    );
    let both = run_json(&[
        "identify",
        "ts.toml",
        "--measurement",
        "ball-sensor:bs.csv",
        "--part",
        "--deviations-out",
        "dev.toml",
        "--json",
    ]);
    let mut nd: Vec<&str> = both["not_determined"]
        .as_array()
        .expect("not_determined")
        .iter()
        .map(|v| v.as_str().expect("name"))
        .collect();
    nd.sort();
    assert_eq!(nd, ["EC0C", "EZ0C"]);
    let (a, b) = (json_terms(&alone), json_terms(&both));
    assert_eq!(a.len(), 8);
    assert_eq!(b.len(), 8);
    let dev = std::fs::read_to_string(sb.dir.join("dev.toml")).expect("dev.toml");
    for ((name, va, sa), (nb, vb, sb_)) in a.iter().zip(&b) {
        assert_eq!(name, nb);
        let t = truth
            .iter()
            .find(|(k, _)| k == name)
            .map_or(0.0, |(_, v)| *v);
        assert!(
            (vb - t).abs() <= 3.0 * sb_,
            "{name}: {vb} ± {sb_} against {t}"
        );
        assert!(*sb_ <= sa * (1.0 + 1e-6), "{name}: σ {sb_} against {sa}");
        let spread = (sa * sa - sb_ * sb_).max(0.0).sqrt();
        assert!((vb - va).abs() <= 3.0 * spread + 1e-12, "{name}");
        let written = dev
            .lines()
            .find_map(|l| l.strip_prefix(&format!("\"{name}\" = ")))
            .and_then(|r| r.split_whitespace().next())
            .and_then(|v| v.parse::<Real>().ok())
            .unwrap_or_else(|| panic!("{name} in {dev}"));
        assert!(
            (written - vb).abs() <= 1e-12,
            "{name}: wrote {written}, identified {vb}"
        );
    }
    assert!(
        b.iter()
            .zip(&a)
            .any(|((n, _, sb_), (_, _, sa))| n.starts_with("E") && *sb_ < 0.95 * sa),
        "the part adds information"
    );
    assert!(
        !dev.lines()
            .any(|l| l.starts_with("\"EC0C\" =") || l.starts_with("\"EZ0C\" =")),
        "{dev}"
    );
    let on_twin = run_json(&[
        "measure",
        "ts.toml",
        "--deviations",
        "dev.toml",
        "--instrument",
        "ball-sensor",
        "--out",
        "bs2.csv",
        "--json",
    ]);
    assert_eq!(json_terms(&on_twin["identification"]).len(), 8);

    // A second set-up whose sweep 2 reads 10 µm more along X: no rigid fixed point explains it.
    let trace = std::fs::read_to_string(sb.dir.join("bs.csv")).expect("trace");
    let bent: String = trace
        .lines()
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            if f.first() == Some(&"2") {
                let mut f: Vec<String> = f.iter().map(|s| s.to_string()).collect();
                let k = f.len() - 6;
                let v: Real = f[k].parse().expect("dx");
                f[k] = format!("{:?}", v + 0.010);
                f.join(",") + "\n"
            } else {
                format!("{l}\n")
            }
        })
        .collect();
    sb.write("bent.csv", bent.as_bytes());
    let refused =
        |args: &[&str], names: &[&str]| crate::identify_instruments::refused(&sb, args, names);
    let with_out = |a: &[&'static str]| -> Vec<&'static str> {
        let mut v = a.to_vec();
        v.extend(["--deviations-out", "out.toml"]);
        v
    };
    refused(
        &with_out(&[
            "identify",
            "ts.toml",
            "--measurement",
            "bs.csv",
            "--measurement",
            "bent.csv",
        ]),
        &["bent.csv", "refused"],
    );
    sb.write(
        "bad.csv",
        trace.replacen("\n1,C,30.0,", "\n1,Q,30.0,", 1).as_bytes(),
    );
    refused(
        &with_out(&["identify", "ts.toml", "--measurement", "bad.csv"]),
        &["bad.csv:4:3", "not a rotary axis"],
    );
    refused(
        &with_out(&[
            "identify",
            "ts.toml",
            "--measurement",
            "bs.csv",
            "--measurement",
            "laser:bs.csv",
        ]),
        &["bs.csv", "not laser readings"],
    );
    refused(
        &with_out(&[
            "identify",
            "ts.toml",
            "--measurement",
            "bs.csv",
            "--readings",
            "bs.csv",
        ]),
        &["--readings"],
    );
}
