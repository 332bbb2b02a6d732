//! Physical plausibility of a capture, checked once it is loaded: what cannot work is refused
//! with an [`Error`], what is merely doubtful becomes a note (which `run` prints and writes into
//! `report.json`'s `notes`).
//!
//! Refused: every light at or below the horizon
//! (z ≤ 0: no light reaches a surface that faces the camera); no pixel of the mask with three
//! lights whose readings are neither black nor saturated (all-black or saturated images).
//!
//! Noted: a light at or below the horizon; fewer than three lights above it; two lights with the
//! same direction; an image more than [`MAX_SATURATED_SHARE`] saturated or more than
//! [`MAX_BLACK_SHARE`] black inside the mask; an image uniform inside the mask; two images
//! identical inside the mask; and, after estimation, mask pixels left without a normal
//! ([`unestimated_note`]).

use crate::base::error::{Error, Result};
use crate::model::capture::Capture;
use std::collections::HashMap;

/// Share of mask pixels saturated in an image above which a note is made.
pub const MAX_SATURATED_SHARE: f64 = 0.2;
/// Share of mask pixels black in an image above which a note is made.
pub const MAX_BLACK_SHARE: f64 = 0.2;
/// Two lights closer than this (degrees) are reported as the same direction.
pub const DUPLICATE_LIGHT_DEG: f64 = 0.01;
/// At most this many items are listed in one note; the rest are counted.
const LISTED: usize = 6;

/// Checks a loaded capture (see the module documentation). `Err` for what cannot work,
/// otherwise the notes for what is doubtful.
pub fn check_capture(capture: &Capture) -> Result<Vec<String>> {
    let mut notes = Vec::new();
    check_lights(capture, &mut notes)?;
    check_images(capture, &mut notes)?;
    Ok(notes)
}

/// A note counting the mask pixels left without a normal (zero or non-finite) after
/// estimation; `None` when every mask pixel has one. `normals` and `mask` are full-frame.
pub fn unestimated_note(normals: &[[f32; 3]], mask: &[bool]) -> Option<String> {
    let inside = mask.iter().filter(|&&m| m).count();
    let missing = normals
        .iter()
        .zip(mask)
        .filter(|(n, &m)| m && (**n == [0.0; 3] || n.iter().any(|v| !v.is_finite())))
        .count();
    (missing > 0).then(|| {
        format!(
            "{missing} of {inside} mask pixels ({:.1}%) were left without a normal (written as (0, 0, 0))",
            100.0 * missing as f64 / inside.max(1) as f64
        )
    })
}

fn check_lights(capture: &Capture, notes: &mut Vec<String>) -> Result<()> {
    let dirs = &capture.lights.directions;
    let n = dirs.len();
    let below: Vec<usize> = (0..n).filter(|&k| dirs[k][2] <= 0.0).collect();
    if !below.is_empty() && below.len() == n {
        return Err(Error::invalid(format!(
            "all {n} lights are at or below the horizon (z ≤ 0): no light reaches a surface that faces \
             the camera. Directions point from the surface toward the light with z toward the camera; \
             check the sign of the light file's third column"
        )));
    }
    if !below.is_empty() {
        notes.push(format!(
            "{} of {n} light(s) at or below the horizon (z ≤ 0): light {}; they reach only surfaces \
             steeper than their elevation, check their directions",
            below.len(),
            list(below.iter().map(|k| k + 1))
        ));
        let above = n - below.len();
        if above < 3 {
            notes.push(format!(
                "only {above} light(s) above the horizon: surfaces facing the camera see fewer than three lights"
            ));
        }
    }
    let cos_min = DUPLICATE_LIGHT_DEG.to_radians().cos();
    let mut pairs = Vec::new();
    for a in 0..n {
        for b in a + 1..n {
            let d = dirs[a][0] * dirs[b][0] + dirs[a][1] * dirs[b][1] + dirs[a][2] * dirs[b][2];
            if d >= cos_min {
                pairs.push(format!("{} and {}", a + 1, b + 1));
            }
        }
    }
    if !pairs.is_empty() {
        notes.push(format!(
            "{} pair(s) of lights share a direction (within {DUPLICATE_LIGHT_DEG}°): lights {}; \
             a duplicated light adds no information about the normal",
            pairs.len(),
            list(pairs.iter())
        ));
    }
    Ok(())
}

/// Per light: how its readings inside the mask look.
#[derive(Clone, Default)]
struct ImageStats {
    saturated: usize,
    black: usize,
    min: f32,
    max: f32,
    hash: u64,
}

