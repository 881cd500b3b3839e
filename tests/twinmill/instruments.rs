//! The virtual instruments on the twin: the laser interferometer's ISO 230-2 figures and the
//! ball bar's ISO 230-4 figures and diagnostics against derivations written here from the
//! error functions and the chain's definition (never from the program's output), and
//! `twinmill measure` writing what `evaluate` reads back, refusing bad input cleanly.

use crate::{Sandbox, builtin, files_in};
use std::path::Path;
use twinmill::math::{Real, Vector3};
use twinmill::metrology::ballbar::{self, BallBarSetup, Plane, Turns};
use twinmill::metrology::circular::{
    self, CircularFigures, CircularOptions, Diagnosis, Sample, Turn,
};
use twinmill::metrology::interferometer::{self, LaserSetup, Targets};
use twinmill::metrology::positioning::{self, Direction as Approach, Reading};
use twinmill::nc::{AxisLetter, AxisValues};
use twinmill::scene::Scene;

/// A 3-axis machine (X, Y, Z from the workpiece, home Z = 50) with `extra` sections. The
/// program it names does not exist: the instruments use only the machine.
fn machine(extra: &str) -> Scene {
    let text = format!(
        "program = \"none.ngc\"\n\
         [machine]\n\
         axes = [\n\
           {{ name = \"X\", kind = \"linear\", direction = [1, 0, 0] }},\n\
           {{ name = \"Y\", kind = \"linear\", direction = [0, 1, 0] }},\n\
           {{ name = \"Z\", kind = \"linear\", direction = [0, 0, 1] }},\n\
         ]\n\
         home = {{ X = 0, Y = 0, Z = 50 }}\n\
         [tool]\nkind = \"flat\"\ndiameter_mm = 6.0\nlength_mm = 20.0\n\
         [stock]\nmin = [0.0, 0.0, 0.0]\nmax = [60.0, 40.0, 20.0]\npitch_mm = 0.5\n\
         {extra}\n"
    );
    Scene::parse(&text, Path::new("machine.toml")).expect("the machine loads")
}

fn values(x: Real, y: Real, z: Real) -> AxisValues {
    AxisValues::default()
        .with(AxisLetter::X, x)
        .with(AxisLetter::Y, y)
        .with(AxisLetter::Z, z)
}

fn laser(scene: &Scene, setup: &LaserSetup) -> Vec<Reading> {
    interferometer::measure(scene.chain(), setup)
        .expect("the laser measures")
        .readings
}

/// The reading of `target`, `direction`, `run`.
fn reading(r: &[Reading], target: Real, direction: Approach, run: u32) -> Real {
    r.iter()
        .find(|x| x.target_mm == target && x.direction == direction && x.run == run)
        .map(|x| x.deviation_mm)
        .expect("every target both ways in every run")
}

// ---------------------------------------------------------------------------------------
// The laser interferometer.

