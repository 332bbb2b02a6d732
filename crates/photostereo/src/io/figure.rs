//! Small raster figures without external fonts: an RGB canvas, a perceptual colour map, a 5×7
//! bitmap font for numbers and short labels, and the angular-error map with its scale bar.

use crate::base::error::Result;
use crate::io::imageio::write_png8;
use std::path::Path;

/// An 8-bit RGB raster, row 0 at the top.
#[derive(Clone, Debug)]
pub struct Canvas {
    pub width: usize,
    pub height: usize,
    pub data: Vec<u8>,
}

impl Canvas {
    /// A canvas filled with `background`.
    pub fn new(width: usize, height: usize, background: [u8; 3]) -> Self {
        let data = background.repeat(width * height);
        Canvas {
            width,
            height,
            data,
        }
    }

    /// Sets one pixel (ignored outside the canvas).
    #[inline]
    pub fn put(&mut self, x: usize, y: usize, rgb: [u8; 3]) {
        if x < self.width && y < self.height {
            let i = (y * self.width + x) * 3;
            self.data[i..i + 3].copy_from_slice(&rgb);
        }
    }

    /// Fills a rectangle.
    pub fn fill_rect(&mut self, x: usize, y: usize, w: usize, h: usize, rgb: [u8; 3]) {
        for yy in y..(y + h).min(self.height) {
            for xx in x..(x + w).min(self.width) {
                self.put(xx, yy, rgb);
            }
        }
    }

    /// Copies another canvas with its top-left corner at (x, y).
    pub fn blit(&mut self, src: &Canvas, x: usize, y: usize) {
        // Row by row, clipped to this canvas (what `put` per pixel would keep).
        if x >= self.width {
            return;
        }
        let w = src.width.min(self.width - x);
        for yy in 0..src.height.min(self.height.saturating_sub(y)) {
            let s = yy * src.width * 3;
            let d = ((y + yy) * self.width + x) * 3;
            self.data[d..d + w * 3].copy_from_slice(&src.data[s..s + w * 3]);
        }
    }

    /// Draws `text` with the built-in 5×7 font scaled by `scale`, top-left at (x, y).
    /// Returns the width drawn. Characters without a glyph are drawn as spaces.
    pub fn text(&mut self, x: usize, y: usize, text: &str, scale: usize, rgb: [u8; 3]) -> usize {
        let mut cx = x;
        for ch in text.chars() {
            if let Some(rows) = glyph(ch) {
                for (ry, bits) in rows.iter().enumerate() {
                    for rx in 0..5 {
                        if bits & (1 << (4 - rx)) != 0 {
                            self.fill_rect(cx + rx * scale, y + ry * scale, scale, scale, rgb);
                        }
                    }
                }
            }
            cx += 6 * scale;
        }
        cx - x
    }

    /// Writes the canvas as an 8-bit RGB PNG.
    pub fn save(&self, path: &Path) -> Result<()> {
        write_png8(path, self.width, self.height, 3, &self.data)
    }
}

/// Width in pixels of `text` drawn at `scale`.
pub fn text_width(text: &str, scale: usize) -> usize {
    text.chars().count() * 6 * scale
}

