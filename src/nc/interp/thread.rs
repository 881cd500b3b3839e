//! Spindle-synchronised motion as LinuxCNC 2.9 does it (`interp_convert.cc`:
//! `convert_straight`, `convert_threading_cycle`, `threading_pass`): G33 is a straight
//! feed at K program units per spindle revolution between `START_SPEED_FEED_SYNC(K, 0)` and
//! `STOP_SPEED_FEED_SYNCH()`; G76 is the threading cycle, which LinuxCNC also runs on a
//! mill, in any plane, always across X (depth) and along Z (thread) at the start's Y.
//!
//! G76: from the start point (the safe X of the cycle) each pass goes back to the depth's
//! clearance X, in to the cut depth (straight, or along an entry taper of length E when L
//! has bit 1), along Z to the end (with an exit taper when L has bit 2) at P per
//! revolution, and back out; the first depth is |I| + |J|, the next |I| + |J|·n^(1/R)
//! (n = 2, 3, …; R ≥ 1, default 1) while below the full depth |I| + |K|, which is cut once
//! and then H more times (spring passes). Q is the compound angle (degrees): each pass
//! starts that much further along Z. I > 0 threads inside (boring). The cycle ends with a
//! traverse to the block's X, Y, Z. The tapers run at P·√(E² + K²)/E per revolution.
//!
//! Both are refused with cutter compensation (LinuxCNC's compensated straight move does
//! only G0 and G1), without a turning spindle, and G76 with A, B or C motion; G33 takes no
//! F and needs K in every block; G76 needs P, I, J, K (I ≠ 0, J > 0, K > J) in every block.
//! Both are modal. Synchronised moves carry the pitch (mm/rev) as their feed.

use crate::math::Real;
use crate::nc::AxisValues;
use crate::nc::comp::{PlaneMove, PlaneMoveKind};
use crate::nc::lex::Block;
use crate::nc::output::{EventArg, Motion, MotionKind};

use super::Interpreter;
use super::errors::LR;

/// Most passes of one G76 block (LinuxCNC loops for ever on a J that is tiny against K or
/// a huge R).
const MAX_G76_PASSES: usize = 10_000;
/// How far a value may be from an integer for LinuxCNC's integer words (L, H).
const INTEGER_TOL: Real = 0.0001;

/// Words LinuxCNC's G76 reads besides X Y Z (program units and degrees).
struct Threading {
    pitch: Real,
    i: Real,
    j: Real,
    k: Real,
    /// Compound angle, degrees (LinuxCNC's −1 when there is no Q: none).
    q: Real,
    spring: i64,
    degression: Option<Real>,
    taper: Option<Real>,
    flags: i64,
}

