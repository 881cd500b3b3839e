//! Features: measured planes (a straight cut's flank or floor fitted in a scan) and ball
//! centres, ISO location and squareness terms, each feature's prediction from the chain and
//! its residuals, and the features taken from a rotary-axis test or a cloud.
//!
//! **Invariant:** a prediction is the exact plane or point of the deviated chain, or `None`
//! for a degenerate cut, never a guess.

use super::*;

// ---------------------------------------------------------------------------------------
// Features.

/// A measured plane: a face of a straight cut, fitted in a scan.
#[derive(Clone, Debug, PartialEq)]
pub struct PlaneFeature {
    /// Name used in reports.
    pub name: String,
    /// The cut that made it.
    pub cut: Move,
    /// Flank or floor.
    pub kind: FaceKind,
    /// The nominal (model) normal into the material: orients the predicted normal.
    pub expected_normal: UnitVector3,
    /// The measured plane (scan frame), normal into the material.
    pub plane: Plane,
    /// The measured centroid (on the plane).
    pub centroid: Point3,
    /// In-plane directions the slopes are measured along.
    pub basis: [UnitVector3; 2],
    /// Standard uncertainty of the offset at the centroid (mm).
    pub offset_sigma_mm: Real,
    /// Whitening of the two slopes: `w · (slopes)` has unit covariance (1/rad).
    pub slope_whitening: Matrix2<Real>,
    /// Floors: the cross-feed range (mm, relative to the tool's tip line) the measured
    /// points cover, over which the envelope's least-squares plane is predicted.
    pub cross_range_mm: (Real, Real),
    /// Floors from a scan: the least-squares line of `√(R² − x₂²)` over the cross-feed
    /// coordinates of the points actually fitted (value at the tip line, slope), so the
    /// prediction weighs the envelope as the fit did. `None`: uniform over `cross_range_mm`.
    pub cross_moments: Option<(Real, Real)>,
    /// Points used in the fit.
    pub points: usize,
    /// RMS residual of the fit (mm).
    pub rms_mm: Real,
    /// The fit's variance inflation for correlated residuals (≥ 1; [`FaceDesign`]).
    pub correlation_inflation: Real,
    /// The standard deviation of the fitted points' coordinate along the cut (mm). With
    /// error motions the face of a straight move is not a plane: its least-squares plane is
    /// predicted through the path at the centroid ± this (exact for a path bent
    /// quadratically, Gauss's two points). `None`: through the move's ends.
    pub cut_spread_mm: Option<Real>,
}

/// A measured ball centre: the tool-side point at axis values `q`, relative to a point
/// fixed on the table (see the module documentation).
#[derive(Clone, Debug, PartialEq)]
pub struct BallFeature {
    /// Name used in reports.
    pub name: String,
    /// The axis values at the measurement (mm, degrees).
    pub q: AxisValues,
    /// The tool-side point in the tool frame (mm): a stylus or master ball's centre.
    pub tool_offset: Vector3,
    /// Which fixed point on the table (index from 0; each has its own unknown position).
    pub anchor: usize,
    /// The measured position of the tool-side point relative to the fixed point, in the
    /// workpiece frame (mm).
    pub measured: Vector3,
    /// Standard uncertainty of each coordinate of `measured` (mm).
    pub sigma_mm: [Real; 3],
}

/// A measured feature: each has its own prediction from the chain.
#[derive(Clone, Debug, PartialEq)]
#[expect(
    clippy::large_enum_variant,
    reason = "features number tens to hundreds per identification; boxing planes would cost               an allocation each for no measurable gain"
)]
pub enum Feature {
    /// A fitted face of a straight cut.
    Plane(PlaneFeature),
    /// A ball centre relative to a fixed point on the table.
    Ball(BallFeature),
}

impl Feature {
    /// The feature's name.
    pub fn name(&self) -> &str {
        match self {
            Feature::Plane(p) => &p.name,
            Feature::Ball(b) => &b.name,
        }
    }
    /// How many residuals it contributes.
    pub fn residual_count(&self) -> usize {
        match self {
            Feature::Plane(_) | Feature::Ball(_) => 3,
        }
    }
}

