//! Hexapod kinematics benches (`cargo bench --bench hexapod`), on the machining-centre scene
//! (`scenes/hexapod-machining-centre.toml`, a 6-6 platform with its deviations):
//!
//! - **IK**: one closed-form inverse kinematics (six strut lengths), poses per second.
//! - **FK, servo cycle**: forward kinematics from the previous pose, as a controller runs it
//!   each cycle: 4,096 seeded target poses over the workspace (±250 mm, z 150–450 mm, a and
//!   b ±15°, c ±30°), each solved from a start 0.1 mm and 0.01° away; single thread.
//! - **FK, from home**: the same targets solved from the home pose (the cold start).
//! - **FK, batch on all threads**: the servo-cycle batch through
//!   `Hexapod::forward_unchecked_batch` (rayon's pool, fixed chunks of 256); solves per
//!   second on every core.
//! - **DBB calibration**: seed 000's identification from 15 circles × 360 readings
//!   (jig-free) and 7 × 360 (ball plate), readings measured once beforehand.

use criterion::criterion_main;

mod group {
    use criterion::{Criterion, Throughput, criterion_group};
    use std::hint::black_box;
    use std::path::Path;
    use twinmill::machine::hexapod::{Hexapod, Pose, Struts};
    use twinmill::math::{CounterRng, Real};
    use twinmill::scene::HexapodScene;

    const SCENE: &str = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/scenes/hexapod-machining-centre.toml"
    );
    const BATCH: usize = 4096;

    /// Seeded reachable targets, their strut lengths and a start near each.
    fn targets(h: &Hexapod) -> Vec<(Struts, Pose)> {
        let rng = CounterRng::new(5);
        let range = [
            (-250.0, 250.0),
            (-250.0, 250.0),
            (150.0, 450.0),
            (-15.0, 15.0),
            (-15.0, 15.0),
            (-30.0, 30.0),
        ];
        let mut out = Vec::with_capacity(BATCH);
        let mut n = 0u64;
        while out.len() < BATCH {
            n += 1;
            let v: [Real; 6] = std::array::from_fn(|k| {
                range[k].0 + (range[k].1 - range[k].0) * rng.uniform(n, k as u64)
            });
            let pose = Pose::from_mm_deg(v);
            if let Ok(l) = h.inverse(&pose) {
                let near = Pose::from_mm_deg([
                    v[0] + 0.1,
                    v[1] - 0.1,
                    v[2] + 0.1,
                    v[3] + 0.01,
                    v[4] - 0.01,
                    v[5] + 0.01,
                ]);
                out.push((l, near));
            }
        }
        out
    }

    fn kinematics(c: &mut Criterion) {
        let scene = HexapodScene::load(Path::new(SCENE)).expect("scene loads");
        let h = scene.actual.clone();
        let home = scene.home;
        let batch = targets(&h);
        let mut g = c.benchmark_group("hexapod");
        g.throughput(Throughput::Elements(1));
        let pose = Pose::from_mm_deg([40.0, -70.0, 320.0, 8.0, -12.0, 20.0]);
        g.bench_function("ik", |b| b.iter(|| h.strut_lengths(black_box(&pose))));
        g.throughput(Throughput::Elements(BATCH as u64));
        g.bench_function("fk servo cycle, 1 thread", |b| {
            b.iter(|| {
                batch
                    .iter()
                    .map(|(l, near)| h.forward_unchecked(l, near).expect("converges").iterations)
                    .sum::<usize>()
            })
        });
        g.bench_function("fk from home, 1 thread", |b| {
            b.iter(|| {
                batch
                    .iter()
                    .map(|(l, _)| h.forward_unchecked(l, &home).expect("converges").iterations)
                    .sum::<usize>()
            })
        });
        g.bench_function("fk servo cycle, batch over all threads", |b| {
            b.iter(|| {
                h.forward_unchecked_batch(black_box(&batch))
                    .iter()
                    .map(|s| s.as_ref().expect("converges").iterations)
                    .sum::<usize>()
            })
        });
        g.finish();
    }

    /// Seed 000's jig-free calibration: 15 circles × 360 readings measured once on the
    /// deviated machine (σ 0.5 µm), then identified (24 parameters + 45 table-ball
    /// coordinates) per iteration; and the 7-circle ball-plate one.
    fn dbb_calibration(c: &mut Criterion) {
        use twinmill::calibration::hexapod_calibrate::{
            CircleReadings, DEFAULT_POINTS, Procedure, calibrate, default_plan,
        };
        use twinmill::metrology::hexapod_dbb::{DbbInstrument, measure};
        let scene = HexapodScene::load(Path::new(SCENE)).expect("scene loads");
        let ws = scene.workspace.expect("the scene has a workspace");
        let mut g = c.benchmark_group("hexapod dbb calibration");
        g.sample_size(10);
        for procedure in [Procedure::JigFree, Procedure::BallPlate] {
            let plan = default_plan(procedure, &ws, DEFAULT_POINTS);
            let readings: Vec<CircleReadings> = plan
                .circles
                .iter()
                .enumerate()
                .map(|(j, circle)| {
                    let inst = DbbInstrument {
                        mount_mm: twinmill::math::Vector3::zeros(),
                        noise_sigma_mm: 0.5e-3,
                        seed: 1,
                        stream: (j as u64) << 32,
                    };
                    let m =
                        measure(&scene.nominal, &scene.actual, circle, &inst).expect("measurable");
                    CircleReadings {
                        lengths_mm: m.lengths_mm(circle.radius_mm),
                        commands: m.commands,
                    }
                })
                .collect();
            g.throughput(Throughput::Elements(plan.readings() as u64));
            g.bench_function(procedure.name(), |b| {
                b.iter(|| {
                    calibrate(&scene.nominal, &scene.actual, &plan, &readings, 0.5e-3)
                        .expect("solves")
                        .iterations
                })
            });
        }
        g.finish();
    }

    criterion_group!(benches, kinematics, dbb_calibration);
}

criterion_main!(group::benches);
