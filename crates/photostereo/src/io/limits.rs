//! Size limits of the readers. Every reader checks what a file *declares* (image size, array
//! shape, element count) against these limits, against what the file can actually hold, and
//! against the memory available, before it allocates anything of that size: a forged or huge
//! header is an [`Error`](crate::Error) naming the file and its declared size, never an abort.
//!
//! The memory available is read from `/proc/meminfo` (`MemAvailable`) and, inside a container,
//! from the cgroup's `memory.max` − `memory.current`; where neither can be read only the fixed
//! limits apply. The environment variable [`MEMORY_LIMIT_VAR`](crate::base::machine::MEMORY_LIMIT_VAR) lowers the budget further
//! (bytes, or with a `K`, `M`, `G` or `T` suffix, powers of 1024), e.g. on a shared machine.

use crate::base::machine::available_memory;
use crate::base::machine::check_memory;
use crate::base::machine::check_memory_with;
use crate::base::machine::human_bytes;
use crate::model::image::MAX_IMAGE_PIXELS;
use crate::model::image::MAX_IMAGE_SIDE;
/// Largest number of elements of a `.npy` or MAT-file array.
pub const MAX_ARRAY_ELEMENTS: u64 = 1 << 32;
/// Largest text file (light, intensity, list files), bytes.
pub const MAX_TEXT_BYTES: u64 = 256 << 20;
/// Deflate (PNG, zlib in MAT-files and TIFF) expands data at most 1032-fold; with a margin for
/// headers, a file cannot hold more decoded bytes than this many times its own size.
pub const MAX_DEFLATE_RATIO: u64 = 1100;
/// The most a TIFF's compressions (LZW, Deflate, PackBits) can expand data.
pub const MAX_TIFF_RATIO: u64 = 4096;
/// A generous bound on what OpenEXR's compressions expand (ZIP at most 1032-fold, RLE 64,
/// PIZ's Huffman runs a few hundred, B44 about 10).
pub const MAX_EXR_RATIO: u64 = 4096;

/// What an image header declares, to check before decoding.
#[derive(Clone, Copy, Debug)]
pub struct DeclaredImage {
    pub width: u64,
    pub height: u64,
    /// Channels in the file (before dropping alpha).
    pub channels: u64,
    /// Bytes per sample in the file's decoded (uncompressed) buffer.
    pub bytes_per_sample: u64,
    /// Channels kept after decoding (1 or 3), as 4-byte floats.
    pub kept_channels: u64,
}

impl DeclaredImage {
    /// `W×H` as the messages write it.
    pub fn size(&self) -> String {
        format!("{}×{}", self.width, self.height)
    }

    /// Bytes of the decoder's buffer.
    pub fn raw_bytes(&self) -> u64 {
        self.width
            .saturating_mul(self.height)
            .saturating_mul(self.channels)
            .saturating_mul(self.bytes_per_sample)
    }

    /// Peak bytes of a decode: the decoder's buffer plus the float image made from it.
    pub fn decode_bytes(&self) -> u64 {
        let floats = self
            .width
            .saturating_mul(self.height)
            .saturating_mul(self.kept_channels)
            .saturating_mul(4);
        self.raw_bytes().saturating_add(floats)
    }

    /// Checks the declared size against [`MAX_IMAGE_SIDE`], [`MAX_IMAGE_PIXELS`], whether
    /// `stored_bytes` (the uncompressed data the header announces) fits in a file of `file_len`
    /// bytes whose compression expands at most `max_ratio`-fold, and the available memory. The
    /// message names the declared size; the caller names the file.
    pub fn check(&self, stored_bytes: u64, file_len: u64, max_ratio: u64) -> Result<(), String> {
        self.check_with(stored_bytes, file_len, max_ratio, available_memory())
    }

