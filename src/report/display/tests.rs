//! Tests of the display mesh, its deviations and view ([`super`]).

use super::*;

/// The closed surface of the cube [−10, 10]³ with an n × n grid on each face, two
/// triangles per square, outward.
fn cube(n: i32) -> TriMesh {
    let mut m = TriMesh::default();
    let mut ids = std::collections::HashMap::new();
    let h = 20.0 / Real::from(n);
    let mut id = |p: [i32; 3], m: &mut TriMesh| {
        *ids.entry(p).or_insert_with(|| {
            let c = |k: usize| Real::from(p[k]) * h - 10.0;
            m.vertices.push(Point3::new(c(0), c(1), c(2)));
            (m.vertices.len() - 1) as u32
        })
    };
    for axis in 0..3 {
        for side in [0, n] {
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            for a in 0..n {
                for b in 0..n {
                    let q = |da: i32, db: i32| {
                        let mut p = [0; 3];
                        p[axis] = side;
                        p[u] = a + da;
                        p[v] = b + db;
                        p
                    };
                    let t = [q(0, 0), q(1, 0), q(1, 1), q(0, 1)].map(|p| id(p, &mut m));
                    if side == n {
                        m.triangles.extend([[t[0], t[1], t[2]], [t[0], t[2], t[3]]]);
                    } else {
                        m.triangles.extend([[t[0], t[2], t[1]], [t[0], t[3], t[2]]]);
                    }
                }
            }
        }
    }
    m
}

#[test]
fn a_cube_of_small_triangles_simplifies_to_a_few_exact_ones() {
    let m = cube(40);
    assert_eq!(m.signed_volume().round(), 8000.0);
    let d = simplify(&m, MAX_TRIANGLES);
    assert!(d.triangles.len() <= 24, "{} triangles", d.triangles.len());
    assert!(d.error_mm <= FIRST_PASS_ERROR_MM);
    // Every display vertex is a source vertex; the solid is kept.
    assert!(d.vertices.iter().all(|p| m.vertices.contains(p)));
    let shown = TriMesh {
        vertices: d.vertices.clone(),
        triangles: d.triangles.clone(),
    };
    assert!((shown.signed_volume() - 8000.0).abs() < 1e-6);
    assert_eq!(d, simplify(&m, MAX_TRIANGLES));
}

/// Each directed edge of `tris` once and its reverse once: a closed, consistently
/// oriented surface with no crack.
fn closed(tris: &[[u32; 3]]) -> bool {
    let mut edges = std::collections::HashMap::new();
    for t in tris {
        for k in 0..3 {
            *edges.entry((t[k], t[(k + 1) % 3])).or_insert(0) += 1;
        }
    }
    edges
        .iter()
        .all(|(&(a, b), &n)| n == 1 && edges.get(&(b, a)) == Some(&1))
}

