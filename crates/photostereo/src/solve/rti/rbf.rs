//! The RBF basis of relight (CNR-ISTI) as its `mrgb` colour space stores it: the readings of a
//! pixel under the N lights, one vector x ∈ R^D (D = N·C, light-major, channels interleaved),
//! are modelled as x ≈ μ + Σ_j c_j e_j, with μ the mean over pixels and e_1…e_P the leading
//! principal components (unit vectors) of the pixels' readings: P coefficients per pixel (the
//! "planes"), shared by the channels.
//!
//! Rendering (the file's contract): the mean and each component are stored as values B at M
//! render positions p_m, and a light l is rendered from them by normalised Gaussian weights
//!
//!   w_m(l) = exp(−|l − p_m|² / σ²) / Σ_m' exp(−|l − p_m'|² / σ²),
//!
//! after which the weights below [`MIN_WEIGHT`] are dropped and the rest renormalised: the
//! prediction is I_c(l) = Σ_m w_m(l) (B_{0,m,c} + Σ_j c_j B_{j,m,c}). relight's renderer and
//! OpenLIME's `ShaderRTI` (`RBF.rbf`) compute exactly these weights, over as many positions as
//! `info.json`'s `lights` holds (its `ndimensions` is that array's length / 3; the basis is
//! indexed `(plane · ndimensions + position) · 3 + channel`), so the positions need not be the
//! capture's lights. That average is a convex combination: with the readings' own values at the
//! lights (relight's choice, [`Interpolant::Kernel`] here) it smooths rather than interpolates
//! and cannot extrapolate past the outermost lights, where PTM's quadratic does.
//!
//! So the values are resampled ([`Interpolant::Smooth`]): the mean and each component, per
//! channel, are fitted over the lights by PTM's ridge quadratic of (l_x, l_y) plus Gaussians of
//! its residuals with smoothing λ ([`super::smoother`]; λ → ∞ leaves the ridge quadratic, PTM's
//! own fit of the PCA-reconstructed pixel), evaluated at the render positions — a square grid
//! over the lights and one largest light gap beyond them ([`super::smoother::render_positions`])
//! — and deconvolved, B = W⁻¹ S with W_{m m'} = w_m'(p_m), so that the rendering reproduces the
//! smoother at every position. A σ whose W⁻¹ amplifies values more than
//! [`MAX_DECONVOLUTION_GAIN`] (row-sum norm) is not offered. The mean's values are clamped to
//! [0, 1], as the file's bytes hold them, in the model as in the file.
//!
//! The choice ([`Width::Auto`], [`Smoothing::Auto`]), by the exact leave-one-out error over a
//! regular sample of mask pixels: first the quadratic's ridge weight ρ among PTM's grid
//! ([`super::RIDGE_GRID`] × N), by the quadratic's own prediction of each left-out light; then
//! together the interpolant and σ: the smoother with λ = ∞, [`LAMBDA_GRID`] and 0, each with σ
//! among [`SIGMA_FACTORS`] × the grid's spacing; and relight's own values at the lights
//! ([`Interpolant::Kernel`]) with σ among [`SIGMA_FACTORS`] × the median nearest-light
//! distance. Ties go to the smoother (larger λ, relight's kernel last) and the default σ. Since
//! the rendered ridge quadratic and relight's own fit are candidates, the chosen error on the
//! sample is at most theirs.
//!
//! Leave-one-out: the fit without light k is exactly what a file written without light k
//! renders at l_k: the PCA of the same pixels' readings without light k's C entries (the mean
//! without them and the eigenvectors of the covariance with light k's rows and columns
//! deleted), the projection of the pixel's other readings on it, the smoother over the other
//! lights, the render positions of the other lights, the deconvolution and the weights at l_k
//! (σ, λ, ρ and the Gaussians' width are the fit's). All of it is linear in the pixel's
//! readings (the clamped mean is a constant of the fold), so the prediction of light k is
//! a_{k,c} + Σ_j c_j Σ_i r_{k,i} e_{j,i,c}, c_j the pixel's coefficients on the PCA without
//! light k and r_k a row over the other lights, r_k = Sᵀ W⁻ᵀ w(l_k), computed once per light and
//! candidate: a pixel costs N·C·D operations (N·C·P for each candidate over the sample, whose
//! projections on each light's PCA are kept).
//!
//! The PCA uses up to [`PCA_PIXELS`] evenly spaced mask pixels (as relight samples its
//! pixels); the covariance is D × D in f64, `8 · D²` bytes.

use super::smoother::{self, Smoother};
use super::{display_gain, CoefficientSink, RelightErrors, RtiFit, BLOCK_PIXELS};
use crate::base::error::{Error, Result};
use crate::model::capture::Capture;
use nalgebra::{DMatrix, DVector, SymmetricEigen};
use rayon::prelude::*;

