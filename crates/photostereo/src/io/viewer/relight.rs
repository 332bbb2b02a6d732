//! The relighting model of the viewer, computed on the CPU. The page's fragment shader
//! (`assets/image.frag`, layer `relight`) evaluates the same expression; the browser test
//! compares a screenshot of the page with [`relight`].
//!
//! At a pixel with unit normal n, albedo ρ (per channel, linear) and a distant light l (unit,
//! camera frame: x right, y up, z toward the viewer):
//!
//! ```text
//! d    = max(0, n · l)
//! h    = normalize(l + v),  v = (0, 0, 1)
//! s    = (n · h)^shininess   when d > 0, else 0
//! lin  = 2^exposure · ( ρ / white · (ambient + (1 − ambient) · d) + specular · s )
//! out  = encode(clamp(lin, 0, 1)),  encode = the sRGB transfer function (or identity)
//! ```
//!
//! `white` is the albedo that displays as white at exposure 0: the 99.5th percentile of the
//! albedo samples inside the mask ([`albedo_white`]), the same scaling as `albedo.png`.

/// Parameters of [`relight`]; the page's URL fragment carries the same names
/// (`#light=x,y,z&exposure=…&specular=…&shininess=…&ambient=…&srgb=1`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RelightParams {
    /// Direction toward the light (normalised by [`relight`]).
    pub light: [f32; 3],
    /// Exposure in stops: the linear value is multiplied by 2^exposure.
    pub exposure: f32,
    /// Weight of the white Blinn–Phong specular term (0 = Lambertian only).
    pub specular: f32,
    /// Blinn–Phong exponent.
    pub shininess: f32,
    /// Share of the albedo shown regardless of the light (0 = none).
    pub ambient: f32,
    /// Albedo shown as white at exposure 0.
    pub white: f32,
    /// Encode with the sRGB transfer function (else linear values are shown as they are).
    pub srgb: bool,
}

impl Default for RelightParams {
    fn default() -> Self {
        RelightParams {
            light: DEFAULT_LIGHT,
            exposure: 0.0,
            specular: 0.0,
            shininess: 40.0,
            ambient: 0.0,
            white: 1.0,
            srgb: true,
        }
    }
}

/// The page's initial light: from the upper left, 45° above the image plane.
pub const DEFAULT_LIGHT: [f32; 3] = [-0.5, 0.5, std::f32::consts::FRAC_1_SQRT_2];

/// The sRGB transfer function (IEC 61966-2-1) on [0, 1].
pub fn srgb_encode(v: f32) -> f32 {
    let v = v.clamp(0.0, 1.0);
    if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

/// A linear value in [0, 1] (clamped) as a display byte, sRGB-encoded when `srgb`.
pub fn display_byte(v: f32, srgb: bool) -> u8 {
    let v = v.clamp(0.0, 1.0);
    let e = if srgb { srgb_encode(v) } else { v };
    (e * 255.0).round() as u8
}

/// The 99.5th percentile of the finite albedo samples inside the mask (1 when there are none or
/// it is not positive). `albedo` is `H·W·channels`, `mask` `H·W`.
pub fn albedo_white(albedo: &[f32], channels: usize, mask: &[bool]) -> f32 {
    let mut inside: Vec<f32> = albedo
        .chunks_exact(channels.max(1))
        .zip(mask)
        .filter(|(_, &m)| m)
        .flat_map(|(v, _)| v.iter().copied())
        .filter(|v| v.is_finite())
        .collect();
    if inside.is_empty() {
        return 1.0;
    }
    let k = ((inside.len() as f64 * 0.995) as usize).min(inside.len() - 1);
    let (_, v, _) = inside.select_nth_unstable_by(k, |a, b| a.total_cmp(b));
    if *v > 0.0 {
        *v
    } else {
        1.0
    }
}

fn normalize(v: [f32; 3]) -> [f32; 3] {
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if n > 0.0 {
        [v[0] / n, v[1] / n, v[2] / n]
    } else {
        [0.0, 0.0, 1.0]
    }
}

/// The linear (before clamping and encoding) relit value of one pixel.
pub fn relight_pixel(n: [f32; 3], rho: [f32; 3], p: &RelightParams) -> [f32; 3] {
    let l = normalize(p.light);
    let d = (n[0] * l[0] + n[1] * l[1] + n[2] * l[2]).max(0.0);
    let h = normalize([l[0], l[1], l[2] + 1.0]);
    let s = if d > 0.0 {
        (n[0] * h[0] + n[1] * h[1] + n[2] * h[2])
            .max(0.0)
            .powf(p.shininess)
    } else {
        0.0
    };
    let gain = p.exposure.exp2();
    let shade = p.ambient + (1.0 - p.ambient) * d;
    rho.map(|r| gain * (r / p.white * shade + p.specular * s))
}

/// Relights a normal map: `normals` is `H·W` unit vectors ((0, 0, 0) outside the mask), `albedo`
/// `H·W·channels` (1 or 3 channels; grey is shown as grey). Returns `H·W` RGB bytes, black
/// outside the mask, as the page draws them.
pub fn relight(
    normals: &[[f32; 3]],
    albedo: &[f32],
    channels: usize,
    p: &RelightParams,
) -> Vec<[u8; 3]> {
    let ch = channels.max(1);
    normals
        .iter()
        .enumerate()
        .map(|(i, &n)| {
            if n == [0.0; 3] {
                return [0; 3];
            }
            let a = &albedo[i * ch..i * ch + ch];
            let rho = if ch >= 3 {
                [a[0], a[1], a[2]]
            } else {
                [a[0]; 3]
            };
            let rho = rho.map(|v| if v.is_finite() { v.max(0.0) } else { 0.0 });
            relight_pixel(n, rho, p).map(|v| display_byte(v, p.srgb))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lambertian_with_defaults_and_outside_black() {
        let p = RelightParams {
            light: [0.0, 0.0, 2.0],
            srgb: false,
            ..Default::default()
        };
        let n = [[0.0, 0.0, 1.0], [0.0; 3], [0.6, 0.0, 0.8]];
        let out = relight(&n, &[0.5, 0.5, 0.5], 1, &p);
        assert_eq!(out, vec![[128; 3], [0; 3], [102; 3]]);
    }

    #[test]
    fn srgb_and_white_and_specular() {
        assert!((srgb_encode(0.5) - 0.735_357).abs() < 1e-5);
        assert_eq!(srgb_encode(0.0), 0.0);
        let mask = vec![true; 1000];
        let albedo: Vec<f32> = (0..1000).map(|i| i as f32).collect();
        assert_eq!(albedo_white(&albedo, 1, &mask), 995.0);
        let p = RelightParams {
            light: [0.0, 0.0, 1.0],
            specular: 1.0,
            srgb: false,
            ..Default::default()
        };
        // Facing the light and the viewer: diffuse 1 plus specular 1, clamped to white.
        assert_eq!(relight_pixel([0.0, 0.0, 1.0], [0.0; 3], &p), [1.0; 3]);
    }
}
