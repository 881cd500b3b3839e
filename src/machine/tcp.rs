//! Tool-centre-point (TCP) programs: what a controller with TCP kinematics runs (LinuxCNC's
//! switchable `xyzac-trt-kins` / `xyzbc-trt-kins` in their TCP mode, the `G43.4`-style modes
//! of other controllers). The program's X Y Z are the tool tip (the origin of the tool frame,
//! the control point the chain defines, tool length included) in the workpiece frame; its
//! A B C are the rotary axes' values. The controller turns them into joint values through the
//! **nominal** chain: the rotary axes as programmed, the linear axes by the inverse kinematics
//! at those rotary values ([`Chain::solve_linear_axes`]).
//!
//! A move is interpolated in TCP coordinates: the tip runs along the programmed straight line
//! (or arc) in the workpiece frame while every rotary axis turns linearly with the move's
//! parameter. [`joint_program`] turns such a program into joint moves, once, for everything
//! downstream (sweep, instruments, correction):
//!
//! - a straight move that turns no rotary axis is one joint move, exact: with the rotaries
//!   fixed the tip is affine in the linear axes (see `calibration::correct`'s proof), so the
//!   joint move between the two solved ends is the TCP line;
//! - any other move (a rotary axis turning, an arc) is split into `n` equal parts of its
//!   parameter, each a joint move between the solved sub-points, with `n` the smallest of the
//!   doubling sequence for which the tip on every joint move, compared at the same parameter
//!   with the TCP path (same rotary values), is within [`TCP_PATH_BOUND_MM`] at seven
//!   checked points of each part (1/8 … 7/8). The error of a part vanishes at its ends and
//!   falls as 1/n²; its largest value sits in the middle.
//!
//! Each joint part keeps its share of the TCP move's duration: the TCP move takes `T =
//! L/F` (L the length a feed-per-minute controller applies F to, summed over the parts), each
//! part `T/n`, and gets the feed that makes its own joint length take that long. Rapids stay
//! rapids, feed moves (and arcs' chords) become straight feed moves; every part keeps the
//! source line.
//!
//! **Invariant:** only the nominal chain is used here: the controller's kinematics knows
//! nothing of the machine's deviations.

use crate::machine::chain::{AxisKind, Chain};
use crate::machine::error_motion::Directions;
use crate::math::{Point3, Real};
use crate::nc::{AxisLetter, AxisValues, Move, MoveKind, Program, controller_length};

/// Largest distance (mm) between the tool tip on the joint moves a TCP move becomes and the
/// TCP path at the same parameter: 0.1 µm, a tenth of the micrometre the correction aims at
/// and well above the inverse kinematics' 1e-10 mm.
pub const TCP_PATH_BOUND_MM: Real = 1e-4;

/// Largest number of joint moves one TCP move becomes.
pub const MAX_TCP_PARTS: usize = 1 << 20;

/// Where a part's tip is compared with the TCP path, as fractions of the part.
const CHECK_AT: [Real; 7] = [0.125, 0.25, 0.375, 0.5, 0.625, 0.75, 0.875];

/// How a scene's controller reads its program's axis words (`[machine] controller`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Controller {
    /// `"joint"` (the default): every word is an axis value.
    #[default]
    Joint,
    /// `"tcp"`: X Y Z are the tool tip in the workpiece frame, A B C the rotary axes.
    Tcp,
}