#[test]
fn a_large_mesh_simplified_in_pieces_stays_closed_and_within_its_bound() {
    // A sphere of radius 10 mm (the cube's 190 × 190 face grids pushed out to it):
    // 433,200 triangles, so the first pass runs in pieces.
    let r = 10.0;
    let mut m = cube(190);
    for p in &mut m.vertices {
        p.coords *= r / p.coords.norm();
    }
    assert!(m.triangles.len() > CHUNKED_ABOVE);
    assert!(closed(&m.triangles));
    // How far the source's own triangles lie inside the sphere (their sagitta).
    let centroid = |v: &[Point3], t: &[u32; 3]| {
        (v[t[0] as usize].coords + v[t[1] as usize].coords + v[t[2] as usize].coords) / 3.0
    };
    let sag = m
        .triangles
        .iter()
        .map(|t| r - centroid(&m.vertices, t).norm())
        .fold(0.0, Real::max);
    let d = simplify(&m, MAX_TRIANGLES);
    // The pieces meet: their shared vertices were locked, so the surface has no crack.
    assert!(closed(&d.triangles), "the pieces leave a crack");
    assert!(
        d.vertices
            .iter()
            .all(|p| (p.coords.norm() - r).abs() < 1e-9)
    );
    assert!(d.triangles.len() < m.triangles.len() / 4);
    assert!(d.triangles.len() <= MAX_TRIANGLES);
    // Two passes of at most the first pass's bound each, by meshoptimizer's measure.
    assert!(d.error_mm <= 2.0 * FIRST_PASS_ERROR_MM, "{}", d.error_mm);
    // How far the display surface lies from the sphere (its triangles' centroids), beyond
    // the source's own sagitta: no more than half again what the whole mesh simplified
    // at once leaves. (meshoptimizer's measure is not a bound on this distance: the
    // whole mesh's triangles reach about twice its reported error.)
    let worst = |d: &DisplayMesh| {
        d.triangles
            .iter()
            .map(|t| (r - centroid(&d.vertices, t).norm()).abs())
            .fold(0.0, Real::max)
    };
    let whole = simplify_in(&m, MAX_TRIANGLES, usize::MAX);
    assert!(closed(&whole.triangles));
    let (w, w1) = (worst(&d), worst(&whole));
    assert!(w > sag && w1 > sag, "the simplification moved nothing");
    assert!(w - sag <= 1.5 * (w1 - sag), "in pieces {w}, whole {w1}");
    assert!(
        w <= 2.0 * FIRST_PASS_ERROR_MM + w1,
        "in pieces {w}, whole {w1}"
    );
    // The sphere's volume: 4/3·π·r³, less the source's facets and the simplification.
    let shown = TriMesh {
        vertices: d.vertices.clone(),
        triangles: d.triangles.clone(),
    };
    let ball = 4.0 / 3.0 * std::f64::consts::PI * r * r * r;
    let area = 4.0 * std::f64::consts::PI * r * r;
    let v = shown.signed_volume();
    assert!(v < ball && v > ball - area * w, "{v} vs {ball}");
    assert_eq!(d, simplify(&m, MAX_TRIANGLES));
}

#[test]
fn a_large_cube_simplified_in_pieces_keeps_its_faces_exactly() {
    let m = cube(190);
    assert!(m.triangles.len() > CHUNKED_ABOVE);
    let d = simplify(&m, MAX_TRIANGLES);
    assert!(closed(&d.triangles));
    // The seams between the pieces collapse in the joined pass: a few triangles a face.
    assert!(
        d.triangles.len() <= 6 * 64,
        "{} triangles",
        d.triangles.len()
    );
    let shown = TriMesh {
        vertices: d.vertices.clone(),
        triangles: d.triangles.clone(),
    };
    assert!((shown.signed_volume() - 8000.0).abs() < 1e-6);
    assert!(d.vertices.iter().all(|p| m.vertices.contains(p)));
}

#[test]
fn a_bumpy_surface_is_cut_to_the_budget_and_says_how_far_it_moved() {
    let mut m = cube(40);
    for (k, p) in m.vertices.iter_mut().enumerate() {
        p.coords *= 1.0 + 0.01 * ((k * 7919) % 13) as Real;
    }
    let d = simplify(&m, 500);
    assert!(d.triangles.len() <= 500);
    assert!(d.error_mm > FIRST_PASS_ERROR_MM);
    assert_eq!(d.source_triangles, 19200);
}

#[test]
fn deviations_are_measured_along_each_face_normal_not_to_the_nearest_face() {
    // Reference: the cube [−10, 10]³. Part: the same cube with its −y face 0.5 mm
    // further in (a gouge) — shown by its −y face and its −z face.
    let r = cube(4);
    let reference = ReferenceSurface::new(r.vertices.clone(), r.triangles.clone()).unwrap();
    let d = DisplayMesh {
        vertices: vec![
            Point3::new(-10.0, -9.5, -10.0),
            Point3::new(10.0, -9.5, -10.0),
            Point3::new(10.0, -9.5, 10.0),
            Point3::new(10.0, 10.0, -10.0),
        ],
        // The −y face (normal −y) and a piece of the −z face (normal −z), sharing the
        // edge y = −9.5, z = −10, which lies on the reference's −z face.
        triangles: vec![[0, 1, 2], [0, 3, 1]],
        source_triangles: 2,
        error_mm: 0.0,
    };
    // The cut part behind the display triangles (their sag on it is zero: all plane).
    let part = TriDexel::new_box(
        Aabb {
            min: Point3::new(-10.0, -9.5, -10.0),
            max: Point3::new(10.0, 10.0, 10.0),
        },
        0.5,
        1e9,
    )
    .expect("fits");
    let dev = deviations(&d, &reference, &part);
    for c in dev[0] {
        assert!((c + 0.5).abs() < 1e-9, "{c}");
    }
    for c in dev[1] {
        assert!(c.abs() < 1e-9, "{c}");
    }
    // A ledge facing −z at z = 0, 0.4 mm outside the −y face: no counterpart along −z
    // (the reference's −z face is 10 mm away), so the distance from its centroid.
    let ledge = DisplayMesh {
        vertices: vec![
            Point3::new(-5.0, -10.4, 0.0),
            Point3::new(5.0, -10.4, 0.0),
            Point3::new(5.0, -10.3, 0.0),
        ],
        triangles: vec![[0, 2, 1]],
        source_triangles: 1,
        error_mm: 0.0,
    };
    let dev = deviations(&ledge, &reference, &part);
    let expected = 10.4 - 1.0 / 3.0 * 0.1 - 10.0;
    for c in dev[0] {
        assert!((c - expected).abs() < 1e-9, "{c} vs {expected}");
    }
}

