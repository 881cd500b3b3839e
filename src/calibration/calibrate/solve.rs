//! Identification on [`crate::calibration::engine`]: the model as its forward model, the
//! registration and fixed points as its nuisance unknowns, the estimates with their
//! uncertainties, and the fit check of the features' residuals.
//!
//! **Invariant:** gives values only to the parameters and combinations the features
//! determine; a solve that does not converge is an error.

use super::*;
use crate::calibration::engine::{self, Block, EngineError, Forward, Problem, Unknown};

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

/// A [`Model`] as the engine's forward model: its predictions are the features' whitened
/// residuals (observed as 0 at σ 1, one block per feature), its Jacobian the model's
/// closed form (forward-mode automatic differentiation).
pub struct FeatureForward<'m, 'a> {
    /// The model.
    pub model: &'m Model<'a>,
}

impl Forward for FeatureForward<'_, '_> {
    fn predict(&self, x: &[Real]) -> Result<Vec<Real>, String> {
        self.model
            .residuals(&DVector::from_column_slice(x))
            .map(|r| r.as_slice().to_vec())
            .ok_or_else(|| "a feature's prediction is degenerate at the solve's unknowns".into())
    }

    fn jacobian(&self, x: &[Real]) -> Option<Result<DMatrix<Real>, String>> {
        Some(
            self.model
                .jacobian(&DVector::from_column_slice(x))
                .ok_or_else(|| {
                    "a feature's prediction is degenerate at the solve's unknowns".into()
                }),
        )
    }
}

impl FeatureForward<'_, '_> {
    /// The engine's unknowns at the model's start ([`Model::start`]): the parameters with
    /// their realistic magnitudes ([`Model::param_scales`]), then the registration and the
    /// fixed points, offsets at [`OFFSET_MAGNITUDE_MM`], turns at [`ANGLE_MAGNITUDE_RAD`]
    /// (a scan's registration and a sphere's place are unknown by more than that, but the
    /// magnitudes only scale the nuisance columns before their rank is taken).
    pub fn unknowns(&self) -> (Vec<Unknown>, Vec<Unknown>) {
        let m = self.model;
        let x0 = m.start();
        let np = m.params();
        let parameters = m
            .param_names()
            .into_iter()
            .zip(m.param_scales())
            .enumerate()
            .map(|(k, (name, magnitude))| Unknown {
                name,
                start: x0[k],
                magnitude,
            })
            .collect();
        let nuisance = m
            .nuisance_names()
            .into_iter()
            .enumerate()
            .map(|(k, name)| Unknown {
                start: x0[np + k],
                magnitude: if k < m.reg_cols() && k >= 3 {
                    ANGLE_MAGNITUDE_RAD
                } else {
                    OFFSET_MAGNITUDE_MM
                },
                name,
            })
            .collect();
        (parameters, nuisance)
    }

    /// The observations: each feature's three whitened residuals, observed 0 at σ 1.
    pub fn blocks(&self) -> Vec<Block> {
        self.model
            .features
            .iter()
            .map(|f| Block {
                name: f.name().to_string(),
                values: vec![0.0; f.residual_count()],
                sigma: vec![1.0; f.residual_count()],
            })
            .collect()
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
/// from ([`feature_fit`]). The solve is [`crate::calibration::engine`]'s on
/// [`FeatureForward`]: the registration and the fixed points are its nuisance unknowns.
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
    if model.residuals(&x0).is_none() || model.jacobian(&x0).is_none() {
        let at = model
            .features
            .iter()
            .find(|f| {
                let one = Model {
                    features: std::slice::from_ref(*f),
                    ..model.clone()
                };
                one.residuals(&one.start()).is_none()
            })
            .or(model.features.first())
            .map_or(String::new(), |f| f.name().to_string());
        return Err(CalibrateError::Degenerate(at));
    }
    let forward = FeatureForward { model };
    let (parameters, nuisance) = forward.unknowns();
    let problem = Problem {
        parameters,
        nuisance,
        blocks: forward.blocks(),
        forward: &forward,
        statistic: feature_statistic(model.features).into(),
    };
    let o = engine::solve(&problem).map_err(|e| match e {
        EngineError::NoData(names) => CalibrateError::NoData(names),
        EngineError::NoParameters => CalibrateError::NoParameters,
        EngineError::NoObservations => CalibrateError::NoFeatures,
        other => CalibrateError::NotConverged(other.to_string()),
    })?;
    if !o.converged {
        return Err(CalibrateError::NotConverged(o.termination));
    }
    let np = model.params();
    let x = DVector::from_iterator(model.cols(), o.solution.iter().chain(&o.nuisance).copied());
    let r = model.residuals(&x).ok_or_else(|| {
        CalibrateError::NotConverged("residuals undefined at the solution".into())
    })?;
    let j_full = model
        .jacobian(&x)
        .ok_or_else(|| CalibrateError::NotConverged("Jacobian undefined at the solution".into()))?;
    let fit = fit_of(model, &r, &j_full, scan);
    let mut registration = [0.0; 6];
    for (c, r) in registration.iter_mut().enumerate().take(model.reg_cols()) {
        *r = x[np + c];
    }
    let base = model.reg_cols();
    let anchors = (0..model.anchor_count())
        .map(|a| {
            let k = base + 3 * a;
            let s = &o.nuisance_sigma;
            (
                Point3::new(x[np + k], x[np + k + 1], x[np + k + 2]),
                [s[k], s[k + 1], s[k + 2]],
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
    let dof = model
        .rows()
        .saturating_sub(o.identifiability.rank + o.nuisance_rank);
    Ok(Identification {
        identifiability: o.identifiability,
        parameters: o.parameters,
        combinations: o.combinations,
        solution: o.solution,
        registration,
        anchors,
        solver: SolveReport {
            evaluations: o.evaluations,
            termination: o.termination,
            chi2_start: o.chi2_history.first().copied().unwrap_or(Real::NAN),
            chi2: r.norm_squared(),
            dof,
        },
        residuals,
        fit,
    })
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
