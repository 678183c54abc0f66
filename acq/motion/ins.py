"""Post-processed GNSS/INS trajectories in CSV files: read (:func:`from_csv`) and written
(:func:`to_csv`); errors name the file, line and column (:class:`TrajectoryFileError`)."""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import numpy.typing as npt

from acq.atomic_write import atomic
from acq.errors import InputValueError
from acq.geometry.geodesy import WorldFrame, ned_to_enu
from acq.geometry.rotations import euler_from_matrices, matrices_from_euler
from acq.motion.trajectory import Trajectory
from acq.time import gpstime

__all__ = ["TrajectoryFileError", "from_csv", "to_csv"]


class TrajectoryFileError(InputValueError):
    """A trajectory file that cannot be read; the message names the file, line and
    column."""


_TIME_COLS = (("time",), ("gps_week", "gps_sow"))
_POS_COLS = (("x", "y", "z"), ("lat", "lon", "h"))
_ATT_COLS = (("roll", "pitch", "yaw"), ("roll", "pitch", "heading"))


def _fail(path: Path, line: int, msg: str) -> TrajectoryFileError:
    return TrajectoryFileError(f"{path}:{line}: {msg}")


def _pick_cols(
    path: Path, line: int, header: list[str], sets: tuple[tuple[str, ...], ...], what: str
) -> tuple[str, ...]:
    found = [s for s in sets if all(c in header for c in s)]
    if not found:
        want = " or ".join(",".join(s) for s in sets)
        raise _fail(path, line, f"no {what} columns: the header needs {want}")
    if what == "position" and len(found) > 1:
        raise _fail(path, line, "both x,y,z and lat,lon,h columns: keep one set")
    if what == "attitude" and len(found) > 1:
        raise _fail(path, line, "both yaw and heading columns: keep one")
    return found[0]


def _parse_time(s: str) -> float:
    try:
        return float(s)
    except ValueError:
        pass
    dt = datetime.fromisoformat(s)
    if dt.tzinfo is None:
        dt = dt.replace(tzinfo=UTC)
    return dt.timestamp()


