//! Fixtures shared by the segmentation tests (the step experiment's three faces, poses,
//! points on a sphere, RANSAC options, index checks), and the tests that span the module:
//! bit-identity across thread counts, the errors of every entry point, awkward inputs.

use super::*;
use crate::math::{CounterRng, Isometry3, Point3, Real, Rotation3, UnitVector3, Vector3};
use crate::metrology::fit::{Plane, PlaneFit, RobustRule};
use proptest::prelude::*;

/// Scanner noise (mm) and point spacing (mm) of the structured-light scanner.
pub(super) const SIGMA: Real = 0.025;

const PITCH: Real = 0.185;

/// Viewing direction of the scene's camera (from (0, −330, 80) towards the face).
fn view() -> Vector3 {
    Vector3::new(0.0, 308.0, -80.0).normalize()
}

/// A rectangle `origin + s·u + t·v`, s ∈ [0, lu], t ∈ [0, lv], rastered at `pitch`.
struct Face {
    origin: Point3,
    u: Vector3,
    v: Vector3,
    lu: Real,
    lv: Real,
}

/// Raster points of `face` with Gaussian noise of `noise` mm along the view, labelled.
fn raster(face: &Face, label: u8, noise: Real, pitch: Real, cloud: &mut Labelled) {
    let rng = CounterRng::new(17);
    let (nu, nv) = ((face.lu / pitch) as usize, (face.lv / pitch) as usize);
    for j in 0..nv {
        for i in 0..nu {
            let k = cloud.points.len() as u64;
            let p = face.origin
                + face.u * ((i as Real + 0.5) * pitch)
                + face.v * ((j as Real + 0.5) * pitch);
            cloud.points.push(p + view() * (noise * rng.normal(k)));
            cloud.labels.push(label);
        }
    }
}

#[derive(Default)]
pub(super) struct Labelled {
    pub(super) points: Vec<Point3>,
    pub(super) labels: Vec<u8>,
    planes: Vec<Plane>,
}

/// The step experiment: face A (y = 0, z ∈ [0, 10]), face B 1 mm back (y = 1,
/// z ∈ [−10, 0]), both 40 mm wide, and the top face (z = 10, y ∈ [0, 10]) at 90°;
/// moved by `pose`.
pub(super) fn step_cloud(noise: Real, pose: &Isometry3) -> Labelled {
    let (x, y, z) = (Vector3::x(), Vector3::y(), Vector3::z());
    let faces = [
        (
            Face {
                origin: Point3::new(0.0, 0.0, 0.0),
                u: x,
                v: z,
                lu: 40.0,
                lv: 10.0,
            },
            y,
            0.0,
        ),
        (
            Face {
                origin: Point3::new(0.0, 1.0, -10.0),
                u: x,
                v: z,
                lu: 40.0,
                lv: 10.0,
            },
            y,
            1.0,
        ),
        (
            Face {
                origin: Point3::new(0.0, 0.0, 10.0),
                u: x,
                v: y,
                lu: 40.0,
                lv: 10.0,
            },
            z,
            10.0,
        ),
    ];
    let mut c = Labelled::default();
    for (label, (face, normal, offset)) in faces.iter().enumerate() {
        raster(face, label as u8, noise, PITCH, &mut c);
        let n = UnitVector3::new_normalize(pose.rotation * normal);
        let on = pose * Point3::from(normal * *offset);
        c.planes.push(Plane::through(&on, n));
    }
    for p in &mut c.points {
        *p = pose * *p;
    }
    c
}

pub(super) fn step_opts() -> PlaneSegmentOptions {
    PlaneSegmentOptions {
        min_points: 1000,
        ..PlaneSegmentOptions::default()
    }
}

pub(super) fn tilted_pose() -> Isometry3 {
    Isometry3::from_parts(
        Vector3::new(150.0, -80.0, 60.0).into(),
        Rotation3::from_axis_angle(
            &UnitVector3::new_normalize(Vector3::new(1.0, 2.0, 3.0)),
            0.7,
        ),
    )
}

/// Angle (rad) between two lines.
pub(super) fn line_angle(a: &Vector3, b: &Vector3) -> Real {
    a.normalize().cross(&b.normalize()).norm()
}

/// The face each segment holds most points of.
pub(super) fn majority(seg: &PlaneSegment, labels: &[u8]) -> u8 {
    let mut count = [0usize; 3];
    for &i in &seg.indices {
        count[labels[i as usize] as usize] += 1;
    }
    (0..3).max_by_key(|&k| count[k]).unwrap_or(0) as u8
}

