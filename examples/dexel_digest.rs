//! A digest of every dexel crossing (coordinate, normal and NC line, bit for bit) after the
//! sweep of benchmarks P1-flat, P1-ball (0.05 mm), P3 and P4 (docs/benchmarks.md), the rotary
//! move of the brute-force test, the programs of the scenes in `scenes/` (the hexapod
//! scenes that cut among them) and the simultaneous 5-axis benchmarks' trunnion blade and
//! hexapod side cut (`benches/data`): changes to the
//! sweep engine that must not change its results are checked by comparing the digests
//! before and after.
//!
//! ```text
//! cargo run --release --example dexel_digest [FILTER] [--check | --record]
//! ```
//!
//! Prints one line per case: the FNV-1a 64 digest, the number of crossings and the time.
//! The digests of the sweep as it stands are recorded in `examples/dexel_digest.txt`
//! (digest, crossings, case): `--check` compares every case run with that file and exits 1
//! naming each case whose digest or count differs or that the file lacks (CI runs it);
//! `--record` writes the file anew from the cases run (all of them: no FILTER), for a change
//! that is meant to change the crossings — say so, and why, in its commit.
//!
//! ```text
//! cargo run --release --example dexel_digest [FILTER] --save DIR
//! cargo run --release --example dexel_digest [FILTER] --against DIR
//! ```
//!
//! For a change meant to move the crossings within a bound (the envelope's, say): `--save`
//! keeps each case's stock in `DIR` (one `.dexel` file a case), and a later build's
//! `--against` compares its stocks with those, ray by ray: the rays whose segment counts
//! differ, and over the rest the largest distance between corresponding crossings and
//! the largest angle between their normals. `--scene FILE` (repeatable) adds the program
//! of another scene file as a case (not recorded).

#![allow(
    clippy::print_stdout,
    clippy::print_stderr,
    reason = "an example reports on the terminal"
)]

use std::path::Path;
use std::time::Instant;
use twinmill::cutting::stock::TriDexel;
use twinmill::cutting::sweep::{SweepOptions, sweep_program};
use twinmill::cutting::tool::{Tool, ToolKind};
use twinmill::machine::chain::Chain;
use twinmill::math::{Aabb, Point3, Real};
use twinmill::nc::{AxisLetter, AxisValues, Move, MoveKind};
use twinmill::progress::NoProgress;
use twinmill::scene::Scene;
use twinmill::{cutting, math, nc};

#[path = "support/crossing_digest.rs"]
mod crossing_digest;
use crossing_digest::digest;
#[path = "../benches/support/p1.rs"]
mod p1;
#[path = "../benches/support/rotary.rs"]
mod rotary;
use rotary::{bar, helix, hexagon};

fn xyz_chain() -> Chain {
    Chain::cartesian([AxisLetter::Y, AxisLetter::X, AxisLetter::Z]).expect("valid chain")
}

/// The recorded digests: `examples/dexel_digest.txt`.
const RECORDED: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/examples/dexel_digest.txt");

/// The recorded file's cases: name → (digest, crossings).
fn recorded() -> std::collections::BTreeMap<String, (String, usize)> {
    let text = std::fs::read_to_string(RECORDED)
        .unwrap_or_else(|e| panic!("{RECORDED}: {e} (write it with --record)"));
    text.lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty() && !l.starts_with('#'))
        .map(|(i, l)| {
            let bad = || panic!("{RECORDED}:{}: expected `digest  crossings  case`", i + 1);
            let mut w = l.split_whitespace();
            let (Some(h), Some(n)) = (w.next(), w.next()) else {
                bad()
            };
            let n: usize = n.parse().unwrap_or_else(|_| bad());
            let name = w.collect::<Vec<_>>().join(" ");
            if name.is_empty() {
                bad();
            }
            (name, (h.to_string(), n))
        })
        .collect()
}

