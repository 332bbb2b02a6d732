//! The viewer's RTI layer, computed on the CPU: the relightable image an RTI fit wrote
//! (`rti.json`, `coefficients.npy`, `chroma.npy` for PTM LRGB, `basis.npy` for RBF; see
//! [`crate::io::rti`]) relit under any light, with the enhancement modes heritage viewers offer.
//! The page's fragment shader (`assets/image.frag`, layer `rti`) evaluates the same expression
//! from the same planes; the browser test compares a screenshot with [`relight_rti`].
//!
//! A pixel's planes v_q (q < K = fitted channels × T, then for PTM LRGB its chroma) and the
//! light l (unit, camera frame) give per channel c
//!
//! ```text
//! rti_c = w0_c(l) + Σ_q v_q · w_q,c(l)          (× chroma_c for PTM LRGB)
//! ```
//!
//! with, for PTM and HSH, w_q,c = b_j(l) on the planes of channel c (every channel for a fit of
//! one channel) and w0 = 0 ([`crate::solve::rti::Basis::eval`]), and for RBF w0 the interpolated
//! mean and w_q the interpolated component q ([`crate::solve::rti::rbf::RbfModel::light_basis`]).
//!
//! Enhancement modes, all off by default:
//! - diffuse gain g (PTM only; Malzbender, Gelb & Wolters 2001, "Polynomial texture maps",
//!   §5.2): each channel's polynomial L(u, v) = a0 u² + a1 v² + a2 uv + a3 u + a4 v + a5 is
//!   replaced by the one with the same value and gradient at (u0, v0) and g times its second
//!   derivatives; (u0, v0) is the stationary point of the channels' mean polynomial,
//!   u0 = (a2 a4 − 2 a1 a3) / (4 a0 a1 − a2²), v0 = (a2 a3 − 2 a0 a4) / (4 a0 a1 − a2²), the
//!   projection of the surface normal, clamped to the unit disk ((0, 0) when the denominator is
//!   0);
//! - specular enhancement from the normals n of the run: + ks · (n · h)^α where n · l > 0,
//!   h = normalize(l + v), v = (0, 0, 1), white;
//! - unsharp masking of the normals: n' = normalize(n + k (n − n̄)), n̄ the normals blurred by a
//!   Gaussian of [`UNSHARP_SIGMA`] pixels ([`blur_normals`]), adds the change it makes to the
//!   Lambertian shading of the run's albedo, ρ / white · (max(0, n' · l) − max(0, n · l)).
//!
//! The displayed value is encode(clamp(2^exposure · (rti + specular + unsharp), 0, 1)), encode
//! the sRGB transfer function or the identity, as the relight layer's (`io::viewer::relight`).

use super::relight::{display_byte, RelightParams};
use crate::base::error::{Error, Result};
use crate::solve::rti::{rbf::RbfModel, Basis, MAX_TERMS};
use rayon::prelude::*;
use std::path::Path;

/// The file an RTI fit's model is described in, beside its arrays
/// (`crate::io::rti::write_model_json` writes it).
pub const MODEL_JSON: &str = "rti.json";

/// The unsharp mask's Gaussian, standard deviation in pixels of the level shown (support
/// ±3σ).
pub const UNSHARP_SIGMA: f32 = 2.0;

/// An RTI fit as the viewer reads it.
#[derive(Clone, Debug)]
pub struct RtiLayer {
    /// The basis.
    pub basis: Basis,
    /// Planes of coefficients per pixel, K = fitted channels × T.
    pub coefficient_planes: usize,
    /// Channels fitted (1 for PTM LRGB and RBF, or for a grey capture).
    pub fitted_channels: usize,
    /// Whether three chroma planes follow the coefficients (PTM LRGB).
    pub chroma: bool,
    /// Per frame pixel, the planes (`[pixel][plane]`, K + 3 with chroma), display units.
    pub values: Vec<f32>,
    /// RBF: the model the coefficients weight.
    pub rbf: Option<RbfModel>,
}

