//! **Metrology**: measuring the cut part and the machine. Point clouds and their files
//! ([`cloud`]), the virtual structured-light scanner ([`scan`]), least-squares fits of
//! planes, spheres, circles and cylinders with their uncertainties ([`fit`]), and
//! segmentation of whole clouds into faces and shapes ([`segment`]); the evaluations of the
//! standards, which read one small CSV dialect ([`table`]): ISO 230-2 positioning accuracy
//! from any readings ([`positioning`]), the LinuxCNC axis compensation table written from
//! them and applied as that controller applies it ([`comp_table`]), ISO 230-4 circular
//! tests with the ball-bar diagnostics ([`circular`]); seed 003's non-contact ball sensor
//! with its Z uncertainty and working window ([`ball_sensor`]); and the standards'
//! instruments run on the twin's chain: the laser interferometer's ISO 230-2 test cycle
//! ([`interferometer`], with or without a compensation table) and the ball bar's ISO 230-4
//! circles ([`ballbar`]), whose readings and traces those evaluations take as they are, and
//! the ISO 10791-6 motion test read by the ball sensor with probed sphere positions at
//! rotary indices ([`rotary_test`]); the double ball bar on a hexapod ([`hexapod_dbb`]).
//!
//! May use [`crate::math`], [`crate::progress`], [`crate::nc`] (axis letters and values),
//! [`crate::machine`] (the instruments read the chain) and [`crate::cutting`] (the scanner
//! looks at the stock's crossings). Fits and segmentation work on any cloud, from twinmill or
//! from a real instrument: they never run the sweep, and nothing here identifies deviations.

pub mod cloud;
pub mod scan;
pub mod fit;
pub mod segment;
pub mod table;
pub mod positioning;
pub mod comp_table;
pub mod circular;
pub mod ball_sensor;
pub mod interferometer;
pub mod ballbar;
pub mod rotary_test;
pub mod hexapod_dbb;
