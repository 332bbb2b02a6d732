//! Relightable-image files of an RTI fit ([`crate::solve::rti`]): `.ptm` (HP Labs' PTM file
//! format v1.2, [`ptm`]), `.rti` (the hemispherical-harmonics layout RTIViewer reads, [`hsh`])
//! and relight's web format that OpenLIME reads ([`relight`]), with the float coefficients
//! beside them as `.npy` for checking the quantisation.
//!
//! Both formats store one byte per coefficient with a per-term linear map shared by every pixel
//! (and channel); [`TermMap`] holds it. Pixels outside the mask are written with zero
//! coefficients (and, for PTM LRGB, black chroma).
//!
//! Every file is written by row bands of the frame ([`FitSource`]), from a fit held in memory
//! ([`RtiFit`]) or from its coefficients on disk ([`StoredFit`]: `coefficients.npy` and
//! `chroma.npy`, written as the fit makes them): what is held is one band of
//! [`BAND_BYTES`] of floats at a time, and for relight's plane images a PNG band and their
//! tile pyramids' row strips ([`tiles::TilePyramid`], [`tiles::BYTES_PER_COLUMN`] a column):
//! nothing the size of the frame.

pub mod hsh;
pub mod ptm;
pub mod relight;
pub mod tiles;

use crate::base::error::{Error, Result};
use crate::io::export::write_npy_f32;
use crate::solve::rti::{CoefficientSink, RtiFit};
use std::fs::File;
use std::io::Write;
use std::ops::Range;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

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

/// Writes an RBF fit's model as `.npy` (1 + P, M, C): the mean at each of the M render
/// positions and channel, then the P principal components there (display units); returns the
/// file's description. Fails for a fit of another basis.
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
/// channels, the display gain, and for RBF the kernel width σ and the render positions (unit,
/// camera frame: x right, y up, z toward the camera) its model's kernel average runs over.
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

/// Bytes of floats a row band holds at most (coefficients and chroma), but one row at least.
pub const BAND_BYTES: usize = 16 << 20;

/// One row band of a fit over the frame: rows × columns, zero outside the mask.
#[derive(Default)]
pub struct Band {
    /// `[row][col][fitted channel][term]`, display units.
    pub coefficients: Vec<f32>,
    /// PTM LRGB: `[row][col][3]`; empty otherwise.
    pub chroma: Vec<f32>,
    /// `[row][col]`: whether the pixel is in the mask.
    pub inside: Vec<bool>,
}

/// A fit whose coefficients can be read a row band of the frame at a time.
pub trait FitSource {
    /// The fit's basis, frame, mask pixels, gain, model and ranges (its `coefficients` and
    /// `chroma` may be empty: read them with [`FitSource::band`]).
    fn meta(&self) -> &RtiFit;
    /// The frame rows `rows` into `band` (resized).
    fn band(&self, rows: Range<usize>, band: &mut Band) -> Result<()>;
    /// Rows a band holds: as many as [`BAND_BYTES`] of floats allow, one at least.
    fn band_rows(&self) -> usize {
        let meta = self.meta();
        let (per, chroma) = band_floats(meta);
        (BAND_BYTES / (4 * (per + chroma) * meta.width.max(1))).max(1)
    }
}

/// Floats per frame pixel of a fit's band: coefficients, then the chroma of PTM LRGB.
fn band_floats(fit: &RtiFit) -> (usize, usize) {
    let chroma = if fit.basis.luminance() { 3 } else { 0 };
    (fit.fitted_channels * fit.basis.terms(), chroma)
}

/// Resizes `band` to `rows` rows of `fit`'s frame, all zero and outside, and marks the mask
/// pixels inside; returns the range of mask pixels (indices into `fit.pixels`) in the band.
fn clear_band(fit: &RtiFit, rows: &Range<usize>, band: &mut Band) -> Range<usize> {
    let (per, chroma) = band_floats(fit);
    let n = rows.len() * fit.width;
    for (v, len) in [
        (&mut band.coefficients, n * per),
        (&mut band.chroma, n * chroma),
    ] {
        v.clear();
        v.resize(len, 0.0);
    }
    band.inside.clear();
    band.inside.resize(n, false);
    let (a, b) = (rows.start * fit.width, rows.end * fit.width);
    let p0 = fit.pixels.partition_point(|&i| (i as usize) < a);
    let p1 = fit.pixels.partition_point(|&i| (i as usize) < b);
    for &i in &fit.pixels[p0..p1] {
        band.inside[i as usize - a] = true;
    }
    p0..p1
}

