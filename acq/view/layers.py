"""What `acq view` shows: a layer is one file (a ``.ply`` cloud or mesh, a ``.glb``
mesh, a ``.las``/``.laz``/``.copc.laz`` cloud) or one drive (a session's ``.mcap`` logs,
read by :mod:`acq.view.drive`), checked before it is served so that the page never gets a
file it cannot draw; a folder stands for the viewable files in it."""

from __future__ import annotations

import json
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from acq.errors import InputError, first_line
from acq.view import las_rows

__all__ = ["SUFFIXES", "Layer", "layer_of", "layers_of"]

SUFFIXES = (".ply", ".glb", ".las", ".laz", ".mcap")  # .copc.laz among the .laz
_GLB_MAGIC, _GLB_JSON, _GLB_BIN = b"glTF", 0x4E4F534A, 0x004E4942


@dataclass(frozen=True)
class Layer:
    """A file the page draws: ``kind`` "cloud" (points) or "mesh" (triangles), ``count``
    its vertices (a cloud's points), ``size`` its bytes; or a "drive": the ``files`` of
    one session's logs (``path`` the first), ``count`` of them."""

    path: Path
    kind: Literal["cloud", "mesh", "drive"]
    count: int
    size: int
    files: tuple[Path, ...] = ()

    @property
    def name(self) -> str:
        return self.path.name


def layers_of(paths: Sequence[Path]) -> list[Layer]:
    """The layers of ``paths`` (files, or folders standing for their files of
    :data:`SUFFIXES`, by name), in order; InputError naming the first path that is
    missing, unreadable, malformed or a folder with nothing to view. The ``.mcap`` logs
    among them make one "drive" layer per session (:func:`acq.log.inputs.sessions`), in
    the place of the session's first file; their contents are checked by
    :class:`acq.view.drive.Drive`."""
    layers: list[Layer | list[Path]] = []
    logs: list[Path] = []
    for path in paths:
        if path.is_dir():
            found = sorted(p for p in path.iterdir() if p.suffix.lower() in SUFFIXES)
            if not found:
                shown = f"{', '.join(SUFFIXES[:-1])} or {SUFFIXES[-1]}"
                raise InputError(f"{path}: a folder with no {shown} file in it")
        else:
            found = [path]
        for p in found:
            if p.suffix.lower() == ".mcap":
                if not logs:
                    layers.append(logs)  # the drives' place among the layers
                logs.append(p)
            else:
                layers.append(layer_of(p))
    return [
        drive for item in layers for drive in (_drives(item) if isinstance(item, list) else [item])
    ]


def _drives(logs: list[Path]) -> list[Layer]:
    """A "drive" layer per session of the logs ``logs``."""
    from acq.log.inputs import sessions

    for path in logs:
        if not path.is_file():
            raise InputError(f"{path}: {'not a file' if path.exists() else 'no such file'}")
    found = sessions(logs, option="PATH")
    sizes = [sum(f.stat().st_size for f in s.files) for s in found]
    return [
        Layer(s.files[0], "drive", len(s.files), size, tuple(s.files))
        for s, size in zip(found, sizes, strict=True)
    ]


def layer_of(path: Path) -> Layer:
    """The layer of the file ``path``, checked; InputError naming it otherwise."""

    suffix = path.suffix.lower()
    if suffix not in SUFFIXES:
        raise InputError(f"{path}: not a file acq view shows (expected {', '.join(SUFFIXES)})")
    try:
        size = path.stat().st_size
        if not path.is_file():
            raise InputError(f"{path}: not a file")
        if suffix == ".mcap":
            return _drives([path])[0]
        if suffix == ".ply":
            kind, count = _ply(path)
        elif suffix in las_rows.SUFFIXES:
            kind, count = "cloud", las_rows.check(path)
        else:
            kind, count = _glb(path, size)
    except OSError as e:
        raise InputError(f"{path}: {e.strerror or e}") from None
    return Layer(path, kind, count, size)


