//! **The machine**: what turns axis values into tool poses. A machine is a kinematic chain
//! of linear and rotary axes from the workpiece to the tool, with an exact rigid deviation
//! at every joint ([`chain`]); a scene describes it as data, never as code.
//!
//! Owns the chain, the deviation names (`dy_AY`, `gamma_YX`, …) and their exact transforms.
//! May use [`crate::math`] and [`crate::nc`] (axis letters and values). Knows nothing of
//! tools, stock, measurements or files.

pub mod chain;
