//! Light directions and intensities, and the check that a rig can determine a normal at all
//! (the light files themselves are read by [`crate::io::light_files`]).
//!
//! Directions are unit vectors in the camera frame (x right, y up, z toward the camera), from the
//! surface toward the distant light. Intensities are per light and per channel (R, G, B); every
//! image channel is divided by its light's intensity before estimation.

use crate::base::error::{Error, Result};
use serde::Serialize;

/// A rig's directions above this condition number are refused as (near) coplanar: normals
/// estimated with them would amplify the image noise by about that factor.
pub const MAX_CONDITION_NUMBER: f64 = 1.0e3;

/// The range of a light's relative intensity. Readings are divided by it in `f32`: within
/// this range every reading of an 8- or 16-bit image (1/65535 … 1) and of a float image up to
/// 10⁶ stays a normal `f32` number after the division (f32 spans 1.2·10⁻³⁸ … 3.4·10³⁸), so no
/// reading turns into 0 or ∞.
pub const INTENSITY_RANGE: [f64; 2] = [1e-30, 1e30];

/// True when `x` is a light intensity within [`INTENSITY_RANGE`].
pub fn intensity_in_range(x: f64) -> bool {
    (INTENSITY_RANGE[0]..=INTENSITY_RANGE[1]).contains(&x)
}

/// The lights of a capture, one per image: their directions and intensities — of distant
/// lights, or, for near point lights, the distant approximation at the object's centre — with
/// the near-light model (`near`) and the camera (`camera`) when the rig has them.
#[derive(Clone, Debug, PartialEq)]
pub struct Lights {
    /// Unit directions toward each light, camera frame.
    pub directions: Vec<[f64; 3]>,
    /// Relative intensity of each light per channel (R, G, B); grey captures use the mean.
    pub intensities: Vec<[f64; 3]>,
    /// How many input directions were not unit length and were normalised.
    pub renormalised: usize,
    /// Near point lights ([`crate::model::lightmodel`]): then `directions` and `intensities` are the
    /// distant approximation at the object's centre (directions toward each LED and the
    /// brightness it gives there), and the kernel asks the model for per-pixel vectors.
    pub near: Option<std::sync::Arc<crate::model::lightmodel::NearLights>>,
    /// A pinhole camera and the object's mean distance (mm) for distant lights seen through a
    /// lens (`K.txt` without LED positions): the depth is then integrated through the camera,
    /// Z in mm. Near lights carry their own camera.
    pub camera: Option<(crate::model::lightmodel::Camera, f64)>,
}

impl Lights {
    /// Lights with unit intensity. Directions are normalised; zero or non-finite ones are an error.
    pub fn new(directions: &[[f64; 3]]) -> Result<Self> {
        let mut out = Vec::with_capacity(directions.len());
        let mut renormalised = 0;
        for (k, d) in directions.iter().enumerate() {
            out.push(
                normalise_direction(*d, &mut renormalised).map_err(|m| {
                    Error::invalid(format!("light {} direction {:?}: {m}", k + 1, d))
                })?,
            );
        }
        Ok(Lights {
            intensities: vec![[1.0; 3]; out.len()],
            directions: out,
            renormalised,
            near: None,
            camera: None,
        })
    }

    /// The camera and mean distance (mm) the depth is integrated with, if any: the near
    /// model's, or the one given for distant lights.
    pub fn perspective(&self) -> Option<(crate::model::lightmodel::Camera, f64)> {
        match &self.near {
            Some(m) => Some((m.camera, m.mean_distance)),
            None => self.camera,
        }
    }

    /// Number of lights.
    pub fn len(&self) -> usize {
        self.directions.len()
    }

    /// True when there is no light.
    pub fn is_empty(&self) -> bool {
        self.directions.is_empty()
    }

    /// Replaces the intensities (one RGB triple per light); each must lie in
    /// [`INTENSITY_RANGE`].
    pub fn with_intensities(mut self, intensities: Vec<[f64; 3]>) -> Result<Self> {
        if intensities.len() != self.len() {
            return Err(Error::invalid(format!(
                "{} light intensities for {} light directions",
                intensities.len(),
                self.len()
            )));
        }
        for (k, v) in intensities.iter().enumerate() {
            if let Some(bad) = v.iter().find(|x| !intensity_in_range(**x)) {
                return Err(Error::invalid(format!(
                    "light {} intensity {bad}: expected a value in [{:e}, {:e}]",
                    k + 1,
                    INTENSITY_RANGE[0],
                    INTENSITY_RANGE[1]
                )));
            }
        }
        self.intensities = intensities;
        Ok(self)
    }

    /// Checks that the rig determines normals: at least three lights and a light matrix of rank
    /// three with condition number at most [`MAX_CONDITION_NUMBER`]. Returns the condition number.
    pub fn check_rank(&self) -> Result<f64> {
        if self.len() < 3 {
            return Err(Error::invalid(format!(
                "{} light(s): photometric stereo needs at least three",
                self.len()
            )));
        }
        let cond = self.condition_number();
        if cond.is_nan() || cond > MAX_CONDITION_NUMBER {
            return Err(Error::invalid(format!(
                "the light directions have rank < 3 (coplanar or nearly so): condition number {:.3e} exceeds {:.0e}",
                cond, MAX_CONDITION_NUMBER
            )));
        }
        Ok(cond)
    }

    /// Condition number of the N×3 light matrix (ratio of its largest to smallest singular value).
    pub fn condition_number(&self) -> f64 {
        let ltl = self.gram();
        let eig = nalgebra::SymmetricEigen::new(ltl).eigenvalues;
        let max = eig.max().max(0.0);
        let min = eig.min().max(0.0);
        if min <= 0.0 {
            f64::INFINITY
        } else {
            (max / min).sqrt()
        }
    }

