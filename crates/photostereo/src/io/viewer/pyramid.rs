//! The viewer's image pyramid: level 0 is the full frame, each next level halves both sides, up
//! to the first level that fits one tile. Every level is cut into tiles of [`TILE`]² pixels and
//! each tile's maps are written as small JavaScript files (`PSV.tile(key, base64)`, the payload
//! zlib-compressed little-endian arrays), which a page opened from `file://` can load with
//! `<script src>` where `fetch` is refused.
//!
//! Groups (one file per tile and group):
//! - `n`: normals, 3 × u16 per pixel, (n + 1) / 2 · 65535; (0, 0, 0) outside the mask.
//! - `a`: albedo, 3 × u16 per pixel, albedo / `albedo_max` · 65535 (grey repeated).
//! - `d`: shaded depth, 3 × u8 per pixel (colour by height times a hill shade), 0 outside.
//! - `q`: 2 × u8 per pixel: the count of unusable lights (capped at 255) and flags
//!   ([`FLAG_INSIDE`], [`FLAG_UNRELIABLE`], [`FLAG_HIGHLIGHT`], [`FLAG_FEWER_THAN_THREE`]).
//! - `r`: 2 × f32 per pixel: the residual statistic and the angular error in degrees (−1 when
//!   absent).
//! - `s`: light statuses, 2 bits per light (0 used, 1 shadow, 2 highlight, 3 rejected), four
//!   lights per byte: plane p (lights 4p..4p+3, light 4p+j in bits 2j..2j+1) is `tw·th` bytes,
//!   planes one after the other.
//! - `c`: the RTI fit's planes ([`super::rti::RtiLayer`]), P per pixel, each as u16,
//!   (v − lo_q) / span_q · 65535 with the plane's range over the frame ([`Level::rti_ranges`]),
//!   packed four planes a texel: layer L (planes 4L..4L+3, zero past P) is `tw·th` texels of
//!   4 × u16, layers one after the other.
//! - `u`: the normals blurred for the unsharp mask ([`super::rti::blur_normals`] of the level's
//!   normals), as `n`.
//! - `g`: 2 × f32 per pixel: specular strength and roughness (−1 where missing).
//!
//! Reduced levels: normals are the normalised sum of the inside children, albedo and shaded depth
//! their mean, the unusable count and residual their maximum, the error its mean, flags their
//! union, statuses those of the first inside child (row-major), RTI planes and gloss their mean.

use super::folder::RunFolder;
use crate::base::error::{Error, Result};
use crate::io::figure::colormap;
use rayon::prelude::*;
use std::io::Write;
use std::path::Path;

/// Tile side, pixels.
pub const TILE: usize = 512;
pub const FLAG_INSIDE: u8 = 1;
pub const FLAG_UNRELIABLE: u8 = 2;
pub const FLAG_HIGHLIGHT: u8 = 4;
pub const FLAG_FEWER_THAN_THREE: u8 = 8;

/// One level of the pyramid, full frame.
pub struct Level {
    pub width: usize,
    pub height: usize,
    pub normals: Vec<[f32; 3]>,
    pub albedo: Vec<[f32; 3]>,
    pub depth_rgb: Option<Vec<[u8; 3]>>,
    /// (unusable count, flags).
    pub q: Vec<[u8; 2]>,
    /// (residual, error°).
    pub r: Option<Vec<[f32; 2]>>,
    /// Packed statuses: `planes` planes of `width·height` bytes.
    pub status: Option<Vec<u8>>,
    pub planes: usize,
    /// RTI planes, `[pixel][plane]`, `rti_planes` per pixel.
    pub rti: Option<Vec<f32>>,
    pub rti_planes: usize,
    /// Per RTI plane, the least value and the span of its u16 code.
    pub rti_ranges: Vec<(f32, f32)>,
    /// Blurred normals (with the RTI layer).
    pub blurred: Option<Vec<[f32; 3]>>,
    /// (specular strength, roughness).
    pub gloss: Option<Vec<[f32; 2]>>,
}

