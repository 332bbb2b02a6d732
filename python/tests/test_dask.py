"""The Dask example on a two-worker LocalCluster: its outputs equal serial runs'."""

import importlib.util

import numpy as np

import photostereo as ps
from conftest import ROOT

spec = importlib.util.spec_from_file_location("dask_batch", ROOT / "examples" / "dask_batch.py")
dask_batch = importlib.util.module_from_spec(spec)
spec.loader.exec_module(dask_batch)


def test_dask_batch_equals_serial_runs(tmp_path):
    scenes = ["sphere", "bumps", "blocks", "face"]
    (tmp_path / "captures").mkdir()
    (tmp_path / "serial").mkdir()
    captures = [
        ps.synth(s, tmp_path / "captures" / s, rig="ring8", size=64, seed=i + 1)
        for i, s in enumerate(scenes)
    ]
    rows = dask_batch.run_batch(
        captures, str(tmp_path / "dask"), n_workers=2, gt_name="gt/normal.npy", method="recursive"
    )
    assert [r["capture"] for r in rows] == scenes
    for row, capture in zip(rows, captures):
        serial = ps.run(capture, tmp_path / "serial" / row["capture"], method="recursive",
                        gt=f"{capture}/gt/normal.npy")
        assert row["mean_error_deg"] == serial["error"]["mean_deg"]
        assert row["lights"] == 8 and row["pixels"] == serial["input"]["mask_pixels"]
        a = np.load(f"{row['output']}/normals.npy")
        b = np.load(tmp_path / "serial" / row["capture"] / "normals.npy")
        assert np.array_equal(a, b)
