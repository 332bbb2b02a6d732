#!/usr/bin/env bash
# `photostereo integrate --no-mesh` on a full SIZE² normal map against a 15-line scipy DCT script
# (benches/scipy_dct.py), each as a whole process (start, read, solve, write, exit), interleaved,
# RUNS times; prints the medians and the ratios, and the max |depth − truth| of each against the
# analytic surface (benches/make_normals.py).
#
#   benches/integrate_vs_scipy.sh [SIZE] [RUNS]        # defaults 2048 and 7
#
# Needs a Python with numpy and scipy: $PYTHON, else /tmp/sv/bin/python, made by
#   python3 -m venv /tmp/sv && /tmp/sv/bin/pip install numpy scipy
set -euo pipefail
SIZE=${1:-2048}
RUNS=${2:-7}
ROOT=$(cd "$(dirname "$0")/.." && pwd)
B=${PHOTOSTEREO:-$ROOT/target/release/photostereo}
PY=${PYTHON:-/tmp/sv/bin/python}
[ -x "$B" ] || (cd "$ROOT" && cargo build --release -p photostereo-cli)
DIR=$(mktemp -d /tmp/integrate-vs-scipy.XXXXXX)
trap 'rm -rf "$DIR"' EXIT
"$PY" "$ROOT/benches/make_normals.py" "$SIZE" "$DIR/normals.npy" "$DIR/truth.npy"
now() { date +%s.%N; }
declare -A T
for ((k = 0; k < RUNS; k++)); do
  for m in scipy dct poisson; do
    rm -rf "${DIR:?}/$m" "$DIR/$m.npy"   # each run writes afresh (no --force removal timed)
    t0=$(now)
    if [ $m = scipy ]; then
      "$PY" "$ROOT/benches/scipy_dct.py" "$DIR/normals.npy" "$DIR/$m.npy"
    else
      "$B" integrate "$DIR/normals.npy" --method $m --no-mesh -o "$DIR/$m" --quiet
    fi
    t1=$(now)
    T[$m]+="$(echo "$t1 - $t0" | bc) "
  done
done
"$PY" - "$DIR" "${T[scipy]}" "${T[dct]}" "${T[poisson]}" <<'PY'
import sys, json, numpy as np
d = sys.argv[1]
t = {m: np.median([float(x) for x in s.split()]) for m, s in zip(("scipy", "dct", "poisson"), sys.argv[2:5])}
truth = np.load(f"{d}/truth.npy")
def err(a):
    a = a - a.mean()
    return float(np.abs(a - truth).max())
e = {"scipy": err(np.load(f"{d}/scipy.npy"))}
for m in ("dct", "poisson"):
    e[m] = err(np.load(f"{d}/{m}/depth.npy"))
    r = json.load(open(f"{d}/{m}/report.json"))["timings_s"]
    print(f"{m:8s} median {t[m]:.3f} s  ({t['scipy'] / t[m]:.2f}x faster than scipy)  last run: "
          + ", ".join(f"{k} {v:.3f}" for k, v in r.items()) + f"  max|depth-truth| {e[m]:.2e} px")
print(f"scipy    median {t['scipy']:.3f} s  max|depth-truth| {e['scipy']:.2e} px")
PY
