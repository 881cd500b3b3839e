//! **Calibration**: from measurements back to the machine, and from the machine to a
//! corrected program. The goodness of fit every identification checks its result with
//! ([`goodness`]), the 0°/180° step experiment ([`identify`]), what a whitened Jacobian
//! determines, the one report every identification gives ([`determined`]), one engine for
//! any forward model ([`engine`]), and on it general identification of any set of
//! deviations from planes and balls ([`calibrate`]), test-cut design ([`design`]),
//! NC-program correction with its verification ([`correct`]), the step experiment's
//! identification ([`step`]), a hexapod's kinematic parameters from
//! double-ball-bar lengths ([`hexapod_calibrate`], its circles by design in
//! [`hexapod_design`]), a serial machine from laser readings and ball-bar circles together
//! ([`instruments`]), a hexapod calibrated in rounds from touch-probe readings of
//! positioning and pivot accuracy ([`hexapod_probe`]), and a hexapod from bar and probe
//! readings at once ([`hexapod_dbb_probe`]).
//!
//! May use everything below it: [`crate::math`], [`crate::nc`], [`crate::machine`],
//! [`crate::cutting`] (the verification sweeps the corrected program) and
//! [`crate::metrology`] (fits and face selection). Never values what the measurements do not
//! determine; never opens files.

pub mod goodness;
pub mod identify;
pub mod determined;
pub mod engine;
pub mod calibrate;
pub mod design;
pub mod correct;
pub mod step;
pub mod hexapod_calibrate;
pub mod hexapod_design;
pub mod instruments;
pub mod hexapod_probe;
pub mod hexapod_dbb_probe;
