"""Type stubs of photostereo's native module (Rust, pyo3). Use the package ``photostereo``,
whose functions wrap these with typed keywords, result classes and the library's defaults;
shapes are (N lights, H rows, W columns, C channels), arrays row-major, the camera frame x
right, y up, z toward the camera. Every bad value raises PhotostereoError naming its keyword."""

import os
from typing import Any, Callable, Dict, List, Literal, Optional, Sequence, Tuple, TypedDict, Union

import numpy as np

__version__: str

Progress = Callable[[str, int, int], Any]
Path = Union[str, "os.PathLike[str]"]

class PhotostereoError(ValueError):
    """Bad input: the message names the file, line or keyword at fault and what was expected."""

# --- parameters: generated from the library's table ---
class ParamValues(TypedDict, total=False):
    """Every parameter of a reconstruction by its keyword, as `defaults()` gives them (generated from the library's table; `Params` nests them by stage)."""

    method: Literal["l2", "coleman-jain", "barsky-petrou", "recursive"]  # default "recursive"
    detect: bool  # default True
    integrate: bool  # default True
    memory_limit: Union[int, str, None]  # default None
    refine_lights: bool  # default False
    occluding_contour: bool  # default True
    sigma: Optional[float]  # default None
    relative_noise: Optional[float]  # default None
    confidence: float  # default 0.95
    min_kept_share: float  # default 0.25
    batch_alpha: float  # default 0.05
    shadow_sigmas: float  # default 3.0
    shadow_ratio: float  # default 0.1
    attribute: bool  # default True
    noise_estimate: Literal["images", "residuals"]  # default "images"
    noise_refinements: int  # default 1
    light_noise: bool  # default True
    max_iterations: int  # default 10
    change_tolerance: float  # default 0.002
    fallback: Literal["neighbours", "brightest"]  # default "neighbours"
    consensus_radius: int  # default 2
    surface_prior: float  # default 1.0
    reflectance: Literal["lambert", "auto", "lobe", "material"]  # default "lambert"
    attached_tolerance: float  # default 0.02
    cast_tolerance: float  # default 0.05
    integrator: Literal["bilateral", "poisson", "dct", "fft", "paths"]  # default "bilateral"
    max_slope: float  # default 20.0
    unreliable_weight: float  # default 0.1
# --- end of the generated parameters ---

class ParameterInfo(TypedDict):
    """One row of the library's parameter table."""

    name: str
    stage: Literal["run", "detection", "recursive", "integration"]
    stage_doc: str
    type: Literal["bool", "int", "float", "float or none", "choice", "bytes"]
    default: Any
    choices: List[str]
    none: Optional[str]
    domain: str
    unit: str
    doc: str
    methods: List[str]
    report_key: str

def parameters() -> List[ParameterInfo]:
    """The library's parameter table, in table order."""

def defaults() -> ParamValues:
    """The library's default of every parameter, by name."""

def check_parameter(name: str, value: Any) -> None:
    """Raises PhotostereoError when ``value`` is outside the parameter's domain."""

def methods() -> List[str]:
    """The names ``method=`` accepts: l2, coleman-jain, barsky-petrou, recursive."""

class NativeCapture:
    """A capture held by the library: the mask pixels' samples, divided by the light
    intensities, with the lights (distant or near), the camera and the mask. Pickles whole."""

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
    @property
    def distance(self) -> Optional[float]:
        """The object's mean distance in mm, with a camera."""
    def lights(self) -> np.ndarray:
        """(N, 3) float64 unit directions toward the lights."""
    def intensities(self) -> np.ndarray:
        """(N, C) float64 light intensities."""
    def mask(self) -> np.ndarray:
        """(H, W) bool."""
    def images(self) -> np.ndarray:
        """(N, H, W, C) float32 images as given (full scale 1), zero outside the mask."""
    def camera(self) -> Optional[np.ndarray]:
        """(3, 3) float64 intrinsics K, or None."""
    def near(self) -> Optional[Dict[str, np.ndarray]]:
        """light_positions (N, 3) mm, light_axes (N, 3), light_anisotropy (N,); or None."""

def load_capture(
    inputs: Sequence[str],
    lights: Optional[str] = None,
    intensities: Optional[str] = None,
    mask: Optional[str] = None,
    num_threads: Optional[int] = None,
    distance: Optional[float] = None,
    camera: Union[str, np.ndarray, None] = None,
    memory_limit: Union[int, str, None] = None,
    response: Optional[str] = None,
    ambient: Optional[str] = None,
    dark: Optional[str] = None,
    flat: Optional[str] = None,
    ignore_exposure: bool = False,
) -> NativeCapture:
    """A DiLiGenT folder, a near-light folder, an .lp file, a list file (with lights) or image
    files (with lights), within the memory budget."""

