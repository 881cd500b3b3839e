//! Bad input that outside fuzzing found, each case a test: damaged study shards, endless NC
//! loops, output paths that are not plain files, machines no one can build, and the one
//! form of every message (`file:line:col: key: what is wrong, what is expected`).

use crate::{Sandbox, builtin};
use std::path::{Path, PathBuf};
use twinmill::nc::{InterpOptions, Interpreter};
use twinmill::scene::{Scene, SceneError};
use twinmill::study::{self, Manifest, Row};

// ---------------------------------------------------------------------------------------
// Damaged shards

/// A planned study (the built-in step scene identifying `dy_AY`, `trials` trials, one shard)
/// and the path of its manifest.
fn planned_study(sb: &Sandbox, trials: usize) -> (Manifest, PathBuf) {
    sb.write("mdx50-step.ngc", builtin("mdx50-step.ngc").as_bytes());
    let scene = builtin("mdx50-step.toml").replace(
        "known = {}",
        "known = {}\nparameters = [\"dy_AY\", \"gamma_AY\"]",
    );
    sb.write("s.toml", scene.as_bytes());
    sb.write(
        "study.toml",
        format!(
            "scene = \"s.toml\"\ntrials = {trials}\nseed = 7\n\
             [vary.deviations]\ndy_AY = {{ uniform = [-0.6, -0.4] }}\n"
        )
        .as_bytes(),
    );
    let (code, _, err) = sb.run(&[
        "study",
        "plan",
        "study.toml",
        "--shards",
        "1",
        "--out",
        "m.json",
    ]);
    assert_eq!(code, 0, "{err}");
    let path = sb.dir.join("m.json");
    (study::read_manifest(&path).expect("the manifest"), path)
}

/// Rows for every trial of `m` with made-up outcomes of every kind (values, nulls, an
/// error), as `study run` would have them.
pub(crate) fn rows_for(m: &Manifest) -> Vec<Row> {
    m.trials
        .iter()
        .enumerate()
        .map(|(i, t)| {
            let x = i as f64;
            Row {
                inputs: t.clone(),
                estimates: (0..m.parameters.len())
                    .map(|k| (i + k != 2).then_some((-0.5 + 0.01 * x, 1e-3 * (1.0 + x))))
                    .collect(),
                injected: (0..m.parameters.len())
                    .map(|k| -0.5 - 0.1 * k as f64)
                    .collect(),
                chi2: (i != 1).then_some(100.0 + x),
                dof: Some(120 + i as u64),
                rounds: Some(2),
                converged: Some(i % 2 == 0),
                error: (i == 1).then(|| "a face cut nothing".to_string()),
                seconds: 0.25 * (x + 1.0),
            }
        })
        .collect()
}

