//! Image decoding and encoding: PNG (8/16-bit, grey or RGB), JPEG (baseline and progressive,
//! [`crate::io::jpeg`]), TIFF (8/16-bit, 32-bit float) and OpenEXR in; PNG and OpenEXR out.
//! JPEG and TIFF images are returned upright (their EXIF orientation applied). The values are
//! the files' encoded ones: [`crate::io::photometry`] makes them linear. Integer images are scaled to [0, 1] by their bit depth and
//! 16-bit data is never reduced to 8 bits. Alpha channels are dropped.

use crate::base::error::{Error, Result};
use crate::io::limits::{DeclaredImage, MAX_DEFLATE_RATIO, MAX_EXR_RATIO, MAX_TIFF_RATIO};
use crate::model::image::Image;
use crate::model::image::MAX_IMAGE_SIDE;
use std::io::Cursor;
use std::path::Path;

/// The container formats the library reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    Png,
    Tiff,
    Exr,
    Jpeg,
    /// Camera RAW ([`crate::io::raw`]): DNG and the TIFF-based vendor formats.
    Raw,
}

/// Identifies the format from the file's first bytes (a camera RAW file by its first image
/// directory, [`crate::io::raw::is_raw`]: from a file's first 8 bytes only, a TIFF-based RAW
/// reads as TIFF).
pub fn sniff(bytes: &[u8]) -> Option<Format> {
    if crate::io::raw::is_raw(bytes) {
        Some(Format::Raw)
    } else if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
        Some(Format::Png)
    } else if bytes.starts_with(b"II*\0")
        || bytes.starts_with(b"MM\0*")
        || bytes.starts_with(b"II+\0")
        || bytes.starts_with(b"MM\0+")
    {
        Some(Format::Tiff)
    } else if bytes.starts_with(&[0x76, 0x2f, 0x31, 0x01]) {
        Some(Format::Exr)
    } else if bytes.starts_with(&[0xFF, 0xD8, 0xFF]) {
        Some(Format::Jpeg)
    } else {
        None
    }
}

/// Reads and decodes an image file. Errors name the file. The size the header declares is
/// checked against [`crate::io::limits`] (and the memory available) before decoding.
pub fn read_image(path: &Path) -> Result<Image> {
    if path.is_dir() {
        return Err(Error::file(path, "is a folder, expected an image file"));
    }
    let bytes = crate::io::limits::read_file(path)?;
    decode_image(&bytes).map_err(|m| Error::file(path, m))
}

/// Decodes an in-memory image (PNG, JPEG, TIFF or OpenEXR). The declared size is checked against
/// [`crate::io::limits`], against what `bytes` can hold and against the available memory first.
pub fn decode_image(bytes: &[u8]) -> Result<Image, String> {
    match sniff(bytes) {
        Some(Format::Png) => decode_png(bytes),
        Some(Format::Tiff) => decode_tiff(bytes).map(|img| {
            let o = crate::io::jpeg::container_orientation(bytes);
            crate::io::jpeg::orient(img, o)
        }),
        Some(Format::Exr) => decode_exr(bytes),
        Some(Format::Jpeg) => crate::io::jpeg::decode_jpeg(bytes),
        Some(Format::Raw) => crate::io::raw::decode_raw(bytes),
        None => {
            Err("unsupported image format (expected PNG, JPEG, TIFF, OpenEXR or camera RAW)".into())
        }
    }
}

