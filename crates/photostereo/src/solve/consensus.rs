//! Spatial consistency of light statuses: a light's fault at a pixel — a shadow, a
//! highlight, a reading off the model — is a region on the object, not a single pixel. Cast and
//! attached shadows and highlights have extent; a removal that none of a pixel's neighbours
//! share is the χ² test's noise-level decision, and so is a kept light that every neighbour
//! drops. Per light, a pixel's removal is replaced by the majority of its square neighbourhood
//! inside the mask (itself included). This is what keeps the recursive normal field as smooth as
//! the least-squares one where the surface is: neighbouring pixels use the same lights, so they
//! share the same model error instead of switching between subsets with different biases.
//!
//! Statuses are per mask pixel and light (`n_pixels * n_lights`, the layout of
//! [`crate::solve::detect::Detection::light_status`]).

use crate::base::codes2::{pack_into, Codes2};
use crate::model::capture::Capture;
use crate::solve::lambert::{status, Statuses, CHUNK};
use rayon::prelude::*;

/// The majority filter of the removals of each light over the (2·`radius` + 1)² neighbourhood
/// of every mask pixel (neighbours outside the mask do not vote). A pixel whose filtered set
/// would keep fewer than `min_kept` lights keeps its own statuses. A light newly removed takes
/// the label most of its removing neighbours gave it; a light newly kept becomes USED.
///
/// Returns the filtered statuses and the number of mask pixels whose usable set changed.
pub fn majority_filter(
    capture: &Capture,
    light_status: &[u8],
    radius: usize,
    min_kept: usize,
) -> (Vec<u8>, usize) {
    majority_filter_where(capture, light_status, radius, min_kept, None)
}

/// [`majority_filter`] at the mask pixels where `only` is true (every pixel when None); the
/// others keep their statuses and are not counted.
pub fn majority_filter_where(
    capture: &Capture,
    light_status: &[u8],
    radius: usize,
    min_kept: usize,
    only: Option<&[bool]>,
) -> (Vec<u8>, usize) {
    let n = capture.n_lights();
    debug_assert_eq!(light_status.len(), capture.n_pixels() * n);
    let mut out = light_status.to_vec();
    let filter = Filter {
        capture,
        radius,
        min_kept,
        only,
    };
    let changed = filter.run(light_status, &mut out, n, |row, o| o.copy_from_slice(row));
    (out, changed)
}

/// [`majority_filter_where`] on statuses held as 2-bit codes (one row a mask pixel): the same
/// statuses, packed.
pub fn majority_filter_codes(
    capture: &Capture,
    light_status: &Codes2,
    radius: usize,
    min_kept: usize,
    only: Option<&[bool]>,
) -> (Codes2, usize) {
    debug_assert_eq!(light_status.rows(), capture.n_pixels());
    let mut out = light_status.clone();
    let stride = out.stride();
    let filter = Filter {
        capture,
        radius,
        min_kept,
        only,
    };
    let changed = filter.run(light_status, out.as_bytes_mut(), stride, pack_into);
    (out, changed)
}

/// The majority filter's settings.
struct Filter<'a> {
    capture: &'a Capture,
    radius: usize,
    min_kept: usize,
    only: Option<&'a [bool]>,
}

impl Filter<'_> {
    /// Filters `light_status` into `out` (`stride` bytes a mask pixel, each pixel's statuses
    /// written by `write` from one byte a status; pixels not filtered are left as they are).
    /// Returns the number of pixels whose usable set changed.
    fn run(
        &self,
        light_status: &(impl Statuses + ?Sized),
        out: &mut [u8],
        stride: usize,
        write: impl Fn(&[u8], &mut [u8]) + Sync,
    ) -> usize {
        let (capture, radius, min_kept, only) =
            (self.capture, self.radius, self.min_kept, self.only);
        let n = capture.n_lights();
        let (w, h) = (capture.width, capture.height);
        if n == 0 || stride == 0 {
            return 0;
        }
        // The mask pixels of each row (no frame-sized index: 4 bytes a frame pixel).
        let mask_rows = MaskRows::new(capture);
        out.par_chunks_mut(CHUNK * stride)
            .enumerate()
            .map_init(
                || {
                    (
                        vec![[0u32; 4]; n],
                        Vec::with_capacity((2 * radius + 1).pow(2)),
                        vec![0u8; n],
                        vec![0u8; n],
                        vec![0u8; n],
                    )
                },
                |(votes, neighbours, st, own, row), (chunk, rows)| {
                    let mut changed = 0;
                    for (dp, out_row) in rows.chunks_mut(stride).enumerate() {
                        let p = chunk * CHUNK + dp;
                        if only.is_some_and(|o| !o[p]) {
                            continue;
                        }
                        let pix = capture.pixels[p] as usize;
                        let (r, c) = (pix / w, pix % w);
                        neighbours.clear();
                        for rr in r.saturating_sub(radius)..(r + radius + 1).min(h) {
                            neighbours.extend(mask_rows.between(
                                rr,
                                c.saturating_sub(radius),
                                (c + radius).min(w - 1),
                            ));
                        }
                        let total = neighbours.len() as u32;
                        for v in votes.iter_mut() {
                            *v = [0; 4];
                        }
                        for &q in neighbours.iter() {
                            light_status.row_into(q, st);
                            for (v, &s) in votes.iter_mut().zip(st.iter()) {
                                if s != status::USED && (s as usize) < 4 {
                                    v[s as usize] += 1;
                                }
                            }
                        }
                        light_status.row_into(p, own);
                        let mut kept = 0;
                        let mut differs = false;
                        for k in 0..n {
                            let removals = votes[k][1] + votes[k][2] + votes[k][3];
                            let removed = 2 * removals > total;
                            row[k] = if !removed {
                                status::USED
                            } else if own[k] != status::USED {
                                own[k]
                            } else {
                                // The label most removing neighbours gave.
                                (1..4u8).max_by_key(|&s| votes[k][s as usize]).unwrap()
                            };
                            kept += usize::from(!removed);
                            differs |= (row[k] == status::USED) != (own[k] == status::USED);
                        }
                        if kept < min_kept {
                            write(own, out_row);
                        } else {
                            write(row, out_row);
                            if differs {
                                changed += 1;
                            }
                        }
                    }
                    changed
                },
            )
            .sum()
    }
}

