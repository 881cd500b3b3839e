//! Byte-level reading of one RS274/NGC line into a `Block`.
//!
//! A line is first normalised into a reusable buffer (spaces and tabs outside comments
//! dropped, letters lower-cased; where bytes were dropped is remembered, which gives the
//! source byte offset of every kept byte), then read word by word. Plain numbers of up to
//! 15 digits are converted exactly by one division of an integer mantissa by a power of
//! ten; longer ones go through the standard library's parser. Values (`X[1+#2]`, `X#<a>`, `Xsin[30]`) are evaluated while reading, as
//! LinuxCNC does: parameter reads see the values from before the line, and parameter
//! assignments on the line are collected in `Block::assigns` to be applied after the whole
//! line has been read. Words live in fixed arrays, so reading a plain motion block does not
//! allocate once the buffers have grown.

use crate::math::Real;

/// Number of numbered parameters (`#1` … `#5601`), as LinuxCNC.
pub(crate) const NUM_PARAMS: usize = 5602;

/// Two values compare equal in `EQ`/`NE` when closer than this (LinuxCNC's tolerance for
/// expression equality, in program units).
const EXPR_EQUAL_TOL: Real = 1e-4;

/// A parameter index must be this close to an integer.
const PARAM_INDEX_TOL: Real = 1e-4;

/// Deepest nesting of brackets, `#` indirections and unary operators in one value.
const MAX_NESTING: usize = 64;

/// Maximum number of G codes (and of M codes) kept for one block.
pub(crate) const MAX_CODES: usize = 16;

/// Read access to parameters while a line is read.
pub(crate) trait ParamRead {
    /// Value of `#n` (1 ≤ n < [`NUM_PARAMS`]).
    fn numbered(&self, n: usize) -> Real;
    /// Value of `#<name>` (name lower-case, without spaces), or an error message.
    fn named(&self, name: &str) -> Result<Real, String>;
    /// Whether `#<name>` exists.
    fn exists(&self, name: &str) -> bool;
}

/// Parameters for syntax-only checking: every read gives 0.
pub(crate) struct NoParams;

impl ParamRead for NoParams {
    fn numbered(&self, _n: usize) -> Real {
        0.0
    }
    fn named(&self, _name: &str) -> Result<Real, String> {
        Ok(0.0)
    }
    fn exists(&self, _name: &str) -> bool {
        true
    }
}

/// An error while reading a line: byte range in the original line and a message.
#[derive(Debug, Clone)]
pub(crate) struct LexError {
    /// Byte offset (original line) where the offending word starts.
    pub start: usize,
    /// Byte offset just after the offending word.
    pub end: usize,
    /// LinuxCNC-style message.
    pub message: String,
}

/// Keyword of an O-word line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum OKeyword {
    /// `sub`
    Sub,
    /// `endsub`
    EndSub,
    /// `call`
    Call,
    /// `do`
    Do,
    /// `while`
    While,
    /// `endwhile`
    EndWhile,
    /// `if`
    If,
    /// `elseif`
    ElseIf,
    /// `else`
    Else,
    /// `endif`
    EndIf,
    /// `repeat`
    Repeat,
    /// `endrepeat`
    EndRepeat,
    /// `break`
    Break,
    /// `continue`
    Continue,
    /// `return`
    Return,
    /// No keyword: a Fanuc-style program number `O1000` (subprogram start).
    Fanuc,
}

/// The O-word of a line.
#[derive(Debug, Clone)]
pub(crate) struct OWord {
    /// Label: the number as text (`100`) or the name (`<name>` lower-case, spaces removed).
    pub label: String,
    /// Keyword.
    pub keyword: OKeyword,
    /// Value of the bracketed condition / count / return value, if any.
    pub value: Option<Real>,
    /// Call arguments.
    pub args: Vec<Real>,
}

/// A parameter assignment collected on a line.
#[derive(Debug, Clone)]
pub(crate) enum Assign {
    /// `#n = value`
    Numbered(usize, Real),
    /// `#<name> = value` (name lower-case)
    Named(String, Real),
}

/// Comment kinds that do something.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Message {
    /// `(MSG, text)`
    Msg(String),
    /// `(DEBUG, text)` or `(PRINT, text)` (parameters not substituted).
    Debug(String),
}

/// One read line.
#[derive(Debug, Default)]
pub(crate) struct Block {
    /// `/` at the start.
    pub block_delete: bool,
    /// Letter words a..z (not g, m, n, o), then the polar words `@` (26) and `^` (27),
    /// value in program units; only meaningful where [`Block::present`] has the bit.
    words: [Real; 28],
    /// Bit `k` set: word slot `k` was given on the line.
    present: u32,
    /// Byte offset of each word in the original line.
    pub word_pos: [u32; 28],
    /// G codes ×10 (`G38.2` = 382) with their byte offsets.
    pub g: [(i32, u32); MAX_CODES],
    /// Number of G codes.
    pub ng: usize,
    /// M codes with their byte offsets.
    pub m: [(i32, u32); MAX_CODES],
    /// Number of M codes.
    pub nm: usize,
    /// N word.
    pub n: Option<Real>,
    /// O word.
    pub o: Option<OWord>,
    /// Byte offset of the O word.
    pub o_pos: usize,
    /// Parameter assignments, in order.
    pub assigns: Vec<Assign>,
    /// Active comment.
    pub message: Option<Message>,
    /// The line had anything but blanks and comments.
    pub has_words: bool,
}

