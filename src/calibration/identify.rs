//! Model correction for the A-axis 0°/180° experiment (seed 002 §4; see
//! docs/identification-and-correction.md): segment the two faces in a cloud, fit planes,
//! measure the step, identify dy_AY and gamma_AY + gamma_YX.
//!
//! **Faces.** Each face is named by the NC line of the straight cut that made it. The cut's
//! flank plane on the *model* chain (nominal plus known deviations) gives the face's
//! expected place: the region between the move's ends and between the tool tip and the
//! tool's length, clipped to the stock and shrunk by a margin, within a band around the
//! plane. Points there are fitted by orthogonal least squares with outlier rejection.
//!
//! **Measurements.** With `P` the midpoint of the two faces' centroids, `n` the first face's
//! model normal (into the material) and `u` its cut direction: the *step* is the distance
//! from the first plane to the second along the line through `P` in direction `n`, and the
//! *tilt* is `(n₂ − n₁)·u`, the relative rotation of the faces about the tool axis.
//! To first order (seed 002 eq. 6, 7, with y1 = −y2): step = −2·dy_AY,
//! tilt = 2·(gamma_AY + gamma_YX).
//!
//! **Identification.** Those two measurements are matched exactly: Levenberg–Marquardt on
//! the exact chain (the flank planes recomputed from the transforms) over dy and gamma of the
//! rotary axis's joint, with every other deviation held at its known value. The Jacobian's
//! singular values decide whether the pair is identifiable from these faces; if not, no
//! value is given. Everything else is reported as not observable from this experiment.
//!
//! **Invariant:** identification reads a cloud and the program's moves; it never runs the
//! sweep or the scanner (it must work on clouds twinmill did not make).

use crate::cutting::tool::Tool;
use crate::machine::chain::{AxisKind, Chain, Component, DeviationId};
use crate::math::{Aabb, Point3, Real, UnitVector3, Vector3, tol};
use crate::metrology::fit::{FitError, Plane, PlaneFit, RobustRule, fit_plane_robust};
use crate::metrology::segment::{PlaneSegmentOptions, select_box, select_region_from_seed};
use crate::nc::{Move, MoveKind};
use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
use nalgebra::{Matrix2, Owned, U2, Vector2};

/// Errors of face extraction and identification.
#[derive(Debug, PartialEq, thiserror::Error)]
pub enum IdentifyError {
    /// The face names a line with no move on it.
    #[error("face '{face}': no move on NC line {line}")]
    NoMove {
        /// Face name.
        face: String,
        /// Line asked for.
        line: usize,
    },
    /// The move on the face's line is not a straight cut at fixed rotary values.
    #[error("face '{face}': line {line} is not a feed move at constant rotary position")]
    NotACut {
        /// Face name.
        face: String,
        /// Line.
        line: usize,
    },
    /// The face region, clipped to the stock and margins, is empty.
    #[error("face '{face}': the cut's flank does not cover the stock beyond the margin")]
    EmptyRegion {
        /// Face name.
        face: String,
    },
    /// The plane fit failed (too few points in the region, degenerate).
    #[error("face '{face}': {source} ({points} points in the region)")]
    Fit {
        /// Face name.
        face: String,
        /// Points found in the region.
        points: usize,
        /// Why.
        source: FitError,
    },
    /// The experiment needs exactly two faces cut 180° apart about one rotary axis.
    #[error("the 0/180 experiment needs two faces cut 180° apart about one rotary axis: {0}")]
    NotAStepPair(String),
}

/// Options for face extraction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FaceOptions {
    /// Distance kept from the face's edges (mm); ≥ 0. Typical 1.0.
    pub margin_mm: Real,
    /// Half-width of the band around the expected plane that points must fall in (mm); > 0.
    /// Must exceed the largest expected deviation of the face; typical 2.0.
    pub band_mm: Real,
    /// Outlier rejection.
    pub robust: RobustRule,
}

