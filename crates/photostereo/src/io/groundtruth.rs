//! Reading normal maps that follow the conventions: `.npy` (H, W, 3) float, DiLiGenT's
//! `Normal_gt.mat`, or a normal-map image (16-bit PNG encoded as (n + 1) / 2 · 65535; 8-bit and
//! float images are accepted too, floats taken as the components themselves).

use crate::base::error::{Error, Result};
use crate::io::imageio::read_image;
use std::path::Path;

/// A normal map: `height * width` vectors, row-major; (0, 0, 0) marks pixels without data.
#[derive(Clone, Debug, PartialEq)]
pub struct NormalMap {
    pub width: usize,
    pub height: usize,
    pub normals: Vec<[f32; 3]>,
    /// Vectors of the file with a NaN or infinite component, read as (0, 0, 0) ("no data").
    pub non_finite: usize,
}

/// Reads a normal map by its extension (`.npy`, `.mat`, or an image).
pub fn read_normal_map(path: &Path) -> Result<NormalMap> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    match ext.as_str() {
        "npy" => read_npy(path),
        "mat" => read_mat_normals(path),
        _ => read_image_normals(path),
    }
}

/// A depth map: `height * width` values, row-major; NaN where there is none.
#[derive(Clone, Debug, PartialEq)]
pub struct DepthMap {
    pub width: usize,
    pub height: usize,
    pub values: Vec<f32>,
}

/// Reads a depth map (ground truth or a prior): `.npy` of shape (H, W), float32 or float64, in C
/// or Fortran order; `.npz` (its first array, stored or deflated, as numpy's `savez` writes
/// it); or a one-channel float EXR/TIFF. Values are taken as they are (units are the caller's).
pub fn read_depth_map(path: &Path) -> Result<DepthMap> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    match ext.as_str() {
        "npy" => {
            let bytes = crate::io::limits::read_file(path)?;
            decode_depth_npy(&bytes).map_err(|m| Error::file(path, m))
        }
        "npz" => {
            let bytes = crate::io::limits::read_file(path)?;
            let npy = first_zip_member(&bytes).map_err(|m| Error::file(path, m))?;
            decode_depth_npy(&npy).map_err(|m| Error::file(path, m))
        }
        _ => {
            let img = read_image(path)?;
            if img.channels != 1 || img.bit_depth != 32 {
                return Err(Error::file(
                    path,
                    "a depth image must be one-channel float (EXR or 32-bit TIFF); or use .npy",
                ));
            }
            Ok(DepthMap {
                width: img.width,
                height: img.height,
                values: img.data,
            })
        }
    }
}

/// The bytes of a zip archive's first member (stored or deflated), size-checked.
fn first_zip_member(bytes: &[u8]) -> Result<Vec<u8>, String> {
    use std::io::Read;
    if !bytes.starts_with(b"PK\x03\x04") || bytes.len() < 30 {
        return Err("not a .npz (zip) file".into());
    }
    let le16 = |o: usize| u16::from_le_bytes([bytes[o], bytes[o + 1]]) as usize;
    let start = 30 + le16(26) + le16(28);
    let data = bytes.get(start..).ok_or("truncated .npz")?;
    let limit = (bytes.len() as u64).saturating_mul(crate::io::limits::MAX_DEFLATE_RATIO);
    match le16(8) {
        0 => Ok(data.to_vec()),
        8 => {
            let mut out = Vec::new();
            flate2::read::DeflateDecoder::new(data)
                .take(limit)
                .read_to_end(&mut out)
                .map_err(|e| format!("corrupt .npz member: {e}"))?;
            Ok(out)
        }
        m => Err(format!(".npz compression method {m} is not supported")),
    }
}

/// Decodes a depth map from the bytes of a `.npy` file: float32 or float64, shape (H, W).
fn decode_depth_npy(bytes: &[u8]) -> Result<DepthMap, String> {
    use ndarray_npy::ReadNpyExt;
    let header = parse_npy_header(bytes)?;
    if header.shape.len() != 2 {
        return Err(format!(
            "shape {}: expected a depth map (H, W)",
            shape_text(&header.shape)
        ));
    }
    let arr: ndarray::Array2<f32> = match ndarray::Array2::<f32>::read_npy(bytes) {
        Ok(a) => a,
        Err(_) => ndarray::Array2::<f64>::read_npy(bytes)
            .map_err(|e| format!("expected a float32 or float64 array of shape (H, W): {e}"))?
            .mapv(|v| v as f32),
    };
    let (height, width) = arr.dim();
    let values = arr.as_standard_layout().iter().copied().collect();
    Ok(DepthMap {
        width,
        height,
        values,
    })
}

fn read_npy(path: &Path) -> Result<NormalMap> {
    let bytes = crate::io::limits::read_file(path)?;
    decode_npy(&bytes).map_err(|m| Error::file(path, m))
}

