//! **NC**: the program becomes motion. Owns the RS274/NGC language in LinuxCNC's dialect —
//! reading, modal state, offsets, subroutines, canned cycles, cutter compensation, tool
//! tables — and the motion records it produces. May use [`crate::math`] only: it knows
//! nothing about machines, tools or stock, reads only the files it is given and never
//! writes.
//!
//! RS274/NGC interpreter for a milling machine, in LinuxCNC's dialect, matching LinuxCNC's
//! standalone interpreter (`rs274`) move for move.
//!
//! # Pipeline
//!
//! A program is read line by line from a seekable source ([`source`]): each line is read by
//! a byte-level lexer ([`lex`]) into a block of words in fixed arrays, with expressions
//! evaluated as they are read; the interpreter ([`interp`]) executes the block in
//! LinuxCNC's order (comments and messages, feed mode, F, S, T, M6, spindle, coolant, dwell,
//! plane, units, cutter compensation, tool length, coordinate system, path mode, distance
//! mode, retract mode, G10/G28/G30/G52/G92, motion, stops) in *program coordinates* and
//! converts every end point to *machine coordinates* (LinuxCNC's: program point in mm, plus
//! G92/G52 offset, rotated by the G10 L2 R rotation, plus the G54–G59.3 offset, plus the
//! tool length offset). Records ([`output`]) stream out through [`Interpreter`] (an
//! iterator): memory does not grow with program length. [`parse_program`] /
//! [`interpret_program`] collect a small program into a [`Program`] of [`Move`]s.
//!
//! *Invariant:* the interpreter knows nothing about machines; it reads the files it is
//! given (program, subroutine files, tool table, var and INI files) and never writes.
//!
//! # Language
//!
//! G0 G1 G2 G3 (centre I/J/K and R forms, full circles, helices, P turns) in G17/G18/G19;
//! G4; G5 cubic spline, G5.1 quadratic B-spline, G5.2/G5.3 NURBS (issued as the arcs and
//! lines LinuxCNC's task makes of the curve); G10 L1/L2/L10/L11/L20; G20/G21; G28/G30,
//! G28.1/G30.1; G33 spindle-synchronised motion; G33.1 rigid tap; G38.2–G38.5
//! probe (rs274's simulated probe: trips at the target, backs off 0.254 mm, sets
//! #5061–#5070); G40/G41/G42/
//! G41.1/G42.1 cutter radius compensation ([`comp`], applied in program coordinates of the
//! plane between motion generation and the machine conversion, as LinuxCNC does: entry and
//! exit moves, concave corners by intersection, convex corners by inserted arcs, LinuxCNC's
//! gouging errors); G43 (H or current tool), G43.1, G49;
//! G52/G92/G92.1/G92.2/G92.3; G53; G54–G59.3; G61/G61.1/G64; canned cycles G73 G81 G82
//! G83 G84 G85 G86 G89 with G98/G99, L repeats and sticky Z/R/Q; the G76 threading cycle
//! (as LinuxCNC runs it on a mill: across X, along Z); G80; G90/G91,
//! G90.1/G91.1; G93/G94/G95; M0 M1 M2 M3 M4 M5 M6 M7 M8 M9 M30 M60 M61; M98/M99
//! Fanuc-style subprograms; T S F; A B C rotary words in degrees (no wrap). O-words:
//! sub/endsub/call with arguments, return with value (`#<_value>`), if/elseif/else/endif,
//! while/endwhile, do/while, repeat/endrepeat, break, continue; subroutines found later in
//! the file or in `NAME.ngc` files of the INI's `SUBROUTINE_PATH`. Numbered parameters
//! `#1`–`#5601` (with LinuxCNC's meaning of `#5161…` G28 home, `#5181…` G30 home,
//! `#5210…` G92, `#5220` current system, `#5221…` G54 …), local and global (`#<_name>`)
//! named parameters; expressions with RS274/NGC precedence (`**`; `* / MOD`; `+ -`;
//! `EQ NE GT GE LT LE`; `AND OR XOR`) and functions SIN COS TAN ASIN ACOS ATAN\[a\]/\[b\]
//! SQRT ABS EXP LN ROUND FIX FUP EXISTS (degrees). Comments `( )` and `;`, `(MSG,…)`,
//! block delete `/`, N numbers, `%` delimiters, case and space insensitivity.
//!
//! # Units of external files
//!
//! Tool tables, var files and the offset parameters are in the *external length unit*
//! [`InterpOptions::external_unit`]. LinuxCNC's standalone `rs274` hard-wires inches
//! ([`LengthUnit::Inch`], what the conformance corpus uses); a machine configured in mm
//! uses [`LengthUnit::Mm`], the default of [`InterpOptions::default`] and of the CLI
//! (`--external-units inch` selects LinuxCNC's standalone behaviour).
//!
//! # LinuxCNC versus Fanuc
//!
//! LinuxCNC's reading is the default; where a Fanuc control differs the program is read
//! the LinuxCNC way (the probes in the project's test data show each case):
//! a number without decimal point is a whole unit (`X10` = 10 mm, not 10 µm); `G4 P` is
//! seconds; `G10 L2 P0` means the active system; `;` starts a comment; `G91 G28 X0` moves
//! through the incremental intermediate point; `G52` is a G92-style local offset; arcs
//! whose end radius differs from the start radius by more than LinuxCNC's tolerance are
//! rejected (not corrected); `R` cannot make a full circle; G92 offsets persist until
//! G92.1; `G43 H` names a tool number (not an offset register); rotary words do not wrap.
//! Fanuc-only codes (G15/G16 polar, G51/G51.1 scaling and mirror, G54.1, G65, G68, Fanuc's
//! G76 fine boring without I J K, Macro B `WHILE…DO`/`GOTO`, canned-cycle `K` repeats) are rejected with
//! LinuxCNC's message. Fanuc-style `O1000 … M99` subprograms called by `M98 P1000 L2` are
//! accepted, as LinuxCNC does; [`InterpOptions::fanuc_subs`] = false (`--no-fanuc-subs`,
//! or `DISABLE_FANUC_STYLE_SUB = 1` in the INI) turns them off.
//!
//! # Errors
//!
//! Every error names file:line:column and the offending word. A syntax error, or an error
//! while executing (LinuxCNC's "semantic" errors), stops the program at that line, like
//! LinuxCNC; the reported [`NcError`] then also lists every syntax error of the rest of
//! the file. The message texts are LinuxCNC's where practical.
//!
//! # Limitations
//!
//! G87/G88, the lathe cycles G70–G72 and lathe modes (G7/G8), U V W axes (their words are
//! bad characters, as in `rs274` on an X Y Z A B C machine), `#5xxx` parameters newer than
//! LinuxCNC 2.9 and Python remaps are not supported.

