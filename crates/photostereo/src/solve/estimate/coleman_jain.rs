//! Coleman & Jain's four-source method (ALGORITHMS.md §3), generalised to N lights.
//!
//! From each leave-one-out subset of lights (the four triplets when N = 4) an albedo. If the
//! albedos disagree — relative spread (max − min) / mean above a threshold — the pixel holds a
//! highlight, which inflates the albedo of every subset that contains it: keep the subset with
//! the smallest albedo, i.e. drop the light whose removal gives it. With N > 4 this is iterated
//! while the spread stays above the threshold, down to the detector's floor on kept lights
//! (`min_kept_share`, never fewer than three). Otherwise all
//! lights are used. There is no shadow handling: that is the method.
//!
//! The threshold is calibrated on the capture itself, for 95% of noise-only Lambertian pixels:
//! for a deterministic sample of pixels, the intensities predicted by their all-light fit plus
//! Gaussian noise of the capture's noise model ([`crate::solve::detect::noise_model`]) give a spread
//! distribution whose 95% quantile is the threshold.

use super::{channel_mean, write_normal_albedo_with, Estimate, Estimator, SubsetSolver, CHUNK};
use crate::base::error::Result;
use crate::base::progress::Progress;
use crate::base::rng::Pcg32;
use crate::model::capture::Capture;
use crate::solve::detect::{noise_model, DetectionParams, NoiseModel};
use crate::solve::estimate::status;
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

/// Coleman & Jain; the detector's parameters give the noise model used for calibration.
#[derive(Clone, Debug)]
pub struct ColemanJain {
    pub params: DetectionParams,
    /// Share of noise-only Lambertian pixels the threshold accepts (default 0.95).
    pub calibration_quantile: f64,
}

impl Default for ColemanJain {
    fn default() -> Self {
        ColemanJain {
            params: DetectionParams::default(),
            calibration_quantile: 0.95,
        }
    }
}

/// Least-squares state over a set of kept lights, with O(N) leave-one-out albedos
/// (m₋ₖ = m − G⁻¹ lₖ eₖ / (1 − hₖ), the standard deletion formula).
#[derive(Clone)]
struct Fit<'a> {
    directions: &'a [[f64; 3]],
    gram: Matrix3<f64>,
    gram_inv: Matrix3<f64>,
    m: Vector3<f64>,
}

impl<'a> Fit<'a> {
    fn new(directions: &'a [[f64; 3]], kept: &[bool], grey: &[f64]) -> Option<Self> {
        let mut gram = Matrix3::zeros();
        for (d, _) in directions.iter().zip(kept).filter(|(_, &k)| k) {
            let l = Vector3::from(*d);
            gram += l * l.transpose();
        }
        let mut fit = Fit {
            directions,
            gram,
            gram_inv: Matrix3::zeros(),
            m: Vector3::zeros(),
        };
        fit.refit(kept, grey)?;
        Some(fit)
    }

    fn refit(&mut self, kept: &[bool], grey: &[f64]) -> Option<()> {
        self.gram_inv = self.gram.try_inverse()?;
        let mut b = Vector3::zeros();
        for ((d, &i), _) in self
            .directions
            .iter()
            .zip(grey)
            .zip(kept)
            .filter(|(_, &k)| k)
        {
            b += Vector3::from(*d) * i;
        }
        self.m = self.gram_inv * b;
        Some(())
    }

    fn remove(&mut self, k: usize, kept: &mut [bool], grey: &[f64]) -> Option<()> {
        kept[k] = false;
        let l = Vector3::from(self.directions[k]);
        self.gram -= l * l.transpose();
        self.refit(kept, grey)
    }

