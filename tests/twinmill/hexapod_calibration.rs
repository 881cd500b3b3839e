//! The virtual double ball bar on the hexapod and seed 000's calibration: a perfect machine
//! reads zero, a strut-length offset reads what a first-order derivation written here
//! predicts, the identifiability of the two procedures (the six base-frame gauge directions
//! named without a jig; all 24 parameters with the ball plate), the calibration round trip
//! over seeded trials — machines drawn, measured and graded by the test, pose errors from
//! its own kinematics — and bad input.

use super::{Sandbox, dbb_readings, hexapod_centre as centre};
use std::path::Path;
use twinmill::calibration::hexapod_calibrate::{
    CircleReadings, DEFAULT_POINTS, Plan, Procedure, TableCalibration, calibrate, calibrated_model,
    default_plan, gauge_names, pose_errors, tool_table_calibration,
};
use twinmill::calibration::hexapod_design::{CircleDesign, design, reachable};
use twinmill::machine::hexapod::{Hexapod, ParameterId, Pose};
use twinmill::machine::hexapod_accuracy::Workspace;
use twinmill::math::{Real, Vector3};
use twinmill::metrology::ballbar::Turns;
use twinmill::metrology::circular::{CircularOptions, evaluate, parse_trace};
use twinmill::metrology::hexapod_dbb::{DbbCircle, DbbInstrument, DbbPlane, measure};
use twinmill::pipeline::dbb::{CALIBRATION_NOISE_MM, parse_plan, plan_toml, trial_machine};
use twinmill::scene::HexapodScene;

fn workspace(s: &HexapodScene) -> Workspace {
    s.workspace.expect("the scene has a [workspace]")
}

fn circle(plane: DbbPlane, tilt_deg: Real, orientation_deg: [Real; 3]) -> DbbCircle {
    DbbCircle {
        centre_mm: Vector3::new(50.0, -30.0, 250.0),
        radius_mm: 100.0,
        plane,
        tilt_deg,
        orientation_deg,
        swing_deg: 0.0,
        turns: Turns::Both,
        points: 72,
    }
}

fn quiet() -> DbbInstrument {
    DbbInstrument {
        mount_mm: Vector3::zeros(),
        noise_sigma_mm: 0.0,
        seed: 1,
        stream: 0,
    }
}

#[test]
fn dbb_on_a_perfect_machine_reads_zero_in_every_plane_tilt_and_orientation() {
    let s = centre();
    for plane in [DbbPlane::XY, DbbPlane::YZ, DbbPlane::ZX] {
        for (tilt, o) in [
            (0.0, [0.0; 3]),
            (30.0, [10.0, -5.0, 20.0]),
            (-45.0, [0.0, 12.0, 0.0]),
        ] {
            let m = measure(&s.nominal, &s.nominal, &circle(plane, tilt, o), &quiet())
                .expect("measurable");
            let worst = m
                .samples
                .iter()
                .map(|x| x.deviation_mm.abs())
                .fold(0.0, Real::max);
            assert!(worst < 1e-9, "{plane:?} tilt {tilt}: {worst} mm");
            assert_eq!(m.samples.len(), 144);
        }
    }
}

/// A first-order derivation independent of the library's Jacobians: with strut i longer by
/// δ than the controller believes, the tool point moves by `δ·J_o[:, i]` where `J_o` is the
/// inverse of the strut Jacobian, here formed by central differences of the lengths
/// `|t + R·(a − o) − b|` written out from the scene's joints; the bar's length changes by
/// `u · δp`, `u` the bar's unit vector from the table ball to the tool ball.
#[test]
fn a_strut_length_offset_reads_the_first_order_prediction() {
    let s = centre();
    let delta = 0.01;
    let mut actual = s.nominal.clone();
    let id = ParameterId::from_name("l0_3").expect("known");
    actual
        .set_parameter(id, s.nominal.parameter(id) + delta)
        .expect("finite");
    let c = circle(DbbPlane::XY, 30.0, [5.0, -5.0, 0.0]);
    let m = measure(&s.nominal, &actual, &c, &quiet()).expect("measurable");
    let h: &Hexapod = &s.nominal;
    let (b, a, o) = (h.base_joints(), h.platform_joints(), h.tool_offset());
    let lengths = |v: [Real; 6]| -> [Real; 6] {
        let (ca, sa) = v[3].cos_sin();
        let (cb, sb) = v[4].cos_sin();
        let (cc, sc) = v[5].cos_sin();
        let rx = nalgebra::Matrix3::new(1.0, 0.0, 0.0, 0.0, ca, -sa, 0.0, sa, ca);
        let ry = nalgebra::Matrix3::new(cb, 0.0, sb, 0.0, 1.0, 0.0, -sb, 0.0, cb);
        let rz = nalgebra::Matrix3::new(cc, -sc, 0.0, sc, cc, 0.0, 0.0, 0.0, 1.0);
        let r = rz * ry * rx;
        let t = Vector3::new(v[0], v[1], v[2]);
        std::array::from_fn(|i| (t + r * (a[i] - o) - b[i]).norm())
    };
    let mut worst: Real = 0.0;
    for (sample, cmd) in m.samples.iter().zip(&m.commands) {
        let v = cmd.to_vector();
        let v: [Real; 6] = std::array::from_fn(|k| v[k]);
        let mut j = nalgebra::Matrix6::<Real>::zeros();
        for k in 0..6 {
            let e = if k < 3 { 1e-4 } else { 1e-7 };
            let (mut p, mut q) = (v, v);
            p[k] += e;
            q[k] -= e;
            let (lp, lq) = (lengths(p), lengths(q));
            for i in 0..6 {
                j[(i, k)] = (lp[i] - lq[i]) / (2.0 * e);
            }
        }
        let jo = j.try_inverse().expect("regular");
        let dp = Vector3::new(jo[(0, 2)], jo[(1, 2)], jo[(2, 2)]) * delta;
        let u = (cmd.position - c.centre_mm).normalize();
        let predicted = u.dot(&dp);
        worst = worst.max((sample.deviation_mm - predicted).abs());
    }
    // Second order: |δp|²/(2R) and the Jacobian's change over δp, about 1e-6 mm here.
    assert!(worst < 2e-6, "first-order prediction off by {worst} mm");
    let peak = m
        .samples
        .iter()
        .map(|x| x.deviation_mm.abs())
        .fold(0.0, Real::max);
    assert!(peak > 2e-3, "the offset shows: {peak} mm");
}