/// A slot cut by a flat Ø6 mm end mill into the block [−10, 10]² × [0, 20] at pitch
/// 0.1 mm: the tip at z = 12 moving from x = −15 to x = 2 along y = 0 (two walls, a
/// floor, a half-round end), on the nominal pose and on the pose moved by `t`.
fn slot(t: &crate::math::Isometry3) -> TriDexel {
    use crate::cutting::sweep::TranslatedTool;
    use crate::cutting::tool::{Tool, ToolKind};
    let b = Aabb {
        min: Point3::new(-10.0, -10.0, 0.0),
        max: Point3::new(10.0, 10.0, 20.0),
    };
    let mut s = TriDexel::new_box(b, 0.1, 1e9).expect("fits");
    let tool = Tool::try_new(ToolKind::Flat, 6.0, 30.0).expect("valid");
    let cut = TranslatedTool::new(
        tool,
        t * Point3::new(-15.0, 0.0, 12.0),
        t * Vector3::new(17.0, 0.0, 0.0),
        UnitVector3::new_normalize(t * Vector3::z()),
    );
    assert!(s.remove(&cut, 1));
    s
}

#[test]
fn deviations_from_a_cut_part_are_its_displacement_along_the_normal() {
    // The part cut on a pose moved by the small rigid motion p ↦ R·p + e: every point of
    // its cut surface is the nominal one moved by u(p) = (R − I)·p + e, so its deviation
    // along the outward normal n is u(p)·n (to first order: the second-order terms,
    // |u|²/(tool radius) and |R − I|·|u|, are below 0.2 µm here); the stock's own
    // faces, cut by neither, deviate 0.
    use crate::cutting::adaptive::{AdaptiveOptions, mesh_stock_adaptive};
    use crate::math::Isometry3;
    let e = Vector3::new(0.012, 0.021, -0.017);
    let moved = Isometry3::new(e, Vector3::new(3e-4, -2e-4, 1e-4));
    let nominal = slot(&Isometry3::identity());
    let part = slot(&moved);
    let (mesh, _) = mesh_stock_adaptive(&part, &AdaptiveOptions::default()).expect("meshes");
    let shown = simplify(&mesh, MAX_TRIANGLES);
    let expected = |p: &Point3, n: &Vector3| {
        let on_stock = [p.x.abs() - 10.0, p.y.abs() - 10.0, p.z, p.z - 20.0]
            .iter()
            .any(|d| d.abs() < 1e-6);
        if on_stock {
            0.0
        } else {
            ((moved * p) - p).dot(n)
        }
    };
    // On the plane faces (the walls, the floor, the stock's faces: triangles whose normal
    // is within 0.01 rad of an axis) more than 0.3 mm from their edges, the formula
    // holds exactly (the display triangles lie in the faces).
    let from_part = part_deviations(&shown, &nominal, &part);
    let mut planar = 0;
    for (t, d) in shown.triangles.iter().zip(&from_part) {
        let p = t.map(|i| shown.vertices[i as usize]);
        let n = (p[1] - p[0]).cross(&(p[2] - p[0])).normalize();
        // The walls |y| = 3 and the floor z = 12 short of the half-round end (x < 2), the
        // stock's top away from the slot.
        let wall =
            |q: &Point3| (q.y.abs() - 3.0).abs() < 0.05 && q.z > 12.3 && q.z < 19.7 && q.x < 1.7;
        let floor = |q: &Point3| (q.z - 12.0).abs() < 0.05 && q.y.abs() < 2.7 && q.x < 1.7;
        let top = |q: &Point3| (q.z - 20.0).abs() < 1e-6 && (q.y.abs() > 3.3 || q.x > 5.3);
        if n.amax() < 1.0 - 5e-5 {
            continue;
        }
        for (q, v) in p.iter().zip(d) {
            if q.x < -9.7 || ![wall, floor, top].iter().any(|face| face(q)) {
                continue;
            }
            planar += 1;
            let want = expected(q, &n);
            assert!(
                (v - want).abs() < 5e-4,
                "at {q:?} normal {n:?}: {v} mm, want {want}"
            );
        }
    }
    assert!(planar >= 20, "{planar} corners on plane faces");
    // Everywhere (the half-round end, shown by chords, and the edges), the same values
    // as measured from the nominal part's mesh, within the two surfaces' own errors.
    let (nm, _) = mesh_stock_adaptive(&nominal, &AdaptiveOptions::default()).expect("meshes");
    let surface = ReferenceSurface::new(nm.vertices, nm.triangles).expect("closed");
    let from_mesh = deviations(&shown, &surface, &part);
    // Nine in ten corners of either within 5 µm of the displacement: the display's
    // chords of the half-round end lie up to tens of µm under the part (the sag of
    // meshoptimizer's bound), and a corner that takes its centroid's distance reads it at
    // the cut part's crossing nearest the centroid (`near_crossing`), a point of the part
    // itself; the rest are edges.
    for from in [&from_mesh, &from_part] {
        let mut off: Vec<Real> = shown
            .triangles
            .iter()
            .zip(from)
            .flat_map(|(t, d)| {
                let p = t.map(|i| shown.vertices[i as usize]);
                let n = (p[1] - p[0]).cross(&(p[2] - p[0])).normalize();
                (0..3).map(move |k| (d[k] - expected(&p[k], &n)).abs())
            })
            .collect();
        off.sort_by(Real::total_cmp);
        let p90 = off[off.len() * 9 / 10];
        assert!(p90 < 5e-3, "90th percentile {p90}");
    }
    let mut diff: Vec<Real> = from_part
        .iter()
        .zip(&from_mesh)
        .flat_map(|(a, b)| (0..3).map(move |k| (a[k] - b[k]).abs()))
        .collect();
    diff.sort_by(Real::total_cmp);
    // Half the corners within 1 µm; the 1 % worst, at the edges where the two pick
    // different counterparts, within half the displacement.
    assert!(
        diff[diff.len() / 2] < 1e-3,
        "median {}",
        diff[diff.len() / 2]
    );
    let p99 = diff[diff.len() * 99 / 100];
    assert!(p99 < 0.5 * e.norm(), "99th percentile {p99}");
}