/// A perceptually ordered colour map (dark blue → green → yellow) for t in [0, 1].
pub fn colormap(t: f32) -> [u8; 3] {
    const STOPS: [[f32; 3]; 9] = [
        [68.0, 1.0, 84.0],
        [71.0, 44.0, 122.0],
        [59.0, 81.0, 139.0],
        [44.0, 113.0, 142.0],
        [33.0, 144.0, 141.0],
        [39.0, 173.0, 129.0],
        [92.0, 200.0, 99.0],
        [170.0, 220.0, 50.0],
        [253.0, 231.0, 37.0],
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let x = t * (STOPS.len() - 1) as f32;
    // x ≥ 0: truncation is the floor.
    let i = (x as usize).min(STOPS.len() - 2);
    let f = x - i as f32;
    let mut out = [0u8; 3];
    for c in 0..3 {
        out[c] = round_u8(STOPS[i][c] * (1.0 - f) + STOPS[i + 1][c] * f);
    }
    out
}

/// `x.round() as u8` (half away from zero, saturating, NaN to 0) without a libm call: below
/// 2^23 the fraction x − trunc(x) of a non-negative x is exact.
#[inline]
pub fn round_u8(x: f32) -> u8 {
    let whole = x as u32; // truncation, saturating (0 for negatives and NaN)
    let up = x - whole as f32 >= 0.5;
    whole.saturating_add(up as u32).min(255) as u8
}

/// Renders per-pixel values (NaN = no data, drawn dark grey) with the colour map over
/// [0, `max`], with a vertical scale bar labelled in `unit` on the right.
pub fn heat_map(values: &[f32], width: usize, height: usize, max: f32, unit: &str) -> Canvas {
    let scale = if height >= 300 { 2 } else { 1 };
    let label = format!("{}{unit}", fmt_tick(max));
    let panel = 24 * scale + text_width(&label, scale) + 8 * scale;
    let mut c = Canvas::new(width + panel, height.max(60 * scale), [255, 255, 255]);
    for y in 0..height {
        for x in 0..width {
            let v = values[y * width + x];
            let rgb = if v.is_nan() {
                [40, 40, 40]
            } else {
                colormap(v / max)
            };
            c.put(x, y, rgb);
        }
    }
    // The bar: top = max, bottom = 0.
    let bar_x = width + 6 * scale;
    let bar_w = 10 * scale;
    let top = 6 * scale;
    let bottom = c.height - 6 * scale;
    let span = bottom - top;
    for y in top..bottom {
        let t = 1.0 - (y - top) as f32 / (span - 1).max(1) as f32;
        c.fill_rect(bar_x, y, bar_w, 1, colormap(t));
    }
    // Ticks on the bar's left edge: a tick right before a label would read as a minus sign.
    let tx = bar_x + bar_w + 4 * scale;
    for (frac, value) in [(0.0f32, max), (0.5, max / 2.0), (1.0, 0.0)] {
        let y = top + (frac * (span - 1) as f32) as usize;
        // The tick mark on the bar's left side: on the right it would read as a minus sign.
        c.fill_rect(bar_x - 3 * scale, y, 3 * scale, scale, [0, 0, 0]);
        let ty = y.saturating_sub(3 * scale).min(c.height - 7 * scale);
        c.text(
            tx,
            ty,
            &format!("{}{unit}", fmt_tick(value)),
            scale,
            [0, 0, 0],
        );
    }
    c
}

fn fmt_tick(v: f32) -> String {
    if (v - v.round()).abs() < 1e-3 {
        format!("{}", v.round() as i64)
    } else {
        format!("{v:.1}")
    }
}

/// Colour-mapped angular-error PNG in degrees with a scale bar from 0 to `max_deg`.
pub fn write_error_map(
    path: &Path,
    errors_deg: &[f32],
    width: usize,
    height: usize,
    max_deg: f32,
) -> Result<()> {
    heat_map(errors_deg, width, height, max_deg, "°").save(path)
}

/// Encodes unit normals as an 8-bit RGB picture ((n + 1) / 2), black where zero.
pub fn normals_picture(normals: &[[f32; 3]], width: usize, height: usize) -> Canvas {
    let mut c = Canvas::new(width, height, [0, 0, 0]);
    for (i, n) in normals.iter().enumerate() {
        if *n != [0.0; 3] {
            c.put(
                i % width,
                i / width,
                n.map(|v| round_u8(((v + 1.0) * 0.5).clamp(0.0, 1.0) * 255.0)),
            );
        }
    }
    c
}

/// Greys in [0, 1] (values above 1 clip) as an RGB canvas.
pub fn grey_picture(values: &[f32], width: usize, height: usize) -> Canvas {
    let mut c = Canvas::new(width, height, [0, 0, 0]);
    for (i, v) in values.iter().enumerate() {
        let g = round_u8(v.clamp(0.0, 1.0) * 255.0);
        c.put(i % width, i / width, [g, g, g]);
    }
    c
}

/// 5×7 glyphs, one byte per row, bit 4 = leftmost column.
fn glyph(ch: char) -> Option<[u8; 7]> {
    Some(match ch.to_ascii_uppercase() {
        '0' => [0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E],
        '1' => [0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E],
        '2' => [0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F],
        '3' => [0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E],
        '4' => [0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02],
        '5' => [0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E],
        '6' => [0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E],
        '7' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08],
        '8' => [0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E],
        '9' => [0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C],
        '.' => [0x00, 0x00, 0x00, 0x00, 0x00, 0x0C, 0x0C],
        '-' => [0x00, 0x00, 0x00, 0x1F, 0x00, 0x00, 0x00],
        '%' => [0x18, 0x19, 0x02, 0x04, 0x08, 0x13, 0x03],
        '°' => [0x0C, 0x12, 0x12, 0x0C, 0x00, 0x00, 0x00],
        ':' => [0x00, 0x0C, 0x0C, 0x00, 0x0C, 0x0C, 0x00],
        '/' => [0x01, 0x01, 0x02, 0x04, 0x08, 0x10, 0x10],
        '(' => [0x02, 0x04, 0x08, 0x08, 0x08, 0x04, 0x02],
        ')' => [0x08, 0x04, 0x02, 0x02, 0x02, 0x04, 0x08],
        '=' => [0x00, 0x00, 0x1F, 0x00, 0x1F, 0x00, 0x00],
        '+' => [0x00, 0x04, 0x04, 0x1F, 0x04, 0x04, 0x00],
        ',' => [0x00, 0x00, 0x00, 0x00, 0x0C, 0x04, 0x08],
        '<' => [0x02, 0x04, 0x08, 0x10, 0x08, 0x04, 0x02],
        '>' => [0x08, 0x04, 0x02, 0x01, 0x02, 0x04, 0x08],
        'A' => [0x0E, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11],
        'B' => [0x1E, 0x11, 0x11, 0x1E, 0x11, 0x11, 0x1E],
        'C' => [0x0E, 0x11, 0x10, 0x10, 0x10, 0x11, 0x0E],
        'D' => [0x1C, 0x12, 0x11, 0x11, 0x11, 0x12, 0x1C],
        'E' => [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x1F],
        'F' => [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x10],
        'G' => [0x0E, 0x11, 0x10, 0x17, 0x11, 0x11, 0x0F],
        'H' => [0x11, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11],
        'I' => [0x0E, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E],
        'J' => [0x07, 0x02, 0x02, 0x02, 0x02, 0x12, 0x0C],
        'K' => [0x11, 0x12, 0x14, 0x18, 0x14, 0x12, 0x11],
        'L' => [0x10, 0x10, 0x10, 0x10, 0x10, 0x10, 0x1F],
        'M' => [0x11, 0x1B, 0x15, 0x15, 0x11, 0x11, 0x11],
        'N' => [0x11, 0x11, 0x19, 0x15, 0x13, 0x11, 0x11],
        'O' => [0x0E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E],
        'P' => [0x1E, 0x11, 0x11, 0x1E, 0x10, 0x10, 0x10],
        'Q' => [0x0E, 0x11, 0x11, 0x11, 0x15, 0x12, 0x0D],
        'R' => [0x1E, 0x11, 0x11, 0x1E, 0x14, 0x12, 0x11],
        'S' => [0x0F, 0x10, 0x10, 0x0E, 0x01, 0x01, 0x1E],
        'T' => [0x1F, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04],
        'U' => [0x11, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E],
        'V' => [0x11, 0x11, 0x11, 0x11, 0x11, 0x0A, 0x04],
        'W' => [0x11, 0x11, 0x11, 0x15, 0x15, 0x15, 0x0A],
        'X' => [0x11, 0x11, 0x0A, 0x04, 0x0A, 0x11, 0x11],
        'Y' => [0x11, 0x11, 0x11, 0x0A, 0x04, 0x04, 0x04],
        'Z' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x10, 0x1F],
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_u8_is_f32_round_then_a_saturating_cast() {
        let mut values = vec![
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            -0.0,
            -0.5,
            -0.7,
            1e9,
        ];
        for k in 0..=300u32 {
            let x = k as f32;
            values.extend([x, x + 0.5, x - 0.5, x + 0.49999997, x + 0.25, x + 0.75]);
            values.extend([
                f32::from_bits((x + 0.5).to_bits() - 1),
                f32::from_bits((x + 0.5).to_bits() + 1),
            ]);
        }
        for k in 0..100_000u32 {
            values.push(k as f32 * 0.002_551);
        }
        for v in values {
            assert_eq!(round_u8(v), v.round() as u8, "{v:?}");
        }
    }

    #[test]
    fn colormap_is_monotone_in_lightness() {
        let l = |t: f32| {
            let c = colormap(t);
            0.2126 * c[0] as f32 + 0.7152 * c[1] as f32 + 0.0722 * c[2] as f32
        };
        let mut prev = l(0.0);
        for i in 1..=20 {
            let cur = l(i as f32 / 20.0);
            assert!(cur > prev, "lightness must increase");
            prev = cur;
        }
    }

    #[test]
    fn heat_map_has_bar_and_labels() {
        let vals = vec![0.0f32, 45.0, f32::NAN, 22.5];
        let c = heat_map(&vals, 2, 2, 45.0, "°");
        assert!(c.width > 2 && c.height >= 60);
        let px = |x: usize, y: usize| {
            [
                c.data[(y * c.width + x) * 3],
                c.data[(y * c.width + x) * 3 + 1],
                c.data[(y * c.width + x) * 3 + 2],
            ]
        };
        assert_eq!(px(0, 0), colormap(0.0));
        assert_eq!(px(1, 0), colormap(1.0));
        assert_eq!(px(0, 1), [40, 40, 40]);
        // Some black label pixels exist in the panel.
        let dark = (0..c.height)
            .flat_map(|y| (2..c.width).map(move |x| (x, y)))
            .filter(|&(x, y)| px(x, y) == [0, 0, 0])
            .count();
        assert!(dark > 20);
    }

    #[test]
    fn scale_labels_have_no_dash_before_them() {
        // Nothing black between the bar and its labels: a tick there reads as "-45°".
        let c = heat_map(&[0.0; 100], 10, 10, 45.0, "°");
        let (bar_x, bar_w) = (10 + 6, 10);
        for y in 0..c.height {
            for x in bar_x + bar_w..bar_x + bar_w + 4 {
                let i = (y * c.width + x) * 3;
                assert_ne!(&c.data[i..i + 3], &[0, 0, 0], "black at ({x}, {y})");
            }
        }
    }
}
