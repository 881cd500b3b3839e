//! The program driver: arcs as chords, collinear straight moves joined into runs, rotary
//! moves by the envelope or bounded sub-steps, moves of a pose source sampled, and each
//! piece shown to a [`SweepObserver`].
//!
//! **Invariant:** the one path by which a program removes material from the stock; an
//! observer only reads the stock, so the removal is bit-identical whatever the observer.

use super::*;
use crate::cutting::envelope::EnvelopeError;
use rayon::prelude::*;
/// The moves with every arc replaced by chords within `bound` (mm) of it: borrowed as they
/// are when there is no arc.
pub fn as_chords(moves: &[Move], bound: Real) -> std::borrow::Cow<'_, [Move]> {
    if moves.iter().any(|m| matches!(m.kind, MoveKind::Arc(_))) {
        std::borrow::Cow::Owned(moves.iter().flat_map(|m| m.chords(bound)).collect())
    } else {
        std::borrow::Cow::Borrowed(moves)
    }
}

/// One piece of a move as the driver cuts it, shown to a [`SweepObserver`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Piece {
    /// A pure translation of the tool: its tip moves from `tip` by `d` with the tool axis
    /// `axis` (W). A straight move at fixed rotary values, or one sub-step of a move that
    /// turns a rotary axis (see [`rotary_substeps`]), whose rotation is `rotation`.
    Translation {
        /// The tip at the start (W, mm).
        tip: Point3,
        /// The tip's travel (W, mm).
        d: Vector3,
        /// The tool's orientation (T to W); its +z is the tool axis.
        rotation: Rotation3,
    },
    /// A whole move that turns a rotary axis, or that moves an axis with error motions.
    /// `envelope`: cut at once by the exact [`RotaryEnvelope`] of the tool; else cut in
    /// sub-steps (each shown to [`SweepObserver::before_rapid`] as a
    /// [`Piece::Translation`]).
    Rotary {
        /// Whether the move was cut by the envelope.
        envelope: bool,
        /// The reversal shares the move starts from ([`Chain::reversal_state`]).
        state: [Real; 6],
    },
    /// A whole move of a machine read pose by pose ([`Kinematics::Poses`]) that is not a
    /// pure translation, cut in sub-steps (each shown to [`SweepObserver::before_rapid`] as
    /// a [`Piece::Translation`]).
    Sampled,
}

impl Piece {
    /// The tool axis of a translation (W).
    pub fn axis(rotation: &Rotation3) -> UnitVector3 {
        UnitVector3::new_normalize(rotation * Vector3::z())
    }
}

/// What the sweep driver shows of each move to code that checks it (collision checks):
/// the stock just before a rapid removes material, and just after each move's material is
/// removed. An observer only reads the stock, so the material removed is the same with any
/// observer.
pub trait SweepObserver {
    /// Before `piece` of the rapid (G0) `mv` is removed from `stock`. `k` is the move's index
    /// among the moves with arcs as chords. A rapid never joins the moves before it
    /// (see [`sweep_observed`]), so `stock` is the stock the rapid meets (for sub-steps: as
    /// the earlier sub-steps of the rapid left it). The default looks at nothing.
    fn before_rapid(
        &mut self,
        stock: &TriDexel,
        k: usize,
        mv: &Move,
        piece: &Piece,
    ) -> Result<(), SweepError> {
        let _ = (stock, k, mv, piece);
        Ok(())
    }

    /// After the material of move `k` was removed: `piece` is the move's translation for a
    /// straight move, [`Piece::Rotary`] for one that turns a rotary axis. For a run of
    /// joined moves, called for each move of the run in program order once the whole run
    /// is removed. The default looks at nothing.
    fn after_move(
        &mut self,
        stock: &TriDexel,
        k: usize,
        mv: &Move,
        piece: &Piece,
    ) -> Result<(), SweepError> {
        let _ = (stock, k, mv, piece);
        Ok(())
    }

    /// Whether the observer looks at the stock after a move. One that does not lets the
    /// driver cut consecutive envelope moves together ([`TriDexel::remove_each`], the same
    /// stock bit for bit), calling [`SweepObserver::after_move`] for them once they are all
    /// removed; the moves before a rapid are always removed before
    /// [`SweepObserver::before_rapid`] is shown the stock, so the observer is called in the
    /// same order, with the same stock before each rapid, either way. The default: it looks.
    fn looks(&self) -> bool {
        true
    }
}

/// The observer of the plain sweep: looks at nothing.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoObserver;

impl SweepObserver for NoObserver {
    fn looks(&self) -> bool {
        false
    }
}

