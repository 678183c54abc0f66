"""The HTTP server of `acq view`: the page (``/``), its files and vendored libraries
(``/static/...``), the list of layers (``/api/layers``) and each layer's bytes
(``/data/<k>/<name>``; a cloud's points ``points.bin`` and their other attributes
``attributes.bin``, the parts of :func:`acq.view.points_payload.split_payload`), on a
thread of its own; nothing else is reachable. A cloud over
``max_points`` also serves its chunks (``/data/<k>/lod.json``, ``/data/<k>/chunk/<c>.bin``:
:mod:`acq.view.lod`). A drive's layer (:mod:`acq.view.drive`) serves
``/data/<k>/drive.json``, its cloud ``/data/<k>/cloud.bin`` (its attributes
``/data/<k>/cloud-attributes.bin``) and its frames
``/data/<k>/frame/<camera>/<frame>.jpg``; ``/api/frame?layer=K&point=I`` answers which
frame a cloud's point was coloured from (:mod:`acq.view.frames`)."""

from __future__ import annotations

import errno
import json
import shutil
import socket
import sys
import threading
import time
from collections.abc import Callable, Sequence
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, Literal
from urllib.parse import parse_qs, quote, unquote, urlsplit

from acq.addresses import is_loopback
from acq.errors import InputError, first_line
from acq.view import lod, static
from acq.view.crs import crs_of
from acq.view.errors import FrameError
from acq.view.layers import Layer, layers_of
from acq.view.points_payload import Split, payload, rows_and_shown, split_payload

if TYPE_CHECKING:
    from acq.view.drive import Drive

__all__ = [
    "ATTRIBUTES_NAME", "DEFAULT_MAX_POINTS", "LOD_NAME", "POINTS_NAME", "AddressError",
    "ViewServer",
]  # fmt: skip

_CHUNK = 1 << 20  # bytes copied to the socket at a time
# a laptop's browser draws about a million points well and slows around 5-10 M
DEFAULT_MAX_POINTS = 2_000_000
POINTS_NAME = "points.bin"  # a cloud layer's URL name: its points packed for the page
ATTRIBUTES_NAME = "attributes.bin"  # and their attributes (but sRGB), for the colour modes
LOD_NAME = "lod.json"  # a subsampled cloud's chunks, each at chunk/<c>.bin
# a drive's URL names (its cloud packed, its cloud's attributes)
DRIVE_NAME, DRIVE_CLOUD, DRIVE_ATTRIBUTES = "drive.json", "cloud.bin", "cloud-attributes.bin"
_POLL_S = 2.0  # how long a request for points still decoding waits before a 202


class AddressError(InputError):
    """The server cannot listen where it was asked: ``about`` "host" (no address of this
    machine) or "port" (in use, or privileged); ``reason`` says why."""

    def __init__(self, about: Literal["host", "port"], value: object, reason: str) -> None:
        super().__init__(f"{about} {value}: {reason}")
        self.about, self.value, self.reason = about, value, reason


