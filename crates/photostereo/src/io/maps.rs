//! Maps that read at a glance on real captures: figures cropped to the object, outlined, with
//! colour bars and titles. Built on [`crate::io::figure`]'s canvas and font.
//!
//! - [`View`]: the object's bounding box (plus a margin), reduced by an integer factor so the
//!   longer side fits a panel size; every panel of a figure shares one view.
//! - Panels: [`View::colour_panel`] (any per-pixel colour), [`View::heat_panel`] (values on the
//!   colour map), [`View::binary_panel`] (a per-pixel flag, black on white, outlined),
//!   [`shaded_depth_panel`] (a height field lit by a raking light).
//! - Legends: [`colour_bar`] (vertical, ticks on the left of the bar so no tick reads as a
//!   minus sign), [`titled`] (a panel with a title strip above it), [`Grid`] (rows of panels
//!   under column headings, each row with a caption).
//! - Files of a run: [`unreliable_figure`] (the paper's Fig. 6a with a scale) and
//!   [`unusable_lights_figure`] (lights in shadow, in highlight and unusable per pixel).

use crate::base::error::Result;
use crate::io::figure::{colormap, text_width, Canvas};
use crate::method::engine::Reconstruction;
use crate::method::statusmap::StatusMap;
use crate::solve::lambert::status;
use std::path::Path;

/// Text colour.
pub const INK: [u8; 3] = [0, 0, 0];
/// Background of figures.
pub const PAPER: [u8; 3] = [255, 255, 255];
/// Outside the object in panels.
pub const OUTSIDE: [u8; 3] = [200, 200, 210];
/// The object's outline.
pub const OUTLINE: [u8; 3] = [215, 40, 40];

/// A crop of the frame (the object's bounding box with a margin) and a reduction factor.
#[derive(Clone, Debug)]
pub struct View {
    /// Frame size.
    pub width: usize,
    pub height: usize,
    /// The crop: columns x0..x1, rows y0..y1 of the frame.
    pub x0: usize,
    pub y0: usize,
    pub x1: usize,
    pub y1: usize,
    /// Each panel pixel averages factor × factor frame pixels.
    pub factor: usize,
    /// The frame's mask, for outlines and the outside colour.
    pub mask: Vec<bool>,
}

impl View {
    /// The mask's bounding box with a margin of 4% of its size (at least 2 pixels), reduced by
    /// the smallest integer factor that brings its longer side to at most `max_side` pixels.
    /// An empty mask gives the whole frame.
    pub fn of_mask(mask: &[bool], width: usize, height: usize, max_side: usize) -> View {
        let (mut x0, mut y0, mut x1, mut y1) = (width, height, 0, 0);
        for (i, _) in mask.iter().enumerate().filter(|(_, &m)| m) {
            let (r, c) = (i / width, i % width);
            x0 = x0.min(c);
            x1 = x1.max(c + 1);
            y0 = y0.min(r);
            y1 = y1.max(r + 1);
        }
        if x0 >= x1 {
            (x0, y0, x1, y1) = (0, 0, width, height);
        }
        let margin = ((x1 - x0).max(y1 - y0) / 25).max(2);
        let (x0, y0) = (x0.saturating_sub(margin), y0.saturating_sub(margin));
        let (x1, y1) = ((x1 + margin).min(width), (y1 + margin).min(height));
        let side = (x1 - x0).max(y1 - y0);
        let factor = side.div_ceil(max_side.max(1)).max(1);
        View {
            width,
            height,
            x0,
            y0,
            x1,
            y1,
            factor,
            mask: mask.to_vec(),
        }
    }

    /// Panel size in pixels.
    pub fn size(&self) -> (usize, usize) {
        (
            (self.x1 - self.x0).div_ceil(self.factor),
            (self.y1 - self.y0).div_ceil(self.factor),
        )
    }

