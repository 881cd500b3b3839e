//! The part a program cuts on the nominal machine, read as a signed distance near the
//! surface of the part the deviated machine cut: what the deviation colours are measured
//! from, without sweeping the program a second time.
//!
//! The nominal part is the stock less the tool swept along the program on the nominal
//! machine. Near a point `p` of the cut part's surface its signed distance (mm; + outside,
//! − inside) is `max(F_stock(p), −F_swept(p))`:
//!
//! - `F_swept(p)` is the least, over the moves and their poses `T(λ)` on the nominal machine,
//!   of the tool's signed distance at `T(λ)⁻¹·p` ([`crate::cutting::tool::Tool::signed_distance`]).
//!   Outside the swept volume that is the exact distance from it. Inside, it is the depth
//!   into the deepest single pose, which differs from the depth into the union of poses by
//!   terms of second order in the depth (the union's surface is the envelope of the poses,
//!   touching the deepest one's surface where it is nearest `p`).
//! - `F_stock(p)` is the distance of `p` from the tangent plane of the nearest crossing of
//!   an uncut stock face (line 0) of the cut part near `p`: both machines start from the same
//!   stock, so a face neither cuts is the same face.
//!
//! **Which moves.** Every crossing of the cut part carries the NC line that made it. The
//! two machines differ by deviations of micrometres, so the moves that made the cut part's
//! surface around `p` are the ones that make the nominal part's surface there: the
//! candidates are the moves of the lines of the crossings on the rays within [`NEAR`]
//! indices of `p` in the three grids. Where two moves' surfaces meet (a cusp), crossings of
//! both lie around it. A move the deviated machine cuts nowhere near `p` but the nominal
//! machine cuts deepest there would be missed: it would have to reach more than the
//! deviations' difference deeper on one machine than on the other.
//!
//! **Within a move.** Each move's poses at `λ = k/`[`KEPT`] are kept, with `D`, a bound on
//! how far a tool point moves between consecutive kept poses (the tool's reach about its
//! middle times the turn, plus the middle's travel, the largest over the move — a bound on
//! every point's chord — grown for the bow of the path: by a quarter where the kept poses
//! turn by 45° or less, doubled beyond). The tool's signed distance at `p` is evaluated at the
//! kept poses; each move's values between two kept poses are at least the mean of the two
//! less `D/2` (the distance moves no more than the tool does), and the moves whose bound is
//! below the best value so far are refined, least bound first, by Brent's method over the
//! two intervals beside the least sample, until the tool moves less than [`DISTANCE_TOL`]
//! across the bracket.
//!
//! **Poses** are the nominal machine's own at the axis values the controller interpolates
//! (linear in `λ`; arcs are cut as the sweep's chords): a chain's through the envelope's
//! [`MovePath`] (the chain's fixed factors folded, one rotation a turning axis: the same
//! poses to rounding), a pose source's from the source. A pose the machine cannot take drops
//! its move from the candidates.
//!
//! **Invariant:** reads the cut part's crossings and the nominal machine's poses, never
//! changes either; the same inputs give the same distance bit for bit, whatever the thread
//! count.

use crate::cutting::envelope::MovePath;
use crate::cutting::stock::TriDexel;
use crate::cutting::sweep::as_chords;
use crate::cutting::tool::Tool;
use crate::machine::PoseSource;
use crate::machine::chain::Chain;
use crate::math::{Isometry3, Point3, Real, Vector3};
use crate::nc::Move;
use std::collections::BTreeMap;

/// Intervals each move is kept at (kept poses at `λ = k/KEPT`, `k = 0..=KEPT`).
pub const KEPT: usize = 8;

/// Rays on each side of a point whose crossings name its candidate moves and its stock face.
pub const NEAR: usize = 2;

/// The nominal machine: a serial chain, or a machine read pose by pose.
pub enum NominalMachine {
    /// A serial chain (its nominal form).
    Chain(Chain),
    /// A machine read pose by pose (a hexapod with its nominal parameters).
    Poses(Box<dyn PoseSource + Send>),
}

impl std::fmt::Debug for NominalMachine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            NominalMachine::Chain(c) => f.debug_tuple("Chain").field(c).finish(),
            NominalMachine::Poses(_) => f.write_str("Poses(..)"),
        }
    }
}