    /// Relative spread (max − min) / mean of the leave-one-out albedos, and the light whose
    /// removal gives the smallest albedo.
    fn spread(&self, kept: &[bool], grey: &[f64]) -> Option<(f64, usize)> {
        let (mut lo, mut hi, mut sum, mut count, mut arg) =
            (f64::INFINITY, 0f64, 0.0, 0, usize::MAX);
        for (k, (d, &i)) in self.directions.iter().zip(grey).enumerate() {
            if !kept[k] {
                continue;
            }
            let l = Vector3::from(*d);
            let v = self.gram_inv * l;
            let h = l.dot(&v);
            if h >= 1.0 - 1e-9 {
                return None;
            }
            let e = i - l.dot(&self.m);
            let rho = (self.m - v * (e / (1.0 - h))).norm();
            if rho < lo {
                lo = rho;
                arg = k;
            }
            hi = hi.max(rho);
            sum += rho;
            count += 1;
        }
        let mean = sum / count.max(1) as f64;
        (mean > 0.0).then_some(((hi - lo) / mean, arg))
    }
}

impl ColemanJain {
    fn calibrate(&self, capture: &Capture, noise: &NoiseModel) -> f64 {
        let n = capture.n_lights();
        let c = capture.channels;
        let all = SubsetSolver::all_lights(capture);
        let dirs = &capture.lights.directions;
        let mut rng = Pcg32::new(0x0C0C_5EED, 0);
        let mut grey = vec![0f64; n];
        let mut sim = vec![0f64; n];
        let kept = vec![true; n];
        let mut spreads = Vec::new();
        let stride = (capture.n_pixels() / 2000).max(1);
        // Near lights: each sampled pixel's own vectors at the current surface.
        let mut lights = capture.pixel_lights();
        let mut buf = vec![[0f64; 3]; n];
        for p in (0..capture.n_pixels()).step_by(stride) {
            channel_mean(capture.pixel_samples(p), c, &mut grey);
            let dirs: &[[f64; 3]] = if lights.is_near() {
                buf.copy_from_slice(lights.at(capture.pixels[p] as usize));
                &buf
            } else {
                dirs
            };
            let m = if lights.is_near() {
                crate::solve::lambert::solve_with(dirs, None, &grey)
            } else {
                all.solve(&grey)
            };
            let Some(m) = m else { continue };
            let clean: Vec<f64> = dirs
                .iter()
                .map(|l| l[0] * m.x + l[1] * m.y + l[2] * m.z)
                .collect();
            if clean.iter().any(|&v| v <= 0.0) {
                continue;
            }
            let level = clean.iter().sum::<f64>() / n as f64;
            let sd = noise.variance(level).sqrt();
            for _ in 0..4 {
                for (s, v) in sim.iter_mut().zip(&clean) {
                    *s = v + sd * rng.next_normal();
                }
                if let Some((sp, _)) =
                    Fit::new(dirs, &kept, &sim).and_then(|f| f.spread(&kept, &sim))
                {
                    spreads.push(sp);
                }
            }
        }
        if spreads.is_empty() {
            return f64::INFINITY;
        }
        let k =
            ((spreads.len() as f64 * self.calibration_quantile) as usize).min(spreads.len() - 1);
        let (_, v, _) = spreads.select_nth_unstable_by(k, |a, b| a.total_cmp(b));
        *v
    }
}

impl Estimator for ColemanJain {
    fn name(&self) -> &'static str {
        "coleman-jain"
    }

    fn estimate(&self, capture: &Capture, progress: &dyn Progress) -> Result<Estimate> {
        let n = capture.n_lights();
        if n < 4 {
            return Err(crate::Error::invalid(format!(
                "coleman-jain needs at least four lights; the capture has {n}"
            )));
        }
        let noise = noise_model(capture, &self.params, progress)?;
        let threshold = self.calibrate(capture, &noise);
        self.estimate_calibrated(capture, &noise, threshold, progress)
    }
}

impl ColemanJain {
    /// The noise model and the spread threshold of a capture (or of a view holding the pixels
    /// the statistics read, see [`crate::solve::tiled::statistics_view`]).
    pub fn calibration(
        &self,
        capture: &Capture,
        progress: &dyn Progress,
    ) -> Result<(NoiseModel, f64)> {
        let noise = noise_model(capture, &self.params, progress)?;
        let threshold = self.calibrate(capture, &noise);
        Ok((noise, threshold))
    }

