//! Recursive photometric stereo (Argyriou & Petrou, §3 and Fig. 2; ALGORITHMS.md §7).
//!
//! 1. Detect the non-Lambertian pixels E with the χ² test and attribute their faults
//!    ([`crate::solve::detect`]); estimate every pixel from the lights it kept.
//! 2. Integrate the normals into a height field, with low weight on the pixels of E (which
//!    fills them from their reliable surroundings) and zero weight where fewer than three lights
//!    remain.
//! 3. From that surface, each light's attached shadow (n·l ≤ τ) and cast shadow (horizon sweep,
//!    [`crate::geometry::shadows`]).
//! 4. The highlight map H = E − (S₁ ∪ … ∪ S_N): unreliable pixels no shadow explains.
//! 5. Per pixel, the usable lights: every light in geometric shadow is dropped; at the pixels of
//!    E, the remaining lights are tested again and the faulty ones dropped one by one while the
//!    χ² test fails — a light brighter than the Lambertian prediction of the others is a
//!    highlight source (the paper's intensity threshold, set by the noise level and the test's
//!    confidence rather than by hand), a darker one a shadow the surface missed.
//! 6. Re-estimate every pixel from its usable lights, and repeat from 2 until the usable-light
//!    sets change at fewer than `change_tolerance` of the pixels, or `max_iterations`.
//!
//! 7. The final estimate: each pixel's usable readings with the last surface's normal as a
//!    robust prior ([`SurfacePrior`]), which steadies the pixels the readings determine
//!    poorly (few usable lights, dark readings) and leaves the others.
//!
//! 8. With distant lights and `reflectance` other than lambert, the pixels with a highlight
//!    are fitted with a specular lobe over all their lights out of shadow
//!    ([`crate::solve::gloss`]) and take that fit's normal where the χ² evidence says so.
//!
//! Pixels left with fewer than three usable lights (the paper's Fig. 13) are recorded and
//! completed by [`Fallback`].

use crate::base::codes2::{get_in, pack_into, unpack_into, Codes2};
use crate::base::error::{Error, Result};
use crate::base::progress::{Progress, Silent};
use crate::geometry::integrate::{
    gradients_from_normals, normal_from_depth_at, normals_from_depth, Bilateral, IntegrationParams,
    IntegrationProblem, IntegratorKind, Poisson,
};
use crate::geometry::shadows::{shadow_maps, ShadowMaps, ShadowParams};
use crate::model::capture::Capture;
use crate::model::store::{Parked, Parking};
use crate::solve::detect::{
    AttributionScratch, Attributor, Detection, DetectionParams, NoiseModel,
};
use crate::solve::estimate::Estimator;
use crate::solve::gloss::{GlossMaps, GlossSummary, Reflectance};
use crate::solve::lambert::{
    channel_mean, status, write_normal_albedo_with, Estimate, Statuses, CHUNK,
};
use crate::solve::metrics::angular_error_deg;
use rayon::prelude::*;
use serde::Serialize;
use std::str::FromStr;
use std::sync::Arc;
use std::time::Instant;

/// What to do at pixels with fewer than three usable lights.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum Fallback {
    #[serde(rename = "brightest")]
    /// Complement them with the brightest remaining lights (the paper's choice).
    BrightestLights,
    /// Use the reliable neighbours: their albedo (median over the nearest reliable pixels) turns
    /// two usable lights into a normal — two-source photometric stereo with known albedo, the
    /// root closer to the integrated surface's normal — and with fewer than two lights the
    /// normal of the integrated surface is taken.
    #[serde(rename = "neighbours")]
    Neighbours,
}

impl FromStr for Fallback {
    type Err = crate::Error;
    fn from_str(s: &str) -> Result<Self> {
        if s == "neighbors" {
            return Ok(Fallback::Neighbours);
        }
        crate::base::error::parse_name(s, Fallback::ALL, Fallback::name, "fallback")
    }
}

impl Fallback {
    /// Every choice, default first.
    pub const ALL: &'static [Fallback] = &[Fallback::Neighbours, Fallback::BrightestLights];

    /// The name accepted by `--fallback` (and the Python keyword `fallback`).
    pub fn name(self) -> &'static str {
        match self {
            Fallback::Neighbours => "neighbours",
            Fallback::BrightestLights => "brightest",
        }
    }
}

/// Parameters of the recursive method; every default comes from a stated principle. The
/// detector's parameters and the integrator are the reconstruction's own
/// ([`DetectionParams`], [`IntegrationParams`]): one value of each serves every stage.
#[derive(Clone, Debug, Serialize)]
pub struct RecursiveParams {
    /// Attached and cast shadow tolerances (recorded in `report.json` only when changed).
    #[serde(flatten, skip_serializing_if = "ShadowParams::is_default")]
    pub shadows: ShadowParams,
    /// Iteration limit (default 10, at most [`MAX_ITERATIONS`]; the paper gives none): the
    /// usable-light sets settle within a few iterations on every capture measured, and the
    /// limit bounds the run when they oscillate.
    pub max_iterations: usize,
    /// Stop when the usable-light sets change at fewer than this share of the mask pixels
    /// (default 0.002: the estimate then changes at a handful of pixels per thousand).
    pub change_tolerance: f64,
    /// Completion of pixels with fewer than three usable lights. Default [`Fallback::Neighbours`]:
    /// on the built-in scenes under the four-light rig it roughly halves the error of those
    /// pixels relative to the paper's brightest-lights choice, which feeds shadowed readings
    /// back into the solve.
    pub fallback: Fallback,
    /// Radius of the spatial consensus of the usable lights ([`crate::solve::consensus`]): each
    /// light's removal at a pixel follows the majority of its (2r + 1)² neighbourhood in the
    /// mask, where the pixel's readings pass the χ² test with that set. Default 2 (5 × 5): a
    /// fault region narrower than three pixels is not told apart from the test's noise-level
    /// decisions; 0 turns the consensus off (the paper's per-pixel decisions). At most
    /// [`MAX_CONSENSUS_RADIUS`]: the filter's work grows with the square of the radius.
    pub consensus_radius: usize,
    /// The final re-estimate takes the last integrated surface as a prior on each normal
    /// ([`SurfacePrior`]): its angular standard deviation in degrees (default 1; 0 turns the
    /// step off and the estimate is the usable lights' least squares).
    pub surface_prior_deg: f64,
    /// The reflectance model of the final estimate with distant lights
    /// ([`crate::solve::gloss`]): at pixels with a highlight, the normal fitted jointly with a
    /// specular lobe instead of from the lights left after the highlight is dropped. Default
    /// lambert (the paper): with a dozen 8-bit lights the lobe fit can trade the diffuse
    /// readings for a broad lobe and turn a normal far from the readings' own. `material`
    /// shares the lobe over the pixels of a material ([`crate::solve::gloss::material`]).
    pub reflectance: Reflectance,
}

impl Default for RecursiveParams {
    fn default() -> Self {
        RecursiveParams {
            shadows: ShadowParams::default(),
            max_iterations: 10,
            change_tolerance: 0.002,
            fallback: Fallback::Neighbours,
            consensus_radius: 2,
            surface_prior_deg: 1.0,
            reflectance: Reflectance::Lambert,
        }
    }
}

/// Figures of one iteration.
#[derive(Clone, Debug, Serialize)]
pub struct IterationRecord {
    pub iteration: usize,
    /// Mask pixels whose usable-light set changed.
    pub changed_pixels: usize,
    pub changed_share: f64,
    /// Pixels of the highlight map H.
    pub highlight_pixels: usize,
    /// Pixels left with fewer than three usable lights.
    pub fewer_than_three: usize,
    /// Pixels held at their set since they went back to an earlier one (the oscillation rule),
    /// up to this iteration.
    pub oscillating_pixels: usize,
    /// Mean share of (pixel, light) pairs in geometric shadow.
    pub shadowed_share: f64,
    /// Mean angular error against ground truth, when given (degrees).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mean_error_deg: Option<f64>,
    pub seconds: f64,
}

/// Maps and figures of a recursive run, beyond the normals, albedo and light statuses.
#[derive(Clone, Debug)]
pub struct RecursiveDiagnostics {
    /// Shadow maps of the last surface.
    pub shadows: ShadowMaps,
    /// H, full frame.
    pub highlight: Vec<bool>,
    /// Pixels with fewer than three usable lights (before the fallback), full frame.
    pub fewer_than_three: Vec<bool>,
    /// The last intermediate surface, full frame, pixel units, NaN outside the mask.
    pub depth: Vec<f32>,
    /// Pixels whose usable lights pass the χ² test (or were never unreliable), full frame.
    pub reliable: Vec<bool>,
    /// Per-pixel integration trust of the final estimate, full frame, by the rule the
    /// iterations use (1 reliable, `unreliable_weight` unreliable, 0 without a normal; with
    /// near lights, exactly determined pixels by their solve's relative precision); the input
    /// of [`weighted_normals`](crate::geometry::integrate::weighted_normals) for the exported depth.
    pub trust: Vec<f32>,
    pub iterations: Vec<IterationRecord>,
    pub fallback: Fallback,
    /// Whether the usable-light sets settled: changed at fewer than `change_tolerance` of the
    /// pixels before the iteration limit.
    pub converged: bool,
    /// The share of pixels whose usable-light set changed in the last iteration.
    pub final_change: f64,
    /// Why the recursion stopped, in words.
    pub stop_reason: String,
    /// The final re-estimate with the surface as prior, when it ran.
    pub surface_prior: Option<SurfacePriorRecord>,
    /// The highlight lobes' fit (distant lights) and its maps, full frame, when it ran.
    pub gloss: Option<(GlossSummary, GlossMaps)>,
    /// The final usable-light statuses per mask pixel, packed (2 bits a light): the
    /// estimate's `light_status` is left `None`, so that no byte-per-light copy is made
    /// ([`Recursive`]'s [`Estimator`] result unpacks them).
    pub light_status: Codes2,
}

/// The normals, albedo and light statuses of a recursive run, and its diagnostics.
#[derive(Clone, Debug)]
pub struct RecursiveResult {
    pub estimate: Estimate,
    /// The initial χ² test over all lights (residual and unreliable maps, noise model), per
    /// mask pixel; untested (nothing flagged) with three lights.
    pub detection: Detection,
    /// Seconds the initial test and attribution took (part of the method's run time).
    pub detect_seconds: f64,
    pub diagnostics: RecursiveDiagnostics,
}

/// The recursive method with everything it needs: its own parameters, the detector's and the
/// integrator. As an [`Estimator`] it returns the estimate only; [`Recursive::run`] returns the
/// diagnostics too.
#[derive(Clone, Debug, Default)]
pub struct Recursive {
    pub params: RecursiveParams,
    pub detection: DetectionParams,
    pub integration: IntegrationParams,
    /// Ground-truth normals (full frame, or one per mask pixel) for the per-iteration error
    /// figures, when known.
    pub truth: Option<Arc<Vec<[f32; 3]>>>,
}

impl Estimator for Recursive {
    fn name(&self) -> &'static str {
        "recursive"
    }

    fn estimate(&self, capture: &Capture, progress: &dyn Progress) -> Result<Estimate> {
        let r = self.run(capture, progress, &mut |_| {})?;
        let mut estimate = r.estimate;
        estimate.light_status = Some(r.diagnostics.light_status.unpack());
        Ok(estimate)
    }
}

/// The largest iteration limit accepted.
pub const MAX_ITERATIONS: usize = 1000;
/// The largest consensus radius accepted (a 41 × 41 neighbourhood).
pub const MAX_CONSENSUS_RADIUS: usize = 20;

