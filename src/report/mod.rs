//! **Reports**: what the commands tell the user. PNG heat maps with a colour bar
//! ([`render`]), the deviation map of a cut part against its design model
//! ([`deviation_map`]), and the serialisable report of every command with the summary text
//! the CLI prints (re-exported here: [`Report`], [`SimulationReport`], [`CorrectReport`], …).
//!
//! May use every stage folder below it (it reports their results). Plain data and
//! pictures in memory: it computes no physics beyond the deviation map and writes no files
//! (that is [`crate::output`]'s work).

pub mod render;
pub mod deviation_map;
mod reports;

pub use reports::*;