    /// The per-pixel estimate with a given noise model and threshold ([`Self::calibration`]):
    /// what [`Estimator::estimate`] does after calibrating, for any set of pixels (a tile).
    pub fn estimate_calibrated(
        &self,
        capture: &Capture,
        noise: &NoiseModel,
        threshold: f64,
        progress: &dyn Progress,
    ) -> Result<Estimate> {
        let n = capture.n_lights();
        let c = capture.channels;
        let np = capture.n_pixels();
        // The same floor on kept lights as the detector (never fewer than three).
        let min_kept = ((self.params.min_kept_share * n as f64).ceil() as usize).max(3);
        let mut normals = vec![[0f32; 3]; np];
        let mut albedo = vec![0f32; np * c];
        let mut light_status = vec![status::USED; np * n];
        progress.begin("coleman-jain", np as u64);
        normals
            .par_chunks_mut(CHUNK)
            .zip(albedo.par_chunks_mut(CHUNK * c))
            .zip(light_status.par_chunks_mut(CHUNK * n))
            .enumerate()
            .for_each_init(
                || {
                    (
                        vec![0f64; n],
                        vec![true; n],
                        capture.pixel_lights(),
                        vec![[0f64; 3]; n],
                    )
                },
                |(grey, kept, lights, buf), (chunk, ((nrm, alb), st))| {
                    for dp in 0..nrm.len() {
                        let p = chunk * CHUNK + dp;
                        // Near lights: this pixel's own vectors (ALGORITHMS.md §9).
                        let dirs: &[[f64; 3]] = if lights.is_near() {
                            buf.copy_from_slice(lights.at(capture.pixels[p] as usize));
                            buf
                        } else {
                            &capture.lights.directions
                        };
                        let samples = capture.pixel_samples(p);
                        channel_mean(samples, c, grey);
                        kept.fill(true);
                        let mut fit = Fit::new(dirs, kept, grey);
                        let mut count = n;
                        let level = grey.iter().sum::<f64>() / n as f64;
                        let dark = noise.shadow_level(&self.params, level);
                        while count > min_kept {
                            let Some(f) = fit.as_mut() else { break };
                            match f.spread(kept, grey) {
                                Some((sp, k)) if sp > threshold => {
                                    // A removal that would leave the lights unable to
                                    // determine a normal is not made: the pixel keeps the
                                    // last determined subset (at worst a triplet).
                                    let before = f.clone();
                                    if f.remove(k, kept, grey).is_none() || f.m.norm() <= 1e-12 {
                                        kept[k] = true;
                                        *f = before;
                                        break;
                                    }
                                    // The method knows highlights only, but a reading at the
                                    // shadow level (also where the fit predicts a negative
                                    // value: an attached shadow) is labelled a shadow.
                                    st[dp * n + k] = if grey[k] <= dark {
                                        status::SHADOW
                                    } else {
                                        status::HIGHLIGHT
                                    };
                                    count -= 1;
                                }
                                _ => break,
                            }
                        }
                        if fit.as_ref().is_some_and(|f| f.m.norm() <= 1e-12) {
                            fit = None;
                        }
                        if fit.is_none() {
                            // Fall back to all lights.
                            kept.fill(true);
                            st[dp * n..(dp + 1) * n].fill(status::USED);
                            fit = Fit::new(dirs, kept, grey);
                        }
                        let out_a = &mut alb[dp * c..(dp + 1) * c];
                        match &fit {
                            Some(f) => write_normal_albedo_with(
                                dirs,
                                c,
                                samples,
                                &f.m,
                                Some(kept),
                                &mut nrm[dp],
                                out_a,
                            ),
                            None => {
                                nrm[dp] = [0.0; 3];
                                out_a.fill(0.0);
                            }
                        }
                    }
                    progress.advance(nrm.len() as u64);
                },
            );
        progress.end();
        Ok(Estimate {
            normals,
            albedo,
            light_status: Some(light_status),
        })
    }
}
