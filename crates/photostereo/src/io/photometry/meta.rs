//! What an image file says about its photometry, read from its headers without decoding the
//! pixels: its decoder, bit depth, the response its colour metadata declares, the exposure
//! settings and orientation its EXIF records.

use super::{Exposure, Response};
use crate::io::imageio::{sniff, Format};
use std::io::Cursor;

/// An image file's photometric metadata.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageMeta {
    pub format: Format,
    /// Bits per sample: 8, 16 or 32 (float).
    pub bit_depth: u8,
    /// The decoder and its variant, for report.json (`png 16-bit`, `jpeg progressive 8-bit`).
    pub decoder: String,
    /// The response the file declares (or its format implies) and what says so; `None` for
    /// integer data without colour metadata.
    pub declared: Option<(Response, String)>,
    pub exposure: Exposure,
    /// EXIF orientation, 1 to 8 (1 without a tag).
    pub orientation: u16,
}

impl ImageMeta {
    /// The response to use when nothing overrides the file: its declared one, else linear
    /// (16-bit integer data without metadata comes from linear pipelines: scientific cameras,
    /// RAW conversions such as DiLiGenT's; 8-bit data without metadata is checked against the
    /// capture by the caller).
    pub fn default_response(&self) -> (Response, String) {
        self.declared.clone().unwrap_or_else(|| {
            (
                Response::Linear,
                format!("{}-bit data without colour metadata", self.bit_depth),
            )
        })
    }
}

/// Reads the metadata of an image file held in memory. Errors are the format's own header
/// errors (the caller names the file).
pub fn read_meta(bytes: &[u8]) -> Result<ImageMeta, String> {
    match sniff(bytes) {
        Some(Format::Png) => png_meta(bytes),
        Some(Format::Jpeg) => jpeg_meta(bytes),
        Some(Format::Tiff) => tiff_meta(bytes),
        Some(Format::Exr) => Ok(ImageMeta {
            format: Format::Exr,
            bit_depth: 32,
            decoder: "openexr float".into(),
            declared: Some((Response::Linear, "OpenEXR holds linear light".into())),
            exposure: Exposure::default(),
            orientation: 1,
        }),
        Some(Format::Raw) => {
            let (exposure, orientation, _) = exif_facts(bytes);
            Ok(ImageMeta {
                format: Format::Raw,
                bit_depth: 16,
                decoder: crate::io::raw::describe(bytes),
                declared: Some((Response::Linear, "camera RAW (sensor readings)".into())),
                exposure,
                orientation,
            })
        }
        None => {
            Err("unsupported image format (expected PNG, JPEG, TIFF, OpenEXR or camera RAW)".into())
        }
    }
}

fn png_meta(bytes: &[u8]) -> Result<ImageMeta, String> {
    let decoder = png::Decoder::new(Cursor::new(bytes));
    let reader = decoder
        .read_info()
        .map_err(|e| format!("corrupt PNG: {e}"))?;
    let info = reader.info();
    let bit_depth = if info.bit_depth == png::BitDepth::Sixteen {
        16
    } else {
        8
    };
    // PNG 1.2 §10.5: an sRGB chunk overrides gAMA and iCCP; an ICC profile overrides gAMA.
    let declared = if info.srgb.is_some() {
        Some((Response::Srgb, "PNG sRGB chunk".to_string()))
    } else if let Some(r) = info.icc_profile.as_deref().and_then(icc_response) {
        Some((r, "PNG ICC profile".to_string()))
    } else {
        info.gama_chunk.map(|g| {
            // gAMA stores the encoding exponent (0.45455 for a 2.2 display gamma).
            let enc = g.into_value() as f64;
            let r = if (enc - 1.0).abs() < 1e-3 {
                Response::Linear
            } else {
                Response::Gamma(round_exponent(1.0 / enc))
            };
            (r, format!("PNG gAMA chunk ({enc})"))
        })
    };
    let (exposure, orientation, _) = exif_facts(bytes);
    Ok(ImageMeta {
        format: Format::Png,
        bit_depth,
        decoder: format!("png {bit_depth}-bit"),
        declared,
        exposure,
        orientation,
    })
}

fn jpeg_meta(bytes: &[u8]) -> Result<ImageMeta, String> {
    use zune_core::bytestream::ZCursor;
    let mut dec = zune_jpeg::JpegDecoder::new(ZCursor::new(bytes));
    dec.decode_headers()
        .map_err(|e| format!("corrupt JPEG: {e:?}"))?;
    let progressive = dec.info().is_some_and(|i| i.sof.is_progressive());
    let (exposure, orientation, colour_space) = exif_facts(bytes);
    let declared = if let Some(r) = dec.icc_profile().as_deref().and_then(icc_response) {
        (r, "JPEG ICC profile".to_string())
    } else if colour_space == Some(0xFFFF) {
        // Uncalibrated: in practice Adobe RGB (1998), whose transfer is a 563/256 power.
        (
            Response::Gamma(563.0 / 256.0),
            "EXIF colour space uncalibrated (Adobe RGB)".to_string(),
        )
    } else if colour_space == Some(1) {
        (Response::Srgb, "EXIF colour space sRGB".to_string())
    } else {
        (Response::Srgb, "JPEG (sRGB by convention)".to_string())
    };
    Ok(ImageMeta {
        format: Format::Jpeg,
        bit_depth: 8,
        decoder: format!(
            "jpeg {} 8-bit",
            if progressive {
                "progressive"
            } else {
                "baseline"
            }
        ),
        declared: Some(declared),
        exposure,
        orientation,
    })
}

