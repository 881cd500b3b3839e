//! Unit tests of the envelope: the move path against the chain's poses, the intervals
//! against a brute-force union over densely sampled poses, grazing and twice-crossed rays.
//!
//! **Invariant:** expected values come from independent derivations, never from the
//! program's output.

use super::solve::hermite_extreme;
use super::*;
use crate::cutting::cutter::SweptTool;
use crate::machine::chain::trunnion_for_tests as trunnion;
use crate::nc::AxisLetter;
use proptest::prelude::*;

mod edge_normal;
mod height;
mod probe;

fn deviated() -> Chain {
    let mut c = crate::machine::chain::mdx50_for_tests();
    for (name, v) in [
        ("dy_AY", -0.3),
        ("dz_AY", 0.2),
        ("beta_AY", 2e-4),
        ("gamma_AY", -3e-4),
        ("alpha_YX", 4e-4),
        ("beta_XZ", -2e-4),
        ("alpha_ZS", 1e-4),
        ("beta_ZS", -5e-4),
    ] {
        let id = c.deviation_id(name).expect("known");
        c.set_deviation(id, v);
    }
    c
}

fn q(x: Real, y: Real, z: Real, a: Real) -> AxisValues {
    AxisValues::default()
        .with(AxisLetter::X, x)
        .with(AxisLetter::Y, y)
        .with(AxisLetter::Z, z)
        .with(AxisLetter::A, a)
}

/// The chain's own pose at `l` of the move `a → b`, every axis interpolated linearly (the
/// tests' independent pose, never the envelope's `MovePath`).
fn chain_pose(c: &Chain, a: &AxisValues, b: &AxisValues, l: Real) -> Isometry3 {
    let mut qq = *a;
    for axis in c.axes() {
        let (u, w) = (a.get(axis.letter), b.get(axis.letter));
        qq.set(axis.letter, u + (w - u) * l);
    }
    c.w_from_t(&qq)
}

#[test]
fn move_path_is_the_chain_pose() {
    let c = deviated();
    let (a, b) = (q(1.0, -2.0, 8.0, 10.0), q(4.0, -2.0, 7.0, 47.0));
    let path = MovePath::new(&c, &a, &b);
    for k in 0..=10 {
        let l = k as Real / 10.0;
        let d = path.w_from_t(l).to_homogeneous() - chain_pose(&c, &a, &b, l).to_homogeneous();
        assert!(d.abs().max() < 1e-12, "λ = {l}: {d}");
    }
}

/// The rates of the sample `s` at `l` (tool frame) are the central differences of the poses
/// `(rotation, tip)` at `l ∓ h`, to 1e-6 relative.
fn assert_rates_are_differences(
    l: Real,
    s: &Sample,
    lo: (Matrix3, Vector3),
    hi: (Matrix3, Vector3),
    h: Real,
) {
    let v = s.rot.tr_mul(&((hi.1 - lo.1) / (2.0 * h)));
    let w = s.rot.transpose() * ((hi.0 - lo.0) / (2.0 * h));
    let w = Vector3::new(w[(2, 1)], w[(0, 2)], w[(1, 0)]);
    assert!(
        (v - s.v_t).norm() < 1e-6 * (1.0 + v.norm()),
        "λ {l}: v {v} vs {}",
        s.v_t
    );
    assert!(
        (w - s.w_t).norm() < 1e-6 * (1.0 + w.norm()),
        "λ {l}: ω {w} vs {}",
        s.w_t
    );
}

/// A chain that starts with a turn (a table's rotary axis; its pose is built from the
/// identity without the products with it): on a first axis tilted and off the origin, and on
/// the trunnion (C about z through the origin, A after it), the pose is the chain's own and
/// its rates (tool frame) are the central differences of the chain's poses.
#[test]
fn a_chain_starting_with_a_turn_has_the_chain_pose_and_its_rates() {
    use crate::machine::chain::{Axis, AxisKind};
    let ax = |letter, kind, d: Vector3, o: Point3| Axis {
        letter,
        kind,
        direction: nalgebra::Unit::new_normalize(d),
        origin: o,
    };
    let o = Point3::origin();
    let tilted = Chain::new(
        vec![
            ax(
                AxisLetter::B,
                AxisKind::Rotary,
                Vector3::new(0.2, 1.0, -0.1),
                Point3::new(7.0, -4.0, 12.0),
            ),
            ax(
                AxisLetter::A,
                AxisKind::Rotary,
                Vector3::x(),
                Point3::new(0.0, 3.0, -40.0),
            ),
            ax(AxisLetter::X, AxisKind::Linear, Vector3::x(), o),
            ax(AxisLetter::Y, AxisKind::Linear, Vector3::y(), o),
            ax(AxisLetter::Z, AxisKind::Linear, Vector3::z(), o),
        ],
        "S",
    )
    .expect("valid chain");
    let at = |x, y, z, a, b, c| {
        AxisValues::default()
            .with(AxisLetter::X, x)
            .with(AxisLetter::Y, y)
            .with(AxisLetter::Z, z)
            .with(AxisLetter::A, a)
            .with(AxisLetter::B, b)
            .with(AxisLetter::C, c)
    };
    let cases = [
        (
            tilted,
            at(2.0, -5.0, 30.0, -10.0, 25.0, 0.0),
            at(6.0, -1.0, 27.0, 35.0, -40.0, 0.0),
        ),
        (
            trunnion(),
            at(0.0, -19.0, 10.0, -10.0, 0.0, 20.0),
            at(0.5, -19.0, 12.0, 15.0, 0.0, 65.0),
        ),
    ];
    for (c, a, b) in &cases {
        let path = MovePath::new(c, a, b);
        let h = 1e-6;
        for k in 0..=20 {
            let l = (k as Real + 0.3) / 21.0;
            let s = path.sample(l);
            let p = chain_pose(c, a, b, l);
            let rot = p.rotation.to_rotation_matrix().into_inner();
            assert!(
                (s.rot - rot).abs().max() < 1e-12,
                "λ {l}: {} vs {rot}",
                s.rot
            );
            assert!(
                (s.tip.coords - p.translation.vector).norm() < 1e-12,
                "λ {l}"
            );
            let pose = |p: Isometry3| {
                (
                    p.rotation.to_rotation_matrix().into_inner(),
                    p.translation.vector,
                )
            };
            let (lo, hi) = (chain_pose(c, a, b, l - h), chain_pose(c, a, b, l + h));
            assert_rates_are_differences(l, &s, pose(lo), pose(hi), h);
        }
    }
}

/// The curve through a move's pilot poses ([`SampledPath`]): on the nodes it is the pose,
/// between them within its own error estimate of the chain's exact pose (which it never
/// sees between the nodes), and its rates are its derivatives (central differences of its
/// own poses).
#[test]
fn the_curve_through_pilot_poses_follows_the_move_within_its_estimate() {
    let c = deviated();
    let (a, b) = (q(-3.0, 1.0, 8.0, -25.0), q(4.0, 1.0, 6.0, 35.0));
    let path = MovePath::new(&c, &a, &b);
    let pilot: Vec<Isometry3> = (0..=64).map(|j| path.w_from_t(j as Real / 64.0)).collect();
    let curve = SampledPath::new(&pilot);
    let reach = 10.0;
    let estimate = SampledPath::error_estimate(&pilot, reach);
    let dist = |s: &Sample, p: &Isometry3| {
        let r = p.rotation.to_rotation_matrix().into_inner();
        let rel = nalgebra::Rotation3::from_matrix_unchecked(r.transpose() * s.rot);
        let angle = nalgebra::UnitQuaternion::from_rotation_matrix(&rel).angle();
        (s.tip.coords - p.translation.vector).norm() + angle * reach
    };
    for (j, p) in pilot.iter().enumerate() {
        let s = curve.sample(j as Real / 64.0);
        assert!(dist(&s, p) < 1e-12, "node {j}: {}", dist(&s, p));
    }
    let mut worst: Real = 0.0;
    for k in 0..=3000 {
        let l = k as Real / 3000.0;
        worst = worst.max(dist(&curve.sample(l), &path.w_from_t(l)));
    }
    assert!(
        worst > 0.0 && worst <= estimate,
        "off by {worst} mm, estimate {estimate} mm"
    );
    assert!(estimate < 1e-4, "{estimate}");
    // Rates against central differences of the curve's own poses (off the nodes).
    let h = 1e-6;
    for k in 0..40 {
        let l = (k as Real + 0.37) / 40.0;
        let (s, lo, hi) = (curve.sample(l), curve.sample(l - h), curve.sample(l + h));
        let pose = |p: Sample| (p.rot, p.tip.coords);
        assert_rates_are_differences(l, &s, pose(lo), pose(hi), h);
    }
}

