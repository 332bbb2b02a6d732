//! The tiled sample store: the samples of a capture's mask pixels at the input's precision
//! (`u16` for 8- and 16-bit images, `f32` for float images), pixel-major, in tiles of whole
//! rows of the frame, held in memory or in a temporary spill file when they do not fit the
//! memory budget (ARCHITECTURE.md, "Samples behind one door"; ALGORITHMS.md §10).
//!
//! A tile is read back as `f32` samples `[pixel][light][channel]` already divided by each
//! light's intensity, computed with exactly the operations the image decoders use
//! (`u as f32 * (1/65535)` for PNG, `u as f32 / 65535` for TIFF, …) followed by the same
//! multiplication by `1 / intensity` as an in-memory capture: the values are bit-identical to
//! those of a capture held whole as `f32`.
//!
//! The spill file is created in the folder given (the output's staging folder for `run`) and
//! unlinked at once: it has no name from then on, the process's open handle is the only
//! reference, and the operating system frees it when the store is dropped or the process ends
//! for any reason (success, error, Ctrl-C, even SIGKILL). Tiles are moved with positioned reads
//! and writes into a bounded buffer, so the resident memory never holds more than the tiles in
//! use.

use crate::base::error::{Error, Result};
use rayon::prelude::*;
use std::fs::File;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

/// The type samples are stored as.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SampleType {
    /// 8- and 16-bit images: the integer read from the file (2 bytes).
    U16,
    /// Float images (4 bytes).
    F32,
}

impl SampleType {
    /// Bytes per stored sample.
    pub fn bytes(self) -> usize {
        match self {
            SampleType::U16 => 2,
            SampleType::F32 => 4,
        }
    }
}

/// How the stored value of one light's image becomes the decoder's `f32`, bit for bit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Decode {
    /// `u as f32 * r` (the PNG decoder: `r = 1/255` or `1/65535`, computed in `f32`).
    MulRecip(f32),
    /// `u as f32 / f` (the TIFF decoder and in-memory integer stacks: `f = 255` or `65535`).
    Div(f32),
    /// The stored `f32` as it is.
    Float,
}

impl Decode {
    #[inline]
    fn apply_u16(self, u: u16) -> f32 {
        match self {
            Decode::MulRecip(r) => u as f32 * r,
            Decode::Div(f) => u as f32 / f,
            Decode::Float => u as f32,
        }
    }

    /// The stored integer of a decoded value `v` (exact for values the decoder produced).
    pub fn to_u16(self, v: f32) -> u16 {
        let full = match self {
            Decode::MulRecip(r) => (1.0 / r as f64).round(),
            Decode::Div(f) => f as f64,
            Decode::Float => 1.0,
        };
        (v as f64 * full).round().clamp(0.0, 65535.0) as u16
    }
}

/// Row bands of the frame and the mask pixels each holds: tile `t` is rows
/// `rows[t]..rows[t + 1]` and mask pixels `starts[t]..starts[t + 1]`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Tiling {
    /// Row boundaries, `tiles + 1` values from 0 to the frame's height.
    pub rows: Vec<usize>,
    /// Mask-pixel boundaries, `tiles + 1` values from 0 to the mask pixel count.
    pub starts: Vec<usize>,
}

impl Tiling {
    /// Bands of whole rows holding at most `tile_pixels` mask pixels each (a band holds at
    /// least one row, whatever its count).
    pub fn new(mask: &[bool], width: usize, height: usize, tile_pixels: usize) -> Tiling {
        let tile_pixels = tile_pixels.max(1);
        let mut rows = vec![0];
        let mut starts = vec![0];
        let mut in_tile = 0usize;
        let mut total = 0usize;
        for r in 0..height {
            let count = mask[r * width..(r + 1) * width]
                .iter()
                .filter(|&&m| m)
                .count();
            if in_tile > 0 && in_tile + count > tile_pixels {
                rows.push(r);
                starts.push(total);
                in_tile = 0;
            }
            in_tile += count;
            total += count;
        }
        rows.push(height);
        starts.push(total);
        Tiling { rows, starts }
    }

