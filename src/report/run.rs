//! What `twinmill run` reports: the fitted faces, the step, the identified deviations with
//! their uncertainties, the solver's figures, and the summary the CLI prints.

use super::scan::ScanReport;
use super::simulate::StockReport;
use crate::calibration::goodness::{FitCheck, RankMargin};
use crate::cutting::sweep::SweepReport;
use serde::Serialize;
use std::collections::BTreeMap;
use std::fmt::Write as _;

/// One fitted face.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FaceReport {
    /// Face name.
    pub name: String,
    /// NC line of its cut.
    pub line: usize,
    /// Rotary positions of the cut (degrees), per rotary axis.
    pub rotary_deg: Vec<f64>,
    /// Points used in the fit.
    pub points: usize,
    /// Points rejected as outliers.
    pub rejected: usize,
    /// Unit normal (into the material), workpiece frame.
    pub normal: [f64; 3],
    /// Plane offset: normal · x = offset (mm).
    pub offset_mm: f64,
    /// Centroid of the fitted points (mm).
    pub centroid_mm: [f64; 3],
    /// RMS of the residuals (mm).
    pub rms_mm: f64,
    /// Largest absolute residual (mm).
    pub max_abs_mm: f64,
}

/// Solver figures of the identification.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SolverReport {
    /// Method used.
    pub method: String,
    /// Singular values of the Jacobian of (step, tilt) w.r.t. the two parameters.
    pub singular_values: [f64; 2],
    /// How clearly the pair's rank was decided: the gap between the last kept and the
    /// first dropped singular value.
    pub margin: RankMargin,
    /// Residual evaluations.
    pub evaluations: usize,
    /// Final residual norm.
    pub residual: f64,
}

/// The whole report.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Report {
    /// Set when the faces do not fit the model at the scanner's noise and the misfit was
    /// accepted on request: the report's first word.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub warning: Option<String>,
    /// Scene name.
    pub scene: String,
    /// Machine name.
    pub machine: String,
    /// The chain, workpiece to tool.
    pub chain: String,
    /// Program file.
    pub program: String,
    /// Moves in the program.
    pub moves: usize,
    /// Measured step between the faces (mm): second face minus first along the first's
    /// normal into the material, at the faces' centre. For seed 002's setup, −2·dy_AY.
    pub step_mm: f64,
    /// Standard uncertainty of the measured step (mm).
    pub step_sigma_mm: f64,
    /// The step the exact twin predicts for the injected deviations (mm).
    pub predicted_step_mm: f64,
    /// Measured relative tilt of the faces about the tool axis (rad).
    pub tilt_rad: f64,
    /// The tilt the exact twin predicts (rad).
    pub predicted_tilt_rad: f64,
    /// Deviations injected into the simulated machine (mm or rad).
    pub injected: BTreeMap<String, f64>,
    /// Deviations assumed known in the identification (mm or rad).
    pub known: BTreeMap<String, f64>,
    /// Identified deviations and combinations (mm or rad).
    pub identified: BTreeMap<String, f64>,
    /// Standard uncertainties of the identified values, from the fit residuals.
    pub uncertainty: BTreeMap<String, f64>,
    /// Deviations this experiment does not identify; held at their known values, never
    /// given an identified value.
    pub not_identified: Vec<String>,
    /// Why the rotary axis's offset or angle combination was not identified, one sentence
    /// each (empty when both were).
    pub why_not_identified: Vec<String>,
    /// The fitted faces.
    pub faces: Vec<FaceReport>,
    /// The faces' goodness of fit: each face's points against the scanner's noise.
    pub fit: FitCheck,
    /// Identification solver.
    pub solver: SolverReport,
    /// Stock.
    pub stock: StockReport,
    /// Sweep, with the bound on the rotary sub-step approximation.
    pub sweep: SweepReport,
    /// Scan.
    pub scan: ScanReport,
    /// Wall-clock seconds per stage, in pipeline order.
    pub timings_s: Vec<(String, f64)>,
}

impl Report {
    /// The short human summary.
    pub fn summary(&self) -> String {
        let mut s = String::new();
        if let Some(w) = &self.warning {
            let _ = writeln!(s, "twinmill: {w}");
        }
        let _ = writeln!(
            s,
            "twinmill: {} on {} ({} moves)",
            self.scene, self.machine, self.moves
        );
        let inj: Vec<String> = self
            .injected
            .iter()
            .map(|(k, v)| format!("{k} = {}", super::deviation_value(k, *v)))
            .collect();
        let _ = writeln!(
            s,
            "  injected      {}",
            if inj.is_empty() {
                "none".into()
            } else {
                inj.join(", ")
            }
        );
        let _ = writeln!(
            s,
            "  step          {:+.4} mm ± {:.4} (predicted by the twin {:+.4} mm)",
            self.step_mm, self.step_sigma_mm, self.predicted_step_mm
        );
        for (k, v) in &self.identified {
            let u = self.uncertainty.get(k).copied().unwrap_or(f64::NAN);
            let unit = if k.starts_with('d') {
                ("mm", 1.0)
            } else {
                ("µrad", 1e6)
            };
            let _ = writeln!(
                s,
                "  identified    {k} = {:+.4} ± {:.4} {}",
                v * unit.1,
                u * unit.1,
                unit.0
            );
        }
        for w in &self.why_not_identified {
            let _ = writeln!(s, "  not identified {w}");
        }
        for (f, p) in self.faces.iter().zip(&self.fit.parts) {
            let _ = writeln!(
                s,
                "  face {:<8} {} points, rms {:.4} mm (the scanner's noise allows ≤ {:.4})",
                f.name, f.points, f.rms_mm, p.limit
            );
        }
        let _ = writeln!(
            s,
            "  rank          {} of 2, {}",
            self.identified.len(),
            self.solver.margin.describe()
        );
        let _ = writeln!(
            s,
            "  scan          {} points ({} shadowed), σ = {} mm; sweep bound on rotary moves {:.1e} mm",
            self.scan.points,
            self.scan.shadowed,
            self.scan.noise_sigma_mm,
            self.sweep.rotary_error_bound_mm
        );
        let total: f64 = self.timings_s.iter().map(|(_, t)| t).sum();
        let stages: Vec<String> = self
            .timings_s
            .iter()
            .map(|(k, t)| format!("{k} {:.3}", t))
            .collect();
        let _ = writeln!(s, "  time          {total:.3} s ({})", stages.join(", "));
        s
    }
}
