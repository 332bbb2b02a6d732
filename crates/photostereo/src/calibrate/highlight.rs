//! The specular highlight of a mirror sphere in one image: the brightest blob inside the
//! sphere's outline, located to sub-pixel accuracy by its intensity-weighted centroid.
//!
//! Image coordinates: `x` = column, `y` = row, pixels, centre of pixel (col, row) at (col, row).

use super::circle::{grey_at, label_regions, Circle};
use crate::model::image::Image;

/// Parameters of the highlight search.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct HighlightOptions {
    /// Least difference between the highlight's peak and the sphere's median grey value, in
    /// image units ([0, 1] for integer images); below it the highlight is "missing".
    pub min_contrast: f32,
    /// Blobs with fewer pixels are treated as dust or hot pixels and ignored.
    pub min_blob_pixels: usize,
    /// The blob is the set of connected pixels above `background + level · (peak − background)`;
    /// a low level keeps the tails of a glow, which removes most of the pixel-locking bias of a
    /// thresholded centroid (0.2 by default).
    pub level: f32,
    /// A second blob whose mass (Σ of grey − threshold) is at least this share of the first's
    /// makes the highlight "doubled".
    pub doubled_mass_share: f64,
    /// A saturated area larger than this share of the sphere's disc makes the highlight
    /// "clipped".
    pub max_saturated_share: f64,
    /// A highlight blob covering more than this share of the sphere's disc is not a mirror's
    /// highlight (0.1 by default). A mirror sphere shows a distant light of angular radius α as
    /// a spot covering sin²(α/2) of the disc (near its centre): 10% is a light 74° across, far
    /// beyond the small lights of photometric stereo, which leaves room for the camera's glow
    /// and bloom and a clipped core (on the rendered 70 px spheres: 0.5% with the default glow
    /// and bloom, 1.8% with a saturated core of radius 9 px, 4–5% with a bloom of σ 15 px). A
    /// matte (Lambertian) sphere's brightest region, the pixels a fifth of the way from its
    /// median to its peak, is the broad cosine lobe: 37–42% of the disc for any light slant
    /// from 0° to 90° (gain, ambient light and the median's level cancel), 42–48% with a 1/2.2
    /// gamma; `psmImages/gray` measures 27–41%. 10% sits a factor 2.7 below the least of these.
    pub max_disc_share: f64,
    /// Least height of the highlight's peak above the sphere's median, in units of the image
    /// noise σ (5 by default). σ is estimated from the differences of adjacent pixels inside
    /// the disc (1.4826 · median |a − b| / √2: insensitive to the smooth environment a mirror
    /// reflects), at least the quantisation noise (one step / √12). The peak is reached by two
    /// adjacent pixels; in pure Gaussian noise both exceed the median by 5σ with probability
    /// about 4 · Φ(−5)² ≈ 3·10⁻¹³ per pixel, so no disc of noise passes (uniform and Gaussian
    /// noise measure 1.6–3.4σ), while highlights stand tens to hundreds of σ out (12σ for a
    /// faint rendered one, 883σ on `psmImages/chrome`).
    pub min_significance: f64,
}

impl Default for HighlightOptions {
    fn default() -> Self {
        HighlightOptions {
            min_contrast: 0.1,
            min_blob_pixels: 3,
            level: 0.2,
            doubled_mass_share: 0.25,
            max_saturated_share: 0.005,
            max_disc_share: 0.1,
            min_significance: 5.0,
        }
    }
}

/// A located highlight.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Highlight {
    /// Column of the intensity-weighted centroid, pixels.
    pub x: f64,
    /// Row of the intensity-weighted centroid, pixels.
    pub y: f64,
    /// Robust peak grey value (reached by at least two adjacent pixels), image units.
    pub peak: f32,
    /// Median grey value over the sphere's disc, image units.
    pub background: f32,
    /// Pixels of the blob.
    pub pixels: usize,
    /// Saturated pixels of the blob.
    pub saturated: usize,
    /// Blob area over the area of the smallest disc about its centroid that holds it, 0..1.
    pub compactness: f64,
    /// Mass of the next brightest blob (not dust) over this blob's mass, 0..1 (0 when none).
    pub second_blob_share: f64,
    /// Centroid of the next brightest blob (column, row), when there is one.
    pub second_blob: Option<[f64; 2]>,
    /// Pixels of the blob over the pixels of the sphere's disc, 0..1.
    pub disc_share: f64,
    /// Noise σ of the image inside the disc, image units: 1.4826 · median |a − b| / √2 over
    /// horizontally and vertically adjacent pixels, at least one quantisation step / √12.
    pub noise: f32,
    /// (peak − background) / noise: how many σ the highlight stands above the sphere's median.
    pub significance: f64,
}

