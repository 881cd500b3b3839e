//! Rotary cutting on the MDX-50 chain: a rotary move against a brute-force point-in-sweep
//! test, indexed 3+1 faces (P3) and a simultaneous XA helical groove (P4).

use crate::{mdx50_deviations, mdx50_w_from_t, rot, scene, set_deviation};
use nalgebra::Vector4;
use twinmill::cutting::stock::TriDexel;
use twinmill::cutting::sweep::{SweepOptions, sweep_program};
use twinmill::machine::chain::Chain;
use twinmill::math::{Aabb, Point3, Real, Vector3};
use twinmill::nc::{AxisLetter, AxisValues, Move, MoveKind};
use twinmill::progress::NoProgress;

// ---------------------------------------------------------------------------------------
// A rotary move: the dexel surface agrees with a brute-force point-in-sweep test.

fn nominal_mdx50() -> Chain {
    scene().chain().nominal()
}

#[test]
fn rotary_move_surface_agrees_with_brute_force() {
    let chain = nominal_mdx50();
    let tool =
        twinmill::cutting::tool::Tool::try_new(twinmill::cutting::tool::ToolKind::Flat, 6.0, 10.0)
            .expect("valid");
    let start = AxisValues::default().with(AxisLetter::Z, 6.0);
    let mv = Move {
        kind: MoveKind::Linear,
        start,
        end: start.with(AxisLetter::A, 90.0),
        feed_mm_per_min: Some(100.0),
        line: 3,
    };
    let bounds = Aabb {
        min: Point3::new(-8.03, -10.0, -10.0),
        max: Point3::new(7.97, 10.0, 10.0),
    };
    // The 0.03 mm shift keeps every ray off the tool's tangent planes x = ±3, where the
    // swept solid is a sheet of zero thickness that point sampling cannot find.
    let mut stock = TriDexel::new_box(bounds, 0.4, 4e9).expect("fits");
    let opts = SweepOptions {
        rotary_step_bound_mm: 5e-4,
    };
    let rep = sweep_program(&mut stock, &chain, &tool, &[mv], &opts, &NoProgress).expect("sweeps");
    assert_eq!(rep.rotary_moves, 1);
    assert!(rep.rotary_error_bound_mm <= 5e-4 && rep.rotary_error_bound_mm > 0.0);
    // Brute force: p is in the sweep iff RotX(−a)·p is inside the tool for some a ∈ [0°, 90°].
    // With 40,000 samples the tool moves ≤ 16 mm · (π/2)/40,000 = 0.6 µm between samples.
    let inside = |p: &Vector3| {
        (0..=40_000).any(|k| {
            let a = (k as Real / 40_000.0) * std::f64::consts::FRAC_PI_2;
            let (s, c) = a.sin_cos();
            let (y, z) = (c * p.y + s * p.z, -s * p.y + c * p.z);
            let h = z - 6.0;
            (p.x * p.x + y * y).sqrt() <= 3.0 && (0.0..=10.0).contains(&h)
        })
    };
    let mut checked = 0;
    for g in stock.grids() {
        let mut pts = Vec::new();
        g.for_each_crossing(|p, c| {
            if c.line == 3 {
                pts.push((p, c.normal()));
            }
        });
        for (p, n) in pts.iter().step_by(23) {
            // 5 µm into the cut is inside the sweep, 5 µm into the material is not.
            let into_cut = p.coords + n * 5e-3;
            let into_material = p.coords - n * 5e-3;
            assert!(inside(&into_cut), "{p} + 5 µm n should be cut");
            assert!(!inside(&into_material), "{p} − 5 µm n should be material");
            checked += 1;
        }
    }
    assert!(checked > 80, "only {checked} crossings checked");
}

// ---------------------------------------------------------------------------------------
// P3, indexed 3+1: faces milled on a round bar at A = 0, 90, 180, 270° and at 60° steps
// (a hexagon); planes fitted to the faces' dexel crossings against the exact planes of the
// deviated chain (the independent 4 × 4 derivation above).

/// Bar radius, face distance from the A axis and tool of the P3 cuts (mm).
const BAR_R: Real = 10.0;
const FACE_D: Real = 8.0;

