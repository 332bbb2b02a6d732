//! `photostereo._native`: the Python package's native module, a thin layer over the photostereo
//! library like the command line. It converts numpy arrays and Python values to the library's
//! types and back, releases the GIL while the library works, polls for Ctrl-C, and turns every
//! library error into `PhotostereoError` with the library's message. No numerics live here.
//!
//! The public, documented API is the pure-Python package `photostereo` (python/photostereo),
//! which wraps these functions into typed signatures with the library's defaults.

use ndarray::{Array2, Array3, Array4, ArrayView2, ArrayView3, Axis};
use numpy::{IntoPyArray, PyReadonlyArray2, PyReadonlyArray3, PyReadonlyArray4};
use photostereo::app::pipeline::{LightSubset, RunOptions};
use photostereo::base::progress::Progress;
use photostereo::io::layouts::CaptureFiles;
use photostereo::io::synth::near_synth_to_folder;
use photostereo::io::synth::synth_to_folder;
use photostereo::method::engine::{Method, Params, Reconstruction};
use photostereo::method::recursive::Fallback;
use photostereo::model::capture::{Capture, Stack};
use photostereo::model::image::Image;
use photostereo::model::lightmodel::Camera;
use photostereo::model::lights::Lights;
use photostereo::scene::near::{synthesize_near, NearRig, NearSpec};
use photostereo::scene::{Brdf, SceneKind, SynthSpec};
use photostereo::solve::detect::NoiseEstimate;
use pyo3::create_exception;
use pyo3::exceptions::{PyKeyboardInterrupt, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{mpsc, Arc, Mutex};
use std::time::Duration;

create_exception!(
    _native,
    PhotostereoError,
    PyValueError,
    "Bad input to photostereo: the message names the file, line or parameter at fault and what was expected."
);

/// The library's error as `PhotostereoError`, parameters spelt as Python keywords.
fn py_err(e: photostereo::Error) -> PyErr {
    match e {
        photostereo::Error::Cancelled => PyKeyboardInterrupt::new_err("cancelled"),
        other => PhotostereoError::new_err(python_spelling(&other.to_string())),
    }
}

/// The command line's flags that the library's messages name, as the Python keywords that
/// replace them.
const PYTHON_KEYWORDS: &[(&str, &str)] = &[
    ("--distance", "distance="),
    (
        "pass --force to replace it",
        "pass force=True to replace it",
    ),
    ("--lights FILE", "lights="),
    ("pass --lights", "pass lights="),
];

/// `message` with each command-line flag of [`PYTHON_KEYWORDS`] spelt as its Python keyword
/// (the library's file errors say what a command-line user passes: a missing
/// `mean_distance.txt` asks for `--distance`, which in Python is `distance=`).
fn python_spelling(message: &str) -> String {
    PYTHON_KEYWORDS
        .iter()
        .fold(message.to_string(), |m, (flag, keyword)| {
            m.replace(flag, keyword)
        })
}

fn bad(message: impl Into<String>) -> PyErr {
    PhotostereoError::new_err(message.into())
}

// ---------------------------------------------------------------------------------------------
// Running library work off the GIL, with progress and Ctrl-C.

/// Progress shared between the worker thread (which advances it) and the calling thread (which
/// reports it to the Python callback and raises the cancel flag on Ctrl-C).
#[derive(Default)]
struct SharedProgress {
    stage: Mutex<String>,
    total: AtomicU64,
    done: AtomicU64,
    cancel: AtomicBool,
}

impl Progress for SharedProgress {
    fn begin(&self, stage: &str, total: u64) {
        if let Ok(mut s) = self.stage.lock() {
            *s = stage.to_string();
        }
        self.done.store(0, Ordering::Relaxed);
        self.total.store(total, Ordering::Relaxed);
    }
    fn advance(&self, units: u64) {
        self.done.fetch_add(units, Ordering::Relaxed);
    }
    fn cancelled(&self) -> bool {
        self.cancel.load(Ordering::Relaxed)
    }
}

/// Runs `work` on a worker thread (in a rayon pool of `num_threads` when given) with the GIL
/// released. The calling thread wakes every 50 ms: it checks for signals (Ctrl-C raises
/// KeyboardInterrupt at once and asks the library to stop at its next stage boundary) and
/// calls `progress(stage, done, total)` when the figures changed.
fn run_detached<T: Send + 'static>(
    py: Python<'_>,
    num_threads: Option<usize>,
    progress: Option<Py<PyAny>>,
    work: impl FnOnce(&dyn Progress) -> photostereo::Result<T> + Send + 'static,
) -> PyResult<T> {
    if num_threads == Some(0) {
        return Err(bad(
            "num_threads 0: expected at least one thread (or None for all cores)",
        ));
    }
    let pool = match num_threads {
        Some(n) => Some(
            rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .map_err(|e| bad(format!("num_threads {n}: {e}")))?,
        ),
        None => None,
    };
    let shared = Arc::new(SharedProgress::default());
    let (tx, rx) = mpsc::channel();
    // Receivers are not Sync; the mutex makes the detached closure Send (it is never contended).
    let rx = Mutex::new(rx);
    let worker_progress = Arc::clone(&shared);
    // The work runs on a pool thread, not a fresh one: the allocator's per-thread arenas of the
    // pool are reused from call to call instead of growing one more for every call.
    let job = move || {
        let p: &dyn Progress = worker_progress.as_ref();
        let result = work(p);
        release_free_memory();
        let _ = tx.send(result);
    };
    match pool {
        Some(pool) => pool.spawn(job),
        None => rayon::spawn(job),
    }
    let mut last = (String::new(), u64::MAX, u64::MAX);
    loop {
        let received = py.detach(|| match rx.lock() {
            Ok(r) => r.recv_timeout(Duration::from_millis(50)),
            Err(_) => Err(mpsc::RecvTimeoutError::Disconnected),
        });
        match received {
            Ok(result) => return result.map_err(py_err),
            Err(mpsc::RecvTimeoutError::Disconnected) => {
                return Err(bad("the worker thread ended without a result"))
            }
            Err(mpsc::RecvTimeoutError::Timeout) => {}
        }
        if let Err(e) = py.check_signals() {
            shared.cancel.store(true, Ordering::Relaxed);
            return Err(e);
        }
        if let Some(cb) = &progress {
            let stage = shared.stage.lock().map(|s| s.clone()).unwrap_or_default();
            let now = (
                stage,
                shared.done.load(Ordering::Relaxed),
                shared.total.load(Ordering::Relaxed),
            );
            if now != last && !now.0.is_empty() {
                if let Err(e) = cb.call1(py, (now.0.as_str(), now.1, now.2)) {
                    shared.cancel.store(true, Ordering::Relaxed);
                    return Err(e);
                }
                last = now;
            }
        }
    }
}