/// The outcome of the search in one image.
#[derive(Clone, Debug, PartialEq)]
pub enum HighlightSearch {
    /// A highlight was found.
    Found(Highlight),
    /// None was found; the reason says why.
    Missing(String),
}

/// Smallest grey value that counts as saturated for an image of `bit_depth` bits per sample
/// (integer images saturate at 1; float images are taken as unclipped).
pub fn saturation_level(bit_depth: u8) -> f32 {
    match bit_depth {
        8 => 254.5 / 255.0,
        16 => 65534.5 / 65535.0,
        _ => f32::INFINITY,
    }
}

/// Finds the specular highlight of `image` inside `circle`.
///
/// The peak is the brightest value reached by two adjacent pixels (a lone hot pixel cannot set
/// it); the blobs are the 8-connected regions above `level` (a fifth) of the way from the sphere's
/// median and that peak; blobs smaller than `min_blob_pixels` are dust; the highlight is the
/// blob of largest mass Σ(grey − threshold), and its position is the centroid weighted by
/// grey − threshold.
pub fn find_highlight(image: &Image, circle: &Circle, opts: &HighlightOptions) -> HighlightSearch {
    let (w, h) = (image.width, image.height);
    let r_in = circle.r;
    let row0 = ((circle.cy - r_in).floor().max(0.0)) as usize;
    let row1 = ((circle.cy + r_in).ceil().max(0.0) as usize).min(h.saturating_sub(1));
    let col0 = ((circle.cx - r_in).floor().max(0.0)) as usize;
    let col1 = ((circle.cx + r_in).ceil().max(0.0) as usize).min(w.saturating_sub(1));
    if row0 > row1 || col0 > col1 {
        return HighlightSearch::Missing("the sphere lies outside the image".into());
    }
    let bw = col1 - col0 + 1;
    let bh = row1 - row0 + 1;
    // Grey values in the sphere's bounding box; NaN outside the disc.
    let mut grey = vec![f32::NAN; bw * bh];
    let mut inside = Vec::with_capacity(bw * bh);
    for r in 0..bh {
        let dy = (row0 + r) as f64 - circle.cy;
        for c in 0..bw {
            let dx = (col0 + c) as f64 - circle.cx;
            if dx * dx + dy * dy <= r_in * r_in {
                let v = grey_at(image, (row0 + r) * w + col0 + c);
                grey[r * bw + c] = v;
                inside.push(v);
            }
        }
    }
    if inside.is_empty() {
        return HighlightSearch::Missing("the sphere's disc holds no pixel".into());
    }
    let disc_pixels = inside.len();
    let background = median(&mut inside);
    let noise = noise_sigma(&grey, bw, bh, image.bit_depth);
    // Robust peak: max over pixels of min(value, brightest 8-neighbour).
    let mut peak = f32::NEG_INFINITY;
    for r in 0..bh {
        for c in 0..bw {
            let v = grey[r * bw + c];
            if v.is_nan() {
                continue;
            }
            let mut nb = f32::NEG_INFINITY;
            for (dr, dc) in NEIGHBOURS {
                let (rr, cc) = (r as isize + dr, c as isize + dc);
                if rr >= 0 && cc >= 0 && (rr as usize) < bh && (cc as usize) < bw {
                    let u = grey[rr as usize * bw + cc as usize];
                    if u > nb {
                        nb = u;
                    }
                }
            }
            peak = peak.max(v.min(nb));
        }
    }
    let contrast = peak - background;
    if contrast.is_nan() || contrast < opts.min_contrast {
        return HighlightSearch::Missing(format!(
            "no highlight: the brightest spot ({:.3}) is only {:.3} above the sphere's median ({:.3}); \
             at least {:.3} expected",
            peak.max(background),
            (peak - background).max(0.0),
            background,
            opts.min_contrast
        ));
    }
    let threshold = background + opts.level * (peak - background);
    let above: Vec<bool> = grey.iter().map(|&v| v >= threshold).collect();
    let labels = label_regions(&above, bw, bh, true);
    let sat = saturation_level(image.bit_depth);
    #[derive(Clone, Copy, Default)]
    struct Blob {
        mass: f64,
        sx: f64,
        sy: f64,
        pixels: usize,
        saturated: usize,
    }
    let mut blobs = vec![Blob::default(); labels.count + 1];
    for r in 0..bh {
        for c in 0..bw {
            let l = labels.labels[r * bw + c] as usize;
            if l == 0 {
                continue;
            }
            let v = grey[r * bw + c];
            let wgt = (v - threshold) as f64 + 1e-6;
            let b = &mut blobs[l];
            b.mass += wgt;
            b.sx += wgt * (col0 + c) as f64;
            b.sy += wgt * (row0 + r) as f64;
            b.pixels += 1;
            if v >= sat {
                b.saturated += 1;
            }
        }
    }
    let mut order: Vec<usize> = (1..blobs.len())
        .filter(|&l| blobs[l].pixels >= opts.min_blob_pixels)
        .collect();
    if order.is_empty() {
        return HighlightSearch::Missing(format!(
            "no highlight: only isolated bright pixels (fewer than {} each; dust or hot pixels?)",
            opts.min_blob_pixels
        ));
    }
    order.sort_by(|&a, &b| blobs[b].mass.total_cmp(&blobs[a].mass));
    let best = blobs[order[0]];
    let (x, y) = (best.sx / best.mass, best.sy / best.mass);
    // Compactness: blob area over the disc about the centroid reaching its farthest pixel.
    let mut far2 = 0.0f64;
    for r in 0..bh {
        for c in 0..bw {
            if labels.labels[r * bw + c] as usize == order[0] {
                let d2 = ((col0 + c) as f64 - x).powi(2) + ((row0 + r) as f64 - y).powi(2);
                far2 = far2.max(d2);
            }
        }
    }
    let reach = far2.sqrt() + 0.5;
    let compactness = (best.pixels as f64 / (std::f64::consts::PI * reach * reach)).min(1.0);
    let (second_blob_share, second_blob) = match order.get(1) {
        Some(&l) => (
            blobs[l].mass / best.mass,
            Some([blobs[l].sx / blobs[l].mass, blobs[l].sy / blobs[l].mass]),
        ),
        None => (0.0, None),
    };
    HighlightSearch::Found(Highlight {
        x,
        y,
        peak,
        background,
        pixels: best.pixels,
        saturated: best.saturated,
        compactness,
        second_blob_share,
        second_blob,
        disc_share: best.pixels as f64 / disc_pixels as f64,
        noise,
        significance: ((peak - background) / noise) as f64,
    })
}

