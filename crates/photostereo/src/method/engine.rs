//! The engine: [`reconstruct`] turns a [`Capture`] in memory into a [`Reconstruction`] — normals,
//! albedo, per-light statuses, the detector's maps, depth and curl, all full frame — and a
//! [`Report`] value. It reads no file, writes none and prints nothing: the CLI's `run`
//! ([`crate::app::pipeline`]) and the Python package are thin layers over it.
//!
//! Shapes (row-major, H rows, W columns, N lights, C channels; frames as in [`crate::solve::lambert`]):
//!
//! | field | shape | outside the mask |
//! |---|---|---|
//! | `normals` | (H, W, 3) unit vectors, camera frame | (0, 0, 0) |
//! | `albedo` | (H, W, C), units of the intensity-normalised images | 0 |
//! | `light_status` | (N, H, W), values of [`status`](crate::solve::lambert::status) | 255 |
//! | `residual` | (H, W), ‖r‖ / σ_p of the χ² test with all lights | 0 |
//! | `unreliable` | (H, W), the χ² test failed | false |
//! | `depth` | (H, W), pixel units toward the camera | NaN |
//! | `curl` | (H, W), the integrability residual of eq. 10 | NaN |
//! | `trust` | (H, W), integration weight of each pixel in 0..1 | 0 |

use crate::base::codes2::Codes2;
use crate::base::error::{Error, Result};
use crate::base::progress::{check_cancelled, Progress, Silent};
use crate::geometry::integrate::{
    gradients_from_normals, surface_from_gradients, weighted_normals, IntegrationParams, Surface,
};
use crate::geometry::shadows::ShadowMaps;
use crate::method::recursive::{RecursiveDiagnostics, RecursiveParams};
use crate::method::report::{InputSummary, Report};
use crate::model::capture::Capture;
use crate::model::store::{Parked, Parking};
use crate::solve::detect::{Detection, DetectionParams};
use crate::solve::estimate::{BarskyPetrou, ColemanJain, Estimator, LeastSquares};
use crate::solve::lambert::Estimate;
use crate::solve::metrics::{evaluate, ErrorStats};
use std::str::FromStr;
use std::time::Instant;

/// The estimation methods.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    /// Least squares over all lights (Woodham).
    L2,
    /// Coleman & Jain: highlights by albedo disagreement between light subsets.
    ColemanJain,
    /// Barsky & Petrou: the eq. 5 test and one faulty light dropped (iterated for N > 4).
    BarskyPetrou,
    /// Recursive photometric stereo (Argyriou & Petrou): shadows from the reconstructed surface,
    /// highlights from what the shadows do not explain, repeated.
    Recursive,
}

impl Method {
    /// Every method, in the order tables list them.
    pub const ALL: &'static [Method] = &[
        Method::L2,
        Method::ColemanJain,
        Method::BarskyPetrou,
        Method::Recursive,
    ];

    /// The name accepted by `--method` and the Python keyword `method`.
    pub fn name(self) -> &'static str {
        match self {
            Method::L2 => "l2",
            Method::ColemanJain => "coleman-jain",
            Method::BarskyPetrou => "barsky-petrou",
            Method::Recursive => "recursive",
        }
    }

    /// Whether the method decides per pixel which lights to drop from the detector's
    /// attribution (and so needs the attribution, not only the test).
    fn attributes(self) -> bool {
        matches!(self, Method::BarskyPetrou | Method::Recursive)
    }
}

impl FromStr for Method {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        crate::base::error::parse_name(s, Method::ALL, Method::name, "method")
    }
}

/// Everything that shapes a reconstruction, and nothing else: no paths, no front-end flags.
/// Each default is defined once, here and in the parameter types it gathers; the table of
/// [`crate::method::params`] describes every field and sets and reads them by name.
#[derive(Clone, Debug)]
pub struct Params {
    /// The estimation method (default `recursive`).
    pub method: Method,
    /// The detector: noise model, χ² confidence, attribution. Shared by every method that uses
    /// it and by the maps of the others.
    pub detection: DetectionParams,
    /// The recursive method's own parameters.
    pub recursive: RecursiveParams,
    /// The integrator, slope cap and weight of unreliable pixels, for the recursive method's
    /// surfaces and the exported depth alike.
    pub integration: IntegrationParams,
    /// Run the χ² test for its maps (`residual`, `unreliable`) with methods that do not need it
    /// (default true; needs four lights or more).
    pub detect: bool,
    /// Integrate the final normals into depth and curl (default true).
    pub integrate: bool,
    /// The memory budget, bytes (default `None`: half of the memory available, see
    /// [`crate::model::memory`]). Captures whose samples do not fit as `f32` are held in tiles
    /// at the input's precision, in memory or in a spill file; the results are the same. The
    /// budget applies where a capture is built — from files by the run, from an array by
    /// [`Capture::from_stack_with`] — and [`reconstruct`] records it.
    pub memory_limit: Option<u64>,
    /// Refine the lights from the readings before estimating ([`prepare`],
    /// [`crate::solve::refine::refine_lights`]; distant lights, six or more). Default false: the
    /// lights are taken as given, and every method (`l2` included) sees the lights a user
    /// supplied. It recovers lights given a few degrees off on Lambertian renders; on the real
    /// captures measured its effect is mixed (README, "Light refinement").
    pub refine_lights: bool,
    /// Give the mask's edge pixels the occluding contour's normal where the pixels inside
    /// them say the edge is a blurred silhouette ([`crate::geometry::contour`]; orthographic
    /// cameras). Default true.
    pub occluding_contour: bool,
}

