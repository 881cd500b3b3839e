//! NC-program correction (seed 002 Fig. 1; see docs/identification-and-correction.md):
//! rewrite a program so that the deviated machine reproduces the nominal tool path, and
//! measure how well it does.
//!
//! # The pose problem
//!
//! For every commanded pose `q` the nominal machine puts the tool at `N(q) = nominal
//! w_from_t(q)`. Correction looks for `q'` with `D(q') ≈ N(q)`, `D` the deviated chain (the
//! model to correct for). The tool is rotationally symmetric, so only its axis line matters:
//! its tip position (3 DOF) and direction (2 DOF) — 5 numbers, while an XYZA machine has 4
//! commands. The solve is therefore least squares, on what cuts: the squared distance of
//! the deviated tool axis from the nominal one, *averaged over the flute* `h ∈ [0, L]`,
//!
//! ```text
//! F(q') = (1/L) ∫₀ᴸ |D(q')·a(h) − N(q)·a(h)|² dh,   a(h) = (0, 0, h) in the tool frame.
//! ```
//!
//! The error `e(h)` of an axis point is affine in `h`, so `|e(h)|²` is a quadratic and the
//! two-point Gauss–Legendre rule `h = L/2·(1 ∓ 1/√3)`, weights ½, integrates it exactly:
//! `F = (|e(h₁)|² + |e(h₂)|²)/2`. Gauss–Newton runs on the six residuals `e(h₁), e(h₂)` with
//! the analytic Jacobian of the chain (a linear axis moves every point along its direction
//! in W, a rotary axis about its line: `ω × (p − o)`), solved by SVD so that a redundant axis
//! (a C axis parallel to the tool) takes the minimum-norm step and stays where it was
//! commanded. Why this weighting rather than the tip alone: a tool axis that cannot be made
//! parallel to the nominal one (below) is best placed crossing the nominal axis at the
//! middle of the flute, which halves the largest error over the cutting length and
//! minimises its mean square; the tip and the flute's end are each `|δv|·L/2` off.
//! `sqrt(F)` is reported as the pose's *residual*: what cannot be corrected.
//!
//! **What four axes cannot correct.** The axis direction error depends only on the rotary
//! values; when the linear axes span R³ they make the flute's mid point exact whatever the
//! rotaries are, so the optimum splits into "rotaries minimise the direction error, linear
//! axes place the mid point". On an XYZA machine the A axis turns the tool direction about
//! X only: a tilt of the tool in the plane of X and the tool axis (the sum of the beta
//! deviations of the joints between A and the spindle, on the MDX-50 `beta_AY + beta_YX +
//! beta_XZ + beta_ZS`) stays, with a residual of `|β|·L/√12` RMS over the flute.
//!
//! **A rotary axis parallel to the tool.** Turning a rotary axis changes the tool direction
//! by the sine of its angle to the tool; parallel (C at A = 0 on a trunnion, at B = 0 on a
//! head-table machine) it only carries the part around under the tool, which the linear axes
//! undo. Near there the least-squares optimum is flat along the rotary (exactly flat at the
//! parallel pose), and an undamped step turns it by degrees to buy micro-radians of direction.
//! The solve minimises instead `F(q') + λ²·(L²/6)/2·|r' − r|²` over the rotary values `r'`
//! (commanded `r`, radians), `ROTARY_DAMPING` `λ`, so a rotary departure costs what the same
//! angle of direction error costs on the flute: one damping row per free rotary axis beside
//! the six flute residuals. A rotary then moves by at most `|δv|/(2λ)` to remove a direction
//! error `δv`, continuously in the commanded pose, and stays on the commanded branch; what
//! it leaves is reported as the pose's residual and its axis angle.
//!
//! # Straight moves stay single moves
//!
//! *Claim:* on any chain of rigid transforms, a move that interpolates the linear axes
//! linearly at fixed rotary values moves the tool along a straight line at constant
//! orientation. *Proof:* `w_from_t(q) = Π M_i(q_i)·E_i`; with the rotaries fixed every
//! rotary `M_i` and every `E_i` is a constant transform, and every linear `M_i` is the pure
//! translation `Trans(d_i·q_i)`. Moving a pure translation left through the constant
//! transforms before it turns it into a translation by `R_{<i}·d_i·q_i`, with `R_{<i}` the
//! constant rotation of the prefix, so `w_from_t(q) = Trans(Σ R_{<i} d_i q_i)·C` with `C`
//! constant: the orientation is constant and the position affine in the linear values.
//! Linear interpolation of `q` between two corrected end points is then the straight
//! segment between the two deviated end poses, at the nominal orientation-optimum — and the
//! nominal path is the straight segment between the nominal end poses. Their distance is
//! the linear interpolation of the two end residuals, so it never exceeds them. ∎
//! Both ends get the same rotary values exactly (solved once, kept for the end, whose linear
//! axes alone are solved), so the corrected move still turns no rotary axis.
//!
//! # Moves that turn a rotary axis
//!
//! Between two corrected sub-points the deviated machine interpolates axis values
//! linearly, which is not the corrected path in between. Such a move is split into `n`
//! equal parts of its source parameter, every sub-point corrected, and the distance between
//! the deviated tool axis (tip and flute end) on the chord and on the best achievable pose
//! is checked at ¼, ½ and ¾ of every part; `n` grows until it is within the path tolerance.
//! Sub-moves keep the source move's feed and kind (rapids stay `G0`, feed moves become `G1`
//! chords). Moves are read only through [`path_point`] and [`straight_at_fixed_rotary`]: a
//! new move kind (an arc) needs one match arm in each and nothing else.
//!
//! # Verification
//!
//! [`path_error`] samples every corrected sub-move densely on a chain (the simulated
//! machine) against the nominal path; [`face_errors`] measures the milled faces of a
//! swept stock: the dexel crossings cut by a face's source line inside the face region,
//! against the nominal flank plane — exact along each ray, no scanner, no grid bias.
//!
//! # Tool-centre-point programs
//!
//! A scene whose controller runs TCP programs is corrected on the joint moves its program
//! becomes ([`crate::machine::tcp`]); [`in_tcp`] writes the corrected joint poses back as
//! the TCP coordinates the controller turns into them.
//!
//! **Invariant:** correction reads moves and chains and writes G-code into a writer it is
//! given; it never parses text, opens files or runs the scanner.