/// Hands the allocator's free memory back to the system after a job. With glibc, memory freed
/// on a pool thread stays in that thread's arena, where the next call (often on another pool
/// thread) cannot reuse it: a reconstruction after a `load_capture` then peaked about 60 MB
/// higher on DiLiGenT cat than the same work in the command line.
fn release_free_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only returns free pages of the allocator's arenas to the system.
    unsafe {
        libc::malloc_trim(0);
    }
}

// ---------------------------------------------------------------------------------------------
// Parameters.

/// `Params` from a dict of keyword arguments (every key the Python signature has).
fn params_from(dict: &Bound<'_, PyDict>) -> PyResult<Params> {
    let mut p = Params::default();
    for (key, value) in dict.iter() {
        let key: String = key.extract()?;
        let name = key.as_str();
        let f64_of = |v: &Bound<'_, PyAny>| -> PyResult<f64> {
            v.extract::<f64>()
                .map_err(|_| bad(format!("{name}: expected a number, got {}", type_name(v))))
        };
        let usize_of = |v: &Bound<'_, PyAny>| -> PyResult<usize> {
            v.extract::<usize>().map_err(|_| {
                bad(format!(
                    "{name}: expected a non-negative integer, got {}",
                    repr(v)
                ))
            })
        };
        let bool_of = |v: &Bound<'_, PyAny>| -> PyResult<bool> {
            v.extract::<bool>()
                .map_err(|_| bad(format!("{name}: expected True or False, got {}", repr(v))))
        };
        let str_of = |v: &Bound<'_, PyAny>| -> PyResult<String> {
            v.extract::<String>()
                .map_err(|_| bad(format!("{name}: expected a string, got {}", type_name(v))))
        };
        let v = &value;
        match name {
            "method" => p.method = str_of(v)?.parse().map_err(py_err)?,
            "sigma" => p.detection.sigma = optional(v, f64_of)?,
            "relative_noise" => p.detection.relative_noise = optional(v, f64_of)?,
            "confidence" => p.detection.confidence = f64_of(v)?,
            "min_kept_share" => p.detection.min_kept_share = f64_of(v)?,
            "batch_alpha" => p.detection.batch_alpha = f64_of(v)?,
            "shadow_sigmas" => p.detection.shadow_sigmas = f64_of(v)?,
            "shadow_ratio" => p.detection.shadow_ratio = f64_of(v)?,
            "noise_estimate" => {
                p.detection.noise_estimate = match str_of(v)?.as_str() {
                    "images" => NoiseEstimate::Images,
                    "residuals" => NoiseEstimate::Residuals,
                    other => {
                        return Err(bad(format!(
                            "noise_estimate '{other}': expected 'images' or 'residuals'"
                        )))
                    }
                }
            }
            "noise_refinements" => p.detection.noise_refinements = usize_of(v)?,
            "max_iterations" => p.recursive.max_iterations = usize_of(v)?,
            "change_tolerance" => p.recursive.change_tolerance = f64_of(v)?,
            "surface_prior" => p.recursive.surface_prior_deg = f64_of(v)?,
            "refine_lights" => p.refine_lights = bool_of(v)?,
            "fallback" => p.recursive.fallback = str_of(v)?.parse::<Fallback>().map_err(py_err)?,
            "integrator" => p.integration.method = str_of(v)?.parse().map_err(py_err)?,
            "max_slope" => p.integration.max_slope = f64_of(v)? as f32,
            "unreliable_weight" => p.integration.unreliable_weight = f64_of(v)? as f32,
            "detect" => p.detect = bool_of(v)?,
            "integrate" => p.integrate = bool_of(v)?,
            "memory_limit" => {
                p.memory_limit = optional(v, |x| {
                    if let Ok(b) = x.extract::<u64>() {
                        return Ok(b);
                    }
                    let s = str_of(x)?;
                    photostereo::base::machine::parse_bytes(&s).ok_or_else(|| {
                        bad(format!(
                            "memory_limit '{s}': expected bytes or a size such as '4G' or '500M'"
                        ))
                    })
                })?
            }
            other => return Err(bad(format!("unknown parameter '{other}'"))),
        }
    }
    p.validate().map_err(py_err)?;
    Ok(p)
}

