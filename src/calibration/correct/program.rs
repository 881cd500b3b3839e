//! The corrected program: every move corrected, rotary moves subdivided until their path
//! is within tolerance.

use super::*;
use crate::cutting::tool::Tool;
use crate::machine::chain::{AxisKind, Chain};
use crate::machine::error_motion::Directions;
use crate::math::{Real, Vector3};
use crate::nc::{AxisLetter, AxisValues, Move, MoveKind, Program};

/// One block of the corrected program: a straight move to `end`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Block {
    /// Rapid or linear.
    pub kind: MoveKind,
    /// Axis values at the block's end, as printed.
    pub end: AxisValues,
    /// Feed (mm/min) of linear blocks, as in the source.
    pub feed_mm_per_min: Option<Real>,
    /// Index of the source move in the program; `None` for the positioning block to the
    /// corrected start.
    pub source: Option<usize>,
    /// 1-based source line.
    pub line: usize,
    /// This block's part (1-based) and the number of parts of its source move.
    pub part: (usize, usize),
    /// The source move's parameter interval this block covers.
    pub s: (Real, Real),
    /// Inverse-time feed `F` (1/min) when the block is written in `G93`: a corrected move
    /// that turns a rotary axis and would take another time than its part of the source
    /// move at the programmed feed (see `inverse_time_feeds`); `None`: `G94`.
    pub inverse_time_per_min: Option<Real>,
}

/// The correction of one source move.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct MoveCorrection {
    /// Source line.
    pub line: usize,
    /// Sub-moves it became (1 if not subdivided).
    pub sub_moves: usize,
    /// Largest RMS residual over the flute at its corrected points (mm): uncorrectable.
    pub residual_rms_mm: Real,
    /// Largest residual at the flute's tip or end at its corrected points (mm).
    pub residual_max_mm: Real,
    /// Largest angle between the deviated and the nominal tool axes at its corrected
    /// points (rad): the orientation error left.
    pub axis_angle_rad: Real,
    /// Largest checked distance between the chord and the best achievable path (mm); 0 for
    /// straight moves at fixed rotary values (exact, see the module docs).
    pub subdivision_error_mm: Real,
}

/// Figures of a whole correction.
#[derive(Clone, Copy, Debug, PartialEq, Default, serde::Serialize)]
pub struct CorrectionSummary {
    /// Source moves.
    pub moves: usize,
    /// Blocks emitted (including a positioning block to the corrected start).
    pub blocks: usize,
    /// Source moves that were subdivided.
    pub subdivided_moves: usize,
    /// Poses solved (end points, sub-points and check points).
    pub poses_solved: usize,
    /// Largest Gauss–Newton iteration count of a pose.
    pub max_iterations: usize,
    /// Largest RMS residual over the flute (mm): the uncorrectable part.
    pub residual_rms_mm: Real,
    /// Largest residual at a flute end (mm).
    pub residual_max_mm: Real,
    /// Largest angle between the deviated and the nominal tool axes (rad).
    pub axis_angle_rad: Real,
    /// Source line of the largest residual (0 if none).
    pub residual_line: usize,
    /// Largest checked subdivision error (mm).
    pub subdivision_error_mm: Real,
    /// Largest correction of a linear axis (mm).
    pub max_linear_correction_mm: Real,
    /// Largest correction of a rotary axis (degrees).
    pub max_rotary_correction_deg: Real,
    /// Blocks written with inverse-time feed (`G93`) to keep their source move's duration.
    pub inverse_time_blocks: usize,
}

/// A corrected program: blocks to emit and the same as moves to simulate.
#[derive(Clone, Debug, PartialEq)]
pub struct CorrectedProgram {
    /// Axis values before the first block (the machine's start position, uncorrected).
    pub start: AxisValues,
    /// The axes printed in every block (the chain's, in X Y Z A B C order).
    pub axes: Vec<AxisLetter>,
    /// The blocks, in order.
    pub blocks: Vec<Block>,
    /// The blocks as moves from `start` (values exactly as printed; lines are source lines).
    pub moves: Vec<Move>,
    /// Per source move.
    pub per_move: Vec<MoveCorrection>,
    /// Totals.
    pub summary: CorrectionSummary,
    /// Whether the source ended with M2/M30 (the output then ends with M30).
    pub ended: bool,
}

/// The value as printed in the output (then read back): what the machine will get.
pub fn as_printed(letter: AxisLetter, v: Real) -> Real {
    let s = format_axis(letter, v);
    // The text is a plain decimal that f64 parsing reads exactly as printed.
    s.parse::<Real>().unwrap_or(v)
}

