"""A simulated camera and its MJPEG server (:func:`acq.sim.mjpeg_server.serve_camera`) in
a child process, so a client's timing is not disturbed by the renderer holding the GIL in
its own process: :class:`MjpegServerProcess` drives it with JSON commands over a pipe.

Times are the host's ``time.monotonic()`` seconds.
"""

from __future__ import annotations

import contextlib
import os
import select
import signal
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

from acq.sim.camera_device import FrameTruth
from acq.sim.mjpeg_server import serve_camera

__all__ = ["MjpegServerProcess"]


def _child_main() -> None:
    """``python -m acq.sim.mjpeg_process --child``: JSON commands on stdin, replies on stdout."""
    import json
    import sys

    spec = json.loads(sys.stdin.readline())
    options = dict(spec["options"])
    prerender_s = float(options.pop("prerender_s", 0.0))
    try:
        server = serve_camera(spec["listen"], start=not prerender_s, **options)
        server.camera.prerender(prerender_s)
    except Exception as e:  # reported to the parent, which raises it
        print(json.dumps({"error": repr(e)}), flush=True)
        return
    print(json.dumps({"url": server.url}), flush=True)
    try:
        for line in sys.stdin:
            command, *args = json.loads(line)
            value: Any
            if command == "close":
                break
            if command == "start":
                server.camera.t_origin = float(args[0])
                server.start()
                value = None
            elif command == "truth":
                value = [asdict(t) for t in server.camera.truth()]
            elif command == "cpu":
                value = time.process_time()
            elif command in ("stall", "drop_connection", "corrupt_next", "skip_next"):
                value = getattr(server, command)(*args)
            elif command == "flood":
                server.flood(args[0], bytes.fromhex(args[1]))
                value = None
            elif command == "flooded_bytes":
                value = server.flooded_bytes()
            else:
                value = None
            print(json.dumps({"value": value}), flush=True)
    finally:
        server.close()


def _cpu_s(pid: int) -> float | None:
    """CPU s (user and system) process ``pid`` has used; None where /proc cannot say."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


class MjpegServerProcess:
    """:func:`serve_camera` in a child process: the same faults, ``truth()`` fetched over
    a pipe. ``options`` must be JSON values (no Street or Rig objects: ``camera`` names
    the rig's camera, ``street_seed`` the street). The default ``listen`` picks a free
    port on 127.0.0.1.

    ``prerender_s``: the child renders the frames of the drive's first ``prerender_s``
    seconds before it answers (:meth:`SimCamera.prerender`) and serves nothing until
    :meth:`start` gives the drive's start, ``t_origin``."""

    def __init__(
        self,
        listen: str | None = "http://127.0.0.1:0/stream.mjpg",
        *,
        prerender_s: float = 0.0,
        **options: Any,
    ):
        import json
        import subprocess
        import sys

        self._proc = subprocess.Popen(
            [sys.executable, "-m", "acq.sim.mjpeg_process", "--child"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        self._json = json
        assert self._proc.stdin is not None and self._proc.stdout is not None
        if prerender_s:
            options["prerender_s"] = prerender_s
        try:
            self._proc.stdin.write(json.dumps({"listen": listen, "options": options}) + "\n")
            self._proc.stdin.flush()
        except BrokenPipeError:  # it is gone already: said below, with its exit status
            self._proc.wait(5)
        # a frame takes 20-40 ms of a core to render: 0.5-1 s of the child's CPU per second
        # of frames, whatever the wall time a machine busy with other work stretches it to
        budget_s = 60 + 5 * prerender_s
        t0 = time.monotonic()
        reply: dict[str, Any] = {}
        while self._proc.poll() is None:
            ready, _, _ = select.select([self._proc.stdout], [], [], 1.0)
            if ready:
                reply = json.loads(self._proc.stdout.readline() or "{}")
                break
            used = _cpu_s(self._proc.pid)
            waited = time.monotonic() - t0
            if (used if used is not None else waited) > budget_s or waited > 20 * budget_s:
                cpu = f"{used:.0f} s of its CPU in " if used is not None else ""
                rendering = f"rendering {prerender_s:g} s of frames first"
                reply = {"error": f"no answer after {cpu}{waited:.0f} s ({rendering})"}
                break
        if "url" not in reply:
            self._proc.kill()
            status = self._proc.wait(5)
            for pipe in (self._proc.stdin, self._proc.stdout):
                with contextlib.suppress(OSError):  # the spec it never read: a broken pipe
                    pipe.close()
            why = reply.get("error") or f"it exited with status {status} before serving"
            raise RuntimeError(f"the simulated camera process failed: {why}")
        self.url: str = reply["url"]

    def _call(self, *command: Any) -> Any:
        assert self._proc.stdin is not None and self._proc.stdout is not None
        self._proc.stdin.write(self._json.dumps(command) + "\n")
        self._proc.stdin.flush()
        return self._json.loads(self._proc.stdout.readline())["value"]

    def start(self, t_origin: float) -> None:
        """Serve, the drive starting at ``t_origin`` (host monotonic s): with
        ``prerender_s``, the server waits for this."""
        self._call("start", t_origin)

    def stall(self, seconds: float) -> None:
        self._call("stall", seconds)

    def drop_connection(self) -> None:
        self._call("drop_connection")

    def corrupt_next(self) -> None:
        self._call("corrupt_next")

    def skip_next(self) -> None:
        self._call("skip_next")

    def flood(self, seconds: float, body: bytes = b"") -> None:
        self._call("flood", seconds, body.hex())

    def freeze(self) -> None:
        """Stop the camera's process (SIGSTOP): its port still takes connections (they
        queue in the listen backlog), nothing is read, rendered or sent until :meth:`thaw`."""
        self._proc.send_signal(signal.SIGSTOP)

    def thaw(self) -> None:
        """Resume the process :meth:`freeze` stopped (SIGCONT)."""
        self._proc.send_signal(signal.SIGCONT)

    def kill(self) -> None:
        """The camera's process dies (SIGKILL): its connections and port closed."""
        self._proc.kill()
        self._proc.wait(5)

    def flooded_bytes(self) -> int:
        return int(self._call("flooded_bytes"))

    def truth(self) -> list[FrameTruth]:
        return [FrameTruth(**t) for t in self._call("truth")]

    def cpu_seconds(self) -> float:
        """The server process's CPU time so far (s)."""
        return float(self._call("cpu"))

    def close(self) -> None:
        if self._proc.poll() is None:
            self.thaw()
            assert self._proc.stdin is not None
            with contextlib.suppress(OSError, ValueError):
                self._proc.stdin.write(self._json.dumps(["close"]) + "\n")
                self._proc.stdin.close()
            try:
                self._proc.wait(5)
            except Exception:
                self._proc.kill()
                self._proc.wait(5)
        if self._proc.stdout is not None:
            self._proc.stdout.close()

    def __enter__(self) -> MjpegServerProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


if __name__ == "__main__":
    import sys

    if sys.argv[1:] == ["--child"]:
        _child_main()