/// Bits of a real shard's footer and metadata (and the magic number that opens it), and of
/// its data, flipped one at a time: the reader never panics; the
/// shard is refused with one line naming it, or — when the flipped bit is one the reader
/// does not use — read back to exactly the rows written. (The truth is the rows handed to
/// the writer, not anything the reader reports.)
#[test]
fn damaged_shards_are_refused_by_name_never_panicking() {
    let sb = Sandbox::new("damaged-shard");
    let (m, _) = planned_study(&sb, 4);
    let rows = rows_for(&m);
    let bytes = study::shard_parquet(&m, &rows).expect("a shard");
    let path = sb.dir.join(study::shard_file_name(0, 1));
    std::fs::write(&path, &bytes).expect("written");
    assert_eq!(study::read_shard(&m, &path).expect("the shard reads"), rows);
    let n = bytes.len();
    let meta_len = u32::from_le_bytes(bytes[n - 8..n - 4].try_into().expect("4 bytes")) as usize;
    let footer = n - 8 - meta_len;
    // every third bit of the metadata (3 and 8 coprime: every bit position of a byte), every
    // bit of the footer's length and magic and of the opening magic, every eleventh of the data
    let mut bits: Vec<usize> = (0..32).chain((n - 8) * 8..n * 8).collect();
    bits.extend((footer * 8..(n - 8) * 8).step_by(3));
    bits.extend((32..footer * 8).step_by(11));
    let name = path.display().to_string();
    let (mut refused, mut contained) = (0usize, None);
    for &bit in &bits {
        let mut damaged = bytes.clone();
        damaged[bit / 8] ^= 1 << (bit % 8);
        std::fs::write(&path, &damaged).expect("written");
        let r = std::panic::catch_unwind(|| study::read_shard(&m, &path));
        match r {
            Err(_) => panic!("bit {bit}: the reader panicked"),
            Ok(Ok(back)) => assert_eq!(back, rows, "bit {bit}: read back other rows"),
            Ok(Err(e)) => {
                let msg = e.to_string();
                assert!(
                    msg.starts_with(&format!("{name}: ")) && !msg.contains('\n'),
                    "bit {bit}: {msg}"
                );
                refused += 1;
                if contained.is_none() && msg.contains("the reader failed") {
                    contained = Some(damaged);
                }
            }
        }
    }
    // most flips damage something the reader needs
    assert!(
        refused * 2 > bits.len(),
        "{refused} of {} flips refused",
        bits.len()
    );
    // `study merge` on a damaged shard: exit 1 (not a panic's 101), one line naming it; the
    // shard whose damage made the Parquet reader panic when there is one
    let damaged = contained.unwrap_or_else(|| {
        let mut d = bytes.clone();
        d[n - 6] ^= 0x40; // the footer's metadata length, far beyond the file
        d
    });
    std::fs::write(&path, &damaged).expect("written");
    let (code, stdout, stderr) = sb.run(&["study", "merge", "m.json"]);
    assert_eq!(code, 1, "{stderr}");
    assert!(stdout.is_empty(), "{stdout}");
    assert_eq!(stderr.trim_end().lines().count(), 1, "{stderr}");
    assert!(
        stderr.starts_with("twinmill: error: ")
            && stderr.contains("shard-00000-of-00001.parquet: ")
            && stderr.contains("run the shard again")
            && !stderr.contains("panicked"),
        "{stderr}"
    );
}

// ---------------------------------------------------------------------------------------
// Endless loops

fn interpret(text: &str, opts: InterpOptions) -> Result<usize, String> {
    let mut moves = 0;
    for r in Interpreter::from_text(text, Path::new("loop.ngc"), opts) {
        match r {
            Ok(r) if matches!(r.body, twinmill::nc::RecordBody::Motion(_)) => moves += 1,
            Ok(_) => {}
            Err(e) => return Err(e.to_string()),
        }
    }
    Ok(moves)
}

/// Loops that move nothing are stopped after `max_idle_blocks` lines in a row, whatever
/// their form, with the limit in the message; loops that move run on (their lines in a
/// row without motion stay few); a move to where the tool is counts as no motion.
#[test]
fn endless_loops_stop_after_the_idle_limit() {
    let opts = |limit: u64| InterpOptions {
        max_idle_blocks: limit,
        ..InterpOptions::default()
    };
    let endless = [
        "o100 while [1]\no100 endwhile\nM2\n",
        "o100 repeat [100000000]\no100 endrepeat\nM2\n",
        "M98 P1000 L100000000\nM30\nO1000\nM99\n",
        "G0 X1\no100 while [1]\nG0 X1\no100 endwhile\nM2\n",
        "#1=0\no100 do\n#1=[#1+1]\no100 while [#1 GT -1]\nM2\n",
    ];
    for text in endless {
        let e = interpret(text, opts(5_000)).expect_err(text);
        assert!(
            e.contains("more than 5000 blocks in a row without motion") && !e.contains('\n'),
            "{text}: {e}"
        );
    }
    // 3,000 turns of a loop that moves: 6,000 moves, at most four lines between two
    let moving = "o100 repeat [3000]\nG1 X1 F100\nG1 X0\no100 endrepeat\nM2\n";
    assert_eq!(interpret(moving, opts(5)), Ok(6000));
    // the same program with the limit below the lines between its moves
    let sparse = "G1 X1 F100\n#1=1\n#2=2\n#3=3\n#4=4\nG1 X0\nM2\n";
    assert_eq!(interpret(sparse, opts(5)), Ok(2));
    assert!(interpret(sparse, opts(4)).is_err());
}

