//! Capture loading: the DiLiGenT layout, the list-file layout and explicit image lists
//! (CONVENTIONS.md, "Capture layouts"), decoded in parallel into one sample store.
//!
//! Samples are stored pixel-major for the pixels inside the mask only:
//! `samples[(p * N + k) * C + c]` is channel `c` of light `k` at the `p`-th mask pixel, already
//! divided by light `k`'s intensity. Memory is `4 · P · N · C` bytes (P mask pixels, N lights,
//! C channels), with a transient second copy of the same size while loading from files; an
//! in-memory stack ([`Capture::from_stack`]) is read straight into the store.

use crate::base::error::{Error, Result};
use crate::model::image::Image;
use crate::model::image::{MAX_IMAGE_PIXELS, MAX_IMAGE_SIDE};
use crate::model::lights::Lights;
use crate::model::memory::{CaptureSize, Force, Layout, MemoryPlan};
use crate::model::store::{Decode, SampleStore, SampleType, Tiling};
use ndarray::{ArrayView2, ArrayView4, Axis};
use rayon::prelude::*;
use std::path::PathBuf;
use std::sync::Arc;

/// Images, lights and mask of one capture, intensity-normalised, restricted to the mask.
#[derive(Clone, Debug)]
pub struct Capture {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Channels per image (1 or 3).
    pub channels: usize,
    /// Bits per sample of the source images (8, 16 or 32); 32 for in-memory float data.
    pub bit_depth: u8,
    /// The lights, one per image, in image order.
    pub lights: Lights,
    /// `height * width` flags, row-major: true inside the object.
    pub mask: Vec<bool>,
    /// Row-major flat index (`row * width + col`) of each mask pixel, ascending.
    pub pixels: Vec<u32>,
    /// Intensity-normalised samples, `[pixel][light][channel]`; empty when the samples are in
    /// a tiled [`SampleStore`] (`store`), which [`Capture::for_each_tile`] reads tile by tile.
    /// After changing them in place once a method has run, call
    /// [`Capture::forget_statistics`].
    pub samples: Vec<f32>,
    /// The tiled store, when the samples did not fit the memory budget as `f32`.
    pub store: Option<Arc<SampleStore>>,
    /// The plan the capture was loaded with (`None` for captures built in memory).
    pub memory: Option<MemoryPlan>,
    /// For a sampled view ([`Capture::sampled`]): the mask pixels whose samples `samples`
    /// holds, ascending.
    sparse: Option<Arc<Vec<u32>>>,
    /// The image files, when loaded from files.
    pub sources: Vec<PathBuf>,
    /// Remarks made while loading (path resolution, renormalised lights…).
    pub notes: Vec<String>,
    /// The refinement of the lights from the readings, once applied
    /// ([`Capture::apply_light_refinement`]): `lights` and the samples are then the refined
    /// ones.
    pub light_refinement: Option<crate::model::lights::LightRefinement>,
    /// The capture-wide statistics once measured (noise level, dark floor, κ): every method
    /// run on this capture reads them instead of measuring them again. A clone or any capture
    /// derived from this one starts without them.
    statistics: Statistics,
}

impl Capture {
    /// A parking file for the per-pixel arrays a full-frame stage does not read, when the
    /// memory plan asks for one ([`MemoryPlan::park`]): beside the samples' spill file, else in
    /// the system's temporary folder.
    pub fn parking(&self) -> Result<Option<crate::model::store::Parking>> {
        if !self.memory.as_ref().is_some_and(|m| m.park) {
            return Ok(None);
        }
        let dir = self
            .store
            .as_ref()
            .and_then(|s| s.spill_dir().map(std::path::Path::to_path_buf))
            .unwrap_or_else(std::env::temp_dir);
        crate::model::store::Parking::new(&dir).map(Some)
    }
}

/// The capture-wide statistics of one [`Capture`], each measured on first use
/// ([`crate::solve::detect::image_noise`], [`crate::solve::detect::dark_floor`],
/// [`crate::solve::detect::estimate_kappa_weighted`], [`crate::solve::detect::light_noise_factors`]). They are a function of the samples, lights and mask, which
/// the library never changes in place once a capture is built (the one capture whose samples
/// change, the tile view of [`Capture::for_each_tile`], forgets them with each tile); cloning
/// gives an empty memo, so a derived capture measures its own.
#[derive(Debug, Default)]
pub(crate) struct Statistics {
    /// Sensor noise of the channel-mean images (`None`: too few interior pixels).
    pub image_noise: std::sync::OnceLock<Option<f64>>,
    /// The dark floor, in intensity-normalised units.
    pub dark_floor: std::sync::OnceLock<f64>,
    /// Statistics that depend on further arguments (κ for given σ₀, floor, shadow σ's and
    /// light factors; the light factors for a noise model), keyed by a tag and the arguments'
    /// bits.
    keyed: std::sync::Mutex<Vec<(Vec<u64>, Vec<f64>)>>,
}

impl Statistics {
    /// The values remembered under `key`, or those `measure` gives, then remembered. Measuring
    /// runs outside the lock (two threads asking at once may both measure; both get the same
    /// values).
    pub fn remember(&self, key: Vec<u64>, measure: impl FnOnce() -> Vec<f64>) -> Vec<f64> {
        let known = self
            .keyed
            .lock()
            .ok()
            .and_then(|m| m.iter().find(|(k, _)| *k == key).map(|(_, v)| v.clone()));
        if let Some(values) = known {
            return values;
        }
        let values = measure();
        if let Ok(mut m) = self.keyed.lock() {
            m.push((key, values.clone()));
        }
        values
    }

    /// The values remembered under `key`, if any (nothing is measured).
    pub fn recall(&self, key: &[u64]) -> Option<Vec<f64>> {
        let m = self.keyed.lock().ok()?;
        m.iter().find(|(k, _)| k == key).map(|(_, v)| v.clone())
    }

