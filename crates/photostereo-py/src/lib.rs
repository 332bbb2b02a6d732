//! `photostereo._native`: the Python package's native module, a thin layer over the photostereo
//! library like the command line. It converts numpy arrays and Python values to the library's
//! types and back (arrays and dicts, never JSON text), releases the GIL while the library works,
//! polls for Ctrl-C, and turns every library error into `PhotostereoError` with the library's
//! message, parameters spelt as Python keywords (`spell`). No numerics live here, and no
//! parameter list: the parameters come from the library's table
//! (`photostereo::method::params`).
//!
//! The public, documented API is the pure-Python package `photostereo` (python/photostereo).

use ndarray::{Array1, Array2, Array3, Array4, ArrayViewD, Axis, Ix4};
use numpy::{IntoPyArray, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use photostereo::app::pipeline::{LightSubset, RunOptions};
use photostereo::base::error::ParamRef;
use photostereo::base::progress::Progress;
use photostereo::io::layouts::{CaptureFiles, LoadOptions};
use photostereo::io::photometry::{Frames, Photometry};
use photostereo::method::engine::{Method, Params, Reconstruction};
use photostereo::method::params::{parameter, Value, PARAMETERS};
use photostereo::model::capture::{Capture, Stack, StackOptions};
use photostereo::model::lightmodel::Camera;
use photostereo::model::lights::Lights;
use photostereo::scene::near::{synthesize_near, NearRig, NearSpec};
use photostereo::scene::{Brdf, SceneKind, SynthSpec};
use pyo3::create_exception;
use pyo3::exceptions::{PyKeyboardInterrupt, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyBytes, PyDict, PyFloat, PyInt, PyList, PyString, PyTuple};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{mpsc, Arc, Mutex};
use std::time::Duration;

create_exception!(
    _native,
    PhotostereoError,
    PyValueError,
    "Bad input to photostereo: the message names the file, line or keyword at fault and what was expected."
);

/// A parameter reference of a library message as Python spells it: the keyword itself, or
/// `keyword=` where a value is asked for (`force=True` for a switch).
fn spell(r: ParamRef<'_>) -> String {
    match r.value {
        None => r.name.to_string(),
        Some("true") => format!("{}=True", r.name),
        Some("false") => format!("{}=False", r.name),
        Some(v) => format!("{}={v}", r.name),
    }
}

/// The library's error as `PhotostereoError` (Ctrl-C's cancellation as `KeyboardInterrupt`).
fn py_err(e: photostereo::Error) -> PyErr {
    match e {
        photostereo::Error::Cancelled => PyKeyboardInterrupt::new_err("cancelled"),
        other => PhotostereoError::new_err(other.spelled(&spell)),
    }
}

fn bad(message: impl Into<String>) -> PyErr {
    PhotostereoError::new_err(message.into())
}

/// A shape as Python writes it: `(2, 3)`, `(4,)`.
fn shape_text(s: &[usize]) -> String {
    match s {
        [one] => format!("({one},)"),
        _ => format!(
            "({})",
            s.iter()
                .map(|d| d.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

fn repr(v: &Bound<'_, PyAny>) -> String {
    v.repr()
        .map(|r| r.to_string())
        .unwrap_or_else(|_| "?".into())
}

// ---------------------------------------------------------------------------------------------
// Keyword values: every value a keyword takes is checked here once, naming the keyword.

/// A whole number in `lo..=hi` (a bool is not one).
fn whole(v: &Bound<'_, PyAny>, name: &str, lo: i64, hi: i64, what: &str) -> PyResult<i64> {
    let n = if v.is_instance_of::<PyBool>() {
        None
    } else {
        v.extract::<i64>().ok()
    };
    match n {
        Some(n) if (lo..=hi).contains(&n) => Ok(n),
        _ => Err(bad(format!(
            "{name} {}: expected an integer in [{lo}, {hi}]{what}",
            repr(v)
        ))),
    }
}

/// A finite number accepted by `ok`.
fn real(v: &Bound<'_, PyAny>, name: &str, ok: impl Fn(f64) -> bool, what: &str) -> PyResult<f64> {
    match v.extract::<f64>() {
        Ok(x) if !v.is_instance_of::<PyBool>() && x.is_finite() && ok(x) => Ok(x),
        _ => Err(bad(format!("{name} {}: expected {what}", repr(v)))),
    }
}

/// `None` or a value read by `f`.
fn optional<T>(
    v: Option<&Bound<'_, PyAny>>,
    f: impl FnOnce(&Bound<'_, PyAny>) -> PyResult<T>,
) -> PyResult<Option<T>> {
    match v {
        Some(v) if !v.is_none() => f(v).map(Some),
        _ => Ok(None),
    }
}

/// The most worker threads a call may ask for: a few per core, and never thousands.
fn max_threads() -> i64 {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    (4 * cores).max(64) as i64
}

/// `num_threads`: `None` (all cores) or 1 to [`max_threads`].
fn threads(v: Option<&Bound<'_, PyAny>>) -> PyResult<Option<usize>> {
    optional(v, |v| {
        whole(v, "num_threads", 1, max_threads(), " (None: all cores)").map(|n| n as usize)
    })
}

/// `progress`: `None` or a callable `progress(stage, done, total)`.
fn callback(v: Option<&Bound<'_, PyAny>>) -> PyResult<Option<Py<PyAny>>> {
    optional(v, |v| {
        if v.is_callable() {
            Ok(v.clone().unbind())
        } else {
            Err(bad(format!(
                "progress {}: expected a callable progress(stage, done, total), or None",
                repr(v)
            )))
        }
    })
}

/// A parameter's value from Python: None, bool, int, float or str (numpy scalars included).
fn value_of(name: &str, v: &Bound<'_, PyAny>) -> PyResult<Value> {
    if v.is_none() {
        return Ok(Value::None);
    }
    if let Ok(b) = v.extract::<bool>() {
        return Ok(Value::Bool(b));
    }
    if let Ok(s) = v.cast::<PyString>() {
        return Ok(Value::Text(s.to_string()));
    }
    if let Ok(i) = v.extract::<i64>() {
        return Ok(Value::Int(i));
    }
    if !v.is_instance_of::<PyInt>() {
        if let Ok(f) = v.extract::<f64>() {
            return Ok(Value::Float(f));
        }
    }
    let expected = parameter(name).map_or("a value".into(), |p| p.expected());
    Err(bad(format!("{name} {}: expected {expected}", repr(v))))
}

/// A parameter's value as Python holds it.
fn py_of(py: Python<'_>, v: &Value) -> PyResult<Py<PyAny>> {
    Ok(match v {
        Value::None => py.None(),
        Value::Bool(b) => PyBool::new(py, *b).to_owned().into_any().unbind(),
        Value::Int(i) => i.into_pyobject(py)?.into_any().unbind(),
        Value::Float(f) => PyFloat::new(py, *f).into_any().unbind(),
        Value::Text(t) => PyString::new(py, t).into_any().unbind(),
    })
}

/// A JSON value (a report, a calibration, error figures) as Python dicts, lists and numbers.
fn py_json(py: Python<'_>, v: &serde_json::Value) -> PyResult<Py<PyAny>> {
    use serde_json::Value as J;
    Ok(match v {
        J::Null => py.None(),
        J::Bool(b) => PyBool::new(py, *b).to_owned().into_any().unbind(),
        J::Number(n) => match (n.as_i64(), n.as_u64()) {
            (Some(i), _) => i.into_pyobject(py)?.into_any().unbind(),
            (None, Some(u)) => u.into_pyobject(py)?.into_any().unbind(),
            _ => PyFloat::new(py, n.as_f64().unwrap_or(f64::NAN))
                .into_any()
                .unbind(),
        },
        J::String(s) => PyString::new(py, s).into_any().unbind(),
        J::Array(a) => {
            let items = a
                .iter()
                .map(|x| py_json(py, x))
                .collect::<PyResult<Vec<_>>>()?;
            PyList::new(py, items)?.into_any().unbind()
        }
        J::Object(o) => {
            let d = PyDict::new(py);
            for (k, x) in o {
                d.set_item(k, py_json(py, x)?)?;
            }
            d.into_any().unbind()
        }
    })
}

/// A serializable library value as Python objects.
fn py_serde(py: Python<'_>, v: &impl serde::Serialize) -> PyResult<Py<PyAny>> {
    py_json(
        py,
        &serde_json::to_value(v).map_err(|e| bad(e.to_string()))?,
    )
}

// ---------------------------------------------------------------------------------------------
// Parameters: the library's table.

/// `Params` from a dict of parameter names and values, each checked by the table.
fn params_from(dict: &Bound<'_, PyDict>) -> PyResult<Params> {
    let mut p = Params::default();
    for (key, value) in dict.iter() {
        let name: String = key.extract()?;
        let v = value_of(&name, &value)?;
        p.set(&name, v).map_err(py_err)?;
    }
    p.validate().map_err(py_err)?;
    Ok(p)
}

/// Every parameter of the library's table: name, stage, type, default, choices, the word for
/// none, domain, unit, doc, methods and the key `report.json` records it under.
#[pyfunction]
fn parameters(py: Python<'_>) -> PyResult<Vec<Bound<'_, PyDict>>> {
    PARAMETERS
        .iter()
        .map(|p| {
            let d = PyDict::new(py);
            d.set_item("name", p.name)?;
            d.set_item("stage", p.stage.name())?;
            d.set_item("stage_doc", p.stage.doc())?;
            d.set_item("type", p.kind.type_name())?;
            d.set_item("default", py_of(py, &p.default())?)?;
            d.set_item("choices", p.kind.choices())?;
            d.set_item("none", p.kind.none_word())?;
            d.set_item("domain", p.expected())?;
            d.set_item("unit", p.unit)?;
            d.set_item("doc", p.doc)?;
            d.set_item(
                "methods",
                p.methods.iter().map(|m| m.name()).collect::<Vec<_>>(),
            )?;
            d.set_item("report_key", p.report_key)?;
            Ok(d)
        })
        .collect()
}

/// The library's default of every parameter, keyed by name.
#[pyfunction]
fn defaults(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    let d = PyDict::new(py);
    for p in PARAMETERS {
        d.set_item(p.name, py_of(py, &p.default())?)?;
    }
    Ok(d)
}

/// Checks one parameter's value against the table; raises `PhotostereoError` naming it.
#[pyfunction]
fn check_parameter(name: &str, value: &Bound<'_, PyAny>) -> PyResult<()> {
    let p = parameter(name).ok_or_else(|| bad(format!("unknown parameter '{name}'")))?;
    let v = value_of(name, value)?;
    let mut params = Params::default();
    p.set(&mut params, v).map_err(py_err)?;
    params.validate().map_err(py_err)
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

/// What a Ctrl-C (or an exception from the progress callback) does besides asking the library
/// to stop at its next stage boundary.
#[derive(Clone, Copy, PartialEq, Eq)]
enum OnCancel {
    /// Raise at once; the worker winds down on its own (nothing of its work outlives it).
    Raise,
    /// Raise once the worker has stopped, so that the output it was writing (a staging folder)
    /// is gone when the caller sees the exception; a second Ctrl-C raises at once.
    CleanUpFirst,
}

/// Runs `work` on a worker thread (in a rayon pool of `num_threads` when given) with the GIL
/// released. The calling thread wakes every 50 ms: it checks for signals (Ctrl-C raises
/// KeyboardInterrupt, as `on_cancel` says, and asks the library to stop at its next stage
/// boundary) and calls `progress(stage, done, total)` when the figures changed.
fn run_detached<T: Send + 'static>(
    py: Python<'_>,
    num_threads: Option<usize>,
    progress: Option<Py<PyAny>>,
    on_cancel: OnCancel,
    work: impl FnOnce(&dyn Progress) -> photostereo::Result<T> + Send + 'static,
) -> PyResult<T> {
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
            return Err(wind_down(py, &rx, on_cancel, e));
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
                    return Err(wind_down(py, &rx, on_cancel, e));
                }
                last = now;
            }
        }
    }
}

/// After a cancel, with [`OnCancel::CleanUpFirst`]: waits for the worker to stop at its next
/// stage boundary, so that what it was writing (the staging folder of `run`'s output) is
/// removed before `error` reaches the caller. A second Ctrl-C while waiting raises at once; the
/// folder is then removed when the interpreter exits ([`abandon_pending_outputs`]).
fn wind_down<T: Send>(
    py: Python<'_>,
    rx: &Mutex<mpsc::Receiver<photostereo::Result<T>>>,
    on_cancel: OnCancel,
    error: PyErr,
) -> PyErr {
    if on_cancel == OnCancel::Raise {
        return error;
    }
    loop {
        let received = py.detach(|| match rx.lock() {
            Ok(r) => r.recv_timeout(Duration::from_millis(50)),
            Err(_) => Err(mpsc::RecvTimeoutError::Disconnected),
        });
        match received {
            Ok(_) | Err(mpsc::RecvTimeoutError::Disconnected) => return error,
            Err(mpsc::RecvTimeoutError::Timeout) => {}
        }
        if let Err(again) = py.check_signals() {
            return again;
        }
    }
}

/// Hands the allocator's free memory back to the system after a job. With glibc, memory freed
/// on a pool thread stays in that thread's arena, where the next call (often on another pool
/// thread) cannot reuse it.
fn release_free_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only returns free pages of the allocator's arenas to the system.
    unsafe {
        libc::malloc_trim(0);
    }
}

/// Removes the output folders still being written (their `.NAME.tmp-PID` staging folders):
/// the package calls it when the interpreter exits, so that a run interrupted by Ctrl-C
/// leaves nothing behind even when its worker has not reached its next stage boundary.
#[pyfunction]
fn abandon_pending_outputs() -> usize {
    photostereo::io::export::abandon_pending()
}

// ---------------------------------------------------------------------------------------------
// Arrays in.

/// An (N, H, W) or (N, H, W, C) image stack of one of the accepted sample types.
enum StackArray<'py> {
    U8(PyReadonlyArrayDyn<'py, u8>),
    U16(PyReadonlyArrayDyn<'py, u16>),
    F32(PyReadonlyArrayDyn<'py, f32>),
    F64(PyReadonlyArrayDyn<'py, f64>),
}

fn four_d<'a, T>(v: ArrayViewD<'a, T>, name: &str) -> PyResult<ndarray::ArrayView4<'a, T>> {
    let shape = v.shape().to_vec();
    let v = match v.ndim() {
        3 => v.insert_axis(Axis(3)),
        4 => v,
        _ => {
            return Err(bad(format!(
                "{name}: expected an (N, H, W) or (N, H, W, C) array, got shape {}",
                shape_text(&shape)
            )))
        }
    };
    v.into_dimensionality::<Ix4>()
        .map_err(|e| bad(format!("{name}: {e}")))
}

impl<'py> StackArray<'py> {
    fn extract(obj: &Bound<'py, PyAny>, name: &str) -> PyResult<Self> {
        if let Ok(a) = obj.extract() {
            return Ok(StackArray::U8(a));
        }
        if let Ok(a) = obj.extract() {
            return Ok(StackArray::U16(a));
        }
        if let Ok(a) = obj.extract() {
            return Ok(StackArray::F32(a));
        }
        if let Ok(a) = obj.extract() {
            return Ok(StackArray::F64(a));
        }
        let dtype = obj
            .getattr("dtype")
            .map(|d| d.to_string())
            .unwrap_or_else(|_| repr(obj));
        Err(bad(format!(
            "{name}: expected an array of uint8, uint16, float32 or float64 samples, got {dtype}"
        )))
    }

    fn stack(&self, name: &str) -> PyResult<Stack<'_>> {
        Ok(match self {
            StackArray::U8(a) => Stack::U8(four_d(a.as_array(), name)?),
            StackArray::U16(a) => Stack::U16(four_d(a.as_array(), name)?),
            StackArray::F32(a) => Stack::F32(four_d(a.as_array(), name)?),
            StackArray::F64(a) => Stack::F64(four_d(a.as_array(), name)?),
        })
    }
}

/// A float64 array with `ndim` dimensions (and `cols` columns when given).
fn floats<'py>(
    obj: &Bound<'py, PyAny>,
    name: &str,
    shapes: &str,
    ok: impl Fn(&[usize]) -> bool,
) -> PyResult<PyReadonlyArrayDyn<'py, f64>> {
    let a: PyReadonlyArrayDyn<'py, f64> = obj
        .extract()
        .map_err(|_| bad(format!("{name}: expected an array of numbers")))?;
    if !ok(a.shape()) {
        return Err(bad(format!(
            "{name}: expected {shapes}, got shape {}",
            shape_text(a.shape())
        )));
    }
    Ok(a)
}