/// Checks the segmentation of a step cloud; returns the segments' faces.
pub(super) fn check_step(
    c: &Labelled,
    segs: &[PlaneSegment],
    opts: &PlaneSegmentOptions,
    exact: bool,
) {
    assert_eq!(segs.len(), 3, "three segments");
    let mut seen = [false; 3];
    for s in segs {
        let f = majority(s, &c.labels) as usize;
        assert!(!seen[f], "two segments on face {f}");
        seen[f] = true;
        let truth = &c.planes[f];
        let face_points = c.labels.iter().filter(|&&l| l as usize == f).count();
        assert!(
            s.indices.len() * 100 >= face_points * 97,
            "face {f}: {} of {face_points} points",
            s.indices.len()
        );
        let angle = line_angle(&s.fit.plane.normal, &truth.normal);
        let offset = truth.signed_distance(&s.fit.centroid).abs();
        if exact {
            assert!(angle <= 1e-9, "face {f}: angle {angle:e}");
            assert!(offset <= 1e-9, "face {f}: offset {offset:e}");
        } else {
            let n = s.fit.n_used as Real;
            assert!(angle <= 1e-3, "face {f}: angle {angle:e}");
            assert!(
                offset <= 3.0 * 5.0 * SIGMA / n.sqrt(),
                "face {f}: offset {offset:e}"
            );
        }
        assert!(s.indices.windows(2).all(|w| w[0] < w[1]), "sorted, unique");
        assert_eq!(s.fit.n_used + s.fit.n_rejected, s.indices.len());
        for &i in &s.indices {
            let (p, l) = (&c.points[i as usize], c.labels[i as usize] as usize);
            if l != f {
                let d = truth.signed_distance(p).abs();
                assert!(
                    d <= 2.0 * opts.max_distance_mm,
                    "point {i} of face {l} in face {f}'s segment, {d} mm from its plane"
                );
            }
        }
    }
    for w in segs.windows(2) {
        assert!(w[0].indices.len() >= w[1].indices.len(), "largest first");
    }
}

fn fit_bits(f: &PlaneFit) -> Vec<u64> {
    let mut v = vec![
        f.plane.offset.to_bits(),
        f.rms_mm.to_bits(),
        f.max_abs_mm.to_bits(),
    ];
    v.extend(f.plane.normal.iter().map(|c| c.to_bits()));
    v.extend(f.centroid.iter().map(|c| c.to_bits()));
    v
}

#[test]
fn bit_identical_for_one_and_two_threads() {
    let c = step_cloud(SIGMA, &tilted_pose());
    let opts = step_opts();
    let one = crate::math::in_pool(1, || segment_planes(&c.points, &opts).expect("one"));
    let two = crate::math::in_pool(2, || segment_planes(&c.points, &opts).expect("two"));
    assert_eq!(one, two);
    for (a, b) in one.iter().zip(&two) {
        assert_eq!(fit_bits(&a.fit), fit_bits(&b.fit));
    }
    let seed = c.points[c.points.len() / 2];
    let r1 = crate::math::in_pool(1, || select_region_from_seed(&c.points, &seed, &opts));
    let r2 = crate::math::in_pool(2, || select_region_from_seed(&c.points, &seed, &opts));
    assert_eq!(r1, r2);
    let sub = &c.points[..5000];
    let n1 = crate::math::in_pool(1, || estimate_normals(sub, 12, None).expect("n1"));
    let n2 = crate::math::in_pool(2, || estimate_normals(sub, 12, None).expect("n2"));
    assert_eq!(n1, n2);
    let ro = RansacOptions {
        distance_mm: 0.1,
        iterations: 50,
        seed: 9,
        min_inliers: 100,
    };
    let p1 = crate::math::in_pool(1, || ransac_plane(&c.points, &ro));
    let p2 = crate::math::in_pool(2, || ransac_plane(&c.points, &ro));
    assert_eq!(p1, p2);
}

