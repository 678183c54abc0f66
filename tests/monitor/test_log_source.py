"""LogSource on real MCAP files written by the recorder's LogWriter: it follows the
newest part of a session as the writer rolls files, reads a required device from the
log's configuration, and says whether the file is being written."""

from __future__ import annotations

import time
from pathlib import Path

import yaml

from acq.log import schemas
from acq.log.writer import LogWriter
from acq.monitor.log_source import LogSource, newest_log
from acq.monitor.snapshot import problems

CONFIG = {
    "version": 1,
    "scanners": [{"name": "laser", "driver": "hokuyo", "url": "socket://127.0.0.1:9",
                  "required": True}],
    "cameras": [{"name": "camera", "driver": "opencv", "source": "http://127.0.0.1:9/x"}],
}  # fmt: skip


def _status(uptime: float, laser_connected: bool = True, gap: float = 0.01) -> bytes:
    return schemas.status(
        timestamp_ns=time.monotonic_ns(),
        uptime_s=uptime,
        devices=[
            {"name": "laser", "kind": "scanner", "connected": laser_connected, "rate_hz": 40.0,
             "gap_s": gap, "clock_uncertainty_s": 1e-4},
            {"name": "camera", "kind": "camera", "connected": True, "rate_hz": 25.0},
        ],
    )  # fmt: skip


def test_the_newest_part_followed_across_rolls(tmp_path: Path) -> None:
    w = LogWriter(tmp_path, split_bytes=2000, metadata={"config": {"yaml": yaml.safe_dump(CONFIG)}})
    w.add_channel("/acq/status", schemas.SCHEMAS["acq.Status"])
    source = LogSource(tmp_path)
    for s in range(1, 40):
        now = time.monotonic_ns()
        w.write("/acq/status", _status(float(s)), now, now)
        w.sync()
        if s == 3:
            first = source.snapshot()
    assert len(w.files) > 2  # the writer rolled files
    snap = source.snapshot()
    assert first.writing and first.uptime_s == 3.0
    assert first.file in map(str, w.files[:-1])  # since replaced by a newer part
    assert snap.file == str(w.path) and snap.file == str(newest_log(tmp_path))
    assert snap.writing and snap.uptime_s == 39.0 and problems(snap) == []
    laser, camera = snap.devices
    assert laser.required and not camera.required
    # a required device that reports itself disconnected is a problem at once
    now = time.monotonic_ns()
    w.write("/acq/status", _status(40.0, laser_connected=False), now, now)
    w.sync()
    assert problems(source.snapshot()) == ["laser: required, disconnected (no answer)"]
    # the next part as the writer creates it, its magic not yet written: the last read
    # part stays followed until it is
    part = newest_log(tmp_path)
    stem = part.name.removesuffix(".mcap").rsplit("_", 1)[0]
    (tmp_path / f"{stem}_999.mcap").write_bytes(b"")
    assert source.snapshot().file == str(part)
    (tmp_path / f"{stem}_999.mcap").unlink()
    w.close()
    done = source.snapshot()
    assert not done.writing and done.closed and done.status_age_s is None


def _older_status_schema() -> schemas.Schema:
    """``acq.Status`` as logs written before the live colouring declare it: no
    ``colouring`` (nor its messages), no device ``required``."""
    from google.protobuf import descriptor_pb2

    fds = descriptor_pb2.FileDescriptorSet.FromString(schemas.SCHEMAS["acq.Status"].data)
    (acq,) = [f for f in fds.file if f.package == "acq"]
    for msg in list(acq.message_type):
        if msg.name in ("Colouring", "ColourShare"):
            acq.message_type.remove(msg)
        for f in list(msg.field):
            if (msg.name, f.name) in {("Status", "colouring"), ("DeviceStatus", "required")}:
                msg.field.remove(f)
    return schemas.Schema("acq.Status", "protobuf", fds.SerializeToString())


def test_a_log_of_an_older_status_reads_without_colouring(tmp_path: Path) -> None:
    w = LogWriter(tmp_path, metadata={"config": {"yaml": yaml.safe_dump(CONFIG)}})
    w.add_channel("/acq/status", _older_status_schema())
    w.write("/acq/status", _status(1.0), time.monotonic_ns(), time.monotonic_ns())
    w.close()
    snap = LogSource(tmp_path).snapshot()
    assert snap.colouring is None and snap.closed
    assert [(d.name, d.required) for d in snap.devices] == [("laser", True), ("camera", False)]
