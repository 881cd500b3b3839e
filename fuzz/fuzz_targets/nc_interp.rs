//! Fuzz target: any bytes as an NC program through the interpreter, read or refused with one
//! error naming the file, never a panic (`checks::nc_interp`). `.ci/fuzz nc_interp` (from the crate root).
#![no_main]

#[path = "../checks.rs"]
mod checks;

libfuzzer_sys::fuzz_target!(|data: &[u8]| checks::nc_interp(data));
