//! Offsets and coordinate systems: the G54–G59.3 offsets and XY rotation and the G92/G52
//! offset read from the parameters and announced, the conversion between program and
//! machine coordinates, tool length offsets (G43, G43.1, G49), G10 (L1, L2, L10, L11, L20),
//! G52/G92 and the moves to the stored G28/G30 positions.

#![expect(
    clippy::needless_range_loop,
    reason = "six-axis arrays (position, offsets, words) are indexed in parallel"
)]

use crate::math::Real;
use crate::nc::lex::Block;
use crate::nc::output::{EventArg, MotionKind};

use super::Interpreter;
use super::errors::LR;

impl Interpreter {
    pub(super) fn announce_g5x(&mut self) {
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

    pub(super) fn announce_g92(&mut self) {
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
    pub(super) fn load_offsets(&mut self) {
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
    #[inline(always)]
    pub(super) fn to_machine(&self, p: &[Real; 6]) -> [Real; 6] {
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
    #[inline(always)]
    pub(super) fn to_program(&self, m: &[Real; 6]) -> [Real; 6] {
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

    /// The current point (program coordinates, mm).
    #[inline(always)]
    pub(super) fn prog(&self) -> [Real; 6] {
        match self.prog_override {
            Some(p) => p,
            None => {
                let mut p = self.to_program(&self.mpos);
                if self.offs_set {
                    for i in 0..6 {
                        p[i] += self.cur_off[i];
                    }
                }
                p
            }
        }
    }

    /// The machine position of the current point: `mpos`, unless a probe or a tool change
    /// has set the current point elsewhere (see `cur_off`).
    pub(super) fn cur_machine(&self) -> [Real; 6] {
        if self.offs_set && self.prog_override.is_none() {
            self.to_machine(&self.prog())
        } else {
            self.mpos
        }
    }

    /// Where the standalone interpreter's canon believes the tool is (program coordinates,
    /// mm): the end of the last move in the present offsets, before tool length changes
    /// made since.
    pub(super) fn canon_pos(&self) -> [Real; 6] {
        let mut p = self.to_program(&self.mpos);
        for i in 0..6 {
            p[i] += self.canon_off[i];
        }
        p
    }

    /// Sets where the canon and the current point are, as offsets from `to_program(mpos)`.
    pub(super) fn set_canon_offsets(&mut self, canon_off: [Real; 6], cur_off: [Real; 6]) {
        self.canon_off = canon_off;
        self.cur_off = cur_off;
        self.offs_set = canon_off.iter().chain(&cur_off).any(|v| *v != 0.0);
    }

    /// G43, G43.1, G49. The current point keeps its machine position, so its program
    /// coordinates change by the change of offset; the canon's position does not (it moves
    /// with the next move, or the current point is read back from it after a tool change).
    pub(super) fn tool_length(&mut self, l: i32, b: &Block) -> LR<()> {
        if self.comp_on {
            return Err(self.err_g(
                b,
                l,
                "Cannot change tool offset with cutter radius compensation on",
            ));
        }
        let old = self.tool_off;
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
        if self.tool_off != old {
            let mut canon_off = self.canon_off;
            for i in 0..6 {
                canon_off[i] += self.tool_off[i] - old[i];
            }
            self.set_canon_offsets(canon_off, self.cur_off);
            // after G40 the current point is the programmed one (not where the machine
            // is): it too keeps its machine position
            if let Some(p) = self.prog_override.as_mut() {
                for i in 0..6 {
                    p[i] -= self.tool_off[i] - old[i];
                }
            }
        }
        Ok(())
    }

    pub(super) fn g10(&mut self, b: &Block) -> LR<()> {
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
                    let cur_m = self.cur_machine();
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
                                cur_m[i] - self.tool_off[i] - rq[i]
                            } else {
                                cur_m[i] - self.tool_off[i] - (vm + self.g92[i])
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
                let cur_m = self.cur_machine();
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
                            cur_m[i] - fixture - vm
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

    pub(super) fn g92(&mut self, b: &Block, code: i32) -> LR<()> {
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

    pub(super) fn g28(&mut self, b: &Block, code: i32) -> LR<()> {
        let base = if code == 280 { 5161 } else { 5181 };
        let mut given = [false; 6];
        for (i, c) in [b'x', b'y', b'z', b'a', b'b', b'c'].iter().enumerate() {
            given[i] = b.word(*c).is_some();
        }
        let any = given.iter().any(|g| *g);
        // intermediate point
        let end = self.target(b)?;
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
}