impl RecursiveParams {
    /// Checks the domains; errors name the parameter.
    pub fn validate(&self) -> Result<()> {
        if !(1..=MAX_ITERATIONS).contains(&self.max_iterations) {
            return Err(Error::parameter(
                "max_iterations",
                format!(
                    "{}: expected an integer in [1, {MAX_ITERATIONS}] (the recursive method needs at least one iteration)",
                    self.max_iterations
                ),
            ));
        }
        if self.consensus_radius > MAX_CONSENSUS_RADIUS {
            return Err(Error::parameter(
                "consensus_radius",
                format!(
                    "{}: expected an integer in [0, {MAX_CONSENSUS_RADIUS}]",
                    self.consensus_radius
                ),
            ));
        }
        self.shadows.check()?;
        if !(self.surface_prior_deg.is_finite() && (0.0..=90.0).contains(&self.surface_prior_deg)) {
            // The parameter's name (`surface_prior`), not the field's.
            return Err(Error::parameter(
                "surface_prior",
                format!(
                    "{}: expected an angle in degrees in [0, 90] (0 turns the surface prior off)",
                    self.surface_prior_deg
                ),
            ));
        }
        if !(0.0..=1.0).contains(&self.change_tolerance) {
            return Err(Error::parameter(
                "change_tolerance",
                format!("{}: expected a share in [0, 1]", self.change_tolerance),
            ));
        }
        Ok(())
    }
}

impl Recursive {
    /// Runs the method. `on_iteration` is called after each iteration.
    pub fn run(
        &self,
        capture: &Capture,
        progress: &dyn Progress,
        on_iteration: &mut dyn FnMut(&IterationRecord),
    ) -> Result<RecursiveResult> {
        recursive(
            capture,
            &self.params,
            &self.detection,
            &self.integration,
            self.truth.as_deref().map(|v| v.as_slice()),
            progress,
            on_iteration,
        )
    }
}

/// Runs the recursive method. `truth` (full-frame normals, or one per mask pixel) adds error
/// figures per iteration; `on_iteration` is called after each iteration.
///
/// The paper's flow chart (Fig. 2), step by step as the module's list numbers them: detect the
/// unreliable pixels E and estimate every pixel from the lights it kept (1), then repeat —
/// integrate the surface (2), its shadow maps (3), each pixel's usable lights (4–5) with the
/// spatial consensus and the oscillation rule, the re-estimate with the completion of pixels
/// left with fewer than three lights (6) — until the stop rule ends it; last, the final
/// estimate with the surface as prior (7).
pub fn recursive(
    capture: &Capture,
    params: &RecursiveParams,
    detection_params: &DetectionParams,
    integration: &IntegrationParams,
    truth: Option<&[[f32; 3]]>,
    progress: &dyn Progress,
    on_iteration: &mut dyn FnMut(&IterationRecord),
) -> Result<RecursiveResult> {
    params.validate()?;
    detection_params.validate()?;
    integration.validate()?;
    let detect_start = Instant::now();
    let (mut detection, attributor) = detect_and_attribute(capture, detection_params, progress)?;
    let detect_seconds = detect_start.elapsed().as_secs_f64();
    // The detector's statuses start the recursion: moved, not copied (the result's statuses
    // are the estimate's; the detection keeps its residuals and flags).
    let light_status = Codes2::from_codes(
        &std::mem::take(&mut detection.light_status),
        capture.n_lights(),
    );
    let setting = Setting {
        capture,
        params,
        detection_params,
        integration,
        detection: &detection,
        attributor,
        progress,
    };
    let mut state = Recursion::start(&setting, light_status)?;
    // The truth at the mask pixels: borrowed when given per mask pixel, gathered otherwise.
    let (w, h) = (capture.width, capture.height);
    let truth_masked = truth
        .map(|t| crate::solve::metrics::truth_at_pixels(t, w, h, &capture.pixels))
        .transpose()?;
    let mut stop = StopRule::new(params, fingerprint(&state.light_status));
    let mut records = Vec::new();
    let (mut converged, mut stop_reason) = (false, String::new());
    for iteration in 1..=params.max_iterations {
        crate::base::progress::check_cancelled(progress)?;
        let start = Instant::now();
        let mut record = state.iterate(&setting, iteration)?;
        record.mean_error_deg = truth_masked
            .as_ref()
            .map(|t| mean_error(&state.est.normals, t));
        record.seconds = start.elapsed().as_secs_f64();
        on_iteration(&record);
        let change = record.changed_share;
        records.push(record);
        if let Some((done, reason)) =
            stop.after(iteration, change, fingerprint(&state.light_status))
        {
            converged = done;
            stop_reason = reason;
            break;
        }
    }
    progress.begin("recursive: final estimate", 1);
    let (estimate, diagnostics) = state.finish(&setting, records, converged, stop_reason)?;
    progress.end();
    Ok(RecursiveResult {
        estimate,
        detection,
        detect_seconds,
        diagnostics,
    })
}

/// Step 1 (paper eqs. 4–6, ALGORITHMS.md §2): the χ² test over all lights flags the
/// non-Lambertian pixels E and attributes their faults to lights; the attributor re-runs that
/// attribution in the iterations. With three lights there is no linear test (N − 3 = 0 degrees
/// of freedom): every pixel starts reliable and only the geometric shadows of the surface prune
/// lights.
fn detect_and_attribute<'a>(
    capture: &'a Capture,
    detection_params: &'a DetectionParams,
    progress: &dyn Progress,
) -> Result<(Detection, Option<Attributor<'a>>)> {
    if capture.n_lights() >= 4 {
        let detection = crate::solve::tiled::detect_tiles(capture, detection_params, progress)?;
        let attributor = Attributor::new(capture, detection_params, detection.noise.clone())?;
        Ok((detection, Some(attributor)))
    } else {
        let view = crate::solve::tiled::statistics_view(capture)?;
        Ok((Detection::untested(&view, detection_params), None))
    }
}

/// What every step of the recursion reads and none changes: the capture, the parameters, the
/// initial detection and the attribution.
struct Setting<'a> {
    capture: &'a Capture,
    params: &'a RecursiveParams,
    detection_params: &'a DetectionParams,
    integration: &'a IntegrationParams,
    /// The initial test: E (`unreliable`), the noise model and the verdicts on the lights its
    /// attribution kept (`settled`).
    detection: &'a Detection,
    /// The attribution of faults to lights (none with three lights).
    attributor: Option<Attributor<'a>>,
    /// Where the iterations' steps are reported.
    progress: &'a dyn Progress,
}

impl Setting<'_> {
    fn n_lights(&self) -> usize {
        self.capture.n_lights()
    }

    fn n_pixels(&self) -> usize {
        self.capture.n_pixels()
    }

    fn near_lights(&self) -> bool {
        self.capture.lights.near.is_some()
    }

    /// Bytes of one pixel's shadow bits and attribution key (3 under 24 lights).
    fn key_bytes(&self) -> usize {
        self.n_lights().div_ceil(8)
    }

    /// Reports the start of step `what` of iteration `iteration` (`units` of work), as the
    /// stage `recursive I/M: what` (M the iteration limit), ending the step before it (the
    /// surface is an iteration's first step).
    fn step(&self, iteration: usize, what: &str, units: u64) {
        if what != "surface" {
            self.progress.end();
        }
        let max = self.params.max_iterations;
        self.progress
            .begin(&format!("recursive {iteration}/{max}: {what}"), units);
    }
}

/// The recursion's state between iterations, per mask pixel: the usable lights and the
/// estimate made from them, the test's verdict on them, and what the hysteresis and the
/// oscillation rule remember of earlier iterations.
struct Recursion {
    /// The usable lights, `n` statuses per pixel (a row of 2-bit codes).
    light_status: Codes2,
    est: Estimate,
    /// Whether each pixel's usable lights pass the test (initially: the pixels outside E).
    consistent: Vec<bool>,
    /// Pixels left with fewer than three usable lights (the paper's Fig. 13).
    few: Vec<bool>,
    /// Pixels of `few` whose normal came from two lights and the neighbours' albedo.
    solved_two: Vec<bool>,
    /// H (eq. 13): unreliable pixels no shadow explains.
    highlight: Vec<bool>,
    /// The pixels' own decisions of the last iteration, before the spatial consensus.
    own: OwnDecisions,
    /// Per pixel, a fingerprint of the usable set it had before its current one (the
    /// oscillation rule).
    earlier_print: Vec<u32>,
    /// Pixels held at their set since they went back to an earlier one.
    oscillating: Vec<bool>,
    /// The last iteration's shadow maps: held, or (under a tight budget) parked in their own
    /// file until [`Recursion::finish`] hands them over, every other array of it released.
    last_maps: Option<Held>,
    /// The last intermediate surface, full frame, pixel units.
    last_depth: Vec<f32>,
}

/// The per-pixel decisions of the last iteration before the spatial consensus, for the
/// hysteresis of the attribution and the reuse of decisions whose input did not change.
#[derive(Default)]
struct OwnDecisions {
    /// The statuses, held as their difference from the ones the iteration ended with.
    status: OwnStatuses,
    consistent: Vec<bool>,
    few: Vec<bool>,
    /// Per pixel, the attribution's input as bits (the lights the surface shadows where the
    /// reading agrees), `key_bytes` per pixel.
    key: Vec<u8>,
}

/// One iteration's surface: the height field and, with near lights, its normals (the light
/// vectors follow the surface).
struct Surface {
    depth: crate::geometry::integrate::Depth,
    near_normals: Option<Vec<[f32; 3]>>,
}

impl Surface {
    /// The surface's unit normal at full-frame pixel `i`.
    fn normal_at(&self, i: usize, capture: &Capture) -> [f32; 3] {
        match &self.near_normals {
            Some(map) => map[i],
            None => normal_from_depth_at(
                i,
                capture.width,
                capture.height,
                &self.depth.values,
                &capture.mask,
            ),
        }
    }
}

/// Per mask pixel, the lights the surface shadows, as bits (`key_bytes` per pixel, bit `k % 8`
/// of byte `k / 8` for light `k`).
struct ShadowBits {
    bits: Vec<u8>,
    key_bytes: usize,
}

impl ShadowBits {
    #[inline]
    fn at(&self, p: usize, k: usize) -> bool {
        self.bits[p * self.key_bytes + k / 8] >> (k % 8) & 1 != 0
    }
}

/// The usable-light decisions of an iteration, per mask pixel.
struct Decisions {
    /// `n` statuses per pixel (a row of 2-bit codes).
    status: Codes2,
    /// The usable lights pass the χ² test.
    consistent: Vec<bool>,
    /// Fewer than three usable lights.
    few: Vec<bool>,
    /// The pixel is in H.
    highlight: Vec<bool>,
}

/// The decisions of a run of pixels, as slices of [`Decisions`].
struct DecisionChunk<'d> {
    /// The packed status rows, `stride` bytes a pixel.
    status: &'d mut [u8],
    stride: usize,
    consistent: &'d mut [bool],
    few: &'d mut [bool],
    highlight: &'d mut [bool],
}

/// One pixel's decision, written in place.
struct PixelDecision<'d> {
    /// The statuses of its `n` lights, one a byte (packed into the decisions by the caller).
    status: &'d mut [u8],
    /// Room for the statuses an earlier decision gave it (`n` bytes).
    previous: &'d mut [u8],
    consistent: &'d mut bool,
    few: &'d mut bool,
    highlight: &'d mut bool,
}

impl Decisions {
    /// Every light usable, nothing flagged, for `np` pixels of `n` lights.
    fn new(np: usize, n: usize) -> Self {
        Decisions {
            status: Codes2::filled(np, n, status::USED),
            consistent: vec![false; np],
            few: vec![false; np],
            highlight: vec![false; np],
        }
    }

    /// The decisions of mask pixels `range`, in chunks of `per` pixels.
    fn par_chunks(
        &mut self,
        range: std::ops::Range<usize>,
        per: usize,
    ) -> impl IndexedParallelIterator<Item = DecisionChunk<'_>> {
        let stride = self.status.stride();
        self.status
            .par_rows_mut(range.clone(), per)
            .zip(self.consistent[range.clone()].par_chunks_mut(per))
            .zip(self.few[range.clone()].par_chunks_mut(per))
            .zip(self.highlight[range].par_chunks_mut(per))
            .map(
                move |(((status, consistent), few), highlight)| DecisionChunk {
                    status,
                    stride,
                    consistent,
                    few,
                    highlight,
                },
            )
    }
}

