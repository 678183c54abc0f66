"""Partial JPEG decoding for colouring (issue 32): how much of each frame colouring reads,
and what decoding only that costs against decoding the frame whole.

Data: ``bench/colorize_speed.py``'s two-camera drive (``--seconds``, default 20; kept in
``--work``, e.g. the folder that bench uses). ``acq colorize``'s pipeline
(:func:`acq.cloud.colorize.run`, its defaults) runs once in this process, watched: each
frame it decodes and colours is kept with the pixels its colouring reads
(:func:`acq.camera.projection.pixels_read` of the points and pairs it colours there:
every pixel the sampling reads, and one more each side).

One JSON line per figure:

- ``need``: per frame, the fraction of its iMCU rows (16 px for 4:2:0) that hold a pixel
  read (``imcu_rows``), of the rows up to the end of the last such iMCU row (the entropy
  decoding stops there: ``to_last``), of its pixels in the box of rows x columns read
  (``box``), of its 16 x 16 px blocks that hold a pixel read (``blocks16``: what a
  decoder skipping whole blocks would decode; the float64 camera model, no margin);
  median and mean over the frames.
- ``decode``: ms per frame per core, on every core as colouring decodes (a thread each)
  and on one, and CPU seconds: ``whole`` (``acq.camera.jpeg.decode_jpeg_transient``,
  simplejpeg, as colouring decodes), ``partial`` (`bench/jpeg_partial.py`'s
  header check and decode of those pixels), ``whole_libjpeg`` (the same library
  decoding every pixel) and ``entropy_only`` (its decode of the last iMCU row, 16
  columns: the entropy decoding of the whole frame that skipping rows cannot avoid).
- ``identical``: frames whose pixels read differ between the partial decode and
  simplejpeg's whole one, and the largest channel difference.

Without the system libjpeg-turbo, one line says so and the script exits 0.

Run as a script: ``python bench/partial_decode.py [--seconds S] [--work DIR] [--repeat N]``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # run as a script or loaded by path
from colorize_speed import drive

Kept = tuple[bytes, Any, np.ndarray, int, int, np.ndarray]  # jpeg, header, rows, x0, x1, blocks
BLOCK = 16  # px: the MCU of a 4:2:0 JPEG


def _line(bench: str, **fields: Any) -> None:
    print(json.dumps({"bench": "partial_decode", "figure": bench, **fields}), flush=True)


def _colorize(files: list[Path], calib: Path, out: Path) -> None:
    from acq.camera import calibfile
    from acq.cloud import colorize

    colorize.run(files, calibfile.load(calib), out, preview=None)


def kept_frames(files: list[Path], calib: Path, work: Path) -> list[Kept]:
    """Each frame colouring decodes and colours, with the pixels it reads there."""
    import jpeg_partial

    from acq.camera import jpeg, projection
    from acq.cloud import views

    marks: dict[int, tuple[bytes, np.ndarray, np.ndarray, np.ndarray]] = {}
    lock = threading.Lock()
    last = threading.local()  # the frame this thread decoded last
    decode, colour = jpeg.decode_jpeg_transient, views.Colouring.colour_image

    def decoding(data: bytes) -> np.ndarray | None:
        last.jpeg = data
        return decode(data)

    def colouring(self: Any, image: Any, idx: Any, R: Any, t: Any, *rest: Any) -> bool:
        data = getattr(last, "jpeg", None)
        model = self.model
        if (
            data is not None
            and image is not None
            and image.shape[:2] == (model.height, model.width)
        ):
            with lock:
                _, rows, cols, blocks = marks.setdefault(id(data), (
                    data, np.zeros(model.height, bool), np.array([model.width, 0]),
                    np.zeros((-(-model.height // BLOCK), -(-model.width // BLOCK)), bool),
                ))  # fmt: skip
                pairs = rest[0] if rest else None
                for P, sub in ((self.P, idx), (self.pair_P, pairs)):
                    if sub is not None and sub.size:
                        projection.pixels_read(P, sub, model, (R, t), rows, cols)
                        _mark_blocks(model, (P[sub] - t) @ R, blocks)
        return colour(self, image, idx, R, t, *rest)

    jpeg.decode_jpeg_transient = decoding  # type: ignore[assignment]
    views.decode_jpeg_transient = decoding  # type: ignore[assignment]
    views.Colouring.colour_image = colouring  # type: ignore[method-assign]
    try:
        _colorize(files, calib, work / "colour.ply")
    finally:
        jpeg.decode_jpeg_transient = decode  # type: ignore[assignment]
        views.decode_jpeg_transient = decode  # type: ignore[assignment]
        views.Colouring.colour_image = colour  # type: ignore[method-assign]
    kept = []
    for data, rows, cols, blocks in marks.values():
        header = jpeg_partial.plain_header(data)
        if header is not None:
            kept.append((data, header, rows, int(cols[0]), int(cols[1]), blocks))
    return kept


def _mark_blocks(model: Any, P_cam: np.ndarray, blocks: np.ndarray) -> None:
    """The BLOCK x BLOCK px blocks holding a pixel the sampling reads for the points
    ``P_cam`` (camera frame, m), by the float64 camera model (no margin)."""
    uv, ok = model.project(P_cam)
    uv = uv[ok]
    for du in (0, 1):  # bilinear reads floor(x) and floor(x) + 1
        for dv in (0, 1):
            u = np.clip(np.floor(uv[:, 0]).astype(int) + du, 0, model.width - 1)
            v = np.clip(np.floor(uv[:, 1]).astype(int) + dv, 0, model.height - 1)
            blocks[v // BLOCK, u // BLOCK] = True


def _stats(values: list[float]) -> dict[str, float]:
    return {
        "median": round(statistics.median(values), 4),
        "mean": round(statistics.fmean(values), 4),
    }


def need(kept: list[Kept]) -> dict[str, Any]:
    imcu, to_last, box, in_blocks = [], [], [], []
    for _, header, rows, x0, x1, blocks in kept:
        in_blocks.append(float(blocks.mean()))
        step = header.imcu_rows
        blocks = np.add.reduceat(rows.astype(np.int64), np.arange(0, rows.size, step)) > 0
        imcu.append(float(blocks.mean()))
        used = np.flatnonzero(blocks)
        to_last.append(float((used[-1] + 1) / blocks.size) if used.size else 0.0)
        r = np.flatnonzero(rows)
        span = (r[-1] - r[0] + 1) * max(x1 - x0, 0) if r.size else 0
        box.append(float(span) / (header.width * header.height))
    return {"frames": len(kept), "imcu_rows": _stats(imcu), "to_last": _stats(to_last),
            "box": _stats(box), f"blocks{BLOCK}": _stats(in_blocks)}  # fmt: skip


def _timed(fn: Callable[[Kept], object], kept: list[Kept], threads: int) -> tuple[float, float]:
    """(wall s, CPU s of the process) for ``fn`` over ``kept`` on ``threads`` threads."""
    t0, c0 = time.perf_counter(), time.process_time()
    with ThreadPoolExecutor(max_workers=threads) as pool:
        for _ in pool.map(fn, kept, chunksize=16):
            pass
    return time.perf_counter() - t0, time.process_time() - c0


_buffers = threading.local()


def _out(header: Any) -> np.ndarray:
    """This thread's image for ``header``'s size."""
    shape = (header.height, header.width, 3)
    out: np.ndarray | None = getattr(_buffers, "out", None)
    if out is None or out.shape != shape:
        out = np.empty(shape, np.uint8)
        _buffers.out = out
    return out


def decode(kept: list[Kept], repeat: int) -> dict[str, Any]:
    import jpeg_partial

    from acq.camera.jpeg import decode_jpeg_transient

    def whole(k: Kept) -> object:
        return decode_jpeg_transient(k[0])

    def partial(k: Kept) -> object:
        header = jpeg_partial.plain_header(k[0])
        return jpeg_partial.decode_rows(k[0], header, k[2], k[3], k[4], _out(header))

    def whole_libjpeg(k: Kept) -> object:
        rows = np.ones(k[1].height, bool)
        return jpeg_partial.decode_rows(k[0], k[1], rows, 0, k[1].width, _out(k[1]))

    def entropy_only(k: Kept) -> object:
        rows = np.zeros(k[1].height, bool)
        rows[-1] = True
        return jpeg_partial.decode_rows(k[0], k[1], rows, 0, 16, _out(k[1]))

    cores = os.cpu_count() or 1
    out: dict[str, Any] = {"frames": len(kept), "cores": cores, "repeat": repeat}
    kinds = {"whole": whole, "partial": partial, "whole_libjpeg": whole_libjpeg,
             "entropy_only": entropy_only}  # fmt: skip
    for threads in sorted({cores, 1}, reverse=True):
        for name, fn in kinds.items():
            best = min((_timed(fn, kept, threads) for _ in range(repeat)), key=lambda w: w[0])
            out[f"{name}_ms_per_frame_core_{threads}t"] = round(
                best[0] * threads / max(len(kept), 1) * 1e3, 3
            )
            out[f"{name}_cpu_s_{threads}t"] = round(best[1], 3)
    out["cpu_whole_over_partial"] = round(
        out[f"whole_cpu_s_{cores}t"] / max(out[f"partial_cpu_s_{cores}t"], 1e-9), 2
    )
    return out


def identical(kept: list[Kept]) -> dict[str, Any]:
    import jpeg_partial
    import simplejpeg

    differ, largest, fell_back = 0, 0, 0
    for jpeg, header, rows, x0, x1, _ in kept:
        whole = simplejpeg.decode_jpeg(jpeg, colorspace="BGR")
        part = np.zeros_like(whole)
        if not jpeg_partial.decode_rows(jpeg, header, rows, x0, x1, part):
            fell_back += 1
            continue
        a, b = whole[rows, x0:x1].astype(np.int16), part[rows, x0:x1].astype(np.int16)
        d = int(np.abs(a - b).max()) if a.size else 0
        differ += d > 0
        largest = max(largest, d)
    return {"frames": len(kept), "differ": differ, "largest_difference": largest,
            "not_decoded_partially": fell_back}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="the drive's length (20)")
    ap.add_argument("--work", type=Path, help="keep the drive here (default: a temporary folder)")
    ap.add_argument("--repeat", type=int, default=3, help="timed passes, the best kept (3)")
    args = ap.parse_args()
    import jpeg_partial

    if not jpeg_partial.available():
        _line("skipped", why=jpeg_partial.why_unavailable())
        return
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        files, calib, _ = drive(work, args.seconds)
        kept = kept_frames(files, calib, Path(tmp))
        _line("need", **need(kept))
        _line("decode", **decode(kept, args.repeat), load=[round(x, 2) for x in os.getloadavg()])
        _line("identical", **identical(kept))


if __name__ == "__main__":
    main()