impl Block {
    fn clear(&mut self) {
        self.block_delete = false;
        self.present = 0;
        self.ng = 0;
        self.nm = 0;
        self.n = None;
        self.o = None;
        self.assigns.clear();
        self.message = None;
        self.has_words = false;
    }

    /// Value of word `c` (lower-case letter, `@` or `^`).
    pub fn word(&self, c: u8) -> Option<Real> {
        let k = slot(c);
        if self.present & (1 << k) != 0 {
            Some(self.words[k])
        } else {
            None
        }
    }

    /// Byte offset of word `c`.
    pub fn pos(&self, c: u8) -> usize {
        self.word_pos[slot(c)] as usize
    }

    /// The G codes.
    pub fn gs(&self) -> &[(i32, u32)] {
        &self.g[..self.ng]
    }

    /// The M codes.
    pub fn ms(&self) -> &[(i32, u32)] {
        &self.m[..self.nm]
    }
}

/// Index of word `c` in [`Block::words`].
fn slot(c: u8) -> usize {
    match c {
        b'@' => 26,
        b'^' => 27,
        _ => (c.wrapping_sub(b'a') as usize).min(25),
    }
}

/// Reusable reader of lines.
#[derive(Default)]
pub(crate) struct Lexer {
    /// The normalised line in `norm[..len]` (the buffers only grow).
    norm: Vec<u8>,
    /// Where bytes were dropped: `(k, d)` means the normalised byte `k` and those after it
    /// (up to the next entry) come from original offset `k + d`.
    gaps: Vec<(u32, u32)>,
    /// Length of the normalised line.
    len: usize,
    /// The block of the last line read (boxed, so the interpreter can swap it out cheaply).
    pub block: Box<Block>,
}

/// Reading position inside the normalised line.
struct Cursor<'a, P: ParamRead + ?Sized> {
    depth: usize,
    s: &'a [u8],
    gaps: &'a [(u32, u32)],
    orig_len: usize,
    i: usize,
    params: &'a P,
}

type LResult<T> = Result<T, LexError>;

