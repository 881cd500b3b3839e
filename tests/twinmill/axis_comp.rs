//! LinuxCNC axis compensation: `evaluate iso230-2 --comp` writes the `[JOINT_n] COMP_FILE`
//! (`COMP_FILE_TYPE = 1`) of a laser test; `measure --instrument laser --comp` measures the
//! machine with it applied. The expected figures come from the scene's error functions by
//! hand, and LinuxCNC's reading of the file from a small model of its loader
//! (`usrmotLoadComp` and `EMCMOT_SET_JOINT_COMP`), not from the code under test.

use crate::Sandbox;
use std::path::Path;
use twinmill::math::Real;
use twinmill::metrology::comp_table::{CompTable, MAX_ENTRIES};

const SCENE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/xyz-error-motions.toml");

/// The targets of the test (mm).
const TARGETS: [Real; 7] = [0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0];

/// The scene's X error seen by the laser at the tool point, approaching in `+`, zeroed at the
/// first target approached in `+` (mm), by hand from scenes/xyz-error-motions.toml:
/// `EXX = 15e-6·x`; `EBX` the table 0, 20 µrad, 0 at x = 0, 30, 60 (linear between), which
/// turns the tool point at Z = 50 (the scene's home, held) by `50·sin(EBX)` along X
/// (docs/scenes.md: `EBX` moves a tool tip at height z by z·EBX in X); `EYX`, `EZY` and the
/// squareness move the tool across the beam only (Y is held at 0).
fn x_up(t: Real) -> Real {
    let ebx = if t <= 30.0 {
        20e-6 * t / 30.0
    } else {
        20e-6 * (60.0 - t) / 30.0
    };
    15e-6 * t + 50.0 * ebx.sin()
}

/// The reversal value of X, `B = x̄↑ − x̄↓` (mm): approaching in `−` reads `x_up − B`.
const B: Real = -0.003;

/// ISO 230-2's A with no scatter (s = 0): the largest mean deviation of either direction
/// less the smallest (mm).
fn a_by_hand() -> Real {
    let all: Vec<Real> = TARGETS
        .iter()
        .flat_map(|&t| [x_up(t), x_up(t) - B])
        .collect();
    all.iter().copied().fold(Real::MIN, Real::max) - all.iter().copied().fold(Real::MAX, Real::min)
}

fn figure(json: &str, key: &str) -> Real {
    let v: serde_json::Value = serde_json::from_str(json).expect("JSON figures");
    v[key].as_f64().expect("a number")
}

/// LinuxCNC's loader as its source reads a file (usrmotintf.cc `usrmotLoadComp`, type 1):
/// lines of three numbers until the first line that is not; then command.c keeps an entry
/// only if there is room (256) and its nominal is above the last kept one.
fn linuxcnc_loads(text: &str) -> Vec<[Real; 3]> {
    let mut kept: Vec<[Real; 3]> = Vec::new();
    for line in text.lines() {
        let w: Vec<Real> = line
            .split_whitespace()
            .take(3)
            .map_while(|x| x.parse().ok())
            .collect();
        if w.len() != 3 {
            break;
        }
        if kept.len() < 256 && kept.last().is_none_or(|l| w[0] > l[0]) {
            kept.push([w[0], w[1], w[2]]);
        }
    }
    kept
}

#[test]
fn a_laser_comp_table_cancels_the_x_positioning_error_at_the_targets() {
    let sb = Sandbox::new("axis-comp");
    let list = "0,10,20,30,40,50,60";
    let measure = |out: &str, comp: Option<&str>| {
        let mut args = vec![
            "measure",
            SCENE,
            "--instrument",
            "laser",
            "--axis",
            "X",
            "--target-list",
            list,
            "--out",
            out,
            "--json",
        ];
        if let Some(c) = comp {
            args.extend(["--comp", c]);
        }
        let (code, stdout, stderr) = sb.run(&args);
        assert_eq!(code, 0, "{stderr}");
        stdout
    };
    // Before: 3 µm of reversal on 1.45 µm of scale and pitch error at X 30.
    let before = measure("before.csv", None);
    let a_before = figure(&before, "A");
    assert!((a_by_hand() - 4.45e-3).abs() < 1e-8, "{}", a_by_hand());
    assert!(
        (a_before - a_by_hand()).abs() < 1e-9,
        "A before {a_before} mm, by hand {} mm",
        a_by_hand()
    );

    let (code, stdout, stderr) =
        sb.run(&["evaluate", "iso230-2", "before.csv", "--comp", "x.comp"]);
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stdout.contains("[JOINT_0] COMP_FILE = x.comp, COMP_FILE_TYPE = 1"),
        "{stdout}"
    );
    let text = std::fs::read_to_string(sb.dir.join("x.comp")).expect("written");
    // The trims cancel the mean deviations: −x̄↑, −x̄↓ at every target.
    let loaded = linuxcnc_loads(&text);
    assert_eq!(loaded.len(), TARGETS.len(), "{text}");
    for (row, &t) in loaded.iter().zip(&TARGETS) {
        assert_eq!(row[0], t);
        assert!((row[1] + x_up(t)).abs() < 1e-12, "{row:?}");
        assert!((row[2] + x_up(t) - B).abs() < 1e-12, "{row:?}");
    }
    assert!(text.contains("# LinuxCNC axis compensation for axis X (joint 0), units mm"));
    assert!(text.contains("before.csv"));

    // After: the compensated machine reaches every target with no mean deviation.
    let after = measure("after.csv", Some("x.comp"));
    let a_after = figure(&after, "A");
    assert!(a_after <= 1e-4, "A after {a_after} mm (bound 0.1 µm)");
    let readings = std::fs::read_to_string(sb.dir.join("after.csv")).expect("written");
    assert!(readings.contains("compensation: x.comp (7 entries) applied to X"));
    // The set-up record says so, and identification refuses to model it as uncompensated.
    assert!(readings.contains("comp_entries=7"));

    // --axis and --joint name the joint in the file; another axis than the readings' is
    // refused.
    let (code, _, stderr) = sb.run(&[
        "evaluate",
        "iso230-2",
        "before.csv",
        "--comp",
        "y.comp",
        "--axis",
        "Y",
    ]);
    assert_ne!(code, 0);
    assert!(
        stderr.contains("before.csv:") && stderr.contains("axis X"),
        "{stderr}"
    );
    assert!(!sb.dir.join("y.comp").exists());
    let (code, _, stderr) = sb.run(&[
        "evaluate",
        "iso230-2",
        "before.csv",
        "--comp",
        "j.comp",
        "--axis",
        "x",
        "--joint",
        "3",
    ]);
    assert_eq!(code, 0, "{stderr}");
    let j = std::fs::read_to_string(sb.dir.join("j.comp")).expect("written");
    assert!(j.contains("[JOINT_3] COMP_FILE = j.comp"));
}

