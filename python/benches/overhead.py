"""The Python binding's overhead against the command line: `photostereo.run` in a warm Python
process against the `photostereo run` process on the same capture, interleaved, medians.

    python python/benches/overhead.py [CAPTURE] [--repeats 7] [--method recursive]
"""

import argparse
import pathlib
import statistics
import subprocess
import tempfile
import time

import photostereo

ROOT = pathlib.Path(__file__).resolve().parents[2]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("capture", nargs="?", default=str(ROOT.parent / "shared/data/diligent/catPNG"))
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--method", default="recursive")
    ap.add_argument("--cli", default=str(ROOT / "target/release/photostereo"))
    a = ap.parse_args()
    py, cli, engine = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(a.repeats):
            t = time.perf_counter()
            subprocess.run([a.cli, "run", a.capture, "--method", a.method, "-o", f"{tmp}/c{i}",
                            "--quiet"], check=True)
            cli.append(time.perf_counter() - t)
            t = time.perf_counter()
            report = photostereo.run(a.capture, f"{tmp}/p{i}", method=a.method)
            py.append(time.perf_counter() - t)
            engine.append(report["timings_s"]["total"])
    m_cli, m_py = statistics.median(cli), statistics.median(py)
    print(f"{a.capture} ({a.method}), {a.repeats} runs each, interleaved:")
    print(f"  photostereo run (process):      median {m_cli:.3f} s")
    print(f"  photostereo.run (Python call):   median {m_py:.3f} s  "
          f"(library's own total {statistics.median(engine):.3f} s)")
    print(f"  ratio Python / command line: {m_py / m_cli:.3f}")


if __name__ == "__main__":
    main()
