//! Verification: the corrected path sampled on a machine, the milled faces and the whole
//! part against the nominal ones.

use super::*;
use crate::calibration::identify::{FaceOptions, FaceSpec, StepFrame, extent, flank};
use crate::cutting::stock::TriDexel;
use crate::cutting::tool::Tool;
use crate::machine::chain::Chain;
use crate::machine::error_motion::Directions;
use crate::math::{Aabb, Point3, Real, Vector3};
use crate::metrology::fit::{Plane, fit_plane};
use crate::nc::{AxisValues, Move, Program};

/// The tool path of a corrected program on a machine against the nominal path.
#[derive(Clone, Copy, Debug, PartialEq, Default, serde::Serialize)]
pub struct PathError {
    /// Largest distance of a deviated tool-axis point (tip or flute end) from its nominal
    /// place, over every sample (mm).
    pub max_mm: Real,
    /// RMS of those distances (mm).
    pub rms_mm: Real,
    /// Samples taken (points in time; two tool points each).
    pub samples: usize,
    /// Source line of the largest distance (0 if none).
    pub worst_line: usize,
}

/// Samples every block of `corrected` on `machine` at its ends and [`PATH_SAMPLES`] inner
/// points, and compares the tool axis (tip and flute end) with the nominal chain's at the
/// same parameter of the source move of `program`. The positioning block to the corrected
/// start has no nominal path and is skipped.
pub fn path_error(
    machine: &Chain,
    tool: &Tool,
    program: &Program,
    corrected: &CorrectedProgram,
) -> PathError {
    let nominal = machine.nominal();
    let flute = FlutePoints::of(tool);
    let mut out = PathError::default();
    let mut sum = 0.0;
    let mut at = corrected.start;
    let mut dirs = Directions::default();
    for b in &corrected.blocks {
        let old = machine.reversal_state(&dirs);
        dirs = dirs.after_move(&at, &b.end);
        let state = machine.reversal_state(&dirs);
        let from = taken_up(machine, &at, &old, &state);
        at = b.end;
        let Some(src) = b.source.and_then(|i| program.moves.get(i)) else {
            continue;
        };
        for i in 0..=PATH_SAMPLES + 1 {
            let t = i as Real / (PATH_SAMPLES + 1) as Real;
            let s = b.s.0 + (b.s.1 - b.s.0) * t;
            let dev = machine.w_from_t_state(&lerp(&from, &b.end, t), &state);
            let nom = nominal.w_from_t(&path_point(src, s));
            for h in flute.ends {
                let d = (dev * axis_point(h) - nom * axis_point(h)).norm();
                sum += d * d;
                if d > out.max_mm {
                    out.max_mm = d;
                    out.worst_line = b.line;
                }
            }
            out.samples += 1;
        }
    }
    out.rms_mm = if out.samples > 0 {
        (sum / (2 * out.samples) as Real).sqrt()
    } else {
        0.0
    };
    out
}

/// The error of one milled face.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct FaceError {
    /// Face name.
    pub name: String,
    /// Source line of its cut.
    pub line: usize,
    /// Dexel crossings on it.
    pub crossings: usize,
    /// Largest distance of a crossing from the nominal plane (mm).
    pub max_abs_mm: Real,
    /// RMS distance (mm).
    pub rms_mm: Real,
    /// Mean signed distance (mm), positive into the material (material left).
    pub mean_mm: Real,
    /// Angle between the plane fitted to the crossings and the nominal plane (rad).
    pub tilt_rad: Real,
}

/// The milled faces of a part against the nominal ones.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct FaceCheck {
    /// Per face.
    pub faces: Vec<FaceError>,
    /// For two faces: the step between their fitted planes (mm), measured like the
    /// identification does, minus the nominal step.
    pub step_mm: Option<Real>,
}

impl FaceCheck {
    /// The largest distance of any crossing from its nominal face (mm); `None` when no face
    /// was measured (the scene names none).
    pub fn max_abs_mm(&self) -> Option<Real> {
        self.faces.iter().map(|f| f.max_abs_mm).reduce(Real::max)
    }
}

