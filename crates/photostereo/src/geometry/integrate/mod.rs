//! Integrating normals into a height field (ALGORITHMS.md §5).
//!
//! Frame and units: the height field f is in pixel units, toward the camera (z); gradients are
//! per pixel, `p = ∂f/∂col = −n_x/n_z` and `q = ∂f/∂row = +n_y/n_z` (row index grows downward,
//! y upward). Depth maps are `height * width` f32, row-major, NaN outside the mask.
//!
//! Every integrator minimises the same discrete energy on the mask's 4-neighbour graph:
//! `Σ_edges w_e (f_b − f_a − d_e)² + λ Σ_i (f_i − prior_i)²`, where the edge target `d_e` is the
//! mean of the two pixels' gradients along the edge (the trapezoid rule, second-order accurate)
//! and `w_e = max(min(w_a, w_b), min_edge_weight)`. Without a prior each connected component is
//! defined up to a constant: its mean is set to zero.
//!
//! - [`Poisson`] solves the normal equations (a graph Laplacian) on any mask by multigrid-
//!   preconditioned conjugate gradients: O(n) per iteration, grid-independent iteration counts.
//! - [`Dct`] solves the same equations on the full rectangle by a DCT (Neumann boundary).
//! - [`Fft`] is Frankot–Chellappa: the least-squares fit in the Fourier basis with the
//!   spectral derivative, on the rectangle mirrored to 2H × 2W (no periodic wrap-around bias).
//! - [`Paths`] averages path integrals along L-shaped scan orders from several seeds (eqs. 11–12).
//!
//! `dct` and `fft` work on the whole rectangle: outside the mask the gradients are taken as 0
//! (a flat apron), which biases the result near the mask's border; use `poisson` on masks.
//!
//! Weights (per pixel, 0..1): pixels whose weight is below `fill_below` are unreliable; their
//! gradients are replaced by a harmonic interpolation (Laplace's equation) of the reliable
//! gradients around them before integration (ALGORITHMS.md §4), so garbage there cannot leak.

mod bilateral;
mod multigrid;
mod paths;
pub mod perspective;
mod poisson;
mod spectral;

pub use bilateral::{
    bilateral_reference, Bilateral, DEFAULT_ENERGY_TOLERANCE, DEFAULT_REWEIGHTINGS,
    DEFAULT_SHARPNESS,
};
pub use paths::Paths;
pub use poisson::{InitialGuess, Poisson};
pub use spectral::{Dct, Fft};

use crate::base::error::{Error, Result};
use crate::base::progress::{Progress, Silent};
use multigrid::{pcg, Hierarchy, Level};
use rayon::prelude::*;
use serde::Serialize;
use std::borrow::Cow;
use std::str::FromStr;

/// Default cap on |p| and |q| (pixel units per pixel): a slope of 20 is 87.1° from the view
/// direction. Normals closer to grazing get their slope clamped.
pub const DEFAULT_MAX_SLOPE: f32 = 20.0;
/// Default relative residual at which `poisson` stops.
pub const DEFAULT_TOLERANCE: f64 = 1e-6;
/// Default weight below which a pixel's gradient is replaced by interpolation.
pub const DEFAULT_FILL_BELOW: f32 = 0.05;
/// Default lower bound of an edge weight (keeps every component connected and solvable).
pub const DEFAULT_MIN_EDGE_WEIGHT: f32 = 1e-3;

/// Peak memory of integrating a normal map with `bilateral` ([`integrate_normal_map`],
/// orthographic or perspective), in bytes per frame pixel beyond the caller's normal map: the
/// gradients and mask (9), the surface and the residual (8), the forward weights (B3) of both
/// axes (8), the two CG work vectors (8) and the coarse multigrid levels with their work
/// vectors (about 7), the finest level's edge weights and inverse diagonal computed row by row;
/// 8 more when some pixels' gradients are filled (weights below `fill_below`). Measured at
/// 4000 × 3000: 40 on the whole frame, 41.5 on the ellipse inscribed in it (`cargo run
/// --release -p photostereo --example integrate_memory -- 4000 3000`). A mask whose bounding
/// box is at most 3/4 of the frame is solved on that box (the same per box pixel, plus copies
/// of the inputs).
pub const BILATERAL_BYTES_PER_PIXEL: usize = 42;

/// Peak memory of integrating a normal map with `poisson`, as [`BILATERAL_BYTES_PER_PIXEL`]:
/// on a mask, the gradients and mask (9), the surface, the residual and the two CG work vectors
/// (16) and the coarse levels (about 7), the finest level's operator computed row by row; on
/// the whole frame with unit weights, the direct DCT solve (two f64 arrays, 16, beside the
/// gradients). Measured at 4000 × 3000: 25 on the whole frame, 33 on the inscribed ellipse.
pub const POISSON_BYTES_PER_PIXEL: usize = 33;

/// Gradients of a height field from a normal map, with the mask of usable pixels.
#[derive(Clone, Debug)]
pub struct Gradients {
    pub width: usize,
    pub height: usize,
    /// `∂f/∂col`, `height * width`, 0 outside the mask.
    pub p: Vec<f32>,
    /// `∂f/∂row`, `height * width`, 0 outside the mask.
    pub q: Vec<f32>,
    /// Pixels with a usable normal (inside the given mask, finite, non-zero, facing the camera).
    pub mask: Vec<bool>,
    /// Pixels of the given mask dropped for a NaN/infinite or zero normal.
    pub rejected_invalid: usize,
    /// Pixels of the given mask dropped because they face away from the camera (`n_z ≤ 0`
    /// orthographic, `n · ray ≥ 0` perspective).
    pub rejected_backfacing: usize,
    /// Without a mask: non-zero vectors left out because they are not of unit length while most
    /// are (a background colour of a normal-map image, e.g. white decoding to (1, 1, 1)).
    pub not_unit: usize,
    /// Pixels whose |p| or |q| was clamped to `max_slope`.
    pub capped: usize,
}

/// Length band `|‖n‖ − 1|` within which a vector counts as a unit normal when no mask is given.
const UNIT_BAND: f64 = 0.1;

