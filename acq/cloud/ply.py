"""Coloured clouds as binary PLY: x y z, colour, UTC time, scan index, intensity, coloured,
source camera and frame (:class:`PlyStream`); facets with per-vertex colour
(:func:`write_mesh`).

The property names and types are those every common reader keeps: CloudCompare imports a
vertex property as a scalar field only when its name holds ``scalar`` (or is ``intensity``)
and drops the ``scalar_`` prefix, the name it writes itself; Open3D's tensor reader skips
``char``, ``short`` and ``uint`` properties. Integers are therefore ``uchar``, ``ushort``
or ``int``; PCL, plyfile and trimesh read all of these. The cameras are named by a header
comment each, ``camera <index> <name>``, in index order."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from acq.atomic_write import atomic, discard, release, temporary_beside

PLY_DTYPE = np.dtype(
    [
        ("x", "<f8"),
        ("y", "<f8"),
        ("z", "<f8"),
        ("red", "u1"),
        ("green", "u1"),
        ("blue", "u1"),
        ("scalar_time", "<f8"),
        ("scalar_scan", "<i4"),
        ("intensity", "<f4"),
        ("scalar_coloured", "u1"),
        ("scalar_camera", "u1"),
        ("scalar_frame", "<i4"),
    ]
)


# the PLY types every reader above keeps, by numpy type
_PLY_TYPES = {"|u1": "uchar", "<u2": "ushort", "<i4": "int", "<f4": "float", "<f8": "double"}


WRITE_POINTS = 1 << 16  # points laid out and written at a time (3 MB)


class PlyStream:
    """A binary little-endian PLY, one ``vertex`` per point: x y z (double, m, world),
    red green blue (uchar), scalar_time (double, UTC s), scalar_scan (int), intensity
    (float), scalar_coloured (uchar 0/1), scalar_camera (uchar, the index in ``cameras``
    of the camera that coloured the point, 255 none), scalar_frame (int, the index of
    that camera's frame, -1 none); written part by part to a temporary of its own
    beside ``path`` (:func:`acq.atomic_write.temporary_beside`), renamed on
    :meth:`close` (:meth:`abort` removes it). Its header, with the counts known only at
    the end, is written last into the room kept for it (the rest of the room a comment
    of spaces)."""

    def __init__(
        self, path: str | os.PathLike[str], comments: Sequence[str] = (),
        cameras: Sequence[str] = (),
    ) -> None:  # fmt: skip
        self.path = Path(path)
        self._comments = [*comments, *(f"camera {k} {name}" for k, name in enumerate(cameras))]
        if not all(c.isprintable() for c in self._comments):  # a line break ends the header
            raise ValueError(f"a PLY comment is one line of printable text: {self._comments}")
        self.points = self.coloured = 0
        self._room = len(self._header(10**15, 10**15))
        self._tmp = temporary_beside(self.path)
        self._file = open(self._tmp, "r+b")
        self._file.seek(self._room)

    def _header(self, points: int, coloured: int, pad: int = 0) -> bytes:
        lines = [
            "ply",
            "format binary_little_endian 1.0",
            "comment acq coloured cloud: x y z metres in the world frame; scalar_time UTC s",
            f"comment {coloured} of {points} points coloured",
            *(f"comment {c}" for c in self._comments),
            "comment " + " " * pad,  # what is left of the room kept for the header
            f"element vertex {points}",
            *(f"property {_PLY_TYPES[PLY_DTYPE[k].str]} {k}" for k in PLY_DTYPE.names or ()),
            "end_header",
        ]
        return ("\n".join(lines) + "\n").encode()

    def write(
        self, xyz: np.ndarray, rgb: np.ndarray, utc_s: np.ndarray, intensity: np.ndarray,
        scan: np.ndarray, coloured: np.ndarray, camera: np.ndarray, frame: np.ndarray,
    ) -> None:  # fmt: skip
        """Append points: ``xyz`` (N,3) m, ``rgb`` (N,3) uint8, ``utc_s`` (N,) UTC
        seconds, ``intensity``, ``scan`` index, ``coloured`` flag, source ``camera``
        (255 none) and ``frame`` (-1 none)."""
        n = utc_s.size
        v = np.empty(min(n, WRITE_POINTS), dtype=PLY_DTYPE)
        for lo in range(0, n, WRITE_POINTS):  # a slice at a time: no copy of the whole
            k = slice(lo, min(n, lo + WRITE_POINTS))
            w = v[: k.stop - lo]
            w["x"], w["y"], w["z"] = xyz[k, 0], xyz[k, 1], xyz[k, 2]
            w["red"], w["green"], w["blue"] = rgb[k, 0], rgb[k, 1], rgb[k, 2]
            w["scalar_time"] = utc_s[k]
            w["scalar_scan"] = scan[k]
            w["intensity"] = intensity[k]
            w["scalar_coloured"] = coloured[k]
            w["scalar_camera"] = camera[k]
            w["scalar_frame"] = frame[k]
            w.tofile(self._file)
        self.points += int(n)
        self.coloured += int(np.count_nonzero(coloured))

    def close(self) -> int:
        """Write the header and finish the file; its size, bytes."""
        head = self._header(self.points, self.coloured)
        head = self._header(self.points, self.coloured, self._room - len(head))
        self._file.seek(0)
        self._file.write(head)
        self._file.close()
        self._tmp.replace(self.path)
        release(self._tmp)
        return self.path.stat().st_size

    def abort(self) -> None:
        """Drop the unfinished file; never raises (closing it flushes what a full disk
        refused again)."""
        try:
            self._file.close()
        except OSError:
            pass
        finally:
            discard(self._tmp)


MESH_VERTEX_DTYPE = np.dtype(
    [("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("red", "u1"), ("green", "u1"), ("blue", "u1")]
)
# a face: its vertex count (3) and their indices, as PLY's list property stores it
_MESH_FACE_DTYPE = np.dtype([("n", "u1"), ("vertex_indices", "<i4", (3,))])


def write_mesh(
    path: str | os.PathLike[str], xyz: np.ndarray, rgb: np.ndarray, faces: np.ndarray,
    comments: Sequence[str] = (),
) -> int:  # fmt: skip
    """A binary little-endian PLY of triangles: ``vertex`` x y z (double, m: a projected
    CRS's coordinates keep their millimetres), red green blue (uchar) from ``xyz``
    (V,3) and ``rgb`` (V,3) uint8; ``face`` vertex_indices (uchar count, int indices)
    from ``faces`` (F,3). ``comments``: header lines (the first should carry acq's mark,
    ``acq ...``). Written whole or not at all; the file's size in bytes."""
    if not all(c.isprintable() for c in comments):  # a line break ends the header
        raise ValueError(f"a PLY comment is one line of printable text: {list(comments)}")
    v = np.empty(xyz.shape[0], dtype=MESH_VERTEX_DTYPE)
    v["x"], v["y"], v["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    v["red"], v["green"], v["blue"] = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    f = np.empty(faces.shape[0], dtype=_MESH_FACE_DTYPE)
    f["n"] = 3
    f["vertex_indices"] = faces
    names = MESH_VERTEX_DTYPE.names or ()
    header = [
        "ply",
        "format binary_little_endian 1.0",
        *(f"comment {c}" for c in comments),
        f"element vertex {v.size}",
        *(f"property {_PLY_TYPES[MESH_VERTEX_DTYPE[k].str]} {k}" for k in names),
        f"element face {f.size}",
        "property list uchar int vertex_indices",
        "end_header",
    ]
    path = Path(path)
    with atomic(path) as tmp, open(tmp, "wb") as out:
        out.write(("\n".join(header) + "\n").encode())
        v.tofile(out)
        f.tofile(out)
    return path.stat().st_size