/// A face to extract: a name and the NC line of the cut that made it.
#[derive(Clone, Debug, PartialEq)]
pub struct FaceSpec {
    /// Name used in reports.
    pub name: String,
    /// 1-based NC line of the cut.
    pub line: usize,
    /// Where the face's points are.
    pub region: FaceRegion,
    /// Which face of the cut: its flank (side) or its floor (bottom of a flat end mill).
    pub kind: FaceKind,
}

/// Which face of a straight cut.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum FaceKind {
    /// The side: tangent to the tool cylinder, containing the tool axis and the path.
    #[default]
    Flank,
    /// The bottom of a flat end mill's track.
    Floor,
}

/// How a face's points are chosen from a cloud.
#[derive(Clone, Debug, PartialEq)]
pub enum FaceRegion {
    /// From the cut's flank on the model chain, clipped to the stock, shrunk by the margin,
    /// within the band around the expected plane.
    Auto,
    /// The points inside a box (W).
    Box(Aabb),
    /// The planar region grown from the point nearest to a seed point (W).
    Seed(Point3),
}

/// The flank plane of a straight cut, and the frame of its face.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Flank {
    /// The plane, normal pointing from the tool into the material.
    pub plane: Plane,
    /// Unit cut direction.
    pub u: UnitVector3,
    /// Unit tool axis (tip to shank).
    pub v: UnitVector3,
    /// A point on the tool axis at the tip, at the cut's start.
    pub tip: Point3,
    /// Length of the cut (mm).
    pub length: Real,
}

/// The flank plane of `mv` on `chain`: tangent to the tool cylinder, parallel to the tool
/// axis and the cut direction, on the side where more of `stock` lies.
pub fn flank(chain: &Chain, tool: &Tool, mv: &Move, stock: &Aabb) -> Option<Flank> {
    let p0 = chain.w_from_t(&mv.start);
    let p1 = chain.w_from_t(&mv.end);
    let tip = p0 * Point3::origin();
    let d = p1 * Point3::origin() - tip;
    let length = d.norm();
    let v = UnitVector3::new_normalize(p0.rotation * Vector3::z());
    let u = UnitVector3::try_new(d, tol::LENGTH_EPS)?;
    let side = UnitVector3::try_new(u.cross(&v), tol::LENGTH_EPS)?;
    // Pick the side with the stock beyond it.
    let reach = |n: &Vector3| {
        corners(stock)
            .iter()
            .map(|c| n.dot(&(c - tip)) - tool.radius())
            .fold(Real::NEG_INFINITY, Real::max)
    };
    let n = if reach(&side) >= reach(&-side.into_inner()) {
        side
    } else {
        -side
    };
    Some(Flank {
        plane: Plane::through(&(tip + n.into_inner() * tool.radius()), n),
        u,
        v,
        tip,
        length,
    })
}

/// The range of `w · (x − origin)` over the box: its extent along `w` (mm).
pub fn extent(stock: &Aabb, origin: &Point3, w: &UnitVector3) -> (Real, Real) {
    corners(stock)
        .iter()
        .fold((Real::INFINITY, Real::NEG_INFINITY), |(lo, hi), c| {
            let x = w.dot(&(c - origin));
            (lo.min(x), hi.max(x))
        })
}

fn corners(b: &Aabb) -> [Point3; 8] {
    std::array::from_fn(|i| {
        Point3::new(
            if i & 1 == 0 { b.min.x } else { b.max.x },
            if i & 2 == 0 { b.min.y } else { b.max.y },
            if i & 4 == 0 { b.min.z } else { b.max.z },
        )
    })
}

