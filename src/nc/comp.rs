//! Cutter radius compensation (G41/G42, G41.1/G42.1, G40) with the behaviour of the
//! LinuxCNC 2.9 RS274/NGC interpreter.
//!
//! The compensator works in the two coordinates of the selected plane, in program
//! coordinates: G17 → (X, Y), G18 → (Z, X), G19 → (Y, Z) (see [`Plane`]; LinuxCNC refuses
//! compensation in G19, [`Plane::check_comp_allowed`]). The coordinate along the plane normal
//! (Z in G17) is carried as `along` and never compensated. Left, right and counter-clockwise
//! are meant in the right-handed frame (first, second, normal): left of the direction of
//! travel is a quarter turn counter-clockwise from it (in G18, Z to the right and X up).
//! Any length unit will do as long as the radius is in the same one (a G20 program may be
//! fed in mm): the decisions are angles and ratios, and the one length tolerance is an
//! internal-error check.
//!
//! # Use by the interpreter
//!
//! * On G41/G42 (diameter of the tool-table entry named by D, or of the loaded tool) or
//!   G41.1/G42.1 (diameter in the D word): [`Compensator::new`] with the side, the tool
//!   *radius* (half the diameter; a negative radius swaps the side and zero makes every move
//!   pass through unchanged, as in LinuxCNC) and the current position. In a block with both
//!   G41/G42/G40 and motion, the compensation change comes first.
//!   Each move of the selected plane while compensation is on goes through
//!   [`Compensator::push_move`] as a [`PlaneMove`]: its end point and, for arcs, its centre
//!   are the *programmed* ones, computed by the interpreter from the programmed start point
//!   [`Compensator::programmed`] (also the base of G91 increments and of I/J/K), and validated
//!   by it (radius mismatch, R too small) as without compensation. A move with no motion in
//!   the plane (e.g. only Z) is a straight whose `end` equals [`Compensator::programmed`].
//! * The non-motion canonical calls that LinuxCNC queues while compensation is on go through
//!   [`Compensator::push_event`] and are released in program order with the moves: COMMENT,
//!   SET_FEED_RATE, SET_FEED_MODE, DWELL, MIST_ON/OFF, FLOOD_ON/OFF, START_SPINDLE_CLOCKWISE /
//!   COUNTERCLOCKWISE, STOP_SPINDLE_TURNING, SET_SPINDLE_MODE, SET_SPINDLE_SPEED. Any other
//!   call LinuxCNC issues at once, i.e. ahead of the held move: to match it, the interpreter
//!   calls [`Compensator::drain`] and then emits the call itself.
//! * A call that returns an error leaves the compensator as it was (events pushed before it
//!   stay queued), so an interpreter that goes on checking after an error can treat the
//!   refused block as absent; LinuxCNC itself stops at the first error.
//! * After each block, [`Compensator::drain`] yields the outputs that can no longer change,
//!   in order. The last move in the plane (and the moves without plane motion and the
//!   events after it) is held back until the next move decides its end point (a concave
//!   corner moves it to the intersection of the offset paths).
//! * M0, M1, M60 (and M2/M30): [`Compensator::release_held`] releases the held move as it is
//!   before the stop; compensation stays on (M2/M30 then end it: [`Compensator::finish`],
//!   without the exit rule).
//! * On G40: push the "compensation off" event if any, then [`Compensator::finish`], which
//!   releases everything. When it reports [`CompEnd::exit_must_be_straight`] (the radius
//!   was not zero), the next motion block is the exit move: it
//!   starts at the tool point [`Compensator::tool_point`] (where the machine is) and is
//!   programmed from [`Compensator::programmed`] (the interpreter's current position from
//!   then on); an arc there is [`CompError::ArcAfterCompOff`] (LinuxCNC clears the rule on
//!   any straight move).
//! * Errors the interpreter raises itself, with LinuxCNC's texts: G41/G42 in G19
//!   ([`CompError::PlaneNotAllowed`]), G41/G42 while on ("Cannot turn cutter radius comp on
//!   when on"), a plane change while on ("Cannot change planes with cutter radius
//!   compensation on"), G53 ("Cannot use g53 with cutter radius comp"), tool change ("Cannot
//!   change tools with cutter radius compensation on"), G43/G49 ("Cannot change tool offset
//!   with cutter radius compensation on"), G54–G59.3 ("Cannot change coordinate systems with
//!   cutter radius compensation on"), G52/G92 ("Cannot change axis offsets with cutter radius
//!   comp"), splines ("Cannot convert spline with cutter radius compensation").
//!
//! Every output carries a clone of the payload `E` of the move that produced it, including
//! the arcs inserted around convex corners (LinuxCNC gives those the new move's A/B/C/U/V/W
//! end values and line number, and the *old* normal-axis value: the normal axis moves only
//! on the programmed move).
//!
//! # Algorithm (LinuxCNC 2.9)
//!
//! * Entry move (first move after G41/G42, "comp1"). Straight: the tool ends one radius from
//!   the programmed end, perpendicular to the programmed line on the compensation side; the
//!   move must be longer than the radius. Arc: the tool ends one radius from the programmed end
//!   along the arc's radius (towards the centre when the tool is inside the arc); the arc is
//!   re-centred on the perpendicular bisector of the tool's start and end, on the line from
//!   the new end to the programmed centre.
//! * Following moves ("comp2"): the tool ends one radius off the programmed end. At the
//!   start of the move, the angle between the previous direction and the new one decides:
//!   convex corner (beyond [`CONCAVE_CORNER_ANGLE`]) → an arc of the tool radius around the
//!   programmed corner is inserted (for a rapid, a straight traverse to the arc's end);
//!   tangent → nothing; concave → the previous (held) move's end point is moved to the
//!   intersection of the two offset paths (line-line, line-arc, arc-line, arc-arc), with the
//!   gouging checks of LinuxCNC (a straight whose direction would reverse, an arc whose sweep
//!   would grow). A turn of about 180° next to an arc the tool is outside of (the "h" and "m"
//!   shapes) counts as concave, so the tool stays on the outside.
//! * The entry move must move in the plane: one with only normal-axis motion is "not greater
//!   than the tool radius" ([`CompError::EntryMoveTooShort`]), as in LinuxCNC.
//! * G40 flushes the held move as it is: the exit move is the interpreter's own. The exit
//!   rule holds even when no move was made since G41/G42, as in LinuxCNC 2.9.0 (later
//!   versions skip G40's work in that case; 2.9.0 then also jumps its position to a stale
//!   programmed point, which is not reproduced: [`Compensator::programmed`] is the G41
//!   position).
//!
//! Not reproduced: lathe tool orientations (the tool-tip origin shift of G41.1/G42.1 with an
//! L word or a tool-table orientation other than 0/9), inverse-time feed recomputation (an
//! interpreter matter: LinuxCNC keeps the programmed length), and the internal consistency
//! check on the re-centred entry arc (it holds by construction).