/// The tool's interval along the ray at λ from the cutter's sweep of the standing tool
/// (an independent closed form), on the library chain's pose.
fn exact_at(
    c: &Chain,
    tool: &Tool,
    a: &AxisValues,
    b: &AxisValues,
    l: Real,
    o: &Point3,
    e: &Vector3,
) -> Option<(Real, Real)> {
    let pose = chain_pose(c, a, b, l);
    let v = nalgebra::Unit::new_normalize(pose.rotation * Vector3::z());
    let st = SweptTool::new(tool, pose * Point3::origin(), Vector3::zeros(), v);
    let mut out = Vec::new();
    st.intervals(o, e, &mut out);
    Some((out.first()?.t_in, out.last()?.t_out))
}

/// The envelope of `tool` on the move `a → b` of `c`, built with the tolerance `tol`,
/// against a brute-force search over 4,000 poses, on the axis ray through the tool's middle
/// at λ = ½ shifted by `(ou, ov)` (×4 mm): no pose reaches further than the envelope (to
/// `tol`), the sampled poses come within the sampling error of each end, between intervals
/// no pose touches the ray, and within the span `(f0, f1)` of the sampled hull the answer
/// is the same.
#[allow(clippy::too_many_arguments)]
fn check_against_brute_force(
    c: &Chain,
    tool: &Tool,
    (a, b): (AxisValues, AxisValues),
    axis: usize,
    (ou, ov): (Real, Real),
    (f0, f1): (Real, Real),
    tol: Real,
) -> Result<(), TestCaseError> {
    let (c, tool) = (c.clone(), tool.clone());
    let env = RotaryEnvelope::new(&c, &tool, &a, &b)
        .expect("supported")
        .with_tolerance(tol);
    prop_assert_eq!(env.tolerance(), tol);
    // A ray through the region the tool sweeps: aimed near the tool's middle at λ = ½.
    let mid = MovePath::new(&c, &a, &b).w_from_t(0.5) * Point3::new(0.0, 0.0, 3.0);
    let mut o = mid;
    o[(axis + 1) % 3] += 4.0 * ou;
    o[(axis + 2) % 3] += 4.0 * ov;
    let mut e = Vector3::zeros();
    e[axis] = 1.0;
    let mut cuts = Vec::new();
    env.intervals(&o, &e, &mut cuts);
    for w in cuts.windows(2) {
        prop_assert!(w[0].t_out < w[1].t_in, "not sorted/disjoint: {cuts:?}");
    }
    let n = 4000;
    let mut lo = Real::INFINITY;
    let mut hi = Real::NEG_INFINITY;
    let mut hits = Vec::new();
    for k in 0..=n {
        let l = k as Real / n as Real;
        if let Some((t0, t1)) = exact_at(&c, &tool, &a, &b, l, &o, &e) {
            lo = lo.min(t0);
            hi = hi.max(t1);
            hits.push((t0, t1));
        }
    }
    // Around the poses reaching furthest either way, 4,000 poses more within ±1/n.
    let mut far = [(Real::INFINITY, 0.0), (Real::NEG_INFINITY, 0.0)];
    for k in 0..=n {
        let l = k as Real / n as Real;
        if let Some((t0, t1)) = exact_at(&c, &tool, &a, &b, l, &o, &e) {
            if t0 < far[0].0 {
                far[0] = (t0, l);
            }
            if t1 > far[1].0 {
                far[1] = (t1, l);
            }
        }
    }
    for &(_, l0) in &far {
        for k in 0..=n {
            let l = (l0 + (2.0 * k as Real / n as Real - 1.0) / n as Real).clamp(0.0, 1.0);
            if let Some(h) = exact_at(&c, &tool, &a, &b, l, &o, &e) {
                hits.push(h);
            }
        }
    }
    // Sampling error, worked out here and not from the envelope's own speed bound:
    // between consecutive sampled poses no tool point moves further than
    // M = max_k |Δc_k| + 2·sin(θ_k/2)·ρ (c the tool's mid point on its axis, θ_k
    // the rotation between the poses, ρ = √(R² + (L/2)²) the farthest a tool point
    // lies from c); an interval end moves along the ray by up to a few times that
    // where the ray meets the surface at a slant: 4·M, and 1 nm for rounding.
    let mid = Point3::new(0.0, 0.0, tool.length() / 2.0);
    let rho = tool.radius().hypot(tool.length() / 2.0);
    let pose = |l: Real| chain_pose(&c, &a, &b, l);
    let mut step_max: Real = 0.0;
    let mut prev = pose(0.0);
    for k in 1..=n {
        let next = pose(k as Real / n as Real);
        let moved = ((next * mid) - (prev * mid)).norm()
            + 2.0 * (next.rotation.angle_to(&prev.rotation) / 2.0).sin() * rho;
        step_max = step_max.max(moved);
        prev = next;
    }
    let samp = 4.0 * step_max + 1e-6;
    for &(t0, t1) in &hits {
        // Every pose's interval lies inside one of the envelope's intervals.
        let inside = cuts
            .iter()
            .any(|c| c.t_in <= t0 + tol && t1 <= c.t_out + tol);
        prop_assert!(
            inside || t1 - t0 < 1e-6,
            "pose interval [{t0}, {t1}] not inside {cuts:?}"
        );
    }
    for cut in &cuts {
        // Each end is reached by some pose, within the sampling error.
        let near_in = hits.iter().any(|h| (h.0 - cut.t_in).abs() <= samp);
        let near_out = hits.iter().any(|h| (h.1 - cut.t_out).abs() <= samp);
        prop_assert!(
            near_in && near_out,
            "{cut:?} not reached; sampled [{lo}, {hi}]"
        );
    }
    if hits.is_empty() {
        prop_assert!(
            cuts.iter().all(|c| c.t_out - c.t_in < samp),
            "{cuts:?} but no pose hits"
        );
    }
    // Within a span (the material's extent) the answer is the same.
    let span = (lo + f0 * (hi - lo), lo + f1 * (hi - lo));
    if span.0 < span.1 {
        let clip = |cs: &[RayCut]| -> Vec<(Real, Real)> {
            cs.iter()
                .map(|c| (c.t_in.max(span.0), c.t_out.min(span.1)))
                .filter(|(a, b)| b - a > 1e-6)
                .collect()
        };
        let mut part = Vec::new();
        env.intervals_in(&o, &e, span, &mut part);
        let (full, part) = (clip(&cuts), clip(&part));
        prop_assert_eq!(full.len(), part.len(), "{:?} vs {:?}", full, part);
        for (x, y) in full.iter().zip(&part) {
            prop_assert!(
                (x.0 - y.0).abs() <= 2.0 * tol && (x.1 - y.1).abs() <= 2.0 * tol,
                "{:?} vs {:?}",
                full,
                part
            );
        }
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, failure_persistence: None, rng_seed: proptest::test_runner::RngSeed::Fixed(0x5eed), ..ProptestConfig::default() })]

    /// On random rotary moves (A turning with X, Z), every interval end agrees with a
    /// brute-force search over 4,000 poses ([`check_against_brute_force`]).
    #[test]
    fn envelope_agrees_with_brute_force(
        ball in any::<bool>(), a0 in -40.0..40.0f64, da in -30.0..30.0f64,
        x0 in -3.0..3.0f64, dx in -4.0..4.0f64, z0 in 4.0..9.0f64, dz in -2.0..2.0f64,
        y in -2.0..2.0f64, axis in 0usize..3, ou in -1.0..1.0f64, ov in -1.0..1.0f64,
        f0 in -0.2..0.6f64, f1 in 0.4..1.2f64,
    ) {
        let kind = if ball { ToolKind::Ball } else { ToolKind::Flat };
        let tool = Tool::try_new(kind, 6.0, 12.0).expect("valid");
        let (a, b) = (q(x0, y, z0, a0), q(x0 + dx, y, z0 + dz, a0 + da));
        check_against_brute_force(&deviated(), &tool, (a, b), axis, (ou, ov), (f0, f1), ENVELOPE_TOL)?;
    }

    /// The same on the trunnion A/C, C and A turning together while the tool moves: the
    /// speed bound that sizes the cells takes each rotary axis with its own distance. And
    /// with the tolerance loosened to 1 µm, as a sweep whose bound allows it builds its
    /// envelopes: the solves stop sooner, and still no pose reaches further than an
    /// interval end by more than the tolerance.
    #[test]
    fn envelope_agrees_with_brute_force_on_two_turning_axes(
        ball in any::<bool>(), c0 in -180.0..180.0f64, dc in -40.0..40.0f64,
        a0 in -20.0..20.0f64, da in -15.0..15.0f64, x0 in -5.0..5.0f64, dx in -2.0..2.0f64,
        y0 in -20.0..-10.0f64, z0 in 10.0..30.0f64, dz in -2.0..2.0f64,
        axis in 0usize..3, ou in -1.0..1.0f64, ov in -1.0..1.0f64,
        f0 in -0.2..0.6f64, f1 in 0.4..1.2f64,
    ) {
        let kind = if ball { ToolKind::Ball } else { ToolKind::Flat };
        let tool = Tool::try_new(kind, 6.0, 12.0).expect("valid");
        let at = |x: Real, z: Real, a: Real, cc: Real| {
            q(x, y0, z, a).with(AxisLetter::C, cc)
        };
        let (a, b) = (at(x0, z0, a0, c0), at(x0 + dx, z0 + dz, a0 + da, c0 + dc));
        for tol in [ENVELOPE_TOL, 1e-3] {
            check_against_brute_force(&trunnion(), &tool, (a, b), axis, (ou, ov), (f0, f1), tol)?;
        }
    }
}

