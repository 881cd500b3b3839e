//! Fuzz target: any bytes as a point-cloud file: PLY, XYZ, PTS (seeds: `tests/data/*.ply`), read or refused with one
//! error naming the file, never a panic (`checks::cloud`). `.ci/fuzz cloud` (from the crate root).
#![no_main]

#[path = "../checks.rs"]
mod checks;

libfuzzer_sys::fuzz_target!(|data: &[u8]| checks::cloud(data));
