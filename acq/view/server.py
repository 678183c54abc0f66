"""The HTTP server of `acq view`: the page (``/``), its files and vendored libraries
(``/static/...``), the list of layers (``/api/layers``) and each layer's bytes
(``/data/<k>/<name>``), a subsampled cloud's chunks (``/data/<k>/lod.json``,
``/data/<k>/chunk/<c>.bin``: :mod:`acq.view.lod`), on a thread of its own; nothing else
is reachable."""

from __future__ import annotations

import errno
import json
import shutil
import socket
import sys
import threading
from collections.abc import Sequence
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from types import TracebackType
from typing import Any, Literal
from urllib.parse import quote, unquote, urlsplit

from acq.addresses import is_loopback
from acq.errors import InputError
from acq.view import las_points, lod, static
from acq.view.layers import Layer, layers_of

__all__ = ["DEFAULT_MAX_POINTS", "LOD_NAME", "POINTS_NAME", "AddressError", "ViewServer"]

_CHUNK = 1 << 20  # bytes copied to the socket at a time
# a laptop's browser draws about a million points well and slows around 5-10 M
DEFAULT_MAX_POINTS = 2_000_000
POINTS_NAME = "points.bin"  # a LAS/LAZ layer's URL name: its points packed for the page
LOD_NAME = "lod.json"  # a subsampled LAS/LAZ layer's chunks, each at chunk/<c>.bin


class AddressError(InputError):
    """The server cannot listen where it was asked: ``about`` "host" (no address of this
    machine) or "port" (in use, or privileged); ``reason`` says why."""

    def __init__(self, about: Literal["host", "port"], value: object, reason: str) -> None:
        super().__init__(f"{about} {value}: {reason}")
        self.about, self.value, self.reason = about, value, reason


class ViewServer:
    """Serves the layers of ``paths`` (checked on construction: InputError naming a bad
    one) on ``host``:``port`` (0: a free port) while the context is open; ``url`` is
    ``http://HOST:PORT/``. A LAS/LAZ/COPC cloud is decoded here, once, into the page's
    binary (:mod:`acq.view.las_points`), at most ``max_points`` of its points; one over
    that is also cut into chunks (:mod:`acq.view.lod`, runs of ``run_points`` rows unless
    it is COPC) decoded when the page asks for one."""

    def __init__(
        self, paths: Sequence[Path], host: str = "127.0.0.1", port: int = 0,
        max_points: int = DEFAULT_MAX_POINTS, run_points: int = lod.RUN_POINTS,
    ) -> None:  # fmt: skip
        self.layers = layers_of(paths)
        self.points = {
            k: las_points.payload(layer.path, max_points)
            for k, layer in enumerate(self.layers)
            if layer.path.suffix.lower() in las_points.SUFFIXES
        }
        self.chunks = {
            k: lod.chunks(self.layers[k].path, self.layers[k].count, data, run_points)
            for k, data in self.points.items()
            if las_points.shown(data) < self.layers[k].count
        }
        self.host, self.port = host, port
        self._httpd: _Server | None = None
        self._thread: threading.Thread | None = None

    @property
    def url(self) -> str:
        if self._httpd is None:
            raise RuntimeError("the server is not started")
        host = self.host if ":" not in self.host else f"[{self.host}]"
        return f"http://{host}:{self._httpd.server_address[1]}/"

    def listing(self) -> list[dict[str, Any]]:
        """What ``/api/layers`` answers: each layer's name, kind, URL, bytes and count, and
        ``shown``, the points or vertices the page gets (fewer than ``count`` for a cloud
        subsampled to ``max_points``, which has ``lod`` too: its chunks' URL)."""
        return [
            {
                "name": layer.name,
                "kind": layer.kind,
                "url": self._data_url(k, layer),
                "bytes": layer.size,
                "count": layer.count,
                "shown": las_points.shown(self.points[k]) if k in self.points else layer.count,
            }
            | ({"lod": f"/data/{k}/{LOD_NAME}"} if k in self.chunks else {})
            for k, layer in enumerate(self.layers)
        ]

    def chunk(self, k: int, c: int) -> bytearray:
        """The page's binary of chunk ``c`` of layer ``k``: its rows, at most
        :data:`acq.view.lod.CHUNK_CAP` of them (evenly spread beyond)."""
        found = self.chunks[k][c]
        return las_points.payload(self.layers[k].path, lod.CHUNK_CAP, found.start, found.stop)

    def _data_url(self, k: int, layer: Layer) -> str:
        return f"/data/{k}/{POINTS_NAME if k in self.points else quote(layer.name)}"

    def __enter__(self) -> ViewServer:
        self.start()
        return self

    def __exit__(
        self, kind: type[BaseException] | None, value: BaseException | None,
        tb: TracebackType | None,
    ) -> None:  # fmt: skip
        self.stop()

    def start(self) -> None:
        """Listen and serve on a thread; AddressError when it cannot listen there."""
        try:
            family = socket.getaddrinfo(self.host, self.port, type=socket.SOCK_STREAM)[0][0]
        except (socket.gaierror, UnicodeError) as e:
            raise AddressError("host", self.host, f"not a host name or address ({e})") from None
        server_class = type("_Server", (_Server,), {"address_family": family})
        try:
            self._httpd = server_class((self.host, self.port), _Handler)
        except OSError as e:
            if e.errno == errno.EADDRNOTAVAIL:
                raise AddressError("host", self.host, "not an address of this machine") from None
            why = {
                errno.EADDRINUSE: f"in use on {self.host} (another server listens there)",
                errno.EACCES: "not permitted (a port under 1024 needs privileges)",
            }.get(e.errno or 0, e.strerror or str(e))
            raise AddressError("port", self.port, why) from None
        self._httpd.view = self
        self._thread = threading.Thread(
            target=self._httpd.serve_forever, name="acq-view", daemon=True
        )
        self._thread.start()

    def stop(self) -> None:
        """Stop listening and close the socket (a transfer under way is cut)."""
        if self._httpd is not None:
            self._httpd.shutdown()
            self._httpd.server_close()
        if self._thread is not None:
            self._thread.join()
        self._httpd = self._thread = None


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    view: ViewServer

    def handle_error(self, request: Any, client_address: Any) -> None:
        # a browser that closes its connection mid-answer is no error of ours
        if not isinstance(sys.exc_info()[1], ConnectionError):
            super().handle_error(request, client_address)


