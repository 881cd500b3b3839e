//! What seed 001 (Harbin) does to keep a hexapod accurate, on the twin: (a) the resolution
//! amplification factors K_p (mm/mm) and K_a (°/mm) mapped over a workspace and tilt range,
//! and the strut resolution an output resolution demands; (c) homing by a coarse switch and
//! the encoder's index pulse once per screw lead T, the check that the switch-to-index
//! distance S lies in (0.3–0.7)·T, and what latching the wrong index does to the pose;
//! (d) pivot accuracy: how far the tool tip travels while the orientation swings about it,
//! on a machine with deviations commanded through the nominal inverse kinematics.
//!
//! **Invariant:** plain functions of the hexapods and options they are given; a pose the
//! machine cannot reach is reported as unreachable with the reason, never given a figure.

use crate::machine::hexapod::{
    Amplification, Hexapod, HexapodError, Pose, STRUTS, Struts, twin_pose,
};
use crate::math::{Real, Vector3};
use serde::Serialize;

/// A box of tool positions (base frame, mm) and the tilt range (degrees) a map covers.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Workspace {
    /// x range (mm).
    pub x_mm: (Real, Real),
    /// y range (mm).
    pub y_mm: (Real, Real),
    /// z range (mm).
    pub z_mm: (Real, Real),
    /// The largest tilt of a and of b (degrees, ≥ 0).
    pub tilt_deg: Real,
}

impl Workspace {
    /// Checks the ranges: finite, min ≤ max, tilt in [0°, 90°).
    pub fn validate(&self) -> Result<(), String> {
        for (name, (lo, hi)) in [("x", self.x_mm), ("y", self.y_mm), ("z", self.z_mm)] {
            if !(lo.is_finite() && hi.is_finite() && lo <= hi) {
                return Err(format!(
                    "workspace {name} range [{lo}, {hi}] mm must be finite with min ≤ max"
                ));
            }
        }
        if !(self.tilt_deg.is_finite() && (0.0..90.0).contains(&self.tilt_deg)) {
            return Err(format!(
                "workspace tilt {}° must lie in [0°, 90°)",
                self.tilt_deg
            ));
        }
        Ok(())
    }

    /// `n` evenly spaced values over `[lo, hi]` (the midpoint for `n` = 1).
    fn values(range: (Real, Real), n: usize) -> Vec<Real> {
        if n <= 1 {
            return vec![0.5 * (range.0 + range.1)];
        }
        (0..n)
            .map(|k| range.0 + (range.1 - range.0) * k as Real / (n - 1) as Real)
            .collect()
    }

    /// The orientations a map samples (a, b, c in degrees): level, then ±tilt about x and
    /// about y (only level if the tilt is zero).
    pub fn orientations(&self) -> Vec<[Real; 3]> {
        let t = self.tilt_deg;
        if t == 0.0 {
            return vec![[0.0; 3]];
        }
        vec![
            [0.0, 0.0, 0.0],
            [t, 0.0, 0.0],
            [-t, 0.0, 0.0],
            [0.0, t, 0.0],
            [0.0, -t, 0.0],
        ]
    }
}

/// One pose of an amplification map.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MapSample {
    /// x, y, z (mm), a, b, c (degrees).
    pub pose: [Real; 6],
    /// K_p and K_a there; `None` where the pose is outside the workspace.
    pub factors: Option<Amplification>,
    /// Why the pose is outside the workspace.
    pub unreachable: Option<String>,
}

/// The range of a figure over a set of poses.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Range {
    /// Smallest value.
    pub min: Real,
    /// Largest value.
    pub max: Real,
}

impl Range {
    /// The range of `values`; `None` if there are none.
    pub fn of(values: impl Iterator<Item = Real>) -> Option<Range> {
        values.fold(None, |r, v| {
            Some(match r {
                None => Range { min: v, max: v },
                Some(Range { min, max }) => Range {
                    min: min.min(v),
                    max: max.max(v),
                },
            })
        })
    }
}