pub mod comp;
pub mod interp;
pub mod lex;
pub mod output;
pub mod source;
pub mod synthetic;
pub mod tooltable;

use std::path::{Path, PathBuf};

use crate::math::Real;

pub use interp::Interpreter;
pub use output::{ArcGeom, Event, EventArg, Motion, MotionKind, Plane, Record, RecordBody};
pub use tooltable::{IniSettings, TableError, ToolEntry, ToolTable, parse_ini, parse_var_file};

/// Length unit of tool tables, var files and offset parameters.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum LengthUnit {
    /// Millimetres (a machine configured in mm).
    #[default]
    Mm,
    /// Inches (LinuxCNC's standalone `rs274`).
    Inch,
}

/// Options of an interpreter run.
#[derive(Clone, Debug)]
pub struct InterpOptions {
    /// Block delete switch on: lines starting with `/` are skipped (LinuxCNC's `-b`).
    pub block_delete: bool,
    /// Unit of tool-table lengths, var-file values and offset parameters.
    pub external_unit: LengthUnit,
    /// The tool table (lengths in `external_unit`).
    pub tool_table: ToolTable,
    /// Initial numbered parameters (a var file's contents).
    pub parameters: Vec<(usize, Real)>,
    /// Folders searched for `NAME.ngc` subroutine files.
    pub subroutine_path: Vec<PathBuf>,
    /// Accept Fanuc-style `O1000 … M99` subprograms and `M98` calls.
    pub fanuc_subs: bool,
    /// Machine position before the first move.
    pub start: AxisValues,
    /// Stop with an error after this many executed lines (endless loops).
    pub max_blocks: u64,
    /// Stop with an error after this many executed lines in a row that move the machine
    /// nowhere (endless loops without motion: `o100 while [1]`, `M98 L100000000`).
    pub max_idle_blocks: u64,
}

