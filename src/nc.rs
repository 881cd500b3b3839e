//! A minimal, strict RS274/NGC (LinuxCNC dialect) reader for a milling machine.
//!
//! The supported subset is small and every block outside it is rejected with a precise
//! [`Diagnostic`] (file, 1-based line, 1-based column, offending word as written).
//!
//! # Supported
//!
//! * `G0`, `G1` (motion, modal) with axis words `X Y Z A B C`;
//! * `G90` / `G91` (absolute / incremental distance, modal; default `G90`);
//! * `G20` / `G21` (inch / mm, modal; default `G21`); `X Y Z` are scaled by 25.4 under
//!   `G20`, `A B C` are degrees and never scaled;
//! * `F` (feed in current units per minute, stored as mm/min; modal; `F0` is allowed but a
//!   `G1` move with a zero feed rate is an error; a negative `F` is an error);
//! * `N` line numbers (ignored; any non-negative number, anywhere in the block);
//! * `M2`, `M30` (end of program: the block is executed, later lines are not even read);
//! * comments `( ... )` (no nesting; unclosed is an error) and `;` to end of line;
//! * a line whose first token is `%` (program delimiter; skipped, only comments may follow).
//!
//! Letters are case-insensitive; spaces and tabs are ignored anywhere inside a number and
//! between a letter and its number (`G 1 X - 3 0 . 5` is `G1 X-30.5`). Numbers are an
//! optional sign, then digits with at most one decimal point (`1`, `1.`, `.5`, `-0.25`,
//! `+3`); exponents are not RS274 (`1e5` reads `E` as an unsupported word). A `G` or `M`
//! number is compared by value, so `G01`, `G1.`, `G1.0` all mean `G1`, while `G1.5` or
//! `G-1` are unsupported.
//!
//! # Block semantics
//!
//! Within a block, units, distance mode and feed take effect before the motion of that
//! block, whatever the word order. Two words of one modal group (`G0 G1`, `G90 G91`,
//! `G20 G21`, two `M` words) or one letter twice (`X1 X2`, `F1 F2`, `N1 N2`) is an error.
//! Axis words with no motion mode in effect are an error. A block whose axis words give an
//! end position exactly equal to the current one emits **no** [`Move`] (its axis letters
//! still count in [`Program::axes_used`]).
//!
//! # Errors
//!
//! Every line is checked and all errors are reported together in an [`NcError`]. The first
//! error of a line ends the checking of that line; an erroneous line contributes no move and
//! no modal change, as if it were absent (so an `M2`/`M30` on an erroneous line does not end
//! the program). Columns count Unicode scalar values (characters), not bytes. Non-finite
//! values (a number with hundreds of digits, or a position or feed that overflows after
//! unit conversion or incremental accumulation) are errors naming the word.

use std::path::{Path, PathBuf};

use crate::math::Real;

/// Millimetres per inch (exact by definition).
const MM_PER_INCH: Real = 25.4;

/// Words longer than this many characters are shortened inside messages (the full word
/// stays in [`Diagnostic::word`]).
const MAX_WORD_IN_MESSAGE: usize = 64;

/// One problem found in a program.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{path}:{line}:{column}: {message}")]
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

/// Kind of motion.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MoveKind {
    /// `G0`: rapid positioning (no programmed feed).
    Rapid,
    /// `G1`: linear interpolation at the programmed feed.
    Linear,
}

/// One straight move in machine axis space (axes interpolated linearly from start to end).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Move {
    /// Rapid or linear.
    pub kind: MoveKind,
    /// Position before the move.
    pub start: AxisValues,
    /// Position after the move (never equal to `start`).
    pub end: AxisValues,
    /// Programmed feed in mm/min for linear moves (always > 0); `None` for rapids.
    pub feed_mm_per_min: Option<Real>,
    /// 1-based source line of the block.
    pub line: usize,
}

/// A parsed program.
#[derive(Clone, Debug, PartialEq)]
pub struct Program {
    /// File the program came from.
    pub path: PathBuf,
    /// The moves, in execution order.
    pub moves: Vec<Move>,
    /// Sorted, deduplicated letters that appear in any executed axis word.
    pub axes_used: Vec<AxisLetter>,
    /// Line of the `M2`/`M30` that ended the program, if any.
    pub ended_by: Option<usize>,
}

/// Parses program text. `path` is only used for messages. `start` is the machine position
/// before the first move (all six axes).
///
/// Returns every problem of the program at once (see the module documentation).
pub fn parse_program(text: &str, path: &Path, start: AxisValues) -> Result<Program, NcError> {
    let mut state = ModalState {
        pos: start,
        motion: None,
        incremental: false,
        inch: false,
        feed_mm_per_min: 0.0,
    };
    let mut moves = Vec::new();
    let mut used = [false; 6];
    let mut ended_by = None;
    let mut diagnostics = Vec::new();

    for (index, line_text) in text.lines().enumerate() {
        let line = index + 1;
        let chars: Vec<char> = line_text.chars().collect();
        let block = match scan_block(&chars) {
            Ok(block) => block,
            Err(e) => {
                diagnostics.push(e.into_diagnostic(path, line));
                continue;
            }
        };
        match execute_block(&block, &state, line) {
            Ok(outcome) => {
                state = outcome.state;
                if let Some(m) = outcome.mv {
                    moves.push(m);
                }
                for (u, named) in used.iter_mut().zip(block.axes.iter()) {
                    *u |= named.is_some();
                }
                if block.end.is_some() {
                    ended_by = Some(line);
                    break;
                }
            }
            Err(e) => diagnostics.push(e.into_diagnostic(path, line)),
        }
    }

    if !diagnostics.is_empty() {
        return Err(NcError { diagnostics });
    }
    let axes_used = AxisLetter::ALL
        .iter()
        .zip(used.iter())
        .filter(|(_, u)| **u)
        .map(|(a, _)| *a)
        .collect();
    Ok(Program {
        path: path.to_path_buf(),
        moves,
        axes_used,
        ended_by,
    })
}