/// The indexed program: per angle, turn A at a safe height, plunge beside the bar, side-mill
/// along X with the tool's +y flank at machine y = −FACE_D, retract. Returns the moves and the
/// line of each face cut.
fn indexed_program(angles: &[Real], r: Real) -> (Vec<Move>, Vec<usize>) {
    let y = -(FACE_D + r);
    let safe = 60.0;
    let home = AxisValues::default()
        .with(AxisLetter::X, -30.0)
        .with(AxisLetter::Y, y)
        .with(AxisLetter::Z, safe);
    let mut points = vec![home];
    let mut cuts = Vec::new();
    for &a in angles {
        let p = home.with(AxisLetter::A, a);
        points.push(p);
        points.push(p.with(AxisLetter::Z, -12.0));
        // The move ending at the next point is the face cut; lines count from 1.
        cuts.push(points.len());
        points.push(p.with(AxisLetter::Z, -12.0).with(AxisLetter::X, 30.0));
        points.push(p.with(AxisLetter::X, 30.0));
        points.push(p);
    }
    (polyline_moves(&points), cuts)
}

/// Feed moves through `points`, the k-th move on line k (from 1).
fn polyline_moves(points: &[AxisValues]) -> Vec<Move> {
    points
        .windows(2)
        .enumerate()
        .map(|(k, w)| Move {
            kind: MoveKind::Linear,
            start: w[0],
            end: w[1],
            feed_mm_per_min: Some(600.0),
            line: k + 1,
        })
        .collect()
}

/// The exact flank plane of the cut at `a_deg`: unit normal into the material (towards the
/// A axis) and offset, from the tool tip's path and axis through the independent chain.
fn exact_index_face(dev: &[[Real; 6]; 4], a_deg: Real, r: Real) -> (Vector3, Real) {
    let y = -(FACE_D + r);
    let m0 = mdx50_w_from_t(dev, -30.0, y, -12.0, a_deg);
    let m1 = mdx50_w_from_t(dev, 30.0, y, -12.0, a_deg);
    let p0 = (m0 * Vector4::new(0.0, 0.0, 0.0, 1.0)).xyz();
    let p1 = (m1 * Vector4::new(0.0, 0.0, 0.0, 1.0)).xyz();
    let axis = (m0 * Vector4::new(0.0, 0.0, 1.0, 0.0)).xyz();
    let mut n = (p1 - p0).cross(&axis).normalize();
    // Nominally the material lies towards RotX(a)·(+y) from the tool.
    let toward = (rot(0, a_deg.to_radians()) * Vector4::new(0.0, 1.0, 0.0, 0.0)).xyz();
    if n.dot(&toward) < 0.0 {
        n = -n;
    }
    (n, n.dot(&p0) + r)
}

/// Orthogonal least-squares plane of points: (unit normal, offset), normal along `hint`.
fn fit_plane(points: &[Vector3], hint: &Vector3) -> (Vector3, Real) {
    let c = points.iter().sum::<Vector3>() / points.len() as Real;
    let mut m = nalgebra::Matrix3::zeros();
    for p in points {
        let d = p - c;
        m += d * d.transpose();
    }
    let eig = m.symmetric_eigen();
    let k = eig.eigenvalues.imin();
    let mut n: Vector3 = eig.eigenvectors.column(k).into_owned();
    if n.dot(hint) < 0.0 {
        n = -n;
    }
    (n, n.dot(&c))
}

/// Largest offset (mm) and normal (rad) error of the fitted against the exact planes, and
/// the largest distance of a single crossing from its exact plane.
fn indexed_face_errors(angles: &[Real], devs: &[(&str, Real)]) -> (Real, Real, Real) {
    let mut s = scene();
    for (name, v) in devs {
        set_deviation(&mut s, name, *v);
    }
    let dev = mdx50_deviations(&s);
    let r = s.tool.radius();
    let (moves, cuts) = indexed_program(angles, r);
    let bar = twinmill::cutting::shape::Cylinder::try_new(
        Point3::new(-20.0, 0.0, 0.0),
        Vector3::x(),
        BAR_R,
        40.0,
    )
    .expect("valid");
    let bounds = Aabb {
        min: Point3::new(-20.0, -BAR_R - 0.5, -BAR_R - 0.5),
        max: Point3::new(20.0, BAR_R + 0.5, BAR_R + 0.5),
    };
    let mut stock = TriDexel::from_solid(bounds, 0.2, 4e9, &bar).expect("fits");
    sweep_program(
        &mut stock,
        s.chain(),
        &s.tool,
        &moves,
        &s.sweep,
        &NoProgress,
    )
    .expect("sweeps");
    let (mut off, mut ang, mut worst) = (0.0 as Real, 0.0 as Real, 0.0 as Real);
    for (&a, &line) in angles.iter().zip(&cuts) {
        let (n, d) = exact_index_face(&dev, a, r);
        let mut pts = Vec::new();
        for g in stock.grids() {
            g.for_each_crossing(|p, c| {
                if c.line as usize == line {
                    pts.push(p.coords);
                    worst = worst.max((n.dot(&p.coords) - d).abs());
                }
            });
        }
        // The face is 40 mm long and 2·sqrt(R² − d²) wide, less what the neighbours take.
        assert!(pts.len() > 2000, "A{a}: only {} crossings", pts.len());
        let (nf, df) = fit_plane(&pts, &n);
        // Offsets compared at the face's centroid (the planes' distance there).
        let c = pts.iter().sum::<Vector3>() / pts.len() as Real;
        off = off.max(((d - n.dot(&c)) - (df - nf.dot(&c))).abs());
        ang = ang.max((nf - n).norm());
    }
    (off, ang, worst)
}

