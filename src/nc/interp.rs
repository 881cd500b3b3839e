//! The interpreter: executes blocks in LinuxCNC's order and streams [`Record`]s.

#![expect(
    clippy::needless_range_loop,
    reason = "six-axis arrays (position, offsets, words) are indexed in parallel"
)]

use std::collections::{HashMap, VecDeque};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::math::{Point3, Real, Vector3};

use super::comp::{
    CompError, CompOutput, Compensator, Plane as CompPlane, PlaneMove, PlaneMoveKind, Side,
};
use super::lex::{
    Assign, Block, LexError, Lexer, Message, NUM_PARAMS, NoParams, OKeyword, OWord, ParamRead,
};
use super::output::{ArcGeom, Event, EventArg, Motion, MotionKind, Plane, Record, RecordBody};
use super::source::{Pos, Source};
use super::{AxisValues, Diagnostic, InterpOptions, LengthUnit, NcError};

/// Millimetres per inch.
const MM_PER_INCH: Real = 25.4;
/// rs274's simulated probe backs off this far (mm) from the target after tripping.
const PROBE_BACKOFF_MM: Real = 0.254;
/// Rapid clearance above each peck of G73/G83, inch programs (LinuxCNC: 0.010 in).
const PECK_CLEARANCE_INCH: Real = 0.010;
/// Same for mm programs (LinuxCNC: 0.254 mm).
const PECK_CLEARANCE_MM: Real = 0.254;
/// Center-format arc: allowed difference of start and end radius, inch programs (LinuxCNC
/// default `CENTER_ARC_RADIUS_TOLERANCE_INCH`).
const ARC_CENTER_TOL_INCH: Real = 2.0 * 0.001 * std::f64::consts::SQRT_2;
/// Same for mm programs.
const ARC_CENTER_TOL_MM: Real = 2.0 * 0.01 * std::f64::consts::SQRT_2;
/// Above this relative radius difference a center-format arc is rejected (0.1 %).
const ARC_CENTER_REL_TOL: Real = 0.001;
/// R-format arc: how much the chord may exceed the diameter (inch).
const ARC_R_TOL_INCH: Real = 0.00005;
/// Same, mm.
const ARC_R_TOL_MM: Real = 0.00127;
/// A zero-length-radius test used by LinuxCNC's R-format arcs.
const ARC_TINY: Real = 1e-12;
/// Angle tolerance when computing an arc's sweep (radians).
const SWEEP_EPS: Real = 1e-12;

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum FeedMode {
    PerMinute,
    InverseTime,
    PerRev,
}

/// Why reading stopped.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum RunState {
    Running,
    Ended,
    Failed,
}

/// A call frame.
struct Frame {
    ret: Pos,
    saved: [Real; 30],
    locals: HashMap<String, Real>,
    fanuc: bool,
    repeat_left: u32,
    start: Pos,
    label: String,
}

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum LoopKind {
    While,
    Do,
    Repeat,
}

struct LoopState {
    kind: LoopKind,
    pos: Pos,
    left: i64,
}

/// What to do when a skip reaches its target line.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum SkipThen {
    /// Execute the target line normally.
    Exec,
    /// Resume after the target line.
    Consume,
    /// A forward search for a sub: call it when found.
    CallFound,
}

struct Skip {
    label: String,
    until: &'static [OKeyword],
    then: SkipThen,
    /// Skipping a Fanuc subprogram body: ends at an M99 line.
    fanuc_body: bool,
    /// For CallFound: the pending call.
    call: Option<PendingCall>,
}

#[derive(Clone)]
struct PendingCall {
    label: String,
    args: Vec<Real>,
    fanuc: bool,
    repeat: u32,
    ret: Pos,
    err_line: usize,
    err_path: Arc<Path>,
    searched_external: bool,
}

/// Parameters and the state predefined named parameters expose.
pub(crate) struct Params {
    pub numbered: Vec<Real>,
    pub globals: HashMap<String, Real>,
    pub locals: Vec<HashMap<String, Real>>,
    pub snap_pos: [Real; 6],
    pub snap_line: Real,
    pub metric: bool,
    pub incremental: bool,
}

impl ParamRead for Params {
    fn numbered(&self, n: usize) -> Real {
        self.numbered.get(n).copied().unwrap_or(0.0)
    }
    fn named(&self, name: &str) -> Result<Real, String> {
        if let Some(v) = self.lookup(name) {
            return Ok(v);
        }
        Err(format!("Named parameter #<{name}> not defined"))
    }
    fn exists(&self, name: &str) -> bool {
        self.lookup(name).is_some()
    }
}

impl Params {
    fn lookup(&self, name: &str) -> Option<Real> {
        if name.starts_with('_') {
            if let Some(v) = self.globals.get(name) {
                return Some(*v);
            }
            let axis = |i: usize| Some(self.snap_pos[i]);
            return match name {
                "_x" => axis(0),
                "_y" => axis(1),
                "_z" => axis(2),
                "_a" => axis(3),
                "_b" => axis(4),
                "_c" => axis(5),
                "_line" => Some(self.snap_line),
                "_metric" => Some(if self.metric { 1.0 } else { 0.0 }),
                "_imperial" => Some(if self.metric { 0.0 } else { 1.0 }),
                "_absolute" => Some(if self.incremental { 0.0 } else { 1.0 }),
                "_incremental" => Some(if self.incremental { 1.0 } else { 0.0 }),
                "_task" => Some(0.0),
                "_vmajor" => Some(2.0),
                "_vminor" => Some(9.0),
                _ => None,
            };
        }
        self.locals.last().and_then(|m| m.get(name).copied())
    }
}

/// The RS274/NGC interpreter, streaming records (see the module documentation).
pub struct Interpreter {
    opts: InterpOptions,
    files: Vec<Source>,
    cur: usize,
    lexer: Lexer,
    /// A second block for [`Interpreter::exec_lexed`].
    spare_block: Option<Box<Block>>,
    buf: Vec<u8>,
    params: Params,
    out: VecDeque<Record>,
    state: RunState,
    error: Option<NcError>,
    // position of the line being executed
    line_start: Pos,
    line_no: usize,
    line_n: Option<Real>,
    // modal state
    u: Real,
    ext: Real,
    plane: Plane,
    incremental: bool,
    arc_incremental: bool,
    feed_mode: FeedMode,
    feed: Real,
    spindle_cw: Option<bool>,
    motion: Option<i32>,
    retract_r: bool,
    cycle_z: Option<Real>,
    cycle_r: Option<Real>,
    cycle_q: Option<Real>,
    coord: usize,
    g5x: [Real; 6],
    g92: [Real; 6],
    rot: Real,
    tool_off: [Real; 6],
    tool: i32,
    selected: i32,
    mpos: [Real; 6],
    /// Where the last emitted move ended when that differs from `mpos` (LinuxCNC's G84
    /// in G18/G19): the start of the next record.
    out_pos: Option<[Real; 6]>,
    comp_on: bool,
    /// Cutter radius compensation in effect (G41/G42 … G40).
    comp: Option<Compensator<CompPayload>>,
    /// The plane compensation works in.
    comp_plane: CompPlane,
    /// The programmed current point (program coordinates, mm) while compensation or its
    /// exit move decides it (the machine is then elsewhere).
    prog_override: Option<[Real; 6]>,
    /// After G40: the next move is the exit move and must be straight.
    exit_pending: bool,
    // control flow
    frames: Vec<Frame>,
    loops: HashMap<(usize, String), LoopState>,
    ifs: HashMap<(usize, String), bool>,
    subs: HashMap<String, Pos>,
    fanuc_subs: HashMap<String, Pos>,
    skip: Option<Skip>,
    percent_started: bool,
    first_line: bool,
    main_title: bool,
    blocks: u64,
}

/// What the interpreter attaches to a move or event held by the compensator.
#[derive(Clone, Debug)]
struct CompPayload {
    line: usize,
    n: Option<Real>,
    file: usize,
    feed: Option<Real>,
    per_rev: bool,
    /// Program A B C at the end of the move.
    abc: [Real; 3],
    /// Set for a held event.
    event: Option<Event>,
}

/// A located error for the current line.
struct LineErr {
    col: usize,
    word: String,
    message: String,
}

type LR<T> = Result<T, LineErr>;

fn lerr(col: usize, word: &str, message: impl Into<String>) -> LineErr {
    LineErr {
        col,
        word: word.to_string(),
        message: message.into(),
    }
}

fn round4(v: Real) -> Real {
    (v * 1e4).round() / 1e4
}

impl Interpreter {
    /// An interpreter over a program held in memory.
    pub fn from_text(text: &str, path: &Path, opts: InterpOptions) -> Interpreter {
        let src = Source::from_bytes(Arc::from(text.as_bytes()), path);
        Interpreter::with_source(src, opts)
    }

    /// An interpreter reading the program file at `path` as it goes (constant memory).
    pub fn from_file(path: &Path, opts: InterpOptions) -> Result<Interpreter, NcError> {
        let src = Source::open(path).map_err(|e| NcError {
            diagnostics: vec![Diagnostic {
                path: path.to_path_buf(),
                line: 0,
                column: 0,
                word: String::new(),
                message: format!("cannot read program: {e}"),
            }],
        })?;
        Ok(Interpreter::with_source(src, opts))
    }

    fn with_source(src: Source, opts: InterpOptions) -> Interpreter {
        let ext = match opts.external_unit {
            LengthUnit::Mm => 1.0,
            LengthUnit::Inch => MM_PER_INCH,
        };
        let mut numbered = vec![0.0; NUM_PARAMS];
        for (n, v) in &opts.parameters {
            if *n < NUM_PARAMS {
                numbered[*n] = *v;
            }
        }
        if numbered[5220] < 1.0 || numbered[5220] > 9.0 {
            numbered[5220] = 1.0;
        }
        let coord = numbered[5220] as usize;
        let mpos = opts.start.to_array();
        let mut it = Interpreter {
            files: vec![src],
            cur: 0,
            lexer: Lexer::default(),
            spare_block: None,
            buf: Vec::with_capacity(256),
            params: Params {
                numbered,
                globals: HashMap::from([
                    ("_value".to_string(), 0.0),
                    ("_value_returned".to_string(), 0.0),
                ]),
                locals: vec![HashMap::new()],
                snap_pos: [0.0; 6],
                snap_line: 0.0,
                metric: true,
                incremental: false,
            },
            out: VecDeque::new(),
            state: RunState::Running,
            error: None,
            line_start: Pos {
                file: 0,
                offset: 0,
                line: 1,
            },
            line_no: 0,
            line_n: None,
            u: 1.0,
            ext,
            plane: Plane::Xy,
            incremental: false,
            arc_incremental: true,
            feed_mode: FeedMode::PerMinute,
            feed: 0.0,
            spindle_cw: None,
            motion: None,
            retract_r: true,
            cycle_z: None,
            cycle_r: None,
            cycle_q: None,
            coord,
            g5x: [0.0; 6],
            g92: [0.0; 6],
            rot: 0.0,
            tool_off: [0.0; 6],
            tool: 0,
            selected: 0,
            mpos,
            out_pos: None,
            comp_on: false,
            comp: None,
            comp_plane: CompPlane::Xy,
            prog_override: None,
            exit_pending: false,
            frames: Vec::new(),
            loops: HashMap::new(),
            ifs: HashMap::new(),
            subs: HashMap::new(),
            fanuc_subs: HashMap::new(),
            skip: None,
            percent_started: false,
            first_line: true,
            main_title: false,
            blocks: 0,
            opts,
        };
        it.load_offsets();
        it.event(
            "USE_LENGTH_UNITS",
            vec![EventArg::Text("CANON_UNITS_MM".into())],
        );
        it.announce_g5x();
        it.announce_g92();
        it
    }

