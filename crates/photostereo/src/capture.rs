//! Capture loading: the DiLiGenT layout, the list-file layout and explicit image lists
//! (CONVENTIONS.md, "Capture layouts"), decoded in parallel into one sample store.
//!
//! Samples are stored pixel-major for the pixels inside the mask only:
//! `samples[(p * N + k) * C + c]` is channel `c` of light `k` at the `p`-th mask pixel, already
//! divided by light `k`'s intensity. Memory is `4 · P · N · C` bytes (P mask pixels, N lights,
//! C channels), with a transient second copy of the same size while loading from files; an
//! in-memory stack ([`Capture::from_stack`]) is read straight into the store.

use crate::error::{Error, Result};
use crate::imageio::{read_image, read_mask, Image};
use crate::lights::Lights;
use crate::memory::{CaptureSize, Force, Layout, MemoryPlan};
use crate::progress::Progress;
use crate::store::{Decode, SampleStore, SampleType, Tiling};
use ndarray::{ArrayView2, ArrayView4, Axis};
use rayon::prelude::*;
use std::path::{Path, PathBuf};
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
    pub light_refinement: Option<crate::calibrate::LightRefinement>,
    /// The capture-wide statistics once measured (noise level, dark floor, κ): every method
    /// run on this capture reads them instead of measuring them again. A clone or any capture
    /// derived from this one starts without them.
    statistics: Statistics,
}

/// The capture-wide statistics of one [`Capture`], each measured on first use
/// ([`crate::detect::image_noise`], [`crate::detect::dark_floor`],
/// [`crate::detect::estimate_kappa_weighted`], [`crate::detect::light_noise_factors`]). They are a function of the samples, lights and mask, which
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
}

impl Clone for Statistics {
    fn clone(&self) -> Self {
        Statistics::default()
    }
}

/// Where a capture's files are: the images, their lights and an optional mask.
#[derive(Clone, Debug)]
pub struct CaptureFiles {
    /// Image files in light order.
    pub images: Vec<PathBuf>,
    /// Light directions (and intensities), one per image.
    pub lights: Lights,
    /// Optional mask image (non-zero = object).
    pub mask: Option<PathBuf>,
    /// Remarks made while resolving the layout.
    pub notes: Vec<String>,
}

