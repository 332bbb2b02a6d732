//! # photostereo
//!
//! Photometric stereo in Rust: per-pixel surface normals and albedo from images taken from one
//! viewpoint under known distant lights, with the recursive handling of shadows and highlights of
//! Argyriou & Petrou.
//!
//! ## Conventions (binding; see `CONVENTIONS.md` of the project)
//! - Camera frame: x to the image's right, y to the image's top, z toward the camera;
//!   orthographic camera looking down −z. Arrays are `[row][col]`, row 0 at the top, so y grows
//!   opposite to the row index.
//! - Normals are unit vectors in that frame with n_z > 0 on visible surfaces; light directions
//!   are unit vectors from the surface toward the light.
//! - A height field f in pixel units has ∂f/∂col = −n_x/n_z and ∂f/∂row = +n_y/n_z.
//! - Angular error: arccos of the dot product of normalised vectors, in degrees.
//!
//! ## Stages (data flows one way)
//! [`capture`] loads images and lights → [`estimate`] computes normals and albedo →
//! [`metrics`] scores them → [`export`] writes the output folder. [`pipeline`] drives a run;
//! [`scene`] renders ground-truth scenes; [`shadows`] finds the attached and cast shadows of a
//! height field. The library never prints: progress goes through [`progress::Progress`].

pub mod calibrate;
pub mod capture;
pub mod detect;
pub mod error;
pub mod estimate;
pub mod export;
pub mod figure;
pub mod groundtruth;
pub mod imageio;
pub mod integrate;
pub mod lights;
pub mod matfile;
pub mod metrics;
pub mod pipeline;
pub mod progress;
pub mod recursive;
pub mod report;
pub mod rng;
pub mod scene;
pub mod shadows;
pub mod stats;
pub mod surface;
pub mod viewer;

pub use capture::{Capture, CaptureFiles};
pub use error::{Error, Result};
pub use estimate::{Estimate, Estimator};
pub use lights::Lights;
pub use pipeline::{Method, RunOptions};