/// The fuzz reproducers through `nc motion` with its default limit: one line, exit 1,
/// within the million idle lines (not the 10⁸-line guard); `--max-idle-blocks 0` is
/// refused.
#[test]
fn nc_motion_stops_endless_loops_by_default() {
    let sb = Sandbox::new("endless-loops");
    for (name, text) in [
        ("while.ngc", "o100 while [1]\no100 endwhile\nM2\n"),
        (
            "repeat.ngc",
            "o100 repeat [100000000]\no100 endrepeat\nM2\n",
        ),
        ("m98.ngc", "M98 P1000 L100000000\nM30\nO1000\nM99\n"),
    ] {
        sb.write(name, text.as_bytes());
        let (code, _, stderr) = sb.run(&["nc", "motion", name, "--jsonl"]);
        assert_eq!(code, 1, "{name}: {stderr}");
        assert_eq!(stderr.trim_end().lines().count(), 1, "{stderr}");
        assert!(
            stderr.starts_with(&format!("twinmill: error: {name}:"))
                && stderr.contains("more than 1000000 blocks in a row without motion"),
            "{stderr}"
        );
    }
    let (code, _, stderr) = sb.run(&["nc", "motion", "while.ngc", "--max-idle-blocks", "0"]);
    assert_ne!(code, 0, "{stderr}");
}

// ---------------------------------------------------------------------------------------
// Output paths

/// `evaluate iso230-2` of the repository's measured readings, writing its plot to `png`.
fn evaluate_to(sb: &Sandbox, png: &str) -> (i32, String) {
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/iso230-2-psi-sls-stage.csv");
    let (code, _, stderr) = sb.run(&[
        "evaluate",
        "iso230-2",
        &data.display().to_string(),
        "--png",
        png,
    ]);
    (code, stderr)
}

/// A missing folder is reported under the path given (not a temporary name); a symbolic
/// link is written through to its target; a FIFO and a device (behind a link, so that a
/// failure here cannot touch the machine's /dev) are refused and left as they are.
#[cfg(unix)]
#[test]
fn output_paths_are_named_as_given_and_never_replace_what_is_not_a_file() {
    use std::os::unix::fs::FileTypeExt;
    let sb = Sandbox::new("output-paths");
    let (code, stderr) = evaluate_to(&sb, "nodir/plot.png");
    assert_eq!(code, 1, "{stderr}");
    assert_eq!(stderr.trim_end().lines().count(), 1, "{stderr}");
    assert!(
        stderr.starts_with(
            "twinmill: error: nodir/plot.png: cannot write: the folder nodir does not exist"
        ) && !stderr.contains("partial"),
        "{stderr}"
    );
    // a link to a file in another folder: the file is written, the link stays a link
    std::fs::create_dir_all(sb.dir.join("real")).expect("dir");
    std::os::unix::fs::symlink("real/plot.png", sb.dir.join("link.png")).expect("link");
    let (code, stderr) = evaluate_to(&sb, "link.png");
    assert_eq!(code, 0, "{stderr}");
    let meta = std::fs::symlink_metadata(sb.dir.join("link.png")).expect("still there");
    assert!(meta.file_type().is_symlink());
    let png = std::fs::read(sb.dir.join("real/plot.png")).expect("the target written");
    assert!(png.starts_with(b"\x89PNG\r\n\x1a\n"));
    // a FIFO, and a link to a device: refused by name, left alone
    let fifo = sb.dir.join("fifo.png");
    let made = std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .expect("mkfifo");
    assert!(made.success());
    std::os::unix::fs::symlink("/dev/null", sb.dir.join("null.png")).expect("link");
    for (name, what) in [
        ("fifo.png", "a FIFO"),
        ("null.png", "it leads to /dev/null, a device"),
    ] {
        let (code, stderr) = evaluate_to(&sb, name);
        assert_eq!(code, 1, "{stderr}");
        assert!(
            stderr.starts_with(&format!("twinmill: error: {name}: cannot write: {what}"))
                && stderr.trim_end().lines().count() == 1,
            "{stderr}"
        );
    }
    assert!(
        std::fs::symlink_metadata(&fifo)
            .expect("fifo")
            .file_type()
            .is_fifo()
    );
    assert!(
        std::fs::metadata("/dev/null")
            .expect("null")
            .file_type()
            .is_char_device()
    );
    assert!(
        std::fs::symlink_metadata(sb.dir.join("null.png"))
            .expect("link")
            .file_type()
            .is_symlink()
    );
}