/// Most envelope moves cut together when the observer does not look
/// ([`SweepObserver::looks`]).
const BATCH: usize = 16;

/// Consecutive envelope moves of a batch tested together by one [`GroupHull`].
const GROUP: usize = 4;

/// The groups' tests are kept while they clear at least one in this many rays they are asked
/// about; else they rest for this many batches and are tried again.
const GROUP_TRIAL: u64 = 8;

/// Envelope moves waiting to be cut together: each with its index, move and the piece it
/// is shown to the observer as.
struct Batch<'m> {
    moves: Vec<(RotaryEnvelope, usize, &'m Move, Piece)>,
    /// Batches left before the groups' tests are tried again (0: they are used).
    groups_rest: u64,
}

impl<'m> Batch<'m> {
    /// Cuts move `k` by its envelope `env`, shown to the observer as `piece`: a rapid shown
    /// to the observer first, after the waiting moves are cut; then kept to be cut with the
    /// next ones when the observer does not look after moves (the batch cut once full),
    /// else cut now after the waiting ones.
    fn cut(
        &mut self,
        env: RotaryEnvelope,
        (k, mv): (usize, &'m Move),
        piece: Piece,
        stock: &mut TriDexel,
        report: &mut SweepReport,
        observer: &mut dyn SweepObserver,
    ) -> Result<(), SweepError> {
        report.sweeps += 1;
        if mv.kind == MoveKind::Rapid {
            self.flush(stock, report, observer)?;
            observer.before_rapid(stock, k, mv, &piece)?;
        }
        if !observer.looks() {
            self.moves.push((env, k, mv, piece));
            if self.moves.len() >= BATCH {
                self.flush(stock, report, observer)?;
            }
            return Ok(());
        }
        self.flush(stock, report, observer)?;
        if stock.remove(&env, mv.line as u32) {
            report.cutting_moves += 1;
        }
        observer.after_move(stock, k, mv, &piece)
    }

    /// Cuts the waiting moves, each in turn for each ray, counting those that removed
    /// material, and shows each to the observer.
    fn flush(
        &mut self,
        stock: &mut TriDexel,
        report: &mut SweepReport,
        observer: &mut dyn SweepObserver,
    ) -> Result<(), SweepError> {
        if self.moves.is_empty() {
            return Ok(());
        }
        let cutters: Vec<(&dyn Cutter, u32)> = self
            .moves
            .iter()
            .map(|(env, _, mv, _)| (env as &dyn Cutter, mv.line as u32))
            .collect();
        // Groups of consecutive moves, each tested at once by its hull: a ray whose material
        // the hull misses skips the group's moves (the same stock; see `GroupHull`).
        let tried = self.groups_rest == 0;
        let hulls: Vec<(std::ops::Range<usize>, GroupHull)> = if tried {
            let envs: Vec<&RotaryEnvelope> = self.moves.iter().map(|(env, ..)| env).collect();
            (0..envs.len())
                .step_by(GROUP)
                .map(|a| a..(a + GROUP).min(envs.len()))
                .filter(|g| g.len() > 1)
                .map(|g| (g.clone(), GroupHull::of(&envs[g])))
                .collect()
        } else {
            Vec::new()
        };
        let groups: Vec<Group> = hulls
            .iter()
            .map(|(g, hull)| Group {
                cutters: g.clone(),
                cull: hull,
            })
            .collect();
        let removed = stock.remove_each(&cutters, &groups);
        drop((cutters, groups));
        self.groups_rest = if !tried {
            self.groups_rest - 1
        } else if removed.group_skips * GROUP_TRIAL < removed.group_tests {
            GROUP_TRIAL
        } else {
            0
        };
        for ((_, k, mv, piece), cut) in self.moves.drain(..).zip(removed.by_cutter) {
            if cut {
                report.cutting_moves += 1;
            }
            observer.after_move(stock, k, mv, &piece)?;
        }
        Ok(())
    }
}

/// The largest distance (mm) of the chords replacing the arc `mv` ([`Move::chords`] with
/// sagitta at most `bound`) from the arc: `r·(1 − cos(θ/2))` for chords spanning the angle
/// `θ` of an arc of radius `r` (the larger of its start and end radii for a spiral); 0 for
/// a straight move.
pub fn chord_sagitta(mv: &Move, bound: Real) -> Real {
    match &mv.kind {
        MoveKind::Arc(a) => {
            let r = a.radius.max(a.radius_end);
            let theta = a.sweep_deg.to_radians().abs() / mv.chord_count(bound) as Real;
            r * (1.0 - (theta / 2.0).cos())
        }
        _ => 0.0,
    }
}

/// Sweeps the tool through `moves` on the machine (a chain or a pose source), removing
/// material from `stock` (the plain sweep: [`sweep_observed`] with [`NoObserver`]).
pub fn sweep_program<'a>(
    stock: &mut TriDexel,
    machine: impl Into<Kinematics<'a>>,
    tool: &Tool,
    moves: &[Move],
    opts: &SweepOptions,
    progress: &dyn Progress,
) -> Result<SweepReport, SweepError> {
    sweep_observed(stock, machine, tool, moves, opts, progress, &mut NoObserver)
}

