//! Tool sweep: every move's swept volume, through the deviated chain, removed from the stock.
//!
//! **Straight moves at constant rotary values are exact.** In any chain of linear and rotary
//! axes, holding the rotary values fixed makes the tool's orientation constant and its
//! position an affine function of the linear axis values, so a linearly interpolated move is
//! a pure translation of the tool in the workpiece frame. Flat and ball end mills are convex,
//! so the swept volume is convex, and its interval along a ray is found in closed form: with
//! `t` the ray parameter and `s ∈ [0, 1]` the move parameter, the set of `(t, s)` where the
//! ray point lies inside the tool at `s` is bounded by one convex quadric (the tool's radius)
//! and straight lines (its end faces and `s = 0, 1`). The extremes of `t` over that 2-D
//! convex set lie on one of a handful of candidate points (the quadric's own extremes, line
//! ∩ quadric, line ∩ line), each computed by a quadratic formula.
//!
//! **Moves that turn a rotary axis** with a flat or ball end mill are cut by the exact
//! per-ray envelope of [`crate::cutting::envelope`], its interval ends within the bound
//! asked for (`rotary_step_bound_mm`, the envelope's tolerance, so a looser bound buys
//! fewer solve steps) of the true swept surface, the bound reported. Other tools, or a
//! bound asked tighter than [`crate::cutting::envelope::ENVELOPE_TOL`] = 1e-7 mm (0.1 nm),
//! the envelope's finest, fall back to sub-steps:
//!
//! such a move is split into `N` sub-steps, each swept as a
//! translation with the mid-step orientation, its mid-height point `c` moving straight
//! between its exact positions at the sub-step's ends. The distance between any tool point
//! on the true and on the approximate motion is at most
//! `ε(N) = ω·ρ_tool/(2N) + (ω²·ρ_axis + 2·ω·v)/(8N²)`, with `ω` the total rotation (rad),
//! `ρ_tool` the largest distance of a tool point from `c`, `ρ_axis` the largest distance of
//! `c` from a rotary axis point and `v` the linear travel: the first term is the orientation
//! held fixed over a sub-step, the second the chord error of `c`'s curved path
//! (`|c''| ≤ ω²ρ_axis + 2ωv`). `N` is the smallest that meets the bound asked for, and the
//! achieved bound is reported.
//!
//! **One driver.** [`sweep_observed`] runs a program: arcs become chords (their exact
//! sagitta reported), consecutive collinear straight moves are joined into one sweep (a
//! rapid always starts a new run), rotary moves go to the envelope or to sub-steps. The plain
//! sweep ([`sweep_program`]) and the collision checks ([`crate::cutting::collide`], through the
//! [`SweepObserver`] trait) both use it, so they remove the same material bit for bit. When
//! the observer does not look at the stock (the plain sweep), up to 16 consecutive envelope
//! moves are cut together, each ray through all of them in turn
//! ([`TriDexel::remove_each`]), and each run of four of them has one test for the lot
//! ([`GroupHull`]: a ray whose material it misses skips the four): the same stock, bit for
//! bit, as move by move.
//!
//! **Invariant:** the sweep reads moves and poses; it never parses text or touches files; an
//! observer only reads the stock.
//!
//! **Files.** This one holds the options, errors, report and the machine the sweep drives;
//! `translated` the closed-form sweep of a translated tool, `substeps` the bounds and
//! sub-steps of moves cut in pieces, `driver` the program driver and its observer, `tests`
//! the unit tests.

use crate::cutting::cutter::{Line, Quadric, SweptTool, t_extremes};
use crate::cutting::envelope::{
    ENVELOPE_TOL, GroupHull, MovePath, RotaryEnvelope, SampledPath, error_motion_speed,
    rotation_and_travel,
};
use crate::cutting::stock::{Cutter, Group, RayCut, TriDexel};
use crate::cutting::tool::{Tool, ToolKind};
use crate::machine::PoseSource;
use crate::machine::chain::{AxisKind, Chain};
use crate::machine::error_motion::Directions;
use crate::math::{Aabb, Isometry3, Point3, Real, Rotation3, UnitVector3, Vector3, tol};
use crate::nc::{AxisLetter, AxisValues, Move, MoveKind};
use crate::progress::Progress;

mod driver;
mod substeps;
mod translated;

pub use driver::{
    NoObserver, Piece, SweepObserver, as_chords, chord_sagitta, sweep_observed, sweep_program,
};
#[cfg(test)]
use substeps::pose_at;
use substeps::{COARSE, Poses, substeps};
pub use substeps::{RotaryBound, SAMPLED_BOUND_FACTOR, SampledBound, rotary_substeps};
pub use translated::TranslatedTool;

/// Options of the sweep.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SweepOptions {
    /// Largest allowed distance (mm) between the true and the simulated tool motion on moves
    /// that turn a rotary axis. Valid: (0, 1]. Typical: 1e-4 (0.1 µm).
    pub rotary_step_bound_mm: Real,
}

