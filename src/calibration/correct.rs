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
//! **Invariant:** correction reads moves and chains and writes G-code into a writer it is
//! given; it never parses text, opens files or runs the scanner.

use crate::calibration::identify::{FaceOptions, FaceSpec, StepFrame, extent, flank};
use crate::cutting::stock::TriDexel;
use crate::cutting::tool::Tool;
use crate::machine::chain::{AxisKind, Chain};
use crate::machine::error_motion::{self, Direction, Directions};
use crate::math::{Aabb, Isometry3, Point3, Real, Vector3};
use crate::metrology::fit::{Plane, fit_plane};
use crate::nc::{AxisLetter, AxisValues, Move, MoveKind, Program};
use nalgebra::{SMatrix, SVector};
use std::io::Write;

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
/// Largest number of sub-moves for one source move.
pub const MAX_SUBMOVES: usize = 100_000;
/// Where a sub-move's chord is checked against the best achievable path.
const CHECK_AT: [Real; 3] = [0.25, 0.5, 0.75];
/// Decimals printed for linear axes (mm): 1 nm.
pub const LINEAR_DECIMALS: usize = 6;
/// Decimals printed for rotary axes (degrees): 1e-7° is 0.17 nm at 100 mm from the axis.
pub const ROTARY_DECIMALS: usize = 7;
/// Samples per sub-move (besides its ends) in [`path_error`]: the chord's distance from a
/// smooth path peaks inside; 8 samples see it to within a few percent.
pub const PATH_SAMPLES: usize = 8;
/// A crossing belongs to a face when its material normal is within 25° of the face's
/// (cos 25° ≈ 0.9): crossings on the face itself have normals within 1e-7 rad of it.
const FACE_NORMAL_COS: Real = 0.9;

type Jacobian = SMatrix<Real, 6, 6>;
type Residual = SVector<Real, 6>;

/// The flute points the solve and the path checks use, in the tool frame (mm along +z).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FlutePoints {
    /// The two Gauss–Legendre heights on [0, L].
    pub gauss: [Real; 2],
    /// The flute's ends: the tip (0) and the cutting length L.
    pub ends: [Real; 2],
}

impl FlutePoints {
    /// The points of a tool with cutting length `length`.
    pub fn of(tool: &Tool) -> Self {
        let l = tool.length();
        let g = 1.0 / 3.0_f64.sqrt();
        Self {
            gauss: [l / 2.0 * (1.0 - g), l / 2.0 * (1.0 + g)],
            ends: [0.0, l],
        }
    }
}

/// The corrected pose of one commanded pose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseFit {
    /// The corrected axis values.
    pub q: AxisValues,
    /// Gauss–Newton iterations.
    pub iterations: usize,
    /// RMS distance of the deviated tool axis from the nominal one over the flute (mm):
    /// what the machine's axes cannot correct.
    pub residual_rms_mm: Real,
    /// Largest distance of the deviated tool axis from the nominal one on the flute (at its
    /// tip or end, mm).
    pub residual_max_mm: Real,
}

/// Solves corrected poses on a deviated chain.
#[derive(Clone, Debug)]
pub struct PoseSolver<'a> {
    machine: &'a Chain,
    /// The reversal shares the machine carries at the poses solved
    /// ([`Chain::reversal_state`]); all settled in `+` until set.
    state: [Real; 6],
    nominal: Chain,
    flute: FlutePoints,
    max_correction: Real,
    /// Length (mm) that turns a rotary step (degrees) into mm at the flute.
    lever_mm_per_deg: Real,
}

fn axis_point(h: Real) -> Point3 {
    Point3::new(0.0, 0.0, h)
}

impl<'a> PoseSolver<'a> {
    /// A solver for the deviated `machine` (its nominal is the same chain without
    /// deviations) and `tool`.
    pub fn new(machine: &'a Chain, tool: &Tool, max_correction: Real) -> Self {
        Self {
            machine,
            state: machine.reversal_state(&Directions::default()),
            nominal: machine.nominal(),
            flute: FlutePoints::of(tool),
            max_correction,
            lever_mm_per_deg: tool.length().to_radians(),
        }
    }

    /// Solves the next poses with the axes settled in `dirs` (their reversal shares).
    pub fn set_directions(&mut self, dirs: &Directions) {
        self.state = self.machine.reversal_state(dirs);
    }

