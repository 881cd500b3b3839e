//! Measure → identify → simulate on the identified twin, for a serial machine from its
//! instruments' files: laser runs on X, Y, Z and ball-bar circles in XY, YZ, ZX measured on
//! `scenes/xyz-error-motions.toml` with seeded noise (through `measure`, in process for the
//! hundred trials and through the binary once), identified back (`identify --measurement`),
//! every determined term checked against the scene's value — written here from the scene
//! file, not from the program — and its σ against the spread over the trials; the
//! identified machine written (`--deviations-out`) and simulated (`--deviations`) bit for
//! bit as the same values pasted into the scene; bad input refused in one line.

use crate::{Sandbox, builtin, files_in};
use std::path::{Path, PathBuf};
use twinmill::pipeline::measure::{
    BallbarOptions, LaserOptions, MeasureInstrument, MeasureRequest, RotaryOptions, measure,
};
use twinmill::pipeline::measurements::{IdentifyRequest, MeasurementKind, identify_measurements};
use twinmill::scene::Scene;

const SCENE: &str = "xyz-error-motions.toml";

/// Noise σ of every reading and sample (µm).
pub(crate) const NOISE_UM: f64 = 0.5;

/// The scene's values (scenes/xyz-error-motions.toml, read off the file by hand): the
/// squareness, the scale of X, Y's wave along X, X's pitch table, Z's bow along Y, the lost
/// motions.
const TRUTH: &[(&str, f64)] = &[
    ("EC(0X)Y", 20e-6),
    ("EXX.polynomial[0]", 0.0),
    ("EXX.polynomial[1]", 15e-6),
    ("EYX.periodic[0]", 0.002),
    ("EBX.table[0]", 0.0),
    ("EBX.table[1]", 20e-6),
    ("EBX.table[2]", 0.0),
    ("EZY.polynomial[0]", 0.0),
    ("EZY.polynomial[1]", 0.0),
    ("EZY.polynomial[2]", 2e-6),
    ("reversal.X", -0.003),
    ("reversal.Y", -0.002),
];

/// What no set of laser runs and ball-bar circles can determine: a constant offset of an
/// error motion (the laser is zeroed at its first target, a ball bar's centre is estimated).
const BLIND: &[&str] = &["EXX.polynomial[0]", "EZY.polynomial[0]"];

fn scene_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes")
        .join(SCENE)
}

/// The six tests as `measure` options: (file name, instrument, laser, ball bar).
fn tests() -> Vec<(String, MeasureInstrument, LaserOptions, BallbarOptions)> {
    let mut out = Vec::new();
    for (axis, to, at) in [
        ("X", 60.0, "Y=20,Z=50"),
        ("Y", 40.0, "X=30,Z=50"),
        ("Z", 50.0, "X=30,Y=20"),
    ] {
        out.push((
            format!("laser-{axis}.csv"),
            MeasureInstrument::Laser,
            LaserOptions {
                axis: Some(axis.into()),
                from: Some(0.0),
                to: Some(to),
                targets: Some(7),
                at: Some(at.into()),
                // The reflector 30 mm above the tool point: X's pitch shows as an Abbe error.
                abbe: Some(vec![0.0, 0.0, 30.0]),
                ..LaserOptions::default()
            },
            BallbarOptions::default(),
        ));
    }
    for plane in ["XY", "YZ", "ZX"] {
        out.push((
            format!("ballbar-{plane}.csv"),
            MeasureInstrument::Ballbar,
            LaserOptions::default(),
            BallbarOptions {
                plane: Some(plane.into()),
                centre: Some("X=30,Y=20,Z=30".into()),
                radius: Some(20.0),
                ..BallbarOptions::default()
            },
        ));
    }
    out
}

/// The six files of trial `seed`, written into `dir` by `measure` in process.
fn measure_all(dir: &Path, seed: u64) -> Vec<(MeasurementKind, PathBuf)> {
    measure_into(&scene_path(), dir, seed, tests())
}