trait CosSin {
    fn cos_sin(self) -> (Real, Real);
}
impl CosSin for Real {
    fn cos_sin(self) -> (Real, Real) {
        (self.cos(), self.sin())
    }
}

fn readings(s: &HexapodScene, actual: &Hexapod, procedure: Procedure) -> Vec<CircleReadings> {
    let plan = default_plan(procedure, &workspace(s), DEFAULT_POINTS);
    dbb_readings(&s.nominal, actual, &plan.circles, 0.0, 1, |_| {
        Vector3::zeros()
    })
}

#[test]
fn length_only_data_lose_exactly_the_six_named_base_frame_gauge_directions() {
    let s = centre();
    let plan = default_plan(Procedure::JigFree, &workspace(&s), DEFAULT_POINTS);
    assert_eq!(plan.circles.len(), 15);
    let r = readings(&s, &s.actual, Procedure::JigFree);
    let cal = calibrate(&s.nominal, &s.actual, &plan, &r, 0.5e-3).expect("solves");
    let id = &cal.identifiability;
    assert_eq!(id.unknowns, 24 + 45);
    assert_eq!(id.rank, id.unknowns - 6, "rank = parameters − 6");
    assert_eq!(id.parameters_determined, 18);
    assert_eq!(id.gauge, gauge_names());
    assert!(id.gauge[0].contains("translation x") && id.gauge[5].contains("rotation about z"));
    assert!(
        id.undetermined_outside_gauge < 1e-6,
        "the undetermined subspace is the named gauge: {}",
        id.undetermined_outside_gauge
    );
    // The six smallest singular values are rounding against the seventh (the Jacobian is
    // formed through FK solved to 1e-9 mm): a gap of more than three orders.
    let sv = &id.singular_values;
    assert!(sv[sv.len() - 6] < 1e-3 * sv[sv.len() - 7], "{sv:?}");
    assert!(id.weak.is_empty(), "{:?}", id.weak);
}

#[test]
fn the_ball_plate_determines_all_24_parameters() {
    let s = centre();
    let plan = default_plan(Procedure::BallPlate, &workspace(&s), DEFAULT_POINTS);
    assert_eq!(plan.circles.len(), 7);
    let r = readings(&s, &s.actual, Procedure::BallPlate);
    let cal = calibrate(&s.nominal, &s.actual, &plan, &r, 0.5e-3).expect("solves");
    let id = &cal.identifiability;
    assert_eq!(id.unknowns, 24);
    assert_eq!(id.rank, 24);
    assert_eq!(id.parameters_determined, 24);
    assert!(id.gauge.is_empty());
}

// ---------------------------------------------------------------------------------------
// The calibration round trip, graded here: the test draws each trial's machine, measures its
// circles with its own mounting errors and noise seeds, has the library identify them, and
// compares with what it injected — in the report's gauge worked out here — and measures the
// calibrated controller's pose errors with its own inverse and forward kinematics.

/// The platform pose's rotation `R = Rz(c)·Ry(b)·Rx(a)` (a, b, c in rad).
pub(crate) fn rotation(a: Real, b: Real, c: Real) -> nalgebra::Matrix3<Real> {
    let (sa, ca) = a.sin_cos();
    let (sb, cb) = b.sin_cos();
    let (sc, cc) = c.sin_cos();
    let rx = nalgebra::Matrix3::new(1.0, 0.0, 0.0, 0.0, ca, -sa, 0.0, sa, ca);
    let ry = nalgebra::Matrix3::new(cb, 0.0, sb, 0.0, 1.0, 0.0, -sb, 0.0, cb);
    let rz = nalgebra::Matrix3::new(cc, -sc, 0.0, sc, cc, 0.0, 0.0, 0.0, 1.0);
    rz * ry * rx
}

/// A machine's geometry as this test reads it: base joints `b_i`, platform joints `a_i`,
/// tool point `o` (platform frame) and reference lengths `l0_i`.
pub(crate) struct Geometry {
    pub(crate) b: [Vector3; 6],
    pub(crate) a: [Vector3; 6],
    pub(crate) o: Vector3,
    pub(crate) l0: [Real; 6],
}

impl Geometry {
    pub(crate) fn of(h: &Hexapod) -> Geometry {
        let l0 = std::array::from_fn(|i| {
            h.parameter(ParameterId::from_name(&format!("l0_{}", i + 1)).expect("known"))
        });
        Geometry {
            b: *h.base_joints(),
            a: *h.platform_joints(),
            o: h.tool_offset(),
            l0,
        }
    }

    /// Strut lengths `|t + R·(a_i − o) − b_i|` at the pose `v` = (x, y, z mm; a, b, c rad).
    pub(crate) fn lengths(&self, v: &[Real; 6]) -> [Real; 6] {
        let r = rotation(v[3], v[4], v[5]);
        let t = Vector3::new(v[0], v[1], v[2]);
        std::array::from_fn(|i| (t + r * (self.a[i] - self.o) - self.b[i]).norm())
    }

    /// The drives' readings a controller on this geometry commands for `v`: `L_i − l0_i`.
    pub(crate) fn readings(&self, v: &[Real; 6]) -> [Real; 6] {
        let l = self.lengths(v);
        std::array::from_fn(|i| l[i] - self.l0[i])
    }

