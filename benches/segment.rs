//! Benchmark of `segment::segment_planes` on a 1,266,606-point step-experiment cloud.
//!
//! `cargo bench --bench segment`. The cloud: the step experiment's two faces 1 mm apart
//! plus the top face at 90°, scanned at the scanner's 0.185 mm spacing with σ = 0.025 mm
//! Gaussian noise along the viewing ray (camera at (0, −330, 80) looking at the origin, as
//! in `scenes/mdx50-step.toml`). The faces are larger than the experiment's 40 × 10 mm so
//! that the cloud has the size of a full scan: one raster 1,100 points (203.5 mm) wide in
//! x, whose rows run
//!
//! * rows 0–383: face B, plane y = 1, z from −71.04 to 0 (the lower face, 1 mm back);
//! * rows 384–767: face A, plane y = 0, z from 0 to 71.04 (the upper face);
//! * rows 768–1151: the top face, plane z = 71.04, y from 0 to 71.0 (the last row holds
//!   506 points),
//!
//! 1,266,606 points in all, in raster (acquisition) order.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use std::hint::black_box;
use twinmill::math::{CounterRng, Point3, Real, Vector3};
use twinmill::metrology::segment::{PlaneSegmentOptions, segment_planes};

/// Points in the cloud.
const N: usize = 1_266_606;
/// Points per raster row.
const ROW: usize = 1_100;
/// Rows per face.
const FACE_ROWS: usize = 384;
/// Point spacing (mm).
const PITCH: Real = 0.185;
/// Range noise (mm).
const SIGMA: Real = 0.025;

fn step_cloud() -> Vec<Point3> {
    let rng = CounterRng::new(2002);
    let view = Vector3::new(0.0, 308.0, -80.0).normalize();
    let height = FACE_ROWS as Real * PITCH;
    (0..N)
        .map(|i| {
            let (row, col) = (i / ROW, i % ROW);
            let x = (col as Real + 0.5) * PITCH;
            let t = ((row % FACE_ROWS) as Real + 0.5) * PITCH;
            let p = match row / FACE_ROWS {
                0 => Point3::new(x, 1.0, t - height),
                1 => Point3::new(x, 0.0, t),
                _ => Point3::new(x, t, height),
            };
            p + view * (SIGMA * rng.normal(i as u64))
        })
        .collect()
}

fn benches(c: &mut Criterion) {
    let cloud = step_cloud();
    let opts = PlaneSegmentOptions::default();
    let segments = segment_planes(&cloud, &opts).expect("segments");
    assert_eq!(segments.len(), 3, "three faces");

    let mut g = c.benchmark_group("segment");
    g.sample_size(20);
    g.throughput(Throughput::Elements(N as u64));
    g.bench_function(
        "segment_planes (1.27 M points, 3 faces + robust fits)",
        |b| b.iter(|| segment_planes(black_box(&cloud), &opts).expect("segments")),
    );
    g.finish();
}

// criterion_group! generates an undocumented public function: keep it in a private module.
mod group {
    use super::*;
    criterion_group!(segment, benches);
}
criterion_main!(group::segment);