fn optional<T>(
    v: &Bound<'_, PyAny>,
    f: impl Fn(&Bound<'_, PyAny>) -> PyResult<T>,
) -> PyResult<Option<T>> {
    if v.is_none() {
        Ok(None)
    } else {
        f(v).map(Some)
    }
}

fn type_name(v: &Bound<'_, PyAny>) -> String {
    v.get_type()
        .name()
        .map(|n| n.to_string())
        .unwrap_or_else(|_| "?".into())
}

fn repr(v: &Bound<'_, PyAny>) -> String {
    v.repr()
        .map(|r| r.to_string())
        .unwrap_or_else(|_| "?".into())
}

/// The library's defaults, keyed as the Python keywords.
#[pyfunction]
fn defaults(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    let p = Params::default();
    let d = PyDict::new(py);
    d.set_item("method", p.method.name())?;
    d.set_item("sigma", p.detection.sigma)?;
    // None: measured on the capture (the default).
    d.set_item("relative_noise", p.detection.relative_noise)?;
    d.set_item("confidence", p.detection.confidence)?;
    d.set_item("min_kept_share", p.detection.min_kept_share)?;
    d.set_item("batch_alpha", p.detection.batch_alpha)?;
    d.set_item("shadow_sigmas", p.detection.shadow_sigmas)?;
    d.set_item("shadow_ratio", p.detection.shadow_ratio)?;
    d.set_item(
        "noise_estimate",
        match p.detection.noise_estimate {
            NoiseEstimate::Images => "images",
            NoiseEstimate::Residuals => "residuals",
        },
    )?;
    d.set_item("noise_refinements", p.detection.noise_refinements)?;
    d.set_item("max_iterations", p.recursive.max_iterations)?;
    d.set_item("change_tolerance", p.recursive.change_tolerance)?;
    d.set_item("surface_prior", p.recursive.surface_prior_deg)?;
    d.set_item("refine_lights", p.refine_lights)?;
    d.set_item("fallback", p.recursive.fallback.name())?;
    d.set_item("integrator", p.integration.method.name())?;
    d.set_item(
        "max_slope",
        photostereo::base::number::f32_as_given(p.integration.max_slope),
    )?;
    d.set_item(
        "unreliable_weight",
        photostereo::base::number::f32_as_given(p.integration.unreliable_weight),
    )?;
    d.set_item("detect", p.detect)?;
    d.set_item("integrate", p.integrate)?;
    d.set_item("memory_limit", p.memory_limit)?;
    Ok(d)
}

// ---------------------------------------------------------------------------------------------
// Captures.

/// A capture held by the library: the mask pixels' intensity-normalised samples, the lights
/// and the mask. Shared, never copied, by `reconstruct`.
#[pyclass(frozen, module = "photostereo._native")]
struct NativeCapture {
    inner: Arc<Capture>,
}

#[pymethods]
impl NativeCapture {
    #[getter]
    fn width(&self) -> usize {
        self.inner.width
    }
    #[getter]
    fn height(&self) -> usize {
        self.inner.height
    }
    #[getter]
    fn channels(&self) -> usize {
        self.inner.channels
    }
    #[getter]
    fn n_lights(&self) -> usize {
        self.inner.n_lights()
    }
    #[getter]
    fn bit_depth(&self) -> u8 {
        self.inner.bit_depth
    }
    #[getter]
    fn notes(&self) -> Vec<String> {
        self.inner.notes.clone()
    }
    #[getter]
    fn sources(&self) -> Vec<String> {
        self.inner
            .sources
            .iter()
            .map(|p| p.display().to_string())
            .collect()
    }
    /// (N, 3) unit light directions, float64.
    fn lights<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray2<f64>> {
        let d = &self.inner.lights.directions;
        Array2::from_shape_fn((d.len(), 3), |(k, j)| d[k][j]).into_pyarray(py)
    }
    /// (N, C) light intensities, float64.
    fn intensities<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray2<f64>> {
        let c = self.inner.channels;
        let e = &self.inner.lights.intensities;
        Array2::from_shape_fn((e.len(), c), |(k, j)| {
            if c == 1 {
                (e[k][0] + e[k][1] + e[k][2]) / 3.0
            } else {
                e[k][j]
            }
        })
        .into_pyarray(py)
    }
    /// (H, W) bool.
    fn mask<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, numpy::PyArray2<bool>>> {
        let c = &self.inner;
        Ok(Array2::from_shape_vec((c.height, c.width), c.mask.clone())
            .map_err(|e| bad(e.to_string()))?
            .into_pyarray(py))
    }
    /// (N, H, W, C) float32: the images as read (full scale 1), zero outside the mask.
    fn images<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray4<f32>> {
        let c = &self.inner;
        let (n, ch, w) = (c.n_lights(), c.channels, c.width);
        let mut out = Array4::<f32>::zeros((n, c.height, w, ch));
        // Tile by tile when the capture was loaded in tiles (one tile otherwise).
        let _ = c.for_each_tile(|_, tile| {
            for (p, &i) in tile.pixels.iter().enumerate() {
                let (row, col) = (i as usize / w, i as usize % w);
                let s = tile.pixel_samples(p);
                for k in 0..n {
                    let e = c.lights.intensities[k];
                    let mean = ((e[0] + e[1] + e[2]) / 3.0) as f32;
                    for j in 0..ch {
                        let scale = if ch == 1 { mean } else { e[j] as f32 };
                        out[[k, row, col, j]] = s[k * ch + j] * scale;
                    }
                }
            }
            Ok(())
        });
        out.into_pyarray(py)
    }
}

/// The input arguments of `load_capture` and `run`, as the command line takes them, with the
/// near-light keywords `distance` (replaces `mean_distance.txt`, as `--distance`) and `camera`
/// (replaces `K.txt`, or gives distant lights a camera).
struct InputFiles {
    inputs: Vec<PathBuf>,
    lights: Option<PathBuf>,
    intensities: Option<PathBuf>,
    mask: Option<PathBuf>,
    distance: Option<f64>,
    camera: Option<Camera>,
}

impl InputFiles {
    fn resolve(&self) -> photostereo::Result<CaptureFiles> {
        use photostereo::io::layouts::near::is_near_layout;
        use photostereo::io::layouts::near::{attach_camera_with, near_capture_files_with};
        if self.distance.is_none() && self.camera.is_none() {
            return CaptureFiles::from_inputs(
                &self.inputs,
                self.lights.as_deref(),
                self.intensities.as_deref(),
                self.mask.as_deref(),
            );
        }
        let dir = match self.inputs.as_slice() {
            [dir] if dir.is_dir() => dir,
            _ => {
                return Err(photostereo::Error::parameter(
                    "distance",
                    "distance= and camera= apply to one capture folder (near lights: light_positions.txt; distant lights: light_directions.txt)",
                ))
            }
        };
        let mut files = if is_near_layout(dir) {
            near_capture_files_with(dir, self.distance, self.camera)?
        } else {
            let mut f = CaptureFiles::diligent_with_lights(dir, self.lights.as_deref())?;
            if let Some(p) = &self.intensities {
                f = f.with_intensities_file(p)?;
            }
            attach_camera_with(f, dir, self.distance, self.camera)?
        };
        if let Some(m) = &self.mask {
            files.mask = Some(m.clone());
        }
        Ok(files)
    }
}

/// A camera from a K.txt path or a 3×3 array of intrinsics (pixels).
fn camera_from(obj: Option<&Bound<'_, PyAny>>) -> PyResult<Option<Camera>> {
    let Some(obj) = obj else { return Ok(None) };
    if obj.is_none() {
        return Ok(None);
    }
    if let Ok(path) = obj.extract::<PathBuf>() {
        return photostereo::io::layouts::near::read_camera(&path)
            .map(Some)
            .map_err(py_err);
    }
    let k = obj
        .extract::<PyReadonlyArray2<'_, f64>>()
        .ok()
        .filter(|a| a.as_array().dim() == (3, 3))
        .ok_or_else(|| {
            bad(format!(
                "camera: expected a 3×3 array K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (pixels) or the path of a K.txt, got {}",
                repr(obj)
            ))
        })?;
    let k = k.as_array();
    let rows = [
        [k[[0, 0]], k[[0, 1]], k[[0, 2]]],
        [k[[1, 0]], k[[1, 1]], k[[1, 2]]],
        [k[[2, 0]], k[[2, 1]], k[[2, 2]]],
    ];
    photostereo::io::layouts::near::camera_from_matrix(rows)
        .map(Some)
        .map_err(py_err)
}

/// Reads a capture from files: a DiLiGenT-layout folder, a list file with `lights`, or image
/// files with `lights`.
#[pyfunction]
#[pyo3(signature = (inputs, lights=None, intensities=None, mask=None, num_threads=None, distance=None, camera=None))]
#[allow(clippy::too_many_arguments)]
fn load_capture(
    py: Python<'_>,
    inputs: Vec<PathBuf>,
    lights: Option<PathBuf>,
    intensities: Option<PathBuf>,
    mask: Option<PathBuf>,
    num_threads: Option<usize>,
    distance: Option<f64>,
    camera: Option<&Bound<'_, PyAny>>,
) -> PyResult<NativeCapture> {
    let files = InputFiles {
        inputs,
        lights,
        intensities,
        mask,
        distance,
        camera: camera_from(camera)?,
    };
    let capture = run_detached(py, num_threads, None, move |progress| {
        files.resolve()?.load(progress)
    })?;
    Ok(NativeCapture {
        inner: Arc::new(capture),
    })
}

/// The rows of an (N, 1|3) intensity array as RGB triples (one value: grey light).
fn rgb_rows(e: &ArrayView2<'_, f64>) -> Vec<[f64; 3]> {
    e.rows()
        .into_iter()
        .map(|r| {
            if r.len() == 1 {
                [r[0]; 3]
            } else {
                [r[0], r[1], r[2]]
            }
        })
        .collect()
}

/// Lights from (N, 3) directions and optional (N, C) intensities.
fn lights_from(
    directions: ArrayView2<'_, f64>,
    intensities: Option<ArrayView2<'_, f64>>,
    channels: usize,
) -> PyResult<Lights> {
    if directions.ncols() != 3 {
        return Err(bad(format!(
            "lights: expected an (N, 3) array of directions, got shape {:?}",
            directions.shape()
        )));
    }
    let dirs: Vec<[f64; 3]> = directions
        .rows()
        .into_iter()
        .map(|r| [r[0], r[1], r[2]])
        .collect();
    if let Some(k) = dirs.iter().position(|d| d.iter().any(|v| !v.is_finite())) {
        return Err(bad(format!(
            "lights: light {} has a non-finite direction {:?}",
            k + 1,
            dirs[k]
        )));
    }
    let mut lights = Lights::new(&dirs).map_err(py_err)?;
    if let Some(e) = intensities {
        if e.nrows() != dirs.len() || (e.ncols() != 1 && e.ncols() != channels && e.ncols() != 3) {
            return Err(bad(format!(
                "intensities: expected an (N, C) array with N = {} lights and C = 1 or {channels}, got shape {:?}",
                dirs.len(),
                e.shape()
            )));
        }
        let rows = rgb_rows(&e);
        lights = lights.with_intensities(rows).map_err(py_err)?;
    }
    Ok(lights)
}

/// Near lights from LED positions (N, 3) mm, a camera, the mean distance, optional axes (N, 3),
/// anisotropy (N,) and radiances (N, C) (1 when absent).
#[allow(clippy::too_many_arguments)]
fn near_lights_from(
    positions: ArrayView2<'_, f64>,
    camera: Option<Camera>,
    distance: Option<f64>,
    axes: Option<ArrayView2<'_, f64>>,
    anisotropy: Option<Vec<f64>>,
    intensities: Option<ArrayView2<'_, f64>>,
    channels: usize,
) -> PyResult<Lights> {
    let rows3 = |a: ArrayView2<'_, f64>, what: &str| -> PyResult<Vec<[f64; 3]>> {
        if a.ncols() != 3 {
            return Err(bad(format!(
                "{what}: expected an (N, 3) array, got shape {:?}",
                a.shape()
            )));
        }
        Ok(a.rows().into_iter().map(|r| [r[0], r[1], r[2]]).collect())
    };
    let positions = rows3(positions, "light_positions")?;
    let n = positions.len();
    if n < 3 {
        return Err(bad(format!(
            "light_positions: {n} light(s): expected at least three rows x y z in mm"
        )));
    }
    let camera = camera.ok_or_else(|| {
        bad("camera: near lights need the camera intrinsics (a 3×3 K or a K.txt path)")
    })?;
    let distance = distance.ok_or_else(|| {
        bad("distance: near lights need the object's mean distance in mm; without it the lights cannot be placed")
    })?;
    let axes = axes.map(|a| rows3(a, "light_axes")).transpose()?;
    if let Some(a) = &axes {
        if a.len() != n {
            return Err(bad(format!(
                "light_axes: {} axes for {n} light positions: expected one per light",
                a.len()
            )));
        }
    }
    if let Some(m) = &anisotropy {
        if m.len() != n {
            return Err(bad(format!(
                "light_anisotropy: {} values for {n} light positions: expected one per light",
                m.len()
            )));
        }
    }
    let intensities = match intensities {
        None => vec![[1.0; 3]; n],
        Some(e) => {
            if e.nrows() != n || (e.ncols() != 1 && e.ncols() != channels && e.ncols() != 3) {
                return Err(bad(format!(
                    "intensities: expected an (N, C) array of radiances with N = {n} lights and C = 1 or {channels}, got shape {:?}",
                    e.shape()
                )));
            }
            rgb_rows(&e)
        }
    };
    let layout = photostereo::io::layouts::near::NearLayout {
        camera,
        positions,
        axes,
        anisotropy,
        intensities,
        distance,
    };
    layout
        .lights(std::path::Path::new("light_positions"))
        .map_err(py_err)
}