    /// The next record, or the error that stopped the program (returned once), or `None`
    /// when the program has ended.
    pub fn next_record(&mut self) -> Option<Result<Record, NcError>> {
        loop {
            if let Some(r) = self.out.pop_front() {
                return Some(Ok(r));
            }
            match self.state {
                RunState::Running => self.step(),
                RunState::Ended => return None,
                RunState::Failed => return self.error.take().map(Err),
            }
        }
    }

    // ------------------------------------------------------------------ helpers

    fn path(&self) -> Arc<Path> {
        self.files[self.cur].path.clone()
    }

    fn event(&mut self, call: &'static str, args: Vec<EventArg>) {
        if self.comp.is_some() {
            let mut payload = self.payload(None, &[0.0; 6]);
            payload.event = Some(Event { call, args });
            if let Some(c) = self.comp.as_mut() {
                c.push_event(payload);
            }
            return;
        }
        let rec = Record {
            body: RecordBody::Event(Event { call, args }),
            path: self.files[self.cur].path.clone(),
            line: self.line_no,
            n: self.line_n,
        };
        self.out.push_back(rec);
    }

    fn motion(&mut self, mut m: Motion) {
        if let Some(p) = self.out_pos.take() {
            m.start = AxisValues::from_array(p);
        }
        let rec = Record {
            body: RecordBody::Motion(m),
            path: self.files[self.cur].path.clone(),
            line: self.line_no,
            n: self.line_n,
        };
        self.out.push_back(rec);
    }

    fn pu(&self, mm: Real) -> EventArg {
        EventArg::Num(round4(mm / self.u))
    }

    fn announce_g5x(&mut self) {
        let mut args = vec![EventArg::Num(self.coord as Real)];
        for i in 0..6 {
            args.push(if i < 3 {
                self.pu(self.g5x[i])
            } else {
                EventArg::Num(self.g5x[i])
            });
        }
        self.event("SET_G5X_OFFSET", args);
        self.event("SET_XY_ROTATION", vec![EventArg::Num(self.rot)]);
    }

    fn announce_g92(&mut self) {
        let args = (0..6)
            .map(|i| {
                if i < 3 {
                    self.pu(self.g92[i])
                } else {
                    EventArg::Num(self.g92[i])
                }
            })
            .collect();
        self.event("SET_G92_OFFSET", args);
    }

    /// Recomputes offsets (mm) from the parameters (external unit).
    fn load_offsets(&mut self) {
        let base = 5201 + 20 * self.coord;
        for i in 0..6 {
            let v = self.params.numbered[base + i];
            self.g5x[i] = if i < 3 { v * self.ext } else { v };
        }
        self.rot = self.params.numbered[base + 9];
        let on = self.params.numbered[5210] != 0.0;
        for i in 0..6 {
            let v = if on {
                self.params.numbered[5211 + i]
            } else {
                0.0
            };
            self.g92[i] = if i < 3 { v * self.ext } else { v };
        }
    }

    /// Program coordinates (mm, deg) → machine.
    fn to_machine(&self, p: &[Real; 6]) -> [Real; 6] {
        let mut q = [0.0; 6];
        for i in 0..6 {
            q[i] = p[i] + self.g92[i];
        }
        if self.rot != 0.0 {
            let (s, c) = self.rot.to_radians().sin_cos();
            let (x, y) = (q[0], q[1]);
            q[0] = x * c - y * s;
            q[1] = x * s + y * c;
        }
        for i in 0..6 {
            q[i] += self.g5x[i] + self.tool_off[i];
        }
        q
    }

    /// Machine → program coordinates (mm, deg).
    fn to_program(&self, m: &[Real; 6]) -> [Real; 6] {
        let mut q = [0.0; 6];
        for i in 0..6 {
            q[i] = m[i] - self.g5x[i] - self.tool_off[i];
        }
        if self.rot != 0.0 {
            let (s, c) = self.rot.to_radians().sin_cos();
            let (x, y) = (q[0], q[1]);
            q[0] = x * c + y * s;
            q[1] = -x * s + y * c;
        }
        for i in 0..6 {
            q[i] -= self.g92[i];
        }
        q
    }

    fn prog(&self) -> [Real; 6] {
        match self.prog_override {
            Some(p) => p,
            None => self.to_program(&self.mpos),
        }
    }

    fn col(&self, byte: usize) -> usize {
        let b = byte.min(self.buf.len());
        String::from_utf8_lossy(&self.buf[..b]).chars().count() + 1
    }

    fn word_text(&self, byte: usize) -> String {
        let b = byte.min(self.buf.len());
        let rest = &self.buf[b..];
        let mut end = 1.min(rest.len());
        while end < rest.len()
            && !rest[end].is_ascii_alphabetic()
            && rest[end] != b'('
            && rest[end] != b';'
        {
            end += 1;
        }
        String::from_utf8_lossy(&rest[..end]).trim().to_string()
    }

    fn err_at(&self, byte: usize, message: impl Into<String>) -> LineErr {
        LineErr {
            col: self.col(byte),
            word: self.word_text(byte),
            message: message.into(),
        }
    }

    fn err_word(&self, b: &Block, letter: u8, message: impl Into<String>) -> LineErr {
        self.err_at(b.pos(letter), message)
    }

    fn err_g(&self, b: &Block, g: i32, message: impl Into<String>) -> LineErr {
        let pos = b
            .gs()
            .iter()
            .find(|(c, _)| *c == g)
            .map_or(0, |(_, p)| *p as usize);
        self.err_at(pos, message)
    }

    fn fail(&mut self, e: LineErr) {
        let d = Diagnostic {
            path: self.files[self.cur].path.to_path_buf(),
            line: self.line_no,
            column: e.col,
            word: e.word,
            message: e.message,
        };
        let mut diagnostics = vec![d];
        self.collect_syntax_errors(&mut diagnostics);
        self.error = Some(NcError { diagnostics });
        self.state = RunState::Failed;
    }

    /// After a stopping error: every syntax error of the rest of the current file.
    fn collect_syntax_errors(&mut self, diags: &mut Vec<Diagnostic>) {
        let mut lexer = Lexer::default();
        let mut buf = Vec::new();
        let path = self.files[self.cur].path.to_path_buf();
        loop {
            let (_, line) = self.files[self.cur].tell();
            match self.files[self.cur].read_line(&mut buf) {
                Ok(true) => {}
                _ => break,
            }
            if buf.first() == Some(&b'%') {
                continue;
            }
            if let Err(e) = lexer.read(&buf, &NoParams) {
                if e.message.contains("not defined") {
                    continue;
                }
                let col = String::from_utf8_lossy(&buf[..e.start.min(buf.len())])
                    .chars()
                    .count()
                    + 1;
                let word =
                    String::from_utf8_lossy(&buf[e.start.min(buf.len())..e.end.min(buf.len())])
                        .into_owned();
                diags.push(Diagnostic {
                    path: path.clone(),
                    line,
                    column: col,
                    word,
                    message: e.message,
                });
            }
        }
    }

    fn lex_error(&self, e: LexError) -> LineErr {
        let s = e.start.min(self.buf.len());
        let end = e.end.clamp(s, self.buf.len());
        LineErr {
            col: self.col(s),
            word: String::from_utf8_lossy(&self.buf[s..end]).into_owned(),
            message: e.message,
        }
    }

    // ------------------------------------------------------------------ reading

    fn seek(&mut self, pos: Pos) -> LR<()> {
        self.cur = pos.file;
        self.files[self.cur]
            .seek(pos.offset, pos.line)
            .map_err(|e| lerr(1, "", format!("cannot seek in program: {e}")))
    }

    fn tell(&self) -> Pos {
        let (offset, line) = self.files[self.cur].tell();
        Pos {
            file: self.cur,
            offset,
            line,
        }
    }

    /// Reads and executes one line.
    fn step(&mut self) {
        self.blocks += 1;
        if self.blocks > self.opts.max_blocks {
            let e = lerr(
                1,
                "",
                format!(
                    "more than {} blocks executed (endless loop?)",
                    self.opts.max_blocks
                ),
            );
            self.fail(e);
            return;
        }
        self.line_start = self.tell();
        let mut buf = std::mem::take(&mut self.buf);
        let more = self.files[self.cur].read_line(&mut buf);
        self.buf = buf;
        self.line_no = self.line_start.line;
        self.line_n = None;
        match more {
            Err(e) => {
                let e = lerr(1, "", format!("cannot read program: {e}"));
                self.fail(e);
            }
            Ok(false) => self.at_eof(),
            Ok(true) => {
                if let Err(e) = self.line() {
                    self.fail(e);
                }
            }
        }
    }

    fn at_eof(&mut self) {
        let last = self.line_no.saturating_sub(1).max(1);
        self.at_eof_line(last, false);
    }

    /// The end of the file (or a closing `%`) at line `last`.
    fn at_eof_line(&mut self, last: usize, percent: bool) {
        self.line_no = last;
        if let Some(skip) = &self.skip {
            if let Some(call) = skip.call.clone()
                && !call.searched_external
                && !percent
                && !call.fanuc
            {
                self.skip = None;
                if let Err(e) = self.call_external(call) {
                    self.fail(e);
                }
                return;
            }
            let msg = match &skip.call {
                Some(c) if c.fanuc || percent => {
                    format!("Failed to find sub 'O{}' before EOF", c.label)
                }
                Some(c) => format!("Unable to find subroutine o{}", c.label),
                None => format!("Reached end of file while skipping to O{}", skip.label),
            };
            let e = lerr(1, "", msg);
            self.fail(e);
            return;
        }
        if self.cur != 0 || !self.frames.is_empty() {
            let e = lerr(1, "", "File ended inside a subroutine");
            self.fail(e);
            return;
        }
        if self.percent_started {
            let e = lerr(1, "", "File ended with no percent sign");
            self.fail(e);
            return;
        }
        let e = lerr(1, "", "File ended with no percent sign or program end");
        self.fail(e);
    }

    fn line(&mut self) -> LR<()> {
        // '%' lines
        let first_non_blank = self.buf.iter().position(|c| !matches!(c, b' ' | b'\t'));
        if let Some(i) = first_non_blank
            && self.buf[i] == b'%'
        {
            if self.skip.is_some() && !self.first_line {
                self.at_eof_line(self.line_no, true);
                return Ok(());
            }
            if self.first_line {
                self.first_line = false;
                self.percent_started = true;
                return Ok(());
            }
            self.end_program();
            return Ok(());
        }
        if first_non_blank.is_some() {
            self.first_line = false;
        }
        if self.skip.is_some() {
            return self.skip_line();
        }
        let reads_params = match self.lexer.prepare(&self.buf) {
            Ok(h) => h,
            Err(e) => return Err(self.lex_error(e)),
        };
        if reads_params {
            self.params.snap_line = self.line_no as Real;
            let p = self.prog();
            for (i, v) in p.iter().enumerate() {
                self.params.snap_pos[i] = if i < 3 { v / self.u } else { *v };
            }
            self.params.metric = self.u == 1.0;
            self.params.incremental = self.incremental;
        }
        if let Err(e) = self.lexer.parse(&self.buf, &self.params) {
            return Err(self.lex_error(e));
        }
        self.exec_lexed()
    }