impl DecisionChunk<'_> {
    /// The decision of the chunk's pixel `dp`, its statuses unpacked into `row` (`n` bytes);
    /// [`DecisionChunk::store`] packs them back.
    fn pixel<'r>(
        &'r mut self,
        dp: usize,
        row: &'r mut [u8],
        previous: &'r mut [u8],
    ) -> PixelDecision<'r> {
        unpack_into(self.packed(dp), row);
        PixelDecision {
            status: row,
            previous,
            consistent: &mut self.consistent[dp],
            few: &mut self.few[dp],
            highlight: &mut self.highlight[dp],
        }
    }

    /// The packed statuses of the chunk's pixel `dp`.
    fn packed(&self, dp: usize) -> &[u8] {
        &self.status[dp * self.stride..(dp + 1) * self.stride]
    }

    /// The packed statuses of the chunk's pixel `dp`, to write.
    fn packed_mut(&mut self, dp: usize) -> &mut [u8] {
        &mut self.status[dp * self.stride..(dp + 1) * self.stride]
    }

    /// Packs `row` (one status a byte) into the chunk's pixel `dp`.
    fn store(&mut self, dp: usize, row: &[u8]) {
        pack_into(row, self.packed_mut(dp));
    }
}

impl Recursion {
    /// The state after step 1: every pixel estimated from the lights the detector kept.
    fn start(setting: &Setting, light_status: Codes2) -> Result<Self> {
        let capture = setting.capture;
        let np = setting.n_pixels();
        let noise = &setting.detection.noise;
        let mut est = crate::solve::tiled::solve_statuses(capture, &light_status)?;
        if !noise.light_factor.is_empty() && !setting.near_lights() {
            // Lights with their own noise factors: the estimate is the weighted fit the test
            // made.
            resolve_where(
                capture,
                &light_status,
                |_| true,
                &mut est,
                &noise.light_factor,
            )?;
        }
        Ok(Recursion {
            light_status,
            est,
            consistent: setting.detection.unreliable.iter().map(|&u| !u).collect(),
            few: vec![false; np],
            solved_two: vec![false; np],
            highlight: vec![false; np],
            own: OwnDecisions::default(),
            earlier_print: vec![0u32; np],
            oscillating: vec![false; np],
            last_maps: None,
            last_depth: Vec::new(),
        })
    }

    /// One pass of the loop of Fig. 2 (steps 2–6); the record lacks the error figure and the
    /// time, which the driver adds.
    fn iterate(&mut self, setting: &Setting, iteration: usize) -> Result<IterationRecord> {
        let (n, np) = (setting.n_lights(), setting.n_pixels());
        // The last iteration's shadow maps are replaced below: not kept beside the new ones.
        drop(self.last_maps.take());
        // A tight budget: the per-pixel arrays wait in a file while the surface and its
        // shadows are made, the estimate until the re-estimate.
        let mut parking = setting.capture.parking()?;
        // 2. The surface, and 3. its shadows.
        setting.step(iteration, "surface", 1);
        let (mut surface, shading, parked) = self.integrate_surface(setting, parking.as_mut())?;
        setting.step(iteration, "shadows", 1);
        let maps = shadows_of(setting, &surface, &shading)?;
        drop(shading);
        let parked_estimate = match (parking.as_ref(), parked) {
            (Some(parking), Some(parked)) => Some(self.unpark(parking, parked)?),
            _ => None,
        };
        // 4–5. The usable lights: each pixel's own decisions, the neighbourhood's consensus,
        // and the oscillation rule.
        setting.step(iteration, "usable lights", np as u64);
        let (own, keys) = self.decide_usable_lights(setting, iteration, &maps)?;
        setting.step(iteration, "consensus", 1);
        let (mut new, own_status) = self.consensus(setting, iteration, own, keys)?;
        self.hold_oscillating(iteration, n, &mut new);
        // 6. The re-estimate, and the completion of the pixels left with fewer than three.
        setting.step(iteration, "re-estimate", 1);
        let changed: Vec<bool> = (0..np)
            .into_par_iter()
            .map(|p| usable_differs(&new.status, &self.light_status, p, n))
            .collect();
        let changed_pixels = changed.iter().filter(|&&x| x).count();
        let shadowed_share =
            maps.count(ShadowMaps::ATTACHED | ShadowMaps::CAST) as f64 / (n * np).max(1) as f64;
        // A tight budget: the shadow maps and the surface wait in the file while the estimate
        // is read back and solved again (the shadow maps until the iteration's end, the
        // surface until the fill of the pixels with fewer than three lights).
        let (maps, parked_depth) = match (parking.as_mut(), setting.capture.parking()?) {
            (Some(parking), Some(mut own)) => {
                let (w, h, lights) = (maps.width, maps.height, maps.lights);
                let [a, c] = maps.into_planes();
                let planes = [own.park(a)?, own.park(c)?];
                let depth = parking.shelve(&mut surface.depth.values)?;
                (Held::Parked(own, w, h, lights, planes), Some(depth))
            }
            _ => (Held::Here(maps), None),
        };
        let estimate = parking.as_ref().zip(parked_estimate);
        self.re_estimate(setting, new, own_status, changed, estimate)?;
        if let (Some(parking), Some(depth)) = (parking.as_ref(), parked_depth) {
            parking.unshelve(&mut surface.depth.values, depth)?;
        }
        if setting.params.fallback == Fallback::Neighbours {
            self.fill_few(setting, &surface)?;
        }
        drop(parking);
        let count = |v: &[bool]| v.iter().filter(|&&x| x).count();
        let record = IterationRecord {
            iteration,
            changed_pixels,
            changed_share: changed_pixels as f64 / np.max(1) as f64,
            highlight_pixels: count(&self.highlight),
            fewer_than_three: count(&self.few),
            oscillating_pixels: count(&self.oscillating),
            shadowed_share,
            mean_error_deg: None,
            seconds: 0.0,
        };
        self.last_maps = Some(maps);
        self.last_depth = surface.depth.values;
        setting.progress.end();
        Ok(record)
    }

    /// The integration trust of the current estimate per mask pixel ([`pixel_trust`]; with near
    /// lights, exactly determined pixels by their solve's relative precision, [`exact_trust`]).
    fn trust(&self, setting: &Setting) -> Vec<f32> {
        let mut trust = pixel_trust(
            &self.est,
            &self.consistent,
            &self.few,
            &self.solved_two,
            setting.integration.unreliable_weight,
        );
        if setting.near_lights() {
            exact_trust(setting.capture, &self.light_status, &self.few, &mut trust);
        }
        trust
    }

    /// Step 2 (paper eqs. 11–12, ALGORITHMS.md §5): the normals integrated into a height field,
    /// with low weight on the pixels of E (which fills them from their reliable surroundings)
    /// and zero weight where fewer than three lights remain. Returns the surface and the normals
    /// its shadows are shaded with (the estimate where it is trusted, the surface elsewhere).
    ///
    /// With a `parking` file the recursion's per-pixel arrays are parked once the inputs are
    /// made ([`Recursion::park`]).
    fn integrate_surface(
        &mut self,
        setting: &Setting,
        mut parking: Option<&mut Parking>,
    ) -> Result<(Surface, Vec<[f32; 3]>, Option<ParkedState>)> {
        let capture = setting.capture;
        let (w, h) = (capture.width, capture.height);
        // Made from the mask pixels' estimate and trust: no full-frame copy of either.
        let weighted = |normals: &[[f32; 3]], trust: &[f32]| {
            crate::geometry::integrate::weighted_normals_at(
                w * h,
                &capture.pixels,
                normals,
                &|p, _| trust[p],
            )
        };
        let ((normals_full, weights), parked) = match parking.as_deref_mut() {
            Some(parking) => {
                let (parked, inputs) = self.park(parking, setting, weighted)?;
                (inputs, Some(parked))
            }
            None => (weighted(&self.est.normals, &self.trust(setting)), None),
        };
        let (surface, shading) = match capture.lights.near.as_deref() {
            None => {
                // The last iteration's surface starts the solve: the normals changed at few
                // pixels since, so the solver needs a fraction of its iterations. The normal
                // map is dropped once its gradients are taken.
                let depth = integrate(
                    w,
                    h,
                    normals_full,
                    &capture.mask,
                    &weights,
                    std::mem::take(&mut self.last_depth),
                    setting.integration,
                )?;
                // Attached shadows from the estimate where it is trusted (there the integrated
                // normal was the estimate itself), from the surface elsewhere.
                let mut shading = normals_from_depth(w, h, &depth.values, &capture.mask);
                let parked_normals = match (parking.as_deref(), parked.as_ref()) {
                    (Some(parking), Some(parked)) => parking.read(&parked.estimate.0)?,
                    _ => Vec::new(),
                };
                let normals = match parked.as_ref() {
                    Some(_) => &parked_normals,
                    None => &self.est.normals,
                };
                for (p, &i) in capture.pixels.iter().enumerate() {
                    if weights[i as usize] >= 1.0 {
                        shading[i as usize] = normals[p];
                    }
                }
                let surface = Surface {
                    depth,
                    near_normals: None,
                };
                (surface, shading)
            }
            // Near lights: the surface in mm through the camera, and the light vectors follow
            // it (ALGORITHMS.md §9).
            Some(near) => {
                let (depth, surface_normals) =
                    near_surface(capture, near, &normals_full, &weights, setting.integration)?;
                let shading: Vec<[f32; 3]> = (0..w * h)
                    .map(|i| {
                        if weights[i] >= 1.0 {
                            normals_full[i]
                        } else {
                            surface_normals[i]
                        }
                    })
                    .collect();
                let surface = Surface {
                    depth,
                    near_normals: Some(surface_normals),
                };
                (surface, shading)
            }
        };
        Ok((surface, shading, parked))
    }

    /// Parks the recursion's per-pixel arrays in `parking` (the estimate, the statuses, the
    /// own decisions, the flags and fingerprints), leaving them empty.
    ///
    /// The normals go last: `made` is given them and the integration trust ([`Recursion::trust`],
    /// made once what it does not read is parked) once the rest is parked (what is made from
    /// them is not held beside the other arrays) and its result is returned.
    fn park<T>(
        &mut self,
        parking: &mut Parking,
        setting: &Setting,
        made: impl FnOnce(&[[f32; 3]], &[f32]) -> T,
    ) -> Result<(ParkedState, T)> {
        let albedo = parking.shelve(&mut self.est.albedo)?;
        let own_status = (
            parking.shelve(&mut self.own.status.ids)?,
            parking.shelve(&mut self.own.status.codes)?,
        );
        let key = parking.shelve(&mut self.own.key)?;
        let earlier_print = parking.shelve(&mut self.earlier_print)?;
        let [highlight, oscillating, own_consistent, own_few] = [
            parking.shelve(&mut self.highlight)?,
            parking.shelve(&mut self.oscillating)?,
            parking.shelve(&mut self.own.consistent)?,
            parking.shelve(&mut self.own.few)?,
        ];
        // The trust reads the statuses (near lights) and the flags parked next: made once the
        // rest is parked, and given to `made` with the normals.
        let trust = self.trust(setting);
        let status = std::mem::take(&mut self.light_status);
        let status = (status.width(), parking.park(status.into_bytes())?);
        let flags = [
            parking.shelve(&mut self.consistent)?,
            parking.shelve(&mut self.few)?,
            parking.shelve(&mut self.solved_two)?,
            highlight,
            oscillating,
            own_consistent,
            own_few,
        ];
        let result = made(&self.est.normals, &trust);
        drop(trust);
        let normals = parking.shelve(&mut self.est.normals)?;
        let parked = ParkedState {
            estimate: (normals, albedo),
            status,
            own_status,
            key,
            earlier_print,
            flags,
        };
        Ok((parked, result))
    }

