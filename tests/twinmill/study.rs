//! Sharded studies: K shards run as separate processes merge to what one process gives, the
//! Parquet files read back with the documented schema, and shards that are missing, foreign
//! or stale are refused by name.

use crate::{Sandbox, builtin};
use twinmill::pipeline::identify_scene;
use twinmill::progress::NoProgress;
use twinmill::study::{self, Row};

/// The built-in step scene, coarse (tri-dexel 0.2 mm, scanner pitch 0.3 mm), identifying
/// `dy_AY`; and a study of `trials` trials varying dy_AY and gamma_AY.
fn files(sb: &Sandbox, trials: usize) {
    sb.write("mdx50-step.ngc", builtin("mdx50-step.ngc").as_bytes());
    let scene = builtin("mdx50-step.toml")
        .replace("known = {}", "known = {}\nparameters = [\"dy_AY\"]")
        .replace("pitch_mm = 0.1 ", "pitch_mm = 0.2 ")
        .replace("pitch_mm = 0.185 ", "pitch_mm = 0.3 ");
    sb.write("s.toml", scene.as_bytes());
    sb.write(
        "study.toml",
        format!(
            "scene = \"s.toml\"\ntrials = {trials}\nseed = 7\n\
             [vary]\nscanner_noise_sigma_mm = {{ uniform = [0.01, 0.03] }}\n\
             [vary.deviations]\ndy_AY = {{ uniform = [-0.6, -0.4] }}\n\
             gamma_AY = {{ normal = [0.0, 1e-4] }}\n"
        )
        .as_bytes(),
    );
}

/// What must not depend on the shard count: everything but the shard number and timing.
fn key(r: &Row) -> String {
    format!(
        "{} {} {:?} {:?} {:?} {:?} {:?} {:?} {:?} {:?} {:?}",
        r.inputs.trial,
        r.inputs.scanner_seed,
        r.inputs.noise_sigma_mm.to_bits(),
        r.inputs.deviations,
        r.estimates,
        r.injected,
        r.chi2,
        r.dof,
        r.rounds,
        r.converged,
        r.error
    )
}

#[test]
fn shards_run_as_separate_processes_merge_to_the_one_process_result() {
    let sb = Sandbox::new("study-shards");
    files(&sb, 7);
    let mut reference: Option<(Vec<String>, String)> = None;
    for k in [1usize, 3, 7] {
        let dir = sb.dir.join(format!("k{k}"));
        std::fs::create_dir_all(&dir).expect("dir");
        let manifest = format!("k{k}/m.json");
        let (code, _, err) = sb.run(&[
            "study",
            "plan",
            "study.toml",
            "--shards",
            &k.to_string(),
            "--out",
            &manifest,
        ]);
        assert_eq!(code, 0, "{err}");
        // Shards in reverse order, each its own process.
        for i in (0..k).rev() {
            let (code, _, err) = sb.run(&["study", "run", &manifest, "--shard", &i.to_string()]);
            assert_eq!(code, 0, "{err}");
        }
        let m = study::read_manifest(&sb.dir.join(&manifest)).expect("manifest");
        let (summary, rows) = study::merge(&m, &dir).expect("merges");
        assert_eq!(rows.len(), 7);
        assert_eq!(summary.failed, 0, "{:?}", summary.failures);
        let keys: Vec<String> = rows.iter().map(key).collect();
        let figures = format!("{:?}", summary.parameters);
        match &reference {
            None => reference = Some((keys, figures)),
            Some((rk, rf)) => {
                assert_eq!(&keys, rk, "rows with {k} shards");
                assert_eq!(&figures, rf, "summary with {k} shards");
            }
        }
    }
}

/// `identify` on `s` scanned with trial `t`'s scanner seed and noise: its first
/// identified parameter.
fn first_identified_with_the_trials_scanner(
    s: &mut twinmill::scene::Scene,
    t: &study::TrialInputs,
) -> twinmill::report::EstimateReport {
    let sc = s.scanner.as_mut().expect("scanner");
    sc.seed = t.scanner_seed;
    sc.noise_sigma_mm = t.noise_sigma_mm;
    let program = s.load_program().expect("program");
    let out = identify_scene(s, &program, None, Some(0), &NoProgress).expect("identifies");
    out.report.identified[0].clone()
}

