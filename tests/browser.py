"""A headless Chromium for the page tests, driven over the Chrome DevTools Protocol (CDP).

Debian's ``chromium`` (``make test`` installs it) runs headless with WebGL rendered in
software: current Chromium no longer falls back to SwiftShader by itself, so ANGLE is told
to use it (``--use-angle=swiftshader --enable-unsafe-swiftshader``). The protocol is spoken
over ``websockets``' sync client on the page target, one request at a time; the events that
arrive between the answers are kept (console messages, exceptions, the page's loads).
Playwright is not used: it downloads its own browser, which cannot be had offline.
"""

from __future__ import annotations

import base64
import itertools
import json
import os
import shutil
import signal
import subprocess
import tempfile
import time
import urllib.parse
import urllib.request
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

import cv2
import numpy as np
import pytest
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect

CHROMIUM = Path("/usr/bin/chromium")
FLAGS = (
    "--headless=new",
    "--no-sandbox",  # the tests may run as root, where Chromium's sandbox refuses to start
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-quic",
    # WebGL in software: without these two a machine with no GPU has no WebGL context
    "--enable-unsafe-swiftshader",
    "--use-angle=swiftshader",
    "--force-color-profile=srgb",  # screenshots hold the page's colours as it gave them
    "--hide-scrollbars",  # screenshots of the page alone
    "--mute-audio",
    "--remote-debugging-port=0",  # a free port, written to DevToolsActivePort
)
# below this (width, height) Chromium 150's window keeps a larger minimum size and every
# other Page.captureScreenshot never answers
MIN_SIZE = (200, 200)
START_TIMEOUT_S = 30.0
CALL_TIMEOUT_S = 30.0


class BrowserError(RuntimeError):
    """Chromium failed to start, died, or the page's script threw."""


class BrowserTimeout(BrowserError):
    """A condition awaited in the page did not hold in time (the message has the console)."""


@dataclass(frozen=True)
class ConsoleMessage:
    """One message the page gave: ``source`` is "console" (console.log/warn/error...),
    "exception" (thrown and not caught) or "log" (the browser's own, e.g. a failed
    request); ``level`` is "error", "warning", "info", "log", "debug" or
    "verbose"."""

    source: str
    level: str
    text: str

    def __str__(self) -> str:
        return f"[{self.source} {self.level}] {self.text}"


def chromium_or_skip(binary: Path = CHROMIUM) -> Path:
    """``binary`` when it exists; otherwise skip the test saying why, or fail it on CI
    (env CI=true), where ``make test`` installs Chromium and its absence is a fault."""
    if os.access(binary, os.X_OK):
        return binary
    reason = f"{binary} is not installed (Debian: apt-get install chromium; make test does)"
    if os.environ.get("CI", "").lower() == "true":
        pytest.fail(f"{reason}, and CI=true: the page tests must run here")
    pytest.skip(reason)


def _remote_text(obj: dict[str, Any]) -> str:
    """A CDP RemoteObject as console.log prints it (its value, else its description)."""
    if "value" in obj:
        value = obj["value"]
        return value if isinstance(value, str) else json.dumps(value)
    return str(obj.get("description", obj.get("type", "")))