// ---------------------------------------------------------------------------------------
// Modal state and block execution
// ---------------------------------------------------------------------------------------

/// The interpreter state carried from block to block.
#[derive(Clone, Copy, Debug)]
struct ModalState {
    pos: AxisValues,
    motion: Option<MoveKind>,
    incremental: bool,
    inch: bool,
    feed_mm_per_min: Real,
}

/// What a correct block does.
struct Outcome {
    state: ModalState,
    mv: Option<Move>,
}

/// A word as written: its 1-based column and its source text.
#[derive(Clone, Debug)]
struct WordRef {
    column: usize,
    text: String,
}

/// An error located on the current line (the line number and path are added later).
#[derive(Debug)]
struct LineError {
    column: usize,
    word: String,
    message: String,
}

impl LineError {
    /// An error whose message is `what "word"` followed by `detail` (may be empty).
    fn new(column: usize, word: String, what: &str, detail: &str) -> Self {
        let message = format!("{what} {}{detail}", quoted(&word));
        Self {
            column,
            word,
            message,
        }
    }

    fn at(w: &WordRef, what: &str, detail: &str) -> Self {
        Self::new(w.column, w.text.clone(), what, detail)
    }

    fn into_diagnostic(self, path: &Path, line: usize) -> Diagnostic {
        Diagnostic {
            path: path.to_path_buf(),
            line,
            column: self.column,
            word: self.word,
            message: self.message,
        }
    }
}

/// `"word"`, shortened if very long.
fn quoted(word: &str) -> String {
    if word.chars().count() > MAX_WORD_IN_MESSAGE {
        let head: String = word.chars().take(MAX_WORD_IN_MESSAGE).collect();
        format!("\"{head}...\"")
    } else {
        format!("\"{word}\"")
    }
}

/// The words of one block, sorted by role.
#[derive(Default, Debug)]
struct Block {
    motion: Option<(MoveKind, WordRef)>,
    distance_incremental: Option<(bool, WordRef)>,
    units_inch: Option<(bool, WordRef)>,
    feed: Option<(Real, WordRef)>,
    end: Option<WordRef>,
    line_number: Option<WordRef>,
    axes: [Option<(Real, WordRef)>; 6],
    /// The first axis word in source order.
    first_axis: Option<WordRef>,
}

/// Applies a syntactically correct block to `state`.
fn execute_block(block: &Block, state: &ModalState, line: usize) -> Result<Outcome, LineError> {
    let mut next = *state;
    if let Some((inch, _)) = &block.units_inch {
        next.inch = *inch;
    }
    if let Some((incremental, _)) = &block.distance_incremental {
        next.incremental = *incremental;
    }
    let scale = if next.inch { MM_PER_INCH } else { 1.0 };
    if let Some((f, w)) = &block.feed {
        let mm = f * scale;
        if !mm.is_finite() {
            return Err(LineError::at(w, "feed rate out of range:", ""));
        }
        next.feed_mm_per_min = mm;
    }
    if let Some((kind, _)) = &block.motion {
        next.motion = Some(*kind);
    }

    let Some(first_axis) = &block.first_axis else {
        return Ok(Outcome {
            state: next,
            mv: None,
        });
    };
    let Some(kind) = next.motion else {
        return Err(LineError::at(
            first_axis,
            "axis word",
            " with no motion mode in effect (no G0/G1 on this or an earlier line)",
        ));
    };
    if kind == MoveKind::Linear && next.feed_mm_per_min <= 0.0 {
        let culprit = match &block.motion {
            Some((_, w)) => w,
            None => first_axis,
        };
        return Err(LineError::at(
            culprit,
            "G1 with zero feed rate at",
            " (no F word, or F0, given yet)",
        ));
    }

    let mut end = next.pos;
    for (axis, slot) in AxisLetter::ALL.iter().zip(block.axes.iter()) {
        let Some((value, w)) = slot else { continue };
        let v = if axis.is_rotary() {
            *value
        } else {
            value * scale
        };
        let target = if next.incremental {
            next.pos.get(*axis) + v
        } else {
            v
        };
        if !target.is_finite() {
            return Err(LineError::at(w, "position out of range at", ""));
        }
        end.set(*axis, target);
    }

    let mv = (end != next.pos).then_some(Move {
        kind,
        start: next.pos,
        end,
        feed_mm_per_min: match kind {
            MoveKind::Rapid => None,
            MoveKind::Linear => Some(next.feed_mm_per_min),
        },
        line,
    });
    next.pos = end;
    Ok(Outcome { state: next, mv })
}

