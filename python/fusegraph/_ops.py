"""Ops written in Python: `@fusegraph.op` declares one in the terms of the
built-in declarations (ports with value types, parameters with kind,
default, unit, range and doc, a version), so it validates, caches and lists
in `fusegraph.nodes()` as they do.

The cache key of a Python op's nodes holds its declaration and the source
of its function: editing the function re-runs those nodes only. Bump
`version` when its results change for another reason (a library it calls).
"""

from __future__ import annotations

import inspect
import json
import os
import traceback
from dataclasses import dataclass, field
from typing import Any, Callable, Dict, List, Optional, Sequence, Union

from . import _native
from ._values import TYPES, from_native, to_native

__all__ = ["op", "Param", "Port", "Context"]

_KINDS = {
    int: "int",
    float: "float",
    bool: "bool",
    str: "string",
    "int": "int",
    "float": "float",
    "bool": "bool",
    "string": "string",
    "str": "string",
    "int_list": "int_list",
    "float_list": "float_list",
    "string_list": "string_list",
}


@dataclass
class Param:
    """A parameter: its kind (`int`, `float`, `bool`, `str`, or "int_list",
    "float_list", "string_list"), default (None: the graph must set it),
    unit (put it in the name too: `block_px`), range, choices and doc."""

    kind: Any
    default: Any = None
    unit: str = ""
    min: Optional[float] = None
    max: Optional[float] = None
    choices: Sequence[str] = ()
    doc: str = ""

    def declaration(self, name: str) -> dict:
        kind = _KINDS.get(self.kind)
        if kind is None:
            raise ValueError(f"parameter {name!r}: unknown kind {self.kind!r}")
        d = {"name": name, "kind": kind, "unit": self.unit, "doc": self.doc,
             "choices": list(self.choices)}
        if self.default is not None:
            d["default"] = list(self.default) if isinstance(self.default, (list, tuple)) else self.default
        if self.min is not None:
            d["min"] = float(self.min)
        if self.max is not None:
            d["max"] = float(self.max)
        return d


@dataclass
class Port:
    """A port: its value type (or types, for an input: "Image | Disparity"),
    whether an input may be left unconnected, and a doc with units and frame."""

    types: Union[str, Sequence[str]]
    optional: bool = False
    doc: str = ""

    def type_names(self, name: str) -> List[str]:
        names = self.types.split("|") if isinstance(self.types, str) else list(self.types)
        names = [t.strip() for t in names]
        for t in names:
            if t not in TYPES:
                raise ValueError(f"port {name!r}: unknown value type {t!r} (one of {', '.join(TYPES)})")
        return names


def _port(name: str, spec: Union[str, Port]) -> Port:
    return spec if isinstance(spec, Port) else Port(spec)


def _param(name: str, spec: Any) -> Param:
    if isinstance(spec, Param):
        return spec
    if isinstance(spec, (type, str)):
        return Param(spec)
    # A bare default: its kind follows from its Python type.
    if isinstance(spec, bool):
        return Param(bool, spec)
    if isinstance(spec, (int, float, str)):
        return Param(type(spec), spec)
    if isinstance(spec, (list, tuple)) and spec:
        first = type(spec[0])
        kind = {int: "int_list", float: "float_list", str: "string_list"}.get(first)
        if kind:
            return Param(kind, list(spec))
    raise ValueError(f"parameter {name!r}: give a fusegraph.Param or a default value, not {spec!r}")


class Context:
    """What an op records besides its outputs: `metric(name, value)` (units
    in the name: `rmse_mm`) and `note(text)` (an input refused or repaired,
    and why). A function that takes a `ctx` argument gets one."""

    def __init__(self) -> None:
        self.metrics: Dict[str, float] = {}
        self.notes: List[str] = []

    def metric(self, name: str, value: float) -> None:
        self.metrics[str(name)] = float(value)

    def note(self, text: str) -> None:
        self.notes.append(str(text))


def _source(fn: Callable) -> str:
    try:
        return inspect.getsource(fn)
    except (OSError, TypeError):
        # No source file (a REPL): the compiled code stands in for it.
        code = fn.__code__
        return code.co_code.hex() + repr(code.co_consts) + repr(code.co_names)


