//! `.rti` files of hemispherical-harmonics coefficients, as RTIViewer reads them (its
//! "universal RTI" loader; the files RTIBuilder's HSH fitter and relight write).
//!
//! Layout:
//! - ASCII lines ending in `\n`: `#HSH1.2` (lines starting with `#` are comments), the RTI type
//!   `3` (HSH), `WIDTH HEIGHT 3` (three colour bands), `TERMS 2 1` (coefficients per band,
//!   basis type 2, one byte per coefficient).
//! - `TERMS` little-endian float32 scales, then `TERMS` float32 biases, one per term, shared by
//!   the three bands.
//! - Bytes, rows from the top, left to right; per pixel the `TERMS` red coefficients, then the
//!   green, then the blue. A byte c maps to the coefficient c / 255 · scale + bias.
//!
//! Units: a viewer shows Σ_j c_j H_j(l) × 255 per band, so the coefficients are in display
//! units (1 = full scale). The basis H_j is [`crate::solve::rti::Basis::eval`]'s.

use super::{for_each_band, FitSource, TermMap};
use crate::base::error::{Error, Result};
use crate::solve::rti::Basis;
use std::io::Write;
use std::path::Path;

/// Writes `fit` (an HSH basis) to `path`, row band by row band; returns the per-term scale and
/// bias it used.
pub fn write_hsh(path: &Path, fit: &dyn FitSource) -> Result<Vec<TermMap>> {
    let meta = fit.meta();
    if !matches!(meta.basis, Basis::Hsh2 | Basis::Hsh3) {
        return Err(Error::invalid(format!(
            "an .rti file of hemispherical harmonics holds an HSH basis, not {}",
            meta.basis.name()
        )));
    }
    let (w, h, t, fc) = (
        meta.width,
        meta.height,
        meta.basis.terms(),
        meta.fitted_channels,
    );
    // The ranges over the frame: the mask's coefficients and the zeros outside.
    let mut ranges = vec![(0.0f64, 0.0f64); t];
    for_each_band(fit, false, |_, band| {
        for (i, &v) in band.coefficients.iter().enumerate() {
            let e = &mut ranges[i % t];
            e.0 = e.0.min(f64::from(v));
            e.1 = e.1.max(f64::from(v));
        }
        Ok(())
    })?;
    let maps: Vec<TermMap> = ranges
        .into_iter()
        .map(|(lo, hi)| TermMap {
            scale: (hi - lo).max(1e-9),
            bias: lo,
        })
        .collect();
    let mut head = format!("#HSH1.2\n3\n{w} {h} 3\n{t} 2 1\n").into_bytes();
    for m in &maps {
        head.extend_from_slice(&(m.scale as f32).to_le_bytes());
    }
    for m in &maps {
        head.extend_from_slice(&(m.bias as f32).to_le_bytes());
    }
    let io = |e| Error::io(path, e);
    let mut out = std::io::BufWriter::new(std::fs::File::create(path).map_err(io)?);
    out.write_all(&head).map_err(io)?;
    let mut body = Vec::new();
    for_each_band(fit, false, |_, band| {
        body.clear();
        for i in 0..band.inside.len() {
            for band_c in 0..3 {
                let src = band_c.min(fc - 1);
                for (j, m) in maps.iter().enumerate() {
                    let v = f64::from(band.coefficients[(i * fc + src) * t + j]);
                    // The map stored is the float32 one a reader applies.
                    let (scale, bias) = (f64::from(m.scale as f32), f64::from(m.bias as f32));
                    body.push(((v - bias) / scale * 255.0).round().clamp(0.0, 255.0) as u8);
                }
            }
        }
        out.write_all(&body).map_err(io)
    })?;
    out.flush().map_err(io)?;
    Ok(maps)
}
