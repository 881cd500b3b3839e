//! General identification of a machine's deviations from measured features (see
//! docs/identification-and-correction.md): any chain, any set of features, any choice of
//! deviations to solve for.
//!
//! **Features.** A [`Feature`] is one measured quantity group with its uncertainty:
//! [`PlaneFeature`], a face cut by a straight move of a flat (or ball) end mill and fitted in
//! a scan — its *flank* (tangent to the tool cylinder, containing the tool axis and the path:
//! an exact plane) or, for flat end mills, its *floor*; and [`BallFeature`], a ball centre: the
//! tool-side point (a probe's stylus ball, a master ball in the spindle) at known axis values,
//! measured relative to a point fixed on the table (a calibration sphere a probe touched, a
//! ball sensor's origin). Ball-bar lengths and interferometer readings are further variants:
//! each only needs a prediction from the chain written with the generic scalar below.
//!
//! **Parameters.** The unknowns are joint deviations (`dy_AY`) and, on top of the chain's
//! current values, ISO 230-7 location and squareness terms ([`IsoTerm`]: `EX0C`, `EB0A`,
//! `EC(0X)Y`) applied exactly as [`Chain::apply_iso_term`] does — the names a user of
//! KinematicsOpt or CYCLE996 reads.
//!
//! **Balls.** Residual: `(p(q) − (a_k + m))/σ` per coordinate, `p(q)` the tool-side point in
//! the workpiece frame, `m` the measured offset from the fixed point `k` (zero when a probe
//! found the sphere's centre, the sensor's reading otherwise) and `a_k` the fixed point's
//! position, estimated jointly (3 nuisance parameters per fixed point): where a sphere sits on
//! the table is never known well enough to take as given.
//!
//! **Floors.** The bottom disc of a flat end mill translating along `u` sweeps an exact plane
//! only when the tool axis `v` is perpendicular to `u`. With `t = u·v ≠ 0` the disc's rim
//! leaves an elliptic cylinder along `u` whose depth below the plane through the tip line
//! (containing `u` and the cross-feed direction `e₂ ⟂ u, v`) is exactly `|t|·√(R² − x₂²)`
//! at cross-feed coordinate `x₂`. The predicted floor is the least-squares plane of that
//! surface over the cross-feed range the measured points cover (uniform in `x₂`): depth
//! `|t|·F₀` at the tip line and tilt `|t|·F₂` about `u`, with `F₀, F₂` the intercept at
//! `x₂ = 0` and the slope of the least-squares line of `√(R² − x₂²)` there. The along-feed tilt enters a floor only through `|t|` (second order
//! and sign-blind); floors therefore inform the across-feed tilt and the path's slope.
//!
//! **Residuals.** Per plane: the predicted plane's signed distance at the measured centroid
//! divided by its standard uncertainty there, and the two slopes of the predicted normal
//! relative to the measured one along the face's in-plane basis, whitened by the fit's
//! design (scatter of the points, residual σ inflated for correlation: [`FaceDesign`]).
//!
//! **Registration.** A scan is not in the workpiece frame: by default a rigid registration
//! `s_from_w = Trans·Rx·Ry·Rz` (6 nuisance parameters) is estimated jointly, so only the
//! relative geometry of the faces identifies deviations. `Registration::Workpiece` trusts the
//! W frame instead.
//!
//! **Jacobian.** Forward-mode automatic differentiation: the chain and the feature
//! predictions are written once for a generic scalar ([`Scalar`]), evaluated in `f64` for the
//! residuals and in dual numbers, one parameter per pass, for the Jacobian's columns.
//!
//! **Identifiability.** The whitened Jacobian of the deviations, with the registration's
//! columns projected out, is scaled by each parameter's realistic magnitude
//! ([`magnitude`]: 0.5 mm, 5e-4 rad) and decomposed (SVD). A direction is *determined*
//! when its standard uncertainty is below [`DETERMINED_FRACTION`] of its realistic magnitude.
//! A parameter lying in the determined subspace is identified on its own; the rest of the
//! subspace is reported as named combinations (e.g. `gamma_AY + gamma_YX`); the
//! complement is *not determined*, reported in named form, held at its prior value and
//! never given a value. Levenberg–Marquardt solves only in the determined subspace.
//!
//! **Invariant:** reads features and a chain; never runs the sweep or the scanner, never
//! touches files; never gives a value to a parameter or combination the features do not
//! determine.

use crate::calibration::goodness::{
    FitCheck, MODEL_ACCURACY_MM, PartFit, REFUSE_P, RankMargin, ScanNoise, face_rms_check,
    least_squares_check,
};
use crate::calibration::identify::{
    FaceDesign, FaceOptions, FaceSelection, FaceSpec, extent, face_design, fit_face, fit_selection,
    flank, select_face, used_points,
};
use crate::cutting::tool::{Tool, ToolKind};
use crate::machine::chain::{Chain, DeviationId};
use crate::math::{Aabb, Point3, Real, UnitVector3, Vector3, tol};
use crate::metrology::fit::Plane;
use crate::nc::{AxisValues, Move};
use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
use nalgebra::{DMatrix, DVector, Dyn, Matrix2, Owned};
use std::ops::{Add, Div, Mul, Neg, Sub};

pub use crate::calibration::identify::FaceKind;

/// Errors of general identification.
#[derive(Debug, PartialEq, thiserror::Error)]
pub enum CalibrateError {
    /// Face extraction failed.
    #[error("{0}")]
    Face(#[from] crate::calibration::identify::IdentifyError),
    /// A floor was asked of a tool without a flat bottom.
    #[error("face '{0}': a floor needs a flat end mill")]
    FloorNeedsFlatTool(String),
    /// No parameter to solve for.
    #[error("no deviation to identify was given")]
    NoParameters,
    /// No feature to solve from.
    #[error("no measured feature was given")]
    NoFeatures,
    /// A requested parameter is not informed by any feature at all.
    #[error("no data for {0}: no measured feature depends on it (add cuts that do, or drop it)")]
    NoData(String),
    /// A feature's prediction is degenerate (a cut along the tool axis, a zero-length move).
    #[error("feature '{0}': the model cannot predict it (degenerate cut)")]
    Degenerate(String),
    /// The solver did not converge.
    #[error("the solver did not converge: {0}")]
    NotConverged(String),
}

// ---------------------------------------------------------------------------------------
// Generic scalar: f64 for values, dual numbers for derivatives.

/// The arithmetic the predictions are written in: `f64` gives values, [`Dual`] one
/// directional derivative alongside.
pub trait Scalar:
    Copy
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
{
    /// A constant.
    fn c(x: Real) -> Self;
    /// The value part.
    fn value(self) -> Real;
    /// Square root.
    fn sqrt(self) -> Self;
    /// Sine.
    fn sin(self) -> Self;
    /// Cosine.
    fn cos(self) -> Self;
    /// Absolute value (derivative: the sign; 0 at 0).
    fn abs(self) -> Self;
}

impl Scalar for Real {
    fn c(x: Real) -> Self {
        x
    }
    fn value(self) -> Real {
        self
    }
    fn sqrt(self) -> Self {
        Real::sqrt(self)
    }
    fn sin(self) -> Self {
        Real::sin(self)
    }
    fn cos(self) -> Self {
        Real::cos(self)
    }
    fn abs(self) -> Self {
        Real::abs(self)
    }
}

/// A dual number `v + d·ε`, ε² = 0: forward-mode automatic differentiation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Dual {
    /// Value.
    pub v: Real,
    /// Derivative along the seeded direction.
    pub d: Real,
}