impl NominalMachine {
    /// The tool's pose at fraction `lambda` of `mv` (whose chain path is `path`, for a
    /// chain), if the machine can take it.
    fn pose(&self, mv: &Move, path: Option<&MovePath>, lambda: Real) -> Option<Isometry3> {
        match (self, path) {
            (NominalMachine::Chain(_), Some(path)) => Some(path.w_from_t(lambda)),
            (NominalMachine::Chain(c), None) => Some(c.w_from_t(&mv.point_at(lambda))),
            (NominalMachine::Poses(src), _) => src
                .w_from_t(&src.interpolate(&mv.start, &mv.end, lambda))
                .ok(),
        }
    }
}

/// A move's kept poses and the motion between them.
#[derive(Clone, Debug)]
struct Kept {
    /// A chain's move as the envelope reads it: the chain with its fixed factors folded, one
    /// rotation a turning axis (the same poses as the chain's, a fraction of the cost).
    path: Option<MovePath>,
    poses: [Isometry3; KEPT + 1],
    /// Bound on how far a tool point moves between consecutive kept poses (mm).
    step: Real,
    /// The refinement's bracket width in `λ`: [`DISTANCE_TOL`] over the tool's speed.
    lambda_tol: Real,
}

/// The program on the nominal machine, as a signed distance near a cut part's surface (see
/// the module docs).
#[derive(Debug)]
pub struct NominalPath {
    tool: Tool,
    machine: NominalMachine,
    moves: Vec<Move>,
    /// Per move (arcs as chords): its kept poses, `None` where the machine cannot take one.
    kept: Vec<Option<Kept>>,
    /// The moves of each NC line.
    by_line: BTreeMap<u32, Vec<u32>>,
}

impl NominalPath {
    /// The program `moves` cut by `tool` on `machine`, arcs as chords within `chord_mm`
    /// (the sweep's `rotary_step_bound_mm`, so the chords are the sweep's own).
    pub fn new(tool: &Tool, machine: NominalMachine, moves: &[Move], chord_mm: Real) -> Self {
        use rayon::prelude::*;
        let moves = as_chords(moves, chord_mm).into_owned();
        let middle = Point3::new(0.0, 0.0, tool.length() / 2.0);
        let reach = tool.reach_from(tool.length() / 2.0);
        let kept = moves
            .par_iter()
            .map(|mv| {
                let path = match &machine {
                    NominalMachine::Chain(c) => Some(MovePath::new(c, &mv.start, &mv.end)),
                    NominalMachine::Poses(_) => None,
                };
                let poses: Vec<Isometry3> = (0..=KEPT)
                    .map(|k| machine.pose(mv, path.as_ref(), k as Real / KEPT as Real))
                    .collect::<Option<_>>()?;
                let (chord, turn) = poses
                    .windows(2)
                    .map(|w| {
                        let turn = w[0].rotation.angle_to(&w[1].rotation);
                        ((w[1] * middle - w[0] * middle).norm() + turn * reach, turn)
                    })
                    .fold((0.0, 0.0), |a: (Real, Real), b| {
                        (a.0.max(b.0), a.1.max(b.1))
                    });
                // A point's path between kept poses is longer than its chord by the bow of
                // its turn: an arc of 45° is 2.6 % longer than its chord, of 180° 57 %.
                let bow = if turn <= std::f64::consts::FRAC_PI_4 {
                    1.25
                } else {
                    2.0
                };
                Some(Kept {
                    path,
                    poses: poses.try_into().ok()?,
                    step: bow * chord,
                    lambda_tol: (DISTANCE_TOL / (KEPT as Real * chord)).clamp(1e-12, 1e-4),
                })
            })
            .collect();
        let mut by_line: BTreeMap<u32, Vec<u32>> = BTreeMap::new();
        for (k, mv) in moves.iter().enumerate() {
            by_line.entry(mv.line as u32).or_default().push(k as u32);
        }
        Self {
            tool: tool.clone(),
            machine,
            moves,
            kept,
            by_line,
        }
    }

    /// The signed distance (mm; + outside, − inside) of `p`, a point on or near the surface
    /// of `cut` (the part the program cut on the deviated machine), from the nominal part's
    /// surface, with that surface's outward normal at its point nearest `p`; `None` where
    /// `cut` has no crossing near `p` (see the module docs).
    pub fn nearest(&self, cut: &TriDexel, p: &Point3) -> Option<Nearest> {
        SCRATCH.with_borrow_mut(|scratch| self.nearest_with(cut, p, scratch))
    }