/// EXX = c0 + c1·x + c2·x² + a·sin(2πx/p + φ) and a reversal B on X, no noise: every
/// reading follows from the error function (zeroed at the first target, approached in +),
/// so every ISO 230-2 figure is computed here by hand from it.
#[test]
fn laser_figures_equal_a_hand_computation_from_the_error_functions() {
    let (c0, c1, c2) = (0.002, 8e-6, -3e-8);
    let (a, p, phase) = (0.0015, 25.0, 30.0_f64);
    let b = -0.0035;
    let scene = machine(&format!(
        "[error_motions]\nEXX = {{ polynomial = [{c0}, {c1}, {c2}], periodic = [{{ amplitude = \
         {a}, period = {p}, phase_deg = {phase} }}] }}\n[reversal]\nX = {b}\n"
    ));
    let e = |x: Real| {
        c0 + c1 * x + c2 * x * x + a * (std::f64::consts::TAU * x / p + phase.to_radians()).sin()
    };
    // Irregular spacing, 11 targets over 500 mm (ISO 230-2: at least 5 per metre).
    let targets = [
        0.0, 48.7, 101.3, 149.2, 203.9, 251.1, 298.4, 352.6, 400.0, 447.2, 500.0,
    ];
    let setup = LaserSetup::new(
        AxisLetter::X,
        Targets::List(targets.to_vec()),
        values(0.0, 30.0, 80.0),
    );
    let r = laser(&scene, &setup);
    // Every + reading carries +B/2 as the zero did; every − reading −B/2.
    let up: Vec<Real> = targets.iter().map(|&t| e(t) - e(targets[0])).collect();
    let down: Vec<Real> = up.iter().map(|x| x - b).collect();
    for (i, &t) in targets.iter().enumerate() {
        for run in 1..=5 {
            let (f, w) = (
                reading(&r, t, Approach::Forward, run),
                reading(&r, t, Approach::Backward, run),
            );
            assert!(
                (f - up[i]).abs() < 1e-12,
                "{t} + run {run}: {f} vs {}",
                up[i]
            );
            assert!(
                (w - down[i]).abs() < 1e-12,
                "{t} − run {run}: {w} vs {}",
                down[i]
            );
        }
    }
    // No scatter: s = 0, so R_i = |B_i| = |B|, A = E, and so on.
    let range = |v: &[Real]| {
        v.iter().copied().fold(Real::NEG_INFINITY, Real::max)
            - v.iter().copied().fold(Real::INFINITY, Real::min)
    };
    let both: Vec<Real> = up.iter().chain(&down).copied().collect();
    let mean: Vec<Real> = up.iter().zip(&down).map(|(u, d)| 0.5 * (u + d)).collect();
    let f = positioning::evaluate(&r, Path::new("laser")).expect("a complete set");
    for (name, got, want) in [
        ("B", f.b, b.abs()),
        ("B_mean", f.b_mean, b),
        ("R", f.r, b.abs()),
        ("R_fwd", f.r_fwd, 0.0),
        ("R_bwd", f.r_bwd, 0.0),
        ("E_fwd", f.e_fwd, range(&up)),
        ("E_bwd", f.e_bwd, range(&down)),
        ("E", f.e, range(&both)),
        ("M", f.m, range(&mean)),
        ("A", f.a, range(&both)),
        ("A_fwd", f.a_fwd, range(&up)),
        ("A_bwd", f.a_bwd, range(&down)),
    ] {
        assert!((got - want).abs() < 1e-9, "{name}: {got} vs {want}");
    }
    assert_eq!(f.runs, 5);
    for (t, x) in f.targets.iter().zip(&up) {
        assert!((t.mean_fwd - x).abs() < 1e-12 && (t.b - b).abs() < 1e-12);
    }
    // The figures are of µm size, far above the tolerance: the test sees the errors.
    assert!(f.e > 3e-3, "E {}", f.e);
}

/// Pitch EBX = k·x and yaw ECX = g0 + g1·x with the retroreflector at h = (hx, hy, hz) from
/// the tool point: X's error transform turns the tool side by R = Ry(β)·Rz(γ) about the X
/// carriage's origin, so the reflector sits at R·h from where the tool point is, and along
/// the beam (+X) the readings move by [R(t)·h − R(t₁)·h]_x against those at the tool point —
/// the rigid-body lever, with [Ry(β)·Rz(γ)·h]_x = cos β (hx cos γ − hy sin γ) + hz sin β.
#[test]
fn an_abbe_offset_moves_the_readings_by_the_rigid_body_lever() {
    let (k, g0, g1) = (4e-7, 1e-5, -2e-7);
    let scene = machine(&format!(
        "[error_motions]\nEBX = {{ polynomial = [0, {k}] }}\nECX = {{ polynomial = [{g0}, {g1}] }}\n"
    ));
    let h = Vector3::new(15.0, -40.0, 120.0);
    let mut setup = LaserSetup::new(
        AxisLetter::X,
        Targets::Even {
            start_mm: -100.0,
            end_mm: 400.0,
            count: 11,
        },
        values(0.0, 20.0, 60.0),
    );
    let at_tool = laser(&scene, &setup);
    setup.abbe_offset_mm = h;
    let at_offset = laser(&scene, &setup);
    let lever = |x: Real| {
        let (beta, gamma) = (k * x, g0 + g1 * x);
        beta.cos() * (h.x * gamma.cos() - h.y * gamma.sin()) + h.z * beta.sin()
    };
    let mut largest: Real = 0.0;
    for (a, b) in at_tool.iter().zip(&at_offset) {
        assert_eq!(
            (a.target_mm, a.direction, a.run),
            (b.target_mm, b.direction, b.run)
        );
        let want = lever(a.target_mm) - lever(-100.0);
        let got = b.deviation_mm - a.deviation_mm;
        assert!(
            (got - want).abs() < 1e-12,
            "{}: {got} vs {want}",
            a.target_mm
        );
        largest = largest.max(got.abs());
    }
    // To first order hz·Δβ − hy·Δγ = 120·2e-4 + 40·(−1e-4) = 20 µm at the far end.
    assert!((largest - 0.020).abs() < 1e-4, "largest lever {largest}");
}

