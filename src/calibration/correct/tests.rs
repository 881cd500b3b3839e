//! Tests of the pose solver and the corrected program.

use super::*;
use crate::cutting::tool::Tool;
use crate::cutting::tool::ToolKind;
use crate::machine::chain::Axis;
use crate::machine::chain::{AxisKind, Chain, TRUNNION_DEVIATIONS, trunnion_for_tests as trunnion};
use crate::math::CounterRng;
use crate::math::{Point3, Real, UnitVector3, Vector3};
use crate::nc::{AxisLetter, AxisValues, Move, MoveKind, Program};

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
    // Emitted: parts named; the turn's sub-moves in inverse time, each taking its share of
    // the source move's 40 mm at 500 mm/min (LinuxCNC feeds the XYZ length), then G94 again
    // for the straight move at its programmed feed.
    let mut text = Vec::new();
    write_gcode(&cp, &["head test".into()], &mut text).expect("writes");
    let text = String::from_utf8(text).expect("utf-8");
    let n = turn_fix.sub_moves;
    assert!(text.contains(&format!("(src line 1, {n}/{n})")), "{text}");
    assert_eq!(text.matches("F500").count(), 1, "{text}");
    assert_eq!(cp.summary.inverse_time_blocks, n);
    let share = 40.0 / 500.0 / n as Real;
    for b in cp.blocks.iter().filter(|b| b.source == Some(0)) {
        let f = b.inverse_time_per_min.expect("inverse time");
        assert!((f * share - 1.0).abs() < 1e-12, "{f}");
    }
    let g93 = text.find("\nG93\n").expect("G93");
    let g94 = text
        .find("\nG94\nG1")
        .expect("G94 before the straight move");
    assert!(g93 < g94 && text[g94..].contains("F500"), "{text}");
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

/// The trunnion's tool pose written out by hand, independently of `Chain`:
/// `RotZ(c)·E_CA·[Trans(0,0,−50)·RotX(a)·Trans(0,0,50)]·E_AY·Trans(x, y, z)` with
/// `E = Trans(d)·Rx(α)·Ry(β)·Rz(γ)`; returns the tool point at height `h` on the axis.
fn trunnion_oracle(dev: bool, q: &AxisValues, h: Real) -> Vector3 {
    use nalgebra::{Matrix3, Vector3 as V};
    let v = |n: &str| {
        if !dev {
            return 0.0;
        }
        TRUNNION_DEVIATIONS
            .iter()
            .find(|(k, _)| *k == n)
            .map_or(0.0, |(_, x)| *x)
    };
    let rx = |t: Real| Matrix3::new(1.0, 0.0, 0.0, 0.0, t.cos(), -t.sin(), 0.0, t.sin(), t.cos());
    let ry = |t: Real| Matrix3::new(t.cos(), 0.0, t.sin(), 0.0, 1.0, 0.0, -t.sin(), 0.0, t.cos());
    let rz = |t: Real| Matrix3::new(t.cos(), -t.sin(), 0.0, t.sin(), t.cos(), 0.0, 0.0, 0.0, 1.0);
    let e = |j: &str, p: V<Real>| {
        let r = rx(v(&format!("alpha_{j}")))
            * ry(v(&format!("beta_{j}")))
            * rz(v(&format!("gamma_{j}")));
        r * p
            + V::new(
                v(&format!("dx_{j}")),
                v(&format!("dy_{j}")),
                v(&format!("dz_{j}")),
            )
    };
    let (c, a) = (
        q.get(AxisLetter::C).to_radians(),
        q.get(AxisLetter::A).to_radians(),
    );
    let p = V::new(
        q.get(AxisLetter::X),
        q.get(AxisLetter::Y),
        q.get(AxisLetter::Z) + h,
    );
    let p = e("AY", p);
    let pivot = V::new(0.0, 0.0, -50.0);
    let p = rx(a) * (p - pivot) + pivot;
    rz(c) * e("CA", p)
}

fn trunnion_pose(c: Real, a: Real, x: Real, y: Real, z: Real) -> AxisValues {
    AxisValues::default()
        .with(AxisLetter::C, c)
        .with(AxisLetter::A, a)
        .with(AxisLetter::X, x)
        .with(AxisLetter::Y, y)
        .with(AxisLetter::Z, z)
}