/// A folder of outputs: a link to a folder is written through (the link stays), a file
/// where the folder goes is refused and kept, and a streamed file over a FIFO is refused.
#[cfg(unix)]
#[test]
fn output_folders_follow_links_and_refuse_files() {
    use twinmill::output::{write_files, write_streamed};
    let sb = Sandbox::new("output-folders");
    let files = [("a.txt", b"one".to_vec()), ("b.txt", b"two".to_vec())];
    std::fs::create_dir_all(sb.dir.join("target")).expect("dir");
    std::fs::write(sb.dir.join("target/old.txt"), b"old").expect("old");
    std::os::unix::fs::symlink("target", sb.dir.join("out")).expect("link");
    write_files(&sb.dir.join("out"), &files).expect("written through the link");
    assert!(
        std::fs::symlink_metadata(sb.dir.join("out"))
            .expect("link")
            .file_type()
            .is_symlink()
    );
    assert_eq!(
        std::fs::read(sb.dir.join("target/b.txt")).expect("b"),
        b"two"
    );
    assert!(
        !sb.dir.join("target/old.txt").exists(),
        "the folder is replaced as a whole"
    );
    let file = sb.write("plain", b"keep me");
    let e = write_files(&file, &files).expect_err("a file where the folder goes");
    assert!(
        e.to_string()
            .starts_with(&format!("{}: cannot write: a file", file.display())),
        "{e}"
    );
    assert_eq!(std::fs::read(&file).expect("kept"), b"keep me");
    let made = std::process::Command::new("mkfifo")
        .arg(sb.dir.join("target/c.txt"))
        .status()
        .expect("mkfifo");
    assert!(made.success());
    let streamed: Vec<twinmill::output::StreamedFile<'_>> = vec![(
        "c.txt".to_string(),
        Box::new(|w: &mut dyn std::io::Write| w.write_all(b"three")),
    )];
    let e = write_streamed(&sb.dir.join("target"), streamed).expect_err("a FIFO");
    assert!(e.to_string().contains("c.txt: cannot write: a FIFO"), "{e}");
    let leftovers: Vec<_> = crate::files_in(&sb.dir.join("target"))
        .into_iter()
        .filter(|p| p.to_string_lossy().contains("partial"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
}

/// A folder of streamed outputs (how `simulate` writes its mesh) whose second file fails
/// half-way: the error names that file, the folder keeps what it held before, whole, and no
/// staging folder is left beside it.
#[test]
fn a_streamed_output_folder_failing_half_way_leaves_the_old_one_whole() {
    use twinmill::output::{StreamedFile, write_files, write_files_streamed};
    let sb = Sandbox::new("streamed-folder");
    let out = sb.dir.join("out");
    write_files(
        &out,
        &[("a.txt", b"old a".to_vec()), ("b.txt", b"old b".to_vec())],
    )
    .expect("the first outputs");
    let files: Vec<StreamedFile<'_>> = vec![
        ("a.txt".into(), Box::new(|w| w.write_all(b"new a"))),
        (
            "b.txt".into(),
            Box::new(|w| {
                w.write_all(&[7u8; 100_000])?;
                Err(std::io::Error::other("the mesh failed half-way"))
            }),
        ),
    ];
    let e = write_files_streamed(&out, files).expect_err("the second file fails");
    assert!(
        e.to_string().contains("b.txt") && e.to_string().contains("half-way"),
        "{e}"
    );
    assert_eq!(std::fs::read(out.join("a.txt")).expect("a"), b"old a");
    assert_eq!(std::fs::read(out.join("b.txt")).expect("b"), b"old b");
    let left: Vec<_> = crate::files_in(&sb.dir)
        .into_iter()
        .filter(|p| p.to_string_lossy().contains("partial"))
        .collect();
    assert!(left.is_empty(), "{left:?}");
    let files: Vec<StreamedFile<'_>> = vec![
        ("a.txt".into(), Box::new(|w| w.write_all(b"new a"))),
        ("c.txt".into(), Box::new(|w| w.write_all(&[7u8; 100_000]))),
    ];
    write_files_streamed(&out, files).expect("written");
    assert_eq!(std::fs::read(out.join("a.txt")).expect("a"), b"new a");
    assert_eq!(std::fs::read(out.join("c.txt")).expect("c").len(), 100_000);
    assert!(
        !out.join("b.txt").exists(),
        "the folder is replaced as a whole"
    );
}

