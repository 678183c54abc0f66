"""The recorder end to end over real transports: the simulated UTM-30LX on TCP (SCIP),
the simulated fisheye as MJPEG over HTTP (in its own process), the real drivers, the
real MCAP files read back with the `mcap` readers and the Foxglove protobuf schemas."""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from acq.log.reader import LogReader
from acq.record.recorder import EXIT_DISK_FULL, Recorder
from tests.sim_rig import Rig, read_log

# drives simulated devices in real time: run alone (`make test`)
pytestmark = pytest.mark.realtime

ROOT = Path(__file__).resolve().parents[2]
TOPICS = {"/laser/scan", "/laser/raw", "/acq/timing/laser", "/camera/image/compressed",
          "/acq/timing/camera", "/acq/status", "/acq/clock"}  # fmt: skip
LATCHED = {"/tf_static", "/camera/calibration"}


def test_record_the_simulated_rig(rig: Rig, tmp_path: Path) -> None:
    cfg = rig.config(tmp_path)
    code = Recorder(cfg, duration_s=6.0).run()
    assert code == 0
    files = sorted((tmp_path / "logs").glob("*.mcap"))
    assert len(files) == 1
    log = read_log(files[0])
    scans = log["/laser/scan"]
    raws = log["/laser/raw"]
    images = log["/camera/image/compressed"]
    # every scan the device sent between the first and the last recorded is there, once,
    # with the bytes as they came
    by_tick = {s.timestamp: s for s in list(rig.scanner.sent)}
    recorded = [by_tick[m.device_ticks[0]] for _, _, m in raws]
    assert len({s.timestamp for s in recorded}) == len(recorded)
    between = [s for s in by_tick.values() if recorded[0].t0 <= s.t0 <= recorded[-1].t0]
    assert len(recorded) == len(between)
    assert all(m.data == s.telegram for (_, _, m), s in zip(raws, recorded, strict=True))
    assert len(scans) == len(raws) == len(log["/acq/timing/laser"])
    # the stamps: point 0's true time, the latency measured with TM round trips (the
    # default), within 1 ms once the clock has a few seconds of scans; plus what the
    # simulator's lateness raised the floor of either half's delays by (a loaded host
    # keeps it from writing a scan when due: no recorder can see below that floor)
    step_dt = rig.scanner.step_dt
    err = np.array([p * 1e-9 - (s.t0 + s.start * step_dt)
                    for (_, p, _), s in zip(scans, recorded, strict=True)])  # fmt: skip
    late = np.array([s.t_sent - s.t_stamp for s in recorded])
    half = len(late) // 2
    slack = max(late[:half].min(), late[half:].min()) - late.min()
    assert abs(float(np.median(err[half:]))) < 1e-3 + slack, (
        np.percentile(err, [5, 50, 95]), slack)  # fmt: skip
    # rates: scans at 40 Hz, frames at 25 Hz, nothing lost between the first and the last
    span = (scans[-1][1] - scans[0][1]) * 1e-9
    assert len(scans) == pytest.approx(span * 40 + 1, rel=0.01)
    # every frame the camera sent between the first and the last recorded, once, in order
    # (not 25 Hz exactly: on a loaded machine the simulator drops the frames it is late with)
    sent = {t.digest: t.sequence for t in rig.camera.truth() if t.status == "sent"}
    from acq.sim.camera_device import jpeg_digest

    got = [sent[jpeg_digest(m.data)] for _, _, m in images]  # KeyError: a frame never sent
    assert got == sorted(set(got))
    assert len(got) == sum(got[0] <= k <= got[-1] for k in sent.values())
    fspan = (images[-1][1] - images[0][1]) * 1e-9
    assert len(images) > 0.8 * fspan * 25
    # times: log_time (receipt) and publish_time (first point / mid-exposure) monotonic
    for topic in ("/laser/scan", "/camera/image/compressed"):
        logt = np.array([t for t, _, _ in log[topic]])
        pub = np.array([p for _, p, _ in log[topic]])
        # records that came in one read (a host busy for a while) share their receipt, and
        # so do the stamps of a camera without a clock of its own (stamped at receipt:
        # offline re-timing puts its frames back on their grid); a scan's is its own
        assert np.all(np.diff(logt) >= 0), (topic, logt)
        strictly = topic == "/laser/scan"
        assert np.all(np.diff(pub) > 0 if strictly else np.diff(pub) >= 0), (topic, pub)
        assert np.all(pub < logt)  # measured before it was received
    # the Foxglove messages carry what the devices sent
    first = scans[0][2]
    assert len(first.ranges) == 1081 and len(first.intensities) == 1081
    assert first.start_angle == pytest.approx(np.radians(-135.0))
    assert images[0][2].format == "jpeg"
    # status at 1 Hz, clock pairs, metadata
    status = log["/acq/status"]
    assert len(status) == pytest.approx(6, abs=1)
    last = status[-1][2]
    names = {d.name: d for d in last.devices}
    # rates over the last 2 s of receipts (a loaded host bunches them: 15 %)
    assert names["laser"].connected and names["laser"].rate_hz == pytest.approx(40, rel=0.15)
    assert names["camera"].rate_hz == pytest.approx(25, rel=0.15)
    assert all(d.gap_s >= 0 for d in last.devices)
    assert last.disk_free_bytes > 0
    assert len(log["/acq/clock"]) == len(status)
    with files[0].open("rb") as f:
        meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}
    assert "config" in meta and "acq" in meta
    # as any MCAP tool sees the file: UTC times (today's), the host monotonic ones plus the
    # session's offset, in log and publish times and the Foxglove stamps; acq.* monotonic
    offset = int(meta["acq"]["utc_offset_ns"])
    assert abs(offset - (time.time_ns() - time.monotonic_ns())) < 10**9
    with files[0].open("rb") as f:
        seen = {}
        for _, channel, message in make_reader(f).iter_messages(log_time_order=False):
            seen.setdefault(channel.topic, (message.log_time, message.publish_time))
    assert abs(seen["/laser/scan"][0] - time.time_ns()) < 60 * 10**9
    for topic in ("/laser/scan", "/camera/image/compressed", "/acq/timing/laser"):
        log_ns, pub_ns, _ = log[topic][0]
        assert seen[topic] == (log_ns + offset, pub_ns + offset)
    assert scans[0][2].timestamp.ToNanoseconds() == scans[0][1]  # monotonic, as read back
    timing = log["/acq/timing/laser"][0]
    assert timing[2].stamp_ns == timing[1] and timing[2].recv_ns == timing[0]
    import json

    geometry = json.loads(meta["device.laser"]["geometry"])
    assert geometry["time_increment"] == pytest.approx(0.025 / 1440)
    assert geometry["stamp_offset_s"] == pytest.approx(180 * 0.025 / 1440)
    assert json.loads(meta["device.laser"]["params"])["ares"] == 1440
    assert json.loads(meta["device.camera"]["format"])["width"] == 780
    # the clock offsets in the metadata and the status: host minus device time
    offset = int(meta["clock"]["laser.offset_ns"])
    assert offset != 0 and int(meta["clock"]["laser.epoch"]) == 0
    assert abs(names["laser"].clock_offset_ns - offset) < 0.01e9  # drift over seconds: tiny


