"""`acq info` on a log written before credentials in query strings were redacted: the
old log still holds the password in its config metadata; info prints it masked."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from acq.cli.main import main as acq_main
from acq.sim.drive_log import DriveTruth
from tests.log_rewrite import mcap_copy

SECRET = "s3cret-Pw"


def _with_old_config(src: Path, dst: Path) -> None:
    """``src`` copied with a device record whose URL carries a password in its query,
    as logs of older versions stored it."""
    url = f"http://cam.local/videostream.cgi?user=admin&pwd={SECRET}"

    def with_url(name: str, values: dict[str, str]) -> dict[str, str]:
        if not name.startswith("device."):
            return values
        return {**values, "url": url, "info": json.dumps({"source": url})}

    mcap_copy(src, dst, metadata=with_url)


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