/// Gaussian repeatability σ per reading: the pooled standard uncertainty of the readings
/// (21 targets × 2 directions, 20 runs: 798 degrees of freedom) is σ within four of its
/// standard errors σ/√(2·798) (3.6 %); the reversal survives the noise; the same seed gives
/// the same readings, another seed others; a drift d per run adds d·(reading index)/(2m).
#[test]
fn laser_noise_gives_the_repeatability_it_was_given_and_is_deterministic() {
    let b = -0.002;
    let scene = machine(&format!("[reversal]\nX = {b}\n"));
    let sigma_um = 0.8;
    let mut setup = LaserSetup::new(
        AxisLetter::X,
        Targets::Even {
            start_mm: 0.0,
            end_mm: 600.0,
            count: 21,
        },
        values(0.0, 0.0, 50.0),
    );
    setup.runs = 20;
    setup.noise_um = sigma_um;
    setup.seed = 7;
    let r = laser(&scene, &setup);
    let f = positioning::evaluate(&r, Path::new("laser")).expect("a complete set");
    let pooled = (f
        .targets
        .iter()
        .map(|t| t.s_fwd * t.s_fwd + t.s_bwd * t.s_bwd)
        .sum::<Real>()
        / (2 * f.targets.len()) as Real)
        .sqrt();
    let sigma = sigma_um * 1e-3;
    let se = sigma / (2.0 * 798.0_f64).sqrt();
    assert!(
        (pooled - sigma).abs() < 4.0 * se,
        "pooled s {pooled} vs σ {sigma}"
    );
    // B̄ averages 21 differences of two means of 20: σ·√(2/20/21).
    let se_b = sigma * (2.0 / 20.0 / 21.0_f64).sqrt();
    assert!((f.b_mean - b).abs() < 4.0 * se_b, "B̄ {} vs {b}", f.b_mean);
    assert_eq!(r, laser(&scene, &setup), "same seed, same readings");
    setup.seed = 8;
    assert_ne!(r, laser(&scene, &setup), "another seed, other readings");
    // Drift alone on a perfect machine: the first target approached in + is reading
    // (run − 1)·2m, so it reads d·(run − 1).
    let plain = machine("");
    setup.noise_um = 0.0;
    setup.drift_um_per_run = 1.2;
    let r = laser(&plain, &setup);
    for run in 1..=20 {
        let x = reading(&r, 0.0, Approach::Forward, run);
        assert!(
            (x - 1.2e-3 * (run - 1) as Real).abs() < 1e-15,
            "run {run}: {x}"
        );
    }
}

// ---------------------------------------------------------------------------------------
// The ball bar.

fn value(d: &Diagnosis) -> (Real, Real) {
    match d {
        Diagnosis::Value { value, sigma } => (*value, *sigma),
        Diagnosis::NotDetermined { not_determined } => panic!("not determined: {not_determined}"),
    }
}

fn bar(scene: &Scene, setup: &BallBarSetup) -> Vec<Sample> {
    ballbar::measure(scene.chain(), setup)
        .expect("the ball bar measures")
        .samples
}

fn evaluate(samples: &[Sample], r: Real) -> CircularFigures {
    let opts = CircularOptions {
        radius_mm: r,
        pitch_mm: None,
    };
    circular::evaluate(samples, &opts, Path::new("bb")).expect("the trace evaluates")
}

/// The sample of `turn` at `deg` degrees.
fn at(s: &[Sample], turn: Turn, deg: Real) -> Real {
    s.iter()
        .find(|x| x.turn == turn && (x.angle_rad.to_degrees() - deg).abs() < 1e-9)
        .map(|x| x.deviation_mm)
        .expect("a sample at that angle")
}