/// The parameters of [`relight_rti`] besides the light and exposure (taken from
/// [`RelightParams`] with its specular weight and shininess).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Enhancement {
    /// Diffuse gain g (1: off); PTM only.
    pub diffuse_gain: f32,
    /// Unsharp-mask amount k of the normals (0: off).
    pub unsharp: f32,
}

impl Default for Enhancement {
    fn default() -> Self {
        Enhancement {
            diffuse_gain: 1.0,
            unsharp: 0.0,
        }
    }
}

fn npy_err(path: &Path, e: impl std::fmt::Display) -> Error {
    Error::file(path, format!("reading .npy failed: {e}"))
}

impl RtiLayer {
    /// Total planes per pixel (coefficients and chroma).
    pub fn planes(&self) -> usize {
        self.coefficient_planes + if self.chroma { 3 } else { 0 }
    }

    /// The fit in `dir` (`rti.json` and its arrays), `None` when the folder has no `rti.json`;
    /// its frame must be `width × height`.
    pub fn read(dir: &Path, width: usize, height: usize) -> Result<Option<RtiLayer>> {
        let mp = dir.join(MODEL_JSON);
        if !mp.is_file() {
            return Ok(None);
        }
        let text = std::fs::read_to_string(&mp).map_err(|e| Error::io(&mp, e))?;
        let model: serde_json::Value =
            serde_json::from_str(&text).map_err(|e| Error::file(&mp, format!("not JSON: {e}")))?;
        let basis: Basis = model["basis"]
            .as_str()
            .ok_or_else(|| Error::file(&mp, "no \"basis\""))?
            .parse()?;
        let cp = dir.join("coefficients.npy");
        let c: ndarray::Array4<f32> = ndarray_npy::read_npy(&cp).map_err(|e| npy_err(&cp, e))?;
        let (h, w, fc, t) = c.dim();
        if (h, w) != (height, width) || t != basis.terms() || !(fc == 1 || fc == 3) {
            return Err(Error::file(
                &cp,
                format!(
                    "shape ({h}, {w}, {fc}, {t}): expected ({height}, {width}, 1 or 3, {}) for {}",
                    basis.terms(),
                    basis.name()
                ),
            ));
        }
        let k = fc * t;
        let chroma = basis.luminance();
        let per = k + if chroma { 3 } else { 0 };
        let mut values = vec![0f32; w * h * per];
        let coef = c.as_standard_layout();
        let coef = coef.as_slice().expect("standard layout");
        for (i, px) in values.chunks_exact_mut(per).enumerate() {
            px[..k].copy_from_slice(&coef[i * k..(i + 1) * k]);
        }
        if chroma {
            let chp = dir.join("chroma.npy");
            let ch: ndarray::Array3<f32> =
                ndarray_npy::read_npy(&chp).map_err(|e| npy_err(&chp, e))?;
            if ch.dim() != (h, w, 3) {
                return Err(Error::file(
                    &chp,
                    format!("shape {:?}: expected ({h}, {w}, 3)", ch.dim()),
                ));
            }
            let ch = ch.as_standard_layout();
            let ch = ch.as_slice().expect("standard layout");
            for (i, px) in values.chunks_exact_mut(per).enumerate() {
                px[k..].copy_from_slice(&ch[i * 3..i * 3 + 3]);
            }
        }
        let rbf = match basis {
            Basis::Rbf => Some(read_rbf(dir, &mp, &model)?),
            _ => None,
        };
        Ok(Some(RtiLayer {
            basis,
            coefficient_planes: k,
            fitted_channels: fc,
            chroma,
            values,
            rbf,
        }))
    }