/// A capture from an (N, H, W, C) array of uint8, uint16, float32 or float64, (N, 3) lights,
/// optional (N, C) intensities and (H, W) mask. The array is read once into the library's
/// store, with the GIL released.
#[pyfunction]
#[pyo3(signature = (images, lights, intensities=None, mask=None, light_positions=None,
    camera=None, distance=None, light_axes=None, light_anisotropy=None))]
#[allow(clippy::too_many_arguments)]
fn capture_from_stack(
    py: Python<'_>,
    images: &Bound<'_, PyAny>,
    lights: Option<PyReadonlyArray2<'_, f64>>,
    intensities: Option<PyReadonlyArray2<'_, f64>>,
    mask: Option<PyReadonlyArray2<'_, bool>>,
    light_positions: Option<PyReadonlyArray2<'_, f64>>,
    camera: Option<&Bound<'_, PyAny>>,
    distance: Option<f64>,
    light_axes: Option<PyReadonlyArray2<'_, f64>>,
    light_anisotropy: Option<Vec<f64>>,
) -> PyResult<NativeCapture> {
    let channels = images
        .getattr("shape")
        .ok()
        .and_then(|s| s.extract::<Vec<usize>>().ok())
        .and_then(|s| s.get(3).copied())
        .unwrap_or(1);
    let camera = camera_from(camera)?;
    let lights = match (light_positions, lights) {
        (Some(positions), None) => near_lights_from(
            positions.as_array(),
            camera,
            distance,
            light_axes.as_ref().map(|a| a.as_array()),
            light_anisotropy,
            intensities.as_ref().map(|i| i.as_array()),
            channels,
        )?,
        (Some(_), Some(_)) => {
            return Err(bad(
                "lights and light_positions: give directions (distant lights) or LED positions (near lights), not both",
            ))
        }
        (None, Some(lights)) => {
            if light_axes.is_some() || light_anisotropy.is_some() {
                return Err(bad(
                    "light_axes and light_anisotropy describe near lights: they need light_positions",
                ));
            }
            let mut l = lights_from(
                lights.as_array(),
                intensities.as_ref().map(|i| i.as_array()),
                channels,
            )?;
            match (camera, distance) {
                (Some(c), Some(d)) => {
                    if !(d.is_finite() && d > 0.0) {
                        return Err(bad(format!(
                            "distance {d}: expected the object's mean distance in mm, finite and positive"
                        )));
                    }
                    l.camera = Some((c, d));
                }
                (None, None) => {}
                (Some(_), None) => {
                    return Err(bad(
                        "camera: distant lights seen through a camera need distance= (the object's mean distance in mm) too",
                    ))
                }
                (None, Some(_)) => {
                    return Err(bad(
                        "distance: needs camera= (a 3×3 K or a K.txt path), or light_positions= for near lights",
                    ))
                }
            }
            l
        }
        (None, None) => {
            return Err(bad(
                "lights: an image array needs (N, 3) light directions, or light_positions (N, 3) in mm with camera and distance for near lights",
            ))
        }
    };
    let mask_view = mask.as_ref().map(|m| m.as_array());
    macro_rules! build {
        ($t:ty, $variant:ident) => {
            if let Ok(a) = images.extract::<PyReadonlyArray4<'_, $t>>() {
                let view = a.as_array();
                let capture = py
                    .detach(|| Capture::from_stack(Stack::$variant(view), lights, mask_view))
                    .map_err(py_err)?;
                return Ok(NativeCapture {
                    inner: Arc::new(capture),
                });
            }
        };
    }
    build!(u8, U8);
    build!(u16, U16);
    build!(f32, F32);
    build!(f64, F64);
    let dtype = images
        .getattr("dtype")
        .map(|d| d.to_string())
        .unwrap_or_else(|_| type_name(images));
    Err(bad(format!(
        "images: expected a 4-d array (N, H, W, C) of uint8, uint16, float32 or float64, got {dtype}"
    )))
}