    /// Number of tiles.
    pub fn len(&self) -> usize {
        self.starts.len() - 1
    }

    /// Whether there is no tile.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The mask pixels of tile `t`.
    pub fn pixels(&self, t: usize) -> std::ops::Range<usize> {
        self.starts[t]..self.starts[t + 1]
    }

    /// The most mask pixels of one tile.
    pub fn max_pixels(&self) -> usize {
        (0..self.len())
            .map(|t| self.starts[t + 1] - self.starts[t])
            .max()
            .unwrap_or(0)
    }
}

enum Backing {
    Memory(Vec<u8>),
    Spill(File),
}

/// The samples of a capture's mask pixels in tiles (see the module documentation).
pub struct SampleStore {
    kind: SampleType,
    n_lights: usize,
    channels: usize,
    tiling: Tiling,
    /// Per light: stored value → decoded value.
    decode: Vec<Decode>,
    /// Per light and channel: the factor 1 / intensity.
    scale: Vec<[f32; 3]>,
    /// Per light: the factor 1 / gain of a light refinement, applied after `scale` (as a
    /// capture held whole applies it to its samples); empty when the lights are as given.
    gain: Vec<f32>,
    backing: Backing,
    /// The folder of the spill file, when the tiles are spilled.
    spill_dir: Option<PathBuf>,
}

impl std::fmt::Debug for SampleStore {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SampleStore")
            .field("kind", &self.kind)
            .field("tiles", &self.tiling.len())
            .field("bytes", &self.bytes())
            .field("spill_dir", &self.spill_dir)
            .finish()
    }
}

impl SampleStore {
    /// An empty store for `tiling` (zeros), in memory, or in a spill file in `spill_dir` when
    /// given. `decode` and `scale` have one entry per light.
    pub fn new(
        kind: SampleType,
        channels: usize,
        tiling: Tiling,
        decode: Vec<Decode>,
        scale: Vec<[f32; 3]>,
        spill_dir: Option<&Path>,
    ) -> Result<SampleStore> {
        let n_lights = decode.len();
        let bytes = (*tiling.starts.last().unwrap_or(&0) as u64)
            * (n_lights * channels * kind.bytes()) as u64;
        let backing = match spill_dir {
            None => Backing::Memory(vec![0u8; bytes as usize]),
            Some(dir) => {
                let file = nameless_file(dir, "samples")?;
                file.set_len(bytes).map_err(|e| Error::io(dir, e))?;
                Backing::Spill(file)
            }
        };
        Ok(SampleStore {
            kind,
            n_lights,
            channels,
            tiling,
            decode,
            scale,
            gain: Vec::new(),
            backing,
            spill_dir: spill_dir.map(Path::to_path_buf),
        })
    }

    /// Multiplies light k's samples by `inverse_gains[k]` when they are read, after the
    /// intensity scale (what [`crate::model::capture::Capture::apply_light_refinement`] does to a
    /// capture held whole, with the same two roundings). Once only: a store whose gains are
    /// set keeps them.
    pub fn set_light_gains(&mut self, inverse_gains: Vec<f32>) -> Result<()> {
        if inverse_gains.len() != self.n_lights {
            return Err(Error::invalid(format!(
                "light gains: {} values for {} lights",
                inverse_gains.len(),
                self.n_lights
            )));
        }
        if !self.gain.is_empty() {
            return Err(Error::invalid(
                "light gains: this store's lights were refined already".to_string(),
            ));
        }
        self.gain = inverse_gains;
        Ok(())
    }

    /// The sample type.
    pub fn kind(&self) -> SampleType {
        self.kind
    }

    /// The tiles.
    pub fn tiling(&self) -> &Tiling {
        &self.tiling
    }

    /// Bytes of stored samples.
    pub fn bytes(&self) -> u64 {
        *self.tiling.starts.last().unwrap_or(&0) as u64 * self.pixel_bytes() as u64
    }

    /// Whether the tiles live in a spill file.
    pub fn spilled(&self) -> bool {
        matches!(self.backing, Backing::Spill(_))
    }

