//! Public behaviour of twinmill, through the library API and the `twinmill` binary. This
//! root holds what several topics share (the built-in scene, the independent 4×4 derivation
//! of the MDX-50 chain, the command-line sandbox, mesh text); each module checks one topic.

mod step;
mod rotary;
mod cli;
mod architecture;
mod correct;
mod identify;
mod tool_shapes;
mod solids_collisions_deviation;
mod simulate;
mod sweep;
mod evaluate;
mod error_motions;
mod instruments;
mod rotary_location;
mod study;
mod hexapod;
mod html;
mod hexapod_calibration;
mod hexapod_probe;
mod hexapod_dbb_probe;
mod hexapod_cut;
mod hexapod_correct;
mod hexapod_controller;
mod verbs;
mod fuzz;
mod robustness;
mod misfit;
mod identify_instruments;
mod axis_comp;
mod iso_names;
mod tcp;
mod design_rotary;
mod identify_combined;

use nalgebra::{Matrix4, Vector4};
use std::path::{Path, PathBuf};
use std::process::Command;
use twinmill::calibration::calibrate::IsoTerm;
use twinmill::calibration::hexapod_calibrate::CircleReadings;
use twinmill::machine::chain::Chain;
use twinmill::machine::hexapod::Hexapod;
use twinmill::math::{Aabb, CounterRng, Point3, Real, Vector3};
use twinmill::metrology::hexapod_dbb::{DbbCircle, DbbInstrument, measure};
use twinmill::metrology::rotary_test::{Setup, Sweep};
use twinmill::metrology::scan::ScannerConfig;
use twinmill::nc::{AxisLetter, AxisValues};
use twinmill::pipeline::{Outcome, run};
use twinmill::progress::NoProgress;
use twinmill::scene::HexapodScene;
use twinmill::scene::Scene;
// `crate::math` and `crate::nc` for the shared P1 benchmark support (`html`).
use twinmill::{math, nc};

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
    let m = scene.serial_mut().expect("a serial machine");
    let id = m.chain.deviation_id(name).expect("known name");
    m.chain.set_deviation(id, value);
    m.injected.insert(name.to_string(), value);
}

// ---------------------------------------------------------------------------------------
// An independent derivation of the exact faces (seed 002 §4): homogeneous 4×4 matrices built
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
    std::array::from_fn(|j| scene.chain().deviations()[j].values)
}

// ---------------------------------------------------------------------------------------
// The nine deviations of the MDX-50 chain that the step experiment and the designed cuts
// identify.

const NINE: [&str; 9] = [
    "dy_AY", "dz_AY", "beta_AY", "gamma_AY", "alpha_YX", "gamma_YX", "beta_XZ", "alpha_ZS",
    "beta_ZS",
];

// ---------------------------------------------------------------------------------------
// The command line: a sandbox directory to run the binary in, and the built-in files.

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

