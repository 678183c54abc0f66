#!/usr/bin/env python3
"""Vendor Mermaid from npm into the documentation site, so that its diagrams draw offline
(Material loads Mermaid from a CDN unless the page already has it).

Fetches mermaid with the machine's npm (``npm pack mermaid@VERSION``), copies its
``dist/mermaid.min.js`` and ``LICENSE`` into docs/javascripts/mermaid/, and writes
VENDORED.json there: the package, its version, the npm tarball's integrity, and each
file's sha256 (tests/docs/test_reference.py checks them). Run from the repository's root
with its venv's Python: ``.venv/bin/python tools/vendor_mermaid.py [--version 11.17.2]``.
"""

from __future__ import annotations

import argparse
import hashlib
import shutil
import tempfile
from pathlib import Path

from vendor_viewer import pack, write_record

PACKAGE = "mermaid"
VERSION = "11.17.2"  # the major version Material for MkDocs loads
FILES = ("dist/mermaid.min.js", "LICENSE")
OUT = Path("docs/javascripts/mermaid")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--version", default=VERSION, help=f"mermaid's npm version ({VERSION})")
    parser.add_argument("--out", type=Path, default=OUT, help=f"the folder replaced ({OUT})")
    args = parser.parse_args(argv)
    out: Path = args.out
    with tempfile.TemporaryDirectory() as tmp:
        spec = f"{PACKAGE}@{args.version}"
        root, integrity = pack(spec, args.version, Path(tmp), PACKAGE)
        shutil.rmtree(out, ignore_errors=True)
        out.mkdir(parents=True)
        listed = []
        for path in FILES:
            target = out / Path(path).name
            shutil.copyfile(root / path, target)
            listed.append(
                {"path": target.name, "sha256": hashlib.sha256(target.read_bytes()).hexdigest()}
            )
    write_record(out, PACKAGE, args.version, integrity, spec, listed)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