/// The default mask of a normal map: the non-zero vectors, less those not of unit length when
/// the map is one of unit normals (see [`Gradients::not_unit`]). A map is taken for one of unit
/// normals when most of its non-zero vectors are of unit length, or when some are and all the
/// others are one and the same vector (a uniform background, e.g. white decoding to (1, 1, 1),
/// however large); a map of scaled normals (albedo times normal), whose lengths vary, keeps
/// every non-zero vector. Returns the mask and the count left out for their length.
pub fn default_mask(normals: &[[f32; 3]]) -> (Vec<bool>, usize) {
    // A NaN or infinite vector is not judged by its length: it stays in the mask, to be
    // counted as invalid with the zero-length ones.
    let length_ok = |v: &[f32; 3]| {
        let l2 = v.iter().map(|&x| x as f64 * x as f64).sum::<f64>();
        !l2.is_finite() || (l2.sqrt() - 1.0).abs() <= UNIT_BAND
    };
    let off_unit = |v: &[f32; 3]| *v != [0.0; 3] && !length_ok(v);
    let (nonzero, unit) = normals
        .par_iter()
        .fold(
            || (0usize, 0usize),
            |(a, b), v| {
                if *v == [0.0; 3] {
                    (a, b)
                } else {
                    (a + 1, b + usize::from(length_ok(v)))
                }
            },
        )
        .reduce(|| (0, 0), |x, y| (x.0 + y.0, x.1 + y.1));
    let uniform_background = unit > 0
        && normals
            .par_iter()
            .find_first(|v| off_unit(v))
            .is_some_and(|first| {
                let first = *first;
                normals.par_iter().all(|v| !off_unit(v) || *v == first)
            });
    let by_length = (unit * 2 > nonzero || uniform_background) && unit < nonzero;
    let mask: Vec<bool> = normals
        .par_iter()
        .map(|v| *v != [0.0; 3] && (!by_length || length_ok(v)))
        .collect();
    (mask, if by_length { nonzero - unit } else { 0 })
}

/// Computes `p = −n_x/n_z`, `q = n_y/n_z` (clamped to ±`max_slope`) over `mask` (default:
/// [`default_mask`]). Bad normals (NaN, zero, `n_z ≤ 0`) are dropped from the mask and
/// counted. Errors on wrong lengths or a non-positive `max_slope`.
pub fn gradients_from_normals(
    width: usize,
    height: usize,
    normals: &[[f32; 3]],
    mask: Option<&[bool]>,
    max_slope: f32,
) -> Result<Gradients> {
    gradients_with(
        width,
        height,
        normals,
        mask,
        max_slope,
        [1.0; 2],
        |_, [x, y, z]| (z > 0.0).then(|| (-x / z, y / z)),
    )
}

/// [`gradients_from_normals`] with the slopes of pixel `i`'s normal `n` given by `slopes(i, n)`
/// (`None`: facing away), clamped to ±`max_slope`, then multiplied by `scale` (along the
/// columns, along the rows).
pub(crate) fn gradients_with(
    width: usize,
    height: usize,
    normals: &[[f32; 3]],
    mask: Option<&[bool]>,
    max_slope: f32,
    scale: [f64; 2],
    slopes: impl Fn(usize, [f64; 3]) -> Option<(f64, f64)> + Sync,
) -> Result<Gradients> {
    let n = width * height;
    if normals.len() != n {
        return Err(Error::invalid(format!(
            "normal map has {} vectors: expected {width}×{height} = {n}",
            normals.len()
        )));
    }
    if let Some(m) = mask {
        if m.len() != n {
            return Err(Error::invalid(format!(
                "mask has {} pixels: expected {width}×{height} = {n}",
                m.len()
            )));
        }
    }
    if !(max_slope > 0.0 && max_slope.is_finite()) {
        return Err(Error::invalid(format!(
            "max_slope {max_slope}: expected a positive finite number"
        )));
    }
    let (default, not_unit) = match mask {
        Some(_) => (Vec::new(), 0),
        None => default_mask(normals),
    };
    let wanted_mask: &[bool] = mask.unwrap_or(&default);
    let mut g = Gradients {
        width,
        height,
        p: vec![0.0; n],
        q: vec![0.0; n],
        mask: vec![false; n],
        rejected_invalid: 0,
        rejected_backfacing: 0,
        not_unit,
        capped: 0,
    };
    let cap = max_slope as f64;
    let w = width.max(1);
    // Rows in parallel; each returns its counts (invalid, back-facing, capped).
    let counts =
        g.p.par_chunks_mut(w)
            .zip(g.q.par_chunks_mut(w))
            .zip(g.mask.par_chunks_mut(w))
            .enumerate()
            .map(|(r, ((p_row, q_row), m_row))| {
                let mut counts = [0usize; 3];
                for c in 0..p_row.len() {
                    let i = r * w + c;
                    if !wanted_mask[i] {
                        continue;
                    }
                    let v = normals[i];
                    let finite = v.iter().all(|x| x.is_finite());
                    let (x, y, z) = (v[0] as f64, v[1] as f64, v[2] as f64);
                    // f32 components cannot overflow a sum of squares in f64; |n| < 1e-12.
                    let tiny = x * x + y * y + z * z < 1e-24;
                    if !finite || tiny {
                        counts[0] += 1;
                        continue;
                    }
                    let Some((p, q)) = slopes(i, [x, y, z]) else {
                        counts[1] += 1;
                        continue;
                    };
                    if p.abs() > cap || q.abs() > cap {
                        counts[2] += 1;
                    }
                    p_row[c] = (p.clamp(-cap, cap) * scale[0]) as f32;
                    q_row[c] = (q.clamp(-cap, cap) * scale[1]) as f32;
                    m_row[c] = true;
                }
                counts
            })
            .reduce(|| [0; 3], |a, b| [a[0] + b[0], a[1] + b[1], a[2] + b[2]]);
    g.rejected_invalid = counts[0];
    g.rejected_backfacing = counts[1];
    g.capped = counts[2];
    Ok(g)
}

