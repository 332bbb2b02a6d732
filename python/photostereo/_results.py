"""The results of photostereo's functions: documented fields with documented array shapes.

Shapes are (N lights, H rows, W columns, C channels), arrays row-major with row 0 at the top,
in the camera frame of CONVENTIONS.md (x right, y up, z toward the camera). Each result also
answers ``result["field"]`` (and ``"field" in result`` for the fields that are set), so code
written against the dicts earlier versions returned keeps working.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Dict, List, NamedTuple, Optional

import numpy as np


class _Record:
    """Mapping access to a dataclass's fields: ``r["name"]`` is ``r.name``."""

    def keys(self) -> List[str]:
        return [f.name for f in dataclasses.fields(self)]  # type: ignore[arg-type]

    def __getitem__(self, key: str) -> Any:
        if key not in self.keys():
            raise KeyError(key)
        return getattr(self, key)

    def __contains__(self, key: object) -> bool:
        return key in self.keys() and getattr(self, key) is not None  # type: ignore[arg-type]

    def get(self, key: str, default: Any = None) -> Any:
        return getattr(self, key) if key in self else default

    def to_dict(self) -> Dict[str, Any]:
        """The fields as a dict."""
        return {k: getattr(self, k) for k in self.keys()}


@dataclasses.dataclass
class Reconstruction(_Record):
    """The result of :func:`reconstruct`; every map is full frame (H rows, W columns).

    Attributes
    ----------
    normals : ndarray of float32, shape (H, W, 3)
        Unit normals in the camera frame; (0, 0, 0) outside the mask and where undetermined.
    albedo : ndarray of float32, shape (H, W, C)
        Albedo per channel, in units of the intensity-normalised images; 0 outside the mask.
    depth : ndarray of float32, shape (H, W), or None
        Height toward the camera in pixel units (with a camera: Z in mm along the optical
        axis); NaN outside the mask. None with ``integrate=False``.
    light_status : ndarray of uint8, shape (N, H, W)
        0 used, 1 shadow (attached or cast), 2 highlight, 3 rejected for another reason,
        255 outside the mask.
    residual : ndarray of float32, shape (H, W), or None
        The chi-square statistic ||r|| / sigma_p with all lights; None when the test did not
        run (fewer than four lights, or ``detect=False`` with l2 or coleman-jain).
    unreliable : ndarray of bool, shape (H, W), or None
        Where the chi-square test failed; None when it did not run.
    curl : ndarray of float32, shape (H, W), or None
        The integrability residual of the normals (the paper's eq. 10); None without depth.
    trust : ndarray of float32, shape (H, W)
        The integration weight of each pixel (1 reliable, ``unreliable_weight`` unreliable,
        0 without a normal).
    mask : ndarray of bool, shape (H, W)
        The mask used.
    highlight : ndarray of bool, shape (H, W), or None
        The recursive method's highlight map; None for the other methods.
    fewer_than_three : ndarray of bool, shape (H, W), or None
        Pixels the recursive method left with fewer than three usable lights.
    report : dict
        What report.json holds: the method, the parameters, the input, timings, notes and the
        method's figures.
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


@dataclasses.dataclass
class AngularError(_Record):
    """The angular error of normals against ground truth (:func:`angular_error`), over the mask
    pixels where the truth is non-zero, both vectors normalised.

    Attributes
    ----------
    mean_deg : float
        Mean angular error (MAE), degrees.
    median_deg : float
        Median angular error, degrees.
    under_5deg, under_10deg, under_20deg : float
        Shares of the pixels under 5, 10 and 20 degrees (0..1).
    mean_eq14_deg : float
        The mean of the paper's eq. 14 figure (a 1 appended to each vector; not the headline).
    pixels : int
        Pixels evaluated.
    missing : int
        Evaluated pixels without a prediction (zero or non-finite), counted as 90 degrees.
    map : ndarray of float32, shape (H, W)
        The error of each pixel in degrees; NaN where not evaluated.
    """

    mean_deg: float
    median_deg: float
    under_5deg: float
    under_10deg: float
    under_20deg: float
    mean_eq14_deg: float
    pixels: int
    missing: int
    map: np.ndarray


@dataclasses.dataclass
class Calibration(_Record):
    """Light directions from a mirror sphere (:func:`calibrate`).

    Attributes
    ----------
    lights : ndarray of float64, shape (N, 3)
        Unit directions toward each light, camera frame; NaN where no highlight was found.
    confidence : ndarray of float64, shape (N,)
        Each light's confidence in 0..1 (0.25 and more: confident).
    per_light : list of dict
        Each image's highlight, normal, direction, confidence and its parts.
    sphere : dict
        The sphere's fitted outline (centre and radius in pixels, fit figures).
    sphere_source : str
        Where the outline came from (the mask, or detected from the images).
    warnings : list of dict
        Problems found, in image order.
    width, height : int
        The images' size in pixels.
    """

    lights: np.ndarray
    confidence: np.ndarray
    per_light: List[Dict[str, Any]]
    sphere: Dict[str, Any]
    sphere_source: Any
    warnings: List[Any]
    width: int
    height: int


@dataclasses.dataclass
class NearRig(_Record):
    """A near-light rig as :func:`reconstruct` takes it (``reconstruct(images, mask=mask,
    **rig.to_dict())``): LEDs a few hundred mm away seen through a pinhole camera.

    Attributes
    ----------
    light_positions : ndarray of float64, shape (N, 3)
        LED positions in mm, camera frame, camera centre at the origin (the object at z < 0).
    light_axes : ndarray of float64, shape (N, 3)
        Unit vectors, the direction each LED points.
    light_anisotropy : ndarray of float64, shape (N,)
        mu per LED: radiance falls as cos^mu off the axis.
    intensities : ndarray of float64, shape (N, 3)
        Each LED's radiance along its axis at 1 mm.
    camera : ndarray of float64, shape (3, 3)
        The intrinsics K in pixels.
    distance : float
        The object's mean distance along the optical axis, mm.
    """

    light_positions: np.ndarray
    light_axes: np.ndarray
    light_anisotropy: np.ndarray
    intensities: np.ndarray
    camera: np.ndarray
    distance: float


@dataclasses.dataclass
class SceneTruth(_Record):
    """The ground truth of a rendered scene (S × S pixels, N lights).

    Attributes
    ----------
    normals : ndarray of float32, shape (S, S, 3)
        Unit normals, camera frame; zero outside the object.
    depth : ndarray of float32, shape (S, S)
        Height in pixel units (near rigs: Z in mm along the optical axis).
    shadows : ndarray of bool, shape (N, S, S)
        Pixels in shadow (attached or cast) under each light.
    near : NearRig or None
        The rig of a near-light scene; None for distant rigs.
    """

    normals: np.ndarray
    depth: np.ndarray
    shadows: np.ndarray
    near: Optional[NearRig] = None


class Scene(NamedTuple):
    """A rendered scene (:func:`render_scene`); unpacks as ``images, lights, mask, truth``.

    Attributes
    ----------
    images : ndarray of float32, shape (N, S, S, 3)
        The images at full scale 1 (16-bit quantised, with the requested noise).
    lights : ndarray of float64, shape (N, 3)
        Unit directions toward the lights (near rigs: toward each LED from the object's centre,
        the distant approximation).
    mask : ndarray of bool, shape (S, S)
        The object.
    truth : SceneTruth
        Normals, depth, shadows and, for near rigs, the rig.
    """

    images: np.ndarray
    lights: np.ndarray
    mask: np.ndarray
    truth: SceneTruth
