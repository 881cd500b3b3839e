//! Correction of a hexapod's program: every commanded pose `q` rewritten to `q'` with
//! `FK_actual(IK_controller(q')) = q` in all six degrees of freedom, moves split where the
//! controller's interpolation between corrected poses would leave the nominal path.
//!
//! # The pose problem
//!
//! The controller turns a command `p` into readings on its parameters, the machine as
//! built goes where those readings put it ([`twin_pose`]): `G(p) = FK_actual(IK_controller(p))`.
//! The nominal pose of a command is the command itself (the design's `FK(IK(q)) = q`), so
//! correction solves `G(q') = q`. Six struts give six degrees of freedom: the solution is
//! exact (no least squares, nothing uncorrectable) wherever `q'` lies in the controller's
//! workspace. Newton's step follows from the struts: the drives read
//! `L_c(p) − l0_c`, the actual struts are `l0_a + L_c(p) − l0_c` long, so
//! `J_a·dG = J_c·dp` with `J_c`, `J_a` the strut Jacobians of the controller at `p` and of
//! the actual machine at `G(p)` ([`Hexapod::strut_jacobian`]), and
//! `dp = J_c⁻¹·J_a·(G(p) − q)`. The pose difference is taken in `(x, y, z, a, b, c)`, which
//! near a pose is a chart of the poses: its zero is the pose itself.
//!
//! # Between corrected poses
//!
//! The controller interpolates the command linearly between block ends; the machine then
//! follows `G` of that line, which is not the nominal line even when both ends are exact
//! (the strut lengths are not linear in the pose). Every move is therefore checked like
//! the serial machine's rotary moves: split into `n` equal parts of its parameter, every
//! sub-point corrected, and the tool axis (tip and flute end) of `G(chord)` compared with
//! the nominal pose at ¼, ½ and ¾ of every part; `n` grows until within the path
//! tolerance. The error of a chord falls as `1/n²`.
//!
//! **Invariant:** reads moves and the twin, writes nothing; a corrected pose outside the
//! controller's workspace (stroke, joint limits, singularity) or a Newton solve that does
//! not settle is an error naming the source line.

use super::*;
use crate::cutting::tool::Tool;
use crate::machine::hexapod::{Hexapod, HexapodTwin, Pose, pose_isometry, twin_pose};
use crate::math::{Isometry3, Real};
use crate::nc::{AxisLetter, AxisValues, MoveKind, Program};

/// The pose of axis values (no table axes: X Y Z A B C are the platform's pose).
fn pose_of(q: &AxisValues) -> Pose {
    Pose::from_mm_deg(q.to_array())
}

fn values_of(p: &Pose) -> AxisValues {
    AxisValues::from_array(p.to_mm_deg())
}

/// The six axes a hexapod's program drives.
const HEXAPOD_AXES: [AxisLetter; 6] = AxisLetter::ALL;

/// Distances of the tool's tip and flute end between two tool frames (mm).
fn axis_distances(a: &Isometry3, b: &Isometry3, flute: &FlutePoints) -> [Real; 2] {
    flute
        .ends
        .map(|h| (a * axis_point(h) - b * axis_point(h)).norm())
}

/// Angle between the tool axes (+z) of two tool frames (rad).
fn axis_angle(a: &Isometry3, b: &Isometry3) -> Real {
    let (u, v) = (
        a.rotation * crate::math::Vector3::z(),
        b.rotation * crate::math::Vector3::z(),
    );
    u.cross(&v).norm().atan2(u.dot(&v))
}

/// Solves the corrected commands of a hexapod twin.
pub struct HexapodSolver<'a> {
    twin: &'a HexapodTwin,
    flute: FlutePoints,
    /// mm of tool motion per radian of orientation step (the flute's length, at least 1).
    lever_mm: Real,
    max_correction: Real,
}

/// One corrected command.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HexapodFit {
    /// The corrected command.
    pub q: AxisValues,
    /// Newton iterations.
    pub iterations: usize,
    /// Distances of the reached tool tip and flute end from the nominal ones (mm).
    pub residual_mm: [Real; 2],
    /// Angle between the reached and the nominal tool axes (rad).
    pub axis_angle_rad: Real,
}