impl<P: ParamRead + ?Sized> Cursor<'_, P> {
    fn peek(&self) -> Option<u8> {
        self.s.get(self.i).copied()
    }
    fn peek_at(&self, k: usize) -> Option<u8> {
        self.s.get(self.i + k).copied()
    }
    fn orig(&self, i: usize) -> usize {
        if i >= self.s.len() {
            return self.orig_len;
        }
        let dropped = self
            .gaps
            .iter()
            .rev()
            .find(|g| g.0 as usize <= i)
            .map_or(0, |g| g.1 as usize);
        i + dropped
    }
    fn err(&self, start: usize, message: impl Into<String>) -> LexError {
        let end = self.orig(self.i.max(start + 1).min(self.s.len()));
        LexError {
            start: self.orig(start),
            end: end
                .max(self.orig(start) + 1)
                .min(self.orig_len.max(self.orig(start) + 1)),
            message: message.into(),
        }
    }

    /// A plain number: optional sign, digits, optional point and digits.
    #[inline]
    fn number(&mut self) -> LResult<Real> {
        let d = Decimal::scan(self.s, self.i);
        if !d.is_fast() {
            return self.number_general(self.i);
        }
        self.i = d.end;
        Ok(d.value())
    }

    /// [`Cursor::number`] for any number of digits, and its errors.
    #[cold]
    #[inline(never)]
    fn number_general(&mut self, start: usize) -> LResult<Real> {
        self.i = start;
        let mut neg = false;
        if let Some(c @ (b'+' | b'-')) = self.peek() {
            neg = c == b'-';
            self.i += 1;
        }
        let mut mant: u64 = 0;
        let mut digits = 0usize;
        let mut frac = 0i32;
        let mut exact = true;
        let mut seen_point = false;
        let num_start = self.i;
        while let Some(c) = self.peek() {
            if c.is_ascii_digit() {
                if mant < MANT_LIMIT {
                    mant = mant * 10 + (c - b'0') as u64;
                    if seen_point {
                        frac += 1;
                    }
                } else {
                    exact = false;
                }
                digits += 1;
            } else if c == b'.' && !seen_point {
                seen_point = true;
            } else {
                break;
            }
            self.i += 1;
        }
        if digits == 0 {
            let text = String::from_utf8_lossy(&self.s[start..self.i]).into_owned();
            return Err(self.err(
                start,
                format!("bad number format (conversion failed) parsing '{text}'"),
            ));
        }
        let v = if exact && frac <= 22 {
            mant as Real / POW10[frac as usize]
        } else {
            let text = std::str::from_utf8(&self.s[num_start..self.i]).unwrap_or("0");
            let t = text.strip_suffix('.').unwrap_or(text);
            t.parse::<Real>().unwrap_or(Real::NAN)
        };
        if !v.is_finite() {
            return Err(self.err(start, "Number out of range"));
        }
        Ok(if neg { -v } else { v })
    }

    /// The value of a word: a plain unsigned number read directly, anything else through
    /// [`Cursor::real_value`] (the same result; the common case skips the dispatch).
    fn value(&mut self) -> LResult<Real> {
        match self.peek() {
            Some(b'0'..=b'9' | b'.') => self.number(),
            _ => self.real_value(),
        }
    }

    /// A real value: number, `[expr]`, `#param`, unary function, or signed value.
    fn real_value(&mut self) -> LResult<Real> {
        self.depth += 1;
        let r = if self.depth > MAX_NESTING {
            Err(self.err(self.i, "Expression nested too deeply"))
        } else {
            self.real_value_inner()
        };
        self.depth -= 1;
        r
    }

    fn real_value_inner(&mut self) -> LResult<Real> {
        let start = self.i;
        match self.peek() {
            None => Err(self.err(start, "Unexpected end of line reading value")),
            Some(b'[') => self.expression(),
            Some(b'#') => self.parameter(),
            Some(c @ (b'+' | b'-')) if !matches!(self.peek_at(1), Some(b'0'..=b'9' | b'.')) => {
                self.i += 1;
                let v = self.real_value()?;
                Ok(if c == b'-' { -v } else { v })
            }
            Some(b'a'..=b'z') => self.unary(),
            Some(_) => self.number(),
        }
    }

    /// `#n`, `##n`, `#[expr]`, `#<name>`.
    fn parameter(&mut self) -> LResult<Real> {
        let start = self.i;
        self.i += 1; // '#'
        if self.peek() == Some(b'<') {
            let name = self.name()?;
            return self.params.named(&name).map_err(|m| self.err(start, m));
        }
        let idx = self.param_index(start)?;
        Ok(self.params.numbered(idx))
    }

    /// The index after `#`.
    fn param_index(&mut self, start: usize) -> LResult<usize> {
        let v = self.real_value()?;
        let r = v.round();
        if !(1.0..NUM_PARAMS as Real).contains(&r) || (v - r).abs() > PARAM_INDEX_TOL {
            return Err(self.err(start, "Parameter number out of range"));
        }
        Ok(r as usize)
    }

    /// `<name>` (cursor on `<`); returns the lower-case name.
    fn name(&mut self) -> LResult<String> {
        let start = self.i;
        self.i += 1;
        let from = self.i;
        while let Some(c) = self.peek() {
            if c == b'>' {
                let name = String::from_utf8_lossy(&self.s[from..self.i]).into_owned();
                self.i += 1;
                return Ok(name);
            }
            self.i += 1;
        }
        Err(self.err(start, "Named parameter not terminated"))
    }

    /// `[ expression ]` (cursor on `[`).
    fn expression(&mut self) -> LResult<Real> {
        let start = self.i;
        self.i += 1;
        let v = self.binary(0)?;
        if self.peek() != Some(b']') {
            return Err(self.err(start, "Unclosed expression"));
        }
        self.i += 1;
        Ok(v)
    }

    /// Operator at the cursor: (precedence, op id, length).
    fn operator(&self) -> Option<(u8, u8, usize)> {
        let rest = &self.s[self.i..];
        let ops: [(&[u8], u8, u8); 15] = [
            (b"**", 6, 0),
            (b"*", 5, 1),
            (b"/", 5, 2),
            (b"mod", 5, 3),
            (b"+", 4, 4),
            (b"-", 4, 5),
            (b"eq", 3, 6),
            (b"ne", 3, 7),
            (b"gt", 3, 8),
            (b"ge", 3, 9),
            (b"lt", 3, 10),
            (b"le", 3, 11),
            (b"and", 2, 12),
            (b"or", 2, 13),
            (b"xor", 2, 14),
        ];
        ops.iter()
            .find(|(t, _, _)| rest.starts_with(t))
            .map(|(t, p, id)| (*p, *id, t.len()))
    }

    /// Precedence climbing, all operators left-associative (as LinuxCNC).
    fn binary(&mut self, min_prec: u8) -> LResult<Real> {
        let mut lhs = self.real_value()?;
        loop {
            if self.peek() == Some(b']') {
                return Ok(lhs);
            }
            let op_start = self.i;
            let Some((prec, id, len)) = self.operator() else {
                return Err(self.err(op_start, "Unknown operation"));
            };
            if prec <= min_prec {
                return Ok(lhs);
            }
            self.i += len;
            let rhs = self.binary(prec)?;
            lhs = self.apply(id, lhs, rhs, op_start)?;
        }
    }

    fn apply(&self, id: u8, a: Real, b: Real, at: usize) -> LResult<Real> {
        let t = |c: bool| if c { 1.0 } else { 0.0 };
        Ok(match id {
            0 => {
                if a < 0.0 && b.fract() != 0.0 {
                    return Err(
                        self.err(at, "Attempt to raise negative number to non-integer power")
                    );
                }
                a.powf(b)
            }
            1 => a * b,
            2 => {
                if b == 0.0 {
                    return Err(self.err(at, "Attempt to divide by zero"));
                }
                a / b
            }
            3 => {
                if b == 0.0 {
                    return Err(self.err(at, "Attempt to divide by zero"));
                }
                let r = a % b;
                if r < 0.0 { r + b.abs() } else { r }
            }
            4 => a + b,
            5 => a - b,
            6 => t((a - b).abs() < EXPR_EQUAL_TOL),
            7 => t((a - b).abs() >= EXPR_EQUAL_TOL),
            8 => t(a > b),
            9 => t(a >= b),
            10 => t(a < b),
            11 => t(a <= b),
            12 => t(a != 0.0 && b != 0.0),
            13 => t(a != 0.0 || b != 0.0),
            _ => t((a != 0.0) != (b != 0.0)),
        })
    }

    /// A unary function (cursor on its first letter).
    fn unary(&mut self) -> LResult<Real> {
        let start = self.i;
        let rest = &self.s[self.i..];
        const FUNCS: [&[u8]; 14] = [
            b"abs", b"acos", b"asin", b"atan", b"cos", b"exp", b"fix", b"fup", b"ln", b"round",
            b"sin", b"sqrt", b"tan", b"exists",
        ];
        let Some(f) = FUNCS.iter().find(|f| rest.starts_with(f)) else {
            let c = rest[0] as char;
            return Err(self.err(start, format!("Unknown word starting with {c}")));
        };
        self.i += f.len();
        if self.peek() != Some(b'[') {
            return Err(self.err(start, "Left bracket missing after unary operation name"));
        }
        if *f == b"exists" {
            self.i += 1;
            if self.peek() != Some(b'#') {
                return Err(self.err(self.i, "Expected # reading parameter"));
            }
            let v = if self.peek_at(1) == Some(b'<') {
                self.i += 1;
                let name = self.name()?;
                if self.params.exists(&name) { 1.0 } else { 0.0 }
            } else {
                self.i += 1;
                let v = self.real_value()?;
                let r = v.round();
                if (1.0..NUM_PARAMS as Real).contains(&r) {
                    1.0
                } else {
                    0.0
                }
            };
            if self.peek() != Some(b']') {
                return Err(self.err(self.i, "Expected ] reading bracketed parameter"));
            }
            self.i += 1;
            return Ok(v);
        }
        let v = self.expression()?;
        let deg = |x: Real| x.to_radians();
        let out = match *f {
            b"abs" => v.abs(),
            b"acos" => {
                if !(-1.0..=1.0).contains(&v) {
                    return Err(self.err(start, "Argument to acos out of range"));
                }
                v.acos().to_degrees()
            }
            b"asin" => {
                if !(-1.0..=1.0).contains(&v) {
                    return Err(self.err(start, "Argument to asin out of range"));
                }
                v.asin().to_degrees()
            }
            b"atan" => {
                if self.peek() != Some(b'/') {
                    return Err(self.err(start, "Slash missing after first atan argument"));
                }
                self.i += 1;
                if self.peek() != Some(b'[') {
                    return Err(self.err(start, "Left bracket missing after slash with atan"));
                }
                let x = self.expression()?;
                v.atan2(x).to_degrees()
            }
            b"cos" => deg(v).cos(),
            b"exp" => v.exp(),
            b"fix" => v.floor(),
            b"fup" => v.ceil(),
            b"ln" => {
                if v <= 0.0 {
                    return Err(self.err(start, "Zero or negative argument to ln"));
                }
                v.ln()
            }
            b"round" => v.round(),
            b"sin" => deg(v).sin(),
            b"sqrt" => {
                if v < 0.0 {
                    return Err(self.err(start, "Attempt to take square root of negative number"));
                }
                v.sqrt()
            }
            _ => deg(v).tan(),
        };
        Ok(out)
    }
}

