//! Identification: Levenberg–Marquardt in the determined subspace, the estimates with
//! their uncertainties, and the fit check of the features' residuals.
//!
//! **Invariant:** gives values only to the parameters and combinations the features
//! determine; a solve that does not converge is an error.

use super::*;

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
pub(super) const NO_DATA_SENSITIVITY: Real = 1e-3;
