//! Public behaviour of twinmill, through the library API and the `twinmill` binary.

use nalgebra::{Matrix4, Vector4};
use proptest::prelude::*;
use std::path::{Path, PathBuf};
use std::process::Command;
use twinmill::cutting::stock::TriDexel;
use twinmill::cutting::sweep::{SweepOptions, sweep_program};
use twinmill::machine::chain::Chain;
use twinmill::math::{Aabb, Point3, Real, Vector3};
use twinmill::metrology::scan::ScannerConfig;
use twinmill::nc::{AxisLetter, AxisValues, Move, MoveKind};
use twinmill::pipeline::{Outcome, run};
use twinmill::progress::NoProgress;
use twinmill::scene::Scene;

const SCENE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/mdx50-step.toml");

fn scene() -> Scene {
    Scene::load(Path::new(SCENE)).expect("the built-in scene loads")
}

fn run_scene(scene: &Scene) -> Outcome {
    let program = scene.load_program().expect("the built-in program parses");
    run(scene, &program, &NoProgress).expect("the pipeline runs")
}

/// The scene's scanner, to change its settings.
fn scanner(scene: &mut Scene) -> &mut ScannerConfig {
    scene
        .scanner
        .as_mut()
        .expect("the built-in scenes have a [scanner]")
}

fn set_deviation(scene: &mut Scene, name: &str, value: Real) {
    let id = scene.chain.deviation_id(name).expect("known name");
    scene.chain.set_deviation(id, value);
    scene.injected.insert(name.to_string(), value);
}

// ---------------------------------------------------------------------------------------
// An independent derivation of the exact faces (BRIEF §4): homogeneous 4×4 matrices built
// here from the chain's definition, not from the library's kinematics or sweep code.

fn trans(x: Real, y: Real, z: Real) -> Matrix4<Real> {
    let mut m = Matrix4::identity();
    m[(0, 3)] = x;
    m[(1, 3)] = y;
    m[(2, 3)] = z;
    m
}

fn rot(axis: usize, a: Real) -> Matrix4<Real> {
    let (s, c) = a.sin_cos();
    let (i, j) = ((axis + 1) % 3, (axis + 2) % 3);
    let mut m = Matrix4::identity();
    m[(i, i)] = c;
    m[(i, j)] = -s;
    m[(j, i)] = s;
    m[(j, j)] = c;
    m
}

/// E = Trans(dx,dy,dz)·Rx(alpha)·Ry(beta)·Rz(gamma)
fn deviation(d: [Real; 6]) -> Matrix4<Real> {
    trans(d[0], d[1], d[2]) * rot(0, d[3]) * rot(1, d[4]) * rot(2, d[5])
}

/// r_W = RotX(a)·E_AY·Ty·E_YX·Tx·E_XZ·Tz·E_ZS·r_T
fn mdx50_w_from_t(dev: &[[Real; 6]; 4], x: Real, y: Real, z: Real, a_deg: Real) -> Matrix4<Real> {
    rot(0, a_deg.to_radians())
        * deviation(dev[0])
        * trans(0.0, y, 0.0)
        * deviation(dev[1])
        * trans(x, 0.0, 0.0)
        * deviation(dev[2])
        * trans(0.0, 0.0, z)
        * deviation(dev[3])
}

/// The flank plane (unit normal towards +Y_W, offset) of a straight cut along X of a
/// cylinder of radius `r`: tangent to the cylinder, parallel to its axis and the path.
fn exact_face(dev: &[[Real; 6]; 4], y: Real, a_deg: Real, r: Real) -> (Vector3, Real) {
    let m0 = mdx50_w_from_t(dev, -30.0, y, 0.0, a_deg);
    let m1 = mdx50_w_from_t(dev, 30.0, y, 0.0, a_deg);
    let p0 = (m0 * Vector4::new(0.0, 0.0, 0.0, 1.0)).xyz();
    let p1 = (m1 * Vector4::new(0.0, 0.0, 0.0, 1.0)).xyz();
    let axis = (m0 * Vector4::new(0.0, 0.0, 1.0, 0.0)).xyz();
    let mut n = (p1 - p0).cross(&axis).normalize();
    if n.y < 0.0 {
        n = -n;
    }
    (n, n.dot(&p0) + r)
}

fn mdx50_deviations(scene: &Scene) -> [[Real; 6]; 4] {
    std::array::from_fn(|j| scene.chain.deviations()[j].values)
}

// ---------------------------------------------------------------------------------------
// Acceptance of the 0°/180° experiment.

#[test]
fn noise_off_step_and_identification_are_exact() {
    let mut s = scene();
    scanner(&mut s).noise_sigma_mm = 0.0;
    let out = run_scene(&s);
    let r = &out.report;
    assert!((r.step_mm - 1.0).abs() < 0.5e-3, "step {}", r.step_mm);
    let dy = r.identified["dy_AY"];
    assert!((dy + 0.5).abs() < 0.5e-3, "dy_AY {dy}");
    let g = r.identified["gamma_AY+gamma_YX"];
    assert!(g.abs() < 2e-6, "gamma sum {g}");
    // Far tighter in fact: the faces are exact.
    assert!((r.step_mm - 1.0).abs() < 1e-6, "step {}", r.step_mm);
}

#[test]
fn noise_on_identifies_dy_ay_within_2_um() {
    let mut s = scene();
    assert_eq!(scanner(&mut s).noise_sigma_mm, 0.025);
    assert_eq!(scanner(&mut s).pitch_mm, 0.185);
    let r = run_scene(&s).report;
    let dy = r.identified["dy_AY"];
    assert!((dy + 0.5).abs() < 2e-3, "dy_AY {dy}");
    // The stated uncertainty is honest: the error is within 4 of it.
    assert!(
        (dy + 0.5).abs() < 4.0 * r.uncertainty["dy_AY"],
        "dy_AY {dy} ± {}",
        r.uncertainty["dy_AY"]
    );
}

#[test]
fn zero_deviations_leave_no_step() {
    let mut s = scene();
    set_deviation(&mut s, "dy_AY", 0.0);
    scanner(&mut s).noise_sigma_mm = 0.0;
    let r = run_scene(&s).report;
    assert!(r.step_mm.abs() < 0.1e-3, "step {}", r.step_mm);
}

#[test]
fn faces_selected_in_the_scene_by_box_or_seed_identify_the_same() {
    let text = builtin("mdx50-step.toml")
        .replace(
            "{ name = \"A0\", line = 9 },",
            "{ name = \"A0\", line = 9, box = { min = [-18.0, -30.0, 1.0], max = [18.0, -15.0, 9.0] } },",
        )
        .replace("{ name = \"A180\", line = 14 },", "{ name = \"A180\", line = 14, seed = [0.0, -21.5, -5.0] },");
    assert!(text.contains("box =") && text.contains("seed ="));
    let mut s = Scene::parse(&text, Path::new(SCENE)).expect("parses");
    scanner(&mut s).noise_sigma_mm = 0.0;
    let r = run_scene(&s).report;
    assert!((r.step_mm - 1.0).abs() < 0.5e-3, "step {}", r.step_mm);
    assert!((r.identified["dy_AY"] + 0.5).abs() < 0.5e-3);
    // Both ways found a sizeable face.
    assert!(
        r.faces.iter().all(|f| f.points > 5000),
        "{:?}",
        r.faces.iter().map(|f| f.points).collect::<Vec<_>>()
    );
}

#[test]
fn gamma_sum_is_identified_from_the_tilt() {
    // gamma_AY + gamma_YX tilts the two faces oppositely (eq. 6, 7).
    let mut s = scene();
    scanner(&mut s).noise_sigma_mm = 0.0;
    set_deviation(&mut s, "gamma_AY", 3e-4);
    set_deviation(&mut s, "gamma_YX", -1e-4);
    let r = run_scene(&s).report;
    let g = r.identified["gamma_AY+gamma_YX"];
    assert!((g - 2e-4).abs() < 2e-6, "gamma sum {g}");
    assert!((r.identified["dy_AY"] + 0.5).abs() < 0.5e-3);
    // To first order the tilt is 2(γ_AY + γ_YX).
    assert!((r.tilt_rad - 4e-4).abs() < 1e-6, "tilt {}", r.tilt_rad);
}

fn realistic_scene() -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/mdx50-step-realistic.toml");
    Scene::load(&path).expect("loads")
}

#[test]
fn realistic_scanner_still_gives_dy_ay_within_2_um() {
    // Correlated noise (ℓ 0.3 mm), three turntable views with registration errors, grazing
    // drop-out, working range.
    let mut s = realistic_scene();
    assert_eq!(
        scanner(&mut s)
            .turntable
            .as_ref()
            .map(|t| t.angles_deg.len()),
        Some(3)
    );
    let r = run_scene(&s).report;
    assert_eq!(r.scan.views.len(), 3);
    let (dy, sigma) = (r.identified["dy_AY"], r.uncertainty["dy_AY"]);
    assert!((dy + 0.5).abs() < 2e-3, "dy_AY {dy}");
    assert!((dy + 0.5).abs() < 3.0 * sigma, "dy_AY {dy} ± {sigma}");
}

#[test]
fn scanner_study_separates_the_effects_and_reports_honest_uncertainties() {
    let mut s = scene();
    s.study.trials = 12;
    let program = s.load_program().expect("parses");
    let cases = {
        let part = twinmill::pipeline::machine_part(&s, &program, &NoProgress).expect("machines");
        let surface = twinmill::metrology::scan::Surface::new(&part.stock);
        twinmill::pipeline::scanner_study(&s, &program, &surface, &s.study).expect("runs")
    };
    assert_eq!(cases.len(), 6);
    let [ideal, white, correlated, misregistered, all, _configured] = &cases[..] else {
        unreachable!()
    };
    assert_eq!(ideal.parameter, "dy_AY");
    assert_eq!(ideal.truth_mm, -0.5);
    assert!(
        ideal.worst_error_mm < 1e-6,
        "ideal {}",
        ideal.worst_error_mm
    );
    // One view: a rigid registration error moves both faces together; the step is a
    // difference and does not see it.
    assert!(
        misregistered.worst_error_mm < 1e-5,
        "misregistered {}",
        misregistered.worst_error_mm
    );
    // Correlated noise leaves fewer independent samples: a larger spread...
    assert!(correlated.spread_mm > 3.0 * white.spread_mm);
    // ...which the reported uncertainty follows (12 trials: the spread itself is known to ±20 %).
    for c in [white, correlated, all] {
        let ratio = c.mean_reported_sigma_mm / c.spread_mm;
        assert!(
            (0.6..1.6).contains(&ratio),
            "{}: reported {} vs spread {}",
            c.case,
            c.mean_reported_sigma_mm,
            c.spread_mm
        );
        assert!(
            (c.mean_mm - c.truth_mm).abs() < 3.0 * c.spread_mm / (c.trials as Real).sqrt() + 1e-7,
            "{} biased",
            c.case
        );
    }
}

#[test]
fn another_chain_needs_only_a_scene_file() {
    // A VMC with the rotary table on the X table: chain A, X, Y, Z; the A axis's offset is
    // dy_AX. Same program, same experiment.
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/vmc-4th-axis-step.toml");
    let mut s = Scene::load(&path).expect("loads");
    assert_eq!(s.chain.joint_name(0), "AX");
    scanner(&mut s).noise_sigma_mm = 0.0;
    let r = run_scene(&s).report;
    assert!(
        (r.identified["dy_AX"] - 0.12).abs() < 0.5e-3,
        "dy_AX {}",
        r.identified["dy_AX"]
    );
    let g = r.identified["gamma_AX+gamma_XY"];
    assert!((g - 8e-5).abs() < 2e-6, "gamma sum {g}");
    assert!((r.step_mm + 0.24).abs() < 0.5e-3, "step {}", r.step_mm);
}

#[test]
fn ball_end_mill_cuts_the_same_step() {
    // The ball's flank starts one radius above the tip: with the tip 3 mm lower, both
    // flanks start at Z_W = 0 as the flat mill's do.
    let mut s = scene();
    s.tool =
        twinmill::cutting::tool::Tool::try_new(twinmill::cutting::tool::ToolKind::Ball, 6.0, 25.0)
            .expect("valid");
    scanner(&mut s).noise_sigma_mm = 0.0;
    let text = builtin("mdx50-step.ngc").replace("G0 Z0", "G0 Z-3");
    let program =
        twinmill::nc::parse_program(&text, Path::new("ball.ngc"), s.home).expect("parses");
    let r = run(&s, &program, &NoProgress).expect("runs").report;
    assert!((r.step_mm - 1.0).abs() < 0.5e-3, "step {}", r.step_mm);
    assert!((r.identified["dy_AY"] + 0.5).abs() < 0.5e-3);
}

// ---------------------------------------------------------------------------------------
// Predicted step heights: the real simulation (sweep, noise-free scan, plane fits) against
// the faces derived here from 4×4 matrices.

const NINE: [&str; 9] = [
    "dy_AY", "dz_AY", "beta_AY", "gamma_AY", "alpha_YX", "gamma_YX", "beta_XZ", "alpha_ZS",
    "beta_ZS",
];

/// Ten deviation sets mixing all nine: offsets within ±0.5 mm, angles within ±5e-4 rad
/// (a fixed table of signs and fractions; the first is seed 002's experiment).
fn deviation_table() -> Vec<[Real; 9]> {
    let mut out = vec![[-0.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]];
    let mut state: u64 = 0x2002;
    for _ in 0..10 {
        let mut row = [0.0; 9];
        for (k, v) in row.iter_mut().enumerate() {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let f = ((state >> 11) as Real / (1u64 << 53) as Real) * 2.0 - 1.0;
            *v = if k < 2 { 0.5 * f } else { 5e-4 * f };
        }
        out.push(row);
    }
    out
}

/// Step and tilt of the two exact faces, measured as the report measures them: along +Y_W
/// (the first face's nominal normal) through `at`, tilt along the cut direction +X_W.
fn exact_step_and_tilt(dev: &[[Real; 6]; 4], r: Real, at: Vector3) -> (Real, Real) {
    let (n1, d1) = exact_face(dev, -25.0, 0.0, r);
    let (n2, d2) = exact_face(dev, 25.0, 180.0, r);
    let t1 = (d1 - n1.dot(&at)) / n1.y;
    let t2 = (d2 - n2.dot(&at)) / n2.y;
    (t2 - t1, n2.x - n1.x)
}

#[test]
fn predicted_steps_match_the_chain_for_mixed_deviations() {
    for (i, row) in deviation_table().iter().enumerate() {
        let mut s = scene();
        scanner(&mut s).noise_sigma_mm = 0.0;
        for (name, v) in NINE.iter().zip(row) {
            set_deviation(&mut s, name, *v);
        }
        let r = run_scene(&s).report;
        let c = |k: usize| Vector3::from(r.faces[k].centroid_mm);
        let at = (c(0) + c(1)) / 2.0;
        let (step, tilt) = exact_step_and_tilt(&mdx50_deviations(&s), s.tool.radius(), at);
        if i == 0 {
            assert!((step - 1.0).abs() < 1e-9, "seed 002: exact step {step}");
        }
        assert!(
            (r.step_mm - step).abs() <= 0.5e-3,
            "set {i}: step {} vs exact {step}",
            r.step_mm
        );
        assert!(
            (r.predicted_step_mm - step).abs() <= 0.5e-3,
            "set {i}: twin's step {} vs exact {step}",
            r.predicted_step_mm
        );
        assert!(
            (r.tilt_rad - tilt).abs() <= 1e-6,
            "set {i}: tilt {} vs exact {tilt}",
            r.tilt_rad
        );
    }
}

// ---------------------------------------------------------------------------------------
// The simulated faces coincide with the exact planes of the chain.

fn check_faces_exact(s: &Scene) -> Result<(), TestCaseError> {
    let dev = mdx50_deviations(s);
    let r = s.tool.radius();
    let faces = [(-25.0, 0.0, 1.5, 8.5), (25.0, 180.0, -8.5, -1.5)];
    let program = s.load_program().expect("parses");
    let mut stock = TriDexel::new_box(s.stock_box, s.pitch_mm, 4e9).expect("fits");
    sweep_program(
        &mut stock,
        &s.chain,
        &s.tool,
        &program.moves,
        &s.sweep,
        &NoProgress,
    )
    .expect("sweeps");
    for (y, a, z0, z1) in faces {
        let (n, d) = exact_face(&dev, y, a, r);
        let mut count = 0;
        let mut worst: Real = 0.0;
        for g in stock.grids() {
            g.for_each_crossing(|p, c| {
                let in_region =
                    p.x.abs() <= 18.0 && p.z >= z0 && p.z <= z1 && (p.y + 22.0).abs() <= 1.8;
                if in_region && c.normal().y < -0.9 {
                    count += 1;
                    worst = worst.max((n.dot(&p.coords) - d).abs());
                }
            });
        }
        prop_assert!(count > 5000, "A{a}: only {count} crossings on the face");
        prop_assert!(
            worst <= 0.5e-3,
            "A{a}: dexel crossing {worst} mm off the exact plane"
        );
        // And the noise-free scan of the face.
        let mut sc = s.scanner.clone().expect("the scene has a [scanner]");
        sc.noise_sigma_mm = 0.0;
        let scanned = twinmill::metrology::scan::scan(&stock, &sc, &NoProgress).expect("scans");
        let mut count = 0;
        let mut worst: Real = 0.0;
        for p in &scanned.cloud.points {
            if p.x.abs() <= 18.0 && p.z >= z0 && p.z <= z1 && (p.y + 22.0).abs() <= 1.8 {
                count += 1;
                worst = worst.max((n.dot(&p.coords) - d).abs());
            }
        }
        prop_assert!(count > 5000, "A{a}: only {count} scan points on the face");
        prop_assert!(
            worst <= 0.5e-3,
            "A{a}: scan point {worst} mm off the exact plane"
        );
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 12, failure_persistence: None, ..ProptestConfig::default() })]
    #[test]
    fn simulated_faces_coincide_with_exact_planes(
        dy in -1.0..1.0f64, dz in -0.5..0.5f64,
        g_ay in -5e-4..5e-4f64, g_yx in -5e-4..5e-4f64, a_yx in -5e-4..5e-4f64,
        b_xz in -5e-4..5e-4f64, a_zs in -5e-4..5e-4f64, b_zs in -5e-4..5e-4f64,
    ) {
        let mut s = scene();
        for (name, v) in [("dy_AY", dy), ("dz_AY", dz), ("gamma_AY", g_ay), ("gamma_YX", g_yx),
                          ("alpha_YX", a_yx), ("beta_XZ", b_xz), ("alpha_ZS", a_zs), ("beta_ZS", b_zs)] {
            set_deviation(&mut s, name, v);
        }
        check_faces_exact(&s)?;
    }
}

