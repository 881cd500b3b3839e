//! Seed 001's calibration of the hexapod from gauge-block / touch-probe readings, graded
//! here: the machining-centre scene starts at ≥ 0.3 mm positioning and ≥ 0.5 mm pivot
//! error, and two rounds bring it to ≤ 15 µm and ≤ 20 µm — both figures computed by this
//! test's own kinematics (its own inverse kinematics of the controller, its own Newton
//! forward kinematics of the machine, `hexapod_calibration::Geometry`) on poses of its
//! own: the 5 × 5 × 5 grid over the workspace and random level points for positioning,
//! pivot swings over ±tilt about points none of the measured plan's.

use super::hexapod_calibration::Geometry;
use super::hexapod_centre as centre;
use twinmill::calibration::hexapod_probe::{
    ProbeError, ProbeOptions, calibrate, default_plan, identify, measure,
};
use twinmill::machine::hexapod::{Hexapod, Pose};
use twinmill::machine::hexapod_accuracy::Workspace;
use twinmill::math::{CounterRng, Real, Vector3};

/// The probe's noise in the acceptance run (mm): a touch probe against gauge blocks.
const SIGMA_MM: Real = 0.0015;

/// The largest level positioning error and the largest pivot travel of `actual` driven by
/// a controller on `controller`, by this test's kinematics, over its own poses: the
/// 5 × 5 × 5 grid spanning `ws` and 40 random level points; pivot at the centre, four
/// points 0.3 of the half-widths from it and four random points, each swung to the 5 × 5
/// grid of a, b over ±tilt and 8 random orientations within it (mm).
fn own_errors(controller: &Hexapod, actual: &Hexapod, ws: &Workspace) -> (Real, Real) {
    let (c, m) = (Geometry::of(controller), Geometry::of(actual));
    let tip = |v: [Real; 6]| {
        let r = m.reached(&c.readings(&v), &v);
        Vector3::new(r[0], r[1], r[2])
    };
    let rng = CounterRng::new(0x0070_726f_6265);
    let lin = |(lo, hi): (Real, Real), f: Real| lo + (hi - lo) * f;
    let mut level: Vec<[Real; 3]> = (0..125)
        .map(|n| {
            let f = |k: usize| (k % 5) as Real / 4.0;
            [
                lin(ws.x_mm, f(n)),
                lin(ws.y_mm, f(n / 5)),
                lin(ws.z_mm, f(n / 25)),
            ]
        })
        .collect();
    level.extend((0..40).map(|n| {
        [
            lin(ws.x_mm, rng.uniform(n, 0)),
            lin(ws.y_mm, rng.uniform(n, 1)),
            lin(ws.z_mm, rng.uniform(n, 2)),
        ]
    }));
    let mut position: Real = 0.0;
    for p in &level {
        let v = [p[0], p[1], p[2], 0.0, 0.0, 0.0];
        if controller.check_pose(&Pose::from_mm_deg(v)).is_err() {
            continue;
        }
        position = position.max((tip(v) - Vector3::new(p[0], p[1], p[2])).norm());
    }
    let mut points: Vec<[Real; 3]> = [
        (0.5, 0.5),
        (0.35, 0.35),
        (0.65, 0.35),
        (0.35, 0.65),
        (0.65, 0.65),
    ]
    .iter()
    .map(|&(fx, fy)| [lin(ws.x_mm, fx), lin(ws.y_mm, fy), lin(ws.z_mm, 0.55)])
    .collect();
    points.extend((100..104).map(|n| {
        [
            lin(ws.x_mm, 0.2 + 0.6 * rng.uniform(n, 0)),
            lin(ws.y_mm, 0.2 + 0.6 * rng.uniform(n, 1)),
            lin(ws.z_mm, 0.3 + 0.4 * rng.uniform(n, 2)),
        ]
    }));
    let t = ws.tilt_deg.to_radians();
    let mut pivot: Real = 0.0;
    for (j, p) in points.iter().enumerate() {
        let zero = tip([p[0], p[1], p[2], 0.0, 0.0, 0.0]);
        let mut angles: Vec<(Real, Real)> = (0..25)
            .map(|n| {
                (
                    lin((-t, t), (n % 5) as Real / 4.0),
                    lin((-t, t), (n / 5) as Real / 4.0),
                )
            })
            .collect();
        angles.extend((0..8).map(|k| {
            let s = 1000 + 8 * j as u64 + k;
            (
                lin((-t, t), rng.uniform(s, 0)),
                lin((-t, t), rng.uniform(s, 1)),
            )
        }));
        for (a, b) in angles {
            let v = [p[0], p[1], p[2], a, b, 0.0];
            if controller
                .check_pose(&Pose::from_mm_deg([
                    p[0],
                    p[1],
                    p[2],
                    a.to_degrees(),
                    b.to_degrees(),
                    0.0,
                ]))
                .is_err()
            {
                continue;
            }
            pivot = pivot.max((tip(v) - zero).norm());
        }
    }
    (position, pivot)
}

