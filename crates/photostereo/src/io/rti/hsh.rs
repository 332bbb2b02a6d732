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

use super::{frame_coefficients, term_ranges, write_file, TermMap};
use crate::base::error::{Error, Result};
use crate::solve::rti::{Basis, RtiFit};
use std::path::Path;

/// Writes `fit` (an HSH basis) to `path`; returns the per-term scale and bias it used.
pub fn write_hsh(path: &Path, fit: &RtiFit) -> Result<Vec<TermMap>> {
    if !matches!(fit.basis, Basis::Hsh2 | Basis::Hsh3) {
        return Err(Error::invalid(format!(
            "an .rti file of hemispherical harmonics holds an HSH basis, not {}",
            fit.basis.name()
        )));
    }
    let (w, h, t, fc) = (
        fit.width,
        fit.height,
        fit.basis.terms(),
        fit.fitted_channels,
    );
    let values = frame_coefficients(fit, 1.0);
    let maps: Vec<TermMap> = term_ranges(&values, t)
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
    let mut body = Vec::with_capacity(w * h * 3 * t);
    for i in 0..w * h {
        for band in 0..3 {
            let src = band.min(fc - 1);
            for (j, m) in maps.iter().enumerate() {
                let v = f64::from(values[(i * fc + src) * t + j]);
                // The map stored is the float32 one a reader applies.
                let (scale, bias) = (f64::from(m.scale as f32), f64::from(m.bias as f32));
                body.push(((v - bias) / scale * 255.0).round().clamp(0.0, 255.0) as u8);
            }
        }
    }
    write_file(path, &[&head, &body])?;
    Ok(maps)
}