/// The integrability map of eq. 10: `curl = (p[r+1,c] − p[r,c]) − (q[r,c+1] − q[r,c])`, defined
/// where the 2×2 block starting at `(r, c)` lies inside the mask, NaN elsewhere. Returns the map
/// and the mean |curl| over the defined pixels (0 when none).
pub fn curl_map(
    width: usize,
    height: usize,
    p: &[f32],
    q: &[f32],
    mask: &[bool],
) -> (Vec<f32>, f64) {
    let mut curl = vec![f32::NAN; width * height];
    let w = width.max(1);
    let (sum, count) = curl
        .par_chunks_mut(w)
        .enumerate()
        .take(height.saturating_sub(1))
        .map(|(r, row)| {
            let (mut sum, mut count) = (0f64, 0usize);
            for (c, out) in row.iter_mut().enumerate().take(width.saturating_sub(1)) {
                let i = r * width + c;
                if mask[i] && mask[i + 1] && mask[i + width] && mask[i + width + 1] {
                    let v = (p[i + width] - p[i]) - (q[i + 1] - q[i]);
                    *out = v;
                    sum += v.abs() as f64;
                    count += 1;
                }
            }
            (sum, count)
        })
        .collect::<Vec<_>>()
        .into_iter()
        .fold((0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    (curl, if count > 0 { sum / count as f64 } else { 0.0 })
}

/// Normals of a depth map by central differences inside the mask (one-sided at its border; a
/// pixel without any neighbour along an axis gets slope 0 along it). Zero outside the mask or
/// where the depth is not finite. The inverse of [`gradients_from_normals`] for testing and
/// shading.
pub fn normals_from_depth(
    width: usize,
    height: usize,
    depth: &[f32],
    mask: &[bool],
) -> Vec<[f32; 3]> {
    let mut out = vec![[0f32; 3]; width * height];
    out.par_chunks_mut(width).enumerate().for_each(|(r, row)| {
        for (c, o) in row.iter_mut().enumerate() {
            *o = normal_from_depth_at(r * width + c, width, height, depth, mask);
        }
    });
    out
}

/// [`normals_from_depth`] at one pixel `i` (row-major): the same value, without the map.
pub fn normal_from_depth_at(
    i: usize,
    width: usize,
    height: usize,
    depth: &[f32],
    mask: &[bool],
) -> [f32; 3] {
    let ok = |i: usize| mask[i] && depth[i].is_finite();
    if !ok(i) {
        return [0.0; 3];
    }
    let d = |a: usize| depth[a] as f64;
    let slope =
        |pair: Option<(usize, usize, f64)>| pair.map_or(0.0, |(a, b, steps)| (d(b) - d(a)) / steps);
    let [along_cols, along_rows] = difference_pairs(i, width, height, ok);
    let (p, q) = (slope(along_cols), slope(along_rows));
    let norm = (p * p + q * q + 1.0).sqrt();
    [(-p / norm) as f32, (q / norm) as f32, (1.0 / norm) as f32]
}

/// The pixels a finite difference at pixel `i` (row-major, `width × height`) takes along the
/// columns and along the rows, among the pixels where `ok` holds: `(a, b, steps)` with `b` one
/// or two pixels after `a` (right of it, or below it) — central (`i − 1, i + 1`, 2 steps) where
/// both neighbours are valid, one-sided (1 step) where one is, `None` where neither is.
pub(crate) fn difference_pairs(
    i: usize,
    width: usize,
    height: usize,
    ok: impl Fn(usize) -> bool,
) -> [Option<(usize, usize, f64)>; 2] {
    let (r, c) = (i / width, i % width);
    let pair = |before: Option<usize>, after: Option<usize>| match (before, after) {
        (Some(a), Some(b)) => Some((a, b, 2.0)),
        (None, Some(b)) => Some((i, b, 1.0)),
        (Some(a), None) => Some((a, i, 1.0)),
        (None, None) => None,
    };
    let valid = |j: usize| ok(j).then_some(j);
    [
        pair(
            (c > 0).then(|| i - 1).and_then(valid),
            (c + 1 < width).then(|| i + 1).and_then(valid),
        ),
        pair(
            (r > 0).then(|| i - width).and_then(valid),
            (r + 1 < height).then(|| i + width).and_then(valid),
        ),
    ]
}

/// A depth prior: the solution is pulled toward `depth` with strength `lambda` per pixel
/// (relative to unit edge weights).
#[derive(Clone, Copy, Debug)]
pub struct Prior<'a> {
    /// `height * width`, pixel units; must be finite inside the mask.
    pub depth: &'a [f32],
    /// ≥ 0.
    pub lambda: f32,
}

/// The input every integrator takes.
#[derive(Clone, Copy, Debug)]
pub struct IntegrationProblem<'a> {
    pub width: usize,
    pub height: usize,
    /// `∂f/∂col`, `height * width`, row-major.
    pub p: &'a [f32],
    /// `∂f/∂row`, `height * width`, row-major.
    pub q: &'a [f32],
    /// Pixels to reconstruct.
    pub mask: &'a [bool],
    /// Per-pixel reliability in 0..1 (1 when absent).
    pub weights: Option<&'a [f32]>,
    pub prior: Option<Prior<'a>>,
    /// A starting point for iterative solvers (`height * width`, the depth's units; values
    /// outside the mask and non-finite ones are ignored), e.g. the last depth when a similar
    /// problem is solved again. It changes the solution only within the solver's tolerance;
    /// direct solvers ignore it.
    pub initial: Option<&'a [f32]>,
}

impl<'a> IntegrationProblem<'a> {
    /// An unweighted problem without prior.
    pub fn new(width: usize, height: usize, p: &'a [f32], q: &'a [f32], mask: &'a [bool]) -> Self {
        IntegrationProblem {
            width,
            height,
            p,
            q,
            mask,
            weights: None,
            prior: None,
            initial: None,
        }
    }

    /// The first pixel of the mask (in scan order) for which `bad` holds; rows are scanned in
    /// parallel.
    fn first_masked(&self, bad: impl Fn(usize) -> bool + Sync) -> Option<usize> {
        let w = self.width;
        (0..self.height)
            .into_par_iter()
            .find_map_first(|r| (r * w..(r + 1) * w).find(|&i| self.mask[i] && bad(i)))
    }

    /// Checks shapes and values; errors name the offending input.
    pub fn validate(&self) -> Result<()> {
        let n = self.width * self.height;
        if self.width == 0 || self.height == 0 {
            return Err(Error::invalid("integration: the grid is empty"));
        }
        for (name, len) in [
            ("p", self.p.len()),
            ("q", self.q.len()),
            ("mask", self.mask.len()),
        ] {
            if len != n {
                return Err(Error::invalid(format!(
                    "integration: {name} has {len} values, expected {}×{} = {n}",
                    self.width, self.height
                )));
            }
        }
        if let Some(i) = self.first_masked(|i| !(self.p[i].is_finite() && self.q[i].is_finite())) {
            return Err(Error::invalid(format!(
                "integration: gradient at row {}, column {} is not finite",
                i / self.width,
                i % self.width
            )));
        }
        if let Some(w) = self.weights {
            if w.len() != n {
                return Err(Error::invalid(format!(
                    "integration: weights have {} values, expected {n}",
                    w.len()
                )));
            }
            if let Some(i) = self.first_masked(|i| !(0.0..=1.0).contains(&w[i])) {
                return Err(Error::invalid(format!(
                    "integration: weight {} at row {}, column {}: expected 0..1",
                    w[i],
                    i / self.width,
                    i % self.width
                )));
            }
        }
        if let Some(prior) = self.prior {
            if prior.depth.len() != n {
                return Err(Error::invalid(format!(
                    "integration: prior depth has {} values, expected {n}",
                    prior.depth.len()
                )));
            }
            if !(prior.lambda >= 0.0 && prior.lambda.is_finite()) {
                return Err(Error::invalid(format!(
                    "integration: prior lambda {}: expected ≥ 0",
                    prior.lambda
                )));
            }
            if let Some(i) = self.first_masked(|i| !prior.depth[i].is_finite()) {
                return Err(Error::invalid(format!(
                    "integration: prior depth at row {}, column {} is not finite",
                    i / self.width,
                    i % self.width
                )));
            }
        }
        Ok(())
    }
}