/// The files of `tests` (name, instrument, laser, ball bar) measured on `scene` in process
/// into `dir`, trial `seed`: laser readings and ball-bar samples with [`NOISE_UM`], a
/// rotary-axis test with its instrument's own noise (and no identification of its own).
pub(crate) fn measure_into(
    scene: &Path,
    dir: &Path,
    seed: u64,
    tests: Vec<(String, MeasureInstrument, LaserOptions, BallbarOptions)>,
) -> Vec<(MeasurementKind, PathBuf)> {
    tests
        .into_iter()
        .enumerate()
        .map(|(k, (name, instrument, laser, ballbar))| {
            let file = dir.join(&name);
            let rotary = matches!(
                instrument,
                MeasureInstrument::BallSensor | MeasureInstrument::Probe
            );
            let m = measure(&MeasureRequest {
                scene: scene.to_path_buf(),
                instrument,
                out: Some(file.clone()),
                png: None,
                html: None,
                seed: seed * 8 + k as u64,
                noise_um: (!rotary).then_some(NOISE_UM),
                overshoot: None,
                laser,
                ballbar,
                rotary: RotaryOptions {
                    no_identify: true,
                    ..RotaryOptions::default()
                },
                accept_misfit: false,
                deviations: None,
                controller: None,
            })
            .unwrap_or_else(|e| panic!("{name}: {e}"));
            std::fs::write(&file, m.text).expect("writes");
            let kind = MeasurementKind::of_file(&file).expect("the set-up record says");
            (kind, file)
        })
        .collect()
}

fn truth(name: &str) -> f64 {
    value_in(TRUTH, name)
}

/// The z-scores `z` ((value − truth)/σ) of parameter `name` over `trials` seeded trials:
/// one per trial, within 3σ in ≥ 95 % of them, their RMS in `rms` (σ neither overstated
/// nor understated).
pub(crate) fn assert_covered(
    name: &str,
    z: &[f64],
    trials: usize,
    rms: std::ops::RangeInclusive<f64>,
) {
    assert_eq!(z.len(), trials, "{name}: determined in some trials only");
    let hits = z.iter().filter(|x| x.abs() <= 3.0).count();
    let r = (z.iter().map(|x| x * x).sum::<f64>() / z.len() as f64).sqrt();
    assert!(
        hits * 100 >= 95 * trials,
        "{name}: within 3σ in {hits} of {trials} trials"
    );
    assert!(
        rms.contains(&r),
        "{name}: RMS of (value − truth)/σ {r:.3} over {trials} trials"
    );
}

/// The value of `name` in a test's table of a scene's values.
pub(crate) fn value_in(table: &[(&str, f64)], name: &str) -> f64 {
    table
        .iter()
        .find(|(n, _)| *n == name)
        .unwrap_or_else(|| panic!("{name} is one of the scene's terms"))
        .1
}

