//! The RBF basis of relight (CNR-ISTI) as its `mrgb` colour space stores it: the readings of a
//! pixel under the N lights, one vector x ∈ R^D (D = N·C, light-major, channels interleaved),
//! are modelled as x ≈ μ + Σ_j c_j e_j, with μ the mean over pixels and e_1…e_P the leading
//! principal components (unit vectors) of the pixels' readings: P coefficients per pixel (the
//! "planes"), shared by the channels. Under a light l that was not photographed the mean and
//! each component are interpolated over the lights by normalised Gaussian weights
//!
//!   w_i(l) = exp(−|l − l_i|² / σ²) / Σ_m exp(−|l − l_m|² / σ²),
//!
//! after which the weights below [`MIN_WEIGHT`] are dropped and the rest renormalised (the rule
//! relight's renderer and OpenLIME's RTI shader apply, so a file renders as the fit predicts).
//! The prediction is I_c(l) = Σ_i w_i(l) (μ_{i,c} + Σ_j c_j e_{j,i,c}).
//!
//! σ (a chord length) is chosen per capture ([`Width::Auto`]): the default is the median over
//! the lights of the chord distance to the nearest other light (the kernel reaches a light's
//! neighbours and no further, whatever the rig's density), and of the half octaves
//! [`SIGMA_FACTORS`] × that default the one with the least exact leave-one-out error over a
//! regular sample of mask pixels is kept, the default on a tie. The fit's σ is the one the
//! written files carry, so a renderer weights the lights as the chosen fit predicts.
//!
//! Leave-one-out: the fit without light k is the PCA of the same pixels' readings without
//! light k's C entries — the mean without them and the eigenvectors of the covariance with
//! light k's rows and columns deleted — the projection of the pixel's other readings on it,
//! and the kernel interpolation at l_k over the other lights. All of it is linear in the
//! pixel's readings, so the prediction of light k is a_{k,c} + W_{k,c} · x (W zero on light k's
//! entries), precomputed once per light: exact, and N·C·D operations a pixel. The PCA without
//! light k does not depend on σ, so each candidate σ costs only its predictors and the sample's
//! N·C·D operations a pixel.
//!
//! The PCA uses up to [`PCA_PIXELS`] evenly spaced mask pixels (as relight samples its
//! pixels); the covariance is D × D in f64, `8 · D²` bytes.

use super::{display_gain, CoefficientSink, RelightErrors, RtiFit, BLOCK_PIXELS, MAX_TERMS};
use crate::base::error::{Error, Result};
use crate::model::capture::Capture;
use nalgebra::{DMatrix, SymmetricEigen};
use rayon::prelude::*;

/// Principal components kept: the coefficient planes of each pixel (three RGB images).
pub const PLANES: usize = MAX_TERMS;
/// Normalised kernel weights below this are dropped (relight's and OpenLIME's rule).
pub const MIN_WEIGHT: f64 = 0.001;
/// Mask pixels the PCA samples at most.
pub const PCA_PIXELS: usize = 65_536;

/// The model shared by every pixel of an RBF fit: the lights, the kernel width, the mean and
/// the principal components (display units; `[light][channel]` within each vector).
#[derive(Clone, Debug, PartialEq)]
pub struct RbfModel {
    /// The light directions (unit, camera frame).
    pub lights: Vec<[f64; 3]>,
    /// Kernel width σ (chord length on the unit sphere).
    pub sigma: f64,
    /// Channels C per light.
    pub channels: usize,
    /// Mean reading μ, D = N·C values.
    pub mean: Vec<f64>,
    /// The P principal components, `[plane][D]`, unit length.
    pub planes: Vec<f64>,
    /// Share of the readings' variance (about the mean) the P components hold.
    pub explained_variance: f64,
    /// Pixels the PCA sampled.
    pub pca_pixels: usize,
}

impl RbfModel {
    /// The kernel weights at `l` over the lights (with light `skip` left out), into `w`.
    pub fn weights(&self, l: [f64; 3], skip: Option<usize>, w: &mut [f64]) {
        kernel_weights(&self.lights, self.sigma, l, skip, w);
    }