/// What a `.npy` header declares.
#[derive(Clone, Debug, PartialEq)]
pub struct NpyHeader {
    /// The `descr` field, e.g. `<f4`.
    pub descr: String,
    pub fortran_order: bool,
    pub shape: Vec<u64>,
    /// Offset of the data.
    pub data_offset: usize,
}

/// A shape as numpy writes it: `(2, 3)`, `(5,)`.
fn shape_text(shape: &[u64]) -> String {
    let parts: Vec<String> = shape.iter().map(u64::to_string).collect();
    if parts.len() == 1 {
        format!("({},)", parts[0])
    } else {
        format!("({})", parts.join(", "))
    }
}

impl NpyHeader {
    /// Bytes per element from `descr` (the digits after the type letter).
    pub fn item_size(&self) -> Option<u64> {
        let digits: String = self
            .descr
            .chars()
            .skip_while(|c| !c.is_ascii_digit())
            .take_while(|c| c.is_ascii_digit())
            .collect();
        digits.parse().ok().filter(|&n| n > 0)
    }
}

/// Parses a `.npy` header (format versions 1 to 3) without trusting it: the declared shape is
/// checked against [`crate::io::limits::MAX_ARRAY_ELEMENTS`] and against the bytes that follow.
pub fn parse_npy_header(bytes: &[u8]) -> Result<NpyHeader, String> {
    if !bytes.starts_with(b"\x93NUMPY") || bytes.len() < 10 {
        return Err("not a .npy file (no \\x93NUMPY magic)".into());
    }
    let (len, start): (usize, usize) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 if bytes.len() >= 12 => (
            u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            12,
        ),
        v => return Err(format!(".npy format version {v} is not supported")),
    };
    let end = start
        .checked_add(len)
        .filter(|&e| e <= bytes.len())
        .ok_or("truncated .npy header")?;
    let text = std::str::from_utf8(&bytes[start..end]).map_err(|_| "malformed .npy header")?;
    let field = |name: &str| -> Result<&str, String> {
        let key = text
            .find(&format!("'{name}'"))
            .or_else(|| text.find(&format!("\"{name}\"")))
            .ok_or_else(|| format!("malformed .npy header: no '{name}'"))?;
        let rest = &text[key + name.len() + 2..];
        let colon = rest
            .find(':')
            .ok_or_else(|| format!("malformed .npy header after '{name}'"))?;
        Ok(rest[colon + 1..].trim_start())
    };
    let d = field("descr")?;
    let quote = d.chars().next().filter(|c| *c == '\'' || *c == '"');
    let descr = match quote {
        Some(q) => d[1..]
            .split(q)
            .next()
            .ok_or("malformed .npy header: descr")?
            .to_string(),
        None => return Err("unsupported .npy dtype (a structured array?)".into()),
    };
    let fortran_order = field("fortran_order")?.starts_with("True");
    let s = field("shape")?;
    let inner = s
        .strip_prefix('(')
        .and_then(|r| r.split(')').next())
        .ok_or("malformed .npy header: shape")?;
    let shape = inner
        .split(',')
        .map(str::trim)
        .filter(|t| !t.is_empty())
        .map(|t| t.trim_end_matches('L').parse::<u64>())
        .collect::<Result<Vec<u64>, _>>()
        .map_err(|_| format!("malformed .npy shape ({inner})"))?;
    let header = NpyHeader {
        descr,
        fortran_order,
        shape,
        data_offset: end,
    };
    let elements = header
        .shape
        .iter()
        .try_fold(1u64, |a, &d| a.checked_mul(d))
        .filter(|&n| n <= crate::io::limits::MAX_ARRAY_ELEMENTS)
        .ok_or_else(|| {
            format!(
                "declares shape {}: more than {} elements",
                shape_text(&header.shape),
                crate::io::limits::MAX_ARRAY_ELEMENTS
            )
        })?;
    let item = header
        .item_size()
        .ok_or_else(|| format!("unsupported .npy dtype '{}'", header.descr))?;
    let data = elements.saturating_mul(item);
    let held = (bytes.len() - end) as u64;
    if data > held {
        return Err(format!(
            "declares shape {} of '{}' ({}) but holds only {}: truncated or forged",
            shape_text(&header.shape),
            header.descr,
            crate::base::machine::human_bytes(data),
            crate::base::machine::human_bytes(held)
        ));
    }
    Ok(header)
}