    /// The weights of the planes under the unit light `l`: w0 and w_q per channel (module
    /// documentation).
    pub fn weights(&self, l: [f64; 3]) -> ([f64; 3], Vec<[f64; 3]>) {
        let k = self.coefficient_planes;
        let mut w = vec![[0.0; 3]; k];
        if let Some(m) = &self.rbf {
            let c = m.channels;
            let mut b = vec![0.0; (k + 1) * c];
            m.light_basis(l, &mut b);
            let at = |p: usize, ch: usize| b[p * c + ch.min(c - 1)];
            for (q, wq) in w.iter_mut().enumerate() {
                *wq = [at(q + 1, 0), at(q + 1, 1), at(q + 1, 2)];
            }
            return ([at(0, 0), at(0, 1), at(0, 2)], w);
        }
        let t = self.basis.terms();
        let mut b = [0.0; MAX_TERMS];
        self.basis.eval(l, &mut b);
        for (q, wq) in w.iter_mut().enumerate() {
            let (ch, j) = (q / t, q % t);
            *wq = if self.fitted_channels == 1 {
                [b[j]; 3]
            } else {
                let mut v = [0.0; 3];
                v[ch] = b[j];
                v
            };
        }
        ([0.0; 3], w)
    }
}

/// The RBF model of a fit: σ and the lights from `rti.json`, the mean and components from
/// `basis.npy` (1 + P, N, C).
fn read_rbf(dir: &Path, mp: &Path, model: &serde_json::Value) -> Result<RbfModel> {
    let sigma = model["rbf"]["sigma"]
        .as_f64()
        .ok_or_else(|| Error::file(mp, "rbf without \"sigma\""))?;
    let lights: Vec<[f64; 3]> = serde_json::from_value(model["rbf"]["lights"].clone())
        .map_err(|e| Error::file(mp, format!("rbf \"lights\": {e}")))?;
    let bp = dir.join("basis.npy");
    let b: ndarray::Array3<f32> = ndarray_npy::read_npy(&bp).map_err(|e| npy_err(&bp, e))?;
    let (p1, n, c) = b.dim();
    if p1 != Basis::Rbf.terms() + 1 || n != lights.len() || !(c == 1 || c == 3) {
        return Err(Error::file(
            &bp,
            format!(
                "shape ({p1}, {n}, {c}): expected ({}, {}, 1 or 3)",
                Basis::Rbf.terms() + 1,
                lights.len()
            ),
        ));
    }
    let v: Vec<f64> = b.iter().map(|&x| f64::from(x)).collect();
    let d = n * c;
    Ok(RbfModel {
        lights,
        sigma,
        channels: c,
        mean: v[..d].to_vec(),
        planes: v[d..].to_vec(),
        explained_variance: f64::NAN,
        pca_pixels: 0,
        interpolant: crate::solve::rti::rbf::Interpolant::Kernel,
        capture_lights: Vec::new(),
        pca_mean: Vec::new(),
        pca_planes: Vec::new(),
    })
}

/// A PTM polynomial (photostereo's order a0 u² + a1 v² + a2 uv + a3 u + a4 v + a5) with its
/// second derivatives scaled by `g` about (u0, v0), keeping its value and gradient there
/// (Malzbender et al. 2001, §5.2).
pub fn diffuse_gain(a: [f64; 6], (u0, v0): (f64, f64), g: f64) -> [f64; 6] {
    let a3 = (1.0 - g) * (2.0 * a[0] * u0 + a[2] * v0) + a[3];
    let a4 = (1.0 - g) * (2.0 * a[1] * v0 + a[2] * u0) + a[4];
    let a5 = (1.0 - g) * (a[0] * u0 * u0 + a[1] * v0 * v0 + a[2] * u0 * v0)
        + (a[3] - a3) * u0
        + (a[4] - a4) * v0
        + a[5];
    [g * a[0], g * a[1], g * a[2], a3, a4, a5]
}

/// The stationary point of a PTM polynomial, the projection of the surface normal, clamped
/// to the unit disk; (0, 0) when it has none.
pub fn ptm_normal(a: [f64; 6]) -> (f64, f64) {
    let den = 4.0 * a[0] * a[1] - a[2] * a[2];
    if den == 0.0 || !den.is_finite() {
        return (0.0, 0.0);
    }
    let u = (a[2] * a[4] - 2.0 * a[1] * a[3]) / den;
    let v = (a[2] * a[3] - 2.0 * a[0] * a[4]) / den;
    let r = (u * u + v * v).sqrt();
    if !r.is_finite() {
        (0.0, 0.0)
    } else if r > 1.0 {
        (u / r, v / r)
    } else {
        (u, v)
    }
}