    /// Remembers what `other` has measured and this memo has not: for a capture held in tiles,
    /// whose statistics are those of its statistics view
    /// ([`crate::solve::tiled::statistics_view`]), once that view is dropped.
    pub fn adopt(&self, other: &Statistics) {
        if let Some(&v) = other.image_noise.get() {
            let _ = self.image_noise.set(v);
        }
        if let Some(&v) = other.dark_floor.get() {
            let _ = self.dark_floor.set(v);
        }
        let theirs = match other.keyed.lock() {
            Ok(m) => m.clone(),
            Err(_) => return,
        };
        for (key, values) in theirs {
            if self.recall(&key).is_none() {
                if let Ok(mut m) = self.keyed.lock() {
                    m.push((key, values));
                }
            }
        }
    }
}

impl Clone for Statistics {
    fn clone(&self) -> Self {
        Statistics::default()
    }
}

/// The frame indices of the mask's pixels, row-major, in a list of exactly their number (a
/// list grown by pushes would hold up to twice the 4 bytes a pixel through every stage).
pub fn mask_pixel_indices(mask: &[bool]) -> Vec<u32> {
    let mut pixels = Vec::with_capacity(mask.iter().filter(|&&m| m).count());
    pixels.extend(
        mask.iter()
            .enumerate()
            .filter(|(_, &m)| m)
            .map(|(i, _)| i as u32),
    );
    pixels
}

/// Readings that are not finite (NaN, ±∞) in one image's samples at the mask pixels: set to
/// 0 and counted. A 0 reads as a shadow, which the robust methods (recursive, the χ² test of
/// the others) leave out of the pixel's fit, so the pixel keeps its normal from its other
/// lights instead of being dropped whole; see [`MissingReadings`] for what is refused and
/// what is said.
pub fn zero_non_finite(values: &mut [f32]) -> usize {
    let mut count = 0;
    for v in values.iter_mut().filter(|v| !v.is_finite()) {
        *v = 0.0;
        count += 1;
    }
    count
}

/// The count of non-finite readings per image of a capture, and the rule applied to them: an
/// image with no finite reading inside the mask is refused (it holds no measurement at all);
/// an image with some is kept, its non-finite readings read as 0 ([`zero_non_finite`]), and a
/// note names it.
#[derive(Clone, Debug)]
pub struct MissingReadings {
    /// Non-finite readings of each image (light), over its mask pixels and channels.
    pub per_image: Vec<usize>,
    /// Readings of one image: mask pixels × channels.
    pub readings_per_image: usize,
}

impl MissingReadings {
    /// No missing reading yet, for `images` images of `readings_per_image` readings each.
    pub fn new(images: usize, readings_per_image: usize) -> Self {
        MissingReadings {
            per_image: vec![0; images],
            readings_per_image,
        }
    }

    /// Counts the non-finite readings of pixel-major `samples` (`pixels × images × channels`)
    /// per image, setting them to 0.
    pub fn zero_in_samples(&mut self, samples: &mut [f32], channels: usize) {
        let n = self.per_image.len();
        if samples.iter().all(|v| v.is_finite()) {
            return;
        }
        for (j, v) in samples.iter_mut().enumerate() {
            if !v.is_finite() {
                *v = 0.0;
                self.per_image[(j / channels) % n] += 1;
            }
        }
    }

    /// The rule: `Err` naming the first image without a finite reading; else the note naming
    /// the images with some, or `None`. `sources` are the images' files (empty for an array,
    /// whose images are then named by their 1-based index).
    pub fn verdict(&self, sources: &[PathBuf]) -> Result<Option<String>> {
        let total = self.readings_per_image;
        let name = |k: usize| match sources.get(k) {
            Some(path) => path.display().to_string(),
            None => format!("image {} of the stack", k + 1),
        };
        if let Some(k) = self.per_image.iter().position(|&m| total > 0 && m == total) {
            let message =
                "no reading inside the mask is finite (all NaN or infinite): expected intensities";
            return Err(match sources.get(k) {
                Some(path) => Error::file(path, message),
                None => Error::invalid(format!("{}: {message}", name(k))),
            });
        }
        let bad: Vec<String> = (0..self.per_image.len())
            .filter(|&k| self.per_image[k] > 0)
            .map(|k| {
                format!(
                    "{} ({} of {total} readings, {:.2}%)",
                    name(k),
                    self.per_image[k],
                    100.0 * self.per_image[k] as f64 / total as f64
                )
            })
            .collect();
        Ok((!bad.is_empty()).then(|| {
            format!(
                "non-finite readings (NaN or infinite) read as 0, a shadow, which the robust \
                 methods leave out and l2 fits as a reading: {}",
                bad.join(", ")
            )
        }))
    }
}

/// Whether a channel of light `k`'s reading in a pixel's `samples` (`[light][channel]`, `c`
/// channels) is at or above its clip level `clip[k]` ([`Capture::clip_levels`]).
pub fn clipped(samples: &[f32], c: usize, k: usize, clip: &[[f32; 3]]) -> bool {
    samples[k * c..(k + 1) * c]
        .iter()
        .zip(&clip[k])
        .any(|(x, top)| x >= top)
}

/// Per-channel factors 1 / intensity (grey images use the mean of the RGB intensities): what
/// a sample is multiplied by to divide it by its light's intensity.
pub fn light_scale(intensity: &[f64; 3], channels: usize) -> [f32; 3] {
    if channels == 1 {
        let m = (intensity[0] + intensity[1] + intensity[2]) / 3.0;
        [(1.0 / m) as f32; 3]
    } else {
        [
            (1.0 / intensity[0]) as f32,
            (1.0 / intensity[1]) as f32,
            (1.0 / intensity[2]) as f32,
        ]
    }
}

/// Turns light-major planes (`planes[k][p * C + c]`) into the pixel-major sample store.
pub fn interleave(planes: &[Vec<f32>], n_pixels: usize, channels: usize) -> Vec<f32> {
    let n = planes.len();
    let stride = n * channels;
    let mut samples = vec![0f32; n_pixels * stride];
    const CHUNK: usize = 1024;
    samples
        .par_chunks_mut(CHUNK * stride)
        .enumerate()
        .for_each(|(chunk, out)| {
            let p0 = chunk * CHUNK;
            for (k, plane) in planes.iter().enumerate() {
                for (dp, px) in out.chunks_exact_mut(stride).enumerate() {
                    let src = (p0 + dp) * channels;
                    px[k * channels..(k + 1) * channels]
                        .copy_from_slice(&plane[src..src + channels]);
                }
            }
        });
    samples
}

