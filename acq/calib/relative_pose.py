"""The cameras' poses relative to each other, from their calibrations against one laser.

Each camera's ``camera_to_laser`` is found on its own; camera A -> camera B is then
``inverse(B) @ A`` (P_B = R @ P_A + t). On a rigid support that transform is fixed, so it
is the rig's consistency check: its error is what both calibrations' errors add up to,
and it is what a surface seen by both cameras shows as a seam.

Units: degrees for the rotation angles, metres for translations.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from acq.camera.calibfile import CalibStd
from acq.geometry.rotations import rotation_angle
from acq.geometry.transforms import Rigid

__all__ = ["RelativePose", "difference", "relative_poses"]


def difference(got: Rigid, truth: Rigid) -> tuple[float, float]:
    """How far ``got`` is from ``truth``: the geodesic angle of R_got R_truthᵀ (deg) and
    the distance between the translations (m)."""
    angle = math.degrees(rotation_angle(got.rotation @ truth.rotation.T))
    return angle, float(np.linalg.norm(got.translation - truth.translation))


@dataclass(frozen=True)
class RelativePose:
    """Camera ``a`` -> camera ``b`` (P_b = R @ P_a + t): ``transform``, its rotation angle
    (deg) and translation length (m); ``std_deg``/``std_m``: one standard deviation of
    the rotation and of the translation expected from the two calibrations' std (their
    rotations' and translations' std added in quadrature; NaN where a std is missing)."""

    a: str
    b: str
    transform: Rigid
    angle_deg: float
    translation_m: float
    std_deg: float
    std_m: float

    def to_dict(self) -> dict[str, Any]:
        def num(x: float, digits: int) -> float | None:
            return round(x, digits) if math.isfinite(x) else None

        return {
            "from": self.a,
            "to": self.b,
            "angle_deg": round(self.angle_deg, 4),
            "translation_m": round(self.translation_m, 5),
            "std_deg": num(self.std_deg, 4),
            "std_m": num(self.std_m, 5),
            "transform": self.transform.to_dict(),
        }

    def line(self) -> str:
        """One line for a person."""
        t = ", ".join(f"{x:+.4f}" for x in self.transform.translation)
        spread = ""
        if math.isfinite(self.std_deg) and math.isfinite(self.std_m):
            spread = f" (+- {self.std_deg:.3f} deg, {self.std_m * 1e3:.1f} mm from the std)"
        return (
            f"  {self.a} -> {self.b}: rotation {self.angle_deg:.3f} deg, translation "
            f"{self.translation_m:.4f} m ({t}){spread}"
        )


def _norm(values: tuple[float, ...] | None) -> float:
    return math.nan if values is None else math.sqrt(sum(v * v for v in values))


def relative_poses(
    cameras: Mapping[str, Rigid], std: Mapping[str, CalibStd] | None = None
) -> list[RelativePose]:
    """Every pair of ``cameras`` (name -> camera_to_laser), in their order: the first
    named -> the second."""
    std = std or {}
    out = []
    for (a, A), (b, B) in itertools.combinations(cameras.items(), 2):
        T = B.inverse() @ A
        sa, sb = std.get(a, CalibStd()), std.get(b, CalibStd())
        out.append(
            RelativePose(
                a,
                b,
                T,
                math.degrees(rotation_angle(T.rotation)),
                float(np.linalg.norm(T.translation)),
                math.hypot(_norm(sa.rotation_deg), _norm(sb.rotation_deg)),
                math.hypot(_norm(sa.translation_m), _norm(sb.translation_m)),
            )
        )
    return out
