//! Benchmarks P3 and P4 of `docs/benchmarks.md` on the MDX-50 chain: the round-bar stock and
//! the two programs.
//!
//! - **P3, indexed 3+1**: six faces of a hexagon side-milled on a Ø20 mm round bar at A = 0,
//!   60, …, 300° (each face: the A turn in the air, plunge beside the bar, the cut along X,
//!   retract).
//! - **P4, simultaneous XA**: one turn of a helical groove 1 mm deep on a Ø16 mm bar, ball
//!   Ø4 mm, A and X together in 60 moves of 6°.
//!
//! Shared by the benches (`#[path = "support/rotary.rs"] mod rotary;` next to
//! `use twinmill::{cutting, math, nc};`) and the examples: it names the library only through
//! `crate::cutting`, `crate::math` and `crate::nc`.

#![allow(dead_code, reason = "each user takes the parts it needs")]

use crate::cutting::shape::Cylinder;
use crate::cutting::stock::TriDexel;
use crate::math::{Aabb, Point3, Real, Vector3};
use crate::nc::{AxisLetter, AxisValues, Move, MoveKind};

/// Feed moves at `feed` mm/min through `points`, the k-th move on line k (from 1).
pub fn polyline(points: &[AxisValues], feed: Real) -> Vec<Move> {
    points
        .windows(2)
        .enumerate()
        .map(|(k, w)| Move {
            kind: MoveKind::Linear,
            start: w[0],
            end: w[1],
            feed_mm_per_min: Some(feed),
            line: k + 1,
        })
        .collect()
}

/// A round bar along x from `x0`, `len` long, as a tri-dexel at `pitch` in a box 0.5 mm
/// larger than its radius.
pub fn bar(radius: Real, x0: Real, len: Real, pitch: Real) -> TriDexel {
    let c = Cylinder::try_new(Point3::new(x0, 0.0, 0.0), Vector3::x(), radius, len).expect("valid");
    let b = radius + 0.5;
    let bounds = Aabb {
        min: Point3::new(x0, -b, -b),
        max: Point3::new(x0 + len, b, b),
    };
    TriDexel::from_solid(bounds, pitch, 8e9, &c).expect("fits")
}

/// P3: the hexagon's six faces, a tool of radius `r` (the bar: `bar(10.0, -20.0, 40.0, …)`).
pub fn hexagon(r: Real) -> Vec<Move> {
    let home = AxisValues::default()
        .with(AxisLetter::X, -30.0)
        .with(AxisLetter::Y, -(8.0 + r))
        .with(AxisLetter::Z, 60.0);
    let mut points = vec![home];
    for k in 0..6 {
        let p = home.with(AxisLetter::A, 60.0 * k as Real);
        points.push(p);
        points.push(p.with(AxisLetter::Z, -12.0));
        points.push(p.with(AxisLetter::Z, -12.0).with(AxisLetter::X, 30.0));
        points.push(p.with(AxisLetter::X, 30.0));
        points.push(p);
    }
    polyline(&points, 600.0)
}

/// P4: one turn of the helical groove (the bar: `bar(8.0, -10.0, 20.0, …)`, ball Ø4 × 12).
pub fn helix() -> Vec<Move> {
    let points: Vec<AxisValues> = (0..=60)
        .map(|k| {
            let f = k as Real / 60.0;
            AxisValues::default()
                .with(AxisLetter::X, -5.0 + 10.0 * f)
                .with(AxisLetter::Z, 7.0)
                .with(AxisLetter::A, 360.0 * f)
        })
        .collect();
    polyline(&points, 600.0)
}