/// Points on the sphere |p − centre| = radius by the Fibonacci lattice (about `pitch`
/// apart), those with (p − centre)·dir ≥ cos_cap · radius, with radial noise.
pub(super) fn sphere_points(
    centre: Point3,
    radius: Real,
    cos_cap: Real,
    noise: Real,
) -> Vec<Point3> {
    let rng = CounterRng::new(5);
    let area = 2.0 * std::f64::consts::TAU * radius * radius;
    let n = (area / (PITCH * PITCH)) as usize;
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .filter_map(|i| {
            let z = 1.0 - 2.0 * (i as Real + 0.5) / n as Real;
            let r = (1.0 - z * z).sqrt();
            let phi = golden * i as Real;
            let dir = Vector3::new(r * phi.cos(), r * phi.sin(), z);
            (z >= cos_cap).then(|| centre + dir * (radius + noise * rng.normal(i as u64)))
        })
        .collect()
}

pub(super) fn ransac_opts(seed: u64) -> RansacOptions {
    RansacOptions {
        distance_mm: 4.0 * SIGMA,
        iterations: 200,
        seed,
        min_inliers: 500,
    }
}

#[test]
fn errors() {
    let c = step_cloud(SIGMA, &Isometry3::identity());
    let opts = step_opts();
    assert_eq!(segment_planes(&[], &opts), Err(SegmentError::NoPoints));
    let mut bad = c.points.clone();
    bad[7000].y = Real::NAN;
    bad[9000].z = Real::INFINITY;
    assert_eq!(
        segment_planes(&bad, &opts),
        Err(SegmentError::NonFinite { index: 7000 })
    );
    bad[100].x = 2e9;
    assert_eq!(
        estimate_normals(&bad, 8, None),
        Err(SegmentError::NonFinite { index: 100 })
    );
    assert_eq!(
        ransac_plane(&bad, &ransac_opts(1)),
        Err(SegmentError::NonFinite { index: 100 })
    );
    assert!(matches!(
        KdIndex::new(&bad),
        Err(SegmentError::NonFinite { index: 100 })
    ));
    for o in [
        PlaneSegmentOptions {
            cell_mm: 0.0,
            ..opts
        },
        PlaneSegmentOptions {
            cell_mm: Real::NAN,
            ..opts
        },
        PlaneSegmentOptions {
            max_angle_rad: 0.0,
            ..opts
        },
        PlaneSegmentOptions {
            max_angle_rad: 2.0,
            ..opts
        },
        PlaneSegmentOptions {
            max_distance_mm: -1.0,
            ..opts
        },
        PlaneSegmentOptions {
            robust: RobustRule {
                k_sigma: Real::NAN,
                max_iterations: 3,
            },
            ..opts
        },
    ] {
        assert!(matches!(
            segment_planes(&c.points, &o),
            Err(SegmentError::BadOptions(_))
        ));
    }
    let fine = PlaneSegmentOptions {
        cell_mm: 1e-4,
        ..opts
    };
    match segment_planes(&c.points, &fine) {
        Err(SegmentError::BadOptions(m)) => {
            assert!(m.contains("use a cell of at least"), "{m}")
        }
        other => panic!("{other:?}"),
    }
    let far = [
        Point3::origin(),
        Point3::new(1e9, -1e9, 1e9),
        Point3::new(1.0, 2.0, 3.0),
    ];
    assert!(matches!(
        segment_planes(&far, &opts),
        Err(SegmentError::BadOptions(_))
    ));
    let tiny = PlaneSegmentOptions {
        cell_mm: 1e-300,
        ..opts
    };
    assert!(matches!(
        segment_planes(&far, &tiny),
        Err(SegmentError::BadOptions(_))
    ));
    // Nothing planar: a line, or too few points.
    let line: Vec<Point3> = (0..5000)
        .map(|i| Point3::new(i as Real * 0.01, 0.0, 0.0))
        .collect();
    assert_eq!(
        segment_planes(&line, &opts),
        Err(SegmentError::NothingFound)
    );
    let big = PlaneSegmentOptions {
        min_points: 20_000,
        ..opts
    };
    assert_eq!(
        segment_planes(&c.points, &big),
        Err(SegmentError::NothingFound)
    );
    assert!(matches!(
        select_region_from_seed(&c.points, &Point3::new(Real::NAN, 0.0, 0.0), &opts),
        Err(SegmentError::BadOptions(_))
    ));
    assert!(matches!(
        estimate_normals(&c.points, 2, None),
        Err(SegmentError::BadOptions(_))
    ));
    assert_eq!(
        estimate_normals(&c.points[..2], 5, None),
        Err(SegmentError::NothingFound)
    );
    assert!(matches!(
        ransac_plane(
            &c.points,
            &RansacOptions {
                iterations: 0,
                ..ransac_opts(1)
            }
        ),
        Err(SegmentError::BadOptions(_))
    ));
    assert!(matches!(
        ransac_sphere(
            &c.points,
            &RansacOptions {
                distance_mm: 0.0,
                ..ransac_opts(1)
            }
        ),
        Err(SegmentError::BadOptions(_))
    ));
    assert_eq!(
        ransac_sphere(&c.points[..3], &ransac_opts(1)),
        Err(SegmentError::NothingFound)
    );
}

