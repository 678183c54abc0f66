"""Driver registries: a configuration's ``driver:`` name -> the class that serves it.

Entries are ``"module:Class"`` strings imported on first use (as python-can resolves
its interfaces), so a missing optional dependency of one driver breaks no other.
"""

from __future__ import annotations

import importlib
from typing import Any, Generic, TypeVar, cast

__all__ = ["Registry"]

T = TypeVar("T")


class Registry(Generic[T]):
    """Named driver classes of one kind (``scanner``, ``camera``), all subclasses of ``base``."""

    def __init__(self, kind: str, base: type, entries: dict[str, str]) -> None:
        # base is an abstract class, which type[T] cannot name (mypy: type-abstract)
        self.kind = kind
        self.base = base
        self.entries = dict(entries)

    def names(self) -> list[str]:
        return sorted(self.entries)

    def get(self, name: str) -> type[T]:
        try:
            target = self.entries[name]
        except KeyError:
            raise ValueError(
                f"unknown {self.kind} driver {name!r}; expected one of {', '.join(self.names())}"
            ) from None
        module, _, cls = target.partition(":")
        found = getattr(importlib.import_module(module), cls)
        if not (isinstance(found, type) and issubclass(found, self.base)):
            raise TypeError(f"{target} is not a {self.base.__name__}")
        return cast(type[T], found)

    def create(self, driver: str, /, *args: Any, **options: Any) -> T:
        """An instance of ``driver``'s class (``options`` may include the device's ``name``)."""
        return self.get(driver)(*args, **options)
