//! What `twinmill design` reports: the designed cuts and faces and what they are expected
//! to determine.

use serde::Serialize;
use std::fmt::Write as _;

/// What `twinmill design` reports.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct DesignReport {
    /// Scene the design is for.
    pub scene: String,
    /// Parameters asked for.
    pub parameters: Vec<String>,
    /// Cuts: name, rotary index (degrees), NC line of the cut.
    pub cuts: Vec<(String, f64, usize)>,
    /// Faces to measure: name and kind.
    pub faces: Vec<(String, String)>,
    /// Singular values of the scaled Jacobian on the designed scene's simulated scan.
    pub singular_values: Vec<f64>,
    /// How clearly the determined subspace was decided there: the gap between the last
    /// determined and the first undetermined singular value.
    pub margin: crate::calibration::goodness::RankMargin,
    /// Condition number.
    pub condition_number: f64,
    /// Parameters the design identifies on their own.
    pub identified: Vec<String>,
    /// Further determined combinations.
    pub determined_combinations: Vec<String>,
    /// Directions the design does not determine.
    pub not_determined: Vec<String>,
    /// Directions near the threshold of determination (named, with the singular value):
    /// another scan may decide them the other way.
    pub borderline: Vec<(String, f64)>,
    /// How the promise was made: the designed scene cut, scanned and identified as
    /// `twinmill identify` does it (which scan, how many designs were tried).
    pub verified: String,
    /// Standard uncertainty of each identified parameter on the designed scene's simulated
    /// scan, over its realistic magnitude (0.5 mm, 5e-4 rad).
    pub relative_sigma: Vec<(String, f64)>,
    /// Candidate evaluations made.
    pub evaluated: usize,
    /// Why the weak directions are weak (the tip-height lever of the Z-squareness and
    /// spindle-tilt pairs).
    pub notes: Vec<String>,
    /// Parameters this part leaves undetermined that a second part designed for them
    /// alone determines (the block has no room left for the cuts that see them), and that
    /// part's cut count; empty when there are none.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub second_part: Vec<String>,
    /// The second part's cuts.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub second_part_cuts: Option<usize>,
}

impl DesignReport {
    /// The short human summary.
    pub fn summary(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "twinmill design: {} — {} cuts, {} faces ({} candidates evaluated)",
            self.scene,
            self.cuts.len(),
            self.faces.len(),
            self.evaluated
        );
        for (name, a, line) in &self.cuts {
            let _ = writeln!(s, "  cut           {name:<16} A = {a:>5.1}°  line {line}");
        }
        let _ = writeln!(s, "  identified    {}", self.identified.join(", "));
        for c in &self.determined_combinations {
            let _ = writeln!(s, "  combination   {c}");
        }
        for c in &self.not_determined {
            let _ = writeln!(s, "  not determined {c}");
        }
        for (c, sv) in &self.borderline {
            let _ = writeln!(s, "  {}", super::identify::borderline_line(c, *sv));
        }
        let _ = writeln!(s, "  condition     {:.3e}", self.condition_number);
        let _ = writeln!(s, "  rank          {}", self.margin.describe());
        let _ = writeln!(s, "  verified      {}", self.verified);
        for n in &self.notes {
            let _ = writeln!(s, "  lever         {n}");
        }
        if let Some(n) = self.second_part_cuts {
            let names = self.second_part.join(",");
            let _ = writeln!(
                s,
                "  second part   {names}: no room is left on this block for the cuts that see \
                 them; a second block designed for them alone (design --params {names}) is \
                 expected to determine them with {n} cuts"
            );
        }
        s
    }
}