    /// Reads back what [`Recursion::park`] parked, except the estimate (returned, still
    /// parked: the re-estimate reads it back).
    fn unpark(&mut self, parking: &Parking, p: ParkedState) -> Result<ParkedEstimate> {
        let (width, status) = p.status;
        self.light_status = Codes2::from_bytes(width, parking.take(status)?);
        let (ids, codes) = p.own_status;
        parking.unshelve(&mut self.own.status.ids, ids)?;
        parking.unshelve(&mut self.own.status.codes, codes)?;
        parking.unshelve(&mut self.own.key, p.key)?;
        parking.unshelve(&mut self.earlier_print, p.earlier_print)?;
        let [a, b, c, d, e, f, g] = p.flags;
        parking.unshelve(&mut self.consistent, a)?;
        parking.unshelve(&mut self.few, b)?;
        parking.unshelve(&mut self.solved_two, c)?;
        parking.unshelve(&mut self.highlight, d)?;
        parking.unshelve(&mut self.oscillating, e)?;
        parking.unshelve(&mut self.own.consistent, f)?;
        parking.unshelve(&mut self.own.few, g)?;
        Ok(p.estimate)
    }

    /// Steps 4–5 at every pixel ([`Recursion::decide_pixel`]), tile by tile (the whole capture
    /// at once when it is held whole): the pixels' own decisions, and their attribution keys.
    fn decide_usable_lights(
        &self,
        setting: &Setting,
        iteration: usize,
        maps: &ShadowMaps,
    ) -> Result<(Decisions, Vec<u8>)> {
        let capture = setting.capture;
        let (n, np, c) = (setting.n_lights(), setting.n_pixels(), capture.channels);
        let key_bytes = setting.key_bytes();
        let shadow = ShadowBits {
            bits: maps.pixel_bits(&capture.pixels),
            key_bytes,
        };
        let mut own = Decisions::new(np, n);
        let mut keys = vec![0u8; np * key_bytes];
        // `off` is the tile's first mask pixel, `tile` its view (local indices).
        capture.for_each_tile(|off, tile| {
            let tn = tile.n_pixels();
            own.par_chunks(off..off + tn, CHUNK)
                .zip(
                    keys[off * key_bytes..(off + tn) * key_bytes].par_chunks_mut(CHUNK * key_bytes),
                )
                .enumerate()
                .for_each_init(
                    || {
                        let scratch = setting.attributor.as_ref().map(|a| a.scratch());
                        (vec![0f64; n], scratch, vec![0u8; n], vec![0u8; n])
                    },
                    |(grey, scratch, row, previous), (chunk, (mut decisions, keys))| {
                        for dp in 0..decisions.consistent.len() {
                            let lp = chunk * CHUNK + dp;
                            channel_mean(tile.pixel_samples(lp), c, grey);
                            let key = &mut keys[dp * key_bytes..(dp + 1) * key_bytes];
                            let pixel = PixelInput {
                                p: off + lp,
                                grey,
                                shadow: &shadow,
                            };
                            let d = decisions.pixel(dp, row, previous);
                            self.decide_pixel(setting, iteration, &pixel, key, scratch.as_mut(), d);
                            decisions.store(dp, row);
                        }
                    },
                );
            setting.progress.advance(tn as u64);
            Ok(())
        })?;
        Ok((own, keys))
    }

    /// Steps 4–5 at mask pixel `p`: every light in geometric shadow is dropped where its
    /// reading agrees (at the shadow level; a clearly lit reading says the surface is off there
    /// and the light stays for the test to judge); at the pixels of E the remaining lights are
    /// tested again and the faulty ones dropped one by one while the χ² test fails — a light
    /// brighter than the Lambertian prediction of the others is a highlight source, a darker
    /// one a shadow the surface missed. The pixel is in H (eq. 13) when no shadow explains its
    /// fault. Fewer than three usable lights: recorded, and completed with the brightest ones
    /// under [`Fallback::BrightestLights`]. `key` receives the attribution's input beyond the
    /// fixed readings.
    fn decide_pixel<'a>(
        &self,
        setting: &Setting<'a>,
        iteration: usize,
        pixel: &PixelInput,
        key: &mut [u8],
        scratch: Option<&mut AttributionScratch<'a>>,
        mut d: PixelDecision,
    ) {
        let (n, p, grey) = (setting.n_lights(), pixel.p, pixel.grey);
        let level = grey.iter().sum::<f64>() / n as f64;
        let dark = setting
            .detection
            .noise
            .shadow_level(setting.detection_params, level);
        // The lights the surface shadows where the reading agrees, as bits.
        key.fill(0);
        for k in 0..n {
            if pixel.shadow.at(p, k) && grey[k] <= dark {
                key[k / 8] |= 1 << (k % 8);
            }
        }
        if self.reuse_decision(setting, iteration, pixel, dark, key, &mut d) {
            return;
        }
        let unreliable = setting.detection.unreliable[p];
        let s = d.status;
        let mut shadowed = 0;
        for (k, sk) in s.iter_mut().enumerate() {
            if pixel.shadow.at(p, k) && grey[k] <= dark {
                *sk = status::SHADOW;
                shadowed += 1;
            }
        }
        let count =
            if let (true, Some(att), Some(scratch)) = (unreliable, &setting.attributor, scratch) {
                *d.highlight = shadowed == 0;
                let pix = setting.capture.pixels[p] as usize;
                let (stat, count) = att.run_at(pix, grey, s, scratch);
                *d.consistent = count > 3 && stat <= att.threshold(count);
                count
            } else {
                *d.consistent = true;
                n - shadowed
            };
        let count = if setting.near_lights() && count == 3 {
            exact_dark_as_shadow(s, grey, dark)
        } else {
            count
        };
        if count < 3 {
            *d.few = true;
            *d.consistent = false;
            if setting.params.fallback == Fallback::BrightestLights {
                complete_with_brightest(s, grey, count);
            }
        }
    }

    /// The decisions a pixel takes over instead of attributing again (writes them into `d`
    /// and returns true):
    /// - hysteresis: a usable set that passed the test in the last iteration and already drops
    ///   every light the new surface shadows (where the reading agrees) stays; the recursion
    ///   then settles instead of trading equally good sets between iterations;
    /// - in the first iteration, a pixel of E the surface shadows nowhere (where the reading
    ///   agrees) keeps the detector's decisions, made from every light (distant lights);
    /// - the same attribution input as in the last iteration gives the same decisions
    ///   (distant lights: the light vectors do not follow the surface): reused, not recomputed.
    fn reuse_decision(
        &self,
        setting: &Setting,
        iteration: usize,
        pixel: &PixelInput,
        dark: f64,
        key: &[u8],
        d: &mut PixelDecision,
    ) -> bool {
        let (n, p, grey) = (setting.n_lights(), pixel.p, pixel.grey);
        let key_bytes = setting.key_bytes();
        let near_lights = setting.near_lights();
        let own = &self.own;
        if iteration > 1 {
            unpack_into(own.status.at(p, &self.light_status), d.previous);
        } else {
            // (In the first iteration the current statuses are the detector's.)
            self.light_status.unpack_row(p, d.previous);
        }
        let previous = &d.previous[..n];
        if iteration > 1
            && own.consistent[p]
            && !own.few[p]
            && (0..n)
                .all(|k| previous[k] != status::USED || !(pixel.shadow.at(p, k) && grey[k] <= dark))
        {
            d.status.copy_from_slice(previous);
            *d.consistent = true;
            *d.highlight = self.highlight[p];
            return true;
        }
        let detected = previous;
        if iteration == 1
            && !near_lights
            && setting.detection.unreliable[p]
            && key.iter().all(|&b| b == 0)
            && detected.iter().filter(|&&x| x == status::USED).count() >= 3
        {
            d.status.copy_from_slice(detected);
            *d.consistent = setting.detection.settled[p];
            *d.highlight = true;
            return true;
        }
        if iteration > 1
            && !near_lights
            && own.key.get(p * key_bytes..(p + 1) * key_bytes) == Some(key)
        {
            d.status.copy_from_slice(previous);
            *d.consistent = own.consistent[p];
            *d.few = own.few[p];
            *d.highlight = self.highlight[p];
            return true;
        }
        false
    }
}

/// The estimate's normals and albedo, parked.
type ParkedEstimate = (Parked<[f32; 3]>, Parked<f32>);

/// An iteration's shadow maps from its re-estimate on: held, or parked as their bit planes in
/// a file of their own (width, height, lights, the attached and cast planes).
enum Held {
    Here(ShadowMaps),
    Parked(Parking, usize, usize, usize, [Parked<u64>; 2]),
}

impl Held {
    /// The maps, read back when parked (their file is then freed).
    fn into_maps(self) -> Result<ShadowMaps> {
        match self {
            Held::Here(maps) => Ok(maps),
            Held::Parked(parking, w, h, lights, [a, c]) => Ok(ShadowMaps::from_planes(
                w,
                h,
                lights,
                [parking.take(a)?, parking.take(c)?],
            )),
        }
    }
}

/// Where [`Recursion::park`] put the recursion's per-pixel arrays.
struct ParkedState {
    estimate: ParkedEstimate,
    /// The statuses' width (lights) and packed rows.
    status: (usize, Parked<u8>),
    own_status: (Parked<u32>, Parked<u8>),
    key: Parked<u8>,
    earlier_print: Parked<u32>,
    /// `consistent`, `few`, `solved_two`, `highlight`, `oscillating` and the own decisions'
    /// `consistent` and `few`.
    flags: [Parked<bool>; 7],
}

/// What a pixel's decision reads: its mask index, its grey readings and the surface's shadows.
struct PixelInput<'i> {
    p: usize,
    grey: &'i [f64],
    shadow: &'i ShadowBits,
}

/// Step 3 (paper eq. 13's S_k, ALGORITHMS.md §6): each light's attached shadow (n·l ≤ τ, with
/// the `shading` normals) and cast shadow (horizon sweep) on the surface; of point lights with
/// a near model.
fn shadows_of(setting: &Setting, surface: &Surface, shading: &[[f32; 3]]) -> Result<ShadowMaps> {
    let capture = setting.capture;
    let (w, h) = (capture.width, capture.height);
    let depth = &surface.depth.values;
    let params = &setting.params.shadows;
    match capture.lights.near.as_deref() {
        None => shadow_maps(
            depth,
            shading,
            &capture.mask,
            w,
            h,
            &capture.lights.directions,
            params,
        ),
        Some(near) => crate::geometry::shadows::near::near_shadow_maps(
            near,
            depth,
            shading,
            &capture.mask,
            w,
            h,
            params,
        ),
    }
}

impl Recursion {
    /// The spatial consensus of the usable lights: a fault is a region, not a pixel (see
    /// [`crate::solve::consensus`]). The neighbourhood proposes, the test disposes: a pixel takes
    /// the filtered set only when its own readings pass the χ² test with it (labels follow the
    /// final fit); otherwise its own decisions stand. The pixels' `own` decisions become the
    /// last iteration's; returns the decisions after the consensus and the own statuses.
    fn consensus(
        &mut self,
        setting: &Setting,
        iteration: usize,
        own: Decisions,
        keys: Vec<u8>,
    ) -> Result<(Decisions, Codes2)> {
        let (capture, params) = (setting.capture, setting.params);
        let (n, np) = (setting.n_lights(), setting.n_pixels());
        let radius = params.consensus_radius;
        // From the second iteration, the filter and the settling are redone only near the
        // pixels whose own decisions changed: elsewhere their inputs are the last iteration's,
        // and so are their results (distant lights; near-light vectors follow the surface,
        // and with them the settling's fit).
        let redo = (iteration > 1 && radius > 0 && !setting.near_lights()).then(|| {
            let seeds: Vec<bool> = (0..np)
                .into_par_iter()
                .map(|p| {
                    self.own.status.at(p, &self.light_status) != own.status.row(p)
                        || self.own.consistent[p] != own.consistent[p]
                        || self.own.few[p] != own.few[p]
                })
                .collect();
            crate::solve::consensus::neighbourhood_of(capture, &seeds, radius)
        });
        // The pixels' own decisions become the last iteration's (moved: the last ones are not
        // kept beside them); the consensus writes its result into a new array, so that three
        // status arrays at most are held (current, own, filtered).
        drop(std::mem::take(&mut self.own.status));
        let Decisions {
            status: own_status,
            mut consistent,
            mut few,
            highlight,
        } = own;
        self.own.consistent.clone_from(&consistent);
        self.own.few.clone_from(&few);
        self.own.key = keys;
        if radius == 0 {
            let status = own_status.clone();
            return Ok((
                Decisions {
                    status,
                    consistent,
                    few,
                    highlight,
                },
                own_status,
            ));
        }
        let min_kept = ((setting.detection_params.min_kept_share * n as f64).ceil() as usize)
            .clamp(3, n.max(3));
        let (mut status, _) = crate::solve::consensus::majority_filter_codes(
            capture,
            &own_status,
            radius,
            min_kept,
            redo.as_deref(),
        );
        let redone = |p: usize| redo.as_ref().is_none_or(|r| r[p]);
        let moved: Vec<usize> = (0..np)
            .filter(|&p| redone(p) && usable_differs(&status, &own_status, p, n))
            .collect();
        for p in (0..np).filter(|&p| !redone(p)) {
            status.row_mut(p).copy_from_slice(self.light_status.row(p));
            consistent[p] = self.consistent[p];
            few[p] = self.few[p];
        }
        let mut filtered = Decisions {
            status,
            consistent,
            few,
            highlight,
        };
        if let Some(att) = setting.attributor.as_ref() {
            settle_moved(capture, att, &moved, &own_status, &mut filtered)?;
        }
        Ok((filtered, own_status))
    }