impl Add for Dual {
    type Output = Dual;
    fn add(self, o: Dual) -> Dual {
        Dual {
            v: self.v + o.v,
            d: self.d + o.d,
        }
    }
}
impl Sub for Dual {
    type Output = Dual;
    fn sub(self, o: Dual) -> Dual {
        Dual {
            v: self.v - o.v,
            d: self.d - o.d,
        }
    }
}
impl Mul for Dual {
    type Output = Dual;
    fn mul(self, o: Dual) -> Dual {
        Dual {
            v: self.v * o.v,
            d: self.d * o.v + self.v * o.d,
        }
    }
}
impl Div for Dual {
    type Output = Dual;
    fn div(self, o: Dual) -> Dual {
        Dual {
            v: self.v / o.v,
            d: (self.d * o.v - self.v * o.d) / (o.v * o.v),
        }
    }
}
impl Neg for Dual {
    type Output = Dual;
    fn neg(self) -> Dual {
        Dual {
            v: -self.v,
            d: -self.d,
        }
    }
}
impl Scalar for Dual {
    fn c(x: Real) -> Self {
        Dual { v: x, d: 0.0 }
    }
    fn value(self) -> Real {
        self.v
    }
    fn sqrt(self) -> Self {
        let s = self.v.sqrt();
        Dual {
            v: s,
            d: self.d / (2.0 * s),
        }
    }
    fn sin(self) -> Self {
        Dual {
            v: self.v.sin(),
            d: self.d * self.v.cos(),
        }
    }
    fn cos(self) -> Self {
        Dual {
            v: self.v.cos(),
            d: -self.d * self.v.sin(),
        }
    }
    fn abs(self) -> Self {
        if self.v < 0.0 {
            -self
        } else if self.v > 0.0 {
            self
        } else {
            Dual::c(0.0)
        }
    }
}

type V3<T> = [T; 3];

fn v3<T: Scalar>(v: &Vector3) -> V3<T> {
    [T::c(v.x), T::c(v.y), T::c(v.z)]
}
fn vadd<T: Scalar>(a: V3<T>, b: V3<T>) -> V3<T> {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
fn vsub<T: Scalar>(a: V3<T>, b: V3<T>) -> V3<T> {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn vscale<T: Scalar>(a: V3<T>, s: T) -> V3<T> {
    [a[0] * s, a[1] * s, a[2] * s]
}
fn dot<T: Scalar>(a: V3<T>, b: V3<T>) -> T {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn cross<T: Scalar>(a: V3<T>, b: V3<T>) -> V3<T> {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
fn normalize<T: Scalar>(a: V3<T>) -> V3<T> {
    vscale(a, T::c(1.0) / dot(a, a).sqrt())
}
fn values<T: Scalar>(a: V3<T>) -> Vector3 {
    Vector3::new(a[0].value(), a[1].value(), a[2].value())
}

/// A rigid transform in generic scalars: rotation (row-major) and translation.
#[derive(Clone, Copy)]
struct Rigid<T> {
    r: [[T; 3]; 3],
    t: V3<T>,
}

impl<T: Scalar> Rigid<T> {
    fn from_isometry(iso: &crate::math::Isometry3) -> Self {
        let m = iso.rotation.to_rotation_matrix();
        let m = m.matrix();
        Rigid {
            r: std::array::from_fn(|i| std::array::from_fn(|j| T::c(m[(i, j)]))),
            t: v3(&iso.translation.vector),
        }
    }
    /// Trans(dx,dy,dz)·Rx(alpha)·Ry(beta)·Rz(gamma), exact.
    fn deviation(p: &[T; 6]) -> Self {
        let (sa, ca) = (p[3].sin(), p[3].cos());
        let (sb, cb) = (p[4].sin(), p[4].cos());
        let (sg, cg) = (p[5].sin(), p[5].cos());
        let (o, z) = (T::c(1.0), T::c(0.0));
        let rx = [[o, z, z], [z, ca, -sa], [z, sa, ca]];
        let ry = [[cb, z, sb], [z, o, z], [-sb, z, cb]];
        let rz = [[cg, -sg, z], [sg, cg, z], [z, z, o]];
        Rigid {
            r: mat_mul(&mat_mul(&rx, &ry), &rz),
            t: [p[0], p[1], p[2]],
        }
    }
    fn compose(&self, o: &Rigid<T>) -> Rigid<T> {
        Rigid {
            r: mat_mul(&self.r, &o.r),
            t: vadd(self.rotate(o.t), self.t),
        }
    }
    fn rotate(&self, v: V3<T>) -> V3<T> {
        std::array::from_fn(|i| self.r[i][0] * v[0] + self.r[i][1] * v[1] + self.r[i][2] * v[2])
    }
    fn inverse(&self) -> Rigid<T> {
        let r: [[T; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| self.r[j][i]));
        let t = std::array::from_fn(|i| {
            -(r[i][0] * self.t[0] + r[i][1] * self.t[1] + r[i][2] * self.t[2])
        });
        Rigid { r, t }
    }
}

fn mat_mul<T: Scalar>(a: &[[T; 3]; 3], b: &[[T; 3]; 3]) -> [[T; 3]; 3] {
    std::array::from_fn(|i| {
        std::array::from_fn(|j| a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j])
    })
}

/// The unknowns a pose depends on: joint deviations replaced by `p`, ISO terms `iso` with
/// values `t` composed on top (generic scalars).
#[derive(Clone, Copy)]
struct Params<'a, T> {
    ids: &'a [DeviationId],
    p: &'a [T],
    iso: &'a [IsoTerm],
    t: &'a [T],
}

/// `w_from_t(q)` of `chain` with the deviations `ids` replaced by `p` and the ISO terms
/// applied (generic scalars): an axis with terms moves as `L·M·L⁻¹` (`M·L⁻¹` for the first
/// axis, whose `L` next to the workpiece frame only moves that frame), exactly as
/// [`Chain::apply_iso_term`] composes them onto the joints.
fn pose<T: Scalar>(chain: &Chain, x: &Params<T>, q: &AxisValues) -> Rigid<T> {
    let mut out = Rigid::from_isometry(&crate::math::Isometry3::identity());
    for (j, (axis, dev)) in chain.axes().iter().zip(chain.deviations()).enumerate() {
        let mut d: [T; 6] = std::array::from_fn(|k| T::c(dev.values[k]));
        for (id, v) in x.ids.iter().zip(x.p) {
            if id.joint == j {
                d[id.component as usize] = *v;
            }
        }
        let m = Rigid::from_isometry(&axis.motion(q.get(axis.letter)));
        let m = if x.iso.iter().any(|t| t.axis == j) {
            let mut v: [T; 6] = std::array::from_fn(|_| T::c(0.0));
            for (term, val) in x.iso.iter().zip(x.t) {
                if term.axis == j {
                    v[term.component as usize] = v[term.component as usize] + *val;
                }
            }
            let o = v3::<T>(&chain.error_centre(j).coords);
            let e = Rigid::deviation(&v);
            // L = Trans(o)·Trans(d)·R·Trans(−o)
            let l = Rigid {
                r: e.r,
                t: vsub(vadd(o, e.t), e.rotate(o)),
            };
            let ml = m.compose(&l.inverse());
            if j == 0 { ml } else { l.compose(&ml) }
        } else {
            m
        };
        out = out.compose(&m).compose(&Rigid::deviation(&d));
    }
    out
}

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
    let p0 = pose(chain, x, &f.cut.start);
    let p1 = pose(chain, x, &f.cut.end);
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
fn feature_residuals<T: Scalar>(
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
// The least-squares model.

/// How the scan's frame relates to the workpiece frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Registration {
    /// Estimate a rigid registration (6 nuisance parameters) with the deviations.
    #[default]
    Estimate,
    /// The scan is in the workpiece frame.
    Workpiece,
}

/// The full model: residuals and Jacobian of features w.r.t. deviations and registration.
#[derive(Clone, Debug)]
pub struct Model<'a> {
    /// The chain at the prior (known and current values of every deviation).
    pub chain: &'a Chain,
    /// The deviations solved for.
    pub ids: &'a [DeviationId],
    /// The ISO location and squareness terms solved for, on top of the chain's values.
    pub iso_terms: &'a [IsoTerm],
    /// The tool.
    pub tool: &'a Tool,
    /// The features.
    pub features: &'a [Feature],
    /// Registration handling.
    pub registration: Registration,
}

impl Model<'_> {
    /// Number of residuals.
    pub fn rows(&self) -> usize {
        self.features.iter().map(Feature::residual_count).sum()
    }

    /// Number of unknowns: deviations, ISO terms, then 6 registration parameters if
    /// estimated (and planes are measured), then 3 per fixed point of the ball features.
    pub fn cols(&self) -> usize {
        self.params() + self.reg_cols() + 3 * self.anchor_count()
    }

    /// Number of parameters of the machine solved for: deviations, then ISO terms.
    pub fn params(&self) -> usize {
        self.ids.len() + self.iso_terms.len()
    }

    /// The parameters' names, in solve order.
    pub fn param_names(&self) -> Vec<String> {
        self.ids
            .iter()
            .map(|id| self.chain.deviation_name(*id))
            .chain(self.iso_terms.iter().map(|t| t.name.clone()))
            .collect()
    }

    /// The parameters' realistic magnitudes ([`magnitude`]), in solve order.
    pub fn param_scales(&self) -> Vec<Real> {
        self.ids
            .iter()
            .map(|id| magnitude(*id))
            .chain(
                self.iso_terms
                    .iter()
                    .map(|t| component_magnitude(t.component)),
            )
            .collect()
    }

    /// Number of registration parameters: 6 when estimated and a plane is measured.
    pub fn reg_cols(&self) -> usize {
        let planes = self.features.iter().any(|f| matches!(f, Feature::Plane(_)));
        match self.registration {
            Registration::Estimate if planes => 6,
            _ => 0,
        }
    }

    /// Number of fixed points the ball features are measured from.
    pub fn anchor_count(&self) -> usize {
        self.features
            .iter()
            .filter_map(|f| match f {
                Feature::Ball(b) => Some(b.anchor + 1),
                Feature::Plane(_) => None,
            })
            .max()
            .unwrap_or(0)
    }

    fn eval<T: Scalar>(&self, x: &[T]) -> Option<Vec<T>> {
        let (p, rest) = x.split_at(self.ids.len());
        let (t, rest) = rest.split_at(self.iso_terms.len());
        let (reg, anchors) = rest.split_at(self.reg_cols());
        let reg: [T; 6] = std::array::from_fn(|k| reg.get(k).copied().unwrap_or(T::c(0.0)));
        let params = Params {
            ids: self.ids,
            p,
            iso: self.iso_terms,
            t,
        };
        let mut out = Vec::with_capacity(self.rows());
        for f in self.features {
            out.extend(feature_residuals(
                self.chain, &params, &reg, anchors, self.tool, f,
            )?);
        }
        Some(out)
    }

    /// Whitened residuals at `x` (absolute deviation values, then registration).
    pub fn residuals(&self, x: &DVector<Real>) -> Option<DVector<Real>> {
        Some(DVector::from_vec(self.eval::<Real>(x.as_slice())?))
    }

    /// The Jacobian of the whitened residuals at `x`, by forward-mode automatic
    /// differentiation (one dual-number pass per unknown).
    pub fn jacobian(&self, x: &DVector<Real>) -> Option<DMatrix<Real>> {
        let (m, n) = (self.rows(), self.cols());
        let mut j = DMatrix::zeros(m, n);
        for k in 0..n {
            let xd: Vec<Dual> = x
                .iter()
                .enumerate()
                .map(|(i, &v)| Dual {
                    v,
                    d: if i == k { 1.0 } else { 0.0 },
                })
                .collect();
            let r = self.eval(&xd)?;
            for (i, ri) in r.iter().enumerate() {
                j[(i, k)] = ri.d;
            }
        }
        Some(j)
    }

    /// The starting point: the chain's current deviation values, ISO terms and
    /// registration zero, each fixed point at the mean of where its balls put it.
    pub fn start(&self) -> DVector<Real> {
        let mut x = DVector::zeros(self.cols());
        for (k, id) in self.ids.iter().enumerate() {
            x[k] = self.chain.deviation(*id);
        }
        let base = self.params() + self.reg_cols();
        let mut count = vec![0usize; self.anchor_count()];
        for f in self.features {
            if let Feature::Ball(b) = f {
                let p = self.chain.w_from_t(&b.q) * Point3::from(b.tool_offset) - b.measured;
                for k in 0..3 {
                    x[base + 3 * b.anchor + k] += p[k];
                }
                count[b.anchor] += 1;
            }
        }
        for (a, n) in count.iter().enumerate() {
            for k in 0..3 {
                x[base + 3 * a + k] /= (*n).max(1) as Real;
            }
        }
        x
    }

    /// Names of the nuisance unknowns after the parameters: registration, fixed points.
    fn nuisance_names(&self) -> Vec<String> {
        let reg = ["dx", "dy", "dz", "alpha", "beta", "gamma"];
        reg.iter()
            .take(self.reg_cols())
            .map(|r| format!("registration {r}"))
            .chain((0..self.anchor_count()).flat_map(|a| {
                ["x", "y", "z"]
                    .into_iter()
                    .map(move |c| format!("fixed point {} {c}", a + 1))
            }))
            .collect()
    }
}