mod gcode;
mod hexapod;
mod path;
mod pose;
mod program;
mod tcp;
#[cfg(test)]
mod tests;
mod verify;

pub use gcode::write_gcode;
pub use hexapod::{HexapodFit, HexapodSolver, correct_hexapod_program, hexapod_path_error};
use path::{emitted_kind, lerp, taken_up};
pub use path::{path_point, straight_at_fixed_rotary};
use pose::axis_point;
pub use pose::{FlutePoints, PoseFit, PoseSolver};
pub use program::{
    Block, CorrectedProgram, CorrectionSummary, MoveCorrection, as_printed, controller_length,
    correct_program, uncorrected,
};
use program::{block_moves, format_axis, inverse_time_feeds, printed};
pub use tcp::in_tcp;
pub use verify::{
    FaceCheck, FaceError, PartError, PathError, axis_angle_error, face_errors, nominal_face,
    part_error, path_error,
};

use crate::math::Real;

/// Errors of correction and its verification.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum CorrectError {
    /// The accuracy asked for is not a positive finite length.
    #[error("the accuracy must be a positive number of mm, got {0}")]
    BadAccuracy(Real),
    /// An option is out of its range.
    #[error("{name} must be {range}, got {value}")]
    BadOption {
        /// The option.
        name: &'static str,
        /// Its valid range.
        range: &'static str,
        /// The value given.
        value: Real,
    },
    /// A move has a non-finite axis value or feed.
    #[error("line {line}: axis {axis} is not a finite number")]
    NonFinite {
        /// Source line.
        line: usize,
        /// Axis letter (`F` for the feed).
        axis: char,
    },
    /// A move drives an axis the machine does not have.
    #[error("line {line}: the machine has no {axis} axis")]
    MissingAxis {
        /// Source line.
        line: usize,
        /// Axis letter.
        axis: char,
    },
    /// Gauss–Newton did not settle on a pose.
    #[error(
        "line {line}: the corrected pose did not converge in {iterations} iterations (last step {step_mm:.3e} mm)"
    )]
    NotConverged {
        /// Source line.
        line: usize,
        /// Iterations made.
        iterations: usize,
        /// Size of the last step (mm at the flute).
        step_mm: Real,
    },
    /// The pose needs a correction larger than allowed: the deviated machine cannot reach
    /// it near the commanded axis values.
    #[error(
        "line {line}: the pose is not reachable: axis {axis} would need a correction of {correction:.6} (limit {limit})"
    )]
    Unreachable {
        /// Source line.
        line: usize,
        /// Axis letter.
        axis: char,
        /// The correction it would need (mm or degrees).
        correction: Real,
        /// The limit (mm or degrees).
        limit: Real,
    },
    /// A hexapod's corrected command lies outside the controller's workspace (a strut out
    /// of its stroke, a joint past its limit, a singular pose), or the machine cannot
    /// reach a command.
    #[error("line {line}: the corrected pose {pose} is outside the workspace: {message}")]
    Workspace {
        /// Source line.
        line: usize,
        /// The command (mm, degrees).
        pose: String,
        /// Why.
        message: String,
    },
    /// A rotary move would need more sub-moves than allowed to meet the path tolerance.
    #[error(
        "line {line}: meeting the path tolerance of {tolerance_mm} mm needs more than {limit} sub-moves"
    )]
    TooManySubmoves {
        /// Source line.
        line: usize,
        /// The tolerance (mm).
        tolerance_mm: Real,
        /// The limit.
        limit: usize,
    },
    /// What correction does not do on this machine.
    #[error("{0}")]
    Unsupported(String),
    /// A face to check has no cut on its line, or too few crossings to fit.
    #[error("face '{face}': {message}")]
    Face {
        /// Face name.
        face: String,
        /// What is wrong.
        message: String,
    },
}