/// A loosened envelope's interval ends lie within its tolerance of those of the envelope
/// built at [`ENVELOPE_TOL`] (itself within that of the true surface, by the brute-force
/// tests), never beyond them by more than the finer one's own tolerance (every end is the
/// exact interval of some pose), and some of them differ (the solves stop sooner): on the
/// trunnion's four moves, rays on a grid about the tool's middle along all three axes.
#[test]
fn a_loosened_envelope_stays_within_its_tolerance_of_the_finest() {
    let c = trunnion();
    let (mut differ, mut ends) = (0usize, 0usize);
    for kind in [ToolKind::Flat, ToolKind::Ball] {
        let tool = Tool::try_new(kind, 6.0, 12.0).expect("valid");
        for (a, b) in trunnion_moves() {
            let fine = RotaryEnvelope::new(&c, &tool, &a, &b).expect("supported");
            let mid = MovePath::new(&c, &a, &b).w_from_t(0.5) * Point3::new(0.0, 0.0, 6.0);
            for tol in [1e-5, 1e-3] {
                let loose = fine.clone().with_tolerance(tol);
                for axis in 0..3 {
                    let mut e = Vector3::zeros();
                    e[axis] = 1.0;
                    for (i, j) in (0..21).flat_map(|i| (0..21).map(move |j| (i, j))) {
                        let mut o = mid;
                        o[(axis + 1) % 3] += 0.45 * (i as Real - 10.0);
                        o[(axis + 2) % 3] += 0.65 * (j as Real - 10.0);
                        let (mut x, mut y) = (Vec::new(), Vec::new());
                        fine.intervals(&o, &e, &mut x);
                        loose.intervals(&o, &e, &mut y);
                        // A touch shallower than the tolerance may be left out.
                        let keep = |cs: Vec<RayCut>| -> Vec<RayCut> {
                            cs.into_iter()
                                .filter(|c| c.t_out - c.t_in > 4.0 * tol)
                                .collect()
                        };
                        let (x, y) = (keep(x), keep(y));
                        assert_eq!(x.len(), y.len(), "{kind:?} tol {tol}: {x:?} vs {y:?}");
                        for (p, q) in x.iter().zip(&y) {
                            for (f, l, outward) in [(p.t_in, q.t_in, -1.0), (p.t_out, q.t_out, 1.0)]
                            {
                                ends += 1;
                                differ += usize::from(f != l);
                                assert!(
                                    (f - l).abs() <= tol + 2.0 * ENVELOPE_TOL,
                                    "{kind:?} tol {tol}: {f} vs {l}"
                                );
                                assert!(
                                    outward * (l - f) <= 2.0 * ENVELOPE_TOL,
                                    "{kind:?} tol {tol}: the loose end {l} beyond {f}"
                                );
                            }
                        }
                    }
                }
            }
        }
    }
    assert!(ends > 1000, "{ends} ends");
    assert!(differ * 10 > ends, "{differ} of {ends} ends differ");
}

/// Four moves of the trunnion A/C turning both axes: two of the side cut (C 0.5°, A up to
/// 0.21°, the tool 19 mm from C's line), then A 35° with C 50° and A 60° with C 180°, the
/// linear axes moving.
fn trunnion_moves() -> [(AxisValues, AxisValues); 4] {
    let at = |x: Real, y: Real, z: Real, a: Real, cc: Real| q(x, y, z, a).with(AxisLetter::C, cc);
    [
        (
            at(0.0, -19.0, 40.0, 0.0, 0.0),
            at(0.0, -19.0, 39.995, 0.21, 0.5),
        ),
        (
            at(0.0, -19.0, 4.0, 7.9, 250.0),
            at(0.0, -19.0, 3.995, 8.0, 250.5),
        ),
        (
            at(3.0, -10.0, 20.0, -20.0, 30.0),
            at(-2.0, -14.0, 25.0, 15.0, 80.0),
        ),
        (
            at(0.0, 5.0, 60.0, 30.0, -90.0),
            at(1.0, 5.0, 58.0, -30.0, 90.0),
        ),
    ]
}

/// The speed bound that sizes the envelope's cells holds: on moves of the trunnion A/C
/// turning both axes (and the linear axes), no point of the tool, nor any within its reach
/// of the axis' middle, moves faster per unit λ than the bound, measured here by finite
/// differences of the chain's own poses over 2,000 steps at points on the tool's surface
/// and axis and on the sphere of that reach; and on the side cut's moves
/// (C 0.5°, A up to 0.21°, the tool 19 mm from C's line and 70-110 mm from A's) the bound
/// taking each axis with its own distance is well below the total turn times the largest
/// distance.
#[test]
fn the_speed_bound_holds_on_two_turning_axes() {
    let c = trunnion();
    let (r, l) = (3.0, 25.0);
    let tool = Tool::try_new(ToolKind::Flat, 2.0 * r, l).expect("valid");
    let points: Vec<Point3> = (0..=5)
        .flat_map(|h| {
            let z = l * h as Real / 5.0;
            (0..8)
                .map(move |k| {
                    let phi = k as Real * std::f64::consts::FRAC_PI_4;
                    Point3::new(r * phi.cos(), r * phi.sin(), z)
                })
                .chain([Point3::new(0.0, 0.0, z)])
        })
        // The bound holds for every point within the reach of the axis' middle: the sphere
        // of that radius, along the axes and the diagonals.
        .chain((0..27).filter(|&k| k != 13).map(|k| {
            let d = Vector3::new(
                (k % 3) as Real - 1.0,
                ((k / 3) % 3) as Real - 1.0,
                (k / 9) as Real - 1.0,
            );
            Point3::new(0.0, 0.0, l / 2.0) + d.normalize() * tool.reach_from(l / 2.0)
        }))
        .collect();
    let pose = |a: &AxisValues, b: &AxisValues, lam: Real| chain_pose(&c, a, b, lam);
    let moves = trunnion_moves();
    let state = [0.0; 6];
    let n = 2000;
    for (k, (a, b)) in moves.iter().enumerate() {
        let bound = speed_bound(&c, l / 2.0, tool.reach_from(l / 2.0), a, b, &state);
        let mut fastest: Real = 0.0;
        let mut prev = pose(a, b, 0.0);
        for s in 1..=n {
            let next = pose(a, b, s as Real / n as Real);
            for p in &points {
                fastest = fastest.max((next * p - prev * p).norm() * n as Real);
            }
            prev = next;
        }
        assert!(
            fastest <= bound,
            "move {k}: a tool point moves at {fastest} > bound {bound}"
        );
        // The whole bound: the total turn times the largest distance (widened by 1 + ω).
        let (omega, travel) = rotation_and_travel(&c, a, b);
        let mid = Point3::new(0.0, 0.0, l / 2.0);
        let mut rho: Real = 0.0;
        for qq in [a, b] {
            let m = c.w_from_t(qq) * mid;
            for (p, d) in c.rotary_lines_in_w(qq) {
                let w = m - p;
                rho = rho.max((w - d * w.dot(&d)).norm());
            }
        }
        let whole = omega * (rho + tool.reach_from(l / 2.0) + travel) * (1.0 + omega) + travel;
        assert!(
            bound <= whole,
            "move {k}: {bound} above the whole bound {whole}"
        );
        if k < 2 {
            assert!(
                bound < 0.7 * whole && fastest > 0.5 * bound,
                "move {k}: the per-axis bound {bound}, the whole {whole}, measured {fastest}"
            );
        }
    }
}