/// Per plane of `values` (`planes` per pixel), over the pixels `inside` marks: the least value
/// and the span (1 when the plane is constant).
fn plane_ranges(values: &[f32], planes: usize, inside: impl Fn(usize) -> bool) -> Vec<(f32, f32)> {
    let mut r = vec![(f32::INFINITY, f32::NEG_INFINITY); planes];
    for (i, px) in values.chunks_exact(planes).enumerate() {
        if inside(i) {
            for (e, &v) in r.iter_mut().zip(px) {
                if v.is_finite() {
                    *e = (e.0.min(v), e.1.max(v));
                }
            }
        }
    }
    r.into_iter()
        .map(|(lo, hi)| {
            if lo < hi {
                (lo, hi - lo)
            } else if lo.is_finite() {
                (lo, 1.0)
            } else {
                (0.0, 1.0)
            }
        })
        .collect()
}

/// The size of the next level of a pyramid: both sides halved, rounded up (a pixel of the
/// next level covers the 2 × 2 block of pixels at twice its coordinates, cut at the border).
/// Deep Zoom's levels follow the same rule (level sizes ⌈W / 2^k⌉).
pub fn half(w: usize, h: usize) -> (usize, usize) {
    (w.div_ceil(2), h.div_ceil(2))
}

/// The next level of an 8-bit image with `c` interleaved channels: each pixel the rounded mean
/// of the (up to four) pixels it covers ([`half`]).
pub fn halve_u8(w: usize, h: usize, c: usize, data: &[u8]) -> (usize, usize, Vec<u8>) {
    let (w2, h2) = half(w, h);
    let mut out = vec![0u8; w2 * h2 * c];
    out.par_chunks_mut(w2 * c)
        .enumerate()
        .for_each(|(r2, row)| {
            for c2 in 0..w2 {
                let rows = 2 * r2..(2 * r2 + 2).min(h);
                let cols = 2 * c2..(2 * c2 + 2).min(w);
                let n = (rows.len() * cols.len()) as u32;
                for k in 0..c {
                    let mut sum = 0u32;
                    for r in rows.clone() {
                        for col in cols.clone() {
                            sum += u32::from(data[(r * w + col) * c + k]);
                        }
                    }
                    row[c2 * c + k] = ((sum + n / 2) / n) as u8;
                }
            }
        });
    (w2, h2, out)
}

/// Light direction of the depth layer's hill shade (upper left, camera frame).
const HILL_LIGHT: [f32; 3] = [-0.4851, 0.4851, 0.7276];

/// Depth range (min, max) over finite values.
pub fn depth_range(depth: &[f32]) -> Option<(f32, f32)> {
    let (lo, hi) = depth
        .iter()
        .filter(|v| v.is_finite())
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    (lo <= hi).then_some((lo, hi))
}

/// The depth layer: colour by height over `range`, times a hill shade from the depth gradient.
fn shade_depth(w: usize, h: usize, depth: &[f32], (lo, hi): (f32, f32)) -> Vec<[u8; 3]> {
    let span = if hi > lo { hi - lo } else { 1.0 };
    let at = |r: usize, c: usize| depth[r * w + c];
    (0..w * h)
        .into_par_iter()
        .map(|i| {
            let (r, c) = (i / w, i % w);
            let z = depth[i];
            if !z.is_finite() {
                return [0; 3];
            }
            // One-sided differences where a neighbour is missing.
            let diff = |a: Option<f32>, b: Option<f32>| match (a, b) {
                (Some(a), Some(b)) => (b - a) / 2.0,
                (None, Some(b)) => b - z,
                (Some(a), None) => z - a,
                (None, None) => 0.0,
            };
            let f = |v: f32| v.is_finite().then_some(v);
            let left = (c > 0).then(|| at(r, c - 1)).and_then(f);
            let right = (c + 1 < w).then(|| at(r, c + 1)).and_then(f);
            let up = (r > 0).then(|| at(r - 1, c)).and_then(f);
            let down = (r + 1 < h).then(|| at(r + 1, c)).and_then(f);
            let dx = diff(left, right);
            let dy = -diff(up, down); // y grows opposite to the row index
            let len = (dx * dx + dy * dy + 1.0).sqrt();
            let m = [-dx / len, -dy / len, 1.0 / len];
            let lit = (m[0] * HILL_LIGHT[0] + m[1] * HILL_LIGHT[1] + m[2] * HILL_LIGHT[2]).max(0.0);
            let shade = 0.3 + 0.7 * lit;
            colormap((z - lo) / span).map(|v| (v as f32 * shade).round().clamp(0.0, 255.0) as u8)
        })
        .collect()
}