/// Default [`InterpOptions::max_idle_blocks`]: a million lines without motion, about half a
/// second of interpretation; no part program computes that long between two moves.
pub const DEFAULT_MAX_IDLE_BLOCKS: u64 = 1_000_000;

impl Default for InterpOptions {
    fn default() -> Self {
        InterpOptions {
            block_delete: false,
            external_unit: LengthUnit::Mm,
            tool_table: ToolTable::default(),
            parameters: Vec::new(),
            subroutine_path: Vec::new(),
            fanuc_subs: true,
            start: AxisValues::default(),
            max_blocks: 100_000_000,
            max_idle_blocks: DEFAULT_MAX_IDLE_BLOCKS,
        }
    }
}

impl InterpOptions {
    /// Applies an INI file's `[RS274NGC]` settings.
    pub fn apply_ini(&mut self, ini: &IniSettings) {
        self.subroutine_path
            .extend(ini.subroutine_path.iter().cloned());
        if ini.disable_fanuc_subs {
            self.fanuc_subs = false;
        }
    }
}

/// One problem found in a program.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{}:{line}:{column}: {}{message}", path.display(), word_prefix(word))]
pub struct Diagnostic {
    /// File the program came from (only used for messages).
    pub path: PathBuf,
    /// 1-based line number.
    pub line: usize,
    /// 1-based column (in characters) of the offending word's letter or character.
    pub column: usize,
    /// The offending word as written in the source (e.g. `G2`, `M3`, `X1.2.3`).
    pub word: String,
    /// Human-readable explanation; contains the offending word in double quotes.
    pub message: String,
}

/// `"word": ` for the message, or nothing when there is no word.
fn word_prefix(word: &str) -> String {
    if word.is_empty() {
        String::new()
    } else if word.chars().count() > 64 {
        let head: String = word.chars().take(64).collect();
        format!("\"{head}...\": ")
    } else {
        format!("\"{word}\": ")
    }
}

/// All problems of a program.
///
/// `Display` is a single line: the first diagnostic, followed by ` (and N more errors)` when
/// there are more. [`NcError::full_report`] lists all of them.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{}", summary(diagnostics))]
pub struct NcError {
    /// Every diagnostic, in source order.
    pub diagnostics: Vec<Diagnostic>,
}

impl NcError {
    /// One line per diagnostic, each terminated by a newline.
    pub fn full_report(&self) -> String {
        let mut out = String::new();
        for d in &self.diagnostics {
            out.push_str(&d.to_string());
            out.push('\n');
        }
        out
    }
}

/// The single-line summary used by `Display for NcError`.
fn summary(diagnostics: &[Diagnostic]) -> String {
    match diagnostics {
        [] => "no diagnostics".to_owned(),
        [only] => only.to_string(),
        [first, rest @ ..] => {
            let n = rest.len();
            let plural = if n == 1 { "error" } else { "errors" };
            format!("{first} (and {n} more {plural})")
        }
    }
}

/// An axis letter of RS274/NGC. X Y Z are linear (mm), A B C rotary (degrees).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum AxisLetter {
    /// Linear X (mm).
    X,
    /// Linear Y (mm).
    Y,
    /// Linear Z (mm).
    Z,
    /// Rotary about X (degrees).
    A,
    /// Rotary about Y (degrees).
    B,
    /// Rotary about Z (degrees).
    C,
}

impl AxisLetter {
    /// All six axes in the order X Y Z A B C (the order of [`AxisLetter::index`]).
    pub const ALL: [AxisLetter; 6] = [
        AxisLetter::X,
        AxisLetter::Y,
        AxisLetter::Z,
        AxisLetter::A,
        AxisLetter::B,
        AxisLetter::C,
    ];

    /// Position of the axis in [`AxisLetter::ALL`] (X = 0 … C = 5).
    pub fn index(self) -> usize {
        match self {
            AxisLetter::X => 0,
            AxisLetter::Y => 1,
            AxisLetter::Z => 2,
            AxisLetter::A => 3,
            AxisLetter::B => 4,
            AxisLetter::C => 5,
        }
    }

    /// True for A, B, C (degrees), false for X, Y, Z (mm).
    pub fn is_rotary(self) -> bool {
        matches!(self, AxisLetter::A | AxisLetter::B | AxisLetter::C)
    }

