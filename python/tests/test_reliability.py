"""Python never aborts, hangs or silently changes a capture: huge and strided arrays are held
to the image limits and the memory budget as files are, keyword values out of range raise
PhotostereoError naming the keyword, an interrupted run leaves no staging folder, and every
kind of capture survives pickling."""

import pickle
import re
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import photostereo as ps
from conftest import DILIGENT


def ring(n, slant_deg=35.0):
    s = np.radians(slant_deg)
    t = 2 * np.pi * np.arange(n) / n + 0.3
    return np.stack([np.sin(s) * np.cos(t), np.sin(s) * np.sin(t), np.full(n, np.cos(s))], 1)


def python(script, timeout=120):
    """Runs `script` in a fresh interpreter; its return code and output."""
    return subprocess.run([sys.executable, "-c", textwrap.dedent(script)], capture_output=True,
                          text=True, timeout=timeout)


def test_huge_strided_arrays_are_refused_not_allocated():
    # In a child interpreter: an abort would end it, not this test run.
    out = python(
        """
        import numpy as np, photostereo as ps
        t = 2 * np.pi * np.arange(8) / 8
        lights = np.stack([0.5 * np.cos(t), 0.5 * np.sin(t), np.full(8, 0.8)], 1)
        zero = np.zeros(1, np.float32)
        for shape, limit in [((8, 30000, 30000), "200M"), ((8, 200000, 200000), None),
                             ((8, 200000, 200000), "200M"), ((8, 40000, 40000, 3), "1G")]:
            view = np.lib.stride_tricks.as_strided(zero, shape=shape, strides=(0,) * len(shape))
            try:
                ps.reconstruct(view, lights, memory_limit=limit)
            except ps.PhotostereoError as e:
                print("refused:", e)
        """
    )
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert len(lines) == 4, out.stdout
    assert "memory_limit 200M: too small for this capture (30000×30000 pixels" in lines[0]
    assert "smallest budget that works" in lines[0]
    assert "a side exceeds the limit of 131072 pixels" in lines[1]
    assert "a side exceeds the limit of 131072 pixels" in lines[2]
    assert "more than the limit of 1073741824 pixels" in lines[3]


def test_the_budget_holds_an_array_in_tiles_with_the_same_normals():
    rng = np.random.default_rng(1)
    lights = ring(12)
    n = rng.normal(size=(160, 160, 3)) * [0.3, 0.3, 0.0] + [0.0, 0.0, 1.0]
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    images = np.clip(np.einsum("hwj,kj->khw", n, lights), 0, None).astype(np.float32)
    images = np.repeat(images[..., None], 3, axis=-1)
    whole = ps.reconstruct(images, lights, method="l2", integrate=False)
    assert "memory" not in whole.report
    with pytest.raises(ps.PhotostereoError, match="memory_limit 1M: too small") as e:
        ps.reconstruct(images, lights, method="l2", memory_limit="1M")
    smallest = int(re.search(r"smallest budget that works is (\d+)M", str(e.value)).group(1))
    tiled = ps.reconstruct(images, lights, method="l2", integrate=False,
                           memory_limit=f"{smallest + 1}M")
    assert tiled.report["memory"]["layout"] != "in memory", tiled.report["memory"]
    assert tiled.report["memory"]["tiles"] > 1
    assert np.array_equal(tiled.normals, whole.normals)
    # uint8 arrays are held as their integers, with the same results.
    u8 = np.round(images * 255).astype(np.uint8)
    a = ps.reconstruct(u8, lights, method="l2", integrate=False)
    b = ps.reconstruct(u8, lights, method="l2", integrate=False, memory_limit=f"{smallest + 1}M")
    assert b.report["memory"]["sample_type"] == "u16"
    assert np.array_equal(a.normals, b.normals)
    # Non-finite readings follow the same rule in tiles as whole: read as 0, with one note.
    holes = images.copy()
    holes[2, 10:20, 10:20] = np.nan
    a = ps.reconstruct(holes, lights, method="l2", integrate=False)
    b = ps.reconstruct(holes, lights, method="l2", integrate=False,
                       memory_limit=f"{smallest + 1}M")
    assert b.report["memory"]["tiles"] > 1
    assert np.array_equal(a.normals, b.normals)
    notes = [[n for n in r.report["notes"] if "non-finite" in n] for r in (a, b)]
    assert len(notes[0]) == 1 and "image 3 of the stack (300 of" in notes[0][0], notes[0]
    assert notes[0] == notes[1]
    holes[3] = np.inf
    with pytest.raises(ps.PhotostereoError, match="image 4 of the stack: no reading"):
        ps.reconstruct(holes, lights, method="l2", memory_limit=f"{smallest + 1}M")
    # A tiled capture pickles whole.
    cap = ps.Capture.from_arrays(images, lights, memory_limit=f"{smallest + 1}M")
    again = pickle.loads(pickle.dumps(cap))
    assert np.array_equal(ps.reconstruct(again, method="l2", integrate=False).normals, whole.normals)