/// [`Lexer::normalise`]'s table: the lower-cased byte, or 0 for the bytes it treats
/// specially (blanks, `#`, `(`, `;`, and NUL itself).
const NORMAL: [u8; 256] = {
    let mut t = [0u8; 256];
    let mut c = 1;
    while c < 256 {
        t[c] = (c as u8).to_ascii_lowercase();
        c += 1;
    }
    t[b' ' as usize] = 0;
    t[b'\t' as usize] = 0;
    t[b'\r' as usize] = 0;
    t[b'#' as usize] = 0;
    t[b'(' as usize] = 0;
    t[b';' as usize] = 0;
    t
};

/// A plain decimal as scanned: optional sign, digits, optional point and digits.
#[derive(Clone, Copy)]
struct Decimal {
    neg: bool,
    /// The digits as an integer (wrapping: meaningful when [`Decimal::is_fast`]).
    mant: u64,
    /// Digits in all, and after the point.
    digits: usize,
    frac: usize,
    /// Index just after the number.
    end: usize,
}

impl Decimal {
    /// Scans the decimal starting at `s[i]` (no digits at all: `digits` is 0).
    #[inline(always)]
    fn scan(s: &[u8], mut i: usize) -> Decimal {
        let mut neg = false;
        if let Some(&c @ (b'+' | b'-')) = s.get(i) {
            neg = c == b'-';
            i += 1;
        }
        let (mut mant, mut digits, mut frac) = (0u64, 0, 0);
        digits += digit_run(s, &mut i, &mut mant);
        if s.get(i) == Some(&b'.') {
            i += 1;
            frac = digit_run(s, &mut i, &mut mant);
            digits += frac;
        }
        Decimal {
            neg,
            mant,
            digits,
            frac,
            end: i,
        }
    }

    /// Some digits, and few enough for [`Decimal::value`] to be exact.
    #[inline(always)]
    fn is_fast(&self) -> bool {
        self.digits > 0 && self.digits <= FAST_DIGITS
    }

    /// The value: mantissa (< 10^15 < 2^53) and power of ten are both exact, so one
    /// division rounds correctly.
    #[inline(always)]
    fn value(&self) -> Real {
        let v = self.mant as Real / POW10[self.frac];
        if self.neg { -v } else { v }
    }
}

