"""photostereo: recursive photometric stereo, numpy in and out.

Per pixel a surface normal and an albedo from images taken from one viewpoint under known
lights, with shadows and highlights found and left out (Argyriou & Petrou's recursive method and
its baselines), then a depth map by integrating the normals. The engine is the Rust library
behind the ``photostereo`` command line; this package is a thin layer over it: the GIL is
released while it works, Ctrl-C raises KeyboardInterrupt, bad input raises PhotostereoError
naming the keyword at fault.

Conventions (the project's CONVENTIONS.md): camera frame x right, y up, z toward the camera;
arrays are row-major with row 0 at the top; normals are unit vectors with n_z > 0; light
directions point from the surface toward the light; integer images are scaled to [0, 1] by
their bit depth; depth is in pixel units toward the camera (in mm with a camera).

Examples
--------
>>> import photostereo as ps
>>> cap = ps.load_capture("catPNG")                                  # doctest: +SKIP
>>> rec = ps.reconstruct(cap, method="recursive", confidence=0.99)   # doctest: +SKIP
>>> rec.normals.shape                                                # doctest: +SKIP
(512, 612, 3)
>>> p = ps.Params(method="l2")
>>> p.detection.confidence
0.95
"""

from __future__ import annotations

import atexit
import os
import pathlib
import textwrap
from typing import TYPE_CHECKING, Any, Callable, Dict, Optional, Sequence, Union

import numpy as np

from . import _native
from ._native import PhotostereoError, __version__
from ._params import DetectionParams, IntegrationParams, Params, RecursiveParams
from ._params import build as _build_params
from ._results import (
    AngularError,
    Calibration,
    NearRig,
    Reconstruction,
    Scene,
    SceneTruth,
)

if TYPE_CHECKING:
    from typing_extensions import Unpack

    from ._native import ParamValues

__all__ = [
    "AngularError",
    "Calibration",
    "Capture",
    "DetectionParams",
    "IntegrationParams",
    "NearRig",
    "Params",
    "PhotostereoError",
    "Reconstruction",
    "RecursiveParams",
    "Scene",
    "SceneTruth",
    "angular_error",
    "calibrate",
    "defaults",
    "integrate",
    "load_capture",
    "read_image",
    "read_normals",
    "reconstruct",
    "render_scene",
    "rti",
    "run",
    "synth",
    "__version__",
]

PathLike = Union[str, "os.PathLike[str]"]
#: ``progress(stage, done, total)``: called from the calling thread while the library works.
ProgressCallback = Callable[[str, int, int], Any]

# A run interrupted by Ctrl-C raises once its worker has stopped and removed the output folder
# it was writing; after a second Ctrl-C it raises at once, and the output folders still being
# written are removed when the interpreter exits.
atexit.register(_native.abandon_pending_outputs)


def defaults() -> Dict[str, Any]:
    """The library's default of every parameter, by name (``Params().to_dict()``)."""
    return dict(_native.defaults())


def _real(values: Any, name: str, dtype: Any) -> np.ndarray:
    """``values`` as an array of ``dtype``; shapes are checked by the library, naming ``name``."""
    try:
        a = np.asarray(values)
        if np.iscomplexobj(a):
            raise TypeError(f"got {a.dtype}")
        with np.errstate(over="ignore", invalid="ignore"):
            return a.astype(dtype, copy=False)
    except (TypeError, ValueError) as e:
        raise PhotostereoError(f"{name}: expected an array of real numbers ({e})") from None
    except MemoryError:
        shape = getattr(values, "shape", "?")
        raise PhotostereoError(
            f"{name}: an array of shape {shape} does not fit in memory as {np.dtype(dtype).name}"
        ) from None


def _floats(values: Any, name: str) -> Optional[np.ndarray]:
    return None if values is None else _real(values, name, np.float64)


def _booleans(values: Any, name: str) -> Optional[np.ndarray]:
    """``values`` as a bool array, non-zero meaning True."""
    if values is None:
        return None
    try:
        a = np.asarray(values)
        return a if a.dtype == np.bool_ else a != 0
    except (TypeError, ValueError) as e:
        raise PhotostereoError(f"{name}: expected an array ({e})") from None


def _normals(values: Any, name: str) -> np.ndarray:
    return _real(values, name, np.float32)


