//! The built-in surfaces: height fields with analytic gradients, so that the ground-truth normals
//! are exact (not finite differences of the sampled heights).
//!
//! Each surface is a function g(u, v) in normalised coordinates: u = (col − c)/S to the right,
//! v = (c − row)/S upward, with c = (N − 1)/2 the image centre and S = N/2, so the frame spans
//! u, v ∈ [−1, 1]. The height in pixel units is h = S·g, hence ∂h/∂x = ∂g/∂u and ∂h/∂y = ∂g/∂v
//! (x = col, y = −row) and the unit normal is (−g_u, −g_v, 1)/‖·‖: the shapes and their normals
//! do not depend on N. Steep walls are tanh ramps about 1.5 pixels wide (their width is given in
//! pixels, so they stay sharp at every size) and keep n_z > 0 everywhere.

use crate::base::error::{Error, Result};
use std::fmt;
use std::str::FromStr;

/// Width of the tanh ramps that make steep walls, in pixels.
pub const WALL_WIDTH_PX: f64 = 1.5;

/// The built-in scenes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SceneKind {
    /// A sphere cut by the ground plane where its slope is 75°, resting on the plane: a smooth dome
    /// with highlights, attached shadows near its rim and a cast shadow on the ground.
    Sphere,
    /// Concave cavities in a plane: two spherical bowls (rim slopes 65° and 72°) and a
    /// flat-bottomed pit with steep walls; the rims shadow the insides.
    Cavities,
    /// Blocks with steep walls (tanh ramps) and gently domed tops, and a thin tall wall: long cast
    /// shadows on the ground, highlights on the tops.
    Blocks,
    /// Ridged terrain: a sum of four sharp-crested ridge waves in different directions.
    Terrain,
    /// Six overlapping steep Gaussian bumps.
    Bumps,
    /// A face-like composite: an ellipsoidal head with nose, eye sockets, brows, cheeks, lips and
    /// chin.
    Face,
}