/// The slot of [`slot`] as a program of one move (NC line 1) on a nominal 3-axis mill.
fn slot_path() -> NominalPath {
    use crate::cutting::nominal::{NominalMachine, NominalStock};
    use crate::cutting::tool::{Tool, ToolKind};
    use crate::nc::{AxisValues, Move, MoveKind};
    let tool = Tool::try_new(ToolKind::Flat, 6.0, 30.0).expect("valid");
    let mv = Move {
        kind: MoveKind::Linear,
        start: AxisValues::from_array([-15.0, 0.0, 12.0, 0.0, 0.0, 0.0]),
        end: AxisValues::from_array([2.0, 0.0, 12.0, 0.0, 0.0, 0.0]),
        feed_mm_per_min: Some(600.0),
        line: 1,
    };
    let machine = NominalMachine::Chain(crate::machine::chain::xyz_for_tests());
    let block = Aabb {
        min: Point3::new(-10.0, -10.0, 0.0),
        max: Point3::new(10.0, 10.0, 20.0),
    };
    NominalPath::new(&tool, machine, NominalStock::boxed(block), &[mv], 1e-4)
}

#[test]
fn deviations_from_the_nominal_path_are_exact_on_the_slots_plane_faces() {
    // The slot cut on the pose moved by p ↦ R·p + e. Display triangles placed in the
    // moved faces, away from their edges: the floor, both walls and the stock's top
    // (cut by neither). The nominal part's faces there are the planes z = 12, y = ±3 and
    // z = 20, so a pulled corner q of a triangle with normal n meets its face x_a = c
    // along n at (q_a − c)/n_a: exactly, with no first-order approximation.
    use crate::math::Isometry3;
    let e = Vector3::new(0.012, 0.021, -0.017);
    let moved = Isometry3::new(e, Vector3::new(3e-4, -2e-4, 1e-4));
    let part = slot(&moved);
    // (nominal centre, two in-face directions whose cross product is the outward normal,
    // whether the face is cut (moved) or the stock's, axis a and plane c).
    let faces = [
        (
            Point3::new(-5.0, 0.5, 12.0),
            Vector3::x(),
            Vector3::y(),
            true,
            2,
            12.0,
        ),
        (
            Point3::new(-4.0, 3.0, 16.0),
            Vector3::x(),
            Vector3::z(),
            true,
            1,
            3.0,
        ),
        (
            Point3::new(-6.0, -3.0, 15.0),
            Vector3::z(),
            Vector3::x(),
            true,
            1,
            -3.0,
        ),
        (
            Point3::new(-5.0, 7.0, 20.0),
            Vector3::x(),
            Vector3::y(),
            false,
            2,
            20.0,
        ),
    ];
    let mut vertices = Vec::new();
    let mut triangles = Vec::new();
    for (c, u, v, cut, _, _) in &faces {
        let place = |p: Point3| if *cut { moved * p } else { p };
        let k = vertices.len() as u32;
        vertices.extend([
            place(c - u * 0.4 - v * 0.3),
            place(c + u * 0.5 - v * 0.2),
            place(c + v * 0.45),
        ]);
        triangles.push([k, k + 1, k + 2]);
    }
    let shown = DisplayMesh {
        vertices,
        triangles,
        source_triangles: 4,
        error_mm: 0.0,
    };
    let from_path = path_deviations(&shown, &part, &slot_path());
    for ((t, d), (_, _, _, _, a, c)) in shown.triangles.iter().zip(&from_path).zip(&faces) {
        let p = t.map(|i| shown.vertices[i as usize]);
        let n = (p[1] - p[0]).cross(&(p[2] - p[0])).normalize();
        let centre = Point3::from((p[0].coords + p[1].coords + p[2].coords) / 3.0);
        for (q, v) in p.iter().zip(d) {
            let pulled = q + (centre - q) * CORNER_PULL;
            let want = (pulled[*a] - c) / n[*a];
            assert!(
                (v - want).abs() < 1e-7,
                "at {q:?} normal {n:?}: {v} mm, want {want}"
            );
        }
    }
    // Not vacuous: the cut faces deviate by micrometres, the floor by e_z and more.
    assert!(from_path[0].iter().all(|d| (d + 0.017).abs() < 3e-3));
    assert!(from_path[3].iter().all(|d| d.abs() < 1e-12));
}

