//! Simultaneous 5-axis benches (`cargo bench --bench five_axis`) on the trunnion A/C scene
//! (`scenes/trunnion-ac.toml` with its rotary-axis location errors, tri-dexel pitch 0.1 mm),
//! every move turning C and A while the tool moves, each cut by the per-ray envelope;
//! moves per second:
//!
//! - **Side cut, flat**: the flat Ø6 × 25 mm end mill at the cube's side (X0 Y−19), C turning
//!   0.5° a move while Z descends 36 mm over 7,200 moves (ten turns) and A oscillates ±8°,
//!   three periods a turn: the first turn (720 moves) from Z40.
//! - **Side cut, ball**: the same turn with a ball Ø6 × 25 mm end mill.
//! - **Blade-like finishing**: a ball Ø6 mm end mill 0.2 mm into a Ø40 mm cylinder on the
//!   C table, C turning 0.25° a move and A oscillating ±5° twice a turn, the axis values
//!   solved on the nominal chain so that the ball's centre follows a helix 0.2 mm inside the
//!   cylinder, descending 0.2 mm a turn: half a turn (720 moves).

use criterion::{BatchSize, Criterion, Throughput, criterion_main};
use std::path::Path;
use twinmill::cutting::shape::Cylinder;
use twinmill::cutting::stock::TriDexel;
use twinmill::cutting::sweep::sweep_program;
use twinmill::cutting::tool::{Tool, ToolKind};
use twinmill::math::{Aabb, Point3, Real, Vector3};
use twinmill::nc::{AxisLetter, AxisValues, Move, MoveKind};
use twinmill::progress::NoProgress;
use twinmill::scene::Scene;

const SCENE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/trunnion-ac.toml");
const PITCH: Real = 0.1;

/// Feed moves through `points`, the k-th move on line k (from 1).
fn polyline(points: &[AxisValues]) -> Vec<Move> {
    points
        .windows(2)
        .enumerate()
        .map(|(k, w)| Move {
            kind: MoveKind::Linear,
            start: w[0],
            end: w[1],
            feed_mm_per_min: Some(2000.0),
            line: k + 1,
        })
        .collect()
}

/// The first `n` of the side cut's 7,200 moves: move k ends at Z = 40 − 36·k/7200,
/// A = 8·sin(1.5·k°), C = 0.5·k°.
fn side_cut(n: usize) -> Vec<Move> {
    let at = |k: usize| {
        let k = k as Real;
        AxisValues::default()
            .with(AxisLetter::X, 0.0)
            .with(AxisLetter::Y, -19.0)
            .with(AxisLetter::Z, 40.0 - 36.0 * k / 7200.0)
            .with(AxisLetter::A, 8.0 * (1.5 * k).to_radians().sin())
            .with(AxisLetter::C, 0.5 * k)
    };
    polyline(&(0..=n).map(at).collect::<Vec<_>>())
}

/// The blade-like path's `n` moves: the machine axes that put the ball's centre (the tool
/// point plus `r` along the tool axis) at radius 22.8 mm from C's line at the angle of C,
/// 35 mm high descending 0.2 mm a turn, with A = 5·sin(2·C); solved on the nominal chain
/// `r_W = RotZ(c)·RotX(a about z = −50)·(x, y, z)` and checked against the scene's chain.
fn blade(scene: &Scene, r: Real, n: usize) -> Vec<Move> {
    let nominal = scene.chain.nominal();
    let pivot = Vector3::new(0.0, 0.0, -50.0);
    let at = |k: usize| {
        let c_deg = 0.25 * k as Real;
        let a_deg = 5.0 * (2.0 * c_deg).to_radians().sin();
        let rz = nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), c_deg.to_radians());
        let rx = nalgebra::Rotation3::from_axis_angle(&Vector3::x_axis(), a_deg.to_radians());
        let phi = c_deg.to_radians() - std::f64::consts::FRAC_PI_2;
        let centre = Vector3::new(
            22.8 * phi.cos(),
            22.8 * phi.sin(),
            35.0 - 0.2 * c_deg / 360.0,
        );
        let axis_w = rz * rx * Vector3::z();
        let tip_w = centre - axis_w * r;
        let v = pivot + rx.inverse() * (rz.inverse() * tip_w - pivot);
        let q = AxisValues::default()
            .with(AxisLetter::X, v.x)
            .with(AxisLetter::Y, v.y)
            .with(AxisLetter::Z, v.z)
            .with(AxisLetter::A, a_deg)
            .with(AxisLetter::C, c_deg);
        let pose = nominal.w_from_t(&q);
        let got = pose * Point3::new(0.0, 0.0, r);
        assert!(
            (got.coords - centre).norm() < 1e-9,
            "the blade path's ball centre lands where it was solved for"
        );
        q
    };
    polyline(&(0..=n).map(at).collect::<Vec<_>>())
}

/// A Ø40 mm cylinder, 40 mm high, on the C table (z from 0), as a tri-dexel at `pitch`.
fn cylinder(pitch: Real) -> TriDexel {
    let c =
        Cylinder::try_new(Point3::origin(), Vector3::z(), 20.0, 40.0).expect("a valid cylinder");
    let bounds = Aabb {
        min: Point3::new(-20.5, -20.5, 0.0),
        max: Point3::new(20.5, 20.5, 40.0),
    };
    TriDexel::from_solid(bounds, pitch, 8e9, &c).expect("fits")
}

fn benches(c: &mut Criterion) {
    let mut scene = Scene::load(Path::new(SCENE)).expect("scene");
    scene.pitch_mm = PITCH;
    let mut g = c.benchmark_group("five_axis");
    g.sample_size(10);

    let moves = side_cut(720);
    g.throughput(Throughput::Elements(moves.len() as u64));
    let ball = Tool::try_new(ToolKind::Ball, 6.0, 25.0).expect("valid");
    for (name, tool) in [("flat", scene.tool.clone()), ("ball", ball.clone())] {
        // The cube is built outside the timing: moves per second of cutting only.
        g.bench_function(
            format!("trunnion side cut, {name}, {PITCH} mm, 720 of 7,200 moves (moves)"),
            |b| {
                b.iter_batched(
                    || twinmill::pipeline::make_stock(&scene).expect("stock"),
                    |mut stock| {
                        sweep_program(
                            &mut stock,
                            &scene.chain,
                            &tool,
                            &moves,
                            &scene.sweep,
                            &NoProgress,
                        )
                        .expect("sweeps")
                    },
                    BatchSize::LargeInput,
                )
            },
        );
    }

    let moves = blade(&scene, ball.radius(), 720);
    g.throughput(Throughput::Elements(moves.len() as u64));
    g.bench_function(
        format!("blade-like finishing, ball, {PITCH} mm, 720 moves (moves)"),
        |b| {
            b.iter_batched(
                || cylinder(PITCH),
                |mut stock| {
                    sweep_program(
                        &mut stock,
                        &scene.chain,
                        &ball,
                        &moves,
                        &scene.sweep,
                        &NoProgress,
                    )
                    .expect("sweeps")
                },
                BatchSize::LargeInput,
            )
        },
    );
    g.finish();
}

mod group {
    criterion::criterion_group!(five_axis, super::benches);
}
criterion_main!(group::five_axis);