/// Figures an integrator reports.
#[derive(Clone, Debug, Default, Serialize)]
pub struct IntegrationStats {
    pub method: String,
    /// Solver iterations (CG iterations for `poisson`, paths averaged for `paths`, 0 for direct
    /// methods).
    pub iterations: usize,
    /// Final ‖b − A f‖ / ‖b‖ of the normal equations (`poisson`; 0 otherwise).
    pub relative_residual: f64,
    /// Connected components of the mask.
    pub components: usize,
    /// Pixels whose gradients were interpolated (weight below `fill_below`).
    pub filled_pixels: usize,
    /// Multigrid levels (`poisson`; 0 when solved directly).
    pub levels: usize,
    /// `poisson` only: the mask covered the whole rectangle with unit weights, so its equations
    /// — the same as `dct`'s there — were solved exactly by the DCT (0 iterations; the relative
    /// residual is the true one of the solution).
    pub direct: bool,
    /// `bilateral`: reweighting iterations (solves of the reweighted system before the last).
    pub reweightings: usize,
    pub notes: Vec<String>,
}

/// An integrated height field.
#[derive(Clone, Debug)]
pub struct Depth {
    pub width: usize,
    pub height: usize,
    /// `height * width`, pixel units toward the camera, NaN outside the mask.
    pub values: Vec<f32>,
    pub stats: IntegrationStats,
    /// Discontinuity-preserving integrators: per pixel, how sharply the surface breaks at its
    /// edges (0 continuous … 1 a jump), NaN outside the mask. `None` for the others.
    pub discontinuities: Option<Vec<f32>>,
}

/// Something that turns gradients into depth.
pub trait Integrator: Send + Sync {
    /// The name accepted by `--method`.
    fn name(&self) -> &'static str;
    /// Integrates `problem`; reports progress as stage "integrate".
    fn integrate(&self, problem: &IntegrationProblem, progress: &dyn Progress) -> Result<Depth>;
}

/// The integration methods on offer.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum IntegratorKind {
    /// Masked weighted least squares by multigrid-preconditioned CG (any mask).
    Poisson,
    /// Full-rectangle least squares by DCT (Neumann).
    Dct,
    /// Frankot–Chellappa on the mirrored rectangle.
    Fft,
    /// Averaged path integration (eqs. 11–12).
    Paths,
    /// Discontinuity-preserving bilaterally weighted least squares (any mask; the default: on
    /// real objects with depth jumps it is several times more accurate than `poisson`, and on
    /// smooth surfaces it finds no jump and gives `poisson`'s surface).
    #[default]
    Bilateral,
}

impl IntegratorKind {
    /// Every method, default first.
    pub const ALL: &'static [IntegratorKind] = &[
        IntegratorKind::Bilateral,
        IntegratorKind::Poisson,
        IntegratorKind::Dct,
        IntegratorKind::Fft,
        IntegratorKind::Paths,
    ];

    /// The name accepted by `--method` / `--integrator`.
    pub fn name(self) -> &'static str {
        match self {
            IntegratorKind::Poisson => "poisson",
            IntegratorKind::Dct => "dct",
            IntegratorKind::Fft => "fft",
            IntegratorKind::Paths => "paths",
            IntegratorKind::Bilateral => "bilateral",
        }
    }

    /// The integrator with its default parameters.
    pub fn integrator(self) -> Box<dyn Integrator> {
        match self {
            IntegratorKind::Poisson => Box::new(Poisson::default()),
            IntegratorKind::Dct => Box::new(Dct::default()),
            IntegratorKind::Fft => Box::new(Fft::default()),
            IntegratorKind::Paths => Box::new(Paths::default()),
            IntegratorKind::Bilateral => Box::new(Bilateral::default()),
        }
    }
}

impl IntegratorKind {
    /// The integrator of the recursive method's intermediate surfaces, which serve only its
    /// shadow maps: as [`IntegratorKind::integrator`], except that `bilateral` solves its last
    /// system as (B4) under the converged weights and starts from ½ weights on every mask. (B5)
    /// removes the one-sided slope bias of the exported depth, but on estimated normals that are
    /// wrong near a jump its symmetric targets carry those errors into the surface that casts
    /// the shadows; (B4) keeps them damped, and the recursion's normal errors are those of the
    /// published method (its start from `poisson`'s surface on a whole frame changes the local
    /// optimum the reweighting finds, and with it the shadows).
    pub fn intermediate_integrator(self) -> Box<dyn Integrator> {
        match self {
            IntegratorKind::Bilateral => Box::new(Bilateral::intermediate()),
            other => other.integrator(),
        }
    }
}

impl FromStr for IntegratorKind {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        crate::base::error::parse_name(
            s,
            IntegratorKind::ALL,
            IntegratorKind::name,
            "integration method",
        )
    }
}

/// Integrates a normal map (`height * width` vectors in the camera frame) over `mask` (default:
/// non-zero normals) with optional per-pixel `weights` (0..1), using `method` with its default
/// parameters and [`DEFAULT_MAX_SLOPE`]. Bad normals are masked out (NaN depth there).
pub fn integrate_normals(
    width: usize,
    height: usize,
    normals: &[[f32; 3]],
    mask: Option<&[bool]>,
    weights: Option<&[f32]>,
    method: IntegratorKind,
) -> Result<Depth> {
    let g = gradients_from_normals(width, height, normals, mask, DEFAULT_MAX_SLOPE)?;
    let problem = IntegrationProblem {
        weights,
        ..IntegrationProblem::new(width, height, &g.p, &g.q, &g.mask)
    };
    method.integrator().integrate(&problem, &Silent)
}

/// How a reconstruction's normals are integrated. One value serves both the recursive
/// method's intermediate surfaces and the exported depth.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct IntegrationParams {
    /// The integrator (default `bilateral`; it and `poisson` honour any mask and weights).
    #[serde(serialize_with = "serialize_kind")]
    pub method: IntegratorKind,
    /// Cap on |p| and |q| in pixel units per pixel (default [`DEFAULT_MAX_SLOPE`]).
    #[serde(serialize_with = "crate::base::number::serialize_f32")]
    pub max_slope: f32,
    /// Integration weight of unreliable pixels, relative to 1 for a reliable one. Default 0.1:
    /// one tenth, so that the surface there follows the reliable surroundings (the paper's
    /// interpolation) while keeping the detail of estimates that are merely uncertain.
    #[serde(serialize_with = "crate::base::number::serialize_f32")]
    pub unreliable_weight: f32,
}