    /// The pose this machine takes for `readings` (lengths `l0_i + s_i`): Newton from
    /// `near` on central-difference Jacobians, to 1e-12 mm.
    pub(crate) fn reached(&self, readings: &[Real; 6], near: &[Real; 6]) -> [Real; 6] {
        let want: [Real; 6] = std::array::from_fn(|i| self.l0[i] + readings[i]);
        let mut v = *near;
        for _ in 0..30 {
            let l = self.lengths(&v);
            let f = nalgebra::Vector6::from_fn(|i, _| l[i] - want[i]);
            if f.amax() < 1e-12 {
                return v;
            }
            let mut j = nalgebra::Matrix6::<Real>::zeros();
            for k in 0..6 {
                let e = if k < 3 { 1e-4 } else { 1e-7 };
                let (mut p, mut q) = (v, v);
                p[k] += e;
                q[k] -= e;
                let (lp, lq) = (self.lengths(&p), self.lengths(&q));
                for i in 0..6 {
                    j[(i, k)] = (lp[i] - lq[i]) / (2.0 * e);
                }
            }
            let step = j.lu().solve(&f).expect("a regular pose");
            for k in 0..6 {
                v[k] -= step[k];
            }
        }
        panic!("forward kinematics did not converge near {near:?}");
    }
}

/// The pose errors of `actual` driven by a controller on `controller`: the largest level
/// positioning error over the 5 × 5 × 5 grid of the workspace, and the largest pivot error
/// (the tool tip's travel from its level position with a and b over ±min(tilt, 15°), five
/// steps each) at the workspace's centre and four points half way to its corners, mid
/// height (mm). Grid points the nominal machine cannot reach are left out.
pub(crate) fn own_pose_errors(
    nominal: &Hexapod,
    controller: &Hexapod,
    actual: &Hexapod,
    ws: &Workspace,
) -> (Real, Real) {
    let (c, m) = (Geometry::of(controller), Geometry::of(actual));
    let tip = |v: [Real; 6]| {
        let r = m.reached(&c.readings(&v), &v);
        Vector3::new(r[0], r[1], r[2])
    };
    let lin =
        |(lo, hi): (Real, Real), k: usize, n: usize| lo + (hi - lo) * k as Real / (n - 1) as Real;
    let mut position: Real = 0.0;
    for (i, j, k) in (0..125).map(|n| (n % 5, (n / 5) % 5, n / 25)) {
        let v = [
            lin(ws.x_mm, i, 5),
            lin(ws.y_mm, j, 5),
            lin(ws.z_mm, k, 5),
            0.0,
            0.0,
            0.0,
        ];
        if nominal.check_pose(&Pose::from_mm_deg(v)).is_err() {
            continue;
        }
        position = position.max((tip(v) - Vector3::new(v[0], v[1], v[2])).norm());
    }
    let mid = |(lo, hi): (Real, Real)| 0.5 * (lo + hi);
    let half = |(lo, hi): (Real, Real)| 0.5 * (hi - lo);
    let tilt = ws.tilt_deg.min(15.0).to_radians();
    let mut pivot: Real = 0.0;
    for (fx, fy) in [
        (0.0, 0.0),
        (0.5, 0.5),
        (-0.5, 0.5),
        (-0.5, -0.5),
        (0.5, -0.5),
    ] {
        let p = [
            mid(ws.x_mm) + fx * half(ws.x_mm),
            mid(ws.y_mm) + fy * half(ws.y_mm),
            mid(ws.z_mm),
        ];
        let level = tip([p[0], p[1], p[2], 0.0, 0.0, 0.0]);
        for n in 0..25 {
            let (a, b) = (lin((-tilt, tilt), n % 5, 5), lin((-tilt, tilt), n / 5, 5));
            pivot = pivot.max((tip([p[0], p[1], p[2], a, b, 0.0]) - level).norm());
        }
    }
    (position, pivot)
}

/// The rigid motion (Kabsch: SVD of the cross-covariance) best mapping `from` onto `to`.
fn kabsch(from: &[Vector3; 6], to: &[Vector3; 6]) -> (nalgebra::Matrix3<Real>, Vector3) {
    let cf = from.iter().sum::<Vector3>() / 6.0;
    let ct = to.iter().sum::<Vector3>() / 6.0;
    let h = from
        .iter()
        .zip(to)
        .fold(nalgebra::Matrix3::zeros(), |h, (f, t)| {
            h + (f - cf) * (t - ct).transpose()
        });
    let svd = h.svd(true, true);
    let (u, vt) = (svd.u.expect("u"), svd.v_t.expect("vᵀ"));
    let d = (vt.transpose() * u.transpose()).determinant().signum();
    let q = vt.transpose()
        * nalgebra::Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d))
        * u.transpose();
    (q, ct - q * cf)
}

