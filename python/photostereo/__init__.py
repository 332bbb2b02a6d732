"""photostereo: recursive photometric stereo, numpy in and out.

Per pixel a surface normal and an albedo from images taken from one viewpoint under known
lights, with shadows and highlights found and left out (Argyriou & Petrou's recursive method and
its baselines), then a depth map by integrating the normals. The engine is the Rust library
behind the ``photostereo`` command line; this package is a thin layer over it: the GIL is
released while it works, Ctrl-C raises KeyboardInterrupt, bad input raises PhotostereoError.

Conventions (the project's CONVENTIONS.md): camera frame x right, y up, z toward the camera;
arrays are row-major with row 0 at the top; normals are unit vectors with n_z > 0; light
directions point from the surface toward the light; integer images are scaled to [0, 1] by
their bit depth; depth is in pixel units toward the camera.

Example::

    import numpy as np, photostereo
    cap = photostereo.load_capture("catPNG")
    rec = photostereo.reconstruct(cap)
    print(rec.report["method"], rec.normals.shape)
    np.save("normals.npy", rec.normals)
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from typing import Any, Callable, Dict, Optional, Sequence, Tuple, Union

import numpy as np

from . import _native
from ._native import PhotostereoError, __version__

__all__ = [
    "Capture",
    "PhotostereoError",
    "Reconstruction",
    "angular_error",
    "calibrate",
    "defaults",
    "integrate",
    "load_capture",
    "read_image",
    "read_normals",
    "reconstruct",
    "render_scene",
    "run",
    "synth",
    "__version__",
]

PathLike = Union[str, "os.PathLike[str]"]
#: ``progress(stage, done, total)``: called from the calling thread while the library works.
ProgressCallback = Callable[[str, int, int], Any]


def defaults() -> Dict[str, Any]:
    """The library's default for every reconstruction keyword (the one source of defaults)."""
    return dict(_native.defaults())


class Capture:
    """Images, lights and mask of one capture, held by the library.

    Only the pixels inside the mask are stored, divided by their light's intensity (the
    library's sample store); ``reconstruct`` uses that store without copying it. Build one with
    :func:`load_capture` (files) or :func:`Capture.from_arrays` (numpy).
    """

    __slots__ = ("_native",)

    def __init__(self, native: "_native.NativeCapture"):
        self._native = native

    @classmethod
    def from_arrays(
        cls,
        images: np.ndarray,
        lights: Any = None,
        intensities: Any = None,
        mask: Any = None,
        *,
        light_positions: Any = None,
        camera: Any = None,
        distance: Optional[float] = None,
        light_axes: Any = None,
        light_anisotropy: Any = None,
    ) -> "Capture":
        """A capture from an (N, H, W) or (N, H, W, C) array of uint8, uint16, float32 or
        float64 (any strides), (N, 3) light directions, optional (N,) or (N, C) intensities and
        an (H, W) mask (non-zero = object). The array is read once into the library's store.

        Near lights (LEDs a few hundred mm away; CONVENTIONS.md): instead of ``lights``, give
        ``light_positions`` (N, 3) in mm in the camera frame (camera centre at the origin, x
        right, y up, z toward the camera: the object has z < 0), ``camera`` (the 3x3
        intrinsics K in pixels, or the path of a K.txt) and ``distance`` (the object's mean
        distance along the optical axis, mm); optional ``light_axes`` (N, 3) (default: each
        LED aims at (0, 0, -distance)), ``light_anisotropy`` (N,) (mu: radiance ~ cos^mu off
        the axis; default 0) and ``intensities`` (each LED's radiance along its axis at 1 mm;
        default 1). Every method then uses per-pixel light vectors and the depth is Z in mm.
        Distant ``lights`` with ``camera`` and ``distance`` keep the distant model but
        integrate through the camera (depth in mm)."""
        stack = _as_stack(images)
        lights_arr = None if lights is None else _float_array(lights, "lights")
        intens = None
        if intensities is not None:
            intens = _float_array(intensities, "intensities")
            if intens.ndim == 1:
                intens = intens[:, None]
        mask_arr = None if mask is None else _mask_array(mask)
        positions = None
        if light_positions is not None:
            positions = _float_array(light_positions, "light_positions")
        axes = None if light_axes is None else _float_array(light_axes, "light_axes")
        mu = None
        if light_anisotropy is not None:
            mu = [float(v) for v in _float_array(light_anisotropy, "light_anisotropy").ravel()]
        return cls(
            _native.capture_from_stack(
                stack,
                lights_arr,
                intens,
                mask_arr,
                positions,
                _camera_arg(camera),
                None if distance is None else float(distance),
                axes,
                mu,
            )
        )

    @property
    def width(self) -> int:
        return self._native.width

    @property
    def height(self) -> int:
        return self._native.height

    @property
    def channels(self) -> int:
        return self._native.channels

    @property
    def n_lights(self) -> int:
        return self._native.n_lights

    @property
    def bit_depth(self) -> int:
        """Bits per sample of the source: 8, 16, or 32 for float data."""
        return self._native.bit_depth

    @property
    def images(self) -> np.ndarray:
        """(N, H, W, C) float32, full scale 1; zero outside the mask (built on each access)."""
        return self._native.images()

    @property
    def lights(self) -> np.ndarray:
        """(N, 3) float64 unit directions toward the lights, camera frame."""
        return self._native.lights()

    @property
    def intensities(self) -> np.ndarray:
        """(N, C) float64 light intensities."""
        return self._native.intensities()

    @property
    def mask(self) -> np.ndarray:
        """(H, W) bool, True inside the object."""
        return self._native.mask()

    @property
    def notes(self) -> list:
        """Remarks made while loading (normalised lights, resolved paths...)."""
        return list(self._native.notes)

    def __reduce__(self):
        return (
            _capture_from_state,
            (self.images, self.lights, self.intensities, self.mask, self.bit_depth),
        )

    def __repr__(self) -> str:
        return (
            f"Capture({self.n_lights} lights, {self.width}x{self.height}, "
            f"{self.channels} channel(s), {self.bit_depth}-bit)"
        )


