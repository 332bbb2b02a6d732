//! Progress reporting from long stages to whatever front end is listening. The library never
//! prints; a front end implements [`Progress`] (a terminal bar, a Python callback, nothing).

/// Receives progress of the library's stages. Implementations must be cheap and thread-safe:
/// `advance` is called from worker threads.
pub trait Progress: Sync {
    /// A stage named `stage` starts with `total` units of work.
    fn begin(&self, _stage: &str, _total: u64) {}
    /// `units` more units of the current stage are done.
    fn advance(&self, _units: u64) {}
    /// The current stage is over.
    fn end(&self) {}
}

/// Ignores all progress.
#[derive(Clone, Copy, Debug, Default)]
pub struct Silent;

impl Progress for Silent {}