#[test]
fn simultaneous_five_axis_moves_through_the_parallel_pose_are_corrected_on_a_hand_written_chain() {
    // The oracle agrees with the chain (both ways of writing the same machine).
    let c = trunnion();
    let probe = trunnion_pose(37.0, -21.0, 12.0, -7.0, 33.0);
    let chain_tip = c.w_from_t(&probe) * Point3::new(0.0, 0.0, 5.0);
    assert!((chain_tip.coords - trunnion_oracle(true, &probe, 5.0)).norm() < 1e-9);
    let nominal_tip = c.nominal().w_from_t(&probe) * Point3::new(0.0, 0.0, 5.0);
    assert!((nominal_tip.coords - trunnion_oracle(false, &probe, 5.0)).norm() < 1e-9);

    // A 3+2 pose at A = 0 (C parallel to the tool), then simultaneous moves: C turning
    // while cutting at A = 0, C and A turning with X, Y, Z, and A passing through 0 with C
    // turning.
    let p0 = trunnion_pose(0.0, 0.0, -30.0, -22.6, 20.0);
    let p1 = trunnion_pose(0.0, 0.0, 30.0, -22.6, 20.0);
    let p2 = trunnion_pose(90.0, 0.0, 30.0, -22.6, 20.0);
    let p3 = trunnion_pose(150.0, 30.0, 10.0, -10.0, 35.0);
    let p4 = trunnion_pose(270.0, -15.0, -5.0, 12.0, 30.0);
    let mv = |line, a: AxisValues, b: AxisValues| Move {
        kind: MoveKind::Linear,
        start: a,
        end: b,
        feed_mm_per_min: Some(600.0),
        line,
    };
    let program = Program {
        path: "trunnion.ngc".into(),
        moves: vec![mv(1, p0, p1), mv(2, p1, p2), mv(3, p2, p3), mv(4, p3, p4)],
        axes_used: vec![
            AxisLetter::X,
            AxisLetter::Y,
            AxisLetter::Z,
            AxisLetter::A,
            AxisLetter::C,
        ],
        ended_by: Some(5),
    };
    let tool = tool();
    let accuracy = 1e-3;
    let opts = CorrectOptions::for_accuracy(accuracy);
    let cp = correct_program(&c, &tool, &program, &p0, &opts).expect("corrects");

    // The direction error no rotary value removes at A = 0: the deviated tool axis's X
    // component in A's frame, the sum of the tilts about Y (C's line turns with C and does
    // not change the tool's angle to it; A turns about X).
    let stuck = (-30e-6 + 60e-6 as Real).abs();
    let l = tool.length();
    // Sampled along every corrected block as the machine interpolates it, the oracle's tool
    // tip and flute end against the nominal oracle at the same parameter of the source move.
    let mut at = cp.start;
    let (mut worst_tip, mut worst_mid, mut worst_uncorrected): (Real, Real, Real) = (0.0, 0.0, 0.0);
    let mut max_angle: Real = 0.0;
    for b in &cp.blocks {
        let from = at;
        at = b.end;
        let Some(src) = b.source.map(|i| &program.moves[i]) else {
            continue;
        };
        // Continuity: every corrected rotary value stays within 0.2° of the commanded one
        // at the same parameter: no flip, no 360° jump.
        for (l_, q) in [(AxisLetter::A, b.end), (AxisLetter::C, b.end)] {
            let commanded = path_point(src, b.s.1).get(l_);
            assert!(
                (q.get(l_) - commanded).abs() < 0.2,
                "line {}: {l_:?} {} vs commanded {commanded}",
                b.line,
                q.get(l_)
            );
        }
        for i in 0..=10 {
            let t = i as Real / 10.0;
            let q = lerp(&from, &b.end, t);
            let s = b.s.0 + (b.s.1 - b.s.0) * t;
            let nominal = path_point(src, s);
            let tip =
                (trunnion_oracle(true, &q, 0.0) - trunnion_oracle(false, &nominal, 0.0)).norm();
            let mid = (trunnion_oracle(true, &q, l / 2.0)
                - trunnion_oracle(false, &nominal, l / 2.0))
            .norm();
            let end = (trunnion_oracle(true, &q, l) - trunnion_oracle(false, &nominal, l)).norm();
            worst_tip = worst_tip.max(tip).max(end);
            worst_mid = worst_mid.max(mid);
            let dv = (trunnion_oracle(true, &q, l) - trunnion_oracle(true, &q, 0.0)) / l;
            let dn =
                (trunnion_oracle(false, &nominal, l) - trunnion_oracle(false, &nominal, 0.0)) / l;
            max_angle = max_angle.max(dv.angle(&dn));
            let given = (trunnion_oracle(true, &nominal, 0.0)
                - trunnion_oracle(false, &nominal, 0.0))
            .norm();
            worst_uncorrected = worst_uncorrected.max(given);
        }
    }
    // Without correction the tool is tens of µm off: the check is not vacuous.
    assert!(worst_uncorrected > 0.02, "uncorrected {worst_uncorrected}");
    // The tool point (mid-flute, where the solve places the axis) within the accuracy, the
    // tip and flute end within it too (the stuck tilt costs |δv|·L/2 ≈ 0.4 µm there).
    assert!(worst_mid < accuracy / 2.0, "mid-flute {worst_mid}");
    assert!(worst_tip < accuracy, "tip or flute end {worst_tip}");
    // The orientation error is bounded by what the axes cannot reach near A = 0 (the stuck
    // tilt; the damping leaves a little more near the parallel pose) and reported.
    assert!(max_angle >= 0.9 * stuck, "{max_angle} vs {stuck}");
    assert!(max_angle < 2.0 * stuck, "{max_angle} vs {stuck}");
    assert!(
        cp.summary.axis_angle_rad >= 0.95 * stuck && cp.summary.axis_angle_rad <= max_angle + 1e-9,
        "reported {} vs oracle {max_angle}",
        cp.summary.axis_angle_rad
    );
    assert!(
        cp.summary.max_rotary_correction_deg < 0.2,
        "{:?}",
        cp.summary
    );
}