#[test]
fn comp_tables_round_trip_and_keep_linuxcncs_rules() {
    let path = Path::new("t.comp");
    // The largest table LinuxCNC keeps, with awkward numbers.
    let text: String = (0..MAX_ENTRIES)
        .map(|k| {
            let x = -100.0 + k as Real * 0.7;
            format!("{x} {} {}\n", 1e-7 * k as Real, -0.0031 / (k + 1) as Real)
        })
        .collect::<String>()
        + "# trailer\n";
    let t = CompTable::parse(&text, path).expect("reads");
    let again = t.to_text(&["trailer".to_string()]);
    assert_eq!(CompTable::parse(&again, path).expect("reads"), t);
    // What LinuxCNC keeps of our text is every entry, exactly.
    let loaded = linuxcnc_loads(&again);
    assert_eq!(loaded.len(), MAX_ENTRIES);
    for (e, l) in t.entries().iter().zip(&loaded) {
        assert_eq!([e.nominal, e.forward_trim, e.reverse_trim], *l);
    }
    // One more is refused with its line.
    let over = format!("{}1000 0 0\n", text.replace("# trailer\n", ""));
    let e = CompTable::parse(&over, path)
        .expect_err("too many")
        .to_string();
    assert!(e.starts_with("t.comp:257:"), "{e}");
}

#[test]
fn bad_comp_input_names_file_and_line_and_writes_nothing() {
    let sb = Sandbox::new("axis-comp-bad");
    // A readings file of the wrong format.
    sb.write(
        "bad.csv",
        b"target,direction,run,deviation\n0,+,1,0\n10,up,1,0\n",
    );
    let (code, _, stderr) = sb.run(&["evaluate", "iso230-2", "bad.csv", "--comp", "out.comp"]);
    assert_ne!(code, 0);
    assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
    assert!(stderr.contains("bad.csv:3:"), "{stderr}");
    assert!(!sb.dir.join("out.comp").exists());
    // Compensation files LinuxCNC would not load whole.
    for (name, text, line) in [
        ("decreasing.comp", "0 0 0\n10 0 0\n5 0 0\n", 3),
        ("nonfinite.comp", "0 0 0\n10 inf 0\n", 2),
        ("words.comp", "0 0 0\n10 0.001\n", 2),
        ("comment-first.comp", "# made by hand\n0 0 0\n", 2),
    ] {
        sb.write(name, text.as_bytes());
        let (code, _, stderr) = sb.run(&[
            "measure",
            SCENE,
            "--instrument",
            "laser",
            "--axis",
            "X",
            "--from",
            "0",
            "--to",
            "60",
            "--comp",
            name,
            "--out",
            "r.csv",
        ]);
        assert_ne!(code, 0, "{name}");
        assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
        assert!(
            stderr.contains(&format!("{name}:{line}:")),
            "{name}: {stderr}"
        );
        assert!(!sb.dir.join("r.csv").exists() && !sb.dir.join("r.html").exists());
    }
    // More targets than LinuxCNC keeps entries.
    let mut many = String::from("target,direction,run,deviation\n");
    for k in 0..=MAX_ENTRIES {
        for d in ["+", "-"] {
            for run in 1..=2 {
                many.push_str(&format!("{k},{d},{run},0\n"));
            }
        }
    }
    sb.write("many.csv", many.as_bytes());
    let (code, _, stderr) = sb.run(&[
        "evaluate", "iso230-2", "many.csv", "--comp", "m.comp", "--axis", "X",
    ]);
    assert_ne!(code, 0);
    assert!(
        stderr.contains("many.csv") && stderr.contains("256"),
        "{stderr}"
    );
    assert!(!sb.dir.join("m.comp").exists());
}