fn pack_status(n: usize, hw: usize, status: &[u8]) -> (Vec<u8>, usize) {
    let planes = n.div_ceil(4);
    let mut out = vec![0u8; planes * hw];
    for k in 0..n {
        let (p, shift) = (k / 4, 2 * (k % 4));
        let src = &status[k * hw..(k + 1) * hw];
        let dst = &mut out[p * hw..(p + 1) * hw];
        for (d, &s) in dst.iter_mut().zip(src) {
            let code = match s {
                0 | 255 => 0,
                1 => 1,
                2 => 2,
                _ => 3,
            };
            *d |= code << shift;
        }
    }
    (out, planes)
}

/// One pixel of a reduced level (see `Level::reduce_pixel`).
struct Px {
    n: [f32; 3],
    a: [f32; 3],
    d: [u8; 3],
    q: [u8; 2],
    r: [f32; 2],
    first: usize,
}

impl Level {
    /// Level 0 from an output folder.
    pub fn base(f: &RunFolder, depth_range: Option<(f32, f32)>) -> Level {
        let (w, h) = (f.width, f.height);
        let hw = w * h;
        let ch = f.albedo_channels;
        let albedo: Vec<[f32; 3]> = (0..hw)
            .map(|i| {
                let a = &f.albedo[i * ch..i * ch + ch];
                let v = if ch >= 3 {
                    [a[0], a[1], a[2]]
                } else {
                    [a[0]; 3]
                };
                v.map(|x| if x.is_finite() { x.max(0.0) } else { 0.0 })
            })
            .collect();
        let n_lights = f.status.as_ref().map_or(0, |(n, _)| *n);
        let q: Vec<[u8; 2]> = (0..hw)
            .into_par_iter()
            .map(|i| {
                if !f.mask[i] {
                    return [0, 0];
                }
                let count = f.unusable_count(i);
                let mut flags = FLAG_INSIDE;
                if f.unreliable.as_ref().is_some_and(|m| m[i]) {
                    flags |= FLAG_UNRELIABLE;
                }
                if f.highlight.as_ref().is_some_and(|m| m[i]) {
                    flags |= FLAG_HIGHLIGHT;
                }
                let few = match &f.fewer_than_three {
                    Some(m) => m[i],
                    None => n_lights > 0 && n_lights - count < 3,
                };
                if few {
                    flags |= FLAG_FEWER_THAN_THREE;
                }
                [count.min(255) as u8, flags]
            })
            .collect();
        let r = (f.residual.is_some() || f.error_deg.is_some()).then(|| {
            (0..hw)
                .map(|i| {
                    let res = f.residual.as_ref().map_or(f32::NAN, |v| v[i]);
                    let err = f.error_deg.as_ref().map_or(f32::NAN, |v| v[i]);
                    if f.mask[i] {
                        [res, err]
                    } else {
                        [f32::NAN; 2]
                    }
                })
                .collect()
        });
        let depth_rgb = match (&f.depth, depth_range) {
            (Some(d), Some(range)) => Some(shade_depth(w, h, d, range)),
            _ => None,
        };
        let (status, planes) = match &f.status {
            Some((n, s)) => {
                let (p, planes) = pack_status(*n, hw, s);
                (Some(p), planes)
            }
            None => (None, 0),
        };
        let rti_planes = f.rti.as_ref().map_or(0, |l| l.planes());
        let rti = f.rti.as_ref().map(|l| l.values.clone());
        let rti_ranges = rti
            .as_ref()
            .map_or(Vec::new(), |v| plane_ranges(v, rti_planes, |i| f.mask[i]));
        let blurred = f
            .rti
            .as_ref()
            .map(|_| super::rti::blur_normals(w, h, &f.normals, super::rti::UNSHARP_SIGMA));
        let gloss = f.gloss.as_ref().map(|(s, r)| {
            (0..hw)
                .map(|i| {
                    if f.mask[i] {
                        [s[i], r[i]]
                    } else {
                        [f32::NAN; 2]
                    }
                })
                .collect()
        });
        Level {
            width: w,
            height: h,
            normals: f.normals.clone(),
            albedo,
            depth_rgb,
            q,
            r,
            status,
            planes,
            rti,
            rti_planes,
            rti_ranges,
            blurred,
            gloss,
        }
    }

