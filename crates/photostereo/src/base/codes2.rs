//! Rows of 2-bit codes (values 0–3), packed four to a byte: a per-pixel, per-light table of
//! small codes (the light statuses) in `⌈n / 4⌉` bytes a row instead of `n`.
//!
//! Each row starts on a byte, so that runs of whole rows are plain byte slices
//! ([`Codes2::par_rows_mut`]) that threads write without sharing a byte. Code `k` of a row is
//! bits `2·(k % 4)`…`2·(k % 4) + 1` of the row's byte `k / 4`.

use rayon::prelude::*;

/// `rows × width` codes of two bits.
#[derive(Clone, Debug, PartialEq, Eq, Default)]
pub struct Codes2 {
    width: usize,
    stride: usize,
    data: Vec<u8>,
}

/// Bytes of a row of `width` codes.
#[inline]
pub fn row_bytes(width: usize) -> usize {
    width.div_ceil(4)
}

/// Code `k` of the packed row `row`.
#[inline]
pub fn get_in(row: &[u8], k: usize) -> u8 {
    (row[k / 4] >> (2 * (k % 4))) & 3
}

/// Sets code `k` of the packed row `row` to `v` (0–3).
#[inline]
pub fn set_in(row: &mut [u8], k: usize, v: u8) {
    debug_assert!(v < 4, "a 2-bit code");
    let shift = 2 * (k % 4);
    let b = &mut row[k / 4];
    *b = (*b & !(3 << shift)) | ((v & 3) << shift);
}

/// Unpacks the packed row `row` into `out` (one code a byte, `out.len()` codes).
#[inline]
pub fn unpack_into(row: &[u8], out: &mut [u8]) {
    for (k, o) in out.iter_mut().enumerate() {
        *o = get_in(row, k);
    }
}

/// Packs `codes` (one a byte, each 0–3) into the packed row `row`.
#[inline]
pub fn pack_into(codes: &[u8], row: &mut [u8]) {
    row.fill(0);
    for (k, &v) in codes.iter().enumerate() {
        debug_assert!(v < 4, "a 2-bit code");
        row[k / 4] |= (v & 3) << (2 * (k % 4));
    }
}

impl Codes2 {
    /// `rows` rows of `width` codes, all `fill` (0–3).
    pub fn filled(rows: usize, width: usize, fill: u8) -> Codes2 {
        assert!(fill < 4, "a 2-bit code");
        let stride = row_bytes(width);
        let mut byte = 0u8;
        for k in 0..4 {
            byte |= fill << (2 * k);
        }
        let mut c = Codes2 {
            width,
            stride,
            data: vec![byte; rows * stride],
        };
        // Padding bits stay zero, so that equal codes mean equal bytes.
        if width % 4 != 0 {
            for r in 0..rows {
                let last = &mut c.data[r * stride + stride - 1];
                *last &= (1u8 << (2 * (width % 4))) - 1;
            }
        }
        c
    }

    /// Packs `codes` (`rows × width`, row-major, one code a byte, each 0–3). Panics on a code
    /// above 3 or a length that is not a whole number of rows (programming errors).
    pub fn from_codes(codes: &[u8], width: usize) -> Codes2 {
        let rows = codes.len().checked_div(width).unwrap_or(0);
        assert_eq!(rows * width, codes.len(), "whole rows of codes");
        assert!(codes.iter().all(|&v| v < 4), "2-bit codes");
        let stride = row_bytes(width);
        let mut data = vec![0u8; rows * stride];
        if width > 0 {
            data.par_chunks_mut(stride)
                .zip(codes.par_chunks(width))
                .for_each(|(row, c)| pack_into(c, row));
        }
        Codes2 {
            width,
            stride,
            data,
        }
    }

    /// Codes per row.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Rows.
    pub fn rows(&self) -> usize {
        self.data.len().checked_div(self.stride).unwrap_or(0)
    }

    /// Bytes of one packed row.
    pub fn stride(&self) -> usize {
        self.stride
    }

    /// Code `k` of row `r`.
    #[inline]
    pub fn get(&self, r: usize, k: usize) -> u8 {
        get_in(self.row(r), k)
    }

    /// Sets code `k` of row `r` to `v` (0–3).
    #[inline]
    pub fn set(&mut self, r: usize, k: usize, v: u8) {
        let s = self.stride;
        set_in(&mut self.data[r * s..(r + 1) * s], k, v);
    }

    /// Row `r`, packed.
    #[inline]
    pub fn row(&self, r: usize) -> &[u8] {
        &self.data[r * self.stride..(r + 1) * self.stride]
    }

    /// Row `r`, packed, to write.
    #[inline]
    pub fn row_mut(&mut self, r: usize) -> &mut [u8] {
        let s = self.stride;
        &mut self.data[r * s..(r + 1) * s]
    }