    /// The oscillation rule: a pixel whose new usable set is the one it had before its current
    /// set goes back and forth between two sets that both pass the test as the surface moves a
    /// little between iterations (both sets the recursion's own, not the detector's). It keeps
    /// its current set (and flags) from then on: the recursion settles instead of trading them,
    /// and the change it reports is the change of the other pixels.
    fn hold_oscillating(&mut self, iteration: usize, n: usize, new: &mut Decisions) {
        let np = self.oscillating.len();
        let (current, consistent) = (&self.light_status, &self.consistent);
        let (few, highlight) = (&self.few, &self.highlight);
        new.par_chunks(0..np, 1)
            .zip(self.oscillating.par_iter_mut())
            .zip(self.earlier_print.par_iter_mut())
            .enumerate()
            .for_each(|(p, ((mut chunk, stuck), print))| {
                let current = current.row(p);
                if !usable_sets_differ(chunk.packed(0), current, n) {
                    return;
                }
                if *stuck || usable_print(chunk.packed(0), n) == *print {
                    *stuck = true;
                    chunk.packed_mut(0).copy_from_slice(current);
                    chunk.consistent[0] = consistent[p];
                    chunk.few[0] = few[p];
                    chunk.highlight[0] = highlight[p];
                } else if iteration > 1 {
                    // (The detector's initial sets are not the recursion's decisions: a pixel
                    // that returns to one is settling, not oscillating.)
                    *print = usable_print(current, n);
                }
            });
    }

    /// Step 6: the new decisions replace the current ones and every pixel is estimated again
    /// from its usable lights. With distant lights a pixel's least-squares result depends only
    /// on its usable lights: only pixels whose set `changed` are solved again, and those the
    /// neighbour fill rewrote in the last iteration or rewrites in this one.
    fn re_estimate(
        &mut self,
        setting: &Setting,
        new: Decisions,
        own_status: Codes2,
        changed: Vec<bool>,
        parked_estimate: Option<(&Parking, ParkedEstimate)>,
    ) -> Result<()> {
        let capture = setting.capture;
        // The last statuses have served: replaced before the re-estimate, not kept beside it.
        self.light_status = new.status;
        self.own.status = OwnStatuses::of(&own_status, &self.light_status);
        drop(own_status);
        // The pixels solved again, marked in `changed`; the last flags are then replaced.
        let mut again = changed;
        again
            .par_iter_mut()
            .zip(self.few.par_iter().zip(&new.few))
            .for_each(|(a, (&was, &is))| *a |= was || is);
        self.consistent = new.consistent;
        self.few = new.few;
        self.highlight = new.highlight;
        // A parked estimate comes back once the pixels' own statuses are reduced to their
        // difference and the last flags released: not beside three status arrays.
        if let Some((parking, (normals, albedo))) = parked_estimate {
            parking.unshelve(&mut self.est.normals, normals)?;
            parking.unshelve(&mut self.est.albedo, albedo)?;
        }
        if setting.near_lights() {
            self.est = crate::solve::tiled::solve_statuses(capture, &self.light_status)?;
        } else {
            let factors = &setting.detection.noise.light_factor;
            let statuses = &self.light_status;
            resolve_where(capture, statuses, |p| again[p], &mut self.est, factors)?;
        }
        Ok(())
    }

    /// The [`Fallback::Neighbours`] completion of the pixels left with fewer than three usable
    /// lights, with the surface's normals.
    fn fill_few(&mut self, setting: &Setting, surface: &Surface) -> Result<()> {
        let capture = setting.capture;
        self.solved_two.fill(false);
        let few_ids: Vec<usize> = (0..self.few.len()).filter(|&p| self.few[p]).collect();
        fill_from_neighbours(
            capture,
            &few_ids,
            &mut self.est,
            &self.light_status,
            &self.few,
            &self.consistent,
            &|i: usize| surface.normal_at(i, capture),
            &mut self.solved_two,
        )
    }

    /// Step 7 and the result: the final estimate — each pixel's usable lights with the last
    /// surface as a prior on its normal ([`SurfacePrior`]; distant lights, near lights keep
    /// their least-squares estimate) — its integration trust, and the diagnostics.
    fn finish(
        mut self,
        setting: &Setting,
        records: Vec<IterationRecord>,
        converged: bool,
        stop_reason: String,
    ) -> Result<(Estimate, RecursiveDiagnostics)> {
        let (capture, params) = (setting.capture, setting.params);
        let noise = &setting.detection.noise;
        // The iterations' bookkeeping has served: freed before the final estimate and the
        // full-frame maps are made.
        drop(std::mem::take(&mut self.own));
        drop(std::mem::take(&mut self.earlier_print));
        drop(std::mem::take(&mut self.oscillating));
        let surface_prior = if params.surface_prior_deg > 0.0
            && !setting.near_lights()
            && !self.last_depth.is_empty()
        {
            let scatter = usable_scatter(capture, &self.light_status, &self.few, noise)?;
            let prior = SurfacePrior {
                sigma_rad: params.surface_prior_deg.to_radians(),
                noise: NoiseModel {
                    kappa: scatter,
                    ..noise.clone()
                },
            };
            let (status, few, depth) = (&self.light_status, &self.few, &self.last_depth);
            Some(prior.apply(capture, status, few, depth, &mut self.est)?)
        } else {
            None
        };
        // Step 8: the highlights' lobes, where the reflectance model asks for them.
        let gloss = if params.reflectance != Reflectance::Lambert && !setting.near_lights() {
            let (summary, maps) = crate::solve::gloss::model_highlights(
                capture,
                &self.light_status,
                &mut self.est,
                noise,
                setting.detection_params.confidence,
                params.reflectance,
            )?;
            let full = GlossMaps {
                strength: capture.scatter(&maps.strength, 1, f32::NAN),
                roughness: capture.scatter(&maps.roughness, 1, f32::NAN),
            };
            Some((summary, full))
        } else {
            None
        };
        // The full-frame maps replace their per-mask-pixel values (are them, on a mask that is
        // the whole frame); the shadow maps come back from their file last, once the trust is
        // made and its inputs released.
        let trust = capture.scatter_owned(self.trust(setting), 1, 0.0);
        let highlight = capture.scatter_owned(std::mem::take(&mut self.highlight), 1, false);
        let fewer_than_three = capture.scatter_owned(std::mem::take(&mut self.few), 1, false);
        let reliable = capture.scatter_owned(std::mem::take(&mut self.consistent), 1, false);
        drop(std::mem::take(&mut self.solved_two));
        let diagnostics = RecursiveDiagnostics {
            trust,
            shadows: self
                .last_maps
                .expect("at least one iteration")
                .into_maps()?,
            highlight,
            fewer_than_three,
            depth: self.last_depth,
            reliable,
            final_change: records.last().map_or(0.0, |r| r.changed_share),
            iterations: records,
            fallback: params.fallback,
            converged,
            stop_reason,
            surface_prior,
            gloss,
            light_status: self.light_status,
        };
        Ok((self.est, diagnostics))
    }
}

/// The second half of the consensus at the pixels `moved` (those the filter gave another
/// usable set): the attribution settles the filtered set against the pixel's own readings; a
/// set that passes the χ² test is taken (the pixel is then consistent), otherwise the pixel's
/// own decisions stand (the test disposes).
fn settle_moved(
    capture: &Capture,
    att: &Attributor,
    moved: &[usize],
    own_status: &Codes2,
    filtered: &mut Decisions,
) -> Result<()> {
    let (n, c) = (capture.n_lights(), capture.channels);
    let mut scratch = att.scratch();
    let mut grey = vec![0f64; n];
    let mut s = vec![0u8; n];
    capture.for_ids_by_tile(moved, |sub, view| {
        for &p in sub {
            channel_mean(view.pixel_samples(p), c, &mut grey);
            let pix = capture.pixels[p] as usize;
            filtered.status.unpack_row(p, &mut s);
            let (stat, count) = att.settle_at(pix, &grey, &mut s, &mut scratch);
            if count > 3 && stat <= att.threshold(count) {
                filtered.consistent[p] = true;
                filtered.few[p] = false;
                filtered.status.pack_row(p, &s);
            } else {
                // The neighbours' set does not fit this pixel's readings: the pixel's own
                // decisions stand (the test disposes).
                filtered
                    .status
                    .row_mut(p)
                    .copy_from_slice(own_status.row(p));
            }
        }
        Ok(())
    })
}

/// The recursive method's final step: a maximum a posteriori estimate of each pixel's scaled
/// normal b = ρ n from its usable lights, with the last integrated surface as a prior on n.
///
/// The data term is the usable readings' weighted least squares under `noise` (σ_k² =
/// c_k² (σ₀² + κ² Ī²), Ī the mean of the usable readings); the prior says b ≈ ρ̂ n_s with an isotropic standard deviation ρ̂ σ_s,
/// n_s the surface's normal and ρ̂ the pixel's own least-squares albedo:
/// b = (G + π I)⁻¹ (r + π ρ̂ n_s), G = Σ l_k l_kᵀ / σ_k², r = Σ l_k I_k / σ_k², π = 1 / (ρ̂ σ_s)².
/// Where the readings determine the normal well (many lights, bright) the prior barely moves
/// it; where they do not (few usable lights, dark, readings near the noise floor) the surface's
/// normal — the integrable part of the neighbourhood's normals — steadies it. That removes
/// the speckle of per-pixel usable sets without smoothing what the readings show: the prior is
/// robust, its precision divided by 1 + a² / (3² (σ_s² + v)), a the angle between the
/// least-squares normal and the surface's and v the least-squares normal's own angular
/// variance, so that where the two disagree beyond three combined standard deviations (a
/// crease or a step the integration smooths over) the readings decide.
pub struct SurfacePrior {
    /// σ_s, radians.
    pub sigma_rad: f64,
    /// The readings' noise: the detector's σ₀, floor and light factors, with κ the scatter of
    /// the usable readings (`usable_scatter`; the test's κ is a decision threshold, this one
    /// what the readings the estimate uses show).
    pub noise: NoiseModel,
}

