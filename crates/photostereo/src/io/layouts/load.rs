//! Decoding a capture's files into a [`Capture`]: whole in memory as `f32` when it fits the
//! memory budget, else into a tiled sample store in memory or in a spill file
//! (ALGORITHMS.md §10), with the refusals of a budget too small.

use super::CaptureFiles;
use crate::base::error::{Error, Result};
use crate::base::progress::Progress;
use crate::io::imageio::{read_image, read_mask};
use crate::io::photometry::{Linearisation, PhotometryReport};
use crate::model::capture::{
    interleave, light_scale, zero_non_finite, Capture, CaptureParts, MissingReadings,
};
use crate::model::image::Image;
use crate::model::memory::{CaptureSize, Force, Layout, MemoryPlan};
use crate::model::store::{Decode, SampleStore, SampleType, Tiling};
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::Arc;

impl CaptureFiles {
    /// Decodes the images in parallel and builds the capture, within the default memory
    /// budget ([`crate::model::memory::default_budget`]).
    pub fn load(&self, progress: &dyn Progress) -> Result<Capture> {
        self.load_with(progress, &LoadOptions::default())
    }

    /// Decodes the images and builds the capture within `options.budget`: whole in memory as
    /// `f32` when that fits, else in tiles (see [`crate::model::memory`]); the plan is in the
    /// capture's `memory`. A budget too small for the capture's full-frame stages is refused
    /// (naming `memory_limit` and the smallest budget that works) before the samples are read.
    pub fn load_with(&self, progress: &dyn Progress, options: &LoadOptions) -> Result<Capture> {
        self.load_measured(progress, options).map(|(c, _)| c)
    }

    /// [`CaptureFiles::load_with`], with what was done to make each image linear (see
    /// [`crate::io::photometry`]): report.json's `photometry`.
    pub fn load_measured(
        &self,
        progress: &dyn Progress,
        options: &LoadOptions,
    ) -> Result<(Capture, PhotometryReport)> {
        self.check_counts()?;
        let budget = options
            .budget
            .unwrap_or_else(crate::model::memory::default_budget);
        let info = crate::io::imageio::probe(&self.images[0])?;
        if let Some((camera, _)) = self.lights.perspective() {
            if let Err(m) = camera.check_frame(info.width, info.height) {
                let folder = self.images[0].parent().unwrap_or(Path::new("."));
                let k = folder.join("K.txt");
                return Err(Error::file(if k.exists() { k } else { folder.into() }, m));
            }
        }
        let mut size = CaptureSize {
            width: info.width,
            height: info.height,
            pixels: 0,
            lights: self.images.len(),
            channels: info.channels,
            sample_type: if info.bit_depth == 32 {
                SampleType::F32
            } else {
                SampleType::U16
            },
            threads: rayon::current_num_threads(),
            ground_truth: options.ground_truth,
            decoded_whole: !info.streamable,
            beside: options.beside,
        };
        // Without `memory_limit` the budget is the machine's: a refusal names the images and
        // the memory available, as the readers' own checks do.
        let refusal = |e: Error| match (e, options.budget) {
            (Error::Parameter { message, .. }, None) => Error::file(
                &self.images[0],
                format!(
                    "declares {}×{} pixels × {} images: {} (the default budget is half of the \
                     memory available{}; {} sets it)",
                    info.width,
                    info.height,
                    self.images.len(),
                    message.split_once(": ").map_or(message.as_str(), |m| m.1),
                    if std::env::var_os(crate::base::machine::MEMORY_LIMIT_VAR).is_some() {
                        format!(", with {} set", crate::base::machine::MEMORY_LIMIT_VAR)
                    } else {
                        String::new()
                    },
                    crate::base::error::param("memory_limit")
                ),
            ),
            (e, _) => e,
        };
        // The frame alone (no mask pixel) already tells a budget that cannot work, before any
        // image is decoded; the smallest budget that works is then named with the mask's
        // pixels counted.
        if let Err(e) = crate::model::memory::plan(&size, budget, Force::default()) {
            let Ok(mask) = self.read_mask_for(info.width, info.height) else {
                return Err(refusal(e));
            };
            size.pixels = mask.iter().filter(|&&m| m).count();
            return Err(refusal(
                crate::model::memory::plan(&size, budget, Force::default())
                    .err()
                    .unwrap_or(e),
            ));
        }
        let mask = self.read_mask_for(info.width, info.height)?;
        size.pixels = mask.iter().filter(|&&m| m).count();
        let photometric = self.photometric_plan(&mask, info.channels)?;
        let lin = &photometric.linearisation;
        if !lin.is_identity() {
            size.sample_type = SampleType::F32;
            size.decoded_whole = true;
        }
        let (layout, plan) =
            crate::model::memory::plan(&size, budget, options.force).map_err(refusal)?;
        let mut capture = if layout == Layout::InMemory {
            self.load_in_memory(progress, mask, lin)?
        } else {
            if options.return_freed_memory_when_tiled {
                crate::base::machine::return_freed_memory();
            }
            let dir = options.spill_dir.clone().unwrap_or_else(std::env::temp_dir);
            let at_once = crate::model::memory::images_at_once(&size, &plan);
            self.load_tiled(
                progress,
                mask,
                (&plan, at_once),
                (layout == Layout::Spill).then_some(&*dir),
                lin,
            )?
        };
        capture.memory = Some(plan);
        super::check_sources(&capture.sources)?;
        let notes = crate::solve::plausibility::check_capture(&capture)?;
        capture.notes.extend(notes);
        let (w, h) = (capture.width, capture.height);
        capture.notes.extend(self.whole_frame_note(w, h));
        capture.notes.extend(photometric.notes);
        let mut report = photometric.report;
        if lin.ambient.is_none() {
            report.offset_check = crate::io::layouts::photometric::offset_of(&capture)?;
            if let Some(c) = report.offset_check.as_ref().filter(|c| c.detected) {
                capture
                    .notes
                    .push(crate::io::layouts::photometric::offset_note(c));
            }
        }
        Ok((capture, report))
    }

