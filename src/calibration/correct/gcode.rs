//! The corrected program written as RS274/NGC.

use super::*;
use crate::math::Real;
use crate::nc::MoveKind;
use std::io::Write;

/// Makes a comment safe for RS274/NGC: no parentheses or line breaks inside.
fn comment(text: &str) -> String {
    text.chars()
        .map(|c| match c {
            '(' | '[' => '<',
            ')' | ']' => '>',
            '\n' | '\r' | ';' => ' ',
            c => c,
        })
        .collect()
}

fn format_feed(f: Real) -> String {
    let s = format!("{f:.6}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    s.to_string()
}

/// Writes the corrected program as RS274/NGC, block by block: a `%` line, the `header`
/// lines as comments, `G21 G90 G94`, one `G0`/`G1` per block with every axis of the machine
/// (linear axes to 1 nm, rotary to 1e-7°) and the feed on every `G1`, a comment naming the
/// source line (and the part, for subdivided moves), `M30` if the source ended so, `%`.
///
/// Blocks with an inverse-time feed ([`Block::inverse_time_per_min`]) are written in `G93`
/// with their `F` (1/min, the shortest decimal that reads back exactly) on every block, as
/// LinuxCNC asks of each `G93` motion block: a `G93` line before the first of a run, a `G94`
/// line after its last (before the next block, or before `M30`), so the program continues
/// and ends in units per minute.
pub fn write_gcode(
    program: &CorrectedProgram,
    header: &[String],
    out: &mut dyn Write,
) -> std::io::Result<()> {
    writeln!(out, "%")?;
    for h in header {
        writeln!(out, "({})", comment(h))?;
    }
    writeln!(out, "G21 G90 G94")?;
    let mut line = String::new();
    let mut inverse_time = false;
    for b in &program.blocks {
        line.clear();
        if b.inverse_time_per_min.is_some() != inverse_time {
            inverse_time = !inverse_time;
            writeln!(out, "{}", if inverse_time { "G93" } else { "G94" })?;
        }
        // Blocks are straight (see `emitted_kind`): G0 or G1.
        let rapid = matches!(b.kind, MoveKind::Rapid);
        line.push_str(if rapid { "G0" } else { "G1" });
        for &l in &program.axes {
            line.push(' ');
            line.push(l.as_char());
            line.push_str(&format_axis(l, b.end.get(l)));
        }
        match (rapid, b.inverse_time_per_min, b.feed_mm_per_min) {
            (true, _, _) => {}
            (false, Some(inverse), _) => {
                line.push_str(" F");
                line.push_str(&format!("{inverse}"));
            }
            (false, None, Some(f)) => {
                line.push_str(" F");
                line.push_str(&format_feed(f));
            }
            (false, None, None) => {}
        }
        match (b.source, b.part) {
            (None, _) => line.push_str(" (corrected start position)"),
            (Some(_), (1, 1)) => line.push_str(&format!(" (src line {})", b.line)),
            (Some(_), (k, n)) => line.push_str(&format!(" (src line {}, {k}/{n})", b.line)),
        }
        writeln!(out, "{line}")?;
    }
    if inverse_time {
        writeln!(out, "G94")?;
    }
    if program.ended {
        writeln!(out, "M30")?;
    }
    writeln!(out, "%")?;
    Ok(())
}