/// The model error κ of the readings the estimate uses: over a regular sample of at most 8192
/// mask pixels with four usable lights or more (not flagged in `skip`), each pixel's weighted
/// least-squares residual variance s² over its usable lights (light factors of `noise`), scaled
/// to the median of its χ² distribution (so that the median over the pixels estimates the
/// variance, whatever each pixel's degrees of freedom), gives κ_p² = (s² − σ₀²) / Ī², Ī the
/// usable readings' mean; κ is the square root of the median of κ_p² (0 when negative or with
/// fewer than 100 pixels). Unlike the capture's κ measured over all lights
/// ([`crate::solve::detect::estimate_kappa`]), it leaves out the readings the recursion dropped:
/// highlights and shadows do not count as the readings' scatter.
fn usable_scatter(
    capture: &Capture,
    light_status: &Codes2,
    skip: &[bool],
    noise: &NoiseModel,
) -> Result<f64> {
    use nalgebra::{Matrix3, Vector3};
    let (n, c) = (capture.n_lights(), capture.channels);
    let np = capture.n_pixels();
    let ids: Vec<usize> = (0..np)
        .step_by(np.div_ceil(8192).max(1))
        .filter(|&p| !skip[p])
        .collect();
    let mut dirs = crate::solve::detect::distant_directions(capture);
    for (k, d) in dirs.iter_mut().enumerate() {
        *d /= noise.light_factor.get(k).copied().unwrap_or(1.0);
    }
    // The median of χ²_ν / ν per degrees of freedom ν.
    let chi2_median: Vec<f64> = (0..n.max(4))
        .map(|dof| {
            if dof == 0 {
                1.0
            } else {
                crate::base::stats::chi2_quantile(0.5, dof) / dof as f64
            }
        })
        .collect();
    let mut k2 = Vec::with_capacity(ids.len());
    let mut grey = vec![0f64; n];
    capture.for_ids_by_tile(&ids, |sub, view| {
        for &p in sub {
            channel_mean(view.pixel_samples(p), c, &mut grey);
            for (k, g) in grey.iter_mut().enumerate() {
                *g /= noise.light_factor.get(k).copied().unwrap_or(1.0);
            }
            let used = |k: usize| light_status.get(p, k) == status::USED;
            let count = (0..n).filter(|&k| used(k)).count();
            if count < 4 {
                continue;
            }
            let (mut gram, mut rhs, mut level) = (Matrix3::zeros(), Vector3::zeros(), 0.0);
            for k in (0..n).filter(|&k| used(k)) {
                gram += dirs[k] * dirs[k].transpose();
                rhs += dirs[k] * grey[k];
                level += grey[k];
            }
            let Some(gi) = gram.try_inverse() else {
                continue;
            };
            let m = gi * rhs;
            let rss: f64 = (0..n)
                .filter(|&k| used(k))
                .map(|k| (grey[k] - dirs[k].dot(&m)).powi(2))
                .sum();
            let dof = count - 3;
            let level = level / count as f64;
            if level > 0.0 {
                let s2 = rss / dof as f64 / chi2_median[dof];
                k2.push((s2 - noise.sigma0 * noise.sigma0) / (level * level));
            }
        }
        Ok(())
    })?;
    if k2.len() < 100 {
        return Ok(0.0);
    }
    Ok(crate::solve::metrics::median(&mut k2).max(0.0).sqrt())
}

/// What [`SurfacePrior::apply`] did, for the report.
#[derive(Clone, Debug, Serialize)]
pub struct SurfacePriorRecord {
    /// σ_s, degrees.
    pub prior_deg: f64,
    /// κ of the data term.
    pub kappa: f64,
    /// Pixels re-estimated (mask pixels with three usable lights or more and a surface normal).
    pub pixels: usize,
    /// Mean angle between the least-squares and the final normals, degrees.
    pub mean_shift_deg: f64,
}

/// The prior is released where the least-squares normal and the surface disagree beyond this
/// many combined standard deviations (a Cauchy weight with scale 3).
const PRIOR_RELEASE_SIGMAS: f64 = 3.0;

impl SurfacePrior {
    /// Re-estimates the mask pixels of `est` not flagged in `skip` (they keep their estimate)
    /// from their usable lights in `light_status` and the surface `depth` (full frame, pixel
    /// units, NaN outside the mask). Distant lights.
    pub fn apply(
        &self,
        capture: &Capture,
        light_status: &(impl Statuses + ?Sized),
        skip: &[bool],
        depth: &[f32],
        est: &mut Estimate,
    ) -> Result<SurfacePriorRecord> {
        let (n, c) = (capture.n_lights(), capture.channels);
        let (w, h) = (capture.width, capture.height);
        let factors = &self.noise.light_factor;
        let dirs = crate::solve::detect::distant_directions(capture);
        // The shift summed in nanodegrees as integers: the same total in any order, however
        // the capture is tiled.
        let (mut pixels, mut shift_nano) = (0usize, 0u64);
        capture.for_each_tile(|off, tile| {
            let tn = tile.n_pixels();
            let sums: Vec<(usize, u64)> = est.normals[off..off + tn]
                .par_chunks_mut(CHUNK)
                .zip(est.albedo[off * c..(off + tn) * c].par_chunks_mut(CHUNK * c))
                .enumerate()
                .map_init(
                    || (vec![0f64; n], vec![false; n]),
                    |(grey, used), (chunk, (normals, albedo))| {
                        let (mut count, mut nano) = (0usize, 0u64);
                        for (dp, old) in normals.iter_mut().enumerate() {
                            let lp = chunk * CHUNK + dp;
                            let p = off + lp;
                            if skip[p] {
                                continue;
                            }
                            let samples = tile.pixel_samples(lp);
                            channel_mean(samples, c, grey);
                            light_status.used_into(p, used);
                            let i = capture.pixels[p] as usize;
                            let surface = normal_from_depth_at(i, w, h, depth, &capture.mask);
                            let Some(m) = self.solve(&dirs, factors, grey, used, surface) else {
                                continue;
                            };
                            let mut normal = [0f32; 3];
                            write_normal_albedo_with(
                                &capture.lights.directions,
                                c,
                                samples,
                                &m,
                                Some(used),
                                &mut normal,
                                &mut albedo[dp * c..(dp + 1) * c],
                            );
                            nano += (angular_error_deg(normal, *old) * 1e9).round() as u64;
                            *old = normal;
                            count += 1;
                        }
                        (count, nano)
                    },
                )
                .collect();
            for (count, nano) in sums {
                pixels += count;
                shift_nano += nano;
            }
            Ok(())
        })?;
        let shift = shift_nano as f64 * 1e-9;
        Ok(SurfacePriorRecord {
            prior_deg: self.sigma_rad.to_degrees(),
            kappa: self.noise.kappa,
            pixels,
            mean_shift_deg: shift / pixels.max(1) as f64,
        })
    }

    /// One pixel's scaled normal: `grey` its channel-mean readings, `used` its usable lights,
    /// `surface` the surface's unit normal there ((0, 0, 0): none). `None` when the usable
    /// lights do not determine a normal or there is no surface normal (the estimate stays).
    fn solve(
        &self,
        dirs: &[nalgebra::Vector3<f64>],
        factors: &[f64],
        grey: &[f64],
        used: &[bool],
        surface: [f32; 3],
    ) -> Option<nalgebra::Vector3<f64>> {
        use nalgebra::{Matrix3, Vector3};
        if surface == [0.0; 3] {
            return None;
        }
        // The model error scales with the readings the fit uses (at a pixel most of whose
        // lights are in shadow, the lit ones), not with the mean over every light.
        let (sum, used_count) = grey
            .iter()
            .zip(used)
            .filter(|(_, &u)| u)
            .fold((0.0, 0usize), |(s, c), (g, _)| (s + g, c + 1));
        if used_count < 3 {
            return None;
        }
        let variance = self.noise.variance(sum / used_count as f64);
        let (mut gram, mut rhs) = (Matrix3::<f64>::zeros(), Vector3::<f64>::zeros());
        for k in (0..dirs.len()).filter(|&k| used[k]) {
            let f = factors.get(k).copied().unwrap_or(1.0);
            let inv = 1.0 / (variance * f * f);
            gram += dirs[k] * dirs[k].transpose() * inv;
            rhs += dirs[k] * (grey[k] * inv);
        }
        let gram_inv = gram.try_inverse()?;
        let m = gram_inv * rhs;
        let rho = m.norm();
        if !(rho.is_finite() && rho > 1e-12) {
            return None;
        }
        let normal = m / rho;
        let prior = Vector3::new(surface[0] as f64, surface[1] as f64, surface[2] as f64);
        // The least-squares normal's angular variance v: its covariance G⁻¹ / ρ² on the
        // tangent plane; a: its angle to the surface's normal.
        let tangent = Matrix3::identity() - normal * normal.transpose();
        let own = (tangent * gram_inv * tangent).trace() / (rho * rho);
        let angle = normal.dot(&prior).clamp(-1.0, 1.0).acos();
        let s2 = self.sigma_rad * self.sigma_rad;
        let release = 1.0 + angle * angle / (PRIOR_RELEASE_SIGMAS.powi(2) * (s2 + own));
        let precision = 1.0 / (rho * rho * s2 * release);
        (gram + Matrix3::identity() * precision)
            .try_inverse()
            .map(|g| g * (rhs + prior * (rho * precision)))
    }
}

/// A status array of `n` lights per mask pixel held as its difference from another (the
/// pixels' own decisions against the statuses after the consensus, which differ at a few
/// pixels): the pixels where they differ and their statuses there, as packed rows.
#[derive(Default)]
struct OwnStatuses {
    /// Mask pixels where the statuses differ, ascending.
    ids: Vec<u32>,
    /// Their packed status rows, `stride` bytes per pixel of `ids`.
    codes: Vec<u8>,
    stride: usize,
}

impl OwnStatuses {
    /// `own` held as its difference from `base` (both a row of `n` codes per mask pixel).
    fn of(own: &Codes2, base: &Codes2) -> OwnStatuses {
        let stride = own.stride();
        let mut held = OwnStatuses {
            stride,
            ..OwnStatuses::default()
        };
        for p in 0..own.rows() {
            if !own.rows_equal(p, base, p) {
                held.ids.push(p as u32);
                held.codes.extend_from_slice(own.row(p));
            }
        }
        held
    }

    /// Mask pixel `p`'s packed statuses, `base`'s (the array this was made against) where
    /// they agree.
    fn at<'a>(&'a self, p: usize, base: &'a Codes2) -> &'a [u8] {
        match self.ids.binary_search(&(p as u32)) {
            Ok(j) => &self.codes[j * self.stride..(j + 1) * self.stride],
            Err(_) => base.row(p),
        }
    }
}

/// Solves the mask pixels `ids` of `est` again with their usable lights in `statuses`
/// ([`crate::solve::lambert::resolve_subsets_at`], lights weighted by `factors`), reading their
/// samples from a sampled view when the capture is tiled.
fn resolve_at(
    capture: &Capture,
    statuses: &Codes2,
    ids: &[usize],
    est: &mut Estimate,
    factors: &[f64],
) -> Result<()> {
    capture.for_ids_by_tile(ids, |sub, view| {
        crate::solve::lambert::resolve_subsets_at(view, statuses, sub, est, factors);
        Ok(())
    })
}

/// Mask pixels listed at once by [`resolve_where`] on a capture held whole.
const RESOLVE_BLOCK: usize = 1 << 16;

/// [`resolve_at`] the mask pixels `again` selects, a block of pixels at a time (a tile of a
/// tiled capture): no list of every selected pixel (8 bytes each) is held beside the estimate.
fn resolve_where(
    capture: &Capture,
    statuses: &Codes2,
    again: impl Fn(usize) -> bool,
    est: &mut Estimate,
    factors: &[f64],
) -> Result<()> {
    let np = capture.n_pixels();
    let blocks: Vec<std::ops::Range<usize>> = match &capture.store {
        Some(store) => (0..store.tiling().len())
            .map(|t| store.tiling().pixels(t))
            .collect(),
        None => (0..np)
            .step_by(RESOLVE_BLOCK)
            .map(|s| s..(s + RESOLVE_BLOCK).min(np))
            .collect(),
    };
    for block in blocks {
        let ids: Vec<usize> = block.filter(|&p| again(p)).collect();
        if !ids.is_empty() {
            resolve_at(capture, statuses, &ids, est, factors)?;
        }
    }
    Ok(())
}

/// Whether mask pixel `p`'s usable-light set differs between two status arrays of `n` lights
/// per pixel (labels of removed lights aside).
fn usable_differs(a: &Codes2, b: &Codes2, p: usize, n: usize) -> bool {
    usable_sets_differ(a.row(p), b.row(p), n)
}

/// Whether two packed status rows of `n` lights differ in their usable-light sets.
fn usable_sets_differ(a: &[u8], b: &[u8], n: usize) -> bool {
    (0..n).any(|k| (get_in(a, k) == status::USED) != (get_in(b, k) == status::USED))
}