class _Handler(BaseHTTPRequestHandler):
    server: _Server
    protocol_version = "HTTP/1.1"

    def log_message(self, format: str, *args: Any) -> None:
        pass  # the page's requests are not the user's business

    def do_HEAD(self) -> None:
        self._answer(body=False)

    def do_GET(self) -> None:
        self._answer(body=True)

    def _answer(self, body: bool) -> None:
        path = unquote(urlsplit(self.path).path)
        view = self.server.view
        if not _host_allowed(view.host, self.headers.get("Host")):
            self.send_error(HTTPStatus.FORBIDDEN, "a loopback server answers loopback names only")
        elif path in ("/", "/index.html"):
            self._file(static.PAGE / "index.html", body)
        elif path.startswith("/static/"):
            found = static.page_file(path.removeprefix("/static/"))
            self._file(found, body)
        elif path == "/api/layers":
            data = json.dumps(view.listing()).encode()
            self._send(data, "application/json", body)
        elif path.startswith("/data/"):
            self._data(view, path, body)
        else:
            self._not_found()

    def _data(self, view: ViewServer, path: str, body: bool) -> None:
        found = _data_route(view, path)
        if found is None:
            self._not_found()
            return
        k, c = found
        if c == "lod":
            data = json.dumps(lod.index(view.chunks[k])).encode()
            self._send(data, "application/json", body, "no-cache")
        elif isinstance(c, int):
            try:
                chunk = view.chunk(k, c)
            except InputError as e:  # the file changed since the server started
                self.send_error(HTTPStatus.INTERNAL_SERVER_ERROR, "a chunk unread", str(e))
                return
            self._send(chunk, "application/octet-stream", body, "no-cache")
        elif k in view.points:
            self._send(view.points[k], "application/octet-stream", body, "no-cache")
        else:
            self._file(view.layers[k].path, body)

    def _file(self, path: Path | None, body: bool) -> None:
        if path is None:
            self._not_found()
            return
        try:
            f = open(path, "rb")  # closed by the with below
        except OSError:  # a layer removed since the server started
            self._not_found()
            return
        with f:
            size = f.seek(0, 2)
            f.seek(0)
            self.send_response(HTTPStatus.OK)
            self.send_header("Content-Type", static.content_type(path))
            self.send_header("Content-Length", str(size))
            self.send_header("Cache-Control", "no-cache")
            self.end_headers()
            if body:
                shutil.copyfileobj(f, self.wfile, _CHUNK)

    def _send(
        self, data: bytes | bytearray, kind: str, body: bool, cache: str = "no-store"
    ) -> None:
        self.send_response(HTTPStatus.OK)
        self.send_header("Content-Type", kind)
        self.send_header("Content-Length", str(len(data)))
        self.send_header("Cache-Control", cache)
        self.end_headers()
        if body:
            view = memoryview(data)
            for start in range(0, len(data), _CHUNK):
                self.wfile.write(view[start : start + _CHUNK])

    def _not_found(self) -> None:
        self.send_error(HTTPStatus.NOT_FOUND, "not a file acq view serves")


def _host_allowed(served: str, header: str | None) -> bool:
    """Whether a request naming ``header`` as its Host may be answered by a server on
    ``served``: on loopback, only a loopback name (a web page whose own name was made to
    point at 127.0.0.1, DNS rebinding, reads nothing); any on another address."""
    if header is None or not is_loopback(served):
        return True
    try:
        name = urlsplit(f"//{header}").hostname
    except ValueError:
        return False
    return name is not None and is_loopback(name)


def _data_route(view: ViewServer, path: str) -> tuple[int, int | str | None] | None:
    """What ``path`` names below /data/: (k, None) for layer k's own URL (its file's
    name, or :data:`POINTS_NAME` for a LAS/LAZ cloud), (k, "lod") for its chunks' index,
    (k, c) for its chunk c (``chunk/<c>.bin``); None for anything else."""
    parts = path.split("/")
    k = _number(parts[2]) if len(parts) in (4, 5) else None
    if k is None or k >= len(view.layers):
        return None
    if len(parts) == 5:
        c = _number(parts[4].removesuffix(".bin")) if parts[4].endswith(".bin") else None
        if k in view.chunks and parts[3] == "chunk" and c is not None:
            return (k, c) if c < len(view.chunks[k]) else None
        return None
    if parts[3] == LOD_NAME:
        return (k, "lod") if k in view.chunks else None
    expected = POINTS_NAME if k in view.points else view.layers[k].name
    return (k, None) if parts[3] == expected else None


def _number(text: str) -> int | None:
    """The number ``text`` writes in ASCII decimal digits, or None."""
    return int(text) if text.isascii() and text.isdigit() else None