#[test]
fn a_trial_is_what_identify_gives_on_its_inputs() {
    let sb = Sandbox::new("study-trial");
    files(&sb, 2);
    let m = study::plan(&sb.dir.join("study.toml"), 1).expect("plans");
    let rows = study::run_shard(&m, 0).expect("runs");
    // Independently: the scene loaded, the trial's deviations set by hand, identified.
    let mut s = twinmill::scene::Scene::load(&sb.dir.join("s.toml")).expect("scene");
    let t = &m.trials[1];
    for (name, v) in &t.deviations {
        let chain = &mut s.serial_mut().expect("a serial machine").chain;
        let id = chain.deviation_id(name).expect("name");
        chain.set_deviation(id, *v);
    }
    let e = first_identified_with_the_trials_scanner(&mut s, t);
    assert_eq!(e.name, "dy_AY");
    assert_eq!(rows[1].estimates[0], Some((e.value, e.sigma)));
    let dy = t
        .deviations
        .iter()
        .find(|d| d.0 == "dy_AY")
        .expect("varied")
        .1;
    assert_eq!(rows[1].injected[0], dy);
    assert!((0.01..=0.03).contains(&t.noise_sigma_mm));
    assert!((-0.6..=-0.4).contains(&dy));
}

#[test]
fn shard_files_have_the_documented_schema() {
    let sb = Sandbox::new("study-schema");
    files(&sb, 2);
    let m = study::plan(&sb.dir.join("study.toml"), 1).expect("plans");
    let rows = study::run_shard(&m, 0).expect("runs");
    let bytes = study::shard_parquet(&m, &rows).expect("parquet");
    assert_eq!(&bytes[..4], b"PAR1");
    let path = sb.write(&study::shard_file_name(0, 1), &bytes);
    let back = study::read_shard(&m, &path).expect("reads back");
    assert_eq!(back, rows);
    let names: Vec<String> = study::schema(&m)
        .fields()
        .iter()
        .map(|f| f.name().clone())
        .collect();
    assert_eq!(
        names,
        [
            "trial",
            "shard",
            "scanner_seed",
            "noise_sigma_mm",
            "in.dy_AY",
            "in.gamma_AY",
            "dy_AY.value",
            "dy_AY.sigma",
            "dy_AY.injected",
            "dy_AY.determined",
            "chi2",
            "dof",
            "rounds",
            "converged",
            "error",
            "seconds"
        ]
    );
}

#[test]
fn missing_foreign_and_stale_shards_are_refused_by_name() {
    let sb = Sandbox::new("study-bad");
    files(&sb, 2);
    let run = |args: &[&str]| sb.run(args);
    assert_eq!(
        run(&[
            "study",
            "plan",
            "study.toml",
            "--shards",
            "2",
            "--out",
            "a.json"
        ])
        .0,
        0
    );
    assert_eq!(run(&["study", "run", "a.json", "--shard", "0"]).0, 0);
    let (code, out, err) = run(&["study", "merge", "a.json"]);
    assert_ne!(code, 0);
    assert!(out.is_empty());
    assert!(err.contains("shard 1 is missing"), "{err}");
    // A shard of another plan of another study in the same folder.
    std::fs::write(
        sb.dir.join("other.toml"),
        std::fs::read_to_string(sb.dir.join("study.toml"))
            .expect("study")
            .replace("seed = 7", "seed = 8"),
    )
    .expect("write");
    assert_eq!(
        run(&[
            "study",
            "plan",
            "other.toml",
            "--shards",
            "2",
            "--out",
            "b.json"
        ])
        .0,
        0
    );
    assert_eq!(run(&["study", "run", "b.json", "--shard", "1"]).0, 0);
    let (code, _, err) = run(&["study", "merge", "a.json"]);
    assert_ne!(code, 0);
    assert!(err.contains("belongs to study"), "{err}");
    for (args, want) in [
        (
            &["study", "run", "a.json", "--shard", "5"][..],
            "shard 5 does not exist",
        ),
        (&["study", "run", "a.json"][..], "no shard"),
        (
            &["study", "plan", "study.toml", "--shards", "0"][..],
            "--shards must be",
        ),
        (&["study", "plan", "nope.toml"][..], "nope.toml"),
    ] {
        let (code, _, err) = run(args);
        assert_ne!(code, 0, "{args:?}");
        assert_eq!(err.trim_end().lines().count(), 1, "{err}");
        assert!(err.contains(want), "{args:?}: '{want}' not in {err}");
    }
    // An unknown deviation, named with its place.
    sb.write(
        "bad.toml",
        b"scene = \"s.toml\"\ntrials = 2\n[vary.deviations]\ndy_AQ = { fixed = 1.0 }\n",
    );
    let (code, _, err) = run(&["study", "plan", "bad.toml"]);
    assert_ne!(code, 0);
    assert!(err.contains("dy_AQ"), "{err}");
    // A manifest edited by hand, and a scene changed after planning.
    let text = std::fs::read_to_string(sb.dir.join("a.json")).expect("manifest");
    sb.write(
        "c.json",
        text.replace("\"scanner_seed\": ", "\"scanner_seed\": 1")
            .as_bytes(),
    );
    let (code, _, err) = run(&["study", "run", "c.json", "--shard", "0"]);
    assert_ne!(code, 0);
    assert!(err.contains("changed after planning"), "{err}");
    let scene = std::fs::read_to_string(sb.dir.join("s.toml")).expect("scene");
    sb.write("s.toml", format!("{scene}\n# edited\n").as_bytes());
    let (code, _, err) = run(&["study", "run", "a.json", "--shard", "1"]);
    assert_ne!(code, 0);
    assert!(err.contains("changed since the study was planned"), "{err}");
}