def _acq(*args: str, **kw: object) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        [sys.executable, "-m", "acq.cli", *args], cwd=ROOT, stderr=subprocess.PIPE, **kw
    )  # type: ignore[call-overload]


def test_sigterm_finishes_the_file_within_2_s(rig: Rig, tmp_path: Path) -> None:
    cfg = rig.config(tmp_path)
    assert cfg.source is not None
    proc = _acq("record", "-c", str(cfg.source))
    time.sleep(4.0)
    t0 = time.monotonic()
    proc.send_signal(signal.SIGTERM)
    code = proc.wait(10)
    took = time.monotonic() - t0
    err = proc.stderr.read().decode() if proc.stderr else ""
    assert code == 0, err
    assert took < 2.0, err
    files = sorted((tmp_path / "logs").glob("*.mcap"))
    log = read_log(files[-1])  # the seeking reader: footer and summary are there
    assert len(log["/laser/scan"]) > 40


def test_bad_config_exits_2_with_one_line(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text("version: 1\nscanners:\n  - name: laser\n    driver: hokuyo\n    url: x\n"
                    "    latncy_s: 0\n")  # fmt: skip
    proc = _acq("record", "-c", str(path))
    code = proc.wait(30)
    err = proc.stderr.read().decode().strip() if proc.stderr else ""
    assert code == 2
    assert len(err.splitlines()) == 1 and "scanners[0].latncy_s" in err and str(path) in err


@pytest.fixture
def small_disk(tmp_path: Path) -> Iterator[Path]:
    """An 8 MB tmpfs (root can mount one; elsewhere skip: the reserve test still runs)."""
    mount = tmp_path / "disk"
    mount.mkdir()
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=8m", "tmpfs", str(mount)], capture_output=True
    )
    if done.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs here: {done.stderr.decode().strip()}")
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], capture_output=True)