impl Default for Params {
    fn default() -> Self {
        Params {
            method: Method::Recursive,
            detection: DetectionParams::default(),
            recursive: RecursiveParams::default(),
            integration: IntegrationParams::default(),
            detect: true,
            integrate: true,
            memory_limit: None,
            refine_lights: false,
            occluding_contour: true,
        }
    }
}

/// Prepares a capture for [`reconstruct`] with `params`: with `refine_lights`, its lights
/// refined from its readings ([`crate::solve::refine::refine_capture_lights`], once per capture; the report's
/// `input.light_refinement` records it). Every front end calls it once a capture is loaded;
/// [`reconstruct`] itself takes the lights as they are. Returns whether the lights changed.
pub fn prepare(capture: &mut Capture, params: &Params) -> Result<bool> {
    if !params.refine_lights {
        return Ok(false);
    }
    let refine = crate::solve::refine::RefineParams::default();
    let changed = crate::solve::refine::refine_capture_lights(capture, &refine)?;
    if !changed && capture.light_refinement.is_none() {
        let n = capture.n_lights();
        let why = if capture.lights.near.is_some() {
            "they are near point lights (the refinement fits distant directions)".to_string()
        } else if n < 6 {
            format!("{n} lights are too few (the refinement needs six or more)")
        } else {
            format!(
                "the readings do not determine them (fewer than 100 usable pixels for a light, \
                 or a change beyond {}°)",
                refine.max_angle_deg
            )
        };
        capture.notes.push(format!(
            "the lights were not refined: {why}; they are used as given"
        ));
    }
    Ok(changed)
}

impl Params {
    /// Checks every parameter's domain; errors name the parameter ([`Error::Parameter`]).
    pub fn validate(&self) -> Result<()> {
        if self.memory_limit == Some(0) {
            return Err(Error::parameter(
                "memory_limit",
                "0: expected a size in bytes such as 4G or 500M",
            ));
        }
        self.detection.validate()?;
        self.recursive.validate()?;
        self.integration.validate()
    }

    /// The parameters as `report.json` records them: names as in the library, enum values as
    /// the front ends spell them.
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "method": self.method.name(),
            "detect": self.detect,
            "integrate": self.integrate,
            "refine_lights": self.refine_lights,
            "occluding_contour": self.occluding_contour,
            "detection": self.detection,
            "recursive": self.recursive,
            "integration": self.integration,
            "memory_limit": self.memory_limit,
        })
    }
}

/// The recursive method's maps, full frame.
#[derive(Clone, Debug)]
pub struct RecursiveMaps {
    /// Shadow maps of the last surface (attached and cast, per light).
    pub shadows: crate::geometry::shadows::ShadowMaps,
    /// (H, W): unreliable pixels no shadow explains (the highlight map H).
    pub highlight: Vec<bool>,
    /// (H, W): pixels left with fewer than three usable lights (before the fallback).
    pub fewer_than_three: Vec<bool>,
    /// (H, W): pixels whose usable lights pass the χ² test.
    pub reliable: Vec<bool>,
    /// Per-iteration figures.
    pub iterations: Vec<crate::method::recursive::IterationRecord>,
    /// (H, W) each: the fitted highlight lobes' strength and roughness, when the reflectance
    /// model fitted them ([`crate::solve::gloss`]).
    pub gloss: Option<crate::solve::gloss::GlossMaps>,
}

/// The result of [`reconstruct`]: every map full frame (shapes in the module documentation).
#[derive(Clone, Debug)]
pub struct Reconstruction {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub n_lights: usize,
    /// (H, W, 3) unit normals; (0, 0, 0) outside the mask and where undetermined.
    pub normals: Vec<[f32; 3]>,
    /// (H, W, C) albedo per channel.
    pub albedo: Vec<f32>,
    /// (H, W): the mask used.
    pub mask: Vec<bool>,
    /// (N, H, W): which lights each pixel's estimate used
    /// ([`status`](crate::solve::lambert::status)); all USED for `l2`. Held per mask pixel;
    /// [`StatusMap::plane`](crate::method::statusmap::StatusMap::plane) and
    /// [`StatusMap::to_full`](crate::method::statusmap::StatusMap::to_full) give the frame.
    pub light_status: crate::method::statusmap::StatusMap,
    /// Whether `light_status` holds the method's own decisions (false for `l2`, which uses
    /// every light, and for `coleman-jain` without detection: nothing to write).
    pub statuses_decided: bool,
    /// (H, W) ‖r‖ / σ_p with all lights, when the χ² test ran.
    pub residual: Option<Vec<f32>>,
    /// (H, W) the χ² test failed, when it ran.
    pub unreliable: Option<Vec<bool>>,
    /// (H, W) the integration weight of each pixel (see [`weighted_normals`]).
    pub trust: Vec<f32>,
    /// Depth, curl and integration figures, when integration ran.
    pub surface: Option<Surface>,
    /// The recursive method's maps.
    pub recursive: Option<RecursiveMaps>,
    /// The camera of a near-light capture or of distant lights given with `K.txt`: then
    /// `depth` is Z in mm along the optical axis and the meshes are in mm.
    pub camera: Option<crate::model::lightmodel::Camera>,
    /// (H, W) angular error in degrees against ground truth (NaN where not evaluated), when
    /// evaluated ([`Reconstruction::evaluate`]).
    pub error_map: Option<Vec<f32>>,
    /// What `report.json` holds.
    pub report: Report,
    /// The surface's maps while they wait in a parking file ([`reconstruct_to_write`]).
    waiting_surface: Option<std::sync::Arc<WaitingSurface>>,
}