/// Resolution amplification over a workspace (seed 001 §1).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct AmplificationMap {
    /// The region mapped.
    pub workspace: Workspace,
    /// Grid points along x, y, z.
    pub steps: [usize; 3],
    /// Every pose: x fastest, then y, z, orientation.
    pub samples: Vec<MapSample>,
    /// K_p (mm/mm) over the level poses.
    pub position_level: Option<Range>,
    /// K_a (°/mm) over the level poses.
    pub angle_level: Option<Range>,
    /// K_p over the tilted poses.
    pub position_tilted: Option<Range>,
    /// K_a over the tilted poses.
    pub angle_tilted: Option<Range>,
    /// Poses outside the workspace (stroke, joint limits, singular).
    pub unreachable: usize,
}

impl AmplificationMap {
    /// The largest K_p and K_a over every reachable pose: the machine's general factors
    /// (seed 001 takes the larger values as valid everywhere).
    pub fn worst(&self) -> Option<Amplification> {
        let all = || self.samples.iter().filter_map(|s| s.factors);
        Some(Amplification {
            position_mm_per_mm: Range::of(all().map(|f| f.position_mm_per_mm))?.max,
            angle_deg_per_mm: Range::of(all().map(|f| f.angle_deg_per_mm))?.max,
        })
    }
}

/// K_p and K_a at every point of an `steps[0] × steps[1] × steps[2]` grid over `ws`, for each
/// of [`Workspace::orientations`]; poses outside the machine's workspace are marked, not
/// valued.
pub fn amplification_map(hexapod: &Hexapod, ws: &Workspace, steps: [usize; 3]) -> AmplificationMap {
    let xs = Workspace::values(ws.x_mm, steps[0]);
    let ys = Workspace::values(ws.y_mm, steps[1]);
    let zs = Workspace::values(ws.z_mm, steps[2]);
    let mut samples = Vec::with_capacity(xs.len() * ys.len() * zs.len() * 5);
    for o in ws.orientations() {
        for &z in &zs {
            for &y in &ys {
                for &x in &xs {
                    let v = [x, y, z, o[0], o[1], o[2]];
                    let pose = Pose::from_mm_deg(v);
                    let got = hexapod
                        .check_pose(&pose)
                        .and_then(|()| hexapod.amplification(&pose));
                    let (factors, unreachable) = match got {
                        Ok(f) => (Some(f), None),
                        Err(e) => (None, Some(e.to_string())),
                    };
                    samples.push(MapSample {
                        pose: v,
                        factors,
                        unreachable,
                    });
                }
            }
        }
    }
    let level = |s: &&MapSample| s.pose[3] == 0.0 && s.pose[4] == 0.0;
    let pick = |want_level: bool, f: fn(&Amplification) -> Real| {
        Range::of(
            samples
                .iter()
                .filter(|s| level(s) == want_level)
                .filter_map(|s| s.factors.as_ref().map(f)),
        )
    };
    AmplificationMap {
        workspace: *ws,
        steps: [xs.len(), ys.len(), zs.len()],
        position_level: pick(true, |a| a.position_mm_per_mm),
        angle_level: pick(true, |a| a.angle_deg_per_mm),
        position_tilted: pick(false, |a| a.position_mm_per_mm),
        angle_tilted: pick(false, |a| a.angle_deg_per_mm),
        unreachable: samples.iter().filter(|s| s.factors.is_none()).count(),
        samples,
    }
}

/// The strut resolution an output resolution demands (seed 001's t_i): the smaller of
/// `position_mm / K_p` and `angle_deg / K_a` (mm).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ResolutionBudget {
    /// Strut resolution for the position resolution (mm).
    pub for_position_mm: Real,
    /// Strut resolution for the angle resolution (mm).
    pub for_angle_mm: Real,
    /// The smaller: what the struts must resolve (mm).
    pub required_mm: Real,
}