    /// Executes the block the lexer has just read (moved out by swapping boxes, so the
    /// interpreter can be borrowed mutably while the block is read).
    fn exec_lexed(&mut self) -> LR<()> {
        let spare = self.spare_block.take().unwrap_or_default();
        let block = std::mem::replace(&mut self.lexer.block, spare);
        let r = self.exec_block(&block);
        self.spare_block = Some(std::mem::replace(&mut self.lexer.block, block));
        r
    }

    /// A line read while skipping to an O-word target.
    fn skip_line(&mut self) -> LR<()> {
        let r = self.lexer.read(&self.buf, &NoParams);
        if r.is_err() {
            return Ok(());
        }
        let Some(skip) = &self.skip else {
            return Ok(());
        };
        if skip.fanuc_body {
            if self.lexer.block.ms().iter().any(|(m, _)| *m == 99) {
                self.skip = None;
            }
            return Ok(());
        }
        let Some(o) = &self.lexer.block.o else {
            return Ok(());
        };
        // remember sub definitions passed over by a forward search
        if skip.then == SkipThen::CallFound {
            let target = skip.call.as_ref().map(|c| (c.label.clone(), c.fanuc));
            if let Some((label, fanuc)) = target {
                let is_def = if fanuc {
                    o.keyword == OKeyword::Fanuc
                } else {
                    o.keyword == OKeyword::Sub
                };
                let wrong_style = if fanuc {
                    o.keyword == OKeyword::Sub
                } else {
                    o.keyword == OKeyword::Fanuc
                };
                if wrong_style && o.label == label {
                    self.skip = None;
                    let msg = if fanuc {
                        "'O.... sub' subroutine must be called with 'O.... call'"
                    } else {
                        "Fanuc 'O....' subroutine must be called with 'M98'"
                    };
                    let at = self.lexer.block.o_pos;
                    return Err(self.err_at(at, msg));
                }
                if is_def && o.label == label {
                    let skip = self.skip.take();
                    let pos = self.tell();
                    if fanuc {
                        self.fanuc_subs.insert(label, pos);
                    } else {
                        self.subs.insert(label, pos);
                    }
                    if let Some(call) = skip.and_then(|s| s.call) {
                        return self.enter_sub(call, pos);
                    }
                    return Ok(());
                }
                if o.keyword == OKeyword::Sub && !self.subs.contains_key(&o.label) {
                    let pos = self.tell();
                    self.subs.insert(o.label.clone(), pos);
                }
            }
            return Ok(());
        }
        if o.keyword == OKeyword::Sub && skip.until == [OKeyword::EndSub] && o.label != skip.label {
            let at = self.lexer.block.o_pos;
            self.skip = None;
            return Err(self.err_at(at, "Nested subroutine definition"));
        }
        if o.label == skip.label && skip.until.contains(&o.keyword) {
            let then = skip.then;
            self.skip = None;
            if then == SkipThen::Exec {
                // re-read with real parameters and execute
                if let Err(e) = self.lexer.read(&self.buf, &self.params) {
                    return Err(self.lex_error(e));
                }
                return self.exec_lexed();
            }
            if let Some(o) = &self.lexer.block.o {
                let key = (self.frames.len(), o.label.clone());
                if matches!(
                    o.keyword,
                    OKeyword::EndWhile | OKeyword::EndRepeat | OKeyword::While
                ) {
                    self.loops.remove(&key);
                }
                if o.keyword == OKeyword::EndIf {
                    self.ifs.remove(&key);
                }
            }
        }
        Ok(())
    }

    fn end_program(&mut self) {
        self.event("PROGRAM_END", Vec::new());
        self.state = RunState::Ended;
    }

    // ------------------------------------------------------------------ O-words

    fn skip_to(&mut self, label: &str, until: &'static [OKeyword], then: SkipThen) {
        self.skip = Some(Skip {
            label: label.to_string(),
            until,
            then,
            fanuc_body: false,
            call: None,
        });
    }

    fn oword(&mut self, o: &OWord, b: &Block) -> LR<()> {
        let depth = self.frames.len();
        let key = (depth, o.label.clone());
        let here = self.line_start;
        let opos = b.o_pos;
        match o.keyword {
            OKeyword::Sub => {
                let pos = self.tell();
                if let Some(f) = self.frames.last()
                    && !f.fanuc
                    && f.label == o.label
                {
                    return Err(self.err_at(opos, "Nested subroutine definition"));
                }
                if self.main_title && self.frames.is_empty() {
                    let msg = format!(
                        "File:{} line:{} sub: o|{}| found in illegal location",
                        self.files[self.cur].path.display(),
                        self.line_no,
                        o.label.trim_start_matches('<').trim_end_matches('>')
                    );
                    return Err(self.err_at(opos, msg));
                }
                self.subs.insert(o.label.clone(), pos);
                self.skip_to(&o.label, &[OKeyword::EndSub], SkipThen::Consume);
            }
            OKeyword::Fanuc => {
                // in the normal flow a bare O-number is a program title; subprogram bodies
                // are found by the search of an M98 call
                self.main_title = true;
            }
            OKeyword::EndSub | OKeyword::Return => {
                if self.frames.is_empty() {
                    if o.keyword == OKeyword::Return {
                        return Err(self.err_at(opos, "Return outside of a subroutine"));
                    }
                    return Err(self.err_at(opos, "Endsub outside of a subroutine"));
                }
                if self.frames.last().is_some_and(|f| f.fanuc) {
                    return Err(self.err_at(
                        opos,
                        "Fanuc 'O....' subroutine definition must end with 'M99'",
                    ));
                }
                if let Some(v) = o.value {
                    self.params.globals.insert("_value".into(), v);
                    self.params.globals.insert("_value_returned".into(), 1.0);
                } else {
                    self.params.globals.insert("_value".into(), 0.0);
                    self.params.globals.insert("_value_returned".into(), 0.0);
                }
                self.return_from_sub()?;
            }
            OKeyword::Call => {
                let call = PendingCall {
                    label: o.label.clone(),
                    args: o.args.clone(),
                    fanuc: false,
                    repeat: 1,
                    ret: self.tell(),
                    err_line: self.line_no,
                    err_path: self.path(),
                    searched_external: false,
                };
                if self.fanuc_subs.contains_key(&o.label) && !self.subs.contains_key(&o.label) {
                    return Err(
                        self.err_at(opos, "Fanuc 'O....' subroutine must be called with 'M98'")
                    );
                }
                self.call(call)?;
            }
            OKeyword::If => {
                let c = o.value.unwrap_or(0.0) != 0.0;
                self.ifs.insert(key, c);
                if !c {
                    self.skip_to(
                        &o.label,
                        &[OKeyword::ElseIf, OKeyword::Else, OKeyword::EndIf],
                        SkipThen::Exec,
                    );
                }
            }
            OKeyword::ElseIf => {
                let taken = self.ifs.get(&key).copied().unwrap_or(true);
                if taken {
                    self.skip_to(&o.label, &[OKeyword::EndIf], SkipThen::Consume);
                } else {
                    let c = o.value.unwrap_or(0.0) != 0.0;
                    if c {
                        self.ifs.insert(key, true);
                    } else {
                        self.skip_to(
                            &o.label,
                            &[OKeyword::ElseIf, OKeyword::Else, OKeyword::EndIf],
                            SkipThen::Exec,
                        );
                    }
                }
            }
            OKeyword::Else => {
                let taken = self.ifs.get(&key).copied().unwrap_or(true);
                if taken {
                    self.skip_to(&o.label, &[OKeyword::EndIf], SkipThen::Consume);
                } else {
                    self.ifs.insert(key, true);
                }
            }
            OKeyword::EndIf => {
                self.ifs.remove(&key);
            }
            OKeyword::Do => {
                let pos = self.tell();
                self.loops.insert(
                    key,
                    LoopState {
                        kind: LoopKind::Do,
                        pos,
                        left: 0,
                    },
                );
            }
            OKeyword::While => {
                let c = o.value.unwrap_or(0.0) != 0.0;
                if let Some(l) = self.loops.get(&key)
                    && l.kind == LoopKind::Do
                {
                    if c {
                        let p = l.pos;
                        self.seek(p)?;
                    } else {
                        self.loops.remove(&key);
                    }
                    return Ok(());
                }
                if c {
                    self.loops.insert(
                        key,
                        LoopState {
                            kind: LoopKind::While,
                            pos: here,
                            left: 0,
                        },
                    );
                } else {
                    self.loops.remove(&key);
                    self.skip_to(&o.label, &[OKeyword::EndWhile], SkipThen::Consume);
                }
            }
            OKeyword::EndWhile => {
                if let Some(l) = self.loops.get(&key) {
                    let p = l.pos;
                    self.seek(p)?;
                }
            }
            OKeyword::Repeat => {
                let n = o.value.unwrap_or(0.0).round() as i64;
                if n > 0 {
                    let pos = self.tell();
                    self.loops.insert(
                        key,
                        LoopState {
                            kind: LoopKind::Repeat,
                            pos,
                            left: n,
                        },
                    );
                } else {
                    self.skip_to(&o.label, &[OKeyword::EndRepeat], SkipThen::Consume);
                }
            }
            OKeyword::EndRepeat => {
                if let Some(l) = self.loops.get_mut(&key) {
                    l.left -= 1;
                    if l.left > 0 {
                        let p = l.pos;
                        self.seek(p)?;
                    } else {
                        self.loops.remove(&key);
                    }
                }
            }
            OKeyword::Break => {
                let kind = self.loops.get(&key).map(|l| l.kind);
                self.loops.remove(&key);
                match kind {
                    Some(LoopKind::Do) => {
                        self.skip_to(&o.label, &[OKeyword::While], SkipThen::Consume)
                    }
                    Some(LoopKind::Repeat) => {
                        self.skip_to(&o.label, &[OKeyword::EndRepeat], SkipThen::Consume)
                    }
                    _ => self.skip_to(&o.label, &[OKeyword::EndWhile], SkipThen::Consume),
                }
            }
            OKeyword::Continue => {
                let l = self.loops.get(&key).map(|l| (l.kind, l.pos));
                match l {
                    Some((LoopKind::While, p)) => self.seek(p)?,
                    Some((LoopKind::Do, _)) => {
                        self.skip_to(&o.label, &[OKeyword::While], SkipThen::Exec)
                    }
                    Some((LoopKind::Repeat, _)) => {
                        self.skip_to(&o.label, &[OKeyword::EndRepeat], SkipThen::Exec)
                    }
                    None => {}
                }
            }
        }
        Ok(())
    }

    fn call(&mut self, call: PendingCall) -> LR<()> {
        let known = if call.fanuc {
            self.fanuc_subs.get(&call.label).copied()
        } else {
            self.subs.get(&call.label).copied()
        };
        if let Some(pos) = known {
            return self.enter_sub(call, pos);
        }
        // search forward in the current file, then in external files
        self.skip = Some(Skip {
            label: call.label.clone(),
            until: &[],
            then: SkipThen::CallFound,
            fanuc_body: false,
            call: Some(call),
        });
        Ok(())
    }