fn decode_png(bytes: &[u8]) -> Result<Image, String> {
    let mut decoder = png::Decoder::new(Cursor::new(bytes));
    decoder.set_transformations(png::Transformations::EXPAND);
    let mut reader = decoder
        .read_info()
        .map_err(|e| format!("corrupt PNG: {e}"))?;
    {
        // The decoder's palette expansion assumes a well-formed PLTE (and tRNS no longer than
        // it) and panics otherwise: check first.
        let info = reader.info();
        if info.color_type == png::ColorType::Indexed {
            let plte = info.palette.as_deref().unwrap_or(&[]);
            if plte.is_empty() || plte.len() % 3 != 0 || plte.len() > 3 * 256 {
                return Err(format!(
                    "corrupt PNG: the palette holds {} bytes (expected 1 to 256 entries of 3 bytes)",
                    plte.len()
                ));
            }
            let trns = info.trns.as_deref().map_or(0, <[u8]>::len);
            if trns > plte.len() / 3 {
                return Err(format!(
                    "corrupt PNG: {trns} transparency entries for {} palette entries",
                    plte.len() / 3
                ));
            }
        }
    }
    let (color, depth) = reader.output_color_type();
    let (stored_bytes, declared) = {
        let info = reader.info();
        let (w, h) = (info.width as u64, info.height as u64);
        let bits = info.color_type.samples() as u64 * info.bit_depth as u8 as u64;
        let stored = w
            .saturating_mul(bits)
            .div_ceil(8)
            .saturating_add(1)
            .saturating_mul(h);
        let channels = color.samples() as u64;
        (
            stored,
            DeclaredImage {
                width: w,
                height: h,
                channels,
                bytes_per_sample: if depth == png::BitDepth::Sixteen {
                    2
                } else {
                    1
                },
                kept_channels: if channels >= 3 { 3 } else { 1 },
            },
        )
    };
    declared.check(stored_bytes, bytes.len() as u64, MAX_DEFLATE_RATIO)?;
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| "PNG too large".to_string())?;
    let mut buf = vec![0u8; size];
    let info = reader
        .next_frame(&mut buf)
        .map_err(|e| format!("corrupt or truncated PNG: {e}"))?;
    let (width, height) = (info.width as usize, info.height as usize);
    let src_channels = info.color_type.samples();
    let channels = if src_channels >= 3 { 3 } else { 1 };
    let n = width * height;
    let mut data = vec![0f32; n * channels];
    match info.bit_depth {
        png::BitDepth::Sixteen => {
            let scale = 1.0 / 65535.0;
            for (i, px) in data.chunks_exact_mut(channels).enumerate() {
                let base = i * src_channels * 2;
                for (c, v) in px.iter_mut().enumerate() {
                    let b = base + 2 * c;
                    *v = u16::from_be_bytes([buf[b], buf[b + 1]]) as f32 * scale;
                }
            }
        }
        png::BitDepth::Eight => {
            let scale = 1.0 / 255.0;
            for (i, px) in data.chunks_exact_mut(channels).enumerate() {
                let base = i * src_channels;
                for (c, v) in px.iter_mut().enumerate() {
                    *v = buf[base + c] as f32 * scale;
                }
            }
        }
        other => return Err(format!("unsupported PNG bit depth {other:?}")),
    }
    let bit_depth = if info.bit_depth == png::BitDepth::Sixteen {
        16
    } else {
        8
    };
    Ok(Image {
        width,
        height,
        channels,
        bit_depth,
        data,
    })
}

/// What an image file declares, read without decoding its pixels (PNG) or by decoding it
/// (other formats).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ImageInfo {
    pub width: usize,
    pub height: usize,
    /// Channels kept (1 or 3).
    pub channels: usize,
    /// 8, 16 or 32.
    pub bit_depth: u8,
    pub format: Format,
    /// Whether the file can be read row by row ([`PngRows`]): a PNG without interlacing.
    pub streamable: bool,
}

fn open_png(path: &Path) -> Result<png::Reader<std::io::BufReader<std::fs::File>>> {
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let len = file.metadata().map(|m| m.len()).unwrap_or(0);
    let mut decoder = png::Decoder::new(std::io::BufReader::with_capacity(64 << 10, file));
    decoder.set_transformations(png::Transformations::EXPAND);
    let reader = decoder
        .read_info()
        .map_err(|e| Error::file(path, format!("corrupt PNG: {e}")))?;
    let info = reader.info();
    if info.color_type == png::ColorType::Indexed {
        return Err(Error::file(
            path,
            "a palette PNG cannot be read row by row (decode it whole)",
        ));
    }
    let (w, h) = (info.width as u64, info.height as u64);
    let bits = info.color_type.samples() as u64 * info.bit_depth as u8 as u64;
    let stored = w
        .saturating_mul(bits)
        .div_ceil(8)
        .saturating_add(1)
        .saturating_mul(h);
    // Only one row is decoded at a time: the declared size is checked against the fixed limits
    // and the file's size, not against a whole decoded image.
    let declared = DeclaredImage {
        width: w,
        height: h,
        channels: info.color_type.samples() as u64,
        bytes_per_sample: 0,
        kept_channels: 0,
    };
    declared
        .check(stored, len, MAX_DEFLATE_RATIO)
        .map_err(|m| Error::file(path, m))?;
    Ok(reader)
}

/// Reads an image file's size, channels and depth. PNG headers are read alone; other formats
/// are decoded (their readers cannot do less).
pub fn probe(path: &Path) -> Result<ImageInfo> {
    if path.is_dir() {
        return Err(Error::file(path, "is a folder, expected an image file"));
    }
    let mut head = [0u8; 8];
    {
        use std::io::Read;
        let mut f = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
        let mut got = 0;
        while got < 8 {
            match f.read(&mut head[got..]) {
                Ok(0) => break,
                Ok(k) => got += k,
                Err(e) => return Err(Error::io(path, e)),
            }
        }
    }
    let is_png = sniff(&head) == Some(Format::Png);
    if is_png {
        if let Ok(reader) = open_png(path) {
            let info = reader.info();
            let (color, depth) = reader.output_color_type();
            return Ok(ImageInfo {
                width: info.width as usize,
                height: info.height as usize,
                channels: if color.samples() >= 3 { 3 } else { 1 },
                bit_depth: if depth == png::BitDepth::Sixteen {
                    16
                } else {
                    8
                },
                format: Format::Png,
                streamable: !info.interlaced,
            });
        }
    }
    let img = read_image(path)?;
    Ok(ImageInfo {
        width: img.width,
        height: img.height,
        channels: img.channels,
        bit_depth: img.bit_depth,
        format: sniff(&head).unwrap_or(Format::Png),
        streamable: false,
    })
}

