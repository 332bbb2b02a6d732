//! The tile loops of the per-pixel stages (ALGORITHMS.md §10): the detector's test and
//! attribution, the least-squares solves, and the capture-wide statistics they need (noise
//! model, dark floor, κ, Coleman & Jain's calibration), which look at a regular sample of
//! pixels and are computed once on a [`Capture::sampled`] view holding exactly those pixels.
//!
//! Each function gives the same values, bit for bit, as the stage run on a capture held whole:
//! the per-pixel code is the same, run on tile views ([`Capture::for_each_tile`]), and the
//! statistics see the same pixels in the same order. A capture held whole is one tile.

use crate::base::error::{Error, Result};
use crate::base::progress::{Progress, Silent};
use crate::model::capture::Capture;
use crate::solve::detect::{
    detect_with_noise, estimate_kappa_weighted, noise_model, remembered_kappa, Detection,
    DetectionParams, NoiseEstimate, NoiseModel,
};
use crate::solve::lambert::{solve_subsets, Estimate};
use std::borrow::Cow;

/// Forwards `advance` only: the tile loop begins and ends the stage once for all tiles.
pub struct TileProgress<'a>(pub &'a dyn Progress);

impl Progress for TileProgress<'_> {
    fn advance(&self, units: u64) {
        self.0.advance(units)
    }
    fn cancelled(&self) -> bool {
        self.0.cancelled()
    }
}

/// The mask pixels the capture-wide statistics read: the dark floor's sample (at most 4096
/// pixels), κ's (8192), Coleman & Jain's calibration (about 2000) and the 3×3 neighbourhoods
/// of the image-noise sample (4096 interior pixels). Each list is the one its function builds.
pub fn statistics_pixels(capture: &Capture) -> Vec<usize> {
    let np = capture.n_pixels();
    let mut ids: Vec<usize> = Vec::new();
    if np == 0 {
        return ids;
    }
    ids.extend((0..np).step_by(np.div_ceil(4096).max(1)));
    ids.extend((0..np).step_by(np.div_ceil(8192).max(1)));
    ids.extend((0..np).step_by((np / 2000).max(1)));
    // Image noise: interior pixels (whole 3×3 neighbourhood in the mask), every stride-th.
    let (sampled, interior) = crate::solve::detect::interior_neighbourhoods(capture, 4096);
    if interior >= 100 {
        for nb in &sampled {
            ids.extend(nb.iter().map(|&q| q as usize));
        }
    }
    ids
}

/// The view the capture-wide statistics run on: the capture itself when held whole, else a
/// sampled view of [`statistics_pixels`].
pub fn statistics_view(capture: &Capture) -> Result<Cow<'_, Capture>> {
    if capture.is_tiled() {
        Ok(Cow::Owned(capture.sampled(&statistics_pixels(capture))?))
    } else {
        Ok(Cow::Borrowed(capture))
    }
}

/// κ measured under the noise model `noise` ([`estimate_kappa_weighted`] with its σ₀, floor
/// and light factors): from the capture's memo when [`detect_tiles`] left it there, else on the
/// statistics view.
pub fn measured_kappa(
    capture: &Capture,
    noise: &NoiseModel,
    params: &DetectionParams,
) -> Result<Option<f64>> {
    let (s0, floor, factors) = (noise.sigma0, noise.floor, &noise.light_factor[..]);
    if let Some(k) = remembered_kappa(capture, s0, floor, params, factors) {
        return Ok(k);
    }
    let view = statistics_view(capture)?;
    Ok(estimate_kappa_weighted(&view, s0, floor, params, factors))
}

