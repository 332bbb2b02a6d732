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
    /// Whether the caller asked to stop (Ctrl-C in a front end). The engine checks it between
    /// stages and between the recursive method's iterations and then returns
    /// [`crate::Error::Cancelled`]; a stage under way runs to its end.
    fn cancelled(&self) -> bool {
        false
    }
}

/// [`crate::Error::Cancelled`] when `progress` says the caller asked to stop.
pub fn check_cancelled(progress: &dyn Progress) -> crate::Result<()> {
    if progress.cancelled() {
        Err(crate::Error::Cancelled)
    } else {
        Ok(())
    }
}

/// Ignores all progress.
#[derive(Clone, Copy, Debug, Default)]
pub struct Silent;

impl Progress for Silent {}
