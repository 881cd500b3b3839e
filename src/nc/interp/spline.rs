//! Splines and NURBS as LinuxCNC 2.9 reads them (`interp_convert.cc`: `convert_spline`,
//! `convert_nurbs`): G5 (cubic, I J P Q), G5.1 (quadratic, I J) and G5.2 … G5.3 (control
//! points with weights P, order L) each become one canonical `NURBS_FEED` of control points
//! and an order, recorded as an event (`args`: number of control points, order; the
//! standalone `rs274` prints `NURBS_FEED(n, ...)`), followed by the moves LinuxCNC's task
//! makes of it ([`super::nurbs`]): arcs and straight feeds in the plane's first two axes,
//! the other axes staying where the machine is.
//!
//! LinuxCNC's rules, kept here: G5 and G5.1 are refused with cutter compensation, outside
//! G17, with Z, A, B or C words and with a zero feed (F word missing in G93); they leave
//! the motion mode as it was. G5 without I and J continues from the last G5's −P, −Q.
//! G5.2 is modal; its first block starts the list with the current point (weight P when
//! the block has no X and Y, else 1) and every block adds X, Y with weight P (LinuxCNC
//! takes −1 when the first block has X and Y but no P); L above 3 sets the order. G5.3
//! issues the curve. G5.2 works in any plane and under compensation: the curve is issued at
//! once, ahead of any move the compensation holds, from the tool's position, and outside
//! G17 LinuxCNC's task draws its arcs in the selected plane with the X and Y of the points
//! (both as LinuxCNC). The list is shared: G5/G5.1 between G5.2 and G5.3 issues all of it.
//!
//! Afterwards the interpreter's X and Y are those of the last control point. A piece to a
//! point that is not finite (a biarc between parallel tangents on a straight stretch,
//! which LinuxCNC's task sends on to motion as it is) is left out.

use crate::math::Real;
use crate::nc::AxisValues;
use crate::nc::lex::Block;
use crate::nc::output::{Event, EventArg, Motion, MotionKind, Plane, Record, RecordBody};

use super::errors::LR;
use super::nurbs::{ControlPoint, Nurbs, Piece};
use super::{FeedMode, Interpreter};

/// Highest NURBS order evaluated (LinuxCNC has no limit, but its recursive basis takes
/// time exponential in the order; twinmill's takes order² per point).
const MAX_ORDER: usize = 32;

impl Interpreter {
    /// The interpreter's current X, Y (mm, program coordinates): LinuxCNC's `current_x`,
    /// `current_y`, the tool's position when compensation is on.
    fn spline_current(&self) -> [Real; 2] {
        if let Some(c) = &self.comp {
            let xyz = self.comp_plane.join(c.tool_point(), c.along());
            [xyz[0], xyz[1]]
        } else {
            let p = self.prog();
            [p[0], p[1]]
        }
    }

    /// The end point's X, Y of the block's axis words (mm).
    fn spline_end(&self, b: &Block) -> LR<[Real; 2]> {
        let e = self.target(b)?;
        Ok([e[0], e[1]])
    }

    /// A control point in program units from mm.
    fn cp(&self, xy: [Real; 2], w: Real) -> ControlPoint {
        [xy[0] / self.u, xy[1] / self.u, w]
    }