    /// [`Self::nearest`] with the scratch buffers `scratch`.
    fn nearest_with(&self, cut: &TriDexel, p: &Point3, scratch: &mut Scratch) -> Option<Nearest> {
        let Scratch { lines, cands } = scratch;
        lines.clear();
        let mut stock_face: Option<(Real, Point3, Vector3)> = None;
        // Crossings farther than the window's half-width (its corner) are not around `p`.
        let radius2 = (cut.max_spacing() * (NEAR as Real + 0.5)).powi(2) * 3.0;
        for g in cut.grids() {
            g.for_each_crossing_near(p, NEAR, |q, c| {
                if (q - p).norm_squared() > radius2 {
                    return;
                }
                if c.line == 0 {
                    let d = (q - p).norm_squared();
                    if stock_face.is_none_or(|b| d < b.0) {
                        stock_face = Some((d, q, c.normal()));
                    }
                } else {
                    lines.push(c.line);
                }
            });
        }
        lines.sort_unstable();
        lines.dedup();
        let stock = stock_face.map(|(_, q, n)| Nearest {
            distance: (p - q).dot(&n),
            normal: n,
        });
        // Inside the swept volume is outside the part: the part's distance is the negated
        // one, its outward normal the tool's inward one.
        let swept = self.swept_distance(p, lines, cands).map(|(d, n)| Nearest {
            distance: -d,
            normal: -n,
        });
        match (stock, swept) {
            (Some(s), Some(w)) => Some(if w.distance > s.distance { w } else { s }),
            (s, w) => s.or(w),
        }
    }

    /// The least signed distance of `p` from the tool over the moves of `lines`, with the
    /// tool's outward normal there (`None` without such a move).
    fn swept_distance(
        &self,
        p: &Point3,
        lines: &[u32],
        cands: &mut Vec<Candidate>,
    ) -> Option<(Real, Vector3)> {
        // (lower bound, least sample, its index, move) of every candidate, least bound
        // first. Between consecutive kept poses no tool point moves by more than `D`, and the
        // signed distance moves no more than the point: the interval's values are at least
        // the mean of its ends' less `D/2`.
        cands.clear();
        cands.extend(
            lines
                .iter()
                .filter_map(|l| self.by_line.get(l))
                .flatten()
                .filter_map(|&m| {
                    let kept = self.kept[m as usize].as_ref()?;
                    let f: [(Real, Vector3); KEPT + 1] =
                        std::array::from_fn(|k| self.tool_distance(&kept.poses[k], p));
                    let (k, s) = f
                        .iter()
                        .enumerate()
                        .min_by(|a, b| a.1.0.total_cmp(&b.1.0))?;
                    let bound = f
                        .windows(2)
                        .map(|w| 0.5 * (w[0].0 + w[1].0 - kept.step))
                        .fold(Real::INFINITY, Real::min);
                    Some((bound, *s, k, m))
                }),
        );
        cands.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.3.cmp(&b.3)));
        let mut best = cands
            .iter()
            .map(|c| c.1)
            .min_by(|a, b| a.0.total_cmp(&b.0))?;
        for &(bound, s, k, m) in cands.iter() {
            if bound >= best.0 {
                break;
            }
            let r = self.refine(m as usize, k, s, p);
            if r.0 < best.0 {
                best = r;
            }
        }
        Some(best)
    }

    /// The tool's signed distance at `p` in pose `t`, with its outward normal (W).
    fn tool_distance(&self, t: &Isometry3, p: &Point3) -> (Real, Vector3) {
        let (d, n) = self.tool.signed_distance(&t.inverse_transform_point(p));
        (d, t.rotation * n)
    }

    /// The least signed distance of `p` from the tool on move `m` over the two intervals
    /// beside kept pose `k` (whose value is `fk`), by Brent's method (golden section with
    /// parabolic steps, until the tool moves less than [`DISTANCE_TOL`] across the bracket), with
    /// the tool's normal there.
    fn refine(&self, m: usize, k: usize, fk: (Real, Vector3), p: &Point3) -> (Real, Vector3) {
        let mv = &self.moves[m];
        let path = self.kept[m].as_ref().and_then(|k| k.path.as_ref());
        let at = |lambda: Real| {
            self.machine
                .pose(mv, path, lambda)
                .map_or((Real::INFINITY, Vector3::z()), |t| {
                    self.tool_distance(&t, p)
                })
        };
        let step = 1.0 / KEPT as Real;
        let x0 = k as Real * step;
        let (a, b) = ((x0 - step).max(0.0), (x0 + step).min(1.0));
        let tol = self.kept[m].as_ref().map_or(1e-12, |k| k.lambda_tol);
        brent(at, (a, b), (x0, fk), tol)
    }
}