    fn call_external(&mut self, mut call: PendingCall) -> LR<()> {
        call.searched_external = true;
        let name = call
            .label
            .trim_start_matches('<')
            .trim_end_matches('>')
            .to_string();
        let mut dirs: Vec<PathBuf> = self.opts.subroutine_path.clone();
        if let Some(d) = self.files[0].path.parent() {
            dirs.push(d.to_path_buf());
        }
        let restore_line = call.err_line;
        for d in dirs {
            let p = d.join(format!("{name}.ngc"));
            if call.fanuc || !p.is_file() {
                continue;
            }
            if let Ok(src) = Source::open(&p) {
                self.files.push(src);
                self.cur = self.files.len() - 1;
                self.skip = Some(Skip {
                    label: call.label.clone(),
                    until: &[],
                    then: SkipThen::CallFound,
                    fanuc_body: false,
                    call: Some(call),
                });
                return Ok(());
            }
        }
        // report at the calling line
        self.cur = call.ret.file;
        self.line_no = restore_line;
        let msg = if call.fanuc {
            format!("Failed to find sub 'O{}' before EOF", call.label)
        } else {
            format!("Unable to open file <{name}.ngc>")
        };
        let _ = call.err_path;
        Err(lerr(1, &format!("o{}", call.label), msg))
    }

    fn enter_sub(&mut self, call: PendingCall, pos: Pos) -> LR<()> {
        if self.frames.len() > 200 {
            return Err(lerr(1, "", "Too many nested subroutine calls"));
        }
        let mut saved = [0.0; 30];
        saved.copy_from_slice(&self.params.numbered[1..31]);
        if !call.fanuc {
            for i in 0..30 {
                self.params.numbered[1 + i] = call.args.get(i).copied().unwrap_or(0.0);
            }
        }
        self.frames.push(Frame {
            ret: call.ret,
            saved,
            locals: HashMap::new(),
            fanuc: call.fanuc,
            repeat_left: call.repeat,
            start: pos,
            label: call.label.clone(),
        });
        let locals = if call.fanuc {
            self.params.locals.last().cloned().unwrap_or_default()
        } else {
            HashMap::new()
        };
        self.params.locals.push(locals);
        self.seek(pos)
    }

    fn return_from_sub(&mut self) -> LR<()> {
        let Some(f) = self.frames.pop() else {
            return Ok(());
        };
        let depth = self.frames.len() + 1;
        self.loops.retain(|(d, _), _| *d < depth);
        self.ifs.retain(|(d, _), _| *d < depth);
        self.params.locals.pop();
        let _ = f.locals;
        if !f.fanuc {
            self.params.numbered[1..31].copy_from_slice(&f.saved);
        }
        self.seek(f.ret)
    }

    // ------------------------------------------------------------------ compensation

    fn payload(&self, feed: Option<Real>, end_p: &[Real; 6]) -> CompPayload {
        CompPayload {
            line: self.line_no,
            n: self.line_n,
            file: self.cur,
            feed,
            per_rev: self.feed_mode == FeedMode::PerRev,
            abc: [end_p[3], end_p[4], end_p[5]],
            event: None,
        }
    }

    fn comp_err(&self, b: &Block, code: i32, e: CompError) -> LineErr {
        self.err_g(b, code, e.to_string())
    }

    fn push_comp(&mut self, mv: PlaneMove<CompPayload>, b: &Block, code: i32) -> LR<()> {
        let r = match self.comp.as_mut() {
            Some(c) => c.push_move(mv),
            None => Ok(()),
        };
        r.map_err(|e| self.comp_err(b, code, e))
    }

    /// G40 / G41 / G42 / G41.1 / G42.1.
    fn comp_change(&mut self, code: i32, b: &Block) -> LR<()> {
        if code == 400 {
            self.comp_on = false;
            if let Some(mut c) = self.comp.take() {
                // events of this block before the G40 stay in order
                let end = c.finish().map_err(|e| self.comp_err(b, code, e))?;
                self.comp = Some(c);
                self.flush_comp();
                self.comp = None;
                self.exit_pending = end.exit_must_be_straight;
                if !self.exit_pending {
                    self.prog_override = None;
                }
            }
            return Ok(());
        }
        if self.comp_on {
            return Err(self.err_g(b, code, "Cannot turn cutter radius comp on when already on"));
        }
        let plane = match self.plane {
            Plane::Xy => CompPlane::Xy,
            Plane::Xz => CompPlane::Zx,
            Plane::Yz => CompPlane::Yz,
        };
        plane
            .check_comp_allowed()
            .map_err(|e| self.comp_err(b, code, e))?;
        let side = if matches!(code, 410 | 411) {
            Side::Left
        } else {
            Side::Right
        };
        let radius = if matches!(code, 411 | 421) {
            let Some(d) = b.word(b'd') else {
                return Err(self.err_g(b, code, "D word missing with G41.1 or G42.1"));
            };
            d * self.u / 2.0
        } else {
            let t = match b.word(b'd') {
                Some(d) => {
                    if d < 0.0 || d.fract() != 0.0 {
                        return Err(self.err_word(b, b'd', "D word must be a positive integer"));
                    }
                    d as i32
                }
                None => self.tool,
            };
            if t == 0 {
                0.0
            } else {
                match self.opts.tool_table.tools.get(&t) {
                    Some(e) => e.diameter * self.ext / 2.0,
                    None => {
                        return Err(self.err_word(
                            b,
                            b'd',
                            format!("Requested tool {t} not found in the tool table"),
                        ));
                    }
                }
            }
        };
        // a pending exit move is replaced by the new entry
        self.exit_pending = false;
        let p = self.prog();
        let (start, along) = plane.split([p[0], p[1], p[2]]);
        let c =
            Compensator::new(side, radius, start, along).map_err(|e| self.comp_err(b, code, e))?;
        self.comp = Some(c);
        self.comp_plane = plane;
        self.comp_on = true;
        self.prog_override = Some(p);
        Ok(())
    }

    /// Emits what the compensator has released.
    fn flush_comp(&mut self) {
        let Some(mut c) = self.comp.take() else {
            return;
        };
        let outs: Vec<CompOutput<CompPayload>> = c.drain().collect();
        let plane = self.comp_plane;
        let (save_line, save_n, save_cur) = (self.line_no, self.line_n, self.cur);
        for o in outs {
            match o {
                CompOutput::Event(p) => {
                    self.line_no = p.line;
                    self.line_n = p.n;
                    self.cur = p.file;
                    if let Some(e) = p.event {
                        self.event(e.call, e.args);
                    }
                }
                CompOutput::Straight {
                    rapid,
                    end,
                    along,
                    payload,
                } => {
                    self.line_no = payload.line;
                    self.line_n = payload.n;
                    self.cur = payload.file;
                    let xyz = plane.join(end, along);
                    let q = [
                        xyz[0],
                        xyz[1],
                        xyz[2],
                        payload.abc[0],
                        payload.abc[1],
                        payload.abc[2],
                    ];
                    let m = self.to_machine(&q);
                    let kind = if rapid {
                        MotionKind::Rapid
                    } else {
                        MotionKind::Linear
                    };
                    let feed = if rapid { None } else { payload.feed };
                    self.emit_line(kind, m, feed);
                }
                CompOutput::Arc {
                    center,
                    ccw,
                    turns,
                    end,
                    along,
                    payload,
                } => {
                    self.line_no = payload.line;
                    self.line_n = payload.n;
                    self.cur = payload.file;
                    let xyz = plane.join(end, along);
                    let q = [
                        xyz[0],
                        xyz[1],
                        xyz[2],
                        payload.abc[0],
                        payload.abc[1],
                        payload.abc[2],
                    ];
                    let cxyz = plane.join(center, along);
                    let (a1, a2, _) = self.plane.axes();
                    let t = turns.min(i32::MAX as u32) as i32;
                    let turn = if ccw { t } else { -t };
                    let (end_m, geom, _) =
                        self.arc_geometry(&q, cxyz[a1], cxyz[a2], turn.max(-1_000_000));
                    let mot = Motion {
                        kind: MotionKind::Arc,
                        start: AxisValues::from_array(self.mpos),
                        end: AxisValues::from_array(end_m),
                        feed: payload.feed,
                        feed_per_rev: payload.per_rev,
                        arc: Some(geom),
                    };
                    self.motion(mot);
                    self.mpos = end_m;
                }
            }
        }
        self.line_no = save_line;
        self.line_n = save_n;
        self.cur = save_cur;
        self.comp = Some(c);
    }

    // ------------------------------------------------------------------ blocks

    fn exec_block(&mut self, b: &Block) -> LR<()> {
        if b.block_delete && self.opts.block_delete {
            return Ok(());
        }
        self.line_n = b.n;
        for a in &b.assigns {
            match a {
                Assign::Numbered(n, v) => self.params.numbered[*n] = *v,
                Assign::Named(name, v) => {
                    if name.starts_with('_') {
                        self.params.globals.insert(name.clone(), *v);
                    } else if let Some(m) = self.params.locals.last_mut() {
                        m.insert(name.clone(), *v);
                    }
                }
            }
        }
        if let Some(o) = &b.o {
            return self.oword(o, b);
        }
        if let Some(m) = &b.message {
            match m {
                Message::Msg(t) => self.event("MESSAGE", vec![EventArg::Text(t.clone())]),
                Message::Debug(_) => {}
            }
        }
        if !b.has_words {
            return Ok(());
        }
        self.exec_words(b)
    }

    /// Checks modal-group conflicts and returns the codes by group.
    fn groups(&self, b: &Block) -> LR<GCodes> {
        let mut g = GCodes::default();
        for &(code, pos) in b.gs() {
            let slot = match code {
                40 | 100 | 280 | 281 | 300 | 301 | 520 | 530 | 920 | 921 | 922 | 923 => {
                    &mut g.nonmodal
                }
                0 | 10 | 20 | 30 | 331 | 382 | 383 | 384 | 385 | 730 | 800 | 810 | 820 | 830
                | 840 | 850 | 860 | 870 | 880 | 890 | 740 | 760 | 50 | 51 | 52 | 330 => {
                    &mut g.motion
                }
                170 | 180 | 190 => &mut g.plane,
                900 | 910 => &mut g.distance,
                901 | 911 => &mut g.arc_distance,
                930 | 940 | 950 => &mut g.feed_mode,
                200 | 210 => &mut g.units,
                400 | 410 | 420 | 411 | 421 => &mut g.comp,
                430 | 431 | 490 => &mut g.length,
                980 | 990 => &mut g.retract,
                540 | 550 | 560 | 570 | 580 | 590 | 591 | 592 | 593 => &mut g.coord,
                610 | 611 | 640 => &mut g.path,
                960 | 970 => &mut g.spindle_mode,
                _ => return Err(self.err_at(pos as usize, "Unknown g code used")),
            };
            if slot.is_some() {
                return Err(self.err_at(pos as usize, "Two G codes used from same modal group"));
            }
            *slot = Some(code);
        }
        Ok(g)
    }