/// The distance along `-n` from `q` to the surface of the nominal slot of [`slot`] that
/// faces like `n` (the block less the slot: the tool's side |y| ≤ 3 up to x = 2 and its
/// half-round end (x − 2)² + y² ≤ 9, above z = 12), nearest `q` within `reach`: the
/// crossings found by stepping 1 µm and bisecting to 1e-12 mm, in closed form.
fn exact_slot_along(q: &Point3, n: &Vector3, reach: Real) -> Option<Real> {
    let inside = |p: Point3| {
        let in_block = p.x.abs() <= 10.0 && p.y.abs() <= 10.0 && (0.0..=20.0).contains(&p.z);
        let in_slot = p.z >= 12.0
            && ((p.x <= 2.0 && p.y.abs() <= 3.0) || (p.x - 2.0).powi(2) + p.y * p.y <= 9.0);
        in_block && !in_slot
    };
    let at = |d: Real| inside(q - n * d);
    let step = 1e-3;
    let steps = (reach / step) as i64;
    let mut best: Option<Real> = None;
    for k in -steps..steps {
        let (a, b) = (k as Real * step, (k + 1) as Real * step);
        // Outside at the smaller d, inside at the larger: a face like n.
        if !at(a) && at(b) {
            let (mut lo, mut hi) = (a, b);
            while hi - lo > 1e-12 {
                let mid = 0.5 * (lo + hi);
                if at(mid) { hi = mid } else { lo = mid }
            }
            let d = 0.5 * (lo + hi);
            if best.is_none_or(|x: Real| d.abs() < x.abs()) {
                best = Some(d);
            }
        }
    }
    best
}