@pytest.mark.parametrize(
    "call, needle",
    [
        (lambda f, l: ps.reconstruct(f, l, num_threads=10**12), "num_threads 1000000000000"),
        (lambda f, l: ps.reconstruct(f, l, num_threads=-1), "num_threads -1: expected an integer"),
        (lambda f, l: ps.reconstruct(f, l, num_threads=True), "num_threads True"),
        (lambda f, l: ps.reconstruct(f, l, num_threads=2.5), "num_threads 2.5"),
        (lambda f, l: ps.reconstruct(f, l, progress=42), "progress 42: expected a callable"),
        (lambda f, l: ps.reconstruct(f, l, max_iterations=10**30), "max_iterations"),
        (lambda f, l: ps.reconstruct(f, l, consensus_radius=10**9), "consensus_radius 1000000000"),
        (lambda f, l: ps.reconstruct(f, l, noise_refinements=-2), "noise_refinements -2"),
        (lambda f, l: ps.reconstruct(f, l, detect=1), "detect 1: expected true or false"),
        (lambda f, l: ps.reconstruct(f, l, memory_limit=-5), "memory_limit -5"),
        (lambda f, l: ps.reconstruct(f, l, memory_limit=[1]), "memory_limit [1]"),
        (lambda f, l: ps.reconstruct(f, l, distance=float("nan")), "distance nan"),
        (lambda f, l: ps.integrate(np.zeros((4, 4, 3)), max_slope=-1), "max_slope -1"),
        (lambda f, l: ps.integrate(np.zeros((4, 4, 3)), num_threads=-3), "num_threads -3"),
        (lambda f, l: ps.load_capture(DILIGENT / "ballPNG", num_threads=0), "num_threads 0"),
        (lambda f, l: ps.render_scene("sphere", size=-1), "size -1: expected an integer in [8, 8192]"),
        (lambda f, l: ps.render_scene("sphere", size=10**20), "size 100000000000000000000"),
        (lambda f, l: ps.render_scene("sphere", seed=-1), "seed -1"),
        (lambda f, l: ps.render_scene("sphere", noise=float("inf")), "noise inf"),
        (lambda f, l: ps.synth("sphere", "/nonexistent/x", size=-1), "size -1"),
    ],
)
def test_keyword_values_out_of_range_raise_photostereo_error(call, needle):
    images = np.ones((6, 8, 8), np.float32)
    with pytest.raises(ps.PhotostereoError) as e:
        call(images, ring(6))
    assert needle in str(e.value), str(e.value)


def test_ctrl_c_during_run_leaves_no_staging_folder(tmp_path):
    out = python(
        f"""
        import _thread, os, threading, photostereo as ps
        threading.Timer(0.5, _thread.interrupt_main).start()
        try:
            ps.run({str(DILIGENT / "catPNG")!r}, {str(tmp_path / "out")!r}, method="recursive",
                   max_iterations=50, change_tolerance=0.0)
        except KeyboardInterrupt:
            # What is left when the interrupt reaches the script, before the interpreter's exit.
            print("left:", sorted(os.listdir({str(tmp_path)!r})))
            raise
        """,
        timeout=300,
    )
    assert "KeyboardInterrupt" in out.stderr, out.stderr
    assert "left: []" in out.stdout, out.stdout
    assert list(tmp_path.iterdir()) == [], list(tmp_path.iterdir())


