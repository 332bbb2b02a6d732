//! Figures of shadow maps: one labelled tile per light, cropped to the object.

use crate::geometry::shadows::ShadowMaps;
use crate::io::figure::{text_width, Canvas};

/// A montage of per-light binary maps (each `width * height`, row-major, true = shadowed):
/// a grid of tiles, each reduced by an integer factor to at most 128 px on a side (grey level =
/// share of shadowed pixels, white = lit, black = shadowed), labelled with the light's 1-based
/// index above it.
pub fn shadow_montage(maps: &[Vec<bool>], width: usize, height: usize) -> Canvas {
    shadow_montage_outlined(maps, None, width, height)
}

/// [`shadow_montage`] with the object drawn: with `mask`, each map is first cropped to the
/// object's bounding box (plus a small margin), tile pixels outside the object are blue-grey,
/// its border red, each label adds the share of the object in shadow (when the tile is wide
/// enough), and a legend line is added under the grid.
pub fn shadow_montage_outlined(
    maps: &[Vec<bool>],
    mask: Option<&[bool]>,
    width: usize,
    height: usize,
) -> Canvas {
    let shadowed = |k: usize, i: usize| maps[k].get(i).copied().unwrap_or(false);
    montage_of(maps.len(), &shadowed, mask, width, height)
}

/// [`shadow_montage_outlined`] of the union of each light's shadows of `maps`, read from the
/// bit planes (no per-light map is made).
pub fn shadow_maps_montage(maps: &ShadowMaps, mask: Option<&[bool]>) -> Canvas {
    let shadowed = |k: usize, i: usize| maps.is_shadowed(k, i);
    montage_of(maps.lights, &shadowed, mask, maps.width, maps.height)
}

/// The montage of `lights` maps of a `width × height` frame, `shadowed(k, i)` answering for
/// light `k` at pixel `i` (row-major); with a mask, cropped to the object's bounding box.
fn montage_of(
    lights: usize,
    shadowed: &dyn Fn(usize, usize) -> bool,
    mask: Option<&[bool]>,
    width: usize,
    height: usize,
) -> Canvas {
    let Some(m) = mask.filter(|m| m.len() == width * height) else {
        return montage(lights, shadowed, None, width, (0, 0, width, height));
    };
    let v = crate::io::maps::View::of_mask(m, width, height, usize::MAX);
    let window = (v.x0, v.y0, v.x1 - v.x0, v.y1 - v.y0);
    montage(lights, shadowed, Some(m), width, window)
}

/// The montage proper over the window `(x0, y0, width, height)` of a frame `frame_width`
/// pixels wide: `shadowed(k, i)` and `mask` are read at frame indices.
fn montage(
    lights: usize,
    shadowed: &dyn Fn(usize, usize) -> bool,
    mask: Option<&[bool]>,
    frame_width: usize,
    (wx, wy, width, height): (usize, usize, usize, usize),
) -> Canvas {
    // Frame index of window pixel (r, c).
    let at = |r: usize, c: usize| (wy + r) * frame_width + wx + c;
    const TILE_MAX: usize = 128;
    const GAP: usize = 6;
    const LABEL_H: usize = 11;
    let background = [200, 200, 210];
    if lights == 0 || width == 0 || height == 0 {
        return Canvas::new(1, 1, background);
    }
    let factor = width.max(height).div_ceil(TILE_MAX).max(1);
    let (tw, th) = (width.div_ceil(factor), height.div_ceil(factor));
    let cols = (lights as f64).sqrt().ceil() as usize;
    let rows = lights.div_ceil(cols);
    let cell_w = tw.max(text_width(&lights.to_string(), 1)) + GAP;
    let cell_h = th + LABEL_H + GAP;
    const LEGEND: &str = "black: shadow  white: lit  red: object outline";
    let legend_h = if mask.is_some() { LABEL_H + GAP } else { 0 };
    let mut canvas = Canvas::new(
        (cols * cell_w + GAP).max(text_width(LEGEND, 1) + 2 * GAP * mask.is_some() as usize),
        rows * cell_h + GAP + legend_h,
        background,
    );
    // Per tile pixel: how many of its frame pixels are inside the object.
    let inside: Option<Vec<(usize, usize)>> = mask.map(|m| {
        let mut v = vec![(0usize, 0usize); tw * th];
        for y in 0..th {
            for x in 0..tw {
                let (mut n, mut total) = (0, 0);
                for r in y * factor..((y + 1) * factor).min(height) {
                    for c in x * factor..((x + 1) * factor).min(width) {
                        total += 1;
                        n += m.get(at(r, c)).copied().unwrap_or(false) as usize;
                    }
                }
                v[y * tw + x] = (n, total);
            }
        }
        v
    });
    let object_pixels = mask.map(|m| {
        (0..height)
            .flat_map(|r| (0..width).map(move |c| (r, c)))
            .filter(|&(r, c)| m[at(r, c)])
            .count()
    });
    let outline = |x: usize, y: usize, v: &[(usize, usize)]| {
        let (n, total) = v[y * tw + x];
        if n == 0 {
            return false;
        }
        let out = |xx: usize, yy: usize| v[yy * tw + xx].0 == 0;
        n < total
            || x == 0
            || y == 0
            || x + 1 == tw
            || y + 1 == th
            || out(x - 1, y)
            || out(x + 1, y)
            || out(x, y - 1)
            || out(x, y + 1)
    };
    for k in 0..lights {
        let x0 = GAP + (k % cols) * cell_w;
        let y0 = GAP + (k / cols) * cell_h;
        let mut label = (k + 1).to_string();
        if let (Some(m), Some(total)) = (mask, object_pixels) {
            let in_shadow = (0..height)
                .flat_map(|r| (0..width).map(move |c| at(r, c)))
                .filter(|&i| m[i] && shadowed(k, i))
                .count();
            let with_share = format!(
                "{label} {:.0}%",
                100.0 * in_shadow as f64 / total.max(1) as f64
            );
            if text_width(&with_share, 1) <= tw {
                label = with_share;
            }
        }
        canvas.text(x0, y0, &label, 1, [0, 0, 0]);
        let ty = y0 + LABEL_H;
        for y in 0..th {
            for x in 0..tw {
                if let Some(v) = &inside {
                    if v[y * tw + x].0 == 0 {
                        canvas.put(x0 + x, ty + y, [225, 228, 240]);
                        continue;
                    }
                    if outline(x, y, v) {
                        canvas.put(x0 + x, ty + y, [215, 40, 40]);
                        continue;
                    }
                }
                let (mut dark, mut total) = (0usize, 0usize);
                for r in y * factor..((y + 1) * factor).min(height) {
                    for c in x * factor..((x + 1) * factor).min(width) {
                        total += 1;
                        if shadowed(k, at(r, c)) {
                            dark += 1;
                        }
                    }
                }
                let g = 255 - (255 * dark / total.max(1)) as u8;
                canvas.put(x0 + x, ty + y, [g, g, g]);
            }
        }
    }
    if mask.is_some() {
        canvas.text(GAP, rows * cell_h + GAP, LEGEND, 1, [0, 0, 0]);
    }
    canvas
}