/// Rows of three numbers from an (N, 3) array.
fn rows3(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Vec<[f64; 3]>> {
    let a = floats(obj, name, "an (N, 3) array", |s| s.len() == 2 && s[1] == 3)?;
    Ok(a.as_array()
        .rows()
        .into_iter()
        .map(|r| [r[0], r[1], r[2]])
        .collect())
}

/// Intensities from an (N,) or (N, C) array, as RGB triples (one value: grey light).
fn intensity_rows(obj: &Bound<'_, PyAny>, channels: usize) -> PyResult<Vec<[f64; 3]>> {
    let a = floats(
        obj,
        "intensities",
        &format!("an (N,) or (N, C) array with C = 1 or {channels}"),
        |s| s.len() == 1 || (s.len() == 2 && (s[1] == 1 || s[1] == channels || s[1] == 3)),
    )?;
    let a = a.as_array();
    Ok(if a.ndim() == 1 {
        a.iter().map(|&v| [v; 3]).collect()
    } else {
        a.outer_iter()
            .map(|r| {
                if r.len() == 1 {
                    [r[0]; 3]
                } else {
                    [r[0], r[1], r[2]]
                }
            })
            .collect()
    })
}

/// A mask of `h` × `w`: an (H, W) array, or (H, W, 1|3|4) whose non-zero channels mark the
/// object. Returned as given when 2-d (the library checks its shape).
fn mask_of(obj: &Bound<'_, PyAny>, h: usize, w: usize) -> PyResult<ndarray::Array2<bool>> {
    let m: PyReadonlyArrayDyn<'_, bool> = obj
        .extract()
        .map_err(|_| bad("mask: expected an array of booleans"))?;
    let v = m.as_array();
    let s = v.shape().to_vec();
    match s.len() {
        2 => Ok(v
            .into_dimensionality()
            .map_err(|e| bad(e.to_string()))?
            .to_owned()),
        3 if s[0] == h && s[1] == w && matches!(s[2], 1 | 3 | 4) => Ok(v
            .map_axis(Axis(2), |px| px.iter().any(|&b| b))
            .into_dimensionality()
            .map_err(|e| bad(e.to_string()))?),
        _ => Err(bad(format!(
            "mask: expected an ({h}, {w}) array like the images, got shape {}",
            shape_text(&s)
        ))),
    }
}

/// A camera from a K.txt path or a 3x3 array of intrinsics (pixels).
fn camera_from(obj: Option<&Bound<'_, PyAny>>) -> PyResult<Option<Camera>> {
    optional(obj, |obj| {
        if let Ok(path) = obj.extract::<PathBuf>() {
            return photostereo::io::layouts::near::read_camera(&path).map_err(py_err);
        }
        let k = floats(
            obj,
            "camera",
            "a 3x3 array K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (pixels) or the path of a K.txt",
            |s| s == [3, 3],
        )?;
        let k = k.as_array();
        let rows = [0, 1, 2].map(|r| [k[[r, 0]], k[[r, 1]], k[[r, 2]]]);
        photostereo::io::layouts::near::camera_from_matrix(rows).map_err(py_err)
    })
}

fn distance_of(obj: Option<&Bound<'_, PyAny>>) -> PyResult<Option<f64>> {
    optional(obj, |v| {
        real(
            v,
            "distance",
            |d| d > 0.0,
            "the object's mean distance in mm, finite and positive",
        )
    })
}

fn memory_limit_of(obj: Option<&Bound<'_, PyAny>>) -> PyResult<Option<u64>> {
    let mut p = Params::default();
    if let Some(v) = obj {
        p.set("memory_limit", value_of("memory_limit", v)?)
            .map_err(py_err)?;
    }
    Ok(p.memory_limit)
}

// ---------------------------------------------------------------------------------------------
// Captures.

/// A capture held by the library: the mask pixels' intensity-normalised samples, the lights
/// (distant or near) and the mask. Shared, never copied, by `reconstruct`; pickled whole.
#[pyclass(frozen, module = "photostereo._native")]
struct NativeCapture {
    inner: Arc<Capture>,
}

fn k_matrix(c: &Camera) -> Array2<f64> {
    Array2::from_shape_vec(
        (3, 3),
        vec![c.fx, 0.0, c.cx, 0.0, c.fy, c.cy, 0.0, 0.0, 1.0],
    )
    .expect("3x3")
}

fn rows_array(v: &[[f64; 3]]) -> Array2<f64> {
    Array2::from_shape_fn((v.len(), 3), |(k, j)| v[k][j])
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
    /// The object's mean distance in mm, with a camera.
    #[getter]
    fn distance(&self) -> Option<f64> {
        self.inner.lights.perspective().map(|(_, d)| d)
    }
    /// (N, 3) unit light directions (near lights: toward each LED from the object's centre).
    fn lights<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray2<f64>> {
        rows_array(&self.inner.lights.directions).into_pyarray(py)
    }
    /// (N, C) light intensities.
    fn intensities<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, numpy::PyArray2<f64>>> {
        let c = &self.inner;
        Ok(
            Array2::from_shape_vec((c.n_lights(), c.channels), c.channel_intensities())
                .map_err(|e| bad(e.to_string()))?
                .into_pyarray(py),
        )
    }
    /// (H, W) bool.
    fn mask<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, numpy::PyArray2<bool>>> {
        let c = &self.inner;
        Ok(Array2::from_shape_vec((c.height, c.width), c.mask.clone())
            .map_err(|e| bad(e.to_string()))?
            .into_pyarray(py))
    }
    /// (N, H, W, C) float32: the images as given (full scale 1), zero outside the mask.
    fn images<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, numpy::PyArray4<f32>>> {
        let c = Arc::clone(&self.inner);
        let data = py.detach(|| c.images()).map_err(py_err)?;
        let c = &self.inner;
        Ok(
            Array4::from_shape_vec((c.n_lights(), c.height, c.width, c.channels), data)
                .map_err(|e| bad(e.to_string()))?
                .into_pyarray(py),
        )
    }
    /// The 3x3 intrinsics K of the capture's camera (near lights, or distant lights seen
    /// through a camera), or None.
    fn camera<'py>(&self, py: Python<'py>) -> Option<Bound<'py, numpy::PyArray2<f64>>> {
        self.inner
            .lights
            .perspective()
            .map(|(c, _)| k_matrix(&c).into_pyarray(py))
    }
    /// The near-light rig (`light_positions`, `light_axes`, `light_anisotropy`), or None.
    fn near<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        let Some(n) = self.inner.lights.near.as_deref() else {
            return Ok(None);
        };
        let d = PyDict::new(py);
        d.set_item("light_positions", rows_array(&n.positions).into_pyarray(py))?;
        d.set_item("light_axes", rows_array(&n.axes).into_pyarray(py))?;
        d.set_item(
            "light_anisotropy",
            Array1::from_vec(n.anisotropy.clone()).into_pyarray(py),
        )?;
        Ok(Some(d))
    }
    /// Pickles the whole capture: samples, mask, lights with their near model, camera
    /// (`photostereo::io::capture_state`).
    fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyTuple>> {
        let rebuild = py
            .import("photostereo._native")?
            .getattr("_capture_from_state")?;
        let c = Arc::clone(&self.inner);
        let state = py
            .detach(|| photostereo::io::capture_state::to_bytes(&c))
            .map_err(py_err)?;
        let args = PyTuple::new(py, [PyBytes::new(py, &state)])?;
        PyTuple::new(py, [rebuild, args.into_any()])
    }
}

