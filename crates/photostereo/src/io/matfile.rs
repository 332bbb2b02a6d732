//! A minimal reader of MATLAB level-5 MAT-files: numeric, real, dense arrays, plain or inside
//! zlib-compressed elements. Enough for DiLiGenT's `Normal_gt.mat`; anything else is a clear error.

use crate::base::error::{Error, Result};
use std::io::Read;
use std::path::Path;

/// A numeric array read from a MAT-file: dimensions and values in column-major order.
#[derive(Clone, Debug)]
pub struct MatArray {
    /// Variable name.
    pub name: String,
    /// Dimensions (MATLAB order: rows, columns, pages…).
    pub dims: Vec<usize>,
    /// Values, column-major (first index fastest).
    pub data: Vec<f64>,
}

const MI_INT8: u32 = 1;
const MI_UINT8: u32 = 2;
const MI_INT16: u32 = 3;
const MI_UINT16: u32 = 4;
const MI_INT32: u32 = 5;
const MI_UINT32: u32 = 6;
const MI_SINGLE: u32 = 7;
const MI_DOUBLE: u32 = 9;
const MI_INT64: u32 = 12;
const MI_UINT64: u32 = 13;
const MI_MATRIX: u32 = 14;
const MI_COMPRESSED: u32 = 15;

/// Reads the variable `name` (or the first numeric array when `name` is `None`).
pub fn read_mat(path: &Path, name: Option<&str>) -> Result<MatArray> {
    let bytes = crate::io::limits::read_file(path)?;
    parse(&bytes, name).map_err(|m| Error::file(path, m))
}

/// Parses the bytes of a MAT-file (see [`read_mat`]). Compressed elements are inflated to at
/// most [`crate::io::limits::MAX_DEFLATE_RATIO`] times their size and within the available memory;
/// declared dimensions are checked against the values actually present.
pub fn parse_mat(bytes: &[u8], name: Option<&str>) -> Result<MatArray, String> {
    parse(bytes, name)
}

fn parse(bytes: &[u8], name: Option<&str>) -> Result<MatArray, String> {
    if bytes.len() < 128 || !bytes.starts_with(b"MATLAB 5.0") {
        return Err("not a MATLAB 5.0 MAT-file".into());
    }
    let little = match &bytes[126..128] {
        b"IM" => true,
        b"MI" => false,
        _ => return Err("bad MAT-file endian indicator".into()),
    };
    let rd = Reader { little };
    let mut pos = 128;
    let mut found = Vec::new();
    while pos + 8 <= bytes.len() {
        let ty = rd.u32(&bytes[pos..]);
        let len = rd.u32(&bytes[pos + 4..]) as usize;
        let start = pos + 8;
        let end = start
            .checked_add(len)
            .filter(|&e| e <= bytes.len())
            .ok_or("truncated MAT-file")?;
        let body = &bytes[start..end];
        match ty {
            MI_COMPRESSED => {
                let most = (body.len() as u64).saturating_mul(crate::io::limits::MAX_DEFLATE_RATIO);
                crate::base::machine::check_memory(
                    most.min(1 << 30),
                    "inflating a compressed element",
                )?;
                let mut inflated = Vec::new();
                flate2::read::ZlibDecoder::new(body)
                    .take(most.saturating_add(1))
                    .read_to_end(&mut inflated)
                    .map_err(|e| format!("corrupt compressed element: {e}"))?;
                if inflated.len() as u64 > most {
                    return Err(
                        "corrupt compressed element: it inflates beyond what zlib can produce"
                            .into(),
                    );
                }
                if inflated.len() >= 8 && rd.u32(&inflated) == MI_MATRIX {
                    let l = rd.u32(&inflated[4..]) as usize;
                    let inner = 8usize
                        .checked_add(l)
                        .and_then(|e| inflated.get(8..e))
                        .ok_or("truncated compressed matrix")?;
                    if let Some(a) = rd.matrix(inner)? {
                        found.push(a);
                    }
                }
            }
            MI_MATRIX => {
                if let Some(a) = rd.matrix(body)? {
                    found.push(a);
                }
            }
            _ => {}
        }
        pos = end + ((8 - len % 8) % 8) * usize::from(ty != MI_COMPRESSED);
    }
    match name {
        Some(n) => found
            .into_iter()
            .find(|a| a.name == n)
            .ok_or_else(|| format!("no numeric variable named '{n}'")),
        None => found
            .into_iter()
            .next()
            .ok_or_else(|| "no numeric array".into()),
    }
}

struct Reader {
    little: bool,
}

impl Reader {
    fn u32(&self, b: &[u8]) -> u32 {
        let a = [b[0], b[1], b[2], b[3]];
        if self.little {
            u32::from_le_bytes(a)
        } else {
            u32::from_be_bytes(a)
        }
    }