/// The sweep driver: sweeps the tool through `moves` on `chain`, removing material from
/// `stock`, and shows `observer` the stock before each rapid's pieces and after each move.
/// Arcs become chords ([`as_chords`]); consecutive collinear straight moves are joined into
/// one sweep, except that a rapid always starts a new run (so that its check sees the stock
/// before it); moves that turn a rotary axis are cut by the envelope or in sub-steps. The
/// stock comes out the same, bit for bit, whatever the observer. A machine read pose by
/// pose ([`Kinematics::Poses`]) has every move sampled ([`PILOT_STEPS`]): an exact
/// translation joins runs like a straight move, any other is cut in sub-steps within the
/// bound ([`SampledBound`]).
pub fn sweep_observed<'a>(
    stock: &mut TriDexel,
    machine: impl Into<Kinematics<'a>>,
    tool: &Tool,
    moves: &[Move],
    opts: &SweepOptions,
    progress: &dyn Progress,
    observer: &mut dyn SweepObserver,
) -> Result<SweepReport, SweepError> {
    let machine = machine.into();
    let bound = opts.rotary_step_bound_mm;
    if !(bound > 0.0 && bound <= 1.0) {
        return Err(SweepError::BadBound(bound));
    }
    // Each chord's sagitta, in the order of the chords (empty without arcs).
    let sagittas: Vec<Real> = if moves.iter().any(|m| matches!(m.kind, MoveKind::Arc(_))) {
        moves
            .iter()
            .flat_map(|m| std::iter::repeat_n(chord_sagitta(m, bound), m.chord_count(bound)))
            .collect()
    } else {
        Vec::new()
    };
    let moves = as_chords(moves, bound);
    let moves: &[Move] = &moves;
    debug_assert!(sagittas.is_empty() || sagittas.len() == moves.len());
    let mut report = SweepReport::default();
    progress.start("sweep", moves.len() as u64);
    let joinable = TranslatedTool::has_closed_form(tool);
    let mut run: Option<Run> = None;
    let mut batch = Batch {
        moves: Vec::new(),
        groups_rest: 0,
    };
    // A pose source's next moves, prepared ahead ([`Prepared`]); a chain's next moves'
    // envelopes ([`chain_envelopes`]).
    let mut ahead: std::collections::VecDeque<Prepared> = std::collections::VecDeque::new();
    let mut envelopes: std::collections::VecDeque<Option<ChainEnvelope>> =
        std::collections::VecDeque::new();
    // Before the first move every axis is taken as last moved in +.
    let (errors, mut state) = match machine {
        Kinematics::Chain(chain) => (
            chain.has_error_motions(),
            chain.reversal_state(&Directions::default()),
        ),
        Kinematics::Poses(_) => (false, [0.0; 6]),
    };
    if let Kinematics::Poses(_) = machine {
        report.tip_error_mm = Some(0.0);
        report.path_bow_mm = Some(0.0);
    }
    for (k, mv) in moves.iter().enumerate() {
        if let Some(missing) = AxisLetter::ALL
            .into_iter()
            .find(|&l| !machine.has_axis(l) && mv.start.get(l) != mv.end.get(l))
        {
            batch.flush(stock, &mut report, observer)?;
            flush(run.take(), stock, tool, moves, &mut report, observer)?;
            return Err(SweepError::MissingAxis {
                line: mv.line,
                axis: missing.as_char(),
            });
        }
        report.moves += 1;
        let sagitta = sagittas.get(k).copied().unwrap_or(0.0);
        report.chord_error_bound_mm = report.chord_error_bound_mm.max(sagitta);
        report.error_bound_mm = report.error_bound_mm.max(sagitta);
        let before = state;
        let step = match machine {
            Kinematics::Chain(chain) => {
                // Every move of a chain passes here once, in order: the queue holds the next
                // moves' envelopes (built side by side when it runs dry).
                if envelopes.is_empty() {
                    let end = (k + AHEAD).min(moves.len());
                    let next = chain_envelopes(chain, tool, bound, &moves[k..end], errors, state);
                    envelopes.extend(next);
                }
                let envelope = envelopes.pop_front().flatten();
                let (curve, rotary) = chain_curve(chain, mv, errors);
                if errors {
                    state = chain.reversal_after_move(&state, &mv.start, &mv.end);
                }
                if !curve {
                    Step::Straight(if errors {
                        (
                            chain.w_from_t_state(&mv.start, &before),
                            chain.w_from_t_state(&mv.end, &state),
                        )
                    } else {
                        (chain.w_from_t(&mv.start), chain.w_from_t(&mv.end))
                    })
                } else {
                    Step::Curved {
                        rotary,
                        chain,
                        envelope,
                    }
                }
            }
            Kinematics::Poses(src) => {
                // Every move of a pose source passes here once, in order: the queue holds
                // the next moves' preparations (made side by side when it runs dry).
                if ahead.is_empty() {
                    let end = (k + AHEAD).min(moves.len());
                    let next: Vec<Prepared> = moves[k..end]
                        .par_iter()
                        .map(|m| Prepared::of(src, tool, bound, m))
                        .collect();
                    ahead.extend(next);
                }
                let Prepared { pilot, curve } = ahead
                    .pop_front()
                    .unwrap_or_else(|| Prepared::of(src, tool, bound, mv));
                let pilot = match pilot {
                    Ok(p) => record_pilot(p, mv, &mut report),
                    Err(e) => {
                        // What came before the move is cut, as without the batch.
                        batch.flush(stock, &mut report, observer)?;
                        return Err(e);
                    }
                };
                match curve {
                    None => Step::Straight((pilot[0], pilot[PILOT_STEPS])),
                    Some(curve) => {
                        let rotary = AxisLetter::ALL
                            .into_iter()
                            .any(|l| l.is_rotary() && mv.start.get(l) != mv.end.get(l));
                        Step::Sampled {
                            rotary,
                            src,
                            pilot,
                            curve,
                        }
                    }
                }
            }
        };
        let (rotary, e) = match step {
            Step::Straight((p0, p1)) => {
                batch.flush(stock, &mut report, observer)?;
                let tip0 = p0 * Point3::origin();
                let tip1 = p1 * Point3::origin();
                if let Some(r) = &mut run
                    && joinable
                    && mv.kind != MoveKind::Rapid
                    && r.extend(k, mv, &tip1, &p0.rotation)
                {
                    progress.advance(1);
                    continue;
                }
                flush(run.take(), stock, tool, moves, &mut report, observer)?;
                run = Some(Run::new(k, mv, tip0, tip1, p0.rotation));
                progress.advance(1);
                continue;
            }
            Step::Curved {
                rotary,
                chain,
                envelope,
            } => {
                flush(run.take(), stock, tool, moves, &mut report, observer)?;
                let e = sweep_rotary(
                    stock,
                    (chain, envelope),
                    tool,
                    (k, mv),
                    &before,
                    bound,
                    &mut report,
                    (observer, &mut batch),
                )?;
                (rotary, e)
            }
            Step::Sampled {
                rotary,
                src,
                pilot,
                curve,
            } => {
                flush(run.take(), stock, tool, moves, &mut report, observer)?;
                let e = sweep_sampled(
                    stock,
                    src,
                    tool,
                    (k, mv),
                    (&pilot, curve),
                    bound,
                    &mut report,
                    (observer, &mut batch),
                )?;
                (rotary, e)
            }
        };
        if rotary {
            report.rotary_moves += 1;
        } else {
            report.curved_moves += 1;
        }
        report.rotary_error_bound_mm = report.rotary_error_bound_mm.max(e);
        // A chord of an arc that also turns a rotary axis carries both errors.
        report.error_bound_mm = report.error_bound_mm.max(e + sagitta);
        progress.advance(1);
    }
    batch.flush(stock, &mut report, observer)?;
    flush(run.take(), stock, tool, moves, &mut report, observer)?;
    progress.finish();
    Ok(report)
}