def _camera(camera: Any) -> Any:
    """``camera=`` as the native module takes it: a path, or K as a float64 array."""
    if camera is None or isinstance(camera, (str, os.PathLike)):
        return None if camera is None else os.fspath(camera)
    return _floats(camera, "camera")


def _paths(path: Union[PathLike, Sequence[PathLike]]) -> list:
    if isinstance(path, (str, os.PathLike)):
        return [os.fspath(path)]
    return [os.fspath(p) for p in path]


def _path(p: Optional[PathLike]) -> Optional[str]:
    return None if p is None else os.fspath(p)


class Capture:
    """Images, lights and mask of one capture, held by the library.

    Only the pixels inside the mask are stored, divided by their light's intensity (the
    library's sample store, whole or in tiles within the memory budget); :func:`reconstruct`
    uses that store without copying it. Build one with :func:`load_capture` (files) or
    :meth:`Capture.from_arrays` (numpy). A capture pickles whole, near lights and camera
    included, so it can be shipped to Dask or Ray workers.
    """

    __slots__ = ("_native",)

    def __init__(self, native: "_native.NativeCapture"):
        self._native = native

    @classmethod
    def from_arrays(
        cls,
        images: Any,
        lights: Any = None,
        intensities: Any = None,
        mask: Any = None,
        *,
        light_positions: Any = None,
        camera: Any = None,
        distance: Optional[float] = None,
        light_axes: Any = None,
        light_anisotropy: Any = None,
        memory_limit: Union[int, str, None] = None,
    ) -> "Capture":
        """A capture from arrays.

        Parameters
        ----------
        images : array of uint8, uint16, float32 or float64, shape (N, H, W) or (N, H, W, C)
            Any strides (a transposed or sliced view is read without a copy); integers are
            scaled to [0, 1] by 255 or 65535; C is 1 or 3.
        lights : array_like, shape (N, 3)
            Unit directions toward the distant lights, camera frame.
        intensities : array_like, shape (N,) or (N, C), optional
            Each light's intensity (near lights: each LED's radiance along its axis at 1 mm).
        mask : array_like, shape (H, W) or (H, W, 1|3|4), optional
            Non-zero inside the object (default: the whole frame).
        light_positions : array_like, shape (N, 3), optional
            Near lights instead of ``lights``: LED positions in mm, camera frame, camera
            centre at the origin (the object at z < 0). Needs ``camera`` and ``distance``.
        camera : array_like, shape (3, 3), or path, optional
            The intrinsics K in pixels, or the path of a K.txt. With distant ``lights`` and
            ``distance``, the depth is integrated through the camera (mm).
        distance : float, optional
            The object's mean distance along the optical axis, mm.
        light_axes : array_like, shape (N, 3), optional
            The direction each LED points (default: toward (0, 0, -distance)).
        light_anisotropy : array_like, shape (N,), optional
            mu per LED: radiance falls as cos^mu off the axis (default 0).
        memory_limit : int or str, optional
            The memory budget (bytes, or ``"4G"``; default half of the memory available), as
            for files: samples that do not fit as float32 are held in tiles at the array's
            precision, and a budget too small for the capture is refused.

        Raises
        ------
        PhotostereoError
            Shapes, counts, sizes beyond the image limits or the budget, non-finite samples,
            an empty mask, lights that do not determine a normal.
        """
        return cls(
            _native.capture_from_stack(
                np.asarray(images),
                _floats(lights, "lights"),
                _floats(intensities, "intensities"),
                _booleans(mask, "mask"),
                _floats(light_positions, "light_positions"),
                _camera(camera),
                distance,
                _floats(light_axes, "light_axes"),
                _floats(light_anisotropy, "light_anisotropy"),
                memory_limit,
            )
        )

    @property
    def width(self) -> int:
        """Columns W."""
        return self._native.width

    @property
    def height(self) -> int:
        """Rows H."""
        return self._native.height

    @property
    def channels(self) -> int:
        """Channels C per image (1 or 3)."""
        return self._native.channels

    @property
    def n_lights(self) -> int:
        """Lights N (= images)."""
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
        """(N, 3) float64 unit directions toward the lights, camera frame (near lights: toward
        each LED from the object's centre)."""
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
    def camera(self) -> Optional[np.ndarray]:
        """(3, 3) float64 intrinsics K of the capture's camera, or None (orthographic)."""
        return self._native.camera()

    @property
    def distance(self) -> Optional[float]:
        """The object's mean distance in mm, with a camera; else None."""
        return self._native.distance

    @property
    def near(self) -> Optional[Dict[str, np.ndarray]]:
        """The near-light rig (``light_positions`` (N, 3) mm, ``light_axes`` (N, 3),
        ``light_anisotropy`` (N,)), or None for distant lights."""
        near = self._native.near()
        return None if near is None else dict(near)

    @property
    def notes(self) -> list:
        """Remarks made while loading (normalised lights, resolved paths...)."""
        return list(self._native.notes)

    def __reduce__(self):
        return (Capture, (self._native,))

    def __repr__(self) -> str:
        kind = ", near lights" if self._native.near() is not None else ""
        return (
            f"Capture({self.n_lights} lights, {self.width}x{self.height}, "
            f"{self.channels} channel(s), {self.bit_depth}-bit{kind})"
        )