fn serialize_kind<S: serde::Serializer>(
    k: &IntegratorKind,
    s: S,
) -> std::result::Result<S::Ok, S::Error> {
    s.serialize_str(k.name())
}

impl Default for IntegrationParams {
    fn default() -> Self {
        IntegrationParams {
            method: IntegratorKind::default(),
            max_slope: DEFAULT_MAX_SLOPE,
            unreliable_weight: 0.1,
        }
    }
}

impl IntegrationParams {
    /// Checks the domains; errors name the parameter.
    pub fn validate(&self) -> Result<()> {
        if !(self.max_slope.is_finite() && self.max_slope > 0.0) {
            return Err(Error::parameter(
                "max_slope",
                format!("{}: expected a finite positive slope", self.max_slope),
            ));
        }
        if !(0.0..=1.0).contains(&self.unreliable_weight) {
            return Err(Error::parameter(
                "unreliable_weight",
                format!("{}: expected a value in [0, 1]", self.unreliable_weight),
            ));
        }
        Ok(())
    }
}

/// The one weighting rule of a reconstruction's integration (ALGORITHMS.md §4), used by the
/// recursive method for its intermediate surfaces and by the engine for the exported depth.
///
/// `normals` and `trust` are full frame (`height * width`); `trust` is each pixel's weight in
/// 0..1 (1 where absent: a trusted estimate, a low weight for an unreliable one, 0 for none).
/// A pixel without a usable normal (zero, non-finite or `n_z ≤ 0`) gets weight 0 and the
/// placeholder normal (0, 0, 1): integration fills it from its surroundings rather than leaving
/// a hole. Outside `mask` the weight is 0. Returns (normals to integrate, weights).
pub fn weighted_normals(
    normals: &[[f32; 3]],
    mask: &[bool],
    trust: Option<&[f32]>,
) -> (Vec<[f32; 3]>, Vec<f32>) {
    let mut out = vec![[0f32; 3]; normals.len()];
    let mut weights = vec![0f32; normals.len()];
    out.par_iter_mut()
        .zip(weights.par_iter_mut())
        .enumerate()
        .for_each(|(i, (o, w))| {
            if !mask[i] {
                return;
            }
            (*o, *w) = weighted_normal(normals[i], trust.map_or(1.0, |t| t[i]));
        });
    (out, weights)
}

/// One mask pixel's normal to integrate and weight under [`weighted_normals`]' rule.
#[inline]
fn weighted_normal(n: [f32; 3], t: f32) -> ([f32; 3], f32) {
    let usable = n.iter().all(|v| v.is_finite()) && n[2] > 0.0 && t > 0.0;
    if usable {
        (n, t)
    } else {
        ([0.0, 0.0, 1.0], 0.0)
    }
}

/// [`weighted_normals`] from the estimate of the mask pixels alone: `normals[p]` and
/// `trust(p, i)` belong to mask pixel `p` at flat frame index `pixels[p]` (ascending) of a
/// `frame_len`-pixel frame. The same maps, without a full-frame copy of the estimate.
pub fn weighted_normals_at(
    frame_len: usize,
    pixels: &[u32],
    normals: &[[f32; 3]],
    trust: &dyn Fn(usize, usize) -> f32,
) -> (Vec<[f32; 3]>, Vec<f32>) {
    let mut out = vec![[0f32; 3]; frame_len];
    let mut weights = vec![0f32; frame_len];
    for (p, (&i, &n)) in pixels.iter().zip(normals).enumerate() {
        let i = i as usize;
        (out[i], weights[i]) = weighted_normal(n, trust(p, i));
    }
    (out, weights)
}

/// A depth map with its diagnostics: what `run` and `photostereo integrate` write.
#[derive(Clone, Debug)]
pub struct Surface {
    pub depth: Depth,
    /// Eq. 10's map, NaN where undefined.
    pub curl: Vec<f32>,
    pub mean_abs_curl: f64,
    pub rejected_invalid: usize,
    pub rejected_backfacing: usize,
    /// See [`Gradients::not_unit`].
    pub not_unit: usize,
    pub capped: usize,
    pub max_slope: f32,
}

impl Surface {
    /// Pixels the integrator found on a jump (discontinuity above ½; 0 for integrators that do
    /// not look for jumps).
    pub fn discontinuity_pixels(&self) -> usize {
        self.depth
            .discontinuities
            .as_ref()
            .map_or(0, |d| d.par_iter().filter(|&&v| v > 0.5).count())
    }

    /// The figures for `report.json`.
    pub fn summary(&self) -> serde_json::Value {
        serde_json::json!({
            "method": self.depth.stats.method,
            "iterations": self.depth.stats.iterations,
            "relative_residual": self.depth.stats.relative_residual,
            "levels": self.depth.stats.levels,
            "direct": self.depth.stats.direct,
            "components": self.depth.stats.components,
            "filled_pixels": self.depth.stats.filled_pixels,
            "mean_abs_curl": self.mean_abs_curl,
            "max_slope": self.max_slope,
            "capped_pixels": self.capped,
            "rejected_invalid_normals": self.rejected_invalid,
            "rejected_backfacing_normals": self.rejected_backfacing,
            "not_unit_normals": self.not_unit,
            "reweightings": self.depth.stats.reweightings,
            "discontinuity_pixels": self.discontinuity_pixels(),
            "notes": self.depth.stats.notes,
        })
    }
}

/// Gradients, curl and depth from a normal map in one call.
#[allow(clippy::too_many_arguments)]
pub fn surface_from_normals(
    width: usize,
    height: usize,
    normals: &[[f32; 3]],
    mask: Option<&[bool]>,
    weights: Option<&[f32]>,
    integrator: &dyn Integrator,
    max_slope: f32,
    progress: &dyn Progress,
) -> Result<Surface> {
    let g = gradients_from_normals(width, height, normals, mask, max_slope)?;
    surface_from_gradients(g, weights, integrator, max_slope, progress)
}

/// How [`integrate_normal_map`] integrates a normal map.
#[derive(Clone, Copy, Debug)]
pub struct NormalMapIntegration<'a> {
    /// The integrator, with its default parameters (default `bilateral`).
    pub method: IntegratorKind,
    /// Cap on the slopes, pixels per pixel (default [`DEFAULT_MAX_SLOPE`]).
    pub max_slope: f32,
    /// A pinhole camera and the object's mean distance along its axis (mm): the depth is then
    /// Z in mm ([`perspective::perspective_surface`]); `None`, heights in pixels.
    pub camera: Option<(&'a crate::model::lightmodel::Camera, f64)>,
}

