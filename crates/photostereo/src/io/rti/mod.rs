//! Relightable-image files of an RTI fit ([`crate::solve::rti`]): `.ptm` (HP Labs' PTM file
//! format v1.2, [`ptm`]), `.rti` (the hemispherical-harmonics layout RTIViewer reads, [`hsh`])
//! and relight's web format that OpenLIME reads ([`relight`]), with the float coefficients
//! beside them as `.npy` for checking the quantisation.
//!
//! Both formats store one byte per coefficient with a per-term linear map shared by every pixel
//! (and channel); [`TermMap`] holds it. Pixels outside the mask are written with zero
//! coefficients (and, for PTM LRGB, black chroma).

pub mod hsh;
pub mod ptm;
pub mod relight;
pub mod tiles;

use crate::base::error::Result;
use crate::io::export::write_npy_f32;
use crate::solve::rti::RtiFit;
use std::io::Write;
use std::path::Path;

/// The byte map of one term: `value = (byte − offset) · step` for PTM (offset an integer, the
/// format's "bias"), `value = byte / 255 · step + offset` for HSH.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct TermMap {
    /// The file's scale of the term.
    pub scale: f64,
    /// The file's bias of the term.
    pub bias: f64,
}

/// A fit's coefficients scattered over the frame: `[row][col][fitted channel][term]`, zero
/// outside the mask.
pub(crate) fn frame_coefficients(fit: &RtiFit, unit: f64) -> Vec<f32> {
    let per = fit.fitted_channels * fit.basis.terms();
    let mut out = vec![0f32; fit.width * fit.height * per];
    for (p, &i) in fit.pixels.iter().enumerate() {
        let i = i as usize;
        for (o, &c) in out[i * per..(i + 1) * per]
            .iter_mut()
            .zip(&fit.coefficients[p * per..(p + 1) * per])
        {
            *o = (f64::from(c) * unit) as f32;
        }
    }
    out
}

/// Per term, the least and greatest of `values` (`[..][term]`, `terms` per row), widened to
/// hold 0.
pub(crate) fn term_ranges(values: &[f32], terms: usize) -> Vec<(f64, f64)> {
    let mut r = vec![(0.0f64, 0.0f64); terms];
    for (i, &v) in values.iter().enumerate() {
        let e = &mut r[i % terms];
        e.0 = e.0.min(f64::from(v));
        e.1 = e.1.max(f64::from(v));
    }
    r
}

/// Writes `coefficients.npy` (H, W, fitted channels, T), display units, and for PTM LRGB
/// `chroma.npy` (H, W, 3): the floats the files quantise.
pub fn write_float_coefficients(dir: &Path, fit: &RtiFit) -> Result<()> {
    let (w, h, t) = (fit.width, fit.height, fit.basis.terms());
    write_npy_f32(
        &dir.join("coefficients.npy"),
        &[h, w, fit.fitted_channels, t],
        &frame_coefficients(fit, 1.0),
    )?;
    if fit.basis.luminance() {
        let mut chroma = vec![0f32; w * h * 3];
        for (p, &i) in fit.pixels.iter().enumerate() {
            let i = i as usize;
            chroma[i * 3..i * 3 + 3].copy_from_slice(&fit.chroma[p * 3..p * 3 + 3]);
        }
        write_npy_f32(&dir.join("chroma.npy"), &[h, w, 3], &chroma)?;
    }
    Ok(())
}

/// Writes an RBF fit's model as `.npy` (1 + P, N, C): the mean reading per light and channel,
/// then the P principal components (display units); returns the file's description. Fails
/// for a fit of another basis.
pub fn write_rbf_basis(path: &Path, fit: &RtiFit) -> Result<serde_json::Value> {
    let model = fit.rbf.as_ref().ok_or_else(|| {
        crate::base::error::Error::invalid(format!(
            "{} is not an RBF fit: no basis to write",
            fit.basis.name()
        ))
    })?;
    let (n, c) = (model.lights.len(), model.channels);
    let values: Vec<f32> = model
        .mean
        .iter()
        .chain(&model.planes)
        .map(|&v| v as f32)
        .collect();
    write_npy_f32(path, &[1 + fit.basis.terms(), n, c], &values)?;
    Ok(serde_json::json!({ "sigma": model.sigma, "shape": [1 + fit.basis.terms(), n, c] }))
}

/// The name of the file describing a fit's model for the viewer ([`write_model_json`]).
pub use crate::io::viewer::rti::MODEL_JSON;

/// Writes `rti.json`: what the viewer needs besides the coefficients (`coefficients.npy`,
/// `chroma.npy`, `basis.npy`) to relight the fit under any light: the basis, the frame, the
/// channels, the display gain, and for RBF the kernel width σ and the light directions (unit,
/// camera frame: x right, y up, z toward the camera) its model interpolates over.
pub fn write_model_json(path: &Path, fit: &RtiFit) -> Result<serde_json::Value> {
    let mut v = serde_json::json!({
        "format": "photostereo-rti 1",
        "basis": fit.basis.name(),
        "width": fit.width,
        "height": fit.height,
        "channels": fit.channels,
        "fitted_channels": fit.fitted_channels,
        "terms": fit.basis.terms(),
        "display_gain": fit.gain,
    });
    if let Some(m) = &fit.rbf {
        v["rbf"] = serde_json::json!({ "sigma": m.sigma, "lights": m.lights });
    }
    let text = serde_json::to_string_pretty(&v)
        .map_err(|e| crate::base::error::Error::invalid(format!("{MODEL_JSON}: {e}")))?;
    write_file(path, &[text.as_bytes()])?;
    Ok(v)
}

/// Writes `bytes` to `path` through a buffer, naming the file on failure.
pub(crate) fn write_file(path: &Path, parts: &[&[u8]]) -> Result<()> {
    let io = |e| crate::base::error::Error::io(path, e);
    let mut f = std::io::BufWriter::new(std::fs::File::create(path).map_err(io)?);
    for p in parts {
        f.write_all(p).map_err(io)?;
    }
    f.flush().map_err(io)
}