    /// The axis named by `c` (case-insensitive), if any.
    pub fn from_char(c: char) -> Option<AxisLetter> {
        match c.to_ascii_uppercase() {
            'X' => Some(AxisLetter::X),
            'Y' => Some(AxisLetter::Y),
            'Z' => Some(AxisLetter::Z),
            'A' => Some(AxisLetter::A),
            'B' => Some(AxisLetter::B),
            'C' => Some(AxisLetter::C),
            _ => None,
        }
    }

    /// The upper-case letter of the axis.
    pub fn as_char(self) -> char {
        match self {
            AxisLetter::X => 'X',
            AxisLetter::Y => 'Y',
            AxisLetter::Z => 'Z',
            AxisLetter::A => 'A',
            AxisLetter::B => 'B',
            AxisLetter::C => 'C',
        }
    }
}

/// Values of all six axes: X Y Z in mm, A B C in degrees.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct AxisValues {
    values: [Real; 6],
}

impl AxisValues {
    /// Values from an array in the order X Y Z A B C.
    pub fn from_array(values: [Real; 6]) -> Self {
        Self { values }
    }

    /// The values as an array in the order X Y Z A B C.
    pub fn to_array(self) -> [Real; 6] {
        self.values
    }

    /// The value of axis `a`.
    pub fn get(&self, a: AxisLetter) -> Real {
        self.values[a.index()]
    }

    /// Sets the value of axis `a`.
    pub fn set(&mut self, a: AxisLetter, v: Real) {
        self.values[a.index()] = v;
    }

    /// A copy with axis `a` set to `v`.
    pub fn with(mut self, a: AxisLetter, v: Real) -> Self {
        self.set(a, v);
        self
    }
}

/// The length a feed-per-minute controller applies F to (LinuxCNC's, its interpreter's
/// `find_straight_length`): the XYZ length of a straight move (mm) when it is not zero,
/// else its A B C length (degrees).
pub fn controller_length(from: &AxisValues, to: &AxisValues) -> Real {
    let d = |ls: [AxisLetter; 3]| {
        ls.iter()
            .map(|&l| (to.get(l) - from.get(l)).powi(2))
            .sum::<Real>()
            .sqrt()
    };
    let xyz = d([AxisLetter::X, AxisLetter::Y, AxisLetter::Z]);
    if xyz > 0.0 {
        xyz
    } else {
        d([AxisLetter::A, AxisLetter::B, AxisLetter::C])
    }
}

/// Options from a tool table, var file and INI file (each optional), lengths in `unit`.
pub fn options_from_files(
    tool_table: Option<&Path>,
    var: Option<&Path>,
    ini: Option<&Path>,
    unit: LengthUnit,
) -> Result<InterpOptions, NcError> {
    fn read(p: Option<&Path>) -> Result<Option<String>, NcError> {
        p.map(|p| {
            std::fs::read_to_string(p).map_err(|e| file_error(p, 0, format!("cannot read: {e}")))
        })
        .transpose()
    }
    let (t, v, i) = (read(tool_table)?, read(var)?, read(ini)?);
    options_from_texts(
        t.as_deref().zip(tool_table),
        v.as_deref().zip(var),
        i.as_deref().zip(ini),
        unit,
    )
}

/// Options from the texts of a tool table, var file and INI file (each optional, with the
/// path that names it in messages and resolves the INI's folders), lengths in `unit`.
pub fn options_from_texts(
    tool_table: Option<(&str, &Path)>,
    var: Option<(&str, &Path)>,
    ini: Option<(&str, &Path)>,
    unit: LengthUnit,
) -> Result<InterpOptions, NcError> {
    let table = |e: TableError| file_error(Path::new(&e.path), e.line, e.message);
    let mut opts = InterpOptions {
        external_unit: unit,
        ..InterpOptions::default()
    };
    if let Some((text, p)) = tool_table {
        opts.tool_table = ToolTable::parse(text, p).map_err(table)?;
    }
    if let Some((text, p)) = var {
        opts.parameters = parse_var_file(text, p).map_err(table)?;
    }
    if let Some((text, p)) = ini {
        let settings = parse_ini(text, p);
        opts.apply_ini(&settings);
    }
    Ok(opts)
}

fn file_error(path: &Path, line: usize, message: String) -> NcError {
    NcError {
        diagnostics: vec![Diagnostic {
            path: path.to_path_buf(),
            line,
            column: 0,
            word: String::new(),
            message,
        }],
    }
}