/// A face found in a cloud.
#[derive(Clone, Debug, PartialEq)]
pub struct Face {
    /// Its name.
    pub name: String,
    /// The cut that made it.
    pub cut: Move,
    /// The model flank that defined its region.
    pub flank: Flank,
    /// The rotary position of the cut (degrees), per rotary axis in chain order.
    pub rotary_deg: Vec<Real>,
    /// The fitted plane, normal oriented like the flank's.
    pub fit: PlaneFit,
    /// Indices of the cloud points in the region.
    pub indices: Vec<usize>,
    /// How the fitted plane's uncertainty spreads over the face.
    pub design: FaceDesign,
}

/// The least-squares design of a face's plane fit, for propagating its uncertainty to any
/// point and direction: in-plane coordinates along the cut (`u`) and the tool axis (`v`)
/// relative to the centroid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FaceDesign {
    /// In-plane directions (cut direction, tool axis), as on the flank.
    pub basis: [UnitVector3; 2],
    /// Scatter matrix Σ q qᵀ of the used points' in-plane coordinates q (mm²).
    pub scatter: Matrix2<Real>,
    /// Points used.
    pub n: usize,
    /// Residual standard deviation, inflated for correlated residuals (mm).
    pub sigma_mm: Real,
    /// The inflation of the variance for correlated residuals (≥ 1; 1 for independent
    /// noise), from block averaging.
    pub correlation_inflation: Real,
}

impl FaceDesign {
    /// Standard uncertainty (mm) of the plane's offset at the in-plane point `at`.
    pub fn offset_sigma_at(&self, centroid: &Point3, at: &Point3) -> Real {
        let d = at - centroid;
        let q = Vector2::new(self.basis[0].dot(&d), self.basis[1].dot(&d));
        let minv = self
            .scatter
            .try_inverse()
            .unwrap_or_else(|| Matrix2::from_element(Real::INFINITY));
        self.sigma_mm * (1.0 / self.n as Real + (q.transpose() * minv * q)[0]).sqrt()
    }

    /// Standard uncertainty (rad) of the plane's slope along the cut direction.
    pub fn slope_sigma_along_cut(&self) -> Real {
        let minv = self
            .scatter
            .try_inverse()
            .unwrap_or_else(|| Matrix2::from_element(Real::INFINITY));
        self.sigma_mm * minv[(0, 0)].sqrt()
    }
}

/// Block edges (mm) over which residual correlation is looked for: from about three point
/// pitches to a fifth of a typical face.
const BLOCK_EDGES_MM: [Real; 4] = [0.5, 1.0, 2.0, 4.0];
/// Fewest points in a block for its mean to count.
const BLOCK_MIN_POINTS: usize = 4;

/// The design of a fit from its points, with the variance inflation for correlated residuals
/// found by block averaging (Flyvbjerg & Petersen): residual means over blocks of edge b vary
/// like σ²·f/n_block if the residuals are correlated over less than b; f is the largest such
/// ratio over the block sizes, and 1 for independent noise.
pub fn face_design(points: &[Point3], fit: &PlaneFit, basis: [UnitVector3; 2]) -> FaceDesign {
    let c = fit.centroid;
    let coords: Vec<(Real, Real, Real)> = points
        .iter()
        .map(|p| {
            let d = p - c;
            (
                basis[0].dot(&d),
                basis[1].dot(&d),
                fit.plane.signed_distance(p),
            )
        })
        .collect();
    let mut scatter = Matrix2::zeros();
    let mut ss = 0.0;
    for &(u, v, r) in &coords {
        scatter += Matrix2::new(u * u, u * v, u * v, v * v);
        ss += r * r;
    }
    let n = coords.len();
    let var = ss / (n.saturating_sub(3).max(1)) as Real;
    let mut inflation: Real = 1.0;
    for b in BLOCK_EDGES_MM {
        let mut blocks: std::collections::BTreeMap<(i64, i64), (usize, Real)> = Default::default();
        for &(u, v, r) in &coords {
            let e = blocks
                .entry(((u / b).floor() as i64, (v / b).floor() as i64))
                .or_default();
            e.0 += 1;
            e.1 += r;
        }
        let (mut num, mut den) = (0.0, 0usize);
        for &(k, sum) in blocks.values().filter(|(k, _)| *k >= BLOCK_MIN_POINTS) {
            let mean = sum / k as Real;
            num += k as Real * mean * mean;
            den += 1;
        }
        if den >= 8 && var > 0.0 {
            inflation = inflation.max(num / den as Real / var);
        }
    }
    FaceDesign {
        basis,
        scatter,
        n,
        sigma_mm: (var * inflation).sqrt(),
        correlation_inflation: inflation,
    }
}

