//! Tests of the compensator on constructed paths: corner arcs and intersections of offset
//! lines and circles, entry and exit moves, LinuxCNC's gouging and exit-rule errors,
//! regular polygons, invariance under units, rotation and shift, and random programs.
//! LinuxCNC's own regression programs are in `linuxcnc_corpus`.

use super::*;

/// Geometry here is exact up to a few ulps of values of order 10.
const GEOM_EPS: Real = 1e-9;

#[derive(Debug, Clone, PartialEq)]
enum Tag {
    Move(u32),
    Note(&'static str),
}

fn straight(end: [Real; 2], n: u32) -> PlaneMove<Tag> {
    PlaneMove {
        kind: PlaneMoveKind::Straight { rapid: false },
        end,
        along: 0.0,
        payload: Tag::Move(n),
    }
}

fn rapid(end: [Real; 2], n: u32) -> PlaneMove<Tag> {
    PlaneMove {
        kind: PlaneMoveKind::Straight { rapid: true },
        end,
        along: 0.0,
        payload: Tag::Move(n),
    }
}

fn arc(end: [Real; 2], center: [Real; 2], ccw: bool, n: u32) -> PlaneMove<Tag> {
    PlaneMove {
        kind: PlaneMoveKind::Arc {
            center,
            ccw,
            turns: 1,
        },
        end,
        along: 0.0,
        payload: Tag::Move(n),
    }
}

/// Expected output, compared within `GEOM_EPS`.
#[derive(Debug, Clone, PartialEq)]
enum Want {
    Line([Real; 2]),
    Rapid([Real; 2]),
    /// End, centre, ccw.
    Arc([Real; 2], [Real; 2], bool),
    Note(&'static str),
}

fn near2(a: [Real; 2], b: [Real; 2], eps: Real) -> bool {
    (a[0] - b[0]).abs() <= eps && (a[1] - b[1]).abs() <= eps
}

fn check(outputs: &[CompOutput<Tag>], want: &[Want]) {
    assert_eq!(
        outputs.len(),
        want.len(),
        "outputs {outputs:#?}\nwant {want:#?}"
    );
    for (i, (o, w)) in outputs.iter().zip(want).enumerate() {
        let ok = match (o, w) {
            (CompOutput::Straight { rapid, end, .. }, Want::Line(e)) => {
                !rapid && near2(*end, *e, GEOM_EPS)
            }
            (CompOutput::Straight { rapid, end, .. }, Want::Rapid(e)) => {
                *rapid && near2(*end, *e, GEOM_EPS)
            }
            (
                CompOutput::Arc {
                    center, ccw, end, ..
                },
                Want::Arc(e, c, w_ccw),
            ) => ccw == w_ccw && near2(*end, *e, GEOM_EPS) && near2(*center, *c, GEOM_EPS),
            (CompOutput::Event(Tag::Note(s)), Want::Note(t)) => s == t,
            _ => false,
        };
        assert!(ok, "output {i}: got {o:?}, want {w:?}\nall: {outputs:#?}");
    }
}

fn run(side: Side, r: Real, start: [Real; 2], moves: Vec<PlaneMove<Tag>>) -> Vec<CompOutput<Tag>> {
    let mut comp = Compensator::new(side, r, start, 0.0).unwrap();
    for m in moves {
        comp.push_move(m).unwrap();
    }
    comp.finish().unwrap();
    comp.drain().collect()
}

/// Intersection of two circles nearest to `near` (independent of the module's
/// angle-based construction: radical line and chord half-length).
fn circle_circle(c1: [Real; 2], r1: Real, c2: [Real; 2], r2: Real, near: [Real; 2]) -> [Real; 2] {
    let d = dist(c1, c2);
    let a = (r1 * r1 - r2 * r2 + d * d) / (2.0 * d);
    let h = (r1 * r1 - a * a).sqrt();
    let u = [(c2[0] - c1[0]) / d, (c2[1] - c1[1]) / d];
    let m = [c1[0] + a * u[0], c1[1] + a * u[1]];
    let p1 = [m[0] - h * u[1], m[1] + h * u[0]];
    let p2 = [m[0] + h * u[1], m[1] - h * u[0]];
    if dist(p1, near) <= dist(p2, near) {
        p1
    } else {
        p2
    }
}

#[test]
fn outside_of_clockwise_square_gets_corner_arcs() {
    // G41 on a clockwise square: the tool is outside, every corner is convex and is
    // rounded by an arc of the tool radius around the programmed corner.
    let r = 1.0;
    let out = run(
        Side::Left,
        r,
        [0.0, -5.0],
        vec![
            straight([0.0, 0.0], 1),
            straight([0.0, 10.0], 2),
            straight([10.0, 10.0], 3),
            straight([10.0, 0.0], 4),
            straight([0.0, 0.0], 5),
            straight([0.0, 10.0], 6),
        ],
    );
    check(
        &out,
        &[
            Want::Line([-r, 0.0]),
            Want::Line([-r, 10.0]),
            Want::Arc([0.0, 10.0 + r], [0.0, 10.0], false),
            Want::Line([10.0, 10.0 + r]),
            Want::Arc([10.0 + r, 10.0], [10.0, 10.0], false),
            Want::Line([10.0 + r, 0.0]),
            Want::Arc([10.0, -r], [10.0, 0.0], false),
            Want::Line([0.0, -r]),
            Want::Arc([-r, 0.0], [0.0, 0.0], false),
            Want::Line([-r, 10.0]),
        ],
    );
}

#[test]
fn inside_of_counter_clockwise_square_meets_offset_lines() {
    // G41 on a counter-clockwise square: the tool is inside, every corner is concave and
    // the held move ends where the offset edges meet (the inner offset square).
    let r = 1.0;
    let out = run(
        Side::Left,
        r,
        [5.0, 5.0],
        vec![
            straight([5.0, 0.0], 1),
            straight([10.0, 0.0], 2),
            straight([10.0, 10.0], 3),
            straight([0.0, 10.0], 4),
            straight([0.0, 0.0], 5),
        ],
    );
    check(
        &out,
        &[
            Want::Line([5.0 + r, r]),
            Want::Line([10.0 - r, r]),
            Want::Line([10.0 - r, 10.0 - r]),
            Want::Line([r, 10.0 - r]),
            // The last move is released by G40 as it is: one radius off its end.
            Want::Line([r, 0.0]),
        ],
    );
}

#[test]
fn right_side_mirrors_left_side() {
    // G42 on the counter-clockwise square is outside: convex corners, counter-clockwise
    // corner arcs.
    let r = 0.5;
    let out = run(
        Side::Right,
        r,
        [-5.0, 0.0],
        vec![
            straight([0.0, 0.0], 1),
            straight([10.0, 0.0], 2),
            straight([10.0, 10.0], 3),
        ],
    );
    check(
        &out,
        &[
            Want::Line([0.0, -r]),
            Want::Line([10.0, -r]),
            Want::Arc([10.0 + r, 0.0], [10.0, 0.0], true),
            Want::Line([10.0 + r, 10.0]),
        ],
    );
}

#[test]
fn full_circle_outside_after_concave_entry() {
    // G42 around a counter-clockwise circle of radius 5: the tool runs on radius 5 + r.
    // The entry line y = 0 (towards −x, tool on its right at y = +r) meets the offset
    // circle at (√((5 + r)² − r²), r).
    let r = 0.25;
    let out = run(
        Side::Right,
        r,
        [10.0, 0.0],
        vec![
            straight([5.0, 0.0], 1),
            arc([5.0, 0.0], [0.0, 0.0], true, 2),
        ],
    );
    let x = ((5.0 + r) * (5.0 + r) - r * r).sqrt();
    check(
        &out,
        &[
            Want::Line([x, r]),
            Want::Arc([5.0 + r, 0.0], [0.0, 0.0], true),
        ],
    );
}

#[test]
fn tangent_arc_entry_and_inside_circle() {
    // G41 inside a counter-clockwise circle of radius 5 entered along a tangent line:
    // no corner, the tool runs on radius 5 − r.
    let r = 1.0;
    let out = run(
        Side::Left,
        r,
        [5.0, -5.0],
        vec![
            straight([5.0, 0.0], 1),
            arc([5.0, 0.0], [0.0, 0.0], true, 2),
        ],
    );
    check(
        &out,
        &[
            Want::Line([5.0 - r, 0.0]),
            Want::Arc([5.0 - r, 0.0], [0.0, 0.0], true),
        ],
    );
}

#[test]
fn concave_line_to_arc_meets_offset_circle() {
    // Line along +x (tool on y = +r), then a counter-clockwise arc around (5, 0) turning
    // left by 90°: the tool is inside the arc, on radius 5 − r.
    let r = 1.0;
    let out = run(
        Side::Left,
        r,
        [0.0, 0.0],
        vec![
            straight([10.0, 0.0], 1),
            arc([5.0, 5.0], [5.0, 0.0], true, 2),
        ],
    );
    let x = 5.0 + ((5.0 - r) * (5.0 - r) - r * r).sqrt();
    check(
        &out,
        &[
            Want::Line([x, r]),
            Want::Arc([5.0, 5.0 - r], [5.0, 0.0], true),
        ],
    );
}

#[test]
fn concave_line_to_clockwise_arc_inside_and_outside() {
    let r = 1.0;
    // G42, line along +x (tool on y = −r), right turn into a clockwise arc around (5, 0):
    // the tool is inside, on radius 5 − r.
    let out = run(
        Side::Right,
        r,
        [0.0, 0.0],
        vec![
            straight([10.0, 0.0], 1),
            arc([5.0, -5.0], [5.0, 0.0], false, 2),
        ],
    );
    let x = 5.0 + ((5.0 - r) * (5.0 - r) - r * r).sqrt();
    check(
        &out,
        &[
            Want::Line([x, -r]),
            Want::Arc([5.0, -5.0 + r], [5.0, 0.0], false),
        ],
    );
    // G41, line along +x (tool on y = +r), left turn into a clockwise arc around (15, 0):
    // the tool is outside, on radius 5 + r, and meets the offset line left of the centre.
    let out = run(
        Side::Left,
        r,
        [0.0, 0.0],
        vec![
            straight([10.0, 0.0], 1),
            arc([15.0, 5.0], [15.0, 0.0], false, 2),
        ],
    );
    let x = 15.0 - ((5.0 + r) * (5.0 + r) - r * r).sqrt();
    check(
        &out,
        &[
            Want::Line([x, r]),
            Want::Arc([15.0, 5.0 + r], [15.0, 0.0], false),
        ],
    );
}

#[test]
fn nearly_tangent_arc_across_the_angle_wrap() {
    // Along +y, then a counter-clockwise arc turning left by only 0.01 rad, whose centre
    // direction from the corner is just past −π: the corner angle must wrap to 0.01, a
    // tangent join (no corner arc, nothing moved), not a concave corner.
    let r = 1.0;
    let center = add_polar([0.0, 0.0], 5.0, -PI + 0.01);
    let end = add_polar(center, 5.0, 0.01 + FRAC_PI_2);
    let out = run(
        Side::Left,
        r,
        [0.0, -10.0],
        vec![straight([0.0, 0.0], 1), arc(end, center, true, 2)],
    );
    check(
        &out,
        &[
            Want::Line([-r, 0.0]),
            Want::Arc(add_polar(center, 5.0 - r, 0.01 + FRAC_PI_2), center, true),
        ],
    );
}

#[test]
fn concave_arc_to_line_meets_offset_line() {
    // Inside a counter-clockwise arc of radius 10 (tool on radius 9), then straight down
    // the y axis (tool on x = +r): the arc ends at (r, √(9² − r²)).
    let r = 1.0;
    let out = run(
        Side::Left,
        r,
        [10.0, -5.0],
        vec![
            straight([10.0, 0.0], 1),
            arc([0.0, 10.0], [0.0, 0.0], true, 2),
            straight([0.0, 0.0], 3),
        ],
    );
    let y = (9.0_f64 * 9.0 - r * r).sqrt();
    check(
        &out,
        &[
            Want::Line([10.0 - r, 0.0]),
            Want::Arc([r, y], [0.0, 0.0], true),
            Want::Line([r, 0.0]),
        ],
    );
}

#[test]
fn concave_arc_to_arc_meets_offset_circles() {
    // Inside arc of radius 10 around the origin, then inside arc of radius 5 around
    // (5, 10) turning left at (0, 10): the first arc ends where the circles of radius
    // 10 − r and 5 − r meet.
    let r = 1.0;
    let out = run(
        Side::Left,
        r,
        [10.0, -5.0],
        vec![
            straight([10.0, 0.0], 1),
            arc([0.0, 10.0], [0.0, 0.0], true, 2),
            arc([5.0, 5.0], [5.0, 10.0], true, 3),
        ],
    );
    let meet = circle_circle([0.0, 0.0], 10.0 - r, [5.0, 10.0], 5.0 - r, [0.0, 10.0]);
    check(
        &out,
        &[
            Want::Line([10.0 - r, 0.0]),
            Want::Arc(meet, [0.0, 0.0], true),
            Want::Arc([5.0, 5.0 + r], [5.0, 10.0], true),
        ],
    );
}

#[test]
fn convex_line_to_arc_inserts_corner_arc() {
    // Line along +x (tool above), then a clockwise arc around (5, 0) turning right: the
    // tool is outside; a clockwise corner arc around (10, 0) takes it from (10, r) to
    // (10 + r, 0), then it follows radius 5 + r.
    let r = 1.0;
    let out = run(
        Side::Left,
        r,
        [0.0, 0.0],
        vec![
            straight([10.0, 0.0], 1),
            arc([5.0, -5.0], [5.0, 0.0], false, 2),
        ],
    );
    check(
        &out,
        &[
            Want::Line([10.0, r]),
            Want::Arc([10.0 + r, 0.0], [10.0, 0.0], false),
            Want::Arc([5.0, -5.0 - r], [5.0, 0.0], false),
        ],
    );
}

#[test]
fn corner_arc_keeps_old_normal_coordinate_and_payload_of_new_move() {
    let mut comp = Compensator::new(Side::Left, 1.0, [0.0, 0.0], 3.0).unwrap();
    comp.push_move(PlaneMove {
        along: 2.0,
        ..straight([10.0, 0.0], 1)
    })
    .unwrap();
    comp.push_move(PlaneMove {
        along: 1.0,
        ..straight([10.0, -10.0], 2)
    })
    .unwrap();
    comp.finish().unwrap();
    let out: Vec<_> = comp.drain().collect();
    assert_eq!(out.len(), 3);
    assert!(matches!(
        out[1],
        CompOutput::Arc { along, payload: Tag::Move(2), .. } if along == 2.0
    ));
    assert!(matches!(
        out[2],
        CompOutput::Straight { along, payload: Tag::Move(2), .. } if along == 1.0
    ));
}

#[test]
fn rapid_around_convex_corner_is_a_traverse_to_the_corner_arc_end() {
    let r = 1.0;
    let out = run(
        Side::Left,
        r,
        [0.0, 0.0],
        vec![straight([10.0, 0.0], 1), rapid([10.0, -10.0], 2)],
    );
    check(
        &out,
        &[
            Want::Line([10.0, r]),
            Want::Rapid([10.0 + r, 0.0]),
            Want::Rapid([10.0 + r, -10.0]),
        ],
    );
}

#[test]
fn moves_without_plane_motion_and_events_stay_in_order_behind_the_held_move() {
    let r = 1.0;
    let mut comp = Compensator::new(Side::Left, r, [5.0, 5.0], 1.0).unwrap();
    comp.push_event(Tag::Note("before"));
    comp.push_move(straight([5.0, 0.0], 1)).unwrap();
    comp.push_event(Tag::Note("a"));
    // Plunge: no motion in the plane.
    comp.push_move(PlaneMove {
        along: -1.0,
        ..straight([5.0, 0.0], 2)
    })
    .unwrap();
    comp.push_event(Tag::Note("b"));
    let early: Vec<_> = comp.drain().collect();
    check(&early, &[Want::Note("before")]);
    // Concave corner: the entry move and the plunge both end at the corner point.
    comp.push_move(straight([10.0, 0.0], 3)).unwrap();
    let out: Vec<_> = comp.drain().collect();
    check(
        &out,
        &[
            Want::Line([5.0 + r, r]),
            Want::Note("a"),
            Want::Line([5.0 + r, r]),
            Want::Note("b"),
        ],
    );
    assert!(matches!(out[2], CompOutput::Straight { along, .. } if along == -1.0));
    assert_eq!(comp.programmed(), [10.0, 0.0]);
    assert!(near2(comp.tool_point(), [10.0, r], GEOM_EPS));
    comp.push_event(Tag::Note("off"));
    let end = comp.finish().unwrap();
    assert!(end.exit_must_be_straight);
    check(
        &comp.drain().collect::<Vec<_>>(),
        &[Want::Line([10.0, r]), Want::Note("off")],
    );
}

#[test]
fn zero_radius_passes_moves_through() {
    let mut comp = Compensator::new(Side::Right, 0.0, [0.0, 0.0], 0.0).unwrap();
    comp.push_move(straight([1.0, 0.0], 1)).unwrap();
    comp.push_move(arc([2.0, 1.0], [1.0, 1.0], true, 2))
        .unwrap();
    assert!(comp.awaiting_entry());
    let end = comp.finish().unwrap();
    assert!(!end.exit_must_be_straight);
    check(
        &comp.drain().collect::<Vec<_>>(),
        &[
            Want::Line([1.0, 0.0]),
            Want::Arc([2.0, 1.0], [1.0, 1.0], true),
        ],
    );
}

#[test]
fn negative_radius_swaps_side() {
    let comp = Compensator::<Tag>::new(Side::Left, -0.5, [0.0, 0.0], 0.0).unwrap();
    assert_eq!(comp.side(), Side::Right);
    assert_eq!(comp.radius(), 0.5);
    let out = run(Side::Left, -0.5, [0.0, 0.0], vec![straight([1.0, 0.0], 1)]);
    check(&out, &[Want::Line([1.0, -0.5])]);
}

#[test]
fn gouging_concave_corner_is_an_error_after_releasing_what_was_done() {
    // tests/interp/bad/ccomp-gouging.ngc: G41.1 D.25, a 0.1 step up then back: the
    // step is shorter than the radius, so its compensated end would run backwards.
    let mut comp = Compensator::new(Side::Left, 0.125, [0.0, 0.0], 0.0).unwrap();
    comp.push_move(straight([1.0, 0.0], 1)).unwrap();
    comp.push_move(straight([2.0, 0.0], 2)).unwrap();
    comp.push_move(straight([2.0, 0.1], 3)).unwrap();
    let err = comp.push_move(straight([1.0, 0.1], 4)).unwrap_err();
    assert_eq!(err, CompError::StraightFeedGouging);
    assert_eq!(
        err.to_string(),
        "Straight feed in concave corner cannot be reached by the tool without gouging"
    );
    check(
        &comp.drain().collect::<Vec<_>>(),
        &[Want::Line([1.0, 0.125]), Want::Line([1.875, 0.125])],
    );
    // The refused move changed nothing: the program can go on as if it were absent.
    assert_eq!(comp.programmed(), [2.0, 0.1]);
    assert!(near2(comp.tool_point(), [1.875, 0.1], GEOM_EPS));
    comp.push_move(straight([2.0, 1.0], 5)).unwrap();
    comp.finish().unwrap();
    check(
        &comp.drain().collect::<Vec<_>>(),
        &[Want::Line([1.875, 0.1]), Want::Line([1.875, 1.0])],
    );
}

#[test]
fn g40_refuses_a_held_straight_that_runs_backwards() {
    // A 0.1 step after a concave corner with radius 0.125: the compensated step runs from
    // y = 0.125 down to y = 0.1, against its programmed direction.
    let mut comp = Compensator::new(Side::Left, 0.125, [0.0, 0.0], 0.0).unwrap();
    comp.push_move(straight([1.0, 0.0], 1)).unwrap();
    comp.push_move(straight([2.0, 0.0], 2)).unwrap();
    comp.push_move(straight([2.0, 0.1], 3)).unwrap();
    assert_eq!(comp.finish(), Err(CompError::StraightFeedGouging));
    // Nothing held was released; compensation is still on.
    check(
        &comp.drain().collect::<Vec<_>>(),
        &[Want::Line([1.0, 0.125]), Want::Line([1.875, 0.125])],
    );
    assert!(comp.push_move(straight([2.0, 1.0], 4)).is_ok());
}

#[test]
fn tool_inside_too_small_arc_is_an_error() {
    let mut comp = Compensator::new(Side::Left, 1.0, [0.0, 0.0], 0.0).unwrap();
    comp.push_move(straight([10.0, 0.0], 1)).unwrap();
    // Counter-clockwise radius 0.5 with the tool (radius 1) inside.
    let err = comp
        .push_move(arc([10.5, 0.5], [10.0, 0.5], true, 2))
        .unwrap_err();
    assert_eq!(err, CompError::ToolRadiusNotLessThanArcRadius);
    assert_eq!(
        err.to_string(),
        "Tool radius not less than arc radius with comp"
    );
    // Entry arc likewise.
    let mut comp = Compensator::new(Side::Right, 1.0, [0.0, 0.0], 0.0).unwrap();
    let err = comp
        .push_move(arc([0.0, 1.8], [0.0, 0.9], false, 1))
        .unwrap_err();
    assert_eq!(err, CompError::ToolRadiusNotLessThanArcRadius);
}

#[test]
fn short_entry_moves_are_errors() {
    let mut comp = Compensator::new(Side::Left, 1.0, [0.0, 0.0], 0.0).unwrap();
    assert_eq!(
        comp.push_move(straight([0.5, 0.5], 1))
            .unwrap_err()
            .to_string(),
        "Length of cutter compensation entry move is not greater than the tool radius"
    );
    assert_eq!(
        comp.push_move(arc([1.0, 0.0], [0.5, 0.0], false, 1))
            .unwrap_err()
            .to_string(),
        "Radius of cutter compensation entry arc is not greater than the tool radius"
    );
    // An entry with only normal-axis motion has length 0 in the plane.
    let err = comp
        .push_move(PlaneMove {
            along: -1.0,
            ..straight([0.0, 0.0], 1)
        })
        .unwrap_err();
    assert_eq!(err, CompError::EntryMoveTooShort);
    assert!(comp.awaiting_entry());
}

#[test]
fn arc_gouging_in_concave_corner_is_an_error() {
    // Line along +x (tool on y = 1), then a left turn into a counter-clockwise arc
    // around (8.4, 0) of radius 1.6 with the tool (radius 1) inside: the offset circle
    // (radius 0.6) never reaches the offset line y = 1.
    let mut comp = Compensator::new(Side::Left, 1.0, [0.0, 0.0], 0.0).unwrap();
    comp.push_move(straight([10.0, 0.0], 1)).unwrap();
    let err = comp
        .push_move(arc([8.4, 1.6], [8.4, 0.0], true, 2))
        .unwrap_err();
    assert_eq!(
        err.to_string(),
        "Arc move in concave corner cannot be reached by the tool without gouging"
    );
}

#[test]
fn exit_rule_and_messages() {
    let mut comp = Compensator::new(Side::Left, 0.125, [0.0, 0.0], 0.0).unwrap();
    comp.push_move(straight([1.0, 0.0], 1)).unwrap();
    comp.push_move(straight([2.0, 0.0], 2)).unwrap();
    comp.push_event(Tag::Note("interpreter: cutter radius compensation off"));
    let end = comp.finish().unwrap();
    assert!(end.exit_must_be_straight);
    // tests/interp/bad/ccomp-arcexit: the moves and the comment are released before
    // the arc that follows is refused.
    check(
        &comp.drain().collect::<Vec<_>>(),
        &[
            Want::Line([1.0, 0.125]),
            Want::Line([2.0, 0.125]),
            Want::Note("interpreter: cutter radius compensation off"),
        ],
    );
    assert_eq!(comp.programmed(), [2.0, 0.0]);
    assert_eq!(
        CompError::ArcAfterCompOff.to_string(),
        "The move just after exiting cutter compensation mode must be straight, not an arc"
    );
    assert_eq!(
        comp.push_move(straight([3.0, 0.0], 3)),
        Err(CompError::Finished)
    );
    assert_eq!(comp.finish(), Err(CompError::Finished));
}

#[test]
fn g40_right_after_g41_still_requires_a_straight_exit() {
    // LinuxCNC 2.9.0 sets the exit rule on G40 whenever the radius is not zero.
    let mut comp = Compensator::<Tag>::new(Side::Left, 0.5, [3.0, 4.0], 1.0).unwrap();
    comp.push_event(Tag::Note("off"));
    let end = comp.finish().unwrap();
    assert!(end.exit_must_be_straight);
    check(&comp.drain().collect::<Vec<_>>(), &[Want::Note("off")]);
    assert_eq!(comp.programmed(), [3.0, 4.0]);
    assert_eq!(comp.tool_point(), [3.0, 4.0]);
}

#[test]
fn non_finite_input_is_rejected() {
    assert!(matches!(
        Compensator::<Tag>::new(Side::Left, Real::NAN, [0.0, 0.0], 0.0),
        Err(CompError::NonFinite { .. })
    ));
    let mut comp = Compensator::new(Side::Left, 1.0, [0.0, 0.0], 0.0).unwrap();
    assert!(matches!(
        comp.push_move(straight([Real::INFINITY, 0.0], 1)),
        Err(CompError::NonFinite { .. })
    ));
}

#[test]
fn nearly_tangent_corner_gets_no_arc_below_the_corner_tolerance() {
    // A right turn (convex for G41) of 0.03 rad is taken as tangent: no corner arc, the
    // next straight starts where the last one ended. At 0.06 rad an arc is inserted.
    let r = 1.0;
    for (turn, with_arc) in [(0.03, false), (0.06, true)] {
        let second = [10.0 + 10.0 * Real::cos(turn), -10.0 * Real::sin(turn)];
        let out = run(
            Side::Left,
            r,
            [0.0, 0.0],
            vec![straight([10.0, 0.0], 1), straight(second, 2)],
        );
        let normal = FRAC_PI_2 - turn;
        let tool_end = add_polar(second, r, normal);
        let mut want = vec![Want::Line([10.0, r])];
        if with_arc {
            want.push(Want::Arc(
                add_polar([10.0, 0.0], r, normal),
                [10.0, 0.0],
                false,
            ));
        }
        want.push(Want::Line(tool_end));
        check(&out, &want);
    }
}

#[test]
fn reversing_goes_around_the_end_point() {
    // Out and straight back with G41: a half turn around the end point.
    let r = 1.0;
    let out = run(
        Side::Left,
        r,
        [0.0, 0.0],
        vec![straight([10.0, 0.0], 1), straight([0.0, 0.0], 2)],
    );
    check(
        &out,
        &[
            Want::Line([10.0, r]),
            Want::Arc([10.0, -r], [10.0, 0.0], false),
            Want::Line([0.0, -r]),
        ],
    );
}

#[test]
fn regular_polygons_offset_outside_and_inside() {
    // Regular n-gons of circumradius 10 around the origin. Clockwise with G41 (outside):
    // each edge is shifted out by r and each vertex is rounded by an arc of radius r.
    // Counter-clockwise with G41 (inside): the tool follows the inset polygon, whose
    // vertices lie at (apothem − r) / cos(π/n) from the centre on the vertex rays.
    let r = 0.7;
    for n in 3..=12_u32 {
        let step = TAU / Real::from(n);
        let vertex = |k: u32| add_polar([0.0, 0.0], 10.0, Real::from(k) * step);
        // Clockwise: vertices in decreasing angle, entering at vertex 0 from the centre.
        let mut moves = vec![straight(vertex(0), 0)];
        for k in 1..=n + 1 {
            moves.push(straight(vertex((n - k % n) % n), k));
        }
        let out = run(Side::Left, r, [0.0, 0.0], moves);
        let mut arcs = 0;
        for o in &out[1..] {
            match o {
                CompOutput::Arc {
                    center, end, ccw, ..
                } => {
                    arcs += 1;
                    assert!(!ccw);
                    assert!((dist(*center, *end) - r).abs() < GEOM_EPS);
                    assert!((dist(*center, [0.0, 0.0]) - 10.0).abs() < GEOM_EPS);
                }
                CompOutput::Straight { end, .. } => {
                    // One radius outside the edge's supporting line: distance from the
                    // centre along the edge normal is apothem + r.
                    let apothem = 10.0 * (step / 2.0).cos();
                    let dist_to_center = dist(*end, [0.0, 0.0]);
                    assert!(dist_to_center > apothem + r - GEOM_EPS, "n {n}: {o:?}");
                }
                CompOutput::Event(_) => unreachable!(),
            }
        }
        // One arc per vertex plus the corner between the radial entry and the first edge.
        assert_eq!(arcs, n + 1, "n {n}");

        // Counter-clockwise inside, entering from the centre towards the middle of
        // edge 0 → 1, then around the polygon and once more along the first edge.
        let mid = [
            (vertex(0)[0] + vertex(1)[0]) / 2.0,
            (vertex(0)[1] + vertex(1)[1]) / 2.0,
        ];
        let mut moves = vec![straight(mid, 0)];
        for k in 1..=n + 1 {
            moves.push(straight(vertex(k % n), k));
        }
        let out = run(Side::Left, r, [0.0, 0.0], moves);
        let half = step / 2.0;
        let apothem = 10.0 * half.cos();
        let inset = (apothem - r) / half.cos();
        let ends: Vec<[Real; 2]> = out
            .iter()
            .map(|o| match o {
                CompOutput::Straight { end, .. } => *end,
                _ => panic!("n {n}: {o:?}"),
            })
            .collect();
        assert_eq!(ends.len(), n as usize + 2, "n {n}: {out:#?}");
        // The radial entry (tool r to its left, i.e. towards vertex 1) meets the inner
        // offset of edge 0 → 1 at (apothem − r) along the ray, r along the edge.
        let entry = add_polar(
            add_polar([0.0, 0.0], apothem - r, half),
            r,
            half + FRAC_PI_2,
        );
        assert!(
            near2(ends[0], entry, GEOM_EPS),
            "n {n}: {:?} vs {entry:?}",
            ends[0]
        );
        // Each edge ends at the inset vertex where the next edge begins.
        for k in 1..=n {
            let want = add_polar([0.0, 0.0], inset, Real::from(k) * step);
            let got = ends[k as usize];
            assert!(
                near2(got, want, GEOM_EPS),
                "n {n} k {k}: {got:?} vs {want:?}"
            );
        }
        // The last edge is released by G40 unmoved: one radius inside vertex 1.
        let last = add_polar(vertex(1), -r, half);
        assert!(near2(ends[n as usize + 1], last, GEOM_EPS), "n {n}");
    }
}

#[test]
fn entry_arc_is_recentred_through_start_and_offset_end() {
    // The entry arc must start at the tool's position and end one radius off the
    // programmed end, on a circle whose centre lies on the line from the new end to the
    // programmed centre.
    for (side, ccw) in [
        (Side::Left, true),
        (Side::Left, false),
        (Side::Right, true),
        (Side::Right, false),
    ] {
        let start = [3.0, -1.0];
        let center = [0.5, 0.5];
        let radius = dist(start, center);
        let angle = dir_angle(sub(start, center)) + if ccw { 1.2 } else { -1.2 };
        let end = add_polar(center, radius, angle);
        let out = run(side, 0.4, start, vec![arc(end, center, ccw, 1)]);
        let [
            CompOutput::Arc {
                center: c2,
                end: e2,
                ccw: ccw2,
                ..
            },
        ] = out.as_slice()
        else {
            panic!("{out:?}")
        };
        assert_eq!(*ccw2, ccw);
        let toward_center = side.inside(ccw);
        let want_end = add_polar(
            end,
            if toward_center { -0.4 } else { 0.4 },
            dir_angle(sub(end, center)),
        );
        assert!(near2(*e2, want_end, GEOM_EPS));
        assert!((dist(*c2, start) - dist(*c2, *e2)).abs() < GEOM_EPS);
        let u = sub(*c2, *e2);
        let v = sub(center, *e2);
        assert!(
            (u[0] * v[1] - u[1] * v[0]).abs() < GEOM_EPS,
            "not collinear"
        );
    }
}

#[test]
fn arc_pulled_back_past_its_start_is_gouging() {
    // Inside a counter-clockwise arc of radius 10 sweeping only 0.05 rad, then a sharp
    // left turn: the offset line y = 10·sin 0.05 − 1 < 0 meets the tool's circle (radius
    // 9) before the arc's start, so the held arc would have to sweep almost a full turn.
    let r = 1.0;
    let mut comp = Compensator::new(Side::Left, r, [10.0, -5.0], 0.0).unwrap();
    comp.push_move(straight([10.0, 0.0], 1)).unwrap();
    let arc_end = add_polar([0.0, 0.0], 10.0, 0.05);
    comp.push_move(arc(arc_end, [0.0, 0.0], true, 2)).unwrap();
    let err = comp
        .push_move(straight([arc_end[0] - 5.0, arc_end[1]], 3))
        .unwrap_err();
    assert_eq!(err, CompError::ArcGouging);
}

#[test]
fn rapid_gouging_names_the_traverse() {
    let mut comp = Compensator::new(Side::Left, 0.125, [0.0, 0.0], 0.0).unwrap();
    comp.push_move(straight([1.0, 0.0], 1)).unwrap();
    comp.push_move(straight([2.0, 0.0], 2)).unwrap();
    comp.push_move(rapid([2.0, 0.1], 3)).unwrap();
    let err = comp.push_move(straight([1.0, 0.1], 4)).unwrap_err();
    assert_eq!(
        err.to_string(),
        "Straight traverse in concave corner cannot be reached by the tool without gouging"
    );
}

#[test]
fn reversing_on_the_same_circle_is_an_error() {
    // Inside a counter-clockwise arc, then back clockwise on the same circle: LinuxCNC
    // treats the 180° turn as a concave arc-to-arc corner with one centre.
    let mut comp = Compensator::new(Side::Left, 1.0, [10.0, -5.0], 0.0).unwrap();
    comp.push_move(straight([10.0, 0.0], 1)).unwrap();
    comp.push_move(arc([0.0, 10.0], [0.0, 0.0], true, 2))
        .unwrap();
    let err = comp
        .push_move(arc([10.0, 0.0], [0.0, 0.0], false, 3))
        .unwrap_err();
    assert_eq!(
        err.to_string(),
        "Arc to arc motion is invalid because the arcs have the same center"
    );
}

#[test]
fn program_stop_releases_the_held_move() {
    let r = 1.0;
    let mut comp = Compensator::new(Side::Left, r, [0.0, 0.0], 0.0).unwrap();
    comp.push_move(straight([10.0, 0.0], 1)).unwrap();
    comp.push_event(Tag::Note("M0"));
    assert!(comp.drain().next().is_none());
    comp.release_held().unwrap();
    check(
        &comp.drain().collect::<Vec<_>>(),
        &[Want::Line([10.0, r]), Want::Note("M0")],
    );
    // Compensation goes on: a convex corner still gets its arc.
    comp.push_move(straight([10.0, -10.0], 2)).unwrap();
    comp.finish().unwrap();
    check(
        &comp.drain().collect::<Vec<_>>(),
        &[
            Want::Arc([10.0 + r, 0.0], [10.0, 0.0], false),
            Want::Line([10.0 + r, -10.0]),
        ],
    );
}

#[test]
fn sweep_follows_turn_sense_and_count() {
    let c = [1.0, 1.0];
    let east = [2.0, 1.0];
    let north = [1.0, 2.0];
    assert!((sweep(east, c, 1, north) - FRAC_PI_2).abs() < GEOM_EPS);
    assert!((sweep(east, c, -1, north) + 3.0 * FRAC_PI_2).abs() < GEOM_EPS);
    // Start on the end: a full turn, plus one per extra P.
    assert!((sweep(east, c, 1, east) - TAU).abs() < GEOM_EPS);
    assert!((sweep(east, c, -1, east) + TAU).abs() < GEOM_EPS);
    assert!((sweep(east, c, 3, north) - (FRAC_PI_2 + 2.0 * TAU)).abs() < GEOM_EPS);
    assert!((sweep(east, c, -2, north) + (3.0 * FRAC_PI_2 + TAU)).abs() < GEOM_EPS);
    assert_eq!(sweep(east, c, 0, north), 0.0);
}

#[test]
fn short_tangent_straight_pulled_back_past_its_start_is_gouging() {
    // A 0.05 continuation (shorter than the radius 0.125) followed by a left turn: the
    // corner point lies 0.125 back from its end, before its start.
    let mut comp = Compensator::new(Side::Left, 0.125, [0.0, 0.0], 0.0).unwrap();
    comp.push_move(straight([1.0, 0.0], 1)).unwrap();
    comp.push_move(straight([1.05, 0.0], 2)).unwrap();
    let err = comp.push_move(straight([1.05, 1.0], 3)).unwrap_err();
    assert_eq!(err, CompError::StraightFeedGouging);
}

#[test]
fn inch_program_in_mm_rotated_and_shifted_gives_the_same_path() {
    // Compensation commutes with a change of unit, a rotation and a shift of the program
    // (all its decisions are angles and ratios): the part of mill-line-arc-entry under
    // G41 (radius 0.5 in), given in mm, turned by 30° and moved, gives the transformed
    // path.
    let moves = |f: &dyn Fn([Real; 2]) -> [Real; 2]| {
        vec![
            straight(f([1.0, 4.0]), 1),
            arc(f([2.0, 3.0]), f([2.0, 4.0]), true, 2),
            arc(f([3.0, 2.0]), f([2.0, 2.0]), false, 3),
            straight(f([3.0, -1.0]), 4),
            arc(f([2.0, -2.0]), f([2.0, -1.0]), false, 5),
            straight(f([-2.0, -2.0]), 6),
            arc(f([-2.6, -0.2]), f([-2.0, -1.0]), false, 7),
            straight(f([1.4, 2.8]), 8),
            arc(f([2.0, 3.0]), f([2.0, 2.0]), false, 9),
        ]
    };
    let (sin, cos) = (30.0_f64.to_radians()).sin_cos();
    let to_mm = |p: [Real; 2]| {
        let q = [25.4 * p[0], 25.4 * p[1]];
        [
            cos * q[0] - sin * q[1] + 100.0,
            sin * q[0] + cos * q[1] - 40.0,
        ]
    };
    let inch = run(Side::Left, 0.5, [1.0, 5.0], moves(&|p| p));
    let mm = run(Side::Left, 0.5 * 25.4, to_mm([1.0, 5.0]), moves(&to_mm));
    assert_eq!(inch.len(), mm.len());
    // f64 rounding of the trigonometry at ~100 mm.
    let eps = 1e-9;
    for (a, b) in inch.iter().zip(&mm) {
        match (a, b) {
            (CompOutput::Straight { end: e1, .. }, CompOutput::Straight { end: e2, .. }) => {
                assert!(near2(to_mm(*e1), *e2, eps), "{a:?} vs {b:?}");
            }
            (
                CompOutput::Arc {
                    center: c1,
                    end: e1,
                    ccw: w1,
                    ..
                },
                CompOutput::Arc {
                    center: c2,
                    end: e2,
                    ccw: w2,
                    ..
                },
            ) => {
                assert_eq!(w1, w2);
                assert!(near2(to_mm(*e1), *e2, eps), "{a:?} vs {b:?}");
                assert!(near2(to_mm(*c1), *c2, eps), "{a:?} vs {b:?}");
            }
            _ => panic!("{a:?} vs {b:?}"),
        }
    }
}

#[test]
fn random_programs_never_panic_and_keep_events_in_order() {
    // Deterministic pseudo-random programs (lines, rapids, plunges, arcs of random sense
    // and size, events in between): every call either succeeds or returns an error, all
    // outputs are finite, and the events come out once each, in order.
    let mut state: u64 = 0x9e37_79b9_7f4a_7c15;
    let mut next = move || {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        ((state >> 11) as Real) / ((1_u64 << 53) as Real)
    };
    for program in 0..300 {
        let side = if next() < 0.5 {
            Side::Left
        } else {
            Side::Right
        };
        let radius = [0.0, 0.05, 0.5, 2.0][(next() * 4.0) as usize];
        let mut comp = Compensator::new(side, radius, [0.0, 0.0], 0.0).unwrap();
        let mut pushed = 0_u32;
        let mut released = Vec::new();
        for step in 0..40_u32 {
            if next() < 0.3 {
                comp.push_event(Tag::Move(1000 + pushed));
                pushed += 1;
            }
            let from = comp.programmed();
            let roll = next();
            let mv = if roll < 0.1 {
                PlaneMove {
                    along: next() * 5.0,
                    ..straight(from, step)
                }
            } else if roll < 0.55 {
                let end = [from[0] + next() * 6.0 - 3.0, from[1] + next() * 6.0 - 3.0];
                if next() < 0.2 {
                    rapid(end, step)
                } else {
                    straight(end, step)
                }
            } else {
                let center = [from[0] + next() * 4.0 - 2.0, from[1] + next() * 4.0 - 2.0];
                let r = dist(from, center);
                let end = add_polar(center, r, dir_angle(sub(from, center)) + next() * 6.0);
                arc(end, center, next() < 0.5, step)
            };
            // Errors are allowed (gouging, tool too big, ...); panics are not.
            let _ = comp.push_move(mv);
            released.extend(comp.drain());
        }
        // G40 itself may refuse (the held move would run backwards), as in LinuxCNC;
        // then what is still held is never released.
        let finished = comp.finish().is_ok();
        released.extend(comp.drain());
        let events: Vec<u32> = released
            .iter()
            .filter_map(|o| match o {
                CompOutput::Event(Tag::Move(k)) => Some(*k),
                _ => None,
            })
            .collect();
        assert!(events.windows(2).all(|w| w[0] < w[1]), "program {program}");
        if finished {
            assert_eq!(events.len() as u32, pushed, "program {program}");
        }
        for o in &released {
            match o {
                CompOutput::Straight { end, along, .. } => {
                    assert!(end.iter().all(|v| v.is_finite()) && along.is_finite());
                }
                CompOutput::Arc {
                    center, end, along, ..
                } => {
                    assert!(end.iter().chain(center).all(|v| v.is_finite()));
                    assert!(along.is_finite());
                }
                CompOutput::Event(_) => {}
            }
        }
    }
}

#[test]
fn planes_split_and_join() {
    let p = [1.0, 2.0, 3.0];
    assert_eq!(Plane::Xy.split(p), ([1.0, 2.0], 3.0));
    assert_eq!(Plane::Zx.split(p), ([3.0, 1.0], 2.0));
    assert_eq!(Plane::Yz.split(p), ([2.0, 3.0], 1.0));
    for plane in [Plane::Xy, Plane::Zx, Plane::Yz] {
        let (q, a) = plane.split(p);
        assert_eq!(plane.join(q, a), p);
    }
    assert_eq!(
        Plane::Yz.check_comp_allowed(),
        Err(CompError::PlaneNotAllowed)
    );
    assert!(Plane::Zx.check_comp_allowed().is_ok());
}

mod linuxcnc_corpus;