/// Principal components kept: the coefficient planes of each pixel (six RGB images). 18 is
/// what PTM RGB stores per pixel (6 terms × 3 channels), so the two bases are compared at the
/// same storage; the components are shared by all pixels, so fewer of them hold less of the
/// readings' variance than a per-pixel fit with as many numbers. relight's `mrgb` format
/// allows any multiple of 3 (`nplanes`; relight's own default is 9). A rig whose readings under the other lights span
/// fewer dimensions (D − C < 18: a grey capture of fewer than 19 lights) has only D − C
/// components; the rest are stored as zeros ([`components`]).
pub const PLANES: usize = 18;
/// Normalised kernel weights below this are dropped (relight's and OpenLIME's rule).
pub const MIN_WEIGHT: f64 = 0.001;
/// Mask pixels the PCA samples at most.
pub const PCA_PIXELS: usize = 65_536;
/// The smoothing candidates λ of the residuals besides 0 and ∞: half decades from 10⁻³ to 10
/// (the Gaussians' matrix has unit diagonal, so λ is a noise-to-signal variance ratio).
pub const LAMBDA_GRID: [f64; 9] = [1e-3, 3.16e-3, 1e-2, 3.16e-2, 0.1, 0.316, 1.0, 3.16, 10.0];
/// The most the deconvolution W⁻¹ may amplify the smoother's values (row-sum norm): the stored
/// components are quantised to their greatest magnitude / 127, so this costs at most two of
/// the basis bytes' eight bits.
pub const MAX_DECONVOLUTION_GAIN: f64 = 4.0;

/// How the mean and components are carried from the lights to the render positions.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Interpolant {
    /// relight's own: the values at the lights, rendered by the kernel average alone.
    Kernel,
    /// PTM's ridge quadratic plus Gaussians of its residuals ([`super::smoother`]), resampled
    /// at the render positions and deconvolved.
    Smooth {
        /// Smoothing λ of the residuals (≥ 0; infinite: the ridge quadratic alone).
        lambda: f64,
        /// Ridge weight ρ of the quadratic (≥ 0; over all N lights, as PTM's λ).
        ridge: f64,
        /// Width ε of the Gaussians (> 0, in the (l_x, l_y) plane).
        width: f64,
    },
}

impl Interpolant {
    /// `kernel`, `smooth` or `quadratic` (λ = ∞).
    pub fn name(self) -> &'static str {
        match self {
            Interpolant::Kernel => "kernel",
            Interpolant::Smooth { lambda, .. } if lambda.is_infinite() => "quadratic",
            Interpolant::Smooth { .. } => "smooth",
        }
    }

    /// The smoothing λ (`None` for the kernel).
    pub fn lambda(self) -> Option<f64> {
        match self {
            Interpolant::Kernel => None,
            Interpolant::Smooth { lambda, .. } => Some(lambda),
        }
    }
}

/// The model shared by every pixel of an RBF fit: the render positions, the kernel width, the
/// mean and the components there (display units; `[position][channel]` within each vector),
/// and the PCA the coefficients are projections on.
#[derive(Clone, Debug, PartialEq)]
pub struct RbfModel {
    /// The render positions (unit, camera frame): the `lights` of the written files.
    pub lights: Vec<[f64; 3]>,
    /// Kernel width σ (chord length on the unit sphere).
    pub sigma: f64,
    /// How the values at the positions were obtained.
    pub interpolant: Interpolant,
    /// Channels C per position.
    pub channels: usize,
    /// The mean at the positions, M·C values in [0, 1].
    pub mean: Vec<f64>,
    /// The P components at the positions, `[plane][M·C]`.
    pub planes: Vec<f64>,
    /// Share of the readings' variance (about the mean) the P components hold.
    pub explained_variance: f64,
    /// Pixels the PCA sampled.
    pub pca_pixels: usize,
    /// The capture's lights (empty for a model read back from its files).
    pub capture_lights: Vec<[f64; 3]>,
    /// The mean reading μ at the capture's lights, D = N·C values (empty when read back).
    pub pca_mean: Vec<f64>,
    /// The P principal components e_j at the capture's lights, `[plane][D]`, unit length
    /// (empty when read back).
    pub pca_planes: Vec<f64>,
}

impl RbfModel {
    /// The kernel weights at `l` over the render positions, into `w`.
    pub fn weights(&self, l: [f64; 3], w: &mut [f64]) {
        kernel_weights(&self.lights, self.sigma, l, None, w);
    }