/// The realistic magnitude of a deviation, used to scale the Jacobian before deciding
/// what is determined: 0.5 mm for offsets, 5e-4 rad for angles (the sizes of
/// assembly deviations of small machines).
pub fn magnitude(id: DeviationId) -> Real {
    component_magnitude(id.component)
}

/// The realistic magnitude of a component (see [`magnitude`]).
pub fn component_magnitude(c: crate::machine::Component) -> Real {
    if c.is_angle() {
        ANGLE_MAGNITUDE_RAD
    } else {
        OFFSET_MAGNITUDE_MM
    }
}

/// Realistic size of an offset deviation (mm).
pub const OFFSET_MAGNITUDE_MM: Real = 0.5;
/// Realistic size of an angular deviation (rad).
pub const ANGLE_MAGNITUDE_RAD: Real = 5e-4;
/// A direction of parameter space is determined when its standard uncertainty is below
/// this fraction of its realistic magnitude: it is then known to a tenth of what it could
/// plausibly be.
pub const DETERMINED_FRACTION: Real = 0.1;
/// A direction whose singular value lies within this factor of the threshold of
/// determination (either side) is *borderline*: its uncertainty is judged from the scan's
/// own residuals (σ, and its inflation for correlated noise by block averaging), which
/// another scan of the same part estimates differently — by about ±5 % on the designed
/// scenes, so a factor 1.25 is a few of those spreads — and another scan may decide it the
/// other way. Both `design` and `identify` name borderline directions.
pub const BORDERLINE_FACTOR: Real = 1.25;
/// A parameter counts as identified on its own when the part of its unit direction (in
/// scaled units) outside the determined subspace is below this: then the undetermined
/// directions, held at their prior, move its value by at most this fraction of their
/// realistic size.
pub const LEAKAGE: Real = 2e-3;
/// Coefficients of a named combination below this (relative to the largest, in scaled
/// units) are dropped from its name and value: they are second-order couplings.
pub const COMBINATION_CUTOFF: Real = 1e-2;

/// A linear combination of deviations, named like `gamma_AY + gamma_YX`.
#[derive(Clone, Debug, PartialEq)]
pub struct Combination {
    /// Readable name.
    pub name: String,
    /// Coefficients in physical units, one per solved parameter (the leading one is 1); the
    /// name omits terms below [`COMBINATION_CUTOFF`], the coefficients keep them.
    pub coefficients: Vec<Real>,
}