    /// The mean and the components interpolated at `l`: `[1 + P][channel]` into `out`.
    pub fn light_basis(&self, l: [f64; 3], out: &mut [f64]) {
        let (n, c) = (self.lights.len(), self.channels);
        let mut w = vec![0.0; n];
        self.weights(l, None, &mut w);
        let d = n * c;
        out[..(PLANES + 1) * c].fill(0.0);
        for (i, &wi) in w.iter().enumerate().filter(|(_, &wi)| wi > 0.0) {
            for ch in 0..c {
                out[ch] += wi * self.mean[i * c + ch];
                for j in 0..PLANES {
                    out[(j + 1) * c + ch] += wi * self.planes[j * d + i * c + ch];
                }
            }
        }
    }
}

/// Normalised Gaussian weights of the unit light `l` over `lights` (light `skip` weighted 0),
/// the small ones dropped and the rest renormalised, into `w`.
pub fn kernel_weights(
    lights: &[[f64; 3]],
    sigma: f64,
    l: [f64; 3],
    skip: Option<usize>,
    w: &mut [f64],
) {
    let radius = 1.0 / (sigma * sigma);
    for (i, li) in lights.iter().enumerate() {
        let d2 = (0..3).map(|a| (li[a] - l[a]) * (li[a] - l[a])).sum::<f64>();
        w[i] = if Some(i) == skip {
            0.0
        } else {
            (-radius * d2).exp()
        };
    }
    let total: f64 = w.iter().sum();
    if total <= 0.0 || !total.is_finite() {
        // Every light is too far for the kernel (underflow): the nearest takes all.
        let nearest = (0..lights.len())
            .filter(|&i| Some(i) != skip)
            .min_by(|&a, &b| {
                let d = |i: usize| (0..3).map(|x| (lights[i][x] - l[x]).powi(2)).sum::<f64>();
                d(a).total_cmp(&d(b))
            });
        w.fill(0.0);
        if let Some(i) = nearest {
            w[i] = 1.0;
        }
        return;
    }
    let mut kept = 0.0;
    for x in w.iter_mut() {
        *x /= total;
        if *x > MIN_WEIGHT {
            kept += *x;
        } else {
            *x = 0.0;
        }
    }
    for x in w.iter_mut() {
        *x /= kept;
    }
}

/// The kernel width: the median over the lights of the chord distance to the nearest other.
pub fn kernel_width(lights: &[[f64; 3]]) -> f64 {
    let mut nn: Vec<f64> = (0..lights.len())
        .map(|i| {
            (0..lights.len())
                .filter(|&j| j != i)
                .map(|j| {
                    (0..3)
                        .map(|a| (lights[i][a] - lights[j][a]).powi(2))
                        .sum::<f64>()
                        .sqrt()
                })
                .fold(f64::INFINITY, f64::min)
        })
        .collect();
    nn.sort_by(f64::total_cmp);
    nn[nn.len() / 2]
}

/// Mean and covariance (D × D) of the readings × `gain` of up to [`PCA_PIXELS`] evenly spaced
/// mask pixels; returns them with the number of pixels used.
fn moments(capture: &Capture, gain: f64) -> Result<(Vec<f64>, DMatrix<f64>, usize)> {
    let (np, d) = (capture.n_pixels(), capture.n_lights() * capture.channels);
    let ids = super::sample_ids(np, PCA_PIXELS);
    let view = super::sample_view(capture, &ids)?;
    let m = ids.len();
    let mut mean = vec![0.0; d];
    for &p in &ids {
        for (a, &x) in mean.iter_mut().zip(view.pixel_samples(p)) {
            *a += f64::from(x) * gain;
        }
    }
    mean.iter_mut().for_each(|a| *a /= m as f64);
    // Σ (x − μ)(x − μ)ᵀ by blocks of pixels (a block's centred readings as a matrix).
    const BLOCK: usize = 2048;
    let cov = ids
        .par_chunks(BLOCK)
        .map(|block| {
            let x = DMatrix::from_fn(d, block.len(), |r, col| {
                f64::from(view.pixel_samples(block[col])[r]) * gain - mean[r]
            });
            &x * x.transpose()
        })
        .reduce(|| DMatrix::zeros(d, d), |a, b| a + b)
        / m as f64;
    Ok((mean, cov, m))
}

