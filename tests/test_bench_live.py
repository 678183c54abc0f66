"""What bench/live_agreement.py and bench/live.py compute, on real files: the matcher of
live coloured scans against ``acq colorize``'s PLY on a real log (live clouds written into
a copy of the log from the offline colours, as ``foxglove.PointCloud`` with the fields the
live colourer publishes), and the latency from a scan's last point."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from foxglove_schemas_protobuf.LaserScan_pb2 import LaserScan
from mcap.writer import Writer

from acq.log.acq_proto import DeviceStatusMsg, StatusMsg
from acq.log.cloud_message import point_cloud
from acq.log.reader import LogReader, read_metadata
from acq.log.schemas import SCHEMAS  # the descriptor sets the logs carry
from tests.bench_scripts import load
from tests.log_rewrite import mcap_copy

agreement = load("live_agreement")
live = load("live")
swath = load("live_swath")


def _cloud(xyz: np.ndarray, rgb: np.ndarray, coloured: np.ndarray, stamp_ns: int) -> bytes:
    """A coloured scan as the live colourer publishes it."""
    return point_cloud(xyz, rgb, "laser", stamp_ns, np.where(coloured, 255, 0).astype(np.uint8))


@pytest.fixture(scope="module")
def offline(
    short_drive: tuple[object, Path], tmp_path_factory: pytest.TempPathFactory
) -> tuple[Path, Path]:
    """The short drive's log and ``acq colorize --frame laser --view nearest`` of it."""
    _, calib = short_drive
    log = next(calib.parent.glob("*.mcap"))
    ply = tmp_path_factory.mktemp("live_agreement") / "offline.ply"
    agreement.colorize([log], calib, ply)
    return log, ply


def _with_live(log: Path, ply: Path, dst: Path, edit: object = None) -> Path:
    """A copy of ``log`` with ``/laser/colored`` clouds made of the PLY's points, scan by
    scan, stamped with the scan's log stamp (``edit(k, rgb, coloured)`` may change a
    scan's colours, or give None to leave the scan out)."""
    points = agreement.read_ply(ply)
    reader = LogReader(log)
    offset = read_metadata(log)["acq"].get("utc_offset_ns", "0")
    stamps = sorted(
        m.timestamp.seconds * 10**9 + m.timestamp.nanos + int(offset)  # back on the log's clock
        for _, ch, _, m in reader.decoded(lambda _s, c: c.topic == "/laser/scan" or None)
    )

    def add(w: Writer) -> None:
        s = SCHEMAS["foxglove.PointCloud"]
        schema = w.register_schema(s.name, s.encoding, s.data)
        channel = w.register_channel("/laser/colored", "protobuf", schema)
        for k in np.unique(points.scan):
            sel = points.scan == k
            rgb, coloured = points.rgb[sel], points.coloured[sel]
            if edit is not None:
                changed = edit(int(k), rgb.copy(), coloured.copy())  # type: ignore[operator]
                if changed is None:
                    continue
                rgb, coloured = changed
            t = stamps[int(k)]
            w.add_message(channel, t, _cloud(points.xyz[sel], rgb, coloured, t), t)

    mcap_copy(log, dst, extra=add)
    return dst


def _figures(log: Path, ply: Path) -> dict[str, object]:
    geometry = json.loads(read_metadata(log)["device.laser"]["geometry"])
    points, orphans = agreement.read_live([log], "laser")
    assert orphans == 0
    return agreement.agreement(points, agreement.read_ply(ply), geometry)  # type: ignore[no-any-return]


def test_identical_live_and_offline_colours_agree_entirely(
    offline: tuple[Path, Path], tmp_path: Path
) -> None:
    log, ply = offline
    f = _figures(_with_live(log, ply, tmp_path / "same.mcap"), ply)
    assert f["offline_coloured"] > 1000
    assert f["matched"] == f["offline_points"] == f["live_points"]
    assert f["range_mismatch"] == 0
    assert f["colour_within"] == 1.0 and f["coloured_live"] == 1.0 and f["ok"]


