//! Unit tests of the adaptive mesh: closed and outward, every crossing within the bound,
//! identical for any thread count, the plane masks against the points one by one.
//!
//! **Invariant:** expected values come from independent derivations, never from the
//! program's output.

use super::p1;
use super::*;
use crate::cutting::mesh::mesh_stock;
use crate::cutting::tool::{Tool, ToolKind};
use crate::math::UnitVector3;
use parry3d_f64::query::PointQuery;

use crate::cutting::mesh::test_parts::{
    STADIUM, closed, cut, cut_along, random_part, stadium_stages, stock,
};

fn adaptive(s: &TriDexel) -> (TriMesh, AdaptiveReport) {
    mesh_stock_adaptive(s, &AdaptiveOptions::default()).expect("meshes")
}

/// Largest distance to the mesh (parry3d's closest point, independent of the mesher)
/// from the crossings the lattice resolves: those on sign-changing lattice edges, the
/// crossing vertices of the dexel-resolution contour ([`mesh_stock`]). With `all`,
/// from every crossing of every ray instead.
fn worst_distance(s: &TriDexel, m: &TriMesh, all: bool) -> Real {
    let shape = parry3d_f64::shape::TriMesh::new(m.vertices.clone(), m.triangles.clone())
        .expect("a valid triangle mesh");
    let mut pts = Vec::new();
    if all {
        for g in s.grids() {
            g.for_each_crossing(|p, _| pts.push(p));
        }
    } else {
        let (fine, r) = mesh_stock(s).expect("meshes");
        pts.extend_from_slice(&fine.vertices[..r.crossing_vertices]);
    }
    let (d, p) = pts
        .par_iter()
        .map(|p| ((shape.project_local_point(p, false).point - p).norm(), *p))
        .reduce(
            || (0.0, Point3::origin()),
            |a, b| if b.0 > a.0 { b } else { a },
        );
    assert!(p.coords.iter().all(|c| c.is_finite()));
    d
}

#[test]
fn a_box_is_twelve_triangles_worth_of_exact_planes() {
    let s = stock([4.0, 3.0, 2.0], 0.25);
    let (m, r) = adaptive(&s);
    assert_eq!(closed(&m), 2);
    // The faces and the sharp edges are exact: the volume is the box's.
    assert!(
        (m.signed_volume() - 24.0).abs() < 1e-9,
        "{}",
        m.signed_volume()
    );
    assert!((m.area() - 52.0).abs() < 1e-9, "{}", m.area());
    for p in &m.vertices {
        let on = (0..3).any(|k| p[k].abs() < 1e-9 || (p[k] - [4.0, 3.0, 2.0][k]).abs() < 1e-9);
        assert!(on, "{p:?}");
    }
    // The dexel-resolution contour has hundreds; here only the corner cells are fine.
    let (fine, _) = mesh_stock(&s).expect("meshes");
    assert!(
        m.triangles.len() * 3 < fine.triangles.len(),
        "{} vs {}",
        m.triangles.len(),
        fine.triangles.len()
    );
    assert!(r.planar_leaves > 0 && r.edge_leaves > 0, "{r:?}");
    assert!(worst_distance(&s, &m, true) < 1e-9);
}

#[test]
fn pocket_groove_hole_and_slot_keep_their_topology_and_volume() {
    let stages = stadium_stages();
    let (m, rep) = adaptive(&stages[0].0);
    assert_eq!(closed(&m), 2);
    // Blind stadium pocket: box minus stadium area × depth. Flat faces and sharp edges
    // are exact; only the curved wall is replaced by planes within the bound.
    let (r, len, depth) = STADIUM;
    let exact = 500.0 - (2.0 * r * len + std::f64::consts::PI * r * r) * depth;
    let wall = 2.0 * (len + std::f64::consts::PI * r) * depth;
    let v = m.signed_volume();
    assert!((v - exact).abs() <= rep.bound_mm * wall, "{v} vs {exact}");
    // Then the ball groove, the through hole and the side slot: topology and bound.
    for (s, euler) in &stages {
        let (m, rep) = adaptive(s);
        assert_eq!(closed(&m), *euler);
        assert!(worst_distance(s, &m, false) <= rep.bound_mm + 1e-9);
    }
}

#[test]
fn random_cuts_always_give_a_closed_oriented_mesh_within_the_bound() {
    // Thin walls, slivers, tiny islands, tilted tools: the topology guarantee holds for
    // any stock, and the bound for every crossing the lattice resolves.
    for case in 0..40u64 {
        let s = random_part(5, case, true);
        let (m, rep) = adaptive(&s);
        m.check_watertight()
            .unwrap_or_else(|e| panic!("case {case}: {e}"));
        assert!(
            m.signed_volume() > 0.0 || s.volume() == 0.0,
            "case {case}: outward"
        );
        let d = worst_distance(&s, &m, false);
        assert!(d <= rep.bound_mm + 1e-9, "case {case}: {d}");
    }
}

