//! Motion and event records produced by the interpreter, and their JSON-lines form.
//!
//! Positions are machine coordinates (LinuxCNC's: after work offsets, G92/G52, XY rotation
//! and tool length), X Y Z in mm and A B C in degrees. The JSON form has the fields of the
//! normalised LinuxCNC output used as the conformance reference (`seq`, `kind`, `n`,
//! `start`, `end`, `feed`, `feed_unit`, and for arcs `center`, `plane`, `direction`,
//! `turns`, `rotation`, `normal`, `radius`, `radius_end`, `sweep_deg`), plus `line` and
//! `file` (the source line of the block).

use std::fmt::Write as _;
use std::path::Path;
use std::sync::Arc;

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
    /// Source file of the block.
    pub path: Arc<Path>,
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

fn num(out: &mut String, v: Real) {
    let v = r6(v);
    if v.is_finite() {
        if v.fract() == 0.0 && v.abs() < 1e15 {
            let _ = write!(out, "{v:.1}");
        } else {
            let _ = write!(out, "{v}");
        }
    } else {
        out.push_str("null");
    }
}

fn point6(out: &mut String, p: &AxisValues) {
    let a = p.to_array();
    out.push('{');
    for (i, name) in ["x", "y", "z", "a", "b", "c"].iter().enumerate() {
        if i > 0 {
            out.push_str(", ");
        }
        let _ = write!(out, "\"{name}\": ");
        num(out, a[i]);
    }
    out.push('}');
}

fn json_string(out: &mut String, s: &str) {
    out.push('"');
    for ch in s.chars() {
        match ch {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            c if (c as u32) < 0x20 => {
                let _ = write!(out, "\\u{:04x}", c as u32);
            }
            c => out.push(c),
        }
    }
    out.push('"');
}

/// Appends the JSON line (without newline) of `rec` with sequence number `seq` to `out`.
pub fn write_json(out: &mut String, seq: usize, rec: &Record) {
    let _ = write!(out, "{{\"seq\": {seq}, ");
    match &rec.body {
        RecordBody::Motion(m) => {
            let _ = write!(out, "\"kind\": \"{}\", ", m.kind.name());
            write_n(out, rec.n);
            out.push_str(", \"start\": ");
            point6(out, &m.start);
            out.push_str(", \"end\": ");
            point6(out, &m.end);
            if let Some(a) = &m.arc {
                out.push_str(", \"center\": {\"x\": ");
                num(out, a.center.x);
                out.push_str(", \"y\": ");
                num(out, a.center.y);
                out.push_str(", \"z\": ");
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
                        out.push_str(", ");
                    }
                    num(out, *c);
                }
                out.push(']');
            }
            out.push_str(", \"feed\": ");
            match m.feed {
                Some(f) => num(out, f),
                None => out.push_str("null"),
            }
            if m.feed_per_rev {
                out.push_str(", \"feed_unit\": \"mm/rev\"");
            }
            if let Some(a) = &m.arc {
                out.push_str(", \"radius\": ");
                num(out, a.radius);
                out.push_str(", \"radius_end\": ");
                num(out, a.radius_end);
                out.push_str(", \"sweep_deg\": ");
                num(out, a.sweep_deg);
            }
        }
        RecordBody::Event(e) => {
            out.push_str("\"kind\": \"event\", ");
            write_n(out, rec.n);
            let _ = write!(out, ", \"call\": \"{}\", \"args\": [", e.call);
            for (i, a) in e.args.iter().enumerate() {
                if i > 0 {
                    out.push_str(", ");
                }
                match a {
                    EventArg::Num(v) => num(out, *v),
                    EventArg::Text(t) => json_string(out, t),
                }
            }
            out.push(']');
        }
    }
    let _ = write!(out, ", \"line\": {}", rec.line);
    out.push('}');
}

fn write_n(out: &mut String, n: Option<Real>) {
    out.push_str("\"n\": ");
    match n {
        Some(v) if v.fract() == 0.0 && v.abs() < 1e15 => {
            let _ = write!(out, "{}", v as i64);
        }
        Some(v) => num(out, v),
        None => out.push_str("null"),
    }
}
