//! Woodham's least squares over all lights (ALGORITHMS.md §1).

use super::{solve_subsets, Estimate, Estimator};
use crate::base::error::Result;
use crate::base::progress::Progress;
use crate::model::capture::Capture;

/// Least squares over all lights: the normal from the channel mean, per-channel albedo with the
/// normal fixed. No shadow or highlight handling.
#[derive(Clone, Copy, Debug, Default)]
pub struct LeastSquares;

impl Estimator for LeastSquares {
    fn name(&self) -> &'static str {
        "l2"
    }

    fn estimate(&self, capture: &Capture, progress: &dyn Progress) -> Result<Estimate> {
        Ok(solve_subsets(capture, None, progress))
    }
}
