//! Self-calibration of distant lights from the object's own readings (capture preparation,
//! before estimation; the mirror-sphere calibration of the parent module needs a sphere).
//!
//! A rig's light directions are known to a degree or two and its intensities to a few per
//! cent; the error reaches every reading of that light and shows as model error the χ² test
//! has to absorb (κ) or blame on the light at each pixel. The readings themselves pin the
//! lights down: with each pixel's scaled normal m_p = ρ_p n_p fitted robustly from all lights,
//! light k's vector L_k = s_k d_k (direction and relative intensity) is the least-squares
//! solution of I_pk ≈ m_p · L_k over thousands of pixels, a 3-unknown problem per light.
//! Alternating the two fits lowers the misfit of every pixel.
//!
//! The readings determine the lights only up to an invertible 3 × 3 transform A (I = m·L =
//! (A⁻ᵀ m)·(A L)), so each round maps the refined vectors back onto the given ones by the A
//! that fits them best in least squares: the rig's calibration keeps fixing the frame (and the
//! overall scale), the readings fix the lights relative to one another. Lights change by
//! what the data asks, typically a degree or two and a few per cent.
//!
//! Frame: camera frame of CONVENTIONS.md (x right, y up, z toward the camera); directions unit,
//! gains relative (their mean over the lights is about 1).

use crate::base::error::Result;
use crate::model::capture::Capture;
use crate::model::lights::LightRefinement;
use crate::solve::lambert::channel_mean;
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use serde::Serialize;

/// Parameters of [`refine_lights`]; every default comes from a stated principle.
#[derive(Clone, Debug, Serialize)]
pub struct RefineParams {
    /// Most rounds of alternation (default 20): each round attributes the readings under the
    /// current lights, then fits the lights to the readings kept. Readings of a light whose
    /// given vector is off are faults to the detector at first; as the light comes closer
    /// they are kept again, so the first rounds move by a fraction of the error each.
    pub rounds: usize,
    /// Stop once no light's direction moved by more than this in a round (degrees, default
    /// 0.01: a hundredth of the calibration errors the refinement is for).
    pub tolerance_deg: f64,
    /// A reading enters light k's fit only where the pixel's fit predicts at least this share
    /// of its mean level from light k (default 0.3): near the terminator a reading is the
    /// soft edge of a shadow, not a Lambertian one.
    pub min_prediction: f64,
    /// Refinements that move a light by more than this angle (degrees, default 10) are refused
    /// and the given lights kept: a light file that far off is a wrong file, not a calibration
    /// error, and an object whose readings pull that far is not Lambertian enough to calibrate
    /// on.
    pub max_angle_deg: f64,
}

impl Default for RefineParams {
    fn default() -> Self {
        RefineParams {
            rounds: 20,
            tolerance_deg: 0.01,
            min_prediction: 0.3,
            max_angle_deg: 10.0,
        }
    }
}

/// Pixels sampled: at most this many, evenly over the mask (the statistics view's stride).
const SAMPLE: usize = 8192;

/// Fewest pixels that must enter a light's fit for it to be refined.
const MIN_PIXELS_PER_LIGHT: usize = 100;

