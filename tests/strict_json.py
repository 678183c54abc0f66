"""JSON as RFC 8259 defines it, for the tests of ``--json`` outputs: Python's parser
accepts NaN and Infinity, which JSON does not have."""

from __future__ import annotations

import json
from typing import Any


def strict_json(text: str) -> Any:
    """``text`` parsed as RFC 8259 JSON; ValueError on NaN, Infinity or -Infinity."""

    def refuse(word: str) -> None:
        raise ValueError(f"not JSON: {word}")

    return json.loads(text, parse_constant=refuse)