/// The straight cut on the face's NC line, at constant rotary positions.
pub fn find_cut<'m>(
    moves: &'m [Move],
    spec: &FaceSpec,
    chain: &Chain,
) -> Result<&'m Move, IdentifyError> {
    let mv = moves
        .iter()
        .find(|m| m.line == spec.line)
        .ok_or_else(|| IdentifyError::NoMove {
            face: spec.name.clone(),
            line: spec.line,
        })?;
    let turns = chain
        .axes()
        .iter()
        .any(|a| a.kind == AxisKind::Rotary && mv.start.get(a.letter) != mv.end.get(a.letter));
    if mv.kind != MoveKind::Linear || turns {
        return Err(IdentifyError::NotACut {
            face: spec.name.clone(),
            line: spec.line,
        });
    }
    Ok(mv)
}

/// Indices of the points a face region selects: those passing `auto` for
/// [`FaceRegion::Auto`] (the model's expectation of the face), those in the box, or the
/// planar region grown from the seed (none if no region grows there).
pub fn region_indices(
    points: &[Point3],
    region: &FaceRegion,
    auto: impl Fn(&Point3) -> bool,
) -> Vec<usize> {
    match region {
        FaceRegion::Auto => points
            .iter()
            .enumerate()
            .filter(|(_, p)| auto(p))
            .map(|(i, _)| i)
            .collect(),
        FaceRegion::Box(b) => select_box(points, &b.min, &b.max)
            .into_iter()
            .map(|i| i as usize)
            .collect(),
        FaceRegion::Seed(seed) => {
            select_region_from_seed(points, seed, &PlaneSegmentOptions::default())
                .map(|r| r.indices.into_iter().map(|i| i as usize).collect())
                .unwrap_or_default()
        }
    }
}

/// Segments and fits one face.
pub fn extract_face(
    points: &[Point3],
    spec: &FaceSpec,
    moves: &[Move],
    model: &Chain,
    tool: &Tool,
    stock: &Aabb,
    opts: &FaceOptions,
) -> Result<Face, IdentifyError> {
    let mv = find_cut(moves, spec, model)?;
    let empty = || IdentifyError::EmptyRegion {
        face: spec.name.clone(),
    };
    let fl = flank(model, tool, mv, stock).ok_or_else(empty)?;
    // Extent of the stock along u and v, relative to the cut's start tip.
    let (su, sv) = (extent(stock, &fl.tip, &fl.u), extent(stock, &fl.tip, &fl.v));
    let m = opts.margin_mm;
    let (u0, u1) = (su.0.max(0.0) + m, su.1.min(fl.length) - m);
    // The flank is the cylindrical part of the tool at its full radius: from the tip (flat)
    // or one radius above it (ball); a tool with no such part makes no planar flank.
    let flank_start = tool.flank_start().ok_or_else(empty)?;
    let (v0, v1) = (sv.0.max(flank_start) + m, sv.1.min(tool.length()) - m);
    if u0 >= u1 || v0 >= v1 {
        return Err(empty());
    }
    let indices = region_indices(points, &spec.region, |p| {
        let w = p - fl.tip;
        let (u, v) = (fl.u.dot(&w), fl.v.dot(&w));
        u >= u0
            && u <= u1
            && v >= v0
            && v <= v1
            && fl.plane.signed_distance(p).abs() <= opts.band_mm
    });
    let sel: Vec<Point3> = indices.iter().map(|&i| points[i]).collect();
    let mut fit = fit_plane_robust(&sel, &opts.robust).map_err(|source| IdentifyError::Fit {
        face: spec.name.clone(),
        points: sel.len(),
        source,
    })?;
    fit.plane = fit.plane.oriented_towards(&fl.plane.normal);
    let used: Vec<Point3> = sel
        .iter()
        .copied()
        .filter(|p| {
            fit.plane.signed_distance(p).abs()
                <= opts.robust.k_sigma * fit.rms_mm.max(tol::LENGTH_EPS)
        })
        .collect();
    let design = face_design(&used, &fit, [fl.u, fl.v]);
    let rotary_deg = model
        .axes()
        .iter()
        .filter(|a| a.kind == AxisKind::Rotary)
        .map(|a| mv.start.get(a.letter))
        .collect();
    Ok(Face {
        name: spec.name.clone(),
        cut: *mv,
        flank: fl,
        rotary_deg,
        fit,
        indices,
        design,
    })
}