/// How `after` differs from `before` (the same grids): rays whose segment counts differ,
/// and over the others the largest distance (mm) between corresponding crossings and the
/// largest angle (rad) between their normals, and how many turned by more than 1 mrad (an
/// interval end at an edge of the tool may take either face's normal).
fn compare(before: &TriDexel, after: &TriDexel) -> String {
    let (mut rays, mut counts, mut crossings, mut faces) = (0usize, 0usize, 0usize, 0usize);
    let (mut moved, mut turned): (Real, Real) = (0.0, 0.0);
    for (g0, g1) in before.grids().iter().zip(after.grids()) {
        assert_eq!(g0.dims(), g1.dims(), "the saved stock has other grids");
        let (nu, nv) = g0.dims();
        for iv in 0..nv {
            for iu in 0..nu {
                let (a, b) = (g0.ray(iu, iv), g1.ray(iu, iv));
                rays += 1;
                if a.len() != b.len() {
                    counts += 1;
                    continue;
                }
                for (x, y) in a
                    .iter()
                    .zip(b)
                    .flat_map(|(x, y)| [(&x.lo, &y.lo), (&x.hi, &y.hi)])
                {
                    crossings += 1;
                    moved = Real::max(moved, (x.t - y.t).abs());
                    let angle = x
                        .normal()
                        .cross(&y.normal())
                        .norm()
                        .atan2(x.normal().dot(&y.normal()));
                    turned = Real::max(turned, angle);
                    if angle > 1e-3 {
                        faces += 1;
                    }
                }
            }
        }
    }
    format!(
        "against the saved stock: {counts} of {rays} rays with other segment counts; over \
         {crossings} crossings the largest move {moved:.3e} mm, the largest normal turn \
         {turned:.3e} rad ({faces} turned by more than 1 mrad)"
    )
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let check = args.iter().any(|a| a == "--check");
    let record = args.iter().any(|a| a == "--record");
    let value_of = |flag: &str| {
        args.iter()
            .position(|a| a == flag)
            .map(|i| match args.get(i + 1) {
                Some(v) if !v.starts_with("--") => std::path::PathBuf::from(v),
                _ => panic!("{flag} needs a folder"),
            })
    };
    let (save, against) = (value_of("--save"), value_of("--against"));
    let takes_value =
        |i: usize| i > 0 && ["--save", "--against", "--scene"].contains(&args[i - 1].as_str());
    let filter = args
        .iter()
        .enumerate()
        .find(|(i, a)| !a.starts_with("--") && !takes_value(*i))
        .map(|(_, a)| a.clone())
        .unwrap_or_default();
    assert!(
        !(record && (check || !filter.is_empty())),
        "--record writes every case: no FILTER, no --check"
    );
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes");
    let mdx = Scene::load(&Path::new(dir).join("mdx50-step.toml")).expect("scene");
    let opts = SweepOptions {
        rotary_step_bound_mm: math::tol::ROTARY_STEP_BOUND,
    };
    let bench_opts = SweepOptions {
        rotary_step_bound_mm: 1e-4,
    };
    type Case = Box<dyn Fn() -> TriDexel>;
    let mut cases: Vec<(String, Case)> = Vec::new();
    for (name, kind) in [("flat", ToolKind::Flat), ("ball", ToolKind::Ball)] {
        cases.push((
            format!("P1-{name} 0.05 mm"),
            Box::new(move || {
                let tool = Tool::try_new(kind, p1::TOOL_DIAMETER, 30.0).expect("valid");
                let mut s = TriDexel::new_box(p1::stock_box(), 0.05, 8e9).expect("fits");
                sweep_program(
                    &mut s,
                    &xyz_chain(),
                    &tool,
                    &p1::moves(),
                    &opts,
                    &NoProgress,
                )
                .expect("sweeps");
                s
            }),
        ));
    }
    for pitch in [0.2, 0.1] {
        let chain = mdx.chain().clone();
        cases.push((
            format!("P4 helical groove {pitch} mm"),
            Box::new(move || {
                let ball = Tool::try_new(ToolKind::Ball, 4.0, 12.0).expect("valid");
                let mut s = bar(8.0, -10.0, 20.0, pitch);
                sweep_program(&mut s, &chain, &ball, &helix(), &bench_opts, &NoProgress)
                    .expect("sweeps");
                s
            }),
        ));
    }
    {
        let (chain, tool) = (mdx.chain().clone(), mdx.tool.clone());
        cases.push((
            "P3 hexagon 0.1 mm".into(),
            Box::new(move || {
                let mut s = bar(10.0, -20.0, 40.0, 0.1);
                let moves = hexagon(tool.radius());
                sweep_program(&mut s, &chain, &tool, &moves, &bench_opts, &NoProgress)
                    .expect("sweeps");
                s
            }),
        ));
    }
    {
        // tests/twinmill/rotary.rs: rotary_move_surface_agrees_with_brute_force.
        let chain = mdx.chain().nominal();
        cases.push((
            "rotary move A 0-90 0.4 mm".into(),
            Box::new(move || {
                let tool = Tool::try_new(ToolKind::Flat, 6.0, 10.0).expect("valid");
                let start = AxisValues::default().with(AxisLetter::Z, 6.0);
                let mv = Move {
                    kind: MoveKind::Linear,
                    start,
                    end: start.with(AxisLetter::A, 90.0),
                    feed_mm_per_min: Some(100.0),
                    line: 3,
                };
                let bounds = Aabb {
                    min: Point3::new(-8.03, -10.0, -10.0),
                    max: Point3::new(7.97, 10.0, 10.0),
                };
                let mut s = TriDexel::new_box(bounds, 0.4, 4e9).expect("fits");
                let o = SweepOptions {
                    rotary_step_bound_mm: 5e-4,
                };
                sweep_program(&mut s, &chain, &tool, &[mv], &o, &NoProgress).expect("sweeps");
                s
            }),
        ));
    }
    let mut names: Vec<_> = std::fs::read_dir(dir)
        .expect("scenes")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        // Of the hexapod scenes, those that cut (the others hold only a machine).
        .filter(|p| {
            !p.to_string_lossy().contains("hexapod")
                || std::fs::read_to_string(p).is_ok_and(|t| t.contains("\nprogram"))
        })
        .collect();
    names.sort();
    let mut labelled: Vec<(String, std::path::PathBuf)> = names
        .into_iter()
        .map(|p| ("scene", p))
        .chain(
            // Simultaneous 5-axis benchmark programs (docs/benchmarks.md): the trunnion's
            // blade-like finishing path and the hexapod's side cut.
            ["trunnion-blade.toml", "hexapod-side-cut.toml"]
                .map(|f| ("bench", Path::new(dir).join("../benches/data").join(f))),
        )
        .map(|(kind, p)| {
            let file = p
                .file_name()
                .unwrap_or_default()
                .to_string_lossy()
                .into_owned();
            (format!("{kind} {file}"), p)
        })
        .collect();
    labelled.sort_by(|a, b| a.0.cmp(&b.0));
    for (i, a) in args.iter().enumerate() {
        if a == "--scene" {
            let p = std::path::PathBuf::from(args.get(i + 1).expect("--scene needs a file"));
            labelled.push((format!("file {}", p.display()), p));
        }
    }
    for (label, path) in labelled {
        cases.push((
            label,
            Box::new(move || {
                let scene = match Scene::load(&path) {
                    Err(twinmill::scene::SceneError::Hexapod { .. }) => {
                        Scene::load_hexapod_cut(&path, &twinmill::scene::MemoryBudget::installed())
                    }
                    other => other,
                }
                .expect("scene");
                let program = scene.load_program().expect("program");
                twinmill::pipeline::machine_part(&scene, &program, &NoProgress)
                    .expect("sweeps")
                    .stock
            }),
        ));
    }
    let expected = if check {
        recorded()
    } else {
        Default::default()
    };
    let (mut lines, mut wrong) = (Vec::new(), Vec::new());
    for (name, run) in cases.iter().filter(|(n, _)| n.contains(&filter)) {
        let t = Instant::now();
        let s = run();
        let dt = t.elapsed().as_secs_f64();
        let (h, n) = digest(&s);
        let h = format!("{h:016x}");
        let verdict = match expected.get(name) {
            _ if !check => "",
            Some((eh, en)) if *eh == h && *en == n => "  as recorded",
            Some((eh, en)) => {
                wrong.push(format!("{name}: {h} ({n}), recorded {eh} ({en})"));
                "  DIFFERS"
            }
            None => {
                wrong.push(format!("{name}: not in {RECORDED}"));
                "  NOT RECORDED"
            }
        };
        println!("{h}  {n:>9} crossings  {dt:7.3} s  {name}{verdict}");
        let file = |dir: &Path| dir.join(format!("{}.dexel", name.replace([' ', '/'], "_")));
        if let Some(dir) = &save {
            std::fs::create_dir_all(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
            std::fs::write(file(dir), s.to_bytes())
                .unwrap_or_else(|e| panic!("{}: {e}", file(dir).display()));
        }
        if let Some(dir) = &against {
            let f = file(dir);
            let bytes = std::fs::read(&f).unwrap_or_else(|e| panic!("{}: {e}", f.display()));
            let before = TriDexel::from_bytes(&bytes)
                .unwrap_or_else(|| panic!("{}: not a saved stock", f.display()));
            println!("{:>44}{}", "", compare(&before, &s));
        }
        lines.push(format!("{h}  {n:>9}  {name}"));
    }
    if check && filter.is_empty() {
        for name in expected.keys() {
            if !cases.iter().any(|(n, _)| n == name) {
                wrong.push(format!("{name}: recorded, but no such case"));
            }
        }
    }
    if record {
        let head = "# FNV-1a 64 digests of every dexel crossing (coordinates, normal, NC line, bit for\n\
                    # bit) after each case of examples/dexel_digest.rs: digest, crossings, case.\n\
                    # Checked by `cargo run --release --example dexel_digest -- --check` (.ci/run);\n\
                    # written by `-- --record`.\n";
        std::fs::write(RECORDED, format!("{head}{}\n", lines.join("\n")))
            .unwrap_or_else(|e| panic!("{RECORDED}: {e}"));
        println!("recorded {} cases in {RECORDED}", lines.len());
    }
    if !wrong.is_empty() {
        eprintln!(
            "dexel_digest: {} case(s) differ from {RECORDED}:",
            wrong.len()
        );
        for w in &wrong {
            eprintln!("  {w}");
        }
        std::process::exit(1);
    }
}
