"""Small clouds and meshes as acq writes them, for the tests of `acq view`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from acq.cloud.ply import PlyStream
from acq.mesh import files

# a unit square's two triangles, one corner raised, each corner its own colour
XYZ = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 1]], float)
RGB = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [255, 255, 0]], np.uint8)
FACES = np.array([[0, 1, 2], [1, 3, 2]])


def cloud(path: Path, n: int = 500, seed: int = 0) -> Path:
    """A PLY cloud of ``n`` points as `acq colorize` writes it (every column)."""
    rng = np.random.default_rng(seed)
    out = PlyStream(path, ["frame world"], ["left"])
    out.write(
        rng.uniform(-5, 5, (n, 3)), rng.integers(0, 256, (n, 3), dtype=np.uint8),
        np.sort(rng.uniform(0, 10, n)), rng.uniform(0, 1, n).astype(np.float32),
        np.arange(n, dtype=np.int32) // 50, np.ones(n, bool), np.zeros(n, np.uint8),
        np.arange(n, dtype=np.int32),
    )  # fmt: skip
    out.close()
    return path


def mesh(path: Path, offset: float = 0.0) -> Path:
    """A mesh of two triangles as `acq mesh` writes it (.ply or .glb by the suffix)."""
    files.write(path, XYZ + offset, RGB, FACES)
    return path


def las_cloud(
    path: Path,
    n: int = 500,
    seed: int = 0,
    at: tuple[float, float, float] = (0, 0, 0),
    rgb: tuple[int, int, int] | None = None,
    xyz: np.ndarray | None = None,
    crs: str | None = "EPSG:25831",
) -> tuple[Path, np.ndarray, np.ndarray]:
    """A LAS, LAZ or COPC cloud (by the suffix: .las, .laz, .copc.laz) of ``n`` points
    within 5 m of ``at`` (or of the points ``xyz``, m) in ``crs`` as `acq colorize` writes
    it, all of colour ``rgb`` or random; the path, the points' xyz (m) and rgb as written."""
    from acq.cloud.copc import CopcStream
    from acq.cloud.las import LasStream

    rng = np.random.default_rng(seed)
    if xyz is None:
        xyz = rng.uniform(-5, 5, (n, 3)) + np.array(at, float)
    n = len(xyz)
    colours = (
        np.tile(np.array(rgb, np.uint8), (n, 1)) if rgb is not None
        else rng.integers(0, 256, (n, 3), dtype=np.uint8)
    )  # fmt: skip
    stream = CopcStream if path.name.endswith(".copc.laz") else LasStream
    out = stream(path, crs=crs, cameras=["left"])
    out.write(
        xyz, colours, np.sort(rng.uniform(0, 10, n)), rng.uniform(0, 1, n).astype(np.float32),
        np.arange(n, dtype=np.int32) // 50, np.ones(n, bool), np.zeros(n, np.uint8),
        np.arange(n, dtype=np.int32),
    )  # fmt: skip
    out.close()
    return path, xyz, colours


def unpack(data: bytes | bytearray, attributes: bytes | bytearray | None = None) -> dict[str, Any]:
    """A payload of acq.view.points_payload read back (its layout written out again, from
    its documentation, as the page's parser reads it): the header's fields ("flags": the
    columns the file has, "part": its part bits), "names" (the cameras'), "xyz" (float64,
    the origin added) and each column it holds; with ``attributes``, the attributes part
    of the same points, whose columns are added (its header checked to be the same)."""
    out = _unpack(data)
    if attributes is not None:
        more = _unpack(attributes)
        assert (out["part"], more["part"]) == (64, 128), (out["part"], more["part"])
        same = ("shown", "rows", "start", "stop", "origin", "time0", "flags", "names")
        assert all(out[key] == more[key] for key in same)
        out |= {key: value for key, value in more.items() if key not in same}
        out["part"] = 0
    return out


def _unpack(data: bytes | bytearray) -> dict[str, Any]:
    from acq.view.points_payload import HEADER, MAGIC

    magic, m, rows, start, stop, ox, oy, oz, time0, flags, length = HEADER.unpack_from(data)
    assert magic == MAGIC
    at = HEADER.size + -(-length // 4) * 4
    part = flags & 192
    assert part in (0, 64, 128) and flags < 256, flags
    out: dict[str, Any] = {
        "shown": m, "rows": rows, "start": start, "stop": stop, "origin": (ox, oy, oz),
        "time0": time0, "flags": flags & 63, "part": part,
        "names": bytes(data[HEADER.size : HEADER.size + length]).decode().split("\n")
        if length else [],
    }  # fmt: skip
    if part != 128:  # the attributes part has no positions
        offsets = np.frombuffer(data, np.float32, 3 * m, at).reshape(m, 3)
        out["xyz"] = offsets.astype(np.float64) + np.array([ox, oy, oz])
        at += 12 * m
    for name, flag, kind, width in [
        ("time", 2, np.float32, 1), ("scan", 4, np.uint32, 1), ("intensity", 8, np.float32, 1),
        ("rgb", 1, np.uint8, 3), ("coloured", 16, np.uint8, 1), ("camera", 32, np.uint8, 1),
    ]:  # fmt: skip
        # the points part holds sRGB only, the attributes part all but sRGB
        held = part == 0 or (part == 64) == (name == "rgb")
        if flags & flag and held:
            values = np.frombuffer(data, kind, width * m, at)
            out[name] = values.reshape(m, 3) if width == 3 else values
            at += values.nbytes
    assert at == len(data), f"{len(data)} bytes, {at} expected"
    return out
