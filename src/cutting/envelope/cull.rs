//! Culling: a cheap, conservative test of whether a move can change a ray's material, run
//! before the ray's envelope is solved.
//!
//! The move's poses at `λ = k/(C·N)`, `k = 0..=C·N` (`N` cells, `C` = [`CULL_STEPS`] poses a
//! cell), are kept. Every `λ` lies within `1/(2·C·N)` of one of them, and no tool point
//! moves faster than the speed bound `M` per unit `λ`, so the tool at any `λ` lies inside
//! the tool at the nearest kept pose grown by `g = M/(2·C·N)` (plus [`CULL_MARGIN`] for the
//! rounding of the interval arithmetic). Along a ray the swept volume therefore lies inside
//! the union of the grown tools' intervals. When none of those meets a material segment
//! (open intervals, as [`crate::cutting::stock`] subtracts them), every interval the
//! envelope returns misses the material too and the ray comes out unchanged: skipping its
//! solve changes nothing, bit for bit. (The envelope joins intervals less than
//! [`tol::SLIVER`] apart; a material segment is at least that long, so it cannot lie in
//! such a gap clear of both grown ends.)
//!
//! A cell's middle pose grown by the envelope's `δ` holds the tool over the whole cell: a
//! ray whose material that misses is culled for the cell at once. Likewise the kept pose in
//! the middle of each half-cell (`λ` within `1/(4N)` of it) grown by `M/(4N)` holds the tool
//! over that half: where it misses the material, the half's inner kept poses need no test.
//!
//! **Invariant:** a ray is culled only when the exact envelope could not change it.

use super::*;
use crate::cutting::stock::Segment;

/// Kept poses per cell for the cull test.
pub(super) const CULL_STEPS: usize = 8;

/// Added to the grown distance of the cull test (mm): far above the rounding of poses and
/// intervals in a workpiece a metre across, far below a dexel pitch.
pub(super) const CULL_MARGIN: Real = 1e-9;

/// The poses of the cull test and their growth.
#[derive(Clone, Debug)]
pub(super) struct CullPoses {
    pub(super) poses: Vec<Sample>,
    pub(super) grow: Real,
    /// The growth of a half-cell's middle pose that holds the tool over the half-cell.
    pub(super) half_grow: Real,
}

impl CullPoses {
    /// The kept poses of `path` for `cells` cells with speed bound `speed`.
    pub(super) fn new(path: &MovePath, cells: usize, speed: Real) -> Self {
        let n = CULL_STEPS * cells;
        let poses = (0..=n)
            .map(|k| path.sample(k as Real / n as Real))
            .collect();
        Self {
            poses,
            grow: speed / (2 * n) as Real + CULL_MARGIN,
            half_grow: speed / (4 * cells) as Real + CULL_MARGIN,
        }
    }
}

impl RotaryEnvelope {
    /// Whether the move may change the material `segs` of the ray `o + t·e` (`e` unit):
    /// false only when no grown kept pose meets any segment (see the module docs). Each
    /// cell is first tested whole, by its middle pose grown by `δ` (which holds the tool
    /// throughout the cell); its kept poses only when that meets the material, the cell's
    /// ends first (where a move that cuts the ray usually meets its material), then the
    /// inner ones of each half-cell whose middle pose, grown to hold the half, meets it.
    pub fn may_cut(&self, o: &Point3, e: &Vector3, segs: &[Segment]) -> bool {
        let meets = |s: &Sample, g: Real| {
            let p = s.rot.tr_mul(&(o - s.tip));
            let u = s.rot.tr_mul(e);
            tool_interval(self.shape, self.r, self.l, &p, &u, g)
                .is_some_and(|(t0, _, t1, _)| segs.iter().any(|m| t0 < m.hi.t && t1 > m.lo.t))
        };
        let (g, half) = (self.cull.grow, self.cull.half_grow);
        const H: usize = CULL_STEPS / 2;
        (0..self.cells).any(|j| {
            let kept = &self.cull.poses[j * CULL_STEPS..=(j + 1) * CULL_STEPS];
            // Half 0 holds kept poses 0..=H (0 tested already), half 1 H..=2H (H and 2H
            // tested already).
            let inner = |h: usize| {
                let range = if h == 0 { 1..=H } else { H + 1..=2 * H - 1 };
                meets(&kept[h * H + H / 2], half) && kept[range].iter().any(|s| meets(s, g))
            };
            meets(&self.samples[2 * j + 1], self.delta + CULL_MARGIN)
                && (meets(&kept[0], g) || meets(&kept[CULL_STEPS], g) || inner(0) || inner(1))
        })
    }
}
