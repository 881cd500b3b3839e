//! Motion and event records produced by the interpreter, and their JSON-lines form.
//!
//! Positions are machine coordinates (LinuxCNC's: after work offsets, G92/G52, XY rotation
//! and tool length), X Y Z in mm and A B C in degrees. The JSON form has the fields of the
//! normalised LinuxCNC output used as the conformance reference (`seq`, `kind`, `n`,
//! `start`, `end`, `feed`, `feed_unit`, and for arcs `center`, `plane`, `direction`,
//! `turns`, `rotation`, `normal`, `radius`, `radius_end`, `sweep_deg`), plus `line` (the
//! source line of the block).

use std::io::Write as _;

use crate::math::{Point3, Real, Vector3};

use super::AxisValues;

/// Plane of an arc (G17 XY, G18 XZ, G19 YZ).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Plane {
    /// G17: first axis X, second Y, normal Z.
    Xy,
    /// G18: first axis Z, second X, normal Y.
    Xz,
    /// G19: first axis Y, second Z, normal X.
    Yz,
}

impl Plane {
    /// `XY`, `XZ` or `YZ`.
    pub fn name(self) -> &'static str {
        match self {
            Plane::Xy => "XY",
            Plane::Xz => "XZ",
            Plane::Yz => "YZ",
        }
    }

    /// Indices (first, second, normal) into X Y Z.
    pub fn axes(self) -> (usize, usize, usize) {
        match self {
            Plane::Xy => (0, 1, 2),
            Plane::Xz => (2, 0, 1),
            Plane::Yz => (1, 2, 0),
        }
    }
}

/// Geometry of an arc or helix in machine coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ArcGeom {
    /// Centre (mm); its coordinate along the normal is the end point's.
    pub center: Point3,
    /// Unit normal; positive `sweep_deg` is counter-clockwise about it.
    pub normal: Vector3,
    /// Program plane.
    pub plane: Plane,
    /// LinuxCNC's signed rotation: +n counter-clockwise (G3), −n clockwise (G2), |n| − 1
    /// extra full turns.
    pub rotation: i32,
    /// Radius at the start (mm).
    pub radius: Real,
    /// Radius at the end (mm; differs slightly from `radius` on a spiral).
    pub radius_end: Real,
    /// Signed angle swept about `normal` (degrees).
    pub sweep_deg: Real,
}

/// Kind of a motion record.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MotionKind {
    /// Rapid traverse (G0 and the rapids of cycles, G28, …).
    Rapid,
    /// Straight feed.
    Linear,
    /// Arc or helix (see [`Motion::arc`]).
    Arc,
    /// Straight probe (G38.x) towards `end`.
    Probe,
    /// Rigid tap (G33.1) to `end` and back to `start`.
    RigidTap,
}

impl MotionKind {
    /// The JSON `kind` string.
    pub fn name(self) -> &'static str {
        match self {
            MotionKind::Rapid => "rapid",
            MotionKind::Linear => "linear",
            MotionKind::Arc => "arc",
            MotionKind::Probe => "probe",
            MotionKind::RigidTap => "rigid_tap",
        }
    }
}

/// One move in machine coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Motion {
    /// What kind of move.
    pub kind: MotionKind,
    /// Position before the move.
    pub start: AxisValues,
    /// Position after the move (for a rigid tap: the bottom).
    pub end: AxisValues,
    /// Feed (mm/min, or mm/rev when `feed_per_rev`); `None` for rapids.
    pub feed: Option<Real>,
    /// The feed is per spindle revolution (G95, G33.1).
    pub feed_per_rev: bool,
    /// Arc geometry for [`MotionKind::Arc`].
    pub arc: Option<ArcGeom>,
}

/// An argument of an event.
#[derive(Clone, Debug, PartialEq)]
pub enum EventArg {
    /// A number as LinuxCNC's canon prints it (program units for lengths).
    Num(Real),
    /// A symbol or text.
    Text(String),
}