/// The geometry the step and tilt are measured with, fixed from the model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepFrame {
    /// Where the step is measured (midpoint of the faces' centroids).
    pub at: Point3,
    /// Direction of measurement: the first face's model normal, into the material.
    pub n: UnitVector3,
    /// The first face's cut direction.
    pub u: UnitVector3,
}

impl StepFrame {
    /// Step (mm) and tilt (rad) between two planes.
    pub fn measure(&self, first: &Plane, second: &Plane) -> Option<(Real, Real)> {
        let a = first.intersect_line(&self.at, &self.n)?;
        let b = second.intersect_line(&self.at, &self.n)?;
        let step = (b - a).dot(&self.n);
        let tilt = (second.normal.into_inner() - first.normal.into_inner()).dot(&self.u);
        Some((step, tilt))
    }
}

/// Outcome of the identification.
#[derive(Clone, Debug, PartialEq)]
pub struct StepIdentification {
    /// The measurement frame.
    pub frame: StepFrame,
    /// Measured step (mm): second face minus first, along the first face's normal.
    pub step_mm: Real,
    /// Its standard uncertainty from the fits (mm).
    pub step_sigma_mm: Real,
    /// Measured tilt (rad).
    pub tilt_rad: Real,
    /// Its standard uncertainty (rad).
    pub tilt_sigma_rad: Real,
    /// Name and value of the offset parameter (e.g. `dy_AY`, mm), if identifiable.
    pub offset: Option<(String, Real, Real)>,
    /// Name and value of the angle sum (e.g. `gamma_AY+gamma_YX`, rad), if identifiable.
    pub angle_sum: Option<(String, Real, Real)>,
    /// Name of the offset parameter solved for (e.g. `dy_AY`).
    pub offset_name: String,
    /// Name of the angle combination solved for (e.g. `gamma_AY+gamma_YX`).
    pub angle_name: String,
    /// Singular values of the 2×2 Jacobian (step, tilt) w.r.t. (offset, angle).
    pub singular_values: [Real; 2],
    /// Levenberg–Marquardt evaluations and final residual norm.
    pub solver: (usize, Real),
    /// Deviation names this experiment does not identify (alone or separably): held at
    /// their known values (0 unless the scene gives them), never given a value.
    pub not_identified: Vec<String>,
}

/// The two parameters solved for, on a model chain.
struct StepProblem<'a> {
    model: Chain,
    ids: [DeviationId; 2],
    base: [Real; 2],
    cuts: [&'a Move; 2],
    tool: &'a Tool,
    stock: &'a Aabb,
    frame: StepFrame,
    measured: Vector2<Real>,
    x: Vector2<Real>,
}

