//! Solving one corrected pose: Gauss–Newton on the flute points of the deviated chain.

use super::*;
use crate::cutting::tool::Tool;
use crate::machine::chain::{AxisKind, Chain};
use crate::machine::error_motion::{self, Direction, Directions};
use crate::math::{Isometry3, Point3, Real};
use crate::nc::AxisValues;
use nalgebra::{SMatrix, SVector};

pub(super) type Jacobian = SMatrix<Real, 6, 6>;
/// The six flute coordinates and one damping row per axis.
type Residual = SVector<Real, 12>;
type Augmented = SMatrix<Real, 12, 6>;

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
    /// Angle between the deviated and the nominal tool axes (rad): the orientation error
    /// the correction leaves.
    pub axis_angle_rad: Real,
}

/// Solves corrected poses on a deviated chain.
#[derive(Clone, Debug)]
pub struct PoseSolver<'a> {
    machine: &'a Chain,
    /// The reversal shares the machine carries at the poses solved
    /// ([`Chain::reversal_state`]); all settled in `+` until set.
    pub(super) state: [Real; 6],
    nominal: Chain,
    pub(super) flute: FlutePoints,
    max_correction: Real,
    /// Length (mm) that turns a rotary step (degrees) into mm at the flute.
    lever_mm_per_deg: Real,
    /// Weight (mm per degree) of a rotary axis's departure from its commanded value in the
    /// solve: [`ROTARY_DAMPING`] in the units of the flute residuals.
    damping_mm_per_deg: Real,
}

pub(super) fn axis_point(h: Real) -> Point3 {
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
            // |e₁|² + |e₂|² = 2·|e_mid|² + |δv|²·L²/6: a direction error δv (rad) weighs
            // L/√6 mm per rad; the damping weighs a rotary departure λ times that.
            damping_mm_per_deg: ROTARY_DAMPING * tool.length() / 6.0_f64.sqrt()
                * (1.0 as Real).to_radians(),
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

    /// The angle (rad) between the deviated tool axis at `corrected` (with the solver's
    /// reversal shares) and the nominal one at `commanded`.
    pub fn axis_angle(&self, commanded: &AxisValues, corrected: &AxisValues) -> Real {
        let z = crate::math::Vector3::z();
        let a = self.machine.w_from_t_state(corrected, &self.state).rotation * z;
        let b = self.nominal.w_from_t(commanded).rotation * z;
        a.angle(&b)
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
            // The rotary axes held towards their commanded values (see the module docs).
            let mut j = Augmented::from_fn(|row, col| if row < 6 { j[(row, col)] } else { 0.0 });
            for (i, axis) in self.machine.axes().iter().enumerate() {
                if axis.kind == AxisKind::Rotary && free[i] {
                    let w = self.damping_mm_per_deg;
                    j[(6 + i, i)] = w;
                    r[6 + i] = w * (q.get(axis.letter) - x.get(axis.letter));
                }
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
                    axis_angle_rad: self.axis_angle(q, &x),
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
