//! Unit tests of a probe's edge circles: `φ` (the radius where the ray crosses an end plane,
//! less the tool radius) and its sign read off the squared radius without the root.
//!
//! **Invariant:** expected values come from independent derivations, never from the
//! program's output.

use super::*;

/// The sign test of `φ = √s − r` agrees with the root's own sign for every `s` near the
/// threshold, where rounding decides: a thousand floats either side of `r²` for radii whose
/// squares round (and some that do not), and across `[0, 4r²]`, `+∞` and NaN.
#[test]
fn the_edge_sign_is_the_roots_sign_for_every_squared_radius() {
    let radii = [
        3.0,
        0.5,
        1.0 / 3.0,
        2.999_999_9,
        3.175,
        0.1 + 0.2,
        1e-3,
        12.7,
        7.0_f64.sqrt(),
    ];
    for r in radii {
        let sign = EdgeSign::new(r);
        let root = |s: Real| s.sqrt() - r < 0.0;
        let mut s = r * r;
        for _ in 0..1000 {
            s = s.next_down();
        }
        for _ in 0..2000 {
            assert_eq!(sign.inside(s), root(s), "r = {r}, s = {s:e}");
            s = s.next_up();
        }
        for k in 0..=4000 {
            let s = 4.0 * r * r * k as Real / 4000.0;
            assert_eq!(sign.inside(s), root(s), "r = {r}, s = {s:e}");
        }
        assert!(!sign.inside(Real::INFINITY));
        assert!(!sign.inside(Real::NAN));
    }
}

/// A probe's `φ` per edge is the geometry's: the ray `p + t·u` (tool frame) crosses the plane
/// `z = h` at `t = (h − p_z)/u_z`, where its distance from the axis less `R` is `φ` — bit for
/// bit — and `+∞` for a ray along the plane or an edge the tool has not (a ball's bottom);
/// the sign test says `φ < 0`. Rays through a turning flat and ball end mill's poses, from
/// every side.
#[test]
fn a_probes_edges_are_where_the_ray_crosses_the_end_planes() {
    let c = trunnion();
    let (a, b) = (
        AxisValues::default()
            .with(AxisLetter::A, -10.0)
            .with(AxisLetter::C, 20.0)
            .with(AxisLetter::Z, 10.0),
        AxisValues::default()
            .with(AxisLetter::A, 15.0)
            .with(AxisLetter::C, 65.0)
            .with(AxisLetter::Z, 12.0),
    );
    for kind in [ToolKind::Flat, ToolKind::Ball] {
        let tool = Tool::try_new(kind, 6.0, 25.0).expect("valid");
        let env = RotaryEnvelope::new(&c, &tool, &a, &b).expect("supported");
        let (r, l) = (env.r, env.l);
        let mut seen = [0usize; 2];
        for k in 0..400 {
            let lambda = k as Real / 399.0;
            // origins about the tool, directions from every side (the three axes among them)
            let (o, dirs) = rays_about(k, Vector3::new(0.0, 0.0, 10.0));
            for (i, e) in dirs.iter().enumerate() {
                let ray = whole(&o, e, i);
                let probe = env.probe_at(lambda, &ray);
                let s = env.path.sample(lambda);
                let p = s.rot.tr_mul(&(o - s.tip));
                let u = s.rot.tr_mul(e);
                let want = |h: Real| {
                    if u.z.abs() <= tol::RELATIVE_EPS {
                        return Real::INFINITY;
                    }
                    let q = p + u * ((h - p.z) / u.z);
                    (q.x * q.x + q.y * q.y).sqrt() - r
                };
                let bottom = match env.shape {
                    Shape::Flat => want(0.0),
                    Shape::Ball => Real::INFINITY,
                };
                for (edge, want) in [bottom, want(l)].into_iter().enumerate() {
                    let got = probe.phi(edge, r);
                    assert_eq!(
                        got.to_bits(),
                        want.to_bits(),
                        "λ {lambda}, ray {i}, edge {edge}"
                    );
                    assert_eq!(env.edge.inside(probe.edge_r2[edge]), want < 0.0);
                    seen[edge] += usize::from(want < 0.0);
                }
            }
        }
        // both edges were crossed inside their circles by some rays (a flat end mill's bottom)
        assert!(
            seen[1] > 0 && (env.shape == Shape::Ball || seen[0] > 0),
            "{seen:?}"
        );
    }
}

/// The rate of `φ` that guides an edge crossing's solve is `φ`'s own derivative: on a
/// trunnion move turning A and C with X, Y and Z, for rays from every side (the three axes
/// and oblique ones) and both edges of a flat end mill, [`RotaryEnvelope::phi_rate`] at a
/// probe equals the central difference of the probes' `φ` over `λ ± 1e-6` (`φ` itself is
/// checked against the direct formula above), to 1e-5 relative, wherever `φ` is finite
/// and the ray crosses the plane away from the tool's axis.
#[test]
fn the_edge_crossing_s_rate_is_the_derivative_of_phi() {
    let c = trunnion();
    let (a, b) = (
        q(3.0, -10.0, 20.0, -20.0).with(AxisLetter::C, 30.0),
        q(-2.0, -14.0, 25.0, 15.0).with(AxisLetter::C, 80.0),
    );
    let tool = Tool::try_new(ToolKind::Flat, 6.0, 25.0).expect("valid");
    let env = RotaryEnvelope::new(&c, &tool, &a, &b).expect("supported");
    let h = 1e-6;
    let mut checked = 0;
    for k in 1..200 {
        let lambda = k as Real / 200.0;
        let (o, dirs) = rays_about(k, Vector3::new(0.0, -12.0, 25.0));
        for (i, e) in dirs.iter().enumerate() {
            let ray = whole(&o, e, i);
            let at = |l: Real| env.probe_at(l, &ray);
            let (p, lo, hi) = (at(lambda), at(lambda - h), at(lambda + h));
            for edge in 0..2 {
                let phi = |p: &Probe| p.phi(edge, env.r);
                let want = (phi(&hi) - phi(&lo)) / (2.0 * h);
                if !(want.is_finite() && phi(&p) > -0.5 * env.r) {
                    continue;
                }
                let got = env.phi_rate(&p, edge);
                assert!(
                    (got - want).abs() <= 1e-5 * (1.0 + want.abs()),
                    "λ {lambda}, ray {i}, edge {edge}: φ' {got} against {want}"
                );
                checked += 1;
            }
        }
    }
    assert!(checked > 400, "{checked} rates checked");
}

/// The `k`-th of a family of rays about `centre`: an origin within 8 mm across and 20 mm
/// along z of it, and four directions, the x, y and z axes and an oblique one.
fn rays_about(k: usize, centre: Vector3) -> (Point3, [Vector3; 4]) {
    let f = k as Real;
    let o = Point3::new(
        (f * 0.37).sin() * 8.0,
        (f * 0.23).cos() * 8.0,
        (f * 0.11).sin() * 20.0,
    ) + centre;
    let oblique = Vector3::new((f * 0.7).cos(), (f * 0.3).sin(), (f * 0.5).cos()).normalize();
    (o, [Vector3::x(), Vector3::y(), Vector3::z(), oblique])
}

/// The whole ray from `o` along `e`, the `i`-th of [`rays_about`]'s directions (an axis ray
/// for the first three).
fn whole<'a>(o: &'a Point3, e: &'a Vector3, i: usize) -> Ray<'a> {
    Ray {
        o,
        e,
        span: (Real::NEG_INFINITY, Real::INFINITY),
        axis: (i < 3).then_some(i),
    }
}
