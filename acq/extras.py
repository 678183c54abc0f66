"""The optional parts of an install (pyproject.toml's extras) and the one-line error a
command gives when it needs one that is not installed.

The core (``pip install acq``) records, calibrates and colours; each extra below adds the
libraries of one job a recording PC does not need. A module imports an extra's library
inside the function that needs it, under :func:`needs`.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator
from contextlib import contextmanager

from acq.errors import InputError

__all__ = ["EXTRAS", "MissingExtraError", "needs", "require"]

# extra -> the top-level modules it installs (pyproject.toml's [project.optional-dependencies])
EXTRAS: dict[str, tuple[str, ...]] = {
    "cluster": ("dask", "distributed"),
    "e57": ("pye57",),
    "copc": ("copclib",),
    "ros2": ("rosbags",),
    "mesh": ("pygltflib", "pyfqmr", "scipy", "trimesh", "PIL"),
}


class MissingExtraError(InputError):
    """A command asked for a part of acq this install lacks (exit status 2: the usage is
    one this install does not allow; nothing was read or written yet)."""

    def __init__(self, what: str, extra: str) -> None:
        super().__init__(f"{what} needs the {extra} extra: pip install 'acq[{extra}]'")
        self.extra = extra


@contextmanager
def needs(extra: str, what: str) -> Iterator[None]:
    """Imports of ``extra``'s libraries inside this block raise :class:`MissingExtraError`
    saying that ``what`` (an option, an output, a command) needs it; an ImportError of any
    other module passes through as it is (a bug, not a missing extra)."""
    modules = EXTRAS[extra]
    try:
        yield
    except ImportError as e:
        if (e.name or "").split(".")[0] not in modules:
            raise
        raise MissingExtraError(what, extra) from e


def require(extra: str, what: str) -> None:
    """:class:`MissingExtraError` now, before any work, unless ``extra``'s libraries import;
    ``what`` as in :func:`needs`."""
    with needs(extra, what):
        for module in EXTRAS[extra]:
            importlib.import_module(module)