#[test]
fn tilted_flat_faces_become_few_triangles_within_the_bound() {
    // A flat end mill tilted 30° about x, run along x: a sloping flat face and a
    // sloping wall, neither on a lattice direction.
    let mut s = stock([12.0, 10.0, 6.0], 0.1);
    let axis = Vector3::new(
        0.0,
        -(30.0f64.to_radians()).sin(),
        30.0f64.to_radians().cos(),
    );
    cut_along(
        &mut s,
        ToolKind::Flat,
        8.0,
        [-2.0, 5.0, 4.5],
        [14.0, 5.0, 4.5],
        axis,
    );
    let (m, rep) = adaptive(&s);
    assert_eq!(closed(&m), 2);
    let (fine, _) = mesh_stock(&s).expect("meshes");
    assert!(
        m.triangles.len() * 10 < fine.triangles.len(),
        "{} vs {}",
        m.triangles.len(),
        fine.triangles.len()
    );
    assert!(rep.planar_leaves > 0, "{rep:?}");
    assert!(worst_distance(&s, &m, false) <= rep.bound_mm + 1e-9);
    // The sloping face is exact: its vertices (crossings and corners) on the plane
    // n·x = n·(tip) through the tool's end face.
    let tip = Vector3::new(0.0, 5.0, 4.5);
    let n = UnitVector3::new_normalize(axis);
    let on_face = m
        .vertices
        .iter()
        .filter(|p| (n.dot(&(p.coords - tip))).abs() < 1e-9)
        .count();
    assert!(on_face >= 4, "{on_face}");
    // Volume against the dexel-resolution contour: equal within the bound over the area.
    let dv = (m.signed_volume() - fine.signed_volume()).abs();
    assert!(dv <= 0.01 * fine.area() * 0.1, "{dv}");
}

#[test]
fn the_p1_pocket_is_small_closed_and_within_the_bound() {
    let mut s = TriDexel::new_box(p1::stock_box(), 0.2, 1e9).expect("fits");
    let tool = Tool::try_new(ToolKind::Flat, p1::TOOL_DIAMETER, 30.0).expect("valid");
    let opts = crate::cutting::sweep::SweepOptions {
        rotary_step_bound_mm: crate::math::tol::ROTARY_STEP_BOUND,
    };
    crate::cutting::sweep::sweep_program(
        &mut s,
        &crate::machine::chain::xyz_for_tests(),
        &tool,
        &p1::moves(),
        &opts,
        &crate::progress::NoProgress,
    )
    .expect("sweeps");
    let (m, rep) = adaptive(&s);
    assert_eq!(closed(&m), 2);
    // Removed volume: 1.5 mm × the 3 mm offset of the path polyline (docs/benchmarks.md),
    // within the bound over the pocket's walls and floor.
    let removed = 100.0 * 100.0 * 20.0 - m.signed_volume();
    let truth = 1.5 * p1::offset_area(3.0);
    assert!((removed - truth).abs() < 0.5, "{removed} vs {truth}");
    assert!(m.triangles.len() < 60_000, "{}", m.triangles.len());
    // Here every crossing of every ray is resolved by the lattice.
    assert!(worst_distance(&s, &m, true) <= rep.bound_mm + 1e-9);
}

#[test]
fn the_mesh_is_identical_on_one_and_two_threads() {
    let mut s = stock([10.0, 8.0, 5.0], 0.1);
    cut(
        &mut s,
        ToolKind::Ball,
        3.0,
        [1.0, 2.0, 4.0],
        [9.0, 6.0, 3.0],
    );
    cut(
        &mut s,
        ToolKind::Flat,
        2.0,
        [2.0, 6.0, 3.5],
        [8.0, 6.0, 3.5],
    );
    let run = |threads| crate::math::in_pool(threads, || adaptive(&s));
    let (a, ra) = run(1);
    let (b, rb) = run(2);
    assert_eq!(a, b);
    assert_eq!(ra, rb);
}

