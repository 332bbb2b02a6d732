"""Captures as cameras write them, from Python (issue 33): the capture-reading keywords
``response=``, ``ambient=`` and ``ignore_exposure=`` of ``load_capture``, ``run`` and ``rti``,
with the command line's meaning. Each is checked against the ground truth of a synthetic
capture rendered by ``photostereo synth``: the linear 16-bit render is the reference, and the
same scene written through a camera's response, with a lamp left on, or at varying exposure
must come back to within noise of it with the right keyword (and clearly worse without)."""

import json
import pathlib
import shutil
import subprocess

import numpy as np
import pytest

import photostereo as ps


def synth(cli, folder, *extra):
    # A Lambertian sphere under 24 dome lights: l2 is exact on it up to noise and shadows.
    subprocess.run(
        [cli, "synth", "sphere", "--rig", "dome-24", "--brdf", "lambert", "--size", "64", "-q",
         "-o", str(folder), *extra],
        check=True,
    )
    return folder


def error(capture, folder):
    """Mean angular error (degrees) of l2 on a loaded capture against the folder's truth."""
    rec = ps.reconstruct(capture, method="l2", integrate=False)
    truth = np.load(folder / "gt" / "normal.npy")
    return ps.angular_error(rec.normals, truth, capture.mask).mean_deg


@pytest.fixture(scope="module")
def captures(cli, tmp_path_factory):
    d = tmp_path_factory.mktemp("camera")
    return {
        "linear": synth(cli, d / "linear"),
        # 16-bit values through a bare 2.2 power law, no colour chunk: read as linear unless told.
        "gamma": synth(cli, d / "gamma", "--response", "gamma:2.2", "--format", "png16"),
        # A lamp left on at up to 8% of full scale, its frame written as ambient.png.
        "ambient": synth(cli, d / "ambient", "--ambient", "0.08"),
        # sRGB JPEGs whose EXIF exposure varies over x0.5-x2.
        "jpeg": synth(cli, d / "jpeg", "--response", "srgb", "--format", "jpeg",
                      "--exposure-jitter", "2"),
    }


@pytest.fixture(scope="module")
def reference(captures):
    return error(ps.load_capture(captures["linear"]), captures["linear"])


def test_the_linear_render_is_accurate(reference):
    # The reference itself: l2 on a noisy Lambertian sphere under 24 dome lights, its attached
    # shadows (l2 does not leave them out) costing a few degrees.
    assert 0.5 < reference < 6.0


def test_response_undoes_a_power_law(captures, reference):
    folder = captures["gamma"]
    right = error(ps.load_capture(folder, response="gamma:2.2"), folder)
    wrong = error(ps.load_capture(folder, response="linear"), folder)
    auto_cap = ps.load_capture(folder, response="auto")
    estimated = error(auto_cap, folder)
    # The right response gives the linear render's error within its noise; reading the encoded
    # values as linear bends every reading and costs degrees.
    assert abs(right - reference) < 0.3, (right, reference)
    assert wrong > right + 2.0, (wrong, right)
    assert abs(estimated - reference) < 0.5, (estimated, reference)


def test_run_reports_the_response_given(captures, reference, tmp_path):
    folder = captures["gamma"]
    report = ps.run(folder, tmp_path / "out", gt=folder / "gt" / "normal.npy", method="l2",
                    integrate=False, response="gamma:2.2")
    images = report["photometry"]["images"]
    assert len(images) == 24
    assert all(i["response"] == "gamma:2.2" for i in images)
    assert abs(report["error"]["mean_deg"] - reference) < 0.3
    on_disk = json.loads((tmp_path / "out" / "report.json").read_text())
    assert on_disk["photometry"]["images"][0]["response"] == "gamma:2.2"


def test_ambient_replaces_the_folders_frame(captures, reference, tmp_path):
    # The folder's own ambient.png is found by itself; moved out of the folder, only the
    # keyword brings it back.
    folder = captures["ambient"]
    with_frame = error(ps.load_capture(folder), folder)
    moved = tmp_path / "capture"
    shutil.copytree(folder, moved)
    frame = tmp_path / "lamp.png"
    (moved / "ambient.png").rename(frame)
    without = error(ps.load_capture(moved), moved)
    given = error(ps.load_capture(moved, ambient=frame), moved)
    assert abs(with_frame - reference) < 0.3, (with_frame, reference)
    assert abs(given - reference) < 0.3, (given, reference)
    assert without > given + 0.3, (without, given)
    report = ps.run(moved, tmp_path / "out", method="l2", integrate=False, ambient=frame)
    assert report["photometry"]["ambient_file"].endswith("lamp.png")
    assert all(i["ambient_removed"] for i in report["photometry"]["images"])


def test_ignore_exposure_leaves_the_exposures(captures, reference):
    folder = captures["jpeg"]
    corrected = error(ps.load_capture(folder), folder)
    ignored = error(ps.load_capture(folder, ignore_exposure=True), folder)
    # 8-bit sRGB JPEG at quality 90: within 0.8 deg of the linear render (the bound).
    assert abs(corrected - reference) < 0.8, (corrected, reference)
    assert ignored > corrected + 1.0, (ignored, corrected)


def test_rti_takes_the_keywords(captures, tmp_path):
    # The basis fitted to the power-law capture read through its response is the one fitted
    # to the linear render (up to noise); read as linear it is another.
    def coefficients(folder, name, **kw):
        ps.rti(folder, tmp_path / name, basis="hsh2", **kw)
        return np.load(tmp_path / name / "coefficients.npy")

    reference = coefficients(captures["linear"], "linear")
    right = coefficients(captures["gamma"], "right", response="gamma:2.2")
    wrong = coefficients(captures["gamma"], "wrong", response="linear")
    scale = np.abs(reference).mean()
    assert np.abs(right - reference).mean() < 0.05 * scale
    assert np.abs(wrong - reference).mean() > 0.2 * scale


@pytest.mark.parametrize(
    "kwargs,words",
    [
        (dict(response="gamma:9"), ["response=gamma:9", "expected linear, srgb, gamma:G"]),
        (dict(response="log"), ["response=log", "auto"]),
        (dict(ambient="nowhere.png"), ["ambient=nowhere.png", "no such image file"]),
        (dict(dark="nowhere.png"), ["dark=nowhere.png", "no such image file"]),
        (dict(flat="nowhere.png"), ["flat=nowhere.png", "no such image file"]),
    ],
)
def test_bad_keywords_are_named(captures, kwargs, words, tmp_path):
    for call in (
        lambda: ps.load_capture(captures["linear"], **kwargs),
        lambda: ps.run(captures["linear"], tmp_path / "out", **kwargs),
    ):
        with pytest.raises(ps.PhotostereoError) as e:
            call()
        for w in words:
            assert w in str(e.value), str(e.value)
    assert not (tmp_path / "out").exists()


def test_the_docs_are_the_librarys():
    # The keywords' meanings come from the library's one definition, as the CLI's flags do.
    doc = " ".join(ps.load_capture.__doc__.split())
    for o in ps._native.capture_options():
        assert " ".join(o["doc"].split()) in doc, o["name"]
    assert "%(capture_options)s" not in ps.load_capture.__doc__
