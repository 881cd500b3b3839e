//! Benchmark of general identification: the nine deviations of seed 002 Fig. 3 from the
//! test cuts `twinmill design` proposes for them on the built-in MDX-50 scene.
//!
//! `cargo bench --bench identify`. Setup (not timed): design the cuts, write the designed
//! scene and program to a temporary folder, cut them on a machine with all nine deviations
//! set (offsets 0.2–0.4 mm, angles 1–4e-4 rad), scan with the scene's EinScan-class
//! scanner (four turntable views, σ 0.025 mm, pitch 0.185 mm). Timed:
//!
//! * `identify (solve)`: identifiability analysis, Levenberg–Marquardt in the determined
//!   subspace with the registration, uncertainties, and the model-correction loop, from
//!   the fitted faces;
//! * `identify (fit + solve)`: the same, starting from the scanned cloud (face selection
//!   and robust plane fits of the faces included).
//!
//! Also the rotary axes' location errors from a ball-sensor test (`rotary location`) and a
//! serial machine from three laser runs and three ball-bar circles (`instruments`).

use criterion::{Criterion, criterion_group, criterion_main};
use std::hint::black_box;
use std::path::Path;
use twinmill::calibration::design::{DesignOptions, design};
use twinmill::metrology::scan::Surface;
use twinmill::pipeline::{correction_loop, extract_features, machine_part};
use twinmill::progress::NoProgress;
use twinmill::scene::{Scene, design_scene_toml};

const NINE: [(&str, f64); 9] = [
    ("dy_AY", -0.4),
    ("dz_AY", 0.2),
    ("beta_AY", 1e-4),
    ("gamma_AY", -2e-4),
    ("alpha_YX", 3e-4),
    ("gamma_YX", 1e-4),
    ("beta_XZ", -4e-4),
    ("alpha_ZS", 2e-4),
    ("beta_ZS", -3e-4),
];