/// Why a TCP program cannot be turned into joint moves.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum TcpError {
    /// The inverse kinematics found no linear axis values for a tip position.
    #[error(
        "the tool tip at X{x:.6} Y{y:.6} Z{z:.6} has no linear axis values at these rotary values"
    )]
    Unreachable {
        /// Source line.
        line: usize,
        /// The tip (workpiece frame, mm).
        x: Real,
        /// …
        y: Real,
        /// …
        z: Real,
    },
    /// A move would need more joint moves than [`MAX_TCP_PARTS`] to stay within the bound.
    #[error(
        "keeping the tool tip within {bound_mm} mm of its TCP path needs more than {limit} joint moves"
    )]
    TooManyParts {
        /// Source line.
        line: usize,
        /// The bound (mm).
        bound_mm: Real,
        /// The limit.
        limit: usize,
    },
    /// A value is not finite.
    #[error("axis {axis} is not a finite number")]
    NonFinite {
        /// Source line.
        line: usize,
        /// The axis letter.
        axis: char,
    },
}

impl TcpError {
    /// The source line the error is about.
    pub fn line(&self) -> usize {
        match self {
            TcpError::Unreachable { line, .. }
            | TcpError::TooManyParts { line, .. }
            | TcpError::NonFinite { line, .. } => *line,
        }
    }
}

const LINEAR: [AxisLetter; 3] = [AxisLetter::X, AxisLetter::Y, AxisLetter::Z];

/// The TCP coordinates of joint values `q` on `chain` (the nominal one, for a controller):
/// X Y Z the tool tip in the workpiece frame, A B C as in `q`.
pub fn tcp_from_joint(chain: &Chain, q: &AxisValues) -> AxisValues {
    let p = chain.w_from_t(q) * Point3::origin();
    let mut out = *q;
    for (l, v) in LINEAR.into_iter().zip([p.x, p.y, p.z]) {
        out.set(l, v);
    }
    out
}

/// The joint values of TCP coordinates `p` on `chain`: the rotary axes as in `p`, the linear
/// axes solved (from `p` as the start, so the answer depends on `p` alone); `None` if the
/// inverse kinematics fails.
pub fn joint_from_tcp(chain: &Chain, p: &AxisValues) -> Option<AxisValues> {
    let target = Point3::new(
        p.get(AxisLetter::X),
        p.get(AxisLetter::Y),
        p.get(AxisLetter::Z),
    );
    chain.solve_linear_axes(p, &Point3::origin(), &target, &Directions::default())
}

/// Whether `chain` turns the tool tip with any of its axes (a rotary axis): TCP mode means
/// something only then.
pub fn has_rotary(chain: &Chain) -> bool {
    chain.axes().iter().any(|a| a.kind == AxisKind::Rotary)
}

fn joint(chain: &Chain, p: &AxisValues, line: usize) -> Result<AxisValues, TcpError> {
    if let Some(l) = AxisLetter::ALL.into_iter().find(|l| !p.get(*l).is_finite()) {
        return Err(TcpError::NonFinite {
            line,
            axis: l.as_char(),
        });
    }
    joint_from_tcp(chain, p).ok_or(TcpError::Unreachable {
        line,
        x: p.get(AxisLetter::X),
        y: p.get(AxisLetter::Y),
        z: p.get(AxisLetter::Z),
    })
}

fn lerp(a: &AxisValues, b: &AxisValues, t: Real) -> AxisValues {
    let (a, b) = (a.to_array(), b.to_array());
    AxisValues::from_array(std::array::from_fn(|k| a[k] + (b[k] - a[k]) * t))
}

fn tip(q: &AxisValues) -> Point3 {
    Point3::new(
        q.get(AxisLetter::X),
        q.get(AxisLetter::Y),
        q.get(AxisLetter::Z),
    )
}

/// The largest distance, at the checked points, between the tip on the joint moves through
/// `joints` (the solved sub-points of `mv` at `j/n`) and the TCP path at the same parameter.
pub fn part_deviation(chain: &Chain, mv: &Move, joints: &[AxisValues]) -> Real {
    let n = joints.len() - 1;
    let mut worst: Real = 0.0;
    for j in 0..n {
        for t in CHECK_AT {
            let s = (j as Real + t) / n as Real;
            let q = lerp(&joints[j], &joints[j + 1], t);
            let at = chain.w_from_t(&q) * Point3::origin();
            worst = worst.max((at - tip(&mv.point_at(s))).norm());
        }
    }
    worst
}