/// The smallest growth of a swept pose (tool of `shape`, radius `r`, length `l`, swept
/// along `±reach`) that holds the point `y` of its frame: the tests' own measure, by the
/// point's distance from the reach's segment across the axis (and, for the ball, from the
/// sphere centre's segment), never the cull's code.
fn growth_to_hold(shape: Shape, (r, l): (Real, Real), reach: &Vector3, y: &Vector3) -> Real {
    let nearest = |p: &Vector3, d: &Vector3| {
        let dd = d.norm_squared();
        let tau = if dd > 0.0 {
            (p.dot(d) / dd).clamp(-1.0, 1.0)
        } else {
            0.0
        };
        (p - d * tau).norm()
    };
    let dz = reach.z.abs();
    let dxy = Vector3::new(reach.x, reach.y, 0.0);
    let across = nearest(&Vector3::new(y.x, y.y, 0.0), &dxy) - r;
    let z0 = match shape {
        Shape::Flat => 0.0,
        Shape::Ball => r,
    };
    let along = (z0 - dz - y.z).max(y.z - l - dz);
    let side = across.max(along);
    match shape {
        Shape::Flat => side,
        Shape::Ball => side.min(nearest(&(y - Vector3::new(0.0, 0.0, r)), reach) - r),
    }
}

/// The swept cull's poses hold the tool over their stretch of the move: on moves of the
/// trunnion A/C turning both axes (the side cut's small moves, and moves turning A by 35°
/// and 60° with C by 50° and 180°, the linear axes moving), for flat and ball end mills,
/// every point of the tool's surface at 41 poses across each swept pose's stretch (the
/// chain's own poses, not the envelope's path) lies in that pose's tool translated along
/// its reach and grown by its growth, measured by the tests' own distance. The bound is
/// not loose: some point needs more than a tenth of the growth on every move, and on the
/// side cut's moves a half-cell's growth is below half of the kept poses' growth.
#[test]
fn swept_poses_hold_the_tool_over_their_stretch() {
    let c = trunnion();
    let (r, l) = (3.0, 25.0);
    let moves = trunnion_moves();
    for kind in [ToolKind::Flat, ToolKind::Ball] {
        let tool = Tool::try_new(kind, 2.0 * r, l).expect("valid");
        let shape = if kind == ToolKind::Flat {
            Shape::Flat
        } else {
            Shape::Ball
        };
        // Points of the tool's surface (tool frame): rims of the side, the end faces' disks
        // and, for the ball, its hemisphere.
        let mut points = Vec::new();
        let z0 = if shape == Shape::Flat { 0.0 } else { r };
        for h in 0..=10 {
            let z = z0 + (l - z0) * h as Real / 10.0;
            for k in 0..24 {
                let phi = k as Real * std::f64::consts::TAU / 24.0;
                points.push(Vector3::new(r * phi.cos(), r * phi.sin(), z));
            }
        }
        for k in 0..12 {
            let phi = k as Real * std::f64::consts::TAU / 12.0;
            points.push(Vector3::new(0.5 * r * phi.cos(), 0.5 * r * phi.sin(), l));
            if shape == Shape::Flat {
                points.push(Vector3::new(0.5 * r * phi.cos(), 0.5 * r * phi.sin(), 0.0));
            }
        }
        if shape == Shape::Ball {
            for i in 0..=6 {
                let th = i as Real * std::f64::consts::FRAC_PI_2 / 6.0;
                for k in 0..24 {
                    let phi = k as Real * std::f64::consts::TAU / 24.0;
                    points.push(Vector3::new(
                        r * th.sin() * phi.cos(),
                        r * th.sin() * phi.sin(),
                        r - r * th.cos(),
                    ));
                }
            }
        }
        for (m, (a, b)) in moves.iter().enumerate() {
            let env = RotaryEnvelope::new(&c, &tool, a, b).expect("supported");
            let swept = env.swept.as_ref().expect("constant rates: the swept cull");
            let n = env.cells() as Real;
            assert_eq!(swept.poses.len(), 3 * env.cells());
            let mut most: Real = 0.0;
            for (k, s) in swept.poses.iter().enumerate() {
                let j = (k / 3) as Real;
                let (mid, half) = match k % 3 {
                    0 => ((2.0 * j + 1.0) / (2.0 * n), 0.5 / n),
                    1 => ((4.0 * j + 1.0) / (4.0 * n), 0.25 / n),
                    _ => ((4.0 * j + 3.0) / (4.0 * n), 0.25 / n),
                };
                for i in 0..=40 {
                    let lam = mid + half * (i as Real / 20.0 - 1.0);
                    let pose = chain_pose(&c, a, b, lam);
                    for x in &points {
                        let w = pose * Point3::from(*x);
                        let y = s.rot.tr_mul(&(w - s.tip));
                        let need = growth_to_hold(shape, (r, l), &s.reach, &y);
                        assert!(
                            need <= s.grow,
                            "{kind:?} move {m}, swept pose {k}, λ {lam}: the point {x:?} needs \
                             {need} > {}",
                            s.grow
                        );
                        most = most.max(need / s.grow);
                    }
                }
                if m < 2 && k % 3 != 0 {
                    assert!(
                        s.grow < 0.5 * env.cull.grow,
                        "{kind:?} move {m}: a half-cell's growth {} vs the kept poses' {}",
                        s.grow,
                        env.cull.grow
                    );
                }
            }
            assert!(
                most > 0.1,
                "{kind:?} move {m}: at most {most} of the growth needed"
            );
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, failure_persistence: None, rng_seed: proptest::test_runner::RngSeed::Fixed(0x5e9), ..ProptestConfig::default() })]

    /// The swept cull's least distance between a ray's stretch and the reach's segment is
    /// not above the least found by the tests' own search (golden sections over the
    /// segment, the stretch's nearest point in closed form), and below it by no more than
    /// its allowance where the two are nearly parallel (none otherwise): over stretches in
    /// general position, nearly parallel to the segment (1e-7 rad), of no direction, and
    /// segments of no length.
    #[test]
    fn the_swept_cull_finds_the_least_distance(
        p in prop::array::uniform3(-5.0..5.0f64), u in prop::array::uniform3(-1.0..1.0f64),
        d in prop::array::uniform3(-2.0..2.0f64), lo in -6.0..6.0f64, len in 0.0..8.0f64,
        case in 0..4usize, tilt in -1e-7..1e-7f64,
    ) {
        let (p, mut u, mut d) = (Vector3::from(p), Vector3::from(u), Vector3::from(d));
        match case {
            1 => u = d + Vector3::new(tilt, -tilt, 0.0),
            2 => d = Vector3::zeros(),
            3 => u = Vector3::new(0.0, 0.0, 0.0),
            _ => {}
        }
        if u.norm() > 0.0 { u = u.normalize(); }
        let hi = lo + len;
        let got = cull::least_distance2(&p, &cull::Pair::new(u, d), (lo, hi));
        // For a point of the segment, the stretch's nearest point in closed form.
        let at = |tau: Real| {
            let w = p - d * tau;
            let t = if u.norm_squared() > 0.0 { (-w.dot(&u) / u.norm_squared()).clamp(lo, hi) } else { lo };
            (w + u * t).norm_squared()
        };
        let (mut a, mut b) = (-1.0, 1.0);
        let g = (5.0f64.sqrt() - 1.0) / 2.0;
        for _ in 0..200 {
            let (x1, x2) = (b - g * (b - a), a + g * (b - a));
            if at(x1) <= at(x2) { b = x2 } else { a = x1 }
        }
        let best = at(0.5 * (a + b)).min(at(-1.0)).min(at(1.0));
        prop_assert!(got <= best + 1e-12 * (1.0 + best), "{got} vs {best}");
        // Nearly parallel, the edges' least less its allowance for the interior.
        prop_assert!(got >= best - 2e-8 * len * len - 1e-12 * (1.0 + best), "{got} vs {best}");
    }
}

