//! Drivers over files: `run` (load → reconstruct → evaluate → report → export) and `compare` (every
//! method on one capture).

pub mod compare;
pub mod pipeline;
pub mod rti;