// ---------------------------------------------------------------------------------------------
// Reconstruction.

fn flat3(v: &[[f32; 3]]) -> Vec<f32> {
    v.iter().flat_map(|x| x.iter().copied()).collect()
}

/// The arrays and report of a reconstruction as a dict (the maps are moved, not copied).
fn reconstruction_dict<'py>(
    py: Python<'py>,
    mut rec: Reconstruction,
) -> PyResult<Bound<'py, PyDict>> {
    let (h, w, c, n) = (rec.height, rec.width, rec.channels, rec.n_lights);
    let shape_err = |e: ndarray::ShapeError| bad(e.to_string());
    let d = PyDict::new(py);
    let report = serde_json::to_string(&rec.report).map_err(|e| bad(e.to_string()))?;
    d.set_item("report_json", report)?;
    let normals = Array3::from_shape_vec((h, w, 3), flat3(&rec.normals)).map_err(shape_err)?;
    d.set_item("normals", normals.into_pyarray(py))?;
    let albedo =
        Array3::from_shape_vec((h, w, c), std::mem::take(&mut rec.albedo)).map_err(shape_err)?;
    d.set_item("albedo", albedo.into_pyarray(py))?;
    let status =
        Array3::from_shape_vec((n, h, w), rec.light_status.to_full()).map_err(shape_err)?;
    d.set_item("light_status", status.into_pyarray(py))?;
    let hw = |v| Array2::from_shape_vec((h, w), v).map_err(shape_err);
    d.set_item("mask", hw(std::mem::take(&mut rec.mask))?.into_pyarray(py))?;
    let hw32 = |v| Array2::<f32>::from_shape_vec((h, w), v).map_err(shape_err);
    let hwb = |v| Array2::<bool>::from_shape_vec((h, w), v).map_err(shape_err);
    d.set_item(
        "trust",
        hw32(std::mem::take(&mut rec.trust))?.into_pyarray(py),
    )?;
    let optional_f32 = |v: Option<Vec<f32>>| -> PyResult<Py<PyAny>> {
        Ok(match v {
            Some(v) => hw32(v)?.into_pyarray(py).into_any().unbind(),
            None => py.None(),
        })
    };
    let optional_bool = |v: Option<Vec<bool>>| -> PyResult<Py<PyAny>> {
        Ok(match v {
            Some(v) => hwb(v)?.into_pyarray(py).into_any().unbind(),
            None => py.None(),
        })
    };
    d.set_item("residual", optional_f32(rec.residual.take())?)?;
    d.set_item("unreliable", optional_bool(rec.unreliable.take())?)?;
    let (depth, curl) = match rec.surface.take() {
        Some(s) => (Some(s.depth.values), Some(s.curl)),
        None => (None, None),
    };
    d.set_item("depth", optional_f32(depth)?)?;
    d.set_item("curl", optional_f32(curl)?)?;
    let (highlight, few) = match rec.recursive.take() {
        Some(r) => (Some(r.highlight), Some(r.fewer_than_three)),
        None => (None, None),
    };
    d.set_item("highlight", optional_bool(highlight)?)?;
    d.set_item("fewer_than_three", optional_bool(few)?)?;
    Ok(d)
}