#[test]
fn a_tree_meshed_again_keeps_the_leaves_no_split_touched_and_is_the_same() {
    // After a round in which leaves split, a tree is meshed again keeping the triangles
    // of the leaves no split touched: the mesh and its report must be those of meshing
    // every leaf again. Random parts and a tilted cut (whose sloping faces make leaves
    // fail and split), at least one of them meshed in more than one round.
    let mut parts: Vec<TriDexel> = (0..12u64).map(|case| random_part(5, case, true)).collect();
    let mut s = stock([12.0, 10.0, 6.0], 0.1);
    let axis = Vector3::new(
        0.0,
        -(25.0f64.to_radians()).sin(),
        25.0f64.to_radians().cos(),
    );
    cut_along(
        &mut s,
        ToolKind::Ball,
        6.0,
        [-2.0, 4.0, 4.0],
        [14.0, 6.0, 3.0],
        axis,
    );
    cut_along(
        &mut s,
        ToolKind::Flat,
        4.0,
        [3.0, -2.0, 5.0],
        [9.0, 12.0, 4.0],
        axis,
    );
    parts.push(s);
    let mut rounds = 0;
    for (case, s) in parts.iter().enumerate() {
        let opts = AdaptiveOptions::default();
        let (a, ra) = mesh_adaptive(s, &opts, true).expect("meshes");
        let (b, rb) = mesh_adaptive(s, &opts, false).expect("meshes");
        assert_eq!(a, b, "case {case}");
        assert_eq!(ra, rb, "case {case}");
        rounds += ra.split_rounds;
    }
    assert!(rounds > 0, "no part was meshed again");
}

/// Planes along a column (`A + B·t`): plain ones, a crossing landing on lattice points
/// (exact and one ulp off), slopes too small for a finite crossing, and non-finite values.
fn plane_cases() -> Vec<(Real, Real)> {
    let mut cases: Vec<(Real, Real)> = vec![
        (-3.2, 0.1),
        (2.0, -0.25),
        (0.0, 1.0),
        (-1.0, 0.0),
        (5.0, 0.0),
        (-0.5, 1e-30),
        (7.5, -0.25),
        (0.5, -1e-300),
        (-1e300, 1e-300),
        (Real::NAN, 1.0),
        (1.0, Real::NAN),
        (Real::INFINITY, -1.0),
        (-0.0, -0.0),
    ];
    for k in 0..=32 {
        let b = 0.1 * (k % 7 + 1) as Real;
        for a in [
            -b * k as Real,
            (-b * k as Real).next_up(),
            (-b * k as Real).next_down(),
        ] {
            cases.push((a, b));
            cases.push((-a, -b));
        }
    }
    cases
}

#[test]
fn plane_masks_match_the_points_one_by_one() {
    for (a, b) in plane_cases() {
        for s in [1usize, 4, 17, 32] {
            let m = plane_mask(a, b, s);
            for t in 0..=s {
                assert_eq!(
                    m >> t & 1 == 1,
                    a + b * (t as Real) < 0.0,
                    "{a} {b} {s} {t}"
                );
                assert_eq!(plane_inside(a, b, t), m >> t & 1 == 1, "{a} {b} {s} {t}");
            }
            assert_eq!(m >> (s + 1), 0);
        }
    }
}

#[test]
fn the_key_index_finds_each_key_where_it_sorts() {
    // Keys as the mesher makes them (crossings, corners, fan centres) on a small lattice,
    // sorted and distinct: each found at its place, as a binary search finds it.
    for n in [0usize, 1, 2, 3, 7, 50, 400] {
        let mut keys: Vec<Key> = (0..n)
            .flat_map(|i| {
                let p = [
                    (i % 5) as isize,
                    (i / 5 % 5) as isize,
                    (i / 25) as isize - 1,
                ];
                [
                    lattice::crossing_key(i % 3, p),
                    corner_key(i % 3, i % 4, p),
                    local_key(i, i / 2, i % 3),
                ]
            })
            .collect();
        keys.sort_unstable();
        keys.dedup();
        let verts: Vec<(Key, Point3)> = keys.iter().map(|&k| (k, Point3::origin())).collect();
        let index = triangles::KeyIndex::of(&verts, Vec::new());
        for (i, &k) in keys.iter().enumerate() {
            assert_eq!(index.find(&verts, k), i as u32);
        }
    }
}

#[test]
fn gallop_finds_what_partition_point_finds() {
    // Every split point of sorted runs with repeats, from every start, on empty and short
    // slices too.
    for n in 0..70usize {
        let xs: Vec<usize> = (0..n).map(|i| i / 3).collect();
        for start in 0..=n {
            for key in 0..=n / 3 + 1 {
                let pred = |x: &usize| *x < key;
                let want = xs[start..].partition_point(pred);
                assert_eq!(
                    gallop(&xs[start..], pred),
                    want,
                    "n {n} start {start} key {key}"
                );
            }
        }
    }
}