#[test]
fn the_library_chain_matches_the_independent_derivation() {
    let mut s = scene();
    let vals = [
        ("dy_AY", -0.3),
        ("dz_AY", 0.2),
        ("beta_AY", 1e-4),
        ("gamma_AY", -2e-4),
        ("alpha_YX", 3e-4),
        ("gamma_YX", 1e-4),
        ("beta_XZ", -1e-4),
        ("alpha_ZS", 2e-4),
        ("beta_ZS", -3e-4),
        ("dx_ZS", 0.05),
    ];
    for (n, v) in vals {
        set_deviation(&mut s, n, v);
    }
    let dev = mdx50_deviations(&s);
    for (x, y, z, a) in [
        (1.0, 2.0, 3.0, 0.0),
        (-12.0, 25.0, 7.0, 180.0),
        (3.0, -4.0, 50.0, 37.5),
    ] {
        let q = AxisValues::default()
            .with(AxisLetter::X, x)
            .with(AxisLetter::Y, y)
            .with(AxisLetter::Z, z)
            .with(AxisLetter::A, a);
        let lib = s.chain.w_from_t(&q).to_homogeneous();
        let ind = mdx50_w_from_t(&dev, x, y, z, a);
        assert!(
            (lib - ind).abs().max() < 1e-12,
            "pose differs at {x} {y} {z} {a}"
        );
    }
}

// ---------------------------------------------------------------------------------------
// A rotary move: the dexel surface agrees with a brute-force point-in-sweep test.

fn nominal_mdx50() -> Chain {
    scene().chain.nominal()
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
    sweep_program(&mut stock, &s.chain, &s.tool, &moves, &s.sweep, &NoProgress).expect("sweeps");
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
fn golden_min(mut a: Real, mut b: Real, f: impl Fn(Real) -> Real) -> Real {
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
    assert!(
        rep.rotary_error_bound_mm <= 1e-7,
        "{}",
        rep.rotary_error_bound_mm
    );
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
    let mut stock = helix_stock(0.2);
    sweep_program(
        &mut stock,
        &s.chain,
        &helix_tool(),
        &moves,
        &s.sweep,
        &NoProgress,
    )
    .expect("sweeps");
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
            .map(|k| distance_from_move(&dev, &moves[k - 1], p))
            .fold(Real::INFINITY, Real::min);
        worst = worst.max(d.abs());
    }
    assert!(
        worst <= 2e-7,
        "a groove crossing lies {worst} mm from the swept surface"
    );
}

// ---------------------------------------------------------------------------------------
// Determinism.

#[test]
fn output_is_identical_for_one_and_two_threads() {
    let s = scene();
    let run_with = |threads| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool");
        let mut out = pool.install(|| run_scene(&s));
        out.report.timings_s.clear();
        out
    };
    let (a, b) = (run_with(1), run_with(2));
    assert_eq!(a.cloud, b.cloud);
    assert_eq!(a.report, b.report);
    assert_eq!(a.heat_map_png, b.heat_map_png);
}

// ---------------------------------------------------------------------------------------
// The command line.

struct Sandbox {
    dir: PathBuf,
}

impl Sandbox {
    fn new(name: &str) -> Self {
        let dir = std::env::temp_dir().join(format!("twinmill-test-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("temp dir");
        Self { dir }
    }

    fn write(&self, name: &str, bytes: &[u8]) -> PathBuf {
        let p = self.dir.join(name);
        std::fs::write(&p, bytes).expect("write");
        p
    }

    fn run(&self, args: &[&str]) -> (i32, String, String) {
        let out = Command::new(env!("CARGO_BIN_EXE_twinmill"))
            .args(args)
            .current_dir(&self.dir)
            .output()
            .expect("binary runs");
        (
            out.status.code().unwrap_or(-1),
            String::from_utf8_lossy(&out.stdout).into_owned(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    }
}

impl Drop for Sandbox {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

fn builtin(name: &str) -> String {
    std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("scenes")
            .join(name),
    )
    .expect("built-in file")
}

#[test]
fn cli_run_writes_report_cloud_and_picture() {
    let sb = Sandbox::new("run");
    sb.write("s.toml", builtin("mdx50-step.toml").as_bytes());
    sb.write("mdx50-step.ngc", builtin("mdx50-step.ngc").as_bytes());
    let (code, stdout, stderr) = sb.run(&["run", "s.toml", "--json"]);
    assert_eq!(code, 0, "{stderr}");
    let report: serde_json::Value =
        serde_json::from_str(&stdout).expect("--json prints the report");
    assert!(
        report["step_mm"]
            .as_f64()
            .is_some_and(|s| (s - 1.0).abs() < 2e-3)
    );
    assert_eq!(report["injected"]["dy_AY"].as_f64(), Some(-0.5));
    assert!(report["identified"]["dy_AY"].is_number());
    assert!(report["timings_s"].as_array().is_some_and(|t| t.len() >= 5));
    let dir = sb.dir.join("out/mdx50-step");
    let written: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("report.json")).expect("report.json"))
            .expect("json");
    assert_eq!(written["step_mm"], report["step_mm"]);
    let ply = std::fs::read(dir.join("cloud.ply")).expect("cloud.ply");
    let cloud =
        twinmill::metrology::cloud::read_ply(&ply, &dir.join("cloud.ply")).expect("readable PLY");
    assert_eq!(
        Some(cloud.points.len() as u64),
        report["scan"]["points"].as_u64()
    );
    let png = std::fs::read(dir.join("faces.png")).expect("faces.png");
    assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
    // The summary (no --json) names the step and the identified deviation.
    let (code, stdout, _) = sb.run(&["run", "s.toml"]);
    assert_eq!(code, 0);
    assert!(
        stdout.contains("step") && stdout.contains("dy_AY"),
        "{stdout}"
    );
}

#[test]
fn scene_nc_section_sets_tool_table_and_units() {
    let sb = Sandbox::new("nc-section");
    let scene = builtin("mdx50-step.toml").replace(
        "program = \"mdx50-step.ngc\"",
        "program = \"p.ngc\"\n[nc]\ntool_table = \"t.tbl\"\nexternal_units = \"inch\"\n",
    );
    // The [nc] table must come after the top-level keys: move it to the end of the file.
    let (head, nc) = scene.split_once("[nc]").expect("inserted");
    let (nc_body, rest) = nc.split_at(nc.find("\n\n").expect("blank line after"));
    let scene = format!("{head}{rest}\n[nc]{nc_body}\n");
    let path = sb.write("s.toml", scene.as_bytes());
    // Tool 1 is 0.5 inch long: after G43 H1 the machine Z (spindle gauge line) is the
    // programmed tip Z plus 12.7 mm.
    sb.write("t.tbl", b"T1 P1 Z0.5 D0.25 ;quarter-inch end mill\n");
    sb.write("p.ngc", b"G21 G90\nT1 M6\nG43 H1\nG0 X1 Y2 Z5\nM2\n");
    let s = Scene::load(&path).expect("valid scene");
    let program = s.load_program().expect("valid program");
    let last = program.moves.last().expect("a move");
    assert_eq!(last.end.get(AxisLetter::Z), 5.0 + 12.7);
    assert_eq!(last.end.get(AxisLetter::X), 1.0);
    // A missing table is an error naming it.
    std::fs::remove_file(sb.dir.join("t.tbl")).expect("removed");
    let err = s.load_program().expect_err("missing table").to_string();
    assert!(err.contains("t.tbl"), "{err}");
}

#[test]
fn cli_simulate_writes_a_closed_mesh_of_the_cut_part() {
    let sb = Sandbox::new("simulate");
    // A coarser pitch keeps the mesh small; the geometry is the built-in scene's.
    let scene = builtin("mdx50-step.toml").replace("pitch_mm = 0.1 ", "pitch_mm = 0.25");
    sb.write("s.toml", scene.as_bytes());
    sb.write("mdx50-step.ngc", builtin("mdx50-step.ngc").as_bytes());
    let (code, stdout, stderr) = sb.run(&["simulate", "s.toml", "--json", "--mesh", "stl,ply"]);
    assert_eq!(code, 0, "{stderr}");
    let report: serde_json::Value = serde_json::from_str(&stdout).expect("--json prints it");
    // The cut at A = 0 (tool at W y = −25.5 with dy_AY = −0.5, flutes on z ≥ 0) leaves the
    // face y = −22.5 and removes y ∈ [−24, −22.5] × z ∈ [0, 10] over the 40 mm length; the
    // cut at A = 180 (W y = −24.5, z ≤ 0) removes y ∈ [−24, −21.5] × z ∈ [−10, 0]:
    // 40 · 10 · (1.5 + 2.5) = 1,600 mm³. Faces lie on the dexel rays' exact crossings.
    let removed = report["stock"]["removed_mm3"].as_f64().expect("number");
    assert!((removed - 1600.0).abs() < 1e-6, "{removed}");
    // One closed surface with no handle: Euler characteristic 2; its volume is the stock's
    // less at most (h/2)²/2 per mm of sharp edge (≈ 450 mm of edges at h = 0.25 mm).
    assert_eq!(report["mesh"]["euler_characteristic"].as_i64(), Some(2));
    let volume = report["mesh"]["volume_mm3"].as_f64().expect("number");
    let edge_bound = 450.0 * (0.25_f64 / 2.0).powi(2) / 2.0;
    assert!(
        volume <= 24_000.0 + 1e-6 && volume > 24_000.0 - edge_bound,
        "{volume}"
    );
    let dir = sb.dir.join("out/mdx50-step-simulate");
    let stl = std::fs::read(dir.join("part.stl")).expect("part.stl");
    let triangles = u32::from_le_bytes(stl[80..84].try_into().expect("4 bytes")) as u64;
    assert_eq!(Some(triangles), report["mesh"]["triangles"].as_u64());
    assert_eq!(stl.len() as u64, 84 + 50 * triangles);
    let ply = std::fs::read(dir.join("part.ply")).expect("part.ply");
    assert!(ply.starts_with(b"ply\nformat binary_little_endian 1.0\n"));
    assert!(!dir.join("part.obj").exists());
    let png = std::fs::read(dir.join("part.png")).expect("part.png");
    assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
}

#[test]
fn cli_fit_segments_any_cloud_and_measures_the_step() {
    let sb = Sandbox::new("fit");
    sb.write("s.toml", builtin("mdx50-step.toml").as_bytes());
    sb.write("mdx50-step.ngc", builtin("mdx50-step.ngc").as_bytes());
    let (code, _, stderr) = sb.run(&["run", "s.toml"]);
    assert_eq!(code, 0, "{stderr}");
    // Every planar face, and the distance between the two halves of the stepped face.
    let (code, stdout, stderr) = sb.run(&["fit", "out/mdx50-step/cloud.ply", "--json"]);
    assert_eq!(code, 0, "{stderr}");
    let r: serde_json::Value = serde_json::from_str(&stdout).expect("json");
    let planes = r["planes"].as_array().expect("planes");
    assert!(planes.len() >= 2);
    let step = r["pairs"][0]["distance_mm"]
        .as_f64()
        .expect("two parallel faces");
    assert!((step.abs() - 1.0).abs() < 3e-3, "step {step}");
    // One plane in a box.
    let (code, stdout, _) = sb.run(&[
        "fit",
        "out/mdx50-step/cloud.ply",
        "--plane",
        "--box",
        "-18,-30,1,18,-15,9",
        "--json",
    ]);
    assert_eq!(code, 0);
    let r: serde_json::Value = serde_json::from_str(&stdout).expect("json");
    assert!((r["planes"][0]["offset_mm"].as_f64().expect("offset").abs() - 22.5).abs() < 3e-3);
    // Bad input: a missing file, a truncated file, a bad box.
    for (args, expect) in [
        (vec!["fit", "missing.ply"], "missing.ply"),
        (vec!["fit", "short.ply"], "short.ply"),
        (
            vec!["fit", "out/mdx50-step/cloud.ply", "--box", "1,2,3"],
            "six numbers",
        ),
    ] {
        sb.write("short.ply", b"ply\nformat binary_little_endian 1.0\nelement vertex 10\nproperty double x\nproperty double y\nproperty double z\nend_header\n\x01\x02");
        let (code, _, stderr) = sb.run(&args);
        assert_ne!(code, 0);
        assert!(
            stderr.contains(expect) && !stderr.contains("panicked"),
            "{stderr}"
        );
    }
}

#[test]
fn clouds_written_by_cloudcompare_read_exactly() {
    let expect = [
        [0.0, 0.0, 0.0],
        [1.5, -2.25, 3.125],
        [-10.5, 20.25, 0.0625],
        [100.125, -0.5, 7.75],
        [3.0, 4.0, 5.0],
    ];
    for name in ["cloudcompare-small.ply", "cloudcompare-small-ascii.ply"] {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data")
            .join(name);
        let cloud =
            twinmill::metrology::cloud::read_cloud_file(&path).expect("CloudCompare's PLY reads");
        assert_eq!(cloud.points.len(), 5, "{name}");
        for (p, e) in cloud.points.iter().zip(expect) {
            assert_eq!([p.x, p.y, p.z], e, "{name}");
        }
    }
}

/// Runs a broken variant of the built-in scene and checks the failure is clean.
fn check_bad(name: &str, scene: &str, program: &[u8], expect_in_message: &[&str]) {
    let sb = Sandbox::new(name);
    sb.write("scene.toml", scene.as_bytes());
    sb.write("mdx50-step.ngc", program);
    let (code, stdout, stderr) = sb.run(&["run", "scene.toml"]);
    assert_ne!(code, 0, "{name}: should fail");
    assert!(!stderr.contains("panicked"), "{name}: panicked: {stderr}");
    assert_eq!(
        stderr.trim_end().lines().count(),
        1,
        "{name}: one line expected: {stderr}"
    );
    for e in expect_in_message {
        assert!(stderr.contains(e), "{name}: '{e}' not in: {stderr}");
    }
    assert!(stdout.is_empty(), "{name}: printed {stdout}");
    let out = sb.dir.join("out");
    let leftovers: Vec<_> = std::fs::read_dir(&out)
        .map(|d| d.flatten().map(|e| e.path()).collect())
        .unwrap_or_default();
    assert!(leftovers.is_empty(), "{name}: left {leftovers:?}");
}

#[test]
fn bad_input_fails_cleanly_with_a_located_message() {
    let scene = builtin("mdx50-step.toml");
    let program = builtin("mdx50-step.ngc");
    let line_of = |needle: &str| {
        scene
            .lines()
            .position(|l| l.starts_with(needle))
            .expect("line present")
            + 1
    };

    check_bad(
        "malformed",
        &scene.replace("[tool]", "[tool"),
        program.as_bytes(),
        &["scene.toml:"],
    );
    let l = line_of("dy_AY");
    check_bad(
        "unknown-deviation",
        &scene.replace("dy_AY = -0.50", "dy_AX = -0.50"),
        program.as_bytes(),
        &[&format!("scene.toml:{l}:9:"), "unknown deviation 'dy_AX'"],
    );
    check_bad(
        "non-finite",
        &scene.replace("dy_AY = -0.50", "dy_AY = nan"),
        program.as_bytes(),
        &[&format!("scene.toml:{l}:9:"), "finite"],
    );
    let l = line_of("pitch_mm = 0.1");
    check_bad(
        "non-finite-pitch",
        &scene.replace("pitch_mm = 0.1 ", "pitch_mm = inf "),
        program.as_bytes(),
        &[&format!("scene.toml:{l}:"), "finite"],
    );
    check_bad(
        "pitch-too-fine",
        &scene.replace("pitch_mm = 0.1 ", "pitch_mm = 0.00001 "),
        program.as_bytes(),
        &[
            &format!("scene.toml:{l}:12:"),
            "MiB",
            "use a pitch of at least",
        ],
    );
    check_bad(
        "missing-program",
        &scene.replace("\"mdx50-step.ngc\"", "\"nowhere.ngc\""),
        program.as_bytes(),
        &["nowhere.ngc: cannot read"],
    );
    check_bad(
        "unreadable-program",
        &scene.replace("\"mdx50-step.ngc\"", "\".\""),
        program.as_bytes(),
        &["cannot read"],
    );
    check_bad(
        "non-utf8-program",
        &scene,
        b"G21 G90\nG0 X1 (\xff\xfe)\nM30\n",
        &["mdx50-step.ngc:2:", "UTF-8"],
    );
    check_bad(
        "unsupported-word",
        &scene,
        program
            .replace(
                "G0 Z0\nG1 X30 F600 (cut at A = 0",
                "G0 Z0\nG12 X30 F600 (cut at A = 0",
            )
            .as_bytes(),
        &["mdx50-step.ngc:9:1:", "G12"],
    );
    check_bad(
        "no-such-axis",
        &scene,
        program.replace("G0 A180", "G0 B180").as_bytes(),
        &["mdx50-step.ngc:12:", "no B axis"],
    );
    check_bad(
        "one-face",
        &scene.replace(
            "  { name = \"A180\", line = 14 },   # NC line of the cut at A = 180°\n",
            "",
        ),
        program.as_bytes(),
        &["scene.toml:", "exactly two faces"],
    );
    check_bad(
        "face-not-a-cut",
        &scene.replace("line = 14", "line = 12"),
        program.as_bytes(),
        &["scene.toml", "line 12 is not a feed move"],
    );
    check_bad(
        "rotary-bound-unreachable",
        &scene.replace("rotary_step_bound_mm = 1e-4", "rotary_step_bound_mm = 1e-9"),
        program.as_bytes(),
        &["mdx50-step.ngc:12: meeting", "sub-steps"],
    );
    check_bad(
        "zero-tool",
        &scene.replace("diameter_mm = 6.0", "diameter_mm = 0.0"),
        program.as_bytes(),
        &["scene.toml:", "diameter_mm must be positive"],
    );
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 400, failure_persistence: None, ..ProptestConfig::default() })]
    /// Random edits of a valid scene (deleted, replaced or inserted characters, numbers
    /// swapped for extreme values) give a scene or an error, never a panic.
    #[test]
    fn mutated_scenes_never_panic(
        edits in proptest::collection::vec((0usize..4000, 0u8..4, proptest::sample::select(vec![
            "", "=", "[", "]", "\"", "nan", "-inf", "1e308", "-0", "0", "{", "}", ",", "\n", "é", "A", "dy_Q",
        ])), 1..6)
    ) {
        let mut text = builtin("mdx50-step.toml");
        for (at, kind, piece) in edits {
            let mut at = at % (text.len() + 1);
            while !text.is_char_boundary(at) {
                at -= 1;
            }
            match kind {
                0 => { text.insert_str(at, piece); }
                1 => { let end = text[at..].chars().next().map_or(at, |c| at + c.len_utf8()); text.replace_range(at..end, piece); }
                2 => { let end = text[at..].char_indices().nth(8).map_or(text.len(), |(i, _)| at + i); text.replace_range(at..end, ""); }
                _ => { text.insert_str(at, &format!(" = {piece}")); }
            }
        }
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/mutated.toml");
        if let Ok(scene) = Scene::parse(&text, &path) {
            // A scene that still parses must still be fully valid.
            prop_assert!(scene.pitch_mm > 0.0 && scene.pitch_mm.is_finite());
            prop_assert!(scene.scanner.as_ref().is_none_or(|s| s.validate().is_ok()));
        }
    }
}