/// Reads the decimal digits at `s[*i..]` into `mant` (wrapping), moving `i` past them;
/// returns how many there were.
#[inline(always)]
fn digit_run(s: &[u8], i: &mut usize, mant: &mut u64) -> usize {
    let mut n = 0;
    while let Some(d) = s.get(*i).map(|c| c.wrapping_sub(b'0'))
        && d <= 9
    {
        *mant = mant.wrapping_mul(10).wrapping_add(d as u64);
        n += 1;
        *i += 1;
    }
    n
}

/// Numbers with at most this many digits take the fast path of [`Cursor::number`]: their
/// mantissa stays below 10^15 < 2^53, exact in f64.
const FAST_DIGITS: usize = 15;

/// A decimal mantissa below this times ten stays below 2^53 (exact in f64).
const MANT_LIMIT: u64 = (1u64 << 53) / 10;

/// Letters that make a word of [`Block::words`] (not g, m, n, o). U, V and W are bad
/// characters, as in LinuxCNC's standalone interpreter (an X Y Z A B C machine).
const WORD_LETTER: [bool; 256] = {
    let mut t = [false; 256];
    let letters = b"abcdefhijklpqrstxyz@^";
    let mut k = 0;
    while k < letters.len() {
        t[letters[k] as usize] = true;
        k += 1;
    }
    t
};

/// Powers of ten exactly representable in f64.
const POW10: [Real; 23] = [
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16,
    1e17, 1e18, 1e19, 1e20, 1e21, 1e22,
];

const O_KEYWORDS: [(&[u8], OKeyword); 15] = [
    (b"endsub", OKeyword::EndSub),
    (b"endwhile", OKeyword::EndWhile),
    (b"endif", OKeyword::EndIf),
    (b"endrepeat", OKeyword::EndRepeat),
    (b"elseif", OKeyword::ElseIf),
    (b"else", OKeyword::Else),
    (b"sub", OKeyword::Sub),
    (b"call", OKeyword::Call),
    (b"do", OKeyword::Do),
    (b"while", OKeyword::While),
    (b"if", OKeyword::If),
    (b"repeat", OKeyword::Repeat),
    (b"break", OKeyword::Break),
    (b"continue", OKeyword::Continue),
    (b"return", OKeyword::Return),
];

impl Lexer {
    /// Normalises `line` (without its newline) into the internal buffer (spaces, tabs and
    /// carriage returns outside comments dropped, letters lower-cased, comments kept
    /// verbatim; `gaps` records where bytes were dropped). Returns whether a `#` occurs
    /// outside comments.
    fn normalise(&mut self, line: &[u8]) -> LResult<bool> {
        let n = line.len();
        // the normalised line is never longer than the line: grow once, write in place
        if self.norm.len() < n {
            self.norm.resize(n, 0);
        }
        self.gaps.clear();
        let norm = &mut self.norm[..n];
        let mut k = 0;
        let mut hash = false;
        let mut i = 0;
        while i < n {
            let c = line[i];
            let lower = NORMAL[c as usize];
            if lower != 0 {
                norm[k] = lower;
                k += 1;
                i += 1;
                continue;
            }
            match c {
                b' ' | b'\t' | b'\r' => {
                    while i < n && matches!(line[i], b' ' | b'\t' | b'\r') {
                        i += 1;
                    }
                    self.gaps.push((k as u32, (i - k) as u32));
                }
                b'(' => {
                    let start = i;
                    let mut j = i + 1;
                    while j < n && line[j] != b')' {
                        if line[j] == b'(' {
                            self.len = 0;
                            return Err(LexError {
                                start: j,
                                end: j + 1,
                                message: "Nested comment found".into(),
                            });
                        }
                        j += 1;
                    }
                    if j >= n {
                        self.len = 0;
                        return Err(LexError {
                            start,
                            end: n,
                            message: "Unclosed comment found".into(),
                        });
                    }
                    // keep the comment verbatim, marked by '(' and ')'
                    let len = j + 1 - start;
                    norm[k..k + len].copy_from_slice(&line[start..=j]);
                    k += len;
                    i = j + 1;
                }
                b';' => {
                    // the rest of the line is a comment, kept verbatim
                    norm[k..k + n - i].copy_from_slice(&line[i..]);
                    k += n - i;
                    break;
                }
                _ => {
                    // '#' (the line reads parameters) or a NUL byte, kept
                    hash |= c == b'#';
                    norm[k] = c;
                    k += 1;
                    i += 1;
                }
            }
        }
        self.len = k;
        Ok(hash)
    }

    /// First half of [`Lexer::read`]: clears the block and normalises `line`. Returns
    /// whether the line reads parameters (a `#` outside comments), so the caller can
    /// update what parameter reads see before [`Lexer::parse`].
    pub fn prepare(&mut self, line: &[u8]) -> LResult<bool> {
        self.block.clear();
        self.normalise(line)
    }

    /// Second half of [`Lexer::read`]: reads the line given to [`Lexer::prepare`] into
    /// [`Lexer::block`].
    pub fn parse<P: ParamRead + ?Sized>(&mut self, line: &[u8], params: &P) -> LResult<()> {
        let k = self.len;
        read_block(&self.norm[..k], &self.gaps, line, params, &mut self.block)
    }

