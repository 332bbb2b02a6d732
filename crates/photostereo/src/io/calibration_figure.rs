//! The calibration figure: one thumbnail per image, cropped around the sphere, with the fitted
//! circle (green), the highlight (red cross), the image number, the confidence and any warning.

use crate::calibrate::{Calibration, WarningKind};
use crate::io::figure::Canvas;
use crate::model::image::Image;

/// Side of one thumbnail, pixels.
const TILE: usize = 200;
/// Height of the caption under a thumbnail, pixels.
const CAPTION: usize = 22;
/// Gap between tiles, pixels.
const GAP: usize = 6;

/// A montage of thumbnails (four per row) of `images`, each cropped to the sphere's
/// neighbourhood and brightened with a gamma of 1/2.2 so that a dark mirror sphere shows.
pub fn calibration_figure(images: &[Image], cal: &Calibration) -> Canvas {
    let n = images.len().max(1);
    let cols = n.min(4);
    let rows = n.div_ceil(cols);
    let mut canvas = Canvas::new(
        cols * (TILE + GAP) + GAP,
        rows * (TILE + CAPTION + GAP) + GAP,
        [255, 255, 255],
    );
    let c = cal.sphere.circle;
    let half = 1.2 * c.r;
    let (x0, y0) = (c.cx - half, c.cy - half);
    let scale = 2.0 * half / TILE as f64; // image pixels per thumbnail pixel
    for (k, img) in images.iter().enumerate() {
        let (tx, ty) = (
            GAP + (k % cols) * (TILE + GAP),
            GAP + (k / cols) * (TILE + CAPTION + GAP),
        );
        let mut tile = Canvas::new(TILE, TILE, [60, 60, 60]);
        let mut vmax = 1e-6f32;
        let mut values = vec![f32::NAN; TILE * TILE];
        for ty_ in 0..TILE {
            let row = (y0 + (ty_ as f64 + 0.5) * scale).floor();
            for tx_ in 0..TILE {
                let col = (x0 + (tx_ as f64 + 0.5) * scale).floor();
                if row < 0.0 || col < 0.0 || row >= img.height as f64 || col >= img.width as f64 {
                    continue;
                }
                let v = img.grey(row as usize, col as usize);
                vmax = vmax.max(v);
                values[ty_ * TILE + tx_] = v;
            }
        }
        for (i, v) in values.iter().enumerate() {
            if v.is_nan() {
                continue;
            }
            let g = ((v / vmax).clamp(0.0, 1.0).powf(1.0 / 2.2) * 255.0).round() as u8;
            tile.put(i % TILE, i / TILE, [g, g, g]);
        }
        // The fitted circle.
        let steps = (2.0 * std::f64::consts::PI * c.r / scale * 2.0).ceil() as usize + 8;
        for s in 0..steps {
            let a = s as f64 / steps as f64 * std::f64::consts::TAU;
            let (px, py) = (
                (c.cx + c.r * a.cos() - x0) / scale,
                (c.cy + c.r * a.sin() - y0) / scale,
            );
            if px >= 0.0 && py >= 0.0 {
                tile.put(px as usize, py as usize, [40, 220, 60]);
            }
        }
        let light = &cal.lights[k];
        if let Some(h) = light.highlight {
            let (px, py) = ((h.x - x0) / scale, (h.y - y0) / scale);
            for d in -7i64..=7 {
                for (xx, yy) in [(px + d as f64, py), (px, py + d as f64)] {
                    if xx >= 0.0 && yy >= 0.0 && d.abs() > 1 {
                        tile.put(xx as usize, yy as usize, [255, 40, 40]);
                    }
                }
            }
        }
        canvas.blit(&tile, tx, ty);
        let label = format!("{} C={:.2}", k + 1, light.confidence);
        let w = canvas.text(tx, ty + TILE + 4, &label, 1, [0, 0, 0]);
        let flags: Vec<&str> = cal
            .warnings
            .iter()
            .filter(|wn| wn.image == Some(k))
            .map(|wn| match wn.kind {
                WarningKind::Missing => "MISSING",
                WarningKind::Doubled => "DOUBLED",
                WarningKind::Clipped => "CLIPPED",
                WarningKind::NearRim => "RIM",
                WarningKind::SphereCut => "CUT",
                WarningKind::RoughOutline => "ROUGH",
                WarningKind::MaskOffSphere => "MASK OFF",
                WarningKind::NotMirror => "BROAD",
                WarningKind::Faint => "FAINT",
                WarningKind::LowConfidence => "LOW",
            })
            .collect();
        if !flags.is_empty() {
            canvas.text(tx + w + 6, ty + TILE + 4, &flags.join(" "), 1, [220, 90, 0]);
        }
    }
    canvas
}
