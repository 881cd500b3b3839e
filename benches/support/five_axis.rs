//! The simultaneous 5-axis programs of `benches/five_axis.rs` and of the scenes in
//! `benches/data/` (written by `cargo run --release --example five_axis_programs`): every
//! move turns a rotary axis (or tilts a hexapod's tool) while the tool moves.
//!
//! - **Side cut** on the trunnion A/C scene: the tool at the cube's side (X0 Y−19), C turning
//!   0.5° a move while Z descends 36 mm over 7,200 moves (ten turns) and A oscillates ±8°,
//!   three periods a turn, from Z40.
//! - **Blade-like finishing** on the trunnion: a ball end mill's centre on a helix 0.2 mm
//!   inside a Ø40 mm cylinder on the C table, C turning 0.25° a move, A oscillating ±5°
//!   twice a turn, descending 0.2 mm a turn; the axis values solved on the nominal chain.
//! - **Hexapod side cut**: the hexapod machining centre's tool point on a circle of radius
//!   21 mm about a Ø40 mm cylinder, 0.5° a move, descending 3.6 mm a turn, the tool tilted
//!   ±8° about x three times a turn (its poses sampled, each move cut in bounded sub-steps).
//!
//! Shared by the benches (`#[path = "support/five_axis.rs"] mod five_axis;` next to
//! `#[path = "support/rotary.rs"] mod rotary;` and `use twinmill::{machine, math, nc};`) and the examples.

#![allow(dead_code, reason = "each user takes the parts it needs")]

use crate::machine::chain::Chain;
use crate::math::{Point3, Real, Vector3};
use crate::nc::{AxisLetter, AxisValues};

/// Feed of the programs (mm/min).
pub const FEED: Real = 2000.0;

/// Point k (0..=7,200) of the side cut: Z = 40 − 36·k/7200, A = 8·sin(1.5·k°), C = 0.5·k°.
pub fn side_cut_point(k: usize) -> AxisValues {
    let k = k as Real;
    AxisValues::default()
        .with(AxisLetter::X, 0.0)
        .with(AxisLetter::Y, -19.0)
        .with(AxisLetter::Z, 40.0 - 36.0 * k / 7200.0)
        .with(AxisLetter::A, 8.0 * (1.5 * k).to_radians().sin())
        .with(AxisLetter::C, 0.5 * k)
}

/// The first `n` + 1 points of the side cut (its first `n` moves).
pub fn side_cut(n: usize) -> Vec<AxisValues> {
    (0..=n).map(side_cut_point).collect()
}

/// Radius (mm) of the blade path's ball centre from C's line.
pub const BLADE_RADIUS: Real = 22.8;

/// The blade-like path's first `n` + 1 points for a ball of radius `r`: the machine axes
/// that put the ball's centre (the tool point plus `r` along the tool axis) at
/// [`BLADE_RADIUS`] from C's line at the angle of C, 35 mm high descending 0.2 mm a turn,
/// with A = 5·sin(2·C); solved on the nominal chain
/// `r_W = RotZ(c)·RotX(a about z = −50)·(x, y, z)` and checked against `nominal`.
pub fn blade(nominal: &Chain, r: Real, n: usize) -> Vec<AxisValues> {
    let pivot = Vector3::new(0.0, 0.0, -50.0);
    let at = |k: usize| {
        let c_deg = 0.25 * k as Real;
        let a_deg = 5.0 * (2.0 * c_deg).to_radians().sin();
        let rz = nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), c_deg.to_radians());
        let rx = nalgebra::Rotation3::from_axis_angle(&Vector3::x_axis(), a_deg.to_radians());
        let phi = c_deg.to_radians() - std::f64::consts::FRAC_PI_2;
        let centre = Vector3::new(
            BLADE_RADIUS * phi.cos(),
            BLADE_RADIUS * phi.sin(),
            35.0 - 0.2 * c_deg / 360.0,
        );
        let axis_w = rz * rx * Vector3::z();
        let tip_w = centre - axis_w * r;
        let v = pivot + rx.inverse() * (rz.inverse() * tip_w - pivot);
        let q = AxisValues::default()
            .with(AxisLetter::X, v.x)
            .with(AxisLetter::Y, v.y)
            .with(AxisLetter::Z, v.z)
            .with(AxisLetter::A, a_deg)
            .with(AxisLetter::C, c_deg);
        let got = nominal.w_from_t(&q) * Point3::new(0.0, 0.0, r);
        assert!(
            (got.coords - centre).norm() < 1e-9,
            "the blade path's ball centre lands where it was solved for"
        );
        q
    };
    (0..=n).map(at).collect()
}

/// Point k of the hexapod side cut: the tool point at radius 21 mm, angle 0.5·k° from −y,
/// z = 178 − 3.6·k/720 (the cylinder's top at 180), tilted A = 8·sin(1.5·k°).
pub fn hexapod_side_point(k: usize) -> AxisValues {
    let k = k as Real;
    let phi = (0.5 * k).to_radians() - std::f64::consts::FRAC_PI_2;
    AxisValues::default()
        .with(AxisLetter::X, 21.0 * phi.cos())
        .with(AxisLetter::Y, 21.0 * phi.sin())
        .with(AxisLetter::Z, 178.0 - 3.6 * k / 720.0)
        .with(AxisLetter::A, 8.0 * (1.5 * k).to_radians().sin())
        .with(AxisLetter::B, 0.0)
        .with(AxisLetter::C, 0.0)
}

/// The first `n` + 1 points of the hexapod side cut.
pub fn hexapod_side(n: usize) -> Vec<AxisValues> {
    (0..=n).map(hexapod_side_point).collect()
}

/// The NC text of a feed polyline through `points` (G21 G90, a rapid above the first point
/// at `clear_z`, then one G1 a point), for the axes `letters`.
pub fn nc_text(
    points: &[AxisValues],
    letters: &[AxisLetter],
    clear_z: Real,
    title: &str,
) -> String {
    let word = |p: &AxisValues| {
        letters
            .iter()
            .map(|&l| format!("{}{:.6}", l.as_char(), p.get(l)))
            .collect::<Vec<_>>()
            .join(" ")
    };
    let mut s = format!("%\n({title})\nG21 G90\n");
    let first = points[0];
    let above = first.with(AxisLetter::Z, clear_z);
    s += &format!("G0 {}\n", word(&above));
    s += &format!("G1 {} F{FEED}\n", word(&first));
    for p in &points[1..] {
        s += &format!("G1 {}\n", word(p));
    }
    s += &format!("G0 Z{clear_z:.3}\nM30\n%\n");
    s
}
