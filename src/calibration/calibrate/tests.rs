//! Unit tests of general identification: the floor's envelope line, the Jacobian against
//! finite differences, what a 0/180 cut determines, parameters without data refused.
//!
//! **Invariant:** expected values come from independent derivations, never from the
//! program's output.

use super::*;
use crate::nc::{AxisLetter, MoveKind};

fn mdx50() -> Chain {
    crate::machine::chain::mdx50_for_tests()
}

fn cut(line: usize, a: Real, y: Real, z: Real) -> Move {
    let q = |x| {
        AxisValues::default()
            .with(AxisLetter::X, x)
            .with(AxisLetter::Y, y)
            .with(AxisLetter::Z, z)
            .with(AxisLetter::A, a)
    };
    Move {
        kind: MoveKind::Linear,
        start: q(-30.0),
        end: q(30.0),
        feed_mm_per_min: Some(600.0),
        line,
    }
}

fn tool() -> Tool {
    Tool::try_new(ToolKind::Flat, 6.0, 25.0).expect("valid")
}

fn stock() -> Aabb {
    Aabb {
        min: Point3::new(-20.0, -24.0, -10.0),
        max: Point3::new(20.0, 8.0, 10.0),
    }
}

fn spec(name: &str, kind: FaceKind) -> FaceSpec {
    FaceSpec {
        name: name.into(),
        line: 0,
        region: crate::calibration::identify::FaceRegion::Auto,
        kind,
    }
}

const NINE: [&str; 9] = [
    "dy_AY", "dz_AY", "beta_AY", "gamma_AY", "alpha_YX", "gamma_YX", "beta_XZ", "alpha_ZS",
    "beta_ZS",
];

fn ids(c: &Chain, names: &[&str]) -> Vec<DeviationId> {
    names
        .iter()
        .map(|n| c.deviation_id(n).expect("known"))
        .collect()
}

fn step_features(truth: &Chain) -> Vec<Feature> {
    let model = truth.nominal();
    [
        ("A0", cut(1, 0.0, -25.0, 0.0)),
        ("A180", cut(2, 180.0, 25.0, 0.0)),
    ]
    .iter()
    .map(|(n, c)| {
        Feature::Plane(
            synthetic_plane_feature(
                &spec(n, FaceKind::Flank),
                c,
                truth,
                &model,
                &tool(),
                &stock(),
                0.5e-3,
                [2e-5, 2e-4],
                (0.0, 0.0),
            )
            .expect("a face"),
        )
    })
    .collect()
}

#[test]
fn tilted_floor_is_the_least_squares_line_of_the_elliptic_envelope() {
    // A spindle tilted along the feed leaves a floor of depth |t|·√(R² − x₂²) below the
    // tip line. Over an off-centre cross range the predicted plane must be that
    // surface's least-squares line, placed where the points are (not at the tip line).
    let mut truth = mdx50();
    truth.set_deviation(truth.deviation_id("beta_ZS").expect("known"), 0.05);
    let mv = cut(3, 0.0, -10.0, 8.0);
    let tool = tool();
    let range = (-0.5, 2.8);
    let f = synthetic_plane_feature(
        &spec("floor", FaceKind::Floor),
        &mv,
        &truth,
        &truth,
        &tool,
        &stock(),
        1e-3,
        [1e-4, 1e-4],
        range,
    )
    .expect("a floor");
    let plane = predicted_plane(&truth, &tool, &f).expect("defined");
    // The envelope's frame, from the poses (independent of the prediction code).
    let (p0, p1) = (truth.w_from_t(&mv.start), truth.w_from_t(&mv.end));
    let tip = p0 * Point3::origin();
    let u = (p1 * Point3::origin() - tip).normalize();
    let v = p0.rotation * Vector3::z();
    let t = u.dot(&v);
    assert!(
        t.abs() > 0.04,
        "the test needs a real tilt along the feed, t = {t}"
    );
    let e2 = v.cross(&u).normalize();
    let m = (u * t - v).normalize();
    // Discrete least squares of h(x) = |t|·√(R² − x²) over uniform x in the range.
    let n = 100_001;
    let r = tool.radius();
    let xs: Vec<Real> = (0..n)
        .map(|i| range.0 + (range.1 - range.0) * i as Real / (n - 1) as Real)
        .collect();
    let hs: Vec<Real> = xs
        .iter()
        .map(|x| t.abs() * (r * r - x * x).sqrt())
        .collect();
    let mx = xs.iter().sum::<Real>() / n as Real;
    let mh = hs.iter().sum::<Real>() / n as Real;
    let sxy: Real = xs.iter().zip(&hs).map(|(x, h)| (x - mx) * (h - mh)).sum();
    let sxx: Real = xs.iter().map(|x| (x - mx).powi(2)).sum();
    let slope = sxy / sxx;
    for x in [range.0, mx, range.1] {
        let want = mh + slope * (x - mx);
        // The predicted plane's depth along m at cross-feed x.
        let n_ = plane.normal.into_inner();
        let got = (plane.offset - n_.dot(&(tip.coords + e2 * x))) / n_.dot(&m);
        assert!(
            (got.abs() - want).abs() < 1e-6,
            "x₂ = {x}: predicted depth {got}, least squares {want}"
        );
    }
}

