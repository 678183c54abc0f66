"""`acq record --live` end to end: a real recorder (its own process) on the simulated rig
serves the Foxglove WebSocket protocol; the clients here speak ``foxglove.sdk.v1`` with
`websockets`: one that decodes scans and images with the advertised protobuf schemas,
one that subscribes to everything and never reads, one that sends garbage. The log keeps
every scan the scanner sent, whatever the clients do."""

from __future__ import annotations

import asyncio
import json
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from acq.camera import calibfile
from acq.log.reader import read_metadata
from acq.log.timebase import TimeBase
from acq.monitor.foxglove_client import Seen, connect_client, take
from acq.record import live_colour
from acq.record.live_colour import LiveColourer
from tests.sim_rig import Rig, read_log

pytestmark = pytest.mark.realtime

ROOT = Path(__file__).resolve().parents[2]


def _with_calibration(rig: Rig, tmp_path: Path, calib: Path) -> Path:
    """The rig's configuration with its true calibration ``calib`` (so the log has
    /tf_static and /camera/calibration, latched)."""
    rig.config(tmp_path)
    path = tmp_path / "rig.yaml"
    data = yaml.safe_load(path.read_text())
    path.write_text(yaml.safe_dump({**data, "calibration": str(calib)}))
    return path


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


async def _clients(url: str, seconds: float) -> tuple[Seen, Seen]:
    """A garbage client, a stalled one and a reader, for ``seconds`` once connected."""
    # garbage: a binary frame of no opcode, text that is not JSON, a subscription of nothing
    bad = await connect_client(url)
    await bad.send(b"\xff\x00garbage")
    await bad.send("not json {")
    await bad.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": "x"}]}))
    await bad.send(json.dumps({"op": "unsubscribe", "subscriptionIds": [7, 8]}))
    # stalled: subscribes to what is advertised in its first 1.5 s, then never reads
    # (websockets then stops reading the socket: its queue holds 1 message)
    stalled = await connect_client(url, max_queue=1)
    stalled_seen = Seen()
    await take(stalled, stalled_seen, time.monotonic() + 1.5, decode=False)
    reader = await connect_client(url)
    seen = Seen()
    await take(reader, seen, time.monotonic() + seconds, decode=True)
    await reader.close()
    stalled.transport.abort()
    bad.transport.abort()
    return seen, stalled_seen


def _summary(url: str, seconds: float) -> dict[str, Any]:
    """What the clients saw, as JSON (the decoded messages' classes stay in the process
    that built them)."""
    seen, stalled = asyncio.run(_clients(url, seconds))
    scans = seen.messages.get("/laser/scan", [])
    images = seen.messages.get("/camera/image/compressed", [])
    tf = seen.messages.get("/tf_static", [])
    status = seen.messages.get("/acq/status", [])
    return {
        "name": seen.info.get("name"),
        "channels": {ch["topic"]: [ch["schemaName"], ch["encoding"]]
                     for ch in seen.channels.values()},
        "scans": len(scans),
        "scan_span_s": scans[-1][0] - scans[0][0] if scans else 0.0,
        "scan_points": [len(scans[0][1].ranges), len(scans[0][1].intensities)] if scans else [],
        "images": len(images),
        "image": [images[0][1].format, images[0][1].data[:2].hex()] if images else [],
        "transforms": len(tf[0][1].transforms) if tf else 0,
        "status_devices": [d.name for d in status[-1][1].devices] if status else [],
        "stalled_channels": len(stalled.channels),
        "colored": _clouds(seen.messages.get("/laser/colored", [])),
        "swath": _clouds(seen.messages.get("/live/swath", [])),
    }  # fmt: skip