impl Default for NormalMapIntegration<'_> {
    fn default() -> Self {
        NormalMapIntegration {
            method: IntegratorKind::default(),
            max_slope: DEFAULT_MAX_SLOPE,
            camera: None,
        }
    }
}

/// A normal map (`height * width` vectors, row-major) into a [`Surface`], orthographic or
/// through a camera: the entry point of the front ends. `mask` defaults to [`default_mask`];
/// `weights` (0..1) trust each pixel. The result holds the depth (NaN outside the integrated
/// pixels), the curl map, the discontinuity map of `bilateral` (`depth.discontinuities`), the
/// counts of dropped and capped pixels and the integrator's figures and notes. Errors name
/// the parameter at fault (`max_slope`, `distance`, wrong lengths).
pub fn integrate_normal_map(
    width: usize,
    height: usize,
    normals: &[[f32; 3]],
    mask: Option<&[bool]>,
    weights: Option<&[f32]>,
    how: &NormalMapIntegration,
    progress: &dyn Progress,
) -> Result<Surface> {
    let integrator = how.method.integrator();
    match how.camera {
        Some((camera, distance)) => {
            if !(distance.is_finite() && distance > 0.0) {
                return Err(Error::parameter(
                    "distance",
                    format!("{distance}: expected the object's mean distance in mm, positive"),
                ));
            }
            perspective::perspective_surface(
                width,
                height,
                normals,
                mask,
                weights,
                camera,
                distance,
                integrator.as_ref(),
                how.max_slope,
                progress,
            )
        }
        None => surface_from_normals(
            width,
            height,
            normals,
            mask,
            weights,
            integrator.as_ref(),
            how.max_slope,
            progress,
        ),
    }
}

/// [`surface_from_normals`] from gradients already taken (`max_slope` the cap they were
/// taken with): the caller can drop its normal map before the integrator runs.
pub fn surface_from_gradients(
    g: Gradients,
    weights: Option<&[f32]>,
    integrator: &dyn Integrator,
    max_slope: f32,
    progress: &dyn Progress,
) -> Result<Surface> {
    let (width, height) = (g.width, g.height);
    let problem = IntegrationProblem {
        weights,
        ..IntegrationProblem::new(width, height, &g.p, &g.q, &g.mask)
    };
    let depth = integrator.integrate(&problem, progress)?;
    // The curl map is made after the solve: not held beside the integrator's work arrays.
    let (curl, mean_abs_curl) = curl_map(width, height, &g.p, &g.q, &g.mask);
    Ok(Surface {
        depth,
        curl,
        mean_abs_curl,
        rejected_invalid: g.rejected_invalid,
        rejected_backfacing: g.rejected_backfacing,
        not_unit: g.not_unit,
        capped: g.capped,
        max_slope,
    })
}

// ---------------------------------------------------------------------------------------------
// Shared machinery.

/// The 4-connected components of a mask.
pub(crate) struct Components {
    /// Component of each pixel; whole grid (one component) without labels, which saves a label
    /// per pixel on the common full grid; one byte per pixel for fewer than 255 components.
    labels: Labels,
    /// Number of components.
    pub count: usize,
}

/// A view of [`Components`]' labels (`MAX` outside the mask).
pub(crate) enum LabelSlice<'a> {
    Whole,
    Small(&'a [u8]),
    Large(&'a [u32]),
}

/// Per-pixel component labels (`MAX` outside the mask).
enum Labels {
    Whole,
    Small(Vec<u8>),
    Large(Vec<u32>),
}

impl Components {
    /// Labels the components of `mask` (`width * height`).
    pub fn of(width: usize, height: usize, mask: &[bool]) -> Components {
        let n = width * height;
        if mask.par_iter().all(|&m| m) {
            return Components {
                labels: Labels::Whole,
                count: usize::from(n > 0),
            };
        }
        let mut labels = vec![u32::MAX; n];
        let mut count = 0u32;
        let mut stack: Vec<u32> = Vec::new();
        for seed in 0..n {
            if !mask[seed] || labels[seed] != u32::MAX {
                continue;
            }
            labels[seed] = count;
            stack.push(seed as u32);
            while let Some(i) = stack.pop() {
                let i = i as usize;
                let (r, c) = (i / width, i % width);
                let mut visit = |j: usize| {
                    if mask[j] && labels[j] == u32::MAX {
                        labels[j] = count;
                        stack.push(j as u32);
                    }
                };
                if c > 0 {
                    visit(i - 1);
                }
                if c + 1 < width {
                    visit(i + 1);
                }
                if r > 0 {
                    visit(i - width);
                }
                if r + 1 < height {
                    visit(i + width);
                }
            }
            count += 1;
        }
        let labels = if count < u8::MAX as u32 {
            Labels::Small(
                labels
                    .par_iter()
                    .map(|&l| if l == u32::MAX { u8::MAX } else { l as u8 })
                    .collect(),
            )
        } else {
            Labels::Large(labels)
        };
        Components {
            labels,
            count: count as usize,
        }
    }

    /// The component of pixel `i` (`None` outside the mask).
    #[inline]
    pub fn label(&self, i: usize) -> Option<usize> {
        match &self.labels {
            Labels::Whole => Some(0),
            Labels::Small(l) => (l[i] != u8::MAX).then_some(l[i] as usize),
            Labels::Large(l) => (l[i] != u32::MAX).then_some(l[i] as usize),
        }
    }

    /// The labels.
    pub fn labels(&self) -> LabelSlice<'_> {
        match &self.labels {
            Labels::Whole => LabelSlice::Whole,
            Labels::Small(l) => LabelSlice::Small(l),
            Labels::Large(l) => LabelSlice::Large(l),
        }
    }

    /// Whether the mask covers the whole grid (one component, no labels).
    pub fn is_whole_grid(&self) -> bool {
        matches!(self.labels, Labels::Whole)
    }

    /// The means of `a` (and of `b` when given) over each component's pixels (labelled masks),
    /// in one pass. Summed over threads when the components are few, else in one thread.
    fn labelled_means<T: Sample, U: Sample>(&self, a: &[T], b: Option<&[U]>) -> [Vec<f64>; 2] {
        match &self.labels {
            Labels::Whole => unreachable!("labelled means of a whole grid"),
            Labels::Small(l) => labelled_means_of(l, self.count, a, b),
            Labels::Large(l) => labelled_means_of(l, self.count, a, b),
        }
    }

    /// The mean of `f` over each component (sums in f64).
    pub fn means<T: Sample>(&self, f: &[T]) -> Vec<f64> {
        if self.is_whole_grid() {
            let sum = f
                .par_chunks(1 << 14)
                .map(|c| c.iter().map(|&v| v.to_f64()).sum::<f64>())
                .collect::<Vec<f64>>()
                .into_iter()
                .sum::<f64>();
            return vec![sum / f.len().max(1) as f64];
        }
        let [m, _] = self.labelled_means::<T, T>(f, None);
        m
    }

    /// Subtracts each component's mean from `f` (values outside the mask are left alone) and
    /// returns the means of `other` over each component, taken in the same pass (labelled
    /// masks; empty on the whole grid).
    pub fn remove_means_and_measure<T: Sample, U: Sample>(
        &self,
        f: &mut [T],
        other: Option<&[U]>,
    ) -> Vec<f64> {
        if self.is_whole_grid() {
            let mean = self.means(f)[0];
            f.par_iter_mut()
                .for_each(|v| *v = T::from_f64(v.to_f64() - mean));
            return Vec::new();
        }
        let [mean, other_means] = self.labelled_means(f, other);
        fn subtract<L: LabelInt, T: Sample>(labels: &[L], f: &mut [T], mean: &[f64]) {
            f.par_chunks_mut(1 << 14)
                .zip(labels.par_chunks(1 << 14))
                .for_each(|(fs, ls)| {
                    for (v, &l) in fs.iter_mut().zip(ls) {
                        if let Some(l) = l.get() {
                            *v = T::from_f64(v.to_f64() - mean[l]);
                        }
                    }
                });
        }
        match &self.labels {
            Labels::Whole => {}
            Labels::Small(l) => subtract(l, f, &mean),
            Labels::Large(l) => subtract(l, f, &mean),
        }
        other_means
    }

    /// Subtracts each component's mean from `f` (values outside the mask are left alone).
    pub fn remove_means<T: Sample>(&self, f: &mut [T]) {
        self.remove_means_and_measure::<T, T>(f, None);
    }
}

