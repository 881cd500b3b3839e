//! twinmill: a digital twin of machine-tool accuracy.
//!
//! The pipeline, one folder per stage, each using only the stages before it:
//! [`nc`] (program → moves) → [`machine`] (axis values → tool poses through the deviated
//! chain) → [`cutting`] (tools swept through the chain carve a tri-dexel stock; collisions;
//! the part's mesh) → [`metrology`] (clouds, the virtual scanner, fits, segmentation) →
//! [`calibration`] (identification, test-cut design, NC correction) → [`report`] (reports,
//! pictures, the deviation map). At the edges: [`math`] and [`progress`] below everything;
//! [`scene`] loads input files, [`pipeline`] runs the commands, [`output`] writes results.
//! See `docs/architecture.md`.

pub mod math;
pub mod progress;

pub mod nc;
pub mod machine;
pub mod cutting;
pub mod metrology;
pub mod calibration;
pub mod report;

pub mod scene;
pub mod pipeline;
pub mod output;
pub mod study;