impl SceneKind {
    /// Every scene, in the order of tables and `--list`.
    pub const ALL: &'static [SceneKind] = &[
        SceneKind::Sphere,
        SceneKind::Cavities,
        SceneKind::Blocks,
        SceneKind::Terrain,
        SceneKind::Bumps,
        SceneKind::Face,
    ];

    /// The scene's name as `synth` accepts it.
    pub fn name(self) -> &'static str {
        match self {
            SceneKind::Sphere => "sphere",
            SceneKind::Cavities => "cavities",
            SceneKind::Blocks => "blocks",
            SceneKind::Terrain => "terrain",
            SceneKind::Bumps => "bumps",
            SceneKind::Face => "face",
        }
    }

    /// The mask a scene uses unless overridden.
    pub fn default_mask(self) -> MaskShape {
        match self {
            SceneKind::Sphere | SceneKind::Cavities | SceneKind::Blocks => MaskShape::Full,
            SceneKind::Face => MaskShape::Circle,
            SceneKind::Terrain | SceneKind::Bumps => MaskShape::Irregular,
        }
    }

    /// The base (mean) albedo, RGB.
    pub fn base_albedo(self) -> [f64; 3] {
        match self {
            SceneKind::Sphere => [0.75, 0.66, 0.55],
            SceneKind::Cavities => [0.62, 0.68, 0.74],
            SceneKind::Blocks => [0.70, 0.70, 0.66],
            SceneKind::Terrain => [0.66, 0.72, 0.58],
            SceneKind::Bumps => [0.74, 0.62, 0.64],
            SceneKind::Face => [0.78, 0.64, 0.56],
        }
    }

    /// g(u, v) and its partial derivatives (g, ∂g/∂u, ∂g/∂v) at normalised coordinates (u, v);
    /// `pixel` is the size of one pixel in normalised units (1/S).
    #[inline]
    pub fn surface(self, u: f64, v: f64, pixel: f64) -> [f64; 3] {
        let wall = WALL_WIDTH_PX * pixel;
        match self {
            SceneKind::Sphere => sphere_cap(u, v, 0.0, 0.0, 0.62, 75.0),
            SceneKind::Cavities => add(&[
                bowl(u, v, -0.45, 0.40, 0.33, 65.0),
                bowl(u, v, 0.42, 0.45, 0.28, 72.0),
                pit(u, v, 0.0, -0.42, 0.36, 0.30, wall),
            ]),
            SceneKind::Blocks => add(&[
                block(u, v, [-0.45, 0.45], [0.28, 0.22], 0.35, 0.12, wall),
                block(u, v, [0.35, 0.35], [0.20, 0.35], 0.50, 0.15, wall),
                block(u, v, [-0.30, -0.45], [0.40, 0.12], 0.25, 0.08, wall),
                block(u, v, [0.45, -0.45], [0.06, 0.30], 0.40, 0.02, wall),
            ]),
            SceneKind::Terrain => add(&[
                ridge(u, v, 20.0, 0.90, 0.24, 0.3),
                ridge(u, v, 75.0, 0.70, 0.19, 1.7),
                ridge(u, v, 130.0, 0.55, 0.14, 4.0),
                ridge(u, v, 165.0, 0.45, 0.08, 2.2),
            ]),
            SceneKind::Bumps => add(&[
                gauss(u, v, [-0.35, 0.35], 0.45, [0.14, 0.14]),
                gauss(u, v, [-0.08, 0.18], 0.35, [0.11, 0.11]),
                gauss(u, v, [0.38, 0.32], 0.50, [0.14, 0.14]),
                gauss(u, v, [0.20, -0.32], 0.38, [0.11, 0.11]),
                gauss(u, v, [-0.32, -0.35], 0.30, [0.09, 0.09]),
                gauss(u, v, [0.50, -0.02], 0.22, [0.07, 0.07]),
            ]),
            SceneKind::Face => add(&[
                head(u, v, [0.62, 0.82], 0.5, 0.25),
                gauss(u, v, [0.0, -0.02], 0.20, [0.055, 0.16]), // nose ridge
                gauss(u, v, [0.0, -0.16], 0.06, [0.06, 0.06]),  // nose tip
                gauss(u, v, [-0.24, 0.18], -0.12, [0.11, 0.07]), // eye sockets
                gauss(u, v, [0.24, 0.18], -0.12, [0.11, 0.07]),
                gauss(u, v, [-0.24, 0.18], 0.04, [0.04, 0.04]), // eyeballs
                gauss(u, v, [0.24, 0.18], 0.04, [0.04, 0.04]),
                gauss(u, v, [-0.24, 0.32], 0.07, [0.14, 0.04]), // brows
                gauss(u, v, [0.24, 0.32], 0.07, [0.14, 0.04]),
                gauss(u, v, [-0.30, -0.15], 0.06, [0.13, 0.13]), // cheeks
                gauss(u, v, [0.30, -0.15], 0.06, [0.13, 0.13]),
                gauss(u, v, [0.0, -0.40], 0.05, [0.14, 0.03]), // lips
                gauss(u, v, [0.0, -0.48], 0.05, [0.11, 0.035]),
                gauss(u, v, [0.0, -0.65], 0.05, [0.15, 0.08]), // chin
            ]),
        }
    }

    /// Albedo at (u, v): the base colour, modulated by a smooth texture when `textured`
    /// (values stay within 0.55–1.15 of the base, hence ≤ 0.9).
    pub fn albedo(self, u: f64, v: f64, textured: bool) -> [f64; 3] {
        let base = self.base_albedo();
        if !textured {
            return base;
        }
        let pattern = 0.85 + 0.2 * (5.3 * u + 1.1).sin() * (4.1 * v - 0.7).sin();
        let mut out = [0.0; 3];
        for (c, o) in out.iter_mut().enumerate() {
            let tint = 1.0 + 0.1 * (3.0 * u + 2.0 * v + 2.1 * c as f64).sin();
            *o = base[c] * pattern * tint;
        }
        out
    }
}