    fn exec_words(&mut self, b: &Block) -> LR<()> {
        let g = self.groups(b)?;
        // M codes by group
        let mut stop = None;
        let mut toolchange = None;
        let mut spindle = None;
        let mut coolant: Vec<i32> = Vec::new();
        let mut m98 = None;
        let mut m99 = None;
        for &(m, pos) in b.ms() {
            let slot = match m {
                0 | 1 | 2 | 30 | 60 => &mut stop,
                6 | 61 => &mut toolchange,
                3 | 4 | 5 | 19 => &mut spindle,
                7..=9 => {
                    coolant.push(m);
                    continue;
                }
                98 => &mut m98,
                99 => &mut m99,
                48..=53 | 62..=68 | 70..=73 => continue,
                _ => return Err(self.err_at(pos as usize, "Unknown m code used")),
            };
            if slot.is_some() {
                return Err(self.err_at(pos as usize, "Two M codes used from same modal group"));
            }
            *slot = Some((m, pos as usize));
        }
        let axis_given = [b'x', b'y', b'z', b'a', b'b', b'c', b'@', b'^']
            .iter()
            .any(|c| b.word(*c).is_some());

        // motion mode after this block
        let motion_now = g.motion.or(self.motion);
        let uses_axes = g
            .nonmodal
            .is_some_and(|c| matches!(c, 100 | 280 | 300 | 520 | 920))
            || g.length == Some(431)
            || g.motion.is_some()
            || (self.motion.is_some()
                && g.nonmodal
                    .is_none_or(|c| !matches!(c, 100 | 280 | 300 | 520 | 920)));
        if axis_given && !uses_axes {
            let first = [b'x', b'y', b'z', b'a', b'b', b'c']
                .iter()
                .find(|c| b.word(**c).is_some())
                .copied()
                .unwrap_or(b'x');
            return Err(self.err_word(
                b,
                first,
                "Cannot use axis values without a g code that uses them",
            ));
        }
        if g.nonmodal
            .is_some_and(|c| matches!(c, 100 | 280 | 300 | 520 | 920))
            && g.motion.is_some()
        {
            return Err(self.err_g(
                b,
                g.nonmodal.unwrap_or(0),
                "Cannot use two g codes that both use axis values",
            ));
        }
        // words without a user
        if b.word(b'r').is_some() {
            let r_ok = matches!(motion_now, Some(20 | 30 | 730 | 740 | 810..=890))
                && (g.motion.is_some() || axis_given)
                || g.nonmodal == Some(100);
            if !r_ok {
                return Err(self.err_word(b, b'r', "R word with no g code that uses it"));
            }
        }
        if b.word(b'k').is_some() {
            let ok = matches!(motion_now, Some(20 | 30 | 330 | 331 | 760))
                && (g.motion.is_some() || axis_given)
                || matches!(motion_now, Some(20 | 30)) && g.motion.is_some();
            if !ok && !matches!(g.motion, Some(20 | 30)) {
                return Err(self.err_word(
                    b,
                    b'k',
                    "K word with no G2, G3, G33, G33.1, G76, or G87 to use it",
                ));
            }
        }
        // E belongs to G76 and M66-M68 only: `X1e5` is X1 followed by a stray E word.
        if b.word(b'e').is_some()
            && g.motion != Some(760)
            && !b.m[..b.nm].iter().any(|(m, _)| matches!(m, 66..=68))
        {
            return Err(self.err_word(b, b'e', "E word with no G76, M66, M67 or M68 to use it"));
        }
        if matches!(motion_now, Some(810..=890 | 730 | 740)) && (g.motion.is_some() || axis_given) {
            for (c, name) in [(b'a', "a"), (b'b', "b"), (b'c', "c")] {
                if b.word(c).is_some() {
                    return Err(self.err_word(
                        b,
                        c,
                        format!("Cannot put an {name} in canned cycle"),
                    ));
                }
            }
        }
        if g.motion == Some(760) {
            if b.word(b'i').is_none() || b.word(b'j').is_none() || b.word(b'k').is_none() {
                return Err(self.err_g(b, 760, "I J or K words missing with G76"));
            }
            return Err(self.err_g(b, 760, "G76 is a lathe cycle, not supported on a mill"));
        }

        // 2. feed mode, 3. feed, 4. speed
        if let Some(fm) = g.feed_mode {
            self.feed_mode = match fm {
                930 => FeedMode::InverseTime,
                950 => FeedMode::PerRev,
                _ => FeedMode::PerMinute,
            };
        }
        if let Some(f) = b.word(b'f') {
            if f < 0.0 {
                return Err(self.err_word(b, b'f', "Negative F word used"));
            }
            self.feed = f * self.u;
            if self.feed_mode == FeedMode::PerMinute {
                self.event("SET_FEED_RATE", vec![EventArg::Num(f)]);
            }
        }
        if let Some(s) = b.word(b's') {
            if s < 0.0 {
                return Err(self.err_word(b, b's', "Negative spindle speed used"));
            }
            self.event(
                "SET_SPINDLE_SPEED",
                vec![EventArg::Num(0.0), EventArg::Num(s)],
            );
        }
        // 5. tool select
        if let Some(t) = b.word(b't') {
            if t < 0.0 {
                return Err(self.err_word(b, b't', "Negative tool id used"));
            }
            let t = t.round() as i32;
            if t != 0 && !self.opts.tool_table.tools.contains_key(&t) {
                return Err(self.err_word(
                    b,
                    b't',
                    format!("Requested tool {t} not found in the tool table"),
                ));
            }
            self.selected = t;
            self.event("SELECT_TOOL", vec![EventArg::Num(t as Real)]);
        }
        // 6. tool change
        if let Some((m, pos)) = toolchange {
            if m == 6 {
                self.tool = self.selected;
                self.event("CHANGE_TOOL", vec![EventArg::Num(self.tool as Real)]);
            } else {
                let Some(q) = b.word(b'q') else {
                    return Err(self.err_at(pos, "Q word missing with M61"));
                };
                self.tool = q.round() as i32;
                self.event("CHANGE_TOOL_NUMBER", vec![EventArg::Num(self.tool as Real)]);
            }
        }
        // 7. spindle
        if let Some((m, _)) = spindle {
            match m {
                3 => {
                    self.spindle_cw = Some(true);
                    self.event("START_SPINDLE_CLOCKWISE", vec![EventArg::Num(0.0)]);
                }
                4 => {
                    self.spindle_cw = Some(false);
                    self.event("START_SPINDLE_COUNTERCLOCKWISE", vec![EventArg::Num(0.0)]);
                }
                5 => {
                    self.spindle_cw = None;
                    self.event("STOP_SPINDLE_TURNING", vec![EventArg::Num(0.0)]);
                }
                _ => self.event("ORIENT_SPINDLE", vec![EventArg::Num(0.0)]),
            }
        }
        // 8. coolant
        for m in coolant {
            let call = match m {
                7 => "MIST_ON",
                8 => "FLOOD_ON",
                _ => "FLOOD_OFF",
            };
            self.event(call, Vec::new());
        }
        // 10. dwell
        if g.nonmodal == Some(40) {
            let Some(p) = b.word(b'p') else {
                return Err(self.err_g(b, 40, "Dwell time missing with G4"));
            };
            if p < 0.0 {
                return Err(self.err_word(b, b'p', "Negative P word used"));
            }
            self.event("DWELL", vec![EventArg::Num(p)]);
        }
        // 11. plane
        if let Some(p) = g.plane {
            self.plane = match p {
                170 => Plane::Xy,
                180 => Plane::Xz,
                _ => Plane::Yz,
            };
            let name = match self.plane {
                Plane::Xy => "CANON_PLANE_XY",
                Plane::Xz => "CANON_PLANE_XZ",
                Plane::Yz => "CANON_PLANE_YZ",
            };
            self.event("SELECT_PLANE", vec![EventArg::Text(name.into())]);
        }
        // 12. units
        if let Some(u) = g.units {
            self.u = if u == 200 { MM_PER_INCH } else { 1.0 };
            let name = if u == 200 {
                "CANON_UNITS_INCHES"
            } else {
                "CANON_UNITS_MM"
            };
            self.event("USE_LENGTH_UNITS", vec![EventArg::Text(name.into())]);
        }
        // 13. cutter compensation
        if let Some(c) = g.comp {
            self.comp_change(c, b)?;
        }
        // 14. tool length
        if let Some(l) = g.length {
            self.tool_length(l, b)?;
        }
        // 15. coordinate system
        if let Some(c) = g.coord {
            let idx = match c {
                540 => 1,
                550 => 2,
                560 => 3,
                570 => 4,
                580 => 5,
                590 => 6,
                591 => 7,
                592 => 8,
                _ => 9,
            };
            if self.comp_on {
                return Err(self.err_g(
                    b,
                    c,
                    "Cannot change coordinate systems with cutter radius compensation on",
                ));
            }
            self.coord = idx;
            self.params.numbered[5220] = idx as Real;
            self.load_offsets();
            self.announce_g5x();
        }
        // 16. path control
        if let Some(p) = g.path {
            let mode = match p {
                610 => "CANON_EXACT_PATH",
                611 => "CANON_EXACT_STOP",
                _ => "CANON_CONTINUOUS",
            };
            self.event("SET_MOTION_CONTROL_MODE", vec![EventArg::Text(mode.into())]);
        }
        // 17. distance modes
        if let Some(d) = g.distance {
            self.incremental = d == 910;
        }
        if let Some(d) = g.arc_distance {
            self.arc_incremental = d == 911;
        }
        // 18. retract mode
        if let Some(r) = g.retract {
            self.retract_r = r == 990;
        }
        // 19. non-modal
        if let Some(nm) = g.nonmodal {
            match nm {
                100 => self.g10(b)?,
                280 | 300 => self.g28(b, nm)?,
                281 | 301 => {
                    let base = if nm == 281 { 5161 } else { 5181 };
                    for i in 0..6 {
                        let v = self.mpos[i];
                        self.params.numbered[base + i] = if i < 3 { v / self.ext } else { v };
                    }
                }
                520 | 920 => self.g92(b, nm)?,
                921 | 922 => {
                    for i in 0..6 {
                        self.g92[i] = 0.0;
                    }
                    if nm == 921 {
                        for i in 0..9 {
                            self.params.numbered[5211 + i] = 0.0;
                        }
                    }
                    self.params.numbered[5210] = 0.0;
                    self.announce_g92();
                }
                923 => {
                    self.params.numbered[5210] = 1.0;
                    self.load_offsets();
                    self.announce_g92();
                }
                _ => {}
            }
        }
        // 20. motion
        if g.motion == Some(800) {
            self.motion = None;
            self.cycle_z = None;
            self.cycle_r = None;
        } else if let Some(m) = g.motion {
            self.motion = Some(m);
        }
        let g53 = g.nonmodal == Some(530);
        let run_motion = g.motion.is_some_and(|m| m != 800)
            || (axis_given
                && g.length != Some(431)
                && g.nonmodal
                    .is_none_or(|c| !matches!(c, 100 | 280 | 300 | 520 | 920))
                && self.motion.is_some());
        if g53 && !matches!(motion_now, Some(0 | 10)) {
            return Err(self.err_g(b, 530, "Must use G0 or G1 with G53"));
        }
        if run_motion && let Some(m) = self.motion {
            self.do_motion(m, b, g53, g.motion.is_some())?;
            if self.exit_pending && matches!(m, 0 | 10) {
                self.exit_pending = false;
                self.prog_override = None;
            }
        }
        if self.comp.is_some() {
            self.flush_comp();
        }
        if g.motion == Some(800) && axis_given {
            return Err(self.err_g(b, 800, "Cannot use axis values with G80"));
        }
        // 21. stops
        if let Some((_, pos)) = m98 {
            let Some(p) = b.word(b'p') else {
                return Err(self.err_at(pos, "Found 'm98' code with no P-word"));
            };
            let label = (p.round() as i64).to_string();
            if self.subs.contains_key(&label) && !self.fanuc_subs.contains_key(&label) {
                return Err(self.err_at(
                    pos,
                    "'O.... sub' subroutine must be called with 'O.... call'",
                ));
            }
            let repeat = b.word(b'l').map_or(1, |l| l.round().max(1.0) as u32);
            let call = PendingCall {
                label,
                args: Vec::new(),
                fanuc: true,
                repeat,
                ret: self.tell(),
                err_line: self.line_no,
                err_path: self.path(),
                searched_external: false,
            };
            return self.call(call);
        }
        if let Some((_, pos)) = m99 {
            match self.frames.last_mut() {
                Some(f) if f.fanuc => {
                    if f.repeat_left > 1 {
                        f.repeat_left -= 1;
                        let p = f.start;
                        self.seek(p)?;
                    } else {
                        self.return_from_sub()?;
                    }
                }
                Some(_) => {
                    return Err(self.err_at(pos, "'O.... endsub' or 'O.... return' must follow 'O.... sub' subroutine definition"));
                }
                None => {
                    // M99 in the main program: rs274 ends the program here
                    self.end_program();
                }
            }
            return Ok(());
        }
        if let Some((m, _)) = stop
            && let Some(c) = self.comp.as_mut()
        {
            let r = if matches!(m, 2 | 30) {
                c.finish().map(|_| ())
            } else {
                c.release_held()
            };
            r.map_err(|e| lerr(1, "", e.to_string()))?;
            self.flush_comp();
            if matches!(m, 2 | 30) {
                self.comp = None;
                self.prog_override = None;
                self.exit_pending = false;
            }
        }
        if let Some((m, _)) = stop {
            match m {
                0 | 60 => self.event("PROGRAM_STOP", Vec::new()),
                1 => self.event("OPTIONAL_PROGRAM_STOP", Vec::new()),
                _ => {
                    if !self.frames.is_empty() || self.cur != 0 {
                        // LinuxCNC ends the whole program
                    }
                    self.reset_at_end();
                    self.end_program();
                }
            }
        }
        Ok(())
    }

