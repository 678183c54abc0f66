"""The headless-browser harness (tests/browser.py) on pages of its own, served over HTTP on
127.0.0.1: WebGL drawn by SwiftShader and seen in a screenshot, the console's errors,
exceptions and failed requests, waiting for a flag and timing out with the console, a
throttled and a blocked request."""

from __future__ import annotations

import functools
import os
import signal
import socket
import threading
import time
from collections.abc import Iterator
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.browser import MIN_SIZE, Browser, BrowserError, BrowserTimeout, chromium_or_skip

BACKGROUND = (32, 160, 96)  # the canvas's clear colour, RGB
QUAD = (200, 40, 120)  # the shader's colour, on the canvas's right half

# a canvas over the whole page cleared to BACKGROUND, then a quad over its right half drawn
# by a vertex and a fragment shader (the pipeline three.js uses, not a clear alone)
WEBGL_PAGE = f"""<!doctype html>
<html><head><style>html, body {{ margin: 0; overflow: hidden; }}
canvas {{ display: block; width: 100vw; height: 100vh; }}</style></head>
<body><canvas id="c"></canvas><script>
const canvas = document.getElementById("c");
canvas.width = innerWidth; canvas.height = innerHeight;
const gl = canvas.getContext("webgl");
const info = gl.getExtension("WEBGL_debug_renderer_info");
window.renderer = gl.getParameter(info.UNMASKED_RENDERER_WEBGL);
gl.clearColor({BACKGROUND[0]} / 255, {BACKGROUND[1]} / 255, {BACKGROUND[2]} / 255, 1);
gl.clear(gl.COLOR_BUFFER_BIT);
function shader(kind, source) {{
  const s = gl.createShader(kind); gl.shaderSource(s, source); gl.compileShader(s); return s;
}}
const program = gl.createProgram();
gl.attachShader(program, shader(gl.VERTEX_SHADER,
  "attribute vec2 p; void main() {{ gl_Position = vec4(p, 0.0, 1.0); }}"));
gl.attachShader(program, shader(gl.FRAGMENT_SHADER,
  "void main() {{ gl_FragColor = vec4({QUAD[0]}.0, {QUAD[1]}.0, {QUAD[2]}.0, 255.0) / 255.0; }}"));
gl.linkProgram(program); gl.useProgram(program);
gl.bindBuffer(gl.ARRAY_BUFFER, gl.createBuffer());
gl.bufferData(gl.ARRAY_BUFFER, new Float32Array([0, -1, 1, -1, 0, 1, 1, 1]), gl.STATIC_DRAW);
gl.enableVertexAttribArray(0); gl.vertexAttribPointer(0, 2, gl.FLOAT, false, 0, 0);
gl.drawArrays(gl.TRIANGLE_STRIP, 0, 4);
requestAnimationFrame(() => {{ window.drawn = true; }});
</script></body></html>
"""

# what goes wrong on a page: console.error, a classic script and an ES module that throw,
# a script that is not there (the server's 404)
CONSOLE_PAGE = """<!doctype html>
<html><body>
<script>console.error("x"); console.warn("careful", 7);</script>
<script>throw new Error("boom in a script");</script>
<script type="module">throw new TypeError("boom in a module");</script>
<script src="/missing.js"></script>
</body></html>
"""

LATE_PAGE = """<!doctype html>
<html><body><script>
console.log("waiting for the flag");
setTimeout(() => { window.flag = 42; }, 300);
</script></body></html>
"""

# every click's kind, place and button, as the page's events saw them
CLICK_PAGE = """<!doctype html>
<html><body style="margin: 0; height: 100vh"><script>
window.clicks = [];
for (const kind of ["pointerdown", "pointermove", "pointerup", "click"]) {
  addEventListener(kind, (e) => clicks.push([e.type, e.clientX, e.clientY, e.button]));
}
</script></body></html>
"""

QUIET_PAGE = "<!doctype html><html><body><p>nothing to say</p></body></html>\n"

# ES modules through an import map, as the viewer's page loads three.js: a module that is
# there, then one the map points at but the server does not have
MODULE_PAGE = """<!doctype html>
<html><head><script type="importmap">
{"imports": {"lib": "/static/lib.js", "gone": "/static/gone.js"}}
</script></head><body><script type="module">
import { answer } from "lib";
window.answer = answer;
</script><script type="module">
import "gone";
window.unreachable = true;
</script></body></html>
"""
LIB_MODULE = "export const answer = 42;\n"


class _QuietHandler(SimpleHTTPRequestHandler):
    def log_message(self, format: str, *args: Any) -> None:
        pass  # the test's output is pytest's


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """The pages above served from a folder by Python's HTTP server; its base URL."""
    root = tmp_path_factory.mktemp("pages")
    pages = {"webgl": WEBGL_PAGE, "console": CONSOLE_PAGE, "late": LATE_PAGE, "click": CLICK_PAGE}
    for name, text in {**pages, "quiet": QUIET_PAGE, "modules": MODULE_PAGE}.items():
        (root / f"{name}.html").write_text(text)
    (root / "static").mkdir()
    (root / "static" / "lib.js").write_text(LIB_MODULE)
    (root / "mb.bin").write_bytes(bytes(1_000_000))
    handler = functools.partial(_QuietHandler, directory=str(root))
    server = ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}/"
    finally:
        server.shutdown()
        server.server_close()
        thread.join()


