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

impl Interpreter {
    /// End point (program coordinates, mm) of the axis words of `b`.
    pub(super) fn target(&self, b: &Block, _g53: bool) -> [Real; 6] {
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

    pub(super) fn emit_line(&mut self, kind: MotionKind, end: [Real; 6], feed: Option<Real>) {
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
}

fn dist(a: &[Real; 6], b: &[Real; 6]) -> Real {
    let l = ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
    if l > 0.0 {
        l
    } else {
        ((a[3] - b[3]).powi(2) + (a[4] - b[4]).powi(2) + (a[5] - b[5]).powi(2)).sqrt()
    }
}