def test_shifted_colours_and_missing_scans_lower_the_figures(
    offline: tuple[Path, Path], tmp_path: Path
) -> None:
    log, ply = offline

    def edit(k: int, rgb: np.ndarray, coloured: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        if k % 4 == 0:
            return None  # a scan the live colourer skipped
        if k % 4 == 1:  # colours off by 40/255 in red
            rgb[:, 0] = np.where(rgb[:, 0] > 127, rgb[:, 0] - 40, rgb[:, 0] + 40)
        return rgb, coloured

    f = _figures(_with_live(log, ply, tmp_path / "edited.mcap", edit), ply)
    assert 0.6 < f["coloured_live"] < 0.85  # a quarter of the scans missing
    assert f["coloured_live_in_live_scans"] == 1.0  # every point of the scans published
    assert 0.55 < f["colour_within"] < 0.8  # a third of the rest off
    assert not f["ok"]


def test_packed_rgb_clouds_are_read_as_every_point_coloured() -> None:
    fields = {"rgb": np.array([0x00FF8001, 0x00000000], np.uint32)}
    rgb, coloured = agreement.cloud_colours(fields)
    assert rgb.tolist() == [[255, 128, 1], [0, 0, 0]] and coloured.all()


def test_latency_runs_from_the_scans_last_point_to_its_receipt() -> None:
    offset = 1_700_000_000 * 10**9  # the log's UTC offset
    stamp_mono = 5_000_000_000  # point 0, host monotonic ns
    msg = LaserScan()
    msg.timestamp.seconds, msg.timestamp.nanos = divmod(stamp_mono + offset, 10**9)
    last = live.last_point_s(
        {"device.laser": {"geometry": json.dumps({"n_points": 1081, "time_increment": 2.5e-5})}},
        "laser",
    )
    assert last == pytest.approx(0.027)
    received = stamp_mono / 1e9 + 0.027 + 0.012  # 12 ms after the last point
    ms = live.latencies_ms([(received, msg)], offset, last)
    assert ms.tolist() == pytest.approx([12.0], abs=1e-3)
    figures = live.latency_figures(np.array([1.0, 2.0, 3.0, 100.0]))
    assert figures["median_ms"] == 2.5 and figures["max_ms"] == 100.0
    assert live.latency_figures(np.zeros(0))["p99_ms"] is None


def test_the_recorders_cpu_counts_its_children() -> None:
    """A shell whose child burns 0.3 s of CPU: the tree has it, the shell alone not."""
    processes = load("processes")
    burn = (
        "import time\nwhile time.process_time() < 0.3: pass\n"
        "print('burnt', flush=True)\ntime.sleep(30)"
    )
    shell = subprocess.Popen(["sh", "-c", f'{sys.executable} -c "{burn}"; true'],
                             stdout=subprocess.PIPE, text=True)  # fmt: skip
    try:
        assert shell.stdout is not None and shell.stdout.readline().strip() == "burnt"
        assert processes.tree_cpu_s(shell.pid) >= 0.28  # /proc counts 10 ms ticks
        assert processes.cpu_s(shell.pid) < 0.1
    finally:
        shell.kill()
        for child in _children(shell.pid):
            os.kill(child, signal.SIGKILL)
        shell.wait()


def _children(pid: int) -> list[int]:
    """The live children of ``pid``, from /proc."""
    out = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                ppid = int((entry / "stat").read_text().rpartition(")")[2].split()[1])
            except (OSError, IndexError):
                continue
            if ppid == pid:
                out.append(int(entry.name))
    return out


def test_drops_are_counted_between_two_statuses() -> None:
    def status(laser: int, left: int) -> object:
        return StatusMsg(devices=[DeviceStatusMsg(name="laser", dropped=laser),
                                  DeviceStatusMsg(name="left", dropped=left)])  # fmt: skip

    statuses = [(1.0, status(0, 3)), (2.0, status(0, 5)), (3.0, status(2, 9)), (4.0, status(2, 9))]
    assert live.drops_between(statuses, 1.5, 3.5) == {"laser": 2, "left": 6}
    assert live.drops_between(statuses, 0.0, 2.5) == {"laser": 0, "left": 2}
    assert live.drops_between(statuses, 0.0, 0.5) == {}


def _script(*args: object) -> tuple[dict[str, object], str]:
    bench = Path(__file__).resolve().parents[1] / "bench" / "live_agreement.py"
    done = subprocess.run([sys.executable, str(bench), *map(str, args)], capture_output=True,
                          text=True, check=True)  # fmt: skip
    return json.loads(done.stdout), done.stderr


def test_the_script_prints_one_line_and_says_when_the_coloured_topic_is_absent(
    offline: tuple[Path, Path], short_drive: tuple[object, Path], tmp_path: Path
) -> None:
    log, ply = offline
    calib = short_drive[1]
    line, _ = _script(_with_live(log, ply, tmp_path / "same.mcap"), "--calib", calib,
                      "--offline", ply)  # fmt: skip
    assert line["present"] and line["ok"] and line["coloured_live"] == 1.0
    line, err = _script(log, "--calib", calib)
    assert line == {"bench": "live_agreement", "topic": "/laser/colored", "present": False,
                    "orphan_clouds": 0, "ok": False}  # fmt: skip
    assert "no /laser/colored messages (record with --log-colored)" in err


@pytest.mark.realtime
def test_the_live_bench_measures_a_real_recorder(tmp_path: Path) -> None:
    """bench/live.py's latency and stalled parts against ``acq record --live`` on the
    simulated rig (a UTM-30LX on TCP, a camera over HTTP): the raw scans' latency, no
    coloured scans (the rig has no calibration here), no scan lost to the stalled client."""
    from tests.sim_rig import warm_rig

    for rig in warm_rig():
        rig.config(tmp_path)
        bench = Path(__file__).resolve().parents[1] / "bench" / "live.py"
        done = subprocess.run(
            [sys.executable, str(bench), "--latency", "--stalled", "-c", str(tmp_path / "rig.yaml"),
             "--warmup-s", "1", "--latency-s", "3", "--stall-s", "3"],
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        assert done.returncode == 0, done.stderr[-2000:]
    lines = [json.loads(line) for line in done.stdout.splitlines()]
    colored, scan, stalled = lines
    assert colored["topic"] == "/laser/colored" and not colored["present"]
    assert colored["median_ms"] is None
    assert scan["topic"] == "/laser/scan" and scan["present"] and scan["reader_closed"] == ""
    assert scan["messages"] >= 60  # 40 Hz for 3 s, on a busy machine
    assert 0 < scan["median_ms"] < 500
    assert stalled["bench"] == "live_stalled" and stalled["exit_code"] == 0
    got, nominal = map(int, stalled["scans"].split("/"))
    assert got == nominal > 100 and stalled["dropped"]["laser"] == 0
    assert stalled["reader_latency"]["/laser/scan"]["with_stalled"]["present"]
    assert stalled["stalled_client_messages"]["/laser/scan"] > 0


def test_the_swath_picture_shows_the_street_from_above_and_its_left_side() -> None:
    """bench/live_swath.py's drawing of a swath: a red wall 5 m left of a straight track,
    a blue one 5 m right, a grey road between; seen from above and from the street."""
    x = np.repeat(np.arange(0.0, 40.0, 0.05), 40)
    z = np.tile(np.linspace(0.0, 8.0, 40), x.size // 40)
    wall = np.stack([x, np.full_like(x, 5.0), z], axis=1)
    road = np.stack([x, np.tile(np.linspace(-4, 4, 40), x.size // 40), np.zeros_like(x)], 1)
    right = wall * [1, -1, 1]
    rgb = np.vstack([np.tile(c, (x.size, 1)) for c in ([200, 30, 30], [90, 90, 90], [30, 30, 200])])
    data = point_cloud(np.vstack([wall, road, right]), rgb.astype(np.uint8), "odometry", 0)
    from acq.log import schemas

    xyz, got_rgb = swath.swath_points(schemas.decode("foxglove.PointCloud", data))
    np.testing.assert_allclose(xyz[: x.size], wall, atol=1e-5)
    picture = swath.draw(xyz, got_rgb, res=0.1)
    red = (picture[..., 2] == 200) & (picture[..., 1] == 30)
    rows = np.flatnonzero(red.any(axis=1))
    assert red.sum() > 0.5 * 400 * 80  # the side view: 40 m x 8 m of wall at 10 cm/px
    assert rows.max() - rows.min() > 70  # the wall's height, seen from the street
    assert ((picture[..., 0] == 90) & (picture[..., 1] == 90)).sum() > 400 * 40  # road
    blue = (picture[..., 0] == 200) & (picture[..., 2] == 30)  # BGR
    assert blue.sum() < 400 * 10  # the right wall only as a line from above