fn check_images(capture: &Capture, notes: &mut Vec<String>) -> Result<()> {
    let (n, c, p) = (capture.n_lights(), capture.channels, capture.n_pixels());
    if p == 0 || n == 0 || (!capture.is_tiled() && capture.samples.len() != p * n * c) {
        return Ok(());
    }
    // Back to the image values: the samples were divided by each light's intensity.
    let scale: Vec<[f32; 3]> = capture
        .lights
        .intensities
        .iter()
        .map(|i| {
            if c == 1 {
                [((i[0] + i[1] + i[2]) / 3.0) as f32; 3]
            } else {
                [i[0] as f32, i[1] as f32, i[2] as f32]
            }
        })
        .collect();
    let integer = matches!(capture.bit_depth, 8 | 16);
    let step = if integer {
        0.5 / ((1u32 << capture.bit_depth) - 1) as f32
    } else {
        0.0
    };
    let (black_at, saturated_at) = (step, if integer { 1.0 - step } else { f32::INFINITY });
    let mut stats = vec![
        ImageStats {
            min: f32::INFINITY,
            max: f32::NEG_INFINITY,
            hash: 0xcbf2_9ce4_8422_2325,
            ..Default::default()
        };
        n
    ];
    let mut usable_pixels = 0usize;
    capture.for_each_tile(|_, tile| {
        for px in tile.samples.chunks_exact(n * c) {
            let mut usable = 0;
            for (k, s) in stats.iter_mut().enumerate() {
                let v = &px[k * c..(k + 1) * c];
                let mut all_black = true;
                let mut any_saturated = false;
                for (ch, &x) in v.iter().enumerate() {
                    let raw = x * scale[k][ch];
                    all_black &= raw <= black_at;
                    any_saturated |= raw >= saturated_at;
                    s.min = s.min.min(raw);
                    s.max = s.max.max(raw);
                    s.hash = (s.hash ^ raw.to_bits() as u64).wrapping_mul(0x0100_0000_01b3);
                }
                s.black += usize::from(all_black);
                s.saturated += usize::from(any_saturated);
                usable += usize::from(!all_black && !any_saturated);
            }
            usable_pixels += usize::from(usable >= 3);
        }
        Ok(())
    })?;
    let name = |k: usize| match capture.sources.get(k) {
        Some(p) => format!("image {} ({})", k + 1, p.display()),
        None => format!("image {}", k + 1),
    };
    if usable_pixels == 0 {
        let all_black = stats.iter().all(|s| s.black == p);
        let all_saturated = stats.iter().all(|s| s.saturated == p);
        let what = if all_black {
            "every image is black inside the mask".to_string()
        } else if all_saturated {
            "every image is saturated inside the mask".to_string()
        } else {
            "no pixel of the mask has three lights whose readings are neither black nor saturated"
                .to_string()
        };
        return Err(Error::invalid(format!(
            "{what}: nothing can be estimated (check the exposure, the images and the mask)"
        )));
    }
    let share = |count: usize| count as f64 / p as f64;
    let mut black = Vec::new();
    let mut saturated = Vec::new();
    let mut uniform = Vec::new();
    for (k, s) in stats.iter().enumerate() {
        if share(s.saturated) > MAX_SATURATED_SHARE {
            saturated.push(format!("{} {:.0}%", name(k), 100.0 * share(s.saturated)));
        }
        if share(s.black) > MAX_BLACK_SHARE {
            black.push(format!("{} {:.0}%", name(k), 100.0 * share(s.black)));
        }
        if p > 1 && s.min == s.max && s.black < p && s.saturated < p {
            uniform.push(name(k));
        }
    }
    if !saturated.is_empty() {
        notes.push(format!(
            "{} image(s) more than {:.0}% saturated inside the mask: {}",
            saturated.len(),
            100.0 * MAX_SATURATED_SHARE,
            list(saturated.iter())
        ));
    }
    if !black.is_empty() {
        notes.push(format!(
            "{} image(s) more than {:.0}% black inside the mask: {}",
            black.len(),
            100.0 * MAX_BLACK_SHARE,
            list(black.iter())
        ));
    }
    if !uniform.is_empty() {
        notes.push(format!(
            "{} image(s) uniform inside the mask (one value everywhere): {}",
            uniform.len(),
            list(uniform.iter())
        ));
    }
    let mut by_hash: HashMap<(u64, u32, u32), Vec<usize>> = HashMap::new();
    for (k, s) in stats.iter().enumerate() {
        by_hash
            .entry((s.hash, s.min.to_bits(), s.max.to_bits()))
            .or_default()
            .push(k);
    }
    let mut same: Vec<&Vec<usize>> = by_hash.values().filter(|v| v.len() > 1).collect();
    same.sort();
    if !same.is_empty() {
        notes.push(format!(
            "identical images inside the mask (the same picture under different lights?): {}",
            list(
                same.iter()
                    .map(|v| format!("images {}", list(v.iter().map(|k| k + 1))))
            )
        ));
    }
    Ok(())
}

