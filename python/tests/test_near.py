"""Near lights and a perspective camera from Python (issue 13): LED positions in mm, the camera
as a 3x3 K or a K.txt path, the object's distance; checked against a synthetic near scene's
ground truth (normals, Z in mm)."""

import json
import pathlib

import numpy as np
import pytest

import photostereo as ps


@pytest.fixture(scope="module")
def ring():
    # 12 LEDs on a 75 mm ring around the lens, object at 300 mm, Blinn-Phong highlights.
    return ps.render_scene("bumps", rig="near-ring", size=64)


def centre_brightness(near):
    """Each LED's brightness at the object's centre (0, 0, -D): cos^mu / r^2, computed here from
    the rig (independently of the library's light model)."""
    c = np.array([0.0, 0.0, -near["distance"]])
    d = near["light_positions"] - c
    r = np.linalg.norm(d, axis=1)
    cos = np.einsum("ij,ij->i", near["light_axes"], -d) / r
    return cos ** near["light_anisotropy"] / r**2


def test_render_scene_gives_the_near_rig(ring):
    images, lights, mask, truth = ring
    near = truth["near"]
    assert images.shape == (12, 64, 64, 3)
    assert near["light_positions"].shape == (12, 3)
    # The ring: radius 75 mm in the camera plane.
    np.testing.assert_allclose(np.hypot(*near["light_positions"][:, :2].T), 75.0, rtol=1e-9)
    k = near["camera"]
    assert k.shape == (3, 3) and k[2, 2] == 1.0 and k[0, 1] == 0.0
    # Depth is Z in mm: its mean over the mask is the stated distance, about 300 mm.
    z = truth["depth"][mask]
    assert abs(z.mean() - near["distance"]) < 1e-3 * near["distance"]
    assert 280.0 < near["distance"] < 320.0
    # lights: the distant approximation, unit directions toward each LED from the centre.
    c = np.array([0.0, 0.0, -near["distance"]])
    d = near["light_positions"] - c
    np.testing.assert_allclose(lights, d / np.linalg.norm(d, axis=1)[:, None], atol=1e-3)


def test_near_model_beats_the_distant_approximation(ring):
    images, lights, mask, truth = ring
    near = truth["near"]
    rec = ps.reconstruct(
        images,
        mask=mask,
        light_positions=near["light_positions"],
        light_axes=near["light_axes"],
        light_anisotropy=near["light_anisotropy"],
        intensities=near["intensities"],
        camera=near["camera"],
        distance=near["distance"],
    )
    err_near = ps.angular_error(rec.normals, truth["normals"], mask)["mean_deg"]
    # The distant approximation: directions and brightness at the object's centre.
    distant_intensities = near["intensities"] * centre_brightness(near)[:, None]
    dist = ps.reconstruct(
        images, lights, mask=mask, intensities=distant_intensities, method="l2"
    )
    err_distant = ps.angular_error(dist.normals, truth["normals"], mask)["mean_deg"]
    assert err_near <= 0.25 * err_distant, (err_near, err_distant)
    assert rec.report["near"]["rounds"], rec.report["near"]
    # The depth is Z in mm along the optical axis: within 1% of the truth on average.
    z, zt = rec.depth[mask], truth["depth"][mask]
    assert np.isfinite(z).all()
    assert np.mean(np.abs(z - zt)) < 0.01 * near["distance"], np.mean(np.abs(z - zt))