    /// Frame indices averaged into panel pixel (px, py).
    fn block(&self, px: usize, py: usize) -> impl Iterator<Item = usize> + '_ {
        let (r0, c0) = (self.y0 + py * self.factor, self.x0 + px * self.factor);
        let (r1, c1) = (
            (r0 + self.factor).min(self.y1),
            (c0 + self.factor).min(self.x1),
        );
        (r0..r1).flat_map(move |r| (c0..c1).map(move |c| r * self.width + c))
    }

    /// A panel whose pixels average `colour(i)` over the frame pixels i inside the mask; a
    /// panel pixel with no mask pixel is [`OUTSIDE`]. With `outline`, the mask's border is
    /// drawn in [`OUTLINE`].
    pub fn colour_panel(&self, outline: bool, colour: impl Fn(usize) -> [u8; 3]) -> Canvas {
        let (w, h) = self.size();
        let mut c = Canvas::new(w, h, OUTSIDE);
        let mut inside = vec![0u8; w * h]; // 0 none, 1 partly, 2 fully inside
        if self.factor == 1 {
            // One frame pixel per panel pixel: its colour as it is (the mean of one).
            for py in 0..h {
                let row = (self.y0 + py) * self.width + self.x0;
                for px in 0..w {
                    let i = row + px;
                    if self.mask[i] {
                        let o = (py * w + px) * 3;
                        c.data[o..o + 3].copy_from_slice(&colour(i));
                        inside[py * w + px] = 2;
                    }
                }
            }
        } else {
            for py in 0..h {
                for px in 0..w {
                    let (mut sum, mut n, mut total) = ([0u32; 3], 0u32, 0u32);
                    for i in self.block(px, py) {
                        total += 1;
                        if self.mask[i] {
                            let v = colour(i);
                            for k in 0..3 {
                                sum[k] += v[k] as u32;
                            }
                            n += 1;
                        }
                    }
                    if n > 0 {
                        c.put(px, py, sum.map(|s| ((s + n / 2) / n) as u8));
                        inside[py * w + px] = if n == total { 2 } else { 1 };
                    }
                }
            }
        }
        if outline {
            for py in 0..h {
                for px in 0..w {
                    let v = inside[py * w + px];
                    if v == 0 {
                        continue;
                    }
                    let edge = v == 1
                        || px == 0
                        || py == 0
                        || px + 1 == w
                        || py + 1 == h
                        || inside[py * w + px - 1] == 0
                        || inside[py * w + px + 1] == 0
                        || inside[(py - 1) * w + px] == 0
                        || inside[(py + 1) * w + px] == 0;
                    if edge {
                        c.put(px, py, OUTLINE);
                    }
                }
            }
        }
        c
    }

    /// Values on the colour map over [0, `max`]; NaN drawn dark grey.
    pub fn heat_panel(&self, values: &[f32], max: f32) -> Canvas {
        self.heat_panel_by(|i| values[i], max)
    }

    /// [`View::heat_panel`] of the values `value(i)` at frame pixels `i`.
    pub fn heat_panel_by(&self, value: impl Fn(usize) -> f32, max: f32) -> Canvas {
        self.colour_panel(false, |i| {
            let v = value(i);
            if v.is_nan() {
                [40, 40, 40]
            } else {
                colormap(v / max)
            }
        })
    }

    /// A per-pixel flag: black where set, white elsewhere inside the mask, outlined.
    pub fn binary_panel(&self, flags: impl Fn(usize) -> bool) -> Canvas {
        self.colour_panel(true, |i| if flags(i) { [0, 0, 0] } else { [255; 3] })
    }

    /// Unit normals as (n + 1) / 2 colours.
    pub fn normals_panel(&self, normals: &[[f32; 3]]) -> Canvas {
        self.colour_panel(false, |i| {
            let n = normals[i];
            if n == [0.0; 3] {
                [0, 0, 0]
            } else {
                n.map(|v| crate::io::figure::round_u8(((v + 1.0) * 0.5).clamp(0.0, 1.0) * 255.0))
            }
        })
    }
}

/// The direction of the raking light of [`shaded_depth_panel`]: from the upper left, 65° from
/// the viewing direction (camera frame: x right, y up, z toward the camera).
pub const RAKING_LIGHT: [f64; 3] = [-0.640_856, 0.640_856, 0.422_618];

