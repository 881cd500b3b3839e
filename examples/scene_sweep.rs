//! A scene's program swept into its stock once, for profiling and for measuring peak memory:
//! `cargo run --release --example scene_sweep -- SCENE [MOVES] [PITCH] [MESHES]` (a chain
//! scene, or a hexapod scene that cuts).
//!
//! `MOVES` keeps the program's first moves only (all by default), `PITCH` replaces the
//! scene's `pitch_mm`. Prints the sweep's wall time, moves per second, the crossings'
//! digest (as `dexel_digest` computes it) and the bytes the tri-dexel holds; with `MESHES`,
//! the cut part's adaptive mesh (what `simulate` writes) is then made that many times and
//! each wall time printed.

#![allow(clippy::print_stdout, reason = "an example reports on the terminal")]

use std::io::Write;
use std::path::Path;
use std::time::Instant;
use twinmill::cutting::sweep::sweep_program;
use twinmill::progress::NoProgress;
use twinmill::scene::{MemoryBudget, Scene, SceneError};

#[path = "support/crossing_digest.rs"]
mod crossing_digest;
use crossing_digest::digest;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let Some(path) = args.get(1) else {
        say(format_args!(
            "usage: scene_sweep SCENE [MOVES] [PITCH] [MESHES]"
        ));
        return;
    };
    let mut scene = match Scene::load(Path::new(path)) {
        Err(SceneError::Hexapod { .. }) => {
            Scene::load_hexapod_cut(Path::new(path), &MemoryBudget::installed())
        }
        other => other,
    }
    .expect("scene loads");
    if let Some(p) = args.get(3).and_then(|s| s.parse().ok()) {
        scene.pitch_mm = p;
    }
    let program = scene.load_program().expect("program");
    let n = args
        .get(2)
        .and_then(|s| s.parse().ok())
        .unwrap_or(program.moves.len())
        .min(program.moves.len());
    let moves = &program.moves[..n];
    let mut stock = twinmill::pipeline::make_stock(&scene).expect("stock");
    let t = Instant::now();
    let rep = sweep_program(
        &mut stock,
        scene.kinematics(),
        &scene.tool,
        moves,
        &scene.sweep,
        &NoProgress,
    )
    .expect("sweeps");
    let dt = t.elapsed().as_secs_f64();
    let (h, count) = digest(&stock);
    say(format_args!(
        "{}: {n} moves at {} mm in {dt:.3} s, {:.0} moves/s, {} cutting, {} sweeps",
        scene.name,
        scene.pitch_mm,
        n as f64 / dt,
        rep.cutting_moves,
        rep.sweeps
    ));
    say(format_args!(
        "digest {h:016x}, {count} crossings, stock {:.1} MiB",
        stock.memory_bytes() as f64 / 1048576.0
    ));
    let meshes: usize = args.get(4).and_then(|s| s.parse().ok()).unwrap_or(0);
    for _ in 0..meshes {
        let t = Instant::now();
        let (mesh, _) =
            twinmill::cutting::adaptive::mesh_stock_adaptive(&stock, &Default::default())
                .expect("meshes");
        say(format_args!(
            "mesh {:.3} s, {} triangles",
            t.elapsed().as_secs_f64(),
            mesh.triangles.len()
        ));
    }
}

/// Prints a line; a closed pipe (`scene_sweep … | head`) ends the program quietly.
fn say(line: std::fmt::Arguments) {
    if writeln!(std::io::stdout().lock(), "{line}").is_err() {
        std::process::exit(0);
    }
}