/// Small awkward point sets: duplicates, collinear and coplanar runs, NaN, ±∞, huge.
fn awkward_points() -> impl Strategy<Value = Vec<Point3>> {
    let coord = prop_oneof![
        8 => (-3i32..4).prop_map(|v| v as Real * 0.5),
        1 => Just(Real::NAN),
        1 => Just(Real::INFINITY),
        1 => Just(1e12),
        1 => -1e3..1e3f64,
    ];
    let point = (coord.clone(), coord.clone(), coord).prop_map(|(x, y, z)| Point3::new(x, y, z));
    prop_oneof![
        proptest::collection::vec(point.clone(), 0..60),
        // Mostly finite, with long duplicate and collinear runs.
        (proptest::collection::vec(point, 1..8), 1usize..40).prop_map(|(base, reps)| {
            let mut v = Vec::new();
            for (k, p) in base.iter().enumerate() {
                for r in 0..reps {
                    let shift = if k % 2 == 0 { 0.0 } else { r as Real * 0.1 };
                    v.push(Point3::new(p.x + shift, p.y, p.z));
                }
            }
            v
        }),
    ]
}

pub(super) fn check_indices(idx: &[u32], n: usize) {
    assert!(idx.windows(2).all(|w| w[0] < w[1]));
    assert!(idx.iter().all(|&i| (i as usize) < n));
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(1024))]

    #[test]
    fn awkward_inputs_never_panic(
        pts in awkward_points(),
        cell in prop_oneof![Just(0.3), Just(1.0), Just(7.0), Just(1e-7), Just(-1.0), Just(Real::NAN)],
        min_points in 0usize..12,
        k in 0usize..12,
        iterations in 0usize..30,
        seed in any::<u64>(),
    ) {
        let opts = PlaneSegmentOptions {
            cell_mm: cell,
            max_angle_rad: 0.3,
            max_distance_mm: 0.2,
            min_points,
            robust: RobustRule::default(),
        };
        if let Ok(segs) = segment_planes(&pts, &opts) {
            let mut all: Vec<u32> = Vec::new();
            for s in &segs {
                check_indices(&s.indices, pts.len());
                prop_assert_eq!(s.fit.n_used + s.fit.n_rejected, s.indices.len());
                all.extend(&s.indices);
            }
            all.sort_unstable();
            prop_assert!(all.windows(2).all(|w| w[0] < w[1]), "disjoint");
        }
        let seed_point = pts.first().copied().unwrap_or_else(Point3::origin);
        if let Ok(s) = select_region_from_seed(&pts, &seed_point, &opts) {
            check_indices(&s.indices, pts.len());
        }
        if let Ok(n) = estimate_normals(&pts, k, Some(Point3::new(0.0, 0.0, 50.0))) {
            prop_assert_eq!(n.len(), pts.len());
            prop_assert!(n.iter().all(|v| (v.norm() - 1.0).abs() < 1e-9));
        }
        let ro = RansacOptions { distance_mm: 0.2, iterations, seed, min_inliers: min_points };
        if let Ok(i) = ransac_plane(&pts, &ro) {
            check_indices(&i, pts.len());
        }
        if let Ok(m) = ransac_sphere(&pts, &ro) {
            check_indices(&m.inliers, pts.len());
        }
        let normals = vec![UnitVector3::new_normalize(Vector3::new(0.3, 0.4, 1.0)); pts.len()];
        if let Ok(m) = ransac_cylinder(&pts, &normals, &ro) {
            check_indices(&m.inliers, pts.len());
        }
        if let Ok(index) = KdIndex::new(&pts) {
            let q = pts[pts.len() / 2];
            prop_assert!(index.nearest(&q, k).len() <= k);
            let _ = index.within(&q, cell.abs());
        }
        check_indices(&select_box(&pts, &Point3::new(-1.0, -1.0, -1.0), &Point3::new(1.0, 1.0, 1.0)), pts.len());
    }
}