use std::collections::VecDeque;
use std::collections::vec_deque::Drain;
use std::f64::consts::{FRAC_PI_2, PI, TAU};

use thiserror::Error;

use crate::math::Real;

/// Angle (radians) within which two successive directions count as tangent, so no corner
/// arc is inserted and no end point is moved: LinuxCNC's `TOLERANCE_CONCAVE_CORNER`. It
/// absorbs the direction noise of CAM output (chords and arcs meeting at a few hundredths of a
/// radian) without visible facets.
pub const CONCAVE_CORNER_ANGLE: Real = 0.05;

/// Slack (radians) before a held arc whose end is pulled back into a concave corner counts
/// as sweeping further than programmed (LinuxCNC's 0.001): rounding of the intersection must
/// not raise a gouging error on an arc that is only shortened.
const SWEEP_SLACK: Real = 0.001;

/// Largest difference (program units) between the radius of a held arc and the radius at its
/// moved end point before it is reported as an internal error (LinuxCNC's 0.01): the moved
/// end is computed on the arc, so any real difference is a bug, not rounding.
const RADIUS_MISMATCH: Real = 0.01;

/// Below this |cos| (LinuxCNC's `TOLERANCE_EQUAL`, 1e-4) the re-centring of an entry arc is
/// degenerate (the tool's start lies on the perpendicular through the new end): the arc
/// radius is then not larger than the tool radius in effect.
const ENTRY_ARC_COS_EPS: Real = 1e-4;

/// Which side of the programmed path the tool runs on, looking along the direction of travel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Side {
    /// G41 / G41.1: tool to the left of the path.
    Left,
    /// G42 / G42.1: tool to the right of the path.
    Right,
}

impl Side {
    fn opposite(self) -> Side {
        match self {
            Side::Left => Side::Right,
            Side::Right => Side::Left,
        }
    }

    /// Whether the tool runs inside an arc turning counter-clockwise (`ccw`) or clockwise.
    fn inside(self, ccw: bool) -> bool {
        matches!((self, ccw), (Side::Left, true) | (Side::Right, false))
    }
}

/// The selected plane (G17/G18/G19) and how program coordinates split into the two in-plane
/// coordinates and the normal one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Plane {
    /// G17: in-plane (X, Y), normal Z.
    Xy,
    /// G18: in-plane (Z, X), normal Y.
    Zx,
    /// G19: in-plane (Y, Z), normal X. LinuxCNC refuses compensation here.
    Yz,
}

impl Plane {
    /// Splits an (X, Y, Z) point into the in-plane coordinates and the normal coordinate.
    pub fn split(self, p: [Real; 3]) -> ([Real; 2], Real) {
        match self {
            Plane::Xy => ([p[0], p[1]], p[2]),
            Plane::Zx => ([p[2], p[0]], p[1]),
            Plane::Yz => ([p[1], p[2]], p[0]),
        }
    }

    /// Joins in-plane coordinates and the normal coordinate back into (X, Y, Z).
    pub fn join(self, q: [Real; 2], along: Real) -> [Real; 3] {
        match self {
            Plane::Xy => [q[0], q[1], along],
            Plane::Zx => [q[1], along, q[0]],
            Plane::Yz => [along, q[0], q[1]],
        }
    }

    /// LinuxCNC compensates only in G17 and G18.
    pub fn check_comp_allowed(self) -> Result<(), CompError> {
        match self {
            Plane::Yz => Err(CompError::PlaneNotAllowed),
            Plane::Xy | Plane::Zx => Ok(()),
        }
    }
}

