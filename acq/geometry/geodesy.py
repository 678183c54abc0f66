"""World frames on the Earth: WGS-84 to a local ENU tangent plane or a projected CRS
(through pyproj), ECEF -> ENU rotations, and NED/FRD attitudes into ENU/FLU.

A :class:`WorldFrame` is named ``"odometry"`` (where dead reckoning starts, no relation to
the Earth), ``"enu"`` (the tangent plane at ``origin`` = (latitude °, longitude °,
ellipsoidal height m): x east, y north, z up) or a projected CRS (anything
``pyproj.CRS`` takes, e.g. ``"EPSG:25832"``: x grid east, y grid north, z the ellipsoidal
height, minus the ``origin`` offset (x0, y0, z0)). Grid metres are not metres: a
projection's scale factor (UTM: 0.9996 to 1.0004) is not applied here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from acq.geometry.rotations import matrices_from_euler

if TYPE_CHECKING:
    import pyproj

__all__ = ["WorldFrame", "ecef_to_enu", "ned_to_enu"]

# NED/FRD attitude (heading clockwise from north, pitch nose up, roll right side down) to
# ENU/FLU: R_enu_flu = _NED_TO_ENU @ R_ned_frd @ _FLU_TO_FRD
_NED_TO_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
_FLU_TO_FRD = np.diag([1.0, -1.0, -1.0])


def ned_to_enu(R_ned: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """(N,3,3) attitudes of a forward-right-down body in north-east-down axes -> those of
    the forward-left-up body in east-north-up axes."""
    R_enu: npt.NDArray[np.float64] = np.einsum(
        "ij,njk,kl->nil", _NED_TO_ENU, np.asarray(R_ned), _FLU_TO_FRD
    )
    return R_enu


def ecef_to_enu(lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike) -> np.ndarray:
    """(..., 3, 3) rotation ECEF -> local ENU at geodetic (lat, lon) degrees."""
    la, lo = np.radians(lat_deg), np.radians(lon_deg)
    sl, cl, so, co = np.sin(la), np.cos(la), np.sin(lo), np.cos(lo)
    zero = np.zeros_like(sl)
    return np.stack(
        [
            np.stack([-so, co, zero], axis=-1),
            np.stack([-sl * co, -sl * so, cl], axis=-1),
            np.stack([cl * co, cl * so, sl], axis=-1),
        ],
        axis=-2,
    )


@lru_cache(maxsize=16)
def _transformer(name: str, origin: tuple[float, float, float]) -> pyproj.Transformer:
    """Geodetic (lon °, lat °, h m on WGS-84) -> the frame's axes (before any offset)."""
    # imported here: pyproj takes 60 ms to import, and only georeferenced frames need it
    import pyproj

    if name == "enu":
        lat0, lon0, h0 = origin
        return pyproj.Transformer.from_pipeline(
            "+proj=pipeline +step +proj=cart +ellps=WGS84 "
            f"+step +proj=topocentric +ellps=WGS84 +lat_0={lat0!r} +lon_0={lon0!r} +h_0={h0!r}"
        )
    try:
        crs = pyproj.CRS.from_user_input(name)
    except pyproj.exceptions.CRSError as e:
        raise ValueError(f"unknown frame {name!r}: not 'odometry', 'enu' or a CRS ({e})") from e
    if not crs.is_projected:
        raise ValueError(f"frame {name!r} is not a projected CRS (metres east, north)")
    return pyproj.Transformer.from_crs("EPSG:4979", crs, always_xy=True)


@dataclass(frozen=True)
class WorldFrame:
    """A world frame by name (``"odometry"``, ``"enu"``, a CRS) and its ``origin``
    ((lat °, lon °, h m) of an ENU plane; the (x0, y0, z0) offset of a projected CRS)."""

    name: str = "odometry"
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        o = tuple(float(v) for v in self.origin)
        if len(o) != 3 or not all(math.isfinite(v) for v in o):
            raise ValueError(f"origin must be 3 finite numbers, got {self.origin!r}")
        object.__setattr__(self, "origin", o)
        if self.name == "enu" and not (-90.0 <= o[0] <= 90.0):
            raise ValueError(f"an ENU origin is (lat, lon, h); latitude {o[0]} is out of range")
        if self.georeferenced:
            _transformer(self.name, self._key())  # fail early on an unknown CRS

    @property
    def georeferenced(self) -> bool:
        """False for the odometry frame (no relation to the Earth)."""
        return self.name != "odometry"

    def _key(self) -> tuple[float, float, float]:
        return self.origin if self.name == "enu" else (0.0, 0.0, 0.0)

    def _offset(self) -> npt.NDArray[np.float64]:
        return np.zeros(3) if self.name == "enu" else np.asarray(self.origin, dtype=np.float64)

    def _need_geo(self) -> None:
        if not self.georeferenced:
            raise ValueError("the odometry frame is not tied to the Earth: no geodetic coordinates")

    def from_geodetic(
        self, lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike, h_m: npt.ArrayLike
    ) -> np.ndarray:
        """WGS-84 latitude, longitude (°), ellipsoidal height (m) -> (N,3) m in this frame."""
        self._need_geo()
        lat, lon, h = np.broadcast_arrays(
            *(np.asarray(a, dtype=np.float64).reshape(-1) for a in (lat_deg, lon_deg, h_m))
        )
        x, y, z = _transformer(self.name, self._key()).transform(lon, lat, h)
        return np.stack([x, y, z], axis=1) - self._offset()

    def to_geodetic(self, xyz: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(N,3) m in this frame -> (latitude °, longitude °, ellipsoidal height m)."""
        self._need_geo()
        P = np.asarray(xyz, dtype=np.float64).reshape(-1, 3) + self._offset()
        lon, lat, h = _transformer(self.name, self._key()).transform(
            P[:, 0], P[:, 1], P[:, 2], direction="INVERSE"
        )
        return np.asarray(lat), np.asarray(lon), np.asarray(h)

    def rotation_from_local_enu(
        self, lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike, h_m: npt.ArrayLike
    ) -> np.ndarray:
        """(N,3,3) rotations taking vectors in the local ENU at each point into this
        frame's axes: exact for an ENU frame (the tangent planes' tilt); for a projected
        CRS the turn from true to grid north (meridian convergence), by differences."""
        self._need_geo()
        lat, lon, h = np.broadcast_arrays(
            *(np.asarray(a, dtype=np.float64).reshape(-1) for a in (lat_deg, lon_deg, h_m))
        )
        if self.name == "enu":
            R: npt.NDArray[np.float64] = ecef_to_enu(self.origin[0], self.origin[1])[
                None
            ] @ np.swapaxes(ecef_to_enu(lat, lon), -1, -2)
            return R
        d = 1e-6  # degrees of latitude, ~0.1 m
        n = self.from_geodetic(lat + d, lon, h) - self.from_geodetic(lat - d, lon, h)
        # local north (ENU angle pi/2) points along n in the grid
        return matrices_from_euler(0.0, 0.0, np.arctan2(n[:, 1], n[:, 0]) - math.pi / 2)
