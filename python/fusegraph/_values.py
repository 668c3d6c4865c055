"""fusegraph's value types as Python objects holding numpy arrays.

Units and frames are the engine's: lengths in mm, pixels in px, volumes'
affines map voxel (i, j, k) to patient LPS mm. Arrays that come out of a run
are read-only views of the engine's own buffers (no copy); copy one
(`arr.copy()`) to change it.

Some types are plain Python values: an Image or a Disparity is an ndarray
((H, W) or (H, W, 3); a Disparity float32 with NaN where nothing matched), a
Scalar a float, a Table a dict of 1-D float arrays (its columns), a Path a
`pathlib.Path`.
"""

from __future__ import annotations

import pathlib
from dataclasses import dataclass, fields
from typing import Any, Optional

import numpy as np

__all__ = [
    "Volume",
    "Mask",
    "Labels",
    "Mesh",
    "PointCloud",
    "Markers",
    "Matches",
    "Camera",
    "StereoRig",
    "Rectification",
    "Transform",
    "TYPES",
]

#: Every value type's name, as ports declare them.
TYPES = (
    "Volume", "Mask", "Labels", "Image", "Disparity", "Mesh", "PointCloud",
    "Markers", "Matches", "Camera", "StereoRig", "Rectification", "Transform",
    "Table", "Scalar", "Path",
)


@dataclass
class _Grid:
    #: Voxels, shape (nz, ny, nx): `array[k, j, i]` is voxel (i, j, k).
    array: np.ndarray
    #: 4 x 4 voxel (i, j, k, 1) -> patient LPS mm.
    affine: np.ndarray

    @property
    def spacing_mm(self) -> np.ndarray:
        """Voxel size along i, j, k, mm."""
        return np.linalg.norm(np.asarray(self.affine)[:3, :3], axis=0)


@dataclass
class Volume(_Grid):
    """Scalar voxels (float32) on a grid; see `_Grid`."""


@dataclass
class Mask(_Grid):
    """0 / 1 voxels (uint8) on a grid."""


@dataclass
class Labels(_Grid):
    """Component labels (uint32, 0 = background) on a grid."""


@dataclass
class Mesh:
    """A triangle mesh: vertices (N, 3) float32 mm, triangles (M, 3) uint32."""

    vertices: np.ndarray
    triangles: np.ndarray
    normals: Optional[np.ndarray] = None
    frame: str = ""


@dataclass
class PointCloud:
    """Points (N, 3) float32 mm, optional colours (N, 3) uint8 and normals."""

    points: np.ndarray
    colors: Optional[np.ndarray] = None
    normals: Optional[np.ndarray] = None
    frame: str = ""


@dataclass
class Markers:
    """Marker centres (N, 3) float64 mm with their ids (N,) uint32."""

    positions_mm: np.ndarray
    ids: np.ndarray
    frame: str = ""


@dataclass
class Matches:
    """Keypoint pairs: left and right (N, 2) float32 px, scores (N,)."""

    left_px: np.ndarray
    right_px: np.ndarray
    scores: np.ndarray


@dataclass
class Camera:
    """A pinhole camera: image size px, K (3 x 3, px), distortion (k1, k2, p1, p2, k3)."""

    width: int
    height: int
    k: np.ndarray
    distortion: np.ndarray


@dataclass
class StereoRig:
    """Two cameras; a left-camera point x is at rotation @ x + translation_mm in the right's frame."""

    left: Camera
    right: Camera
    rotation: np.ndarray
    translation_mm: np.ndarray


@dataclass
class Rectification:
    """Stereo rectification: R1, R2 (3 x 3), P1, P2 (3 x 4, px), Q (4 x 4)."""

    width: int
    height: int
    r1: np.ndarray
    r2: np.ndarray
    p1: np.ndarray
    p2: np.ndarray
    q: np.ndarray


@dataclass
class Transform:
    """A 4 x 4 homogeneous transform (mm) from one named frame to another."""

    matrix: np.ndarray
    from_frame: str = ""
    to_frame: str = ""


_CLASSES = {
    c.__name__: c
    for c in (Volume, Mask, Labels, Mesh, PointCloud, Markers, Matches,
              Camera, StereoRig, Rectification, Transform)
}

# The dtype each array field crosses into the engine with.
_DTYPES = {
    ("Volume", "array"): np.float32,
    ("Mask", "array"): np.uint8,
    ("Labels", "array"): np.uint32,
    ("Mesh", "vertices"): np.float32,
    ("Mesh", "triangles"): np.uint32,
    ("Mesh", "normals"): np.float32,
    ("PointCloud", "points"): np.float32,
    ("PointCloud", "colors"): np.uint8,
    ("PointCloud", "normals"): np.float32,
    ("Markers", "positions_mm"): np.float64,
    ("Markers", "ids"): np.uint32,
    ("Matches", "left_px"): np.float32,
    ("Matches", "right_px"): np.float32,
    ("Matches", "scores"): np.float32,
}


def from_native(value: Any) -> Any:
    """The engine's plain form (a dict with `type`) as the package's object."""
    if isinstance(value, dict) and "type" in value:
        kind = value["type"]
        cls = _CLASSES[kind]
        args = {f.name: value.get(f.name) for f in fields(cls)}
        if kind == "StereoRig":
            args["left"] = from_native(args["left"])
            args["right"] = from_native(args["right"])
        return cls(**args)
    return value


def to_native(value: Any, type_name: str) -> Any:
    """`value` in the plain form the engine reads as a `type_name`."""
    if type_name not in TYPES:
        raise ValueError(f"unknown value type {type_name!r} (one of {', '.join(TYPES)})")
    if type_name == "Image":
        a = np.asarray(value)
        dtype = np.uint8 if a.dtype == np.uint8 else np.float32
        return np.ascontiguousarray(a, dtype=dtype)
    if type_name == "Disparity":
        return np.ascontiguousarray(value, dtype=np.float32)
    if type_name == "Scalar":
        return float(value)
    if type_name == "Path":
        return str(pathlib.Path(value))
    if type_name == "Table":
        if not isinstance(value, dict):
            raise ValueError("a Table is a dict of equally long columns")
        return {str(k): np.ascontiguousarray(v, dtype=np.float64).reshape(-1) for k, v in value.items()}
    cls = _CLASSES[type_name]
    if isinstance(value, dict):
        value = cls(**{k: v for k, v in value.items() if k != "type"})
    if not isinstance(value, cls):
        raise ValueError(f"expected a fusegraph.{type_name}, got {type(value).__name__}")
    out = {"type": type_name}
    for f in fields(cls):
        v = getattr(value, f.name)
        if isinstance(v, Camera):
            v = to_native(v, "Camera")
        elif isinstance(v, (str, int)) and not isinstance(v, bool):
            pass
        elif v is not None:
            v = np.ascontiguousarray(v, dtype=_DTYPES.get((type_name, f.name), np.float64))
        out[f.name] = v
    return out
