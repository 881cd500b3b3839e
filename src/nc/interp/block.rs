//! One block: parameter assignments, then an O-word or the words of the block, checked for
//! modal-group conflicts and words without a user, and executed in LinuxCNC's order
//! (comments and messages, feed mode, F, S, T, M6, spindle, coolant, dwell, plane, units,
//! cutter compensation, tool length, coordinate system, path mode, distance mode, retract
//! mode, G10/G28/G30/G52/G92, motion, stops); and the resets of M2/M30.

use crate::math::Real;
use crate::nc::lex::{Assign, Block, Message};
use crate::nc::output::{EventArg, Plane};

use super::errors::{LR, lerr};
use super::{FeedMode, Interpreter, MM_PER_INCH};

impl Interpreter {
    pub(super) fn exec_block(&mut self, b: &Block) -> LR<()> {
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
    #[inline(always)]
    fn groups(&self, b: &Block) -> LR<GCodes> {
        let mut g = GCodes::default();
        for &(code, pos) in b.gs() {
            let slot = match code {
                40 | 53 | 100 | 280 | 281 | 300 | 301 | 520 | 530 | 920 | 921 | 922 | 923 => {
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
            // LinuxCNC (read_g): a G80 beside another motion code gives way to it, in
            // either order (`G0 G80 X1` is G0); two other codes of one group are an error
            match *slot {
                Some(_) if code == 800 => continue,
                Some(800) | None => {}
                Some(_) => {
                    return Err(self.err_at(pos as usize, "Two G codes used from same modal group"));
                }
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
        // polar words (LinuxCNC's enhance_block): only in the XY plane selected before this
        // block, and never beside X or Y
        if let Some(polar) = [b'@', b'^'].into_iter().find(|c| b.word(*c).is_some()) {
            if self.plane != Plane::Xy {
                return Err(self.err_word(
                    b,
                    polar,
                    "Cannot use polar coordinate except in G17 plane",
                ));
            }
            for (c, name) in [(b'x', 'X'), (b'y', 'Y')] {
                if b.word(c).is_some() {
                    return Err(self.err_word(
                        b,
                        c,
                        format!("Cannot specify both polar coordinate and {name} word"),
                    ));
                }
            }
        }

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
            let r_ok = matches!(motion_now, Some(20 | 30 | 730 | 740 | 760 | 810..=890))
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
            && !(g.motion.is_none() && axis_given && self.motion == Some(760))
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
        let nonmodal_takes_axes = g
            .nonmodal
            .is_some_and(|c| matches!(c, 100 | 280 | 300 | 520 | 920));
        let motion_to_be = g
            .motion
            .or(self.motion.filter(|_| axis_given && !nonmodal_takes_axes));
        self.check_spline_thread_words(b, g.motion, motion_to_be, g.nonmodal, g.path, axis_given)?;

        // 2. feed mode, 3. feed, 4. speed
        // Every G93/G94/G95 block is a new mode, even the one in effect: G94 and G95 set
        // the feed rate to zero (an F in the same block counts, read after the mode)
        if let Some(fm) = g.feed_mode {
            self.feed_mode = match fm {
                930 => FeedMode::InverseTime,
                950 => FeedMode::PerRev,
                _ => FeedMode::PerMinute,
            };
            let per_rev = Real::from(u8::from(fm == 950));
            self.event(
                "SET_FEED_MODE",
                vec![EventArg::Num(0.0), EventArg::Num(per_rev)],
            );
            if fm != 930 {
                self.feed = 0.0;
                self.event("SET_FEED_RATE", vec![EventArg::Num(0.0)]);
            }
        }
        if let Some(f) = b.word(b'f') {
            if f < 0.0 {
                return Err(self.err_word(b, b'f', "Negative F word used"));
            }
            self.feed = f * self.u;
            if self.feed_mode != FeedMode::InverseTime {
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
            // LinuxCNC reads the position back from the canon before the next line
            self.resync_pending = true;
            if m == 6 {
                if self.comp_on {
                    return Err(self.err_at(
                        pos,
                        "Cannot change tools with cutter radius compensation on",
                    ));
                }
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
                    let cur_m = self.cur_machine();
                    for (i, v) in cur_m.into_iter().enumerate() {
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
                53 => self.nurbs_end(b, axis_given && g.motion.is_none())?,
                _ => {}
            }
        }
        // 20. motion
        self.motion_before = self.motion;
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
        if g.motion == Some(800)
            || run_motion && !matches!(self.motion, Some(730 | 740 | 810..=890))
        {
            self.cycle_il = None;
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
            return self.m98(b, pos);
        }
        if let Some((_, pos)) = m99 {
            return self.m99(pos);
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