/// When the recursion stops, and why: the usable-light sets settled (the share of pixels that
/// changed fell below the tolerance, or the sets did not change), they cycle (an iteration
/// repeats the sets of an earlier one, not the last), the change stalled (no new smallest
/// change for [`STALL_ITERATIONS`] iterations), or the iteration limit.
struct StopRule {
    tolerance: f64,
    max_iterations: usize,
    /// Fingerprints of the usable-light sets after each iteration (the initial sets first).
    seen: Vec<u64>,
    /// The smallest change so far and its iteration.
    best_change: (f64, usize),
}

impl StopRule {
    fn new(params: &RecursiveParams, initial: u64) -> Self {
        StopRule {
            tolerance: params.change_tolerance,
            max_iterations: params.max_iterations,
            seen: vec![initial],
            best_change: (f64::INFINITY, 0),
        }
    }

    /// After `iteration` (from 1), whose sets have fingerprint `print` and changed at a share
    /// `change` of the pixels: `Some((converged, reason))` to stop, `None` to go on (the
    /// iteration limit gives `Some((false, …))`).
    fn after(&mut self, iteration: usize, change: f64, print: u64) -> Option<(bool, String)> {
        let (pct, tol) = (100.0 * change, 100.0 * self.tolerance);
        if change < self.tolerance {
            return Some((
                true,
                format!(
                    "converged after {iteration} iterations: {pct:.2}% of the pixels changed their usable lights (tolerance {tol:.2}%)"
                ),
            ));
        }
        if self.seen.last() == Some(&print) {
            // Only labels changed: the usable sets, hence the estimate, are settled.
            return Some((
                true,
                format!(
                    "converged after {iteration} iterations: the usable-light sets did not change"
                ),
            ));
        }
        if let Some(at) = self.seen.iter().rposition(|&f| f == print) {
            return Some((
                false,
                format!(
                    "not converged: iteration {iteration} repeats the usable-light sets of iteration {at} (a cycle of period {}); {pct:.2}% of the pixels change per iteration against a tolerance of {tol:.2}%",
                    iteration - at
                ),
            ));
        }
        self.seen.push(print);
        if change < self.best_change.0 {
            self.best_change = (change, iteration);
        } else if iteration - self.best_change.1 >= STALL_ITERATIONS {
            return Some((
                false,
                format!(
                    "not converged: the change has not fallen below its smallest value ({:.2}% at iteration {}) for {STALL_ITERATIONS} iterations; {pct:.2}% of the pixels change per iteration against a tolerance of {tol:.2}%",
                    100.0 * self.best_change.0,
                    self.best_change.1
                ),
            ));
        }
        (iteration >= self.max_iterations).then(|| {
            (
                false,
                format!(
                    "not converged: stopped at the iteration limit ({iteration}) with {pct:.2}% of the pixels changing their usable lights (tolerance {tol:.2}%)"
                ),
            )
        })
    }
}

/// Iterations without a new smallest change after which the recursion is declared stalled
/// (it wanders between nearly the same sets without settling).
pub const STALL_ITERATIONS: usize = 10;

/// A fingerprint of per-pixel light statuses (usable or not), for cycle detection.
/// A 32-bit fingerprint (FNV-1a) of one pixel's usable-light set (its statuses `row`); never
/// 0 for a set, so that 0 can stand for none.
fn usable_print(row: &[u8], n: usize) -> u32 {
    let mut h = 0x811c_9dc5u32;
    for start in (0..n).step_by(8) {
        let mut bits = 0u8;
        for (i, k) in (start..(start + 8).min(n)).enumerate() {
            bits |= u8::from(get_in(row, k) == status::USED) << i;
        }
        h = (h ^ u32::from(bits)).wrapping_mul(0x0100_0193);
    }
    h.max(1)
}

/// The usable flags of every (pixel, light) in pixel-major order, hashed 64 at a time.
fn fingerprint(light_status: &Codes2) -> u64 {
    use std::hash::{Hash, Hasher};
    let mut h = std::collections::hash_map::DefaultHasher::new();
    let n = light_status.width();
    let (mut bits, mut i) = (0u64, 0usize);
    for p in 0..light_status.rows() {
        let row = light_status.row(p);
        for k in 0..n {
            bits |= u64::from(get_in(row, k) == status::USED) << i;
            i += 1;
            if i == 64 {
                bits.hash(&mut h);
                (bits, i) = (0, 0);
            }
        }
    }
    if i > 0 {
        bits.hash(&mut h);
    }
    h.finish()
}

/// The recursion's integration trust per mask pixel: 1 where the usable lights pass the test
/// and at least three remain, `unreliable_weight` where they do not, 0 where the normal came
/// from neither (fewer than three lights and no two-source solution).
fn pixel_trust(
    est: &Estimate,
    consistent: &[bool],
    few: &[bool],
    solved_two: &[bool],
    unreliable_weight: f32,
) -> Vec<f32> {
    (0..est.normals.len())
        .map(|p| {
            if few[p] && !solved_two[p] {
                0.0
            } else if consistent[p] && !few[p] {
                1.0
            } else {
                unreliable_weight
            }
        })
        .collect()
}

/// An intermediate surface: the weighted normals integrated with the reconstruction's
/// integrator and slope cap.
fn integrate(
    w: usize,
    h: usize,
    normals: Vec<[f32; 3]>,
    mask: &[bool],
    weights: &[f32],
    initial: Vec<f32>,
    integration: &IntegrationParams,
) -> Result<crate::geometry::integrate::Depth> {
    let g = gradients_from_normals(w, h, &normals, Some(mask), integration.max_slope)?;
    drop(normals);
    if integration.method == IntegratorKind::Bilateral {
        // `bilateral` fills the gradients and solves in the arrays given: no second copy of
        // the gradients or of the last surface is held. The first surface starts from 0, as
        // without a start.
        let initial = if initial.is_empty() {
            vec![0.0; w * h]
        } else {
            initial
        };
        let mut depth = Bilateral::intermediate().integrate_owned(
            w,
            h,
            g.p,
            g.q,
            &g.mask,
            Some(weights),
            initial,
            &Silent,
        )?;
        depth.discontinuities = None;
        return Ok(depth);
    }
    let problem = IntegrationProblem {
        weights: Some(weights),
        ..IntegrationProblem::new(w, h, &g.p, &g.q, &g.mask)
    };
    let mut depth = match integration.method {
        // `poisson` solves in the last surface's buffer: one depth map held, not two.
        IntegratorKind::Poisson if !initial.is_empty() => {
            Poisson::default().integrate_in_place(&problem, initial, &Silent)
        }
        _ => {
            let problem = IntegrationProblem {
                initial: (!initial.is_empty()).then_some(&initial[..]),
                ..problem
            };
            integration
                .method
                .intermediate_integrator()
                .integrate(&problem, &Silent)
        }
    }?;
    // The recursion reads the heights only: `bilateral`'s discontinuity map is not kept.
    depth.discontinuities = None;
    Ok(depth)
}

/// A near-light iteration's surface: the weighted normals integrated through the camera into
/// Z (mm), made the light model's current surface, and its normals (for shading and shadows).
fn near_surface(
    capture: &Capture,
    near: &crate::model::lightmodel::NearLights,
    normals: &[[f32; 3]],
    weights: &[f32],
    integration: &IntegrationParams,
) -> Result<(crate::geometry::integrate::Depth, Vec<[f32; 3]>)> {
    let (w, h) = (capture.width, capture.height);
    let s = crate::geometry::integrate::perspective::perspective_surface(
        w,
        h,
        normals,
        Some(&capture.mask),
        Some(weights),
        &near.camera,
        near.mean_distance,
        integration.method.intermediate_integrator().as_ref(),
        integration.max_slope,
        &Silent,
    )?;
    near.set_surface(&s.depth.values);
    let shading = crate::geometry::integrate::perspective::normals_from_z(
        w,
        h,
        &s.depth.values,
        &capture.mask,
        &near.camera,
    );
    Ok((s.depth, shading))
}

/// The [`Fallback::Neighbours`] completion of the pixels `few_ids` (ascending), those with
/// fewer than three usable lights; their samples are read a tile at a time.
#[allow(clippy::too_many_arguments)]
fn fill_from_neighbours(
    capture: &Capture,
    few_ids: &[usize],
    est: &mut Estimate,
    light_status: &Codes2,
    few: &[bool],
    reliable: &[bool],
    surface_normal: &dyn Fn(usize) -> [f32; 3],
    solved: &mut [bool],
) -> Result<()> {
    let n = capture.n_lights();
    let c = capture.channels;
    let (w, h) = (capture.width, capture.height);
    if few_ids.is_empty() {
        return Ok(());
    }
    // Grey albedo of the reliable pixels, full frame (NaN elsewhere), from the estimate before
    // any pixel is completed.
    let mut albedo_map = vec![f32::NAN; w * h];
    for (p, &i) in capture.pixels.iter().enumerate() {
        if reliable[p] && !few[p] && est.normals[p] != [0.0; 3] {
            albedo_map[i as usize] = est.albedo[p * c..(p + 1) * c].iter().sum::<f32>() / c as f32;
        }
    }
    let mut lights = capture.pixel_lights();
    let mut dirs = vec![[0f64; 3]; n];
    let mut grey = vec![0f64; n];
    let mut samples = Vec::new();
    let mut used: Vec<usize> = Vec::with_capacity(n);
    let mut flags = vec![false; n];
    capture.for_ids_by_tile(few_ids, |sub, samples_of| {
        for &p in sub {
            let pix = capture.pixels[p] as usize;
            let (row, col) = (pix / w, pix % w);
            let surf = surface_normal(pix);
            // Median albedo of the nearest reliable pixels (growing windows). Near lights: as
            // far as the nearest reliable pixels are (a point light's cast shadow is wider in
            // pixels the finer the image), as [`crate::solve::near_lobe::correct_two`] does.
            let widest = if lights.is_near() { w.max(h) } else { 32 };
            let rho = crate::solve::metrics::median_in_growing_window(
                &albedo_map,
                w,
                h,
                (row, col),
                widest,
                &mut samples,
            );
            used.clear();
            used.extend((0..n).filter(|&k| light_status.get(p, k) == status::USED));
            channel_mean(samples_of.pixel_samples(p), c, &mut grey);
            dirs.copy_from_slice(lights.at(pix));
            let two = if used.len() == 2 && rho.is_finite() && !lights.is_near() {
                two_source_normal(
                    dirs[used[0]],
                    dirs[used[1]],
                    grey[used[0]] / rho,
                    grey[used[1]] / rho,
                    surf,
                )
            } else if used.len() == 2 && rho.is_finite() {
                // Scaled near-light vectors v = b·l: n · l = I / (ρ b).
                let unit = |v: [f64; 3]| {
                    let b = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                    ([v[0] / b, v[1] / b, v[2] / b], b)
                };
                let ((l1, b1), (l2, b2)) = (unit(dirs[used[0]]), unit(dirs[used[1]]));
                two_source_normal(
                    l1,
                    l2,
                    grey[used[0]] / (rho * b1),
                    grey[used[1]] / (rho * b2),
                    surf,
                )
            } else {
                None
            };
            solved[p] = two.is_some();
            let nrm = match two {
                Some(v) => v,
                None if surf != [0.0; 3] => surf,
                None => continue,
            };
            let m = nalgebra::Vector3::new(nrm[0] as f64, nrm[1] as f64, nrm[2] as f64);
            for (k, f) in flags.iter_mut().enumerate() {
                *f = used.contains(&k);
            }
            let mut out_n = [0f32; 3];
            write_normal_albedo_with(
                &dirs,
                c,
                samples_of.pixel_samples(p),
                &m,
                Some(&flags),
                &mut out_n,
                &mut est.albedo[p * c..(p + 1) * c],
            );
            est.normals[p] = nrm;
        }
        Ok(())
    })
}