// ---------------------------------------------------------------------------------------
// Architecture: folders and the modules in them depend only on what comes before them in
// the pipeline, and docs/architecture.md maps exactly this layout.

/// The library's layout in pipeline order: each top-level module or folder of `src/`, and
/// for a folder its modules in order. A module may use only modules of earlier folders and
/// earlier modules of its own folder (a folder's `mod.rs` is its shared vocabulary).
const LAYOUT: &[(&str, &[&str])] = &[
    ("math", &[]),
    ("progress", &[]),
    (
        "nc",
        &[
            "source",
            "lex",
            "tooltable",
            "output",
            "comp",
            "interp",
            "synthetic",
        ],
    ),
    ("machine", &["chain"]),
    (
        "cutting",
        &[
            "tool", "shape", "stock", "cutter", "envelope", "sweep", "collide", "mesh", "zmap",
        ],
    ),
    ("metrology", &["cloud", "scan", "fit", "segment"]),
    (
        "calibration",
        &["identify", "calibrate", "design", "correct"],
    ),
    (
        "report",
        &[
            "render",
            "deviation_map",
            "simulate",
            "scan",
            "run",
            "fit",
            "correct",
            "identify",
            "design",
        ],
    ),
    ("scene", &[]),
    (
        "pipeline",
        &["simulate", "run", "fit", "correct", "identify"],
    ),
    ("output", &[]),
];

/// Every `.rs` file at or below `path` (a file or a folder), sorted.
fn rust_files(path: &Path) -> Vec<PathBuf> {
    if path.is_file() {
        return vec![path.to_path_buf()];
    }
    let mut out = Vec::new();
    let mut entries: Vec<PathBuf> = std::fs::read_dir(path)
        .map(|d| d.flatten().map(|e| e.path()).collect())
        .unwrap_or_default();
    entries.sort();
    for e in entries {
        if e.is_dir() {
            out.extend(rust_files(&e));
        } else if e.extension().is_some_and(|x| x == "rs") {
            out.push(e);
        }
    }
    out
}

/// The source of a module (a file, or a folder of files) without its comment lines.
fn module_code(path: &Path) -> String {
    rust_files(path)
        .iter()
        .map(|p| std::fs::read_to_string(p).expect("source"))
        .collect::<Vec<_>>()
        .join("\n")
        .lines()
        .filter(|l| !l.trim_start().starts_with("//"))
        .collect::<Vec<_>>()
        .join("\n")
}

/// The names that follow each occurrence of `prefix` in `code` (`crate::a::b` → ["a", "b"]).
fn paths_after(code: &str, prefix: &str) -> Vec<Vec<String>> {
    code.match_indices(prefix)
        .filter(|(i, _)| {
            // `crate::` itself, not the tail of a longer identifier.
            code[..*i]
                .chars()
                .next_back()
                .is_none_or(|c| !(c.is_ascii_alphanumeric() || c == '_'))
        })
        .map(|(i, _)| {
            code[i + prefix.len()..]
                .split("::")
                .map(|seg| {
                    seg.chars()
                        .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                        .collect::<String>()
                })
                .take_while(|seg| !seg.is_empty())
                .take(2)
                .collect()
        })
        .collect()
}

/// The place of a module in the layout: (folder rank, rank within the folder).
fn place(folder: &str, module: Option<&str>) -> Option<(usize, Option<usize>)> {
    let f = LAYOUT.iter().position(|(name, _)| *name == folder)?;
    match module {
        None => Some((f, None)),
        Some(m) => Some((f, Some(LAYOUT[f].1.iter().position(|x| *x == m)?))),
    }
}

#[test]
fn module_dependencies_point_down_the_pipeline() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    // Every file and folder of src/ is in the layout, and every module of a folder too.
    let mut found: Vec<String> = std::fs::read_dir(&src)
        .expect("src")
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.is_dir() || p.extension().is_some_and(|x| x == "rs"))
        .map(|p| {
            p.file_stem()
                .and_then(|s| s.to_str())
                .unwrap_or("")
                .to_string()
        })
        .filter(|s| s != "lib" && s != "main")
        .collect();
    found.sort();
    let mut listed: Vec<String> = LAYOUT.iter().map(|(n, _)| n.to_string()).collect();
    listed.sort();
    assert_eq!(found, listed, "src/ against the layout");
    let mut checked = 0;
    for (folder, modules) in LAYOUT {
        let dir = src.join(folder);
        // (module name or None for a top-level file or a folder's mod.rs, its path)
        let mut units: Vec<(Option<&str>, PathBuf)> = Vec::new();
        if dir.is_dir() {
            let mut inside: Vec<String> = std::fs::read_dir(&dir)
                .expect("folder")
                .flatten()
                .map(|e| e.path())
                .filter(|p| p.is_dir() || p.extension().is_some_and(|x| x == "rs"))
                .map(|p| {
                    p.file_stem()
                        .and_then(|s| s.to_str())
                        .unwrap_or("")
                        .to_string()
                })
                .filter(|s| s != "mod" && s != "tests")
                .collect();
            inside.sort();
            inside.dedup();
            let mut expected: Vec<String> = modules.iter().map(|m| m.to_string()).collect();
            expected.sort();
            assert_eq!(
                inside, expected,
                "modules of src/{folder}/ against the layout"
            );
            let head = std::fs::read_to_string(dir.join("mod.rs")).expect("mod.rs");
            assert!(
                head.starts_with("//! **"),
                "src/{folder}/mod.rs must open with a paragraph on what the folder owns and may use"
            );
            units.push((None, dir.join("mod.rs")));
            for m in *modules {
                let file = dir.join(format!("{m}.rs"));
                let sub = dir.join(m);
                if file.is_file() {
                    units.push((Some(m), file));
                }
                if sub.is_dir() {
                    units.push((Some(m), sub));
                }
            }
        } else {
            units.push((None, src.join(format!("{folder}.rs"))));
        }
        for (module, path) in units {
            let name = match module {
                Some(m) => format!("{folder}::{m}"),
                None => folder.to_string(),
            };
            let (rank, inner) = place(folder, module).expect("placed");
            let code = module_code(&path);
            for used in paths_after(&code, "crate::") {
                let Some(top) = used.first() else { continue };
                let Some((r, _)) = place(top, None) else {
                    continue;
                };
                assert!(
                    r <= rank,
                    "{name} uses crate::{top}, a later stage: dependencies must point down the pipeline"
                );
                // Within its own folder, a module uses only the modules before it.
                if r == rank
                    && let (Some(me), Some(other)) = (inner, used.get(1))
                    && let Some((_, Some(o))) = place(top, Some(other))
                {
                    assert!(
                        o <= me,
                        "{name} uses crate::{top}::{other}, a later module of its folder"
                    );
                }
            }
            // The same through `super::` from a folder's module to its siblings.
            if let Some(me) = inner {
                for used in paths_after(&code, "super::") {
                    if let Some((_, Some(o))) = used.first().and_then(|s| place(folder, Some(s))) {
                        assert!(
                            o <= me,
                            "{name} uses super::{}, a later module of its folder",
                            used[0]
                        );
                    }
                }
            }
            // The library never prints.
            for bad in ["println!", "eprintln!", "print!(", "dbg!("] {
                assert!(!code.contains(bad), "{name} contains {bad}");
            }
            checked += 1;
        }
    }
    assert!(checked >= 30, "only {checked} modules checked");

    // docs/architecture.md names every folder and module, in this order, as bold code.
    let doc =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/architecture.md"))
            .expect("docs/architecture.md");
    let named: Vec<String> = doc
        .match_indices("**`")
        .filter_map(|(i, _)| {
            let rest = &doc[i + 3..];
            let end = rest.find("`**")?;
            let n = &rest[..end];
            n.chars()
                .all(|c| c.is_ascii_lowercase() || c == '_' || c == '/')
                .then(|| n.to_string())
        })
        .collect();
    let mut expected = Vec::new();
    for (folder, modules) in LAYOUT {
        if src.join(folder).is_dir() {
            expected.push(format!("{folder}/"));
            expected.extend(modules.iter().map(|m| m.to_string()));
        } else {
            expected.push(folder.to_string());
        }
    }
    assert_eq!(
        named, expected,
        "docs/architecture.md must name every folder and module of src/, in pipeline order, as **`name`** (folders as **`name/`**)"
    );
}

// ---------------------------------------------------------------------------------------
// NC correction: the corrected program, simulated on the deviated machine, cuts the
// nominal faces. Measured here from the dexel crossings against the nominal face of the
// independent 4 × 4 derivation, not with the correction module's own measurement.

/// Sweeps `moves` on the scene's (deviated) machine and returns, per face (A0 upper half,
/// A180 lower half), the signed distances of the face's crossings from the nominal face
/// Y_W = −22 (from `exact_face` with zero deviations), positive into the material.
fn face_distances(s: &Scene, moves: &[Move]) -> [Vec<Real>; 2] {
    let mut stock = TriDexel::new_box(s.stock_box, s.pitch_mm, 4e9).expect("fits");
    let opts = SweepOptions {
        rotary_step_bound_mm: 1e-5,
    };
    sweep_program(&mut stock, &s.chain, &s.tool, moves, &opts, &NoProgress).expect("sweeps");
    let zero = [[0.0; 6]; 4];
    let (n, d) = exact_face(&zero, -25.0, 0.0, s.tool.radius());
    let mut out = [Vec::new(), Vec::new()];
    for (k, (z0, z1)) in [(1.5, 8.5), (-8.5, -1.5)].into_iter().enumerate() {
        for g in stock.grids() {
            g.for_each_crossing(|p, c| {
                if p.x.abs() <= 18.0
                    && p.z >= z0
                    && p.z <= z1
                    && (p.y + 22.0).abs() <= 1.8
                    && c.normal().y < -0.9
                {
                    // n points to +Y (into the material); d is the face's offset.
                    out[k].push(n.dot(&p.coords) - d);
                }
            });
        }
    }
    out
}

fn mean(v: &[Real]) -> Real {
    v.iter().sum::<Real>() / v.len() as Real
}

fn max_abs(v: &[Real]) -> Real {
    v.iter().fold(0.0, |m, x| m.max(x.abs()))
}

#[test]
fn corrected_program_leaves_no_step_on_the_paper_scene() {
    let s = scene();
    let program = s.load_program().expect("parses");
    // Sanity of the measurement: the program as given leaves the paper's 1 mm step.
    let [a0, a180] = face_distances(&s, &program.moves);
    let step = mean(&a180) - mean(&a0);
    assert!((step.abs() - 1.0).abs() < 1e-6, "uncorrected step {step}");

    let out =
        twinmill::pipeline::correct(&s, &program, &s.chain, 1e-3, &NoProgress).expect("corrects");
    assert!(out.report.met, "{}", out.report.status);
    let [a0, a180] = face_distances(&s, &out.corrected.moves);
    assert!(a0.len() > 5000 && a180.len() > 5000);
    let step = mean(&a180) - mean(&a0);
    assert!(step.abs() < 1e-3, "corrected step {step} mm");
    assert!(max_abs(&a0) < 1e-3 && max_abs(&a180) < 1e-3);
    // In fact at the G-code's resolution.
    assert!(step.abs() < 1e-5, "corrected step {step} mm");

    // The emitted program is the simulated one: read back, it gives the same moves.
    let mut text = Vec::new();
    twinmill::calibration::correct::write_gcode(&out.corrected, &out.header, &mut text)
        .expect("writes");
    let text = String::from_utf8(text).expect("utf-8");
    assert!(text.contains("G21 G90 G94") && text.contains("(src line 9)"));
    assert!(text.contains("(src line 14)") && text.contains("F600"));
    // The minimal reader has no G94 (the default mode it assumes): drop the word.
    let parsed = twinmill::nc::parse_program(
        &text.replace(" G94", ""),
        Path::new("corrected.ngc"),
        s.home,
    )
    .expect("the corrected program parses");
    assert_eq!(parsed.moves.len(), out.corrected.moves.len());
    for (a, b) in parsed.moves.iter().zip(&out.corrected.moves) {
        assert_eq!((a.kind, a.start, a.end), (b.kind, b.start, b.end));
        assert_eq!(a.feed_mm_per_min, b.feed_mm_per_min);
    }
}

/// The nine deviations of seed 002 Fig. 3, with the size each is set to.
const NINE_SIZED: [(&str, Real); 9] = [
    ("dy_AY", 0.5),
    ("dz_AY", 0.5),
    ("beta_AY", 5e-4),
    ("gamma_AY", 5e-4),
    ("alpha_YX", 5e-4),
    ("gamma_YX", 5e-4),
    ("beta_XZ", 5e-4),
    ("alpha_ZS", 5e-4),
    ("beta_ZS", 5e-4),
];

#[test]
fn mixed_deviation_sets_are_corrected_to_within_1_um_on_the_faces() {
    let rng = twinmill::math::CounterRng::new(2002);
    let program = scene().load_program().expect("parses");
    for set in 0..12u64 {
        let mut s = scene();
        set_deviation(&mut s, "dy_AY", 0.0);
        let mut beta = 0.0;
        let mut any = false;
        for (k, (name, size)) in NINE_SIZED.iter().enumerate() {
            // Each deviation in two sets of three, with a random sign; the last set all.
            if set == 11 || rng.uniform(set, k as u64) < 2.0 / 3.0 {
                let sign = if rng.uniform(set, 100 + k as u64) < 0.5 {
                    -1.0
                } else {
                    1.0
                };
                set_deviation(&mut s, name, sign * size);
                any = true;
                if name.starts_with("beta") {
                    beta += sign * size;
                }
            }
        }
        assert!(any);
        let out = twinmill::pipeline::correct(&s, &program, &s.chain, 1e-3, &NoProgress)
            .expect("corrects");
        let [a0, a180] = face_distances(&s, &out.corrected.moves);
        assert!(a0.len() > 5000 && a180.len() > 5000, "set {set}");
        let (m0, m1) = (max_abs(&a0), max_abs(&a180));
        assert!(
            m0 < 1e-3 && m1 < 1e-3,
            "set {set} {:?}: faces off by {m0} and {m1} mm",
            s.injected
        );
        // And every cut surface of the part, against the program as given on the nominal
        // machine, ray by ray: no floor or other surface shows the uncorrectable tilt.
        let last = out.report.iterations.last().expect("a pass");
        assert!(
            last.part.crossings > 50_000 && last.part.unmatched_rays == 0,
            "set {set}"
        );
        assert!(last.part.max_mm < 1e-3, "set {set}: part {:?}", last.part);
        // What four axes cannot correct: the tool's tilt about Y, the beta sum. The best
        // line through the tilted axis crosses the nominal one mid-flute: RMS |β|·L/√12.
        let expect = beta.abs() * s.tool.length() / 12.0_f64.sqrt();
        let got = out.report.correction.residual_rms_mm;
        assert!(
            // Second-order products of the angles (2.5e-7 rad) add up to 2e-6 mm.
            (got - expect).abs() <= 0.01 * expect + 1e-5,
            "set {set}: residual {got} vs {expect}"
        );
        // It tilts the tool in the plane of the cut direction (X) and the tool axis: the
        // flank, parallel to both, does not move — hence the faces above are exact anyway.
        // With a beta sum the tool's ends stay |β|·L/2 ≥ 6 µm off the nominal path: the
        // report says the accuracy is met on the faces, not on the path.
        let no_tilt = beta.abs() < 1e-12;
        assert_eq!(out.report.met, no_tilt, "set {set}: {}", out.report.status);
        assert!(
            out.report
                .status
                .contains(if no_tilt { "met in" } else { "faces within" })
        );
    }
}

#[test]
fn correcting_for_identified_deviations_closes_the_loop() {
    // Seed 002 Fig. 1: scan the part, identify, correct for what was identified, and cut
    // again on the (unchanged) machine. The scanner's noise leaves dy_AY a fraction of a µm
    // off, and the step after correction is that error twice.
    let s = scene();
    let program = s.load_program().expect("parses");
    let run_out = run(&s, &program, &NoProgress).expect("runs");
    let model = twinmill::pipeline::identified_model(&s, &run_out.report).expect("identified");
    let dy = model.deviation(model.deviation_id("dy_AY").expect("known"));
    assert_eq!(dy, run_out.report.identified["dy_AY"]);
    let out =
        twinmill::pipeline::correct(&s, &program, &model, 1e-3, &NoProgress).expect("corrects");
    let [a0, a180] = face_distances(&s, &out.corrected.moves);
    let step = mean(&a180) - mean(&a0);
    let expect = 2.0 * (dy + 0.5);
    assert!(
        (step.abs() - expect.abs()).abs() < 1e-5,
        "step {step} vs {expect}"
    );
    assert!(
        step.abs() < 1e-3,
        "step {step} mm after correcting for dy_AY = {dy}"
    );
}

#[test]
fn correct_rejects_bad_accuracy_and_unreachable_poses() {
    let s = scene();
    let program = s.load_program().expect("parses");
    for acc in [0.0, -1.0, Real::NAN, Real::INFINITY] {
        let e = twinmill::pipeline::correct(&s, &program, &s.chain, acc, &NoProgress)
            .expect_err("bad accuracy");
        assert!(e.to_string().contains("accuracy"), "{e}");
    }
    let mut far = s.chain.clone();
    far.set_deviation(far.deviation_id("dz_AY").expect("known"), 50.0);
    let e = twinmill::pipeline::correct(&s, &program, &far, 1e-3, &NoProgress)
        .expect_err("unreachable");
    assert!(e.to_string().contains("not reachable"), "{e}");
    assert!(e.to_string().contains("mdx50-step.ngc:"), "{e}");
}