/// Measures the faces `specs` of a swept `stock` (cut by moves whose lines are the source
/// lines of `moves`) against the nominal flank planes of their cuts: every dexel crossing
/// made by the face's line, inside the face's region (the cut's extent along the path and
/// the tool axis, clipped to the stock, shrunk by the margin, within the band of the plane),
/// with its material normal along the face's.
pub fn face_errors(
    stock: &TriDexel,
    nominal: &Chain,
    tool: &Tool,
    moves: &[Move],
    specs: &[FaceSpec],
    stock_box: &Aabb,
    opts: &FaceOptions,
) -> Result<FaceCheck, CorrectError> {
    let mut faces = Vec::new();
    let mut planes = Vec::new();
    for spec in specs {
        let err = |message: String| CorrectError::Face {
            face: spec.name.clone(),
            message,
        };
        let mv = moves
            .iter()
            .find(|m| m.line == spec.line)
            .ok_or_else(|| err(format!("no move on line {}", spec.line)))?;
        let fl = flank(nominal, tool, mv, stock_box)
            .ok_or_else(|| err("the cut has no flank (no travel across the tool)".into()))?;
        let (su, sv) = (
            extent(stock_box, &fl.tip, &fl.u),
            extent(stock_box, &fl.tip, &fl.v),
        );
        let m = opts.margin_mm;
        let h0 = tool
            .flank_start()
            .ok_or_else(|| err("the tool has no cylindrical flank to cut a planar face".into()))?;
        let (u0, u1) = (su.0.max(0.0) + m, su.1.min(fl.length) - m);
        let (v0, v1) = (sv.0.max(h0) + m, sv.1.min(tool.length()) - m);
        let n = fl.plane.normal.into_inner();
        let mut pts = Vec::new();
        for g in stock.grids() {
            g.for_each_crossing(|p, c| {
                if c.line as usize != spec.line || c.normal().dot(&n) > -FACE_NORMAL_COS {
                    return;
                }
                let w = p - fl.tip;
                let (u, v) = (fl.u.dot(&w), fl.v.dot(&w));
                if u >= u0
                    && u <= u1
                    && v >= v0
                    && v <= v1
                    && fl.plane.signed_distance(&p).abs() <= opts.band_mm
                {
                    pts.push(p);
                }
            });
        }
        let fit = fit_plane(&pts)
            .map_err(|e| err(format!("{e} ({} crossings in the region)", pts.len())))?;
        let fitted = fit.plane.oriented_towards(&n);
        let d: Vec<Real> = pts.iter().map(|p| fl.plane.signed_distance(p)).collect();
        let k = d.len().max(1) as Real;
        faces.push(FaceError {
            name: spec.name.clone(),
            line: spec.line,
            crossings: d.len(),
            max_abs_mm: d.iter().map(|x| x.abs()).fold(0.0, Real::max),
            rms_mm: (d.iter().map(|x| x * x).sum::<Real>() / k).sqrt(),
            mean_mm: d.iter().sum::<Real>() / k,
            tilt_rad: fitted.normal.angle(&fl.plane.normal),
        });
        planes.push((fl, fitted, fit.centroid));
    }
    let step_mm = match &planes[..] {
        [(f0, p0, c0), (f1, p1, c1)] => {
            let frame = StepFrame {
                at: Point3::from((c0.coords + c1.coords) / 2.0),
                n: f0.plane.normal,
                u: f0.u,
            };
            let nominal_step = frame.measure(&f0.plane, &f1.plane).map(|m| m.0);
            let step = frame.measure(p0, p1).map(|m| m.0);
            step.zip(nominal_step).map(|(s, n)| s - n)
        }
        _ => None,
    };
    Ok(FaceCheck { faces, step_mm })
}