/// A case a random search found in an earlier, Brent-based envelope: a z ray the flat
/// tool leaves through the edge of its top face while A turns. The farthest exit is where
/// the ray passes through the top edge circle (λ ≈ 0.924), at the end of the poses that
/// meet the ray; 20,001 independent poses must not reach beyond the envelope.
#[test]
fn envelope_reaches_the_farthest_pose_on_a_grazing_top_face_ray() {
    let c = deviated();
    let tool = Tool::try_new(ToolKind::Flat, 6.0, 12.0).expect("valid");
    let (a, b) = (
        q(
            0.0,
            0.094_409_715_186_335,
            7.462_192_328_664_928,
            -33.606_531_410_104_42,
        ),
        q(
            0.0,
            0.094_409_715_186_335,
            7.462_192_328_664_928 + 0.545_658_555_771_143_7,
            -33.606_531_410_104_42 + 23.179_489_768_036_89,
        ),
    );
    let env = RotaryEnvelope::new(&c, &tool, &a, &b).expect("supported");
    let mut o = MovePath::new(&c, &a, &b).w_from_t(0.5) * Point3::new(0.0, 0.0, 3.0);
    o.y += 4.0 * 0.768_904_124_454_249_4;
    let e = Vector3::z();
    let mut cuts = Vec::new();
    env.intervals(&o, &e, &mut cuts);
    let far = cuts.last().expect("the ray is cut").t_out;
    let n = 20_000;
    for k in 0..=n {
        let l = k as Real / n as Real;
        if let Some((_, t1)) = exact_at(&c, &tool, &a, &b, l, &o, &e) {
            assert!(
                t1 <= far + ENVELOPE_TOL,
                "pose λ = {l} exits at {t1}, envelope at {far}"
            );
        }
    }
}

#[test]
fn a_half_turn_leaves_two_intervals_on_a_ray_the_tool_crosses_twice() {
    // Nominal chain, tool tip 5 mm from the A axis pointing away from it, A turning
    // 0 → 180°: a z ray at y = 0, x = 0 meets the tool at A = 0 (z ∈ [5, 15]) and at
    // A = 180° (z ∈ [−15, −5]); in between the tool swings through the y side.
    let c = crate::machine::chain::mdx50_for_tests();
    let tool = Tool::try_new(ToolKind::Flat, 2.0, 10.0).expect("valid");
    let (a, b) = (q(0.0, 0.0, 5.0, 0.0), q(0.0, 0.0, 5.0, 180.0));
    let env = RotaryEnvelope::new(&c, &tool, &a, &b).expect("supported");
    let mut cuts = Vec::new();
    env.intervals(&Point3::new(0.0, 0.0, 0.0), &Vector3::z(), &mut cuts);
    assert_eq!(cuts.len(), 2, "{cuts:?}");
    // The ray (y = 0) at angle a: the tool covers |y_t| ≤ 1 about its axis, so the
    // z extent at a = ±asin(1/z)… the extremes are ±(sqrt(15² + 1²))·cos… take the
    // exact: points (0, 0, z) inside the tool at some a ∈ [0, π]: |z|·|sin a| ≤ 1 and
    // 5 ≤ |z|·cos a (or −cos a) ≤ 15 → |z| ∈ [5, sqrt(15² + 1)].
    let far = (15.0f64 * 15.0 + 1.0).sqrt();
    assert!((cuts[0].t_in + far).abs() < ENVELOPE_TOL, "{cuts:?}");
    assert!((cuts[0].t_out + 5.0).abs() < ENVELOPE_TOL, "{cuts:?}");
    assert!((cuts[1].t_in - 5.0).abs() < ENVELOPE_TOL, "{cuts:?}");
    assert!((cuts[1].t_out - far).abs() < ENVELOPE_TOL, "{cuts:?}");
    // Material normals face into the cut: +z at the lower ends of each interval.
    assert!(cuts[1].n_in.z > 0.99 && cuts[0].n_in.z > 0.0, "{cuts:?}");
}

/// The envelope with its cull test (`cull`, counting the rays it skips) or without it (every
/// ray in its box solved).
struct Wrapped<'a> {
    env: &'a RotaryEnvelope,
    cull: bool,
    skipped: std::sync::atomic::AtomicUsize,
}

impl<'a> Wrapped<'a> {
    fn new(env: &'a RotaryEnvelope, cull: bool) -> Self {
        Wrapped {
            env,
            cull,
            skipped: Default::default(),
        }
    }
}

impl Cutter for Wrapped<'_> {
    fn bounds(&self) -> Aabb {
        self.env.bounds()
    }
    fn ray_cut(&self, origin: &Point3, axis: usize) -> Option<RayCut> {
        self.env.ray_cut(origin, axis)
    }
    fn costly_rays(&self) -> bool {
        true
    }
    fn may_cut(&self, origin: &Point3, axis: usize, segs: &[Segment]) -> bool {
        let may = !self.cull || Cutter::may_cut(self.env, origin, axis, segs);
        if !may {
            self.skipped
                .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        }
        may
    }
    fn ray_cuts_in_span(
        &self,
        origin: &Point3,
        axis: usize,
        span: (Real, Real),
        line: u32,
        out: &mut Vec<RayCut>,
        lines: &mut Vec<[u32; 2]>,
    ) {
        self.env
            .ray_cuts_in_span(origin, axis, span, line, out, lines);
    }
}

/// Every crossing of the stock, bit for bit: point, coordinate, normal and NC line.
fn crossing_bits(s: &crate::cutting::stock::TriDexel) -> Vec<[u64; 8]> {
    let mut out = Vec::new();
    for g in s.grids() {
        g.for_each_crossing(|p, c| {
            let n = c.normal();
            out.push([
                g.axis() as u64,
                p.x.to_bits(),
                p.y.to_bits(),
                p.z.to_bits(),
                n.x.to_bits(),
                n.y.to_bits(),
                n.z.to_bits(),
                c.line as u64,
            ]);
        });
    }
    out
}

