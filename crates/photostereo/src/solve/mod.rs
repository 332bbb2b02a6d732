//! Per-pixel solvers over a capture: the Lambertian kernel, the χ² detector and attribution, the
//! estimators, consensus of statuses, the lobe models of near and distant lights, plausibility checks, error metrics
//! and the tile loops. Uses [`crate::model`] and [`crate::base`].

pub mod consensus;
pub mod detect;
pub mod estimate;
pub mod gloss;
pub mod lambert;
pub mod metrics;
pub mod near_lobe;
pub mod plausibility;
pub mod refine;
pub mod rti;
pub mod tiled;
