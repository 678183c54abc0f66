"""bench/recorder_bandwidth.py: one real step (pre-rendered cameras in processes of their
own, ``acq record``) counts what it wrote, and the enlarged frames are what they claim."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from acq.drivers.mjpeg import jpeg_size
from acq.sim.prerendered import PrerenderedCamera, enlarged
from tests.bench_scripts import load

# starts simulated devices and a recorder in real time
pytestmark = pytest.mark.realtime


def test_enlarged_frames_have_the_size_asked_and_do_not_compress_to_nothing() -> None:
    camera = PrerenderedCamera(n=2, size=(1296, 972), seed=1)
    sizes = [len(j) for j in camera._jpegs]
    assert [jpeg_size(j) for j in camera._jpegs] == [(1296, 972)] * 2
    assert min(sizes) > 250_000  # the noise keeps a JPEG near a real sensor's size
    assert camera._jpegs[0] != camera._jpegs[1]
    image = np.full((4, 6, 3), 128, np.uint8)
    big = enlarged(image, (12, 8), np.random.default_rng(0))
    assert big.shape == (8, 12, 3) and big.dtype == np.uint8 and big.std() > 3


def test_a_bandwidth_step_records_every_frame_of_two_cameras(tmp_path: Path) -> None:
    bench = load("recorder_bandwidth")
    result = bench._bandwidth_step(tmp_path, 10.0, 2.0, 2, "1296x972", 3)
    assert result["zero_drops"] and result["writer_kept_up"], result
    frames = result["frames"]
    assert set(frames) == {"camera", "camera_2"}
    for text in frames.values():
        got, expected = (int(x) for x in text.split("/"))
        assert got == expected >= 15  # 10 Hz over the 2 s measured, and more
    assert result["mb_per_s"] > 1.0
    assert 0 < result["recorder_cpu_share"] < 2.0


def test_bandwidth_options_are_checked() -> None:
    script = Path(__file__).resolve().parents[1] / "bench" / "recorder_bandwidth.py"
    for args in (["--cameras", "0"], ["--fps", "10", "0"]):
        proc = subprocess.run(
            [sys.executable, str(script), *args],
            capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        assert proc.returncode == 2
        assert args[0] in proc.stderr.splitlines()[-1]
