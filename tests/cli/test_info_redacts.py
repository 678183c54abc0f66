"""`acq info` on a log written before credentials in query strings were redacted: the
old log still holds the password in its config metadata; info prints it masked."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from acq.cli.main import main as acq_main
from acq.sim.drive_log import DriveTruth

SECRET = "s3cret-Pw"


def _with_old_config(src: Path, dst: Path) -> None:
    """``src`` copied record by record, with a config metadata whose camera URL carries a
    password in its query, as logs of older versions stored it."""
    with open(src, "rb") as f, open(dst, "wb") as g:
        reader, writer = make_reader(f), Writer(g)
        writer.start(profile="", library="test")
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if schema is not None and schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(
                    schema.name, schema.encoding, schema.data
                )
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding,
                    schemas.get(channel.schema_id, 0), channel.metadata,
                )  # fmt: skip
            writer.add_message(
                channels[channel.id], message.log_time, message.data, message.publish_time
            )
        for meta in reader.iter_metadata():
            writer.add_metadata(meta.name, dict(meta.metadata))
        url = f"http://cam.local/videostream.cgi?user=admin&pwd={SECRET}"
        writer.add_metadata("device.old", {"url": url, "info": json.dumps({"source": url})})
        writer.finish()


@pytest.mark.parametrize("as_json", [False, True])
def test_info_masks_a_password_an_old_log_holds(
    short_drive: tuple[DriveTruth, Path], tmp_path: Path,
    capsys: pytest.CaptureFixture[str], as_json: bool,
) -> None:  # fmt: skip
    truth, _ = short_drive
    log = tmp_path / "old.mcap"
    _with_old_config(truth.files[0], log)
    assert SECRET.encode() in log.read_bytes()  # the old file keeps it: info must not show it
    assert acq_main(["info", str(log), *(["--json"] if as_json else [])]) == 0
    out = capsys.readouterr()
    assert SECRET not in out.out + out.err
    if as_json:  # the text names long values by their size only
        assert "videostream.cgi?user=admin&pwd=***" in out.out