/// The capture a pickled state describes.
#[pyfunction]
fn _capture_from_state(py: Python<'_>, state: &[u8]) -> PyResult<NativeCapture> {
    let capture = py
        .detach(|| photostereo::io::capture_state::from_bytes(state))
        .map_err(py_err)?;
    Ok(NativeCapture {
        inner: Arc::new(capture),
    })
}

/// Reads a capture from files, in every layout `run` reads (see the package's `load_capture`).
#[pyfunction]
#[pyo3(signature = (inputs, lights=None, intensities=None, mask=None, num_threads=None,
    distance=None, camera=None, memory_limit=None, response=None, ambient=None,
    dark=None, flat=None, ignore_exposure=false))]
#[allow(clippy::too_many_arguments)]
fn load_capture(
    py: Python<'_>,
    inputs: Vec<PathBuf>,
    lights: Option<PathBuf>,
    intensities: Option<PathBuf>,
    mask: Option<PathBuf>,
    num_threads: Option<&Bound<'_, PyAny>>,
    distance: Option<&Bound<'_, PyAny>>,
    camera: Option<&Bound<'_, PyAny>>,
    memory_limit: Option<&Bound<'_, PyAny>>,
    response: Option<String>,
    ambient: Option<PathBuf>,
    dark: Option<PathBuf>,
    flat: Option<PathBuf>,
    ignore_exposure: bool,
) -> PyResult<NativeCapture> {
    let num_threads = threads(num_threads)?;
    let distance = distance_of(distance)?;
    let camera = camera_from(camera)?;
    let budget = memory_limit_of(memory_limit)?;
    let frames = Frames {
        ambient: ambient.as_deref(),
        dark: dark.as_deref(),
        flat: flat.as_deref(),
    };
    let given = photometry_of(response.as_deref(), frames, ignore_exposure)?;
    let capture = run_detached(py, num_threads, None, OnCancel::Raise, move |progress| {
        let mut files = CaptureFiles::from_inputs_with(
            &inputs,
            lights.as_deref(),
            intensities.as_deref(),
            mask.as_deref(),
            distance,
            camera,
        )?;
        files.photometry = given.over(&files.photometry);
        let options = LoadOptions {
            budget,
            ..LoadOptions::default()
        };
        files.load_with(progress, &options)
    })?;
    Ok(NativeCapture {
        inner: Arc::new(capture),
    })
}