/// Seeded trials graded here: each trial's actual machine is the scene's (its platform joints,
/// known from a CMM) with base joints and reference lengths drawn by this test uniformly
/// within ±0.5 mm and ±0.2 mm of nominal; the plan's circles are measured on it (bar noise σ
/// 0.5 µm; jig-free, each table ball mounted up to ±0.05 mm off per coordinate) and
/// identified by `calibrate`, which sees the nominal machine and the platform joints only.
/// The truth is what this test injected, in the report's gauge (jig-free: the actual base
/// joints moved by the rigid motion best fitting them onto the nominal ones, a bar seeing
/// lengths only). Asserts every parameter within 3σ in ≥ 95 % of cases, the spread of each
/// parameter's errors matching its σ both ways (`crate::assert_spread_matches_sigma`), and
/// the pose errors after calibration — the controller `calibrated_model` gives (jig-free:
/// base frame placed by the tool table calibration) on the actual machine, worked out by
/// [`own_pose_errors`] — within `after` (position, pivot; mm), the worst over the trials.
fn round_trip_with(s: &HexapodScene, plan: &Plan, trials: u64, after: (Real, Real)) {
    let ws = workspace(s);
    let pn = s.nominal.parameters();
    let mut state: u64 = 0x000d_bb00 + plan.circles.len() as u64;
    let mut uniform = || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((state >> 11) as Real / (1u64 << 53) as Real) * 2.0 - 1.0
    };
    // What the calibration may know: the nominal machine with the actual platform joints.
    let mut known = s.nominal.parameters();
    known[18..36].copy_from_slice(&s.actual.parameters()[18..36]);
    let known = s.nominal.with_parameters(&known).expect("valid");
    let names: Vec<String> = (0..18)
        .chain(36..42)
        .map(|k| ParameterId::new(k).expect("a parameter").name())
        .collect();
    let mut z: Vec<Vec<Real>> = vec![Vec::new(); names.len()];
    let (mut inside, mut compared) = (0usize, 0usize);
    let (mut before, mut worst) = ((0.0, 0.0), (0.0, 0.0));
    for t in 0..trials {
        let mut p = known.parameters();
        for k in (0..18).chain(36..42) {
            p[k] = pn[k] + uniform() * if k < 18 { 0.5 } else { 0.2 };
        }
        let actual = s.nominal.with_parameters(&p).expect("a machine");
        let readings = dbb_readings(&s.nominal, &actual, &plan.circles, 0.5e-3, 7000 + t, |_| {
            if plan.balls_known() {
                Vector3::zeros()
            } else {
                Vector3::new(uniform(), uniform(), uniform()) * 0.05
            }
        });
        let cal = calibrate(&s.nominal, &known, plan, &readings, 0.5e-3).expect("solves");
        // The truth in the report's gauge.
        let mut truth = p;
        if !plan.balls_known() {
            let b: [Vector3; 6] =
                std::array::from_fn(|i| Vector3::new(p[3 * i], p[3 * i + 1], p[3 * i + 2]));
            let (q, shift) = kabsch(&b, s.nominal.base_joints());
            for (i, bi) in b.iter().enumerate() {
                truth[3 * i..3 * i + 3].copy_from_slice((q * bi + shift).as_slice());
            }
        }
        assert_eq!(cal.estimates.len(), 24);
        for e in &cal.estimates {
            let k = ParameterId::from_name(&e.name)
                .expect("a parameter")
                .index();
            let n = names
                .iter()
                .position(|n| *n == e.name)
                .expect("one of the 24");
            let err = e.value_mm - (truth[k] - pn[k]);
            compared += 1;
            if err.abs() <= 3.0 * e.sigma_mm {
                inside += 1;
            }
            z[n].push(err / e.sigma_mm);
        }
        let (controller, _) =
            calibrated_model(&cal, &known, &actual, &ws, TableCalibration::Tool).expect("placed");
        let b = own_pose_errors(&s.nominal, &s.nominal, &actual, &ws);
        let a = own_pose_errors(&s.nominal, &controller, &actual, &ws);
        before = (Real::max(before.0, b.0), Real::max(before.1, b.1));
        worst = (Real::max(worst.0, a.0), Real::max(worst.1, a.1));
    }
    let share = inside as Real / compared as Real;
    assert!(share >= 0.95, "{share:.3} of parameters within 3σ");
    crate::assert_spread_matches_sigma(&names, &z);
    assert!(before.0 > 0.1 && before.1 > 0.05, "before: {before:?}");
    assert!(
        worst.0 <= after.0 && worst.1 <= after.1,
        "after: position {:.1} µm, pivot {:.1} µm (before {:.0} / {:.0} µm)",
        worst.0 * 1e3,
        worst.1 * 1e3,
        before.0 * 1e3,
        before.1 * 1e3
    );
}

fn round_trip(procedure: Procedure, trials: u64, after: (Real, Real)) {
    let s = centre();
    let plan = default_plan(procedure, &workspace(&s), DEFAULT_POINTS);
    round_trip_with(&s, &plan, trials, after);
}

/// The fixed jig-free plan: the table balls' centres are estimated (three per circle), the
/// parameters' σ grow about 4× against known centres, and with its short bars near the
/// centre the pose errors after calibration stay in the 10–30 µm class (seed 000 reached
/// 15 / 20 µm) — the designed circles below reach ≤ 5 / 10 µm.
#[test]
fn jig_free_calibration_round_trip_over_seeded_trials() {
    round_trip(Procedure::JigFree, 100, (30e-3, 30e-3));
}

#[test]
fn ball_plate_calibration_round_trip_reaches_5_and_10_um() {
    round_trip(Procedure::BallPlate, 100, (5e-3, 10e-3));
}

#[test]
fn trial_machines_have_the_stated_deviation_class() {
    let s = centre();
    let a = trial_machine(&s, 7).expect("valid");
    let (pa, pn) = (a.parameters(), s.nominal.parameters());
    for k in 0..18 {
        assert!((pa[k] - pn[k]).abs() <= 0.5);
    }
    for k in 36..42 {
        assert!((pa[k] - pn[k]).abs() <= 0.2);
    }
    let _ = Pose::from_mm_deg([0.0; 6]);
}

#[test]
fn dbb_trace_file_is_what_evaluate_reads() {
    let s = centre();
    let c = circle(DbbPlane::XY, 0.0, [0.0; 3]);
    let inst = DbbInstrument {
        noise_sigma_mm: 0.5e-3,
        ..quiet()
    };
    let m = measure(&s.nominal, &s.actual, &c, &inst).expect("measurable");
    let back = parse_trace(&m.csv(&["x".into()]), Path::new("t.csv")).expect("parses");
    assert_eq!(back, m.samples);
    let opts = CircularOptions {
        radius_mm: 100.0,
        pitch_mm: None,
    };
    let f = evaluate(&back, &opts, Path::new("t.csv")).expect("evaluates");
    assert_eq!(f.directions.len(), 2);
    // Same seed, same trace.
    let again = measure(&s.nominal, &s.actual, &c, &inst).expect("measurable");
    assert_eq!(again.samples, m.samples);
}

