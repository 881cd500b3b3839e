//! Stock from solids (cylinder, closed meshes), collision events and the deviation map,
//! through the library.

use crate::{aabb, fan, obj, prism};
use std::f64::consts::PI;
use std::path::Path;
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
                assert!((segs[0].lo.t + half).abs() < 1e-9 && (segs[0].hi.t - half).abs() < 1e-9);
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
    Chain::cartesian([AxisLetter::Y, AxisLetter::X, AxisLetter::Z]).expect("chain")
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
    sweep_with_checks(&mut s, &xyz(), &tool, None, &[], &moves, &OPTS, &NoProgress).expect("runs");
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
