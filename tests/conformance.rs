//! Conformance of the NC interpreter with LinuxCNC's standalone interpreter (`rs274`).
//!
//! Every program of the conformance corpus (`tests/corpus`: LinuxCNC's own interpreter tests
//! and the project's samples, with LinuxCNC 2.9's recorded output; see its README) is run
//! through twinmill's interpreter with the options LinuxCNC was run with (tool table,
//! INI, external unit inch as standalone `rs274`) and compared move by move with LinuxCNC's
//! recorded, normalised output (`*.jsonl`): same move kinds, end and start positions within
//! 1e-4 mm (mm programs) or 3e-3 mm (inch programs), same arc centres, directions and
//! turns. A program LinuxCNC rejects must be rejected at the same line (the line whose text
//! LinuxCNC printed as the offending block), after the same moves.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde_json::Value;
use twinmill::nc::{Interpreter, LengthUnit, MotionKind, RecordBody, options_from_files};

/// Position tolerance for programs in mm: rs274 prints 4 decimals of mm.
const TOL_MM_PROGRAM: f64 = 1e-4;
/// Position tolerance for inch programs: 4 decimals of inch (2.54 µm) plus offsets
/// announced with the same rounding.
const TOL_INCH_PROGRAM: f64 = 3e-3;

/// Programs not matched yet, with the reason. Keep it short and exact: the test fails when a
/// listed program starts to match (so the list stays true).
const NOT_MATCHED: &[(&str, &str)] = &[];

/// Programs in the corpus (LinuxCNC's 132 interpreter tests and 50 example programs, and the
/// project's 98 samples): the test runs every one, so a program that goes missing fails it.
const PROGRAMS: usize = 280;

fn corpus_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/corpus")
}

struct Case {
    program: PathBuf,
    reference: PathBuf,
    tool_table: Option<PathBuf>,
    ini: Option<PathBuf>,
}

/// `rs274 options` column of the LinuxCNC corpus README: program → options.
fn readme_options(root: &Path) -> BTreeMap<String, String> {
    let text = std::fs::read_to_string(root.join("linuxcnc/README.md")).expect("README");
    let mut out = BTreeMap::new();
    for line in text.lines() {
        let cols: Vec<&str> = line.split('|').map(str::trim).collect();
        if cols.len() > 3 && cols[1].starts_with('`') && cols[1].ends_with(".ngc`") {
            out.insert(
                cols[1].trim_matches('`').to_string(),
                cols[2].trim_matches('`').to_string(),
            );
        }
    }
    out
}

fn collect(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return;
    };
    let mut entries: Vec<PathBuf> = rd.filter_map(|e| e.ok().map(|e| e.path())).collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            collect(&p, out);
        } else if p.extension().is_some_and(|e| e == "ngc") {
            out.push(p);
        }
    }
}

fn cases(root: &Path) -> Vec<Case> {
    let opts = readme_options(root);
    let mut programs = Vec::new();
    collect(root, &mut programs);
    let mut cases = Vec::new();
    for program in programs {
        let stem = program
            .file_stem()
            .and_then(|s| s.to_str())
            .unwrap_or("")
            .to_string();
        let dir = program.parent().expect("dir").to_path_buf();
        let linuxcnc = dir.join(format!("{stem}.debian-2.9.jsonl"));
        let sample = dir.join(format!("{stem}.jsonl"));
        let (reference, tool_table, ini) = if linuxcnc.is_file() {
            let rel = program
                .strip_prefix(root.join("linuxcnc"))
                .expect("inside")
                .to_string_lossy()
                .to_string();
            let o = opts.get(&rel).cloned().unwrap_or_default();
            let words: Vec<&str> = o.split_whitespace().collect();
            let mut tbl = None;
            let mut ini = None;
            for w in words.windows(2) {
                match w[0] {
                    "-t" => tbl = Some(dir.join(w[1])),
                    "-i" => ini = Some(dir.join(w[1])),
                    _ => {}
                }
            }
            (linuxcnc, tbl, ini)
        } else if sample.is_file() {
            (sample, Some(root.join("rs274-samples/tools.tbl")), None)
        } else {
            continue; // a subroutine file, not a program
        };
        cases.push(Case {
            program,
            reference,
            tool_table,
            ini,
        });
    }
    cases
}

