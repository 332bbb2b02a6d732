"""The parameters of a reconstruction as Python objects, built from the library's table.

Nothing here lists a parameter: :class:`Params` and its stage groups are made at import from
``_native.parameters()``, the library's one table (name, type, default, domain, unit, meaning,
stage, methods), so a parameter added to the library appears here with its default and its
documentation, and a value outside its domain is refused by the library's own check.
"""

from __future__ import annotations

import difflib
from typing import Any, Dict, Iterable, Mapping, Optional

from . import _native

#: The library's table: one dict per parameter, in table order.
TABLE = [dict(p) for p in _native.parameters()]
_BY_NAME = {p["name"]: p for p in TABLE}
#: The stages, in table order; ``run`` holds the parameters of the run as a whole.
STAGES = list(dict.fromkeys(p["stage"] for p in TABLE))
_NESTED = [s for s in STAGES if s != "run"]


def _python_type(p: Dict[str, Any]) -> str:
    if p["type"] == "choice":
        return "{" + ", ".join(f'"{c}"' for c in p["choices"]) + "}"
    return {
        "bool": "bool",
        "int": "int",
        "float": "float",
        "float or none": "float or None",
        "bytes": "int, str or None",
    }[p["type"]]


def _entry(p: Dict[str, Any]) -> str:
    """One numpydoc entry: ``name : type, default value`` and the doc, domain, unit, methods."""
    methods = p["methods"]
    used = "every method" if len(methods) == len(_native.methods()) else ", ".join(methods)
    lines = [f"{p['name']} : {_python_type(p)}, default {p['default']!r}", f"    {p['doc']}"]
    domain = f"Expected: {p['domain']}"
    if p["none"]:
        domain += f" (None: {p['none']})"
    if p["unit"]:
        domain += f"; unit: {p['unit']}"
    lines.append(f"    {domain}. Used by {used}.")
    return "\n".join(lines)


def suggest(name: str) -> str:
    """`` (did you mean x?)`` for a misspelt parameter name, or nothing."""
    close = difflib.get_close_matches(name, list(_BY_NAME), n=3)
    return f" (did you mean {', '.join(close)}?)" if close else ""


def check_names(function: str, names: Iterable[str]) -> None:
    """Raises TypeError, as Python does, for keywords that name no parameter."""
    unknown = [n for n in names if n not in _BY_NAME]
    if unknown:
        raise TypeError(
            f"{function}() got unexpected keyword argument(s): "
            + ", ".join(f"{n!r}{suggest(n)}" for n in unknown)
        )


class _Group:
    """The parameters of one stage: attributes checked by the library's table on assignment."""

    __slots__ = ("_values",)
    _names: tuple = ()

    def __init__(self, **values: Any):
        object.__setattr__(self, "_values", {n: _BY_NAME[n]["default"] for n in self._names})
        for name, value in values.items():
            setattr(self, name, value)

    def __setattr__(self, name: str, value: Any) -> None:
        if name not in self._names:
            raise AttributeError(
                f"{type(self).__name__} has no parameter {name!r}{suggest(name)}"
            )
        setattr_checked(self, name, value)

    def to_dict(self) -> Dict[str, Any]:
        """The values, keyed by parameter name."""
        return dict(self._values)

    def __eq__(self, other: object) -> bool:
        return type(other) is type(self) and other._values == self._values  # type: ignore[attr-defined]

    def __repr__(self) -> str:
        changed = ", ".join(
            f"{n}={v!r}" for n, v in self._values.items() if v != _BY_NAME[n]["default"]
        )
        return f"{type(self).__name__}({changed})"

    def __reduce__(self):
        return (_rebuild_group, (type(self).__name__, self.to_dict()))


def _rebuild_group(name: str, values: Dict[str, Any]) -> "_Group":
    return _GROUPS[name](**values)


def _property(name: str) -> property:
    """A parameter's attribute: read from the group's values; set through ``__setattr__``,
    which checks the value."""

    def get(self: Any) -> Any:
        return self._values[name]

    return property(get, doc=_entry(_BY_NAME[name]))


def setattr_checked(obj: Any, name: str, value: Any) -> None:
    """Sets parameter ``name`` of a group after the library's check of ``value``."""
    _native.check_parameter(name, value)
    obj._values[name] = value


def _group_class(stage: str) -> type:
    names = tuple(p["name"] for p in TABLE if p["stage"] == stage)
    title = stage.capitalize() + "Params"
    doc = (
        f"{TABLE[[p['stage'] for p in TABLE].index(stage)]['stage_doc']}\n\n"
        f"Part of :class:`Params` (``params.{stage}``); every value is checked by the library's "
        "table when it is set.\n\nAttributes\n----------\n"
        + "\n".join(_entry(_BY_NAME[n]) for n in names)
    )
    namespace: Dict[str, Any] = {"__slots__": (), "_names": names, "__doc__": doc}
    namespace["__module__"] = "photostereo"
    for n in names:
        namespace[n] = _property(n)
    return type(title, (_Group,), namespace)