    /// M2/M30 resets: G54 offsets, rotation, feed mode, spindle, G92 kept (LinuxCNC keeps
    /// G92 unless DISABLE_G92_PERSISTENCE).
    fn reset_at_end(&mut self) {
        self.coord = 1;
        self.params.numbered[5220] = 1.0;
        self.load_offsets();
        self.announce_g5x();
        self.plane = Plane::Xy;
        self.incremental = false;
        self.feed_mode = FeedMode::PerMinute;
        self.event(
            "SET_FEED_MODE",
            vec![EventArg::Num(0.0), EventArg::Num(0.0)],
        );
        self.event("SET_FEED_RATE", vec![EventArg::Num(0.0)]);
        self.event("STOP_SPINDLE_TURNING", vec![EventArg::Num(0.0)]);
        self.motion = Some(10);
        self.comp_on = false;
    }

    fn tool_length(&mut self, l: i32, b: &Block) -> LR<()> {
        match l {
            490 => self.tool_off = [0.0; 6],
            430 => {
                let t = match b.word(b'h') {
                    Some(h) => {
                        if h < 0.0 {
                            return Err(self.err_word(
                                b,
                                b'h',
                                "Negative H word tool length offset used",
                            ));
                        }
                        h.round() as i32
                    }
                    None => self.tool,
                };
                if t == 0 {
                    self.tool_off = [0.0; 6];
                } else {
                    let Some(e) = self.opts.tool_table.tools.get(&t) else {
                        return Err(self.err_word(
                            b,
                            b'h',
                            format!("Requested tool {t} not found in the tool table"),
                        ));
                    };
                    for i in 0..6 {
                        self.tool_off[i] = if i < 3 {
                            e.offset[i] * self.ext
                        } else {
                            e.offset[i]
                        };
                    }
                }
            }
            _ => {
                // G43.1 dynamic: axis words give the offset in program units
                let mut off = [0.0; 6];
                for (i, c) in [b'x', b'y', b'z', b'a', b'b', b'c'].iter().enumerate() {
                    if let Some(v) = b.word(*c) {
                        off[i] = if i < 3 { v * self.u } else { v };
                    }
                }
                self.tool_off = off;
            }
        }
        let args = (0..6)
            .map(|i| {
                if i < 3 {
                    self.pu(self.tool_off[i])
                } else {
                    EventArg::Num(self.tool_off[i])
                }
            })
            .collect();
        self.event("USE_TOOL_LENGTH_OFFSET", args);
        Ok(())
    }

    fn g10(&mut self, b: &Block) -> LR<()> {
        let Some(l) = b.word(b'l') else {
            return Err(self.err_g(b, 100, "Line number missing with G10"));
        };
        let l = l.round() as i32;
        let p = b.word(b'p').map(|p| p.round() as i32);
        match l {
            2 | 20 => {
                let Some(mut p) = p else {
                    return Err(self.err_g(b, 100, "P word missing with G10 L2"));
                };
                if !(0..=9).contains(&p) {
                    return Err(self.err_word(b, b'p', "P value out of range with G10 L2"));
                }
                if p == 0 {
                    p = self.coord as i32;
                }
                let base = 5201 + 20 * p as usize;
                let active = p as usize == self.coord;
                if l == 2 {
                    for (i, c) in [b'x', b'y', b'z', b'a', b'b', b'c'].iter().enumerate() {
                        if let Some(v) = b.word(*c) {
                            let v_ext = if i < 3 { v * self.u / self.ext } else { v };
                            self.params.numbered[base + i] = v_ext;
                        }
                    }
                    if let Some(r) = b.word(b'r') {
                        self.params.numbered[base + 9] = r;
                    }
                } else {
                    // L20: offsets such that the current point gets the given coordinates
                    let r_new = b.word(b'r').unwrap_or(self.params.numbered[base + 9]);
                    if b.word(b'r').is_some() {
                        self.params.numbered[base + 9] = r_new;
                    }
                    // current point without work offset: m - tool; in the work system
                    // m = rot(p + g92) + off + tool
                    let xy_given = b.word(b'x').is_some() || b.word(b'y').is_some();
                    for (i, c) in [b'x', b'y', b'z', b'a', b'b', b'c'].iter().enumerate() {
                        let word = b
                            .word(*c)
                            .or(if i < 2 && xy_given { Some(0.0) } else { None });
                        if let Some(v) = word {
                            let vm = if i < 3 { v * self.u } else { v };
                            // X and Y together, with the rotation of the target system
                            let off = if i < 2 {
                                let (s, co) = r_new.to_radians().sin_cos();
                                let q = [
                                    b.word(b'x').map_or_else(|| self.prog()[0], |x| x * self.u)
                                        + self.g92[0],
                                    b.word(b'y').map_or_else(|| self.prog()[1], |y| y * self.u)
                                        + self.g92[1],
                                ];
                                let rq = [q[0] * co - q[1] * s, q[0] * s + q[1] * co];
                                self.mpos[i] - self.tool_off[i] - rq[i]
                            } else {
                                self.mpos[i] - self.tool_off[i] - (vm + self.g92[i])
                            };
                            self.params.numbered[base + i] =
                                if i < 3 { off / self.ext } else { off };
                        }
                    }
                }
                if active {
                    self.load_offsets();
                    self.announce_g5x();
                }
            }
            1 | 10 | 11 => {
                let Some(p) = p else {
                    return Err(self.err_g(b, 100, "P word missing with G10 L1"));
                };
                if !self.opts.tool_table.tools.contains_key(&p) {
                    return Err(self.err_word(
                        b,
                        b'p',
                        format!("Requested tool {p} not found in the tool table"),
                    ));
                }
                let prog = self.prog();
                let mut entry = self.opts.tool_table.tools[&p];
                for (i, c) in [b'x', b'y', b'z', b'a', b'b', b'c'].iter().enumerate() {
                    if let Some(v) = b.word(*c) {
                        let vm = if i < 3 { v * self.u } else { v };
                        let val_mm = if l == 1 {
                            vm
                        } else {
                            // the tool length that makes the current point read `v`
                            let base_fixture = if l == 11 { 5201 + 20 * 9 } else { 0 };
                            let fixture = if l == 11 {
                                let fv = self.params.numbered[base_fixture + i];
                                if i < 3 { fv * self.ext } else { fv }
                            } else {
                                self.g5x[i] + self.g92[i]
                            };
                            let _ = prog;
                            self.mpos[i] - fixture - vm
                        };
                        entry.offset[i] = if i < 3 { val_mm / self.ext } else { val_mm };
                    }
                }
                if let Some(r) = b.word(b'r') {
                    entry.diameter = 2.0 * r * self.u / self.ext;
                }
                self.opts.tool_table.tools.insert(p, entry);
            }
            _ => return Err(self.err_word(b, b'l', "Invalid L value with G10")),
        }
        Ok(())
    }

    fn g92(&mut self, b: &Block, code: i32) -> LR<()> {
        let p = self.prog();
        let mut any = false;
        for (i, c) in [b'x', b'y', b'z', b'a', b'b', b'c'].iter().enumerate() {
            if let Some(v) = b.word(*c) {
                any = true;
                let vm = if i < 3 { v * self.u } else { v };
                let new = if code == 920 {
                    p[i] + self.g92[i] - vm
                } else {
                    vm
                };
                self.g92[i] = new;
            }
        }
        if !any {
            return Err(self.err_g(b, code, "All axes missing with G92"));
        }
        for i in 0..6 {
            self.params.numbered[5211 + i] = if i < 3 {
                self.g92[i] / self.ext
            } else {
                self.g92[i]
            };
        }
        self.params.numbered[5210] = 1.0;
        self.announce_g92();
        Ok(())
    }

    fn g28(&mut self, b: &Block, code: i32) -> LR<()> {
        let base = if code == 280 { 5161 } else { 5181 };
        let mut given = [false; 6];
        for (i, c) in [b'x', b'y', b'z', b'a', b'b', b'c'].iter().enumerate() {
            given[i] = b.word(*c).is_some();
        }
        let any = given.iter().any(|g| *g);
        // intermediate point
        let end = self.target(b, false);
        let m_int = self.to_machine(&end);
        self.emit_line(MotionKind::Rapid, m_int, None);
        let mut home = self.mpos;
        for i in 0..6 {
            if !any || given[i] {
                let v = self.params.numbered[base + i];
                home[i] = if i < 3 { v * self.ext } else { v };
            }
        }
        // home is a position of the controlled point without tool offset
        for i in 0..6 {
            if !any || given[i] {
                home[i] += 0.0;
            }
        }
        self.emit_line(MotionKind::Rapid, home, None);
        Ok(())
    }

    /// End point (program coordinates, mm) of the axis words of `b`.
    fn target(&self, b: &Block, _g53: bool) -> [Real; 6] {
        let p = self.prog();
        let mut end = p;
        for (i, c) in [b'x', b'y', b'z', b'a', b'b', b'c'].iter().enumerate() {
            if let Some(v) = b.word(*c) {
                let vm = if i < 3 { v * self.u } else { v };
                end[i] = if self.incremental { p[i] + vm } else { vm };
            }
        }
        // LinuxCNC polar words: @ radius, ^ angle (degrees) about the origin of the XY plane
        let (pr, pa) = (b.word(b'@'), b.word(b'^'));
        if pr.is_some() || pa.is_some() {
            let cur_r = p[0].hypot(p[1]);
            let cur_a = p[1].atan2(p[0]).to_degrees();
            let (r, a) = if self.incremental {
                (
                    cur_r + pr.unwrap_or(0.0) * self.u,
                    cur_a + pa.unwrap_or(0.0),
                )
            } else {
                (pr.map_or(cur_r, |r| r * self.u), pa.unwrap_or(cur_a))
            };
            let (s, c) = a.to_radians().sin_cos();
            end[0] = r * c;
            end[1] = r * s;
        }
        end
    }

    fn emit_line(&mut self, kind: MotionKind, end: [Real; 6], feed: Option<Real>) {
        let m = Motion {
            kind,
            start: AxisValues::from_array(self.mpos),
            end: AxisValues::from_array(end),
            feed,
            feed_per_rev: self.feed_mode == FeedMode::PerRev && feed.is_some(),
            arc: None,
        };
        self.motion(m);
        self.mpos = end;
    }