#[test]
fn jacobian_matches_finite_differences() {
    let mut truth = mdx50();
    for (n, v) in NINE
        .iter()
        .zip([-0.3, 0.2, 1e-4, -2e-4, 3e-4, 1e-4, -1e-4, 2e-4, -3e-4])
    {
        truth.set_deviation(truth.deviation_id(n).expect("known"), v);
    }
    let mut feats = step_features(&truth);
    // A floor with its axis tilted along the feed (beta sum ≠ 0): the envelope term.
    feats.push(Feature::Plane(
        synthetic_plane_feature(
            &spec("floor", FaceKind::Floor),
            &cut(3, 0.0, -10.0, 8.0),
            &truth,
            &truth.nominal(),
            &tool(),
            &stock(),
            0.5e-3,
            [2e-5, 2e-4],
            (-2.0, 1.0),
        )
        .expect("a floor"),
    ));
    let id = ids(&truth, &NINE);
    let chain = truth.nominal();
    let model = Model {
        chain: &chain,
        ids: &id,
        iso_terms: &[],
        tool: &tool(),
        features: &feats,
        registration: Registration::Estimate,
    };
    let mut x = model.start();
    for k in 0..x.len() {
        x[k] = if k < 9 {
            0.7 * truth.deviation(id[k])
        } else {
            1e-4 * (k as Real - 11.0)
        };
    }
    let j = model.jacobian(&x).expect("defined");
    for k in 0..x.len() {
        // Steps: 1e-6 of the realistic size, far above rounding of residuals ~1e3.
        let h = if k < 9 { magnitude(id[k]) * 1e-4 } else { 1e-6 };
        let (mut a, mut b) = (x.clone(), x.clone());
        a[k] += h;
        b[k] -= h;
        let fd = (model.residuals(&a).expect("a") - model.residuals(&b).expect("b")) / (2.0 * h);
        let err = (&fd - j.column(k)).amax();
        let scale = fd.amax().max(1.0);
        assert!(
            err <= 1e-5 * scale,
            "column {k}: AD vs FD differ by {err} (scale {scale})"
        );
    }
}

#[test]
fn the_0_180_cut_determines_dy_and_the_gamma_sum_only() {
    let mut truth = mdx50();
    let vals = [-0.5, 0.1, 2e-4, 1e-4, -2e-4, 3e-4, 1e-4, -1e-4, 2e-4];
    for (n, v) in NINE.iter().zip(vals) {
        truth.set_deviation(truth.deviation_id(n).expect("known"), v);
    }
    let feats = step_features(&truth);
    let id = ids(&truth, &NINE);
    let chain = truth.nominal();
    let model = Model {
        chain: &chain,
        ids: &id,
        iso_terms: &[],
        tool: &tool(),
        features: &feats,
        registration: Registration::Estimate,
    };
    let r = identify(&model).expect("identifies");
    assert_eq!(r.identifiability.identified, vec!["dy_AY".to_string()]);
    let names: Vec<&str> = r.combinations.iter().map(|c| c.name.as_str()).collect();
    assert_eq!(names, vec!["gamma_AY + gamma_YX"]);
    let dy = &r.parameters[0];
    // Second-order effects of the other deviations bias it by a fraction of a µm.
    assert!((dy.value + 0.5).abs() < 2e-3, "dy_AY = {}", dy.value);
    let g = &r.combinations[0];
    assert!((g.value - 4e-4).abs() < 2e-5, "gamma sum = {}", g.value);
    assert!(
        !r.identifiability
            .not_identified
            .contains(&"dy_AY".to_string())
    );
    assert_eq!(r.identifiability.not_identified.len(), 8);
    // Flanks never see the offset along the tool axis.
    assert!(r.identifiability.no_data.contains(&"dz_AY".to_string()));
}