/// An ISO 230-7 location or squareness term solved for: its name as given, the axis it
/// belongs to (chain index) and its component of the transform `L` (see
/// [`Chain::apply_iso_term`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct IsoTerm {
    /// The name (`EX0C`, `EC(0X)Y`).
    pub name: String,
    /// The axis's index in the chain.
    pub axis: usize,
    /// Which component of `L`.
    pub component: crate::machine::Component,
}

impl IsoTerm {
    /// The term `name` of `chain`, or why it is not one.
    pub fn parse(
        chain: &Chain,
        name: &str,
    ) -> Result<Self, crate::machine::chain::KinematicsError> {
        let (axis, component) = chain.iso_term_id(name)?;
        Ok(IsoTerm {
            name: name.to_string(),
            axis,
            component,
        })
    }
}

impl PlaneFeature {
    /// A feature with the given measured plane and uncertainties: offset σ at the centroid
    /// and independent slope σ along each basis direction.
    #[expect(
        clippy::too_many_arguments,
        reason = "a plain constructor of a data record"
    )]
    pub fn new(
        name: &str,
        cut: Move,
        kind: FaceKind,
        expected_normal: UnitVector3,
        plane: Plane,
        centroid: Point3,
        basis: [UnitVector3; 2],
        offset_sigma_mm: Real,
        slope_sigma_rad: [Real; 2],
        cross_range_mm: (Real, Real),
    ) -> Self {
        PlaneFeature {
            name: name.to_string(),
            cut,
            kind,
            expected_normal,
            plane,
            centroid,
            basis,
            offset_sigma_mm,
            slope_whitening: Matrix2::new(
                1.0 / slope_sigma_rad[0],
                0.0,
                0.0,
                1.0 / slope_sigma_rad[1],
            ),
            cross_range_mm,
            cross_moments: None,
            points: 0,
            rms_mm: 0.0,
            correlation_inflation: 1.0,
            cut_spread_mm: None,
        }
    }

    fn from_design(
        name: &str,
        cut: Move,
        kind: FaceKind,
        expected_normal: UnitVector3,
        fit: &crate::metrology::fit::PlaneFit,
        design: &FaceDesign,
        cross_range_mm: (Real, Real),
    ) -> Self {
        // Slopes have covariance σ²·M⁻¹ (M the scatter); with M = L·Lᵀ, Lᵀ/σ whitens them.
        let l = design
            .scatter
            .cholesky()
            .map(|c| c.l())
            .unwrap_or_else(Matrix2::zeros);
        PlaneFeature {
            name: name.to_string(),
            cut,
            kind,
            expected_normal,
            plane: fit.plane,
            centroid: fit.centroid,
            basis: design.basis,
            offset_sigma_mm: design.sigma_mm / (design.n.max(1) as Real).sqrt(),
            slope_whitening: l.transpose() / design.sigma_mm,
            cross_range_mm,
            cross_moments: None,
            points: design.n,
            rms_mm: fit.rms_mm,
            correlation_inflation: design.correlation_inflation,
            cut_spread_mm: (design.n > 0)
                .then(|| (design.scatter[(0, 0)] / design.n as Real).sqrt()),
        }
    }
}

/// The least-squares line of `√(R² − x²)` over the samples `xs`: its value at `x = 0` and
/// its slope; `None` for fewer than two distinct samples.
fn sampled_envelope_line(r: Real, xs: &[Real]) -> Option<(Real, Real)> {
    let n = xs.len() as Real;
    let f = |x: Real| (r * r - x * x).max(0.0).sqrt();
    let mx = xs.iter().sum::<Real>() / n;
    let mf = xs.iter().map(|&x| f(x)).sum::<Real>() / n;
    let (mut sxx, mut sxf) = (0.0, 0.0);
    for &x in xs {
        sxx += (x - mx) * (x - mx);
        sxf += (x - mx) * (f(x) - mf);
    }
    (xs.len() >= 2 && sxx > 0.0).then(|| {
        let slope = sxf / sxx;
        (mf - slope * mx, slope)
    })
}