def _last_line(e: BaseException) -> str:
    frames = traceback.extract_tb(e.__traceback__)
    where = ""
    if frames:
        f = frames[-1]
        where = f" ({os.path.basename(f.filename)}, line {f.lineno}, in {f.name})"
    return "".join(traceback.format_exception_only(type(e), e)).strip().splitlines()[-1] + where


def _invoker(fn: Callable, outputs: Dict[str, Port]) -> Callable:
    wants_ctx = "ctx" in inspect.signature(fn).parameters
    out_types = {name: port.type_names(name)[0] for name, port in outputs.items()}

    def invoke(inputs: dict, params: dict) -> dict:
        ctx = Context()
        try:
            kwargs = {k: from_native(v) for k, v in inputs.items()}
            kwargs.update(params)
            if wants_ctx:
                kwargs["ctx"] = ctx
            result = fn(**kwargs)
            if len(out_types) == 1 and not (isinstance(result, dict) and set(result) == set(out_types)):
                result = {next(iter(out_types)): result}
            if not isinstance(result, dict):
                raise TypeError(f"return a dict of the outputs {sorted(out_types)}, not {type(result).__name__}")
            missing = sorted(set(out_types) - set(result))
            if missing:
                raise ValueError(f"returned no output {', '.join(repr(m) for m in missing)}")
            native = {}
            for name, ty in out_types.items():
                try:
                    native[name] = to_native(result[name], ty)
                except Exception as e:  # noqa: BLE001 - named for the user
                    raise ValueError(f"output {name!r} ({ty}): {e}") from e
        except Exception as e:  # noqa: BLE001 - becomes the node's error
            return {"error": _last_line(e)}
        return {"outputs": native, "metrics": ctx.metrics, "notes": ctx.notes}

    return invoke


def op(
    name: str,
    *,
    version: int = 1,
    inputs: Optional[Dict[str, Union[str, Port]]] = None,
    outputs: Optional[Dict[str, Union[str, Port]]] = None,
    params: Optional[Dict[str, Any]] = None,
    doc: Optional[str] = None,
) -> Callable[[Callable], Callable]:
    """Declares the decorated function as the op `name` (`stage.action`).

    The function is called with each connected input (as numpy arrays or
    the package's value classes) and each parameter as keyword arguments
    (and `ctx`, a `Context`, if it takes one); it returns the output's value
    or, for several outputs, a dict of them. An exception fails the node
    with the op's name and the traceback's last line; the rest of the graph
    goes on.

        @fusegraph.op("my.matcher", version=1,
                      inputs={"left": "Image", "right": "Image"},
                      outputs={"disparity": "Disparity"},
                      params={"max_disparity_px": fusegraph.Param(int, 64, unit="px", min=1)})
        def matcher(left, right, max_disparity_px):
            ...
    """
    ins = {k: _port(k, v) for k, v in (inputs or {}).items()}
    outs = {k: _port(k, v) for k, v in (outputs or {}).items()}
    ps = {k: _param(k, v) for k, v in (params or {}).items()}

    def declare(fn: Callable) -> Callable:
        text = doc if doc is not None else (inspect.getdoc(fn) or "").split("\n")[0]
        declaration = {
            "name": name,
            "version": int(version),
            "doc": text,
            "inputs": [{"name": k, "types": p.type_names(k), "optional": p.optional, "doc": p.doc}
                       for k, p in ins.items()],
            "outputs": [{"name": k, "type": p.type_names(k)[0], "doc": p.doc} for k, p in outs.items()],
            "params": [p.declaration(k) for k, p in ps.items()],
        }
        for k, p in outs.items():
            if len(p.type_names(k)) != 1:
                raise ValueError(f"op {name!r}: output {k!r} must have one type")
        try:
            file = inspect.getsourcefile(fn) or "<python>"
        except TypeError:
            file = "<python>"
        _native.declare(json.dumps(declaration), _invoker(fn, outs),
                        os.path.abspath(file) if file != "<python>" else file, _source(fn))
        fn.fusegraph_op = name
        return fn

    return declare

