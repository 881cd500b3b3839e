//! Unit tests of the interpreter through its public entry points.

use super::*;

fn run(text: &str) -> Result<Program, NcError> {
    parse_program(text, Path::new("t.ngc"), AxisValues::default())
}

#[test]
fn g0_g1_in_mm() {
    let p = run("G21 G90 G0 X10 Y5\nG1 X20 F100\nM2\n").expect("runs");
    assert_eq!(p.moves.len(), 2);
    assert_eq!(p.moves[1].end.get(AxisLetter::X), 20.0);
    assert_eq!(p.moves[1].feed_mm_per_min, Some(100.0));
    assert_eq!(p.ended_by, Some(3));
}