/// Whether the move turns a rotary axis.
fn turns(mv: &Move) -> bool {
    [AxisLetter::A, AxisLetter::B, AxisLetter::C]
        .iter()
        .any(|&l| mv.start.get(l) != mv.end.get(l))
}

/// The joint moves of one TCP move on `chain` (the nominal one), and the largest checked
/// deviation of their tip from the TCP path (0 for a straight move at fixed rotary values).
pub fn joint_moves(chain: &Chain, mv: &Move) -> Result<(Vec<Move>, Real), TcpError> {
    let line = mv.line;
    let straight = !matches!(mv.kind, MoveKind::Arc(_)) && !turns(mv);
    let (joints, worst) = if straight {
        (
            vec![joint(chain, &mv.start, line)?, joint(chain, &mv.end, line)?],
            0.0,
        )
    } else {
        let mut n = 1usize;
        loop {
            let joints = (0..=n)
                .map(|j| joint(chain, &mv.point_at(j as Real / n as Real), line))
                .collect::<Result<Vec<_>, _>>()?;
            let worst = part_deviation(chain, mv, &joints);
            if worst <= TCP_PATH_BOUND_MM {
                break (joints, worst);
            }
            // The deviation falls as 1/n²: jump close to the n needed, at least double.
            let grow = ((worst / TCP_PATH_BOUND_MM).sqrt() * 1.2).max(2.0);
            let next = (n as Real * grow).ceil();
            if next > MAX_TCP_PARTS as Real {
                return Err(TcpError::TooManyParts {
                    line,
                    bound_mm: TCP_PATH_BOUND_MM,
                    limit: MAX_TCP_PARTS,
                });
            }
            n = next as usize;
        }
    };
    let n = joints.len() - 1;
    // The TCP move's duration (minutes at its feed), shared equally by the parts.
    let part_minutes = mv.feed_mm_per_min.map(|f| {
        let length: Real = (0..n)
            .map(|j| {
                controller_length(
                    &mv.point_at(j as Real / n as Real),
                    &mv.point_at((j + 1) as Real / n as Real),
                )
            })
            .sum();
        length / f / n as Real
    });
    let kind = match mv.kind {
        MoveKind::Rapid => MoveKind::Rapid,
        _ => MoveKind::Linear,
    };
    let mut out = Vec::with_capacity(n);
    for w in joints.windows(2) {
        if w[0] == w[1] {
            continue;
        }
        let feed = match (mv.feed_mm_per_min, part_minutes) {
            (Some(f), Some(t)) if t > 0.0 => {
                let l = controller_length(&w[0], &w[1]);
                // A part as long in joints as in TCP keeps the programmed feed exactly.
                if (l / t - f).abs() <= 1e-12 * f {
                    Some(f)
                } else {
                    Some(l / t)
                }
            }
            (f, _) => f,
        };
        out.push(Move {
            kind,
            start: w[0],
            end: w[1],
            feed_mm_per_min: feed,
            line,
        });
    }
    Ok((out, worst))
}

