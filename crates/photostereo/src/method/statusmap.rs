//! A reconstruction's light statuses ([`crate::solve::lambert::status`]) over the frame, held per mask
//! pixel as 2-bit codes: `⌈N / 4⌉` bytes per mask pixel instead of `N` per frame pixel, with
//! full-frame planes made on demand (one light at a time when written). Outside the mask every
//! light reads [`status::OUTSIDE`].

use crate::base::codes2::Codes2;
use crate::solve::lambert::status;

/// [`StatusMap::count_map`]'s value outside the mask.
pub const COUNT_OUTSIDE: u16 = u16::MAX;

/// Per mask pixel and light, the status of the light in the pixel's estimate.
#[derive(Clone, Debug, PartialEq)]
pub struct StatusMap {
    pub width: usize,
    pub height: usize,
    pub lights: usize,
    /// The frame pixels with statuses (the mask pixels), in mask order.
    pixels: MaskPixels,
    /// Row `p`, code `k`: light `k` at mask pixel `p`; `None`: every light used at every mask
    /// pixel (`l2`).
    codes: Option<Codes2>,
}

/// Which frame pixels a [`StatusMap`] holds statuses for.
#[derive(Clone, Debug, PartialEq)]
enum MaskPixels {
    /// Every frame pixel, row-major: a mask that is the whole frame, whose list of flat indices
    /// would be 0, 1, 2, … (4 bytes a frame pixel not held).
    Frame,
    /// Flat row-major frame index of each mask pixel, ascending; never every frame pixel.
    Listed(Vec<u32>),
}

impl MaskPixels {
    /// The ascending mask pixel list `pixels` of a frame of `frame` pixels: [`MaskPixels::Frame`]
    /// when it names every one of them (ascending, distinct and in the frame, so it is
    /// 0, 1, 2, …).
    fn of(frame: usize, pixels: &[u32]) -> MaskPixels {
        if pixels.len() == frame {
            debug_assert!(pixels.iter().enumerate().all(|(p, &i)| p == i as usize));
            MaskPixels::Frame
        } else {
            MaskPixels::Listed(pixels.to_vec())
        }
    }

    /// [`MaskPixels::of`] that keeps `pixels` (no copy) when it is not the whole frame.
    fn owned(frame: usize, pixels: Vec<u32>) -> MaskPixels {
        if pixels.len() == frame {
            MaskPixels::of(frame, &pixels)
        } else {
            MaskPixels::Listed(pixels)
        }
    }
}

impl StatusMap {
    /// The statuses `codes` (`pixels.len() * lights`, pixel-major) of the mask pixels `pixels`
    /// (flat frame indices) of a `width × height` frame; `None` when every light was used.
    /// Panics when the lengths disagree or a code is not a status (programming errors, not
    /// input).
    pub fn new(
        width: usize,
        height: usize,
        lights: usize,
        pixels: Vec<u32>,
        codes: Option<Vec<u8>>,
    ) -> StatusMap {
        if let Some(c) = &codes {
            assert_eq!(c.len(), pixels.len() * lights, "statuses per mask pixel");
        }
        let codes = codes.map(|c| Codes2::from_codes(&c, lights));
        StatusMap::packed(width, height, lights, pixels, codes)
    }

    /// [`StatusMap::new`] from statuses already packed (one row of `lights` codes per mask
    /// pixel).
    pub fn packed(
        width: usize,
        height: usize,
        lights: usize,
        pixels: Vec<u32>,
        codes: Option<Codes2>,
    ) -> StatusMap {
        let n = pixels.len();
        let pixels = MaskPixels::owned(width * height, pixels);
        StatusMap::checked(width, height, lights, n, pixels, codes)
    }

    /// [`StatusMap::packed`] for the mask pixels `pixels` of a capture that keeps its own list:
    /// copied only when the mask is not the whole frame (a whole frame's list is not held).
    pub fn packed_at(
        width: usize,
        height: usize,
        lights: usize,
        pixels: &[u32],
        codes: Option<Codes2>,
    ) -> StatusMap {
        let mask = MaskPixels::of(width * height, pixels);
        StatusMap::checked(width, height, lights, pixels.len(), mask, codes)
    }

    /// The map of `n` mask pixels, after checking that `codes` has a row of `lights` for each.
    fn checked(
        width: usize,
        height: usize,
        lights: usize,
        n: usize,
        pixels: MaskPixels,
        codes: Option<Codes2>,
    ) -> StatusMap {
        if let Some(c) = &codes {
            assert_eq!(
                (c.rows(), c.width()),
                (n, lights),
                "statuses per mask pixel"
            );
        }
        StatusMap {
            width,
            height,
            lights,
            pixels,
            codes,
        }
    }