/// The normals blurred by a Gaussian of `sigma` pixels over the mask (`(0, 0, 0)` outside):
/// each the normalised weighted sum of the inside normals within ±⌈3σ⌉ (separable, rows then
/// columns), `(0, 0, 0)` outside the mask.
pub fn blur_normals(w: usize, h: usize, normals: &[[f32; 3]], sigma: f32) -> Vec<[f32; 3]> {
    let r = (3.0 * sigma).ceil() as isize;
    let k: Vec<f32> = (-r..=r)
        .map(|d| (-(d * d) as f32 / (2.0 * sigma * sigma)).exp())
        .collect();
    let pass = |src: &[[f32; 3]], horizontal: bool| -> Vec<[f32; 3]> {
        (0..w * h)
            .into_par_iter()
            .map(|i| {
                let (y, x) = ((i / w) as isize, (i % w) as isize);
                let mut s = [0f32; 3];
                for (o, &kw) in (-r..=r).zip(&k) {
                    let (yy, xx) = if horizontal { (y, x + o) } else { (y + o, x) };
                    if yy < 0 || xx < 0 || yy >= h as isize || xx >= w as isize {
                        continue;
                    }
                    let v = src[yy as usize * w + xx as usize];
                    for c in 0..3 {
                        s[c] += kw * v[c];
                    }
                }
                s
            })
            .collect()
    };
    let b = pass(&pass(normals, true), false);
    b.iter()
        .zip(normals)
        .map(|(v, n)| {
            let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            if *n == [0.0; 3] || len <= 0.0 {
                [0.0; 3]
            } else {
                v.map(|x| x / len)
            }
        })
        .collect()
}

fn normalize(v: [f32; 3]) -> [f32; 3] {
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if n > 0.0 {
        v.map(|x| x / n)
    } else {
        [0.0, 0.0, 1.0]
    }
}

fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// The RTI value of one pixel's planes under weights `(w0, w)` (`basis` values `b` for the
/// diffuse gain), per channel, display units.
fn rti_value(
    layer: &RtiLayer,
    v: &[f32],
    (w0, w): &([f64; 3], Vec<[f64; 3]>),
    b: &[f64; 6],
    g: f64,
) -> [f64; 3] {
    let k = layer.coefficient_planes;
    let mut out = *w0;
    let ptm = matches!(layer.basis, Basis::PtmLrgb | Basis::PtmRgb);
    if ptm && g != 1.0 {
        let fc = layer.fitted_channels;
        let poly = |ch: usize| -> [f64; 6] { std::array::from_fn(|j| f64::from(v[ch * 6 + j])) };
        let mean: [f64; 6] =
            std::array::from_fn(|j| (0..fc).map(|ch| poly(ch)[j]).sum::<f64>() / fc as f64);
        let at = ptm_normal(mean);
        for (ch, o) in out.iter_mut().enumerate() {
            let a = diffuse_gain(poly(ch.min(fc - 1)), at, g);
            *o = a.iter().zip(b).map(|(x, y)| x * y).sum();
        }
    } else {
        for (q, wq) in w.iter().enumerate().take(k) {
            for (o, x) in out.iter_mut().zip(wq) {
                *o += f64::from(v[q]) * x;
            }
        }
    }
    if layer.chroma {
        for (o, c) in out.iter_mut().zip(&v[k..k + 3]) {
            *o *= f64::from(*c);
        }
    }
    out
}