def test_a_full_disk_closes_the_file_and_exits_3(
    rig: Rig, tmp_path: Path, small_disk: Path
) -> None:
    cfg = rig.config(tmp_path, reserve_megabytes=2)
    code = Recorder(cfg, out_dir=small_disk, duration_s=30.0).run()
    assert code == EXIT_DISK_FULL
    files = sorted(small_disk.glob("*.mcap"))
    assert files
    log = read_log(files[-1])  # closed cleanly: the seeking reader opens it
    assert len(log["/camera/image/compressed"]) > 20
    free = os.statvfs(small_disk)
    assert free.f_bavail * free.f_frsize > 1e6  # it stopped before the disk was full


def test_below_the_reserve_at_start_exits_3(rig: Rig, tmp_path: Path) -> None:
    free_mb = os.statvfs(tmp_path).f_bavail * os.statvfs(tmp_path).f_frsize / 1e6
    cfg = rig.config(tmp_path, reserve_megabytes=free_mb * 2)
    code = Recorder(cfg, duration_s=10.0).run()
    assert code == EXIT_DISK_FULL
    files = sorted((tmp_path / "logs").glob("*.mcap"))
    read_log(files[-1])


def test_a_scanner_outage_is_a_gap_and_recording_goes_on(
    rig: Rig, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="acq.record")
    cfg = rig.config(tmp_path)
    import threading

    def pull_cable() -> None:
        time.sleep(2.0)
        rig.scanner_server.reboot(1.0)  # down 1 s, then back with a restarted clock

    threading.Thread(target=pull_cable, daemon=True).start()
    assert Recorder(cfg, duration_s=7.0).run() == 0
    files = sorted((tmp_path / "logs").glob("*.mcap"))
    log = read_log(files[-1])
    t = np.array([p for _, p, _ in log["/laser/scan"]]) * 1e-9
    gaps = np.diff(t)
    assert gaps.max() > 0.9  # the outage
    assert t[-1] - t[np.argmax(gaps) + 1] > 2.0  # and scans again after it
    frames = np.array([p for _, p, _ in log["/camera/image/compressed"]]) * 1e-9
    assert np.diff(frames).max() < 0.2  # the camera kept recording meanwhile
    status = [m for _, _, m in log["/acq/status"]]
    laser = [next(d for d in s.devices if d.name == "laser") for s in status]
    assert any(not d.connected or d.gap_s > 0.5 for d in laser)
    assert laser[-1].connected and laser[-1].disconnects >= 1
    assert laser[-1].epoch >= 1  # the device clock restarted: a new epoch
    # the latency measured again at the reconnection, with the new clock: stamps on time
    assert caplog.text.count("20 time queries") >= 2, caplog.text
    by_tick = {s.timestamp: s for s in list(rig.scanner.sent)}
    step_dt = rig.scanner.step_dt
    after = [(p, by_tick[m.device_ticks[0]]) for (_, p, _), (_, _, m)
             in zip(log["/laser/scan"], log["/laser/raw"], strict=True)
             if p * 1e-9 > t[-1] - 1.5 and m.device_ticks[0] in by_tick]  # fmt: skip
    err = [p * 1e-9 - (s.t0 + s.start * step_dt) for p, s in after]
    assert len(err) > 40 and abs(float(np.median(err))) < 1e-3, np.percentile(err, [5, 50, 95])


def _kill_once(rig: Rig, cfg_path: Path, out: Path, delay_s: float) -> tuple[int, Path]:
    """Start `acq record`, SIGKILL it ``delay_s`` after both its devices connected (the
    moment depends on the recording, not on how long a busy machine took to start Python
    and connect); (kill time ns, the file)."""
    said = out.parent / f"{out.name}.log"
    proc = subprocess.Popen(
        [sys.executable, "-m", "acq.cli", "record", "-c", str(cfg_path), "--out", str(out)],
        cwd=ROOT,
        stderr=said.open("wb"),
    )
    deadline = time.monotonic() + 30.0
    while time.monotonic() < deadline and proc.poll() is None:
        log = said.read_text(errors="replace")
        if "laser connected" in log and "camera connected" in log and any(out.glob("*.mcap")):
            break
        time.sleep(0.01)
    time.sleep(delay_s)
    killed_ns = time.monotonic_ns()
    proc.kill()
    proc.wait(10)
    files = sorted(out.glob("*.mcap"))
    assert len(files) == 1, files
    return killed_ns, files[0]