    /// The statuses of the mask pixels `pixels` read from a whole `(N, H, W)` array `full`.
    pub fn from_frame(
        width: usize,
        height: usize,
        lights: usize,
        pixels: Vec<u32>,
        full: &[u8],
    ) -> StatusMap {
        let hw = width * height;
        assert_eq!(full.len(), lights * hw, "statuses of an (N, H, W) array");
        let codes = pixels
            .iter()
            .flat_map(|&i| (0..lights).map(move |k| full[k * hw + i as usize]))
            .collect();
        StatusMap::new(width, height, lights, pixels, Some(codes))
    }

    /// How many mask pixels the map holds statuses for.
    pub fn n_pixels(&self) -> usize {
        match &self.pixels {
            MaskPixels::Frame => self.width * self.height,
            MaskPixels::Listed(v) => v.len(),
        }
    }

    /// Calls `f(p, i)` for each mask pixel `p` (index into the mask pixels, ascending) and its
    /// flat frame index `i`.
    fn for_each_pixel(&self, mut f: impl FnMut(usize, usize)) {
        match &self.pixels {
            MaskPixels::Frame => (0..self.width * self.height).for_each(|i| f(i, i)),
            MaskPixels::Listed(v) => {
                for (p, &i) in v.iter().enumerate() {
                    f(p, i as usize);
                }
            }
        }
    }

    /// Light `k`'s status at mask pixel `p` (index into the ascending mask pixels).
    #[inline]
    pub fn code(&self, p: usize, k: usize) -> u8 {
        self.codes.as_ref().map_or(status::USED, |c| c.get(p, k))
    }

    /// Light `k`'s status at frame pixel `i` (flat row-major index): [`status::OUTSIDE`]
    /// outside the mask. A binary search: for occasional look-ups, not for sweeps.
    pub fn get(&self, k: usize, i: usize) -> u8 {
        let p = match &self.pixels {
            MaskPixels::Frame => (i < self.width * self.height).then_some(i),
            MaskPixels::Listed(v) => v.binary_search(&(i as u32)).ok(),
        };
        p.map_or(status::OUTSIDE, |p| self.code(p, k))
    }

    /// Light `k`'s statuses over the frame (`height * width`, row-major) into `out`.
    pub fn write_plane(&self, k: usize, out: &mut Vec<u8>) {
        out.clear();
        out.resize(self.width * self.height, status::OUTSIDE);
        self.for_each_pixel(|p, i| out[i] = self.code(p, k));
    }

    /// Light `k`'s statuses over the frame.
    pub fn plane(&self, k: usize) -> Vec<u8> {
        let mut out = Vec::new();
        self.write_plane(k, &mut out);
        out
    }

    /// The whole `(N, H, W)` array (N bytes per frame pixel: for callers that need it whole).
    pub fn to_full(&self) -> Vec<u8> {
        let mut full = Vec::with_capacity(self.lights * self.width * self.height);
        let mut plane = Vec::new();
        for k in 0..self.lights {
            self.write_plane(k, &mut plane);
            full.extend_from_slice(&plane);
        }
        full
    }

    /// How many lights of mask pixel `p` have the status `which` (any status but used when
    /// `None`).
    pub fn count_at(&self, p: usize, which: Option<u8>) -> usize {
        (0..self.lights)
            .filter(|&k| {
                let s = self.code(p, k);
                match which {
                    Some(w) => s == w,
                    None => s != status::USED && s != status::OUTSIDE,
                }
            })
            .count()
    }

    /// Per frame pixel, how many lights have the status `which` (any status but used when
    /// `None`); NaN outside the mask.
    pub fn counts(&self, which: Option<u8>) -> Vec<f32> {
        let mut counts = vec![f32::NAN; self.width * self.height];
        self.for_each_pixel(|p, i| counts[i] = self.count_at(p, which) as f32);
        counts
    }