/// The geometry of a programmed move in the plane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PlaneMoveKind {
    /// G0 (`rapid`) or G1.
    Straight {
        /// True for G0.
        rapid: bool,
    },
    /// G2 (`ccw == false`) or G3 (`ccw == true`).
    Arc {
        /// Programmed centre (in-plane coordinates), computed from the programmed start.
        center: [Real; 2],
        /// True for G3.
        ccw: bool,
        /// LinuxCNC's turn count, the P word: 1 for an arc of less than one revolution,
        /// n for n − 1 extra full revolutions. 0 is taken as 1.
        turns: u32,
    },
}

/// One programmed move handed to the compensator.
#[derive(Debug, Clone, PartialEq)]
pub struct PlaneMove<E> {
    /// Straight or arc.
    pub kind: PlaneMoveKind,
    /// Programmed end point, in-plane coordinates (first, second).
    pub end: [Real; 2],
    /// Programmed normal-axis coordinate at the end (Z in G17).
    pub along: Real,
    /// The interpreter's data for this move (line number, feed, rotary ends, ...): cloned
    /// onto every output the move produces.
    pub payload: E,
}

/// A compensated move or a released event, in program order.
#[derive(Debug, Clone, PartialEq)]
pub enum CompOutput<E> {
    /// A straight move of the tool centre.
    Straight {
        /// True for a traverse (G0).
        rapid: bool,
        /// Tool end point, in-plane coordinates.
        end: [Real; 2],
        /// Normal-axis coordinate at the end.
        along: Real,
        /// Payload of the programmed move this came from.
        payload: E,
    },
    /// An arc of the tool centre (a compensated programmed arc or an inserted corner arc).
    Arc {
        /// Centre, in-plane coordinates.
        center: [Real; 2],
        /// Counter-clockwise (G3 sense) if true.
        ccw: bool,
        /// Turn count as in [`PlaneMoveKind::Arc::turns`] (≥ 1).
        turns: u32,
        /// Tool end point, in-plane coordinates.
        end: [Real; 2],
        /// Normal-axis coordinate at the end (helix).
        along: Real,
        /// Payload of the programmed move this came from.
        payload: E,
    },
    /// An event given to [`Compensator::push_event`], released in order.
    Event(E),
}

/// What [`Compensator::finish`] tells the interpreter about the exit move.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CompEnd {
    /// The radius was not zero: the next motion must be a straight move, from the tool point
    /// to its programmed end; an arc there is [`CompError::ArcAfterCompOff`].
    pub exit_must_be_straight: bool,
}

/// Errors of cutter radius compensation, with LinuxCNC's message texts.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum CompError {
    /// The straight entry move ends within one tool radius of its start.
    #[error("Length of cutter compensation entry move is not greater than the tool radius")]
    EntryMoveTooShort,
    /// The entry arc ends within one tool radius of its start.
    #[error("Radius of cutter compensation entry arc is not greater than the tool radius")]
    EntryArcTooShort,
    /// The tool is inside an arc whose radius is not larger than the tool radius.
    #[error("Tool radius not less than arc radius with comp")]
    ToolRadiusNotLessThanArcRadius,
    /// Moving the held straight feed into a concave corner would reverse it.
    #[error("Straight feed in concave corner cannot be reached by the tool without gouging")]
    StraightFeedGouging,
    /// Moving the held straight traverse into a concave corner would reverse it.
    #[error("Straight traverse in concave corner cannot be reached by the tool without gouging")]
    StraightTraverseGouging,
    /// A concave corner before an arc, or after a held arc, that the tool cannot reach.
    #[error("Arc move in concave corner cannot be reached by the tool without gouging")]
    ArcGouging,
    /// A concave arc-to-arc corner between two arcs of one centre.
    #[error("Arc to arc motion is invalid because the arcs have the same center")]
    ArcsSameCenter,
    /// The offset circles of a concave arc-to-arc corner do not meet.
    #[error("Arc to arc motion makes a corner the compensated tool can't fit in without gouging")]
    ArcToArcGouging,
    /// The offset circle and offset line of a concave arc-to-straight corner do not meet.
    #[error(
        "Arc to straight motion makes a corner the compensated tool can't fit in without gouging"
    )]
    ArcToStraightGouging,
    /// A straight move goes straight back along the previous one.
    #[error("Zero degree inside corner is invalid for cutter compensation")]
    ZeroDegreeInsideCorner,
    /// Raised by the interpreter: an arc as the first motion after G40 (see [`CompEnd`]).
    #[error("The move just after exiting cutter compensation mode must be straight, not an arc")]
    ArcAfterCompOff,
    /// Raised by the interpreter: G41/G42 in G19 ([`Plane::check_comp_allowed`]).
    #[error("Cutter radius compensation allowed only in XY, XZ planes")]
    PlaneNotAllowed,
    /// Internal error: a held arc's end was moved off its circle (a bug, as in LinuxCNC).
    #[error(
        "BUG: cutter compensation has generated an invalid arc with mismatched radii r1 {r1:.6} r2 {r2:.6}"
    )]
    MismatchedArcRadii {
        /// Radius to the old end.
        r1: Real,
        /// Radius to the new end.
        r2: Real,
    },
    /// A coordinate or the radius given to the compensator is NaN or infinite.
    #[error("cutter compensation: {what} is not a finite number")]
    NonFinite {
        /// Which input.
        what: &'static str,
    },
    /// A move was pushed after [`Compensator::finish`] (an interpreter bug).
    #[error("cutter compensation: move after G40 finished the compensation")]
    Finished,
}