/// A height field (pixel units toward the camera, NaN where unknown) shaded as a matte grey
/// surface under `light` (a unit vector toward the light), 10% ambient: the relief of the
/// reconstructed surface, as the paper's Figs. 8–12 show it. Slopes are central differences
/// (one-sided at the border of the known region); pixels without a slope are dark grey.
pub fn shaded_depth_panel(view: &View, depth: &[f32], light: [f64; 3]) -> Canvas {
    let (w, h) = (view.width, view.height);
    let at = |r: isize, c: isize| -> Option<f64> {
        if r < 0 || c < 0 || r as usize >= h || c as usize >= w {
            return None;
        }
        let i = r as usize * w + c as usize;
        let v = depth[i];
        (view.mask[i] && v.is_finite()).then_some(v as f64)
    };
    let slope = |r: isize, c: isize, dr: isize, dc: isize| -> Option<f64> {
        let here = at(r, c)?;
        match (at(r - dr, c - dc), at(r + dr, c + dc)) {
            (Some(a), Some(b)) => Some((b - a) / 2.0),
            (None, Some(b)) => Some(b - here),
            (Some(a), None) => Some(here - a),
            (None, None) => None,
        }
    };
    view.colour_panel(false, |i| {
        let (r, c) = ((i / w) as isize, (i % w) as isize);
        match (slope(r, c, 0, 1), slope(r, c, 1, 0)) {
            (Some(dcol), Some(drow)) => {
                // ∂f/∂col = −n_x/n_z, ∂f/∂row = +n_y/n_z.
                let n = [-dcol, drow, 1.0];
                let len = (n[0] * n[0] + n[1] * n[1] + 1.0).sqrt();
                let s = (n[0] * light[0] + n[1] * light[1] + n[2] * light[2]) / len;
                let g = (0.1 + 0.9 * s.max(0.0)).clamp(0.0, 1.0);
                let v = (g * 255.0).round() as u8;
                [v, v, v]
            }
            _ => [40, 40, 40],
        }
    })
}

/// Rounds `v` up to a "nice" scale end: 1, 2, 2.5, 3, 5 or 10 times a power of ten.
pub fn nice_ceil(v: f32) -> f32 {
    if !(v.is_finite() && v > 0.0) {
        return 1.0;
    }
    let p = 10f32.powf(v.log10().floor());
    for m in [1.0, 2.0, 2.5, 3.0, 5.0, 10.0] {
        if v <= m * p * (1.0 + 1e-6) {
            return m * p;
        }
    }
    10.0 * p
}

/// A number for a tick label: integers without decimals, else one or two decimals.
pub fn tick_label(v: f32) -> String {
    if (v - v.round()).abs() < 1e-3 {
        format!("{}", v.round() as i64)
    } else if (v * 10.0 - (v * 10.0).round()).abs() < 1e-3 {
        format!("{v:.1}")
    } else {
        format!("{v:.2}")
    }
}

