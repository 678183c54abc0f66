"""acq: mobile-mapping acquisition, synchronisation, calibration and colouring.

One subpackage per concept, lowest layer first: ``records`` and ``geometry``; ``time``;
``camera`` and ``drivers``; ``log`` and ``motion``; ``calib``, ``cloud`` and ``record``;
``sim``; ``cli``. ``acq.camera.camera_models`` and ``acq.time.clocksync``, the names of the API in
ARCHITECTURE.md, are imported on first use.
"""

from __future__ import annotations

import importlib
from types import ModuleType

__version__ = "0.1.0"

_API = {"camera_models": "acq.camera", "clocksync": "acq.time.clocksync"}


def __getattr__(name: str) -> ModuleType:
    if name in _API:
        return importlib.import_module(_API[name])
    raise AttributeError(f"module 'acq' has no attribute {name!r}")