impl<'a> HexapodSolver<'a> {
    /// A solver for `twin` (no table axes) and `tool`.
    pub fn new(twin: &'a HexapodTwin, tool: &Tool, max_correction: Real) -> Self {
        Self {
            twin,
            flute: FlutePoints::of(tool),
            lever_mm: tool.length().max(1.0),
            max_correction,
        }
    }

    fn workspace_error(line: usize, q: &AxisValues, e: impl std::fmt::Display) -> CorrectError {
        CorrectError::Workspace {
            line,
            pose: format!("{}", pose_of(q)),
            message: e.to_string(),
        }
    }

    /// Where the machine goes for the command `q` (base frame).
    pub fn reached(&self, q: &AxisValues, line: usize) -> Result<Pose, CorrectError> {
        twin_pose(&self.twin.controller, &self.twin.actual, &pose_of(q))
            .map_err(|e| Self::workspace_error(line, q, e))
    }

    /// The command whose reached pose is the nominal pose of `q`, by Newton from `guess`.
    pub fn solve(
        &self,
        q: &AxisValues,
        guess: &AxisValues,
        line: usize,
    ) -> Result<HexapodFit, CorrectError> {
        let (controller, actual): (&Hexapod, &Hexapod) = (&self.twin.controller, &self.twin.actual);
        let target = pose_of(q);
        let mut p = pose_of(guess);
        let mut step = Real::INFINITY;
        for it in 0..MAX_NEWTON {
            let cmd = values_of(&p);
            // Unchecked on the way: only the solution is held to the workspace.
            let readings = controller.readings(&p);
            let reached = actual
                .forward_unchecked(&actual.lengths_of_readings(&readings), &p)
                .map_err(|e| Self::workspace_error(line, &cmd, e))?
                .pose;
            let e = reached.to_vector() - target.to_vector();
            let (jc, ja) = (
                controller.strut_jacobian(&p),
                actual.strut_jacobian(&reached),
            );
            let dp = jc
                .lu()
                .solve(&(ja * e))
                .filter(|d| d.iter().all(|c| c.is_finite()))
                .ok_or_else(|| {
                    Self::workspace_error(line, &cmd, "the strut Jacobian has no inverse there")
                })?;
            p = Pose::from_vector(&(p.to_vector() - dp));
            step = dp.fixed_rows::<3>(0).norm() + dp.fixed_rows::<3>(3).norm() * self.lever_mm;
            if step <= NEWTON_STEP_MM {
                return self.fit(q, &values_of(&p), it + 1, line);
            }
        }
        Err(CorrectError::NotConverged {
            line,
            iterations: MAX_NEWTON,
            step_mm: step,
        })
    }

    /// The figures of the command `c` for the nominal pose of `q`, with the workspace and
    /// correction-size checks.
    fn fit(
        &self,
        q: &AxisValues,
        c: &AxisValues,
        iterations: usize,
        line: usize,
    ) -> Result<HexapodFit, CorrectError> {
        self.twin
            .controller
            .check_pose(&pose_of(c))
            .map_err(|e| Self::workspace_error(line, c, e))?;
        for l in HEXAPOD_AXES {
            let d = (c.get(l) - q.get(l)).abs();
            if d > self.max_correction {
                return Err(CorrectError::Unreachable {
                    line,
                    axis: l.as_char(),
                    correction: d,
                    limit: self.max_correction,
                });
            }
        }
        let (reached, nominal) = (
            pose_isometry(&self.reached(c, line)?),
            pose_isometry(&pose_of(q)),
        );
        Ok(HexapodFit {
            q: *c,
            iterations,
            residual_mm: axis_distances(&reached, &nominal, &self.flute),
            axis_angle_rad: axis_angle(&reached, &nominal),
        })
    }
}

