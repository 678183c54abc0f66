"""Fixtures of the page tests: one headless Chromium per test module (tests/browser.py)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from tests.browser import Browser, chromium_or_skip


@pytest.fixture(scope="module")
def browser() -> Iterator[Browser]:
    """A headless Chromium with WebGL in software, 800 x 600, shared by a module's tests
    (each starts with :meth:`Browser.open`); skips when Chromium is absent, fails on CI."""
    with Browser(binary=chromium_or_skip()) as b:
        yield b