/// How the driver cuts one move.
enum Step<'a> {
    /// A pure translation between two poses.
    Straight((Isometry3, Isometry3)),
    /// A move of a chain that turns a rotary axis or moves an axis with error motions, and
    /// its envelope if it was built ahead ([`chain_envelopes`]).
    Curved {
        rotary: bool,
        chain: &'a Chain,
        envelope: Option<ChainEnvelope>,
    },
    /// A move of a pose source that is not a pure translation: its pilot poses and its
    /// prepared curve ([`Prepared::curve`]).
    Sampled {
        rotary: bool,
        src: &'a dyn PoseSource,
        pilot: Vec<Isometry3>,
        curve: (Real, Option<Box<RotaryEnvelope>>),
    },
}

/// Whether a chain's move is cut as a curve (it turns a rotary axis, or it moves an axis
/// with error motions on a chain that has them: `errors`), and whether it turns a rotary
/// axis. The driver and [`chain_envelopes`] decide by this alike.
fn chain_curve(chain: &Chain, mv: &Move, errors: bool) -> (bool, bool) {
    let (omega, _) = rotation_and_travel(chain, &mv.start, &mv.end);
    let rotary = omega != 0.0;
    (rotary || (errors && moves_error_axis(chain, mv)), rotary)
}

/// A chain's move's envelope built ahead of the cut, or why it has none.
type ChainEnvelope = Result<Box<RotaryEnvelope>, EnvelopeError>;