    pub(crate) fn check_with(
        &self,
        stored_bytes: u64,
        file_len: u64,
        max_ratio: u64,
        available: Option<u64>,
    ) -> Result<(), String> {
        let size = self.size();
        if self.width == 0 || self.height == 0 {
            return Err(format!("declares an empty image ({size} pixels)"));
        }
        if self.width > MAX_IMAGE_SIDE || self.height > MAX_IMAGE_SIDE {
            return Err(format!(
                "declares {size} pixels: a side exceeds the limit of {MAX_IMAGE_SIDE} pixels"
            ));
        }
        let pixels = self.width * self.height;
        if pixels > MAX_IMAGE_PIXELS {
            return Err(format!(
                "declares {size} pixels ({:.2} gigapixels): more than the limit of {MAX_IMAGE_PIXELS} pixels",
                pixels as f64 / 1e9
            ));
        }
        if stored_bytes > file_len.saturating_mul(max_ratio).saturating_add(1 << 16) {
            return Err(format!(
                "declares {size} pixels × {} channel(s) ({} of samples), more than a file of {} can hold: corrupt or forged header",
                self.channels,
                human_bytes(stored_bytes),
                human_bytes(file_len)
            ));
        }
        check_memory_with(
            self.decode_bytes(),
            &format!(
                "declares {size} pixels × {} channel(s): decoding it",
                self.channels
            ),
            available,
        )
    }
}

/// Reads a whole file after checking that its size fits in memory.
pub(crate) fn read_file(path: &std::path::Path) -> crate::Result<Vec<u8>> {
    use crate::base::error::Error;
    let len = std::fs::metadata(path)
        .map_err(|e| Error::io(path, e))?
        .len();
    check_memory(len, "reading the file").map_err(|m| Error::file(path, m))?;
    std::fs::read(path).map_err(|e| Error::io(path, e))
}

/// Reads a text file (light, intensity, list files): at most [`MAX_TEXT_BYTES`], UTF-8, with a
/// leading byte-order mark removed.
pub(crate) fn read_text(path: &std::path::Path) -> crate::Result<String> {
    use crate::base::error::Error;
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if meta.is_dir() {
        return Err(Error::file(path, "is a folder, expected a text file"));
    }
    if meta.len() > MAX_TEXT_BYTES {
        return Err(Error::file(
            path,
            format!(
                "{} is too large for a text file of this kind (limit {})",
                human_bytes(meta.len()),
                human_bytes(MAX_TEXT_BYTES)
            ),
        ));
    }
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    text_from_bytes(&bytes).map_err(|m| Error::file(path, m))
}

/// UTF-8 text with a leading byte-order mark removed (what reading a text file does after reading its bytes).
pub fn text_from_bytes(bytes: &[u8]) -> Result<String, String> {
    let bytes = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes);
    if bytes.starts_with(b"\xFF\xFE") || bytes.starts_with(b"\xFE\xFF") {
        return Err("is UTF-16 text: save it as UTF-8 (or plain ASCII)".into());
    }
    String::from_utf8(bytes.to_vec()).map_err(|e| {
        format!(
            "not UTF-8 text (invalid byte at offset {}): expected a plain text file",
            e.utf8_error().valid_up_to()
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn img(w: u64, h: u64) -> DeclaredImage {
        DeclaredImage {
            width: w,
            height: h,
            channels: 3,
            bytes_per_sample: 2,
            kept_channels: 3,
        }
    }

    #[test]
    fn declared_sizes_are_checked_before_decoding() {
        let e = img(1 << 20, 10).check_with(0, 1, 1, None).unwrap_err();
        assert!(e.contains("1048576×10") && e.contains("limit"), "{e}");
        let e = img(100_000, 100_000).check_with(0, 1, 1, None).unwrap_err();
        assert!(
            e.contains("100000×100000") && e.contains("gigapixels"),
            "{e}"
        );
        let big = img(10_000, 10_000);
        let e = big
            .check_with(big.raw_bytes(), 1000, 1100, None)
            .unwrap_err();
        assert!(e.contains("forged"), "{e}");
        let e = big
            .check_with(big.raw_bytes(), 1 << 30, 1100, Some(100 << 20))
            .unwrap_err();
        assert!(e.contains("10000×10000") && e.contains("memory"), "{e}");
        big.check_with(big.raw_bytes(), 1 << 30, 1100, Some(8 << 30))
            .unwrap();
        assert!(img(0, 5).check_with(0, 100, 1, None).is_err());
    }

    #[test]
    fn text_loses_its_byte_order_mark() {
        assert_eq!(text_from_bytes(b"\xEF\xBB\xBF0.4 1 2").unwrap(), "0.4 1 2");
        assert!(text_from_bytes(b"\xFF\xFE0\x00")
            .unwrap_err()
            .contains("UTF-16"));
        assert!(text_from_bytes(b"a\xFFb").unwrap_err().contains("UTF-8"));
    }
}