def capture_from_stack(
    images: np.ndarray,
    lights: Optional[np.ndarray] = None,
    intensities: Optional[np.ndarray] = None,
    mask: Optional[np.ndarray] = None,
    light_positions: Optional[np.ndarray] = None,
    camera: Union[str, np.ndarray, None] = None,
    distance: Optional[float] = None,
    light_axes: Optional[np.ndarray] = None,
    light_anisotropy: Optional[np.ndarray] = None,
    memory_limit: Union[int, str, None] = None,
    response: Optional[str] = None,
    ambient: Optional[str] = None,
    dark: Optional[str] = None,
    flat: Optional[str] = None,
    ignore_exposure: bool = False,
) -> NativeCapture:
    """images: (N, H, W) or (N, H, W, C) uint8, uint16, float32 or float64, any strides;
    lights (N, 3) float64; intensities (N,) or (N, C) float64; mask (H, W) bool. Held to the
    image size limits and the memory budget, read once with the GIL released."""

def _capture_from_state(state: bytes) -> NativeCapture:
    """The capture a pickled state describes."""

class ReconstructionDict(TypedDict):
    normals: np.ndarray
    albedo: np.ndarray
    light_status: np.ndarray
    mask: np.ndarray
    trust: np.ndarray
    residual: Optional[np.ndarray]
    unreliable: Optional[np.ndarray]
    depth: Optional[np.ndarray]
    curl: Optional[np.ndarray]
    highlight: Optional[np.ndarray]
    fewer_than_three: Optional[np.ndarray]
    report: Dict[str, Any]

def reconstruct(
    capture: NativeCapture,
    params: ParamValues,
    num_threads: Optional[int] = None,
    progress: Optional[Progress] = None,
) -> ReconstructionDict:
    """The maps (shapes in photostereo.Reconstruction) and the report."""

def run(
    inputs: Sequence[str],
    output: str,
    params: ParamValues,
    lights: Optional[str] = None,
    intensities: Optional[str] = None,
    mask: Optional[str] = None,
    gt: Optional[str] = None,
    error_map: bool = False,
    light_subset: Optional[str] = None,
    force: bool = False,
    num_threads: Optional[int] = None,
    progress: Optional[Progress] = None,
    distance: Optional[float] = None,
    camera: Union[str, np.ndarray, None] = None,
    response: Optional[str] = None,
    ambient: Optional[str] = None,
    dark: Optional[str] = None,
    flat: Optional[str] = None,
    ignore_exposure: bool = False,
) -> Dict[str, Any]:
    """The command line's ``run``; returns report.json's content."""

def rti(
    inputs: Sequence[str],
    output: str,
    basis: str,
    lights: Optional[str] = None,
    intensities: Optional[str] = None,
    mask: Optional[str] = None,
    exclude_unreliable: bool = False,
    memory_limit: Optional[int] = None,
    force: bool = False,
    num_threads: Optional[int] = None,
    progress: Optional[Progress] = None,
    response: Optional[str] = None,
    ambient: Optional[str] = None,
    dark: Optional[str] = None,
    flat: Optional[str] = None,
    ignore_exposure: bool = False,
    iiif: Optional[str] = None,
    ridge: Optional[float] = None,
) -> Dict[str, Any]:
    """The command line's ``rti``; returns report.json's content."""

def integrate(
    normals: np.ndarray,
    mask: Optional[np.ndarray] = None,
    method: Optional[str] = None,
    weights: Optional[np.ndarray] = None,
    max_slope: Optional[float] = None,
    camera: Optional[Any] = None,
    distance: Optional[float] = None,
    num_threads: Optional[int] = None,
) -> np.ndarray:
    """(H, W, 3) float32 normals to (H, W) float32 depth in pixel units (Z in mm through a
    camera), NaN outside the mask."""

def angular_error(
    normals: np.ndarray, truth: np.ndarray, mask: Optional[np.ndarray] = None
) -> Tuple[Dict[str, Any], np.ndarray]:
    """(figures, (H, W) error map in degrees)."""

def calibrate(images: np.ndarray, mask: Optional[np.ndarray] = None) -> Dict[str, Any]:
    """Mirror-sphere images; the calibration with lights (N, 3) and confidence (N,) arrays."""

def render_scene(
    name: str,
    rig: str,
    size: int,
    brdf: str,
    noise: float,
    seed: int,
) -> Tuple[
    np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, Optional[Dict[str, Any]]
]:
    """(images, lights, mask, truth normals, truth depth, shadows, near): ``near`` is None for
    distant rigs, else the rig as photostereo.NearRig holds it."""

def synth(
    name: str,
    output: str,
    rig: str,
    size: int,
    brdf: str,
    noise: float,
    seed: int,
    force: bool,
) -> str:
    """Renders a built-in scene into a capture folder; returns the folder."""

def capture_options() -> List[Dict[str, str]]:
    """The capture-reading keywords (response, ambient, dark, flat, ignore_exposure): name, value
    placeholder, meaning."""

def read_image(path: str) -> np.ndarray:
    """(H, W, C) float32, integers scaled to [0, 1]."""

def read_normals(path: str) -> np.ndarray:
    """(H, W, 3) float32 normals from .npy, DiLiGenT .mat or a 16-bit PNG."""

def abandon_pending_outputs() -> int:
    """Removes the output folders still being written; for the interpreter's exit."""