def _check_killed_file(rig: Rig, path: Path, killed_ns: int, started_ns: int) -> int:
    """Every scan and frame the devices sent more than 1.2 s before the kill, after the
    first one recorded, is read back from the killed file; returns how many."""
    from acq.log import info, read_messages

    ticks: set[int] = set()
    jpegs: set[bytes] = set()
    for _schema, channel, message in read_messages(path):
        if channel.topic == "/laser/raw":
            ticks.add(schemas_decode("acq.RawTelegram", message.data).device_ticks[0])
        elif channel.topic == "/camera/image/compressed":
            jpegs.add(jpeg_digest(schemas_decode("foxglove.CompressedImage", message.data).data))
    assert info(path).closed is False
    cutoff = killed_ns * 1e-9 - 1.2
    p = rig.scanner.model
    send_delay = (p.amax + 1) * p.scan_period / p.ares
    sent = [s for s in list(rig.scanner.sent) if started_ns * 1e-9 < s.t0 + send_delay < cutoff]
    recorded = [s for s in sent if s.timestamp in ticks]
    assert recorded, "nothing recorded"
    first = min(s.t0 for s in recorded)
    missing = [s.t0 for s in sent if s.t0 >= first and s.timestamp not in ticks]
    assert not missing, f"{len(missing)} scans sent before the cut-off are lost"
    frames = [t for t in rig.camera.truth()
              if t.status == "sent" and t.t_sent is not None
              and started_ns * 1e-9 < t.t_sent < cutoff]  # fmt: skip
    got = [t for t in frames if t.digest in jpegs]
    assert got
    lost = [t for t in frames if t.t_sent >= min(g.t_sent for g in got) and t.digest not in jpegs]
    assert not lost, f"{len(lost)} frames sent before the cut-off are lost"
    return len(recorded) + len(got)


def schemas_decode(name: str, data: bytes) -> object:
    from acq.log import schemas

    return schemas.decode(name, data)


def jpeg_digest(data: bytes) -> bytes:
    from acq.sim.camera_device import jpeg_digest as digest

    return digest(data)


def _kill_loop(rig: Rig, tmp_path: Path, runs: range, seed: int) -> None:
    from acq.log import info, repair

    cfg = rig.config(tmp_path / f"rig{seed}", latency=0.0)  # no TM queries: a quicker start
    assert cfg.source is not None
    rng = np.random.default_rng(seed)
    for i in runs:
        out = tmp_path / f"kill{i:02d}"
        started = time.monotonic_ns()
        killed, path = _kill_once(rig, cfg.source, out, float(rng.uniform(1.5, 2.3)))
        try:
            n = _check_killed_file(rig, path, killed, started)
        except AssertionError as e:
            log = (tmp_path / f"kill{i:02d}.log").read_text()
            raise AssertionError(f"{e}\nthe recorder said:\n{log}") from None
        assert n >= 2
        if i % 5 == 0:  # and --repair gives a file the seeking reader opens
            fixed = out / "repaired.mcap"
            assert repair(path, fixed) > 0
            assert sum(len(v) for v in read_log(fixed).values()) == info(path).messages
        # power loss is not SIGKILL: the tail after the last complete record may be
        # anything (cut short, zeros, the start of a chunk); the same messages come back
        if i % 4 == 1:
            data = path.read_bytes()
            good = info(path).bytes_read
            expect = info(path).messages
            for j, cut in enumerate([good, *rng.integers(good, len(data) + 1, 3).tolist()]):
                damaged = out / f"cut{j}.mcap"
                damaged.write_bytes(data[:cut] + b"\0" * (4096 if j == 2 else 0))
                assert info(damaged).messages == expect


def test_sigkill_at_random_moments_loses_at_most_the_last_second(rig: Rig, tmp_path: Path) -> None:
    # 20 kills; each file is read up to the cut by `acq info`'s reader, and must hold
    # every scan and frame sent more than 1.2 s before the kill. Two rigs of their own
    # devices, ten kills each at the same time: the recorders mostly wait on their
    # devices, and the suite's time matters.
    from concurrent.futures import ThreadPoolExecutor

    second = Rig().warm_up()
    try:
        for seed in (1, 2):
            (tmp_path / f"rig{seed}").mkdir()
        with ThreadPoolExecutor(2) as pool:
            runs = [
                pool.submit(_kill_loop, rig, tmp_path, range(10), 1),
                pool.submit(_kill_loop, second, tmp_path, range(10, 20), 2),
            ]
            for run in runs:
                run.result()
    finally:
        second.close()