    fn check_counts(&self) -> Result<()> {
        let n = self.images.len();
        if n != self.lights.len() {
            return Err(Error::invalid(format!(
                "{} images but {} light directions: expected one light per image",
                n,
                self.lights.len()
            )));
        }
        if n < 3 {
            return Err(Error::invalid(format!(
                "{n} image(s): photometric stereo needs at least three"
            )));
        }
        self.lights.check_rank().map(|_| ())
    }

    /// The mask (all true without a mask file), checked against the images' size.
    fn read_mask_for(&self, w: usize, h: usize) -> Result<Vec<bool>> {
        Ok(match &self.mask {
            Some(path) => {
                let (mh, mw, m) = read_mask(path)?;
                if (mh, mw) != (h, w) {
                    return Err(Error::file(
                        path,
                        format!(
                            "mask is {}×{} (width×height) but the images are {}×{}",
                            mw, mh, w, h
                        ),
                    ));
                }
                if !m.iter().any(|&v| v) {
                    return Err(Error::file(path, "the mask is empty (no non-zero pixel)"));
                }
                m
            }
            None => vec![true; w * h],
        })
    }

    /// The error for image `k` whose size or channels differ from the first image's.
    fn mismatch(
        &self,
        k: usize,
        (w, h, c): (usize, usize, usize),
        (iw, ih, ic): (usize, usize, usize),
    ) -> Option<Error> {
        let path = &self.images[k];
        if (iw, ih) != (w, h) {
            return Some(Error::file(
                path,
                format!(
                    "image is {}×{} but {} is {}×{}: all images of a capture must share size",
                    iw,
                    ih,
                    self.images[0].display(),
                    w,
                    h
                ),
            ));
        }
        if ic != c {
            return Some(Error::file(
                path,
                format!(
                    "image has {} channel(s) but {} has {}: all images must share the channel count",
                    ic,
                    self.images[0].display(),
                    c
                ),
            ));
        }
        None
    }

