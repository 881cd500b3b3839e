//! Canned cycles (G73, G74, G81–G86, G89) in the selected plane, with G98/G99 retract,
//! L repeats, incremental positions (also polar: `@` and `^` step before each hole), and the
//! sticky Z, R and Q words.

use crate::math::Real;
use crate::nc::lex::Block;
use crate::nc::output::{EventArg, MotionKind, Plane};

use super::errors::LR;
use super::motion::polar;
use super::{FeedMode, Interpreter, MM_PER_INCH};

/// Rapid clearance above each peck of G73/G83, inch programs (LinuxCNC: 0.010 in).
const PECK_CLEARANCE_INCH: Real = 0.010;
/// Same for mm programs (LinuxCNC: 0.254 mm).
const PECK_CLEARANCE_MM: Real = 0.254;
/// Levels closer than this (mm) are one level: LinuxCNC compares the levels it stored
/// exactly; ours come back from machine coordinates with rounding.
const LEVEL_TOL_MM: Real = 1e-9;

impl Interpreter {
    /// The L word as LinuxCNC reads it (`read_l`): a whole number (within 1e-4), not
    /// negative; `None` without L.
    pub(super) fn l_count(&self, b: &Block) -> LR<Option<u64>> {
        let Some(l) = b.word(b'l') else {
            return Ok(None);
        };
        let whole = l.round();
        if (l - whole).abs() > 1e-4 {
            return Err(self.err_word(b, b'l', "Non integer value for integer"));
        }
        if whole < 0.0 {
            return Err(self.err_word(b, b'l', "Negative L word used"));
        }
        if whole > self.opts.max_blocks as Real {
            return Err(self.err_word(b, b'l', "L word too large"));
        }
        Ok(Some(whole as u64))
    }

    pub(super) fn cycle(&mut self, m: i32, b: &Block, explicit: bool) -> LR<()> {
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
        let repeat = match self.l_count(b)? {
            Some(0) => return Err(self.err_word(b, b'l', "Cannot do zero repeats of cycle")),
            Some(l) => l as i64,
            None => 1,
        };
        let p = self.prog();
        // LinuxCNC 2.9 keeps the level of the first block of a run of cycles (until a
        // motion that is not a cycle) as the old level of every later block: the G98
        // retract height and the base of incremental R
        let current_cc0 = p[an];
        let old_cc0 = *self.cycle_il.get_or_insert(current_cc0);
        let (mut aa, mut bb, r, cc, inc_a, inc_b);
        let w1 = b.word(letters[a1]).map(|v| v * self.u);
        let w2 = b.word(letters[a2]).map(|v| v * self.u);
        // polar words (XY plane only, without X and Y: checked with the block)
        let radius = b.word(b'@').map(|v| v * self.u);
        let theta = b.word(b'^').map(Real::to_radians);
        let (mut inc_radius, mut inc_theta) = (0.0, 0.0);
        if self.incremental {
            inc_a = w1.unwrap_or(0.0);
            inc_b = w2.unwrap_or(0.0);
            inc_radius = radius.unwrap_or(0.0);
            inc_theta = theta.unwrap_or(0.0);
            r = r_word * self.u + old_cc0;
            cc = r + z_word * self.u;
            aa = p[a1];
            bb = p[a2];
        } else {
            inc_a = 0.0;
            inc_b = 0.0;
            r = r_word * self.u;
            cc = z_word * self.u;
            if radius.is_some() || theta.is_some() {
                (aa, bb) = polar(
                    radius.unwrap_or_else(|| p[a2].hypot(p[a1])),
                    theta.unwrap_or_else(|| p[a2].atan2(p[a1])),
                );
            } else {
                aa = w1.unwrap_or(p[a1]);
                bb = w2.unwrap_or(p[a2]);
            }
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
        let mut current_cc = current_cc0;
        let mk = |s: &Self, a: Real, bv: Real, c: Real| -> [Real; 6] {
            let mut q = s.prog();
            q[a1] = a;
            q[a2] = bv;
            q[an] = c;
            s.to_machine(&q)
        };
        if old_cc < r - LEVEL_TOL_MM {
            let t = mk(self, p[a1], p[a2], r);
            self.emit_line(MotionKind::Rapid, t, None);
            old_cc = r;
            current_cc = r;
        }
        let clear = if self.retract_r { r } else { old_cc };
        let feed = Some(self.feed);
        let peck = if self.u == 1.0 {
            PECK_CLEARANCE_MM
        } else {
            PECK_CLEARANCE_INCH * MM_PER_INCH
        };
        for k in 0..repeat {
            aa += inc_a;
            bb += inc_b;
            // LinuxCNC's CYCLE_MACRO: incremental polar words step the radius, then turn,
            // before each hole
            for (step, letter) in [(inc_radius, b'@'), (inc_theta, b'^')] {
                if step == 0.0 {
                    continue;
                }
                if aa == 0.0 && bb == 0.0 {
                    return Err(self.err_word(
                        b,
                        letter,
                        "Incremental motion with polar coordinates is indeterminate when at \
                         the origin",
                    ));
                }
                (aa, bb) = if letter == b'@' {
                    polar(bb.hypot(aa) + step, bb.atan2(aa))
                } else {
                    polar(bb.hypot(aa), bb.atan2(aa) + step)
                };
            }
            // the first hole is reached at the current level, the later ones at the
            // clearance level, each then down to R
            let level = if k == 0 && current_cc > r + LEVEL_TOL_MM {
                current_cc
            } else {
                clear
            };
            let t = mk(self, aa, bb, level);
            self.emit_line(MotionKind::Rapid, t, None);
            if level > r + LEVEL_TOL_MM {
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
                    if (clear - r).abs() > LEVEL_TOL_MM {
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
        }
        Ok(())
    }
}