/// The depth, curl and discontinuity maps of a [`Reconstruction`]'s surface, parked until
/// [`Reconstruction::unpark_surface`] reads them back bit for bit.
struct WaitingSurface {
    parking: Parking,
    depth: Parked<f32>,
    curl: Parked<f32>,
    discontinuities: Option<Parked<f32>>,
}

impl std::fmt::Debug for WaitingSurface {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "WaitingSurface({} bytes parked)", self.parking.bytes())
    }
}

impl WaitingSurface {
    /// Parks the maps of `surface` in `parking`, leaving them empty.
    fn park(mut parking: Parking, surface: &mut Surface) -> Result<WaitingSurface> {
        let depth = parking.shelve(&mut surface.depth.values)?;
        let curl = parking.shelve(&mut surface.curl)?;
        let discontinuities = match surface.depth.discontinuities.take() {
            Some(d) => Some(parking.park(d)?),
            None => None,
        };
        Ok(WaitingSurface {
            parking,
            depth,
            curl,
            discontinuities,
        })
    }
}

impl Reconstruction {
    /// Reads back the surface's maps that [`reconstruct_to_write`] left parked (nothing to do
    /// when none wait): after it, `surface` holds them as [`reconstruct`] gives them.
    pub fn unpark_surface(&mut self) -> Result<()> {
        let (Some(waiting), Some(surface)) = (self.waiting_surface.take(), self.surface.as_mut())
        else {
            return Ok(());
        };
        let w = &*waiting;
        surface.depth.values = w.parking.read(&w.depth)?;
        surface.curl = w.parking.read(&w.curl)?;
        surface.depth.discontinuities = match &w.discontinuities {
            Some(d) => Some(w.parking.read(d)?),
            None => None,
        };
        Ok(())
    }

    /// (H, W) depth in pixel units toward the camera, NaN outside the mask, when integrated.
    pub fn depth(&self) -> Option<&[f32]> {
        self.surface.as_ref().map(|s| s.depth.values.as_slice())
    }

    /// (H, W) curl of the normals' gradient field, NaN where undefined, when integrated.
    pub fn curl(&self) -> Option<&[f32]> {
        self.surface.as_ref().map(|s| s.curl.as_slice())
    }

    /// Scores the normals against a ground-truth normal map of the same size ((H, W, 3),
    /// zero where unknown), or against one ground-truth normal per mask pixel (row-major, as
    /// [`crate::solve::metrics::truth_at_pixels`] gathers them): fills `error_map` and the report's
    /// error figures.
    pub fn evaluate(&mut self, truth: &[[f32; 3]]) -> Result<ErrorStats> {
        let mask_pixels = self.mask.iter().filter(|&&m| m).count();
        if truth.len() != self.normals.len() && truth.len() != mask_pixels {
            return Err(Error::invalid(format!(
                "ground truth has {} pixels but the reconstruction {}×{} = {} ({} mask pixels)",
                truth.len(),
                self.width,
                self.height,
                self.normals.len(),
                mask_pixels
            )));
        }
        let (map, stats) = evaluate(&self.normals, truth, Some(&self.mask))?;
        self.error_map = Some(map);
        self.report.error = Some(stats.clone());
        Ok(stats)
    }
}

/// Reconstructs a capture with `params`. See [`reconstruct_with_truth`].
pub fn reconstruct(
    capture: &Capture,
    params: &Params,
    progress: &dyn Progress,
) -> Result<Reconstruction> {
    reconstruct_with_truth(capture, params, None, progress)
}

/// Reconstructs a capture: estimation by `params.method`, the χ² test's maps, integration of
/// the final normals with the same weighting rule the recursive method uses, and the report
/// (input, parameters, stage timings, method figures). `truth` (optional: full-frame normals,
/// or one per mask pixel as [`crate::solve::metrics::truth_at_pixels`] gathers them) only adds
/// per-iteration error figures to the report.
pub fn reconstruct_with_truth(
    capture: &Capture,
    params: &Params,
    truth: Option<&[[f32; 3]]>,
    progress: &dyn Progress,
) -> Result<Reconstruction> {
    reconstruct_surface_waiting(capture, params, truth, progress, false)
}

/// [`reconstruct_with_truth`] for a caller that writes the maps and releases each once
/// written, the surface last: under a plan that parks ([`crate::model::memory::MemoryPlan`]),
/// the surface's depth, curl and discontinuities stay in the parking file (its `surface` holds
/// its figures and empty maps) until [`Reconstruction::unpark_surface`], so that the run's
/// largest stage never holds them beside every other map.
pub fn reconstruct_to_write(
    capture: &Capture,
    params: &Params,
    truth: Option<&[[f32; 3]]>,
    progress: &dyn Progress,
) -> Result<Reconstruction> {
    reconstruct_surface_waiting(capture, params, truth, progress, true)
}

