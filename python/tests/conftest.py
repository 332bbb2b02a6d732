"""Shared fixtures: the repository, the shared real captures and the command-line binary that
the Python results are checked against."""

import os
import pathlib
import subprocess

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
DATA = ROOT.parent / "shared" / "data"
DILIGENT = DATA / "diligent"


@pytest.fixture(scope="session")
def cli():
    """The `photostereo` binary of this checkout (built by `cargo build --release` if absent)."""
    exe = pathlib.Path(os.environ.get("PHOTOSTEREO_BIN", ROOT / "target" / "release" / "photostereo"))
    if not exe.exists():
        subprocess.run(
            ["cargo", "build", "--release", "-p", "photostereo-cli"], cwd=ROOT, check=True
        )
    return str(exe)


@pytest.fixture(scope="session")
def diligent():
    assert DILIGENT.is_dir(), f"{DILIGENT}: the shared DiLiGenT captures are missing"
    return DILIGENT
