//! Cutter radius compensation as the interpreter drives it: G40/G41/G42/G41.1/G42.1 start
//! and end a [`Compensator`] in the selected plane, moves and events go through it with a
//! [`CompPayload`] naming their line, and what it releases is emitted as machine records.

use crate::math::Real;
use crate::nc::AxisValues;
use crate::nc::comp::{CompError, CompOutput, Compensator, Plane as CompPlane, PlaneMove, Side};
use crate::nc::lex::Block;
use crate::nc::output::{Event, Motion, MotionKind, Plane};

use super::errors::{LR, LineErr};
use super::{FeedMode, Interpreter};

/// What the interpreter attaches to a move or event held by the compensator.
#[derive(Clone, Debug)]
pub(super) struct CompPayload {
    line: usize,
    n: Option<Real>,
    file: usize,
    feed: Option<Real>,
    per_rev: bool,
    /// Program A B C at the end of the move.
    abc: [Real; 3],
    /// Set for a held event.
    pub(super) event: Option<Event>,
}

impl Interpreter {
    pub(super) fn payload(&self, feed: Option<Real>, end_p: &[Real; 6]) -> CompPayload {
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

    pub(super) fn push_comp(&mut self, mv: PlaneMove<CompPayload>, b: &Block, code: i32) -> LR<()> {
        let r = match self.comp.as_mut() {
            Some(c) => c.push_move(mv),
            None => Ok(()),
        };
        r.map_err(|e| self.comp_err(b, code, e))
    }

    /// G40 / G41 / G42 / G41.1 / G42.1.
    pub(super) fn comp_change(&mut self, code: i32, b: &Block) -> LR<()> {
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
    pub(super) fn flush_comp(&mut self) {
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
}
