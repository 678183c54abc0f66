"""A log recorded by `acq demo` read by the official TypeScript MCAP reader (@mcap/core,
the one Foxglove uses; its messages decoded from the schemas in the file, as Foxglove
does): its times are the session's date and time, not 1970. Run by `make interop`, which
installs the reader with npm into tests/interop/node; skipped without Node.js."""

from __future__ import annotations

import json
import shutil
import subprocess
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

from acq.cli import main as acq_main
from acq.log.reader import LogReader

pytestmark = pytest.mark.interop

NODE = Path(__file__).parent / "node"
DAY_NS = 86_400 * 10**9


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, int, int]:
    """(the demo's log, wall clock ns before and after it ran)."""
    out = tmp_path_factory.mktemp("demo") / "demo"
    before = time.time_ns()
    assert acq_main(["demo", "--out", str(out), "--seconds", "2"]) == 0
    return out / "demo.mcap", before, time.time_ns()


def _read_with_mcap_core(path: Path) -> dict:
    node = shutil.which("node")
    if node is None or not (NODE / "node_modules" / "@mcap" / "core").is_dir():
        pytest.skip("Node.js or @mcap/core not installed (make interop installs it)")
    done = subprocess.run(
        [node, str(NODE / "mcap_core_read.mjs"), str(path)],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    result: dict = json.loads(done.stdout)
    return result


def test_mcap_core_sees_the_sessions_date_and_time(demo: tuple[Path, int, int]) -> None:
    path, before, after = demo
    seen = _read_with_mcap_core(path)
    offset = int(seen["metadata"]["acq"]["utc_offset_ns"])
    assert seen["profile"] == "acq"
    start = int(seen["message_start_time"])
    assert before - 10**9 <= start <= after  # today, while the demo recorded
    topics = seen["topics"]
    cameras = ("/left/image/compressed", "/right/image/compressed")
    for topic in ("/laser/scan", *cameras, "/tf_static", "/acq/timing/laser"):
        t = topics[topic]
        assert before - 10**9 <= int(t["first_log_time"]) <= int(t["last_log_time"]) <= after
    # Foxglove messages: stamped on the same clock, a few ms before their receipt
    for topic in ("/laser/scan", *cameras, "/tf_static"):
        (stamp,) = {int(s) for s in topics[topic]["stamps"]}
        assert int(topics[topic]["first_log_time"]) - stamp < 10**9
        assert stamp == int(topics[topic]["first_publish_time"])
    # acq.* messages keep host monotonic time: the file's UTC less the session's offset
    raw = topics["/laser/raw"]
    (mono,) = (int(s) for s in raw["stamps"])
    assert int(raw["first_publish_time"]) - offset == mono < DAY_NS * 10_000
    # and acq's reader gives back the host monotonic times it was given
    reader = LogReader(path)
    first = next(m for _, c, m in reader.messages() if c.topic == "/laser/scan")
    assert first.log_time + offset == int(topics["/laser/scan"]["first_log_time"])


def test_mcap_core_reads_uncompressed_image_chunks(tmp_path: Path, shared_dir: Path) -> None:
    """Chunks of JPEGs stored uncompressed (as a rig of large frames writes them) beside a
    zstd one: @mcap/core reads every message and decodes the images."""
    from tests.log.test_mcap_file import _jpegs, _write_both

    _old, new = _write_both(tmp_path, _jpegs(shared_dir))
    with new.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    assert {i.compression for i in summary.chunk_indexes} == {"zstd", ""}
    topics = _read_with_mcap_core(new)["topics"]
    assert topics["/camera/image/compressed"]["count"] == 15
    assert topics["/laser/raw"]["count"] == 40 + 45
    assert topics["/acq/clock"]["count"] == 40