def test_a_webgl_canvas_is_drawn_by_swiftshader_and_the_screenshot_shows_its_colours(
    browser: Browser, site: str
) -> None:
    browser.open(site + "webgl.html")
    browser.wait_for("window.drawn === true")
    assert "SwiftShader" in browser.evaluate("window.renderer")
    image = browser.screenshot()
    assert image.shape == (600, 800, 3) and image.dtype == np.uint8
    left, right = image[:, :390].reshape(-1, 3), image[:, 410:].reshape(-1, 3)
    # every pixel of each half within one level of its colour (8-bit values round-trip)
    assert np.abs(left.astype(int) - BACKGROUND).max() <= 1
    assert np.abs(right.astype(int) - QUAD).max() <= 1
    # not even a warning: without its flags Chromium warns that the fallback to software
    # WebGL is deprecated, or that ReadPixels stalls the GPU
    assert browser.console == []


def test_console_errors_exceptions_and_failed_requests_are_seen(
    browser: Browser, site: str
) -> None:
    browser.open(site + "console.html")
    seen = {(m.source, m.level, m.text) for m in browser.console}
    assert ("console", "error", "x") in seen
    assert ("console", "warning", "careful 7") in seen
    exceptions = [m.text for m in browser.console if m.source == "exception"]
    assert any(t.startswith("Error: boom in a script") for t in exceptions), exceptions
    assert any(t.startswith("TypeError: boom in a module") for t in exceptions), exceptions
    failed = [m for m in browser.errors if m.source == "log"]
    assert len(failed) == 1 and "404" in failed[0].text and "/missing.js" in failed[0].text
    assert len(browser.errors) == 4  # console.error, two exceptions, the 404


def test_es_modules_load_through_an_import_map_and_a_missing_one_is_an_error(
    browser: Browser, site: str
) -> None:
    browser.open(site + "modules.html")
    assert browser.wait_for("window.answer") == 42
    assert browser.evaluate("window.unreachable") is None
    errors = browser.errors
    assert len(errors) == 1 and "404" in errors[0].text and "/static/gone.js" in errors[0].text


def test_click_gives_the_page_a_left_click_where_it_is_told(browser: Browser, site: str) -> None:
    browser.open(site + "click.html")
    browser.click(123.25, 456.5)
    browser.click(7, 8)
    clicks = browser.wait_for("clicks.length === 8 && clicks.filter((c) => c[0] !== 'pointermove')")
    # a pointer event's place keeps its fractions (a click event's are cut off); the
    # primary button is 0
    assert clicks[:3] == [
        ["pointerdown", 123.25, 456.5, 0],
        ["pointerup", 123.25, 456.5, 0],
        ["click", 123, 456, 0],
    ]
    assert [c[0] for c in clicks[3:]] == ["pointerdown", "pointerup", "click"]
    assert all(c[1:] == [7, 8, 0] for c in clicks[3:])
    assert browser.errors == []


def test_drag_presses_moves_and_releases_where_it_is_told(browser: Browser, site: str) -> None:
    browser.open(site + "click.html")
    browser.drag(100, 100, 200, 150, steps=4)
    events = browser.wait_for("clicks.some((c) => c[0] === 'pointerup') && clicks")
    kinds = [e[0] for e in events]
    assert kinds[0] == "pointermove" and kinds[1] == "pointerdown"  # moved there first
    assert events[1][1:] == [100, 100, 0]
    moves = [e[1:3] for e in events[2:] if e[0] == "pointermove"]
    assert moves == [[125, 112.5], [150, 125], [175, 137.5], [200, 150]]
    assert events[-1][0] in ("pointerup", "click") and ["pointerup", 200, 150, 0] in events
    assert browser.errors == []


def test_open_forgets_the_console_of_the_page_before(browser: Browser, site: str) -> None:
    browser.open(site + "console.html")
    assert browser.errors
    browser.open(site + "quiet.html")
    assert browser.console == []
    assert browser.evaluate("document.querySelector('p').textContent") == "nothing to say"


# the seconds a fetch of a URL takes, or its error's message
FETCH = """(async () => {
  const t0 = performance.now();
  try { await (await fetch(%r, { cache: 'no-store' })).arrayBuffer(); }
  catch (error) { return error.message; }
  return (performance.now() - t0) / 1000;
})()"""