/// The capture-reading keywords `response=`, `ambient=`, `dark=`, `flat=`,
/// `ignore_exposure=` (the library's `Photometry`), checked before any file is read.
fn photometry_of(
    response: Option<&str>,
    frames: Frames<'_>,
    ignore_exposure: bool,
) -> PyResult<Photometry> {
    Photometry::from_options(response, frames, ignore_exposure).map_err(py_err)
}

/// The capture-reading keywords with their placeholders and meanings (the library's
/// `CAPTURE_OPTIONS`), for the package's docstrings.
#[pyfunction]
fn capture_options(py: Python<'_>) -> PyResult<Vec<Bound<'_, PyDict>>> {
    photostereo::io::photometry::CAPTURE_OPTIONS
        .iter()
        .map(|o| {
            let d = PyDict::new(py);
            d.set_item("name", o.name)?;
            d.set_item("value", o.value)?;
            d.set_item("doc", o.doc)?;
            Ok(d)
        })
        .collect()
}

/// The lights of an array capture, from the keywords (see `LightArrays`).
#[allow(clippy::too_many_arguments)]
fn lights_of(
    lights: Option<&Bound<'_, PyAny>>,
    intensities: Option<&Bound<'_, PyAny>>,
    light_positions: Option<&Bound<'_, PyAny>>,
    camera: Option<&Bound<'_, PyAny>>,
    distance: Option<&Bound<'_, PyAny>>,
    light_axes: Option<&Bound<'_, PyAny>>,
    light_anisotropy: Option<&Bound<'_, PyAny>>,
    channels: usize,
) -> PyResult<Lights> {
    let anisotropy = optional(light_anisotropy, |a| {
        let a = floats(a, "light_anisotropy", "an (N,) array", |s| s.len() == 1)?;
        Ok(a.as_array().iter().copied().collect())
    })?;
    photostereo::io::layouts::near::LightArrays {
        directions: optional(lights, |v| rows3(v, "lights"))?,
        intensities: optional(intensities, |v| intensity_rows(v, channels))?,
        positions: optional(light_positions, |v| rows3(v, "light_positions"))?,
        camera: camera_from(camera)?,
        distance: distance_of(distance)?,
        axes: optional(light_axes, |v| rows3(v, "light_axes"))?,
        anisotropy,
    }
    .lights()
    .map_err(py_err)
}

/// A capture from an image array (see the package's `Capture.from_arrays`): read once into
/// the library's store, within `memory_limit`, with the GIL released.
#[pyfunction]
#[pyo3(signature = (images, lights=None, intensities=None, mask=None, light_positions=None,
    camera=None, distance=None, light_axes=None, light_anisotropy=None, memory_limit=None))]