def _read_rows(
    path: Path, names: list[str], header_line: int, header: list[str]
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Columns ``names`` as float64 arrays (``time`` may be ISO-8601) and each row's line
    number; errors name the line and column."""
    cols = {n: header.index(n) for n in names}
    values: dict[str, list[float]] = {n: [] for n in names}
    lines: list[int] = []
    with path.open(newline="", encoding="utf-8-sig") as f:
        reader = csv.reader(f)
        for row in reader:
            line = reader.line_num
            if line <= header_line or not row or row[0].lstrip().startswith("#"):
                continue
            if len(row) < len(header):
                raise _fail(path, line, f"{len(row)} fields, the header has {len(header)}")
            for n, i in cols.items():
                s = row[i].strip()
                try:
                    x = _parse_time(s) if n == "time" else float(s)
                except ValueError:
                    kind = "UTC seconds or an ISO-8601 time" if n == "time" else "a number"
                    raise _fail(
                        path, line, f"column {n!r} (column {i + 1}): {s!r} is not {kind}"
                    ) from None
                if not math.isfinite(x):
                    raise _fail(path, line, f"column {n!r} (column {i + 1}): {s!r} is not finite")
                values[n].append(x)
            lines.append(line)
    return {n: np.array(v, dtype=np.float64) for n, v in values.items()}, np.array(lines)


def _header(path: Path) -> tuple[int, list[str], dict[str, tuple[str, int]]]:
    """(line number of the header, lower-case column names, ``# key: value`` comments
    before it with their line numbers)."""
    meta: dict[str, tuple[str, int]] = {}
    try:
        with path.open(newline="", encoding="utf-8-sig") as f:
            for n, text in enumerate(f, start=1):
                s = text.strip()
                if not s:
                    continue
                if s.startswith("#"):
                    key, sep, val = s[1:].partition(":")
                    if sep:
                        meta[key.strip().lower()] = (val.strip(), n)
                    continue
                header = [c.strip().lower() for c in next(csv.reader([s]))]
                dup = sorted({c for c in header if header.count(c) > 1})
                if dup:
                    raise _fail(path, n, f"repeated column {dup[0]!r}")
                return n, header, meta
    except UnicodeDecodeError as e:
        raise TrajectoryFileError(f"{path}: not a text file ({e})") from None
    raise TrajectoryFileError(f"{path}: empty: no header line")


def from_csv(
    path: str | os.PathLike[str],
    *,
    utc_to_host_ns: Callable[[np.ndarray], np.ndarray],
    frame: str | None = None,
    origin: tuple[float, float, float] | None = None,
    max_gap_s: float = math.inf,
    margin_s: float = 0.0,
) -> Trajectory:
    """A post-processed GNSS/INS trajectory from a CSV file with a header.

    Columns (case-insensitive, in any order, others ignored):

    - time: ``time`` (UTC: POSIX seconds, or ISO-8601 such as 2024-05-02T10:00:00.25Z;
      without a zone, UTC) or ``gps_week,gps_sow`` (full GPS week, seconds of week);
    - position: ``x,y,z`` (m, in ``frame``; a projected CRS's full coordinates) or
      ``lat,lon,h`` (WGS-84 °, ellipsoidal m, put into ``frame``, default "enu" at the
      first row);
    - attitude, degrees, of the vehicle frame (x forward, y left, z up): ``roll,pitch,yaw``
      as :func:`acq.geometry.rotations.rotation_from_euler` (``Rz(yaw) Ry(pitch) Rx(roll)``; yaw
      counter-clockwise from east, or from the frame's x axis with x,y,z) or
      ``roll,pitch,heading``, the NED convention of most INS (heading clockwise from
      north, or from the frame's y axis with x,y,z; pitch nose up; roll right side down;
      of a forward-right-down body).

    ``# frame: NAME`` and ``# origin: a, b, c`` comment lines before the header (what
    :func:`to_csv` writes) give the frame where the arguments do not. UTC becomes host
    ns by ``utc_to_host_ns`` (e.g. ``lambda u: acq.time.utc.host_ns_from_utc(u, clock)``). Raises
    :class:`TrajectoryFileError` naming the file, line and column.
    """
    path = Path(path)
    try:
        header_line, header, meta = _header(path)
    except OSError as e:
        raise TrajectoryFileError(f"{path}: {e.strerror or e}") from None
    tcols = _pick_cols(path, header_line, header, _TIME_COLS, "time")
    pcols = _pick_cols(path, header_line, header, _POS_COLS, "position")
    acols = _pick_cols(path, header_line, header, _ATT_COLS, "attitude")
    data, lines = _read_rows(path, [*tcols, *pcols, *acols], header_line, header)
    if lines.size < 2:
        raise _fail(path, header_line, f"{lines.size} data rows: a trajectory needs 2")
    if tcols == ("time",):
        utc = data["time"]
    else:
        utc = gpstime.gps_week_sow_to_utc(data["gps_week"], data["gps_sow"])
    t = np.asarray(utc_to_host_ns(utc), dtype=np.int64).reshape(-1)
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise _fail(path, int(lines[i]), f"time {float(utc[i])!r} is not after the previous row's")

    file_frame = meta["frame"][0] if "frame" in meta else None
    name = frame if frame is not None else file_frame
    if origin is None and "origin" in meta and (frame is None or frame == file_frame):
        text, line = meta["origin"]
        try:
            parsed = [float(v) for v in text.split(",")]
        except ValueError:
            parsed = []
        if len(parsed) != 3:
            raise _fail(path, line, f"'# origin: {text}' is not 3 numbers")
        origin = (parsed[0], parsed[1], parsed[2])
    if pcols == ("lat", "lon", "h"):
        lat, lon, h = data["lat"], data["lon"], data["h"]
        if name is None:
            name = "enu"
        if origin is None:
            origin = (lat[0], lon[0], h[0]) if name == "enu" else (0.0, 0.0, 0.0)
        try:
            world = WorldFrame(name, origin)
            P = world.from_geodetic(lat, lon, h)
            to_frame = world.rotation_from_local_enu(lat, lon, h)
        except ValueError as e:
            raise TrajectoryFileError(f"{path}: {e}") from None
    else:
        if name is None:
            raise _fail(
                path,
                header_line,
                "x,y,z columns need a frame: frame='EPSG:...' (or 'enu' with its origin, "
                "or 'odometry'), or a '# frame:' line",
            )
        if frame is not None and file_frame not in (None, frame):
            raise _fail(
                path,
                meta["frame"][1],
                f"the file's frame is {file_frame!r}, not {frame!r} (x,y,z are not reprojected)",
            )
        if name == "enu" and origin is None:
            raise _fail(path, header_line, "x,y,z in 'enu' need its origin (lat, lon, h)")
        try:
            world = WorldFrame(name, origin if origin is not None else (0.0, 0.0, 0.0))
        except ValueError as e:
            raise TrajectoryFileError(f"{path}: {e}") from None
        offset = np.zeros(3) if world.name in ("enu", "odometry") else np.asarray(world.origin)
        P = np.column_stack([data["x"], data["y"], data["z"]]) - offset
        to_frame = None
    roll, pitch = np.radians(data["roll"]), np.radians(data["pitch"])
    if "yaw" in acols:
        R = matrices_from_euler(roll, pitch, np.radians(data["yaw"]))
    else:
        R = ned_to_enu(matrices_from_euler(roll, pitch, np.radians(data["heading"])))
    if to_frame is not None:
        R = to_frame @ R
    return Trajectory(t, R, P, world.name, world.origin, max_gap_s=max_gap_s, margin_s=margin_s)


def to_csv(
    path: str | os.PathLike[str],
    traj: Trajectory,
    *,
    host_to_utc: Callable[[np.ndarray], np.ndarray],
    t_ns: npt.ArrayLike | None = None,
) -> int:
    """Write ``traj`` (at its samples, or at ``t_ns``) as ``time,x,y,z,roll,pitch,yaw``:
    UTC POSIX seconds by ``host_to_utc`` (e.g. ``lambda t: utc_seconds(t, clock)``),
    metres in the trajectory's frame (a CRS's full coordinates), degrees as
    :func:`from_csv` reads them, with ``# frame:`` and ``# origin:`` lines. Returns the
    number of rows."""
    t = traj.t_ns if t_ns is None else np.asarray(t_ns, dtype=np.int64).reshape(-1)
    R, p = traj.pose_at(t)
    world = traj.world
    if world.name not in ("enu", "odometry"):
        p = p + np.asarray(world.origin)
    utc = np.asarray(host_to_utc(t), dtype=np.float64)
    if not np.isfinite(utc).all():
        raise ValueError("host_to_utc gave non-finite UTC times (a log without clock pairs?)")
    roll, pitch, yaw = (np.degrees(a) for a in euler_from_matrices(R))
    with atomic(Path(path)) as tmp, tmp.open("w", newline="") as f:
        f.write(f"# frame: {world.name}\n")
        if world.name != "odometry":
            f.write("# origin: " + ", ".join(repr(v) for v in world.origin) + "\n")
        f.write("time,x,y,z,roll,pitch,yaw\n")
        for i in range(t.size):
            f.write(
                f"{float(utc[i])!r},{p[i, 0]:.6f},{p[i, 1]:.6f},{p[i, 2]:.6f},"
                f"{roll[i]:.9f},{pitch[i]:.9f},{yaw[i]:.9f}\n"
            )
    return int(t.size)