/// The envelope of `tool` on a chain's move `mv` from the reversal shares `state`, with the
/// sweep's `bound` as its tolerance: built ahead ([`chain_envelopes`]) or, when it was not,
/// at the move ([`sweep_rotary`]), the same either way.
fn chain_envelope(
    chain: &Chain,
    tool: &Tool,
    mv: &Move,
    state: &[Real; 6],
    bound: Real,
) -> ChainEnvelope {
    RotaryEnvelope::with_state(chain, tool, &mv.start, &mv.end, state)
        .map(|env| Box::new(env.with_tolerance(bound)))
}

/// The envelopes of the curved ones among `moves` (a chain's next moves, the first starting
/// from the reversal shares `state`), built side by side: each the pure function of the
/// chain, the tool, the move and the shares it starts from, which are followed here move by
/// move as the driver follows them (`errors`: the chain has error motions). `None` for a
/// move the driver cuts straight, or when `bound` is tighter than the envelope's tolerance.
fn chain_envelopes(
    chain: &Chain,
    tool: &Tool,
    bound: Real,
    moves: &[Move],
    errors: bool,
    mut state: [Real; 6],
) -> Vec<Option<ChainEnvelope>> {
    let starts: Vec<Option<[Real; 6]>> = moves
        .iter()
        .map(|mv| {
            let before = state;
            if errors {
                state = chain.reversal_after_move(&state, &mv.start, &mv.end);
            }
            let (curve, _) = chain_curve(chain, mv, errors);
            (curve && bound >= ENVELOPE_TOL).then_some(before)
        })
        .collect();
    moves
        .par_iter()
        .zip(starts)
        .map(|(mv, start)| start.map(|st| chain_envelope(chain, tool, mv, &st, bound)))
        .collect()
}

/// Moves of a pose source prepared ahead of the cut at a time, side by side
/// ([`Prepared`]).
const AHEAD: usize = 32;

/// The pilot poses of a move of a pose source (λ = j/[`PILOT_STEPS`]) with the largest
/// distance of their tips from the commanded ones and the path's bow from its chord.
struct Pilot {
    poses: Vec<Isometry3>,
    tip_error: Real,
    bow: Real,
}

/// What a move of a pose source needs before it is cut, worked out ahead of it: a pure
/// function of the machine, the tool, the bound and the move, so the moves of a stretch are
/// prepared side by side and the cut is the same in any order and for any thread count.
struct Prepared {
    /// The pilot poses, or the error of a pose the machine cannot take.
    pilot: Result<Pilot, SweepError>,
    /// For a move that is not a pure translation: the estimated error of the curve through
    /// the pilot poses ([`SampledPath::error_estimate`]) plus the envelope's tolerance and,
    /// when the estimate leaves at least [`ENVELOPE_TOL`] of the bound, the curve's envelope
    /// with what it leaves as its tolerance (none when it cannot be built).
    curve: Option<(Real, Option<Box<RotaryEnvelope>>)>,
}

impl Prepared {
    fn of(src: &dyn PoseSource, tool: &Tool, bound: Real, mv: &Move) -> Self {
        let pilot = pilot_of(src, mv);
        let curve = match &pilot {
            Ok(p) if !src.is_translation(&mv.start, &mv.end) => {
                // The envelope takes what the curve leaves of the bound.
                let estimate = SampledPath::error_estimate(&p.poses, tool.reach_from(0.0));
                let envelope = (estimate + ENVELOPE_TOL <= bound)
                    .then(|| RotaryEnvelope::sampled(tool, &p.poses).ok())
                    .flatten()
                    .map(|env| Box::new(env.with_tolerance(bound - estimate)));
                let error = match &envelope {
                    Some(env) => (estimate + env.tolerance()).min(bound),
                    None => estimate + ENVELOPE_TOL,
                };
                Some((error, envelope))
            }
            _ => None,
        };
        Self { pilot, curve }
    }
}

