//! What `twinmill identify` reports: the measured features, the identified values and
//! combinations with their uncertainties, what is not determined, the model-correction
//! loop's rounds and the Monte-Carlo spread.

use crate::calibration::goodness::{FitCheck, RankMargin};
use serde::Serialize;
use std::fmt::Write as _;

/// One measured feature in an identification report.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FeatureReport {
    /// Face name.
    pub name: String,
    /// `flank` or `floor`.
    pub kind: String,
    /// NC line of its cut.
    pub line: usize,
    /// Points used in the fit.
    pub points: usize,
    /// RMS residual of the fit (mm).
    pub rms_mm: f64,
    /// Measured unit normal (into the material), scan frame.
    pub normal: [f64; 3],
    /// Measured centroid (mm).
    pub centroid_mm: [f64; 3],
    /// Standard uncertainty of the offset at the centroid (mm).
    pub offset_sigma_mm: f64,
    /// Whitened residuals after the solve: offset, two slopes (in standard uncertainties).
    pub residuals: [f64; 3],
}

/// One identified quantity.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct EstimateReport {
    /// Parameter or combination name.
    pub name: String,
    /// Identified value (mm or rad).
    pub value: f64,
    /// Standard uncertainty from the features' residual-based uncertainties.
    pub sigma: f64,
    /// Sample standard deviation over the Monte-Carlo trials, if run.
    pub monte_carlo_spread: Option<f64>,
    /// The value the scene injected (simulated scans only).
    pub injected: Option<f64>,
    /// Coefficients over `parameters`.
    pub coefficients: Vec<f64>,
}

/// One round of the model-correction loop.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct LoopRound {
    /// Round number from 1.
    pub round: usize,
    /// Largest distance between a predicted and a measured face over the face's extent
    /// (centroid and corners, mm), after updating the twin in this round.
    pub worst_face_mm: f64,
    /// Weighted sum of squared residuals.
    pub chi2: f64,
}

/// What `twinmill identify` reports.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct IdentifyReport {
    /// Set when the features do not fit the model at their stated noise and the misfit
    /// was accepted on request: the report's first word.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub warning: Option<String>,
    /// Scene name.
    pub scene: String,
    /// The chain.
    pub chain: String,
    /// Where the cloud came from (the simulated scan or a file).
    pub cloud: String,
    /// Registration handling (`estimate` or `workpiece`).
    pub registration: String,
    /// Parameters asked for.
    pub parameters: Vec<String>,
    /// The features.
    pub features: Vec<FeatureReport>,
    /// Singular values of the scaled Jacobian (registration projected out).
    pub singular_values: Vec<f64>,
    /// How clearly the determined subspace was decided: the gap between the last
    /// determined and the first undetermined singular value.
    pub margin: RankMargin,
    /// Condition number (infinite: some direction not seen at all).
    pub condition_number: f64,
    /// Condition number within the determined subspace.
    pub condition_number_determined: f64,
    /// Parameters identified on their own.
    pub identified: Vec<EstimateReport>,
    /// Determined combinations.
    pub combinations: Vec<EstimateReport>,
    /// Directions not determined (named); held at their known values, never valued.
    pub not_determined: Vec<String>,
    /// Directions whose singular value is near the threshold of determination (named, with
    /// the singular value): another scan may decide them the other way.
    pub borderline: Vec<(String, f64)>,
    /// Parameters without an identified value of their own.
    pub not_identified: Vec<String>,
    /// Parameters no feature depends on at all.
    pub no_data: Vec<String>,
    /// What the registration absorbs.
    pub registration_absorbs: Vec<String>,
    /// The estimated registration (dx, dy, dz mm; alpha, beta, gamma rad).
    pub registration_estimate: [f64; 6],
    /// Solver: evaluations, termination, χ² before and after, degrees of freedom.
    pub solver: IdentifySolverReport,
    /// Goodness of fit: the features against each other at their stated σ, each face's
    /// points against the scanner's noise.
    pub fit: FitCheck,
    /// The model-correction loop.
    pub rounds: Vec<LoopRound>,
    /// Whether the loop met its tolerance.
    pub converged: bool,
    /// Monte-Carlo trials run.
    pub monte_carlo_trials: usize,
    /// Seconds per stage.
    pub timings_s: Vec<(String, f64)>,
}

