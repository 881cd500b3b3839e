//! Fuzz target: any bytes as a scene file (seeds: `scenes/*.toml`), read or refused with one
//! error naming the file, never a panic (`checks::scene`). `.ci/fuzz scene` (from the crate root).
#![no_main]

#[path = "../checks.rs"]
mod checks;

libfuzzer_sys::fuzz_target!(|data: &[u8]| checks::scene(data));