/// A PNG read row by row (see [`ImageInfo::streamable`]): only one row is held at a time.
pub struct PngRows {
    reader: png::Reader<std::io::BufReader<std::fs::File>>,
    path: std::path::PathBuf,
    src_channels: usize,
    sixteen: bool,
}

impl PngRows {
    /// Opens a non-interlaced PNG.
    pub fn open(path: &Path) -> Result<PngRows> {
        let reader = open_png(path)?;
        let (color, depth) = reader.output_color_type();
        Ok(PngRows {
            src_channels: color.samples(),
            sixteen: depth == png::BitDepth::Sixteen,
            reader,
            path: path.to_path_buf(),
        })
    }

    /// The next row's samples as integers (`channels` kept per pixel, alpha dropped), into
    /// `out` (`width * channels` values).
    pub fn next_row(&mut self, channels: usize, out: &mut Vec<u16>) -> Result<()> {
        let (sc, sixteen) = (self.src_channels, self.sixteen);
        let row = self
            .reader
            .next_row()
            .map_err(|e| Error::file(&self.path, format!("corrupt or truncated PNG: {e}")))?
            .ok_or_else(|| Error::file(&self.path, "truncated PNG: fewer rows than declared"))?;
        let data = row.data();
        out.clear();
        if sixteen {
            for px in data.chunks_exact(2 * sc) {
                for c in 0..channels {
                    out.push(u16::from_be_bytes([px[2 * c], px[2 * c + 1]]));
                }
            }
        } else {
            for px in data.chunks_exact(sc) {
                out.extend(px[..channels].iter().map(|&v| v as u16));
            }
        }
        Ok(())
    }
}

fn decode_tiff(bytes: &[u8]) -> Result<Image, String> {
    use tiff::decoder::{Decoder, DecodingResult};
    use tiff::ColorType;
    let mut dec = Decoder::new(Cursor::new(bytes)).map_err(|e| format!("corrupt TIFF: {e}"))?;
    let (w, h) = dec.dimensions().map_err(|e| format!("corrupt TIFF: {e}"))?;
    let color = dec.colortype().map_err(|e| format!("corrupt TIFF: {e}"))?;
    let (src_channels, bits) = match color {
        ColorType::Gray(b) => (1, b),
        ColorType::GrayA(b) => (2, b),
        ColorType::RGB(b) => (3, b),
        ColorType::RGBA(b) => (4, b),
        other => {
            return Err(format!(
                "unsupported TIFF colour type {other:?} (expected grey or RGB)"
            ))
        }
    };
    let channels = if src_channels >= 3 { 3 } else { 1 };
    // The decoder's buffer holds at least a byte per sample (8 for 64-bit floats).
    let declared = DeclaredImage {
        width: w as u64,
        height: h as u64,
        channels: src_channels as u64,
        bytes_per_sample: (bits as u64).div_ceil(8).max(1),
        kept_channels: channels as u64,
    };
    declared.check(declared.raw_bytes(), bytes.len() as u64, MAX_TIFF_RATIO)?;
    // The crate's own limits (256 MiB by default) would refuse large valid images; ours above
    // already bound what this file may allocate.
    let budget =
        usize::try_from(declared.raw_bytes().saturating_add(1 << 20)).unwrap_or(usize::MAX);
    let mut limits = tiff::decoder::Limits::default();
    limits.decoding_buffer_size = budget;
    limits.intermediate_buffer_size = budget.max(bytes.len());
    let mut dec = dec.with_limits(limits);
    let (width, height) = (w as usize, h as usize);
    let img = dec
        .read_image()
        .map_err(|e| format!("corrupt or truncated TIFF: {e}"))?;
    let n = width * height;
    let convert = |get: &dyn Fn(usize) -> f32, len: usize| -> Result<Vec<f32>, String> {
        if len < n * src_channels {
            return Err("truncated TIFF data".into());
        }
        let mut data = vec![0f32; n * channels];
        for (i, px) in data.chunks_exact_mut(channels).enumerate() {
            for (c, v) in px.iter_mut().enumerate() {
                *v = get(i * src_channels + c);
            }
        }
        Ok(data)
    };
    let (data, bit_depth) = match &img {
        DecodingResult::U8(v) => (convert(&|i| v[i] as f32 / 255.0, v.len())?, 8),
        DecodingResult::U16(v) => (convert(&|i| v[i] as f32 / 65535.0, v.len())?, 16),
        DecodingResult::F32(v) => (convert(&|i| v[i], v.len())?, 32),
        DecodingResult::F64(v) => (convert(&|i| v[i] as f32, v.len())?, 32),
        _ => {
            return Err("unsupported TIFF sample type (expected 8/16-bit integer or float)".into())
        }
    };
    Ok(Image {
        width,
        height,
        channels,
        bit_depth,
        data,
    })
}