/// The least-squares line of `√(R² − x²)` over `x` uniform in `[a, b]` (Simpson): its value
/// at `x = 0` (the tool's tip line) and its slope.
fn envelope_moments(r: Real, (a, b): (Real, Real)) -> (Real, Real) {
    const N: usize = 64;
    if b <= a {
        return ((r * r - a * a).max(0.0).sqrt(), 0.0);
    }
    let h = (b - a) / N as Real;
    let (mut s0, mut s1, mut s2, mut w) = (0.0, 0.0, 0.0, 0.0);
    for i in 0..=N {
        let x = a + h * i as Real;
        let c = if i == 0 || i == N {
            1.0
        } else if i % 2 == 1 {
            4.0
        } else {
            2.0
        };
        let f = (r * r - x * x).max(0.0).sqrt();
        w += c;
        s0 += c * f;
        s1 += c * x;
        s2 += c * x * f;
    }
    let (mf, mx) = (s0 / w, s1 / w);
    let var = (b - a).powi(2) / 12.0;
    let slope = (s2 / w - mx * mf) / var;
    // The least-squares line passes through (mean x, mean f): its value at x = 0.
    (mf - slope * mx, slope)
}

/// The predicted plane (workpiece frame) of a plane feature: unit normal into the material
/// and offset, or `None` when the cut is degenerate.
fn predict_plane<T: Scalar>(
    chain: &Chain,
    x: &Params<T>,
    tool: &Tool,
    f: &PlaneFeature,
) -> Option<(V3<T>, T)> {
    let mut p0 = pose(chain, x, &f.cut.start);
    let mut p1 = pose(chain, x, &f.cut.end);
    if let Some(spread) = f.cut_spread_mm.filter(|_| chain.has_error_motions()) {
        // The path bends with the error motions: through its points at the centroid ±
        // the points' spread along the cut (where along the move is taken from values:
        // moving it changes the plane only to second order).
        let d = values(vsub(p1.t, p0.t));
        let len2 = d.norm_squared();
        if len2 > tol::LENGTH_EPS * tol::LENGTH_EPS {
            let at = (f.centroid.coords - values(p0.t)).dot(&d) / len2;
            let h = spread / len2.sqrt();
            let q = |s: Real| f.cut.point_at(s.clamp(0.0, 1.0));
            (p0, p1) = (pose(chain, x, &q(at - h)), pose(chain, x, &q(at + h)));
        }
    }
    let tip = p0.t;
    let d = vsub(p1.t, tip);
    let v = [p0.r[0][2], p0.r[1][2], p0.r[2][2]];
    let r = T::c(tool.radius());
    let expected = v3::<T>(&f.expected_normal.into_inner());
    match f.kind {
        FaceKind::Flank => {
            let w = cross(d, v);
            if dot(w, w).value().sqrt() < tol::LENGTH_EPS {
                return None;
            }
            let mut n = normalize(w);
            if dot(n, expected).value() < 0.0 {
                n = vscale(n, T::c(-1.0));
            }
            Some((n, dot(n, tip) + r))
        }
        FaceKind::Floor => {
            if dot(d, d).value().sqrt() < tol::LENGTH_EPS {
                return None;
            }
            let u = normalize(d);
            let t = dot(u, v);
            let m = normalize(vsub(vscale(u, t), v));
            let e2 = normalize(cross(v, u));
            let (f0, f2) = f
                .cross_moments
                .unwrap_or_else(|| envelope_moments(tool.radius(), f.cross_range_mm));
            let (c0, c2) = (t.abs() * T::c(f0), t.abs() * T::c(f2));
            let mut n = normalize(vsub(m, vscale(e2, c2)));
            let at = vadd(tip, vscale(m, c0));
            if dot(n, expected).value() < 0.0 {
                n = vscale(n, T::c(-1.0));
            }
            Some((n, dot(n, at)))
        }
    }
}

