"""Coloured clouds as COPC (Cloud-Optimized Point Cloud, a LAZ 1.4 file whose points
are stored by octree node), for streaming in QGIS, Potree and PDAL; written with
copclib.

The points and their fields are those of :mod:`acq.cloud.las` (point format 7, the
extra bytes ``scan_index``, ``coloured``, ``camera`` and ``frame`` with their true
ranges, the cameras' names VLR, WKT 1, acq's mark).
The octree is a cube around the cloud; each node keeps at most :data:`NODE_POINTS`
points drawn at random (a fixed seed: the same file every run) from those of its cell
not kept by a coarser level, in time order within the node; a cell with no more than
that is a leaf. The points are held in memory until :meth:`CopcStream.close`: the
octree needs the whole cloud's extent.
"""

from __future__ import annotations

import io
import os
import struct
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from acq.atomic_write import temporary_beside
from acq.cloud.las import (
    CAMERAS_VLR,
    SYSTEM_IDENTIFIER,
    cameras_text,
    extra_dims,
    grow_ranges,
    pack_points,
    write_extra_bytes_ranges,
)
from acq.provenance import SOFTWARE

__all__ = ["NODE_POINTS", "CopcStream"]

NODE_POINTS = 50_000  # points per octree node at most
_MAX_DEPTH = 20  # the finest level: whatever is left goes there
_SCALE = 0.001  # m


class CopcStream:
    """A COPC file (module docstring) collected part by part, written and renamed into
    ``path`` on :meth:`close` (:meth:`abort` drops it). ``cameras``: the names, in index
    order, of the cameras the points' ``camera`` indexes. ``comments``: unused, as in LAS."""

    def __init__(
        self, path: str | os.PathLike[str], *, crs: str | None = None,
        comments: Sequence[str] = (), cameras: Sequence[str] = (),
    ) -> None:  # fmt: skip
        self.path = Path(path)
        self._tmp = temporary_beside(self.path)
        self._cameras = cameras_text(cameras).encode()
        if len(self._cameras) > _spare():
            raise ValueError(f"the cameras' names take {len(self._cameras)} bytes: at most "
                             f"{_spare()} fit in a COPC file's header")  # fmt: skip
        self._wkt = ""
        if crs:
            import pyproj

            self._wkt = pyproj.CRS.from_user_input(crs).to_wkt(pyproj.enums.WktVersion.WKT1_GDAL)
        self._parts: list[tuple[np.ndarray, ...]] = []

    def write(
        self, xyz: np.ndarray, rgb: np.ndarray, utc_s: np.ndarray, intensity: np.ndarray,
        scan: np.ndarray, coloured: np.ndarray, camera: np.ndarray, frame: np.ndarray,
    ) -> None:  # fmt: skip
        """Append points: ``xyz`` (N,3) m, ``rgb`` (N,3) uint8, ``utc_s`` (N,) UTC
        seconds, ``intensity``, ``scan`` index, ``coloured`` flag, source ``camera``
        (255 none) and ``frame`` (-1 none)."""
        if xyz.shape[0]:
            self._parts.append((xyz, rgb, utc_s, intensity, scan, coloured, camera, frame))

    def close(self) -> int:
        """Write the file; its size, bytes."""
        import copclib
        import laspy

        cols = [np.concatenate(c) for c in zip(*self._parts, strict=True)] if self._parts else []
        self._parts = []
        xyz = cols[0] if cols else np.zeros((0, 3))
        lo = np.array([xyz[:, k].min() for k in range(3)]) if xyz.size else np.zeros(3)
        hi = np.array([xyz[:, k].max() for k in range(3)]) if xyz.size else np.zeros(3)
        offsets = np.floor(lo)
        centre = (lo + hi) / 2
        half = float(max(hi - lo)) / 2 + _SCALE
        point_format = laspy.PointFormat(7)
        for dim in extra_dims():
            point_format.add_extra_dimension(dim)
        eb = copclib.EbVlr(point_format.num_extra_bytes)  # unnamed bytes: named below
        config = copclib.CopcConfigWriter(
            7, copclib.Vector3(_SCALE, _SCALE, _SCALE), copclib.Vector3(*offsets), self._wkt, eb
        )
        writer = copclib.FileWriter(str(self._tmp), config)
        try:
            header = writer.copc_config.las_header
            header.min, header.max = copclib.Vector3(*lo), copclib.Vector3(*hi)
            header.generating_software = SOFTWARE
            header.system_identifier = SYSTEM_IDENTIFIER
            header.SetGpsTimeBit()
            info = writer.copc_config.copc_info
            info.center_x, info.center_y, info.center_z = (float(v) for v in centre)
            info.halfsize = half
            info.spacing = 2 * half / 128
            ranges: dict[str, tuple[int, int]] = {}
            for key, idx in _octree(xyz, centre - half, 2 * half):
                record = pack_points(point_format, offsets, np.full(3, _SCALE),
                                     *(c[idx] for c in cols))  # fmt: skip
                grow_ranges(ranges, record.array)
                raw = copclib.VectorChar(np.frombuffer(record.array.tobytes(), np.int8))
                writer.AddNode(copclib.VoxelKey(*key), raw)
        finally:
            writer.Close()
        _name_extra_bytes(self._tmp, self._cameras)
        write_extra_bytes_ranges(self._tmp, ranges)
        self._tmp.replace(self.path)
        return self.path.stat().st_size

    def abort(self) -> None:
        """Drop the points and any unfinished file."""
        self._parts = []
        self._tmp.unlink(missing_ok=True)