    /// Corrects `q` like [`PoseSolver::solve`] for a corrected move from `from`, with each
    /// axis's reversal share consistent with the direction the corrected move takes: solved
    /// first with the axes as `dirs` leaves them; an axis with a reversal whose correction
    /// then moves the other way is turned (its lost motion taken up, so the settled share
    /// of the new direction applies) and the pose solved again. Returns the fit and the
    /// directions after the move.
    pub fn solve_from(
        &mut self,
        q: &AxisValues,
        guess: &AxisValues,
        free: &[bool; 6],
        line: usize,
        (from, dirs): (&AxisValues, Directions),
    ) -> Result<(PoseFit, Directions), CorrectError> {
        let mut d = dirs;
        let mut fit = None;
        for _ in 0..4 {
            self.set_directions(&d);
            let f = self.solve(q, guess, free, line)?;
            let mut turned = false;
            for axis in self.machine.axes() {
                let l = axis.letter;
                let has_reversal = self
                    .machine
                    .error_motions(l)
                    .is_some_and(|e| e.reversal != 0.0);
                let dq = f.q.get(l) - from.get(l);
                if has_reversal && dq != 0.0 && dq.signum() != d.get(l).sign() {
                    let flipped = match d.get(l) {
                        Direction::Positive => Direction::Negative,
                        Direction::Negative => Direction::Positive,
                    };
                    d.set(l, flipped);
                    turned = true;
                }
            }
            fit = Some(f);
            if !turned {
                break;
            }
        }
        // Directions of the axes without a reversal follow the move.
        let after = d;
        let f = fit.ok_or(CorrectError::NotConverged {
            line,
            iterations: 0,
            step_mm: Real::INFINITY,
        })?;
        let mut out = dirs.after_move(from, &f.q);
        for axis in self.machine.axes() {
            out.set(axis.letter, after.get(axis.letter));
        }
        self.set_directions(&out);
        Ok((f, out))
    }

    /// The nominal chain.
    pub fn nominal(&self) -> &Chain {
        &self.nominal
    }

    /// The flute points.
    pub fn flute(&self) -> FlutePoints {
        self.flute
    }

    /// The deviated tool axis points at the Gauss heights for `q`, and the Jacobian of those
    /// six coordinates with respect to the chain's axes (column `i` for axis `i` of the
    /// chain, per mm or per degree; unused columns zero).
    pub fn jacobian(&self, q: &AxisValues) -> ([Point3; 2], Jacobian) {
        let mut prefix = Isometry3::identity();
        let mut bases = [Isometry3::identity(); 6];
        for (i, (axis, dev)) in self
            .machine
            .axes()
            .iter()
            .zip(self.machine.deviations())
            .enumerate()
        {
            bases[i] = prefix;
            let qi = q.get(axis.letter);
            prefix *= axis.motion(qi);
            if let Some(e) = &self.machine.error_motions_all()[i] {
                // Error motions: in the pose exactly; their slopes (µm/mm) are left out of
                // the Jacobian, which Gauss–Newton tolerates (a contraction by the slope).
                let v = e.values_with_offset(qi, self.state[axis.letter.index()]);
                prefix *= error_motion::transform(&v, &self.machine.error_centre(i));
            }
            prefix *= dev.transform();
        }
        let pts = self.flute.gauss.map(|h| prefix * axis_point(h));
        let mut j = Jacobian::zeros();
        for (i, axis) in self.machine.axes().iter().enumerate() {
            let dir = bases[i].rotation * axis.direction.into_inner();
            for (k, p) in pts.iter().enumerate() {
                let col = match axis.kind {
                    AxisKind::Linear => dir,
                    AxisKind::Rotary => {
                        let o = bases[i] * axis.origin;
                        dir.cross(&(p - o)) * (1.0 as Real).to_radians()
                    }
                };
                j.fixed_view_mut::<3, 1>(3 * k, i).copy_from(&col);
            }
        }
        (pts, j)
    }

    /// The nominal tool axis points at the Gauss heights for the commanded `q`.
    pub fn targets(&self, q: &AxisValues) -> [Point3; 2] {
        let pose = self.nominal.w_from_t(q);
        self.flute.gauss.map(|h| pose * axis_point(h))
    }

    /// The residual of `corrected` against the nominal pose of `commanded`:
    /// (RMS over the flute, largest at the flute's ends), mm.
    pub fn residual(&self, commanded: &AxisValues, corrected: &AxisValues) -> (Real, Real) {
        let (dev, nom) = (
            self.machine.w_from_t_state(corrected, &self.state),
            self.nominal.w_from_t(commanded),
        );
        let e = |h: Real| (dev * axis_point(h) - nom * axis_point(h)).norm_squared();
        let rms = ((e(self.flute.gauss[0]) + e(self.flute.gauss[1])) / 2.0).sqrt();
        let max = e(self.flute.ends[0]).max(e(self.flute.ends[1])).sqrt();
        (rms, max)
    }