// ---------------------------------------------------------------------------------------
// Lexing a line
// ---------------------------------------------------------------------------------------

/// Spaces and tabs (and a stray carriage return) are ignored between tokens and inside
/// numbers.
fn is_blank(c: char) -> bool {
    c == ' ' || c == '\t' || c == '\r'
}

/// Index of the first non-blank character at or after `i` (may be `chars.len()`).
fn skip_blanks(chars: &[char], mut i: usize) -> usize {
    while chars.get(i).is_some_and(|c| is_blank(*c)) {
        i += 1;
    }
    i
}

/// Source text of `chars[from..to]` (empty if the range is invalid).
fn text_of(chars: &[char], from: usize, to: usize) -> String {
    chars.get(from..to).unwrap_or_default().iter().collect()
}

/// Index just after the last non-blank character in `chars[from..to]`, or `from`.
fn trim_end(chars: &[char], from: usize, mut to: usize) -> usize {
    while to > from && chars.get(to - 1).is_some_and(|c| is_blank(*c)) {
        to -= 1;
    }
    to
}

/// Why a number could not be read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum NumberError {
    /// Nothing that looks like a number.
    Missing,
    /// A sign without digits, or two decimal points.
    Malformed,
    /// Parses to infinity.
    OutOfRange,
}

/// A number read from the source.
#[derive(Debug, Clone, Copy)]
struct Number {
    value: Real,
    negative: bool,
}

/// What follows a letter.
enum WordValue {
    Number(Result<Number, NumberError>),
    Expression,
    Parameter,
}

/// Reads a number starting at `start` (blanks allowed anywhere). Returns the result and
/// the index just after the last non-blank character consumed (`start` if none).
fn scan_number(chars: &[char], start: usize) -> (Result<Number, NumberError>, usize) {
    let mut i = skip_blanks(chars, start);
    let mut end = start;
    let mut literal = String::new();
    let mut negative = false;
    let mut consumed = false;
    if let Some(&c) = chars.get(i)
        && (c == '+' || c == '-')
    {
        negative = c == '-';
        if negative {
            literal.push('-');
        }
        consumed = true;
        i += 1;
        end = i;
    }
    let mut digits = 0usize;
    let mut points = 0usize;
    while let Some(&c) = chars.get(i) {
        if c.is_ascii_digit() {
            digits += 1;
        } else if c == '.' {
            points += 1;
        } else if !is_blank(c) {
            break;
        }
        if !is_blank(c) {
            literal.push(c);
            consumed = true;
            end = i + 1;
        }
        i += 1;
    }
    let result = if !consumed {
        Err(NumberError::Missing)
    } else if digits == 0 || points > 1 {
        Err(NumberError::Malformed)
    } else {
        match literal.parse::<Real>() {
            Ok(v) if v.is_finite() => Ok(Number { value: v, negative }),
            Ok(_) => Err(NumberError::OutOfRange),
            Err(_) => Err(NumberError::Malformed),
        }
    };
    (result, end)
}

/// End (exclusive) of a bracketed expression starting at `start` (which holds `[`): just
/// after the matching `]`, or the trimmed end of the line if unmatched.
fn bracket_end(chars: &[char], start: usize) -> usize {
    let mut depth = 0usize;
    let mut i = start;
    while let Some(&c) = chars.get(i) {
        if c == '[' {
            depth += 1;
        } else if c == ']' {
            depth = depth.saturating_sub(1);
            if depth == 0 {
                return i + 1;
            }
        }
        i += 1;
    }
    trim_end(chars, start, chars.len())
}

/// End (exclusive) of a parameter reference starting at `start` (which holds `#`):
/// `#<name>` or `#` followed by a number.
fn parameter_end(chars: &[char], start: usize) -> usize {
    let next = skip_blanks(chars, start + 1);
    if chars.get(next) == Some(&'<') {
        let mut i = next;
        while let Some(&c) = chars.get(i) {
            if c == '>' {
                return i + 1;
            }
            i += 1;
        }
        return trim_end(chars, start, chars.len());
    }
    let (_, end) = scan_number(chars, start + 1);
    end.max(start + 1)
}

/// Reads what follows a letter at `after` (index after the letter): its kind and end.
fn scan_word_value(chars: &[char], after: usize) -> (WordValue, usize) {
    let k = skip_blanks(chars, after);
    match chars.get(k) {
        Some('[') => (WordValue::Expression, bracket_end(chars, k)),
        Some('#') => (WordValue::Parameter, parameter_end(chars, k)),
        _ => {
            let (n, end) = scan_number(chars, after);
            (WordValue::Number(n), end)
        }
    }
}

