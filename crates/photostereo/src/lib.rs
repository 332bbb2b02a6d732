//! # photostereo
//!
//! Photometric stereo: per-pixel surface normals and albedo from images taken from one
//! viewpoint while a light moves, with the recursive handling of shadows and highlights of
//! Argyriou & Petrou (find the readings that break the Lambertian model, integrate a surface,
//! compute its shadows, estimate again from the reliable lights), then depth and meshes.
//!
//! ```
//! use ndarray::Array4;
//! use photostereo::base::progress::Silent;
//! use photostereo::model::capture::Stack;
//! use photostereo::{reconstruct, Capture, Lights, Params};
//!
//! // Four 32 × 32 grey images of a Lambertian sphere (radius 14 px) under four lights.
//! let dirs = [[0.3, 0.3, 0.9], [-0.3, 0.3, 0.9], [-0.3, -0.3, 0.9], [0.3, -0.3, 0.9]];
//! let lights = Lights::new(&dirs).unwrap();
//! let mut images = Array4::<f32>::zeros((4, 32, 32, 1));
//! for (k, l) in lights.directions.iter().enumerate() {
//!     for r in 0..32 {
//!         for c in 0..32 {
//!             let (x, y) = ((c as f64 - 15.5) / 14.0, (15.5 - r as f64) / 14.0);
//!             if x * x + y * y < 1.0 {
//!                 let n = [x, y, (1.0 - x * x - y * y).sqrt()];
//!                 let shade = n[0] * l[0] + n[1] * l[1] + n[2] * l[2];
//!                 images[[k, r, c, 0]] = (0.8 * shade).max(0.0) as f32;
//!             }
//!         }
//!     }
//! }
//! let capture = Capture::from_stack(Stack::F32(images.view()), lights, None).unwrap();
//! let rec = reconstruct(&capture, &Params::default(), &Silent).unwrap();
//! // The centre pixel faces the camera.
//! let n = rec.normals[16 * 32 + 16];
//! assert!(n[2] > 0.99, "{n:?}");
//! ```
//!
//! ## Conventions (binding; `CONVENTIONS.md` of the project)
//! - Camera frame: x to the image's right, y to the image's top, z toward the camera;
//!   orthographic camera looking down −z. Arrays are `[row][col]`, row 0 at the top, so y grows
//!   opposite to the row index.
//! - Normals are unit vectors in that frame with n_z > 0 on visible surfaces; light directions
//!   are unit vectors from the surface toward the light.
//! - A height field f in pixel units has ∂f/∂col = −n_x/n_z and ∂f/∂row = +n_y/n_z.
//! - Angular error: arccos of the dot product of normalised vectors, in degrees.
//!
//! ## Layers
//! Each folder names only its own modules and the layers below it (`tests/layers.rs` checks
//! it; `ARCHITECTURE.md` of the project draws it), bottom up:
//! - [`base`]: the error type, progress reporting, random numbers, distribution functions,
//!   the machine's memory, number formatting.
//! - [`model`]: images, lights and the per-pixel light model (distant or near), the
//!   [`Capture`] with its sample store, the memory plan. No files.
//! - [`solve`] and [`geometry`], side by side: the Lambertian kernel, the χ² detector and its
//!   attribution, the estimators, consensus, light refinement, plausibility and metrics;
//!   integration of normals into depth and the shadows of a height field.
//! - [`calibrate`] (lights from a mirror sphere) and [`scene`] (ground-truth renders), side by
//!   side.
//! - [`method`]: [`reconstruct`] — `(&Capture, &Params, &dyn Progress) -> Reconstruction`,
//!   every output full frame — the recursive driver and the report's values. It holds no path
//!   and prints nothing.
//! - [`io`]: every format — capture layouts, image readers with size limits, ground truth,
//!   output folders, figures and maps, surfaces and meshes, synthetic capture folders, the
//!   viewer's page.
//! - [`app`]: the file drivers — `run` (load → reconstruct → evaluate → report → export) and
//!   `compare`.
//!
//! The library never prints: progress and cancellation go through
//! [`base::progress::Progress`].

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