/// A candidate move of [`NominalPath::swept_distance`]: the lower bound on its tool's
/// signed distance, its least kept sample (value and normal), that sample's index and the
/// move.
type Candidate = (Real, (Real, Vector3), usize, u32);

/// The buffers of [`NominalPath::nearest`], kept per thread: the candidate lines and moves
/// of each point, without an allocation a point (the colours read about 100 k points on
/// two threads, whose allocations would otherwise contend).
#[derive(Default)]
struct Scratch {
    lines: Vec<u32>,
    cands: Vec<Candidate>,
}

thread_local! {
    static SCRATCH: std::cell::RefCell<Scratch> = std::cell::RefCell::new(Scratch::default());
}

/// How far (mm) a tool point may move within the bracket at which a move's refinement
/// stops: the distance found is within it of the least (exactly so where the least is at a
/// bracket end; far closer at a smooth minimum, where the distance is flat).
pub const DISTANCE_TOL: Real = 1e-6;

/// Most steps of a refinement (golden-section steps alone shrink the bracket by 0.618 a
/// step: 60 reach 3e-13 of it).
const BRENT_STEPS: usize = 60;

/// The least value of `f` over `[a, b]` found by Brent's method (Numerical Recipes' `brent`:
/// parabolic steps through the three best points, golden-section steps where a parabola
/// steps badly), starting from `x` with value `fx`, until the bracket is `tol` wide; `f`'s
/// value carries a payload (the normal) beside the number minimised.
fn brent<T: Copy>(
    f: impl Fn(Real) -> (Real, T),
    (mut a, mut b): (Real, Real),
    (x0, fx0): (Real, (Real, T)),
    tol: Real,
) -> (Real, T) {
    const CGOLD: Real = 0.381_966_011_250_105_1;
    let (mut x, mut w, mut v) = (x0, x0, x0);
    let mut best = fx0;
    let (mut fw, mut fv) = (fx0.0, fx0.0);
    let (mut d, mut e): (Real, Real) = (0.0, 0.0);
    for _ in 0..BRENT_STEPS {
        let xm = 0.5 * (a + b);
        let tol1 = tol * 0.5;
        let tol2 = 2.0 * tol1;
        if (x - xm).abs() <= tol2 - 0.5 * (b - a) {
            break;
        }
        let mut golden = true;
        if e.abs() > tol1 {
            // A parabola through x, w, v.
            let r = (x - w) * (best.0 - fv);
            let mut q = (x - v) * (best.0 - fw);
            let mut pp = (x - v) * q - (x - w) * r;
            q = 2.0 * (q - r);
            if q > 0.0 {
                pp = -pp;
            }
            q = q.abs();
            let etemp = e;
            e = d;
            if !(pp.abs() >= (0.5 * q * etemp).abs() || pp <= q * (a - x) || pp >= q * (b - x)) {
                d = pp / q;
                let u = x + d;
                if u - a < tol2 || b - u < tol2 {
                    d = tol1.copysign(xm - x);
                }
                golden = false;
            }
        }
        if golden {
            e = if x >= xm { a - x } else { b - x };
            d = CGOLD * e;
        }
        let u = if d.abs() >= tol1 {
            x + d
        } else {
            x + tol1.copysign(d)
        };
        let fu = f(u);
        if fu.0 <= best.0 {
            if u >= x {
                a = x;
            } else {
                b = x;
            }
            (v, fv) = (w, fw);
            (w, fw) = (x, best.0);
            (x, best) = (u, fu);
        } else {
            if u < x {
                a = u;
            } else {
                b = u;
            }
            if fu.0 <= fw || w == x {
                (v, fv) = (w, fw);
                (w, fw) = (u, fu.0);
            } else if fu.0 <= fv || v == x || v == w {
                (v, fv) = (u, fu.0);
            }
        }
    }
    best
}

/// The nominal part's surface as seen from a point: its signed distance and the outward
/// normal at its nearest point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Nearest {
    /// Signed distance (mm; + outside the part, − inside).
    pub distance: Real,
    /// The part's outward unit normal at the surface point nearest.
    pub normal: Vector3,
}
