//! Camera RAW files (DNG, and the vendor formats the `rawler` crate reads): the sensor's
//! readings, linear in the light, with the black level subtracted and scaled so that the
//! white level is 1. No tone curve, no colour matrix and no white balance are applied: each
//! channel is the camera's own (white balance "none", said in the decoder's name), so every
//! channel saturates at the same value, 1.
//!
//! A Bayer mosaic (a 2×2 pattern of red, two greens and blue) is read at half size: each 2×2
//! block becomes one pixel with its red, the mean of its two greens and its blue, with no
//! interpolation between blocks (what a photometric fit wants: every value a measurement).
//! Already-demosaiced (linear RGB) and monochrome RAW files are read at full size. Other
//! mosaics (X-Trans, four-colour) are refused.
//!
//! Before the decoder allocates anything, every image directory of a TIFF-based file is
//! checked against [`crate::io::limits`] (every entry's values inside the file, the image and
//! its strips or tiles within the size limits, the main chain of directories without a loop,
//! at most 64 directories); RAW containers that are not TIFF-based (Fujifilm
//! RAF, Canon CR3) are refused with the advice to convert them to DNG.

use crate::io::limits::{DeclaredImage, MAX_TIFF_RATIO};
use crate::model::image::Image;
use rayon::prelude::*;

/// Whether `bytes` (a file's first bytes, at least its first image directory) hold a camera
/// RAW file: a DNG (its `DNGVersion` tag), a TIFF-based vendor RAW (Canon CR2's mark,
/// Olympus ORF and Panasonic RW2 magic numbers, or a first directory that is a
/// reduced-resolution preview or points to sub-images, as NEF, ARW and PEF files have), or a
/// Fujifilm RAF or Canon CR3 container.
pub fn is_raw(bytes: &[u8]) -> bool {
    if bytes.starts_with(b"FUJIFILMCCD-RAW") || is_cr3(bytes) {
        return true;
    }
    let Some(t) = Tiff::new(bytes) else {
        return false;
    };
    if t.vendor_magic || bytes.get(8..10) == Some(b"CR") {
        return true;
    }
    let Some(ifd0) = t.first_ifd() else {
        return false;
    };
    let tags = t.entries(ifd0);
    tags.iter().any(|e| {
        e.tag == TAG_DNG_VERSION || e.tag == TAG_SUB_IFDS || (e.tag == 254 && e.value == 1)
    })
}

fn is_cr3(bytes: &[u8]) -> bool {
    bytes.get(4..12) == Some(b"ftypcrx ")
}

const TAG_DNG_VERSION: u16 = 50706;
const TAG_SUB_IFDS: u16 = 330;
const TAG_EXIF_IFD: u16 = 34665;
/// The most directory entries the decoder reads from one directory (rawler's own limit).
const MAX_ENTRIES: u16 = 4096;
/// The most image directories a RAW file may hold (real files hold a handful: the image, its
/// previews, EXIF and GPS); every one is checked before the decoder reads it.
const MAX_IFDS: usize = 64;

/// A TIFF's byte order and first directory, read without allocating anything per its
/// declarations (only bounded walks over the file's own bytes).
struct Tiff<'a> {
    bytes: &'a [u8],
    le: bool,
    /// An ORF or RW2 magic number in place of TIFF's 42.
    vendor_magic: bool,
}

/// One directory entry: its tag, type, count and first value (or the offset of its values).
#[derive(Clone, Copy, Debug)]
struct Entry {
    tag: u16,
    kind: u16,
    count: u32,
    value: u32,
    /// Where the entry's value field lies in the file.
    at: usize,
}

impl<'a> Tiff<'a> {
    fn new(bytes: &'a [u8]) -> Option<Self> {
        let le = match bytes.get(0..2)? {
            b"II" => true,
            b"MM" => false,
            _ => return None,
        };
        let t = Tiff {
            bytes,
            le,
            vendor_magic: false,
        };
        let magic = t.u16_at(2)?;
        match magic {
            42 => Some(t),
            // Olympus ORF ("IIRO", "IIRS", "MMOR") and Panasonic RW2 (0x55).
            0x4F52 | 0x5352 | 0x55 => Some(Tiff {
                vendor_magic: true,
                ..t
            }),
            _ => None,
        }
    }