/// A stored component label (`MAX` outside the mask).
trait LabelInt: Copy + Send + Sync {
    fn get(self) -> Option<usize>;
}

impl LabelInt for u8 {
    #[inline]
    fn get(self) -> Option<usize> {
        (self != u8::MAX).then_some(self as usize)
    }
}

impl LabelInt for u32 {
    #[inline]
    fn get(self) -> Option<usize> {
        (self != u32::MAX).then_some(self as usize)
    }
}

/// Per-component means of `a` and `b` (see [`Components::labelled_means`]).
fn labelled_means_of<L: LabelInt, T: Sample, U: Sample>(
    labels: &[L],
    k: usize,
    a: &[T],
    b: Option<&[U]>,
) -> [Vec<f64>; 2] {
    const BLOCK: usize = 1 << 16;
    let nb = usize::from(b.is_some());
    // Sums of a, of b, and counts, per component.
    let sums = |lo: usize, hi: usize| {
        let mut acc = vec![[0f64; 3]; k];
        let ls = &labels[lo..hi];
        match b {
            Some(b) => {
                for ((&l, &x), &y) in ls.iter().zip(&a[lo..hi]).zip(&b[lo..hi]) {
                    if let Some(l) = l.get() {
                        let s = &mut acc[l];
                        s[0] += x.to_f64();
                        s[1] += y.to_f64();
                        s[2] += 1.0;
                    }
                }
            }
            None => {
                for (&l, &x) in ls.iter().zip(&a[lo..hi]) {
                    if let Some(l) = l.get() {
                        let s = &mut acc[l];
                        s[0] += x.to_f64();
                        s[2] += 1.0;
                    }
                }
            }
        }
        acc
    };
    let n = labels.len();
    if k == 1 {
        // One component (the common masked case): branch-free sums in independent lanes.
        const LANES: usize = 8;
        let part = |lo: usize, hi: usize| {
            let mut acc = [[0f64; LANES]; 3];
            let (ls, xs) = (&labels[lo..hi], &a[lo..hi]);
            let ys = b.map(|b| &b[lo..hi]);
            for (j, (lc, xc)) in ls.chunks(LANES).zip(xs.chunks(LANES)).enumerate() {
                for (q, (&l, &x)) in lc.iter().zip(xc).enumerate() {
                    // Selects, not products: values outside the mask may be NaN.
                    let on = l.get().is_some();
                    acc[0][q] += if on { x.to_f64() } else { 0.0 };
                    acc[2][q] += if on { 1.0 } else { 0.0 };
                    if let Some(ys) = ys {
                        acc[1][q] += if on { ys[j * LANES + q].to_f64() } else { 0.0 };
                    }
                }
            }
            acc.map(|l| l.iter().sum::<f64>())
        };
        let t = (0..n.div_ceil(BLOCK))
            .into_par_iter()
            .map(|t| part(t * BLOCK, ((t + 1) * BLOCK).min(n)))
            .collect::<Vec<_>>()
            .into_iter()
            .fold([0f64; 3], |x, y| [x[0] + y[0], x[1] + y[1], x[2] + y[2]]);
        let c = t[2].max(1.0);
        return [
            vec![t[0] / c],
            if nb > 0 { vec![t[1] / c] } else { Vec::new() },
        ];
    }
    let acc = if k <= 64 {
        (0..n.div_ceil(BLOCK))
            .into_par_iter()
            .map(|t| sums(t * BLOCK, ((t + 1) * BLOCK).min(n)))
            .collect::<Vec<_>>()
            .into_iter()
            .fold(vec![[0f64; 3]; k], |mut acc, part| {
                for (x, y) in acc.iter_mut().zip(&part) {
                    for j in 0..3 {
                        x[j] += y[j];
                    }
                }
                acc
            })
    } else {
        sums(0, n)
    };
    let mean = |j: usize| {
        acc.iter()
            .map(|s| s[j] / s[2].max(1.0))
            .collect::<Vec<f64>>()
    };
    [mean(0), if nb > 0 { mean(1) } else { Vec::new() }]
}

/// A stored value (f32 or f64) whose sums are taken in f64.
pub(crate) trait Sample: Copy + Send + Sync {
    fn to_f64(self) -> f64;
    fn from_f64(v: f64) -> Self;
}

impl Sample for f32 {
    fn to_f64(self) -> f64 {
        self as f64
    }
    fn from_f64(v: f64) -> Self {
        v as f32
    }
}

impl Sample for f64 {
    fn to_f64(self) -> f64 {
        self
    }
    fn from_f64(v: f64) -> Self {
        v
    }
}

