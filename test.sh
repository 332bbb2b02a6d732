#!/usr/bin/env bash
# Every test of the project on a fresh machine with the Rust toolchain and Python 3:
# the Rust workspace, then the Python package, built with maturin into its own virtual
# environment (target/py-venv, made on first use) and tested with pytest.
set -euo pipefail
cd "$(dirname "$0")"
cargo test --release --workspace
venv="${PHOTOSTEREO_VENV:-target/py-venv}"
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
fi
# maturin's build hook runs `maturin` from PATH.
export PATH="$(cd "$venv/bin" && pwd):$PATH"
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check \
    "maturin>=1.5,<2" numpy pytest hypothesis "dask[distributed]" rawpy pidng
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check --no-build-isolation .
"$venv/bin/python" -m pytest python/tests