/// Kind of motion of a [`Move`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum MoveKind {
    /// Rapid positioning (no programmed feed).
    Rapid,
    /// Straight interpolation at the programmed feed (also probe moves and the two strokes
    /// of a rigid tap).
    Linear,
    /// Circular or helical interpolation about the given machine-frame geometry; the axes
    /// not in the arc's plane (and A B C) move linearly with the swept angle.
    Arc(ArcGeom),
}

/// One move in machine axis space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Move {
    /// Rapid, linear or arc.
    pub kind: MoveKind,
    /// Position before the move.
    pub start: AxisValues,
    /// Position after the move (never equal to `start`, except for a full-circle arc).
    pub end: AxisValues,
    /// Programmed feed in mm/min for feed moves (always > 0); `None` for rapids.
    pub feed_mm_per_min: Option<Real>,
    /// 1-based source line of the block.
    pub line: usize,
}

impl Move {
    /// Position at fraction `lambda` ∈ [0, 1] of the move (along the arc for arcs: angle,
    /// radius, the normal coordinate and A B C vary linearly with `lambda`).
    pub fn point_at(&self, lambda: Real) -> AxisValues {
        let s = self.start.to_array();
        let e = self.end.to_array();
        let mut q = [0.0; 6];
        for (qi, (si, ei)) in q.iter_mut().zip(s.iter().zip(e.iter())) {
            *qi = si + (ei - si) * lambda;
        }
        if let MoveKind::Arc(a) = &self.kind {
            let n = a.normal.normalize();
            let c = a.center.coords;
            let ps = crate::math::Vector3::new(s[0], s[1], s[2]) - c;
            let pe = crate::math::Vector3::new(e[0], e[1], e[2]) - c;
            let hs = ps.dot(&n);
            let he = pe.dot(&n);
            let u_raw = ps - n * hs;
            let u = if u_raw.norm() > 0.0 {
                u_raw.normalize()
            } else {
                n.cross(&crate::math::Vector3::x()).normalize()
            };
            let v = n.cross(&u);
            let theta = a.sweep_deg.to_radians() * lambda;
            let r = a.radius + (a.radius_end - a.radius) * lambda;
            let h = hs + (he - hs) * lambda;
            let p = c + (u * theta.cos() + v * theta.sin()) * r + n * h;
            q[0] = p.x;
            q[1] = p.y;
            q[2] = p.z;
        }
        AxisValues::from_array(q)
    }
}

impl Move {
    /// How many pieces [`Move::chords`] gives: 1 for a straight move; for an arc, the
    /// fewest equal chords whose sagitta is at most `sagitta_mm`.
    pub fn chord_count(&self, sagitta_mm: Real) -> usize {
        match &self.kind {
            MoveKind::Arc(a) => {
                let r = a.radius.max(a.radius_end);
                let step = if r > sagitta_mm {
                    2.0 * (1.0 - sagitta_mm / r).acos()
                } else {
                    std::f64::consts::PI
                };
                let n = (a.sweep_deg.to_radians().abs() / step).ceil();
                if n.is_finite() {
                    (n as usize).clamp(1, 1_000_000)
                } else {
                    1
                }
            }
            _ => 1,
        }
    }

    /// The move as straight pieces: itself for a straight move; for an arc, chords whose
    /// sagitta (largest distance from the arc in its plane) is at most `sagitta_mm`
    /// (> 0), each a [`MoveKind::Linear`] move with the arc's feed and line.
    pub fn chords(&self, sagitta_mm: Real) -> impl Iterator<Item = Move> + '_ {
        let n = self.chord_count(sagitta_mm);
        let arc = matches!(self.kind, MoveKind::Arc(_));
        (0..n).map(move |i| {
            if !arc {
                return *self;
            }
            let (l0, l1) = (i as Real / n as Real, (i + 1) as Real / n as Real);
            Move {
                kind: MoveKind::Linear,
                start: if i == 0 {
                    self.start
                } else {
                    self.point_at(l0)
                },
                end: if i + 1 == n {
                    self.end
                } else {
                    self.point_at(l1)
                },
                feed_mm_per_min: self.feed_mm_per_min,
                line: self.line,
            }
        })
    }
}

/// A program interpreted in full (the collected form, for small programs).
#[derive(Clone, Debug, PartialEq)]
pub struct Program {
    /// File the program came from.
    pub path: PathBuf,
    /// The moves, in execution order (zero-length straight moves left out).
    pub moves: Vec<Move>,
    /// Sorted axes whose value changes in any move.
    pub axes_used: Vec<AxisLetter>,
    /// Line of the `M2`/`M30`/`%` that ended the program, if any.
    pub ended_by: Option<usize>,
}