impl fmt::Display for SceneKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for SceneKind {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        crate::base::error::parse_name(s, SceneKind::ALL, SceneKind::name, "scene")
    }
}

/// The object masks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MaskShape {
    /// The whole frame.
    Full,
    /// A centred disc of radius 0.46·N.
    Circle,
    /// A non-convex blob whose radius varies with the angle between 0.26·N and 0.46·N.
    Irregular,
}

impl MaskShape {
    /// Every mask, in `--list` order.
    pub const ALL: &'static [MaskShape] =
        &[MaskShape::Full, MaskShape::Circle, MaskShape::Irregular];

    /// The name `--mask` accepts.
    pub fn name(self) -> &'static str {
        match self {
            MaskShape::Full => "full",
            MaskShape::Circle => "circle",
            MaskShape::Irregular => "irregular",
        }
    }

    /// Whether normalised position (u, v) is inside the mask.
    pub fn contains(self, u: f64, v: f64) -> bool {
        let r = (u * u + v * v).sqrt();
        match self {
            MaskShape::Full => true,
            MaskShape::Circle => r <= 0.92,
            MaskShape::Irregular => {
                let t = v.atan2(u);
                let radius = 0.72
                    * (1.0
                        + 0.14 * (3.0 * t + 0.4).sin()
                        + 0.09 * (5.0 * t - 1.1).cos()
                        + 0.05 * (8.0 * t + 2.0).sin());
                r <= radius
            }
        }
    }
}

impl fmt::Display for MaskShape {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for MaskShape {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        MaskShape::ALL
            .iter()
            .copied()
            .find(|k| k.name() == s)
            .ok_or_else(|| {
                Error::invalid(format!(
                    "unknown mask '{s}': expected one of full, circle, irregular"
                ))
            })
    }
}

fn add(parts: &[[f64; 3]]) -> [f64; 3] {
    parts
        .iter()
        .fold([0.0; 3], |a, p| [a[0] + p[0], a[1] + p[1], a[2] + p[2]])
}

/// 0.5·(1 + tanh(t / w)) and its derivative in t.
fn smooth_step(t: f64, w: f64) -> (f64, f64) {
    let th = (t / w).tanh();
    (0.5 * (1.0 + th), 0.5 * (1.0 - th * th) / w)
}

/// A sphere centred below the plane so that it meets the plane where its slope is
/// `rim_slope_deg`; zero outside. Top radius `radius` (normalised units).
fn sphere_cap(u: f64, v: f64, cu: f64, cv: f64, radius: f64, rim_slope_deg: f64) -> [f64; 3] {
    let (x, y) = (u - cu, v - cv);
    let below = radius * rim_slope_deg.to_radians().cos();
    let z2 = radius * radius - x * x - y * y;
    if z2 <= below * below {
        return [0.0; 3];
    }
    let z = z2.sqrt();
    [z - below, -x / z, -y / z]
}

/// A spherical bowl sunk into the plane: opening radius `opening`, wall slope `rim_slope_deg`
/// at the rim; zero outside.
fn bowl(u: f64, v: f64, cu: f64, cv: f64, opening: f64, rim_slope_deg: f64) -> [f64; 3] {
    let s = rim_slope_deg.to_radians();
    let radius = opening / s.sin();
    let (x, y) = (u - cu, v - cv);
    let r2 = x * x + y * y;
    if r2 >= opening * opening {
        return [0.0; 3];
    }
    let z = (radius * radius - r2).sqrt();
    let below = radius * s.cos();
    [-(z - below), x / z, y / z]
}