/// "a, b, c" with at most six items, then "and K more".
pub fn list<T: std::fmt::Display>(items: impl Iterator<Item = T>) -> String {
    let all: Vec<String> = items.map(|i| i.to_string()).collect();
    if all.len() <= LISTED {
        all.join(", ")
    } else {
        format!(
            "{} and {} more",
            all[..LISTED].join(", "),
            all.len() - LISTED
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::image::Image;
    use crate::model::lights::Lights;

    fn sphere(lights: &[[f64; 3]], size: usize, gain: f32) -> Vec<Image> {
        lights
            .iter()
            .map(|l| {
                let norm = (l[0] * l[0] + l[1] * l[1] + l[2] * l[2]).sqrt() as f32;
                let data = (0..size * size)
                    .map(|i| {
                        let x = (i % size) as f32 / size as f32 - 0.5;
                        let y = 0.5 - (i / size) as f32 / size as f32;
                        let z = (1.0 - x * x - y * y).max(0.0).sqrt();
                        let s = (x * l[0] as f32 + y * l[1] as f32 + z * l[2] as f32) / norm;
                        (gain * s.max(0.0)).min(1.0)
                    })
                    .collect();
                Image {
                    width: size,
                    height: size,
                    channels: 1,
                    bit_depth: 16,
                    data,
                }
            })
            .collect()
    }

    const RIG: [[f64; 3]; 4] = [
        [0.3, 0.3, 0.9],
        [-0.3, 0.3, 0.9],
        [-0.3, -0.3, 0.9],
        [0.3, -0.3, 0.9],
    ];

    #[test]
    fn a_sound_capture_has_no_notes() {
        let cap =
            Capture::from_images(&sphere(&RIG, 16, 0.8), Lights::new(&RIG).unwrap(), None).unwrap();
        assert_eq!(check_capture(&cap).unwrap(), Vec::<String>::new());
    }

    #[test]
    fn lights_below_the_horizon() {
        let all: Vec<[f64; 3]> = RIG.iter().map(|d| [d[0], d[1], -d[2]]).collect();
        let cap =
            Capture::from_images(&sphere(&RIG, 16, 0.8), Lights::new(&all).unwrap(), None).unwrap();
        let e = check_capture(&cap).unwrap_err().to_string();
        assert!(e.contains("all 4 lights") && e.contains("horizon"), "{e}");
        let mut one = RIG.to_vec();
        one[2][2] = -0.2;
        let cap =
            Capture::from_images(&sphere(&RIG, 16, 0.8), Lights::new(&one).unwrap(), None).unwrap();
        let notes = check_capture(&cap).unwrap();
        assert!(
            notes
                .iter()
                .any(|n| n.contains("light 3") && n.contains("horizon")),
            "{notes:?}"
        );
    }

    #[test]
    fn duplicated_lights_and_identical_images() {
        let mut rig = RIG.to_vec();
        rig.push(RIG[1]);
        let cap =
            Capture::from_images(&sphere(&rig, 16, 0.8), Lights::new(&rig).unwrap(), None).unwrap();
        let notes = check_capture(&cap).unwrap();
        assert!(
            notes.iter().any(|n| n.contains("lights 2 and 5")),
            "{notes:?}"
        );
        assert!(notes.iter().any(|n| n.contains("images 2, 5")), "{notes:?}");
    }

    #[test]
    fn black_and_saturated_images() {
        let lights = Lights::new(&RIG).unwrap();
        let mut imgs = sphere(&RIG, 16, 0.8);
        for img in &mut imgs {
            img.data.iter_mut().for_each(|v| *v = 0.0);
        }
        let cap = Capture::from_images(&imgs, lights.clone(), None).unwrap();
        let e = check_capture(&cap).unwrap_err().to_string();
        assert!(e.contains("black"), "{e}");
        let cap = Capture::from_images(&sphere(&RIG, 16, 100.0), lights.clone(), None).unwrap();
        let e = check_capture(&cap).unwrap_err().to_string();
        assert!(e.contains("saturated"), "{e}");
        let mut imgs = sphere(&RIG, 16, 0.8);
        imgs[1].data.iter_mut().for_each(|v| *v = 1.0);
        let cap = Capture::from_images(&imgs, lights, None).unwrap();
        let notes = check_capture(&cap).unwrap();
        assert!(
            notes
                .iter()
                .any(|n| n.contains("saturated") && n.contains("image 2 100%")),
            "{notes:?}"
        );
    }

    #[test]
    fn pixels_without_normals_are_counted() {
        let normals = [[0.0, 0.0, 1.0], [0.0; 3], [f32::NAN, 0.0, 1.0], [0.0; 3]];
        let mask = [true, true, true, false];
        let n = unestimated_note(&normals, &mask).unwrap();
        assert!(n.starts_with("2 of 3 mask pixels"), "{n}");
        assert!(unestimated_note(&normals[..1], &mask[..1]).is_none());
    }
}