#[test]
fn a_study_of_scanner_seeds_gives_the_spread_identify_monte_carlo_gives() {
    let sb = Sandbox::new("study-mc");
    files(&sb, 1);
    let s = twinmill::scene::Scene::load(&sb.dir.join("s.toml")).expect("scene");
    let program = s.load_program().expect("program");
    let trials = 6;
    let mc = identify_scene(&s, &program, None, Some(trials), &NoProgress).expect("identifies");
    let spread = mc.report.identified[0]
        .monte_carlo_spread
        .expect("Monte Carlo ran");
    // The same trials as a study: nothing varied but the scanner's seed, seeded as
    // `identify` seeds its Monte-Carlo trials.
    sb.write(
        "mc.toml",
        format!(
            "scene = \"s.toml\"\ntrials = {trials}\nscanner_seed_base = {}\n",
            s.monte_carlo_seed
        )
        .as_bytes(),
    );
    let m = study::plan(&sb.dir.join("mc.toml"), 3).expect("plans");
    let mut rows = Vec::new();
    for i in 0..3 {
        rows.extend(study::run_shard(&m, i).expect("runs"));
    }
    let summary = study::summarize(&m, &rows);
    let p = &summary.parameters[0];
    assert_eq!(p.name, "dy_AY");
    assert_eq!(p.determined, trials);
    assert!(
        (p.spread - spread).abs() <= 1e-12 * spread.max(1e-9),
        "study spread {} vs identify --monte-carlo {spread}",
        p.spread
    );
}

#[test]
fn a_study_varies_and_identifies_an_iso_term_by_its_name() {
    let sb = Sandbox::new("study-iso");
    sb.write("mdx50-step.ngc", builtin("mdx50-step.ngc").as_bytes());
    let scene = builtin("mdx50-step.toml")
        .replace("dy_AY = -0.50\n", "")
        .replace("known = {}", "known = {}\nparameters = [\"EY0A\"]")
        .replace("pitch_mm = 0.1 ", "pitch_mm = 0.2 ")
        .replace("pitch_mm = 0.185 ", "pitch_mm = 0.3 ");
    sb.write("s.toml", scene.as_bytes());
    sb.write(
        "study.toml",
        b"scene = \"s.toml\"\ntrials = 1\nseed = 3\n\
          [vary.deviations]\nEY0A = { uniform = [-0.6, -0.4] }\n",
    );
    let m = study::plan(&sb.dir.join("study.toml"), 1).expect("an ISO name is a deviation");
    let rows = study::run_shard(&m, 0).expect("runs");
    let t = &m.trials[0];
    let (name, v) = &t.deviations[0];
    assert_eq!(name, "EY0A");
    assert!((-0.6..=-0.4).contains(v));
    assert_eq!(rows[0].injected[0], *v, "the truth is the draw");
    // Independently: the draw written into the scene file's [deviations] by that name, read
    // by the scene reader, identified with the trial's scanner.
    sb.write(
        "s2.toml",
        scene
            .replace("[deviations]", &format!("[deviations]\nEY0A = {v:e}\n#"))
            .as_bytes(),
    );
    let mut s = twinmill::scene::Scene::load(&sb.dir.join("s2.toml")).expect("scene");
    let e = first_identified_with_the_trials_scanner(&mut s, t);
    assert_eq!(e.name, "EY0A");
    assert_eq!(rows[0].estimates[0], Some((e.value, e.sigma)));
    assert!(
        (e.value - v).abs() < 4.0 * e.sigma.max(1e-4),
        "EY0A {} ± {} against the injected {v}",
        e.value,
        e.sigma
    );
}
