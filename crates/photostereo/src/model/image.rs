//! A decoded image, and the largest image the library takes.

/// A decoded image: interleaved row-major `f32` samples, row 0 at the top.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// 1 (grey) or 3 (RGB).
    pub channels: usize,
    /// Bits per sample of the source file (8, 16 or 32).
    pub bit_depth: u8,
    /// `height * width * channels` samples; integer formats scaled to [0, 1].
    pub data: Vec<f32>,
}

impl Image {
    /// Sample `(row, col, channel)`.
    #[inline]
    pub fn at(&self, row: usize, col: usize, channel: usize) -> f32 {
        self.data[(row * self.width + col) * self.channels + channel]
    }

    /// Mean over channels at `(row, col)`.
    #[inline]
    pub fn grey(&self, row: usize, col: usize) -> f32 {
        let base = (row * self.width + col) * self.channels;
        let s: f32 = self.data[base..base + self.channels].iter().sum();
        s / self.channels as f32
    }
}

/// Largest width or height of an image, pixels.
pub const MAX_IMAGE_SIDE: u64 = 1 << 17;

/// Largest number of pixels of one image (about 1.07 gigapixels).
pub const MAX_IMAGE_PIXELS: u64 = 1 << 30;
