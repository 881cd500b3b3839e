//! Sub-steps of moves the sweep cannot cut as one translation: the bound `ε(N) = a/N + b/N²`
//! of a move that turns a rotary axis ([`RotaryBound`], error motions included) or of a
//! move read pose by pose ([`SampledBound`]), the poses along a move, and the sub-steps
//! themselves in [`COARSE`] groups.
//!
//! **Invariant:** bounds, poses and translations only; never touches the stock.

use super::*;
pub use crate::cutting::envelope::SAMPLED_BOUND_FACTOR;

/// The sub-step bound of a move read pose by pose, from its pilot samples `P_j` at
/// `λ = j/M`: with the tool's mid-height point `c` and orientation `R`, the largest angular
/// speed `Ω = max_j angle(R_j, R_{j+1})·M` (rad per unit λ) and curvature
/// `C = max_j |c_{j−1} − 2c_j + c_{j+1}|·M²` (mm per unit λ²) give the bound of sub-steps as
/// for rotary moves: a sub-step of width `h` held at its mid orientation, `c` moving
/// straight, is off the true motion by at most `ρ_tool·Ω·h/2 + C·h²/8`, so
/// `ε(N) = a/N + b/N²` with `a = F·Ω·ρ_tool/2`, `b = F·C/8` and the safety factor
/// `F` = [`SAMPLED_BOUND_FACTOR`] on rates estimated from samples.
pub struct SampledBound;

impl SampledBound {
    /// The bound of `tool` moved through the pilot poses `pilot` (at least three, evenly
    /// spaced in λ from 0 to 1).
    pub fn of(tool: &Tool, pilot: &[Isometry3]) -> RotaryBound {
        let m = (pilot.len() - 1) as Real;
        let mid = mid_point(tool);
        let c: Vec<Point3> = pilot.iter().map(|p| p * mid).collect();
        let omega = pilot
            .windows(2)
            .map(|w| w[0].rotation.angle_to(&w[1].rotation) * m)
            .fold(0.0, Real::max);
        let curvature = c
            .windows(3)
            .map(|w| (w[0].coords - 2.0 * w[1].coords + w[2].coords).norm() * m * m)
            .fold(0.0, Real::max);
        let rho = tool.reach_from(tool.length() / 2.0);
        RotaryBound {
            a: SAMPLED_BOUND_FACTOR * omega * rho / 2.0,
            b: SAMPLED_BOUND_FACTOR * curvature / 8.0,
        }
    }
}

/// Largest number of sub-steps for one rotary move.
const MAX_SUBSTEPS: Real = 5e7;
/// Sub-steps per coarse interval used to skip parts of a rotary move far from the stock.
pub(super) const COARSE: usize = 64;

/// The error bound of a rotary move's sub-steps: `ε(N) = a/N + b/N²` (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RotaryBound {
    /// First-order coefficient (mm): orientation held fixed over a sub-step.
    pub a: Real,
    /// Second-order coefficient (mm): chord error of the mid point's path.
    pub b: Real,
}

impl RotaryBound {
    /// The bound for a move on `chain` with `tool`, moving axes settled in their direction
    /// of motion.
    pub fn of(chain: &Chain, tool: &Tool, mv: &Move) -> Self {
        let state = chain.reversal_state(&Directions::default().after_move(&mv.start, &mv.end));
        Self::of_state(chain, tool, mv, &state)
    }

    /// The bound for a move on `chain` with `tool` from the reversal shares `state`. With
    /// error motions it adds `a_e/N + b_e/N²` (see docs/cutting.md#sweep-bounds):
    /// `a_e = E + ρ_tool·ω'/2` and `b_e = ((v + ω·ρ_axis)·ω' + ω·E)/2`, `E` the speed the
    /// error motions add to the mid point and `ω'` the rotation they turn
    /// ([`error_motion_speed`]).
    pub fn of_state(chain: &Chain, tool: &Tool, mv: &Move, state: &[Real; 6]) -> Self {
        let plain = Self::plain(chain, tool, mv);
        if !chain.has_error_motions() {
            return plain;
        }
        let (omega, v) = rotation_and_travel(chain, &mv.start, &mv.end);
        let reach = tool.reach_from(tool.length() / 2.0);
        let (e, turn) = error_motion_speed(chain, &mid_point(tool), 0.0, &mv.start, &mv.end, state);
        // ρ_axis from the plain bound's second term: b = (ω²ρ + 2ωv)/8.
        let rho_axis = if omega > 0.0 {
            ((8.0 * plain.b - 2.0 * omega * v) / (omega * omega)).max(0.0)
        } else {
            0.0
        };
        Self {
            a: plain.a + e + reach * turn / 2.0,
            b: plain.b + ((v + omega * rho_axis) * turn + omega * e) / 2.0,
        }
    }

    fn plain(chain: &Chain, tool: &Tool, mv: &Move) -> Self {
        let (omega, v) = rotation_and_travel(chain, &mv.start, &mv.end);
        let rotaries = chain
            .axes()
            .iter()
            .filter(|a| a.kind == AxisKind::Rotary)
            .count();
        let mids =
            [chain.w_from_t(&mv.start), chain.w_from_t(&mv.end)].map(|p| p * mid_point(tool));
        let mut rho = 0.0;
        for (q, c) in [&mv.start, &mv.end].iter().zip(&mids) {
            for (axis_point, _) in chain.rotary_lines_in_w(q) {
                rho = Real::max(rho, (c - axis_point).norm());
            }
        }
        if rotaries > 1 {
            // Several rotaries: distances may grow mid-move by at most the path length.
            rho = (rho + v) * (1.0 + omega);
        }
        Self {
            a: omega * tool.reach_from(tool.length() / 2.0) / 2.0,
            b: (omega * omega * rho + 2.0 * omega * v) / 8.0,
        }
    }

