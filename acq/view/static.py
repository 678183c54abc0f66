"""The page's own files (acq/view/page: HTML, JS, CSS and the vendored libraries under
vendor/): where one named by a URL lies, its content type, and the ES-module imports
and import map the page resolves its libraries by."""

from __future__ import annotations

import json
import re
from pathlib import Path, PurePosixPath
from urllib.parse import urljoin

__all__ = [
    "PAGE",
    "VENDOR",
    "content_type",
    "import_map",
    "module_imports",
    "page_file",
    "resolve_import",
]

PAGE = Path(__file__).resolve().parent / "page"
VENDOR = PAGE / "vendor"

# JS modules must come as JavaScript: a browser refuses a module of any other type
_TYPES = {
    ".html": "text/html; charset=utf-8",
    ".js": "text/javascript; charset=utf-8",
    ".css": "text/css; charset=utf-8",
    ".json": "application/json",
    ".ply": "application/octet-stream",
    ".glb": "model/gltf-binary",
}

# a static import or re-export at the start of a line (`import {A,\n B} from 'x';`,
# `export * from './y.js';`, `import 'z';`): the JSDoc lines that quote an import
# start with ` * ` and are not taken
_IMPORT = re.compile(
    r"""^(?:import|export)\b(?:[^;'"]*?\bfrom)?\s*['"]([^'"]+)['"]""", re.MULTILINE
)
_IMPORT_MAP = re.compile(r'<script type="importmap">(.*?)</script>', re.DOTALL)


def content_type(path: PurePosixPath | Path) -> str:
    """The Content-Type a file is served with, by its suffix."""
    return _TYPES.get(path.suffix.lower(), "application/octet-stream")


def page_file(relative: str) -> Path | None:
    """The file of the page at ``relative`` (a URL path below /static/, already
    unquoted), or None when there is none or it would lie outside the page's folder."""
    parts = PurePosixPath(relative).parts
    if not parts or any(p in ("..", ".") or p.startswith("/") for p in parts):
        return None
    path = PAGE.joinpath(*parts).resolve()
    if not path.is_relative_to(PAGE) or not path.is_file():
        return None
    return path


def module_imports(source: str) -> list[str]:
    """The specifiers of an ES module's static imports and re-exports, in order."""
    return _IMPORT.findall(source)


def import_map(html: str) -> dict[str, str]:
    """The ``imports`` of the page's import map (specifier or prefix -> URL)."""
    found = _IMPORT_MAP.search(html)
    if found is None:
        return {}
    imports: dict[str, str] = json.loads(found.group(1))["imports"]
    return imports


def resolve_import(specifier: str, base_url: str, imports: dict[str, str]) -> str | None:
    """The URL a browser loads for ``specifier`` imported by the module at ``base_url``
    with the import map ``imports``; None for a bare specifier the map does not name."""
    if specifier.startswith(("/", "./", "../")) or "://" in specifier:
        return urljoin(base_url, specifier)
    if specifier in imports:
        return urljoin(base_url, imports[specifier])
    prefixes = [p for p in imports if p.endswith("/") and specifier.startswith(p)]
    if not prefixes:
        return None
    prefix = max(prefixes, key=len)
    return urljoin(base_url, imports[prefix] + specifier[len(prefix) :])