/// What the features determine.
#[derive(Clone, Debug, PartialEq)]
pub struct Identifiability {
    /// Parameter names, in solve order.
    pub parameters: Vec<String>,
    /// Singular values of the scaled, registration-free whitened Jacobian (descending).
    pub singular_values: Vec<Real>,
    /// Largest over smallest singular value (infinite if one is zero).
    pub condition_number: Real,
    /// Condition number within the determined subspace.
    pub condition_number_determined: Real,
    /// Dimension of the determined subspace.
    pub rank: usize,
    /// Parameters identified on their own.
    pub identified: Vec<String>,
    /// Determined combinations that are not single parameters.
    pub determined_combinations: Vec<Combination>,
    /// Directions not determined (named), held at their prior values.
    pub undetermined_combinations: Vec<Combination>,
    /// Directions whose singular value is within [`BORDERLINE_FACTOR`] of the threshold
    /// (named, with their singular values): determined or not, another scan may decide
    /// them the other way.
    pub borderline: Vec<(Combination, Real)>,
    /// Parameters not identified on their own (they may still enter a determined
    /// combination).
    pub not_identified: Vec<String>,
    /// What the registration absorbs: for each registration component, the deviations'
    /// combination it mimics (empty names when it absorbs nothing of them).
    pub registration_absorbs: Vec<String>,
    /// Parameters no feature depends on at all (no data): not identified.
    pub no_data: Vec<String>,
    /// Orthonormal basis (scaled units) of the determined subspace, columns.
    pub determined_basis: DMatrix<Real>,
    /// Per parameter, the leakage of its direction outside the determined subspace.
    pub leakage: Vec<Real>,
    /// How clearly the determined subspace is separated: the singular values either side
    /// of the threshold of determination.
    pub margin: RankMargin,
}

/// Projects the columns of `a` onto the orthogonal complement of the column space of `b`.
fn project_out(a: &DMatrix<Real>, b: &DMatrix<Real>) -> DMatrix<Real> {
    if b.ncols() == 0 {
        return a.clone();
    }
    let svd = b.clone().svd(true, false);
    let u = svd.u.expect("requested");
    let smax = svd.singular_values.max();
    let mut out = a.clone();
    for (k, s) in svd.singular_values.iter().enumerate() {
        if *s > smax * RANK_EPS {
            let uk = u.column(k);
            let proj = uk.transpose() * &out;
            out -= uk * proj;
        }
    }
    out
}

/// Relative singular value below which a matrix's direction is numerically null: a few
/// hundred ulps of the largest.
const RANK_EPS: Real = 1e-12;

fn combo_name(names: &[String], c: &[Real]) -> String {
    let mut s = String::new();
    for (name, &k) in names.iter().zip(c) {
        if k == 0.0 {
            continue;
        }
        let sign = if k < 0.0 { "−" } else { "+" };
        let mag = k.abs();
        let coef = if (mag - 1.0).abs() < 1e-3 {
            String::new()
        } else {
            format!("{mag:.4}·")
        };
        if s.is_empty() {
            if k < 0.0 {
                s.push('−');
            }
            s.push_str(&format!("{coef}{name}"));
        } else {
            s.push_str(&format!(" {sign} {coef}{name}"));
        }
    }
    s
}

/// Named combinations spanning the row space of `rows` (scaled units, each row a
/// direction): reduced row echelon with the largest pivot, small coefficients dropped,
/// converted to physical units with the first coefficient 1.
fn named_combinations(rows: &DMatrix<Real>, scale: &[Real], names: &[String]) -> Vec<Combination> {
    let mut m = rows.clone();
    let (nr, nc) = m.shape();
    let mut out = Vec::new();
    let mut used = vec![false; nc];
    for r in 0..nr {
        // Pivot: largest entry in an unused column of this or a later row.
        let mut best = (0.0, r, 0);
        for i in r..nr {
            for j in 0..nc {
                if !used[j] && m[(i, j)].abs() > best.0 {
                    best = (m[(i, j)].abs(), i, j);
                }
            }
        }
        if best.0 < RANK_EPS {
            break;
        }
        let (_, pi, pj) = best;
        m.swap_rows(r, pi);
        used[pj] = true;
        let piv = m[(r, pj)];
        for j in 0..nc {
            m[(r, j)] /= piv;
        }
        for i in 0..nr {
            if i != r {
                let f = m[(i, pj)];
                if f != 0.0 {
                    for j in 0..nc {
                        let v = m[(r, j)];
                        m[(i, j)] -= f * v;
                    }
                }
            }
        }
    }
    for r in 0..nr {
        let row: Vec<Real> = (0..nc).map(|j| m[(r, j)]).collect();
        let big = row.iter().fold(0.0, |a: Real, b| a.max(b.abs()));
        if big < RANK_EPS {
            continue;
        }
        // Scaled coefficient a_j on q_j = p_j / s_j → a_j / s_j on p_j. The name drops
        // the small terms; the coefficients keep them (values must not depend on the
        // undetermined directions).
        // A coefficient below the numerical rank's resolution is the elimination's
        // rounding, not a coupling: exactly 0 (so a parameter the combination does not
        // contain does not enter its value, or its injected value, at 1e-19).
        let mut c: Vec<Real> = row
            .iter()
            .zip(scale)
            .map(|(a, s)| if a.abs() < RANK_EPS * big { 0.0 } else { a / s })
            .collect();
        let lead_at = row
            .iter()
            .position(|a| a.abs() >= COMBINATION_CUTOFF * big)
            .unwrap_or(0);
        let lead = c[lead_at];
        for v in &mut c {
            *v /= lead;
        }
        let shown: Vec<Real> = row
            .iter()
            .zip(&c)
            .map(|(a, v)| {
                if a.abs() < COMBINATION_CUTOFF * big {
                    0.0
                } else {
                    *v
                }
            })
            .collect();
        out.push(Combination {
            name: combo_name(names, &shown),
            coefficients: c,
        });
    }
    out
}

/// Decides what the features determine, at the deviation values `x` (see the module
/// documentation).
pub fn identifiability(
    model: &Model,
    x: &DVector<Real>,
) -> Result<Identifiability, CalibrateError> {
    let j = model.jacobian(x).ok_or_else(|| {
        CalibrateError::Degenerate(
            model
                .features
                .first()
                .map_or(String::new(), |f| f.name().to_string()),
        )
    })?;
    Ok(identifiability_of(
        &j,
        &model.param_names(),
        &model.param_scales(),
        &model.nuisance_names(),
    ))
}