    /// LᵀL, the 3×3 normal matrix of all lights.
    pub fn gram(&self) -> nalgebra::Matrix3<f64> {
        let mut m = nalgebra::Matrix3::zeros();
        for d in &self.directions {
            let v = nalgebra::Vector3::from(*d);
            m += v * v.transpose();
        }
        m
    }

    /// Returns the lights reordered by `order` (a permutation of 0..N).
    pub fn permuted(&self, order: &[usize]) -> Lights {
        Lights {
            directions: order.iter().map(|&k| self.directions[k]).collect(),
            intensities: order.iter().map(|&k| self.intensities[k]).collect(),
            renormalised: self.renormalised,
            near: self
                .near
                .as_ref()
                .map(|m| std::sync::Arc::new(m.permuted(order))),
            camera: self.camera,
        }
    }
}

/// The four lights of a rig closest to a square rig — slant `slant_deg`, tilts 90° apart at any
/// common rotation — as indices in tilt order. For every light taken as the first corner, each
/// of the four target directions gets its nearest light; the rotation with the smallest sum of
/// angular distances wins. `None` with fewer than four lights or when two corners would share
/// a light.
pub fn closest_square_rig(lights: &Lights, slant_deg: f64) -> Option<[usize; 4]> {
    let n = lights.len();
    if n < 4 {
        return None;
    }
    let slant = slant_deg.to_radians();
    let angle = |a: &[f64; 3], b: &[f64; 3]| {
        (a[0] * b[0] + a[1] * b[1] + a[2] * b[2])
            .clamp(-1.0, 1.0)
            .acos()
    };
    let mut best: Option<(f64, [usize; 4])> = None;
    for d in &lights.directions {
        let t0 = d[1].atan2(d[0]);
        let mut pick = [0usize; 4];
        let mut cost = 0.0;
        for (j, slot) in pick.iter_mut().enumerate() {
            let t = t0 + j as f64 * std::f64::consts::FRAC_PI_2;
            let target = [slant.sin() * t.cos(), slant.sin() * t.sin(), slant.cos()];
            let (k, a) = lights
                .directions
                .iter()
                .enumerate()
                .map(|(k, l)| (k, angle(l, &target)))
                .min_by(|a, b| a.1.total_cmp(&b.1))?;
            *slot = k;
            cost += a;
        }
        let distinct = (0..4).all(|i| (i + 1..4).all(|j| pick[i] != pick[j]));
        if distinct && best.is_none_or(|(c, _)| cost < c) {
            best = Some((cost, pick));
        }
    }
    best.map(|(_, p)| p)
}

/// `d` as a unit vector, counting in `renormalised` a direction that was not unit length;
/// the message says why a zero or non-finite direction is refused.
pub fn normalise_direction(d: [f64; 3], renormalised: &mut usize) -> Result<[f64; 3], String> {
    if d.iter().any(|x| !x.is_finite()) {
        return Err(format!("direction {:?} is not finite", d));
    }
    let norm = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    if norm < 1e-9 {
        return Err("zero light direction: expected a non-zero vector x y z".into());
    }
    if (norm - 1.0).abs() > 1e-3 {
        *renormalised += 1;
    }
    Ok([d[0] / norm, d[1] / norm, d[2] / norm])
}

/// The refined lights and what the refinement changed.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct LightRefinement {
    /// Refined unit directions, camera frame.
    pub directions: Vec<[f64; 3]>,
    /// Relative gain of each light: its readings are divided by it.
    pub gains: Vec<f64>,
    /// Angle between each given and refined direction, degrees.
    pub angle_deg: Vec<f64>,
    /// Pixels whose fits entered the last round.
    pub pixels: usize,
    /// Rounds run.
    pub rounds: usize,
    /// Largest direction change of the last round, degrees.
    pub last_change_deg: f64,
    /// The median relative misfit of the pixels' robust fits (robust scale over mean level)
    /// with the given lights and with the refined ones.
    pub misfit_before: f64,
    pub misfit_after: f64,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn coplanar_lights_are_refused_with_condition_number() {
        let l = Lights::new(&[[1.0, 0.0, 1.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 1.0]]).unwrap();
        let e = l.check_rank().unwrap_err().to_string();
        assert!(e.contains("condition number"), "{e}");
        let l = Lights::new(&[[1.0, 0.0, 1.0], [0.0, 1.0, 1.0], [-1.0, 0.0, 1.0]]).unwrap();
        let c = l.check_rank().unwrap();
        assert!(c > 1.0 && c < 10.0);
    }

    #[test]
    fn square_rig_is_found_in_a_dense_rig() {
        // A dense dome in 10° steps with the four exact corners at slant 35° hidden inside.
        let mut dirs = Vec::new();
        for s in [10.0f64, 25.0, 45.0, 60.0] {
            for t in (0..36).map(|i| i as f64 * 10.0 + 3.0) {
                let (s, t) = (s.to_radians(), t.to_radians());
                dirs.push([s.sin() * t.cos(), s.sin() * t.sin(), s.cos()]);
            }
        }
        let corners: Vec<usize> = (0..4)
            .map(|j| {
                let (s, t) = (35f64.to_radians(), (20.0 + 90.0 * j as f64).to_radians());
                dirs.push([s.sin() * t.cos(), s.sin() * t.sin(), s.cos()]);
                dirs.len() - 1
            })
            .collect();
        let l = Lights::new(&dirs).unwrap();
        let mut got = closest_square_rig(&l, 35.0).unwrap().to_vec();
        got.sort();
        assert_eq!(got, corners);
    }
}
