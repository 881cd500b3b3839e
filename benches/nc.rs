//! Benchmark of the NC interpreter on the 200,000-block synthetic program
//! (`nc::synthetic::bench_program`: G1 with A words, every fifth block a G3 with I/J,
//! about 6.3 MB; `twinmill nc bench-program > bench.ngc` writes the same file for a run of
//! LinuxCNC's `rs274`).
//!
//! `cargo bench --bench nc`. Two cases: streaming from a file (constant memory) and from
//! text in memory; each interprets the whole program and consumes every record.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use std::hint::black_box;
use std::path::Path;
use twinmill::nc::{InterpOptions, Interpreter, RecordBody};

/// Motion blocks in the program.
const BLOCKS: usize = 200_000;

fn count(mut interp: Interpreter) -> usize {
    let mut n = 0;
    while let Some(rec) = interp.next_ref() {
        if let Ok(r) = rec
            && matches!(r.body, RecordBody::Motion(_))
        {
            n += 1;
        }
    }
    n
}

fn bench(c: &mut Criterion) {
    let mut text = String::new();
    twinmill::nc::synthetic::bench_program(BLOCKS, &mut text);
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR"));
    let path = dir.join("nc-bench-200k.ngc");
    std::fs::write(&path, &text).expect("bench program written");
    let mut g = c.benchmark_group("nc");
    g.sample_size(10);
    g.throughput(Throughput::Elements(BLOCKS as u64));
    g.bench_function("interpret_200k_blocks_streaming_file", |b| {
        b.iter(|| {
            let it = Interpreter::from_file(&path, InterpOptions::default()).expect("opens");
            black_box(count(it))
        })
    });
    g.bench_function("interpret_200k_blocks_in_memory", |b| {
        b.iter(|| {
            let it =
                Interpreter::from_text(&text, Path::new("bench.ngc"), InterpOptions::default());
            black_box(count(it))
        })
    });
    g.finish();
}

mod group {
    use super::*;
    criterion_group!(nc, bench);
}
criterion_main!(group::nc);