    /// The mean over the inside children `v[..k]` of each pixel of the next level of a
    /// per-pixel vector field of `per` values (NaN values left out; NaN when none).
    fn reduce_mean(values: &[f32], per: usize, kids: &[([usize; 4], usize)]) -> Vec<f32> {
        let mut out = vec![f32::NAN; kids.len() * per];
        out.par_chunks_mut(per).zip(kids).for_each(|(o, (v, k))| {
            for (q, x) in o.iter_mut().enumerate() {
                let (mut s, mut n) = (0f32, 0usize);
                for &i in &v[..*k] {
                    let y = values[i * per + q];
                    if y.is_finite() {
                        s += y;
                        n += 1;
                    }
                }
                if n > 0 {
                    *x = s / n as f32;
                }
            }
        });
        out
    }

    /// One pixel of the next level from its children inside the mask (indices into this
    /// level, at most four): normals summed and renormalised, albedo and depth colours
    /// averaged, quality the worst, flags united, residual the largest and error the mean.
    fn reduce_pixel(&self, v: &[usize]) -> Px {
        let mut out = Px {
            n: [0.0; 3],
            a: [0.0; 3],
            d: [0; 3],
            q: [0; 2],
            r: [f32::NAN; 2],
            first: usize::MAX,
        };
        if v.is_empty() {
            return out;
        }
        let (mut n, mut a, mut d) = ([0f32; 3], [0f32; 3], [0f32; 3]);
        let (mut res, mut err, mut nerr) = (f32::NAN, 0f32, 0usize);
        let mut q = [0u8, 0u8];
        for &i in v {
            for c in 0..3 {
                n[c] += self.normals[i][c];
                a[c] += self.albedo[i][c];
                if let Some(dr) = &self.depth_rgb {
                    d[c] += dr[i][c] as f32;
                }
            }
            q[0] = q[0].max(self.q[i][0]);
            q[1] |= self.q[i][1];
            if let Some(r) = &self.r {
                if r[i][0].is_finite() {
                    res = if res.is_finite() {
                        res.max(r[i][0])
                    } else {
                        r[i][0]
                    };
                }
                if r[i][1].is_finite() {
                    err += r[i][1];
                    nerr += 1;
                }
            }
        }
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        out.n = if len > 1e-6 {
            n.map(|x| x / len)
        } else {
            [0.0, 0.0, 1.0]
        };
        out.a = a.map(|x| x / v.len() as f32);
        out.d = d.map(|x| (x / v.len() as f32).round() as u8);
        out.q = q;
        out.r = [
            res,
            if nerr > 0 {
                err / nerr as f32
            } else {
                f32::NAN
            },
        ];
        out.first = v[0];
        out
    }

