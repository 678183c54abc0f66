"""The driver registry: every device kind, and per kind the driver classes by the name a
configuration's ``driver:`` key gives them.

Our drivers are listed here (:data:`KINDS`); another distribution adds one through the
entry-point group of its kind, as python-can's ``can.interface`` group adds interfaces::

    [project.entry-points."acq.scanners"]
    mylidar = "mypackage.lidar:MyLidar"    # a subclass of acq.drivers.scanner.Scanner

Ours are built in rather than registered as entry points so that they are there whatever
the state of the installed metadata (a source checkout, an editable install not yet
re-installed) and so that no installed distribution can replace them: an entry point with
a built-in name is ignored. Entries are ``"module:attr"`` strings imported on first use,
so a driver whose dependencies are missing breaks no other; using it raises
:class:`DriverImportError`, naming the driver and the import error.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from importlib.metadata import entry_points
from typing import Any, Generic, TypeVar, cast

__all__ = ["KINDS", "REGISTRIES", "DriverImportError", "Kind", "Registry", "UnknownDriver"]

T = TypeVar("T")


@dataclass(frozen=True)
class Kind:
    """One device kind: its entry-point group, the class every driver of it derives from,
    and our drivers (``"module:attr"`` strings)."""

    name: str
    group: str
    base: str
    builtin: dict[str, str]


KINDS: dict[str, Kind] = {
    k.name: k
    for k in (
        Kind(
            "scanner",
            "acq.scanners",
            "acq.drivers.scanner:Scanner",
            {"hokuyo": "acq.drivers.scip:ScipScanner", "sick": "acq.drivers.cola:ColaScanner"},
        ),
        Kind(
            "camera",
            "acq.cameras",
            "acq.drivers.camera:Camera",
            {
                "opencv": "acq.drivers.camera_opencv:OpenCVCamera",
                "v4l2": "acq.drivers.camera_v4l2:V4L2Camera",
            },
        ),
        Kind(
            "can",
            "acq.can",
            "acq.drivers.can_odometry:CanOdometry",
            {"python-can": "acq.drivers.can_odometry:CanOdometry"},
        ),
        Kind(
            "gnss",
            "acq.gnss",
            "acq.drivers.nmea:NmeaReceiver",
            {"nmea": "acq.drivers.nmea:NmeaReceiver"},
        ),
    )
}


class UnknownDriver(ValueError):
    """A driver name no built-in driver nor installed entry point has."""


class DriverImportError(ImportError):
    """A registered driver that cannot be loaded (its module fails to import, or the entry
    names no driver class of its kind); the message names the driver and the cause."""


def _resolve(target: str) -> Any:
    module, _, attr = target.partition(":")
    found: Any = importlib.import_module(module)
    for part in attr.split(".") if attr else ():
        found = getattr(found, part)
    return found


class Registry(Generic[T]):
    """The drivers of one kind (``scanner``, ``camera``, ``can``, ``gnss``)."""

    def __init__(self, kind: str) -> None:
        self.kind = KINDS[kind]
        self._entries: dict[str, str] | None = None

    @property
    def entries(self) -> dict[str, str]:
        """Driver name -> ``"module:attr"``: ours, then the installed entry points."""
        if self._entries is None:
            entries = dict(self.kind.builtin)
            for ep in entry_points(group=self.kind.group):
                entries.setdefault(ep.name, ep.value)
            self._entries = entries
        return self._entries

    def reload(self) -> None:
        """Read the installed entry points again (after installing a driver)."""
        self._entries = None

    def names(self) -> list[str]:
        return sorted(self.entries)

    def get(self, name: str) -> type[T]:
        """The class registered as ``name``: UnknownDriver, DriverImportError."""
        try:
            target = self.entries[name]
        except KeyError:
            raise UnknownDriver(
                f"unknown {self.kind.name} driver {name!r}; expected one of "
                + ", ".join(self.names())
            ) from None
        try:
            found = _resolve(target)
        except Exception as e:
            raise DriverImportError(
                f"the {self.kind.name} driver {name!r} ({target}) cannot be imported: "
                f"{type(e).__name__}: {e}"
            ) from e
        base = _resolve(self.kind.base)
        if not (isinstance(found, type) and issubclass(found, base)):
            raise DriverImportError(
                f"the {self.kind.name} driver {name!r} ({target}) is not a {base.__name__}"
            )
        return cast(type[T], found)

    def create(self, driver: str, /, *args: Any, **options: Any) -> T:
        """An instance of ``driver``'s class (``options`` may include the device's ``name``)."""
        return self.get(driver)(*args, **options)


REGISTRIES: dict[str, Registry[Any]] = {kind: Registry(kind) for kind in KINDS}
"""One registry per kind; :mod:`acq.drivers.scanner` and :mod:`acq.drivers.camera` name
theirs ``SCANNERS`` and ``CAMERAS``."""
