//! The engine: `reconstruct(&Capture, &Params, &dyn Progress) -> Reconstruction`, the recursive
//! method's driver, the paper's indicators and the report's values. Uses every layer below it;
//! holds no path and prints nothing.

pub mod engine;
pub mod indicators;
pub mod params;
pub mod recursive;
pub mod report;
pub mod statusmap;
