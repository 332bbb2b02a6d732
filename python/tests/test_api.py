"""The Python package against independent truths: analytic surfaces built here in numpy, the
command-line program on the same captures, and public ground truth."""

import json
import math
import pathlib
import pickle
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

import photostereo as ps
from conftest import DATA, ROOT


def ring(n, slant_deg=35.0):
    s = math.radians(slant_deg)
    t = 2 * np.pi * np.arange(n) / n + 0.3
    return np.stack([np.sin(s) * np.cos(t), np.sin(s) * np.sin(t), np.full(n, np.cos(s))], 1)


def lambert_sphere(size=64, radius=24.0, n_lights=8, albedo=(0.8, 0.6, 0.4)):
    """A Lambertian sphere cap lit by every light of a ring: (N, H, W, 3) float64 images,
    lights, mask, analytic normals and height (pixel units)."""
    lights = ring(n_lights)
    c = (size - 1) / 2
    rows, cols = np.mgrid[0:size, 0:size]
    x, y = (cols - c) / radius, (c - rows) / radius
    rr = x * x + y * y
    z = np.sqrt(np.clip(1 - rr, 0, None))
    normals = np.stack([x, y, z], -1)
    shading = np.einsum("hwj,kj->khw", normals, lights)
    mask = (rr < 0.8) & (shading > 0.05).all(0)
    images = np.clip(shading, 0, None)[..., None] * np.asarray(albedo)[None, None, None, :]
    images = images * mask[None, :, :, None]
    normals = normals * mask[..., None]
    return images, lights, mask, normals.astype(np.float32), radius * z


def angles_deg(a, b):
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    return np.degrees(np.arccos(np.clip((a * b).sum(-1), -1, 1)))


# --- reconstruct against an analytic sphere, every accepted dtype and layout -----------------


@pytest.mark.parametrize(
    "dtype,tolerance",
    [(np.float64, 0.01), (np.float32, 0.01), (np.uint16, 0.05), (np.uint8, 1.0)],
)
def test_l2_recovers_an_analytic_sphere_from_every_dtype(dtype, tolerance):
    images, lights, mask, truth, _ = lambert_sphere()
    if dtype == np.uint16:
        stack = np.round(images * 65535).astype(np.uint16)
    elif dtype == np.uint8:
        stack = np.round(images * 255).astype(np.uint8)
    else:
        stack = images.astype(dtype)
    rec = ps.reconstruct(stack, lights, mask=mask, method="l2", integrate=False)
    err = angles_deg(rec.normals[mask], truth[mask])
    assert err.mean() < tolerance, err.mean()
    assert rec.normals.shape == (64, 64, 3) and rec.normals.dtype == np.float32
    assert rec.albedo.shape == (64, 64, 3)
    assert np.allclose(rec.albedo[mask].mean(0), [0.8, 0.6, 0.4], atol=0.01)
    assert (rec.normals[~mask] == 0).all()
    assert rec.light_status.shape == (8, 64, 64) and rec.light_status.dtype == np.uint8
    assert (rec.light_status[:, ~mask] == 255).all() and (rec.light_status[:, mask] == 0).all()


def test_strided_grey_and_capture_inputs_give_the_same_normals():
    images, lights, mask, _, _ = lambert_sphere()
    base = ps.reconstruct(images.astype(np.float32), lights, mask=mask, method="l2")
    # Lights reversed through a negative stride, the channel axis last of a transposed store.
    reversed_view = images.astype(np.float32)[::-1]
    rev = ps.reconstruct(reversed_view, lights[::-1], mask=mask, method="l2")
    assert np.abs(rev.normals - base.normals).max() <= 1e-6
    fortran = np.asfortranarray(images.astype(np.float32))
    assert not fortran.flags.c_contiguous
    f = ps.reconstruct(fortran, lights, mask=mask, method="l2")
    assert np.abs(f.normals - base.normals).max() == 0
    # Grey (N, H, W): the channel mean of an RGB stack with equal channels.
    grey = images.mean(-1)
    g = ps.reconstruct(grey, lights, mask=mask, method="l2")
    assert g.albedo.shape == (64, 64, 1)
    assert np.abs(g.normals - base.normals).max() < 1e-5
    # A Capture built from the arrays.
    cap = ps.Capture.from_arrays(images.astype(np.float32), lights, mask=mask)
    c = ps.reconstruct(cap, method="l2")
    assert np.abs(c.normals - base.normals).max() == 0
    assert cap.images.shape == (8, 64, 64, 3) and np.allclose(cap.images, images, atol=1e-7)