/// The unit normals n with n·l₁ = a and n·l₂ = b (two-source photometric stereo with known
/// albedo): the root closer to `hint` (or the one facing the camera more when `hint` is zero).
fn two_source_normal(
    l1: [f64; 3],
    l2: [f64; 3],
    a: f64,
    b: f64,
    hint: [f32; 3],
) -> Option<[f32; 3]> {
    let v1 = nalgebra::Vector3::from(l1);
    let v2 = nalgebra::Vector3::from(l2);
    let cos = v1.dot(&v2);
    let det = 1.0 - cos * cos;
    if det < 1e-6 {
        return None;
    }
    let alpha = (a - b * cos) / det;
    let beta = (b - a * cos) / det;
    let in_plane = v1 * alpha + v2 * beta;
    let cross = v1.cross(&v2);
    let gamma2 = (1.0 - in_plane.norm_squared()) / cross.norm_squared();
    let gamma = gamma2.max(0.0).sqrt();
    let hint = nalgebra::Vector3::new(hint[0] as f64, hint[1] as f64, hint[2] as f64);
    let score = |n: &nalgebra::Vector3<f64>| if hint.norm() > 0.0 { n.dot(&hint) } else { n.z };
    let candidates = [in_plane + cross * gamma, in_plane - cross * gamma];
    let best = candidates
        .iter()
        .filter(|n| n.norm() > 1e-9)
        .max_by(|x, y| score(x).total_cmp(&score(y)))?;
    let best = best.normalize();
    (best.z > 0.0).then(|| [best.x as f32, best.y as f32, best.z as f32])
}

/// Near lights, a pixel left with exactly three usable lights: nothing can test them, and a
/// reading at the shadow level `dark` among them says only that the light does not reach the
/// point (a cast shadow of a point light reads as dark as an attached one, whatever the normal),
/// not that n · l is zero, which the exact solve would make it. Such readings are marked
/// SHADOW; returns the usable lights left.
fn exact_dark_as_shadow(status_row: &mut [u8], grey: &[f64], dark: f64) -> usize {
    let mut count = 0;
    for (s, &g) in status_row.iter_mut().zip(grey) {
        if *s == status::USED {
            if g <= dark {
                *s = status::SHADOW;
            } else {
                count += 1;
            }
        }
    }
    count
}

/// Near lights: the integration trust of the pixels whose normal is exactly determined (three
/// usable lights, nothing left for the χ² test, so no evidence beyond the noise level) is the
/// precision of that solve relative to the solve with every light, both under the same noise:
/// tr((Σ_all v vᵀ)⁻¹) / tr((Σ_used v vᵀ)⁻¹), v the pixel's scaled light vectors at the current
/// surface (0.5 for a four-light square), in place of 1 or the weight of unreliable pixels.
/// Pixels `few` (completed from two lights or the surface) keep theirs.
fn exact_trust(capture: &Capture, light_status: &Codes2, few: &[bool], trust: &mut [f32]) {
    let n = capture.n_lights();
    let mut lights = capture.pixel_lights();
    let mut st = vec![0u8; n];
    for (p, t) in trust.iter_mut().enumerate() {
        light_status.unpack_row(p, &mut st);
        if few[p] || *t == 0.0 || st.iter().filter(|&&x| x == status::USED).count() != 3 {
            continue;
        }
        if let Some(r) = relative_precision(lights.at(capture.pixels[p] as usize), &st) {
            *t = r as f32;
        }
    }
}

/// tr((Σ_all v vᵀ)⁻¹) / tr((Σ_used v vᵀ)⁻¹) over light vectors `v` (USED in `st`), in [0, 1]:
/// the precision of the least-squares normal from the used lights relative to all of them,
/// under the same noise. `None` when either sum has no inverse (near 0 when nearly singular).
fn relative_precision(v: &[[f64; 3]], st: &[u8]) -> Option<f64> {
    let (mut all, mut used) = (nalgebra::Matrix3::zeros(), nalgebra::Matrix3::zeros());
    for (l, &sk) in v.iter().zip(st) {
        let l = nalgebra::Vector3::from(*l);
        let o = l * l.transpose();
        all += o;
        if sk == status::USED {
            used += o;
        }
    }
    let a = all.try_inverse()?.trace();
    let u = used.try_inverse()?.trace();
    Some((a / u).clamp(0.0, 1.0))
}

#[cfg(test)]
mod exact_tests {
    use super::*;

    /// Three lights of a symmetric four-light square at any slant: Sherman–Morrison gives
    /// tr(G₃⁻¹) = 2 tr(G₄⁻¹), a relative precision of exactly one half; every light kept, 1.
    #[test]
    fn three_of_a_square_have_half_the_precision_of_four() {
        for slant in [15f64, 35.0, 60.0] {
            let (s, c) = (slant.to_radians().sin(), slant.to_radians().cos());
            let v: Vec<[f64; 3]> = (0..4)
                .map(|k| {
                    let phi = (45.0 + 90.0 * k as f64).to_radians();
                    [s * phi.cos(), s * phi.sin(), c]
                })
                .collect();
            for drop in 0..4 {
                let mut st = [status::USED; 4];
                st[drop] = status::SHADOW;
                let r = relative_precision(&v, &st).unwrap();
                assert!((r - 0.5).abs() < 1e-12, "slant {slant}, light {drop}: {r}");
            }
            let r = relative_precision(&v, &[status::USED; 4]).unwrap();
            assert!((r - 1.0).abs() < 1e-12);
            // Two lights: singular (no inverse, or one so large that nothing is left).
            let st = [status::USED, status::USED, status::SHADOW, status::SHADOW];
            let r = relative_precision(&v, &st);
            assert!(r.is_none_or(|r| r < 1e-9), "{r:?}");
        }
    }

    /// Readings at or under the shadow level leave the usable set; lights already removed
    /// keep their labels.
    #[test]
    fn dark_readings_of_an_exact_set_become_shadows() {
        let mut st = [status::USED, status::USED, status::HIGHLIGHT, status::USED];
        let count = exact_dark_as_shadow(&mut st, &[0.5, 0.01, 0.9, 0.02], 0.02);
        assert_eq!(count, 1);
        assert_eq!(
            st,
            [
                status::USED,
                status::SHADOW,
                status::HIGHLIGHT,
                status::SHADOW
            ]
        );
    }
}

/// Marks the brightest unused lights as used until three are.
fn complete_with_brightest(status_row: &mut [u8], grey: &[f64], mut count: usize) {
    while count < 3 {
        let best = (0..status_row.len())
            .filter(|&k| status_row[k] != status::USED)
            .max_by(|&a, &b| grey[a].total_cmp(&grey[b]));
        match best {
            Some(k) => {
                status_row[k] = status::USED;
                count += 1;
            }
            None => break,
        }
    }
}

fn mean_error(normals: &[[f32; 3]], truth: &[[f32; 3]]) -> f64 {
    let (mut sum, mut count) = (0.0, 0usize);
    for (a, t) in normals.iter().zip(truth) {
        if *t != [0.0; 3] {
            let e = if *a == [0.0; 3] {
                90.0
            } else {
                angular_error_deg(*a, *t)
            };
            sum += e;
            count += 1;
        }
    }
    sum / count.max(1) as f64
}

#[cfg(test)]
mod stop_tests {
    use super::*;

    fn rule(tolerance: f64, max_iterations: usize) -> StopRule {
        let params = RecursiveParams {
            change_tolerance: tolerance,
            max_iterations,
            ..RecursiveParams::default()
        };
        StopRule::new(&params, 100)
    }

    #[test]
    fn settling_below_the_tolerance_or_unchanged_sets_converge() {
        let mut r = rule(0.01, 50);
        assert_eq!(r.after(1, 0.2, 1), None);
        let (done, why) = r.after(2, 0.005, 2).unwrap();
        assert!(done && why.contains("0.50%"), "{why}");
        let mut r = rule(0.0, 50);
        assert_eq!(r.after(1, 0.2, 1), None);
        let (done, why) = r.after(2, 0.0, 1).unwrap();
        assert!(done && why.contains("did not change"), "{why}");
    }

    #[test]
    fn a_repeated_set_is_a_cycle_with_its_period() {
        let mut r = rule(0.001, 1000);
        for (i, print) in [1u64, 2, 3].into_iter().enumerate() {
            assert_eq!(r.after(i + 1, 0.1, print), None);
        }
        // Iteration 4 repeats iteration 2's sets: period 2.
        let (done, why) = r.after(4, 0.1, 2).unwrap();
        assert!(
            !done && why.contains("iteration 2") && why.contains("period 2"),
            "{why}"
        );
        // The initial sets count too (iteration 0).
        let mut r = rule(0.001, 1000);
        assert_eq!(r.after(1, 0.1, 7), None);
        let (done, why) = r.after(2, 0.1, 100).unwrap();
        assert!(!done && why.contains("period 2"), "{why}");
    }

    #[test]
    fn a_stall_and_the_limit_stop_without_convergence() {
        let mut r = rule(0.001, 1000);
        assert_eq!(r.after(1, 0.05, 1), None);
        for i in 2..=STALL_ITERATIONS {
            assert_eq!(r.after(i, 0.06, i as u64), None, "iteration {i}");
        }
        let (done, why) = r.after(STALL_ITERATIONS + 1, 0.06, 999).unwrap();
        assert!(!done && why.contains("has not fallen"), "{why}");
        let mut r = rule(0.001, 3);
        assert_eq!(r.after(1, 0.3, 1), None);
        assert_eq!(r.after(2, 0.2, 2), None);
        let (done, why) = r.after(3, 0.1, 3).unwrap();
        assert!(!done && why.contains("iteration limit (3)"), "{why}");
    }
}

#[cfg(test)]
mod own_status_tests {
    use super::*;

    /// The difference form gives back every pixel's own statuses, whatever the base.
    #[test]
    fn own_statuses_are_recovered_from_their_difference() {
        let n = 5;
        let np = 200;
        let mut rng = crate::base::rng::Pcg32::new(7, 1);
        let base: Vec<u8> = (0..np * n).map(|_| (rng.next_u32() % 4) as u8).collect();
        let mut own = base.clone();
        for p in (0..np).filter(|p| p % 7 == 3 || p % 11 == 0) {
            own[p * n + p % n] = (own[p * n + p % n] + 1) % 4;
        }
        let (own_codes, base_codes) = (Codes2::from_codes(&own, n), Codes2::from_codes(&base, n));
        let held = OwnStatuses::of(&own_codes, &base_codes);
        assert_eq!(
            held.ids.len(),
            (0..np).filter(|p| p % 7 == 3 || p % 11 == 0).count()
        );
        let mut row = vec![0u8; n];
        for p in 0..np {
            unpack_into(held.at(p, &base_codes), &mut row);
            assert_eq!(row, &own[p * n..(p + 1) * n], "pixel {p}");
        }
        // Equal arrays: nothing held.
        assert!(OwnStatuses::of(&base_codes, &base_codes).ids.is_empty());
    }

    /// A usable set's fingerprint ignores why a light was dropped, tells the sets of 20 lights
    /// with up to three dropped apart, and is never 0 (the "none" value).
    #[test]
    fn usable_prints_follow_the_usable_sets() {
        let n = 20;
        let set = |dropped: &[usize], label: u8| -> Vec<u8> {
            let codes: Vec<u8> = (0..n)
                .map(|k| {
                    if dropped.contains(&k) {
                        label
                    } else {
                        status::USED
                    }
                })
                .collect();
            Codes2::from_codes(&codes, n).row(0).to_vec()
        };
        assert_eq!(
            usable_print(&set(&[2, 7], status::SHADOW), n),
            usable_print(&set(&[2, 7], status::HIGHLIGHT), n)
        );
        // Every set with one, two or three lights dropped: distinct prints.
        let mut dropped_sets: Vec<Vec<usize>> = Vec::new();
        for a in 0..n {
            dropped_sets.push(vec![a]);
            for b in a + 1..n {
                dropped_sets.push(vec![a, b]);
                for c in b + 1..n {
                    dropped_sets.push(vec![a, b, c]);
                }
            }
        }
        let prints: std::collections::HashSet<u32> = dropped_sets
            .iter()
            .map(|d| usable_print(&set(d, status::REJECTED), n))
            .collect();
        assert_eq!(prints.len(), dropped_sets.len());
        assert!(!prints.contains(&0) && !prints.contains(&usable_print(&set(&[], 0), n)));
    }
}