    /// The spill file's folder, when spilled.
    pub fn spill_dir(&self) -> Option<&Path> {
        self.spill_dir.as_deref()
    }

    /// Stored bytes of one pixel (all lights and channels).
    pub fn pixel_bytes(&self) -> usize {
        self.n_lights * self.channels * self.kind.bytes()
    }

    fn byte_range(&self, t: usize) -> (u64, usize) {
        let r = self.tiling.pixels(t);
        let pb = self.pixel_bytes() as u64;
        (
            r.start as u64 * pb,
            ((r.end - r.start) as u64 * pb) as usize,
        )
    }

    fn io_error(&self, e: std::io::Error) -> Error {
        let dir = self.spill_dir.clone().unwrap_or_default();
        Error::io(dir.join("(spill file)"), e)
    }

    /// Writes tile `t` from its raw bytes (native-endian stored values, pixel-major).
    pub fn write_raw(&mut self, t: usize, raw: &[u8]) -> Result<()> {
        let (off, len) = self.byte_range(t);
        assert_eq!(raw.len(), len, "tile {t}: wrong byte count");
        match &mut self.backing {
            Backing::Memory(v) => {
                v[off as usize..off as usize + len].copy_from_slice(raw);
                Ok(())
            }
            Backing::Spill(f) => {
                let r = f.write_all_at(raw, off);
                r.map_err(|e| self.io_error(e))
            }
        }
    }

    /// Reads tile `t`'s raw bytes into `raw` (resized).
    pub fn read_raw(&self, t: usize, raw: &mut Vec<u8>) -> Result<()> {
        let (off, len) = self.byte_range(t);
        raw.resize(len, 0);
        match &self.backing {
            Backing::Memory(v) => {
                raw.copy_from_slice(&v[off as usize..off as usize + len]);
                Ok(())
            }
            Backing::Spill(f) => f.read_exact_at(raw, off).map_err(|e| self.io_error(e)),
        }
    }

    /// Tile `t` as `f32` samples `[pixel][light][channel]`, intensity-normalised, into `out`
    /// (resized); `raw` is scratch space for the stored bytes.
    pub fn read_tile(&self, t: usize, raw: &mut Vec<u8>, out: &mut Vec<f32>) -> Result<()> {
        let stride = self.n_lights * self.channels;
        match &self.backing {
            Backing::Memory(v) => {
                let (off, len) = self.byte_range(t);
                self.convert(&v[off as usize..off as usize + len], stride, out);
            }
            Backing::Spill(_) => {
                self.read_raw(t, raw)?;
                self.convert(raw, stride, out);
            }
        }
        Ok(())
    }

    fn convert(&self, raw: &[u8], stride: usize, out: &mut Vec<f32>) {
        let pixels = raw.len() / self.pixel_bytes().max(1);
        out.resize(pixels * stride, 0.0);
        let c = self.channels;
        const PIXELS_PER_TASK: usize = 4096;
        let pb = self.pixel_bytes();
        out.par_chunks_mut(PIXELS_PER_TASK * stride)
            .zip(raw.par_chunks(PIXELS_PER_TASK * pb))
            .for_each(|(dst, src)| match self.kind {
                SampleType::U16 => {
                    for (d, s) in dst.chunks_exact_mut(stride).zip(src.chunks_exact(pb)) {
                        for k in 0..self.n_lights {
                            let dec = self.decode[k];
                            let sc = &self.scale[k];
                            for (ch, f) in sc.iter().enumerate().take(c) {
                                let i = k * c + ch;
                                let u = u16::from_ne_bytes([s[2 * i], s[2 * i + 1]]);
                                d[i] = dec.apply_u16(u) * f;
                            }
                        }
                        self.apply_gains(d);
                    }
                }
                SampleType::F32 => {
                    for (d, s) in dst.chunks_exact_mut(stride).zip(src.chunks_exact(pb)) {
                        for k in 0..self.n_lights {
                            let sc = &self.scale[k];
                            for (ch, f) in sc.iter().enumerate().take(c) {
                                let i = k * c + ch;
                                let v = f32::from_ne_bytes([
                                    s[4 * i],
                                    s[4 * i + 1],
                                    s[4 * i + 2],
                                    s[4 * i + 3],
                                ]);
                                d[i] = v * f;
                            }
                        }
                        self.apply_gains(d);
                    }
                }
            });
    }