#[test]
fn cli_correct_writes_program_and_report_or_nothing() {
    let sb = Sandbox::new("correct");
    sb.write("s.toml", builtin("mdx50-step.toml").as_bytes());
    sb.write("mdx50-step.ngc", builtin("mdx50-step.ngc").as_bytes());
    let (code, stdout, stderr) = sb.run(&["correct", "s.toml", "--out", "c", "--json"]);
    assert_eq!(code, 0, "{stderr}");
    let report: serde_json::Value = serde_json::from_str(&stdout).expect("json");
    assert_eq!(report["met"], serde_json::Value::Bool(true));
    let its = report["iterations"].as_array().expect("iterations");
    assert!(its.len() >= 2);
    assert!(
        its[0]["faces"]["step_mm"]
            .as_f64()
            .is_some_and(|x| (x.abs() - 1.0).abs() < 1e-6)
    );
    let ngc = std::fs::read_to_string(sb.dir.join("c/mdx50-step-corrected.ngc")).expect("ngc");
    assert!(
        ngc.starts_with("%\n(")
            && ngc.contains("Y-24.500000")
            && ngc.trim_end().ends_with("M30\n%")
    );
    assert!(sb.dir.join("c/mdx50-step-correct.json").exists());
    // Bad input: a clear one-line error, no files.
    for (args, words) in [
        (
            vec!["correct", "s.toml", "--out", "bad", "--accuracy-mm", "0"],
            "accuracy",
        ),
        (
            vec!["correct", "s.toml", "--out", "bad", "--accuracy-mm", "-1"],
            "accuracy",
        ),
        (
            vec!["correct", "s.toml", "--out", "bad", "--accuracy-mm", "nan"],
            "accuracy",
        ),
    ] {
        let (code, _, stderr) = sb.run(&args);
        assert_ne!(code, 0);
        assert!(
            stderr.contains(words) && !stderr.contains("panicked"),
            "{stderr}"
        );
        assert_eq!(stderr.trim_end().lines().count(), 1, "{stderr}");
    }
    // The nine deviations: faces met, the path not (the beta tilt): exit code 2, files
    // written, the reason on stderr.
    let mut nine = builtin("mdx50-step.toml");
    for (name, size) in NINE_SIZED.iter().skip(1) {
        nine = nine.replace("dy_AY = -0.50", &format!("dy_AY = -0.50\n{name} = {size}"));
    }
    sb.write("nine.toml", nine.as_bytes());
    let (code, stdout, stderr) = sb.run(&["correct", "nine.toml", "--out", "nine"]);
    assert_eq!(code, 2, "{stdout}{stderr}");
    assert!(
        stderr.contains("not met") && stderr.contains("cannot correct"),
        "{stderr}"
    );
    assert!(stdout.contains("beta_ZS") && sb.dir.join("nine/mdx50-step-corrected.ngc").exists());
    sb.write(
        "far.toml",
        builtin("mdx50-step.toml")
            .replace("dy_AY = -0.50", "dy_AY = -40.0")
            .as_bytes(),
    );
    let (code, _, stderr) = sb.run(&["correct", "far.toml", "--out", "bad"]);
    assert_ne!(code, 0);
    assert!(
        stderr.contains("not reachable") && !stderr.contains("panicked"),
        "{stderr}"
    );
    assert!(
        !sb.dir.join("bad").exists()
            || std::fs::read_dir(sb.dir.join("bad"))
                .expect("dir")
                .next()
                .is_none()
    );
}

// ---------------------------------------------------------------------------------------
// General identification: designed cuts, round trip, CLI.

/// The designed test for the nine deviations on the MDX-50 scene, as a scene with coarse
/// CI settings: tri-dexel 0.2 mm, scanner pitch 0.3 mm, range noise 0.007 mm. (At 0.01 mm
/// the real scans determine the Z-squareness and spindle-tilt pairs in only 84 of 100
/// trials. With the noise nearly off, `dz_AY` still comes back 20–70 nm off: a model bias,
/// cause not yet found, that at 0.005 mm would exceed its 3σ more often.)
fn designed_scene(tag: &str) -> Scene {
    use twinmill::calibration::design::{DesignOptions, design};
    let base = scene();
    let ids: Vec<_> = NINE
        .iter()
        .map(|n| base.model.deviation_id(n).expect("known"))
        .collect();
    let mut opts = DesignOptions::standard();
    opts.noise_sigma_mm = 0.007;
    opts.pitch_mm = 0.3;
    let d = design(&base.model, &base.tool, &ids, &opts).expect("a design");
    let params: Vec<String> = NINE.iter().map(|s| s.to_string()).collect();
    let mut s = base.clone();
    s.pitch_mm = 0.2;
    scanner(&mut s).noise_sigma_mm = 0.007;
    scanner(&mut s).pitch_mm = 0.3;
    let toml =
        twinmill::scene::design_scene_toml(&s, &d, &opts, &params, "designed", "designed.ngc")
            .expect("the scene has a [scanner]");
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("designed-{tag}"));
    std::fs::create_dir_all(&dir).expect("temp dir");
    std::fs::write(dir.join("designed.ngc"), &d.program).expect("write program");
    let path = dir.join("designed.toml");
    std::fs::write(&path, &toml).expect("write scene");
    Scene::load(&path).expect("the designed scene loads")
}

#[test]
fn designed_cuts_round_trip_over_100_seeded_trials() {
    use twinmill::pipeline::identify_scene;
    let base = designed_scene("round-trip");
    let program = base.load_program().expect("parses");
    let mut state: u64 = 0x600d;
    let mut next = || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((state >> 11) as Real / (1u64 << 53) as Real) * 2.0 - 1.0
    };
    let trials = 100;
    // Per deviation: trials in which it was valued within 3σ of the injected value. A
    // trial in which it was not valued (or the identification failed) is a failure: the
    // design determines all nine.
    let mut ok = [0usize; 9];
    let mut failed = Vec::new();
    for t in 0..trials {
        let mut s = base.clone();
        scanner(&mut s).seed = 1000 + t as u64;
        for (k, name) in NINE.iter().enumerate() {
            // Offsets within ±0.5 mm, angles within ±5e-4 rad.
            let v = next() * if k < 2 { 0.5 } else { 5e-4 };
            set_deviation(&mut s, name, v);
        }
        let out = match identify_scene(&s, &program, None, Some(0), &NoProgress) {
            Ok(o) => o,
            Err(e) => {
                failed.push(format!("trial {t}: {e}"));
                continue;
            }
        };
        let r = &out.report;
        // What is not determined is named, and never valued.
        let valued: Vec<&str> = r
            .identified
            .iter()
            .chain(&r.combinations)
            .map(|e| e.name.as_str())
            .collect();
        for n in &r.not_determined {
            assert!(
                !valued.contains(&n.as_str()),
                "{n} is both undetermined and valued"
            );
        }
        for n in &r.not_identified {
            assert!(
                !r.identified.iter().any(|e| &e.name == n),
                "{n} is not identified but has a value"
            );
        }
        for (k, name) in NINE.iter().enumerate() {
            match r.identified.iter().find(|e| e.name == *name) {
                Some(e) => {
                    let truth = e.injected.expect("simulated");
                    if (e.value - truth).abs() <= 3.0 * e.sigma {
                        ok[k] += 1;
                    } else {
                        failed.push(format!(
                            "trial {t}: {name} = {:.3e} ± {:.1e}, injected {truth:.3e}",
                            e.value, e.sigma
                        ));
                    }
                }
                None => failed.push(format!("trial {t}: {name} not valued")),
            }
        }
    }
    for (k, name) in NINE.iter().enumerate() {
        assert!(
            ok[k] * 100 >= 95 * trials,
            "{name}: within 3σ in only {} of {trials} trials; failures: {failed:#?}",
            ok[k]
        );
    }
}

/// The built-in step scene with an [identify] section asking for `params`.
fn identify_scene_text(params: &[&str], extra_deviations: &str) -> String {
    let list: Vec<String> = params.iter().map(|p| format!("\"{p}\"")).collect();
    builtin("mdx50-step.toml")
        .replace(
            "known = {}",
            &format!("known = {{}}\nparameters = [{}]", list.join(", ")),
        )
        .replace(
            "dy_AY = -0.50",
            &format!("dy_AY = -0.50\n{extra_deviations}"),
        )
}

fn files_in(dir: &Path) -> Vec<PathBuf> {
    std::fs::read_dir(dir)
        .map(|d| d.flatten().map(|e| e.path()).collect())
        .unwrap_or_default()
}

#[test]
fn cli_identify_values_what_is_determined_and_names_the_rest() {
    let sb = Sandbox::new("identify");
    sb.write(
        "s.toml",
        identify_scene_text(&["dy_AY", "gamma_AY", "gamma_YX"], "").as_bytes(),
    );
    sb.write("mdx50-step.ngc", builtin("mdx50-step.ngc").as_bytes());
    let (code, stdout, stderr) = sb.run(&["identify", "s.toml", "--out", "o", "--json"]);
    assert_eq!(code, 0, "{stderr}");
    let r: serde_json::Value = serde_json::from_str(&stdout).expect("--json prints the report");
    // Seed 002 eq. (6)(7): the 0/180 cut gives dy_AY and gamma_AY + gamma_YX only.
    let ids = r["identified"].as_array().expect("identified");
    assert_eq!(ids.len(), 1, "{ids:?}");
    assert_eq!(ids[0]["name"], "dy_AY");
    let (v, s) = (
        ids[0]["value"].as_f64().expect("value"),
        ids[0]["sigma"].as_f64().expect("sigma"),
    );
    assert!((v + 0.5).abs() <= 3.0 * s + 1e-4, "dy_AY = {v} ± {s}");
    let combos = r["combinations"].as_array().expect("combinations");
    assert!(combos.iter().any(|c| c["name"] == "gamma_AY + gamma_YX"));
    let undetermined: Vec<&str> = r["not_determined"]
        .as_array()
        .expect("named")
        .iter()
        .filter_map(|c| c.as_str())
        .collect();
    assert_eq!(undetermined.len(), 1, "{undetermined:?}");
    assert!(undetermined[0].contains("gamma_AY") && undetermined[0].contains("gamma_YX"));
    assert_eq!(r["singular_values"].as_array().map(Vec::len), Some(3));
    assert_eq!(r["converged"], serde_json::Value::Bool(true));
    assert!(r["rounds"].as_array().is_some_and(|x| !x.is_empty()));
    let dir = sb.dir.join("o/mdx50-step-identify");
    assert!(dir.join("identify.json").exists() && dir.join("cloud.ply").exists());

    // A parameter no face depends on is reported as such, the others still identified.
    sb.write(
        "nodata.toml",
        identify_scene_text(&["dy_AY", "dx_ZS"], "").as_bytes(),
    );
    let (code, stdout, stderr) = sb.run(&["identify", "nodata.toml", "--out", "n", "--json"]);
    assert_eq!(code, 0, "{stderr}");
    let r: serde_json::Value = serde_json::from_str(&stdout).expect("json");
    assert_eq!(r["no_data"][0], "dx_ZS");
    assert!(
        !r["identified"]
            .as_array()
            .expect("list")
            .iter()
            .any(|e| e["name"] == "dx_ZS")
    );
}

// ---------------------------------------------------------------------------------------
// Mesh text shared by the solid, fixture and design tests.

fn aabb(min: [Real; 3], max: [Real; 3]) -> Aabb {
    Aabb {
        min: Point3::from(min),
        max: Point3::from(max),
    }
}

/// OBJ text of a mesh given as vertices and 0-based triangles.
fn obj(vertices: &[[Real; 3]], triangles: &[[usize; 3]]) -> String {
    let mut s = String::new();
    for v in vertices {
        s.push_str(&format!("v {:?} {:?} {:?}\n", v[0], v[1], v[2]));
    }
    for t in triangles {
        s.push_str(&format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1));
    }
    s
}

/// A prism over the counter-clockwise polygon `poly` (x, y) from z0 to z1, caps
/// triangulated by `cap` (0-based triangles of the polygon, counter-clockwise).
fn prism(poly: &[[Real; 2]], cap: &[[usize; 3]], z0: Real, z1: Real) -> String {
    let n = poly.len();
    let mut v: Vec<[Real; 3]> = poly.iter().map(|p| [p[0], p[1], z0]).collect();
    v.extend(poly.iter().map(|p| [p[0], p[1], z1]));
    let mut t = Vec::new();
    for c in cap {
        t.push([c[0], c[2], c[1]]);
        t.push([c[0] + n, c[1] + n, c[2] + n]);
    }
    for i in 0..n {
        let j = (i + 1) % n;
        t.push([i, j, j + n]);
        t.push([i, j + n, i + n]);
    }
    obj(&v, &t)
}

fn fan(n: usize) -> Vec<[usize; 3]> {
    (1..n - 1).map(|k| [0, k, k + 1]).collect()
}

// ---------------------------------------------------------------------------------------
// Tool shapes through the sweep: the closed-form flat/ball sweep and the piecewise cutter
// agree, and a whole program swept with a bull-nose through a machine chain removes the
// analytic slot volume.

mod tool_shapes {
    use super::*;
    use twinmill::cutting::cutter::SweptTool;
    use twinmill::cutting::stock::{Cutter, TriDexel};
    use twinmill::cutting::sweep::{SweepOptions, TranslatedTool, sweep_program};
    use twinmill::cutting::tool::{Tool, ToolKind};
    use twinmill::machine::chain::{Axis, AxisKind, Chain};
    use twinmill::math::{CounterRng, UnitVector3};
    use twinmill::nc::{AxisLetter, AxisValues, Move, MoveKind};
    use twinmill::progress::NoProgress;
    /// The sweep module's closed form (flat, ball) and the cutter's piecewise closed form
    /// agree to rounding on random moves and axis rays, with the tool at least 2R long (the
    /// sweep module's ball is a whole sphere).
    #[test]
    fn flat_and_ball_closed_forms_agree_with_the_piecewise_cutter() {
        let rng = CounterRng::new(5);
        let mut k = 0u64;
        let mut next = || {
            k += 1;
            rng.uniform(k, 0) * 2.0 - 1.0
        };
        let mut compared = 0;
        for case in 0..200 {
            let kind = if case % 2 == 0 {
                ToolKind::Flat
            } else {
                ToolKind::Ball
            };
            let tool = Tool::try_new(kind, 4.0, 8.0).expect("valid");
            let v = UnitVector3::new_normalize(Vector3::new(next() * 0.6, next() * 0.6, 1.0));
            let start = Point3::new(next() * 3.0, next() * 3.0, next() * 3.0);
            let d = Vector3::new(next() * 8.0, next() * 8.0, next() * 4.0);
            let a = TranslatedTool::new(tool.clone(), start, d, v);
            let b = SweptTool::new(&tool, start, d, v);
            for _ in 0..50 {
                let axis = ((next() + 1.0) * 1.5) as usize % 3;
                let o = Point3::new(next() * 8.0, next() * 8.0, next() * 8.0);
                match (a.ray_cut(&o, axis), b.ray_cut(&o, axis)) {
                    (Some(p), Some(q)) => {
                        assert!(
                            (p.t_in - q.t_in).abs() < 1e-9 && (p.t_out - q.t_out).abs() < 1e-9,
                            "{p:?} vs {q:?}"
                        );
                        compared += 1;
                    }
                    (None, None) => {}
                    // A grazing ray: one side may see a sliver the other does not.
                    (p, q) => {
                        let len = |c: Option<twinmill::cutting::stock::RayCut>| {
                            c.map_or(0.0, |c| c.t_out - c.t_in)
                        };
                        assert!(len(p).max(len(q)) < 1e-6, "{p:?} vs {q:?}");
                    }
                }
            }
        }
        assert!(compared > 1000, "only {compared} rays hit");
    }

    fn xyz_chain() -> Chain {
        let lin = |letter, dir: Vector3| Axis {
            letter,
            kind: AxisKind::Linear,
            direction: UnitVector3::new_normalize(dir),
            origin: Point3::origin(),
        };
        Chain::new(
            vec![
                lin(AxisLetter::X, Vector3::x()),
                lin(AxisLetter::Y, Vector3::y()),
                lin(AxisLetter::Z, Vector3::z()),
            ],
            "S",
        )
        .expect("valid chain")
    }

    fn at(x: Real, y: Real, z: Real) -> AxisValues {
        AxisValues::from_array([x, y, z, 0.0, 0.0, 0.0])
    }

    fn mv(start: AxisValues, end: AxisValues, line: usize) -> Move {
        Move {
            kind: MoveKind::Linear,
            start,
            end,
            feed_mm_per_min: Some(500.0),
            line,
        }
    }

    /// A bull-nose slot swept through the machine chain: plunge (straight down, inside the
    /// slot's start), slot along x, retract. Removed volume = vol(K ∩ H) + ℓ·area(K ∩ H along x),
    /// the plunge and retract adding nothing outside the slot's own volume.
    #[test]
    fn bull_nose_program_removes_the_analytic_slot() {
        let (r, rc, depth, len): (Real, Real, Real, Real) = (3.0, 1.0, 4.0, 10.0);
        let tool = Tool::try_bull_nose(2.0 * r, rc, 20.0).expect("valid");
        let mut stock = TriDexel::new_box(
            Aabb {
                min: Point3::new(0.0, -6.0, 0.0),
                max: Point3::new(20.0, 6.0, 10.0),
            },
            0.1,
            1e9,
        )
        .expect("fits");
        let before = stock.volume();
        let z = 10.0 - depth;
        let moves = [
            mv(at(5.0, 0.0, 15.0), at(5.0, 0.0, z), 1),
            mv(at(5.0, 0.0, z), at(5.0 + len, 0.0, z), 2),
            mv(at(5.0 + len, 0.0, z), at(5.0 + len, 0.0, 15.0), 3),
        ];
        let report = sweep_program(
            &mut stock,
            &xyz_chain(),
            &tool,
            &moves,
            &SweepOptions {
                rotary_step_bound_mm: 1e-4,
            },
            &NoProgress,
        )
        .expect("sweeps");
        assert_eq!(report.moves, 3);
        let a = r - rc;
        let pi = std::f64::consts::PI;
        let area = 2.0 * (a * rc + pi * rc * rc / 4.0 + r * (depth - rc));
        let vol = pi
            * (a * a * rc + pi * a * rc * rc / 2.0 + 2.0 * rc.powi(3) / 3.0 + r * r * (depth - rc));
        let want = vol + len * area;
        let got = before - stock.volume();
        assert!(((got - want) / want).abs() < 1e-3, "got {got}, want {want}");
    }

