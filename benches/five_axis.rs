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
//! - **Hexapod side cut**: the hexapod machining centre (`benches/data/hexapod-side-cut.toml`,
//!   the machine of `scenes/hexapod-machining-centre.toml` with a flat Ø6 × 25 mm end mill)
//!   circling a Ø40 mm cylinder, its tool tilted ±8° three times a turn: a quarter turn
//!   (180 moves), every move sampled at 65 poses and cut by the envelope of the curve through them.
//!
//! - **Deviation colours**: the flat side cut's first turn, its display mesh (about 100 k
//!   triangles) coloured by the deviation from the nominal part, read near the cut part
//!   from the program on the nominal machine (no second sweep); triangles per second.
//!
//! The programs are those of `benches/support/five_axis.rs`, which also writes them as the NC
//! of the scenes in `benches/data/` for timing the whole `twinmill simulate` command.

use criterion::{BatchSize, Criterion, Throughput, criterion_main};
use std::path::Path;
use twinmill::cutting::shape::Cylinder;
use twinmill::cutting::stock::TriDexel;
use twinmill::cutting::sweep::{Kinematics, sweep_program};
use twinmill::cutting::tool::{Tool, ToolKind};
use twinmill::math::{Aabb, Point3, Real, Vector3};
use twinmill::progress::NoProgress;
use twinmill::scene::{Machine, MemoryBudget, Scene};
use twinmill::{cutting, machine, math, nc};

#[path = "support/five_axis.rs"]
mod five_axis;
#[path = "support/rotary.rs"]
mod rotary;
use five_axis::{FEED, blade, hexapod_side, side_cut};
use rotary::polyline;

const SCENE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/trunnion-ac.toml");
const HEXAPOD: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/benches/data/hexapod-side-cut.toml"
);
const PITCH: Real = 0.1;

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

    let moves = polyline(&side_cut(720), FEED);
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
                            scene.chain(),
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

    let moves = polyline(&blade(&scene.chain().nominal(), ball.radius(), 720), FEED);
    g.throughput(Throughput::Elements(moves.len() as u64));
    g.bench_function(
        format!("blade-like finishing, ball, {PITCH} mm, 720 moves (moves)"),
        |b| {
            b.iter_batched(
                || cylinder(PITCH),
                |mut stock| {
                    sweep_program(
                        &mut stock,
                        scene.chain(),
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

    // The deviation colours of the flat side cut's first turn: the part cut and its display
    // mesh made outside the timing; timed, the nominal part read at the display's corners
    // (the program on the nominal machine, no second sweep).
    let moves = polyline(&side_cut(720), FEED);
    let mut part = twinmill::pipeline::make_stock(&scene).expect("stock");
    sweep_program(
        &mut part,
        scene.chain(),
        &scene.tool,
        &moves,
        &scene.sweep,
        &NoProgress,
    )
    .expect("sweeps");
    let (mesh, _) = twinmill::cutting::adaptive::mesh_stock_adaptive(&part, &Default::default())
        .expect("meshes");
    let shown =
        twinmill::report::display::simplify(&mesh, twinmill::report::display::MAX_TRIANGLES);
    g.throughput(Throughput::Elements(shown.triangles.len() as u64));
    g.bench_function(
        format!(
            "trunnion side cut, flat, first turn: deviation colours of {} display triangles (triangles)",
            shown.triangles.len()
        ),
        |b| {
            b.iter(|| {
                let reference = twinmill::pipeline::pages::reference_part(&scene, &moves)
                    .expect("reference");
                reference.model.expect("a deviated machine").deviations(&shown, &part)
            })
        },
    );

    let hexapod = Scene::load_hexapod_cut(Path::new(HEXAPOD), &MemoryBudget::installed())
        .expect("hexapod scene");
    let Machine::Hexapod(h) = &hexapod.machine else {
        panic!("a hexapod scene")
    };
    let twin = h.twin.clone();
    let moves = polyline(&hexapod_side(180), FEED);
    g.throughput(Throughput::Elements(moves.len() as u64));
    g.bench_function(
        format!(
            "hexapod side cut, flat, {} mm, 180 moves (moves)",
            hexapod.pitch_mm
        ),
        |b| {
            b.iter_batched(
                || twinmill::pipeline::make_stock(&hexapod).expect("stock"),
                |mut stock| {
                    sweep_program(
                        &mut stock,
                        Kinematics::Poses(&twin),
                        &hexapod.tool,
                        &moves,
                        &hexapod.sweep,
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
