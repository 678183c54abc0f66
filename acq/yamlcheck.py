"""YAML files validated with pydantic, every problem told in one line.

What the configuration (:mod:`acq.record.config`) and calib.yaml
(:mod:`acq.camera.calibfile`) share: :func:`read` (a file's YAML tree, a key given twice
refused), :data:`STRICT` (unknown keys are errors, numbers finite, no coercion),
:func:`fail` (a check's error, optionally below the value checked) and :func:`message`
(a :class:`pydantic.ValidationError` as ``FILE: KEY.PATH: what was expected``, with a
did-you-mean for an unknown key). Each caller raises its own error class with the text.
"""

from __future__ import annotations

import difflib
import math
import types
import typing
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ConfigDict, ValidationError
from pydantic_core import ErrorDetails, PydanticCustomError

__all__ = [
    "STRICT",
    "describe",
    "did_you_mean",
    "fail",
    "line",
    "message",
    "read",
    "show",
]


STRICT = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)
"""The ``model_config`` of a file's sections: unknown keys are errors, numbers finite, no
type coercion."""


def fail(msg: str, *subpath: str | int) -> PydanticCustomError:
    """A validation error ``msg`` at ``subpath`` below the value being validated."""
    return PydanticCustomError("acq", "{msg}", {"msg": msg, "subpath": subpath})


def did_you_mean(key: object, candidates: list[str]) -> str:
    """``"; did you mean KEY?"`` for the closest of ``candidates``, else ``""``."""
    close = difflib.get_close_matches(str(key), candidates, n=1)
    return f"; did you mean {close[0]}?" if close else ""


def show(value: Any) -> str:
    """A value as a message quotes it: short, containers by their kind."""
    if isinstance(value, Mapping):
        return "a mapping"
    if isinstance(value, list | tuple | set):
        return "a list"
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def line(source: str, path: str, msg: str) -> str:
    """``SOURCE: PATH: MSG`` on one line (a newline in a key or value is escaped)."""
    text = f"{source}: {path}: {msg}" if path else f"{source}: {msg}"
    return text.replace("\r", "\\r").replace("\n", "\\n")


def _unwrap(tp: Any) -> Any:
    """``X | None`` -> ``X``."""
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1:
            return _unwrap(args[0])
    return tp


def _key_path(loc: tuple[str | int, ...], root: type[BaseModel]) -> tuple[str, list[str]]:
    """``scanners[0].latency_s`` for a pydantic location below ``root``, and the keys
    allowed beside its last element (for did-you-mean)."""
    text = ""
    tp: Any = root
    keys: list[str] = []
    for elem in loc:
        tp = _unwrap(tp)
        is_model = isinstance(tp, type) and issubclass(tp, BaseModel)
        origin = typing.get_origin(tp)
        args = typing.get_args(tp)
        if elem == "[key]":
            continue
        if isinstance(elem, int) and not is_model and origin is not dict:
            text += f"[{elem}]"
            tp = args[0] if origin is list and args else Any
            continue
        text += f".{elem}" if text else str(elem)
        if is_model:
            keys = [name for name, f in tp.model_fields.items() if not f.exclude]
            field = tp.model_fields.get(str(elem))
            tp = field.annotation if field is not None else Any
        else:  # a mapping's key: its values' type
            keys, tp = [], args[1] if origin is dict and len(args) == 2 else Any
    return text, keys


_TYPES = {
    "float_type": "expected a number",
    "float_parsing": "expected a number",
    "int_type": "expected a whole number",
    "int_parsing": "expected a whole number",
    "int_from_float": "expected a whole number",
    "bool_type": "expected true or false",
    "bool_parsing": "expected true or false",
    "string_type": "expected a string",
    "list_type": "expected a list",
    "tuple_type": "expected a list",
    "dict_type": "expected a mapping",
    "model_type": "expected a mapping",
    "model_attributes_type": "expected a mapping",
    "path_type": "expected a path",
    "finite_number": "expected a finite number",
    "none_required": "expected nothing (null)",
}
_BOUNDS = {
    "greater_than": ">",
    "greater_than_equal": ">=",
    "less_than": "<",
    "less_than_equal": "<=",
}