    /// A rotary move with a tapered ball: the sub-step bound uses the tool's largest radius
    /// and length, and the sweep meets the requested bound.
    #[test]
    fn rotary_move_with_a_tapered_tool_meets_its_bound() {
        let chain = Chain::new(
            vec![
                Axis {
                    letter: AxisLetter::A,
                    kind: AxisKind::Rotary,
                    direction: Vector3::x_axis(),
                    origin: Point3::origin(),
                },
                Axis {
                    letter: AxisLetter::Z,
                    kind: AxisKind::Linear,
                    direction: Vector3::z_axis(),
                    origin: Point3::origin(),
                },
            ],
            "S",
        )
        .expect("valid chain");
        let tool = Tool::try_tapered_ball(2.0, 5.0, 15.0).expect("valid");
        let mut stock = TriDexel::new_box(
            Aabb {
                min: Point3::new(-5.0, -12.0, -12.0),
                max: Point3::new(5.0, 12.0, 12.0),
            },
            0.5,
            1e9,
        )
        .expect("fits");
        let start = AxisValues::from_array([0.0, 0.0, 9.0, 0.0, 0.0, 0.0]);
        let moves = [mv(start, start.with(AxisLetter::A, 30.0), 1)];
        let bound = 1e-3;
        let report = sweep_program(
            &mut stock,
            &chain,
            &tool,
            &moves,
            &SweepOptions {
                rotary_step_bound_mm: bound,
            },
            &NoProgress,
        )
        .expect("sweeps");
        assert_eq!(report.rotary_moves, 1);
        assert!(report.rotary_error_bound_mm <= bound && report.rotary_error_bound_mm > 0.0);
        assert_eq!(report.cutting_moves, 1);
    }

    /// Regression: a ball end mill shorter than its diameter is not a whole sphere above the
    /// tip; a ray above the flutes' top must see nothing.
    #[test]
    fn short_ball_tool_ends_at_its_length() {
        let tool = Tool::try_new(ToolKind::Ball, 6.0, 4.0).expect("valid");
        let t = TranslatedTool::new(tool, Point3::origin(), Vector3::x(), Vector3::z_axis());
        // z = 5 lies inside the whole sphere about (0, 0, 3) but above the tool's 4 mm length.
        assert!(t.ray_cut(&Point3::new(0.5, 0.0, 5.0), 1).is_none());
        let c = t.ray_cut(&Point3::new(0.5, 0.0, 0.0), 2).expect("cuts");
        assert!((c.t_out - 4.0).abs() < 1e-12, "{c:?}");
    }
}

// ---------------------------------------------------------------------------------------
// Stock from solids (cylinder, closed meshes), collision events and the deviation map,
// through the library.

mod solids_collisions_deviation {
    use super::*;
    use std::f64::consts::PI;
    use twinmill::cutting::collide::{EventKind, Fixture, Holder, Part, sweep_with_checks};
    use twinmill::cutting::shape::Solid;
    use twinmill::cutting::shape::{ClosedMesh, Cylinder, read_obj};
    use twinmill::cutting::stock::TriDexel;
    use twinmill::cutting::sweep::SweepOptions;
    use twinmill::cutting::tool::{Tool, ToolKind};
    use twinmill::machine::chain::{Axis, AxisKind, Chain};
    use twinmill::math::{Point3, Real, UnitVector3, Vector3};
    use twinmill::nc::{AxisLetter, AxisValues, Move, MoveKind};
    use twinmill::progress::NoProgress;
    use twinmill::report::deviation_map::{
        DesignModel, DeviationImageOptions, deviation_map, render_deviation_map,
    };
    use twinmill::report::render::encode_png;
    /// Upper bound on |V_dexel − V| for a convex solid of area `a` and integral mean curvature
    /// `m`: every point where the dexel prisms and the solid disagree lies within half a cell
    /// diagonal ρ = h/√2 of the surface, so the error is at most the outer parallel shell
    /// (Steiner): aρ + mρ² + (4π/3)ρ³.
    fn convex_bound(a: Real, m: Real, h: Real) -> Real {
        let r = h / 2f64.sqrt();
        a * r + m * r * r + 4.0 * PI / 3.0 * r * r * r
    }

    #[test]
    fn cylinder_stock_volume_within_the_pitch_bound() {
        let (r, l, pitch) = (10.0, 30.0, 0.2);
        let c = Cylinder::try_new(Point3::new(0.0, 0.0, -5.0), Vector3::z(), r, l).expect("valid");
        let s = TriDexel::from_solid(
            aabb([-10.0, -10.0, -5.0], [10.0, 10.0, 25.0]),
            pitch,
            1e9,
            &c,
        )
        .expect("fits");
        let exact = PI * r * r * l;
        let bound = convex_bound(
            2.0 * PI * r * l + 2.0 * PI * r * r,
            PI * l + PI * PI * r,
            s.max_spacing(),
        );
        let err = (s.volume() - exact).abs();
        assert!(err < bound, "error {err} bound {bound}");
        // The z grid is exact per ray: L times the count of ray centres in the disc.
        let g = &s.grids()[2];
        let (nu, nv) = g.dims();
        let (du, dv) = g.pitches();
        let mut count = 0usize;
        for iv in 0..nv {
            for iu in 0..nu {
                let o = g.ray_origin(iu, iv);
                if o.x * o.x + o.y * o.y < r * r {
                    count += 1;
                }
            }
        }
        assert!((g.volume() - count as Real * du * dv * l).abs() < 1e-6);
        // The x grid's chords are 2·sqrt(r² − y²) to rounding.
        let g = &s.grids()[0];
        let (nu, nv) = g.dims();
        for iv in 0..nv {
            for iu in 0..nu {
                let o = g.ray_origin(iu, iv);
                let segs = g.ray(iu, iv);
                if o.y.abs() < r - 1e-3 {
                    assert_eq!(segs.len(), 1);
                    let half = (r * r - o.y * o.y).sqrt();
                    assert!(
                        (segs[0].lo.t + half).abs() < 1e-9 && (segs[0].hi.t - half).abs() < 1e-9
                    );
                }
            }
        }
    }

    #[test]
    fn tilted_cylinder_stock_volume_within_the_pitch_bound() {
        let (r, l) = (4.0, 20.0);
        let c = Cylinder::try_new(
            Point3::new(1.0, 2.0, 3.0),
            Vector3::new(1.0, 1.0, 1.0),
            r,
            l,
        )
        .expect("valid");
        let s = TriDexel::from_solid(Solid::bounds(&c), 0.25, 1e9, &c).expect("fits");
        let bound = convex_bound(
            2.0 * PI * r * l + 2.0 * PI * r * r,
            PI * l + PI * PI * r,
            s.max_spacing(),
        );
        let err = (s.volume() - PI * r * r * l).abs();
        assert!(err < bound, "error {err} bound {bound}");
    }

    #[test]
    fn obj_cube_stock_equals_the_box_stock() {
        let v = [
            [0.0, 0.0, 0.0],
            [10.0, 0.0, 0.0],
            [10.0, 8.0, 0.0],
            [0.0, 8.0, 0.0],
            [0.0, 0.0, 6.0],
            [10.0, 0.0, 6.0],
            [10.0, 8.0, 6.0],
            [0.0, 8.0, 6.0],
        ];
        let t = [
            [0, 2, 1],
            [0, 3, 2],
            [4, 5, 6],
            [4, 6, 7],
            [0, 1, 5],
            [0, 5, 4],
            [1, 2, 6],
            [1, 6, 5],
            [2, 3, 7],
            [2, 7, 6],
            [3, 0, 4],
            [3, 4, 7],
        ];
        let mesh = read_obj(&obj(&v, &t), Path::new("cube.obj")).expect("closed");
        let b = aabb([0.0; 3], [10.0, 8.0, 6.0]);
        // Pitch 0.5: ray centres fall on the faces' diagonals.
        let a = TriDexel::from_solid(b, 0.5, 1e9, &mesh).expect("fits");
        let e = TriDexel::new_box(b, 0.5, 1e9).expect("fits");
        for (ga, ge) in a.grids().iter().zip(e.grids()) {
            let (nu, nv) = ge.dims();
            for iv in 0..nv {
                for iu in 0..nu {
                    let (sa, se) = (ga.ray(iu, iv), ge.ray(iu, iv));
                    assert_eq!(sa.len(), se.len());
                    for (x, y) in sa.iter().zip(se) {
                        assert!((x.lo.t - y.lo.t).abs() < 1e-9 && (x.hi.t - y.hi.t).abs() < 1e-9);
                        assert_eq!((x.lo.normal, x.hi.normal), (y.lo.normal, y.hi.normal));
                    }
                }
            }
        }
    }

    #[test]
    fn tessellated_cylinder_obj_matches_its_polyhedral_volume() {
        let (n, r, l) = (48usize, 10.0, 12.0);
        let poly: Vec<[Real; 2]> = (0..n)
            .map(|i| {
                let a = 2.0 * PI * i as Real / n as Real;
                [r * a.cos(), r * a.sin()]
            })
            .collect();
        let mesh = read_obj(&prism(&poly, &fan(n), 0.0, l), Path::new("cyl.obj")).expect("closed");
        // Exact volume of the prism over the regular n-gon as written.
        let area = 0.5 * n as Real * r * r * (2.0 * PI / n as Real).sin();
        assert!((mesh.volume() - area * l).abs() < 1e-9);
        let s = TriDexel::from_solid(mesh.bounds(), 0.2, 1e9, &mesh).expect("fits");
        let side = 2.0 * r * (PI / n as Real).sin();
        let perimeter = n as Real * side;
        // Polyhedral integral mean curvature: ½ Σ edge length × exterior angle.
        let m = 0.5 * (n as Real * l * 2.0 * PI / n as Real + 2.0 * perimeter * PI / 2.0);
        let bound = convex_bound(2.0 * area + perimeter * l, m, s.max_spacing());
        let err = (s.volume() - area * l).abs();
        assert!(err < bound, "error {err} bound {bound}");
    }

    #[test]
    fn mesh_stock_respects_the_memory_budget() {
        let c = Cylinder::try_new(Point3::origin(), Vector3::x(), 50.0, 200.0).expect("valid");
        assert!(TriDexel::from_solid(c.bounds(), 1e-3, 1e9, &c).is_err());
    }

    fn xyz() -> Chain {
        let ax = |letter, d: Vector3| Axis {
            letter,
            kind: AxisKind::Linear,
            direction: UnitVector3::new_normalize(d),
            origin: Point3::origin(),
        };
        Chain::new(
            vec![
                ax(AxisLetter::Y, Vector3::y()),
                ax(AxisLetter::X, Vector3::x()),
                ax(AxisLetter::Z, Vector3::z()),
            ],
            "S",
        )
        .expect("chain")
    }

    fn mv(kind: MoveKind, a: [Real; 3], b: [Real; 3], line: usize) -> Move {
        let q = |p: [Real; 3]| AxisValues::from_array([p[0], p[1], p[2], 0.0, 0.0, 0.0]);
        Move {
            kind,
            start: q(a),
            end: q(b),
            feed_mm_per_min: (kind == MoveKind::Linear).then_some(500.0),
            line,
        }
    }

    const OPTS: SweepOptions = SweepOptions {
        rotary_step_bound_mm: 1e-4,
    };

    #[test]
    fn rapid_through_stock_is_reported_at_its_line_with_a_contact_on_the_tool() {
        let mut s = TriDexel::new_box(aabb([0.0; 3], [40.0, 30.0, 20.0]), 0.25, 1e9).expect("fits");
        let tool = Tool::try_new(ToolKind::Flat, 6.0, 25.0).expect("tool");
        let moves = [
            // Above the stock: nothing.
            mv(MoveKind::Rapid, [-10.0, 15.0, 25.0], [50.0, 15.0, 25.0], 10),
            // Through it, 5 mm deep, entering the face x = 0.
            mv(MoveKind::Rapid, [-10.0, 15.1, 15.0], [50.0, 15.1, 15.0], 20),
            // Feeding through material is cutting, not a collision.
            mv(MoveKind::Linear, [-10.0, 5.0, 15.0], [50.0, 5.0, 15.0], 30),
        ];
        let r = sweep_with_checks(&mut s, &xyz(), &tool, None, &[], &moves, &OPTS, &NoProgress)
            .expect("runs");
        assert_eq!(r.events.len(), 1, "{:?}", r.events);
        let e = &r.events[0];
        assert_eq!(
            (e.kind.clone(), e.line),
            (EventKind::RapidThroughMaterial, 20)
        );
        let p = Point3::from(e.point);
        // First contact: on the face x = 0, on the tool's cylinder (axis at x = −3 then),
        // between the tip and the stock top.
        assert!(p.x.abs() < 0.26, "{p:?}");
        assert!(p.z >= 15.0 - 1e-9 && p.z <= 20.0 + 1e-9, "{p:?}");
        // The point lies on the tool's boundary at its first contact: radial distance 3 from an
        // axis at y = 15.1 with its centre left of the face by at most the radius.
        let dy = (p.y - 15.1).abs();
        let cx = p.x - (9.0 - dy * dy).max(0.0).sqrt();
        assert!((-3.0 - 0.26..=1e-9).contains(&cx), "axis at x {cx}");
        // Overlap: a slot 6 wide, 5 deep through 40 mm of stock (the move removed it after).
        let vol = e.volume_mm3.expect("volume");
        assert!(
            (vol - (6.0 * 5.0 * 40.0)).abs() < 0.05 * 1200.0,
            "volume {vol}"
        );
        // Depth: 5 mm below the top (z rays); x rays see 40 mm, y rays 6 mm.
        assert!((e.depth_mm - 5.0).abs() < 1e-6, "depth {}", e.depth_mm);
    }

    #[test]
    fn holder_dipping_into_a_pocket_wall_is_reported() {
        // 60 × 60 × 30 block; a channel along x, 40 wide (y 10..50), floor at z = 5.
        let mut s = TriDexel::new_box(aabb([0.0; 3], [60.0, 60.0, 30.0]), 0.5, 1e9).expect("fits");
        let tool = Tool::try_new(ToolKind::Flat, 10.0, 15.0).expect("tool");
        // Shank Ø9 × 20 above the flutes, holder Ø40 × 50 above it: the holder stays above the
        // top (tip ≥ 5, holder bottom ≥ 40) and the shank inside the channel.
        let holder = Holder::try_new(4.5, 20.0, 20.0, 50.0).expect("holder");
        let mut moves = Vec::new();
        let mut line = 1;
        for z in [20.0, 10.0, 5.0] {
            for y in [15.0, 25.0, 35.0, 45.0] {
                moves.push(mv(MoveKind::Linear, [-10.0, y, z], [70.0, y, z], line));
                line += 1;
            }
        }
        let r = sweep_with_checks(
            &mut s,
            &xyz(),
            &tool,
            Some(&holder),
            &[],
            &moves,
            &OPTS,
            &NoProgress,
        )
        .expect("runs");
        assert!(r.events.is_empty(), "{:?}", r.events);
        // A short shank puts the Ø44 holder's underside at z = 5 + 15 + 5 = 25, below the top
        // (30), 2 mm into each channel wall (y = 10 and 50).
        let holder = Holder::try_new(4.5, 5.0, 22.0, 50.0).expect("holder");
        let dip = [mv(
            MoveKind::Linear,
            [30.0, 30.0, 5.0],
            [31.0, 30.0, 5.0],
            99,
        )];
        let r = sweep_with_checks(
            &mut s,
            &xyz(),
            &tool,
            Some(&holder),
            &[],
            &dip,
            &OPTS,
            &NoProgress,
        )
        .expect("runs");
        assert_eq!(r.events.len(), 1, "{:?}", r.events);
        let e = &r.events[0];
        assert_eq!(
            (e.kind.clone(), e.line),
            (EventKind::NonCuttingInStock(Part::Holder), 99)
        );
        let p = Point3::from(e.point);
        // The contact is on the holder at the start (radius 22 about (30, 30), z 25..30).
        let rad = ((p.x - 30.0).powi(2) + (p.y - 30.0).powi(2)).sqrt();
        assert!(
            (rad - 22.0).abs() < 1e-6 || (p.z - 25.0).abs() < 1e-9,
            "{p:?}"
        );
        assert!(
            rad <= 22.0 + 1e-9 && p.z >= 25.0 - 1e-9 && p.z <= 30.0 + 1e-9,
            "{p:?}"
        );
        // Penetration: 2 mm into the walls along y (y rays; z rays see 5, x rays long chords).
        assert!((e.depth_mm - 2.0).abs() < 1e-9, "{e:?}");
        // Overlap ≈ two circular segments of height 2 (radius 22) × 5 mm, swept 1 mm along x.
        let seg = 22.0 * 22.0 * (20.0_f64 / 22.0).acos() - 20.0 * (22.0_f64 * 22.0 - 400.0).sqrt();
        let expect = 2.0 * seg * 5.0 + 2.0 * 2.0 * 5.0 * 1.0;
        let vol = e.volume_mm3.expect("volume");
        assert!(
            (vol - expect).abs() < 0.15 * expect,
            "volume {vol} vs {expect}"
        );
    }

    #[test]
    fn fixture_hit_is_reported_and_a_clear_path_is_not() {
        // A clamp block at x 30..40, y 0..10, z 0..20.
        let v = [
            [30.0, 0.0, 0.0],
            [40.0, 0.0, 0.0],
            [40.0, 10.0, 0.0],
            [30.0, 10.0, 0.0],
            [30.0, 0.0, 20.0],
            [40.0, 0.0, 20.0],
            [40.0, 10.0, 20.0],
            [30.0, 10.0, 20.0],
        ];
        let t = [
            [0, 2, 1],
            [0, 3, 2],
            [4, 5, 6],
            [4, 6, 7],
            [0, 1, 5],
            [0, 5, 4],
            [1, 2, 6],
            [1, 6, 5],
            [2, 3, 7],
            [2, 7, 6],
            [3, 0, 4],
            [3, 4, 7],
        ];
        let clamp = Fixture::try_new(
            "clamp",
            read_obj(&obj(&v, &t), Path::new("clamp.obj")).expect("closed"),
        )
        .expect("fixture");
        let mut s = TriDexel::new_box(aabb([0.0; 3], [20.0, 20.0, 10.0]), 0.5, 1e9).expect("fits");
        let tool = Tool::try_new(ToolKind::Ball, 6.0, 20.0).expect("tool");
        let moves = [
            mv(MoveKind::Rapid, [0.0, 5.0, 25.0], [60.0, 5.0, 25.0], 5),
            mv(MoveKind::Linear, [0.0, 5.0, 15.0], [60.0, 5.0, 15.0], 6),
        ];
        let r = sweep_with_checks(
            &mut s,
            &xyz(),
            &tool,
            None,
            &[clamp],
            &moves,
            &OPTS,
            &NoProgress,
        )
        .expect("runs");
        assert_eq!(r.events.len(), 1, "{:?}", r.events);
        let e = &r.events[0];
        assert_eq!(e.line, 6);
        assert_eq!(
            e.kind,
            EventKind::FixtureHit {
                part: Part::Tool,
                fixture: "clamp".into()
            }
        );
        let p = Point3::from(e.point);
        // First contact on the clamp's face x = 30, tool at x = 27 then; travel after it 30 mm.
        assert!((p.x - 30.0).abs() < 1e-6, "{p:?}");
        assert!((e.depth_mm - 33.0).abs() < 1e-6, "{}", e.depth_mm);
    }