impl StepProblem<'_> {
    fn predict(&self, x: &Vector2<Real>) -> Option<Vector2<Real>> {
        let mut chain = self.model.clone();
        for k in 0..2 {
            chain.set_deviation(self.ids[k], self.base[k] + x[k]);
        }
        let f0 = flank(&chain, self.tool, self.cuts[0], self.stock)?;
        let f1 = flank(&chain, self.tool, self.cuts[1], self.stock)?;
        let (s, t) = self.frame.measure(&f0.plane, &f1.plane)?;
        Some(Vector2::new(s, t))
    }

    fn jacobian_at(&self, x: &Vector2<Real>) -> Option<Matrix2<Real>> {
        // Central differences; the model is smooth and nearly linear in these parameters.
        // Steps: 0.1 µm and 1 µrad, small against the deviations, large against rounding.
        let h = [1e-4, 1e-6];
        let mut j = Matrix2::zeros();
        for k in 0..2 {
            let mut a = *x;
            let mut b = *x;
            a[k] += h[k];
            b[k] -= h[k];
            let col = (self.predict(&a)? - self.predict(&b)?) / (2.0 * h[k]);
            j.set_column(k, &col);
        }
        Some(j)
    }
}

impl LeastSquaresProblem<Real, U2, U2> for StepProblem<'_> {
    type ResidualStorage = Owned<Real, U2>;
    type JacobianStorage = Owned<Real, U2, U2>;
    type ParameterStorage = Owned<Real, U2>;

    fn set_params(&mut self, x: &Vector2<Real>) {
        self.x = *x;
    }
    fn params(&self) -> Vector2<Real> {
        self.x
    }
    fn residuals(&self) -> Option<Vector2<Real>> {
        Some(self.predict(&self.x)? - self.measured)
    }
    fn jacobian(&self) -> Option<Matrix2<Real>> {
        self.jacobian_at(&self.x)
    }
}

/// Relative singular value below which a parameter combination counts as not identifiable.
const IDENTIFIABLE_RATIO: Real = 1e-8;