fn files_in(dir: &Path) -> Vec<PathBuf> {
    std::fs::read_dir(dir)
        .map(|d| d.flatten().map(|e| e.path()).collect())
        .unwrap_or_default()
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
// Reported uncertainties against the spread over seeded trials, both ways.

/// Bounds on the RMS of normalised errors `z = (estimate − truth)/σ` over `n` seeded
/// trials, two-sided at `z_q` standard normal quantiles each side. If the reported σ is the
/// estimate's true standard deviation (and the estimate unbiased), `Σz²` follows χ² with `n`
/// degrees of freedom, so `RMS(z) = √(χ²_n/n)` lies between `√(χ²_{n,q}/n)` and
/// `√(χ²_{n,1−q}/n)` but with probability `2q`; the quantiles by Wilson and Hilferty,
/// `χ²_{n,q} ≈ n·(1 − 2/(9n) ± z_q·√(2/(9n)))³` (within 1 % for n ≥ 30, 0.1 % for
/// n = 100). A σ overstated
/// by more than the upper margin — which a one-sided "≥ 95 % within 3σ" passes — fails the
/// lower bound; a σ understated (or a bias) the upper one. The tests use `z_q` = 3.29
/// (2q = 1e-3 per term): for n = 100 the RMS must lie in [0.774, 1.238].
fn rms_z_bounds(n: usize, z_q: Real) -> (Real, Real) {
    let k = 2.0 / (9.0 * n as Real);
    let q = |z: Real| (1.0 - k + z * k.sqrt()).powi(3).sqrt();
    (q(-z_q).max(0.0), q(z_q))
}

/// Per-quantity normalised errors over trials: `z[k]` holds `(estimate − truth)/σ` of
/// quantity `k`, one per trial in which it was valued. Asserts each quantity's RMS(z) lies
/// within [`rms_z_bounds`] for its own count at `z_q` = 3.29, naming the quantity.
fn assert_spread_matches_sigma(names: &[String], z: &[Vec<Real>]) {
    for (name, z) in names.iter().zip(z) {
        assert!(z.len() >= 30, "{name}: only {} trials valued", z.len());
        let rms = (z.iter().map(|x| x * x).sum::<Real>() / z.len() as Real).sqrt();
        let (lo, hi) = rms_z_bounds(z.len(), 3.29);
        assert!(
            (lo..=hi).contains(&rms),
            "{name}: RMS of (estimate − truth)/σ is {rms:.3} over {} trials, outside \
             [{lo:.3}, {hi:.3}]: the reported σ does not match the spread",
            z.len()
        );
    }
}

#[test]
fn the_spread_bounds_are_the_chi_square_quantiles() {
    // The χ² quantiles at 0.0005 and 0.9995 (the regularised incomplete gamma function
    // inverted by bisection: n = 100: 59.896, 153.167; n = 50: 23.461, 89.561; n = 30:
    // 10.804, 62.162), against the Wilson–Hilferty bounds used above.
    for (n, lo, hi, tol) in [
        (100, 59.896, 153.167, 2e-3),
        (50, 23.461, 89.561, 5e-3),
        (30, 10.804, 62.162, 1e-2),
    ] {
        let (a, b) = rms_z_bounds(n, 3.2905);
        let (a, b) = (a * a * n as Real, b * b * n as Real);
        assert!(
            (a / lo - 1.0).abs() < tol && (b / hi - 1.0).abs() < tol,
            "{n}: {a} {b}"
        );
    }
}

// ---------------------------------------------------------------------------------------
// The trunnion's rotary location test (ISO 10791-6), shared by the identification and the
// misfit tests.

fn letter(c: char) -> AxisLetter {
    AxisLetter::from_char(c).expect("letter")
}

/// The trunnion A/C machine of the built-in scene, nominal.
fn trunnion_chain() -> Chain {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/trunnion-ac.toml");
    Scene::parse(&builtin("trunnion-ac.toml"), &path)
        .expect("scene")
        .chain()
        .nominal()
}

/// C turned a full circle at A = 0 and at A = −30°, A swept −60…60° at C = 0, and A and C
/// together (two rotary and three linear axes).
fn rotary_sweeps() -> Vec<Sweep> {
    let at = |a: Real| AxisValues::default().with(letter('A'), a);
    vec![
        Sweep {
            axis: letter('C'),
            from: 0.0,
            to: 330.0,
            positions: 12,
            at: at(0.0),
            also: vec![],
        },
        Sweep {
            axis: letter('C'),
            from: 0.0,
            to: 330.0,
            positions: 12,
            at: at(-30.0),
            also: vec![],
        },
        Sweep {
            axis: letter('A'),
            from: -60.0,
            to: 60.0,
            positions: 9,
            at: at(0.0),
            also: vec![],
        },
        Sweep {
            axis: letter('A'),
            from: -45.0,
            to: 45.0,
            positions: 13,
            at: at(0.0),
            also: vec![(letter('C'), 0.0, 180.0)],
        },
    ]
}

fn setup(seed: u64, mounting: Vector3) -> Setup {
    Setup {
        point_w: Point3::new(60.0, 0.0, 30.0),
        mounting_mm: mounting,
        tool_offset: Vector3::zeros(),
        seed,
    }
}

/// The location terms of the trunnion (the C table's offset along itself and angle zero
/// included, which no table-side test can see).
fn terms(chain: &Chain) -> (Vec<String>, Vec<IsoTerm>) {
    let names = chain.rotary_location_terms();
    let terms = names
        .iter()
        .map(|n| IsoTerm::parse(chain, n).expect("term"))
        .collect();
    (names, terms)
}

/// Random location errors of a trial: offsets uniform in ±50 µm, tilts in ±100 µrad, the
/// two terms no test sees left zero.
fn draw(rng: &CounterRng, trial: u64, names: &[String]) -> Vec<Real> {
    names
        .iter()
        .enumerate()
        .map(|(k, n)| {
            let u = 2.0 * rng.uniform(trial, k as u64) - 1.0;
            match n.as_str() {
                "EZ0C" | "EC0C" => 0.0,
                _ if matches!(n.as_bytes()[1], b'A' | b'B' | b'C') => 100e-6 * u,
                _ => 0.05 * u,
            }
        })
        .collect()
}

fn inject(nominal: &Chain, names: &[String], values: &[Real]) -> Chain {
    let mut actual = nominal.clone();
    // The two terms no test sees are not location errors: never injected (drawn zero).
    for (n, v) in names.iter().zip(values).filter(|(_, v)| **v != 0.0) {
        actual.apply_iso_term(n, *v).expect("known term");
    }
    actual
}

fn mounting(rng: &CounterRng, trial: u64) -> Vector3 {
    Vector3::from_fn(|k, _| 0.2 * (2.0 * rng.uniform(trial, 100 + k as u64) - 1.0))
}

// ---------------------------------------------------------------------------------------
// The hexapod machining centre and its double ball bar, shared by the calibration and the
// misfit tests.

const HEXAPOD_CENTRE: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/scenes/hexapod-machining-centre.toml"
);

fn hexapod_centre() -> HexapodScene {
    HexapodScene::load(Path::new(HEXAPOD_CENTRE)).expect("machining-centre scene loads")
}

/// The bar lengths of `circles` run on `actual` (`nominal` the controller's model), as
/// `calibrate` takes them: circle `j` read with noise σ `noise_sigma_mm` from the seed
/// `seed` on its own stream (`j << 32`), the bar mounted `mount(j)` off its ball.
fn dbb_readings(
    nominal: &Hexapod,
    actual: &Hexapod,
    circles: &[DbbCircle],
    noise_sigma_mm: Real,
    seed: u64,
    mut mount: impl FnMut(usize) -> Vector3,
) -> Vec<CircleReadings> {
    circles
        .iter()
        .enumerate()
        .map(|(j, c)| {
            let inst = DbbInstrument {
                mount_mm: mount(j),
                noise_sigma_mm,
                seed,
                stream: (j as u64) << 32,
            };
            let m = measure(nominal, actual, c, &inst).expect("measurable");
            CircleReadings {
                lengths_mm: m.lengths_mm(c.radius_mm),
                commands: m.commands,
            }
        })
        .collect()
}