    /// [`StatusMap::counts`] as whole numbers in two bytes a frame pixel: [`COUNT_OUTSIDE`]
    /// outside the mask, counts above `u16::MAX − 1` clipped there.
    pub fn count_map(&self, which: Option<u8>) -> Vec<u16> {
        let mut counts = vec![COUNT_OUTSIDE; self.width * self.height];
        self.for_each_pixel(|p, i| {
            counts[i] = self.count_at(p, which).min(COUNT_OUTSIDE as usize - 1) as u16;
        });
        counts
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn planes_counts_and_the_whole_array_agree_with_a_dense_reference() {
        // 3×2 frame, mask pixels 0, 2, 5; three lights.
        let (w, h, n) = (3, 2, 3);
        let pixels = vec![0u32, 2, 5];
        let codes = vec![
            status::USED,
            status::SHADOW,
            status::HIGHLIGHT, // pixel 0
            status::SHADOW,
            status::SHADOW,
            status::USED, // pixel 2
            status::USED,
            status::USED,
            status::REJECTED, // pixel 5
        ];
        let map = StatusMap::new(w, h, n, pixels.clone(), Some(codes.clone()));
        // The dense (N, H, W) reference, built directly.
        let mut dense = vec![status::OUTSIDE; n * w * h];
        for (p, &i) in pixels.iter().enumerate() {
            for k in 0..n {
                dense[k * w * h + i as usize] = codes[p * n + k];
            }
        }
        assert_eq!(map.to_full(), dense);
        assert_eq!(StatusMap::from_frame(w, h, n, pixels.clone(), &dense), map);
        let packed = Codes2::from_codes(&codes, n);
        assert_eq!(
            StatusMap::packed(w, h, n, pixels.clone(), Some(packed)),
            map
        );
        for k in 0..n {
            for i in 0..w * h {
                assert_eq!(map.get(k, i), dense[k * w * h + i]);
            }
        }
        for k in 0..n {
            assert_eq!(map.plane(k), dense[k * w * h..(k + 1) * w * h]);
        }
        let shadow = map.counts(Some(status::SHADOW));
        assert_eq!(shadow[0], 1.0);
        assert_eq!(shadow[2], 2.0);
        assert_eq!(shadow[5], 0.0);
        assert!(shadow[1].is_nan() && shadow[3].is_nan() && shadow[4].is_nan());
        let any = map.counts(None);
        assert_eq!((any[0], any[2], any[5]), (2.0, 2.0, 1.0));
        // The 2-byte map holds the same counts, and its own value outside the mask.
        for which in [Some(status::SHADOW), Some(status::HIGHLIGHT), None] {
            let f = map.counts(which);
            let u = map.count_map(which);
            for i in 0..w * h {
                if f[i].is_nan() {
                    assert_eq!(u[i], COUNT_OUTSIDE);
                } else {
                    assert_eq!(u[i] as f32, f[i]);
                }
            }
        }
        // Without codes every mask pixel uses every light.
        let all = StatusMap::new(w, h, n, pixels, None);
        assert_eq!(all.counts(None)[2], 0.0);
        assert_eq!(all.plane(1)[5], status::USED);
        assert_eq!(all.plane(1)[4], status::OUTSIDE);
    }

    #[test]
    fn a_whole_frame_mask_reads_as_its_dense_reference_without_a_pixel_list() {
        // 2×2 frame, every pixel in the mask; two lights.
        let (w, h, n) = (2, 2, 2);
        let codes = vec![
            status::USED,
            status::SHADOW, // pixel 0
            status::HIGHLIGHT,
            status::USED, // pixel 1
            status::SHADOW,
            status::SHADOW, // pixel 2
            status::USED,
            status::REJECTED, // pixel 3
        ];
        let pixels: Vec<u32> = (0..4).collect();
        let packed = Codes2::from_codes(&codes, n);
        let map = StatusMap::packed_at(w, h, n, &pixels, Some(packed.clone()));
        assert_eq!(map.pixels, MaskPixels::Frame);
        assert_eq!(map, StatusMap::new(w, h, n, pixels, Some(codes.clone())));
        assert_eq!(map.n_pixels(), 4);
        for k in 0..n {
            let plane: Vec<u8> = (0..4).map(|p| codes[p * n + k]).collect();
            assert_eq!(map.plane(k), plane);
            for (i, &s) in plane.iter().enumerate() {
                assert_eq!(map.get(k, i), s);
            }
            assert_eq!(map.get(k, 4), status::OUTSIDE);
        }
        assert_eq!(map.counts(None), vec![1.0, 1.0, 2.0, 1.0]);
        assert_eq!(map.count_map(Some(status::SHADOW)), vec![1, 0, 2, 0]);
        // A mask short of the whole frame keeps its list.
        let part = StatusMap::packed_at(w, h, n, &[0, 3], None);
        assert_eq!(part.pixels, MaskPixels::Listed(vec![0, 3]));
        assert_eq!(part.get(0, 1), status::OUTSIDE);
        assert_eq!(part.get(0, 3), status::USED);
    }
}
