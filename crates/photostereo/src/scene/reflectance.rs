//! Reflectance models of the renderer. Every model is Lambertian diffuse reflection plus an
//! optional specular lobe of the light's colour (dichromatic model). Values are in units of full
//! scale for a light of intensity 1: the pixel value of channel c under light k is
//! `E_k,c · (ρ_c · max(n·l, 0) + specular(n, l))`, zero where the pixel is shadowed.
//!
//! The viewer is the orthographic camera, v = (0, 0, 1). The constants are chosen so that a
//! surface facing the half vector of a light at slant 35° (the `square4` rig) reaches a specular
//! value of about 0.5–0.6 of full scale: with an albedo of 0.6–0.8 such highlights clip at white.

use crate::base::error::{Error, Result};
use std::fmt;
use std::str::FromStr;

/// Blinn–Phong specular coefficient k_s (fraction of full scale at n = h).
pub const BLINN_PHONG_KS: f64 = 0.6;
/// Blinn–Phong exponent: the lobe `(n·h)^100` falls to 2% of full scale at 15° from h.
pub const BLINN_PHONG_EXPONENT: f64 = 100.0;
/// Torrance–Sparrow specular coefficient.
pub const TORRANCE_SPARROW_KS: f64 = 0.15;
/// Beckmann RMS slope m of the micro-facets: with k_s = 0.15 the lobe peaks at 0.56 of full
/// scale and falls to 2% at about 15° from h, like the Blinn–Phong lobe.
pub const BECKMANN_ROUGHNESS: f64 = 0.15;
/// Schlick reflectance at normal incidence; Fresnel is normalised to 1 at normal incidence.
pub const FRESNEL_F0: f64 = 0.04;

/// The reflectance models of `--brdf`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Brdf {
    /// Lambertian only.
    Lambert,
    /// Lambert plus a Blinn–Phong lobe `k_s (n·h)^α` (only where n·l > 0).
    BlinnPhong,
    /// Lambert plus a Torrance–Sparrow lobe: `k_s · D · G · F / (4 n·v)` with the Beckmann
    /// distribution D, the V-cavity geometric attenuation G and Schlick's Fresnel term F
    /// (normalised to 1 at normal incidence).
    TorranceSparrow,
}

impl Brdf {
    /// Every model, in the order `--list` shows them.
    pub const ALL: &'static [Brdf] = &[Brdf::Lambert, Brdf::BlinnPhong, Brdf::TorranceSparrow];

    /// The name accepted by `--brdf`.
    pub fn name(self) -> &'static str {
        match self {
            Brdf::Lambert => "lambert",
            Brdf::BlinnPhong => "blinn-phong",
            Brdf::TorranceSparrow => "torrance-sparrow",
        }
    }

    /// The specular term (full-scale units for a unit light) for unit normal `n` and unit light
    /// direction `l`, viewer (0, 0, 1). Zero for Lambert and where n·l ≤ 0 or n·v ≤ 0.
    #[inline]
    pub fn specular(self, n: [f64; 3], l: [f64; 3]) -> f64 {
        self.specular_with_half(n, l, Brdf::half_vector(l))
    }

    /// The unit half vector between `l` and the viewer (0, 0, 1); `None` when they are
    /// opposite (no specular term). The same for every pixel of a light.
    #[inline]
    pub fn half_vector(l: [f64; 3]) -> Option<[f64; 3]> {
        let v = [l[0], l[1], l[2] + 1.0];
        let norm = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if norm < 1e-12 {
            return None;
        }
        Some([v[0] / norm, v[1] / norm, v[2] / norm])
    }

    /// [`Brdf::specular`] with `half` = [`Brdf::half_vector`]`(l)` computed once per light.
    #[inline]
    pub fn specular_with_half(self, n: [f64; 3], l: [f64; 3], half: Option<[f64; 3]>) -> f64 {
        let n_dot_l = n[0] * l[0] + n[1] * l[1] + n[2] * l[2];
        let n_dot_v = n[2];
        if n_dot_l <= 0.0 || n_dot_v <= 0.0 {
            return 0.0;
        }
        let Some(h) = half else {
            return 0.0;
        };
        let n_dot_h = (n[0] * h[0] + n[1] * h[1] + n[2] * h[2]).max(0.0);
        match self {
            Brdf::Lambert => 0.0,
            Brdf::BlinnPhong => BLINN_PHONG_KS * n_dot_h.powf(BLINN_PHONG_EXPONENT),
            Brdf::TorranceSparrow => {
                if n_dot_h <= 1e-6 {
                    return 0.0;
                }
                let m2 = BECKMANN_ROUGHNESS * BECKMANN_ROUGHNESS;
                let cos2 = n_dot_h * n_dot_h;
                let tan2 = (1.0 - cos2) / cos2;
                let d = (-tan2 / m2).exp() / (std::f64::consts::PI * m2 * cos2 * cos2);
                let v_dot_h = h[2];
                let g = 1f64
                    .min(2.0 * n_dot_h * n_dot_v / v_dot_h)
                    .min(2.0 * n_dot_h * n_dot_l / v_dot_h);
                let schlick = FRESNEL_F0 + (1.0 - FRESNEL_F0) * (1.0 - v_dot_h).powi(5);
                let f = schlick / FRESNEL_F0;
                TORRANCE_SPARROW_KS * d * g * f / (4.0 * n_dot_v)
            }
        }
    }
}

impl fmt::Display for Brdf {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Brdf {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        crate::base::error::parse_name(s, Brdf::ALL, Brdf::name, "reflectance model")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit(v: [f64; 3]) -> [f64; 3] {
        let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        [v[0] / n, v[1] / n, v[2] / n]
    }

    #[test]
    fn lobes_peak_at_the_half_vector() {
        let s = 35f64.to_radians();
        let l = [s.sin(), 0.0, s.cos()];
        let h = unit([l[0], l[1], l[2] + 1.0]);
        for brdf in [Brdf::BlinnPhong, Brdf::TorranceSparrow] {
            let peak = brdf.specular(h, l);
            assert!(peak > 0.4 && peak < 0.8, "{brdf}: peak {peak}");
            for off in [5f64, 10.0, 20.0] {
                let a = (17.5 + off).to_radians();
                let b = (17.5 - off).to_radians();
                let n1 = [a.sin(), 0.0, a.cos()];
                let n2 = [b.sin(), 0.0, b.cos()];
                assert!(brdf.specular(n1, l) < peak && brdf.specular(n2, l) < peak);
            }
        }
        assert_eq!(Brdf::Lambert.specular(h, l), 0.0);
        // Blinn–Phong at 15° from h: 0.6 · cos(15°)^100 ≈ 0.019.
        let a = (17.5 + 15.0f64).to_radians();
        let v = Brdf::BlinnPhong.specular([a.sin(), 0.0, a.cos()], l);
        assert!((v - 0.6 * 15f64.to_radians().cos().powi(100)).abs() < 1e-12);
    }

    #[test]
    fn no_specular_facing_away() {
        let l = unit([1.0, 0.0, 0.2]);
        assert_eq!(
            Brdf::TorranceSparrow.specular(unit([-1.0, 0.0, 0.1]), l),
            0.0
        );
        assert_eq!(Brdf::BlinnPhong.specular(unit([-1.0, 0.0, 0.1]), l), 0.0);
    }

    #[test]
    fn names_round_trip() {
        for b in Brdf::ALL {
            assert_eq!(b.name().parse::<Brdf>().unwrap(), *b);
        }
        assert!("phong"
            .parse::<Brdf>()
            .unwrap_err()
            .to_string()
            .contains("blinn-phong"));
    }
}
