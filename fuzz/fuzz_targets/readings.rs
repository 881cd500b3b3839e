//! Fuzz target: any text as a readings file: ISO 230-2 readings, a ball-bar trace, ball-sensor readings, a DBB plan, read or refused with one
//! error naming the file, never a panic (`checks::readings`). `.ci/fuzz readings` (from the crate root).
#![no_main]

#[path = "../checks.rs"]
mod checks;

libfuzzer_sys::fuzz_target!(|data: &[u8]| checks::readings(data));