#[test]
fn deviations_from_the_nominal_path_match_the_exact_slot_closer_than_the_swept_part() {
    // The slot cut on the moved pose, every display corner: its deviation along the
    // triangle's normal from the exact nominal slot (closed form), against the
    // deviations measured from the program on the nominal machine (path_deviations)
    // and from the nominal part swept into a tri-dexel (part_deviations).
    use crate::cutting::adaptive::{AdaptiveOptions, mesh_stock_adaptive};
    use crate::math::Isometry3;
    let e = Vector3::new(0.012, 0.021, -0.017);
    let moved = Isometry3::new(e, Vector3::new(3e-4, -2e-4, 1e-4));
    let part = slot(&moved);
    let (mesh, _) = mesh_stock_adaptive(&part, &AdaptiveOptions::default()).expect("meshes");
    let shown = simplify(&mesh, MAX_TRIANGLES);
    let swept = part_deviations(&shown, &slot(&Isometry3::identity()), &part);
    let from_path = path_deviations(&shown, &part, &slot_path());
    let (mut err_path, mut err_swept) = (Vec::new(), Vec::new());
    for (t, (a, b)) in shown.triangles.iter().zip(from_path.iter().zip(&swept)) {
        let p = t.map(|i| shown.vertices[i as usize]);
        let n = (p[1] - p[0]).cross(&(p[2] - p[0])).normalize();
        let centre = Point3::from((p[0].coords + p[1].coords + p[2].coords) / 3.0);
        for k in 0..3 {
            let q = p[k] + (centre - p[k]) * CORNER_PULL;
            if let Some(want) = exact_slot_along(&q, &n, 0.1) {
                err_path.push((a[k] - want).abs());
                err_swept.push((b[k] - want).abs());
            }
        }
    }
    let stats = |v: &mut Vec<Real>| {
        v.sort_by(Real::total_cmp);
        let at = |f: Real| v[((v.len() - 1) as Real * f) as usize];
        [at(0.5), at(0.9), at(0.99)]
    };
    let (path, swept) = (stats(&mut err_path), stats(&mut err_swept));
    assert!(err_path.len() > 500, "{} corners", err_path.len());
    // Exact off the edges: half the corners within 1 nm, nine in ten within 0.1 µm (the
    // swept part's interpolation between rays leaves 0.2 µm at the median, 2 µm at the
    // 90th percentile).
    assert!(path[0] < 1e-6, "median {} (swept {})", path[0], swept[0]);
    assert!(
        path[1] < 1e-4,
        "90th percentile {} (swept {})",
        path[1],
        swept[1]
    );
    // At the edges, where the normal line meets the neighbouring face, both take the
    // centroid's closest distance: no farther than the swept part's.
    assert!(
        path[2] <= swept[2],
        "99th percentile {} vs {}",
        path[2],
        swept[2]
    );
}