/// What a whitened Jacobian `j` determines: its first `names.len()` columns are the
/// parameters (physical units, realistic magnitudes `scale`), the rest nuisance unknowns
/// (`nuisance_names`), projected out before the parameters' SVD (see the module
/// documentation). Every identification's report of what is and is not determined.
pub fn identifiability_of(
    j: &DMatrix<Real>,
    names: &[String],
    scale: &[Real],
    nuisance_names: &[String],
) -> Identifiability {
    let names = names.to_vec();
    let np = names.len();
    let mut jp = j.columns(0, np).into_owned();
    for (k, s) in scale.iter().enumerate() {
        jp.column_mut(k).scale_mut(*s);
    }
    let jr = j.columns(np, j.ncols() - np).into_owned();
    let jf = project_out(&jp, &jr);
    let svd = jf.clone().svd(false, true);
    let vt = svd.v_t.expect("requested");
    let mut order: Vec<usize> = (0..svd.singular_values.len()).collect();
    order.sort_by(|a, b| svd.singular_values[*b].total_cmp(&svd.singular_values[*a]));
    let sv: Vec<Real> = order.iter().map(|&i| svd.singular_values[i]).collect();
    let mut full_sv = sv.clone();
    full_sv.resize(np, 0.0);
    let threshold = 1.0 / DETERMINED_FRACTION;
    let det: Vec<usize> = order
        .iter()
        .copied()
        .filter(|&i| svd.singular_values[i] >= threshold)
        .collect();
    let rank = det.len();
    let mut basis = DMatrix::zeros(np, rank);
    for (c, &i) in det.iter().enumerate() {
        basis.set_column(c, &vt.row(i).transpose());
    }
    let leakage: Vec<Real> = (0..np)
        .map(|k| {
            let proj = basis.row(k).norm_squared();
            (1.0 - proj).max(0.0).sqrt()
        })
        .collect();
    let identified_idx: Vec<usize> = (0..np).filter(|&k| leakage[k] < LEAKAGE).collect();
    // Determined combinations: the determined subspace with the identified axes removed.
    let mut reduced = basis.transpose();
    for &k in &identified_idx {
        reduced.column_mut(k).fill(0.0);
    }
    let reduced = if reduced.nrows() > 0 {
        let s = reduced.clone().svd(false, true);
        let vt = s.v_t.expect("requested");
        let big = s.singular_values.max();
        let keep: Vec<usize> = (0..s.singular_values.len())
            .filter(|&i| s.singular_values[i] > 0.5 * big.max(1.0))
            .collect();
        DMatrix::from_fn(keep.len(), np, |r, c| vt[(keep[r], c)])
    } else {
        DMatrix::zeros(0, np)
    };
    let determined_combinations = named_combinations(&reduced, scale, &names);
    // Undetermined: the complement of the determined subspace.
    let complement = {
        let mut eye = DMatrix::<Real>::identity(np, np);
        if rank > 0 {
            eye -= &basis * basis.transpose();
        }
        let s = eye.svd(false, true);
        let vt = s.v_t.expect("requested");
        let keep: Vec<usize> = (0..s.singular_values.len())
            .filter(|&i| s.singular_values[i] > 0.5)
            .collect();
        DMatrix::from_fn(keep.len(), np, |r, c| vt[(keep[r], c)])
    };
    let undetermined_combinations = named_combinations(&complement, scale, &names);
    let borderline = order
        .iter()
        .filter(|&&i| {
            let s = svd.singular_values[i];
            s >= threshold / BORDERLINE_FACTOR && s < threshold * BORDERLINE_FACTOR
        })
        .filter_map(|&i| {
            let row = DMatrix::from_fn(1, np, |_, c| vt[(i, c)]);
            named_combinations(&row, scale, &names)
                .pop()
                .map(|c| (c, svd.singular_values[i]))
        })
        .collect();
    // What the registration absorbs: the deviation combination each registration column
    // reproduces best (least squares), if it does so well.
    let mut registration_absorbs = Vec::new();
    if jr.ncols() > 0 {
        let reg_names = nuisance_names;
        let pinv = jp.clone().pseudo_inverse(RANK_EPS).ok();
        for (k, reg_name) in reg_names.iter().enumerate().take(jr.ncols()) {
            let col = jr.column(k).into_owned();
            let norm = col.norm();
            let text = match &pinv {
                Some(pi) if norm > 0.0 => {
                    let coef = pi * &col;
                    let fit = &jp * &coef;
                    let resid = (&col - fit).norm() / norm;
                    if resid < 0.1 {
                        let c: Vec<Real> = coef
                            .iter()
                            .zip(scale)
                            .map(|(a, s)| {
                                if a.abs() < COMBINATION_CUTOFF * coef.amax() {
                                    0.0
                                } else {
                                    a / s
                                }
                            })
                            .collect();
                        format!("{}: mimics {}", reg_name, combo_name(&names, &c))
                    } else {
                        format!("{}: absorbs no deviation", reg_name)
                    }
                }
                _ => format!("{}: not constrained by the features", reg_name),
            };
            registration_absorbs.push(text);
        }
    }
    let positive: Vec<Real> = sv.iter().copied().filter(|s| *s > 0.0).collect();
    let cond = |v: &[Real]| match (v.first(), v.last()) {
        (Some(a), Some(b)) if *b > 0.0 => a / b,
        _ => Real::INFINITY,
    };
    let condition_number = if positive.len() < np {
        Real::INFINITY
    } else {
        cond(&full_sv)
    };
    Identifiability {
        parameters: names.clone(),
        margin: RankMargin::new(&full_sv, rank, threshold),
        singular_values: full_sv,
        condition_number,
        condition_number_determined: cond(&sv[..rank]),
        rank,
        identified: identified_idx.iter().map(|&k| names[k].clone()).collect(),
        determined_combinations,
        undetermined_combinations,
        borderline,
        not_identified: (0..np)
            .filter(|k| !identified_idx.contains(k))
            .map(|k| names[k].clone())
            .collect(),
        registration_absorbs,
        no_data: (0..np)
            .filter(|&k| j.column(k).amax() * scale[k] < NO_DATA_SENSITIVITY)
            .map(|k| names[k].clone())
            .collect(),
        determined_basis: basis,
        leakage,
    }
}

/// One identified quantity: a parameter or a determined combination.
#[derive(Clone, Debug, PartialEq)]
pub struct Estimate {
    /// Name (`dy_AY`, `gamma_AY + gamma_YX`).
    pub name: String,
    /// Value (mm or rad; for combinations in the units of their first parameter).
    pub value: Real,
    /// Standard uncertainty propagated from the features' uncertainties.
    pub sigma: Real,
    /// Coefficients over the solved parameters (a unit vector for a single parameter).
    pub coefficients: Vec<Real>,
}

/// The solver's account.
#[derive(Clone, Debug, PartialEq)]
pub struct SolveReport {
    /// Residual evaluations.
    pub evaluations: usize,
    /// Why it stopped.
    pub termination: String,
    /// Weighted sum of squared residuals before and after.
    pub chi2_start: Real,
    /// After.
    pub chi2: Real,
    /// Degrees of freedom (residuals − unknowns solved).
    pub dof: usize,
}

/// The outcome of [`identify`].
#[derive(Clone, Debug, PartialEq)]
pub struct Identification {
    /// What the features determine.
    pub identifiability: Identifiability,
    /// Parameters identified on their own.
    pub parameters: Vec<Estimate>,
    /// Determined combinations.
    pub combinations: Vec<Estimate>,
    /// The full solved deviation vector (undetermined directions at their prior): for
    /// updating a twin, not for reporting individual values.
    pub solution: Vec<Real>,
    /// The estimated registration (dx, dy, dz mm, alpha, beta, gamma rad), zero when the
    /// workpiece frame is trusted.
    pub registration: [Real; 6],
    /// The fixed points of the ball features (workpiece frame, mm) with their standard
    /// uncertainties per coordinate.
    pub anchors: Vec<(Point3, [Real; 3])>,
    /// Solver account.
    pub solver: SolveReport,
    /// Per feature: whitened residuals after the solve.
    pub residuals: Vec<(String, [Real; 3])>,
    /// Whether the features can come from the model at their stated uncertainties
    /// ([`feature_fit`] without a scanner's account; a command measuring a scan checks
    /// again with it). Callers refuse a misfit with [`FitCheck::enforce`].
    pub fit: FitCheck,
}

struct Subspace<'a> {
    model: &'a Model<'a>,
    x0: DVector<Real>,
    /// Columns: parameter-space directions (physical units) for each solved coordinate.
    dirs: DMatrix<Real>,
    z: DVector<Real>,
}

impl Subspace<'_> {
    fn full(&self, z: &DVector<Real>) -> DVector<Real> {
        &self.x0 + &self.dirs * z
    }
}