class ViewServer:
    """Serves the layers of ``paths`` (checked on construction: InputError naming a bad
    one) on ``host``:``port`` (0: a free port) while the context is open; ``url`` is
    ``http://HOST:PORT/``. Each cloud is packed into the page's binary
    (:mod:`acq.view.points_payload`), at most ``max_points`` of its points, once, on a
    thread started with the server: its URL answers 202 (Accepted, Retry-After) until
    then; a cloud whose points turn out unreadable answers 422 with the one-line reason,
    also given to ``on_error``. One over ``max_points`` is also cut into chunks
    (:mod:`acq.view.lod`, runs of ``run_points`` rows unless it is COPC) decoded when the
    page asks for one. A drive is read here (:class:`acq.view.drive.Drive`, with
    ``calib``, its cloud made in ``cache`` when none lies beside it); a cloud layer's log
    is the drive it was found beside, else the only drive given."""

    def __init__(
        self, paths: Sequence[Path], host: str = "127.0.0.1", port: int = 0,
        max_points: int = DEFAULT_MAX_POINTS, calib: Path | None = None,
        cache: Path | None = None, on_error: Callable[[str], None] | None = None,
        run_points: int = lod.RUN_POINTS,
    ) -> None:  # fmt: skip
        if max_points < 1:
            raise ValueError(f"max_points {max_points}: at least 1")
        self.layers = layers_of(paths)
        self.crs = [crs_of(layer.path) for layer in self.layers]
        self.max_points = max_points
        self.points = {
            k: _Packing() for k, layer in enumerate(self.layers) if layer.kind == "cloud"
        }
        self.drives: dict[int, Drive] = {}
        if any(layer.kind == "drive" for layer in self.layers):
            # here: a drive's reading imports the colouring's (numba: ~100 MB resident)
            from acq.view.drive import Drive

            self.drives = {
                k: Drive(layer.files, calib, cache)
                for k, layer in enumerate(self.layers)
                if layer.kind == "drive"
            }
        if calib is not None and not self.drives:
            raise InputError(f"--calib {calib}: no .mcap log to use it with")
        self._on_error = on_error
        self._packer: threading.Thread | None = None
        self._drive_packings: dict[tuple[int, Path], _Packing] = {}
        self._drive_lock = threading.Lock()
        # the clouds over max_points: their chunks, found once their subset is packed
        self.chunks: dict[int, list[lod.Chunk]] = {
            k: [] for k in self.points if self.layers[k].count > max_points
        }
        self._run_points = run_points
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
        subsampled to ``max_points``, which has ``lod`` too: its chunks' URL); a cloud's
        ``attributes``, its attributes' URL (:data:`ATTRIBUTES_NAME`); ``log``, for
        a cloud, the drive layer whose log it was coloured from (None: none known); ``crs``,
        its file's (:func:`acq.view.crs.crs_of`)."""
        return [
            {
                "name": layer.name,
                "kind": layer.kind,
                "url": self._data_url(k, layer),
                "bytes": layer.size,
                "count": layer.count,
                "shown": self.shown(k),
                "log": self.log_of(k) if layer.kind == "cloud" else None,
                "crs": self.crs[k],
            }
            | ({"lod": f"/data/{k}/{LOD_NAME}"} if k in self.chunks else {})
            | ({"attributes": f"/data/{k}/{ATTRIBUTES_NAME}"} if k in self.points else {})
            for k, layer in enumerate(self.layers)
        ]

    def shown(self, k: int) -> int:
        """The points or vertices of layer ``k`` the page gets."""
        count = self.layers[k].count
        return min(count, self.max_points) if k in self.points else count

    def log_of(self, k: int) -> int | None:
        """The drive layer whose cloud the cloud layer ``k`` is (found beside its log),
        else the only drive layer; None when there is none, or several."""
        path = self.layers[k].path.resolve()
        for d, drive in self.drives.items():
            found = drive.cloud()
            if found is not None and found.resolve() == path:
                return d
        return next(iter(self.drives)) if len(self.drives) == 1 else None

    def drive_data(self, k: int) -> dict[str, Any]:
        """``/data/<k>/drive.json``: the drive's data (:meth:`Drive.data`), its cloud's
        URLs once there is one (``url``, its attributes ``attributes``), or the cloud
        layer that is its cloud (not sent twice)."""
        data = self.drives[k].data()
        cloud = self.drives[k].cloud()
        if cloud is not None:
            same = [
                j for j, layer in enumerate(self.layers) if layer.path.resolve() == cloud.resolve()
            ]
            urls = {
                "url": f"/data/{k}/{DRIVE_CLOUD}",
                "attributes": f"/data/{k}/{DRIVE_ATTRIBUTES}",
            }
            data["cloud"] |= {"layer": same[0]} if same else urls
        return data

    def drive_packing(self, k: int) -> _Packing | None:
        """Drive ``k``'s cloud packed for the page as a cloud layer's is (at most
        ``max_points`` points, once per file, on a thread of its own from the first
        asking), None while the drive has no cloud."""
        cloud = self.drives[k].cloud()
        if cloud is None:
            return None
        with self._drive_lock:
            packing = self._drive_packings.get((k, cloud))
            if packing is None:
                packing = self._drive_packings[(k, cloud)] = _Packing()
                threading.Thread(
                    target=self._pack_one,
                    args=(cloud, packing),
                    name="acq-view-pack-drive",
                    daemon=True,
                ).start()
        return packing

    def frame_of(self, k: int, point: int) -> dict[str, Any]:
        """``/api/frame``: the frame point ``point`` (the page's index) of the cloud layer
        or drive ``k`` was coloured from (:func:`acq.view.frames.point_frame`), its JPEG's
        URL; FrameError (with its HTTP status) otherwise."""
        if not 0 <= k < len(self.layers):
            raise FrameError(f"no layer {k}")
        if k in self.drives:
            d, cloud, packing = k, self.drives[k].cloud(), self.drive_packing(k)
            if cloud is None or packing is None:
                raise FrameError(f"{self.layers[k].name}: no cloud (yet)")
            packing.done.wait()
            if packing.data is None:
                raise FrameError(packing.error or f"{cloud}: its points cannot be read", 409)
            count, shown = rows_and_shown(packing.data.points)
        elif self.layers[k].kind == "cloud":
            found = self.log_of(k)
            if found is None:
                raise FrameError(
                    f"{self.layers[k].name}: no log to show its frames from (give its .mcap "
                    "after it)",
                    409,
                )
            d, cloud, count, shown = found, self.layers[k].path, self.layers[k].count, self.shown(k)
        else:
            raise FrameError(f"{self.layers[k].name}: a {self.layers[k].kind}, not a cloud", 400)
        if not 0 <= point < shown:
            raise FrameError(f"{self.layers[k].name}: no point {point} (the page has {shown})")
        from acq.view.frames import point_frame, point_row

        answer = point_frame(self.drives[d], point_row(cloud, point * count // shown))
        if answer["camera"] is not None:
            answer["url"] = f"/data/{d}/frame/{quote(answer['camera'])}/{answer['frame']}.jpg"
        return {"layer": k, "point": point, "log": d} | answer

    def chunk(self, k: int, c: int) -> bytearray:
        """The page's binary of chunk ``c`` of layer ``k``: its rows, at most
        :data:`acq.view.lod.CHUNK_CAP` of them (evenly spread beyond)."""
        found = self.chunks[k][c]
        return payload(self.layers[k].path, lod.CHUNK_CAP, found.start, found.stop)

    def _data_url(self, k: int, layer: Layer) -> str:
        if k in self.drives:
            return f"/data/{k}/{DRIVE_NAME}"
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
        """Listen and serve on a thread, and start making the drives' clouds that are to
        be made; AddressError when it cannot listen there."""
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
            # a stop (Ctrl-C) waits for the loop's next poll: 50 ms, not socketserver's 0.5 s
            target=self._httpd.serve_forever,
            args=(0.05,),
            name="acq-view",
            daemon=True,
        )
        self._thread.start()
        for drive in self.drives.values():
            drive.start()
        if self._packer is None:
            self._packer = threading.Thread(target=self._pack, name="acq-view-pack", daemon=True)
            self._packer.start()

    def _pack(self) -> None:
        """Pack each cloud layer's points in turn."""
        for k, packing in self.points.items():
            self._pack_one(self.layers[k].path, packing, k if k in self.chunks else None)

    def _pack_one(self, path: Path, packing: _Packing, chunked: int | None = None) -> None:
        """Pack the cloud ``path`` into ``packing`` (and find the chunks of layer
        ``chunked``); its reason, also to ``on_error``, when its points cannot be read."""
        try:
            packing.data = split_payload(path, self.max_points)
            if chunked is not None:
                self.chunks[chunked] = lod.chunks(
                    path, self.layers[chunked].count, packing.data.points, self._run_points
                )
        except InputError as e:
            packing.error = str(e)
        # never a page left waiting: said, whatever it was (a Rust decoder's panic comes
        # as a BaseException)
        except BaseException as e:
            packing.error = f"{path}: its points cannot be read ({first_line(e)})"
        packing.done.set()
        if packing.error is not None and self._on_error is not None:
            self._on_error(packing.error)

    def wait(self, timeout: float | None = None) -> bool:
        """Whether every cloud is packed (or failed) within ``timeout`` seconds."""
        end = None if timeout is None else time.monotonic() + timeout
        return all(
            p.done.wait(None if end is None else max(0.0, end - time.monotonic()))
            for p in self.points.values()
        )

    def stop(self) -> None:
        """Stop listening and close the socket (a transfer under way is cut)."""
        if self._httpd is not None:
            self._httpd.shutdown()
            self._httpd.server_close()
        if self._thread is not None:
            self._thread.join()
        self._httpd = self._thread = None


class _Packing:
    """A cloud's payload in the making: ``data`` (its two parts) once ``done``, or
    ``error`` (one line)."""

    def __init__(self) -> None:
        self.done = threading.Event()
        self.data: Split | None = None
        self.error: str | None = None


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
        elif path == "/api/frame":
            self._frame(body)
        elif (route := _drive_route(view, path)) is not None:
            self._drive(*route, body)
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
        if c is None and k not in view.points:
            self._file(view.layers[k].path, body)
        elif (packed := self._packed(view.points[k], view.layers[k].name, body)) is None:
            return  # a 202 or 422 said
        elif c is None or c == "attributes":
            part = packed.points if c is None else packed.attributes
            self._send(part, "application/octet-stream", body, "no-cache")
        elif c == "lod":
            data = json.dumps(lod.index(view.chunks[k])).encode()
            self._send(data, "application/json", body, "no-cache")
        elif isinstance(c, str) or c >= len(view.chunks[k]):
            self._not_found()
        else:
            try:
                chunk = view.chunk(k, c)
            except InputError as e:  # the file changed since the server started
                self.send_error(HTTPStatus.INTERNAL_SERVER_ERROR, "a chunk unread", str(e))
                return
            self._send(chunk, "application/octet-stream", body, "no-cache")

    def _frame(self, body: bool) -> None:
        query = parse_qs(urlsplit(self.path).query)
        try:
            k, point = (int(query[key][0]) for key in ("layer", "point"))
        except (KeyError, ValueError):
            self._json({"error": "expected /api/frame?layer=K&point=I (integers)"}, 400, body)
            return
        try:
            self._json(self.server.view.frame_of(k, point), 200, body)
        except FrameError as e:
            self._json({"error": str(e)}, e.status, body)
        except (InputError, OSError, ValueError) as e:  # a cloud or log unreadable (since)
            self._json({"error": first_line(e)}, 409, body)

    def _drive(self, k: int, rest: list[str], body: bool) -> None:
        """A drive's routes (``rest`` the URL's parts after ``/data/<k>/``)."""
        view = self.server.view
        drive = view.drives[k]
        if rest == [DRIVE_NAME]:
            self._json(view.drive_data(k), 200, body)
        elif rest in ([DRIVE_CLOUD], [DRIVE_ATTRIBUTES]):
            packing = view.drive_packing(k)
            if packing is None:
                self._not_found()
            elif (packed := self._packed(packing, view.layers[k].name, body)) is not None:
                part = packed.points if rest == [DRIVE_CLOUD] else packed.attributes
                self._send(part, "application/octet-stream", body, "no-cache")
        elif len(rest) == 3 and rest[0] == "frame" and rest[2].removesuffix(".jpg").isdigit():
            try:
                from acq.view.frames import frame_jpeg

                jpeg = frame_jpeg(drive, rest[1], int(rest[2].removesuffix(".jpg")))
            except FrameError as e:
                self.send_error(e.status, str(e))
                return
            except (InputError, OSError) as e:  # the log unreadable since the start
                self.send_error(HTTPStatus.CONFLICT, first_line(e))
                return
            self._send(jpeg, "image/jpeg", body, "max-age=3600")
        else:
            self._not_found()

    def _json(self, data: Any, status: int, body: bool) -> None:
        self._send(json.dumps(data).encode(), "application/json", body, status=status)

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
        self, data: bytes | bytearray, kind: str, body: bool, cache: str = "no-store",
        status: int = HTTPStatus.OK,
    ) -> None:  # fmt: skip
        self.send_response(status)
        self.send_header("Content-Type", kind)
        self.send_header("Content-Length", str(len(data)))
        self.send_header("Cache-Control", cache)
        self.end_headers()
        if body:
            view = memoryview(data)
            for start in range(0, len(data), _CHUNK):
                self.wfile.write(view[start : start + _CHUNK])

    def _packed(self, packing: _Packing, name: str, body: bool) -> Split | None:
        """A cloud's two parts once packed; if not (None), 202 said (Accepted: a browser
        logs a 503 as an error) after a wait, so that it comes as soon as it is ready, or
        422 and the reason when its points could not be read."""
        if not packing.done.wait(_POLL_S):
            self.send_response(HTTPStatus.ACCEPTED)
            self.send_header("Retry-After", "0")  # the next request waits again
            self._text(f"decoding {name}", body)
            return None
        if packing.data is None:
            self.send_response(HTTPStatus.UNPROCESSABLE_ENTITY)
            self._text(packing.error or "", body)
        return packing.data

    def _text(self, text: str, body: bool) -> None:
        """The rest of an answer whose status is sent: ``text`` as its body."""
        data = text.encode()
        self.send_header("Content-Type", "text/plain; charset=utf-8")
        self.send_header("Content-Length", str(len(data)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        if body:
            self.wfile.write(data)

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


def _drive_route(view: ViewServer, path: str) -> tuple[int, list[str]] | None:
    """(k, the parts after it) of a ``/data/<k>/...`` URL whose layer k is a drive."""
    parts = path.split("/")
    k = _number(parts[2]) if len(parts) >= 4 else None
    return (k, parts[3:]) if k is not None and k in view.drives else None


def _data_route(view: ViewServer, path: str) -> tuple[int, int | str | None] | None:
    """What ``path`` names below /data/: (k, None) for layer k's own URL (its file's
    name, or :data:`POINTS_NAME` for a cloud), (k, "attributes") for a cloud's
    :data:`ATTRIBUTES_NAME`, (k, "lod") for its chunks' index, (k, c)
    for its chunk c (``chunk/<c>.bin``); None for anything else."""
    parts = path.split("/")
    k = _number(parts[2]) if len(parts) in (4, 5) else None
    if k is None or k >= len(view.layers):
        return None
    if len(parts) == 5:
        c = _number(parts[4].removesuffix(".bin")) if parts[4].endswith(".bin") else None
        if k in view.chunks and parts[3] == "chunk" and c is not None:
            return k, c  # its number checked once the chunks are known
        return None
    if parts[3] == LOD_NAME:
        return (k, "lod") if k in view.chunks else None
    if parts[3] == ATTRIBUTES_NAME and k in view.points:
        return k, "attributes"
    expected = POINTS_NAME if k in view.points else view.layers[k].name
    return (k, None) if parts[3] == expected else None


def _number(text: str) -> int | None:
    """The number ``text`` writes in ASCII decimal digits, or None."""
    return int(text) if text.isascii() and text.isdigit() else None