impl Interpreter {
    /// Checks the words of a block whose motion is one of this file's or of the spline
    /// file's codes, in LinuxCNC's order of `enhance_block` and `check_other_codes`
    /// (`motion_to_be`: the block's motion code, or the modal one when it has axis words;
    /// `nonmodal`, `path`: its group 0 and path-mode codes).
    pub(super) fn check_spline_thread_words(
        &self,
        b: &Block,
        explicit: Option<i32>,
        motion_to_be: Option<i32>,
        nonmodal: Option<i32>,
        path: Option<i32>,
        axis_given: bool,
    ) -> LR<()> {
        let m = motion_to_be;
        if let Some(g) = explicit
            && matches!(g, 50 | 51 | 330 | 760)
            && !axis_given
        {
            return Err(self.err_g(b, g, "All axes missing with motion code"));
        }
        if nonmodal == Some(53) && explicit.is_some_and(|g| g != 52) {
            return Err(self.err_g(
                b,
                53,
                "Between G5.2 and G5.3 codes, only additional G5.2 codes are allowed.",
            ));
        }
        let Some(m) = m.filter(|m| matches!(m, 50 | 51 | 52 | 330 | 331 | 760)) else {
            return Ok(());
        };
        let ms = |set: &[i32]| b.ms().iter().any(|(c, _)| set.contains(c));
        // words read as integers
        for (c, name) in [(b'l', 'l'), (b'h', 'h')] {
            if let Some(v) = b.word(c) {
                let floor = v.floor();
                if v - floor > INTEGER_TOL && v - floor <= 1.0 - INTEGER_TOL {
                    return Err(self.err_word(b, c, "Non integer value for integer"));
                }
                let lowest = if c == b'l' { 0.0 } else { -1.0 };
                if v.round() < lowest {
                    return Err(self.err_word(b, c, format!("Negative {name} word used")));
                }
            }
        }
        if b.word(b'i').is_some() && matches!(m, 52 | 330) && nonmodal != Some(100) {
            return Err(self.err_word(
                b,
                b'i',
                "I word with no G2, G3, G5, G5.1, G10, G33.1, G76, or G87 to use it",
            ));
        }
        if b.word(b'j').is_some() && matches!(m, 52 | 330 | 331) && nonmodal != Some(100) {
            return Err(self.err_word(
                b,
                b'j',
                "J word with no G2, G3, G5, G5.1, G10, G76 or G87 to use it",
            ));
        }
        if b.word(b'l').is_some()
            && matches!(m, 50 | 51 | 330 | 331)
            && nonmodal != Some(100)
            && !ms(&[66, 98])
        {
            return Err(self.err_word(
                b,
                b'l',
                "L word with no G10, cutter compensation, canned cycle, digital/analog input, M98 or NURBS code",
            ));
        }
        if b.word(b'p').is_some()
            && matches!(m, 51 | 330 | 331)
            && !matches!(nonmodal, Some(40 | 100))
            && path != Some(640)
            && !ms(&[50, 51, 52, 53, 62, 63, 64, 65, 66, 98])
        {
            return Err(self.err_word(
                b,
                b'p',
                "P word with no G2 G3 G4 G10 G64 G5 G5.2 G76 G82 G86 G88 G89 or M50 M51 M52 M53 M62 M63 M64 M65 M66 M98 or user M code to use it",
            ));
        }
        if b.word(b'q').is_some()
            && matches!(m, 51 | 52 | 330 | 331)
            && nonmodal != Some(100)
            && path != Some(640)
            && !ms(&[19, 66, 67, 68])
        {
            return Err(self.err_word(
                b,
                b'q',
                "Q word with no G5, G10, G64, G73, G76, G83, M19, M66, M67, M68 or user M code that uses it",
            ));
        }
        if b.word(b'h').is_some() && m != 760 {
            return Err(self.err_word(b, b'h', "H word with no G43 or G76 to use it"));
        }
        if matches!(m, 330 | 331) {
            if b.word(b'k').is_none() {
                return Err(self.err_g(b, m, "K word missing with g33/g33.1"));
            }
            if b.word(b'f').is_some() {
                return Err(self.err_word(b, b'f', "F word used with a g33/g33.1"));
            }
        }
        if m == 760 {
            if b.word(b'p').is_none() {
                return Err(self.err_g(b, 760, "P word missing with G76"));
            }
            if b.word(b'i').is_none() || b.word(b'j').is_none() || b.word(b'k').is_none() {
                return Err(self.err_g(b, 760, "I J or K words missing with G76"));
            }
        }
        Ok(())
    }

    /// The error of a G33/G76 block under cutter compensation with a radius: LinuxCNC's
    /// compensated straight move refuses every code but G0 and G1, after its own checks.
    fn comp_refuses(&self, b: &Block, code: i32) -> Option<LR<()>> {
        let c = self.comp.as_ref()?;
        if c.radius() <= 0.0 {
            return None;
        }
        let end = match self.target(b) {
            Ok(e) => e,
            Err(e) => return Some(Err(e)),
        };
        let (end2, along) = self.comp_plane.split([end[0], end[1], end[2]]);
        let mut probe = c.clone();
        let mv = PlaneMove {
            kind: PlaneMoveKind::Straight { rapid: false },
            end: end2,
            along,
            payload: self.payload(None, &end),
        };
        Some(match probe.push_move(mv) {
            Err(e) => Err(self.err_g(b, code, e.to_string())),
            Ok(()) => Err(self.err_g(b, code, "Bug code not g0 or g1")),
        })
    }

    fn spindle_turning(&self) -> bool {
        self.spindle_cw.is_some()
    }

    /// A synchronised feed move to machine position `end` at `pitch_mm` per revolution.
    fn synced_feed(&mut self, end: [Real; 6], pitch_mm: Real) {
        let m = Motion {
            kind: MotionKind::Linear,
            start: AxisValues::from_array(self.mpos),
            end: AxisValues::from_array(end),
            feed: Some(pitch_mm),
            feed_per_rev: true,
            arc: None,
        };
        self.motion(m);
        self.mpos = end;
    }

