//! JPEG decoding (baseline and progressive, grey or YCbCr colour) and the EXIF orientation
//! that cameras write instead of rotating the pixels.

use crate::io::limits::DeclaredImage;
use crate::model::image::{Image, MAX_IMAGE_SIDE};
use zune_core::bytestream::ZCursor;
use zune_core::colorspace::ColorSpace;
use zune_core::options::DecoderOptions;
use zune_jpeg::JpegDecoder;

/// A baseline JPEG codes each 8×8 block of each component in at least two bits (its DC
/// difference and an end of block), and a block of a 2×2-subsampled chroma component covers
/// 16×16 pixels: at most 256 decoded samples a bit, 2048 a byte. Progressive scans code runs
/// of empty blocks in a few bits, so for them only the fixed limits and the memory bound apply.
pub const MAX_BASELINE_JPEG_RATIO: u64 = 2048;

/// Decodes a JPEG held in memory, upright: the EXIF orientation, when the file has one, is
/// applied (see [`orient`]). Integer samples are scaled to [0, 1]; the values are the file's
/// encoded ones (sRGB for a camera's JPEG), not linear.
pub fn decode_jpeg(bytes: &[u8]) -> Result<Image, String> {
    let (image, orientation) = decode_jpeg_stored(bytes)?;
    Ok(orient(image, orientation))
}

/// Decodes a JPEG as stored (no orientation applied), with its EXIF orientation (1 to 8; 1
/// without a tag).
pub fn decode_jpeg_stored(bytes: &[u8]) -> Result<(Image, u16), String> {
    let side = MAX_IMAGE_SIDE.min(u16::MAX as u64) as usize;
    // Strict: a truncated or damaged scan is an error, not an image padded with grey.
    let options = DecoderOptions::default()
        .set_max_width(side)
        .set_max_height(side)
        .set_strict_mode(true);
    let mut dec = JpegDecoder::new_with_options(ZCursor::new(bytes), options);
    dec.decode_headers()
        .map_err(|e| format!("corrupt JPEG: {e:?}"))?;
    let info = dec
        .info()
        .ok_or_else(|| "corrupt JPEG: no frame header".to_string())?;
    let (width, height) = (info.width as usize, info.height as usize);
    let input = dec
        .input_colorspace()
        .ok_or_else(|| "corrupt JPEG: no colour space".to_string())?;
    let (out_space, channels) = match input {
        ColorSpace::Luma => (ColorSpace::Luma, 1),
        ColorSpace::YCbCr | ColorSpace::RGB => (ColorSpace::RGB, 3),
        other => {
            return Err(format!(
                "unsupported JPEG colour space {other:?} (expected grey or YCbCr colour)"
            ))
        }
    };
    let declared = DeclaredImage {
        width: width as u64,
        height: height as u64,
        channels: channels as u64,
        bytes_per_sample: 1,
        kept_channels: channels as u64,
    };
    let ratio = if info.sof.is_progressive() {
        u64::MAX
    } else {
        MAX_BASELINE_JPEG_RATIO
    };
    declared.check(declared.raw_bytes(), bytes.len() as u64, ratio)?;
    check_complete(bytes)?;
    let orientation = dec
        .exif()
        .and_then(|raw| exif_orientation(raw))
        .unwrap_or(1);
    dec.set_options(options.jpeg_set_out_colorspace(out_space));
    let pixels = dec
        .decode()
        .map_err(|e| format!("corrupt or truncated JPEG: {e:?}"))?;
    if pixels.len() < width * height * channels {
        return Err("truncated JPEG: fewer samples than declared".into());
    }
    let data = pixels[..width * height * channels]
        .iter()
        .map(|&v| v as f32 / 255.0)
        .collect();
    Ok((
        Image {
            width,
            height,
            channels,
            bit_depth: 8,
            data,
        },
        orientation,
    ))
}

/// Refuses a file whose last scan has no end-of-image marker after it: a truncated file (the
/// decoder would fill the missing blocks with grey). Coded data cannot hold the marker's
/// bytes (an `FF` there is followed by `00`), so an `FF D9` after the last start-of-scan ends
/// it; an embedded thumbnail's markers lie before the main image's scans.
fn check_complete(bytes: &[u8]) -> Result<(), String> {
    let last_scan = bytes
        .windows(2)
        .rposition(|w| w == [0xFF, 0xDA])
        .ok_or_else(|| "truncated JPEG: no scan".to_string())?;
    if bytes[last_scan..].windows(2).any(|w| w == [0xFF, 0xD9]) {
        Ok(())
    } else {
        Err(format!(
            "truncated JPEG: the data ends after {} bytes without an end-of-image marker",
            bytes.len()
        ))
    }
}