    /// Reads a *plain* line straight into [`Lexer::block`], without the normalised copy:
    /// words of a letter and an unsigned or signed decimal number of at most
    /// [`FAST_DIGITS`] digits, separated by blanks or nothing, G codes with at most one
    /// decimal, M codes whole, no repeated word. That is what most lines of a long program
    /// are. Returns false, with nothing decided, for any other line (comments, parameters,
    /// expressions, O-words, block delete, a blank inside a word, anything in error): the
    /// caller then reads it with [`Lexer::prepare`] and [`Lexer::parse`], which give the
    /// same block for a plain line (tested on every line of the conformance corpus).
    pub fn read_plain(&mut self, line: &[u8]) -> bool {
        let b = &mut *self.block;
        b.clear();
        let n = line.len();
        let mut i = 0;
        loop {
            while i < n && matches!(line[i], b' ' | b'\t' | b'\r') {
                i += 1;
            }
            if i == n {
                return true;
            }
            let start = i;
            let letter = line[i];
            if !letter.is_ascii_alphabetic() {
                return false;
            }
            let ch = letter.to_ascii_lowercase();
            let num = Decimal::scan(line, i + 1);
            if !num.is_fast() {
                return false;
            }
            let Decimal {
                neg, mant, frac, ..
            } = num;
            // what follows a number is a blank, the next letter or the end (a blank then a
            // digit, a point or a sign would continue the number in the general reader)
            let mut j = num.end;
            while j < n && matches!(line[j], b' ' | b'\t' | b'\r') {
                j += 1;
            }
            if j < n && !line[j].is_ascii_alphabetic() {
                return false;
            }
            let pos = start as u32;
            match ch {
                b'g' | b'm' => {
                    // the code ×10, exactly what the general reader rounds `v × 10` to
                    let code = match frac {
                        0 if mant < 100_000 => mant as i32 * 10,
                        1 if mant < 1_000_000 => mant as i32,
                        _ => return false,
                    };
                    if neg {
                        return false;
                    }
                    if ch == b'g' {
                        if b.ng >= MAX_CODES {
                            return false;
                        }
                        b.g[b.ng] = (code, pos);
                        b.ng += 1;
                    } else {
                        if code % 10 != 0 || b.nm >= MAX_CODES {
                            return false;
                        }
                        b.m[b.nm] = (code / 10, pos);
                        b.nm += 1;
                    }
                }
                b'n' => {
                    if b.n.is_some() {
                        return false;
                    }
                    b.n = Some(num.value());
                }
                _ => {
                    if !WORD_LETTER[ch as usize] {
                        return false;
                    }
                    let k = slot(ch);
                    if b.present & (1 << k) != 0 {
                        return false;
                    }
                    b.words[k] = num.value();
                    b.present |= 1 << k;
                    b.word_pos[k] = pos;
                }
            }
            b.has_words = true;
            i = j;
        }
    }

    /// Reads `line` into [`Lexer::block`].
    pub fn read<P: ParamRead + ?Sized>(&mut self, line: &[u8], params: &P) -> LResult<()> {
        self.prepare(line)?;
        self.parse(line, params)
    }
}

fn comment_message(text: &[u8]) -> Option<Message> {
    // text is between the parentheses
    let t = String::from_utf8_lossy(text);
    let trimmed = t.trim_start();
    let lower = trimmed.to_ascii_lowercase();
    for (key, debug) in [("msg,", false), ("debug,", true), ("print,", true)] {
        if lower.starts_with(key) {
            let body = trimmed[key.len()..].to_string();
            return Some(if debug {
                Message::Debug(body)
            } else {
                Message::Msg(body)
            });
        }
    }
    None
}

