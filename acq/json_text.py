"""Command output as JSON under RFC 8259: :func:`dumps`, which every ``--json`` report
and JSON file of acq goes through. JSON has no NaN or Infinity: a value that is not a
finite number (a reading nothing could be computed from) is written as ``null``, and one
WARNING line says where and why."""

from __future__ import annotations

import dataclasses
import json
import logging
import math
from os import PathLike
from typing import Any

import numpy as np

__all__ = ["dumps", "plain"]

log = logging.getLogger(__name__)


def plain(value: Any, where: str = "$", nulled: list[str] | None = None) -> Any:
    """``value`` as JSON's types: dicts, lists, str, int, float, bool, None. Dataclasses
    become dicts, tuples, sets and numpy arrays lists, numpy scalars Python numbers,
    paths str; a float that is NaN or infinite becomes None, its place (``$.a.b[2]``)
    appended to ``nulled``."""
    if isinstance(value, bool | str | int) or value is None:
        return value
    if isinstance(value, np.generic | np.ndarray):
        return plain(value.tolist(), where, nulled)
    if isinstance(value, float):
        if math.isfinite(value):
            return value
        if nulled is not None:
            nulled.append(where)
        return None
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        value = dataclasses.asdict(value)
    if isinstance(value, dict):
        return {str(k): plain(v, f"{where}.{k}", nulled) for k, v in value.items()}
    if isinstance(value, list | tuple | set | frozenset):
        return [plain(v, f"{where}[{i}]", nulled) for i, v in enumerate(value)]
    if isinstance(value, PathLike):
        return str(value)
    raise TypeError(f"{where}: a {type(value).__name__} has no JSON form")


def dumps(value: Any, *, indent: int | None = 2, what: str = "JSON output") -> str:
    """``value`` as RFC 8259 JSON text (see :func:`plain`); values that are not finite
    numbers written as null, with one WARNING naming them (``what``: the output)."""
    nulled: list[str] = []
    text = json.dumps(plain(value, "$", nulled), indent=indent, allow_nan=False)
    if nulled:
        shown = ", ".join(nulled[:5]) + (f" and {len(nulled) - 5} more" if len(nulled) > 5 else "")
        log.warning(
            "%s: %d values not finite numbers (NaN or infinite) written as null, as JSON "
            "has no NaN: %s", what, len(nulled), shown,
        )  # fmt: skip
    return text