fn decode_exr(bytes: &[u8]) -> Result<Image, String> {
    let meta = exr::meta::MetaData::read_from_buffered(Cursor::new(bytes), false)
        .map_err(|e| format!("corrupt or unsupported OpenEXR: {e}"))?;
    let mut budget = 0u64;
    for header in &meta.headers {
        let data = header.layer_size;
        let stored_per_pixel: u64 = header
            .channels
            .list
            .iter()
            .map(|c| c.sample_type.bytes_per_sample() as u64)
            .sum();
        let declared = DeclaredImage {
            width: data.width() as u64,
            height: data.height() as u64,
            channels: header.channels.list.len() as u64,
            bytes_per_sample: 4,
            kept_channels: 3,
        };
        let stored = (data.width() as u64)
            .saturating_mul(data.height() as u64)
            .saturating_mul(stored_per_pixel);
        declared.check(stored, bytes.len() as u64, MAX_EXR_RATIO)?;
        // A tile is decoded whole: its declared size must fit in the file too.
        if let exr::meta::BlockDescription::Tiles(t) = header.blocks {
            let tile = DeclaredImage {
                width: t.tile_size.width() as u64,
                height: t.tile_size.height() as u64,
                ..declared
            };
            let tile_stored = tile
                .width
                .saturating_mul(tile.height)
                .saturating_mul(stored_per_pixel);
            tile.check(tile_stored, bytes.len() as u64, MAX_EXR_RATIO)
                .map_err(|m| format!("tile size: {m}"))?;
        }
        // The decoded picture covers the display window (RGBA floats, then RGB floats), which
        // the file must fill at half a float (2 bytes) per pixel at least: a forged display
        // window around a tiny data window would otherwise cost gigabytes.
        let display = header.shared_attributes.display_window.size;
        let shown = DeclaredImage {
            width: display.width() as u64,
            height: display.height() as u64,
            channels: 4,
            bytes_per_sample: 4,
            kept_channels: 3,
        };
        let shown_stored = shown.width.saturating_mul(shown.height).saturating_mul(2);
        shown.check(shown_stored, bytes.len() as u64, MAX_EXR_RATIO)?;
        budget = budget
            .max(declared.decode_bytes())
            .max(shown.decode_bytes());
    }
    if let Some(grey) = meta.headers.first().and_then(grey_channel) {
        return decode_exr_grey(bytes, &grey);
    }
    let mut reader =
        image::ImageReader::with_format(Cursor::new(bytes), image::ImageFormat::OpenExr);
    let mut limits = image::Limits::no_limits();
    limits.max_image_width = Some(MAX_IMAGE_SIDE as u32);
    limits.max_image_height = Some(MAX_IMAGE_SIDE as u32);
    limits.max_alloc = Some(budget.saturating_add(1 << 20));
    reader.limits(limits);
    let img = reader
        .decode()
        .map_err(|e| format!("corrupt or unsupported OpenEXR: {e}"))?;
    let rgb = img.to_rgb32f();
    let (width, height) = (rgb.width() as usize, rgb.height() as usize);
    Ok(Image {
        width,
        height,
        channels: 3,
        bit_depth: 32,
        data: rgb.into_raw(),
    })
}

/// The channel of a grey OpenEXR: none of R, G and B, and either a `Y` channel or a single
/// channel of any name (how photostereo writes `depth.exr`).
fn grey_channel(header: &exr::meta::header::Header) -> Option<String> {
    let names: Vec<String> = header
        .channels
        .list
        .iter()
        .map(|c| c.name.to_string())
        .collect();
    if names.iter().any(|n| matches!(n.as_str(), "R" | "G" | "B")) {
        return None;
    }
    names
        .iter()
        .find(|n| n.as_str() == "Y")
        .or(if names.len() == 1 {
            names.first()
        } else {
            None
        })
        .cloned()
}

/// Decodes the channel `name` of a grey OpenEXR (sizes already checked) as a one-channel image
/// over its data window, which must be the display window.
fn decode_exr_grey(bytes: &[u8], name: &str) -> Result<crate::model::image::Image, String> {
    type Picture = crate::model::image::Image;
    use exr::prelude::{read, FlatSamples, ReadChannels, ReadLayers};
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_buffered(Cursor::new(bytes))
        .map_err(|e| format!("corrupt or unsupported OpenEXR: {e}"))?;
    let layer = &image.layer_data;
    if layer.size != image.attributes.display_window.size {
        return Err(format!(
            "grey OpenEXR whose data window ({}×{}) is not its display window ({}×{})",
            layer.size.width(),
            layer.size.height(),
            image.attributes.display_window.size.width(),
            image.attributes.display_window.size.height()
        ));
    }
    let channel = layer
        .channel_data
        .list
        .iter()
        .find(|c| c.name.to_string() == name)
        .ok_or_else(|| format!("OpenEXR channel {name} missing"))?;
    let data: Vec<f32> = match &channel.sample_data {
        FlatSamples::F16(v) => v.iter().map(|x| x.to_f32()).collect(),
        FlatSamples::F32(v) => v.clone(),
        FlatSamples::U32(v) => v.iter().map(|&x| x as f32).collect(),
    };
    Ok(Picture {
        width: layer.size.width(),
        height: layer.size.height(),
        channels: 1,
        bit_depth: 32,
        data,
    })
}