/// The pilot poses of a move of a pose source; a pose the machine cannot take is the error
/// of the move's line.
fn pilot_of(src: &dyn PoseSource, mv: &Move) -> Result<Pilot, SweepError> {
    let mut pilot = Vec::with_capacity(PILOT_STEPS + 1);
    let mut tip_error: Real = 0.0;
    for j in 0..=PILOT_STEPS {
        let lambda = j as Real / PILOT_STEPS as Real;
        let q = src.interpolate(&mv.start, &mv.end, lambda);
        let pose = pose_of(src, mv, &q, lambda)?;
        let commanded = src.commanded(&q);
        tip_error = tip_error.max((pose.translation.vector - commanded.translation.vector).norm());
        pilot.push(pose);
    }
    let (a, b) = (
        pilot[0].translation.vector,
        pilot[PILOT_STEPS].translation.vector,
    );
    let chord = b - a;
    let bow = pilot
        .iter()
        .map(|p| {
            let w = p.translation.vector - a;
            let n2 = chord.norm_squared();
            if n2 > 0.0 {
                (w - chord * (w.dot(&chord) / n2).clamp(0.0, 1.0)).norm()
            } else {
                w.norm()
            }
        })
        .fold(0.0, Real::max);
    Ok(Pilot {
        poses: pilot,
        tip_error,
        bow,
    })
}

/// Records a move's pilot tip error and bow in `report` and hands back its poses.
fn record_pilot(pilot: Pilot, mv: &Move, report: &mut SweepReport) -> Vec<Isometry3> {
    report.tip_error_mm = Some(report.tip_error_mm.unwrap_or(0.0).max(pilot.tip_error));
    // The bow of a straight move only: a move that turns an angle curves by design.
    let turns = AxisLetter::ALL
        .into_iter()
        .any(|l| l.is_rotary() && mv.start.get(l) != mv.end.get(l));
    if !turns {
        report.path_bow_mm = Some(report.path_bow_mm.unwrap_or(0.0).max(pilot.bow));
    }
    pilot.poses
}

/// The pose of a pose source at `q`, `lambda` of the way along `mv`, or the error naming
/// the move's line, the place and the axis values.
fn pose_of(
    src: &dyn PoseSource,
    mv: &Move,
    q: &AxisValues,
    lambda: Real,
) -> Result<Isometry3, SweepError> {
    src.w_from_t(q).map_err(|e| {
        let v = q.to_array();
        SweepError::Pose {
            line: mv.line,
            message: format!(
                "at {:.0} % of the move (X{:.4} Y{:.4} Z{:.4} A{:.4} B{:.4} C{:.4}): {e}",
                lambda * 100.0,
                v[0],
                v[1],
                v[2],
                v[3],
                v[4],
                v[5]
            ),
        }
    })
}

