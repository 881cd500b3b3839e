//! Benchmarks of the main job on the built-in scene, whole and per stage.
//!
//! `cargo bench --bench pipeline`; figures and the machine they came from are in README.md.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use std::hint::black_box;
use std::path::Path;
use twinmill::cutting::stock::TriDexel;
use twinmill::cutting::sweep::sweep_program;
use twinmill::metrology::scan::scan;
use twinmill::pipeline::run;
use twinmill::progress::NoProgress;
use twinmill::scene::Scene;

const SCENE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/mdx50-step.toml");

fn benches(c: &mut Criterion) {
    let scene = Scene::load(Path::new(SCENE)).expect("scene");
    let program = scene.load_program().expect("program");

    let mut g = c.benchmark_group("mdx50-step");
    g.sample_size(20);
    g.bench_function("run (whole pipeline, default resolution)", |b| {
        b.iter(|| run(black_box(&scene), black_box(&program), &NoProgress).expect("runs"))
    });

    // The sweep as it runs in the pipeline: a fresh stock cut by the whole program.
    let swept = || {
        let mut stock = TriDexel::new_box(scene.stock_box, scene.pitch_mm, 8e9).expect("fits");
        let (chain, tool) = (scene.chain(), &scene.tool);
        sweep_program(
            &mut stock,
            chain,
            tool,
            &program.moves,
            &scene.sweep,
            &NoProgress,
        )
        .expect("sweeps");
        stock
    };
    g.throughput(Throughput::Elements(program.moves.len() as u64));
    g.bench_function("stock + sweep (moves)", |b| b.iter(swept));

    let stock = swept();
    let scanner = scene
        .scanner
        .as_ref()
        .expect("the built-in scene has a [scanner]");
    let rays = (scanner.fov_mm.0 / scanner.pitch_mm).round()
        * (scanner.fov_mm.1 / scanner.pitch_mm).round();
    g.throughput(Throughput::Elements(rays as u64));
    g.bench_function("scan (camera rays)", |b| {
        b.iter(|| scan(black_box(&stock), scanner, &NoProgress).expect("scans"))
    });
    g.finish();
}

// criterion_group! generates an undocumented public function: keep it in a private module.
mod group {
    use super::*;
    criterion_group!(pipeline, benches);
}
criterion_main!(group::pipeline);