    /// The mean and the components rendered at `l`: `[1 + P][channel]` into `out`.
    pub fn light_basis(&self, l: [f64; 3], out: &mut [f64]) {
        let (m, c) = (self.lights.len(), self.channels);
        let mut w = vec![0.0; m];
        self.weights(l, &mut w);
        let d = m * c;
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

    /// The coefficients of a pixel whose readings are all 0: −E μ.
    pub fn black(&self) -> Vec<f64> {
        let d = self.pca_mean.len();
        (0..PLANES)
            .map(|j| {
                -(0..d)
                    .map(|r| self.pca_planes[j * d + r] * self.pca_mean[r])
                    .sum::<f64>()
            })
            .collect()
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

/// The number of nonzero components of a capture of `lights` × `channels`: [`PLANES`], or
/// fewer when the readings under all lights but one span fewer dimensions (D − C), which the
/// leave-one-out PCA must match.
pub fn components(lights: usize, channels: usize) -> usize {
    (lights.saturating_sub(1) * channels).min(PLANES)
}

/// The `keep` leading unit eigenvectors of the symmetric `cov` as [`PLANES`] planes, the rest
/// zero (`[plane][dim]`), and the share of its trace they hold.
fn principal(cov: DMatrix<f64>, keep: usize) -> (Vec<f64>, f64) {
    let d = cov.nrows();
    let trace = cov.trace();
    let eig = SymmetricEigen::new(cov);
    let mut order: Vec<usize> = (0..d).collect();
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let mut planes = vec![0.0; PLANES * d];
    let mut held = 0.0;
    for (j, &o) in order.iter().take(keep.min(PLANES)).enumerate() {
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

/// The prediction of a left-out light k as a row over the other lights: channel c is
/// `mean_at[c] + Σ_j c_j Σ_i row[i] e_{j,i,c}` with c_j the pixel's coefficients on the PCA
/// without light k (`row[k]` = 0).
#[derive(Clone, Debug)]
struct LooRow {
    row: Vec<f64>,
    mean_at: Vec<f64>,
}

/// The fit without light k, for the smoother: the other lights' smoother, their render
/// positions, and the smoother's values of their mean at those positions per λ.
struct Fold {
    k: usize,
    light: [f64; 3],
    smoother: Smoother,
    positions: Vec<[f64; 3]>,
    /// G(|p_m − u_i|) (M × (N − 1)) and p(p_m) (M × 6).
    phi: DMatrix<f64>,
    poly: DMatrix<f64>,
    /// `[λ candidate][channel]`: the smoother's mean at the positions (M values).
    mean_values: Vec<Vec<DVector<f64>>>,
}

impl Fold {
    fn new(
        lights: &[[f64; 3]],
        mean: &[f64],
        (c, k): (usize, usize),
        (ridge, width): (f64, f64),
        lambdas: &[f64],
    ) -> Result<Fold> {
        let keep: Vec<usize> = (0..lights.len()).filter(|&i| i != k).collect();
        let others: Vec<[f64; 3]> = keep.iter().map(|&i| lights[i]).collect();
        let smoother = Smoother::new(&others, ridge, width)
            .map_err(|e| Error::invalid(format!("without light {}: {e}", k + 1)))?;
        let positions = smoother::render_positions(&others).0;
        let (m, n1) = (positions.len(), others.len());
        let phi = DMatrix::from_fn(m, n1, |a, i| {
            smoother::gauss(positions[a], others[i], width)
        });
        let poly = DMatrix::from_fn(m, smoother::POLY, |a, t| smoother::poly(positions[a])[t]);
        let ys: Vec<DVector<f64>> = (0..c)
            .map(|ch| DVector::from_iterator(n1, keep.iter().map(|&i| mean[i * c + ch])))
            .collect();
        let mean_values = lambdas
            .iter()
            .map(|&l| {
                let v = smoother.values(&ys, l, &positions);
                v.into_iter().map(DVector::from_vec).collect()
            })
            .collect();
        Ok(Fold {
            k,
            light: lights[k],
            smoother,
            positions,
            phi,
            poly,
            mean_values,
        })
    }

    /// The rows of light k under width `sigma` for each of `lambdas` (r = Sᵀ W⁻ᵀ w(l_k): the
    /// smoother's row for the right-hand side Σ_m g_m (G(p_m), p(p_m)), g = W⁻ᵀ w(l_k)); `None`
    /// when the positions' kernel matrix W is singular.
    fn rows(&self, n: usize, c: usize, sigma: f64, lambdas: &[f64]) -> Option<Vec<LooRow>> {
        let wm = kernel_matrix(&self.positions, sigma);
        let lu_t = wm.transpose().lu();
        let lu = wm.lu();
        let mut w = vec![0.0; self.positions.len()];
        kernel_weights(&self.positions, sigma, self.light, None, &mut w);
        let w = DVector::from_vec(w);
        let g = lu_t.solve(&w)?;
        let f = self.phi.transpose() * &g;
        let mut gp = [0.0; smoother::POLY];
        gp.copy_from_slice((self.poly.transpose() * &g).as_slice());
        let reduced = self.smoother.reduce(&f, &gp);
        // w · clamp(W⁻¹ s): the rendered mean, from the clamped values at the positions.
        let rendered = |s: &DVector<f64>| -> f64 {
            let v = lu.solve(s).unwrap_or_else(|| DVector::zeros(s.len()));
            w.iter()
                .zip(v.iter())
                .map(|(a, b)| a * b.clamp(0.0, 1.0))
                .sum()
        };
        let rows = lambdas
            .iter()
            .zip(&self.mean_values)
            .map(|(&lambda, means)| {
                let a = self.smoother.solve(&reduced, lambda);
                let mut row = Vec::with_capacity(n);
                row.extend(a.iter().take(self.k));
                row.push(0.0);
                row.extend(a.iter().skip(self.k));
                LooRow {
                    row,
                    mean_at: means.iter().take(c).map(rendered).collect(),
                }
            })
            .collect();
        Some(rows)
    }
}

/// W of the render positions under width `sigma`: W_{m m'} = w_m'(p_m), the kernel weights at
/// each position.
fn kernel_matrix(positions: &[[f64; 3]], sigma: f64) -> DMatrix<f64> {
    let m = positions.len();
    let mut w = DMatrix::zeros(m, m);
    let mut row = vec![0.0; m];
    for (a, &p) in positions.iter().enumerate() {
        kernel_weights(positions, sigma, p, None, &mut row);
        for (b, &v) in row.iter().enumerate() {
            w[(a, b)] = v;
        }
    }
    w
}

/// W⁻¹ of the render positions under width `sigma` ([`kernel_matrix`]) and its row-sum norm,
/// the most it amplifies values; `None` when W is singular.
fn deconvolution(positions: &[[f64; 3]], sigma: f64) -> Option<(DMatrix<f64>, f64)> {
    let inv = kernel_matrix(positions, sigma).try_inverse()?;
    let gain = inv
        .row_iter()
        .map(|r| r.iter().map(|v| v.abs()).sum::<f64>())
        .fold(0.0, f64::max);
    gain.is_finite().then_some((inv, gain))
}

/// relight's own leave-one-out row: the kernel weights at l_k over the other lights, the
/// clamped mean at the lights.
fn kernel_row(lights: &[[f64; 3]], mean: &[f64], c: usize, sigma: f64, k: usize) -> LooRow {
    let mut row = vec![0.0; lights.len()];
    kernel_weights(lights, sigma, lights[k], Some(k), &mut row);
    let mean_at = (0..c)
        .map(|ch| {
            row.iter()
                .enumerate()
                .map(|(i, w)| w * mean[i * c + ch].clamp(0.0, 1.0))
                .sum()
        })
        .collect();
    LooRow { row, mean_at }
}

/// Per light k, `b[j·C + c]` = Σ_i row_i e^{(k)}_{j,i,c} of its row over `planes`, the
/// [`PLANES`] components of the PCA without light k (`[plane][D − C]`).
fn plane_weights(row: &LooRow, planes: &[f64], k: usize, c: usize) -> Vec<f64> {
    let dk = planes.len() / PLANES;
    let mut b = vec![0.0; PLANES * c];
    for (i, &ri) in row
        .row
        .iter()
        .enumerate()
        .filter(|&(i, &ri)| i != k && ri != 0.0)
    {
        let red = if i < k { i } else { i - 1 };
        for j in 0..PLANES {
            for ch in 0..c {
                b[j * c + ch] += ri * planes[j * dk + red * c + ch];
            }
        }
    }
    b
}

/// The leave-one-out predictor of light k from its row: per channel, a_c and W_c (length D,
/// zero on light k's entries) with prediction a_c + W_c · x.
fn loo_predictor(row: &LooRow, planes: &[f64], mean: &[f64], k: usize, c: usize) -> Predictor {
    let d = mean.len();
    let dk = d - c;
    let at = |r: usize| if r / c < k { r } else { r + c };
    let b = plane_weights(row, planes, k, c);
    let mut offset = vec![0.0; c];
    let mut weights = vec![0.0; c * d];
    for ch in 0..c {
        let w = &mut weights[ch * d..(ch + 1) * d];
        for j in 0..PLANES {
            let bj = b[j * c + ch];
            for r in 0..dk {
                w[at(r)] += bj * planes[j * dk + r];
            }
        }
        offset[ch] = row.mean_at[ch] - (0..d).map(|r| w[r] * mean[r]).sum::<f64>();
    }
    (offset, weights)
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
    /// Chosen from the data: of [`SIGMA_FACTORS`] × [`kernel_width`], with the interpolant,
    /// the one with the least leave-one-out error over up to [`super::RIDGE_SAMPLE`] evenly
    /// spaced mask pixels.
    Auto,
    /// This σ (chord length on the unit sphere, > 0).
    Fixed(f64),
}

/// How the values at the render positions are obtained.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Smoothing {
    /// Chosen with σ from the data (module documentation).
    Auto,
    /// This interpolant.
    Fixed(Interpolant),
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

/// One candidate of the choice and its error.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Candidate {
    /// The rendering width σ.
    pub sigma: f64,
    /// The interpolant.
    pub interpolant: Interpolant,
    /// The mean over the lights of its leave-one-out RMSE (8-bit units) over the sample;
    /// infinite when it cannot be rendered (W singular or amplifying more than
    /// [`MAX_DECONVOLUTION_GAIN`]).
    pub loo: f64,
}

/// The rendering of a fit and how it was chosen.
#[derive(Clone, Debug, PartialEq)]
pub struct KernelChoice {
    /// The default width, [`kernel_width`] of the lights.
    pub default: f64,
    /// Every candidate (σ, interpolant) with its error; empty when both were given.
    pub candidates: Vec<Candidate>,
    /// Mask pixels of the sample (0 when both were given).
    pub sample_pixels: usize,
    /// The ridge weights per light ρ / N of the quadratic part tried ([`super::RIDGE_GRID`])
    /// and their errors (the quadratic at the left-out light, before rendering); empty when
    /// the interpolant was given.
    pub ridge_candidates: Vec<(f64, f64)>,
}

/// The smoother candidates with ridge `ridge` and width `width`, smoothest first: λ = ∞,
/// [`LAMBDA_GRID`] from the greatest, λ = 0.
fn interpolants(ridge: f64, width: f64) -> Vec<Interpolant> {
    std::iter::once(f64::INFINITY)
        .chain(LAMBDA_GRID.iter().rev().copied())
        .chain(std::iter::once(0.0))
        .map(|lambda| Interpolant::Smooth {
            lambda,
            ridge,
            width,
        })
        .collect()
}

/// The PCA of a fit, with each light left out.
struct Pca {
    lights: Vec<[f64; 3]>,
    channels: usize,
    mean: Vec<f64>,
    /// Per light, the [`PLANES`] components without it (`[plane][D − C]`).
    loo_planes: Vec<Vec<f64>>,
}

impl Pca {
    /// The leave-one-out rows of every light for each (σ, interpolant): `[σ][interpolant]`,
    /// `None` for a smoother candidate a fold cannot render.
    fn rows(
        &self,
        sigmas: &[f64],
        interps: &[Interpolant],
    ) -> Result<Vec<Vec<Option<Vec<LooRow>>>>> {
        let (n, c) = (self.lights.len(), self.channels);
        let lambdas: Vec<f64> = interps.iter().filter_map(|i| i.lambda()).collect();
        let folds: Vec<Fold> = match interps.first() {
            Some(&Interpolant::Smooth { ridge, width, .. }) => (0..n)
                .into_par_iter()
                .map(|k| Fold::new(&self.lights, &self.mean, (c, k), (ridge, width), &lambdas))
                .collect::<Result<_>>()?,
            _ => Vec::new(),
        };
        // [k][σ][λ]
        let smooth_rows: Vec<Vec<Option<Vec<LooRow>>>> = folds
            .par_iter()
            .map(|f| sigmas.iter().map(|&s| f.rows(n, c, s, &lambdas)).collect())
            .collect();
        Ok(sigmas
            .iter()
            .enumerate()
            .map(|(si, &sigma)| {
                let mut li = 0;
                interps
                    .iter()
                    .map(|interp| match interp {
                        Interpolant::Kernel => Some(
                            (0..n)
                                .map(|k| kernel_row(&self.lights, &self.mean, c, sigma, k))
                                .collect(),
                        ),
                        Interpolant::Smooth { .. } => {
                            li += 1;
                            smooth_rows
                                .iter()
                                .map(|per_k| per_k[si].as_ref().map(|r| r[li - 1].clone()))
                                .collect()
                        }
                    })
                    .collect()
            })
            .collect())
    }

    /// The full leave-one-out predictors of the rows ([`loo_predictor`]).
    fn predictors(&self, rows: &[LooRow]) -> Vec<Predictor> {
        rows.par_iter()
            .enumerate()
            .map(|(k, r)| loo_predictor(r, &self.loo_planes[k], &self.mean, k, self.channels))
            .collect()
    }
}

/// A regular sample of mask pixels for the choice: their readings and, per light k, their
/// projections on the PCA without k (`[pixel][k][plane]`), which no candidate changes.
struct Sample {
    x: Vec<f64>,
    proj: Vec<f64>,
    pixels: usize,
}

impl Sample {
    fn new(capture: &Capture, pca: &Pca, gain: f64) -> Result<Sample> {
        let ids = super::sample_ids(capture.n_pixels(), super::RIDGE_SAMPLE);
        let view = super::sample_view(capture, &ids)?;
        let (n, c) = (pca.lights.len(), pca.channels);
        let d = n * c;
        let x: Vec<f64> = ids
            .iter()
            .flat_map(|&p| {
                view.pixel_samples(p)
                    .iter()
                    .map(move |&v| f64::from(v) * gain)
            })
            .collect();
        let mut proj = vec![0.0; ids.len() * n * PLANES];
        proj.par_chunks_mut(n * PLANES)
            .zip(x.par_chunks(d))
            .for_each(|(out, xp)| {
                for k in 0..n {
                    let planes = &pca.loo_planes[k];
                    let dk = d - c;
                    for j in 0..PLANES {
                        let e = &planes[j * dk..(j + 1) * dk];
                        out[k * PLANES + j] = (0..dk)
                            .map(|r| {
                                let at = if r / c < k { r } else { r + c };
                                e[r] * (xp[at] - pca.mean[at])
                            })
                            .sum();
                    }
                }
            });
        Ok(Sample {
            x,
            proj,
            pixels: ids.len(),
        })
    }

    /// The mean over the lights of the leave-one-out RMSE (8-bit units) of the rows.
    fn error(&self, pca: &Pca, rows: &[LooRow]) -> f64 {
        let (n, c) = (pca.lights.len(), pca.channels);
        let b: Vec<Vec<f64>> = rows
            .iter()
            .enumerate()
            .map(|(k, r)| plane_weights(r, &pca.loo_planes[k], k, c))
            .collect();
        (0..self.pixels)
            .into_par_iter()
            .fold(
                || RelightErrors::new(n),
                |mut e, p| {
                    let x = &self.x[p * n * c..(p + 1) * n * c];
                    for k in 0..n {
                        let pr = &self.proj[(p * n + k) * PLANES..(p * n + k + 1) * PLANES];
                        for ch in 0..c {
                            let s: f64 = (0..PLANES).map(|j| b[k][j * c + ch] * pr[j]).sum();
                            e.add(k, rows[k].mean_at[ch] + s, x[k * c + ch]);
                        }
                    }
                    e
                },
            )
            .reduce(|| RelightErrors::new(n), RelightErrors::merge)
            .mean_rmse_8bit()
    }
}

/// The leave-one-out row of light k for PTM's ridge quadratic of the other lights alone,
/// evaluated at l_k (before any rendering): r = P (PᵀP + ρ D)⁻¹ p(l_k).
fn quadratic_row(
    lights: &[[f64; 3]],
    mean: &[f64],
    c: usize,
    k: usize,
    ridge: f64,
) -> Result<LooRow> {
    let keep: Vec<usize> = (0..lights.len()).filter(|&i| i != k).collect();
    let p = DMatrix::from_fn(keep.len(), smoother::POLY, |a, t| {
        smoother::poly(lights[keep[a]])[t]
    });
    let mut normal = p.transpose() * &p;
    for (t, d) in smoother::roughness().iter().enumerate() {
        normal[(t, t)] += ridge * d;
    }
    let x = DVector::from_row_slice(&smoother::poly(lights[k]));
    let z = normal.lu().solve(&x).ok_or_else(|| {
        Error::invalid(format!(
            "rbf: without light {} the lights do not determine PTM's quadratic",
            k + 1
        ))
    })?;
    let reduced = &p * z;
    let mut row = vec![0.0; lights.len()];
    for (a, &i) in keep.iter().enumerate() {
        row[i] = reduced[a];
    }
    let mean_at = (0..c)
        .map(|ch| {
            row.iter()
                .enumerate()
                .map(|(i, r)| r * mean[i * c + ch])
                .sum()
        })
        .collect();
    Ok(LooRow { row, mean_at })
}

/// The ridge weight ρ of the smoother's quadratic: of [`super::RIDGE_GRID`] × N, the one whose
/// quadratic predicts the left-out lights of the sample best (PTM's own choice, made on the
/// PCA's reconstruction); the smaller on a tie. Returns ρ and each candidate (ρ / N, error).
fn choose_ridge(pca: &Pca, sample: &Sample) -> Result<(f64, Vec<(f64, f64)>)> {
    let n = pca.lights.len();
    let mut candidates = Vec::new();
    let mut best = (0.0, f64::INFINITY);
    for per_light in super::RIDGE_GRID {
        let ridge = per_light * n as f64;
        let rows: Vec<LooRow> = (0..n)
            .into_par_iter()
            .map(|k| quadratic_row(&pca.lights, &pca.mean, pca.channels, k, ridge))
            .collect::<Result<_>>()?;
        let e = sample.error(pca, &rows);
        if e < best.1 {
            best = (ridge, e);
        }
        candidates.push((per_light, e));
    }
    Ok((best.0, candidates))
}

/// The candidates as groups of σ × interpolants, smoothest first: the smoother's (`smooth`)
/// with σ a multiple of the render grid's spacing, then relight's kernel (`kernel`) with σ a
/// multiple of the lights' spacing ([`SIGMA_FACTORS`], the default first).
fn candidate_groups(
    pca: &Pca,
    width: Width,
    smooth: Option<Vec<Interpolant>>,
    kernel: bool,
) -> Vec<(Vec<f64>, Vec<Interpolant>)> {
    let sigmas = |unit: f64| -> Vec<f64> {
        match width {
            Width::Auto => std::iter::once(unit)
                .chain(
                    SIGMA_FACTORS
                        .iter()
                        .filter(|&&f| f != 1.0)
                        .map(|f| f * unit),
                )
                .collect(),
            Width::Fixed(s) => vec![s],
        }
    };
    let mut groups = Vec::new();
    if let Some(interps) = smooth {
        let step = smoother::render_positions(&pca.lights).1;
        groups.push((sigmas(step), interps));
    }
    if kernel {
        groups.push((sigmas(kernel_width(&pca.lights)), vec![Interpolant::Kernel]));
    }
    groups
}

/// The candidates of `width` and `smoothing` ([`candidate_groups`]; the smoother's ridge first
/// by [`choose_ridge`]), their errors over the sample, and the chosen one (least error; ties to
/// the earlier: the smoother interpolant, the default σ) with its rows. A smoother whose
/// full-set deconvolution amplifies more than [`MAX_DECONVOLUTION_GAIN`] is not offered.
fn choose(
    capture: &Capture,
    pca: &Pca,
    gain: f64,
    width: Width,
    smoothing: Smoothing,
) -> Result<(Candidate, Vec<LooRow>, KernelChoice)> {
    let fixed = matches!((width, smoothing), (Width::Fixed(_), Smoothing::Fixed(_)));
    let sample = if fixed {
        None
    } else {
        Some(Sample::new(capture, pca, gain)?)
    };
    let (ridge_candidates, smooth, kernel) = match (smoothing, &sample) {
        (Smoothing::Auto, Some(sample)) => {
            let (ridge, cands) = choose_ridge(pca, sample)?;
            let eps = smoother::spacing(&pca.lights);
            (cands, Some(interpolants(ridge, eps)), true)
        }
        (Smoothing::Fixed(Interpolant::Kernel), _) => (Vec::new(), None, true),
        (Smoothing::Fixed(i), _) => (Vec::new(), Some(vec![i]), false),
        (Smoothing::Auto, None) => unreachable!("a sample unless both are fixed"),
    };
    let positions = smoother::render_positions(&pca.lights).0;
    let mut candidates = Vec::new();
    let mut best: Option<(Candidate, Vec<LooRow>)> = None;
    for (sigmas, interps) in candidate_groups(pca, width, smooth, kernel) {
        let smooth = interps[0] != Interpolant::Kernel;
        let (ok, refused): (Vec<f64>, Vec<f64>) = sigmas.iter().partition(|&&s| {
            !smooth
                || deconvolution(&positions, s).is_some_and(|(_, g)| g <= MAX_DECONVOLUTION_GAIN)
        });
        let mut rows = pca.rows(&ok, &interps)?;
        for (ii, &interp) in interps.iter().enumerate() {
            for (si, &sigma) in ok.iter().enumerate() {
                let loo = match (&rows[si][ii], &sample) {
                    (Some(r), Some(s)) => s.error(pca, r),
                    (Some(_), None) => 0.0,
                    (None, _) => f64::INFINITY,
                };
                let c = Candidate {
                    sigma,
                    interpolant: interp,
                    loo,
                };
                if loo.is_finite() && best.as_ref().is_none_or(|b| loo < b.0.loo) {
                    best = Some((c, rows[si][ii].take().expect("rows of a finite candidate")));
                }
                candidates.push(c);
            }
            candidates.extend(refused.iter().map(|&sigma| Candidate {
                sigma,
                interpolant: interp,
                loo: f64::INFINITY,
            }));
        }
    }
    let (pick, rows) = best.ok_or_else(|| {
        Error::parameter(
            "rbf_sigma",
            format!(
                "{width:?} with {smoothing:?}: the render positions' kernel matrix is singular \
                 or amplifies the values more than {MAX_DECONVOLUTION_GAIN}× (a narrower σ \
                 renders)"
            ),
        )
    })?;
    let choice = KernelChoice {
        default: kernel_width(&pca.lights),
        candidates: if fixed { Vec::new() } else { candidates },
        sample_pixels: sample.map_or(0, |s| s.pixels),
        ridge_candidates,
    };
    Ok((pick, rows, choice))
}

/// The render positions, and the mean and the components there ([`render`]).
type Rendered = (Vec<[f64; 3]>, Vec<f64>, Vec<f64>);

/// The mean and components `(mean, planes)` at the render positions of `interp` under width
/// `sigma` (module documentation), with the positions.
fn render(
    pca_mean: &[f64],
    pca_planes: &[f64],
    lights: &[[f64; 3]],
    c: usize,
    sigma: f64,
    interp: Interpolant,
) -> Result<Rendered> {
    let (lambda, smoother) = match interp {
        Interpolant::Kernel => {
            let mean = pca_mean.iter().map(|v| v.clamp(0.0, 1.0)).collect();
            return Ok((lights.to_vec(), mean, pca_planes.to_vec()));
        }
        Interpolant::Smooth {
            lambda,
            ridge,
            width,
        } => (lambda, Smoother::new(lights, ridge, width)?),
    };
    let positions = smoother::render_positions(lights).0;
    let (inv, _) = deconvolution(&positions, sigma).ok_or_else(|| {
        Error::parameter(
            "rbf_sigma",
            format!("{sigma}: the render positions' kernel matrix is singular"),
        )
    })?;
    let (n, m) = (lights.len(), positions.len());
    let d = n * c;
    let vectors: Vec<&[f64]> = std::iter::once(pca_mean)
        .chain(pca_planes.chunks(d))
        .collect();
    let ys: Vec<DVector<f64>> = vectors
        .iter()
        .flat_map(|v| {
            (0..c).map(move |ch| DVector::from_iterator(n, (0..n).map(|i| v[i * c + ch])))
        })
        .collect();
    let at_positions = smoother.values(&ys, lambda, &positions);
    let mut out = vec![0.0; vectors.len() * m * c];
    for (y, s) in at_positions.into_iter().enumerate() {
        let (v, ch) = (y / c, y % c);
        let b = &inv * DVector::from_vec(s);
        for (a, &x) in b.iter().enumerate() {
            out[v * m * c + a * c + ch] = if v == 0 { x.clamp(0.0, 1.0) } else { x };
        }
    }
    let planes = out.split_off(m * c);
    Ok((positions, out, planes))
}

/// Bytes the choice of an RBF fit holds at once for N `lights` and C `channels`: the sample's
/// readings and per-light projections (`8 · S · N · (C + P)`, S = [`super::RIDGE_SAMPLE`]) and
/// per light the smoother's matrices and the values at the render positions
/// (`8 · N · (M · (N + 6 + C · 11) + 3 N²)`, M = [`smoother::MAX_POSITIONS`]).
pub fn choice_bytes(lights: usize, channels: usize) -> u64 {
    let (n, c, m) = (
        lights as u64,
        channels as u64,
        smoother::MAX_POSITIONS as u64,
    );
    let sample = 8 * super::RIDGE_SAMPLE as u64 * n * (c + PLANES as u64);
    let folds = 8 * n * (m * (n + 6 + c * (LAMBDA_GRID.len() as u64 + 2)) + 3 * n * n);
    sample + folds
}

/// Fits the RBF basis to every mask pixel of `capture` and measures its leave-one-out error
/// (module documentation). The result's coefficients are `[pixel][plane]` (one fitted channel).
pub fn fit(capture: &Capture) -> Result<RtiFit> {
    super::fit(capture, super::Basis::Rbf, None)
}

/// [`fit`] with the kernel width set by `width` (the coefficients in the result).
pub fn fit_width(capture: &Capture, width: Width) -> Result<RtiFit> {
    fit_with(capture, width, Smoothing::Auto)
}

/// [`fit`] with the kernel width and the interpolant set by `width` and `smoothing` (the
/// coefficients in the result).
pub fn fit_with(capture: &Capture, width: Width, smoothing: Smoothing) -> Result<RtiFit> {
    super::check_distant(capture)?;
    let mut kept = super::Collect::default();
    let mut f = fit_into(capture, width, smoothing, &mut kept)?;
    f.coefficients = kept.coefficients;
    Ok(f)
}

/// Refuses a width or smoothing that is not a number in range.
fn check_options(width: Width, smoothing: Smoothing) -> Result<()> {
    if let Width::Fixed(sigma) = width {
        if !(sigma.is_finite() && sigma > 0.0) {
            return Err(Error::parameter(
                "rbf_sigma",
                format!("{sigma}: the kernel width must be a finite number > 0"),
            ));
        }
    }
    if let Smoothing::Fixed(Interpolant::Smooth {
        lambda,
        ridge,
        width,
    }) = smoothing
    {
        if !(lambda >= 0.0 && ridge >= 0.0 && ridge.is_finite() && width > 0.0 && width.is_finite())
        {
            return Err(Error::parameter(
                "rbf_smoothing",
                format!(
                    "λ {lambda}, ρ {ridge}, ε {width}: the smoothing must be ≥ 0 (or infinite), \
                     the ridge weight finite and ≥ 0, the width finite and > 0"
                ),
            ));
        }
    }
    Ok(())
}

/// [`fit`], the coefficients put into `sink` block by block ([`super::fit_into`]).
pub(super) fn fit_into(
    capture: &Capture,
    width: Width,
    smoothing: Smoothing,
    sink: &mut dyn CoefficientSink,
) -> Result<RtiFit> {
    let (np, n, c) = (capture.n_pixels(), capture.n_lights(), capture.channels);
    if n < 2 {
        return Err(Error::invalid(format!(
            "rbf models each light from the pixels' readings under the other lights; the \
             capture has {n} light(s) (needs 2)"
        )));
    }
    check_options(width, smoothing)?;
    let gain = display_gain(capture)?;
    let lights = capture.lights.directions.clone();
    if smoothing != Smoothing::Fixed(Interpolant::Kernel) {
        // The smoother's rig check, before the PCA's cost.
        Smoother::new(&lights, 1.0, smoother::spacing(&lights).max(1e-3))?;
    }
    let (mean, cov, pca_pixels) = moments(capture, gain)?;
    let (planes, explained_variance) = principal(cov.clone(), components(n, c));
    // The PCA without each light does not depend on the candidates: once for all of them.
    let loo_planes: Vec<Vec<f64>> = (0..n)
        .into_par_iter()
        .map(|k| principal(without_light(&cov, k, c), components(n, c)).0)
        .collect();
    drop(cov);
    let pca = Pca {
        lights: lights.clone(),
        channels: c,
        mean,
        loo_planes,
    };
    let (pick, rows, kernel) = choose(capture, &pca, gain, width, smoothing)?;
    let (positions, rmean, rplanes) =
        render(&pca.mean, &planes, &lights, c, pick.sigma, pick.interpolant)?;
    let predictors = pca.predictors(&rows);
    let model = RbfModel {
        lights: positions,
        sigma: pick.sigma,
        interpolant: pick.interpolant,
        channels: c,
        mean: rmean,
        planes: rplanes,
        explained_variance,
        pca_pixels,
        capture_lights: lights,
        pca_mean: pca.mean,
        pca_planes: planes,
    };
    let (loo, ranges) = project_all(capture, &model, &predictors, gain, np, sink)?;
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

/// Projects every mask pixel into `sink` block by block; returns the leave-one-out sums and
/// the coefficients' ranges.
fn project_all(
    capture: &Capture,
    model: &RbfModel,
    predictors: &[Predictor],
    gain: f64,
    np: usize,
    sink: &mut dyn CoefficientSink,
) -> Result<(RelightErrors, Vec<(f32, f32)>)> {
    let mut loo = RelightErrors::new(capture.n_lights());
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
                model,
                predictors,
            };
            loo = std::mem::take(&mut loo).merge(block.run(&mut coefficients));
            super::widen_ranges(&mut ranges, &coefficients);
            sink.put(start + first, &coefficients, &[])?;
        }
        Ok(())
    })?;
    Ok((loo, ranges))
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
        let e = &model.pca_planes[j * d..(j + 1) * d];
        *cj = (0..d)
            .map(|r| e[r] * (x[r] - model.pca_mean[r]))
            .sum::<f64>() as f32;
    }
}