/// Corrects a hexapod's `program` (see the module docs): `start` is the command before the
/// first move; the output starts with a rapid to the corrected start when it differs.
/// A twin with table axes is refused by the caller (the platform then holds the table's
/// angle at home: five commanded degrees of freedom for a six-degree correction).
pub fn correct_hexapod_program(
    twin: &HexapodTwin,
    tool: &Tool,
    program: &Program,
    start: &AxisValues,
    opts: &CorrectOptions,
) -> Result<CorrectedProgram, CorrectError> {
    opts.validate()?;
    let solver = HexapodSolver::new(twin, tool, opts.max_correction);
    let axes: Vec<AxisLetter> = HEXAPOD_AXES.to_vec();
    for mv in &program.moves {
        check_finite(mv)?;
    }
    let first_line = program.moves.first().map_or(1, |m| m.line);
    if let Some(l) = AxisLetter::ALL
        .into_iter()
        .find(|l| !start.get(*l).is_finite())
    {
        return Err(CorrectError::NonFinite {
            line: first_line,
            axis: l.as_char(),
        });
    }
    let mut summary = CorrectionSummary {
        moves: program.moves.len(),
        ..CorrectionSummary::default()
    };
    let note = |fit: &HexapodFit, q: &AxisValues, line: usize, s: &mut CorrectionSummary| {
        s.poses_solved += 1;
        s.max_iterations = s.max_iterations.max(fit.iterations);
        let [r0, r1] = fit.residual_mm;
        let rms = ((r0 * r0 + r1 * r1) / 2.0).sqrt();
        if rms > s.residual_rms_mm {
            s.residual_rms_mm = rms;
            s.residual_line = line;
        }
        s.residual_max_mm = s.residual_max_mm.max(r0.max(r1));
        s.axis_angle_rad = s.axis_angle_rad.max(fit.axis_angle_rad);
        for l in HEXAPOD_AXES {
            let c = (fit.q.get(l) - q.get(l)).abs();
            if l.is_rotary() {
                s.max_rotary_correction_deg = s.max_rotary_correction_deg.max(c);
            } else {
                s.max_linear_correction_mm = s.max_linear_correction_mm.max(c);
            }
        }
    };
    let mut blocks = Vec::new();
    let mut per_move = Vec::with_capacity(program.moves.len());
    let c0 = solver.solve(start, start, first_line)?;
    note(&c0, start, first_line, &mut summary);
    let mut prev = printed(&axes, &c0.q);
    if prev != printed(&axes, start) && !program.moves.is_empty() {
        blocks.push(Block {
            kind: MoveKind::Rapid,
            end: prev,
            feed_mm_per_min: None,
            source: None,
            line: first_line,
            part: (1, 1),
            s: (0.0, 0.0),
            inverse_time_per_min: None,
        });
    }
    for (index, mv) in program.moves.iter().enumerate() {
        let kind = emitted_kind(mv.kind);
        let mut n = 1usize;
        let (points, worst, fits) = loop {
            let mut pts = vec![prev];
            let mut fits = Vec::with_capacity(n);
            for j in 1..=n {
                let q = path_point(mv, j as Real / n as Real);
                let last = pts[j - 1];
                let before = path_point(mv, (j - 1) as Real / n as Real);
                // Warm start: the correction varies slowly along a move.
                let guess = {
                    let (l, b, qa) = (last.to_array(), before.to_array(), q.to_array());
                    AxisValues::from_array(std::array::from_fn(|k| qa[k] + (l[k] - b[k])))
                };
                let fit = solver.solve(&q, &guess, mv.line)?;
                note(&fit, &q, mv.line, &mut summary);
                // The ends as printed: what the controller will interpolate between.
                pts.push(printed(&axes, &fit.q));
                fits.push(fit);
            }
            let mut worst: Real = 0.0;
            for j in 0..n {
                for t in CHECK_AT {
                    let s = (j as Real + t) / n as Real;
                    let chord = lerp(&pts[j], &pts[j + 1], t);
                    summary.poses_solved += 1;
                    let reached = pose_isometry(&solver.reached(&chord, mv.line)?);
                    let nominal = pose_isometry(&pose_of(&path_point(mv, s)));
                    let [d0, d1] = axis_distances(&reached, &nominal, &solver.flute);
                    worst = worst.max(d0).max(d1);
                }
            }
            if worst <= opts.path_tolerance_mm {
                break (pts, worst, fits);
            }
            n = next_split(n, worst, opts, mv.line)?;
        };
        for (j, p) in points.iter().enumerate().skip(1) {
            blocks.push(Block {
                kind,
                end: *p,
                feed_mm_per_min: mv.feed_mm_per_min,
                source: Some(index),
                line: mv.line,
                part: (j, n),
                s: ((j - 1) as Real / n as Real, j as Real / n as Real),
                inverse_time_per_min: None,
            });
        }
        if n > 1 {
            summary.subdivided_moves += 1;
        }
        summary.subdivision_error_mm = summary.subdivision_error_mm.max(worst);
        let max_of = |f: &dyn Fn(&HexapodFit) -> Real| fits.iter().map(f).fold(0.0, Real::max);
        per_move.push(MoveCorrection {
            line: mv.line,
            sub_moves: n,
            residual_rms_mm: max_of(&|f| {
                let [a, b] = f.residual_mm;
                ((a * a + b * b) / 2.0).sqrt()
            }),
            residual_max_mm: max_of(&|f| f.residual_mm[0].max(f.residual_mm[1])),
            axis_angle_rad: max_of(&|f| f.axis_angle_rad),
            subdivision_error_mm: worst,
        });
        prev = *points.last().unwrap_or(&prev);
    }
    summary.blocks = blocks.len();
    summary.inverse_time_blocks = inverse_time_feeds(&mut blocks, &program.moves, start);
    let moves = block_moves(&blocks, start);
    Ok(CorrectedProgram {
        start: *start,
        axes,
        blocks,
        moves,
        per_move,
        summary,
        ended: program.ended_by.is_some(),
    })
}