/// Reconstructs a capture; `params` holds every keyword (see `defaults()`).
#[pyfunction]
#[pyo3(signature = (capture, params, num_threads=None, progress=None))]
fn reconstruct<'py>(
    py: Python<'py>,
    capture: &NativeCapture,
    params: &Bound<'py, PyDict>,
    num_threads: Option<usize>,
    progress: Option<Py<PyAny>>,
) -> PyResult<Bound<'py, PyDict>> {
    let params = params_from(params)?;
    let capture = Arc::clone(&capture.inner);
    let rec = run_detached(py, num_threads, progress, move |p| {
        if params.refine_lights {
            // The Capture object stays as built: the refined lights (and rescaled samples)
            // belong to a copy made for this call.
            let mut own = (*capture).clone();
            photostereo::method::engine::prepare(&mut own, &params)?;
            photostereo::method::engine::reconstruct(&own, &params, p)
        } else {
            photostereo::method::engine::reconstruct(&capture, &params, p)
        }
    })?;
    reconstruction_dict(py, rec)
}

/// The command line's `run`: reads the capture, reconstructs, writes the output folder
/// atomically; returns report.json's content as a string.
#[pyfunction]
#[pyo3(signature = (inputs, output, params, lights=None, intensities=None, mask=None, gt=None,
    error_map=false, light_subset=None, force=false, num_threads=None, progress=None,
    distance=None, camera=None))]
#[allow(clippy::too_many_arguments)]
fn run(
    py: Python<'_>,
    inputs: Vec<PathBuf>,
    output: PathBuf,
    params: &Bound<'_, PyDict>,
    lights: Option<PathBuf>,
    intensities: Option<PathBuf>,
    mask: Option<PathBuf>,
    gt: Option<PathBuf>,
    error_map: bool,
    light_subset: Option<String>,
    force: bool,
    num_threads: Option<usize>,
    progress: Option<Py<PyAny>>,
    distance: Option<f64>,
    camera: Option<&Bound<'_, PyAny>>,
) -> PyResult<String> {
    let params = params_from(params)?;
    let camera = camera_from(camera)?;
    let light_subset = light_subset
        .map(|s| s.parse::<LightSubset>())
        .transpose()
        .map_err(py_err)?;
    let options = RunOptions {
        params,
        ground_truth: gt,
        error_map,
        error_map_max_deg: None,
        light_subset,
        obj_any_size: false,
        // The interpreter's allocator settings stay its own.
        return_freed_memory_when_tiled: false,
    };
    let files = InputFiles {
        inputs,
        lights,
        intensities,
        mask,
        distance,
        camera,
    };
    let rec = run_detached(py, num_threads, progress, move |p| {
        photostereo::app::pipeline::run(&files.resolve()?, &options, &output, force, p)
    })?;
    serde_json::to_string(&rec.report).map_err(|e| bad(e.to_string()))
}

// ---------------------------------------------------------------------------------------------
// Integration, metrics, calibration, scenes.

fn normals_from(view: ArrayView3<'_, f32>, what: &str) -> PyResult<Vec<[f32; 3]>> {
    if view.shape()[2] != 3 {
        return Err(bad(format!(
            "{what}: expected an (H, W, 3) array, got shape {:?}",
            view.shape()
        )));
    }
    Ok(view
        .lanes(Axis(2))
        .into_iter()
        .map(|l| [l[0], l[1], l[2]])
        .collect())
}

fn mask_from(
    mask: Option<ArrayView2<'_, bool>>,
    h: usize,
    w: usize,
) -> PyResult<Option<Vec<bool>>> {
    match mask {
        Some(m) if m.dim() != (h, w) => Err(bad(format!(
            "mask: expected shape ({h}, {w}) like the normals, got {:?}",
            m.shape()
        ))),
        Some(m) => Ok(Some(m.iter().copied().collect())),
        None => Ok(None),
    }
}