/// The nine deviations of seed 002 Fig. 3 at realistic sizes (±0.5 mm, ±5e-4 rad).
const NINE_REALISTIC: [(&str, Real); 9] = [
    ("dy_AY", -0.5),
    ("dz_AY", 0.35),
    ("beta_AY", 4e-4),
    ("gamma_AY", -5e-4),
    ("alpha_YX", 3e-4),
    ("gamma_YX", 2.5e-4),
    ("beta_XZ", -4.5e-4),
    ("alpha_ZS", 5e-4),
    ("beta_ZS", -3.5e-4),
];

#[test]
fn indexed_faces_at_90_degree_steps_fit_the_exact_planes() {
    for devs in [&[("dy_AY", 0.0)][..], &NINE_REALISTIC[..]] {
        let (off, ang, worst) = indexed_face_errors(&[0.0, 90.0, 180.0, 270.0], devs);
        assert!(off <= 1e-4, "offset error {off} mm");
        assert!(ang <= 1e-6, "normal error {ang} rad");
        assert!(worst <= 1e-4, "a crossing {worst} mm off its exact plane");
    }
}

#[test]
fn hexagon_faces_at_60_degree_steps_fit_the_exact_planes() {
    let angles: Vec<Real> = (0..6).map(|k| 60.0 * k as Real).collect();
    for devs in [&[("dy_AY", 0.0)][..], &NINE_REALISTIC[..]] {
        let (off, ang, worst) = indexed_face_errors(&angles, devs);
        assert!(off <= 1e-4, "offset error {off} mm");
        assert!(ang <= 1e-6, "normal error {ang} rad");
        assert!(worst <= 1e-4, "a crossing {worst} mm off its exact plane");
    }
}

// ---------------------------------------------------------------------------------------
// P4, simultaneous XA: a helical groove wrapped on a round bar by a ball end mill at
// constant depth, A turning with X. Removed volume against an independent integral over the
// screw motion's orbits, and every crossing of the groove against a brute-force distance
// from the true swept ball (dense λ sampling of the exact pose, then golden-section).

const HELIX_BAR_R: Real = 8.0;
const HELIX_DEPTH: Real = 1.0;
const HELIX_BALL_R: Real = 2.0;
/// Advance of X per turn of A (mm), and moves per turn.
const HELIX_LEAD: Real = 10.0;
const HELIX_STEPS: usize = 60;

fn helix_tool() -> twinmill::cutting::tool::Tool {
    twinmill::cutting::tool::Tool::try_new(
        twinmill::cutting::tool::ToolKind::Ball,
        2.0 * HELIX_BALL_R,
        12.0,
    )
    .expect("valid")
}

/// One turn of the helix: the tool already at depth at A = 0, X = −LEAD/2.
fn helix_moves() -> Vec<Move> {
    let z = HELIX_BAR_R - HELIX_DEPTH;
    let points: Vec<AxisValues> = (0..=HELIX_STEPS)
        .map(|k| {
            let f = k as Real / HELIX_STEPS as Real;
            AxisValues::default()
                .with(AxisLetter::X, -HELIX_LEAD / 2.0 + HELIX_LEAD * f)
                .with(AxisLetter::Z, z)
                .with(AxisLetter::A, 360.0 * f)
        })
        .collect();
    polyline_moves(&points)
}

