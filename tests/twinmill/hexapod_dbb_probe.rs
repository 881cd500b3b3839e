//! The hexapod identified from double-ball-bar lengths and touch-probe readings at once, on
//! the machining-centre scene, graded against the scene's injected deviations: together the
//! two instruments determine every direction but the three platform rotations about the
//! tool point — which neither can see — while the probe alone leaves a base joint along its
//! strut against its reference length, and the bar alone the base frame's six rigid
//! motions, undetermined; the combined values lie within 3σ of the truth once the three
//! invisible rotations (worked out here from the platform joints) are taken out; a file
//! with a planted bias is refused by name.

use super::{dbb_readings, hexapod_centre as centre};
use twinmill::calibration::hexapod_calibrate::{
    CircleReadings, DEFAULT_POINTS, Plan, Procedure, default_plan as dbb_plan,
};
use twinmill::calibration::hexapod_dbb_probe::{DbbData, ProbeData, identify};
use twinmill::calibration::hexapod_probe::{
    ProbeError, ProbeIdentification, ProbePlan, ProbeReadings, default_plan as probe_plan, measure,
};
use twinmill::machine::hexapod::{Hexapod, PARAMETERS};
use twinmill::math::{Real, Vector3};
use twinmill::scene::HexapodScene;

/// The bar's noise (mm) and the probe's (mm): a ±0.5 µm DBB, a touch probe on gauge blocks.
const DBB_SIGMA_MM: Real = 0.5e-3;
const PROBE_SIGMA_MM: Real = 0.0015;

struct Data {
    s: HexapodScene,
    dbb: Plan,
    circles: Vec<CircleReadings>,
    files: Vec<String>,
    probe: ProbePlan,
    probed: ProbeReadings,
}

/// The jig-free circles (each table ball mounted up to 0.05 mm off) and the probe's plan
/// measured on the scene's actual machine through its nominal controller.
fn data() -> Data {
    let s = centre();
    let ws = s.workspace.expect("workspace");
    let dbb = dbb_plan(Procedure::JigFree, &ws, DEFAULT_POINTS);
    let circles = dbb_readings(&s.nominal, &s.actual, &dbb.circles, DBB_SIGMA_MM, 11, |j| {
        let f = |k: usize| (((j * 3 + k) * 7919 % 101) as Real / 50.0 - 1.0) * 0.05;
        Vector3::new(f(0), f(1), f(2))
    });
    let files = (1..=circles.len())
        .map(|j| format!("circle-{j:02}.csv"))
        .collect();
    let probe = probe_plan(&s.nominal, &ws);
    let probed = measure(&s.nominal, &s.actual, &probe, PROBE_SIGMA_MM, 5).expect("measures");
    Data {
        s,
        dbb,
        circles,
        files,
        probe,
        probed,
    }
}

fn run(
    d: &Data,
    circles: Option<&[CircleReadings]>,
    probed: Option<&ProbeReadings>,
) -> Result<ProbeIdentification, ProbeError> {
    identify(
        &d.s.nominal,
        circles.map(|c| DbbData {
            plan: &d.dbb,
            readings: c,
            files: &d.files,
            sigma_mm: DBB_SIGMA_MM,
        }),
        probed.map(|r| ProbeData {
            plan: &d.probe,
            readings: r,
            file: "probe.csv",
        }),
        false,
    )
}

/// Whether a named direction holds platform joints only (`ax_1`, …, no base joint or
/// reference length).
fn platform_only(name: &str) -> bool {
    !["bx_", "by_", "bz_", "l0_"]
        .iter()
        .any(|b| name.contains(b))
}

/// The platform joints turned about the tool point, worked out here: for joint `a_i` (the
/// platform frame) and tool offset `o`, a small rotation `ω` moves it by `ω × (a_i − o)`;
/// three orthonormal columns over the 42 parameters (zero outside the platform joints).
fn platform_rotations(h: &Hexapod) -> nalgebra::DMatrix<Real> {
    let o = h.tool_offset();
    let mut g = nalgebra::DMatrix::zeros(PARAMETERS, 3);
    for (i, a) in h.platform_joints().iter().enumerate() {
        for k in 0..3 {
            let w = Vector3::ith(k, 1.0).cross(&(a - o));
            for r in 0..3 {
                g[(18 + 3 * i + r, k)] = w[r];
            }
        }
    }
    g.qr().q()
}