    /// One pixel's samples times the light gains, when set.
    #[inline]
    fn apply_gains(&self, pixel: &mut [f32]) {
        if !self.gain.is_empty() {
            for (light, &g) in pixel.chunks_exact_mut(self.channels).zip(&self.gain) {
                for v in light {
                    *v *= g;
                }
            }
        }
    }

    /// A store with only the lights `keep` (in that order), in memory or spilled like this
    /// one (tile by tile).
    pub fn select_lights(&self, keep: &[usize]) -> Result<SampleStore> {
        let mut out = SampleStore::new(
            self.kind,
            self.channels,
            self.tiling.clone(),
            keep.iter().map(|&k| self.decode[k]).collect(),
            keep.iter().map(|&k| self.scale[k]).collect(),
            self.spill_dir.as_deref(),
        )?;
        if !self.gain.is_empty() {
            out.gain = keep.iter().map(|&k| self.gain[k]).collect();
        }
        let sb = self.channels * self.kind.bytes();
        let (pin, pout) = (self.pixel_bytes(), out.pixel_bytes());
        let mut raw = Vec::new();
        let mut dst = Vec::new();
        for t in 0..self.tiling.len() {
            self.read_raw(t, &mut raw)?;
            let pixels = raw.len() / pin.max(1);
            dst.resize(pixels * pout, 0);
            for (d, s) in dst.chunks_exact_mut(pout).zip(raw.chunks_exact(pin)) {
                for (j, &k) in keep.iter().enumerate() {
                    d[j * sb..(j + 1) * sb].copy_from_slice(&s[k * sb..(k + 1) * sb]);
                }
            }
            out.write_raw(t, &dst)?;
        }
        Ok(out)
    }
}

/// Plain values that a [`Parking`] file holds as their bytes: every bit pattern the program
/// writes reads back as the same value (no padding, no pointers).
///
/// # Safety
/// Implementors have no padding and no invalid bit patterns among the values written.
pub unsafe trait Plain: Copy + Default + Send + Sync + 'static {}
unsafe impl Plain for u8 {}
unsafe impl Plain for u32 {}
unsafe impl Plain for u64 {}
unsafe impl Plain for f32 {}
unsafe impl Plain for [f32; 3] {}
// Only `bool`s the program made are written, and they read back as 0 or 1.
unsafe impl Plain for bool {}

/// A per-pixel array waiting in a [`Parking`] file: where it is, and how many values.
#[derive(Debug)]
#[must_use = "a parked array is read back with Parking::take"]
pub struct Parked<T> {
    offset: u64,
    len: usize,
    _values: std::marker::PhantomData<T>,
}

impl<T> Parked<T> {
    /// Values parked.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether no value is parked.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
}

/// A temporary file where per-pixel arrays wait while a full-frame stage (an integration, the
/// shadow maps) needs the memory they hold (ALGORITHMS.md §10): [`Parking::park`] writes an
/// array and frees it, [`Parking::take`] reads it back bit for bit. Like the sample store's
/// spill file it is unlinked at once, so the system frees it however the run ends; arrays are
/// moved with positioned I/O in bounded chunks, so the resident memory never holds a second
/// copy.
pub struct Parking {
    file: File,
    dir: PathBuf,
    end: u64,
}

/// A new read-write file in `dir`, unlinked at once (`.photostereo-{what}-{pid}-{n}.spill`
/// while it has a name): the handle keeps it and the system frees it however the process ends.
fn nameless_file(dir: &Path, what: &str) -> Result<std::fs::File> {
    static NEXT: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let path = dir.join(format!(
        ".photostereo-{what}-{}-{}.spill",
        std::process::id(),
        NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
    ));
    let file = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create_new(true)
        .open(&path)
        .map_err(|e| Error::io(&path, e))?;
    std::fs::remove_file(&path).map_err(|e| Error::io(&path, e))?;
    Ok(file)
}