/// The `PLANES` leading unit eigenvectors of the symmetric `cov` (`[plane][dim]`) and the share
/// of its trace they hold.
fn principal(cov: DMatrix<f64>) -> (Vec<f64>, f64) {
    let d = cov.nrows();
    let trace = cov.trace();
    let eig = SymmetricEigen::new(cov);
    let mut order: Vec<usize> = (0..d).collect();
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let mut planes = vec![0.0; PLANES * d];
    let mut held = 0.0;
    for (j, &o) in order.iter().take(PLANES).enumerate() {
        held += eig.eigenvalues[o].max(0.0);
        for r in 0..d {
            planes[j * d + r] = eig.eigenvectors[(r, o)];
        }
    }
    (planes, if trace > 0.0 { held / trace } else { 1.0 })
}

/// The covariance without light k's C rows and columns.
fn without_light(cov: &DMatrix<f64>, k: usize, c: usize) -> DMatrix<f64> {
    let d = cov.nrows();
    let keep: Vec<usize> = (0..d).filter(|&r| r / c != k).collect();
    DMatrix::from_fn(keep.len(), keep.len(), |a, b| cov[(keep[a], keep[b])])
}

/// The leave-one-out predictor of light k under kernel width `sigma`, from `planes`, the
/// [`PLANES`] leading eigenvectors of the covariance without light k (`[plane][D − C]`, which
/// do not depend on σ): per channel, a_c and W_c (length D, zero on light k's entries) with
/// prediction a_c + W_c · x.
fn loo_predictor(model: &RbfModel, sigma: f64, planes: &[f64], k: usize) -> (Vec<f64>, Vec<f64>) {
    let (n, c) = (model.lights.len(), model.channels);
    let d = n * c;
    let dk = d - c;
    // Positions in x of the reduced vector's entries.
    let at = |r: usize| if r / c < k { r } else { r + c };
    let mut w = vec![0.0; n];
    kernel_weights(&model.lights, sigma, model.lights[k], Some(k), &mut w);
    let mut offset = vec![0.0; c];
    let mut weights = vec![0.0; c * d];
    for ch in 0..c {
        // b_j = Σ_i w_i e_j[i, ch] over the other lights (reduced indices).
        let b: Vec<f64> = (0..PLANES)
            .map(|j| {
                (0..n)
                    .filter(|&i| i != k)
                    .map(|i| {
                        let r = if i < k { i * c + ch } else { (i - 1) * c + ch };
                        w[i] * planes[j * dk + r]
                    })
                    .sum()
            })
            .collect();
        let row = &mut weights[ch * d..(ch + 1) * d];
        for (j, &bj) in b.iter().enumerate() {
            for r in 0..dk {
                row[at(r)] += bj * planes[j * dk + r];
            }
        }
        let mean_at_k: f64 = (0..n).map(|i| w[i] * model.mean[i * c + ch]).sum();
        offset[ch] = mean_at_k - (0..d).map(|r| row[r] * model.mean[r]).sum::<f64>();
    }
    (offset, weights)
}

/// The leave-one-out predictors of every light under kernel width `sigma`.
fn predictors(model: &RbfModel, sigma: f64, loo_planes: &[Vec<f64>]) -> Vec<Predictor> {
    (0..model.lights.len())
        .into_par_iter()
        .map(|k| loo_predictor(model, sigma, &loo_planes[k], k))
        .collect()
}

/// Per light, a_c and W_c of its leave-one-out prediction ([`loo_predictor`]).
type Predictor = (Vec<f64>, Vec<f64>);

/// Adds the leave-one-out errors of one pixel's readings `x` (display units, D values).
fn add_loo(predictors: &[Predictor], c: usize, x: &[f64], e: &mut RelightErrors) {
    let d = x.len();
    for (k, (a, wts)) in predictors.iter().enumerate() {
        for ch in 0..c {
            let row = &wts[ch * d..(ch + 1) * d];
            let pred = a[ch] + row.iter().zip(x).map(|(w, v)| w * v).sum::<f64>();
            e.add(k, pred, x[k * c + ch]);
        }
    }
}

/// How the kernel width σ of a fit is set.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Width {
    /// Chosen from the data: of [`SIGMA_FACTORS`] × [`kernel_width`], the one with the least
    /// leave-one-out error over up to [`super::RIDGE_SAMPLE`] evenly spaced mask pixels.
    Auto,
    /// This σ (chord length on the unit sphere, > 0).
    Fixed(f64),
}

/// The candidate kernel widths, × the median nearest-light distance ([`kernel_width`]): half
/// octaves from 1/2 (a light's nearest neighbours barely reach it) to 4 (a broad average).
pub const SIGMA_FACTORS: [f64; 7] = [
    0.5,
    std::f64::consts::FRAC_1_SQRT_2,
    1.0,
    std::f64::consts::SQRT_2,
    2.0,
    2.0 * std::f64::consts::SQRT_2,
    4.0,
];

