//! Benchmark P1 of `docs/benchmarks.md`: the 3-axis zig-zag pocket, as moves and as G-code.
//!
//! Box stock 100 × 100 × 20 mm; Ø6 mm tool plunged from z = 25 to z = 18.5 at (10, 10);
//! 41 rows along x, 80 mm long, 2 mm apart in y, each row cut as 80 G1 moves of 1 mm;
//! between rows a 2 mm step-over along y (one move) alternately at x = 90 and x = 10.
//! 1 plunge + 41·80 row moves + 40 step-overs = 3,321 moves, ending at (90, 90).
//!
//! Shared by the benches (`#[path = "support/p1.rs"] mod p1;` next to
//! `use twinmill::{math, nc};`) and by unit tests (`#[path = "../benches/support/p1.rs"]`):
//! it names the library only through `crate::math` and `crate::nc`.

#![allow(dead_code, reason = "each user takes the parts it needs")]

use crate::math::{Aabb, Point3, Real};
use crate::nc::{AxisLetter, AxisValues, Move, MoveKind};

/// Stock box of P1 (mm).
pub fn stock_box() -> Aabb {
    Aabb {
        min: Point3::new(0.0, 0.0, 0.0),
        max: Point3::new(100.0, 100.0, 20.0),
    }
}

/// Tool diameter (mm).
pub const TOOL_DIAMETER: Real = 6.0;
/// Tool tip height while cutting (mm): one level 1.5 mm deep.
pub const Z_CUT: Real = 18.5;
/// Height the plunge starts from (mm).
pub const Z_CLEAR: Real = 25.0;
/// First row's y and the rows' x start (mm).
pub const START: Real = 10.0;
/// Last row's y and the rows' x end (mm).
pub const END: Real = 90.0;
/// Row spacing (mm).
pub const STEP: Real = 2.0;
/// Feed (mm/min).
pub const FEED: Real = 600.0;

/// Tip positions (x, y) of the path after the plunge, in order: the polyline vertices.
pub fn path_points() -> Vec<(Real, Real)> {
    let rows = ((END - START) / STEP).round() as usize + 1;
    let cols = (END - START).round() as usize;
    let mut pts = vec![(START, START)];
    for row in 0..rows {
        let y = START + STEP * row as Real;
        if row > 0 {
            // Step-over from the previous row's end.
            let x = pts.last().map(|p| p.0).unwrap_or(START);
            pts.push((x, y));
        }
        for k in 1..=cols {
            let x = if row % 2 == 0 {
                START + k as Real
            } else {
                END - k as Real
            };
            pts.push((x, y));
        }
    }
    pts
}

/// A straight run of the path in xy: (start, end).
pub type Run = ((Real, Real), (Real, Real));

/// The 81 straight runs of the path (41 rows and 40 step-overs), in order.
pub fn runs() -> Vec<Run> {
    let rows = ((END - START) / STEP).round() as usize + 1;
    let mut out = Vec::new();
    for row in 0..rows {
        let y = START + STEP * row as Real;
        let (xa, xb) = if row % 2 == 0 {
            (START, END)
        } else {
            (END, START)
        };
        if row > 0 {
            out.push(((xa, y - STEP), (xa, y)));
        }
        out.push(((xa, y), (xb, y)));
    }
    out
}

/// The G-code text of P1: a header on lines 1–3, the plunge on line 4, then one move a line.
pub fn gcode() -> String {
    let mut s = String::from("(P1 3-axis pocket, docs/benchmarks.md)\nG21 G90\n");
    s.push_str(&format!("G0 X{START} Y{START} Z{Z_CLEAR}\n"));
    s.push_str(&format!("G1 Z{Z_CUT} F{FEED}\n"));
    for (x, y) in path_points().into_iter().skip(1) {
        s.push_str(&format!("G1 X{x} Y{y}\n"));
    }
    s.push_str("M2\n");
    s
}

/// The position before the program (the parser's `start`): above the plunge point.
pub fn start_position() -> AxisValues {
    AxisValues::default()
        .with(AxisLetter::X, START)
        .with(AxisLetter::Y, START)
        .with(AxisLetter::Z, Z_CLEAR)
}

/// The moves of [`gcode`], built directly (line numbers as in the text).
pub fn moves() -> Vec<Move> {
    let at = |x: Real, y: Real, z: Real| {
        AxisValues::default()
            .with(AxisLetter::X, x)
            .with(AxisLetter::Y, y)
            .with(AxisLetter::Z, z)
    };
    let mv = |start, end, line| Move {
        kind: MoveKind::Linear,
        start,
        end,
        feed_mm_per_min: Some(FEED),
        line,
    };
    let mut out = vec![mv(at(START, START, Z_CLEAR), at(START, START, Z_CUT), 4)];
    let pts = path_points();
    for (k, w) in pts.windows(2).enumerate() {
        out.push(mv(
            at(w[0].0, w[0].1, Z_CUT),
            at(w[1].0, w[1].1, Z_CUT),
            5 + k,
        ));
    }
    out
}

/// Exact area (mm²) of the set within `r` of the path polyline, for `r` between half the
/// row spacing and the row spacing (so rows overlap and only the two side edges scallop):
/// the square [START − r, END + r]² less 4 rounded corners (r² − πr²/4 each) and less the
/// bites between step-overs on the side edges. A bite is a `STEP` × r rectangle minus the
/// two circular pieces of radius r centred on its corners on the path:
/// `2·∫₀^{STEP/2} sqrt(r² − y²) dy`. There are 20 bites per side (19 between step-overs
/// plus one at the path's start or end).
pub fn offset_area(r: Real) -> Real {
    let side = END - START + 2.0 * r;
    let corner = r * r - std::f64::consts::PI * r * r / 4.0;
    let h = STEP / 2.0;
    let piece = h / 2.0 * (r * r - h * h).sqrt() + r * r / 2.0 * (h / r).asin();
    let bite = STEP * r - 2.0 * piece;
    let rows = ((END - START) / STEP).round() as usize + 1;
    let bites = (rows - 1) as Real; // 2 × 20 for 41 rows.
    side * side - 4.0 * corner - bites * bite
}