/// [`reconstruct_with_truth`], the surface's maps left parked when `surface_waits` and the
/// plan parks ([`reconstruct_to_write`]).
fn reconstruct_surface_waiting(
    capture: &Capture,
    params: &Params,
    truth: Option<&[[f32; 3]]>,
    progress: &dyn Progress,
    surface_waits: bool,
) -> Result<Reconstruction> {
    params.validate()?;
    let mut report = start_report(capture, params);
    let can_detect = capture.n_lights() >= 4;
    if params.detect && !can_detect {
        report
            .notes
            .push("detection skipped: it needs at least four lights".into());
    }
    let (mut estimate, detection, mut diagnostics) = match capture.lights.near.as_deref() {
        None => estimate(capture, params, truth, can_detect, progress, &mut report)?,
        Some(near) => alternate(
            capture,
            near,
            params,
            truth,
            can_detect,
            progress,
            &mut report,
        )?,
    };
    check_cancelled(progress)?;
    occluding_contour(capture, params, &mut estimate, &mut report);
    // The statuses packed (2 bits a light; the recursive method's come packed) before the
    // final integration: no byte-per-light array is held beside the integrator's work arrays.
    let recursive_status = diagnostics
        .as_mut()
        .map(|d| std::mem::take(&mut d.light_status))
        .filter(|c| c.rows() > 0);
    let statuses_decided =
        estimate.light_status.is_some() || detection.is_some() || recursive_status.is_some();
    let mut packed_status = match recursive_status {
        Some(c) => Some(c),
        None => estimate
            .light_status
            .take()
            .map(|s| Codes2::from_codes(&s, capture.n_lights())),
    };
    if let Some(d) = &detection {
        record_detection(capture, &estimate, packed_status.as_ref(), d, &mut report)?;
    }
    // The recursive method's trust map is moved out of its diagnostics, not copied.
    // The last intermediate surface is not an output: freed before the final integration.
    let trust = match diagnostics.as_mut() {
        Some(d) => {
            drop(std::mem::take(&mut d.depth));
            std::mem::take(&mut d.trust)
        }
        None => integration_trust(capture, params, None, detection.as_ref()),
    };
    // During the final integration the trust and the recursion's flag maps are held per mask
    // pixel (7 bytes a frame pixel fewer at the run's largest stage) and scattered again
    // after it.
    let trust = capture.gather_owned(trust);
    let mut flags_at_mask = diagnostics.as_mut().map(|d| {
        [&mut d.highlight, &mut d.fewer_than_three, &mut d.reliable]
            .map(|map| capture.gather_owned(std::mem::take(map)))
    });
    let t = Instant::now();
    // A tight budget: what the integration does not read waits in a file while it runs (the
    // inputs are made from the normals once the rest is parked).
    let mut parking = capture.parking()?;
    let mut detection = detection;
    let mut arrays = RunArrays {
        estimate: &mut estimate,
        status: &mut packed_status,
        detection: &mut detection,
        flags: &mut flags_at_mask,
        diagnostics: &mut diagnostics,
    };
    let make_inputs = |normals: &[[f32; 3]]| final_inputs(capture, params, normals, &trust);
    let (inputs, parked) = match parking.as_mut() {
        Some(parking) => {
            let (parked, inputs) = arrays.park(parking, make_inputs)?;
            (inputs?, Some(parked))
        }
        None => (make_inputs(&arrays.estimate.normals)?, None),
    };
    let mut surface = final_surface(capture, params, inputs, t, progress, &mut report)?;
    // The surface waits in the file (when asked) before the other arrays come back.
    let waiting_surface = match (parking, parked) {
        (Some(parking), Some(parked)) => match surface.as_mut().filter(|_| surface_waits) {
            Some(s) => {
                let waiting = WaitingSurface::park(parking, s)?;
                arrays.unpark(&waiting.parking, parked)?;
                Some(std::sync::Arc::new(waiting))
            }
            None => {
                arrays.unpark(&parking, parked)?;
                None
            }
        },
        _ => None,
    };
    // Each full-frame map replaces its per-mask-pixel values (is them, on a mask that is the
    // whole frame): freed once scattered, never held twice.
    let trust = capture.scatter_owned(trust, 1, 0.0);
    if let (Some(d), Some([highlight, few, reliable])) = (diagnostics.as_mut(), flags_at_mask) {
        d.highlight = capture.scatter_owned(highlight, 1, false);
        d.fewer_than_three = capture.scatter_owned(few, 1, false);
        d.reliable = capture.scatter_owned(reliable, 1, false);
    }
    let normals = capture.scatter_owned(std::mem::take(&mut estimate.normals), 1, [0.0; 3]);
    let albedo = capture.scatter_owned(std::mem::take(&mut estimate.albedo), capture.channels, 0.0);
    // The statuses copy the capture's mask pixel list only where the mask is not the whole
    // frame: a whole frame's list (4 bytes a pixel) is not held twice.
    let light_status = crate::method::statusmap::StatusMap::packed_at(
        capture.width,
        capture.height,
        capture.n_lights(),
        &capture.pixels,
        packed_status,
    );
    crate::method::indicators::record(capture, &light_status, statuses_decided, &mut report);
    let recursive = diagnostics.map(|d| recursive_maps(d, &mut report));
    let (residual, unreliable) = match detection {
        Some(d) => (
            Some(capture.scatter_owned(d.residual, 1, 0.0)),
            Some(capture.scatter_owned(d.unreliable, 1, false)),
        ),
        None => (None, None),
    };
    Ok(Reconstruction {
        width: capture.width,
        height: capture.height,
        channels: capture.channels,
        n_lights: capture.n_lights(),
        albedo,
        normals,
        mask: capture.mask.clone(),
        light_status,
        statuses_decided,
        residual,
        unreliable,
        trust,
        surface,
        recursive,
        camera: capture.lights.perspective().map(|(c, _)| c),
        error_map: None,
        report,
        waiting_surface,
    })
}

/// The occluding contour's normals at the mask's edge pixels, where `params` asks for them and
/// the camera is orthographic (before the final integration, which they feed), and what it
/// did in `report.json`.
fn occluding_contour(
    capture: &Capture,
    params: &Params,
    estimate: &mut crate::solve::lambert::Estimate,
    report: &mut Report,
) {
    if !params.occluding_contour || capture.lights.perspective().is_some() {
        return;
    }
    let t = Instant::now();
    let frame = crate::geometry::contour::MaskFrame {
        width: capture.width,
        height: capture.height,
        mask: &capture.mask,
        pixels: &capture.pixels,
    };
    let summary = crate::geometry::contour::apply(
        &frame,
        crate::geometry::contour::Estimates {
            normals: &mut estimate.normals,
            albedo: &estimate.albedo,
            channels: capture.channels,
        },
    );
    report.extra.insert(
        "occluding_contour".into(),
        serde_json::json!({"edge_pixels": summary.edge_pixels, "replaced": summary.replaced}),
    );
    report.time("occluding_contour", t);
}