/// Bytes moved per positioned read or write.
const PARK_CHUNK: usize = 8 << 20;

impl Parking {
    /// A new, empty parking file in `dir`.
    pub fn new(dir: &Path) -> Result<Parking> {
        Ok(Parking {
            file: nameless_file(dir, "parked")?,
            dir: dir.to_path_buf(),
            end: 0,
        })
    }

    fn io_error(&self, e: std::io::Error) -> Error {
        Error::io(self.dir.join("(parking file)"), e)
    }

    /// Bytes written so far.
    pub fn bytes(&self) -> u64 {
        self.end
    }

    /// Writes `values` to the file and frees them.
    pub fn park<T: Plain>(&mut self, values: Vec<T>) -> Result<Parked<T>> {
        // SAFETY: `T: Plain` has no padding; the slice covers the vector's initialised values.
        let bytes = unsafe {
            std::slice::from_raw_parts(
                values.as_ptr() as *const u8,
                std::mem::size_of_val(values.as_slice()),
            )
        };
        let offset = self.end;
        for (i, chunk) in bytes.chunks(PARK_CHUNK).enumerate() {
            let at = offset + (i * PARK_CHUNK) as u64;
            self.file
                .write_all_at(chunk, at)
                .map_err(|e| self.io_error(e))?;
        }
        self.end += bytes.len() as u64;
        Ok(Parked {
            offset,
            len: values.len(),
            _values: std::marker::PhantomData,
        })
    }

    /// Reads a parked array back (it stays in the file: [`Parking::read`] can read it again).
    pub fn take<T: Plain>(&self, parked: Parked<T>) -> Result<Vec<T>> {
        self.read(&parked)
    }

    /// Parks the array `values` holds, leaving it empty.
    pub fn shelve<T: Plain>(&mut self, values: &mut Vec<T>) -> Result<Parked<T>> {
        self.park(std::mem::take(values))
    }

    /// Puts a parked array back into `values` (empty on entry).
    pub fn unshelve<T: Plain>(&self, values: &mut Vec<T>, parked: Parked<T>) -> Result<()> {
        *values = self.take(parked)?;
        Ok(())
    }