#[test]
fn dbb_and_probe_together_determine_what_neither_does_alone_and_recover_the_scene() {
    let d = data();
    let both = run(&d, Some(&d.circles), Some(&d.probed)).expect("identifies");
    let probe = run(&d, None, Some(&d.probed)).expect("identifies");
    let bar = run(&d, Some(&d.circles), None).expect("identifies");
    assert!(both.fit.fits, "{}", both.fit.describe());
    // Neither instrument sees the platform turned about the tool point: exactly those
    // three directions stay undetermined together.
    assert_eq!(both.rank, PARAMETERS - 3, "{:?}", both.not_determined);
    assert_eq!(both.not_determined.len(), 3, "{:?}", both.not_determined);
    assert!(both.not_determined.iter().all(|n| platform_only(n)));
    // The probe alone leaves a direction of base joints and reference lengths too; the
    // bar alone (lengths only, its table balls unknown) the base frame's six rigid motions.
    assert!(probe.rank < both.rank, "{:?}", probe.not_determined);
    assert!(
        probe.not_determined.iter().any(|n| !platform_only(n)),
        "{:?}",
        probe.not_determined
    );
    assert!(bar.rank <= PARAMETERS - 9, "{:?}", bar.not_determined);
    // And what both determine, they determine closer: the reference lengths' σ (along the
    // determined directions) under 0.6 of the probe's alone.
    for k in PARAMETERS - 6..PARAMETERS {
        assert!(
            both.parameter_sigma[k] < 0.6 * probe.parameter_sigma[k],
            "{k}: σ {} mm together, {} mm the probe alone",
            both.parameter_sigma[k],
            probe.parameter_sigma[k]
        );
    }
    // Within 3σ of the scene's deviations, once the three invisible rotations are taken out
    // of the error (the engine's determined subspace is orthogonal to them).
    let (pa, pn) = (d.s.actual.parameters(), d.s.nominal.parameters());
    let err = nalgebra::DVector::from_fn(PARAMETERS, |k, _| both.parameters[k] - pa[k]);
    let g = platform_rotations(&d.s.nominal);
    let seen = &err - &g * (g.transpose() * &err);
    let mut inside = 0;
    let mut worst: Real = 0.0;
    for k in 0..PARAMETERS {
        let z = seen[k] / both.parameter_sigma[k];
        worst = worst.max(z.abs());
        if z.abs() <= 3.0 {
            inside += 1;
        }
    }
    assert!(inside >= 40, "{inside} of 42 within 3σ (worst {worst:.2}σ)");
    // What the readings can see of the scene's deviations is found: the error left is a
    // tenth of them (RMS, the invisible rotations taken out of both).
    let dev = nalgebra::DVector::from_fn(PARAMETERS, |k, _| pa[k] - pn[k]);
    let visible = &dev - &g * (g.transpose() * &dev);
    assert!(
        seen.norm() < 0.1 * visible.norm(),
        "left {} mm of {} mm",
        seen.norm(),
        visible.norm()
    );
}

#[test]
fn a_file_with_a_planted_bias_is_refused_by_name() {
    let d = data();
    // Circle 7's file off by 4 µm·cos 2θ (eight times the bar's σ): an oval no table
    // ball's centre makes. (A constant offset would not do: with the bar tilted, the ball
    // moved along the circle's axis lengthens every reading alike.)
    let mut circles = d.circles.clone();
    let n = circles[6].lengths_mm.len() as Real;
    for (k, l) in circles[6].lengths_mm.iter_mut().enumerate() {
        *l += 0.004 * (2.0 * std::f64::consts::TAU * k as Real / n).cos();
    }
    match run(&d, Some(&circles), Some(&d.probed)) {
        Err(ProbeError::Misfit(m)) => {
            assert!(m.contains("circle-07.csv"), "{m}");
            assert!(!m.contains("probe.csv"), "{m}");
        }
        other => panic!("expected a misfit naming circle-07.csv, got {other:?}"),
    }
    // The probe read 10 µm off in x at every swung orientation of the second pivot (a
    // constant offset of the tip's travel no kinematic parameter makes; a constant offset
    // of the positioning would be the base frame's translation, which the bar cannot see).
    let mut probed = d.probed.clone();
    for v in &mut probed.pivot_mm[1] {
        v[0] += 0.010;
    }
    match run(&d, Some(&d.circles), Some(&probed)) {
        Err(ProbeError::Misfit(m)) => assert!(m.contains("probe.csv"), "{m}"),
        other => panic!("expected a misfit naming probe.csv, got {other:?}"),
    }
}

