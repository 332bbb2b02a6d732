//! relight's web format (CNR-ISTI), the one OpenLIME's RTI layer loads: a folder with
//! `info.json` and the coefficient planes as 8-bit RGB images `plane_0.png`, `plane_1.png`, …,
//! image g holding planes 3g, 3g + 1, 3g + 2 in its red, green and blue.
//!
//! `info.json` (the fields relight writes and OpenLIME's `ShaderRTI` reads): `width`, `height`,
//! `format` (the planes' file suffix; here `png`, lossless), `type` (`ptm`, `hsh`, `rbf`),
//! `colorspace` (`lrgb`, `rgb`, `mrgb`), `nplanes`, for `rbf` `lights` (x, y, z per render
//! position, flat; the camera frame: x right, y up, z toward the camera; any number of them:
//! OpenLIME's `ShaderRTI` takes their count as `ndimensions` = `lights.length / 3`), `sigma` and
//! `basis`, and
//! `materials`: one object with per-plane `scale` and `bias` (and `range` for `mrgb`).
//!
//! A byte b of plane q stands for the value (b / 255 − bias_q) · scale_q, in the viewer's units
//! (1 = white); photostereo's display units are the same. A viewer then computes, per channel:
//! - `rgb` (PTM, HSH): Σ_j w_j(l) · value(plane 3j + channel), with w_j relight's functions of
//!   the light: PTM in the order 1, l_x, l_y, l_x², l_x l_y, l_y²; HSH H0…H8 as `.rti` files.
//! - `lrgb` (PTM): planes 0–2 a base colour (scale 1, bias 0), planes 3… the luminance
//!   polynomial's six coefficients in the same order; colour = Σ_j w_j(l) value(3 + j) · base.
//! - `mrgb` (RBF): base_0(l) + Σ_j value(j) · base_{j+1}(l), with base_p(l) = Σ_i w_i(l) B_{p,i}
//!   the kernel interpolation of `basis` (`[plane 0…P][position][channel]` bytes: plane 0 the mean
//!   × 255, plane p ≥ 1 the component e as 127 + range_p · e, range_p = 127 / max |e|).
//!
//! Each plane image is also written as a Deep Zoom pyramid, `plane_G.dzi` and
//! `plane_G_files/` ([`super::tiles`]), which OpenLIME loads with its `deepzoom1px` layout.
//!
//! Pixels outside the mask are written as black: zero coefficients, and for RBF the
//! coefficients of a black pixel, −E μ.

use super::{for_each_band, FitSource, TermMap};
use crate::base::error::{Error, Result};
use crate::io::imageio::write_png8_bands;
use crate::solve::rti::{rbf, Basis, RtiFit};
use serde_json::{json, Value};
use std::ops::Range;
use std::path::Path;

/// The PTM terms in relight's order (1, x, y, x², xy, y²) as indices of photostereo's
/// (x², y², xy, x, y, 1).
const PTM_ORDER: [usize; 6] = [5, 3, 4, 0, 2, 1];

/// Writes `fit` as relight's web format into the folder `dir` (created; files in it are
/// replaced); returns the `info.json` it wrote.
pub fn write_relight(dir: &Path, fit: &dyn FitSource) -> Result<Value> {
    write_relight_with(dir, fit, None).map(|(info, _)| info)
}

