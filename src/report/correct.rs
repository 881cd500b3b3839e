//! What `twinmill correct` writes to `<scene>-correct.json`: every pass of the correction
//! loop, what no axis command can correct, and the summary the CLI prints.

use crate::cutting::sweep::SweepReport;
use serde::Serialize;
use std::collections::BTreeMap;
use std::fmt::Write as _;

/// One pass of the correction loop: the program simulated on the machine and measured.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CorrectIteration {
    /// 0 for the program as given, then 1, 2, … for each correction.
    pub iteration: usize,
    /// The subdivision tolerance used (mm); `None` for the program as given.
    pub path_tolerance_mm: Option<f64>,
    /// Blocks simulated.
    pub blocks: usize,
    /// Tool path on the simulated machine against the nominal path.
    pub path: crate::calibration::correct::PathError,
    /// The milled faces against the nominal faces.
    pub faces: crate::calibration::correct::FaceCheck,
    /// Every cut surface of the part against the nominal part (the program as given swept
    /// on the nominal machine), ray by ray.
    pub part: crate::calibration::correct::PartError,
    /// The predicted machining error: the largest distance of a milled-face crossing from
    /// its nominal face (mm); `None` (null) when no face was measured — the scene names no
    /// faces (`[identify]`), or they are too far off to find.
    pub predicted_error_mm: Option<f64>,
    /// What the sweep did.
    pub sweep: SweepReport,
}

/// The residual one deviation alone leaves after correction.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct UncorrectableReport {
    /// Deviation name.
    pub deviation: String,
    /// Its value in the model corrected for (mm or rad).
    pub value: f64,
    /// Largest RMS residual over the flute it alone leaves (mm).
    pub residual_rms_mm: f64,
    /// Largest residual at the flute's tip or end (mm).
    pub residual_max_mm: f64,
}

/// What `twinmill correct` writes to `<scene>-correct.json`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CorrectReport {
    /// Set when the model corrected for was identified from data that do not fit it at the
    /// stated noise and the misfit was accepted on request: the report's first word.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub warning: Option<String>,
    /// Scene name.
    pub scene: String,
    /// Source program file.
    pub program: String,
    /// The corrected program's file name.
    pub corrected_program: String,
    /// Deviations corrected for (the model; mm or rad), non-zero ones.
    pub corrected_for: BTreeMap<String, f64>,
    /// Deviations of the simulated machine (mm or rad).
    pub simulated: BTreeMap<String, f64>,
    /// The accuracy asked for (mm).
    pub accuracy_mm: f64,
    /// Whether the last iteration's faces and path are within the accuracy.
    pub met: bool,
    /// How the loop ended, in words.
    pub status: String,
    /// Every pass, the program as given first.
    pub iterations: Vec<CorrectIteration>,
    /// The final correction's figures.
    pub correction: crate::calibration::correct::CorrectionSummary,
    /// Each non-zero deviation alone: the residual no axis command can remove.
    pub uncorrectable: Vec<UncorrectableReport>,
    /// Per source move of the final correction.
    pub moves: Vec<crate::calibration::correct::MoveCorrection>,
    /// Seconds per stage.
    pub timings_s: Vec<(String, f64)>,
}

impl CorrectReport {
    /// The short human summary.
    pub fn summary(&self) -> String {
        let mut s = String::new();
        if let Some(w) = &self.warning {
            let _ = writeln!(s, "twinmill correct: {w}");
        }
        let _ = writeln!(
            s,
            "twinmill correct: {} ({}) for accuracy {} mm",
            self.scene, self.program, self.accuracy_mm
        );
        for (k, v) in &self.corrected_for {
            let _ = writeln!(s, "  corrected for {k} = {}", super::deviation_value(k, *v));
        }
        for it in &self.iterations {
            let label = if it.iteration == 0 {
                "as given ".to_string()
            } else {
                format!("pass {:<4}", it.iteration)
            };
            let step = it
                .faces
                .step_mm
                .map_or(String::new(), |x| format!(", step {:+.4} µm", x * 1e3));
            let faces = match it.predicted_error_mm {
                Some(e) => format!("faces max {:.4} µm{step}", e * 1e3),
                None => "faces not measured".to_string(),
            };
            let _ = writeln!(
                s,
                "  {label} {faces}; path max {:.4} µm, rms {:.4} µm; whole part max {:.4} µm ({} blocks)",
                it.path.max_mm * 1e3,
                it.path.rms_mm * 1e3,
                it.part.max_mm * 1e3,
                it.blocks
            );
        }
        let c = &self.correction;
        let _ = writeln!(
            s,
            "  residual      {:.4} µm RMS over the flute, {:.4} µm at a flute end (uncorrectable); {} moves subdivided",
            c.residual_rms_mm * 1e3,
            c.residual_max_mm * 1e3,
            c.subdivided_moves
        );
        for u in self
            .uncorrectable
            .iter()
            .filter(|u| u.residual_max_mm > crate::math::tol::LENGTH_EPS)
        {
            let _ = writeln!(
                s,
                "  {:<13} alone leaves {:.4} µm RMS (cannot be corrected with these axes)",
                u.deviation,
                u.residual_rms_mm * 1e3
            );
        }
        let _ = writeln!(s, "  status        {}", self.status);
        let total: f64 = self.timings_s.iter().map(|t| t.1).sum();
        let parts: Vec<String> = self
            .timings_s
            .iter()
            .map(|(n, t)| format!("{n} {t:.3}"))
            .collect();
        let _ = writeln!(s, "  time          {total:.3} s ({})", parts.join(", "));
        s
    }
}