pub(super) fn format_axis(letter: AxisLetter, v: Real) -> String {
    let d = if letter.is_rotary() {
        ROTARY_DECIMALS
    } else {
        LINEAR_DECIMALS
    };
    let s = format!("{v:.d$}");
    // No "-0.000000".
    if s.trim_start_matches('-')
        .chars()
        .all(|c| c == '0' || c == '.')
    {
        format!("{:.d$}", 0.0)
    } else {
        s
    }
}

pub(super) fn printed(axes: &[AxisLetter], q: &AxisValues) -> AxisValues {
    let mut out = *q;
    for &l in axes {
        out.set(l, as_printed(l, q.get(l)));
    }
    out
}

/// Corrects `program` for the deviated chain `machine` (see the module docs).
///
/// `start` is the machine's position before the first move (the scene's home). The
/// output starts with a rapid to the corrected start position when it differs.
pub fn correct_program(
    machine: &Chain,
    tool: &Tool,
    program: &Program,
    start: &AxisValues,
    opts: &CorrectOptions,
) -> Result<CorrectedProgram, CorrectError> {
    opts.validate()?;
    let mut solver = PoseSolver::new(machine, tool, opts.max_correction);
    // Each axis's lost motion as the commanded program leaves it (all `+` at the start).
    let mut dirs = Directions::default();
    let axes: Vec<AxisLetter> = AxisLetter::ALL
        .into_iter()
        .filter(|l| machine.has_axis(*l))
        .collect();
    let n_axes = machine.axes().len();
    let all_free: [bool; 6] = std::array::from_fn(|i| i < n_axes);
    let linear_free: [bool; 6] =
        std::array::from_fn(|i| i < n_axes && machine.axes()[i].kind == AxisKind::Linear);
    for mv in &program.moves {
        check_move(machine, mv)?;
    }
    for l in AxisLetter::ALL {
        if !start.get(l).is_finite() {
            return Err(CorrectError::NonFinite {
                line: program.moves.first().map_or(1, |m| m.line),
                axis: l.as_char(),
            });
        }
    }
    let mut summary = CorrectionSummary {
        moves: program.moves.len(),
        ..CorrectionSummary::default()
    };
    let note = |fit: &PoseFit, q: &AxisValues, line: usize, s: &mut CorrectionSummary| {
        s.poses_solved += 1;
        s.max_iterations = s.max_iterations.max(fit.iterations);
        if fit.residual_rms_mm > s.residual_rms_mm {
            s.residual_rms_mm = fit.residual_rms_mm;
            s.residual_line = line;
        }
        s.residual_max_mm = s.residual_max_mm.max(fit.residual_max_mm);
        s.axis_angle_rad = s.axis_angle_rad.max(fit.axis_angle_rad);
        for axis in machine.axes() {
            let c = (fit.q.get(axis.letter) - q.get(axis.letter)).abs();
            match axis.kind {
                AxisKind::Linear => s.max_linear_correction_mm = s.max_linear_correction_mm.max(c),
                AxisKind::Rotary => {
                    s.max_rotary_correction_deg = s.max_rotary_correction_deg.max(c)
                }
            }
        }
    };

    let mut blocks = Vec::new();
    let mut per_move = Vec::with_capacity(program.moves.len());
    let first_line = program.moves.first().map_or(1, |m| m.line);
    // The corrected start: where the machine must be for the first move to start right.
    let c0 = solver.solve(start, start, &all_free, first_line)?;
    note(&c0, start, first_line, &mut summary);
    let mut prev = c0.q;
    if printed(&axes, &prev) != printed(&axes, start) && !program.moves.is_empty() {
        blocks.push(Block {
            kind: MoveKind::Rapid,
            end: printed(&axes, &prev),
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
        let dirs0 = dirs;
        let offset = |q: &AxisValues| {
            // Warm start: the correction varies slowly along a program.
            let (p, s0) = (prev.to_array(), mv.start.to_array());
            let q = q.to_array();
            AxisValues::from_array(std::array::from_fn(|k| q[k] + (p[k] - s0[k])))
        };
        if straight_at_fixed_rotary(machine, mv) {
            // Same rotary values as the start (exactly), linear axes solved.
            let mut guess = offset(&mv.end);
            for a in machine.axes().iter().filter(|a| a.kind == AxisKind::Rotary) {
                guess.set(a.letter, prev.get(a.letter));
            }
            let (fit, d) =
                solver.solve_from(&mv.end, &guess, &linear_free, mv.line, (&prev, dirs0))?;
            dirs = d;
            note(&fit, &mv.end, mv.line, &mut summary);
            blocks.push(Block {
                kind,
                end: printed(&axes, &fit.q),
                feed_mm_per_min: mv.feed_mm_per_min,
                source: Some(index),
                line: mv.line,
                part: (1, 1),
                s: (0.0, 1.0),
                inverse_time_per_min: None,
            });
            per_move.push(MoveCorrection {
                line: mv.line,
                sub_moves: 1,
                residual_rms_mm: fit.residual_rms_mm,
                residual_max_mm: fit.residual_max_mm,
                axis_angle_rad: fit.axis_angle_rad,
                subdivision_error_mm: 0.0,
            });
            prev = fit.q;
            continue;
        }
        // A move that turns a rotary axis (or a curved one): subdivide.
        let mut n = 1usize;
        let (points, worst, fits) = loop {
            let mut pts = vec![prev];
            let mut fits = Vec::with_capacity(n);
            let mut point_dirs = vec![dirs0];
            for j in 1..=n {
                let s = j as Real / n as Real;
                let q = path_point(mv, s);
                let last = *pts.last().unwrap_or(&prev);
                let prev_q = path_point(mv, (j - 1) as Real / n as Real);
                let guess = {
                    let (l, pq, qa) = (last.to_array(), prev_q.to_array(), q.to_array());
                    AxisValues::from_array(std::array::from_fn(|k| qa[k] + (l[k] - pq[k])))
                };
                let from = (&last, point_dirs[j - 1]);
                let (fit, d) = solver.solve_from(&q, &guess, &all_free, mv.line, from)?;
                note(&fit, &q, mv.line, &mut summary);
                pts.push(fit.q);
                fits.push(fit);
                point_dirs.push(d);
            }
            // Check the chords against the best achievable pose inside each part.
            let mut worst: Real = 0.0;
            for j in 0..n {
                let before = machine.reversal_state(&point_dirs[j]);
                solver.set_directions(&point_dirs[j + 1]);
                let ca = taken_up(machine, &pts[j], &before, &solver.state);
                let cb = pts[j + 1];
                for t in CHECK_AT {
                    let s = (j as Real + t) / n as Real;
                    let q = path_point(mv, s);
                    let chord = lerp(&ca, &cb, t);
                    let best = solver.solve(&q, &chord, &all_free, mv.line)?;
                    summary.poses_solved += 1;
                    let (pc, pb) = (
                        machine.w_from_t_state(&chord, &solver.state),
                        machine.w_from_t_state(&best.q, &solver.state),
                    );
                    for h in solver.flute.ends {
                        worst = worst.max((pc * axis_point(h) - pb * axis_point(h)).norm());
                    }
                }
            }
            if worst <= opts.path_tolerance_mm {
                dirs = *point_dirs.last().unwrap_or(&dirs0);
                solver.set_directions(&dirs);
                break (pts, worst, fits);
            }
            n = next_split(n, worst, opts, mv.line)?;
        };
        for (j, p) in points.iter().enumerate().skip(1) {
            blocks.push(Block {
                kind,
                end: printed(&axes, p),
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
        per_move.push(MoveCorrection {
            line: mv.line,
            sub_moves: n,
            residual_rms_mm: fits.iter().map(|f| f.residual_rms_mm).fold(0.0, Real::max),
            residual_max_mm: fits.iter().map(|f| f.residual_max_mm).fold(0.0, Real::max),
            axis_angle_rad: fits.iter().map(|f| f.axis_angle_rad).fold(0.0, Real::max),
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

pub use crate::nc::controller_length;

/// The blocks as moves from `start`, as the controller runs them (a block that goes
/// nowhere is no move).
pub(super) fn block_moves(blocks: &[Block], start: &AxisValues) -> Vec<Move> {
    let mut moves = Vec::with_capacity(blocks.len());
    let mut at = *start;
    for b in blocks {
        if b.end != at {
            // A G93 block runs at the feed that makes its length take 1/F minutes, as the
            // controller converts it.
            let feed = match b.inverse_time_per_min {
                Some(f) => Some(f * controller_length(&at, &b.end)),
                None => b.feed_mm_per_min,
            };
            moves.push(Move {
                kind: b.kind,
                start: at,
                end: b.end,
                feed_mm_per_min: feed,
                line: b.line,
            });
        }
        at = b.end;
    }
    moves
}

/// The length a feed-per-minute controller applies a source move's F to: a straight move's
/// [`controller_length`]; an arc's helix in X Y Z (LinuxCNC's `find_arc_length`: the start
/// radius times the angle swept, with the travel along the normal as the other side of the
/// right triangle when there is any), whatever A B C do meanwhile.
fn source_length(mv: &Move) -> Real {
    match mv.kind {
        MoveKind::Arc(g) => {
            let xyz = |v: &AxisValues| {
                Vector3::new(
                    v.get(AxisLetter::X),
                    v.get(AxisLetter::Y),
                    v.get(AxisLetter::Z),
                )
            };
            let along = (xyz(&mv.end) - xyz(&mv.start)).dot(&g.normal);
            let around = g.radius * g.sweep_deg.to_radians().abs();
            if along == 0.0 {
                around
            } else {
                around.hypot(along)
            }
        }
        _ => controller_length(&mv.start, &mv.end),
    }
}

/// Puts the feed blocks of source moves (straight or arcs) that turn a rotary axis (in the source or
/// in the block) into inverse time where the programmed feed would give them another
/// duration than their part of the source move: the source move takes `T =
/// controller_length / F` minutes, each of its `n` parts (equal shares of its parameter)
/// must take `T/n`, and gets `F = n/T` in `G93` unless `controller_length / F` of the block
/// is within [`DURATION_TOLERANCE`] of `T/n` (an arc's `T` is its helix's length at F,
/// [`source_length`]). Returns the number of blocks put in inverse time.
pub(super) fn inverse_time_feeds(
    blocks: &mut [Block],
    source: &[Move],
    start: &AxisValues,
) -> usize {
    let turns = |a: &AxisValues, b: &AxisValues| {
        [AxisLetter::A, AxisLetter::B, AxisLetter::C]
            .iter()
            .any(|&l| a.get(l) != b.get(l))
    };
    let mut count = 0;
    let mut at = *start;
    for b in blocks.iter_mut() {
        let from = at;
        at = b.end;
        let (Some(i), Some(f), MoveKind::Linear) = (b.source, b.feed_mm_per_min, b.kind) else {
            continue;
        };
        let mv = &source[i];
        if matches!(mv.kind, MoveKind::Rapid)
            || !(turns(&mv.start, &mv.end) || turns(&from, &b.end))
        {
            continue;
        }
        // The parts are equal shares of the source parameter (an arc's angle): each takes
        // T/n, F = n·f/L.
        let (length, parts) = (source_length(mv), b.part.1 as Real);
        let nominal = length / f / parts;
        let as_programmed = controller_length(&from, &b.end) / f;
        if nominal > 0.0 && (as_programmed - nominal).abs() > DURATION_TOLERANCE * nominal {
            b.inverse_time_per_min = Some(f * parts / length);
            count += 1;
        }
    }
    count
}

/// The program as given, in the form of a corrected one (every move one block, values
/// unchanged): what the deviated machine does without correction.
pub fn uncorrected(
    machine: &Chain,
    program: &Program,
    start: &AxisValues,
) -> Result<CorrectedProgram, CorrectError> {
    for mv in &program.moves {
        check_move(machine, mv)?;
    }
    let blocks: Vec<Block> = program
        .moves
        .iter()
        .enumerate()
        .map(|(i, mv)| Block {
            kind: emitted_kind(mv.kind),
            end: mv.end,
            feed_mm_per_min: mv.feed_mm_per_min,
            source: Some(i),
            line: mv.line,
            part: (1, 1),
            s: (0.0, 1.0),
            inverse_time_per_min: None,
        })
        .collect();
    Ok(CorrectedProgram {
        start: *start,
        axes: AxisLetter::ALL
            .into_iter()
            .filter(|l| machine.has_axis(*l))
            .collect(),
        summary: CorrectionSummary {
            moves: program.moves.len(),
            blocks: blocks.len(),
            ..CorrectionSummary::default()
        },
        blocks,
        moves: program.moves.clone(),
        per_move: Vec::new(),
        ended: program.ended_by.is_some(),
    })
}

fn check_move(machine: &Chain, mv: &Move) -> Result<(), CorrectError> {
    for l in AxisLetter::ALL {
        for v in [mv.start.get(l), mv.end.get(l)] {
            if !v.is_finite() {
                return Err(CorrectError::NonFinite {
                    line: mv.line,
                    axis: l.as_char(),
                });
            }
        }
        if !machine.has_axis(l) && mv.start.get(l) != mv.end.get(l) {
            return Err(CorrectError::MissingAxis {
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