#[allow(clippy::too_many_arguments)]
fn capture_from_stack(
    py: Python<'_>,
    images: &Bound<'_, PyAny>,
    lights: Option<&Bound<'_, PyAny>>,
    intensities: Option<&Bound<'_, PyAny>>,
    mask: Option<&Bound<'_, PyAny>>,
    light_positions: Option<&Bound<'_, PyAny>>,
    camera: Option<&Bound<'_, PyAny>>,
    distance: Option<&Bound<'_, PyAny>>,
    light_axes: Option<&Bound<'_, PyAny>>,
    light_anisotropy: Option<&Bound<'_, PyAny>>,
    memory_limit: Option<&Bound<'_, PyAny>>,
) -> PyResult<NativeCapture> {
    let array = StackArray::extract(images, "images")?;
    let stack = array.stack("images")?;
    let (_, h, w, channels) = stack.dim();
    let lights = lights_of(
        lights,
        intensities,
        light_positions,
        camera,
        distance,
        light_axes,
        light_anisotropy,
        channels,
    )?;
    let mask = optional(mask, |m| mask_of(m, h, w))?;
    let options = StackOptions {
        budget: memory_limit_of(memory_limit)?,
        spill_dir: None,
    };
    let capture = py
        .detach(|| {
            Capture::from_stack_with(stack, lights, mask.as_ref().map(|m| m.view()), &options)
        })
        .map_err(py_err)?;
    Ok(NativeCapture {
        inner: Arc::new(capture),
    })
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
    d.set_item("report", py_serde(py, &rec.report)?)?;
    let normals = Array3::from_shape_vec((h, w, 3), flat3(&rec.normals)).map_err(shape_err)?;
    d.set_item("normals", normals.into_pyarray(py))?;
    let albedo =
        Array3::from_shape_vec((h, w, c), std::mem::take(&mut rec.albedo)).map_err(shape_err)?;
    d.set_item("albedo", albedo.into_pyarray(py))?;
    let status =
        Array3::from_shape_vec((n, h, w), rec.light_status.to_full()).map_err(shape_err)?;
    d.set_item("light_status", status.into_pyarray(py))?;
    let hw32 = |v| Array2::<f32>::from_shape_vec((h, w), v).map_err(shape_err);
    let hwb = |v| Array2::<bool>::from_shape_vec((h, w), v).map_err(shape_err);
    d.set_item("mask", hwb(std::mem::take(&mut rec.mask))?.into_pyarray(py))?;
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

/// Reconstructs a capture with the parameters of `params` (names of the library's table).
#[pyfunction]
#[pyo3(signature = (capture, params, num_threads=None, progress=None))]
fn reconstruct<'py>(
    py: Python<'py>,
    capture: &NativeCapture,
    params: &Bound<'py, PyDict>,
    num_threads: Option<&Bound<'py, PyAny>>,
    progress: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyDict>> {
    let params = params_from(params)?;
    let (num_threads, progress) = (threads(num_threads)?, callback(progress)?);
    let capture = Arc::clone(&capture.inner);
    let rec = run_detached(py, num_threads, progress, OnCancel::Raise, move |p| {
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
/// atomically; returns report.json's content.
#[pyfunction]
#[pyo3(signature = (inputs, output, params, lights=None, intensities=None, mask=None, gt=None,
    error_map=false, light_subset=None, force=false, num_threads=None, progress=None,
    distance=None, camera=None, response=None, ambient=None, dark=None, flat=None,
    ignore_exposure=false, rti=None))]
#[allow(clippy::too_many_arguments)]
fn run<'py>(
    py: Python<'py>,
    inputs: Vec<PathBuf>,
    output: PathBuf,
    params: &Bound<'py, PyDict>,
    lights: Option<PathBuf>,
    intensities: Option<PathBuf>,
    mask: Option<PathBuf>,
    gt: Option<PathBuf>,
    error_map: bool,
    light_subset: Option<String>,
    force: bool,
    num_threads: Option<&Bound<'py, PyAny>>,
    progress: Option<&Bound<'py, PyAny>>,
    distance: Option<&Bound<'py, PyAny>>,
    camera: Option<&Bound<'py, PyAny>>,
    response: Option<String>,
    ambient: Option<PathBuf>,
    dark: Option<PathBuf>,
    flat: Option<PathBuf>,
    ignore_exposure: bool,
    rti: Option<String>,
) -> PyResult<Py<PyAny>> {
    let params = params_from(params)?;
    let rti = rti
        .map(|b| b.parse::<photostereo::solve::rti::Basis>())
        .transpose()
        .map_err(py_err)?;
    let frames = Frames {
        ambient: ambient.as_deref(),
        dark: dark.as_deref(),
        flat: flat.as_deref(),
    };
    let given = photometry_of(response.as_deref(), frames, ignore_exposure)?;
    let (num_threads, progress) = (threads(num_threads)?, callback(progress)?);
    let distance = distance_of(distance)?;
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
        rti,
    };
    let rec = run_detached(
        py,
        num_threads,
        progress,
        OnCancel::CleanUpFirst,
        move |p| {
            let mut files = CaptureFiles::from_inputs_with(
                &inputs,
                lights.as_deref(),
                intensities.as_deref(),
                mask.as_deref(),
                distance,
                camera,
            )?;
            files.photometry = given.over(&files.photometry);
            photostereo::app::pipeline::run(&files, &options, &output, force, p)
        },
    )?;
    py_serde(py, &rec.report)
}