fn read_block<P: ParamRead + ?Sized>(
    s: &[u8],
    gaps: &[(u32, u32)],
    line: &[u8],
    params: &P,
    b: &mut Block,
) -> LResult<()> {
    let mut c = Cursor {
        depth: 0,
        s,
        gaps,
        orig_len: line.len(),
        i: 0,
        params,
    };
    if c.peek() == Some(b'/') {
        b.block_delete = true;
        c.i += 1;
    }
    while let Some(ch) = c.peek() {
        let start = c.i;
        match ch {
            b'(' => {
                let mut j = c.i + 1;
                while j < s.len() && s[j] != b')' {
                    j += 1;
                }
                if b.message.is_none() {
                    b.message = comment_message(&s[c.i + 1..j.min(s.len())]);
                }
                c.i = j + 1;
            }
            b';' => break,
            b'#' => {
                b.has_words = true;
                c.i += 1;
                let assign = if c.peek() == Some(b'<') {
                    let name = c.name()?;
                    expect_eq(&mut c, start)?;
                    Assign::Named(name, c.real_value()?)
                } else {
                    let idx = c.param_index(start)?;
                    expect_eq(&mut c, start)?;
                    Assign::Numbered(idx, c.real_value()?)
                };
                b.assigns.push(assign);
            }
            b'n' => {
                b.has_words = true;
                c.i += 1;
                if b.n.is_some() {
                    return Err(c.err(start, "Multiple n words on one line"));
                }
                b.n = Some(c.number()?);
            }
            b'o' => {
                b.has_words = true;
                c.i += 1;
                b.o_pos = c.orig(start);
                b.o = Some(read_oword(&mut c, start)?);
            }
            b'g' | b'm' => {
                b.has_words = true;
                c.i += 1;
                let v = c.value()?;
                let code = (v * 10.0).round();
                if (v * 10.0 - code).abs() > PARAM_INDEX_TOL || code.abs() > 1e6 {
                    let what = if ch == b'g' { "G code" } else { "M code" };
                    return Err(c.err(start, format!("{what} out of range")));
                }
                let pos = c.orig(start) as u32;
                if ch == b'g' {
                    if b.ng >= MAX_CODES {
                        return Err(c.err(start, "Too many G codes on line"));
                    }
                    b.g[b.ng] = (code as i32, pos);
                    b.ng += 1;
                } else {
                    if code as i32 % 10 != 0 {
                        return Err(c.err(start, "Unknown m code used"));
                    }
                    if b.nm >= MAX_CODES {
                        return Err(c.err(start, "Too many M codes on line"));
                    }
                    b.m[b.nm] = (code as i32 / 10, pos);
                    b.nm += 1;
                }
            }
            b'a'..=b'z' | b'@' | b'^' if !matches!(ch, b'g' | b'm' | b'n' | b'o') => {
                if !WORD_LETTER[ch as usize] {
                    return Err(c.err(start, format!("Bad character '{}' used", ch as char)));
                }
                b.has_words = true;
                c.i += 1;
                let k = slot(ch);
                if b.present & (1 << k) != 0 {
                    return Err(c.err(start, format!("Multiple {} words on one line", ch as char)));
                }
                let v = c.value()?;
                if !v.is_finite() {
                    return Err(c.err(start, "Number out of range"));
                }
                b.words[k] = v;
                b.present |= 1 << k;
                b.word_pos[k] = c.orig(start) as u32;
            }
            _ => {
                let shown = if ch.is_ascii() {
                    (ch as char).to_string()
                } else {
                    String::from_utf8_lossy(&line[c.orig(start)..])
                        .chars()
                        .next()
                        .map_or_else(|| "?".to_string(), |x| x.to_string())
                };
                return Err(c.err(start, format!("Bad character '{shown}' used")));
            }
        }
    }
    Ok(())
}

fn expect_eq<P: ParamRead + ?Sized>(c: &mut Cursor<'_, P>, start: usize) -> LResult<()> {
    if c.peek() != Some(b'=') {
        return Err(c.err(start, "Equal sign missing in parameter setting"));
    }
    c.i += 1;
    Ok(())
}