def test_distance_and_camera_keywords_on_a_near_folder(tmp_path, ring):
    folder = pathlib.Path(
        ps.synth("bumps", tmp_path / "scene", rig="near-square", size=48, brdf="lambert")
    )
    assert (folder / "K.txt").is_file() and (folder / "light_positions.txt").is_file()
    d = float((folder / "mean_distance.txt").read_text())
    k = np.loadtxt(folder / "K.txt")
    a = ps.run(folder, tmp_path / "a", method="l2")
    # The same distance and camera given as keywords (K as an array and as a path): the same
    # reconstruction to the last bit.
    b = ps.run(folder, tmp_path / "b", method="l2", distance=d, camera=k)
    c = ps.run(folder, tmp_path / "c", method="l2", camera=folder / "K.txt")
    na, nb, nc = (np.load(tmp_path / x / "normals.npy") for x in "abc")
    assert np.array_equal(na, nb) and np.array_equal(na, nc)
    assert a["near"]["mean_distance_mm"] == pytest.approx(d)
    # A different distance moves the object: the mean depth follows it.
    e = ps.run(folder, tmp_path / "e", method="l2", distance=1.1 * d)
    assert e["near"]["mean_distance_mm"] == pytest.approx(1.1 * d)
    ze = np.load(tmp_path / "e" / "depth.npy")
    assert np.nanmean(ze) == pytest.approx(1.1 * d, rel=1e-3)
    # load_capture takes the same keywords.
    cap = ps.load_capture(folder, distance=d, camera=k)
    rec = ps.reconstruct(cap, method="l2")
    assert np.array_equal(rec.normals, na)
    truth = ps.read_normals(folder / "gt" / "normal.npy")
    # Lambertian bumps under four LEDs: l2 in the near model errs only at their cast shadows.
    assert ps.angular_error(rec.normals, truth, rec.mask)["mean_deg"] < 5.0
    json.dumps(a)


def test_camera_and_distance_give_distant_lights_depth_in_mm(ring):
    images, lights, mask, truth = ring
    near = truth["near"]
    rec = ps.reconstruct(
        images,
        lights,
        mask=mask,
        method="l2",
        camera=near["camera"],
        distance=near["distance"],
    )
    assert "near" not in rec.report
    assert np.nanmean(rec.depth[mask]) == pytest.approx(near["distance"], rel=1e-3)


@pytest.mark.parametrize(
    "kwargs, words",
    [
        (dict(camera=None), ["camera"]),
        (dict(distance=None), ["distance"]),
        (dict(distance=-5.0), ["distance"]),
        (dict(camera=[[500.0, 3.0, 32.0], [0.0, 500.0, 32.0], [0.0, 0.0, 1.0]]), ["camera", "skew"]),
        (dict(camera=[[0.0, 0.0, 32.0], [0.0, 500.0, 32.0], [0.0, 0.0, 1.0]]), ["camera", "invertible"]),
        (dict(camera=np.eye(2)), ["camera", "3x3"]),
        (dict(light_axes=np.ones((3, 3))), ["light_axes", "12"]),
        (dict(lights=np.ones((12, 3))), ["lights", "light_positions"]),
    ],
)
def test_bad_near_input_is_named(ring, kwargs, words):
    images, _, mask, truth = ring
    near = truth["near"]
    args = dict(
        mask=mask,
        light_positions=near["light_positions"],
        camera=near["camera"],
        distance=near["distance"],
        method="l2",
    )
    lights = kwargs.pop("lights", None)
    args.update(kwargs)
    with pytest.raises(ps.PhotostereoError) as e:
        ps.reconstruct(images, lights, **args)
    message = str(e.value)
    for w in words:
        assert w in message, message


def test_a_led_behind_the_object_is_refused(ring):
    images, _, mask, truth = ring
    near = truth["near"]
    positions = near["light_positions"].copy()
    positions[4, 2] = -2.0 * near["distance"]
    with pytest.raises(ps.PhotostereoError, match="light 5.*behind the object"):
        ps.reconstruct(
            images,
            mask=mask,
            light_positions=positions,
            camera=near["camera"],
            distance=near["distance"],
        )


def test_a_missing_distance_names_the_python_keyword(tmp_path):
    # A near-light folder without mean_distance.txt: the message names the file and the Python
    # keyword that replaces it (distance=), not the command line's flag.
    folder = pathlib.Path(
        ps.synth("bumps", tmp_path / "scene", rig="near-square", size=32, brdf="lambert")
    )
    (folder / "mean_distance.txt").unlink()
    for call in (
        lambda: ps.load_capture(folder),
        lambda: ps.run(folder, tmp_path / "out", method="l2"),
    ):
        with pytest.raises(ps.PhotostereoError) as e:
            call()
        message = str(e.value)
        assert "mean_distance.txt" in message and "distance=" in message, message
        assert "--distance" not in message, message
    assert not (tmp_path / "out").exists()
    # With the keyword the same folder runs.
    rec = ps.reconstruct(ps.load_capture(folder, distance=300.0), method="l2")
    assert rec.report["near"]["mean_distance_mm"] == pytest.approx(300.0)