impl CaptureFiles {
    /// Every input layout, as the command line and the Python package take it: one folder
    /// (the DiLiGenT layout; `lights` replaces its directions, `intensities` its intensities),
    /// one `.txt` list file (with `lights`), or image files (with `lights`). `mask` replaces the
    /// layout's own mask.
    pub fn from_inputs(
        inputs: &[PathBuf],
        lights: Option<&Path>,
        intensities: Option<&Path>,
        mask: Option<&Path>,
    ) -> Result<Self> {
        let is_list = |p: &Path| {
            p.extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| e.eq_ignore_ascii_case("txt"))
        };
        let mut files = match inputs {
            [] => {
                return Err(Error::invalid(
                    "no input: expected a capture folder, a list file or image files",
                ))
            }
            // Near lights (CONVENTIONS.md): the folder's own LED positions, unless --lights.
            [dir] if dir.is_dir() && lights.is_none() && crate::nearlayout::is_near_layout(dir) => {
                if let Some(p) = intensities {
                    return Err(Error::file(
                        p,
                        format!(
                            "{} is a near-light capture: its LEDs' radiance is read from \
                             light_intensities.txt in that folder, so --intensities does not apply \
                             (edit that file instead)",
                            dir.display()
                        ),
                    ));
                }
                crate::nearlayout::near_capture_files(dir, None)?
            }
            [lp] if lp.extension().is_some_and(|e| e.eq_ignore_ascii_case("lp")) => {
                let f = crate::nearlayout::lp_capture_files(lp)?;
                match intensities {
                    Some(p) => f.with_intensities_file(p)?,
                    None => f,
                }
            }
            [dir] if dir.is_dir() => {
                let f = CaptureFiles::diligent_with_lights(dir, lights)?;
                let f = crate::nearlayout::attach_camera(f, dir, None)?;
                match intensities {
                    Some(p) => f.with_intensities_file(p)?,
                    None => f,
                }
            }
            [list] if is_list(list) => {
                if !list.is_file() {
                    return Err(Error::file(list, "no such list file"));
                }
                let Some(l) = lights else {
                    return Err(Error::file(
                        list,
                        "a list file needs the light directions (--lights FILE)",
                    ));
                };
                let f = CaptureFiles::list_file(list, l)?;
                match intensities {
                    Some(p) => f.with_intensities_file(p)?,
                    None => f,
                }
            }
            [single] if !single.exists() => {
                return Err(Error::file(
                    single,
                    "no such file or folder (expected a capture folder, a list file or image files)",
                ));
            }
            images => {
                if let Some(dir) = images.iter().find(|p| p.is_dir()) {
                    return Err(Error::file(
                        dir,
                        "a folder among several inputs; give one DiLiGenT-layout folder, one list file, or image files",
                    ));
                }
                for p in images {
                    if !p.is_file() {
                        return Err(Error::file(p, "no such image file"));
                    }
                }
                let Some(l) = lights else {
                    return Err(Error::invalid(
                        "image files given explicitly need the light directions (--lights FILE, one direction per image)",
                    ));
                };
                CaptureFiles::explicit(images.to_vec(), l, intensities, None)?
            }
        };
        if let Some(m) = mask {
            files.mask = Some(m.to_path_buf());
        }
        Ok(files)
    }

    /// The DiLiGenT layout: a folder with the images, `filenames.txt` (optional),
    /// `light_directions.txt`, `light_intensities.txt` (optional) and `mask.png` (optional).
    pub fn diligent(dir: &Path) -> Result<Self> {
        Self::diligent_with_lights(dir, None)
    }

    /// The DiLiGenT layout with the light directions read from `lights` instead of the folder's
    /// `light_directions.txt` (the folder's intensities are still used when present).
    pub fn diligent_with_lights(dir: &Path, lights: Option<&Path>) -> Result<Self> {
        if !dir.is_dir() {
            return Err(Error::file(
                dir,
                "not a folder (expected the DiLiGenT layout)",
            ));
        }
        let lights_path = lights
            .map(Path::to_path_buf)
            .unwrap_or_else(|| dir.join("light_directions.txt"));
        if !lights_path.exists() {
            return Err(Error::file(
                &lights_path,
                "missing: the DiLiGenT layout needs light_directions.txt (or pass --lights)",
            ));
        }
        let lights = Lights::read_directions(&lights_path)?;
        let names = dir.join("filenames.txt");
        let images = folder_images(dir)?;
        let source = if names.exists() {
            format!("listed in {}", names.display())
        } else {
            format!("in {}", dir.display())
        };
        check_light_count(images.len(), &source, &lights, &lights_path)?;
        let intens = dir.join("light_intensities.txt");
        let lights = if intens.exists() {
            attach_intensities(lights, &intens, images.len(), &source)?
        } else {
            lights
        };
        let mask = dir.join("mask.png");
        let mut files = CaptureFiles {
            images,
            lights,
            mask: mask.exists().then_some(mask),
            notes: Vec::new(),
        };
        files.note_renormalised();
        Ok(files)
    }

    /// The list-file layout: a text file with the image count, the image paths and the mask path
    /// (see [`read_list_file`]); lights from a separate file.
    pub fn list_file(list: &Path, lights_path: &Path) -> Result<Self> {
        let listed = read_list_file(list)?;
        let lights = Lights::read_directions(lights_path)?;
        check_light_count(
            listed.images.len(),
            &format!("listed in {}", list.display()),
            &lights,
            lights_path,
        )?;
        let mut files = CaptureFiles {
            images: listed.images,
            lights,
            mask: listed.mask,
            notes: listed.notes,
        };
        files.note_renormalised();
        Ok(files)
    }

    /// Explicit image paths with a light file and optional intensities and mask.
    pub fn explicit(
        images: Vec<PathBuf>,
        lights_path: &Path,
        intensities: Option<&Path>,
        mask: Option<PathBuf>,
    ) -> Result<Self> {
        let mut lights = Lights::read_directions(lights_path)?;
        let source = "given on the command line";
        check_light_count(images.len(), source, &lights, lights_path)?;
        if let Some(p) = intensities {
            lights = attach_intensities(lights, p, images.len(), source)?;
        }
        let mut files = CaptureFiles {
            images,
            lights,
            mask,
            notes: Vec::new(),
        };
        files.note_renormalised();
        Ok(files)
    }

    /// Replaces the lights' intensities with those of `path` (e.g. `--intensities`); the row
    /// count must match the images and lights, and a mismatch names the file and both counts.
    pub fn with_intensities_file(mut self, path: &Path) -> Result<Self> {
        self.lights = attach_intensities(self.lights, path, self.images.len(), "in the capture")?;
        Ok(self)
    }

    fn note_renormalised(&mut self) {
        if self.lights.renormalised > 0 {
            self.notes.push(format!(
                "{} light direction(s) were not unit length and were normalised",
                self.lights.renormalised
            ));
        }
    }

    /// Decodes the images in parallel and builds the capture, within the default memory
    /// budget ([`crate::memory::default_budget`]).
    pub fn load(&self, progress: &dyn Progress) -> Result<Capture> {
        self.load_with(progress, &LoadOptions::default())
    }

    /// Decodes the images and builds the capture within `options.budget`: whole in memory as
    /// `f32` when that fits, else in tiles (see [`crate::memory`]); the plan is in the
    /// capture's `memory`. A budget too small for the capture's full-frame stages is refused
    /// (naming `memory_limit` and the smallest budget that works) before the samples are read.
    pub fn load_with(&self, progress: &dyn Progress, options: &LoadOptions) -> Result<Capture> {
        self.check_counts()?;
        let budget = options.budget.unwrap_or_else(crate::memory::default_budget);
        let info = crate::imageio::probe(&self.images[0])?;
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
        };
        // Without --memory-limit the budget is the machine's: a refusal names the images and
        // the memory available, as the readers' own checks do.
        let refusal = |e: Error| match (e, options.budget) {
            (Error::Parameter { message, .. }, None) => Error::file(
                &self.images[0],
                format!(
                    "declares {}×{} pixels × {} images: {} (the default budget is half of the \
                     memory available{}; --memory-limit sets it)",
                    info.width,
                    info.height,
                    self.images.len(),
                    message.split_once(": ").map_or(message.as_str(), |m| m.1),
                    if std::env::var_os(crate::limits::MEMORY_LIMIT_VAR).is_some() {
                        format!(", with {} set", crate::limits::MEMORY_LIMIT_VAR)
                    } else {
                        String::new()
                    }
                ),
            ),
            (e, _) => e,
        };
        // The frame alone (no mask pixel) already tells a budget that cannot work, before any
        // image is decoded; the smallest budget that works is then named with the mask's
        // pixels counted.
        if let Err(e) = crate::memory::plan(&size, budget, Force::default()) {
            let Ok(mask) = self.read_mask_for(info.width, info.height) else {
                return Err(refusal(e));
            };
            size.pixels = mask.iter().filter(|&&m| m).count();
            return Err(refusal(
                crate::memory::plan(&size, budget, Force::default())
                    .err()
                    .unwrap_or(e),
            ));
        }
        let mask = self.read_mask_for(info.width, info.height)?;
        size.pixels = mask.iter().filter(|&&m| m).count();
        let (layout, plan) = crate::memory::plan(&size, budget, options.force).map_err(refusal)?;
        let mut capture = if layout == Layout::InMemory {
            self.load_in_memory(progress, mask)?
        } else {
            if options.return_freed_memory_when_tiled {
                crate::limits::return_freed_memory();
            }
            let dir = options.spill_dir.clone().unwrap_or_else(std::env::temp_dir);
            self.load_tiled(
                progress,
                mask,
                &plan,
                (layout == Layout::Spill).then_some(&*dir),
            )?
        };
        capture.memory = Some(plan);
        let notes = crate::plausibility::check_capture(&capture)?;
        capture.notes.extend(notes);
        let (w, h) = (capture.width, capture.height);
        capture.notes.extend(self.whole_frame_note(w, h));
        Ok(capture)
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
        plan: &MemoryPlan,
        spill_dir: Option<&Path>,
    ) -> Result<Capture> {
        let n = self.images.len();
        let infos: Vec<crate::imageio::ImageInfo> = self
            .images
            .par_iter()
            .map(|p| crate::imageio::probe(p))
            .collect::<Result<_>>()?;
        let (w, h, c) = (infos[0].width, infos[0].height, infos[0].channels);
        for (k, i) in infos.iter().enumerate() {
            if let Some(e) = self.mismatch(k, (w, h, c), (i.width, i.height, i.channels)) {
                return Err(e);
            }
        }
        let kind = if infos.iter().any(|i| i.bit_depth == 32) {
            SampleType::F32
        } else {
            SampleType::U16
        };
        let decode: Vec<Decode> = infos
            .iter()
            .map(|i| match (kind, i.format, i.bit_depth) {
                (SampleType::F32, _, _) => Decode::Float,
                (_, crate::imageio::Format::Png, 8) => Decode::MulRecip(1.0f32 / 255.0),
                (_, crate::imageio::Format::Png, _) => Decode::MulRecip(1.0f32 / 65535.0),
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
        let pixels: Vec<u32> = mask
            .iter()
            .enumerate()
            .filter(|(_, &m)| m)
            .map(|(i, _)| i as u32)
            .collect();
        let tiling = Tiling::new(&mask, w, h, plan.tile_pixels);
        let mut store =
            SampleStore::new(kind, c, tiling.clone(), decode.clone(), scale, spill_dir)?;
        let e = kind.bytes();
        let sb = c * e; // bytes of one light's sample of one pixel
        let pb = n * sb;
        let streamed = infos.iter().all(|i| i.streamable);
        progress.begin("loading", (n * h) as u64);
        let mut raw: Vec<u8> = Vec::new();
        // The bytes of light k for the pixels of a tile, from integer or decoded values.
        let put_u16 = |dec: Decode, u: u16, out: &mut Vec<u8>| match kind {
            SampleType::U16 => out.extend_from_slice(&u.to_ne_bytes()),
            SampleType::F32 => {
                let v = match dec {
                    Decode::Div(f) => u as f32 / f,
                    Decode::MulRecip(r) => u as f32 * r,
                    Decode::Float => u as f32,
                };
                out.extend_from_slice(&v.to_ne_bytes())
            }
        };
        if streamed {
            let mut readers: Vec<crate::imageio::PngRows> = self
                .images
                .iter()
                .map(|p| crate::imageio::PngRows::open(p))
                .collect::<Result<_>>()?;
            let mut planes: Vec<Vec<u8>> = vec![Vec::new(); n];
            for t in 0..tiling.len() {
                crate::progress::check_cancelled(progress)?;
                let (r0, r1) = (tiling.rows[t], tiling.rows[t + 1]);
                let tile_pixels = &pixels[tiling.pixels(t)];
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
                                    put_u16(decode[k], u, plane);
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
        } else {
            // Decoded whole, as many at a time as there are threads; each group patched into
            // every tile.
            let group = rayon::current_num_threads().max(1);
            for k0 in (0..n).step_by(group) {
                crate::progress::check_cancelled(progress)?;
                let ks: Vec<usize> = (k0..(k0 + group).min(n)).collect();
                let images: Vec<Image> = ks
                    .par_iter()
                    .map(|&k| {
                        let img = read_image(&self.images[k])?;
                        if let Some(e) =
                            self.mismatch(k, (w, h, c), (img.width, img.height, img.channels))
                        {
                            return Err(e);
                        }
                        progress.advance(h as u64);
                        Ok(img)
                    })
                    .collect::<Result<_>>()?;
                for t in 0..tiling.len() {
                    let tile_pixels = &pixels[tiling.pixels(t)];
                    store.read_raw(t, &mut raw)?;
                    raw.par_chunks_mut(pb)
                        .zip(tile_pixels.par_iter())
                        .for_each(|(px, &i)| {
                            let mut bytes = Vec::with_capacity(sb);
                            for (&k, img) in ks.iter().zip(&images) {
                                bytes.clear();
                                let src = &img.data[i as usize * c..(i as usize + 1) * c];
                                for &v in src {
                                    match kind {
                                        SampleType::U16 => bytes
                                            .extend_from_slice(&decode[k].to_u16(v).to_ne_bytes()),
                                        SampleType::F32 => {
                                            bytes.extend_from_slice(&v.to_ne_bytes())
                                        }
                                    }
                                }
                                px[k * sb..(k + 1) * sb].copy_from_slice(&bytes);
                            }
                        });
                    store.write_raw(t, &raw)?;
                }
            }
        }
        progress.end();
        let _ = pb;
        Ok(Capture {
            width: w,
            height: h,
            channels: c,
            bit_depth: infos[0].bit_depth,
            lights: self.lights.clone(),
            mask,
            pixels,
            samples: Vec::new(),
            store: Some(Arc::new(store)),
            memory: None,
            sparse: None,
            sources: self.images.clone(),
            notes: self.notes.clone(),
            statistics: Statistics::default(),
            light_refinement: None,
        })
    }

    /// The loader of captures held whole as `f32`.
    fn load_in_memory(&self, progress: &dyn Progress, mask: Vec<bool>) -> Result<Capture> {
        let n = self.images.len();
        progress.begin("loading", n as u64);
        let first = read_image(&self.images[0])?;
        progress.advance(1);
        if mask.len() != first.width * first.height {
            return Err(Error::file(
                &self.images[0],
                "the image's size changed while the capture was read",
            ));
        }
        let pixels: Vec<u32> = mask
            .iter()
            .enumerate()
            .filter(|(_, &m)| m)
            .map(|(i, _)| i as u32)
            .collect();
        let (w, h, c) = (first.width, first.height, first.channels);
        // The samples of the mask pixels, plus their transient second copy while loading.
        let needed = (pixels.len() as u64)
            .saturating_mul(n as u64)
            .saturating_mul(c as u64)
            .saturating_mul(8);
        if let Err(m) = crate::limits::check_memory(
            needed,
            &format!(
                "{n} images of {} mask pixels × {c} channel(s) ({} of samples, twice while loading)",
                pixels.len(),
                crate::limits::human_bytes(needed / 2)
            ),
        ) {
            return Err(Error::invalid(format!(
                "{m}: use a smaller mask or fewer images (or set {})",
                crate::limits::MEMORY_LIMIT_VAR
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
        let bit_depth = first.bit_depth;
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
        let samples = interleave(&planes, pixels.len(), c);
        let capture = Capture {
            width: w,
            height: h,
            channels: c,
            bit_depth,
            lights: self.lights.clone(),
            mask,
            pixels,
            samples,
            store: None,
            memory: None,
            sparse: None,
            sources: self.images.clone(),
            notes: self.notes.clone(),
            statistics: Statistics::default(),
            light_refinement: None,
        };
        Ok(capture)
    }

    /// The note a capture without a mask gets: its whole frame is taken as the object, which is
    /// rarely meant (background pixels get normals and join the integration).
    pub fn whole_frame_note(&self, width: usize, height: usize) -> Option<String> {
        self.mask.is_none().then(|| {
            format!(
                "no mask: the whole {width}×{height} frame is used as the object \
                 (no mask.png in the capture folder, no mask line in a list file, no --mask)"
            )
        })
    }
}

/// The images of a capture folder: the names listed in `filenames.txt` (one per line, blank
/// lines skipped) when it exists, else every PNG, TIFF or OpenEXR file of the folder but the mask
/// and the ground truth (`mask*`, `Normal_gt*`), sorted by name.
pub(crate) fn folder_images(dir: &Path) -> Result<Vec<PathBuf>> {
    let names = dir.join("filenames.txt");
    if names.is_file() {
        return Ok(crate::limits::read_text(&names)?
            .lines()
            .map(str::trim)
            .filter(|l| !l.is_empty())
            .map(|l| dir.join(l))
            .collect());
    }
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| Error::io(dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            let name = p.file_name().and_then(|n| n.to_str()).unwrap_or("");
            let ext = p
                .extension()
                .and_then(|e| e.to_str())
                .unwrap_or("")
                .to_ascii_lowercase();
            matches!(ext.as_str(), "png" | "tif" | "tiff" | "exr")
                && !name.starts_with("mask")
                && !name.starts_with("Normal_gt")
        })
        .collect();
    v.sort();
    Ok(v)
}

/// The images and mask named by a list file (CONVENTIONS.md, layout 2).
#[derive(Clone, Debug)]
pub struct ListFile {
    pub images: Vec<PathBuf>,
    pub mask: Option<PathBuf>,
    /// How the paths were resolved, when it matters.
    pub notes: Vec<String>,
}

/// Reads a list file: a first line with the image count, then one image path per line, then an
/// optional mask path; blank lines and `#` comments are skipped. Paths are taken relative to the
/// list file's folder and, failing that, to its parent (the shared `psmImages` lists name
/// `psmImages/<object>/<file>`); a note says when the parent was used.
pub fn read_list_file(list: &Path) -> Result<ListFile> {
    parse_list_file(&crate::limits::read_text(list)?, list)
}

/// [`read_list_file`] on text already read from `list` (paths still resolve against its
/// folder and that folder's parent).
pub fn parse_list_file(text: &str, list: &Path) -> Result<ListFile> {
    let lines: Vec<(usize, &str)> = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
        .collect();
    let (first_line, first) = *lines
        .first()
        .ok_or_else(|| Error::file(list, "empty list file"))?;
    let count: usize = first.parse().map_err(|_| {
        Error::parse(
            list,
            first_line,
            format!("'{first}': expected the image count"),
        )
    })?;
    if lines.len() - 1 < count {
        return Err(Error::file(
            list,
            format!(
                "the count line (line {first_line}) announces {count} images but {} path(s) follow",
                lines.len() - 1
            ),
        ));
    }
    if lines.len() - 1 > count.saturating_add(1) {
        return Err(Error::file(
            list,
            format!(
                "the count line (line {first_line}) announces {count} images but {} path(s) follow \
                 (expected the {count} images and at most a mask)",
                lines.len() - 1
            ),
        ));
    }
    if lines.len() - 1 == count {
        // No mask line: a last "image" named like a mask means the count line counts the mask
        // as a photograph (or a photograph is missing).
        let (line, last) = lines[count];
        let name = Path::new(last)
            .file_name()
            .map(|n| n.to_string_lossy().to_ascii_lowercase())
            .unwrap_or_default();
        if name.contains("mask") {
            return Err(Error::file(
                list,
                format!(
                    "the count line (line {first_line}) announces {count} images, but image path \
                     {count}, '{last}' (line {line}), names a mask: {} photograph(s) and a mask \
                     follow; write {} on the count line, or add the missing photograph",
                    count - 1,
                    count - 1
                ),
            ));
        }
    }
    let base = match list.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let parent = match base.parent() {
        Some(p) if !p.as_os_str().is_empty() && base != Path::new(".") => p.to_path_buf(),
        _ => base.join(".."),
    };
    let bases = [base, parent];
    let mut used_parent = false;
    let mut resolve = |line: usize, rel: &str, what: &str| -> Result<PathBuf> {
        for (i, b) in bases.iter().enumerate() {
            let p = b.join(rel);
            if p.exists() {
                used_parent |= i == 1;
                return Ok(p);
            }
        }
        Err(Error::parse(
            list,
            line,
            format!("{what} '{rel}' not found relative to the list file's folder or its parent"),
        ))
    };
    let mut images = Vec::with_capacity(count);
    for (line, rel) in &lines[1..=count] {
        images.push(resolve(*line, rel, "image")?);
    }
    let mask = match lines.get(count + 1) {
        Some((line, rel)) => Some(resolve(*line, rel, "mask")?),
        None => None,
    };
    let mut notes = Vec::new();
    if used_parent {
        notes.push(format!(
            "paths in {} resolved relative to its parent folder",
            list.display()
        ));
    }
    Ok(ListFile {
        images,
        mask,
        notes,
    })
}

/// Refuses a light file whose row count differs from the image count, naming the file, where
/// the images come from (`source`) and both numbers.
fn check_light_count(images: usize, source: &str, lights: &Lights, path: &Path) -> Result<()> {
    if images != lights.len() {
        return Err(Error::file(
            path,
            format!(
                "{} light direction(s) for {images} image(s) {source}: expected one light per image",
                lights.len()
            ),
        ));
    }
    Ok(())
}

/// Reads an intensity file and attaches it, naming the file and the counts on a mismatch.
fn attach_intensities(lights: Lights, path: &Path, images: usize, source: &str) -> Result<Lights> {
    let rows = crate::lights::read_intensity_rows(path, Some(lights.len()))?;
    if rows.len() != lights.len() {
        return Err(Error::file(
            path,
            format!(
                "{} intensity row(s) for {} light direction(s) and {images} image(s) {source}: expected one row per light",
                rows.len(),
                lights.len()
            ),
        ));
    }
    lights.with_intensities(rows)
}

/// Per-channel factors 1 / intensity (grey images use the mean of the RGB intensities).
fn light_scale(intensity: &[f64; 3], channels: usize) -> [f32; 3] {
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

/// Options of [`CaptureFiles::load_with`].
#[derive(Clone, Debug, Default)]
pub struct LoadOptions {
    /// The memory budget, bytes (default: [`crate::memory::default_budget`]).
    pub budget: Option<u64>,
    /// Where a spill file goes (default: the system's temporary folder); `run` gives the
    /// output's staging folder.
    pub spill_dir: Option<PathBuf>,
    /// A forced layout or tile size (tests, experiments).
    pub force: Force,
    /// When the capture is loaded into tiles, make the C allocator hand large freed blocks
    /// back to the system at once ([`crate::limits::return_freed_memory`]): the process's peak
    /// then stays near what the run holds. Process-wide and lasting, so only a program that
    /// owns its process (the command line) sets it; a library host such as Python leaves it.
    pub return_freed_memory_when_tiled: bool,
    /// Ground-truth normals will be held (per mask pixel) to score the run: the plan counts
    /// them.
    pub ground_truth: bool,
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

/// Turns light-major planes (`planes[k][p * C + c]`) into the pixel-major sample store.
fn interleave(planes: &[Vec<f32>], n_pixels: usize, channels: usize) -> Vec<f32> {
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

impl Capture {
    /// The memo of this capture's statistics (see [`Statistics`]).
    pub(crate) fn statistics(&self) -> &Statistics {
        &self.statistics
    }

    /// Forgets the capture-wide statistics measured so far (noise level, dark floor, κ), which
    /// every method run on this capture otherwise reuses: call it after changing `samples`,
    /// `lights` or the mask in place. (Clones and captures derived by the library's functions
    /// always measure their own.)
    pub fn forget_statistics(&mut self) {
        self.statistics = Statistics::default();
    }

    /// Refines the lights from the readings ([`crate::calibrate::refine_lights`]) and applies
    /// the result ([`Capture::apply_light_refinement`]); returns whether the lights changed
    /// (`false`: the capture is not one to calibrate on, see `refine_lights`, or its lights
    /// were refined already).
    pub fn refine_lights(&mut self, params: &crate::calibrate::RefineParams) -> Result<bool> {
        if self.light_refinement.is_some() {
            return Ok(false);
        }
        match crate::calibrate::refine_lights(self, params)? {
            Some(r) => {
                self.apply_light_refinement(r)?;
                Ok(true)
            }
            None => Ok(false),
        }
    }

    /// Makes `refinement`'s lights the capture's: directions replaced, light k's samples
    /// divided by its gain (a tiled capture's store divides them as it reads them, with the
    /// same rounding), intensities multiplied by it (the record of what the lights are),
    /// statistics forgotten. Refused on a sampled view, on a capture already refined and on a
    /// tiled capture whose store is shared with another capture.
    pub fn apply_light_refinement(
        &mut self,
        refinement: crate::calibrate::LightRefinement,
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
        let pixels: Vec<u32> = (0..w * h).filter(|&i| mask[i]).map(|i| i as u32).collect();
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
        let samples = interleave(&planes, pixels.len(), c);
        Ok(Capture::in_memory(
            (w, h, c),
            images[0].bit_depth,
            lights,
            mask,
            pixels,
            samples,
        ))
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

    /// Builds a capture from one image stack in memory: `stack` is (N, H, W, C) with C = 1 or
    /// 3, any strides (a transposed or sliced view is fine); integer samples are scaled to
    /// [0, 1] by their type's full scale (255, 65535), float samples taken as they are. Each
    /// sample is divided by its light's intensity. `mask` is (H, W), true inside the object
    /// (default: the whole frame).
    ///
    /// The stack is read once, straight into the pixel-major sample store: that store is the
    /// only copy made. Errors name what is wrong (shapes, counts, non-finite samples, an empty
    /// mask, lights that do not determine a normal).
    pub fn from_stack(
        stack: Stack<'_>,
        lights: Lights,
        mask: Option<ArrayView2<'_, bool>>,
    ) -> Result<Self> {
        let (n, h, w, c) = stack.dim();
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
        if h == 0 || w == 0 {
            return Err(Error::invalid(format!(
                "the images are {w}×{h} (width×height): expected at least one pixel"
            )));
        }
        if c != 1 && c != 3 {
            return Err(Error::invalid(format!(
                "the images have {c} channels: expected 1 (grey) or 3 (RGB)"
            )));
        }
        lights.check_rank()?;
        let mask: Vec<bool> = match mask {
            Some(m) => {
                if m.dim() != (h, w) {
                    return Err(Error::invalid(format!(
                        "the mask is {}×{} (rows×columns) but the images are {h}×{w}",
                        m.dim().0,
                        m.dim().1
                    )));
                }
                m.iter().copied().collect()
            }
            None => vec![true; w * h],
        };
        let pixels: Vec<u32> = (0..w * h).filter(|&i| mask[i]).map(|i| i as u32).collect();
        if pixels.is_empty() {
            return Err(Error::invalid(
                "the mask is empty (no pixel inside the object)",
            ));
        }
        let scales: Vec<[f32; 3]> = lights
            .intensities
            .iter()
            .map(|i| light_scale(i, c))
            .collect();
        let (samples, bit_depth) = match stack {
            Stack::U8(v) => (gather_stack(&v, &pixels, &scales, |x| x as f32 / 255.0), 8),
            Stack::U16(v) => (
                gather_stack(&v, &pixels, &scales, |x| x as f32 / 65535.0),
                16,
            ),
            Stack::F32(v) => (gather_stack(&v, &pixels, &scales, |x| x), 32),
            Stack::F64(v) => (gather_stack(&v, &pixels, &scales, |x| x as f32), 32),
        };
        if let Some(bad) = samples.iter().position(|v| !v.is_finite()) {
            let p = bad / (n * c);
            let k = (bad / c) % n;
            let i = pixels[p] as usize;
            return Err(Error::invalid(format!(
                "image {} has a non-finite sample at row {}, column {}: expected finite intensities",
                k + 1,
                i / w,
                i % w
            )));
        }
        Ok(Capture::in_memory(
            (w, h, c),
            bit_depth,
            lights,
            mask,
            pixels,
            samples,
        ))
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