/// Cutter radius compensation from G41/G42 to G40. See the module documentation.
#[derive(Debug, Clone)]
pub struct Compensator<E> {
    side: Side,
    radius: Real,
    /// Last programmed (uncompensated) point.
    programmed: [Real; 2],
    /// Where the tool centre is at the end of the last move.
    tool: [Real; 2],
    /// Normal-axis coordinate at the end of the last move.
    along: Real,
    /// No move yet since G41/G42: the next one is the entry move.
    first_move: bool,
    finished: bool,
    /// Start point of the held move, when known (LinuxCNC's `endpoint`/`endpoint_valid`):
    /// the base of the gouging checks when its end is moved.
    hold_start: Option<[Real; 2]>,
    /// The held move(s) and the events behind them.
    held: VecDeque<Held<E>>,
    /// Outputs that can no longer change.
    ready: VecDeque<CompOutput<E>>,
}

#[derive(Debug, Clone)]
enum Held<E> {
    Move(HeldMove<E>),
    Event(E),
}

#[derive(Debug, Clone)]
struct HeldMove<E> {
    shape: HeldShape,
    end: [Real; 2],
    along: Real,
    payload: E,
}

#[derive(Debug, Clone, Copy)]
enum HeldShape {
    Straight {
        rapid: bool,
        /// Direction recorded for the reversal check (not normalised).
        dir: [Real; 2],
    },
    Arc {
        center: [Real; 2],
        ccw: bool,
        turns: u32,
        /// Signed sweep as queued (radians); 0 for corner arcs, which are never moved.
        sweep: Real,
    },
}

impl<E> HeldMove<E> {
    fn into_output(self) -> CompOutput<E> {
        match self.shape {
            HeldShape::Straight { rapid, .. } => CompOutput::Straight {
                rapid,
                end: self.end,
                along: self.along,
                payload: self.payload,
            },
            HeldShape::Arc {
                center, ccw, turns, ..
            } => CompOutput::Arc {
                center,
                ccw,
                turns,
                end: self.end,
                along: self.along,
                payload: self.payload,
            },
        }
    }
}

/// The held arc in front of the queue, as needed by the concave-corner intersections.
#[derive(Debug, Clone, Copy)]
struct PrevArc {
    center: [Real; 2],
    end: [Real; 2],
    ccw: bool,
}

/// The programmed arc being compensated, as needed by the concave-corner intersections.
#[derive(Debug, Clone, Copy)]
struct NextArc {
    center: [Real; 2],
    /// Programmed radius.
    radius: Real,
    ccw: bool,
    /// The tool runs inside it.
    inside: bool,
}

fn sub(a: [Real; 2], b: [Real; 2]) -> [Real; 2] {
    [a[0] - b[0], a[1] - b[1]]
}

fn add_polar(p: [Real; 2], length: Real, angle: Real) -> [Real; 2] {
    [p[0] + length * angle.cos(), p[1] + length * angle.sin()]
}

fn dir_angle(v: [Real; 2]) -> Real {
    v[1].atan2(v[0])
}