fn helix_stock(pitch: Real) -> TriDexel {
    let bar = twinmill::cutting::shape::Cylinder::try_new(
        Point3::new(-10.0, 0.0, 0.0),
        Vector3::x(),
        HELIX_BAR_R,
        20.0,
    )
    .expect("valid");
    let b = HELIX_BAR_R + 0.5;
    let bounds = Aabb {
        min: Point3::new(-10.0, -b, -b),
        max: Point3::new(10.0, b, b),
    };
    TriDexel::from_solid(bounds, pitch, 4e9, &bar).expect("fits")
}

/// Golden-section minimum of `f` on [a, b] to a bracket of 1e-12.
pub(crate) fn golden_min(mut a: Real, mut b: Real, f: impl Fn(Real) -> Real) -> Real {
    let g = (5.0f64.sqrt() - 1.0) / 2.0;
    let (mut c, mut d) = (b - g * (b - a), a + g * (b - a));
    let (mut fc, mut fd) = (f(c), f(d));
    while b - a > 1e-12 {
        if fc < fd {
            (b, d, fd) = (d, c, fc);
            c = b - g * (b - a);
            fc = f(c);
        } else {
            (a, c, fc) = (c, d, fd);
            d = a + g * (b - a);
            fd = f(d);
        }
    }
    f(0.5 * (a + b))
}

/// The removed volume of the nominal helix, independently: the motion is a screw about X
/// (A and X linear together), under which the bar is invariant. Counting along the screw's
/// orbits (helices), a turn Θ sweeps V = vol(ball ∩ bar) + Θ·∫∫_S r dr dx0, S the meridian
/// set of orbits (radius r, x0 at A = 0) that meet the ball; an orbit meets the ball in one
/// arc because |orbit − centre|² is convex in the angle where it can be ≤ R².
fn helix_volume_independent() -> Real {
    let rc = HELIX_BAR_R - HELIX_DEPTH + HELIX_BALL_R; // ball centre's distance from X
    let k = HELIX_LEAD / std::f64::consts::TAU; // X advance per radian
    let rb = HELIX_BALL_R;
    let r_lo = rc - rb;
    // Orbit (r, x0) at angle θ: |p − c|² = r² + rc² − 2 r rc cos θ + (x0 + kθ)².
    let meets = |r: Real, x0: Real| {
        let f = |th: Real| r * r + rc * rc - 2.0 * r * rc * th.cos() + (x0 + k * th).powi(2);
        golden_min(-1.5, 1.5, f) <= rb * rb
    };
    // Half-width w(r) of S in x0 (S is symmetric: θ → −θ, x0 → −x0), by bisection.
    let w = |r: Real| {
        let (mut a, mut b) = (0.0, rb + k * 1.5 + 1.0);
        if !meets(r, 0.0) {
            return 0.0;
        }
        for _ in 0..60 {
            let m = 0.5 * (a + b);
            if meets(r, m) {
                a = m;
            } else {
                b = m;
            }
        }
        a
    };
    // Angular width of the ball at (r, x) about its centre's meridian.
    let dth = |r: Real, x: Real| {
        let c = (r * r + rc * rc + x * x - rb * rb) / (2.0 * r * rc);
        if c >= 1.0 {
            0.0
        } else {
            2.0 * c.max(-1.0).acos()
        }
    };
    // r = r_lo + u², which makes the square-root ends smooth; midpoint rule in u and x.
    let n = 400;
    let u_max = (HELIX_BAR_R - r_lo).sqrt();
    let (mut area, mut ball) = (0.0, 0.0);
    for i in 0..n {
        let u = (i as Real + 0.5) / n as Real * u_max;
        let r = r_lo + u * u;
        let dr = 2.0 * u * u_max / n as Real;
        area += r * 2.0 * w(r) * dr;
        let half = (rb * rb - (r - rc).powi(2)).max(0.0).sqrt() + 1e-9;
        let m = 400;
        let mut s = 0.0;
        for j in 0..m {
            let x = -half + (j as Real + 0.5) / m as Real * 2.0 * half;
            s += dth(r, x);
        }
        ball += r * s * (2.0 * half / m as Real) * dr;
    }
    ball + std::f64::consts::TAU * area
}