    /// The next level: both sides halved (rounded up).
    pub fn reduce(&self) -> Level {
        let (w, h) = (self.width, self.height);
        let (w2, h2) = half(w, h);
        let children = |r2: usize, c2: usize| {
            let mut v = [usize::MAX; 4];
            let mut k = 0;
            for r in 2 * r2..(2 * r2 + 2).min(h) {
                for c in 2 * c2..(2 * c2 + 2).min(w) {
                    let i = r * w + c;
                    if self.q[i][1] & FLAG_INSIDE != 0 {
                        v[k] = i;
                        k += 1;
                    }
                }
            }
            (v, k)
        };
        let px: Vec<Px> = (0..w2 * h2)
            .into_par_iter()
            .map(|j| {
                let (v, k) = children(j / w2, j % w2);
                self.reduce_pixel(&v[..k])
            })
            .collect();
        let kids: Vec<([usize; 4], usize)> = if self.rti.is_some() || self.gloss.is_some() {
            (0..w2 * h2).map(|j| children(j / w2, j % w2)).collect()
        } else {
            Vec::new()
        };
        let rti = self
            .rti
            .as_ref()
            .map(|v| Self::reduce_mean(v, self.rti_planes, &kids));
        let gloss = self.gloss.as_ref().map(|g| {
            let flat: Vec<f32> = g.iter().flatten().copied().collect();
            Self::reduce_mean(&flat, 2, &kids)
                .chunks_exact(2)
                .map(|p| [p[0], p[1]])
                .collect()
        });
        let normals: Vec<[f32; 3]> = px.iter().map(|x| x.n).collect();
        let blurred = self.blurred.as_ref().map(|_| {
            let inside: Vec<[f32; 3]> = normals
                .iter()
                .zip(&px)
                .map(|(n, x)| {
                    if x.q[1] & FLAG_INSIDE != 0 {
                        *n
                    } else {
                        [0.0; 3]
                    }
                })
                .collect();
            super::rti::blur_normals(w2, h2, &inside, super::rti::UNSHARP_SIGMA)
        });
        let status = self.status.as_ref().map(|s| {
            let (hw, hw2) = (w * h, w2 * h2);
            let mut out = vec![0u8; self.planes * hw2];
            for p in 0..self.planes {
                for (j, x) in px.iter().enumerate() {
                    if x.first != usize::MAX {
                        out[p * hw2 + j] = s[p * hw + x.first];
                    }
                }
            }
            out
        });
        Level {
            width: w2,
            height: h2,
            normals,
            albedo: px.iter().map(|x| x.a).collect(),
            depth_rgb: self
                .depth_rgb
                .as_ref()
                .map(|_| px.iter().map(|x| x.d).collect()),
            q: px.iter().map(|x| x.q).collect(),
            r: self.r.as_ref().map(|_| px.iter().map(|x| x.r).collect()),
            status,
            planes: self.planes,
            rti,
            rti_planes: self.rti_planes,
            rti_ranges: self.rti_ranges.clone(),
            blurred,
            gloss,
        }
    }

    pub fn cols(&self) -> usize {
        self.width.div_ceil(TILE)
    }

    pub fn rows(&self) -> usize {
        self.height.div_ceil(TILE)
    }

    /// The bytes of one group of tile (`tr`, `tc`), `None` when the level lacks that group.
    pub fn tile_bytes(
        &self,
        group: char,
        tr: usize,
        tc: usize,
        albedo_max: f32,
    ) -> Option<Vec<u8>> {
        let (x0, y0) = (tc * TILE, tr * TILE);
        let tw = TILE.min(self.width - x0);
        let th = TILE.min(self.height - y0);
        let idx = move |y: usize, x: usize| (y0 + y) * self.width + x0 + x;
        let pixels = move || (0..th).flat_map(move |y| (0..tw).map(move |x| idx(y, x)));
        let mut out = Vec::new();
        match group {
            'n' | 'u' => {
                let normals = if group == 'n' {
                    &self.normals
                } else {
                    self.blurred.as_ref()?
                };
                out.reserve(tw * th * 6);
                for i in pixels() {
                    let n = normals[i];
                    let inside = self.q[i][1] & FLAG_INSIDE != 0;
                    for v in n {
                        let code = if inside {
                            (((v + 1.0) * 0.5).clamp(0.0, 1.0) * 65535.0).round() as u16
                        } else {
                            0
                        };
                        out.extend_from_slice(&code.to_le_bytes());
                    }
                }
            }
            'a' => {
                out.reserve(tw * th * 6);
                for i in pixels() {
                    for v in self.albedo[i] {
                        let code = ((v / albedo_max).clamp(0.0, 1.0) * 65535.0).round() as u16;
                        out.extend_from_slice(&code.to_le_bytes());
                    }
                }
            }
            'd' => {
                let d = self.depth_rgb.as_ref()?;
                for i in pixels() {
                    out.extend_from_slice(&d[i]);
                }
            }
            'q' => {
                for i in pixels() {
                    out.extend_from_slice(&self.q[i]);
                }
            }
            'r' => {
                let r = self.r.as_ref()?;
                for i in pixels() {
                    for v in r[i] {
                        let v = if v.is_finite() { v } else { -1.0 };
                        out.extend_from_slice(&v.to_le_bytes());
                    }
                }
            }
            'c' => {
                let v = self.rti.as_ref()?;
                let p = self.rti_planes;
                for layer in 0..p.div_ceil(4) {
                    for i in pixels() {
                        for q in 4 * layer..4 * layer + 4 {
                            let code = if q < p && v[i * p + q].is_finite() {
                                let (lo, span) = self.rti_ranges[q];
                                ((v[i * p + q] - lo) / span * 65535.0)
                                    .round()
                                    .clamp(0.0, 65535.0) as u16
                            } else {
                                0
                            };
                            out.extend_from_slice(&code.to_le_bytes());
                        }
                    }
                }
            }
            'g' => {
                let g = self.gloss.as_ref()?;
                for i in pixels() {
                    for v in g[i] {
                        let v = if v.is_finite() { v } else { -1.0 };
                        out.extend_from_slice(&v.to_le_bytes());
                    }
                }
            }
            's' => {
                let s = self.status.as_ref()?;
                let hw = self.width * self.height;
                for p in 0..self.planes {
                    for i in pixels() {
                        out.push(s[p * hw + i]);
                    }
                }
            }
            _ => return None,
        }
        Some(out)
    }
}