/// The command line's `rti`: fits a relightable-image basis and writes its folder; returns
/// report.json's content.
#[pyfunction]
#[pyo3(signature = (inputs, output, basis, lights=None, intensities=None, mask=None,
    exclude_unreliable=false, memory_limit=None, force=false, num_threads=None, progress=None,
    response=None, ambient=None, dark=None, flat=None, ignore_exposure=false, iiif=None,
    ridge=None))]
#[allow(clippy::too_many_arguments)]
fn rti<'py>(
    py: Python<'py>,
    inputs: Vec<PathBuf>,
    output: PathBuf,
    basis: &str,
    lights: Option<PathBuf>,
    intensities: Option<PathBuf>,
    mask: Option<PathBuf>,
    exclude_unreliable: bool,
    memory_limit: Option<u64>,
    force: bool,
    num_threads: Option<&Bound<'py, PyAny>>,
    progress: Option<&Bound<'py, PyAny>>,
    response: Option<String>,
    ambient: Option<PathBuf>,
    dark: Option<PathBuf>,
    flat: Option<PathBuf>,
    ignore_exposure: bool,
    iiif: Option<String>,
    ridge: Option<f64>,
) -> PyResult<Py<PyAny>> {
    let frames = Frames {
        ambient: ambient.as_deref(),
        dark: dark.as_deref(),
        flat: flat.as_deref(),
    };
    let given = photometry_of(response.as_deref(), frames, ignore_exposure)?;
    let basis = basis
        .parse::<photostereo::solve::rti::Basis>()
        .map_err(py_err)?;
    let (num_threads, progress) = (threads(num_threads)?, callback(progress)?);
    let options = photostereo::app::rti::RtiOptions {
        basis,
        exclude_unreliable,
        ridge,
        memory_limit,
        iiif,
    };
    let report = run_detached(
        py,
        num_threads,
        progress,
        OnCancel::CleanUpFirst,
        move |p| {
            let mut files = CaptureFiles::from_inputs(
                &inputs,
                lights.as_deref(),
                intensities.as_deref(),
                mask.as_deref(),
            )?;
            files.photometry = given.over(&files.photometry);
            photostereo::app::rti::rti(&files, &options, &output, force, p)
        },
    )?;
    py_serde(py, &report)
}

// ---------------------------------------------------------------------------------------------
// Integration, metrics, calibration, scenes.

/// (H, W, 3) normals from a float32 array.
fn normals_of<'py>(obj: &Bound<'py, PyAny>, name: &str) -> PyResult<(usize, usize, Vec<[f32; 3]>)> {
    let a: PyReadonlyArrayDyn<'py, f32> = obj
        .extract()
        .map_err(|_| bad(format!("{name}: expected an array of numbers")))?;
    let v = a.as_array();
    let s = v.shape().to_vec();
    if s.len() != 3 || s[2] != 3 {
        return Err(bad(format!(
            "{name}: expected an (H, W, 3) array, got shape {}",
            shape_text(&s)
        )));
    }
    check_map_size(name, s[0], s[1])?;
    let mut normals = reserved(name, s[0] * s[1])?;
    normals.extend(v.lanes(Axis(2)).into_iter().map(|l| [l[0], l[1], l[2]]));
    Ok((s[0], s[1], normals))
}

/// An (H, W) map held to the image readers' limits ([`MAX_IMAGE_SIDE`] a side,
/// [`MAX_IMAGE_PIXELS`] in all) before it is copied, so that a huge or zero-strided view is
/// refused instead of exhausting memory.
fn check_map_size(name: &str, h: usize, w: usize) -> PyResult<()> {
    use photostereo::model::image::{MAX_IMAGE_PIXELS, MAX_IMAGE_SIDE};
    let limit = if h as u64 > MAX_IMAGE_SIDE || w as u64 > MAX_IMAGE_SIDE {
        format!("a side exceeds the limit of {MAX_IMAGE_SIDE} pixels")
    } else if (h as u64) * (w as u64) > MAX_IMAGE_PIXELS {
        format!("more than the limit of {MAX_IMAGE_PIXELS} pixels")
    } else {
        return Ok(());
    };
    Err(bad(format!("{name}: {h}×{w} (rows×columns): {limit}")))
}

/// An empty vector with room for `len` items, or an error naming `name` when the memory is
/// not there (instead of the allocator's abort).
fn reserved<T>(name: &str, len: usize) -> PyResult<Vec<T>> {
    let mut v = Vec::new();
    v.try_reserve_exact(len).map_err(|_| {
        bad(format!(
            "{name}: {len} pixels do not fit in the memory available"
        ))
    })?;
    Ok(v)
}