/// The strut resolution needed for `position_mm` and `angle_deg` of output resolution at
/// amplification `k`.
pub fn resolution_budget(
    k: &Amplification,
    position_mm: Real,
    angle_deg: Real,
) -> ResolutionBudget {
    let p = position_mm / k.position_mm_per_mm;
    let a = angle_deg / k.angle_deg_per_mm;
    ResolutionBudget {
        for_position_mm: p,
        for_angle_mm: a,
        required_mm: p.min(a),
    }
}

/// The homing of one strut (seed 001 §3): a coarse switch, then the next encoder index
/// pulse in the homing direction; index pulses come once per screw lead.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct HomingSetup {
    /// Screw lead T (mm per revolution: the spacing of index pulses along the strut).
    pub lead_mm: Real,
    /// S: distance from the switch's trip point to the index taken as home, per strut (mm).
    pub switch_to_index_mm: Struts,
    /// Standard deviation of the switch's trip point (mm): its threshold varies.
    pub trip_sigma_mm: Real,
}

/// The band seed 001 recommends for S/T.
pub const SWITCH_BAND: (Real, Real) = (0.3, 0.7);

/// One strut's homing check.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct StrutHoming {
    /// 1-based strut.
    pub strut: usize,
    /// S (mm).
    pub switch_to_index_mm: Real,
    /// S/T.
    pub fraction: Real,
    /// Whether S/T lies in [0.3, 0.7].
    pub in_band: bool,
    /// How far the trip point may move before another index is latched: min(S, T − S) (mm).
    pub margin_mm: Real,
    /// The probability that a homing latches an index one lead off, for a Gaussian trip
    /// point of the setup's σ: Φ(−S/σ) + Φ(−(T − S)/σ).
    pub wrong_index_probability: Real,
}

/// The index a homing latches, counted from the right one, when the switch trips `error`
/// mm late (positive: further along the homing direction): the switch trips at `error − S`
/// relative to the right index, and the first index at or after that point is taken.
pub fn index_latched(lead_mm: Real, switch_to_index_mm: Real, error_mm: Real) -> i64 {
    ((error_mm - switch_to_index_mm) / lead_mm).ceil() as i64
}

/// The homing check of every strut.
pub fn homing_check(setup: &HomingSetup) -> Vec<StrutHoming> {
    let t = setup.lead_mm;
    (0..STRUTS)
        .map(|i| {
            let s = setup.switch_to_index_mm[i];
            let f = s / t;
            let p = if setup.trip_sigma_mm > 0.0 {
                normal_tail(s / setup.trip_sigma_mm) + normal_tail((t - s) / setup.trip_sigma_mm)
            } else {
                0.0
            };
            StrutHoming {
                strut: i + 1,
                switch_to_index_mm: s,
                fraction: f,
                in_band: (SWITCH_BAND.0..=SWITCH_BAND.1).contains(&f),
                margin_mm: s.min(t - s),
                wrong_index_probability: p,
            }
        })
        .collect()
}

/// What one strut homed one index off does to the pose.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct WrongIndex {
    /// 1-based strut.
    pub strut: usize,
    /// +1: the next index (the strut is one lead longer than the controller believes), −1:
    /// the previous one.
    pub index_offset: i64,
    /// Tool-point error (mm), base frame; `None` if the machine cannot assemble.
    pub position_error_mm: Option<[Real; 3]>,
    /// Its length (mm).
    pub position_error_norm_mm: Option<Real>,
    /// Orientation error a, b, c (degrees).
    pub angle_error_deg: Option<[Real; 3]>,
    /// Why there is no pose.
    pub failure: Option<String>,
}