    /// The tiled loader: every image decoded once, row band by row band (PNG, streamed; other
    /// formats decoded whole, a few at a time), scattered into the tiles of `plan`.
    fn load_tiled(
        &self,
        progress: &dyn Progress,
        mask: Vec<bool>,
        (plan, images_at_once): (&MemoryPlan, usize),
        spill_dir: Option<&Path>,
        lin: &Linearisation,
    ) -> Result<Capture> {
        let n = self.images.len();
        let infos: Vec<crate::io::imageio::ImageInfo> = self
            .images
            .par_iter()
            .map(|p| crate::io::imageio::probe(p))
            .collect::<Result<_>>()?;
        let (w, h, c) = (infos[0].width, infos[0].height, infos[0].channels);
        for (k, i) in infos.iter().enumerate() {
            if let Some(e) = self.mismatch(k, (w, h, c), (i.width, i.height, i.channels)) {
                return Err(e);
            }
        }
        // Linearised readings are no integer levels: held as floats.
        let kind = if infos.iter().any(|i| i.bit_depth == 32) || !lin.is_identity() {
            SampleType::F32
        } else {
            SampleType::U16
        };
        let decode: Vec<Decode> = infos
            .iter()
            .map(|i| match (kind, i.format, i.bit_depth) {
                (SampleType::F32, _, _) => Decode::Float,
                (_, crate::io::imageio::Format::Png, 8) => Decode::MulRecip(1.0f32 / 255.0),
                (_, crate::io::imageio::Format::Png, _) => Decode::MulRecip(1.0f32 / 65535.0),
                (_, _, 8) => Decode::Div(255.0),
                _ => Decode::Div(65535.0),
            })
            .collect();
        let scale: Vec<[f32; 3]> = self
            .lights
            .intensities
            .iter()
            .map(|i| light_scale(i, c))
            .collect();
        let pixels = crate::model::capture::mask_pixel_indices(&mask);
        let tiling = Tiling::new(&mask, w, h, plan.tile_pixels);
        let mut store =
            SampleStore::new(kind, c, tiling.clone(), decode.clone(), scale, spill_dir)?;
        let fill = TileFill {
            files: self,
            kind,
            decode: &decode,
            pixels: &pixels,
            tiling: &tiling,
            size: (w, h, c),
            lin,
            images_at_once,
        };
        progress.begin("loading", (n * h) as u64);
        // Streamed images are integer PNGs, whose readings are always finite.
        let mut notes = self.notes.clone();
        if infos.iter().all(|i| i.streamable) && lin.is_identity() {
            fill.stream_rows(&mut store, progress)?;
        } else {
            let missing = fill.patch_decoded(&mut store, progress)?;
            notes.extend(missing.verdict(&self.images)?);
        }
        progress.end();
        Ok(Capture::from_parts(CaptureParts {
            width: w,
            height: h,
            channels: c,
            bit_depth: infos[0].bit_depth,
            lights: self.lights.clone(),
            mask,
            pixels,
            samples: Vec::new(),
            store: Some(Arc::new(store)),
            sources: self.images.clone(),
            notes,
        }))
    }

    /// The loader of captures held whole as `f32`.
    fn load_in_memory(
        &self,
        progress: &dyn Progress,
        mask: Vec<bool>,
        lin: &Linearisation,
    ) -> Result<Capture> {
        let n = self.images.len();
        progress.begin("loading", n as u64);
        let mut first = read_image(&self.images[0])?;
        let bit_depth = first.bit_depth;
        lin.apply(0, &mut first);
        progress.advance(1);
        if mask.len() != first.width * first.height {
            return Err(Error::file(
                &self.images[0],
                "the image's size changed while the capture was read",
            ));
        }
        let pixels = crate::model::capture::mask_pixel_indices(&mask);
        let (w, h, c) = (first.width, first.height, first.channels);
        // The samples of the mask pixels, plus their transient second copy while loading.
        let needed = (pixels.len() as u64)
            .saturating_mul(n as u64)
            .saturating_mul(c as u64)
            .saturating_mul(8);
        if let Err(m) = crate::base::machine::check_memory(
            needed,
            &format!(
                "{n} images of {} mask pixels × {c} channel(s) ({} of samples, twice while loading)",
                pixels.len(),
                crate::base::machine::human_bytes(needed / 2)
            ),
        ) {
            return Err(Error::invalid(format!(
                "{m}: use a smaller mask or fewer images (or set {})",
                crate::base::machine::MEMORY_LIMIT_VAR
            )));
        }
        let gather = |k: usize, img: &Image| -> Vec<f32> {
            let scale = light_scale(&self.lights.intensities[k], c);
            let mut out = Vec::with_capacity(pixels.len() * c);
            for &i in &pixels {
                let base = i as usize * c;
                out.extend(
                    img.data[base..base + c]
                        .iter()
                        .zip(&scale)
                        .map(|(v, s)| v * s),
                );
            }
            out
        };
        let first_planes = gather(0, &first);
        drop(first);
        let rest: Vec<Result<Vec<f32>>> = (1..n)
            .into_par_iter()
            .map(|k| {
                let path = &self.images[k];
                let img = read_image(path)?;
                if (img.width, img.height) != (w, h) {
                    return Err(Error::file(
                        path,
                        format!(
                            "image is {}×{} but {} is {}×{}: all images of a capture must share size",
                            img.width,
                            img.height,
                            self.images[0].display(),
                            w,
                            h
                        ),
                    ));
                }
                if img.channels != c {
                    return Err(Error::file(
                        path,
                        format!(
                            "image has {} channel(s) but {} has {}: all images must share the channel count",
                            img.channels,
                            self.images[0].display(),
                            c
                        ),
                    ));
                }
                let mut img = img;
                lin.apply(k, &mut img);
                let planes = gather(k, &img);
                progress.advance(1);
                Ok(planes)
            })
            .collect();
        let mut planes = Vec::with_capacity(n);
        planes.push(first_planes);
        for r in rest {
            planes.push(r?);
        }
        progress.end();
        let mut missing = MissingReadings::new(n, pixels.len() * c);
        for (count, plane) in missing.per_image.iter_mut().zip(planes.iter_mut()) {
            *count = zero_non_finite(plane);
        }
        let mut notes = self.notes.clone();
        notes.extend(missing.verdict(&self.images)?);
        let samples = interleave(&planes, pixels.len(), c);
        let capture = Capture::from_parts(CaptureParts {
            width: w,
            height: h,
            channels: c,
            bit_depth,
            lights: self.lights.clone(),
            mask,
            pixels,
            samples,
            store: None,
            sources: self.images.clone(),
            notes,
        });
        Ok(capture)
    }
}

