"""A channel whose schema the file garbled: its messages are read, not decoded, and the
reader says so once, naming the file and the topic."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest
from mcap.writer import Writer

from acq.log.reader import LogReader


def test_a_garbled_schema_is_one_warning_and_its_messages_undecoded(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / "garbled.mcap"
    with path.open("wb") as f:
        w = Writer(f)
        w.start()
        schema = w.register_schema("acq.Status", "protobuf", b"\xff\x00not a descriptor set")
        channel = w.register_channel("/acq/status", "protobuf", schema)
        for t in range(3):
            w.add_message(channel, log_time=t, data=b"\x08\x01", publish_time=t)
        w.finish()
    reader = LogReader(path)
    with caplog.at_level(logging.WARNING, logger="acq.log"):
        decoded = [reader.decode(s, c, m) for s, c, m in reader.messages()]
    assert decoded == [None, None, None]
    (line,) = [r.getMessage() for r in caplog.records]
    assert line.startswith(f"{path}: /acq/status (acq.Status) cannot be decoded: ")
