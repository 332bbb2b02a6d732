"""`photostereo rti` files read by readers written here from the format descriptions, not by
the library: PTM v1.2 (HP Labs: ASCII header, bottom-up rows, coefficient = (byte - bias) *
scale) and RTIViewer's HSH `.rti` (ASCII header, float32 scales and biases, top-down rows,
coefficient = byte / 255 * scale + bias). The dequantised coefficients must equal the fit's
float coefficients (coefficients.npy) within half a quantisation step, and relighting from the
file must match relighting from the floats."""

import json
import math
import subprocess

import numpy as np
import pytest


def hsh_basis(l, terms):
    """Hemispherical harmonics (Gautron et al. 2004) in RTIViewer's order, cos(theta) = l_z."""
    ct = min(max(l[2], 0.0), 1.0)
    phi = math.atan2(l[1], l[0])
    s = math.sqrt(max(ct - ct * ct, 0.0))
    h = [
        1 / math.sqrt(2 * math.pi),
        math.sqrt(6 / math.pi) * math.cos(phi) * s,
        math.sqrt(3 / (2 * math.pi)) * (2 * ct - 1),
        math.sqrt(6 / math.pi) * math.sin(phi) * s,
        math.sqrt(30 / math.pi) * math.cos(2 * phi) * (ct * ct - ct),
        math.sqrt(30 / math.pi) * math.cos(phi) * (2 * ct - 1) * s,
        math.sqrt(5 / (2 * math.pi)) * (6 * ct * ct - 6 * ct + 1),
        math.sqrt(30 / math.pi) * math.sin(phi) * (2 * ct - 1) * s,
        math.sqrt(30 / math.pi) * math.sin(2 * phi) * (ct * ct - ct),
    ]
    return np.array(h[:terms])


def ptm_basis(l):
    u, v = l[0], l[1]
    return np.array([u * u, v * v, u * v, u, v, 1.0])


def header_lines(data, n):
    lines, at = [], 0
    while len(lines) < n:
        end = data.index(b"\n", at)
        lines.append(data[at:end].decode("ascii").strip())
        at = end + 1
    return lines, at


def read_ptm(path):
    data = path.read_bytes()
    head, at = header_lines(data, 6)
    assert head[0] == "PTM_1.2"
    w, h = int(head[2]), int(head[3])
    scale = np.array([float(x) for x in head[4].split()])
    bias = np.array([int(x) for x in head[5].split()])
    planes = 1 if head[1] == "PTM_FORMAT_LRGB" else 3
    n = w * h * 6
    coeffs = []
    for _ in range(planes):
        raw = np.frombuffer(data, np.uint8, n, at).reshape(h, w, 6)[::-1]  # bottom row first
        coeffs.append((raw.astype(np.float64) - bias) * scale)
        at += n
    rgb = None
    if planes == 1:
        rgb = np.frombuffer(data, np.uint8, w * h * 3, at).reshape(h, w, 3)[::-1]
        at += w * h * 3
    assert at == len(data)
    return head[1], np.stack(coeffs, axis=2), scale, rgb


def read_hsh(path):
    data = path.read_bytes()
    head, at = header_lines(data, 4)
    assert head[0].startswith("#") and head[1] == "3"
    w, h, bands = map(int, head[2].split())
    terms, basis_type, size = map(int, head[3].split())
    assert (bands, basis_type, size) == (3, 2, 1)
    scale = np.frombuffer(data, "<f4", terms, at).astype(np.float64)
    bias = np.frombuffer(data, "<f4", terms, at + 4 * terms).astype(np.float64)
    raw = np.frombuffer(data, np.uint8, w * h * 3 * terms, at + 8 * terms)
    assert at + 8 * terms + raw.size == len(data)
    coeffs = raw.reshape(h, w, 3, terms).astype(np.float64) / 255.0 * scale + bias
    return coeffs, scale