/// Integrates (H, W, 3) normals into (H, W) depth (pixel units, NaN outside the mask).
#[pyfunction]
#[pyo3(signature = (normals, mask=None, method="poisson", weights=None, max_slope=None, num_threads=None))]
fn integrate<'py>(
    py: Python<'py>,
    normals: PyReadonlyArray3<'py, f32>,
    mask: Option<PyReadonlyArray2<'py, bool>>,
    method: &str,
    weights: Option<PyReadonlyArray2<'py, f32>>,
    max_slope: Option<f32>,
    num_threads: Option<usize>,
) -> PyResult<Bound<'py, numpy::PyArray2<f32>>> {
    let view = normals.as_array();
    let (h, w) = (view.shape()[0], view.shape()[1]);
    let normals = normals_from(view, "normals")?;
    let mask = mask_from(mask.as_ref().map(|m| m.as_array()), h, w)?;
    let weights: Option<Vec<f32>> = match &weights {
        Some(wt) if wt.as_array().dim() != (h, w) => {
            return Err(bad(format!(
                "weights: expected shape ({h}, {w}) like the normals, got {:?}",
                wt.as_array().shape()
            )))
        }
        Some(wt) => Some(wt.as_array().iter().copied().collect()),
        None => None,
    };
    let kind: photostereo::geometry::integrate::IntegratorKind = method.parse().map_err(py_err)?;
    let max_slope = max_slope.unwrap_or(photostereo::geometry::integrate::DEFAULT_MAX_SLOPE);
    let depth = run_detached(py, num_threads, None, move |p| {
        photostereo::geometry::integrate::surface_from_normals(
            w,
            h,
            &normals,
            mask.as_deref(),
            weights.as_deref(),
            kind.integrator().as_ref(),
            max_slope,
            p,
        )
    })?;
    Ok(Array2::from_shape_vec((h, w), depth.depth.values)
        .map_err(|e| bad(e.to_string()))?
        .into_pyarray(py))
}

/// Angular error figures of (H, W, 3) normals against ground truth: (stats as JSON, error map).
#[pyfunction]
#[pyo3(signature = (normals, truth, mask=None))]
fn angular_error<'py>(
    py: Python<'py>,
    normals: PyReadonlyArray3<'py, f32>,
    truth: PyReadonlyArray3<'py, f32>,
    mask: Option<PyReadonlyArray2<'py, bool>>,
) -> PyResult<(String, Bound<'py, numpy::PyArray2<f32>>)> {
    let (pv, tv) = (normals.as_array(), truth.as_array());
    if pv.shape() != tv.shape() {
        return Err(bad(format!(
            "normals {:?} and truth {:?}: expected the same (H, W, 3) shape",
            pv.shape(),
            tv.shape()
        )));
    }
    let (h, w) = (pv.shape()[0], pv.shape()[1]);
    let pred = normals_from(pv, "normals")?;
    let gt = normals_from(tv, "truth")?;
    let mask = mask_from(mask.as_ref().map(|m| m.as_array()), h, w)?;
    let (map, stats) = py
        .detach(|| photostereo::solve::metrics::evaluate(&pred, &gt, mask.as_deref()))
        .map_err(py_err)?;
    let json = serde_json::to_string(&stats).map_err(|e| bad(e.to_string()))?;
    let map = Array2::from_shape_vec((h, w), map).map_err(|e| bad(e.to_string()))?;
    Ok((json, map.into_pyarray(py)))
}

/// Images from an (N, H, W, C) float32 array.
fn images_from(view: ndarray::ArrayView4<'_, f32>) -> Vec<Image> {
    let (_, h, w, c) = view.dim();
    view.outer_iter()
        .map(|img| Image {
            width: w,
            height: h,
            channels: c,
            bit_depth: 32,
            data: img.iter().copied().collect(),
        })
        .collect()
}

/// Light directions from images of a mirror sphere ((N, H, W, C) float32, full scale 1):
/// the calibration as JSON.
#[pyfunction]
#[pyo3(signature = (images, mask=None))]
fn calibrate(
    py: Python<'_>,
    images: PyReadonlyArray4<'_, f32>,
    mask: Option<PyReadonlyArray2<'_, bool>>,
) -> PyResult<String> {
    let view = images.as_array();
    let (_, h, w, _) = view.dim();
    let imgs = images_from(view);
    let mask = mask_from(mask.as_ref().map(|m| m.as_array()), h, w)?;
    let cal = py
        .detach(|| {
            photostereo::calibrate::calibrate(
                &imgs,
                mask.as_deref(),
                None,
                &photostereo::calibrate::CalibrationOptions::default(),
            )
        })
        .map_err(py_err)?;
    serde_json::to_string(&cal).map_err(|e| bad(e.to_string()))
}

fn spec_from(
    name: &str,
    rig: &str,
    size: usize,
    brdf: &str,
    noise: f64,
    seed: u64,
) -> PyResult<SynthSpec> {
    if !(8..=8192).contains(&size) {
        return Err(bad(format!("size {size}: expected 8..=8192 pixels")));
    }
    if !(noise.is_finite() && noise >= 0.0) {
        return Err(bad(format!("noise {noise}: expected a finite value ≥ 0")));
    }
    let scene: SceneKind = name.parse().map_err(py_err)?;
    let mut spec = SynthSpec::new(
        scene,
        photostereo::io::light_files::parse_rig(rig).map_err(py_err)?,
    );
    spec.size = size;
    spec.render.brdf = brdf.parse::<Brdf>().map_err(py_err)?;
    spec.render.noise_sigma = noise;
    spec.render.seed = seed;
    Ok(spec)
}

/// The spec of a near-light scene (`rig` near-ring, near-square or near-dome).
fn near_spec_from(
    name: &str,
    rig: NearRig,
    size: usize,
    brdf: &str,
    noise: f64,
    seed: u64,
) -> PyResult<NearSpec> {
    let scene: SceneKind = name.parse().map_err(py_err)?;
    Ok(NearSpec {
        size,
        brdf: brdf.parse::<Brdf>().map_err(py_err)?,
        noise_sigma: noise,
        seed,
        ..NearSpec::new(scene, rig)
    })
}