/// Refuses lights seen through a camera whose principal point lies outside the `width ×
/// height` images ([`crate::model::lightmodel::Camera::check_frame`]).
pub fn check_camera_frame(lights: &Lights, width: usize, height: usize) -> Result<()> {
    match lights.perspective() {
        Some((camera, _)) => camera
            .check_frame(width, height)
            .map_err(|m| Error::parameter("camera", m)),
        None => Ok(()),
    }
}

/// What a loader assembles a [`Capture`] from ([`Capture::from_parts`]); the fields are the
/// capture's own.
#[derive(Debug)]
pub struct CaptureParts {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub bit_depth: u8,
    pub lights: Lights,
    pub mask: Vec<bool>,
    pub pixels: Vec<u32>,
    pub samples: Vec<f32>,
    pub store: Option<Arc<SampleStore>>,
    pub sources: Vec<PathBuf>,
    pub notes: Vec<String>,
}

impl Capture {
    /// The memo of this capture's statistics (see [`Statistics`]).
    pub(crate) fn statistics(&self) -> &Statistics {
        &self.statistics
    }

    /// Per-thread access to the light vectors of one pixel after another
    /// ([`crate::model::lightmodel::PixelLights`]) for this capture's lights.
    pub fn pixel_lights(&self) -> crate::model::lightmodel::PixelLights<'_> {
        crate::model::lightmodel::PixelLights::new(
            &self.lights.directions,
            self.lights.near.as_deref(),
            self.width,
        )
    }

    /// Forgets the capture-wide statistics measured so far (noise level, dark floor, κ), which
    /// every method run on this capture otherwise reuses: call it after changing `samples`,
    /// `lights` or the mask in place. (Clones and captures derived by the library's functions
    /// always measure their own.)
    pub fn forget_statistics(&mut self) {
        self.statistics = Statistics::default();
    }

    /// Makes `refinement`'s lights the capture's: directions replaced, light k's samples
    /// divided by its gain (a tiled capture's store divides them as it reads them, with the
    /// same rounding), intensities multiplied by it (the record of what the lights are),
    /// statistics forgotten. Refused on a sampled view, on a capture already refined and on a
    /// tiled capture whose store is shared with another capture.
    pub fn apply_light_refinement(
        &mut self,
        refinement: crate::model::lights::LightRefinement,
    ) -> Result<()> {
        let n = self.n_lights();
        if refinement.directions.len() != n || refinement.gains.len() != n {
            return Err(Error::invalid(format!(
                "light refinement: {} directions and {} gains for {} lights",
                refinement.directions.len(),
                refinement.gains.len(),
                n
            )));
        }
        if self.light_refinement.is_some() {
            return Err(Error::invalid(
                "light refinement: the lights were refined already",
            ));
        }
        if self.sparse.is_some() || self.lights.near.is_some() {
            return Err(Error::invalid(
                "light refinement: applies to a whole capture under distant lights",
            ));
        }
        if refinement
            .gains
            .iter()
            .any(|g| !(g.is_finite() && *g > 0.0))
        {
            return Err(Error::invalid("light refinement: gains must be positive"));
        }
        let inverse: Vec<f32> = refinement.gains.iter().map(|g| (1.0 / g) as f32).collect();
        let c = self.channels;
        match self.store.as_mut() {
            Some(store) => Arc::get_mut(store)
                .ok_or_else(|| {
                    Error::invalid(
                        "light refinement: the tiled samples are shared with another capture",
                    )
                })?
                .set_light_gains(inverse)?,
            None => self.samples.par_chunks_mut(n * c).for_each(|pixel| {
                for (light, &g) in pixel.chunks_exact_mut(c).zip(&inverse) {
                    for v in light {
                        *v *= g;
                    }
                }
            }),
        }
        for (k, (d, g)) in refinement
            .directions
            .iter()
            .zip(&refinement.gains)
            .enumerate()
        {
            self.lights.directions[k] = *d;
            if let Some(i) = self.lights.intensities.get_mut(k) {
                for v in i.iter_mut() {
                    *v *= g;
                }
            }
        }
        let mean = refinement.angle_deg.iter().sum::<f64>() / n as f64;
        let max = refinement.angle_deg.iter().cloned().fold(0.0, f64::max);
        let gain_spread = refinement
            .gains
            .iter()
            .map(|g| (g - 1.0).abs())
            .fold(0.0, f64::max);
        self.notes.push(format!(
            "lights refined from the readings: directions moved {mean:.2}° on average (at most \
             {max:.2}°), intensities by up to {:.1}%; the pixels' median misfit {:.2}% → {:.2}% \
             of their level",
            100.0 * gain_spread,
            100.0 * refinement.misfit_before,
            100.0 * refinement.misfit_after
        ));
        self.light_refinement = Some(refinement);
        self.forget_statistics();
        Ok(())
    }

    /// Builds a capture from decoded images (all of one size and channel count), their lights
    /// and an optional mask (`height * width`, row-major). Images are divided by the lights'
    /// intensities as when loading files.
    pub fn from_images(images: &[Image], lights: Lights, mask: Option<Vec<bool>>) -> Result<Self> {
        if images.len() != lights.len() {
            return Err(Error::invalid(format!(
                "{} images but {} lights",
                images.len(),
                lights.len()
            )));
        }
        if images.len() < 3 {
            return Err(Error::invalid(
                "photometric stereo needs at least three images",
            ));
        }
        lights.check_rank()?;
        let (w, h, c) = (images[0].width, images[0].height, images[0].channels);
        check_camera_frame(&lights, w, h)?;
        for (k, img) in images.iter().enumerate() {
            if (img.width, img.height, img.channels) != (w, h, c) {
                return Err(Error::invalid(format!(
                    "image {} is {}×{}×{}, expected {}×{}×{}",
                    k + 1,
                    img.width,
                    img.height,
                    img.channels,
                    w,
                    h,
                    c
                )));
            }
        }
        let mask = mask.unwrap_or_else(|| vec![true; w * h]);
        if mask.len() != w * h {
            return Err(Error::invalid(format!(
                "mask has {} pixels, images have {}",
                mask.len(),
                w * h
            )));
        }
        let pixels = mask_pixel_indices(&mask);
        if pixels.is_empty() {
            return Err(Error::invalid("the mask is empty"));
        }
        let planes: Vec<Vec<f32>> = images
            .par_iter()
            .enumerate()
            .map(|(k, img)| {
                let s = light_scale(&lights.intensities[k], c);
                let mut out = Vec::with_capacity(pixels.len() * c);
                for &i in &pixels {
                    let base = i as usize * c;
                    out.extend(img.data[base..base + c].iter().zip(&s).map(|(v, f)| v * f));
                }
                out
            })
            .collect();
        let mut samples = interleave(&planes, pixels.len(), c);
        let mut missing = MissingReadings::new(images.len(), pixels.len() * c);
        missing.zero_in_samples(&mut samples, c);
        let note = missing.verdict(&[])?;
        let mut capture = Capture::in_memory(
            (w, h, c),
            images[0].bit_depth,
            lights,
            mask,
            pixels,
            samples,
        );
        capture.notes.extend(note);
        Ok(capture)
    }

    /// A capture assembled by a loader from its parts (statistics not yet measured, lights not
    /// refined).
    pub fn from_parts(p: CaptureParts) -> Capture {
        Capture {
            width: p.width,
            height: p.height,
            channels: p.channels,
            bit_depth: p.bit_depth,
            lights: p.lights,
            mask: p.mask,
            pixels: p.pixels,
            samples: p.samples,
            store: p.store,
            memory: None,
            sparse: None,
            sources: p.sources,
            notes: p.notes,
            statistics: Statistics::default(),
            light_refinement: None,
        }
    }

    /// A capture built in memory (no source files, no notes).
    fn in_memory(
        (width, height, channels): (usize, usize, usize),
        bit_depth: u8,
        lights: Lights,
        mask: Vec<bool>,
        pixels: Vec<u32>,
        samples: Vec<f32>,
    ) -> Capture {
        Capture {
            width,
            height,
            channels,
            bit_depth,
            lights,
            mask,
            pixels,
            samples,
            store: None,
            memory: None,
            sparse: None,
            sources: Vec::new(),
            notes: Vec::new(),
            statistics: Statistics::default(),
            light_refinement: None,
        }
    }

    /// Builds a capture from one image stack in memory within the default memory budget: see
    /// [`Capture::from_stack_with`].
    pub fn from_stack(
        stack: Stack<'_>,
        lights: Lights,
        mask: Option<ArrayView2<'_, bool>>,
    ) -> Result<Self> {
        Self::from_stack_with(stack, lights, mask, &StackOptions::default())
    }

    /// Builds a capture from one image stack in memory: `stack` is (N, H, W, C) with C = 1 or
    /// 3, any strides (a transposed or sliced view is fine); integer samples are scaled to
    /// [0, 1] by their type's full scale (255, 65535), float samples taken as they are. Each
    /// sample is divided by its light's intensity. `mask` is (H, W), true inside the object
    /// (default: the whole frame).
    ///
    /// The images are held to the limits and the memory budget of images read from files
    /// ([`MAX_IMAGE_SIDE`], [`MAX_IMAGE_PIXELS`], [`crate::model::memory::plan`]) before
    /// anything is allocated: the stack is read once, straight into the pixel-major sample
    /// store, whole as `f32` when that fits the budget, else in tiles at the stack's precision
    /// (in memory or in a spill file; the plan is then the capture's `memory`). Errors name
    /// what is wrong (sizes, shapes, counts, an image without a finite sample, an empty mask,
    /// lights that do not determine a normal, a budget too small); non-finite samples of an
    /// image that has finite ones follow [`MissingReadings`], held whole or in tiles.
    pub fn from_stack_with(
        stack: Stack<'_>,
        lights: Lights,
        mask: Option<ArrayView2<'_, bool>>,
        options: &StackOptions,
    ) -> Result<Self> {
        let (n, h, w, c) = stack.dim();
        check_frame(w, h)?;
        if n != lights.len() {
            return Err(Error::invalid(format!(
                "the image stack holds {n} images but {} lights were given: expected one light per image",
                lights.len()
            )));
        }
        if n < 3 {
            return Err(Error::invalid(format!(
                "{n} image(s): photometric stereo needs at least three"
            )));
        }
        if c != 1 && c != 3 {
            return Err(Error::invalid(format!(
                "the images have {c} channels: expected 1 (grey) or 3 (RGB)"
            )));
        }
        lights.check_rank()?;
        check_camera_frame(&lights, w, h)?;
        if let Some(m) = &mask {
            if m.dim() != (h, w) {
                return Err(Error::invalid(format!(
                    "the mask is {}×{} (rows×columns) but the images are {h}×{w}",
                    m.dim().0,
                    m.dim().1
                )));
            }
        }
        let size = CaptureSize {
            width: w,
            height: h,
            pixels: mask
                .as_ref()
                .map_or(w * h, |m| m.iter().filter(|&&v| v).count()),
            lights: n,
            channels: c,
            sample_type: match stack {
                Stack::U8(_) | Stack::U16(_) => SampleType::U16,
                Stack::F32(_) | Stack::F64(_) => SampleType::F32,
            },
            threads: 0,
            ground_truth: false,
            decoded_whole: false,
            beside: Default::default(),
        };
        if size.pixels == 0 {
            return Err(Error::invalid(
                "the mask is empty (no pixel inside the object)",
            ));
        }
        let budget = options
            .budget
            .unwrap_or_else(crate::model::memory::default_budget);
        let (layout, plan) =
            crate::model::memory::plan(&size, budget, Force::default()).map_err(|e| {
                match options.budget {
                    Some(_) => e,
                    // The machine's budget: say so, and which parameter sets another.
                    None => Error::invalid(format!(
                        "an image stack of {n}×{h}×{w}×{c} (images × rows × columns × channels): \
                         the default memory budget ({}, half of the memory available) is {}; {} sets it",
                        crate::model::memory::size_flag(budget),
                        crate::model::memory::too_small(&size),
                        crate::base::error::param("memory_limit")
                    )),
                }
            })?;
        let mask: Vec<bool> = match mask {
            Some(m) => m.iter().copied().collect(),
            None => vec![true; w * h],
        };
        let pixels = mask_pixel_indices(&mask);
        let scales: Vec<[f32; 3]> = lights
            .intensities
            .iter()
            .map(|i| light_scale(i, c))
            .collect();
        if layout != Layout::InMemory {
            let spill = (layout == Layout::Spill)
                .then(|| options.spill_dir.clone().unwrap_or_else(std::env::temp_dir));
            let mut missing = MissingReadings::new(n, pixels.len() * c);
            let store = tiled_store(
                &stack,
                (&mask, &pixels),
                &scales,
                &plan,
                spill.as_deref(),
                &mut missing,
            )?;
            let note = missing.verdict(&[])?;
            let mut capture = Capture::from_parts(CaptureParts {
                width: w,
                height: h,
                channels: c,
                bit_depth: stack.bit_depth(),
                lights,
                mask,
                pixels,
                samples: Vec::new(),
                store: Some(Arc::new(store)),
                sources: Vec::new(),
                notes: note.into_iter().collect(),
            });
            capture.memory = Some(plan);
            return Ok(capture);
        }
        let samples = match stack {
            Stack::U8(v) => gather_stack(&v, &pixels, &scales, |x| x as f32 / 255.0),
            Stack::U16(v) => gather_stack(&v, &pixels, &scales, |x| x as f32 / 65535.0),
            Stack::F32(v) => gather_stack(&v, &pixels, &scales, |x| x),
            Stack::F64(v) => gather_stack(&v, &pixels, &scales, |x| x as f32),
        };
        let mut samples = samples;
        let mut missing = MissingReadings::new(n, pixels.len() * c);
        missing.zero_in_samples(&mut samples, c);
        let note = missing.verdict(&[])?;
        let mut capture =
            Capture::in_memory((w, h, c), stack.bit_depth(), lights, mask, pixels, samples);
        capture.notes.extend(note);
        Ok(capture)
    }

    /// The samples of every mask pixel, `[pixel][light][channel]`, intensity-normalised: the
    /// store of a capture held whole, or its tiles read in turn.
    pub fn samples_whole(&self) -> Result<Vec<f32>> {
        if self.store.is_none() {
            return Ok(self.samples.clone());
        }
        let mut out = Vec::with_capacity(self.n_pixels() * self.n_lights() * self.channels);
        self.for_each_tile(|_, tile| {
            out.extend_from_slice(&tile.samples);
            Ok(())
        })?;
        Ok(out)
    }

    /// The light intensities per image channel, (N, C): each light's RGB intensities, or
    /// their mean for grey images (what each channel was divided by).
    pub fn channel_intensities(&self) -> Vec<f64> {
        let c = self.channels;
        self.lights
            .intensities
            .iter()
            .flat_map(|e| {
                if c == 1 {
                    vec![(e[0] + e[1] + e[2]) / 3.0]
                } else {
                    e[..c].to_vec()
                }
            })
            .collect()
    }

    /// The images as given, (N, H, W, C) row-major `f32` at full scale 1: the samples
    /// multiplied back by their light's intensity (for grey images the mean of its RGB
    /// intensities), zero outside the mask.
    pub fn images(&self) -> Result<Vec<f32>> {
        let (n, c, w, h) = (self.n_lights(), self.channels, self.width, self.height);
        let mut out = vec![0f32; n * h * w * c];
        let scales: Vec<[f32; 3]> = self
            .lights
            .intensities
            .iter()
            .map(|e| {
                if c == 1 {
                    [((e[0] + e[1] + e[2]) / 3.0) as f32; 3]
                } else {
                    [e[0] as f32, e[1] as f32, e[2] as f32]
                }
            })
            .collect();
        self.for_each_tile(|_, tile| {
            for (p, &i) in tile.pixels.iter().enumerate() {
                let s = tile.pixel_samples(p);
                for (k, scale) in scales.iter().enumerate() {
                    let at = (k * h * w + i as usize) * c;
                    for j in 0..c {
                        out[at + j] = s[k * c + j] * scale[j];
                    }
                }
            }
            Ok(())
        })?;
        Ok(out)
    }

    /// Per light and channel, the intensity-normalised reading at and above which the camera
    /// may have clipped it: full scale less half a code step of the source's bit depth,
    /// divided by the light's intensity as the samples are ([`light_scale`]). Every response
    /// the loaders linearise maps full scale to 1 and the code below it to at most 1 − 1 / L
    /// (L = 2^bits − 1), so only readings at full scale reach it. Float sources (32 bits) do
    /// not clip: `f32::INFINITY`. A reading from which an ambient frame was subtracted lies
    /// below its level and is not caught.
    pub fn clip_levels(&self) -> Vec<[f32; 3]> {
        let top = match self.bit_depth {
            8 | 16 => 1.0 - 0.5 / ((1u32 << self.bit_depth) - 1) as f64,
            _ => return vec![[f32::INFINITY; 3]; self.n_lights()],
        };
        (0..self.n_lights())
            .map(|k| {
                let i = self.lights.intensities.get(k).copied().unwrap_or([1.0; 3]);
                light_scale(&i, self.channels).map(|s| (top * f64::from(s)) as f32)
            })
            .collect()
    }

    /// Number of lights (= images).
    pub fn n_lights(&self) -> usize {
        self.lights.len()
    }

    /// Number of pixels inside the mask.
    pub fn n_pixels(&self) -> usize {
        self.pixels.len()
    }

    /// The samples of mask pixel `p`: `N * C` values, light-major.
    #[inline]
    pub fn pixel_samples(&self, p: usize) -> &[f32] {
        let stride = self.n_lights() * self.channels;
        let j = match &self.sparse {
            None => p,
            Some(ids) => ids
                .binary_search(&(p as u32))
                .unwrap_or_else(|_| panic!("mask pixel {p} is not in this sampled view")),
        };
        &self.samples[j * stride..(j + 1) * stride]
    }

    /// (row, col) of mask pixel `p`.
    #[inline]
    pub fn pixel_position(&self, p: usize) -> (usize, usize) {
        let i = self.pixels[p] as usize;
        (i / self.width, i % self.width)
    }

    /// A capture with only the lights `keep` (in that order), for light-subset experiments.
    pub fn select_lights(&self, keep: &[usize]) -> Result<Capture> {
        let n = self.n_lights();
        if let Some(&bad) = keep.iter().find(|&&k| k >= n) {
            return Err(Error::invalid(format!(
                "light index {} out of range 1..={n}",
                bad + 1
            )));
        }
        let lights = self.lights.permuted(keep);
        lights.check_rank()?;
        let sources = keep
            .iter()
            .filter_map(|&k| self.sources.get(k).cloned())
            .collect();
        if let Some(store) = &self.store {
            return Ok(Capture {
                lights,
                store: Some(Arc::new(store.select_lights(keep)?)),
                sources,
                ..self.clone_without_samples()
            });
        }
        let c = self.channels;
        let stride_in = n * c;
        let stride_out = keep.len() * c;
        let mut samples = vec![0f32; self.n_pixels() * stride_out];
        samples
            .par_chunks_mut(stride_out)
            .zip(self.samples.par_chunks(stride_in))
            .for_each(|(out, src)| {
                for (j, &k) in keep.iter().enumerate() {
                    out[j * c..(j + 1) * c].copy_from_slice(&src[k * c..(k + 1) * c]);
                }
            });
        Ok(Capture {
            lights,
            samples,
            sources,
            ..self.clone_without_samples()
        })
    }

    /// Whether the samples are in a tiled store rather than whole in memory.
    pub fn is_tiled(&self) -> bool {
        self.store.is_some()
    }

    /// Runs `f` on every tile of the capture in turn, in mask-pixel order, with the index of
    /// the tile's first mask pixel and a view of the tile: a capture of the tile's pixels only
    /// (local indices `0..view.n_pixels()`, the same lights, channels and frame size, no mask),
    /// whose `pixel_samples` are the `f32` values a capture held whole gives. A capture held
    /// whole is its own single tile (no copy). Per-pixel stages run on the views; what needs
    /// the whole frame does not belong in `f`.
    pub fn for_each_tile(&self, mut f: impl FnMut(usize, &Capture) -> Result<()>) -> Result<()> {
        let Some(store) = &self.store else {
            return f(0, self);
        };
        let tiling = store.tiling();
        let mut raw = Vec::new();
        let mut view = Capture {
            mask: Vec::new(),
            pixels: Vec::new(),
            sources: Vec::new(),
            notes: Vec::new(),
            memory: None,
            ..self.clone_without_samples_and_mask()
        };
        for t in 0..tiling.len() {
            let range = tiling.pixels(t);
            if range.is_empty() {
                continue;
            }
            store.read_tile(t, &mut raw, &mut view.samples)?;
            view.forget_statistics();
            view.pixels.clear();
            view.pixels.extend_from_slice(&self.pixels[range.clone()]);
            f(range.start, &view)?;
        }
        Ok(())
    }

    /// Runs `f` on the mask pixels `ids` (ascending global indices) one tile at a time, with
    /// the tile's share of `ids` and a view whose `pixel_samples(p)` answers for those `p`
    /// (the `f32` values a capture held whole gives). The view has the capture's lights,
    /// channels and frame size but no mask or pixel list; a capture held whole is passed as it
    /// is with all of `ids`. Memory: one tile's samples at most, however many pixels `ids`
    /// names (the per-pixel re-solves of a large capture stay within the budget).
    pub fn for_ids_by_tile(
        &self,
        ids: &[usize],
        mut f: impl FnMut(&[usize], &Capture) -> Result<()>,
    ) -> Result<()> {
        let Some(store) = &self.store else {
            return f(ids, self);
        };
        debug_assert!(ids.windows(2).all(|w| w[0] < w[1]), "ids must ascend");
        let tiling = store.tiling();
        let mut raw = Vec::new();
        let mut view = Capture {
            memory: None,
            ..self.clone_without_samples_and_mask()
        };
        let mut j = 0;
        for t in 0..tiling.len() {
            let range = tiling.pixels(t);
            let first = j;
            while j < ids.len() && ids[j] < range.end {
                j += 1;
            }
            if j == first {
                continue;
            }
            let sub = &ids[first..j];
            // The view holds the whole tile (no copy of the selected pixels' samples) and
            // answers for the tile's pixels.
            store.read_tile(t, &mut raw, &mut view.samples)?;
            view.sparse = Some(Arc::new((range.start as u32..range.end as u32).collect()));
            view.forget_statistics();
            f(sub, &view)?;
        }
        Ok(())
    }

    /// A view holding the samples of the mask pixels `ids` only (any order, duplicates
    /// allowed), for statistics over a regular sample of pixels: `pixel_samples(p)` answers for
    /// those `p` (global indices) and panics for others; `n_pixels`, `pixels` and the mask are
    /// the whole capture's. A capture held whole is returned as it is (cloned).
    pub fn sampled(&self, ids: &[usize]) -> Result<Capture> {
        let Some(store) = &self.store else {
            return Ok(self.clone());
        };
        let mut ids: Vec<u32> = ids.iter().map(|&p| p as u32).collect();
        ids.sort_unstable();
        ids.dedup();
        let stride = self.n_lights() * self.channels;
        let mut samples = vec![0f32; ids.len() * stride];
        let tiling = store.tiling();
        let (mut raw, mut tile) = (Vec::new(), Vec::new());
        let mut j = 0;
        for t in 0..tiling.len() {
            let range = tiling.pixels(t);
            let first = j;
            while j < ids.len() && (ids[j] as usize) < range.end {
                j += 1;
            }
            if j == first {
                continue;
            }
            store.read_tile(t, &mut raw, &mut tile)?;
            for (i, &p) in ids[first..j].iter().enumerate() {
                let local = p as usize - range.start;
                samples[(first + i) * stride..(first + i + 1) * stride]
                    .copy_from_slice(&tile[local * stride..(local + 1) * stride]);
            }
        }
        Ok(Capture {
            samples,
            sparse: Some(Arc::new(ids)),
            ..self.clone_without_samples()
        })
    }

    fn clone_without_samples_and_mask(&self) -> Capture {
        Capture {
            width: self.width,
            height: self.height,
            channels: self.channels,
            bit_depth: self.bit_depth,
            lights: self.lights.clone(),
            mask: Vec::new(),
            pixels: Vec::new(),
            samples: Vec::new(),
            store: None,
            memory: None,
            sparse: None,
            sources: Vec::new(),
            notes: Vec::new(),
            statistics: Statistics::default(),
            light_refinement: self.light_refinement.clone(),
        }
    }

    fn clone_without_samples(&self) -> Capture {
        Capture {
            width: self.width,
            height: self.height,
            channels: self.channels,
            bit_depth: self.bit_depth,
            lights: self.lights.clone(),
            mask: self.mask.clone(),
            pixels: self.pixels.clone(),
            samples: Vec::new(),
            store: None,
            memory: self.memory.clone(),
            sparse: None,
            sources: Vec::new(),
            notes: self.notes.clone(),
            statistics: Statistics::default(),
            light_refinement: self.light_refinement.clone(),
        }
    }

    /// The values of a full-frame map (row-major, one per frame pixel) at the mask pixels, in
    /// mask order: the inverse of [`Capture::scatter`] with one value per pixel.
    pub fn gather<T: Copy>(&self, frame: &[T]) -> Vec<T> {
        self.pixels.iter().map(|&i| frame[i as usize]).collect()
    }

    /// Scatters per-mask-pixel values (`per_pixel` values each) into a full
    /// `height × width × per_pixel` row-major buffer filled with `fill` outside the mask.
    pub fn scatter<T: Copy + Send + Sync>(
        &self,
        values: &[T],
        per_pixel: usize,
        fill: T,
    ) -> Vec<T> {
        let mut out = vec![fill; self.width * self.height * per_pixel];
        for (p, &i) in self.pixels.iter().enumerate() {
            let i = i as usize;
            out[i * per_pixel..(i + 1) * per_pixel]
                .copy_from_slice(&values[p * per_pixel..(p + 1) * per_pixel]);
        }
        out
    }

    /// Whether the mask is the whole frame: the mask pixels are then the frame pixels in
    /// order, and a per-mask-pixel array is its full-frame map.
    pub fn mask_is_frame(&self) -> bool {
        self.pixels.len() == self.width * self.height
    }

    /// [`Capture::scatter`] of values given up: on a mask that is the whole frame they are the
    /// full-frame map already and are returned as they are (no second copy is made).
    pub fn scatter_owned<T: Copy + Send + Sync>(
        &self,
        values: Vec<T>,
        per_pixel: usize,
        fill: T,
    ) -> Vec<T> {
        if self.mask_is_frame() {
            values
        } else {
            self.scatter(&values, per_pixel, fill)
        }
    }

    /// [`Capture::gather`] of a map given up: on a mask that is the whole frame it is returned
    /// as it is.
    pub fn gather_owned<T: Copy>(&self, frame: Vec<T>) -> Vec<T> {
        if self.mask_is_frame() {
            frame
        } else {
            self.gather(&frame)
        }
    }
}