// ---------------------------------------------------------------------------------------
// Machines no one can build

/// The scene error for `text`, with the 1-based line and column of the first occurrence of
/// `at` in it: where the message must point.
fn scene_error(text: &str, at: &str) -> (String, String) {
    let path = Path::new("m.toml");
    let e = match Scene::parse(text, path) {
        Err(e @ SceneError::Invalid { .. }) => e.to_string(),
        other => panic!(
            "expected a located error for '{at}', got {:?}",
            other.map(|_| ())
        ),
    };
    let offset = text.find(at).expect("the marker is in the text");
    let line = text[..offset].matches('\n').count() + 1;
    let column = offset - text[..offset].rfind('\n').map_or(0, |i| i + 1) + 1;
    (e, format!("m.toml:{line}:{column}: "))
}

/// Where the scene's `axes` array begins: the span of machine-wide axis errors.
const AXES: &str = "[\n  { name = \"A\"";

/// `home` at 1e308, an axis direction of length 1e308, X parallel to Y (and nearly so), three
/// linear axes in a plane: refused at the value, naming the key; a skewed but real machine
/// (Y 5° off square) is accepted.
#[test]
fn absurd_machines_are_refused_naming_the_key() {
    let base = builtin("mdx50-step.toml");
    assert!(base.contains("Z = 60, A = 0 }   # axis"));
    let y_axis = "{ name = \"Y\", kind = \"linear\", direction = [0, 1, 0]";
    assert!(base.contains(y_axis), "the built-in scene's Y axis");
    let cases: [(&str, &str, &str, &str); 5] = [
        (
            "Z = 60, A = 0 }",
            "Z = 1e308, A = 0 }",
            "1e308",
            "machine.home.Z: got 1e308 mm, expected within ±100000 mm",
        ),
        (
            "A = 0 }   # axis",
            "A = 1e9 }   # axis",
            "1e9",
            "machine.home.A: got 1e9°",
        ),
        (
            y_axis,
            &y_axis.replace("[0, 1, 0]", "[1, 1e308, 0]"),
            "[1, 1e308",
            "machine.axes.Y.direction: got [1.0, 1e308, 0.0] (length 1e308), expected a direction of length 0.001 to 1000",
        ),
        (
            y_axis,
            &y_axis.replace("[0, 1, 0]", "[1, 0, 0]"),
            AXES,
            "machine.axes: axes Y and X are 0.000° from parallel, expected linear axes at least 1° apart",
        ),
        (
            y_axis,
            &y_axis.replace("[0, 1, 0]", "[1, 0.01, 0]"),
            AXES,
            "machine.axes: axes Y and X are 0.573° from parallel",
        ),
    ];
    for (from, to, at, expect) in cases {
        let text = base.replacen(from, to, 1);
        let (e, loc) = scene_error(&text, at);
        assert!(
            e.starts_with(&loc) && e.contains(expect),
            "{e}\nexpected {loc}{expect}"
        );
    }
    let coplanar = base.replacen(
        "{ name = \"Z\", kind = \"linear\", direction = [0, 0, 1]",
        "{ name = \"Z\", kind = \"linear\", direction = [1, 1, 0]",
        1,
    );
    let (e, loc) = scene_error(&coplanar, AXES);
    assert!(
        e.starts_with(&loc) && e.contains("lie 0.000° from one plane"),
        "{e}"
    );
    // 5° off square is a machine (a skewed one): accepted
    let skewed = 5f64.to_radians();
    let text = base.replacen(
        y_axis,
        &y_axis.replace(
            "[0, 1, 0]",
            &format!("[{}, {}, 0]", skewed.sin(), skewed.cos()),
        ),
        1,
    );
    Scene::parse(&text, Path::new("m.toml")).expect("a skewed machine is a machine");
}