/// The pose error at `command` when strut i latched the index `±1` lead off, for every
/// strut and both signs, on the `actual` machine commanded through `nominal`.
pub fn wrong_index_effects(
    nominal: &Hexapod,
    actual: &Hexapod,
    command: &Pose,
    lead_mm: Real,
) -> Result<Vec<WrongIndex>, HexapodError> {
    nominal.check_pose(command)?;
    let right = twin_pose(nominal, actual, command)?;
    let readings = nominal.readings(command);
    let mut out = Vec::new();
    for i in 0..STRUTS {
        for k in [1i64, -1] {
            let mut lengths = actual.lengths_of_readings(&readings);
            lengths[i] += k as Real * lead_mm;
            let got = actual.forward_unchecked(&lengths, &right);
            out.push(match got {
                Ok(sol) => {
                    let dp = sol.pose.position - right.position;
                    let da = (sol.pose.angles - right.angles).map(Real::to_degrees);
                    WrongIndex {
                        strut: i + 1,
                        index_offset: k,
                        position_error_mm: Some([dp.x, dp.y, dp.z]),
                        position_error_norm_mm: Some(dp.norm()),
                        angle_error_deg: Some([da.x, da.y, da.z]),
                        failure: None,
                    }
                }
                Err(e) => WrongIndex {
                    strut: i + 1,
                    index_offset: k,
                    position_error_mm: None,
                    position_error_norm_mm: None,
                    angle_error_deg: None,
                    failure: Some(e.to_string()),
                },
            });
        }
    }
    Ok(out)
}

/// P(Z > x) for a standard normal Z: erfc(x/√2)/2, by the Chebyshev fit of Numerical
/// Recipes (fractional error below 1.2e-7 everywhere).
pub fn normal_tail(x: Real) -> Real {
    let z = x / std::f64::consts::SQRT_2;
    let a = z.abs();
    let t = 1.0 / (1.0 + 0.5 * a);
    let poly = -a * a - 1.265_512_23
        + t * (1.000_023_68
            + t * (0.374_091_96
                + t * (0.096_784_18
                    + t * (-0.186_288_06
                        + t * (0.278_868_07
                            + t * (-1.135_203_98
                                + t * (1.488_515_87 + t * (-0.822_152_23 + t * 0.170_872_77))))))));
    let erfc = t * poly.exp();
    0.5 * if z >= 0.0 { erfc } else { 2.0 - erfc }
}

/// One orientation of a pivot test.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct PivotSample {
    /// Commanded a, b (degrees; c = 0).
    pub angles_deg: [Real; 2],
    /// The tool point reached (mm, base frame).
    pub tip_mm: [Real; 3],
    /// Its distance from the commanded point (mm).
    pub deviation_mm: Real,
    /// Its distance from the tip reached with the tool level (mm).
    pub travel_mm: Real,
}

/// Pivot accuracy (seed 001 §5, Fig. 4): the tool point commanded to stay at one point while
/// a and b swing over `[−tilt, tilt]`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PivotReport {
    /// The commanded point (mm).
    pub point_mm: [Real; 3],
    /// The largest |a| and |b| (degrees).
    pub tilt_deg: Real,
    /// The tool point reached with the tool level (mm).
    pub level_tip_mm: [Real; 3],
    /// Every orientation (an `n × n` grid over a and b).
    pub samples: Vec<PivotSample>,
    /// The pivot error: the largest distance of the tip from where it was with the tool
    /// level (mm): how far it travels while the orientation changes.
    pub pivot_error_mm: Real,
    /// The largest distance of the tip from the commanded point (mm).
    pub max_deviation_mm: Real,
}