/// A TCP program as the joint moves its controller makes on `chain` (the nominal one): see
/// the module docs. Zero-length joint moves are left out; `axes_used` are the joint axes that
/// move.
pub fn joint_program(chain: &Chain, program: &Program) -> Result<Program, TcpError> {
    let mut moves = Vec::with_capacity(program.moves.len());
    for mv in &program.moves {
        moves.extend(joint_moves(chain, mv)?.0);
    }
    let axes_used = AxisLetter::ALL
        .into_iter()
        .filter(|&l| moves.iter().any(|m| m.start.get(l) != m.end.get(l)))
        .collect();
    Ok(Program {
        path: program.path.clone(),
        moves,
        axes_used,
        ended_by: program.ended_by,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::machine::chain::Axis;
    use crate::math::{UnitVector3, Vector3};

    /// C table on X, Y, Z, B head about Y with its pivot 150 above the tip.
    fn head_table() -> Chain {
        let ax = |letter, kind, d: [Real; 3], o: [Real; 3]| Axis {
            letter,
            kind,
            direction: UnitVector3::new_normalize(Vector3::from(d)),
            origin: Point3::from(o),
        };
        Chain::new(
            vec![
                ax(AxisLetter::C, AxisKind::Rotary, [0., 0., 1.], [0.; 3]),
                ax(AxisLetter::X, AxisKind::Linear, [1., 0., 0.], [0.; 3]),
                ax(AxisLetter::Y, AxisKind::Linear, [0., 1., 0.], [0.; 3]),
                ax(AxisLetter::Z, AxisKind::Linear, [0., 0., 1.], [0.; 3]),
                ax(
                    AxisLetter::B,
                    AxisKind::Rotary,
                    [0., 1., 0.],
                    [0., 0., 150.],
                ),
            ],
            "S",
        )
        .expect("chain")
    }

    #[test]
    fn tcp_and_joint_values_round_trip() {
        let c = head_table();
        let q = AxisValues::from_array([12.0, -7.0, 40.0, 0.0, 25.0, 70.0]);
        let p = tcp_from_joint(&c, &q);
        // Hand: at B = b the tip sits 150·(−sin b, 0, 1 − cos b) from (x, y, z) in the C
        // table's frame, turned by C.
        let b = 25f64.to_radians();
        let (x, z) = (12.0 - 150.0 * b.sin(), 40.0 + 150.0 - 150.0 * b.cos());
        let cz = 70f64.to_radians();
        let (px, py) = (x * cz.cos() + 7.0 * cz.sin(), x * cz.sin() - 7.0 * cz.cos());
        assert!((p.get(AxisLetter::X) - px).abs() < 1e-9);
        assert!((p.get(AxisLetter::Y) - py).abs() < 1e-9);
        assert!((p.get(AxisLetter::Z) - z).abs() < 1e-9);
        let back = joint_from_tcp(&c, &p).expect("solves");
        for l in AxisLetter::ALL {
            assert!((back.get(l) - q.get(l)).abs() < 1e-9, "{l:?}");
        }
    }

    #[test]
    fn a_move_turning_c_keeps_the_tip_on_its_line_within_the_bound() {
        let c = head_table();
        let mv = Move {
            kind: MoveKind::Linear,
            start: AxisValues::from_array([-10.0, 5.0, 30.0, 0.0, 0.0, 0.0]),
            end: AxisValues::from_array([10.0, 5.0, 30.0, 0.0, 20.0, 90.0]),
            feed_mm_per_min: Some(600.0),
            line: 7,
        };
        let (moves, worst) = joint_moves(&c, &mv).expect("converts");
        assert!(
            moves.len() > 10 && worst <= TCP_PATH_BOUND_MM,
            "{} {worst}",
            moves.len()
        );
        // Densely, every part: the tip within the bound of the line at the same C and B.
        let n = moves.len() as Real;
        for (j, m) in moves.iter().enumerate() {
            for k in 0..=32 {
                let t = k as Real / 32.0;
                let q = lerp(&m.start, &m.end, t);
                let s = (j as Real + t) / n;
                let want = tip(&mv.point_at(s));
                let at = c.w_from_t(&q) * Point3::origin();
                assert!((at - want).norm() <= TCP_PATH_BOUND_MM, "part {j} t {t}");
            }
        }
        // The parts take the TCP move's 20 mm at 600 mm/min: 2 s in all.
        let minutes: Real = moves
            .iter()
            .map(|m| controller_length(&m.start, &m.end) / m.feed_mm_per_min.expect("feed"))
            .sum();
        assert!((minutes * 60.0 - 2.0).abs() < 1e-9, "{minutes}");
    }
}