/// Noise σ of the grey values `grey` (a `bw` × `bh` box, NaN outside the disc): the robust σ
/// of the differences of horizontally and vertically adjacent pixels inside the disc divided
/// by √2 (1.4826 · median |a − b| / √2), which a smooth image hardly raises; at least the
/// quantisation noise of `bit_depth` (one step / √12; 10⁻⁶ for float images).
pub fn noise_sigma(grey: &[f32], bw: usize, bh: usize, bit_depth: u8) -> f32 {
    let mut diffs = Vec::with_capacity(2 * grey.len());
    for r in 0..bh {
        for c in 0..bw {
            let v = grey[r * bw + c];
            if v.is_nan() {
                continue;
            }
            if c + 1 < bw && !grey[r * bw + c + 1].is_nan() {
                diffs.push((v - grey[r * bw + c + 1]).abs());
            }
            if r + 1 < bh && !grey[(r + 1) * bw + c].is_nan() {
                diffs.push((v - grey[(r + 1) * bw + c]).abs());
            }
        }
    }
    let floor = match bit_depth {
        8 => 1.0 / (255.0 * 12f32.sqrt()),
        16 => 1.0 / (65535.0 * 12f32.sqrt()),
        _ => 1e-6,
    };
    if diffs.is_empty() {
        return floor;
    }
    (1.4826 * median(&mut diffs) / std::f32::consts::SQRT_2).max(floor)
}

const NEIGHBOURS: [(isize, isize); 8] = [
    (-1, -1),
    (-1, 0),
    (-1, 1),
    (0, -1),
    (0, 1),
    (1, -1),
    (1, 0),
    (1, 1),
];

fn median(v: &mut [f32]) -> f32 {
    let mid = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
    *m
}
