"""tools/vendor_viewer.py, run offline on a local copy of the package: it vendors the
page's modules and every module they import, records their hashes, and refuses an
import the page could not resolve."""

from __future__ import annotations

import importlib.util
import json
import shutil
from pathlib import Path
from types import ModuleType

import pytest

from acq.view.static import VENDOR

SCRIPT = Path(__file__).resolve().parents[2] / "tools" / "vendor_viewer.py"

pytestmark = pytest.mark.skipif(
    shutil.which("npm") is None, reason="npm not installed: tools/vendor_viewer.py runs it"
)


def _script() -> ModuleType:
    spec = importlib.util.spec_from_file_location("vendor_viewer", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _package(tmp_path: Path) -> Path:
    """three's files as vendored, as an npm package folder, with a module nobody imports."""
    package = tmp_path / "three"
    shutil.copytree(VENDOR / "three", package)
    (package / "package.json").write_text(json.dumps({"name": "three", "version": "0.187.0"}))
    (package / "examples/jsm/Unused.js").write_text("import { Color } from 'three';\n")
    return package


def test_vendors_the_imported_modules_with_their_hashes(tmp_path: Path) -> None:
    out = tmp_path / "vendor"
    assert _script().main(["--package", str(_package(tmp_path)), "--out", str(out)]) == 0
    record = json.loads((out / "VENDORED.json").read_text())
    committed = json.loads((VENDOR / "VENDORED.json").read_text())
    assert record["files"] == committed["files"]
    assert (record["package"], record["version"]) == ("three", "0.187.0")
    assert record["integrity"].startswith("sha512-")
    assert not (out / "three/examples/jsm/Unused.js").exists()


def test_an_import_the_page_cannot_resolve_is_refused(tmp_path: Path) -> None:
    package = _package(tmp_path)
    loader = package / "examples/jsm/loaders/PLYLoader.js"
    loader.write_text("import { x } from 'left-pad';\n" + loader.read_text())
    out = tmp_path / "vendor"
    with pytest.raises(SystemExit, match=r"PLYLoader\.js: imports 'left-pad'"):
        _script().main(["--package", str(package), "--out", str(out)])
    assert not out.exists()