/// A flat-bottomed circular pit of depth `depth` with a tanh wall of width `wall`.
fn pit(u: f64, v: f64, cu: f64, cv: f64, radius: f64, depth: f64, wall: f64) -> [f64; 3] {
    let (x, y) = (u - cu, v - cv);
    let r = (x * x + y * y).sqrt();
    let (s, ds) = smooth_step(radius - r, wall);
    // g = −depth·s(radius − r); dg/dr = depth·s'(radius − r).
    let dg_dr = depth * ds;
    if r < 1e-12 {
        return [-depth * s, 0.0, 0.0];
    }
    [-depth * s, dg_dr * x / r, dg_dr * y / r]
}

/// A rectangular block of height `height` with tanh walls of width `wall`, half sizes
/// `half`, and a parabolic dome of height `dome` on top.
fn block(
    u: f64,
    v: f64,
    c: [f64; 2],
    half: [f64; 2],
    height: f64,
    dome: f64,
    wall: f64,
) -> [f64; 3] {
    let (x, y) = (u - c[0], v - c[1]);
    let (wx, dwx_dt) = smooth_step(half[0] - x.abs(), wall);
    let (wy, dwy_dt) = smooth_step(half[1] - y.abs(), wall);
    let dwx = -x.signum() * dwx_dt;
    let dwy = -y.signum() * dwy_dt;
    let (px, dpx) = parabola(x, half[0]);
    let (py, dpy) = parabola(y, half[1]);
    let top = height + dome * px * py;
    let g = top * wx * wy;
    let gu = dome * dpx * py * wx * wy + top * dwx * wy;
    let gv = dome * px * dpy * wx * wy + top * wx * dwy;
    [g, gu, gv]
}

/// max(0, 1 − (t/a)²) and its derivative.
fn parabola(t: f64, a: f64) -> (f64, f64) {
    if t.abs() >= a {
        (0.0, 0.0)
    } else {
        (1.0 - (t / a) * (t / a), -2.0 * t / (a * a))
    }
}

/// A ridge wave exp(β (cos(k·p + φ) − 1)) with sharp crests (β = 3), direction `angle_deg`,
/// wavelength `wavelength` and amplitude `amp` (normalised units).
fn ridge(u: f64, v: f64, angle_deg: f64, wavelength: f64, amp: f64, phase: f64) -> [f64; 3] {
    const BETA: f64 = 3.0;
    let a = angle_deg.to_radians();
    let k = 2.0 * std::f64::consts::PI / wavelength;
    let (ku, kv) = (k * a.cos(), k * a.sin());
    let t = ku * u + kv * v + phase;
    let e = (BETA * (t.cos() - 1.0)).exp();
    let dg_dt = -amp * BETA * t.sin() * e;
    [amp * e, dg_dt * ku, dg_dt * kv]
}

/// An axis-aligned Gaussian bump of amplitude `amp` (negative = a dent) and widths `sigma`.
fn gauss(u: f64, v: f64, c: [f64; 2], amp: f64, sigma: [f64; 2]) -> [f64; 3] {
    let (x, y) = (u - c[0], v - c[1]);
    let (sx2, sy2) = (sigma[0] * sigma[0], sigma[1] * sigma[1]);
    let g = amp * (-(x * x / (2.0 * sx2) + y * y / (2.0 * sy2))).exp();
    [g, -g * x / sx2, -g * y / sy2]
}

/// An ellipsoidal head: height·(√(1 − q) − rim) with q = (x/a)² + (y/b)², zero where
/// √(1 − q) ≤ rim (the head meets the plane with a finite, steep slope).
fn head(u: f64, v: f64, axes: [f64; 2], height: f64, rim: f64) -> [f64; 3] {
    let (a2, b2) = (axes[0] * axes[0], axes[1] * axes[1]);
    let q = u * u / a2 + v * v / b2;
    let s2 = 1.0 - q;
    if s2 <= rim * rim {
        return [0.0; 3];
    }
    let s = s2.sqrt();
    [
        height * (s - rim),
        -height * u / (a2 * s),
        -height * v / (b2 * s),
    ]
}