fn read_oword<P: ParamRead + ?Sized>(c: &mut Cursor<'_, P>, start: usize) -> LResult<OWord> {
    let label = if c.peek() == Some(b'<') {
        format!("<{}>", c.name()?)
    } else if c.peek() == Some(b'[') || c.peek() == Some(b'#') {
        let v = c.real_value()?;
        format!("{}", v.round() as i64)
    } else {
        let from = c.i;
        while c.peek().is_some_and(|x| x.is_ascii_digit()) {
            c.i += 1;
        }
        if from == c.i {
            return Err(c.err(start, "Bad O-word label"));
        }
        let digits = std::str::from_utf8(&c.s[from..c.i]).unwrap_or("0");
        let v: u64 = digits.parse().unwrap_or(0);
        v.to_string()
    };
    let rest = &c.s[c.i..];
    let kw = O_KEYWORDS.iter().find(|(t, _)| rest.starts_with(t));
    let keyword = match kw {
        Some((t, k)) => {
            c.i += t.len();
            *k
        }
        None => {
            if rest.is_empty() || rest[0] == b'(' || rest[0] == b';' {
                OKeyword::Fanuc
            } else {
                return Err(c.err(c.i, "Unknown word in O-word line"));
            }
        }
    };
    let mut value = None;
    let mut args = Vec::new();
    match keyword {
        OKeyword::Call => loop {
            match c.peek() {
                Some(b'[') => args.push(c.expression()?),
                Some(b'(') => {
                    while c.peek().is_some_and(|x| x != b')') {
                        c.i += 1;
                    }
                    c.i += 1;
                }
                _ => break,
            }
        },
        OKeyword::While | OKeyword::If | OKeyword::ElseIf | OKeyword::Repeat => {
            if c.peek() != Some(b'[') {
                return Err(c.err(start, "Left bracket missing after O-word condition"));
            }
            value = Some(c.expression()?);
        }
        OKeyword::Return | OKeyword::EndSub if c.peek() == Some(b'[') => {
            value = Some(c.expression()?);
        }
        _ => {}
    }
    // only comments may follow
    while let Some(ch) = c.peek() {
        match ch {
            b'(' => {
                while c.peek().is_some_and(|x| x != b')') {
                    c.i += 1;
                }
                c.i += 1;
            }
            b';' => break,
            _ => return Err(c.err(c.i, "Unexpected word after O-word statement")),
        }
    }
    Ok(OWord {
        label,
        keyword,
        value,
        args,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn val(expr: &str) -> Real {
        let mut lx = Lexer::default();
        lx.read(format!("x{expr}").as_bytes(), &NoParams)
            .expect("reads");
        lx.block.word(b'x').expect("x")
    }

    #[test]
    fn precedence_and_functions() {
        assert_eq!(val("[1+2*3]"), 7.0);
        assert_eq!(val("[2**3**2]"), 64.0); // left associative
        assert_eq!(val("[7 mod 3]"), 1.0);
        assert_eq!(val("[-7 mod 3]"), 2.0);
        assert_eq!(val("[1 lt 2 and 3 gt 2]"), 1.0);
        assert!((val("atan[1]/[1]") - 45.0).abs() < 1e-12);
        assert!((val("[sin[30]]") - 0.5).abs() < 1e-12);
        assert_eq!(val("-[2]"), -2.0);
        assert_eq!(val("[fix[-1.5]+fup[1.2]]"), 0.0);
    }

    #[test]
    fn numbers_and_spaces() {
        assert_eq!(val(" - 3 0 . 5"), -30.5);
        assert_eq!(val("1."), 1.0);
        assert_eq!(val(".5"), 0.5);
        assert_eq!(val("0.1"), 0.1);
    }

    /// The fields of a block that mean something, for comparing two readings of a line.
    fn meaning(b: &Block) -> String {
        let words: Vec<_> = (0..28)
            .filter(|k| b.present & (1 << k) != 0)
            .map(|k| (k, b.words[k].to_bits(), b.word_pos[k]))
            .collect();
        format!(
            "{} {:?} {:?} {:?} {:?} {:?} {:?} {} {:?}",
            b.block_delete,
            words,
            b.gs(),
            b.ms(),
            b.n.map(Real::to_bits),
            b.o.as_ref().map(|o| &o.label),
            b.assigns,
            b.has_words,
            b.message
        )
    }

    /// Reads `line` with the plain reader and, when it takes it, checks the block is the
    /// general reader's, bit for bit. Returns whether the plain reader took it.
    fn plain_agrees(line: &[u8]) -> bool {
        let mut plain = Lexer::default();
        let mut general = Lexer::default();
        let took = plain.read_plain(line);
        if took {
            let text = String::from_utf8_lossy(line);
            general
                .read(line, &NoParams)
                .unwrap_or_else(|e| panic!("{text:?}: plain read, general refused: {e:?}"));
            assert_eq!(meaning(&plain.block), meaning(&general.block), "{text:?}");
        }
        took
    }

    #[test]
    fn plain_lines_read_as_the_general_reader_reads_them() {
        for line in [
            "G1 X1.25 Y-0.5 A30.125",
            "g1x1y2z-3",
            "N10 G0 X0",
            "G3 X1 Y0 I0.5 J0",
            "G38.2 Z-5 F100",
            "M3 S1000",
            "G1 X+.5",
            "G1 X1.",
            "X1e5",
            "T1 M6",
            "G21 G90 G17 G94 F1200",
            "G1\tX1\r",
            "",
            "   ",
            "X123456789012345",
        ] {
            assert!(
                plain_agrees(line.as_bytes()),
                "plain line refused: {line:?}"
            );
        }
        // lines only the general reader reads (or refuses): a blank inside a word, an
        // expression, a parameter, a comment, an O-word, block delete, a bad or repeated
        // word, a G code with two decimals, a fractional M code, too many digits
        for line in [
            "G1 X1 .5",
            "G 1 X1",
            "G1 X1 2",
            "G1 X1 -2",
            "G1 X[1+2]",
            "G1 X#1",
            "#1=2",
            "G1 X1 (move)",
            "G1 X1 ; move",
            "o100 sub",
            "/G1 X1",
            "G1 U1",
            "G1 X1 X2",
            "N1 N2",
            "G1.23",
            "M3.5",
            "G-1",
            "X.",
            "X",
            "Xsin[30]",
            "G1 X1.2.3",
            "X1234567890123456",
            "G1 X1 %",
        ] {
            assert!(
                !plain_agrees(line.as_bytes()),
                "needs the general reader: {line:?}"
            );
        }
        // every line of the conformance corpus and the LinuxCNC examples
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/corpus");
        let mut stack = vec![root];
        let (mut lines, mut plain) = (0usize, 0usize);
        while let Some(dir) = stack.pop() {
            for entry in std::fs::read_dir(&dir).expect("corpus folder") {
                let path = entry.expect("entry").path();
                if path.is_dir() {
                    stack.push(path);
                } else if path.extension().is_some_and(|e| e == "ngc") {
                    let bytes = std::fs::read(&path).expect("corpus file");
                    for line in bytes.split(|c| *c == b'\n') {
                        let line = line.strip_suffix(b"\r").unwrap_or(line);
                        lines += 1;
                        plain += plain_agrees(line) as usize;
                    }
                }
            }
        }
        assert!(lines > 10_000, "corpus lines read: {lines}");
        assert!(plain * 3 > lines, "plain lines: {plain} of {lines}");
    }

    #[test]
    fn errors_name_the_problem() {
        let mut lx = Lexer::default();
        let e = lx.read(b"g0 x[1/0]", &NoParams).unwrap_err();
        assert_eq!(e.message, "Attempt to divide by zero");
        let e = lx.read(b"g0 x1 x2", &NoParams).unwrap_err();
        assert_eq!(e.message, "Multiple x words on one line");
        assert_eq!(e.start, 6);
        let e = lx.read(b"G0 X EXISTS[#<foo]", &NoParams).unwrap_err();
        assert_eq!(e.message, "Named parameter not terminated");
    }
}