/// The report of a reconstruction before it runs: the method, the input, the capture's notes,
/// every parameter and the memory plan.
fn start_report(capture: &Capture, params: &Params) -> Report {
    let mut report = Report::new(params.method.name());
    report.input = InputSummary::of(capture);
    report.notes.extend(capture.notes.iter().cloned());
    for (name, value) in params
        .to_json()
        .as_object()
        .into_iter()
        .flat_map(|m| m.iter())
    {
        report.param(name, value.clone());
    }
    if let Some(plan) = &capture.memory {
        report.extra.insert(
            "memory".into(),
            serde_json::to_value(plan).unwrap_or_default(),
        );
    }
    report
}

/// The report's `detection` entry: the noise model, the test's threshold and confidence, the
/// unreliable share, κ as measured on the capture, and the labels of the shadowed readings.
fn record_detection(
    capture: &Capture,
    estimate: &Estimate,
    status: Option<&Codes2>,
    d: &Detection,
    report: &mut Report,
) -> Result<()> {
    report.extra.insert(
        "detection".into(),
        serde_json::json!({
            "noise": d.noise,
            "light_kappa": d.noise.light_kappa(),
            "threshold_chi2": d.threshold,
            "confidence": d.params.confidence,
            "unreliable_share": d.unreliable_share(),
            "kappa_measured": crate::solve::tiled::measured_kappa(capture, &d.noise, &d.params)?,
            "shadow_labels": match status {
                Some(s) => Some(tiled_shadow_labels(capture, estimate, s)?),
                None => None,
            },
        }),
    );
    Ok(())
}

/// What the final integration reads: the gradients of the weighted normals and the weights
/// (orthographic), or the full-frame normals and trust (through the camera).
enum FinalInputs {
    Orthographic(crate::geometry::integrate::Gradients, Vec<f32>),
    Perspective(Vec<[f32; 3]>, Vec<f32>),
}

/// The final integration's inputs from the estimate's normals and the per-mask-pixel `trust`
/// (the same weighting rule the recursive method uses); none unless `params.integrate`.
fn final_inputs(
    capture: &Capture,
    params: &Params,
    normals: &[[f32; 3]],
    trust: &[f32],
) -> Result<Option<FinalInputs>> {
    if !params.integrate {
        return Ok(None);
    }
    let (w, h) = (capture.width, capture.height);
    if capture.lights.perspective().is_some() {
        let normals = capture.scatter(normals, 1, [0.0; 3]);
        let trust = capture.scatter(trust, 1, 0.0);
        return Ok(Some(FinalInputs::Perspective(normals, trust)));
    }
    // The output's normal map is made after the solve: during it only the gradients, the
    // weights and the integrator's arrays are held whole.
    let (weighted, weights) = crate::geometry::integrate::weighted_normals_at(
        w * h,
        &capture.pixels,
        normals,
        &|p, _| trust[p],
    );
    // The weighted copy of the normal map is dropped once its gradients are taken.
    let gradients = gradients_from_normals(
        w,
        h,
        &weighted,
        Some(&capture.mask),
        params.integration.max_slope,
    )?;
    Ok(Some(FinalInputs::Orthographic(gradients, weights)))
}

/// The final integration of [`final_inputs`]: through the camera with a perspective model,
/// orthographic otherwise; timed from `t`.
fn final_surface(
    capture: &Capture,
    params: &Params,
    inputs: Option<FinalInputs>,
    t: Instant,
    progress: &dyn Progress,
    report: &mut Report,
) -> Result<Option<Surface>> {
    let surface = match inputs {
        None => return Ok(None),
        Some(FinalInputs::Perspective(normals, trust)) => {
            near_integration(capture, params, &normals, &trust, progress)?
        }
        Some(FinalInputs::Orthographic(gradients, weights)) => surface_from_gradients(
            gradients,
            Some(&weights),
            params.integration.method.integrator().as_ref(),
            params.integration.max_slope,
            progress,
        )?,
    };
    report.extra.insert("integration".into(), surface.summary());
    report.time("integrate", t);
    Ok(Some(surface))
}

/// The per-pixel arrays of a run beside its final integration, which it does not read.
struct RunArrays<'a> {
    estimate: &'a mut Estimate,
    status: &'a mut Option<crate::base::codes2::Codes2>,
    detection: &'a mut Option<Detection>,
    flags: &'a mut Option<[Vec<bool>; 3]>,
    diagnostics: &'a mut Option<RecursiveDiagnostics>,
}

/// Where [`RunArrays::park`] put each array.
struct ParkedRun {
    normals: Parked<[f32; 3]>,
    albedo: Parked<f32>,
    status: Option<(usize, Parked<u8>)>,
    detection: Option<[Parked<f32>; 1]>,
    verdicts: Option<[Parked<bool>; 2]>,
    flags: Option<[Parked<bool>; 3]>,
    shadows: Option<([usize; 3], [Parked<u64>; 2])>,
}