/// The acceptance case: squareness EC(0X)Y = 50 µrad (Y's line turned 50 µrad about +Z,
/// towards −X), radius 100 mm. The commanded (x, y, z) lands at (x − y sin ε, y cos ε, z),
/// so about a centre on the X axis the bar is |(R cos θ − R sin θ sin ε, R sin θ cos ε)|:
/// −Rε/2 = −2.5 µm at 45°, +2.5 µm at 135°. The axes' angle is 90° + ε, which ISO 230-4's
/// diagnostics report as a squareness of −50 µm/m (positive when less than 90°).
#[test]
fn ballbar_reads_50_urad_of_squareness() {
    let eps: Real = 50e-6;
    let scene = machine(&format!("[deviations]\n\"EC(0X)Y\" = {eps}\n"));
    let r = 100.0;
    let (cx, cz) = (150.0, 40.0);
    let mut setup = BallBarSetup::new(Plane::Xy, values(cx, 0.0, cz), r);
    let clean = bar(&scene, &setup);
    assert_eq!(clean.len(), 720);
    for s in &clean {
        let (sn, cs) = s.angle_rad.sin_cos();
        let want = (r * cs - r * sn * eps.sin()).hypot(r * sn * eps.cos()) - r;
        assert!((s.deviation_mm - want).abs() < 1e-12, "{s:?}: {want}");
    }
    for turn in [Turn::Ccw, Turn::Cw] {
        assert!((at(&clean, turn, 45.0) + 2.5e-3).abs() < 1e-6);
        assert!((at(&clean, turn, 135.0) - 2.5e-3).abs() < 1e-6);
    }
    setup.noise_um = 0.1;
    setup.seed = 3;
    let f = evaluate(&bar(&scene, &setup), r);
    let (sq, sigma) = value(&f.squareness_urad);
    assert!(
        (sq + 50.0).abs() < 0.02 * 50.0,
        "squareness {sq} ± {sigma} µm/m"
    );
    assert!(
        (sq + 50.0).abs() < 4.0 * sigma,
        "squareness {sq} ± {sigma} µm/m"
    );
    assert!(value(&f.servo_mismatch_urad).0.abs() < 1.0);
}

/// The acceptance case: 10 ppm of scale on X (EXX = 10e-6·x), radius 100 mm. The commanded
/// x lands at x(1 + s): at 0° the bar is R + s(cx + R) long, at 180° R + sR − s·cx, so the X
/// diameter is 2sR = 2 µm long wherever the centre is; on a centre at X = 0 the path is the
/// ellipse with semi-axes R(1 + s) and R, G = sR and F from 0 (at 90°) to sR (at 0°). The
/// diagnostics read the cos 2θ term sR/2 as a scale mismatch of 10 µm/m (3,600 samples per
/// revolution keep its noise, σ·√(2/3600), under 0.5 %).
#[test]
fn ballbar_reads_10_ppm_of_scale_as_2_um_of_diameter() {
    let s: Real = 10e-6;
    let scene = machine(&format!(
        "[error_motions]\nEXX = {{ polynomial = [0, {s}] }}\n"
    ));
    let r = 100.0;
    for cx in [0.0, 120.0] {
        let mut setup = BallBarSetup::new(Plane::Xy, values(cx, -60.0, 50.0), r);
        let clean = bar(&scene, &setup);
        for turn in [Turn::Ccw, Turn::Cw] {
            let diameter = at(&clean, turn, 0.0) + at(&clean, turn, 180.0);
            assert!((diameter - 2.0 * s * r).abs() < 1e-12, "{cx}: {diameter}");
            let want0 = s * (cx + r);
            assert!((at(&clean, turn, 0.0) - want0).abs() < 1e-12);
        }
        if cx == 0.0 {
            let f = evaluate(&clean, r);
            for d in &f.directions {
                assert!((d.f_max - s * r).abs() < 1e-12, "F max {}", d.f_max);
                assert!(d.f_min.abs() < 1e-12, "F min {}", d.f_min);
                assert!((d.g - s * r).abs() < 1e-7, "G {}", d.g);
            }
        }
        setup.points = 3600;
        setup.noise_um = 0.1;
        setup.seed = 11;
        let f = evaluate(&bar(&scene, &setup), r);
        for d in &f.directions {
            let (m, sigma) = value(&d.scale_mismatch_um_per_m);
            assert!(
                (m - 10.0).abs() < 0.2,
                "{cx} {:?}: {m} ± {sigma}",
                d.direction
            );
        }
    }
}