/// One of our moves: kind, start, end, arc centre and signed rotation.
type OurMove = (MotionKind, [f64; 6], [f64; 6], Option<[f64; 4]>);

struct Ours {
    motions: Vec<OurMove>,
    error: Option<(PathBuf, usize, String)>,
}

fn run_ours(case: &Case) -> Result<Ours, String> {
    let opts = options_from_files(
        case.tool_table.as_deref(),
        None,
        case.ini.as_deref(),
        LengthUnit::Inch,
    )
    .map_err(|e| e.to_string())?;
    let interp = Interpreter::from_file(&case.program, opts).map_err(|e| e.to_string())?;
    let mut motions = Vec::new();
    let mut error = None;
    for rec in interp {
        match rec {
            Ok(r) => {
                if let RecordBody::Motion(m) = r.body {
                    let arc = m
                        .arc
                        .map(|a| [a.center.x, a.center.y, a.center.z, a.rotation as f64]);
                    motions.push((m.kind, m.start.to_array(), m.end.to_array(), arc));
                }
            }
            Err(e) => {
                let d = &e.diagnostics[0];
                error = Some((d.path.clone(), d.line, d.message.clone()));
                break;
            }
        }
    }
    Ok(Ours { motions, error })
}

fn point(v: &Value) -> Option<[f64; 6]> {
    let mut p = [0.0; 6];
    for (i, k) in ["x", "y", "z", "a", "b", "c"].iter().enumerate() {
        p[i] = v.get(*k)?.as_f64()?;
    }
    Some(p)
}