/// The kernel width of a fit and how it was chosen.
#[derive(Clone, Debug, PartialEq)]
pub struct KernelChoice {
    /// The default width, [`kernel_width`] of the lights.
    pub default: f64,
    /// Each candidate σ and the mean over the lights of its leave-one-out RMSE (8-bit units)
    /// over the sample; empty when σ was given ([`Width::Fixed`]).
    pub candidates: Vec<(f64, f64)>,
    /// Mask pixels of the sample (0 when σ was given).
    pub sample_pixels: usize,
}

/// σ of [`Width::Auto`]: of the candidates [`SIGMA_FACTORS`] × `default`, the one whose exact
/// leave-one-out error (mean over the lights of the RMSE, as [`RtiFit::loo`] reports it) over
/// up to [`super::RIDGE_SAMPLE`] evenly spaced mask pixels is least; the default on a tie, so
/// by construction the sample's error at the chosen σ is at most the default's.
fn choose_sigma(
    capture: &Capture,
    model: &RbfModel,
    loo_planes: &[Vec<f64>],
    gain: f64,
) -> Result<(f64, KernelChoice)> {
    let default = kernel_width(&model.lights);
    let ids = super::sample_ids(capture.n_pixels(), super::RIDGE_SAMPLE);
    let view = super::sample_view(capture, &ids)?;
    let (n, c) = (capture.n_lights(), capture.channels);
    let candidates: Vec<(f64, f64)> = SIGMA_FACTORS
        .iter()
        .map(|&f| {
            let sigma = f * default;
            let pred = predictors(model, sigma, loo_planes);
            let errors = ids
                .par_chunks(256)
                .fold(
                    || (RelightErrors::new(n), vec![0.0; n * c]),
                    |(mut e, mut x), chunk| {
                        for &p in chunk {
                            for (xr, &v) in x.iter_mut().zip(view.pixel_samples(p)) {
                                *xr = f64::from(v) * gain;
                            }
                            add_loo(&pred, c, &x, &mut e);
                        }
                        (e, x)
                    },
                )
                .map(|(e, _)| e)
                .reduce(|| RelightErrors::new(n), RelightErrors::merge);
            (sigma, errors.mean_rmse_8bit())
        })
        .collect();
    let at_default = candidates[SIGMA_FACTORS.iter().position(|&f| f == 1.0).unwrap_or(0)];
    let best = candidates
        .iter()
        .copied()
        .fold(at_default, |b, x| if x.1 < b.1 { x } else { b });
    let choice = KernelChoice {
        default,
        candidates,
        sample_pixels: ids.len(),
    };
    Ok((best.0, choice))
}

/// Fits the RBF basis to every mask pixel of `capture` and measures its leave-one-out error
/// (module documentation). The result's coefficients are `[pixel][plane]` (one fitted channel).
pub fn fit(capture: &Capture) -> Result<RtiFit> {
    super::fit(capture, super::Basis::Rbf, None)
}

/// [`fit`] with the kernel width set by `width` (the coefficients in the result).
pub fn fit_width(capture: &Capture, width: Width) -> Result<RtiFit> {
    super::check_distant(capture)?;
    let mut kept = super::Collect::default();
    let mut f = fit_into(capture, width, &mut kept)?;
    f.coefficients = kept.coefficients;
    Ok(f)
}