/// Tokenizes and classifies one line. The first error ends the line.
fn scan_block(chars: &[char]) -> Result<Block, LineError> {
    let mut block = Block::default();
    let mut i = 0usize;
    let mut seen_word = false;
    let mut percent_line = false;
    while let Some(&c) = chars.get(i) {
        if is_blank(c) {
            i += 1;
            continue;
        }
        let column = i + 1;
        match c {
            '(' => i = comment_end(chars, i)?,
            ';' => break,
            '%' if !seen_word && !percent_line => {
                percent_line = true;
                i += 1;
            }
            '[' => {
                let end = bracket_end(chars, i);
                return Err(LineError::new(
                    column,
                    text_of(chars, i, end),
                    "expressions are not supported:",
                    "",
                ));
            }
            '#' => {
                let end = parameter_end(chars, i);
                return Err(LineError::new(
                    column,
                    text_of(chars, i, end),
                    "parameters are not supported:",
                    "",
                ));
            }
            '/' => {
                return Err(LineError::new(
                    column,
                    "/".to_owned(),
                    "block delete is not supported:",
                    "",
                ));
            }
            c if c.is_ascii_alphabetic() => {
                let (value, end) = scan_word_value(chars, i + 1);
                let word = WordRef {
                    column,
                    text: text_of(chars, i, end.max(i + 1)),
                };
                if percent_line {
                    return Err(LineError::at(
                        &word,
                        "unexpected word",
                        " on a '%' delimiter line",
                    ));
                }
                seen_word = true;
                classify_word(&mut block, c.to_ascii_uppercase(), value, word)?;
                i = end.max(i + 1);
            }
            other => {
                return Err(LineError::new(
                    column,
                    other.to_string(),
                    "unexpected character",
                    "",
                ));
            }
        }
    }
    Ok(block)
}

/// Index just after the `)` closing the comment opened at `open`.
fn comment_end(chars: &[char], open: usize) -> Result<usize, LineError> {
    let mut j = open + 1;
    loop {
        match chars.get(j) {
            Some(')') => return Ok(j + 1),
            Some('(') => {
                return Err(LineError::new(
                    j + 1,
                    "(".to_owned(),
                    "nested comment:",
                    " (comments cannot contain '(')",
                ));
            }
            Some(_) => j += 1,
            None => {
                let end = trim_end(chars, open, chars.len());
                return Err(LineError::new(
                    open + 1,
                    text_of(chars, open, end),
                    "unclosed comment",
                    " (missing ')')",
                ));
            }
        }
    }
}

/// Records the word `letter`+`value` (written as `word`) into `block`.
fn classify_word(
    block: &mut Block,
    letter: char,
    value: WordValue,
    word: WordRef,
) -> Result<(), LineError> {
    let supported =
        matches!(letter, 'G' | 'M' | 'N' | 'F') || AxisLetter::from_char(letter).is_some();
    if !supported {
        return Err(LineError::at(
            &word,
            "unsupported word",
            " (supported letters: G M N F X Y Z A B C)",
        ));
    }
    let number = match value {
        WordValue::Expression => {
            return Err(LineError::at(&word, "expressions are not supported:", ""));
        }
        WordValue::Parameter => {
            return Err(LineError::at(&word, "parameters are not supported:", ""));
        }
        WordValue::Number(Err(NumberError::Missing)) => {
            return Err(LineError::at(&word, "missing number after letter in", ""));
        }
        WordValue::Number(Err(NumberError::Malformed)) => {
            return Err(LineError::at(&word, "malformed number in", ""));
        }
        WordValue::Number(Err(NumberError::OutOfRange)) => {
            return Err(LineError::at(&word, "number out of range in", ""));
        }
        WordValue::Number(Ok(n)) => n,
    };

    match letter {
        'G' => classify_g(block, number, word),
        'M' => {
            if number.negative || !(number.value == 2.0 || number.value == 30.0) {
                return Err(LineError::at(
                    &word,
                    "unsupported M-code",
                    " (supported: M2 M30)",
                ));
            }
            if let Some(prev) = &block.end {
                return Err(conflict(&word, prev));
            }
            block.end = Some(word);
            Ok(())
        }
        'N' => {
            if number.negative {
                return Err(LineError::at(&word, "negative line number", ""));
            }
            if block.line_number.is_some() {
                return Err(LineError::at(&word, "duplicate word", " (letter N twice)"));
            }
            block.line_number = Some(word);
            Ok(())
        }
        'F' => {
            if number.negative && number.value != 0.0 {
                return Err(LineError::at(&word, "negative feed rate", ""));
            }
            if block.feed.is_some() {
                return Err(LineError::at(&word, "duplicate word", " (letter F twice)"));
            }
            block.feed = Some((number.value.abs(), word));
            Ok(())
        }
        _ => {
            let Some(axis) = AxisLetter::from_char(letter) else {
                // Unreachable: `supported` checked above; report rather than panic.
                return Err(LineError::at(&word, "unsupported word", ""));
            };
            let Some(slot) = block.axes.get_mut(axis.index()) else {
                return Err(LineError::at(&word, "unsupported word", ""));
            };
            if slot.is_some() {
                let detail = format!(" (letter {} twice)", axis.as_char());
                return Err(LineError::at(&word, "duplicate word", &detail));
            }
            if block.first_axis.is_none() {
                block.first_axis = Some(word.clone());
            }
            *slot = Some((number.value, word));
            Ok(())
        }
    }
}

/// The error for `word` colliding with `prev` of the same modal group.
fn conflict(word: &WordRef, prev: &WordRef) -> LineError {
    let detail = format!(
        " conflicts with {} earlier in the block (same modal group)",
        quoted(&prev.text)
    );
    LineError::at(word, "word", &detail)
}

