"""Every Python block of the documentation runs: the fenced ```python blocks of README.md and
docs/*.md, each in a fresh interpreter, in a temporary folder laid out as the documentation
expects (`my_capture/`, a small synthetic capture in the folder layout with ground truth in
`gt/`, and `../shared` beside it). A block preceded by `<!-- not run: REASON -->` is skipped with
that reason. The shell blocks are run by crates/photostereo-cli/tests/doc_commands.rs."""

import pathlib
import re
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
SHARED = ROOT.parent / "shared"
NOT_RUN = re.compile(r"^<!--\s*not run:\s*(\S.*?)\s*-->$")


def python_blocks(path, root=ROOT):
    """(place, code, reason-not-to-run or None) for each ```python block of a markdown file;
    places are given relative to `root`."""
    lines = path.read_text(encoding="utf-8").splitlines()
    blocks, previous, i = [], "", 0
    while i < len(lines):
        line = lines[i]
        stripped = line.strip()
        if stripped.startswith("```"):
            lang = stripped[3:].strip().split(" ")[0].lower()
            start = i
            body = []
            i += 1
            while i < len(lines) and not lines[i].strip().startswith("```"):
                body.append(lines[i])
                i += 1
            if lang == "python":
                m = NOT_RUN.match(previous.strip())
                place = f"{path.relative_to(root)}:{start + 1}"
                blocks.append((place, "\n".join(body) + "\n", m.group(1) if m else None))
            previous = ""
        elif stripped:
            previous = stripped
        i += 1
    return blocks


def doc_files():
    return [ROOT / "README.md"] + sorted((ROOT / "docs").glob("*.md"))


BLOCKS = [b for f in doc_files() for b in python_blocks(f)]


def test_the_readme_has_a_python_quick_start():
    readme = [b for b in BLOCKS if b[0].startswith("README.md:")]
    assert readme, "README.md has no ```python block"
    assert any(b[2] is None for b in readme), "the README's Python quick start must run"


@pytest.mark.parametrize("place,code,reason", BLOCKS, ids=[b[0] for b in BLOCKS])
def test_python_block_runs(place, code, reason, tmp_path, cli):
    if reason is not None:
        pytest.skip(f"not run: {reason}")
    work = tmp_path / "work"
    work.mkdir()
    if SHARED.is_dir():
        (tmp_path / "shared").symlink_to(SHARED)
    subprocess.run(
        [cli, "synth", "sphere", "--rig", "ring8", "--size", "64", "-o", "my_capture", "--quiet"],
        cwd=work,
        check=True,
    )
    result = subprocess.run(
        [sys.executable, "-c", code], cwd=work, capture_output=True, text=True, timeout=600
    )
    assert result.returncode == 0, (
        f"{place}: the block failed\n--- code\n{code}\n--- stdout\n{result.stdout}\n"
        f"--- stderr\n{result.stderr}"
    )


def test_blocks_honour_the_not_run_marker(tmp_path):
    md = tmp_path / "x.md"
    md.write_text(
        "<!-- not run: needs a GPU -->\n```python\nimport x\n```\n\n```python\nprint(1)\n```\n"
        "\n```sh\nls\n```\n"
    )
    blocks = [(code, reason) for _, code, reason in python_blocks(md, root=tmp_path)]
    assert blocks == [("import x\n", "needs a GPU"), ("print(1)\n", None)]