def load_capture(
    path: Union[PathLike, Sequence[PathLike]],
    lights: Optional[PathLike] = None,
    intensities: Optional[PathLike] = None,
    mask: Optional[PathLike] = None,
    *,
    distance: Optional[float] = None,
    camera: Any = None,
    memory_limit: Union[int, str, None] = None,
    num_threads: Optional[int] = None,
    response: Optional[str] = None,
    ambient: Optional[PathLike] = None,
    dark: Optional[PathLike] = None,
    flat: Optional[PathLike] = None,
    ignore_exposure: bool = False,
) -> Capture:
    """Reads a capture from files, in every layout the command line reads.

    Parameters
    ----------
    path : path or sequence of paths
        A DiLiGenT-layout folder, a near-light folder (``light_positions.txt``, ``K.txt``...),
        an ``.lp`` file, a list file (with ``lights``), or image files (with ``lights``).
    lights, intensities, mask : path, optional
        Replace the layout's own light directions, intensities and mask.
    distance : float, optional
        For one folder: the object's mean distance in mm (replaces ``mean_distance.txt``).
    camera : array_like, shape (3, 3), or path, optional
        For one folder: K in pixels, or a K.txt (replaces ``K.txt``); on a folder of distant
        lights, with ``distance``, the depth is then integrated in mm.
    memory_limit : int or str, optional
        The memory budget (bytes, or ``"4G"``; default half of the memory available).
    num_threads : int, optional
        Cap on the decoding threads (None: all cores).
%(capture_options)s
    Returns
    -------
    Capture
    """
    return Capture(
        _native.load_capture(
            _paths(path),
            _path(lights),
            _path(intensities),
            _path(mask),
            num_threads,
            distance,
            _camera(camera),
            memory_limit,
            response,
            _path(ambient),
            _path(dark),
            _path(flat),
            ignore_exposure,
        )
    )


def reconstruct(
    images: Union[Capture, np.ndarray],
    lights: Any = None,
    mask: Any = None,
    *,
    params: Optional[Params] = None,
    intensities: Any = None,
    light_positions: Any = None,
    camera: Any = None,
    distance: Optional[float] = None,
    light_axes: Any = None,
    light_anisotropy: Any = None,
    num_threads: Optional[int] = None,
    progress: Optional[ProgressCallback] = None,
    **overrides: "Unpack[ParamValues]",
) -> Reconstruction:
    """Normals, albedo, light statuses, the detector's maps and depth of a capture.

    Parameters
    ----------
    images : Capture or array, shape (N, H, W) or (N, H, W, C)
        A :class:`Capture`, or an array of uint8, uint16, float32 or float64 (any strides)
        with ``lights`` (and the other capture keywords of :meth:`Capture.from_arrays`).
    lights : array_like, shape (N, 3), optional
        Unit directions toward the lights.
    mask : array_like, shape (H, W), optional
        Non-zero inside the object.
    params : Params, optional
        The parameters (default: the library's); ``overrides`` apply on top.
    intensities, light_positions, camera, distance, light_axes, light_anisotropy : optional
        As for :meth:`Capture.from_arrays` (near lights, a camera).
    num_threads : int, optional
        Cap on the worker threads (None: all cores); several workers can share a node.
    progress : callable, optional
        ``progress(stage, done, total)``, called from this thread while the work runs.
    **overrides
        Any parameter of :class:`Params` by name (``method="l2"``, ``confidence=0.99``,
        ``memory_limit="4G"``...); ``photostereo.defaults()`` lists them with their defaults.

    Returns
    -------
    Reconstruction

    Raises
    ------
    PhotostereoError
        A bad value, shape or size, naming the keyword; a budget too small.
    TypeError
        A keyword that names no parameter.
    """
    values = _build_params(params, overrides, "reconstruct")
    if isinstance(images, Capture):
        extra = dict(
            lights=lights,
            mask=mask,
            intensities=intensities,
            light_positions=light_positions,
            camera=camera,
            distance=distance,
            light_axes=light_axes,
            light_anisotropy=light_anisotropy,
        )
        given = [k for k, v in extra.items() if v is not None]
        if given:
            raise PhotostereoError(
                f"{', '.join(given)}: images is a Capture, which carries its own lights, "
                "intensities, mask, camera and distance"
            )
        capture = images
    else:
        capture = Capture.from_arrays(
            images,
            lights,
            intensities,
            mask,
            light_positions=light_positions,
            camera=camera,
            distance=distance,
            light_axes=light_axes,
            light_anisotropy=light_anisotropy,
            memory_limit=values["memory_limit"],
        )
    out = _native.reconstruct(capture._native, values, num_threads, progress)
    return Reconstruction(**out)