/// The hexapod reader refuses the same: a home pose 1e308 mm away, a joint axis of length
/// 1e308, a joint beyond 100 m.
#[test]
fn absurd_hexapods_are_refused_naming_the_key() {
    use twinmill::scene::HexapodScene;
    let base = builtin("hexapod-genhexkins.toml");
    let home = base
        .lines()
        .find(|l| l.trim_start().starts_with("home"))
        .expect("a home line")
        .to_string();
    let first = home.find('[').expect("home = [") + 1;
    let mut bad_home = home.clone();
    bad_home.replace_range(first..first + home[first..].find(',').expect("x,"), "1e308");
    for (from, to, expect) in [
        (
            home.as_str(),
            bad_home.as_str(),
            "machine.home: got 1e308 mm",
        ),
        (
            "[machine]",
            "[machine]\nbase_joint_axis = [1, 1e308, 0]",
            "machine.base_joint_axis: got [1.0, 1e308, 0.0]",
        ),
    ] {
        let text = base.replacen(from, to, 1);
        let e = match HexapodScene::parse(&text, Path::new("h.toml")) {
            Err(e) => e.to_string(),
            Ok(_) => panic!("accepted: {to}"),
        };
        let line = text[..text.find(to).expect("inserted")]
            .matches('\n')
            .count()
            + 1;
        assert!(
            e.starts_with(&format!("h.toml:{line}:"))
                || e.starts_with(&format!("h.toml:{}:", line + 1)),
            "{e}"
        );
        assert!(e.contains(expect), "{e}");
    }
}

// ---------------------------------------------------------------------------------------
// One form of message

/// The 1-based line and column of the first `needle` in `text`.
fn at(text: &str, needle: &str) -> String {
    let offset = text.find(needle).expect("the needle is in the text");
    let line = text[..offset].matches('\n').count() + 1;
    let column = text[..offset]
        .rsplit('\n')
        .next()
        .map_or(0, |l| l.chars().count())
        + 1;
    format!("{line}:{column}")
}

/// The error of scene `text` (as `s.toml`).
fn parse_error(text: &str) -> String {
    match Scene::parse(text, Path::new("s.toml")) {
        Err(e) => e.to_string(),
        Ok(_) => panic!("accepted:\n{text}"),
    }
}

/// A TOML type error names the file, the value's line and column, the key, what was given
/// and what is expected — in words, not Rust's (`invalid type: string "ball", expected f64`).
#[test]
fn toml_type_errors_name_the_key_in_words() {
    let base = builtin("mdx50-step.toml");
    let cases = [
        (
            "diameter_mm = 6.0",
            "diameter_mm = \"ball\"",
            "\"ball\"",
            "tool.diameter_mm: got the string \"ball\", expected a number",
        ),
        (
            "Z = 60, A = 0 }",
            "Z = true, A = 0 }",
            "true",
            "machine.home.Z: got the boolean true, expected a number",
        ),
        (
            "direction = [0, 1, 0]",
            "direction = [0, 1]",
            "[0, 1]",
            "got 2 values, expected an array of length 3",
        ),
        (
            "kind = \"flat\"",
            "kind = 3",
            "3         # flat",
            "tool.kind: got the integer 3, expected a string",
        ),
    ];
    for (from, to, value, expect) in cases {
        let text = base.replacen(from, to, 1);
        let e = parse_error(&text);
        let loc = format!("s.toml:{}: ", at(&text, value));
        assert!(
            e.starts_with(&loc) && e.contains(expect) && !e.contains('\n'),
            "{e}\nexpected {loc}{expect}"
        );
        assert!(!e.contains("f64") && !e.contains("invalid type"), "{e}");
    }
    // a key the reader does not know, and one that is missing
    let text = base.replacen("diameter_mm = 6.0", "diameter = 6.0", 1);
    let e = parse_error(&text);
    let loc = format!("s.toml:{}: ", at(&text, "diameter ="));
    assert!(
        e.starts_with(&loc) && e.contains("tool.diameter: unknown key, expected one of \"kind\""),
        "{e}"
    );
    let text = base.replacen("length_mm = 25.0", "", 1);
    let e = parse_error(&text);
    assert!(
        e.starts_with("s.toml:") && e.contains("tool.length_mm: missing, expected a value"),
        "{e}"
    );
}

