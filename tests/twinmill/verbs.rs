//! One vocabulary for every machine: `--help` lists the verbs in pipeline order on one
//! 80×24 screen, and every built-in scene, serial or hexapod, runs `simulate`, `measure`,
//! `identify`, `design` and `correct`, or refuses in one line that names the scene and says
//! why — never a panic, never a multi-line error, never a half-written output.

use crate::{Sandbox, files_in};
use std::path::Path;

/// The verbs `twinmill --help` lists, in the pipeline's order.
const VERBS: &[&str] = &[
    "nc", "simulate", "scan", "measure", "evaluate", "fit", "identify", "design", "correct", "run",
    "study", "hexapod",
];

#[test]
fn help_lists_the_verbs_in_pipeline_order_on_one_screen() {
    let sb = Sandbox::new("verbs-help");
    let (code, help, err) = sb.run(&["--help"]);
    assert_eq!(code, 0, "{err}");
    assert!(
        help.lines().count() <= 24,
        "{} lines:\n{help}",
        help.lines().count()
    );
    for l in help.lines() {
        assert!(l.chars().count() <= 80, "wider than 80 columns: {l:?}");
    }
    // The command lines: two spaces, the name, its one-line summary.
    let listed: Vec<&str> = help
        .lines()
        .skip_while(|l| !l.starts_with("Commands:"))
        .skip(1)
        .take_while(|l| l.starts_with("  "))
        .filter_map(|l| l.split_whitespace().next())
        .filter(|n| *n != "help")
        .collect();
    assert_eq!(listed, VERBS, "{help}");
    // Every verb has a one-line summary and longer help behind it.
    for verb in VERBS {
        let (code, long, err) = sb.run(&[verb, "--help"]);
        assert_eq!(code, 0, "{verb}: {err}");
        let (_, short, _) = sb.run(&[verb, "-h"]);
        assert!(
            long.len() > short.len(),
            "{verb}: --help adds nothing to -h"
        );
    }
}

/// Whether a failed command's stderr is one line naming the scene and saying why.
fn one_line_refusal(args: &[&str], code: i32, err: &str, scene: &str) {
    assert_eq!(err.trim().lines().count(), 1, "{args:?}: {err}");
    assert!(!err.contains("panicked"), "{args:?}: {err}");
    assert!(err.starts_with("twinmill: error: "), "{args:?}: {err}");
    assert!(
        err.contains(scene) || err.contains("--"),
        "{args:?}: the refusal names neither the scene nor the option: {err}"
    );
    assert_ne!(code, 0, "{args:?}");
}

#[test]
fn every_builtin_scene_runs_each_verb_or_refuses_in_one_line() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes");
    let mut scenes: Vec<_> = std::fs::read_dir(&dir)
        .expect("scenes/")
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        .collect();
    scenes.sort();
    assert!(scenes.len() >= 10, "{} scenes", scenes.len());
    let (mut ran, mut refused) = (0, 0);
    for path in &scenes {
        let scene = path.to_str().expect("utf-8");
        let text = std::fs::read_to_string(path).expect("scene");
        let hexapod = text.contains("kind = \"hexapod\"");
        let stem = path.file_stem().and_then(|s| s.to_str()).expect("stem");
        // A deviation every serial chain of the built-in scenes has (the spindle's tilt on
        // Z); a hexapod designs circles, not test cuts.
        let design: Vec<&str> = if hexapod {
            vec!["design", scene, "--circles", "3", "--out", "out"]
        } else {
            vec!["design", scene, "--params", "alpha_ZS", "--out", "out"]
        };
        let mut jobs: Vec<Vec<&str>> = vec![
            vec!["simulate", scene, "--out", "out"],
            vec![
                "measure",
                scene,
                "--instrument",
                "ballbar",
                "--out",
                "m.csv",
            ],
            vec![
                "measure",
                scene,
                "--instrument",
                "laser",
                "--axis",
                "X",
                "--from",
                "-10",
                "--to",
                "10",
                "--out",
                "l.csv",
            ],
            // A hexapod's identification writes its page only when asked.
            if hexapod {
                vec!["identify", scene, "--html", "identify.html"]
            } else {
                vec!["identify", scene, "--out", "out"]
            },
            design,
        ];
        // The corrections of the two largest programs take minutes (tools/compare_binaries.py
        // runs them whole); their scenes load for `correct` exactly as for `simulate`.
        if !["p1-pocket", "xyz-error-motions"].contains(&stem) {
            jobs.push(vec!["correct", scene, "--out", "out"]);
        }
        for args in jobs {
            let sb = Sandbox::new(&format!("verbs-{stem}-{}", args[0]));
            let (code, out, err) = sb.run(&args);
            assert!(!err.contains("panicked"), "{args:?}: {err}");
            match code {
                // Ran (2: ran and wrote, but the twin says the accuracy is not met).
                0 | 2 => {
                    assert!(!out.is_empty(), "{args:?}: nothing printed");
                    assert!(!files_in(&sb.dir).is_empty(), "{args:?}: nothing written");
                    ran += 1;
                }
                _ => {
                    one_line_refusal(&args, code, &err, stem);
                    assert!(files_in(&sb.dir).is_empty(), "{args:?}: wrote on refusal");
                    refused += 1;
                }
            }
        }
    }
    // The hexapods refuse the laser, and a hexapod that does not cut refuses `simulate`;
    // the serial scenes without [scanner] refuse `design`: both kinds occur.
    assert!(ran >= 25 && refused >= 10, "ran {ran}, refused {refused}");
}
