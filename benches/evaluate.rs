//! Benchmark of the ISO 230-2 evaluation (`metrology::positioning`): 10,000 readings — 100
//! targets, 10 runs each way — from a fixed sequence, and the same readings read from the
//! long CSV layout first.
//!
//! And of the ISO 230-4 evaluation (`metrology::circular`): a 360-point ball-bar circle in
//! each direction with squareness, scale mismatch, backlash and noise.
//!
//! And of the virtual instruments on the chain of `scenes/xyz-error-motions.toml` (error
//! motions, reversals, squareness): a 360-point ball-bar circle simulated and evaluated, and
//! the laser interferometer's 5-run ISO 230-2 cycle with its evaluation.
//!
//! `cargo bench --bench evaluate`. Goals: ≤ 1 ms for the evaluation of 10,000 readings;
//! ≤ 1 ms for a 360-point circle with its evaluation; ≤ 1 ms for a 360-point ball-bar circle
//! simulated on the chain and evaluated.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use std::hint::black_box;
use std::path::Path;
use twinmill::math::CounterRng;
use twinmill::metrology::circular::{self, CircularOptions, Sample, Turn};
use twinmill::metrology::positioning::{Direction, Reading, evaluate, parse_readings};

/// 100 targets 5 mm apart, 10 runs in each direction: 10,000 readings (mm).
fn readings() -> Vec<Reading> {
    let rng = CounterRng::new(2302);
    let mut out = Vec::with_capacity(10_000);
    for i in 0..100 {
        for (d, direction) in [Direction::Forward, Direction::Backward].iter().enumerate() {
            for run in 1..=10 {
                let k = (i * 20 + d * 10 + run) as u64;
                out.push(Reading {
                    target_mm: 5.0 * i as f64,
                    direction: *direction,
                    run: run as u32,
                    deviation_mm: 0.002 * (i as f64 * 0.1).sin() - 0.003 * d as f64
                        + 0.001 * rng.normal(k),
                });
            }
        }
    }
    out
}

fn bench(c: &mut Criterion) {
    let r = readings();
    let mut text = String::from("target,direction,run,deviation\n");
    for x in &r {
        text.push_str(&format!(
            "{},{},{},{}\n",
            x.target_mm,
            x.direction.sign(),
            x.run,
            x.deviation_mm
        ));
    }
    let path = Path::new("bench.csv");
    let mut g = c.benchmark_group("iso230-2");
    g.throughput(Throughput::Elements(r.len() as u64));
    g.bench_function("evaluate 10,000 readings", |b| {
        b.iter(|| evaluate(black_box(&r), path).expect("complete"))
    });
    g.bench_function("parse and evaluate 10,000 readings (long CSV)", |b| {
        b.iter(|| {
            let r = parse_readings(black_box(&text), path).expect("readable");
            evaluate(&r, path).expect("complete")
        })
    });
    g.finish();
}

/// One 360-point circle of radius 100 mm in `turn`, with 50 µrad squareness, 10 ppm of scale
/// on X, 3 µm of lost motion on X and 0.1 µm noise.
fn circle(turn: Turn) -> Vec<Sample> {
    let rng = CounterRng::new(2304);
    let dir = if turn == Turn::Ccw { 1.0 } else { -1.0 };
    (0..360)
        .map(|i| {
            let t = (i as f64 + 0.5).to_radians();
            let (x, y) = (100.0 * t.cos(), 100.0 * t.sin());
            let ax = x * (1.0 + 10e-6) + 50e-6 * y + 1.5e-3 * (t.sin() * dir).signum();
            Sample {
                turn,
                angle_rad: t,
                deviation_mm: ax.hypot(y) - 100.0 + 1e-4 * rng.normal(i),
            }
        })
        .collect()
}

fn bench_circular(c: &mut Criterion) {
    let ccw = circle(Turn::Ccw);
    let mut both = ccw.clone();
    both.extend(circle(Turn::Cw));
    let opts = CircularOptions {
        radius_mm: 100.0,
        pitch_mm: None,
    };
    let with_pitch = CircularOptions {
        pitch_mm: Some(5.0),
        ..opts
    };
    let path = Path::new("bench.csv");
    let mut g = c.benchmark_group("iso230-4");
    g.bench_function("360-point circle", |b| {
        b.iter(|| circular::evaluate(black_box(&ccw), &opts, path).expect("evaluates"))
    });
    g.bench_function("360-point circle each way, with cyclic terms", |b| {
        b.iter(|| circular::evaluate(black_box(&both), &with_pitch, path).expect("evaluates"))
    });
    g.finish();
}

/// The virtual ball bar and laser on the scene's machine.
fn bench_instruments(c: &mut Criterion) {
    use twinmill::metrology::ballbar::{self, BallBarSetup, Plane, Turns};
    use twinmill::metrology::interferometer::{self, LaserSetup, Targets};
    use twinmill::nc::AxisLetter;
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/xyz-error-motions.toml");
    let scene = twinmill::scene::Scene::load(&path).expect("the built-in scene loads");
    let chain = scene.chain();
    let mut circle = BallBarSetup::new(Plane::Xy, scene.home(), 100.0);
    circle.turns = Turns::Ccw;
    circle.noise_um = 0.1;
    let opts = CircularOptions {
        radius_mm: 100.0,
        pitch_mm: None,
    };
    let both = BallBarSetup {
        turns: Turns::Both,
        ..circle.clone()
    };
    let file = Path::new("bench.csv");
    let mut g = c.benchmark_group("ballbar");
    g.throughput(Throughput::Elements(circle.points as u64));
    g.bench_function(
        "360-point circle simulated on the chain and evaluated",
        |b| {
            b.iter(|| {
                let m = ballbar::measure(chain, black_box(&circle)).expect("measures");
                circular::evaluate(&m.samples, &opts, file).expect("evaluates")
            })
        },
    );
    g.bench_function("360-point circle each way simulated and evaluated", |b| {
        b.iter(|| {
            let m = ballbar::measure(chain, black_box(&both)).expect("measures");
            circular::evaluate(&m.samples, &opts, file).expect("evaluates")
        })
    });
    g.finish();
    let mut laser = LaserSetup::new(
        AxisLetter::X,
        Targets::Even {
            start_mm: 0.0,
            end_mm: 60.0,
            count: 11,
        },
        scene.home(),
    );
    laser.noise_um = 0.5;
    let mut g = c.benchmark_group("laser");
    g.throughput(Throughput::Elements(110));
    g.bench_function("5-run cycle of 11 targets simulated and evaluated", |b| {
        b.iter(|| {
            let m = interferometer::measure(chain, black_box(&laser)).expect("measures");
            evaluate(&m.readings, file).expect("complete")
        })
    });
    g.finish();
}

mod group {
    use super::*;
    criterion_group!(evaluate, bench, bench_circular, bench_instruments);
}
criterion_main!(group::evaluate);