def test_files_roll_over_with_nothing_lost_or_repeated(rig: Rig, tmp_path: Path) -> None:
    cfg = rig.config(tmp_path, split_megabytes=1.5)
    cfg = cfg.model_copy(update={"calibration": rig.calibration(tmp_path)})
    assert Recorder(cfg, duration_s=4.0).run() == 0
    files = sorted((tmp_path / "logs").glob("*.mcap"))
    assert len(files) >= 3
    ticks: list[int] = []
    frames: list[int] = []  # the camera's received count at each frame
    for path in files:
        log = read_log(path)  # each file opens on its own, indexed
        # and stands alone: transforms, camera calibration, metadata at its start
        assert len(log["/tf_static"]) == 1 and len(log["/camera/calibration"]) == 1
        # stamped when the recorder started, in a later file with the log time of the record
        # that opened it (records of other devices may follow with earlier receive times:
        # their threads queue them in turn)
        in_file_order = LogReader(path).messages()
        opening = next(m for _, c, m in in_file_order if c.topic not in LATCHED)
        start = min(t for msgs in log.values() for t, _, _ in msgs)
        assert log["/tf_static"][0][0] == (start if path == files[0] else opening.log_time)
        tf = log["/tf_static"][0][2]
        assert {t.child_frame_id for t in tf.transforms} >= {"camera"}
        with path.open("rb") as f:
            reader = make_reader(f)
            names = {m.name for m in reader.iter_metadata()}
            summary = reader.get_summary()
        assert {"acq", "config", "calibration", "device.laser"} <= names or path == files[0]
        # every channel is in every file; a device's records need not be (the last file
        # may hold only the scans that came after the last frame, before the stop)
        assert summary is not None and TOPICS <= {c.topic for c in summary.channels.values()}
        ticks += [m.device_ticks[0] for _, _, m in log.get("/laser/raw", [])]
        timing = log.get("/acq/timing/camera", [])
        frames += [m.received for _, _, m in timing]
        assert len(log.get("/camera/image/compressed", [])) == len(timing)
    # across the boundaries: every scan once, in order, none missing (40 Hz: 25 ms steps)
    assert len(ticks) == len(set(ticks))
    steps = np.diff(np.array(ticks))
    assert np.all((steps >= 24) & (steps <= 26)), steps[(steps < 24) | (steps > 26)]
    # every frame the recorder received, once (its running count goes up by one)
    assert np.all(np.diff(frames) == 1)


def test_two_cameras_each_recorded_whole_on_their_own_topics(tmp_path: Path) -> None:
    """A rig with a left and a right fisheye (each its own MJPEG server): every frame each
    camera sent between its first and last recorded is on its own topics, once, bytes as
    sent; its timing, its device status and its row in `acq info`."""
    from acq.log import info
    from acq.sim.camera_device import jpeg_digest

    two = Rig(cameras=("left", "right"))
    try:
        two.warm_up()
        assert Recorder(two.config(tmp_path), duration_s=5.0).run() == 0
        truths = {name: camera.truth() for name, camera in two.cameras.items()}
    finally:
        two.close()
    (path,) = sorted((tmp_path / "logs").glob("*.mcap"))
    log = read_log(path)
    for name, truth in truths.items():
        images, timing = log[f"/{name}/image/compressed"], log[f"/acq/timing/{name}"]
        sent = [t for t in truth if t.status == "sent"]
        by_digest = {t.digest: t.sequence for t in sent}
        got = [by_digest[jpeg_digest(m.data)] for _, _, m in images]  # KeyError: not its own
        window = [t.sequence for t in sent if got[0] <= t.sequence <= got[-1]]
        assert got == window and len(got) > 0.9 * 5.0 * 25, name  # none lost, none twice
        assert len(timing) == len(images)
        counts = [m.received for _, _, m in timing]  # the camera's running count
        assert counts == list(range(counts[0], counts[0] + len(timing)))
    status = {d.name: d for d in log["/acq/status"][-1][2].devices}
    assert status.keys() == {"laser", "left", "right"}
    assert all(status[n].connected and status[n].rate_hz > 20 for n in ("left", "right"))
    summary = info(path)
    assert {d for d in summary.drops} >= {"left", "right"}
    assert {c.topic for c in summary.channels} >= {"/left/image/compressed",
                                                   "/right/image/compressed"}  # fmt: skip