/// A chain of small rotary moves from X −1 and the given `[y, z, a]`, each step
/// `(da, dx, dy, dz)` added to the last pose: their envelopes.
fn move_chain(
    c: &Chain,
    tool: &Tool,
    [y0, z0, a0]: [Real; 3],
    steps: &[(Real, Real, Real, Real)],
) -> Vec<RotaryEnvelope> {
    let mut at = q(-1.0, y0, z0, a0);
    let mut out = Vec::with_capacity(steps.len());
    for &(da, dx, dy, dz) in steps {
        let next = q(
            at.get(AxisLetter::X) + dx,
            at.get(AxisLetter::Y) + dy,
            at.get(AxisLetter::Z) + dz,
            at.get(AxisLetter::A) + da,
        );
        out.push(RotaryEnvelope::new(c, tool, &at, &next).expect("supported"));
        at = next;
    }
    out
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 12, failure_persistence: None, rng_seed: proptest::test_runner::RngSeed::Fixed(0xc011), ..ProptestConfig::default() })]

    /// The cull test changes nothing: a chain of small rotary moves (A turning 0.2–2° a
    /// move with X, Y and Z) cut into a box with the cull test and with every ray solved
    /// leaves the same crossings, bit for bit; and the test does skip rays.
    #[test]
    fn culled_sweep_is_bit_identical_to_the_unculled_one(
        ball in any::<bool>(), a0 in -30.0..30.0f64, y0 in -2.0..2.0f64, z0 in 3.0..4.5f64,
        steps in proptest::collection::vec(
            (0.2..2.0f64, -0.3..0.3f64, -0.05..0.05f64, -0.1..0.05f64), 6..14),
    ) {
        use crate::cutting::stock::TriDexel;
        let c = deviated();
        let kind = if ball { ToolKind::Ball } else { ToolKind::Flat };
        let tool = Tool::try_new(kind, 4.0, 10.0).expect("valid");
        let bounds = Aabb { min: Point3::new(-5.0, -5.0, -5.0), max: Point3::new(5.0, 5.0, 5.0) };
        let mut culled = TriDexel::new_box(bounds, 0.2, 1e9).expect("fits");
        let mut plain = culled.clone();
        let mut skipped = 0;
        for (k, env) in move_chain(&c, &tool, [y0, z0, a0], &steps).iter().enumerate() {
            let counted = Wrapped::new(env, true);
            culled.remove(&counted, k as u32 + 1);
            plain.remove(&Wrapped::new(env, false), k as u32 + 1);
            skipped += counted.skipped.into_inner();
        }
        prop_assert!(skipped > 0, "no ray was culled");
        prop_assert!(crossing_bits(&culled) == crossing_bits(&plain));
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 12, failure_persistence: None, rng_seed: proptest::test_runner::RngSeed::Fixed(0xba7c), ..ProptestConfig::default() })]

    /// Cutting a chain of small rotary moves together (each ray taken through every move,
    /// the last first, [`TriDexel::remove_each`]) leaves the same crossings, bit for bit, as
    /// removing them one after another, and says of each move whether it cut as removing
    /// them one by one from the last does; some moves of the chain cut and a far one does
    /// not.
    #[test]
    fn moves_cut_together_are_bit_identical_to_moves_cut_in_turn(
        ball in any::<bool>(), a0 in -30.0..30.0f64, y0 in -2.0..2.0f64, z0 in 3.0..4.5f64,
        steps in proptest::collection::vec(
            (0.2..2.0f64, -0.3..0.3f64, -0.05..0.05f64, -0.1..0.05f64), 6..14),
    ) {
        use crate::cutting::stock::TriDexel;
        let c = deviated();
        let kind = if ball { ToolKind::Ball } else { ToolKind::Flat };
        let tool = Tool::try_new(kind, 4.0, 10.0).expect("valid");
        let bounds = Aabb { min: Point3::new(-5.0, -5.0, -5.0), max: Point3::new(5.0, 5.0, 5.0) };
        let mut together = TriDexel::new_box(bounds, 0.2, 1e9).expect("fits");
        let mut in_turn = together.clone();
        let mut envs = move_chain(&c, &tool, [y0, z0, a0], &steps);
        // A move far above the stock, in the middle of the chain: it cuts nothing.
        let high = |z| q(0.0, 0.0, z, a0);
        envs.insert(3, RotaryEnvelope::new(&c, &tool, &high(40.0), &high(41.0)).expect("supported"));
        for (k, env) in envs.iter().enumerate() {
            in_turn.remove(env, k as u32 + 1);
        }
        let cutters: Vec<(&dyn Cutter, u32)> = envs
            .iter()
            .enumerate()
            .map(|(k, env)| (env as &dyn Cutter, k as u32 + 1))
            .collect();
        // Whether each move cut, the moves removed one by one from the last.
        let mut from_last = TriDexel::new_box(bounds, 0.2, 1e9).expect("fits");
        let mut latest_first: Vec<bool> = envs
            .iter()
            .enumerate()
            .rev()
            .map(|(k, env)| from_last.remove(env, k as u32 + 1))
            .collect();
        latest_first.reverse();
        let expected = latest_first;
        let removed = together.remove_each(&cutters, &[]).by_cutter;
        prop_assert!(expected.iter().filter(|&&c| c).count() >= 2, "{expected:?}");
        prop_assert!(!expected[3]);
        prop_assert_eq!(&removed, &expected);
        prop_assert!(crossing_bits(&together) == crossing_bits(&in_turn));
        // In groups of three, each tested at once by its hull: the same again.
        let mut grouped = TriDexel::new_box(bounds, 0.2, 1e9).expect("fits");
        let hulls: Vec<(std::ops::Range<usize>, GroupHull)> = (0..envs.len())
            .step_by(3)
            .map(|a| a..(a + 3).min(envs.len()))
            .map(|g| (g.clone(), GroupHull::of(&envs[g].iter().collect::<Vec<_>>())))
            .collect();
        let groups: Vec<crate::cutting::stock::Group> = hulls
            .iter()
            .map(|(g, hull)| crate::cutting::stock::Group { cutters: g.clone(), cull: hull })
            .collect();
        let by_groups = grouped.remove_each(&cutters, &groups);
        prop_assert!(by_groups.group_tests > 0 && by_groups.group_skips > 0, "{by_groups:?}");
        prop_assert_eq!(&by_groups.by_cutter, &expected);
        prop_assert!(crossing_bits(&grouped) == crossing_bits(&in_turn));
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 4000, failure_persistence: None, rng_seed: proptest::test_runner::RngSeed::Fixed(0x9e0), ..ProptestConfig::default() })]

    /// The cull's test without roots (`cull::grown_meets`) answers as the grown tool's
    /// interval against the material does: whenever the interval meets a segment so does
    /// it, and it says yes only where the tool grown by 1e-9 mm more meets one — for flat
    /// and ball end mills, lines in any direction (along the tool's axis and across it
    /// among them) and one to three segments of material.
    #[test]
    fn the_cull_test_without_roots_agrees_with_the_grown_interval(
        ball in any::<bool>(), p in (-8.0..8.0f64, -8.0..8.0f64, -6.0..32.0f64),
        dir in (-1.0..1.0f64, -1.0..1.0f64, -1.0..1.0f64), axial in 0..4usize,
        g in 0.0..1.0f64,
        cuts in proptest::collection::vec((-30.0..30.0f64, 0.01..12.0f64), 1..4),
    ) {
        use crate::cutting::stock::{Crossing, Segment};
        let shape = if ball { Shape::Ball } else { Shape::Flat };
        let (r, l) = (3.0, 25.0);
        let p = Vector3::new(p.0, p.1, p.2);
        let u = match axial {
            0 => Vector3::z(),
            1 => Vector3::new(dir.0, dir.1, 0.0),
            _ => Vector3::new(dir.0, dir.1, dir.2),
        };
        let Some(u) = u.try_normalize(1e-6) else { return Ok(()) };
        // Disjoint sorted segments from the drawn starts and lengths.
        let mut starts: Vec<(Real, Real)> = cuts;
        starts.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut segs: Vec<Segment> = Vec::new();
        let end = |t: Real| Crossing { t, normal: [0.0, 0.0, 1.0], line: 0 };
        for (t0, len) in starts {
            let t0 = segs.last().map_or(t0, |s| t0.max(s.hi.t + 0.01));
            segs.push(Segment { lo: end(t0), hi: end(t0 + len) });
        }
        let reference = |g: Real| {
            cull::meets_material(tool_interval(shape, r, l, &p, &u, g), &segs)
        };
        let fast = cull::grown_meets(shape, (r, l), &p, &u, g, &segs);
        if reference(g) {
            prop_assert!(fast, "the interval meets the material, the test says no");
        }
        if fast {
            prop_assert!(reference(g + 1e-9), "the test says yes, the interval grown by 1e-9 misses");
        }
    }
}

/// Material along the whole of a ray.
fn whole_ray() -> [crate::cutting::stock::Segment; 1] {
    use crate::cutting::stock::{Crossing, Segment};
    let end = |t: Real| Crossing {
        t,
        normal: [0.0, 0.0, 1.0],
        line: 0,
    };
    [Segment {
        lo: end(-1e3),
        hi: end(1e3),
    }]
}

/// Every x, y and z ray of a 0.05 mm grid across `b`: `f(origin, axis, direction)`.
fn grid_rays(b: &Aabb, f: impl FnMut(Point3, usize, Vector3)) {
    grid_rays_every(0.05, b, f);
}

/// Every x, y and z ray of a grid of pitch `step` (mm) across `b`.
fn grid_rays_every(step: Real, b: &Aabb, mut f: impl FnMut(Point3, usize, Vector3)) {
    for axis in 0..3 {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        let n = |k: usize| ((b.max[k] - b.min[k]) / step) as usize;
        for i in 0..=n(u) {
            for j in 0..=n(v) {
                let mut o = Point3::origin();
                o[u] = b.min[u] + step * i as Real;
                o[v] = b.min[v] + step * j as Real;
                f(o, axis, Vector3::ith(axis, 1.0));
            }
        }
    }
}

/// The cull never skips a ray the tool meets: material along the whole of every ray of a
/// fine grid (x, y and z rays at 0.05 mm across the move's box) on moves of several cells
/// (A turning 12° and 30° with X, Y and Z), each ray the cull skips is met by no pose of
/// the move sampled every 1/4096 of it (the tool's interval at each pose, no growth). Many
/// rays are skipped only after the middle pose of their cell, grown to hold the cell, met
/// them: the kept poses decided.
#[test]
fn culled_rays_meet_no_pose_of_the_move() {
    let c = deviated();
    let material = whole_ray();
    for (kind, a1, dx, dz) in [
        (ToolKind::Flat, 12.0, 0.4, -0.2),
        (ToolKind::Ball, 30.0, -0.6, 0.3),
    ] {
        let tool = Tool::try_new(kind, 4.0, 10.0).expect("valid");
        let env = RotaryEnvelope::new(
            &c,
            &tool,
            &q(-1.0, 0.5, 3.0, 0.0),
            &q(-1.0 + dx, 0.3, 3.0 + dz, a1),
        )
        .expect("supported");
        assert!(env.cells() >= 2, "{} cells", env.cells());
        let poses: Vec<Sample> = (0..=4096)
            .map(|k| env.path.sample(k as Real / 4096.0))
            .collect();
        let b = env.bounds();
        let (mut skipped, mut decided_by_kept) = (0, 0);
        grid_rays(&b, |o, axis, e| {
            if env.may_cut(&o, axis, &material) {
                return;
            }
            skipped += 1;
            let meets_at = |s: &Sample, g: Real| {
                let p = s.rot.tr_mul(&(o - s.tip));
                let w = s.rot.tr_mul(&e);
                tool_interval(env.shape, env.r, env.l, &p, &w, g).is_some()
            };
            if (0..env.cells()).any(|k| meets_at(&env.samples[2 * k + 1], env.delta)) {
                decided_by_kept += 1;
            }
            assert!(
                !poses.iter().any(|s| meets_at(s, 0.0)),
                "{kind:?}: the ray through {o:?} along axis {axis} was skipped but the tool meets it"
            );
        });
        assert!(
            decided_by_kept > 1000,
            "{kind:?}: {decided_by_kept} of {skipped}"
        );
    }
}