/// Which way X last moved at θ on a circle about its centre run in `turn`: against sin θ
/// for ccw (x = R cos θ), with it for cw; at 0° and 180° the way it arrived (+ at its
/// largest, − at its smallest).
fn x_last_moved(theta: Real, turn: Turn) -> Real {
    let deg = theta.to_degrees().round();
    if (theta.to_degrees() - deg).abs() < 1e-9 && deg.rem_euclid(180.0) == 0.0 {
        return if deg.rem_euclid(360.0) == 0.0 {
            1.0
        } else {
            -1.0
        };
    }
    let dir = if turn == Turn::Ccw { 1.0 } else { -1.0 };
    -dir * theta.sin().signum()
}

/// The acceptance case: a lost motion b = 4 µm on X (`[reversal] X = −0.004`, ISO 230-2's
/// B = −b: X lags b/2 behind its motion), radius 100 mm. The tool is at x + (B/2)·(the way X
/// last moved), taken up within 0.5° of each reversal (R(1 − cos θ) ≥ b): every sample is
/// |(R cos θ + (B/2)·dir_x, R sin θ)| − R; the diagnostics read the step b at X's reversals
/// and nothing at Y's; the two directions differ by about b near X's reversals, which is H.
#[test]
fn ballbar_reads_a_lost_motion_at_its_axis_reversals() {
    let big_b = -0.004;
    let scene = machine(&format!("[reversal]\nX = {big_b}\n"));
    let r = 100.0;
    let mut setup = BallBarSetup::new(Plane::Xy, values(0.0, 0.0, 50.0), r);
    let clean = bar(&scene, &setup);
    let hand = |theta: Real, turn: Turn| {
        let (sn, cs) = theta.sin_cos();
        (r * cs + 0.5 * big_b * x_last_moved(theta, turn)).hypot(r * sn) - r
    };
    for s in &clean {
        let want = hand(s.angle_rad, s.turn);
        assert!((s.deviation_mm - want).abs() < 1e-12, "{s:?}: {want}");
    }
    // H: the largest gap between the directions at the same angle (both sample every degree).
    let h = (0..360)
        .map(|k| {
            let t = (k as Real).to_radians();
            (hand(t, Turn::Ccw) - hand(t, Turn::Cw)).abs()
        })
        .fold(0.0, Real::max);
    let f = evaluate(&clean, r);
    assert!(
        (f.h.expect("both directions") - h).abs() < 1e-12,
        "H {:?} vs {h}",
        f.h
    );
    assert!((h - 0.004).abs() < 1e-5, "H {h}");
    setup.noise_um = 0.1;
    setup.seed = 5;
    let f = evaluate(&bar(&scene, &setup), r);
    for d in &f.directions {
        let (b1, s1) = value(&d.reversal_1_mm);
        assert!(
            (b1 - 0.004).abs() < 0.02 * 0.004,
            "{:?}: {b1} ± {s1}",
            d.direction
        );
        let (b2, s2) = value(&d.reversal_2_mm);
        assert!(
            b2.abs() < 4.0 * s2.max(1e-5),
            "{:?}: {b2} ± {s2}",
            d.direction
        );
    }
}

/// A centre ball mounted e = 12 µm off (at 30°) on a perfect machine: the path is the
/// circle of radius R about the centre command, so the bar reads |R·u(θ) − e| − R: exactly
/// −|e| at 30° and +|e| at 210° (F), the least-squares centre is −e, and G is the trace's
/// second-order shape: about −e the samples lie at R + 2q(θ) with
/// q = (|e|² − (e·u)²)/(2R), so G = |e|²/R (0.0014 µm). Both directions read the same: H = 0.
#[test]
fn a_mounting_offset_is_a_centre_offset_with_known_g_f_and_h() {
    let scene = machine("");
    let r = 100.0;
    let (len, phi) = (0.012_f64, 30.0_f64.to_radians());
    let e = Vector3::new(len * phi.cos(), len * phi.sin(), 0.0);
    let mut setup = BallBarSetup::new(Plane::Xy, values(10.0, 20.0, 30.0), r);
    setup.mount_offset_mm = e;
    setup.tool_ball_mm = Vector3::new(0.0, 0.0, 25.0);
    let s = bar(&scene, &setup);
    for x in &s {
        let u = Vector3::new(x.angle_rad.cos(), x.angle_rad.sin(), 0.0);
        let want = (r * u - e).norm() - r;
        assert!((x.deviation_mm - want).abs() < 1e-12);
    }
    let f = evaluate(&s, r);
    for d in &f.directions {
        assert!((d.f_max - len).abs() < 1e-12 && (d.f_min + len).abs() < 1e-12);
        assert!((d.centre_mm[0] + e.x).abs() < 1e-8 && (d.centre_mm[1] + e.y).abs() < 1e-8);
        assert!((d.g - len * len / r).abs() < 1e-8, "G {}", d.g);
    }
    assert_eq!(f.h, Some(0.0));
}