/// Errors of the sweep.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SweepError {
    /// A move names an axis the machine does not have.
    #[error("the machine has no {axis} axis")]
    MissingAxis {
        /// Source line.
        line: usize,
        /// Axis letter.
        axis: char,
    },
    /// A rotary move would need an absurd number of sub-steps for the requested bound.
    #[error(
        "meeting the rotary bound of {bound_mm} mm needs {steps:.3e} sub-steps; raise rotary_step_bound_mm"
    )]
    TooManySubsteps {
        /// Source line.
        line: usize,
        /// The bound asked for (mm).
        bound_mm: Real,
        /// The sub-steps it would need.
        steps: Real,
    },
    /// The bound is not in (0, 1] mm.
    #[error("rotary_step_bound_mm must be in (0, 1], got {0}")]
    BadBound(Real),
    /// The machine cannot take a pose of the move (a pose source: out of the workspace, no
    /// forward solution).
    #[error("the machine cannot follow the move: {message}")]
    Pose {
        /// Source line.
        line: usize,
        /// Where along the move, the axis values and why.
        message: String,
    },
}

impl SweepError {
    /// The NC line the error is about, if any.
    pub fn line(&self) -> Option<usize> {
        match self {
            SweepError::MissingAxis { line, .. }
            | SweepError::TooManySubsteps { line, .. }
            | SweepError::Pose { line, .. } => Some(*line),
            SweepError::BadBound(_) => None,
        }
    }
}

/// What the sweep did.
#[derive(Clone, Copy, Debug, PartialEq, Default, serde::Serialize)]
pub struct SweepReport {
    /// Moves processed.
    pub moves: usize,
    /// Moves that removed material. Moves swept as one joined run count when a cut of the
    /// run that removed material names them at one of its ends; envelope moves cut
    /// together (up to 16 consecutive ones, each ray through the latest first, see
    /// [`crate::cutting::stock::TriDexel::remove_each`]) when they removed material the
    /// later moves of their batch left: a move all of whose cut the next few moves re-cut
    /// is not counted there, where cutting each move on its own (an observer that looks
    /// after every move, a holder's checks) counts it.
    pub cutting_moves: usize,
    /// Moves that turned a rotary axis.
    pub rotary_moves: usize,
    /// Moves at fixed rotary values swept as curved moves because an axis with error
    /// motions moves (cut like rotary moves; absent from the report when 0).
    #[serde(skip_serializing_if = "is_zero")]
    pub curved_moves: usize,
    /// Sweeps evaluated (1 per run of joined straight moves, 1 per rotary move cut by the
    /// envelope, N per rotary move cut in sub-steps, pruned ones excluded).
    pub sweeps: usize,
    /// Largest bound on the error of rotary moves (envelope tolerance or sub-step bound) over
    /// all rotary moves (mm); 0 if none.
    pub rotary_error_bound_mm: Real,
    /// Largest distance of the chords that replace arcs from their arcs (mm): the exact
    /// sagitta `r·(1 − cos(θ/2))` of the widest chord; 0 if no arcs.
    pub chord_error_bound_mm: Real,
    /// Largest distance between the true and the simulated tool motion over all moves (mm):
    /// per move its chord sagitta plus its rotary bound, the largest over the moves.
    pub error_bound_mm: Real,
    /// A machine driven pose by pose ([`Kinematics::Poses`]): the largest distance of the
    /// tool tip from where the controller commands it, over the sampled poses (mm; absent
    /// from the report for a chain).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tip_error_mm: Option<Real>,
    /// A machine driven pose by pose: the largest distance of the tool tip's path from the
    /// straight line between the move's reached ends, over the sampled poses of every move
    /// that turns no angle (mm): how far the deviations curve the controller's straight
    /// moves.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub path_bow_mm: Option<Real>,
}

fn is_zero(n: &usize) -> bool {
    *n == 0
}

/// The machine the sweep drives: a serial chain (every pose through the chain, rotary moves
/// by the envelope or bounded sub-steps), or a machine read pose by pose (a hexapod), each
/// of whose moves is sampled at [`PILOT_STEPS`] + 1 poses and, unless it is an exact
/// translation, cut in sub-steps bounded from those samples (see [`SampledBound`]).
#[derive(Clone, Copy)]
pub enum Kinematics<'a> {
    /// A serial chain.
    Chain(&'a Chain),
    /// A machine read pose by pose.
    Poses(&'a dyn PoseSource),
}

impl<'a> From<&'a Chain> for Kinematics<'a> {
    fn from(chain: &'a Chain) -> Self {
        Kinematics::Chain(chain)
    }
}

impl Kinematics<'_> {
    fn has_axis(&self, l: AxisLetter) -> bool {
        match self {
            Kinematics::Chain(c) => c.has_axis(l),
            Kinematics::Poses(p) => p.has_axis(l),
        }
    }
}

/// Intervals a move of a pose source is sampled in before it is cut: its workspace is
/// checked at these poses and its sub-step bound estimated from them.
pub const PILOT_STEPS: usize = 64;

#[cfg(test)]
#[path = "../../../benches/support/p1.rs"]
#[allow(
    clippy::duplicate_mod,
    reason = "benchmark P1's program is shared by the unit tests of sweep and zmap"
)]
mod p1;

#[cfg(test)]
mod tests;