fn compare(case: &Case) -> Result<(), String> {
    let text = std::fs::read_to_string(&case.reference).map_err(|e| e.to_string())?;
    let recs: Vec<Value> = text
        .lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| serde_json::from_str(l).map_err(|e| e.to_string()))
        .collect::<Result<_, _>>()?;
    let inch = recs
        .iter()
        .any(|r| r["call"] == "USE_LENGTH_UNITS" && r["args"][0] == "CANON_UNITS_INCHES");
    let tol = if inch {
        TOL_INCH_PROGRAM
    } else {
        TOL_MM_PROGRAM
    };
    let ours = run_ours(case)?;
    let mut k = 0;
    for r in &recs {
        let kind = r["kind"].as_str().unwrap_or("");
        if kind == "event" || kind == "error" {
            continue;
        }
        let Some((mk, ms, me, marc)) = ours.motions.get(k) else {
            return Err(format!(
                "move {k} ({kind}) missing: we stopped after {} moves{}",
                ours.motions.len(),
                ours.error
                    .as_ref()
                    .map(|(p, l, m)| format!(" with error {}:{l}: {m}", p.display()))
                    .unwrap_or_default()
            ));
        };
        if mk.name() != kind {
            return Err(format!("move {k}: kind {} vs LinuxCNC {kind}", mk.name()));
        }
        let close = |a: &[f64; 6], b: &[f64; 6]| a.iter().zip(b).all(|(x, y)| (x - y).abs() <= tol);
        if let Some(end) = point(&r["end"])
            && !close(me, &end)
        {
            return Err(format!("move {k} ({kind}): end {me:?} vs LinuxCNC {end:?}"));
        }
        if let Some(start) = point(&r["start"])
            && !close(ms, &start)
        {
            return Err(format!(
                "move {k} ({kind}): start {ms:?} vs LinuxCNC {start:?}"
            ));
        }
        if kind == "arc" {
            let c = &r["center"];
            let rc = [
                c["x"].as_f64().unwrap_or(f64::NAN),
                c["y"].as_f64().unwrap_or(f64::NAN),
                c["z"].as_f64().unwrap_or(f64::NAN),
            ];
            let a = marc.unwrap_or([f64::NAN; 4]);
            if (0..3).any(|i| (a[i] - rc[i]).abs() > tol || a[i].is_nan()) {
                return Err(format!(
                    "move {k}: arc centre {:?} vs LinuxCNC {rc:?}",
                    &a[..3]
                ));
            }
            let rot = r["rotation"].as_f64().unwrap_or(0.0);
            if a[3] != rot {
                return Err(format!("move {k}: arc rotation {} vs LinuxCNC {rot}", a[3]));
            }
        }
        k += 1;
    }
    if k < ours.motions.len() {
        return Err(format!(
            "{} extra moves (first: {:?} to {:?})",
            ours.motions.len() - k,
            ours.motions[k].0,
            ours.motions[k].2
        ));
    }
    let reference_error = recs.iter().find(|r| r["kind"] == "error");
    match (reference_error, &ours.error) {
        (None, None) => Ok(()),
        (None, Some((p, l, m))) => Err(format!("we reject at {}:{l}: {m}", p.display())),
        (Some(r), None) => Err(format!("LinuxCNC rejects ({}) but we accept", r["message"])),
        (Some(r), Some((p, l, m))) => {
            let block = r["block"].as_str().unwrap_or("").trim().to_string();
            let src = std::fs::read_to_string(p).unwrap_or_default();
            let ours_line = src
                .lines()
                .nth(l.saturating_sub(1))
                .unwrap_or("")
                .trim()
                .to_string();
            if ours_line == block {
                Ok(())
            } else {
                Err(format!(
                    "rejected at {}:{l} \"{ours_line}\" ({m}) but LinuxCNC at \"{block}\" ({})",
                    p.display(),
                    r["message"]
                ))
            }
        }
    }
}

#[test]
fn corpus_matches_linuxcnc_move_for_move() {
    let root = corpus_root();
    assert!(
        root.is_dir(),
        "the conformance corpus is missing: expected LinuxCNC's recorded outputs at {}",
        root.display()
    );
    let cases = cases(&root);
    assert_eq!(
        cases.len(),
        PROGRAMS,
        "corpus programs with a recording under {}",
        root.display()
    );
    let listed: BTreeMap<&str, &str> = NOT_MATCHED.iter().copied().collect();
    let mut matched = 0;
    let mut unexpected = Vec::new();
    let mut now_matching = Vec::new();
    let mut known = 0;
    for case in &cases {
        let rel = case
            .program
            .strip_prefix(&root)
            .unwrap_or(&case.program)
            .to_string_lossy()
            .to_string();
        let result =
            std::panic::catch_unwind(|| compare(case)).unwrap_or_else(|_| Err("PANIC".to_string()));
        match (result, listed.get(rel.as_str())) {
            (Ok(()), None) => matched += 1,
            (Ok(()), Some(_)) => now_matching.push(rel),
            (Err(_), Some(_)) => known += 1,
            (Err(e), None) => unexpected.push(format!("{rel}: {e}")),
        }
    }
    let summary = format!(
        "{matched} of {} corpus programs match LinuxCNC; {known} listed as not matched; \
         {} unexpected failures; {} listed but now matching",
        cases.len(),
        unexpected.len(),
        now_matching.len()
    );
    if !unexpected.is_empty() || !now_matching.is_empty() {
        panic!(
            "{summary}\nunexpected failures:\n  {}\nlisted but matching (remove from NOT_MATCHED):\n  {}",
            unexpected.join("\n  "),
            now_matching.join("\n  ")
        );
    }
    #[expect(
        clippy::print_stdout,
        reason = "the summary belongs in the test output"
    )]
    {
        println!("{summary}");
    }
}