    /// The design: the block [0,40]×[0,30]×[0,20] with a slot along x, y 12..18, floor z = 14.
    fn slot_design(floor: Real) -> ClosedMesh {
        read_obj(&slot_design_obj(floor), Path::new("design.obj")).expect("closed")
    }

    /// OBJ text of [`slot_design`].
    pub(super) fn slot_design_obj(floor: Real) -> String {
        let (w, h, a, b) = (30.0, 20.0, 12.0, 18.0);
        // U profile in (y, z), counter-clockwise seen from +x, extruded along x.
        let prof = [
            [0.0, 0.0],
            [w, 0.0],
            [w, h],
            [b, h],
            [b, floor],
            [a, floor],
            [a, h],
            [0.0, h],
        ];
        let cap = [
            [0, 1, 4],
            [0, 4, 5],
            [1, 2, 3],
            [1, 3, 4],
            [0, 5, 6],
            [0, 6, 7],
        ];
        // prism() extrudes along z over (x, y): rotate coordinates (y, z, x) → (x, y, z).
        let text = prism(&prof, &cap, 0.0, 40.0);
        let rotated: String = text
            .lines()
            .map(|l| match l.strip_prefix("v ") {
                Some(rest) => {
                    let c: Vec<&str> = rest.split_whitespace().collect();
                    format!("v {} {} {}\n", c[2], c[0], c[1])
                }
                None => format!("{l}\n"),
            })
            .collect();
        rotated
    }

    fn cut_slot(floor: Real) -> TriDexel {
        let mut s = TriDexel::new_box(aabb([0.0; 3], [40.0, 30.0, 20.0]), 0.25, 1e9).expect("fits");
        let tool = Tool::try_new(ToolKind::Flat, 6.0, 25.0).expect("tool");
        let moves = [mv(
            MoveKind::Linear,
            [-5.0, 15.0, floor],
            [45.0, 15.0, floor],
            7,
        )];
        sweep_with_checks(&mut s, &xyz(), &tool, None, &[], &moves, &OPTS, &NoProgress)
            .expect("runs");
        s
    }

    #[test]
    fn exact_cut_has_no_deviation() {
        let design = DesignModel::try_new(slot_design(14.0)).expect("design");
        let (points, rep) = deviation_map(&cut_slot(14.0), &design).expect("map");
        // Crossings lie on the planar cut faces to rounding (coordinates ≤ 40 mm: ~1e-14).
        assert!(
            rep.max_mm.abs() < 1e-9 && rep.min_mm.abs() < 1e-9,
            "{rep:?}"
        );
        assert!(points.len() > 10_000);
        let img = render_deviation_map(
            &points,
            &DeviationImageOptions {
                title: "slot".into(),
                width_px: 640,
                height_px: 400,
                range_mm: None,
                point_pitch_mm: 0.25,
            },
        )
        .expect("image");
        let png = encode_png(&img).expect("png");
        let back = image::load_from_memory(&png).expect("decodes");
        assert_eq!((back.width(), back.height()), (640, 400));
    }

    #[test]
    fn a_floor_left_high_shows_its_offset() {
        let design = DesignModel::try_new(slot_design(14.0)).expect("design");
        let (points, rep) = deviation_map(&cut_slot(14.1), &design).expect("map");
        let floor: Vec<_> = points
            .iter()
            .filter(|p| p.line == 7 && p.normal.z > 0.99 && (p.point.y - 15.0).abs() < 2.5)
            .collect();
        assert!(floor.len() > 100);
        for p in floor {
            assert!((p.distance_mm - 0.1).abs() < 1e-6, "{p:?}");
        }
        assert!((rep.max_mm - 0.1).abs() < 1e-6, "{rep:?}");
        // Nothing is gouged.
        assert!(rep.min_mm > -1e-9, "{rep:?}");
        let img = render_deviation_map(
            &points,
            &DeviationImageOptions {
                title: "floor +0.1 mm".into(),
                width_px: 800,
                height_px: 600,
                range_mm: None,
                point_pitch_mm: 0.25,
            },
        )
        .expect("image");
        std::fs::write(
            std::env::temp_dir().join("twinmill_deviation.png"),
            encode_png(&img).expect("png"),
        )
        .expect("write");
    }

    #[test]
    fn fixture_hit_during_a_rotary_move_is_reported() {
        // Workpiece on A (about +X), tool at machine (0, 0, 20): its tip circles the X axis.
        let ax = |letter, kind, d: Vector3| Axis {
            letter,
            kind,
            direction: UnitVector3::new_normalize(d),
            origin: Point3::origin(),
        };
        let chain = Chain::new(
            vec![
                ax(AxisLetter::A, AxisKind::Rotary, Vector3::x()),
                ax(AxisLetter::Y, AxisKind::Linear, Vector3::y()),
                ax(AxisLetter::X, AxisKind::Linear, Vector3::x()),
                ax(AxisLetter::Z, AxisKind::Linear, Vector3::z()),
            ],
            "S",
        )
        .expect("chain");
        // A block on the tip's path at 45° (tip at (0, −14.1, 14.1) in W for A = +45°).
        let v = [
            [-5.0, -16.0, 12.0],
            [5.0, -16.0, 12.0],
            [5.0, -12.0, 12.0],
            [-5.0, -12.0, 12.0],
            [-5.0, -16.0, 16.0],
            [5.0, -16.0, 16.0],
            [5.0, -12.0, 16.0],
            [-5.0, -12.0, 16.0],
        ];
        let t = [
            [0, 2, 1],
            [0, 3, 2],
            [4, 5, 6],
            [4, 6, 7],
            [0, 1, 5],
            [0, 5, 4],
            [1, 2, 6],
            [1, 6, 5],
            [2, 3, 7],
            [2, 7, 6],
            [3, 0, 4],
            [3, 4, 7],
        ];
        let block = Fixture::try_new(
            "block",
            read_obj(&obj(&v, &t), Path::new("b.obj")).expect("closed"),
        )
        .expect("fixture");
        let mut s = TriDexel::new_box(aabb([-2.0; 3], [2.0; 3]), 0.5, 1e9).expect("fits");
        let tool = Tool::try_new(ToolKind::Flat, 2.0, 10.0).expect("tool");
        let q = |a: Real| AxisValues::from_array([0.0, 0.0, 20.0, a, 0.0, 0.0]);
        let turn = |a: Real, line| Move {
            kind: MoveKind::Rapid,
            start: q(0.0),
            end: q(a),
            feed_mm_per_min: None,
            line,
        };
        let opts = SweepOptions {
            rotary_step_bound_mm: 1e-2,
        };
        // Turning the other way misses it.
        let r = sweep_with_checks(
            &mut s,
            &chain,
            &tool,
            None,
            std::slice::from_ref(&block),
            &[turn(-90.0, 3)],
            &opts,
            &NoProgress,
        )
        .expect("runs");
        assert!(r.events.is_empty(), "{:?}", r.events);
        let r = sweep_with_checks(
            &mut s,
            &chain,
            &tool,
            None,
            &[block],
            &[turn(90.0, 4)],
            &opts,
            &NoProgress,
        )
        .expect("runs");
        assert_eq!(r.events.len(), 1, "{:?}", r.events);
        let e = &r.events[0];
        assert_eq!(e.line, 4);
        assert_eq!(
            e.kind,
            EventKind::FixtureHit {
                part: Part::Tool,
                fixture: "block".into()
            }
        );
        // The contact is on the block's surface.
        let p = Point3::from(e.point);
        let inside = |k: usize, lo: Real, hi: Real| p[k] >= lo - 1e-6 && p[k] <= hi + 1e-6;
        assert!(
            inside(0, -5.0, 5.0) && inside(1, -16.0, -12.0) && inside(2, 12.0, 16.0),
            "{p:?}"
        );
    }

    #[test]
    fn mesh_of_two_blocks_gives_two_sorted_segments_per_ray() {
        let cube = |x0: Real, x1: Real, base: usize| {
            let v = [
                [x0, 0.0, 0.0],
                [x1, 0.0, 0.0],
                [x1, 2.0, 0.0],
                [x0, 2.0, 0.0],
                [x0, 0.0, 2.0],
                [x1, 0.0, 2.0],
                [x1, 2.0, 2.0],
                [x0, 2.0, 2.0],
            ];
            let t = [
                [0, 2, 1],
                [0, 3, 2],
                [4, 5, 6],
                [4, 6, 7],
                [0, 1, 5],
                [0, 5, 4],
                [1, 2, 6],
                [1, 6, 5],
                [2, 3, 7],
                [2, 7, 6],
                [3, 0, 4],
                [3, 4, 7],
            ];
            (v, t.map(|f| f.map(|i| i + base)))
        };
        let (va, ta) = cube(0.0, 1.0, 0);
        let (vb, tb) = cube(1.5, 3.0, 8);
        let v: Vec<_> = va.iter().chain(&vb).copied().collect();
        let t: Vec<_> = ta.iter().chain(&tb).copied().collect();
        let mesh = read_obj(&obj(&v, &t), Path::new("two.obj")).expect("closed");
        let s = TriDexel::from_solid(mesh.bounds(), 0.25, 1e9, &mesh).expect("fits");
        let per: Vec<_> = s.grids().iter().map(|g| g.volume()).collect();
        assert!(
            (s.volume() - (1.0 * 4.0 + 1.5 * 4.0)).abs() < 1e-9,
            "{per:?}"
        );
        let g = &s.grids()[0];
        let (nu, nv) = g.dims();
        for iv in 0..nv {
            for iu in 0..nu {
                let t: Vec<_> = g.ray(iu, iv).iter().map(|s| (s.lo.t, s.hi.t)).collect();
                assert_eq!(t, vec![(0.0, 1.0), (1.5, 3.0)]);
            }
        }
    }
}

// ---------------------------------------------------------------------------------------
// `simulate` on scenes with cylinder and mesh stock, fixtures, holders and a design model.

/// A three-axis scene (X, Y, Z; the tool tip at W = (x, y, z)) with `tool`, `stock` and
/// `extra` TOML; the program is `p.ngc`. No scanner and no faces: `simulate` needs neither.
fn xyz_scene(tool: &str, stock: &str, extra: &str) -> String {
    format!(
        r#"name = "t"
program = "p.ngc"

[machine]
axes = [
  {{ name = "X", kind = "linear", direction = [1, 0, 0] }},
  {{ name = "Y", kind = "linear", direction = [0, 1, 0] }},
  {{ name = "Z", kind = "linear", direction = [0, 0, 1] }},
]
home = {{ X = -20, Y = 0, Z = 60 }}

[tool]
{tool}

[stock]
{stock}

{extra}
"#
    )
}

const FLAT6: &str = "kind = \"flat\"\ndiameter_mm = 6.0\nlength_mm = 20.0";

/// OBJ text of the box [min, max].
fn box_obj(min: [Real; 3], max: [Real; 3]) -> String {
    let v: Vec<[Real; 3]> = (0..8)
        .map(|k| {
            [
                if k & 1 == 0 { min[0] } else { max[0] },
                if k & 2 == 0 { min[1] } else { max[1] },
                if k & 4 == 0 { min[2] } else { max[2] },
            ]
        })
        .collect();
    // Outward, counter-clockwise seen from outside.
    let t = [
        [0, 2, 1],
        [1, 2, 3],
        [4, 5, 6],
        [5, 7, 6],
        [0, 1, 4],
        [1, 5, 4],
        [2, 6, 3],
        [3, 6, 7],
        [0, 4, 2],
        [2, 4, 6],
        [1, 3, 5],
        [3, 7, 5],
    ];
    obj(&v, &t)
}

/// Runs `twinmill simulate` on a scene with the given files; returns the exit code, the
/// report (if it printed one) and stderr.
fn simulate_in(
    sb: &Sandbox,
    scene: &str,
    program: &str,
    files: &[(&str, &str)],
) -> (i32, serde_json::Value, String) {
    sb.write("s.toml", scene.as_bytes());
    sb.write("p.ngc", program.as_bytes());
    for (name, text) in files {
        sb.write(name, text.as_bytes());
    }
    let (code, stdout, stderr) = sb.run(&["simulate", "s.toml", "--json"]);
    let report = serde_json::from_str(&stdout).unwrap_or(serde_json::Value::Null);
    (code, report, stderr)
}

/// Upper bound on the dexel error of a convex body's volume (area `s`, diameter `diam`) at
/// ray spacing `h`: the outer parallel shell at half a cell diagonal ρ = h/√2 (Steiner,
/// with the integral mean curvature at most 2π·diameter).
fn convex_shell_bound(s: Real, diam: Real, h: Real) -> Real {
    let r = h / 2f64.sqrt();
    s * r + 2.0 * std::f64::consts::PI * diam * r * r + 4.0 * std::f64::consts::PI / 3.0 * r * r * r
}

/// Distance from (x, y) to the rectangle [x0, x1] × [y0, y1] (0 inside).
fn rect_distance(x: Real, y: Real, [x0, x1, y0, y1]: [Real; 4]) -> Real {
    let dx = (x0 - x).max(x - x1).max(0.0);
    let dy = (y0 - y).max(y - y1).max(0.0);
    dx.hypot(dy)
}

#[test]
fn a_three_axis_scene_of_machine_tool_stock_and_program_is_complete_for_simulate() {
    // The built-in pocket scene has nothing but the program, [machine], [tool] and [stock].
    let text = builtin("xyz-pocket.toml");
    let table: toml::Table = toml::from_str(&text).expect("TOML");
    let keys: Vec<&str> = table.keys().map(String::as_str).collect();
    assert_eq!(keys, ["machine", "program", "stock", "tool"], "{keys:?}");
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/xyz-pocket.toml");
    let scene = Scene::load(&path).expect("scene");
    assert_eq!(
        scene.name, "xyz-pocket",
        "the name defaults to the file's stem"
    );
    assert!(scene.scanner.is_none() && scene.faces.is_empty());

    // The tool centre covers R = [15, 45] × [12, 28] at z = 15 (rows 4 mm apart and the
    // contour of R, Ø6): the pocket is R grown by 3 mm, 5 mm deep in the 20 mm block. Every
    // z ray strictly inside it ends at the floor, every ray outside at the top — exactly,
    // since dexels store exact crossings.
    let program = scene.load_program().expect("program");
    let part = twinmill::pipeline::machine_part(&scene, &program, &NoProgress).expect("cut");
    let r_path = [15.0, 45.0, 12.0, 28.0];
    let (floor, top, radius) = (15.0, 20.0, 3.0);
    let grid = &part.stock.grids()[2];
    assert_eq!(grid.axis(), 2);
    let (nu, nv) = grid.dims();
    let (mut inside, mut outside) = (0, 0);
    for iu in 0..nu {
        for iv in 0..nv {
            let o = grid.ray_origin(iu, iv);
            let d = rect_distance(o.x, o.y, r_path) - radius;
            let ray = grid.ray(iu, iv);
            let highest = ray
                .iter()
                .map(|s| s.hi.t)
                .fold(Real::NEG_INFINITY, Real::max);
            if d < -1e-6 {
                inside += 1;
                assert!((highest - floor).abs() < 1e-9, "ray at {o}: top {highest}");
            } else if d > 1e-6 {
                outside += 1;
                assert!((highest - top).abs() < 1e-9, "ray at {o}: top {highest}");
            }
        }
    }
    assert!(
        inside > 70_000 && outside > 100_000,
        "{inside} in, {outside} out"
    );

    // Through the CLI: `simulate` works, removing the pocket's volume within the dexel
    // bound of a convex body; `run`, `scan`, `identify` and `design` each fail with one line
    // naming what they need, and write nothing.
    let sb = Sandbox::new("xyz-pocket");
    sb.write("pocket.toml", text.as_bytes());
    sb.write("xyz-pocket.ngc", builtin("xyz-pocket.ngc").as_bytes());
    let (code, stdout, stderr) = sb.run(&["simulate", "pocket.toml", "--json"]);
    assert_eq!(code, 0, "{stderr}");
    let report: serde_json::Value = serde_json::from_str(&stdout).expect("report");
    let (w, h) = (r_path[1] - r_path[0], r_path[3] - r_path[2]);
    let area =
        (w + 2.0 * radius) * (h + 2.0 * radius) - (4.0 - std::f64::consts::PI) * radius * radius;
    let depth = top - floor;
    let exact = area * depth;
    let perimeter = 2.0 * (w + h) + 2.0 * std::f64::consts::PI * radius;
    let diam = ((w + 2.0 * radius).powi(2) + (h + 2.0 * radius).powi(2) + depth * depth).sqrt();
    let bound = convex_shell_bound(2.0 * area + perimeter * depth, diam, scene.pitch_mm);
    let removed = report["stock"]["removed_mm3"].as_f64().expect("number");
    assert!(
        (removed - exact).abs() < bound,
        "removed {removed}, exact {exact}, bound {bound}"
    );
    assert_eq!(report["collisions"].as_array().map(Vec::len), Some(0));
    for (args, needs) in [
        (
            &["run", "pocket.toml"][..],
            &["run needs [scanner]", "[identify] faces"][..],
        ),
        (&["scan", "pocket.toml"][..], &["scan needs [scanner]"][..]),
        (
            &["identify", "pocket.toml"][..],
            &["identify needs [identify] parameters", "[scanner]"][..],
        ),
        (
            &["design", "pocket.toml", "--params", "dy_XY"][..],
            &["design needs [scanner]"][..],
        ),
    ] {
        let listing = || {
            let mut f = files_in(&sb.dir.join("out"));
            f.sort();
            f
        };
        let before = listing();
        let (code, stdout, stderr) = sb.run(args);
        assert_ne!(code, 0, "{args:?} should fail");
        assert_eq!(stderr.trim_end().lines().count(), 1, "{args:?}: {stderr}");
        assert!(stderr.contains("pocket.toml: "), "{args:?}: {stderr}");
        for n in needs {
            assert!(stderr.contains(n), "{args:?}: '{n}' not in {stderr}");
        }
        assert!(stdout.is_empty(), "{args:?}: {stdout}");
        assert_eq!(listing(), before, "{args:?} wrote files");
    }
    // `correct` needs no faces: it measures the path and the whole part, and says that no
    // face was measured instead of giving a number.
    let (code, stdout, stderr) = sb.run(&["correct", "pocket.toml", "--json"]);
    assert_eq!(code, 0, "{stderr}");
    let report: serde_json::Value = serde_json::from_str(&stdout).expect("report");
    let last = report["iterations"]
        .as_array()
        .and_then(|i| i.last())
        .expect("a pass");
    assert!(last["predicted_error_mm"].is_null(), "{last}");
    assert!(
        last["path"]["max_mm"].as_f64().is_some_and(|m| m < 1e-9),
        "{last}"
    );
}

