"""A driver's class from its registry name, and the ``options`` a configuration gives it:
checked against the keyword parameters of the driver class (and of the bases it forwards
``**options`` to), numbers bounded where an option has our drivers' meaning
(:data:`OPTION_BOUNDS`)."""

from __future__ import annotations

import functools
import inspect
import math
import types
import typing
from typing import Annotated, Any, NoReturn

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError

from acq.drivers.registry import REGISTRIES, DriverImportError, UnknownDriver
from acq.yamlcheck import describe, did_you_mean, fail, show

__all__ = ["MAX_BAUD", "OPTION_BOUNDS", "check_options", "driver_class", "expected_one_of"]

MAX_BAUD = 10_000_000
"""The largest serial or CAN bit rate, bit/s."""
OPTION_BOUNDS: dict[str, tuple[float, float]] = {
    "timeout": (0.01, 60.0),  # s, a read's wait
    "exposure_s": (1e-6, 10.0),  # s
    "gain": (-(2**31), 2**31 - 1),  # device units (a V4L2 control is 32-bit)
    "white_balance_k": (1000, 20000),  # K
    "buffers": (1, 32),  # mmap buffers queued (VIDEO_MAX_FRAME)
    "jpeg_quality": (1, 100),
    "baudrate": (1, MAX_BAUD),  # bit/s
    "initial_baudrate": (1, MAX_BAUD),
    "cluster": (1, 99),  # SCIP: steps grouped per range
    "angle_min": (-2 * math.pi, 2 * math.pi),  # rad
    "angle_max": (-2 * math.pi, 2 * math.pi),
}
"""(min, max) of the numeric driver options of these names (our drivers' meaning)."""
_LOGIN = tuple[
    Annotated[int, Field(ge=0, le=255)], Annotated[int, Field(ge=0, le=2**32 - 1)]
]  # CoLa's SetAccessMode: a user level byte and a 32-bit password hash


def expected_one_of(choices: list[str], value: Any) -> NoReturn:
    raise fail(f"expected one of: {', '.join(choices)}, got {show(value)}")


def driver_class(kind: str, name: str) -> type:
    """The registered class of a driver name (a validation error when it is unknown or its
    module cannot be imported)."""
    registry = REGISTRIES[kind]
    try:
        return registry.get(name)
    except UnknownDriver:
        return expected_one_of(registry.names(), name)
    except DriverImportError as e:
        raise fail(str(e)) from None


@functools.cache
def _driver_params(kind: str, driver: str) -> dict[str, TypeAdapter[Any]]:
    """The keyword parameters of the driver class (and of the bases it forwards
    ``**options`` to) that a YAML value can fill, with their validators."""
    cls = driver_class(kind, driver)
    params: dict[str, TypeAdapter[Any]] = {}
    for klass in cls.__mro__:
        init = klass.__dict__.get("__init__")
        if init is None:
            continue
        try:
            hints = typing.get_type_hints(init)
        except Exception:
            hints = {}
        forwards = False
        for p in list(inspect.signature(init).parameters.values())[1:]:
            if p.kind is p.VAR_KEYWORD:
                forwards = True
            elif p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD) and p.name not in params:
                try:  # a parameter no YAML value can fill (a test hook) is not an option
                    params[p.name] = TypeAdapter(
                        _bounded(p.name, hints.get(p.name, Any)),
                        config=ConfigDict(allow_inf_nan=False),
                    )
                except Exception:
                    continue
        if not forwards:
            break
    return params


def _bounded(name: str, hint: Any) -> Any:
    """``hint`` with the bounds :data:`OPTION_BOUNDS` gives ``name`` (a number, optional or
    not); CoLa's ``login`` bounded per element."""
    if name == "login" and hint == tuple[int, int]:
        return _LOGIN
    bounds = OPTION_BOUNDS.get(name)
    args = typing.get_args(hint)
    optional = typing.get_origin(hint) in (typing.Union, types.UnionType) and type(None) in args
    inner = [a for a in args if a is not type(None)] if optional else [hint]
    if bounds is None or len(inner) != 1 or inner[0] not in (int, float):
        return hint
    annotated: Any = Annotated  # a type built at run time
    number = annotated[inner[0], Field(ge=bounds[0], le=bounds[1])]
    return number | None if optional else number


def check_options(
    kind: str, driver: str, options: dict[str, Any], model: type[BaseModel]
) -> dict[str, Any]:
    params = _driver_params(kind, driver)
    checked: dict[str, Any] = {}
    for key, value in options.items():
        if key in model.model_fields:
            raise fail(f"set {key} on the {kind} itself, not under options", key)
        adapter = params.get(key)
        if adapter is None:
            hint = did_you_mean(key, [p for p in params if p not in model.model_fields])
            raise fail(f"unknown option of the {driver} driver{hint}", key)
        try:
            checked[key] = adapter.validate_python(value)
        except ValidationError as e:
            err = e.errors()[0]
            raise fail(describe(err, []), key, *err["loc"]) from None
    return checked