def _ply(path: Path) -> tuple[Literal["cloud", "mesh"], int]:
    """A PLY's kind and vertex count, its every element read (memory-mapped where its
    rows are of fixed size) and its coordinates finite."""
    from plyfile import PlyData, PlyParseError

    try:
        try:  # acq's facets are triangles: mapped, not parsed row by row
            data = PlyData.read(str(path), known_list_len={"face": {"vertex_indices": 3}})
        except PlyParseError:
            data = PlyData.read(str(path))
    except (PlyParseError, ValueError, UnicodeDecodeError, IndexError, struct.error) as e:
        raise InputError(f"{path}: not a readable PLY file ({first_line(e)})") from None
    if "vertex" not in data:
        raise InputError(f"{path}: a PLY file without a vertex element")
    vertex = data["vertex"].data
    names = vertex.dtype.names or ()
    if not {"x", "y", "z"} <= set(names):
        raise InputError(f"{path}: a PLY file whose vertices lack x, y or z")
    if len(vertex) == 0:
        raise InputError(f"{path}: a PLY file with no vertex")
    bad = ~(np.isfinite(vertex["x"]) & np.isfinite(vertex["y"]) & np.isfinite(vertex["z"]))
    if bad.any():
        raise InputError(
            f"{path}: {int(bad.sum())} vertices with a non-finite coordinate (vertex "
            f"{int(np.argmax(bad))} the first); the page cannot frame them"
        )
    faces = len(data["face"].data) if "face" in data else 0
    return ("mesh" if faces else "cloud"), len(vertex)


def _glb(path: Path, size: int) -> tuple[Literal["cloud", "mesh"], int]:
    """A glTF binary's vertex count (its meshes' POSITION accessors), its header, chunks
    and buffer views checked against the file's bytes (glTF 2.0 §4.4)."""
    with open(path, "rb") as f:
        head = f.read(20)
        if len(head) < 20 or head[:4] != _GLB_MAGIC:
            raise InputError(f"{path}: not a glTF binary file (no glTF header)")
        version, length, json_length, json_type = struct.unpack("<IIII", head[4:])
        if version != 2:
            raise InputError(f"{path}: glTF version {version}; expected 2")
        if length != size:
            raise InputError(f"{path}: its header says {length} bytes, the file has {size}")
        if json_type != _GLB_JSON or 20 + json_length > size:
            raise InputError(f"{path}: no JSON chunk where a glTF binary has one")
        text = f.read(json_length)
        bin_length = 0
        chunk = f.read(8)
        if len(chunk) == 8:
            bin_length, bin_type = struct.unpack("<II", chunk)
            if bin_type != _GLB_BIN or 28 + json_length + bin_length > size:
                raise InputError(f"{path}: its binary chunk runs past the end of the file")
    try:
        gltf: dict[str, Any] = json.loads(text)
        count = _glb_vertices(gltf, bin_length)
    except (ValueError, KeyError, TypeError, IndexError) as e:
        raise InputError(f"{path}: a malformed glTF JSON chunk ({first_line(e)})") from None
    if count == 0:
        raise InputError(f"{path}: a glTF binary with no mesh vertex")
    return "mesh", count


def _glb_vertices(gltf: dict[str, Any], bin_length: int) -> int:
    """The vertices of a glTF's mesh primitives; ValueError for a buffer view beyond the
    binary chunk."""
    for k, view in enumerate(gltf.get("bufferViews", [])):
        end = int(view.get("byteOffset", 0)) + int(view["byteLength"])
        if view.get("buffer", 0) == 0 and end > bin_length:
            raise ValueError(f"bufferViews[{k}] ends at byte {end}, past the binary chunk")
    accessors = gltf.get("accessors", [])
    return sum(
        int(accessors[p["attributes"]["POSITION"]]["count"])
        for mesh in gltf.get("meshes", [])
        for p in mesh["primitives"]
    )
