"""The shell blocks the documentation marks runnable (a fence opened with
```` ```{.sh .runnable} ````), read from its Markdown, and their lines run as `acq` would
run them: in this process through :func:`acq.cli.main` (one interpreter, its imports and
compiled kernels shared), in a given folder."""

from __future__ import annotations

import contextlib
import io
import os
import re
import shlex
from collections.abc import Iterator
from pathlib import Path

from acq.cli import main

DOCS = Path(__file__).resolve().parents[2] / "docs"
FENCE = re.compile(r"^```\{\.sh \.runnable\}\n(.*?)^```$", re.M | re.S)


def blocks(page: Path) -> list[list[list[str]]]:
    """Each runnable block of ``page``: its commands, each as its words (comments and
    blank lines dropped)."""
    found = []
    for body in FENCE.findall(page.read_text()):
        commands = [shlex.split(line, comments=True) for line in body.splitlines()]
        found.append([c for c in commands if c])
    return found


def pages_with_blocks() -> Iterator[Path]:
    """The quick start and the how-to guides that have runnable blocks."""
    for page in [DOCS / "quickstart.md", *sorted((DOCS / "how-to").glob("*.md"))]:
        if blocks(page):
            yield page


def run(argv: list[str], folder: Path) -> tuple[int, str]:
    """``argv`` (``acq ...``) run in ``folder``; its exit status and what it printed."""
    assert argv[0] == "acq", f"a runnable block runs acq commands only, not {argv[0]!r}"
    printed = io.StringIO()
    cwd = os.getcwd()
    os.chdir(folder)
    try:
        with contextlib.redirect_stdout(printed), contextlib.redirect_stderr(printed):
            code = main(argv[1:])
    finally:
        os.chdir(cwd)
    return code, printed.getvalue()