/// The same circle in YZ and ZX reads each plane's own axes: 10 ppm of scale on Z shows as
/// the first axis's in ZX and the second's in YZ (opposite signs of the cos 2θ term).
#[test]
fn ballbar_planes_take_their_axes_in_order() {
    let scene = machine("[error_motions]\nEZZ = { polynomial = [0, 10e-6] }\n");
    let r = 150.0;
    let mut m = Vec::new();
    for plane in [Plane::Zx, Plane::Yz] {
        let mut setup = BallBarSetup::new(plane, values(0.0, 0.0, 0.0), r);
        setup.turns = Turns::Ccw;
        let f = evaluate(&bar(&scene, &setup), r);
        m.push(value(&f.directions[0].scale_mismatch_um_per_m).0);
    }
    assert!(
        (m[0] - 10.0).abs() < 1e-3 && (m[1] + 10.0).abs() < 1e-3,
        "{m:?}"
    );
}

// ---------------------------------------------------------------------------------------
// The command line.

#[test]
fn measure_writes_what_evaluate_reads_back_with_the_same_figures() {
    let sb = Sandbox::new("measure");
    // The built-in scene with error motions, without its program: measure needs none.
    sb.write("em.toml", builtin("xyz-error-motions.toml").as_bytes());
    let (code, stdout, stderr) = sb.run(&[
        "measure",
        "em.toml",
        "--instrument",
        "laser",
        "--axis",
        "X",
        "--from",
        "0",
        "--to",
        "60",
        "--targets",
        "7",
        "--noise",
        "0.5",
        "--abbe",
        "0,0,-20",
        "--json",
    ]);
    assert_eq!(code, 0, "{stderr}");
    let measured: serde_json::Value = serde_json::from_str(&stdout).expect("json");
    assert!(sb.dir.join("em-laser.csv").is_file());
    let (code, evaluated, stderr) = sb.run(&["evaluate", "iso230-2", "em-laser.csv", "--json"]);
    assert_eq!(code, 0, "{stderr}");
    assert_eq!(stdout, evaluated, "the same figures");
    // The scene's reversal X = −0.003 reads as B̄ = −3 µm. Its noise: each Bᵢ is the
    // difference of two means of 5 readings of σ 0.5 µm, B̄ the mean of 7 targets' Bᵢ, so
    // its standard error is σ·√(2/(5·7)) = 0.12 µm; within 4 of them (the program's other
    // errors — scale, Abbe lever, straightness — are the same both ways and cancel in B).
    let b = measured["B_mean"].as_f64().expect("B_mean");
    let se = 0.5e-3 * (2.0_f64 / 35.0).sqrt();
    assert!(
        (b + 0.003).abs() < 4.0 * se,
        "B̄ {b} mm, standard error {se} mm"
    );
    // The summary and the plot.
    let (code, stdout, stderr) = sb.run(&[
        "measure",
        "em.toml",
        "--instrument",
        "laser",
        "--axis",
        "X",
        "--from",
        "0",
        "--to",
        "60",
        "--out",
        "x.csv",
        "--png",
        "x.png",
    ]);
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.contains("reversal      B 3.0000 µm") && stdout.contains("wrote         x.csv"));
    assert!(std::fs::read(sb.dir.join("x.png")).is_ok_and(|p| p.starts_with(b"\x89PNG")));

    let (code, stdout, stderr) = sb.run(&[
        "measure",
        "em.toml",
        "--instrument",
        "ballbar",
        "--radius",
        "150",
        "--centre",
        "X=30,Y=20",
        "--noise",
        "0.1",
        "--json",
        "--png",
        "polar.png",
    ]);
    assert_eq!(code, 0, "{stderr}");
    let (code, evaluated, stderr) = sb.run(&[
        "evaluate",
        "iso230-4",
        "em-ballbar.csv",
        "--radius",
        "150",
        "--json",
    ]);
    assert_eq!(code, 0, "{stderr}");
    assert_eq!(stdout, evaluated, "the same figures");
    let j: serde_json::Value = serde_json::from_str(&stdout).expect("json");
    assert_eq!(j["directions"].as_array().map(Vec::len), Some(2));
    // The scene's 20 µrad of EC(0X)Y read as a squareness of −20 µm/m, within four of its
    // reported uncertainties (the scene's 2 µm straightness wave scatters the fit).
    let sq = j["squareness_urad"]["value"].as_f64().expect("squareness");
    let sigma = j["squareness_urad"]["sigma"].as_f64().expect("sigma");
    assert!((sq + 20.0).abs() < 4.0 * sigma, "squareness {sq} ± {sigma}");
    assert!(std::fs::read(sb.dir.join("polar.png")).is_ok_and(|p| p.starts_with(b"\x89PNG")));
}

