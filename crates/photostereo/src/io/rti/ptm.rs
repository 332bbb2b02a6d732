//! `.ptm` files: the PTM file format v1.2 of Malzbender, Gelb & Wolters (HP Labs, 2001),
//! uncompressed `PTM_FORMAT_LRGB` and `PTM_FORMAT_RGB`.
//!
//! Layout, as the format document describes it and RTIViewer reads it:
//! - ASCII lines: `PTM_1.2`, the format (`PTM_FORMAT_LRGB` or `PTM_FORMAT_RGB`), the width and
//!   the height (each on its own line), six scale floats, six bias integers.
//! - Then bytes, rows in reversed scan-line order (the bottom row first), left to right:
//!   - LRGB: six luminance coefficients a0…a5 per pixel for the whole image, then R, G, B per
//!     pixel for the whole image;
//!   - RGB: the six coefficients per pixel of the red channel for the whole image, then green,
//!     then blue.
//! - A stored byte c' maps to the coefficient a = (c' − bias) · scale, so c' = a / scale + bias.
//!
//! Units: coefficients are on the 8-bit scale (255 = full scale). A viewer shows channel C of
//! an RGB file as Σ a_j b_j(l) and of an LRGB file as R · L(l) / 255, with L = Σ a_j b_j(l) the
//! luminance polynomial. The fit's luminance Y and chroma χ_c (channel / Y) are stored as
//! L = 255 · m · Y and R, G, B = 255 · χ_c / m with m = max_c χ_c, so that the chroma bytes use
//! their whole range and R · L / 255 = 255 · χ_c · Y.
//!
//! RTIViewer truncates each dequantised coefficient to an integer; with the 8-bit scale above
//! that costs at most one unit of the polynomial's coefficient, about a quantisation step for a
//! term whose range spans 254 units.

use super::{for_each_band, Band, FitSource, TermMap};
use crate::base::error::{Error, Result};
use crate::solve::rti::{Basis, RtiFit};
use std::io::Write;
use std::path::Path;

/// Writes `fit` (a PTM basis) to `path`, row band by row band; returns the per-term scale and
/// bias it used.
pub fn write_ptm(path: &Path, fit: &dyn FitSource) -> Result<Vec<TermMap>> {
    let meta = fit.meta();
    let (w, h) = (meta.width, meta.height);
    let lrgb = match meta.basis {
        Basis::PtmLrgb => true,
        Basis::PtmRgb => false,
        other => {
            return Err(Error::invalid(format!(
                "a .ptm file holds a PTM basis, not {}",
                other.name()
            )))
        }
    };
    // Per frame pixel: the six coefficients per plane (one plane for LRGB, three for RGB).
    let planes = if lrgb { 1 } else { 3 };
    let (mut values, mut rgb) = (Vec::new(), Vec::new());
    let mut ranges = vec![(0.0f64, 0.0f64); 6];
    for_each_band(fit, false, |_, band| {
        ptm_values(meta, band, &mut values, &mut rgb);
        for (i, &v) in values.iter().enumerate() {
            let e = &mut ranges[i % 6];
            e.0 = e.0.min(f64::from(v));
            e.1 = e.1.max(f64::from(v));
        }
        Ok(())
    })?;
    let maps = ptm_maps(&ranges);
    let io = |e| Error::io(path, e);
    let mut out = std::io::BufWriter::new(std::fs::File::create(path).map_err(io)?);
    out.write_all(ptm_header(lrgb, w, h, &maps).as_bytes())
        .map_err(io)?;
    let mut body = Vec::new();
    for plane in 0..planes {
        for_each_band(fit, true, |rows, band| {
            ptm_values(meta, band, &mut values, &mut rgb);
            body.clear();
            for row in (0..rows.len()).rev() {
                for col in 0..w {
                    let i = row * w + col;
                    for (j, m) in maps.iter().enumerate() {
                        let v = f64::from(values[(i * planes + plane) * 6 + j]);
                        body.push((v / m.scale + m.bias).round().clamp(0.0, 255.0) as u8);
                    }
                }
            }
            out.write_all(&body).map_err(io)
        })?;
    }
    if lrgb {
        for_each_band(fit, true, |rows, band| {
            ptm_values(meta, band, &mut values, &mut rgb);
            for row in (0..rows.len()).rev() {
                out.write_all(&rgb[row * w * 3..(row + 1) * w * 3])
                    .map_err(io)?;
            }
            Ok(())
        })?;
    }
    out.flush().map_err(io)?;
    Ok(maps)
}

/// The values a band's pixels store, on the 8-bit scale (`[pixel][plane][term]`), and for
/// LRGB their chroma bytes (`[pixel][3]`): L = 255 · m · Y and 255 · χ_c / m (module
/// documentation); zero outside the mask.
fn ptm_values(fit: &RtiFit, band: &Band, values: &mut Vec<f32>, rgb: &mut Vec<u8>) {
    let lrgb = fit.basis.luminance();
    let planes = if lrgb { 1 } else { 3 };
    let n = band.inside.len();
    values.clear();
    values.resize(n * planes * 6, 0.0);
    rgb.clear();
    rgb.resize(if lrgb { n * 3 } else { 0 }, 0);
    let fc = fit.fitted_channels;
    for i in 0..n {
        let c = &band.coefficients[i * fc * 6..(i + 1) * fc * 6];
        if lrgb {
            let chroma = &band.chroma[i * 3..i * 3 + 3];
            let m = chroma.iter().fold(0f32, |a, &b| a.max(b));
            let m = if m > 0.0 { m } else { 1.0 };
            for j in 0..6 {
                values[i * 6 + j] = 255.0 * m * c[j];
            }
            for ch in 0..3 {
                rgb[i * 3 + ch] = (255.0 * chroma[ch] / m).round().clamp(0.0, 255.0) as u8;
            }
        } else {
            for plane in 0..3 {
                let src = plane.min(fc - 1);
                for j in 0..6 {
                    values[(i * 3 + plane) * 6 + j] = 255.0 * c[src * 6 + j];
                }
            }
        }
    }
}

/// Per term: scale = range / 254 over the values and 0 (`ranges`), bias = the integer byte of
/// 0, so that every value's byte a / scale + bias lies in [−0.5, 254.5].
fn ptm_maps(ranges: &[(f64, f64)]) -> Vec<TermMap> {
    ranges
        .iter()
        .map(|&(lo, hi)| {
            let scale = ((hi - lo) / 254.0).max(1e-6);
            TermMap {
                scale,
                bias: (-lo / scale).round().clamp(0.0, 255.0),
            }
        })
        .collect()
}

fn ptm_header(lrgb: bool, w: usize, h: usize, maps: &[TermMap]) -> String {
    let format = if lrgb {
        "PTM_FORMAT_LRGB"
    } else {
        "PTM_FORMAT_RGB"
    };
    let scales: Vec<String> = maps.iter().map(|m| format!("{}", m.scale)).collect();
    let biases: Vec<String> = maps.iter().map(|m| format!("{}", m.bias as i32)).collect();
    format!(
        "PTM_1.2\n{format}\n{w}\n{h}\n{}\n{}\n",
        scales.join(" "),
        biases.join(" ")
    )
}