/// The EXIF orientation (1 to 8; 1 without EXIF) of an image file held in memory (TIFF's own
/// directories, JPEG's APP1, PNG's eXIf).
pub fn container_orientation(bytes: &[u8]) -> u16 {
    exif::Reader::new()
        .read_from_container(&mut std::io::Cursor::new(bytes))
        .ok()
        .and_then(|e| {
            e.get_field(exif::Tag::Orientation, exif::In::PRIMARY)?
                .value
                .get_uint(0)
        })
        .filter(|o| (1..=8).contains(o))
        .map_or(1, |o| o as u16)
}

/// The orientation tag (1 to 8) of raw EXIF data (a TIFF structure), if it has a valid one.
pub fn exif_orientation(raw: &[u8]) -> Option<u16> {
    let exif = exif::Reader::new().read_raw(raw.to_vec()).ok()?;
    let o = exif
        .get_field(exif::Tag::Orientation, exif::In::PRIMARY)?
        .value
        .get_uint(0)?;
    (1..=8).contains(&o).then_some(o as u16)
}

/// The image as it is meant to be seen, given its EXIF orientation (TIFF 6.0 tag 274: where
/// the stored 0th row and 0th column lie on the visual image): 1 as stored, 2 mirrored left to
/// right, 3 turned half a turn, 4 mirrored top to bottom, 5 transposed, 6 turned a quarter
/// turn clockwise, 7 transposed across the other diagonal, 8 turned a quarter turn
/// counter-clockwise. Other values leave the image as stored.
pub fn orient(img: Image, orientation: u16) -> Image {
    if !(2..=8).contains(&orientation) {
        return img;
    }
    let (w, h, c) = (img.width, img.height, img.channels);
    let swap = orientation >= 5;
    let (ow, oh) = if swap { (h, w) } else { (w, h) };
    // Stored (x, y) of the visual pixel (u, v).
    let source = |u: usize, v: usize| -> (usize, usize) {
        match orientation {
            2 => (w - 1 - u, v),
            3 => (w - 1 - u, h - 1 - v),
            4 => (u, h - 1 - v),
            5 => (v, u),
            6 => (v, h - 1 - u),
            7 => (w - 1 - v, h - 1 - u),
            _ => (w - 1 - v, u),
        }
    };
    let mut data = Vec::with_capacity(img.data.len());
    for v in 0..oh {
        for u in 0..ow {
            let (x, y) = source(u, v);
            let i = (y * w + x) * c;
            data.extend_from_slice(&img.data[i..i + c]);
        }
    }
    Image {
        width: ow,
        height: oh,
        channels: c,
        bit_depth: img.bit_depth,
        data,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(w: usize, h: usize) -> Image {
        Image {
            width: w,
            height: h,
            channels: 1,
            bit_depth: 8,
            data: (0..w * h).map(|i| i as f32).collect(),
        }
    }

    /// The stored (row, column) shown at the visual corners (top-left, top-right,
    /// bottom-left) for a 3 × 2 stored image.
    fn corners(o: u16) -> [f32; 3] {
        let img = orient(image(3, 2), o);
        let (w, h) = (img.width, img.height);
        [img.data[0], img.data[w - 1], img.data[(h - 1) * w]]
    }

    #[test]
    fn orientations_follow_the_tiff_definition() {
        // Stored 3 × 2: row 0 = [0 1 2], row 1 = [3 4 5].
        // 1: row 0 at the top, column 0 at the left.
        assert_eq!(corners(1), [0.0, 2.0, 3.0]);
        // 2: row 0 at the top, column 0 at the right.
        assert_eq!(corners(2), [2.0, 0.0, 5.0]);
        // 3: row 0 at the bottom, column 0 at the right.
        assert_eq!(corners(3), [5.0, 3.0, 2.0]);
        // 4: row 0 at the bottom, column 0 at the left.
        assert_eq!(corners(4), [3.0, 5.0, 0.0]);
        // 5: row 0 on the left, column 0 at the top.
        assert_eq!(corners(5), [0.0, 3.0, 2.0]);
        // 6: row 0 on the right, column 0 at the top.
        assert_eq!(corners(6), [3.0, 0.0, 5.0]);
        // 7: row 0 on the right, column 0 at the bottom.
        assert_eq!(corners(7), [5.0, 2.0, 3.0]);
        // 8: row 0 on the left, column 0 at the bottom.
        assert_eq!(corners(8), [2.0, 5.0, 0.0]);
        for o in 5..=8 {
            let img = orient(image(3, 2), o);
            assert_eq!((img.width, img.height), (2, 3));
        }
    }
}