#[test]
fn measure_refuses_bad_input_naming_the_problem_and_writes_nothing() {
    let sb = Sandbox::new("measure-bad");
    sb.write("em.toml", builtin("xyz-error-motions.toml").as_bytes());
    let laser = [
        "--instrument",
        "laser",
        "--axis",
        "X",
        "--from",
        "0",
        "--to",
        "60",
    ];
    let ballbar = ["--instrument", "ballbar"];
    let cases: &[(&[&str], &[&str], &str)] = &[
        (&laser[..2], &["--from", "0", "--to", "10"], "needs --axis"),
        (
            &laser[..2],
            &["--axis", "Q", "--from", "0", "--to", "1"],
            "--axis: 'Q'",
        ),
        (
            &laser[..2],
            &["--axis", "A", "--from", "0", "--to", "1"],
            "no axis A",
        ),
        (&laser[..4], &[], "needs --from and --to"),
        (&laser, &["--runs", "1"], "--runs: 1 given"),
        (&laser, &["--targets", "1"], "--targets: 1 given"),
        (&laser[..6], &["--to", "nan"], "must be finite"),
        (&laser, &["--noise", "-1"], "--noise"),
        (&laser, &["--drift", "inf"], "--drift"),
        (&laser, &["--overshoot", "0"], "--overshoot"),
        (&laser, &["--abbe", "1,2"], "--abbe needs three numbers"),
        (&laser, &["--at", "W=3"], "'W' is not an axis"),
        (&laser, &["--at", "X=3"], "X is the measured axis"),
        (&laser, &["--at", "Y=nan"], "not finite"),
        (&laser[..4], &["--target-list", "0,5,5"], "given twice"),
        (
            &laser,
            &["--radius", "100"],
            "--radius is an option of --instrument ballbar",
        ),
        (&ballbar, &["--radius", "0"], "--radius: must be a positive"),
        (&ballbar, &["--radius", "-5"], "--radius"),
        (&ballbar, &["--radius", "inf"], "--radius"),
        (&ballbar, &["--plane", "XZ"], "--plane: 'XZ'"),
        (&ballbar, &["--points", "4"], "--points"),
        (&ballbar, &["--centre", "X=1,Q=2"], "'Q' is not an axis"),
        (&ballbar, &["--overshoot", "-1"], "--overshoot"),
        (&ballbar, &["--feed", "0"], "--feed"),
        (&ballbar, &["--pitch", "0"], "--pitch"),
        (&ballbar, &["--mount", "80,0,0"], "cannot be evaluated"),
        (
            &ballbar,
            &["--axis", "X"],
            "--axis is an option of --instrument laser",
        ),
        (&ballbar, &["--noise", "nan"], "--noise"),
    ];
    for (base, extra, want) in cases {
        let mut args = vec!["measure", "em.toml"];
        args.extend(base.iter().copied());
        args.extend(extra.iter().copied());
        args.extend(["--png", "p.png"]);
        let (code, stdout, stderr) = sb.run(&args);
        assert_ne!(code, 0, "{args:?}");
        assert!(stdout.is_empty(), "{args:?}: {stdout}");
        assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
        assert_eq!(stderr.trim_end().lines().count(), 1, "{args:?}: {stderr}");
        assert!(stderr.contains(want), "{args:?}: '{want}' not in {stderr}");
        let files = files_in(&sb.dir);
        assert_eq!(files.len(), 1, "{args:?} wrote {files:?}");
    }
    // A scene that does not load is its own one-line error.
    let (code, _, stderr) = sb.run(&["measure", "nowhere.toml", "--instrument", "ballbar"]);
    assert_ne!(code, 0);
    assert!(stderr.contains("nowhere.toml") && stderr.trim_end().lines().count() == 1);
}