/// The start of the `tEXt` chunk every PNG written here carries (keyword `Software`, NUL, then
/// `photostereo VERSION`): how `--force` recognises a file photostereo wrote.
pub const PNG_SOFTWARE_TEXT: &[u8] = b"Software\0photostereo";

/// Images of more raw bytes than this are encoded band by band straight into the file (memory:
/// two bands); smaller ones are encoded whole in memory and written at once, which is faster
/// for the many small files of a demo.
const PNG_STREAM_ABOVE_BYTES: usize = 32 << 20;
/// Rows per band of a streamed PNG.
const PNG_BAND_ROWS: usize = 64;

/// Samples per row of a `width × height × channels` image given `samples` in all; an error
/// naming the file when they disagree.
fn checked_row_len(
    path: &Path,
    (width, height, channels): (usize, usize, usize),
    samples: usize,
) -> Result<usize> {
    let row = width * channels;
    if samples != row * height {
        return Err(Error::invalid(format!(
            "PNG {}: {samples} samples for {width}×{height}×{channels}",
            path.display()
        )));
    }
    Ok(row)
}

/// Writes a 16-bit PNG with 1 (grey) or 3 (RGB) interleaved channels.
pub fn write_png16(
    path: &Path,
    width: usize,
    height: usize,
    channels: usize,
    data: &[u16],
) -> Result<()> {
    let row = checked_row_len(path, (width, height, channels), data.len())?;
    write_png16_rows(path, width, height, channels, |r, out| {
        out.copy_from_slice(&data[r * row..(r + 1) * row])
    })
}

/// Writes a 16-bit PNG with 1 (grey) or 3 (RGB) interleaved channels whose row `r` the caller
/// computes into `out` (`width * channels` samples), rows in parallel: no copy of the whole
/// image is made for a large one.
pub fn write_png16_rows(
    path: &Path,
    width: usize,
    height: usize,
    channels: usize,
    fill_row: impl Fn(usize, &mut [u16]) + Sync,
) -> Result<()> {
    use rayon::prelude::*;
    let row = width * channels;
    write_png_bands(
        path,
        width,
        height,
        channels,
        png::BitDepth::Sixteen,
        |rows, bytes| {
            // Each row computed into a per-thread scratch row, then stored big-endian.
            bytes
                .par_chunks_mut((2 * row).max(1))
                .zip(rows)
                .for_each_init(
                    || vec![0u16; row],
                    |values, (out, r)| {
                        fill_row(r, values);
                        for (o, v) in out.chunks_exact_mut(2).zip(values.iter()) {
                            o.copy_from_slice(&v.to_be_bytes());
                        }
                    },
                );
        },
    )
}

/// Writes an 8-bit PNG with 1 (grey) or 3 (RGB) interleaved channels.
pub fn write_png8(
    path: &Path,
    width: usize,
    height: usize,
    channels: usize,
    data: &[u8],
) -> Result<()> {
    let row = checked_row_len(path, (width, height, channels), data.len())?;
    write_png_bands(
        path,
        width,
        height,
        channels,
        png::BitDepth::Eight,
        |rows, bytes| bytes.copy_from_slice(&data[rows.start * row..rows.end * row]),
    )
}

/// The PNG encoder's settings shared by every file written here.
fn png_encoder<W: std::io::Write>(
    out: W,
    path: &Path,
    width: usize,
    height: usize,
    channels: usize,
    depth: png::BitDepth,
) -> Result<png::Writer<W>> {
    let color = match channels {
        1 => png::ColorType::Grayscale,
        3 => png::ColorType::Rgb,
        4 => png::ColorType::Rgba,
        _ => {
            return Err(Error::invalid(format!(
                "cannot write a PNG with {channels} channels"
            )))
        }
    };
    let mut enc = png::Encoder::new(out, width as u32, height as u32);
    enc.set_color(color);
    enc.set_depth(depth);
    enc.set_compression(png::Compression::Fast);
    if depth == png::BitDepth::Sixteen {
        // Paeth on every row: files as small as the adaptive choice on 16-bit renders and
        // maps (within 0.4%), a third less encoding time. The pixels are the same.
        enc.set_filter(png::Filter::Paeth);
    }
    enc.add_text_chunk(
        "Software".into(),
        format!("photostereo {}", env!("CARGO_PKG_VERSION")),
    )
    .map_err(|e| Error::file(path, format!("PNG encoding failed: {e}")))?;
    enc.write_header()
        .map_err(|e| Error::file(path, format!("PNG encoding failed: {e}")))
}