def test_depth_of_an_analytic_sphere():
    images, lights, mask, truth, height = lambert_sphere()
    rec = ps.reconstruct(images, lights, mask=mask, method="l2")
    d = rec.depth
    assert d.shape == (64, 64) and np.isnan(d[~mask]).all() and np.isfinite(d[mask]).all()
    offset = (d[mask] - height[mask]).mean()
    rms = np.sqrt(((d[mask] - offset - height[mask]) ** 2).mean())
    assert rms < 0.05, rms
    # integrate() on the analytic normals alone.
    z = ps.integrate(truth, mask, method="poisson")
    offset = (z[mask] - height[mask]).mean()
    assert np.sqrt(((z[mask] - offset - height[mask]) ** 2).mean()) < 0.05
    w = np.where(mask, 1.0, 0.0).astype(np.float32)
    z2 = ps.integrate(truth, mask, method="poisson", weights=w)
    assert np.nanmax(np.abs(z2 - z)) < 1e-3


def test_angular_error_against_numpy():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(20, 30, 3)).astype(np.float32)
    a[..., 2] = np.abs(a[..., 2]) + 0.5
    b = a + rng.normal(scale=0.1, size=a.shape).astype(np.float32)
    mask = rng.random((20, 30)) > 0.3
    out = ps.angular_error(a, b, mask)
    ref = angles_deg(a.astype(np.float64), b.astype(np.float64))[mask]
    assert out["pixels"] == mask.sum()
    assert abs(out["mean_deg"] - ref.mean()) < 1e-4
    assert abs(out["median_deg"] - np.median(ref)) < 1e-3
    assert abs(out["under_5deg"] - (ref < 5).mean()) < 1e-9
    assert np.allclose(out["map"][mask], ref, atol=1e-3) and np.isnan(out["map"][~mask]).all()


# --- the same results as the command line on real captures ---------------------------------


@pytest.mark.parametrize("obj", ["ball", "cat"])
@pytest.mark.parametrize("method", ["l2", "recursive"])
def test_normals_equal_the_command_line(cli, diligent, tmp_path, obj, method):
    folder = diligent / f"{obj}PNG"
    out = tmp_path / "cli"
    subprocess.run(
        [cli, "run", str(folder), "--method", method, "--no-depth", "-o", str(out), "--quiet"],
        check=True,
    )
    cli_normals = np.load(out / "normals.npy")
    rec = ps.reconstruct(ps.load_capture(folder), method=method, integrate=False)
    assert np.abs(rec.normals - cli_normals).max() <= 1e-6
    cli_status = np.load(out / "light_status.npy")
    assert (rec.light_status == cli_status).all()
    # Ground truth: the same figure from Python's metric as from the command line's.
    truth = ps.read_normals(folder / "Normal_gt.mat")
    mine = ps.angular_error(rec.normals, truth, rec.mask)
    report = ps.run(folder, tmp_path / "py", method=method, gt=folder / "Normal_gt.mat",
                    integrate=False)
    assert abs(mine["mean_deg"] - report["error"]["mean_deg"]) < 1e-9
    if method == "l2":
        # The README's least-squares figures.
        assert round(mine["mean_deg"], 2) == {"ball": 3.98, "cat": 8.28}[obj]
    else:
        l2 = ps.angular_error(
            ps.reconstruct(ps.load_capture(folder), method="l2", integrate=False).normals,
            truth,
            rec.mask,
        )
        assert mine["mean_deg"] < l2["mean_deg"] - 1.0