    fn u16_at(&self, at: usize) -> Option<u16> {
        let b: [u8; 2] = self.bytes.get(at..at + 2)?.try_into().ok()?;
        Some(if self.le {
            u16::from_le_bytes(b)
        } else {
            u16::from_be_bytes(b)
        })
    }

    fn u32_at(&self, at: usize) -> Option<u32> {
        let b: [u8; 4] = self.bytes.get(at..at + 4)?.try_into().ok()?;
        Some(if self.le {
            u32::from_le_bytes(b)
        } else {
            u32::from_be_bytes(b)
        })
    }

    fn first_ifd(&self) -> Option<usize> {
        Some(self.u32_at(4)? as usize)
    }

    /// The entries of the directory at `at` (at most [`MAX_ENTRIES`], as many as the decoder
    /// reads; none past the file's end).
    fn entries(&self, at: usize) -> Vec<Entry> {
        let n = self.u16_at(at).unwrap_or(0).min(MAX_ENTRIES) as usize;
        (0..n)
            .map_while(|i| {
                let e = at + 2 + 12 * i;
                let tag = self.u16_at(e)?;
                let kind = self.u16_at(e + 2)?;
                let count = self.u32_at(e + 4)?;
                let value = if kind == 3 && count <= 2 {
                    self.u16_at(e + 8)? as u32
                } else {
                    self.u32_at(e + 8)?
                };
                Some(Entry {
                    tag,
                    kind,
                    count,
                    value,
                    at: e + 8,
                })
            })
            .collect()
    }

    /// The offset of the directory after the one at `at` (0: none), where the decoder reads
    /// it: after the entries it reads.
    fn next_ifd(&self, at: usize) -> usize {
        let n = self.u16_at(at).unwrap_or(0).min(MAX_ENTRIES) as usize;
        self.u32_at(at + 2 + 12 * n).unwrap_or(0) as usize
    }

    /// The values of a LONG (or IFD) entry holding offsets: its sub-directories.
    fn offsets(&self, e: &Entry) -> Vec<usize> {
        let n = (e.count as usize).min(64);
        if n <= 1 {
            return vec![e.value as usize];
        }
        (0..n)
            .filter_map(|i| self.u32_at(e.value as usize + 4 * i).map(|v| v as usize))
            .collect()
    }

    /// The unsigned integer values (SHORT, LONG or IFD) of an entry, read where they lie: in
    /// the entry when they fit its four bytes, at its offset otherwise; `None` for other types
    /// or values past the file's end.
    fn integers(&self, e: &Entry) -> Option<Vec<u64>> {
        let size = match e.kind {
            3 => 2,
            4 | 13 => 4,
            _ => return None,
        };
        let n = e.count as usize;
        let start = if n * size <= 4 {
            e.at
        } else {
            e.value as usize
        };
        if start.checked_add(n.checked_mul(size)?)? > self.bytes.len() {
            return None;
        }
        (0..n)
            .map(|i| {
                let at = start + i * size;
                if size == 2 {
                    self.u16_at(at).map(u64::from)
                } else {
                    self.u32_at(at).map(u64::from)
                }
            })
            .collect()
    }

    /// Every image directory: the main chain, their sub-directories, EXIF directories and
    /// whatever an ICC profile tag points to (the decoder reads it as a directory), each once;
    /// at most [`MAX_IFDS`] + 1 (more is refused).
    fn all_ifds(&self) -> Vec<usize> {
        let mut seen = Vec::new();
        let mut todo = vec![self.first_ifd().unwrap_or(0)];
        while let Some(at) = todo.pop() {
            if at == 0 || at >= self.bytes.len() || seen.contains(&at) || seen.len() > MAX_IFDS {
                continue;
            }
            seen.push(at);
            todo.push(self.next_ifd(at));
            for e in self.entries(at) {
                // Sub-images, EXIF, GPS, interoperability and ICC profile directories.
                if matches!(e.tag, TAG_SUB_IFDS | TAG_EXIF_IFD | 34853 | 40965 | 34675) {
                    todo.extend(self.offsets(&e));
                }
            }
        }
        seen
    }

