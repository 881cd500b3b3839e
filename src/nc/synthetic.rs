//! A deterministic synthetic program for speed measurements (the benchmark program of the
//! project's peer comparison): G1 moves with A words, every fifth block a G3 arc with I/J.

use std::fmt::Write as _;

/// Writes the benchmark program with `blocks` motion blocks (plus a header and an `M2`
/// line) into `out`. Block `k` (0-based) is, for `k % 5 == 4`, a counter-clockwise G3 half
/// circle of radius 0.5 mm about a centre 0.5 mm in +X of the current point (`I0.5 J0`),
/// otherwise a G1 move 0.25 mm along X with Y following a slow triangle wave and A
/// advancing 0.1° per block (no wrap). Only decimal digits, no randomness: the same
/// `blocks` always give the same bytes. 200,000 blocks make about 6.3 MB.
pub fn bench_program(blocks: usize, out: &mut String) {
    out.push_str("(synthetic benchmark program: G1 with A words, every fifth block G3)\n");
    out.push_str("G21 G90 G17 G94 F1200\nG0 X0 Y0 Z5 A0\nG1 Z0\n");
    let (mut x, mut y) = (0.0f64, 0.0f64);
    for k in 0..blocks {
        if k % 5 == 4 {
            // half circle about (x + 0.5, y): ends at (x + 1, y)
            x += 1.0;
            let _ = writeln!(out, "G3 X{x:.4} Y{y:.4} I0.5 J0");
        } else {
            x += 0.25;
            let phase = (k / 5) % 400;
            y = if phase < 200 {
                phase as f64 * 0.05
            } else {
                (400 - phase) as f64 * 0.05
            };
            let a = (k as f64) * 0.1;
            let _ = writeln!(out, "G1 X{x:.4} Y{y:.4} A{a:.3}");
        }
        if x > 400.0 {
            x = 0.0;
            let _ = writeln!(out, "G0 X0");
        }
    }
    out.push_str("M2\n");
}