/// An (N, H, W, C) image stack in memory: N images of H rows, W columns and C channels, of
/// one of the sample types cameras and arrays give. See [`Capture::from_stack`].
#[derive(Clone, Debug)]
pub enum Stack<'a> {
    /// 8-bit samples, full scale 255.
    U8(ArrayView4<'a, u8>),
    /// 16-bit samples, full scale 65535.
    U16(ArrayView4<'a, u16>),
    /// Float samples, full scale 1.
    F32(ArrayView4<'a, f32>),
    /// Double samples, full scale 1 (stored as f32).
    F64(ArrayView4<'a, f64>),
}

impl Stack<'_> {
    /// (N, H, W, C).
    pub fn dim(&self) -> (usize, usize, usize, usize) {
        match self {
            Stack::U8(v) => v.dim(),
            Stack::U16(v) => v.dim(),
            Stack::F32(v) => v.dim(),
            Stack::F64(v) => v.dim(),
        }
    }
}

impl Stack<'_> {
    /// The stack as images at full scale 1 (integers divided by 255 or 65535, as
    /// [`Capture::from_stack_with`] reads them), after the frame limits of
    /// [`Capture::from_stack_with`].
    pub fn images(&self) -> Result<Vec<Image>> {
        let (_, h, w, _) = self.dim();
        check_frame(w, h)?;
        fn each<T: Copy + Sync>(
            v: &ArrayView4<'_, T>,
            bits: u8,
            f: impl Fn(T) -> f32 + Sync,
        ) -> Vec<Image> {
            let (_, h, w, c) = v.dim();
            v.outer_iter()
                .into_par_iter()
                .map(|img| Image {
                    width: w,
                    height: h,
                    channels: c,
                    bit_depth: bits,
                    data: img.iter().map(|&x| f(x)).collect(),
                })
                .collect()
        }
        Ok(match self {
            Stack::U8(v) => each(v, 8, |x| x as f32 / 255.0),
            Stack::U16(v) => each(v, 16, |x| x as f32 / 65535.0),
            Stack::F32(v) => each(v, 32, |x| x),
            Stack::F64(v) => each(v, 32, |x| x as f32),
        })
    }

    /// Bits per sample of the stack's type: 8, 16, or 32 for floats.
    pub fn bit_depth(&self) -> u8 {
        match self {
            Stack::U8(_) => 8,
            Stack::U16(_) => 16,
            Stack::F32(_) | Stack::F64(_) => 32,
        }
    }
}

/// Where an image stack from memory is held ([`Capture::from_stack_with`]).
#[derive(Clone, Debug, Default)]
pub struct StackOptions {
    /// The memory budget, bytes (`None`: [`crate::model::memory::default_budget`]).
    pub budget: Option<u64>,
    /// The folder of the spill file when the samples go to one (`None`: the system's
    /// temporary folder).
    pub spill_dir: Option<PathBuf>,
}

/// Refuses a frame beyond the limits every image reader applies.
fn check_frame(w: usize, h: usize) -> Result<()> {
    if w == 0 || h == 0 {
        return Err(Error::invalid(format!(
            "the images are {w}×{h} (width×height): expected at least one pixel"
        )));
    }
    if w as u64 > MAX_IMAGE_SIDE || h as u64 > MAX_IMAGE_SIDE {
        return Err(Error::invalid(format!(
            "the images are {w}×{h} (width×height): a side exceeds the limit of {MAX_IMAGE_SIDE} pixels"
        )));
    }
    if (w as u64) * (h as u64) > MAX_IMAGE_PIXELS {
        return Err(Error::invalid(format!(
            "the images are {w}×{h} (width×height): more than the limit of {MAX_IMAGE_PIXELS} pixels"
        )));
    }
    Ok(())
}

/// The samples of a stack in a tiled store at its precision (`u16` for integer stacks, `f32`
/// for floats), under `plan`, for the frame's `mask` and its mask `pixels`; the same `f32`
/// values as [`gather_stack`] when read back, non-finite ones stored as 0 and counted in
/// `missing` (the rule of [`MissingReadings`]).
fn tiled_store(
    stack: &Stack<'_>,
    (mask, pixels): (&[bool], &[u32]),
    scales: &[[f32; 3]],
    plan: &MemoryPlan,
    spill_dir: Option<&std::path::Path>,
    missing: &mut MissingReadings,
) -> Result<SampleStore> {
    let (n, h, w, c) = stack.dim();
    let (kind, decode) = match stack {
        Stack::U8(_) => (SampleType::U16, Decode::Div(255.0)),
        Stack::U16(_) => (SampleType::U16, Decode::Div(65535.0)),
        Stack::F32(_) | Stack::F64(_) => (SampleType::F32, Decode::Float),
    };
    let tiling = Tiling::new(mask, w, h, plan.tile_pixels);
    let mut store = SampleStore::new(
        kind,
        c,
        tiling.clone(),
        vec![decode; n],
        scales.to_vec(),
        spill_dir,
    )?;
    let mut raw = Vec::new();
    for t in 0..tiling.len() {
        let tile = &pixels[tiling.pixels(t)];
        match stack {
            Stack::U8(v) => stored_bytes(v, tile, &mut raw, |x| (x as u16).to_ne_bytes()),
            Stack::U16(v) => stored_bytes(v, tile, &mut raw, |x: u16| x.to_ne_bytes()),
            Stack::F32(v) => float_bytes(v, tile, scales, &mut raw, missing, |x| x),
            Stack::F64(v) => float_bytes(v, tile, scales, &mut raw, missing, |x| x as f32),
        }
        store.write_raw(t, &raw)?;
    }
    Ok(store)
}

/// The stored bytes of the pixels `tile` (pixel-major, then light, then channel) of an
/// integer stack.
fn stored_bytes<T: Copy + Sync, const B: usize>(
    view: &ArrayView4<'_, T>,
    tile: &[u32],
    raw: &mut Vec<u8>,
    bytes: impl Fn(T) -> [u8; B] + Sync,
) {
    let (n, _, w, c) = view.dim();
    let pb = n * c * B;
    raw.clear();
    raw.resize(tile.len() * pb, 0);
    raw.par_chunks_mut(pb)
        .zip(tile.par_iter())
        .for_each(|(out, &i)| {
            let (row, col) = (i as usize / w, i as usize % w);
            for k in 0..n {
                for ch in 0..c {
                    let at = (k * c + ch) * B;
                    out[at..at + B].copy_from_slice(&bytes(view[[k, row, col, ch]]));
                }
            }
        });
}

/// The stored `f32` bytes of the pixels `tile` of a float stack; a sample whose
/// intensity-normalised value is not finite is stored as 0 and counted in `missing`.
fn float_bytes<T: Copy + Sync>(
    view: &ArrayView4<'_, T>,
    tile: &[u32],
    scales: &[[f32; 3]],
    raw: &mut Vec<u8>,
    missing: &mut MissingReadings,
    to_f32: impl Fn(T) -> f32 + Sync,
) {
    stored_bytes(view, tile, raw, |x| to_f32(x).to_ne_bytes());
    let (n, _, _, c) = view.dim();
    for px in raw.chunks_exact_mut(n * c * 4) {
        for (j, v) in px.chunks_exact_mut(4).enumerate() {
            let (k, ch) = (j / c, j % c);
            let x = f32::from_ne_bytes([v[0], v[1], v[2], v[3]]);
            if !(x * scales[k][ch]).is_finite() {
                v.copy_from_slice(&0f32.to_ne_bytes());
                missing.per_image[k] += 1;
            }
        }
    }
}

/// The pixel-major sample store (`[pixel][light][channel]`) of the mask pixels `pixels`, read
/// from an (N, H, W, C) view of any strides, each sample scaled by `to_f32` and its light's
/// intensity scale. Chunks of pixels run in parallel; within a chunk, light by light, so each
/// image is read along its rows.
fn gather_stack<T: Copy + Sync>(
    view: &ArrayView4<'_, T>,
    pixels: &[u32],
    scales: &[[f32; 3]],
    to_f32: impl Fn(T) -> f32 + Sync,
) -> Vec<f32> {
    let (n, _, w, c) = view.dim();
    let stride = n * c;
    let mut samples = vec![0f32; pixels.len() * stride];
    const PIXELS_PER_TASK: usize = 4096;
    samples
        .par_chunks_mut(PIXELS_PER_TASK * stride)
        .zip(pixels.par_chunks(PIXELS_PER_TASK))
        .for_each(|(out, chunk)| {
            for (k, scale) in scales.iter().enumerate() {
                let image = view.index_axis(Axis(0), k);
                for (dp, &i) in chunk.iter().enumerate() {
                    let (row, col) = (i as usize / w, i as usize % w);
                    let dst = &mut out[dp * stride + k * c..dp * stride + (k + 1) * c];
                    for (ch, d) in dst.iter_mut().enumerate() {
                        *d = to_f32(image[[row, col, ch]]) * scale[ch];
                    }
                }
            }
        });
    samples
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interleave_transposes() {
        let planes = vec![vec![1.0, 2.0, 3.0, 4.0], vec![5.0, 6.0, 7.0, 8.0]];
        // 2 pixels, 2 channels, 2 lights
        let s = interleave(&planes, 2, 2);
        assert_eq!(s, vec![1.0, 2.0, 5.0, 6.0, 3.0, 4.0, 7.0, 8.0]);
    }
}
