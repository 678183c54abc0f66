"""Coloured clouds as COPC (Cloud-Optimized Point Cloud, a LAZ 1.4 file whose points
are stored by octree node), for streaming in QGIS, Potree and PDAL; written with
copclib.

The points and their fields are those of :mod:`acq.cloud.las` (point format 7, the
extra bytes ``scan_index``, ``coloured``, ``camera`` and ``frame`` with their true
ranges, the cameras' names VLR, WKT 1, acq's mark), with the offset at the first part's
rounded minimum (1 mm in 32 bits: points within 2,147 km of it).
The octree is a cube around the cloud; each node keeps at most
:data:`acq.cloud.octree.NODE_POINTS` points drawn at random (seeded: the same file every
run) from those of its cell not kept by a coarser level, in time order within the node;
a cell with no more than that is a leaf. The octree needs the whole cloud's extent: the
points wait in scratch files beside the output until :meth:`CopcStream.close`, which
builds it out of core (:mod:`acq.cloud.octree`), so memory does not grow with the cloud.
Before copclib gets a node, the disk must have room for it (copclib aborts the process
on a failed write): otherwise an OSError (ENOSPC, or EFBIG under a file size limit)
names the output and its folder, and nothing is left behind.
"""

from __future__ import annotations

import errno
import io
import os
import resource
import struct
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from acq.atomic_write import discard, release, temporary_beside
from acq.cloud.las import (
    CAMERAS_VLR,
    SYSTEM_IDENTIFIER,
    cameras_text,
    extra_dims,
    grow_ranges,
    pack_points,
    write_extra_bytes_ranges,
)
from acq.cloud.octree import Cube, Key, Scratch, build, drop_all
from acq.errors import AcqError
from acq.extras import needs
from acq.provenance import SOFTWARE

__all__ = ["CopcStream"]

_SCALE = 0.001  # m
_REACH = 2**31 - 1  # a record's coordinate, in _SCALE units from the offset, at most
_MARGIN = 1 << 20  # bytes of room kept beyond a node's raw size (LAZ, hierarchy, header)
_PAGE_ENTRY = 32  # bytes: a node's entry in the hierarchy page
_FULL = (errno.ENOSPC, errno.EFBIG, errno.EDQUOT)