/// [`fit`], the coefficients put into `sink` block by block ([`super::fit_into`]).
pub(super) fn fit_into(
    capture: &Capture,
    width: Width,
    sink: &mut dyn CoefficientSink,
) -> Result<RtiFit> {
    let (np, n, c) = (capture.n_pixels(), capture.n_lights(), capture.channels);
    let d = n * c;
    if n < 2 || d - c < PLANES {
        return Err(Error::invalid(format!(
            "rbf keeps {PLANES} principal components of each pixel's readings under the other \
             lights; {n} lights × {c} channels leave {} (needs {} lights with colour, {} grey)",
            d.saturating_sub(c),
            PLANES.div_ceil(3) + 1,
            PLANES + 1
        )));
    }
    let gain = display_gain(capture)?;
    let lights = capture.lights.directions.clone();
    let (mean, cov, pca_pixels) = moments(capture, gain)?;
    let (planes, explained_variance) = principal(cov.clone());
    let mut model = RbfModel {
        sigma: kernel_width(&lights),
        lights,
        channels: c,
        mean,
        planes,
        explained_variance,
        pca_pixels,
    };
    // The PCA without each light does not depend on σ: once for every candidate.
    let loo_planes: Vec<Vec<f64>> = (0..n)
        .into_par_iter()
        .map(|k| principal(without_light(&cov, k, c)).0)
        .collect();
    drop(cov);
    let kernel = match width {
        Width::Auto => {
            let (sigma, choice) = choose_sigma(capture, &model, &loo_planes, gain)?;
            model.sigma = sigma;
            choice
        }
        Width::Fixed(sigma) if sigma.is_finite() && sigma > 0.0 => {
            model.sigma = sigma;
            KernelChoice {
                default: kernel_width(&model.lights),
                candidates: Vec::new(),
                sample_pixels: 0,
            }
        }
        Width::Fixed(sigma) => {
            return Err(Error::parameter(
                "rbf_sigma",
                format!("{sigma}: the kernel width must be a finite number > 0"),
            ))
        }
    };
    let predictors = predictors(&model, model.sigma, &loo_planes);
    let mut loo = RelightErrors::new(n);
    let mut ranges = vec![(f32::INFINITY, f32::NEG_INFINITY); PLANES];
    let mut coefficients = Vec::new();
    capture.for_each_tile(|start, view| {
        let count = view.n_pixels().min(np - start);
        for first in (0..count).step_by(BLOCK_PIXELS) {
            let len = BLOCK_PIXELS.min(count - first);
            coefficients.clear();
            coefficients.resize(len * PLANES, 0f32);
            let block = Block {
                view,
                first,
                gain,
                model: &model,
                predictors: &predictors,
            };
            loo = std::mem::take(&mut loo).merge(block.run(&mut coefficients));
            super::widen_ranges(&mut ranges, &coefficients);
            sink.put(start + first, &coefficients, &[])?;
        }
        Ok(())
    })?;
    Ok(RtiFit {
        basis: super::Basis::Rbf,
        width: capture.width,
        height: capture.height,
        channels: c,
        pixels: capture.pixels.clone(),
        fitted_channels: 1,
        coefficients: Vec::new(),
        chroma: Vec::new(),
        gain,
        loo,
        excluded_readings: 0,
        fell_back_to_all_lights: 0,
        rbf: Some(model),
        ridge: None,
        kernel: Some(kernel),
        ranges,
    })
}

/// One block of a tile's pixels: their projections and leave-one-out errors.
struct Block<'a> {
    view: &'a Capture,
    /// The block's first pixel within the tile.
    first: usize,
    gain: f64,
    model: &'a RbfModel,
    /// Per light, the leave-one-out predictor ([`loo_predictor`]).
    predictors: &'a [Predictor],
}

impl Block<'_> {
    /// Projects the block's pixels into `out` (`[pixel][plane]`); returns their LOO sums.
    fn run(&self, out: &mut [f32]) -> RelightErrors {
        let (n, c) = (self.view.n_lights(), self.view.channels);
        let d = n * c;
        out.par_chunks_mut(PLANES * 256)
            .enumerate()
            .fold(
                || (RelightErrors::new(n), vec![0.0; d]),
                |(mut e, mut x), (i, chunk)| {
                    for (j, coef) in chunk.chunks_mut(PLANES).enumerate() {
                        let s = self.view.pixel_samples(self.first + i * 256 + j);
                        for (xr, &v) in x.iter_mut().zip(s) {
                            *xr = f64::from(v) * self.gain;
                        }
                        project(self.model, &x, coef);
                        add_loo(self.predictors, c, &x, &mut e);
                    }
                    (e, x)
                },
            )
            .map(|(e, _)| e)
            .reduce(|| RelightErrors::new(n), RelightErrors::merge)
    }
}

/// The coefficients c_j = e_j · (x − μ) of one pixel's readings `x` (display units).
fn project(model: &RbfModel, x: &[f64], coef: &mut [f32]) {
    let d = x.len();
    for (j, cj) in coef.iter_mut().enumerate() {
        let e = &model.planes[j * d..(j + 1) * d];
        *cj = (0..d).map(|r| e[r] * (x[r] - model.mean[r])).sum::<f64>() as f32;
    }
}