    /// Reads one sub-element: (type, payload, bytes consumed including padding).
    fn element<'a>(&self, b: &'a [u8]) -> Result<(u32, &'a [u8], usize), String> {
        if b.len() < 8 {
            return Err("truncated matrix element".into());
        }
        let word = self.u32(b);
        if word >> 16 != 0 {
            // Small data element: type in the low half, size in the high half, data in 4 bytes.
            let ty = word & 0xffff;
            let len = (word >> 16) as usize;
            if len > 4 {
                return Err("bad small data element".into());
            }
            return Ok((ty, &b[4..4 + len], 8));
        }
        let len = self.u32(&b[4..]) as usize;
        let end = 8usize
            .checked_add(len)
            .filter(|&e| e <= b.len())
            .ok_or("truncated matrix element")?;
        let padded = end.div_ceil(8) * 8;
        Ok((word, &b[8..end], padded.min(b.len())))
    }

    fn numbers(&self, ty: u32, b: &[u8]) -> Result<Vec<f64>, String> {
        let l = self.little;
        macro_rules! conv {
            ($t:ty, $n:expr) => {
                b.chunks_exact($n)
                    .map(|c| {
                        let a: [u8; $n] = c.try_into().unwrap();
                        (if l {
                            <$t>::from_le_bytes(a)
                        } else {
                            <$t>::from_be_bytes(a)
                        }) as f64
                    })
                    .collect()
            };
        }
        Ok(match ty {
            MI_INT8 => b.iter().map(|&v| v as i8 as f64).collect(),
            MI_UINT8 => b.iter().map(|&v| v as f64).collect(),
            MI_INT16 => conv!(i16, 2),
            MI_UINT16 => conv!(u16, 2),
            MI_INT32 => conv!(i32, 4),
            MI_UINT32 => conv!(u32, 4),
            MI_SINGLE => conv!(f32, 4),
            MI_DOUBLE => conv!(f64, 8),
            MI_INT64 => conv!(i64, 8),
            MI_UINT64 => conv!(u64, 8),
            other => return Err(format!("unsupported MAT data type {other}")),
        })
    }

    /// Parses a miMATRIX body; `None` for arrays that are not numeric (cells, structs, sparse).
    fn matrix(&self, b: &[u8]) -> Result<Option<MatArray>, String> {
        let (_, flags, used) = self.element(b)?;
        if flags.len() < 4 {
            return Err("bad array flags".into());
        }
        let class = self.u32(flags) & 0xff;
        let complex = self.u32(flags) & 0x0800 != 0;
        // Classes 6..=15 are the numeric ones (double, single, int8 … uint64).
        if !(6..=15).contains(&class) || complex {
            return Ok(None);
        }
        let mut pos = used;
        let (dty, dims_b, used) = self.element(&b[pos..])?;
        pos += used;
        let dims_f = self.numbers(dty, dims_b)?;
        if dims_f.len() < 2 || dims_f.iter().any(|&d| !(d >= 0.0 && d.fract() == 0.0)) {
            return Err(format!("bad array dimensions {dims_f:?}"));
        }
        let dims: Vec<usize> = dims_f
            .iter()
            .map(|&d| d.min(crate::io::limits::MAX_ARRAY_ELEMENTS as f64) as usize)
            .collect();
        let (_, name_b, used) = self.element(&b[pos..])?;
        pos += used;
        let name = String::from_utf8_lossy(name_b).to_string();
        let (rty, real_b, _) = self.element(&b[pos..])?;
        let data = self.numbers(rty, real_b)?;
        let count = dims
            .iter()
            .try_fold(1usize, |a, &d| a.checked_mul(d))
            .filter(|&n| n as u64 <= crate::io::limits::MAX_ARRAY_ELEMENTS);
        if count != Some(data.len()) {
            return Err(format!(
                "array '{name}' holds {} values for dimensions {:?}",
                data.len(),
                dims
            ));
        }
        Ok(Some(MatArray { name, dims, data }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Builds an uncompressed little-endian MAT-file holding one double array.
    fn mat_bytes(name: &str, dims: &[i32], data: &[f64], compress: bool) -> Vec<u8> {
        fn el(ty: u32, payload: &[u8]) -> Vec<u8> {
            let mut v = Vec::new();
            v.extend_from_slice(&ty.to_le_bytes());
            v.extend_from_slice(&(payload.len() as u32).to_le_bytes());
            v.extend_from_slice(payload);
            while v.len() % 8 != 0 {
                v.push(0);
            }
            v
        }
        let mut body = Vec::new();
        body.extend(el(MI_UINT32, &[6u8, 0, 0, 0, 0, 0, 0, 0]));
        let d: Vec<u8> = dims.iter().flat_map(|x| x.to_le_bytes()).collect();
        body.extend(el(MI_INT32, &d));
        body.extend(el(MI_INT8, name.as_bytes()));
        let r: Vec<u8> = data.iter().flat_map(|x| x.to_le_bytes()).collect();
        body.extend(el(MI_DOUBLE, &r));
        let matrix = el(MI_MATRIX, &body);
        let mut out = vec![b' '; 128];
        out[..10].copy_from_slice(b"MATLAB 5.0");
        out[124] = 0;
        out[125] = 1;
        out[126] = b'I';
        out[127] = b'M';
        if compress {
            use std::io::Write;
            let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
            z.write_all(&matrix).unwrap();
            let c = z.finish().unwrap();
            out.extend_from_slice(&MI_COMPRESSED.to_le_bytes());
            out.extend_from_slice(&(c.len() as u32).to_le_bytes());
            out.extend(c);
        } else {
            out.extend(matrix);
        }
        out
    }

    #[test]
    fn reads_plain_and_compressed_arrays() {
        let data: Vec<f64> = (0..12).map(|i| i as f64 * 0.5).collect();
        for compress in [false, true] {
            let b = mat_bytes("Normal_gt", &[2, 2, 3], &data, compress);
            let a = parse(&b, Some("Normal_gt")).unwrap();
            assert_eq!(a.dims, vec![2, 2, 3]);
            assert_eq!(a.data, data);
            assert!(parse(&b, Some("other")).is_err());
        }
    }

    #[test]
    fn rejects_garbage() {
        assert!(parse(b"hello", None).is_err());
        let mut b = mat_bytes("x", &[1, 4], &[1.0, 2.0, 3.0, 4.0], false);
        b.truncate(b.len() - 10);
        assert!(parse(&b, None).is_err());
    }
}