/// [`crate::solve::detect::detect`] tile by tile: the noise model from the statistics view, then the
/// test and attribution of every tile.
pub fn detect_tiles(
    capture: &Capture,
    params: &DetectionParams,
    progress: &dyn Progress,
) -> Result<Detection> {
    if capture.is_tiled()
        && params.sigma.is_none()
        && params.noise_estimate == NoiseEstimate::Residuals
    {
        return Err(Error::parameter(
            "noise_estimate",
            "residuals: this estimate reads every pixel and needs the samples whole in memory; \
             raise the memory limit, give the noise level (sigma) or use the images' estimate",
        ));
    }
    let stats = statistics_view(capture)?;
    let noise = noise_model(&stats, params, progress)?;
    if let Cow::Owned(view) = &stats {
        // The κ a report of this detection reads ([`measured_kappa`]), measured while the view
        // is held and remembered by the capture with the rest of its statistics: none of the
        // capture is copied again for it when the run's maps are whole.
        let _ =
            estimate_kappa_weighted(view, noise.sigma0, noise.floor, params, &noise.light_factor);
        capture.statistics().adopt(view.statistics());
    }
    drop(stats);
    if !capture.is_tiled() {
        return detect_with_noise(capture, params, noise, progress);
    }
    let (n, np) = (capture.n_lights(), capture.n_pixels());
    let mut merged: Option<Detection> = None;
    progress.begin("detecting", np as u64);
    let tp = TileProgress(progress);
    capture.for_each_tile(|_, tile| {
        let d = detect_with_noise(tile, params, noise.clone(), &tp)?;
        match &mut merged {
            None => {
                let mut m = d;
                m.residual.reserve(np - m.residual.len());
                m.unreliable.reserve(np - m.unreliable.len());
                m.light_status.reserve(np * n - m.light_status.len());
                m.settled.reserve(np - m.settled.len());
                merged = Some(m);
            }
            Some(m) => {
                m.residual.extend_from_slice(&d.residual);
                m.unreliable.extend_from_slice(&d.unreliable);
                m.light_status.extend_from_slice(&d.light_status);
                m.settled.extend_from_slice(&d.settled);
            }
        }
        crate::base::progress::check_cancelled(progress)
    })?;
    progress.end();
    merged.ok_or_else(|| Error::invalid("the capture has no mask pixel"))
}

/// [`solve_subsets`] tile by tile (`usable`, when given, for the whole capture).
pub fn solve_tiles(
    capture: &Capture,
    usable: Option<&[bool]>,
    progress: &dyn Progress,
) -> Result<Estimate> {
    if !capture.is_tiled() {
        return Ok(solve_subsets(capture, usable, progress));
    }
    estimate_tiles(capture, progress, |off, tile| {
        let n = capture.n_lights();
        let flags = usable.map(|u| &u[off * n..(off + tile.n_pixels()) * n]);
        Ok(solve_subsets(tile, flags, &Silent))
    })
}

/// [`solve_subsets`] over the lights each pixel's status (`n_pixels * n_lights`, values of
/// [`crate::solve::lambert::status`]) marks USED, tile by tile: the usable flags are made per tile.
pub fn solve_statuses(
    capture: &Capture,
    light_status: &(impl crate::solve::lambert::Statuses + ?Sized),
) -> Result<Estimate> {
    let n = capture.n_lights();
    if !capture.is_tiled() {
        let flags = crate::solve::lambert::usable_of(light_status, 0..capture.n_pixels(), n);
        return Ok(solve_subsets(capture, Some(&flags), &Silent));
    }
    estimate_tiles(capture, &Silent, |off, tile| {
        let flags = crate::solve::lambert::usable_of(light_status, off..off + tile.n_pixels(), n);
        Ok(solve_subsets(tile, Some(&flags), &Silent))
    })
}

/// Runs a per-pixel estimator on every tile and joins the tiles' estimates in mask-pixel
/// order. `f` gets the tile's first mask pixel and the tile view.
pub fn estimate_tiles(
    capture: &Capture,
    progress: &dyn Progress,
    mut f: impl FnMut(usize, &Capture) -> Result<Estimate>,
) -> Result<Estimate> {
    if !capture.is_tiled() {
        return f(0, capture);
    }
    let (n, c, np) = (capture.n_lights(), capture.channels, capture.n_pixels());
    let mut out = Estimate {
        normals: Vec::with_capacity(np),
        albedo: Vec::with_capacity(np * c),
        light_status: None,
    };
    progress.begin("estimating", np as u64);
    capture.for_each_tile(|off, tile| {
        let e = f(off, tile)?;
        out.normals.extend_from_slice(&e.normals);
        out.albedo.extend_from_slice(&e.albedo);
        if let Some(s) = &e.light_status {
            out.light_status
                .get_or_insert_with(|| Vec::with_capacity(np * n))
                .extend_from_slice(s);
        }
        progress.advance(tile.n_pixels() as u64);
        crate::base::progress::check_cancelled(progress)
    })?;
    progress.end();
    Ok(out)
}
