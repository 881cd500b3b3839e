//! Benchmark of NC correction: a deterministic 10,000-move XYZA program (straight moves at
//! fixed A, and every tenth move turning A by 15°) corrected for the nine deviations of
//! seed 002 Fig. 3 on the MDX-50 chain.
//!
//! `cargo bench --bench correct`; the figure and the machine it came from are in README.md.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use std::hint::black_box;
use std::path::{Path, PathBuf};
use twinmill::calibration::correct::{CorrectOptions, correct_program};
use twinmill::math::{CounterRng, Real};
use twinmill::nc::{AxisLetter, Move, MoveKind, Program};
use twinmill::scene::Scene;

const SCENE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/mdx50-step.toml");

/// 10,000 moves from a fixed seed.
fn program(scene: &Scene, n: usize) -> Program {
    let rng = CounterRng::new(7);
    let mut at = scene.home();
    let mut moves = Vec::with_capacity(n);
    for i in 0..n {
        let u = |k| rng.uniform(i as u64, k);
        let mut end = at;
        if i % 10 == 9 {
            end.set(AxisLetter::A, at.get(AxisLetter::A) + 15.0);
            end.set(AxisLetter::Y, at.get(AxisLetter::Y) + u(0) - 0.5);
        } else {
            end.set(AxisLetter::X, u(0) * 60.0 - 30.0);
            end.set(AxisLetter::Y, u(1) * 50.0 - 25.0);
            end.set(AxisLetter::Z, u(2) * 10.0);
        }
        moves.push(Move {
            kind: MoveKind::Linear,
            start: at,
            end,
            feed_mm_per_min: Some(600.0),
            line: i + 1,
        });
        at = end;
    }
    Program {
        path: PathBuf::from("generated.ngc"),
        moves,
        axes_used: vec![AxisLetter::X, AxisLetter::Y, AxisLetter::Z, AxisLetter::A],
        ended_by: None,
    }
}

fn benches(c: &mut Criterion) {
    let mut scene = Scene::load(Path::new(SCENE)).expect("scene");
    for (name, v) in [
        ("dy_AY", -0.5),
        ("dz_AY", 0.5),
        ("beta_AY", 5e-4),
        ("gamma_AY", -5e-4),
        ("alpha_YX", 5e-4),
        ("gamma_YX", 5e-4),
        ("beta_XZ", -5e-4),
        ("alpha_ZS", -5e-4),
        ("beta_ZS", 5e-4),
    ] {
        let m = scene.serial_mut().expect("a serial machine");
        let id = m.chain.deviation_id(name).expect("known");
        m.chain.set_deviation(id, v as Real);
    }
    let prog = program(&scene, 10_000);
    let opts = CorrectOptions::for_accuracy(1e-3);
    let mut g = c.benchmark_group("correct");
    g.sample_size(10);
    g.throughput(Throughput::Elements(prog.moves.len() as u64));
    g.bench_function("10,000 moves, nine deviations (moves)", |b| {
        b.iter(|| {
            correct_program(
                black_box(scene.chain()),
                &scene.tool,
                black_box(&prog),
                &scene.home(),
                &opts,
            )
            .expect("corrects")
        })
    });
    g.finish();
}

// criterion_group! generates an undocumented public function: keep it in a private module.
mod group {
    use super::*;
    criterion_group!(correct, benches);
}
criterion_main!(group::correct);