def _capture_from_state(images, lights, intensities, mask, bit_depth):
    # The stored images are already multiplied back by the intensities: rebuild with them.
    return Capture.from_arrays(images, lights, intensities, mask)


@dataclass
class Reconstruction:
    """The result of :func:`reconstruct`; every map is full frame (H rows, W columns).

    normals:          (H, W, 3) float32 unit normals, camera frame; 0 outside the mask.
    albedo:           (H, W, C) float32 per channel, in units of the intensity-normalised
                      images; 0 outside the mask.
    depth:            (H, W) float32, pixel units toward the camera, NaN outside the mask;
                      None with ``integrate=False``.
    light_status:     (N, H, W) uint8: 0 used, 1 shadow, 2 highlight, 3 rejected, 255 outside.
    residual:         (H, W) float32, the chi-square statistic ||r|| / sigma with all lights;
                      None when the test did not run (fewer than four lights, detect=False).
    unreliable:       (H, W) bool, the test failed; None when it did not run.
    curl:             (H, W) float32 integrability residual (eq. 10); None without depth.
    trust:            (H, W) float32 integration weight of each pixel (1, unreliable_weight, 0).
    mask:             (H, W) bool.
    highlight:        (H, W) bool, the recursive method's highlight map; None for others.
    fewer_than_three: (H, W) bool, pixels left with fewer than three usable lights (recursive).
    report:           dict, the content of report.json.
    """

    normals: np.ndarray
    albedo: np.ndarray
    depth: Optional[np.ndarray]
    light_status: np.ndarray
    residual: Optional[np.ndarray]
    unreliable: Optional[np.ndarray]
    curl: Optional[np.ndarray]
    trust: np.ndarray
    mask: np.ndarray
    highlight: Optional[np.ndarray]
    fewer_than_three: Optional[np.ndarray]
    report: Dict[str, Any]


def _as_stack(images: Any) -> np.ndarray:
    """An (N, H, W, C) view of ``images`` without copying when the dtype is accepted."""
    if isinstance(images, Capture):
        raise PhotostereoError("images: a Capture needs no lights or intensities")
    arr = np.asarray(images)
    if arr.dtype not in (np.uint8, np.uint16, np.float32, np.float64):
        raise PhotostereoError(
            f"images: expected uint8, uint16, float32 or float64 samples, got {arr.dtype}"
        )
    if arr.ndim == 3:
        arr = arr[..., None]
    if arr.ndim != 4:
        raise PhotostereoError(
            f"images: expected an (N, H, W) or (N, H, W, C) array, got shape {arr.shape}"
        )
    return arr