def test_run_writes_the_output_folder_like_the_command_line(cli, diligent, tmp_path):
    folder = diligent / "ballPNG"
    report = ps.run(folder, tmp_path / "py", method="l2", detect=False)
    subprocess.run([cli, "run", str(folder), "--method", "l2", "--no-detect", "-o",
                    str(tmp_path / "cli"), "--quiet"], check=True)
    py_files = sorted(p.name for p in (tmp_path / "py").iterdir())
    cli_files = sorted(p.name for p in (tmp_path / "cli").iterdir())
    assert py_files == cli_files
    assert np.array_equal(np.load(tmp_path / "py" / "normals.npy"),
                          np.load(tmp_path / "cli" / "normals.npy"))
    on_disk = json.loads((tmp_path / "py" / "report.json").read_text())
    assert on_disk["input"] == report["input"] and report["method"] == "l2"
    with pytest.raises(ps.PhotostereoError, match="already exists") as exists:
        ps.run(folder, tmp_path / "py", method="l2")
    # The library's advice is spelt in Python's keywords, not the command line's flags.
    assert "force=True" in str(exists.value) and "--force" not in str(exists.value)
    with pytest.raises(TypeError, match="unexpected keyword"):
        ps.run(folder, tmp_path / "x", metod="l2")


def test_run_within_a_memory_limit_gives_the_same_normals(diligent, tmp_path):
    folder = diligent / "ballPNG"
    whole = ps.run(folder, tmp_path / "whole", method="l2")
    # Just above ball's smallest budget (107M): the samples go to tiles.
    tiled = ps.run(folder, tmp_path / "tiled", method="l2", memory_limit="110M")
    assert whole["memory"]["layout"] == "in memory"
    assert tiled["memory"]["layout"] != "in memory" and tiled["memory"]["tiles"] > 1
    assert tiled["memory"]["budget"] == 110 << 20
    assert np.array_equal(np.load(tmp_path / "whole" / "normals.npy"),
                          np.load(tmp_path / "tiled" / "normals.npy"))
    with pytest.raises(ps.PhotostereoError, match="smallest budget that works"):
        ps.run(folder, tmp_path / "small", method="l2", memory_limit="1M")
    with pytest.raises(ps.PhotostereoError, match="memory_limit"):
        ps.run(folder, tmp_path / "bad", method="l2", memory_limit="lots")


# --- calibration and scenes ----------------------------------------------------------------


def test_calibrate_matches_the_command_line_and_the_reference(cli, tmp_path):
    listing = (DATA / "psmImages" / "chrome.txt").read_text().split()
    n = int(listing[0])
    images = np.stack([ps.read_image(DATA / p) for p in listing[1 : n + 1]])
    mask = ps.read_image(DATA / listing[n + 1])[..., 0] > 0
    cal = ps.calibrate(images, mask)
    subprocess.run([cli, "calibrate", str(DATA / "psmImages" / "chrome.txt"), "-o",
                    str(tmp_path / "rig"), "--quiet"], check=True)
    rows = [r.split() for r in (tmp_path / "rig" / "light_directions.txt").read_text().splitlines()]
    rows = [list(map(float, r)) for r in rows if len(r) == 3]
    assert np.allclose(cal["lights"], np.array(rows), atol=1e-5)
    ref = [r.split() for r in (DATA / "psmImages" / "lights.reference.txt").read_text().splitlines()]
    ref = np.array([list(map(float, r)) for r in ref if len(r) == 3])
    diff = angles_deg(cal["lights"], ref)
    # The published directions come from a larger fitted outline: about 3 degrees apart.
    assert 2.0 < diff.mean() < 4.0, diff
    assert cal["confidence"].shape == (12,) and (cal["confidence"] > 0).all()


def test_render_scene_equals_the_synth_folder(tmp_path):
    images, lights, mask, truth = ps.render_scene("sphere", "ring8", 48, seed=3)
    assert images.shape == (8, 48, 48, 3) and lights.shape == (8, 3)
    assert np.allclose(np.linalg.norm(truth["normals"][mask], axis=-1), 1, atol=1e-5)
    folder = pathlib.Path(ps.synth("sphere", tmp_path / "s", "ring8", 48, seed=3))
    names = (folder / "filenames.txt").read_text().split()
    on_disk = np.stack([ps.read_image(folder / n) for n in names])
    assert np.abs(on_disk - images).max() < 1e-6
    rec = ps.reconstruct(images, lights, mask=mask, method="recursive")
    err = ps.angular_error(rec.normals, truth["normals"], mask)
    assert err["mean_deg"] < 3.0, err["mean_deg"]


