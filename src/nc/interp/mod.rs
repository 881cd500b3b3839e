//! The interpreter: executes blocks in LinuxCNC's order and streams [`Record`]s.
//!
//! This file holds the [`Interpreter`] type with its modal state, its construction, the
//! iterator over records, the records it emits and the reading loop (a line at a time, lexed
//! with the parameters as they are at that line). The rest is split by topic:
//!
//! * `params`: numbered, local and global named parameters, and the predefined ones;
//! * `errors`: errors located on the current line, and the report of a stopping error;
//! * `block`: one block's words, checked and executed in LinuxCNC's order;
//! * `oword`: O-word control flow, subroutines and Fanuc-style subprograms (M98/M99);
//! * `offsets`: coordinate systems, G92/G52, tool length offsets, G10, G28/G30 and the
//!   conversion between program and machine coordinates;
//! * `cutter_comp`: cutter radius compensation on and off, and the moves it releases;
//! * `motion`: end points, feeds, straight moves, rigid tapping and probing;
//! * `arc`: G2/G3 in the centre and radius formats, and their machine geometry;
//! * `cycle`: the drilling, boring and tapping canned cycles;
//! * `nurbs`: the curve maths of G5/G5.1/G5.2 (LinuxCNC's rational B-spline and its task's
//!   biarc segmentation);
//! * `spline`: G5, G5.1 and G5.2 … G5.3 as the interpreter reads them, and the moves of a
//!   curve;
//! * `thread`: spindle-synchronised motion, G33, and the G76 threading cycle;
//! * `queue`: the records produced and not yet handed out, in reused slots.

mod params;
mod errors;
mod block;
mod oword;
mod offsets;
mod cutter_comp;
mod motion;
mod arc;
mod cycle;
mod nurbs;
mod spline;
mod thread;
mod queue;

use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

use crate::math::Real;

use super::comp::{Compensator, Plane as CompPlane};
use super::lex::{Block, Lexer, NUM_PARAMS};
use super::output::{Event, EventArg, Motion, MotionKind, Plane, Record, RecordBody};
use super::source::{Pos, Source};
use super::{AxisValues, Diagnostic, InterpOptions, LengthUnit, NcError};

pub(crate) use params::Params;

use cutter_comp::CompPayload;
use errors::{LR, lerr};
use oword::{Frame, LoopState, Skip};
use queue::{Origin, Queue};

