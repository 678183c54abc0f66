#!/usr/bin/env python3
"""Vendor the JavaScript libraries of `acq view`'s page from npm into the package's data.

Fetches three.js with the machine's npm (``npm pack three@VERSION``), copies the
modules the page imports (three.module.js, GLTFLoader, PLYLoader, OrbitControls) and
every module they import in turn, at their paths in the npm package, into
acq/view/page/vendor/three/, and writes acq/view/page/vendor/VENDORED.json: the
package, its version, the npm tarball's integrity, and each file's path and sha256.
The wheel then serves them with no network. Run from the repository's root with its
venv's Python: ``.venv/bin/python tools/vendor_viewer.py [--version 0.187.0]``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path, PurePosixPath

from acq.view.static import VENDOR, module_imports

PACKAGE = "three"
VERSION = "0.187.0"  # r187
# the modules the page imports, as paths in the npm package
ENTRIES = (
    "build/three.module.js",
    "examples/jsm/loaders/GLTFLoader.js",
    "examples/jsm/loaders/PLYLoader.js",
    "examples/jsm/controls/OrbitControls.js",
)
# the package's bare specifier, as the page's import map names it
BARE = {"three": "build/three.module.js"}


def pack(spec: str, version: str, into: Path, package: str = PACKAGE) -> tuple[Path, str]:
    """The npm tarball of ``spec`` (``three@VERSION``, or a local package folder or
    tarball) unpacked in ``into``; its folder and integrity. SystemExit unless it is
    ``package`` ``version``."""
    done = subprocess.run(
        ["npm", "pack", spec, "--json", "--pack-destination", str(into)],
        check=True, capture_output=True, text=True,
    )  # fmt: skip
    info = json.loads(done.stdout)[0]
    if (info["name"], info["version"]) != (package, version):
        raise SystemExit(f"npm gave {info['name']} {info['version']}, not {package} {version}")
    with tarfile.open(into / info["filename"]) as tar:
        tar.extractall(into, filter="data")
    return into / "package", info["integrity"]


def closure(root: Path) -> list[str]:
    """The entry modules and every module they import, as paths in the package."""
    seen: list[str] = []
    todo = list(ENTRIES)
    while todo:
        path = todo.pop()
        if path in seen:
            continue
        seen.append(path)
        for spec in module_imports((root / path).read_text(encoding="utf-8")):
            if spec in BARE:
                todo.append(BARE[spec])
            elif spec.startswith("."):
                joined = PurePosixPath(path).parent / spec
                parts: list[str] = []
                for part in joined.parts:
                    if part == "..":
                        parts.pop()
                    elif part != ".":
                        parts.append(part)
                todo.append("/".join(parts))
            else:
                raise SystemExit(f"{path}: imports {spec!r}, which the page cannot resolve")
    return sorted(seen)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--version", default=VERSION, help=f"three's npm version ({VERSION})")
    parser.add_argument(
        "--package", metavar="SPEC",
        help="what npm packs (default three@VERSION from the registry; a folder or tarball "
        "of the package packs offline)",
    )  # fmt: skip
    parser.add_argument(
        "--out", type=Path, default=VENDOR, help=f"the folder replaced (default {VENDOR})"
    )
    args = parser.parse_args(argv)
    out: Path = args.out
    with tempfile.TemporaryDirectory() as tmp:
        spec = args.package or f"{PACKAGE}@{args.version}"
        root, integrity = pack(spec, args.version, Path(tmp))
        files = [*closure(root), "LICENSE"]
        shutil.rmtree(out, ignore_errors=True)
        listed = []
        for path in files:
            target = out / PACKAGE / path
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(root / path, target)
            digest = hashlib.sha256(target.read_bytes()).hexdigest()
            listed.append({"path": f"{PACKAGE}/{path}", "sha256": digest})
    write_record(out, PACKAGE, args.version, integrity, spec, listed)
    return 0


def write_record(
    out: Path, package: str, version: str, integrity: str, spec: str, listed: list[dict[str, str]]
) -> None:
    """VENDORED.json in ``out``: the package, its version, the tarball's integrity, where it
    came from and each file's sha256 (``listed``); said on stderr."""
    record = {
        "package": package, "version": version, "integrity": integrity,
        "source": f"npm pack {spec}", "files": listed,
    }  # fmt: skip
    (out / "VENDORED.json").write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
    print(f"vendored {package} {version}: {len(listed)} files in {out}", file=sys.stderr)


if __name__ == "__main__":
    raise SystemExit(main())
