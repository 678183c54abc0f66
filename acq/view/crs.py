"""The coordinate reference system (CRS) of a layer's file, for the page's labels, scale
bar and north arrow: a LAS/LAZ/COPC file's (its WKT or GeoTIFF keys, read by laspy and
pyproj), a PLY's ``comment crs ...`` (as `acq colorize --crs` and `acq mesh --crs` write
it); a ``.glb`` has no place for one. The page draws metres: a CRS whose horizontal axes
are in other units (degrees of a geographic CRS, feet) is refused, naming the file; a CRS
that cannot be parsed leaves the file shown in its own coordinates, with a note."""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Any, TypedDict

from acq.errors import InputError, first_line
from acq.view import las_rows

__all__ = ["FileCrs", "crs_of"]

_PLY_HEADER_MAX = 1 << 16  # bytes of a PLY read for its header's comments


class FileCrs(TypedDict):
    """A file's CRS as ``/api/layers`` gives it: ``name`` ("EPSG:25831" when EPSG knows
    it, else the CRS's own name), ``epsg`` (int or None), ``units`` of its horizontal
    axes ("metre"), ``projected``; or, for a CRS that cannot be read, every field None
    (``projected`` False) and ``note`` saying why."""

    name: str | None
    epsg: int | None
    units: str | None
    projected: bool
    note: str | None


def crs_of(path: Path) -> FileCrs | None:
    """The CRS of the layer file ``path``, None when it declares none (acq's local frames,
    a ``.glb``); InputError naming the file for a CRS not in metres."""
    import pyproj

    suffix = path.suffix.lower()
    try:
        if suffix in las_rows.SUFFIXES:
            crs = _las_crs(path)
        elif suffix == ".ply":
            text = _ply_crs_text(path)
            crs = None if text is None else pyproj.CRS.from_user_input(text)
        else:
            return None
    except (pyproj.exceptions.CRSError, ValueError, IndexError, struct.error) as e:
        note = f"its CRS cannot be read ({first_line(e)}): shown in the file's own coordinates"
        return FileCrs(name=None, epsg=None, units=None, projected=False, note=note)
    if crs is None:
        return None
    return _described(path, crs)


def _described(path: Path, crs: Any) -> FileCrs:
    """The page's description of the pyproj CRS ``crs`` of ``path``; InputError when its
    horizontal axes are not in metres."""
    units = {axis.unit_name for axis in crs.axis_info[:2]}
    if crs.is_geographic or units != {"metre"}:
        kind = "a geographic CRS (degrees)" if crs.is_geographic else f"in {', '.join(units)}"
        raise InputError(
            f"{path}: its CRS {crs.name} is {kind}; acq view draws metres (reproject it to a "
            "projected CRS in metres, e.g. with pdal translate)"
        )
    epsg = crs.to_epsg()
    name = f"EPSG:{epsg}" if epsg is not None else str(crs.name)
    return FileCrs(name=name, epsg=epsg, units="metre", projected=bool(crs.is_projected), note=None)


def _las_crs(path: Path) -> Any:
    """A LAS/LAZ file's pyproj CRS (WKT preferred over GeoTIFF keys), None without one."""
    import laspy

    try:
        with laspy.open(path) as reader:
            return reader.header.parse_crs(prefer_wkt=True)
    except laspy.LaspyException as e:
        raise ValueError(first_line(e)) from None


def _ply_crs_text(path: Path) -> str | None:
    """The text after ``comment crs`` in a PLY's header, None without such a comment."""
    with open(path, "rb") as f:
        head = f.read(_PLY_HEADER_MAX)
    for line in head.split(b"\n"):
        words = line.decode("ascii", "replace").strip()
        if words == "end_header":
            break
        if words.startswith("comment crs "):
            return words.removeprefix("comment crs ").strip()
    return None