fn benches(c: &mut Criterion) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/mdx50-step.toml");
    let mut base = Scene::load(&path).expect("scene");
    let m = base.serial_mut().expect("a serial machine");
    for (n, v) in NINE {
        let id = m.chain.deviation_id(n).expect("known");
        m.chain.set_deviation(id, v);
        m.injected.insert(n.into(), v);
    }
    let ids: Vec<_> = NINE
        .iter()
        .map(|(n, _)| base.model().deviation_id(n).expect("known"))
        .collect();
    let opts = DesignOptions::standard();
    let d = design(base.model(), &base.tool, &ids, &opts).expect("design");
    let params: Vec<String> = NINE.iter().map(|(n, _)| n.to_string()).collect();
    let toml = design_scene_toml(&base, &d, &opts, &params, "bench-design", "bench.ngc")
        .expect("the scene has a [scanner]");
    let dir = std::env::temp_dir().join(format!("twinmill-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    std::fs::write(dir.join("bench.ngc"), &d.program).expect("program");
    std::fs::write(dir.join("bench.toml"), &toml).expect("scene");
    let scene = Scene::load(&dir.join("bench.toml")).expect("designed scene");
    let program = scene.load_program().expect("program");
    let part = machine_part(&scene, &program, &NoProgress).expect("part");
    let cloud = Surface::new(&part.stock)
        .scan(
            scene
                .scanner
                .as_ref()
                .expect("the built-in scene has a [scanner]"),
            &NoProgress,
        )
        .expect("scan")
        .cloud;
    let _ = std::fs::remove_dir_all(&dir);
    let features = extract_features(&scene, &program, &cloud.points, None).expect("features");
    let solve = || {
        correction_loop(
            scene.model(),
            &ids,
            &scene.tool,
            black_box(&features),
            scene.registration,
            scene.loop_tolerance_mm,
            None,
        )
        .expect("identifies")
    };
    solve();

    let mut g = c.benchmark_group("identify");
    g.sample_size(20);
    g.bench_function(
        format!(
            "identify (solve, nine deviations, {} faces)",
            features.len()
        ),
        |b| b.iter(solve),
    );
    g.bench_function(
        format!("identify (fit + solve, {} points)", cloud.points.len()),
        |b| {
            b.iter(|| {
                let f = extract_features(&scene, &program, black_box(&cloud.points), None)
                    .expect("features");
                correction_loop(
                    scene.model(),
                    &ids,
                    &scene.tool,
                    &f,
                    scene.registration,
                    scene.loop_tolerance_mm,
                    None,
                )
                .expect("identifies")
            })
        },
    );
    g.finish();
}

/// `identify (rotary location …)`: the eight ISO 230-7 location errors of the trunnion A/C
/// machine (`scenes/trunnion-ac.toml`) and its table's two unseen terms, with the sphere's
/// position, from the default ISO 10791-6 test read by the ball sensor (46 ball centres):
/// identifiability, Levenberg–Marquardt and uncertainties. Setup (the test on the twin) is
/// not timed.
fn rotary_location(c: &mut Criterion) {
    use twinmill::calibration::calibrate::{IsoTerm, Model, Registration, ball_features, identify};
    use twinmill::cutting::tool::{Tool, ToolKind};
    use twinmill::metrology::ball_sensor::BallSensor;
    use twinmill::metrology::rotary_test::{default_sweeps, sensor_test};
    use twinmill::pipeline::default_setup;
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/trunnion-ac.toml");
    let scene = Scene::load(&path).expect("scene");
    let sweeps = default_sweeps(scene.chain());
    let setup = default_setup(1);
    let samples = sensor_test(
        scene.chain(),
        scene.model(),
        &BallSensor::seed003(8.0),
        1.0,
        &setup,
        &sweeps,
    )
    .expect("trace");
    let features = ball_features(&samples, setup.tool_offset, 0);
    let terms: Vec<IsoTerm> = scene
        .model()
        .rotary_location_terms()
        .iter()
        .map(|n| IsoTerm::parse(scene.model(), n).expect("term"))
        .collect();
    let tool = Tool::try_new(ToolKind::Ball, 1.0, 1.0).expect("tool");
    let model = Model {
        chain: scene.model(),
        ids: &[],
        iso_terms: &terms,
        tool: &tool,
        features: &features,
        registration: Registration::Workpiece,
    };
    let mut g = c.benchmark_group("identify");
    g.bench_function(
        format!(
            "identify (rotary location, {} terms, {} ball centres)",
            terms.len(),
            features.len()
        ),
        |b| b.iter(|| identify(black_box(&model)).expect("identifies")),
    );
    g.finish();
}

/// A serial machine from its instruments (`identify --measurement`): the error motions,
/// squareness and lost motions of `scenes/xyz-error-motions.toml` (every term the scene
/// models, 12 parameters, and 6 ball-bar centre unknowns) from three laser runs (X, Y, Z:
/// 36 targets, 5 bidirectional runs, 360 readings each) and three ball-bar circles (XY, YZ,
/// ZX: radius 20 mm, one counter-clockwise turn of 360 samples each), σ 0.5 µm.
/// Timed: the model set-up, identifiability, Levenberg–Marquardt, uncertainties and the
/// fit check ([`twinmill::calibration::instruments::identify`]); the readings (not timed)
/// are simulated on the scene's machine.
fn instruments(c: &mut Criterion) {
    use twinmill::calibration::instruments::{Measurement, identify, scene_parameters};
    use twinmill::metrology::ballbar::{self, BallBarSetup, Plane, Turns};
    use twinmill::metrology::interferometer::{self, LaserSetup, Targets};
    use twinmill::nc::{AxisLetter, AxisValues};
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/xyz-error-motions.toml");
    let scene = Scene::load(&path).expect("scene");
    let chain = scene.chain();
    let at = AxisValues::default()
        .with(AxisLetter::X, 30.0)
        .with(AxisLetter::Y, 20.0)
        .with(AxisLetter::Z, 30.0);
    let mut set = Vec::new();
    for (k, (axis, to)) in [
        (AxisLetter::X, 60.0),
        (AxisLetter::Y, 40.0),
        (AxisLetter::Z, 50.0),
    ]
    .into_iter()
    .enumerate()
    {
        let mut s = LaserSetup::new(
            axis,
            Targets::Even {
                start_mm: 0.0,
                end_mm: to,
                count: 36,
            },
            at,
        );
        s.abbe_offset_mm = twinmill::math::Vector3::new(0.0, 0.0, 30.0);
        s.noise_um = 0.5;
        s.seed = 1 + k as u64;
        let readings = interferometer::measure(chain, &s).expect("laser").readings;
        assert_eq!(readings.len(), 360);
        set.push(Measurement::Laser {
            name: format!("laser-{}", axis.as_char()),
            setup: s,
            readings,
        });
    }
    for (k, plane) in [Plane::Xy, Plane::Yz, Plane::Zx].into_iter().enumerate() {
        let mut s = BallBarSetup::new(plane, at, 20.0);
        s.turns = Turns::Ccw;
        s.points = 360;
        s.noise_um = 0.5;
        s.seed = 10 + k as u64;
        let samples = ballbar::measure(chain, &s).expect("ball bar").samples;
        assert_eq!(samples.len(), 360);
        set.push(Measurement::BallBar {
            name: format!("ballbar-{}", plane.name()),
            setup: s,
            samples,
        });
    }
    let params = scene_parameters(chain, scene.injected()).expect("parameters");
    let mut g = c.benchmark_group("identify");
    g.bench_function(
        format!(
            "identify (instruments: {} parameters, 3 laser runs + 3 ball-bar circles × 360)",
            params.len()
        ),
        |b| {
            b.iter(|| {
                identify(black_box(chain), params.clone(), black_box(set.clone()))
                    .expect("identifies")
            })
        },
    );
    g.finish();
}

// criterion_group! generates an undocumented public function: keep it in a private module.
mod group {
    use super::*;
    criterion_group!(identify, benches, rotary_location, instruments);
}
criterion_main!(group::identify);