def test_integrate_refuses_normals_without_a_valid_pixel():
    nan = np.full((6, 7, 3), np.nan, np.float32)
    with pytest.raises(ps.PhotostereoError, match="normals: no pixel with a valid normal"):
        ps.integrate(nan)
    mask = np.zeros((6, 7), bool)
    mask[2:4, 2:5] = True
    with pytest.raises(ps.PhotostereoError, match="6 invalid .* inside the mask"):
        ps.integrate(nan, mask)
    away = np.zeros((6, 7, 3), np.float32)
    away[..., 2] = -1
    with pytest.raises(ps.PhotostereoError, match="42 facing away"):
        ps.integrate(away)
    # One valid normal is enough: a flat patch, NaN elsewhere.
    some = nan.copy()
    some[1:3, 1:3] = [0, 0, 1]
    depth = ps.integrate(some)
    assert np.isfinite(depth).sum() == 4 and np.isnan(depth[0, 0])


def test_huge_normal_maps_are_refused_not_copied():
    zero = np.zeros(1, np.float32)
    for shape, needle in [((200000, 8, 3), "a side exceeds the limit of 131072 pixels"),
                          ((40000, 40000, 3), "more than the limit of 1073741824 pixels")]:
        view = np.lib.stride_tricks.as_strided(zero, shape=shape, strides=(0, 0, 0))
        with pytest.raises(ps.PhotostereoError, match=needle):
            ps.integrate(view)
        with pytest.raises(ps.PhotostereoError, match=needle):
            ps.angular_error(view, view)


def test_a_near_capture_has_the_same_recursive_error_after_pickling(tmp_path):
    folder = ps.synth("bumps", tmp_path / "near", rig="near-ring", size=64)
    cap = ps.load_capture(folder)
    truth = ps.read_normals(folder / "gt" / "normal.npy")
    again = pickle.loads(pickle.dumps(cap))
    assert again.near is not None and again.camera is not None and again.distance == cap.distance
    before = ps.angular_error(ps.reconstruct(cap, method="recursive").normals, truth)
    after = ps.angular_error(ps.reconstruct(again, method="recursive").normals, truth)
    print("recursive mean error before/after pickling:", before.mean_deg, after.mean_deg)
    assert before.pixels == after.pixels > 1000
    assert before.mean_deg == after.mean_deg and before.median_deg == after.median_deg
    assert after.mean_deg < 5.0, after.mean_deg


def test_every_kind_of_capture_pickles(tmp_path):
    near = ps.synth("bumps", tmp_path / "near", rig="near-square", size=48, brdf="lambert")
    distant = ps.synth("bumps", tmp_path / "distant", rig="ring8", size=48, brdf="lambert")
    k = np.loadtxt(near / "K.txt")
    captures = {
        "near": ps.load_capture(near),
        "camera": ps.load_capture(distant, camera=k, distance=300.0),
        "distant": ps.load_capture(distant),
    }
    images, lights, mask, truth = ps.render_scene("bumps", "near-ring", 48)
    captures["near arrays"] = ps.Capture.from_arrays(images, mask=mask, **{
        k: v for k, v in truth.near.to_dict().items()})
    for name, cap in captures.items():
        again = pickle.loads(pickle.dumps(cap))
        assert repr(again) == repr(cap), name
        assert (again.camera is None) == (cap.camera is None), name
        if cap.camera is not None:
            assert np.array_equal(again.camera, cap.camera) and again.distance == cap.distance
        assert (again.near is None) == (cap.near is None), name
        if cap.near is not None:
            for key, value in cap.near.items():
                assert np.array_equal(again.near[key], value), (name, key)
        assert np.array_equal(again.images, cap.images), name
        assert np.array_equal(again.intensities, cap.intensities), name
        a = ps.reconstruct(cap, method="l2")
        b = ps.reconstruct(again, method="l2")
        assert np.array_equal(a.normals, b.normals), name
        assert np.array_equal(a.depth, b.depth, equal_nan=True), name
        assert a.report == b.report or a.report["input"] == b.report["input"], name
    # The near capture's depth is Z in mm after pickling too.
    rec = ps.reconstruct(pickle.loads(pickle.dumps(captures["near"])), method="l2")
    assert 250 < np.nanmean(rec.depth) < 350
