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
//! ## Layers (data flows one way; no module names a type of a module above it)
//! 1. Foundations: [`error`], [`stats`], [`rng`], [`progress`].
//! 2. Inputs in memory: [`lights`] (directions and intensities) and [`capture`] (images, lights
//!    and mask as pixel-major samples; [`Capture::from_stack`] builds one from an (N, H, W, C)
//!    array, [`CaptureFiles`] from files).
//! 3. [`lambert`]: the Lambertian kernel — channel mean, least squares over any subset of lights
//!    with cached solvers, per-light statuses.
//! 4. [`detect`]: the χ² test and the attribution of faults to lights (uses [`lambert`]).
//! 5. [`estimate`]: the estimators `l2`, `coleman-jain`, `barsky-petrou` behind one trait
//!    (uses [`lambert`], [`detect`]).
//! 6. [`integrate`] (normals to depth; below the recursive driver) and [`shadows`] (attached
//!    and cast shadows of a height field).
//! 7. [`recursive`]: the recursive method, driving [`detect`], [`lambert`], [`integrate`] and
//!    [`shadows`]; it returns its own diagnostics.
//! 8. [`engine`]: `reconstruct(&Capture, &Params, &dyn Progress) -> Reconstruction`, every
//!    output full frame, and a [`report::Report`] value; [`metrics`] scores normals;
//!    [`indicators`] measures the paper's Table 2 indicator from the capture and the statuses.
//! 9. io at the edge: [`imageio`], [`groundtruth`], [`matfile`], [`export`], [`surface`],
//!    [`figure`], [`report`] serialisation, and [`pipeline`], the file driver of `run`
//!    (load → reconstruct → evaluate → report → export); [`compare`] runs every method on one
//!    capture (the paper's Tables 1–2 and Figs. 7–12); [`maps`] draws legible figures.
//!
//! Beside them: [`scene`] renders ground-truth scenes and [`calibrate`] finds lights from a
//! mirror sphere. The library never prints: progress goes through [`progress::Progress`].

pub mod app;
pub mod base;
pub mod calibrate;
#[cfg(test)]
pub(crate) mod fixtures;
pub mod geometry;
pub mod io;
pub mod method;
pub mod model;
pub mod scene;
pub mod solve;

pub use app::pipeline::RunOptions;
pub use base::error::{Error, Result};
pub use io::layouts::CaptureFiles;
pub use method::engine::{reconstruct, Method, Params, Reconstruction};
pub use model::capture::Capture;
pub use model::lights::Lights;
pub use solve::estimate::{Estimate, Estimator};