def run(
    path: Union[PathLike, Sequence[PathLike]],
    output: PathLike,
    *,
    params: Optional[Params] = None,
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
    response: Optional[str] = None,
    ambient: Optional[PathLike] = None,
    dark: Optional[PathLike] = None,
    flat: Optional[PathLike] = None,
    ignore_exposure: bool = False,
    rti: Optional[str] = None,
    **overrides: "Unpack[ParamValues]",
) -> Dict[str, Any]:
    """The command line's ``run``: reads the capture at ``path`` (any layout, as
    :func:`load_capture`), reconstructs it, scores it against ``gt`` when given, and writes the
    output folder ``output`` atomically (normals, albedo, maps, depth, meshes, report.json).

    Parameters
    ----------
    path, lights, intensities, mask, distance, camera
        As for :func:`load_capture`.
    response, ambient, dark, flat, ignore_exposure
        As for :func:`load_capture` (report.json's ``photometry`` says per image what was
        done to make it linear).
    output : path
        The output folder; an existing one is refused unless ``force`` (and only a folder
        photostereo's ``run`` wrote, or an empty one, is replaced).
    params, **overrides
        As for :func:`reconstruct`; ``memory_limit`` also sets where the samples live
        (``report["memory"]`` gives the plan and the peak).
    gt : path, optional
        Ground-truth normals (.npy, DiLiGenT .mat, 16-bit PNG): adds ``report["error"]``.
    error_map : bool
        Also write error_map.png (needs ``gt``).
    light_subset : str, optional
        ``"square"``, ``"square:SLANT"`` or 1-based indices such as ``"1,5,9,13"``.
    rti : str, optional
        Also fit this relightable-image basis (as :func:`rti`'s ``basis``) to the same readings
        and write its files into ``output`` (the command line's ``run --rti``); its figures are
        ``report["rti"]``.

    Returns
    -------
    dict
        The content of report.json.

    Raises
    ------
    PhotostereoError
        A bad value, file or output folder, naming the keyword, file or line at fault.
    KeyboardInterrupt
        On Ctrl-C, once the library has stopped at its next stage boundary and removed the
        output folder it was writing (a second Ctrl-C raises at once).
    """
    values = _build_params(params, overrides, "run")
    return _native.run(
        _paths(path),
        os.fspath(output),
        values,
        _path(lights),
        _path(intensities),
        _path(mask),
        _path(gt),
        error_map,
        light_subset,
        force,
        num_threads,
        progress,
        distance,
        _camera(camera),
        response,
        _path(ambient),
        _path(dark),
        _path(flat),
        ignore_exposure,
        rti,
    )


