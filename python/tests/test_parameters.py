"""The Python front end against the library's parameter table: ``defaults()``, ``Params``
(nested by stage, documented), the keywords ``reconstruct`` accepts (each reaching the library's
report), the native stub and ``docs/parameters.md``. The command line's flags are checked
against the same table by the CLI's tests (crates/photostereo-cli/src/params.rs), so a
parameter removed from one front end only, or a default changed there, fails a test."""

import pickle
import types

import numpy as np
import pytest

import photostereo as ps
from photostereo import _native
from conftest import ROOT

TABLE = _native.parameters()


def differences(what, expected, surface):
    """Every disagreement between the table (``expected``: name -> default) and a front end's
    ``surface`` (name -> default): missing, unknown, or another default."""
    out = []
    for name, value in expected.items():
        if name not in surface:
            out.append(f"{what}: {name} is missing")
        elif surface[name] != value:
            out.append(f"{what}: {name} defaults to {surface[name]!r}, the library to {value!r}")
    out += [f"{what}: {name} is not in the library's table" for name in surface if name not in expected]
    return out


def params_surface(params):
    """What a Params offers: each table parameter found on its stage's group (the run's on the
    object itself), with its value and its documentation."""
    out = {}
    for p in TABLE:
        owner = params if p["stage"] == "run" else getattr(params, p["stage"], None)
        if owner is None or not hasattr(owner, p["name"]):
            continue
        doc = getattr(type(owner), p["name"], None).__doc__ or ""
        documented = p["doc"] in doc and f"default {p['default']!r}" in doc
        out[p["name"]] = getattr(owner, p["name"]) if documented else "(undocumented)"
    return out


def stub_surface(text):
    """The parameters of the stub's generated ``ParamValues`` block and their defaults."""
    block = text.split("# --- parameters: generated from the library's table ---")[-1]
    block = block.split("# --- end of the generated parameters ---")[0]
    out = {}
    for line in block.splitlines():
        if line.startswith("    ") and ": " in line and "# default " in line:
            name = line.strip().split(":")[0]
            out[name] = eval(line.split("# default ")[1])  # noqa: S307 - our own stub
    return out


def docs_surface(text):
    """The Python cells (``name=default``) of docs/parameters.md."""
    out = {}
    for line in text.splitlines():
        if line.startswith("| `--"):
            cell = line.split("|")[2].strip().strip("`")
            name, default = cell.split("=", 1)
            out[name] = eval(default)  # noqa: S307 - our own page
    return out


def surfaces(defaults, params, stub, page):
    expected = {p["name"]: p["default"] for p in TABLE}
    problems = []
    problems += differences("defaults()", expected, defaults)
    problems += differences("Params()", expected, params_surface(params))
    problems += differences("_native.pyi", expected, stub_surface(stub))
    problems += differences("docs/parameters.md", expected, docs_surface(page))
    return problems


def test_every_parameter_is_offered_with_the_librarys_default():
    stub = (ROOT / "python" / "photostereo" / "_native.pyi").read_text()
    page = (ROOT / "docs" / "parameters.md").read_text()
    assert surfaces(ps.defaults(), ps.Params(), stub, page) == []


def test_the_checker_reports_a_removal_from_one_front_end():
    stub = (ROOT / "python" / "photostereo" / "_native.pyi").read_text()
    page = (ROOT / "docs" / "parameters.md").read_text()
    # A keyword gone from defaults() only.
    doctored = {k: v for k, v in ps.defaults().items() if k != "consensus_radius"}
    assert surfaces(doctored, ps.Params(), stub, page) == ["defaults(): consensus_radius is missing"]
    # A default changed in defaults() only.
    doctored = dict(ps.defaults(), confidence=0.9)
    assert surfaces(doctored, ps.Params(), stub, page) == [
        "defaults(): confidence defaults to 0.9, the library to 0.95"
    ]
    # A Params whose recursive stage lacks one parameter.
    params = ps.Params()
    recursive = {k: v for k, v in params.recursive.to_dict().items() if k != "fallback"}
    fake = types.SimpleNamespace(**{p["name"]: getattr(params, p["name"]) for p in TABLE
                                    if p["stage"] == "run"})
    fake.detection, fake.integration = params.detection, params.integration
    fake.recursive = types.SimpleNamespace(**recursive)
    problems = surfaces(ps.defaults(), fake, stub, page)
    assert "Params(): fallback is missing" in problems
    # A keyword gone from the stub, a row from the page.
    doctored_stub = "\n".join(l for l in stub.splitlines() if not l.strip().startswith("batch_alpha:"))
    assert surfaces(ps.defaults(), ps.Params(), doctored_stub, page) == [
        "_native.pyi: batch_alpha is missing"
    ]
    doctored_page = "\n".join(l for l in page.splitlines() if "`shadow_ratio=" not in l)
    assert surfaces(ps.defaults(), ps.Params(), stub, doctored_page) == [
        "docs/parameters.md: shadow_ratio is missing"
    ]