#[test]
fn simulate_cylinder_stock_removes_the_analytic_volume() {
    let sb = Sandbox::new("sim-cylinder");
    let (r, len, pitch, z_cut, half) = (10.0_f64, 40.0_f64, 0.2_f64, 7.0_f64, 3.0_f64);
    let stock = format!(
        "kind = \"cylinder\"\nends = [[0.0, 0.0, 0.0], [{len}, 0.0, 0.0]]\nradius_mm = {r}\npitch_mm = {pitch}"
    );
    // A flat Ø6 end mill at z = 7 along the whole bar, entering and leaving in the air.
    let program = "G21 G90\nG0 X-10 Y0 Z60\nG0 Z7\nG1 X50 F600\nG0 Z60\nM30\n";
    let (code, report, stderr) = simulate_in(&sb, &xyz_scene(FLAT6, &stock, ""), program, &[]);
    assert_eq!(code, 0, "{stderr}");
    // Removed: the bar's section cut by z ≥ 7, |y| ≤ 3, times its length:
    // A = ∫_{−3}^{3} (√(r² − y²) − 7) dy = [y/2·√(r² − y²) + r²/2·asin(y/r)]_{−3}^{3} − 6·7.
    let area = half * (r * r - half * half).sqrt() + r * r * (half / r).asin() - 2.0 * half * z_cut;
    let exact = len * area;
    // The removed region is convex: its dexel volume is within the parallel-shell bound.
    // Section perimeter: the floor (6), two sides up to the arc, the arc.
    let side = (r * r - half * half).sqrt() - z_cut;
    let perimeter = 2.0 * half + 2.0 * side + 2.0 * r * (half / r).asin();
    let s = 2.0 * area + len * perimeter;
    let diam = (len * len + 4.0 * half * half + (r - z_cut) * (r - z_cut)).sqrt();
    let bound = convex_shell_bound(s, diam, pitch);
    let removed = report["stock"]["removed_mm3"].as_f64().expect("number");
    assert!(
        (removed - exact).abs() < bound,
        "removed {removed}, exact {exact}, bound {bound}"
    );
    // And the bar itself: π r² L within its own bound.
    let total = removed + report["stock"]["volume_mm3"].as_f64().expect("number");
    let bar = std::f64::consts::PI * r * r * len;
    let bar_bound = convex_shell_bound(
        2.0 * std::f64::consts::PI * r * (r + len),
        (len * len + 4.0 * r * r).sqrt(),
        pitch,
    );
    assert!(
        (total - bar).abs() < bar_bound,
        "{total} vs {bar} ± {bar_bound}"
    );
    assert_eq!(report["collisions"].as_array().map(Vec::len), Some(0));
    assert!(report["deviation"].is_null());
}

#[test]
fn simulate_reports_a_fixture_hit_at_its_line() {
    let sb = Sandbox::new("sim-fixture");
    let stock = "min = [0.0, -10.0, 0.0]\nmax = [40.0, 10.0, 10.0]\npitch_mm = 0.25";
    let extra = "[[fixtures]]\nname = \"clamp\"\nfile = \"clamp.obj\"\nposition = [45.0, 0.0, 0.0]";
    // The clamp is [45, 55] × [−5, 5] × [0, 20] once placed; line 4 cuts along the stock
    // at z = 5 and runs on into it: the Ø6 tool touches x = 45 with its tip at x = 42.
    let program = "G21 G90\nG0 X-10 Y0 Z60\nG0 Z5\nG1 X60 F600\nG0 Z60\nM30\n";
    let clamp = box_obj([0.0, -5.0, 0.0], [10.0, 5.0, 20.0]);
    let (code, report, stderr) = simulate_in(
        &sb,
        &xyz_scene(FLAT6, stock, extra),
        program,
        &[("clamp.obj", &clamp)],
    );
    assert_eq!(code, 0, "{stderr}");
    let events = report["collisions"].as_array().expect("list");
    assert_eq!(events.len(), 1, "{events:?}");
    let e = &events[0];
    assert_eq!(e["kind"], "fixture_hit");
    assert_eq!(e["fixture"], "clamp");
    assert_eq!(e["part"], "tool");
    assert_eq!(e["line"], 4);
    let p: Vec<Real> = e["point_mm"]
        .as_array()
        .expect("point")
        .iter()
        .map(|c| c.as_f64().expect("number"))
        .collect();
    assert!(
        (p[0] - 45.0).abs() < 1e-6 && p[1].abs() <= 3.0 + 1e-9 && (5.0..=25.0).contains(&p[2]),
        "{p:?}"
    );
    // Travel after first contact: from x = 42 to 60.
    assert!(
        (e["depth_mm"].as_f64().expect("number") - 18.0).abs() < 1e-6,
        "{e}"
    );
    // The cut itself is unchanged by the checks: a 6 × 5 slot through the 40 mm stock.
    let removed = report["stock"]["removed_mm3"].as_f64().expect("number");
    assert!((removed - 40.0 * 6.0 * 5.0).abs() < 1e-6, "{removed}");
}

#[test]
fn simulate_checks_a_holder_given_as_sections() {
    let sb = Sandbox::new("sim-holder-sections");
    let stock = "min = [0.0, -10.0, 0.0]\nmax = [40.0, 10.0, 10.0]\npitch_mm = 0.25";
    // The tip feeds at z = −20 along y: the flutes (20 mm) end at the stock's bottom, the
    // shank (Ø10 × 6) runs through it from z = 0 to 6, the holder's conical section (radius
    // 8 at z = 6 to 20 at z = 16) dips 4 mm in below the top at z = 10.
    let program = "G21 G90\nG0 X20 Y30 Z-20\nG1 Y-30 F600\nG0 Z60\nM30\n";
    let tool = format!(
        "{FLAT6}\nshank_diameter_mm = 10.0\nshank_length_mm = 6.0\nholder_sections = [{{ length_mm = 10.0, radius_bottom_mm = 8.0, radius_top_mm = 20.0 }}, {{ length_mm = 30.0, radius_bottom_mm = 20.0, radius_top_mm = 20.0 }}]"
    );
    let (code, report, stderr) = simulate_in(&sb, &xyz_scene(&tool, stock, ""), program, &[]);
    assert_eq!(code, 0, "{stderr}");
    let events = report["collisions"].as_array().expect("list");
    let find = |kind: &str| {
        events
            .iter()
            .find(|e| e["kind"] == kind)
            .unwrap_or_else(|| panic!("no {kind} in {events:?}"))
    };
    let (shank, holder) = (find("shank_in_stock"), find("holder_in_stock"));
    assert_eq!(
        (shank["line"].as_i64(), holder["line"].as_i64()),
        (Some(3), Some(3))
    );
    // Depths along z: the shank the whole 6 mm it spans inside, the cone from 6 to 10.
    let depth = |e: &serde_json::Value| e["depth_mm"].as_f64().expect("number");
    assert!((depth(shank) - 6.0).abs() < 1e-6, "{shank}");
    assert!((depth(holder) - 4.0).abs() < 1e-6, "{holder}");
    // The holder's first contact lies on the cone: radius 8 + 1.2·(z − 6) about the tool axis
    // (x = 20), within a dexel spacing.
    let p: Vec<Real> = (0..3)
        .map(|k| holder["point_mm"][k].as_f64().expect("number"))
        .collect();
    assert!((6.0 - 1e-6..=10.0 + 1e-6).contains(&p[2]), "{p:?}");
    let r_at = 8.0 + 1.2 * (p[2] - 6.0);
    assert!((p[0] - 20.0).abs() <= r_at + 0.25, "{p:?}");
}

#[test]
fn simulate_reports_a_rapid_through_material_and_a_holder_in_the_stock() {
    let sb = Sandbox::new("sim-rapid");
    let stock = "min = [0.0, -10.0, 0.0]\nmax = [40.0, 10.0, 10.0]\npitch_mm = 0.25";
    // Line 3 rapids through the stock at z = 5. Line 5 feeds at z = −12, so the flutes
    // (20 mm) end 2 mm below the top of the stock at z = 8 and the shank (Ø10) dips 2 mm in.
    let program = "G21 G90\nG0 X-10 Y0 Z5\nG0 X60\nG0 X20 Y30 Z-12\nG1 Y-30 F600\nG0 Z60\nM30\n";
    let tool = format!(
        "{FLAT6}\nshank_diameter_mm = 10.0\nshank_length_mm = 30.0\nholder_diameter_mm = 40.0\nholder_length_mm = 50.0"
    );
    let (code, report, stderr) = simulate_in(&sb, &xyz_scene(&tool, stock, ""), program, &[]);
    assert_eq!(code, 0, "{stderr}");
    let events = report["collisions"].as_array().expect("list");
    let kinds: Vec<(String, i64)> = events
        .iter()
        .map(|e| {
            (
                e["kind"].as_str().unwrap_or("").to_string(),
                e["line"].as_i64().unwrap_or(0),
            )
        })
        .collect();
    assert_eq!(
        kinds,
        [
            ("rapid_through_material".to_string(), 3),
            ("shank_in_stock".to_string(), 5)
        ],
        "{events:?}"
    );
    // The rapid's first contact is on the stock's face x = 0 (to a dexel spacing); the
    // deepest overlap is along z: from the tip at z = 5 to the top at z = 10.
    let rapid = &events[0];
    let x = rapid["point_mm"][0].as_f64().expect("number");
    assert!(x.abs() <= 0.25 + 1e-3, "{rapid}");
    assert!(
        (rapid["depth_mm"].as_f64().expect("number") - 5.0).abs() < 1e-6,
        "{rapid}"
    );
    // The shank's overlap: 2 mm deep (tip at −12, flutes 20 mm, shank from z = 8 to 10).
    let shank = &events[1];
    assert!(
        (shank["depth_mm"].as_f64().expect("number") - 2.0).abs() < 1e-6,
        "{shank}"
    );
    assert_eq!(shank["part"], "shank");
}

#[test]
fn simulate_mesh_stock_cuts_like_the_box_it_describes() {
    let sb = Sandbox::new("sim-mesh-stock");
    // The box [−20, 20] × [−5, 5] × [−10, 10] turned 90° about x ((x, y, z) ↦ (x, −z, y))
    // and moved by (20, 0, 5) is the stock [0, 40] × [−10, 10] × [0, 10].
    let blank = box_obj([-20.0, -5.0, -10.0], [20.0, 5.0, 10.0]);
    let stock = "kind = \"mesh\"\nfile = \"blank.obj\"\nposition = [20.0, 0.0, 5.0]\nrotation_deg = [90.0, 0.0, 0.0]\npitch_mm = 0.25";
    let program = "G21 G90\nG0 X-10 Y0 Z60\nG0 Z5\nG1 X50 F600\nG0 Z60\nM30\n";
    let (code, report, stderr) = simulate_in(
        &sb,
        &xyz_scene(FLAT6, stock, ""),
        program,
        &[("blank.obj", &blank)],
    );
    assert_eq!(code, 0, "{stderr}");
    // A 6 × 5 slot through the 40 mm length; the blank is 40 × 20 × 10.
    let removed = report["stock"]["removed_mm3"].as_f64().expect("number");
    let left = report["stock"]["volume_mm3"].as_f64().expect("number");
    assert!((removed - 40.0 * 6.0 * 5.0).abs() < 1e-6, "{removed}");
    assert!(
        (removed + left - 40.0 * 20.0 * 10.0).abs() < 1e-6,
        "{}",
        removed + left
    );
}

/// Signed distance of a point on the cut slot part to the slot design with floor
/// `design_floor` (≤ the part's floor 14): inside the design's slot void the distance to its
/// floor or nearer wall, else 0 (the part's other faces lie on the design's).
fn slot_distance(p: &Point3, design_floor: Real) -> Real {
    if p.y > 12.0 && p.y < 18.0 && p.z > design_floor && p.z < 20.0 {
        (p.z - design_floor).min(p.y - 12.0).min(18.0 - p.y)
    } else {
        0.0
    }
}

#[test]
fn simulate_maps_the_deviation_from_a_design_mesh() {
    let pitch = 0.25;
    let stock = format!("min = [0.0, 0.0, 0.0]\nmax = [40.0, 30.0, 20.0]\npitch_mm = {pitch}");
    // A Ø6 flat end mill cuts the slot y 12..18, floor z = 14, straight through along x.
    let program = "G21 G90\nG0 X-10 Y15 Z60\nG0 Z14\nG1 X50 F600\nG0 Z60\nM30\n";
    for (tag, design_floor) in [("exact", 14.0), ("offset", 13.9)] {
        let sb = Sandbox::new(&format!("sim-design-{tag}"));
        let design = solids_collisions_deviation::slot_design_obj(design_floor);
        let scene = xyz_scene(FLAT6, &stock, "[design]\nfile = \"design.obj\"");
        let (code, report, stderr) = simulate_in(&sb, &scene, program, &[("design.obj", &design)]);
        assert_eq!(code, 0, "{stderr}");
        let d = &report["deviation"];
        let (max, min, rms) = (
            d["max_mm"].as_f64().expect("max"),
            d["min_mm"].as_f64().expect("min"),
            d["rms_mm"].as_f64().expect("rms"),
        );
        // The same part, cut through the library; the distances from the analytic design.
        let s = Scene::load(&sb.dir.join("s.toml")).expect("scene");
        let prog = s.load_program().expect("program");
        let mut stock = twinmill::pipeline::make_stock(&s).expect("stock");
        sweep_program(
            &mut stock,
            &s.chain,
            &s.tool,
            &prog.moves,
            &s.sweep,
            &NoProgress,
        )
        .expect("sweep");
        let mut dist = Vec::new();
        for g in stock.grids() {
            g.for_each_crossing(|p, _| dist.push(slot_distance(&p, design_floor)));
        }
        assert_eq!(d["points"].as_u64(), Some(dist.len() as u64));
        let want_max = dist.iter().copied().fold(Real::NEG_INFINITY, Real::max);
        let want_rms = (dist.iter().map(|x| x * x).sum::<Real>() / dist.len() as Real).sqrt();
        assert!(
            (max - want_max).abs() < 1e-9,
            "{tag}: max {max} vs {want_max}"
        );
        assert!(
            (rms - want_rms).abs() < 1e-9,
            "{tag}: rms {rms} vs {want_rms}"
        );
        assert!(min > -1e-9, "{tag}: no gouge expected, min {min}");
        assert!(
            (want_max - (14.0 - design_floor)).abs() < 1e-9,
            "{tag}: {want_max}"
        );
        let png =
            std::fs::read(sb.dir.join("out/t-simulate/deviation.png")).expect("deviation.png");
        assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
    }
}

/// Runs `simulate` on a broken scene or program and checks the failure is clean: non-zero
/// exit, one line naming what is expected, nothing written.
fn check_bad_simulate(
    name: &str,
    scene: &str,
    program: &str,
    files: &[(&str, &str)],
    expect: &[&str],
) {
    let sb = Sandbox::new(&format!("bad-sim-{name}"));
    let (code, report, stderr) = simulate_in(&sb, scene, program, files);
    assert_ne!(code, 0, "{name}: should fail");
    assert!(report.is_null(), "{name}: printed a report");
    assert!(!stderr.contains("panicked"), "{name}: panicked: {stderr}");
    assert_eq!(
        stderr.trim_end().lines().count(),
        1,
        "{name}: one line expected: {stderr}"
    );
    for e in expect {
        assert!(stderr.contains(e), "{name}: '{e}' not in: {stderr}");
    }
    let leftovers: Vec<_> = std::fs::read_dir(sb.dir.join("out"))
        .map(|d| d.flatten().map(|e| e.path()).collect())
        .unwrap_or_default();
    assert!(leftovers.is_empty(), "{name}: left {leftovers:?}");
}