/// Edge targets: `dh[i]` for the edge `i → i + 1`, `dv[i]` for `i → i + w` (mean of the two
/// pixels' gradients; 0 where the edge leaves the mask).
pub(crate) fn edge_targets(
    width: usize,
    height: usize,
    p: &[f32],
    q: &[f32],
    mask: &[bool],
) -> (Vec<f32>, Vec<f32>) {
    let n = width * height;
    let mut dh = vec![0f32; n];
    let mut dv = vec![0f32; n];
    dh.par_chunks_mut(width)
        .zip(dv.par_chunks_mut(width))
        .enumerate()
        .for_each(|(r, (hrow, vrow))| {
            for c in 0..width {
                let i = r * width + c;
                if !mask[i] {
                    continue;
                }
                if c + 1 < width && mask[i + 1] {
                    hrow[c] = 0.5 * (p[i] + p[i + 1]);
                }
                if r + 1 < height && mask[i + width] {
                    vrow[c] = 0.5 * (q[i] + q[i + width]);
                }
            }
        });
    (dh, dv)
}

/// Gradients with the pixels of weight below `fill_below` replaced by the harmonic interpolation
/// of the others (Laplace's equation on the mask graph, Dirichlet data from reliable neighbours;
/// a component without reliable pixels gets zero gradients). Returns `(p, q, filled_count)`.
///
/// Memory: the two copies of the gradients (f32), plus [`fill_unreliable_in_place`]'s.
pub(crate) fn fill_unreliable<'a>(
    problem: &IntegrationProblem<'a>,
    fill_below: f32,
) -> (Cow<'a, [f32]>, Cow<'a, [f32]>, usize) {
    let unchanged = (Cow::Borrowed(problem.p), Cow::Borrowed(problem.q), 0);
    let Some(weights) = problem.weights else {
        return unchanged;
    };
    let (w, h, mask) = (problem.width, problem.height, problem.mask);
    if count_holes(w, h, mask, weights, fill_below) == 0 {
        return unchanged;
    }
    let (mut p, mut q) = (problem.p.to_vec(), problem.q.to_vec());
    let filled = fill_unreliable_in_place(w, h, mask, weights, fill_below, &mut p, &mut q);
    (Cow::Owned(p), Cow::Owned(q), filled)
}

/// The mask pixels of weight below `fill_below`.
fn count_holes(w: usize, h: usize, mask: &[bool], weights: &[f32], fill_below: f32) -> usize {
    (0..h)
        .into_par_iter()
        .map(|r| {
            (r * w..(r + 1) * w)
                .filter(|&i| mask[i] && weights[i] < fill_below)
                .count()
        })
        .sum::<usize>()
}

/// [`fill_unreliable`] in the gradients' own buffers `p` and `q` (`h * w`): the same values,
/// without the copies. Returns the number of pixels filled.
///
/// Memory: while each gradient is solved, the multigrid CG's work (three f32 vectors and the
/// coarse levels); the holes' operator is computed from the mask and weights, not stored.
pub(crate) fn fill_unreliable_in_place(
    w: usize,
    h: usize,
    mask: &[bool],
    weights: &[f32],
    fill_below: f32,
    p: &mut [f32],
    q: &mut [f32],
) -> usize {
    let is_hole = |i: usize| mask[i] && weights[i] < fill_below;
    let filled = count_holes(w, h, mask, weights, fill_below);
    if filled == 0 {
        return 0;
    }
    let n = w * h;
    // Components of the holes without any reliable neighbour get one pinned cell (zero gradient).
    let pins = {
        let hole: Vec<bool> = (0..n).into_par_iter().map(is_hole).collect();
        let components = Components::of(w, h, &hole);
        let mut anchored = vec![false; components.count];
        let mut first = vec![usize::MAX; components.count];
        for i in 0..n {
            let Some(l) = components.label(i) else {
                continue;
            };
            if first[l] == usize::MAX {
                first[l] = i;
            }
            let (r, c) = (i / w, i % w);
            let reliable = |j: usize| mask[j] && !hole[j];
            anchored[l] |= (c > 0 && reliable(i - 1))
                || (c + 1 < w && reliable(i + 1))
                || (r > 0 && reliable(i - w))
                || (r + 1 < h && reliable(i + w));
        }
        (0..components.count)
            .filter(|&l| !anchored[l])
            .map(|l| first[l])
            .collect::<Vec<usize>>()
    };
    let mut hier = Hierarchy::new(Level::fill(w, h, mask, weights, fill_below, pins));
    // Each gradient is solved in place: the holes start at 0, the other cells are inactive
    // (never read through a non-zero weight, never written).
    let mut solve_in_place = |x: &mut [f32]| {
        x.par_iter_mut().enumerate().for_each(|(i, v)| {
            if is_hole(i) {
                *v = 0.0;
            }
        });
        let g = &*x;
        let mut r: Vec<f32> = multigrid::par_zeros(n);
        // b_i: the sum of the gradient over the hole's reliable neighbours.
        let b_norm2 = hier.fine().residual_from(
            |row, _, b| {
                for (c, bv) in b.iter_mut().enumerate() {
                    let i = row * w + c;
                    *bv = 0.0;
                    if !is_hole(i) {
                        continue;
                    }
                    let nbrs = [
                        (c > 0, i.wrapping_sub(1)),
                        (c + 1 < w, i + 1),
                        (row > 0, i.wrapping_sub(w)),
                        (row + 1 < h, i + w),
                    ];
                    for (ok, j) in nbrs {
                        if ok && mask[j] && !is_hole(j) {
                            *bv += g[j] as f64;
                        }
                    }
                }
            },
            None,
            &mut r,
        );
        pcg(
            &mut hier,
            &mut r,
            b_norm2.sqrt(),
            x,
            None,
            1e-6,
            200,
            &Silent,
        );
    };
    solve_in_place(p);
    solve_in_place(q);
    filled
}

/// Converts a solution to a depth map (NaN outside the mask).
pub(crate) fn to_depth(
    width: usize,
    height: usize,
    f: &[f64],
    mask: &[bool],
    stats: IntegrationStats,
) -> Depth {
    let values = f
        .par_iter()
        .zip(mask.par_iter())
        .map(|(&v, &m)| if m { v as f32 } else { f32::NAN })
        .collect();
    Depth {
        width,
        height,
        values,
        stats,
        discontinuities: None,
    }
}

/// A solution computed in place in f32 made a depth map: NaN outside the mask (no copy).
pub(crate) fn into_depth(
    width: usize,
    height: usize,
    mut values: Vec<f32>,
    mask: &[bool],
    stats: IntegrationStats,
) -> Depth {
    values
        .par_iter_mut()
        .zip(mask.par_iter())
        .for_each(|(v, &m)| {
            if !m {
                *v = f32::NAN;
            }
        });
    Depth {
        width,
        height,
        values,
        stats,
        discontinuities: None,
    }
}
