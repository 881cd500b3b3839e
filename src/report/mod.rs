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