/// A vertical colour bar `height` pixels tall for values 0..`max` (top = max), drawn with
/// `colour(t)` for t in [0, 1], labelled at `ticks` (value, label) and with `title` above.
/// Tick marks sit on the bar's left side, labels on its right: no mark touches a label.
pub fn colour_bar(
    height: usize,
    max: f32,
    ticks: &[(f32, String)],
    title: &str,
    scale: usize,
    colour: &dyn Fn(f32) -> [u8; 3],
) -> Canvas {
    let label_w = ticks
        .iter()
        .map(|(_, l)| text_width(l, scale))
        .max()
        .unwrap_or(0);
    let bar_w = 12 * scale;
    let title_h = if title.is_empty() { 0 } else { 11 * scale };
    let width = (4 * scale + bar_w + 4 * scale + label_w + 2 * scale).max(text_width(title, scale));
    let height = height.max(title_h + 40 * scale);
    let mut c = Canvas::new(width, height, PAPER);
    if !title.is_empty() {
        c.text(0, 0, title, scale, INK);
    }
    let top = title_h + 4 * scale;
    let bottom = height - 4 * scale;
    let span = (bottom - top).max(2);
    let bar_x = 4 * scale;
    for y in top..bottom {
        let t = 1.0 - (y - top) as f32 / (span - 1) as f32;
        c.fill_rect(bar_x, y, bar_w, 1, colour(t));
    }
    let tx = bar_x + bar_w + 4 * scale;
    for (value, label) in ticks {
        let t = if max > 0.0 {
            (value / max).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let y = top + ((1.0 - t) * (span - 1) as f32).round() as usize;
        c.fill_rect(0, y, bar_x, scale, INK);
        let ty = y.saturating_sub(3 * scale).min(height - 7 * scale);
        c.text(tx, ty, label, scale, INK);
    }
    c
}

/// Steps that divide a [`nice_ceil`] scale end into round tick values (1 → 2, 2 → 4, 2.5 → 5,
/// 3 → 3, 5 → 5, 10 → 5 times a power of ten).
pub fn nice_steps(max: f32) -> usize {
    if !(max.is_finite() && max > 0.0) {
        return 1;
    }
    let m = max / 10f32.powf(max.log10().floor());
    [(1.0, 2), (2.0, 4), (2.5, 5), (3.0, 3), (5.0, 5), (10.0, 5)]
        .iter()
        .find(|(v, _)| (m - v).abs() < 1e-3)
        .map_or(4, |&(_, s)| s)
}

/// Evenly spaced ticks 0, max/k, …, max for a bar, labelled with `unit` appended.
pub fn even_ticks(max: f32, steps: usize, unit: &str) -> Vec<(f32, String)> {
    (0..=steps)
        .map(|i| {
            let v = max * i as f32 / steps as f32;
            (v, format!("{}{unit}", tick_label(v)))
        })
        .collect()
}

/// A panel with `title` in a strip above it (text scale `scale`).
pub fn titled(panel: &Canvas, title: &str, scale: usize) -> Canvas {
    let strip = 11 * scale;
    let mut c = Canvas::new(
        panel.width.max(text_width(title, scale)),
        panel.height + strip,
        PAPER,
    );
    c.text(0, 2 * scale, title, scale, INK);
    c.blit(panel, 0, strip);
    c
}

/// Panels side by side with a gap, tops aligned.
pub fn hstack(panels: &[Canvas], gap: usize) -> Canvas {
    let w = panels.iter().map(|p| p.width).sum::<usize>() + gap * panels.len().saturating_sub(1);
    let h = panels.iter().map(|p| p.height).max().unwrap_or(1);
    let mut c = Canvas::new(w.max(1), h, PAPER);
    let mut x = 0;
    for p in panels {
        c.blit(p, x, 0);
        x += p.width + gap;
    }
    c
}

/// A figure: a title, column headings, then rows of panels each under its caption.
#[derive(Clone, Debug, Default)]
pub struct Grid {
    pub title: Vec<String>,
    pub headings: Vec<String>,
    /// The headings are drawn just above this row (0: above the first).
    pub headings_at: usize,
    pub rows: Vec<(String, Vec<Canvas>)>,
    /// Drawn under the rows (legends).
    pub footer: Vec<Canvas>,
    /// Text scale (1 or 2).
    pub scale: usize,
}

impl Grid {
    /// Lays the figure out: column widths are the widest panel of each column.
    pub fn render(&self) -> Canvas {
        let s = self.scale.max(1);
        let gap = 6 * s;
        let line = 11 * s;
        let ncol = self
            .rows
            .iter()
            .map(|(_, p)| p.len())
            .max()
            .unwrap_or(0)
            .max(self.headings.len());
        let mut col_w = vec![0usize; ncol];
        for (_, panels) in &self.rows {
            for (j, p) in panels.iter().enumerate() {
                col_w[j] = col_w[j].max(p.width);
            }
        }
        for (j, h) in self.headings.iter().enumerate() {
            col_w[j] = col_w[j].max(text_width(h, s));
        }
        let grid_w = col_w.iter().sum::<usize>() + gap * ncol.saturating_sub(1);
        let text_w = self
            .title
            .iter()
            .map(|t| text_width(t, s))
            .chain(self.rows.iter().map(|(l, _)| text_width(l, s)))
            .max()
            .unwrap_or(0);
        let footer_w = self.footer.iter().map(|f| f.width).max().unwrap_or(0);
        let width = grid_w.max(text_w).max(footer_w) + 2 * gap;
        let height = gap
            + self.title.len() * line
            + if self.headings.is_empty() {
                0
            } else {
                line + gap / 2
            }
            + self
                .rows
                .iter()
                .map(|(_, p)| line + p.iter().map(|c| c.height).max().unwrap_or(0) + gap)
                .sum::<usize>()
            + self.footer.iter().map(|f| f.height + gap).sum::<usize>()
            + gap;
        let mut c = Canvas::new(width, height, PAPER);
        let mut y = gap;
        for t in &self.title {
            c.text(gap, y, t, s, INK);
            y += line;
        }
        for (row, (label, panels)) in self.rows.iter().enumerate() {
            if !self.headings.is_empty() && row == self.headings_at.min(self.rows.len() - 1) {
                y += gap / 2;
                let mut x = gap;
                for (j, h) in self.headings.iter().enumerate() {
                    c.text(x, y, h, s, [60, 60, 140]);
                    x += col_w[j] + gap;
                }
                y += line;
            }
            c.text(gap, y + s, label, s, INK);
            y += line;
            let mut x = gap;
            for (j, p) in panels.iter().enumerate() {
                c.blit(p, x, y);
                x += col_w[j] + gap;
            }
            y += panels.iter().map(|p| p.height).max().unwrap_or(0) + gap;
        }
        for f in &self.footer {
            c.blit(f, gap, y);
            y += f.height + gap;
        }
        c
    }
}

/// The paper's Fig. 6a with a scale: the non-Lambertian statistic ‖r‖/σ (`residual`, full
/// frame) as grey, square-root scaled to its maximum inside the mask, cropped to the object,
/// with a bar labelled in units of σ and the test's threshold (`threshold`, in the same
/// units) marked in red.
pub fn unreliable_figure(
    residual: &[f32],
    mask: &[bool],
    width: usize,
    height: usize,
    threshold: Option<f64>,
) -> Canvas {
    let top = residual
        .iter()
        .zip(mask)
        .filter(|(r, &m)| m && r.is_finite())
        .map(|(r, _)| *r)
        .fold(1e-6f32, f32::max);
    let view = View::of_mask(mask, width, height, 640);
    let scale = if view.size().1 >= 300 { 2 } else { 1 };
    let panel = view.colour_panel(false, |i| {
        let g = ((residual[i] / top).max(0.0).sqrt().clamp(0.0, 1.0) * 255.0) as u8;
        [g, g, g]
    });
    // The bar is linear in its grey level, i.e. in √(value): ticks at values v sit at √(v/top).
    let root_top = top.sqrt();
    let ticks: Vec<(f32, String)> = [0.0f32, 0.25, 0.5, 0.75, 1.0]
        .iter()
        .map(|f| {
            let v = (f * root_top).powi(2);
            (f * root_top, tick_label(round_sig(v)))
        })
        .collect();
    let mut bar = colour_bar(panel.height, root_top, &ticks, "r/sigma", scale, &|t| {
        let g = (t * 255.0) as u8;
        [g, g, g]
    });
    if let Some(t) = threshold.filter(|t| t.is_finite() && *t > 0.0) {
        let pos = ((t as f32) / top).sqrt().min(1.0) * root_top;
        // The threshold: a red mark across the bar (its value is in the caption).
        let title_h = 11 * scale;
        let top_y = title_h + 4 * scale;
        let span = (bar.height - 4 * scale - top_y).max(2);
        let y = top_y + ((1.0 - pos / root_top) * (span - 1) as f32).round() as usize;
        bar.fill_rect(0, y, 4 * scale + 12 * scale, scale.max(2), [220, 30, 30]);
    }
    let caption = match threshold {
        Some(t) => format!(
            "residual of eq. 5 / noise (sqrt scale); test threshold T = {} (red)",
            tick_label(round_sig(t as f32))
        ),
        None => "residual of eq. 5 / noise (sqrt scale)".into(),
    };
    let body = hstack(&[panel, bar], 8 * scale);
    titled(&body, &caption, 1)
}

/// Rounds to two significant digits for labels.
fn round_sig(v: f32) -> f32 {
    if v <= 0.0 || !v.is_finite() {
        return 0.0;
    }
    let p = 10f32.powf(v.log10().floor() - 1.0);
    (v / p).round() * p
}

/// Three panels side by side, one colour scale: per pixel the number of lights the method
/// put in shadow, in highlight, and dropped for any reason, of the capture's `n` lights; the
/// bar is labelled in lights and in shares of `n`.
pub fn unusable_lights_figure(
    light_status: &StatusMap,
    mask: &[bool],
    width: usize,
    height: usize,
    method: &str,
) -> Canvas {
    use crate::method::statusmap::COUNT_OUTSIDE;
    let n = light_status.lights;
    // Per count 0..=n, the mask pixels with it (from a 2-byte count map): the percentile and
    // the means come from these.
    let histogram = |counts: &[u16]| {
        let mut bins = vec![0usize; n + 1];
        for &c in counts.iter().filter(|&&c| c != COUNT_OUTSIDE) {
            bins[usize::from(c).min(n)] += 1;
        }
        bins
    };
    let mean = |bins: &[usize]| {
        let total: usize = bins.iter().sum();
        let sum: f64 = bins.iter().enumerate().map(|(v, &c)| (v * c) as f64).sum();
        sum / total.max(1) as f64
    };
    // The scale ends at the 99th percentile of the unusable count (a few pixels with every
    // light dropped would otherwise squeeze the rest into the bottom colours); above it clips.
    // The value of rank ⌊0.99 (m − 1)⌋ among the m mask pixels' counts, from their histogram.
    let any = light_status.count_map(None);
    let any_bins = histogram(&any);
    let total: usize = any_bins.iter().sum();
    let p99 = if total == 0 {
        1.0
    } else {
        let rank = ((total - 1) as f64 * 0.99) as usize;
        let mut below = 0;
        any_bins
            .iter()
            .position(|&c| {
                below += c;
                below > rank
            })
            .unwrap_or(n) as f32
    };
    let max = nice_ceil(p99.max(1.0)).min(n as f32).max(1.0);
    let view = View::of_mask(mask, width, height, 360);
    let scale = if view.size().1 >= 240 { 2 } else { 1 };
    let panel = |name: &str, counts: &[u16], bins: &[usize]| {
        let heat = view.heat_panel_by(
            |i| match counts[i] {
                COUNT_OUTSIDE => f32::NAN,
                c => c as f32,
            },
            max,
        );
        titled(&heat, &format!("{name}: mean {:.1}", mean(bins)), scale)
    };
    // One further count map at a time beside the unusable one, in two bytes a pixel.
    let mut panels: Vec<Canvas> = [
        ("in shadow", status::SHADOW),
        ("in highlight", status::HIGHLIGHT),
    ]
    .iter()
    .map(|&(name, which)| {
        let counts = light_status.count_map(Some(which));
        panel(name, &counts, &histogram(&counts))
    })
    .collect();
    panels.push(panel("unusable (any)", &any, &any_bins));
    let steps = if max <= 4.0 { max as usize } else { 4 };
    let ticks: Vec<(f32, String)> = (0..=steps)
        .map(|i| {
            let v = max * i as f32 / steps as f32;
            let more = if i == steps && max < n as f32 {
                "+"
            } else {
                ""
            };
            (
                v,
                format!("{}{more} ({:.0}%)", tick_label(v), 100.0 * v / n as f32),
            )
        })
        .collect();
    let bar = colour_bar(panels[0].height, max, &ticks, "lights", scale, &colormap);
    let mut row = panels;
    row.push(bar);
    titled(
        &hstack(&row, 8 * scale),
        &format!("{method}: lights per pixel the method did not use, of {n}"),
        scale,
    )
}

/// Writes `unreliable.png` ([`unreliable_figure`]) for a reconstruction whose χ² test ran;
/// the threshold comes from its report (`detection.threshold_chi2`, on ‖r‖²/σ²).
pub fn write_unreliable(dir: &Path, rec: &Reconstruction, residual: &[f32]) -> Result<()> {
    let threshold = rec
        .report
        .extra
        .get("detection")
        .and_then(|d| d.get("threshold_chi2"))
        .and_then(|t| t.as_f64())
        .map(f64::sqrt);
    unreliable_figure(residual, &rec.mask, rec.width, rec.height, threshold)
        .save(&dir.join("unreliable.png"))
}

/// Writes `unusable_lights.png` ([`unusable_lights_figure`]) from a reconstruction's statuses.
pub fn write_unusable_lights(dir: &Path, rec: &Reconstruction) -> Result<()> {
    unusable_lights_figure(
        &rec.light_status,
        &rec.mask,
        rec.width,
        rec.height,
        &rec.report.method,
    )
    .save(&dir.join("unusable_lights.png"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn view_crops_to_the_mask_and_reduces() {
        let (w, h) = (100, 80);
        let mut mask = vec![false; w * h];
        for r in 20..40 {
            for c in 30..70 {
                mask[r * w + c] = true;
            }
        }
        let v = View::of_mask(&mask, w, h, 1000);
        assert_eq!((v.x0, v.x1, v.y0, v.y1, v.factor), (28, 72, 18, 42, 1));
        let v = View::of_mask(&mask, w, h, 20);
        assert_eq!(v.factor, 3);
        assert_eq!(v.size(), (15, 8));
        let p = v.binary_panel(|i| i % w < 50);
        assert_eq!((p.width, p.height), (15, 8));
    }

    #[test]
    fn outline_and_outside_colours() {
        let (w, h) = (10, 10);
        let mut mask = vec![false; w * h];
        for r in 3..7 {
            for c in 3..7 {
                mask[r * w + c] = true;
            }
        }
        let v = View::of_mask(&mask, w, h, 100);
        let p = v.binary_panel(|_| false);
        let px = |x: usize, y: usize| {
            let i = (y * p.width + x) * 3;
            [p.data[i], p.data[i + 1], p.data[i + 2]]
        };
        // Margin 2: the mask starts at panel (2, 2); its border is outlined, its inside white.
        assert_eq!(px(0, 0), OUTSIDE);
        assert_eq!(px(2, 2), OUTLINE);
        assert_eq!(px(3, 3), [255; 3]);
    }

    #[test]
    fn nice_numbers_and_labels() {
        assert_eq!(nice_ceil(7.3), 10.0);
        assert_eq!(nice_ceil(2.2), 2.5);
        assert_eq!(nice_ceil(41.0), 50.0);
        assert_eq!(nice_ceil(0.3), 0.3);
        assert_eq!(tick_label(45.0), "45");
        assert_eq!(tick_label(22.5), "22.5");
        assert_eq!(tick_label(0.25), "0.25");
        assert_eq!(nice_steps(30.0), 3);
        assert_eq!(nice_steps(2.5), 5);
        assert_eq!(nice_steps(100.0), 2);
    }

    #[test]
    fn shaded_plane_facing_the_light_is_bright() {
        let (w, h) = (8, 8);
        let mask = vec![true; w * h];
        let view = View::of_mask(&mask, w, h, 100);
        // f rises to the right and downward: the plane faces left and up, toward the light.
        let depth: Vec<f32> = (0..w * h)
            .map(|i| (i % w) as f32 + (i / w) as f32)
            .collect();
        let lit = shaded_depth_panel(&view, &depth, RAKING_LIGHT);
        let flat = shaded_depth_panel(&view, &vec![0.0; w * h], RAKING_LIGHT);
        let g = |c: &Canvas| c.data[(4 * c.width + 4) * 3];
        assert!(g(&lit) > g(&flat), "{} vs {}", g(&lit), g(&flat));
    }
}