def _float_array(values: Any, name: str) -> np.ndarray:
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise PhotostereoError(f"{name}: expected an array of numbers ({e})") from None
    if name == "lights" and (arr.ndim != 2 or arr.shape[1] != 3):
        raise PhotostereoError(f"lights: expected an (N, 3) array, got shape {arr.shape}")
    if name in ("light_positions", "light_axes") and (arr.ndim != 2 or arr.shape[1] != 3):
        raise PhotostereoError(f"{name}: expected an (N, 3) array in mm, got shape {arr.shape}")
    if name == "intensities" and arr.ndim not in (1, 2):
        raise PhotostereoError(
            f"intensities: expected an (N,) or (N, C) array, got shape {arr.shape}"
        )
    return arr


def _mask_array(mask: Any) -> np.ndarray:
    arr = np.asarray(mask)
    if arr.ndim == 3 and arr.shape[2] in (1, 3, 4):
        arr = arr.any(axis=2)
    if arr.ndim != 2:
        raise PhotostereoError(f"mask: expected an (H, W) array, got shape {arr.shape}")
    return arr.astype(bool, copy=False)


def _camera_arg(camera: Any) -> Any:
    """``camera=`` as the native module takes it: a path string or a (3, 3) float64 array."""
    if camera is None:
        return None
    if isinstance(camera, (str, os.PathLike)):
        return os.fspath(camera)
    try:
        k = np.asarray(camera, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise PhotostereoError(
            f"camera: expected a 3x3 array K or the path of a K.txt ({e})"
        ) from None
    if k.shape != (3, 3):
        raise PhotostereoError(
            f"camera: expected a 3x3 array K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], got shape {k.shape}"
        )
    return np.ascontiguousarray(k)


def _paths(path: Union[PathLike, Sequence[PathLike]]) -> list:
    if isinstance(path, (str, os.PathLike)):
        return [os.fspath(path)]
    return [os.fspath(p) for p in path]


def _opt_path(p: Optional[PathLike]) -> Optional[str]:
    return None if p is None else os.fspath(p)


def load_capture(
    path: Union[PathLike, Sequence[PathLike]],
    lights: Optional[PathLike] = None,
    intensities: Optional[PathLike] = None,
    mask: Optional[PathLike] = None,
    *,
    distance: Optional[float] = None,
    camera: Any = None,
    num_threads: Optional[int] = None,
) -> Capture:
    """Reads a capture from files, in every layout the command line reads: a DiLiGenT-layout
    folder (``lights`` replaces its directions), a near-light folder (``light_positions.txt``,
    ``K.txt``...), a list file (with ``lights``), or a list of image files (with ``lights``).
    ``intensities`` and ``mask`` replace the layout's own. For one folder, ``distance`` (mm)
    replaces ``mean_distance.txt`` (as ``--distance``) and ``camera`` (a 3x3 K in pixels or a
    K.txt path) replaces ``K.txt``; on a folder of distant lights they add a camera (depth in
    mm). Images are decoded in parallel (``num_threads`` caps the threads)."""
    native = _native.load_capture(
        _paths(path),
        _opt_path(lights),
        _opt_path(intensities),
        _opt_path(mask),
        num_threads,
        None if distance is None else float(distance),
        _camera_arg(camera),
    )
    return Capture(native)


def reconstruct(
    images: Union[Capture, np.ndarray],
    lights: Any = None,
    *,
    mask: Any = None,
    intensities: Any = None,
    light_positions: Any = None,
    camera: Any = None,
    distance: Optional[float] = None,
    light_axes: Any = None,
    light_anisotropy: Any = None,
    method: str = "recursive",
    sigma: Optional[float] = None,
    relative_noise: Optional[float] = None,
    confidence: float = 0.95,
    min_kept_share: float = 0.25,
    batch_alpha: float = 0.05,
    shadow_sigmas: float = 3.0,
    shadow_ratio: float = 0.1,
    noise_estimate: str = "images",
    noise_refinements: int = 1,
    max_iterations: int = 10,
    change_tolerance: float = 0.002,
    surface_prior: float = 1.0,
    refine_lights: bool = False,
    fallback: str = "neighbours",
    integrator: str = "poisson",
    max_slope: float = 20.0,
    unreliable_weight: float = 0.1,
    detect: bool = True,
    integrate: bool = True,
    memory_limit: Union[int, str, None] = None,
    num_threads: Optional[int] = None,
    progress: Optional[ProgressCallback] = None,
) -> Reconstruction:
    """Normals, albedo, statuses, maps and depth of a capture.

    images: a :class:`Capture`, or an (N, H, W) / (N, H, W, C) array of uint8, uint16,
        float32 or float64 (any strides; integers scaled by 255 or 65535), with ``lights``
        (N, 3) unit directions toward the lights and optional ``intensities`` (N,) or (N, C)
        and ``mask`` (H, W).
    light_positions, camera, distance, light_axes, light_anisotropy: near lights instead of
        ``lights`` (LED positions (N, 3) in mm, camera frame; ``camera`` the 3x3 intrinsics K in
        pixels or a K.txt path; ``distance`` the object's mean distance in mm; optional axes
        and anisotropy; ``intensities`` then the LEDs' radiances at 1 mm), or ``camera`` and
        ``distance`` with distant ``lights``: see :meth:`Capture.from_arrays`. Then ``depth`` is
        Z in mm along the optical axis and ``report["near"]`` gives the rounds of the
        alternation.
    method: ``l2``, ``coleman-jain``, ``barsky-petrou`` or ``recursive``.
    sigma: image noise per channel, full scale 1 (None: estimated from the images).
    relative_noise: model error as a share of a pixel's mean intensity (kappa), e.g. 0.01;
        None (default): measured from the capture, the light-to-light part of its misfit
        (reported as ``detection.kappa_measured``; 0.01 with fewer than five lights or with
        near lights).
    confidence: confidence of the chi-square test of non-Lambertian pixels.
    min_kept_share: the attribution keeps at least this share of the lights (and three).
    batch_alpha: family-wise error rate for removing several dark readings in one step.
    shadow_sigmas, shadow_ratio: a too-dark reading is a shadow below
        shadow_sigmas * sigma_p + shadow_ratio * (the pixel's mean intensity).
    noise_estimate: ``images`` (sensor noise from the images) or ``residuals``.
    noise_refinements: rounds of noise re-estimation (``residuals`` only).
    max_iterations: the recursive method's iteration limit.
    change_tolerance: stop when the usable-light sets change at fewer than this share of pixels.
    surface_prior: the recursive method's final estimate takes the integrated surface's normal
        as a prior with this angular standard deviation in degrees (0: least squares alone).
    refine_lights: refine the lights from the readings first (distant lights, six or more;
        ``report["input"]["light_refinement"]`` says how far each moved); the Capture object
        keeps its lights (a copy of its samples is refined for the call).
    fallback: completion of pixels with fewer than three lights: ``neighbours`` or ``brightest``.
    integrator: ``poisson`` (any mask), ``dct``, ``fft`` or ``paths``.
    max_slope: cap on |dz/dx|, |dz/dy| in pixel units per pixel.
    unreliable_weight: integration weight of unreliable pixels (reliable ones weigh 1).
    detect: run the chi-square test for its maps with methods that do not need it.
    integrate: integrate the normals into depth and curl.
    memory_limit: the memory budget (bytes, or a size such as ``"4G"``; None: half of the memory
        available), as for :func:`run`; an array given here is already held whole in memory.
    num_threads: cap on worker threads (None: all cores); several workers can share a node.
    progress: ``progress(stage, done, total)``, called from this thread while the work runs.
    """
    params = dict(
        method=method,
        sigma=sigma,
        relative_noise=relative_noise,
        confidence=confidence,
        min_kept_share=min_kept_share,
        batch_alpha=batch_alpha,
        shadow_sigmas=shadow_sigmas,
        shadow_ratio=shadow_ratio,
        noise_estimate=noise_estimate,
        noise_refinements=noise_refinements,
        max_iterations=max_iterations,
        change_tolerance=change_tolerance,
        surface_prior=surface_prior,
        refine_lights=refine_lights,
        fallback=fallback,
        integrator=integrator,
        max_slope=max_slope,
        unreliable_weight=unreliable_weight,
        detect=detect,
        integrate=integrate,
        memory_limit=memory_limit,
    )
    near = dict(
        light_positions=light_positions,
        camera=camera,
        distance=distance,
        light_axes=light_axes,
        light_anisotropy=light_anisotropy,
    )
    if isinstance(images, Capture):
        given = [k for k, v in near.items() if v is not None]
        if lights is not None or intensities is not None or mask is not None or given:
            raise PhotostereoError(
                "images is a Capture: it carries its own lights, intensities, mask, camera "
                "and distance"
            )
        capture = images
    else:
        if lights is None and light_positions is None:
            raise PhotostereoError(
                "lights: an image array needs (N, 3) light directions, or light_positions "
                "(N, 3) in mm with camera and distance for near lights"
            )
        capture = Capture.from_arrays(images, lights, intensities, mask, **near)
    out = _native.reconstruct(capture._native, params, num_threads, progress)
    report = json.loads(out.pop("report_json"))
    return Reconstruction(report=report, **out)


def run(
    path: Union[PathLike, Sequence[PathLike]],
    output: PathLike,
    *,
    lights: Optional[PathLike] = None,
    intensities: Optional[PathLike] = None,
    mask: Optional[PathLike] = None,
    gt: Optional[PathLike] = None,
    error_map: bool = False,
    light_subset: Optional[str] = None,
    force: bool = False,
    distance: Optional[float] = None,
    camera: Any = None,
    num_threads: Optional[int] = None,
    progress: Optional[ProgressCallback] = None,
    **params: Any,
) -> Dict[str, Any]:
    """The command line's ``run``: reads the capture at ``path`` (any layout, as
    :func:`load_capture`), reconstructs it, scores it against ``gt`` when given, and writes the
    output folder ``output`` atomically (normals, albedo, maps, depth, meshes, report.json).
    ``params`` are :func:`reconstruct`'s keywords (``method=``, ``confidence=``...) and
    ``memory_limit=`` (bytes, or a size such as ``"4G"`` or ``"500M"``; default: half of the
    memory available): a capture whose samples do not fit as float32 is held in tiles at the
    images' precision, in memory or in a spill file, with the same results (``report["memory"]``
    gives the plan and the peak). Returns the report. ``force`` replaces an existing output
    folder. ``distance`` (mm) and ``camera`` (a 3x3 K in pixels or a K.txt path) act as in
    :func:`load_capture`: on a near-light folder the depth is Z in mm and ``report["near"]``
    gives the rounds."""
    full = defaults()
    unknown = sorted(set(params) - set(full))
    if unknown:
        raise TypeError(f"run() got unexpected keyword argument(s): {', '.join(unknown)}")
    full.update(params)
    report = _native.run(
        _paths(path),
        os.fspath(output),
        full,
        _opt_path(lights),
        _opt_path(intensities),
        _opt_path(mask),
        _opt_path(gt),
        error_map,
        light_subset,
        force,
        num_threads,
        progress,
        None if distance is None else float(distance),
        _camera_arg(camera),
    )
    return json.loads(report)


def integrate(
    normals: np.ndarray,
    mask: Any = None,
    method: str = "poisson",
    weights: Optional[np.ndarray] = None,
    *,
    max_slope: float = 20.0,
    num_threads: Optional[int] = None,
) -> np.ndarray:
    """Integrates an (H, W, 3) normal map into (H, W) float32 depth (pixel units toward the
    camera, NaN outside the mask). ``mask`` (H, W) defaults to the non-zero normals;
    ``weights`` (H, W) in 0..1 lower the say of unreliable pixels (``poisson`` honours any mask
    and weights; ``dct`` and ``fft`` work on the full rectangle)."""
    n = np.asarray(normals, dtype=np.float32)
    if n.ndim != 3:
        raise PhotostereoError(f"normals: expected an (H, W, 3) array, got shape {n.shape}")
    m = None if mask is None else _mask_array(mask)
    w = None if weights is None else np.asarray(weights, dtype=np.float32)
    return _native.integrate(n, m, method, w, max_slope, num_threads)


def angular_error(
    normals: np.ndarray, truth: np.ndarray, mask: Any = None
) -> Dict[str, Any]:
    """Angular error in degrees between (H, W, 3) normals and ground truth, over the mask where
    the truth is non-zero: ``mean_deg``, ``median_deg``, ``under_5deg``/``10``/``20`` (shares),
    ``pixels``, ``missing`` (zero predictions, counted as 90 degrees), and ``map`` (H, W)
    float32 (NaN where not evaluated)."""
    n = np.asarray(normals, dtype=np.float32)
    t = np.asarray(truth, dtype=np.float32)
    if n.ndim != 3 or t.ndim != 3:
        raise PhotostereoError(
            f"normals {n.shape} and truth {t.shape}: expected (H, W, 3) arrays"
        )
    m = None if mask is None else _mask_array(mask)
    stats, error_map = _native.angular_error(n, t, m)
    out = json.loads(stats)
    out["map"] = error_map
    return out


def calibrate(images: np.ndarray, mask: Any = None) -> Dict[str, Any]:
    """Light directions from images of a mirror sphere: (N, H, W) or (N, H, W, C) images
    (integers scaled by their full scale) and an optional (H, W) mask of the sphere. Returns
    ``lights`` (N, 3) (NaN where no highlight was found), ``confidence`` (N,) in 0..1, and the
    full calibration (``sphere``, ``per_light`` highlights, ``warnings``). Raises
    PhotostereoError when no light's highlight is confident (a matte sphere, noise)."""
    stack = _as_stack(images)
    if stack.dtype == np.uint8:
        stack = stack.astype(np.float32) / 255.0
    elif stack.dtype == np.uint16:
        stack = stack.astype(np.float32) / 65535.0
    stack = np.asarray(stack, dtype=np.float32)
    m = None if mask is None else _mask_array(mask)
    cal = json.loads(_native.calibrate(stack, m))
    per_light = cal.pop("lights")
    cal["per_light"] = per_light
    cal["lights"] = np.array(
        [p["direction"] if p["direction"] is not None else [np.nan] * 3 for p in per_light],
        dtype=np.float64,
    ).reshape(-1, 3)
    cal["confidence"] = np.array([p["confidence"] for p in per_light], dtype=np.float64)
    return cal


def render_scene(
    name: str,
    rig: str = "square4",
    size: int = 128,
    *,
    brdf: str = "blinn-phong",
    noise: float = 0.005,
    seed: int = 1,
) -> Tuple[np.ndarray, np.ndarray, np.ndarray, Dict[str, np.ndarray]]:
    """Renders a built-in scene (``sphere``, ``cavities``, ``blocks``, ``terrain``, ``bumps``,
    ``face``) under a rig (``square4``, ``ring8``, ``dome-N``...) at size x size pixels with
    16-bit quantisation and Gaussian noise ``noise`` (full scale 1). Returns ``(images (N, S,
    S, 3) float32, lights (N, 3), mask (S, S), truth)`` with ``truth`` a dict of ``normals``
    (S, S, 3), ``depth`` (S, S) and per-light ``shadows`` (N, S, S).

    The near-light rigs ``near-ring`` (12 LEDs around the lens), ``near-square`` and
    ``near-dome`` place the object about 300 mm in front of a pinhole camera (``brdf``
    ``lambert`` or ``blinn-phong``, textured albedo): ``lights`` is then the distant
    approximation (directions at the object's centre), ``truth["depth"]`` is Z in mm, and
    ``truth["near"]`` holds the rig as :func:`reconstruct` takes it: ``light_positions``
    (N, 3) mm, ``light_axes``, ``light_anisotropy``, ``intensities`` (radiance at 1 mm),
    ``camera`` (3x3 K) and ``distance`` (mm)."""
    images, lights, mask, normals, depth, shadows, near = _native.render_scene(
        name, rig, size, brdf, noise, seed
    )
    truth = {"normals": normals, "depth": depth, "shadows": shadows}
    if near is not None:
        truth["near"] = dict(near)
    return images, lights, mask, truth


def synth(
    name: str,
    output: PathLike,
    rig: str = "square4",
    size: int = 128,
    *,
    brdf: str = "blinn-phong",
    noise: float = 0.005,
    seed: int = 1,
    force: bool = False,
) -> str:
    """Renders a built-in scene into a DiLiGenT-layout folder with ground truth (``gt/``), as
    ``photostereo synth`` does (a near rig writes the near-light layout: ``K.txt``,
    ``light_positions.txt``, ``mean_distance.txt``...). Returns the folder."""
    return _native.synth(name, os.fspath(output), rig, size, brdf, noise, seed, force)


def read_image(path: PathLike) -> np.ndarray:
    """An image file (PNG 8/16-bit, TIFF, EXR) as (H, W, C) float32, integers scaled to [0, 1]."""
    return _native.read_image(os.fspath(path))


def read_normals(path: PathLike) -> np.ndarray:
    """A normal map (.npy, DiLiGenT .mat, 16-bit normal-map PNG) as (H, W, 3) float32."""
    return _native.read_normals(os.fspath(path))