    /// G5 (`m` = 50) and G5.1 (51).
    pub(super) fn spline(&mut self, m: i32, b: &Block) -> LR<()> {
        // G5 and G5.1 do not change the motion mode
        self.motion = self.motion_before;
        if self.comp_on {
            return Err(self.err_g(
                b,
                m,
                "Cannot convert spline with cutter radius compensation",
            ));
        }
        match self.feed_mode {
            FeedMode::PerMinute if self.feed == 0.0 => {
                return Err(self.err_g(b, m, "Cannot make arc with zero feed rate"));
            }
            FeedMode::InverseTime if b.word(b'f').is_none() => {
                return Err(self.err_g(b, m, "F word missing with inverse time arc move"));
            }
            _ => {}
        }
        if self.plane != Plane::Xy {
            return Err(self.err_g(b, m, "Splines must be in the XY plane"));
        }
        if [b'z', b'a', b'b', b'c']
            .iter()
            .any(|c| b.word(*c).is_some())
        {
            return Err(self.err_g(b, m, "Splines may not have motion in Z, A, B, or C"));
        }
        let cur = self.spline_current();
        let (i, j) = (b.word(b'i'), b.word(b'j'));
        let u = self.u;
        if m == 51 {
            let (Some(i), Some(j)) = (i, j) else {
                return Err(self.err_g(b, m, "Must specify both I and J with G5.1"));
            };
            let p1 = [cur[0] + i * u, cur[1] + j * u];
            let p2 = self.spline_end(b)?;
            let pts = [self.cp(cur, 1.0), self.cp(p1, 1.0), self.cp(p2, 1.0)];
            self.nurbs_points.extend_from_slice(&pts);
            self.issue_curve(3, b, m)
        } else {
            let p1 = match (i, j) {
                (Some(i), Some(j)) => [cur[0] + i * u, cur[1] + j * u],
                (None, None) => [
                    cur[0] + self.spline_ij[0] * u,
                    cur[1] + self.spline_ij[1] * u,
                ],
                _ => return Err(self.err_g(b, m, "Must specify both I and J, or neither")),
            };
            let p3 = self.spline_end(b)?;
            let (Some(p), Some(q)) = (b.word(b'p'), b.word(b'q')) else {
                return Err(self.err_g(b, m, "Must specify both P and Q with G5"));
            };
            let p2 = [p3[0] + p * u, p3[1] + q * u];
            let pts = [
                self.cp(cur, 1.0),
                self.cp(p1, 1.0),
                self.cp(p2, 1.0),
                self.cp(p3, 1.0),
            ];
            self.nurbs_points.extend_from_slice(&pts);
            self.issue_curve(4, b, m)?;
            self.spline_ij = [-p, -q];
            Ok(())
        }
    }

    /// G5.2: one control point (or the first, from the current point).
    pub(super) fn nurbs_block(&mut self, b: &Block) -> LR<()> {
        let (x, y) = (b.word(b'x'), b.word(b'y'));
        // LinuxCNC's p_number: −1 when there is no P word
        let p = b.word(b'p').unwrap_or(-1.0);
        if x.is_some() != y.is_some() {
            return Err(self.err_g(
                b,
                52,
                "You must specify both X and Y coordinates for Control Points",
            ));
        }
        let has_xy = x.is_some();
        if !has_xy && p > 0.0 && !self.nurbs_points.is_empty() {
            return Err(self.err_word(
                b,
                b'p',
                "Can specify P without X and Y only for the first control point",
            ));
        }
        if p <= 0.0 && !self.nurbs_points.is_empty() {
            return Err(self.err_g(
                b,
                52,
                "Must specify positive weight P for every Control Point",
            ));
        }
        if self.feed_mode == FeedMode::PerMinute && self.feed == 0.0 {
            return Err(self.err_g(b, 52, "Cannot make a NURBS with 0 feedrate"));
        }
        if self.motion_before != Some(52) {
            self.nurbs_points.clear();
        }
        if self.nurbs_points.is_empty() {
            let w = if !has_xy && p > 0.0 { p } else { 1.0 };
            let cp = self.cp(self.spline_current(), w);
            self.nurbs_points.push(cp);
            self.nurbs_order = 3;
        }
        if let Some(l) = b.word(b'l')
            && l > 3.0
        {
            self.nurbs_order = l.round().min(usize::MAX as Real) as usize;
        }
        if has_xy {
            let cp = self.cp(self.spline_end(b)?, p);
            self.nurbs_points.push(cp);
        }
        self.motion = Some(52);
        Ok(())
    }