impl LeastSquaresProblem<Real, Dyn, Dyn> for Subspace<'_> {
    type ResidualStorage = Owned<Real, Dyn>;
    type JacobianStorage = Owned<Real, Dyn, Dyn>;
    type ParameterStorage = Owned<Real, Dyn>;
    fn set_params(&mut self, z: &DVector<Real>) {
        self.z.copy_from(z);
    }
    fn params(&self) -> DVector<Real> {
        self.z.clone()
    }
    fn residuals(&self) -> Option<DVector<Real>> {
        self.model.residuals(&self.full(&self.z))
    }
    fn jacobian(&self) -> Option<DMatrix<Real>> {
        Some(self.model.jacobian(&self.full(&self.z))? * &self.dirs)
    }
}

/// Identifies the deviations `model.ids` from `model.features`, starting at the chain's
/// current values: decides what is determined, solves by Levenberg–Marquardt in the
/// determined subspace (with the registration if estimated), and propagates the features'
/// uncertainties. Never gives a value to what is not determined. Its goodness of fit
/// ([`Identification::fit`]) takes the features' uncertainties as stated.
pub fn identify(model: &Model) -> Result<Identification, CalibrateError> {
    identify_with(model, None)
}

/// [`identify`], the goodness of fit accounting for the views `scan` merged its cloud
/// from ([`feature_fit`]).
pub fn identify_with(
    model: &Model,
    scan: Option<&ScanNoise>,
) -> Result<Identification, CalibrateError> {
    if model.params() == 0 {
        return Err(CalibrateError::NoParameters);
    }
    if model.features.is_empty() {
        return Err(CalibrateError::NoFeatures);
    }
    let x0 = model.start();
    for f in model.features {
        if model.residuals(&x0).is_none() {
            return Err(CalibrateError::Degenerate(f.name().to_string()));
        }
    }
    let ident = identifiability(model, &x0)?;
    let np = model.params();
    let scale = model.param_scales();
    if ident.no_data.len() == np {
        return Err(CalibrateError::NoData(ident.no_data.join(", ")));
    }
    // Registration directions the features constrain (the others, e.g. a slide along a
    // lone plane, stay zero).
    let reg_dirs: Vec<DVector<Real>> = {
        let j = model
            .jacobian(&x0)
            .ok_or_else(|| CalibrateError::Degenerate(String::new()))?;
        let jr = j.columns(np, model.cols() - np).into_owned();
        if jr.ncols() == 0 {
            Vec::new()
        } else {
            let svd = jr.svd(false, true);
            let vt = svd.v_t.expect("requested");
            let smax = svd.singular_values.max();
            (0..svd.singular_values.len())
                .filter(|&i| svd.singular_values[i] > smax * REGISTRATION_RANK_EPS)
                .map(|i| vt.row(i).transpose())
                .collect()
        }
    };
    let nreg = reg_dirs.len();
    let rank = ident.rank;
    let mut dirs = DMatrix::zeros(model.cols(), rank + nreg);
    for c in 0..rank {
        for k in 0..np {
            dirs[(k, c)] = ident.determined_basis[(k, c)] * scale[k];
        }
    }
    for (c, d) in reg_dirs.iter().enumerate() {
        for k in 0..d.len() {
            dirs[(np + k, rank + c)] = d[k];
        }
    }
    let chi2_start = model.residuals(&x0).map_or(Real::NAN, |r| r.norm_squared());
    let problem = Subspace {
        model,
        x0: x0.clone(),
        dirs: dirs.clone(),
        z: DVector::zeros(rank + nreg),
    };
    let (solved, rep) = LevenbergMarquardt::new()
        .with_patience(200)
        .minimize(problem);
    if !rep.termination.was_successful() {
        return Err(CalibrateError::NotConverged(format!(
            "{:?}",
            rep.termination
        )));
    }
    let x = solved.full(&solved.z);
    let r = model.residuals(&x).ok_or_else(|| {
        CalibrateError::NotConverged("residuals undefined at the solution".into())
    })?;
    let j_full = model
        .jacobian(&x)
        .ok_or_else(|| CalibrateError::NotConverged("Jacobian undefined at the solution".into()))?;
    let fit = fit_of(model, &r, &j_full, scan);
    let jz = &j_full * &dirs;
    let info = jz.transpose() * &jz;
    let cov_z = info
        .clone()
        .try_inverse()
        .or_else(|| info.pseudo_inverse(RANK_EPS).ok())
        .ok_or_else(|| CalibrateError::NotConverged("singular normal equations".into()))?;
    let cov_x = &dirs * cov_z * dirs.transpose();
    let (parameters, combinations) = estimates_of(
        &ident,
        &x.as_slice()[..np],
        &cov_x.view((0, 0), (np, np)).into_owned(),
        &scale,
    );
    let mut registration = [0.0; 6];
    for (c, r) in registration.iter_mut().enumerate().take(model.reg_cols()) {
        *r = x[np + c];
    }
    let base = np + model.reg_cols();
    let anchors = (0..model.anchor_count())
        .map(|a| {
            let k = base + 3 * a;
            let cov = |i: usize| cov_x[(k + i, k + i)].max(0.0).sqrt();
            (
                Point3::new(x[k], x[k + 1], x[k + 2]),
                [cov(0), cov(1), cov(2)],
            )
        })
        .collect();
    let mut residuals = Vec::new();
    let mut i = 0;
    for f in model.features {
        let n = f.residual_count();
        residuals.push((f.name().to_string(), [r[i], r[i + 1], r[i + 2]]));
        i += n;
    }
    let dof = model.rows().saturating_sub(rank + nreg);
    Ok(Identification {
        identifiability: ident,
        parameters,
        combinations,
        solution: x.rows(0, np).iter().copied().collect(),
        registration,
        anchors,
        solver: SolveReport {
            evaluations: rep.number_of_evaluations,
            termination: format!("{:?}", rep.termination),
            chi2_start,
            chi2: r.norm_squared(),
            dof,
        },
        residuals,
        fit,
    })
}

/// The values with σ of what an identification determines, at the solution `x` (the
/// parameters, physical units) with the parameters' covariance `cov` and realistic
/// magnitudes `scale`: each parameter identified on its own, valued as the determined
/// combination nearest to it (its projection on the determined subspace, whose other
/// coefficients are below [`LEAKAGE`] in scaled units, so its value does not depend on the
/// undetermined directions), then each determined combination.
pub fn estimates_of(
    ident: &Identifiability,
    x: &[Real],
    cov: &DMatrix<Real>,
    scale: &[Real],
) -> (Vec<Estimate>, Vec<Estimate>) {
    let np = x.len();
    let xp = DVector::from_column_slice(x);
    let estimate = |name: String, c: Vec<Real>| {
        let cv = DVector::from_iterator(np, c.iter().copied());
        let value = cv.dot(&xp);
        let var = (cv.transpose() * cov * &cv)[0];
        Estimate {
            name,
            value,
            sigma: var.max(0.0).sqrt(),
            coefficients: c,
        }
    };
    let basis = &ident.determined_basis;
    let parameters = ident
        .identified
        .iter()
        .map(|name| {
            let k = ident.parameters.iter().position(|n| n == name).unwrap_or(0);
            let a = basis * basis.row(k).transpose();
            let c = (0..np)
                .map(|j| {
                    // A coupling below the numerical rank's resolution is the projection's
                    // rounding, not a coupling: exactly 0 (a parameter nothing couples to is
                    // valued, and compared with the truth, on its own).
                    let r = a[j] / a[k];
                    if j != k && r.abs() < RANK_EPS {
                        0.0
                    } else {
                        scale[k] * r / scale[j]
                    }
                })
                .collect();
            estimate(name.clone(), c)
        })
        .collect();
    let combinations = ident
        .determined_combinations
        .iter()
        .map(|c| estimate(c.name.clone(), c.coefficients.clone()))
        .collect();
    (parameters, combinations)
}