def _number_hint(kind: str, value: Any) -> str:
    """For a number YAML read as text (YAML 1.1 wants a dot: ``1e12`` is a string), how
    to write it."""
    if kind not in ("float_type", "int_type") or not isinstance(value, str):
        return ""
    try:
        number = float(value)
    except ValueError:
        return ""
    if not math.isfinite(number) or (kind == "int_type" and not number.is_integer()):
        return ""
    text = str(int(number)) if kind == "int_type" else repr(number)
    if "e" in text and "." not in text:
        text = text.replace("e", ".0e")
    return f" (text to YAML; write {text} for the number)"


def describe(err: ErrorDetails, keys: list[str]) -> str:
    """A pydantic error in plain words; ``keys``: those allowed beside an unknown one."""
    kind = err["type"]
    ctx = err.get("ctx") or {}
    got = f", got {show(err.get('input'))}"
    if kind == "acq":
        return str(ctx["msg"])
    if kind == "extra_forbidden":
        return "unknown key" + did_you_mean(err["loc"][-1], keys)
    if kind == "invalid_key" or "[key]" in err["loc"]:
        return "expected a string key" + got
    if kind == "missing":
        return "required key missing"
    if kind in _TYPES:
        return _TYPES[kind] + got + _number_hint(kind, err.get("input"))
    if kind == "literal_error":
        expected = str(ctx.get("expected", "")).replace("'", "").replace(" or ", ", ")
        return f"expected one of: {expected}{got}"
    if kind in _BOUNDS:
        bound = next(iter(ctx.values()), "?")
        shown = (
            bound if isinstance(bound, int) else f"{bound:g}" if isinstance(bound, float) else bound
        )
        return f"must be {_BOUNDS[kind]} {shown}{got}"
    if kind == "string_too_short":
        return "must not be empty"
    if kind == "value_error" and "error" in ctx:
        return str(ctx["error"])
    msg = err["msg"]
    return msg[:1].lower() + msg[1:] + got


def message(e: ValidationError, source: str, root: type[BaseModel]) -> str:
    """The first problem of ``e`` (validating ``root`` from file ``source``) in one line."""
    errors = e.errors()
    # a misspelt key also makes its right spelling "missing": name the misspelling
    err = next((x for x in errors if x["type"] in ("extra_forbidden", "invalid_key")), errors[0])
    loc = tuple(err["loc"])
    if err["type"] == "acq":
        loc += tuple((err.get("ctx") or {}).get("subpath", ()))
    path, keys = _key_path(loc, root)
    return line(source, path, describe(err, keys))


class _Loader(yaml.SafeLoader):
    """SafeLoader that refuses a key given twice in one mapping (YAML keeps the last)."""


def _construct_mapping(loader: _Loader, node: yaml.MappingNode) -> dict[Any, Any]:
    seen: set[Any] = set()
    for key_node, _ in node.value:
        if not isinstance(key_node, yaml.ScalarNode) or key_node.tag == "tag:yaml.org,2002:merge":
            continue
        key = loader.construct_object(key_node)
        if key in seen:
            raise yaml.constructor.ConstructorError(
                "while reading a mapping",
                node.start_mark,
                f"duplicate key {key}",
                key_node.start_mark,
            )
        seen.add(key)
    return loader.construct_mapping(node)


_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


def read(path: Path, error: Callable[[str], Exception]) -> Any:
    """The YAML tree of file ``path``; a file that cannot be read or is not YAML raises
    ``error(one line)``."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise error(line(str(path), "", "no such file")) from None
    except UnicodeDecodeError as e:
        raise error(line(str(path), "", f"not UTF-8 text (byte {e.start})")) from None
    except OSError as e:
        raise error(line(str(path), "", f"cannot read: {e.strerror or e}")) from None
    try:
        return yaml.load(text, Loader=_Loader)
    except yaml.MarkedYAMLError as e:
        mark = e.problem_mark or e.context_mark
        where = f"{path}:{mark.line + 1}:{mark.column + 1}" if mark else str(path)
        problem = " ".join(str(e.problem or e.context or "syntax error").split())
        raise error(line(where, "", f"invalid YAML: {problem}")) from None
    except yaml.YAMLError as e:
        raise error(line(str(path), "", f"invalid YAML: {' '.join(str(e).split())}")) from None
    except RecursionError:
        raise error(line(str(path), "", "invalid YAML: nested too deeply")) from None
