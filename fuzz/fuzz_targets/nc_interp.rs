//! Fuzz target: any bytes as an NC program through the interpreter must not panic.
//! `cargo +nightly fuzz run nc_interp` (from the crate root).
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use twinmill::nc::{InterpOptions, Interpreter, ToolTable};

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    let Ok(tool_table) = ToolTable::parse("T1 P1 Z1 D0.5\nT2 P2 Z2 D1\n", Path::new("t.tbl"))
    else {
        return;
    };
    let opts = InterpOptions {
        max_blocks: 5_000,
        tool_table,
        ..InterpOptions::default()
    };
    for rec in Interpreter::from_text(&text, Path::new("fuzz.ngc"), opts) {
        if rec.is_err() {
            break;
        }
    }
});