/// An (H, W) map of `T` matching the normals' (H, W).
fn map_of<'py, T: numpy::Element + Copy>(
    obj: Option<&Bound<'py, PyAny>>,
    name: &str,
    (h, w): (usize, usize),
) -> PyResult<Option<Vec<T>>> {
    optional(obj, |o| {
        let a: PyReadonlyArrayDyn<'_, T> = o
            .extract()
            .map_err(|_| bad(format!("{name}: expected an array")))?;
        let v = a.as_array();
        if v.shape() != [h, w] {
            return Err(bad(format!(
                "{name}: expected shape ({h}, {w}) like the normals, got {}",
                shape_text(v.shape())
            )));
        }
        let mut out = reserved(name, h * w)?;
        out.extend(v.iter().copied());
        Ok(out)
    })
}

/// Integrates (H, W, 3) normals into (H, W) depth (pixel units, NaN outside the mask; Z in mm
/// through a camera).
#[pyfunction]
#[pyo3(signature = (normals, mask=None, method=None, weights=None, max_slope=None, camera=None, distance=None, num_threads=None))]
#[allow(clippy::too_many_arguments)]
fn integrate<'py>(
    py: Python<'py>,
    normals: &Bound<'py, PyAny>,
    mask: Option<&Bound<'py, PyAny>>,
    method: Option<&str>,
    weights: Option<&Bound<'py, PyAny>>,
    max_slope: Option<&Bound<'py, PyAny>>,
    camera: Option<&Bound<'py, PyAny>>,
    distance: Option<&Bound<'py, PyAny>>,
    num_threads: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, numpy::PyArray2<f32>>> {
    use photostereo::geometry::integrate::{integrate_normal_map, NormalMapIntegration};
    let (h, w, normals) = normals_of(normals, "normals")?;
    let mask = map_of::<bool>(mask, "mask", (h, w))?;
    let has_mask = mask.is_some();
    let weights = map_of::<f32>(weights, "weights", (h, w))?;
    let mut p = Params::default();
    if let Some(m) = method {
        p.set_text("integrator", m)
            .map_err(|e| bad(format!("method: {e}")))?;
    }
    if let Some(v) = max_slope {
        p.set("max_slope", value_of("max_slope", v)?)
            .map_err(py_err)?;
    }
    let camera = match (camera_from(camera)?, distance_of(distance)?) {
        (Some(k), Some(d)) => Some((k, d)),
        (None, None) => None,
        (Some(_), None) => {
            return Err(bad(
                "camera: needs distance (the object's mean distance, mm)",
            ))
        }
        (None, Some(_)) => return Err(bad("distance: applies only with camera")),
    };
    let (kind, max_slope) = (p.integration.method, p.integration.max_slope);
    let num_threads = threads(num_threads)?;
    let depth = run_detached(py, num_threads, None, OnCancel::Raise, move |p| {
        let how = NormalMapIntegration {
            method: kind,
            max_slope,
            camera: camera.as_ref().map(|(k, d)| (k, *d)),
        };
        integrate_normal_map(w, h, &normals, mask.as_deref(), weights.as_deref(), &how, p)
    })?;
    if !depth.depth.values.iter().any(|z| z.is_finite()) {
        // As the command line's `integrate` refuses a map without a usable normal.
        return Err(bad(format!(
            "normals: no pixel with a valid normal to integrate ({} invalid — zero, NaN or \
             infinite — and {} facing away from the camera{})",
            depth.rejected_invalid,
            depth.rejected_backfacing,
            if has_mask { ", inside the mask" } else { "" }
        )));
    }
    Ok(Array2::from_shape_vec((h, w), depth.depth.values)
        .map_err(|e| bad(e.to_string()))?
        .into_pyarray(py))
}

/// Angular error figures of (H, W, 3) normals against ground truth: (figures, error map).
#[pyfunction]
#[pyo3(signature = (normals, truth, mask=None))]
fn angular_error<'py>(
    py: Python<'py>,
    normals: &Bound<'py, PyAny>,
    truth: &Bound<'py, PyAny>,
    mask: Option<&Bound<'py, PyAny>>,
) -> PyResult<(Py<PyAny>, Bound<'py, numpy::PyArray2<f32>>)> {
    let (h, w, pred) = normals_of(normals, "normals")?;
    let (th, tw, gt) = normals_of(truth, "truth")?;
    if (th, tw) != (h, w) {
        return Err(bad(format!(
            "normals ({h}, {w}, 3) and truth ({th}, {tw}, 3): expected the same shape"
        )));
    }
    let mask = map_of::<bool>(mask, "mask", (h, w))?;
    let (map, stats) = py
        .detach(|| photostereo::solve::metrics::evaluate(&pred, &gt, mask.as_deref()))
        .map_err(py_err)?;
    let map = Array2::from_shape_vec((h, w), map).map_err(|e| bad(e.to_string()))?;
    Ok((py_serde(py, &stats)?, map.into_pyarray(py)))
}

/// Light directions from images of a mirror sphere: the calibration as a dict, with
/// `lights` (N, 3) (NaN where no highlight was found) and `confidence` (N,) arrays.
#[pyfunction]
#[pyo3(signature = (images, mask=None))]
fn calibrate<'py>(
    py: Python<'py>,
    images: &Bound<'py, PyAny>,
    mask: Option<&Bound<'py, PyAny>>,
) -> PyResult<Py<PyAny>> {
    let array = StackArray::extract(images, "images")?;
    let stack = array.stack("images")?;
    let (_, h, w, _) = stack.dim();
    let imgs = stack.images().map_err(py_err)?;
    let mask = optional(mask, |m| mask_of(m, h, w))?;
    if let Some(m) = &mask {
        if m.dim() != (h, w) {
            return Err(bad(format!(
                "mask: expected an ({h}, {w}) array like the images, got shape {}",
                shape_text(m.shape())
            )));
        }
    }
    let mask: Option<Vec<bool>> = mask.map(|m| m.iter().copied().collect());
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
    let out = py_serde(py, &cal)?;
    let d = out.bind(py).cast::<PyDict>()?;
    let n = cal.lights.len();
    let lights = Array2::from_shape_fn((n, 3), |(k, j)| {
        cal.lights[k].direction.map_or(f64::NAN, |d| d[j])
    });
    let confidence = Array1::from_iter(cal.lights.iter().map(|l| l.confidence));
    d.set_item("per_light", d.get_item("lights")?)?;
    d.set_item("lights", lights.into_pyarray(py))?;
    d.set_item("confidence", confidence.into_pyarray(py))?;
    Ok(out)
}

