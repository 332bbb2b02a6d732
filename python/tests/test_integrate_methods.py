"""``integrate``'s integrators and camera against analytic surfaces: a sphere cap (smooth) and
a fronto-parallel plane seen through a pinhole camera (Z equal to the distance everywhere).
The integrators' handling of depth jumps is tested in Rust (crates/photostereo/tests/integrate.rs)."""

import numpy as np
import pytest

import photostereo as ps


def sphere_cap(size=64, radius=40.0):
    r, c = np.mgrid[0:size, 0:size].astype(np.float64)
    x, y = c - (size - 1) / 2, (size - 1) / 2 - r
    inside = x**2 + y**2 < (0.9 * radius) ** 2
    z = np.sqrt(np.clip(radius**2 - x**2 - y**2, 0, None))
    n = np.dstack([x, y, z]) / radius
    n[~inside] = 0
    return n.astype(np.float32), inside, np.where(inside, z, np.nan)


def test_the_default_is_the_library_s_and_smooth_surfaces_agree():
    n, mask, z = sphere_cap()
    assert ps.defaults()["integrator"] == "bilateral"
    for method in (None, "bilateral", "poisson"):
        d = ps.integrate(n, mask, method=method)
        d = d - np.nanmean(d[mask]) + np.nanmean(z[mask])
        err = np.abs(d - z)[mask]
        # Within 0.5% of the depth range on a smooth surface.
        assert err.mean() < 0.005 * np.ptp(z[mask]), (method, err.mean())
        assert np.isnan(d[~mask]).all()


def test_a_plane_through_the_camera_is_at_its_distance():
    size = 48
    n = np.zeros((size, size, 3), np.float32)
    n[..., 2] = 1.0
    k = np.array([[200.0, 0, 23.5], [0, 200.0, 23.5], [0, 0, 1]])
    for method in ("bilateral", "poisson"):
        z = ps.integrate(n, method=method, camera=k, distance=500.0)
        assert np.nanmean(z) == pytest.approx(500.0, rel=1e-4)
        assert np.nanstd(z) < 1e-3 * 500.0


@pytest.mark.parametrize(
    "kwargs, needle",
    [
        (dict(method="splines"), "method"),
        (dict(camera=np.diag([100.0, 100.0, 1.0])), "distance"),
        (dict(distance=100.0), "camera"),
        (dict(camera=np.eye(2), distance=100.0), "camera"),
        (dict(camera=np.diag([100.0, 100.0, 1.0]), distance=-5.0), "distance"),
    ],
)
def test_bad_choices_name_their_keyword(kwargs, needle):
    n, mask, _ = sphere_cap(16, 10.0)
    with pytest.raises(ps.PhotostereoError, match=needle):
        ps.integrate(n, mask, **kwargs)