def test_throttle_slows_the_page_s_requests_and_block_fails_them(
    browser: Browser, site: str
) -> None:
    browser.open(site + "quiet.html")
    url = site + "mb.bin"
    browser.throttle(4.0)  # 1 MB at 4 Mbit/s: 2 s
    try:
        slow = browser.evaluate(FETCH % url)
    finally:
        browser.throttle(None)
    fast = browser.evaluate(FETCH % url)
    assert slow >= 1.8 and fast < slow / 2, (slow, fast)
    browser.block("*/mb.bin")
    try:
        assert browser.evaluate(FETCH % url) == "Failed to fetch"
    finally:
        browser.block()
    assert not isinstance(browser.evaluate(FETCH % url), str)  # seconds, not an error


def test_wait_for_returns_a_flag_set_after_a_timeout(browser: Browser, site: str) -> None:
    browser.open(site + "late.html")
    assert browser.evaluate("window.flag") is None  # not yet: set 300 ms after the load
    start = time.monotonic()
    assert browser.wait_for("window.flag", timeout_s=10) == 42
    assert time.monotonic() - start < 5


def test_wait_for_times_out_naming_the_expression_and_the_console(
    browser: Browser, site: str
) -> None:
    browser.open(site + "late.html")
    start = time.monotonic()
    with pytest.raises(BrowserTimeout) as raised:
        browser.wait_for("window.never === true", timeout_s=0.5)
    assert 0.5 <= time.monotonic() - start < 3
    message = str(raised.value)
    assert "'window.never === true' still False after 0.5 s" in message
    assert "[console log] waiting for the flag" in message


def test_evaluate_gives_json_values_and_raises_the_page_s_exception(
    browser: Browser, site: str
) -> None:
    browser.open(site + "quiet.html")
    assert browser.evaluate("({a: [1, 2.5, 'b'], n: null})") == {"a": [1, 2.5, "b"], "n": None}
    assert browser.evaluate("undefined") is None
    assert browser.evaluate("new Promise(r => setTimeout(() => r(3), 50))") == 3
    with pytest.raises(BrowserError, match="TypeError: Cannot read properties of null"):
        browser.evaluate("null.x")


def test_opening_an_address_nobody_serves_raises(browser: Browser) -> None:
    with socket.socket() as s:  # a port just free: nothing listens there
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(BrowserError, match=f"127.0.0.1:{port}/: net::ERR_CONNECTION_REFUSED"):
        browser.open(f"http://127.0.0.1:{port}/")


def _processes_naming(text: str) -> list[int]:
    """The processes whose command line holds ``text``."""
    found = []
    for entry in Path("/proc").iterdir():
        try:
            if entry.name.isdigit() and text in (entry / "cmdline").read_text():
                found.append(int(entry.name))
        except OSError:
            pass  # ended meanwhile, or not ours to read
    return found


def test_close_ends_chromium_and_its_helpers_and_removes_its_profile() -> None:
    with Browser(320, 200, binary=chromium_or_skip()) as b:
        folder = b.folder
        assert b.screenshot().shape == (200, 320, 3)
        assert len(_processes_naming(str(folder))) >= 2  # the browser and its helpers
    assert not folder.exists()
    assert _processes_naming(str(folder)) == []


def test_a_chromium_that_died_is_reported_with_its_stderr() -> None:
    with Browser(320, 200, binary=chromium_or_skip()) as b:
        assert b.pid is not None
        os.killpg(b.pid, signal.SIGKILL)  # the browser we started, and its helpers
        with pytest.raises(BrowserError, match="chromium closed the connection; its stderr"):
            for _ in range(100):  # the connection's end is seen within a few calls
                b.evaluate("1")
                time.sleep(0.01)
    assert not b.folder.exists()


def test_an_absent_chromium_skips_saying_why_but_fails_on_ci(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    absent = tmp_path / "chromium"
    monkeypatch.delenv("CI", raising=False)
    with pytest.raises(pytest.skip.Exception, match=f"{absent} is not installed"):
        chromium_or_skip(absent)
    monkeypatch.setenv("CI", "true")
    with pytest.raises(pytest.fail.Exception, match="CI=true"):
        chromium_or_skip(absent)
    assert os.access(chromium_or_skip(Path("/bin/sh")), os.X_OK)  # one that is there


def test_the_browser_s_own_favicon_request_is_no_error_of_the_page(
    browser: Browser, site: str
) -> None:
    browser.open(site + "quiet.html")
    # fetched one after the other, both missing: their console lines come in this order
    fetches = (
        "(async () => [(await fetch('/favicon.ico')).status, (await fetch('/other.ico')).status])()"
    )
    assert browser.evaluate(fetches) == [404, 404]
    deadline = time.monotonic() + 10
    while not any("/other.ico" in m.text for m in browser.errors):
        assert time.monotonic() < deadline, browser.console
        time.sleep(0.02)
    assert [m for m in browser.console if "favicon" in m.text] == []


def test_a_page_smaller_than_chromium_can_screenshot_is_refused() -> None:
    # refused before anything starts: no Chromium is needed to see it
    with pytest.raises(ValueError, match=r"a page of 320 x 120: at least 200 x 200"):
        Browser(MIN_SIZE[0] + 120, 120)