/// [`write_relight`], and with `iiif` (the URI the folder `dir` is served at) each plane
/// image's IIIF level-0 tiles as well, in `plane_G/` with the id `IIIF/plane_G`
/// ([`super::tiles::write_iiif`]); returns `info.json` and the IIIF ids.
pub fn write_relight_with(
    dir: &Path,
    fit: &dyn FitSource,
    iiif: Option<&str>,
) -> Result<(Value, Vec<String>)> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let meta = fit.meta();
    let planes = Planes::new(fit)?;
    let outside = planes.outside(meta);
    let n = planes.count;
    let mut row = vec![0f32; n];
    // The ranges of the mask pixels' plane values, widened to hold 0 and the outside value.
    let mut ranges = vec![(0.0f64, 0.0f64); n];
    for_each_band(fit, false, |_, band| {
        for i in (0..band.inside.len()).filter(|&i| band.inside[i]) {
            planes.pixel(meta, band, i, &mut row);
            for (e, &v) in ranges.iter_mut().zip(&row) {
                e.0 = e.0.min(f64::from(v));
                e.1 = e.1.max(f64::from(v));
            }
        }
        Ok(())
    })?;
    let maps: Vec<TermMap> = (0..n)
        .map(|q| {
            if planes.fixed_base && q < 3 {
                return TermMap {
                    scale: 1.0,
                    bias: 0.0,
                };
            }
            let (lo, hi) = ranges[q];
            let (lo, hi) = (lo.min(outside[q]), hi.max(outside[q]));
            let span = (hi - lo).max(1e-9);
            TermMap {
                scale: span,
                bias: -lo / span,
            }
        })
        .collect();
    let (w, h) = (meta.width, meta.height);
    let mut ids = Vec::new();
    let mut band = super::Band::default();
    for g in 0..n.div_ceil(3) {
        let dzi = dir.join(format!("plane_{g}.dzi"));
        let tiles = dir.join(format!("plane_{g}"));
        let id = iiif.map(|base| format!("{base}/plane_{g}"));
        let mut pyramid = super::tiles::TilePyramid::new(
            (w, h),
            Some((&dzi, super::tiles::DZI_TILE, super::tiles::DZI_OVERLAP)),
            id.as_deref()
                .map(|id| (tiles.as_path(), id, super::tiles::IIIF_TILE)),
        )?;
        let plane = PlaneBytes {
            fit,
            planes: &planes,
            maps: &maps,
            outside: &outside,
            group: g,
        };
        write_png8_bands(
            &dir.join(format!("plane_{g}.png")),
            (w, h, 3),
            |rows, bytes| {
                plane.rows(rows, bytes, &mut band)?;
                // A small image comes whole: its rows go to the pyramid a PNG band's worth at a time.
                bytes
                    .chunks(64 * w * 3)
                    .try_for_each(|rows| pyramid.push(rows))
            },
        )?;
        pyramid.finish()?;
        ids.extend(id);
    }
    let info = planes.info(meta, &maps);
    let text = serde_json::to_string_pretty(&info)
        .map_err(|e| Error::invalid(format!("info.json: {e}")))?;
    super::write_file(&dir.join("info.json"), &[text.as_bytes()])?;
    Ok((info, ids))
}

/// The bytes of one plane image (planes 3g, 3g + 1, 3g + 2 in red, green, blue).
struct PlaneBytes<'a> {
    fit: &'a dyn FitSource,
    planes: &'a Planes,
    maps: &'a [TermMap],
    outside: &'a [f64],
    group: usize,
}

impl PlaneBytes<'_> {
    /// The image's rows `rows` into `out` (RGB), read from the fit in bands of at most
    /// [`FitSource::band_rows`] rows.
    fn rows(&self, rows: Range<usize>, out: &mut [u8], band: &mut super::Band) -> Result<()> {
        let meta = self.fit.meta();
        let (w, n) = (meta.width, self.planes.count);
        let mut row = vec![0f32; n];
        for y in rows.clone().step_by(self.fit.band_rows()) {
            let part = y..(y + self.fit.band_rows()).min(rows.end);
            self.fit.band(part.clone(), band)?;
            let at = (part.start - rows.start) * w * 3;
            let bytes = &mut out[at..at + part.len() * w * 3];
            for (i, px) in bytes.chunks_exact_mut(3).enumerate() {
                if band.inside[i] {
                    self.planes.pixel(meta, band, i, &mut row);
                }
                for (k, b) in px.iter_mut().enumerate() {
                    let q = 3 * self.group + k;
                    *b = match (q < n, band.inside[i]) {
                        (false, _) => 0,
                        (true, true) => quantise(f64::from(row[q]), &self.maps[q]),
                        (true, false) => quantise(self.outside[q], &self.maps[q]),
                    };
                }
            }
        }
        Ok(())
    }
}

/// The byte of `v` under `m`: round(255 (v / scale + bias)), clamped.
fn quantise(v: f64, m: &TermMap) -> u8 {
    (255.0 * (v / m.scale + m.bias)).round().clamp(0.0, 255.0) as u8
}

/// How a basis maps onto relight's planes.
struct Planes {
    count: usize,
    /// `lrgb`: planes 0–2 are the base colour, stored with scale 1 and bias 0.
    fixed_base: bool,
    /// `lrgb`: the factor dividing the chroma (and multiplying the luminance coefficients) so
    /// that the base colour is within [0, 1].
    chroma_scale: f64,
}

impl Planes {
    /// The planes of `fit`; for `lrgb` a pass over its chroma finds the chroma's greatest
    /// value.
    fn new(fit: &dyn FitSource) -> Result<Planes> {
        let meta = fit.meta();
        let lrgb = meta.basis.luminance();
        let count = match meta.basis {
            Basis::PtmLrgb => 9,
            Basis::Rbf => meta.basis.terms(),
            _ => 3 * meta.basis.terms(),
        };
        let mut chroma_scale = 1.0f64;
        if lrgb {
            // Outside the mask the chroma is 0, below the scale's start.
            for_each_band(fit, false, |_, band| {
                chroma_scale = band
                    .chroma
                    .iter()
                    .fold(chroma_scale, |m, &c| m.max(f64::from(c)));
                Ok(())
            })?;
        }
        Ok(Planes {
            count,
            fixed_base: lrgb,
            chroma_scale,
        })
    }