def tiny():
    """A 12 × 12 Lambertian plane under six lights: a capture every method runs on in ms."""
    t = np.linspace(0, 2 * np.pi, 6, endpoint=False)
    lights = np.stack([0.5 * np.cos(t), 0.5 * np.sin(t), np.full(6, 0.8)], 1)
    lights /= np.linalg.norm(lights, axis=1, keepdims=True)
    n = np.array([0.1, 0.2, 1.0]) / np.linalg.norm([0.1, 0.2, 1.0])
    images = np.broadcast_to((lights @ n)[:, None, None], (6, 12, 12)).astype(np.float32)
    return ps.Capture.from_arrays(images.copy(), lights)


def reported(report, key):
    v = report["parameters"]
    for part in key.split("."):
        if part not in v:
            return "(not reported)"
        v = v[part]
    return v


def test_every_keyword_reaches_the_library():
    """Each parameter given to reconstruct by keyword, at a value other than its default, is
    what the library's report records (the shadow tolerances are recorded once changed)."""
    cap = tiny()
    for p in TABLE:
        d = p["default"]
        if p["type"] == "bool":
            value = not d
        elif p["type"] == "choice":
            value = [c for c in p["choices"] if c != d][0]
        elif p["type"] == "int":
            value = d + 1
        elif p["type"] == "bytes":
            value = 1 << 30
        elif p["name"] == "confidence":
            value = 0.9
        elif p["name"] == "attached_tolerance":
            value = 0.05
        else:
            value = 0.5 if d != 0.5 else 0.25
        kwargs = {"integrate": False, p["name"]: value}
        if p["name"] == "noise_refinements":
            kwargs["noise_estimate"] = "residuals"
        rec = ps.reconstruct(cap, **kwargs)
        assert reported(rec.report, p["report_key"]) == value, (p["name"], value)
        # The same through a Params object.
        again = ps.reconstruct(cap, params=ps.Params(**kwargs))
        assert reported(again.report, p["report_key"]) == value, p["name"]


def test_params_nests_by_stage_checks_values_and_pickles():
    p = ps.Params(method="l2", confidence=0.99, max_iterations=3)
    assert p.method == "l2" and p.detection.confidence == 0.99
    assert p.recursive.max_iterations == 3 and p.integration.integrator == "bilateral"
    assert p.to_dict() == dict(ps.defaults(), method="l2", confidence=0.99, max_iterations=3)
    assert p.replace(fallback="brightest").recursive.fallback == "brightest"
    assert p.recursive.fallback == "neighbours"
    assert pickle.loads(pickle.dumps(p)) == p
    assert repr(p) == "Params(method='l2', confidence=0.99, max_iterations=3)"
    with pytest.raises(ps.PhotostereoError, match=r"confidence 1\.5: expected a number in \(0\.5, 1\)"):
        p.detection.confidence = 1.5
    with pytest.raises(ps.PhotostereoError, match="max_iterations 0"):
        ps.Params(max_iterations=0)
    with pytest.raises(ps.PhotostereoError, match="memory_limit 'lots'"):
        ps.Params(memory_limit="lots")
    with pytest.raises(TypeError, match="did you mean confidence"):
        ps.Params(confidense=0.9)
    with pytest.raises(AttributeError, match="no parameter"):
        p.detection.max_iterations = 3
    # Keywords of reconstruct override params=; an unknown one is a TypeError.
    cap = tiny()
    rec = ps.reconstruct(cap, params=p, method="l2", integrate=False, confidence=0.9)
    assert rec.report["parameters"]["detection"]["confidence"] == 0.9
    with pytest.raises(TypeError, match="unexpected keyword.*'metod'"):
        ps.reconstruct(cap, metod="l2")
    # numpydoc: every parameter with its default in the class documentation.
    for q in TABLE:
        cls = ps.Params if q["stage"] == "run" else getattr(ps, q["stage"].capitalize() + "Params")
        assert f"{q['name']} : " in cls.__doc__, q["name"]
    assert "Attributes\n----------" in ps.Params.__doc__


def test_other_functions_default_to_the_table():
    """Keywords outside ``reconstruct``/``run`` that are table parameters take the table's
    default (``integrate``'s ``max_slope``), and the stub declares the native classes."""
    import inspect

    assert inspect.signature(ps.integrate).parameters["max_slope"].default == ps.defaults()["max_slope"]
    stub = (ROOT / "python" / "photostereo" / "_native.pyi").read_text()
    assert "def reconstruct(" in stub and "class NativeCapture" in stub