    /// Corrects the commanded pose `q` starting from `guess`; only the chain axes marked in
    /// `free` (by chain index) move. `line` names the source line in errors.
    pub fn solve(
        &self,
        q: &AxisValues,
        guess: &AxisValues,
        free: &[bool; 6],
        line: usize,
    ) -> Result<PoseFit, CorrectError> {
        for axis in self.machine.axes() {
            for v in [q.get(axis.letter), guess.get(axis.letter)] {
                if !v.is_finite() {
                    return Err(CorrectError::NonFinite {
                        line,
                        axis: axis.letter.as_char(),
                    });
                }
            }
        }
        let targets = self.targets(q);
        let mut x = *guess;
        let mut step_mm = Real::INFINITY;
        for it in 1..=MAX_NEWTON {
            let (pts, mut j) = self.jacobian(&x);
            for (i, f) in free.iter().enumerate() {
                if !f {
                    j.column_mut(i).fill(0.0);
                }
            }
            let mut r = Residual::zeros();
            for k in 0..2 {
                r.fixed_view_mut::<3, 1>(3 * k, 0)
                    .copy_from(&(targets[k] - pts[k]));
            }
            let svd = j.svd(true, true);
            let eps = svd.singular_values.max() * RANK_RATIO;
            let Ok(dq) = svd.solve(&r, eps) else {
                break;
            };
            step_mm = 0.0;
            for (i, axis) in self.machine.axes().iter().enumerate() {
                let v = x.get(axis.letter) + dq[i];
                x.set(axis.letter, v);
                let scale = match axis.kind {
                    AxisKind::Linear => 1.0,
                    AxisKind::Rotary => self.lever_mm_per_deg,
                };
                step_mm = Real::max(step_mm, (dq[i] * scale).abs());
                let c = v - q.get(axis.letter);
                if !c.is_finite() {
                    break;
                }
                if c.abs() > self.max_correction {
                    return Err(CorrectError::Unreachable {
                        line,
                        axis: axis.letter.as_char(),
                        correction: c,
                        limit: self.max_correction,
                    });
                }
            }
            if !step_mm.is_finite() {
                break;
            }
            if step_mm < NEWTON_STEP_MM {
                let (rms, max) = self.residual(q, &x);
                return Ok(PoseFit {
                    q: x,
                    iterations: it,
                    residual_rms_mm: rms,
                    residual_max_mm: max,
                });
            }
        }
        Err(CorrectError::NotConverged {
            line,
            iterations: MAX_NEWTON,
            step_mm,
        })
    }
}

// ---------------------------------------------------------------------------------------
// Moves as paths

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
fn emitted_kind(kind: MoveKind) -> MoveKind {
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
fn taken_up(machine: &Chain, from: &AxisValues, old: &[Real; 6], new: &[Real; 6]) -> AxisValues {
    let mut q = *from;
    for axis in machine.axes() {
        let k = axis.letter.index();
        if old[k] != new[k] {
            q.set(axis.letter, from.get(axis.letter) + old[k] - new[k]);
        }
    }
    q
}

fn lerp(a: &AxisValues, b: &AxisValues, s: Real) -> AxisValues {
    let (a, b) = (a.to_array(), b.to_array());
    AxisValues::from_array(std::array::from_fn(|k| a[k] + (b[k] - a[k]) * s))
}

// ---------------------------------------------------------------------------------------
// The program

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
    /// Source line of the largest residual (0 if none).
    pub residual_line: usize,
    /// Largest checked subdivision error (mm).
    pub subdivision_error_mm: Real,
    /// Largest correction of a linear axis (mm).
    pub max_linear_correction_mm: Real,
    /// Largest correction of a rotary axis (degrees).
    pub max_rotary_correction_deg: Real,
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

fn format_axis(letter: AxisLetter, v: Real) -> String {
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

fn printed(axes: &[AxisLetter], q: &AxisValues) -> AxisValues {
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
            });
            per_move.push(MoveCorrection {
                line: mv.line,
                sub_moves: 1,
                residual_rms_mm: fit.residual_rms_mm,
                residual_max_mm: fit.residual_max_mm,
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
            // The chord error falls as 1/n²: jump close to the n needed, at least double.
            let grow = (worst / opts.path_tolerance_mm).sqrt() * 1.2;
            let next = ((n as Real) * grow.max(2.0)).ceil();
            if next > MAX_SUBMOVES as Real {
                return Err(CorrectError::TooManySubmoves {
                    line: mv.line,
                    tolerance_mm: opts.path_tolerance_mm,
                    limit: MAX_SUBMOVES,
                });
            }
            n = next as usize;
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
            subdivision_error_mm: worst,
        });
        prev = *points.last().unwrap_or(&prev);
    }
    summary.blocks = blocks.len();
    let mut moves = Vec::with_capacity(blocks.len());
    let mut at = *start;
    for b in &blocks {
        if b.end != at {
            moves.push(Move {
                kind: b.kind,
                start: at,
                end: b.end,
                feed_mm_per_min: b.feed_mm_per_min,
                line: b.line,
            });
        }
        at = b.end;
    }
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

/// Makes a comment safe for RS274/NGC: no parentheses or line breaks inside.
fn comment(text: &str) -> String {
    text.chars()
        .map(|c| match c {
            '(' | '[' => '<',
            ')' | ']' => '>',
            '\n' | '\r' | ';' => ' ',
            c => c,
        })
        .collect()
}