/// Millimetres per inch.
const MM_PER_INCH: Real = 25.4;

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
    out: Queue,
    /// The front of `out` was lent by [`Interpreter::next_ref`]: it goes at the next call.
    lent: bool,
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
    /// The level (program coordinate along the plane normal, mm) where the present run of
    /// canned cycles began: LinuxCNC's `cycle_il`, forgotten at a motion that is not a cycle.
    cycle_il: Option<Real>,
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
    /// Where the standalone interpreter's canon believes the tool is, minus
    /// `to_program(mpos)` (program coordinates, mm): the tool length changes since the
    /// last move (the canon position does not follow them) and, after a probe, the
    /// difference between the canon's backoff and the machine's. Zero after every move.
    canon_off: [Real; 6],
    /// The current point minus `to_program(mpos)`: LinuxCNC sets its current point to the
    /// canon position after a probe and after a tool change (M6, M61); zero after every
    /// move.
    cur_off: [Real; 6],
    /// `canon_off` or `cur_off` is not zero.
    offs_set: bool,
    /// A tool changed in this block: the current point is read back from the canon before
    /// the next line.
    resync_pending: bool,
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
    /// Lines executed since the last move that went somewhere.
    idle_blocks: u64,
    // splines and threading
    /// The motion mode before this block's motion step (LinuxCNC's `motion_mode` there).
    motion_before: Option<i32>,
    /// Control points gathered by G5.2 (program units: X, Y, weight), shared with G5/G5.1
    /// as LinuxCNC shares its list.
    nurbs_points: Vec<[Real; 3]>,
    /// Order of the G5.2 curve (3 unless an L word above 3 says otherwise).
    nurbs_order: usize,
    /// G5's first control-point offset when I and J are left out: the last G5's −P, −Q
    /// (program units).
    spline_ij: [Real; 2],
    /// Feed (mm/min) of the last feed move: what LinuxCNC's task runs a curve at in G93.
    last_feed: Option<Real>,
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
            out: Queue::default(),
            lent: false,
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
            cycle_il: None,
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
            canon_off: [0.0; 6],
            cur_off: [0.0; 6],
            offs_set: false,
            resync_pending: false,
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
            idle_blocks: 0,
            motion_before: None,
            nurbs_points: Vec::new(),
            nurbs_order: 3,
            spline_ij: [0.0; 2],
            last_feed: None,
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
        if self.fill() {
            return self.out.take_front().map(Ok);
        }
        self.error.take().map(Err)
    }

    /// [`Interpreter::next_record`] without moving the record out: it is lent until the
    /// next call. The way to read a long program when each record is only looked at
    /// (written out, converted): a record is about 230 bytes, and moving it out through
    /// the iterator's `Option<Result<…>>` costs a tenth of the interpretation.
    pub fn next_ref(&mut self) -> Option<Result<&Record, NcError>> {
        if self.fill() {
            self.lent = true;
            return self.out.front().map(Ok);
        }
        self.error.take().map(Err)
    }

    /// Drops a lent record and runs lines until a record is waiting (true) or the program
    /// has ended or failed (false).
    fn fill(&mut self) -> bool {
        if self.lent {
            self.lent = false;
            self.out.drop_front();
        }
        while self.out.is_empty() {
            if self.state != RunState::Running {
                return false;
            }
            self.step();
        }
        true
    }

    /// The path of a record's [`Record::file`].
    pub fn file_path(&self, file: usize) -> Option<&Path> {
        self.files.get(file).map(|f| &*f.path)
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
            file: self.cur,
            line: self.line_no,
            n: self.line_n,
        };
        self.out.push(rec);
    }

    /// Emits a move (see [`Queue::push_motion`]).
    #[inline(always)]
    fn motion(&mut self, mut m: Motion) {
        if let Some(p) = self.out_pos.take() {
            m.start = AxisValues::from_array(p);
        }
        if m.start != m.end {
            self.idle_blocks = 0;
        }
        // a move sets the canon position (rs274's rigid tap leaves it, coming back)
        if self.offs_set && m.kind != MotionKind::RigidTap {
            self.canon_off = [0.0; 6];
            self.cur_off = [0.0; 6];
            self.offs_set = false;
        }
        if m.kind != MotionKind::Rapid
            && !m.feed_per_rev
            && let Some(f) = m.feed
            && f > 0.0
        {
            self.last_feed = Some(f);
        }
        let at = Origin {
            file: self.cur,
            line: self.line_no,
            n: self.line_n,
        };
        self.out.push_motion(at, m);
    }

    fn pu(&self, mm: Real) -> EventArg {
        EventArg::Num(round4(mm / self.u))
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
        self.idle_blocks += 1;
        if self.idle_blocks > self.opts.max_idle_blocks {
            let e = lerr(
                1,
                "",
                format!(
                    "more than {} blocks in a row without motion (endless loop?); expected \
                     a move within that many blocks (the limit is [nc] max_idle_blocks, \
                     nc motion --max-idle-blocks)",
                    self.opts.max_idle_blocks
                ),
            );
            self.fail(e);
            return;
        }
        if self.resync_pending {
            // LinuxCNC re-reads the position from the canon after a tool change
            self.resync_pending = false;
            self.cur_off = self.canon_off;
            // also after G40: the programmed point is forgotten for the canon's, which is
            // where the compensated tool went (the exit move must still be straight)
            self.prog_override = None;
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

    fn line(&mut self) -> LR<()> {
        // '%' lines: a program whose first non-blank line is a lone '%' ends at the next
        // one (also while skipping to an O-word); any other '%' is a bad character (read
        // by the lexer), except on a line passed over while skipping
        if is_percent_line(&self.buf) {
            if self.first_line {
                self.first_line = false;
                self.percent_started = true;
                return Ok(());
            }
            if self.percent_started {
                if self.skip.is_some() {
                    self.at_eof_line(self.line_no, true);
                } else {
                    self.end_program();
                }
                return Ok(());
            }
        }
        if self.buf.iter().any(|c| !c_space(*c)) {
            self.first_line = false;
        }
        if self.skip.is_some() {
            return self.skip_line();
        }
        if self.lexer.read_plain(&self.buf) {
            return self.exec_lexed();
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

    fn end_program(&mut self) {
        self.event("PROGRAM_END", Vec::new());
        self.state = RunState::Ended;
    }
}

impl Iterator for Interpreter {
    type Item = Result<Record, NcError>;
    fn next(&mut self) -> Option<Self::Item> {
        self.next_record()
    }
}

/// C's `isspace` in the "C" locale: what LinuxCNC trims around a `%` line.
fn c_space(c: u8) -> bool {
    matches!(c, b' ' | b'\t' | b'\n' | b'\x0b' | b'\x0c' | b'\r')
}

/// A line holding a lone `%` between white space (LinuxCNC's program delimiter).
pub(super) fn is_percent_line(line: &[u8]) -> bool {
    let mut rest = line.iter().filter(|c| !c_space(**c));
    rest.next() == Some(&b'%') && rest.next().is_none()
}