/// The mask pixels of each frame row, found from [`Capture::pixels`] (ascending): `h + 1`
/// offsets instead of a frame-sized index.
struct MaskRows<'a> {
    pixels: &'a [u32],
    width: usize,
    /// Mask index of the first mask pixel of each row, and `n_pixels` last.
    starts: Vec<usize>,
}

impl<'a> MaskRows<'a> {
    fn new(capture: &'a Capture) -> Self {
        let (w, h) = (capture.width, capture.height);
        let pixels = &capture.pixels[..];
        let starts = (0..=h)
            .map(|r| pixels.partition_point(|&i| (i as usize) < r * w))
            .collect();
        MaskRows {
            pixels,
            width: w,
            starts,
        }
    }

    /// The mask indices of row `row`'s mask pixels in columns `first..=last`, in order.
    fn between(&self, row: usize, first: usize, last: usize) -> std::ops::Range<usize> {
        let (a, b) = (self.starts[row], self.starts[row + 1]);
        let in_row = &self.pixels[a..b];
        let base = row * self.width;
        let lo = in_row.partition_point(|&i| (i as usize) < base + first);
        let hi = in_row.partition_point(|&i| (i as usize) <= base + last);
        a + lo..a + hi
    }
}

/// The mask pixels within `radius` (Chebyshev distance, in pixels) of a mask pixel where
/// `seeds` is true: where [`majority_filter`]'s result can differ after the statuses changed
/// at the seeds.
pub fn neighbourhood_of(capture: &Capture, seeds: &[bool], radius: usize) -> Vec<bool> {
    let (w, h) = (capture.width, capture.height);
    // Per frame pixel, whether a seed lies within `radius` columns on its row, then within
    // `radius` rows of that.
    let mut across = vec![false; w * h];
    for (p, &i) in capture.pixels.iter().enumerate() {
        if seeds[p] {
            let (r, c) = (i as usize / w, i as usize % w);
            let row = &mut across[r * w..(r + 1) * w];
            row[c.saturating_sub(radius)..(c + radius + 1).min(w)].fill(true);
        }
    }
    capture
        .pixels
        .par_iter()
        .map(|&i| {
            let (r, c) = (i as usize / w, i as usize % w);
            (r.saturating_sub(radius)..(r + radius + 1).min(h)).any(|rr| across[rr * w + c])
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::rng::Pcg32;
    use crate::fixtures::{lambert_sphere, ring};

    /// Against a direct count over the neighbourhood, on random statuses over a sphere's mask
    /// (whose border pixels have partial neighbourhoods).
    #[test]
    fn the_filter_is_the_neighbourhood_majority() {
        let (capture, _) = lambert_sphere(40, 15.0, &ring(8, 30.0));
        let (n, np, w) = (capture.n_lights(), capture.n_pixels(), capture.width);
        let mut rng = Pcg32::new(19, 0);
        let statuses: Vec<u8> = (0..np * n)
            .map(|_| match rng.next_u32() % 10 {
                0..=5 => status::USED,
                6 | 7 => status::SHADOW,
                8 => status::HIGHLIGHT,
                _ => status::REJECTED,
            })
            .collect();
        for radius in [1usize, 2] {
            let (out, changed) = majority_filter(&capture, &statuses, radius, 3);
            let mut expect_changed = 0;
            for p in 0..np {
                let (r, c) = (
                    capture.pixels[p] as usize / w,
                    capture.pixels[p] as usize % w,
                );
                let neighbours: Vec<usize> = (0..np)
                    .filter(|&q| {
                        let (rq, cq) = (
                            capture.pixels[q] as usize / w,
                            capture.pixels[q] as usize % w,
                        );
                        rq.abs_diff(r) <= radius && cq.abs_diff(c) <= radius
                    })
                    .collect();
                let removed: Vec<bool> = (0..n)
                    .map(|k| {
                        let votes = neighbours
                            .iter()
                            .filter(|&&q| statuses[q * n + k] != status::USED)
                            .count();
                        2 * votes > neighbours.len()
                    })
                    .collect();
                let own = &statuses[p * n..(p + 1) * n];
                let row = &out[p * n..(p + 1) * n];
                if removed.iter().filter(|&&x| !x).count() < 3 {
                    assert_eq!(row, own, "pixel {p} keeps its own statuses");
                    continue;
                }
                let mut differs = false;
                for k in 0..n {
                    assert_eq!(row[k] != status::USED, removed[k], "pixel {p} light {k}");
                    if removed[k] && own[k] != status::USED {
                        assert_eq!(row[k], own[k], "own label kept");
                    }
                    differs |= removed[k] != (own[k] != status::USED);
                }
                expect_changed += usize::from(differs);
            }
            assert_eq!(changed, expect_changed);
            assert!(
                changed > np / 2,
                "random statuses mostly change: {changed}/{np}"
            );
        }
    }

    /// Filtering only the neighbourhood of the pixels whose statuses changed gives the whole
    /// filter of the changed statuses.
    #[test]
    fn filtering_the_neighbourhood_of_changes_equals_filtering_everything() {
        let (capture, _) = lambert_sphere(40, 15.0, &ring(8, 30.0));
        let (n, np) = (capture.n_lights(), capture.n_pixels());
        let mut rng = Pcg32::new(7, 0);
        let random = |rng: &mut Pcg32| match rng.next_u32() % 10 {
            0..=5 => status::USED,
            6 | 7 => status::SHADOW,
            8 => status::HIGHLIGHT,
            _ => status::REJECTED,
        };
        let before: Vec<u8> = (0..np * n).map(|_| random(&mut rng)).collect();
        let mut after = before.clone();
        let mut seeds = vec![false; np];
        for _ in 0..12 {
            let p = rng.next_u32() as usize % np;
            seeds[p] = true;
            for k in 0..n {
                after[p * n + k] = random(&mut rng);
            }
        }
        for radius in [1usize, 2] {
            let (old, _) = majority_filter(&capture, &before, radius, 3);
            let (full, _) = majority_filter(&capture, &after, radius, 3);
            let near = neighbourhood_of(&capture, &seeds, radius);
            assert!(near.iter().filter(|&&x| x).count() < np / 2);
            let (part, _) = majority_filter_where(&capture, &after, radius, 3, Some(&near));
            let mut merged = old.clone();
            for p in (0..np).filter(|&p| near[p]) {
                merged[p * n..(p + 1) * n].copy_from_slice(&part[p * n..(p + 1) * n]);
            }
            assert_eq!(merged, full, "radius {radius}");
            assert_ne!(old, full, "the changes reach the filter");
        }
    }

    /// A removal no neighbour shares is dropped; a region of removals stays but for its
    /// corners (a 6×6 block under a 5×5 window).
    #[test]
    fn isolated_removals_go_and_regions_stay() {
        let (capture, _) = lambert_sphere(40, 18.0, &ring(8, 30.0));
        let (n, np, w) = (capture.n_lights(), capture.n_pixels(), capture.width);
        let at = |r: usize, c: usize| capture.pixels.iter().position(|&i| i as usize == r * w + c);
        let mut statuses = vec![status::USED; np * n];
        let lone = at(20, 20).unwrap();
        statuses[lone * n + 2] = status::HIGHLIGHT;
        let mut block = Vec::new();
        for r in 8..14 {
            for c in 17..23 {
                let p = at(r, c).unwrap();
                statuses[p * n + 5] = status::SHADOW;
                block.push(p);
            }
        }
        let (out, changed) = majority_filter(&capture, &statuses, 2, 3);
        assert_eq!(out[lone * n + 2], status::USED);
        let mut kept_in_block = 0;
        for &p in &block {
            let (r, c) = (
                capture.pixels[p] as usize / w,
                capture.pixels[p] as usize % w,
            );
            let inner = (9..13).contains(&r) && (18..22).contains(&c);
            let shadow = out[p * n + 5] == status::SHADOW;
            assert!(shadow || !inner, "({r}, {c}) inside the region");
            kept_in_block += usize::from(shadow);
        }
        // Only pixels near the block's corners fall (fewer than 13 of their 25 neighbours
        // remove the light): 2 at each corner.
        assert_eq!(kept_in_block, 36 - 4 * 3);
        assert_eq!(changed, 1 + 4 * 3);
    }
}