def test_refine_lights_recovers_a_perturbed_light_and_leaves_the_capture():
    # Twelve lights on a noise-free Lambertian sphere cap; light 0 given 2 degrees off (rotated
    # about the y axis): the refined direction comes back toward the truth.
    images, lights, mask, truth, _ = lambert_sphere(size=96, radius=40.0, n_lights=12)
    given = lights.copy()
    s, c = math.sin(math.radians(2.0)), math.cos(math.radians(2.0))
    x, z = given[0, 0], given[0, 2]
    given[0, 0], given[0, 2] = c * x + s * z, -s * x + c * z
    cap = ps.Capture.from_arrays(images.astype(np.float32), given, mask=mask)
    lights_before, images_before = cap.lights.copy(), cap.images.copy()
    rec = ps.reconstruct(cap, method="l2", refine_lights=True, integrate=False)
    refined = rec.report["input"]["light_refinement"]
    directions = np.asarray(refined["directions"])
    assert angles_deg(directions[0], lights[0]) < 0.5 * angles_deg(given[0], lights[0])
    assert abs(refined["gains"][0] - 1.0) < 0.01, refined["gains"]
    assert rec.report["parameters"]["refine_lights"] is True
    # The Capture keeps the lights and samples it was built with.
    assert np.array_equal(cap.lights, lights_before)
    assert np.array_equal(cap.images, images_before)
    plain = ps.reconstruct(cap, method="l2", integrate=False)
    assert "light_refinement" not in plain.report["input"]
    # The surface prior is reported and can be turned off.
    with_prior = ps.reconstruct(cap, method="recursive", integrate=False)
    assert with_prior.report["recursive"]["surface_prior"]["prior_deg"] == 1.0
    without = ps.reconstruct(cap, method="recursive", integrate=False, surface_prior=0.0)
    assert without.report["recursive"]["surface_prior"] is None


# --- bad input ------------------------------------------------------------------------------


def test_bad_inputs_raise_photostereo_error():
    images, lights, mask, _, _ = lambert_sphere(size=16, radius=6)
    f32 = images.astype(np.float32)
    cases = [
        (lambda: ps.reconstruct(f32[0, :, :, 0], lights), "shape"),
        (lambda: ps.reconstruct(f32, lights[:5]), "8 images but 5 lights"),
        (lambda: ps.reconstruct(f32[:2], lights[:2]), "at least three"),
        (lambda: ps.reconstruct(f32, np.full((8, 3), np.nan)), "non-finite"),
        (lambda: ps.reconstruct(f32, lights[:, :2]), "(N, 3)"),
        (lambda: ps.reconstruct(f32.astype(np.int32), lights), "int32"),
        (lambda: ps.reconstruct(f32, lights, mask=np.zeros((16, 16), bool)), "mask is empty"),
        (lambda: ps.reconstruct(f32, lights, mask=np.ones((15, 16), bool)), "mask is 15×16"),
        (lambda: ps.reconstruct(f32, lights, method="magic"), "unknown method 'magic'"),
        (lambda: ps.reconstruct(f32, lights, relative_noise=-1), "relative_noise"),
        (lambda: ps.reconstruct(f32, lights, confidence=1.5), "confidence"),
        (lambda: ps.reconstruct(f32, lights, max_iterations=0), "max_iterations"),
        (lambda: ps.reconstruct(f32, lights, confidence="high"), "confidence 'high': expected a number"),
        (lambda: ps.reconstruct(f32, lights, intensities=np.ones((3, 3))), "intensities"),
        (lambda: ps.reconstruct(f32, lights, num_threads=0), "num_threads"),
        (lambda: ps.reconstruct(np.where(np.isfinite(f32), np.nan, 0).astype(np.float32), lights),
         "image 1 of the stack: no reading inside the mask is finite"),
        (lambda: ps.load_capture("/nonexistent/capture"), "/nonexistent/capture"),
        (lambda: ps.integrate(np.zeros((4, 4)), None), "(H, W, 3)"),
        (lambda: ps.angular_error(np.zeros((4, 4, 3)), np.zeros((4, 5, 3))), "same"),
        (lambda: ps.render_scene("teapot"), "teapot"),
    ]
    for call, needle in cases:
        with pytest.raises(ps.PhotostereoError) as info:
            call()
        assert needle in str(info.value), (needle, str(info.value))
    assert issubclass(ps.PhotostereoError, ValueError)


# --- threads, interrupts, pickling, progress, memory -----------------------------------------