fn tiff_meta(bytes: &[u8]) -> Result<ImageMeta, String> {
    use tiff::decoder::Decoder;
    use tiff::ColorType;
    let mut dec = Decoder::new(Cursor::new(bytes)).map_err(|e| format!("corrupt TIFF: {e}"))?;
    let color = dec.colortype().map_err(|e| format!("corrupt TIFF: {e}"))?;
    let bits = match color {
        ColorType::Gray(b) | ColorType::GrayA(b) | ColorType::RGB(b) | ColorType::RGBA(b) => b,
        _ => 8,
    };
    let float = matches!(
        dec.find_tag(tiff::tags::Tag::SampleFormat),
        Ok(Some(v)) if v.clone().into_u16().ok() == Some(3)
    );
    let bit_depth = if float || bits > 16 { 32 } else { bits.max(8) };
    let icc = dec
        .find_tag(tiff::tags::Tag::IccProfile)
        .ok()
        .flatten()
        .and_then(|v| v.into_u8_vec().ok());
    let (exposure, orientation, colour_space) = exif_facts(bytes);
    let declared = if bit_depth == 32 {
        Some((Response::Linear, "floating-point TIFF".to_string()))
    } else if let Some(r) = icc.as_deref().and_then(icc_response) {
        Some((r, "TIFF ICC profile".to_string()))
    } else if colour_space == Some(1) {
        Some((Response::Srgb, "EXIF colour space sRGB".to_string()))
    } else {
        None
    };
    Ok(ImageMeta {
        format: Format::Tiff,
        bit_depth,
        decoder: if bit_depth == 32 {
            "tiff float".into()
        } else {
            format!("tiff {bit_depth}-bit")
        },
        declared,
        exposure,
        orientation,
    })
}

/// Exposure, orientation and the EXIF colour space (1 sRGB, 0xFFFF uncalibrated) of a file
/// with EXIF data (JPEG APP1, TIFF's own directories, PNG eXIf); defaults without.
fn exif_facts(bytes: &[u8]) -> (Exposure, u16, Option<u32>) {
    let Ok(exif) = exif::Reader::new().read_from_container(&mut Cursor::new(bytes)) else {
        return (Exposure::default(), 1, None);
    };
    let number = |tag: exif::Tag| -> Option<f64> {
        let f = exif.get_field(tag, exif::In::PRIMARY)?;
        let v = match &f.value {
            exif::Value::Rational(r) => r.first().map(|r| r.to_f64()),
            exif::Value::SRational(r) => r.first().map(|r| r.to_f64()),
            other => other.get_uint(0).map(f64::from),
        }?;
        (v.is_finite() && v > 0.0).then_some(v)
    };
    let exposure = Exposure {
        time_s: number(exif::Tag::ExposureTime),
        iso: number(exif::Tag::PhotographicSensitivity),
        f_number: number(exif::Tag::FNumber),
    };
    let orientation = exif
        .get_field(exif::Tag::Orientation, exif::In::PRIMARY)
        .and_then(|f| f.value.get_uint(0))
        .filter(|o| (1..=8).contains(o))
        .unwrap_or(1) as u16;
    let colour_space = exif
        .get_field(exif::Tag::ColorSpace, exif::In::PRIMARY)
        .and_then(|f| f.value.get_uint(0));
    (exposure, orientation, colour_space)
}

/// An exponent rounded to 4 decimals (a gAMA chunk's 0.45455 gives 2.2, not 2.199978).
fn round_exponent(g: f64) -> f64 {
    (g * 1e4).round() / 1e4
}