/// The pivot test at `point` over an `steps × steps` grid of a, b in `[−tilt, tilt]`, on the
/// `actual` machine commanded through `nominal`.
pub fn pivot_test(
    nominal: &Hexapod,
    actual: &Hexapod,
    point: &Vector3,
    tilt_deg: Real,
    steps: usize,
) -> Result<PivotReport, HexapodError> {
    let reach = |a: Real, b: Real| {
        let pose = Pose {
            position: *point,
            angles: Vector3::new(a.to_radians(), b.to_radians(), 0.0),
        };
        twin_pose(nominal, actual, &pose).map(|p| p.position)
    };
    let level = reach(0.0, 0.0)?;
    let n = steps.max(2);
    let mut samples = Vec::with_capacity(n * n);
    for j in 0..n {
        for i in 0..n {
            let f = |k: usize| -tilt_deg + 2.0 * tilt_deg * k as Real / (n - 1) as Real;
            let (a, b) = (f(i), f(j));
            let tip = reach(a, b)?;
            samples.push(PivotSample {
                angles_deg: [a, b],
                tip_mm: [tip.x, tip.y, tip.z],
                deviation_mm: (tip - point).norm(),
                travel_mm: (tip - level).norm(),
            });
        }
    }
    let fold = |f: fn(&PivotSample) -> Real| samples.iter().map(f).fold(0.0, Real::max);
    Ok(PivotReport {
        point_mm: [point.x, point.y, point.z],
        tilt_deg,
        level_tip_mm: [level.x, level.y, level.z],
        pivot_error_mm: fold(|s| s.travel_mm),
        max_deviation_mm: fold(|s| s.deviation_mm).max((level - point).norm()),
        samples,
    })
}

/// Positioning with the tool level over a workspace (seed 001's first calibration item).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct LevelPositioning {
    /// The largest distance between commanded and reached tool point (mm).
    pub max_error_mm: Real,
    /// The commanded point where it occurs (mm).
    pub at_mm: [Real; 3],
    /// Grid points measured.
    pub measured: usize,
    /// Grid points outside the nominal workspace, skipped.
    pub skipped: usize,
}

/// The level positioning survey over an `steps[0] × steps[1] × steps[2]` grid of `ws`: the
/// poses the nominal machine can reach, commanded through it on `actual`; `None` if it
/// reaches none.
pub fn level_positioning(
    nominal: &Hexapod,
    actual: &Hexapod,
    ws: &Workspace,
    steps: [usize; 3],
) -> Result<Option<LevelPositioning>, HexapodError> {
    let mut out = LevelPositioning {
        max_error_mm: 0.0,
        at_mm: [Real::NAN; 3],
        measured: 0,
        skipped: 0,
    };
    for z in Workspace::values(ws.z_mm, steps[2]) {
        for y in Workspace::values(ws.y_mm, steps[1]) {
            for x in Workspace::values(ws.x_mm, steps[0]) {
                let cmd = Pose::from_mm_deg([x, y, z, 0.0, 0.0, 0.0]);
                if nominal.check_pose(&cmd).is_err() {
                    out.skipped += 1;
                    continue;
                }
                let got = twin_pose(nominal, actual, &cmd)?;
                let e = (got.position - cmd.position).norm();
                out.measured += 1;
                if e >= out.max_error_mm {
                    out.max_error_mm = e;
                    out.at_mm = [x, y, z];
                }
            }
        }
    }
    Ok((out.measured > 0).then_some(out))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn index_latched_follows_the_trip_point() {
        // T = 6, S = 3: the right index for trip errors in (−3, 3].
        assert_eq!(index_latched(6.0, 3.0, 0.0), 0);
        assert_eq!(index_latched(6.0, 3.0, 2.9), 0);
        assert_eq!(index_latched(6.0, 3.0, 3.1), 1);
        assert_eq!(index_latched(6.0, 3.0, -2.9), 0);
        assert_eq!(index_latched(6.0, 3.0, -3.1), -1);
        // S = 0.3 mm close to 0: a late trip of 0.31 mm latches the next index.
        assert_eq!(index_latched(6.0, 0.3, 0.31), 1);
    }

    #[test]
    fn normal_tail_matches_known_values() {
        for (x, p) in [
            (0.0, 0.5),
            (1.0, 0.158_655_253_9),
            (2.0, 0.022_750_131_9),
            (3.0, 0.001_349_898_0),
            (-1.0, 0.841_344_746_1),
        ] {
            assert!((normal_tail(x) - p).abs() <= 1.2e-7 * p.max(1e-3), "{x}");
        }
    }
}
