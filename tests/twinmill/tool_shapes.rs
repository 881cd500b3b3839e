//! Tool shapes through the sweep: the closed-form flat/ball sweep and the piecewise cutter
//! agree, and a whole program swept with a bull-nose through a machine chain removes the
//! analytic slot volume.

use twinmill::cutting::cutter::SweptTool;
use twinmill::cutting::stock::{Cutter, TriDexel};
use twinmill::cutting::sweep::{SweepOptions, TranslatedTool, sweep_program};
use twinmill::cutting::tool::{Tool, ToolKind};
use twinmill::machine::chain::{Axis, AxisKind, Chain};
use twinmill::math::{Aabb, CounterRng, Point3, Real, UnitVector3, Vector3};
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
    Chain::cartesian([AxisLetter::X, AxisLetter::Y, AxisLetter::Z]).expect("valid chain")
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
    let vol =
        pi * (a * a * rc + pi * a * rc * rc / 2.0 + 2.0 * rc.powi(3) / 3.0 + r * r * (depth - rc));
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