#[test]
fn simulate_refuses_bad_tools_stocks_meshes_and_numbers() {
    let stock = "min = [0.0, -10.0, 0.0]\nmax = [40.0, 10.0, 10.0]\npitch_mm = 0.25";
    let program = "G21 G90\nG0 X-10 Y0 Z5\nG1 X50 F600\nM30\n";
    let bad_tool = |name: &str, tool: &str, expect: &[&str]| {
        check_bad_simulate(name, &xyz_scene(tool, stock, ""), program, &[], expect);
    };
    for d in ["0.0", "-6.0", "nan"] {
        bad_tool(
            &format!("diameter{d}"),
            &FLAT6.replace("6.0", d),
            &["s.toml:", "diameter_mm must be"],
        );
    }
    bad_tool(
        "corner-radius",
        "kind = \"bull_nose\"\ndiameter_mm = 6.0\ncorner_radius_mm = 3.5\nlength_mm = 20.0",
        &["s.toml:", "corner"],
    );
    bad_tool(
        "holder-incomplete",
        &format!("{FLAT6}\nshank_diameter_mm = 6.0"),
        &["s.toml:", "tool.shank_length_mm is missing"],
    );
    // Holder sections: every bad value names its section and field.
    let shank = "shank_diameter_mm = 6.0\nshank_length_mm = 10.0";
    let sec = |a: &str, b: &str| {
        format!(
            "holder_sections = [{{ length_mm = 10.0, radius_bottom_mm = 8.0, radius_top_mm = 12.0 }}, {{ length_mm = {a}, radius_bottom_mm = 15.0, radius_top_mm = {b} }}]"
        )
    };
    for (tag, a, b, field) in [
        (
            "len0",
            "0.0",
            "15.0",
            "tool.holder_sections[1].length_mm must be positive",
        ),
        (
            "rneg",
            "20.0",
            "-1.0",
            "tool.holder_sections[1].radius_top_mm must be positive",
        ),
        (
            "rnan",
            "20.0",
            "nan",
            "tool.holder_sections[1].radius_top_mm",
        ),
    ] {
        bad_tool(
            &format!("holder-section-{tag}"),
            &format!("{FLAT6}\n{shank}\n{}", sec(a, b)),
            &["s.toml:", field],
        );
    }
    bad_tool(
        "holder-sections-and-cylinder",
        &format!(
            "{FLAT6}\n{shank}\nholder_diameter_mm = 40.0\n{}",
            sec("20.0", "15.0")
        ),
        &[
            "s.toml:",
            "tool.holder_diameter_mm and tool.holder_sections both describe the holder",
        ],
    );
    bad_tool(
        "holder-sections-no-shank",
        &format!("{FLAT6}\n{}", sec("20.0", "15.0")),
        &["s.toml:", "tool.shank_diameter_mm is missing"],
    );
    bad_tool(
        "holder-sections-empty",
        &format!("{FLAT6}\n{shank}\nholder_sections = []"),
        &["s.toml:", "tool.holder_sections is empty"],
    );
    // A pitch whose tri-dexel cannot fit: the error names the scene key and a pitch that fits.
    check_bad_simulate(
        "pitch",
        &xyz_scene(FLAT6, &stock.replace("0.25", "0.00001"), ""),
        program,
        &[],
        &[
            "s.toml:",
            "stock.pitch_mm",
            "MiB",
            "use a pitch of at least",
        ],
    );
    // A mesh with a hole: the cube without its last triangle.
    let cube = box_obj([0.0; 3], [10.0; 3]);
    let open: String = cube
        .lines()
        .take(8 + 11)
        .map(|l| format!("{l}\n"))
        .collect();
    let mesh_stock = "kind = \"mesh\"\nfile = \"open.obj\"\npitch_mm = 0.25";
    check_bad_simulate(
        "open-stock",
        &xyz_scene(FLAT6, mesh_stock, ""),
        program,
        &[("open.obj", &open)],
        &[
            "s.toml:",
            "stock.file",
            "open.obj",
            "not a closed",
            "for example edge",
            "used by one triangle only",
        ],
    );
    check_bad_simulate(
        "open-fixture",
        &xyz_scene(FLAT6, stock, "[[fixtures]]\nfile = \"open.obj\""),
        program,
        &[("open.obj", &open)],
        &[
            "s.toml:",
            "fixtures[0].file",
            "open.obj",
            "for example edge",
        ],
    );
    check_bad_simulate(
        "open-design",
        &xyz_scene(FLAT6, stock, "[design]\nfile = \"open.obj\""),
        program,
        &[("open.obj", &open)],
        &["s.toml:", "design.file", "open.obj", "for example edge"],
    );
    check_bad_simulate(
        "missing-mesh",
        &xyz_scene(FLAT6, stock, "[design]\nfile = \"nowhere.stl\""),
        program,
        &[],
        &["s.toml:", "design.file", "nowhere.stl", "cannot read"],
    );
    let nan_vertex = cube.replacen("v 0.0 0.0 0.0", "v nan 0.0 0.0", 1);
    check_bad_simulate(
        "nan-vertex",
        &xyz_scene(FLAT6, mesh_stock.replace("open", "nan").as_str(), ""),
        program,
        &[("nan.obj", &nan_vertex)],
        &["s.toml:", "nan.obj:1", "not finite"],
    );
    // Non-finite numbers in the scene.
    check_bad_simulate(
        "nan-stock",
        &xyz_scene(FLAT6, &stock.replace("min = [0.0", "min = [nan"), ""),
        program,
        &[],
        &["s.toml:", "stock.min must have finite components"],
    );
    check_bad_simulate(
        "inf-cylinder",
        &xyz_scene(
            FLAT6,
            "kind = \"cylinder\"\nends = [[0.0, 0.0, 0.0], [inf, 0.0, 0.0]]\nradius_mm = 5.0\npitch_mm = 0.25",
            "",
        ),
        program,
        &[],
        &["s.toml:", "stock.ends must have finite components"],
    );
    check_bad_simulate(
        "nan-fixture-position",
        &xyz_scene(
            FLAT6,
            stock,
            "[[fixtures]]\nfile = \"c.obj\"\nposition = [0.0, nan, 0.0]",
        ),
        program,
        &[("c.obj", &cube)],
        &[
            "s.toml:",
            "fixtures[0].position must have finite components",
        ],
    );
    check_bad_simulate(
        "box-key-on-cylinder",
        &xyz_scene(
            FLAT6,
            &format!("kind = \"cylinder\"\nradius_mm = 5.0\n{stock}"),
            "",
        ),
        program,
        &[],
        &["s.toml:", "stock.min does not apply to a 'cylinder' stock"],
    );
    // Non-finite numbers in the NC program.
    let scene = xyz_scene(FLAT6, stock, "");
    check_bad_simulate(
        "nc-overflow",
        &scene,
        "G21 G90\n#1 = [10 ** 400]\nG1 X#1 F600\nM30\n",
        &[],
        &["p.ngc:3:", "out of range"],
    );
    check_bad_simulate(
        "nc-divide-by-zero",
        &scene,
        "G21 G90\nG1 X[1/0] F600\nM30\n",
        &[],
        &["p.ngc:2:", "divide by zero"],
    );
}

#[test]
fn cli_identify_rejects_inconsistent_input_cleanly() {
    let sb = Sandbox::new("identify-bad");
    sb.write("mdx50-step.ngc", builtin("mdx50-step.ngc").as_bytes());
    let one_line_error = |args: &[&str], words: &[&str], out: &str| {
        let (code, stdout, stderr) = sb.run(args);
        assert_ne!(code, 0, "{args:?}: should fail");
        assert_ne!(code, 2, "{args:?}: an error, not a report");
        assert!(!stderr.contains("panicked"), "{stderr}");
        assert_eq!(stderr.trim_end().lines().count(), 1, "{stderr}");
        for w in words {
            assert!(stderr.contains(w), "'{w}' not in {stderr}");
        }
        assert!(stdout.is_empty(), "{stdout}");
        let left = files_in(&sb.dir.join(out).join("mdx50-step-identify"));
        assert!(left.is_empty(), "half-written output: {left:?}");
    };
    // Only parameters nothing depends on: an error naming them.
    sb.write(
        "nodata.toml",
        identify_scene_text(&["dx_ZS"], "").as_bytes(),
    );
    one_line_error(
        &["identify", "nodata.toml", "--out", "a"],
        &["no data", "dx_ZS"],
        "a",
    );
    // A cloud without the expected faces (a patch far from the part).
    sb.write("s.toml", identify_scene_text(&["dy_AY"], "").as_bytes());
    let mut xyz = String::new();
    for i in 0..40 {
        for j in 0..40 {
            xyz.push_str(&format!("{} {} 500\n", i as f64 * 0.5, j as f64 * 0.5));
        }
    }
    sb.write("elsewhere.xyz", xyz.as_bytes());
    one_line_error(
        &[
            "identify",
            "s.toml",
            "--cloud",
            "elsewhere.xyz",
            "--out",
            "b",
        ],
        &["A0"],
        "b",
    );
    // An unknown parameter name.
    sb.write(
        "unknown.toml",
        identify_scene_text(&["dy_AQ"], "").as_bytes(),
    );
    one_line_error(&["identify", "unknown.toml", "--out", "c"], &["dy_AQ"], "c");
    // A machine the solved set cannot explain (the 1 mm step of dy_AY; only the spindle
    // tilt alpha_ZS solved for): the loop does not converge; the report says so, exit code
    // 2, the reason on stderr.
    sb.write(
        "short.toml",
        identify_scene_text(&["alpha_ZS"], "").as_bytes(),
    );
    let (code, stdout, stderr) = sb.run(&["identify", "short.toml", "--out", "d", "--json"]);
    assert_eq!(code, 2, "{stdout}{stderr}");
    assert!(stderr.contains("did not converge"), "{stderr}");
    let r: serde_json::Value = serde_json::from_str(&stdout).expect("json");
    assert_eq!(r["converged"], serde_json::Value::Bool(false));
    let worst = r["rounds"]
        .as_array()
        .and_then(|x| x.last())
        .and_then(|x| x["worst_face_mm"].as_f64())
        .expect("rounds");
    assert!(worst > 0.05, "the unexplained step stays: {worst}");
}

#[test]
fn cli_design_writes_a_program_and_scene_that_identify_all_nine() {
    let sb = Sandbox::new("design");
    sb.write("s.toml", builtin("mdx50-step.toml").as_bytes());
    sb.write("mdx50-step.ngc", builtin("mdx50-step.ngc").as_bytes());
    let nine = NINE.join(",");
    let (code, stdout, stderr) = sb.run(&["design", "s.toml", "--params", &nine, "--json"]);
    assert_eq!(code, 0, "{stderr}");
    let r: serde_json::Value = serde_json::from_str(&stdout).expect("json");
    assert_eq!(r["singular_values"].as_array().map(Vec::len), Some(9));
    let notes = r["notes"].as_array().expect("notes");
    assert!(notes.iter().any(|n| {
        n.as_str()
            .is_some_and(|n| n.starts_with("beta_XZ − beta_ZS"))
    }));
    let dir = sb.dir.join("out/mdx50-step-design");
    let ngc = std::fs::read_to_string(dir.join("design.ngc")).expect("design.ngc");
    assert!(ngc.starts_with("%\n") && ngc.trim_end().ends_with("%"));
    // The cuts the report lists are the program's G1 lines.
    for c in r["cuts"].as_array().expect("cuts") {
        let line = c[2].as_u64().expect("line") as usize;
        let text = ngc.lines().nth(line - 1).expect("the line exists");
        assert!(text.starts_with("G1 ") && text.contains(c[0].as_str().expect("name")));
    }
    // The written scene loads, and names the faces and the nine parameters.
    let scene = Scene::load(&dir.join("design.toml")).expect("the designed scene loads");
    assert_eq!(scene.parameters.len(), 9);
    assert_eq!(scene.faces.len(), r["faces"].as_array().map_or(0, Vec::len));
    scene.load_program().expect("the designed program parses");
    // Bad requests: one line, no files.
    for (args, word) in [
        (
            vec!["design", "s.toml", "--params", "dy_AQ", "--out", "x"],
            "dy_AQ",
        ),
        (
            vec!["design", "missing.toml", "--params", "dy_AY", "--out", "x"],
            "missing.toml",
        ),
    ] {
        let (code, _, stderr) = sb.run(&args);
        assert_ne!(code, 0);
        assert!(
            stderr.contains(word) && !stderr.contains("panicked"),
            "{stderr}"
        );
        assert_eq!(stderr.trim_end().lines().count(), 1, "{stderr}");
        assert!(files_in(&sb.dir.join("x")).is_empty());
    }
}

// ---------------------------------------------------------------------------------------
// One sweep driver: the checked sweep of `simulate` removes exactly what the sweep removes.

/// Every crossing of a stock (point, then its stored data), in grid order.
fn all_crossings(s: &TriDexel) -> Vec<(Point3, twinmill::cutting::stock::Crossing)> {
    let mut out = Vec::new();
    for g in s.grids() {
        g.for_each_crossing(|p, c| out.push((p, *c)));
    }
    out
}

/// The MDX-50 scene with `program` and the tri-dexel at `pitch`, loaded from a sandbox.
fn mdx50_with(sb: &Sandbox, program: &str, pitch: &str, tool: Option<&str>) -> Scene {
    let mut text = builtin("mdx50-step.toml")
        .replace("program = \"mdx50-step.ngc\"", "program = \"p.ngc\"")
        .replace("pitch_mm = 0.1 ", &format!("pitch_mm = {pitch} "));
    if let Some(t) = tool {
        text = text.replace("kind = \"flat\"         # flat | ball", t);
    }
    sb.write("s.toml", text.as_bytes());
    sb.write("p.ngc", program.as_bytes());
    Scene::load(&sb.dir.join("s.toml")).expect("scene")
}

/// Cutting while A turns, arcs, a collinear run split in three, rapids through material and
/// a holder that dips into the stock: the checked sweep's stock equals the plain sweep's bit
/// for bit (every crossing's point, normal and NC line), with the same sweep report, for a
/// flat end mill (rotary moves cut by the envelope) and a bull-nose (cut in sub-steps); and
/// one or two threads give the same events and stock.
#[test]
fn checked_sweep_removes_exactly_what_the_sweep_removes() {
    use twinmill::cutting::collide::{Holder, HolderSection, sweep_with_checks};
    let program = "G21 G90 G17\nG0 Z60 A0\nG0 X-30 Y-25\nG0 Z5\n\
        G1 X-10 F600\nG1 X0\nG1 X10\n\
        G3 X20 Y-15 I0 J10\nG3 X10 Y-5 I-10 J0\n\
        G1 Z2\nG1 A30 F600\nG1 X-10 A45\nG0 A60\nG0 X-25 Y-20\n\
        G1 Y-10 Z0\nG0 Z60\nG0 A0\nM30\n";
    let holder = Holder::try_sections(
        4.0,
        10.0,
        &[
            HolderSection {
                length: 3.0,
                radius_bottom: 8.0,
                radius_top: 12.0,
            },
            HolderSection {
                length: 5.0,
                radius_bottom: 15.0,
                radius_top: 15.0,
            },
        ],
    )
    .expect("holder");
    for (tag, tool, bound) in [
        ("flat", None, 1e-4),
        (
            "bull",
            Some("kind = \"bull_nose\"\ncorner_radius_mm = 1.0"),
            2e-2,
        ),
    ] {
        let sb = Sandbox::new(&format!("one-driver-{tag}"));
        let mut s = mdx50_with(&sb, program, "0.6", tool);
        s.sweep.rotary_step_bound_mm = bound;
        let prog = s.load_program().expect("program");
        assert!(
            prog.moves
                .iter()
                .any(|m| matches!(m.kind, MoveKind::Arc(_))),
            "the program has arcs"
        );
        let mut plain = twinmill::pipeline::make_stock(&s).expect("stock");
        let v0 = plain.volume();
        let rep = sweep_program(
            &mut plain,
            &s.chain,
            &s.tool,
            &prog.moves,
            &s.sweep,
            &NoProgress,
        )
        .expect("sweep");
        assert!(rep.rotary_moves >= 3 && rep.cutting_moves >= 6, "{rep:?}");
        assert!(plain.volume() < v0 - 100.0, "the program cuts");
        let checked = |threads| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("pool");
            pool.install(|| {
                let mut stock = twinmill::pipeline::make_stock(&s).expect("stock");
                let r = sweep_with_checks(
                    &mut stock,
                    &s.chain,
                    &s.tool,
                    Some(&holder),
                    &[],
                    &prog.moves,
                    &s.sweep,
                    &NoProgress,
                )
                .expect("checked sweep");
                (stock, r)
            })
        };
        let (stock, r) = checked(1);
        assert_eq!(r.sweep, rep, "{tag}: same sweep report");
        let want = all_crossings(&plain);
        assert!(
            all_crossings(&stock) == want,
            "{tag}: the checked sweep's stock differs from the sweep's"
        );
        // Rapids through material (G0 A60 and G0 X-25 Y-20 at Z2 inside the blank) are seen.
        assert!(
            r.events
                .iter()
                .any(|e| e.kind == twinmill::cutting::collide::EventKind::RapidThroughMaterial),
            "{tag}: {:?}",
            r.events
        );
        assert!(r.check_error_bound_mm > 0.0 && r.check_error_bound_mm <= bound.max(1e-3));
        let (stock2, r2) = checked(2);
        assert_eq!(r2, r, "{tag}: events depend on the thread count");
        assert!(all_crossings(&stock2) == want, "{tag}: 2 threads");
    }
}

/// Arcs become chords: the report states their error, the largest distance of an arc point
/// from its chord, which is the sagitta r·(1 − cos(θ/2)) of the chord spanning θ; measured
/// here on points of the arc against the chords the sweep cut.
#[test]
fn sweep_report_states_the_chord_sagitta_of_arcs() {
    let sb = Sandbox::new("chord-sagitta");
    // A quarter circle of radius 10 about (10, -15) and a half circle of radius 4.
    let program = "G21 G90 G17\nG0 Z60\nG0 X10 Y-25\nG0 Z5\nG3 X20 Y-15 I0 J10 F600\n\
        G3 X12 Y-15 I-4 J0\nG0 Z60\nM30\n";
    let mut s = mdx50_with(&sb, program, "0.5", None);
    let bound = 2e-3;
    s.sweep.rotary_step_bound_mm = bound;
    let prog = s.load_program().expect("program");
    let mut stock = twinmill::pipeline::make_stock(&s).expect("stock");
    let rep = sweep_program(
        &mut stock,
        &s.chain,
        &s.tool,
        &prog.moves,
        &s.sweep,
        &NoProgress,
    )
    .expect("sweep");
    // Independently: the chords' ends in axis space and each arc's centre and radius.
    let arcs: [([Real; 2], Real, Real, Real); 2] = [
        // (centre, radius, start angle, end angle) — clockwise quarter from -90° to 0°.
        ([10.0, -15.0], 10.0, -PI_2, 0.0),
        // Counter-clockwise half from 0° to 180°.
        ([16.0, -15.0], 4.0, 0.0, std::f64::consts::PI),
    ];
    let mut worst: Real = 0.0;
    let arc_moves: Vec<&Move> = prog
        .moves
        .iter()
        .filter(|m| matches!(m.kind, MoveKind::Arc(_)))
        .collect();
    assert_eq!(arc_moves.len(), 2);
    for (m, (c, r, a0, a1)) in arc_moves.iter().zip(arcs) {
        let chords: Vec<Move> = m.chords(bound).collect();
        let xy = |q: &AxisValues| [q.get(AxisLetter::X), q.get(AxisLetter::Y)];
        let n = 20_000;
        let mut arc_worst: Real = 0.0;
        for i in 0..=n {
            let phi = a0 + (a1 - a0) * i as Real / n as Real;
            let p = [c[0] + r * phi.cos(), c[1] + r * phi.sin()];
            // Distance to the nearest chord segment.
            let d = chords
                .iter()
                .map(|ch| {
                    let (a, b) = (xy(&ch.start), xy(&ch.end));
                    let (ux, uy) = (b[0] - a[0], b[1] - a[1]);
                    let t = (((p[0] - a[0]) * ux + (p[1] - a[1]) * uy) / (ux * ux + uy * uy))
                        .clamp(0.0, 1.0);
                    (p[0] - a[0] - t * ux).hypot(p[1] - a[1] - t * uy)
                })
                .fold(Real::INFINITY, Real::min);
            arc_worst = arc_worst.max(d);
        }
        // The formula, from the chord count and the arc's angle.
        let theta = (a1 - a0).abs() / chords.len() as Real;
        let sagitta = r * (1.0 - (theta / 2.0).cos());
        assert!(
            (arc_worst - sagitta).abs() < 1e-6,
            "{arc_worst} vs {sagitta}"
        );
        worst = worst.max(sagitta);
    }
    assert!(worst <= bound && worst > bound / 4.0, "{worst}");
    assert!(
        (rep.chord_error_bound_mm - worst).abs() < 1e-12,
        "reported {} vs {worst}",
        rep.chord_error_bound_mm
    );
    assert!(rep.error_bound_mm >= rep.chord_error_bound_mm);
    assert_eq!(rep.rotary_error_bound_mm, 0.0);
}

const PI_2: Real = std::f64::consts::FRAC_PI_2;