/// Records a G word.
fn classify_g(block: &mut Block, number: Number, word: WordRef) -> Result<(), LineError> {
    const SUPPORTED: &str = " (supported: G0 G1 G20 G21 G90 G91)";
    if number.negative {
        return Err(LineError::at(&word, "unsupported G-code", SUPPORTED));
    }
    let v = number.value;
    if v == 0.0 || v == 1.0 {
        let kind = if v == 0.0 {
            MoveKind::Rapid
        } else {
            MoveKind::Linear
        };
        if let Some((_, prev)) = &block.motion {
            return Err(conflict(&word, prev));
        }
        block.motion = Some((kind, word));
    } else if v == 20.0 || v == 21.0 {
        if let Some((_, prev)) = &block.units_inch {
            return Err(conflict(&word, prev));
        }
        block.units_inch = Some((v == 20.0, word));
    } else if v == 90.0 || v == 91.0 {
        if let Some((_, prev)) = &block.distance_incremental {
            return Err(conflict(&word, prev));
        }
        block.distance_incremental = Some((v == 91.0, word));
    } else {
        return Err(LineError::at(&word, "unsupported G-code", SUPPORTED));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn prog_path() -> &'static Path {
        Path::new("prog.ngc")
    }

    fn parse(input: &str) -> Result<Program, NcError> {
        parse_program(input, prog_path(), AxisValues::default())
    }

    /// Formats a number compactly (6 decimals, trailing zeros removed).
    fn num(v: Real) -> String {
        let s = format!("{v:.6}");
        let s = s.trim_end_matches('0').trim_end_matches('.');
        if s == "-0" {
            "0".to_owned()
        } else {
            s.to_owned()
        }
    }

    /// Renders a result: one line per move (`line G0|G1 <non-zero end axes> [F]`), or one
    /// line per diagnostic (`line:column word`).
    fn render(result: &Result<Program, NcError>) -> String {
        let mut lines = Vec::new();
        match result {
            Ok(p) => {
                for m in &p.moves {
                    let mut s = format!(
                        "{} {}",
                        m.line,
                        match m.kind {
                            MoveKind::Rapid => "G0",
                            MoveKind::Linear => "G1",
                        }
                    );
                    for a in AxisLetter::ALL {
                        let v = m.end.get(a);
                        if v != 0.0 {
                            s.push_str(&format!(" {}{}", a.as_char(), num(v)));
                        }
                    }
                    if let Some(f) = m.feed_mm_per_min {
                        s.push_str(&format!(" F{}", num(f)));
                    }
                    lines.push(s);
                }
            }
            Err(e) => {
                for d in &e.diagnostics {
                    lines.push(format!("{}:{} {}", d.line, d.column, d.word));
                }
            }
        }
        lines.join("\n")
    }

    /// Parses `input` from the origin and compares the rendering with `expected`
    /// (whose lines are trimmed).
    fn check(input: &str, expected: &str) {
        let got = render(&parse(input));
        let want: Vec<&str> = expected
            .lines()
            .map(str::trim)
            .filter(|l| !l.is_empty())
            .collect();
        assert_eq!(got, want.join("\n"), "input:\n{input}");
    }

    /// Parses `input`, expects an error, returns the diagnostics.
    fn errors(input: &str) -> Vec<Diagnostic> {
        match parse(input) {
            Ok(p) => panic!("expected errors for {input:?}, got {p:?}"),
            Err(e) => e.diagnostics,
        }
    }

    // ---- supported words ---------------------------------------------------------------

    #[test]
    fn g0_rapid() {
        check("G0 X1 Y2 Z3", "1 G0 X1 Y2 Z3");
    }

    #[test]
    fn g1_linear_with_feed() {
        check("G1 X1 F100", "1 G1 X1 F100");
    }

    #[test]
    fn all_six_axes() {
        check("G0 X1 Y2 Z3 A4 B5 C6", "1 G0 X1 Y2 Z3 A4 B5 C6");
        let p = parse("G0 X1 Y2 Z3 A4 B5 C6").unwrap();
        assert_eq!(p.axes_used, AxisLetter::ALL.to_vec());
    }

    #[test]
    fn leading_zero_codes_and_decimal_g() {
        check(
            "G00 X1\nG01 F10 X2\nG1.0 X3\nG1. X4",
            "1 G0 X1\n2 G1 X2 F10\n3 G1 X3 F10\n4 G1 X4 F10",
        );
    }

    #[test]
    fn number_forms() {
        check(
            "G0 X1.\nX.5\nX-0.25\nX+3\nX007",
            "1 G0 X1\n2 G0 X0.5\n3 G0 X-0.25\n4 G0 X3\n5 G0 X7",
        );
    }

    #[test]
    fn line_numbers_ignored() {
        check("N10 G0 X1\nN20.5 X2\nn 3 0 X3", "1 G0 X1\n2 G0 X2\n3 G0 X3");
    }

    #[test]
    fn modal_carry_over() {
        check(
            "G1 F200 X1\nY2\nX3 Y4\nG0 Z5\nZ6",
            "1 G1 X1 F200\n2 G1 X1 Y2 F200\n3 G1 X3 Y4 F200\n4 G0 X3 Y4 Z5\n5 G0 X3 Y4 Z6",
        );
    }

    #[test]
    fn mode_set_without_axis_words() {
        check("G1 F100\nX1\nG0\nY1", "2 G1 X1 F100\n4 G0 X1 Y1");
    }

    #[test]
    fn move_start_is_previous_end_and_given_start() {
        let start = AxisValues::from_array([10.0, 20.0, 30.0, 40.0, 50.0, 60.0]);
        let p = parse_program("G91 G0 X1\nG90 A0", prog_path(), start).unwrap();
        assert_eq!(p.moves.len(), 2);
        assert_eq!(p.moves[0].start, start);
        assert_eq!(p.moves[0].end, start.with(AxisLetter::X, 11.0));
        assert_eq!(p.moves[1].start, p.moves[0].end);
        assert_eq!(p.moves[1].end, p.moves[0].end.with(AxisLetter::A, 0.0));
        assert_eq!(p.axes_used, vec![AxisLetter::X, AxisLetter::A]);
    }

    #[test]
    fn zero_displacement_emits_no_move() {
        let p = parse("G0 X0 Y0\nG91 Z0").unwrap();
        assert!(p.moves.is_empty());
        assert_eq!(
            p.axes_used,
            vec![AxisLetter::X, AxisLetter::Y, AxisLetter::Z]
        );
        check("G0 X1\nX1\nX2", "1 G0 X1\n3 G0 X2");
    }

    #[test]
    fn g91_accumulates() {
        check(
            "G91 G0 X1\nX1\nX1 Y-2\nG1 F60 A90\nA90",
            "1 G0 X1\n2 G0 X2\n3 G0 X3 Y-2\n4 G1 X3 Y-2 A90 F60\n5 G1 X3 Y-2 A180 F60",
        );
    }

    #[test]
    fn g90_returns_to_absolute() {
        check("G91 G0 X1\nX1\nG90 X5\nX5", "1 G0 X1\n2 G0 X2\n3 G0 X5");
    }

    #[test]
    fn g20_converts_lengths_and_feed_not_angles() {
        check("G20 G1 F10 X1 A1", "1 G1 X25.4 A1 F254");
        check(
            "G20 G91 G0 X1\nX1\nG21 X1",
            "1 G0 X25.4\n2 G0 X50.8\n3 G0 X51.8",
        );
    }

    #[test]
    fn feed_keeps_physical_value_across_unit_change() {
        check("G20 F10 G1 X1\nG21 X30", "1 G1 X25.4 F254\n2 G1 X30 F254");
        check("F10 G20 G1 X1", "1 G1 X25.4 F254");
    }

    #[test]
    fn block_modes_take_effect_before_motion_regardless_of_order() {
        check("G1 F10 X1 G20", "1 G1 X25.4 F254");
        check("G0 X1\nX1 G91", "1 G0 X1\n2 G0 X2");
        check("X1 F5 G1", "1 G1 X1 F5");
    }

    #[test]
    fn default_modes_are_g21_g90() {
        check("G0 X2\nX3", "1 G0 X2\n2 G0 X3");
    }

    #[test]
    fn comments_and_semicolons() {
        check(
            "G0 (move) X1 ; trailing (not a comment\n(only a comment)\n; only semi\nG0(c)X2(d)",
            "1 G0 X1\n4 G0 X2",
        );
        // A comment may not split a word.
        check("G0 X(mid)2", "1:4 X");
    }

    #[test]
    fn percent_lines_and_blank_lines() {
        check("%\n\nG0 X1\n  \n% (end)\n", "3 G0 X1");
    }

    #[test]
    fn program_end_stops_reading() {
        let p = parse("G0 X1\nM30\nG2 X5 $$$ [garbage\nX9").unwrap();
        assert_eq!(p.ended_by, Some(2));
        assert_eq!(render(&Ok(p)), "1 G0 X1");
        let p = parse("G0 X1 M02\nX2").unwrap();
        assert_eq!(p.ended_by, Some(1));
        assert_eq!(render(&Ok(p)), "1 G0 X1");
        let p = parse("m2").unwrap();
        assert_eq!(p.ended_by, Some(1));
        assert_eq!(parse("G0 X1").unwrap().ended_by, None);
    }

    #[test]
    fn spaces_inside_numbers() {
        check("G 1 X - 3 0 . 5 F 1 00", "1 G1 X-30.5 F100");
        check("\tG0\tX 1\t2", "1 G0 X12");
    }

    #[test]
    fn lower_case() {
        check("g1 x1 y2 z3 a4 b5 c6 f100", "1 G1 X1 Y2 Z3 A4 B5 C6 F100");
    }

    #[test]
    fn crlf_line_endings() {
        check("G0 X1\r\nX2\r\n", "1 G0 X1\n2 G0 X2");
    }

    #[test]
    fn f0_allowed_for_rapids() {
        check("F0 G0 X1", "1 G0 X1");
    }

    // ---- errors ------------------------------------------------------------------------

    #[test]
    fn same_modal_group_conflicts() {
        check("G0 G1 X1", "1:4 G1");
        check("G90 G91", "1:5 G91");
        check("G20 G21", "1:5 G21");
        check("G1 G1 F1 X1", "1:4 G1");
        check("M2 M30", "1:4 M30");
    }

    #[test]
    fn duplicate_letters() {
        check("G0 X1 X2", "1:7 X2");
        check("G1 F1 F2 X1", "1:7 F2");
        check("N1 N2", "1:4 N2");
        let d = errors("G0 a1 A2");
        assert!(d[0].message.contains("\"A2\""), "{}", d[0].message);
    }

    #[test]
    fn axis_word_without_motion_mode() {
        check("X1", "1:1 X1");
        check("F100 Y2", "1:6 Y2");
        check("G91 Z1 X1", "1:5 Z1");
        let d = errors("X1");
        assert!(d[0].message.contains("motion mode"), "{}", d[0].message);
    }

    #[test]
    fn g1_without_feed() {
        check("G1 X1", "1:1 G1");
        check("G1 F0 X1", "1:1 G1");
        check("G1\nX1", "2:1 X1");
        check("G1 F100 X1\nF0 X2", "2:4 X2");
        let d = errors("G1 X1");
        assert!(
            d[0].message.contains("G1 with zero feed rate"),
            "{}",
            d[0].message
        );
    }

    #[test]
    fn negative_feed() {
        check("F-1", "1:1 F-1");
        check("G1 F - 5 X1", "1:4 F - 5");
        // -0 is zero, not negative.
        check("G0 F-0 X1", "1 G0 X1");
    }

    #[test]
    fn unsupported_words() {
        check("G2 X1", "1:1 G2");
        check("G0 X1\nM3", "2:1 M3");
        check("S1000", "1:1 S1000");
        check("G0 T1", "1:4 T1");
        check("G0 #1", "1:4 #1");
        check("G0 X#<len>", "1:4 X#<len>");
        check("[1+2]", "1:1 [1+2]");
        check("G0 X[1+2]", "1:4 X[1+2]");
        check("/G0 X1", "1:1 /");
        check("G0 X1 $", "1:7 $");
        check("G17", "1:1 G17");
        check("G1.5", "1:1 G1.5");
        check("G-1", "1:1 G-1");
        check("O100 sub", "1:1 O100");
        check("G0 X1e5", "1:6 e5");
        check("G0 X1 )", "1:7 )");
        check("G0 X1 %", "1:7 %");
        check("% G0", "1:3 G0");
        for letter in "DEHIJKLPQRUVW".chars() {
            check(&format!("G0 {letter}1"), &format!("1:4 {letter}1"));
        }
    }

    #[test]
    fn unsupported_messages_quote_the_word() {
        let d = errors("G2 X1");
        assert_eq!(d[0].word, "G2");
        assert!(d[0].message.contains("\"G2\""));
        let d = errors("M3");
        assert!(d[0].message.contains("\"M3\""));
        let d = errors("S1000");
        assert!(d[0].message.contains("\"S1000\""));
    }

    #[test]
    fn malformed_numbers() {
        check("G0 X1.2.3", "1:4 X1.2.3");
        check("G0 X", "1:4 X");
        check("G0 X-", "1:4 X-");
        check("G0 X.", "1:4 X.");
        check("G0 X Y1", "1:4 X");
        check("G", "1:1 G");
    }

    #[test]
    fn overflowing_numbers_are_rejected() {
        let big = "9".repeat(400);
        let d = errors(&format!("G0 X{big}"));
        assert_eq!(d.len(), 1);
        assert_eq!(d[0].word, format!("X{big}"));
        assert_eq!((d[0].line, d[0].column), (1, 4));
        assert!(d[0].message.contains("out of range"));
        assert!(
            d[0].message.len() < 200,
            "long words are shortened in messages"
        );

        // Finite as typed but infinite after inch conversion or accumulation.
        let e307 = format!("1{}", "0".repeat(307));
        check(&format!("G20 G0 X{e307}"), &format!("1:8 X{e307}"));
        let lines = vec![format!("G91 G0 X{e307}"); 20].join("\n");
        let d = errors(&lines);
        assert_eq!(d.len(), 3, "lines 18..=20 overflow: {d:?}");
        assert_eq!(d[0].line, 18);
        let d = errors(&format!("G20 F{e307}"));
        assert_eq!(d[0].column, 5);
    }

    #[test]
    fn comment_errors() {
        check("G0 X1 (oops", "1:7 (oops");
        check("G0 (a (b) c) X1", "1:7 (");
        let d = errors("(never closed   ");
        assert_eq!(d[0].word, "(never closed");
        assert!(d[0].message.contains("unclosed comment"));
    }

    #[test]
    fn all_errors_are_reported() {
        let program = "G0 X1\nG2 X2\nX3\nM3\nS100 X5\nG0 Y1";
        check(program, "2:1 G2\n4:1 M3\n5:1 S100");
    }

    #[test]
    fn error_line_leaves_modal_state_untouched() {
        // Line 2 fails; its G91 must not take effect, nor its move.
        check("G0 X1\nG91 G2 X1\nX2", "2:5 G2");
        let text = "G0 X1\nG91 X1 T1\nX2";
        let d = errors(text);
        assert_eq!(d.len(), 1);
        let fixed = "G0 X1\nX2";
        check(fixed, "1 G0 X1\n2 G0 X2");
        // Axis words after an erroneous first motion line have no motion mode.
        check("G0 X1 X2\nY3", "1:7 X2\n2:1 Y3");
        // An M30 on an erroneous line does not end the program.
        check("M30 G2\nG5", "1:5 G2\n2:1 G5");
    }

    #[test]
    fn only_first_error_of_a_line() {
        let d = errors("G2 M3 S1");
        assert_eq!(d.len(), 1);
        assert_eq!(d[0].word, "G2");
    }

    #[test]
    fn columns_count_characters() {
        check("(é) G2", "1:5 G2");
        check("G0 X1 é", "1:7 é");
    }

    #[test]
    fn display_formats() {
        let e = parse("G2\nM3\nS1").unwrap_err();
        let first = &e.diagnostics[0];
        assert_eq!(
            first.to_string(),
            format!("prog.ngc:1:1: {}", first.message)
        );
        let shown = e.to_string();
        assert!(!shown.contains('\n'));
        assert!(shown.starts_with("prog.ngc:1:1: "));
        assert!(shown.ends_with(" (and 2 more errors)"), "{shown}");
        let report = e.full_report();
        assert_eq!(report.lines().count(), 3);
        assert!(report.lines().nth(2).unwrap().starts_with("prog.ngc:3:1: "));

        let single = parse("G2").unwrap_err();
        assert!(!single.to_string().contains("more"));
        let two = parse("G2\nG3").unwrap_err();
        assert!(two.to_string().ends_with(" (and 1 more error)"));
    }

    #[test]
    fn axis_letter_helpers() {
        for (i, a) in AxisLetter::ALL.iter().enumerate() {
            assert_eq!(a.index(), i);
            assert_eq!(AxisLetter::from_char(a.as_char()), Some(*a));
            assert_eq!(
                AxisLetter::from_char(a.as_char().to_ascii_lowercase()),
                Some(*a)
            );
            assert_eq!(a.is_rotary(), i >= 3);
        }
        assert_eq!(AxisLetter::from_char('U'), None);
        let v = AxisValues::default().with(AxisLetter::B, 2.0);
        assert_eq!(v.get(AxisLetter::B), 2.0);
        assert_eq!(v.to_array(), [0.0, 0.0, 0.0, 0.0, 2.0, 0.0]);
    }

    #[test]
    fn empty_program() {
        let p = parse("").unwrap();
        assert!(p.moves.is_empty() && p.axes_used.is_empty() && p.ended_by.is_none());
        assert_eq!(p.path, PathBuf::from("prog.ngc"));
    }

    // ---- robustness --------------------------------------------------------------------

    const VALID: &str = "%\nN10 G21 G90 (setup)\nG0 X10 Y-5.5 Z2\nG1 F300 Z-1 ; plunge\n\
        G91 X 1 0 A45\nG20 Y.5 C-1.\nG90 G21 G0 Z5\nM30\n%\n";

    #[test]
    fn valid_sample_parses() {
        let p = parse(VALID).unwrap();
        assert_eq!(p.moves.len(), 5);
        assert_eq!(p.ended_by, Some(8));
    }

    #[derive(Clone, Debug)]
    enum Edit {
        Insert(usize, char),
        Delete(usize),
        Replace(usize, char),
    }

    fn edit_strategy() -> impl Strategy<Value = Edit> {
        let ch = prop_oneof![
            proptest::char::range(' ', '~'),
            Just('\n'),
            Just('\t'),
            any::<char>(),
        ];
        prop_oneof![
            (any::<usize>(), ch.clone()).prop_map(|(i, c)| Edit::Insert(i, c)),
            any::<usize>().prop_map(Edit::Delete),
            (any::<usize>(), ch).prop_map(|(i, c)| Edit::Replace(i, c)),
        ]
    }

    proptest! {
        #[test]
        fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
            let text = String::from_utf8_lossy(&bytes);
            let _ = parse(&text);
        }

        #[test]
        fn random_ascii_never_panics(text in "[ -~\n\t]{0,300}") {
            let _ = parse(&text);
        }

        #[test]
        fn mutated_valid_program_never_panics(edits in proptest::collection::vec(edit_strategy(), 1..12)) {
            let mut chars: Vec<char> = VALID.chars().collect();
            for e in edits {
                let n = chars.len();
                match e {
                    Edit::Insert(i, c) => chars.insert(i % (n + 1), c),
                    Edit::Delete(i) if n > 0 => { chars.remove(i % n); }
                    Edit::Replace(i, c) if n > 0 => chars[i % n] = c,
                    _ => {}
                }
            }
            let text: String = chars.into_iter().collect();
            match parse(&text) {
                Ok(p) => {
                    for m in &p.moves {
                        prop_assert!(m.start != m.end);
                        for a in AxisLetter::ALL {
                            prop_assert!(m.end.get(a).is_finite());
                        }
                        if let Some(f) = m.feed_mm_per_min {
                            prop_assert!(f > 0.0 && f.is_finite());
                        }
                    }
                }
                Err(e) => {
                    prop_assert!(!e.diagnostics.is_empty());
                    for d in &e.diagnostics {
                        prop_assert!(d.line >= 1 && d.column >= 1);
                        prop_assert!(!d.word.is_empty());
                    }
                }
            }
        }
    }
}