/// Options of [`CaptureFiles::load_with`].
#[derive(Clone, Debug, Default)]
pub struct LoadOptions {
    /// The memory budget, bytes (default: [`crate::model::memory::default_budget`]).
    pub budget: Option<u64>,
    /// Where a spill file goes (default: the system's temporary folder); `run` gives the
    /// output's staging folder.
    pub spill_dir: Option<PathBuf>,
    /// A forced layout or tile size (tests, experiments).
    pub force: Force,
    /// When the capture is loaded into tiles, make the C allocator hand large freed blocks
    /// back to the system at once ([`crate::base::machine::return_freed_memory`]): the process's peak
    /// then stays near what the run holds. Process-wide and lasting, so only a program that
    /// owns its process (the command line) sets it; a library host such as Python leaves it.
    pub return_freed_memory_when_tiled: bool,
    /// Ground-truth normals will be held (per mask pixel) to score the run: the plan counts
    /// them.
    pub ground_truth: bool,
    /// What the command holds beside the run's stages (`run --rti`, `rti`): the plan counts
    /// it.
    pub beside: crate::model::memory::Beside,
}

/// Filling the tiles of a sample store from a capture's image files: the store's sample type,
/// each image's decoder, the mask pixels (ascending) and their tiling, and the images' width,
/// height and channels.
struct TileFill<'a> {
    files: &'a CaptureFiles,
    kind: SampleType,
    decode: &'a [Decode],
    pixels: &'a [u32],
    tiling: &'a Tiling,
    size: (usize, usize, usize),
    /// How each image is made linear (identity when the rows are streamed).
    lin: &'a Linearisation,
    /// Images decoded whole at once ([`crate::model::memory::images_at_once`]).
    images_at_once: usize,
}