fn dist(a: [Real; 2], b: [Real; 2]) -> Real {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

fn finite2(p: [Real; 2], what: &'static str) -> Result<(), CompError> {
    if p[0].is_finite() && p[1].is_finite() {
        Ok(())
    } else {
        Err(CompError::NonFinite { what })
    }
}

fn finite(x: Real, what: &'static str) -> Result<(), CompError> {
    if x.is_finite() {
        Ok(())
    } else {
        Err(CompError::NonFinite { what })
    }
}

/// Signed sweep (radians, positive counter-clockwise) of an arc from `start` to `end` around
/// `center` with LinuxCNC's signed turn count (±P; 0 gives 0). A zero-length arc (start on the
/// end) is a full turn.
fn sweep(start: [Real; 2], center: [Real; 2], turn: i64, end: [Real; 2]) -> Real {
    if turn == 0 {
        return 0.0;
    }
    let mut a = dir_angle(sub(start, center));
    let mut b = dir_angle(sub(end, center));
    if turn > 0 {
        if b <= a {
            b += TAU;
        }
        (b - a) + (turn - 1) as Real * TAU
    } else {
        if a <= b {
            a += TAU;
        }
        (b - a) + (turn + 1) as Real * TAU
    }
}

fn signed_turn(ccw: bool, turns: u32) -> i64 {
    if ccw {
        i64::from(turns)
    } else {
        -i64::from(turns)
    }
}

impl<E> Compensator<E> {
    /// Starts compensation (G41/G42) on `side` with the tool `radius` (program units; a
    /// negative radius swaps the side, 0 makes every move pass through unchanged), the tool
    /// at `start_tool_point` (in-plane) and `start_along` (normal axis).
    pub fn new(
        side: Side,
        radius: Real,
        start_tool_point: [Real; 2],
        start_along: Real,
    ) -> Result<Self, CompError> {
        finite(radius, "tool radius")?;
        finite2(start_tool_point, "start point")?;
        finite(start_along, "start point")?;
        let (side, radius) = if radius < 0.0 {
            (side.opposite(), -radius)
        } else {
            (side, radius)
        };
        Ok(Compensator {
            side,
            radius,
            programmed: start_tool_point,
            tool: start_tool_point,
            along: start_along,
            first_move: true,
            finished: false,
            hold_start: None,
            held: VecDeque::new(),
            ready: VecDeque::new(),
        })
    }

    /// The side in effect (after a negative radius swapped it).
    pub fn side(&self) -> Side {
        self.side
    }

    /// The tool radius in effect (≥ 0).
    pub fn radius(&self) -> Real {
        self.radius
    }

    /// The last programmed (uncompensated) point in the plane: the start of the next
    /// programmed move, base of G91 increments and incremental arc centres.
    pub fn programmed(&self) -> [Real; 2] {
        self.programmed
    }

    /// Where the tool centre is (in the plane) at the end of the last compensated move.
    pub fn tool_point(&self) -> [Real; 2] {
        self.tool
    }

    /// The normal-axis coordinate at the end of the last move (programmed = actual).
    pub fn along(&self) -> Real {
        self.along
    }

    /// Moves the tool point (and the normal-axis coordinate) without a move, the programmed
    /// point staying: LinuxCNC does this when a canonical move bypasses its compensation
    /// queue (a G5.2 … G5.3 curve, or G33 with a zero radius), which sets the interpreter's
    /// current point only. The next move is compensated from there.
    pub fn set_tool_point(&mut self, tool: [Real; 2], along: Real) {
        self.tool = tool;
        self.along = along;
    }

    /// True until the first move after G41/G42 (the entry move) has been pushed.
    pub fn awaiting_entry(&self) -> bool {
        self.first_move
    }

    /// Queues a non-motion canonical call; it is released in order with the moves.
    pub fn push_event(&mut self, event: E) {
        if self.held.is_empty() {
            self.ready.push_back(CompOutput::Event(event));
        } else {
            self.held.push_back(Held::Event(event));
        }
    }

    /// The outputs that can no longer change, in program order.
    pub fn drain(&mut self) -> Drain<'_, CompOutput<E>> {
        self.ready.drain(..)
    }
}

impl<E: Clone> Compensator<E> {
    /// Releases the held move unchanged and the events behind it, compensation staying on:
    /// LinuxCNC does this for M0, M1 and M60 (and for M2/M30, where it then ends
    /// compensation without the exit rule: call [`Compensator::finish`] and ignore
    /// [`CompEnd::exit_must_be_straight`]). A concave corner right after it finds no held
    /// move to pull back (LinuxCNC's behaviour is undefined there); the tool then goes
    /// straight from its position to the new offset end.
    pub fn release_held(&mut self) -> Result<(), CompError> {
        self.move_end_and_flush(self.tool)?;
        self.flush();
        Ok(())
    }

    /// G40: releases the held move unchanged and every event. Afterwards the interpreter's
    /// position is [`Compensator::programmed`]; the machine is at [`Compensator::tool_point`].
    ///
    /// Like LinuxCNC's G40 it runs the gouging checks on the held move (a straight that
    /// ended up running backwards from the last concave corner is refused); on an error
    /// nothing is released and compensation stays on (LinuxCNC drops its queue and stops).
    pub fn finish(&mut self) -> Result<CompEnd, CompError> {
        if self.finished {
            return Err(CompError::Finished);
        }
        if self.radius > 0.0 {
            self.move_end_and_flush(self.tool)?;
        }
        self.flush();
        self.finished = true;
        Ok(CompEnd {
            exit_must_be_straight: self.radius > 0.0,
        })
    }

    /// Compensates one programmed move in the plane.
    pub fn push_move(&mut self, mv: PlaneMove<E>) -> Result<(), CompError> {
        if self.finished {
            return Err(CompError::Finished);
        }
        finite2(mv.end, "end point")?;
        finite(mv.along, "end point")?;
        if let PlaneMoveKind::Arc { center, .. } = mv.kind {
            finite2(center, "arc centre")?;
        }
        if self.radius == 0.0 {
            self.pass_through(mv);
            return Ok(());
        }
        let PlaneMove {
            kind,
            end,
            along,
            payload,
        } = mv;
        match kind {
            PlaneMoveKind::Straight { rapid } if self.first_move => {
                self.straight_entry(rapid, end, along, payload)
            }
            PlaneMoveKind::Straight { rapid } => self.straight_follow(rapid, end, along, payload),
            PlaneMoveKind::Arc { center, ccw, turns } => {
                let turns = turns.max(1);
                if self.first_move {
                    self.arc_entry(center, ccw, turns, end, along, payload)
                } else {
                    self.arc_follow(center, ccw, turns, end, along, payload)
                }
            }
        }
    }

