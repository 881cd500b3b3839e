//! twinmill: a digital twin of machine-tool accuracy.
//!
//! The pipeline, in module order: [`nc`] (program → moves) → [`kinematics`] (axis values →
//! tool poses through the deviated chain) → [`tool`] → [`stock`] and [`sweep`] (exact
//! material removal on a tri-dexel) → [`mesh`] (surface of the cut stock) and [`zmap`]
//! (3-axis height-field fast path) → [`cloud`] → [`scan`] (virtual structured-light
//! scanner) → [`fit`] (planes, spheres, circles, cylinders) → [`segment`] (normals, planar
//! regions, RANSAC) → [`identify`] (deviations from the fitted faces) → [`correct`] (the NC
//! program rewritten for the deviated machine, and verified) → [`render`] and [`report`];
//! [`scene`] loads input files, [`pipeline`] runs it all and [`output`] writes the results.
//! See README.md, *Architecture*.

pub mod calibrate;
pub mod cloud;
pub mod collide;
pub mod correct;
pub mod cutter;
pub mod design;
pub mod deviation;
pub mod envelope;
pub mod fit;
pub mod identify;
pub mod kinematics;
pub mod math;
pub mod mesh;
pub mod nc;
pub mod output;
pub mod pipeline;
pub mod progress;
pub mod render;
pub mod report;
pub mod scan;
pub mod scene;
pub mod segment;
pub mod shape;
pub mod stock;
pub mod sweep;
pub mod tool;
pub mod zmap;