    /// Checks the main chain of directories, which the decoder follows from each directory's
    /// next-directory offset without remembering where it has been: a chain that comes back
    /// to a directory it passed would be read (and allocated) without end.
    fn check_chain(&self) -> Result<(), String> {
        let mut seen = Vec::new();
        let mut at = self.first_ifd().unwrap_or(0);
        while at != 0 && at < self.bytes.len() {
            if seen.contains(&at) {
                return Err(format!(
                    "corrupt RAW file: its chain of image directories loops back to the \
                     directory at byte {at}"
                ));
            }
            if seen.len() >= MAX_IFDS {
                return Err(format!(
                    "corrupt RAW file: more than {MAX_IFDS} image directories in its main chain"
                ));
            }
            seen.push(at);
            at = self.next_ifd(at);
        }
        Ok(())
    }
}

/// Checks every image directory's declared size (width, height, samples, bits) against the
/// limits and the file's size, before the decoder sees the file.
fn check_declared(bytes: &[u8]) -> Result<(), String> {
    if bytes.starts_with(b"FUJIFILMCCD-RAW") || is_cr3(bytes) {
        return Err(
            "unsupported RAW container (Fujifilm RAF or Canon CR3): convert it to DNG first \
             (Adobe DNG Converter, dnglab)"
                .into(),
        );
    }
    let t = Tiff::new(bytes).ok_or("corrupt RAW file: no TIFF header")?;
    t.check_chain()?;
    let ifds = t.all_ifds();
    if ifds.len() > MAX_IFDS {
        return Err(format!(
            "corrupt RAW file: more than {MAX_IFDS} image directories"
        ));
    }
    for at in ifds {
        let entries = t.entries(at);
        // Every entry's values lie in the file: the decoder allocates what a count declares.
        for e in &entries {
            // Unknown types count as 1 byte a value (the decoder reads them as bytes).
            let size = [1u64, 1, 1, 2, 4, 8, 1, 1, 2, 4, 8, 4, 8, 4]
                .get(e.kind as usize)
                .copied()
                .unwrap_or(8);
            let total = (e.count as u64).saturating_mul(size);
            let end = if total <= 4 {
                0
            } else {
                total.saturating_add(e.value as u64)
            };
            if total > bytes.len() as u64 || end > bytes.len() as u64 {
                return Err(format!(
                    "corrupt RAW file: tag {} declares {} values, beyond what the file holds",
                    e.tag, e.count
                ));
            }
        }
        check_segments(&t, &entries)?;
        let get = |tag: u16| entries.iter().find(|e| e.tag == tag);
        // Each value read as the decoder reads it: the first of the entry's values, wherever
        // they lie.
        let first = |tag: u16| get(tag).map(|e| t.integers(e).and_then(|v| v.first().copied()));
        let (Some(w), Some(h)) = (first(256), first(257)) else {
            continue;
        };
        let (Some(w), Some(h)) = (w, h) else {
            return Err("corrupt RAW file: an image's width or height is unreadable".into());
        };
        let spp = first(277).flatten().unwrap_or(1).max(1);
        let bits = first(258).flatten().unwrap_or(16);
        let declared = DeclaredImage {
            width: w,
            height: h,
            channels: spp,
            bytes_per_sample: 2,
            kept_channels: 3,
        };
        let stored = declared
            .width
            .saturating_mul(declared.height)
            .saturating_mul(spp)
            .saturating_mul(bits.clamp(1, 32))
            .div_ceil(8);
        declared.check(stored, bytes.len() as u64, MAX_TIFF_RATIO)?;
    }
    Ok(())
}