/// Renders a built-in scene: (images (N, S, S, 3) float32, lights (N, 3), mask (S, S),
/// truth normals (S, S, 3), truth depth (S, S), shadows (N, S, S) bool, near) with `near`
/// None for distant rigs and, for the near rigs, a dict of the rig (`light_positions` (N, 3)
/// mm, `light_axes` (N, 3), `light_anisotropy` (N,), `intensities` (N, 3) radiance at 1 mm,
/// `camera` (3, 3) K in pixels, `distance` mm); the depth is then Z in mm.
#[pyfunction]
#[pyo3(signature = (name, rig="square4", size=128, brdf="blinn-phong", noise=0.005, seed=1))]
fn render_scene<'py>(
    py: Python<'py>,
    name: &str,
    rig: &str,
    size: usize,
    brdf: &str,
    noise: f64,
    seed: u64,
) -> PyResult<Bound<'py, PyTuple>> {
    let (r, near) = match NearRig::parse(rig) {
        Some(near_rig) => {
            let spec = near_spec_from(name, near_rig, size, brdf, noise, seed)?;
            let r = py.detach(|| synthesize_near(&spec)).map_err(py_err)?;
            let d = PyDict::new(py);
            let rows = |v: &[[f64; 3]]| Array2::from_shape_fn((v.len(), 3), |(k, j)| v[k][j]);
            d.set_item("light_positions", rows(&r.positions).into_pyarray(py))?;
            d.set_item("light_axes", rows(&r.axes).into_pyarray(py))?;
            d.set_item(
                "light_anisotropy",
                ndarray::Array1::from_vec(r.anisotropy.clone()).into_pyarray(py),
            )?;
            d.set_item("intensities", rows(&r.radiance).into_pyarray(py))?;
            let k = &r.camera;
            let kk = Array2::from_shape_vec(
                (3, 3),
                vec![k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0],
            )
            .map_err(|e| bad(e.to_string()))?;
            d.set_item("camera", kk.into_pyarray(py))?;
            d.set_item("distance", r.distance)?;
            (r.rendered, d.into_any().unbind())
        }
        None => {
            let spec = spec_from(name, rig, size, brdf, noise, seed)?;
            let r = py
                .detach(|| photostereo::scene::synthesize(&spec))
                .map_err(py_err)?;
            (r, py.None())
        }
    };
    let (n, s) = (r.images.len(), size);
    let mut images = Array4::<f32>::zeros((n, s, s, 3));
    for (k, img) in r.images.iter().enumerate() {
        let dst = images.index_axis_mut(Axis(0), k);
        for (d, v) in dst.into_iter().zip(&img.data) {
            *d = *v;
        }
    }
    let lights = Array2::from_shape_fn((n, 3), |(k, j)| r.lights.directions[k][j]);
    let t = &r.truth;
    let mask = Array2::from_shape_vec((s, s), t.mask.clone()).map_err(|e| bad(e.to_string()))?;
    let normals =
        Array3::from_shape_vec((s, s, 3), flat3(&t.normals)).map_err(|e| bad(e.to_string()))?;
    let depth = Array2::from_shape_vec((s, s), t.depth.clone()).map_err(|e| bad(e.to_string()))?;
    let shadows = Array3::from_shape_fn((n, s, s), |(k, i, j)| t.shadow[k][i * s + j]);
    PyTuple::new(
        py,
        [
            images.into_pyarray(py).into_any(),
            lights.into_pyarray(py).into_any(),
            mask.into_pyarray(py).into_any(),
            normals.into_pyarray(py).into_any(),
            depth.into_pyarray(py).into_any(),
            shadows.into_pyarray(py).into_any(),
            near.into_bound(py),
        ],
    )
}

/// Renders a built-in scene into a DiLiGenT-layout folder with ground truth (`gt/`), as
/// `photostereo synth` does; returns the folder.
#[pyfunction]
#[pyo3(signature = (name, output, rig="square4", size=128, brdf="blinn-phong", noise=0.005, seed=1, force=false))]
#[allow(clippy::too_many_arguments)]
fn synth(
    py: Python<'_>,
    name: &str,
    output: PathBuf,
    rig: &str,
    size: usize,
    brdf: &str,
    noise: f64,
    seed: u64,
    force: bool,
) -> PyResult<String> {
    if let Some(near_rig) = NearRig::parse(rig) {
        let spec = near_spec_from(name, near_rig, size, brdf, noise, seed)?;
        let (_, target) = py
            .detach(|| near_synth_to_folder(&spec, &output, force))
            .map_err(py_err)?;
        return Ok(target.display().to_string());
    }
    let spec = spec_from(name, rig, size, brdf, noise, seed)?;
    let (_, target) = py
        .detach(|| synth_to_folder(&spec, &output, force))
        .map_err(py_err)?;
    Ok(target.display().to_string())
}

/// An image file as (H, W, C) float32, integers scaled to [0, 1].
#[pyfunction]
fn read_image<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, numpy::PyArray3<f32>>> {
    let img = py
        .detach(|| photostereo::io::imageio::read_image(&path))
        .map_err(py_err)?;
    Ok(
        Array3::from_shape_vec((img.height, img.width, img.channels), img.data)
            .map_err(|e| bad(e.to_string()))?
            .into_pyarray(py),
    )
}

/// A normal map file (.npy, DiLiGenT .mat, 16-bit PNG) as (H, W, 3) float32.
#[pyfunction]
fn read_normals<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, numpy::PyArray3<f32>>> {
    let map = py
        .detach(|| photostereo::io::groundtruth::read_normal_map(&path))
        .map_err(py_err)?;
    Ok(
        Array3::from_shape_vec((map.height, map.width, 3), flat3(&map.normals))
            .map_err(|e| bad(e.to_string()))?
            .into_pyarray(py),
    )
}

/// The names `method=` accepts.
#[pyfunction]
fn methods() -> Vec<&'static str> {
    Method::ALL.iter().map(|m| m.name()).collect()
}

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("PhotostereoError", m.py().get_type::<PhotostereoError>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_class::<NativeCapture>()?;
    m.add_function(wrap_pyfunction!(defaults, m)?)?;
    m.add_function(wrap_pyfunction!(methods, m)?)?;
    m.add_function(wrap_pyfunction!(load_capture, m)?)?;
    m.add_function(wrap_pyfunction!(capture_from_stack, m)?)?;
    m.add_function(wrap_pyfunction!(reconstruct, m)?)?;
    m.add_function(wrap_pyfunction!(run, m)?)?;
    m.add_function(wrap_pyfunction!(integrate, m)?)?;
    m.add_function(wrap_pyfunction!(angular_error, m)?)?;
    m.add_function(wrap_pyfunction!(calibrate, m)?)?;
    m.add_function(wrap_pyfunction!(render_scene, m)?)?;
    m.add_function(wrap_pyfunction!(synth, m)?)?;
    m.add_function(wrap_pyfunction!(read_image, m)?)?;
    m.add_function(wrap_pyfunction!(read_normals, m)?)?;
    Ok(())
}