def _clouds(got: list[tuple[float, Any]]) -> dict[str, Any]:
    """What a client saw of a PointCloud topic: how many, their fields, frame, points, the
    share of points with a colour (alpha 255), and the newest one's points as a list."""
    if not got:
        return {"count": 0}
    last = got[-1][1]
    raw = np.frombuffer(last.data, np.uint8).reshape(-1, last.point_stride)
    alphas = np.concatenate([np.frombuffer(m.data, np.uint8)[15 :: m.point_stride] for _, m in got])
    return {
        "count": len(got),
        "fields": [[f.name, f.offset, f.type] for f in last.fields],
        "frame_id": last.frame_id,
        "points": [len(m.data) // m.point_stride for _, m in got],
        "coloured_share": float(np.mean(alphas == 255)) if alphas.size else 0.0,
        "stamps": [m.timestamp.seconds * 10**9 + m.timestamp.nanos for _, m in got],
        "last_xyz": raw[:, :12].copy().view("<f4").round(3).tolist(),
        "last_rgb": raw[:, 12:15].tolist(),
    }


def test_live_clients_see_every_channel_and_the_log_keeps_every_record(
    rig: Rig, tmp_path: Path
) -> None:
    calib = rig.calibration(tmp_path)
    cfg_path = _with_calibration(rig, tmp_path, calib)
    # numba's cache filled first: a first recording's wait for its kernels (seconds, the
    # scans waiting meanwhile: test_live_colour) is not what this test is about
    LiveColourer(
        calibfile.load(calib),
        "laser",
        emit=lambda _: None,
        time_increment_s=lambda: None,
    ).warm_up()
    port = _free_port()
    out = tmp_path / "logs"
    proc = subprocess.Popen(
        [sys.executable, "-m", "acq.cli", "record", "-c", str(cfg_path), "--out", str(out),
         "--duration", "9", "--live", f"127.0.0.1:{port}", "--live-image-hz", "4",
         "--log-colored", "--live-swath-s", "2"],
        cwd=ROOT, stderr=subprocess.PIPE,
    )  # fmt: skip
    try:
        # the clients in their own process: not this one, which runs the scanner
        client = subprocess.run(
            [sys.executable, "-m", "tests.record.test_live", f"ws://127.0.0.1:{port}", "5"],
            cwd=ROOT, capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        _, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert client.returncode == 0, client.stderr
    seen = json.loads(client.stdout)
    assert proc.returncode == 0, err.decode()
    assert f"live server on ws://127.0.0.1:{port}" in err.decode()
    assert seen["name"] == "acq record"
    # every channel of the log, with the log's schemas
    for topic in ("/laser/scan", "/laser/raw", "/camera/image/compressed", "/acq/status",
                  "/acq/clock", "/tf_static", "/camera/calibration"):  # fmt: skip
        assert topic in seen["channels"], sorted(seen["channels"])
    assert seen["channels"]["/laser/scan"] == ["foxglove.LaserScan", "protobuf"]
    assert seen["scan_points"] == [1081, 1081]
    # scans keep coming to this client while the stalled one holds its backlog
    span = seen["scan_span_s"]
    assert span > 2.5 and seen["scans"] > 20 * span, seen
    assert seen["image"] == ["jpeg", "ffd8"]
    assert 1 <= seen["images"] <= 4 * 5.0 + 2  # at most --live-image-hz, for 5 s
    # the latched messages reach a client that connected after they were written
    assert seen["transforms"] > 0
    assert seen["status_devices"] == ["laser", "camera"]
    assert seen["stalled_channels"] > 0  # it subscribed before it stalled
    # the log: every scan the scanner sent between the first and the last recorded
    log = read_log(next(out.glob("*.mcap")))
    by_tick = {s.timestamp: s for s in list(rig.scanner.sent)}
    recorded = [by_tick[m.device_ticks[0]] for _, _, m in log["/laser/raw"]]
    between = [s for s in by_tick.values() if recorded[0].t0 <= s.t0 <= recorded[-1].t0]
    got = {s.timestamp for s in recorded}
    missing = [round(s.t0 - recorded[0].t0, 3) for s in between if s.timestamp not in got]
    assert len(recorded) == len(between) == len(log["/laser/scan"]), (missing, err.decode())
    laser = next(d for d in log["/acq/status"][-1][2].devices if d.name == "laser")
    assert laser.dropped == 0
    assert len(log["/camera/image/compressed"]) > 25 * 6  # every frame, not 4 Hz
    # coloured scans: one a scan, x y z float32 and red green blue alpha uint8, stamped
    # with the scan's own stamp, in the log (--log-colored) and live
    colored = seen["colored"]
    logged, in_log = log["/laser/colored"], log["/laser/scan"]
    # each scan coloured (and logged, unless the writer was behind) or, the colourer
    # behind on a loaded machine, skipped and counted; the last status is up to 1 s old
    # (40 scans after it), with up to MAX_WAITING scans waiting for their frames and
    # BEHIND_RECORDS records queued before the colourer then
    figures = log["/acq/status"][-1][2].colouring  # the colourer's figures each second
    unknown = 40 + live_colour.MAX_WAITING + live_colour.BEHIND_RECORDS
    assert figures.scans_coloured + figures.scans_skipped >= len(in_log) - unknown
    # (a loaded host may leave the live server's or the colourer's thread behind: then
    # fewer are coloured or sent, and the recorder says so, the log losing nothing)
    behind = " fell behind: " in err.decode() or figures.scans_skipped > 0
    why = (colored["count"], str(figures), err.decode())
    if behind and figures.scans_coloured <= 5 * span:
        pytest.skip(f"the colourer was behind all along (every scan counted): {why}")
    assert colored["count"] >= (1 if behind else 5 * span), why
    assert colored["fields"] == [["x", 0, 7], ["y", 4, 7], ["z", 8, 7], ["red", 12, 1],
                                 ["green", 13, 1], ["blue", 14, 1], ["alpha", 15, 1]]  # fmt: skip
    assert colored["frame_id"] == "laser"
    assert colored["coloured_share"] > 0.2  # one fisheye sees the street's side
    assert figures.scans_coloured > 5 * span
    assert 0.5 * figures.scans_coloured <= len(logged) <= len(in_log)

    def stamps(messages: list[tuple[int, int, Any]], offset: int = 0) -> set[int]:
        return {m.timestamp.seconds * 10**9 + m.timestamp.nanos + offset for *_, m in messages}

    assert stamps(logged) <= stamps(in_log)
    # live, on the log's clock (UTC): each a scan's own stamp
    utc = TimeBase.of_metadata(read_metadata(next(out.glob("*.mcap")))).utc_offset_ns
    assert set(colored["stamps"]) <= stamps(in_log, utc)
    assert "/live/swath" not in log  # live only
    assert [c.camera for c in figures.cameras] == ["camera"]
    assert figures.coloured_share == pytest.approx(figures.cameras[0].share)
    assert figures.coloured_share > 0.2
    # the swath: 2 s of coloured scans at 2 Hz, in the laser frame (this rig has no CAN)
    swath = seen["swath"]
    if behind and swath["count"] < 2:  # (said: a listener or the colourer fell behind)
        return
    assert swath["count"] >= (2 if behind else 2 * span - 3), (swath["count"], err.decode())
    assert swath["frame_id"] == "laser"
    # 2 Hz: made each 0.5 s of the recorder's clock, stamped with the scan just coloured
    assert np.median(np.diff(swath["stamps"])) >= 0.5e9 - 30e6
    assert 0 < max(swath["points"]) <= 300_000
    assert swath["coloured_share"] == 1.0  # only coloured points


@pytest.mark.parametrize(
    ("args", "said"),
    [(["--live", "nowhere"], "--live: 'nowhere': expected HOST:PORT"),
     (["--live", "127.0.0.1:70000"], "expected HOST:PORT"),
     (["--live-image-hz", "2"], "--live-image-hz: only with --live"),
     (["--live", "--live-image-hz", "-1"], "--live-image-hz")],
)  # fmt: skip
def test_live_option_errors_are_one_line(tmp_path: Path, args: list[str], said: str) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "acq.cli", "record", *args, "--duration", "1",
         "--out", str(tmp_path / "logs")],
        cwd=ROOT, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert proc.returncode == 2
    assert said in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert not (tmp_path / "logs").exists()


def test_a_taken_port_is_a_runtime_error_before_recording(tmp_path: Path) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        proc = subprocess.run(
            [sys.executable, "-m", "acq.cli", "record", "--live", f"127.0.0.1:{port}",
             "--duration", "1", "--out", str(tmp_path / "logs")],
            cwd=ROOT, capture_output=True, text=True, timeout=60,
        )  # fmt: skip
    assert proc.returncode == 1
    assert f"--live 127.0.0.1:{port}: cannot listen" in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert not (tmp_path / "logs").exists()  # nothing recorded, nothing written


@pytest.mark.parametrize(
    ("address", "warned"),
    [("0.0.0.0:0", "every network interface"), ("127.0.0.2:0", None), ("[::1]:0", None)],
)
def test_a_live_server_off_loopback_is_a_warning(
    rig: Rig, tmp_path: Path, address: str, warned: str | None
) -> None:
    cfg = rig.config(tmp_path)
    proc = subprocess.run(
        [sys.executable, "-m", "acq.cli", "record", "-c", str(tmp_path / "rig.yaml"),
         "--live", address, "--duration", "0.5", "--out", str(cfg.output.dir)],
        cwd=ROOT, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    warnings = [line for line in proc.stderr.splitlines() if "warning: --live" in line]
    if warned is None:
        assert warnings == []
    else:
        assert len(warnings) == 1 and warned in warnings[0]


def test_which_hosts_are_loopback() -> None:
    from acq.addresses import is_loopback
    from acq.record.live import parse_address

    assert [is_loopback(h) for h in ("127.0.0.1", "127.1.2.3", "::1", "localhost")] == [True] * 4
    assert [is_loopback(h) for h in ("0.0.0.0", "192.168.1.20", "::", "rig.local")] == [False] * 4
    assert parse_address("[::1]:8765") == ("::1", 8765)
    assert parse_address("rig.local:80") == ("rig.local", 80)


if __name__ == "__main__":  # the test's clients, in their own process
    print(json.dumps(_summary(sys.argv[1], float(sys.argv[2]))))


def test_a_recorders_listener_gets_every_record_of_the_log(rig: Rig, tmp_path: Path) -> None:
    from mcap.reader import make_reader

    from acq.record.listeners import Listener, LogRecord
    from acq.record.recorder import Recorder

    class Keep(Listener):
        def __init__(self) -> None:
            self.got: list[LogRecord] = []

        def on_record(self, record: LogRecord) -> None:
            self.got.append(record)

    keep = Keep()
    cfg = rig.config(tmp_path).model_copy(update={"calibration": rig.calibration(tmp_path)})
    recorder = Recorder(cfg, duration_s=2.5, listeners=[keep])
    assert recorder.run() == 0
    assert recorder.listeners.feeds == []  # closed
    with next((tmp_path / "logs").glob("*.mcap")).open("rb") as f:
        in_log = [(c.topic, s.name if s else "", m.data, m.log_time)
                  for s, c, m in make_reader(f).iter_messages(log_time_order=False)]  # fmt: skip
    got = [(r.topic, r.schema.name, r.data, r.log_time_ns) for r in keep.got]
    assert got == in_log  # the same records, bytes, schemas and log times, in order
    assert {"/laser/scan", "/camera/image/compressed", "/acq/status", "/tf_static"} <= {
        t for t, *_ in got
    }
    assert [r.topic for r in keep.got if r.latched] == ["/tf_static", "/camera/calibration"]
