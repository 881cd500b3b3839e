//! Fuzz target: any bytes as a study's file — a study file (TOML), a manifest (JSON), a
//! shard (Parquet) — read or refused with one error naming the file, never a panic (the
//! Parquet and Arrow readers' own panics are contained by `study::read_shard`;
//! `checks::study`). `.ci/fuzz study` (from the crate root).
#![no_main]

#[path = "../checks.rs"]
mod checks;

libfuzzer_sys::fuzz_target!(|data: &[u8]| checks::study(checks::study_setup(), data));