/// Writes an 8-bit PNG with `channels` interleaved channels whose rows `fill(rows, bytes)`
/// produces a band at a time, top to bottom (a large image is streamed into the file; what is
/// held is one band of rows). The first error `fill` returns stops the writing and is returned.
pub fn write_png8_bands(
    path: &Path,
    (width, height, channels): (usize, usize, usize),
    mut fill: impl FnMut(std::ops::Range<usize>, &mut [u8]) -> Result<()>,
) -> Result<()> {
    let mut failed = None;
    write_png_bands(
        path,
        width,
        height,
        channels,
        png::BitDepth::Eight,
        |rows, bytes| {
            if failed.is_none() {
                failed = fill(rows, bytes).err();
            }
        },
    )?;
    failed.map_or(Ok(()), Err)
}

/// Writes a PNG whose raw (big-endian, unfiltered) bytes `fill(rows, bytes)` produces for a range
/// of rows at a time: the whole image at once when it is small, else bands of
/// [`PNG_BAND_ROWS`] rows streamed through the encoder into the file.
fn write_png_bands(
    path: &Path,
    width: usize,
    height: usize,
    channels: usize,
    depth: png::BitDepth,
    fill: impl FnMut(std::ops::Range<usize>, &mut [u8]),
) -> Result<()> {
    write_png_bands_above(
        path,
        (width, height, channels),
        depth,
        PNG_STREAM_ABOVE_BYTES,
        fill,
    )
}

/// [`write_png_bands`] streaming above `stream_above` raw bytes (tests stream small images).
fn write_png_bands_above(
    path: &Path,
    (width, height, channels): (usize, usize, usize),
    depth: png::BitDepth,
    stream_above: usize,
    mut fill: impl FnMut(std::ops::Range<usize>, &mut [u8]),
) -> Result<()> {
    let sample_bytes = if depth == png::BitDepth::Sixteen {
        2
    } else {
        1
    };
    let row_bytes = width * channels * sample_bytes;
    let failed = |e: png::EncodingError| Error::file(path, format!("PNG encoding failed: {e}"));
    if row_bytes * height <= stream_above {
        let mut bytes = vec![0u8; row_bytes * height];
        fill(0..height, &mut bytes);
        let mut out = Vec::new();
        {
            let mut writer = png_encoder(&mut out, path, width, height, channels, depth)?;
            writer.write_image_data(&bytes).map_err(failed)?;
        }
        return std::fs::write(path, out).map_err(|e| Error::io(path, e));
    }
    use std::io::Write;
    let file = std::fs::File::create(path).map_err(|e| Error::io(path, e))?;
    let mut buffered = std::io::BufWriter::with_capacity(1 << 20, file);
    {
        let mut writer = png_encoder(&mut buffered, path, width, height, channels, depth)?;
        {
            let mut stream = writer
                .stream_writer_with_size(PNG_BAND_ROWS * row_bytes)
                .map_err(failed)?;
            let mut band = vec![0u8; PNG_BAND_ROWS * row_bytes];
            for r0 in (0..height).step_by(PNG_BAND_ROWS) {
                let r1 = (r0 + PNG_BAND_ROWS).min(height);
                let bytes = &mut band[..(r1 - r0) * row_bytes];
                fill(r0..r1, bytes);
                stream.write_all(bytes).map_err(|e| Error::io(path, e))?;
            }
            stream.finish().map_err(failed)?;
        }
        writer.finish().map_err(failed)?;
    }
    buffered.flush().map_err(|e| Error::io(path, e))
}

/// Writes a float RGB OpenEXR file from interleaved samples (`height * width * 3`).
pub fn write_exr_rgb(path: &Path, width: usize, height: usize, data: &[f32]) -> Result<()> {
    use exr::prelude::*;
    // Uncompressed scan lines: float maps hardly compress (RLE saved nothing on depth and
    // normal maps) and this writes at memory speed.
    let channels = SpecificChannels::rgb(|Vec2(x, y): Vec2<usize>| {
        let i = (y * width + x) * 3;
        (data[i], data[i + 1], data[i + 2])
    });
    exr::prelude::Image::from_encoded_channels((width, height), Encoding::UNCOMPRESSED, channels)
        .write()
        .to_file(path)
        .map_err(|e| crate::base::error::Error::file(path, format!("OpenEXR encoding failed: {e}")))
}

/// Writes a float single-channel OpenEXR file (channel `Y`).
pub fn write_exr_grey(path: &Path, width: usize, height: usize, data: &[f32]) -> Result<()> {
    use exr::prelude::*;
    // Samples read from the caller's map as the file is written: no copy of it.
    let channel = SpecificChannels::build()
        .with_channel::<f32>("Y")
        .with_pixel_fn(|Vec2(x, y): Vec2<usize>| (data[y * width + x],));
    exr::prelude::Image::from_encoded_channels((width, height), Encoding::UNCOMPRESSED, channel)
        .write()
        .to_file(path)
        .map_err(|e| crate::base::error::Error::file(path, format!("OpenEXR encoding failed: {e}")))
}

