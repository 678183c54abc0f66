"""The calib.yaml that `acq calibrate extrinsic|time-offset` write: its --force, and
whether it is one of the inputs, updated in place."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["FORCE_HELP", "same_file"]

FORCE_HELP = (
    "replace an existing output YAML (or update the input one in place), keeping NAME.bak, "
    "and outputs that acq did not write"
)


def same_file(a: Path, b: Path | None) -> bool:
    """Whether ``a`` and ``b`` both exist and are one file (a calibration updated in place)."""
    return b is not None and a.exists() and b.exists() and os.path.samefile(a, b)
