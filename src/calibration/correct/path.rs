//! Moves as paths: the commanded axis values along a move, and the moves whose deviated
//! path is straight.

use crate::machine::chain::{AxisKind, Chain};
use crate::math::Real;
use crate::nc::{AxisValues, Move, MoveKind};

/// The commanded axis values at parameter `s ∈ [0, 1]` of a move.
pub fn path_point(mv: &Move, s: Real) -> AxisValues {
    match mv.kind {
        MoveKind::Rapid | MoveKind::Linear => lerp(&mv.start, &mv.end, s),
        MoveKind::Arc(_) => mv.point_at(s),
    }
}

/// Whether the move is a straight line in axis space with every rotary axis of `chain`
/// fixed and no axis with error motions moving (then its deviated path is straight too:
/// see the module docs).
pub fn straight_at_fixed_rotary(chain: &Chain, mv: &Move) -> bool {
    match mv.kind {
        MoveKind::Rapid | MoveKind::Linear => chain
            .axes()
            .iter()
            .zip(chain.error_motions_all())
            .filter(|(a, e)| a.kind == AxisKind::Rotary || e.is_some())
            .all(|(a, _)| mv.start.get(a.letter) == mv.end.get(a.letter)),
        MoveKind::Arc(_) => false,
    }
}

/// The kind a corrected (straight) sub-move of `kind` is emitted as: rapids stay rapids,
/// every feed move (an arc too) becomes straight `G1` chords.
pub(super) fn emitted_kind(kind: MoveKind) -> MoveKind {
    if matches!(kind, MoveKind::Rapid) {
        MoveKind::Rapid
    } else {
        MoveKind::Linear
    }
}

/// Where the path of a move from `from` really starts when its axes change their reversal
/// share from `old` to `new` ([`Chain::reversal_state`]): the lost motion is taken up first
/// (the axis dwells while the command travels `old − new`), so the commanded point whose
/// settled pose is the move's true start is `from + (old − new)` on each such axis. The
/// path checks compare the move from there; the dwell itself is a delay along the path,
/// not a departure from it.
pub(super) fn taken_up(
    machine: &Chain,
    from: &AxisValues,
    old: &[Real; 6],
    new: &[Real; 6],
) -> AxisValues {
    let mut q = *from;
    for axis in machine.axes() {
        let k = axis.letter.index();
        if old[k] != new[k] {
            q.set(axis.letter, from.get(axis.letter) + old[k] - new[k]);
        }
    }
    q
}

pub(super) fn lerp(a: &AxisValues, b: &AxisValues, s: Real) -> AxisValues {
    let (a, b) = (a.to_array(), b.to_array());
    AxisValues::from_array(std::array::from_fn(|k| a[k] + (b[k] - a[k]) * s))
}