/// Checks a directory's strips or tiles: every one of `StripOffsets`/`StripByteCounts` (tags
/// 273/279) and `TileOffsets`/`TileByteCounts` (324/325) lies inside the file (the decoder
/// allocates what a byte count declares), and a tile (`TileWidth` × `TileLength`, 322/323) or
/// strip (`RowsPerStrip`, 278, rows of the image's width) declares no more decoded samples
/// than the limits and the file allow.
fn check_segments(t: &Tiff, entries: &[Entry]) -> Result<(), String> {
    let len = t.bytes.len() as u64;
    let get = |tag: u16| entries.iter().find(|e| e.tag == tag);
    let values = |tag: u16, name: &str| -> Result<Vec<u64>, String> {
        match get(tag) {
            None => Ok(Vec::new()),
            Some(e) => t.integers(e).ok_or_else(|| {
                format!("corrupt RAW file: its {name} (tag {tag}) lie beyond the file's end")
            }),
        }
    };
    for (offsets, counts, what) in [(273, 279, "strip"), (324, 325, "tile")] {
        let off = values(offsets, &format!("{what} offsets"))?;
        let cnt = values(counts, &format!("{what} byte counts"))?;
        for (i, (&o, &c)) in off.iter().zip(&cnt).enumerate() {
            if o.saturating_add(c) > len {
                return Err(format!(
                    "corrupt RAW file: {what} {i} declares {c} bytes at offset {o}, beyond the \
                     file's {len} bytes"
                ));
            }
        }
    }
    let first = |tag: u16| get(tag).and_then(|e| t.integers(e)?.first().copied());
    let width = first(256).unwrap_or(0);
    let height = first(257).unwrap_or(0);
    let (tw, th) = match (first(322), first(323)) {
        (Some(w), Some(h)) => (w, h),
        _ => (width, first(278).unwrap_or(height).min(height)),
    };
    let spp = first(277).unwrap_or(1).max(1);
    let stored = tw.saturating_mul(th).saturating_mul(spp).saturating_mul(4);
    if tw > crate::model::image::MAX_IMAGE_SIDE
        || th > crate::model::image::MAX_IMAGE_SIDE
        || stored > len.saturating_mul(MAX_TIFF_RATIO).saturating_add(1 << 16)
    {
        return Err(format!(
            "corrupt RAW file: a {tw}×{th} tile or strip of {spp} sample(s) per pixel, more \
             than a file of {len} bytes can hold"
        ));
    }
    Ok(())
}

/// What the RAW decoder read, for report.json: the container, the sensor's bits and layout.
pub fn describe(bytes: &[u8]) -> String {
    let kind = if bytes.get(8..10) == Some(b"CR") {
        "cr2"
    } else if Tiff::new(bytes).is_some_and(|t| {
        t.first_ifd()
            .is_some_and(|i| t.entries(i).iter().any(|e| e.tag == TAG_DNG_VERSION))
    }) {
        "dng"
    } else {
        "vendor"
    };
    format!("raw {kind} (rawler), black level subtracted, white balance none (camera channels)")
}

/// Decodes a camera RAW file held in memory to linear readings in [0, 1] (see the module's
/// documentation), upright (its orientation applied).
pub fn decode_raw(bytes: &[u8]) -> Result<Image, String> {
    check_declared(bytes)?;
    // The decoder is a third party's: a panic on a malformed file is that file's error.
    let decoded = std::panic::catch_unwind(|| {
        let source = rawler::rawsource::RawSource::new_from_slice(bytes);
        rawler::decode(&source, &rawler::decoders::RawDecodeParams::default())
    })
    .map_err(|_| "corrupt or unsupported camera RAW file (the RAW decoder failed)".to_string())?
    .map_err(|e| format!("unsupported or corrupt camera RAW file: {e}"))?;
    let image = linear_image(&decoded)?;
    Ok(crate::io::jpeg::orient(image, decoded.orientation.to_u16()))
}