    /// Radius 0: LinuxCNC issues the move as programmed and stays "before the entry move".
    fn pass_through(&mut self, mv: PlaneMove<E>) {
        let out = match mv.kind {
            PlaneMoveKind::Straight { rapid } => CompOutput::Straight {
                rapid,
                end: mv.end,
                along: mv.along,
                payload: mv.payload,
            },
            PlaneMoveKind::Arc { center, ccw, turns } => CompOutput::Arc {
                center,
                ccw,
                turns: turns.max(1),
                end: mv.end,
                along: mv.along,
                payload: mv.payload,
            },
        };
        self.flush();
        self.ready.push_back(out);
        self.programmed = mv.end;
        self.tool = mv.end;
        self.along = mv.along;
    }

    /// +1 for left, −1 for right: the offset direction is the travel direction turned by
    /// `side_sign() · 90°`.
    fn side_sign(&self) -> Real {
        match self.side {
            Side::Left => 1.0,
            Side::Right => -1.0,
        }
    }

    fn hold(&mut self, shape: HeldShape, end: [Real; 2], along: Real, payload: E) {
        self.held.push_back(Held::Move(HeldMove {
            shape,
            end,
            along,
            payload,
        }));
    }

    /// Releases every held move and event as they are.
    fn flush(&mut self) {
        for h in self.held.drain(..) {
            self.ready.push_back(match h {
                Held::Move(m) => m.into_output(),
                Held::Event(e) => CompOutput::Event(e),
            });
        }
        self.hold_start = None;
    }

    /// The held arc at the front of the queue (the last move in the plane), if it is an arc.
    fn front_arc(&self) -> Option<PrevArc> {
        let front = self.held.iter().find_map(|h| match h {
            Held::Move(m) => Some(m),
            Held::Event(_) => None,
        })?;
        match front.shape {
            HeldShape::Arc { center, ccw, .. } => Some(PrevArc {
                center,
                end: front.end,
                ccw,
            }),
            HeldShape::Straight { .. } => None,
        }
    }

    /// Moves the end of every held move to `to` (the last move in the plane and the moves
    /// without motion in the plane behind it), checks for gouging, and releases them.
    fn move_end_and_flush(&mut self, to: [Real; 2]) -> Result<(), CompError> {
        if self.held.is_empty() {
            return Ok(());
        }
        // Check every held move before changing any, so an error leaves the state as it was.
        for h in &self.held {
            if let Held::Move(m) = h {
                self.check_move_end(m, to)?;
            }
        }
        for h in &mut self.held {
            if let Held::Move(m) = h {
                m.end = to;
            }
        }
        self.flush();
        self.hold_start = Some(to);
        Ok(())
    }

    /// LinuxCNC's checks before a held move's end is moved to `to`: a straight must not
    /// reverse, an arc must stay on its circle and not sweep further than programmed.
    fn check_move_end(&self, m: &HeldMove<E>, to: [Real; 2]) -> Result<(), CompError> {
        match m.shape {
            HeldShape::Arc {
                center,
                ccw,
                turns,
                sweep: old_sweep,
            } => {
                let r1 = dist(m.end, center);
                let r2 = dist(to, center);
                if (r1 - r2).abs() > RADIUS_MISMATCH {
                    return Err(CompError::MismatchedArcRadii { r1, r2 });
                }
                if let Some(s) = self.hold_start
                    && old_sweep != 0.0
                {
                    let new_sweep = sweep(s, center, signed_turn(ccw, turns), to);
                    if new_sweep.abs() > old_sweep.abs() + SWEEP_SLACK {
                        return Err(CompError::ArcGouging);
                    }
                }
            }
            HeldShape::Straight { rapid, dir } => {
                if let Some(s) = self.hold_start {
                    let v = sub(to, s);
                    if dir[0] * v[0] + dir[1] * v[1] < 0.0 {
                        return Err(if rapid {
                            CompError::StraightTraverseGouging
                        } else {
                            CompError::StraightFeedGouging
                        });
                    }
                }
            }
        }
        Ok(())
    }

    fn straight_entry(
        &mut self,
        rapid: bool,
        p: [Real; 2],
        along: Real,
        payload: E,
    ) -> Result<(), CompError> {
        let c = self.tool;
        let r = self.radius;
        if dist(p, c) <= r {
            return Err(CompError::EntryMoveTooShort);
        }
        let normal = dir_angle(sub(p, c)) + self.side_sign() * FRAC_PI_2;
        let end = add_polar(p, r, normal);
        self.hold_start = Some(c);
        // LinuxCNC records the offset normal, not the travel direction, for the reversal
        // check of the entry move.
        let dir = [normal.cos(), normal.sin()];
        self.hold(HeldShape::Straight { rapid, dir }, end, along, payload);
        self.first_move = false;
        self.tool = end;
        self.programmed = p;
        self.along = along;
        Ok(())
    }

