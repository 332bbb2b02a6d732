//! Per-pixel estimation of normals and albedo. Every estimator implements [`Estimator`]; the
//! shared machinery solves least squares per pixel over any subset of usable lights, with the
//! 3×3 normal matrices cached per subset and the pixels split over threads in chunks.
//!
//! Normals are unit vectors in the camera frame (x right, y up, z toward the camera); albedo is
//! per channel, in the units of the intensity-normalised images.

mod barsky_petrou;
mod coleman_jain;
mod least_squares;

pub use barsky_petrou::BarskyPetrou;
pub use coleman_jain::ColemanJain;
pub use least_squares::LeastSquares;

use crate::base::error::Result;
use crate::base::progress::Progress;
use crate::model::capture::Capture;

pub use crate::solve::lambert::{
    channel_mean, solve_subsets, status, write_normal_albedo, write_normal_albedo_with, Estimate,
    SubsetCache, SubsetSolver, CHUNK,
};

/// A normal-and-albedo estimator. Implementations are stateless between calls and thread-safe.
pub trait Estimator: Sync {
    /// Short name, as accepted by `--method`.
    fn name(&self) -> &'static str;
    /// Estimates normals and albedo for every mask pixel of `capture`.
    fn estimate(&self, capture: &Capture, progress: &dyn Progress) -> Result<Estimate>;
}

#[cfg(test)]
pub(crate) mod tests;
