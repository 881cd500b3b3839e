//! Progress reporting for stages that take long. The library never prints: it calls a
//! [`Progress`] the caller supplies (the CLI draws bars with indicatif; tests pass
//! [`NoProgress`]).

/// Receives progress of long stages.
pub trait Progress: Sync {
    /// A stage named `stage` starts with `total` units of work.
    fn start(&self, stage: &str, total: u64);
    /// `n` more units are done.
    fn advance(&self, n: u64);
    /// The current stage is done.
    fn finish(&self);
}

/// Ignores all progress.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoProgress;

impl Progress for NoProgress {
    fn start(&self, _stage: &str, _total: u64) {}
    fn advance(&self, _n: u64) {}
    fn finish(&self) {}
}
