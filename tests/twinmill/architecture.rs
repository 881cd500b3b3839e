//! Architecture: folders and the modules in them depend only on what comes before them in
//! the pipeline, and docs/architecture.md maps exactly this layout.

use std::path::{Path, PathBuf};

/// The library's layout in pipeline order: each top-level module or folder of `src/`, and
/// for a folder its modules in order. A module may use only modules of earlier folders and
/// earlier modules of its own folder (a folder's `mod.rs` is its shared vocabulary).
const LAYOUT: &[(&str, &[&str])] = &[
    ("math", &[]),
    ("progress", &[]),
    (
        "nc",
        &[
            "source",
            "lex",
            "tooltable",
            "output",
            "comp",
            "interp",
            "synthetic",
        ],
    ),
    (
        "machine",
        &[
            "error_motion",
            "chain",
            "tcp",
            "hexapod",
            "hexapod_accuracy",
        ],
    ),
    (
        "cutting",
        &[
            "tool", "shape", "stock", "cutter", "envelope", "sweep", "collide", "mesh", "adaptive",
            "zmap", "nominal",
        ],
    ),
    (
        "metrology",
        &[
            "cloud",
            "scan",
            "fit",
            "segment",
            "table",
            "positioning",
            "comp_table",
            "circular",
            "ball_sensor",
            "interferometer",
            "ballbar",
            "rotary_test",
            "hexapod_dbb",
        ],
    ),
    (
        "calibration",
        &[
            "goodness",
            "identify",
            "determined",
            "engine",
            "calibrate",
            "design",
            "correct",
            "step",
            "hexapod_calibrate",
            "hexapod_design",
            "instruments",
            "hexapod_probe",
            "hexapod_dbb_probe",
        ],
    ),
    (
        "report",
        &[
            "render",
            "deviation_map",
            "plots",
            "glb",
            "display",
            "part_view",
            "svg",
            "html",
            "simulate",
            "scan",
            "run",
            "fit",
            "correct",
            "identify",
            "design",
            "hexapod",
            "pages",
        ],
    ),
    (
        "scene",
        &[
            "file",
            "check",
            "memory",
            "machine",
            "deviations",
            "hexapod",
            "cut",
            "scanner",
            "identify",
            "report",
            "program",
            "read",
            "write",
        ],
    ),
    (
        "pipeline",
        &[
            "pages",
            "simulate",
            "run",
            "fit",
            "correct",
            "identify",
            "design",
            "rotary",
            "hexapod",
            "dbb",
            "instrument_pages",
            "evaluate",
            "measure",
            "measurements",
            "hexapod_probe",
        ],
    ),
    ("output", &[]),
    ("study", &[]),
    // The binary crate's argument tree, one file per verb (`src/main.rs` declares it).
    (
        "cli",
        &[
            "nc", "simulate", "scan", "measure", "evaluate", "fit", "identify", "design",
            "correct", "run", "study", "hexapod",
        ],
    ),
];

/// Every `.rs` file at or below `path` (a file or a folder), sorted.
fn rust_files(path: &Path) -> Vec<PathBuf> {
    if path.is_file() {
        return vec![path.to_path_buf()];
    }
    let mut out = Vec::new();
    let mut entries: Vec<PathBuf> = std::fs::read_dir(path)
        .map(|d| d.flatten().map(|e| e.path()).collect())
        .unwrap_or_default();
    entries.sort();
    for e in entries {
        if e.is_dir() {
            out.extend(rust_files(&e));
        } else if e.extension().is_some_and(|x| x == "rs") {
            out.push(e);
        }
    }
    out
}

/// The source of a module (a file, or a folder of files) without its comment lines.
fn module_code(path: &Path) -> String {
    rust_files(path)
        .iter()
        .map(|p| std::fs::read_to_string(p).expect("source"))
        .collect::<Vec<_>>()
        .join("\n")
        .lines()
        .filter(|l| !l.trim_start().starts_with("//"))
        .collect::<Vec<_>>()
        .join("\n")
}

/// The names that follow each occurrence of `prefix` in `code` (`crate::a::b` → ["a", "b"]).
fn paths_after(code: &str, prefix: &str) -> Vec<Vec<String>> {
    code.match_indices(prefix)
        .filter(|(i, _)| {
            // `crate::` itself, not the tail of a longer identifier.
            code[..*i]
                .chars()
                .next_back()
                .is_none_or(|c| !(c.is_ascii_alphanumeric() || c == '_'))
        })
        .map(|(i, _)| {
            code[i + prefix.len()..]
                .split("::")
                .map(|seg| {
                    seg.chars()
                        .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                        .collect::<String>()
                })
                .take_while(|seg| !seg.is_empty())
                .take(2)
                .collect()
        })
        .collect()
}

/// The place of a module in the layout: (folder rank, rank within the folder).
fn place(folder: &str, module: Option<&str>) -> Option<(usize, Option<usize>)> {
    let f = LAYOUT.iter().position(|(name, _)| *name == folder)?;
    match module {
        None => Some((f, None)),
        Some(m) => Some((f, Some(LAYOUT[f].1.iter().position(|x| *x == m)?))),
    }
}