/// A study file's errors in the same form: the file once, the location once, the key.
#[test]
fn study_errors_have_the_one_form() {
    let sb = Sandbox::new("study-messages");
    planned_study(&sb, 2);
    let study = "scene = \"s.toml\"\ntrials = \"x\"\n";
    sb.write("bad.toml", study.as_bytes());
    let (code, _, stderr) = sb.run(&["study", "plan", "bad.toml"]);
    assert_eq!(code, 1);
    assert_eq!(
        stderr.trim_end(),
        format!(
            "twinmill: error: bad.toml:{}: trials: got the string \"x\", expected a whole number, 0 or more",
            at(study, "\"x\"")
        )
    );
    let study = "scene = \"s.toml\"\ntrials = 0\n";
    sb.write("zero.toml", study.as_bytes());
    let (_, _, stderr) = sb.run(&["study", "plan", "zero.toml"]);
    assert_eq!(
        stderr.trim_end(),
        format!(
            "twinmill: error: zero.toml:{}: trials: got 0, expected 1 to 10000000",
            at(study, "0")
        )
    );
    // an error in the scene is the scene's, located there, named once
    let scene = std::fs::read_to_string(sb.dir.join("s.toml"))
        .expect("scene")
        .replacen("diameter_mm = 6.0", "diameter_mm = \"x\"", 1);
    sb.write("s.toml", scene.as_bytes());
    let (_, _, stderr) = sb.run(&["study", "plan", "study.toml"]);
    let loc = format!("s.toml:{}: tool.diameter_mm: ", at(&scene, "\"x\""));
    assert!(
        stderr.contains(&loc) && stderr.matches("s.toml").count() == 1,
        "{stderr}"
    );
}

/// `fit --sphere` on points in one plane says so (not `nothing found`); a PLY value that is
/// not a number is located to its line and column with its property; an NC program's errors
/// are one line with the prefix.
#[test]
fn fit_ply_and_nc_messages_say_what_is_wrong() {
    let sb = Sandbox::new("messages");
    let mut ply = String::from(
        "ply\nformat ascii 1.0\nelement vertex 400\nproperty double x\nproperty double y\n\
         property double z\nend_header\n",
    );
    for i in 0..400 {
        ply.push_str(&format!("{} {} 5\n", i % 20, i / 20));
    }
    sb.write("flat.ply", ply.as_bytes());
    let (code, _, stderr) = sb.run(&["fit", "flat.ply", "--sphere"]);
    assert_eq!(code, 1, "{stderr}");
    assert!(
        stderr.starts_with(
            "twinmill: error: flat.ply: no sphere found: the 400 points lie in one plane"
        ) && stderr.trim_end().lines().count() == 1,
        "{stderr}"
    );
    let bad = ply.replacen("3 1 5\n", "3 1 z5\n", 1);
    sb.write("bad.ply", bad.as_bytes());
    let (code, _, stderr) = sb.run(&["fit", "bad.ply"]);
    assert_eq!(code, 1, "{stderr}");
    assert_eq!(
        stderr.trim_end(),
        format!(
            "twinmill: error: bad.ply:{}: malformed PLY: vertex 23, property z: got 'z5', expected a double",
            at(&bad, "z5")
        )
    );
    sb.write("p.ngc", b"G21\nG1 X1 F100\nG2 X2\nG1 X3 Y4.4.4\nM2\n");
    let (code, _, stderr) = sb.run(&["nc", "motion", "p.ngc", "--jsonl"]);
    assert_eq!(code, 1, "{stderr}");
    assert_eq!(stderr.trim_end().lines().count(), 1, "{stderr}");
    assert!(
        stderr.starts_with("twinmill: error: p.ngc:3:1: \"G2\": "),
        "{stderr}"
    );
}