    /// The plane values of pixel `i` of `band` (in the mask) into `row`.
    fn pixel(&self, fit: &RtiFit, band: &super::Band, i: usize, row: &mut [f32]) {
        let (n, t, fc) = (self.count, fit.basis.terms(), fit.fitted_channels);
        let coef = &band.coefficients[i * fc * t..(i + 1) * fc * t];
        match fit.basis {
            Basis::PtmLrgb => {
                for (v, &c) in row.iter_mut().zip(&band.chroma[i * 3..i * 3 + 3]) {
                    *v = (f64::from(c) / self.chroma_scale) as f32;
                }
                for (j, &o) in PTM_ORDER.iter().enumerate() {
                    row[3 + j] = (f64::from(coef[o]) * self.chroma_scale) as f32;
                }
            }
            Basis::PtmRgb => {
                for (j, &o) in PTM_ORDER.iter().enumerate() {
                    for c in 0..3 {
                        row[3 * j + c] = coef[c.min(fc - 1) * t + o];
                    }
                }
            }
            Basis::Hsh2 | Basis::Hsh3 => {
                for j in 0..t {
                    for c in 0..3 {
                        row[3 * j + c] = coef[c.min(fc - 1) * t + j];
                    }
                }
            }
            Basis::Rbf => row[..n].copy_from_slice(coef),
        }
    }

    /// The values written outside the mask: 0, and for RBF those of a black pixel.
    fn outside(&self, fit: &RtiFit) -> Vec<f64> {
        let mut outside = vec![0.0; self.count];
        if let Some(m) = &fit.rbf {
            outside[..m.black().len()].copy_from_slice(&m.black());
        }
        outside
    }

    /// The `info.json` object.
    fn info(&self, fit: &RtiFit, maps: &[TermMap]) -> Value {
        let (kind, colorspace) = match fit.basis {
            Basis::PtmLrgb => ("ptm", "lrgb"),
            Basis::PtmRgb => ("ptm", "rgb"),
            Basis::Hsh2 | Basis::Hsh3 => ("hsh", "rgb"),
            Basis::Rbf => ("rbf", "mrgb"),
        };
        let round = |v: f64| (v * 1e6).round() / 1e6;
        let mut material = json!({
            "scale": maps.iter().map(|m| m.scale).collect::<Vec<_>>(),
            "bias": maps.iter().map(|m| m.bias).collect::<Vec<_>>(),
        });
        let mut info = json!({
            "width": fit.width,
            "height": fit.height,
            "format": "png",
            "type": kind,
            "colorspace": colorspace,
            "nplanes": self.count,
        });
        if let Some(m) = &fit.rbf {
            let (bytes, range) = rbf_basis(m);
            info["sigma"] = json!(m.sigma);
            info["lights"] = json!(m
                .lights
                .iter()
                .flat_map(|l| l.iter().map(|&v| round(v)))
                .collect::<Vec<_>>());
            info["basis"] = json!(bytes);
            material["range"] = json!(range);
        }
        info["materials"] = json!([material]);
        info
    }
}

/// An RBF model's `basis` bytes (`[plane 0…P][position][channel of 3]`) and the per-component
/// `range` (module documentation); a grey capture's channel is repeated.
fn rbf_basis(m: &rbf::RbfModel) -> (Vec<u8>, Vec<f64>) {
    let (n, c) = (m.lights.len(), m.channels);
    let d = n * c;
    let p = m.planes.len() / d;
    let range: Vec<f64> = (0..p)
        .map(|j| {
            let top = m.planes[j * d..(j + 1) * d]
                .iter()
                .fold(0.0f64, |a, &v| a.max(v.abs()));
            127.0 / top.max(1e-12)
        })
        .collect();
    let mut bytes = Vec::with_capacity((p + 1) * n * 3);
    for plane in 0..=p {
        for i in 0..n {
            for k in 0..3 {
                let r = i * c + k.min(c - 1);
                let b = if plane == 0 {
                    255.0 * m.mean[r]
                } else {
                    127.0 + range[plane - 1] * m.planes[(plane - 1) * d + r]
                };
                bytes.push(b.round().clamp(0.0, 255.0) as u8);
            }
        }
    }
    (bytes, range)
}