/// A machined part against the nominal part, ray by ray over the three dexel grids: the
/// distance between each cut surface and the same surface of the nominal part (the surface
/// the same NC line made).
#[derive(Clone, Copy, Debug, PartialEq, Default, serde::Serialize)]
pub struct PartError {
    /// Crossings compared (made by the same cut in both parts, seen at most 60° off the
    /// ray).
    pub crossings: usize,
    /// Largest distance between corresponding crossings, along the surface normal (mm).
    pub max_mm: Real,
    /// RMS of those distances (mm).
    pub rms_mm: Real,
    /// Where the largest distance is (workpiece frame, mm).
    pub worst_at: [Real; 3],
    /// Rays whose material intervals differ in number or in the orientation of their ends
    /// (a surface edge moved across the ray): not compared.
    pub unmatched_rays: usize,
    /// Corresponding crossings made by different NC lines in the two parts (or by a cut in
    /// one and the stock in the other): an edge between two surfaces moved across the ray,
    /// so the ray meets one surface in one part and another in the other — their distance
    /// along the ray is the height of the edge, not a surface error. Not compared.
    pub other_surface_crossings: usize,
}

/// A crossing is compared on a grid whose rays meet its surface at most 60° off the normal
/// (|n·e| ≥ 0.5); every surface has a normal component ≥ 1/√3 on some axis, so each is
/// compared on at least one grid, never at grazing incidence.
const PART_RAY_COS: Real = 0.5;

/// Compares every cut surface of `part` with `nominal` (the same stock box and pitch): on
/// each ray, corresponding crossings' distance along the ray times the cosine between ray
/// and normal — the distance between the surfaces there, to first order — where both
/// crossings lie on the same surface: made by the same NC line (a corrected program's
/// blocks carry their source line). Where an edge between two surfaces has moved across a
/// ray (a floor's edge at a step: the ray meets the upper floor in one part, the lower in
/// the other), the crossings are of different lines and are counted, not compared.
pub fn part_error(part: &TriDexel, nominal: &TriDexel) -> PartError {
    let mut out = PartError::default();
    let mut sum = 0.0;
    for (g, h) in part.grids().iter().zip(nominal.grids()) {
        let (nu, nv) = g.dims();
        if h.dims() != (nu, nv) {
            continue;
        }
        let axis = g.axis();
        for iv in 0..nv {
            for iu in 0..nu {
                let (a, b) = (g.ray(iu, iv), h.ray(iu, iv));
                let cut = |segs: &[crate::cutting::stock::Segment]| {
                    segs.iter().any(|s| s.lo.line != 0 || s.hi.line != 0)
                };
                if !cut(a) && !cut(b) {
                    continue;
                }
                let pairs = || {
                    a.iter()
                        .zip(b)
                        .flat_map(|(x, y)| [(&x.lo, &y.lo), (&x.hi, &y.hi)])
                };
                if a.len() != b.len()
                    || pairs().any(|(x, y)| x.normal().dot(&y.normal()) < FACE_NORMAL_COS)
                {
                    out.unmatched_rays += 1;
                    continue;
                }
                for (x, y) in pairs() {
                    let n = y.normal();
                    if (x.line == 0 && y.line == 0) || n[axis].abs() < PART_RAY_COS {
                        continue;
                    }
                    if x.line != y.line {
                        out.other_surface_crossings += 1;
                        continue;
                    }
                    let d = (x.t - y.t).abs() * n[axis].abs();
                    out.crossings += 1;
                    sum += d * d;
                    if d > out.max_mm {
                        out.max_mm = d;
                        let mut p = g.ray_origin(iu, iv);
                        p[axis] = y.t;
                        out.worst_at = [p.x, p.y, p.z];
                    }
                }
            }
        }
    }
    out.rms_mm = if out.crossings > 0 {
        (sum / out.crossings as Real).sqrt()
    } else {
        0.0
    };
    out
}

/// The nominal flank plane of a straight cut (for tests and reports).
pub fn nominal_face(nominal: &Chain, tool: &Tool, mv: &Move, stock_box: &Aabb) -> Option<Plane> {
    flank(nominal, tool, mv, stock_box).map(|f| f.plane)
}

/// The tool axis direction error (rad) of a corrected pose: the angle between the deviated
/// and the nominal tool axes.
pub fn axis_angle_error(machine: &Chain, commanded: &AxisValues, corrected: &AxisValues) -> Real {
    let z = Vector3::z();
    let a = machine.w_from_t(corrected).rotation * z;
    let b = machine.nominal().w_from_t(commanded).rotation * z;
    a.angle(&b)
}
