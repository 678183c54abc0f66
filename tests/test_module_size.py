"""The house limit on a module's size: one concept a module, none of the acq package's
over 600 lines (split by concept, keeping the public names importable where they were)."""

from __future__ import annotations

from pathlib import Path

import acq

LIMIT = 600  # lines


def test_no_module_of_the_acq_package_is_over_the_house_limit() -> None:
    package = Path(acq.__file__).parent
    sizes = {p.relative_to(package.parent): len(p.read_bytes().splitlines())
             for p in package.rglob("*.py")}  # fmt: skip
    assert len(sizes) > 100  # the whole package, not a folder of it
    over = sorted(f"{p} ({n} lines)" for p, n in sizes.items() if n > LIMIT)
    assert over == [], f"over {LIMIT} lines, split by concept: {', '.join(over)}"