/// Reads a mask image: a pixel is inside when any colour channel is non-zero. A PNG whose
/// colour channels are black everywhere but whose alpha channel is not (a cut-out saved with
/// the object in alpha only) is read from its alpha: inside where alpha is non-zero.
pub fn read_mask(path: &Path) -> Result<(usize, usize, Vec<bool>)> {
    let img = read_image(path)?;
    let mask: Vec<bool> = img
        .data
        .chunks_exact(img.channels)
        .map(|px| px.iter().any(|v| *v > 0.0))
        .collect();
    if mask.iter().any(|&m| m) {
        return Ok((img.height, img.width, mask));
    }
    let bytes = crate::io::limits::read_file(path)?;
    match png_alpha(&bytes) {
        Some(alpha) if alpha.len() == mask.len() && alpha.iter().any(|&a| a) => {
            Ok((img.height, img.width, alpha))
        }
        _ => Ok((img.height, img.width, mask)),
    }
}

/// The alpha channel of a PNG with one (grey or colour with alpha, or a transparency chunk) as
/// flags, true where alpha is non-zero; `None` for other files. Sizes were checked by
/// [`read_image`] on the same bytes.
fn png_alpha(bytes: &[u8]) -> Option<Vec<bool>> {
    if sniff(bytes) != Some(Format::Png) {
        return None;
    }
    let mut decoder = png::Decoder::new(Cursor::new(bytes));
    decoder.set_transformations(png::Transformations::EXPAND);
    let mut reader = decoder.read_info().ok()?;
    let (color, depth) = reader.output_color_type();
    let channels = match color {
        png::ColorType::GrayscaleAlpha => 2,
        png::ColorType::Rgba => 4,
        _ => return None,
    };
    let bytes_per_sample = if depth == png::BitDepth::Sixteen {
        2
    } else {
        1
    };
    let mut buf = vec![0; reader.output_buffer_size()?];
    let info = reader.next_frame(&mut buf).ok()?;
    let stride = channels * bytes_per_sample;
    let alpha_at = (channels - 1) * bytes_per_sample;
    Some(
        buf[..info.buffer_size()]
            .chunks_exact(stride)
            .map(|px| px[alpha_at..].iter().any(|&b| b != 0))
            .collect(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_mask_with_its_object_in_alpha_only_is_read_from_alpha() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("mask.png");
        // 3 × 2 RGBA, black everywhere, opaque at (0, 1) and (1, 2) only.
        let mut px = vec![0u8; 3 * 2 * 4];
        for i in [1usize, 5] {
            px[i * 4 + 3] = 255;
        }
        let mut enc = png::Encoder::new(std::fs::File::create(&p).unwrap(), 3, 2);
        enc.set_color(png::ColorType::Rgba);
        enc.set_depth(png::BitDepth::Eight);
        enc.write_header().unwrap().write_image_data(&px).unwrap();
        let (h, w, m) = read_mask(&p).unwrap();
        assert_eq!((h, w), (2, 3));
        assert_eq!(m, vec![false, true, false, false, false, true]);
        // Colour wins where it marks the object.
        px[0] = 255;
        let mut enc = png::Encoder::new(std::fs::File::create(&p).unwrap(), 3, 2);
        enc.set_color(png::ColorType::Rgba);
        enc.set_depth(png::BitDepth::Eight);
        enc.write_header().unwrap().write_image_data(&px).unwrap();
        let (_, _, m) = read_mask(&p).unwrap();
        assert_eq!(m, vec![true, false, false, false, false, false]);
    }

    #[test]
    fn a_grey_openexr_is_read_as_one_channel() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("depth.exr");
        let data: Vec<f32> = (0..12).map(|i| i as f32 * 0.25 - 1.0).collect();
        write_exr_grey(&p, 4, 3, &data).unwrap();
        let img = read_image(&p).unwrap();
        assert_eq!((img.width, img.height, img.channels), (4, 3, 1));
        assert_eq!(img.data, data);
    }

    #[test]
    fn png16_round_trip_keeps_full_depth() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.png");
        let data: Vec<u16> = (0..(4 * 3 * 3)).map(|i| (i * 1817 + 3) as u16).collect();
        write_png16(&p, 4, 3, 3, &data).unwrap();
        let img = read_image(&p).unwrap();
        assert_eq!(
            (img.width, img.height, img.channels, img.bit_depth),
            (4, 3, 3, 16)
        );
        for (a, b) in img.data.iter().zip(&data) {
            assert!((a * 65535.0 - *b as f32).abs() < 1e-2);
        }
    }

    #[test]
    fn streamed_pngs_hold_the_same_pixels_as_whole_ones() {
        // 301 × 203 (odd band count, a last short band), 16-bit RGB and 8-bit grey, written
        // whole and streamed band by band (threshold 0): both decode to the written samples
        // and carry the Software text that `--force` looks for.
        let dir = tempfile::tempdir().unwrap();
        let (w, h) = (301, 203);
        let rgb: Vec<u16> = (0..w * h * 3)
            .map(|i| ((i as u64 * 2_654_435_761) >> 7) as u16)
            .collect();
        let grey: Vec<u8> = (0..w * h).map(|i| ((i * 37) % 251) as u8).collect();
        for stream_above in [usize::MAX, 0] {
            let p16 = dir.path().join(format!("rgb{stream_above}.png"));
            write_png_bands_above(
                &p16,
                (w, h, 3),
                png::BitDepth::Sixteen,
                stream_above,
                |rows, bytes| {
                    for (o, v) in bytes
                        .chunks_exact_mut(2)
                        .zip(&rgb[rows.start * w * 3..rows.end * w * 3])
                    {
                        o.copy_from_slice(&v.to_be_bytes());
                    }
                },
            )
            .unwrap();
            let img = read_image(&p16).unwrap();
            assert_eq!((img.width, img.height, img.channels), (w, h, 3));
            for (i, (a, &b)) in img.data.iter().zip(&rgb).enumerate() {
                assert_eq!((a * 65535.0).round() as u16, b, "16-bit sample {i}");
            }
            let p8 = dir.path().join(format!("grey{stream_above}.png"));
            write_png_bands_above(
                &p8,
                (w, h, 1),
                png::BitDepth::Eight,
                stream_above,
                |rows, bytes| bytes.copy_from_slice(&grey[rows.start * w..rows.end * w]),
            )
            .unwrap();
            let img = read_image(&p8).unwrap();
            assert_eq!((img.width, img.height, img.channels), (w, h, 1));
            for (i, (a, &b)) in img.data.iter().zip(&grey).enumerate() {
                assert_eq!((a * 255.0).round() as u8, b, "8-bit sample {i}");
            }
            for p in [&p16, &p8] {
                let bytes = std::fs::read(p).unwrap();
                assert!(bytes
                    .windows(PNG_SOFTWARE_TEXT.len())
                    .any(|win| win == PNG_SOFTWARE_TEXT));
            }
        }
    }

    #[test]
    fn tiff_float_and_16bit_grey_decode() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.tif");
        let vals: Vec<f32> = (0..12).map(|i| i as f32 * 0.25).collect();
        {
            let f = std::fs::File::create(&p).unwrap();
            let mut enc = tiff::encoder::TiffEncoder::new(f).unwrap();
            enc.write_image::<tiff::encoder::colortype::Gray32Float>(4, 3, &vals)
                .unwrap();
        }
        let img = read_image(&p).unwrap();
        assert_eq!(
            (img.width, img.height, img.channels, img.bit_depth),
            (4, 3, 1, 32)
        );
        assert_eq!(img.data, vals);
        let p16 = dir.path().join("b.tif");
        let v16: Vec<u16> = (0..12).map(|i| i * 5000).collect();
        {
            let f = std::fs::File::create(&p16).unwrap();
            let mut enc = tiff::encoder::TiffEncoder::new(f).unwrap();
            enc.write_image::<tiff::encoder::colortype::Gray16>(4, 3, &v16)
                .unwrap();
        }
        let img = read_image(&p16).unwrap();
        assert_eq!(img.bit_depth, 16);
        assert!((img.data[3] - 15000.0 / 65535.0).abs() < 1e-6);
    }

    #[test]
    fn exr_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.exr");
        let data: Vec<f32> = (0..(5 * 2 * 3)).map(|i| i as f32 * 0.1 - 1.0).collect();
        write_exr_rgb(&p, 5, 2, &data).unwrap();
        let img = read_image(&p).unwrap();
        assert_eq!((img.width, img.height, img.channels), (5, 2, 3));
        for (a, b) in img.data.iter().zip(&data) {
            assert!((a - b).abs() < 1e-6);
        }
    }

    #[test]
    fn corrupt_and_unknown_files_are_errors() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.png");
        write_png8(&p, 8, 8, 1, &[7u8; 64]).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        std::fs::write(&p, &bytes[..bytes.len() / 2]).unwrap();
        let e = read_image(&p).unwrap_err().to_string();
        assert!(e.contains("a.png") && e.contains("PNG"), "{e}");
        let q = dir.path().join("b.jpg");
        std::fs::write(&q, b"GIF89a not really").unwrap();
        let e = read_image(&q).unwrap_err().to_string();
        assert!(e.contains("unsupported image format"), "{e}");
        std::fs::write(&q, b"\xff\xd8\xff\xe0 not really").unwrap();
        let e = read_image(&q).unwrap_err().to_string();
        assert!(e.contains("b.jpg") && e.contains("corrupt JPEG"), "{e}");
    }
}