fn format_feed(f: Real) -> String {
    let s = format!("{f:.6}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    s.to_string()
}

/// Writes the corrected program as RS274/NGC, block by block: a `%` line, the `header`
/// lines as comments, `G21 G90 G94`, one `G0`/`G1` per block with every axis of the machine
/// (linear axes to 1 nm, rotary to 1e-7°) and the feed on every `G1`, a comment naming the
/// source line (and the part, for subdivided moves), `M30` if the source ended so, `%`.
pub fn write_gcode(
    program: &CorrectedProgram,
    header: &[String],
    out: &mut dyn Write,
) -> std::io::Result<()> {
    writeln!(out, "%")?;
    for h in header {
        writeln!(out, "({})", comment(h))?;
    }
    writeln!(out, "G21 G90 G94")?;
    let mut line = String::new();
    for b in &program.blocks {
        line.clear();
        // Blocks are straight (see `emitted_kind`): G0 or G1.
        let rapid = matches!(b.kind, MoveKind::Rapid);
        line.push_str(if rapid { "G0" } else { "G1" });
        for &l in &program.axes {
            line.push(' ');
            line.push(l.as_char());
            line.push_str(&format_axis(l, b.end.get(l)));
        }
        if let (false, Some(f)) = (rapid, b.feed_mm_per_min) {
            line.push_str(" F");
            line.push_str(&format_feed(f));
        }
        match (b.source, b.part) {
            (None, _) => line.push_str(" (corrected start position)"),
            (Some(_), (1, 1)) => line.push_str(&format!(" (src line {})", b.line)),
            (Some(_), (k, n)) => line.push_str(&format!(" (src line {}, {k}/{n})", b.line)),
        }
        writeln!(out, "{line}")?;
    }
    if program.ended {
        writeln!(out, "M30")?;
    }
    writeln!(out, "%")?;
    Ok(())
}

// ---------------------------------------------------------------------------------------
// Verification

/// The tool path of a corrected program on a machine against the nominal path.
#[derive(Clone, Copy, Debug, PartialEq, Default, serde::Serialize)]
pub struct PathError {
    /// Largest distance of a deviated tool-axis point (tip or flute end) from its nominal
    /// place, over every sample (mm).
    pub max_mm: Real,
    /// RMS of those distances (mm).
    pub rms_mm: Real,
    /// Samples taken (points in time; two tool points each).
    pub samples: usize,
    /// Source line of the largest distance (0 if none).
    pub worst_line: usize,
}

/// Samples every block of `corrected` on `machine` at its ends and [`PATH_SAMPLES`] inner
/// points, and compares the tool axis (tip and flute end) with the nominal chain's at the
/// same parameter of the source move of `program`. The positioning block to the corrected
/// start has no nominal path and is skipped.
pub fn path_error(
    machine: &Chain,
    tool: &Tool,
    program: &Program,
    corrected: &CorrectedProgram,
) -> PathError {
    let nominal = machine.nominal();
    let flute = FlutePoints::of(tool);
    let mut out = PathError::default();
    let mut sum = 0.0;
    let mut at = corrected.start;
    let mut dirs = Directions::default();
    for b in &corrected.blocks {
        let old = machine.reversal_state(&dirs);
        dirs = dirs.after_move(&at, &b.end);
        let state = machine.reversal_state(&dirs);
        let from = taken_up(machine, &at, &old, &state);
        at = b.end;
        let Some(src) = b.source.and_then(|i| program.moves.get(i)) else {
            continue;
        };
        for i in 0..=PATH_SAMPLES + 1 {
            let t = i as Real / (PATH_SAMPLES + 1) as Real;
            let s = b.s.0 + (b.s.1 - b.s.0) * t;
            let dev = machine.w_from_t_state(&lerp(&from, &b.end, t), &state);
            let nom = nominal.w_from_t(&path_point(src, s));
            for h in flute.ends {
                let d = (dev * axis_point(h) - nom * axis_point(h)).norm();
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
    out
}

/// The error of one milled face.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct FaceError {
    /// Face name.
    pub name: String,
    /// Source line of its cut.
    pub line: usize,
    /// Dexel crossings on it.
    pub crossings: usize,
    /// Largest distance of a crossing from the nominal plane (mm).
    pub max_abs_mm: Real,
    /// RMS distance (mm).
    pub rms_mm: Real,
    /// Mean signed distance (mm), positive into the material (material left).
    pub mean_mm: Real,
    /// Angle between the plane fitted to the crossings and the nominal plane (rad).
    pub tilt_rad: Real,
}

/// The milled faces of a part against the nominal ones.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct FaceCheck {
    /// Per face.
    pub faces: Vec<FaceError>,
    /// For two faces: the step between their fitted planes (mm), measured like the
    /// identification does, minus the nominal step.
    pub step_mm: Option<Real>,
}

impl FaceCheck {
    /// The largest distance of any crossing from its nominal face (mm); `None` when no face
    /// was measured (the scene names none).
    pub fn max_abs_mm(&self) -> Option<Real> {
        self.faces.iter().map(|f| f.max_abs_mm).reduce(Real::max)
    }
}

/// Measures the faces `specs` of a swept `stock` (cut by moves whose lines are the source
/// lines of `moves`) against the nominal flank planes of their cuts: every dexel crossing
/// made by the face's line, inside the face's region (the cut's extent along the path and
/// the tool axis, clipped to the stock, shrunk by the margin, within the band of the plane),
/// with its material normal along the face's.
pub fn face_errors(
    stock: &TriDexel,
    nominal: &Chain,
    tool: &Tool,
    moves: &[Move],
    specs: &[FaceSpec],
    stock_box: &Aabb,
    opts: &FaceOptions,
) -> Result<FaceCheck, CorrectError> {
    let mut faces = Vec::new();
    let mut planes = Vec::new();
    for spec in specs {
        let err = |message: String| CorrectError::Face {
            face: spec.name.clone(),
            message,
        };
        let mv = moves
            .iter()
            .find(|m| m.line == spec.line)
            .ok_or_else(|| err(format!("no move on line {}", spec.line)))?;
        let fl = flank(nominal, tool, mv, stock_box)
            .ok_or_else(|| err("the cut has no flank (no travel across the tool)".into()))?;
        let (su, sv) = (
            extent(stock_box, &fl.tip, &fl.u),
            extent(stock_box, &fl.tip, &fl.v),
        );
        let m = opts.margin_mm;
        let h0 = tool
            .flank_start()
            .ok_or_else(|| err("the tool has no cylindrical flank to cut a planar face".into()))?;
        let (u0, u1) = (su.0.max(0.0) + m, su.1.min(fl.length) - m);
        let (v0, v1) = (sv.0.max(h0) + m, sv.1.min(tool.length()) - m);
        let n = fl.plane.normal.into_inner();
        let mut pts = Vec::new();
        for g in stock.grids() {
            g.for_each_crossing(|p, c| {
                if c.line as usize != spec.line || c.normal().dot(&n) > -FACE_NORMAL_COS {
                    return;
                }
                let w = p - fl.tip;
                let (u, v) = (fl.u.dot(&w), fl.v.dot(&w));
                if u >= u0
                    && u <= u1
                    && v >= v0
                    && v <= v1
                    && fl.plane.signed_distance(&p).abs() <= opts.band_mm
                {
                    pts.push(p);
                }
            });
        }
        let fit = fit_plane(&pts)
            .map_err(|e| err(format!("{e} ({} crossings in the region)", pts.len())))?;
        let fitted = fit.plane.oriented_towards(&n);
        let d: Vec<Real> = pts.iter().map(|p| fl.plane.signed_distance(p)).collect();
        let k = d.len().max(1) as Real;
        faces.push(FaceError {
            name: spec.name.clone(),
            line: spec.line,
            crossings: d.len(),
            max_abs_mm: d.iter().map(|x| x.abs()).fold(0.0, Real::max),
            rms_mm: (d.iter().map(|x| x * x).sum::<Real>() / k).sqrt(),
            mean_mm: d.iter().sum::<Real>() / k,
            tilt_rad: fitted.normal.angle(&fl.plane.normal),
        });
        planes.push((fl, fitted, fit.centroid));
    }
    let step_mm = match &planes[..] {
        [(f0, p0, c0), (f1, p1, c1)] => {
            let frame = StepFrame {
                at: Point3::from((c0.coords + c1.coords) / 2.0),
                n: f0.plane.normal,
                u: f0.u,
            };
            let nominal_step = frame.measure(&f0.plane, &f1.plane).map(|m| m.0);
            let step = frame.measure(p0, p1).map(|m| m.0);
            step.zip(nominal_step).map(|(s, n)| s - n)
        }
        _ => None,
    };
    Ok(FaceCheck { faces, step_mm })
}

/// A machined part against the nominal part, ray by ray over the three dexel grids: the
/// distance between each cut surface and the same surface of the nominal part (the surface
/// the same NC line made).
#[derive(Clone, Copy, Debug, PartialEq, Default, serde::Serialize)]
pub struct PartError {
    /// Crossings compared (made by the same cut in both parts, seen at most 60° off the
    /// ray).
    pub crossings: usize,
    /// Largest distance between corresponding crossings, along the surface normal (mm).
    pub max_mm: Real,
    /// RMS of those distances (mm).
    pub rms_mm: Real,
    /// Where the largest distance is (workpiece frame, mm).
    pub worst_at: [Real; 3],
    /// Rays whose material intervals differ in number or in the orientation of their ends
    /// (a surface edge moved across the ray): not compared.
    pub unmatched_rays: usize,
    /// Corresponding crossings made by different NC lines in the two parts (or by a cut in
    /// one and the stock in the other): an edge between two surfaces moved across the ray,
    /// so the ray meets one surface in one part and another in the other — their distance
    /// along the ray is the height of the edge, not a surface error. Not compared.
    pub other_surface_crossings: usize,
}

/// A crossing is compared on a grid whose rays meet its surface at most 60° off the normal
/// (|n·e| ≥ 0.5); every surface has a normal component ≥ 1/√3 on some axis, so each is
/// compared on at least one grid, never at grazing incidence.
const PART_RAY_COS: Real = 0.5;

/// Compares every cut surface of `part` with `nominal` (the same stock box and pitch): on
/// each ray, corresponding crossings' distance along the ray times the cosine between ray
/// and normal — the distance between the surfaces there, to first order — where both
/// crossings lie on the same surface: made by the same NC line (a corrected program's
/// blocks carry their source line). Where an edge between two surfaces has moved across a
/// ray (a floor's edge at a step: the ray meets the upper floor in one part, the lower in
/// the other), the crossings are of different lines and are counted, not compared.
pub fn part_error(part: &TriDexel, nominal: &TriDexel) -> PartError {
    let mut out = PartError::default();
    let mut sum = 0.0;
    for (g, h) in part.grids().iter().zip(nominal.grids()) {
        let (nu, nv) = g.dims();
        if h.dims() != (nu, nv) {
            continue;
        }
        let axis = g.axis();
        for iv in 0..nv {
            for iu in 0..nu {
                let (a, b) = (g.ray(iu, iv), h.ray(iu, iv));
                let cut = |segs: &[crate::cutting::stock::Segment]| {
                    segs.iter().any(|s| s.lo.line != 0 || s.hi.line != 0)
                };
                if !cut(a) && !cut(b) {
                    continue;
                }
                let pairs = || {
                    a.iter()
                        .zip(b)
                        .flat_map(|(x, y)| [(&x.lo, &y.lo), (&x.hi, &y.hi)])
                };
                if a.len() != b.len()
                    || pairs().any(|(x, y)| x.normal().dot(&y.normal()) < FACE_NORMAL_COS)
                {
                    out.unmatched_rays += 1;
                    continue;
                }
                for (x, y) in pairs() {
                    let n = y.normal();
                    if (x.line == 0 && y.line == 0) || n[axis].abs() < PART_RAY_COS {
                        continue;
                    }
                    if x.line != y.line {
                        out.other_surface_crossings += 1;
                        continue;
                    }
                    let d = (x.t - y.t).abs() * n[axis].abs();
                    out.crossings += 1;
                    sum += d * d;
                    if d > out.max_mm {
                        out.max_mm = d;
                        let mut p = g.ray_origin(iu, iv);
                        p[axis] = y.t;
                        out.worst_at = [p.x, p.y, p.z];
                    }
                }
            }
        }
    }
    out.rms_mm = if out.crossings > 0 {
        (sum / out.crossings as Real).sqrt()
    } else {
        0.0
    };
    out
}

/// The nominal flank plane of a straight cut (for tests and reports).
pub fn nominal_face(nominal: &Chain, tool: &Tool, mv: &Move, stock_box: &Aabb) -> Option<Plane> {
    flank(nominal, tool, mv, stock_box).map(|f| f.plane)
}

/// The tool axis direction error (rad) of a corrected pose: the angle between the deviated
/// and the nominal tool axes.
pub fn axis_angle_error(machine: &Chain, commanded: &AxisValues, corrected: &AxisValues) -> Real {
    let z = Vector3::z();
    let a = machine.w_from_t(corrected).rotation * z;
    let b = machine.nominal().w_from_t(commanded).rotation * z;
    a.angle(&b)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cutting::tool::ToolKind;
    use crate::machine::chain::Axis;
    use crate::math::{CounterRng, UnitVector3};

    fn mdx50() -> Chain {
        crate::machine::chain::mdx50_for_tests()
    }

    fn tool() -> Tool {
        Tool::try_new(ToolKind::Flat, 6.0, 25.0).expect("valid")
    }

    /// Random deviations of every joint: offsets ±`off` mm, angles ±`ang` rad.
    fn deviated(seed: u64, off: Real, ang: Real) -> Chain {
        let mut c = mdx50();
        let rng = CounterRng::new(seed);
        let names = c.deviation_names();
        for (i, name) in names.iter().enumerate() {
            let id = c.deviation_id(name).expect("known");
            let u = rng.uniform(i as u64, 0) * 2.0 - 1.0;
            let v = if id.component.is_angle() {
                u * ang
            } else {
                u * off
            };
            c.set_deviation(id, v);
        }
        c
    }

    fn pose(x: Real, y: Real, z: Real, a: Real) -> AxisValues {
        AxisValues::default()
            .with(AxisLetter::X, x)
            .with(AxisLetter::Y, y)
            .with(AxisLetter::Z, z)
            .with(AxisLetter::A, a)
    }

    const FREE: [bool; 6] = [true, true, true, true, false, false];

    #[test]
    fn nominal_chain_returns_the_commanded_pose() {
        let c = mdx50();
        let s = PoseSolver::new(&c, &tool(), 10.0);
        for q in [
            pose(1.0, 2.0, 3.0, 0.0),
            pose(-12.0, 25.0, 7.0, 180.0),
            pose(3.0, -4.0, 50.0, 37.5),
        ] {
            let fit = s.solve(&q, &q, &FREE, 1).expect("solves");
            assert_eq!(fit.q, q, "a nominal chain needs no correction");
            assert!(fit.residual_rms_mm < 1e-12);
        }
    }

    #[test]
    fn jacobian_matches_central_differences() {
        let c = deviated(5, 0.5, 5e-4);
        let s = PoseSolver::new(&c, &tool(), 10.0);
        for q in [
            pose(1.0, 2.0, 3.0, 10.0),
            pose(-12.0, 25.0, 7.0, 180.0),
            pose(3.0, -4.0, 50.0, -37.5),
        ] {
            let (_, j) = s.jacobian(&q);
            for (i, axis) in c.axes().iter().enumerate() {
                // Steps 1e-4 (mm or °): truncation O(h²·curvature) ~1e-9, rounding ~1e-12.
                let h = 1e-4;
                let plus = q.with(axis.letter, q.get(axis.letter) + h);
                let minus = q.with(axis.letter, q.get(axis.letter) - h);
                let pts = |q: &AxisValues| s.jacobian(q).0;
                let (a, b) = (pts(&plus), pts(&minus));
                for k in 0..2 {
                    let fd = (a[k] - b[k]) / (2.0 * h);
                    let an = j.fixed_view::<3, 1>(3 * k, i).into_owned();
                    assert!((fd - an).norm() < 1e-8, "axis {i} point {k}: {fd} vs {an}");
                }
            }
        }
    }

    #[test]
    fn random_deviations_converge_to_the_least_squares_pose() {
        for seed in 0..40 {
            let c = deviated(seed, 0.5, 5e-4);
            let s = PoseSolver::new(&c, &tool(), 10.0);
            let rng = CounterRng::new(1000 + seed);
            let q = pose(
                rng.uniform(0, 0) * 100.0 - 50.0,
                rng.uniform(1, 0) * 100.0 - 50.0,
                rng.uniform(2, 0) * 60.0,
                rng.uniform(3, 0) * 360.0 - 180.0,
            );
            let fit = s.solve(&q, &q, &FREE, 1).expect("converges");
            assert!(fit.iterations <= 6, "{} iterations", fit.iterations);
            // The deviated tool axis's X component v_x depends on the deviations only (the
            // A axis turns about X, the linear axes do not turn): the best pose turns the
            // rest onto the nominal axis, leaving the angle asin|v_x| between them, and
            // places the axis through the nominal one mid-flute. Over [0, L] the distance
            // is then |h − L/2|·2·sin(θ/2): RMS 2·sin(θ/2)·L/√12.
            let vx = (c.w_from_t(&q).rotation * Vector3::z()).x;
            let theta = vx.abs().asin();
            let expect = 2.0 * (theta / 2.0).sin() * 25.0 / 12.0_f64.sqrt();
            assert!(
                (fit.residual_rms_mm - expect).abs() < 1e-9,
                "seed {seed}: residual {} vs {expect}",
                fit.residual_rms_mm
            );
            let angle = axis_angle_error(&c, &q, &fit.q);
            assert!(
                (angle - theta).abs() < 1e-9,
                "seed {seed}: {angle} vs {theta}"
            );
            // To first order v_x is the sum of the beta deviations.
            let beta: Real = ["beta_AY", "beta_YX", "beta_XZ", "beta_ZS"]
                .iter()
                .map(|n| c.deviation(c.deviation_id(n).expect("known")))
                .sum();
            assert!((vx - beta).abs() < 1e-6, "seed {seed}: {vx} vs {beta}");
        }
    }

    #[test]
    fn straight_move_at_fixed_rotary_is_a_straight_deviated_path() {
        // The claim of the module docs, checked on a chain with every deviation set.
        let c = deviated(9, 0.5, 5e-4);
        let (a, b) = (pose(-30.0, -25.0, 3.0, 37.0), pose(30.0, 12.0, -4.0, 37.0));
        let (pa, pb) = (c.w_from_t(&a), c.w_from_t(&b));
        for i in 0..=10 {
            let t = i as Real / 10.0;
            let p = c.w_from_t(&lerp(&a, &b, t));
            let line = pa.translation.vector.lerp(&pb.translation.vector, t);
            assert!((p.translation.vector - line).norm() < 1e-12);
            assert!(p.rotation.angle_to(&pa.rotation) < 1e-15);
        }
    }

    /// X, Y, Z, then a B head pivoting 150 mm above the tool tip: deviations before the
    /// rotary axis make the correction depend on B, so B moves need sub-moves.
    fn head_machine() -> Chain {
        let ax = |letter, kind, d: Vector3, o: Point3| Axis {
            letter,
            kind,
            direction: UnitVector3::new_normalize(d),
            origin: o,
        };
        let mut c = Chain::new(
            vec![
                ax(
                    AxisLetter::X,
                    AxisKind::Linear,
                    Vector3::x(),
                    Point3::origin(),
                ),
                ax(
                    AxisLetter::Y,
                    AxisKind::Linear,
                    Vector3::y(),
                    Point3::origin(),
                ),
                ax(
                    AxisLetter::Z,
                    AxisKind::Linear,
                    Vector3::z(),
                    Point3::origin(),
                ),
                ax(
                    AxisLetter::B,
                    AxisKind::Rotary,
                    Vector3::y(),
                    Point3::new(0.0, 0.0, 150.0),
                ),
            ],
            "S",
        )
        .expect("valid chain");
        for (n, v) in [
            ("dx_XY", 0.3),
            ("gamma_XY", 5e-4),
            ("dy_YZ", -0.2),
            ("alpha_YZ", -4e-4),
            ("beta_ZB", 3e-4),
            ("dz_BS", 0.1),
        ] {
            c.set_deviation(c.deviation_id(n).expect("known"), v);
        }
        c
    }

    #[test]
    fn rotary_moves_are_subdivided_until_the_path_is_within_tolerance() {
        let c = head_machine();
        let tool = tool();
        let start = AxisValues::default().with(AxisLetter::Z, 10.0);
        let turn = start.with(AxisLetter::B, 90.0).with(AxisLetter::X, 40.0);
        let straight = turn.with(AxisLetter::Y, 30.0);
        let mv = |line, a: AxisValues, b: AxisValues| Move {
            kind: MoveKind::Linear,
            start: a,
            end: b,
            feed_mm_per_min: Some(500.0),
            line,
        };
        let program = Program {
            path: "head.ngc".into(),
            moves: vec![mv(1, start, turn), mv(2, turn, straight)],
            axes_used: vec![AxisLetter::X, AxisLetter::Y, AxisLetter::Z, AxisLetter::B],
            ended_by: Some(3),
        };
        let opts = CorrectOptions::for_accuracy(1e-3);
        let cp = correct_program(&c, &tool, &program, &start, &opts).expect("corrects");
        let turn_fix = &cp.per_move[0];
        assert!(turn_fix.sub_moves > 4, "{turn_fix:?}");
        assert!(turn_fix.subdivision_error_mm <= opts.path_tolerance_mm);
        // B turns the tool about its own, deviated direction w (Y through the rotations of
        // the joints before it): the tool axis reaches only directions perpendicular to w,
        // so a nominal axis v leaves the angle asin|v·w|, at the flute's ends
        // 2·sin(θ/2)·L/2 away. On the second move v = RotY(90°)·z = x.
        let rot: Vec<_> = c.deviations()[..3]
            .iter()
            .map(|d| d.transform().rotation)
            .collect();
        let w = rot[0] * rot[1] * rot[2] * Vector3::y();
        let theta = w.x.abs().asin();
        let expect_max = 2.0 * (theta / 2.0).sin() * 25.0 / 2.0;
        let got = cp.per_move[1].residual_max_mm;
        assert!(
            (got - expect_max).abs() < 1e-6 * expect_max,
            "{got} vs {expect_max}"
        );
        // Densely sampled on the machine, the path is within tolerance beyond that residual.
        let path = path_error(&c, &tool, &program, &cp);
        assert!(path.samples > 9 * turn_fix.sub_moves);
        assert!(
            path.max_mm <= cp.summary.residual_max_mm + opts.path_tolerance_mm,
            "{path:?} vs residual {}",
            cp.summary.residual_max_mm
        );
        // Without subdivision the chord strays much further: the check is not vacuous.
        let coarse = CorrectOptions {
            path_tolerance_mm: 1.0,
            ..opts
        };
        let one = correct_program(&c, &tool, &program, &start, &coarse).expect("corrects");
        assert_eq!(one.per_move[0].sub_moves, 1);
        let path1 = path_error(&c, &tool, &program, &one);
        assert!(path1.max_mm > cp.summary.residual_max_mm + 10.0 * opts.path_tolerance_mm);
        // The straight move at fixed B stays one block with B exactly unchanged.
        let last = cp.blocks.last().expect("blocks");
        let before = cp.blocks[cp.blocks.len() - 2];
        assert_eq!(last.part, (1, 1));
        assert_eq!(last.end.get(AxisLetter::B), before.end.get(AxisLetter::B));
        // Emitted: parts named, feed kept on every sub-move.
        let mut text = Vec::new();
        write_gcode(&cp, &["head test".into()], &mut text).expect("writes");
        let text = String::from_utf8(text).expect("utf-8");
        let n = turn_fix.sub_moves;
        assert!(text.contains(&format!("(src line 1, {n}/{n})")), "{text}");
        assert_eq!(text.matches("F500").count(), n + 1);
        assert!(text.contains("G21 G90 G94") && text.trim_end().ends_with("M30\n%"));
    }

    #[test]
    fn unreachable_and_non_finite_are_errors() {
        let c = deviated(3, 0.5, 5e-4);
        let s = PoseSolver::new(&c, &tool(), 1e-3);
        let q = pose(1.0, 2.0, 3.0, 0.0);
        assert!(matches!(
            s.solve(&q, &q, &FREE, 7),
            Err(CorrectError::Unreachable { line: 7, .. })
        ));
        let s = PoseSolver::new(&c, &tool(), 10.0);
        let bad = q.with(AxisLetter::Y, Real::NAN);
        assert!(matches!(
            s.solve(&bad, &q, &FREE, 8),
            Err(CorrectError::NonFinite { line: 8, axis: 'Y' })
        ));
    }

    #[test]
    fn printed_values_read_back_exactly() {
        for v in [0.1, -0.0000001, 25.5000004, -1234.56789012] {
            let p = as_printed(AxisLetter::X, v);
            assert_eq!(format_axis(AxisLetter::X, p), format_axis(AxisLetter::X, v));
            assert!((p - v).abs() <= 0.5e-6);
        }
        assert_eq!(format_axis(AxisLetter::Y, -1e-9), "0.000000");
    }
}