#[test]
fn helical_groove_removes_the_screw_volume() {
    let chain = nominal_mdx50();
    let mut stock = helix_stock(0.1);
    let before = stock.volume();
    let opts = SweepOptions {
        rotary_step_bound_mm: 1e-4,
    };
    let rep = sweep_program(
        &mut stock,
        &chain,
        &helix_tool(),
        &helix_moves(),
        &opts,
        &NoProgress,
    )
    .expect("sweeps");
    assert_eq!(rep.rotary_moves, HELIX_STEPS);
    assert_eq!(rep.sweeps, HELIX_STEPS, "one envelope per move");
    // The envelope takes the bound asked for as its tolerance.
    assert_eq!(rep.rotary_error_bound_mm, opts.rotary_step_bound_mm);
    let got = before - stock.volume();
    let want = helix_volume_independent();
    // The dexel measure integrates across rays by the midpoint rule: its error, not the
    // crossings', sets the tolerance (cf. the straight-slot volume tests of the cutter).
    assert!(
        ((got - want) / want).abs() < 1e-3,
        "removed {got} mm³, independent {want} mm³"
    );
}

/// Signed distance of `p` from the ball end mill (a capsule below its top) on move `mv` of
/// the chain with deviations `dev`, minimised over the move: dense samples, then golden
/// section around the best.
fn distance_from_move(dev: &[[Real; 6]; 4], mv: &Move, p: &Vector3) -> Real {
    let at = |l: Real| {
        let q = |a: AxisLetter| mv.start.get(a) + (mv.end.get(a) - mv.start.get(a)) * l;
        let m = mdx50_w_from_t(
            dev,
            q(AxisLetter::X),
            q(AxisLetter::Y),
            q(AxisLetter::Z),
            q(AxisLetter::A),
        );
        let rot = m.fixed_view::<3, 3>(0, 0).into_owned();
        let local = rot.transpose() * (p - m.fixed_view::<3, 1>(0, 3));
        let h = local.z.clamp(HELIX_BALL_R, 12.0);
        Vector3::new(local.x, local.y, local.z - h).norm() - HELIX_BALL_R
    };
    let n: usize = 400;
    let (mut best, mut kb) = (Real::INFINITY, 0usize);
    for k in 0..=n {
        let d = at(k as Real / n as Real);
        if d < best {
            (best, kb) = (d, k);
        }
    }
    let a = (kb.saturating_sub(1)) as Real / n as Real;
    let b = ((kb + 1).min(n)) as Real / n as Real;
    best.min(golden_min(a, b, at))
}

#[test]
fn helical_groove_crossings_lie_on_the_true_swept_surface() {
    let mut s = scene();
    for (name, v) in NINE_REALISTIC {
        set_deviation(&mut s, name, v);
    }
    let dev = mdx50_deviations(&s);
    let moves = helix_moves();
    // At the envelope's finest tolerance, then at the scene's bound (0.1 µm), which the
    // envelope takes as its own: the crossings lie within what the sweep reports.
    let finest = SweepOptions {
        rotary_step_bound_mm: 1e-7,
    };
    for (opts, within) in [
        (&finest, 2e-7),
        (&s.sweep, s.sweep.rotary_step_bound_mm + 1e-7),
    ] {
        let mut stock = helix_stock(0.2);
        let rep = sweep_program(
            &mut stock,
            s.chain(),
            &helix_tool(),
            &moves,
            opts,
            &NoProgress,
        )
        .expect("sweeps");
        assert_eq!(rep.rotary_error_bound_mm, opts.rotary_step_bound_mm);
        let worst = groove_distance(&dev, &moves, &stock);
        assert!(
            worst <= within,
            "at the bound {} mm a groove crossing lies {worst} mm from the swept surface",
            opts.rotary_step_bound_mm
        );
    }
}

/// The largest distance of 400 of the groove's crossings in `stock`, cut by `moves` on the
/// chain with deviations `dev`, from the true swept surface of their moves and neighbours.
fn groove_distance(dev: &[[Real; 6]; 4], moves: &[Move], stock: &TriDexel) -> Real {
    let mut pts = Vec::new();
    for g in stock.grids() {
        g.for_each_crossing(|p, c| {
            if c.line > 0 {
                pts.push((p.coords, c.line as usize));
            }
        });
    }
    assert!(pts.len() > 5000, "{} crossings", pts.len());
    let mut worst: Real = 0.0;
    for (p, line) in pts.iter().step_by(pts.len() / 400) {
        // Distance from the union of the sweeps of this move and its neighbours.
        let lo = line.saturating_sub(3).max(1);
        let hi = (line + 3).min(moves.len());
        let d = (lo..=hi)
            .map(|k| distance_from_move(dev, &moves[k - 1], p))
            .fold(Real::INFINITY, Real::min);
        worst = worst.max(d.abs());
    }
    worst
}