/// A non-motion canonical call (tool change, spindle, offsets, …), named as LinuxCNC's
/// canon calls it.
#[derive(Clone, Debug, PartialEq)]
pub struct Event {
    /// Canon call name, e.g. `CHANGE_TOOL`, `SET_FEED_RATE`.
    pub call: &'static str,
    /// Arguments.
    pub args: Vec<EventArg>,
}

/// What a record carries.
#[derive(Clone, Debug, PartialEq)]
pub enum RecordBody {
    /// A move.
    Motion(Motion),
    /// A non-motion call.
    Event(Event),
}

/// One output record with its source position.
#[derive(Clone, Debug, PartialEq)]
pub struct Record {
    /// Move or event.
    pub body: RecordBody,
    /// Source file of the block: 0 for the program, then subroutine files in the order
    /// they were opened ([`crate::nc::Interpreter::file_path`] names them).
    pub file: usize,
    /// 1-based source line of the block.
    pub line: usize,
    /// The block's N word, if any.
    pub n: Option<Real>,
}

/// Rounds to 6 decimals like the reference normaliser (and turns −0 into 0).
fn r6(v: Real) -> Real {
    let r = (v * 1e6).round() / 1e6;
    if r == 0.0 { 0.0 } else { r }
}

fn num(out: &mut Vec<u8>, v: Real) {
    let x = v * 1e6;
    if x.abs() < FAST_LIMIT_MICRO {
        fixed6(out, x);
        return;
    }
    let v = r6(v);
    if !v.is_finite() {
        out.extend_from_slice("null".as_bytes());
    } else if v.fract() == 0.0 && v.abs() < 1e15 {
        let _ = write!(out, "{v:.1}");
    } else {
        let _ = write!(out, "{v}");
    }
}

/// Below this magnitude (in micrometres, 1e9 mm) a value rounded to 6 decimals is written by
/// [`fixed6`]: doubles there are spaced by less than 1e-6 / 2, so every multiple of 1e-6 is
/// its own double and its shortest round-trip form is the multiple's decimal with trailing
/// zeros dropped — exactly what `{}` prints for [`r6`]'s value (and `{:.1}` for whole
/// numbers).
const FAST_LIMIT_MICRO: Real = 1e15;

/// Writes `x / 1e6` rounded to 6 decimals (half away from zero, as [`r6`]) as `{}` would,
/// `{:.1}` for whole numbers: integer digits, then the fraction's digits without trailing
/// zeros; zero, and what rounds to it, is `0.0`.
fn fixed6(out: &mut Vec<u8>, x: Real) {
    let a = x.abs();
    // round(a) without a libm call: floor(a + 0.5), undone where the addition rounded up
    // across an integer (a just below a half).
    let mut micro = (a + 0.5) as u64;
    if micro as Real - a > 0.5 {
        micro -= 1;
    }
    if micro == 0 {
        out.extend_from_slice("0.0".as_bytes());
        return;
    }
    if x < 0.0 {
        out.push(b'-');
    }
    let (int, mut frac) = (micro / 1_000_000, micro % 1_000_000);
    digits(out, int);
    out.push(b'.');
    if frac == 0 {
        out.push(b'0');
        return;
    }
    let mut width = 6;
    while frac % 10 == 0 {
        frac /= 10;
        width -= 1;
    }
    let mut buf = [b'0'; 6];
    for slot in buf[..width].iter_mut().rev() {
        *slot = b'0' + (frac % 10) as u8;
        frac /= 10;
    }
    for &b in &buf[..width] {
        out.push(b);
    }
}

/// Writes the decimal digits of `n`.
fn digits(out: &mut Vec<u8>, mut n: u64) {
    let mut buf = [0u8; 20];
    let mut i = buf.len();
    loop {
        i -= 1;
        buf[i] = b'0' + (n % 10) as u8;
        n /= 10;
        if n == 0 {
            break;
        }
    }
    for &b in &buf[i..] {
        out.push(b);
    }
}