#[test]
fn the_nominal_paths_distance_is_the_exact_one_on_a_five_axis_cut() {
    // The trunnion with its location errors cutting a 16 mm cube's side while C turns
    // 5° a move through a turn, A swings ±5° and Z descends 2 mm. At display vertices of
    // the cut part, the nominal part's signed distance from the program on the nominal
    // machine (read as a chain, and pose by pose like the hexapod) against brute force
    // (every move's poses at 400 steps, the least refined by ternary search, and the
    // stock box's own distance).
    use crate::cutting::adaptive::{AdaptiveOptions, mesh_stock_adaptive};
    use crate::cutting::nominal::tests::five_axis_cut;
    use crate::cutting::nominal::{NominalMachine, NominalStock};
    use crate::machine::chain::ChainPoses;
    let cut = five_axis_cut();
    let (nominal, part) = (&cut.nominal, &cut.part);
    let (mesh, _) = mesh_stock_adaptive(part, &AdaptiveOptions::default()).expect("meshes");
    let shown = simplify(&mesh, MAX_TRIANGLES);
    let stock = || NominalStock::boxed(cut.stock);
    let as_chain = NominalPath::new(
        &cut.tool,
        NominalMachine::Chain(nominal.clone()),
        stock(),
        &cut.moves,
        1e-4,
    );
    let from_path = path_deviations(&shown, part, &as_chain);
    let pose_by_pose = NominalPath::new(
        &cut.tool,
        NominalMachine::Poses(Box::new(ChainPoses(nominal.clone()))),
        stock(),
        &cut.moves,
        1e-4,
    );
    let by_poses = path_deviations(&shown, part, &pose_by_pose);
    // Read pose by pose (the chain's own poses, not the envelope's folded path): the same
    // distance at every vertex within twice the refinement's tolerance (its bracket
    // lands elsewhere when the poses round differently); the display's corners alike
    // but for a few at edges, whose choice between their own plane and the centroid's
    // that may tip.
    for v in &shown.vertices {
        let a = as_chain.nearest(part, v).map(|f| f.distance);
        let b = pose_by_pose.nearest(part, v).map(|f| f.distance);
        assert!(
            a.zip(b).is_some_and(|(a, b)| (a - b).abs() < 2e-6),
            "{v:?}: {a:?} {b:?}"
        );
    }
    let differ = from_path
        .iter()
        .flatten()
        .zip(by_poses.iter().flatten())
        .filter(|(a, b)| !(a.is_nan() && b.is_nan() || (*a - *b).abs() < 2e-6))
        .count();
    assert!(
        differ * 1000 < 3 * from_path.len(),
        "{differ} corners differ"
    );
    let mut checked = 0;
    let mut deviating = 0;
    for v in shown
        .vertices
        .iter()
        .step_by(shown.vertices.len() / 100 + 1)
    {
        let want = cut.brute(v);
        if want.abs() > 0.5 {
            continue;
        }
        let got = as_chain.nearest(part, v).expect("near the cut").distance;
        assert!(
            (got - want).abs() < 1e-6,
            "at {v:?}: {got} mm, brute force {want}"
        );
        checked += 1;
        deviating += usize::from(want.abs() > 1e-3);
    }
    // Not vacuous: most vertices checked lie micrometres off the nominal part.
    assert!(
        checked > 60 && deviating > checked / 2,
        "{deviating} of {checked}"
    );
}