    fn arc_entry(
        &mut self,
        center: [Real; 2],
        ccw: bool,
        turns: u32,
        p: [Real; 2],
        along: Real,
        payload: E,
    ) -> Result<(), CompError> {
        let c = self.tool;
        let r = self.radius;
        if dist(p, c) <= r {
            return Err(CompError::EntryArcTooShort);
        }
        let inside = self.side.inside(ccw);
        if inside && dist(center, c) <= r {
            return Err(CompError::ToolRadiusNotLessThanArcRadius);
        }
        let gamma = if inside {
            dir_angle(sub(center, p))
        } else {
            dir_angle(sub(p, center))
        };
        let end = add_polar(p, r, gamma);
        // The new centre lies on the line from the new end towards the programmed centre,
        // equidistant from the tool's start and the new end.
        let half_chord = dist(c, end) / 2.0;
        let to_center = dir_angle(sub(center, end));
        let cos_a = (dir_angle(sub(c, end)) - to_center).cos();
        if cos_a.abs() < ENTRY_ARC_COS_EPS {
            return Err(CompError::ToolRadiusNotLessThanArcRadius);
        }
        let new_center = add_polar(end, half_chord / cos_a, to_center);
        let sw = sweep(c, new_center, signed_turn(ccw, turns), end);
        self.hold(
            HeldShape::Arc {
                center: new_center,
                ccw,
                turns,
                sweep: sw,
            },
            end,
            along,
            payload,
        );
        self.first_move = false;
        self.programmed = p;
        self.tool = end;
        self.along = along;
        Ok(())
    }

    fn straight_follow(
        &mut self,
        rapid: bool,
        p: [Real; 2],
        along: Real,
        payload: E,
    ) -> Result<(), CompError> {
        let c = self.tool;
        let op = self.programmed;
        let old_along = self.along;
        let r = self.radius;
        if p == op {
            // No motion in the plane: the tool stays where it is.
            self.hold(
                HeldShape::Straight {
                    rapid,
                    dir: [0.0, 0.0],
                },
                c,
                along,
                payload,
            );
            self.along = along;
            return Ok(());
        }
        // theta: direction from the old programmed point to the tool (the previous offset
        // normal); alpha: the new programmed direction; beta: turn from the previous
        // direction to the new one measured against the compensation side (positive =
        // convex, the tool goes around the outside of the corner).
        let mut theta = dir_angle(sub(c, op));
        let mut alpha = dir_angle(sub(p, op));
        let (beta, gamma) = match self.side {
            Side::Left => {
                if theta < alpha {
                    theta += TAU;
                }
                (theta - alpha - FRAC_PI_2, FRAC_PI_2)
            }
            Side::Right => {
                if alpha < theta {
                    alpha += TAU;
                }
                (alpha - theta - FRAC_PI_2, -FRAC_PI_2)
            }
        };
        let end = add_polar(p, r, alpha + gamma);
        let corner_end = add_polar(op, r, alpha + gamma);
        let prev_arc = self.front_arc();
        let small = CONCAVE_CORNER_ANGLE;
        // "h" shape: coming off an arc the tool is outside of, turning back by ~180°: LinuxCNC
        // stays on the outside rather than looping around.
        let h_shape = beta > PI - small
            && prev_arc.is_some_and(|a| match self.side {
                Side::Right => a.ccw,
                Side::Left => !a.ccw,
            });
        let concave = beta < -small || beta > PI + small || h_shape;
        if !concave && beta > small {
            self.move_end_and_flush(c)?;
            let shape = if rapid {
                HeldShape::Straight {
                    rapid: true,
                    dir: [0.0, 0.0],
                }
            } else {
                HeldShape::Arc {
                    center: op,
                    ccw: self.side == Side::Right,
                    turns: 1,
                    sweep: 0.0,
                }
            };
            self.hold(shape, corner_end, old_along, payload.clone());
            self.flush();
            self.hold_start = Some(corner_end);
        } else if concave {
            let meet = match prev_arc {
                None => {
                    let half_corner = (beta + PI) / 2.0;
                    if half_corner == 0.0 {
                        return Err(CompError::ZeroDegreeInsideCorner);
                    }
                    let retreat = r / half_corner.tan();
                    add_polar(c, retreat, theta + gamma)
                }
                Some(prev) => self.arc_line_corner(prev, op, p)?,
            };
            self.move_end_and_flush(meet)?;
        } else {
            self.flush();
            self.hold_start = Some(c);
        }
        self.hold(
            HeldShape::Straight {
                rapid,
                dir: sub(p, op),
            },
            end,
            along,
            payload,
        );
        self.tool = end;
        self.programmed = p;
        self.along = along;
        Ok(())
    }

    /// Concave corner from the held (compensated) arc `prev` into the straight `op → p`: the
    /// point of the offset arc where the offset line meets it.
    fn arc_line_corner(
        &self,
        prev: PrevArc,
        op: [Real; 2],
        p: [Real; 2],
    ) -> Result<[Real; 2], CompError> {
        let r = self.radius;
        let old_radius = dist(prev.center, prev.end);
        let base = dir_angle(sub(p, op));
        let theta = if prev.ccw {
            base + FRAC_PI_2
        } else {
            base - FRAC_PI_2
        };
        let phi = dir_angle(sub(prev.center, op));
        let inside = self.side.inside(prev.ccw);
        let programmed_radius = if inside {
            old_radius + r
        } else {
            old_radius - r
        };
        // Distance from the old centre to the programmed line, then to the offset line.
        let d = programmed_radius * (theta - phi).cos();
        let l = (if inside { d - r } else { d + r }) / old_radius;
        if !(-1.0..=1.0).contains(&l) {
            return Err(CompError::ArcToStraightGouging);
        }
        let turn_back = if inside == prev.ccw {
            -l.acos()
        } else {
            l.acos()
        };
        Ok(add_polar(prev.center, old_radius, turn_back + theta + PI))
    }