impl CorrectError {
    /// The source line the error is about, if any.
    pub fn line(&self) -> Option<usize> {
        match self {
            CorrectError::NonFinite { line, .. }
            | CorrectError::MissingAxis { line, .. }
            | CorrectError::NotConverged { line, .. }
            | CorrectError::Unreachable { line, .. }
            | CorrectError::Workspace { line, .. }
            | CorrectError::TooManySubmoves { line, .. } => Some(*line),
            _ => None,
        }
    }
}

/// Options of [`correct_program`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CorrectOptions {
    /// Largest distance (mm) between the deviated machine's tool axis on a corrected rotary
    /// move and the best achievable one, checked between sub-points. Valid: (0, 1].
    /// Typical: a quarter of the accuracy asked for.
    pub path_tolerance_mm: Real,
    /// Largest correction of one axis (mm for linear axes, degrees for rotary ones) before a
    /// pose counts as unreachable. Valid: (0, 1000]. Assembly deviations need well under
    /// 1 mm; 10 catches a solve that wandered off.
    pub max_correction: Real,
}

impl CorrectOptions {
    /// Options for an accuracy (mm): path tolerance a quarter of it, corrections up to 10.
    pub fn for_accuracy(accuracy_mm: Real) -> Self {
        Self {
            path_tolerance_mm: accuracy_mm / 4.0,
            max_correction: 10.0,
        }
    }

    fn validate(&self) -> Result<(), CorrectError> {
        let t = self.path_tolerance_mm;
        if !(t > 0.0 && t <= 1.0) {
            return Err(CorrectError::BadOption {
                name: "path_tolerance_mm",
                range: "in (0, 1] mm",
                value: t,
            });
        }
        let m = self.max_correction;
        if !(m > 0.0 && m <= 1000.0) {
            return Err(CorrectError::BadOption {
                name: "max_correction",
                range: "in (0, 1000]",
                value: m,
            });
        }
        Ok(())
    }
}

