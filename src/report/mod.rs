//! **Reports**: what the commands tell the user. PNG heat maps with a colour bar
//! ([`render`]), the standards' plots (ISO 230-2 bidirectional, ISO 230-4 polar:
//! [`plots`]), the deviation map of a cut part against its design model
//! ([`deviation_map`]), the self-contained HTML page ([`html`]: a GLB of the display
//! geometry from [`glb`] and [`display`], SVG plots from [`svg`]), the shaded part picture
//! ([`part_view`]), and the serialisable report of every command with the summary text
//! the CLI prints: one private module per command (`simulate`, `scan`, `run`, `fit`,
//! `correct`, `identify`, `design`), their types re-exported here ([`Report`],
//! [`SimulationReport`], [`CorrectReport`], …).
//!
//! May use every stage folder below it (it reports their results). Plain data and
//! pictures in memory: it computes no physics beyond the deviation map and writes no files
//! (that is [`crate::output`]'s work).

pub mod render;
pub mod deviation_map;
pub mod plots;
pub mod glb;
pub mod display;
pub mod part_view;
pub mod svg;
pub mod html;
mod simulate;
mod scan;
mod run;
mod fit;
mod correct;
mod identify;
mod design;
pub mod hexapod;
pub mod pages;

pub use correct::{CorrectIteration, CorrectReport, UncorrectableReport};
pub use design::DesignReport;
pub use fit::{CircleReport, CylinderReport, FitFileReport, PlanePair, PlaneReport, SphereReport};
pub use identify::{
    EstimateReport, FeatureReport, IdentifyReport, IdentifySolverReport, LoopRound,
};
pub use run::{FaceReport, Report, SolverReport};
pub use scan::{ScanFileReport, ScanReport, StudyCase};
pub use simulate::{CollisionEvent, DeviationSummary, MeshSummary, SimulationReport, StockReport};

/// Resolution of a printed offset deviation (mm): a picometre, far below what any
/// instrument resolves and far above the rounding of a composed transform (about 1e-15 of
/// the lengths it involves).
pub const OFFSET_RESOLUTION_MM: f64 = 1e-9;
/// Resolution of a printed angle deviation (rad), likewise.
pub const ANGLE_RESOLUTION_RAD: f64 = 1e-12;

/// Whether a deviation name (joint, ISO 230-7 or combination) is an angle (rad): `alpha_…`,
/// `beta_…`, `gamma_…`, and the ISO tilts and squarenesses `EA…`, `EB…`, `EC…`; else an
/// offset or length (mm).
pub fn is_angle_name(name: &str) -> bool {
    name.starts_with("alpha")
        || name.starts_with("beta")
        || name.starts_with("gamma")
        || matches!(name.as_bytes(), [b'E', b'A' | b'B' | b'C', ..])
}

/// A deviation's value as text at the precision that reflects what it means: offsets to
/// [`OFFSET_RESOLUTION_MM`], angles to [`ANGLE_RESOLUTION_RAD`], in plain decimals with
/// trailing zeros dropped — `dz_BS = 0.01` for a composed 0.009999999999990905,
/// `gamma_AY = 0.000025`, `0` for what rounds to nothing.
pub fn deviation_value(name: &str, value: f64) -> String {
    if !value.is_finite() {
        return value.to_string();
    }
    let decimals = if is_angle_name(name) { 12 } else { 9 };
    let text = format!("{value:.decimals$}");
    let text = text.trim_end_matches('0').trim_end_matches('.');
    match text {
        "-0" | "" => "0".to_string(),
        t => t.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn deviation_values_print_at_their_resolution_not_their_rounding() {
        // Offsets to 1 pm, angles to 1 prad, written out by hand.
        for (name, v, text) in [
            ("dz_BS", 0.009999999999990905, "0.01"),
            ("dy_AY", -0.5, "-0.5"),
            ("EX0C", 0.020000000000000004, "0.02"),
            ("l0_1", 0.06, "0.06"),
            ("dx_XY", 1.25e-7, "0.000000125"),
            ("dx_XY", -4e-13, "0"),
            ("gamma_AY", 2.5e-5, "0.000025"),
            ("gamma_AY+gamma_YX", 3.9999999999999996e-5, "0.00004"),
            ("EC0A", 1.474830e-19, "0"),
            ("EC(0X)Y", -4e-5, "-0.00004"),
            ("beta_ZS", 1.2e-9, "0.0000000012"),
        ] {
            assert_eq!(deviation_value(name, v), text, "{name} = {v:e}");
        }
    }
}