    /// Row `r` unpacked into `out` (`width` bytes).
    #[inline]
    pub fn unpack_row(&self, r: usize, out: &mut [u8]) {
        unpack_into(self.row(r), &mut out[..self.width]);
    }

    /// Writes row `r` from `codes` (`width` codes, one a byte).
    #[inline]
    pub fn pack_row(&mut self, r: usize, codes: &[u8]) {
        let w = self.width;
        pack_into(&codes[..w], self.row_mut(r));
    }

    /// Whether rows `r` of `self` and `q` of `other` hold the same codes.
    #[inline]
    pub fn rows_equal(&self, r: usize, other: &Codes2, q: usize) -> bool {
        self.row(r) == other.row(q)
    }

    /// Rows `range` unpacked, one code a byte (`range.len() × width`).
    pub fn unpack_rows(&self, range: std::ops::Range<usize>) -> Vec<u8> {
        let w = self.width;
        let mut out = vec![0u8; range.len() * w];
        if w > 0 {
            out.par_chunks_mut(w)
                .zip(
                    self.data[range.start * self.stride..range.end * self.stride]
                        .par_chunks(self.stride),
                )
                .for_each(|(o, row)| unpack_into(row, o));
        }
        out
    }

    /// All rows unpacked (one code a byte).
    pub fn unpack(&self) -> Vec<u8> {
        self.unpack_rows(0..self.rows())
    }

    /// The packed bytes of rows `range`, in runs of `per` rows, for threads to write.
    pub fn par_rows_mut(
        &mut self,
        range: std::ops::Range<usize>,
        per: usize,
    ) -> rayon::slice::ChunksMut<'_, u8> {
        let s = self.stride;
        self.data[range.start * s..range.end * s].par_chunks_mut((per * s).max(1))
    }

    /// The packed rows, `stride` bytes each, to write (codes 0–3, padding bits zero).
    pub fn as_bytes_mut(&mut self) -> &mut [u8] {
        &mut self.data
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.data.len()
    }

    /// The packed rows as bytes ([`Codes2::as_bytes_mut`]), given up (to park them in a file).
    pub fn into_bytes(self) -> Vec<u8> {
        self.data
    }

    /// Rows of `width` codes from their packed bytes ([`Codes2::into_bytes`]).
    pub fn from_bytes(width: usize, data: Vec<u8>) -> Codes2 {
        let stride = row_bytes(width);
        assert!(
            data.len() % stride.max(1) == 0,
            "whole rows of {stride} bytes"
        );
        Codes2 {
            width,
            stride,
            data,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::rng::Pcg32;

    #[test]
    fn packed_codes_read_back_as_a_byte_array_after_random_writes() {
        let mut rng = Pcg32::new(7, 1);
        for width in [1usize, 3, 4, 5, 8, 24, 25, 96] {
            let rows = 37;
            let mut reference: Vec<u8> = (0..rows * width)
                .map(|_| (rng.next_u32() % 4) as u8)
                .collect();
            let mut packed = Codes2::from_codes(&reference, width);
            assert_eq!(packed.rows(), rows);
            assert_eq!(packed.bytes(), rows * width.div_ceil(4));
            assert_eq!(packed.unpack(), reference);
            // Random single writes, whole-row writes and reads against the byte array.
            let mut buf = vec![0u8; width];
            for _ in 0..2000 {
                let r = rng.next_u32() as usize % rows;
                let k = rng.next_u32() as usize % width;
                let v = (rng.next_u32() % 4) as u8;
                match rng.next_u32() % 3 {
                    0 => {
                        packed.set(r, k, v);
                        reference[r * width + k] = v;
                    }
                    1 => {
                        for (j, b) in buf.iter_mut().enumerate() {
                            *b = ((v as usize + j * 3) % 4) as u8;
                        }
                        packed.pack_row(r, &buf);
                        reference[r * width..(r + 1) * width].copy_from_slice(&buf);
                    }
                    _ => {
                        packed.unpack_row(r, &mut buf);
                        assert_eq!(buf, reference[r * width..(r + 1) * width]);
                    }
                }
                assert_eq!(packed.get(r, k), reference[r * width + k]);
            }
            assert_eq!(packed.unpack(), reference);
            assert_eq!(packed.unpack_rows(3..9), reference[3 * width..9 * width]);
            // Rows compare equal exactly when their codes do (the padding stays zero).
            for r in 0..rows {
                for q in 0..rows {
                    assert_eq!(
                        packed.rows_equal(r, &packed, q),
                        reference[r * width..(r + 1) * width]
                            == reference[q * width..(q + 1) * width]
                    );
                }
            }
            for fill in 0..4u8 {
                let f = Codes2::filled(rows, width, fill);
                assert_eq!(f.unpack(), vec![fill; rows * width]);
                assert_eq!(f, Codes2::from_codes(&vec![fill; rows * width], width));
            }
        }
    }
}