/// Gauss–Newton stops when a step moves the flute by less than this (mm): 0.1 pm, far
/// below the 1 nm the G-code prints and above f64 rounding of poses at 1,000 mm (1e-13).
const NEWTON_STEP_MM: Real = 1e-10;
/// Gauss–Newton iterations before giving up. Deviations are small: 2–4 iterations suffice;
/// 30 allows for large offsets on long lever arms.
const MAX_NEWTON: usize = 30;
/// Singular values below this fraction of the largest are treated as zero: a redundant axis
/// (a rotary parallel to the tool) gets no step. 1e-10 is far above f64 rounding of the
/// Jacobian (1e-16 relative) and far below any real axis's lever (1e-3 relative and more).
const RANK_RATIO: Real = 1e-10;
/// Tikhonov weight λ of a rotary axis's departure from its commanded value, against the
/// tool-direction error it buys (rad per rad). Near an orientation where a rotary axis is
/// parallel to the tool (C at A = 0 on a trunnion, C at B = 0 on a head-table machine) the
/// axis barely turns the tool's direction (its lever is the sine of the angle between
/// them), and undamped Gauss–Newton would turn it by degrees to buy micro-radians. With
/// the damping a rotary moves by at most `|δv|/(2λ)` to remove a direction error `δv`
/// (30 µrad: 0.09°), continuously as the pose approaches the parallel one, and what it
/// does not remove stays as the reported residual; far from it (lever ≈ 1) it leaves
/// `λ²` of the correctable direction error: 1e-4 of 1 mrad, 2.5 nm over a 25 mm flute.
const ROTARY_DAMPING: Real = 1e-2;
/// Largest number of sub-moves for one source move.
pub const MAX_SUBMOVES: usize = 100_000;

/// The next number of parts to split the move at `line` into, after `n` parts left a
/// chord error of `worst` against the tolerance: the chord error falls as 1/n², so jump
/// close to the n needed, at least doubling; refused past [`MAX_SUBMOVES`].
pub(crate) fn next_split(
    n: usize,
    worst: Real,
    opts: &CorrectOptions,
    line: usize,
) -> Result<usize, CorrectError> {
    let grow = (worst / opts.path_tolerance_mm).sqrt() * 1.2;
    let next = ((n as Real) * grow.max(2.0)).ceil();
    if next > MAX_SUBMOVES as Real {
        return Err(CorrectError::TooManySubmoves {
            line,
            tolerance_mm: opts.path_tolerance_mm,
            limit: MAX_SUBMOVES,
        });
    }
    Ok(next as usize)
}
/// Where a sub-move's chord is checked against the best achievable path.
const CHECK_AT: [Real; 3] = [0.25, 0.5, 0.75];
/// Decimals printed for linear axes (mm): 1 nm.
pub const LINEAR_DECIMALS: usize = 6;
/// Decimals printed for rotary axes (degrees): 1e-7° is 0.17 nm at 100 mm from the axis.
pub const ROTARY_DECIMALS: usize = 7;
/// A rotary block whose duration at the programmed feed is within this fraction of its share
/// of the source move's keeps `G94`: 1e-9 is far above f64 rounding of lengths (1e-15), so a
/// move nothing changed stays as programmed; any real change, even the printed values'
/// rounding to 1 nm (up to 5e-8 of a 10 mm move), is above it and gets `G93`, which keeps the
/// duration exactly.
const DURATION_TOLERANCE: Real = 1e-9;
/// Samples per sub-move (besides its ends) in [`path_error`]: the chord's distance from a
/// smooth path peaks inside; 8 samples see it to within a few percent.
pub const PATH_SAMPLES: usize = 8;
/// A crossing belongs to a face when its material normal is within 25° of the face's
/// (cos 25° ≈ 0.9): crossings on the face itself have normals within 1e-7 rad of it.
const FACE_NORMAL_COS: Real = 0.9;
