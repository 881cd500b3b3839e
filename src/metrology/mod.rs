//! **Metrology**: measuring the cut part. Point clouds and their files ([`cloud`]), the
//! virtual structured-light scanner ([`scan`]), least-squares fits of planes, spheres,
//! circles and cylinders with their uncertainties ([`fit`]), and segmentation of whole
//! clouds into faces and shapes ([`segment`]), and the evaluations of the standards, which read one small CSV dialect ([`table`]): ISO 230-2
//! positioning accuracy from any readings ([`positioning`]) and ISO 230-4 circular tests with the
//! ball-bar diagnostics ([`circular`]), and seed 003's non-contact ball sensor with its Z
//! uncertainty and working window ([`ball_sensor`]). The instruments of the standards
//! run on the twin belong here too: the ISO 10791-6 motion test read by the ball sensor and
//! probed sphere positions at rotary indices ([`rotary_test`]).
//!
//! May use [`crate::math`], [`crate::progress`], [`crate::nc`] (axis values),
//! [`crate::machine`] (the instruments follow the chain) and [`crate::cutting`] (the scanner
//! looks at the stock's crossings). Fits and segmentation work on any cloud, from twinmill or from a
//! real instrument: they never run the sweep, and nothing here identifies deviations.

pub mod cloud;
pub mod scan;
pub mod fit;
pub mod segment;
pub mod table;
pub mod positioning;
pub mod circular;
pub mod ball_sensor;
pub mod rotary_test;
