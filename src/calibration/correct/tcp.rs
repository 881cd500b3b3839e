//! The corrected program for a tool-centre-point controller: every corrected joint pose
//! written as the TCP coordinates the controller turns back into it (the nominal chain's
//! forward kinematics, [`crate::machine::tcp`]).

use super::*;
use crate::machine::chain::Chain;
use crate::machine::tcp::tcp_from_joint;
use crate::nc::{AxisValues, MoveKind, controller_length};

/// `program` (corrected joint blocks) with every block's end in TCP coordinates of the
/// nominal chain `nominal`: X Y Z the tool tip in the workpiece frame, A B C the corrected
/// rotary values, as printed. A TCP controller fed these blocks solves the same joint values
/// at every block end (to the printing's 1 nm); between the ends it keeps the tip on the
/// straight line in the workpiece frame, where the joint blocks would move it along a chord in
/// joint space — the corrected path is a small correction of the programmed one, so it is at
/// least as close to it.
///
/// Durations stay those of the joint blocks: a `G93` block keeps its `F` (1/min); a `G94`
/// feed block whose TCP length at its feed would take another time than its joint length
/// (one that turns a rotary axis) is put in `G93` with `F = 1/T`. `moves` stay the joint
/// moves (what the twin simulates).
pub fn in_tcp(program: &CorrectedProgram, nominal: &Chain) -> CorrectedProgram {
    let mut out = program.clone();
    let printed = |q: &AxisValues| {
        let mut p = *q;
        for &l in &program.axes {
            p.set(l, as_printed(l, q.get(l)));
        }
        p
    };
    let mut at = (program.start, tcp_from_joint(nominal, &program.start));
    let mut count = 0;
    for b in out.blocks.iter_mut() {
        let (from, from_tcp) = at;
        let end_tcp = tcp_from_joint(nominal, &b.end);
        at = (b.end, end_tcp);
        if let (MoveKind::Linear, None, Some(f)) =
            (b.kind, b.inverse_time_per_min, b.feed_mm_per_min)
        {
            let minutes = controller_length(&from, &b.end) / f;
            let tcp_length = controller_length(&from_tcp, &end_tcp);
            if minutes > 0.0 && (tcp_length / minutes - f).abs() > DURATION_TOLERANCE * f {
                b.inverse_time_per_min = Some(1.0 / minutes);
            }
        }
        if b.inverse_time_per_min.is_some() {
            count += 1;
        }
        b.end = printed(&end_tcp);
    }
    out.summary.inverse_time_blocks = count;
    out
}