impl RunArrays<'_> {
    /// Moves the arrays into `parking` (the run's results are unchanged: they are read back
    /// bit for bit by [`RunArrays::unpark`]).
    ///
    /// The normals go last: `made` is given them once the rest is parked (the final
    /// integration's inputs are not made beside the other arrays) and its result is returned.
    fn park<T>(
        &mut self,
        parking: &mut Parking,
        made: impl FnOnce(&[[f32; 3]]) -> T,
    ) -> Result<(ParkedRun, T)> {
        let albedo = parking.shelve(&mut self.estimate.albedo)?;
        let status = match self.status.take() {
            Some(c) => Some((c.width(), parking.park(c.into_bytes())?)),
            None => None,
        };
        let (detection, verdicts) = match self.detection.as_mut() {
            Some(d) => (
                Some([parking.shelve(&mut d.residual)?]),
                Some([
                    parking.shelve(&mut d.unreliable)?,
                    parking.shelve(&mut d.settled)?,
                ]),
            ),
            None => (None, None),
        };
        let flags = match self.flags.as_mut() {
            Some([a, b, c]) => Some([parking.shelve(a)?, parking.shelve(b)?, parking.shelve(c)?]),
            None => None,
        };
        let shadows = match self.diagnostics.as_mut() {
            Some(d) => {
                let maps = std::mem::replace(&mut d.shadows, ShadowMaps::empty(0, 0, 0));
                let size = [maps.width, maps.height, maps.lights];
                let [a, c] = maps.into_planes();
                Some((size, [parking.park(a)?, parking.park(c)?]))
            }
            None => None,
        };
        let result = made(&self.estimate.normals);
        let normals = parking.shelve(&mut self.estimate.normals)?;
        let parked = ParkedRun {
            normals,
            albedo,
            status,
            detection,
            verdicts,
            flags,
            shadows,
        };
        Ok((parked, result))
    }

    /// Reads back what [`RunArrays::park`] parked.
    fn unpark(&mut self, parking: &Parking, p: ParkedRun) -> Result<()> {
        parking.unshelve(&mut self.estimate.normals, p.normals)?;
        parking.unshelve(&mut self.estimate.albedo, p.albedo)?;
        if let Some((width, bytes)) = p.status {
            *self.status = Some(Codes2::from_bytes(width, parking.take(bytes)?));
        }
        if let (Some(d), Some([residual]), Some([unreliable, settled])) =
            (self.detection.as_mut(), p.detection, p.verdicts)
        {
            parking.unshelve(&mut d.residual, residual)?;
            parking.unshelve(&mut d.unreliable, unreliable)?;
            parking.unshelve(&mut d.settled, settled)?;
        }
        if let (Some([a, b, c]), Some([pa, pb, pc])) = (self.flags.as_mut(), p.flags) {
            parking.unshelve(a, pa)?;
            parking.unshelve(b, pb)?;
            parking.unshelve(c, pc)?;
        }
        if let (Some(d), Some(([w, h, n], [a, c]))) = (self.diagnostics.as_mut(), p.shadows) {
            let planes = [parking.take(a)?, parking.take(c)?];
            d.shadows = ShadowMaps::from_planes(w, h, n, planes);
        }
        Ok(())
    }
}

/// The recursive method's maps for the reconstruction, its figures into the report.
fn recursive_maps(d: RecursiveDiagnostics, report: &mut Report) -> RecursiveMaps {
    let few = d.fewer_than_three.iter().filter(|&&f| f).count();
    report.extra.insert(
        "recursive".into(),
        serde_json::json!({
            "iterations": d.iterations,
            "fewer_than_three_pixels": few,
            "fallback": d.fallback,
            "converged": d.converged,
            "final_change": d.final_change,
            "stop_reason": d.stop_reason,
            "surface_prior": d.surface_prior,
        }),
    );
    if let Some((summary, _)) = &d.gloss {
        report
            .extra
            .insert("reflectance".into(), serde_json::json!(summary));
    }
    if !d.converged {
        report.notes.push(format!("recursive: {}", d.stop_reason));
    }
    report
        .extra
        .insert("fewer_than_three_pixels".into(), few.into());
    RecursiveMaps {
        shadows: d.shadows,
        highlight: d.highlight,
        fewer_than_three: d.fewer_than_three,
        reliable: d.reliable,
        iterations: d.iterations,
        gloss: d.gloss.map(|(_, maps)| maps),
    }
}

/// Integration trust: the recursive method's own; unreliable pixels low for the methods that
/// keep faulty lights; 1 for Barsky & Petrou, which drops them itself. Full frame.
fn integration_trust(
    capture: &Capture,
    params: &Params,
    diagnostics: Option<&RecursiveDiagnostics>,
    detection: Option<&Detection>,
) -> Vec<f32> {
    let low = params.integration.unreliable_weight;
    match (diagnostics, detection) {
        (Some(r), _) => r.trust.clone(),
        (None, Some(d)) if params.method != Method::BarskyPetrou => capture.scatter(
            &d.unreliable
                .iter()
                .map(|&u| if u { low } else { 1.0 })
                .collect::<Vec<f32>>(),
            1,
            0.0,
        ),
        _ => capture.scatter(&vec![1f32; capture.n_pixels()], 1, 0.0),
    }
}

/// Perspective integration of full-frame normals with the capture's camera (the near model's,
/// or the one given for distant lights): Z in mm along the optical axis, mean over the mask =
/// the mean distance.
fn near_integration(
    capture: &Capture,
    params: &Params,
    normals: &[[f32; 3]],
    trust: &[f32],
    progress: &dyn Progress,
) -> Result<Surface> {
    let (camera, distance) = capture
        .lights
        .perspective()
        .ok_or_else(|| Error::invalid("perspective integration needs a camera"))?;
    let (weighted, weights) = weighted_normals(normals, &capture.mask, Some(trust));
    crate::geometry::integrate::perspective::perspective_surface(
        capture.width,
        capture.height,
        &weighted,
        Some(&capture.mask),
        Some(&weights),
        &camera,
        distance,
        params.integration.method.integrator().as_ref(),
        params.integration.max_slope,
        progress,
    )
}