/// 100 seeded trials: every determined term within 3σ of the scene's value in ≥ 95 % of
/// them, and RMS((value − truth)/σ) within 0.8–1.25 for each (σ neither overstated nor
/// understated); the constant offsets named not determined, never valued.
#[test]
fn a_hundred_measured_sets_identify_the_scene_within_their_sigma() {
    let scene = Scene::load(&scene_path()).expect("scene");
    let dir = std::env::temp_dir().join(format!("twinmill-ident-instr-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    const TRIALS: usize = 100;
    let mut z: Vec<Vec<f64>> = vec![Vec::new(); TRUTH.len()];
    for trial in 0..TRIALS {
        let files = measure_all(&dir, trial as u64 + 1);
        let o = identify_measurements(
            &scene,
            &IdentifyRequest {
                measurements: files,
                parameters: None,
                accept_misfit: false,
                parts: Vec::new(),
                monte_carlo: None,
            },
        )
        .unwrap_or_else(|e| panic!("trial {trial}: {e}"));
        // Every term of the scene is solved for.
        let mut names = o.parameters.clone();
        names.sort();
        let mut expected: Vec<String> = TRUTH.iter().map(|(n, _)| n.to_string()).collect();
        expected.sort();
        assert_eq!(names, expected);
        for b in BLIND {
            assert!(
                o.report.not_determined.iter().any(|n| n == b),
                "trial {trial}: {b} named not determined: {:?}",
                o.report.not_determined
            );
            assert!(o.report.identified.iter().all(|e| e.name != *b));
        }
        for e in &o.report.identified {
            let k = TRUTH
                .iter()
                .position(|(n, _)| *n == e.name)
                .expect("a scene term");
            assert!(
                e.sigma > 0.0 && e.sigma.is_finite(),
                "{}: σ {}",
                e.name,
                e.sigma
            );
            z[k].push((e.value - truth(&e.name)) / e.sigma);
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
    let mut valued = 0;
    for ((name, _), z) in TRUTH.iter().zip(&z) {
        if z.is_empty() {
            assert!(BLIND.contains(name) || name.starts_with("EBX") || name.starts_with("EZY"));
            continue;
        }
        valued += 1;
        assert_covered(name, z, TRIALS, 0.8..=1.25);
    }
    // The squareness, the scale, the wave, the bow and both lost motions at least.
    assert!(valued >= 6, "{valued} terms determined");
}

/// Measures the six tests through the binary into `sb`, as the file names of `tests()`.
fn measure_cli(sb: &Sandbox, scene: &str, extra: &[&str]) {
    for (k, (name, instrument, laser, ballbar)) in tests().into_iter().enumerate() {
        let seed = (100 + k).to_string();
        let noise = NOISE_UM.to_string();
        let mut args: Vec<String> = vec![
            "measure".into(),
            scene.into(),
            "--out".into(),
            name.clone(),
            "--seed".into(),
            seed,
            "--noise".into(),
            noise,
        ];
        match instrument {
            MeasureInstrument::Laser => {
                let abbe = laser.abbe.expect("abbe");
                args.extend([
                    "--instrument".into(),
                    "laser".into(),
                    "--axis".into(),
                    laser.axis.expect("axis"),
                    "--from".into(),
                    "0".into(),
                    "--to".into(),
                    laser.to.expect("to").to_string(),
                    "--targets".into(),
                    "7".into(),
                    "--at".into(),
                    laser.at.expect("at"),
                    "--abbe".into(),
                    format!("{},{},{}", abbe[0], abbe[1], abbe[2]),
                ]);
            }
            _ => {
                args.extend([
                    "--instrument".into(),
                    "ballbar".into(),
                    "--plane".into(),
                    ballbar.plane.expect("plane"),
                    "--centre".into(),
                    ballbar.centre.expect("centre"),
                    "--radius".into(),
                    "20".into(),
                ]);
            }
        }
        args.extend(extra.iter().map(|s| s.to_string()));
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let (code, _, err) = sb.run(&args);
        assert_eq!(code, 0, "measure {name}: {err}");
    }
}

/// The scene's text with its deviation sections replaced by `sections`.
fn pasted(scene_text: &str, sections: &str) -> String {
    let mut out = String::new();
    let mut skip = false;
    for line in scene_text.lines() {
        let t = line.trim();
        if t.starts_with('[') && !t.starts_with("[[") {
            skip = matches!(t, "[deviations]" | "[error_motions]" | "[reversal]");
        }
        if !skip {
            out.push_str(line);
            out.push('\n');
        }
    }
    out.push('\n');
    out.push_str(sections);
    out
}

/// The deviation sections of a deviations file (everything before `[identified]`).
fn sections_of(file: &str) -> &str {
    file.split("\n[identified]").next().expect("sections")
}

/// Every file under `dir`, relative, with its bytes, sorted.
fn tree(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for p in files_in(&d) {
            if p.is_dir() {
                stack.push(p);
            } else {
                let bytes = std::fs::read(&p).expect("reads");
                out.push((p.strip_prefix(dir).expect("below").to_path_buf(), bytes));
            }
        }
    }
    out.sort();
    out
}

#[test]
fn identify_from_files_writes_a_machine_that_simulates_bit_for_bit_as_pasted_in() {
    let sb = Sandbox::new("ident-instr-cli");
    sb.write(SCENE, builtin(SCENE).as_bytes());
    sb.write("xyz-pocket.ngc", builtin("xyz-pocket.ngc").as_bytes());
    measure_cli(&sb, SCENE, &[]);
    let mut args = vec!["identify", SCENE];
    let specs: Vec<String> = tests()
        .iter()
        .enumerate()
        .map(|(k, (name, ..))| match k {
            // One with its kind and axis given, one with its kind, the rest from the record.
            0 => format!("laser:X:{name}"),
            3 => format!("ballbar:{name}"),
            _ => name.clone(),
        })
        .collect();
    for s in &specs {
        args.extend(["--measurement", s.as_str()]);
    }
    args.extend(["--deviations-out", "identified.toml"]);
    let (code, out, err) = sb.run(&args);
    assert_eq!(code, 0, "{err}");
    // Every determined value with σ and the scene's value; the blind ones named, unvalued.
    for b in BLIND {
        let line = out
            .lines()
            .find(|l| l.contains(b))
            .unwrap_or_else(|| panic!("{b} named: {out}"));
        assert!(
            line.contains("not determined") && !line.contains('±'),
            "{line}"
        );
    }
    let identified: Vec<&str> = out.lines().filter(|l| l.contains("identified ")).collect();
    assert!(identified.len() >= 6, "{out}");
    for l in &identified {
        assert!(l.contains('±') && l.contains("[injected"), "{l}");
    }
    // The file: the sections, the record, σ for each value printed.
    let file = std::fs::read_to_string(sb.dir.join("identified.toml")).expect("written");
    assert!(file.contains("[identified]\n"), "{file}");
    assert!(file.contains("axes = [\"X\", \"Y\", \"Z\"]"), "{file}");
    assert!(file.contains("misfit_accepted = false"), "{file}");
    assert!(file.contains("\"ballbar-ZX.csv\""), "{file}");
    assert!(
        file.contains("[identified.sigma]\n\"EC(0X)Y\" = "),
        "{file}"
    );
    // The identified twin, through --deviations and pasted into the scene (beside it, named
    // as it is): the same part, picture and report but for the wall-clock timings.
    sb.write(
        "pasted.toml",
        format!(
            "name = \"xyz-error-motions\"\n{}",
            pasted(&builtin(SCENE), sections_of(&file))
        )
        .as_bytes(),
    );
    let (code, _, err) = sb.run(&[
        "simulate",
        SCENE,
        "--deviations",
        "identified.toml",
        "--out",
        "a",
    ]);
    assert_eq!(code, 0, "{err}");
    let (code, _, err) = sb.run(&["simulate", "pasted.toml", "--out", "b"]);
    assert_eq!(code, 0, "{err}");
    let (a, b) = (tree(&sb.dir.join("a")), tree(&sb.dir.join("b")));
    assert_eq!(
        a.iter().map(|(p, _)| p).collect::<Vec<_>>(),
        b.iter().map(|(p, _)| p).collect::<Vec<_>>()
    );
    let mut compared = 0;
    for ((p, x), (_, y)) in a.iter().zip(&b) {
        match p.extension().and_then(|e| e.to_str()) {
            Some("stl" | "png") => assert!(x == y, "{} differs", p.display()),
            Some("json") => {
                let untimed = |bytes: &[u8]| {
                    let mut v: serde_json::Value = serde_json::from_slice(bytes).expect("json");
                    v.as_object_mut().expect("an object").remove("timings_s");
                    serde_json::to_vec(&v).expect("json")
                };
                assert!(untimed(x) == untimed(y), "{} differs", p.display());
            }
            _ => continue,
        }
        compared += 1;
    }
    assert_eq!(compared, 3, "part.stl, part.png and report.json compared");
    // The measurements taken on the identified twin.
    measure_cli(&sb, SCENE, &["--deviations", "identified.toml"]);
}

/// One refusal: exit non-zero, one line on stderr containing each of `names`, no file.
pub(crate) fn refused(sb: &Sandbox, args: &[&str], names: &[&str]) {
    let _ = std::fs::remove_file(sb.dir.join("out.toml"));
    let (code, out, err) = sb.run(args);
    assert_ne!(code, 0, "{args:?}: {out}");
    assert_eq!(err.trim_end().lines().count(), 1, "{args:?}: {err}");
    for n in names {
        assert!(err.contains(n), "{args:?}: '{n}' in {err}");
    }
    assert!(!sb.dir.join("out.toml").exists(), "{args:?} wrote");
    assert!(!sb.dir.join("out").exists(), "{args:?} wrote out/");
}

#[test]
fn bad_files_parameters_and_deviations_files_are_refused_in_one_line() {
    let sb = Sandbox::new("ident-instr-bad");
    sb.write(SCENE, builtin(SCENE).as_bytes());
    sb.write("xyz-pocket.ngc", builtin("xyz-pocket.ngc").as_bytes());
    measure_cli(&sb, SCENE, &[]);
    let all = [
        "laser-X.csv",
        "laser-Y.csv",
        "laser-Z.csv",
        "ballbar-XY.csv",
        "ballbar-YZ.csv",
        "ballbar-ZX.csv",
    ];
    // The Y laser's readings handed over as X's: the misfit is blamed on that file.
    let mut args = vec!["identify", SCENE, "--deviations-out", "out.toml"];
    args.extend(["--measurement", "laser:X:laser-Y.csv"]);
    for f in &all[1..] {
        args.extend(["--measurement", f]);
    }
    refused(&sb, &args, &["laser-Y.csv", "refused"]);
    // A ball-bar trace given as laser readings.
    let mut args = vec!["identify", SCENE, "--deviations-out", "out.toml"];
    args.extend(["--measurement", "laser:ballbar-XY.csv"]);
    refused(&sb, &args, &["ballbar-XY.csv", "not laser readings"]);
    // A file without a set-up record and no kind given.
    sb.write("plain.csv", b"# no record\n0,0\n");
    let args = [
        "identify",
        SCENE,
        "--measurement",
        "plain.csv",
        "--deviations-out",
        "out.toml",
    ];
    refused(&sb, &args, &["plain.csv", "set-up record"]);
    // A parameter the machine lacks.
    let args = [
        "identify",
        SCENE,
        "--measurement",
        "laser-X.csv",
        "--parameters",
        "EXX.polynomial[1],EAA.polynomial[1]",
        "--deviations-out",
        "out.toml",
    ];
    refused(&sb, &args, &[SCENE, "EAA.polynomial[1]", "axis A"]);
    // Deviations files: without σ, for another machine, with an unknown key, non-finite.
    let record = "[identified]\nmachine = \"m\"\nscene = \"s\"\naxes = [\"X\", \"Y\", \"Z\"]\n\
                  sources = []\nmisfit_accepted = false\nnot_determined = []\n";
    sb.write(
        "no-sigma.toml",
        format!("[reversal]\nX = -0.003\n{record}").as_bytes(),
    );
    sb.write(
        "other.toml",
        format!(
            "[reversal]\nX = -0.003\n{}[identified.sigma]\n",
            record.replace("[\"X\", \"Y\", \"Z\"]", "[\"X\", \"Y\", \"Z\", \"A\"]")
        )
        .as_bytes(),
    );
    sb.write(
        "unknown.toml",
        format!("[reversal]\nX = -0.003\n{record}colour = 1\n[identified.sigma]\n").as_bytes(),
    );
    sb.write(
        "nan.toml",
        format!("[reversal]\nX = nan\n{record}[identified.sigma]\n").as_bytes(),
    );
    for (file, at) in [
        ("no-sigma.toml", "no-sigma.toml:3:1:"),
        ("other.toml", "other.toml:6:8:"),
        ("unknown.toml", "unknown.toml:10:1:"),
        ("nan.toml", "nan.toml:2:5:"),
    ] {
        refused(
            &sb,
            &["simulate", SCENE, "--deviations", file, "--out", "out"],
            &[at],
        );
        refused(
            &sb,
            &[
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
                "--deviations",
                file,
                "--out",
                "out.toml",
            ],
            &[at],
        );
    }
}