/// What the features' residual χ² is of, in words.
fn feature_statistic(features: &[Feature]) -> &'static str {
    let planes = features.iter().any(|f| matches!(f, Feature::Plane(_)));
    let balls = features.iter().any(|f| matches!(f, Feature::Ball(_)));
    match (planes, balls) {
        (true, false) => "faces' offsets and slopes at their fits' σ",
        (false, true) => "ball centres at their stated σ",
        _ => "faces' offsets and slopes at their fits' σ and ball centres at their stated σ",
    }
}

/// The goodness of fit of the features at the unknowns `x` (deviations, ISO terms,
/// registration, fixed points): their whitened residuals after the best fit over every
/// unknown (see [`crate::calibration::goodness`]), one part per feature. Faces' and balls'
/// uncertainties are taken as stated, with two additions: the twin's own accuracy
/// ([`MODEL_ACCURACY_MM`] per face point for faces, [`tol::LENGTH_EPS`] for balls, whose
/// prediction is the chain alone), and — with `scan` a cloud merged from several views with
/// a registration error — each view's offset and tilt, added to every face's offset and
/// slope variance (as if each face were seen by its own view: the faces of one view share
/// that view's error, which the registration takes up in part, so this errs towards
/// accepting). `None` if the model cannot be evaluated at `x`.
pub fn feature_fit(model: &Model, x: &DVector<Real>, scan: Option<&ScanNoise>) -> Option<FitCheck> {
    let r = model.residuals(x)?;
    let j = model.jacobian(x)?;
    Some(fit_of(model, &r, &j, scan))
}

fn fit_of(
    model: &Model,
    r: &DVector<Real>,
    j: &DMatrix<Real>,
    scan: Option<&ScanNoise>,
) -> FitCheck {
    let (mut r, mut j) = (r.clone(), j.clone());
    let mut parts = Vec::with_capacity(model.features.len());
    let mut row = 0;
    for f in model.features {
        let n = f.residual_count();
        let t = match f {
            Feature::Plane(p) => plane_rewhitening(p, scan),
            Feature::Ball(b) => {
                let s = |k: usize| b.sigma_mm[k] / b.sigma_mm[k].hypot(tol::LENGTH_EPS);
                nalgebra::Matrix3::from_diagonal(&Vector3::new(s(0), s(1), s(2)))
            }
        };
        let rows = r.rows(row, 3).into_owned();
        r.rows_mut(row, 3).copy_from(&(t * rows));
        let jr = j.rows(row, 3).into_owned();
        j.rows_mut(row, 3).copy_from(&(t * jr));
        parts.push((f.name().to_string(), row..row + n));
        row += n;
    }
    least_squares_check(feature_statistic(model.features), &r, &j, &parts)
}

/// Each scanned face's points against the scanner's noise ([`face_rms_check`]): one part
/// per plane feature fitted in a scan (synthetic features, with no points, have none).
pub fn face_rms_parts(features: &[Feature], scan: &ScanNoise) -> Vec<PartFit> {
    let faces: Vec<&PlaneFeature> = features
        .iter()
        .filter_map(|f| match f {
            Feature::Plane(p) if p.points > 0 => Some(p),
            _ => None,
        })
        .collect();
    let p_limit = REFUSE_P / faces.len().max(1) as Real;
    faces
        .iter()
        .map(|p| {
            face_rms_check(
                &p.name,
                p.rms_mm,
                p.points,
                p.correlation_inflation,
                scan,
                p_limit,
            )
        })
        .collect()
}

/// The map from a plane feature's whitened residuals (offset, two slopes) to the same
/// residuals whitened by the uncertainties the goodness of fit uses: per-point σ with the
/// twin's accuracy added, and the views' misregistration (see [`feature_fit`]).
fn plane_rewhitening(p: &PlaneFeature, scan: Option<&ScanNoise>) -> nalgebra::Matrix3<Real> {
    // The fit's σ per point, and the offset and slope covariances it implies.
    let acc2 = MODEL_ACCURACY_MM * MODEL_ACCURACY_MM;
    let (off_var, floor) = if p.points > 0 {
        let sp2 = p.offset_sigma_mm.powi(2) * p.points as Real;
        // Every uncertainty of a scanned face scales with its per-point σ.
        (p.offset_sigma_mm.powi(2), (sp2 / (sp2 + acc2)).sqrt())
    } else {
        (p.offset_sigma_mm.powi(2), 1.0)
    };
    let mut off_new = if p.points > 0 {
        off_var / (floor * floor)
    } else {
        off_var + acc2
    };
    let w = p.slope_whitening * floor;
    let Some(w_inv) = p.slope_whitening.try_inverse() else {
        return nalgebra::Matrix3::identity();
    };
    // Slope covariance the goodness of fit uses: (WᵀW)⁻¹/floor², plus the views' tilt.
    let mut cov = (w.transpose() * w)
        .try_inverse()
        .unwrap_or_else(Matrix2::zeros);
    if let Some(s) = scan.filter(|s| s.views >= 2) {
        off_new += s.translation_sigma_mm.powi(2) + (s.rotation_sigma_rad * s.lever_mm).powi(2);
        cov += Matrix2::identity() * s.rotation_sigma_rad.powi(2);
    }
    // New whitening: W' with W'ᵀW' = cov⁻¹ (upper Cholesky factor of the inverse).
    let w_new = cov
        .try_inverse()
        .and_then(|i| i.cholesky())
        .map(|c| c.l().transpose())
        .unwrap_or(w);
    let t = w_new * w_inv;
    let mut m = nalgebra::Matrix3::zeros();
    m[(0, 0)] = (off_var / off_new).sqrt();
    for a in 0..2 {
        for b in 0..2 {
            m[(1 + a, 1 + b)] = t[(a, b)];
        }
    }
    m
}

/// Relative singular value below which a registration direction counts as unconstrained
/// by the features (a plane does not see a slide along itself or a turn about its normal).
const REGISTRATION_RANK_EPS: Real = 1e-9;