def test_the_gil_is_released_while_reconstructing(diligent):
    cap = ps.load_capture(diligent / "catPNG")
    ticks = [0]
    done = threading.Event()

    def spin():
        while not done.is_set():
            ticks[0] += 1
            time.sleep(0.001)

    t = threading.Thread(target=spin)
    t.start()
    start = time.time()
    ps.reconstruct(cap, method="barsky-petrou", integrate=False)
    elapsed = time.time() - start
    done.set()
    t.join()
    # A thread blocked by the GIL would tick a handful of times; a free one about once a ms.
    assert ticks[0] > 0.2 * elapsed * 1000, (ticks[0], elapsed)


def test_ctrl_c_raises_keyboard_interrupt_within_a_second(diligent):
    import _thread

    cap = ps.load_capture(diligent / "catPNG")
    # Python's own Ctrl-C handler, whatever an earlier import or the parent process set.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    fired = []

    def interrupt():
        fired.append(time.time())
        _thread.interrupt_main()

    timer = threading.Timer(0.3, interrupt)
    start = time.time()
    try:
        timer.start()
        try:
            ps.reconstruct(cap, method="recursive", max_iterations=50, change_tolerance=0.0)
        except KeyboardInterrupt:
            elapsed = time.time() - start
        else:
            pytest.fail(f"reconstruct returned after {time.time() - start:.2f} s without "
                        f"KeyboardInterrupt; the interrupt was sent at "
                        f"{[round(t - start, 2) for t in fired]} s")
    finally:
        timer.cancel()
        signal.signal(signal.SIGINT, previous)
    assert elapsed < 1.3, elapsed


def test_results_and_captures_pickle():
    images, lights, mask, _, _ = lambert_sphere(size=32, radius=12)
    cap = ps.Capture.from_arrays(images.astype(np.float32), lights, mask=mask)
    rec = ps.reconstruct(cap, method="l2")
    rec2 = pickle.loads(pickle.dumps(rec))
    assert np.array_equal(rec2.normals, rec.normals) and rec2.report == rec.report
    cap2 = pickle.loads(pickle.dumps(cap))
    again = ps.reconstruct(cap2, method="l2")
    assert np.abs(again.normals - rec.normals).max() <= 1e-6


def test_progress_and_thread_cap():
    images, lights, mask, _, _ = lambert_sphere(size=96, radius=36)
    seen = []
    rec1 = ps.reconstruct(images, lights, mask=mask, num_threads=1,
                          progress=lambda stage, done, total: seen.append((stage, done, total)))
    rec2 = ps.reconstruct(images, lights, mask=mask)
    assert np.abs(rec1.normals - rec2.normals).max() <= 1e-6
    for stage, done, total in seen:
        assert isinstance(stage, str) and 0 <= done <= max(total, done)


def test_peak_memory_of_reconstruct_stays_near_the_command_line(cli, diligent, tmp_path):
    """The memory reconstruct takes in a Python process (its peak above the interpreter with
    numpy and photostereo imported) against the whole command-line run's peak."""
    folder = diligent / "catPNG"
    script = (
        "import photostereo as ps\n"
        "def kb(key):\n"
        "    for line in open('/proc/self/status'):\n"
        "        if line.startswith(key):\n"
        "            return int(line.split()[1])\n"
        "base = kb('VmRSS')\n"
        f"rec = ps.reconstruct(ps.load_capture({str(folder)!r}))\n"
        "print(base, kb('VmHWM'))\n"
    )
    base, peak = map(int, subprocess.run([sys.executable, "-c", script], check=True,
                                         capture_output=True, text=True).stdout.split())
    probe = (
        "import resource, subprocess, sys\n"
        "subprocess.run(sys.argv[1:], check=True)\n"
        "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)\n"
    )
    cli_kb = int(subprocess.run(
        [sys.executable, "-c", probe, cli, "run", str(folder), "-o", str(tmp_path / "o"),
         "--quiet"], check=True, capture_output=True, text=True).stdout.split()[-1])
    print(f"python: interpreter {base / 1024:.0f} MB, reconstruct {(peak - base) / 1024:.0f} MB "
          f"above it; command line run {cli_kb / 1024:.0f} MB")
    assert peak - base <= 1.2 * cli_kb, (base, peak, cli_kb)