/// The command line: `hexapod probe-calibrate --readings-out` writes the probe's readings,
/// `identify --readings … --probe FILE` identifies them with the bar's ball-plate traces
/// — rank 39 (the three platform rotations about the tool point named), every parameter of
/// the controller file within 3σ of the scene file's `[deviations]` once those rotations
/// are taken out — and writes the page (both instruments' files, the identifiability) and
/// the genhexkins pins of the controller file's machine beside it; outputs that cannot all
/// be written and a bad probe file are one line (naming file and line), nothing written.
#[test]
fn cli_identify_reads_bar_traces_and_a_probe_file_together() {
    use super::Sandbox;
    use super::hexapod_calibration::{ball_plate_readings, identify_ball_plate};
    let sb = Sandbox::new("hexapod-dbb-probe");
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes/hexapod-machining-centre.toml");
    let scene = path.to_str().expect("utf-8");
    let s = centre();
    let ws = s.workspace.expect("workspace");
    let (code, _, err) = sb.run(&[
        "hexapod",
        "probe-calibrate",
        scene,
        "--rounds",
        "1",
        "--readings-out",
        "probe.csv",
    ]);
    assert_eq!(code, 0, "{err}");
    let names = ball_plate_readings(&sb, &s.nominal, &s.actual, &ws, 3, "plate", "");
    let list = names.join(",");
    // The bar's traces and a probe file identified together, and `extra`.
    let with_probe = |probe: &str, extra: &[&str]| {
        let mut args = vec!["--probe", probe];
        args.extend(extra);
        identify_ball_plate(&sb, scene, &list, &args)
    };
    let (code, out, err) = with_probe(
        "probe.csv",
        &["--corrected", "both.toml", "--html", "both.html", "--json"],
    );
    assert_eq!(code, 0, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).expect("json");
    assert_eq!(v["identification"]["rank"], PARAMETERS - 3);
    // The engine's Monte Carlo over both instruments' stated σ: 20 trials, each identified
    // parameter's spread within 0.6–1.6 of its σ (the ratio's standard deviation is about
    // 0.16), the values those without the trials.
    let (code, out, err) = with_probe("probe.csv", &["--monte-carlo", "20", "--json"]);
    assert_eq!(code, 0, "{err}");
    let mc: serde_json::Value = serde_json::from_str(&out).expect("json");
    let (with, without) = (
        mc["identification"]["identified"]
            .as_array()
            .expect("identified"),
        v["identification"]["identified"]
            .as_array()
            .expect("identified"),
    );
    super::hexapod_calibration::spreads_within(with, "sigma_mm", "monte_carlo_spread_mm", 0.6..1.6);
    for (a, b) in with.iter().zip(without) {
        assert_eq!(a["value_mm"], b["value_mm"]);
    }
    // The page names both instruments' files and gives the identifiability and the σ.
    let page = std::fs::read_to_string(sb.dir.join("both.html")).expect("page written");
    for want in [
        names[0].as_str(),
        names[names.len() - 1].as_str(),
        "probe.csv",
        "Identifiability",
        "touch probe",
        "double ball bar",
        "σ (µm)",
        "l0_6",
    ] {
        assert!(page.contains(want), "the page lacks {want}");
    }
    // The controller file against the scene file's own [deviations] (absent names: 0).
    let file: toml::Table = std::fs::read_to_string(&path)
        .expect("reads")
        .parse()
        .expect("toml");
    let injected = file["deviations"].as_table().expect("deviations");
    let text = std::fs::read_to_string(sb.dir.join("both.toml")).expect("written");
    let corrected: toml::Table = text.parse().expect("TOML");
    let corrected = corrected["controller"].as_table().expect("[controller]");
    let names: Vec<String> = (0..PARAMETERS)
        .map(|k| {
            twinmill::machine::hexapod::ParameterId::new(k)
                .expect("a parameter")
                .name()
        })
        .collect();
    let value = |t: &toml::Table, n: &str| t.get(n).and_then(|v| v.as_float()).unwrap_or(0.0);
    let err = nalgebra::DVector::from_fn(PARAMETERS, |k, _| {
        value(corrected, &names[k]) - value(injected, &names[k])
    });
    let g = platform_rotations(&s.nominal);
    let seen = &err - &g * (g.transpose() * &err);
    // σ from the file's comments (`# σ 0.0000123`).
    let sigma: Vec<Real> = names
        .iter()
        .map(|n| {
            let line = text
                .lines()
                .find(|l| l.starts_with(&format!("{n} =")))
                .expect("every parameter written");
            line.rsplit("σ")
                .next()
                .expect("σ")
                .trim()
                .parse()
                .expect("σ")
        })
        .collect();
    let inside = (0..PARAMETERS)
        .filter(|&k| seen[k].abs() <= 3.0 * sigma[k])
        .count();
    assert!(inside >= 40, "{inside} of 42 within 3σ");
    // The genhexkins pins beside the controller file are that file's controller, read back
    // here: `base.N` the base joints b_i, `platform.N` the platform joints about the tool
    // point a_i − o (N = i − 1), each joint's home offset its reference length; both files
    // written to 1e-7 mm.
    let controller = super::hexapod_controller::controller_of(&s.nominal, &text);
    let hal = std::fs::read_to_string(sb.dir.join("both.hal")).expect("genhexkins file");
    let pins = super::hexapod_controller::hal_pins(&hal);
    let o = controller.tool_offset();
    for i in 0..6 {
        for (k, c) in ["x", "y", "z"].iter().enumerate() {
            let base = pins[&format!("genhexkins.base.{i}.{c}")];
            let platform = pins[&format!("genhexkins.platform.{i}.{c}")];
            let (b, a) = (
                controller.base_joints()[i][k],
                controller.platform_joints()[i][k] - o[k],
            );
            assert!((base - b).abs() < 1.5e-7, "base {i} {c}: {base} vs {b}");
            assert!(
                (platform - a).abs() < 1.5e-7,
                "platform {i} {c}: {platform} vs {a}"
            );
        }
        let l0 = super::hexapod_controller::home_offset(&hal, i);
        let want = controller.reference_lengths()[i];
        assert!((l0 - want).abs() < 1.5e-7, "joint {i}: {l0} vs {want}");
    }
    // Outputs that cannot all be written: refused before anything is — the page named as
    // the genhexkins file, a page in a folder that does not exist.
    for (corrected, page, named) in [
        ("clash.toml", "clash.hal", "clash.hal"),
        ("lost.toml", "missing/page.html", "missing/page.html"),
    ] {
        let (code, out, err) = with_probe("probe.csv", &["--corrected", corrected, "--html", page]);
        assert_ne!(code, 0, "{out}");
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(err.contains(named), "{err}");
        let hal = std::path::Path::new(corrected).with_extension("hal");
        for f in [
            std::path::Path::new(corrected),
            hal.as_path(),
            std::path::Path::new(page),
        ] {
            assert!(!sb.dir.join(f).exists(), "{} written", f.display());
        }
    }
    // Bad probe files: one line naming file and line; nothing written.
    let good = std::fs::read_to_string(sb.dir.join("probe.csv")).expect("written");
    let header_line = good
        .lines()
        .position(|l| l.starts_with("item,"))
        .expect("column line")
        + 1;
    let mut lines: Vec<String> = good.lines().map(String::from).collect();
    lines[header_line] = lines[header_line].replace("positioning,1,", "pivot,1,");
    let wrong_item = lines.join("\n");
    let mut lines: Vec<String> = good.lines().map(String::from).collect();
    let last = lines.len() - 1;
    lines[last] = lines[last].replacen(",", ",x", 8);
    let bad_number = lines.join("\n");
    let truncated: String = good
        .lines()
        .take(header_line + 3)
        .collect::<Vec<_>>()
        .join("\n");
    for (bad, line) in [
        (wrong_item, header_line + 1),
        (bad_number, last + 1),
        (truncated, header_line + 3),
    ] {
        sb.write("bad.csv", bad.as_bytes());
        let (code, out, err) = with_probe(
            "bad.csv",
            &["--corrected", "bad.toml", "--html", "bad.html"],
        );
        assert_ne!(code, 0, "{out}");
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(err.contains(&format!("bad.csv:{line}")), "{err}");
        for f in ["bad.toml", "bad.hal", "bad.html"] {
            assert!(!sb.dir.join(f).exists(), "{f} written");
        }
    }
}