/// A parameter whose realistic magnitude moves no whitened residual by more than this has
/// no data at all (a thousandth of a standard uncertainty).
const NO_DATA_SENSITIVITY: Real = 1e-3;

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
    f.plane = plane;
    Some(f)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nc::{AxisLetter, MoveKind};

    fn mdx50() -> Chain {
        crate::machine::chain::mdx50_for_tests()
    }

    fn cut(line: usize, a: Real, y: Real, z: Real) -> Move {
        let q = |x| {
            AxisValues::default()
                .with(AxisLetter::X, x)
                .with(AxisLetter::Y, y)
                .with(AxisLetter::Z, z)
                .with(AxisLetter::A, a)
        };
        Move {
            kind: MoveKind::Linear,
            start: q(-30.0),
            end: q(30.0),
            feed_mm_per_min: Some(600.0),
            line,
        }
    }

    fn tool() -> Tool {
        Tool::try_new(ToolKind::Flat, 6.0, 25.0).expect("valid")
    }

    fn stock() -> Aabb {
        Aabb {
            min: Point3::new(-20.0, -24.0, -10.0),
            max: Point3::new(20.0, 8.0, 10.0),
        }
    }

    fn spec(name: &str, kind: FaceKind) -> FaceSpec {
        FaceSpec {
            name: name.into(),
            line: 0,
            region: crate::calibration::identify::FaceRegion::Auto,
            kind,
        }
    }

    const NINE: [&str; 9] = [
        "dy_AY", "dz_AY", "beta_AY", "gamma_AY", "alpha_YX", "gamma_YX", "beta_XZ", "alpha_ZS",
        "beta_ZS",
    ];

    fn ids(c: &Chain, names: &[&str]) -> Vec<DeviationId> {
        names
            .iter()
            .map(|n| c.deviation_id(n).expect("known"))
            .collect()
    }

    fn step_features(truth: &Chain) -> Vec<Feature> {
        let model = truth.nominal();
        [
            ("A0", cut(1, 0.0, -25.0, 0.0)),
            ("A180", cut(2, 180.0, 25.0, 0.0)),
        ]
        .iter()
        .map(|(n, c)| {
            Feature::Plane(
                synthetic_plane_feature(
                    &spec(n, FaceKind::Flank),
                    c,
                    truth,
                    &model,
                    &tool(),
                    &stock(),
                    0.5e-3,
                    [2e-5, 2e-4],
                    (0.0, 0.0),
                )
                .expect("a face"),
            )
        })
        .collect()
    }

    #[test]
    fn tilted_floor_is_the_least_squares_line_of_the_elliptic_envelope() {
        // A spindle tilted along the feed leaves a floor of depth |t|·√(R² − x₂²) below the
        // tip line. Over an off-centre cross range the predicted plane must be that
        // surface's least-squares line, placed where the points are (not at the tip line).
        let mut truth = mdx50();
        truth.set_deviation(truth.deviation_id("beta_ZS").expect("known"), 0.05);
        let mv = cut(3, 0.0, -10.0, 8.0);
        let tool = tool();
        let range = (-0.5, 2.8);
        let f = synthetic_plane_feature(
            &spec("floor", FaceKind::Floor),
            &mv,
            &truth,
            &truth,
            &tool,
            &stock(),
            1e-3,
            [1e-4, 1e-4],
            range,
        )
        .expect("a floor");
        let plane = predicted_plane(&truth, &tool, &f).expect("defined");
        // The envelope's frame, from the poses (independent of the prediction code).
        let (p0, p1) = (truth.w_from_t(&mv.start), truth.w_from_t(&mv.end));
        let tip = p0 * Point3::origin();
        let u = (p1 * Point3::origin() - tip).normalize();
        let v = p0.rotation * Vector3::z();
        let t = u.dot(&v);
        assert!(
            t.abs() > 0.04,
            "the test needs a real tilt along the feed, t = {t}"
        );
        let e2 = v.cross(&u).normalize();
        let m = (u * t - v).normalize();
        // Discrete least squares of h(x) = |t|·√(R² − x²) over uniform x in the range.
        let n = 100_001;
        let r = tool.radius();
        let xs: Vec<Real> = (0..n)
            .map(|i| range.0 + (range.1 - range.0) * i as Real / (n - 1) as Real)
            .collect();
        let hs: Vec<Real> = xs
            .iter()
            .map(|x| t.abs() * (r * r - x * x).sqrt())
            .collect();
        let mx = xs.iter().sum::<Real>() / n as Real;
        let mh = hs.iter().sum::<Real>() / n as Real;
        let sxy: Real = xs.iter().zip(&hs).map(|(x, h)| (x - mx) * (h - mh)).sum();
        let sxx: Real = xs.iter().map(|x| (x - mx).powi(2)).sum();
        let slope = sxy / sxx;
        for x in [range.0, mx, range.1] {
            let want = mh + slope * (x - mx);
            // The predicted plane's depth along m at cross-feed x.
            let n_ = plane.normal.into_inner();
            let got = (plane.offset - n_.dot(&(tip.coords + e2 * x))) / n_.dot(&m);
            assert!(
                (got.abs() - want).abs() < 1e-6,
                "x₂ = {x}: predicted depth {got}, least squares {want}"
            );
        }
    }

    #[test]
    fn jacobian_matches_finite_differences() {
        let mut truth = mdx50();
        for (n, v) in NINE
            .iter()
            .zip([-0.3, 0.2, 1e-4, -2e-4, 3e-4, 1e-4, -1e-4, 2e-4, -3e-4])
        {
            truth.set_deviation(truth.deviation_id(n).expect("known"), v);
        }
        let mut feats = step_features(&truth);
        // A floor with its axis tilted along the feed (beta sum ≠ 0): the envelope term.
        feats.push(Feature::Plane(
            synthetic_plane_feature(
                &spec("floor", FaceKind::Floor),
                &cut(3, 0.0, -10.0, 8.0),
                &truth,
                &truth.nominal(),
                &tool(),
                &stock(),
                0.5e-3,
                [2e-5, 2e-4],
                (-2.0, 1.0),
            )
            .expect("a floor"),
        ));
        let id = ids(&truth, &NINE);
        let chain = truth.nominal();
        let model = Model {
            chain: &chain,
            ids: &id,
            iso_terms: &[],
            tool: &tool(),
            features: &feats,
            registration: Registration::Estimate,
        };
        let mut x = model.start();
        for k in 0..x.len() {
            x[k] = if k < 9 {
                0.7 * truth.deviation(id[k])
            } else {
                1e-4 * (k as Real - 11.0)
            };
        }
        let j = model.jacobian(&x).expect("defined");
        for k in 0..x.len() {
            // Steps: 1e-6 of the realistic size, far above rounding of residuals ~1e3.
            let h = if k < 9 { magnitude(id[k]) * 1e-4 } else { 1e-6 };
            let (mut a, mut b) = (x.clone(), x.clone());
            a[k] += h;
            b[k] -= h;
            let fd =
                (model.residuals(&a).expect("a") - model.residuals(&b).expect("b")) / (2.0 * h);
            let err = (&fd - j.column(k)).amax();
            let scale = fd.amax().max(1.0);
            assert!(
                err <= 1e-5 * scale,
                "column {k}: AD vs FD differ by {err} (scale {scale})"
            );
        }
    }

    #[test]
    fn the_0_180_cut_determines_dy_and_the_gamma_sum_only() {
        let mut truth = mdx50();
        let vals = [-0.5, 0.1, 2e-4, 1e-4, -2e-4, 3e-4, 1e-4, -1e-4, 2e-4];
        for (n, v) in NINE.iter().zip(vals) {
            truth.set_deviation(truth.deviation_id(n).expect("known"), v);
        }
        let feats = step_features(&truth);
        let id = ids(&truth, &NINE);
        let chain = truth.nominal();
        let model = Model {
            chain: &chain,
            ids: &id,
            iso_terms: &[],
            tool: &tool(),
            features: &feats,
            registration: Registration::Estimate,
        };
        let r = identify(&model).expect("identifies");
        assert_eq!(r.identifiability.identified, vec!["dy_AY".to_string()]);
        let names: Vec<&str> = r.combinations.iter().map(|c| c.name.as_str()).collect();
        assert_eq!(names, vec!["gamma_AY + gamma_YX"]);
        let dy = &r.parameters[0];
        // Second-order effects of the other deviations bias it by a fraction of a µm.
        assert!((dy.value + 0.5).abs() < 2e-3, "dy_AY = {}", dy.value);
        let g = &r.combinations[0];
        assert!((g.value - 4e-4).abs() < 2e-5, "gamma sum = {}", g.value);
        assert!(
            !r.identifiability
                .not_identified
                .contains(&"dy_AY".to_string())
        );
        assert_eq!(r.identifiability.not_identified.len(), 8);
        // Flanks never see the offset along the tool axis.
        assert!(r.identifiability.no_data.contains(&"dz_AY".to_string()));
    }

    #[test]
    fn parameters_nothing_depends_on_are_an_error() {
        let truth = mdx50();
        let feats = step_features(&truth);
        let id = ids(&truth, &["dx_ZS"]);
        let chain = truth.nominal();
        let model = Model {
            chain: &chain,
            ids: &id,
            iso_terms: &[],
            tool: &tool(),
            features: &feats,
            registration: Registration::Workpiece,
        };
        // dx moves the flank planes along themselves: no feature sees it.
        assert_eq!(
            identify(&model).map(|_| ()),
            Err(CalibrateError::NoData("dx_ZS".into()))
        );
    }
}