class Browser:
    """A headless Chromium showing one page of ``width`` x ``height`` CSS pixels (at one
    device pixel each, at least MIN_SIZE); a context manager that kills it and removes its
    profile."""

    def __init__(self, width: int = 800, height: int = 600, binary: Path = CHROMIUM) -> None:
        if width < MIN_SIZE[0] or height < MIN_SIZE[1]:
            raise ValueError(
                f"a page of {width} x {height}: at least {MIN_SIZE[0]} x {MIN_SIZE[1]}"
            )
        self.width, self.height = width, height
        self._console: list[ConsoleMessage] = []
        self._loads = 0  # Page.loadEventFired seen so far
        self._ids = itertools.count(1)
        self._dir = Path(tempfile.mkdtemp(prefix="acq-chromium-"))
        self._stderr = (self._dir / "stderr.txt").open("wb")
        profile = self._dir / "profile"
        self._process: subprocess.Popen[bytes] | None = None
        self._ws: ClientConnection | None = None
        self._exits = ExitStack()
        try:
            size = f"--window-size={width},{height}"
            self._process = subprocess.Popen(
                [str(binary), *FLAGS, f"--user-data-dir={profile}", size, "about:blank"],
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                stderr=self._stderr,
                start_new_session=True,  # its own process group: close() ends its helpers too
            )
            port = self._devtools_port(self._process, profile / "DevToolsActivePort")
            # entered as a context manager, as websockets wants (17.1 warns otherwise);
            # no keep-alive pings: a local browser busy drawing may answer them late
            self._ws = self._exits.enter_context(
                connect(self._page_target(port), max_size=None, open_timeout=10, ping_interval=None)
            )
            for domain in ("Page", "Runtime", "Log"):
                self._call(f"{domain}.enable")
            self._call(
                "Emulation.setDeviceMetricsOverride",
                width=width,
                height=height,
                deviceScaleFactor=1,
                mobile=False,
            )
        except BaseException:
            self.close()
            raise

    def __enter__(self) -> Browser:
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        trace: TracebackType | None,
    ) -> None:
        self.close()

    @property
    def pid(self) -> int | None:
        """Chromium's process id (the leader of its process group)."""
        return None if self._process is None else self._process.pid

    @property
    def folder(self) -> Path:
        """The temporary folder of its profile and stderr, removed by :meth:`close`."""
        return self._dir

    @property
    def console(self) -> list[ConsoleMessage]:
        """The page's messages and exceptions since the last :meth:`open`, in order."""
        self._drain()
        return list(self._console)

    @property
    def errors(self) -> list[ConsoleMessage]:
        """The messages of level "error" among :attr:`console` (exceptions included)."""
        return [m for m in self.console if m.level == "error"]

    def open(self, url: str, timeout_s: float = CALL_TIMEOUT_S) -> None:
        """Navigates to ``url`` and returns once its load event fired (the page's scripts,
        modules included, have run); forgets the console of the page before."""
        self._drain()
        self._console.clear()
        loads = self._loads
        answer = self._call("Page.navigate", url=url)
        if answer.get("errorText"):
            raise BrowserError(f"{url}: {answer['errorText']}")
        deadline = time.monotonic() + timeout_s
        while self._loads == loads:
            if not self._receive(deadline):
                raise BrowserTimeout(self._with_console(f"{url} did not load in {timeout_s} s"))

    def evaluate(self, js: str) -> Any:
        """The value of the expression ``js`` in the page (promises awaited), as JSON
        gives it (undefined: None); raises BrowserError with the page's exception."""
        answer = self._call(
            "Runtime.evaluate", expression=js, returnByValue=True, awaitPromise=True
        )
        details = answer.get("exceptionDetails")
        if details is not None:
            thrown = details.get("exception", {})
            raise BrowserError(f"{js!r} threw: {_remote_text(thrown) or details.get('text')}")
        return answer["result"].get("value")

    def wait_for(self, js_expr: str, timeout_s: float = 10.0, interval_s: float = 0.05) -> Any:
        """The first truthy value of ``js_expr``, polled every ``interval_s``; raises
        BrowserTimeout after ``timeout_s`` with the console messages so far."""
        deadline = time.monotonic() + timeout_s
        while True:
            value = self.evaluate(js_expr)
            if value:
                return value
            if time.monotonic() >= deadline:
                raise BrowserTimeout(
                    self._with_console(f"{js_expr!r} still {value!r} after {timeout_s} s")
                )
            time.sleep(interval_s)

    def block(self, *patterns: str) -> None:
        """Requests to URLs matching ``patterns`` (``*`` any characters) fail in the
        browser from now on, as on a network that drops them; none given: none blocked."""
        self._call("Network.enable")
        self._call("Network.setBlockedURLs", urls=list(patterns))

    def throttle(self, mbit_s: float | None, latency_ms: float = 2.0) -> None:
        """The page's requests received at ``mbit_s`` megabits a second after
        ``latency_ms`` (a Wi-Fi link's, say), as Chromium's DevTools emulate it; None: at
        full speed again."""
        self._call("Network.enable")
        rate = -1 if mbit_s is None else mbit_s * 1e6 / 8  # bytes/s; -1: no limit
        self._call(
            "Network.emulateNetworkConditions", offline=False, latency=latency_ms,
            downloadThroughput=rate, uploadThroughput=rate,
        )  # fmt: skip

    def click(self, x: float, y: float) -> None:
        """A left click of the mouse at (x, y) CSS pixels from the page's top-left corner
        (fractions kept): moved there, pressed and released, as a user's click."""
        self.drag(x, y, x, y)

    def drag(self, x0: float, y0: float, x1: float, y1: float, steps: int = 5) -> None:
        """The left button pressed at (x0, y0) CSS pixels, the mouse moved in ``steps``
        equal steps to (x1, y1) and released there (none when the two are one place)."""
        left = {"button": "left", "clickCount": 1}
        self._call("Input.dispatchMouseEvent", type="mouseMoved", x=x0, y=y0)
        self._call("Input.dispatchMouseEvent", type="mousePressed", x=x0, y=y0, **left)
        if (x0, y0) != (x1, y1):
            for k in range(1, steps + 1):
                x, y = x0 + (x1 - x0) * k / steps, y0 + (y1 - y0) * k / steps
                self._call("Input.dispatchMouseEvent", type="mouseMoved", x=x, y=y, buttons=1)
        self._call("Input.dispatchMouseEvent", type="mouseReleased", x=x1, y=y1, **left)

    def screenshot(self) -> np.ndarray:
        """What the page shows: an (height, width, 3) uint8 RGB image."""
        answer = self._call("Page.captureScreenshot", format="png")
        png = np.frombuffer(base64.b64decode(answer["data"]), dtype=np.uint8)
        bgr = cv2.imdecode(png, cv2.IMREAD_COLOR)
        if bgr is None:
            raise BrowserError("Page.captureScreenshot gave no decodable PNG")
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)

    def close(self) -> None:
        """Kills Chromium (its whole process group) and removes its profile folder."""
        self._exits.close()
        self._ws = None
        process = self._process
        if process is not None and process.poll() is None:
            try:
                os.killpg(process.pid, signal.SIGTERM)
                process.wait(5)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait()
            except ProcessLookupError:
                pass
        self._stderr.close()
        shutil.rmtree(self._dir, ignore_errors=True)

    # the protocol

    def _devtools_port(self, process: subprocess.Popen[bytes], path: Path) -> int:
        """The port Chromium chose, from the first line of its DevToolsActivePort."""
        deadline = time.monotonic() + START_TIMEOUT_S
        while time.monotonic() < deadline:
            if process.poll() is not None:
                raise BrowserError(self._with_stderr(f"chromium exited ({process.returncode})"))
            try:
                first = path.read_text().split("\n", 1)[0]
                if first.isdigit():
                    return int(first)
            except FileNotFoundError:
                pass
            time.sleep(0.02)
        raise BrowserError(
            self._with_stderr(f"chromium wrote no {path.name} in {START_TIMEOUT_S} s")
        )

    def _page_target(self, port: int) -> str:
        """The WebSocket URL of the page Chromium opened (about:blank)."""
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=10) as answer:
            targets = json.load(answer)
        pages = [t for t in targets if t.get("type") == "page"]
        if not pages:
            raise BrowserError(f"chromium lists no page target: {targets}")
        return str(pages[0]["webSocketDebuggerUrl"])

    def _call(self, method: str, **params: Any) -> dict[str, Any]:
        """Sends one command and returns its result, keeping the events read meanwhile."""
        ident = next(self._ids)
        try:
            self._connection().send(json.dumps({"id": ident, "method": method, "params": params}))
        except ConnectionClosed as e:
            raise BrowserError(
                self._with_stderr(f"{method}: chromium closed the connection")
            ) from e
        deadline = time.monotonic() + CALL_TIMEOUT_S
        while True:
            message = self._receive(deadline)
            if message is None:
                raise BrowserTimeout(
                    self._with_console(f"{method}: no answer in {CALL_TIMEOUT_S} s")
                )
            if message.get("id") == ident:
                if "error" in message:
                    raise BrowserError(f"{method}: {message['error'].get('message')}")
                result: dict[str, Any] = message.get("result", {})
                return result

    def _connection(self) -> ClientConnection:
        if self._ws is None:
            raise BrowserError("the browser is not connected (closed, or failed to start)")
        return self._ws

    def _drain(self) -> None:
        """Reads the events that have arrived, without waiting."""
        while self._receive(time.monotonic()) is not None:
            pass

    def _receive(self, deadline: float) -> dict[str, Any] | None:
        """The next message, its event (if it is one) recorded; None at ``deadline``."""
        try:
            raw = self._connection().recv(timeout=max(0.0, deadline - time.monotonic()))
        except TimeoutError:
            return None
        except ConnectionClosed as e:
            raise BrowserError(self._with_stderr("chromium closed the connection")) from e
        message: dict[str, Any] = json.loads(raw)
        self._record(message.get("method"), message.get("params", {}))
        return message

    def _record(self, method: str | None, params: dict[str, Any]) -> None:
        if method == "Page.loadEventFired":
            self._loads += 1
        elif method == "Runtime.consoleAPICalled":
            kind = params["type"]  # log, info, warning, error, assert, table, trace...
            level = "error" if kind == "assert" else kind
            if level not in ("error", "warning", "info", "debug"):
                level = "log"
            text = " ".join(_remote_text(a) for a in params.get("args", []))
            self._console.append(ConsoleMessage("console", level, text))
        elif method == "Runtime.exceptionThrown":
            details = params["exceptionDetails"]
            text = _remote_text(details["exception"]) if "exception" in details else ""
            self._console.append(ConsoleMessage("exception", "error", text or details["text"]))
        elif method == "Log.entryAdded":
            entry = params["entry"]
            if urllib.parse.urlsplit(entry.get("url", "")).path == "/favicon.ico":
                return  # the browser's own request, at a moment of its choosing: not the page's
            where = f" ({entry['url']})" if entry.get("url") else ""
            self._console.append(ConsoleMessage("log", entry["level"], entry["text"] + where))

    def _with_console(self, what: str) -> str:
        lines = [str(m) for m in self._console] or ["(no console message)"]
        return "\n  ".join([f"{what}; the page's console:", *lines])

    def _with_stderr(self, what: str) -> str:
        self._stderr.flush()
        tail = (self._dir / "stderr.txt").read_text(errors="replace")[-2000:]
        return f"{what}; its stderr ends:\n{tail}"