fn point6(out: &mut Vec<u8>, p: &AxisValues) {
    let a = p.to_array();
    out.push(b'{');
    for (i, key) in [
        "\"x\": ",
        ", \"y\": ",
        ", \"z\": ",
        ", \"a\": ",
        ", \"b\": ",
        ", \"c\": ",
    ]
    .iter()
    .enumerate()
    {
        out.extend_from_slice(key.as_bytes());
        num(out, a[i]);
    }
    out.push(b'}');
}

fn json_string(out: &mut Vec<u8>, s: &str) {
    out.push(b'"');
    for ch in s.chars() {
        match ch {
            '"' => out.extend_from_slice("\\\"".as_bytes()),
            '\\' => out.extend_from_slice("\\\\".as_bytes()),
            '\n' => out.extend_from_slice("\\n".as_bytes()),
            c if (c as u32) < 0x20 => {
                let _ = write!(out, "\\u{:04x}", c as u32);
            }
            c => {
                let mut buf = [0u8; 4];
                out.extend_from_slice(c.encode_utf8(&mut buf).as_bytes());
            }
        }
    }
    out.push(b'"');
}

/// Appends the JSON line (without newline) of `rec` with sequence number `seq` to `out`.
pub fn write_json(out: &mut Vec<u8>, seq: usize, rec: &Record) {
    write_json_with(out, seq, rec, &mut PointMemo::default());
}

/// The text of the last end point written, so that the next record's start — the same
/// point whenever motion is continuous — is copied rather than formatted again.
#[derive(Clone, Debug, Default)]
pub struct PointMemo {
    point: Option<[u64; 6]>,
    text: Vec<u8>,
}

impl PointMemo {
    fn write(&mut self, out: &mut Vec<u8>, p: &AxisValues) {
        let bits = p.to_array().map(Real::to_bits);
        if self.point != Some(bits) {
            self.text.clear();
            point6(&mut self.text, p);
            self.point = Some(bits);
        }
        out.extend_from_slice(&self.text);
    }
}

/// [`write_json`] with a [`PointMemo`] carried from one record to the next (the same
/// bytes, fewer numbers formatted).
pub fn write_json_with(out: &mut Vec<u8>, seq: usize, rec: &Record, memo: &mut PointMemo) {
    out.extend_from_slice("{\"seq\": ".as_bytes());
    digits(out, seq as u64);
    out.extend_from_slice(", ".as_bytes());
    match &rec.body {
        RecordBody::Motion(m) => {
            out.extend_from_slice("\"kind\": \"".as_bytes());
            out.extend_from_slice(m.kind.name().as_bytes());
            out.extend_from_slice("\", ".as_bytes());
            write_n(out, rec.n);
            out.extend_from_slice(", \"start\": ".as_bytes());
            memo.write(out, &m.start);
            out.extend_from_slice(", \"end\": ".as_bytes());
            memo.write(out, &m.end);
            if let Some(a) = &m.arc {
                out.extend_from_slice(", \"center\": {\"x\": ".as_bytes());
                num(out, a.center.x);
                out.extend_from_slice(", \"y\": ".as_bytes());
                num(out, a.center.y);
                out.extend_from_slice(", \"z\": ".as_bytes());
                num(out, a.center.z);
                let dir = if a.rotation > 0 { "ccw" } else { "cw" };
                let _ = write!(
                    out,
                    "}}, \"plane\": \"{}\", \"direction\": \"{dir}\", \"turns\": {}, \"rotation\": {}, \"normal\": [",
                    a.plane.name(),
                    a.rotation.unsigned_abs(),
                    a.rotation
                );
                for (i, c) in a.normal.iter().enumerate() {
                    if i > 0 {
                        out.extend_from_slice(", ".as_bytes());
                    }
                    num(out, *c);
                }
                out.push(b']');
            }
            out.extend_from_slice(", \"feed\": ".as_bytes());
            match m.feed {
                Some(f) => num(out, f),
                None => out.extend_from_slice("null".as_bytes()),
            }
            if m.feed_per_rev {
                out.extend_from_slice(", \"feed_unit\": \"mm/rev\"".as_bytes());
            }
            if let Some(a) = &m.arc {
                out.extend_from_slice(", \"radius\": ".as_bytes());
                num(out, a.radius);
                out.extend_from_slice(", \"radius_end\": ".as_bytes());
                num(out, a.radius_end);
                out.extend_from_slice(", \"sweep_deg\": ".as_bytes());
                num(out, a.sweep_deg);
            }
        }
        RecordBody::Event(e) => {
            out.extend_from_slice("\"kind\": \"event\", ".as_bytes());
            write_n(out, rec.n);
            let _ = write!(out, ", \"call\": \"{}\", \"args\": [", e.call);
            for (i, a) in e.args.iter().enumerate() {
                if i > 0 {
                    out.extend_from_slice(", ".as_bytes());
                }
                match a {
                    EventArg::Num(v) => num(out, *v),
                    EventArg::Text(t) => json_string(out, t),
                }
            }
            out.push(b']');
        }
    }
    out.extend_from_slice(", \"line\": ".as_bytes());
    digits(out, rec.line as u64);
    out.push(b'}');
}