@pytest.fixture(scope="module")
def capture(cli, tmp_path_factory):
    folder = tmp_path_factory.mktemp("rti") / "dome"
    subprocess.run([cli, "synth", "sphere", "--rig", "dome-30", "--size", "40", "-o",
                    str(folder), "--quiet"], check=True)
    lights = np.loadtxt(folder / "light_directions.txt")
    return folder, lights


@pytest.mark.parametrize("basis", ["ptm", "ptm-rgb", "hsh2", "hsh3"])
def test_files_hold_the_fit_within_quantisation(cli, capture, tmp_path, basis):
    folder, lights = capture
    out = tmp_path / basis
    subprocess.run([cli, "rti", str(folder), "--basis", basis, "-o", str(out), "--quiet"],
                   check=True)
    report = json.loads((out / "report.json").read_text())
    assert report["basis"] == basis
    assert len(report["leave_one_out"]["rmse_8bit"]) == len(lights)
    floats = np.load(out / "coefficients.npy")  # (H, W, fitted channels, T), display units
    mask = np.any(floats != 0, axis=(2, 3))
    assert mask.sum() > 100
    if basis.startswith("ptm"):
        fmt, coeffs, scale, rgb = read_ptm(out / "image.ptm")
        assert fmt == ("PTM_FORMAT_LRGB" if basis == "ptm" else "PTM_FORMAT_RGB")
        if basis == "ptm":
            chroma = np.load(out / "chroma.npy")
            m = np.maximum(chroma.max(axis=2), 1e-30)[..., None]
            want = 255.0 * m[..., None] * floats  # L = 255 m Y
            assert np.all(np.abs(coeffs - want)[mask] <= 0.5 * scale * 1.001 + 1e-6)
            assert np.all(np.abs(rgb - 255.0 * chroma / m)[mask] <= 0.5 + 1e-4)
        else:
            want = 255.0 * np.repeat(floats, 3, axis=2) if floats.shape[2] == 1 else 255.0 * floats
            assert np.all(np.abs(coeffs - want)[mask] <= 0.5 * scale * 1.001 + 1e-6)
        for l in lights[::5]:
            b = ptm_basis(l)
            poly = coeffs @ b  # (H, W, planes)
            shown = rgb * poly / 255.0 if basis == "ptm" else poly
            if basis == "ptm":
                truth = 255.0 * chroma * (floats[:, :, 0, :] @ b)[..., None]
                bound = 0.5 * np.abs(b) @ scale + np.abs(poly) / 255.0
            else:
                truth = 255.0 * (floats @ b)
                bound = 0.5 * np.abs(b) @ scale
            err = np.abs(shown - truth)[mask]
            bound = np.broadcast_to(bound, shown.shape)[mask]
            assert np.all(err <= bound * 1.001 + 1e-6), err.max()
    else:
        coeffs, scale = read_hsh(out / "image.rti")
        terms = coeffs.shape[3]
        assert terms == (4 if basis == "hsh2" else 9)
        full = np.repeat(floats, 3, axis=2) if floats.shape[2] == 1 else floats
        assert np.all(np.abs(coeffs - full)[mask] <= scale / 255.0 * 0.5 * 1.001 + 1e-7)
        for l in lights[::5]:
            b = hsh_basis(l, terms)
            err = np.abs(255.0 * (coeffs @ b) - 255.0 * (full @ b))[mask]
            assert np.all(err <= 255.0 * (np.abs(b) @ scale) / 255.0 * 0.5 * 1.001 + 1e-5)