fn check_finite(mv: &crate::nc::Move) -> Result<(), CorrectError> {
    for l in AxisLetter::ALL {
        if !(mv.start.get(l).is_finite() && mv.end.get(l).is_finite()) {
            return Err(CorrectError::NonFinite {
                line: mv.line,
                axis: l.as_char(),
            });
        }
    }
    if let Some(f) = mv.feed_mm_per_min
        && !(f.is_finite() && f > 0.0)
    {
        return Err(CorrectError::NonFinite {
            line: mv.line,
            axis: 'F',
        });
    }
    Ok(())
}

/// The tool path of a corrected hexapod program on `twin` against the nominal path: every
/// block sampled at its ends and [`PATH_SAMPLES`] inner points, the reached tool axis (tip
/// and flute end) against the nominal pose at the same parameter of the source move. The
/// positioning block to the corrected start has no nominal path and is skipped. A sample
/// the machine cannot reach is an error.
pub fn hexapod_path_error(
    twin: &HexapodTwin,
    tool: &Tool,
    program: &Program,
    corrected: &CorrectedProgram,
) -> Result<PathError, CorrectError> {
    let solver = HexapodSolver::new(twin, tool, Real::INFINITY);
    let mut out = PathError::default();
    let mut sum = 0.0;
    let mut at = corrected.start;
    for b in &corrected.blocks {
        let from = at;
        at = b.end;
        let Some(src) = b.source.and_then(|i| program.moves.get(i)) else {
            continue;
        };
        for i in 0..=PATH_SAMPLES + 1 {
            let t = i as Real / (PATH_SAMPLES + 1) as Real;
            let s = b.s.0 + (b.s.1 - b.s.0) * t;
            let reached = pose_isometry(&solver.reached(&lerp(&from, &b.end, t), b.line)?);
            let nominal = pose_isometry(&pose_of(&path_point(src, s)));
            for d in axis_distances(&reached, &nominal, &solver.flute) {
                sum += d * d;
                if d > out.max_mm {
                    out.max_mm = d;
                    out.worst_line = b.line;
                }
            }
            out.samples += 1;
        }
    }
    out.rms_mm = if out.samples > 0 {
        (sum / (2 * out.samples) as Real).sqrt()
    } else {
        0.0
    };
    Ok(out)
}
