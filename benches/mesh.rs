//! Meshing the P1 pocket stock (docs/benchmarks.md: 100 × 100 × 20 box, Ø6 flat pocket
//! 1.5 mm deep): the adaptive part mesh at 0.05 mm (what `twinmill simulate` writes) and
//! the dexel-resolution contour at 0.1 mm, throughput in triangles/s; and that contour
//! simplified for display (`report::display::simplify`, in pieces above 200 k triangles),
//! throughput in source triangles/s.
//!
//! `cargo bench --bench mesh`.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use std::hint::black_box;
use twinmill::cutting::adaptive::{AdaptiveOptions, mesh_stock_adaptive};
use twinmill::cutting::mesh::mesh_stock;
use twinmill::cutting::stock::TriDexel;
use twinmill::cutting::sweep::{SweepOptions, sweep_program};
use twinmill::cutting::tool::{Tool, ToolKind};
use twinmill::machine::chain::Chain;
use twinmill::nc::AxisLetter;
use twinmill::progress::NoProgress;
use twinmill::report::display::{MAX_TRIANGLES, simplify};
use twinmill::{math, nc};

#[path = "support/p1.rs"]
mod p1;

fn p1_stock(pitch: f64) -> TriDexel {
    let chain =
        Chain::cartesian([AxisLetter::Y, AxisLetter::X, AxisLetter::Z]).expect("valid chain");
    let tool = Tool::try_new(ToolKind::Flat, p1::TOOL_DIAMETER, 30.0).expect("valid");
    let mut s = TriDexel::new_box(p1::stock_box(), pitch, 8e9).expect("fits");
    let opts = SweepOptions {
        rotary_step_bound_mm: math::tol::ROTARY_STEP_BOUND,
    };
    sweep_program(&mut s, &chain, &tool, &p1::moves(), &opts, &NoProgress).expect("sweeps");
    s
}

#[expect(
    clippy::print_stdout,
    reason = "a bench reports the mesh size it measured"
)]
fn benches(c: &mut Criterion) {
    let stock = p1_stock(0.1);
    let (mesh, report) = mesh_stock(&stock).expect("meshes");
    println!(
        "P1 flat at 0.1 mm: {} triangles, {} vertices, {report:?}; mesh volume {:.3} mm³, tri-dexel {:.3} mm³",
        mesh.triangles.len(),
        mesh.vertices.len(),
        mesh.signed_volume(),
        stock.volume()
    );
    let fine = p1_stock(0.05);
    let opts = AdaptiveOptions::default();
    let (adaptive, areport) = mesh_stock_adaptive(&fine, &opts).expect("meshes");
    println!(
        "P1 flat at 0.05 mm, adaptive: {} triangles, {} vertices, Euler {}, volume {:.3} mm³; {areport:?}",
        adaptive.triangles.len(),
        adaptive.vertices.len(),
        adaptive.euler_characteristic(),
        adaptive.signed_volume(),
    );
    let mut g = c.benchmark_group("mesh");
    g.sample_size(10);
    g.throughput(Throughput::Elements(adaptive.triangles.len() as u64));
    g.bench_function("P1 flat 0.05 mm adaptive (triangles)", |b| {
        b.iter(|| mesh_stock_adaptive(black_box(&fine), &opts))
    });
    g.throughput(Throughput::Elements(mesh.triangles.len() as u64));
    g.bench_function("P1 flat 0.1 mm (triangles)", |b| {
        b.iter(|| mesh_stock(black_box(&stock)))
    });
    let shown = simplify(&mesh, MAX_TRIANGLES);
    println!(
        "P1 flat at 0.1 mm for display: {} of {} triangles, error {:.4} mm",
        shown.triangles.len(),
        mesh.triangles.len(),
        shown.error_mm
    );
    g.bench_function("P1 flat 0.1 mm display mesh (source triangles)", |b| {
        b.iter(|| simplify(black_box(&mesh), MAX_TRIANGLES))
    });
    g.finish();
}

// criterion_group! generates an undocumented public function: keep it in a private module.
mod group {
    use super::*;
    criterion_group!(mesh, benches);
}
criterion_main!(group::mesh);