def _octree(
    xyz: np.ndarray, cube_min: np.ndarray, size: float
) -> list[tuple[tuple[int, int, int, int], np.ndarray]]:
    """The nodes ((level, i, j, k), indices into ``xyz`` in order) of the octree over the
    cube at ``cube_min`` of edge ``size`` m (module docstring)."""
    left = np.random.default_rng(0).permutation(xyz.shape[0])
    nodes: list[tuple[tuple[int, int, int, int], np.ndarray]] = []
    level = 0
    while left.size:
        cells = 1 << level
        ijk = np.floor((xyz[left] - cube_min) / (size / cells)).astype(np.int64)
        ijk = np.clip(ijk, 0, cells - 1)
        key = (ijk[:, 0] * cells + ijk[:, 1]) * cells + ijk[:, 2]
        order = np.argsort(key, kind="stable")  # random within a cell: left is shuffled
        key, left, ijk = key[order], left[order], ijk[order]
        starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
        rank = np.arange(key.size) - np.repeat(starts, np.diff(np.r_[starts, key.size]))
        take = rank < NODE_POINTS if level < _MAX_DEPTH else np.ones(key.size, bool)
        ends = np.r_[starts[1:], key.size]
        for a, b in zip(starts.tolist(), ends.tolist(), strict=True):
            kept = left[a:b][take[a:b]]
            i, j, k = (int(v) for v in ijk[a])
            nodes.append(((level, i, j, k), np.sort(kept)))
        left = left[~take]
        level += 1
    return nodes


_EB_DESCRIPTOR, _VLR_HEADER = 192, 54  # bytes: an extra-bytes descriptor, a VLR's header


def _spare() -> int:
    """The bytes of VLR payload left when copclib's extra-bytes VLR (a descriptor per
    extra byte) is replaced by :func:`acq.cloud.las.extra_dims`' descriptors and the
    header of one more VLR."""
    dims = extra_dims()
    size = sum(int(np.dtype(d.type).itemsize) for d in dims)
    return _EB_DESCRIPTOR * (size - len(dims)) - _VLR_HEADER


def _name_extra_bytes(path: Path, cameras: bytes) -> None:
    """Give the extra-bytes VLR copclib wrote (one unnamed byte per extra byte) the
    named, typed descriptors of :func:`acq.cloud.las.extra_dims`, in place: the space
    they leave becomes the cameras' VLR (``cameras``, its text, then NULs), or a padding
    VLR when there are none, so every offset stays."""
    import laspy

    header = laspy.LasHeader(point_format=7, version="1.4")
    header.add_extra_dims(extra_dims())
    buf = io.BytesIO()
    laspy.LasData(header).write(buf)
    named = _vlr_at(buf.getvalue(), b"LASF_Spec", 4)
    with open(path, "r+b") as f:
        data = f.read(1 << 16)
        old = _vlr_at(data, b"LASF_Spec", 4)
        at = data.index(old)
        spare = len(old) - len(named) - _VLR_HEADER
        if spare < len(cameras):
            raise RuntimeError("copclib's extra-bytes VLR is smaller than expected")
        user_id, record_id, description = CAMERAS_VLR if cameras else ("acq", 0, "padding")
        pad = struct.pack("<H16sHH32s", 0, user_id.encode(), record_id, spare, description.encode())
        pad += cameras + bytes(spare - len(cameras))
        f.seek(at)
        f.write(named + pad)
        count = struct.unpack_from("<I", data, 100)[0]
        f.seek(100)
        f.write(struct.pack("<I", count + 1))


def _vlr_at(data: bytes, user_id: bytes, record_id: int) -> bytes:
    """The whole VLR (header and payload) of ``user_id``/``record_id`` in the LAS bytes
    ``data``."""
    at = struct.unpack_from("<H", data, 94)[0]
    for _ in range(struct.unpack_from("<I", data, 100)[0]):
        uid = data[at + 2 : at + 18].rstrip(b"\0")
        rid, length = struct.unpack_from("<HH", data, at + 18)
        if uid == user_id and rid == record_id:
            return data[at : at + 54 + length]
        at += 54 + length
    raise RuntimeError(f"no {user_id.decode()} {record_id} VLR")
