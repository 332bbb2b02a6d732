//! Foundations every layer may use: the error type, progress reporting, the random number
//! generator, distribution functions. Names nothing above it.

pub mod cholesky;
pub mod codes2;
pub mod error;
pub mod machine;
pub mod number;
pub mod progress;
pub mod rng;
pub mod stats;
