//! Motion: the end point of a block's axis words (Cartesian or `@`/`^` polar, absolute or
//! incremental), feed rates, and the straight moves (G0, G1, G53), rigid tapping (G33.1)
//! and probing (G38.2–G38.5, rs274's simulated probe); arcs and canned cycles are sent on.

use crate::math::Real;
use crate::nc::AxisValues;
use crate::nc::comp::{CompError, PlaneMove, PlaneMoveKind};
use crate::nc::lex::Block;
use crate::nc::output::{Motion, MotionKind};

use super::errors::LR;
use super::{FeedMode, Interpreter};

/// rs274's simulated probe backs off this far (mm) from the target after tripping.
const PROBE_BACKOFF_MM: Real = 0.254;
/// Two points closer than this on every axis (mm, degrees) are LinuxCNC's "same point"
/// (it compares exactly; this absorbs the round trip through machine coordinates).
const SAME_POINT_MM: Real = 1e-9;

impl Interpreter {
    /// End point (program coordinates, mm) of the axis words of `b`, as LinuxCNC's
    /// `find_ends`: X Y Z A B C absolute or incremental, or the polar words `@` (radius) and
    /// `^` (angle, degrees) about the program origin of the XY plane (`block` has refused
    /// X or Y beside them); absolute `@` alone keeps the angle, `^` alone the radius, and
    /// incremental ones add to them, which the origin leaves undefined.
    #[inline(always)]
    pub(super) fn target(&self, b: &Block) -> LR<[Real; 6]> {
        let p = self.prog();
        let mut end = p;
        for (i, c) in [b'x', b'y', b'z', b'a', b'b', b'c'].iter().enumerate() {
            if let Some(v) = b.word(*c) {
                let vm = if i < 3 { v * self.u } else { v };
                end[i] = if self.incremental { p[i] + vm } else { vm };
            }
        }
        let (pr, pa) = (b.word(b'@'), b.word(b'^'));
        if pr.is_none() && pa.is_none() {
            return Ok(end);
        }
        let (mut x, mut y) = (p[0], p[1]);
        let at_origin = |x: Real, y: Real| x == 0.0 && y == 0.0;
        if self.incremental {
            if let Some(r) = pr {
                if at_origin(x, y) {
                    return Err(self.err_word(
                        b,
                        b'@',
                        "Incremental motion with polar coordinates is indeterminate when at \
                         the origin",
                    ));
                }
                (x, y) = polar(x.hypot(y) + r * self.u, y.atan2(x));
            }
            if let Some(a) = pa {
                if at_origin(x, y) {
                    return Err(self.err_word(
                        b,
                        b'^',
                        "G91 motion with polar coordinates is indeterminate when at the origin",
                    ));
                }
                (x, y) = polar(x.hypot(y), y.atan2(x) + a.to_radians());
            }
        } else {
            (x, y) = match (pr, pa) {
                (Some(r), Some(a)) => polar(r * self.u, a.to_radians()),
                (Some(r), None) => {
                    if at_origin(x, y) {
                        return Err(self.err_word(
                            b,
                            b'@',
                            "Must specify angle in polar coordinate if at the origin",
                        ));
                    }
                    polar(r * self.u, y.atan2(x))
                }
                (None, Some(a)) => polar(x.hypot(y), a.to_radians()),
                (None, None) => (x, y),
            };
        }
        end[0] = x;
        end[1] = y;
        Ok(end)
    }

    #[inline(always)]
    pub(super) fn emit_line(&mut self, kind: MotionKind, end: [Real; 6], feed: Option<Real>) {
        self.motion(Motion {
            kind,
            start: AxisValues::from_array(self.mpos),
            end: AxisValues::from_array(end),
            feed,
            feed_per_rev: self.feed_mode == FeedMode::PerRev && feed.is_some(),
            arc: None,
        });
        self.mpos = end;
    }