_GROUPS = {stage.capitalize() + "Params": _group_class(stage) for stage in _NESTED}
DetectionParams = _GROUPS["DetectionParams"]
RecursiveParams = _GROUPS["RecursiveParams"]
IntegrationParams = _GROUPS["IntegrationParams"]


class Params(_Group):
    __slots__ = tuple(_NESTED)
    _names = tuple(p["name"] for p in TABLE if p["stage"] == "run")

    def __init__(self, **overrides: Any):
        object.__setattr__(self, "_values", {n: _BY_NAME[n]["default"] for n in self._names})
        for stage in _NESTED:
            object.__setattr__(self, stage, _GROUPS[stage.capitalize() + "Params"]())
        self._apply(overrides, "Params")

    def _apply(self, overrides: Mapping[str, Any], function: str) -> None:
        check_names(function, [k for k in overrides if k not in _NESTED])
        for name, value in overrides.items():
            if name in _NESTED:
                group = _GROUPS[name.capitalize() + "Params"]
                if isinstance(value, Mapping):
                    value = group(**value)
                if not isinstance(value, group):
                    raise TypeError(f"{name}: expected a {group.__name__} or a dict")
                object.__setattr__(self, name, group(**value.to_dict()))
                continue
            stage = _BY_NAME[name]["stage"]
            target = self if stage == "run" else getattr(self, stage)
            setattr_checked(target, name, value)

    def __setattr__(self, name: str, value: Any) -> None:
        if name in _NESTED:
            self._apply({name: value}, "Params")
        elif name in self._names:
            setattr_checked(self, name, value)
        else:
            raise AttributeError(
                f"Params has no attribute {name!r}{suggest(name)}; the parameters of a stage "
                f"are set on it ({', '.join('params.' + s for s in _NESTED)})"
            )

    def replace(self, **overrides: Any) -> "Params":
        """A copy with ``overrides`` (parameters by name, or whole stages) applied."""
        out = Params(**self.to_dict())
        out._apply(overrides, "replace")
        return out

    def to_dict(self) -> Dict[str, Any]:
        """Every parameter by name, flat: the keywords :func:`reconstruct` and :func:`run`
        take, and what :func:`defaults` gives for a default ``Params``."""
        out = dict(self._values)
        for stage in _NESTED:
            out.update(getattr(self, stage).to_dict())
        return {p["name"]: out[p["name"]] for p in TABLE}

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> "Params":
        """Parameters from a flat mapping of names to values (missing ones default)."""
        return cls(**dict(values))

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Params) and other.to_dict() == self.to_dict()

    def __repr__(self) -> str:
        changed = ", ".join(
            f"{n}={v!r}" for n, v in self.to_dict().items() if v != _BY_NAME[n]["default"]
        )
        return f"Params({changed})"

    def __reduce__(self):
        return (_rebuild_params, (self.to_dict(),))


def _rebuild_params(values: Dict[str, Any]) -> Params:
    return Params(**values)


for _name in Params._names:
    setattr(Params, _name, _property(_name))


Params.__module__ = "photostereo"
Params.__doc__ = (
    "Every parameter of a reconstruction, nested by stage, with the library's defaults.\n\n"
    "Built from the library's parameter table (the one the command line's flags come from); "
    "each value is checked when it is set, and a bad one raises PhotostereoError naming the "
    "parameter. Pass it to :func:`reconstruct` or :func:`run` as ``params=``; keywords given "
    "there override it.\n\n"
    "Parameters\n----------\n**overrides\n"
    "    Any parameter by name (``confidence=0.99``), or a whole stage "
    "(``detection=DetectionParams(...)`` or a dict).\n\n"
    "Attributes\n----------\n"
    + "\n".join(_entry(_BY_NAME[n]) for n in Params._names)
    + "\n"
    + "\n".join(
        f"{s} : {s.capitalize()}Params\n    "
        + TABLE[[p['stage'] for p in TABLE].index(s)]["stage_doc"]
        for s in _NESTED
    )
    + "\n\nExamples\n--------\n"
    ">>> p = Params(method=\"l2\", confidence=0.99)\n"
    ">>> p.detection.confidence\n0.99\n"
    ">>> p.replace(max_iterations=3).recursive.max_iterations\n3\n"
)


def build(params: Optional[Params], overrides: Mapping[str, Any], function: str) -> Dict[str, Any]:
    """The flat parameter dict of ``params`` (or the defaults) with ``overrides`` applied, each
    checked against the table."""
    if params is not None and not isinstance(params, Params):
        if isinstance(params, Mapping):
            params = Params.from_dict(params)
        else:
            raise TypeError(f"params: expected a photostereo.Params or a dict, got {params!r}")
    base = Params() if params is None else params
    if overrides:
        base = Params(**base.to_dict())
        base._apply(overrides, function)
    return base.to_dict()
