//! Benchmark P1 (docs/benchmarks.md) on the Z-map fast path, and on the tri-dexel sweep for
//! comparison: throughput in moves/s.
//!
//! `cargo bench --bench zmap`; goals: Z-map ≥ 15,000 moves/s at 0.05 mm (FreeCAD 0.20:
//! 14.2 k), tri-dexel sweep ≥ 2,000 moves/s on P1-flat (`cargo bench --bench zmap --
//! tri-dexel`).

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use std::hint::black_box;
use twinmill::cutting::stock::TriDexel;
use twinmill::cutting::sweep::{SweepOptions, sweep_program};
use twinmill::cutting::tool::{Tool, ToolKind};
use twinmill::cutting::zmap::{ZMap, ZMapOptions};
use twinmill::machine::chain::Chain;
use twinmill::nc::AxisLetter;
use twinmill::progress::NoProgress;
use twinmill::{math, nc};

#[path = "support/p1.rs"]
mod p1;

/// The nominal 3-axis machine (Y table, X carriage, Z spindle).
pub fn xyz_chain() -> Chain {
    Chain::cartesian([AxisLetter::Y, AxisLetter::X, AxisLetter::Z]).expect("valid chain")
}

fn benches(c: &mut Criterion) {
    let moves = p1::moves();
    let chain = xyz_chain();
    let mut g = c.benchmark_group("p1");
    g.sample_size(10);
    g.throughput(Throughput::Elements(moves.len() as u64));
    for (name, kind) in [("flat", ToolKind::Flat), ("ball", ToolKind::Ball)] {
        let tool = Tool::try_new(kind, p1::TOOL_DIAMETER, 30.0).expect("valid");
        for (mode, merge_collinear) in [("runs joined", true), ("move by move", false)] {
            let opts = ZMapOptions {
                merge_collinear,
                ..ZMapOptions::default()
            };
            g.bench_function(format!("zmap 0.05 mm {name}, {mode} (moves)"), |b| {
                b.iter(|| {
                    let mut z = ZMap::new_box(p1::stock_box(), 0.05, 1e9).expect("fits");
                    z.sweep_program(&chain, &tool, black_box(&moves), &opts)
                        .expect("3-axis");
                    z
                })
            });
        }
    }
    let opts = SweepOptions {
        rotary_step_bound_mm: math::tol::ROTARY_STEP_BOUND,
    };
    for (name, kind) in [("flat", ToolKind::Flat), ("ball", ToolKind::Ball)] {
        let tool = Tool::try_new(kind, p1::TOOL_DIAMETER, 30.0).expect("valid");
        g.bench_function(format!("tri-dexel 0.05 mm {name} (moves)"), |b| {
            b.iter(|| {
                let mut s = TriDexel::new_box(p1::stock_box(), 0.05, 8e9).expect("fits");
                sweep_program(&mut s, &chain, &tool, black_box(&moves), &opts, &NoProgress)
                    .expect("sweeps");
                s
            })
        });
    }
    g.finish();
}

// criterion_group! generates an undocumented public function: keep it in a private module.
mod group {
    use super::*;
    criterion_group!(zmap, benches);
}
criterion_main!(group::zmap);