    fn feed_for(&self, b: &Block, code: i32, length_mm: Real) -> LR<Real> {
        match self.feed_mode {
            FeedMode::InverseTime => {
                let Some(f) = b.word(b'f') else {
                    let name = if code == 10 {
                        "g1"
                    } else if code == 20 {
                        "g2"
                    } else {
                        "g3"
                    };
                    return Err(self.err_g(
                        b,
                        code,
                        format!("F word missing with inverse time {name} move"),
                    ));
                };
                Ok(f * length_mm)
            }
            _ => {
                if self.feed <= 0.0 {
                    let msg = match code {
                        10 => "Cannot do g1 with zero feed rate".to_string(),
                        20 | 30 => "Cannot make arc with zero feed rate".to_string(),
                        382..=385 => "Cannot probe with zero feed rate".to_string(),
                        _ => "Cannot feed with zero feed rate".to_string(),
                    };
                    let pos = b
                        .gs()
                        .iter()
                        .find(|(c, _)| *c == code)
                        .map_or(0, |(_, p)| *p as usize);
                    return Err(self.err_at(pos, msg));
                }
                Ok(self.feed)
            }
        }
    }

    fn do_motion(&mut self, m: i32, b: &Block, g53: bool, explicit: bool) -> LR<()> {
        match m {
            0 | 10 if self.comp.is_some() => {
                if g53 {
                    return Err(self.err_g(b, 530, "Cannot use g53 with cutter radius comp"));
                }
                let end = self.target(b, false);
                let feed = if m == 0 {
                    None
                } else {
                    let len = dist(&self.prog(), &end);
                    Some(self.feed_for(b, 10, len)?)
                };
                let plane = self.comp_plane;
                let (end2, along) = plane.split([end[0], end[1], end[2]]);
                let payload = self.payload(feed, &end);
                let mv = PlaneMove {
                    kind: PlaneMoveKind::Straight { rapid: m == 0 },
                    end: end2,
                    along,
                    payload,
                };
                self.push_comp(mv, b, m)?;
                self.prog_override = Some(end);
            }
            0 | 10 => {
                let end_m = if g53 {
                    let mut e = self.mpos;
                    for (i, c) in [b'x', b'y', b'z', b'a', b'b', b'c'].iter().enumerate() {
                        if let Some(v) = b.word(*c) {
                            e[i] = if i < 3 { v * self.u } else { v };
                        }
                    }
                    e
                } else {
                    let end = self.target(b, false);
                    self.to_machine(&end)
                };
                if m == 0 {
                    self.emit_line(MotionKind::Rapid, end_m, None);
                } else {
                    let len = dist(&self.mpos, &end_m);
                    let f = self.feed_for(b, 10, len)?;
                    self.emit_line(MotionKind::Linear, end_m, Some(f));
                }
            }
            20 | 30 => {
                if self.exit_pending {
                    return Err(self.err_g(b, m, CompError::ArcAfterCompOff.to_string()));
                }
                self.arc(m, b)?
            }
            331 => {
                let Some(k) = b.word(b'k') else {
                    return Err(self.err_g(b, 331, "K word missing with G33.1"));
                };
                let end = self.target(b, false);
                let end_m = self.to_machine(&end);
                let mot = Motion {
                    kind: MotionKind::RigidTap,
                    start: AxisValues::from_array(self.mpos),
                    end: AxisValues::from_array([
                        end_m[0],
                        end_m[1],
                        end_m[2],
                        self.mpos[3],
                        self.mpos[4],
                        self.mpos[5],
                    ]),
                    feed: Some(k * self.u),
                    feed_per_rev: true,
                    arc: None,
                };
                self.motion(mot);
            }
            382..=385 => {
                let axis = [b'x', b'y', b'z', b'a', b'b', b'c']
                    .iter()
                    .any(|c| b.word(*c).is_some());
                if !axis {
                    return Err(self.err_g(b, m, "All axes missing with motion code"));
                }
                let end = self.target(b, false);
                let end_m = self.to_machine(&end);
                let len = dist(&self.mpos, &end_m);
                let f = self.feed_for(b, m, len)?;
                let start = self.mpos;
                self.emit_line(MotionKind::Probe, end_m, Some(f));
                let d = [
                    start[0] - end_m[0],
                    start[1] - end_m[1],
                    start[2] - end_m[2],
                ];
                let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                if n > 0.0 {
                    for i in 0..3 {
                        self.mpos[i] = end_m[i] + PROBE_BACKOFF_MM * d[i] / n;
                    }
                }
            }
            730 | 740 | 810..=890 => self.cycle(m, b, explicit)?,
            _ => {
                return Err(self.err_g(b, m, "Motion mode not supported"));
            }
        }
        Ok(())
    }

    fn arc(&mut self, m: i32, b: &Block) -> LR<()> {
        let (a1, a2, _) = self.plane.axes();
        let off_letters = match self.plane {
            Plane::Xy => (b'i', b'j'),
            Plane::Xz => (b'k', b'i'),
            Plane::Yz => (b'j', b'k'),
        };
        let start_p = self.prog();
        let end_p = self.target(b, false);
        let inch = self.u != 1.0;
        let r_word = b.word(b'r');
        let o1 = b.word(off_letters.0);
        let o2 = b.word(off_letters.1);
        let code = m;
        let axis_letters = [b'x', b'y', b'z'];
        let in_plane_given =
            b.word(axis_letters[a1]).is_some() || b.word(axis_letters[a2]).is_some();
        if r_word.is_none() && o1.is_none() && o2.is_none() {
            return Err(self.err_g(b, code, "R i j k words all missing for arc"));
        }
        let rotation_mag = match b.word(b'p') {
            Some(p) => {
                let pi = p.round();
                if pi < 1.0 || (p - pi).abs() > 1e-4 {
                    return Err(self.err_word(b, b'p', "P value not an integer with G2 or G3"));
                }
                pi as i32
            }
            None => 1,
        };
        let turn = if m == 20 { -rotation_mag } else { rotation_mag };
        let (s1, s2) = (start_p[a1], start_p[a2]);
        let (e1, e2) = (end_p[a1], end_p[a2]);
        let (c1, c2);
        if let Some(r) = r_word {
            if !in_plane_given {
                return Err(self.err_g(
                    b,
                    code,
                    "First axis and second axis both missing with R-format arc",
                ));
            }
            let r = r * self.u;
            let tol = if inch {
                ARC_R_TOL_INCH * MM_PER_INCH
            } else {
                ARC_R_TOL_MM
            };
            if e1 == s1 && e2 == s2 {
                return Err(self.err_g(b, code, "Current point same as end point of arc"));
            }
            let abs_r = r.abs();
            let (m1, m2) = ((e1 + s1) / 2.0, (e2 + s2) / 2.0);
            let mut half = ((m1 - e1).powi(2) + (m2 - e2).powi(2)).sqrt();
            if half - abs_r > tol {
                return Err(self.err_word(b, b'r', "Arc radius too small to reach end point"));
            }
            if half / abs_r > 1.0 - ARC_TINY {
                half = abs_r;
            }
            let base = (e2 - s2).atan2(e1 - s1);
            let theta = if (m == 20 && r > 0.0) || (m == 30 && r < 0.0) {
                base - std::f64::consts::FRAC_PI_2
            } else {
                base + std::f64::consts::FRAC_PI_2
            };
            let t2 = (half / abs_r).asin();
            let off = abs_r * t2.cos();
            c1 = m1 + off * theta.cos();
            c2 = m2 + off * theta.sin();
        } else {
            let i1 = o1.unwrap_or(0.0) * self.u;
            let i2 = o2.unwrap_or(0.0) * self.u;
            if self.arc_incremental {
                c1 = s1 + i1;
                c2 = s2 + i2;
            } else {
                c1 = i1;
                c2 = i2;
            }
            let r1 = ((c1 - s1).powi(2) + (c2 - s2).powi(2)).sqrt();
            let r2 = ((c1 - e1).powi(2) + (c2 - e2).powi(2)).sqrt();
            let tol = if inch {
                ARC_CENTER_TOL_INCH * MM_PER_INCH
            } else {
                ARC_CENTER_TOL_MM
            };
            if r1 < 0.1 * tol * 1e-3 || r2 < 0.1 * tol * 1e-3 {
                return Err(self.err_g(b, code, "Zero radius arc"));
            }
            let abs_err = (r1 - r2).abs();
            let rel_err = abs_err / r1.max(r2);
            if abs_err > 100.0 * tol || (abs_err > tol && rel_err > ARC_CENTER_REL_TOL) {
                let u = self.u;
                let (n1, n2) = (arc_name(self.plane, true), arc_name(self.plane, false));
                let msg = format!(
                    "Radius to end of arc differs from radius to start: start=({n1}{:.4},{n2}{:.4}) center=({n1}{:.4},{n2}{:.4}) end=({n1}{:.4},{n2}{:.4}) r1={:.4} r2={:.4} abs_err={} rel_err={}%",
                    s1 / u,
                    s2 / u,
                    c1 / u,
                    c2 / u,
                    e1 / u,
                    e2 / u,
                    r1 / u,
                    r2 / u,
                    fmt_g4(abs_err / u),
                    fmt_g4(rel_err * 100.0)
                );
                return Err(self.err_g(b, code, msg));
            }
        }
        let (end_m, geom, len) = self.arc_geometry(&end_p, c1, c2, turn);
        let f = self.feed_for(b, code, len)?;
        if self.comp.is_some() {
            let plane = self.comp_plane;
            let (end2, along) = plane.split([end_p[0], end_p[1], end_p[2]]);
            let mut cen = end_p;
            cen[a1] = c1;
            cen[a2] = c2;
            let (center, _) = plane.split([cen[0], cen[1], cen[2]]);
            let payload = self.payload(Some(f), &end_p);
            let mv = PlaneMove {
                kind: PlaneMoveKind::Arc {
                    center,
                    ccw: turn > 0,
                    turns: turn.unsigned_abs(),
                },
                end: end2,
                along,
                payload,
            };
            self.push_comp(mv, b, code)?;
            self.prog_override = Some(end_p);
            return Ok(());
        }
        let mot = Motion {
            kind: MotionKind::Arc,
            start: AxisValues::from_array(self.mpos),
            end: AxisValues::from_array(end_m),
            feed: Some(f),
            feed_per_rev: self.feed_mode == FeedMode::PerRev,
            arc: Some(geom),
        };
        self.motion(mot);
        self.mpos = end_m;
        Ok(())
    }