#[test]
fn parameters_nothing_depends_on_are_an_error() {
    let truth = mdx50();
    let feats = step_features(&truth);
    let id = ids(&truth, &["dx_ZS"]);
    let chain = truth.nominal();
    let model = Model {
        chain: &chain,
        ids: &id,
        iso_terms: &[],
        tool: &tool(),
        features: &feats,
        registration: Registration::Workpiece,
    };
    // dx moves the flank planes along themselves: no feature sees it.
    assert_eq!(
        identify(&model).map(|_| ()),
        Err(CalibrateError::NoData("dx_ZS".into()))
    );
}

/// The generic pose of a chain with error motions on a linear and a rotary axis and ISO
/// location terms on top equals the chain's own pose after [`Chain::apply_iso_term`]: the
/// two compose `M·Err` inside the line's `L` independently (the chain moves the joints, the
/// generic pose wraps the motion); a term on the first axis and one on a later axis, at
/// tilted A and moved X, Y, Z.
#[test]
fn the_pose_carries_the_error_motions_inside_the_location_terms_as_the_chain_does() {
    use crate::machine::Component;
    use crate::machine::error_motion::{AxisErrorMotions, Term};
    let mut chain = mdx50();
    let mut ex = AxisErrorMotions::for_axis(AxisLetter::X);
    ex.functions[Component::Dx as usize].terms = vec![Term::Polynomial(vec![0.0, 4e-4])];
    ex.functions[Component::Dy as usize].terms = vec![Term::Periodic {
        amplitude: 0.02,
        period: 7.0,
        phase_deg: 30.0,
    }];
    ex.functions[Component::Beta as usize].terms = vec![Term::Polynomial(vec![1e-4, 3e-6])];
    chain.set_error_motions(AxisLetter::X, ex).expect("X");
    let mut ea = AxisErrorMotions::for_axis(AxisLetter::A);
    ea.functions[Component::Dz as usize].terms = vec![Term::Polynomial(vec![0.0, 2e-4])];
    ea.functions[Component::Gamma as usize].terms = vec![Term::Polynomial(vec![5e-5, 1e-6])];
    chain.set_error_motions(AxisLetter::A, ea).expect("A");
    let names = ["EY0A", "EB0A", "EC(0X)Y"];
    let values = [0.03, 4e-4, -3e-4];
    let terms: Vec<IsoTerm> = names
        .iter()
        .map(|n| IsoTerm::parse(&chain, n).expect("a term of the chain"))
        .collect();
    let mut moved = chain.clone();
    for (n, v) in names.iter().zip(values) {
        moved.apply_iso_term(n, v).expect("applies");
    }
    let params = Params {
        ids: &[],
        p: &[],
        iso: &terms,
        t: &values,
    };
    for (a, x, y, z) in [
        (0.0, 0.0, 0.0, 0.0),
        (35.0, 12.0, -7.0, 3.0),
        (-80.0, -25.0, 14.0, -9.0),
    ] {
        let q = AxisValues::default()
            .with(AxisLetter::A, a)
            .with(AxisLetter::X, x)
            .with(AxisLetter::Y, y)
            .with(AxisLetter::Z, z);
        let g = pose::<Real>(&chain, &params, &q);
        let c = moved.w_from_t(&q);
        let m = c.rotation.to_rotation_matrix();
        for i in 0..3 {
            assert!(
                (g.t[i] - c.translation.vector[i]).abs() < 1e-12,
                "A {a}: t[{i}] {} against {}",
                g.t[i],
                c.translation.vector[i]
            );
            for k in 0..3 {
                assert!((g.r[i][k] - m[(i, k)]).abs() < 1e-14, "A {a}: r[{i}][{k}]");
            }
        }
        // The error motions are there: without them the tip moves by their size.
        let bare = pose::<Real>(&chain.without_error_motions(), &params, &q);
        let d = (0..3)
            .map(|i| (bare.t[i] - g.t[i]).abs())
            .fold(0.0, Real::max);
        assert!(d > 1e-4, "A {a}: {d}");
    }
}
