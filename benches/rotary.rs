//! Rotary-axis cutting benches (`cargo bench --bench rotary`):
//!
//! - **P3, indexed 3+1**: six faces of a hexagon side-milled on a Ø20 mm round bar at A = 0,
//!   60, …, 300° (flat Ø6 end mill, the scene's deviated MDX-50), faces per second (each
//!   face: the A turn in the air, plunge beside the bar, the cut along X, retract).
//! - **P4, simultaneous XA**: one turn of a helical groove 1 mm deep on a Ø16 mm bar, ball
//!   Ø4 mm, A and X together in 60 moves of 6°, every move cut by the per-ray envelope;
//!   moves per second, at tri-dexel pitches 0.2 and 0.1 mm.
//! - **Chain pose**: one `w_from_t` of the MDX-50 chain with its deviations, and of the
//!   same chain with error motions on X, Y and Z (a table, a polynomial and a periodic term
//!   each, and a reversal), poses per second.

use criterion::criterion_main;
use twinmill::{cutting, math, nc};

#[path = "support/rotary.rs"]
mod rotary;

mod group {
    use crate::rotary::{bar, helix, hexagon};
    use criterion::{BatchSize, Criterion, Throughput, criterion_group};
    use std::path::Path;
    use twinmill::cutting::sweep::{SweepOptions, sweep_program};
    use twinmill::cutting::tool::{Tool, ToolKind};
    use twinmill::nc::{AxisLetter, AxisValues};
    use twinmill::progress::NoProgress;
    use twinmill::scene::Scene;

    const SCENE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/mdx50-step.toml");

    fn benches(c: &mut Criterion) {
        let scene = Scene::load(Path::new(SCENE)).expect("scene");
        let opts = SweepOptions {
            rotary_step_bound_mm: 1e-4,
        };
        let mut g = c.benchmark_group("rotary");
        g.sample_size(10);

        let moves = hexagon(scene.tool.radius());
        g.throughput(Throughput::Elements(6));
        g.bench_function("P3 hexagon on a round bar, 0.1 mm (faces)", |b| {
            b.iter(|| {
                let mut stock = bar(10.0, -20.0, 40.0, 0.1);
                sweep_program(
                    &mut stock,
                    scene.chain(),
                    &scene.tool,
                    &moves,
                    &opts,
                    &NoProgress,
                )
                .expect("sweeps")
            })
        });

        let ball = Tool::try_new(ToolKind::Ball, 4.0, 12.0).expect("valid");
        let moves = helix();
        g.throughput(Throughput::Elements(moves.len() as u64));
        for pitch in [0.2, 0.1] {
            // The bar is built outside the timing: moves per second of cutting only.
            g.bench_function(format!("P4 helical groove, {pitch} mm (moves)"), |b| {
                b.iter_batched(
                    || bar(8.0, -10.0, 20.0, pitch),
                    |mut stock| {
                        sweep_program(&mut stock, scene.chain(), &ball, &moves, &opts, &NoProgress)
                            .expect("sweeps")
                    },
                    BatchSize::LargeInput,
                )
            });
        }
        g.finish();

        // The chain's pose with and without error motions.
        use twinmill::machine::error_motion::{AxisErrorMotions, Term};
        let mut g = c.benchmark_group("chain");
        g.throughput(Throughput::Elements(1));
        let q = AxisValues::default()
            .with(AxisLetter::X, 12.5)
            .with(AxisLetter::Y, -20.0)
            .with(AxisLetter::Z, 3.0)
            .with(AxisLetter::A, 30.0);
        let plain = scene.chain().clone();
        g.bench_function("w_from_t without error motions", |b| {
            b.iter(|| plain.w_from_t(std::hint::black_box(&q)))
        });
        let mut with = scene.chain().clone();
        for l in [AxisLetter::X, AxisLetter::Y, AxisLetter::Z] {
            let mut e = AxisErrorMotions::for_axis(l);
            e.functions[0].terms = vec![
                Term::table(vec![-50.0, 0.0, 50.0], vec![0.0, 2e-3, -1e-3]).expect("valid"),
                Term::polynomial(vec![0.0, 1e-5, 1e-7]).expect("valid"),
                Term::periodic(1e-3, 5.0, 0.0).expect("valid"),
            ];
            e.functions[4].terms = vec![Term::polynomial(vec![1e-5, 1e-7]).expect("valid")];
            e.reversal = -0.003;
            with.set_error_motions(l, e).expect("axis");
        }
        g.bench_function("w_from_t with error motions", |b| {
            b.iter(|| with.w_from_t(std::hint::black_box(&q)))
        });
        g.finish();
    }

    criterion_group!(rotary, benches);
}
criterion_main!(group::rotary);