    /// Concave corner from the held straight into the arc `next`: the point of the offset
    /// line (previous direction `theta`, corner angle `beta`) on the arc's offset circle.
    fn line_arc_corner(
        &self,
        next: NextArc,
        theta: Real,
        beta: Real,
    ) -> Result<[Real; 2], CompError> {
        let r = self.radius;
        // Signed distance from the programmed line to the arc centre, across the line.
        let foot = next.radius * (beta - FRAC_PI_2).sin();
        let (tool_radius, l) = if next.inside {
            (next.radius - r, (foot + r) / (next.radius - r))
        } else {
            (next.radius + r, (foot - r) / (next.radius + r))
        };
        if !(-1.0..=1.0).contains(&l) {
            return Err(CompError::ArcGouging);
        }
        let angle = match (next.inside, next.ccw) {
            (true, true) => theta + l.asin(),
            (true, false) => theta - l.asin(),
            (false, true) => theta + PI - l.asin(),
            (false, false) => theta + PI + l.asin(),
        };
        Ok(add_polar(next.center, tool_radius, angle))
    }

    /// Concave corner from the held (compensated) arc `prev` into the arc `next`: where the
    /// two offset circles meet, on the side LinuxCNC picks from the turning senses.
    fn arc_arc_corner(&self, prev: PrevArc, next: NextArc) -> Result<[Real; 2], CompError> {
        let old_radius = dist(prev.center, prev.end);
        let new_radius = if next.inside {
            next.radius - self.radius
        } else {
            next.radius + self.radius
        };
        let centers = dist(prev.center, next.center);
        if old_radius == 0.0 || centers == 0.0 {
            return Err(CompError::ArcsSameCenter);
        }
        // Law of cosines in the triangle (old centre, new centre, meeting point).
        let a = (old_radius * old_radius + centers * centers - new_radius * new_radius)
            / (2.0 * old_radius * centers);
        if !(-1.0..=1.0).contains(&a) {
            return Err(CompError::ArcToArcGouging);
        }
        let pullback = a.acos();
        let cc_dir = dir_angle(sub(next.center, prev.center));
        let dir = if self.side.inside(prev.ccw) == next.ccw {
            cc_dir + pullback
        } else {
            cc_dir - pullback
        };
        Ok(add_polar(prev.center, old_radius, dir))
    }

    fn arc_follow(
        &mut self,
        center: [Real; 2],
        ccw: bool,
        turns: u32,
        p: [Real; 2],
        along: Real,
        payload: E,
    ) -> Result<(), CompError> {
        let c = self.tool;
        let op = self.programmed;
        let old_along = self.along;
        let r = self.radius;
        let arc_radius = dist(center, p);
        // theta: previous direction of travel; alpha: the arc's tangent at its start.
        let theta = dir_angle(sub(c, op)) - self.side_sign() * FRAC_PI_2;
        let mut delta = dir_angle(sub(center, op));
        let alpha = if ccw {
            delta - FRAC_PI_2
        } else {
            delta + FRAC_PI_2
        };
        let mut beta = match self.side {
            Side::Left => theta - alpha,
            Side::Right => alpha - theta,
        };
        if beta > 1.5 * PI {
            beta -= TAU;
        } else if beta < -FRAC_PI_2 {
            beta += TAU;
        }
        let inside = self.side.inside(ccw);
        let gamma = if inside {
            if arc_radius <= r {
                return Err(CompError::ToolRadiusNotLessThanArcRadius);
            }
            dir_angle(sub(center, p))
        } else {
            delta += PI;
            dir_angle(sub(p, center))
        };
        let end = add_polar(p, r, gamma);
        let turn = signed_turn(ccw, turns);
        let sw = sweep(op, center, turn, p);
        let small = CONCAVE_CORNER_ANGLE;
        let arc_shape = HeldShape::Arc {
            center,
            ccw,
            turns,
            sweep: sw,
        };
        if beta < -small || beta > PI + small || ((beta - PI).abs() < small && !inside) {
            let next = NextArc {
                center,
                radius: arc_radius,
                ccw,
                inside,
            };
            let meet = match self.front_arc() {
                None => self.line_arc_corner(next, theta, beta)?,
                Some(prev) => self.arc_arc_corner(prev, next)?,
            };
            self.move_end_and_flush(meet)?;
            self.hold(arc_shape, end, along, payload);
        } else if beta > small {
            let corner_end = add_polar(op, r, delta);
            self.flush();
            self.hold(
                HeldShape::Arc {
                    center: op,
                    ccw: self.side == Side::Right,
                    turns: 1,
                    sweep: 0.0,
                },
                corner_end,
                old_along,
                payload.clone(),
            );
            self.flush();
            self.hold_start = Some(corner_end);
            self.hold(arc_shape, end, along, payload);
        } else {
            self.flush();
            self.hold_start = Some(c);
            self.hold(arc_shape, end, along, payload);
        }
        self.programmed = p;
        self.tool = end;
        self.along = along;
        Ok(())
    }
}

#[cfg(test)]
mod tests;