def rti(
    path: Union[PathLike, Sequence[PathLike]],
    output: PathLike,
    *,
    basis: str = "hsh3",
    lights: Optional[PathLike] = None,
    intensities: Optional[PathLike] = None,
    mask: Optional[PathLike] = None,
    exclude_unreliable: bool = False,
    memory_limit: Optional[int] = None,
    force: bool = False,
    num_threads: Optional[int] = None,
    progress: Optional[ProgressCallback] = None,
    response: Optional[str] = None,
    ambient: Optional[PathLike] = None,
    dark: Optional[PathLike] = None,
    flat: Optional[PathLike] = None,
    ignore_exposure: bool = False,
    iiif: Optional[str] = None,
    ridge: Optional[float] = None,
) -> Dict[str, Any]:
    """The command line's ``rti``: fits a relightable image to the capture at ``path`` (any
    layout, as :func:`load_capture`; distant lights) and writes the output folder ``output``
    atomically: the viewer file (``image.ptm``, ``image.rti``, or ``basis.npy`` for rbf),
    relight's web folder ``relight/`` for OpenLIME, ``coefficients.npy`` and report.json.

    Parameters
    ----------
    basis : str
        ``"ptm"``, ``"ptm-rgb"``, ``"hsh2"``, ``"hsh3"`` or ``"rbf"``.
    exclude_unreliable : bool
        Run the recursive method first and leave its shadows and highlights, and the
        readings the camera clipped at full scale, out of each pixel's fit (not with
        ``"rbf"``).
    memory_limit : int, optional
        Memory budget in bytes (default: half the memory available), as ``run``'s.
    force : bool
        Replace an existing ``rti`` output folder.
    response, ambient, dark, flat, ignore_exposure
        As for :func:`load_capture`.
    iiif : str, optional
        Also write each plane image of ``relight/`` as IIIF Image API 3.0 level-0 static
        tiles, ``relight/plane_G/``, served at this ``http://`` or ``https://`` base URI (the
        command line's ``rti --iiif BASE_URI``).
    ridge : float, optional
        The ridge weight per light, λ / N, of the ptm and hsh fits, toward zero (0: plain
        least squares); default: chosen from the data by leave-one-out error, for hsh also
        among weights toward PTM's fit (the command line's ``rti --ridge auto``). Not with
        ``"rbf"``.

    Returns
    -------
    dict
        The content of report.json (``leave_one_out`` holds the leave-one-out RMSE per light
        and its mean, ``lambertian_reference`` the same for the normals × albedo).

    Raises
    ------
    PhotostereoError
        A bad value, file or output folder, naming the keyword, file or line at fault.
    """
    return _native.rti(
        _paths(path),
        os.fspath(output),
        basis,
        _path(lights),
        _path(intensities),
        _path(mask),
        exclude_unreliable,
        memory_limit,
        force,
        num_threads,
        progress,
        response,
        _path(ambient),
        _path(dark),
        _path(flat),
        ignore_exposure,
        iiif,
        ridge,
    )


def integrate(
    normals: Any,
    mask: Any = None,
    method: Optional[str] = None,
    weights: Any = None,
    *,
    max_slope: float = _native.defaults()["max_slope"],
    camera: Any = None,
    distance: Optional[float] = None,
    num_threads: Optional[int] = None,
) -> np.ndarray:
    """Integrates a normal map into depth.

    Parameters
    ----------
    normals : array_like, shape (H, W, 3)
        Normals in the camera frame.
    mask : array_like, shape (H, W), optional
        Pixels to integrate (default: the non-zero normals, less a uniform background that is
        not of unit length).
    method : {"bilateral", "poisson", "dct", "fft", "paths"}, optional
        The integrator (default: the library's, ``bilateral``). ``bilateral`` keeps depth jumps
        on any mask; ``poisson`` honours any mask and weights; ``dct`` and ``fft`` work on the
        full rectangle.
    weights : array_like, shape (H, W), optional
        Weights in 0..1 that lower the say of unreliable pixels.
    max_slope : float
        Cap on |dz/dx| and |dz/dy| in pixel units per pixel.
    camera : array_like, shape (3, 3), or str, optional
        A pinhole camera K (pixels) or the path of a K.txt: the normals are integrated through
        it (log-depth) and the result is Z in mm; needs ``distance``.
    distance : float, optional
        With ``camera``: the object's mean distance along the optical axis, mm.
    num_threads : int, optional
        Cap on the worker threads.

    Returns
    -------
    ndarray of float32, shape (H, W)
        Height toward the camera in pixel units (Z in mm with a camera); NaN outside the
        integrated pixels.
    """
    return _native.integrate(
        _normals(normals, "normals"),
        _booleans(mask, "mask"),
        method,
        None if weights is None else _normals(weights, "weights"),
        max_slope,
        camera,
        distance,
        num_threads,
    )