#[test]
fn bad_dbb_set_ups_are_errors_not_panics() {
    let s = centre();
    let good = circle(DbbPlane::XY, 0.0, [0.0; 3]);
    let bad = [
        DbbCircle {
            radius_mm: 0.0,
            ..good.clone()
        },
        DbbCircle {
            radius_mm: Real::NAN,
            ..good.clone()
        },
        DbbCircle {
            tilt_deg: 90.0,
            ..good.clone()
        },
        DbbCircle {
            points: 3,
            ..good.clone()
        },
        DbbCircle {
            centre_mm: Vector3::new(0.0, 0.0, Real::INFINITY),
            ..good.clone()
        },
        // Far outside the strokes.
        DbbCircle {
            centre_mm: Vector3::new(0.0, 0.0, 5000.0),
            ..good.clone()
        },
    ];
    for c in &bad {
        assert!(
            measure(&s.nominal, &s.actual, c, &quiet()).is_err(),
            "{c:?}"
        );
    }
    let noisy = DbbInstrument {
        noise_sigma_mm: -1.0,
        ..quiet()
    };
    assert!(measure(&s.nominal, &s.actual, &good, &noisy).is_err());
}

#[test]
fn cli_measure_ballbar_and_identify_on_a_hexapod_and_bad_input() {
    let sb = Sandbox::new("hexapod-dbb");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/hexapod-machining-centre.toml");
    let scene = scene.to_str().expect("utf-8");
    let (code, _, err) = sb.run(&[
        "measure",
        scene,
        "--instrument",
        "ballbar",
        "--centre",
        "0,0,250",
        "--radius",
        "100",
        "--tilt",
        "30",
        "--direction",
        "both",
        "--out",
        "trace.csv",
        "--png",
        "trace.png",
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(sb.dir.join("trace.csv").exists() && sb.dir.join("trace.png").exists());
    let (code, _, err) = sb.run(&["evaluate", "iso230-4", "trace.csv", "--radius", "100"]);
    assert_eq!(code, 0, "{err}");
    let (code, out, err) = sb.run(&["identify", scene, "--procedure", "ball-plate", "--json"]);
    assert_eq!(code, 0, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).expect("json");
    assert_eq!(v["run"]["calibration"]["identifiability"]["rank"], 24);
    let dbb = ["measure", scene, "--instrument", "ballbar"];
    let with = |extra: &[&'static str]| [&dbb[..], extra].concat();
    for args in [
        with(&["--radius", "-1"]),
        with(&["--radius", "nan"]),
        with(&["--plane", "XQ"]),
        with(&["--centre", "1,2"]),
        with(&["--tilt", "95"]),
        with(&["--noise", "inf"]),
        with(&["--centre", "0,0,9000"]),
        // A serial ball bar's option, and an instrument a hexapod has not.
        with(&["--feed", "500"]),
        vec![
            "measure",
            scene,
            "--instrument",
            "laser",
            "--axis",
            "X",
            "--from",
            "0",
            "--to",
            "9",
        ],
        vec!["identify", scene, "--procedure", "jig"],
        vec!["identify", scene, "--cloud", "x.ply"],
        vec!["identify", "/nonexistent.toml"],
        // The old names refuse as before.
        vec!["ballbar", scene, "--direction", "up"],
        vec!["ballbar", scene, "--centre", "1,2"],
        vec!["calibrate", scene, "--procedure", "jig"],
    ] {
        let mut a = args.clone();
        if args[0] != "identify" && args[0] != "calibrate" {
            a.extend(["--out", "bad.csv", "--png", "bad.png"]);
        }
        let (code, _, err) = sb.run(&a);
        assert_ne!(code, 0, "{args:?}");
        assert_eq!(err.trim().lines().count(), 1, "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
        assert!(!sb.dir.join("bad.csv").exists() && !sb.dir.join("bad.png").exists());
        assert!(!sb.dir.join("bad.html").exists());
    }
}

/// The old names of the hexapod's verbs — `ballbar`, `calibrate`, `calibrate-design` — are
/// hidden from `--help` and do what they did: the same trace, calibration and plan as
/// `measure --instrument ballbar`, `identify` and `design`, written only where asked.
#[test]
fn the_old_hexapod_names_still_work_as_hidden_aliases() {
    let sb = Sandbox::new("hexapod-aliases");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/hexapod-machining-centre.toml");
    let scene = scene.to_str().expect("utf-8");
    let circle = [
        "--tilt", "30", "--radius", "90", "--noise", "0.7", "--seed", "3",
    ];
    let old = [&["ballbar", scene][..], &circle, &["--out", "old.csv"]].concat();
    let (code, old_out, err) = sb.run(&old);
    assert_eq!(code, 0, "{err}");
    let new = [
        &["measure", scene, "--instrument", "ballbar"][..],
        &circle,
        &["--out", "new.csv"],
    ]
    .concat();
    let (code, new_out, err) = sb.run(&new);
    assert_eq!(code, 0, "{err}");
    assert_eq!(old_out, new_out);
    let read = |f: &str| std::fs::read(sb.dir.join(f)).expect(f);
    assert_eq!(read("old.csv"), read("new.csv"));
    // The old command writes only what is asked; `measure` puts its page beside the trace.
    assert!(!sb.dir.join("old.html").exists() && sb.dir.join("new.html").exists());
    let (code, old_out, err) = sb.run(&[
        "calibrate-design",
        scene,
        "--circles",
        "3",
        "--out",
        "plan.toml",
    ]);
    assert_eq!(code, 0, "{err}");
    let (code, new_out, err) = sb.run(&["design", scene, "--circles", "3", "--out", "designs"]);
    assert_eq!(code, 0, "{err}");
    assert!(new_out.starts_with(&old_out), "{old_out}\n---\n{new_out}");
    assert_eq!(
        read("plan.toml"),
        read("designs/hexapod-machining-centre-design/plan.toml")
    );
    let json = |out: &str| -> serde_json::Value { serde_json::from_str(out).expect("json") };
    let (code, old_out, err) = sb.run(&["calibrate", scene, "--plan", "plan.toml", "--json"]);
    assert_eq!(code, 0, "{err}");
    let (code, new_out, err) = sb.run(&["identify", scene, "--plan", "plan.toml", "--json"]);
    assert_eq!(code, 0, "{err}");
    let (o, n) = (json(&old_out), json(&new_out));
    assert_eq!(o["run"]["calibration"], n["run"]["calibration"]);
    assert_eq!(o["run"]["circles"], n["run"]["circles"]);
    let (_, help, _) = sb.run(&["--help"]);
    for hidden in ["ballbar", "calibrate"] {
        assert!(
            !help.lines().any(|l| l.trim_start().starts_with(hidden)),
            "{hidden} listed: {help}"
        );
    }
}

fn designed(s: &HexapodScene, procedure: Procedure, circles: usize) -> CircleDesign {
    let ws = workspace(s);
    let fixed = default_plan(procedure, &ws, DEFAULT_POINTS);
    design(
        &s.nominal,
        procedure,
        &ws,
        circles,
        DEFAULT_POINTS,
        CALIBRATION_NOISE_MM,
        &fixed,
    )
    .expect("designs")
}

/// The designed circles predict a smaller pose error after calibration than the fixed
/// plan's, every circle runs on the nominal machine, and the design is the same on one
/// thread as on the pool.
#[test]
fn designed_circles_beat_the_fixed_plans_and_are_deterministic() {
    let s = centre();
    for (procedure, n) in [(Procedure::JigFree, 15), (Procedure::BallPlate, 7)] {
        let d = designed(&s, procedure, n);
        assert_eq!(d.plan.circles.len(), n);
        assert!(
            d.predicted.worst_position_sigma_mm < 0.5 * d.fixed.worst_position_sigma_mm,
            "{procedure:?}: {:?} against {:?}",
            d.predicted,
            d.fixed
        );
        assert_eq!(d.predicted.rank, d.fixed.rank);
        for c in &d.plan.circles {
            assert!(reachable(&s.nominal, c), "{}", c.describe());
        }
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .expect("pool")
            .install(|| designed(&s, procedure, n));
        assert_eq!(one, d);
    }
}

/// The design's prediction (24 samples a circle, each table ball eliminated by its Schur
/// complement) agrees with the σ the full identification reports for the same circles
/// (360 readings a circle, the 69 × 69 normal matrix at the solution): a second, separate
/// computation of the same covariance.
#[test]
fn the_designed_prediction_matches_the_identifications_uncertainty() {
    let s = centre();
    for (procedure, n) in [(Procedure::JigFree, 15), (Procedure::BallPlate, 7)] {
        let d = designed(&s, procedure, n);
        let r = dbb_readings(&s.nominal, &s.actual, &d.plan.circles, 0.0, 1, |_| {
            Vector3::zeros()
        });
        // Noise-free readings: the residual σ is rounding, so scale the reported σ to the
        // design's σ through the ratio the identification used.
        let cal =
            calibrate(&s.nominal, &s.actual, &d.plan, &r, CALIBRATION_NOISE_MM).expect("solves");
        let k = CALIBRATION_NOISE_MM / cal.sigma_mm;
        let reported = cal
            .estimates
            .iter()
            .map(|e| e.sigma_mm * k)
            .fold(0.0, Real::max);
        let predicted = d.predicted.max_parameter_sigma_mm;
        assert!(
            (reported / predicted - 1.0).abs() < 0.05,
            "{procedure:?}: identification {reported} mm, design {predicted} mm"
        );
        assert_eq!(cal.identifiability.parameters_determined, d.predicted.rank);
    }
}

/// The tool table calibration: a machine whose only deviation is a rigid motion of its base
/// (which lengths cannot see) is put right exactly, the rotation found is the one injected.
#[test]
fn the_tool_table_calibration_removes_a_rigid_base_motion() {
    let s = centre();
    let ws = workspace(&s);
    let rot = nalgebra::Rotation3::from_euler_angles(30e-6, -20e-6, 50e-6);
    let shift = Vector3::new(0.05, -0.03, 0.02);
    let mut p = s.nominal.parameters();
    for (i, b) in s.nominal.base_joints().iter().enumerate() {
        let m = rot * b + shift;
        p[3 * i..3 * i + 3].copy_from_slice(m.as_slice());
    }
    let actual = s.nominal.with_parameters(&p).expect("valid");
    let before = pose_errors(&s.nominal, &actual, &ws).expect("reachable");
    assert!(before.position_mm > 0.04, "{before:?}");
    let (model, angle, _) = tool_table_calibration(&s.nominal, &actual, &ws).expect("fits");
    assert!(
        (angle - rot.angle()).abs() < 1e-9,
        "{angle} against {}",
        rot.angle()
    );
    let after = pose_errors(&model, &actual, &ws).expect("reachable");
    assert!(
        after.position_mm < 1e-7 && after.pivot_mm < 1e-7,
        "{after:?}"
    );
}

/// Designed jig-free circles (15, the fixed plan's count and set-ups) over 100 seeded
/// trials graded here ([`round_trip_with`]): every parameter within 3σ in ≥ 95 % of cases,
/// the spread matching σ both ways, and the pose errors after calibration within the
/// 5 / 10 µm target.
#[test]
fn designed_jig_free_calibration_reaches_5_and_10_um() {
    let s = centre();
    let d = designed(&s, Procedure::JigFree, 15);
    round_trip_with(&s, &d.plan, 100, (5e-3, 10e-3));
}

/// A plan file reads back as the plan written; bad plan files name the file and line.
#[test]
fn plan_files_round_trip_and_bad_ones_name_file_and_line() {
    let s = centre();
    let d = designed(&s, Procedure::BallPlate, 7);
    let text = plan_toml(&d.plan, &["a comment".into()]);
    let back = parse_plan(&text, Path::new("plan.toml")).expect("reads");
    assert_eq!(back, d.plan);
    for (bad, line) in [
        (
            "procedure = \"jig\"\n[[circle]]\ncentre_mm = [0, 0, 0]\nradius_mm = 100\n",
            1,
        ),
        (
            "procedure = \"jig-free\"\n\n[[circle]]\ncentre_mm = [0, 0, 0]\nradius_mm = nan\n",
            3,
        ),
        (
            "procedure = \"jig-free\"\n[[circle]]\ncentre_mm = [0, 0]\nradius_mm = 100\n",
            3,
        ),
        (
            "procedure = \"jig-free\"\n[[circle]]\ncentre_mm = [0, 0, 0]\n",
            2,
        ),
        (
            "procedure = \"jig-free\"\n[[circle]]\ncentre_mm = [0, 0, 0]\nradius_mm = 100\ntilt_deg = 95\n",
            2,
        ),
        ("procedure = \"jig-free\"\n", 1),
    ] {
        let e = parse_plan(bad, Path::new("plan.toml")).expect_err(bad);
        let m = e.to_string();
        assert!(m.starts_with(&format!("plan.toml:{line}:")), "{bad:?}: {m}");
    }
}

#[test]
fn cli_design_writes_the_plan_identify_reads_on_a_hexapod() {
    let sb = Sandbox::new("hexapod-dbb-design");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/hexapod-machining-centre.toml");
    let scene = scene.to_str().expect("utf-8");
    let (code, out, err) = sb.run(&[
        "design",
        scene,
        "--procedure",
        "ball-plate",
        "--circles",
        "5",
        "--out",
        ".",
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("designed") && out.contains("fixed"), "{out}");
    std::fs::rename(
        sb.dir.join("hexapod-machining-centre-design/plan.toml"),
        sb.dir.join("plan.toml"),
    )
    .expect("the plan is written into <out>/<scene>-design/");
    let (code, out, err) = sb.run(&["identify", scene, "--plan", "plan.toml", "--json"]);
    assert_eq!(code, 0, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).expect("json");
    assert_eq!(v["work"][1]["circles"], 5);
    std::fs::write(
        sb.dir.join("bad.toml"),
        "procedure = \"ball-plate\"\n[[circle]]\ncentre_mm = [0, 0, inf]\nradius_mm = 100\n",
    )
    .expect("writes");
    for args in [
        vec!["design", scene, "--circles", "0", "--out", "p2"],
        vec!["design", scene, "--procedure", "x", "--out", "p2"],
        vec!["design", scene, "--params", "dy_AY", "--out", "p2"],
        vec!["identify", scene, "--plan", "bad.toml"],
        vec!["identify", scene, "--plan", "missing.toml"],
        vec![
            "identify",
            scene,
            "--plan",
            "plan.toml",
            "--procedure",
            "jig-free",
        ],
    ] {
        let (code, _, err) = sb.run(&args);
        assert_ne!(code, 0, "{args:?}");
        assert_eq!(err.trim().lines().count(), 1, "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
        assert!(!sb.dir.join("p2").exists());
    }
}

/// Each of a report's `estimates` (JSON) has a Monte-Carlo spread (key `spread`) within
/// `ratio` of its σ (key `sigma`).
pub(crate) fn spreads_within(
    estimates: &[serde_json::Value],
    sigma: &str,
    spread: &str,
    ratio: std::ops::Range<f64>,
) {
    assert!(!estimates.is_empty());
    for e in estimates {
        let (s, m) = (
            e[sigma].as_f64().expect("σ"),
            e[spread].as_f64().expect("a spread"),
        );
        assert!(
            ratio.contains(&(m / s)),
            "{}: spread {m} against σ {s}",
            e["name"]
        );
    }
}

/// `identify SCENE --procedure ball-plate --readings LIST` and `extra`, run in `sb`: the
/// hexapod identified from ball-plate trace files.
pub(crate) fn identify_ball_plate(
    sb: &Sandbox,
    scene: &str,
    list: &str,
    extra: &[&str],
) -> (i32, String, String) {
    let mut args = vec![
        "identify",
        scene,
        "--procedure",
        "ball-plate",
        "--readings",
        list,
    ];
    args.extend(extra);
    sb.run(&args)
}

/// The default ball-plate circles measured on `actual` driven by `controller` (σ 0.5 µm,
/// `seed`, one stream a circle) and written as `<stem>N.csv` under `header`: the files'
/// names, in the plan's order.
pub(crate) fn ball_plate_readings(
    sb: &Sandbox,
    controller: &Hexapod,
    actual: &Hexapod,
    ws: &Workspace,
    seed: u64,
    stem: &str,
    header: &str,
) -> Vec<String> {
    let plan = default_plan(Procedure::BallPlate, ws, DEFAULT_POINTS);
    let mut names = Vec::new();
    for (j, c) in plan.circles.iter().enumerate() {
        let inst = DbbInstrument {
            mount_mm: Vector3::zeros(),
            noise_sigma_mm: 0.5e-3,
            seed,
            stream: (j as u64) << 32,
        };
        let m = measure(controller, actual, c, &inst).expect("measures");
        let name = format!("{stem}{}.csv", j + 1);
        let header: Vec<String> = if header.is_empty() {
            Vec::new()
        } else {
            vec![header.into()]
        };
        std::fs::write(sb.dir.join(&name), m.csv(&header)).expect("writes");
        names.push(name);
    }
    names
}

/// `identify --readings` on a hexapod: bar readings measured elsewhere (here on the scene's machine,
/// written as `twinmill measure --instrument ballbar` writes them) identify the parameters the scene file
/// injects — read from its `[deviations]` table, not from the code — within 3σ; the
/// corrected-parameters fragment holds the same values; bad files name the file and line,
/// exit non-zero and write nothing.
#[test]
fn calibrate_reads_measured_dbb_files_and_writes_the_corrected_parameters() {
    let sb = Sandbox::new("hexapod-dbb-readings");
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/hexapod-machining-centre.toml");
    let s = HexapodScene::load(&path).expect("scene");
    let ws = s.workspace.expect("workspace");
    let plan = default_plan(Procedure::BallPlate, &ws, DEFAULT_POINTS);
    let names = ball_plate_readings(&sb, &s.nominal, &s.actual, &ws, 11, "circle", "# measured");
    let list = names.join(",");
    let scene = path.to_str().expect("utf-8");
    let (code, out, err) = identify_ball_plate(
        &sb,
        scene,
        &list,
        &["--corrected", "corrected.toml", "--json"],
    );
    assert_eq!(code, 0, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).expect("json");
    // The truth: the scene file's own [deviations] (absent names: 0).
    let file: toml::Table = std::fs::read_to_string(&path)
        .expect("reads")
        .parse()
        .expect("toml");
    let injected = file["deviations"].as_table().expect("deviations");
    let fragment: toml::Table = std::fs::read_to_string(sb.dir.join("corrected.toml"))
        .expect("fragment written")
        .parse()
        .expect("fragment is TOML");
    let corrected = fragment["controller"].as_table().expect("[controller]");
    let estimates = v["calibration"]["estimates"].as_array().expect("estimates");
    assert_eq!(estimates.len(), 24);
    for e in estimates {
        let name = e["name"].as_str().expect("name");
        let value = e["value_mm"].as_f64().expect("value");
        let sigma = e["sigma_mm"].as_f64().expect("sigma");
        let truth = injected.get(name).and_then(|t| t.as_float()).unwrap_or(0.0);
        assert!(
            (value - truth).abs() <= 3.0 * sigma + 1e-7,
            "{name}: identified {value} ± {sigma}, injected {truth}"
        );
        // Determined: σ below a tenth of the realistic magnitude (0.5 mm joints, 0.2 mm struts).
        assert!(sigma > 0.0 && sigma < 0.02, "{name}: σ {sigma}");
        let written = corrected[name].as_float().expect("fragment value");
        assert!(
            (written - value).abs() <= 1e-7,
            "{name}: {written} vs {value}"
        );
    }
    // The nominal controller's error on the identified machine is the scene's class.
    let position = v["predicted_correction"]["position_mm"]
        .as_f64()
        .expect("position");
    assert!(position > 0.05, "position correction {position}");

    // The engine's Monte Carlo: 25 trials at the solution, each estimate's spread (in the
    // estimates' gauge) within 0.6–1.6 of its σ (the ratio's standard deviation is about
    // 0.14); the values are those without the trials.
    let (code, out, err) =
        identify_ball_plate(&sb, scene, &list, &["--monte-carlo", "25", "--json"]);
    assert_eq!(code, 0, "{err}");
    let mc: serde_json::Value = serde_json::from_str(&out).expect("json");
    let with = mc["calibration"]["estimates"]
        .as_array()
        .expect("estimates");
    spreads_within(with, "sigma_mm", "monte_carlo_spread_mm", 0.6..1.6);
    for (a, b) in with.iter().zip(estimates) {
        assert_eq!(a["value_mm"], b["value_mm"]);
    }

    // Bad files: a non-finite reading, a missing value, too few samples, the wrong count.
    let good = std::fs::read_to_string(sb.dir.join("circle1.csv")).expect("reads");
    let mut lines: Vec<String> = good.lines().map(String::from).collect();
    let row = lines
        .iter()
        .position(|l| {
            !l.starts_with('#') && l.contains(',') && l.chars().any(|c| c.is_ascii_digit())
        })
        .expect("a data row");
    let data_row = lines[row].clone();
    let cols: Vec<&str> = data_row.split(',').collect();
    let mut nan = lines.clone();
    nan[row] = format!("{},{},nan", cols[0], cols[1]);
    std::fs::write(sb.dir.join("nan.csv"), nan.join("\n")).expect("writes");
    let mut missing = lines.clone();
    missing[row] = format!("{},{}", cols[0], cols[1]);
    std::fs::write(sb.dir.join("missing.csv"), missing.join("\n")).expect("writes");
    lines.truncate(lines.len() - 3);
    std::fs::write(sb.dir.join("short.csv"), lines.join("\n")).expect("writes");
    let with_first = |first: &str| {
        let mut n = names.clone();
        n[0] = first.to_string();
        n.join(",")
    };
    for (files, expect) in [
        (with_first("nan.csv"), "nan.csv:"),
        (with_first("missing.csv"), "missing.csv:"),
        (with_first("short.csv"), "short.csv"),
        (with_first("absent.csv"), "absent.csv"),
        (names[..6].join(","), "6 file(s) for a plan of 7"),
    ] {
        let (code, _, err) = identify_ball_plate(&sb, scene, &files, &["--corrected", "bad.toml"]);
        assert_ne!(code, 0, "{files}");
        assert_eq!(err.trim().lines().count(), 1, "{files}: {err}");
        assert!(err.contains(expect), "{files}: {err}");
        assert!(!err.contains("panicked"), "{files}: {err}");
        assert!(!sb.dir.join("bad.toml").exists(), "{files}");
    }
    // A plan whose procedure is not the one asked for is refused, as on the twin.
    std::fs::write(sb.dir.join("plate.toml"), plan_toml(&plan, &[])).expect("writes");
    let (code, _, err) = sb.run(&[
        "identify",
        scene,
        "--plan",
        "plate.toml",
        "--procedure",
        "jig-free",
        "--readings",
        &list,
        "--corrected",
        "bad.toml",
    ]);
    assert_ne!(code, 0);
    assert!(
        err.contains("the plan is for the ball-plate procedure"),
        "{err}"
    );
    assert!(!sb.dir.join("bad.toml").exists());
}