impl FitSource for RtiFit {
    fn meta(&self) -> &RtiFit {
        self
    }

    fn band(&self, rows: Range<usize>, band: &mut Band) -> Result<()> {
        let (per, chroma) = band_floats(self);
        let a = rows.start * self.width;
        for p in clear_band(self, &rows, band) {
            let i = self.pixels[p] as usize - a;
            band.coefficients[i * per..(i + 1) * per]
                .copy_from_slice(&self.coefficients[p * per..(p + 1) * per]);
            if chroma > 0 {
                band.chroma[i * 3..i * 3 + 3].copy_from_slice(&self.chroma[p * 3..p * 3 + 3]);
            }
        }
        Ok(())
    }
}

/// Calls `f` on each row band of `fit`'s frame ([`BAND_BYTES`]), from the top or, with
/// `bottom_up`, from the bottom.
pub fn for_each_band(
    fit: &dyn FitSource,
    bottom_up: bool,
    mut f: impl FnMut(Range<usize>, &Band) -> Result<()>,
) -> Result<()> {
    let meta = fit.meta();
    let rows = fit.band_rows();
    let mut starts: Vec<usize> = (0..meta.height).step_by(rows).collect();
    if bottom_up {
        starts.reverse();
    }
    let mut band = Band::default();
    for y in starts {
        let r = y..(y + rows).min(meta.height);
        fit.band(r.clone(), &mut band)?;
        f(r, &band)?;
    }
    Ok(())
}

/// One `.npy` float array of the frame, `[row][col][floats]`, read and written with
/// positioned I/O (nothing mapped, nothing held).
struct FrameArray {
    path: PathBuf,
    file: File,
    header: u64,
    floats: usize,
}

impl FrameArray {
    /// Creates `path` for a `width × height × shape` array, all zero (a sparse file).
    fn create(path: PathBuf, (width, height): (usize, usize), shape: &[usize]) -> Result<Self> {
        let io = |e| Error::io(&path, e);
        let mut full = vec![height, width];
        full.extend_from_slice(shape);
        let head = crate::io::export::npy_header("<f4", &full);
        let floats: usize = shape.iter().product();
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(true)
            .open(&path)
            .map_err(io)?;
        file.write_all_at(&head, 0).map_err(io)?;
        let len = head.len() as u64 + (width * height * floats * 4) as u64;
        file.set_len(len).map_err(io)?;
        Ok(FrameArray {
            header: head.len() as u64,
            path,
            file,
            floats,
        })
    }

    /// Writes the values of the mask pixels `pixels` (frame indices, ascending), `floats` per
    /// pixel, run by run of consecutive frame pixels.
    fn put(&self, pixels: &[u32], values: &[f32], bytes: &mut Vec<u8>) -> Result<()> {
        let mut p = 0;
        while p < pixels.len() {
            let mut q = p + 1;
            while q < pixels.len() && pixels[q] == pixels[p] + (q - p) as u32 {
                q += 1;
            }
            bytes.clear();
            for v in &values[p * self.floats..q * self.floats] {
                bytes.extend_from_slice(&v.to_le_bytes());
            }
            let at = self.header + (pixels[p] as u64) * (self.floats as u64) * 4;
            self.file
                .write_all_at(bytes, at)
                .map_err(|e| Error::io(&self.path, e))?;
            p = q;
        }
        Ok(())
    }