/// Interprets program text with `opts` and collects the moves. `path` is used for
/// messages and to find subroutine files next to the program.
pub fn interpret_program(text: &str, path: &Path, opts: InterpOptions) -> Result<Program, NcError> {
    let start = opts.start;
    let mut moves = Vec::new();
    let mut ended_by = None;
    let mut changed = [false; 6];
    let mut last_end = start;
    let mut interp = Interpreter::from_text(text, path, opts);
    while let Some(rec) = interp.next_ref() {
        let rec = rec?;
        match &rec.body {
            RecordBody::Event(e) => {
                if e.call == "PROGRAM_END" {
                    ended_by = Some(rec.line);
                }
            }
            &RecordBody::Motion(m) => {
                let feed = m.feed.filter(|_| !m.feed_per_rev);
                let mut push = |kind: MoveKind, s: AxisValues, e: AxisValues, feed| {
                    let full = matches!(kind, MoveKind::Arc(_));
                    if s != e || full {
                        // An arc moves X, Y and Z even when it ends where it started (a full
                        // circle); the other axes only if their values change.
                        for (k, (c, (a, b))) in changed
                            .iter_mut()
                            .zip(s.to_array().iter().zip(e.to_array().iter()))
                            .enumerate()
                        {
                            *c |= a != b || (full && k < 3);
                        }
                        moves.push(Move {
                            kind,
                            start: s,
                            end: e,
                            feed_mm_per_min: feed,
                            line: rec.line,
                        });
                    }
                };
                // a jump left by rs274's simulated probe back-off
                if m.start != last_end {
                    push(MoveKind::Linear, last_end, m.start, feed.or(Some(1.0)));
                }
                match m.kind {
                    MotionKind::Rapid => push(MoveKind::Rapid, m.start, m.end, None),
                    MotionKind::Linear | MotionKind::Probe => {
                        push(MoveKind::Linear, m.start, m.end, feed.or(Some(1.0)))
                    }
                    MotionKind::Arc => {
                        if let Some(a) = m.arc {
                            push(MoveKind::Arc(a), m.start, m.end, feed.or(Some(1.0)))
                        }
                    }
                    MotionKind::RigidTap => {
                        push(MoveKind::Linear, m.start, m.end, Some(1.0));
                        push(MoveKind::Linear, m.end, m.start, Some(1.0));
                    }
                }
                last_end = if m.kind == MotionKind::RigidTap {
                    m.start
                } else {
                    m.end
                };
            }
        }
    }
    let axes_used = AxisLetter::ALL
        .iter()
        .zip(changed.iter())
        .filter(|(_, c)| **c)
        .map(|(a, _)| *a)
        .collect();
    Ok(Program {
        path: path.to_path_buf(),
        moves,
        axes_used,
        ended_by,
    })
}

/// Interprets program text with default options (tool table empty, mm external unit,
/// LinuxCNC dialect) starting at machine position `start`. Returns every problem of the
/// program at once (see the module documentation).
pub fn parse_program(text: &str, path: &Path, start: AxisValues) -> Result<Program, NcError> {
    interpret_program(
        text,
        path,
        InterpOptions {
            start,
            ..InterpOptions::default()
        },
    )
}

/// Sequence of JSON lines (see [`output`]) of a run; `events` includes non-motion records.
/// Stops at the first error, which is returned after the lines written so far.
pub fn write_jsonl(
    mut interp: Interpreter,
    events: bool,
    mut sink: impl FnMut(&[u8]) -> std::io::Result<()>,
) -> Result<Result<(), NcError>, std::io::Error> {
    let mut seq = 0;
    let mut line = Vec::with_capacity(512);
    let mut memo = output::PointMemo::default();
    while let Some(rec) = interp.next_ref() {
        let rec = match rec {
            Ok(r) => r,
            Err(e) => return Ok(Err(e)),
        };
        if !events && matches!(rec.body, RecordBody::Event(_)) {
            continue;
        }
        line.clear();
        output::write_json_with(&mut line, seq, rec, &mut memo);
        line.push(b'\n');
        seq += 1;
        sink(&line)?;
    }
    Ok(Ok(()))
}

#[cfg(test)]
mod tests;