    /// Machine geometry of an arc from the machine position to program point `end_p`
    /// about the program-plane centre (`c1`, `c2`): end, geometry, length (mm).
    fn arc_geometry(
        &self,
        end_p: &[Real; 6],
        c1: Real,
        c2: Real,
        turn: i32,
    ) -> ([Real; 6], ArcGeom, Real) {
        let (a1, a2, an) = self.plane.axes();
        let mut cen_p = *end_p;
        cen_p[a1] = c1;
        cen_p[a2] = c2;
        let cm = self.to_machine(&cen_p);
        let end_m = self.to_machine(end_p);
        let start_m = self.mpos;
        let mut normal = [0.0; 3];
        normal[an] = 1.0;
        let mut ux = [0.0; 3];
        ux[a1] = 1.0;
        let mut uy = [0.0; 3];
        uy[a2] = 1.0;
        let (s, c) = self.rot.to_radians().sin_cos();
        let rz = |v: [Real; 3]| [v[0] * c - v[1] * s, v[0] * s + v[1] * c, v[2]];
        let (normal, ux, uy) = (rz(normal), rz(ux), rz(uy));
        let proj = |p: &[Real; 6]| {
            let d = [p[0] - cm[0], p[1] - cm[1], p[2] - cm[2]];
            (
                d[0] * ux[0] + d[1] * ux[1] + d[2] * ux[2],
                d[0] * uy[0] + d[1] * uy[1] + d[2] * uy[2],
            )
        };
        let (q1, q2) = proj(&start_m);
        let (w1, w2) = proj(&end_m);
        let radius = q1.hypot(q2);
        let radius_end = w1.hypot(w2);
        let ts = q2.atan2(q1);
        let mut te = w2.atan2(w1);
        if turn < 0 {
            if te + SWEEP_EPS >= ts {
                te -= 2.0 * std::f64::consts::PI;
            }
        } else if te - SWEEP_EPS <= ts {
            te += 2.0 * std::f64::consts::PI;
        }
        let full = if turn > 1 {
            turn - 1
        } else if turn < -1 {
            turn + 1
        } else {
            0
        };
        let sweep = te - ts + 2.0 * std::f64::consts::PI * full as Real;
        let helix = end_m[an] - start_m[an];
        let len = ((sweep * radius).powi(2) + helix * helix).sqrt();
        let geom = ArcGeom {
            center: Point3::new(cm[0], cm[1], cm[2]),
            normal: Vector3::new(normal[0], normal[1], normal[2]),
            plane: self.plane,
            rotation: turn,
            radius,
            radius_end,
            sweep_deg: sweep.to_degrees(),
        };
        (end_m, geom, len)
    }

    fn cycle(&mut self, m: i32, b: &Block, explicit: bool) -> LR<()> {
        let (a1, a2, an) = self.plane.axes();
        let letters = [b'x', b'y', b'z'];
        let z_letter = letters[an];
        let new_mode = explicit;
        if new_mode && b.word(z_letter).is_none() && self.cycle_z.is_none() {
            return Err(self.err_g(
                b,
                m,
                format!(
                    "{} word missing with canned cycle",
                    (z_letter as char).to_ascii_uppercase()
                ),
            ));
        }
        let z_word = match b.word(z_letter) {
            Some(z) => {
                self.cycle_z = Some(z);
                z
            }
            None => self.cycle_z.unwrap_or(0.0),
        };
        let r_word = match b.word(b'r') {
            Some(r) => {
                self.cycle_r = Some(r);
                r
            }
            None => match self.cycle_r {
                Some(r) => r,
                None => {
                    return Err(self.err_g(b, m, "R clearance plane unspecified in canned cycle"));
                }
            },
        };
        if let Some(q) = b.word(b'q') {
            if q <= 0.0 {
                return Err(self.err_word(b, b'q', "Q word must be positive in canned cycle"));
            }
            self.cycle_q = Some(q);
        }
        let repeat = match b.word(b'l') {
            Some(l) => {
                let li = l.round();
                if li < 0.0 {
                    return Err(self.err_word(b, b'l', "Negative L word used"));
                }
                if li > self.opts.max_blocks as Real {
                    return Err(self.err_word(b, b'l', "L word too large"));
                }
                li as i64
            }
            None => 1,
        };
        let p = self.prog();
        let old_cc0 = p[an];
        let (mut aa, mut bb, r, cc, inc_a, inc_b);
        let w1 = b.word(letters[a1]).map(|v| v * self.u);
        let w2 = b.word(letters[a2]).map(|v| v * self.u);
        if self.incremental {
            inc_a = w1.unwrap_or(0.0);
            inc_b = w2.unwrap_or(0.0);
            r = r_word * self.u + old_cc0;
            cc = r + z_word * self.u;
            aa = p[a1];
            bb = p[a2];
        } else {
            inc_a = 0.0;
            inc_b = 0.0;
            r = r_word * self.u;
            cc = z_word * self.u;
            aa = w1.unwrap_or(p[a1]);
            bb = w2.unwrap_or(p[a2]);
        }
        if r < cc {
            let pl = match self.plane {
                Plane::Xy => "XY",
                Plane::Xz => "XZ",
                Plane::Yz => "YZ",
            };
            return Err(self.err_g(b, m, format!("R less than Z in cycle in {pl} plane")));
        }
        if self.feed_mode == FeedMode::InverseTime {
            return Err(self.err_g(b, m, "Cannot use inverse time feed with canned cycles"));
        }
        if self.feed <= 0.0 {
            return Err(self.err_g(b, m, "Cannot feed with zero feed rate"));
        }
        let mut old_cc = old_cc0;
        let mk = |s: &Self, a: Real, bv: Real, c: Real| -> [Real; 6] {
            let mut q = s.prog();
            q[a1] = a;
            q[a2] = bv;
            q[an] = c;
            s.to_machine(&q)
        };
        if old_cc < r {
            let t = mk(self, p[a1], p[a2], r);
            self.emit_line(MotionKind::Rapid, t, None);
            old_cc = r;
        }
        let clear = if self.retract_r { r } else { old_cc };
        let feed = Some(self.feed);
        let peck = if self.u == 1.0 {
            PECK_CLEARANCE_MM
        } else {
            PECK_CLEARANCE_INCH * MM_PER_INCH
        };
        for _ in 0..repeat {
            aa += inc_a;
            bb += inc_b;
            let t = mk(self, aa, bb, old_cc);
            self.emit_line(MotionKind::Rapid, t, None);
            if old_cc != r {
                let t = mk(self, aa, bb, r);
                self.emit_line(MotionKind::Rapid, t, None);
            }
            match m {
                810 | 820 | 860 => {
                    let t = mk(self, aa, bb, cc);
                    self.emit_line(MotionKind::Linear, t, feed);
                    if m != 810
                        && let Some(pw) = b.word(b'p')
                    {
                        self.event("DWELL", vec![EventArg::Num(pw)]);
                    }
                    if m == 860 {
                        self.event("STOP_SPINDLE_TURNING", vec![EventArg::Num(0.0)]);
                    }
                    let t = mk(self, aa, bb, clear);
                    self.emit_line(MotionKind::Rapid, t, None);
                    if m == 860 {
                        self.event("START_SPINDLE_CLOCKWISE", vec![EventArg::Num(0.0)]);
                    }
                }
                740 | 840 => {
                    let right = m == 840;
                    if self.spindle_cw != Some(right) {
                        let msg = if right {
                            "Spindle not turning clockwise in G84 canned cycle"
                        } else {
                            "Spindle not turning counterclockwise in G74 canned cycle"
                        };
                        return Err(self.err_g(b, m, msg));
                    }
                    // LinuxCNC 2.9 feeds the tapping strokes of G18/G19 with the axes of the
                    // other plane (G18 as G19 and G19 as G18); reproduced move for move
                    let (t1, t2, tn) = match self.plane {
                        Plane::Xy => (a1, a2, an),
                        Plane::Xz => Plane::Yz.axes(),
                        Plane::Yz => Plane::Xz.axes(),
                    };
                    let tap = |s: &Self, c: Real| -> [Real; 6] {
                        let mut q = s.prog();
                        q[t1] = aa;
                        q[t2] = bb;
                        q[tn] = c;
                        s.to_machine(&q)
                    };
                    let (fwd, rev) = if right {
                        ("START_SPINDLE_CLOCKWISE", "START_SPINDLE_COUNTERCLOCKWISE")
                    } else {
                        ("START_SPINDLE_COUNTERCLOCKWISE", "START_SPINDLE_CLOCKWISE")
                    };
                    let t = tap(self, cc);
                    self.emit_line(MotionKind::Linear, t, feed);
                    self.event("STOP_SPINDLE_TURNING", vec![EventArg::Num(0.0)]);
                    self.event(rev, vec![EventArg::Num(0.0)]);
                    self.event("DWELL", vec![EventArg::Num(0.0)]);
                    let t = tap(self, clear);
                    self.emit_line(MotionKind::Linear, t, feed);
                    self.event("STOP_SPINDLE_TURNING", vec![EventArg::Num(0.0)]);
                    self.event(fwd, vec![EventArg::Num(0.0)]);
                    if self.plane != Plane::Xy {
                        self.out_pos = Some(self.mpos);
                        self.mpos = mk(self, aa, bb, clear);
                    }
                }
                850 | 890 => {
                    let t = mk(self, aa, bb, cc);
                    self.emit_line(MotionKind::Linear, t, feed);
                    if m == 890
                        && let Some(pw) = b.word(b'p')
                    {
                        self.event("DWELL", vec![EventArg::Num(pw)]);
                    }
                    let t = mk(self, aa, bb, r);
                    self.emit_line(MotionKind::Linear, t, feed);
                    if clear != r {
                        let t = mk(self, aa, bb, clear);
                        self.emit_line(MotionKind::Rapid, t, None);
                    }
                }
                730 | 830 => {
                    let Some(q) = self.cycle_q else {
                        return Err(self.err_g(b, m, "Q word missing with G73 or G83"));
                    };
                    let delta = q * self.u;
                    if (r - cc) / delta > self.opts.max_blocks as Real {
                        return Err(self.err_word(
                            b,
                            b'q',
                            "Q word too small for the depth of the hole",
                        ));
                    }
                    let mut cur = r - delta;
                    while cur > cc {
                        let t = mk(self, aa, bb, cur);
                        self.emit_line(MotionKind::Linear, t, feed);
                        if m == 830 {
                            let t = mk(self, aa, bb, r);
                            self.emit_line(MotionKind::Rapid, t, None);
                        }
                        let t = mk(self, aa, bb, cur + peck);
                        self.emit_line(MotionKind::Rapid, t, None);
                        cur -= delta;
                    }
                    let t = mk(self, aa, bb, cc);
                    self.emit_line(MotionKind::Linear, t, feed);
                    let t = mk(self, aa, bb, clear);
                    self.emit_line(MotionKind::Rapid, t, None);
                }
                _ => return Err(self.err_g(b, m, "Canned cycle not supported")),
            }
            old_cc = clear;
        }
        Ok(())
    }
}

impl Iterator for Interpreter {
    type Item = Result<Record, NcError>;
    fn next(&mut self) -> Option<Self::Item> {
        self.next_record()
    }
}

#[derive(Default)]
struct GCodes {
    nonmodal: Option<i32>,
    motion: Option<i32>,
    plane: Option<i32>,
    distance: Option<i32>,
    arc_distance: Option<i32>,
    feed_mode: Option<i32>,
    units: Option<i32>,
    comp: Option<i32>,
    length: Option<i32>,
    retract: Option<i32>,
    coord: Option<i32>,
    path: Option<i32>,
    spindle_mode: Option<i32>,
}

fn dist(a: &[Real; 6], b: &[Real; 6]) -> Real {
    let l = ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
    if l > 0.0 {
        l
    } else {
        ((a[3] - b[3]).powi(2) + (a[4] - b[4]).powi(2) + (a[5] - b[5]).powi(2)).sqrt()
    }
}

fn arc_name(plane: Plane, first: bool) -> char {
    match (plane, first) {
        (Plane::Xy, true) => 'X',
        (Plane::Xy, false) => 'Y',
        (Plane::Xz, true) => 'Z',
        (Plane::Xz, false) => 'X',
        (Plane::Yz, true) => 'Y',
        (Plane::Yz, false) => 'Z',
    }
}

/// `%.4g`-like formatting used in LinuxCNC's arc error message.
fn fmt_g4(v: Real) -> String {
    if v == 0.0 {
        return "0".into();
    }
    let mag = v.abs().log10().floor() as i32;
    let decimals = (3 - mag).max(0) as usize;
    let s = format!("{v:.decimals$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}