/// A group hull holds every pose of its moves: on four consecutive moves (A turning 1° a
/// move with X, Y and Z, flat and ball end mills), every ray of a fine grid (x, y and z
/// rays at 0.05 mm across the moves' box) that the hull clears, with material along the
/// whole ray, is met by no pose of any of the moves sampled every 1/1024 of it (the tool's
/// interval at each pose, no growth); so for the grown reference tool alone (the hull of
/// moves without the swept cull). Hundreds of the rays each clears pass within 0.5 mm of a
/// pose; the grown tool's growth is at most a cell's own growth plus 2.5 moves' travel (the
/// farthest cell middle is 1.5 moves from the reference pose), and the swept hull clears
/// half as many rays again, dozens of them within 0.1 mm of a pose.
#[test]
fn rays_a_group_hull_clears_meet_no_pose_of_its_moves() {
    use crate::cutting::stock::GroupCull;
    let c = deviated();
    let material = whole_ray();
    for kind in [ToolKind::Flat, ToolKind::Ball] {
        let tool = Tool::try_new(kind, 4.0, 10.0).expect("valid");
        let envs = move_chain(&c, &tool, [0.5, 3.0, -10.0], &[(1.0, 0.1, -0.05, -0.05); 4]);
        let group: Vec<&RotaryEnvelope> = envs.iter().collect();
        let swept = GroupHull::of(&group);
        assert!(swept.swept.is_some(), "constant rates: the swept hull");
        let mut grown = swept.clone();
        grown.swept = None;
        // Its growth: the cells' own plus at most two moves' travel from the reference.
        let travel: Real = envs.iter().map(|e| e.speed).fold(0.0, Real::max);
        assert!(
            grown.grow() <= 2.5 * travel + envs[0].delta,
            "{} vs {travel}",
            grown.grow()
        );
        let poses: Vec<Sample> = envs
            .iter()
            .flat_map(|env| (0..=1024).map(|k| env.path.sample(k as Real / 1024.0)))
            .collect();
        let mut b = Aabb::empty();
        for eb in envs.iter().map(|e| e.bounds()) {
            b.grow(&eb.min);
            b.grow(&eb.max);
        }
        let mut counts = Vec::new();
        for hull in [&grown, &swept] {
            let (mut cleared, mut near, mut close) = (0, 0, 0);
            grid_rays(&b, |o, axis, e| {
                if GroupCull::may_cut(hull, &o, axis, &material) {
                    return;
                }
                cleared += 1;
                let meets = |s: &Sample, g: Real| {
                    let p = s.rot.tr_mul(&(o - s.tip));
                    let w = s.rot.tr_mul(&e);
                    tool_interval(envs[0].shape, envs[0].r, envs[0].l, &p, &w, g).is_some()
                };
                assert!(
                    !poses.iter().any(|s| meets(s, 0.0)),
                    "{kind:?}: the hull cleared the ray through {o:?} along axis {axis}, which a pose meets"
                );
                if poses.iter().step_by(64).any(|s| meets(s, 0.5)) {
                    near += 1;
                }
                if poses.iter().step_by(16).any(|s| meets(s, 0.1)) {
                    close += 1;
                }
            });
            assert!(
                near > 300,
                "{kind:?}: {near} of {cleared} cleared rays within 0.5 mm of a pose"
            );
            counts.push((cleared, close));
        }
        let [(grown_cleared, _), (swept_cleared, swept_close)] = counts[..] else {
            unreachable!("two hulls")
        };
        assert!(
            2 * swept_cleared > 3 * grown_cleared && swept_close > 50,
            "{kind:?}: the swept hull clears {swept_cleared} ({swept_close} within 0.1 mm), \
             the grown tool {grown_cleared}"
        );
    }
}

/// The Hermite guess of the extreme solve is exact for a cubic: for `t(λ) = (λ − p)²·(λ − s)`
/// (a local minimum at `λ* = (2s + p)/3` when `s > p`), given `t` and `t'` at the bracket's
/// ends, it returns `λ*`; it returns NaN where the slope keeps its sign, and a quadratic
/// (no cubic term) has its vertex found too.
#[test]
fn the_hermite_guess_finds_a_cubic_s_extreme() {
    let (p, s) = (0.1, 1.3);
    let t = |l: Real| (l - p) * (l - p) * (l - s);
    let dt = |l: Real| 2.0 * (l - p) * (l - s) + (l - p) * (l - p);
    let want = (2.0 * s + p) / 3.0;
    for (l0, l1) in [(0.5, 1.0), (0.2, 0.95), (0.85, 0.9)] {
        let got = hermite_extreme((l0, l1), (t(l0), t(l1)), (dt(l0), dt(l1)));
        assert!((got - want).abs() < 1e-12, "[{l0}, {l1}]: {got} vs {want}");
    }
    // Falling throughout [1.2, 2.0]'s left part only: a bracket without the minimum.
    let none = hermite_extreme((0.2, 0.5), (t(0.2), t(0.5)), (dt(0.2), dt(0.5)));
    assert!(none.is_nan(), "{none}");
    // t = (λ − 0.37)²: the vertex.
    let q = |l: Real| (l - 0.37) * (l - 0.37);
    let dq = |l: Real| 2.0 * (l - 0.37);
    let got = hermite_extreme((0.0, 1.0), (q(0.0), q(1.0)), (dq(0.0), dq(1.0)));
    assert!((got - 0.37).abs() < 1e-12, "{got}");
}

/// A reproducible stream of numbers uniform in [0, 1) from `seed` (a 64-bit linear
/// congruential generator's top 53 bits).
fn uniform(mut seed: u64) -> impl FnMut() -> Real {
    move || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (seed >> 11) as Real / (1u64 << 53) as Real
    }
}