/// The residuals of one feature for the unknowns `x`, registration `reg` and fixed points
/// `anchors` (generic).
pub(super) fn feature_residuals<T: Scalar>(
    chain: &Chain,
    x: &Params<T>,
    reg: &[T; 6],
    anchors: &[T],
    tool: &Tool,
    f: &Feature,
) -> Option<[T; 3]> {
    match f {
        Feature::Ball(b) => {
            let pose = pose(chain, x, &b.q);
            let p = vadd(pose.rotate(v3(&b.tool_offset)), pose.t);
            let a = anchors.get(3 * b.anchor..3 * b.anchor + 3)?;
            Some(std::array::from_fn(|k| {
                (p[k] - a[k] - T::c(b.measured[k])) / T::c(b.sigma_mm[k])
            }))
        }
        Feature::Plane(pf) => {
            let (n, d) = predict_plane(chain, x, tool, pf)?;
            let s_from_w = Rigid::deviation(reg);
            let ns = s_from_w.rotate(n);
            let ds = d + dot(ns, s_from_w.t);
            let c = v3::<T>(&pf.centroid.coords);
            let r0 = (dot(ns, c) - ds) / T::c(pf.offset_sigma_mm);
            let nm = v3::<T>(&pf.plane.normal.into_inner());
            let dn = vsub(ns, nm);
            let s1 = dot(dn, v3(&pf.basis[0].into_inner()));
            let s2 = dot(dn, v3(&pf.basis[1].into_inner()));
            let w = &pf.slope_whitening;
            Some([
                r0,
                T::c(w[(0, 0)]) * s1 + T::c(w[(0, 1)]) * s2,
                T::c(w[(1, 0)]) * s1 + T::c(w[(1, 1)]) * s2,
            ])
        }
    }
}

/// The predicted plane of a feature on `chain` (workpiece frame): normal into the material
/// and offset. `None` for a degenerate cut.
pub fn predicted_plane(chain: &Chain, tool: &Tool, f: &PlaneFeature) -> Option<Plane> {
    let none = Params {
        ids: &[],
        p: &[],
        iso: &[],
        t: &[],
    };
    let (n, d) = predict_plane::<Real>(chain, &none, tool, f)?;
    let n = UnitVector3::new_normalize(values(n));
    Some(Plane {
        normal: n,
        offset: d,
    })
}

// ---------------------------------------------------------------------------------------
// Features from a rotary-axis test.

/// Ball features from a motion test's or a probing cycle's samples (see
/// [`crate::metrology::rotary_test`]), all measured from fixed point `anchor`, the
/// tool-side ball at `tool_offset` in the tool frame.
pub fn ball_features(
    samples: &[crate::metrology::rotary_test::Sample],
    tool_offset: Vector3,
    anchor: usize,
) -> Vec<Feature> {
    samples
        .iter()
        .map(|s| {
            Feature::Ball(BallFeature {
                name: format!("sweep {} {} = {}°", s.sweep, s.axis, s.angle_deg),
                q: s.q,
                tool_offset,
                anchor,
                measured: Vector3::from(s.deviation_mm),
                sigma_mm: s.sigma_mm,
            })
        })
        .collect()
}

// ---------------------------------------------------------------------------------------
// Features from a cloud.

/// Extracts and fits one face of the scene's program as a plane feature:
/// [`select_plane_face`], then [`plane_feature`].
pub fn extract_plane_feature(
    points: &[Point3],
    spec: &FaceSpec,
    moves: &[Move],
    model: &Chain,
    tool: &Tool,
    stock: &Aabb,
    opts: &FaceOptions,
) -> Result<PlaneFeature, CalibrateError> {
    let sel = select_plane_face(points, spec, moves, model, tool, stock, opts)?;
    plane_feature(points, &sel, model, tool, opts)
}

/// Selects the points of a face (flank or floor) in a cloud ([`select_face`]); a floor
/// needs a flat end mill.
pub fn select_plane_face(
    points: &[Point3],
    spec: &FaceSpec,
    moves: &[Move],
    model: &Chain,
    tool: &Tool,
    stock: &Aabb,
    opts: &FaceOptions,
) -> Result<FaceSelection, CalibrateError> {
    if spec.kind == FaceKind::Floor && tool.kind() != ToolKind::Flat {
        return Err(CalibrateError::FloorNeedsFlatTool(spec.name.clone()));
    }
    Ok(select_face(points, spec, moves, model, tool, stock, opts)?)
}

