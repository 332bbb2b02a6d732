"""Type stubs of photostereo's native module (Rust, pyo3). Use the package ``photostereo``,
whose functions wrap these with typed keywords and the library's defaults; shapes are (N lights,
H rows, W columns, C channels), arrays row-major, the camera frame x right, y up, z toward the
camera."""

from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple

import numpy as np

__version__: str

class PhotostereoError(ValueError):
    """Bad input: the message names the file, line or parameter at fault and what was expected."""

class NativeCapture:
    """A capture held by the library: the mask pixels' samples, divided by the light
    intensities, with the lights and the mask."""

    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...
    @property
    def channels(self) -> int: ...
    @property
    def n_lights(self) -> int: ...
    @property
    def bit_depth(self) -> int:
        """8 or 16 for integer sources, 32 for float data."""
    @property
    def notes(self) -> List[str]: ...
    @property
    def sources(self) -> List[str]: ...
    def lights(self) -> np.ndarray:
        """(N, 3) float64 unit directions toward the lights."""
    def intensities(self) -> np.ndarray:
        """(N, C) float64 light intensities."""
    def mask(self) -> np.ndarray:
        """(H, W) bool."""
    def images(self) -> np.ndarray:
        """(N, H, W, C) float32 images as read (full scale 1), zero outside the mask."""

def defaults() -> Dict[str, Any]:
    """The library's default of every reconstruction keyword."""

def methods() -> List[str]:
    """The names ``method=`` accepts: l2, coleman-jain, barsky-petrou, recursive."""

def load_capture(
    inputs: Sequence[str],
    lights: Optional[str] = None,
    intensities: Optional[str] = None,
    mask: Optional[str] = None,
    num_threads: Optional[int] = None,
    distance: Optional[float] = None,
    camera: Optional[Any] = None,
) -> NativeCapture:
    """A DiLiGenT folder, a near-light folder, a list file (with lights) or image files (with
    lights). For one folder, ``distance`` (mm) replaces mean_distance.txt and ``camera`` (a K.txt
    path or a (3, 3) float64 K in pixels) replaces K.txt."""

def capture_from_stack(
    images: np.ndarray,
    lights: Optional[np.ndarray],
    intensities: Optional[np.ndarray] = None,
    mask: Optional[np.ndarray] = None,
    light_positions: Optional[np.ndarray] = None,
    camera: Optional[Any] = None,
    distance: Optional[float] = None,
    light_axes: Optional[np.ndarray] = None,
    light_anisotropy: Optional[List[float]] = None,
) -> NativeCapture:
    """images: (N, H, W, C) uint8, uint16, float32 or float64, any strides; lights (N, 3)
    float64; intensities (N, C) float64; mask (H, W) bool. Read once, GIL released. Near lights:
    light_positions (N, 3) mm instead of lights, with camera (a K.txt path or a (3, 3) float64
    K), distance (mm), optional light_axes (N, 3) and light_anisotropy (N,); intensities are
    then radiances at 1 mm. Distant lights with camera and distance integrate in mm."""

def reconstruct(
    capture: NativeCapture,
    params: Dict[str, Any],
    num_threads: Optional[int] = None,
    progress: Optional[Callable[[str, int, int], Any]] = None,
) -> Dict[str, Any]:
    """Every keyword of ``defaults()`` in ``params``. Returns the maps (normals (H, W, 3),
    albedo (H, W, C), light_status (N, H, W), residual, unreliable, depth, curl, trust, mask,
    highlight, fewer_than_three) and ``report_json``."""

def run(
    inputs: Sequence[str],
    output: str,
    params: Dict[str, Any],
    lights: Optional[str] = None,
    intensities: Optional[str] = None,
    mask: Optional[str] = None,
    gt: Optional[str] = None,
    error_map: bool = False,
    light_subset: Optional[str] = None,
    force: bool = False,
    num_threads: Optional[int] = None,
    progress: Optional[Callable[[str, int, int], Any]] = None,
    distance: Optional[float] = None,
    camera: Optional[Any] = None,
) -> str:
    """The command line's ``run``; returns report.json's content. ``distance`` and ``camera``
    as in ``load_capture``."""

def integrate(
    normals: np.ndarray,
    mask: Optional[np.ndarray] = None,
    method: str = "poisson",
    weights: Optional[np.ndarray] = None,
    max_slope: Optional[float] = None,
    num_threads: Optional[int] = None,
) -> np.ndarray:
    """(H, W, 3) float32 normals to (H, W) float32 depth in pixel units, NaN outside the mask."""

def angular_error(
    normals: np.ndarray, truth: np.ndarray, mask: Optional[np.ndarray] = None
) -> Tuple[str, np.ndarray]:
    """(figures as JSON, (H, W) error map in degrees)."""

def calibrate(images: np.ndarray, mask: Optional[np.ndarray] = None) -> str:
    """(N, H, W, C) float32 mirror-sphere images; the calibration as JSON."""

def render_scene(
    name: str,
    rig: str = "square4",
    size: int = 128,
    brdf: str = "blinn-phong",
    noise: float = 0.005,
    seed: int = 1,
) -> Tuple[
    np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, Optional[Dict[str, Any]]
]:
    """(images, lights, mask, truth normals, truth depth, shadows, near): ``near`` is None for
    distant rigs; for near-ring, near-square and near-dome a dict of light_positions (N, 3) mm,
    light_axes (N, 3), light_anisotropy (N,), intensities (N, 3) radiance at 1 mm, camera (3, 3)
    K and distance (mm); the depth is then Z in mm."""

def synth(
    name: str,
    output: str,
    rig: str = "square4",
    size: int = 128,
    brdf: str = "blinn-phong",
    noise: float = 0.005,
    seed: int = 1,
    force: bool = False,
) -> str:
    """Renders a built-in scene into a DiLiGenT-layout folder (the near-light layout for a
    near rig); returns the folder."""

def read_image(path: str) -> np.ndarray:
    """(H, W, C) float32, integers scaled to [0, 1]."""

def read_normals(path: str) -> np.ndarray:
    """(H, W, 3) float32 normals from .npy, DiLiGenT .mat or a 16-bit PNG."""