/// The second-order touch test rules a touch out only where the tool never meets the ray:
/// on the trunnion's moves (the side cut's two and the two large ones), for flat and ball
/// end mills, axis rays through points near the tool's side, its bottom edge and below its
/// end at a random pose, in the half-cell around that pose and three finer halvings of it,
/// wherever both ends miss and the test rules a touch out, no pose of 400 between them (the
/// chain's own poses, not the envelope's path) meets the tool. Both ways are exercised: the
/// test rules out nearly all rays the side passes more than 1 µm clear of, and keeps rays
/// that meet the tool (by half or twice the tolerance) between two missing ends.
#[test]
fn the_touch_test_rules_out_only_rays_the_tool_never_meets() {
    let c = trunnion();
    let (r, l) = (3.0, 25.0);
    let tol = 1e-4;
    let mut next = uniform(0x70c4);
    // Half-cells asked about and ruled out: all, and those of the side cut's moves whose ray
    // passes the side more than 1 µm clear of it.
    let (mut asked, mut ruled_out, mut deep_kept) = ([0; 2], [0; 2], 0);
    for (kind, shape) in [(ToolKind::Flat, Shape::Flat), (ToolKind::Ball, Shape::Ball)] {
        let tool = Tool::try_new(kind, 2.0 * r, l).expect("valid");
        for (m, (qa, qb)) in trunnion_moves().into_iter().enumerate() {
            let env = RotaryEnvelope::new(&c, &tool, &qa, &qb)
                .expect("envelope")
                .with_tolerance(tol);
            for _ in 0..1200 {
                let (mut lam, mut phi) = (next(), next() * std::f64::consts::TAU);
                let (mut d, place) = (-2e-3 + next() * 5e-3, (next() * 4.0) as usize);
                let height = 0.5 + next() * 24.0;
                if place == 3 {
                    // Twice or half the tolerance into the side where it moves along
                    // itself, in the middle of a half-cell: the tool passes the ray.
                    let n = 2 * env.cells();
                    lam = ((lam * n as Real).floor() + 0.5) / n as Real;
                    d = if d < 0.5e-3 { -2.0 * tol } else { -0.5 * tol };
                    let axis_point = Point3::new(0.0, 0.0, height);
                    let at = |s: Real| chain_pose(&c, &qa, &qb, s);
                    let moved = at(lam).inverse_transform_vector(
                        &(at(lam + 1e-4) * axis_point - at(lam - 1e-4) * axis_point),
                    );
                    phi = moved.y.atan2(moved.x)
                        + std::f64::consts::FRAC_PI_2 * (1.0 + 2.0 * (phi / 7.0).floor());
                }
                let point = match place {
                    0 | 3 => Point3::new((r + d) * phi.cos(), (r + d) * phi.sin(), height),
                    1 if shape == Shape::Flat => {
                        Point3::new((r + d) * phi.cos(), (r + d) * phi.sin(), -next() * 3e-3)
                    }
                    _ => {
                        let rho = next() * r;
                        let below = match shape {
                            Shape::Flat => -d,
                            Shape::Ball => r - (r * r - rho * rho).sqrt() - d,
                        };
                        Point3::new(rho * phi.cos(), rho * phi.sin(), below)
                    }
                };
                let x = chain_pose(&c, &qa, &qb, lam) * point;
                let axis = if place == 3 {
                    2
                } else {
                    (next() * 3.0) as usize % 3
                };
                let mut o = x;
                o[axis] = 0.0;
                let mut e = Vector3::zeros();
                e[axis] = 1.0;
                let ray = Ray {
                    o: &o,
                    e: &e,
                    span: (Real::NEG_INFINITY, Real::INFINITY),
                    axis: Some(axis),
                };
                for j in 0..4 {
                    let w = 1.0 / (2 * env.cells() * (1 << j)) as Real;
                    let a = (lam / w).floor().min((1.0 / w).round() - 1.0) * w;
                    let b = a + w;
                    let (pa, pb) = (env.probe_at(a, &ray), env.probe_at(b, &ray));
                    if pa.hit.is_some() || pb.hit.is_some() {
                        continue;
                    }
                    let grazing = m < 2 && place == 0 && d > 1e-3;
                    asked[0] += 1;
                    asked[1] += usize::from(grazing);
                    // Whether a pose between the ends meets the tool grown by `g`.
                    let meets = |g: Real| {
                        (0..=400).any(|i| {
                            let pose = chain_pose(&c, &qa, &qb, a + w * i as Real / 400.0);
                            let p = pose.inverse_transform_point(&o).coords;
                            let u = pose.inverse_transform_vector(&e);
                            tool_interval(shape, r, l, &p, &u, g).is_some()
                        })
                    };
                    if env.touch_ruled_out(&ray, (&pa, &pb)) {
                        ruled_out[0] += 1;
                        ruled_out[1] += usize::from(grazing);
                        assert!(
                            !meets(0.0),
                            "{kind:?}, move {qa:?} → {qb:?}: a touch ruled out on axis {axis} \
                             between λ {a} and {b} (ray through {x})"
                        );
                    } else if meets(-tol) {
                        deep_kept += 1;
                    }
                }
            }
        }
    }
    assert!(
        ruled_out[1] * 10 >= asked[1] * 9 && asked[1] > 30 && deep_kept > 20,
        "{ruled_out:?} of {asked:?} half-cells ruled out, {deep_kept} deep touches kept"
    );
}

/// The bits of an interval: its ends and their normals.
fn cut_bits(c: &RayCut) -> [u64; 8] {
    [
        c.t_in, c.t_out, c.n_in.x, c.n_in.y, c.n_in.z, c.n_out.x, c.n_out.y, c.n_out.z,
    ]
    .map(Real::to_bits)
}

/// Every x, y and z ray of a 0.05 mm grid across the first two trunnion moves (one cell
/// each), for a flat and a ball end mill (Ø6 × 25 mm), given to `f` with the move's envelope
/// and a span along it: the whole ray with probability `whole`, else a random stretch of the
/// move's box (drawn from `seed`), and the draws for `f`'s own use.
fn one_cell_rays(
    seed: u64,
    whole: Real,
    mut f: impl FnMut(
        ToolKind,
        &RotaryEnvelope,
        (Point3, usize, Vector3),
        (Real, Real),
        &mut dyn FnMut() -> Real,
    ),
) {
    let c = trunnion();
    let mut next = uniform(seed);
    for kind in [ToolKind::Flat, ToolKind::Ball] {
        let tool = Tool::try_new(kind, 6.0, 25.0).expect("valid");
        for (qa, qb) in trunnion_moves().into_iter().take(2) {
            let env = RotaryEnvelope::new(&c, &tool, &qa, &qb).expect("envelope");
            assert_eq!(env.cells(), 1);
            let b = env.bounds();
            grid_rays(&b, |o, axis, e| {
                let (lo, hi) = (b.min[axis], b.max[axis]);
                let span = if next() < whole {
                    (Real::NEG_INFINITY, Real::INFINITY)
                } else {
                    let (x, y) = (lo + next() * (hi - lo), lo + next() * (hi - lo));
                    (x.min(y), x.max(y))
                };
                f(kind, &env, (o, axis, e), span, &mut next);
            });
        }
    }
}

/// A move of one cell probed without its grown-tool test (a ray the cull kept,
/// [`RotaryEnvelope::intervals_near`]) cuts the material's extent exactly as with the test:
/// on the side cut's two moves (C 0.5°, flat and ball end mills, one cell each), every x, y
/// and z ray of a 0.05 mm grid across the move's box, with the material's extent a random
/// stretch of the ray (or the whole ray), gets the same intervals, bit for bit, wherever
/// they reach into that stretch; what else it gets lies wholly outside it. Some rays do get
/// such intervals (the grown test had skipped the cell: the stretch lies clear of the tool),
/// and thousands get the same intervals inside it.
#[test]
fn a_one_cell_move_probed_without_its_grown_test_cuts_the_same_span() {
    let (mut same, mut outside) = (0, 0);
    one_cell_rays(0x5ba7, 0.2, |kind, env, (o, axis, e), span, _| {
        let (mut with, mut without) = (Vec::new(), Vec::new());
        env.intervals_in(&o, &e, span, &mut with);
        env.intervals_near(&o, &e, span, true, &mut without);
        let reaches = |c: &&RayCut| c.t_out >= span.0 && c.t_in <= span.1;
        let (a, b): (Vec<_>, Vec<_>) = (
            with.iter().filter(reaches).map(cut_bits).collect(),
            without.iter().filter(reaches).map(cut_bits).collect(),
        );
        assert_eq!(
            a, b,
            "{kind:?}: the ray through {o:?} along {axis}, span {span:?}"
        );
        same += a.len();
        outside += without.len() - b.len();
    });
    assert!(
        same > 100_000 && outside > 1000,
        "{same} the same, {outside} outside"
    );
}

/// A one-cell move's rays go through `RotaryEnvelope::one_cell`, its buffers on the stack:
/// the same intervals, bit for bit, as the general path that serves moves of any number of
/// cells gives them. Every x, y and z ray of a 0.05 mm grid across two trunnion moves (A and
/// C turning, Y and Z moving; flat and ball), with the whole ray or a random stretch of it as
/// the material's span, after the cull and not: hundreds of thousands of intervals, among
/// them rays that only some of the three samples meet (the components and the refinement
/// between a hit and a miss) and rays that none meets but the move touches (a component
/// of its own).
#[test]
fn a_one_cell_move_s_stack_path_gives_the_general_path_s_intervals() {
    use super::solve::GENERAL_PATH;
    let (mut intervals, mut partial, mut touched) = (0, 0, 0);
    one_cell_rays(0x0ce1, 0.3, |kind, env, (o, axis, e), span, next| {
        // How many of the three samples' tools the whole ray meets.
        let hits = env
            .samples
            .iter()
            .filter(|s| {
                let (p, w) = (s.rot.tr_mul(&(o - s.tip)), s.rot.tr_mul(&e));
                tool_interval(env.shape, env.r, env.l, &p, &w, 0.0).is_some()
            })
            .count();
        let culled = next() < 0.5;
        let run = |general: bool| {
            GENERAL_PATH.with(|g| g.set(general));
            let mut out = Vec::new();
            env.intervals_near(&o, &e, span, culled, &mut out);
            GENERAL_PATH.with(|g| g.set(false));
            out.iter().map(cut_bits).collect::<Vec<_>>()
        };
        let (stack, general) = (run(false), run(true));
        assert_eq!(
            stack, general,
            "{kind:?}: the ray through {o:?} along {axis}, span {span:?}"
        );
        intervals += stack.len();
        let whole = span.0 == Real::NEG_INFINITY;
        partial += usize::from(whole && (hits == 1 || hits == 2));
        touched += usize::from(whole && hits == 0 && !stack.is_empty());
    });
    assert!(
        intervals > 100_000 && partial > 1000 && touched >= 5,
        "{intervals} intervals, {partial} rays some samples meet, {touched} touched only"
    );
}