/// Fits a selected face as a plane feature: the flank by [`fit_face`], the floor with the
/// cross-feed range and envelope moments of the points it keeps.
pub fn plane_feature(
    points: &[Point3],
    sel: &FaceSelection,
    model: &Chain,
    tool: &Tool,
    opts: &FaceOptions,
) -> Result<PlaneFeature, CalibrateError> {
    let name = &sel.spec.name;
    match sel.spec.kind {
        FaceKind::Flank => {
            let face = fit_face(points, sel, model, opts)?;
            Ok(PlaneFeature::from_design(
                name,
                face.cut,
                FaceKind::Flank,
                face.flank.plane.normal,
                &face.fit,
                &face.design,
                (0.0, 0.0),
            ))
        }
        FaceKind::Floor => {
            let (selected, fit) = fit_selection(points, sel, opts)?;
            let used = used_points(&selected, &fit, opts);
            let [u, e2] = sel.window.axes;
            let tip = sel.window.origin;
            let xs: Vec<Real> = used.iter().map(|p| e2.dot(&(p - tip))).collect();
            let cross = xs
                .iter()
                .fold((Real::INFINITY, Real::NEG_INFINITY), |(a, b), &x| {
                    (a.min(x), b.max(x))
                });
            let design = face_design(&used, &fit, [u, e2]);
            let mut f = PlaneFeature::from_design(
                name,
                sel.cut,
                FaceKind::Floor,
                sel.window.plane.normal,
                &fit,
                &design,
                cross,
            );
            f.cross_moments = sampled_envelope_line(tool.radius(), &xs);
            Ok(f)
        }
    }
}

/// A plane feature exactly as the chain `truth` predicts it, with the given uncertainties:
/// for synthetic studies and tests (no scan). The nominal frame comes from `model`.
#[expect(
    clippy::too_many_arguments,
    reason = "a plain constructor of a data record"
)]
pub fn synthetic_plane_feature(
    spec: &FaceSpec,
    cut: &Move,
    truth: &Chain,
    model: &Chain,
    tool: &Tool,
    stock: &Aabb,
    offset_sigma_mm: Real,
    slope_sigma_rad: [Real; 2],
    cross_range_mm: (Real, Real),
) -> Option<PlaneFeature> {
    let fl = flank(model, tool, cut, stock)?;
    let (expected, basis) = match spec.kind {
        FaceKind::Flank => (fl.plane.normal, [fl.u, fl.v]),
        FaceKind::Floor => {
            let e2 = UnitVector3::try_new(fl.v.cross(&fl.u), tol::LENGTH_EPS)?;
            let m =
                UnitVector3::new_normalize(fl.u.into_inner() * fl.u.dot(&fl.v) - fl.v.into_inner());
            (m, [fl.u, e2])
        }
    };
    let mut f = PlaneFeature::new(
        &spec.name,
        *cut,
        spec.kind,
        expected,
        Plane::through(&fl.tip, expected),
        fl.tip,
        basis,
        offset_sigma_mm,
        slope_sigma_rad,
        cross_range_mm,
    );
    let plane = predicted_plane(truth, tool, &f)?;
    // The measured centroid: the middle of the face's part inside the stock.
    let (su, sv) = (extent(stock, &fl.tip, &fl.u), extent(stock, &fl.tip, &fl.v));
    let along = (su.0.max(0.0) + su.1.min(fl.length)) / 2.0;
    let mid = fl.tip
        + fl.u.into_inner() * along
        + match spec.kind {
            FaceKind::Flank => {
                fl.v.into_inner() * ((sv.0.max(0.0) + sv.1.min(tool.length())) / 2.0)
            }
            FaceKind::Floor => {
                basis[1].into_inner() * ((cross_range_mm.0 + cross_range_mm.1) / 2.0)
            }
        };
    f.centroid = plane.project(&mid);
    f.cut_spread_mm = Some((su.1.min(fl.length) - su.0.max(0.0)).max(0.0) / 12.0_f64.sqrt());
    f.plane = plane;
    Some(f)
}
