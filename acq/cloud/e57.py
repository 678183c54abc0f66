"""Coloured clouds as ASTM E57 (libE57Format through pye57), for CloudCompare, Recap and
the other tools of terrestrial and mobile scanning.

One scan (``data3D[0]``) holding every point: ``cartesianX/Y/Z`` (m, doubles),
``colorRed/Green/Blue`` (0..255), ``isColorInvalid`` (1 where no frame saw the point),
``intensity``, ``timeStamp`` (s after the scan's ``acquisitionStart``, itself GPS time as
E57 gives it), ``rowIndex`` (the scan in the log), and in acq's extension (prefix ``acq``,
URI :data:`ACQ_URI`) ``acq:camera`` (the index of the camera that coloured the point, 255
none) and ``acq:frame`` (the index of that camera's frame in the session, -1 none); the
cameras' names, in index order, in the scan's ``acq:cameras`` (a vector of strings) and
its description (``camera <index> <name>``). E57 has no standard field for either; a
reader that does not know the extension reads the standard fields as before (pye57's
``read_scan`` does). The CRS from ``crs`` as OGC WKT 1 in the root's
``coordinateMetadata``; acq's mark (:mod:`acq.provenance`) in the scan's
``sensorSoftwareVersion``. Written as points come, under a temporary of its own beside
``path`` (:func:`acq.atomic_write.temporary_beside`), renamed on :meth:`E57Stream.close`.
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from acq.atomic_write import discard, release, temporary_beside
from acq.extras import needs
from acq.provenance import SOFTWARE
from acq.time.gpstime import utc_to_gps

__all__ = ["ACQ_URI", "E57Stream"]

ACQ_URI = "urn:acq:e57:1"  # names acq's E57 extension (the fields acq:camera, acq:frame)

_BUFFER = 1 << 16  # points handed to libE57 at a time
_FIELDS = {  # field: numpy type of its buffer (the types pye57's binding takes)
    "cartesianX": "d", "cartesianY": "d", "cartesianZ": "d", "timeStamp": "d",
    "intensity": "f", "colorRed": "B", "colorGreen": "B", "colorBlue": "B",
    "isColorInvalid": "B", "rowIndex": "q", "acq:camera": "B", "acq:frame": "q",
}  # fmt: skip
_BIG = 1e12  # the bounds of a double field: metadata only, nothing is quantised to them


class E57Stream:
    """An E57 file (module docstring) written part by part (:meth:`write`), finished by
    :meth:`close` (:meth:`abort` removes it). ``comments`` become the scan's
    description; ``cameras``: the names, in index order, of the cameras the points'
    ``camera`` indexes."""

    def __init__(
        self, path: str | os.PathLike[str], *, crs: str | None = None,
        comments: Sequence[str] = (), cameras: Sequence[str] = (),
    ) -> None:  # fmt: skip
        with needs("e57", f"{path}: E57 output"):
            from pye57 import libe57

        self.path = Path(path)
        wkt = ""
        if crs:
            import pyproj

            wkt = pyproj.CRS.from_user_input(crs).to_wkt(pyproj.enums.WktVersion.WKT1_GDAL)
        self._e = libe57
        self._tmp = temporary_beside(self.path)
        try:
            imf = libe57.ImageFile(str(self._tmp), "w")
        except BaseException:
            discard(self._tmp)
            raise
        self._imf = imf
        try:
            self._start(imf, comments, cameras, wkt)
        except BaseException:
            self.abort()
            raise

    def _start(self, imf: Any, comments: Sequence[str], cameras: Sequence[str], wkt: str) -> None:
        """Write the file's tree up to the points, and open the points' writer."""
        libe57 = self._e
        root = imf.root()
        imf.extensionsAdd("", libe57.E57_V1_0_URI)
        imf.extensionsAdd("acq", ACQ_URI)
        root.set("formatName", libe57.StringNode(imf, "ASTM E57 3D Imaging Data File"))
        root.set("guid", libe57.StringNode(imf, f"{{{uuid.uuid4()}}}"))
        root.set("versionMajor", libe57.IntegerNode(imf, libe57.E57_FORMAT_MAJOR))
        root.set("versionMinor", libe57.IntegerNode(imf, libe57.E57_FORMAT_MINOR))
        root.set("e57LibraryVersion", libe57.StringNode(imf, libe57.E57_LIBRARY_ID))
        root.set("coordinateMetadata", libe57.StringNode(imf, wkt))
        data3d = libe57.VectorNode(imf, True)
        root.set("data3D", data3d)
        root.set("images2D", libe57.VectorNode(imf, True))
        scan = libe57.StructureNode(imf)
        scan.set("guid", libe57.StringNode(imf, f"{{{uuid.uuid4()}}}"))
        scan.set("name", libe57.StringNode(imf, self.path.stem))
        named = [f"camera {k} {name}" for k, name in enumerate(cameras)]
        scan.set("description", libe57.StringNode(imf, "; ".join([*comments, *named])))
        names = libe57.VectorNode(imf, False)
        for name in cameras:
            names.append(libe57.StringNode(imf, name))
        scan.set("acq:cameras", names)
        scan.set("sensorSoftwareVersion", libe57.StringNode(imf, SOFTWARE))
        proto = libe57.StructureNode(imf)
        for name in ("cartesianX", "cartesianY", "cartesianZ", "timeStamp"):
            proto.set(name, libe57.FloatNode(imf, 0.0, libe57.E57_DOUBLE, -_BIG, _BIG))
        proto.set("intensity", libe57.FloatNode(imf, 0.0, libe57.E57_SINGLE, 0.0, 65535.0))
        for name in ("colorRed", "colorGreen", "colorBlue"):
            proto.set(name, libe57.IntegerNode(imf, 0, 0, 255))
        proto.set("isColorInvalid", libe57.IntegerNode(imf, 0, 0, 1))
        proto.set("rowIndex", libe57.IntegerNode(imf, 0, 0, 2**32 - 1))
        proto.set("acq:camera", libe57.IntegerNode(imf, 0, 0, 255))
        proto.set("acq:frame", libe57.IntegerNode(imf, 0, -1, 2**31 - 1))
        points = libe57.CompressedVectorNode(imf, proto, libe57.VectorNode(imf, True))
        scan.set("points", points)
        data3d.append(scan)
        self._scan = scan
        self._arrays = {k: np.zeros(_BUFFER, dtype=t) for k, t in _FIELDS.items()}
        buffers = libe57.VectorSourceDestBuffer()
        for k, a in self._arrays.items():
            buffers.append(libe57.SourceDestBuffer(imf, k, a, _BUFFER, True, True))
        self._writer: Any = points.writer(buffers)
        self._start_utc: float | None = None
        self._lo = np.full(3, np.inf)
        self._hi = np.full(3, -np.inf)
        self._t_hi = -np.inf
        self._i_lo, self._i_hi, self._scan_lo, self._scan_hi = np.inf, -np.inf, np.inf, -np.inf

    def write(
        self, xyz: np.ndarray, rgb: np.ndarray, utc_s: np.ndarray, intensity: np.ndarray,
        scan: np.ndarray, coloured: np.ndarray, camera: np.ndarray, frame: np.ndarray,
    ) -> None:  # fmt: skip
        """Append points: ``xyz`` (N,3) m, ``rgb`` (N,3) uint8, ``utc_s`` (N,) UTC
        seconds, ``intensity``, ``scan`` index, ``coloured`` flag, source ``camera``
        (255 none) and ``frame`` (-1 none)."""
        n = xyz.shape[0]
        if n == 0:
            return
        if self._start_utc is None:
            self._start_utc = float(utc_s.min())
        inten = np.clip(np.nan_to_num(intensity), 0, 65535).astype(np.float32)
        self._lo = np.minimum(self._lo, [xyz[:, k].min() for k in range(3)])
        self._hi = np.maximum(self._hi, [xyz[:, k].max() for k in range(3)])
        self._t_hi = max(self._t_hi, float(utc_s.max()))
        self._i_lo, self._i_hi = min(self._i_lo, inten.min()), max(self._i_hi, inten.max())
        self._scan_lo, self._scan_hi = (
            min(self._scan_lo, scan.min()),
            max(self._scan_hi, scan.max()),
        )
        a = self._arrays
        for at in range(0, n, _BUFFER):
            k = min(_BUFFER, n - at)
            part = slice(at, at + k)
            for axis, name in enumerate(("cartesianX", "cartesianY", "cartesianZ")):
                a[name][:k] = xyz[part, axis]
            a["timeStamp"][:k] = utc_s[part] - self._start_utc
            a["intensity"][:k] = inten[part]
            for c, name in enumerate(("colorRed", "colorGreen", "colorBlue")):
                a[name][:k] = rgb[part, c]
            a["isColorInvalid"][:k] = ~coloured[part].astype(bool)
            a["rowIndex"][:k] = scan[part]
            a["acq:camera"][:k] = camera[part]
            a["acq:frame"][:k] = frame[part]
            self._writer.write(k)

    def close(self) -> int:
        """Finish the file; its size, bytes."""
        e, imf, scan = self._e, self._imf, self._scan
        self._writer.close()

        def floats(**values: float) -> Any:
            node = e.StructureNode(imf)
            for key, v in values.items():
                node.set(key, e.FloatNode(imf, float(v)))
            return node

        if self._start_utc is not None:
            lo, hi = self._lo, self._hi
            scan.set("cartesianBounds", floats(
                xMinimum=lo[0], xMaximum=hi[0], yMinimum=lo[1], yMaximum=hi[1],
                zMinimum=lo[2], zMaximum=hi[2],
            ))  # fmt: skip
            scan.set("intensityLimits", floats(
                intensityMinimum=self._i_lo, intensityMaximum=self._i_hi))  # fmt: skip
            rows = e.StructureNode(imf)
            rows.set("rowMinimum", e.IntegerNode(imf, int(self._scan_lo)))
            rows.set("rowMaximum", e.IntegerNode(imf, int(self._scan_hi)))
            scan.set("indexBounds", rows)
            for key, utc in (("acquisitionStart", self._start_utc), ("acquisitionEnd", self._t_hi)):
                when = floats(dateTimeValue=float(utc_to_gps(utc)))
                when.set("isAtomicClockReferenced", e.IntegerNode(imf, 0))
                scan.set(key, when)
        colours = e.StructureNode(imf)
        for c in ("Red", "Green", "Blue"):
            colours.set(f"color{c}Minimum", e.IntegerNode(imf, 0))
            colours.set(f"color{c}Maximum", e.IntegerNode(imf, 255))
        scan.set("colorLimits", colours)
        imf.close()
        self._tmp.replace(self.path)
        release(self._tmp)
        return self.path.stat().st_size

    def abort(self) -> None:
        """Drop the unfinished file; never raises (libE57 closing a half-written file on a
        full disk fails again, which would hide the first error)."""
        try:
            writer = getattr(self, "_writer", None)
            if writer is not None and writer.isOpen():
                writer.close()
        except Exception:  # the file is dropped whatever closing it says
            pass
        try:
            self._imf.cancel()
        except Exception:
            pass
        finally:
            discard(self._tmp)