/// Decodes a normal map from the bytes of a `.npy` file: float32 or float64, shape (H, W, 3).
pub fn decode_npy(bytes: &[u8]) -> Result<NormalMap, String> {
    let header = parse_npy_header(bytes)?;
    if !matches!(
        header.descr.as_str(),
        "<f4" | "<f8" | "=f4" | "=f8" | "|f4" | "|f8"
    ) {
        return Err(format!(
            "holds {} samples ('{}'): expected a little-endian float32 or float64 array of shape (H, W, 3)",
            npy_type_name(&header.descr),
            header.descr
        ));
    }
    if header.shape.len() != 3 || header.shape[2] != 3 {
        return Err(format!(
            "shape {}: expected (H, W, 3)",
            shape_text(&header.shape)
        ));
    }
    let (h, w) = (header.shape[0], header.shape[1]);
    let pixels = h.saturating_mul(w);
    if pixels > crate::model::image::MAX_IMAGE_PIXELS
        || h > crate::model::image::MAX_IMAGE_SIDE
        || w > crate::model::image::MAX_IMAGE_SIDE
    {
        return Err(format!(
            "declares {w}×{h} normals: more than the limits of {} pixels a side and {} pixels",
            crate::model::image::MAX_IMAGE_SIDE,
            crate::model::image::MAX_IMAGE_PIXELS
        ));
    }
    crate::base::machine::check_memory(
        pixels.saturating_mul(3 * 8 + 12),
        &format!("declares {w}×{h} normals: reading them"),
    )?;
    // The common case — little-endian float32 in C order — straight from the bytes, rows in
    // parallel (one pass, no intermediate array). The header check above guarantees the bytes.
    let little_f4 = matches!(header.descr.as_str(), "<f4" | "|f4")
        || (header.descr == "=f4" && cfg!(target_endian = "little"));
    if !header.fortran_order && little_f4 {
        let (w, h) = (w as usize, h as usize);
        let data = &bytes[header.data_offset..header.data_offset + w * h * 12];
        let mut normals = vec![[0f32; 3]; w * h];
        use rayon::prelude::*;
        let non_finite = normals
            .par_chunks_mut(w.max(1))
            .zip(data.par_chunks(12 * w.max(1)))
            .map(|(row, raw)| {
                let mut bad = 0usize;
                for (o, px) in row.iter_mut().zip(raw.chunks_exact(12)) {
                    let v = [0, 4, 8]
                        .map(|k| f32::from_le_bytes([px[k], px[k + 1], px[k + 2], px[k + 3]]));
                    let c = clean(v);
                    bad += usize::from(c != v);
                    *o = c;
                }
                bad
            })
            .sum();
        return Ok(NormalMap {
            width: w,
            height: h,
            normals,
            non_finite,
        });
    }
    use ndarray_npy::ReadNpyExt;
    let arr: ndarray::Array3<f32> = match ndarray::Array3::<f32>::read_npy(bytes) {
        Ok(a) => a,
        Err(_) => ndarray::Array3::<f64>::read_npy(bytes)
            .map_err(|e| format!("expected a float32 or float64 array of shape (H, W, 3): {e}"))?
            .mapv(|v| v as f32),
    };
    let (h, w, c) = arr.dim();
    if c != 3 {
        return Err(format!("shape ({h}, {w}, {c}): expected (H, W, 3)"));
    }
    let standard = arr.as_standard_layout();
    let flat = standard.as_slice().ok_or("the array is not contiguous")?;
    Ok(from_vectors(
        w,
        h,
        flat.chunks_exact(3).map(|v| [v[0], v[1], v[2]]),
    ))
}

/// A readable name for a `.npy` `descr` such as `<i4` (int32) or `>f8` (big-endian float64).
fn npy_type_name(descr: &str) -> String {
    let body = descr.trim_start_matches(['<', '>', '=', '|']);
    let mut chars = body.chars();
    let kind = chars.next();
    let bits = chars
        .as_str()
        .parse::<u32>()
        .ok()
        .and_then(|b| b.checked_mul(8));
    let name = match (kind, bits) {
        (Some('f'), Some(b)) => format!("float{b}"),
        (Some('i'), Some(b)) => format!("int{b}"),
        (Some('u'), Some(b)) => format!("uint{b}"),
        (Some('b'), _) => "bool".to_string(),
        (Some('c'), Some(b)) => format!("complex{b}"),
        _ => return format!("'{descr}'"),
    };
    if descr.starts_with('>') && bits.is_some_and(|b| b > 8) {
        format!("big-endian {name}")
    } else {
        name
    }
}

/// A normal map from raw vectors, non-finite ones counted and read as "no data".
fn from_vectors(width: usize, height: usize, v: impl Iterator<Item = [f32; 3]>) -> NormalMap {
    let mut non_finite = 0;
    let normals = v
        .map(|n| {
            let c = clean(n);
            non_finite += usize::from(c != n);
            c
        })
        .collect();
    NormalMap {
        width,
        height,
        normals,
        non_finite,
    }
}