    fn start_sync(&mut self, pitch: Real) {
        self.event(
            "START_SPEED_FEED_SYNC",
            vec![EventArg::Num(pitch), EventArg::Num(0.0)],
        );
    }

    /// G33: a straight feed synchronised with the spindle at K per revolution.
    pub(super) fn g33(&mut self, b: &Block) -> LR<()> {
        if let Some(e) = self.comp_refuses(b, 330) {
            return e;
        }
        if !self.spindle_turning() {
            return Err(self.err_g(b, 330, "Spindle not turning in G33"));
        }
        let Some(k) = b.word(b'k') else {
            return Err(self.err_g(b, 330, "K word missing with g33/g33.1"));
        };
        let end = self.target(b)?;
        let end_m = self.to_machine(&end);
        // with compensation at a zero radius, what it has released goes out first
        self.flush_comp();
        let held = self.comp.take();
        self.start_sync(k);
        self.synced_feed(end_m, k * self.u);
        self.event("STOP_SPEED_FEED_SYNCH", Vec::new());
        if let Some(mut c) = held {
            // LinuxCNC moves its current point only, not the programmed one
            let (tool, along) = self.comp_plane.split([end[0], end[1], end[2]]);
            c.set_tool_point(tool, along);
            self.comp = Some(c);
        }
        Ok(())
    }

