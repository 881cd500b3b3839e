//! Benchmark P1 (docs/benchmarks.md) on the tri-dexel sweep, once, for profiling and for
//! measuring peak memory: `cargo run --release --example p1_sweep -- flat|ball [pitch]`.
//!
//! Prints the wall time, moves/s, removed volume and the bytes the tri-dexel holds; with
//! `mesh` as a third argument also meshes the part adaptively and prints its size, time,
//! Euler characteristic and enclosed volume against the tri-dexel's.

#![allow(clippy::print_stdout, reason = "an example reports on the terminal")]

use std::time::Instant;
use twinmill::cutting::adaptive::{AdaptiveOptions, mesh_stock_adaptive};
use twinmill::cutting::stock::TriDexel;
use twinmill::cutting::sweep::{SweepOptions, sweep_program};
use twinmill::cutting::tool::{Tool, ToolKind};
use twinmill::machine::chain::Chain;
use twinmill::nc::AxisLetter;
use twinmill::progress::NoProgress;
use twinmill::{math, nc};

#[path = "../benches/support/p1.rs"]
mod p1;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let kind = match args.get(1).map(String::as_str) {
        Some("ball") => ToolKind::Ball,
        _ => ToolKind::Flat,
    };
    let pitch: f64 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(0.05);
    let chain =
        Chain::cartesian([AxisLetter::Y, AxisLetter::X, AxisLetter::Z]).expect("valid chain");
    let tool = Tool::try_new(kind, p1::TOOL_DIAMETER, 30.0).expect("valid");
    let moves = p1::moves();
    let opts = SweepOptions {
        rotary_step_bound_mm: math::tol::ROTARY_STEP_BOUND,
    };
    let t0 = Instant::now();
    let mut s = TriDexel::new_box(p1::stock_box(), pitch, 8e9).expect("fits");
    let t1 = Instant::now();
    let rep = sweep_program(&mut s, &chain, &tool, &moves, &opts, &NoProgress).expect("sweeps");
    let dt = t1.elapsed().as_secs_f64();
    println!(
        "{kind:?} pitch {pitch}: build {:.3} s, sweep {dt:.3} s, {:.0} moves/s, {} cutting moves",
        (t1 - t0).as_secs_f64(),
        moves.len() as f64 / dt,
        rep.cutting_moves
    );
    let removed = 100.0 * 100.0 * 20.0 - s.volume();
    println!(
        "removed {removed:.4} mm³ (flat truth {:.4}), memory {:.1} MB",
        1.5 * p1::offset_area(3.0),
        s.memory_bytes() as f64 / 1e6
    );
    if args.get(3).map(String::as_str) == Some("mesh") {
        let t = Instant::now();
        let (m, r) = mesh_stock_adaptive(&s, &AdaptiveOptions::default()).expect("meshes");
        let dt = t.elapsed().as_secs_f64();
        let closed = m.check_watertight().is_ok();
        println!(
            "adaptive mesh {dt:.3} s: {} triangles, {} vertices, closed {closed}, Euler {}, \
             volume {:.4} mm³ (tri-dexel {:.4}); {r:?}",
            m.triangles.len(),
            m.vertices.len(),
            m.euler_characteristic(),
            m.signed_volume(),
            s.volume()
        );
    }
}