fn read_mat_normals(path: &Path) -> Result<NormalMap> {
    let a = crate::io::matfile::read_mat(path, Some("Normal_gt"))
        .or_else(|_| crate::io::matfile::read_mat(path, None))?;
    if a.dims.len() != 3 || a.dims[2] != 3 {
        return Err(Error::file(
            path,
            format!(
                "variable '{}' has dimensions {:?}: expected (H, W, 3)",
                a.name, a.dims
            ),
        ));
    }
    let (h, w) = (a.dims[0], a.dims[1]);
    if h.checked_mul(w).and_then(|n| n.checked_mul(3)) != Some(a.data.len()) {
        return Err(Error::file(path, "inconsistent array dimensions"));
    }
    let at = |r: usize, c: usize, k: usize| a.data[r + h * (c + w * k)] as f32;
    Ok(from_vectors(
        w,
        h,
        (0..h * w).map(|i| {
            let (r, c) = (i / w, i % w);
            [at(r, c, 0), at(r, c, 1), at(r, c, 2)]
        }),
    ))
}

fn read_image_normals(path: &Path) -> Result<NormalMap> {
    let img = read_image(path)?;
    if img.channels != 3 {
        return Err(Error::file(path, "a normal-map image must be RGB"));
    }
    let float = img.bit_depth == 32;
    Ok(from_vectors(
        img.width,
        img.height,
        img.data.chunks_exact(3).map(|v| {
            if float {
                [v[0], v[1], v[2]]
            } else if v.iter().all(|&x| x == 0.0) {
                [0.0; 3]
            } else {
                [v[0] * 2.0 - 1.0, v[1] * 2.0 - 1.0, v[2] * 2.0 - 1.0]
            }
        }),
    ))
}

/// Non-finite vectors become (0, 0, 0), i.e. "no data".
fn clean(v: [f32; 3]) -> [f32; 3] {
    if v.iter().all(|x| x.is_finite()) {
        v
    } else {
        [0.0; 3]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn npy(descr: &str) -> Vec<u8> {
        let header =
            format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': (1, 1, 3), }}\n");
        let mut b = b"\x93NUMPY\x01\x00".to_vec();
        b.extend_from_slice(&(header.len() as u16).to_le_bytes());
        b.extend_from_slice(header.as_bytes());
        b.extend_from_slice(&[0u8; 24]);
        b
    }

    /// A normal map of another dtype is refused with the dtype's name and what was expected;
    /// a descr that starts with a multi-byte character (found by fuzzing) is quoted, not split.
    #[test]
    fn dtype_errors_name_the_type() {
        let e = decode_npy(&npy("<i4")).unwrap_err();
        assert!(e.contains("int32") && e.contains("expected"), "{e}");
        let e = decode_npy(&npy(">f8")).unwrap_err();
        assert!(e.contains("big-endian float64"), "{e}");
        let e = decode_npy(&npy("ѝf8")).unwrap_err();
        assert!(e.contains("'ѝf8'"), "{e}");
        assert!(decode_npy(&npy("<f8")).is_ok());
    }

    /// float32 in C order (the direct path), in Fortran order and float64 (through ndarray)
    /// decode to the same vectors, non-finite ones read as zero and counted.
    #[test]
    fn npy_float32_c_order_matches_the_general_decoder() {
        use ndarray::ShapeBuilder;
        use ndarray_npy::WriteNpyExt;
        let (h, w) = (3usize, 5usize);
        let value = |r: usize, c: usize, k: usize| -> f32 {
            match (r * w + c, k) {
                (4, 1) => f32::NAN,
                (9, 2) => f32::INFINITY,
                (i, k) => 0.1 * i as f32 - 0.7 * k as f32 + 0.05,
            }
        };
        let c_order = ndarray::Array3::from_shape_fn((h, w, 3), |(r, c, k)| value(r, c, k));
        let f_order = ndarray::Array3::from_shape_fn((h, w, 3).f(), |(r, c, k)| value(r, c, k));
        let f64s = c_order.mapv(|v| v as f64);
        let encode = |write: &dyn Fn(&mut Vec<u8>)| {
            let mut b = Vec::new();
            write(&mut b);
            decode_npy(&b).unwrap()
        };
        let maps = [
            encode(&|b| c_order.write_npy(b).unwrap()),
            encode(&|b| f_order.write_npy(b).unwrap()),
            encode(&|b| f64s.write_npy(b).unwrap()),
        ];
        for m in &maps {
            assert_eq!((m.width, m.height, m.non_finite), (w, h, 2));
            for r in 0..h {
                for c in 0..w {
                    let i = r * w + c;
                    let want = if i == 4 || i == 9 {
                        [0.0; 3]
                    } else {
                        [0, 1, 2].map(|k| value(r, c, k))
                    };
                    assert_eq!(m.normals[i], want, "pixel {i}");
                }
            }
        }
    }
}