    /// G76: the threading cycle.
    pub(super) fn g76(&mut self, b: &Block) -> LR<()> {
        if let Some(e) = self.comp_refuses(b, 760) {
            return e;
        }
        if !self.spindle_turning() {
            return Err(self.err_g(b, 760, "Chosen spindle (0) not turning in G76"));
        }
        let cur = self.prog();
        let end = self.target(b)?;
        if (3..6).any(|i| end[i] != cur[i]) {
            return Err(self.err_g(b, 760, "Cannot move rotary axes with G76"));
        }
        if self.comp_on {
            return Err(self.err_g(
                b,
                760,
                "Cannot use G76 threading cycle with cutter radius compensation on",
            ));
        }
        let w = |c: u8| b.word(c);
        let t = Threading {
            pitch: w(b'p').unwrap_or(0.0),
            i: w(b'i').unwrap_or(0.0),
            j: w(b'j').unwrap_or(0.0),
            k: w(b'k').unwrap_or(0.0),
            q: w(b'q').unwrap_or(-1.0),
            spring: w(b'h').map_or(0, |h| h.round() as i64),
            degression: w(b'r'),
            taper: w(b'e'),
            flags: w(b'l').map_or(-1, |l| l.round() as i64),
        };
        if t.i == 0.0 {
            return Err(self.err_g(b, 760, "In G76, I must not be 0"));
        }
        if t.j <= 0.0 {
            return Err(self.err_g(b, 760, "In G76, J must be greater than 0"));
        }
        if t.k <= t.j {
            return Err(self.err_g(b, 760, "In G76, K must be greater than J"));
        }
        let u = self.u;
        let start = [cur[0] / u, cur[1] / u, cur[2] / u];
        let moves = threading_moves(&t, start, end[2] / u)
            .ok_or_else(|| self.err_g(b, 760, "G76 needs more passes than twinmill runs"))?;
        if moves.iter().any(|m| !m.to.iter().all(|v| v.is_finite())) {
            return Err(self.err_g(b, 760, "G76 threading cycle has a point that is not finite"));
        }
        let abc = [cur[3], cur[4], cur[5]];
        for mv in moves {
            let p = [
                mv.to[0] * u,
                mv.to[1] * u,
                mv.to[2] * u,
                abc[0],
                abc[1],
                abc[2],
            ];
            let m = self.to_machine(&p);
            match mv.kind {
                G76Kind::Rapid => self.emit_line(MotionKind::Rapid, m, None),
                G76Kind::Sync(pitch) => self.synced_feed(m, pitch * u),
                G76Kind::StartSync(pitch) => self.start_sync(pitch),
                G76Kind::StopSync => self.event("STOP_SPEED_FEED_SYNCH", Vec::new()),
            }
        }
        let end_m = self.to_machine(&end);
        self.emit_line(MotionKind::Rapid, end_m, None);
        Ok(())
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum G76Kind {
    Rapid,
    /// A synchronised feed at the pitch in effect (program units per revolution).
    Sync(Real),
    StartSync(Real),
    StopSync,
}

/// One step of a G76 cycle; `to` in program units (X, Y, Z).
#[derive(Clone, Copy, Debug)]
struct G76Move {
    kind: G76Kind,
    to: [Real; 3],
}

/// The passes of a G76 cycle from `start` (program units) with the thread ending at
/// `end_z`, as LinuxCNC's `convert_threading_cycle` issues them (without the final traverse
/// to the block's end point); `None` past [`MAX_G76_PASSES`].
fn threading_moves(t: &Threading, start: [Real; 3], end_z: Real) -> Option<Vec<G76Move>> {
    let [safe_x, start_y, start_z] = start;
    let boring = t.i > 0.0;
    let full_dia_depth = t.i.abs();
    let start_depth = t.i.abs() + t.j.abs();
    let cut_increment = t.j.abs();
    let full_threadheight = t.k.abs();
    let end_depth = t.k.abs() + t.i.abs();
    let pitch = t.pitch;
    let mut compound = if t.q == -1.0 { 0.0 } else { t.q };
    compound *= std::f64::consts::PI / 180.0;
    if end_z > start_z {
        compound = -compound;
    }
    let degression = match t.degression {
        Some(r) if r >= 1.0 => r,
        _ => 1.0,
    };
    let mut taper_dist = t.taper.unwrap_or(0.0);
    if taper_dist < 0.0 {
        taper_dist = 0.0;
    }
    let taper_pitch = if taper_dist > 0.0 {
        pitch * taper_dist.hypot(full_threadheight) / taper_dist
    } else {
        pitch
    };
    if end_z > start_z {
        taper_dist = -taper_dist;
    }
    let flags = t.flags.max(0);
    let entry_taper = flags & 1 != 0;
    let exit_taper = flags & 2 != 0;
    let target_z = end_z + t.k.abs() * compound.tan();

    let mut out = Vec::new();
    let mut sync = pitch;
    let mut pass = |depth: Real, zoff: Real, out: &mut Vec<G76Move>| {
        let x_at = |d: Real| if boring { safe_x + d } else { safe_x - d };
        let back_x = x_at(depth - end_depth);
        let cut_x = x_at(depth);
        let full_x = x_at(depth - full_threadheight);
        let mv = |kind, x: Real, z: Real| G76Move {
            kind,
            to: [x, start_y, z],
        };
        let marker = |kind| G76Move { kind, to: [0.0; 3] };
        out.push(mv(G76Kind::Rapid, back_x, start_z - zoff));
        if taper_dist != 0.0 && entry_taper {
            out.push(marker(G76Kind::StartSync(taper_pitch)));
            sync = taper_pitch;
            out.push(mv(G76Kind::Sync(sync), full_x, start_z - zoff));
            out.push(mv(G76Kind::Sync(sync), cut_x, start_z - zoff - taper_dist));
            out.push(marker(G76Kind::StartSync(pitch)));
            sync = pitch;
        } else {
            out.push(mv(G76Kind::Rapid, cut_x, start_z - zoff));
            out.push(marker(G76Kind::StartSync(pitch)));
            sync = pitch;
        }
        if taper_dist != 0.0 && exit_taper {
            out.push(mv(G76Kind::Sync(sync), cut_x, target_z - zoff + taper_dist));
            out.push(marker(G76Kind::StartSync(taper_pitch)));
            sync = taper_pitch;
            out.push(mv(G76Kind::Sync(sync), full_x, target_z - zoff));
        } else {
            out.push(mv(G76Kind::Sync(sync), cut_x, target_z - zoff));
        }
        out.push(marker(G76Kind::StopSync));
        out.push(mv(G76Kind::Rapid, back_x, target_z - zoff));
    };
    let tan = compound.tan();
    let mut depth = start_depth;
    let mut zoff = (depth - full_dia_depth) * tan;
    let mut n: i32 = 1;
    let mut passes = 0;
    while depth < end_depth {
        passes += 1;
        if passes > MAX_G76_PASSES {
            return None;
        }
        pass(depth, zoff, &mut out);
        n += 1;
        depth = full_dia_depth + cut_increment * Real::from(n).powf(1.0 / degression);
        zoff = (depth - full_dia_depth) * tan;
    }
    depth = end_depth;
    zoff = (depth - full_dia_depth) * tan;
    let spring = t.spring.max(-1);
    for _ in 0..spring + 1 {
        passes += 1;
        if passes > MAX_G76_PASSES {
            return None;
        }
        pass(depth, zoff, &mut out);
    }
    Some(out)
}