/// The solver's account in an identification report.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct IdentifySolverReport {
    /// Residual evaluations.
    pub evaluations: usize,
    /// Why it stopped.
    pub termination: String,
    /// χ² at the start.
    pub chi2_start: f64,
    /// χ² at the end.
    pub chi2: f64,
    /// Degrees of freedom.
    pub dof: usize,
}

impl IdentifyReport {
    /// The short human summary.
    pub fn summary(&self) -> String {
        let mut s = String::new();
        if let Some(w) = &self.warning {
            let _ = writeln!(s, "twinmill identify: {w}");
        }
        let _ = writeln!(
            s,
            "twinmill identify: {} — {} faces, registration {}, cloud {}",
            self.scene,
            self.features.len(),
            self.registration,
            self.cloud
        );
        let fmt = |e: &EstimateReport| {
            // Joint and ISO names alike (`dy_AY`, `EX0C` mm; `gamma_YX`, `EC(0X)Y` rad).
            let unit = if super::is_angle_name(&e.name) {
                "rad"
            } else {
                "mm"
            };
            let mut t = format!("{:+.6e} ± {:.2e} {unit}", e.value, e.sigma);
            if let Some(m) = e.monte_carlo_spread {
                let _ = write!(t, " (MC spread {m:.2e})");
            }
            if let Some(i) = e.injected {
                let _ = write!(t, " [injected {}]", super::deviation_value(&e.name, i));
            }
            t
        };
        for e in &self.identified {
            let _ = writeln!(s, "  identified    {:<28} {}", e.name, fmt(e));
        }
        for e in &self.combinations {
            let _ = writeln!(s, "  combination   {:<28} {}", e.name, fmt(e));
        }
        for n in &self.not_determined {
            let _ = writeln!(s, "  not determined {n}");
        }
        for (n, sv) in &self.borderline {
            let _ = writeln!(s, "  {}", borderline_line(n, *sv));
        }
        if !self.no_data.is_empty() {
            let _ = writeln!(s, "  no data       {}", self.no_data.join(", "));
        }
        let _ = writeln!(
            s,
            "  jacobian      condition {:.3e} (determined subspace {:.3e}); singular values {}",
            self.condition_number,
            self.condition_number_determined,
            self.singular_values
                .iter()
                .map(|v| format!("{v:.3e}"))
                .collect::<Vec<_>>()
                .join(" ")
        );
        let _ = writeln!(s, "  rank          {}", self.margin.describe());
        let _ = writeln!(s, "  fit           {}", self.fit.describe());
        let _ = writeln!(
            s,
            "  solver        {} evaluations, {}, χ² {:.3e} → {:.3e} ({} dof)",
            self.solver.evaluations,
            self.solver.termination,
            self.solver.chi2_start,
            self.solver.chi2,
            self.solver.dof
        );
        if let Some(last) = self.rounds.last() {
            let _ = writeln!(
                s,
                "  loop          {} round(s), worst face {:.2e} mm: {}",
                self.rounds.len(),
                last.worst_face_mm,
                if self.converged {
                    "within tolerance"
                } else {
                    "NOT within tolerance"
                }
            );
        }
        s
    }
}

/// The summary line of a borderline direction (shared by `identify` and `design`).
pub fn borderline_line(name: &str, singular_value: f64) -> String {
    format!(
        "borderline    {name} (singular value {singular_value:.2}, determined from {:.0}: another scan may decide it the other way)",
        1.0 / crate::calibration::calibrate::DETERMINED_FRACTION
    )
}