/// The response of an ICC profile (ICC.1:2010): its red (or grey) tone reproduction curve as
/// a `curv` (no entry: linear; one: a power; a table: sRGB when it follows the sRGB curve
/// within 1%, else the power that fits it) or a `para` (type 0: a power; type 3 with sRGB's
/// constants: sRGB). `None` for what it cannot read.
pub fn icc_response(icc: &[u8]) -> Option<Response> {
    if icc.len() < 132 || &icc[36..40] != b"acsp" {
        return None;
    }
    let be32 = |at: usize| -> Option<u32> {
        Some(u32::from_be_bytes(icc.get(at..at + 4)?.try_into().ok()?))
    };
    let be16 = |at: usize| -> Option<u16> {
        Some(u16::from_be_bytes(icc.get(at..at + 2)?.try_into().ok()?))
    };
    let count = be32(128)? as usize;
    let mut trc = None;
    for i in 0..count.min(1000) {
        let at = 132 + 12 * i;
        let sig = icc.get(at..at + 4)?;
        if sig == b"rTRC" || sig == b"kTRC" {
            trc = Some((be32(at + 4)? as usize, be32(at + 8)? as usize));
            if sig == b"rTRC" {
                break;
            }
        }
    }
    let (off, len) = trc?;
    let tag = icc.get(off..off.checked_add(len)?)?;
    match tag.get(0..4)? {
        b"curv" => {
            let n = be32(off + 8)? as usize;
            match n {
                0 => Some(Response::Linear),
                1 => Some(gamma_or_linear(be16(off + 12)? as f64 / 256.0)),
                _ => {
                    let table: Vec<f64> = (0..n.min(1 << 16))
                        .map(|i| be16(off + 12 + 2 * i).map(|v| v as f64 / 65535.0))
                        .collect::<Option<_>>()?;
                    Some(table_response(&table))
                }
            }
        }
        b"para" => {
            let kind = be16(off + 8)?;
            let s15 = |k: usize| be32(off + 12 + 4 * k).map(|v| v as i32 as f64 / 65536.0);
            let g = s15(0)?;
            match kind {
                0 => Some(gamma_or_linear(g)),
                3 if (g - 2.4).abs() < 0.01 && (s15(4)? - 0.040_45).abs() < 0.002 => {
                    Some(Response::Srgb)
                }
                _ => Some(gamma_or_linear(g)),
            }
        }
        _ => None,
    }
}

fn gamma_or_linear(g: f64) -> Response {
    if (g - 1.0).abs() < 1e-3 {
        Response::Linear
    } else {
        Response::Gamma(round_exponent(g))
    }
}

/// The response a sampled tone curve (`table[i]` the linear value at encoded `i / (n - 1)`)
/// stands for.
fn table_response(table: &[f64]) -> Response {
    let n = table.len();
    let at = |i: usize| i as f64 / (n - 1) as f64;
    let srgb_gap = table
        .iter()
        .enumerate()
        .map(|(i, v)| (v - Response::Srgb.linear(at(i))).abs())
        .fold(0.0, f64::max);
    if srgb_gap < 0.01 {
        return Response::Srgb;
    }
    // The power through the curve's points in log-log space, away from 0.
    let (mut num, mut den) = (0.0, 0.0);
    for (i, v) in table.iter().enumerate() {
        let e = at(i);
        if e > 0.05 && *v > 0.0 {
            num += e.ln() * v.ln();
            den += e.ln() * e.ln();
        }
    }
    gamma_or_linear(if den > 0.0 { num / den } else { 1.0 })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A minimal ICC profile: header, a tag table with one rTRC pointing at `trc`.
    fn profile(trc: &[u8]) -> Vec<u8> {
        let mut p = vec![0u8; 132 + 12];
        p[36..40].copy_from_slice(b"acsp");
        p[128..132].copy_from_slice(&1u32.to_be_bytes());
        p[132..136].copy_from_slice(b"rTRC");
        p[136..140].copy_from_slice(&(144u32).to_be_bytes());
        p[140..144].copy_from_slice(&(trc.len() as u32).to_be_bytes());
        p.extend_from_slice(trc);
        p
    }

    #[test]
    fn icc_curves_are_read() {
        let mut curv = b"curv\0\0\0\0".to_vec();
        curv.extend_from_slice(&1u32.to_be_bytes());
        curv.extend_from_slice(&((2.2f64 * 256.0).round() as u16).to_be_bytes());
        assert_eq!(
            icc_response(&profile(&curv)),
            Some(Response::Gamma(round_exponent(563.0 / 256.0)))
        );
        let mut lin = b"curv\0\0\0\0".to_vec();
        lin.extend_from_slice(&0u32.to_be_bytes());
        assert_eq!(icc_response(&profile(&lin)), Some(Response::Linear));
        // sRGB as a 1024-entry table, as many camera profiles carry it.
        let mut table = b"curv\0\0\0\0".to_vec();
        table.extend_from_slice(&1024u32.to_be_bytes());
        for i in 0..1024 {
            let v = Response::Srgb.linear(i as f64 / 1023.0);
            table.extend_from_slice(&((v * 65535.0).round() as u16).to_be_bytes());
        }
        assert_eq!(icc_response(&profile(&table)), Some(Response::Srgb));
        // sRGB as a parametric curve of type 3 (ICC.1 table 65): g, a, b, c, d.
        let mut para = b"para\0\0\0\0\0\x03\0\0".to_vec();
        for v in [2.4, 1.0 / 1.055, 0.055 / 1.055, 1.0 / 12.92, 0.040_45] {
            para.extend_from_slice(&((v * 65536.0f64).round() as i32).to_be_bytes());
        }
        assert_eq!(icc_response(&profile(&para)), Some(Response::Srgb));
        assert_eq!(icc_response(b"not a profile"), None);
        assert_eq!(icc_response(&profile(b"curv")), None);
    }
}