/// Identifies the rotary axis's offset and the angle sum from two faces cut 180° apart.
pub fn identify_step(
    faces: &[Face; 2],
    model: &Chain,
    tool: &Tool,
    stock: &Aabb,
) -> Result<StepIdentification, IdentifyError> {
    let [f0, f1] = faces;
    // The rotary axis whose position differs by 180° between the cuts.
    let rotaries: Vec<(usize, char)> = model
        .axes()
        .iter()
        .enumerate()
        .filter(|(_, a)| a.kind == AxisKind::Rotary)
        .map(|(j, a)| (j, a.letter.as_char()))
        .collect();
    let mut turned = Vec::new();
    for (k, &(joint, letter)) in rotaries.iter().enumerate() {
        let diff = (f1.rotary_deg[k] - f0.rotary_deg[k]).rem_euclid(360.0);
        if (diff - 180.0).abs() < tol::ANGLE_DEG {
            turned.push((joint, letter));
        } else if diff.abs() > tol::ANGLE_DEG && (diff - 360.0).abs() > tol::ANGLE_DEG {
            return Err(IdentifyError::NotAStepPair(format!(
                "axis {letter} differs by {diff}° between '{}' and '{}'",
                f0.name, f1.name
            )));
        }
    }
    let [(joint, _)] = turned[..] else {
        return Err(IdentifyError::NotAStepPair(format!(
            "{} rotary axes differ by 180° between '{}' and '{}'",
            turned.len(),
            f0.name,
            f1.name
        )));
    };
    let ids = [
        DeviationId {
            joint,
            component: Component::Dy,
        },
        DeviationId {
            joint,
            component: Component::Gamma,
        },
    ];
    let frame = StepFrame {
        at: Point3::from((f0.fit.centroid.coords + f1.fit.centroid.coords) / 2.0),
        n: f0.flank.plane.normal,
        u: f0.flank.u,
    };
    let (step, tilt) = frame.measure(&f0.fit.plane, &f1.fit.plane).ok_or_else(|| {
        IdentifyError::NotAStepPair("the fitted faces are perpendicular to each other".into())
    })?;
    // Uncertainties at the point of measurement, not at each face's centroid: the faces'
    // tilts act over the lever arm from their centroids to `at`.
    let step_sigma = f0
        .design
        .offset_sigma_at(&f0.fit.centroid, &frame.at)
        .hypot(f1.design.offset_sigma_at(&f1.fit.centroid, &frame.at));
    let tilt_sigma = f0
        .design
        .slope_sigma_along_cut()
        .hypot(f1.design.slope_sigma_along_cut());
    let problem = StepProblem {
        model: model.clone(),
        ids,
        base: [model.deviation(ids[0]), model.deviation(ids[1])],
        cuts: [&f0.cut, &f1.cut],
        tool,
        stock,
        frame,
        measured: Vector2::new(step, tilt),
        x: Vector2::zeros(),
    };
    let j0 = problem
        .jacobian_at(&Vector2::zeros())
        .ok_or_else(|| IdentifyError::NotAStepPair("the model faces are degenerate".into()))?;
    let sv = j0.svd(false, false).singular_values;
    let (smax, smin) = (sv.max(), sv.min());
    let identifiable = smax > 0.0 && smin / smax > IDENTIFIABLE_RATIO;
    let joint_next = model.joint_name(joint + 1).to_string();
    let offset_name = model.deviation_name(ids[0]);
    let angle_name = if joint + 1 < model.axes().len() {
        format!("{}+gamma_{joint_next}", model.deviation_name(ids[1]))
    } else {
        model.deviation_name(ids[1])
    };
    let mut observed = vec![offset_name.clone(), model.deviation_name(ids[1])];
    if joint + 1 < model.axes().len() {
        observed.push(format!("gamma_{joint_next}"));
    }
    let not_identified = model
        .deviation_names()
        .into_iter()
        .filter(|n| !observed.contains(n))
        .collect();
    let (offset, angle_sum, solver) = if identifiable {
        let (solved, rep) = LevenbergMarquardt::new().minimize(problem);
        let x = solved.x;
        let res = solved
            .residuals()
            .map(|r| r.norm())
            .unwrap_or(Real::INFINITY);
        // Propagate the measurement uncertainties through the inverse Jacobian.
        let jinv = solved
            .jacobian_at(&x)
            .and_then(|j| j.try_inverse())
            .unwrap_or_else(|| Matrix2::from_element(Real::NAN));
        let sig = |k: usize| {
            ((jinv[(k, 0)] * step_sigma).powi(2) + (jinv[(k, 1)] * tilt_sigma).powi(2)).sqrt()
        };
        let gamma_next = if joint + 1 < model.axes().len() {
            model.deviation(DeviationId {
                joint: joint + 1,
                component: Component::Gamma,
            })
        } else {
            0.0
        };
        (
            Some((offset_name.clone(), solved.base[0] + x[0], sig(0))),
            Some((
                angle_name.clone(),
                solved.base[1] + x[1] + gamma_next,
                sig(1),
            )),
            (rep.number_of_evaluations, res),
        )
    } else {
        (None, None, (0, Real::NAN))
    };
    Ok(StepIdentification {
        frame,
        step_mm: step,
        step_sigma_mm: step_sigma,
        tilt_rad: tilt,
        tilt_sigma_rad: tilt_sigma,
        offset,
        angle_sum,
        offset_name,
        angle_name,
        singular_values: [smax, smin],
        solver,
        not_identified,
    })
}

/// The step and tilt the exact chain predicts for two cuts, measured in `frame`.
pub fn predicted_step(
    chain: &Chain,
    tool: &Tool,
    cuts: [&Move; 2],
    stock: &Aabb,
    frame: &StepFrame,
) -> Option<(Real, Real)> {
    let f0 = flank(chain, tool, cuts[0], stock)?;
    let f1 = flank(chain, tool, cuts[1], stock)?;
    frame.measure(&f0.plane, &f1.plane)
}
