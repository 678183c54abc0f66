"""``foxglove.PointCloud`` messages of coloured points: the live coloured scans and swath."""

from __future__ import annotations

import numpy as np
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud

from acq.log.schemas import serialized, set_stamp

__all__ = ["CLOUD_DTYPE", "cloud_of_points", "point_cloud", "points"]

_N = PackedElementField.NumericType
CLOUD_DTYPE = np.dtype(
    [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1"),
     ("alpha", "u1")]
)  # fmt: skip
_CLOUD_FIELDS = [
    PackedElementField(name=name, offset=offset, type=_N.FLOAT32 if name in "xyz" else _N.UINT8)
    for name, offset in (
        ("x", 0),
        ("y", 4),
        ("z", 8),
        ("red", 12),
        ("green", 13),
        ("blue", 14),
        ("alpha", 15),
    )
]


def points(xyz: np.ndarray, rgb: np.ndarray, alpha: np.ndarray | None = None) -> np.ndarray:
    """(N,) points of :data:`CLOUD_DTYPE` from (N,3) metres and (N,3) uint8 RGB colours,
    ``alpha`` (N,) uint8 (default 255: opaque)."""
    P = np.asarray(xyz)
    C = np.asarray(rgb)
    if P.ndim != 2 or P.shape[1] != 3:
        raise ValueError(f"points must be (N,3), got shape {P.shape}")
    if C.shape != P.shape:
        raise ValueError(f"rgb must be (N,3) like points {P.shape}, got shape {C.shape}")
    buf = np.empty(P.shape[0], dtype=CLOUD_DTYPE)
    buf["x"], buf["y"], buf["z"] = P[:, 0], P[:, 1], P[:, 2]
    buf["red"], buf["green"], buf["blue"] = C[:, 0], C[:, 1], C[:, 2]
    buf["alpha"] = 255 if alpha is None else alpha
    return buf


def cloud_of_points(buf: np.ndarray, frame_id: str, stamp_ns: int) -> bytes:
    """``foxglove.PointCloud`` of points of :data:`CLOUD_DTYPE` (:func:`points`, or
    their bytes, (N,16) uint8): 16-byte
    points, x, y, z float32 at 0, 4, 8 and red, green, blue, alpha uint8 at 12-15
    (Foxglove's "RGBA (separate fields)" colour mode)."""
    msg = PointCloud(frame_id=frame_id, point_stride=CLOUD_DTYPE.itemsize, data=buf.tobytes())
    set_stamp(msg.timestamp, stamp_ns)
    msg.pose.orientation.w = 1.0
    msg.fields.extend(_CLOUD_FIELDS)
    return serialized(msg)


def point_cloud(
    xyz: np.ndarray, rgb: np.ndarray, frame_id: str, stamp_ns: int,
    alpha: np.ndarray | None = None,
) -> bytes:  # fmt: skip
    """``foxglove.PointCloud`` (:func:`cloud_of_points`) of (N,3) metres and (N,3) uint8
    RGB colours, ``alpha`` (N,) uint8 (default 255: opaque)."""
    return cloud_of_points(points(xyz, rgb, alpha), frame_id, stamp_ns)