/// Standard base64 (RFC 4648, with padding).
pub fn base64(bytes: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            chunk.get(1).copied().unwrap_or(0),
            chunk.get(2).copied().unwrap_or(0),
        ];
        let v = (b[0] as u32) << 16 | (b[1] as u32) << 8 | b[2] as u32;
        out.push(A[(v >> 18) as usize & 63] as char);
        out.push(A[(v >> 12) as usize & 63] as char);
        out.push(if chunk.len() > 1 {
            A[(v >> 6) as usize & 63] as char
        } else {
            '='
        });
        out.push(if chunk.len() > 2 {
            A[v as usize & 63] as char
        } else {
            '='
        });
    }
    out
}

/// zlib-compresses `bytes`.
pub fn zlib(bytes: &[u8]) -> Vec<u8> {
    let mut enc = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::new(4));
    enc.write_all(bytes).expect("writing to memory");
    enc.finish().expect("writing to memory")
}

/// Writes `PSV.<call>("key", "<base64 of zlib(bytes)>");` to `path`; returns the file size.
pub fn write_js_payload(path: &Path, call: &str, key: &str, bytes: &[u8]) -> Result<u64> {
    let text = format!("PSV.{call}({key:?},\"{}\");\n", base64(&zlib(bytes)));
    std::fs::write(path, &text).map_err(|e| Error::io(path, e))?;
    Ok(text.len() as u64)
}

/// Writes every tile of `level` (number `l`) for `groups` into `dir/<l>/`; returns (files, bytes).
pub fn write_level(
    dir: &Path,
    l: usize,
    level: &Level,
    groups: &[char],
    albedo_max: f32,
) -> Result<(usize, u64)> {
    let ldir = dir.join(l.to_string());
    std::fs::create_dir_all(&ldir).map_err(|e| Error::io(&ldir, e))?;
    let jobs: Vec<(usize, usize, char)> = (0..level.rows())
        .flat_map(|r| (0..level.cols()).flat_map(move |c| groups.iter().map(move |&g| (r, c, g))))
        .collect();
    let sizes: Vec<u64> = jobs
        .par_iter()
        .map(|&(r, c, g)| -> Result<u64> {
            let Some(bytes) = level.tile_bytes(g, r, c, albedo_max) else {
                return Ok(0);
            };
            let key = format!("{l}/{r}_{c}/{g}");
            write_js_payload(&ldir.join(format!("{r}_{c}.{g}.js")), "tile", &key, &bytes)
        })
        .collect::<Result<_>>()?;
    Ok((sizes.iter().filter(|&&s| s > 0).count(), sizes.iter().sum()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_matches_rfc4648_vectors() {
        for (a, b) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(base64(a.as_bytes()), b);
        }
    }

    #[test]
    fn status_packing_two_bits_per_light() {
        // 5 lights, 2 pixels.
        let s = vec![0, 1, 2, 3, 255, 0, 1, 7, 2, 2];
        let (p, planes) = pack_status(5, 2, &s);
        assert_eq!(planes, 2);
        // pixel 0: lights 0..3 = 0, 2, 255→0, 1 ; pixel 1: 1, 3, 0, 3(7); light 4: 2, 2
        assert_eq!(p[0], 2 << 2 | 1 << 6);
        assert_eq!(p[1], 1 | 3 << 2 | 3 << 6);
        assert_eq!(p[2..], [2, 2]);
    }
}