/// Refines a capture's distant lights from its readings (module documentation). `None` when
/// the capture cannot be calibrated on: near lights, fewer than six lights (three unknowns per
/// light need redundancy across lights as well), fewer than 100 usable pixels per light, or a
/// refinement beyond `max_angle_deg`. Reads a regular sample of at most 8192 mask pixels (the
/// capture's statistics view: a tiled capture is not read whole).
pub fn refine_lights(capture: &Capture, params: &RefineParams) -> Result<Option<LightRefinement>> {
    let n = capture.n_lights();
    if capture.lights.near.is_some() || n < 6 || capture.n_pixels() == 0 {
        return Ok(None);
    }
    let view = crate::solve::tiled::statistics_view(capture)?;
    let view: &Capture = &view;
    let c = view.channels;
    let np = capture.n_pixels();
    // Readings above the shadow level of the detector's defaults enter the fits.
    let defaults = crate::solve::detect::DetectionParams::default();
    let sigma0 = crate::solve::detect::image_noise(view)
        .unwrap_or(0.0)
        .max(1e-6);
    let floor = crate::solve::detect::dark_floor(view).min(defaults.shadow_sigmas * sigma0);
    let dark = floor + defaults.shadow_sigmas * sigma0;
    let ids: Vec<usize> = (0..np).step_by(np.div_ceil(SAMPLE).max(1)).collect();
    let mut greys = vec![0f64; ids.len() * n];
    greys
        .par_chunks_mut(n)
        .zip(&ids)
        .for_each(|(g, &p)| channel_mean(view.pixel_samples(p), c, g));
    // The readings enter the lights' fits where the detector keeps them (its attribution under
    // the default noise model and the current lights, each round): highlights and shadows do
    // not pull the lights.
    let noise = crate::solve::detect::noise_model(view, &defaults, &crate::base::progress::Silent)?;
    let mut usable = vec![crate::solve::lambert::status::USED; ids.len() * n];
    let given = crate::solve::detect::distant_directions(capture);
    let mut lights = given.clone();
    let mut misfit_before = f64::NAN;
    let mut last_change = 0.0;
    let mut pixels = 0;
    let mut rounds = 0;
    for round in 0..params.rounds {
        let vectors: Vec<[f64; 3]> = lights.iter().map(|l| [l.x, l.y, l.z]).collect();
        let attributor = crate::solve::detect::Attributor::with_vectors(
            view,
            &defaults,
            noise.clone(),
            &vectors,
        )?;
        usable.fill(crate::solve::lambert::status::USED);
        usable
            .par_chunks_mut(n)
            .zip(greys.par_chunks(n))
            .for_each_init(
                || attributor.scratch(),
                |scratch, (row, grey)| {
                    attributor.run(grey, row, scratch);
                },
            );
        let fits = Fits::of(&lights, &greys, &usable, n, dark, params.min_prediction);
        if round == 0 {
            misfit_before = fits.median_misfit;
        }
        pixels = fits.pixels;
        let mut refined = lights.clone();
        for (r, pairs) in refined.iter_mut().zip(&fits.per_light) {
            match fit_light(pairs) {
                Some(l) => *r = l,
                None => return Ok(None),
            }
        }
        // Back onto the given lights' frame: A = argmin Σ ‖A L'_k − L_k‖².
        let (mut cross, mut own) = (Matrix3::<f64>::zeros(), Matrix3::<f64>::zeros());
        for (g, r) in given.iter().zip(&refined) {
            cross += g * r.transpose();
            own += r * r.transpose();
        }
        let Some(own_inv) = own.try_inverse() else {
            return Ok(None);
        };
        let transform = cross * own_inv;
        last_change = 0.0f64;
        for (l, r) in lights.iter_mut().zip(&refined) {
            let next = transform * r;
            last_change = last_change.max(angle_deg(l, &next));
            *l = next;
        }
        rounds = round + 1;
        if last_change <= params.tolerance_deg {
            break;
        }
    }
    if rounds == 0 {
        return Ok(None);
    }
    let misfit_after =
        Fits::of(&lights, &greys, &usable, n, dark, params.min_prediction).median_misfit;
    let angles: Vec<f64> = given
        .iter()
        .zip(&lights)
        .map(|(g, l)| angle_deg(g, l))
        .collect();
    if angles
        .iter()
        .any(|a| !(a.is_finite() && *a <= params.max_angle_deg))
        || lights.iter().any(|l| l.norm().is_nan() || l.norm() <= 0.0)
    {
        return Ok(None);
    }
    Ok(Some(LightRefinement {
        directions: lights
            .iter()
            .map(|l| {
                let u = l / l.norm();
                [u.x, u.y, u.z]
            })
            .collect(),
        gains: lights.iter().map(|l| l.norm()).collect(),
        angle_deg: angles,
        pixels,
        rounds,
        last_change_deg: last_change,
        misfit_before,
        misfit_after,
    }))
}

/// Angle between two vectors, degrees.
fn angle_deg(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    (a.dot(b) / (a.norm() * b.norm()))
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees()
}

/// One round's pixel fits under given light vectors: per light, the pairs (m_p, I_pk) of the
/// pixels where it reads above the shadow level and is predicted bright enough, m_p the
/// pixel's fit over the other lights the detector and the robust fit keep (leave-one-out, so
/// that a light's own error does not pull the fit it is compared with); and the median
/// relative misfit of the pixels' fits.
struct Fits {
    per_light: Vec<Vec<Pair>>,
    pixels: usize,
    median_misfit: f64,
}