    #[inline(always)]
    pub(super) fn feed_for(&self, b: &Block, code: i32, length_mm: Real) -> LR<Real> {
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

    pub(super) fn do_motion(&mut self, m: i32, b: &Block, g53: bool, explicit: bool) -> LR<()> {
        match m {
            0 | 10 if self.comp.is_some() => {
                if g53 {
                    return Err(self.err_g(b, 530, "Cannot use g53 with cutter radius comp"));
                }
                let end = self.target(b)?;
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
                    let end = self.target(b)?;
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
                let end = self.target(b)?;
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
                self.probe(m, b)?;
            }
            730 | 740 | 810..=890 => self.cycle(m, b, explicit)?,
            50 | 51 => self.spline(m, b)?,
            52 => self.nurbs_block(b)?,
            330 => self.g33(b)?,
            760 => self.g76(b)?,
            _ => {
                return Err(self.err_g(b, m, "Motion mode not supported"));
            }
        }
        Ok(())
    }

    /// G38.2–G38.5 as LinuxCNC's standalone interpreter runs them: its canon has no probe,
    /// so the probe "trips" at the programmed end point. The move goes there; the canon
    /// then backs off 0.254 mm (0.010 in) towards where it was, the interpreter reads that
    /// back as its current point, and the result parameters report the trip point in
    /// program coordinates and units (#5061–#5066; #5067–#5069, U V W, are 0) with #5070
    /// = 0, the stub's probe input. G38.2 and G38.4 (which stop with an error when the
    /// probe does not change state) refuse a move to the point they start from.
    fn probe(&mut self, m: i32, b: &Block) -> LR<()> {
        if self.comp_on {
            return Err(self.err_g(b, m, "Cannot probe with cutter radius comp on"));
        }
        // G93 clears the feed rate (F is per move there)
        if self.feed_mode == FeedMode::InverseTime || self.feed <= 0.0 {
            return Err(self.err_g(b, m, "Cannot probe with zero feed rate"));
        }
        if self.feed_mode == FeedMode::PerRev {
            return Err(self.err_g(b, m, "Cannot probe with feed per rev mode"));
        }
        let end = self.target(b)?;
        if matches!(m, 382 | 384) {
            let cur = self.prog();
            if cur
                .iter()
                .zip(&end)
                .all(|(c, e)| (c - e).abs() <= SAME_POINT_MM)
            {
                return Err(self.err_g(b, m, "Start point too close to probe point"));
            }
        }
        let end_m = self.to_machine(&end);
        let canon_start = self.canon_pos();
        let start = self.mpos;
        self.emit_line(MotionKind::Probe, end_m, Some(self.feed));
        // the next record starts where the machine backs off (as rs274_motion.py has it)
        let back = |from: &[Real; 6], to: &[Real; 6]| -> [Real; 6] {
            let d = [from[0] - to[0], from[1] - to[1], from[2] - to[2]];
            let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            let mut p = *to;
            if n > 0.0 {
                for (q, di) in p.iter_mut().zip(d) {
                    *q += PROBE_BACKOFF_MM * di / n;
                }
            }
            p
        };
        self.mpos = back(&start, &end_m);
        // the current point is where the canon backed off, towards its own position (it
        // differs from the machine's after a tool length change without a move)
        let canon_end = back(&canon_start, &end);
        let base = self.to_program(&self.mpos);
        let off: [Real; 6] = std::array::from_fn(|i| canon_end[i] - base[i]);
        self.set_canon_offsets(off, off);
        let u = self.u;
        let n = &mut self.params.numbered;
        for (i, e) in end.iter().enumerate() {
            n[5061 + i] = if i < 3 { e / u } else { *e };
        }
        n[5067..=5070].fill(0.0);
        Ok(())
    }
}

fn dist(a: &[Real; 6], b: &[Real; 6]) -> Real {
    let l = ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
    if l > 0.0 {
        l
    } else {
        ((a[3] - b[3]).powi(2) + (a[4] - b[4]).powi(2) + (a[5] - b[5]).powi(2)).sqrt()
    }
}

/// The point at `radius` and `theta` (radians) about the origin.
pub(super) fn polar(radius: Real, theta: Real) -> (Real, Real) {
    let (s, c) = theta.sin_cos();
    (radius * c, radius * s)
}