/// The sensor's readings as an [`Image`]: black subtracted, white at 1, mosaics at half size.
fn linear_image(raw: &rawler::RawImage) -> Result<Image, String> {
    use rawler::RawImageData;
    let (full_w, full_h, cpp) = (raw.width, raw.height, raw.cpp);
    if !matches!(cpp, 1 | 3) || full_w == 0 || full_h == 0 {
        return Err(format!(
            "unsupported camera RAW layout: {cpp} samples per pixel (expected 1 or 3)"
        ));
    }
    let len = match &raw.data {
        RawImageData::Integer(v) => v.len(),
        RawImageData::Float(v) => v.len(),
    };
    if len < full_w * full_h * cpp {
        return Err("corrupt camera RAW file: fewer samples than declared".into());
    }
    let area = raw.active_area.map_or((0, 0, full_w, full_h), |r| {
        (
            r.p.x,
            r.p.y,
            r.d.w.min(full_w - r.p.x.min(full_w)),
            r.d.h.min(full_h - r.p.y.min(full_h)),
        )
    });
    let (x0, y0, w, h) = area;
    let sample = |x: usize, y: usize, c: usize| -> f64 {
        let i = ((y0 + y) * full_w + x0 + x) * cpp + c;
        match &raw.data {
            RawImageData::Integer(v) => v[i] as f64,
            RawImageData::Float(v) => v[i] as f64,
        }
    };
    let bl = &raw.blacklevel;
    let black = |x: usize, y: usize, c: usize| -> f64 {
        let (bw, bh, bc) = (bl.width.max(1), bl.height.max(1), bl.cpp.max(1));
        let i = (((y0 + y) % bh) * bw + (x0 + x) % bw) * bc + c.min(bc - 1);
        bl.levels.get(i).map_or(0.0, |r| r.as_f32() as f64)
    };
    let white = |c: usize| -> f64 {
        let wl = &raw.whitelevel.0;
        wl.get(c).or(wl.first()).map_or(65535.0, |&v| v as f64)
    };
    let level = |x: usize, y: usize, c: usize, colour: usize| -> f32 {
        let b = black(x, y, c);
        let range = (white(colour) - b).max(1.0);
        ((sample(x, y, c) - b) / range).clamp(0.0, 1.0) as f32
    };
    match &raw.photometric {
        rawler::rawimage::RawPhotometricInterpretation::Cfa(cfg) => {
            let cfa = &cfg.cfa;
            if cpp != 1 || cfa.width != 2 || cfa.height != 2 {
                return Err(format!(
                    "unsupported colour filter mosaic {} ({}×{}): only 2×2 Bayer patterns \
                     (RGGB and its shifts) are read",
                    cfa.name, cfa.width, cfa.height
                ));
            }
            // The pattern as seen from the active area's corner.
            let colour = |dx: usize, dy: usize| cfa.color_at(y0 + dy, x0 + dx);
            let mut counts = [0; 3];
            for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                match colour(dx, dy) {
                    c @ 0..=2 => counts[c] += 1,
                    _ => counts = [9, 9, 9],
                }
            }
            if counts != [1, 2, 1] {
                return Err(format!(
                    "unsupported colour filter mosaic {}: only red, green, green, blue 2×2 \
                     Bayer patterns are read",
                    cfa.name
                ));
            }
            let (hw, hh) = (w / 2, h / 2);
            if hw == 0 || hh == 0 {
                return Err("camera RAW image smaller than one 2×2 mosaic block".into());
            }
            let mut data = vec![0.0f32; hw * hh * 3];
            data.par_chunks_exact_mut(hw * 3)
                .enumerate()
                .for_each(|(j, row)| {
                    for (i, px) in row.chunks_exact_mut(3).enumerate() {
                        let mut green = 0.0;
                        for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                            let (x, y) = (2 * i + dx, 2 * j + dy);
                            let c = colour(dx, dy);
                            let v = level(x, y, 0, c);
                            match c {
                                1 => green += 0.5 * v,
                                _ => px[c] = v,
                            }
                        }
                        px[1] = green;
                    }
                });
            Ok(Image {
                width: hw,
                height: hh,
                channels: 3,
                bit_depth: 16,
                data,
            })
        }
        _ => {
            let mut data = vec![0.0f32; w * h * cpp];
            data.par_chunks_exact_mut(w * cpp)
                .enumerate()
                .for_each(|(y, row)| {
                    for (x, px) in row.chunks_exact_mut(cpp).enumerate() {
                        for (c, v) in px.iter_mut().enumerate() {
                            *v = level(x, y, c, c);
                        }
                    }
                });
            Ok(Image {
                width: w,
                height: h,
                channels: cpp,
                bit_depth: 16,
                data,
            })
        }
    }
}