class CopcStream:
    """A COPC file (module docstring) collected part by part, written and renamed into
    ``path`` on :meth:`close` (:meth:`abort` drops it and the scratch files). ``cameras``:
    the names, in index order, of the cameras the points' ``camera`` indexes.
    ``comments``: unused, as in LAS."""

    def __init__(
        self, path: str | os.PathLike[str], *, crs: str | None = None,
        comments: Sequence[str] = (), cameras: Sequence[str] = (),
    ) -> None:  # fmt: skip
        import laspy

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
        self._format = laspy.PointFormat(7)
        for dim in extra_dims():
            self._format.add_extra_dimension(dim)
        self._made: set[Scratch] = set()  # the scratch files on disk
        self._points: Scratch | None = None  # every point, as written
        self._offsets = np.zeros(3)
        self._lo, self._hi = np.full(3, np.inf), np.full(3, -np.inf)
        self._ranges: dict[str, tuple[int, int]] = {}

    def write(
        self, xyz: np.ndarray, rgb: np.ndarray, utc_s: np.ndarray, intensity: np.ndarray,
        scan: np.ndarray, coloured: np.ndarray, camera: np.ndarray, frame: np.ndarray,
    ) -> None:  # fmt: skip
        """Append points: ``xyz`` (N,3) m, ``rgb`` (N,3) uint8, ``utc_s`` (N,) UTC
        seconds, ``intensity``, ``scan`` index, ``coloured`` flag, source ``camera``
        (255 none) and ``frame`` (-1 none). AcqError for a point not finite or beyond
        the 32-bit coordinates' reach of the first part's."""
        if not xyz.shape[0]:
            return
        # column by column: numpy's axis-0 reduction of an (N,3) array is 9x slower
        lo = np.array([xyz[:, k].min() for k in range(3)])
        hi = np.array([xyz[:, k].max() for k in range(3)])
        if not (np.isfinite(lo).all() and np.isfinite(hi).all()):
            raise AcqError(f"{self.path}: a point's coordinates are not finite")
        if self._points is None:
            self._offsets = np.floor(lo)
            self._points = self._scratch()
        reach = float(np.max(np.maximum(self._offsets - lo, hi - self._offsets))) / _SCALE
        if not reach <= _REACH:
            raise AcqError(
                f"{self.path}: a point lies {reach * _SCALE / 1000:.0f} km from the "
                f"cloud's first ones: beyond the {_REACH * _SCALE / 1000:.0f} km a COPC "
                "file's millimetre coordinates reach"
            )
        self._lo, self._hi = np.minimum(self._lo, lo), np.maximum(self._hi, hi)
        record = pack_points(self._format, self._offsets, np.full(3, _SCALE),
                             xyz, rgb, utc_s, intensity, scan, coloured, camera, frame)  # fmt: skip
        grow_ranges(self._ranges, record.array)
        with self._full():
            self._points.append(record.array)

    def close(self) -> int:
        """Write the file; its size, bytes. On failure, nothing is left behind."""
        try:
            return self._close()
        except BaseException:
            self.abort()
            raise

    def _close(self) -> int:
        with needs("copc", "COPC output"):
            import copclib

        if self._points is None:
            self._points = self._scratch()
            self._lo = self._hi = np.zeros(3)
        points, lo, hi = self._points, self._lo, self._hi
        with self._full():
            points.close()
        centre = (lo + hi) / 2
        half = float(max(hi - lo)) / 2 + _SCALE
        eb = copclib.EbVlr(self._format.num_extra_bytes)  # unnamed bytes: named below
        config = copclib.CopcConfigWriter(
            7, copclib.Vector3(_SCALE, _SCALE, _SCALE), copclib.Vector3(*self._offsets),
            self._wkt, eb,
        )  # fmt: skip
        writer = copclib.FileWriter(str(self._tmp), config)
        header = writer.copc_config.las_header
        header.min, header.max = copclib.Vector3(*lo), copclib.Vector3(*hi)
        header.generating_software = SOFTWARE
        header.system_identifier = SYSTEM_IDENTIFIER
        header.SetGpsTimeBit()
        info = writer.copc_config.copc_info
        info.center_x, info.center_y, info.center_z = (float(v) for v in centre)
        info.halfsize = half
        info.spacing = 2 * half / 128
        nodes = 0

        def add(key: Key, records: np.ndarray) -> None:
            nonlocal nodes
            self._room(records.nbytes + _PAGE_ENTRY * nodes)
            writer.AddNode(
                copclib.VoxelKey(*key),
                copclib.VectorChar(np.ascontiguousarray(records).view(np.int8)),
            )
            nodes += 1

        cube = Cube(centre - half, 2 * half, self._offsets, _SCALE)
        with self._full():
            build((0, 0, 0, 0), points, cube, add, self._scratch)
        self._room(_PAGE_ENTRY * nodes)  # the hierarchy and the header
        writer.Close()
        _name_extra_bytes(self._tmp, self._cameras)
        write_extra_bytes_ranges(self._tmp, self._ranges)
        self._tmp.replace(self.path)
        release(self._tmp)
        return self.path.stat().st_size

    def abort(self) -> None:
        """Drop the points, the scratch files and any unfinished file."""
        drop_all(self._made)
        self._points = None
        discard(self._tmp)

    def _scratch(self) -> Scratch:
        with self._full():
            return Scratch(self.path, self._format.dtype(), self._made)

    def _room(self, size: int) -> None:
        """OSError naming the output and its folder unless ``size`` bytes and a margin can
        still be written to the temporary file: room on its disk and under the process's
        file size limit (copclib aborts the process on a failed write)."""
        folder = self.path.parent
        disk = os.statvfs(folder)
        free = disk.f_bavail * disk.f_frsize
        need = size + _MARGIN
        if free < need:
            raise OSError(
                errno.ENOSPC, f"No space left on device: {free / 1e6:.1f} MB free on the "
                f"disk of {folder}, {need / 1e6:.1f} MB needed", str(self.path),
            )  # fmt: skip
        limit = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
        if limit != resource.RLIM_INFINITY:
            size_now = self._tmp.stat().st_size if self._tmp.exists() else 0
            if size_now + need > limit:
                raise OSError(
                    errno.EFBIG, f"File too large: the process's file size limit is "
                    f"{limit / 1e6:.1f} MB (ulimit -f)", str(self.path),
                )  # fmt: skip

    @contextmanager
    def _full(self) -> Iterator[None]:
        """A full disk or file size limit met writing a scratch file names the output
        and the scratch file's folder."""
        try:
            yield
        except OSError as e:
            if e.errno not in _FULL or e.filename == str(self.path):  # _room's own
                raise
            why = e.strerror or os.strerror(e.errno)
            raise OSError(e.errno, f"{why} (a scratch file in {self.path.parent})",
                          str(self.path)) from e  # fmt: skip


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