impl Fits {
    fn of(
        lights: &[Vector3<f64>],
        greys: &[f64],
        usable: &[u8],
        n: usize,
        dark: f64,
        min_prediction: f64,
    ) -> Fits {
        // Per block of pixels, added in block order: the same lists whatever the threads.
        const BLOCK: usize = 256;
        type Block = (Vec<Vec<Pair>>, Vec<f64>);
        let blocks: Vec<Block> = greys
            .par_chunks(n * BLOCK)
            .zip(usable.par_chunks(n * BLOCK))
            .map(|(block, block_usable)| {
                let mut pairs = vec![Vec::new(); n];
                let mut misfits = Vec::with_capacity(BLOCK);
                let (mut keep, mut u, mut scratch) =
                    (vec![false; n], Vec::with_capacity(n), Vec::with_capacity(n));
                for (grey, status) in block.chunks_exact(n).zip(block_usable.chunks_exact(n)) {
                    let level = grey.iter().sum::<f64>() / n as f64;
                    for ((k, g), st) in keep.iter_mut().zip(grey).zip(status) {
                        *k = *g > dark && *st == crate::solve::lambert::status::USED;
                    }
                    let Some((scale, m, gram_inv)) = crate::solve::detect::robust_fit_with(
                        lights,
                        grey,
                        &mut keep,
                        &mut u,
                        &mut scratch,
                    ) else {
                        continue;
                    };
                    misfits.push(scale / level);
                    for k in 0..n {
                        if grey[k] <= dark {
                            continue;
                        }
                        // The fit without light k (Sherman–Morrison when k is in it).
                        let without = if keep[k] {
                            let g = gram_inv * lights[k];
                            let h = lights[k].dot(&g);
                            if h >= 1.0 - 1e-9 {
                                continue;
                            }
                            m - g * ((grey[k] - lights[k].dot(&m)) / (1.0 - h))
                        } else {
                            m
                        };
                        if lights[k].dot(&without) > min_prediction * level {
                            pairs[k].push(Pair {
                                fit: without,
                                reading: grey[k],
                                kept: keep[k],
                            });
                        }
                    }
                }
                (pairs, misfits)
            })
            .collect();
        let mut per_light = vec![Vec::new(); n];
        let mut misfits = Vec::new();
        for (pairs, m) in blocks {
            for (all, some) in per_light.iter_mut().zip(pairs) {
                all.extend(some);
            }
            misfits.extend(m);
        }
        let pixels = misfits.len();
        let median_misfit = if misfits.is_empty() {
            f64::NAN
        } else {
            crate::solve::metrics::median(&mut misfits)
        };
        Fits {
            per_light,
            pixels,
            median_misfit,
        }
    }
}

/// One reading of a light with the fit of its pixel over the other lights.
#[derive(Clone, Copy)]
struct Pair {
    /// m_p without the light.
    fit: Vector3<f64>,
    /// I_pk.
    reading: f64,
    /// The detector and the pixel's robust fit kept the reading.
    kept: bool,
}

/// Light k's vector from its pairs: least squares over the readings the detector kept, then
/// again without those beyond three robust scales of the residuals. A light kept at fewer than
/// [`MIN_PIXELS_PER_LIGHT`] pixels is off as a whole (faults are local; a light given far off
/// on a capture with little noise is a fault to the detector everywhere): all of its readings
/// enter, trimmed the same way. `None` with fewer than [`MIN_PIXELS_PER_LIGHT`] readings or a
/// singular system.
fn fit_light(pairs: &[Pair]) -> Option<Vector3<f64>> {
    let kept = pairs.iter().filter(|p| p.kept).count();
    let whole = kept < MIN_PIXELS_PER_LIGHT;
    let solve = |keep: &dyn Fn(&Pair) -> bool| {
        let (mut gram, mut rhs, mut count) = (Matrix3::zeros(), Vector3::zeros(), 0usize);
        for p in pairs.iter().filter(|p| (whole || p.kept) && keep(p)) {
            gram += p.fit * p.fit.transpose();
            rhs += p.fit * p.reading;
            count += 1;
        }
        if count < MIN_PIXELS_PER_LIGHT {
            return None;
        }
        gram.try_inverse().map(|g| g * rhs)
    };
    let first = solve(&|_| true)?;
    let mut residuals: Vec<f64> = pairs
        .iter()
        .filter(|p| whole || p.kept)
        .map(|p| (p.reading - p.fit.dot(&first)).abs())
        .collect();
    let scale = 1.4826 * crate::solve::metrics::median(&mut residuals);
    if scale.is_nan() || scale <= 0.0 {
        return Some(first);
    }
    solve(&|p| (p.reading - p.fit.dot(&first)).abs() <= 3.0 * scale)
}

/// Refines `capture`'s lights from its readings ([`refine_lights`]) and applies the result
/// ([`Capture::apply_light_refinement`]); returns whether the lights changed (`false`: the
/// capture is not one to calibrate on, see [`refine_lights`], or its lights were refined
/// already).
pub fn refine_capture_lights(capture: &mut Capture, params: &RefineParams) -> Result<bool> {
    if capture.light_refinement.is_some() {
        return Ok(false);
    }
    match refine_lights(capture, params)? {
        Some(r) => {
            capture.apply_light_refinement(r)?;
            Ok(true)
        }
        None => Ok(false),
    }
}