/// Relights an RTI fit: `normals` (`H·W`, `(0, 0, 0)` outside the mask) mark the pixels drawn
/// and serve the enhancements with `blurred` ([`blur_normals`] of them) and `albedo` (`H·W`
/// RGB, shown relative to `p.white`). Returns `H·W` RGB bytes, black outside the mask, as the
/// page draws them (module documentation).
pub fn relight_rti(
    layer: &RtiLayer,
    normals: &[[f32; 3]],
    blurred: &[[f32; 3]],
    albedo: &[[f32; 3]],
    p: &RelightParams,
    e: &Enhancement,
) -> Vec<[u8; 3]> {
    let l = normalize(p.light);
    let ld = l.map(f64::from);
    let weights = layer.weights(ld);
    let mut b = [0.0; MAX_TERMS];
    Basis::PtmRgb.eval(ld, &mut b);
    let b6: [f64; 6] = std::array::from_fn(|j| b[j]);
    let per = layer.planes();
    let h = normalize([l[0], l[1], l[2] + 1.0]);
    let gain = p.exposure.exp2();
    normals
        .iter()
        .enumerate()
        .map(|(i, &n)| {
            if n == [0.0; 3] {
                return [0; 3];
            }
            let v = &layer.values[i * per..(i + 1) * per];
            let rti = rti_value(layer, v, &weights, &b6, f64::from(e.diffuse_gain));
            let d = dot(n, l).max(0.0);
            let s = if d > 0.0 {
                dot(n, h).max(0.0).powf(p.shininess)
            } else {
                0.0
            };
            let sharp = if e.unsharp != 0.0 {
                let nb = blurred[i];
                let n2 = normalize(std::array::from_fn(|c| n[c] + e.unsharp * (n[c] - nb[c])));
                dot(n2, l).max(0.0) - d
            } else {
                0.0
            };
            std::array::from_fn(|c| {
                let lin = gain * (rti[c] as f32 + p.specular * s + albedo[i][c] / p.white * sharp);
                display_byte(lin, p.srgb)
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn diffuse_gain_keeps_value_and_gradient_and_scales_curvature() {
        let a = [-0.7, -0.5, 0.2, 0.3, -0.1, 0.6];
        let at = ptm_normal(a);
        let l = |a: &[f64; 6], u: f64, v: f64| {
            a[0] * u * u + a[1] * v * v + a[2] * u * v + a[3] * u + a[4] * v + a[5]
        };
        // The stationary point: both derivatives vanish there.
        let (u0, v0) = at;
        assert!((2.0 * a[0] * u0 + a[2] * v0 + a[3]).abs() < 1e-12);
        assert!((2.0 * a[1] * v0 + a[2] * u0 + a[4]).abs() < 1e-12);
        let g = 3.0;
        let b = diffuse_gain(a, (0.25, -0.4), g);
        let (u, v, e) = (0.25, -0.4, 1e-6);
        assert!((l(&a, u, v) - l(&b, u, v)).abs() < 1e-12);
        for (du, dv) in [(e, 0.0), (0.0, e)] {
            let ga = (l(&a, u + du, v + dv) - l(&a, u - du, v - dv)) / (2.0 * e);
            let gb = (l(&b, u + du, v + dv) - l(&b, u - du, v - dv)) / (2.0 * e);
            assert!((ga - gb).abs() < 1e-6, "{ga} {gb}");
        }
        assert_eq!([b[0], b[1], b[2]], [g * a[0], g * a[1], g * a[2]]);
        // A plane has no stationary point: (0, 0).
        assert_eq!(ptm_normal([0.0, 0.0, 0.0, 0.3, 0.2, 0.1]), (0.0, 0.0));
    }

    #[test]
    fn blur_keeps_a_uniform_field_and_stays_inside() {
        let (w, h) = (9, 7);
        let n0 = normalize([0.3, -0.2, 0.9]);
        let mut n = vec![n0; w * h];
        n[0] = [0.0; 3];
        let b = blur_normals(w, h, &n, 1.5);
        assert_eq!(b[0], [0.0; 3]);
        for v in &b[1..] {
            for c in 0..3 {
                assert!((v[c] - n0[c]).abs() < 1e-6);
            }
        }
    }
}