    /// A copy of a parked array, leaving it parked.
    pub fn read<T: Plain>(&self, parked: &Parked<T>) -> Result<Vec<T>> {
        let mut values: Vec<T> = Vec::with_capacity(parked.len);
        let n_bytes = parked.len * std::mem::size_of::<T>();
        {
            // SAFETY: the capacity holds `n_bytes`; every byte is written below before the
            // length is set, with bytes the same `T`s were written as.
            let bytes =
                unsafe { std::slice::from_raw_parts_mut(values.as_mut_ptr() as *mut u8, n_bytes) };
            for (i, chunk) in bytes.chunks_mut(PARK_CHUNK).enumerate() {
                let at = parked.offset + (i * PARK_CHUNK) as u64;
                self.file
                    .read_exact_at(chunk, at)
                    .map_err(|e| self.io_error(e))?;
            }
        }
        // SAFETY: all `parked.len` values were read in full.
        unsafe { values.set_len(parked.len) };
        Ok(values)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiling_bands_hold_at_most_the_tile_size() {
        // 4×5 frame, mask counts per row 4, 0, 2, 4, 1.
        let rows = [
            [1, 1, 1, 1],
            [0, 0, 0, 0],
            [1, 0, 1, 0],
            [1, 1, 1, 1],
            [0, 0, 1, 0],
        ];
        let mask: Vec<bool> = rows.iter().flatten().map(|&v| v == 1).collect();
        let t = Tiling::new(&mask, 4, 5, 5);
        assert_eq!(t.rows, vec![0, 2, 3, 5]);
        assert_eq!(t.starts, vec![0, 4, 6, 11]);
        assert_eq!(t.max_pixels(), 5);
    }

    #[test]
    fn decoded_values_match_the_decoders_bit_for_bit() {
        let r16 = 1.0f32 / 65535.0;
        for u in [0u16, 1, 2, 255, 4097, 32768, 65534, 65535] {
            // PNG: multiplication by the reciprocal; TIFF: division.
            assert_eq!(Decode::MulRecip(r16).apply_u16(u), u as f32 * r16);
            assert_eq!(Decode::Div(65535.0).apply_u16(u), u as f32 / 65535.0);
            assert_eq!(Decode::MulRecip(r16).to_u16(u as f32 * r16), u);
            assert_eq!(Decode::Div(65535.0).to_u16(u as f32 / 65535.0), u);
        }
    }

    #[test]
    fn spilled_and_memory_stores_read_back_the_same_and_the_file_has_no_name() {
        let mask = vec![true; 6 * 3];
        let tiling = Tiling::new(&mask, 6, 3, 7);
        let decode = vec![Decode::MulRecip(1.0 / 255.0); 4];
        let scale = vec![[0.5, 1.0, 2.0]; 4];
        let dir = std::env::temp_dir().join(format!("ps-store-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut a = SampleStore::new(
            SampleType::U16,
            3,
            tiling.clone(),
            decode.clone(),
            scale.clone(),
            None,
        )
        .unwrap();
        let mut b = SampleStore::new(
            SampleType::U16,
            3,
            tiling.clone(),
            decode,
            scale,
            Some(&dir),
        )
        .unwrap();
        assert!(b.spilled());
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 0);
        for t in 0..tiling.len() {
            let n = tiling.pixels(t).len() * 4 * 3;
            let raw: Vec<u8> = (0..n)
                .flat_map(|i| ((i * 7 + t) as u16 % 256).to_ne_bytes())
                .collect();
            a.write_raw(t, &raw).unwrap();
            b.write_raw(t, &raw).unwrap();
        }
        let (mut raw, mut fa, mut fb) = (Vec::new(), Vec::new(), Vec::new());
        for t in 0..tiling.len() {
            a.read_tile(t, &mut raw, &mut fa).unwrap();
            b.read_tile(t, &mut raw, &mut fb).unwrap();
            assert_eq!(fa, fb);
            let first = ((t as u16) % 256) as f32 * (1.0f32 / 255.0) * 0.5;
            assert_eq!(fa[0], first);
        }
        let sel = b.select_lights(&[2, 0, 1]).unwrap();
        let mut fs = Vec::new();
        sel.read_tile(0, &mut raw, &mut fs).unwrap();
        b.read_tile(0, &mut raw, &mut fb).unwrap();
        assert_eq!(&fs[0..3], &fb[6..9]);
        drop((a, b, sel));
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 0);
        std::fs::remove_dir(&dir).unwrap();
    }

    #[test]
    fn parked_arrays_read_back_bit_for_bit_from_a_nameless_file() {
        let dir = tempfile::tempdir().unwrap();
        let mut park = Parking::new(dir.path()).unwrap();
        let a: Vec<f32> = (0..3_000_000).map(|i| (i as f32).sqrt() - 7.5).collect();
        let b: Vec<bool> = (0..1001).map(|i| i % 3 == 0).collect();
        let c: Vec<[f32; 3]> = (0..17).map(|i| [i as f32, -0.0, f32::NAN]).collect();
        let (pa, pb, pc) = (
            park.park(a.clone()).unwrap(),
            park.park(b.clone()).unwrap(),
            park.park(c.clone()).unwrap(),
        );
        assert_eq!(park.bytes(), 12_000_000 + 1001 + 17 * 12);
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
        assert_eq!(park.take(pb).unwrap(), b);
        let back = park.take(pc).unwrap();
        assert!(back
            .iter()
            .zip(&c)
            .all(|(x, y)| x.map(f32::to_bits) == y.map(f32::to_bits)));
        assert_eq!(park.read(&pa).unwrap(), a);
        assert_eq!(park.take(pa).unwrap(), a);
    }
}
