"""Reconstruct many captures on a Dask cluster with photostereo.

Each capture folder (or list file) is one task: ``photostereo.run`` reads it, reconstructs it
and writes its output folder; the driver collects one row of figures per capture. A
``LocalCluster`` is started when no scheduler address is given; pass ``--scheduler
tcp://host:8786`` to use a real cluster (every worker needs ``pip install photostereo`` and
read access to the captures and the output root). There is no scheduler of our own: Dask does
the distribution, photostereo the numerics.

    python examples/dask_batch.py CAPTURE... --output results/ [--scheduler ADDR]
        [--workers 2] [--threads 1] [--method recursive] [--gt-name gt/normal.npy]

Each worker process runs ``threads`` library threads (``num_threads=``), so that several
workers can share a node without oversubscribing its cores.
"""

from __future__ import annotations

import argparse
import os
import pathlib
from typing import Any, Dict, List, Optional, Sequence

import photostereo


def reconstruct_one(
    capture: str,
    output_root: str,
    gt_name: Optional[str] = None,
    num_threads: Optional[int] = 1,
    **params: Any,
) -> Dict[str, Any]:
    """Runs one capture into ``output_root/<capture name>`` and returns its row of figures.
    A module-level function, so that Dask can ship it to workers by reference."""
    name = pathlib.Path(capture).stem if pathlib.Path(capture).is_file() else pathlib.Path(capture).name
    output = pathlib.Path(output_root) / name
    gt = None
    if gt_name is not None and (pathlib.Path(capture) / gt_name).exists():
        gt = pathlib.Path(capture) / gt_name
    report = photostereo.run(capture, output, gt=gt, force=True, num_threads=num_threads, **params)
    error = report.get("error") or {}
    recursive = report.get("recursive") or {}
    return {
        "capture": name,
        "method": report["method"],
        "lights": report["input"]["lights"],
        "pixels": report["input"]["mask_pixels"],
        "mean_error_deg": error.get("mean_deg"),
        "median_error_deg": error.get("median_deg"),
        "iterations": len(recursive.get("iterations", [])) or None,
        "seconds": report["timings_s"].get("total"),
        "output": str(output),
    }


def run_batch(
    captures: Sequence[str],
    output_root: str,
    scheduler: Optional[str] = None,
    n_workers: int = 2,
    threads_per_worker: int = 1,
    gt_name: Optional[str] = None,
    **params: Any,
) -> List[Dict[str, Any]]:
    """Maps :func:`reconstruct_one` over ``captures`` on a Dask cluster (a LocalCluster of
    ``n_workers`` processes when ``scheduler`` is None) and returns the rows in input order."""
    from dask.distributed import Client, LocalCluster

    os.makedirs(output_root, exist_ok=True)
    cluster = None
    if scheduler is None:
        cluster = LocalCluster(
            n_workers=n_workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
        )
        client = Client(cluster)
    else:
        client = Client(scheduler)
    try:
        futures = client.map(
            reconstruct_one,
            [os.fspath(c) for c in captures],
            output_root=os.fspath(output_root),
            gt_name=gt_name,
            num_threads=threads_per_worker,
            pure=False,
            **params,
        )
        return client.gather(futures)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def print_table(rows: Sequence[Dict[str, Any]]) -> None:
    """The rows as a plain-text table."""
    cols = ["capture", "method", "lights", "pixels", "mean_error_deg", "iterations", "seconds"]

    def cell(v: Any) -> str:
        if v is None:
            return "-"
        return f"{v:.2f}" if isinstance(v, float) else str(v)

    table = [cols] + [[cell(r[c]) for c in cols] for r in rows]
    widths = [max(len(row[i]) for row in table) for i in range(len(cols))]
    for row in table:
        print("  ".join(v.rjust(w) for v, w in zip(row, widths)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("captures", nargs="+", help="capture folders (DiLiGenT layout)")
    ap.add_argument("--output", required=True, help="root of the output folders")
    ap.add_argument("--scheduler", help="address of a running Dask scheduler")
    ap.add_argument("--workers", type=int, default=2, help="LocalCluster worker processes")
    ap.add_argument("--threads", type=int, default=1, help="library threads per worker")
    ap.add_argument("--method", default=photostereo.defaults()["method"])
    ap.add_argument("--gt-name", help="ground truth inside each capture, e.g. gt/normal.npy")
    a = ap.parse_args()
    rows = run_batch(
        a.captures,
        a.output,
        scheduler=a.scheduler,
        n_workers=a.workers,
        threads_per_worker=a.threads,
        gt_name=a.gt_name,
        method=a.method,
    )
    print_table(rows)


if __name__ == "__main__":
    main()