@pytest.mark.parametrize("basis", ["hsh2", "rbf"])
def test_python_rti_writes_what_the_command_line_writes(cli, capture, tmp_path, basis):
    import photostereo

    folder, lights = capture
    report = photostereo.rti(folder, tmp_path / "py", basis=basis)
    subprocess.run([cli, "rti", str(folder), "--basis", basis, "-o", str(tmp_path / "cli"),
                    "--quiet"], check=True)
    on_disk = json.loads((tmp_path / "cli" / "report.json").read_text())
    assert report["basis"] == basis
    assert len(report["leave_one_out"]["rmse_8bit"]) == len(lights)
    assert report["leave_one_out"]["mean_rmse_8bit"] == pytest.approx(
        on_disk["leave_one_out"]["mean_rmse_8bit"], rel=1e-9)
    assert np.array_equal(np.load(tmp_path / "py" / "coefficients.npy"),
                          np.load(tmp_path / "cli" / "coefficients.npy"))
    assert (tmp_path / "py" / "relight" / "info.json").is_file()
    with pytest.raises(photostereo.PhotostereoError, match="basis"):
        photostereo.rti(folder, tmp_path / "bad", basis="rbf9")
    assert not (tmp_path / "bad").exists()
    if basis == "rbf":
        # RBF has no ridge weight.
        with pytest.raises(photostereo.PhotostereoError, match="ridge"):
            photostereo.rti(folder, tmp_path / "bad", basis=basis, ridge=0.1)
        assert not (tmp_path / "bad").exists()
        return
    # ridge=0 is the command line's --ridge 0: the unregularised fit.
    plain = photostereo.rti(folder, tmp_path / "py0", basis=basis, ridge=0.0)
    subprocess.run([cli, "rti", str(folder), "--basis", basis, "--ridge", "0", "-o",
                    str(tmp_path / "cli0"), "--quiet"], check=True)
    assert plain["ridge"]["lambda"] == 0.0 and plain["ridge"]["candidates"] == []
    assert report["ridge"]["candidates"][0]["lambda"] == 0.0
    assert np.array_equal(np.load(tmp_path / "py0" / "coefficients.npy"),
                          np.load(tmp_path / "cli0" / "coefficients.npy"))


def test_python_iiif_and_run_rti_write_what_the_command_line_writes(cli, capture, tmp_path):
    import photostereo

    folder, _ = capture
    base = "https://example.org/obj"
    report = photostereo.rti(folder, tmp_path / "py", basis="hsh2", iiif=base + "/")
    subprocess.run([cli, "rti", str(folder), "--basis", "hsh2", "--iiif", base, "-o",
                    str(tmp_path / "cli"), "--quiet"], check=True)
    # hsh2: 4 terms × 3 channels = 12 planes in 4 RGB images, each with its IIIF service.
    ids = [f"{base}/relight/plane_{g}" for g in range(4)]
    assert report["web"]["iiif"] == ids
    for g, id_ in enumerate(ids):
        py_dir = tmp_path / "py" / "relight" / f"plane_{g}"
        info = json.loads((py_dir / "info.json").read_text())
        assert info["id"] == id_ and info["profile"] == "level0"
        cli_dir = tmp_path / "cli" / "relight" / f"plane_{g}"
        py_files = sorted(p.relative_to(py_dir) for p in py_dir.rglob("*") if p.is_file())
        cli_files = sorted(p.relative_to(cli_dir) for p in cli_dir.rglob("*") if p.is_file())
        assert py_files == cli_files and len(py_files) >= 2
        for f in py_files:
            assert (py_dir / f).read_bytes() == (cli_dir / f).read_bytes(), f
    with pytest.raises(photostereo.PhotostereoError, match="iiif"):
        photostereo.rti(folder, tmp_path / "bad", basis="hsh2", iiif="ftp://example.org")
    assert not (tmp_path / "bad").exists()

    # run(..., rti=) is the command line's run --rti: the same fit beside the normals.
    run = photostereo.run(folder, tmp_path / "run_py", rti="hsh3")
    subprocess.run([cli, "run", str(folder), "--rti", "hsh3", "-o", str(tmp_path / "run_cli"),
                    "--quiet"], check=True)
    assert run["rti"]["basis"] == "hsh3" and run["rti"]["file"]["name"] == "image.rti"
    for name in ["image.rti", "coefficients.npy", "relight/info.json", "relight/plane_8.png"]:
        assert ((tmp_path / "run_py" / name).read_bytes()
                == (tmp_path / "run_cli" / name).read_bytes()), name
    coeffs, _ = read_hsh(tmp_path / "run_py" / "image.rti")
    floats = np.load(tmp_path / "run_py" / "coefficients.npy")
    assert coeffs.shape[3] == 9 and floats.shape[3] == 9