/// The scene arguments shared by `render_scene` and `synth`, checked.
struct SceneArgs {
    size: usize,
    noise: f64,
    seed: u64,
}

fn scene_args(
    size: &Bound<'_, PyAny>,
    noise: &Bound<'_, PyAny>,
    seed: &Bound<'_, PyAny>,
) -> PyResult<SceneArgs> {
    Ok(SceneArgs {
        size: whole(size, "size", 8, 8192, " pixels")? as usize,
        noise: real(noise, "noise", |v| v >= 0.0, "a finite value ≥ 0")?,
        seed: whole(seed, "seed", 0, i64::MAX, "")? as u64,
    })
}

fn spec_from(name: &str, rig: &str, brdf: &str, a: &SceneArgs) -> PyResult<SynthSpec> {
    let scene: SceneKind = name.parse().map_err(py_err)?;
    let mut spec = SynthSpec::new(
        scene,
        photostereo::io::light_files::parse_rig(rig).map_err(py_err)?,
    );
    spec.size = a.size;
    spec.render.brdf = brdf.parse::<Brdf>().map_err(py_err)?;
    spec.render.noise_sigma = a.noise;
    spec.render.seed = a.seed;
    Ok(spec)
}

fn near_spec_from(name: &str, rig: NearRig, brdf: &str, a: &SceneArgs) -> PyResult<NearSpec> {
    let scene: SceneKind = name.parse().map_err(py_err)?;
    Ok(NearSpec {
        size: a.size,
        brdf: brdf.parse::<Brdf>().map_err(py_err)?,
        noise_sigma: a.noise,
        seed: a.seed,
        ..NearSpec::new(scene, rig)
    })
}

/// Renders a built-in scene: (images (N, S, S, 3) float32, lights (N, 3), mask (S, S),
/// truth normals (S, S, 3), truth depth (S, S), shadows (N, S, S) bool, near) with `near`
/// None for distant rigs and, for the near rigs, a dict of the rig as `reconstruct` takes it.
#[pyfunction]
#[pyo3(signature = (name, rig, size, brdf, noise, seed))]
fn render_scene<'py>(
    py: Python<'py>,
    name: &str,
    rig: &str,
    size: &Bound<'py, PyAny>,
    brdf: &str,
    noise: &Bound<'py, PyAny>,
    seed: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyTuple>> {
    let a = scene_args(size, noise, seed)?;
    let (r, near) = match NearRig::parse(rig) {
        Some(near_rig) => {
            let spec = near_spec_from(name, near_rig, brdf, &a)?;
            let r = py.detach(|| synthesize_near(&spec)).map_err(py_err)?;
            let d = PyDict::new(py);
            d.set_item("light_positions", rows_array(&r.positions).into_pyarray(py))?;
            d.set_item("light_axes", rows_array(&r.axes).into_pyarray(py))?;
            d.set_item(
                "light_anisotropy",
                Array1::from_vec(r.anisotropy.clone()).into_pyarray(py),
            )?;
            d.set_item("intensities", rows_array(&r.radiance).into_pyarray(py))?;
            d.set_item("camera", k_matrix(&r.camera).into_pyarray(py))?;
            d.set_item("distance", r.distance)?;
            (r.rendered, d.into_any().unbind())
        }
        None => {
            let spec = spec_from(name, rig, brdf, &a)?;
            let r = py
                .detach(|| photostereo::scene::synthesize(&spec))
                .map_err(py_err)?;
            (r, py.None())
        }
    };
    let (n, s) = (r.images.len(), a.size);
    let data: Vec<f32> = r
        .images
        .iter()
        .flat_map(|i| i.data.iter().copied())
        .collect();
    let images = Array4::from_shape_vec((n, s, s, 3), data).map_err(|e| bad(e.to_string()))?;
    let lights = rows_array(&r.lights.directions);
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

/// Renders a built-in scene into a capture folder with ground truth (`gt/`), as `photostereo
/// synth` does; returns the folder.
#[pyfunction]
#[pyo3(signature = (name, output, rig, size, brdf, noise, seed, force))]
#[allow(clippy::too_many_arguments)]
fn synth<'py>(
    py: Python<'py>,
    name: &str,
    output: PathBuf,
    rig: &str,
    size: &Bound<'py, PyAny>,
    brdf: &str,
    noise: &Bound<'py, PyAny>,
    seed: &Bound<'py, PyAny>,
    force: bool,
) -> PyResult<String> {
    let a = scene_args(size, noise, seed)?;
    let target = match NearRig::parse(rig) {
        Some(near_rig) => {
            let spec = near_spec_from(name, near_rig, brdf, &a)?;
            py.detach(|| photostereo::io::synth::near_synth_to_folder(&spec, &output, force))
                .map_err(py_err)?
                .1
        }
        None => {
            let spec = spec_from(name, rig, brdf, &a)?;
            py.detach(|| photostereo::io::synth::synth_to_folder(&spec, &output, force))
                .map_err(py_err)?
                .1
        }
    };
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
    m.add_function(wrap_pyfunction!(parameters, m)?)?;
    m.add_function(wrap_pyfunction!(defaults, m)?)?;
    m.add_function(wrap_pyfunction!(check_parameter, m)?)?;
    m.add_function(wrap_pyfunction!(methods, m)?)?;
    m.add_function(wrap_pyfunction!(load_capture, m)?)?;
    m.add_function(wrap_pyfunction!(capture_from_stack, m)?)?;
    m.add_function(wrap_pyfunction!(_capture_from_state, m)?)?;
    m.add_function(wrap_pyfunction!(reconstruct, m)?)?;
    m.add_function(wrap_pyfunction!(run, m)?)?;
    m.add_function(wrap_pyfunction!(rti, m)?)?;
    m.add_function(wrap_pyfunction!(integrate, m)?)?;
    m.add_function(wrap_pyfunction!(angular_error, m)?)?;
    m.add_function(wrap_pyfunction!(calibrate, m)?)?;
    m.add_function(wrap_pyfunction!(render_scene, m)?)?;
    m.add_function(wrap_pyfunction!(synth, m)?)?;
    m.add_function(wrap_pyfunction!(read_image, m)?)?;
    m.add_function(wrap_pyfunction!(capture_options, m)?)?;
    m.add_function(wrap_pyfunction!(read_normals, m)?)?;
    m.add_function(wrap_pyfunction!(abandon_pending_outputs, m)?)?;
    Ok(())
}