    /// The bound at `n` sub-steps (mm).
    pub fn at(&self, n: usize) -> Real {
        let n = n as Real;
        self.a / n + self.b / (n * n)
    }

    /// The smallest multiple of `COARSE` sub-steps meeting `bound`, if not absurd.
    pub fn steps_for(&self, bound: Real, line: usize) -> Result<usize, SweepError> {
        let n = (self.a + (self.a * self.a + 4.0 * self.b * bound).sqrt()) / (2.0 * bound);
        let n = ((n.ceil() / COARSE as Real).ceil() * COARSE as Real).max(COARSE as Real);
        if n.is_nan() || n > MAX_SUBSTEPS {
            return Err(SweepError::TooManySubsteps {
                line,
                bound_mm: bound,
                steps: n,
            });
        }
        Ok(n as usize)
    }
}

/// The tool's mid-height point on its axis, tool frame: the point whose path rotary
/// sub-steps interpolate.
fn mid_point(tool: &Tool) -> Point3 {
    Point3::new(0.0, 0.0, tool.length() / 2.0)
}

pub(super) fn pose_at(chain: &Chain, mv: &Move, lambda: Real) -> Isometry3 {
    let mut q = mv.start;
    for axis in chain.axes() {
        let (a, b) = (mv.start.get(axis.letter), mv.end.get(axis.letter));
        q.set(axis.letter, a + (b - a) * lambda);
    }
    chain.w_from_t(&q)
}

/// The poses along a move: the chain's at interpolated axis values, or, with error
/// motions, the exact [`MovePath`] from the reversal shares the move starts with.
pub(super) enum Poses<'a> {
    Plain(&'a Chain, &'a Move),
    Path(MovePath),
}

impl<'a> Poses<'a> {
    /// The poses of `mv` on `chain` from the reversal shares `state`.
    pub(super) fn of(chain: &'a Chain, mv: &'a Move, state: &[Real; 6]) -> Self {
        if chain.has_error_motions() {
            Poses::Path(MovePath::with_state(chain, &mv.start, &mv.end, state))
        } else {
            Poses::Plain(chain, mv)
        }
    }

    pub(super) fn at(&self, lambda: Real) -> Isometry3 {
        match self {
            Poses::Plain(chain, mv) => pose_at(chain, mv, lambda),
            Poses::Path(p) => p.w_from_t(lambda),
        }
    }
}
/// The sub-steps of a move that turns a rotary axis: `n` translations (`n` a multiple of
/// 64, see [`RotaryBound::steps_for`]), in each of which the tool's mid-height point moves
/// straight between its true positions at the sub-step's ends, the tool held at the
/// mid-step orientation (the error bound of [`RotaryBound`]). The sub-steps come in 64
/// groups; `keep_group` sees each group as one coarse translation (tip, travel, rotation)
/// and skips the whole group when it says no; `each` gets every sub-step of a kept group
/// as (tip, travel, rotation), in order.
pub fn rotary_substeps<E>(
    chain: &Chain,
    tool: &Tool,
    mv: &Move,
    state: &[Real; 6],
    n: usize,
    keep_group: impl FnMut(Point3, Vector3, Rotation3) -> bool,
    each: impl FnMut(Point3, Vector3, Rotation3) -> Result<(), E>,
) -> Result<(), E> {
    let poses = Poses::of(chain, mv, state);
    substeps(tool, n, |l| Ok(poses.at(l)), keep_group, each)
}

/// The sub-steps of [`rotary_substeps`] for any pose function `pose_at(λ)` (fallible: a
/// pose source may be unable to take a pose).
pub(super) fn substeps<E>(
    tool: &Tool,
    n: usize,
    pose_at: impl Fn(Real) -> Result<Isometry3, E>,
    mut keep_group: impl FnMut(Point3, Vector3, Rotation3) -> bool,
    mut each: impl FnMut(Point3, Vector3, Rotation3) -> Result<(), E>,
) -> Result<(), E> {
    let mid = mid_point(tool);
    let half = tool.length() / 2.0;
    let translation = |a: Point3, b: Point3, rotation: Rotation3| {
        let v = rotation * Vector3::z();
        (a - v * half, b - a, rotation)
    };
    let per = n / COARSE;
    for j in 0..COARSE {
        let (l0, l1) = (j as Real / COARSE as Real, (j + 1) as Real / COARSE as Real);
        let (a0, a1) = (pose_at(l0)? * mid, pose_at(l1)? * mid);
        let (tip, d, rot) = translation(a0, a1, pose_at((l0 + l1) / 2.0)?.rotation);
        if !keep_group(tip, d, rot) {
            continue;
        }
        let mut prev = a0;
        for k in 0..per {
            let i = j * per + k;
            let (la, lb) = (i as Real / n as Real, (i + 1) as Real / n as Real);
            let next = pose_at(lb)? * mid;
            let (tip, d, rot) = translation(prev, next, pose_at((la + lb) / 2.0)?.rotation);
            each(tip, d, rot)?;
            prev = next;
        }
    }
    Ok(())
}