impl TileFill<'_> {
    /// PNG images, streamed: for each tile, every image's rows of the tile's row band read in
    /// parallel (one reader per image), its mask pixels' samples taken as they pass, and the
    /// lights' planes interleaved into the tile.
    fn stream_rows(&self, store: &mut SampleStore, progress: &dyn Progress) -> Result<()> {
        let (w, _, c) = self.size;
        let n = self.files.images.len();
        let sb = c * self.kind.bytes(); // bytes of one light's sample of one pixel
        let mut raw: Vec<u8> = Vec::new();
        let mut readers: Vec<crate::io::imageio::PngRows> = self
            .files
            .images
            .iter()
            .map(|p| crate::io::imageio::PngRows::open(p))
            .collect::<Result<_>>()?;
        let mut planes: Vec<Vec<u8>> = vec![Vec::new(); n];
        for t in 0..self.tiling.len() {
            crate::base::progress::check_cancelled(progress)?;
            let (r0, r1) = (self.tiling.rows[t], self.tiling.rows[t + 1]);
            let tile_pixels = &self.pixels[self.tiling.pixels(t)];
            readers
                .par_iter_mut()
                .zip(planes.par_iter_mut())
                .enumerate()
                .map(|(k, (reader, plane))| -> Result<()> {
                    plane.clear();
                    let mut row = Vec::with_capacity(w * c);
                    let mut next = 0;
                    for r in r0..r1 {
                        reader.next_row(c, &mut row)?;
                        while next < tile_pixels.len() && tile_pixels[next] as usize / w == r {
                            let col = tile_pixels[next] as usize % w;
                            for &u in &row[col * c..(col + 1) * c] {
                                put_u16(self.kind, self.decode[k], u, plane);
                            }
                            next += 1;
                        }
                    }
                    progress.advance((r1 - r0) as u64);
                    Ok(())
                })
                .collect::<Result<()>>()?;
            interleave_bytes(&planes, tile_pixels.len(), sb, &mut raw);
            store.write_raw(t, &raw)?;
        }
        Ok(())
    }

    /// Other formats, decoded whole, as many at a time as the budget holds (at most one per
    /// thread); each group patched into every tile.
    ///
    /// Non-finite readings at the mask pixels are set to 0 and counted ([`MissingReadings`]).
    fn patch_decoded(
        &self,
        store: &mut SampleStore,
        progress: &dyn Progress,
    ) -> Result<MissingReadings> {
        let (w, h, c) = self.size;
        let files = self.files;
        let n = files.images.len();
        let sb = c * self.kind.bytes(); // bytes of one light's sample of one pixel
        let pb = n * sb;
        let mut raw: Vec<u8> = Vec::new();
        let group = self.images_at_once.max(1);
        let mut missing = MissingReadings::new(n, self.pixels.len() * c);
        for k0 in (0..n).step_by(group) {
            crate::base::progress::check_cancelled(progress)?;
            let ks: Vec<usize> = (k0..(k0 + group).min(n)).collect();
            let images: Vec<(Image, usize)> = ks
                .par_iter()
                .map(|&k| {
                    let mut img = read_image(&files.images[k])?;
                    self.lin.apply(k, &mut img);
                    if let Some(e) =
                        files.mismatch(k, (w, h, c), (img.width, img.height, img.channels))
                    {
                        return Err(e);
                    }
                    let zeroed: usize = self
                        .pixels
                        .iter()
                        .map(|&i| zero_non_finite(&mut img.data[i as usize * c..][..c]))
                        .sum();
                    progress.advance(h as u64);
                    Ok((img, zeroed))
                })
                .collect::<Result<_>>()?;
            for (&k, (_, zeroed)) in ks.iter().zip(&images) {
                missing.per_image[k] = *zeroed;
            }
            for t in 0..self.tiling.len() {
                let tile_pixels = &self.pixels[self.tiling.pixels(t)];
                store.read_raw(t, &mut raw)?;
                raw.par_chunks_mut(pb)
                    .zip(tile_pixels.par_iter())
                    .for_each(|(px, &i)| {
                        for (&k, (img, _)) in ks.iter().zip(&images) {
                            let src = &img.data[i as usize * c..(i as usize + 1) * c];
                            let dst = &mut px[k * sb..(k + 1) * sb];
                            match self.kind {
                                SampleType::U16 => {
                                    for (d, &v) in dst.chunks_exact_mut(2).zip(src) {
                                        d.copy_from_slice(&self.decode[k].to_u16(v).to_ne_bytes());
                                    }
                                }
                                SampleType::F32 => {
                                    for (d, &v) in dst.chunks_exact_mut(4).zip(src) {
                                        d.copy_from_slice(&v.to_ne_bytes());
                                    }
                                }
                            }
                        }
                    });
                store.write_raw(t, &raw)?;
            }
        }
        Ok(missing)
    }
}

/// The bytes of one integer sample `u` in a store of `kind`: the integer itself, or its value
/// decoded by `dec`.
fn put_u16(kind: SampleType, dec: Decode, u: u16, out: &mut Vec<u8>) {
    match kind {
        SampleType::U16 => out.extend_from_slice(&u.to_ne_bytes()),
        SampleType::F32 => {
            let v = match dec {
                Decode::Div(f) => u as f32 / f,
                Decode::MulRecip(r) => u as f32 * r,
                Decode::Float => u as f32,
            };
            out.extend_from_slice(&v.to_ne_bytes())
        }
    }
}

/// Light-major byte planes (`planes[k][p * sb..]`, `sb` bytes per pixel) into the pixel-major
/// raw tile `out` (`[pixel][light]`).
fn interleave_bytes(planes: &[Vec<u8>], n_pixels: usize, sb: usize, out: &mut Vec<u8>) {
    let pb = planes.len() * sb;
    out.resize(n_pixels * pb, 0);
    out.par_chunks_mut(pb).enumerate().for_each(|(p, px)| {
        for (k, plane) in planes.iter().enumerate() {
            px[k * sb..(k + 1) * sb].copy_from_slice(&plane[p * sb..(p + 1) * sb]);
        }
    });
}