/// One round's highlight modelling of the recursive method with near lights
/// ([`crate::solve::near_lobe`]): the lobe fitted at the pixels whose diffuse fit fails (they
/// are then trusted in the integration), and at the pixels left without a spare light the
/// capture's lobe taken out (`capture_lobe`, set when the recursion has diagnostics). `result`
/// is the round's estimate, detection and diagnostics; the detection must be there.
fn model_highlights(
    capture: &Capture,
    near: &crate::model::lightmodel::NearLights,
    params: &Params,
    result: &mut (Estimate, Option<Detection>, Option<RecursiveDiagnostics>),
    lobe_memory: &mut crate::solve::near_lobe::LobeMemory,
    capture_lobe: &mut Option<crate::solve::near_lobe::SpareSummary>,
) -> Result<crate::solve::near_lobe::LobeSummary> {
    let d = result.1.as_ref().expect("a detection");
    let (summary, refined) = crate::solve::near_lobe::refine(
        capture,
        near,
        &mut result.0,
        &d.noise,
        d.params.confidence,
        lobe_memory,
    )?;
    if let Some(diag) = result.2.as_mut() {
        for (p, &i) in capture.pixels.iter().enumerate() {
            if refined[p] {
                diag.trust[i as usize] = 1.0;
            }
        }
    }
    // Pixels left without a spare light: the capture's lobe taken out.
    if let Some(diag) = result.2.as_ref() {
        let reliable: Vec<bool> = capture
            .pixels
            .iter()
            .map(|&i| diag.reliable[i as usize])
            .collect();
        let surface = |est: &Estimate| -> Result<Vec<[f32; 3]>> {
            let normals = capture.scatter(&est.normals, 1, [0.0; 3]);
            let s = near_integration(capture, params, &normals, &diag.trust, &Silent)?;
            Ok(crate::geometry::integrate::perspective::normals_from_z(
                capture.width,
                capture.height,
                &s.depth.values,
                &capture.mask,
                &near.camera,
            ))
        };
        *capture_lobe = crate::solve::near_lobe::correct_without_spare(
            capture,
            near,
            &mut result.0,
            &reliable,
            &refined,
            surface,
        )?;
    }
    Ok(summary)
}

/// The mean absolute change of the depth `z` from `previous` over the mask pixels where `z` is
/// finite (mm).
fn mean_abs_change(capture: &Capture, z: &[f32], previous: &[f32]) -> f64 {
    let (sum, count) = capture
        .pixels
        .iter()
        .map(|&i| i as usize)
        .filter(|&i| z[i].is_finite())
        .fold((0f64, 0usize), |(s, c), i| {
            (s + (z[i] as f64 - previous[i] as f64).abs(), c + 1)
        });
    sum / count.max(1) as f64
}

