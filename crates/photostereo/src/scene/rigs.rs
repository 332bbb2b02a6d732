//! Light rigs for the renderer: directions are unit vectors in the camera frame (x right, y up,
//! z toward the camera) from the surface toward the light. Slant = angle from the viewing axis
//! (+z); tilt = angle in the image plane from +x, counter-clockwise (toward +y, the image's top).

use crate::base::error::{Error, Result};
use crate::model::lights::Lights;

/// Slant of the `square4` rig, degrees (the paper's rig).
pub const SQUARE4_SLANT_DEG: f64 = 35.0;
/// Slant of the `ring8` (and `ring-N`) rig, degrees.
pub const RING_SLANT_DEG: f64 = 40.0;
/// Largest slant of the `dome-N` rig, degrees.
pub const DOME_MAX_SLANT_DEG: f64 = 60.0;

/// A light rig by name, as `--rig` accepts it.
#[derive(Clone, Debug, PartialEq)]
pub enum Rig {
    /// Four lights at the corners of a square: slant 35°, tilts 45°, 135°, 225°, 315°.
    Square4,
    /// `n` lights at slant 40°, tilts 360°/n apart starting at 0° (`ring8` is n = 8).
    Ring(usize),
    /// `n` lights on a golden-angle (Fibonacci) spiral covering the cap of slant 0°..60° with
    /// equal solid angle per light.
    Dome(usize),
    /// Directions given as lights, e.g. read from a light file
    /// ([`crate::io::light_files::parse_rig`]); `name` says where they come from.
    Given { name: String, lights: Lights },
}

impl Rig {
    /// Names of the built-in rigs, as `--list` shows them.
    pub const NAMES: &'static [&'static str] = &["square4", "ring8", "ring-N", "dome-N"];

    /// Parses `square4`, `ring8`, `ring-N`, `dome-N` (N ≥ 3). A light file is read by
    /// [`crate::io::light_files::parse_rig`].
    pub fn parse(s: &str) -> Result<Rig> {
        let count = |rest: &str, what: &str| -> Result<usize> {
            match rest.parse::<usize>() {
                Ok(n) if (3..=10_000).contains(&n) => Ok(n),
                _ => Err(Error::invalid(format!(
                    "rig '{s}': expected {what}-N with N a light count in 3..=10000"
                ))),
            }
        };
        match s {
            "square4" => Ok(Rig::Square4),
            "ring8" => Ok(Rig::Ring(8)),
            _ => {
                if let Some(rest) = s.strip_prefix("dome-") {
                    return Ok(Rig::Dome(count(rest, "dome")?));
                }
                if let Some(rest) = s.strip_prefix("ring-") {
                    return Ok(Rig::Ring(count(rest, "ring")?));
                }
                Err(Error::invalid(format!(
                    "unknown rig '{s}': expected square4, ring8, ring-N, dome-N or an existing light file"
                )))
            }
        }
    }

    /// The rig's name (the file path for a light file).
    pub fn name(&self) -> String {
        match self {
            Rig::Square4 => "square4".into(),
            Rig::Ring(8) => "ring8".into(),
            Rig::Ring(n) => format!("ring-{n}"),
            Rig::Dome(n) => format!("dome-{n}"),
            Rig::Given { name, .. } => name.clone(),
        }
    }

    /// The light directions (unit intensity).
    pub fn lights(&self) -> Result<Lights> {
        match self {
            Rig::Square4 => Ok(slant_tilt_lights(
                SQUARE4_SLANT_DEG,
                &[45.0, 135.0, 225.0, 315.0],
            )),
            Rig::Ring(n) => {
                let tilts: Vec<f64> = (0..*n).map(|k| 360.0 * k as f64 / *n as f64).collect();
                Ok(slant_tilt_lights(RING_SLANT_DEG, &tilts))
            }
            Rig::Dome(n) => Ok(dome_lights(*n, DOME_MAX_SLANT_DEG)),
            Rig::Given { lights, .. } => Ok(lights.clone()),
        }
    }
}

/// Lights at one slant and the given tilts (degrees).
pub fn slant_tilt_lights(slant_deg: f64, tilts_deg: &[f64]) -> Lights {
    let s = slant_deg.to_radians();
    let dirs: Vec<[f64; 3]> = tilts_deg
        .iter()
        .map(|t| {
            let t = t.to_radians();
            [s.sin() * t.cos(), s.sin() * t.sin(), s.cos()]
        })
        .collect();
    Lights {
        intensities: vec![[1.0; 3]; dirs.len()],
        directions: dirs,
        renormalised: 0,
        near: None,
        camera: None,
    }
}

/// `n` directions on a golden-angle spiral over the cap of slants 0..`max_slant_deg`: light k
/// has cos(slant) = 1 − (1 − cos max)·(k + ½)/n (equal solid angle per light) and tilt k·137.5°.
pub fn dome_lights(n: usize, max_slant_deg: f64) -> Lights {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let cos_max = max_slant_deg.to_radians().cos();
    let dirs: Vec<[f64; 3]> = (0..n)
        .map(|k| {
            let z = 1.0 - (1.0 - cos_max) * (k as f64 + 0.5) / n as f64;
            let r = (1.0 - z * z).max(0.0).sqrt();
            let t = golden * k as f64;
            [r * t.cos(), r * t.sin(), z]
        })
        .collect();
    Lights {
        intensities: vec![[1.0; 3]; dirs.len()],
        directions: dirs,
        renormalised: 0,
        near: None,
        camera: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn square4_is_the_papers_rig() {
        let l = Rig::parse("square4").unwrap().lights().unwrap();
        assert_eq!(l.len(), 4);
        for (k, d) in l.directions.iter().enumerate() {
            assert!((d[2] - 35f64.to_radians().cos()).abs() < 1e-12);
            let tilt = d[1].atan2(d[0]).to_degrees().rem_euclid(360.0);
            assert!(
                (tilt - (45.0 + 90.0 * k as f64)).abs() < 1e-9,
                "tilt {tilt}"
            );
        }
    }

    #[test]
    fn dome_spreads_over_the_cap() {
        let l = Rig::parse("dome-96").unwrap().lights().unwrap();
        assert_eq!(l.len(), 96);
        let cos60 = 0.5;
        assert!(l
            .directions
            .iter()
            .all(|d| d[2] >= cos60 - 1e-12 && d[2] <= 1.0));
        // Mean direction close to the axis (the spiral is balanced).
        let mx: f64 = l.directions.iter().map(|d| d[0]).sum::<f64>() / 96.0;
        let my: f64 = l.directions.iter().map(|d| d[1]).sum::<f64>() / 96.0;
        assert!(mx.abs() < 0.03 && my.abs() < 0.03, "{mx} {my}");
        assert!(l.check_rank().is_ok());
    }

    #[test]
    fn bad_names_are_refused() {
        assert!(Rig::parse("dome-2").is_err());
        let e = Rig::parse("hexagon").unwrap_err().to_string();
        assert!(e.contains("square4") && e.contains("dome-N"), "{e}");
        assert_eq!(Rig::parse("ring8").unwrap().lights().unwrap().len(), 8);
        assert_eq!(Rig::parse("ring-5").unwrap().name(), "ring-5");
    }
}