/// Cuts move `k` of a pose source, counting it in `report`; returns its error bound (mm).
/// A flat or ball end mill is cut by the exact envelope of the curve through the pilot
/// poses ([`RotaryEnvelope::sampled`]) when that curve's estimated distance from the
/// machine's path ([`SampledPath::error_estimate`]) plus [`ENVELOPE_TOL`] is within
/// `bound` (a rapid under an observer that looks is cut in sub-steps, which it sees one by
/// one); else in sub-steps within `bound` of the true motion (the bound estimated from the
/// pilot poses, [`SampledBound`]).
#[expect(
    clippy::too_many_arguments,
    reason = "the driver's state, passed down for one move"
)]
fn sweep_sampled<'m>(
    stock: &mut TriDexel,
    src: &dyn PoseSource,
    tool: &Tool,
    (k, mv): (usize, &'m Move),
    (pilot, (curve_error, envelope)): (&[Isometry3], (Real, Option<Box<RotaryEnvelope>>)),
    bound: Real,
    report: &mut SweepReport,
    (observer, batch): (&mut dyn SweepObserver, &mut Batch<'m>),
) -> Result<Real, SweepError> {
    let rapid = mv.kind == MoveKind::Rapid;
    let envelope = envelope.filter(|_| !(rapid && observer.looks()));
    if let Some(env) = envelope {
        batch.cut(*env, (k, mv), Piece::Sampled, stock, report, observer)?;
        return Ok(curve_error);
    }
    batch.flush(stock, report, observer)?;
    let rb = SampledBound::of(tool, pilot);
    let n = rb.steps_for(bound, mv.line)?;
    cut_substeps(
        stock,
        tool,
        (k, mv),
        (&rb, n),
        |l| pose_of(src, mv, &src.interpolate(&mv.start, &mv.end, l), l),
        report,
        observer,
    )?;
    observer.after_move(stock, k, mv, &Piece::Sampled)?;
    Ok(rb.at(n))
}

/// Cuts move `k` in the `n` sub-steps of the pose function `pose_at` ([`substeps`]),
/// skipping the groups whose tool, grown by the bound `rb` at 64 steps, misses the stock,
/// and showing a rapid's sub-steps to the observer; counts the move in `report` if it cut.
fn cut_substeps(
    stock: &mut TriDexel,
    tool: &Tool,
    (k, mv): (usize, &Move),
    (rb, n): (&RotaryBound, usize),
    pose_at: impl Fn(Real) -> Result<Isometry3, SweepError>,
    report: &mut SweepReport,
    observer: &mut dyn SweepObserver,
) -> Result<(), SweepError> {
    let line = mv.line as u32;
    let rapid = mv.kind == MoveKind::Rapid;
    // A coarse sub-step's box, grown by its own bound, holds every fine sub-step in it.
    let eps_c = rb.at(COARSE) + tol::SLIVER;
    let stock_box = *stock.bounds();
    let mut cut = false;
    substeps(
        tool,
        n,
        pose_at,
        |tip, d, rot| {
            TranslatedTool::new(tool.clone(), tip, d, Piece::axis(&rot))
                .bounds()
                .inflated(eps_c)
                .intersects(&stock_box)
        },
        |tip, d, rotation| {
            if rapid {
                observer.before_rapid(stock, k, mv, &Piece::Translation { tip, d, rotation })?;
            }
            let swept = TranslatedTool::new(tool.clone(), tip, d, Piece::axis(&rotation));
            report.sweeps += 1;
            cut |= stock.remove(&swept, line);
            Ok(())
        },
    )?;
    if cut {
        report.cutting_moves += 1;
    }
    Ok(())
}

/// Cuts move `k` that turns a rotary axis (the envelope, else sub-steps), counting it in
/// `report`; returns its error bound (mm).
#[expect(
    clippy::too_many_arguments,
    reason = "the driver's state, passed down for one move"
)]
fn sweep_rotary<'m>(
    stock: &mut TriDexel,
    (chain, built): (&Chain, Option<ChainEnvelope>),
    tool: &Tool,
    (k, mv): (usize, &'m Move),
    state: &[Real; 6],
    bound: Real,
    report: &mut SweepReport,
    (observer, batch): (&mut dyn SweepObserver, &mut Batch<'m>),
) -> Result<Real, SweepError> {
    // Flat and ball end mills: the exact per-ray envelope (usually built ahead), unless a
    // bound tighter than its tolerance is asked for.
    let envelope = match built {
        Some(built) => built.ok(),
        None => (bound >= ENVELOPE_TOL)
            .then(|| chain_envelope(chain, tool, mv, state, bound).ok())
            .flatten(),
    };
    if let Some(env) = envelope {
        let piece = Piece::Rotary {
            envelope: true,
            state: *state,
        };
        let tol = env.tolerance();
        batch.cut(*env, (k, mv), piece, stock, report, observer)?;
        return Ok(tol);
    }
    batch.flush(stock, report, observer)?;
    let rb = RotaryBound::of_state(chain, tool, mv, state);
    let n = rb.steps_for(bound, mv.line)?;
    let poses = Poses::of(chain, mv, state);
    cut_substeps(
        stock,
        tool,
        (k, mv),
        (&rb, n),
        |l| Ok(poses.at(l)),
        report,
        observer,
    )?;
    observer.after_move(
        stock,
        k,
        mv,
        &Piece::Rotary {
            envelope: false,
            state: *state,
        },
    )?;
    Ok(rb.at(n))
}

/// Whether the move changes the value of an axis that has error motions (its pose then
/// follows a curved path: the move is swept like a rotary one).
fn moves_error_axis(chain: &Chain, mv: &Move) -> bool {
    chain
        .axes()
        .iter()
        .zip(chain.error_motions_all())
        .any(|(a, e)| e.is_some() && mv.start.get(a.letter) != mv.end.get(a.letter))
}

/// Largest distance (mm) of a move's end from the line of the run it joins. Far below any
/// length the stock resolves (crossings are exact to about this), so sweeping the joined
/// segment instead of its pieces moves no surface beyond rounding.
const JOIN_TOL: Real = tol::LENGTH_EPS;

/// Consecutive straight moves at the same rotary values along one line in one direction,
/// each starting where the previous ended: the union of their sweeps is the sweep of the
/// whole segment, so they are swept as one.
struct Run {
    /// Tip positions (W) at the run's start and current end.
    tip0: Point3,
    tip1: Point3,
    /// Tool orientation (T to W), the same for every move (same rotary values).
    rotation: Rotation3,
    /// The direction of travel, once a move of non-zero length fixed it.
    dir: Option<UnitVector3>,
    /// Axis values at the current end.
    end: AxisValues,
    /// Index of the run's first move.
    first: usize,
    /// Each move's end tip (W) and NC line.
    parts: Vec<(Point3, u32)>,
}

impl Run {
    fn new(k: usize, mv: &Move, tip0: Point3, tip1: Point3, rotation: Rotation3) -> Self {
        let d = tip1 - tip0;
        Self {
            tip0,
            tip1,
            rotation,
            dir: (d.norm() > JOIN_TOL).then(|| UnitVector3::new_normalize(d)),
            end: mv.end,
            first: k,
            parts: vec![(tip1, mv.line as u32)],
        }
    }

    /// Appends move `k` (tip ending at `tip1`, tool orientation `rotation`) if it continues
    /// the run.
    fn extend(&mut self, k: usize, mv: &Move, tip1: &Point3, rotation: &Rotation3) -> bool {
        if mv.start != self.end || rotation != &self.rotation || k != self.first + self.parts.len()
        {
            return false;
        }
        let d = tip1 - self.tip1;
        let along = match self.dir {
            Some(u) => {
                let from0 = tip1 - self.tip0;
                let off_line = (from0 - u.into_inner() * u.dot(&from0)).norm();
                (u.dot(&d) > 0.0 || d.norm() <= JOIN_TOL) && off_line <= JOIN_TOL
            }
            None => true,
        };
        if !along {
            return false;
        }
        if self.dir.is_none() && (tip1 - self.tip0).norm() > JOIN_TOL {
            self.dir = Some(UnitVector3::new_normalize(tip1 - self.tip0));
        }
        self.tip1 = *tip1;
        self.end = mv.end;
        self.parts.push((*tip1, mv.line as u32));
        true
    }
}

/// Sweeps a run of joined moves; counts the moves that removed material (for a run, the
/// moves a cut that removed material names at one of its ends). A run starting with a rapid
/// shows it to the observer first; after the removal, each of the run's moves.
fn flush(
    run: Option<Run>,
    stock: &mut TriDexel,
    tool: &Tool,
    moves: &[Move],
    report: &mut SweepReport,
    observer: &mut dyn SweepObserver,
) -> Result<(), SweepError> {
    let Some(run) = run else {
        return Ok(());
    };
    let piece = |j: usize| {
        let start = if j == 0 { run.tip0 } else { run.parts[j - 1].0 };
        Piece::Translation {
            tip: start,
            d: run.parts[j].0 - start,
            rotation: run.rotation,
        }
    };
    let axis = Piece::axis(&run.rotation);
    if moves[run.first].kind == MoveKind::Rapid {
        observer.before_rapid(stock, run.first, &moves[run.first], &piece(0))?;
    }
    let d = run.tip1 - run.tip0;
    let first = run.parts[0].1;
    let swept = if run.parts.len() == 1 {
        TranslatedTool::new(tool.clone(), run.tip0, d, axis)
    } else {
        let dd = d.norm_squared();
        let last = run.parts.len() - 1;
        let parts = run
            .parts
            .iter()
            .enumerate()
            .map(|(k, (tip, line))| {
                let s = if k == last || dd == 0.0 {
                    1.0
                } else {
                    (tip - run.tip0).dot(&d) / dd
                };
                (s, *line)
            })
            .collect();
        TranslatedTool::joined(tool.clone(), run.tip0, d, axis, parts)
    };
    report.sweeps += 1;
    let used = stock.remove_lines(&swept, first);
    report.cutting_moves += run
        .parts
        .iter()
        .filter(|(_, l)| used.binary_search(l).is_ok())
        .count();
    for j in 0..run.parts.len() {
        let k = run.first + j;
        observer.after_move(stock, k, &moves[k], &piece(j))?;
    }
    Ok(())
}