/// The near-light alternation (ALGORITHMS.md §9): from the plane Z = D, estimate with each
/// pixel's light vectors, integrate through the camera, update X, and repeat until the mean
/// |ΔZ| of a round falls below [`crate::model::lightmodel::DEPTH_TOLERANCE`] of D or
/// [`crate::model::lightmodel::MAX_ROUNDS`] rounds. Records the rounds under `near` in the report.
#[allow(clippy::too_many_arguments)]
fn alternate(
    capture: &Capture,
    near: &crate::model::lightmodel::NearLights,
    params: &Params,
    truth: Option<&[[f32; 3]]>,
    can_detect: bool,
    progress: &dyn Progress,
    report: &mut Report,
) -> Result<(Estimate, Option<Detection>, Option<RecursiveDiagnostics>)> {
    use crate::model::lightmodel::{DEPTH_TOLERANCE, MAX_ROUNDS};
    near.reset_surface();
    let d = near.mean_distance;
    let mut previous = vec![d as f32; capture.width * capture.height];
    let mut rounds = Vec::new();
    let mut converged = false;
    let mut last = None;
    let method = params.method;
    let mut lobe = None;
    let mut lobe_memory = crate::solve::near_lobe::LobeMemory::default();
    let mut capture_lobe = None;
    for round in 1..=MAX_ROUNDS {
        let t = Instant::now();
        let mut result = estimate(capture, params, truth, can_detect, progress, report)?;
        // The recursive method's highlights, modelled where no light is free of them.
        if method == Method::Recursive && result.1.is_some() {
            let t = Instant::now();
            let summary = model_highlights(
                capture,
                near,
                params,
                &mut result,
                &mut lobe_memory,
                &mut capture_lobe,
            )?;
            report.time("highlight_lobe", t);
            lobe = Some(summary);
        }
        let normals = capture.scatter(&result.0.normals, 1, [0.0; 3]);
        let trust = integration_trust(capture, params, result.2.as_ref(), result.1.as_ref());
        let surface = near_integration(
            capture,
            params,
            &normals,
            &trust,
            &crate::base::progress::Silent,
        )?;
        let z = &surface.depth.values;
        let change = mean_abs_change(capture, z, &previous);
        near.set_surface(z);
        previous.clone_from(z);
        let error = match truth {
            Some(t) => Some(
                crate::solve::metrics::evaluate(&normals, t, Some(&capture.mask))?
                    .1
                    .mean_deg,
            ),
            None => None,
        };
        rounds.push(serde_json::json!({
            "round": round,
            "mean_abs_depth_change_mm": change,
            "mean_error_deg": error,
            "seconds": t.elapsed().as_secs_f64(),
        }));
        last = Some(result);
        if change < DEPTH_TOLERANCE * d {
            converged = true;
            break;
        }
    }
    let cam = near.camera;
    report.extra.insert(
        "near".into(),
        serde_json::json!({
            "model": "near point lights, perspective camera",
            "mean_distance_mm": d,
            "camera": {"fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy},
            "rounds": rounds,
            "converged": converged,
            "tolerance_mm": DEPTH_TOLERANCE * d,
            "highlight_lobe": lobe,
            "capture_lobe": capture_lobe,
        }),
    );
    if !converged {
        report.notes.push(format!(
            "near lights: the depth still changed by more than {:.3} mm after {MAX_ROUNDS} rounds",
            DEPTH_TOLERANCE * d
        ));
    }
    Ok(last.expect("at least one round"))
}

/// The method's estimate, the χ² test's results (when it ran) and the recursive method's
/// diagnostics; records the `estimate` and `detect` timings.
fn estimate(
    capture: &Capture,
    params: &Params,
    truth: Option<&[[f32; 3]]>,
    can_detect: bool,
    progress: &dyn Progress,
    report: &mut Report,
) -> Result<(Estimate, Option<Detection>, Option<RecursiveDiagnostics>)> {
    let method = params.method;
    // The detector runs first for the methods built on it (with attribution) and for the maps
    // of the others (the test only, O(N) per pixel).
    let detection = if method == Method::Recursive {
        None
    } else if method.attributes() || (params.detect && can_detect) {
        let t = Instant::now();
        let detection_params = DetectionParams {
            attribute: method.attributes(),
            ..params.detection.clone()
        };
        let d = crate::solve::tiled::detect_tiles(capture, &detection_params, progress)?;
        report.time("detect", t);
        check_cancelled(progress)?;
        Some(d)
    } else {
        None
    };
    let t = Instant::now();
    let result = match method {
        Method::L2 if capture.is_tiled() => (
            crate::solve::tiled::solve_tiles(capture, None, progress)?,
            detection,
            None,
        ),
        Method::L2 => (LeastSquares.estimate(capture, progress)?, detection, None),
        Method::ColemanJain => {
            let cj = ColemanJain {
                params: params.detection.clone(),
                ..ColemanJain::default()
            };
            if capture.is_tiled() && capture.n_lights() >= 4 {
                let (noise, threshold) =
                    cj.calibration(&*crate::solve::tiled::statistics_view(capture)?, progress)?;
                let est = crate::solve::tiled::estimate_tiles(capture, progress, |_, tile| {
                    cj.estimate_calibrated(tile, &noise, threshold, &Silent)
                })?;
                (est, detection, None)
            } else {
                (cj.estimate(capture, progress)?, detection, None)
            }
        }
        Method::BarskyPetrou => {
            let d = detection.ok_or_else(|| {
                Error::invalid("barsky-petrou needs the detector, which needs four lights")
            })?;
            let est = if capture.is_tiled() {
                let mut est =
                    crate::solve::tiled::solve_tiles(capture, Some(&d.usable()), progress)?;
                if !d.noise.light_factor.is_empty() && capture.lights.near.is_none() {
                    // The lights' noise factors weight the fit, as in memory.
                    let ids: Vec<usize> = (0..capture.n_pixels()).collect();
                    let f = &d.noise.light_factor;
                    capture.for_ids_by_tile(&ids, |sub, view| {
                        crate::solve::lambert::resolve_subsets_at(
                            view,
                            &d.light_status,
                            sub,
                            &mut est,
                            f,
                        );
                        Ok(())
                    })?;
                }
                est.light_status = Some(d.light_status.clone());
                est
            } else {
                BarskyPetrou::from_detection(capture, &d, progress)
            };
            (est, Some(d), None)
        }
        Method::Recursive => {
            // Called with the caller's truth: no copy of it (12 bytes a frame pixel).
            let r = crate::method::recursive::recursive(
                capture,
                &params.recursive,
                &params.detection,
                &params.integration,
                truth,
                progress,
                &mut |_| {},
            )?;
            report
                .timings_s
                .insert("detect".into(), r.detect_seconds.into());
            let tested = (capture.n_lights() >= 4).then_some(r.detection);
            let (mut estimate, mut diagnostics) = (r.estimate, r.diagnostics);
            if capture.lights.near.is_some() {
                // The near model's lobe refinement reads and rewrites the estimate's statuses.
                estimate.light_status =
                    Some(std::mem::take(&mut diagnostics.light_status).unpack());
            }
            (estimate, tested, Some(diagnostics))
        }
    };
    report.time("estimate", t);
    Ok(result)
}

/// [`crate::solve::lambert::shadow_labels`] summed over the tiles.
fn tiled_shadow_labels(
    capture: &Capture,
    est: &Estimate,
    light_status: &Codes2,
) -> Result<crate::solve::lambert::ShadowLabels> {
    if !capture.is_tiled() {
        return Ok(crate::solve::lambert::shadow_labels(
            capture,
            est,
            &light_status.unpack(),
        ));
    }
    let (n, c) = (capture.n_lights(), capture.channels);
    let mut counts = (0usize, 0usize, 0usize);
    capture.for_each_tile(|off, tile| {
        let np = tile.n_pixels();
        let part = Estimate {
            normals: est.normals[off..off + np].to_vec(),
            albedo: est.albedo[off * c..(off + np) * c].to_vec(),
            light_status: None,
        };
        let (a, b, d) = crate::solve::lambert::shadow_label_counts(
            tile,
            &part,
            &light_status.unpack_rows(off..off + np),
        );
        counts = (counts.0 + a, counts.1 + b, counts.2 + d);
        Ok(())
    })?;
    Ok(crate::solve::lambert::ShadowLabels::from_counts(
        counts,
        n,
        capture.n_pixels(),
    ))
}
