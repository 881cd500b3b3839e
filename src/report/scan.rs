//! What `twinmill scan` writes to `scan.json`: the scan's figures (also part of `run`'s
//! report) and the scanner-effects study.

use crate::math::Real;
use crate::metrology::scan::ViewReport;
use serde::Serialize;
use std::fmt::Write as _;

/// Scan figures.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ScanReport {
    /// Camera rays cast.
    pub rays: usize,
    /// Points measured.
    pub points: usize,
    /// Points in the projector's shadow (not measured).
    pub shadowed: usize,
    /// Point pitch at the target distance (mm).
    pub pitch_mm: f64,
    /// Range noise σ (mm).
    pub noise_sigma_mm: f64,
    /// Noise seed.
    pub seed: u64,
    /// Per view: points, drop-outs and the registration error applied.
    pub views: Vec<ViewReport>,
}

impl ScanReport {
    /// The figures of `scan`, made with `cfg`.
    pub fn of(
        scan: &crate::metrology::scan::Scan,
        cfg: &crate::metrology::scan::ScannerConfig,
    ) -> Self {
        Self {
            rays: scan.rays,
            points: scan.cloud.points.len(),
            shadowed: scan.shadowed(),
            pitch_mm: cfg.pitch_mm,
            noise_sigma_mm: cfg.noise_sigma_mm,
            seed: cfg.seed,
            views: scan.views.clone(),
        }
    }
}

/// What `twinmill scan` writes to scan.json.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ScanFileReport {
    /// Scene name.
    pub scene: String,
    /// The scan.
    pub scan: ScanReport,
    /// The scanner-effects study, if asked for.
    pub study: Vec<StudyCase>,
}

impl ScanFileReport {
    /// The short human summary.
    pub fn summary(&self) -> String {
        let mut s = String::new();
        let sc = &self.scan;
        let _ = writeln!(
            s,
            "twinmill scan: {} — {} points from {} view(s), {} rays",
            self.scene,
            sc.points,
            sc.views.len(),
            sc.rays
        );
        for v in &sc.views {
            let _ = writeln!(
                s,
                "  view at table {:>7.2}°: {} points; dropped {} shadowed, {} grazing, {} out of range",
                v.table_deg, v.points, v.shadowed, v.grazing, v.out_of_range
            );
        }
        if !self.study.is_empty() {
            let _ = writeln!(
                s,
                "  scanner study ({} = true value {:+.4} mm):",
                self.study[0].parameter, self.study[0].truth_mm
            );
            let _ = writeln!(
                s,
                "    {:<48} {:>6} {:>11} {:>10} {:>10} {:>10}",
                "case", "trials", "mean mm", "spread µm", "worst µm", "σ rep. µm"
            );
            for c in &self.study {
                let _ = writeln!(
                    s,
                    "    {:<48} {:>6} {:>+11.5} {:>10.2} {:>10.2} {:>10.2}",
                    c.case,
                    c.trials,
                    c.mean_mm,
                    c.spread_mm * 1e3,
                    c.worst_error_mm * 1e3,
                    c.mean_reported_sigma_mm * 1e3
                );
            }
        }
        s
    }
}

/// One case of the study: the identified offset over seeded trials.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct StudyCase {
    /// What the scanner does in this case.
    pub case: String,
    /// Trials run.
    pub trials: usize,
    /// The offset parameter (e.g. `dy_AY`).
    pub parameter: String,
    /// Its true (injected) value (mm).
    pub truth_mm: Real,
    /// Mean identified value (mm).
    pub mean_mm: Real,
    /// Sample standard deviation over the trials (mm); 0 for one trial.
    pub spread_mm: Real,
    /// Largest |identified − truth| (mm).
    pub worst_error_mm: Real,
    /// Mean of the uncertainty the fits report (mm): compare with `spread_mm`.
    pub mean_reported_sigma_mm: Real,
    /// Mean measured step (mm).
    pub mean_step_mm: Real,
}