def angular_error(normals: Any, truth: Any, mask: Any = None) -> AngularError:
    """The angular error of normals against ground truth (CONVENTIONS.md, "Error metric").

    Parameters
    ----------
    normals, truth : array_like, shape (H, W, 3)
        The normals and the ground truth (zero where unknown).
    mask : array_like, shape (H, W), optional
        Pixels to evaluate (default: every pixel with non-zero truth).

    Returns
    -------
    AngularError
        Mean, median, shares under 5/10/20 degrees and the (H, W) error map.
    """
    stats, error_map = _native.angular_error(
        _normals(normals, "normals"), _normals(truth, "truth"), _booleans(mask, "mask")
    )
    return AngularError(map=error_map, **stats)


def calibrate(images: Any, mask: Any = None) -> Calibration:
    """Light directions from images of a mirror sphere.

    Parameters
    ----------
    images : array, shape (N, H, W) or (N, H, W, C)
        uint8, uint16, float32 or float64 images (integers scaled by their full scale).
    mask : array_like, shape (H, W), optional
        The sphere (default: detected from the images).

    Returns
    -------
    Calibration

    Raises
    ------
    PhotostereoError
        When no light's highlight is confident (a matte sphere, noise).
    """
    out = _native.calibrate(np.asarray(images), _booleans(mask, "mask"))
    return Calibration(**out)


def render_scene(
    name: str,
    rig: str = "square4",
    size: int = 128,
    *,
    brdf: str = "blinn-phong",
    noise: float = 0.005,
    seed: int = 1,
) -> Scene:
    """Renders a built-in scene with its ground truth.

    Parameters
    ----------
    name : str
        ``sphere``, ``cavities``, ``blocks``, ``terrain``, ``bumps`` or ``face``.
    rig : str
        ``square4``, ``ring8``, ``dome-N``...; the near-light rigs ``near-ring`` (12 LEDs
        around the lens), ``near-square`` and ``near-dome`` place the object about 300 mm in
        front of a pinhole camera (``truth.near`` holds the rig, ``truth.depth`` is Z in mm).
    size : int
        Pixels per side, 8 to 8192.
    brdf : str
        ``lambert`` or ``blinn-phong``.
    noise : float
        Gaussian noise, full scale 1 (16-bit quantisation on top).
    seed : int
        The noise's seed.

    Returns
    -------
    Scene
        ``images, lights, mask, truth``.
    """
    images, lights, mask, normals, depth, shadows, near = _native.render_scene(
        name, rig, size, brdf, noise, seed
    )
    rig_ = None if near is None else NearRig(**near)
    return Scene(images, lights, mask, SceneTruth(normals, depth, shadows, rig_))


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
) -> pathlib.Path:
    """Renders a built-in scene (as :func:`render_scene`) into a capture folder with ground
    truth (``gt/``), as ``photostereo synth`` does; a near rig writes the near-light layout
    (``K.txt``, ``light_positions.txt``, ``mean_distance.txt``...). Returns the folder."""
    return pathlib.Path(
        _native.synth(name, os.fspath(output), rig, size, brdf, noise, seed, force)
    )


def read_image(path: PathLike) -> np.ndarray:
    """An image file (PNG 8/16-bit, TIFF, EXR, JPEG, camera RAW) as (H, W, C) float32, integers
    scaled to [0, 1]; the file's encoded values (a camera RAW's are linear: black level
    subtracted, white level at 1, one pixel per 2x2 Bayer block, no white balance)."""
    return _native.read_image(os.fspath(path))


def _capture_options_doc() -> str:
    """numpydoc entries for the capture-reading keywords, from the library's one definition
    of their names and meanings (``_native.capture_options()``)."""
    kinds = {"MODE": "str, optional", "IMAGE": "path, optional", "": "bool, default False"}
    out = []
    for o in _native.capture_options():
        out.append(f"    {o['name']} : {kinds[o['value']]}")
        out.extend(textwrap.wrap(o["doc"], 92, initial_indent=" " * 8, subsequent_indent=" " * 8))
    return "\n".join(out) + "\n"


load_capture.__doc__ = (load_capture.__doc__ or "").replace(
    "%(capture_options)s\n", _capture_options_doc()
)


def read_normals(path: PathLike) -> np.ndarray:
    """A normal map (.npy, DiLiGenT .mat, 16-bit normal-map PNG) as (H, W, 3) float32."""
    return _native.read_normals(os.fspath(path))