fn write_n(out: &mut Vec<u8>, n: Option<Real>) {
    out.extend_from_slice("\"n\": ".as_bytes());
    match n {
        Some(v) if v.fract() == 0.0 && v.abs() < 1e15 => {
            if v < 0.0 {
                out.push(b'-');
            }
            digits(out, v.abs() as u64);
        }
        Some(v) => num(out, v),
        None => out.extend_from_slice("null".as_bytes()),
    }
}

#[cfg(test)]
mod format_tests {
    use super::*;
    use proptest::prelude::*;

    /// What the writer printed before the fast path: std's shortest round-trip `{}`, with
    /// `{:.1}` for whole numbers (the oracle).
    fn std_num(v: Real) -> String {
        let v = r6(v);
        if !v.is_finite() {
            "null".into()
        } else if v.fract() == 0.0 && v.abs() < 1e15 {
            format!("{v:.1}")
        } else {
            format!("{v}")
        }
    }

    fn fast(v: Real) -> String {
        let mut s = Vec::new();
        num(&mut s, v);
        String::from_utf8(s).expect("ASCII")
    }

    #[test]
    fn numbers_print_as_std_prints_them_at_the_edges() {
        for v in [
            0.0,
            -0.0,
            1e-7,
            -4e-7,
            5e-7,
            1e-6,
            -1e-6,
            0.25,
            -0.1,
            0.3,
            1.0 / 3.0,
            2.0 / 3.0,
            123.4565,
            123.4575,
            999_999_999.999_999,
            -999_999_999.999_999,
            1e9,
            1e9 + 0.5,
            -1e12,
            1e15,
            1e17,
            12_345.678_901_5,
            0.000_000_5,
            99.999_999_6,
        ] {
            assert_eq!(fast(v), std_num(v), "{v:e}");
        }
        assert_eq!(fast(Real::NAN), "null");
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(20_000))]
        #[test]
        fn numbers_print_as_std_prints_them(m in -1e10f64..1e10, e in -8i32..4) {
            let v = m * 10f64.powi(e - 6);
            prop_assert_eq!(fast(v), std_num(v));
        }

        #[test]
        fn values_near_half_a_micrometre_print_as_std_prints_them(k in -1_000_000_000_000i64..1_000_000_000_000, ulps in -3i64..4) {
            // x·1e6 within a few ulps of k + ½: where the rounding is decided.
            let half = (k as Real + 0.5) / 1e6;
            let v = Real::from_bits((half.to_bits() as i64 + ulps) as u64);
            prop_assert_eq!(fast(v), std_num(v));
        }

        #[test]
        fn multiples_of_a_micrometre_print_as_std_prints_them(k in -1_000_000_000_000_000i64..1_000_000_000_000_000) {
            let v = k as Real / 1e6;
            prop_assert_eq!(fast(v), std_num(v));
        }
    }
}