    /// G5.3: issues the curve of the G5.2 blocks. `axis_given`: the block has axis words,
    /// which LinuxCNC then reads as a G5.2 block starting a new curve.
    pub(super) fn nurbs_end(&mut self, b: &Block, axis_given: bool) -> LR<()> {
        if self.motion != Some(52) {
            return Err(self.err_g(b, 53, "Cannot use G5.3 without G5.2 first"));
        }
        let order = self.nurbs_order;
        if self.nurbs_points.len() < order {
            return Err(self.err_g(
                b,
                53,
                format!(
                    "You must specify a number of control points at least equal to the order L = {order}"
                ),
            ));
        }
        if order > MAX_ORDER {
            return Err(self.err_g(
                b,
                53,
                format!("NURBS order L = {order} is above {MAX_ORDER}, the highest evaluated"),
            ));
        }
        self.issue_curve(order, b, 53)?;
        self.motion = if axis_given { Some(52) } else { None };
        Ok(())
    }

    /// Issues the curve of the gathered control points (and empties the list): the
    /// `NURBS_FEED` event, the moves of LinuxCNC's task, and the new current point.
    fn issue_curve(&mut self, order: usize, b: &Block, code: i32) -> LR<()> {
        let pts = std::mem::take(&mut self.nurbs_points);
        if pts.iter().any(|p| p.iter().any(|v| !v.is_finite())) {
            return Err(self.err_g(b, code, "NURBS control point is not finite"));
        }
        let Some(&last) = pts.last() else {
            return Ok(());
        };
        let Some(curve) = Nurbs::new(&pts, order) else {
            return Ok(());
        };
        // what the compensation has released goes out first; held moves stay behind
        self.flush_comp();
        let rec = Record {
            body: RecordBody::Event(Event {
                call: "NURBS_FEED",
                args: vec![
                    EventArg::Num(pts.len() as Real),
                    EventArg::Num(order as Real),
                ],
            }),
            file: self.cur,
            line: self.line_no,
            n: self.line_n,
        };
        self.out.push(rec);
        let (feed, per_rev) = match self.feed_mode {
            FeedMode::PerMinute => (Some(self.feed), false),
            FeedMode::PerRev => (Some(self.feed), true),
            FeedMode::InverseTime => (self.last_feed, false),
        };
        let feed = feed.filter(|f| f.is_finite() && *f > 0.0);
        let u = self.u;
        let (a1, a2, an) = self.plane.axes();
        let mut at = self.out_pos.take().unwrap_or(self.mpos);
        for piece in curve.pieces() {
            if !piece.is_finite() {
                continue;
            }
            // the task's canon position in program coordinates
            let p = self.to_program(&at);
            let e = piece.end();
            let (end_p, arc) = match piece {
                Piece::Line { .. } => ([e[0] * u, e[1] * u, p[2], p[3], p[4], p[5]], None),
                Piece::Arc {
                    center, rotation, ..
                } => {
                    let mut q = p;
                    q[a1] = e[0] * u;
                    q[a2] = e[1] * u;
                    q[an] = p[2];
                    (q, Some((center[0] * u, center[1] * u, rotation)))
                }
            };
            let (end_m, geom) = match arc {
                None => (self.to_machine(&end_p), None),
                Some((c1, c2, rot)) => {
                    let (end_m, geom, _) = self.arc_geometry_from(&at, &end_p, c1, c2, rot);
                    (end_m, Some(geom))
                }
            };
            if end_m.iter().any(|v| !v.is_finite()) {
                continue;
            }
            let kind = if geom.is_some() {
                MotionKind::Arc
            } else {
                MotionKind::Linear
            };
            self.motion(Motion {
                kind,
                start: AxisValues::from_array(at),
                end: AxisValues::from_array(end_m),
                feed,
                feed_per_rev: per_rev,
                arc: geom,
            });
            at = end_m;
        }
        // LinuxCNC's interpreter is now at the last control point's X and Y
        let (x, y) = (last[0] * u, last[1] * u);
        if let Some(c) = self.comp.as_mut() {
            let plane = self.comp_plane;
            let (tool, along) = plane.split([x, y, plane.join(c.tool_point(), c.along())[2]]);
            c.set_tool_point(tool, along);
            self.mpos = at;
        } else if let Some(po) = self.prog_override.as_mut() {
            po[0] = x;
            po[1] = y;
            self.mpos = at;
        } else {
            let mut prog = self.prog();
            prog[0] = x;
            prog[1] = y;
            self.mpos = self.to_machine(&prog);
            if self.mpos != at {
                self.out_pos = Some(at);
            }
        }
        Ok(())
    }
}
