//! twinmill: a digital twin of machine-tool accuracy.
//!
//! The pipeline, in module order: [`nc`] (program → moves) → [`kinematics`] (axis values →
//! tool poses through the deviated chain) → [`tool`] → [`stock`] and [`sweep`] (exact
//! material removal on a tri-dexel) → [`cloud`] → [`scan`] (virtual structured-light
//! scanner) → [`fit`] (planes, spheres, circles, cylinders) → [`segment`] (normals, planar
//! regions, RANSAC) → [`identify`] (deviations from the fitted faces) →
//! [`render`] and [`report`]; [`scene`] loads input files, [`pipeline`] runs it all and
//! [`output`] writes the results. See README.md, *Architecture*.

pub mod calibrate;
pub mod cloud;
pub mod design;
pub mod fit;
pub mod identify;
pub mod kinematics;
pub mod math;
pub mod nc;
pub mod output;
pub mod pipeline;
pub mod progress;
pub mod render;
pub mod report;
pub mod scan;
pub mod scene;
pub mod segment;
pub mod stock;
pub mod sweep;
pub mod tool;