fn options(rounds: usize) -> ProbeOptions {
    ProbeOptions {
        rounds,
        sigma_mm: SIGMA_MM,
        seed: 1,
        accept_misfit: false,
    }
}

#[test]
fn hexapod_probe_two_rounds_bring_the_machining_centre_to_15_and_20_um() {
    let s = centre();
    let ws = s.workspace.expect("workspace");
    let (pos0, piv0) = own_errors(&s.nominal, &s.actual, &ws);
    // Seed 001's starting point: about 0.30 mm positioning, 0.50 mm pivot.
    assert!(pos0 >= 0.3, "positioning before {pos0} mm");
    assert!(piv0 >= 0.5, "pivot before {piv0} mm");
    let cal = calibrate(&s.nominal, &s.actual, &ws, &options(2)).expect("calibrates");
    assert_eq!(cal.rounds.len(), 2);
    let controller = cal.controller.as_ref().expect("controller");
    let (pos2, piv2) = own_errors(controller, &s.actual, &ws);
    assert!(pos2 <= 0.015, "positioning after two rounds {pos2} mm");
    assert!(piv2 <= 0.020, "pivot after two rounds {piv2} mm");
    // Round 1 alone already removes most of it; the library's own survey of the final
    // controller agrees in size with this test's figures (not the same poses: within a
    // factor of two and 5 µm).
    let r1 = &cal.rounds[0];
    let (pos1, piv1) = {
        let c1 = s
            .nominal
            .with_parameters(&r1.identification.parameters)
            .expect("round-1 controller");
        own_errors(&c1, &s.actual, &ws)
    };
    assert!(pos1 < 0.1 * pos0 && piv1 < 0.1 * piv0, "{pos1} {piv1}");
    let last = &cal.rounds[1].after;
    assert!(
        last.positioning_mm <= 2.0 * pos2 + 0.005,
        "{last:?} vs {pos2}"
    );
    assert!(last.pivot_mm <= 2.0 * piv2 + 0.005, "{last:?} vs {piv2}");
    // Every round's readings fit the identified machine at the stated σ.
    assert!(cal.rounds.iter().all(|r| r.identification.fit.fits));
}

/// A tool-point probe cannot see the platform turned about the tool point: exactly three
/// directions of platform joints alone are not determined, and they are named.
#[test]
fn hexapod_probe_names_the_three_platform_rotations_about_the_tool_point() {
    let s = centre();
    let ws = s.workspace.expect("workspace");
    let plan = default_plan(&s.nominal, &ws);
    let r = measure(&s.nominal, &s.actual, &plan, SIGMA_MM, 5).expect("measures");
    let id = identify(&s.nominal, &plan, &r, false).expect("identifies");
    // Three directions of platform joints alone (their names hold `a`-joints only) are
    // not determined, besides what the noise leaves weak.
    let platform_only = id
        .not_determined
        .iter()
        .filter(|n| !["bx_", "by_", "bz_", "l0_"].iter().any(|b| n.contains(b)))
        .count();
    assert_eq!(platform_only, 3, "{:?}", id.not_determined);
    assert!(id.rank <= 39, "{:?}", id.not_determined);
    // An independent check that such a rotation is invisible: the platform joints turned
    // by 1 mrad about z through the tool point reach the same tool points.
    let o = s.nominal.tool_offset();
    let mut p = s.actual.parameters();
    let rot = nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), 1e-3);
    for (i, a) in s.actual.platform_joints().iter().enumerate() {
        let q = rot * (a - o) + o;
        p[18 + 3 * i..21 + 3 * i].copy_from_slice(q.as_slice());
    }
    let turned = s.actual.with_parameters(&p).expect("turned");
    let rt = measure(&s.nominal, &turned, &plan, 0.0, 5).expect("measures");
    let r0 = measure(&s.nominal, &s.actual, &plan, 0.0, 5).expect("measures");
    let d = rt
        .flat()
        .iter()
        .zip(r0.flat())
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, Real::max);
    assert!(d < 1e-8, "{d} mm");
}

#[test]
fn hexapod_probe_refuses_readings_noisier_than_stated_and_bad_options() {
    let s = centre();
    let ws = s.workspace.expect("workspace");
    let plan = default_plan(&s.nominal, &ws);
    let mut r = measure(&s.nominal, &s.actual, &plan, 0.006, 9).expect("measures");
    r.sigma_mm = 0.0015;
    match identify(&s.nominal, &plan, &r, false) {
        Err(ProbeError::Misfit(m)) => assert!(m.contains("refused"), "{m}"),
        other => panic!("expected a misfit refusal, got {other:?}"),
    }
    assert!(identify(&s.nominal, &plan, &r, true).is_ok());
    for (rounds, sigma) in [(0, 0.0015), (2, 0.0), (2, Real::NAN)] {
        let o = ProbeOptions {
            rounds,
            sigma_mm: sigma,
            ..options(2)
        };
        assert!(matches!(
            calibrate(&s.nominal, &s.actual, &ws, &o),
            Err(ProbeError::Input(_))
        ));
    }
}
