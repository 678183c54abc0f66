"""`acq calibrate fisheye` on an image whose header declares more pixels than any
camera gives (a small PNG claiming 30000x30000): refused by name from its header, exit
2, before anything is decoded; an image of an ordinary size still reads."""

from __future__ import annotations

import struct
import subprocess
import sys
import zlib
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[2]


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def png_of_zeros(width: int, height: int) -> bytes:
    """A valid grey 8-bit PNG of ``width`` x ``height`` black pixels (0.9 MB for 30000 x
    30000), built without compressing them: one flushed deflate block of 100 rows,
    repeated (``height`` a multiple of 100); zeros' Adler-32 is 1 and their count."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    squeeze = zlib.compressobj(9, zlib.DEFLATED, -15)
    rows = squeeze.compress(bytes((width + 1) * 100)) + squeeze.flush(zlib.Z_FULL_FLUSH)
    n = (width + 1) * height
    adler = struct.pack(">I", (n % 65521) << 16 | 1)
    idat = b"\x78\xda" + rows * (height // 100) + b"\x03\x00" + adler
    return (
        b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", idat) + _chunk(b"IEND", b"")
    )


# the command in a process of its own, its peak resident memory (kB) printed last: the
# VmHWM of its own memory (ru_maxrss would count the test process it was spawned from)
MEASURED = (
    "import sys; from acq.cli.main import main; code = main(sys.argv[1:]); "
    "print(next(line.split()[1] for line in open('/proc/self/status') "
    "if line.startswith('VmHWM:'))); sys.exit(code)"
)


def test_an_image_declaring_30000x30000_is_refused_before_decoding(tmp_path: Path) -> None:
    huge = tmp_path / "huge.png"
    huge.write_bytes(png_of_zeros(30000, 30000))
    assert huge.stat().st_size < 1_000_000
    done = subprocess.run(
        [sys.executable, "-c", MEASURED, "calibrate", "fisheye", "--fov", "185",
         "-o", str(tmp_path / "calib.yaml"), str(huge)],
        cwd=ROOT, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    (line,) = done.stderr.strip().splitlines()
    assert f"{huge}: declares 30000x30000 pixels (900 MP), more than the 100 MP" in line, line
    assert not (tmp_path / "calib.yaml").exists()
    peak_mb = int(done.stdout.split()[-1]) / 1024
    assert peak_mb < 500, f"{peak_mb:.0f} MB resident: the image was decoded"


def test_an_image_within_the_limit_still_reads(tmp_path: Path) -> None:
    from acq.calib.fisheye_calib import MAX_IMAGE_PIXELS, read_images

    assert MAX_IMAGE_PIXELS >= 8192 * 8192  # an 8K square sensor is allowed
    ok = tmp_path / "ok.png"
    cv2.imwrite(str(ok), np.full((48, 64), 7, np.uint8))
    (img,) = read_images([ok])
    assert img.shape == (48, 64) and img[0, 0] == 7
