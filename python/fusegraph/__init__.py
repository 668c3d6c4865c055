"""fusegraph from Python.

Run a graph and read every node's outputs as numpy arrays::

    import fusegraph
    r = fusegraph.run("graphs/mri.toml", set={"phantom.size": "small"})
    r.metrics["markers.count"], r.outputs["load.volume"].array.shape

Declare an op in Python, which graphs then name like a built-in one::

    @fusegraph.op("my.threshold", inputs={"volume": "Volume"}, outputs={"mask": "Mask"},
                  params={"level": fusegraph.Param(float, 100.0, doc="intensity")})
    def threshold(volume, level):
        return fusegraph.Mask((volume.array > level).astype("uint8"), volume.affine)

Errors are exceptions with the command line's messages: `GraphError` (an
invalid graph; `.errors` lists each problem with its file, node and key),
`OSError` (a file or folder that cannot be read or written). A node that
fails does not raise: the result says so (`ok`, `failed`, `errors`).
"""

from __future__ import annotations

import json
import os
from typing import Any, Dict, List, Mapping, Optional, Tuple, Union

from . import _native
from ._ops import Context, Param, Port, op
from ._values import (
    Camera, Labels, Markers, Mask, Matches, Mesh, PointCloud, Rectification,
    StereoRig, Transform, Volume, from_native, to_native,
)
from ._values import _CLASSES

GraphError = _native.GraphError

__all__ = [
    "run", "validate", "nodes", "sweep", "op", "Param", "Port", "Context",
    "Result", "GraphError", "Volume", "Mask", "Labels", "Mesh", "PointCloud",
    "Markers", "Matches", "Camera", "StereoRig", "Rectification", "Transform",
]

PathLike = Union[str, "os.PathLike[str]"]


def _sets(set: Optional[Mapping[str, Any]]) -> List[str]:
    """`{"node.key": value}` as `--set node.key=VALUE` (VALUE in TOML; an op
    name or a `node.port` source bare, as on the command line)."""
    out = []
    for key, value in (set or {}).items():
        bare = key.endswith(".op") or ".in." in key
        out.append(f"{key}={value if bare else _toml(value)}")
    return out


def _toml(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, os.PathLike):
        value = os.fspath(value)
    return json.dumps(str(value))


class Result:
    """What a run produced.

    - `ok`: every node ran or came from the cache; `failed`: the ids of
      nodes that failed, `errors`: their messages by id.
    - `metrics`: every metric as `"node.metric"` -> float.
    - `notes`: each node's warnings, by id.
    - `nodes`: each node's report (op, status, ms, key, metrics, notes).
    - `outputs`: `"node.port"` -> value (numpy arrays, the value classes).
    - `report`: report.json as a dict; `out_dir`: where it was written.
    """

    def __init__(self, native: dict) -> None:
        self.report: dict = json.loads(native["report"])
        self.ok: bool = bool(native["succeeded"])
        self.out_dir: str = native["out_dir"]
        self.outputs: Dict[str, Any] = {k: from_native(v) for k, v in native["outputs"].items()}
        self.nodes: Dict[str, dict] = self.report.get("nodes", {})
        self.metrics: Dict[str, float] = self.report.get("metrics", {})
        self.notes: Dict[str, List[str]] = {
            k: n["notes"] for k, n in self.nodes.items() if n.get("notes")
        }
        self.errors: Dict[str, str] = {
            k: n["error"] for k, n in self.nodes.items() if n.get("status") == "failed"
        }
        self.failed: List[str] = list(self.errors)

    @property
    def status(self) -> str:
        """`"succeeded"` or `"failed"`."""
        return "succeeded" if self.ok else "failed"

    def __getitem__(self, key: str) -> Any:
        """The output `"node.port"`."""
        return self.outputs[key]

    def __repr__(self) -> str:
        return f"<fusegraph.Result {self.status}: {len(self.nodes)} nodes, {len(self.outputs)} outputs>"


def run(
    graph: PathLike,
    set: Optional[Mapping[str, Any]] = None,
    out: Optional[PathLike] = None,
    cache: Optional[PathLike] = None,
    no_cache: bool = False,
    jobs: int = 0,
    inputs: Optional[Mapping[str, Union[Any, Tuple[str, Any]]]] = None,
) -> Result:
    """Runs `graph` as `fusegraph run` does and returns its `Result`.

    - `set`: overrides, `{"node.key": value}` (`node.op`, `node.in.port` too).
    - `out`: the output folder (default `out/<graph name>`); `cache`: the cache
      folder (default `.fusegraph/cache` beside the graph); `no_cache`.
    - `jobs`: worker threads (0: one per core).
    - `inputs`: `{"node.port": value}` puts values from Python in place of
      those nodes' outputs (the node then only hands them on; its key is
      their content). The type is the port's own where it is clear (a value
      class, a float); give `("Disparity", array)` for an array.
    """
    given = {k: _given(k, v) for k, v in (inputs or {}).items()}
    native = _native.run(os.fspath(graph), _sets(set), _path(out), _path(cache), no_cache, jobs, given)
    return Result(native)


def _path(p: Optional[PathLike]) -> Optional[str]:
    return None if p is None else os.fspath(p)


def _given(key: str, value: Any) -> Tuple[str, Any]:
    if isinstance(value, tuple) and len(value) == 2 and isinstance(value[0], str):
        ty, v = value
    elif type(value).__name__ in _CLASSES:
        ty, v = type(value).__name__, value
    elif isinstance(value, (int, float)):
        ty, v = "Scalar", value
    elif isinstance(value, dict):
        ty, v = "Table", value
    else:
        raise ValueError(f"inputs[{key!r}]: give its type, e.g. (\"Image\", array)")
    return ty, to_native(v, ty)


def validate(graph: PathLike, set: Optional[Mapping[str, Any]] = None) -> dict:
    """Checks `graph` without running it: `{"name", "nodes"}`, or raises
    `GraphError` listing every problem."""
    return _native.validate(os.fspath(graph), _sets(set))


def nodes() -> List[dict]:
    """Every op's declaration (ports, parameters with kind, default, unit,
    range and doc), the built-in ones and those declared in Python."""
    return json.loads(_native.nodes())


def sweep(
    sweep: PathLike,
    out: Optional[PathLike] = None,
    cache: Optional[PathLike] = None,
    no_cache: bool = False,
    jobs: int = 0,
) -> dict:
    """Runs every variant of a sweep file as `fusegraph sweep` does and
    writes the comparison: `{"out_dir", "variants": [{name, succeeded, ms,
    ran, cached, error}], "comparison": [rows of comparison.csv]}`."""
    result = _native.sweep(os.fspath(sweep), _path(out), _path(cache), no_cache, jobs)
    import csv

    with open(os.path.join(result["out_dir"], "comparison.csv"), newline="") as f:
        result["comparison"] = list(csv.DictReader(f))
    return result
