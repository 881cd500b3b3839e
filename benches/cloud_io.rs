//! Benchmarks of point-cloud I/O: a binary little-endian PLY of 1,266,606 points (x y z
//! `double`, no normals, 30.4 MB), written to memory, read from memory, and written and read
//! through a file in the system temporary directory (a new file, and overwriting one).
//!
//! `cargo bench --bench cloud_io`; figures and the machine they came from are in README.md.

use criterion::{BatchSize, Criterion, Throughput, criterion_group, criterion_main};
use std::hint::black_box;
use std::path::PathBuf;
use twinmill::math::{CounterRng, Point3};
use twinmill::metrology::cloud::{
    Frame, PointCloud, read_ply, read_ply_file, write_ply, write_ply_file,
};

/// Points in the benchmark cloud (a dense scan of a milled part).
const POINTS: usize = 1_266_606;

/// A cloud of `POINTS` points from a fixed seed: x, y uniform over 200 × 150 mm, z normal
/// with σ = 40 mm.
fn cloud() -> PointCloud {
    let rng = CounterRng::new(20_240_607);
    let points = (0..POINTS as u64)
        .map(|i| {
            Point3::new(
                200.0 * rng.uniform(i, 2),
                150.0 * rng.uniform(i, 3),
                40.0 * rng.normal(i),
            )
        })
        .collect();
    PointCloud::new(Frame::Workpiece, points)
}

fn benches(c: &mut Criterion) {
    let cloud = cloud();
    let mut bytes = Vec::new();
    write_ply(&cloud, &mut bytes).expect("writes");
    let path: PathBuf =
        std::env::temp_dir().join(format!("twinmill-bench-cloud-{}.ply", std::process::id()));

    let mut g = c.benchmark_group("cloud_io binary PLY 1.27 M points");
    g.sample_size(30);
    g.throughput(Throughput::Elements(POINTS as u64));
    g.bench_function("write to Vec", |b| {
        b.iter_with_large_drop(|| {
            let mut out = Vec::new();
            write_ply(black_box(&cloud), &mut out).expect("writes");
            out
        })
    });
    g.bench_function("read from bytes", |b| {
        b.iter_with_large_drop(|| read_ply(black_box(&bytes), &path).expect("reads"))
    });
    // A fresh file each time (the setup, not timed, removes the previous one).
    let remove = || {
        let _ = std::fs::remove_file(&path);
    };
    g.bench_function("write_ply_file (new file)", |b| {
        b.iter_batched(
            remove,
            |()| write_ply_file(black_box(&cloud), &path).expect("writes file"),
            BatchSize::PerIteration,
        )
    });
    // Overwriting truncates the old file first: on ext4 that frees its blocks and, by the
    // replace-via-truncate heuristic (auto_da_alloc), starts write-back at close.
    g.bench_function("write_ply_file (overwrite)", |b| {
        b.iter(|| write_ply_file(black_box(&cloud), &path).expect("writes file"))
    });
    g.bench_function("read_ply_file", |b| {
        b.iter_with_large_drop(|| read_ply_file(black_box(&path)).expect("reads file"))
    });
    g.bench_function("write + read via temp file", |b| {
        b.iter_batched(
            remove,
            |()| {
                write_ply_file(black_box(&cloud), &path).expect("writes file");
                read_ply_file(&path).expect("reads file")
            },
            BatchSize::PerIteration,
        )
    });
    g.finish();
    let _ = std::fs::remove_file(&path);
}

// criterion_group! generates an undocumented public function: keep it in a private module.
mod group {
    use super::*;
    criterion_group!(cloud_io, benches);
}
criterion_main!(group::cloud_io);