    /// Reads frame pixels `first..first + out.len() / floats` into `out`.
    fn get(&self, first: usize, out: &mut [f32], bytes: &mut Vec<u8>) -> Result<()> {
        bytes.clear();
        bytes.resize(out.len() * 4, 0);
        let at = self.header + (first * self.floats * 4) as u64;
        self.file
            .read_exact_at(bytes, at)
            .map_err(|e| Error::io(&self.path, e))?;
        for (o, b) in out.iter_mut().zip(bytes.chunks_exact(4)) {
            *o = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        }
        Ok(())
    }
}

/// The float files of a fit in the folder they are written to, filled as the fit makes its
/// coefficients ([`CoefficientSink`]): `coefficients.npy` (H, W, fitted channels, T) and for
/// PTM LRGB `chroma.npy` (H, W, 3), zero outside the mask — the files
/// [`write_float_coefficients`] writes from a fit held whole.
pub struct CoefficientFiles<'a> {
    pixels: &'a [u32],
    coefficients: FrameArray,
    chroma: Option<FrameArray>,
    bytes: Vec<u8>,
}

impl<'a> CoefficientFiles<'a> {
    /// Creates the files in `dir` for a fit of `basis` to a capture of `width × height`
    /// pixels with `channels` channels and the mask pixels `pixels` (frame indices,
    /// ascending).
    pub fn create(
        dir: &Path,
        basis: crate::solve::rti::Basis,
        (width, height, channels): (usize, usize, usize),
        pixels: &'a [u32],
    ) -> Result<Self> {
        let fc = if basis.luminance() || basis == crate::solve::rti::Basis::Rbf {
            1
        } else {
            channels
        };
        let frame = (width, height);
        let coefficients =
            FrameArray::create(dir.join("coefficients.npy"), frame, &[fc, basis.terms()])?;
        let chroma = if basis.luminance() {
            Some(FrameArray::create(dir.join("chroma.npy"), frame, &[3])?)
        } else {
            None
        };
        Ok(CoefficientFiles {
            pixels,
            coefficients,
            chroma,
            bytes: Vec::new(),
        })
    }

    /// The fit `meta` ([`crate::solve::rti::fit_into`]'s result) read back from the files.
    pub fn finish(self, meta: RtiFit) -> StoredFit {
        StoredFit {
            meta,
            coefficients: self.coefficients,
            chroma: self.chroma,
            rows: None,
        }
    }
}

impl CoefficientSink for CoefficientFiles<'_> {
    fn put(&mut self, start: usize, coefficients: &[f32], chroma: &[f32]) -> Result<()> {
        let n = coefficients.len() / self.coefficients.floats.max(1);
        let pixels = &self.pixels[start..start + n];
        self.coefficients
            .put(pixels, coefficients, &mut self.bytes)?;
        if let Some(c) = &self.chroma {
            c.put(pixels, chroma, &mut self.bytes)?;
        }
        Ok(())
    }
}

/// A fit whose coefficients are in its float files ([`CoefficientFiles`]), read back a row
/// band at a time.
pub struct StoredFit {
    meta: RtiFit,
    coefficients: FrameArray,
    chroma: Option<FrameArray>,
    /// Rows per band when not [`FitSource::band_rows`]'s.
    rows: Option<usize>,
}

impl StoredFit {
    /// The same fit read in bands of `rows` rows (at least 1): the files do not depend on it
    /// (tests check that with bands smaller than the frame).
    pub fn with_band_rows(mut self, rows: usize) -> Self {
        self.rows = Some(rows.max(1));
        self
    }
}

impl FitSource for StoredFit {
    fn meta(&self) -> &RtiFit {
        &self.meta
    }

    fn band_rows(&self) -> usize {
        let meta = &self.meta;
        let (per, chroma) = band_floats(meta);
        self.rows
            .unwrap_or((BAND_BYTES / (4 * (per + chroma) * meta.width.max(1))).max(1))
    }

    fn band(&self, rows: Range<usize>, band: &mut Band) -> Result<()> {
        clear_band(&self.meta, &rows, band);
        let first = rows.start * self.meta.width;
        let mut bytes = Vec::new();
        self.coefficients
            .get(first, &mut band.coefficients, &mut bytes)?;
        if let Some(c) = &self.chroma {
            c.get(first, &mut band.chroma, &mut bytes)?;
        }
        Ok(())
    }
}