/// The modules a folder declares by its files and subfolders (a module may be both
/// `name.rs` and `name/`), sorted, without those in `except`.
fn module_names(dir: &Path, except: &[&str]) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .expect("source folder")
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.is_dir() || p.extension().is_some_and(|x| x == "rs"))
        .filter_map(|p| p.file_stem().and_then(|s| s.to_str()).map(str::to_string))
        .filter(|s| !except.contains(&s.as_str()))
        .collect();
    names.sort();
    names.dedup();
    names
}

#[test]
fn module_dependencies_point_down_the_pipeline() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    // Every file and folder of src/ is in the layout, and every module of a folder too.
    let found = module_names(&src, &["lib", "main"]);
    let mut listed: Vec<String> = LAYOUT.iter().map(|(n, _)| n.to_string()).collect();
    listed.sort();
    assert_eq!(found, listed, "src/ against the layout");
    let mut checked = 0;
    for (folder, modules) in LAYOUT {
        let dir = src.join(folder);
        // (module name or None for a top-level file or a folder's mod.rs, its path)
        let mut units: Vec<(Option<&str>, PathBuf)> = Vec::new();
        if dir.is_dir() {
            let inside = module_names(&dir, &["mod", "tests"]);
            let mut expected: Vec<String> = modules.iter().map(|m| m.to_string()).collect();
            expected.sort();
            assert_eq!(
                inside, expected,
                "modules of src/{folder}/ against the layout"
            );
            let head = std::fs::read_to_string(dir.join("mod.rs")).expect("mod.rs");
            assert!(
                head.starts_with("//! **"),
                "src/{folder}/mod.rs must open with a paragraph on what the folder owns and may use"
            );
            units.push((None, dir.join("mod.rs")));
            for m in *modules {
                let file = dir.join(format!("{m}.rs"));
                let sub = dir.join(m);
                if file.is_file() {
                    units.push((Some(m), file));
                }
                if sub.is_dir() {
                    units.push((Some(m), sub));
                }
            }
        } else {
            units.push((None, src.join(format!("{folder}.rs"))));
        }
        for (module, path) in units {
            let name = match module {
                Some(m) => format!("{folder}::{m}"),
                None => folder.to_string(),
            };
            let (rank, inner) = place(folder, module).expect("placed");
            let code = module_code(&path);
            for used in paths_after(&code, "crate::") {
                let Some(top) = used.first() else { continue };
                let Some((r, _)) = place(top, None) else {
                    continue;
                };
                assert!(
                    r <= rank,
                    "{name} uses crate::{top}, a later stage: dependencies must point down the pipeline"
                );
                // Within its own folder, a module uses only the modules before it.
                if r == rank
                    && let (Some(me), Some(other)) = (inner, used.get(1))
                    && let Some((_, Some(o))) = place(top, Some(other))
                {
                    assert!(
                        o <= me,
                        "{name} uses crate::{top}::{other}, a later module of its folder"
                    );
                }
            }
            // The same through `super::` from a folder's module to its siblings.
            if let Some(me) = inner {
                for used in paths_after(&code, "super::") {
                    if let Some((_, Some(o))) = used.first().and_then(|s| place(folder, Some(s))) {
                        assert!(
                            o <= me,
                            "{name} uses super::{}, a later module of its folder",
                            used[0]
                        );
                    }
                }
            }
            // The library never prints.
            for bad in ["println!", "eprintln!", "print!(", "dbg!("] {
                assert!(!code.contains(bad), "{name} contains {bad}");
            }
            checked += 1;
        }
    }
    assert!(checked >= 30, "only {checked} modules checked");

    // The command line is thin and the library never reaches back into it: `main.rs` fits
    // in 200 lines, no library file names `cli::`, and no file of `src/` is over 1,500
    // lines (a module that grows past that becomes a folder of files).
    let main = std::fs::read_to_string(src.join("main.rs")).expect("main.rs");
    assert!(
        main.lines().count() <= 200,
        "src/main.rs has {} lines: arguments go into src/cli/, logic into src/pipeline/",
        main.lines().count()
    );
    for (folder, _) in LAYOUT.iter().filter(|(f, _)| *f != "cli") {
        let path = if src.join(folder).is_dir() {
            src.join(folder)
        } else {
            src.join(format!("{folder}.rs"))
        };
        assert!(
            !module_code(&path).contains("cli::"),
            "{folder} names the command line's cli:: module"
        );
    }
    for file in rust_files(&src) {
        let lines = std::fs::read_to_string(&file)
            .expect("source")
            .lines()
            .count();
        assert!(
            lines <= 1500,
            "{} has {lines} lines (at most 1,500)",
            file.display()
        );
    }

    // docs/architecture.md names every folder and module, in this order, as bold code.
    let doc =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/architecture.md"))
            .expect("docs/architecture.md");
    let named: Vec<String> = doc
        .match_indices("**`")
        .filter_map(|(i, _)| {
            let rest = &doc[i + 3..];
            let end = rest.find("`**")?;
            let n = &rest[..end];
            n.chars()
                .all(|c| c.is_ascii_lowercase() || c == '_' || c == '/')
                .then(|| n.to_string())
        })
        .collect();
    let mut expected = Vec::new();
    for (folder, modules) in LAYOUT {
        if src.join(folder).is_dir() {
            expected.push(format!("{folder}/"));
            expected.extend(modules.iter().map(|m| m.to_string()));
        } else {
            expected.push(folder.to_string());
        }
    }
    assert_eq!(
        named, expected,
        "docs/architecture.md must name every folder and module of src/, in pipeline order, as **`name`** (folders as **`name/`**)"
    );
}