#[test]
fn a_curved_uncut_face_deviates_zero_whatever_the_display_triangles_sag() {
    // A bar of radius 10 along x (length 40) and a slot along it by a flat Ø6 end mill,
    // on a machine whose Z sits 0.02 mm low: the part is the nominal one but for its
    // floor, 0.02 mm deeper. Its display mesh shows the bar's round face by chords whose
    // middles lie µm under it (meshoptimizer's 0.01 mm bound, and more at the rims).
    // Exact deviations, by construction: −0.02 mm on the floor, 0 on every other face
    // (the walls and the round face and ends, which both parts share).
    use crate::cutting::adaptive::{AdaptiveOptions, mesh_stock_adaptive};
    use crate::cutting::nominal::{NominalMachine, NominalStock};
    use crate::cutting::shape::Cylinder;
    use crate::cutting::sweep::TranslatedTool;
    use crate::cutting::tool::{Tool, ToolKind};
    use crate::nc::{AxisValues, Move, MoveKind};
    let (r, len, floor, dz) = (10.0, 40.0, 7.0, -0.02);
    let bar = Cylinder::try_new(Point3::origin(), Vector3::x(), r, len).expect("valid");
    let bounds = Aabb {
        min: Point3::new(0.0, -r, -r),
        max: Point3::new(len, r, r),
    };
    let mut part = TriDexel::from_solid(bounds, 0.2, 1e9, &bar).expect("fits");
    let tool = Tool::try_new(ToolKind::Flat, 6.0, 20.0).expect("valid");
    let (x0, x1) = (-10.0, 50.0);
    assert!(part.remove(
        &TranslatedTool::new(
            tool.clone(),
            Point3::new(x0, 0.0, floor + dz),
            Vector3::new(x1 - x0, 0.0, 0.0),
            UnitVector3::new_normalize(Vector3::z()),
        ),
        1
    ));
    let mv = Move {
        kind: MoveKind::Linear,
        start: AxisValues::from_array([x0, 0.0, floor, 0.0, 0.0, 0.0]),
        end: AxisValues::from_array([x1, 0.0, floor, 0.0, 0.0, 0.0]),
        feed_mm_per_min: Some(600.0),
        line: 1,
    };
    let path = NominalPath::new(
        &tool,
        NominalMachine::Chain(crate::machine::chain::xyz_for_tests()),
        NominalStock::cylinder(bounds, bar),
        &[mv],
        1e-4,
    );
    let (mesh, _) = mesh_stock_adaptive(&part, &AdaptiveOptions::default()).expect("meshes");
    let shown = simplify(&mesh, MAX_TRIANGLES);
    let dev = path_deviations(&shown, &part, &path);
    // The display's vertices are the source mesh's, which places some (at the rims,
    // and where it interpolates between rays) up to ~2 µm off the bar: a corner shows
    // its vertex's own error and the sag of the point it is measured from (1 % of the
    // way to the centroid: 1 % of the centroid's height under the bar's tangent plane at
    // the corner), both along the triangle's normal, to 0.05 µm, but not the triangle's
    // sag.
    let radius = |q: &Point3| q.y.hypot(q.z);
    let (mut round, mut sagging, mut on_floor) = (0, 0, 0);
    for (t, d) in shown.triangles.iter().zip(&dev) {
        let p = t.map(|i| shown.vertices[i as usize]);
        let n = (p[1] - p[0]).cross(&(p[2] - p[0])).normalize();
        let centre = Point3::from((p[0].coords + p[1].coords + p[2].coords) / 3.0);
        // Every corner within the exact range, to the source mesh's error.
        for v in d {
            assert!(
                (dz - 2e-3..=2e-3).contains(v),
                "{v} mm at {p:?} (normal {n:?})"
            );
        }
        // The round face (the ends' rims too): corners within 2 µm of it, the normal
        // within 20° of radial (not a sliver standing across it).
        let radial = |q: &Point3| Vector3::new(0.0, q.y, q.z) / radius(q);
        if p.iter().all(|q| (radius(q) - r).abs() < 2e-3)
            && n.dot(&radial(&centre)) >= SAME_FACE_COS
        {
            round += 1;
            sagging += usize::from(r - radius(&centre) > 2e-3);
            for (q, v) in p.iter().zip(d) {
                let pull = CORNER_PULL * (centre - q).dot(&radial(q)).abs();
                assert!(
                    v.abs() <= ((radius(q) - r).abs() + pull) / n.dot(&radial(q)) + 5e-5,
                    "{v} mm at {q:?}, {} mm off the bar; triangle {p:?} (normal {n:?})",
                    radius(q) - r
                );
            }
        }
        // The floor.
        if n.z > 0.999 && p.iter().all(|q| (q.z - floor - dz).abs() < 1e-6) {
            on_floor += 1;
            assert!(d.iter().all(|v| (v - dz).abs() < 1e-4), "{d:?} at {p:?}");
        }
    }
    // Not vacuous: many chords of the round face sag by more than 2 µm.
    assert!(
        round > 100 && sagging > 20 && on_floor > 0,
        "{round} {sagging} {on_floor}"
    );
}

#[test]
fn the_colour_range_ignores_a_few_outliers() {
    let mut v = vec![0.004; 1000];
    v[3] = 0.9;
    assert!((colour_range_mm(&v) - 0.005).abs() < 1e-15);
    assert_eq!(colour_range_mm(&[0.0; 4]), 1e-3);
    assert_eq!(colour_range_mm(&[]), 1e-3);
}

#[test]
fn decimation_strides_evenly() {
    assert_eq!(decimate(5, 10), vec![0, 1, 2, 3, 4]);
    assert_eq!(decimate(10, 4), vec![0, 3, 6, 9]);
    assert!(decimate(10, 0).is_empty());
}

#[test]
fn the_view_looks_at_the_machined_face() {
    // A face at y = -1 (normal -y) machined into a box [-2, 2]³: seen from -y, above.
    let b = Aabb {
        min: Point3::new(-2.0, -2.0, -2.0),
        max: Point3::new(2.0, 2.0, 2.0),
    };
    let d = DisplayMesh {
        vertices: vec![
            Point3::new(-1.0, -1.0, -1.0),
            Point3::new(1.0, -1.0, -1.0),
            Point3::new(1.0, -1.0, 1.0),
        ],
        triangles: vec![[0, 1, 2]],
        source_triangles: 1,
        error_mm: 0.0,
    };
    let (eye, up) = view_direction(&d, &b);
    assert!(eye.y < -0.7 && eye.z > 0.3, "{eye:?}");
    assert_eq!(up, Vector3::z());
}
